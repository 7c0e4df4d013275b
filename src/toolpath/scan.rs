//! Scanlines at 45, 135, 0 and 90 degrees: exact crossings of loops with parallel lines, and
//! the intervals inside (non-zero winding) along every line.
//!
//! Every direction is exact in integers without rotation: for 45 degrees a point's line key
//! is `t = y - x` and its position along the line `u = x + y` (135 degrees: `t = x + y`,
//! `u = y - x`; 0 degrees: `t = y`, `u = x`; 90 degrees: `t = x`, `u = y`). The diagonals
//! scale distances by `sqrt 2`, so their lines `spacing` um apart are `round(spacing x sqrt 2)`
//! apart in `t`. Line
//! `j` is `t = j x step`. An edge from `p` to `q` crosses line `t` when `t` lies in the
//! half-open range between `t(p)` and `t(q)` (`min <= t < max`), so a vertex on a line is
//! counted once and every crossing is exact; only `u` is rounded (to 1 unit = 0.7 um).
//!
//! Crossings are generated in boundary order (loop after loop, edge after edge, along each
//! edge), which the zigzag linker walks; intervals come from a sort by `(line, u)`.

use crate::geom::Point2;

use super::poly::{div_round, Ring};
use super::Buffer;
use crate::math::isqrt_u64;

/// Line direction.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Angle {
    /// Lines along (1, 1).
    D45,
    /// Lines along (-1, 1).
    D135,
    /// Lines along (1, 0): `t = y`, `u = x`.
    D0,
    /// Lines along (0, 1): `t = x`, `u = y`.
    D90,
}

impl Angle {
    /// Every direction, the infill's two first.
    pub const ALL: [Angle; 4] = [Angle::D45, Angle::D135, Angle::D0, Angle::D90];

    /// The other direction of the infill's two (the axes: each other).
    pub fn other(self) -> Self {
        match self {
            Self::D45 => Self::D135,
            Self::D135 => Self::D45,
            Self::D0 => Self::D90,
            Self::D90 => Self::D0,
        }
    }

    /// `(t, u)` of a point: line key and position along the line.
    #[inline]
    pub fn key(self, p: Point2) -> (i64, i64) {
        let (x, y) = (i64::from(p.x), i64::from(p.y));
        match self {
            Self::D45 => (y - x, x + y),
            Self::D135 => (x + y, y - x),
            Self::D0 => (y, x),
            Self::D90 => (x, y),
        }
    }

    /// The point at `(t, u)`, rounded to um.
    pub fn point(self, t: i64, u: i64) -> Point2 {
        let (x2, y2) = match self {
            Self::D45 => (u - t, u + t),
            Self::D135 => (t - u, t + u),
            Self::D0 => (2 * u, 2 * t),
            Self::D90 => (2 * t, 2 * u),
        };
        Point2::new(div_round(x2, 2) as i32, div_round(y2, 2) as i32)
    }

    /// How much `t` and `u` scale distances, x 1000: `sqrt 2` on the diagonals.
    pub fn scale_milli(self) -> i64 {
        match self {
            Self::D45 | Self::D135 => 1414,
            Self::D0 | Self::D90 => 1000,
        }
    }

    /// The `t` step for lines `spacing_um` apart in this direction.
    pub fn line_step(self, spacing_um: i32) -> i64 {
        match self {
            Self::D45 | Self::D135 => line_step(spacing_um),
            Self::D0 | Self::D90 => i64::from(spacing_um),
        }
    }
}

/// The `t` step for diagonal lines `spacing_um` apart: `round(spacing x sqrt 2)`.
pub fn line_step(spacing_um: i32) -> i64 {
    let s2 = 2 * i64::from(spacing_um) * i64::from(spacing_um);
    let r = isqrt_u64(s2 as u64) as i64;
    // Round to nearest: compare with (r + 0.5)^2 = r^2 + r + 0.25.
    if s2 - r * r > r {
        r + 1
    } else {
        r
    }
}

/// One crossing of a loop edge with a line (8 bytes; its position along the line is
/// recomputed from the edge: [`Loops::u`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Crossing {
    /// Line index (`t = line x step`).
    pub line: i32,
    /// Index (in the loop buffer) of the crossed edge's first point.
    pub edge: u16,
    /// Index of the loop in its buffer times 2, plus 1 when the edge runs towards larger `t`.
    ring_dir: u16,
}

/// Most crossings of one call to [`crossings`]: their indices fit a `u16` below
/// [`NO_CROSSING`].
pub const MAX_CROSSINGS: usize = u16::MAX as usize;
/// No crossing (as a `u16` index).
pub const NO_CROSSING: u16 = u16::MAX;

impl Crossing {
    /// A filler.
    pub const EMPTY: Self = Self { line: 0, edge: 0, ring_dir: 0 };

    /// Index of the loop in its buffer.
    pub fn ring(&self) -> usize {
        usize::from(self.ring_dir >> 1)
    }

    /// +1 when the edge runs towards larger `t`, -1 otherwise.
    pub fn dir(&self) -> i8 {
        if self.ring_dir & 1 == 1 {
            1
        } else {
            -1
        }
    }
}

/// The loops whose crossings with the lines of `angle` (spaced `step` in `t`) are listed.
#[derive(Clone, Copy)]
pub struct Loops<'a> {
    /// Points of the loops.
    pub points: &'a [Point2],
    /// The loops.
    pub rings: &'a [Ring],
    /// Line direction.
    pub angle: Angle,
    /// Line step in `t`.
    pub step: i64,
}

impl Loops<'_> {
    /// Position along its line of crossing `c` (as [`crossings`] rounds it; 0 for a crossing
    /// not of these loops).
    pub fn u(&self, c: &Crossing) -> i32 {
        let Some(r) = self.rings.get(c.ring()) else { return 0 };
        let (k, len) = (usize::from(c.edge).wrapping_sub(r.start as usize), r.len as usize);
        let p = self.points.get(usize::from(c.edge)).filter(|_| k < len);
        let q = p.and_then(|_| self.points.get(r.start as usize + (k + 1) % len));
        let (Some(&p), Some(&q)) = (p, q) else { return 0 };
        let (a, b) = (self.angle.key(p), self.angle.key(q));
        if a.0 == b.0 {
            return 0;
        }
        cross_u(a, b, i64::from(c.line) * self.step) as i32
    }
}

/// The crossings of the loop of crossing `i` (crossings come loop after loop): their range.
pub fn loop_range(cross: &[Crossing], i: usize) -> core::ops::Range<usize> {
    let ring = cross.get(i).map_or(0, Crossing::ring);
    cross.partition_point(|c| c.ring() < ring)..cross.partition_point(|c| c.ring() <= ring)
}

/// The next crossing along the boundary after `i` in `range` (its loop's), wrapping.
pub fn next_in(range: &core::ops::Range<usize>, i: usize) -> usize {
    if i + 1 < range.end {
        i + 1
    } else {
        range.start
    }
}

/// The previous crossing along the boundary before `i` in `range` (its loop's), wrapping.
pub fn prev_in(range: &core::ops::Range<usize>, i: usize) -> usize {
    if i > range.start {
        i - 1
    } else {
        range.end.saturating_sub(1)
    }
}

/// Position along line `t` where the edge from key `(tp, up)` to `(tq, uq)` crosses it
/// (`tp != tq`), rounded.
fn cross_u((tp, up): (i64, i64), (tq, uq): (i64, i64), t: i64) -> i64 {
    up + div_round((uq - up) * (t - tp), tq - tp)
}

fn ceil_div(a: i64, b: i64) -> i64 {
    let q = a.div_euclid(b);
    if q * b == a {
        q
    } else {
        q + 1
    }
}

/// Appends the crossings of `rings` (points in `points`) with the lines of `angle` spaced `step` in
/// `t`, to `out[*n..]`, in boundary order.
///
/// More than `out` or [`MAX_CROSSINGS`] crossings, a point index above `u16::MAX` or more than
/// 32768 loops are [`Buffer::Crossings`].
pub fn crossings(
    points: &[Point2],
    rings: &[Ring],
    angle: Angle,
    step: i64,
    out: &mut [Crossing],
    n: &mut usize,
) -> Result<(), Buffer> {
    let room = out.len().min(MAX_CROSSINGS);
    for (ri, r) in rings.iter().enumerate() {
        let pts = points.get(r.start as usize..(r.start + r.len) as usize).unwrap_or(&[]);
        let ring2 = u16::try_from(2 * ri).map_err(|_| Buffer::Crossings)?;
        for (k, &p) in pts.iter().enumerate() {
            let q = pts[(k + 1) % pts.len()];
            let (tp, tq) = (angle.key(p).0, angle.key(q).0);
            if tp == tq {
                continue;
            }
            let (lo, hi) = (tp.min(tq), tp.max(tq));
            let (j0, j1) = (ceil_div(lo, step), ceil_div(hi, step) - 1);
            if j1 < j0 {
                continue;
            }
            let count = (j1 - j0 + 1) as usize;
            if *n + count > room {
                return Err(Buffer::Crossings);
            }
            let edge = u16::try_from(r.start as usize + k).map_err(|_| Buffer::Crossings)?;
            let up_t = tq > tp;
            for s in 0..count {
                let j = if up_t { j0 + s as i64 } else { j1 - s as i64 };
                out[*n] = Crossing { line: j as i32, edge, ring_dir: ring2 | u16::from(up_t) };
                *n += 1;
            }
        }
    }
    Ok(())
}

/// Sorts `order` (indices into `cross`, crossings of `loops`, at most [`MAX_CROSSINGS`]) by
/// line, then position, then direction (then index).
pub fn sort_by_line(cross: &[Crossing], loops: &Loops<'_>, order: &mut [u16]) {
    for (i, o) in order.iter_mut().enumerate() {
        *o = i as u16;
    }
    // The key is total (the index last): any sort gives this order. This one keeps a fixed
    // small stack (see `super::sort`).
    super::sort::sort_by_key(order, |&i| {
        let c = &cross[usize::from(i)];
        (c.line, loops.u(c), c.dir(), i)
    });
}

/// An interval inside the loops along one line.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Interval {
    /// Line index.
    pub line: i32,
    /// Start position.
    pub u0: i32,
    /// End position.
    pub u1: i32,
    /// Crossing at the start.
    pub c0: u16,
    /// Crossing at the end.
    pub c1: u16,
}

/// Calls `f` for every interval of non-zero winding, line by line, in increasing `u`;
/// empty intervals are skipped.
pub fn intervals(
    cross: &[Crossing],
    loops: &Loops<'_>,
    order: &[u16],
    mut f: impl FnMut(Interval) -> Result<(), Buffer>,
) -> Result<(), Buffer> {
    let mut w = 0i32;
    let mut line = i32::MIN;
    let (mut start, mut start_u) = (0u16, 0);
    for &i in order {
        let c = &cross[usize::from(i)];
        if c.line != line {
            line = c.line;
            w = 0;
        }
        let before = w;
        w += i32::from(c.dir());
        if before == 0 && w != 0 {
            (start, start_u) = (i, loops.u(c));
        } else if before != 0 && w == 0 {
            let u = loops.u(c);
            if u > start_u {
                f(Interval { line, u0: start_u, u1: u, c0: start, c1: i })?;
            }
        }
    }
    Ok(())
}

/// An interval `u0..u1` inside a layer's loops along one line (the skin window, see
/// [`line_spans`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Span {
    /// Start along the line.
    pub u0: i32,
    /// End along the line.
    pub u1: i32,
}

/// A closed loop as [`line_spans`] cuts it: any iterator of its points, or a type with a
/// faster walk of its own (the window's stored loops,
/// [`NearLine`](super::window::NearLine)).
pub trait ScanLoop {
    /// Calls `f(p, q)` for every edge `p -> q` of the loop (the closing one last) that
    /// crosses line `t` of `angle`: `min <= t < max` of its ends' `t`, i.e. one end at or
    /// below `t` and the other above.
    fn crossing_edges(
        self,
        angle: Angle,
        t: i64,
        f: impl FnMut(Point2, Point2) -> Result<(), Buffer>,
    ) -> Result<(), Buffer>;
}

/// The walk along one closed loop for [`ScanLoop::crossing_edges`]: fed each point and
/// whether it lies at or below the line (`low`, its `t` computed once), it reports the
/// edges whose ends lie on different sides, the closing edge at [`close`](Self::close).
pub(super) struct CrossingWalk {
    first: Point2,
    first_low: bool,
    last: Point2,
    last_low: bool,
}

impl CrossingWalk {
    #[inline(always)]
    pub(super) fn new(first: Point2, low: bool) -> Self {
        Self { first, first_low: low, last: first, last_low: low }
    }

    /// The point fed last.
    #[inline(always)]
    pub(super) fn last(&self) -> Point2 {
        self.last
    }

    /// The next point `q`: `f(last, q)` if that edge crosses the line.
    #[inline(always)]
    pub(super) fn to(
        &mut self,
        q: Point2,
        low: bool,
        f: &mut impl FnMut(Point2, Point2) -> Result<(), Buffer>,
    ) -> Result<(), Buffer> {
        if self.last_low != low {
            f(self.last, q)?;
        }
        (self.last, self.last_low) = (q, low);
        Ok(())
    }

    /// The closing edge, back to the first point.
    #[inline(always)]
    pub(super) fn close(
        self,
        f: &mut impl FnMut(Point2, Point2) -> Result<(), Buffer>,
    ) -> Result<(), Buffer> {
        if self.last_low != self.first_low {
            f(self.last, self.first)?;
        }
        Ok(())
    }
}

impl<I: Iterator<Item = Point2>> ScanLoop for I {
    fn crossing_edges(
        mut self,
        angle: Angle,
        t: i64,
        mut f: impl FnMut(Point2, Point2) -> Result<(), Buffer>,
    ) -> Result<(), Buffer> {
        let Some(first) = self.next() else { return Ok(()) };
        let mut walk = CrossingWalk::new(first, angle.key(first).0 <= t);
        for q in self {
            walk.to(q, angle.key(q).0 <= t, &mut f)?;
        }
        walk.close(&mut f)
    }
}

/// Writes to `out` the intervals of non-zero winding of `loops` along line `line` (`t = line x
/// step`) in increasing `u`, empty ones skipped, and returns their number and the number of
/// crossings.
///
/// The same intervals as [`crossings`], [`sort_by_line`] and [`intervals`] give on that line. `out`
/// must hold every crossing of the line (it is their scratch first): more is
/// [`Buffer::WindowSpans`].
pub fn line_spans<L: ScanLoop>(
    loops: impl Iterator<Item = L>,
    angle: Angle,
    line: i32,
    step: i64,
    out: &mut [Span],
) -> Result<(usize, usize), Buffer> {
    // Crossings as (u, dir) first; `u` computed only at crossings.
    let t = i64::from(line) * step;
    let mut n = 0;
    for l in loops {
        l.crossing_edges(angle, t, |p, q| {
            let slot = out.get_mut(n).ok_or(Buffer::WindowSpans)?;
            let (a, b) = (angle.key(p), angle.key(q));
            // Towards larger `t` or not.
            let dir = if b.0 > a.0 { 1 } else { -1 };
            *slot = Span { u0: cross_u(a, b, t) as i32, u1: dir };
            n += 1;
            Ok(())
        })?;
    }
    let out = &mut out[..n];
    // Equal keys are equal spans: any sort gives this order.
    super::sort::sort_by_key(out, |c| (c.u0, c.u1));
    // Winding along the line; span k is written over crossing k, already read.
    let (mut w, mut start, mut k) = (0, 0, 0);
    for i in 0..n {
        let Span { u0: u, u1: dir } = out[i];
        let before = w;
        w += dir;
        if before == 0 && w != 0 {
            start = u;
        } else if before != 0 && w == 0 && u > start {
            out[k] = Span { u0: start, u1: u };
            k += 1;
        }
    }
    Ok((k, n))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::toolpath::poly::LoopBuf;

    #[test]
    fn keys_round_trip() {
        for a in Angle::ALL {
            let p = Point2::new(12_345, -678);
            let (t, u) = a.key(p);
            assert_eq!(a.point(t, u), p);
            // 1000 units along the line are 1000 / scale um.
            let q = a.point(t, u + 1000);
            let d = f64::from(q.x - p.x).hypot(f64::from(q.y - p.y));
            assert!((d - 1e6 / a.scale_milli() as f64).abs() < 1.0, "{a:?} {d}");
        }
        assert_eq!(line_step(450), 636);
        assert_eq!(line_step(1000), 1414);
        assert_eq!(Angle::D0.line_step(450), 450);
    }

    #[test]
    fn square_with_hole_gives_two_intervals_through_the_hole() {
        let mut b = LoopBuf::<16, 4>::new();
        for (x, y) in [(0, 0), (10_000, 0), (10_000, 10_000), (0, 10_000)] {
            b.push(Point2::new(x, y)).unwrap();
        }
        b.close(0, 0, Ring::NO_PARENT).unwrap();
        for (x, y) in [(4_000, 4_000), (4_000, 6_000), (6_000, 6_000), (6_000, 4_000)] {
            b.push(Point2::new(x, y)).unwrap();
        }
        b.close(0, 0, 0).unwrap();
        let mut cross = [Crossing::default(); 256];
        let mut n = 0;
        let step = line_step(450);
        crossings(b.points(), b.rings(), Angle::D45, step, &mut cross, &mut n).unwrap();
        let mut order = [0u16; 256];
        let loops = Loops { points: b.points(), rings: b.rings(), angle: Angle::D45, step };
        sort_by_line(&cross[..n], &loops, &mut order[..n]);
        let mut lines = std::collections::BTreeMap::<i32, Vec<(i32, i32)>>::new();
        intervals(&cross[..n], &loops, &order[..n], |iv| {
            lines.entry(iv.line).or_default().push((iv.u0, iv.u1));
            Ok(())
        })
        .unwrap();
        // t = y - x = 0 passes through the hole's corners (4,4) and (6,6).
        let through = &lines[&0];
        assert_eq!(through, &vec![(0, 8_000), (12_000, 20_000)]);
        // t = 636 * 3 = 1908 misses the hole corner region? (x in 4000..6000 at y = x + 1908)
        assert_eq!(lines[&3].len(), 2);
        assert_eq!(lines[&4].len(), 1);
        // Boundary order links: every crossing's next is on the same loop.
        for (i, c) in cross[..n].iter().enumerate() {
            let range = loop_range(&cross[..n], i);
            assert!(range.contains(&i));
            assert_eq!(cross[next_in(&range, i)].ring(), c.ring());
            assert_eq!(prev_in(&range, next_in(&range, i)), i);
        }
        // One line at a time from the loops alone: the same intervals.
        for line in -20..20 {
            let mut out = [Span::default(); 16];
            let rings = b.rings().iter().map(|r| b.ring_points(r).iter().copied());
            let (k, used) = line_spans(rings, Angle::D45, line, step, &mut out).unwrap();
            let want = lines.get(&line).cloned().unwrap_or_default();
            let got: Vec<(i32, i32)> = out[..k].iter().map(|s| (s.u0, s.u1)).collect();
            assert_eq!(got, want, "line {line}");
            assert_eq!(used, cross[..n].iter().filter(|c| c.line == line).count());
        }
    }
}
