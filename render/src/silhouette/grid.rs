//! A uniform grid of axis-aligned boxes over the part of the image they span, so that the
//! candidates near a pixel cost what is near it: the plan's work follows the silhouette's length,
//! not pixels x triangles, however dense the mesh.

use glam::Vec2;

/// Items (triangles, edges) bucketed by the grid cells their boxes overlap, in CSR layout.
///
/// The grid spans the items' boxes (within the image), with cells sized to the items.
/// Boxes and queries beyond it are clamped to it: projection onto a box is non-expansive, so an
/// item in a border cell is never closer to a query than that cell is, and the nearest-item
/// search stays exact for a query anywhere.
#[derive(Clone, Debug)]
pub(crate) struct BoxGrid {
    origin: Vec2,
    cell_px: f32,
    cols: usize,
    rows: usize,
    /// Items of cell `c` are `items[start[c]..start[c + 1]]`.
    start: Vec<u32>,
    items: Vec<u32>,
    /// The box of each entry of `items`, alongside it: the nearest-item search skips an item
    /// whose box is no nearer than the best found before paying for its distance.
    boxes: Vec<(Vec2, Vec2)>,
}

impl BoxGrid {
    /// Buckets `(item, min, max)` boxes (pixel coordinates) of a `width x height` image, in cells
    /// `boxes_across` times the boxes' mean extent (their larger side) wide, at most
    /// `max_cell_px` and at least a pixel: a dense mesh (a scanned probe's hundred thousand
    /// triangles, a pixel or less each) gets cells that hold a few dozen of them, where cells of
    /// a fixed size would hold hundreds.
    pub fn new(width: usize, height: usize, boxes: &[(u32, Vec2, Vec2)], boxes_across: f32, max_cell_px: f32) -> Self {
        let image = Vec2::new(width as f32, height as f32);
        let (lo, hi) = boxes
            .iter()
            .fold((image, Vec2::ZERO), |(lo, hi), &(_, a, b)| (lo.min(a), hi.max(b)));
        let (lo, hi) = (lo.clamp(Vec2::ZERO, image), hi.clamp(Vec2::ZERO, image).max(lo));
        let span = (hi - lo).max(Vec2::ONE);
        let extent = boxes.iter().map(|&(_, a, b)| (b - a).max_element()).sum::<f32>() / boxes.len().max(1) as f32;
        let cell_px = (boxes_across * extent).clamp(1.0, max_cell_px);
        let cols = (span.x / cell_px).ceil().max(1.0) as usize;
        let rows = (span.y / cell_px).ceil().max(1.0) as usize;
        let mut grid = Self {
            origin: lo,
            cell_px,
            cols,
            rows,
            start: Vec::new(),
            items: Vec::new(),
            boxes: Vec::new(),
        };
        let mut count = vec![0u32; cols * rows + 1];
        for &(_, lo, hi) in boxes {
            grid.for_cells(lo, hi, |c| count[c + 1] += 1);
        }
        for c in 0..cols * rows {
            count[c + 1] += count[c];
        }
        let mut fill = count.clone();
        let entries = count[cols * rows] as usize;
        let (mut items, mut item_boxes) = (vec![0u32; entries], vec![(Vec2::ZERO, Vec2::ZERO); entries]);
        for &(item, lo, hi) in boxes {
            grid.for_cells(lo, hi, |c| {
                items[fill[c] as usize] = item;
                item_boxes[fill[c] as usize] = (lo, hi);
                fill[c] += 1;
            });
        }
        grid.start = count;
        grid.items = items;
        grid.boxes = item_boxes;
        grid
    }

    /// Calls `f` with the index of every cell the box `[lo, hi]` overlaps (clamped to the grid).
    fn for_cells(&self, lo: Vec2, hi: Vec2, mut f: impl FnMut(usize)) {
        let (c0, r0) = self.cell_of(lo);
        let (c1, r1) = self.cell_of(hi);
        for r in r0..=r1 {
            for c in c0..=c1 {
                f(r * self.cols + c);
            }
        }
    }

    /// The (column, row) of the cell holding `p`, clamped to the grid.
    fn cell_of(&self, p: Vec2) -> (usize, usize) {
        let clamp = |v: f32, n: usize| (v / self.cell_px).floor().clamp(0.0, (n - 1) as f32) as usize;
        let p = p - self.origin;
        (clamp(p.x, self.cols), clamp(p.y, self.rows))
    }

    /// The items whose boxes overlap the cell holding `p`.
    pub fn items_at(&self, p: Vec2) -> &[u32] {
        let (c, r) = self.cell_of(p);
        self.cell_items(c, r)
    }

    fn cell_items(&self, c: usize, r: usize) -> &[u32] {
        &self.items[self.cell_range(c, r)]
    }

    fn cell_range(&self, c: usize, r: usize) -> std::ops::Range<usize> {
        let k = r * self.cols + c;
        self.start[k] as usize..self.start[k + 1] as usize
    }

    /// The item nearest to `p` by `distance2(item)` (a squared distance that is at least the
    /// squared distance to the item's box) among those `accept` takes, if one is within
    /// `within2`, with that squared distance. `accept` is asked only of an item nearer than any
    /// taken so far: a costly test runs on a few candidates, not on every one.
    ///
    /// Searches rings of cells outwards from `p`'s cell; every point of ring `r + 1` is at least
    /// `r` cells from `p`, which ends the search.
    pub fn nearest(
        &self,
        p: Vec2,
        within2: f32,
        distance2: impl Fn(u32) -> f32,
        accept: impl Fn(u32) -> bool,
    ) -> Option<(u32, f32)> {
        let (pc, pr) = self.cell_of(p);
        let mut best: Option<(u32, f32)> = None;
        for r in 0..=self.cols.max(self.rows) {
            let (c0, c1) = (pc.saturating_sub(r), (pc + r).min(self.cols - 1));
            let (r0, r1) = (pr.saturating_sub(r), (pr + r).min(self.rows - 1));
            for row in r0..=r1 {
                let on_edge_row = row + r == pr || row == pr + r;
                // Inner rows of the ring hold only its left and right cells.
                let step = if on_edge_row { 1 } else { (2 * r).max(1) };
                let mut col = pc as isize - r as isize;
                while col <= (pc + r) as isize {
                    if col >= c0 as isize && col <= c1 as isize {
                        let range = self.cell_range(col as usize, row);
                        for (&item, &(lo, hi)) in self.items[range.clone()].iter().zip(&self.boxes[range]) {
                            let to_box = (lo - p).max(p - hi).max(Vec2::ZERO).length_squared();
                            if to_box > within2 || best.is_some_and(|(_, b)| to_box >= b) {
                                continue;
                            }
                            let d2 = distance2(item);
                            if d2 <= within2 && best.is_none_or(|(_, b)| d2 < b) && accept(item) {
                                best = Some((item, d2));
                            }
                        }
                    }
                    col += step as isize;
                }
            }
            let reach = r as f32 * self.cell_px;
            if best.map_or(within2, |(_, b)| b) <= reach * reach {
                break;
            }
        }
        best
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Squared distance from `p` to the segment `[a, b]`.
    fn to_segment2(p: Vec2, [a, b]: [Vec2; 2]) -> f32 {
        let t = ((p - a).dot(b - a) / (b - a).length_squared().max(1e-12)).clamp(0.0, 1.0);
        (p - a - t * (b - a)).length_squared()
    }

    #[test]
    fn the_nearest_item_is_the_brute_force_one_for_queries_anywhere_and_cells_of_any_size() {
        // Short segments in a patch of a 200x100 image (a few past its edge), queried inside the
        // patch, around it, beyond the image; every other item refused; within a reach or not.
        let mut state = 12345u64;
        let mut uniform = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 40) as f32 / (1u64 << 24) as f32
        };
        let segments: Vec<[Vec2; 2]> = (0..400)
            .map(|_| {
                let a = Vec2::new(60.0 + 150.0 * uniform(), 20.0 + 50.0 * uniform());
                [a, a + Vec2::new(6.0 * uniform() - 3.0, 6.0 * uniform() - 3.0)]
            })
            .collect();
        let boxes: Vec<(u32, Vec2, Vec2)> = segments
            .iter()
            .enumerate()
            .map(|(k, [a, b])| (k as u32, a.min(*b), a.max(*b)))
            .collect();
        let queries: Vec<Vec2> = (0..300)
            .map(|_| Vec2::new(260.0 * uniform() - 30.0, 160.0 * uniform() - 30.0))
            .collect();
        for (across, max_cell) in [(0.5, 64.0), (4.0, 16.0), (40.0, 8.0), (1.0, 1.0)] {
            let grid = BoxGrid::new(200, 100, &boxes, across, max_cell);
            for &p in &queries {
                for within2 in [f32::INFINITY, 25.0] {
                    let accept = |k: u32| k.is_multiple_of(2);
                    let found = grid.nearest(p, within2, |k| to_segment2(p, segments[k as usize]), accept);
                    let brute = (0..segments.len() as u32)
                        .filter(|&k| accept(k))
                        .map(|k| to_segment2(p, segments[k as usize]))
                        .filter(|&d2| d2 <= within2)
                        .fold(None, |best: Option<f32>, d2| Some(best.map_or(d2, |b| b.min(d2))));
                    assert_eq!(
                        found.map(|(_, d2)| d2),
                        brute,
                        "query {p} within {within2}, cells {across} items across (at most {max_cell} px)"
                    );
                    if let Some((k, _)) = found {
                        assert!(accept(k));
                    }
                }
            }
        }
    }
}
