//! `alp probe`: procedural probes.

use std::path::PathBuf;

use crate::Result;

#[derive(clap::Subcommand, Debug)]
pub enum ProbeAction {
    /// Write a procedural probe folder.
    Make {
        /// can (soda can), cap (thermos cap) or sphere.
        kind: String,
        /// The folder to write.
        #[arg(long)]
        out: PathBuf,
    },
}

/// Runs `alp probe ACTION`.
pub fn run(action: &ProbeAction) -> Result<()> {
    match action {
        ProbeAction::Make { kind, out } => {
            let probe = crate::probes::procedural(kind)?;
            crate::output::write_folder_atomically(out, |dir| Ok(probe.write(dir)?))
        }
    }
}
