//! A uniform grid of axis-aligned boxes over the image, so that the candidates near a pixel cost
//! what is near it: the plan's work follows the silhouette's length, not pixels x triangles.

use glam::Vec2;

/// Items (triangles, edges) bucketed by the grid cells their boxes overlap, in CSR layout.
///
/// Boxes are clamped to the grid: an item beyond the image sits in the border cells, never
/// closer to a query inside the image than those cells (projection onto a box is non-expansive),
/// so the nearest-item search stays exact.
#[derive(Clone, Debug)]
pub(crate) struct BoxGrid {
    cell_px: f32,
    cols: usize,
    rows: usize,
    /// Items of cell `c` are `items[start[c]..start[c + 1]]`.
    start: Vec<u32>,
    items: Vec<u32>,
}

impl BoxGrid {
    /// Buckets `(item, min, max)` boxes (pixel coordinates) over a `width x height` image.
    pub fn new(width: usize, height: usize, cell_px: f32, boxes: &[(u32, Vec2, Vec2)]) -> Self {
        let cols = (width as f32 / cell_px).ceil().max(1.0) as usize;
        let rows = (height as f32 / cell_px).ceil().max(1.0) as usize;
        let mut grid = Self {
            cell_px,
            cols,
            rows,
            start: Vec::new(),
            items: Vec::new(),
        };
        let mut count = vec![0u32; cols * rows + 1];
        for &(_, lo, hi) in boxes {
            grid.for_cells(lo, hi, |c| count[c + 1] += 1);
        }
        for c in 0..cols * rows {
            count[c + 1] += count[c];
        }
        let mut fill = count.clone();
        let mut items = vec![0u32; count[cols * rows] as usize];
        for &(item, lo, hi) in boxes {
            grid.for_cells(lo, hi, |c| {
                items[fill[c] as usize] = item;
                fill[c] += 1;
            });
        }
        grid.start = count;
        grid.items = items;
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
        (clamp(p.x, self.cols), clamp(p.y, self.rows))
    }

    /// The items whose boxes overlap the cell holding `p`.
    pub fn items_at(&self, p: Vec2) -> &[u32] {
        let (c, r) = self.cell_of(p);
        self.cell_items(c, r)
    }

    fn cell_items(&self, c: usize, r: usize) -> &[u32] {
        let k = r * self.cols + c;
        &self.items[self.start[k] as usize..self.start[k + 1] as usize]
    }

    /// The item nearest to `p` by `distance2(item)` (a squared distance that is at least the
    /// squared distance to the item's box), with that squared distance; `None` for an empty grid.
    ///
    /// Searches rings of cells outwards from `p`'s cell; every point of ring `r + 1` is at least
    /// `r` cells from `p`, which ends the search.
    pub fn nearest(&self, p: Vec2, distance2: impl Fn(u32) -> f32) -> Option<(u32, f32)> {
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
                        for &item in self.cell_items(col as usize, row) {
                            let d2 = distance2(item);
                            if best.is_none_or(|(_, b)| d2 < b) {
                                best = Some((item, d2));
                            }
                        }
                    }
                    col += step as isize;
                }
            }
            if let Some((_, b)) = best {
                let reach = r as f32 * self.cell_px;
                if b <= reach * reach {
                    break;
                }
            }
        }
        best
    }
}
