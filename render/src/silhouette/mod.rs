//! Differentiable silhouettes: a soft rasterized mask of the posed probe and the mask losses of
//! the paper (`L_mask` = L1 + Chamfer, and the barycenter of `L_pose_reg`), composed from tape ops.
//!
//! The work is split in two, so that finite differences see a smooth function:
//! - [`SilhouettePlan`] (not differentiated, rebuilt every iteration at the current pose) makes
//!   every discrete choice: the hard coverage, the band of pixels around the silhouette, the
//!   outline (the projected contour edges with the probe on one side only), and for each band
//!   pixel the nearest feature (edge or vertex) of the silhouette's edge.
//! - [`SoftMask`] evaluates, on a tape, the soft coverage of the band pixels, differentiable in
//!   the vertex positions and hence in the pose, from the distance `d(p)` (pixels) of the pixel
//!   centre to the silhouette's edge:
//!
//!   `m(p) = sigmoid(delta(p) d(p)^2 / sigma)`,
//!
//!   with `delta = +1` on a covered centre, its `d` measured to the nearest edge of the outline
//!   (contour edges with the probe on one side only), and `delta = -1` on an uncovered one, its
//!   `d` measured to the nearest front triangle (after SoftRas, Liu et al. 2019, "Soft
//!   Rasterizer", whose sigmoid of the squared distance this keeps). Coverage is one half on the
//!   edge and continuous across it. Pixels outside the band keep their hard coverage (a
//!   constant); the band is wide enough that the soft value there differs from it by less than
//!   `sigmoid(-band_px^2 / sigma)`.
//!
//! SoftRas proper takes the union over every triangle within reach, `1 - prod_j (1 - D_j)`: two
//! front triangles sharing an edge give a pixel centred on it 0.75, and the thin foreshortened
//! triangles crowding along the limb of a curved object lift the coverage on the silhouette
//! above one half, and mask fits shrink the probe; with the distance to the edge the coverage
//! is one half on it and they do not (see docs/results/decisions.md 6.4, Silhouette losses).
//!
//! ```no_run
//! use autodiff::Tape;
//! use render::posed::{MeshVars, PoseVars, PosedMesh, pack_pose};
//! use render::silhouette::{ReferenceMask, SilhouettePlan, SilhouetteSettings};
//! # fn run(mesh: &render::mesh::Mesh, pose: &render::pose::Pose, camera: &render::camera::Camera,
//! #        mask: &render::image_io::Mask) -> render::Result<()> {
//! let reference = ReferenceMask::new(mask)?; // once per photo
//! let plan = SilhouettePlan::new(mesh, &mesh.posed(pose).positions, camera, SilhouetteSettings::default())?;
//! let tape = Tape::<f32>::new();
//! let pose_vars = PoseVars::new(&tape, &pack_pose(pose), true);
//! let posed = PosedMesh::new(&MeshVars::new(&tape, mesh), &pose_vars);
//! let soft = plan.soft_mask(&posed);
//! let loss = soft.mask_l1(&reference)? + soft.chamfer(&reference)?;
//! tape.backward(loss);
//! let pose_grad = tape.grad(pose_vars.params).to_vec();
//! # Ok(()) }
//! ```

mod grid;
mod plan;
mod reference;
mod soft;

pub use plan::SilhouettePlan;
pub use reference::{ReferenceMask, distance_transform, mask_barycenter};
pub use soft::{SoftMask, project_to_pixels};

use crate::error::{RenderError, Result};

/// Sharpness and reach of the soft mask.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SilhouetteSettings {
    /// Sharpness sigma, in squared pixels: a pixel centre `d` pixels outside the silhouette gets
    /// coverage `sigmoid(-d^2 / sigma)` (the default 0.1 px^2: 0.08 at 0.5 px, 5e-5 at 1 px).
    pub sigma_px2: f32,
    /// Half-width of the band around the hard silhouette where coverage is soft, in pixels
    /// (centre-to-centre distance to the nearest boundary pixel).
    pub band_px: f32,
}

impl Default for SilhouetteSettings {
    /// sigma = 0.1 px^2 and a 3 px band: outside the band, soft and hard coverage differ by less
    /// than `sigmoid(-90)`.
    fn default() -> Self {
        Self {
            sigma_px2: 0.1,
            band_px: 3.0,
        }
    }
}

impl SilhouetteSettings {
    /// Checks that sigma is positive and the band at least one pixel wide (both finite).
    pub fn validate(&self) -> Result<()> {
        if !(self.sigma_px2.is_finite() && self.sigma_px2 > 0.0) {
            return Err(RenderError::value(
                "sigma_px2",
                format!("value {} must be finite and > 0", self.sigma_px2),
            ));
        }
        if !(self.band_px.is_finite() && self.band_px >= 1.0) {
            return Err(RenderError::value(
                "band_px",
                format!("value {} must be finite and >= 1", self.band_px),
            ));
        }
        Ok(())
    }
}

/// Centre of pixel `index` of a row-major image `width` wide, in pixel coordinates (x right, y down).
fn pixel_centre(index: usize, width: usize) -> glam::Vec2 {
    glam::Vec2::new((index % width) as f32 + 0.5, (index / width) as f32 + 0.5)
}

/// The feature of the segment `[a, b]` (vertex indices `ends`) nearest to `p`, and its squared
/// distance: the edge itself (`ends`) when the foot of the perpendicular falls inside it, else
/// the nearer endpoint as a degenerate edge (`[a, a]` or `[b, b]`).
///
/// Fixing the feature in the plan makes the tape's distance (`soft::feature_distance2`) smooth
/// in the vertices: the clamped point-segment distance is only once differentiable where the
/// foot crosses an endpoint, which finite differences notice.
fn nearest_feature(p: glam::Vec2, ends: [u32; 2], a: glam::Vec2, b: glam::Vec2) -> ([u32; 2], f32) {
    let e = b - a;
    let w = p - a;
    let t = w.dot(e) / e.length_squared().max(MIN_SEGMENT_LENGTH2);
    if t <= 0.0 {
        ([ends[0]; 2], w.length_squared())
    } else if t >= 1.0 {
        ([ends[1]; 2], (p - b).length_squared())
    } else {
        (ends, (w - t * e).length_squared())
    }
}

/// Floor on a projected edge's squared length (pixels^2): a degenerate edge (an endpoint
/// feature) divides by it, and its zero length cancels the result.
const MIN_SEGMENT_LENGTH2: f32 = 1e-12;
