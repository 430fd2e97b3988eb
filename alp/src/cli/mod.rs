//! What the commands share -- the worker pool (`--threads`), the progress
//! bar, the quality and size flags, reading the user's photo ([`photo`]) --
//! and the handlers of the commands that have no module of their own.

pub mod demo;
pub mod eval;
pub mod photo;
pub mod probe;
pub mod relight;
pub mod render;
pub mod synth;

use crate::error::{Error, Result};
use crate::estimate::Quality;

/// `--threads`, shared by the commands that run on a pool of workers.
#[derive(clap::Args, Clone, Copy, Debug)]
pub struct ThreadsArg {
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
}

impl ThreadsArg {
    /// The pool the flag asks for.
    pub fn pool(&self) -> Result<rayon::ThreadPool> {
        thread_pool(self.threads)
    }
}

/// `--quality`, shared by the commands with quality presets.
#[derive(clap::Args, Clone, Debug)]
pub struct QualityArg {
    /// fast, default or best.
    #[arg(long, default_value = "default")]
    pub quality: String,
}

impl QualityArg {
    /// The preset the flag names.
    pub fn preset(&self) -> Result<Quality> {
        parse_quality(&self.quality)
    }
}

/// The quality preset `q` names (fast, default, best).
pub(crate) fn parse_quality(q: &str) -> Result<Quality> {
    match q {
        "fast" => Ok(Quality::Fast),
        "default" => Ok(Quality::Default),
        "best" => Ok(Quality::Best),
        other => Err(Error::invalid(
            "--quality",
            format!("`{other}` is not one of fast, default, best"),
        )),
    }
}

/// A `WIDTHxHEIGHT` env map size, 2:1.
pub(crate) fn parse_size(s: &str) -> Result<(usize, usize)> {
    parse_dimensions(s, "--env-size", "WIDTH = 2 x HEIGHT", |w, h| w == 2 * h && h >= 2)
}

/// `WIDTHxHEIGHT` given to `flag`, which `valid(width, height)` accepts (its
/// rule, `what`, said in the error).
pub(crate) fn parse_dimensions(
    s: &str,
    flag: &str,
    what: &str,
    valid: impl Fn(usize, usize) -> bool,
) -> Result<(usize, usize)> {
    let size = s
        .split_once('x')
        .and_then(|(w, h)| Some((w.parse().ok()?, h.parse().ok()?)))
        .filter(|&(w, h)| valid(w, h));
    size.ok_or_else(|| Error::invalid(flag, format!("`{s}` is not WIDTHxHEIGHT with {what}")))
}

/// A pool of `threads` workers (all cores when `None`).
pub(crate) fn thread_pool(threads: Option<usize>) -> Result<rayon::ThreadPool> {
    if threads == Some(0) {
        return Err(Error::invalid("--threads", "needs at least one thread"));
    }
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads.unwrap_or_else(rayon::current_num_threads))
        .build()
        .map_err(|e| Error::invalid("--threads", e.to_string()))
}

/// A progress bar on a terminal (`verbose`), hidden otherwise.
pub(crate) fn progress_bar(verbose: bool, template: &str) -> indicatif::ProgressBar {
    let bar = if verbose {
        indicatif::ProgressBar::new(1)
    } else {
        indicatif::ProgressBar::hidden()
    };
    bar.set_style(indicatif::ProgressStyle::with_template(template).expect("a valid template"));
    bar
}
