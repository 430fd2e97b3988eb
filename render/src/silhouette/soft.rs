//! The differentiable half: the soft mask of the band pixels and the mask losses, composed from
//! tape ops (their gradients come from the ops' own vector-Jacobian products).

use autodiff::{Real, Tape, Var, Vec3 as Vec3Var};
use glam::Vec3;

use super::plan::SilhouettePlan;
use super::reference::ReferenceMask;
use super::{MIN_SEGMENT_LENGTH2, pixel_centre};
use crate::camera::Camera;
use crate::error::Result;
use crate::posed::PosedMesh;

/// Distances below this (pixels) are below the raster's resolution: the symmetric Chamfer term
/// uses `sqrt(d^2 + eps^2)`, smooth where a reference pixel touches the rendered silhouette.
const CHAMFER_EPS_PX: f64 = 0.5;

/// From a pixel centre to the edge of its pixel, pixels.
const HALF_PIXEL: f32 = 0.5;

/// Pixel coordinates (x right, y down) of world points: `camera.project` composed from tape ops.
///
/// `x = W/2 + f (d . right) / (d . forward)`, `y = H/2 - f (d . up) / (d . forward)`, with
/// `d = p - origin` and the focal length `f = H / (2 tan(fov_y / 2))` in pixels. Points must be in
/// front of the camera.
pub fn project_to_pixels<'t, T: Real>(camera: &Camera, points: Vec3Var<'t, T>) -> (Var<'t, T>, Var<'t, T>) {
    let focal = camera.height as f64 / (2.0 * (0.5 * (camera.fov_y_deg as f64).to_radians()).tan());
    let o = camera.origin.as_dvec3();
    let d = Vec3Var::new(points.x - T::c(o.x), points.y - T::c(o.y), points.z - T::c(o.z));
    let dot = |axis: Vec3| {
        let a = axis.as_dvec3();
        d.x * T::c(a.x) + d.y * T::c(a.y) + d.z * T::c(a.z)
    };
    let depth = dot(camera.forward);
    let x = (dot(camera.right) / depth).affine(T::c(focal), T::c(0.5 * camera.width as f64));
    let y = (dot(camera.image_up) / depth).affine(T::c(-focal), T::c(0.5 * camera.height as f64));
    (x, y)
}

/// Squared distance from points `p` to the lines through `a` and `b`, or to `a` where `b = a`
/// (the plan's nearest feature, see `nearest_feature`):
/// `t = (p - a).(b - a) / max(|b - a|^2, tiny)`, `d^2 = |p - a - t (b - a)|^2`
/// (a vertex feature has `b - a = 0`, so `t (b - a)` and its gradient vanish).
fn feature_distance2<'t, T: Real>(
    a: (Var<'t, T>, Var<'t, T>),
    b: (Var<'t, T>, Var<'t, T>),
    p: (Var<'t, T>, Var<'t, T>),
) -> Var<'t, T> {
    let (ex, ey) = (b.0 - a.0, b.1 - a.1);
    let (wx, wy) = (p.0 - a.0, p.1 - a.1);
    let length2 = ex.mul_add(ex, ey * ey).max_scalar(T::c(MIN_SEGMENT_LENGTH2 as f64));
    let t = wx.mul_add(ex, wy * ey) / length2;
    let (dx, dy) = (wx - t * ex, wy - t * ey);
    dx.mul_add(dx, dy * dy)
}

/// A constant array on `tape` from f32 values.
fn constant<'t, T: Real>(tape: &'t Tape<T>, values: &[f32]) -> Var<'t, T> {
    let v: Vec<T> = values.iter().map(|&x| T::c(x as f64)).collect();
    tape.constant(&v)
}

/// The soft rendered mask: soft coverage of the band pixels on a tape (see the module docs of
/// `silhouette`), hard coverage elsewhere.
#[derive(Clone, Copy, Debug)]
pub struct SoftMask<'p, 't, T: Real> {
    plan: &'p SilhouettePlan,
    /// Projected vertices, pixels.
    x: Var<'t, T>,
    y: Var<'t, T>,
    /// Coverage in [0, 1] of each band pixel, in the order of [`SilhouettePlan::band_pixels`].
    pub band_coverage: Var<'t, T>,
}

impl SilhouettePlan {
    /// Records the soft mask of the posed mesh (the plan's mesh, at a pose near the plan's).
    ///
    /// Panics when the posed mesh does not have the plan's vertex count (a programming error).
    pub fn soft_mask<'t, T: Real>(&self, posed: &PosedMesh<'t, T>) -> SoftMask<'_, 't, T> {
        let n = posed.positions.x.len();
        assert_eq!(
            n, self.vertex_count,
            "soft_mask: posed mesh has {n} vertices, the plan {}",
            self.vertex_count
        );
        let tape = posed.positions.x.tape();
        let (x, y) = project_to_pixels(&self.camera, posed.positions);
        let p = &self.pairs;
        let (start, end) = (constant(tape, &p.feature_start), constant(tape, &p.feature_end));
        let (px, py) = (constant(tape, &p.x), constant(tape, &p.y));
        let signed_inv_sigma = constant(tape, &p.signed_inv_sigma);
        let band_slot = constant(tape, &p.band_slot);
        let d2 = feature_distance2(
            (x.gather(start), y.gather(start)),
            (x.gather(end), y.gather(end)),
            (px, py),
        );
        // sigmoid(z) = 1 - exp(-softplus(z)), scattered to the band (a pixel without a pair
        // sums nothing: coverage 0).
        let log_uncovered = (d2 * signed_inv_sigma)
            .softplus()
            .segmented_sum(band_slot, self.band.len());
        let band_coverage = (-log_uncovered).exp().rsub(T::one());
        SoftMask {
            plan: self,
            x,
            y,
            band_coverage,
        }
    }
}

impl<'p, 't, T: Real> SoftMask<'p, 't, T> {
    /// The plan this mask was recorded from.
    pub fn plan(&self) -> &'p SilhouettePlan {
        self.plan
    }

    /// Row-major indices of the band pixels (the order of `band_coverage`).
    pub fn band_pixels(&self) -> &'p [u32] {
        &self.plan.band
    }

    /// The whole mask's values (computes the band): soft in the band, hard elsewhere.
    pub fn to_image(&self) -> Vec<f64> {
        let mut image: Vec<f64> = self.plan.covered.iter().map(|&c| c as u8 as f64).collect();
        let band = self.band_coverage.tape().to_vec(self.band_coverage);
        for (&i, v) in self.plan.band.iter().zip(band) {
            image[i as usize] = v.f64();
        }
        image
    }

    /// Mean absolute difference to the reference over the whole image (the L1 part of `L_mask`).
    ///
    /// With a binary reference `|m - r| = m (1 - 2r) + r`: linear in the coverage, no kink. Pixels
    /// outside the band contribute a constant. Fails when the reference's size is not the camera's.
    pub fn mask_l1(&self, reference: &ReferenceMask) -> Result<Var<'t, T>> {
        let plan = self.plan;
        let (width, height) = (plan.camera.width as usize, plan.camera.height as usize);
        reference.check_size(width, height)?;
        let inside = &reference.mask().inside;
        let mismatched = |i: usize| (plan.covered[i] != inside[i]) as u32 as f64;
        let band_ref: Vec<f32> = plan.band.iter().map(|&i| inside[i as usize] as u8 as f32).collect();
        let fixed = (0..width * height).map(mismatched).sum::<f64>()
            - plan.band.iter().map(|&i| mismatched(i as usize)).sum::<f64>()
            + band_ref.iter().map(|&r| r as f64).sum::<f64>();
        let tape = self.band_coverage.tape();
        let slope: Vec<f32> = band_ref.iter().map(|&r| 1.0 - 2.0 * r).collect();
        let band = (self.band_coverage * constant(tape, &slope)).sum();
        Ok((band + T::c(fixed)) * T::c(1.0 / (width * height) as f64))
    }

    /// Symmetric Chamfer distance between the rendered and the reference silhouettes, in pixels
    /// per reference pixel (the Chamfer part of `L_mask`):
    ///
    /// `(sum_p m(p) max(DT_ref(p) - 1/2, 0) + sum_{q in ref, q not covered} sqrt(d(q, contour)^2 + eps^2)) / |ref|`
    ///
    /// The first term charges rendered coverage by its distance to the reference's edge (0 inside
    /// it; `DT_ref` is the distance to the nearest mask pixel's centre, half a pixel beyond the edge);
    /// the second charges every reference pixel the hard render misses by its distance to the
    /// nearest projected contour edge, differentiable in that edge's endpoints (the edge, or the
    /// endpoint, is chosen at the plan's pose). Both stay informative when the silhouettes do not overlap. Fails when
    /// the reference's size is not the camera's.
    pub fn chamfer(&self, reference: &ReferenceMask) -> Result<Var<'t, T>> {
        let plan = self.plan;
        let (width, height) = (plan.camera.width as usize, plan.camera.height as usize);
        reference.check_size(width, height)?;
        let tape = self.band_coverage.tape();
        // Rendered coverage is charged its distance to the reference's edge,
        // half a pixel short of the nearest mask pixel's centre: charged the
        // centre distance, a pixel just outside cost twice what a missed one
        // just inside does, and the fit shrank the probe.
        let distance: Vec<f32> = reference
            .distance()
            .iter()
            .map(|&d| (d - HALF_PIXEL).max(0.0))
            .collect();
        let distance = &distance[..];
        let inside = &reference.mask().inside;

        let band_distance: Vec<f32> = plan.band.iter().map(|&i| distance[i as usize]).collect();
        let fixed_rendered = plan
            .covered
            .iter()
            .zip(distance)
            .filter(|(c, _)| **c)
            .map(|(_, &d)| d as f64)
            .sum::<f64>()
            - plan
                .band
                .iter()
                .filter(|&&i| plan.covered[i as usize])
                .map(|&i| distance[i as usize] as f64)
                .sum::<f64>();
        let mut total = (self.band_coverage * constant(tape, &band_distance)).sum() + T::c(fixed_rendered);

        let mut missed = MissedPixels::default();
        for i in (0..width * height).filter(|&i| inside[i] && !plan.covered[i]) {
            let q = pixel_centre(i, width);
            if let Some(([a, b], _)) = plan.nearest_contour(q) {
                missed.start.push(a as f32);
                missed.end.push(b as f32);
                missed.x.push(q.x);
                missed.y.push(q.y);
            }
        }
        if !missed.x.is_empty() {
            let (start, end) = (constant(tape, &missed.start), constant(tape, &missed.end));
            let d2 = feature_distance2(
                (self.x.gather(start), self.y.gather(start)),
                (self.x.gather(end), self.y.gather(end)),
                (constant(tape, &missed.x), constant(tape, &missed.y)),
            );
            total = total + (d2 + T::c(CHAMFER_EPS_PX * CHAMFER_EPS_PX)).sqrt().sum();
        }
        Ok(total * T::c(1.0 / reference.area() as f64))
    }

    /// Coverage-weighted mean pixel position (x right, y down) of the whole mask: the `B(M_render)`
    /// of the pose regularizer, differentiable through the band.
    pub fn barycenter(&self) -> (Var<'t, T>, Var<'t, T>) {
        let plan = self.plan;
        let tape = self.band_coverage.tape();
        let width = plan.camera.width as usize;
        let (xs, ys): (Vec<f32>, Vec<f32>) = plan
            .band
            .iter()
            .map(|&i| {
                let p = pixel_centre(i as usize, width);
                (p.x, p.y)
            })
            .unzip();
        let m = self.band_coverage;
        let area = m.sum() + T::c(plan.fixed_area);
        let mx = (m * constant(tape, &xs)).sum() + T::c(plan.fixed_moment[0]);
        let my = (m * constant(tape, &ys)).sum() + T::c(plan.fixed_moment[1]);
        (mx / area, my / area)
    }
}

/// Reference pixels the hard render misses, with their nearest contour feature.
#[derive(Default)]
struct MissedPixels {
    start: Vec<f32>,
    end: Vec<f32>,
    x: Vec<f32>,
    y: Vec<f32>,
}
