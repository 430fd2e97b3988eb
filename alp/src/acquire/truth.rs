//! An acquisition against the truth, when the capture holds it (`alp synth
//! captures` writes `true_pose.json` and `true_probe/`): the pose's error,
//! and the textures' RMSE over the surface the views see. The textures are
//! compared where the same camera ray meets the scan at the found pose and
//! at the true one: a turn about a probe's axis of revolution, which no
//! view can tell, moves the acquired texture with the mesh and costs
//! nothing here, as it costs nothing to an estimate that uses the asset.

use std::path::Path;

use glam::Vec3;
use render::integrator::{PrimaryHits, RenderSettings};
use render::pose::Pose;
use render::probe::ProbeAsset;
use serde::Serialize;

use super::capture::Capture;
use super::material::hit_uv;
use crate::error::Result;
use crate::estimate::Settings;
use crate::estimate::symmetry;

/// The truth of a synthetic capture.
pub struct Truth {
    /// The scan's true mesh-to-world pose.
    pub to_world: Pose,
    /// The probe with its true textures (the scan's mesh and `vt`).
    pub probe: ProbeAsset,
}

impl Truth {
    /// `true_pose.json` and `true_probe/` of the capture folder `dir`, when both are there.
    pub fn read(dir: &Path) -> Result<Option<Self>> {
        let (pose, probe) = (dir.join("true_pose.json"), dir.join("true_probe"));
        if !pose.is_file() || !probe.is_dir() {
            return Ok(None);
        }
        Ok(Some(Truth {
            to_world: Pose::read(pose)?,
            probe: ProbeAsset::read(probe)?,
        }))
    }
}

/// How far an acquisition is from the truth.
#[derive(Clone, Debug, Serialize)]
pub struct TruthErrors {
    /// The angle between the found and the true directions of the scan's
    /// axis (of revolution, else of its spread), degrees (180 for a scan
    /// placed end for end).
    pub axis_deg: f64,
    /// The found centre's (the vertices' mean's) distance from the true
    /// one, in % of the scan's true bounding radius.
    pub centre_pct: f64,
    /// `|found scale / true scale - 1|`, %.
    pub scale_pct: f64,
    /// RMSE of the albedo (over channels) where the views see the surface.
    pub albedo_rmse: f64,
    pub roughness_rmse: f64,
    pub visibility_rmse: f64,
    /// Camera rays compared.
    pub rays: usize,
}

impl TruthErrors {
    /// The errors of `asset` placed at `to_world` against `truth`.
    pub fn of(capture: &Capture, truth: &Truth, asset: &ProbeAsset, to_world: &Pose) -> Self {
        let mesh = &capture.mesh;
        let axis = symmetry::axis_to_y(mesh, &Settings::default().symmetry).inverse() * Vec3::Y;
        // The vertices' mean: on the axis of a scan of revolution, so that
        // the turn about it no view can tell does not move it.
        let centre = mesh.positions.iter().sum::<Vec3>() / mesh.positions.len().max(1) as f32;
        let (lo, hi) = mesh.bounds();
        let radius = 0.5 * (hi - lo).length();
        let found_axis = (to_world.rotation * axis).as_dvec3();
        let true_axis = (truth.to_world.rotation * axis).as_dvec3();
        // Signed: a scan placed end for end is wrong by 180 degrees.
        let axis_deg = found_axis.angle_between(true_axis).to_degrees();
        let centre_pct = 100.0
            * (to_world.transform_point(centre) - truth.to_world.transform_point(centre)).length() as f64
            / (truth.to_world.scale * radius) as f64;
        let scale_pct = 100.0 * (to_world.scale as f64 / truth.to_world.scale as f64 - 1.0).abs();
        let found_positions: Vec<Vec3> = mesh.positions.iter().map(|&p| to_world.transform_point(p)).collect();
        let true_positions: Vec<Vec3> = mesh
            .positions
            .iter()
            .map(|&p| truth.to_world.transform_point(p))
            .collect();
        let settings = RenderSettings {
            spp: 1,
            seed: TRUTH_SEED,
        };
        let (mut sums, mut rays) = ([0.0f64; 3], 0usize);
        for view in &capture.views {
            let camera = &view.photo.camera;
            let found = PrimaryHits::trace(mesh, &found_positions, camera, &settings);
            let truth_hits = PrimaryHits::trace(mesh, &true_positions, camera, &settings);
            let mut true_sample = vec![None; camera.width as usize * camera.height as usize];
            for (k, &s) in truth_hits.segment.iter().enumerate() {
                true_sample[truth_hits.pixels[s as usize] as usize] = Some(k);
            }
            for (k, &s) in found.segment.iter().enumerate() {
                let pixel = found.pixels[s as usize] as usize;
                let Some(t) = true_sample[pixel] else { continue };
                if !view.photo.mask.inside[pixel] {
                    continue;
                }
                let a = asset.material(hit_uv(mesh, &found_positions, found.triangle[k], found.point[k]));
                let b = truth.probe.material(hit_uv(
                    mesh,
                    &true_positions,
                    truth_hits.triangle[t],
                    truth_hits.point[t],
                ));
                sums[0] += (0..3).map(|c| (a.albedo[c] - b.albedo[c]).powi(2) as f64).sum::<f64>() / 3.0;
                sums[1] += (a.roughness - b.roughness).powi(2) as f64;
                sums[2] += (a.visibility - b.visibility).powi(2) as f64;
                rays += 1;
            }
        }
        let rmse = |s: f64| (s / rays.max(1) as f64).sqrt();
        TruthErrors {
            axis_deg,
            centre_pct,
            scale_pct,
            albedo_rmse: rmse(sums[0]),
            roughness_rmse: rmse(sums[1]),
            visibility_rmse: rmse(sums[2]),
            rays,
        }
    }
}

/// The seed of the rays the textures are compared along.
const TRUTH_SEED: u64 = 0x7207;
