//! `alp study`: the estimate measured as a product, on any set of scene
//! folders. Each study runs the estimate on every scene under a list of
//! settings ([`Variant`]s), scores each run as `alp eval` does (the three
//! relit spheres' angular errors, the pose's errors) and times it, keeps the
//! rows in `results.jsonl` as they finish (a rerun skips them), and writes
//! `results.csv`, a summary per setting (`summary.csv`, `summary.md`), each
//! setting paired scene by scene against the reference ([`paired`]:
//! `paired.csv`, `paired.md`) and an SVG chart.
//!
//! - [`speed_accuracy`]: the knobs that trade time for accuracy.
//! - [`stability`]: what breaks methods ([`perturb`]), at graded strengths,
//!   and the paper's ablations.

pub mod chart;
pub mod cli;
pub mod inputs;
pub mod paired;
pub mod perturb;
pub mod record;
pub mod scenes;
pub mod speed_accuracy;
pub mod stability;
pub mod summary;

use std::path::{Path, PathBuf};
use std::time::Instant;

use render::RenderError;
use render::envmap::EnvMap;
use render::pose::Pose;

use crate::error::{Error, Result};
use crate::estimate::report::{peak_resident_mb, reset_peak_resident};
use crate::estimate::{Photo, Settings, estimate};
use crate::eval::{compare_spheres, pose_errors};
use crate::relight::{RelightSettings, RelitSpheres, evaluation_region, relight};

use record::{Results, Row};
use scenes::StudyScene;

/// One setting a study runs on every scene.
pub struct Variant {
    /// Its knob family, or the perturbation (`default` for the default setting).
    pub family: String,
    /// `knob=value`: the setting in words, and the key a rerun skips by.
    pub id: String,
    /// Worker threads.
    pub threads: usize,
    /// What runs.
    pub method: Method,
    /// What is done to the photo first, and how hard (none: the photo as it is).
    pub perturbation: Option<Perturbation>,
}

/// Changes a photo before the estimate sees it.
pub type Perturb = Box<dyn Fn(&Photo) -> Result<Photo> + Send + Sync>;

/// A perturbation of the photo at one strength.
pub struct Perturbation {
    /// Its graded level, 1 the mildest (0 is the photo as it is).
    pub level: usize,
    /// Its strength in its own unit (pixels, a share, a factor).
    pub strength: f64,
    /// The change.
    pub apply: Perturb,
}

/// Changes the default settings into a variant's, given the scene's true pose.
pub type Apply = Box<dyn Fn(&mut Settings, &Pose) + Send + Sync>;

/// What a variant runs.
pub enum Method {
    /// Our estimate, under the default settings as this changes them
    /// (given the scene's true pose).
    Estimate(Apply),
    /// An outside method: Mitsuba 3's differentiable path tracer fitting
    /// the map by this many Adam iterations at the true pose
    /// (`tools/mitsuba_lighting.py`, run by [`RunContext::mitsuba_python`]).
    MitsubaAdam {
        /// Adam iterations.
        iters: usize,
    },
}

/// The id of the default setting.
pub const DEFAULT: &str = "default";

impl Variant {
    /// Our estimate under settings that `apply` changes from the default.
    pub fn estimate(
        family: &str,
        id: String,
        threads: usize,
        apply: impl Fn(&mut Settings, &Pose) + Send + Sync + 'static,
    ) -> Self {
        Variant {
            family: family.into(),
            id,
            threads,
            method: Method::Estimate(Box::new(apply)),
            perturbation: None,
        }
    }

    /// The default settings at `threads`.
    pub fn default_setting(threads: usize) -> Self {
        Self::estimate(DEFAULT, DEFAULT.into(), threads, |_, _| {})
    }
}

/// What every run of a study shares.
pub struct RunContext {
    /// The relit spheres' Monte Carlo settings.
    pub eval: RelightSettings,
    /// A Python that imports Mitsuba 3, for the outside method (none: its
    /// variants are left out).
    pub mitsuba_python: Option<PathBuf>,
}

/// `tools/mitsuba_lighting.py` of this source tree.
pub fn mitsuba_script() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../tools/mitsuba_lighting.py")
}

/// Whether `python` runs the Mitsuba tool (it imports Mitsuba 3 and its
/// variant): Ok, or why not.
pub fn mitsuba_available(python: &Path) -> std::result::Result<(), String> {
    let script = mitsuba_script();
    if !script.is_file() {
        return Err(format!("{} is missing", script.display()));
    }
    let output = std::process::Command::new(python)
        .arg(&script)
        .arg("--check")
        .env("PYTHONDONTWRITEBYTECODE", "1")
        .output()
        .map_err(|e| format!("{} does not run: {e}", python.display()))?;
    match output.status.success() {
        true => Ok(()),
        false => Err(String::from_utf8_lossy(&output.stderr)
            .lines()
            .last()
            .unwrap_or("")
            .to_string()),
    }
}

/// Runs every scene under every variant that `out/results.jsonl` does not
/// hold yet, appending each run's row as it finishes; `progress(done,
/// total)` follows the runs. Every scene is read (and checked) before the
/// first run. A run whose estimate fails is a row with its error.
pub fn run(
    scene_dirs: &[PathBuf],
    variants: &[Variant],
    out: &Path,
    context: &RunContext,
    progress: &mut dyn FnMut(usize, usize, &str),
) -> Result<Results> {
    for dir in scene_dirs {
        StudyScene::read(dir)?;
    }
    let mut results = Results::open(out, record::this_build())?;
    if results.other_builds > 0 {
        eprintln!(
            "alp study: {} rows of {} were run by another build of alp: their runs are done again",
            results.other_builds,
            out.join("results.jsonl").display()
        );
    }
    let total = scene_dirs.len() * variants.len();
    let mut done = 0;
    for dir in scene_dirs {
        let name = scene_name(dir);
        let todo: Vec<&Variant> = variants.iter().filter(|v| !results.has(&name, &v.id)).collect();
        done += variants.len() - todo.len();
        if todo.is_empty() {
            continue;
        }
        let scene = StudyScene::read(dir)?;
        let truth = scene.truth_spheres(&context.eval)?;
        for variant in todo {
            progress(done, total, &format!("{} {}", scene.name, variant.id));
            let row = run_one(&scene, &truth, variant, context)?;
            results.push(row)?;
            done += 1;
        }
    }
    progress(done, total, "");
    Ok(of_scenes(results, scene_dirs))
}

/// The rows `out/results.jsonl` holds (the newest build's) on `scene_dirs`,
/// running nothing: a study's tables while it runs, or redrawn after.
pub fn collect(scene_dirs: &[PathBuf], out: &Path) -> Result<Results> {
    let results = Results::read_newest(out)?;
    if results.other_builds > 0 {
        eprintln!(
            "alp study: {} rows of {} left out: another build of alp ran them",
            results.other_builds,
            out.join("results.jsonl").display()
        );
    }
    Ok(of_scenes(results, scene_dirs))
}

/// `results` on the scenes asked for only.
fn of_scenes(mut results: Results, scene_dirs: &[PathBuf]) -> Results {
    let names = scene_names(scene_dirs);
    results.rows.retain(|r| names.contains(&r.scene));
    results
}

/// A scene's name: its folder's.
fn scene_name(dir: &Path) -> String {
    dir.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default()
}

/// The scenes' names.
pub fn scene_names(scene_dirs: &[PathBuf]) -> Vec<String> {
    scene_dirs.iter().map(|d| scene_name(d)).collect()
}

/// What a run found: the map, the pose when it searched for one, and what
/// it warned of.
struct Found {
    env: EnvMap,
    pose: Option<Pose>,
    warning: Option<String>,
}

/// One run: the method timed, its peak memory, its scores. A panic is
/// caught and recorded as the run's error; a perturbation the scene cannot
/// take is a skipped row.
fn run_one(scene: &StudyScene, truth: &RelitSpheres, variant: &Variant, context: &RunContext) -> Result<Row> {
    let mut row = Row {
        level: variant.perturbation.as_ref().map(|p| p.level),
        strength: variant.perturbation.as_ref().map(|p| p.strength),
        probe: scene.probe_family.clone(),
        ..Row::unscored(&scene.name, &variant.family, &variant.id, variant.threads)
    };
    let perturbed;
    let photo = match &variant.perturbation {
        Some(p) => match (p.apply)(&scene.photo) {
            Ok(photo) => {
                perturbed = photo;
                &perturbed
            }
            Err(e) => {
                row.skipped = Some(e.to_string());
                return Ok(row);
            }
        },
        None => &scene.photo,
    };
    let pool = crate::cli::thread_pool(Some(variant.threads))?;
    reset_peak_resident();
    let started = Instant::now();
    let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| match &variant.method {
        Method::Estimate(apply) => {
            let mut settings = Settings::default();
            apply(&mut settings, &scene.pose);
            pool.install(|| estimate(photo, &scene.probe, &settings))
                .map(|e| Found {
                    warning: (e.report.mask_on_border_pixels > 0)
                        .then(|| format!("{} mask pixels on the image's border", e.report.mask_on_border_pixels)),
                    env: e.env,
                    pose: settings.known_pose.is_none().then_some(e.pose),
                })
        }
        Method::MitsubaAdam { iters } => mitsuba_adam(scene, *iters, context),
    }));
    row.wall_s = started.elapsed().as_secs_f64();
    row.peak_mb = match variant.method {
        Method::Estimate(_) => peak_resident_mb(),
        Method::MitsubaAdam { .. } => None,
    };
    let result = match result {
        Ok(result) => result,
        Err(panic) => {
            let what = panic
                .downcast_ref::<String>()
                .cloned()
                .or_else(|| panic.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_default();
            row.error = Some(format!("panicked: {what}"));
            return Ok(row);
        }
    };
    match result {
        Ok(found) => {
            row.warning = found.warning;
            row.non_finite = found.env.radiance().iter().flatten().any(|v| !v.is_finite())
                || found.pose.is_some_and(|p| !p.to_world().is_finite());
            let relit = pool.install(|| relight(&found.env, &scene.photo.camera, &context.eval))?;
            let [m, s, d] = compare_spheres(&relit, truth, &evaluation_region());
            row.mirror_deg = Some(m.angular_deg);
            row.shiny_deg = Some(s.angular_deg);
            row.diffuse_deg = Some(d.angular_deg);
            row.mirror_si_rmse = Some(m.si_rmse);
            row.shiny_si_rmse = Some(s.si_rmse);
            row.diffuse_si_rmse = Some(d.si_rmse);
            if let Some(pose) = found.pose {
                let errors = pose_errors(&pose, &scene.pose);
                row.rotation_deg = Some(errors.rotation_deg);
                row.axis_deg = Some(errors.axis_deg);
                row.translation_mm = Some(errors.translation_mm);
                row.pose_found = Some(scene.observable.found(&errors, scene.diameter_mm));
            }
        }
        Err(e) => row.error = Some(e.to_string()),
    }
    Ok(row)
}

/// The outside method on `scene`: `tools/mitsuba_lighting.py`'s map, read
/// back; its failure (the tool's last line of errors) is the run's error.
fn mitsuba_adam(scene: &StudyScene, iters: usize, context: &RunContext) -> Result<Found> {
    let python = context
        .mitsuba_python
        .as_ref()
        .ok_or_else(|| Error::invalid("--mitsuba-python", "Mitsuba 3 is not available"))?;
    let dir = std::env::temp_dir().join(format!("alp-study-mitsuba-{}", std::process::id()));
    std::fs::create_dir_all(&dir).map_err(|e| RenderError::io(&dir, "create folder", e))?;
    let env_path = dir.join("env.exr");
    let alp = std::env::current_exe().map_err(|e| RenderError::io("alp", "find the running binary", e))?;
    let output = std::process::Command::new(python)
        .arg(mitsuba_script())
        .arg("--scene")
        .arg(&scene.dir)
        .arg("--out")
        .arg(&env_path)
        .arg("--alp")
        .arg(alp)
        .arg("--iters")
        .arg(iters.to_string())
        .env("PYTHONDONTWRITEBYTECODE", "1")
        .output()
        .map_err(|e| RenderError::io(python, "run the Mitsuba tool", e))?;
    if !output.status.success() {
        let why = String::from_utf8_lossy(&output.stderr);
        return Err(Error::invalid(
            "mitsuba_lighting.py",
            why.lines().last().unwrap_or("failed").to_string(),
        ));
    }
    let env = EnvMap::read(&env_path)?;
    let _ = std::fs::remove_dir_all(&dir);
    Ok(Found {
        env,
        pose: None,
        warning: None,
    })
}
