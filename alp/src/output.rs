//! Output folders are written whole or not at all: everything goes to a
//! temporary sibling folder that is renamed into place at the end, so a
//! failed or interrupted run never leaves a half-written `OUT_DIR` (and never
//! destroys the one a previous run left).

use std::path::{Path, PathBuf};

use render::RenderError;

use crate::error::Result;

/// Runs `write` on a fresh temporary folder beside `out`, then replaces `out` with it.
pub fn write_folder_atomically(out: &Path, write: impl FnOnce(&Path) -> Result<()>) -> Result<()> {
    let name = out
        .file_name()
        .ok_or_else(|| RenderError::file(out, "an output folder needs a name (not `/` or `..`)"))?;
    let parent = match out.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    std::fs::create_dir_all(&parent).map_err(|e| RenderError::io(&parent, "create folder", e))?;
    let tmp = parent.join(format!(".{}.partial-{}", name.to_string_lossy(), std::process::id()));
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp).map_err(|e| RenderError::io(&tmp, "remove stale temporary folder", e))?;
    }
    std::fs::create_dir(&tmp).map_err(|e| RenderError::io(&tmp, "create folder", e))?;
    if let Err(e) = write(&tmp) {
        let _ = std::fs::remove_dir_all(&tmp);
        return Err(e);
    }
    if out.exists() {
        let old = parent.join(format!(".{}.old-{}", name.to_string_lossy(), std::process::id()));
        std::fs::rename(out, &old).map_err(|e| RenderError::io(out, "move the previous output aside", e))?;
        std::fs::rename(&tmp, out).map_err(|e| RenderError::io(out, "move the new output into place", e))?;
        std::fs::remove_dir_all(&old).map_err(|e| RenderError::io(&old, "remove the previous output", e))?;
    } else {
        std::fs::rename(&tmp, out).map_err(|e| RenderError::io(out, "move the new output into place", e))?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_failed_write_leaves_the_previous_output_untouched() {
        let base = std::env::temp_dir().join(format!("alp-output-test-{}", std::process::id()));
        let out = base.join("out");
        write_folder_atomically(&out, |dir| {
            std::fs::write(dir.join("a.txt"), "first").map_err(|e| RenderError::io(dir, "write", e).into())
        })
        .expect("first write");
        let failed = write_folder_atomically(&out, |dir| {
            std::fs::write(dir.join("a.txt"), "second").map_err(|e| RenderError::io(dir, "write", e))?;
            Err(RenderError::file(dir, "simulated failure").into())
        });
        assert!(failed.is_err());
        assert_eq!(std::fs::read_to_string(out.join("a.txt")).expect("kept"), "first");
        let leftovers = std::fs::read_dir(&base).expect("base").count();
        assert_eq!(leftovers, 1, "no temporary folder is left behind");
        write_folder_atomically(&out, |dir| {
            std::fs::write(dir.join("b.txt"), "third").map_err(|e| RenderError::io(dir, "write", e).into())
        })
        .expect("replace");
        assert!(!out.join("a.txt").exists() && out.join("b.txt").exists());
        std::fs::remove_dir_all(&base).expect("clean up");
    }
}
