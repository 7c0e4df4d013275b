//! Integer polygon offsetting with merging and collapse.
//!
//! An island (an outer loop and its holes; outer counter-clockwise, holes clockwise, so the
//! material is always on the left) is offset in two steps:
//!
//! 1. **Raw offset curves.** Every edge is shifted `d` to its left (`d > 0` shrinks the
//!    material, `d < 0` grows it). At a vertex where the shifted edges overlap (the side
//!    that shrinks) the exact miter point is used when both edges are long enough to hold
//!    it; otherwise the curve is routed through the original vertex (the trick Clipper uses),
//!    which makes every spurious part of the curve a loop of negative winding. Where the
//!    shifted edges open a gap, a miter (limit 2 x d) or a round join closes it.
//! 2. **Union.** The region the raw curves wind around positively is extracted exactly:
//!    all intersections are found by a sweep over y (edges sorted by lowest y against the
//!    edges spanning that y), edges are split there, coincident pieces are merged, a second
//!    sweep gives every piece the winding number on both sides (a piece's winding is
//!    constant because nothing crosses it), and the pieces with positive winding on exactly
//!    one side are linked into loops, turning at shared vertices so that faces stay simple.
//!    Rounded intersection points bend pieces, which can make them cross again: the pieces
//!    are intersected again until nothing more is rounded, and snap-rounded (no two cross
//!    afterwards) if that has not settled in three passes.
//!
//! Offset curves of a hole and of the outer boundary that cross merge; a part narrower than
//! `2 d` leaves a negatively wound curve and disappears; nothing inverted survives. Inside
//! the engine coordinates are on a 1/16 um grid so rounded intersection points are 30 nm
//! from exact; output is rounded back to um and lightly simplified.

use crate::geom::Point2;

use super::poly::{div_round, div_round_128, orient, Loops, Ring};
use super::simplify::simplify_closed;
use super::sort;
use super::Buffer;
use crate::math::isqrt_u64;

/// Bytes of engine state per unit of its capacity `E` (an edge, a split point or a finished
/// dart, a piece and an active-list entry).
pub const BYTES_PER_EDGE: usize =
    core::mem::size_of::<Seg>() + core::mem::size_of::<Piece>() + core::mem::size_of::<u16>();
/// Most edges or pieces of one union: their indices fit the `u16` active list.
const MAX_ITEMS: usize = 1 << 16;

/// Sub-micrometre grid of the engine: coordinates are multiplied by this.
pub const SCALE: i32 = 16;
/// Deviation allowed for round joins, in engine units (4 um).
const ARC_TOL: i64 = 4 * SCALE as i64;
/// Tolerance of the clean-up pass on output loops, in um.
const OUT_TOL: i64 = 2;
/// Thinnest band a union is split into, engine units (1 um): a line with more work than the
/// engine holds is a capacity error.
const MIN_BAND: i64 = SCALE as i64;

/// How the gap at a vertex on the growing side is closed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Join {
    /// Sharp corner up to a miter length of 2 x d, round beyond.
    Miter,
    /// Circular arc.
    Round,
}

#[derive(Debug, Clone, Copy, Default)]
struct Seg {
    a: Point2,
    b: Point2,
}

/// A split point, kept in an edge slot: `a.x` is the edge's index, `b` the point.
fn split_slot(edge: usize, p: Point2) -> Seg {
    Seg { a: Point2::new(edge as i32, 0), b: p }
}

/// A piece of the arrangement, stored lower end first (`a` before `b` in (y, x) order).
#[derive(Debug, Clone, Copy, Default)]
struct Piece {
    a: Point2,
    b: Point2,
    /// Sum of the orientations merged here: +1 per original edge running a -> b.
    w: i16,
    /// Winding on the +x side (non-horizontal) or above (horizontal).
    wr: i16,
}

impl Piece {
    /// Output direction once classified: 0 not on the boundary, 1 a -> b, -1 b -> a (from
    /// the windings on either side: left `wr + w` and right `wr` of a non-horizontal piece,
    /// above `wr` and below `wr - w` of a horizontal one).
    fn keep(&self) -> i8 {
        let (w, wr) = (i32::from(self.w), i32::from(self.wr));
        let (first, second) = if self.a.y == self.b.y { (wr, wr - w) } else { (wr + w, wr) };
        if (first > 0) == (second > 0) {
            0
        } else if first > 0 {
            1
        } else {
            -1
        }
    }
}

fn less_yx(p: Point2, q: Point2) -> bool {
    (p.y, p.x) < (q.y, q.x)
}

/// Usage counters of the engine (largest values seen).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct OffsetPeaks {
    /// Edge slots in use at once: raw offset edges of one island (or band) and distance,
    /// with their split points and the finished darts of the bands before.
    pub edges: usize,
    /// Split points.
    pub splits: usize,
    /// Arrangement pieces.
    pub pieces: usize,
    /// Boundary darts of one union (the bands' together), which stay until it is traced.
    pub darts: usize,
    /// Bands a union was split into (1: the union was done whole).
    pub bands: usize,
}

/// A horizontal band of the plane, engine units: edges are clipped to `lo <= y <= hi`,
/// horizontal ones kept if `lo <= y < hi`. An empty band (`lo == hi`) stands for the whole
/// plane (so a new engine is all zero bytes).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Band {
    lo: i32,
    hi: i32,
}

impl Band {
    /// The whole plane: nothing is clipped.
    const ALL: Self = Self { lo: 0, hi: 0 };
}

/// The offsetting engine: `E` edge slots and `E` pieces for one island.
///
/// The edge slots hold the raw edges from the front, then their split points and, in the
/// last slots, the boundary darts of the bands already done. When a union does not fit
/// (edges, splits or pieces), it is done in horizontal bands: the raw curves are generated
/// again for each band and clipped to it, each band's boundary darts are kept, and the loops
/// are traced from all of them at the end. Each band is as tall as would have held, at the
/// last band's density of raw edges, half the edge slots the darts leave; one that does not
/// fit is at least halved. Clipped edges of two bands meet at the same rounded
/// point on their shared line, so the bands' boundaries join there exactly.
pub struct Offsetter<const E: usize> {
    segs: [Seg; E],
    n_segs: usize,
    /// Split points, in the edge slots after the edges.
    n_splits: usize,
    /// Boundary darts of the finished bands, in the last edge slots (in bands: the slots of
    /// the chain store).
    n_darts: usize,
    /// The union is done in bands: the darts are kept as chains of points.
    banded: bool,
    /// Points in the chain store (chain headers included).
    chain_points: usize,
    pieces: [Piece; E],
    n_pieces: usize,
    /// Active list of the sweeps (indices), then the darts' used flags.
    act: [u16; E],
    /// Edge slots and pieces this union may use (at most `E`).
    cap: usize,
    /// The band the raw edges are clipped to.
    band: Band,
    /// Lowest and highest y of the raw edges generated (unclipped), engine units.
    y_span: (i32, i32),
    /// A raw edge in the band did not fit.
    overflow: bool,
    /// Raw edges with a part in the band (stored or not).
    in_band: usize,
    /// A split point was rounded (or snapped) in the last intersection pass.
    rounded: bool,
    /// Usage high-water marks.
    pub peaks: OffsetPeaks,
    /// Boundary chains that could not be closed (inconsistent arrangement; should stay 0).
    pub open_chains: u32,
}

impl<const E: usize> Default for Offsetter<E> {
    fn default() -> Self {
        Self::new()
    }
}

/// The part of the edge `a -> b` in `band` (direction kept), or `None`. A clipped end is
/// the edge's point on the band's line, rounded: the same for both bands that share it.
fn clip_to(a: Point2, b: Point2, band: Band) -> Option<(Point2, Point2)> {
    if band == Band::ALL {
        return Some((a, b));
    }
    if a.y == b.y {
        return (band.lo <= a.y && a.y < band.hi).then_some((a, b));
    }
    let (lo, hi) = if a.y < b.y { (a, b) } else { (b, a) };
    if hi.y <= band.lo || lo.y >= band.hi {
        return None;
    }
    let at = |y: i32| {
        if y == lo.y {
            lo
        } else if y == hi.y {
            hi
        } else {
            let dx = i64::from(hi.x) - i64::from(lo.x);
            let t = i64::from(y) - i64::from(lo.y);
            let x = i64::from(lo.x) + div_round(dx * t, i64::from(hi.y) - i64::from(lo.y));
            Point2::new(x as i32, y)
        }
    };
    let (p, q) = (at(lo.y.max(band.lo)), at(hi.y.min(band.hi)));
    Some(if a.y < b.y { (p, q) } else { (q, p) })
}

/// Left normal of `(dx, dy)` scaled to length `d` (engine units; `d` may be negative).
fn normal(dx: i64, dy: i64, len: i64, d: i64) -> (i64, i64) {
    (div_round(-dy * d, len), div_round(dx * d, len))
}

/// `v` scaled to length `r` (engine units).
fn scale_to(v: (i64, i64), r: i64) -> (i64, i64) {
    // Halved until its squared length fits: a round join's direction is a product of two
    // edge lengths (2^42 for two 100 mm edges), whose square would overflow.
    let (mut x, mut y) = v;
    while x.unsigned_abs().max(y.unsigned_abs()) >= 1 << 31 {
        (x, y) = (x / 2, y / 2);
    }
    let len = isqrt_u64((x * x + y * y) as u64) as i64;
    if len == 0 {
        return (0, 0);
    }
    (div_round(x * r, len), div_round(y * r, len))
}

impl<const E: usize> Offsetter<E> {
    /// An empty engine.
    pub const fn new() -> Self {
        Self {
            segs: [Seg { a: Point2::new(0, 0), b: Point2::new(0, 0) }; E],
            n_segs: 0,
            n_splits: 0,
            n_darts: 0,
            banded: false,
            chain_points: 0,
            pieces: [Piece { a: Point2::new(0, 0), b: Point2::new(0, 0), w: 0, wr: 0 }; E],
            n_pieces: 0,
            act: [0; E],
            cap: 0,
            band: Band::ALL,
            y_span: (0, 0),
            overflow: false,
            in_band: 0,
            rounded: false,
            peaks: OffsetPeaks { edges: 0, splits: 0, pieces: 0, darts: 0, bands: 0 },
            open_chains: 0,
        }
    }

    /// Starts a band: no edges, splits or pieces (the darts of the bands before stay; so does
    /// the span of the raw edges, which a band's raw curves do not all take part in).
    fn begin_band(&mut self, band: Band) {
        self.band = band;
        self.n_segs = 0;
        self.n_splits = 0;
        self.n_pieces = 0;
        if band == Band::ALL {
            self.y_span = (i32::MAX, i32::MIN);
        }
        self.overflow = false;
        self.in_band = 0;
    }

    /// Edge slots in use (edges, split points, darts).
    fn slots_used(&self) -> usize {
        self.n_segs + self.n_splits + self.n_darts
    }

    /// Stores an edge as it is (no clipping), or a capacity error.
    fn store_seg(&mut self, a: Point2, b: Point2) -> Result<(), Buffer> {
        if a == b {
            return Ok(());
        }
        if self.slots_used() >= self.cap {
            return Err(Buffer::OffsetEdges);
        }
        self.segs[self.n_segs] = Seg { a, b };
        self.n_segs += 1;
        self.peaks.edges = self.peaks.edges.max(self.slots_used());
        Ok(())
    }

    /// Takes a raw edge: its part in the band is stored; one that does not fit is only
    /// noted (the band is too tall), so a raw curve is always generated whole.
    fn push_seg(&mut self, a: Point2, b: Point2) -> Result<(), Buffer> {
        if a == b {
            return Ok(());
        }
        self.y_span = (self.y_span.0.min(a.y).min(b.y), self.y_span.1.max(a.y).max(b.y));
        let Some((a, b)) = clip_to(a, b, self.band) else { return Ok(()) };
        self.in_band += 1;
        self.overflow |= self.store_seg(a, b).is_err();
        Ok(())
    }

    /// Adds the raw offset curve of one closed loop (um; material on its left) shifted by
    /// `d_um` to the left.
    pub fn add_loop(&mut self, pts: &[Point2], d_um: i32, join: Join) -> Result<(), Buffer> {
        // Distinct consecutive points only.
        let n = pts.len();
        if n < 3 || d_um == 0 {
            return self.add_plain(pts);
        }
        let d = i64::from(d_um) * i64::from(SCALE);
        let next_distinct =
            |i: usize| -> Option<usize> { (1..n).map(|k| (i + k) % n).find(|&j| pts[j] != pts[i]) };
        // Start at a vertex; walk distinct vertices once around.
        let Some(mut i) = (0..n).find(|&i| pts[i] != pts[(i + n - 1) % n]) else {
            return Ok(());
        };
        let first_vertex = i;
        let prev_distinct =
            |i: usize| (0..n).map(|k| (i + n - 1 - k) % n).find(|&j| pts[j] != pts[i]).unwrap_or(i);
        let prev = prev_distinct(i);
        let mut first_out: Option<Point2> = None;
        let mut last_out = Point2::new(0, 0);
        let mut steps = 0;
        // An edge's vector, length (um, floor) and normal (engine units).
        let edge = |from: Point2, to: Point2| {
            let v = (i64::from(to.x) - i64::from(from.x), i64::from(to.y) - i64::from(from.y));
            let len = isqrt_u64((v.0 * v.0 + v.1 * v.1) as u64) as i64;
            (v, len, normal(v.0, v.1, len.max(1), d))
        };
        // In a band, a vertex is skipped when its points and its neighbours' all lie beyond
        // the band on one side (the edges between them would be clipped away): a vertex's
        // points lie within 2 |d| and half its shorter edge of it (the miter limits below),
        // and a unit of rounding. `side` is -1 (below), 1 (above) or 0.
        let (band, banded) = (self.band, self.band != Band::ALL);
        let side = |v: usize, before: usize, after: usize| -> i8 {
            if !banded {
                return 0;
            }
            let l1 = |u: Point2, w: Point2| {
                (i64::from(w.x) - i64::from(u.x)).abs() + (i64::from(w.y) - i64::from(u.y)).abs()
            };
            let shorter = l1(pts[before], pts[v]).min(l1(pts[v], pts[after]));
            let reach = 2 * d.abs() + shorter * i64::from(SCALE) / 2 + 2;
            let y = i64::from(pts[v].y) * i64::from(SCALE);
            if y + reach < i64::from(band.lo) {
                -1
            } else if y - reach > i64::from(band.hi) {
                1
            } else {
                0
            }
        };
        let Some(mut next) = next_distinct(i) else { return Ok(()) };
        let side_prev = if banded { side(prev, prev_distinct(prev), i) } else { 0 };
        let (mut side_prev, mut side_cur) = (side_prev, side(i, prev, next));
        let mut prev = prev;
        // The edge into the vertex (the previous vertex's edge out), once computed.
        let (mut a, mut la, mut na) = ((0, 0), 0, (0, 0));
        let mut have_a = false;
        // The next point emitted starts a new run (the points before it were skipped); the
        // loop's first and last vertices were skipped.
        let mut fresh = false;
        let mut skipped_first = false;
        let mut skipped_last;
        loop {
            let Some(after) = next_distinct(next) else { return Ok(()) };
            let side_next = if banded { side(next, i, after) } else { 0 };
            let skip = side_cur != 0 && side_prev == side_cur && side_cur == side_next;
            skipped_first |= skip && steps == 0;
            skipped_last = skip;
            'join: {
                if skip {
                    (fresh, have_a) = (true, false);
                    break 'join;
                }
                if !have_a {
                    (a, la, na) = edge(pts[prev], pts[i]);
                }
                let p = pts[i];
                let (b, lb, nb) = edge(p, pts[next]);
                let mut emit = |q: Point2, this: &mut Self| -> Result<(), Buffer> {
                    match first_out {
                        None => first_out = Some(q),
                        Some(_) if !fresh => this.push_seg(last_out, q)?,
                        Some(_) => {}
                    }
                    (fresh, last_out) = (false, q);
                    Ok(())
                };
                let ps = (i64::from(p.x) * i64::from(SCALE), i64::from(p.y) * i64::from(SCALE));
                let at = |v: (i64, i64)| Point2::new((ps.0 + v.0) as i32, (ps.1 + v.1) as i32);
                let cross = a.0 * b.1 - a.1 * b.0;
                let dot = a.0 * b.0 + a.1 * b.1;
                let lab = la * lb;
                let d2 = d * d;
                let ndot = na.0 * nb.0 + na.1 * nb.1;
                let miter = |den: i64| {
                    (div_round((na.0 + nb.0) * d2, den), div_round((na.1 + nb.1) * d2, den))
                };
                let shrinking = (cross > 0) == (d > 0) && cross != 0;
                if dot > 0 && cross.abs() * 6 < lab {
                    // Nearly straight (under ~10 degrees): the miter point.
                    emit(at(miter(d2 + ndot)), self)?;
                } else if shrinking {
                    // Miter only if both edges hold the trimmed part: |d| tan(theta/2) <= len/2.
                    let lhs = i128::from(d.abs() / i64::from(SCALE)) * i128::from(cross.abs()) * 2;
                    let rhs = i128::from(la.min(lb)) * i128::from(lab + dot);
                    if d2 + ndot > d2 / 64 && lhs <= rhs {
                        emit(at(miter(d2 + ndot)), self)?;
                    } else {
                        emit(at(na), self)?;
                        emit(Point2::new(ps.0 as i32, ps.1 as i32), self)?;
                        emit(at(nb), self)?;
                    }
                } else if join == Join::Miter && 2 * dot >= -lab && d2 + ndot > 0 {
                    emit(at(miter(d2 + ndot)), self)?;
                } else {
                    // Round: na -> (direction a - b) -> nb by bisection.
                    let r = d.abs();
                    let mid = scale_to((a.0 * lb - b.0 * la, a.1 * lb - b.1 * la), r);
                    emit(at(na), self)?;
                    self.arc(ps, na, mid, r, &mut emit)?;
                    emit(at(mid), self)?;
                    self.arc(ps, mid, nb, r, &mut emit)?;
                    emit(at(nb), self)?;
                }
                (a, la, na, have_a) = (b, lb, nb, true);
            }
            (prev, i, next, side_prev, side_cur) = (i, next, after, side_cur, side_next);
            steps += 1;
            if i == first_vertex || steps > n {
                break;
            }
        }
        match first_out {
            Some(f) if !skipped_first && !skipped_last => self.push_seg(last_out, f),
            _ => Ok(()),
        }
    }

    /// Emits the interior points of the arc from `u` to `v` (both of length `r`, at most 90
    /// degrees apart) around `c`: `2^k` equal parts, `k` the smallest depth (at most 6) whose
    /// sagitta is below [`ARC_TOL`]; each point by bisection from the ends (integers only).
    fn arc(
        &mut self,
        c: (i64, i64),
        u: (i64, i64),
        v: (i64, i64),
        r: i64,
        emit: &mut impl FnMut(Point2, &mut Self) -> Result<(), Buffer>,
    ) -> Result<(), Buffer> {
        // The chord halves (about) with every level; sagitta ~ chord^2 / (8 r).
        let (dx, dy) = (v.0 - u.0, v.1 - u.1);
        let mut chord2 = dx * dx + dy * dy;
        let mut depth = 0u32;
        while chord2 > 8 * r * ARC_TOL && depth < 6 {
            chord2 /= 4;
            depth += 1;
        }
        for k in 1u32..1 << depth {
            let (mut p, mut q) = (u, v);
            for level in (0..depth).rev() {
                let m = scale_to((p.0 + q.0, p.1 + q.1), r);
                if k & (1 << level) != 0 {
                    p = m;
                } else {
                    q = m;
                }
            }
            emit(Point2::new((c.0 + p.0) as i32, (c.1 + p.1) as i32), self)?;
        }
        Ok(())
    }

    /// Adds a loop unchanged (scaled), for a union without offset.
    fn add_plain(&mut self, pts: &[Point2]) -> Result<(), Buffer> {
        let s = |p: Point2| Point2::new(p.x * SCALE, p.y * SCALE);
        if pts.len() < 3 {
            return Ok(());
        }
        let mut a = s(pts[pts.len() - 1]);
        for &p in pts {
            let b = s(p);
            self.push_seg(a, b)?;
            a = b;
        }
        Ok(())
    }

    fn add_split(&mut self, edge: usize, p: Point2) -> Result<(), Buffer> {
        if self.slots_used() >= self.cap {
            return Err(Buffer::OffsetSplits);
        }
        self.segs[self.n_segs + self.n_splits] = split_slot(edge, p);
        self.n_splits += 1;
        self.peaks.splits = self.peaks.splits.max(self.n_splits);
        self.peaks.edges = self.peaks.edges.max(self.slots_used());
        Ok(())
    }

    /// Intersection sweep: records split points; returns true if collinear overlaps exist.
    fn find_splits(&mut self) -> Result<bool, Buffer> {
        let n = self.n_segs;
        sort::sort_by_key(&mut self.segs[..n], |s| s.a.y.min(s.b.y));
        self.sweep_pairs(0, Self::intersect)
    }

    /// Calls `visit(self, i, e, j, f)` for every pair of edges (sorted by lowest y) whose
    /// bounding boxes overlap once `e`'s is grown by `reach` (engine units); `visit` may record
    /// split points. Returns true if any call returned true.
    fn sweep_pairs(
        &mut self,
        reach: i32,
        mut visit: impl FnMut(&mut Self, usize, Seg, usize, Seg) -> Result<bool, Buffer>,
    ) -> Result<bool, Buffer> {
        let n = self.n_segs;
        let mut any = false;
        let mut n_act = 0usize;
        for i in 0..n {
            let e = self.segs[i];
            let y0 = e.a.y.min(e.b.y).saturating_sub(reach);
            let ex0 = e.a.x.min(e.b.x).saturating_sub(reach);
            let ex1 = e.a.x.max(e.b.x).saturating_add(reach);
            // Drop the active segments that end below `e`'s box (a loop without calls: its values
            // stay in registers), then visit the others whose x ranges overlap `e`'s, in the
            // same order (`visit` records splits only, `act` and `segs` stay).
            let (segs, act) = (&self.segs[..n], &mut self.act[..n_act]);
            let mut k = 0;
            for m in 0..act.len() {
                let fi = act[m];
                let Some(f) = segs.get(fi as usize) else { continue };
                if f.a.y < y0 && f.b.y < y0 {
                    continue;
                }
                act[k] = fi;
                k += 1;
            }
            n_act = k;
            for m in 0..n_act {
                let fi = self.act[m] as usize;
                let f = self.segs[fi];
                if (f.a.x < ex0 && f.b.x < ex0) || (f.a.x > ex1 && f.b.x > ex1) {
                    continue;
                }
                any |= visit(self, i, e, fi, f)?;
            }
            // `act` holds at most `n` entries.
            self.act[n_act] = i as u16;
            n_act += 1;
        }
        Ok(any)
    }

    /// Splits `e` and `f` where they meet. Returns true for a collinear overlap.
    fn intersect(&mut self, ei: usize, e: Seg, fi: usize, f: Seg) -> Result<bool, Buffer> {
        // Segments sharing an endpoint (neighbours along a loop, mostly) meet nowhere else
        // unless they are collinear: one orientation settles it.
        let other = if e.a == f.a || e.a == f.b {
            Some(e.b)
        } else if e.b == f.a || e.b == f.b {
            Some(e.a)
        } else {
            None
        };
        if other.is_some_and(|q| orient(f.a, f.b, q) != 0) {
            return Ok(false);
        }
        let d1 = orient(f.a, f.b, e.a);
        let d2 = orient(f.a, f.b, e.b);
        if d1 == 0 && d2 == 0 {
            return self.collinear(ei, e, fi, f);
        }
        if (d1 > 0 && d2 > 0) || (d1 < 0 && d2 < 0) {
            return Ok(false);
        }
        let d3 = orient(e.a, e.b, f.a);
        let d4 = orient(e.a, e.b, f.b);
        if (d3 > 0 && d4 > 0) || (d3 < 0 && d4 < 0) {
            return Ok(false);
        }
        let is_end = |s: Seg, p: Point2| s.a == p || s.b == p;
        if d1 == 0 || d2 == 0 || d3 == 0 || d4 == 0 {
            // Touching: a vertex of one lies on the other.
            if d1 == 0 && !is_end(f, e.a) {
                self.add_split(fi, e.a)?;
            }
            if d2 == 0 && !is_end(f, e.b) {
                self.add_split(fi, e.b)?;
            }
            if d3 == 0 && !is_end(e, f.a) {
                self.add_split(ei, f.a)?;
            }
            if d4 == 0 && !is_end(e, f.b) {
                self.add_split(ei, f.b)?;
            }
            return Ok(false);
        }
        // Proper crossing: x = e.a + (e.b - e.a) d1 / (d1 - d2).
        let den = i128::from(d1) - i128::from(d2);
        let x = i128::from(e.a.x)
            + div_round_128((i128::from(e.b.x) - i128::from(e.a.x)) * i128::from(d1), den);
        let y = i128::from(e.a.y)
            + div_round_128((i128::from(e.b.y) - i128::from(e.a.y)) * i128::from(d1), den);
        let mut p = Point2::new(x as i32, y as i32);
        self.rounded = true;
        for q in [e.a, e.b, f.a, f.b] {
            if (q.x - p.x).abs() <= 1 && (q.y - p.y).abs() <= 1 {
                p = q;
                break;
            }
        }
        if !is_end(e, p) {
            self.add_split(ei, p)?;
        }
        if !is_end(f, p) {
            self.add_split(fi, p)?;
        }
        Ok(false)
    }

    fn collinear(&mut self, ei: usize, e: Seg, fi: usize, f: Seg) -> Result<bool, Buffer> {
        // Strictly inside s (on its line): positive projection from both ends.
        let inside = |s: Seg, q: Point2| {
            let d = |u: Point2, v: Point2, w: Point2| {
                (i64::from(v.x) - i64::from(u.x)) * (i64::from(w.x) - i64::from(u.x))
                    + (i64::from(v.y) - i64::from(u.y)) * (i64::from(w.y) - i64::from(u.y))
            };
            d(s.a, s.b, q) > 0 && d(s.b, s.a, q) > 0
        };
        let mut any = false;
        for q in [f.a, f.b] {
            if inside(e, q) {
                self.add_split(ei, q)?;
                any = true;
            }
        }
        for q in [e.a, e.b] {
            if inside(f, q) {
                self.add_split(fi, q)?;
                any = true;
            }
        }
        let same = (e.a == f.a && e.b == f.b) || (e.a == f.b && e.b == f.a);
        Ok(any || same)
    }

    /// The pieces become the edges of another pass (each as its edge ran).
    fn pieces_to_segs(&mut self) -> Result<(), Buffer> {
        (self.n_segs, self.n_splits) = (0, 0);
        for i in 0..self.n_pieces {
            let p = self.pieces[i];
            let (a, b) = if p.w > 0 { (p.a, p.b) } else { (p.b, p.a) };
            self.store_seg(a, b)?;
        }
        self.n_pieces = 0;
        Ok(())
    }

    /// Snap rounding (Hobby, Greene) of the edges into pieces: a grid point's unit square
    /// (half-open, `[x - 1/2, x + 1/2)` on both axes) is hot if it holds an edge's end or a
    /// crossing of two edges, and every edge becomes the chain through the centres of the hot
    /// squares it meets, in order along it. Such chains never cross: they share vertices or
    /// run together (overlaps and touches are left to an exact intersection pass).
    fn snap_round(&mut self) -> Result<(), Buffer> {
        let n = self.n_segs;
        sort::sort_by_key(&mut self.segs[..n], |s| s.a.y.min(s.b.y));
        // The crossings, rounded to the square that holds them, on both edges; then by edge.
        // A square an edge meets lies within a unit of the edge's box: `reach` 1.
        self.sweep_pairs(1, Self::snap_crossing)?;
        // One record of each crossing square is its owner (`a.y` 1), which the edges that
        // meet the square take it from: once each.
        let hot = self.n_splits;
        let crossings = &mut self.segs[n..n + hot];
        sort::sort_by_key(crossings, |s| (s.b.y, s.b.x));
        for k in 0..hot {
            crossings[k].a.y = i32::from(k == 0 || crossings[k - 1].b != crossings[k].b);
        }
        sort::sort_by_key(crossings, |s| s.a.x);
        self.sweep_pairs(1, |this, i, e, j, f| {
            this.snap_through(i, e, j, f, hot)?;
            this.snap_through(j, f, i, e, hot)?;
            Ok(false)
        })?;
        self.build_pieces()
    }

    /// The crossing of `e` and `f` (interiors, at one point), rounded half up: the centre of
    /// the square that holds it, recorded on both.
    fn snap_crossing(&mut self, ei: usize, e: Seg, fi: usize, f: Seg) -> Result<bool, Buffer> {
        let opposite = |p: i64, q: i64| (p > 0 && q < 0) || (p < 0 && q > 0);
        let (d1, d2) = (orient(f.a, f.b, e.a), orient(f.a, f.b, e.b));
        if !opposite(d1, d2) || !opposite(orient(e.a, e.b, f.a), orient(e.a, e.b, f.b)) {
            return Ok(false);
        }
        // At e.a + (e.b - e.a) d1 / (d1 - d2).
        let den = i128::from(d1) - i128::from(d2);
        let at = |a: i32, b: i32| {
            let num = (i128::from(b) - i128::from(a)) * i128::from(d1);
            (i128::from(a) + round_half_up(num, den)) as i32
        };
        let p = Point2::new(at(e.a.x, e.b.x), at(e.a.y, e.b.y));
        for (i, s) in [(ei, e), (fi, f)] {
            if s.a != p && s.b != p {
                self.add_split(i, p)?;
            }
        }
        Ok(false)
    }

    /// Splits `g` at the hot squares of `e` that `g` meets: its start, its end on a band's
    /// line, and the crossings it owns (in the first `hot` split slots, sorted by edge).
    /// The edges form closed chains (clipped on the band's lines), so every other end is
    /// another edge's start.
    fn snap_through(
        &mut self,
        gi: usize,
        g: Seg,
        ei: usize,
        e: Seg,
        hot: usize,
    ) -> Result<(), Buffer> {
        self.snap_at(gi, g, e.a)?;
        let band = self.band;
        if band != Band::ALL && (e.b.y == band.lo || e.b.y == band.hi) {
            self.snap_at(gi, g, e.b)?;
        }
        let n = self.n_segs;
        let mut k = n + self.segs[n..n + hot].partition_point(|s| (s.a.x as usize) < ei);
        while k < n + hot && self.segs[k].a.x as usize == ei {
            let s = self.segs[k];
            k += 1;
            if s.a.y == 1 {
                self.snap_at(gi, g, s.b)?;
            }
        }
        Ok(())
    }

    /// Splits `g` at `p` if it meets `p`'s square (and `p` is not one of its ends).
    fn snap_at(&mut self, gi: usize, g: Seg, p: Point2) -> Result<(), Buffer> {
        if p != g.a && p != g.b && meets_square(g.a, g.b, p) {
            self.add_split(gi, p)?;
        }
        Ok(())
    }

    fn push_piece(&mut self, a: Point2, b: Point2) -> Result<(), Buffer> {
        if a == b {
            return Ok(());
        }
        let (a, b, w) = if less_yx(a, b) { (a, b, 1) } else { (b, a, -1) };
        let slot = self.pieces.get_mut(self.n_pieces).filter(|_| self.n_pieces < self.cap);
        *slot.ok_or(Buffer::OffsetPieces)? = Piece { a, b, w, wr: 0 };
        self.n_pieces += 1;
        self.peaks.pieces = self.peaks.pieces.max(self.n_pieces);
        Ok(())
    }

    /// Cuts the edges at their split points into pieces.
    fn build_pieces(&mut self) -> Result<(), Buffer> {
        let (start, end) = (self.n_segs, self.n_segs + self.n_splits);
        let (edges, rest) = self.segs.split_at_mut(start);
        let along = |s: &Seg| {
            let (e, p) = (edges[s.a.x as usize], s.b);
            (i64::from(p.x) - i64::from(e.a.x)) * (i64::from(e.b.x) - i64::from(e.a.x))
                + (i64::from(p.y) - i64::from(e.a.y)) * (i64::from(e.b.y) - i64::from(e.a.y))
        };
        sort::sort_by_key(&mut rest[..end - start], |s| (s.a.x, along(s)));
        let mut k = start;
        for i in 0..self.n_segs {
            let e = self.segs[i];
            let mut prev = e.a;
            while k < end && self.segs[k].a.x as usize == i {
                let p = self.segs[k].b;
                k += 1;
                if p != prev && p != e.b {
                    self.push_piece(prev, p)?;
                    prev = p;
                }
            }
            self.push_piece(prev, e.b)?;
        }
        Ok(())
    }

    /// Merges identical pieces (collinear overlaps), dropping those that cancel. More than
    /// `i16::MAX` of them on one piece is [`Buffer::OffsetPieces`].
    fn merge_pieces(&mut self) -> Result<(), Buffer> {
        let n = self.n_pieces;
        sort::sort_by_key(&mut self.pieces[..n], |p| (p.a.y, p.a.x, p.b.y, p.b.x));
        let mut out = 0;
        let mut i = 0;
        while i < n {
            let mut p = self.pieces[i];
            let mut j = i + 1;
            while j < n && self.pieces[j].a == p.a && self.pieces[j].b == p.b {
                p.w = p.w.checked_add(self.pieces[j].w).ok_or(Buffer::OffsetPieces)?;
                j += 1;
            }
            if p.w != 0 {
                self.pieces[out] = p;
                out += 1;
            }
            i = j;
        }
        self.n_pieces = out;
        Ok(())
    }

    /// Winding sweep: every piece gets its side windings and whether it bounds the region
    /// (a horizontal one from the winding above it, or below it on a band's top line). A
    /// winding number beyond `i16` is [`Buffer::OffsetPieces`].
    fn classify(&mut self) -> Result<(), Buffer> {
        let n = self.n_pieces;
        let pieces = &mut self.pieces[..n];
        sort::sort_by(pieces, |p, q| {
            (p.a.y, p.a.x).cmp(&(q.a.y, q.a.x)).then_with(|| {
                let (dpx, dpy) = (i64::from(p.b.x - p.a.x), i64::from(p.b.y - p.a.y));
                let (dqx, dqy) = (i64::from(q.b.x - q.a.x), i64::from(q.b.y - q.a.y));
                // Horizontal pieces last; otherwise by x just above the start.
                match (dpy == 0, dqy == 0) {
                    (true, true) => core::cmp::Ordering::Equal,
                    (true, false) => core::cmp::Ordering::Greater,
                    (false, true) => core::cmp::Ordering::Less,
                    (false, false) => (dpx * dqy).cmp(&(dqx * dpy)),
                }
            }) == core::cmp::Ordering::Less
        });
        let act = &mut self.act;
        let mut n_act = 0usize;
        // Sign of (x_f(y) - x) * dy_f, then slopes on a tie: is f right of (x, slope)?
        let x_cmp = |f: &Piece, y: i64, x2: i64, twice: bool| -> i64 {
            let dy = i64::from(f.b.y) - i64::from(f.a.y);
            let dx = i64::from(f.b.x) - i64::from(f.a.x);
            let xf = i64::from(f.a.x) * dy + dx * (y - i64::from(f.a.y));
            if twice {
                2 * xf - x2 * dy
            } else {
                xf - x2 * dy
            }
        };
        // The winding just above (or below) the midpoint of the horizontal piece `h`, from the
        // active pieces (left to right there): the right side of the last one left of it.
        let beside = |pieces: &[Piece], act: &[u16], h: Piece, below: bool| -> i16 {
            let (x2, yl) = (i64::from(h.a.x) + i64::from(h.b.x), i64::from(h.a.y));
            let mut wr = 0;
            for &m in act {
                let f = &pieces[m as usize];
                // As above, with twice the x: right of the midpoint ends the walk, left
                // of it goes on.
                let (fx0, fx1) = (f.a.x.min(f.b.x), f.a.x.max(f.b.x));
                if 2 * i64::from(fx0) > x2 {
                    break;
                }
                if 2 * i64::from(fx1) < x2 {
                    wr = f.wr;
                    continue;
                }
                // On a tie, a piece leaning left going up is left just above, one leaning
                // right just below.
                let c = x_cmp(f, yl, x2, true);
                let left = c < 0 || (c == 0 && (f.b.x < f.a.x) != below);
                if !left {
                    break;
                }
                wr = f.wr;
            }
            wr
        };
        // A band's top line: rounded points can put pieces on it, and nothing of the band
        // lies above it.
        let top = (self.band != Band::ALL).then_some(self.band.hi);
        let mut i = 0;
        while i < n {
            let y = pieces[i].a.y;
            let yl = i64::from(y);
            if Some(y) == top {
                // Horizontal pieces on the band's top line (only those start there): their
                // winding below is the band's, above it differs by theirs.
                for h_idx in i..n {
                    let h = pieces[h_idx];
                    let below = beside(pieces, &act[..n_act], h, true);
                    pieces[h_idx].wr = below.checked_add(h.w).ok_or(Buffer::OffsetPieces)?;
                }
                break;
            }
            // Drop pieces that ended.
            let mut k = 0;
            for m in 0..n_act {
                let f = act[m];
                if pieces[f as usize].b.y > y {
                    act[k] = f;
                    k += 1;
                }
            }
            n_act = k;
            let mut j = i;
            while j < n && pieces[j].a.y == y {
                j += 1;
            }
            // Insert the non-horizontal pieces starting here, left to right.
            for e_idx in i..j {
                let e = pieces[e_idx];
                if e.b.y == y {
                    continue;
                }
                let (edx, edy) = (i64::from(e.b.x - e.a.x), i64::from(e.b.y - e.a.y));
                let mut pos = n_act;
                for m in 0..n_act {
                    let f = &pieces[act[m] as usize];
                    // An active piece spans y (f.a.y <= y < f.b.y), so its x there lies
                    // between its ends' x: outside that range the sign of `x_cmp` is known.
                    let (fx0, fx1) = (f.a.x.min(f.b.x), f.a.x.max(f.b.x));
                    if e.a.x < fx0 {
                        pos = m;
                        break;
                    }
                    if e.a.x > fx1 {
                        continue;
                    }
                    let c = x_cmp(f, yl, i64::from(e.a.x), false);
                    let right = if c != 0 {
                        c > 0
                    } else {
                        let (fdx, fdy) = (i64::from(f.b.x - f.a.x), i64::from(f.b.y - f.a.y));
                        fdx * edy > edx * fdy
                    };
                    if right {
                        pos = m;
                        break;
                    }
                }
                let wl = if pos > 0 { pieces[act[pos - 1] as usize].wr } else { 0 };
                pieces[e_idx].wr = wl.checked_sub(e.w).ok_or(Buffer::OffsetPieces)?;
                act.copy_within(pos..n_act, pos + 1);
                act[pos] = e_idx as u16;
                n_act += 1;
            }
            // Horizontal pieces: winding just above their midpoint.
            for h_idx in i..j {
                let h = pieces[h_idx];
                if h.b.y == y {
                    pieces[h_idx].wr = beside(pieces, &act[..n_act], h, false);
                }
            }
            i = j;
        }
        Ok(())
    }

    /// Runs the union of the raw curves that `source` adds (with [`add_loop`](Self::add_loop))
    /// and appends the boundary loops (um) to `out`, tagged `island`/`depth`:
    /// [`collect`](Self::collect) with `limit`, then [`trace_into`](Self::trace_into).
    /// Returns the loops added.
    pub fn union_into<const L: usize>(
        &mut self,
        out: &mut Loops<'_, L>,
        island: u16,
        depth: u8,
        min_width_um: i64,
        limit: usize,
        source: impl FnMut(&mut Self) -> Result<(), Buffer>,
    ) -> Result<usize, Buffer> {
        self.collect(limit, source)?;
        self.trace_into(out, island, depth, min_width_um)
    }

    /// Collects the boundary darts of the union of the raw curves that `source` adds (with
    /// [`add_loop`](Self::add_loop)), using at most `limit` (and `E`) edge slots and pieces:
    /// whole if that fits, else band by band (see [`Offsetter`]). `source` is called once per
    /// attempt and must add the same curves every time. A band of 1 um that does not
    /// fit is the capacity error.
    pub fn collect(
        &mut self,
        limit: usize,
        mut source: impl FnMut(&mut Self) -> Result<(), Buffer>,
    ) -> Result<(), Buffer> {
        self.cap = limit.min(E).min(MAX_ITEMS);
        (self.n_darts, self.banded, self.chain_points) = (0, false, 0);
        let mut band = Band::ALL;
        let mut bands = 0;
        loop {
            self.begin_band(band);
            source(self)?;
            let done = if self.overflow { Err(Buffer::OffsetEdges) } else { self.band_darts() };
            let top = i64::from(self.y_span.1) + 1;
            if band == Band::ALL {
                band = Band { lo: self.y_span.0, hi: top as i32 };
            }
            // The height that would have held half the slots the darts leave (the other
            // half for split points), at this band's density of raw edges.
            let tried = i64::from(band.hi) - i64::from(band.lo);
            let room = ((self.cap - self.n_darts) / 2).max(1) as i64;
            let fitting = tried * room / self.in_band.max(1) as i64;
            match done {
                Ok(()) => {
                    bands += 1;
                    if !self.banded || i64::from(band.hi) >= top {
                        break;
                    }
                    let hi = (i64::from(band.hi) + fitting.max(MIN_BAND)).min(top);
                    band = Band { lo: band.hi, hi: hi as i32 };
                }
                Err(e @ (Buffer::OffsetEdges | Buffer::OffsetSplits | Buffer::OffsetPieces)) => {
                    self.banded = true;
                    let height = fitting.min(tried / 2);
                    if height < MIN_BAND {
                        return Err(e);
                    }
                    band.hi = (i64::from(band.lo) + height) as i32;
                }
                Err(e) => return Err(e),
            }
        }
        self.peaks.bands = self.peaks.bands.max(bands);
        Ok(())
    }

    /// The union of the band's edges: its boundary darts go below the stored ones.
    fn band_darts(&mut self) -> Result<(), Buffer> {
        self.rounded = false;
        let mut overlap = self.find_splits()?;
        self.build_pieces()?;
        // Rounded intersection points move pieces by up to 1/32 um, which can make nearly
        // collinear pieces overlap, touch without a shared vertex or cross: run the (exact)
        // intersection pass again on the pieces until no new point had to be rounded. Nearly
        // parallel pieces through nearly one point need not settle (each rounding bends a
        // piece across a neighbour far along it, and the winding sweep then sees pieces
        // cross): after three passes the pieces are snap-rounded, which leaves none crossing,
        // and a last pass splits them, exactly, where they touch or overlap.
        for pass in 0..4 {
            if !self.rounded {
                break;
            }
            self.rounded = false;
            if pass == 3 {
                self.pieces_to_segs()?;
                self.snap_round()?;
            }
            self.pieces_to_segs()?;
            overlap |= self.find_splits()?;
            self.build_pieces()?;
        }
        if overlap {
            self.merge_pieces()?;
        }
        self.classify()?;
        // Darts (directed boundary pieces), in piece order: whole, below the stored darts;
        // in bands, at the bottom, to be traced into chains (the band's edges and splits are
        // no longer needed).
        let k = self.pieces[..self.n_pieces].iter().filter(|p| p.keep() != 0).count();
        if self.n_darts + k > self.cap {
            return Err(Buffer::OffsetEdges);
        }
        let mut slot = if self.banded { 0 } else { self.cap - self.n_darts - k };
        for i in 0..self.n_pieces {
            let p = self.pieces[i];
            let (a, b) = match p.keep() {
                1 => (p.a, p.b),
                -1 => (p.b, p.a),
                _ => continue,
            };
            self.segs[slot] = Seg { a, b };
            slot += 1;
        }
        let used = if self.banded {
            self.store_chains(k)?;
            self.n_darts + k
        } else {
            self.n_darts += k;
            self.n_darts
        };
        self.peaks.edges = self.peaks.edges.max(used);
        self.peaks.darts = self.peaks.darts.max(self.n_darts);
        Ok(())
    }

    /// Where the chain store's record after the one at `at` begins (past its header and
    /// points).
    fn chain_after(&self, at: usize) -> usize {
        at + 1 + self.chain_point(at).x as usize
    }

    /// Point `q` of the chain store: two points an edge slot, from the last slot down.
    fn chain_point(&self, q: usize) -> Point2 {
        let s = &self.segs[self.cap - 1 - q / 2];
        if q % 2 == 0 {
            s.a
        } else {
            s.b
        }
    }

    fn set_chain_point(&mut self, q: usize, p: Point2) {
        let s = &mut self.segs[self.cap - 1 - q / 2];
        if q % 2 == 0 {
            s.a = p;
        } else {
            s.b = p;
        }
    }

    /// Appends a point to the chain store, which must leave the first `floor` slots free.
    fn push_chain_point(&mut self, p: Point2, floor: usize) -> Result<(), Buffer> {
        if (self.chain_points + 1).div_ceil(2) + floor > self.cap {
            return Err(Buffer::OffsetEdges);
        }
        self.set_chain_point(self.chain_points, p);
        self.chain_points += 1;
        Ok(())
    }

    /// Traces the band's `k` darts (in the first `k` slots) into chains, stored as points: a
    /// header (`x` the chain's number of points, `y` 1 once traced into a loop), then the
    /// points from the chain's start to its end (a chain that closes ends at its start). A
    /// chain ends where no unused dart goes on (on the band's lines, mostly), and begins
    /// where none comes in, as far as can be (then the closed ones). On error the band's
    /// chains are dropped.
    fn store_chains(&mut self, k: usize) -> Result<(), Buffer> {
        sort::sort_by_key(&mut self.segs[..k], |s| (s.a.y, s.a.x));
        // `act`: bit 0 used, bit 1 some dart goes on to this one.
        self.act[..k].fill(0);
        for i in 0..k {
            if let Some(next) = next_dart(&self.segs[..k], &self.act[..k], self.segs[i]) {
                self.act[next] |= 2;
            }
        }
        let kept = self.chain_points;
        let mut stored = Ok(());
        for heads in [true, false] {
            for start in 0..k {
                let flags = self.act[start];
                if flags & 1 == 0 && (!heads || flags & 2 == 0) && stored.is_ok() {
                    stored = self.store_chain(start, k);
                }
            }
        }
        if stored.is_err() {
            self.chain_points = kept;
        }
        self.n_darts = self.chain_points.div_ceil(2);
        stored
    }

    /// Chains end on the band's lines and where more than one of the band's `k` darts
    /// leaves: there the loops are linked as darts are ([`next_dart`]'s turn), and a loop
    /// closes at its first return to where it began.
    fn chain_stop(&self, v: Point2, k: usize) -> bool {
        let darts = &self.segs[..k];
        let lo = darts.partition_point(|d| (d.a.y, d.a.x) < (v.y, v.x));
        v.y == self.band.lo || v.y == self.band.hi || darts.get(lo + 1).is_some_and(|d| d.a == v)
    }

    /// Stores the chain of unused darts from dart `start` on (of the first `k`).
    fn store_chain(&mut self, start: usize, k: usize) -> Result<(), Buffer> {
        let header = self.chain_points;
        let origin = self.segs[start].a;
        self.push_chain_point(Point2::new(0, 0), k)?;
        self.push_chain_point(origin, k)?;
        let mut cur = start;
        let mut len = 1;
        for _ in 0..k {
            self.act[cur] |= 1;
            let d = self.segs[cur];
            self.push_chain_point(d.b, k)?;
            len += 1;
            if d.b == origin || self.chain_stop(d.b, k) {
                break;
            }
            let Some(next) = next_dart(&self.segs[..k], &self.act[..k], d) else { break };
            cur = next;
        }
        self.set_chain_point(header, Point2::new(len, 0));
        Ok(())
    }

    /// Traces the darts [`collect`](Self::collect) kept into loops and appends them (um) to
    /// `out`, tagged `island`/`depth`. Loops whose mean width (2 x area / length) is below
    /// `min_width_um` are dropped. Returns the loops added.
    pub fn trace_into<const L: usize>(
        &mut self,
        out: &mut Loops<'_, L>,
        island: u16,
        depth: u8,
        min_width_um: i64,
    ) -> Result<usize, Buffer> {
        if self.banded {
            return self.trace_chains(out, island, depth, min_width_um);
        }
        let nd = self.n_darts;
        self.segs.copy_within(self.cap - nd..self.cap, 0);
        self.n_darts = 0;
        let darts = &mut self.segs[..nd];
        sort::sort_by_key(darts, |s| (s.a.y, s.a.x));
        for u in self.act[..nd].iter_mut() {
            *u = 0;
        }
        let mut added = 0;
        for s in 0..nd {
            if self.act[s] != 0 {
                continue;
            }
            if self.trace(s, nd, out)? && self.finish_loop(out, island, depth, min_width_um)? {
                added += 1;
            }
        }
        Ok(added)
    }

    /// [`trace_into`](Self::trace_into) for a union done in bands: its chains are linked
    /// into loops, each chain going on with the unused one that starts where it ends and
    /// turns first clockwise (as darts are linked).
    fn trace_chains<const L: usize>(
        &mut self,
        out: &mut Loops<'_, L>,
        island: u16,
        depth: u8,
        min_width_um: i64,
    ) -> Result<usize, Buffer> {
        let mut added = 0;
        let mut chain = 0;
        while chain < self.chain_points {
            if self.chain_point(chain).y == 0
                && self.trace_chain_loop(chain, out)?
                && self.finish_loop(out, island, depth, min_width_um)?
            {
                added += 1;
            }
            chain = self.chain_after(chain);
        }
        (self.n_darts, self.banded, self.chain_points) = (0, false, 0);
        Ok(added)
    }

    /// Follows the chains from the one at `first`; writes the loop's points (um) into
    /// `out`'s open loop. Returns false (and discards) on a dead end.
    fn trace_chain_loop<const L: usize>(
        &mut self,
        first: usize,
        out: &mut Loops<'_, L>,
    ) -> Result<bool, Buffer> {
        let origin = self.chain_point(first + 1);
        let mut last_um = to_um(origin);
        out.push(last_um)?;
        let mut chain = first;
        let mut seam = false;
        loop {
            let len = self.chain_point(chain).x as usize;
            self.set_chain_point(chain, Point2::new(len as i32, 1));
            let end = chain + len;
            for q in chain + 2..=end {
                let v = self.chain_point(q);
                if q == end && v == origin {
                    return Ok(true);
                }
                let um = to_um(v);
                if um != last_um {
                    if core::mem::take(&mut seam) {
                        drop_seam_point(out, um);
                    }
                    out.push(um)?;
                    last_um = um;
                }
            }
            seam = true;
            let (v, prev) = (self.chain_point(end), self.chain_point(end - 1));
            match self.next_chain(Seg { a: prev, b: v }) {
                Some(next) => chain = next,
                None => return dead_end(&mut self.open_chains, out),
            }
        }
    }

    /// The unused chain that goes on from the end of `from` (a chain's last dart).
    fn next_chain(&self, from: Seg) -> Option<usize> {
        let mut chain = 0;
        let mut candidates = core::iter::from_fn(|| {
            while chain < self.chain_points {
                let at = chain;
                chain = self.chain_after(at);
                let start = self.chain_point(at + 1);
                if self.chain_point(at).y == 0 && start == from.b {
                    return Some((at, dir(Seg { a: start, b: self.chain_point(at + 2) })));
                }
            }
            None
        });
        first_clockwise(dir(Seg { a: from.b, b: from.a }), &mut candidates)
    }

    /// Follows boundary darts from `start`; writes the loop's points (um) into `out`'s open
    /// loop. Returns false (and discards) on a dead end.
    fn trace<const L: usize>(
        &mut self,
        start: usize,
        nd: usize,
        out: &mut Loops<'_, L>,
    ) -> Result<bool, Buffer> {
        let darts = &self.segs[..nd];
        let used = &mut self.act[..nd];
        let origin = darts[start].a;
        let mut cur = start;
        used[cur] = 1;
        let mut last_um = to_um(origin);
        out.push(last_um)?;
        for _ in 0..nd {
            let v = darts[cur].b;
            if v == origin {
                return Ok(true);
            }
            let um = to_um(v);
            if um != last_um {
                out.push(um)?;
                last_um = um;
            }
            let Some(next) = next_dart(darts, used, darts[cur]) else {
                return dead_end(&mut self.open_chains, out);
            };
            used[next] = 1;
            cur = next;
        }
        dead_end(&mut self.open_chains, out)
    }

    /// Cleans the loop just traced and keeps it if it is wide enough.
    fn finish_loop<const L: usize>(
        &mut self,
        out: &mut Loops<'_, L>,
        island: u16,
        depth: u8,
        min_width_um: i64,
    ) -> Result<bool, Buffer> {
        let pts = out.open_points_mut();
        let n = simplify_closed(pts, OUT_TOL);
        let pts = &pts[..n];
        if n < 3 {
            out.discard_open();
            return Ok(false);
        }
        let area2 = crate::geom::doubled_signed_area(pts);
        let mut length = 0i64;
        let mut prev = pts[n - 1];
        for &p in pts {
            length += super::poly::dist(prev, p);
            prev = p;
        }
        // Mean width of a thin strip: area / (length / 2) = area2 / length.
        if area2 == 0 || area2.abs() < min_width_um * length {
            out.discard_open();
            return Ok(false);
        }
        out.truncate_open(n);
        Ok(out.close(island, depth, Ring::NO_PARENT)?.is_some())
    }
}

/// Drops the open loop's last point (where two chains meet) if it lies on the segment from
/// the point before it to `next` within 1 um: a band's line cut an edge there, it is not a
/// vertex of the union (the output's clean-up would drop it; the loop buffer need not
/// hold it meanwhile).
fn drop_seam_point<const L: usize>(out: &mut Loops<'_, L>, next: Point2) {
    let n = out.open_len();
    if n < 2 {
        return;
    }
    let pts = out.open_points_mut();
    let (a, s) = (pts[n - 2], pts[n - 1]);
    let dot = |u: Point2, v: Point2, w: Point2| {
        (i64::from(v.x) - i64::from(u.x)) * (i64::from(w.x) - i64::from(u.x))
            + (i64::from(v.y) - i64::from(u.y)) * (i64::from(w.y) - i64::from(u.y))
    };
    let len = isqrt_u64(super::poly::dist2(a, next) as u64) as i64;
    if orient(a, next, s).abs() <= len && dot(a, s, next) >= 0 && dot(next, s, a) >= 0 {
        out.truncate_open(n - 1);
    }
}

/// A traced loop that cannot be closed (an inconsistent arrangement): counted in
/// `open_chains` and dropped from `out`.
fn dead_end<const L: usize>(open_chains: &mut u32, out: &mut Loops<'_, L>) -> Result<bool, Buffer> {
    *open_chains += 1;
    out.discard_open();
    Ok(false)
}

/// An engine point in um (rounded).
fn to_um(p: Point2) -> Point2 {
    Point2::new(
        div_round(i64::from(p.x), i64::from(SCALE)) as i32,
        div_round(i64::from(p.y), i64::from(SCALE)) as i32,
    )
}

/// `num / den` rounded half up (towards +infinity): the grid point whose half-open unit
/// square holds it (`den != 0`).
fn round_half_up(num: i128, den: i128) -> i128 {
    let (num, den) = if den < 0 { (-num, -den) } else { (num, den) };
    (2 * num + den).div_euclid(2 * den)
}

/// A bound of a segment's parameter: numerator, denominator (positive), open.
type Bound = (i128, i128, bool);

/// Does the segment `a`-`b` meet the half-open unit square around `c` (`[c - 1/2, c + 1/2)`
/// on both axes)? Exact: the parameters `t` in `[0, 1]` of its points in the square (in
/// doubled coordinates, between bounds that are fractions) are not none.
fn meets_square(a: Point2, b: Point2, c: Point2) -> bool {
    use core::cmp::Ordering;
    let cmp = |p: Bound, q: Bound| (p.0 * q.1).cmp(&(q.0 * p.1));
    let (mut lo, mut hi): (Bound, Bound) = ((0, 1, false), (1, 1, false));
    // A bound narrows `cur` if it lies `inward` of it; an open one at the same place opens it.
    let tighten = |cur: &mut Bound, new: Bound, inward: Ordering| match cmp(new, *cur) {
        Ordering::Equal => cur.2 |= new.2,
        o if o == inward => *cur = new,
        _ => {}
    };
    for (u, v, w) in [(a.x, b.x, c.x), (a.y, b.y, c.y)] {
        // Doubled, the square is [-1, 1) around the origin: -1 <= s + t d < 1.
        let s = 2 * (i128::from(u) - i128::from(w));
        let d = 2 * (i128::from(v) - i128::from(u));
        match d.cmp(&0) {
            Ordering::Greater => {
                tighten(&mut lo, (-1 - s, d, false), Ordering::Greater);
                tighten(&mut hi, (1 - s, d, true), Ordering::Less);
            }
            Ordering::Less => {
                tighten(&mut hi, (1 + s, -d, false), Ordering::Less);
                tighten(&mut lo, (s - 1, -d, true), Ordering::Greater);
            }
            Ordering::Equal if !(-1..1).contains(&s) => return false,
            Ordering::Equal => {}
        }
    }
    match cmp(lo, hi) {
        Ordering::Less => true,
        Ordering::Equal => !lo.2 && !hi.2,
        Ordering::Greater => false,
    }
}

fn dir(s: Seg) -> (i64, i64) {
    (i64::from(s.b.x) - i64::from(s.a.x), i64::from(s.b.y) - i64::from(s.a.y))
}

/// The unused dart (of `darts`, sorted by start; `used` bit 0) that goes on from the end of
/// `from`: the first one turning clockwise from the way back, so that faces stay simple.
fn next_dart(darts: &[Seg], used: &[u16], from: Seg) -> Option<usize> {
    let v = from.b;
    let lo = darts.partition_point(|d| (d.a.y, d.a.x) < (v.y, v.x));
    let outgoing = (lo..darts.len()).take_while(|&m| darts[m].a == v);
    let candidates = outgoing.filter(|&m| used[m] & 1 == 0).map(|m| (m, dir(darts[m])));
    first_clockwise(dir(Seg { a: v, b: from.a }), candidates)
}

/// The candidate (index, direction) reached first turning clockwise from `back` (the first
/// listed of equal ones).
fn first_clockwise(
    back: (i64, i64),
    candidates: impl Iterator<Item = (usize, (i64, i64))>,
) -> Option<usize> {
    let mut best: Option<(usize, (i64, i64))> = None;
    for (m, c) in candidates {
        best = match best {
            Some((_, b)) if !cw_before(back, c, b) => best,
            _ => Some((m, c)),
        };
    }
    best.map(|(m, _)| m)
}

/// Is `c1` reached before `c2` turning clockwise from `r` (a direction equal to `r` last)?
fn cw_before(r: (i64, i64), c1: (i64, i64), c2: (i64, i64)) -> bool {
    let cross = |u: (i64, i64), v: (i64, i64)| u.0 * v.1 - u.1 * v.0;
    let dotp = |u: (i64, i64), v: (i64, i64)| u.0 * v.0 + u.1 * v.1;
    // Half 0: clockwise angle in (0, pi]; half 1: (pi, 2 pi] (2 pi = same direction as r).
    let half = |c: (i64, i64)| {
        let x = cross(r, c);
        if x < 0 || (x == 0 && dotp(r, c) < 0) {
            0
        } else {
            1
        }
    };
    let (h1, h2) = (half(c1), half(c2));
    if h1 != h2 {
        return h1 < h2;
    }
    cross(c1, c2) < 0
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::toolpath::poly::LoopBuf;

    type Out = LoopBuf<4096, 64>;

    fn offset_loops(loops: &[&[Point2]], d: i32, join: Join) -> Box<Out> {
        let (out, peaks) = offset_limited(loops, d, join, usize::MAX).unwrap();
        assert_eq!(peaks.bands, 1);
        out
    }

    /// The union with at most `limit` edge slots and pieces, and the engine's peaks.
    fn offset_limited(
        loops: &[&[Point2]],
        d: i32,
        join: Join,
        limit: usize,
    ) -> Result<(Box<Out>, OffsetPeaks), Buffer> {
        let mut eng = Box::new(Offsetter::<8192>::new());
        let mut out = Box::new(Out::new());
        let curves =
            |e: &mut Offsetter<8192>| loops.iter().try_for_each(|l| e.add_loop(l, d, join));
        eng.union_into(&mut out.loops(), 0, 0, 1, limit, curves)?;
        assert_eq!(eng.open_chains, 0);
        assert!(eng.peaks.edges.max(eng.peaks.pieces) <= limit);
        Ok((out, eng.peaks))
    }

    fn rect(x0: i32, y0: i32, x1: i32, y1: i32) -> [Point2; 4] {
        [Point2::new(x0, y0), Point2::new(x1, y0), Point2::new(x1, y1), Point2::new(x0, y1)]
    }

    fn rev<const N: usize>(mut a: [Point2; N]) -> [Point2; N] {
        a.reverse();
        a
    }

    fn seg_dist_mm(a: Point2, b: Point2) -> f64 {
        (f64::from(a.x - b.x).powi(2) + f64::from(a.y - b.y).powi(2)).sqrt() / 1000.0
    }

    fn area_mm2(out: &Out) -> f64 {
        out.rings().iter().map(|r| r.area2 as f64 / 2e6).sum()
    }

    #[test]
    fn square_shrinks_exactly() {
        let sq = rect(0, 0, 20_000, 20_000);
        let out = offset_loops(&[&sq], 225, Join::Miter);
        assert_eq!(out.rings().len(), 1);
        let r = out.rings()[0];
        assert_eq!((r.min, r.max), (Point2::new(225, 225), Point2::new(19_775, 19_775)));
        assert_eq!(r.len, 4);
        assert_eq!(r.area2, 2 * 19_550i64 * 19_550);
    }

    #[test]
    fn square_with_hole_collapses_to_nothing() {
        let outer = rect(0, 0, 10_000, 10_000);
        let hole = rev(rect(3_000, 3_000, 7_000, 7_000));
        let out = offset_loops(&[&outer, &hole], 1_000, Join::Miter);
        assert_eq!(out.rings().len(), 2);
        assert!((area_mm2(&out) - (64.0 - 36.0)).abs() < 1e-6);
        let out = offset_loops(&[&outer, &hole], 1_499, Join::Miter);
        assert_eq!(out.rings().len(), 2);
        let out = offset_loops(&[&outer, &hole], 1_500, Join::Miter);
        assert!(out.rings().is_empty(), "{:?}", out.rings());
        let out = offset_loops(&[&outer, &hole], 1_600, Join::Miter);
        assert!(out.rings().is_empty());
    }

    #[test]
    fn two_holes_merge() {
        let outer = rect(0, 0, 20_000, 10_000);
        let h1 = rev(rect(3_000, 3_000, 9_000, 7_000));
        let h2 = rev(rect(10_000, 3_000, 16_000, 7_000));
        let out = offset_loops(&[&outer, &h1, &h2], 400, Join::Miter);
        assert_eq!(out.rings().len(), 3);
        // The bar between the holes is 1 mm wide: at 0.6 mm it is gone, the holes merge.
        let out = offset_loops(&[&outer, &h1, &h2], 600, Join::Miter);
        assert_eq!(out.rings().len(), 2, "{:?}", out.rings());
        let holes = out.rings().iter().filter(|r| r.is_hole()).count();
        assert_eq!(holes, 1);
        let expect = (20.0 - 1.2) * (10.0 - 1.2) - (16.0 - 3.0 + 1.2) * (4.0 + 1.2);
        assert!((area_mm2(&out) - expect).abs() < 1e-3, "{} vs {expect}", area_mm2(&out));
    }

    #[test]
    fn thin_slot_splits_region() {
        // A dumbbell: two 5 mm squares joined by a 0.8 mm bridge.
        let pts = [
            Point2::new(0, 0),
            Point2::new(5_000, 0),
            Point2::new(5_000, 2_100),
            Point2::new(8_000, 2_100),
            Point2::new(8_000, 0),
            Point2::new(13_000, 0),
            Point2::new(13_000, 5_000),
            Point2::new(8_000, 5_000),
            Point2::new(8_000, 2_900),
            Point2::new(5_000, 2_900),
            Point2::new(5_000, 5_000),
            Point2::new(0, 5_000),
        ];
        let out = offset_loops(&[&pts], 300, Join::Miter);
        assert_eq!(out.rings().len(), 1);
        let out = offset_loops(&[&pts], 450, Join::Miter);
        assert_eq!(out.rings().len(), 2);
        for r in out.rings() {
            assert!(!r.is_hole());
            assert_eq!(r.area2, 2 * 4_100 * 4_100);
        }
    }

    #[test]
    fn comb_teeth_vanish_one_by_one() {
        // A comb: a 2 mm spine with teeth 0.4, 0.8, 1.2, 1.6 mm wide, 5 mm long.
        let widths = [400, 800, 1_200, 1_600];
        let mut pts = Vec::new();
        pts.push(Point2::new(0, 0));
        let mut x = 1_000;
        let mut right = 0;
        for w in widths {
            right = x + w;
            x = right + 2_000;
        }
        let total = right + 1_000;
        pts.push(Point2::new(total, 0));
        pts.push(Point2::new(total, 2_000));
        let mut x = right;
        for w in widths.iter().rev() {
            // Walk back right to left along the teeth.
            pts.push(Point2::new(x, 2_000));
            pts.push(Point2::new(x, 7_000));
            pts.push(Point2::new(x - w, 7_000));
            pts.push(Point2::new(x - w, 2_000));
            x -= w + 2_000;
        }
        pts.push(Point2::new(0, 2_000));
        let pts: Vec<Point2> = pts;
        for (d, expect_teeth) in [(150, 4), (350, 3), (550, 2), (750, 1)] {
            let out = offset_loops(&[&pts], d, Join::Miter);
            assert_eq!(out.rings().len(), 1, "d {d}");
            let r = out.rings()[0];
            // Each surviving tooth adds 4 points to the spine's 4 (plus round-off merges).
            assert_eq!(r.max.y, if expect_teeth > 0 { 7_000 - d } else { 2_000 - d }, "d {d}");
            let teeth = (r.len as usize - 4) / 4;
            assert_eq!(teeth, expect_teeth, "d {d}: {:?}", out.ring_points(&r));
        }
    }

    #[test]
    fn outward_round_offset_of_a_square_is_a_rounded_square() {
        let sq = rect(0, 0, 10_000, 10_000);
        let out = offset_loops(&[&sq], -3_000, Join::Round);
        assert_eq!(out.rings().len(), 1);
        let exact = 100.0 + 4.0 * 10.0 * 3.0 + core::f64::consts::PI * 9.0;
        let got = area_mm2(&out);
        assert!((got - exact).abs() < exact * 2e-3, "{got} vs {exact}");
        let r = out.rings()[0];
        assert_eq!((r.min, r.max), (Point2::new(-3_000, -3_000), Point2::new(13_000, 13_000)));
    }

    /// A part as wide as the bed: its long edges' round joins stay within range (their
    /// direction, a product of two edge lengths, once overflowed when squared).
    #[test]
    fn outward_round_offset_of_a_bed_wide_square_is_a_rounded_square() {
        let sq = rect(0, 0, 200_000, 200_000);
        let out = offset_loops(&[&sq], -3_000, Join::Round);
        assert_eq!(out.rings().len(), 1);
        let exact = 200.0 * 200.0 + 4.0 * 200.0 * 3.0 + core::f64::consts::PI * 9.0;
        let got = area_mm2(&out);
        assert!((got - exact).abs() < 0.05, "{got} vs {exact} mm^2");
        let r = out.rings()[0];
        assert_eq!((r.min, r.max), (Point2::new(-3_000, -3_000), Point2::new(203_000, 203_000)));
    }

    /// Deterministic pseudo-random numbers (64-bit LCG, high bits).
    struct Lcg(u64);
    impl Lcg {
        fn next(&mut self) -> f64 {
            self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (self.0 >> 11) as f64 / (1u64 << 53) as f64
        }
    }

    fn seg_dist(p: (f64, f64), a: Point2, b: Point2) -> f64 {
        let (ax, ay, bx, by) = (f64::from(a.x), f64::from(a.y), f64::from(b.x), f64::from(b.y));
        let (dx, dy) = (bx - ax, by - ay);
        let l2 = dx * dx + dy * dy;
        let t = if l2 == 0.0 {
            0.0
        } else {
            (((p.0 - ax) * dx + (p.1 - ay) * dy) / l2).clamp(0.0, 1.0)
        };
        ((p.0 - ax - t * dx).powi(2) + (p.1 - ay - t * dy).powi(2)).sqrt()
    }

    fn inside_f64(loops: &[Vec<Point2>], p: (f64, f64)) -> bool {
        let mut w = 0;
        for l in loops {
            for k in 0..l.len() {
                let (a, b) = (l[k], l[(k + 1) % l.len()]);
                let (ay, by) = (f64::from(a.y), f64::from(b.y));
                if (ay <= p.1) != (by <= p.1) {
                    let x = f64::from(a.x) + (p.1 - ay) / (by - ay) * f64::from(b.x - a.x);
                    if x > p.0 {
                        w += if by > ay { 1 } else { -1 };
                    }
                }
            }
        }
        w != 0
    }

    /// Random star-shaped outer loops with a random star-shaped hole, offset with round
    /// joins, against the definition: inside and at least d from the boundary (f64), for
    /// sample points farther than 8 um from the offset boundary; areas shrink with d.
    #[test]
    fn random_polygons_match_f64_distance_reference() {
        let mut rng = Lcg(7);
        for case in 0..40 {
            let n = 5 + (rng.next() * 40.0) as usize;
            let star = |rng: &mut Lcg, n: usize, r0: f64, r1: f64, cx: f64, cy: f64| {
                let mut v: Vec<Point2> = (0..n)
                    .map(|j| {
                        let a =
                            2.0 * core::f64::consts::PI * (j as f64 + 0.8 * rng.next()) / n as f64;
                        let r = r0 + (r1 - r0) * rng.next();
                        Point2::new((cx + r * a.cos()) as i32, (cy + r * a.sin()) as i32)
                    })
                    .collect();
                v.dedup();
                v
            };
            let outer = star(&mut rng, n, 4_000.0, 10_000.0, 0.0, 0.0);
            let mut loops = vec![outer];
            if case % 2 == 0 {
                let mut hole = star(&mut rng, 3 + n / 3, 600.0, 2_500.0, 300.0, -200.0);
                hole.reverse();
                loops.push(hole);
            }
            let refs: Vec<&[Point2]> = loops.iter().map(|l| l.as_slice()).collect();
            let mut last_area = f64::INFINITY;
            for d in [150, 400, 900, 1_700] {
                // Odd cases in bands: the engine holds a third of what the union needs.
                let out = if case % 2 == 1 {
                    // The darts stay; half of the rest of the work (32 slots at least).
                    let (_, whole) = offset_limited(&refs, d, Join::Round, usize::MAX).unwrap();
                    let need = whole.edges.max(whole.pieces);
                    let limit = whole.darts + ((need - whole.darts) / 2).max(32);
                    let (out, peaks) =
                        offset_limited(&refs, d, Join::Round, limit).unwrap_or_else(|e| {
                            panic!("case {case} d {d} limit {limit} {whole:?}: {e:?}")
                        });
                    assert!(peaks.bands > 1 || limit >= need, "case {case} d {d}: {peaks:?}");
                    out
                } else {
                    offset_loops(&refs, d, Join::Round)
                };
                let got: Vec<Vec<Point2>> =
                    out.rings().iter().map(|r| out.ring_points(r).to_vec()).collect();
                let area = area_mm2(&out);
                assert!(area <= last_area + 1e-9, "case {case} d {d}: area grows");
                last_area = area;
                for r in out.rings() {
                    assert!(out.ring_points(r).len() >= 3);
                }
                for k in 0..600 {
                    let p = (rng.next() * 24_000.0 - 12_000.0, rng.next() * 24_000.0 - 12_000.0);
                    let boundary = got
                        .iter()
                        .flat_map(|l| {
                            (0..l.len()).map(move |j| seg_dist(p, l[j], l[(j + 1) % l.len()]))
                        })
                        .fold(f64::INFINITY, f64::min);
                    if boundary < 8.0 {
                        continue;
                    }
                    let to_src = loops
                        .iter()
                        .flat_map(|l| {
                            (0..l.len()).map(move |j| seg_dist(p, l[j], l[(j + 1) % l.len()]))
                        })
                        .fold(f64::INFINITY, f64::min);
                    let truth = inside_f64(&loops, p) && to_src >= f64::from(d);
                    assert_eq!(
                        inside_f64(&got, p),
                        truth,
                        "case {case} d {d} sample {k} at {p:?}: src dist {to_src}"
                    );
                }
            }
        }
    }
    const LM8UU_LAYER: [&[(i32, i32)]; 2] = [
        &[
            (108177, 106328),
            (107779, 106554),
            (104111, 107248),
            (103897, 107765),
            (103696, 108417),
            (107135, 107068),
            (106764, 107482),
            (106503, 107859),
            (103500, 110075),
            (103532, 110634),
            (103633, 111309),
            (106146, 108601),
            (105993, 109135),
            (105921, 109588),
            (104177, 112888),
            (104447, 113378),
            (104832, 113942),
            (105921, 110412),
            (106014, 110960),
            (106146, 111399),
            (106006, 115129),
            (106463, 115453),
            (107054, 115794),
            (106503, 112141),
            (106825, 112594),
            (107135, 112932),
            (108627, 116353),
            (109178, 116447),
            (109860, 116498),
            (107779, 113446),
            (108265, 113714),
            (108691, 113885),
            (111520, 116320),
            (112058, 116165),
            (112693, 115916),
            (109494, 114069),
            (110048, 114100),
            (110506, 114069),
            (114111, 115035),
            (114529, 114662),
            (114993, 114161),
            (111309, 113885),
            (111823, 113673),
            (112221, 113446),
            (115889, 112752),
            (116103, 112235),
            (116304, 111583),
            (112865, 112932),
            (113236, 112518),
            (113497, 112141),
            (116500, 109925),
            (116468, 109366),
            (116367, 108691),
            (113854, 111399),
            (114007, 110865),
            (114079, 110412),
            (115823, 107112),
            (115553, 106622),
            (115168, 106058),
            (114079, 109588),
            (113986, 109040),
            (113854, 108601),
            (113994, 104871),
            (113537, 104547),
            (112946, 104206),
            (113497, 107859),
            (113175, 107406),
            (112865, 107068),
            (111373, 103647),
            (110822, 103553),
            (110140, 103502),
            (112221, 106554),
            (111739, 106287),
            (111309, 106115),
            (108480, 103680),
            (107942, 103835),
            (107307, 104084),
            (110506, 105931),
            (109952, 105900),
            (109494, 105931),
            (105889, 104965),
            (105471, 105338),
            (105007, 105839),
            (108691, 106115),
        ],
        &[
            (117791, 109042),
            (117843, 109680),
            (117843, 110320),
            (117791, 110958),
            (117687, 111590),
            (117532, 112212),
            (117327, 112818),
            (117073, 113406),
            (116771, 113971),
            (116425, 114510),
            (116036, 115019),
            (115607, 115494),
            (115141, 115933),
            (114640, 116332),
            (114108, 116689),
            (113550, 117002),
            (112967, 117268),
            (112365, 117485),
            (111747, 117653),
            (111117, 117770),
            (110480, 117835),
            (109840, 117848),
            (109201, 117809),
            (108567, 117718),
            (107943, 117576),
            (107332, 117383),
            (106739, 117141),
            (106168, 116851),
            (105622, 116516),
            (105106, 116137),
            (104622, 115718),
            (104173, 115261),
            (103764, 114768),
            (103396, 114244),
            (103072, 113692),
            (102794, 113115),
            (102564, 112517),
            (102384, 111903),
            (102254, 111275),
            (102176, 110640),
            (102150, 110000),
            (102176, 109360),
            (102254, 108725),
            (102384, 108097),
            (102564, 107483),
            (102794, 106885),
            (103072, 106308),
            (103396, 105756),
            (103764, 105232),
            (104173, 104739),
            (104622, 104282),
            (105106, 103863),
            (105622, 103484),
            (106168, 103149),
            (106739, 102859),
            (107332, 102617),
            (107943, 102424),
            (108567, 102282),
            (109201, 102191),
            (109840, 102152),
            (110480, 102165),
            (111117, 102230),
            (111747, 102347),
            (112365, 102515),
            (112967, 102732),
            (113550, 102998),
            (114108, 103311),
            (114640, 103668),
            (115141, 104067),
            (115607, 104506),
            (116036, 104981),
            (116425, 105490),
            (116771, 106029),
            (117073, 106594),
            (117327, 107182),
            (117532, 107788),
            (117687, 108410),
        ],
    ];

    fn lm8uu_layer() -> Vec<Vec<Point2>> {
        LM8UU_LAYER.iter().map(|l| l.iter().map(|&(x, y)| Point2::new(x, y)).collect()).collect()
    }

    /// An embodier LM8UU layer (simplified contours) that once left boundary chains open.
    #[test]
    fn lm8uu_layer_offsets_close() {
        let loops = lm8uu_layer();
        let refs: Vec<&[Point2]> = loops.iter().map(|l| l.as_slice()).collect();
        // d = 675 once left a chain open: two nearly collinear edges crossing at a tiny
        // angle became overlapping pieces with different vertices after rounding.
        for d in [225, 675, 900] {
            offset_loops(&refs, d, Join::Miter);
        }
    }

    /// A band's raw curves (vertices far beyond the band skipped) are exactly the whole raw
    /// curves clipped to the band, edge for edge, for random polygons, the LM8UU layer, both
    /// joins, both signs of the distance and bands of every height.
    #[test]
    fn a_band_generates_exactly_the_clipped_curves() {
        let mut rng = Lcg(11);
        let mut shapes: Vec<Vec<Vec<Point2>>> = vec![lm8uu_layer()];
        for _ in 0..12 {
            let n = 5 + (rng.next() * 60.0) as usize;
            let mut v: Vec<Point2> = (0..n)
                .map(|j| {
                    let a = 2.0 * core::f64::consts::PI * (j as f64 + 0.8 * rng.next()) / n as f64;
                    let r = 2_000.0 + 8_000.0 * rng.next();
                    Point2::new((r * a.cos()) as i32 + 50_000, (r * a.sin()) as i32 + 50_000)
                })
                .collect();
            v.dedup();
            shapes.push(vec![v]);
        }
        let generate = |loops: &[Vec<Point2>], d: i32, join: Join, band: Band| {
            let mut e = Box::new(Offsetter::<8192>::new());
            e.cap = 8192;
            e.begin_band(band);
            for l in loops {
                e.add_loop(l, d, join).unwrap();
            }
            assert!(!e.overflow);
            (e.segs[..e.n_segs].to_vec(), e.y_span)
        };
        for loops in &shapes {
            for (d, join) in
                [(225, Join::Miter), (900, Join::Miter), (-400, Join::Round), (-60, Join::Miter)]
            {
                let (whole, (lo, hi)) = generate(loops, d, join, Band::ALL);
                for parts in [2, 3, 7, 20] {
                    let h = (hi - lo) / parts + 1;
                    for k in 0..parts {
                        let band = Band { lo: lo + k * h, hi: lo + (k + 1) * h };
                        let (got, _) = generate(loops, d, join, band);
                        let want: Vec<(Point2, Point2)> = whole
                            .iter()
                            .filter_map(|s| clip_to(s.a, s.b, band))
                            .filter(|(a, b)| a != b)
                            .collect();
                        let got: Vec<(Point2, Point2)> = got.iter().map(|s| (s.a, s.b)).collect();
                        assert_eq!(got, want, "d {d} band {band:?}");
                    }
                }
            }
        }
    }

    /// The LM8UU layer with every engine size from half its darts to what the whole union
    /// needs: either the capacity error or the same loops as the union done whole (area
    /// within the seams' rounding), in more bands for the smallest engine than the largest.
    #[test]
    fn bands_give_the_whole_union() {
        let loops = lm8uu_layer();
        let refs: Vec<&[Point2]> = loops.iter().map(|l| l.as_slice()).collect();
        for d in [225, 675, 900] {
            let (whole, peaks) = offset_limited(&refs, d, Join::Miter, usize::MAX).unwrap();
            let need = peaks.edges.max(peaks.pieces);
            let mut fits = Vec::new();
            for limit in (peaks.darts / 2..need).step_by(3) {
                let (banded, p) = match offset_limited(&refs, d, Join::Miter, limit) {
                    Ok(r) => r,
                    Err(e) => {
                        let capacity =
                            [Buffer::OffsetEdges, Buffer::OffsetSplits, Buffer::OffsetPieces];
                        assert!(capacity.contains(&e), "d {d} limit {limit}: {e:?}");
                        continue;
                    }
                };
                fits.push((limit, p.bands));
                assert!(p.bands > 1, "d {d} limit {limit}: {p:?}");
                // Each seam moves a loop's crossing point by under 1/16 um before the output's
                // rounding to um and clean-up (2 um): every loop but slivers (under 1,000 um2,
                // which the clean-up may keep or drop) is there, with its bounds within 2 um.
                for (x, y) in [(&whole, &banded), (&banded, &whole)] {
                    for r in x.rings().iter().filter(|r| r.area2.abs() >= 2_000) {
                        let near = |s: &Ring| {
                            let dist =
                                |p: Point2, q: Point2| (p.x - q.x).abs().max((p.y - q.y).abs());
                            dist(r.min, s.min) <= 2 && dist(r.max, s.max) <= 2
                        };
                        assert!(y.rings().iter().any(near), "d {d} limit {limit}: {r:?}");
                    }
                }
                // The areas agree within 0.1 um of mean shift along the outlines.
                let outline_mm: f64 = whole
                    .rings()
                    .iter()
                    .map(|r| {
                        let pts = whole.ring_points(r);
                        let n = pts.len();
                        (0..n).map(|i| seg_dist_mm(pts[i], pts[(i + 1) % n])).sum::<f64>()
                    })
                    .sum();
                let (a, b) = (area_mm2(&whole), area_mm2(&banded));
                assert!((a - b).abs() < 1e-4 * outline_mm, "d {d} limit {limit}: {a} vs {b}");
            }
            // The darts are kept as chains of points (8 B a dart, not 16): every limit from
            // 5/6 of them and 24 slots for a band's work up fits.
            let floor = peaks.darts * 5 / 6 + 24;
            let first = fits.first().map_or(need, |f| f.0);
            assert!(first <= floor, "d {d} {peaks:?}: fits from {first}");
            assert_eq!(fits.len(), (first..need).step_by(3).count(), "d {d}: {fits:?}");
            assert!(fits[0].1 > fits[fits.len() - 1].1, "d {d}: {fits:?}");
        }
    }

    /// An engine too small for one line of the union refuses it with the capacity error
    /// (after halving its bands down to the thinnest), and works again afterwards.
    #[test]
    fn too_small_for_one_band_is_a_capacity_error() {
        let comb: Vec<Point2> = (0..40)
            .flat_map(|k| {
                let x = k * 1_000;
                [
                    Point2::new(x, 0),
                    Point2::new(x + 500, 0),
                    Point2::new(x + 500, 5_000),
                    Point2::new(x + 100, 5_000),
                ]
            })
            .rev()
            .collect();
        let square = rect(0, 0, 10_000, 10_000);
        for limit in [0, 1, 3, 8, 30] {
            let err = offset_limited(&[&comb], 50, Join::Miter, limit).err();
            let capacity = [Buffer::OffsetEdges, Buffer::OffsetSplits, Buffer::OffsetPieces];
            assert!(err.is_some_and(|e| capacity.contains(&e)), "limit {limit}: {err:?}");
        }
        let (out, _) = offset_limited(&[&square], 225, Join::Miter, 8).unwrap();
        assert_eq!(out.rings().len(), 1);
        assert_eq!(out.rings()[0].area2, 2 * 9_550i64 * 9_550);
    }

    /// Loops (from the thin-area measurement of a self-intersecting layer: its perimeters
    /// grown back by half a line) whose offset edges run nearly parallel, three of them
    /// within half a unit of one point: the rounded crossings bent pieces across their
    /// neighbours pass after pass, and the winding sweep saw pieces cross, which left a
    /// boundary chain open. Whole and in bands of every size.
    #[test]
    fn near_parallel_edges_through_one_point_close_every_chain() {
        let loops: [&[Point2]; 4] = [
            &[Point2::new(109096, 102650), Point2::new(110023, 101601), Point2::new(115477, 98728)],
            &[
                Point2::new(108163, 102621),
                Point2::new(108588, 102826),
                Point2::new(108525, 102937),
                Point2::new(108529, 102939),
                Point2::new(108509, 102964),
            ],
            &[
                Point2::new(109098, 101952),
                Point2::new(109062, 102000),
                Point2::new(108757, 102532),
                Point2::new(107653, 102147),
            ],
            &[
                Point2::new(108717, 102601),
                Point2::new(108599, 102808),
                Point2::new(108323, 102615),
            ],
        ];
        let (whole, peaks) = offset_limited(&loops, -225, Join::Miter, usize::MAX).unwrap();
        assert_eq!(whole.rings().len(), 1);
        let need = peaks.edges.max(peaks.pieces);
        for limit in peaks.darts / 2..need {
            // `offset_limited` asserts that every chain closed; from the darts and 16 slots
            // for a band's work up every limit fits.
            match offset_limited(&loops, -225, Join::Miter, limit) {
                Ok((out, p)) => {
                    assert!(p.bands > 1, "limit {limit}");
                    assert!((area_mm2(&out) - area_mm2(&whole)).abs() < 1e-3, "limit {limit}");
                }
                Err(e) => assert!(limit < peaks.darts + 16, "limit {limit}: {e:?}"),
            }
        }
    }

    /// Snap rounding leaves no two pieces crossing, for bundles of nearly parallel segments
    /// through nearly one point (where repeated rounding does not settle) and random ones.
    #[test]
    fn snap_rounded_pieces_never_cross() {
        let mut rng = Lcg(5);
        for case in 0..200 {
            let mut eng = Box::new(Offsetter::<16384>::new());
            eng.cap = 16384;
            eng.begin_band(Band::ALL);
            let (cx, cy) = (1_000_000.0, 2_000_000.0);
            let spread = if case % 2 == 0 { 0.02 } else { 3.0 };
            for _ in 0..(2 + case % 9) {
                let a = 0.6 + spread * rng.next();
                let (len0, len1) = (2_000.0 * rng.next() + 10.0, 2_000.0 * rng.next() + 10.0);
                let (ox, oy) = (3.0 * rng.next() - 1.5, 3.0 * rng.next() - 1.5);
                // A thin triangle: the edges form closed chains.
                let p = |l: f64, w: f64| {
                    let (x, y) = (l * a.cos() - w * a.sin(), l * a.sin() + w * a.cos());
                    Point2::new((cx + ox + x) as i32, (cy + oy + y) as i32)
                };
                let w = 5.0 + 60.0 * rng.next();
                let (p, q, r) = (p(-len0, 0.0), p(len1, 0.0), p(len1, w));
                for (u, v) in [(p, q), (q, r), (r, p)] {
                    eng.store_seg(u, v).unwrap();
                }
            }
            // Rounded once (the crossings of the first pass), then snap-rounded.
            eng.find_splits().unwrap();
            eng.build_pieces().unwrap();
            eng.pieces_to_segs().unwrap();
            let edges = eng.segs[..eng.n_segs].to_vec();
            eng.snap_round().unwrap();
            let pieces = eng.pieces[..eng.n_pieces].to_vec();
            for (i, p) in pieces.iter().enumerate() {
                for q in &pieces[..i] {
                    let d1 = orient(q.a, q.b, p.a).signum() * orient(q.a, q.b, p.b).signum();
                    let d2 = orient(p.a, p.b, q.a).signum() * orient(p.a, p.b, q.b).signum();
                    assert!(d1 >= 0 || d2 >= 0, "case {case}: {p:?} crosses {q:?}");
                }
                // Both ends are centres of squares one edge meets: within half a diagonal.
                let near = edges.iter().any(|e| {
                    [p.a, p.b]
                        .iter()
                        .all(|&v| seg_dist((f64::from(v.x), f64::from(v.y)), e.a, e.b) <= 0.7072)
                });
                assert!(near, "case {case}: {p:?} strays");
            }
        }
    }

    /// The half-open unit square test against an exact reference, on segments near the
    /// square and through its corners.
    #[test]
    fn meets_square_is_exact() {
        let mut rng = Lcg(3);
        let c = Point2::new(10, -20);
        for case in 0..4000 {
            let pick = |rng: &mut Lcg| {
                let r = if case % 3 == 0 { 1.0 } else { 4.0 };
                let v = |rng: &mut Lcg, c: i32| c + ((rng.next() * 2.0 - 1.0) * r).round() as i32;
                Point2::new(v(rng, c.x), v(rng, c.y))
            };
            let (a, b) = (pick(&mut rng), pick(&mut rng));
            // Reference: the points at the parameters where the segment crosses a side's
            // line, its ends, and halfway between those (rationals t = num / den, doubled
            // coordinates): the parameters inside form an interval, which holds one of them.
            let (s, d) = (
                [2 * i128::from(a.x - c.x), 2 * i128::from(a.y - c.y)],
                [2 * i128::from(b.x - a.x), 2 * i128::from(b.y - a.y)],
            );
            let mut ts: Vec<(i128, i128)> = vec![(0, 1), (1, 1)];
            for k in 0..2 {
                for side in [-1, 1] {
                    if d[k] != 0 {
                        let (num, den) = (side - s[k], d[k]);
                        let (num, den) = if den < 0 { (-num, -den) } else { (num, den) };
                        if 0 <= num && num <= den {
                            ts.push((num, den));
                        }
                    }
                }
            }
            ts.sort_by(|p, q| (p.0 * q.1).cmp(&(q.0 * p.1)));
            let mids: Vec<(i128, i128)> = ts
                .windows(2)
                .map(|w| (w[0].0 * w[1].1 + w[1].0 * w[0].1, 2 * w[0].1 * w[1].1))
                .collect();
            let inside = ts.iter().chain(&mids).any(|&(num, den)| {
                (0..2).all(|k| (-den..den).contains(&(s[k] * den + d[k] * num)))
            });
            assert_eq!(meets_square(a, b, c), inside, "{a:?} {b:?}");
        }
        // Corners and sides: the square holds its low sides and its low corner only.
        let p = |x: i32, y: i32| Point2::new(x, y);
        assert!(!meets_square(p(0, 1), p(1, 0), p(0, 0)));
        assert!(meets_square(p(-1, 0), p(0, -1), p(0, 0)));
        assert!(meets_square(p(-3, -1), p(1, 1), p(0, 0)));
        assert!(!meets_square(p(-3, 1), p(3, 1), p(0, 0)));
        assert_eq!(round_half_up(1, 2), 1);
        assert_eq!(round_half_up(-1, 2), 0);
        assert_eq!(round_half_up(3, -2), -1);
        assert_eq!(round_half_up(-7, 4), -2);
    }

    /// Thin triangles whose long sides run nearly parallel (from 0.02 to 20 degrees apart)
    /// through nearly one point, as the pieces of one line cut into several loops do, offset
    /// both ways, whole and in bands of three sizes: every chain closes (`offset_limited`
    /// asserts it) and the area does not depend on the bands. More cases with e.g.
    /// `OFFSET_CASES=5000 cargo test --release --lib bundles`.
    #[test]
    fn bundles_of_nearly_parallel_edges_close_every_chain() {
        let mut rng = Lcg(17);
        let cases = std::env::var("OFFSET_CASES").ok().and_then(|v| v.parse().ok());
        for case in 0..cases.unwrap_or(60) {
            let (cx, cy) = (60_000.0 + 1_000.0 * rng.next(), 60_000.0 + 1_000.0 * rng.next());
            let base = core::f64::consts::PI * rng.next();
            let spread = [0.0003, 0.004, 0.03, 0.3][case % 4];
            let loops: Vec<Vec<Point2>> = (0..3 + case % 4)
                .map(|_| {
                    let a = base + spread * (rng.next() - 0.5);
                    let (ox, oy) = (0.2 * rng.next() - 0.1, 0.2 * rng.next() - 0.1);
                    let (l0, l1) = (200.0 + 2_000.0 * rng.next(), 200.0 + 2_000.0 * rng.next());
                    let w = (30.0 + 400.0 * rng.next()) * if rng.next() < 0.5 { -1.0 } else { 1.0 };
                    let p = |l: f64, w: f64| {
                        let (x, y) = (l * a.cos() - w * a.sin(), l * a.sin() + w * a.cos());
                        Point2::new((cx + ox + x).round() as i32, (cy + oy + y).round() as i32)
                    };
                    // Counter-clockwise whichever side the apex is on.
                    let mut t = vec![p(-l0, 0.0), p(l1, 0.0), p(0.3 * l1, w)];
                    if w < 0.0 {
                        t.reverse();
                    }
                    t
                })
                .collect();
            let refs: Vec<&[Point2]> = loops.iter().map(|l| l.as_slice()).collect();
            for d in [-225, -40, 60, 225] {
                let (whole, peaks) = offset_limited(&refs, d, Join::Miter, usize::MAX)
                    .unwrap_or_else(|e| panic!("case {case} d {d}: {e:?}"));
                let need = peaks.edges.max(peaks.pieces);
                let outline_mm: f64 = whole
                    .rings()
                    .iter()
                    .map(|r| {
                        let pts = whole.ring_points(r);
                        let n = pts.len();
                        (0..n).map(|i| seg_dist_mm(pts[i], pts[(i + 1) % n])).sum::<f64>()
                    })
                    .sum();
                for extra in [24, 60, need / 2] {
                    let limit = (peaks.darts + extra).min(need);
                    let Ok((out, _)) = offset_limited(&refs, d, Join::Miter, limit) else {
                        continue;
                    };
                    // The same area, within the clean-up's 2 um along the outline (loops that
                    // touch at a point may be split there differently).
                    let (a, b) = (area_mm2(&whole), area_mm2(&out));
                    let tol = 2.5e-3 * outline_mm;
                    assert!((a - b).abs() <= tol, "case {case} d {d} limit {limit}: {a} vs {b}");
                }
            }
        }
    }

    /// Three thin triangles that vanish at d = 225, in bands: nearly parallel edges cross
    /// just below a band's top line, and the crossing, rounded onto the line, bent a piece
    /// along it, which took the winding above the line (none: the band holds nothing there)
    /// and became a boundary dart that no other band's chain meets.
    #[test]
    fn a_piece_rounded_onto_a_band_line_takes_the_band_winding() {
        let tri = |p: [(i32, i32); 3]| p.map(|(x, y)| Point2::new(x, y));
        let loops = [
            tri([(59768, 59046), (60842, 60989), (60255, 60600)]),
            tri([(60757, 60484), (61072, 61402), (59519, 58598)]),
            tri([(60872, 60171), (60720, 60766), (59412, 58406)]),
        ];
        let refs: Vec<&[Point2]> = loops.iter().map(|l| l.as_slice()).collect();
        let (whole, peaks) = offset_limited(&refs, 225, Join::Miter, usize::MAX).unwrap();
        assert!(whole.rings().is_empty());
        let need = peaks.edges.max(peaks.pieces);
        for limit in 8..need {
            // `offset_limited` asserts that every chain closed.
            if let Ok((out, p)) = offset_limited(&refs, 225, Join::Miter, limit) {
                assert!(p.bands > 1 && out.rings().is_empty(), "limit {limit}: {p:?}");
            }
        }
    }
}
