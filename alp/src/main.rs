//! The `alp` command line.

use std::path::PathBuf;
use std::process::ExitCode;

use alp::cli;
use clap::{Parser, Subcommand};

/// Accidental light probes: lighting from a photo of a known shiny object.
#[derive(Parser)]
#[command(name = "alp", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// The first run: a photo of a soda can rendered from bundled data, its pose and lighting
    /// estimated, spheres relit and an object inserted under the estimate and the truth;
    /// writes OUT/index.html to look at, and report.json.
    Demo {
        /// The folder to write (written whole or not at all).
        #[arg(long, default_value = "demo")]
        out: PathBuf,
    },
    /// Estimate the lighting and the probe's pose from a photo (the main job).
    Estimate(alp::estimate::cli::EstimateArgs),
    /// The estimate over a dataset: a manifest of photos, sharded over machines, resumable.
    Batch(alp::batch::BatchArgs),
    /// Make a probe asset from a capture: many views of the object under known lighting.
    Acquire(alp::acquire::cli::AcquireArgs),
    /// Insert a virtual object into a photo under its estimated lighting, with the shadow it
    /// casts on a ground plane (differential rendering): linear EXR plus a PNG.
    Insert(alp::insert::cli::InsertArgs),
    /// Render a probe at a pose under an environment map (linear EXR plus a PNG preview).
    Render(cli::render::RenderArgs),
    /// Render the evaluation's mirror, shiny and diffuse spheres under an env map (768x256 EXR, left to right).
    Relight(cli::relight::RelightArgs),
    /// Relighting errors of an estimated env map (and pose errors of an estimated pose) against a scene's truth.
    Eval(cli::eval::EvalArgs),
    /// Make a synthetic evaluation scene: a probe at a random pose, random camera, known lighting
    /// (or, `alp synth captures`, a capture folder of a known probe for its acquisition).
    Synth(cli::synth::SynthCommand),
    /// Procedural probes.
    Probe {
        #[command(subcommand)]
        action: cli::probe::ProbeAction,
    },
    /// Studies of the estimate on a set of scenes, with tables and charts: speed against accuracy.
    Study {
        #[command(subcommand)]
        study: alp::study::cli::StudyCommand,
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Demo { out } => cli::demo::run(&out),
        Command::Estimate(args) => alp::estimate::cli::run(&args),
        Command::Acquire(args) => alp::acquire::cli::run(&args),
        Command::Batch(args) => alp::batch::cli(&args),
        Command::Study { study } => alp::study::cli::run(&study),
        Command::Insert(args) => alp::insert::cli::run(&args),
        Command::Render(args) => cli::render::run(&args),
        Command::Relight(args) => cli::relight::run(&args),
        Command::Eval(args) => cli::eval::run(&args),
        Command::Synth(command) => cli::synth::run(&command),
        Command::Probe { action } => cli::probe::run(&action),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("alp: error: {e}");
            ExitCode::from(2)
        }
    }
}
