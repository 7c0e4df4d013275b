//! Ordering, travel, retraction and extrusion amounts: one layer's paths become moves.
//!
//! Islands are visited nearest first. Within an island the perimeters go inner to outer (the
//! external perimeter last, by default) and then the infill runs, each stage nearest first
//! from where the nozzle is; loops start at their seam (the rear-most vertex, or the nearest
//! one), open runs at whichever end is closer. A travel that crosses no contour of the layer
//! stays inside the part (combing) and needs no retraction; one that crosses a contour and is
//! at least `min_retract_travel_um` long retracts first and primes again before the next
//! extrusion.
//!
//! Extrusion: `E = width x height x length / filament area`, accumulated as an exact volume
//! (um^3 x 16) and converted to a rounded absolute filament position, so per-move rounding
//! never drifts. The filament area uses pi = 355/113 (relative error 8.5e-8).

use crate::geom::Point2;
use crate::machine::Rate;

use super::paths::{PathBuf, PathKind, PathRec};
use super::poly::{dist, dist2, isqrt, segments_touch, Ring};
use super::{Feature, LayerStats, Seam, ToolEvent, ToolMove, ToolpathConfig};

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
        let (lo, hi) =
            (Point2::new(a.x.min(b.x), a.y.min(b.y)), Point2::new(a.x.max(b.x), a.y.max(b.y)));
        for r in self.rings {
            if r.max.x < lo.x || r.min.x > hi.x || r.max.y < lo.y || r.min.y > hi.y {
                continue;
            }
            let pts = self.points.get(r.start as usize..(r.start + r.len) as usize).unwrap_or(&[]);
            let Some(&last) = pts.last() else { continue };
            let mut p = last;
            for &q in pts {
                if !(p.x.max(q.x) < lo.x
                    || p.x.min(q.x) > hi.x
                    || p.y.max(q.y) < lo.y
                    || p.y.min(q.y) > hi.y)
                    && segments_touch(a, b, p, q)
                {
                    return true;
                }
                p = q;
            }
        }
        false
    }
}

impl Emitter {
    fn send(&mut self, sink: &mut impl FnMut(&ToolEvent<'_>), m: ToolMove) {
        sink(&ToolEvent::Move(m));
    }

    /// Travels to `to`, retracting first when the travel leaves the part.
    pub fn travel_to(&mut self, ctx: &Ctx<'_>, to: Point2, sink: &mut impl FnMut(&ToolEvent<'_>)) {
        if to == self.pos && self.pending_z.is_none() {
            return;
        }
        let d = dist(self.pos, to);
        let leaves = d > 0 && (!ctx.cfg.comb || ctx.crosses_contour(self.pos, to));
        let retract = leaves
            && d >= i64::from(ctx.cfg.min_retract_travel_um)
            && ctx.cfg.retract_length_um > 0;
        if retract && !self.retracted {
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
        if to != self.pos {
            self.layer.travel_moves += 1;
            self.layer.travel_um += d as u64;
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
        self.extruding = false;
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
        let len16 = isqrt((dist2(self.pos, to) * 256) as u64) as i64;
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
fn rear(pts: &[Point2]) -> usize {
    let mut best = 0;
    for (i, p) in pts.iter().enumerate() {
        let b = pts[best];
        if p.y > b.y || (p.y == b.y && p.x < b.x) {
            best = i;
        }
    }
    best
}

fn nearest(pts: &[Point2], from: Point2) -> usize {
    let mut best = 0;
    let mut bd = i64::MAX;
    for (i, &p) in pts.iter().enumerate() {
        let d = dist2(from, p);
        if d < bd {
            bd = d;
            best = i;
        }
    }
    best
}

/// Where path `r` would start from `from`: (point index, reversed, squared distance).
fn entry<const N: usize, const R: usize>(
    paths: &PathBuf<N, R>,
    r: &PathRec,
    seam: Seam,
    from: Point2,
) -> (usize, bool, i64) {
    let pts = paths.points(r);
    if r.closed {
        let i = match (seam, r.kind) {
            (Seam::Rear, PathKind::Perimeter(_)) => rear(pts),
            _ => nearest(pts, from),
        };
        return (i, false, dist2(from, pts[i]));
    }
    let (d0, d1) = (dist2(from, pts[0]), dist2(from, pts[pts.len() - 1]));
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

fn print_path<const N: usize, const R: usize>(
    em: &mut Emitter,
    ctx: &Ctx<'_>,
    paths: &PathBuf<N, R>,
    r: &PathRec,
    start: usize,
    reversed: bool,
    sink: &mut impl FnMut(&ToolEvent<'_>),
) {
    let pts = paths.points(r);
    let feat = paths.features(r);
    let n = pts.len();
    em.travel_to(ctx, pts[start], sink);
    if r.closed {
        for k in 1..=n {
            let i = (start + k) % n;
            em.extrude_to(ctx, pts[i], feat[i], sink);
        }
    } else if reversed {
        for i in (0..n - 1).rev() {
            em.extrude_to(ctx, pts[i], feat[i + 1], sink);
        }
    } else {
        for i in 1..n {
            em.extrude_to(ctx, pts[i], feat[i], sink);
        }
    }
}

/// Emits every path of the layer in order. `island_stage` is scratch (one entry per island).
pub fn emit_layer<const N: usize, const R: usize>(
    em: &mut Emitter,
    ctx: &Ctx<'_>,
    paths: &mut PathBuf<N, R>,
    island_stage: &mut [u8],
    sink: &mut impl FnMut(&ToolEvent<'_>),
) {
    let cfg = ctx.cfg;
    for s in island_stage.iter_mut() {
        *s = u8::MAX;
    }
    for r in paths.recs() {
        if let Some(s) = island_stage.get_mut(r.island as usize) {
            *s = (*s).min(stage(r, cfg));
        }
    }
    // The skirt first.
    let n = paths.recs().len();
    for i in 0..n {
        let r = paths.recs()[i];
        if r.kind == PathKind::Skirt {
            let (start, rev, _) = entry(paths, &r, cfg.seam, em.pos);
            print_path(em, ctx, paths, &r, start, rev, sink);
            paths.set_done(i);
        }
    }
    loop {
        // Next island: the nearest path among each island's first stage.
        let mut best: Option<(i64, usize)> = None;
        for i in 0..n {
            let r = paths.recs()[i];
            if r.done || island_stage.get(r.island as usize).copied() != Some(stage(&r, cfg)) {
                continue;
            }
            let (_, _, d) = entry(paths, &r, cfg.seam, em.pos);
            if best.map_or(true, |b| d < b.0) {
                best = Some((d, i));
            }
        }
        let Some((_, first)) = best else { break };
        let island = paths.recs()[first].island;
        // Stages of this island in order, nearest first within each.
        while let Some(&st) = island_stage.get(island as usize) {
            let mut pick: Option<(i64, usize, usize, bool)> = None;
            for i in 0..n {
                let r = paths.recs()[i];
                if r.done || r.island != island || stage(&r, cfg) != st {
                    continue;
                }
                let (start, rev, d) = entry(paths, &r, cfg.seam, em.pos);
                if pick.map_or(true, |p| d < p.0) {
                    pick = Some((d, i, start, rev));
                }
            }
            match pick {
                Some((_, i, start, rev)) => {
                    let r = paths.recs()[i];
                    print_path(em, ctx, paths, &r, start, rev, sink);
                    paths.set_done(i);
                }
                None => {
                    // Stage done: the next one present in this island.
                    let next = paths
                        .recs()
                        .iter()
                        .filter(|r| !r.done && r.island == island)
                        .map(|r| stage(r, cfg))
                        .min();
                    match (next, island_stage.get_mut(island as usize)) {
                        (Some(s), Some(slot)) => *slot = s,
                        _ => break,
                    }
                }
            }
        }
    }
}
