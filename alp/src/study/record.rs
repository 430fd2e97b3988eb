//! A study's rows: one per run, kept in `results.jsonl` as they finish (so
//! that a rerun skips them), and written out whole as `results.csv`.

use std::collections::BTreeSet;
use std::io::Write;
use std::path::{Path, PathBuf};

use render::RenderError;
use serde::{Deserialize, Serialize};

use crate::error::Result;

/// One run: a scene under one setting.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Row {
    /// The scene folder's name.
    pub scene: String,
    /// The probe's family (`scene.json`'s `family`, else the probe's name).
    #[serde(default)]
    pub probe: String,
    /// The knob family (`quality`, `spp`, ...; `default` for the default setting).
    pub family: String,
    /// The setting, as `knob=value` (the key a rerun skips by, with the scene).
    pub variant: String,
    /// Worker threads.
    pub threads: usize,
    /// The perturbation's graded level (1 the mildest; none without one).
    pub level: Option<usize>,
    /// The perturbation's strength in its own unit.
    pub strength: Option<f64>,
    /// Mean angular error of the relit mirror sphere, degrees (none when the run failed).
    pub mirror_deg: Option<f64>,
    /// ... of the shiny sphere.
    pub shiny_deg: Option<f64>,
    /// ... of the diffuse sphere.
    pub diffuse_deg: Option<f64>,
    /// Scale-invariant RMSE of the mirror sphere.
    pub mirror_si_rmse: Option<f64>,
    /// ... of the shiny sphere.
    pub shiny_si_rmse: Option<f64>,
    /// ... of the diffuse sphere.
    pub diffuse_si_rmse: Option<f64>,
    /// The pose's rotation error, degrees.
    pub rotation_deg: Option<f64>,
    /// The angle between the estimated and true axes (mesh +Y), degrees.
    pub axis_deg: Option<f64>,
    /// The translation's error, millimetres.
    pub translation_mm: Option<f64>,
    /// Whether the pose's observable part was found (`scenes::Observable`;
    /// none when the run was given the true pose, or failed).
    pub pose_found: Option<bool>,
    /// Wall time of the estimate, seconds (the evaluation not counted).
    pub wall_s: f64,
    /// The process's peak resident memory during the estimate, MB (where the system tells it).
    pub peak_mb: Option<f64>,
    /// What the estimate warned of (a mask on the image's border).
    pub warning: Option<String>,
    /// Whether the map or the pose held a value that is not finite.
    pub non_finite: bool,
    /// Why the run failed (a clear error of the estimate, or a panic), if it did.
    pub error: Option<String>,
    /// Why the run did not happen: a perturbation this scene cannot take
    /// (the probe too small to make smaller, a border cut no crop makes).
    pub skipped: Option<String>,
    /// The `alp` binary that ran it ([`this_build`]): a rerun by another
    /// build runs the scene again instead of mixing two builds' figures.
    #[serde(default)]
    pub build: String,
}

impl Row {
    /// The row of a run of `variant` on `scene` before it is scored.
    pub fn unscored(scene: &str, family: &str, variant: &str, threads: usize) -> Self {
        Row {
            scene: scene.into(),
            probe: String::new(),
            family: family.into(),
            variant: variant.into(),
            threads,
            level: None,
            strength: None,
            mirror_deg: None,
            shiny_deg: None,
            diffuse_deg: None,
            mirror_si_rmse: None,
            shiny_si_rmse: None,
            diffuse_si_rmse: None,
            rotation_deg: None,
            axis_deg: None,
            translation_mm: None,
            pose_found: None,
            wall_s: 0.0,
            peak_mb: None,
            warning: None,
            non_finite: false,
            error: None,
            skipped: None,
            build: String::new(),
        }
    }

    /// The three angular errors, when the run succeeded.
    pub fn angular(&self) -> Option<[f64; 3]> {
        Some([self.mirror_deg?, self.shiny_deg?, self.diffuse_deg?])
    }

    /// The fields in [`CSV_HEADER`]'s order.
    fn csv_fields(&self) -> Vec<String> {
        let num = |v: Option<f64>| v.map(|v| format!("{v}")).unwrap_or_default();
        vec![
            csv_text(&self.scene),
            csv_text(&self.probe),
            csv_text(&self.family),
            csv_text(&self.variant),
            self.threads.to_string(),
            self.level.map(|l| l.to_string()).unwrap_or_default(),
            num(self.strength),
            num(self.mirror_deg),
            num(self.shiny_deg),
            num(self.diffuse_deg),
            num(self.mirror_si_rmse),
            num(self.shiny_si_rmse),
            num(self.diffuse_si_rmse),
            num(self.rotation_deg),
            num(self.axis_deg),
            num(self.translation_mm),
            self.pose_found.map(|f| f.to_string()).unwrap_or_default(),
            format!("{}", self.wall_s),
            num(self.peak_mb),
            csv_text(self.warning.as_deref().unwrap_or("")),
            self.non_finite.to_string(),
            csv_text(self.error.as_deref().unwrap_or("")),
            csv_text(self.skipped.as_deref().unwrap_or("")),
            csv_text(&self.build),
        ]
    }
}

/// The columns of `results.csv`, [`Row`]'s fields.
pub const CSV_HEADER: &str = "scene,probe,family,variant,threads,level,strength,mirror_deg,shiny_deg,diffuse_deg,\
mirror_si_rmse,shiny_si_rmse,diffuse_si_rmse,rotation_deg,axis_deg,translation_mm,pose_found,wall_s,peak_mb,\
warning,non_finite,error,skipped,build";

/// This `alp` binary's identity: a hash of the executable's bytes (16 hex
/// digits; `unknown` where it cannot be read): the same for every build of
/// the same source by the same toolchain.
pub fn this_build() -> &'static str {
    static BUILD: std::sync::OnceLock<String> = std::sync::OnceLock::new();
    BUILD.get_or_init(|| {
        use std::hash::Hasher;
        match std::env::current_exe().and_then(std::fs::read) {
            Ok(bytes) => {
                // Fixed keys: the same bytes, the same digits (under one toolchain).
                let mut hasher = std::hash::DefaultHasher::new();
                hasher.write(&bytes);
                format!("{:016x}", hasher.finish())
            }
            Err(_) => "unknown".into(),
        }
    })
}

/// A CSV field: quoted when it holds a comma, quote or line break.
pub fn csv_text(s: &str) -> String {
    match s.contains([',', '"', '\n', '\r']) {
        true => format!("\"{}\"", s.replace('"', "\"\"")),
        false => s.to_string(),
    }
}

/// `results.jsonl` of a study's output folder: the rows so far.
pub struct Results {
    path: PathBuf,
    /// Every row of `build`, in the order run.
    pub rows: Vec<Row>,
    /// Rows in the file that another build ran (kept there, not summed up).
    pub other_builds: usize,
    build: String,
    done: BTreeSet<(String, String)>,
}

impl Results {
    /// Opens (or starts) `dir/results.jsonl`. A last line cut short (a run
    /// killed while writing it) is dropped with a warning and redone; any
    /// other line that is not a row is an error naming the file and line.
    /// Only the rows `build` ran count as done.
    pub fn open(dir: &Path, build: &str) -> Result<Self> {
        std::fs::create_dir_all(dir).map_err(|e| RenderError::io(dir, "create folder", e))?;
        let path = dir.join("results.jsonl");
        let rows = match path.is_file() {
            true => read_rows(&path, true)?,
            false => Vec::new(),
        };
        Ok(Self::of_build(path, rows, build))
    }

    /// The rows of the newest build (the last row's) in `dir/results.jsonl`,
    /// read only: a study may be appending to it (a last line cut short is
    /// left out, not repaired). What a study's tables are made from while it
    /// runs, or redrawn from after.
    pub fn read_newest(dir: &Path) -> Result<Self> {
        let path = dir.join("results.jsonl");
        if !path.is_file() {
            return Err(RenderError::file(&path, "is missing: the study has not run here").into());
        }
        let rows = read_rows(&path, false)?;
        let build = rows.last().map(|r| r.build.clone()).unwrap_or_default();
        Ok(Self::of_build(path, rows, &build))
    }

    fn of_build(path: PathBuf, mut rows: Vec<Row>, build: &str) -> Self {
        let before = rows.len();
        rows.retain(|r| r.build == build);
        let done = rows.iter().map(|r| (r.scene.clone(), r.variant.clone())).collect();
        Results {
            path,
            other_builds: before - rows.len(),
            rows,
            build: build.to_string(),
            done,
        }
    }

    /// The rows a table sums up: those of the `variants` asked for that ran
    /// on some scene, on the `scenes` where every one of them ran (every
    /// setting on the same scenes); and the scenes left out for a run
    /// missing.
    pub fn complete(&self, scenes: &[String], variants: &[&str]) -> (Vec<Row>, Vec<String>) {
        let ran: BTreeSet<&str> = self
            .rows
            .iter()
            .map(|r| r.variant.as_str())
            .filter(|v| variants.contains(v))
            .collect();
        let (whole, partial): (Vec<&str>, Vec<&str>) = scenes
            .iter()
            .map(String::as_str)
            .partition(|scene| !ran.is_empty() && ran.iter().all(|v| self.has(scene, v)));
        let rows = self
            .rows
            .iter()
            .filter(|r| ran.contains(r.variant.as_str()) && whole.contains(&r.scene.as_str()))
            .cloned()
            .collect();
        (rows, partial.into_iter().map(String::from).collect())
    }

    /// Whether `scene` has run under `variant`.
    pub fn has(&self, scene: &str, variant: &str) -> bool {
        self.done.contains(&(scene.to_string(), variant.to_string()))
    }

    /// Appends a finished run (one whole line, flushed), as this build's.
    pub fn push(&mut self, row: Row) -> Result<()> {
        let row = Row {
            build: self.build.clone(),
            ..row
        };
        let line = serde_json::to_string(&row).map_err(|e| RenderError::io(&self.path, "serialise", e))? + "\n";
        let mut file = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&self.path)
            .map_err(|e| RenderError::io(&self.path, "open for appending", e))?;
        file.write_all(line.as_bytes())
            .and_then(|_| file.flush())
            .map_err(|e| RenderError::io(&self.path, "append", e))?;
        self.done.insert((row.scene.clone(), row.variant.clone()));
        self.rows.push(row);
        Ok(())
    }

    /// Writes `results.csv` beside `results.jsonl`.
    pub fn write_csv(&self) -> Result<()> {
        let mut text = String::from(CSV_HEADER) + "\n";
        for row in &self.rows {
            text += &row.csv_fields().join(",");
            text.push('\n');
        }
        write_atomically(&self.path.with_file_name("results.csv"), &text)
    }
}

/// The rows of `path`. A last line cut short (a run killed, or still
/// writing it) is left out with a warning, and with `repair` cut from the
/// file (its run is then redone); any other line that is not a row is an
/// error naming the file and line.
fn read_rows(path: &Path, repair: bool) -> Result<Vec<Row>> {
    let text = std::fs::read_to_string(path).map_err(|e| RenderError::io(path, "read", e))?;
    let lines: Vec<&str> = text.lines().collect();
    let mut rows = Vec::new();
    for (i, line) in lines.iter().enumerate() {
        if line.trim().is_empty() {
            continue;
        }
        match serde_json::from_str::<Row>(line) {
            Ok(row) => rows.push(row),
            Err(_) if i + 1 == lines.len() && !text.ends_with('\n') => {
                eprintln!(
                    "alp: warning: {}: line {} was cut short{}",
                    path.display(),
                    i + 1,
                    if repair { "; that run is redone" } else { "; left out" }
                );
                if repair {
                    // The whole lines kept as they were: the cut one must not prefix the next row.
                    let whole = text.rfind('\n').map_or(0, |end| end + 1);
                    write_atomically(path, &text[..whole])?;
                }
            }
            Err(e) => {
                return Err(RenderError::file(path, format!("line {} is not a study row: {e}", i + 1)).into());
            }
        }
    }
    Ok(rows)
}

/// Writes `text` to `path` whole or not at all (a temporary sibling renamed into place).
pub fn write_atomically(path: &Path, text: &str) -> Result<()> {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let tmp = path.with_file_name(format!(".{name}.partial-{}", std::process::id()));
    std::fs::write(&tmp, text).map_err(|e| RenderError::io(&tmp, "write", e))?;
    std::fs::rename(&tmp, path).map_err(|e| RenderError::io(path, "move into place", e).into())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(scene: &str, variant: &str) -> Row {
        Row {
            strength: Some(0.5),
            mirror_deg: Some(4.5),
            shiny_deg: Some(1.25),
            mirror_si_rmse: Some(0.5),
            shiny_si_rmse: Some(0.25),
            rotation_deg: Some(1.0),
            axis_deg: Some(0.5),
            translation_mm: Some(2.0),
            pose_found: Some(true),
            wall_s: 3.5,
            error: Some("a \"quoted\", error".into()),
            ..Row::unscored(scene, "quality", variant, 2)
        }
    }

    #[test]
    fn rows_survive_a_reopen_and_a_cut_short_line_is_redone() {
        let dir = std::env::temp_dir().join(format!("alp-study-record-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let mut results = Results::open(&dir, "one").expect("open");
        results.push(row("a", "quality=fast")).expect("push");
        results.push(row("b", "quality=fast")).expect("push");
        // A run killed while writing its line.
        let mut file = std::fs::OpenOptions::new()
            .append(true)
            .open(dir.join("results.jsonl"))
            .expect("append");
        file.write_all(br#"{"scene":"c","fam"#).expect("write");
        drop(file);
        let whole = std::fs::read_to_string(dir.join("results.jsonl")).expect("read");
        let reopened = Results::open(&dir, "one").expect("reopen");
        let ran = |scene: &str| Row {
            build: "one".into(),
            ..row(scene, "quality=fast")
        };
        assert_eq!(reopened.rows, vec![ran("a"), ran("b")]);
        let kept = std::fs::read_to_string(dir.join("results.jsonl")).expect("read");
        assert_eq!(
            kept,
            whole[..whole.rfind('\n').expect("lines") + 1],
            "whole lines kept as written"
        );
        assert!(reopened.has("b", "quality=fast"));
        assert!(!reopened.has("c", "quality=fast") && !reopened.has("a", "quality=best"));
        // Another build runs them again, and sums up its own rows only.
        let other = Results::open(&dir, "two").expect("reopen");
        assert!(!other.has("b", "quality=fast") && other.rows.is_empty() && other.other_builds == 2);
        // A broken line in the middle is an error naming the file and line.
        std::fs::write(dir.join("results.jsonl"), "{}\n{}\n").expect("write");
        let err = Results::open(&dir, "one").err().expect("an error").to_string();
        assert!(err.contains("results.jsonl") && err.contains("line 1"), "{err}");
        std::fs::remove_dir_all(&dir).expect("clean up");
    }

    #[test]
    fn csv_quotes_what_needs_it_and_leaves_missing_numbers_empty() {
        let fields = row("a", "quality=fast").csv_fields();
        assert_eq!(fields.len(), CSV_HEADER.split(',').count());
        assert_eq!(fields[9], "", "no diffuse error");
        assert_eq!(fields[21], "\"a \"\"quoted\"\", error\"");
        assert_eq!(csv_text("plain"), "plain");
    }
}
