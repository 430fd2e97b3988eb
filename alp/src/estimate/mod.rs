//! Single-image estimation of the probe's pose and the scene's lighting
//! (PAPER.md, "Single-image estimation"), as the method's stages:
//!
//! 1. [`photo`]: the photo, its mask and camera; clipped pixels; the working
//!    image (box-filtered when the mask is large).
//! 2. [`symmetry`]: the probe's axis and whether a turn about it shows.
//! 3. [`pose::orientation`]: axis hypotheses from the mask
//!    ([`pose::hypotheses`]), each fitted to the outline
//!    ([`pose::silhouette`]); the kept axes' turns ranked by colour
//!    ([`pose::ranking`]).
//! 4. [`lighting`]: at a fixed pose the image is linear in the env map; the
//!    map is a bounded least-squares solve over the recorded transport. A
//!    pilot map guides the later solves' samples.
//! 5. [`pose::judgement`]: the photo judges what the outline cannot tell: the
//!    size, the lean towards the view ray, the chosen pose against its
//!    rivals, a small probe's refinement.
//! 6. The final map at more samples, guided by the kept pose's map; the
//!    [`report`].
//!
//! Every tuned number lives in [`settings`]. `docs/method.md` explains each
//! stage and the measurements behind its choices.

pub mod blur;
pub mod cli;
pub mod decisions;
pub mod lighting;
pub mod outline;
pub mod photo;
pub mod pose;
pub mod probe;
pub mod probe_box;
pub mod report;
pub mod settings;
pub mod symmetry;

use std::time::Instant;

use glam::Vec3;
use render::bsdf::{Bsdf, GgxMetal};
use render::integrator::{RenderSettings, coverage_mask, render_image};
use render::probe::ProbeAsset;
use render::silhouette::ReferenceMask;

pub use lighting::working_height;
pub use photo::{Photo, WorkingPhoto, mask_on_border, working_factor};
pub use probe::ProbeBsdf;
pub use report::{Estimate, PhaseReport, Report};
pub use settings::{Quality, Settings};

use probe::Probe;

use lighting::{ClippedLight, LightingTerms, MapSizes, OutputSolve, env_from_texels, final_fit, lighting_report};
use pose::orientation::PoseSearch;
use pose::uncertainty::{UncertaintyInput, pose_uncertainty};
use pose::{PoseFound, PoseInput};
use report::{PhaseLog, PoseRecord, WorkingImage};

use crate::error::{Error, Result};

/// Estimates the pose and the lighting from `photo` of `probe`, a metal of
/// the paper's reflectance model ([`GgxMetal`]).
pub fn estimate(photo: &Photo, asset: &ProbeAsset, settings: &Settings) -> Result<Estimate> {
    estimate_with(photo, asset, &GgxMetal, settings, &mut |_, _, _| {})
}

/// [`estimate`] of a probe whose reflectance `bsdf` models (every render of
/// it, in the outline fits, the light transport and the re-render, uses it),
/// calling `on_phase(phase, done, expected)` as each phase ends: what a
/// progress bar follows. `expected` starts at [`Settings::phase_count`] and
/// grows as the run learns how many axis hypotheses and refits the photo
/// needs.
pub fn estimate_with(
    photo: &Photo,
    asset: &ProbeAsset,
    bsdf: &dyn ProbeBsdf,
    settings: &Settings,
    on_phase: &mut dyn FnMut(&PhaseReport, usize, usize),
) -> Result<Estimate> {
    let t0 = Instant::now();
    // The objective's lighting terms, compiled before any work is done.
    let terms = LightingTerms::compile(settings.objective.clone(), settings.lighting.method)?;
    let out_size = settings.env_size;
    if out_size.0 != 2 * out_size.1 || out_size.1 < 2 {
        let (w, h) = out_size;
        return Err(Error::invalid("env size", format!("{w}x{h} is not a 2:1 map")));
    }
    // The probe, its axis turned to mesh +Y (the search turns it about +Y).
    let (to_y, along_y) = symmetry::along_y(asset, &settings.symmetry);
    let asset = along_y.as_ref().unwrap_or(asset);
    let known_pose = settings.known_pose.map(|pose| symmetry::turned_to_y(&pose, to_y));
    let probe = Probe::new(asset, bsdf, &settings.symmetry);
    // The photo's blur: given, or read on the probe's edges. The pose
    // searches model a reading from `min_blur_px`; the photo checks it at
    // the found pose for the output map.
    let reading = match settings.photo.blur_px {
        Some(blur_px) => blur::BlurEstimate {
            blur_px,
            edge_width_px: 0.0,
            edges: 0,
        },
        None => blur::photo_blur(photo, &settings.photo.blur)?,
    };
    let search_blur = match settings.photo.blur_px {
        Some(given) => given,
        None if reading.blur_px >= settings.photo.blur.min_blur_px => reading.blur_px,
        None => 0.0,
    };
    let blurred = match search_blur > 0.0 {
        true => Some(photo.clone().with_blur(search_blur)?),
        false => None,
    };
    // The photo as the estimate works on it.
    let full = blurred.as_ref().unwrap_or(photo);
    let working = WorkingPhoto::new(full, &settings.photo)?;
    let (photo, clipped) = (working.photo(full), &working.clipped);
    let reference = ReferenceMask::new(&photo.mask)?;
    let sizes = MapSizes::new(asset, &settings.lighting)?;
    let mut phases = PhaseLog::new(settings.phase_count(), on_phase);
    // The pose, by the method the settings select.
    let input = PoseInput {
        probe: &probe,
        photo,
        reference: &reference,
        clipped,
        sizes: &sizes,
        settings,
        known_pose,
    };
    let PoseFound {
        search: searched,
        judged,
    } = pose::method(settings.pose_method).find(&input, &mut phases)?;
    // The blur the photo chooses at the found pose.
    let t2 = Instant::now();
    let blur_choice = match (settings.photo.blur_px, judged.pilot.as_deref()) {
        (None, Some(map)) if reading.blur_px >= settings.photo.blur.test_from_px => {
            let sharp = photo.clone().with_blur(0.0)?;
            let input = blur::BlurTestInput {
                probe: &probe,
                photo: &sharp,
                factor: working.factor,
                clipped,
                pose: &judged.pose,
                map,
                work: sizes.search,
            };
            let choice = blur::blur_by_photo(&input, reading.blur_px, settings)?;
            phases.push(choice.phase_report(t2));
            Some(choice)
        }
        _ => None,
    };
    let blur_px = blur_choice.as_ref().map_or(search_blur, |c| c.blur_px);
    let chosen = match blur_px == search_blur {
        true => None,
        false => Some(photo.clone().with_blur(blur_px / working.factor as f32)?),
    };
    let photo = chosen.as_ref().unwrap_or(photo);
    // How far the pose can move before the photo tells.
    let pose_uncertainty = match settings.known_pose {
        Some(_) => None,
        None => {
            let input = UncertaintyInput {
                asset,
                pose: &judged.pose,
                photo,
                alike_turned: probe.alike_turned == Some(true) || searched.as_ref().is_some_and(|s| s.symmetric),
                symmetry: &settings.symmetry,
            };
            Some(pose_uncertainty(&input, &settings.pose_search)?)
        }
    };
    // The output map, at the poses the photo cannot tell from the found one.
    let poses = match &pose_uncertainty {
        Some(uncertainty) => {
            let (lo, hi) = asset.mesh.bounds();
            let lighting = &settings.lighting;
            let camera = photo.camera.with_footprint(0.0)?;
            let (axes, from_px) = (lighting.pose_draw_axes, lighting.pose_draw_from_px);
            uncertainty.draws(&judged.pose, &camera, 0.5 * (lo + hi), axes, from_px)
        }
        None => vec![(judged.pose, 1.0)],
    };
    let t2 = Instant::now();
    let pilot = judged.pilot.as_deref();
    let output = OutputSolve { pilot, terms: &terms };
    let (fit, final_spp) = final_fit(&probe, photo, clipped, &poses, output, &sizes, settings)?;
    let final_psnr = fit.psnr_db();
    phases.push(lighting_report("lighting_final", &fit, t2));
    let clipped_lights = ClippedLight::found(
        &fit.transport,
        &fit.data,
        &fit.hits.pixels,
        (fit.hits.width, fit.hits.height),
        &env_from_texels(&fit.env, sizes.work.0, sizes.work.1)?,
        &fit.rendered,
    );
    let maps = fit.output_maps(sizes.work, out_size, &settings.lighting)?;
    // The probe's outline at the found pose (`mask_found.png`): the sharp
    // camera's pixels it covers at least half of.
    let outline = {
        let sharp = full.camera.with_footprint(0.0)?;
        coverage_mask(asset, &judged.pose, &sharp, &RenderSettings { spp: 4, seed: 0 })
    };
    let rerender = match working.photo {
        None => fit.rerender(),
        // The fit's pixels are blocks of the photo's: the photo's own size
        // is rendered anew, under the map at the working resolution.
        Some(_) => {
            let map = env_from_texels(&fit.env, sizes.work.0, sizes.work.1)?;
            drop(fit);
            let render = RenderSettings {
                spp: settings.photo.rerender_spp,
                seed: settings.seed.wrapping_add(80),
            };
            let camera = full.camera.with_footprint(blur_px)?;
            render_image(asset, &judged.pose, &camera, &map, bsdf, &render).0
        }
    };
    let (axes, starts, chosen_start) = searched.map(PoseSearch::into_accounts).unwrap_or_default();
    let (decisions, warnings) = decisions::decisions(
        &decisions::Choices {
            rival: judged.rival.as_ref(),
            blur: blur_choice.as_ref(),
            clipped_lights: &clipped_lights,
            pose_uncertainty: pose_uncertainty.as_ref(),
        },
        settings,
    );
    let report = Report {
        settings: settings.clone(),
        bsdf: Bsdf::<f32>::name(bsdf),
        axes,
        starts,
        chosen_start,
        rival: judged.rival,
        size: judged.size,
        lean: judged.lean,
        photo_refinement: judged.refinement,
        pose_uncertainty,
        working_resolution: sizes.work,
        search_resolution: sizes.search,
        min_roughness: sizes.min_roughness,
        probe_axis: (to_y.inverse() * Vec3::Y).to_array(),
        mask_on_border_pixels: mask_on_border(&full.mask),
        working_image: WorkingImage::of(photo, working.factor),
        clipped_pixels: clipped.iter().filter(|&&c| c).count(),
        clipped_lights,
        blur: reading,
        blur_choice,
        blur_px,
        final_spp,
        final_poses: poses
            .iter()
            .map(|(pose, share)| (PoseRecord::from(pose), *share))
            .collect(),
        decisions,
        warnings,
        objective: report::ObjectiveReport::new(&settings.objective, terms.is_exact()),
        phases: phases.phases,
        psnr_db: final_psnr,
        wall_s: t0.elapsed().as_secs_f64(),
    };
    Ok(Estimate {
        env: maps.env,
        confidence: maps.confidence,
        uncertainty: maps.uncertainty,
        // A known pose as given; a found one of the mesh as it is.
        pose: match (settings.known_pose, &along_y) {
            (Some(known), _) => known,
            (None, None) => judged.pose,
            (None, Some(_)) => symmetry::turned_back(&judged.pose, to_y),
        },
        rerender,
        outline,
        report,
    })
}

/// What the stages' tests share.
#[cfg(test)]
mod testing {
    use render::camera::Camera;
    use render::envmap::EnvMap;
    use render::pose::Pose;

    use super::*;

    /// The probe `asset` as the estimate holds it.
    pub(super) fn probe_of(asset: &ProbeAsset) -> Probe<'_> {
        Probe {
            turns_show: false,
            ..Probe::new(asset, &GgxMetal, &Settings::default().symmetry)
        }
    }

    /// The procedural can turned 0.3 rad about its axis, and its photo of
    /// `width x height` from `eye`, looking at its middle, under the
    /// courtyard (32 rows), 16 samples per pixel: its label and the light
    /// tell its turn.
    pub(super) fn can_in_the_courtyard(width: u32, height: u32, eye: glam::Vec3) -> (ProbeAsset, Pose, Photo) {
        use glam::{Quat, Vec3};
        let asset = render::procedural::SodaCan::default().build();
        let truth = Pose::new(Quat::from_rotation_y(0.3), 1.0, Vec3::ZERO);
        let camera = Camera::new(width, height, 40.0, eye, Vec3::new(0.0, 0.06, 0.0), Vec3::Y).expect("camera");
        let env_path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/envmaps/courtyard.exr");
        let env = EnvMap::read(env_path).expect("bundled env map").downsample(32);
        let photo = photo_of(&asset, &truth, camera, &env, 16);
        (asset, truth, photo)
    }

    /// A photo of `asset` at `truth` through `camera` under `env`, `spp`
    /// samples per pixel.
    pub(super) fn photo_of(asset: &ProbeAsset, truth: &Pose, camera: Camera, env: &EnvMap, spp: u32) -> Photo {
        let (image, mask) = render_image(asset, truth, &camera, env, &GgxMetal, &RenderSettings { spp, seed: 1 });
        Photo::new(image, mask, camera).expect("a photo")
    }
}
