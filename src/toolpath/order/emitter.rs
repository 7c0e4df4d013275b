//! Extrusion bookkeeping: the nozzle's moves, their filament and the retractions.
//!
//! `E = width x height x length / filament area` is accumulated as an exact volume
//! (um^3 x 16) and converted to a rounded absolute filament position, so per-move rounding
//! never drifts (the filament area uses pi = 355/113, relative error 8.5e-8). Travels that
//! leave the part retract first and prime again before the next extrusion.

use crate::geom::Point2;
use crate::machine::Rate;

use super::super::poly::{dist, dist2, segment_touches_rings, Ring};
use super::super::{Feature, LayerStats, ToolEvent, ToolMove, ToolpathConfig};
use super::comb::*;

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
    /// The part-cooling fan's duty, 0..=255 ([`ToolMove::fan`]).
    fan: u8,
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
            fan: 0,
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
    /// Extrusion feeds scaled by this for the layer's minimum time, q16 (`FEED_SCALE_ONE`:
    /// full speed).
    pub feed_scale_q16: u32,
    /// The wait at the layer's end for the rest of its minimum time, ms (0: none).
    pub cool_wait_ms: u32,
    /// The layer's fan duty, and its bridges' and overhang perimeters' (0..=255).
    pub fan: [u8; 2],
}

/// [`Ctx::feed_scale_q16`] at full speed.
pub const FEED_SCALE_ONE: u32 = 1 << 16;

impl Ctx<'_> {
    /// The feed of a move of `f` in this layer (scaled for its minimum time).
    pub(crate) fn feed(&self, f: Feature) -> Rate {
        let full = self.full_feed(f);
        match f {
            Feature::Travel | Feature::Retract | Feature::Unretract | Feature::Dwell => full,
            _ if self.feed_scale_q16 >= FEED_SCALE_ONE => full,
            // Slower for the layer's minimum time, not below the slowest print feed.
            _ => {
                let scaled = Rate::from_bits(
                    ((u128::from(full.to_bits()) * u128::from(self.feed_scale_q16)) >> 16) as u64,
                );
                scaled.max(self.cfg.min_print_speed_mm_s).min(full)
            }
        }
    }

    /// The feed of a move of `f` at full speed.
    pub(crate) fn full_feed(&self, f: Feature) -> Rate {
        let c = self.cfg;
        match f {
            Feature::Travel | Feature::Dwell => c.travel_speed_mm_s,
            Feature::Retract | Feature::Unretract => c.retract_speed_mm_s,
            _ if self.first_layer => c.first_layer_speed_mm_s,
            Feature::ExternalPerimeter | Feature::Perimeter | Feature::Skirt | Feature::Brim => {
                c.perimeter_speed_mm_s
            }
            Feature::InternalInfill | Feature::SolidInfill | Feature::TopSolidInfill => {
                c.infill_speed_mm_s
            }
            Feature::BridgeInfill | Feature::OverhangPerimeter => {
                Rate::from_num(super::super::BRIDGE_SPEED_MM_S)
            }
        }
    }

    /// Does the segment touch any contour edge of the layer?
    pub(super) fn crosses_contour(&self, a: Point2, b: Point2) -> bool {
        segment_touches_rings(self.points, self.rings, a, b)
    }
}

/// A travel planned by [`Emitter::plan_travel`].
#[derive(Debug, Clone, Copy)]
pub(super) struct Travel {
    /// Retract first (unless already retracted).
    pub(super) retract: bool,
    /// Follow the comb route.
    pub(super) routed: bool,
    /// Moves it emits: retraction, height change and the legs that move.
    pub(super) moves: u32,
}

impl Emitter {
    pub(super) fn send(&mut self, sink: &mut impl FnMut(&ToolEvent<'_>), m: ToolMove) {
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
    pub(super) fn plan_travel(
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
    pub(super) fn travel(
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
            self.retract(ctx, sink);
        }
        if let Some(z) = self.pending_z.take() {
            self.move_z(ctx, z, sink);
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

    /// A Z-only travel to `z` where the nozzle is.
    fn move_z(&mut self, ctx: &Ctx<'_>, z: i32, sink: &mut impl FnMut(&ToolEvent<'_>)) {
        self.z = z;
        self.layer.travel_moves += 1;
        // A layer's fan goes on with its height.
        self.fan = ctx.fan[0];
        let m = ToolMove {
            to: self.pos,
            z_um: z,
            e_um: 0,
            feed_mm_s: ctx.feed(Feature::Travel),
            feature: Feature::Travel,
            fan: self.fan,
        };
        self.send(sink, m);
    }

    /// Pulls the filament back where the nozzle is.
    fn retract(&mut self, ctx: &Ctx<'_>, sink: &mut impl FnMut(&ToolEvent<'_>)) {
        self.retracted = true;
        self.layer.retractions += 1;
        let m = ToolMove {
            to: self.pos,
            z_um: self.z,
            e_um: -ctx.cfg.retract_length_um,
            feed_mm_s: ctx.feed(Feature::Retract),
            feature: Feature::Retract,
            fan: self.fan,
        };
        self.send(sink, m);
    }

    pub(super) fn travel_leg(
        &mut self,
        ctx: &Ctx<'_>,
        to: Point2,
        sink: &mut impl FnMut(&ToolEvent<'_>),
    ) {
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
            fan: self.fan,
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
                fan: self.fan,
            };
            self.send(sink, m);
        }
        if !self.extruding {
            self.layer.stops += 1;
            self.extruding = true;
        }
        let len16 = crate::math::isqrt_u64((dist2(self.pos, to) * 256) as u64) as i64;
        let w = i64::from(ctx.cfg.line_width_um);
        self.vol16 += if feature == Feature::BridgeInfill {
            // A round thread one line wide (it hangs below the layer): pi w^2 / 4, pi = 355/113.
            355 * w * w * len16 / (4 * 113)
        } else {
            w * i64::from(ctx.height_um) * len16
        };
        let e_abs = filament_um(self.vol16, ctx.cfg.filament_diameter_um);
        let e = (e_abs - self.e_abs) as i32;
        self.e_abs = e_abs;
        self.layer.extrusion_moves += 1;
        self.layer.filament_um += i64::from(e);
        self.pos = to;
        let bridge = matches!(feature, Feature::BridgeInfill | Feature::OverhangPerimeter);
        self.fan = ctx.fan[usize::from(bridge)];
        let m = ToolMove {
            to,
            z_um: self.z,
            e_um: e,
            feed_mm_s: ctx.feed(feature),
            feature,
            fan: self.fan,
        };
        self.send(sink, m);
    }

    /// Waits out the rest of the layer's minimum time ([`Ctx::cool_wait_ms`]) off the part:
    /// retracts, lifts the nozzle by [`ToolpathConfig::cool_lift_um`] (below the build
    /// volume's top) and dwells; the next layer's height change brings it back down.
    pub(super) fn cool(&mut self, ctx: &Ctx<'_>, sink: &mut impl FnMut(&ToolEvent<'_>)) {
        if !self.retracted && ctx.cfg.retract_length_um > 0 {
            self.retract(ctx, sink);
        }
        let lifted = self.lifted_z(ctx);
        if lifted != self.z {
            self.move_z(ctx, lifted, sink);
        }
        // ms to s 2^32.
        let seconds = Rate::from_bits((u64::from(ctx.cool_wait_ms) << 32) / 1_000);
        let m = ToolMove {
            to: self.pos,
            z_um: self.z,
            e_um: 0,
            feed_mm_s: seconds,
            feature: Feature::Dwell,
            fan: self.fan,
        };
        self.send(sink, m);
        self.extruding = false;
    }

    /// The moves [`cool`](Self::cool) emits from here.
    pub(super) fn cool_moves(&self, ctx: &Ctx<'_>) -> u32 {
        let retracts = !self.retracted && ctx.cfg.retract_length_um > 0;
        1 + u32::from(retracts) + u32::from(self.lifted_z(ctx) != self.z)
    }

    /// The nozzle's height while the layer cools: lifted, never above the build volume nor
    /// below where it is.
    fn lifted_z(&self, ctx: &Ctx<'_>) -> i32 {
        self.z.saturating_add(i32::from(ctx.cfg.cool_lift_um)).min(ctx.cfg.max_z_um).max(self.z)
    }

    /// Total filament extruded so far, um.
    pub fn filament_total_um(&self) -> i64 {
        self.e_abs
    }
}
