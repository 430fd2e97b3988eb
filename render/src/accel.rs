//! Ray-triangle acceleration with an obvhs BVH: closest hit, occlusion, and the primary-visibility
//! pass that tells, for every sub-pixel sample of a camera, which triangle it sees and where.
//!
//! Intersection and barycentrics come from obvhs' `RtTriangle` (CRATES.md: `Triangle::compute_barycentric`
//! is inaccurate). Triangles are reordered once after the build so that the BVH's leaf indices address
//! them directly; `primitive_indices` maps back to the caller's triangle ids.

use std::time::Duration;

use glam::{Vec2, Vec3, Vec3A};
use obvhs::BvhBuildParams;
use obvhs::bvh2::Bvh2;
use obvhs::bvh2::builder::build_bvh2_from_tris;
use obvhs::ray::{Ray, RayHit};
use obvhs::rt_triangle::RtTriangle;
use obvhs::triangle::Triangle;
use rayon::prelude::*;

use crate::camera::Camera;
use crate::mesh::Mesh;
use crate::sampling::Rng;

/// A ray-triangle intersection.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Index of the triangle in the mesh given to [`Accel::new`].
    pub triangle: u32,
    /// Ray parameter: the hit is at `origin + t * direction`.
    pub t: f32,
    /// Barycentrics (b1, b2): the weights of the triangle's corners 1 and 2 (corner 0 gets 1 - b1 - b2).
    pub barycentric: Vec2,
}

/// A BVH over a mesh's triangles (in the frame of its positions, e.g. world after posing).
pub struct Accel {
    bvh: Bvh2,
    /// Triangles in BVH leaf order.
    triangles: Vec<RtTriangle>,
}

impl Accel {
    /// Builds the BVH of `mesh` (obvhs PLOC, medium quality); panics on a mesh without triangles.
    pub fn new(mesh: &Mesh) -> Self {
        assert!(!mesh.triangles.is_empty(), "Accel::new: the mesh has no triangles");
        let triangles: Vec<Triangle> = (0..mesh.triangles.len())
            .map(|t| {
                let [v0, v1, v2] = mesh.corners(t).map(Vec3A::from);
                Triangle { v0, v1, v2 }
            })
            .collect();
        let bvh = build_bvh2_from_tris(&triangles, BvhBuildParams::medium_build(), &mut Duration::default());
        let triangles = bvh
            .primitive_indices
            .iter()
            .map(|&i| RtTriangle::from(&triangles[i as usize]))
            .collect();
        Self { bvh, triangles }
    }

    /// The closest hit along `origin + t direction` for t in [0, `t_max`], if any.
    pub fn closest_hit(&self, origin: Vec3, direction: Vec3, t_max: f32) -> Option<Hit> {
        let ray = Ray::new(origin.into(), direction.into(), 0.0, t_max);
        let mut hit = RayHit::none();
        if !self
            .bvh
            .ray_traverse(ray, &mut hit, |ray, i| self.triangles[i].intersect(ray))
        {
            return None;
        }
        let leaf = hit.primitive_id as usize;
        Some(Hit {
            triangle: self.bvh.primitive_indices[leaf],
            t: hit.t,
            barycentric: self.triangles[leaf].compute_barycentric(&ray),
        })
    }

    /// Whether anything lies along `origin + t direction` for t in [`t_min`, `t_max`] (shadow / visibility rays).
    pub fn occluded(&self, origin: Vec3, direction: Vec3, t_min: f32, t_max: f32) -> bool {
        let ray = Ray::new(origin.into(), direction.into(), t_min, t_max);
        !self
            .bvh
            .ray_traverse_miss(ray, |ray, i| self.triangles[i].intersect(ray))
    }
}

/// What one sub-pixel sample of the primary-visibility pass sees.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PrimarySample {
    /// Row-major pixel index `row * width + col`.
    pub pixel: u32,
    /// Sub-pixel position of the sample, [0, 1)^2 (x right, y down).
    pub offset: Vec2,
    /// The surface seen, or `None` for the background.
    pub hit: Option<Hit>,
}

/// The sub-pixel offsets in [0, 1)^2 (x right, y down) of the `offsets.len()` samples of `pixel`.
///
/// Stratified by n-rooks (Latin hypercube): sample k sits in the k-th of n vertical strips and in
/// a randomly permuted horizontal strip, so both coordinates are stratified for any n. Drawn from
/// the PCG32 stream keyed by the pixel index: the same for a given `seed` whatever the thread count.
pub fn stratified_offsets(seed: u64, pixel: u32, offsets: &mut [Vec2]) {
    let n = offsets.len();
    let mut rng = Rng::new(seed, pixel as u64);
    for (k, offset) in offsets.iter_mut().enumerate() {
        *offset = Vec2::new(k as f32, k as f32);
    }
    // Fisher-Yates shuffle of the y strips.
    for i in (1..n).rev() {
        let j = rng.next_below(i as u32 + 1) as usize;
        let (yi, yj) = (offsets[i].y, offsets[j].y);
        (offsets[i].y, offsets[j].y) = (yj, yi);
    }
    for offset in offsets.iter_mut() {
        *offset = (*offset + rng.next_2d()) / n as f32;
    }
}

/// Traces `samples_per_pixel` rays through every pixel of `camera` at [`stratified_offsets`], in
/// parallel over rows; sample k of pixel p lies at `result[p * samples_per_pixel + k]`.
pub fn primary_visibility(accel: &Accel, camera: &Camera, samples_per_pixel: u32, seed: u64) -> Vec<PrimarySample> {
    assert!(
        samples_per_pixel > 0,
        "primary_visibility: samples_per_pixel must be > 0"
    );
    let (width, n) = (camera.width as usize, samples_per_pixel as usize);
    let mut samples = vec![
        PrimarySample {
            pixel: 0,
            offset: Vec2::ZERO,
            hit: None
        };
        camera.pixel_count() * n
    ];
    samples
        .par_chunks_mut(width * n)
        .enumerate()
        .for_each(|(row, row_samples)| {
            let mut offsets = vec![Vec2::ZERO; n];
            for (col, pixel_samples) in row_samples.chunks_mut(n).enumerate() {
                let pixel = (row * width + col) as u32;
                stratified_offsets(seed, pixel, &mut offsets);
                for (sample, &offset) in pixel_samples.iter_mut().zip(&offsets) {
                    let (origin, direction) = camera.primary_ray(row as u32, col as u32, offset);
                    *sample = PrimarySample {
                        pixel,
                        offset,
                        hit: accel.closest_hit(origin, direction, f32::INFINITY),
                    };
                }
            }
        });
    samples
}
