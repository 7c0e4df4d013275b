//! Ordering, travel, retraction and extrusion amounts: one layer's paths become moves.
//!
//! Islands are visited nearest first. Within an island the perimeters go inner to outer (the
//! external perimeter last, by default) and then the infill runs, each stage nearest first
//! from where the nozzle is; loops start at their seam (the rear-most vertex, or the nearest
//! one), open runs at whichever end is closer. The nearest path is looked up in a
//! [`NearGrid`] of every path's entry points (rear seams are rotated to the front of their
//! loop first) and, once an island is chosen, only within the box of its paths' entries (the
//! path records are grouped by island first, keeping their order), so a layer of `n` paths
//! costs about `n` grid lookups instead of `n^2` distance checks (islands of at most
//! 16 paths are simply scanned); loops whose entry depends on the nozzle (nearest-vertex seams) are
//! scanned beside it, and a layer whose paths do not fit the grid's buffers is scanned
//! whole. The choice is the scan's in every case (lowest index among equally near paths). A travel that crosses no contour of the layer
//! stays inside the part (combing) and needs no retraction; one that crosses a contour and is
//! at least `min_retract_travel_um` long retracts first and primes again before the next
//! extrusion.
//!
//! Extrusion: `E = width x height x length / filament area`, accumulated as an exact volume
//! (um^3 x 16) and converted to a rounded absolute filament position, so per-move rounding
//! never drifts. The filament area uses pi = 355/113 (relative error 8.5e-8).

use core::ops::Range;

use crate::geom::Point2;
use crate::machine::Rate;
use crate::slot::Slot;

use super::near::{GridShape, NearGrid};
use super::paths;
use super::paths::{PathBuf, PathKind, PathPoints, PathRec};
use super::poly::{dist, dist2, orient, segment_touches_rings, segments_touch, Ring};
use super::{Feature, LayerStats, Room, Seam, ToolEvent, ToolMove, ToolpathConfig};

/// A comb router: waypoints from the first point to the second, `false` if none.
pub type CombFn<'a> = dyn Fn(Point2, Point2, &mut dyn FnMut(Point2)) -> bool + 'a;

/// A combed travel may be this much (um) longer than twice the straight one.
const COMB_EXTRA_UM: i64 = 15_000;
/// Most loops one combed travel goes around.
const MAX_COMB_LOOPS: usize = 16;
/// Most comb waypoints a plan keeps for its travel (the sample models' routes have at most
/// 57, nearly all at most 32); a longer route is found again when travelled.
const ROUTE_POINTS: usize = 32;

/// The waypoints of the comb route [`Emitter::plan_travel`] found, for the travel it planned.
#[derive(Debug, Clone, Copy)]
struct Route {
    pts: [Point2; ROUTE_POINTS],
    /// Waypoints of the route (more than [`ROUTE_POINTS`]: only the first are kept).
    len: usize,
}

impl Route {
    /// No waypoints (all zero bytes).
    const EMPTY: Self = Self { pts: [Point2::new(0, 0); ROUTE_POINTS], len: 0 };

    fn push(&mut self, w: Point2) {
        if let Some(slot) = self.pts.get_mut(self.len) {
            *slot = w;
        }
        self.len = self.len.saturating_add(1);
    }

    /// The waypoints, when all were kept.
    fn points(&self) -> Option<&[Point2]> {
        self.pts.get(..self.len)
    }
}

/// Nozzle state and per-layer counters.
#[derive(Debug, Clone, Copy)]
pub struct Emitter {
    /// Where the nozzle is (XY, um).
    pub pos: Point2,
    /// Nozzle height (um).
    pub z: i32,
    /// Height to move to before the next travel.
    pub pending_z: Option<i32>,
    /// Filament is retracted.
    pub retracted: bool,
    /// Extruded volume so far, um^3 x 16.
    vol16: i64,
    /// Absolute filament position for `vol16`, um (retractions excluded).
    e_abs: i64,
    /// The last move extruded (a travel ends an extrusion run).
    extruding: bool,
    /// Counters of the layer being emitted.
    pub layer: LayerStats,
}

impl Emitter {
    /// At the bed origin, nothing extruded.
    pub const fn new() -> Self {
        Self {
            pos: Point2::new(0, 0),
            z: 0,
            pending_z: None,
            retracted: false,
            vol16: 0,
            e_abs: 0,
            extruding: false,
            layer: LayerStats::EMPTY,
        }
    }
}

impl Default for Emitter {
    fn default() -> Self {
        Self::new()
    }
}

/// Filament length (um) for a volume of `vol16 / 16` um^3: `4 V / (pi d^2)`.
pub fn filament_um(vol16: i64, filament_diameter_um: i32) -> i64 {
    let d2 = i64::from(filament_diameter_um) * i64::from(filament_diameter_um);
    // 4 V 113 / (355 d^2) with V = vol16 / 16.
    vol16 * 113 / (1420 * d2)
}

/// Everything the emitter reads besides its state.
pub struct Ctx<'a> {
    /// Settings.
    pub cfg: &'a ToolpathConfig,
    /// Contour points of the layer (combing).
    pub points: &'a [Point2],
    /// Contour loops of the layer.
    pub rings: &'a [Ring],
    /// Layer height (um), for extrusion.
    pub height_um: i32,
    /// First layer: every extrusion at the first-layer speed.
    pub first_layer: bool,
}

impl Ctx<'_> {
    fn feed(&self, f: Feature) -> Rate {
        let c = self.cfg;
        match f {
            Feature::Travel => c.travel_speed_mm_s,
            Feature::Retract | Feature::Unretract => c.retract_speed_mm_s,
            _ if self.first_layer => c.first_layer_speed_mm_s,
            Feature::ExternalPerimeter | Feature::Perimeter | Feature::Skirt => {
                c.perimeter_speed_mm_s
            }
            Feature::InternalInfill | Feature::SolidInfill | Feature::TopSolidInfill => {
                c.infill_speed_mm_s
            }
        }
    }

    /// Does the segment touch any contour edge of the layer?
    fn crosses_contour(&self, a: Point2, b: Point2) -> bool {
        segment_touches_rings(self.points, self.rings, a, b)
    }
}

/// A travel planned by [`Emitter::plan_travel`].
#[derive(Debug, Clone, Copy)]
struct Travel {
    /// Retract first (unless already retracted).
    retract: bool,
    /// Follow the comb route.
    routed: bool,
    /// Moves it emits: retraction, height change and the legs that move.
    moves: u32,
}

impl Emitter {
    fn send(&mut self, sink: &mut impl FnMut(&ToolEvent<'_>), m: ToolMove) {
        sink(&ToolEvent::Move(m));
    }

    /// Travels to `to`. A travel that crosses no contour stays inside the part; one that
    /// does is routed by `comb` (waypoints after the start, ending at `to`) when that route
    /// crosses no contour and is not much longer; otherwise it retracts first (from
    /// `min_retract_travel_um` on).
    pub fn travel_to(
        &mut self,
        ctx: &Ctx<'_>,
        to: Point2,
        comb: &CombFn<'_>,
        sink: &mut impl FnMut(&ToolEvent<'_>),
    ) {
        let mut route = Route::EMPTY;
        let plan = self.plan_travel(ctx, to, comb, &mut route);
        self.travel(ctx, to, plan, &route, comb, sink);
    }

    /// What [`travel_to`](Self::travel_to) would do from here, nothing emitted: whether it
    /// retracts, whether it takes the comb route (its waypoints into `route`), and its moves
    /// exactly.
    fn plan_travel(
        &self,
        ctx: &Ctx<'_>,
        to: Point2,
        comb: &CombFn<'_>,
        route: &mut Route,
    ) -> Travel {
        if to == self.pos && self.pending_z.is_none() {
            return Travel { retract: false, routed: false, moves: 0 };
        }
        let from = self.pos;
        let d = dist(from, to);
        let mut routed = false;
        // Legs that move (a waypoint equal to the one before makes no move).
        let mut legs = u32::from(to != from);
        // Short hops go straight and retract neither way: whether they cross a contour is
        // not asked.
        let short = d < i64::from(ctx.cfg.min_retract_travel_um);
        let leaves = d > 0 && !short && (!ctx.cfg.comb || ctx.crosses_contour(from, to));
        if leaves && ctx.cfg.comb {
            // Check the detour leg by leg, then take it.
            let (mut prev, mut ok, mut len, mut waypoints, mut moving) =
                (from, true, 0i64, 0u32, 0u32);
            let longest = 2 * d + COMB_EXTRA_UM;
            route.len = 0;
            let found = comb(from, to, &mut |w| {
                route.push(w);
                len += dist(prev, w);
                // A route already refused (too long, or a leg leaves) needs no more checks.
                ok = ok && len <= longest && !ctx.crosses_contour(prev, w);
                waypoints += 1;
                moving += u32::from(w != prev);
                prev = w;
            });
            routed = found && ok && waypoints > 1;
            if routed {
                legs = moving;
            }
        }
        let retract = leaves && !routed && ctx.cfg.retract_length_um > 0;
        let moves = u32::from(retract && !self.retracted) + u32::from(self.pending_z.is_some());
        Travel { retract, routed, moves: moves + legs }
    }

    /// Carries out `plan` (made by [`plan_travel`](Self::plan_travel) from this state, with
    /// `route`; `comb` finds a route too long to be kept again).
    fn travel(
        &mut self,
        ctx: &Ctx<'_>,
        to: Point2,
        plan: Travel,
        route: &Route,
        comb: &CombFn<'_>,
        sink: &mut impl FnMut(&ToolEvent<'_>),
    ) {
        if to == self.pos && self.pending_z.is_none() {
            return;
        }
        let from = self.pos;
        if plan.retract && !self.retracted {
            self.retracted = true;
            self.layer.retractions += 1;
            let m = ToolMove {
                to: self.pos,
                z_um: self.z,
                e_um: -ctx.cfg.retract_length_um,
                feed_mm_s: ctx.feed(Feature::Retract),
                feature: Feature::Retract,
            };
            self.send(sink, m);
        }
        if let Some(z) = self.pending_z.take() {
            self.z = z;
            self.layer.travel_moves += 1;
            let m = ToolMove {
                to: self.pos,
                z_um: z,
                e_um: 0,
                feed_mm_s: ctx.feed(Feature::Travel),
                feature: Feature::Travel,
            };
            self.send(sink, m);
        }
        if plan.routed {
            match route.points() {
                Some(pts) => pts.iter().for_each(|&w| self.travel_leg(ctx, w, sink)),
                None => {
                    comb(from, to, &mut |w| self.travel_leg(ctx, w, sink));
                }
            }
        } else {
            self.travel_leg(ctx, to, sink);
        }
        self.extruding = false;
    }

    fn travel_leg(&mut self, ctx: &Ctx<'_>, to: Point2, sink: &mut impl FnMut(&ToolEvent<'_>)) {
        if to == self.pos {
            return;
        }
        self.layer.travel_moves += 1;
        self.layer.travel_um += dist(self.pos, to) as u64;
        self.pos = to;
        let m = ToolMove {
            to,
            z_um: self.z,
            e_um: 0,
            feed_mm_s: ctx.feed(Feature::Travel),
            feature: Feature::Travel,
        };
        self.send(sink, m);
    }

    /// Extrudes a line to `to`.
    pub fn extrude_to(
        &mut self,
        ctx: &Ctx<'_>,
        to: Point2,
        feature: Feature,
        sink: &mut impl FnMut(&ToolEvent<'_>),
    ) {
        if to == self.pos {
            return;
        }
        if self.retracted {
            self.retracted = false;
            let m = ToolMove {
                to: self.pos,
                z_um: self.z,
                e_um: ctx.cfg.retract_length_um,
                feed_mm_s: ctx.feed(Feature::Unretract),
                feature: Feature::Unretract,
            };
            self.send(sink, m);
        }
        if !self.extruding {
            self.layer.stops += 1;
            self.extruding = true;
        }
        let len16 = crate::math::isqrt_u64((dist2(self.pos, to) * 256) as u64) as i64;
        self.vol16 += i64::from(ctx.cfg.line_width_um) * i64::from(ctx.height_um) * len16;
        let e_abs = filament_um(self.vol16, ctx.cfg.filament_diameter_um);
        let e = (e_abs - self.e_abs) as i32;
        self.e_abs = e_abs;
        self.layer.extrusion_moves += 1;
        self.layer.filament_um += i64::from(e);
        self.pos = to;
        let m = ToolMove { to, z_um: self.z, e_um: e, feed_mm_s: ctx.feed(feature), feature };
        self.send(sink, m);
    }

    /// Total filament extruded so far, um.
    pub fn filament_total_um(&self) -> i64 {
        self.e_abs
    }
}

/// Rear-most vertex (largest y, then smallest x).
fn rear(pts: PathPoints<'_>) -> usize {
    let mut best = 0;
    for (i, p) in pts.iter().enumerate() {
        let b = pts.at(best);
        if p.y > b.y || (p.y == b.y && p.x < b.x) {
            best = i;
        }
    }
    best
}

fn nearest(pts: PathPoints<'_>, from: Point2) -> usize {
    let mut best = 0;
    let mut bd = i64::MAX;
    for (i, p) in pts.iter().enumerate() {
        let d = dist2(from, p);
        if d < bd {
            bd = d;
            best = i;
        }
    }
    best
}

/// Where path `r` would start from `from`: (point index, reversed, squared distance). Rear
/// seams are rotated to the front of their loop before any perimeter is entered.
fn entry<const N: usize>(
    paths: &PathBuf<N>,
    r: &PathRec,
    seam: Seam,
    from: Point2,
) -> (usize, bool, i64) {
    let pts = paths.points(r);
    if r.closed {
        let i = match (seam, r.kind) {
            (Seam::Rear, PathKind::Perimeter(_)) => 0,
            _ => nearest(pts, from),
        };
        return (i, false, dist2(from, pts.at(i)));
    }
    let (d0, d1) = (dist2(from, pts.at(0)), dist2(from, pts.at(pts.len() - 1)));
    if r.reversible && d1 < d0 {
        (pts.len() - 1, true, d1)
    } else {
        (0, false, d0)
    }
}

/// Stage of a path within its island: lower first.
fn stage(r: &PathRec, cfg: &ToolpathConfig) -> u8 {
    match r.kind {
        PathKind::Skirt => 0,
        PathKind::Perimeter(d) => {
            if cfg.outer_perimeter_last {
                cfg.perimeters.saturating_sub(d)
            } else {
                d + 1
            }
        }
        PathKind::Infill => cfg.perimeters.saturating_add(1),
    }
}

/// A loop the travel `a`-`b` crosses: record `rec`, first met on edge `e_in`, last met on
/// edge `e_out` (edge `k` runs from point `k` to the next). The crossings' parameters and
/// points are computed again from the edges (12 bytes a hit on the stack).
#[derive(Clone, Copy)]
struct Hit {
    rec: u32,
    e_in: u32,
    e_out: u32,
}

/// A parameter along a travel: `num / den`, `den > 0`.
type Frac = (i64, i64);

fn frac_lt(x: Frac, y: Frac) -> bool {
    i128::from(x.0) * i128::from(y.1) < i128::from(y.0) * i128::from(x.1)
}

/// Parameter `num / den` (`den > 0`) of the intersection of `a`-`b` with `p`-`q` (they
/// touch); `None` past i64 (coordinates far beyond the print volume).
fn cut_t(a: Point2, b: Point2, p: Point2, q: Point2) -> Option<Frac> {
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
fn point_at(a: Point2, b: Point2, t: Frac) -> Point2 {
    let (num, den) = (i128::from(t.0), i128::from(t.1).max(1));
    let at = |o: i32, e: i32| {
        let v = i128::from(o) + super::poly::div_round_128(i128::from(e - o) * num, den);
        v as i32
    };
    Point2::new(at(a.x, b.x), at(a.y, b.y))
}

/// The comb route from `a` to `b` around the external perimeter loops of `island` that the
/// straight travel crosses: for each (outermost first along the travel) the shorter way
/// along the loop between where the travel meets it first and last. Calls `visit` for every
/// waypoint after `a`, ending with `b`. False if the travel meets too many loops.
fn comb_route<const N: usize>(
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

/// The points path `r` extrudes to from its start point `start` (`reversed`: an open path
/// from its last point): (point index, index of the feature of the move reaching it).
fn path_order(r: &PathRec, start: usize, reversed: bool) -> impl Iterator<Item = (usize, usize)> {
    let n = r.len as usize;
    let (closed, count) = if r.closed { (true, n) } else { (false, n.saturating_sub(1)) };
    (0..count).map(move |k| {
        if closed {
            let i = (start + k + 1) % n;
            (i, i)
        } else if reversed {
            let i = n - 2 - k;
            (i, i + 1)
        } else {
            (k + 1, k + 1)
        }
    })
}

/// The comb router of `island`'s paths.
fn comber<const N: usize>(
    paths: &PathBuf<N>,
    island: u16,
) -> impl Fn(Point2, Point2, &mut dyn FnMut(Point2)) -> bool + '_ {
    move |a, b, visit| comb_route(paths, island, a, b, visit)
}

/// Plans printing path `r` from `start` (`reversed`: from its last point): the travel to
/// its start and the moves of the whole unit (travel, priming, extrusions), exactly.
fn plan_path<const N: usize>(
    em: &Emitter,
    ctx: &Ctx<'_>,
    paths: &PathBuf<N>,
    r: &PathRec,
    start: usize,
    reversed: bool,
    route: &mut Route,
) -> (Travel, u32) {
    let pts = paths.points(r);
    let travel = em.plan_travel(ctx, pts.at(start), &comber(paths, r.island), route);
    // Extrusions: the points that differ from the one before (the nozzle is at the start).
    let mut prev = pts.at(start);
    let mut extrusions = 0u32;
    for (i, _) in path_order(r, start, reversed) {
        extrusions += u32::from(pts.at(i) != prev);
        prev = pts.at(i);
    }
    let primes = (em.retracted || travel.retract) && extrusions > 0;
    (travel, travel.moves + u32::from(primes) + extrusions)
}

/// Emits `unit`'s moves from `em`'s state: the travel (and retraction, height change,
/// priming) and the path, or the closing move.
#[inline(never)]
fn run_unit<const N: usize>(
    em: &mut Emitter,
    ctx: &Ctx<'_>,
    paths: &PathBuf<N>,
    unit: &Unit,
    route: &Route,
    sink: &mut impl FnMut(&ToolEvent<'_>),
) {
    match unit.path {
        Some(p) => {
            let r = paths.rec(p.index);
            print_path(em, ctx, paths, &r, p.start, p.reversed, unit.travel, route, sink);
        }
        None => {
            let here = em.pos;
            em.travel(ctx, here, unit.travel, route, &|_, _, _| false, sink);
        }
    }
}

/// Prints path `r` from `start` after the `travel` planned for it ([`plan_path`]).
#[allow(clippy::too_many_arguments)]
fn print_path<const N: usize>(
    em: &mut Emitter,
    ctx: &Ctx<'_>,
    paths: &PathBuf<N>,
    r: &PathRec,
    start: usize,
    reversed: bool,
    travel: Travel,
    route: &Route,
    sink: &mut impl FnMut(&ToolEvent<'_>),
) {
    let pts = paths.points(r);
    em.travel(ctx, pts.at(start), travel, route, &comber(paths, r.island), sink);
    for (i, f) in path_order(r, start, reversed) {
        em.extrude_to(ctx, pts.at(i), pts.feature(f), sink);
    }
}

/// Where path `i` starts when it is entered at `end` (0: its first point, or a closed
/// loop's seam; 1: an open path's last point), if that point does not depend on where the
/// nozzle is (every path but the closed loops whose start is their nearest vertex).
fn fixed_entry<const N: usize>(
    paths: &PathBuf<N>,
    seam: Seam,
    i: usize,
    end: u32,
) -> Option<Point2> {
    let r = &paths.get(i)?;
    let pts = paths.points(r);
    if r.closed {
        // Rear seams are rotated to the front of the loop before ordering.
        let rear_seam = seam == Seam::Rear && matches!(r.kind, PathKind::Perimeter(_));
        return if rear_seam && end == 0 { pts.first() } else { None };
    }
    match end {
        0 => pts.first(),
        _ if r.reversible => pts.last(),
        _ => None,
    }
}

/// Islands with at most this many paths are searched by scanning them.
const SCAN_MAX: usize = 16;

/// Path search of one layer: a [`NearGrid`] over the fixed entry points (item `2 i + end`
/// for path `i`), plus a scan of the loops whose entry depends on the nozzle; a scan when the
/// grid does not fit its buffers or the paths searched are few. Every query returns what
/// the plain scan over the same paths returns (the nearest entry, the lowest path index
/// among equals, the first end of a path among equals).
struct Finder<'g> {
    grid: Option<NearGrid<'g>>,
    /// Some path's entry depends on the nozzle position (nearest-vertex loops).
    loose: bool,
}

/// The paths one search looks at: indices `range`, entries inside `window` if given.
#[derive(Debug, Clone)]
struct Scope {
    range: Range<usize>,
    window: Option<(Point2, Point2)>,
}

impl<'g> Finder<'g> {
    fn new<const N: usize>(
        paths: &PathBuf<N>,
        seam: Seam,
        head: &'g mut [u32],
        next: &'g mut [u32],
    ) -> Self {
        let n = paths.len();
        let pos = |id: u32| {
            let i = (id / 2) as usize;
            if paths.rec(i).done {
                return None;
            }
            fixed_entry(paths, seam, i, id % 2)
        };
        let loose = (0..n).any(|i| {
            let r = &paths.rec(i);
            !r.done && r.closed && fixed_entry(paths, seam, i, 0).is_none()
        });
        let grid = NearGrid::build(2 * n, pos, head, next).ok();
        Self { grid, loose }
    }

    /// The search of a layer whose grid (of `shape`, if one was built) is in `head` and
    /// `next`; without it (or when they do not hold it) paths are found by scanning.
    fn resume(
        shape: Option<GridShape>,
        loose: bool,
        head: &'g mut [u32],
        next: &'g mut [u32],
    ) -> Self {
        Self { grid: shape.and_then(|s| NearGrid::resume(s, head, next)), loose }
    }

    /// The scope of paths `range`: with the bounding box of their fixed entries.
    fn scope<const N: usize>(paths: &PathBuf<N>, seam: Seam, range: Range<usize>) -> Scope {
        let mut window: Option<(Point2, Point2)> = None;
        for i in range.clone() {
            for end in 0..2 {
                if let Some(p) = fixed_entry(paths, seam, i, end) {
                    let (lo, hi) = window.get_or_insert((p, p));
                    *lo = Point2::new(lo.x.min(p.x), lo.y.min(p.y));
                    *hi = Point2::new(hi.x.max(p.x), hi.y.max(p.y));
                }
            }
        }
        Scope { range, window }
    }

    /// The nearest path from `from` among those of `scope` that `accept` takes (never a
    /// done one): (squared distance, index, start point, reversed).
    fn find<const N: usize>(
        &self,
        paths: &PathBuf<N>,
        seam: Seam,
        from: Point2,
        scope: &Scope,
        accept: &dyn Fn(&PathRec) -> bool,
    ) -> Option<(i64, usize, usize, bool)> {
        let range = scope.range.clone();
        let grid = match &self.grid {
            Some(g) if range.len() > SCAN_MAX => g,
            _ => {
                let mut pick: Option<(i64, usize, usize, bool)> = None;
                for i in range {
                    let r = &paths.rec(i);
                    if r.done || !accept(r) {
                        continue;
                    }
                    let (start, rev, d) = entry(paths, r, seam, from);
                    if pick.map_or(true, |p| d < p.0) {
                        pick = Some((d, i, start, rev));
                    }
                }
                return pick;
            }
        };
        let pos = |id: u32| fixed_entry(paths, seam, (id / 2) as usize, id % 2);
        let take = |id: u32| {
            let i = (id / 2) as usize;
            range.contains(&i) && {
                let r = paths.rec(i);
                !r.done && accept(&r)
            }
        };
        let hit = match scope.window {
            Some((lo, hi)) => grid.nearest_in(from, lo, hi, pos, take),
            None => grid.nearest(from, pos, take),
        };
        let mut pick = hit.map(|(d, id)| {
            let i = (id / 2) as usize;
            let rev = id % 2 == 1;
            let start = if rev { (paths.rec(i).len as usize).saturating_sub(1) } else { 0 };
            (d, i, start, rev)
        });
        if self.loose {
            for i in range.clone() {
                let r = &paths.rec(i);
                if r.done || !r.closed || fixed_entry(paths, seam, i, 0).is_some() || !accept(r) {
                    continue;
                }
                let (start, rev, d) = entry(paths, r, seam, from);
                if pick.map_or(true, |p| (d, i) < (p.0, p.1)) {
                    pick = Some((d, i, start, rev));
                }
            }
        }
        pick
    }

    /// Path `i` was printed.
    fn done<const N: usize>(&mut self, paths: &PathBuf<N>, seam: Seam, i: usize) {
        if let Some(g) = &mut self.grid {
            for end in 0..2 {
                if let Some(p) = fixed_entry(paths, seam, i, end) {
                    g.remove(2 * i as u32 + end, p);
                }
            }
        }
    }
}

/// One unit of a layer's emission, planned: a path with the travel before it, or the
/// layer's closing move to its height.
#[derive(Debug, Clone, Copy)]
struct Unit {
    /// The path, or `None` for the closing move.
    path: Option<PathUnit>,
    /// The travel to the path's start (to where the nozzle is, for the closing move).
    travel: Travel,
    /// Moves the unit emits, exactly.
    moves: u32,
}

/// A path to print: its index, start point, direction and ordering stage.
#[derive(Debug, Clone, Copy)]
struct PathUnit {
    index: usize,
    start: usize,
    reversed: bool,
    stage: u8,
}

/// The island being printed: its paths (`range`, searched within `scope`) and, after a
/// perimeter loop, the next perimeter stage, tried first (the loops around one hole go
/// together).
#[derive(Debug, Clone)]
struct IslandCursor {
    island: u16,
    range: Range<usize>,
    scope: Scope,
    chain: Option<u8>,
}

/// Where a layer's emission stands. `repr(u8)`: a tag byte with `Idle` = 0 (the niche
/// layout would store `Idle` as 3), so that an idle emission is all zero bytes.
#[derive(Debug, Clone)]
#[repr(u8)]
enum Phase {
    /// No layer is being emitted.
    Idle,
    /// The skirt loops, in path order, from path `from` on.
    Skirt { from: usize },
    /// The islands, nearest first (`None`: between two islands).
    Islands(Option<IslandCursor>),
    /// The closing move is next.
    Closing,
    /// Every unit was emitted.
    Closed,
}

/// The emission of one layer's paths, resumable between units.
///
/// The skirt first (in order), then the islands nearest first, in each the stages in order and the
/// nearest path first (see the [module docs](self)), then a move to the layer's height if none went
/// there. Each [`emit`](Self::emit) call emits whole units while the room it was given takes them
/// (each opened with its exact moves, kept or undone at its end); the state between calls is this
/// value, the [`Emitter`], the layer's paths (their done flags, the rear seams rotated, the records
/// grouped by island), `island_stage` and the nearest-path grid's buffers, which the owner keeps
/// untouched until the layer is complete.
#[derive(Debug, Clone)]
pub struct Emission {
    phase: Phase,
    /// The nearest-path grid's shape once built (its lists are in the grid buffers).
    grid: Option<GridShape>,
    /// Some path's entry depends on the nozzle position (nearest-vertex seams).
    loose: bool,
    /// The next unit, planned (it waits for room).
    next: Slot<Unit>,
    /// The comb route of the next unit's travel.
    route: Route,
}

impl Default for Emission {
    fn default() -> Self {
        Self::new()
    }
}

impl Emission {
    /// Nothing to emit.
    pub const fn new() -> Self {
        Self {
            phase: Phase::Idle,
            grid: None,
            loose: false,
            next: Slot::Empty,
            route: Route::EMPTY,
        }
    }

    /// A layer's emission has begun and is not complete.
    pub fn is_active(&self) -> bool {
        !matches!(self.phase, Phase::Idle)
    }

    /// Begins emitting a layer whose paths are all in `paths`; `island_stage` (one entry
    /// per island) gets each island's first stage.
    pub fn begin<const N: usize>(
        &mut self,
        cfg: &ToolpathConfig,
        paths: &PathBuf<N>,
        island_stage: &mut [u8],
    ) {
        for s in island_stage.iter_mut() {
            *s = u8::MAX;
        }
        for i in 0..paths.len() {
            let r = paths.rec(i);
            if let Some(s) = island_stage.get_mut(r.island as usize) {
                *s = (*s).min(stage(&r, cfg));
            }
        }
        *self = Self { phase: Phase::Skirt { from: 0 }, ..Self::new() };
    }

    /// Emits the layer's next units in order into `room` while it takes each (opened with
    /// its moves; when the room undoes it at its close, `em` goes back to its state before
    /// the unit, which nothing else changed). Returns the moves of the unit refused or
    /// undone (it is offered first by a later call), or `None` when
    /// the layer's last unit was emitted (or none was being emitted). `grid_head` and
    /// `grid_next` are scratch for the nearest-path grid (cells, and two entries per path;
    /// when `grid_next` holds fewer, paths are found by scanning: the same order), kept
    /// between the calls of one layer.
    #[allow(clippy::too_many_arguments)]
    pub fn emit<const N: usize, R: Room + ?Sized>(
        &mut self,
        em: &mut Emitter,
        ctx: &Ctx<'_>,
        paths: &mut PathBuf<N>,
        island_stage: &mut [u8],
        grid_head: &mut [u32],
        grid_next: &mut [u32],
        room: &mut R,
    ) -> Option<u32> {
        let seam = ctx.cfg.seam;
        loop {
            let unit = match self.next {
                Slot::Full(u) => u,
                Slot::Empty => {
                    match self.plan_next(em, ctx, paths, island_stage, grid_head, grid_next) {
                        Some(u) => u,
                        None => {
                            self.phase = Phase::Idle;
                            return None;
                        }
                    }
                }
            };
            let taken = room.open(unit.moves) && {
                let before = *em;
                run_unit(em, ctx, paths, &unit, &self.route, &mut |e: &ToolEvent<'_>| {
                    room.event(e)
                });
                room.close() || {
                    *em = before;
                    false
                }
            };
            if !taken {
                self.next = Slot::Full(unit);
                return Some(unit.moves);
            }
            self.next = Slot::Empty;
            em.layer.max_unit_moves = em.layer.max_unit_moves.max(unit.moves);
            let Some(p) = unit.path else { continue };
            if let Phase::Islands(Some(c)) = &mut self.phase {
                let mut finder = Finder::resume(self.grid, self.loose, grid_head, grid_next);
                finder.done(paths, seam, p.index);
                let infill_stage =
                    stage(&PathRec { kind: PathKind::Infill, ..paths::EMPTY_REC }, ctx.cfg);
                c.chain = (p.stage + 1 < infill_stage).then_some(p.stage + 1);
            }
            paths.set_done(p.index);
        }
    }

    /// Finds and plans the next unit from where the nozzle is, advancing through the
    /// phases; `None` when every unit was emitted.
    fn plan_next<const N: usize>(
        &mut self,
        em: &Emitter,
        ctx: &Ctx<'_>,
        paths: &mut PathBuf<N>,
        island_stage: &mut [u8],
        grid_head: &mut [u32],
        grid_next: &mut [u32],
    ) -> Option<Unit> {
        let cfg = ctx.cfg;
        let seam = cfg.seam;
        let n = paths.len();
        let route = &mut self.route;
        let mut plan =
            |paths: &PathBuf<N>, index: usize, start: usize, reversed: bool, stage: u8| {
                let r = paths.rec(index);
                let (travel, moves) = plan_path(em, ctx, paths, &r, start, reversed, route);
                Some(Unit { path: Some(PathUnit { index, start, reversed, stage }), travel, moves })
            };
        loop {
            match &mut self.phase {
                Phase::Idle | Phase::Closed => return None,
                Phase::Skirt { from } => {
                    if let Some(i) = (*from..n).find(|&i| paths.rec(i).kind == PathKind::Skirt) {
                        *from = i + 1;
                        let (start, rev, _) = entry(paths, &paths.rec(i), seam, em.pos);
                        return plan(paths, i, start, rev, 0);
                    }
                    // Rear seams: every perimeter loop starts at its rear-most vertex.
                    if seam == Seam::Rear {
                        for i in 0..n {
                            let r = paths.rec(i);
                            if r.closed && !r.done && matches!(r.kind, PathKind::Perimeter(_)) {
                                let k = rear(paths.points(&r));
                                paths.rotate_loop(i, k);
                            }
                        }
                    }
                    paths.sort_by_island();
                    let finder = Finder::new(paths, seam, grid_head, grid_next);
                    (self.grid, self.loose) =
                        (finder.grid.as_ref().map(NearGrid::shape), finder.loose);
                    self.phase = Phase::Islands(None);
                }
                Phase::Islands(None) => {
                    // Next island: the nearest path among each island's first stage.
                    let stages = &*island_stage;
                    let first_stage =
                        |r: &PathRec| stages.get(r.island as usize).copied() == Some(stage(r, cfg));
                    let everything = Scope { range: 0..n, window: None };
                    let finder = Finder::resume(self.grid, self.loose, grid_head, grid_next);
                    let Some((_, first, _, _)) =
                        finder.find(paths, seam, em.pos, &everything, &first_stage)
                    else {
                        self.phase = Phase::Closing;
                        continue;
                    };
                    let island = paths.rec(first).island;
                    let range = paths.partition_point(|r| r.island < island)
                        ..paths.partition_point(|r| r.island <= island);
                    let scope = if range.len() > SCAN_MAX {
                        Finder::scope(paths, seam, range.clone())
                    } else {
                        Scope { range: range.clone(), window: None }
                    };
                    self.phase =
                        Phase::Islands(Some(IslandCursor { island, range, scope, chain: None }));
                }
                Phase::Islands(Some(c)) => {
                    // Stages of this island in order, nearest first within each; after a
                    // perimeter loop, the nearest loop of the next perimeter stage if any.
                    let Some(&min_stage) = island_stage.get(c.island as usize) else {
                        self.phase = Phase::Islands(None);
                        continue;
                    };
                    let in_stage = |st: u8| move |r: &PathRec| stage(r, cfg) == st;
                    let finder = Finder::resume(self.grid, self.loose, grid_head, grid_next);
                    let mut st = min_stage;
                    let mut pick = None;
                    if let Some(ch) = c.chain {
                        pick = finder.find(paths, seam, em.pos, &c.scope, &in_stage(ch));
                        if pick.is_some() {
                            st = ch;
                        }
                    }
                    if pick.is_none() {
                        pick = finder.find(paths, seam, em.pos, &c.scope, &in_stage(min_stage));
                    }
                    if let Some((_, i, start, rev)) = pick {
                        return plan(paths, i, start, rev, st);
                    }
                    c.chain = None;
                    // Stage done: the next one present in this island.
                    let next = c
                        .range
                        .clone()
                        .map(|i| paths.rec(i))
                        .filter(|r| !r.done)
                        .map(|r| stage(&r, cfg))
                        .min();
                    match (next, island_stage.get_mut(c.island as usize)) {
                        (Some(s), Some(slot)) => *slot = s,
                        _ => self.phase = Phase::Islands(None),
                    }
                }
                Phase::Closing => {
                    // A layer without extrusion still moves to its height.
                    self.phase = Phase::Closed;
                    let travel = em.plan_travel(ctx, em.pos, &|_, _, _| false, route);
                    return Some(Unit { path: None, travel, moves: travel.moves });
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::machine::{MachineConfig, PrintSettings};
    use core::cell::Cell;

    /// A travel across a wall follows the comb route found for it, whether its waypoints
    /// were kept by the plan (routed once) or not (routed again when travelled).
    #[test]
    fn a_combed_travel_follows_its_route_kept_or_found_again() {
        let cfg = ToolpathConfig::new(&MachineConfig::default(), &PrintSettings::default());
        assert!(cfg.comb && cfg.min_retract_travel_um < 20_000);
        // A wall the straight travel from the origin to (20, 0) mm crosses.
        let points = [
            Point2::new(10_000, -1_000),
            Point2::new(11_000, -1_000),
            Point2::new(11_000, 1_000),
            Point2::new(10_000, 1_000),
        ];
        let wall = Ring {
            start: 0,
            len: 4,
            area2: 4_000_000,
            min: points[0],
            max: points[2],
            island: 0,
            depth: 0,
            parent: Ring::NO_PARENT,
        };
        let ctx =
            Ctx { cfg: &cfg, points: &points, rings: &[wall], height_um: 200, first_layer: false };
        let to = Point2::new(20_000, 0);
        for n in [3, ROUTE_POINTS, ROUTE_POINTS + 1, 2 * ROUTE_POINTS] {
            // Up 5 mm, along above the wall in `n - 2` steps, down to `to`.
            let route: Vec<Point2> = (0..n - 1)
                .map(|i| Point2::new((20_000 * i / (n - 2)) as i32, 5_000))
                .chain([to])
                .collect();
            let calls = Cell::new(0);
            let comb = |_: Point2, _: Point2, visit: &mut dyn FnMut(Point2)| {
                calls.set(calls.get() + 1);
                route.iter().for_each(|&w| visit(w));
                true
            };
            let mut em = Emitter::new();
            let mut moves = Vec::new();
            em.travel_to(&ctx, to, &comb, &mut |e: &ToolEvent<'_>| {
                if let ToolEvent::Move(m) = e {
                    moves.push(*m);
                }
            });
            let ends: Vec<Point2> = moves.iter().map(|m| m.to).collect();
            assert_eq!(ends, route, "{n} waypoints");
            assert!(moves.iter().all(|m| m.feature == Feature::Travel && m.e_um == 0));
            assert_eq!((em.pos, em.retracted), (to, false));
            assert_eq!(calls.get(), if n <= ROUTE_POINTS { 1 } else { 2 }, "{n} waypoints");
        }
    }
}
