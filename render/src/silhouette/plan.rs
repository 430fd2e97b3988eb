//! The non-differentiated half of the soft silhouette: every discrete choice, made once per pose.

use std::ops::Range;

use glam::{Vec2, Vec3};

use super::grid::BoxGrid;
use super::{MIN_SEGMENT_LENGTH2, SilhouetteSettings, nearest_feature, pixel_centre};
use crate::camera::Camera;
use crate::error::{RenderError, Result};
use crate::image_io::Mask;
use crate::mesh::{EdgeAdjacency, Mesh};

/// Projected triangles with less area than this (pixels^2, either orientation) are edge-on or
/// degenerate: neither front nor back.
const MIN_PROJECTED_AREA: f32 = 1e-6;
/// Cells of the front-triangle grid are this many triangles across (they tile the silhouette);
/// the procedural probes (4-6k triangles) get the largest cells (sizes below).
const TRIANGLES_ACROSS_CELL: f32 = 2.0;
/// Cells of the rim's and the contour edges' grids are this many items across (they line the
/// silhouette's edge).
const RIM_ACROSS_CELL: f32 = 4.0;
/// Largest cell of the triangle grids, pixels.
const TRIANGLE_CELL_PX: f32 = 8.0;
/// Largest cell of the contour-edge grid, pixels.
const CONTOUR_CELL_PX: f32 = 16.0;
/// How far to either side of a contour edge's midpoint (pixels) the plan looks for the probe: an
/// edge of the outline has it on one side only.
const OUTLINE_PROBE_PX: f32 = 0.05;

/// The (band pixel, silhouette feature) pairs of the soft mask, as flat arrays (indices stored as
/// floats, the tape's convention): at most one per band pixel (none for an uncovered pixel out of
/// every front triangle's reach), ordered by band pixel.
#[derive(Clone, Debug, Default)]
pub(crate) struct Pairs {
    /// The feature of the silhouette's edge nearest to the pixel centre (of the outline for a
    /// covered pixel, of the nearest front triangle for an uncovered one): an edge from
    /// `feature_start` to `feature_end`, or a vertex (both the same).
    pub feature_start: Vec<f32>,
    /// See `feature_start`.
    pub feature_end: Vec<f32>,
    /// Pixel centre, x.
    pub x: Vec<f32>,
    /// Pixel centre, y.
    pub y: Vec<f32>,
    /// `delta / sigma`: `+1/sigma` when the pixel centre is covered, `-1/sigma` when not.
    pub signed_inv_sigma: Vec<f32>,
    /// Index of the pixel in the band.
    pub band_slot: Vec<f32>,
}

/// Everything the soft mask holds fixed, computed (in f32) from the posed vertices.
///
/// Rebuild it at every new pose: it is exact at the pose it was built for and its gradient is the
/// true one there; finite differences around that pose see a smooth function.
#[derive(Clone, Debug)]
pub struct SilhouettePlan {
    pub(crate) camera: Camera,
    pub(crate) settings: SilhouetteSettings,
    pub(crate) vertex_count: usize,
    /// Projected vertices at the plan's pose, pixels.
    pub(crate) projected: Vec<Vec2>,
    /// Hard coverage: the pixel centre lies in a front-facing projected triangle.
    pub(crate) covered: Vec<bool>,
    /// Band pixels (row-major indices), ascending.
    pub(crate) band: Vec<u32>,
    pub(crate) pairs: Pairs,
    /// Contour edges (one front and one back triangle, or an open border of a front one), vertex indices.
    pub(crate) contour: Vec<[u32; 2]>,
    pub(crate) contour_grid: BoxGrid,
    /// Hard-covered pixels outside the band: count and sums of their centres' x and y.
    pub(crate) fixed_area: f64,
    pub(crate) fixed_moment: [f64; 2],
}

impl SilhouettePlan {
    /// Plans the soft mask of `mesh` with vertices at `posed_positions` (world) seen by `camera`.
    ///
    /// Fails on invalid settings, a vertex that is not finite or not in front of the camera, and a
    /// probe that covers no pixel centre or the whole image (no silhouette in view). Panics when
    /// `posed_positions` does not have one position per mesh vertex (a programming error).
    pub fn new(mesh: &Mesh, posed_positions: &[Vec3], camera: &Camera, settings: SilhouetteSettings) -> Result<Self> {
        Self::with_edges(mesh, &EdgeAdjacency::new(mesh), posed_positions, camera, settings)
    }

    /// [`new`](Self::new) with the mesh's edge adjacency computed once by the caller (it does not
    /// depend on the pose).
    pub fn with_edges(
        mesh: &Mesh,
        edges: &EdgeAdjacency,
        posed_positions: &[Vec3],
        camera: &Camera,
        settings: SilhouetteSettings,
    ) -> Result<Self> {
        assert_eq!(
            posed_positions.len(),
            mesh.positions.len(),
            "SilhouettePlan: {} posed positions for a mesh of {} vertices",
            posed_positions.len(),
            mesh.positions.len()
        );
        settings.validate()?;
        let projected = project_all(posed_positions, camera)?;
        let (width, height) = (camera.width as usize, camera.height as usize);

        // Front faces, wound so that their projected signed area is positive. Meshes wind
        // counter-clockwise seen from outside; the image's y axis points down, which flips the
        // sign: a front face has negative area in pixel coordinates.
        let mut facing = vec![0i8; mesh.triangles.len()];
        let mut front: Vec<(u32, [u32; 3])> = Vec::new();
        for (t, &[i0, i1, i2]) in mesh.triangles.iter().enumerate() {
            let [a, b, c] = [i0, i1, i2].map(|i| projected[i as usize]);
            let area2 = (b - a).perp_dot(c - a);
            if area2 < -MIN_PROJECTED_AREA {
                facing[t] = 1;
                front.push((t as u32, [i0, i2, i1]));
            } else if area2 > MIN_PROJECTED_AREA {
                facing[t] = -1;
            }
        }
        let corners = |tri: &[u32; 3]| tri.map(|i| projected[i as usize]);

        let (covered, Some(covered_box)) = rasterize(&front, &projected, width, height) else {
            return Err(RenderError::value(
                "pose",
                format!("the probe covers no pixel centre of the {width}x{height} image"),
            ));
        };
        let band = band_pixels(&covered, &covered_box, width, height, settings.band_px);
        if band.is_empty() {
            return Err(RenderError::value(
                "pose",
                format!("the probe covers the whole {width}x{height} image: no silhouette in view"),
            ));
        }

        let boxes: Vec<(u32, Vec2, Vec2)> = front
            .iter()
            .enumerate()
            .map(|(k, (_, tri))| {
                let [a, b, c] = corners(tri);
                (k as u32, a.min(b).min(c), a.max(b).max(c))
            })
            .collect();
        let triangle_grid = BoxGrid::new(width, height, &boxes, TRIANGLES_ACROSS_CELL, TRIANGLE_CELL_PX);
        // The rim: front triangles with an edge that no other front triangle shares. Two front
        // triangles sharing an edge lie on either side of it in the image, so the silhouette's
        // edge runs along the rim's edges only, and the rim holds the front triangle nearest to
        // any uncovered pixel centre: on a dense mesh, a few of the thousands near the limb.
        let mut rim = vec![false; mesh.triangles.len()];
        for edge in &edges.edges {
            let fronts = || edge.triangles.iter().filter(|&&t| facing[t as usize] > 0);
            if fronts().count() != 2 {
                fronts().for_each(|&t| rim[t as usize] = true);
            }
        }
        let rim_boxes: Vec<(u32, Vec2, Vec2)> = boxes
            .iter()
            .copied()
            .filter(|&(k, _, _)| rim[front[k as usize].0 as usize])
            .collect();
        let rim_grid = BoxGrid::new(width, height, &rim_boxes, RIM_ACROSS_CELL, TRIANGLE_CELL_PX);
        let covers = |q: Vec2| {
            triangle_grid
                .items_at(q)
                .iter()
                .any(|&k| inside_triangle(q, corners(&front[k as usize].1)))
        };
        // Whether the probe lies on one side only of the edge from `a` to `b` at `at`.
        let one_sided = |at: Vec2, a: Vec2, b: Vec2| {
            let across = OUTLINE_PROBE_PX * (b - a).perp().normalize_or_zero();
            covers(at + across) != covers(at - across)
        };
        // Contour edges with the probe on one side only: a contour seen
        // through the probe itself (a can's inner rim over its lid) has it
        // on both and is no part of the outline.
        let contour: Vec<[u32; 2]> = contour_edges(edges, &facing)
            .into_iter()
            .filter(|&[a, b]| {
                let (a, b) = (projected[a as usize], projected[b as usize]);
                one_sided(0.5 * (a + b), a, b)
            })
            .collect();
        let contour_boxes: Vec<(u32, Vec2, Vec2)> = contour
            .iter()
            .enumerate()
            .map(|(k, &[a, b])| {
                let (a, b) = (projected[a as usize], projected[b as usize]);
                (k as u32, a.min(b), a.max(b))
            })
            .collect();
        let contour_grid = BoxGrid::new(width, height, &contour_boxes, RIM_ACROSS_CELL, CONTOUR_CELL_PX);
        // The nearest point of the outline itself: an edge partly hidden behind the probe is
        // outline only where the probe lies on one side of it.
        let nearest_outline = |p: Vec2| {
            let on_outline = |k: u32| {
                let ([a, b], _) = outline_feature(&contour, &projected, k, p);
                let (a, b) = (projected[a as usize], projected[b as usize]);
                let [ea, eb] = contour[k as usize].map(|i| projected[i as usize]);
                let foot = match a == b {
                    true => a,
                    false => a + (p - a).dot(b - a) / (b - a).length_squared().max(MIN_SEGMENT_LENGTH2) * (b - a),
                };
                one_sided(foot, ea, eb)
            };
            contour_grid
                .nearest(
                    p,
                    f32::INFINITY,
                    |k| outline_feature(&contour, &projected, k, p).1,
                    on_outline,
                )
                .map(|(k, _)| outline_feature(&contour, &projected, k, p))
        };

        let inv_sigma = 1.0 / settings.sigma_px2;
        let cutoff2 = settings.band_px * settings.band_px;
        let mut pairs = Pairs::default();
        for (slot, &pixel) in band.iter().enumerate() {
            let p = pixel_centre(pixel as usize, width);
            // A covered pixel centre's distance to the outline, an uncovered
            // one's to the nearest front triangle: the distance to the
            // silhouette's edge either way, so that coverage is one half on
            // it. (SoftRas's union over every triangle within reach lifted
            // it on the limb, where thin foreshortened triangles crowd, and
            // mask fits shrank the probe.)
            let nearest = if covered[pixel as usize] {
                nearest_outline(p).map(|(feature, _)| (feature, inv_sigma))
            } else {
                let feature = |k: u32| nearest_triangle_feature(p, &front[k as usize].1, corners(&front[k as usize].1));
                rim_grid
                    .nearest(p, cutoff2, |k| feature(k).1, |_| true)
                    .map(|(k, _)| feature(k))
                    .map(|(feature, _)| (feature, -inv_sigma))
            };
            if let Some((feature, signed_inv_sigma)) = nearest {
                pairs.feature_start.push(feature[0] as f32);
                pairs.feature_end.push(feature[1] as f32);
                pairs.x.push(p.x);
                pairs.y.push(p.y);
                pairs.signed_inv_sigma.push(signed_inv_sigma);
                pairs.band_slot.push(slot as f32);
            }
        }

        let mut fixed_area = 0.0;
        let mut fixed_moment = [0.0; 2];
        let mut band_iter = band.iter().peekable();
        for i in covered_box.pixels(width) {
            // The band's pixels before `i` (outside the box's columns) are passed over.
            while band_iter.next_if(|&&b| (b as usize) < i).is_some() {}
            if band_iter.next_if(|&&b| b as usize == i).is_some() || !covered[i] {
                continue;
            }
            let p = pixel_centre(i, width);
            fixed_area += 1.0;
            fixed_moment[0] += p.x as f64;
            fixed_moment[1] += p.y as f64;
        }

        Ok(Self {
            camera: *camera,
            settings,
            vertex_count: posed_positions.len(),
            projected,
            covered,
            band,
            pairs,
            contour,
            contour_grid,
            fixed_area,
            fixed_moment,
        })
    }

    /// The camera planned for.
    pub fn camera(&self) -> &Camera {
        &self.camera
    }

    /// The settings planned with.
    pub fn settings(&self) -> SilhouetteSettings {
        self.settings
    }

    /// Projected vertex positions at the plan's pose (pixels, x right, y down).
    pub fn projected(&self) -> &[Vec2] {
        &self.projected
    }

    /// Hard coverage per pixel (row-major): the pixel centre lies in a front-facing projected triangle.
    pub fn covered(&self) -> &[bool] {
        &self.covered
    }

    /// The hard coverage as a mask.
    pub fn hard_mask(&self) -> Mask {
        Mask::new(
            self.camera.width as usize,
            self.camera.height as usize,
            self.covered.clone(),
        )
    }

    /// Row-major indices of the band pixels (ascending), where coverage is soft.
    pub fn band_pixels(&self) -> &[u32] {
        &self.band
    }

    /// Number of (band pixel, feature) pairs the soft mask evaluates.
    pub fn pair_count(&self) -> usize {
        self.pairs.x.len()
    }

    /// Number of projected contour (silhouette) edges.
    pub fn contour_edge_count(&self) -> usize {
        self.contour.len()
    }

    /// The nearest feature (edge or vertex, see `nearest_feature`) of the projected contour to
    /// `p` at the plan's pose, and its squared distance (pixels^2); `None` without a contour.
    pub(crate) fn nearest_contour(&self, p: Vec2) -> Option<([u32; 2], f32)> {
        self.contour_grid
            .nearest(
                p,
                f32::INFINITY,
                |k| outline_feature(&self.contour, &self.projected, k, p).1,
                |_| true,
            )
            .map(|(k, _)| outline_feature(&self.contour, &self.projected, k, p))
    }
}

/// The feature of contour edge `k` nearest to `p`, and its squared distance (see `nearest_feature`).
fn outline_feature(contour: &[[u32; 2]], projected: &[Vec2], k: u32, p: Vec2) -> ([u32; 2], f32) {
    let ends = contour[k as usize];
    nearest_feature(p, ends, projected[ends[0] as usize], projected[ends[1] as usize])
}

/// The feature of the boundary of triangle `tri` (projected corners `v`) nearest to `p`, and its
/// squared distance. The choice is discrete: fixing it in the plan makes the distance a smooth
/// function of the vertices (the min over edges has kinks on the medial axis).
fn nearest_triangle_feature(p: Vec2, tri: &[u32; 3], v: [Vec2; 3]) -> ([u32; 2], f32) {
    (0..3)
        .map(|e| {
            let (a, b) = ((e + 1) % 3, e);
            nearest_feature(p, [tri[a], tri[b]], v[a], v[b])
        })
        .fold(
            ([0; 2], f32::INFINITY),
            |best, cur| if cur.1 < best.1 { cur } else { best },
        )
}

/// Projects every vertex, or fails naming the first one that is not in front of the camera.
fn project_all(positions: &[Vec3], camera: &Camera) -> Result<Vec<Vec2>> {
    let behind = positions
        .iter()
        .filter(|p| (**p - camera.origin).dot(camera.forward) <= 0.0)
        .count();
    if behind == positions.len() {
        return Err(RenderError::value(
            "pose",
            "the probe is entirely behind the camera".to_string(),
        ));
    }
    positions
        .iter()
        .enumerate()
        .map(|(i, &p)| {
            let depth = (p - camera.origin).dot(camera.forward);
            camera.project(p).filter(|q| q.is_finite()).ok_or_else(|| {
                RenderError::value(
                    "pose",
                    format!(
                        "vertex {i} at {p} (depth {depth} m) is not in front of the camera: the probe crosses the camera plane"
                    ),
                )
            })
        })
        .collect()
}

/// Whether `p` lies in the triangle `v` (positive projected area), edges included.
fn inside_triangle(p: Vec2, v: [Vec2; 3]) -> bool {
    (0..3).all(|e| (v[(e + 1) % 3] - v[e]).perp_dot(p - v[e]) >= 0.0)
}

/// The rows and columns of an image a set of pixels lies within.
#[derive(Clone, Debug)]
struct PixelBox {
    rows: Range<usize>,
    cols: Range<usize>,
}

impl PixelBox {
    /// The box grown by `by` pixels each way, clamped to a `width x height` image.
    fn grown(&self, by: usize, width: usize, height: usize) -> PixelBox {
        PixelBox {
            rows: self.rows.start.saturating_sub(by)..(self.rows.end + by).min(height),
            cols: self.cols.start.saturating_sub(by)..(self.cols.end + by).min(width),
        }
    }

    /// Its pixels' row-major indices in an image `width` wide, ascending.
    fn pixels(&self, width: usize) -> impl Iterator<Item = usize> + '_ {
        self.rows
            .clone()
            .flat_map(move |row| self.cols.clone().map(move |col| row * width + col))
    }
}

/// Hard coverage: pixel centres inside any of the `front` triangles, and the box of those
/// covered (None: none is). The later passes over the image keep to the box: the probe is
/// often a small part of the photo.
fn rasterize(
    front: &[(u32, [u32; 3])],
    projected: &[Vec2],
    width: usize,
    height: usize,
) -> (Vec<bool>, Option<PixelBox>) {
    let mut covered = vec![false; width * height];
    let mut bounds: Option<PixelBox> = None;
    for (_, tri) in front {
        let v = tri.map(|i| projected[i as usize]);
        let (lo, hi) = (v[0].min(v[1]).min(v[2]), v[0].max(v[1]).max(v[2]));
        // Columns whose centre c + 0.5 lies in [lo.x, hi.x], clamped to the image.
        let first = |x: f32, n: usize| ((x - 0.5).ceil().max(0.0) as usize).min(n);
        let last = |x: f32, n: usize| ((x - 0.5).floor() + 1.0).clamp(0.0, n as f32) as usize;
        for row in first(lo.y, height)..last(hi.y, height) {
            for col in first(lo.x, width)..last(hi.x, width) {
                let i = row * width + col;
                if !covered[i] && inside_triangle(pixel_centre(i, width), v) {
                    covered[i] = true;
                    bounds = Some(match bounds {
                        None => PixelBox {
                            rows: row..row + 1,
                            cols: col..col + 1,
                        },
                        Some(b) => PixelBox {
                            rows: b.rows.start.min(row)..b.rows.end.max(row + 1),
                            cols: b.cols.start.min(col)..b.cols.end.max(col + 1),
                        },
                    });
                }
            }
        }
    }
    (covered, bounds)
}

/// Pixels within `band_px` (centre to centre) of a boundary pixel: one whose coverage differs
/// from a 4-neighbour's. Ascending row-major indices.
/// A boundary pixel lies within one pixel of `covered_box`, the box of the covered ones.
fn band_pixels(covered: &[bool], covered_box: &PixelBox, width: usize, height: usize, band_px: f32) -> Vec<u32> {
    let mut in_band = vec![false; width * height];
    let r = band_px.floor() as isize;
    let r2 = band_px * band_px;
    let boundary_box = covered_box.grown(1, width, height);
    for row in boundary_box.rows.clone() {
        for col in boundary_box.cols.clone() {
            let i = row * width + col;
            let differs = |dr: isize, dc: isize| {
                let (nr, nc) = (row as isize + dr, col as isize + dc);
                nr >= 0
                    && nc >= 0
                    && (nr as usize) < height
                    && (nc as usize) < width
                    && covered[nr as usize * width + nc as usize] != covered[i]
            };
            if !(differs(-1, 0) || differs(1, 0) || differs(0, -1) || differs(0, 1)) {
                continue;
            }
            for dr in -r..=r {
                for dc in -r..=r {
                    let (nr, nc) = (row as isize + dr, col as isize + dc);
                    if nr >= 0
                        && nc >= 0
                        && (nr as usize) < height
                        && (nc as usize) < width
                        && (dr * dr + dc * dc) as f32 <= r2
                    {
                        in_band[nr as usize * width + nc as usize] = true;
                    }
                }
            }
        }
    }
    let band_box = covered_box.grown(1 + r.max(0) as usize, width, height);
    band_box
        .pixels(width)
        .filter(|&i| in_band[i])
        .map(|i| i as u32)
        .collect()
}

/// Edges between a front- and a back-facing triangle, and open borders of front ones; edge-on
/// (zero projected area) triangles are left out of the count.
fn contour_edges(edges: &EdgeAdjacency, facing: &[i8]) -> Vec<[u32; 2]> {
    edges
        .edges
        .iter()
        .filter(|e| {
            let front = e.triangles.iter().filter(|&&t| facing[t as usize] > 0).count();
            let back = e.triangles.iter().filter(|&&t| facing[t as usize] < 0).count();
            front > 0 && (back > 0 || (front == 1 && e.triangles.len() == 1))
        })
        .map(|e| e.vertices)
        .collect()
}
