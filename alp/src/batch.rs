//! `alp batch`: the estimate over a dataset, on one machine or many.
//!
//! A manifest holds one JSON object per line, `{"id", "image", "mask",
//! "camera", "probe"}` (paths absolute or relative to the manifest's folder)
//! with optional `"quality"`, `"seed"` and `"env_size"`; `"box":
//! "x0,y0,x1,y1"` may stand for the mask (as `alp estimate --box`) and a
//! photo without `"camera"` is read with its EXIF's. Each estimate lands
//! in `OUT/<id>/`, written whole or not at all, so a folder that exists is a
//! finished photo: `--resume` skips those and retries the rest. `--shard I/N`
//! takes the lines whose 0-based index is I modulo N (broken lines count, so
//! a line's shard never depends on another line), which is all a Slurm job
//! array or a Kubernetes indexed Job needs. Each shard appends a line per
//! photo to `OUT/summary-I-of-N.jsonl` as it goes (a killed shard keeps what
//! it finished); `--merge OUT` joins the shards' latest line per photo into
//! `OUT/summary.jsonl` and `OUT/summary.csv`, in manifest order.

use std::collections::{BTreeMap, HashSet};
use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::{Deserialize, Serialize};

use render::RenderError;

use crate::cli::photo::{ProbeMarking, read_inputs};
use crate::cli::{ThreadsArg, parse_quality, parse_size};
use crate::error::{Error, Result};
use crate::estimate::{Settings, estimate};
use crate::output::write_estimate;

/// One line of the manifest.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Entry {
    /// The photo's name: its output folder (letters, digits, `.`, `_`, `-`).
    pub id: String,
    /// The photo (any format `alp estimate` reads).
    pub image: PathBuf,
    /// The probe's mask (or `box`).
    #[serde(default)]
    pub mask: Option<PathBuf>,
    /// Instead of `mask`: a box round the probe, `x0,y0,x1,y1`.
    #[serde(default, rename = "box")]
    pub probe_box: Option<String>,
    /// camera.json (default: the photo's EXIF).
    #[serde(default)]
    pub camera: Option<PathBuf>,
    /// Probe folder or procedural name.
    pub probe: PathBuf,
    /// fast, default or best (default: default).
    #[serde(default)]
    pub quality: Option<String>,
    /// Random seed (default 0).
    #[serde(default)]
    pub seed: Option<u64>,
    /// Output map size, WIDTHxHEIGHT (default 256x128).
    #[serde(default)]
    pub env_size: Option<String>,
}

/// Which lines a run takes: index I modulo N.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Shard {
    /// I, from 0 to N - 1.
    pub index: usize,
    /// N, at least 1.
    pub count: usize,
}

impl std::str::FromStr for Shard {
    type Err = String;

    fn from_str(s: &str) -> std::result::Result<Self, String> {
        let bad = || format!("`{s}` is not I/N with 0 <= I < N (e.g. 0/4)");
        let (i, n) = s.split_once('/').ok_or_else(bad)?;
        let (index, count): (usize, usize) = (
            i.trim().parse().map_err(|_| bad())?,
            n.trim().parse().map_err(|_| bad())?,
        );
        if count == 0 || index >= count {
            return Err(bad());
        }
        Ok(Shard { index, count })
    }
}

impl Shard {
    /// The whole manifest.
    pub const ALL: Shard = Shard { index: 0, count: 1 };

    pub fn summary_name(self) -> String {
        format!("summary-{}-of-{}.jsonl", self.index, self.count)
    }
}

/// What became of one line.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Outcome {
    /// The photo's id (the line number when the line has none).
    pub id: String,
    /// The manifest line, from 1.
    pub line: usize,
    /// `done`, `skipped` (finished before, `--resume`) or `failed`.
    pub status: String,
    /// Why it failed.
    pub error: Option<String>,
    /// The estimate's wall time, seconds.
    pub wall_s: Option<f64>,
    /// The re-render's PSNR against the photo, dB.
    pub psnr_db: Option<f64>,
}

/// How a batch runs.
#[derive(Clone, Copy, Debug)]
pub struct BatchOptions {
    /// The lines this run takes.
    pub shard: Shard,
    /// Skip photos whose output folder exists.
    pub resume: bool,
}

/// Runs the shard's lines of `manifest` into `out`; returns their outcomes
/// (also appended to the shard's summary file). A broken line or a failed
/// photo is reported and the rest go on; the error is the manifest's or the
/// output folder's own.
pub fn run(
    manifest: &Path,
    out: &Path,
    options: BatchOptions,
    mut progress: impl FnMut(&Outcome),
) -> Result<Vec<Outcome>> {
    let text = std::fs::read_to_string(manifest).map_err(|e| RenderError::io(manifest, "read manifest", e))?;
    if text.trim().is_empty() {
        return Err(RenderError::file(manifest, "lists no photos (one JSON object a line)").into());
    }
    let base = manifest.parent().map_or_else(|| PathBuf::from("."), Path::to_path_buf);
    std::fs::create_dir_all(out).map_err(|e| RenderError::io(out, "create folder", e))?;
    let summary_path = out.join(options.shard.summary_name());
    let mut summary = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&summary_path)
        .map_err(|e| RenderError::io(&summary_path, "open", e))?;
    let mut seen = HashSet::new();
    let mut outcomes = Vec::new();
    for (index, raw) in text.lines().enumerate() {
        if raw.trim().is_empty() {
            continue;
        }
        // Ids are checked on every line, so that a duplicate is one whatever the shard.
        let parsed = parse_entry(raw, &mut seen);
        if index % options.shard.count != options.shard.index {
            continue;
        }
        let line = index + 1;
        let outcome = match parsed {
            Err(e) => {
                // The id, when the line has one, names the failure.
                let id = serde_json::from_str::<serde_json::Value>(raw)
                    .ok()
                    .and_then(|v| v["id"].as_str().map(String::from))
                    .unwrap_or_else(|| format!("line {line}"));
                failed(id, line, format!("{}: line {line}: {e}", manifest.display()))
            }
            Ok(entry) => {
                let dir = out.join(&entry.id);
                if options.resume && dir.is_dir() {
                    Outcome {
                        id: entry.id,
                        line,
                        status: "skipped".into(),
                        error: None,
                        wall_s: None,
                        psnr_db: None,
                    }
                } else {
                    let clock = Instant::now();
                    match estimate_one(&entry, &base, &dir) {
                        Ok(psnr_db) => Outcome {
                            id: entry.id,
                            line,
                            status: "done".into(),
                            error: None,
                            wall_s: Some(clock.elapsed().as_secs_f64()),
                            psnr_db: Some(psnr_db),
                        },
                        Err(e) => failed(entry.id, line, e.to_string()),
                    }
                }
            }
        };
        let json = serde_json::to_string(&outcome).map_err(|e| RenderError::io(&summary_path, "serialise", e))?;
        writeln!(summary, "{json}").map_err(|e| RenderError::io(&summary_path, "append", e))?;
        progress(&outcome);
        outcomes.push(outcome);
    }
    Ok(outcomes)
}

fn failed(id: String, line: usize, error: String) -> Outcome {
    Outcome {
        id,
        line,
        status: "failed".into(),
        error: Some(error),
        wall_s: None,
        psnr_db: None,
    }
}

/// A line's entry, its id checked and remembered in `seen`.
fn parse_entry(raw: &str, seen: &mut HashSet<String>) -> Result<Entry> {
    let entry: Entry = serde_json::from_str(raw).map_err(|e| {
        Error::invalid(
            "manifest line",
            format!("{e} (fields: id, image, mask or box, probe; optional camera, quality, seed, env_size)"),
        )
    })?;
    let safe = |c: char| c.is_ascii_alphanumeric() || matches!(c, '.' | '_' | '-');
    if entry.id.is_empty() || entry.id.starts_with('.') || !entry.id.chars().all(safe) {
        return Err(Error::invalid(
            "id",
            format!(
                "`{}` is not a folder name of letters, digits, `.`, `_`, `-` (not starting with `.`)",
                entry.id
            ),
        ));
    }
    if !seen.insert(entry.id.clone()) {
        return Err(Error::invalid(
            "id",
            format!("`{}` is on an earlier line too", entry.id),
        ));
    }
    Ok(entry)
}

/// Estimates one photo into `dir` (whole or not at all); its PSNR.
fn estimate_one(entry: &Entry, base: &Path, dir: &Path) -> Result<f64> {
    let path = |p: &Path| if p.is_absolute() { p.to_path_buf() } else { base.join(p) };
    let mut settings = Settings::new(parse_quality(entry.quality.as_deref().unwrap_or("default"))?);
    settings.seed = entry.seed.unwrap_or(0);
    if let Some(size) = &entry.env_size {
        settings.env_size = parse_size(size)?;
    }
    let mask = entry.mask.as_deref().map(path);
    let marking = match (&mask, &entry.probe_box) {
        (Some(mask), None) => ProbeMarking::Mask(mask),
        (None, Some(text)) => ProbeMarking::Box { text, field: "box" },
        _ => {
            return Err(Error::invalid(
                "mask",
                "give the probe's mask or a box round it (not both)",
            ));
        }
    };
    let camera = entry.camera.as_deref().map(path);
    let photo = read_inputs(&path(&entry.image), marking, camera.as_deref(), &settings)?;
    let probe_path = path(&entry.probe);
    // A procedural name stays a name unless a folder of that name sits beside the manifest.
    let probe = if probe_path.exists() {
        crate::probes::load(&probe_path)?
    } else {
        crate::probes::load(&entry.probe)?
    };
    let result = estimate(&photo, &probe, &settings)?;
    crate::output::write_folder_atomically(dir, |tmp| write_estimate(tmp, &photo, &result))?;
    Ok(result.report.psnr_db)
}

/// Joins the shards' summaries in `out` into `summary.jsonl` and
/// `summary.csv`: per photo its latest line, in manifest order. Returns them.
pub fn merge(out: &Path) -> Result<Vec<Outcome>> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(out)
        .map_err(|e| RenderError::io(out, "read folder", e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| n.starts_with("summary-") && n.ends_with(".jsonl"))
        })
        .collect();
    files.sort();
    if files.is_empty() {
        return Err(RenderError::file(
            out,
            "no summary-I-of-N.jsonl to merge: is this an `alp batch --out` folder?",
        )
        .into());
    }
    let mut latest: BTreeMap<usize, Outcome> = BTreeMap::new();
    for file in &files {
        let text = std::fs::read_to_string(file).map_err(|e| RenderError::io(file, "read", e))?;
        for (n, raw) in text.lines().enumerate().filter(|(_, l)| !l.trim().is_empty()) {
            let outcome: Outcome = serde_json::from_str(raw)
                .map_err(|e| Error::invalid(format!("line {}", n + 1), e.to_string()).in_file(file))?;
            // A skip says only that an earlier run finished the photo: keep that run's line.
            match latest.get(&outcome.line) {
                Some(done) if outcome.status == "skipped" && done.status == "done" => {}
                _ => {
                    latest.insert(outcome.line, outcome);
                }
            }
        }
    }
    let outcomes: Vec<Outcome> = latest.into_values().collect();
    let mut jsonl = String::new();
    let mut csv = String::from("id,line,status,wall_s,psnr_db,error\n");
    let field = |v: Option<f64>| v.map_or(String::new(), |v| format!("{v:.4}"));
    for o in &outcomes {
        jsonl += &(serde_json::to_string(o).map_err(|e| RenderError::io(out, "serialise", e))? + "\n");
        let error = o.error.as_deref().unwrap_or("").replace('"', "\"\"");
        csv += &format!(
            "{},{},{},{},{},\"{error}\"\n",
            o.id,
            o.line,
            o.status,
            field(o.wall_s),
            field(o.psnr_db)
        );
    }
    let (jsonl_path, csv_path) = (out.join("summary.jsonl"), out.join("summary.csv"));
    crate::output::write_files_atomically(vec![
        (
            &jsonl_path,
            Box::new(|p| std::fs::write(p, &jsonl).map_err(|e| RenderError::io(p, "write", e).into())),
        ),
        (
            &csv_path,
            Box::new(|p| std::fs::write(p, &csv).map_err(|e| RenderError::io(p, "write", e).into())),
        ),
    ])?;
    Ok(outcomes)
}

/// Flags of `alp batch`.
#[derive(clap::Args, Debug)]
pub struct BatchArgs {
    /// The manifest: one JSON object per line, {"id", "image", "mask", "camera", "probe"}
    /// (paths absolute or relative to the manifest; "box": "x0,y0,x1,y1" instead of "mask"; no
    /// "camera": the photo's EXIF), optional "quality", "seed", "env_size".
    #[arg(long, required_unless_present = "merge", conflicts_with = "merge")]
    pub manifest: Option<PathBuf>,
    /// Output folder: `OUT/<id>/` per photo, `OUT/summary-I-of-N.jsonl` per shard.
    #[arg(long, required_unless_present = "merge")]
    pub out: Option<PathBuf>,
    /// Take every N-th line starting at line I (0-based): I/N, e.g. $SLURM_ARRAY_TASK_ID/$SLURM_ARRAY_TASK_COUNT.
    #[arg(long, default_value = "0/1")]
    pub shard: Shard,
    /// Skip photos finished before (their `OUT/<id>/` exists); failed ones run again.
    #[arg(long)]
    pub resume: bool,
    #[command(flatten)]
    pub threads: ThreadsArg,
    /// Join the shards' summaries in this folder into summary.jsonl and summary.csv.
    #[arg(long, value_name = "OUT")]
    pub merge: Option<PathBuf>,
}

/// Runs `alp batch`: an error when a photo failed (after all have run).
pub fn cli(args: &BatchArgs) -> Result<()> {
    if let Some(out) = &args.merge {
        let outcomes = merge(out)?;
        let count = |status: &str| outcomes.iter().filter(|o| o.status == status).count();
        println!(
            "{} photos: {} done, {} failed; {}",
            outcomes.len(),
            count("done") + count("skipped"),
            count("failed"),
            out.join("summary.csv").display()
        );
        return Ok(());
    }
    let (Some(manifest), Some(out)) = (&args.manifest, &args.out) else {
        return Err(Error::invalid("--manifest/--out", "both are needed (or --merge OUT)"));
    };
    let options = BatchOptions {
        shard: args.shard,
        resume: args.resume,
    };
    let pool = args.threads.pool()?;
    let outcomes = pool.install(|| {
        run(manifest, out, options, |o| match &o.error {
            Some(e) => eprintln!("alp batch: {} (line {}) failed: {e}", o.id, o.line),
            None => eprintln!("alp batch: {} (line {}) {}", o.id, o.line, o.status),
        })
    })?;
    let failures = outcomes.iter().filter(|o| o.status == "failed").count();
    if failures > 0 {
        return Err(Error::invalid(
            "batch",
            format!(
                "{failures} of {} photos failed (see {})",
                outcomes.len(),
                out.join(options.shard.summary_name()).display()
            ),
        ));
    }
    Ok(())
}
