//! One layer's extrusion paths before ordering: points with the feature of the move that
//! reaches each point, grouped into closed loops (perimeters, skirt) and open runs (infill).
//!
//! Points fill the slot array from the front and the path records its end, two slots each
//! (start, length, island, kind and flags), so a layer of many short runs and one of a few
//! long loops share one capacity. A slot is 48 bits in three `u16`s (6 bytes): a point's x
//! and y as 22-bit signed um (+-2.09 m) and the feature of the move reaching it in 4 bits.

use crate::geom::Point2;

use super::{Buffer, Feature};

/// What a path is, for ordering.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum PathKind {
    /// The skirt loop (first layer).
    Skirt,
    /// A brim loop (first layer): printed after the skirt, nearest first.
    Brim,
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
    /// Skirt, brim, perimeter or infill.
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

/// Bounded path storage: `N` slots of points, path records included (2 each).
pub struct PathBuf<const N: usize> {
    pts: [Slot; N],
    n: usize,
    nr: usize,
    open: usize,
    /// A point of the path being built was moved out of the packed range: its end fails.
    out_of_range: bool,
    /// Largest use of the points (records included).
    pub peak_points: usize,
    /// Largest path count seen.
    pub peak_paths: usize,
    /// Slots not to use ([`set_limit`](Self::set_limit)): 0 in a new buffer, which is then
    /// all zero bytes (a `static` of it stays in `.bss`).
    unused: usize,
}

impl<const N: usize> Default for PathBuf<N> {
    fn default() -> Self {
        Self::new()
    }
}

/// One stored point (or half a record): 48 bits, low word first.
pub type Slot = [u16; 3];

/// Record flags (above the kind code, whose largest value `3 + 255` takes 9 bits).
const CLOSED: u16 = 1 << 12;
const REVERSIBLE: u16 = 1 << 13;
const DONE: u16 = 1 << 14;
/// The kind code's bits in a record's last word.
const KIND_MASK: u16 = (1 << 12) - 1;

/// Bits of a stored point holding its feature (the lowest ones).
const FEATURE_BITS: u32 = 4;
/// Bits of each stored coordinate (signed).
const COORD_BITS: u32 = 22;
/// Path point coordinates that pack, um (both x and y).
const COORD_RANGE: core::ops::RangeInclusive<i32> =
    -(1 << (COORD_BITS - 1))..=(1 << (COORD_BITS - 1)) - 1;

fn slot_of(bits: u64) -> Slot {
    [bits as u16, (bits >> 16) as u16, (bits >> 32) as u16]
}

fn bits_of(s: Slot) -> u64 {
    u64::from(s[0]) | u64::from(s[1]) << 16 | u64::from(s[2]) << 32
}

/// `p` with `feature` (y in bits 4..26, x in 26..48); `None` outside [`COORD_RANGE`].
fn pack(p: Point2, feature: Feature) -> Option<Slot> {
    let mask = (1u64 << COORD_BITS) - 1;
    (COORD_RANGE.contains(&p.x) && COORD_RANGE.contains(&p.y)).then(|| {
        slot_of(
            (p.x as u64 & mask) << (FEATURE_BITS + COORD_BITS)
                | (p.y as u64 & mask) << FEATURE_BITS
                | feature as u64,
        )
    })
}

/// The point of a stored path point.
fn unpack(s: Slot) -> Point2 {
    // Shift the field to the top of an i64, then back with sign extension.
    let b = bits_of(s) as i64;
    let top = 64 - FEATURE_BITS - 2 * COORD_BITS;
    let x = b << top >> (64 - COORD_BITS);
    let y = b << (top + COORD_BITS) >> (64 - COORD_BITS);
    Point2::new(x as i32, y as i32)
}

/// The feature of a stored path point.
fn unpack_feature(s: Slot) -> Feature {
    Feature::ALL
        .get((s[0] & ((1 << FEATURE_BITS) - 1)) as usize)
        .copied()
        .unwrap_or(Feature::Travel)
}

// Every feature's code fits the bits; a point's fields fill the slot.
const _: () = assert!(Feature::ALL.len() <= 1 << FEATURE_BITS);
const _: () = assert!(FEATURE_BITS + 2 * COORD_BITS == 48);

/// The points of one path, unpacked on access.
#[derive(Clone, Copy)]
pub struct PathPoints<'a>(&'a [Slot]);

impl PathPoints<'_> {
    /// Number of points.
    #[inline]
    pub fn len(&self) -> usize {
        self.0.len()
    }

    /// True without points.
    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }

    /// Point `i` (panics past the end, like a slice).
    #[inline]
    pub fn at(&self, i: usize) -> Point2 {
        unpack(self.0[i])
    }

    /// The feature of the move reaching point `i`.
    #[inline]
    pub fn feature(&self, i: usize) -> Feature {
        unpack_feature(self.0[i])
    }

    /// The first point.
    pub fn first(&self) -> Option<Point2> {
        self.0.first().map(|&s| unpack(s))
    }

    /// The last point.
    pub fn last(&self) -> Option<Point2> {
        self.0.last().map(|&s| unpack(s))
    }

    /// The points in order.
    pub fn iter(&self) -> impl Iterator<Item = Point2> + '_ {
        self.0.iter().map(|&s| unpack(s))
    }
}

impl PathKind {
    /// 0 skirt, 1 infill, 2 brim, `3 + depth` perimeter.
    fn code(self) -> u16 {
        match self {
            Self::Skirt => 0,
            Self::Infill => 1,
            Self::Brim => 2,
            Self::Perimeter(d) => 3 + u16::from(d),
        }
    }

    fn from_code(c: u16) -> Self {
        match c {
            0 => Self::Skirt,
            1 => Self::Infill,
            2 => Self::Brim,
            _ => Self::Perimeter((c - 3).clamp(0, 255) as u8),
        }
    }
}

impl<const N: usize> PathBuf<N> {
    /// Empty.
    pub const fn new() -> Self {
        Self {
            pts: [[0; 3]; N],
            n: 0,
            nr: 0,
            open: 0,
            out_of_range: false,
            peak_points: 0,
            peak_paths: 0,
            unused: 0,
        }
    }

    /// Uses at most `limit` of the `N` slots (records included) from now on, as a smaller
    /// buffer would: pushes beyond fail with [`Buffer::PathPoints`] or [`Buffer::Paths`].
    pub fn set_limit(&mut self, limit: usize) {
        self.unused = N - limit.min(N);
    }

    /// Index of the first of record `i`'s two slots.
    fn slot(&self, i: usize) -> Option<usize> {
        (i < self.nr).then(|| N - 2 * (i + 1))
    }

    /// Points free between the paths and the records.
    fn room(&self) -> usize {
        (N - self.unused).saturating_sub(2 * self.nr + self.n)
    }

    fn write_rec(&mut self, i: usize, r: &PathRec) {
        let Some(k) = self.slot(i) else { return };
        let flags = if r.closed { CLOSED } else { 0 }
            | if r.reversible { REVERSIBLE } else { 0 }
            | if r.done { DONE } else { 0 };
        let (start, len) = (r.start, r.len);
        self.pts[k] = [start as u16, (start >> 16) as u16, len as u16];
        self.pts[k + 1] = [(len >> 16) as u16, r.island, r.kind.code() | flags];
    }

    /// Path `i`.
    pub fn get(&self, i: usize) -> Option<PathRec> {
        let k = self.slot(i)?;
        let (a, b) = (self.pts[k], self.pts[k + 1]);
        Some(PathRec {
            start: u32::from(a[0]) | u32::from(a[1]) << 16,
            len: u32::from(a[2]) | u32::from(b[0]) << 16,
            island: b[1],
            kind: PathKind::from_code(b[2] & KIND_MASK),
            closed: b[2] & CLOSED != 0,
            reversible: b[2] & REVERSIBLE != 0,
            done: b[2] & DONE != 0,
        })
    }

    /// Path `i` (an empty record past the end).
    pub fn rec(&self, i: usize) -> PathRec {
        self.get(i).unwrap_or(EMPTY_REC)
    }

    /// Number of paths.
    pub fn len(&self) -> usize {
        self.nr
    }

    /// True without paths.
    pub fn is_empty(&self) -> bool {
        self.nr == 0
    }

    /// The first path index for which `pred` is false (`pred` true on a prefix).
    pub fn partition_point(&self, pred: impl Fn(&PathRec) -> bool) -> usize {
        let (mut lo, mut hi) = (0, self.nr);
        while lo < hi {
            let mid = (lo + hi) / 2;
            if pred(&self.rec(mid)) {
                lo = mid + 1;
            } else {
                hi = mid;
            }
        }
        lo
    }

    /// Removes every path.
    pub fn clear(&mut self) {
        self.n = 0;
        self.nr = 0;
        self.open = 0;
        self.out_of_range = false;
    }

    /// Appends a point reached by a move of `feature` to the path being built (a repeat of
    /// the previous point is skipped). Fails when full or with a coordinate outside +-2^21 um.
    pub fn push(&mut self, p: Point2, feature: Feature) -> Result<(), Buffer> {
        if self.n > self.open && unpack(self.pts[self.n - 1]) == p {
            return Ok(());
        }
        if self.room() == 0 {
            return Err(Buffer::PathPoints);
        }
        self.pts[self.n] = pack(p, feature).ok_or(Buffer::PathRange)?;
        self.n += 1;
        self.peak_points = self.peak_points.max(self.n + 2 * self.nr);
        Ok(())
    }

    /// The `k`-th point of the path being built, counted from its end (0 = last).
    pub fn open_point_from_end(&self, k: usize) -> Option<Point2> {
        (k < self.n - self.open).then(|| unpack(self.pts[self.n - 1 - k]))
    }

    /// Moves the `k`-th point from the end of the path being built (0 = last) or, with
    /// `from_start`, from its start (keeping its feature). Outside the packed range the
    /// point stays and the path's [`end`](Self::end) fails.
    pub fn set_open_point(&mut self, k: usize, from_start: bool, p: Point2) {
        if k < self.n - self.open {
            let i = if from_start { self.open + k } else { self.n - 1 - k };
            match pack(p, unpack_feature(self.pts[i])) {
                Some(s) => self.pts[i] = s,
                None => self.out_of_range = true,
            }
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
        if core::mem::take(&mut self.out_of_range) {
            self.n = self.open;
            return Err(Buffer::PathRange);
        }
        let len = self.n - self.open;
        if len < if closed { 3 } else { 2 } {
            self.n = self.open;
            return Ok(());
        }
        if self.room() < 2 {
            return Err(Buffer::Paths);
        }
        self.nr += 1;
        let r = PathRec {
            start: self.open as u32,
            len: len as u32,
            island,
            kind,
            closed,
            reversible,
            done: false,
        };
        self.write_rec(self.nr - 1, &r);
        self.peak_paths = self.peak_paths.max(self.nr);
        self.peak_points = self.peak_points.max(self.n + 2 * self.nr);
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

    /// Marks path `i` printed.
    pub fn set_done(&mut self, i: usize) {
        if let Some(k) = self.slot(i) {
            self.pts[k + 1][2] |= DONE;
        }
    }

    /// Sorts the path records by island, keeping their order within an island (insertion
    /// sort in place: records of one island mostly come together).
    pub fn sort_by_island(&mut self) {
        let key = |r: &PathRec| (r.island, r.start);
        for i in 1..self.nr {
            let r = self.rec(i);
            let mut j = i;
            while j > 0 && key(&self.rec(j - 1)) > key(&r) {
                let prev = self.rec(j - 1);
                self.write_rec(j, &prev);
                j -= 1;
            }
            if j != i {
                self.write_rec(j, &r);
            }
        }
    }

    /// Sets the feature of the move reaching point `k` of path `i`.
    pub fn set_feature(&mut self, i: usize, k: usize, feature: Feature) {
        let Some(r) = self.get(i).filter(|r| k < r.len as usize) else { return };
        if let Some(s) = self.pts.get_mut(r.start as usize + k) {
            s[0] = s[0] & !((1 << FEATURE_BITS) - 1) | feature as u16;
        }
    }

    /// Makes point `k` of closed path `i` its first (same loop, same direction).
    pub fn rotate_loop(&mut self, i: usize, k: usize) {
        let Some(r) = self.get(i) else { return };
        let range = r.start as usize..(r.start + r.len) as usize;
        if !r.closed || k == 0 || k >= r.len as usize {
            return;
        }
        if let Some(p) = self.pts.get_mut(range) {
            p.rotate_left(k);
        }
    }

    /// Points of `r`, with their features.
    pub fn points(&self, r: &PathRec) -> PathPoints<'_> {
        PathPoints(self.pts.get(r.start as usize..(r.start + r.len) as usize).unwrap_or(&[]))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_kind_survives_its_record() {
        let kinds = [
            PathKind::Skirt,
            PathKind::Brim,
            PathKind::Infill,
            PathKind::Perimeter(0),
            PathKind::Perimeter(255),
        ];
        let mut b = PathBuf::<64>::new();
        for (i, &kind) in kinds.iter().enumerate() {
            let pts = [Point2::new(0, 0), Point2::new(10, 0), Point2::new(i as i32, 10)];
            b.add_loop(&pts, Feature::Brim, i as u16, kind).unwrap();
        }
        for (i, &kind) in kinds.iter().enumerate() {
            let r = b.rec(i);
            assert_eq!((r.kind, r.island, r.closed, r.done), (kind, i as u16, true, false));
            assert_eq!(b.points(&r).feature(1), Feature::Brim);
        }
        b.set_done(1);
        assert_eq!((b.rec(1).kind, b.rec(1).done), (PathKind::Brim, true));
    }

    #[test]
    fn records_share_the_points_and_sort_by_island() {
        let mut b = PathBuf::<16>::new();
        let pts = [Point2::new(0, 0), Point2::new(10, 0), Point2::new(0, 10)];
        b.add_loop(&pts, Feature::Perimeter, 2, PathKind::Perimeter(1)).unwrap();
        b.push(Point2::new(5, 5), Feature::SolidInfill).unwrap();
        b.push(Point2::new(6, 6), Feature::SolidInfill).unwrap();
        b.end(1, PathKind::Infill, false, true).unwrap();
        // 5 points and 2 records of 2: 7 left of 16.
        assert_eq!((b.len(), b.peak_points), (2, 9));
        b.set_done(1);
        b.sort_by_island();
        let (r0, r1) = (b.rec(0), b.rec(1));
        assert_eq!((r0.island, r0.start, r0.len, r0.kind), (1, 3, 2, PathKind::Infill));
        assert!(r0.done && r0.reversible && !r0.closed);
        assert_eq!(
            (r1.island, r1.kind, r1.closed, r1.done),
            (2, PathKind::Perimeter(1), true, false)
        );
        assert!(b.points(&r1).iter().eq(pts));
        assert_eq!(b.points(&r1).feature(2), Feature::Perimeter);
        assert_eq!(b.points(&r0).feature(1), Feature::SolidInfill);
        assert_eq!(b.partition_point(|r| r.island < 2), 1);
        // Full: a path needs its points and two more for its record.
        for k in 0..6 {
            b.push(Point2::new(k, 100), Feature::InternalInfill).unwrap();
        }
        assert_eq!(b.end(0, PathKind::Infill, false, false), Err(Buffer::Paths));
        assert_eq!(b.push(Point2::new(9, 9), Feature::InternalInfill), Ok(()));
        assert_eq!(b.push(Point2::new(9, 8), Feature::InternalInfill), Err(Buffer::PathPoints));
    }

    #[test]
    fn a_slot_gives_back_every_point_and_feature_in_range() {
        let features = Feature::ALL;
        assert!(features.iter().enumerate().all(|(i, &f)| f as usize == i));
        let (lo, hi) = (*COORD_RANGE.start(), *COORD_RANGE.end());
        let mut coords = vec![lo, lo + 1, -1, 0, 1, hi - 1, hi, 220_000, -12_345];
        // A xorshift walk over the whole range.
        let mut r = 0x9E37_79B9_7F4A_7C15u64;
        for _ in 0..200 {
            r ^= r << 13;
            r ^= r >> 7;
            r ^= r << 17;
            coords.push(lo + (r % (1 << COORD_BITS)) as i32);
        }
        for (i, &x) in coords.iter().enumerate() {
            for (j, &y) in coords.iter().enumerate() {
                let f = features[(i + j) % features.len()];
                let s = pack(Point2::new(x, y), f).unwrap();
                assert_eq!((unpack(s), unpack_feature(s)), (Point2::new(x, y), f));
            }
        }
    }

    #[test]
    fn points_beyond_the_packed_range_are_refused() {
        let mut b = PathBuf::<16>::new();
        let far = Point2::new(0, 1 << 21);
        assert_eq!(b.push(far, Feature::Skirt), Err(Buffer::PathRange));
        let edge = Point2::new(-(1 << 21), -(1 << 21));
        b.push(edge, Feature::TopSolidInfill).unwrap();
        b.push(Point2::new((1 << 21) - 1, (1 << 21) - 1), Feature::Unretract).unwrap();
        assert_eq!(b.push(Point2::new(1 << 21, 0), Feature::Skirt), Err(Buffer::PathRange));
        assert_eq!(b.open_point_from_end(1), Some(edge));
        // A moved point out of range fails the path's end, which drops it.
        b.set_open_point(0, true, far);
        assert_eq!(b.end(0, PathKind::Infill, false, true), Err(Buffer::PathRange));
        assert_eq!((b.len(), b.open_len()), (0, 0));
        b.push(edge, Feature::TopSolidInfill).unwrap();
        b.push(Point2::new(1, 2), Feature::Unretract).unwrap();
        b.end(0, PathKind::Infill, false, true).unwrap();
        let pts = b.points(&b.rec(0));
        assert_eq!((pts.at(0), pts.feature(0)), (edge, Feature::TopSolidInfill));
        assert_eq!((pts.last(), pts.feature(1)), (Some(Point2::new(1, 2)), Feature::Unretract));
    }
}
