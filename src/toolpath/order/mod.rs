//! Ordering: one layer's paths become units of moves, in the order they print.
//!
//! The first layer's skirt loops go first, in the order they were made, then its brim loops,
//! each the nearest one left (from the outermost inwards, one brim after the other when the
//! islands' brims are apart).
//!
//! Islands are visited nearest first. Within an island the perimeters go inner to outer (the
//! external perimeter last, by default) and then the infill runs, each stage nearest first
//! from where the nozzle is; loops start at their seam (the rear-most vertex, or the nearest
//! one), open runs at whichever end is closer. The nearest path is looked up in a
//! [`NearGrid`] of every path's entry points (rear seams are rotated to the front of their
//! loop first) and, once an island is chosen, only within the box of its paths' entries (the
//! path records are grouped by island first, keeping their order), so a layer of `n` paths
//! costs about `n` grid lookups instead of `n^2` distance checks (islands of at most
//! [`SCAN_MAX`] paths are simply scanned); loops whose entry depends on the nozzle
//! (nearest-vertex seams) are scanned beside it, and a layer whose paths do not fit the grid's
//! buffers is scanned whole. The choice is the scan's in every case (lowest index among
//! equally near paths).
//!
//! The travels between paths ([`comb`]: a travel that crosses no contour stays inside the
//! part, one that would goes around it when a short route exists) and the extrusion amounts
//! and retractions ([`emitter`]) are their own modules.

use core::ops::Range;

use crate::geom::Point2;
use crate::slot::Slot;

pub mod comb;
pub mod emitter;

pub use comb::CombFn;
use comb::*;
use emitter::*;
pub use emitter::{filament_um, Ctx, Emitter, FEED_SCALE_ONE};

use super::near::{GridShape, NearGrid};
use super::paths;
use super::paths::{PathBuf, PathKind, PathPoints, PathRec};
use super::poly::dist2;
use super::{Room, Seam, ToolEvent, ToolpathConfig};

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

/// The brim loop not yet printed whose nearest vertex is nearest to `from` (lowest index
/// among equals): (index, start point, reversed).
fn nearest_brim<const N: usize>(
    paths: &PathBuf<N>,
    seam: Seam,
    from: Point2,
) -> Option<(usize, usize, bool)> {
    let mut best: Option<(i64, usize, usize, bool)> = None;
    for i in 0..paths.len() {
        let r = paths.rec(i);
        if r.kind == PathKind::Brim && !r.done {
            let (start, rev, d) = entry(paths, &r, seam, from);
            if best.map_or(true, |b| d < b.0) {
                best = Some((d, i, start, rev));
            }
        }
    }
    best.map(|(_, i, start, rev)| (i, start, rev))
}

/// Stage of a path within its island: lower first.
fn stage(r: &PathRec, cfg: &ToolpathConfig) -> u8 {
    match r.kind {
        PathKind::Skirt | PathKind::Brim => 0,
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
        None if unit.cool => em.cool(ctx, sink),
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
pub const SCAN_MAX: usize = 16;

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
    /// The path, or `None` for the cooling wait or the closing move.
    path: Option<PathUnit>,
    /// The cooling wait ([`Emitter::cool`]; no path).
    cool: bool,
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
    /// The skirt loops, in path order, from path `from` on; then the brim loops, nearest
    /// first.
    Skirt { from: usize },
    /// The islands, nearest first (`None`: between two islands).
    Islands(Option<IslandCursor>),
    /// The wait for the rest of the layer's minimum time is next.
    Cooling,
    /// The closing move is next.
    Closing,
    /// Every unit was emitted.
    Closed,
}

/// The emission of one layer's paths, resumable between units.
///
/// The skirt first (in order), then the brim (nearest loop first), then the islands nearest
/// first, in each the stages in order and the nearest path first (see the
/// [module docs](self)), then the wait for the rest of the layer's
/// minimum time if it has one ([`Ctx::cool_wait_ms`]), then a move to the layer's height if none
/// went there. Each [`emit`](Self::emit) call emits whole units while the room it was given takes them
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
                let path = Some(PathUnit { index, start, reversed, stage });
                Some(Unit { path, cool: false, travel, moves })
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
                    // The brim loops (first layer only), each from its vertex nearest the
                    // nozzle: a scan of the layer's paths per loop.
                    if ctx.first_layer && cfg.brim_width_um > 0 {
                        if let Some((i, start, rev)) = nearest_brim(paths, seam, em.pos) {
                            return plan(paths, i, start, rev, 0);
                        }
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
                        self.phase = Phase::Cooling;
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
                Phase::Cooling => {
                    self.phase = Phase::Closing;
                    if ctx.cool_wait_ms > 0 {
                        let travel = Travel { retract: false, routed: false, moves: 0 };
                        let moves = em.cool_moves(ctx);
                        return Some(Unit { path: None, cool: true, travel, moves });
                    }
                }
                Phase::Closing => {
                    // A layer without extrusion still moves to its height.
                    self.phase = Phase::Closed;
                    let travel = em.plan_travel(ctx, em.pos, &|_, _, _| false, route);
                    return Some(Unit { path: None, cool: false, travel, moves: travel.moves });
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::machine::{MachineConfig, PrintSettings};
    use crate::toolpath::poly::Ring;
    use crate::toolpath::Feature;
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
        let ctx = Ctx {
            cfg: &cfg,
            points: &points,
            rings: &[wall],
            height_um: 200,
            first_layer: false,
            feed_scale_q16: FEED_SCALE_ONE,
            cool_wait_ms: 0,
            fan: [0; 2],
        };
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
