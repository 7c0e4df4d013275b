//! The step generator: exact step times of planned blocks, axis by axis in time order,
//! compressed into the step queue incrementally (it stops whenever an axis' queue is full and
//! resumes where it left off).
//!
//! Blocks carry a tag (the layer) and the commands of each tag are hashed apart. Where the
//! tag changes at rest (the planner stops at every layer change), every axis starts afresh
//! on a whole tick: a tag's commands depend on its own blocks only, not on when it starts
//! nor on what moved before it.

use super::compress::{Compressor, Full, Tune};
use super::{motor_after, nearest_step, pack_horizon, step_position_q32, StepConfig, StepProducer};
use crate::machine::{Rate, AXES};
use crate::math::{div_u128, sat_u64, Divisor};
use crate::plan::Block;
use heapless::Deque;

/// What [`StepGenerator::run`] stopped for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum GenStatus {
    /// Every block is generated and sent, and the motion ends at rest: nothing to do until
    /// the next block.
    Idle,
    /// The current block is done and the motion goes on: the next block is needed (the
    /// executor will stall at the horizon without it).
    NeedBlock,
    /// An axis' queue is full: call again after the executor has taken commands.
    QueueFull,
}

/// Counters of the generator.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct GenStats {
    /// Steps generated per axis.
    pub steps: [u64; AXES],
    /// Sequences committed per axis.
    pub sequences: [u64; AXES],
    /// Steps that had to be moved later to respect the driver's minimum intervals (0 unless
    /// an axis reverses within a few microseconds).
    pub clamped: u32,
    /// Sequences that failed the final check against the exact times (always 0).
    pub check_failures: u32,
    /// Blocks completed.
    pub blocks: u32,
}

/// Progress of one axis through the current block.
#[derive(Debug, Clone, Copy, Default)]
struct AxisRun {
    /// Steps still to generate in this block.
    remaining: u32,
    /// Positive direction.
    dir: bool,
    /// Path distance of the next step, um q32 (saturated) and its next 16 fraction bits
    /// (um q48 split so that a step adds 64-bit words, no 128-bit arithmetic).
    s_q32: u64,
    s_frac: u32,
    /// Path distance per step, the same split.
    ds_q32: u64,
    ds_frac: u32,
    /// Exact time of the next step (generator ticks, below 2^48) times 4 plus the axis: the
    /// smallest key is the earliest step, the lower axis first on a tie (`u64::MAX` with no
    /// step left).
    next_key: u64,
}

impl AxisRun {
    /// No step to make.
    const STILL: Self = Self {
        remaining: 0,
        dir: false,
        s_q32: 0,
        s_frac: 0,
        ds_q32: 0,
        ds_frac: 0,
        next_key: u64::MAX,
    };

    /// Every field zero: the state of an unconfigured generator ([`StepGenerator::empty`]),
    /// which [`StepGenerator::reset`] replaces with [`AxisRun::STILL`].
    const EMPTY: Self =
        Self { remaining: 0, dir: false, s_q32: 0, s_frac: 0, ds_q32: 0, ds_frac: 0, next_key: 0 };

    /// One step of the block `b` (which starts at `start_q16`) is generated on `axis`: on to
    /// the next.
    fn advance(&mut self, axis: usize, start_q16: u64, b: &Block) {
        self.remaining -= 1;
        if self.remaining > 0 {
            self.step_distance();
            self.next_key = step_key(tick_at(start_q16, b, self.s_q32), axis);
        } else {
            self.next_key = u64::MAX;
        }
    }

    /// Moves to the next step's distance: `s += ds` in um q48, the integer part saturated
    /// (a distance past `u64::MAX` um q32 is clamped there, as the time is).
    fn step_distance(&mut self) {
        let frac = self.s_frac + self.ds_frac;
        self.s_frac = frac & 0xffff;
        // Wrapping adds (two instructions each on the Cortex-M3, saturating ones six): a
        // position stays below the block's length, far below 2^64.
        self.s_q32 = self.s_q32.wrapping_add(self.ds_q32).wrapping_add((frac >> 16) as u64);
    }
}

/// Turns blocks into compressed step sequences; `B` pending steps per axis at most.
#[derive(Debug, Clone)]
pub struct StepGenerator<const B: usize = 64> {
    tune: Tune,
    /// [`StepConfig::horizon_margin_ticks`].
    horizon_margin: u64,
    pending_ticks: u64,
    steps_per_mm: [Rate; AXES],
    comp: [Compressor<B>; AXES],
    axes: [AxisRun; AXES],
    block: Option<Block>,
    /// The waiting block and its tag.
    next: Option<(Block, u32)>,
    /// Tag of the blocks being generated.
    tag: Option<u32>,
    /// Closed tags and the hash of their commands.
    marks: Deque<(u32, u64), 4>,
    /// Tick of the last step generated.
    last_tick: u64,
    /// Axes still to check for an overdue sequence after the last step (bit per axis).
    overdue: u8,
    /// No pending step is overdue before this tick: at most the earliest first pending step
    /// plus `pending_ticks` (kept low when a step arrives, exact after a full check).
    settle_at: u64,
    /// A block ended at rest: every pending step goes out before the next block.
    flush_all: bool,
    /// Generator time at the start of the current block (or the end of the last), ticks q16.
    block_start_q16: u64,
    /// Where the queued commands can reach, ticks: the current block's end (or the last's),
    /// kept for [`StepGenerator::publish`].
    reach: u64,
    /// Motor position per axis after every step generated or being generated.
    motor: [i64; AXES],
    /// The last block's end per axis (um) and its step position (steps q32): the next
    /// block starts there, so its start needs no division.
    end_position: [(i32, i64); AXES],
    /// The last completed block ended at rest (true before the first).
    at_rest: bool,
    /// The last run stopped at a full step queue.
    queue_blocked: bool,
    blocks: u32,
    /// Steps generated, wrapping: [`progress`](Self::progress).
    progress: u32,
    /// Steps per axis of the blocks completed and the current one: a block's steps are
    /// counted when it starts, those of its axes' `remaining` are still to generate.
    steps: [u64; AXES],
}

impl<const B: usize> StepGenerator<B> {
    const CAPACITY_OK: () =
        assert!(B >= 2, "the generator needs at least two pending steps per axis");

    /// A generator whose axes stand at `position_um` (X, Y, Z, E), at time 0.
    pub fn new(config: &StepConfig, position_um: [i32; AXES]) -> Self {
        let mut g = Self::empty();
        g.reset(config, position_um);
        g
    }

    /// Starts over in place as [`StepGenerator::new`] would (no temporary of the whole
    /// generator on the stack).
    pub fn reset(&mut self, config: &StepConfig, position_um: [i32; AXES]) {
        let spm = config.steps_per_mm;
        self.tune = Tune {
            tol: config.max_error_ticks as i64,
            min_step: config.min_step_ticks() as i64,
            min_rev: config.min_reversal_ticks() as i64,
        };
        self.horizon_margin = config.horizon_margin_ticks() as u64;
        self.pending_ticks = config.max_pending_ticks as u64;
        self.steps_per_mm = spm;
        self.comp.iter_mut().for_each(Compressor::reset);
        self.axes = [AxisRun::STILL; AXES];
        self.block = None;
        self.next = None;
        self.tag = None;
        self.marks.clear();
        self.last_tick = 0;
        self.overdue = 0;
        self.settle_at = 0;
        self.flush_all = false;
        self.block_start_q16 = 0;
        self.reach = 0;
        for (axis, e) in self.end_position.iter_mut().enumerate() {
            *e = (position_um[axis], step_position(position_um[axis], spm[axis]));
        }
        for (m, (&p, &r)) in self.motor.iter_mut().zip(position_um.iter().zip(spm.iter())) {
            *m = nearest_step(step_position_q32(p, r));
        }
        self.at_rest = true;
        self.queue_blocked = false;
        self.blocks = 0;
        self.progress = 0;
        self.steps = [0; AXES];
    }

    /// An unconfigured generator, every byte zero (to be [`reset`](Self::reset) before use).
    /// Lets a large owner be built in a `static` in `.bss`.
    pub const fn empty() -> Self {
        let () = Self::CAPACITY_OK;
        Self {
            tune: Tune { tol: 0, min_step: 0, min_rev: 0 },
            horizon_margin: 0,
            pending_ticks: 0,
            steps_per_mm: [Rate::ZERO; AXES],
            comp: [Compressor::new(), Compressor::new(), Compressor::new(), Compressor::new()],
            axes: [AxisRun::EMPTY; AXES],
            block: None,
            next: None,
            tag: None,
            marks: Deque::new(),
            last_tick: 0,
            overdue: 0,
            settle_at: 0,
            flush_all: false,
            block_start_q16: 0,
            reach: 0,
            motor: [0; AXES],
            end_position: [(0, 0); AXES],
            // `reset` sets it (and `axes`): zero here keeps the value all zero bytes.
            at_rest: false,
            queue_blocked: false,
            blocks: 0,
            progress: 0,
            steps: [0; AXES],
        }
    }

    /// There is room for one more block.
    pub fn wants_block(&self) -> bool {
        self.next.is_none()
    }

    /// Hands over the next block; gives it back if one is already waiting.
    // Giving the item back is the heapless convention; no_std has no Box to shrink it.
    #[allow(clippy::result_large_err)]
    pub fn load(&mut self, block: Block) -> Result<(), Block> {
        self.load_tagged(block, 0)
    }

    /// [`StepGenerator::load`] with a tag (the layer): commands are hashed per tag (see
    /// [`StepGenerator::take_mark`]).
    #[allow(clippy::result_large_err)]
    pub fn load_tagged(&mut self, block: Block, tag: u32) -> Result<(), Block> {
        if self.next.is_some() {
            return Err(block);
        }
        self.next = Some((block, tag));
        Ok(())
    }

    /// No block in progress or waiting and every step sent.
    pub fn is_idle(&self) -> bool {
        self.block.is_none() && self.next.is_none() && self.comp.iter().all(|c| c.is_empty())
    }

    /// Motor positions (steps) once every generated step has run.
    pub fn motor_steps(&self) -> [i64; AXES] {
        self.motor
    }

    /// Blocks whose every step was generated since the reset (wraps at 2^32).
    pub fn blocks_done(&self) -> u32 {
        self.blocks
    }

    /// Generator time at the end of the completed blocks, ticks q16.
    pub fn time_q16(&self) -> u64 {
        self.block_start_q16
    }

    /// Counters.
    pub fn stats(&self) -> GenStats {
        GenStats {
            steps: core::array::from_fn(|a| self.generated(a)),
            sequences: self.comp.each_ref().map(|c| c.sequences),
            clamped: self.comp.iter().map(|c| c.clamped).sum(),
            check_failures: self.comp.iter().map(|c| c.check_failures).sum(),
            blocks: self.blocks,
        }
    }

    /// The last [`run`](Self::run) stopped at a full step queue: it has steps to send and
    /// waits for the executor (not for a block, nor for room for layer marks).
    pub fn waits_on_a_full_queue(&self) -> bool {
        self.queue_blocked
    }

    /// A count of the steps generated that wraps at 2^32: it changed if and only if a step
    /// was generated since it was read (unless 2^32 were), one load.
    pub fn progress(&self) -> u32 {
        self.progress
    }

    /// Steps generated so far, all axes (cheaper than [`stats`](Self::stats)).
    pub fn steps_generated(&self) -> u64 {
        (0..AXES).map(|a| self.generated(a)).sum()
    }

    /// Steps generated so far on `axis`.
    fn generated(&self, axis: usize) -> u64 {
        self.steps[axis] - self.axes[axis].remaining as u64
    }

    /// Generates and sends steps until the blocks run out or a queue is full, publishing the
    /// horizon as sequences go out.
    pub fn run<const N: usize>(&mut self, out: &mut StepProducer<'_, N>) -> GenStatus {
        let status = self.run_inner(out);
        self.publish(out);
        status
    }

    fn run_inner<const N: usize>(&mut self, out: &mut StepProducer<'_, N>) -> GenStatus {
        self.queue_blocked = false;
        loop {
            // Work owed by the last step or block end comes first, and is retried as it was
            // when a queue is full: the commands depend on the blocks only, never on how
            // fast the executor drains the queues.
            if self.settle(out).is_err() {
                self.queue_blocked = true;
                return GenStatus::QueueFull;
            }
            // Borrowed, never copied: a `Block` is a few hundred bytes.
            let Some(block) = self.block.as_ref() else {
                if let Some((b, tag)) = self.next {
                    if self.tag != Some(tag) {
                        if self.marks.is_full() {
                            return GenStatus::QueueFull;
                        }
                        // Between two tags at rest, the new tag's commands start afresh.
                        if self.tag.is_some() && self.at_rest && self.rest_all(out).is_err() {
                            self.queue_blocked = true;
                            return GenStatus::QueueFull;
                        }
                        // The commands so far belong to the previous tag.
                        let h = out.take_hash();
                        if let Some(prev) = self.tag {
                            let _ = self.marks.push_back((prev, h));
                        }
                        self.tag = Some(tag);
                    }
                    self.next = None;
                    self.start_block(b);
                    continue;
                }
                return if self.at_rest { GenStatus::Idle } else { GenStatus::NeedBlock };
            };
            // The axis with the earliest next step (the first of equals; an axis without
            // steps left waits at `u64::MAX`).
            let key = earliest(&self.axes);
            if key == u64::MAX {
                let (duration, at_rest) = (block.duration_ticks_q16(), block.ends_at_rest());
                self.block_start_q16 = self.block_start_q16.saturating_add(duration);
                self.reach = self.block_start_q16 >> 16;
                self.at_rest = at_rest;
                // A stop sends everything before it, whether or not more blocks follow.
                self.flush_all = self.at_rest;
                self.block = None;
                self.blocks += 1;
                continue;
            }
            let (axis, tick) = ((key & 3) as usize, key >> 2);
            let dir = self.axes[axis].dir;
            if self.comp[axis].push_step(axis, tick, dir, out, &self.tune).is_err() {
                // Only a deadlock (the executor waits at the horizon and this queue is still
                // full) sends other axes' steps early; a merely full queue waits.
                if out.executor_waiting() {
                    self.unblock(axis, out);
                }
                self.queue_blocked = true;
                return GenStatus::QueueFull;
            }
            self.axes[axis].advance(axis, self.block_start_q16, block);
            self.progress = self.progress.wrapping_add(1);
            self.last_tick = tick;
            // The axis' first pending step changed only if it is this one (an emit inside
            // `push_step` moves it later, which leaves `settle_at` a valid lower bound).
            if self.comp[axis].pending() == 1 {
                self.settle_at = self.settle_at.min(tick + self.pending_ticks);
            }
            // Every axis is checked after a step, unless nothing can be overdue yet (the
            // last `settle` left `overdue` at 0).
            if tick > self.settle_at {
                self.overdue = (1 << AXES) - 1;
            }
        }
    }

    /// The motion rests between two tags: every axis' reference moves on to the rest time
    /// (the first whole tick at or after the last block's end and every committed step) and
    /// the axes start afresh there ([`Compressor::rest_at`]), so the next tag's commands
    /// depend on its own blocks only, not on when it starts nor on the motion before (a job
    /// paused between two layers, its nozzle parked and brought back, resumes with the steps
    /// it would have made). Repeating the call after `Err` finishes it.
    fn rest_all<const N: usize>(&mut self, out: &mut StepProducer<'_, N>) -> Result<(), Full> {
        let end = self.block_start_q16.div_ceil(1 << 16);
        let t = self.comp.iter().map(|c| c.last()).fold(end, u64::max);
        for (axis, c) in self.comp.iter_mut().enumerate() {
            c.rest_at(axis, t, out)?;
        }
        self.block_start_q16 = t << 16;
        self.reach = t;
        self.last_tick = t;
        self.settle_at = u64::MAX;
        self.overdue = 0;
        Ok(())
    }

    /// Sends what is owed: per axis at most one sequence whose first step waited longer than
    /// `pending_ticks` behind the last step generated, then (at a stop) everything.
    #[inline]
    fn settle<const N: usize>(&mut self, out: &mut StepProducer<'_, N>) -> Result<(), Full> {
        if self.overdue != 0 {
            self.settle_overdue(out)?;
        }
        if self.flush_all {
            for c in 0..AXES {
                while !self.comp[c].is_empty() {
                    self.comp[c].emit(c, out, &self.tune)?;
                    self.publish(out);
                }
            }
            self.flush_all = false;
        }
        Ok(())
    }

    /// The per-axis part of [`StepGenerator::settle`]: at most one sequence for each axis
    /// still to check whose first step is overdue.
    fn settle_overdue<const N: usize>(
        &mut self,
        out: &mut StepProducer<'_, N>,
    ) -> Result<(), Full> {
        let full_check = self.overdue == (1 << AXES) - 1;
        // A first pending step `f` is overdue when `f + pending_ticks < last_tick`.
        let overdue_below = self.last_tick.saturating_sub(self.pending_ticks);
        // The earliest first pending step after the check (`u64::MAX`: none), gathered in the
        // same pass: an axis' first step changes only by its own emit.
        let mut soonest = u64::MAX;
        for c in 0..AXES {
            let Some(mut f) = self.comp[c].first_pending() else {
                continue;
            };
            if self.overdue & (1 << c) != 0 && f < overdue_below {
                if let Err(e) = self.comp[c].emit(c, out, &self.tune) {
                    // The axes before `c` are checked.
                    self.overdue &= !((1 << c) - 1);
                    return Err(e);
                }
                self.publish(out);
                match self.comp[c].first_pending() {
                    Some(g) => f = g,
                    None => continue,
                }
            }
            soonest = soonest.min(f);
        }
        self.overdue = 0;
        if full_check {
            self.settle_at =
                if soonest == u64::MAX { u64::MAX } else { soonest + self.pending_ticks };
        }
        Ok(())
    }

    /// Layer marks completed since the last call: (tag, hash of the step commands queued
    /// while the generator worked on blocks of that tag). The last tag's commands are
    /// closed with [`StepProducer::take_hash`] by the owner once the generator is idle.
    pub fn take_mark(&mut self) -> Option<(u32, u64)> {
        self.marks.pop_front()
    }

    /// The tag of the blocks being generated (the last one started).
    pub fn tag(&self) -> Option<u32> {
        self.tag
    }

    /// `axis` cannot queue more: send the other axes' steps that are older than its last
    /// queued one, so that the executor's horizon passes everything in its queue.
    fn unblock<const N: usize>(&mut self, axis: usize, out: &mut StepProducer<'_, N>) {
        let limit = self.comp[axis].last();
        for c in (0..AXES).filter(|&c| c != axis) {
            while self.comp[c].first_pending().is_some_and(|f| f <= limit) {
                if let Err(Full) = self.comp[c].emit(c, out, &self.tune) {
                    break;
                }
            }
        }
    }

    /// Publishes how far the queued commands reach and whether the motion rests there.
    fn publish<const N: usize>(&self, out: &mut StepProducer<'_, N>) {
        let end = self.reach;
        let complete = self.block.is_none()
            && self.next.is_none()
            && self.at_rest
            && self.comp.iter().all(|c| c.is_empty());
        if complete {
            // Everything is queued; a compressed step may sit up to `tol` after its exact
            // time, so the rest point is past every step.
            let last = self.comp.iter().map(|c| c.last()).max().unwrap_or(0);
            out.publish(pack_horizon(end.max(last + 2), true));
            return;
        }
        let mut h = end;
        for axis in 0..AXES {
            if let Some(f) = self.comp[axis].first_pending() {
                h = h.min(f);
            } else if self.block.is_some() && self.axes[axis].remaining > 0 {
                h = h.min(self.axes[axis].next_key >> 2);
            }
        }
        out.publish(pack_horizon(h.saturating_sub(self.horizon_margin), false));
    }

    fn start_block(&mut self, b: Block) {
        let (start, end) = (b.start_um(), b.end_um());
        let len = b.length_um_q32() as u128;
        for axis in 0..AXES {
            let spm = self.steps_per_mm[axis];
            let (last_um, last_p) = self.end_position[axis];
            let p0 = if start[axis] == last_um { last_p } else { step_position(start[axis], spm) };
            let p1 = step_position(end[axis], spm);
            self.end_position[axis] = (end[axis], p1);
            let m = self.motor[axis];
            let m1 = motor_after(m, p1);
            let run = &mut self.axes[axis];
            *run = AxisRun::STILL;
            if m1 == m {
                continue;
            }
            self.motor[axis] = m1;
            let half = 1i64 << 31;
            let (dir, delta0, dp) = if m1 > m {
                (true, (m << 32) + half - p0, p1 - p0)
            } else {
                (false, p0 - ((m << 32) - half), p0 - p1)
            };
            // 0 <= delta0 < dp; the first crossing is delta0 / dp of the way along.
            // Both quotients divide by dp (below 2^63): its reciprocal is prepared once.
            let by_dp = Divisor::new(dp.max(1) as u64);
            run.remaining = m1.abs_diff(m) as u32;
            self.steps[axis] += run.remaining as u64;
            run.dir = dir;
            let s_q48 = by_dp.div((delta0.max(0) as u128 * len) << 16);
            let ds_q48 = by_dp.div(len << 48);
            (run.s_q32, run.s_frac) = (sat_u64(s_q48 >> 16), s_q48 as u32 & 0xffff);
            (run.ds_q32, run.ds_frac) = (sat_u64(ds_q48 >> 16), ds_q48 as u32 & 0xffff);
        }
        for (axis, run) in self.axes.iter_mut().enumerate().filter(|(_, r)| r.remaining > 0) {
            run.next_key = step_key(tick_at(self.block_start_q16, &b, run.s_q32), axis);
        }
        self.reach = self.block_start_q16.saturating_add(b.duration_ticks_q16()) >> 16;
        self.block = Some(b);
    }
}

/// The smallest `next_key` of the four axes: the earliest step, the first of equals
/// (`u64::MAX`: no step left). Three 64-bit minimums (the axis rides in the key's low bits,
/// no index to select alongside), written out: at opt-level "s" a loop is not unrolled.
#[inline(always)]
fn earliest(axes: &[AxisRun; AXES]) -> u64 {
    const { assert!(AXES == 4) };
    let low = axes[0].next_key.min(axes[1].next_key);
    let high = axes[2].next_key.min(axes[3].next_key);
    low.min(high)
}

/// The key of a step at `tick` (below 2^48: generator ticks are q16 ticks shifted down by
/// 16) on `axis`.
#[inline(always)]
fn step_key(tick: u64, axis: usize) -> u64 {
    const { assert!(AXES <= 4) };
    (tick << 2) | axis as u64
}

/// [`step_position_q32`] (the same value) with the 128-bit division by 1000 done by
/// [`div_u128`]: `floor(p / 1000) = -floor((|p| + 999) / 1000)` for `p < 0`.
fn step_position(um: i32, steps_per_mm: Rate) -> i64 {
    let p = um as i128 * steps_per_mm.to_bits() as i128;
    if p < 0 {
        -(div_u128(p.unsigned_abs() + 999, 1000) as i128) as i64
    } else {
        div_u128(p as u128, 1000) as i64
    }
}

/// Exact time of path distance `s_q32` (um q32) in `b` (which starts at `start_q16`, ticks
/// q16), generator ticks rounded to nearest.
// Inlined: the per-step call's register saves cost more than the copy (about 200 bytes).
#[inline(always)]
fn tick_at(start_q16: u64, b: &Block, s_q32: u64) -> u64 {
    // Wrapping: generator time in q16 ticks wraps after 2^48 ticks (45 days at 72 MHz).
    start_q16.wrapping_add(b.step_time_q16(s_q32)).wrapping_add(1 << 15) >> 16
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fast_step_position_equals_the_reference() {
        let mut next = crate::test_rng::xorshift(0x2545_f491_4f6c_dd1d);
        let rates = [Rate::from_num(80), Rate::from_num(93), Rate::from_num(400), Rate::MAX];
        for i in 0..100_000 {
            let um = (next() as i32) >> (next() % 32);
            let spm =
                if i % 2 == 0 { rates[i % 4] } else { Rate::from_bits(next() >> (next() % 64)) };
            assert_eq!(step_position(um, spm), step_position_q32(um, spm), "{um} um at {spm}");
        }
        for um in [i32::MIN, i32::MAX, 0, -1, 1] {
            for spm in rates {
                assert_eq!(step_position(um, spm), step_position_q32(um, spm));
            }
        }
    }
}
