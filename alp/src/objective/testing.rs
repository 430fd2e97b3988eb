//! Gradients of terms verified, not trusted: a small deterministic scene and
//! a check of a term's pose and env map gradients against central
//! differences in f64 (`autodiff::gradcheck`).
//!
//! ```no_run
//! use alp::objective::testing::{Fixture, check_term};
//! use alp::objective::Chamfer;
//! let fixture = Fixture::new()?;
//! let check = check_term(&Chamfer, &fixture)?;
//! assert!(check.passes(), "{check}");
//! # Ok::<(), alp::Error>(())
//! ```

use autodiff::gradcheck::{GradcheckReport, Input, gradcheck_with};
use autodiff::{Tape, Var};
use glam::{Quat, Vec3};
use render::bsdf::GgxMetal;
use render::camera::Camera;
use render::envmap::EnvMap;
use render::integrator::{LightSampling, PrimaryHits, ProbeScene, ProbeVars, RenderSettings, render_image};
use render::lookup::{ImageVars, image_texels};
use render::pose::Pose;
use render::posed::{PoseVars, PosedMesh, pack_pose};
use render::probe::{ProbeAsset, Texture};
use render::procedural::SodaCan;
use render::silhouette::{ReferenceMask, SilhouettePlan, SilhouetteSettings};

use crate::error::{Error, Result};

use super::{ImageTerms, Phase, Term, TermContext, mask_mean_luminance};
use crate::estimate::pose::hypotheses::front_facing;

/// The largest relative gradient error [`TermCheck::passes`] accepts.
pub const TOLERANCE: f64 = 1e-6;

/// The progress and seed the fixture's context holds (fixed: the check
/// compares evaluations of one function).
const CHECK_PROGRESS: f64 = 0.25;
const CHECK_SEED: u64 = 3;

/// Env map elements compared (evenly spaced over texels and channels); the
/// pose's 8 parameters are all compared.
const ENV_ELEMENTS: usize = 24;

/// The finite-difference step relative to `max(1, |x|)`: the rendered
/// image is stiff in the pose (third derivatives ~1e4 at the scene's
/// scale, see render's integrator tests), so the central difference needs
/// a step below cbrt(eps) to keep its O(h^2) error under 1e-6.
const STEP: f64 = 1e-7;

/// A small deterministic scene with every input a term may read: the can
/// (constant material: texture texels would put kinks into the image) a
/// metre tall, about 45 pixels of a 96x72 image; the photo (target and mask)
/// rendered at a pose about 4 pixels, 3% in scale and 3 degrees away; a
/// 16x8 env map affine in its texel coordinates (bilinear lookups of it
/// have no kinks, so finite differences in direction are exact enough).
///
/// The primary hits and the silhouette plan are made once at the base pose
/// (as an optimiser's iteration does), so nearby poses record the same
/// samples and pairs, and the soft mask is smoothed (sigma = 4 px^2) to be
/// smooth at the finite-difference scale.
pub struct Fixture {
    probe: ProbeAsset,
    camera: Camera,
    pose: Pose,
    env: EnvMap,
    reference: ReferenceMask,
    plan: SilhouettePlan,
    hits: PrimaryHits,
    target: Vec<[f64; 3]>,
    weight: Vec<f64>,
    level: f64,
}

impl Fixture {
    /// Builds the scene (a fraction of a second).
    pub fn new() -> Result<Self> {
        let mut probe = SodaCan {
            segments: 24,
            ..SodaCan::default()
        }
        .build();
        probe.albedo = Texture::constant([0.9, 0.7, 0.5]);
        probe.roughness = Texture::constant([0.3; 3]);
        probe.visibility = Texture::constant([0.8; 3]);
        let camera = Camera::new(
            96,
            72,
            30.0,
            Vec3::new(0.5, 0.8, 3.5),
            Vec3::new(0.0, 0.6, 0.0),
            Vec3::Y,
        )?;
        let pose = Pose::new(
            Quat::from_axis_angle(Vec3::new(0.3, 1.0, 0.2).normalize(), 0.4),
            10.0,
            Vec3::new(0.0, 0.0, 0.2),
        );
        let photo_pose = Pose::new(
            pose.rotation * Quat::from_rotation_z(0.05),
            pose.scale * 0.97,
            pose.translation + Vec3::new(0.1, 0.06, 0.0),
        );
        let (w, h) = (16, 8);
        let env = EnvMap::new(
            w,
            h,
            (0..w * h)
                .map(|i| {
                    let (r, c) = ((i / w) as f32, (i % w) as f32);
                    [
                        1.0 + 0.1 * c + 0.2 * r,
                        2.0 - 0.05 * c + 0.1 * r,
                        0.5 + 0.01 * c + 0.3 * r,
                    ]
                })
                .collect(),
        )?;
        let (photo, mask) = render_image(
            &probe,
            &photo_pose,
            &camera,
            &env,
            &GgxMetal,
            &RenderSettings { spp: 4, seed: 2 },
        );
        let reference = ReferenceMask::new(&mask)?;
        let level = mask_mean_luminance(&photo, &mask)?;
        let posed = probe.mesh.posed(&pose).positions;
        let plan = SilhouettePlan::new(
            &probe.mesh,
            &posed,
            &camera,
            SilhouetteSettings {
                sigma_px2: 4.0,
                band_px: 8.0,
            },
        )?;
        let hits = PrimaryHits::trace(&probe.mesh, &posed, &camera, &RenderSettings { spp: 2, seed: 5 });
        let (target, weight) = hits
            .pixels
            .iter()
            .zip(&hits.coverage)
            .map(|(&p, &c)| {
                let usable = c >= 1.0 && mask.inside[p as usize];
                (photo.pixels[p as usize].map(|v| v as f64), usable as u8 as f64)
            })
            .unzip();
        Ok(Fixture {
            probe,
            camera,
            pose,
            env,
            reference,
            plan,
            hits,
            target,
            weight,
            level,
        })
    }

    /// The pose the derivatives are taken at.
    pub fn pose(&self) -> &Pose {
        &self.pose
    }

    /// The env map the image is rendered with.
    pub fn env(&self) -> &EnvMap {
        &self.env
    }

    /// The camera.
    pub fn camera(&self) -> &Camera {
        &self.camera
    }

    /// The values the derivatives are taken at: the packed pose and the env
    /// map's texel-major RGB (record them as leaves for gradients).
    pub fn parameters(&self) -> [Vec<f64>; 2] {
        [
            pack_pose(&self.pose).to_vec(),
            image_texels::<f64>(&self.env.to_image()),
        ]
    }

    /// Records the scene on `tape` with the packed pose `pose_params` and
    /// the env map's texel-major RGB `env_texels` (leaves or constants) and
    /// runs `f` on the context, which holds every input: the soft mask, the
    /// image, the env map, the given `progress`.
    pub fn with_context<'t, R>(
        &self,
        tape: &'t Tape<f64>,
        pose_params: Var<'t, f64>,
        env_texels: Var<'t, f64>,
        progress: f64,
        f: impl FnOnce(&TermContext<'_, 't>) -> R,
    ) -> Result<R> {
        let pose = PoseVars::from_params(pose_params);
        let probe = ProbeVars::new(tape, &self.probe, false);
        let posed = PosedMesh::new(&probe.mesh, &pose);
        let soft_mask = self.plan.soft_mask(&posed);
        let env = ImageVars::from_texels(env_texels, self.env.width(), self.env.height());
        let rendered = ProbeScene {
            tape,
            hits: &self.hits,
            camera: &self.camera,
            probe: &probe,
            posed: &posed,
            triangles: &self.probe.mesh.triangles,
            bsdf: &GgxMetal,
        }
        .light_samples(&LightSampling::BSDF)
        .radiance(&env);
        let image = ImageTerms::new(&self.hits.pixels, rendered, &self.target, &self.weight, self.level)?;
        Ok(f(&TermContext {
            phase: Phase::Pose,
            tape,
            pose: &pose,
            camera: &self.camera,
            reference: &self.reference,
            soft_mask: Some(&soft_mask),
            image: Some(image),
            env: Some(&env),
            lighting: None,
            front_facing: front_facing(&self.camera),
            progress,
            seed: CHECK_SEED,
        }))
    }

    /// The term's value at `pose_params` and `env_texels`, or NaN where it
    /// fails or does not apply (which the check reports as a mismatch).
    fn term_value<'t>(&self, term: &dyn Term, tape: &'t Tape<f64>, inputs: &[Var<'t, f64>]) -> Var<'t, f64> {
        self.with_context(tape, inputs[0], inputs[1], CHECK_PROGRESS, |ctx| term.evaluate(ctx))
            .and_then(|r| r)
            .ok()
            .flatten()
            .unwrap_or_else(|| tape.scalar(f64::NAN))
    }
}

/// The outcome of [`check_term`]: the pose and the env map gradients
/// against central differences.
#[derive(Clone, Debug)]
pub struct TermCheck {
    /// The term's name.
    pub name: String,
    /// The term's value at the fixture's pose.
    pub value: f64,
    /// The 8 packed pose parameters.
    pub pose: GradcheckReport,
    /// A sample of the env map's texels.
    pub env: GradcheckReport,
}

impl TermCheck {
    /// The worse of the two relative errors.
    pub fn worst_rel_error(&self) -> f64 {
        self.pose.worst_rel_error.max(self.env.worst_rel_error)
    }

    /// Whether both gradients agree with finite differences to [`TOLERANCE`].
    pub fn passes(&self) -> bool {
        self.worst_rel_error() < TOLERANCE
    }
}

impl std::fmt::Display for TermCheck {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "term `{}` (value {:.6e}): pose: {}; env: {}",
            self.name, self.value, self.pose, self.env
        )
    }
}

/// Checks `term`'s gradients in the pose (every parameter) and in the env
/// map (a sample of texels) on `fixture` against central differences.
///
/// Fails when the term fails, does not apply on the fixture (which gives
/// every input) or is not a scalar; the gradients' agreement is the
/// returned check's to judge ([`TermCheck::passes`]).
pub fn check_term(term: &dyn Term, fixture: &Fixture) -> Result<TermCheck> {
    let [pose, env] = fixture.parameters();
    let tape = Tape::new();
    let (p, e) = (tape.constant(&pose), tape.constant(&env));
    let value = fixture
        .with_context(&tape, p, e, CHECK_PROGRESS, |ctx| term.evaluate(ctx))??
        .ok_or_else(|| {
            Error::invalid(
                format!("term `{}`", term.name()),
                "does not apply on the fixture, which records every input",
            )
        })?;
    if value.len() != 1 {
        return Err(Error::invalid(
            format!("term `{}`", term.name()),
            format!("returned {} values; a term is a scalar", value.len()),
        ));
    }
    let check = |inputs: &[Input], per_input: usize| {
        gradcheck_with(inputs, per_input, STEP, |t, v| fixture.term_value(term, t, v))
    };
    Ok(TermCheck {
        name: term.name().to_string(),
        value: tape.item(value),
        pose: check(&[Input::Var(pose.clone()), Input::Const(env.clone())], pose.len()),
        env: check(&[Input::Const(pose), Input::Var(env)], ENV_ELEMENTS),
    })
}
