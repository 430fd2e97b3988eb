//! What the CLI's integration tests share.

use std::path::PathBuf;
use std::process::{Command, Output};

use render::envmap::EnvMap;

/// `alp` run with `args`.
pub fn alp(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_alp"))
        .args(args)
        .output()
        .expect("run alp")
}

/// A fresh folder for one test (`name`, this process's), holding the
/// courtyard map box-filtered to `rows` rows as `env.exr`: the folder and
/// the map's path.
pub fn workspace(name: &str, rows: usize) -> (PathBuf, PathBuf) {
    let dir = std::env::temp_dir().join(format!("alp-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("temp dir");
    let courtyard = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../assets/envmaps/courtyard.exr");
    let env = dir.join("env.exr");
    EnvMap::read(courtyard)
        .expect("courtyard")
        .downsample(rows)
        .write(&env)
        .expect("write env");
    (dir, env)
}
