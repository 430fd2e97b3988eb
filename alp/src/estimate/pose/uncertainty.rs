//! How far the found pose can move before the photo tells: one standard
//! deviation of each of its six parts in the camera's frame
//! ([`crate::pose_frame`]), from what fixed it.
//!
//! - **The outline.** The pose was fitted to the mask's outline, and the
//!   mask is a hint: traced by hand it strays a pixel or two, smoothly along
//!   the outline. Where the found outline and the mask part, their distance
//!   along the outline's normal is the mask's error there; its spread `s`
//!   and its correlation length `l` along the outline (from the pairs of
//!   points at each distance) give the errors' covariance,
//!   `s^2 exp(-d / l)` plus a pixel's rounding. Each outline point moves
//!   along its normal by `J dp` when the pose moves by `dp` (`J` from the
//!   contour's points projected at poses moved by each part), and the
//!   outline tells the pose with information `J^T C^-1 J`.
//!
//! The photo-scored line searches' curvature (the lean search's score
//! against the lean) is no part of it: on train's traced masks it was
//! eight times narrower than the lean's error (the score peaks where the
//! lean makes up for the other parts' errors, not at the truth).
//!
//! Its inverse is the covariance; a part the outline does not tell, or a
//! turn that maps the probe on to itself (the turn of a probe alike at
//! every turn, any turn of a ball of one metal), has no deviation. The deviations
//! are scaled by `PoseSearchSettings::uncertainty_scale`, set on the train
//! split so that two of them cover the true pose's error as often as a
//! Gaussian's do.

use std::collections::BTreeMap;

use glam::Vec2;
use render::accel::Accel;
use render::camera::Camera;
use render::integrator::{RenderSettings, coverage_mask};
use render::pose::Pose;
use render::probe::ProbeAsset;
use serde::Serialize;

use crate::error::Result;
use crate::estimate::outline::{outline_points, signed_distance, signed_distance_at};
use crate::estimate::photo::Photo;
use crate::estimate::settings::{PoseSearchSettings, SymmetrySettings};
use crate::estimate::symmetry::SelfMap;
use crate::linalg::{cholesky, cholesky_solve, symmetric_eigen};
use crate::pose_frame::{PART_NAMES, PoseFrame, PoseParts};

/// The pose's uncertainty (see the module's description), in `report.json`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PoseUncertainty {
    /// One standard deviation of each part, millimetres and degrees (named
    /// as [`PoseParts`]'s fields); null where neither the outline nor the
    /// photo tells the part.
    pub sigma: BTreeMap<&'static str, Option<f64>>,
    /// The parts' covariance (in the order of `sigma`'s names as
    /// [`PART_NAMES`] lists them), scaled as `sigma` is; an untold part's
    /// row and column are 0.
    pub covariance: [[f64; 6]; 6],
    /// The mask's distance from the found outline, root mean square, pixels
    /// of the working image.
    pub outline_rms_px: f64,
    /// The distance along the outline over which the mask's error keeps
    /// its sign (its correlation length), pixels.
    pub outline_correlation_px: f64,
    /// The outline points compared.
    pub outline_points: usize,
    /// Per told part, how far one deviation moves the probe's surface in
    /// the image (root mean square over its pixels, working pixels).
    pub sigma_px: BTreeMap<&'static str, f64>,
    /// Per part, the surface's motion in the image per unit (pixels per
    /// mm or deg).
    #[serde(skip)]
    motion: [f64; 6],
}

impl PoseUncertainty {
    /// Poses about `pose` (of a probe whose bounding box has its centre at
    /// `centre_mesh`, seen by `camera`) that the photo cannot tell from it,
    /// with their shares of a stacked lighting fit (summing to 1): along
    /// each of the `directions` principal axes of the covariance, measured
    /// by how far they move the probe in the image, that move one
    /// deviation at least `from_px` pixels, a three-point Gauss-Hermite
    /// rule (the pose and `sqrt(3)` deviations either way, shares 2/3 and
    /// 1/6 each: a Gaussian's variance and kurtosis). The pose alone when
    /// none does.
    pub(in crate::estimate) fn draws(
        &self,
        pose: &Pose,
        camera: &Camera,
        centre_mesh: glam::Vec3,
        directions: usize,
        from_px: f64,
    ) -> Vec<(Pose, f64)> {
        let d = self.motion;
        let in_px: [[f64; 6]; 6] =
            std::array::from_fn(|i| std::array::from_fn(|j| d[i] * self.covariance[i][j] * d[j]));
        let (values, vectors) = symmetric_eigen(in_px);
        let mut order: Vec<usize> = (0..6).collect();
        order.sort_by(|&a, &b| values[b].total_cmp(&values[a]));
        let axes: Vec<[f64; 6]> = (order.into_iter().take(directions))
            .filter(|&k| values[k] > 0.0 && values[k].sqrt() >= from_px)
            .map(|k| {
                std::array::from_fn(|i| {
                    if d[i] > 0.0 {
                        vectors[k][i] * values[k].sqrt() / d[i]
                    } else {
                        0.0
                    }
                })
            })
            .collect();
        let frame = PoseFrame::new(camera, pose, centre_mesh, glam::Vec3::Y);
        let mut draws = vec![(*pose, 1.0 - axes.len() as f64 / 3.0)];
        for axis in &axes {
            for side in [1.0, -1.0] {
                let parts = PoseParts::from_array(axis.map(|a| side * 3f64.sqrt() * a));
                draws.push((frame.moved(pose, &parts), 1.0 / 6.0));
            }
        }
        draws
    }
}

/// What the pose's uncertainty is read from: the probe, the pose and the
/// photo (the working image).
pub(in crate::estimate) struct UncertaintyInput<'a> {
    pub(in crate::estimate) asset: &'a ProbeAsset,
    pub(in crate::estimate) pose: &'a Pose,
    pub(in crate::estimate) photo: &'a Photo,
    /// Whether the probe looks the same at every turn about its axis: its
    /// turn is then no part of its pose.
    pub(in crate::estimate) alike_turned: bool,
    /// What tells a turn that maps the probe on to itself.
    pub(in crate::estimate) symmetry: &'a SymmetrySettings,
}

/// The turn (degrees) by which a rotation part is tried for the probe's
/// symmetry: no multiple of a grooved cap's groove period, far enough
/// that a can's logo moves off itself.
const ALIKE_TRIAL_DEG: f64 = 37.0;

/// The pose's uncertainty (see the module's description).
pub(in crate::estimate) fn pose_uncertainty(
    input: &UncertaintyInput,
    settings: &PoseSearchSettings,
) -> Result<PoseUncertainty> {
    let camera = input.photo.camera.with_footprint(0.0)?;
    let (lo, hi) = input.asset.mesh.bounds();
    let frame = PoseFrame::new(&camera, input.pose, 0.5 * (lo + hi), glam::Vec3::Y);
    let outline = outline_evidence(input, &camera, &frame, settings.uncertainty_points)?;
    let (mut information, rms, correlation) = outline.information();
    // A turn that maps the probe on to itself (any turn of a ball of one
    // metal, a smooth cap's about its axis) is no part of its pose.
    let self_map = SelfMap::new(input.asset, input.symmetry);
    let alike = |k: usize| {
        let mut parts = [0.0; 6];
        parts[k] = ALIKE_TRIAL_DEG;
        let moved = frame.moved(input.pose, &PoseParts::from_array(parts));
        self_map.alike(input.pose.rotation.inverse() * moved.rotation)
    };
    for k in (3..6).filter(|&k| (k == 5 && input.alike_turned) || alike(k)) {
        (0..6).for_each(|j| (information[k][j], information[j][k]) = (0.0, 0.0));
    }
    let (covariance, told) = covariance_of(information, settings.uncertainty_scale);
    let sigma = (0..6)
        .map(|k| (PART_NAMES[k], told[k].then(|| covariance[k][k].sqrt())))
        .collect();
    let sigma_px = (0..6)
        .filter(|&k| told[k])
        .map(|k| (PART_NAMES[k], covariance[k][k].sqrt() * outline.motion[k]))
        .collect();
    Ok(PoseUncertainty {
        sigma,
        sigma_px,
        motion: outline.motion,
        covariance,
        outline_rms_px: rms,
        outline_correlation_px: correlation,
        outline_points: outline.residual.len(),
    })
}

/// Largest deviation reported (degrees for a turn): beyond it the part is untold.
const UNTOLD_DEG: f64 = 90.0;

/// The inverse of `information` on the directions it tells, times
/// `scale^2`; per part, whether it is told (its deviation finite and a
/// turn's under [`UNTOLD_DEG`], with no share in an untold direction).
fn covariance_of(information: [[f64; 6]; 6], scale: f64) -> ([[f64; 6]; 6], [bool; 6]) {
    let (values, vectors) = symmetric_eigen(information);
    let largest = values.iter().copied().fold(0.0, f64::max);
    let kept: Vec<usize> = (0..6)
        .filter(|&k| values[k] > 1e-12 * largest && largest > 0.0)
        .collect();
    let mut covariance = [[0.0; 6]; 6];
    for &k in &kept {
        for i in 0..6 {
            for j in 0..6 {
                covariance[i][j] += scale * scale * vectors[k][i] * vectors[k][j] / values[k];
            }
        }
    }
    let untold_share = |i: usize| -> f64 {
        (0..6)
            .filter(|k| !kept.contains(k))
            .map(|k| vectors[k][i].powi(2))
            .sum()
    };
    let told: [bool; 6] = std::array::from_fn(|i| {
        let sigma = covariance[i][i].sqrt();
        untold_share(i) < 0.01 && sigma.is_finite() && (i < 3 || sigma < UNTOLD_DEG)
    });
    for i in 0..6 {
        for j in 0..6 {
            if !told[i] || !told[j] {
                covariance[i][j] = 0.0;
            }
        }
    }
    (covariance, told)
}

/// The outline's evidence: per compared point, its place (pixels), how it
/// moves along its normal per unit of each part (pixels per mm or deg),
/// and the mask's distance beyond it along the normal (pixels).
struct OutlineEvidence {
    points: Vec<Vec2>,
    jacobian: Vec<[f64; 6]>,
    residual: Vec<f64>,
    /// Per part, the root mean square of how far the probe's surface moves
    /// in the image per unit of it (pixels per mm or deg), over points
    /// spread over the found outline's inside.
    motion: [f64; 6],
}

/// Surface points at most over which the image's motion per part is averaged.
const MOTION_POINTS: usize = 400;

/// A pixel's rounding of a mask's outline, as a variance (px^2).
const ROUNDING_PX2: f64 = 1.0 / 12.0;
/// A mask farther than this from the found outline (pixels) is no error of
/// tracing but something else (a cut, a hand over the probe): left out.
const FARTHEST_PX: f64 = 8.0;
/// The parts' step in the Jacobian's central differences (mm, deg).
const STEP: f64 = 0.05;

/// The found outline against the photo's mask, at most `max_points` points
/// spread along it.
fn outline_evidence(
    input: &UncertaintyInput,
    camera: &Camera,
    frame: &PoseFrame,
    max_points: usize,
) -> Result<OutlineEvidence> {
    let found = coverage_mask(input.asset, input.pose, camera, &RenderSettings { spp: 4, seed: 0 });
    let mask = &input.photo.mask;
    let mask_distance = signed_distance(mask);
    let (w, h) = (mask.width, mask.height);
    let points = outline_points(&found);
    let every = points.len().div_ceil(max_points.max(1)).max(1);
    let accel = Accel::new(&input.asset.mesh);
    let to_mesh = input.pose.to_world().inverse();
    let moved: Vec<(Pose, Pose)> = (0..6)
        .map(|k| {
            let step = |s: f64| {
                let mut a = [0.0; 6];
                a[k] = s * STEP;
                frame.moved(input.pose, &PoseParts::from_array(a))
            };
            (step(1.0), step(-1.0))
        })
        .collect();
    // Where a ray through pixel coordinates `at` meets the probe, mesh frame.
    let on_mesh = |at: Vec2| {
        let direction = camera.direction_through(at);
        let (o, d) = (
            to_mesh.transform_point3(camera.origin),
            to_mesh.transform_vector3(direction),
        );
        accel.closest_hit(o, d, f32::INFINITY).map(|hit| o + hit.t * d)
    };
    // How far `on_mesh` moves in the image per unit of each part.
    let rates = |on_mesh: glam::Vec3| -> Option<[Vec2; 6]> {
        let mut rates = [Vec2::ZERO; 6];
        for (k, (plus, minus)) in moved.iter().enumerate() {
            let a = camera.project(plus.transform_point(on_mesh))?;
            let b = camera.project(minus.transform_point(on_mesh))?;
            rates[k] = (a - b) / (2.0 * STEP as f32);
        }
        Some(rates)
    };
    let inside: Vec<usize> = (0..found.inside.len()).filter(|&i| found.inside[i]).collect();
    let mut motion = [0.0; 6];
    let mut counted = 0usize;
    for &i in inside.iter().step_by(inside.len().div_ceil(MOTION_POINTS).max(1)) {
        let at = Vec2::new((i % w) as f32 + 0.5, (i / w) as f32 + 0.5);
        if let Some(rates) = on_mesh(at).and_then(rates) {
            (0..6).for_each(|k| motion[k] += rates[k].length_squared() as f64);
            counted += 1;
        }
    }
    let motion = motion.map(|m| (m / counted.max(1) as f64).sqrt());
    let mut evidence = OutlineEvidence {
        points: Vec::new(),
        jacobian: Vec::new(),
        residual: Vec::new(),
        motion,
    };
    for &(at, normal) in points.iter().step_by(every) {
        let residual = -signed_distance_at(&mask_distance, w, h, at) as f64;
        if residual.abs() > FARTHEST_PX {
            continue;
        }
        // The contour's point under the outline, half a pixel inside it.
        let Some(rates) = on_mesh(at - 0.5 * normal).and_then(rates) else {
            continue;
        };
        evidence.points.push(at);
        evidence.jacobian.push(rates.map(|r| normal.dot(r) as f64));
        evidence.residual.push(residual);
    }
    Ok(evidence)
}

impl OutlineEvidence {
    /// The information the outline gives of the parts, the mask's error's
    /// root mean square and its correlation length (pixels).
    fn information(&self) -> ([[f64; 6]; 6], f64, f64) {
        let n = self.residual.len();
        if n < 8 {
            return ([[0.0; 6]; 6], 0.0, 0.0);
        }
        let mean_square = self.residual.iter().map(|r| r * r).sum::<f64>() / n as f64;
        let correlation = self.correlation_length(mean_square);
        // The errors' correlation along the outline.
        let distance = |i: usize, j: usize| self.points[i].distance(self.points[j]) as f64;
        let kernel: Vec<f64> = (0..n * n)
            .map(|k| (-distance(k / n, k % n) / correlation.max(1e-6)).exp())
            .collect();
        // The fit took up the part of the mask's error that moves the pose
        // (a mask traced a pixel wide all round is a probe nearer the
        // camera, and leaves no residual): the residuals' mean square is
        // the errors' variance times tr((I - H) K) / n, H the fit's hat.
        let variance = mean_square * n as f64 / (n as f64 - self.fitted_share(&kernel)).max(1.0);
        // The errors' covariance: correlated along the outline, plus rounding.
        let mut c: Vec<f64> = kernel.iter().map(|k| variance * k).collect();
        (0..n).for_each(|i| c[i * n + i] += ROUNDING_PX2);
        let Some(l) = cholesky(&c, n) else {
            return ([[0.0; 6]; 6], mean_square.sqrt(), correlation);
        };
        // J^T C^-1 J, a column of J at a time.
        let columns: Vec<Vec<f64>> = (0..6).map(|k| self.jacobian.iter().map(|j| j[k]).collect()).collect();
        let solved: Vec<Vec<f64>> = columns.iter().map(|col| cholesky_solve(&l, n, col)).collect();
        let information =
            std::array::from_fn(|a| std::array::from_fn(|b| (0..n).map(|i| columns[a][i] * solved[b][i]).sum()));
        (information, mean_square.sqrt(), correlation)
    }

    /// `tr(H K)`: how much of errors correlated as `kernel` (n x n, unit
    /// variance) a least-squares fit of the pose to the outline takes up,
    /// `H = J (J^T J)^+ J^T` over the directions the outline tells.
    fn fitted_share(&self, kernel: &[f64]) -> f64 {
        let n = self.residual.len();
        let jtj: [[f64; 6]; 6] =
            std::array::from_fn(|a| std::array::from_fn(|b| self.jacobian.iter().map(|j| j[a] * j[b]).sum()));
        let jtkj: [[f64; 6]; 6] = std::array::from_fn(|a| {
            std::array::from_fn(|b| {
                (0..n)
                    .map(|i| self.jacobian[i][a] * (0..n).map(|k| kernel[i * n + k] * self.jacobian[k][b]).sum::<f64>())
                    .sum()
            })
        });
        let (values, vectors) = symmetric_eigen(jtj);
        let largest = values.iter().copied().fold(0.0, f64::max);
        // tr((J^T J)^+ J^T K J) over the eigenvectors of J^T J.
        (0..6)
            .filter(|&k| values[k] > 1e-12 * largest && largest > 0.0)
            .map(|k| {
                let v = vectors[k];
                let quadratic: f64 = (0..6)
                    .flat_map(|a| (0..6).map(move |b| (a, b)))
                    .map(|(a, b)| v[a] * jtkj[a][b] * v[b])
                    .sum();
                quadratic / values[k]
            })
            .sum()
    }

    /// The distance (pixels) over which the mask's error keeps its sign: at
    /// the first of doubling distances where the pairs' mean product falls
    /// to half the mean square, `d / -ln(rho)` (an exponential's length);
    /// the outline's span when it never does (one offset all round).
    fn correlation_length(&self, mean_square: f64) -> f64 {
        let n = self.residual.len();
        if mean_square <= 0.0 {
            return 1.0;
        }
        let mut bins = [(0.0f64, 0usize); 10];
        let mut span = 0.0f64;
        for i in 0..n {
            for j in i + 1..n {
                let d = self.points[i].distance(self.points[j]) as f64;
                span = span.max(d);
                let bin = (d.max(1.0).log2().floor() as usize).min(bins.len() - 1);
                bins[bin].0 += self.residual[i] * self.residual[j];
                bins[bin].1 += 1;
            }
        }
        for (b, &(sum, count)) in bins.iter().enumerate() {
            if count < 4 {
                continue;
            }
            let rho = sum / count as f64 / mean_square;
            if rho < 0.5 {
                let d = 1.5 * (1u64 << b) as f64;
                return match rho > 0.0 {
                    true => d / -rho.ln(),
                    false => d / std::f64::consts::LN_2,
                };
            }
        }
        span.max(1.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimate::Settings;
    use crate::estimate::testing::can_in_the_courtyard;
    use glam::Vec3;
    use render::image_io::Mask;

    #[test]
    fn a_mask_off_by_a_pixel_or_two_widens_the_pose_s_deviations_across_the_view() {
        let (asset, truth, photo) = can_in_the_courtyard(240, 180, Vec3::new(0.0, 0.12, 0.32));
        // The model's own deviations, not the factor set on train.
        let settings = PoseSearchSettings {
            uncertainty_scale: 1.0,
            ..Settings::default().pose_search
        };
        let symmetry = Settings::default().symmetry;
        let at = |mask: &Mask| {
            let photo = photo.clone().with_mask(mask.clone()).expect("a photo");
            let input = UncertaintyInput {
                asset: &asset,
                pose: &truth,
                photo: &photo,
                alike_turned: false,
                symmetry: &symmetry,
            };
            pose_uncertainty(&input, &settings).expect("an uncertainty")
        };
        // The mask moved right by 2 px: a fit would move the pose so far;
        // one deviation of the model (errors correlated along a stretch of
        // the outline, not all round) reaches a good part of it.
        let (w, h) = (photo.mask.width, photo.mask.height);
        let shifted = Mask::new(
            w,
            h,
            (0..w * h).map(|i| i % w >= 2 && photo.mask.inside[i - 2]).collect(),
        );
        let exact = at(&photo.mask);
        let off = at(&shifted);
        let across = |u: &PoseUncertainty| u.sigma_px["across_x_mm"];
        assert!(exact.outline_rms_px < 0.5, "{exact:?}");
        assert!(across(&exact) < 0.3, "exact mask: {} px", across(&exact));
        assert!(off.outline_rms_px > 1.0 && off.outline_correlation_px > 10.0, "{off:?}");
        assert!(across(&off) > 0.5, "mask 2 px off: {} px", across(&off));
        // Draws along the widest axis: the pose and two about it, shares 2/3, 1/6, 1/6.
        let draws = off.draws(
            &truth,
            &photo.camera,
            0.5 * (asset.mesh.bounds().0 + asset.mesh.bounds().1),
            1,
            0.5,
        );
        assert_eq!(draws.len(), 3);
        assert_eq!(draws[0].0, truth);
        assert!((draws.iter().map(|d| d.1).sum::<f64>() - 1.0).abs() < 1e-12);
        let (lo, hi) = asset.mesh.bounds();
        let frame = PoseFrame::new(&photo.camera, &truth, 0.5 * (lo + hi), Vec3::Y);
        let (a, b) = (frame.parts(&truth, &draws[1].0), frame.parts(&truth, &draws[2].0));
        for (x, y) in a.to_array().into_iter().zip(b.to_array()) {
            assert!((x + y).abs() < 1e-3 * (1.0 + x.abs()), "{a:?} against {b:?}");
        }
        // The exact mask's doubt moves the probe less than the threshold: the pose alone.
        let alone = exact.draws(&truth, &photo.camera, 0.5 * (lo + hi), 1, 0.5);
        assert_eq!(alone.len(), 1, "{exact:?}");
    }

    #[test]
    fn a_ball_of_one_metal_has_a_place_but_no_turn() {
        // The can's camera, a ball where the can stood.
        let (_, _, photo) = can_in_the_courtyard(160, 120, Vec3::new(0.0, 0.12, 0.32));
        let ball = render::procedural::UvSphere {
            radius: 0.03,
            ..Default::default()
        }
        .build();
        let at = Pose::new(glam::Quat::IDENTITY, 1.0, Vec3::new(0.0, 0.06, 0.0));
        let env = render::envmap::EnvMap::new(8, 4, vec![[1.0, 0.9, 0.8]; 32]).expect("a map");
        let photo = crate::estimate::testing::photo_of(&ball, &at, photo.camera, &env, 4);
        let symmetry = Settings::default().symmetry;
        let input = UncertaintyInput {
            asset: &ball,
            pose: &at,
            photo: &photo,
            alike_turned: false,
            symmetry: &symmetry,
        };
        let u = pose_uncertainty(&input, &Settings::default().pose_search).expect("an uncertainty");
        for part in ["in_view_deg", "lean_deg", "turn_deg"] {
            assert_eq!(u.sigma[part], None, "{part}: {u:?}");
        }
        assert!(u.sigma["across_x_mm"].is_some_and(|s| s > 0.0), "{u:?}");
    }

    #[test]
    fn an_untold_direction_has_no_deviation() {
        // The first part told with information 4 (sigma 0.5), the second
        // with 1 and correlated with the third, the turn not at all.
        let mut information = [[0.0; 6]; 6];
        information[0][0] = 4.0;
        information[1][1] = 1.0;
        information[2][2] = 1.0;
        information[1][2] = 0.5;
        information[2][1] = 0.5;
        information[3][3] = 1.0;
        information[4][4] = 1.0;
        let (covariance, told) = covariance_of(information, 1.0);
        assert_eq!(told, [true, true, true, true, true, false]);
        assert!((covariance[0][0] - 0.25).abs() < 1e-12);
        assert!((covariance[1][1] - 1.0 / 0.75).abs() < 1e-9, "{}", covariance[1][1]);
        assert_eq!(covariance[5], [0.0; 6]);
    }
}
