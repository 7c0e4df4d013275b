//! Step timing and execution: planned [`Block`](crate::plan::Block)s in, step/dir pin edges out.
//!
//! # Pipeline
//! [`StepGenerator`] (main loop) computes, per axis, the exact time of every step of the
//! planned profile and compresses consecutive step times into [`StepCmd::Steps`] sequences
//! `(interval, count, add)` in timer ticks. The sequences travel through a [`StepQueue`] (one
//! bounded single-producer single-consumer queue per axis, plus a published *horizon*) to the
//! [`Executor`] (timer interrupt), which only does `next += interval; interval += add` per
//! step and drives `embedded-hal` output pins with the driver's pulse and direction timing
//! (a STEP pulse usually rises and falls in the same interrupt: [`StepTimer`]).
//!
//! # Which steps, when
//! An axis' ideal position in steps is `P = position_um * steps_per_mm / 1000` (exact fixed
//! point, [`step_position_q32`]). The motor steps when `P` moves strictly past a half-step
//! boundary `k + 1/2`, so it always sits on the integer nearest to `P`; at an exact tie it stays
//! where it came from (touching a boundary and turning back makes no step). A move from `P0`
//! to `P1` therefore takes its steps at the path distances where `P` crosses those boundaries,
//! and the time of each is [`Block::step_time_q16`](crate::plan::Block::step_time_q16) of that
//! distance: E follows the XY path like any other axis, and straight moves never change an
//! axis' direction inside a move.
//!
//! # Accuracy
//! Every compressed sequence is checked step by step against the exact times before it is
//! committed: each step is within [`StepConfig::max_error_ticks`] (default 0.5 us) of its
//! exact time rounded to the tick (so within 1 us overall), never a step more or less.
//!
//! # Time
//! Generator time starts at 0 ticks at the first block and runs on (`u64`); the executor
//! maps it to its wrapping `u32` timer with an offset and compares only with [`is_before`].
//! `now` is an argument; inside a call the executor reads the board's [`StepTimer`] (if
//! given) only to end the STEP pulses it raised.

use core::sync::atomic::{AtomicU32, Ordering};

use heapless::spsc::{Consumer, Producer, Queue};

use crate::machine::{MachineConfig, Rate, AXES};

mod compress;
mod exec;
mod gen;

pub use exec::{ExecStats, Executor, NoWait, Pins, StepTimer, Wake};
pub use gen::{GenStats, GenStatus, StepGenerator};

/// Wrap-safe "`a` is strictly earlier than `b`" for wrapping `u32` tick counters (valid while
/// the two are less than 2^31 ticks, about 30 s at 72 MHz, apart).
#[inline]
pub const fn is_before(a: u32, b: u32) -> bool {
    (a.wrapping_sub(b) as i32) < 0
}

/// Longest interval or wait in one command, ticks (2^30: about 15 s at 72 MHz, half the
/// [`is_before`] range).
pub const MAX_INTERVAL_TICKS: u32 = 1 << 30;

/// Step and direction timing a stepper driver needs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DriverTiming {
    /// Minimum time STEP stays high, ns.
    pub step_high_ns: u32,
    /// Minimum time STEP stays low between pulses, ns.
    pub step_low_ns: u32,
    /// Minimum time DIR must be stable before a rising STEP edge, ns.
    pub dir_setup_ns: u32,
}

impl DriverTiming {
    /// A4988-class drivers (the Ender-3's stock boards): 1 us high, 1 us low, 200 ns setup.
    pub const A4988: Self = Self { step_high_ns: 1000, step_low_ns: 1000, dir_setup_ns: 200 };
    /// TMC2208/2209 in standalone mode: 100 ns high, 100 ns low, 20 ns setup.
    pub const TMC2208: Self = Self { step_high_ns: 100, step_low_ns: 100, dir_setup_ns: 20 };
}

impl Default for DriverTiming {
    fn default() -> Self {
        Self::A4988
    }
}

/// Configuration shared by the generator and the executor.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub struct StepConfig {
    /// Step timer frequency, Hz (72 MHz on the board).
    pub timer_hz: u32,
    /// Steps per mm for X, Y, Z, E.
    pub steps_per_mm: [Rate; AXES],
    /// Driver pulse and direction timing.
    pub driver: DriverTiming,
    /// Largest allowed difference between a compressed step time and the exact one, ticks.
    pub max_error_ticks: u32,
    /// A step waits at most this long (in generated time) for a longer sequence before it is
    /// sent, ticks; bounds how far the executor's horizon trails the generator.
    pub max_pending_ticks: u32,
    /// DIR pin level for positive motion is low instead of high, per axis.
    pub invert_dir: [bool; AXES],
    /// The shared enable pin is active low (A4988, TMC standalone).
    pub enable_active_low: bool,
    /// Delay between (re)starting the executor and the first step, ticks.
    pub start_lead_ticks: u32,
    /// While stalled (underrun), the executor polls the queue at this interval, ticks.
    pub stall_poll_ticks: u32,
    /// Longest delay from a step's commanded tick to its rising edge on the board (interrupt
    /// entry and the executor's pass up to that pin write), ns. STEP's high time and DIR's
    /// setup count from the real edge, so a reversal leaves room for it: DIR never delays the
    /// step after it ([`ExecStats::late_dir_steps`](crate::step::ExecStats) stays 0).
    pub edge_latency_ns: u32,
}

impl StepConfig {
    /// No configuration: every field zero, a placeholder until
    /// [`from_machine`](Self::from_machine)'s value replaces it.
    pub const EMPTY: Self = Self {
        timer_hz: 0,
        steps_per_mm: [Rate::ZERO; AXES],
        driver: DriverTiming { step_high_ns: 0, step_low_ns: 0, dir_setup_ns: 0 },
        max_error_ticks: 0,
        max_pending_ticks: 0,
        invert_dir: [false; AXES],
        enable_active_low: false,
        start_lead_ticks: 0,
        stall_poll_ticks: 0,
        edge_latency_ns: 0,
    };

    /// The steps/mm of `machine`, a 72 MHz timer, A4988 timing, 0.5 us compression error.
    pub const fn from_machine(machine: &MachineConfig) -> Self {
        Self {
            timer_hz: 72_000_000,
            steps_per_mm: machine.steps_per_mm,
            driver: DriverTiming::A4988,
            max_error_ticks: 36,
            max_pending_ticks: 72_000_000 / 50,
            invert_dir: [false, false, true, false],
            enable_active_low: true,
            start_lead_ticks: 72_000_000 / 1000,
            stall_poll_ticks: 72_000_000 / 10_000,
            // The 64 KB QEMU build measures 4.6 us at 1.5 cycles an instruction (HIL
            // `edge_ticks_max`, asserted below this): twice that and some.
            edge_latency_ns: 10_000,
        }
    }

    /// `ns` in timer ticks, rounded up.
    pub fn ns_to_ticks(&self, ns: u32) -> u32 {
        ((ns as u64 * self.timer_hz as u64).div_ceil(1_000_000_000)) as u32
    }

    /// Shortest STEP high time, ticks.
    pub fn step_high_ticks(&self) -> u32 {
        self.ns_to_ticks(self.driver.step_high_ns).max(1)
    }

    /// Shortest interval between two steps in the same direction, ticks (high + low).
    pub fn min_step_ticks(&self) -> u32 {
        self.step_high_ticks() + self.ns_to_ticks(self.driver.step_low_ns).max(1)
    }

    /// Shortest interval between the last step before a direction change and the first one
    /// after it, ticks: the edge comes up to the latency after its tick, DIR changes when
    /// STEP falls, then needs the low time and the setup.
    pub fn min_reversal_ticks(&self) -> u32 {
        let low = self.ns_to_ticks(self.driver.step_low_ns).max(1);
        self.edge_latency_ticks()
            + self.step_high_ticks()
            + low.max(self.ns_to_ticks(self.driver.dir_setup_ns))
    }

    /// How far the generator's published horizon stays before the earliest step it has not
    /// sent, ticks: a compressed step may run up to `max_error_ticks` before its exact time,
    /// and an axis the executor left idle takes a direction change as late as the horizon,
    /// so DIR's setup must end before that step.
    pub fn horizon_margin_ticks(&self) -> u32 {
        self.max_error_ticks + self.ns_to_ticks(self.driver.dir_setup_ns) + 2
    }

    /// [`StepConfig::edge_latency_ns`] in ticks.
    pub fn edge_latency_ticks(&self) -> u32 {
        self.ns_to_ticks(self.edge_latency_ns)
    }
}

impl Default for StepConfig {
    /// The stock Ender-3 ([`MachineConfig::default`]).
    fn default() -> Self {
        Self::from_machine(&MachineConfig::default())
    }
}

/// One command of an axis' step queue.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StepCmd {
    /// Set the direction for the following steps (`true` = positive).
    Dir(bool),
    /// `count` steps: the first `interval` ticks after the previous step (or wait), then each
    /// one after `interval += add; next += interval`.
    Steps {
        /// Ticks from the previous step to the first one.
        interval: u32,
        /// Number of steps (at least 1).
        count: u16,
        /// Change of the interval after every step, ticks.
        add: i32,
    },
    /// Move the reference time on by `ticks` without stepping (long pauses of one axis).
    Wait(u32),
}

/// The horizon word: generator time (low 32 bits, even) up to which every axis' steps are
/// queued, and bit 0 set when the motion is at rest there with nothing after it.
pub(crate) fn pack_horizon(ticks: u64, at_rest: bool) -> u32 {
    (ticks as u32 & !1) | at_rest as u32
}

/// The queues between generator and executor: `N - 1` commands per axis (`heapless::spsc`
/// keeps one slot free; a power of two keeps the index arithmetic free of division).
#[derive(Debug)]
pub struct StepQueue<const N: usize> {
    axes: [Queue<StepCmd, N>; AXES],
    horizon: AtomicU32,
    /// The horizon word the executor is stalled at ([`NOT_STALLED`] while it runs).
    stalled_at: AtomicU32,
}

/// `stalled_at` while the executor runs (horizon words of a stall are even).
const NOT_STALLED: u32 = 1;

impl<const N: usize> StepQueue<N> {
    /// Empty queues, horizon at time 0, at rest.
    pub const fn new() -> Self {
        Self {
            axes: [Queue::new(), Queue::new(), Queue::new(), Queue::new()],
            horizon: AtomicU32::new(1),
            stalled_at: AtomicU32::new(NOT_STALLED),
        }
    }

    /// Splits into the generator's and the executor's ends.
    pub fn split(&mut self) -> (StepProducer<'_, N>, StepConsumer<'_, N>) {
        let [x, y, z, e] = &mut self.axes;
        let (px, cx) = x.split();
        let (py, cy) = y.split();
        let (pz, cz) = z.split();
        let (pe, ce) = e.split();
        let (h, st) = (&self.horizon, &self.stalled_at);
        (
            StepProducer {
                q: [px, py, pz, pe],
                horizon: h,
                stalled_at: st,
                published: 1,
                hash: FNV_OFFSET,
            },
            StepConsumer { q: [cx, cy, cz, ce], horizon: h, stalled_at: st },
        )
    }
}

impl<const N: usize> Default for StepQueue<N> {
    fn default() -> Self {
        Self::new()
    }
}

/// The generator's end of a [`StepQueue`].
pub struct StepProducer<'q, const N: usize> {
    q: [Producer<'q, StepCmd, N>; AXES],
    horizon: &'q AtomicU32,
    stalled_at: &'q AtomicU32,
    /// The last horizon word published.
    published: u32,
    /// FNV-1a of every command queued since the last [`StepProducer::take_hash`].
    hash: u64,
}

/// FNV-1a 64 offset basis (the step hashes here and on the simulated board).
pub(crate) const FNV_OFFSET: u64 = 0xcbf2_9ce4_8422_2325;
const FNV_PRIME: u64 = 0x0000_0100_0000_01b3;

/// FNV-1a step of `bytes` into `h` (the simulated board's edge hash).
pub(crate) fn fnv(mut h: u64, bytes: &[u8]) -> u64 {
    for &b in bytes {
        h ^= b as u64;
        h = h.wrapping_mul(FNV_PRIME);
    }
    h
}

/// FNV-1a over 32-bit words (`h ^= w; h *= prime`) of one queued command of `axis`: a word
/// of axis, kind and count, then the command's two 32-bit fields. Three 64-bit
/// multiplications per command instead of twelve bytewise ones.
fn hash_cmd(h: u64, axis: usize, cmd: &StepCmd) -> u64 {
    let (kind, a, b) = match *cmd {
        StepCmd::Dir(positive) => (1 | (positive as u32) << 8, 0, 0),
        StepCmd::Wait(ticks) => (2, ticks, 0),
        StepCmd::Steps { interval, count, add } => (3 | (count as u32) << 16, interval, add as u32),
    };
    // Written out: a loop over the three words kept them in a stack array.
    let word = |h: u64, w: u32| (h ^ w as u64).wrapping_mul(FNV_PRIME);
    word(word(word(h, axis as u32 | kind << 4), a), b)
}

impl<const N: usize> StepProducer<'_, N> {
    /// Queues `cmd` for `axis`; gives it back when that queue is full.
    pub fn enqueue(&mut self, axis: usize, cmd: StepCmd) -> Result<(), StepCmd> {
        // The queue's result is returned as it is: taken apart (`?`), its tag byte (the
        // command's) split the command's copies, and the compiler moved the 11 bytes after
        // it with two bytewise `__aeabi_memcpy` calls; now the command moves as three words.
        let hash = hash_cmd(self.hash, axis, &cmd);
        let queued = self.q[axis].enqueue(cmd);
        if queued.is_ok() {
            self.hash = hash;
        }
        queued
    }

    /// The hash of the commands queued since the last call (FNV-1a over axis and command,
    /// in queue order), and starts a new one. Identical block streams give identical
    /// command streams, however the executor's timing fills and drains the queues.
    pub fn take_hash(&mut self) -> u64 {
        core::mem::replace(&mut self.hash, FNV_OFFSET)
    }

    /// The executor holds at the horizon last published: it has run everything it can and
    /// needs more commands before it moves on.
    pub fn executor_waiting(&self) -> bool {
        self.stalled_at.load(Ordering::Acquire) == self.published
    }

    /// Free slots in `axis`' queue.
    pub fn free(&self, axis: usize) -> usize {
        self.q[axis].capacity() - self.q[axis].len()
    }

    /// Commands waiting in `axis`' queue.
    pub fn len(&self, axis: usize) -> usize {
        self.q[axis].len()
    }

    /// All queues are empty.
    pub fn is_empty(&self) -> bool {
        self.q.iter().all(|q| q.len() == 0)
    }

    pub(crate) fn publish(&mut self, word: u32) {
        self.published = word;
        self.horizon.store(word, Ordering::Release);
    }
}

/// The executor's end of a [`StepQueue`].
pub struct StepConsumer<'q, const N: usize> {
    q: [Consumer<'q, StepCmd, N>; AXES],
    horizon: &'q AtomicU32,
    stalled_at: &'q AtomicU32,
}

impl<const N: usize> StepConsumer<'_, N> {
    /// Takes the next command of `axis`.
    #[inline]
    pub fn dequeue(&mut self, axis: usize) -> Option<StepCmd> {
        self.q[axis].dequeue()
    }

    #[inline]
    pub(crate) fn has_data(&self) -> bool {
        self.q.iter().any(|q| q.ready())
    }

    #[inline]
    pub(crate) fn horizon(&self) -> u32 {
        self.horizon.load(Ordering::Acquire)
    }

    /// Says the executor stalled at horizon `word` (or runs again: [`NOT_STALLED`]).
    #[inline]
    pub(crate) fn set_stalled_at(&self, word: u32) {
        self.stalled_at.store(word, Ordering::Release);
    }
}

impl<const N: usize> core::fmt::Debug for StepProducer<'_, N> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let lens: [usize; AXES] = core::array::from_fn(|a| self.q[a].len());
        f.debug_struct("StepProducer").field("queued", &lens).finish()
    }
}

impl<const N: usize> core::fmt::Debug for StepConsumer<'_, N> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let lens: [usize; AXES] = core::array::from_fn(|a| self.q[a].len());
        f.debug_struct("StepConsumer").field("queued", &lens).finish()
    }
}

/// Ideal position in steps (q32 fixed point, floor) of `um` on an axis with `steps_per_mm`.
pub fn step_position_q32(um: i32, steps_per_mm: Rate) -> i64 {
    let p = um as i128 * steps_per_mm.to_bits() as i128;
    p.div_euclid(1000) as i64
}

/// The motor position a fresh start at ideal position `p_q32` takes: the nearest integer, half
/// rounded up.
pub fn nearest_step(p_q32: i64) -> i64 {
    (p_q32 + (1 << 31)) >> 32
}

/// Motor position after moving from motor position `motor` to ideal position `p1_q32`: it
/// steps each time the ideal position moves strictly past a half-step boundary.
pub fn motor_after(motor: i64, p1_q32: i64) -> i64 {
    let half = 1i64 << 31;
    let m_q32 = motor << 32;
    if p1_q32 > m_q32 + half {
        // Highest M with M - 1/2 < p1.
        (p1_q32 + half - 1) >> 32
    } else if p1_q32 < m_q32 - half {
        // Lowest M with M + 1/2 > p1.
        ((p1_q32 - half) >> 32) + 1
    } else {
        motor
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wrap_safe_compare() {
        assert!(is_before(1, 2));
        assert!(!is_before(2, 2));
        assert!(is_before(u32::MAX - 5, 3));
        assert!(!is_before(3, u32::MAX - 5));
    }

    #[test]
    fn motor_follows_half_step_boundaries_with_ties_kept() {
        let spm = Rate::from_num(93);
        // 93 * q / 1000 = 0.5 exactly for q = 500 / 93? No: pick q with 93 q = 500 mod 1000.
        let q = (0..1000).find(|q| 93 * q % 1000 == 500).unwrap();
        let p_tie = step_position_q32(q, spm);
        assert_eq!(p_tie & 0xffff_ffff, 1 << 31);
        let k = p_tie >> 32;
        // Coming from below to the tie: stays at k; from above: stays at k + 1.
        assert_eq!(motor_after(k, p_tie), k);
        assert_eq!(motor_after(k + 1, p_tie), k + 1);
        // Just past it moves.
        assert_eq!(motor_after(k, p_tie + 1), k + 1);
        assert_eq!(motor_after(k + 1, p_tie - 1), k);
        assert_eq!(nearest_step(step_position_q32(20_000, Rate::from_num(80))), 1600);
        assert_eq!(motor_after(0, step_position_q32(-20_000, Rate::from_num(80))), -1600);
    }

    #[test]
    fn driver_timing_in_ticks() {
        let c = StepConfig::default();
        assert_eq!(c.step_high_ticks(), 72);
        assert_eq!(c.min_step_ticks(), 144);
        // 10 us of edge latency, 1 us high, 1 us low (above the 0.2 us setup).
        assert_eq!(c.edge_latency_ticks(), 720);
        assert_eq!(c.min_reversal_ticks(), 720 + 72 + 72);
        let mut t = c;
        t.driver = DriverTiming::TMC2208;
        assert_eq!(t.step_high_ticks(), 8);
        assert_eq!(t.min_reversal_ticks(), 720 + 8 + 8);
    }
}
