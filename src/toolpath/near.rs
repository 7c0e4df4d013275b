//! Nearest-neighbour search over a bounded uniform grid.
//!
//! [`NearGrid`] buckets items (ids `0..n`, each at a point given by a lookup function, or
//! absent) into a uniform grid of at most `head.len()` cells laid over the items' bounding
//! box, as singly linked lists in two caller-provided `u32` buffers (one entry per cell, one
//! per item): nothing is allocated and nothing else is stored. [`NearGrid::nearest`] searches
//! rings of cells outwards from the query point's cell and stops as soon as no unvisited cell
//! can hold anything closer, so it returns exactly what a brute-force scan returns: the
//! accepted item with the smallest squared distance, the smallest id among equals.
//!
//! Building fails with [`GridFull`] when the item buffer is shorter than the items; callers
//! then scan all items instead (the same answer, in quadratic time).

use crate::geom::Point2;

use super::poly::dist2;

/// No item (end of a cell's list).
const NONE: u32 = u32::MAX;

/// The item buffer is too short for the items.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct GridFull {
    /// Items to index.
    pub items: usize,
    /// Entries of the item buffer.
    pub capacity: usize,
}

/// A uniform grid of item lists over borrowed buffers.
pub struct NearGrid<'a> {
    head: &'a mut [u32],
    next: &'a mut [u32],
    origin: Point2,
    cell: i64,
    nx: i64,
    ny: i64,
    /// Items indexed.
    items: usize,
}

/// Where a [`NearGrid`]'s cells lie, without its buffers: an owner that keeps the buffers
/// untouched between calls takes the grid up again with [`NearGrid::resume`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct GridShape {
    origin: Point2,
    cell: i64,
    nx: i64,
    ny: i64,
    /// Items indexed (entries of the item buffer in use).
    items: usize,
}

impl<'a> NearGrid<'a> {
    /// Indexes items `0..n` at `pos(id)` (`None`: not indexed) in a grid of at most
    /// `head.len()` cells (about one item per cell). Errors when `next` is shorter than `n`
    /// or `head` is empty.
    pub fn build(
        n: usize,
        pos: impl Fn(u32) -> Option<Point2>,
        head: &'a mut [u32],
        next: &'a mut [u32],
    ) -> Result<Self, GridFull> {
        if next.len() < n || head.is_empty() || n >= NONE as usize {
            return Err(GridFull { items: n, capacity: next.len() });
        }
        let (mut lo, mut hi) = (Point2::new(i32::MAX, i32::MAX), Point2::new(i32::MIN, i32::MIN));
        let mut count = 0usize;
        for id in 0..n as u32 {
            if let Some(p) = pos(id) {
                lo = Point2::new(lo.x.min(p.x), lo.y.min(p.y));
                hi = Point2::new(hi.x.max(p.x), hi.y.max(p.y));
                count += 1;
            }
        }
        if count == 0 {
            lo = Point2::new(0, 0);
            hi = lo;
        }
        let w = i64::from(hi.x) - i64::from(lo.x) + 1;
        let h = i64::from(hi.y) - i64::from(lo.y) + 1;
        let cells = count.clamp(1, head.len()) as i64;
        // Square cells of about `w h / cells`, grown until the grid has at most `cells`.
        let mut cell = (crate::math::isqrt_u64(((w * h) / cells).max(1) as u64) as i64).max(1);
        let dims = |c: i64| ((w + c - 1) / c, (h + c - 1) / c);
        loop {
            let (nx, ny) = dims(cell);
            if nx * ny <= cells {
                break;
            }
            cell += cell / 8 + 1;
        }
        let (nx, ny) = dims(cell);
        let g = Self { head, next, origin: lo, cell, nx, ny, items: n };
        for c in g.head.iter_mut() {
            *c = NONE;
        }
        // Insert in decreasing id order so every list is sorted by increasing id.
        for id in (0..n as u32).rev() {
            if let Some(p) = pos(id) {
                let c = g.cell_of(p);
                g.next[id as usize] = g.head[c];
                g.head[c] = id;
            }
        }
        Ok(g)
    }

    /// The grid's shape, to [`resume`](Self::resume) it later.
    pub fn shape(&self) -> GridShape {
        let (origin, cell, nx, ny, items) = (self.origin, self.cell, self.nx, self.ny, self.items);
        GridShape { origin, cell, nx, ny, items }
    }

    /// The grid of `shape` over the buffers it was built in (and only changed by
    /// [`remove`](Self::remove) since); `None` when they are too short for it.
    pub fn resume(shape: GridShape, head: &'a mut [u32], next: &'a mut [u32]) -> Option<Self> {
        let cells = usize::try_from(shape.nx * shape.ny).ok()?;
        if head.len() < cells || next.len() < shape.items || shape.cell < 1 {
            return None;
        }
        let GridShape { origin, cell, nx, ny, items } = shape;
        Some(Self { head, next, origin, cell, nx, ny, items })
    }

    /// Cells along x and y.
    pub fn dims(&self) -> (usize, usize) {
        (self.nx as usize, self.ny as usize)
    }

    fn clamp_xy(&self, p: Point2) -> (i64, i64) {
        let cx = ((i64::from(p.x) - i64::from(self.origin.x)).div_euclid(self.cell))
            .clamp(0, self.nx - 1);
        let cy = ((i64::from(p.y) - i64::from(self.origin.y)).div_euclid(self.cell))
            .clamp(0, self.ny - 1);
        (cx, cy)
    }

    fn cell_of(&self, p: Point2) -> usize {
        let (cx, cy) = self.clamp_xy(p);
        (cy * self.nx + cx) as usize
    }

    /// Unlinks item `id` (at `at`, where it was indexed); no effect if it is not there.
    pub fn remove(&mut self, id: u32, at: Point2) {
        let c = self.cell_of(at);
        let mut prev = NONE;
        let mut cur = self.head[c];
        while cur != NONE {
            let nxt = self.next[cur as usize];
            if cur == id {
                if prev == NONE {
                    self.head[c] = nxt;
                } else {
                    self.next[prev as usize] = nxt;
                }
                return;
            }
            prev = cur;
            cur = nxt;
        }
    }

    /// The accepted item nearest to `p`: (squared distance, id), the smallest id among
    /// equally near ones; `None` if no indexed item is accepted.
    pub fn nearest(
        &self,
        p: Point2,
        pos: impl Fn(u32) -> Option<Point2>,
        accept: impl FnMut(u32) -> bool,
    ) -> Option<(i64, u32)> {
        self.search(p, (0, 0, self.nx - 1, self.ny - 1), pos, accept)
    }

    /// [`nearest`](Self::nearest) among the items inside the box `lo`..=`hi` (`None` for an
    /// empty box; only the cells
    /// it overlaps are searched, so an accepted item outside it may be missed: the caller
    /// makes sure there is none). A search that finds nothing costs the box's cells, not
    /// the whole grid's.
    pub fn nearest_in(
        &self,
        p: Point2,
        lo: Point2,
        hi: Point2,
        pos: impl Fn(u32) -> Option<Point2>,
        accept: impl FnMut(u32) -> bool,
    ) -> Option<(i64, u32)> {
        if lo.x > hi.x || lo.y > hi.y {
            return None;
        }
        let (x0, y0) = self.clamp_xy(lo);
        let (x1, y1) = self.clamp_xy(hi);
        self.search(p, (x0, y0, x1, y1), pos, accept)
    }

    /// Ring search from `p`'s cell within the cell window `(x0, y0, x1, y1)` (inclusive).
    fn search(
        &self,
        p: Point2,
        (wx0, wy0, wx1, wy1): (i64, i64, i64, i64),
        pos: impl Fn(u32) -> Option<Point2>,
        mut accept: impl FnMut(u32) -> bool,
    ) -> Option<(i64, u32)> {
        let (cx, cy) = self.clamp_xy(p);
        let (cx, cy) = (cx.clamp(wx0, wx1), cy.clamp(wy0, wy1));
        let mut best: Option<(i64, u32)> = None;
        let mut visit = |c: usize, best: &mut Option<(i64, u32)>| {
            let mut id = self.head[c];
            while id != NONE {
                if let Some(q) = pos(id) {
                    let d = dist2(p, q);
                    if best.map_or(true, |b| (d, id) < b) && accept(id) {
                        *best = Some((d, id));
                    }
                }
                id = self.next[id as usize];
            }
        };
        let (ox, oy) = (i64::from(self.origin.x), i64::from(self.origin.y));
        let (px, py) = (i64::from(p.x), i64::from(p.y));
        let rmax = (wx1 - wx0).max(wy1 - wy0);
        for r in 0..=rmax {
            let (x0, x1, y0, y1) = (cx - r, cx + r, cy - r, cy + r);
            for y in y0.max(wy0)..=y1.min(wy1) {
                let row = y * self.nx;
                if y == y0 || y == y1 {
                    for x in x0.max(wx0)..=x1.min(wx1) {
                        visit((row + x) as usize, &mut best);
                    }
                } else {
                    for x in [x0, x1] {
                        if (wx0..=wx1).contains(&x) {
                            visit((row + x) as usize, &mut best);
                        }
                    }
                }
            }
            // Anything not visited yet lies beyond a side of the searched square that is
            // inside the window, at least that side's distance from `p`.
            let mut bound = i64::MAX;
            if x0 > wx0 {
                bound = bound.min((px - (ox + x0 * self.cell)).max(0));
            }
            if x1 < wx1 {
                bound = bound.min((ox + (x1 + 1) * self.cell - px).max(0));
            }
            if y0 > wy0 {
                bound = bound.min((py - (oy + y0 * self.cell)).max(0));
            }
            if y1 < wy1 {
                bound = bound.min((oy + (y1 + 1) * self.cell - py).max(0));
            }
            if bound == i64::MAX {
                break;
            }
            // Strictly closer: an item at exactly `bound` could have a smaller id.
            if let Some((d, _)) = best {
                if d < bound.saturating_mul(bound) {
                    break;
                }
            }
        }
        best
    }
}

/// The accepted item nearest to `p` by scanning every item: what [`NearGrid::nearest`]
/// returns.
pub fn nearest_brute(
    n: usize,
    p: Point2,
    pos: impl Fn(u32) -> Option<Point2>,
    mut accept: impl FnMut(u32) -> bool,
) -> Option<(i64, u32)> {
    let mut best: Option<(i64, u32)> = None;
    for id in 0..n as u32 {
        if let Some(q) = pos(id) {
            let d = dist2(p, q);
            if best.map_or(true, |b| d < b.0) && accept(id) {
                best = Some((d, id));
            }
        }
    }
    best
}
