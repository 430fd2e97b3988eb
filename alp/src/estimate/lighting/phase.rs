//! The lighting phase: an objective's lighting terms minimised over the map
//! at a fixed pose. When every term has a form the exact least-squares
//! solve covers (the weighted data term and at most one neighbour
//! smoothness), the declaration compiles to that solve; otherwise, or when
//! asked ([`LightingMethod::Tape`]), each evaluation records the terms on a
//! tape -- the map a leaf, the pixels the transport applied to it
//! ([`TransportOp`]) -- and the same bounded, preconditioned L-BFGS
//! minimises them.
//!
//! The output map's solve minimises the estimate's objective; the pose
//! searches' solves are instruments of the search, a data term and a
//! quadratic smoothness of their own weight ([`LightingTerms::quadratic`]).

use std::cell::OnceCell;
use std::collections::BTreeMap;
use std::sync::Arc;

use autodiff::Tape;
use render::lookup::ImageVars;
use render::pose::Pose;
use render::posed::{PoseVars, pack_pose};
use render::silhouette::ReferenceMask;
use render::transport::{Transport, TransportOp};

use super::least_squares::{LightingSolve, Solved, minimise, solve_with};
use crate::error::{Error, Result};
use crate::estimate::photo::Photo;
use crate::estimate::pose::hypotheses::front_facing;
use crate::estimate::settings::LightingMethod;
use crate::objective::{
    DataTerm, ImageTerms, LeastSquaresData, LeastSquaresForm, LightingInputs, NeighbourSmoothness, Objective, Phase,
    PriorBasis, TermContext, Weighting, mask_mean_luminance, summed_curvature,
};

/// The progress at which the lighting phase reads its terms' weights: it
/// runs once the pose is found.
const LIGHTING_PROGRESS: f64 = 1.0;

/// Unknowns whose known curvature is below this fraction of the mean are
/// preconditioned as if at it: a term without a least-squares form tells
/// the solve nothing of its curvature.
const CURVATURE_FLOOR: f64 = 1e-3;

/// How the terms are minimised.
#[derive(Clone, Debug, PartialEq)]
enum Plan {
    /// The exact least-squares solve with these priors (each weight over
    /// the data term's).
    Exact(Vec<(LeastSquaresForm, f64)>),
    /// The terms on a tape.
    Tape,
}

/// An objective's lighting terms, compiled.
pub struct LightingTerms {
    objective: Arc<Objective>,
    plan: Plan,
}

/// One solve of a fit: its transport, the data term, its bounds and budget,
/// and the map it starts from (which also sets its smoothness's levels).
pub(in crate::estimate) struct Level<'a> {
    pub(in crate::estimate) transport: &'a Arc<Transport>,
    pub(in crate::estimate) data: &'a Arc<DataTerm>,
    pub(in crate::estimate) settings: LightingSolve,
    pub(in crate::estimate) start: &'a [f64],
}

/// What the terms on a tape read besides the map: the photo, the pose and
/// the pixels the transport renders.
pub(in crate::estimate) struct TapeScene<'a> {
    photo: &'a Photo,
    pose: &'a Pose,
    pixels: &'a [u32],
    seed: u64,
    /// The photo's mask prepared for the mask terms and its mean level in
    /// the mask, made when a tape first needs them: once per fit, not per
    /// level, and never for a fit the exact solve alone minimises.
    prepared: OnceCell<(ReferenceMask, f64)>,
}

impl<'a> TapeScene<'a> {
    /// The scene of a fit at `pose` rendering `pixels` of `photo`, its
    /// stochastic terms seeded `seed`.
    pub(in crate::estimate) fn new(photo: &'a Photo, pose: &'a Pose, pixels: &'a [u32], seed: u64) -> Self {
        TapeScene {
            photo,
            pose,
            pixels,
            seed,
            prepared: OnceCell::new(),
        }
    }

    /// The photo's prepared mask and its mean level in the mask.
    fn prepared(&self) -> Result<&(ReferenceMask, f64)> {
        if self.prepared.get().is_none() {
            let photo = self.photo;
            let prepared = (
                ReferenceMask::new(&photo.mask)?,
                mask_mean_luminance(&photo.image, &photo.mask)?,
            );
            let _ = self.prepared.set(prepared);
        }
        Ok(self.prepared.get().expect("set above"))
    }
}

impl LightingTerms {
    /// The lighting terms of `objective`: compiled to the exact solve when
    /// each has a least-squares form, the data term is there once at a
    /// positive weight and the smoothness at most once, and `method` is not
    /// [`LightingMethod::Tape`]. Fails when the objective is invalid or
    /// declares no lighting term (the map would be unconstrained).
    pub fn compile(objective: Arc<Objective>, method: LightingMethod) -> Result<Self> {
        objective.validate()?;
        if objective.terms_in(Phase::Lighting).next().is_none() {
            return Err(Error::invalid(
                "objective",
                "declares no term for the lighting phase: the map would be unconstrained \
                 (the default's are data_least_squares and neighbour_smoothness)",
            ));
        }
        let plan = match method {
            LightingMethod::Tape => Plan::Tape,
            _ => exact_plan(&objective).map_or(Plan::Tape, Plan::Exact),
        };
        Ok(LightingTerms { objective, plan })
    }

    /// A pose search's instrument: the data term and a quadratic
    /// smoothness of `weight`.
    pub fn quadratic(weight: f64, method: LightingMethod) -> Result<Self> {
        let objective = Objective::new()
            .term(LeastSquaresData)
            .term(NeighbourSmoothness::quadratic().weight(weight));
        Self::compile(Arc::new(objective), method)
    }

    /// Whether the terms compiled to the exact solve.
    pub fn is_exact(&self) -> bool {
        matches!(self.plan, Plan::Exact(_))
    }

    /// The map minimising the terms at `level`.
    pub(in crate::estimate) fn solve(&self, level: &Level, scene: &TapeScene) -> Result<Solved> {
        match &self.plan {
            Plan::Exact(priors) => solve_with(level.transport, level.data, priors, level.settings, level.start),
            Plan::Tape => self.solve_on_tape(level, scene),
        }
    }

    /// The lighting terms at the map `env` solved at `level` (rendered as
    /// `rendered`): each term's unweighted value and each unknown's
    /// deviation ([`Recorder::posterior_sigma`]).
    pub(in crate::estimate) fn account(
        &self,
        level: &Level,
        env: &[f64],
        rendered: &[[f64; 3]],
        scene: &TapeScene,
    ) -> Result<Account> {
        let recorder = Recorder::new(self, level, scene)?;
        let tape = Tape::new();
        let values = recorder.record(&tape, env)?.1.values();
        Ok(Account {
            values,
            sigma: recorder.posterior_sigma(rendered),
        })
    }

    fn solve_on_tape(&self, level: &Level, scene: &TapeScene) -> Result<Solved> {
        let (settings, x0) = (level.settings, level.start);
        let recorder = Recorder::new(self, level, scene)?;
        let curvature = recorder.curvature();
        let mut failure = None;
        let mut objective = |x: &[f64], g: &mut [f64]| -> f64 {
            let tape = Tape::new();
            match recorder.record(&tape, x) {
                Ok((env, evaluation)) => {
                    tape.backward(evaluation.total);
                    g.copy_from_slice(&tape.grad(env));
                    tape.item(evaluation.total)
                }
                Err(e) => {
                    failure.get_or_insert(e);
                    g.fill(0.0);
                    f64::NAN
                }
            }
        };
        let solved = minimise(&mut objective, &curvature, &recorder.inputs.basis, settings, x0)?;
        match failure {
            Some(e) => Err(e),
            None => Ok(solved),
        }
    }
}

/// Per texel, the curvature of the lighting terms with a prior's
/// least-squares form on `basis` (in one channel, at small differences).
fn prior_curvature(objective: &Objective, basis: &PriorBasis) -> Vec<f64> {
    let priors: Vec<_> = (objective.terms_in(Phase::Lighting))
        .filter_map(|t| {
            let weight = t.weight().at(LIGHTING_PROGRESS);
            t.term().least_squares_form().and_then(|f| f.prior(basis, weight))
        })
        .collect();
    summed_curvature(&priors, basis.width * basis.height)
}

/// The exact solve's priors when every lighting term of non-zero weight
/// has a form it covers: the data term once at a positive weight, each
/// prior at most once (its weight over the data's).
fn exact_plan(objective: &Objective) -> Option<Vec<(LeastSquaresForm, f64)>> {
    let (mut data, mut priors) = (None, Vec::<(LeastSquaresForm, f64)>::new());
    for t in objective.terms_in(Phase::Lighting) {
        let weight = t.weight().at(LIGHTING_PROGRESS);
        // A term at weight 0 is left out of the total (Objective::evaluate).
        if weight == 0.0 {
            continue;
        }
        let form = t.term().least_squares_form()?;
        let repeated = priors
            .iter()
            .any(|(f, _)| std::mem::discriminant(f) == std::mem::discriminant(&form));
        match form {
            LeastSquaresForm::Data if data.is_none() && weight > 0.0 => data = Some(weight),
            LeastSquaresForm::Smoothness(_) | LeastSquaresForm::Latitude(_) if !repeated => priors.push((form, weight)),
            _ => return None,
        }
    }
    let data = data?;
    Some(priors.into_iter().map(|(f, w)| (f, w / data)).collect())
}

/// What [`LightingTerms::account`] tells of a solved map.
pub(in crate::estimate) struct Account {
    /// Each lighting term's unweighted value.
    pub(in crate::estimate) values: BTreeMap<String, f64>,
    /// Each unknown's standard deviation.
    pub(in crate::estimate) sigma: Vec<f64>,
}

/// Records the lighting terms at a map on a tape.
struct Recorder<'a> {
    terms: &'a LightingTerms,
    op: Arc<TransportOp>,
    inputs: LightingInputs,
    scene: &'a TapeScene<'a>,
    reference: &'a ReferenceMask,
    weight: Vec<f64>,
    level: f64,
    pose: [f64; render::posed::POSE_PARAMS],
    front_facing: glam::Quat,
    size: (usize, usize),
}

impl<'a> Recorder<'a> {
    fn new(terms: &'a LightingTerms, level: &Level, scene: &'a TapeScene<'a>) -> Result<Self> {
        let Level {
            transport,
            data,
            settings,
            start,
        } = *level;
        let basis = PriorBasis::new(
            transport,
            data,
            start,
            settings.relative_smoothness,
            settings.clipped_light_share,
        );
        let (reference, level) = scene.prepared()?;
        Ok(Recorder {
            terms,
            op: Arc::new(TransportOp::new(transport.clone())),
            inputs: LightingInputs {
                data: data.clone(),
                basis,
            },
            scene,
            reference,
            weight: (0..data.target.len()).map(|p| data.used(p) as u8 as f64).collect(),
            level: *level,
            pose: pack_pose(scene.pose),
            front_facing: front_facing(&scene.photo.camera),
            size: (transport.width, transport.height),
        })
    }

    /// The weight of the data term (1 when the objective has none: the
    /// curvature then still scales by the photo's).
    fn data_weight(&self) -> f64 {
        let weight = (self.terms.objective.terms_in(Phase::Lighting))
            .filter(|t| t.term().least_squares_form() == Some(LeastSquaresForm::Data))
            .map(|t| t.weight().at(LIGHTING_PROGRESS))
            .sum::<f64>();
        if weight > 0.0 { weight } else { 1.0 }
    }

    /// The objective's curvature per unknown: the data term's and the
    /// priors' with a least-squares form, at least a small share of their
    /// mean (the preconditioner's).
    fn curvature(&self) -> Vec<f64> {
        let basis = &self.inputs.basis;
        let prior = prior_curvature(&self.terms.objective, basis);
        let data_weight = self.data_weight();
        let known: Vec<f64> = (basis.data_curvature.iter().enumerate())
            .map(|(k, d)| data_weight * d + prior[k / 3])
            .collect();
        let least = CURVATURE_FLOOR * known.iter().sum::<f64>() / known.len().max(1) as f64;
        known.into_iter().map(|h| h.max(least)).collect()
    }

    /// Per unknown, the standard deviation a Laplace approximation at the
    /// solution (rendered as `rendered`) gives: the photo's pixels read as
    /// independent Gaussians of the variance the solution's residuals show,
    /// the objective as the negative log posterior on that scale, and of its
    /// Hessian the diagonal ([`Recorder::curvature`]): `sigma_k = sqrt(2 w D
    /// / (n H_k))`, `D` the data term at the solution over its `n` weighted
    /// values, `w` its weight.
    fn posterior_sigma(&self, rendered: &[[f64; 3]]) -> Vec<f64> {
        let data = &self.inputs.data;
        let residual = data.weighted_sq_sum(|p, c| rendered[p][c]) / data.norm();
        let values = data.weight.iter().flatten().filter(|&&w| w > 0.0).count().max(1) as f64;
        let scale = 2.0 * self.data_weight() * residual / values;
        self.curvature()
            .into_iter()
            .map(|h| (scale / h.max(1e-300)).sqrt())
            .collect()
    }

    /// The lighting terms at the map `x` on `tape`: the map's leaf and the
    /// evaluation.
    fn record<'t>(
        &self,
        tape: &'t Tape<f64>,
        x: &[f64],
    ) -> Result<(autodiff::Var<'t, f64>, crate::objective::Evaluation<'t>)> {
        let env = tape.leaf(x);
        let rendered = self.op.render(tape, env);
        let data = &self.inputs.data;
        let image = ImageTerms::new(self.scene.pixels, rendered, &data.target, &self.weight, self.level)?;
        let pose = PoseVars::new(tape, &self.pose, false);
        let map = ImageVars::from_texels(env, self.size.0, self.size.1);
        let camera = &self.scene.photo.camera;
        let evaluation = self.terms.objective.evaluate(&TermContext {
            phase: Phase::Lighting,
            tape,
            pose: &pose,
            camera,
            reference: self.reference,
            soft_mask: None,
            image: Some(image),
            env: Some(&map),
            lighting: Some(&self.inputs),
            front_facing: self.front_facing,
            progress: LIGHTING_PROGRESS,
            seed: self.scene.seed,
        })?;
        Ok((env, evaluation))
    }
}

#[cfg(test)]
mod tests {
    use glam::{Vec2, Vec3};
    use render::camera::Camera;
    use render::image_io::{Mask, RgbImage};

    use super::*;
    use crate::objective::{LatitudePrior, LightSmoothness, RgbL1};

    /// A photo of `w x h` pixels (all the probe's), its pixel `p` reading
    /// its texel and 40 % of the next one's on an 8 x 4 map whose truth
    /// has a bright band; one pixel clipped, every pixel an 8-bit value.
    fn scene() -> (Photo, Arc<Transport>, Arc<DataTerm>, Vec<f64>) {
        let (w, h) = (8, 4);
        let n = w * h;
        let centre = |t: usize| Vec2::new(((t % w) as f32 + 0.5) / w as f32, ((t / w) as f32 + 0.5) / h as f32);
        let uv: Vec<Vec2> = (0..2 * n).map(|k| centre((k / 2 + k % 2) % n)).collect();
        let segment: Vec<u32> = (0..2 * n as u32).map(|k| k / 2).collect();
        let throughput: Vec<[f32; 3]> = (0..2 * n).map(|k| [1.0 - 0.6 * (k % 2) as f32, 0.8, 0.6]).collect();
        let transport = Arc::new(Transport::new(&segment, &uv, &throughput, n, w, h));
        let truth: Vec<f64> = (0..n * 3)
            .map(|i| {
                if (2..4).contains(&(i / 3 % w)) {
                    6.0
                } else {
                    0.5 + 0.1 * (i % 5) as f64
                }
            })
            .collect();
        let mut target = vec![[0.0; 3]; n];
        transport.apply(&truth, &mut target);
        let weight = target.iter().map(|t| t.map(|v| 1.0 / (v + 0.1).powi(2))).collect();
        let mut data = DataTerm::exact(target.clone(), weight);
        data.at_least[10] = true;
        data.tolerance.iter_mut().for_each(|t| *t = [0.004; 3]);
        let pixels = target.iter().map(|t| t.map(|v| v as f32)).collect();
        let camera = Camera::new(w as u32, h as u32, 40.0, Vec3::Z, Vec3::ZERO, Vec3::Y).expect("a camera");
        let photo = Photo::new(RgbImage::new(w, h, pixels), Mask::new(w, h, vec![true; n]), camera).expect("a photo");
        (photo, transport, Arc::new(data), vec![1.0; n * 3])
    }

    /// The tests' solve settings.
    fn settings() -> LightingSolve {
        LightingSolve {
            relative_smoothness: true,
            floor_of_level: 0.02,
            clipped_light_share: 0.5,
            max_iters: 2000,
            method: LightingMethod::LeastSquares,
        }
    }

    fn solve_with(terms: &LightingTerms) -> Vec<f64> {
        let (photo, transport, data, x0) = scene();
        let pixels: Vec<u32> = (0..data.target.len() as u32).collect();
        let settings = settings();
        let scene = TapeScene::new(&photo, &Pose::IDENTITY, &pixels, 5);
        let level = Level {
            transport: &transport,
            data: &data,
            settings,
            start: &x0,
        };
        terms.solve(&level, &scene).expect("a solve").env
    }

    #[test]
    fn the_default_terms_compile_to_the_exact_solve_and_the_tape_finds_the_same_map() {
        let objective = Arc::new(Objective::paper_default());
        let exact = LightingTerms::compile(objective.clone(), LightingMethod::LeastSquares).expect("terms");
        let tape = LightingTerms::compile(objective, LightingMethod::Tape).expect("terms");
        assert!(exact.is_exact() && !tape.is_exact());
        let (a, b) = (solve_with(&exact), solve_with(&tape));
        let scale = a.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        for (k, (x, y)) in a.iter().zip(&b).enumerate() {
            assert!((x - y).abs() < 1e-4 * scale, "unknown {k}: exact {x}, tape {y}");
        }
        // The quadratic instrument too, its weight over the data's.
        let quadratic = |method| LightingTerms::quadratic(0.3, method).expect("terms");
        let (a, b) = (
            solve_with(&quadratic(LightingMethod::LeastSquares)),
            solve_with(&quadratic(LightingMethod::Tape)),
        );
        for (x, y) in a.iter().zip(&b) {
            assert!((x - y).abs() < 1e-4 * scale, "quadratic: exact {x}, tape {y}");
        }
    }

    #[test]
    fn the_posterior_is_tighter_where_the_photo_tells_more() {
        let (photo, transport, data, x0) = scene();
        let pixels: Vec<u32> = (0..data.target.len() as u32).collect();
        let terms = LightingTerms::compile(Arc::new(Objective::paper_default()), LightingMethod::LeastSquares).unwrap();
        let env = solve_with(&terms);
        let level = Level {
            transport: &transport,
            data: &data,
            settings: settings(),
            start: &x0,
        };
        let mut rendered = vec![[0.0; 3]; transport.pixels];
        transport.apply(&env, &mut rendered);
        let scene = TapeScene::new(&photo, &Pose::IDENTITY, &pixels, 5);
        let sigma = terms
            .account(&level, &env, &rendered, &scene)
            .expect("an account")
            .sigma;
        assert_eq!(sigma.len(), env.len());
        assert!(sigma.iter().all(|s| s.is_finite() && *s > 0.0), "{sigma:?}");
        // A texel's deviation falls as its data curvature rises.
        let told = transport.weighted_column_norms(&data.weight);
        let (most, least) = (argmax(&told), argmax(&told.iter().map(|c| -c).collect::<Vec<_>>()));
        assert!(sigma[most] < sigma[least], "{} vs {}", sigma[most], sigma[least]);
    }

    fn argmax(v: &[f64]) -> usize {
        (0..v.len()).max_by(|&a, &b| v[a].total_cmp(&v[b])).expect("values")
    }

    #[test]
    fn the_latitude_prior_compiles_to_the_exact_solve_and_moves_the_map() {
        let objective = Arc::new(Objective::paper_default().term(LatitudePrior.weight(0.3)));
        let exact = LightingTerms::compile(objective.clone(), LightingMethod::LeastSquares).expect("terms");
        let tape = LightingTerms::compile(objective, LightingMethod::Tape).expect("terms");
        assert!(exact.is_exact());
        let (a, b) = (solve_with(&exact), solve_with(&tape));
        let scale = a.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        for (k, (x, y)) in a.iter().zip(&b).enumerate() {
            assert!((x - y).abs() < 1e-4 * scale, "unknown {k}: exact {x}, tape {y}");
        }
        let default = Arc::new(Objective::paper_default());
        let default = solve_with(&LightingTerms::compile(default, LightingMethod::LeastSquares).unwrap());
        let moved = a.iter().zip(&default).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max);
        assert!(moved > 1e-3 * scale, "the map moved {moved}");
    }

    #[test]
    fn a_term_outside_the_exact_form_is_minimised_on_the_tape_and_changes_the_map() {
        let with = |term| Arc::new(Objective::paper_default().term(term));
        let default = Arc::new(Objective::paper_default());
        let default = solve_with(&LightingTerms::compile(default, LightingMethod::LeastSquares).unwrap());
        for objective in [
            with(LightSmoothness::new(10.0).weight(0.5)),
            with(RgbL1::log().weight(0.5).in_phases(crate::objective::Phases::LIGHTING)),
        ] {
            let terms = LightingTerms::compile(objective.clone(), LightingMethod::LeastSquares).expect("terms");
            assert!(!terms.is_exact(), "{objective:?}");
            let map = solve_with(&terms);
            let moved = map.iter().zip(&default).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
            assert!(moved > 1e-3, "{objective:?}: the map moved {moved}");
        }
        // A second smoothness: the exact solve covers one, the tape both.
        let twice = Objective::paper_default().term(NeighbourSmoothness::quadratic().weight(0.1));
        assert!(
            !LightingTerms::compile(Arc::new(twice), LightingMethod::LeastSquares)
                .unwrap()
                .is_exact()
        );
    }

    #[test]
    fn an_objective_without_lighting_terms_is_an_error() {
        let pose_only = Objective::paper_default().without(&["data_least_squares", "neighbour_smoothness"]);
        let e = LightingTerms::compile(Arc::new(pose_only), LightingMethod::LeastSquares)
            .err()
            .expect("an error");
        assert!(e.to_string().contains("no term for the lighting phase"), "{e}");
    }
}
