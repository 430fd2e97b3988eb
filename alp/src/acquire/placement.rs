//! The scan's pose and size in the cameras' frame, from every view's
//! silhouette: the first step of the acquisition (PAPER.md, Sec. 3.2). A
//! scan comes in any frame and at any scale, so the fit starts from the
//! views themselves: the centre where the rays through the masks' centres
//! meet, the size at which the scan's mean outline spans the masks, and
//! its axis (of revolution, else of its spread: `symmetry::axis_to_y`)
//! pointed in directions spread over the sphere. Each start is fitted by
//! Adam on the soft masks' L1 and Chamfer losses summed over the views; the
//! best few are fitted on, and the best kept. A turn about an axis of
//! revolution does not show in silhouettes: the texture solve takes it up
//! (a grooved cap's, which shows faintly, the least-squares solve searches).

use glam::{Quat, Vec3};
use rayon::prelude::*;

use autodiff::Tape;
use optim::Solver;
use render::camera::Camera;
use render::image_io::Mask;
use render::mesh::{EdgeAdjacency, Mesh};
use render::pose::Pose;
use render::posed::{MeshVars, PoseVars, PosedMesh, pack_pose, unpack_pose};
use render::silhouette::{ReferenceMask, SilhouettePlan, SilhouetteSettings};

use super::capture::Capture;
use crate::error::{Error, Result};
use crate::estimate::Settings;
use crate::estimate::pose::silhouette::{PoseSteps, pose_adam};
use crate::estimate::settings::OutlineSettings;
use crate::estimate::symmetry;

/// What the placement trades.
#[derive(Clone, Debug)]
pub struct PlacementSettings {
    /// Axis directions tried, spread evenly over the sphere: more find a
    /// scan in an odd frame more surely, at one short fit each.
    pub axes: usize,
    /// Views the starts read (spread over the capture): a few views tell
    /// the orientation apart; every view costs each start's every step.
    pub start_views: usize,
    /// The starts and the kept fits read the scan merged into this many
    /// cells across its longest side (`Mesh::clustered`): the outline
    /// within a cell at a fraction of the triangles; the polish reads it whole.
    pub coarse_cells: usize,
    /// Adam iterations of each start's fit.
    pub start_iters: usize,
    /// Starts fitted on (the best by their short fit's loss).
    pub kept: usize,
    /// Adam iterations of a kept start's fit.
    pub final_iters: usize,
    /// The starts and the kept fits read the views shrunk by a whole
    /// factor to about this height: fewer pixels, about as sure an outline.
    pub coarse_height_px: u32,
    /// Adam iterations of the best kept fit's polish (and its twin's) at
    /// the views' own size and the scan's own triangles.
    pub polish_iters: usize,
    /// The end-for-end twin of the best fit is a candidate when its
    /// silhouette loss is at most this many times the best's: higher
    /// lets the texture solve judge scans whose ends differ more in outline.
    pub twin_loss_ratio: f64,
}

impl Default for PlacementSettings {
    fn default() -> Self {
        PlacementSettings {
            axes: 26,
            start_views: 8,
            coarse_cells: 32,
            start_iters: 40,
            kept: 3,
            final_iters: 150,
            coarse_height_px: 120,
            polish_iters: 40,
            twin_loss_ratio: 2.0,
        }
    }
}

/// The placement found: the scan's mesh-to-world pose and its loss (the
/// views' mean of soft-mask L1 plus Chamfer).
#[derive(Clone, Copy, Debug)]
pub struct Placement {
    pub to_world: Pose,
    pub loss: f64,
}

/// The views' silhouettes as the fit reads them.
struct Silhouettes<'a> {
    mesh: &'a Mesh,
    edges: EdgeAdjacency,
    views: Vec<(Camera, ReferenceMask)>,
}

impl Silhouettes<'_> {
    /// The mean over the views of soft-mask L1 plus Chamfer (in image
    /// diagonals) at the packed pose `x`, recorded on `tape` (cleared: its
    /// buffers are reused from call to call), and its gradient into `g`;
    /// NaN when the scan leaves a view.
    fn loss(&self, tape: &Tape<f64>, x: &[f64], g: &mut [f64]) -> f64 {
        tape.clear();
        let pose = PoseVars::new(tape, x, true);
        let mesh = MeshVars::new(tape, self.mesh);
        let posed = PosedMesh::new(&mesh, &pose);
        let positions = posed.position_values();
        let mut total = tape.constant(&[0.0]);
        for (camera, reference) in &self.views {
            let plan = match SilhouettePlan::with_edges(
                self.mesh,
                &self.edges,
                &positions,
                camera,
                SilhouetteSettings::default(),
            ) {
                Ok(plan) => plan,
                Err(_) => return f64::NAN,
            };
            let soft = plan.soft_mask(&posed);
            let diagonal = ((camera.width as f64).powi(2) + (camera.height as f64).powi(2)).sqrt();
            let (Ok(l1), Ok(chamfer)) = (soft.mask_l1(reference), soft.chamfer(reference)) else {
                return f64::NAN;
            };
            total = total + l1 + chamfer * (1.0 / diagonal);
        }
        let total = total * (1.0 / self.views.len() as f64);
        tape.backward(total);
        g.copy_from_slice(&tape.grad(pose.params));
        tape.item(total)
    }

    /// Adam from `start` for `iters` iterations: the pose and its loss.
    fn fit(&self, start: &Pose, iters: usize, depth: f32, outline: &OutlineSettings) -> Result<(Pose, f64)> {
        let mut adam = pose_adam(iters, depth, PoseSteps::Full, outline)?;
        let tape = Tape::<f64>::new();
        let mut objective = |x: &[f64], g: &mut [f64]| self.loss(&tape, x, g);
        let state = adam
            .minimize(&mut objective, pack_pose(start).to_vec())
            .map_err(Error::solver("placement"))?;
        Ok((unpack_pose(&state.best_x), state.best_value))
    }
}

/// Places the capture's scan in the cameras' frame (see the module's
/// description): the best fit, and its end-for-end twin when its outline
/// fits nearly as well (best first).
pub fn place(capture: &Capture, settings: &PlacementSettings) -> Result<Vec<Placement>> {
    let (lo, hi) = capture.mesh.bounds();
    let clustered = capture
        .mesh
        .clustered((hi - lo).max_element() / settings.coarse_cells.max(1) as f32);
    let silhouettes = |mesh, reduced_px: Option<u32>, views: usize| -> Result<Silhouettes> {
        let (n, count) = (capture.views.len(), views.clamp(1, capture.views.len()));
        let views = (0..count)
            .map(|k| &capture.views[k * n / count])
            .map(|v| {
                let (camera, mask) = match reduced_px {
                    Some(px) => reduced(&v.photo.camera, &v.photo.mask, px)?,
                    None => (v.photo.camera, v.photo.mask.clone()),
                };
                Ok((camera, ReferenceMask::new(&mask)?))
            })
            .collect::<Result<_>>()?;
        Ok(Silhouettes {
            mesh,
            edges: EdgeAdjacency::new(mesh),
            views,
        })
    };
    let all = capture.views.len();
    let coarse_px = Some(settings.coarse_height_px);
    let few = silhouettes(&clustered, coarse_px, settings.start_views)?;
    let (coarse, full) = (
        silhouettes(&clustered, coarse_px, all)?,
        silhouettes(&capture.mesh, None, all)?,
    );
    let centre = capture.centre()?;
    let scan_centre = 0.5 * (lo + hi);
    let scale = world_radius(capture, centre) / outline_radius(&capture.mesh).max(f32::MIN_POSITIVE);
    let depth = capture
        .views
        .iter()
        .map(|v| (v.photo.camera.origin - centre).length())
        .sum::<f32>()
        / capture.views.len() as f32;
    let estimate = Settings::default();
    let to_y = symmetry::axis_to_y(&capture.mesh, &estimate.symmetry);
    let outline = estimate.outline;
    let starts: Vec<Pose> = spread_directions(settings.axes)
        .into_iter()
        .map(|axis| {
            let rotation = Quat::from_rotation_arc(Vec3::Y, axis) * to_y;
            Pose::new(rotation, scale, centre - scale * (rotation * scan_centre))
        })
        .collect();
    let mut fitted: Vec<(Pose, f64)> = starts
        .par_iter()
        .map(|start| few.fit(start, settings.start_iters, depth, &outline))
        .collect::<Result<_>>()?;
    fitted.retain(|(_, loss)| loss.is_finite());
    fitted.sort_by(|a, b| a.1.total_cmp(&b.1));
    fitted.truncate(settings.kept.max(1));
    let best = fitted
        .par_iter()
        .map(|(pose, _)| coarse.fit(pose, settings.final_iters, depth, &outline))
        .collect::<Result<Vec<_>>>()?
        .into_iter()
        .filter(|(_, loss)| loss.is_finite())
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .ok_or_else(|| Error::invalid("capture", "no start kept the scan in every view"))?;
    // The best fit turned end for end about its centre, fitted in turn: a
    // scan whose two ends cast near the same outline (a can, a cap) is told
    // apart by its texture solve.
    let axis = to_y.inverse() * Vec3::Y;
    let across = axis.any_orthonormal_vector();
    let flipped = Pose::new(
        best.0.rotation * Quat::from_axis_angle(across, std::f32::consts::PI),
        best.0.scale,
        best.0.transform_point(scan_centre)
            - best.0.scale * (best.0.rotation * Quat::from_axis_angle(across, std::f32::consts::PI) * scan_centre),
    );
    let (twin, _) = coarse.fit(&flipped, settings.final_iters, depth, &outline)?;
    let (best, twin) = rayon::join(
        || full.fit(&best.0, settings.polish_iters, depth, &outline),
        || full.fit(&twin, settings.polish_iters, depth, &outline),
    );
    let (best, twin) = (best?, twin?);
    let mut placements = vec![Placement {
        to_world: best.0,
        loss: best.1,
    }];
    if twin.1.is_finite() && twin.1 <= settings.twin_loss_ratio * best.1 {
        placements.push(Placement {
            to_world: twin.0,
            loss: twin.1,
        });
    }
    placements.sort_by(|a, b| a.loss.total_cmp(&b.loss));
    Ok(placements)
}

/// `camera` and `mask` shrunk by the largest whole factor that divides
/// both sides and leaves at least `height_px` rows (the same projection: a
/// factor that divides both keeps the aspect); a pixel of the shrunk mask
/// is inside when at least half of its block is.
fn reduced(camera: &Camera, mask: &Mask, height_px: u32) -> Result<(Camera, Mask)> {
    let (w, h) = (camera.width, camera.height);
    let factor = (1..=(h / height_px.max(1)).max(1))
        .rev()
        .find(|f| w % f == 0 && h % f == 0)
        .unwrap_or(1);
    let (rw, rh) = (w / factor, h / factor);
    let shrunk = Camera::new(rw, rh, camera.fov_y_deg, camera.origin, camera.target, camera.up)?;
    let f = factor as usize;
    let inside = (0..(rw * rh) as usize)
        .map(|p| {
            let (x, y) = (p % rw as usize, p / rw as usize);
            let count = (0..f * f)
                .filter(|k| mask.inside[(y * f + k / f) * mask.width + x * f + k % f])
                .count();
            2 * count >= f * f
        })
        .collect();
    Ok((shrunk, Mask::new(rw as usize, rh as usize, inside)))
}

/// The radius (world units) of a sphere at `centre` whose silhouette has
/// the masks' mean area.
fn world_radius(capture: &Capture, centre: Vec3) -> f32 {
    let radii: Vec<f32> = capture
        .views
        .iter()
        .map(|v| {
            let camera = &v.photo.camera;
            let focal_px = 0.5 * camera.height as f32 / (0.5 * camera.fov_y_deg.to_radians()).tan();
            let mask_radius_px = (v.photo.mask.count() as f32 / std::f32::consts::PI).sqrt();
            mask_radius_px / focal_px * (camera.origin - centre).length()
        })
        .collect();
    radii.iter().sum::<f32>() / radii.len() as f32
}

/// The radius of the disc whose area is the scan's mean outline area over
/// all view directions: for a convex body a quarter of its surface area
/// (Cauchy's formula), so `sqrt(area / 4 pi)`. The start's size matches
/// the masks' mean area with it: a bounding sphere overstates a squat
/// probe's outline (a thermos cap started at 55 % of its size, which 40
/// steps of every start could not close).
fn outline_radius(mesh: &Mesh) -> f32 {
    let area: f32 = mesh
        .triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
            0.5 * (b - a).cross(c - a).length()
        })
        .sum();
    (area / (4.0 * std::f32::consts::PI)).sqrt()
}

/// `n` directions spread evenly over the sphere (a Fibonacci lattice).
fn spread_directions(n: usize) -> Vec<Vec3> {
    let golden = std::f32::consts::PI * (3.0 - 5f32.sqrt());
    (0..n.max(1))
        .map(|k| {
            let y = 1.0 - 2.0 * (k as f32 + 0.5) / n.max(1) as f32;
            let r = (1.0 - y * y).max(0.0).sqrt();
            Vec3::new(r * (golden * k as f32).cos(), y, r * (golden * k as f32).sin())
        })
        .collect()
}
