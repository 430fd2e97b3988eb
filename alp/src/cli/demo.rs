//! `alp demo`: the first run, on bundled data.

use std::path::Path;

use crate::Result;

/// Runs the demo into `out` and prints where to look.
pub fn run(out: &Path) -> Result<()> {
    eprintln!("alp demo: rendering a photo of a soda can, estimating its pose and lighting (about half a minute)");
    let report = crate::demo::run(out)?;
    let shown = out.canonicalize().unwrap_or_else(|_| out.to_path_buf());
    println!(
        "Relighting errors of the estimated map (angular, degrees): mirror {:.2}, shiny {:.2}, diffuse {:.2}",
        report.mirror.angular_deg, report.shiny.angular_deg, report.diffuse.angular_deg
    );
    println!(
        "Pose errors: rotation {:.2} deg, translation {:.1} mm; re-render PSNR {:.1} dB",
        report.pose.rotation_deg, report.pose.translation_mm, report.psnr_db
    );
    println!("Look at {}", shown.join("index.html").display());
    println!("  scene/     the photo, its mask, camera, true pose and map");
    println!("  estimate/  env.exr, pose.json, confidence.exr, rerender.exr, mask_found.png, report.json");
    println!("  report.json, and the figures as PNG");
    Ok(())
}
