//! The mask's outline: its signed distance field, and points on it with
//! their outward normals. The blur is read across it (`blur`); the pose's
//! uncertainty compares the found outline with the photo's mask along it
//! (`pose::uncertainty`).

use glam::Vec2;
use render::image_io::Mask;
use render::silhouette::distance_transform;

/// The signed distance (pixels) of each pixel centre of `mask` to its
/// outline: negative inside, positive outside, the outline at 0, half a
/// pixel beyond the centres of the mask's edge pixels.
pub(super) fn signed_distance(mask: &Mask) -> Vec<f32> {
    let (w, h) = (mask.width, mask.height);
    let outside: Vec<bool> = mask.inside.iter().map(|&m| !m).collect();
    let to_inside = distance_transform(&mask.inside, w, h);
    let to_outside = distance_transform(&outside, w, h);
    (0..w * h)
        .map(|p| match mask.inside[p] {
            true => 0.5 - to_outside[p],
            false => to_inside[p] - 0.5,
        })
        .collect()
}

/// The signed distance field `signed` of a `width x height` mask at the
/// pixel coordinates `p` (x right, y down), bilinear between pixel centres
/// and clamped at the image's border.
pub(super) fn signed_distance_at(signed: &[f32], width: usize, height: usize, p: Vec2) -> f32 {
    let (x, y) = (
        (p.x - 0.5).clamp(0.0, (width - 1) as f32),
        (p.y - 0.5).clamp(0.0, (height - 1) as f32),
    );
    let (i, j) = (
        (x as usize).min(width.saturating_sub(2)),
        (y as usize).min(height.saturating_sub(2)),
    );
    let (fx, fy) = (x - i as f32, y - j as f32);
    let at = |i: usize, j: usize| signed[j.min(height - 1) * width + i.min(width - 1)];
    (1.0 - fy) * ((1.0 - fx) * at(i, j) + fx * at(i + 1, j)) + fy * ((1.0 - fx) * at(i, j + 1) + fx * at(i + 1, j + 1))
}

/// The mask's outline as points and outward normals: one per pixel whose
/// centre lies within half a pixel of it, projected on to it along the
/// gradient of the signed distance.
pub(super) fn outline_points(mask: &Mask) -> Vec<(Vec2, Vec2)> {
    let (w, h) = (mask.width, mask.height);
    let signed = signed_distance(mask);
    let at_px = |x: i64, y: i64| signed[y.clamp(0, h as i64 - 1) as usize * w + x.clamp(0, w as i64 - 1) as usize];
    (0..w * h)
        .filter(|&p| mask.inside[p] && signed[p] >= -0.5)
        .filter_map(|p| {
            let (x, y) = ((p % w) as i64, (p / w) as i64);
            let gradient = Vec2::new(at_px(x + 1, y) - at_px(x - 1, y), at_px(x, y + 1) - at_px(x, y - 1));
            let normal = gradient.try_normalize()?;
            Some((Vec2::new(x as f32 + 0.5, y as f32 + 0.5) - signed[p] * normal, normal))
        })
        .collect()
}
