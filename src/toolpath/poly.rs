//! Bounded loop buffers and the integer helpers every toolpath stage shares.

use crate::geom::Point2;
use crate::math::{div_u128, isqrt_u64};

use super::Buffer;

/// `num / den` rounded to the nearest integer, halves away from zero (`den != 0`).
pub fn div_round(num: i64, den: i64) -> i64 {
    let (num, den) = if den < 0 { (-num, -den) } else { (num, den) };
    let (n, d) = (num.unsigned_abs() + den.unsigned_abs() / 2, den.unsigned_abs());
    // Operands that fit a word (most: offsets of short edges) take the hardware divider,
    // not the library's 64-bit division.
    let q = if n | d <= u64::from(u32::MAX) { u64::from(n as u32 / d as u32) } else { n / d };
    if num >= 0 {
        q as i64
    } else {
        -(q as i64)
    }
}

/// [`div_round`] in `i128`.
///
/// `(|num| + den / 2) / den` with the sign of `num / den`, the division by the planner's exact long
/// division (a 64-bit divisor takes two 32-bit digits on the hardware divider, not the library's
/// 128-bit loop; for `i64` operands the library's 64-bit division is faster and [`div_round`] keeps
/// it).
pub fn div_round_128(num: i128, den: i128) -> i128 {
    let (num, den) = if den < 0 { (-num, -den) } else { (num, den) };
    let den = den.unsigned_abs();
    let q = div_u128(num.unsigned_abs() + den / 2, den) as i128;
    if num >= 0 {
        q
    } else {
        -q
    }
}

/// Cross product of `b - a` and `c - a` (twice the signed triangle area), exact in `i64` for
/// coordinates below 2^30.
pub fn orient(a: Point2, b: Point2, c: Point2) -> i64 {
    let (abx, aby) = (i64::from(b.x) - i64::from(a.x), i64::from(b.y) - i64::from(a.y));
    let (acx, acy) = (i64::from(c.x) - i64::from(a.x), i64::from(c.y) - i64::from(a.y));
    abx * acy - aby * acx
}

/// Squared distance in um^2.
pub fn dist2(a: Point2, b: Point2) -> i64 {
    let (dx, dy) = (i64::from(b.x) - i64::from(a.x), i64::from(b.y) - i64::from(a.y));
    dx * dx + dy * dy
}

/// Distance rounded down to whole units.
pub fn dist(a: Point2, b: Point2) -> i64 {
    isqrt_u64(dist2(a, b) as u64) as i64
}

/// One closed loop of a [`LoopBuf`]: `points[start..start + len]`, closing edge implied.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Ring {
    /// Index of the first point.
    pub start: u32,
    /// Number of points.
    pub len: u32,
    /// Twice the signed area in um^2 (positive counter-clockwise: an outer boundary).
    pub area2: i64,
    /// Bounding box corner with the smallest x and y.
    pub min: Point2,
    /// Bounding box corner with the largest x and y.
    pub max: Point2,
    /// The island (group of loops) this loop belongs to.
    pub island: u16,
    /// Perimeter depth (0 = external) or another small tag.
    pub depth: u8,
    /// Index of the enclosing loop in the same buffer, `u16::MAX` if none.
    pub parent: u16,
}

impl Ring {
    /// No enclosing loop.
    pub const NO_PARENT: u16 = u16::MAX;

    /// True for a clockwise loop (a hole).
    pub fn is_hole(&self) -> bool {
        self.area2 < 0
    }
}

/// Closed loops in bounded storage: `P` points, `L` loops.
pub struct LoopBuf<const P: usize, const L: usize> {
    points: [Point2; P],
    /// The loops and counters.
    pub(crate) meta: LoopMeta<L>,
}

/// A loop buffer's loops and counters without its points, which are lent to it as a [`Loops`].
///
/// The toolpath stage keeps the points of its loops between offsets in the offset engine's
/// place in its working memory.
pub struct LoopMeta<const L: usize> {
    n_points: usize,
    rings: [Ring; L],
    n_rings: usize,
    /// Start of the loop being built.
    open: usize,
    /// Largest `n_points` and `n_rings` seen since creation (or [`reset`](Self::reset)).
    pub(crate) peak_points: usize,
    pub(crate) peak_rings: usize,
}

impl<const L: usize> LoopMeta<L> {
    /// Empty.
    pub const fn new() -> Self {
        Self {
            n_points: 0,
            rings: [Ring {
                start: 0,
                len: 0,
                area2: 0,
                min: Point2::new(0, 0),
                max: Point2::new(0, 0),
                island: 0,
                depth: 0,
                // Slots past `n_rings` are never read (`close` sets a ring's parent): zero,
                // so that an empty buffer is all zero bytes.
                parent: 0,
            }; L],
            n_rings: 0,
            open: 0,
            peak_points: 0,
            peak_rings: 0,
        }
    }

    /// Removes every loop.
    pub fn clear(&mut self) {
        self.n_points = 0;
        self.n_rings = 0;
        self.open = 0;
    }

    /// Removes every loop and forgets the peaks.
    pub fn reset(&mut self) {
        self.clear();
        self.peak_points = 0;
        self.peak_rings = 0;
    }

    /// The loops.
    pub fn rings(&self) -> &[Ring] {
        &self.rings[..self.n_rings]
    }

    /// Number of points of the loop being built.
    pub fn open_len(&self) -> usize {
        self.n_points - self.open
    }

    /// All points in use of `pts` (where these loops' points are), loop after loop.
    fn used<'p>(&self, pts: &'p [Point2]) -> &'p [Point2] {
        pts.get(..self.n_points).unwrap_or(&[])
    }

    /// The points of `r` in `pts`.
    fn ring_in<'p>(r: &Ring, pts: &'p [Point2]) -> &'p [Point2] {
        pts.get(r.start as usize..(r.start + r.len) as usize).unwrap_or(&[])
    }

    /// The points of the loop being built in `pts`.
    fn open_in<'p>(&self, pts: &'p mut [Point2]) -> &'p mut [Point2] {
        &mut pts[self.open..self.n_points]
    }
}

impl<const L: usize> Default for LoopMeta<L> {
    fn default() -> Self {
        Self::new()
    }
}

/// A [`LoopMeta`] with its points: a loop buffer whose points are borrowed (their capacity is
/// the slice's length).
pub struct Loops<'a, const L: usize> {
    points: &'a mut [Point2],
    meta: &'a mut LoopMeta<L>,
}

impl<'a, const L: usize> Loops<'a, L> {
    /// The loops of `meta`, their points in `points`.
    pub fn new(points: &'a mut [Point2], meta: &'a mut LoopMeta<L>) -> Self {
        Self { points, meta }
    }

    /// Removes every loop.
    pub fn clear(&mut self) {
        self.meta.clear();
    }

    /// The loops.
    pub fn rings(&self) -> &[Ring] {
        self.meta.rings()
    }

    /// All points, loop after loop.
    pub fn points(&self) -> &[Point2] {
        self.meta.used(self.points)
    }

    /// The points of `r`.
    pub fn ring_points(&self, r: &Ring) -> &[Point2] {
        LoopMeta::<L>::ring_in(r, self.points)
    }

    /// Number of points of the loop being built.
    pub fn open_len(&self) -> usize {
        self.meta.open_len()
    }

    /// The points of the loop being built.
    pub fn open_points_mut(&mut self) -> &mut [Point2] {
        self.meta.open_in(self.points)
    }

    /// Drops the loop being built.
    pub fn discard_open(&mut self) {
        self.meta.n_points = self.meta.open;
    }

    /// Keeps only the first `len` points of the loop being built.
    pub fn truncate_open(&mut self, len: usize) {
        self.meta.n_points = self.meta.open + len.min(self.open_len());
    }

    /// Appends a point to the loop being built.
    pub fn push(&mut self, p: Point2) -> Result<(), Buffer> {
        let m = &mut *self.meta;
        let slot = self.points.get_mut(m.n_points).ok_or(Buffer::LayerPoints)?;
        *slot = p;
        m.n_points += 1;
        m.peak_points = m.peak_points.max(m.n_points);
        Ok(())
    }

    /// Closes the loop being built (area and bounding box computed here); a loop of fewer than
    /// three points is dropped. Returns its index.
    pub fn close(&mut self, island: u16, depth: u8, parent: u16) -> Result<Option<usize>, Buffer> {
        let m = &mut *self.meta;
        let pts = &self.points[m.open..m.n_points];
        if pts.len() < 3 {
            m.n_points = m.open;
            return Ok(None);
        }
        let slot = m.rings.get_mut(m.n_rings).ok_or(Buffer::LayerLoops)?;
        let (mut min, mut max) = (pts[0], pts[0]);
        for p in pts {
            min = Point2::new(min.x.min(p.x), min.y.min(p.y));
            max = Point2::new(max.x.max(p.x), max.y.max(p.y));
        }
        *slot = Ring {
            start: m.open as u32,
            len: pts.len() as u32,
            area2: crate::geom::doubled_signed_area(pts),
            min,
            max,
            island,
            depth,
            parent,
        };
        m.n_rings += 1;
        m.peak_rings = m.peak_rings.max(m.n_rings);
        m.open = m.n_points;
        Ok(Some(m.n_rings - 1))
    }
}

impl<const P: usize, const L: usize> LoopBuf<P, L> {
    /// Empty.
    pub const fn new() -> Self {
        Self { points: [Point2::new(0, 0); P], meta: LoopMeta::new() }
    }

    /// The buffer as a [`Loops`] (what the offset engine writes).
    pub fn loops(&mut self) -> Loops<'_, L> {
        Loops::new(&mut self.points, &mut self.meta)
    }

    /// Removes every loop.
    pub fn clear(&mut self) {
        self.meta.clear();
    }

    /// The loops.
    pub fn rings(&self) -> &[Ring] {
        self.meta.rings()
    }

    /// All points, loop after loop.
    pub fn points(&self) -> &[Point2] {
        self.meta.used(&self.points)
    }

    /// The points of `r`.
    pub fn ring_points(&self, r: &Ring) -> &[Point2] {
        LoopMeta::<L>::ring_in(r, &self.points)
    }

    /// Number of points of the loop being built.
    pub fn open_len(&self) -> usize {
        self.meta.open_len()
    }

    /// The points of the loop being built.
    pub fn open_points_mut(&mut self) -> &mut [Point2] {
        self.meta.open_in(&mut self.points)
    }

    /// Drops the loop being built.
    pub fn discard_open(&mut self) {
        self.loops().discard_open();
    }

    /// Keeps only the first `len` points of the loop being built.
    pub fn truncate_open(&mut self, len: usize) {
        self.loops().truncate_open(len);
    }

    /// Appends a point to the loop being built.
    pub fn push(&mut self, p: Point2) -> Result<(), Buffer> {
        self.loops().push(p)
    }

    /// Closes the loop being built (area and bounding box computed here); a loop of fewer than
    /// three points is dropped. Returns its index.
    pub fn close(&mut self, island: u16, depth: u8, parent: u16) -> Result<Option<usize>, Buffer> {
        self.loops().close(island, depth, parent)
    }
}

impl<const P: usize, const L: usize> Default for LoopBuf<P, L> {
    fn default() -> Self {
        Self::new()
    }
}

/// Winding number of the loops in `rings` around `p` (crossings of a ray to +x): non-zero
/// inside a region bounded by counter-clockwise outer loops and clockwise holes.
pub fn winding(points: &[Point2], rings: &[Ring], p: Point2) -> i32 {
    let mut w = 0;
    for r in rings {
        if p.y < r.min.y || p.y > r.max.y || p.x > r.max.x {
            continue;
        }
        let pts = points.get(r.start as usize..(r.start + r.len) as usize).unwrap_or(&[]);
        let Some(&last) = pts.last() else { continue };
        let mut a = last;
        for &b in pts {
            if a.y <= p.y {
                if b.y > p.y && orient(a, b, p) > 0 {
                    w += 1;
                }
            } else if b.y <= p.y && orient(a, b, p) < 0 {
                w -= 1;
            }
            a = b;
        }
    }
    w
}

/// True when the open segments `a-b` and `c-d` share a point (touching included).
pub fn segments_touch(a: Point2, b: Point2, c: Point2, d: Point2) -> bool {
    if a.x.max(b.x) < c.x.min(d.x)
        || c.x.max(d.x) < a.x.min(b.x)
        || a.y.max(b.y) < c.y.min(d.y)
        || c.y.max(d.y) < a.y.min(b.y)
    {
        return false;
    }
    let (d1, d2) = (orient(c, d, a), orient(c, d, b));
    let (d3, d4) = (orient(a, b, c), orient(a, b, d));
    // Collinear segments (all four zero) share a point: their boxes overlap (checked above).
    !(((d1 > 0 && d2 > 0) || (d1 < 0 && d2 < 0)) || ((d3 > 0 && d4 > 0) || (d3 < 0 && d4 < 0)))
}

/// Does the segment a-b touch an edge of any ring (`points` holds the rings' corners)?
/// Rings and edges outside the segment's bounding box are skipped.
pub fn segment_touches_rings(points: &[Point2], rings: &[Ring], a: Point2, b: Point2) -> bool {
    let (lo, hi) =
        (Point2::new(a.x.min(b.x), a.y.min(b.y)), Point2::new(a.x.max(b.x), a.y.max(b.y)));
    for r in rings {
        if r.max.x < lo.x || r.min.x > hi.x || r.max.y < lo.y || r.min.y > hi.y {
            continue;
        }
        let pts = points.get(r.start as usize..(r.start + r.len) as usize).unwrap_or(&[]);
        let Some(&last) = pts.last() else { continue };
        // Outcodes: one per corner; an edge whose corners share an outside side misses the box.
        let code = |q: Point2| {
            u8::from(q.x < lo.x)
                | u8::from(q.x > hi.x) << 1
                | u8::from(q.y < lo.y) << 2
                | u8::from(q.y > hi.y) << 3
        };
        let (mut p, mut cp) = (last, code(last));
        for &q in pts {
            let cq = code(q);
            if cp & cq == 0 && segments_touch(a, b, p, q) {
                return true;
            }
            (p, cp) = (q, cq);
        }
    }
    false
}

#[cfg(test)]
mod tests {
    use super::div_round;

    /// Against the exact quotient in `i128`, on both sides of the one-word fast path.
    #[test]
    fn div_round_rounds_halves_away_from_zero() {
        let reference = |n: i64, d: i64| {
            let (n, d) = (i128::from(n), i128::from(d));
            let q = (2 * n.abs() + d.abs()) / (2 * d.abs());
            (if (n < 0) != (d < 0) { -q } else { q }) as i64
        };
        let mut x = 0x9E37_79B9_7F4A_7C15u64;
        let mut next = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x
        };
        let edges = [0i64, 1, 2, 3, 7, (1 << 31) - 1, 1 << 31, (1 << 32) - 1, 1 << 32, 1 << 40];
        for _ in 0..20_000 {
            let shift = next() % 60;
            let n = (next() >> (4 + shift)) as i64 * if next() % 2 == 0 { 1 } else { -1 };
            let d = ((next() >> (4 + next() % 60)) as i64).max(1)
                * if next() % 3 == 0 { -1 } else { 1 };
            assert_eq!(div_round(n, d), reference(n, d), "{n} / {d}");
        }
        for &n in &edges {
            for &d in &edges[1..] {
                for (n, d) in [(n, d), (-n, d), (n, -d), (-n, -d)] {
                    assert_eq!(div_round(n, d), reference(n, d), "{n} / {d}");
                }
            }
        }
    }

    use super::*;

    #[test]
    fn rounding_division_goes_half_away_from_zero() {
        assert_eq!(div_round(5, 2), 3);
        assert_eq!(div_round(-5, 2), -3);
        assert_eq!(div_round(4, 3), 1);
        assert_eq!(div_round(-4, -3), 1);
        assert_eq!(div_round(7, -2), -4);
        assert_eq!(div_round_128(-7, 2), -4);
    }

    #[test]
    fn rounding_division_equals_the_plain_i128_formula() {
        // Halves away from zero with the native division, signs normalised first.
        let plain = |num: i128, den: i128| {
            let (num, den) = if den < 0 { (-num, -den) } else { (num, den) };
            if num >= 0 {
                (num + den / 2) / den
            } else {
                -((-num + den / 2) / den)
            }
        };
        let mut next = crate::test_rng::xorshift(7);
        for k in 0..20_000 {
            // Numerators and divisors of every width the offsets and scanlines use.
            let num = (next() as i64 >> (k % 40)) as i128 * if k % 3 == 0 { 1 << 20 } else { 1 };
            let den = (next() as i64 >> (k % 63)) as i128;
            if den == 0 {
                continue;
            }
            assert_eq!(div_round_128(num, den), plain(num, den), "{num} / {den}");
        }
    }

    #[test]
    fn winding_counts_holes() {
        let mut b = LoopBuf::<16, 4>::new();
        for p in [(0, 0), (100, 0), (100, 100), (0, 100)] {
            b.push(Point2::new(p.0, p.1)).unwrap();
        }
        b.close(0, 0, Ring::NO_PARENT).unwrap();
        for p in [(25, 25), (25, 75), (75, 75), (75, 25)] {
            b.push(Point2::new(p.0, p.1)).unwrap();
        }
        b.close(0, 0, 0).unwrap();
        assert_eq!(winding(b.points(), b.rings(), Point2::new(10, 50)), 1);
        assert_eq!(winding(b.points(), b.rings(), Point2::new(50, 50)), 0);
        assert_eq!(winding(b.points(), b.rings(), Point2::new(150, 50)), 0);
        assert!(b.rings()[1].is_hole());
    }
}
