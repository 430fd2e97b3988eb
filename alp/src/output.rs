//! Outputs are written whole or not at all: everything goes to a temporary
//! sibling (folder or files) renamed into place at the end, so a failed or
//! interrupted run never leaves a half-written output (and never destroys the
//! one a previous run left). An existing output folder is replaced only when
//! it holds nothing but what the new output holds: a folder of the user's
//! own files is refused, not swept away.

use std::path::{Path, PathBuf};

use render::RenderError;
use render::image_io::RgbImage;

use crate::error::Result;
use crate::estimate::{Estimate, Photo};

/// Runs `write` on a fresh temporary folder beside `out`, then replaces `out` with it.
pub fn write_folder_atomically(out: &Path, write: impl FnOnce(&Path) -> Result<()>) -> Result<()> {
    let name = out
        .file_name()
        .ok_or_else(|| RenderError::file(out, "an output folder needs a name (not `/` or `..`)"))?;
    let parent = match out.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    if out.exists() && !out.is_dir() {
        return Err(RenderError::file(out, "exists and is not a folder: the output is a folder").into());
    }
    std::fs::create_dir_all(&parent).map_err(|e| RenderError::io(&parent, "create folder", e))?;
    let tmp = parent.join(format!(".{}.partial-{}", name.to_string_lossy(), std::process::id()));
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp).map_err(|e| RenderError::io(&tmp, "remove stale temporary folder", e))?;
    }
    std::fs::create_dir(&tmp).map_err(|e| RenderError::io(&tmp, "create folder", e))?;
    if let Err(e) = write(&tmp).and_then(|()| check_replaceable(out, &tmp)) {
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

/// An existing `out` is replaced only when it holds nothing but entries
/// the new output (`new`) has too, as a previous run's output does: a
/// folder of the user's own files is never swept away.
fn check_replaceable(out: &Path, new: &Path) -> Result<()> {
    if !out.is_dir() {
        return Ok(());
    }
    let entries = std::fs::read_dir(out).map_err(|e| RenderError::io(out, "list", e))?;
    for entry in entries {
        let entry = entry.map_err(|e| RenderError::io(out, "list", e))?;
        if !new.join(entry.file_name()).exists() {
            return Err(RenderError::file(
                entry.path(),
                "is not one of this output's files: an existing folder is replaced only when it holds \
                 nothing else (choose another output folder, or move it away)",
            )
            .into());
        }
    }
    Ok(())
}

/// How to write one output file (to the path it is given).
pub type WriteFile<'a> = Box<dyn FnOnce(&Path) -> Result<()> + 'a>;

/// One output file and how to write it.
pub type FileWriter<'a> = (&'a Path, WriteFile<'a>);

/// Writes each file to a temporary sibling of the same extension (writers
/// pick the format by it); once all are written, renames them into place.
/// On an error no file is replaced and the temporaries are removed.
pub fn write_files_atomically(files: Vec<FileWriter<'_>>) -> Result<()> {
    let mut written: Vec<(PathBuf, &Path)> = Vec::new();
    let mut outcome = Ok(());
    for (path, write) in files {
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        if name.is_empty() {
            outcome = Err(RenderError::file(path, "an output file needs a name").into());
            break;
        }
        let parent = match path.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
            _ => PathBuf::from("."),
        };
        if let Err(e) = std::fs::create_dir_all(&parent) {
            outcome = Err(RenderError::io(&parent, "create folder", e).into());
            break;
        }
        let tmp = parent.join(format!(".partial-{}-{name}", std::process::id()));
        let result = write(&tmp);
        written.push((tmp, path));
        if let Err(e) = result {
            outcome = Err(e);
            break;
        }
    }
    if outcome.is_ok() {
        for (tmp, path) in &written {
            if let Err(e) = std::fs::rename(tmp, path) {
                outcome = Err(RenderError::io(path, "move the new output into place", e).into());
                break;
            }
        }
    }
    for (tmp, _) in &written {
        let _ = std::fs::remove_file(tmp);
    }
    outcome
}

/// Writes `image` to `out` (linear EXR) and its tone-mapped preview beside
/// it (`out` with the extension `png`), both or neither.
pub fn write_image_and_preview(out: &Path, image: &render::image_io::RgbImage) -> Result<()> {
    let png = out.with_extension("png");
    write_files_atomically(vec![
        (out, Box::new(|p| Ok(image.write_exr(p)?))),
        (&png, Box::new(|p| Ok(image.write_png_preview(p, 0.0)?))),
    ])
}

/// Writes an estimate's files into `dir`: `env.exr`, `pose.json`,
/// `confidence.exr`, `uncertainty.exr`, `rerender.exr`, `mask_found.png`, `preview.png`,
/// `report.json` and `camera.json` (the camera it used, the EXIF's when
/// none was given: for `alp insert` and `alp render`).
pub(crate) fn write_estimate(dir: &Path, photo: &Photo, result: &Estimate) -> Result<()> {
    photo.camera.write(dir.join("camera.json"))?;
    result.env.write(dir.join("env.exr"))?;
    result.outline.write_png(dir.join("mask_found.png"))?;
    result.pose.write(dir.join("pose.json"))?;
    result.confidence.write(dir.join("confidence.exr"))?;
    result.uncertainty.write(dir.join("uncertainty.exr"))?;
    result.rerender.write_exr(dir.join("rerender.exr"))?;
    preview(&photo.image, &result.rerender, &result.env.to_image()).write_png_preview(dir.join("preview.png"), 0.0)?;
    let json = serde_json::to_string_pretty(&result.report)
        .map_err(|e| RenderError::io(dir.join("report.json"), "serialise", e))?;
    std::fs::write(dir.join("report.json"), json + "\n")
        .map_err(|e| RenderError::io(dir.join("report.json"), "write", e).into())
}

/// Photo, re-render and env map side by side (the map scaled to the photo's height).
fn preview(photo: &RgbImage, rerender: &RgbImage, env: &RgbImage) -> RgbImage {
    let h = photo.height;
    let env_w = 2 * h;
    let width = 2 * photo.width + env_w;
    let mut out = RgbImage::filled(width, h, [0.0; 3]);
    for r in 0..h {
        for c in 0..photo.width {
            out.pixels[r * width + c] = photo.pixels[r * photo.width + c];
            out.pixels[r * width + photo.width + c] = rerender.pixels[r * photo.width + c];
        }
        for c in 0..env_w {
            let (er, ec) = (r * env.height / h, c * env.width / env_w);
            out.pixels[r * width + 2 * photo.width + c] = env.pixels[er * env.width + ec];
        }
    }
    out
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
        let write_both = |dir: &Path| {
            for name in ["a.txt", "b.txt"] {
                std::fs::write(dir.join(name), "third").map_err(|e| RenderError::io(dir, "write", e))?;
            }
            Ok(())
        };
        write_folder_atomically(&out, write_both).expect("replace");
        assert_eq!(std::fs::read_to_string(out.join("a.txt")).expect("a"), "third");
        // A folder holding anything the new output lacks is the user's: kept, and named.
        std::fs::write(out.join("photo.jpg"), "mine").expect("user's file");
        let refused = write_folder_atomically(&out, write_both).expect_err("a foreign file");
        assert!(refused.to_string().contains("photo.jpg"), "{refused}");
        assert!(out.join("photo.jpg").exists() && out.join("a.txt").exists());
        assert_eq!(std::fs::read_dir(&base).expect("base").count(), 1, "no temporary left");
        // A file where the folder should go is refused before any work.
        let file = base.join("file");
        std::fs::write(&file, "mine").expect("file");
        let refused = write_folder_atomically(&file, |_| panic!("ran")).expect_err("a file");
        assert!(refused.to_string().contains("not a folder"), "{refused}");
        assert_eq!(std::fs::read_to_string(&file).expect("kept"), "mine");
        std::fs::remove_dir_all(&base).expect("clean up");
    }

    #[test]
    fn files_are_replaced_together_or_not_at_all() {
        let base = std::env::temp_dir().join(format!("alp-output-files-test-{}", std::process::id()));
        let (a, b) = (base.join("a.txt"), base.join("b.txt"));
        let writer = |body: &'static str| -> WriteFile<'static> {
            Box::new(move |p: &Path| std::fs::write(p, body).map_err(|e| RenderError::io(p, "write", e).into()))
        };
        write_files_atomically(vec![(&a, writer("a1")), (&b, writer("b1"))]).expect("first write");
        let failing: WriteFile<'static> = Box::new(|p: &Path| Err(RenderError::file(p, "simulated failure").into()));
        assert!(write_files_atomically(vec![(&a, writer("a2")), (&b, failing)]).is_err());
        assert_eq!(
            std::fs::read_to_string(&a).expect("a"),
            "a1",
            "the first file is not replaced alone"
        );
        assert_eq!(
            std::fs::read_dir(&base).expect("base").count(),
            2,
            "no temporary file is left behind"
        );
        std::fs::remove_dir_all(&base).expect("clean up");
    }
}
