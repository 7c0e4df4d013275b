//! Combing: the travels between paths inside the part.
//!
//! A travel that crosses no contour of the layer stays inside the part and needs no
//! retraction; one that would cross a contour goes around it, inside, when a route at most
//! [`COMB_EXTRA_UM`] longer than twice the straight travel exists. Otherwise it crosses, and
//! one at least `min_retract_travel_um` long retracts first and primes again before the next
//! extrusion ([`super::emitter`]).

use crate::geom::Point2;

use super::super::paths::{PathBuf, PathKind};
use super::super::poly::{dist, dist2, orient, segments_touch};

/// A comb router: waypoints from the first point to the second, `false` if none.
pub type CombFn<'a> = dyn Fn(Point2, Point2, &mut dyn FnMut(Point2)) -> bool + 'a;

/// A combed travel may be this much (um) longer than twice the straight one.
pub const COMB_EXTRA_UM: i64 = 15_000;

/// Most loops one combed travel goes around.
pub(super) const MAX_COMB_LOOPS: usize = 16;

/// Most comb waypoints a plan keeps for its travel (the sample models' routes have at most
/// 57, nearly all at most 32); a longer route is found again when travelled.
pub(super) const ROUTE_POINTS: usize = 32;

/// The waypoints of the comb route [`Emitter::plan_travel`] found, for the travel it planned.
#[derive(Debug, Clone, Copy)]
pub(super) struct Route {
    pub(super) pts: [Point2; ROUTE_POINTS],
    /// Waypoints of the route (more than [`ROUTE_POINTS`]: only the first are kept).
    pub(super) len: usize,
}

impl Route {
    /// No waypoints (all zero bytes).
    pub(super) const EMPTY: Self = Self { pts: [Point2::new(0, 0); ROUTE_POINTS], len: 0 };

    pub(super) fn push(&mut self, w: Point2) {
        if let Some(slot) = self.pts.get_mut(self.len) {
            *slot = w;
        }
        self.len = self.len.saturating_add(1);
    }

    /// The waypoints, when all were kept.
    pub(super) fn points(&self) -> Option<&[Point2]> {
        self.pts.get(..self.len)
    }
}

/// A loop the travel `a`-`b` crosses: record `rec`, first met on edge `e_in`, last met on
/// edge `e_out` (edge `k` runs from point `k` to the next). The crossings' parameters and
/// points are computed again from the edges (12 bytes a hit on the stack).
#[derive(Clone, Copy)]
pub(super) struct Hit {
    rec: u32,
    e_in: u32,
    e_out: u32,
}

/// A parameter along a travel: `num / den`, `den > 0`.
pub(super) type Frac = (i64, i64);

pub(super) fn frac_lt(x: Frac, y: Frac) -> bool {
    i128::from(x.0) * i128::from(y.1) < i128::from(y.0) * i128::from(x.1)
}

/// Parameter `num / den` (`den > 0`) of the intersection of `a`-`b` with `p`-`q` (they
/// touch); `None` past i64 (coordinates far beyond the print volume).
pub(super) fn cut_t(a: Point2, b: Point2, p: Point2, q: Point2) -> Option<Frac> {
    let (da, db) = (i128::from(orient(p, q, a)), i128::from(orient(p, q, b)));
    let (num, den) = if da != db {
        (da, da - db)
    } else {
        // Collinear: the nearer end of p-q along a-b.
        let along = |v: Point2| {
            i128::from(v.x - a.x) * i128::from(b.x - a.x)
                + i128::from(v.y - a.y) * i128::from(b.y - a.y)
        };
        let len2 = i128::from(dist2(a, b)).max(1);
        (along(p).min(along(q)).max(0), len2)
    };
    let (num, den) = if den < 0 { (-num, -den) } else { (num, den) };
    Some((i64::try_from(num).ok()?, i64::try_from(den).ok()?))
}

/// The point at parameter `t` along `a`-`b` (rounded to the nearest unit).
pub(super) fn point_at(a: Point2, b: Point2, t: Frac) -> Point2 {
    let (num, den) = (i128::from(t.0), i128::from(t.1).max(1));
    let at = |o: i32, e: i32| {
        let v = i128::from(o) + super::super::poly::div_round_128(i128::from(e - o) * num, den);
        v as i32
    };
    Point2::new(at(a.x, b.x), at(a.y, b.y))
}

/// The comb route from `a` to `b` around the external perimeter loops of `island` that the
/// straight travel crosses: for each (outermost first along the travel) the shorter way
/// along the loop between where the travel meets it first and last. Calls `visit` for every
/// waypoint after `a`, ending with `b`. False if the travel meets too many loops.
pub(super) fn comb_route<const N: usize>(
    paths: &PathBuf<N>,
    island: u16,
    a: Point2,
    b: Point2,
    visit: &mut dyn FnMut(Point2),
) -> bool {
    let mut hits = [Hit { rec: 0, e_in: 0, e_out: 0 }; MAX_COMB_LOOPS];
    let mut nh = 0;
    let (lo, hi) =
        (Point2::new(a.x.min(b.x), a.y.min(b.y)), Point2::new(a.x.max(b.x), a.y.max(b.y)));
    for ri in 0..paths.len() {
        let r = &paths.rec(ri);
        if r.island != island || r.kind != PathKind::Perimeter(0) {
            continue;
        }
        let pts = paths.points(r);
        let n = pts.len();
        // (t_in, e_in, t_out, e_out) of the loop so far.
        let mut hit: Option<(Frac, usize, Frac, usize)> = None;
        for k in 0..n {
            let (p, q) = (pts.at(k), pts.at((k + 1) % n));
            if p.x.max(q.x) < lo.x
                || p.x.min(q.x) > hi.x
                || p.y.max(q.y) < lo.y
                || p.y.min(q.y) > hi.y
            {
                continue;
            }
            if !segments_touch(a, b, p, q) {
                continue;
            }
            let Some(t) = cut_t(a, b, p, q) else { return false };
            let h = hit.get_or_insert((t, k, t, k));
            if frac_lt(t, h.0) {
                (h.0, h.1) = (t, k);
            }
            if frac_lt(h.2, t) {
                (h.2, h.3) = (t, k);
            }
        }
        if let Some((_, e_in, _, e_out)) = hit {
            if nh == MAX_COMB_LOOPS {
                return false;
            }
            hits[nh] = Hit { rec: ri as u32, e_in: e_in as u32, e_out: e_out as u32 };
            nh += 1;
        }
    }
    // Where the travel meets edge `e` of record `rec` (found touching above).
    let edge_t = |rec: u32, e: u32| {
        let pts = paths.points(&paths.rec(rec as usize));
        let (e, n) = (e as usize, pts.len());
        cut_t(a, b, pts.at(e), pts.at((e + 1) % n)).unwrap_or((0, 1))
    };
    let hits = &mut hits[..nh];
    hits.sort_unstable_by(|x, y| {
        let (tx, ty) = (edge_t(x.rec, x.e_in), edge_t(y.rec, y.e_in));
        (i128::from(tx.0) * i128::from(ty.1)).cmp(&(i128::from(ty.0) * i128::from(tx.1)))
    });
    let mut done_to: Frac = (0, 1);
    for h in hits.iter() {
        let t_in = edge_t(h.rec, h.e_in);
        if frac_lt(t_in, done_to) {
            continue;
        }
        let r = paths.rec(h.rec as usize);
        let pts = paths.points(&r);
        let n = pts.len();
        let (e_in, e_out) = (h.e_in as usize, h.e_out as usize);
        let t_out = edge_t(h.rec, h.e_out);
        let (p_in, p_out) = (point_at(a, b, t_in), point_at(a, b, t_out));
        // Forward: vertices e_in+1 ..= e_out; backward: e_in, e_in-1, ..., e_out+1.
        let fwd_count = (e_out + n - e_in) % n;
        let back_count = (e_in + n - e_out) % n;
        let walk_len = |count: usize, fwd: bool| {
            let mut len = 0i64;
            let mut prev = p_in;
            for s in 0..count {
                let v = if fwd { pts.at((e_in + 1 + s) % n) } else { pts.at((e_in + n - s) % n) };
                len += dist(prev, v);
                prev = v;
            }
            len + dist(prev, p_out)
        };
        let fwd = walk_len(fwd_count, true) <= walk_len(back_count, false);
        visit(p_in);
        let count = if fwd { fwd_count } else { back_count };
        for s in 0..count {
            visit(if fwd { pts.at((e_in + 1 + s) % n) } else { pts.at((e_in + n - s) % n) });
        }
        visit(p_out);
        done_to = t_out;
    }
    visit(b);
    true
}

/// The comb router of `island`'s paths.
pub(super) fn comber<const N: usize>(
    paths: &PathBuf<N>,
    island: u16,
) -> impl Fn(Point2, Point2, &mut dyn FnMut(Point2)) -> bool + '_ {
    move |a, b, visit| comb_route(paths, island, a, b, visit)
}
