//! One layer's extrusion paths before ordering: points with the feature of the move that
//! reaches each point, grouped into closed loops (perimeters, skirt) and open runs (infill).

use crate::geom::Point2;

use super::{Buffer, Feature};

/// What a path is, for ordering.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum PathKind {
    /// The skirt loop (first layer).
    Skirt,
    /// A perimeter loop; 0 is the external one.
    Perimeter(u8),
    /// An infill run (sparse, solid or top, possibly mixed).
    Infill,
}

/// One path: `len` points from `start`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PathRec {
    /// First point.
    pub start: u32,
    /// Number of points.
    pub len: u32,
    /// The island it belongs to.
    pub island: u16,
    /// Skirt, perimeter or infill.
    pub kind: PathKind,
    /// Closed loop (the last point joins the first).
    pub closed: bool,
    /// May be printed from either end.
    pub reversible: bool,
    /// Already printed.
    pub done: bool,
}

/// An empty record.
pub const EMPTY_REC: PathRec = PathRec::EMPTY;

impl PathRec {
    const EMPTY: Self = Self {
        start: 0,
        len: 0,
        island: 0,
        kind: PathKind::Infill,
        closed: false,
        reversible: false,
        done: false,
    };
}

/// Bounded path storage: `N` points, `R` paths.
pub struct PathBuf<const N: usize, const R: usize> {
    pts: [Point2; N],
    feat: [Feature; N],
    n: usize,
    recs: [PathRec; R],
    nr: usize,
    open: usize,
    /// Largest point and path counts seen.
    pub peak_points: usize,
    /// Largest path count seen.
    pub peak_paths: usize,
}

impl<const N: usize, const R: usize> Default for PathBuf<N, R> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize, const R: usize> PathBuf<N, R> {
    /// Empty.
    pub const fn new() -> Self {
        Self {
            pts: [Point2::new(0, 0); N],
            feat: [Feature::Travel; N],
            n: 0,
            recs: [PathRec::EMPTY; R],
            nr: 0,
            open: 0,
            peak_points: 0,
            peak_paths: 0,
        }
    }

    /// Removes every path.
    pub fn clear(&mut self) {
        self.n = 0;
        self.nr = 0;
        self.open = 0;
    }

    /// Appends a point reached by a move of `feature` to the path being built (a repeat of
    /// the previous point is skipped).
    pub fn push(&mut self, p: Point2, feature: Feature) -> Result<(), Buffer> {
        if self.n > self.open && self.pts[self.n - 1] == p {
            return Ok(());
        }
        if self.n >= N {
            return Err(Buffer::PathPoints);
        }
        self.pts[self.n] = p;
        self.feat[self.n] = feature;
        self.n += 1;
        self.peak_points = self.peak_points.max(self.n);
        Ok(())
    }

    /// The `k`-th point of the path being built, counted from its end (0 = last).
    pub fn open_point_from_end(&self, k: usize) -> Option<Point2> {
        (k < self.n - self.open).then(|| self.pts[self.n - 1 - k])
    }

    /// Moves the `k`-th point from the end of the path being built (0 = last) or, with
    /// `from_start`, from its start.
    pub fn set_open_point(&mut self, k: usize, from_start: bool, p: Point2) {
        if k < self.n - self.open {
            let i = if from_start { self.open + k } else { self.n - 1 - k };
            self.pts[i] = p;
        }
    }

    /// Points of the path being built.
    pub fn open_len(&self) -> usize {
        self.n - self.open
    }

    /// Ends the path being built (dropped below 2 points, or 3 for a loop).
    pub fn end(
        &mut self,
        island: u16,
        kind: PathKind,
        closed: bool,
        reversible: bool,
    ) -> Result<(), Buffer> {
        let len = self.n - self.open;
        if len < if closed { 3 } else { 2 } {
            self.n = self.open;
            return Ok(());
        }
        if self.nr >= R {
            return Err(Buffer::Paths);
        }
        self.recs[self.nr] = PathRec {
            start: self.open as u32,
            len: len as u32,
            island,
            kind,
            closed,
            reversible,
            done: false,
        };
        self.nr += 1;
        self.peak_paths = self.peak_paths.max(self.nr);
        self.open = self.n;
        Ok(())
    }

    /// Adds a closed loop with one feature.
    pub fn add_loop(
        &mut self,
        pts: &[Point2],
        feature: Feature,
        island: u16,
        kind: PathKind,
    ) -> Result<(), Buffer> {
        for &p in pts {
            self.push(p, feature)?;
        }
        self.end(island, kind, true, true)
    }

    /// The paths.
    pub fn recs(&self) -> &[PathRec] {
        &self.recs[..self.nr]
    }

    /// Marks path `i` printed.
    pub fn set_done(&mut self, i: usize) {
        if let Some(r) = self.recs.get_mut(i) {
            r.done = true;
        }
    }

    /// Sorts the path records by island, keeping their order within an island.
    pub fn sort_by_island(&mut self) {
        // `start` grows with the order the paths were added in: a stable sort without
        // allocation.
        self.recs[..self.nr].sort_unstable_by_key(|r| (r.island, r.start));
    }

    /// Makes point `k` of closed path `i` its first (same loop, same direction).
    pub fn rotate_loop(&mut self, i: usize, k: usize) {
        let Some(r) = self.recs.get(i) else { return };
        let range = r.start as usize..(r.start + r.len) as usize;
        if !r.closed || k == 0 || k >= r.len as usize {
            return;
        }
        if let (Some(p), Some(f)) = (self.pts.get_mut(range.clone()), self.feat.get_mut(range)) {
            p.rotate_left(k);
            f.rotate_left(k);
        }
    }

    /// Points of `r`.
    pub fn points(&self, r: &PathRec) -> &[Point2] {
        self.pts.get(r.start as usize..(r.start + r.len) as usize).unwrap_or(&[])
    }

    /// Features of `r`'s points.
    pub fn features(&self, r: &PathRec) -> &[Feature] {
        self.feat.get(r.start as usize..(r.start + r.len) as usize).unwrap_or(&[])
    }
}
