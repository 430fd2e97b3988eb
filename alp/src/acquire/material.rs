//! The probe's material from the views (PAPER.md, Sec. 3.2): with the scan
//! placed, the albedo (RGB), roughness and soft visibility textures, in the
//! mesh's own `vt` layout, that re-render every view best under the
//! capture's known lighting. The forward model is the estimate's
//! (`render::integrator`: GGX metal, MIS, one bounce off the probe), here
//! differentiated in the textures instead of the light.
//!
//! Adam minimizes a relative L1 between the views and their re-renders over
//! the pixels well inside the probe (a mask's edge mixes in the background),
//! a few views per step with fresh samples each step, plus total-variation
//! priors on albedo and roughness and a pull of the visibility towards 1 (a
//! metal's albedo and its visibility darken a pixel alike; the prior lets
//! the albedo explain what both can). Bounds keep every texel in range.
//! Coarse to fine: each level doubles the texture's size and starts from
//! the last one's textures. Texels no view saw well take their
//! neighbours' values (`fill`) and are marked in the coverage texture.

use std::time::Instant;

use autodiff::{Tape, Var};
use glam::{Vec2, Vec3};
use optim::schedule::Cosine;
use optim::{Adam, ParamGroup, Solver};
use render::bsdf::Bsdf;
use render::image_io::RgbImage;
use render::integrator::{LightSampling, PROBE_BOUNCES, PrimaryHits, ProbeScene, ProbeVars, RenderSettings};
use render::lookup::{ImageVars, TextureVars};
use render::mesh::Mesh;
use render::pose::Pose;
use render::posed::{MeshVars, PoseVars, PosedMesh};
use render::probe::{ProbeAsset, Texture};
use render::sampling::Rng;
use serde::Serialize;

use super::capture::Capture;
use render::colour::luminance;

use super::observation::Placed;
use crate::error::{Error, Result};

/// What the texture solve trades.
#[derive(Clone, Debug, Serialize)]
pub struct MaterialSettings {
    /// Texture sizes solved for, coarse to fine, each twice the last: the
    /// coarse ones settle the broad values in few unknowns.
    pub levels: usize,
    /// Adam steps per level: more converge further, each costs
    /// `views_per_step` renders.
    pub steps: usize,
    /// Views rendered per step (chosen in turn): more give smoother
    /// gradients at proportionally more time.
    pub views_per_step: usize,
    /// Samples per pixel of each render: fewer are faster and noisier.
    pub spp: u32,
    /// Most pixels of a view one step renders (a random share of a view
    /// with more): bounds a step's time on a probe that fills the views,
    /// at more noise per step there.
    pub pixels_per_view: usize,
    /// Adam's step on texel values (albedo, roughness and visibility in
    /// [0, 1]) at the start of each level: larger moves faster, but Adam's
    /// steps on a texel few samples see are near random (each is about
    /// this long whatever the gradient's noise), so the texel wanders.
    pub step: f64,
    /// The share of `step` a cosine anneals it to over each level: lower
    /// ends with less wander, and stops moving earlier.
    pub step_floor: f64,
    /// Weight of the albedo's total variation: higher fills unseen or
    /// noisy texels more smoothly and blurs printed detail.
    pub albedo_smoothness: f64,
    /// Weight of the roughness's total variation.
    pub roughness_smoothness: f64,
    /// Weight of the pull of the visibility towards 1: lower lets the
    /// visibility darken what the albedo could explain.
    pub visibility_prior: f64,
    /// Levels (from the coarsest) at which the roughness is solved for;
    /// finer ones keep it, upsampled: a texel's roughness shows only in how
    /// a reflection blurs, which a few pixels' noise hides (solved at
    /// every level, a label of one roughness came out salt and pepper).
    pub roughness_levels: usize,
    /// The least roughness solved for: GGX at 0 is a mirror, whose Dirac
    /// lobe has no gradient in the roughness.
    pub min_roughness: f64,
    /// A pixel's error is relative to its value plus this share of its
    /// view's mean: dark pixels count without their noise dominating.
    pub relative_floor: f64,
    /// Pixels (samples, in pixel units) a texel needs to count as seen
    /// (coverage 1); fewer are blended with the neighbours' fill.
    pub well_seen: f64,
}

impl Default for MaterialSettings {
    fn default() -> Self {
        MaterialSettings {
            levels: 4,
            steps: 150,
            views_per_step: 2,
            spp: 4,
            pixels_per_view: 8000,
            step: 0.05,
            step_floor: 0.01,
            albedo_smoothness: 0.1,
            roughness_smoothness: 0.25,
            visibility_prior: 1.0,
            roughness_levels: 2,
            min_roughness: 0.02,
            relative_floor: 0.5,
            well_seen: 2.0,
        }
    }
}

/// One stage of a solve, for the report.
#[derive(Clone, Debug, Serialize)]
pub struct StageReport {
    /// "level" (an Adam level); with the least-squares solve, "roughness"
    /// (a placement's search), "turn" (a search at a turn about the scan's
    /// axis), "observation" (the albedo's renders) or "albedo" (one texture
    /// size).
    pub stage: String,
    /// Texture or grid width and height (an observation: its pixels and hits).
    pub size: [usize; 2],
    /// Adam steps, rungs searched, or conjugate-gradient iterations.
    pub iterations: usize,
    /// The data term at the stage's end (an Adam level: its mean over the
    /// last pass through the views; none for an observation).
    pub data_loss: f64,
    /// Whether its answer went on: the placement chosen; a least-squares
    /// albedo level the views resolve (see `albedo::AlbedoFit::definite`).
    pub kept: bool,
    /// Seconds spent.
    pub seconds: f64,
    /// A turn search's turn about the scan's axis from the silhouettes'
    /// (degrees).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub turn_deg: Option<f64>,
}

/// The loss's terms at the end of the solve.
#[derive(Clone, Debug, Default, Serialize)]
pub struct LossTerms {
    /// Relative L1 between views and re-renders (mean over the views).
    pub data: f64,
    pub albedo_smoothness: f64,
    pub roughness_smoothness: f64,
    pub visibility_prior: f64,
}

/// The material solved for.
pub struct MaterialFit {
    pub albedo: RgbImage,
    /// Roughness in every channel.
    pub roughness: RgbImage,
    /// Visibility in every channel.
    pub visibility: RgbImage,
    /// How well the views saw each texel, in [0, 1], in every channel.
    pub coverage: RgbImage,
    pub terms: LossTerms,
    pub stages: Vec<StageReport>,
}

impl MaterialFit {
    /// The probe asset these textures make with `mesh`.
    pub fn asset(&self, name: &str, mesh: &Mesh) -> ProbeAsset {
        ProbeAsset {
            name: name.to_string(),
            mesh: mesh.clone(),
            albedo: Texture {
                image: self.albedo.clone(),
            },
            roughness: Texture {
                image: self.roughness.clone(),
            },
            visibility: Texture {
                image: self.visibility.clone(),
            },
        }
    }
}

/// The parameter vector's layout at one texture size: albedo RGB
/// (texel-major), roughness, visibility.
#[derive(Clone, Copy)]
struct Layout {
    width: usize,
    height: usize,
}

impl Layout {
    fn texels(&self) -> usize {
        self.width * self.height
    }
    fn len(&self) -> usize {
        5 * self.texels()
    }
    fn roughness(&self) -> std::ops::Range<usize> {
        3 * self.texels()..4 * self.texels()
    }
    fn visibility(&self) -> std::ops::Range<usize> {
        4 * self.texels()..5 * self.texels()
    }

    /// The three textures as images.
    fn images(&self, x: &[f64]) -> [RgbImage; 3] {
        let n = self.texels();
        let image = |f: &dyn Fn(usize) -> [f32; 3]| RgbImage::new(self.width, self.height, (0..n).map(f).collect());
        [
            image(&|t| std::array::from_fn(|c| x[3 * t + c] as f32)),
            image(&|t| [x[3 * n + t] as f32; 3]),
            image(&|t| [x[4 * n + t] as f32; 3]),
        ]
    }

    /// The parameters from three textures resampled to this size.
    fn params(&self, textures: &[RgbImage; 3]) -> Vec<f64> {
        let resampled = textures.each_ref().map(|t| resample(t, self.width, self.height));
        let mut x = Vec::with_capacity(self.len());
        x.extend(resampled[0].pixels.iter().flat_map(|p| p.map(|c| c as f64)));
        x.extend(resampled[1].pixels.iter().map(|p| p[0] as f64));
        x.extend(resampled[2].pixels.iter().map(|p| p[0] as f64));
        x
    }
}

/// `image` resampled bilinearly (texel centres aligned) to `width` x `height`.
pub(crate) fn resample(image: &RgbImage, width: usize, height: usize) -> RgbImage {
    let texture = Texture { image: image.clone() };
    let pixels = (0..width * height)
        .map(|p| {
            let (col, row) = ((p % width) as f32, (p / width) as f32);
            texture.lookup(Vec2::new((col + 0.5) / width as f32, 1.0 - (row + 0.5) / height as f32))
        })
        .collect();
    RgbImage::new(width, height, pixels)
}

/// What every step reads: the scan placed, the lighting and its sampler, the views.
struct Problem<'a> {
    placed: Placed<'a>,
    settings: &'a MaterialSettings,
}

impl Problem<'_> {
    /// The hits of view `v` in its fitted pixels, with sample seed `seed`.
    fn hits(&self, v: usize, seed: u64) -> PrimaryHits {
        view_hits(&self.placed, &self.placed.positions, v, self.settings.spp, seed)
    }

    /// The data term of view `v` at textures `x` (texel values), recorded
    /// on `tape` (cleared first), its gradient added into `g` (see
    /// [`paired_error`]).
    fn data_term(&self, tape: &Tape<f32>, layout: Layout, x: &[f32], v: usize, seed: u64, g: &mut [f64]) -> f64 {
        let s = self.settings;
        let pair = hit_pair(&self.placed, &self.placed.positions, v, s.spp, s.pixels_per_view, seed);
        if pair[0].is_empty() {
            return 0.0;
        }
        tape.clear();
        let params = tape.leaf(x);
        let scene = self.scene(tape, layout, params);
        let (surrogate, value) = paired_error(tape, &self.placed, &scene, v, &pair, s.relative_floor);
        tape.backward(surrogate);
        for (gi, d) in g.iter_mut().zip(tape.grad(params).iter()) {
            *gi += *d as f64;
        }
        value
    }

    /// The probe with the textures `params`, posed, and the lighting, on
    /// `tape`: what every render of a step reads (recorded once a step, not
    /// once a render: the lighting alone is its whole map).
    fn scene<'t>(&self, tape: &'t Tape<f32>, layout: Layout, params: Var<'t, f32>) -> Scene<'t> {
        let n = layout.texels();
        let image =
            |texels: Var<'t, f32>| TextureVars::Image(ImageVars::from_texels(texels, layout.width, layout.height));
        // A scalar texture as the RGB texels a lookup reads (each value thrice).
        let triple = tape.constant(&(0..3 * n).map(|i| (i / 3) as f32).collect::<Vec<f32>>());
        let scalar = |range: std::ops::Range<usize>| image(params.slice(range.start, n).gather(triple));
        let probe = ProbeVars {
            mesh: MeshVars::new(tape, self.placed.mesh),
            albedo: image(params.slice(0, 3 * n)),
            roughness: scalar(layout.roughness()),
            visibility: scalar(layout.visibility()),
        };
        let posed = PosedMesh::new(&probe.mesh, &PoseVars::new(tape, &self.placed.to_world, false));
        Scene {
            probe,
            posed,
            env: ImageVars::env(tape, self.placed.env, false),
        }
    }

    /// The priors at textures `x`: the albedo's and the roughness's total
    /// variation over the texel pairs `pairs` and the visibility's pull
    /// towards 1 (unweighted), their weighted sum's gradient added into `g`.
    fn priors(&self, layout: Layout, pairs: &TexelPairs, x: &[f64], g: &mut [f64]) -> [f64; 3] {
        let tape = Tape::<f64>::new();
        let params = tape.leaf(x);
        let variation = |[a, b]: &[Vec<f64>; 2]| {
            if a.is_empty() {
                return tape.constant(&[0.0]);
            }
            (params.gather(tape.constant(a)) - params.gather(tape.constant(b)))
                .abs()
                .mean()
        };
        let albedo = variation(&pairs.albedo);
        let roughness = variation(&pairs.roughness);
        let visibility = params
            .slice(layout.visibility().start, layout.texels())
            .rsub(1.0)
            .mean();
        let s = self.settings;
        let total = albedo * s.albedo_smoothness + roughness * s.roughness_smoothness + visibility * s.visibility_prior;
        tape.backward(total);
        for (gi, d) in g.iter_mut().zip(tape.grad(params).iter()) {
            *gi += d;
        }
        [tape.item(albedo), tape.item(roughness), tape.item(visibility)]
    }
}

/// A step's probe and lighting on its tape.
pub(crate) struct Scene<'t> {
    pub(crate) probe: ProbeVars<'t, f32>,
    pub(crate) posed: PosedMesh<'t, f32>,
    pub(crate) env: ImageVars<'t, f32>,
}

/// The hits of view `v` of `placed` in its fitted pixels, the scan's
/// vertices at `positions`, `spp` samples a pixel seeded by `seed`.
pub(crate) fn view_hits(placed: &Placed, positions: &[Vec3], v: usize, spp: u32, seed: u64) -> PrimaryHits {
    let view = &placed.views[v];
    let settings = RenderSettings { spp, seed };
    let mut hits = PrimaryHits::trace(placed.mesh, positions, view.camera, &settings);
    hits.retain_pixels(|p| view.slot[p as usize].is_some());
    hits
}

/// Two independent sets of hits (seeds from `seed`) of view `v` over the
/// same fitted pixels: all of them, or when there are more than
/// `pixels_per_view`, a random share of that many (drawn afresh with each
/// seed, so the mean over them stays the view's mean on average).
pub(crate) fn hit_pair(
    placed: &Placed,
    positions: &[Vec3],
    v: usize,
    spp: u32,
    pixels_per_view: usize,
    seed: u64,
) -> [PrimaryHits; 2] {
    let [mut a, mut b] = [seed, seed ^ SECOND_RENDER].map(|s| view_hits(placed, positions, v, spp, s));
    let size = a.width * a.height;
    let mut both = vec![0u8; size];
    for (hits, bit) in [(&a, 1u8), (&b, 2u8)] {
        for &p in &hits.pixels {
            both[p as usize] |= bit;
        }
    }
    let share = pixels_per_view as f32 / placed.views[v].target.len().max(1) as f32;
    let kept = |p: u32| {
        both[p as usize] == 3 && (share >= 1.0 || Rng::new(seed, PIXEL_SHARE_STREAM + p as u64).next_f32() < share)
    };
    a.retain_pixels(kept);
    b.retain_pixels(kept);
    [a, b]
}

/// View `v`'s re-render of `scene` in the pixels of `hits`.
pub(crate) fn render<'t>(
    tape: &'t Tape<f32>,
    placed: &Placed,
    scene: &Scene<'t>,
    v: usize,
    hits: &PrimaryHits,
) -> [Var<'t, f32>; 3] {
    let Scene { probe, posed, env } = scene;
    ProbeScene {
        tape,
        hits,
        camera: placed.views[v].camera,
        probe,
        posed,
        triangles: &placed.mesh.triangles,
        bsdf: placed.bsdf,
    }
    .light_samples(&LightSampling::mis(&placed.sampler).with_bounces(PROBE_BOUNCES))
    .radiance(env)
}

/// The data term of view `v`: the relative squared error of `scene`'s
/// re-render, a pixel's error relative to its photo's luminance plus
/// `relative_floor` times the view's mean. Returns the surrogate to
/// differentiate and the term's value. The gradient is made unbiased
/// under the renders' noise by the two independent renders `a` and `b` of
/// `pair`: `(b - t) da + (a - t) db` (a single render's squared error
/// would also minimize its variance, and an L1 its noise's median: both
/// darken what a light seen by few samples brightens).
pub(crate) fn paired_error<'t>(
    tape: &'t Tape<f32>,
    placed: &Placed,
    scene: &Scene<'t>,
    v: usize,
    pair: &[PrimaryHits; 2],
    relative_floor: f64,
) -> (Var<'t, f32>, f64) {
    let [a, b] = pair;
    let view = &placed.views[v];
    let target: Vec<[f32; 3]> = a
        .pixels
        .iter()
        .map(|&p| view.target[view.slot[p as usize].expect("kept pixels are fitted") as usize])
        .collect();
    let floor = (relative_floor * view.mean_luminance()) as f32;
    let weight: Vec<f32> = target
        .iter()
        .map(|t| (luminance(*t).max(0.0) + floor).max(1e-12).powi(-2))
        .collect();
    let weight = tape.constant(&weight);
    let rgb_a = render(tape, placed, scene, v, a);
    let rgb_b = render(tape, placed, scene, v, b);
    let mut surrogate = tape.constant(&[0.0]);
    let mut value = 0.0;
    let pixels = 3.0 * target.len() as f32;
    for c in 0..3 {
        let t = tape.constant(&target.iter().map(|t| t[c]).collect::<Vec<f32>>());
        let (da, db) = (rgb_a[c] - t, rgb_b[c] - t);
        let cross = da * db.stop_gradient() + da.stop_gradient() * db;
        surrogate = surrogate + (cross * weight).sum() * (1.0 / pixels);
        // Its value, (a - t)(b - t), is the squared error's unbiased
        // estimate: the noise's variance, which a's own square would
        // add, depends on the textures and would favour the smoother.
        value += tape.item((da * db * weight).sum()) / pixels;
    }
    (surrogate, value as f64)
}

/// The neighbouring texels (right and below) of a level's textures, as
/// indices into its parameters: each prior's two sides.
struct TexelPairs {
    albedo: [Vec<f64>; 2],
    roughness: [Vec<f64>; 2],
}

impl TexelPairs {
    fn new(layout: Layout) -> Self {
        let (n, w) = (layout.texels(), layout.width);
        let pairs: Vec<(usize, usize)> = (0..n)
            .flat_map(|t| {
                let right = (t % w + 1 < w).then_some((t, t + 1));
                let below = (t + w < n).then_some((t, t + w));
                right.into_iter().chain(below)
            })
            .collect();
        // The values at `offset + stride * texel + channel` of each side.
        let sides = |offset: usize, stride: usize| {
            let side = |pick: fn(&(usize, usize)) -> usize| {
                (0..stride)
                    .flat_map(|c| pairs.iter().map(move |pair| (offset + stride * pick(pair) + c) as f64))
                    .collect()
            };
            [side(|p| p.0), side(|p| p.1)]
        };
        TexelPairs {
            albedo: sides(0, 3),
            roughness: sides(layout.roughness().start, 1),
        }
    }
}

/// The texture sizes of `levels` levels up to `size` (width, height),
/// coarse to fine, each half the next (no side below 4 texels, or the
/// size's own); an error for an empty size or no placements.
pub(crate) fn level_sizes(size: [usize; 2], placements: usize, levels: usize) -> Result<Vec<[usize; 2]>> {
    let [width, height] = size;
    if width == 0 || height == 0 {
        return Err(Error::invalid(
            "texture size",
            format!("{width}x{height}: both sides must be at least 1"),
        ));
    }
    if placements == 0 {
        return Err(Error::invalid("placements", "none to solve the textures at"));
    }
    let halvings = (0..levels.max(1))
        .take_while(|&k| (width >> k) >= 4.min(width) && (height >> k) >= 4.min(height))
        .count();
    Ok((0..halvings)
        .rev()
        .map(|k| [(width >> k).max(1), (height >> k).max(1)])
        .collect())
}

/// Solves for the material of the capture's scan at texture size `size`
/// (width, height), placed at the first of `placements` whose coarsest
/// level fits the views best (a scan's two ends can cast the same
/// outline); `progress` hears (steps done, steps in all). Returns the fit
/// and the index of the placement kept.
pub fn solve(
    capture: &Capture,
    placements: &[Pose],
    size: [usize; 2],
    bsdf: &dyn Bsdf<f32>,
    settings: &MaterialSettings,
    progress: &dyn Fn(usize, usize),
) -> Result<(MaterialFit, usize)> {
    let sizes = level_sizes(size, placements.len(), settings.levels)?;
    let layouts: Vec<Layout> = sizes.iter().map(|&[width, height]| Layout { width, height }).collect();
    let problems: Vec<Problem> = placements
        .iter()
        .map(|p| Problem::new(capture, p, bsdf, settings))
        .collect();
    let total_steps = (layouts.len() + placements.len() - 1) * settings.steps;
    let initial = [
        RgbImage::filled(1, 1, [INITIAL_ALBEDO; 3]),
        RgbImage::filled(1, 1, [INITIAL_ROUGHNESS; 3]),
        RgbImage::filled(1, 1, [1.0; 3]),
    ];
    let tape = Tape::<f32>::new();
    // The coarsest level at every placement; the best goes on.
    let mut coarse = Vec::with_capacity(problems.len());
    for (k, problem) in problems.iter().enumerate() {
        let done = k * settings.steps;
        coarse.push(problem.fit_level(&tape, layouts[0], &initial, 0, &|step| {
            progress(done + step, total_steps)
        })?);
    }
    let chosen = (0..coarse.len())
        .min_by(|&a, &b| coarse[a].1.data_loss.total_cmp(&coarse[b].1.data_loss))
        .expect("at least one placement");
    let problem = &problems[chosen];
    let (mut textures, first, mut terms) = coarse.swap_remove(chosen);
    let mut stages = vec![first];
    for (level, &layout) in layouts.iter().enumerate().skip(1) {
        let done = (placements.len() + level - 1) * settings.steps;
        let (fitted, report, level_terms) = problem.fit_level(&tape, layout, &textures, level, &|step| {
            progress(done + step, total_steps)
        })?;
        textures = fitted;
        terms = level_terms;
        stages.push(report);
    }
    let layout = *layouts.last().expect("at least one level");
    let coverage = coverage(problem, layout);
    let [albedo, roughness, visibility] = textures.map(|t| fill(&t, &coverage));
    let fit = MaterialFit {
        albedo,
        roughness,
        visibility,
        coverage: RgbImage::new(layout.width, layout.height, coverage.iter().map(|&c| [c; 3]).collect()),
        terms,
        stages,
    };
    Ok((fit, chosen))
}

impl<'a> Problem<'a> {
    fn new(capture: &'a Capture, to_world: &Pose, bsdf: &'a dyn Bsdf<f32>, settings: &'a MaterialSettings) -> Self {
        Problem {
            placed: Placed::new(capture, to_world, bsdf),
            settings,
        }
    }

    /// One level: Adam from `textures` resampled to `layout`, returning the
    /// textures (the mean of the iterates over the level's second half:
    /// each step's few noisy views move a texel at random about its
    /// optimum, and the mean stays at it), the level's report and its
    /// terms; `progress` hears the steps done.
    fn fit_level(
        &self,
        tape: &Tape<f32>,
        layout: Layout,
        textures: &[RgbImage; 3],
        level: usize,
        progress: &dyn Fn(usize),
    ) -> Result<([RgbImage; 3], StageReport, LossTerms)> {
        let t0 = Instant::now();
        let settings = self.settings;
        let n = layout.texels();
        let steps = settings.steps.max(1);
        let anneal = Cosine::new(steps, settings.step_floor).map_err(Error::solver("texture solve"))?;
        let group = |range: std::ops::Range<usize>, lower: f64, step: f64| {
            ParamGroup::new(range, step).bounds(lower, 1.0).schedule(anneal)
        };
        let roughness_step = if level < settings.roughness_levels {
            settings.step
        } else {
            0.0
        };
        let mut adam = Adam::builder(layout.len())
            .group(group(0..3 * n, 0.0, settings.step))
            .group(group(layout.roughness(), settings.min_roughness, roughness_step))
            .group(group(layout.visibility(), 0.0, settings.step))
            .max_iters(steps)
            .build()
            .map_err(Error::solver("texture solve"))?;
        let views = self.placed.views.len();
        let per_step = settings.views_per_step.clamp(1, views);
        let (mut evaluation, mut data_history, mut priors) = (0usize, Vec::with_capacity(steps + 1), [0.0; 3]);
        let (mut mean_x, mut averaged) = (vec![0.0; layout.len()], 0usize);
        let pairs = TexelPairs::new(layout);
        let mut objective = |x: &[f64], g: &mut [f64]| -> f64 {
            let x32: Vec<f32> = x.iter().map(|&v| v as f32).collect();
            let mut view_grad = vec![0.0; g.len()];
            let mut data = 0.0;
            for j in 0..per_step {
                let draw = evaluation * per_step + j;
                let seed = ((level as u64) << 40) | draw as u64;
                data += self.data_term(tape, layout, &x32, draw % views, seed, &mut view_grad);
            }
            for (gi, d) in g.iter_mut().zip(&view_grad) {
                *gi = d / per_step as f64;
            }
            let data = data / per_step as f64;
            priors = self.priors(layout, &pairs, x, g);
            data_history.push(data);
            if 2 * evaluation >= steps {
                mean_x.iter_mut().zip(x).for_each(|(m, &v)| *m += v);
                averaged += 1;
            }
            evaluation += 1;
            progress(evaluation.min(steps));
            data + settings.albedo_smoothness * priors[0]
                + settings.roughness_smoothness * priors[1]
                + settings.visibility_prior * priors[2]
        };
        let state = adam
            .minimize(&mut objective, layout.params(textures))
            .map_err(Error::solver("texture solve"))?;
        let x = if averaged > 0 {
            mean_x.iter().map(|m| m / averaged as f64).collect()
        } else {
            state.x
        };
        // The data term over the last pass through every view.
        let tail = views.div_ceil(per_step).min(data_history.len()).max(1);
        let data_loss = data_history.iter().rev().take(tail).sum::<f64>() / tail as f64;
        let report = StageReport {
            stage: "level".into(),
            size: [layout.width, layout.height],
            iterations: state.iter,
            data_loss,
            kept: true,
            seconds: t0.elapsed().as_secs_f64(),
            turn_deg: None,
        };
        let terms = LossTerms {
            data: data_loss,
            albedo_smoothness: priors[0],
            roughness_smoothness: priors[1],
            visibility_prior: priors[2],
        };
        Ok((layout.images(&x), report, terms))
    }
}

/// The albedo and roughness the solve starts from: a bright, fairly rough metal.
const INITIAL_ALBEDO: f32 = 0.7;
const INITIAL_ROUGHNESS: f32 = 0.3;

/// How well the views saw each texel of `layout`, in [0, 1]: the pixels
/// (each sample weighs 1 / spp) whose surface point lands on it, splatted
/// bilinearly, each weighed by how far its photo stands above the noise
/// floor of the data term, `lum / (lum + relative_floor x the view's mean)`
/// (a surface that reflects only darkness, a can's lid under a dark
/// ceiling, tells little of its albedo however many pixels see it), over
/// `MaterialSettings::well_seen`.
fn coverage(problem: &Problem, layout: Layout) -> Vec<f32> {
    let mut seen = vec![0.0f64; layout.texels()];
    let texture = |uv: Vec2| {
        let x = (uv.x * layout.width as f32 - 0.5).clamp(0.0, (layout.width - 1) as f32);
        let y = ((1.0 - uv.y) * layout.height as f32 - 0.5).clamp(0.0, (layout.height - 1) as f32);
        (x, y)
    };
    for (v, view) in problem.placed.views.iter().enumerate() {
        let hits = problem.hits(v, COVERAGE_SEED);
        let floor = problem.settings.relative_floor * view.mean_luminance();
        for (k, &triangle) in hits.triangle.iter().enumerate() {
            let pixel = hits.pixels[hits.segment[k] as usize] as usize;
            let target = luminance(view.target[view.slot[pixel].expect("kept pixels are fitted") as usize]) as f64;
            let signal = target.max(0.0) / (target.max(0.0) + floor).max(f64::MIN_POSITIVE);
            let uv = hit_uv(problem.placed.mesh, &problem.placed.positions, triangle, hits.point[k]);
            let (x, y) = texture(uv);
            let (col0, row0) = (x.floor() as usize, y.floor() as usize);
            let (fx, fy) = ((x - col0 as f32) as f64, (y - row0 as f32) as f64);
            let (col1, row1) = ((col0 + 1).min(layout.width - 1), (row0 + 1).min(layout.height - 1));
            let share = signal / hits.samples[hits.segment[k] as usize] as f64;
            for (row, wy) in [(row0, 1.0 - fy), (row1, fy)] {
                for (col, wx) in [(col0, 1.0 - fx), (col1, fx)] {
                    seen[row * layout.width + col] += share * wx * wy;
                }
            }
        }
    }
    let well_seen = problem.settings.well_seen.max(f64::MIN_POSITIVE);
    seen.iter().map(|&s| (s / well_seen).min(1.0) as f32).collect()
}

/// The random stream (plus the pixel's index) of a step's share of a view's pixels.
const PIXEL_SHARE_STREAM: u64 = 0x5A4E_0000_0000;

/// Flips the seed of a data term's second render.
const SECOND_RENDER: u64 = 1 << 63;

/// The seed of the samples that measure the coverage.
const COVERAGE_SEED: u64 = 0xC0FE;

/// The texture coordinates of `point` on triangle `triangle` of `mesh` posed at `positions`.
pub(crate) fn hit_uv(mesh: &Mesh, positions: &[Vec3], triangle: u32, point: Vec3) -> Vec2 {
    let corners = mesh.triangles[triangle as usize];
    let [a, b, c] = corners.map(|i| positions[i as usize]);
    corners
        .iter()
        .zip(barycentric(point, a, b, c))
        .map(|(&i, w)| mesh.uvs[i as usize] * w)
        .sum()
}

/// The barycentric weights of point `p` (on the triangle's plane) in triangle `a, b, c`.
fn barycentric(p: Vec3, a: Vec3, b: Vec3, c: Vec3) -> [f32; 3] {
    let (e1, e2, d) = (b - a, c - a, p - a);
    let (d11, d12, d22) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
    let (d1, d2) = (d.dot(e1), d.dot(e2));
    let det = d11 * d22 - d12 * d12;
    if det.abs() < f32::MIN_POSITIVE {
        return [1.0, 0.0, 0.0];
    }
    let w1 = (d22 * d1 - d12 * d2) / det;
    let w2 = (d11 * d2 - d12 * d1) / det;
    [1.0 - w1 - w2, w1, w2]
}

/// `image` with each texel blended towards its neighbourhood's values by
/// how little it was seen (`weight` in [0, 1]): the push-pull fill
/// (Gortler et al. 1996). Each coarser level holds 2x2 blocks'
/// weight-averaged values; going back up, a texel keeps its own value where
/// its weight is 1, takes the coarser level's where it is 0, and blends
/// between, so a hole takes the nearest seen values.
pub(crate) fn fill(image: &RgbImage, weight: &[f32]) -> RgbImage {
    let (w, h) = (image.width, image.height);
    if w <= 1 && h <= 1 {
        return image.clone();
    }
    let (cw, ch) = (w.div_ceil(2), h.div_ceil(2));
    let mut sums = vec![[0.0f32; 3]; cw * ch];
    let mut weights = vec![0.0f32; cw * ch];
    for (p, (&c, texel)) in weight.iter().zip(&image.pixels).enumerate() {
        let q = (p / w / 2) * cw + (p % w) / 2;
        weights[q] += c;
        sums[q].iter_mut().zip(texel).for_each(|(s, &v)| *s += c * v);
    }
    let coarse_image = RgbImage::new(
        cw,
        ch,
        sums.iter()
            .zip(&weights)
            .map(|(s, &c)| if c > 0.0 { s.map(|v| v / c) } else { [0.0; 3] })
            .collect(),
    );
    let coarse_weight: Vec<f32> = weights.iter().map(|&c| c.min(1.0)).collect();
    let coarse = fill(&coarse_image, &coarse_weight);
    let up = resample(&coarse, w, h);
    let pixels = (0..w * h)
        .map(|p| {
            let c = weight[p].min(1.0);
            std::array::from_fn(|k| c * image.pixels[p][k] + (1.0 - c) * up.pixels[p][k])
        })
        .collect();
    RgbImage::new(w, h, pixels)
}
