//! Lookahead motion planner: [`Move`]s in, trapezoidal [`Block`]s out.
//!
//! # Model
//! A move goes in a straight line from the previous target to its own target (X, Y, Z, E in
//! um). Its path length is the XYZ distance (the E distance for an extruder-only move); E is a
//! coordinated axis that follows the path in proportion. Each move gets
//! - a cruise limit: the feed rate, lowered so that no axis exceeds its maximum feed rate
//!   along the move's direction (`v |d_i| / L <= vmax_i`);
//! - an acceleration: print or travel acceleration by [`MoveKind`], lowered so that no axis
//!   exceeds its maximum acceleration along the direction (`a |d_i| / L <= amax_i`);
//! - a start-speed limit at the junction with the previous move: junction
//!   deviation from the square-corner velocity (Klipper's formulation, so a 90 degree corner
//!   passes at exactly the square-corner velocity), the cap that keeps the approximating arc
//!   inside the shorter half of each move, the extruder's allowed velocity jump (1 mm/s by
//!   default) and both moves' cruise limits. Extruder-only moves start and end at rest.
//!
//! # Lookahead
//! The queue holds up to `N` moves (const generic). Speeds are tracked squared (`v^2`, so
//! `v_end^2 = v_start^2 + 2 a L` is linear). The end of the queue is always assumed to stop.
//! Pushing a move runs the backward pass from the new tail only until a move's reachable start
//! speed comes out unchanged (nothing before it can change either), then the forward pass over
//! just the changed range. The head's start speed is fixed (the previous block ended there).
//! The head leaves the queue with [`Planner::pop`] once its exit speed can no longer rise (it
//! already equals the junction limit or the speed reachable by accelerating through it: more
//! moves behind it can only relax the stop at the end of the queue), or with
//! [`Planner::pop_forced`] at any time (end of input, a full queue, a hungry step generator):
//! its profile then still ends at a speed the queued moves can stop from. A queue that is too
//! short therefore only slows motion down; it never breaks a limit.
//!
//! # Profile and time
//! A [`Block`] is a trapezoid (accelerate, cruise, decelerate; a short move may never reach
//! cruise). Its exact duration, in timer ticks with 16 fraction bits, is the sum of the three
//! phase times, and [`Block::time_at_q16`] gives the time at any distance along the move. The
//! step generator evaluates the same trapezoid for every step ([`Block::step_time_q16`]: no
//! division; within about `v_peak 2^-30 / a` of it) and starts each block at the exact sum of the durations
//! before it, so the planner's print-time estimate is the executed motion's duration.
//!
//! # Units (all integer, no floating point)
//! lengths um q32 (`u64`), speeds um/s q16, speeds squared um^2/s^2 q16, accelerations
//! um/s^2 q16, times timer ticks q16, directions q62. Square roots are exact
//! ([`crate::math::isqrt_u128`]). Rates given as [`Rate`] (mm/s, mm/s^2) are clamped to 10 m/s and
//! 1000 m/s^2, and moves to 2^24 um (16.7 m) per axis, so that no intermediate overflows.

use core::fmt;

use fixed::types::U32F32;

use crate::machine::{MachineConfig, Rate, AXES};

mod junction;

use crate::math::{self, div_i128_pos, div_sat_u64, isqrt_u128, sat_u64, Divisor};

/// Largest per-axis distance of one move, in um (2^24 um = 16.7 m).
pub const MAX_AXIS_DELTA_UM: i64 = 1 << 24;

/// Cap of every speed-squared value (um^2/s^2 q16); sums of two never overflow `u64`.
const V2_MAX: u64 = 1 << 62;
/// 10 m/s in um/s q16.
const MAX_SPEED_Q16: u64 = 10_000_000 << 16;
/// 1000 m/s^2 in um/s^2 q16.
const MAX_ACCEL_Q16: u64 = 1_000_000_000 << 16;
/// sqrt(2) - 1 in q62.
const SQRT2_M1_Q62: u128 = 1_910_222_894_239_003_202;

/// What a move does; chooses its acceleration.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum MoveKind {
    /// Extruding move: print acceleration.
    Print,
    /// Non-extruding move: travel acceleration.
    Travel,
    /// Retraction or unretraction (usually extruder only): travel acceleration.
    Retract,
    /// The head waits where it is, at rest, for the move's duration (G-code's `G4`): see
    /// [`Move::dwell`].
    Dwell,
}

/// One straight move to an absolute target.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Move {
    /// Target X, Y, Z, E in um.
    pub target_um: [i32; AXES],
    /// Requested speed along the path (XYZ, or E for an extruder-only move), mm/s; for a
    /// [`MoveKind::Dwell`], the wait in seconds.
    pub feed_mm_s: Rate,
    /// Print, travel or retract.
    pub kind: MoveKind,
}

#[cfg(feature = "defmt")]
impl defmt::Format for Move {
    fn format(&self, f: defmt::Formatter<'_>) {
        defmt::write!(
            f,
            "Move {{ target_um: {}, feed_mm_s: {=u64} / 2^32, kind: {} }}",
            self.target_um,
            self.feed_mm_s.to_bits(),
            self.kind
        )
    }
}

impl Move {
    /// A move to `target_um` at `feed_mm_s`.
    pub const fn new(target_um: [i32; AXES], feed_mm_s: Rate, kind: MoveKind) -> Self {
        Self { target_um, feed_mm_s, kind }
    }

    /// A wait of `seconds` at `at_um` (where the previous move ended).
    pub const fn dwell(at_um: [i32; AXES], seconds: Rate) -> Self {
        Self { target_um: at_um, feed_mm_s: seconds, kind: MoveKind::Dwell }
    }
}

/// Limits and timing for the planner.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub struct PlanConfig {
    /// Timer frequency the times are expressed in, Hz (72 MHz on the board).
    pub timer_hz: u32,
    /// Maximum feed rate per axis X, Y, Z, E in mm/s.
    pub max_feed_mm_s: [Rate; AXES],
    /// Maximum acceleration per axis X, Y, Z, E in mm/s^2.
    pub max_accel_mm_s2: [Rate; AXES],
    /// Acceleration of print moves, mm/s^2.
    pub print_accel_mm_s2: Rate,
    /// Acceleration of travel and retract moves, mm/s^2.
    pub travel_accel_mm_s2: Rate,
    /// Square-corner velocity (speed through a 90 degree corner), mm/s.
    pub square_corner_velocity_mm_s: Rate,
    /// Largest jump of the extruder's velocity at a junction, mm/s (Klipper's
    /// `instantaneous_corner_velocity`).
    pub extruder_corner_velocity_mm_s: Rate,
}

impl PlanConfig {
    /// No configuration: every field zero, a placeholder until
    /// [`from_machine`](Self::from_machine)'s value replaces it.
    pub const EMPTY: Self = Self {
        timer_hz: 0,
        max_feed_mm_s: [Rate::ZERO; AXES],
        max_accel_mm_s2: [Rate::ZERO; AXES],
        print_accel_mm_s2: Rate::ZERO,
        travel_accel_mm_s2: Rate::ZERO,
        square_corner_velocity_mm_s: Rate::ZERO,
        extruder_corner_velocity_mm_s: Rate::ZERO,
    };

    /// The planner limits of `machine`, a 72 MHz timer and a 1 mm/s extruder corner velocity.
    pub const fn from_machine(machine: &MachineConfig) -> Self {
        Self {
            timer_hz: 72_000_000,
            max_feed_mm_s: machine.max_feed_mm_s,
            max_accel_mm_s2: machine.max_accel_mm_s2,
            print_accel_mm_s2: machine.print_accel_mm_s2,
            travel_accel_mm_s2: machine.travel_accel_mm_s2,
            square_corner_velocity_mm_s: machine.square_corner_velocity_mm_s,
            extruder_corner_velocity_mm_s: Rate::ONE,
        }
    }
}

impl Default for PlanConfig {
    /// The stock Ender-3 ([`MachineConfig::default`]).
    fn default() -> Self {
        Self::from_machine(&MachineConfig::default())
    }
}

/// Why a move was not queued.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum PlanError {
    /// The lookahead queue is full: pop a block first.
    QueueFull,
    /// The feed rate is zero.
    ZeroFeed,
    /// One axis moves more than [`MAX_AXIS_DELTA_UM`].
    MoveTooLong {
        /// The axis (0 = X .. 3 = E).
        axis: u8,
    },
}

impl fmt::Display for PlanError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Self::QueueFull => write!(f, "planner queue is full"),
            Self::ZeroFeed => write!(f, "move has a feed rate of zero"),
            Self::MoveTooLong { axis } => {
                write!(f, "move on axis {axis} is longer than {MAX_AXIS_DELTA_UM} um")
            }
        }
    }
}

/// mm/s (or mm/s^2) as `Rate` to um/s q16, clamped to `max`.
fn rate_to_q16(r: Rate, max: u64) -> u64 {
    sat_u64((r.to_bits() as u128 * 1000) >> 16).min(max)
}

/// um/s q16 (or um/s^2) back to mm/s as `Rate` (saturating).
fn q16_to_rate(v: u64) -> Rate {
    Rate::from_bits(sat_u64(((v as u128) << 16) / 1000))
}

/// Speed q16 squared to v^2 q16.
fn square_q16(v: u64) -> u64 {
    sat_u64((v as u128 * v as u128) >> 16).min(V2_MAX)
}

/// Speed q16 from v^2 q16.
fn sqrt_q16(v2: u64) -> u64 {
    isqrt_u128((v2 as u128) << 16) as u64
}

/// The configuration in internal units.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Limits {
    vmax2_q16: [u64; AXES],
    amax_q16: [u64; AXES],
    print_accel_q16: u64,
    travel_accel_q16: u64,
    /// scv^2 (sqrt2 - 1), um^2/s^2 q16.
    scv2_jd_q16: u64,
    ecv_q16: u64,
    timer_hz: u32,
}

impl Limits {
    /// No motion allowed (an unconfigured planner).
    const EMPTY: Self = Self {
        vmax2_q16: [0; AXES],
        amax_q16: [0; AXES],
        print_accel_q16: 0,
        travel_accel_q16: 0,
        scv2_jd_q16: 0,
        ecv_q16: 0,
        timer_hz: 0,
    };

    fn new(c: &PlanConfig) -> Self {
        let scv = rate_to_q16(c.square_corner_velocity_mm_s, MAX_SPEED_Q16);
        Self {
            vmax2_q16: c.max_feed_mm_s.map(|r| square_q16(rate_to_q16(r, MAX_SPEED_Q16))),
            amax_q16: c.max_accel_mm_s2.map(|r| rate_to_q16(r, MAX_ACCEL_Q16)),
            print_accel_q16: rate_to_q16(c.print_accel_mm_s2, MAX_ACCEL_Q16),
            travel_accel_q16: rate_to_q16(c.travel_accel_mm_s2, MAX_ACCEL_Q16),
            scv2_jd_q16: sat_u64((square_q16(scv) as u128 * SQRT2_M1_Q62) >> 62),
            ecv_q16: rate_to_q16(c.extruder_corner_velocity_mm_s, MAX_SPEED_Q16),
            timer_hz: c.timer_hz.max(1),
        }
    }
}

/// Geometry and limits of one move, as the junction with the next move needs them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Geom {
    /// XYZ direction, q62 (zero for an extruder-only move).
    unit: [i64; 3],
    /// Path length, um q32.
    len_q32: u64,
    /// Acceleration along the path, um/s^2 q16.
    accel_q16: u64,
    /// Cruise limit, v^2 q16.
    cruise_v2: u64,
    /// E distance per path distance, q62.
    e_ratio_q62: i128,
}

impl Geom {
    /// Moves X, Y or Z: its direction is not zero (a normalised `unit` has a component of at
    /// least 2^62 / sqrt(3)). Derived rather than stored, so that `Option<Geom>` has no niche
    /// and `None` is zero bytes.
    fn kinematic(&self) -> bool {
        self.unit != [0; 3]
    }
}

/// A queued move and its current plan.
///
/// Its start is the previous entry's end (the head's is the planner's `head_start_um`) and
/// its `2 a L` is recomputed ([`Entry::delta_v2`]): neither is stored per move.
#[derive(Debug, Clone, Copy)]
struct Entry {
    end_um: [i32; AXES],
    /// Path length, um q32: at least 2^32 (1 um) for a move, 0 for a dwell.
    len_q32: u64,
    accel_q16: u64,
    /// Cruise speed squared, um^2/s^2 q16; a dwell's duration, ticks q16 (no field of its
    /// own: 8 bytes more per queued move).
    cruise_v2: u64,
    /// Junction limit of the start speed (includes both cruise limits).
    max_start_v2: u64,
    /// Largest start speed from which the rest of the queue can still stop.
    back_v2: u64,
    /// Planned start speed.
    start_v2: u64,
}

impl Entry {
    const EMPTY: Self = Self {
        end_um: [0; AXES],
        len_q32: 0,
        accel_q16: 0,
        cruise_v2: 0,
        max_start_v2: 0,
        back_v2: 0,
        start_v2: 0,
    };

    /// A wait in place: no length (every move has some).
    fn is_dwell(&self) -> bool {
        self.len_q32 == 0
    }

    /// v^2 gained (or lost) over the whole move at full acceleration: 2 a L, um^2/s^2 q16.
    fn delta_v2(&self) -> u64 {
        sat_u64((2 * self.accel_q16 as u128 * self.len_q32 as u128) >> 32).min(V2_MAX)
    }
}

/// A planned move: trapezoidal speed profile with exact phase times.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Block {
    start_um: [i32; AXES],
    end_um: [i32; AXES],
    len_q32: u64,
    accel_q16: u64,
    /// Start, cruise and end speed squared, um^2/s^2 q16.
    v2: [u64; 3],
    /// Start, cruise and end speed, um/s q16.
    v: [u64; 3],
    /// Distance where acceleration ends and where deceleration starts, um q32.
    accel_end_q32: u64,
    decel_start_q32: u64,
    /// Time where acceleration ends, where deceleration starts, and the whole duration, ticks
    /// q16.
    t_accel_q16: u64,
    t_decel_q16: u64,
    t_total_q16: u64,
    timer_hz: u32,
    /// Start, cruise and end speed, um/s with `8 + fine_shift / 2` fraction bits
    /// (`floor(sqrt(v2 2^fine_shift))`), for the per-step path.
    v_fine: [u64; 3],
    /// Extra fraction bits (doubled) of the per-step speeds: as many as the block's largest
    /// speed squared leaves room for in 62 bits, at most 16 (8 more bits of speed).
    fine_shift: u32,
    /// Ticks q16 per step of `v_fine` at full acceleration: `f 2^(40 - fine_shift / 2) / a_q16`.
    ticks_per_dv: u64,
    /// Ticks q16 per um q32 of cruise, scaled by `2^cruise_shift`.
    ticks_per_um: u64,
    cruise_shift: u32,
}

impl Block {
    /// The block of `e` from `start_um`, ending at `end_v2`.
    ///
    /// `start_v` is `sqrt_q16(e.start_v2)` when the caller already has it (the previous block's
    /// end speed).
    fn new(
        e: &Entry,
        start_um: [i32; AXES],
        end_v2: u64,
        timer_hz: u32,
        start_v: Option<u64>,
    ) -> Self {
        if e.is_dwell() {
            return Self::dwell(start_um, e.cruise_v2, timer_hz);
        }
        let (s2, e2) = (e.start_v2, end_v2);
        let peak = (s2 + e2 + e.delta_v2()) / 2;
        let c2 = e.cruise_v2.min(peak).max(s2).max(e2);
        // Both ramps' distances and the per-step reciprocal divide by a.
        let by_a = Divisor::new(e.accel_q16.max(1));
        let len = e.len_q32;
        // Distances of the ramps: (vc^2 - v^2) 2^32 / 2a = (vc^2 - v^2) 2^31 / a, um q32.
        let ramp = |dv2: u64| by_a.div_sat((dv2 as u128) << 31).min(len);
        let s_acc = ramp(c2 - s2);
        let s_dec = ramp(c2 - e2).min(len - s_acc);
        let s_cruise = len - s_acc - s_dec;
        // Equal speeds squared (no acceleration or no deceleration phase) share their root.
        let v0 = start_v.unwrap_or_else(|| sqrt_q16(s2));
        let v1 = if c2 == s2 { v0 } else { sqrt_q16(c2) };
        let v = [v0, v1, if e2 == c2 { v1 } else { sqrt_q16(e2) }];
        let f = timer_hz as u128;
        // Ramp time 2 s / (v_a + v_b); cruise time s / v; ticks q16.
        let ramp_t = |s: u64, va: u64, vb: u64| {
            if s == 0 {
                0
            } else {
                div_sat_u64(2 * s as u128 * f, (va as u128 + vb as u128).max(1))
            }
        };
        let t_acc = ramp_t(s_acc, v[0], v[1]);
        let by_v1 = Divisor::new(v[1].max(1));
        let t_cruise = if s_cruise == 0 { 0 } else { by_v1.div_sat(s_cruise as u128 * f) };
        let t_dec = ramp_t(s_dec, v[1], v[2]);
        // Per-step reciprocals: one division each per block, none per step.
        // The per-step speeds get 8 more fraction bits when the peak speed is below 33 mm/s
        // (v^2 q16 below 2^46), fewer above: (c2 << fine_shift) < 2^62.
        let half_shift = (c2.leading_zeros().saturating_sub(2) / 2).min(8);
        let fine_shift = 2 * half_shift;
        let ticks_per_dv = by_a.div_sat(f << (40 - half_shift));
        let k = by_v1.div(f << 64);
        let extra = (128 - k.leading_zeros()).saturating_sub(63);
        Self {
            start_um,
            end_um: e.end_um,
            len_q32: len,
            accel_q16: e.accel_q16,
            v2: [s2, c2, e2],
            v,
            accel_end_q32: s_acc,
            decel_start_q32: s_acc + s_cruise,
            t_accel_q16: t_acc,
            t_decel_q16: t_acc.saturating_add(t_cruise),
            t_total_q16: t_acc.saturating_add(t_cruise).saturating_add(t_dec),
            timer_hz,
            // floor(sqrt(v2 2^fine_shift)) = floor(floor(sqrt(v2 2^16)) / 2^(8 - half_shift)).
            v_fine: v.map(|x| x >> (8 - half_shift)),
            fine_shift,
            ticks_per_dv,
            ticks_per_um: (k >> extra) as u64,
            cruise_shift: 64 - extra,
        }
    }

    /// A wait of `ticks_q16` at `at_um`: no length, at rest throughout.
    fn dwell(at_um: [i32; AXES], ticks_q16: u64, timer_hz: u32) -> Self {
        Self {
            start_um: at_um,
            end_um: at_um,
            len_q32: 0,
            accel_q16: 0,
            v2: [0; 3],
            v: [0; 3],
            accel_end_q32: 0,
            decel_start_q32: 0,
            t_accel_q16: 0,
            t_decel_q16: 0,
            t_total_q16: ticks_q16,
            timer_hz,
            v_fine: [0; 3],
            fine_shift: 0,
            ticks_per_dv: 0,
            ticks_per_um: 0,
            cruise_shift: 0,
        }
    }

    /// A wait in place ([`MoveKind::Dwell`]): no length, at rest for its duration.
    pub fn is_dwell(&self) -> bool {
        self.len_q32 == 0
    }

    /// Start position X, Y, Z, E in um.
    pub fn start_um(&self) -> [i32; AXES] {
        self.start_um
    }

    /// End position X, Y, Z, E in um.
    pub fn end_um(&self) -> [i32; AXES] {
        self.end_um
    }

    /// Path length in um, q32.
    pub fn length_um_q32(&self) -> u64 {
        self.len_q32
    }

    /// Acceleration along the path, mm/s^2.
    pub fn accel_mm_s2(&self) -> Rate {
        q16_to_rate(self.accel_q16)
    }

    /// Speed at the start, mm/s.
    pub fn start_speed_mm_s(&self) -> Rate {
        q16_to_rate(self.v[0])
    }

    /// Cruise (peak) speed, mm/s.
    pub fn cruise_speed_mm_s(&self) -> Rate {
        q16_to_rate(self.v[1])
    }

    /// Speed at the end, mm/s.
    pub fn end_speed_mm_s(&self) -> Rate {
        q16_to_rate(self.v[2])
    }

    /// Whether the move ends at rest.
    pub fn ends_at_rest(&self) -> bool {
        self.v2[2] == 0
    }

    /// Duration in timer ticks, q16.
    pub fn duration_ticks_q16(&self) -> u64 {
        self.t_total_q16
    }

    /// Duration in seconds.
    pub fn duration_s(&self) -> U32F32 {
        ticks_q16_to_s(self.t_total_q16, self.timer_hz)
    }

    /// Ticks q16 at which acceleration ends, deceleration starts, and the move ends.
    pub fn phase_ticks_q16(&self) -> [u64; 3] {
        [self.t_accel_q16, self.t_decel_q16, self.t_total_q16]
    }

    /// Distances in um q32 at which acceleration ends and deceleration starts.
    pub fn phase_um_q32(&self) -> [u64; 2] {
        [self.accel_end_q32, self.decel_start_q32]
    }

    /// Time (ticks q16 from the start of the move) at which the path reaches `dist_q32` (um
    /// q32; clamped to the length). Acceleration `t = 2 s / (v0 + sqrt(v0^2 + 2 a s))`, cruise
    /// `t = t_a + (s - s_a) / vc`, deceleration measured back from the end with the mirror
    /// formula: no cancellation near either end of the move.
    pub fn time_at_q16(&self, dist_q32: u64) -> u64 {
        let s = dist_q32.min(self.len_q32);
        let f = self.timer_hz as u128;
        // Time to cover `d` from speed `v` (q16) at full acceleration.
        let ramp = |d: u64, v: u64, v2: u64| -> u64 {
            if d == 0 {
                return 0;
            }
            let w = v2 as u128 + ((2 * self.accel_q16 as u128 * d as u128) >> 32);
            let vd = isqrt_u128(w << 16);
            div_sat_u64(2 * d as u128 * f, (v as u128 + vd).max(1))
        };
        if s <= self.accel_end_q32 {
            ramp(s, self.v[0], self.v2[0]).min(self.t_accel_q16)
        } else if s <= self.decel_start_q32 {
            let d = (s - self.accel_end_q32) as u128 * f;
            let t = div_sat_u64(d, (self.v[1] as u128).max(1));
            self.t_accel_q16.saturating_add(t).min(self.t_decel_q16)
        } else {
            let back = ramp(self.len_q32 - s, self.v[2], self.v2[2]);
            self.t_total_q16.saturating_sub(back).max(self.t_decel_q16)
        }
    }

    /// [`time_at_q16`](Self::time_at_q16) as the step generator computes it for every step:
    /// speed `v = sqrt(v0^2 + 2 a s)` with a 64-bit square root to 2^-16 um/s below 33 mm/s,
    /// to as many bits as 31 hold for faster blocks (2^-14 um/s at 100 mm/s), then
    /// `t = (v - v0) / a` and `t = t_a + (s - s_a) / vc` as multiplications by per-block
    /// reciprocals. No division. It differs from the exact time by at most the speed
    /// resolution over `a`, about `v_peak 2^-30 / a` (93 ns for a 100 mm/s peak at 1 mm/s^2,
    /// 0.2 ns at 500 mm/s^2), never more than `2^-8 um/s / a`, plus a tick q16.
    pub fn step_time_q16(&self, dist_q32: u64) -> u64 {
        let s = dist_q32.min(self.len_q32);
        let accel = s <= self.accel_end_q32;
        if !accel && s <= self.decel_start_q32 {
            let t = math::mul_shr_sat(s - self.accel_end_q32, self.ticks_per_um, self.cruise_shift);
            return self.t_accel_q16.saturating_add(t).min(self.t_decel_q16);
        }
        // Acceleration from the start, or deceleration measured back from the end.
        let (d, phase) = if accel { (s, 0) } else { (self.len_q32 - s, 2) };
        let t = self.ramp_ticks_q16(d, self.v_fine[phase], self.v2[phase]);
        if accel {
            t.min(self.t_accel_q16)
        } else {
            self.t_total_q16.saturating_sub(t).max(self.t_decel_q16)
        }
    }

    /// Time to reach speed^2 `v2 + 2 a d` from speed `v` (`v_fine` units) at full
    /// acceleration, ticks q16, for `d` within the ramp that starts (or ends) at `v2`.
    // Inlined: its one call runs for every ramp step.
    #[inline(always)]
    fn ramp_ticks_q16(&self, d: u64, v_fine: u64, v2: u64) -> u64 {
        // v2 + 2 a d / 2^32 = v2 + a d / 2^31. No saturation or overflow: the ramp's length is
        // at most floor((c2 - v2) 2^32 / 2a), so the sum is at most the cruise speed squared
        // c2, and `c2 << fine_shift` stays below 2^62 (or `fine_shift` is 0).
        let w = v2 + ((self.accel_q16 as u128 * d as u128) >> 31) as u64;
        debug_assert!(w <= self.v2[1] && w <= u64::MAX >> self.fine_shift);
        // At least v_fine = floor(sqrt(v2 2^fine_shift)): w >= v2.
        let dv = math::isqrt_u64_shl(w, self.fine_shift) - v_fine;
        if (dv | self.ticks_per_dv) >> 32 == 0 {
            // One 32x32 -> 64 multiplication.
            (dv * self.ticks_per_dv) >> 16
        } else {
            sat_u64((dv as u128 * self.ticks_per_dv as u128) >> 16)
        }
    }
}

/// Ticks q16 to seconds.
fn ticks_q16_to_s(t_q16: u64, timer_hz: u32) -> U32F32 {
    U32F32::from_bits(div_sat_u64((t_q16 as u128) << 16, timer_hz.max(1) as u128))
}

/// The lookahead planner with a queue of `N` moves.
#[derive(Debug, Clone)]
pub struct Planner<const N: usize> {
    lim: Limits,
    ring: [Entry; N],
    head: usize,
    len: usize,
    /// Start of the head, X, Y, Z, E in um.
    ///
    /// The end of the last released block (the reset position before any); each later entry
    /// starts at the end of the one before it.
    head_start_um: [i32; AXES],
    /// Geometry of the last pushed move, for the junction with the next one.
    last: Option<Geom>,
    /// End speed^2 of the last released block: the fixed start of the head.
    exit_v2: u64,
    /// Its root, `sqrt_q16(exit_v2)` (the head's start speed).
    exit_v: u64,
    released_q16: u64,
    released: u32,
}

// Planner<32> (the board's) on thumbv7m, bytes: 64 per entry, 4-byte usize, 8-aligned i128.
#[cfg(all(target_arch = "arm", target_pointer_width = "32"))]
const _: [(); 2280] = [(); core::mem::size_of::<Planner<32>>()];

impl<const N: usize> Planner<N> {
    const CAPACITY_OK: () = assert!(N >= 1, "the planner needs room for at least one move");

    /// An empty planner at `position_um` (X, Y, Z, E), at rest.
    pub fn new(config: &PlanConfig, position_um: [i32; AXES]) -> Self {
        let mut p = Self::empty();
        p.reset(config, position_um);
        p
    }

    /// Starts over in place as [`Planner::new`] would (the queue's slots are not cleared:
    /// it is empty).
    pub fn reset(&mut self, config: &PlanConfig, position_um: [i32; AXES]) {
        self.lim = Limits::new(config);
        self.head = 0;
        self.len = 0;
        self.head_start_um = position_um;
        self.last = None;
        self.exit_v2 = 0;
        self.exit_v = 0;
        self.released_q16 = 0;
        self.released = 0;
    }

    /// An unconfigured, empty planner (to be replaced by [`Planner::new`] before use; every
    /// move it plans has zero speed limits). Lets a large owner be built in a `static`.
    pub const fn empty() -> Self {
        let () = Self::CAPACITY_OK;
        Self {
            lim: Limits::EMPTY,
            ring: [Entry::EMPTY; N],
            head: 0,
            len: 0,
            head_start_um: [0; AXES],
            last: None,
            exit_v2: 0,
            exit_v: 0,
            released_q16: 0,
            released: 0,
        }
    }

    /// Queue capacity.
    pub const fn capacity(&self) -> usize {
        N
    }

    /// Moves in the queue.
    pub fn len(&self) -> usize {
        self.len
    }

    /// No move queued.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The queue is full: [`pop`](Self::pop) or [`pop_forced`](Self::pop_forced) first.
    pub fn is_full(&self) -> bool {
        self.len == N
    }

    /// The end of the last pushed move (where the next move starts), X, Y, Z, E in um.
    pub fn position_um(&self) -> [i32; AXES] {
        match self.len {
            0 => self.head_start_um,
            n => self.at(n - 1).end_um,
        }
    }

    /// Blocks released so far.
    pub fn released_blocks(&self) -> u32 {
        self.released
    }

    /// Duration of every released block, ticks q16.
    pub fn released_ticks_q16(&self) -> u64 {
        self.released_q16
    }

    /// Duration of the queued moves as currently planned (ending at rest), ticks q16.
    pub fn queued_ticks_q16(&self) -> u64 {
        (0..self.len)
            .map(|i| {
                let end = if i + 1 < self.len { self.at(i + 1).start_v2 } else { 0 };
                let start_v = (i == 0).then_some(self.exit_v);
                let from = self.start_um_of(i);
                Block::new(self.at(i), from, end, self.lim.timer_hz, start_v).t_total_q16
            })
            .fold(0, u64::saturating_add)
    }

    /// Print time of everything pushed so far if it ended at rest after the queued moves,
    /// ticks q16: released blocks plus the current plan of the queue.
    pub fn total_ticks_q16(&self) -> u64 {
        self.released_q16.saturating_add(self.queued_ticks_q16())
    }

    /// Print time in seconds ([`total_ticks_q16`](Self::total_ticks_q16)).
    pub fn total_time_s(&self) -> U32F32 {
        ticks_q16_to_s(self.total_ticks_q16(), self.lim.timer_hz)
    }

    fn idx(&self, i: usize) -> usize {
        (self.head + i) % N
    }

    fn at(&self, i: usize) -> &Entry {
        &self.ring[self.idx(i)]
    }

    fn at_mut(&mut self, i: usize) -> &mut Entry {
        let k = self.idx(i);
        &mut self.ring[k]
    }

    /// Start of queued move `i` (the end of move `i - 1`), X, Y, Z, E in um.
    fn start_um_of(&self, i: usize) -> [i32; AXES] {
        match i {
            0 => self.head_start_um,
            _ => self.at(i - 1).end_um,
        }
    }

    /// Queues a move from the current position to `mv.target_um`. A move that goes nowhere is
    /// accepted and dropped. A dwell ([`Move::dwell`]) stops the head where the last move
    /// ends (its target is not read) and waits there; one of no time is dropped.
    pub fn push(&mut self, mv: Move) -> Result<(), PlanError> {
        if self.len == N {
            return Err(PlanError::QueueFull);
        }
        if mv.kind == MoveKind::Dwell {
            // s 2^32 x f / 2^16: ticks q16.
            let f = u128::from(self.lim.timer_hz);
            let ticks_q16 = sat_u64((u128::from(mv.feed_mm_s.to_bits()) * f) >> 16);
            if ticks_q16 > 0 {
                self.push_entry(Entry {
                    end_um: self.position_um(),
                    cruise_v2: ticks_q16,
                    ..Entry::EMPTY
                });
                // The move after it starts at rest.
                self.last = None;
            }
            return Ok(());
        }
        if mv.feed_mm_s == 0 {
            return Err(PlanError::ZeroFeed);
        }
        let from = self.position_um();
        let mut d = [0i64; AXES];
        for (axis, dst) in d.iter_mut().enumerate() {
            *dst = mv.target_um[axis] as i64 - from[axis] as i64;
            if dst.abs() > MAX_AXIS_DELTA_UM {
                return Err(PlanError::MoveTooLong { axis: axis as u8 });
            }
        }
        if d == [0; AXES] {
            return Ok(());
        }
        let g = self.geometry(&d, &mv);
        let max_start_v2 = match self.last {
            Some(prev) if prev.kinematic() && g.kinematic() => {
                junction::junction_v2(&prev, &g, &self.lim)
            }
            _ => 0,
        };
        let entry = Entry {
            end_um: mv.target_um,
            len_q32: g.len_q32,
            accel_q16: g.accel_q16,
            cruise_v2: g.cruise_v2,
            max_start_v2,
            back_v2: self.exit_v2,
            start_v2: self.exit_v2,
        };
        self.push_entry(entry);
        self.last = Some(g);
        Ok(())
    }

    /// The next move starts at rest (the one before it ends so), as after a dwell: a layer
    /// change is a rest point of the plan, so a layer's blocks never depend on the next
    /// layer's moves.
    pub fn rest_here(&mut self) {
        self.last = None;
    }

    /// Appends `entry` (room checked) and replans. A dwell's junction limit and ramp are 0:
    /// the move before it ends at rest and the one after starts so.
    fn push_entry(&mut self, entry: Entry) {
        let n = self.len;
        *self.at_mut(n) = entry;
        self.len += 1;
        self.replan(n);
    }

    /// Backward pass from the new tail `n` while the reachable start speeds change, then the
    /// forward pass over the changed range.
    fn replan(&mut self, n: usize) {
        if n == 0 {
            return;
        }
        let mut next_back = 0u64;
        let mut first = n;
        let mut i = n;
        loop {
            let e = self.at_mut(i);
            let b = e.max_start_v2.min(next_back + e.delta_v2());
            if i < n && b == e.back_v2 {
                break;
            }
            e.back_v2 = b;
            first = i;
            next_back = b;
            if i == 1 {
                break;
            }
            i -= 1;
        }
        for i in first..=n {
            let prev = self.at(i - 1);
            let reach = prev.start_v2 + prev.delta_v2();
            let e = self.at_mut(i);
            e.start_v2 = e.back_v2.min(reach);
        }
    }

    /// Whether the head's plan is final: its exit speed already equals the most it could
    /// ever be (a dwell always ends at rest).
    pub fn head_is_final(&self) -> bool {
        if self.len >= 1 && self.at(0).is_dwell() {
            return true;
        }
        if self.len < 2 {
            return false;
        }
        let (h, n) = (self.at(0), self.at(1));
        n.start_v2 == n.max_start_v2.min(h.start_v2 + h.delta_v2())
    }

    /// Releases the head if its plan can no longer change.
    pub fn pop(&mut self) -> Option<Block> {
        if self.head_is_final() {
            self.pop_forced()
        } else {
            None
        }
    }

    /// Releases the head with its current plan (it ends at a speed from which the queued moves
    /// can still stop; at rest if it is the only one).
    pub fn pop_forced(&mut self) -> Option<Block> {
        if self.len == 0 {
            return None;
        }
        let end_v2 = if self.len >= 2 { self.at(1).start_v2 } else { 0 };
        // The head starts where the last block ended (replan never changes it).
        debug_assert!(self.at(0).start_v2 == self.exit_v2 && self.exit_v == sqrt_q16(self.exit_v2));
        let (from, hz) = (self.head_start_um, self.lim.timer_hz);
        let block = Block::new(self.at(0), from, end_v2, hz, Some(self.exit_v));
        self.head_start_um = block.end_um;
        self.head = (self.head + 1) % N;
        self.len -= 1;
        self.exit_v2 = end_v2;
        self.exit_v = block.v[2];
        self.released_q16 = self.released_q16.saturating_add(block.t_total_q16);
        self.released += 1;
        Some(block)
    }

    fn geometry(&self, d: &[i64; AXES], mv: &Move) -> Geom {
        let lim = &self.lim;
        let sq = |v: i64| (v * v) as u64;
        let xyz2 = sq(d[0]) + sq(d[1]) + sq(d[2]);
        let kinematic = xyz2 != 0;
        let len2 = if kinematic { xyz2 } else { sq(d[3]) };
        let len_q32 = isqrt_u128((len2 as u128) << 64) as u64;
        let mut cruise_v2 = square_q16(rate_to_q16(mv.feed_mm_s, MAX_SPEED_Q16));
        let mut accel_q16 = match mv.kind {
            MoveKind::Print => lim.print_accel_q16,
            MoveKind::Travel | MoveKind::Retract | MoveKind::Dwell => lim.travel_accel_q16,
        };
        // Axis speed v |d|/L <= vmax: v^2 <= vmax^2 L^2 / d^2 (L^2 exact); axis acceleration
        // a |d|/L <= amax: a <= amax L / |d|. Only the tightest axis of each needs dividing
        // (floor and saturation keep the order): the smallest vmax^2 / d^2 and amax / |d|,
        // compared by cross-multiplying.
        let (mut v_axis, mut a_axis) = (None::<usize>, None::<usize>);
        for (axis, &da) in d.iter().enumerate() {
            if da == 0 {
                continue;
            }
            // Weights below 2^48: 64x64-bit products.
            let tighter = |q: &[u64; AXES], other: Option<usize>, w: fn(i64) -> u64| {
                other.map_or(true, |o| {
                    (q[axis] as u128 * w(d[o]) as u128) < q[o] as u128 * w(da) as u128
                })
            };
            if tighter(&lim.vmax2_q16, v_axis, sq) {
                v_axis = Some(axis);
            }
            if tighter(&lim.amax_q16, a_axis, i64::unsigned_abs) {
                a_axis = Some(axis);
            }
        }
        if let Some(axis) = v_axis {
            let cap = div_sat_u64(lim.vmax2_q16[axis] as u128 * len2 as u128, sq(d[axis]) as u128);
            cruise_v2 = cruise_v2.min(cap);
        }
        if let Some(axis) = a_axis {
            // floor(amax L / (|d| 2^32)) = floor(floor(amax L / 2^32) / |d|): a 32-bit divisor.
            let la = (lim.amax_q16[axis] as u128 * len_q32 as u128) >> 32;
            let cap = div_sat_u64(la, d[axis].unsigned_abs() as u128);
            accel_q16 = accel_q16.min(cap);
        }
        // Every axis divides by the length (at least 2^32: 1 um).
        let by_len = Divisor::new(len_q32);
        let ratio = |v: i64| {
            if kinematic && v != 0 {
                div_i128_pos((v as i128) << 94, &by_len)
            } else {
                0
            }
        };
        Geom {
            unit: [ratio(d[0]) as i64, ratio(d[1]) as i64, ratio(d[2]) as i64],
            len_q32,
            accel_q16: accel_q16.max(1),
            cruise_v2: cruise_v2.max(1),
            e_ratio_q62: ratio(d[3]),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mm(v: u32) -> Rate {
        Rate::from_num(v)
    }

    fn to_f(r: Rate) -> f64 {
        r.to_num::<f64>()
    }

    /// `f64` trapezoid time (s) at distance `s_mm` with start, cruise and end speeds and the
    /// acceleration of `b` (from its accessors) and its phase distances.
    fn f64_time(b: &Block, s_mm: f64) -> f64 {
        let (v0, vc, v1) =
            (to_f(b.start_speed_mm_s()), to_f(b.cruise_speed_mm_s()), to_f(b.end_speed_mm_s()));
        let a = to_f(b.accel_mm_s2());
        let q32 = |x: u64| x as f64 / 4294967296e3;
        let ([sa, sd], len) = (b.phase_um_q32().map(q32), q32(b.length_um_q32()));
        let ta = (vc - v0) / a;
        let td = ta + (sd - sa) / vc;
        let total = td + (vc - v1) / a;
        if s_mm <= sa {
            2.0 * s_mm / (v0 + (v0 * v0 + 2.0 * a * s_mm).sqrt())
        } else if s_mm <= sd {
            ta + (s_mm - sa) / vc
        } else {
            let back = len - s_mm;
            total - 2.0 * back / (v1 + (v1 * v1 + 2.0 * a * back).sqrt())
        }
    }

    /// The per-step time as first written (128-bit products and shifts throughout): the
    /// oracle for the faster [`Block::step_time_q16`], which must give the same bits.
    fn reference_step_time_q16(b: &Block, dist_q32: u64) -> u64 {
        let s = dist_q32.min(b.len_q32);
        let ramp = |d: u64, v_fine: u64, v2: u64| -> u64 {
            let w = sat_u64(v2 as u128 + ((2 * b.accel_q16 as u128 * d as u128) >> 32));
            let w = if w > u64::MAX >> b.fine_shift { u64::MAX } else { w << b.fine_shift };
            let dv = math::isqrt_u64(w).saturating_sub(v_fine);
            sat_u64((dv as u128 * b.ticks_per_dv as u128) >> 16)
        };
        if s <= b.accel_end_q32 {
            ramp(s, b.v_fine[0], b.v2[0]).min(b.t_accel_q16)
        } else if s <= b.decel_start_q32 {
            let d = (s - b.accel_end_q32) as u128;
            let t = sat_u64((d * b.ticks_per_um as u128) >> b.cruise_shift);
            b.t_accel_q16.saturating_add(t).min(b.t_decel_q16)
        } else {
            let back = ramp(b.len_q32 - s, b.v_fine[2], b.v2[2]);
            b.t_total_q16.saturating_sub(back).max(b.t_decel_q16)
        }
    }

    /// The blocks of three travel moves at `feed` mm/s with `accel` mm/s^2 (the axes' own
    /// limits out of the way): 1 mm up, `len_um` along X, 1 mm down (90 degree corners).
    fn cornered_blocks(accel: u32, feed: u32, len_um: i32) -> [Block; 2] {
        let cfg = PlanConfig {
            travel_accel_mm_s2: mm(accel),
            max_accel_mm_s2: [mm(1_000_000); 4],
            max_feed_mm_s: [mm(20_000); 4],
            ..PlanConfig::default()
        };
        let mut p: Planner<4> = Planner::new(&cfg, [0; 4]);
        for to in [[0, 1_000, 0, 0], [len_um, 1_000, 0, 0], [len_um, 0, 0, 0]] {
            p.push(Move::new(to, mm(feed), MoveKind::Travel)).unwrap();
        }
        [p.pop_forced().unwrap(), p.pop_forced().unwrap()]
    }

    #[test]
    fn per_step_time_equals_the_128_bit_reference() {
        let mut next = crate::test_rng::xorshift(0x9e37_79b9_7f4a_7c15);
        for accel in [1u32, 4, 100, 500, 5_000, 200_000, 1_000_000] {
            for feed in [1u32, 30, 100, 300, 1_000, 10_000, 20_000] {
                for len_um in [1i32, 50, 2_000, 50_000, 300_000, 1_000_000] {
                    for b in cornered_blocks(accel, feed, len_um) {
                        let len = b.length_um_q32();
                        let [sa, sd] = b.phase_um_q32();
                        let check = |s: u64| {
                            assert_eq!(b.step_time_q16(s), reference_step_time_q16(&b, s), "{s}");
                        };
                        for i in 0..=300u64 {
                            check(len / 300 * i);
                        }
                        for edge in [0, sa, sd, len] {
                            for k in 0..4 {
                                check(edge.saturating_sub(k));
                                check(edge.saturating_add(k));
                            }
                        }
                        for _ in 0..300 {
                            check(next() % (len + 1));
                        }
                        check(u64::MAX);
                    }
                }
            }
        }
    }

    #[test]
    fn per_step_time_is_within_its_resolution_of_the_f64_trapezoid() {
        for accel in [1u32, 4, 100, 500, 5_000, 200_000] {
            for feed in [1u32, 30, 100, 300, 1_000, 10_000] {
                for len_um in [50i32, 2_000, 50_000, 1_000_000] {
                    // Start and end at speed: a 90 degree corner before and after.
                    let [_, b] = cornered_blocks(accel, feed, len_um);
                    let vc = to_f(b.cruise_speed_mm_s()) * 1e3;
                    let a = to_f(b.accel_mm_s2()) * 1e3;
                    // Speed resolution over a, the ramps' phase-time rounding, a tick q16.
                    let res = (vc * 2f64.powi(-30)).max(2f64.powi(-16)).min(2f64.powi(-8));
                    let tol = res / a * 1.5 + 3.0 / 72e6;
                    for i in 0..=400u64 {
                        let s_q32 = b.length_um_q32() / 400 * i;
                        let t = b.step_time_q16(s_q32) as f64 / 65536.0 / 72e6;
                        let want = f64_time(&b, s_q32 as f64 / 4294967296e3);
                        assert!(
                            (t - want).abs() <= tol,
                            "a {accel} feed {feed} len {len_um}: {t} vs {want} at {i}/400 (tol {tol})"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn entry_holds_end_length_accel_and_four_speeds() {
        // 16 B end, 6 u64 (len, accel, cruise, junction, back, start): the same on thumbv7m.
        assert_eq!(core::mem::size_of::<Entry>(), 64);
    }

    #[test]
    fn each_block_starts_where_the_one_before_ended() {
        let start = [1_000, -2_000, 300, 40];
        let mut p: Planner<3> = Planner::new(&PlanConfig::default(), start);
        let targets = [[5_000, 0, 300, 90], [5_000, 0, 300, -910], [0, 7_000, 500, -910]];
        let mut from = start;
        for (k, to) in targets.into_iter().cycle().take(12).enumerate() {
            if p.is_full() {
                let b = p.pop_forced().unwrap();
                assert_eq!(b.start_um(), from);
                from = b.end_um();
            }
            let to = to.map(|c| c + k as i32);
            p.push(Move::new(to, mm(50), MoveKind::Print)).unwrap();
            assert_eq!(p.position_um(), to);
        }
        let last = p.position_um();
        while let Some(b) = p.pop_forced() {
            assert_eq!(b.start_um(), from);
            from = b.end_um();
        }
        assert_eq!((from, p.position_um()), (last, last));
    }

    #[test]
    fn sqrt2_minus_one_is_the_floor_root() {
        assert_eq!(SQRT2_M1_Q62, isqrt_u128(2 << 124) - (1 << 62));
    }

    #[test]
    fn square_corner_passes_at_square_corner_velocity() {
        let mut p: Planner<16> = Planner::new(&PlanConfig::default(), [0; 4]);
        p.push(Move::new([20_000, 0, 0, 0], mm(60), MoveKind::Travel)).unwrap();
        p.push(Move::new([20_000, 20_000, 0, 0], mm(60), MoveKind::Travel)).unwrap();
        let b = p.pop().expect("head is final: its exit is the junction limit");
        assert!((to_f(b.end_speed_mm_s()) - 5.0).abs() < 1e-6, "{:?}", b.end_speed_mm_s());
        assert!(p.pop().is_none());
        let b2 = p.pop_forced().unwrap();
        assert!((to_f(b2.start_speed_mm_s()) - 5.0).abs() < 1e-6);
        assert!(b2.ends_at_rest());
    }

    #[test]
    fn straight_line_is_not_a_corner() {
        let mut p: Planner<16> = Planner::new(&PlanConfig::default(), [0; 4]);
        for i in 1..=4 {
            p.push(Move::new([i * 50_000, 0, 0, 0], mm(100), MoveKind::Travel)).unwrap();
        }
        let b = p.pop().unwrap();
        assert!((to_f(b.end_speed_mm_s()) - 100.0).abs() < 1e-6);
        assert!((to_f(b.cruise_speed_mm_s()) - 100.0).abs() < 1e-6);
    }

    #[test]
    fn short_move_never_cruises_and_time_matches_formula() {
        let mut p: Planner<4> = Planner::new(&PlanConfig::default(), [0; 4]);
        // 1 mm at 500 mm/s^2 print accel: peak sqrt(a L) = sqrt(500) mm/s.
        p.push(Move::new([1000, 0, 0, 0], mm(200), MoveKind::Print)).unwrap();
        let b = p.pop_forced().unwrap();
        let peak = (500.0f64).sqrt();
        assert!((to_f(b.cruise_speed_mm_s()) - peak).abs() < 1e-6);
        let t = 2.0 * peak / 500.0;
        assert!((b.duration_s().to_num::<f64>() - t).abs() < 1e-9);
    }

    #[test]
    fn extruder_only_moves_start_and_end_at_rest() {
        let mut p: Planner<8> = Planner::new(&PlanConfig::default(), [0; 4]);
        p.push(Move::new([10_000, 0, 0, 300], mm(40), MoveKind::Print)).unwrap();
        p.push(Move::new([10_000, 0, 0, -4700], mm(45), MoveKind::Retract)).unwrap();
        p.push(Move::new([20_000, 0, 0, -4700], mm(150), MoveKind::Travel)).unwrap();
        let a = p.pop().unwrap();
        assert!(a.ends_at_rest());
        let r = p.pop().unwrap();
        assert!(r.ends_at_rest());
        // Retract limited to the E maximum of 25 mm/s.
        assert!((to_f(r.cruise_speed_mm_s()) - 25.0).abs() < 1e-6);
    }
}
