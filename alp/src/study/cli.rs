//! `alp study ...`: the study commands, from flags to an output folder.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};

use crate::cli::progress_bar;
use crate::error::{Error, Result};
use crate::relight::RelightSettings;

use super::record::{Results, Row, write_atomically};
use super::{DEFAULT, Method, RunContext, chart, mitsuba_available, paired, speed_accuracy, stability, summary};

/// The studies.
#[derive(clap::Subcommand, Debug)]
pub enum StudyCommand {
    /// Speed against accuracy: the estimate on every scene under each knob
    /// that trades time for accuracy (quality presets, samples per pixel,
    /// orientation starts, the working map's resolution, the lighting
    /// solve, threads), swept one at a time from the default.
    SpeedAccuracy(SpeedAccuracyArgs),
    /// Where the estimate breaks: the photo perturbed (masks eroded or
    /// dilated, noise, clipped highlights, a wrong exposure, the probe cut
    /// by the border, small probes, blur) at graded strengths, and the
    /// paper's ablations (one start, no pose priors, no light smoothness,
    /// joint rounds).
    Stability(StabilityArgs),
}

/// The flags every study has.
#[derive(clap::Args, Debug)]
pub struct StudyArgs {
    /// Scene folders, or folders of scene folders (FORMATS.md, "Scene folder").
    #[arg(long, num_args = 1.., required = true)]
    pub scenes: Vec<PathBuf>,
    /// Output folder: results.jsonl (kept: a rerun skips the runs it holds),
    /// results.csv, and the study's tables and chart.
    #[arg(long)]
    pub out: PathBuf,
    /// Worker threads (of the default setting's runs).
    #[arg(long, default_value_t = 2)]
    pub threads: usize,
    /// Samples per pixel of the relit spheres that score each run, a square.
    #[arg(long, default_value_t = 256)]
    pub eval_spp: u32,
    /// Run nothing: write the tables and the chart from the rows
    /// results.jsonl holds (its newest build's, on the scenes every setting
    /// has run), e.g. while the study runs, or to redraw them.
    #[arg(long)]
    pub tables_only: bool,
}

/// Flags of `alp study stability` (tables stability.csv, stability.md, and
/// each perturbation against the photo unperturbed, paired.csv, paired.md;
/// chart stability.svg).
#[derive(clap::Args, Debug)]
pub struct StabilityArgs {
    #[command(flatten)]
    pub study: StudyArgs,
    /// The perturbations and ablations to run, comma-separated (default:
    /// all of mask_erode, mask_dilate, mask_traced, mask_segmenter, noise,
    /// clip, exposure_under, exposure_over, border, small, blur, jpeg,
    /// box, one_start, no_pose_priors, no_light_smoothness, joint_rounds).
    #[arg(long, value_delimiter = ',')]
    pub perturbations: Option<Vec<String>>,
}

/// Flags of `alp study speed-accuracy` (tables summary.csv, summary.md, per
/// probe family model.csv, model.md, and each setting against the default
/// scene by scene, paired.csv, paired.md; chart speed_accuracy.svg).
#[derive(clap::Args, Debug)]
pub struct SpeedAccuracyArgs {
    #[command(flatten)]
    pub study: StudyArgs,
    /// The knob families to sweep, comma-separated (default: all of quality,
    /// spp, starts, map, model, lighting, threads, true-pose, mitsuba).
    #[arg(long, value_delimiter = ',')]
    pub families: Option<Vec<String>>,
    /// The Python that runs the outside method (`tools/mitsuba_lighting.py`,
    /// Mitsuba 3): when it cannot import Mitsuba, the `mitsuba` family is
    /// skipped with a note.
    #[arg(long, default_value = "python3")]
    pub mitsuba_python: PathBuf,
    /// An earlier run of this study (its output folder, e.g. by the build
    /// before a change): its runs of this run's scenes and settings paired
    /// with these scene by scene (before.csv, before.md), and its Pareto
    /// front drawn beside this run's in the chart.
    #[arg(long)]
    pub before: Option<PathBuf>,
}

/// Runs a study command.
pub fn run(command: &StudyCommand) -> Result<()> {
    match command {
        StudyCommand::SpeedAccuracy(args) => speed_accuracy_run(args),
        StudyCommand::Stability(args) => stability_run(args),
    }
}

/// The relit spheres' settings for `--eval-spp` (a square), after `--threads` is checked.
fn checked(&StudyArgs { threads, eval_spp, .. }: &StudyArgs) -> Result<RelightSettings> {
    if threads == 0 {
        return Err(Error::invalid("--threads", "needs at least one thread"));
    }
    let strata = (eval_spp as f64).sqrt().round() as u32;
    if eval_spp == 0 || strata * strata != eval_spp {
        return Err(Error::invalid(
            "--eval-spp",
            format!("{eval_spp} is not a square (1, 4, 9, ...)"),
        ));
    }
    Ok(RelightSettings { spp: eval_spp, seed: 0 })
}

/// Every scene under `dirs` under every variant, with a progress bar on a
/// terminal (with `--tables-only`, the rows run so far); `results.csv`
/// written. The rows a table sums up (`Results::complete`), and a note of
/// the scenes it leaves out.
fn run_all(study: &StudyArgs, variants: &[super::Variant], context: &RunContext) -> Result<(Vec<Row>, Option<String>)> {
    let scenes = super::scenes::find(&study.scenes)?;
    let results = match study.tables_only {
        true => super::collect(&scenes, &study.out)?,
        false => run_with_progress(&scenes, variants, &study.out, context)?,
    };
    results.write_csv()?;
    let ids: Vec<&str> = variants.iter().map(|v| v.id.as_str()).collect();
    let (rows, left_out) = results.complete(&super::scene_names(&scenes), &ids);
    if rows.is_empty() {
        return Err(Error::invalid(
            "--out",
            format!("no scene in {} has run under every setting yet", study.out.display()),
        ));
    }
    let note = (!left_out.is_empty()).then(|| {
        let named = match left_out.len() {
            ..=NAMED => left_out.join(", "),
            n => format!("{}, and {} more", left_out[..NAMED].join(", "), n - NAMED),
        };
        format!(
            "{} of the {} scenes left out: not every setting has run on them yet ({named}).",
            left_out.len(),
            scenes.len(),
        )
    });
    if let Some(note) = &note {
        eprintln!("alp study: {note}");
    }
    Ok((rows, note))
}

/// How many scenes a note names.
const NAMED: usize = 4;

/// [`super::run`] with a progress bar on a terminal.
fn run_with_progress(
    scenes: &[PathBuf],
    variants: &[super::Variant],
    out: &Path,
    context: &RunContext,
) -> Result<Results> {
    let bar = progress_bar(
        std::io::stderr().is_terminal(),
        "alp study {bar:30} {pos}/{len} runs, {elapsed} (eta {eta}) {msg}",
    );
    let results = super::run(scenes, variants, out, context, &mut |done, total, what| {
        bar.set_length(total as u64);
        bar.set_position(done as u64);
        bar.set_message(what.to_string());
    });
    bar.finish_and_clear();
    results
}

fn stability_run(args: &StabilityArgs) -> Result<()> {
    let (study, out) = (&args.study, &args.study.out);
    let eval = checked(study)?;
    let names = args
        .perturbations
        .clone()
        .unwrap_or_else(|| stability::PERTURBATIONS.map(String::from).to_vec());
    let variants = stability::sweep(&names, study.threads)?;
    let context = RunContext {
        eval,
        mitsuba_python: None,
    };
    let (rows, left_out) = run_all(study, &variants, &context)?;
    let summaries = summary::summarize_stability(&rows);
    write_atomically(&out.join("stability.csv"), &summary::stability_csv(&summaries))?;
    let table = summary::stability_markdown(&summaries) + &notes(left_out.as_slice());
    write_atomically(&out.join("stability.md"), &table)?;
    write_atomically(&out.join("stability.svg"), &chart::stability_svg(&summaries)?)?;
    write_paired(out, &rows, stability::UNPERTURBED)?;
    finished(&table, rows.len(), &out.join("stability.svg"));
    Ok(())
}

/// `paired.csv` and `paired.md`: every setting against `reference`, scene by scene.
fn write_paired(out: &Path, rows: &[Row], reference: &str) -> Result<()> {
    let all = paired::paired(rows, reference);
    write_atomically(&out.join("paired.csv"), &paired::to_csv(&all))?;
    write_atomically(
        &out.join("paired.md"),
        &paired::to_markdown(&all, &format!("`{reference}`")),
    )
}

/// `before.csv` and `before.md`: each setting of `rows` against the same
/// setting's run of the same scene in the study folder `dir` (its newest
/// build's rows). The summaries of those runs, for the chart's front.
fn write_before(out: &Path, dir: &Path, rows: &[Row]) -> Result<Vec<summary::VariantSummary>> {
    let mut before = Results::read_newest(dir)?.rows;
    before.retain(|b| rows.iter().any(|r| r.scene == b.scene && r.variant == b.variant));
    if before.is_empty() {
        return Err(Error::invalid(
            "--before",
            format!(
                "{} holds no run of this study's scenes under its settings",
                dir.join("results.jsonl").display()
            ),
        ));
    }
    let all = paired::against_before(rows, &before);
    write_atomically(&out.join("before.csv"), &paired::to_csv(&all))?;
    let reference = format!("the same setting in `{}`", dir.display());
    write_atomically(&out.join("before.md"), &paired::to_markdown(&all, &reference))?;
    Ok(summary::summarize(&before, &speed_accuracy::APART))
}

/// Notes below a Markdown table, a paragraph each.
fn notes(notes: &[String]) -> String {
    notes.iter().map(|n| format!("\n{n}\n")).collect()
}

/// Prints the table and where the chart is.
fn finished(table: &str, runs: usize, chart: &Path) {
    println!("{table}");
    eprintln!("alp study: {runs} runs; the chart is {}", chart.display());
}

fn speed_accuracy_run(args: &SpeedAccuracyArgs) -> Result<()> {
    let (study, out) = (&args.study, &args.study.out);
    let eval = checked(study)?;
    let families = args
        .families
        .clone()
        .unwrap_or_else(|| speed_accuracy::FAMILIES.map(String::from).to_vec());
    let mut variants = speed_accuracy::sweep(&families, study.threads)?;
    let mut notes = Vec::new();
    let wants_mitsuba = variants.iter().any(|v| matches!(v.method, Method::MitsubaAdam { .. }));
    let check_mitsuba = wants_mitsuba && !study.tables_only;
    let mitsuba_python = match check_mitsuba.then(|| mitsuba_available(&args.mitsuba_python)) {
        Some(Ok(())) => Some(args.mitsuba_python.clone()),
        Some(Err(why)) => {
            let note = format!(
                "The outside method (Mitsuba 3, `tools/mitsuba_lighting.py`) was skipped: `{}` cannot run it ({why}).",
                args.mitsuba_python.display()
            );
            eprintln!("alp study: {note}");
            notes.push(note);
            variants.retain(|v| !matches!(v.method, Method::MitsubaAdam { .. }));
            None
        }
        None => None,
    };
    let context = RunContext { eval, mitsuba_python };
    let (rows, left_out) = run_all(study, &variants, &context)?;
    notes.extend(left_out);
    let summaries = summary::summarize(&rows, &speed_accuracy::APART);
    write_atomically(&out.join("summary.csv"), &summary::to_csv(&summaries))?;
    let table = summary::to_markdown(&summaries) + &self::notes(&notes);
    write_atomically(&out.join("summary.md"), &table)?;
    let groups = summary::by_probe(&rows, &speed_accuracy::MODELLING, DEFAULT);
    if !groups.is_empty() {
        write_atomically(&out.join("model.csv"), &summary::by_probe_csv(&groups))?;
        write_atomically(&out.join("model.md"), &summary::by_probe_markdown(&groups))?;
    }
    write_paired(out, &rows, DEFAULT)?;
    let before = match &args.before {
        Some(dir) => write_before(out, dir, &rows)?,
        None => Vec::new(),
    };
    write_atomically(
        &out.join("speed_accuracy.svg"),
        &chart::speed_accuracy_svg(&summaries, DEFAULT, &speed_accuracy::APART, &before)?,
    )?;
    finished(&table, rows.len(), &out.join("speed_accuracy.svg"));
    Ok(())
}
