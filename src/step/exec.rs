//! The step executor: runs in the step timer interrupt, integer adds and compares only.
//!
//! Per axis it holds the running sequence (`next`, `interval`, `add`, `remaining`). At a due
//! step it raises STEP and advances with `interval += add; next += interval`. Times are
//! wrapping `u32` ticks compared with [`is_before`].
//!
//! # STEP pulses
//! With a [`StepTimer`] ([`Executor::on_timer_with`]) a pulse usually starts and ends in one
//! call: STEP rises, the timer is read (`raised_at`), the next events are computed, and STEP
//! falls once the timer reads `raised_at + step_high` (busy-waiting the remainder, at most
//! the driver's high time: 72 ticks for an A4988, usually less or nothing as the work after
//! the rise takes about as long). Every STEP still high falls together there. This is done
//! only when no other event (another axis' step, a pulse's deadline, the horizon) is due
//! before that fall; otherwise, and always without a timer ([`Executor::on_timer`]), a fall
//! is an event: STEP may fall at any call from `raised_at + step_high` on (before the axis'
//! other events in that call), and by the middle of the slack before
//! the axis' next rising edge (the high and the low time both keep at least half of the
//! spare time on top of the driver's minimum), so it usually rides along with another axis'
//! event; a pulse with no step of the axis after it (a direction change next, or nothing
//! queued) then falls exactly at `raised_at + step_high`, since DIR may change then.
//!
//! At the last step of a sequence the executor takes the next commands right away, up to the
//! next sequence (waits and sequences set no pin), so the next step needs no call of its own.
//! A direction change is held until STEP has fallen and set then (in the same call with a
//! timer, when the pulse ends in it), which is at least the driver's setup time before the
//! next rising edge because the generator keeps that gap ([`StepConfig::min_reversal_ticks`]).
//! Rising edges are at their commanded ticks either way.
//!
//! # Horizon, underrun, restart
//! The generator publishes the generator time up to which every axis' commands are queued.
//! No step later than that horizon is executed. Reaching the horizon while the motion is not
//! at rest there is an **underrun**: the executor counts it ([`ExecStats::underruns`],
//! [`ExecStats::first_underrun_tick`]), holds every axis (no step dropped, none early) and
//! polls every [`StepConfig::stall_poll_ticks`]. Once the horizon moves on it resumes with
//! every later step delayed by the same amount (stall point to `now + start_lead`), so step
//! counts and relative timing are preserved. Reaching a horizon where the motion rests
//! makes the executor idle ([`Wake::Idle`]); new commands restart it the same way (call
//! [`Executor::on_timer`] after queuing them).

use embedded_hal::digital::{OutputPin, PinState};

use super::{is_before, StepCmd, StepConfig, StepConsumer};
use crate::machine::AXES;

/// The step, direction and shared enable pins.
#[derive(Debug)]
pub struct Pins<P> {
    /// STEP per axis X, Y, Z, E.
    pub step: [P; AXES],
    /// DIR per axis X, Y, Z, E.
    pub dir: [P; AXES],
    /// The shared enable pin.
    pub enable: P,
}

/// The step timer as the executor reads it during a call, to end STEP pulses in the call
/// that starts them (the same clock as the `now` argument, wrapping `u32` ticks).
pub trait StepTimer {
    /// False: no reading inside a call; every fall is an event ([`NoWait`]).
    const WAITS: bool = true;
    /// The timer's tick now.
    fn now(&mut self) -> u32;
    /// Returns once the timer has reached `t` (busy-waits the remainder).
    #[inline]
    fn wait_until(&mut self, t: u32) {
        while is_before(self.now(), t) {}
    }
}

/// No timer: [`Executor::on_timer`]'s mode, every STEP fall is an event.
#[derive(Debug, Clone, Copy, Default)]
pub struct NoWait;

impl StepTimer for NoWait {
    const WAITS: bool = false;
    fn now(&mut self) -> u32 {
        0
    }
}

/// The simulated board's clock: waiting moves it on (to the exact tick).
impl<O: crate::sim::EdgeObserver> StepTimer for &crate::sim::SimBoard<O> {
    fn now(&mut self) -> u32 {
        self.now_u32()
    }
    fn wait_until(&mut self, t: u32) {
        self.advance_to_u32(t);
    }
}

/// When the executor wants to run next.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Wake {
    /// Call [`Executor::on_timer`] again at this tick.
    At(u32),
    /// Nothing queued and the motion is at rest: call again after queuing commands.
    Idle,
}

/// Counters of the executor.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ExecStats {
    /// Steps executed per axis.
    pub steps: [u64; AXES],
    /// Times the horizon was reached while the motion should have gone on.
    pub underruns: u32,
    /// Tick of the first underrun.
    pub first_underrun_tick: Option<u32>,
    /// Steps delayed because DIR changed less than the setup time before them (only after
    /// an underrun-late direction command).
    pub late_dir_steps: u32,
    /// Starts from idle.
    pub starts: u32,
    /// Calls with a rising edge whose STEP fall was left to a later call, as another event
    /// came before it (counted with a [`StepTimer`] only: without one every fall is left).
    pub fall_events: u32,
}

#[derive(Debug, Clone, Copy, Default)]
struct AxisExec {
    /// `high || active`: the axis has an event at `at`. Otherwise it waits for commands.
    armed: bool,
    /// STEP is high (left by a call; with a timer in `Executor::left_high`); it may fall from
    /// `fall_from` (the driver's high time) on and falls by `at` at the latest.
    high: bool,
    /// A sequence is running; its next step is due at `next_at` and, while STEP is low,
    /// is raised at `at` ([`AxisExec::fire_time`]).
    active: bool,
    /// DIR changed at `dir_at` and no step has followed yet.
    dir_fresh: bool,
    /// Current direction is positive.
    positive: bool,
    /// A direction change taken at a sequence's last step: it is set when that STEP pulse
    /// falls (at the fall the next commands are taken).
    held_dir: Option<bool>,
    /// The axis' next event: its rising edge, or with STEP high the fall's deadline.
    at: u32,
    fall_from: u32,
    next_at: u32,
    interval: u32,
    add: u32,
    /// Steps of the running sequence not raised yet, of `count`.
    remaining: u32,
    count: u32,
    /// Time of the last step (or the end of the last wait): sequences count from here. Kept
    /// up to date when a sequence ends (read only when the next commands are taken).
    reference: u32,
    dir_at: u32,
}

impl AxisExec {
    /// Takes a wait or a sequence (no sequence running; a direction change is the
    /// executor's: it sets a pin); true when a sequence starts.
    #[inline]
    fn load(&mut self, cmd: StepCmd, setup: u32) -> bool {
        match cmd {
            StepCmd::Dir(_) => false,
            StepCmd::Wait(ticks) => {
                self.reference = self.reference.wrapping_add(ticks);
                false
            }
            StepCmd::Steps { interval, count, add } => {
                if count == 0 {
                    return false;
                }
                self.interval = interval;
                self.add = add as u32;
                self.remaining = count as u32;
                self.count = count as u32;
                self.next_at = self.reference.wrapping_add(interval);
                self.at = self.fire_time(setup);
                self.active = true;
                self.armed = true;
                true
            }
        }
    }

    /// When the step due at `next_at` may rise: at `next_at`, or the DIR setup time after a
    /// direction change if that is later (only then do the two differ).
    #[inline]
    fn fire_time(&self, setup: u32) -> u32 {
        let ready = self.dir_at.wrapping_add(setup);
        if self.dir_fresh && is_before(self.next_at, ready) {
            ready
        } else {
            self.next_at
        }
    }
}

/// The earlier of `t` and the wake-up so far.
#[inline(always)]
fn earliest(wake: &mut u32, t: u32) {
    if is_before(t, *wake) {
        *wake = t;
    }
}

/// The earlier of `t` and the wake-up so far, if any.
#[inline(always)]
fn earliest_of(wake: &mut Option<u32>, t: u32) {
    match *wake {
        Some(w) if !is_before(t, w) => {}
        _ => *wake = Some(t),
    }
}

/// The deadline of a STEP pulse of `a` that may fall from `fall` on: by the middle of the
/// spare time between the shortest pulse and the shortest low time (`low`) before the next
/// step; with no sequence running exactly at `fall` (DIR may change then).
#[inline(always)]
fn fall_deadline(a: &AxisExec, fall: u32, low: u32) -> u32 {
    if a.active {
        let slack = a.next_at.wrapping_sub(fall).wrapping_sub(low) as i32;
        fall.wrapping_add((slack.max(0) as u32) >> 1)
    } else {
        fall
    }
}

/// What a call collects over the axes.
struct Events {
    /// The next wake-up so far.
    wake: u32,
    /// With a timer: the end of the latest pulse raised (valid when `raised` is not 0).
    fall: u32,
    /// With a timer: STEP pins raised (bit per axis).
    raised: u32,
}

/// What follows the last step of a sequence.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum SeqEnd {
    /// The next sequence runs (no direction change before it).
    Chained,
    /// A direction change comes next: it is held until STEP falls.
    DirFirst,
    /// No command queued.
    Empty,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum State {
    Idle,
    Running,
    /// Waiting for the horizon to pass this generator time.
    Stalled(u32),
}

/// Drives the pins from a [`StepConsumer`].
///
/// # Cost
/// The hot path is one pass over the four axes with adds and compares on `u32`s (the
/// horizon is compared with a step only in a call at or past it: a step due earlier is
/// within it). With a [`StepTimer`] a step is one call: the pulse ends in it (see the module
/// docs), after at most the driver's high time from the rising edge (72 ticks for an A4988),
/// usually with no wait as the pass itself takes that long; the end of a sequence loads the
/// next one in the same call (one 64-bit add per sequence for the counters). Without one, or
/// when another event comes within the pulse, the fall is an event that usually rides along
/// with another axis' step. Rising edges are at their commanded ticks either way.
#[derive(Debug)]
pub struct Executor<'q, const N: usize> {
    q: StepConsumer<'q, N>,
    axes: [AxisExec; AXES],
    /// Executor tick = generator tick + offset.
    offset: u32,
    state: State,
    /// Generator time at which the motion last came to rest.
    rest_gen: u32,
    high_ticks: u32,
    low_ticks: u32,
    setup_ticks: u32,
    lead: u32,
    poll: u32,
    invert: [bool; AXES],
    enable_low: bool,
    /// Steps of the sequences completed, per axis, negative and positive (the running one
    /// is added when read: no 64-bit arithmetic per step, one add per sequence).
    done: [[u64; 2]; AXES],
    /// STEP pins left high by a call with a timer (bit per axis): they fall as events.
    left_high: u32,
    /// With a timer: axes whose sequence ended in the call before a direction change (bit
    /// per axis): they take it after the fall in the call.
    ended: u32,
    stats: ExecStats,
}

impl<'q, const N: usize> Executor<'q, N> {
    /// An idle executor taking commands from `queue`.
    pub fn new(config: &StepConfig, queue: StepConsumer<'q, N>) -> Self {
        Self {
            q: queue,
            axes: [AxisExec::default(); AXES],
            offset: 0,
            state: State::Idle,
            rest_gen: 0,
            high_ticks: config.step_high_ticks(),
            low_ticks: config.ns_to_ticks(config.driver.step_low_ns).max(1),
            setup_ticks: config.ns_to_ticks(config.driver.dir_setup_ns),
            lead: config.start_lead_ticks.max(config.ns_to_ticks(config.driver.dir_setup_ns)),
            poll: config.stall_poll_ticks.max(1),
            invert: config.invert_dir,
            enable_low: config.enable_active_low,
            done: [[0; 2]; AXES],
            left_high: 0,
            ended: 0,
            stats: ExecStats::default(),
        }
    }

    /// Executor tick of generator tick 0 (changes at every start and resume).
    pub fn offset(&self) -> u32 {
        self.offset
    }

    /// Idle: nothing queued, motion at rest.
    pub fn is_idle(&self) -> bool {
        self.state == State::Idle
    }

    /// The published horizon in executor ticks, and whether the motion rests there: a caller
    /// driving the executor on a virtual clock (the QEMU firmware's accelerated time) keeps
    /// the clock before an unrested horizon, or the executor stalls. Only meaningful while
    /// running (a start from idle shifts it).
    pub fn horizon(&self) -> (u32, bool) {
        let word = self.q.horizon();
        ((word & !1).wrapping_add(self.offset), word & 1 != 0)
    }

    /// Stalled by an underrun.
    pub fn is_stalled(&self) -> bool {
        matches!(self.state, State::Stalled(_))
    }

    /// Steps of the running sequence of `axis` raised so far.
    fn running_steps(&self, axis: usize) -> u32 {
        let a = &self.axes[axis];
        if a.active {
            a.count - a.remaining
        } else {
            0
        }
    }

    /// Steps executed per axis, signed by direction, since creation.
    pub fn position_steps(&self) -> [i64; AXES] {
        core::array::from_fn(|axis| {
            let n = self.running_steps(axis) as i64;
            let [neg, pos] = self.done[axis];
            pos as i64 - neg as i64 + if self.axes[axis].positive { n } else { -n }
        })
    }

    /// Counters.
    pub fn stats(&self) -> ExecStats {
        let mut s = self.stats;
        s.steps = core::array::from_fn(|a| {
            self.done[a][0] + self.done[a][1] + self.running_steps(a) as u64
        });
        s
    }

    /// Turns the drivers off; only while idle (returns `Ok(false)` otherwise).
    pub fn disable<P: OutputPin>(&mut self, pins: &mut Pins<P>) -> Result<bool, P::Error> {
        if self.state != State::Idle {
            return Ok(false);
        }
        pins.enable.set_state(PinState::from(self.enable_low))?;
        Ok(true)
    }

    /// Maps generator time `gen` to executor time `at` from now on.
    fn shift(&mut self, at: u32, gen: u32) {
        let offset = at.wrapping_sub(gen);
        let delta = offset.wrapping_sub(self.offset);
        let setup = self.setup_ticks;
        for a in &mut self.axes {
            a.reference = a.reference.wrapping_add(delta);
            a.next_at = a.next_at.wrapping_add(delta);
            if a.active && !a.high {
                a.at = a.fire_time(setup);
            }
        }
        self.offset = offset;
    }

    /// Leaves idle (new commands) or a stall (the horizon moved on) when it can; `Some` is
    /// the answer while it stays idle.
    #[inline(never)]
    fn wake_up<P: OutputPin>(
        &mut self,
        now: u32,
        word: u32,
        pins: &mut Pins<P>,
    ) -> Result<Option<Wake>, P::Error> {
        let (h_gen, at_rest) = (word & !1, word & 1 != 0);
        match self.state {
            State::Running => {}
            State::Idle => {
                if !self.q.has_data() {
                    return Ok(Some(Wake::Idle));
                }
                self.shift(now.wrapping_add(self.lead), self.rest_gen);
                pins.enable.set_state(PinState::from(!self.enable_low))?;
                self.stats.starts += 1;
                self.state = State::Running;
            }
            State::Stalled(stall) => {
                if at_rest || is_before(stall, h_gen) {
                    self.shift(now.wrapping_add(self.lead), stall);
                    self.state = State::Running;
                    self.q.set_stalled_at(super::NOT_STALLED);
                }
            }
        }
        Ok(None)
    }

    /// Services every due event at `now` and says when to come back; every STEP fall is an
    /// event of its own or rides along with another ([`NoWait`]).
    #[inline]
    pub fn on_timer<P: OutputPin>(
        &mut self,
        now: u32,
        pins: &mut Pins<P>,
    ) -> Result<Wake, P::Error> {
        self.on_timer_with(now, pins, &mut NoWait)
    }

    /// Services every due event at `now` (read from `timer`'s clock at the call's start) and
    /// says when to come back; STEP pulses raised here usually fall before it returns (see
    /// the module docs), after `timer` reached their end.
    #[inline(never)]
    pub fn on_timer_with<P: OutputPin, T: StepTimer>(
        &mut self,
        now: u32,
        pins: &mut Pins<P>,
        timer: &mut T,
    ) -> Result<Wake, P::Error> {
        let word = self.q.horizon();
        // Stalled still (the pass does not change the state), or at the horizon.
        let mut special = false;
        if self.state != State::Running {
            if let Some(w) = self.wake_up(now, word, pins)? {
                return Ok(w);
            }
            special = self.state != State::Running;
        }
        let at_rest = word & 1 != 0;
        let h_exec = (word & !1).wrapping_add(self.offset);
        let at_horizon = !is_before(now, h_exec);
        special |= at_horizon;
        // The horizon is a wake-up while ahead; events beyond it lose against it, so they
        // need no filtering here (at the horizon, and while stalled, `at_horizon` computes
        // the wake-up).
        let mut ev = Events { wake: h_exec, fall: now, raised: 0 };
        if T::WAITS && self.left_high != 0 {
            self.fall_due(now, pins)?;
        }
        // No step later than the horizon: only a call at or past it can meet one (a due step
        // is not later than `now`); at rest every step is queued.
        if at_horizon && !at_rest {
            self.pass::<true, P, T>(now, h_exec, pins, timer, &mut ev)?;
        } else {
            self.pass::<false, P, T>(now, h_exec, pins, timer, &mut ev)?;
        }
        if T::WAITS && ev.raised != 0 {
            if !is_before(ev.wake, ev.fall) {
                // Nothing else is due before the pulses end (pulses from earlier calls
                // included: their deadlines are in `wake`): end them here.
                timer.wait_until(ev.fall);
                let mut r = ev.raised;
                while r != 0 {
                    pins.step[r.trailing_zeros() as usize & (AXES - 1)].set_low()?;
                    r &= r - 1;
                }
                if self.left_high | self.ended != 0 {
                    ev.wake = self.after_falls(pins, now, ev.fall, ev.wake)?;
                }
            } else {
                ev.wake = self.leave_high(ev.raised, ev.fall, ev.wake);
            }
        }
        if special {
            return Ok(self.at_horizon(now, word));
        }
        Ok(Wake::At(ev.wake))
    }

    /// With a timer: STEP pins left high by earlier calls whose high time has passed at
    /// `now` fall (the pass then sees their axes as after their fall).
    #[inline(never)]
    fn fall_due<P: OutputPin>(&mut self, now: u32, pins: &mut Pins<P>) -> Result<(), P::Error> {
        let mut left = self.left_high;
        while left != 0 {
            let i = left.trailing_zeros() as usize & (AXES - 1);
            left &= left - 1;
            if !is_before(now, self.axes[i].fall_from) {
                self.fall(i, now, pins)?;
                self.left_high &= !(1 << i);
            }
        }
        Ok(())
    }

    /// STEP of `axis`, high, falls at `now` (a direction change held till then is set).
    #[inline]
    fn fall<P: OutputPin>(
        &mut self,
        axis: usize,
        now: u32,
        pins: &mut Pins<P>,
    ) -> Result<(), P::Error> {
        pins.step[axis].set_low()?;
        let a = &mut self.axes[axis];
        a.high = false;
        a.armed = a.active;
        // No direction change since the rise (one held sets it now and ends the sequence):
        // a running sequence's next step rises at `next_at`.
        a.at = a.next_at;
        if let Some(positive) = a.held_dir.take() {
            set_dir(a, &mut pins.dir[axis], positive, self.invert[axis], now)?;
        }
        Ok(())
    }

    /// After the fall at `fall` in the call (with a timer): STEP pins left high by earlier
    /// calls fall too, and the axes whose sequence ended before a direction change set DIR
    /// (held till now) and take their next commands; returns `wake` with their next steps
    /// (recomputed as at the call's start at `now` when pins left high fell: their deadlines
    /// are in `wake` no more). (Values, not `&mut Events`: the call's events stay in
    /// registers.)
    #[inline(never)]
    fn after_falls<P: OutputPin>(
        &mut self,
        pins: &mut Pins<P>,
        now: u32,
        fall: u32,
        mut wake: u32,
    ) -> Result<u32, P::Error> {
        let left = self.left_high != 0;
        let ended = core::mem::take(&mut self.ended);
        self.after_fall::<0, P>(pins, fall, ended, &mut wake)?;
        self.after_fall::<1, P>(pins, fall, ended, &mut wake)?;
        self.after_fall::<2, P>(pins, fall, ended, &mut wake)?;
        self.after_fall::<3, P>(pins, fall, ended, &mut wake)?;
        if left {
            // The horizon (unchanged: the generator does not run during a call) or a poll.
            let h_exec = (self.q.horizon() & !1).wrapping_add(self.offset);
            wake = if is_before(now, h_exec) { h_exec } else { now.wrapping_add(self.poll) };
            for a in &self.axes {
                if a.armed {
                    earliest(&mut wake, a.at);
                }
            }
        }
        Ok(wake)
    }

    /// Axis `A` after the fall at `fall` in the call (see [`Executor::after_falls`]).
    #[inline(always)]
    fn after_fall<const A: usize, P: OutputPin>(
        &mut self,
        pins: &mut Pins<P>,
        fall: u32,
        ended: u32,
        wake: &mut u32,
    ) -> Result<(), P::Error> {
        let bit = 1 << A;
        let a = &mut self.axes[A];
        if self.left_high & bit != 0 {
            pins.step[A].set_low()?;
            self.left_high &= !bit;
            a.high = false;
            a.armed = a.active;
        } else if ended & bit == 0 {
            return Ok(());
        }
        if let Some(positive) = a.held_dir.take() {
            set_dir(a, &mut pins.dir[A], positive, self.invert[A], fall)?;
        }
        // A running sequence's next step rises at `next_at` (no direction change since the
        // rise); a new one's at `at` ([`AxisExec::load`]).
        if a.active {
            a.at = a.next_at;
            earliest(wake, a.at);
        } else if self.q.q[A].ready() && self.take_commands(A, fall, pins)? {
            earliest(wake, self.axes[A].at);
        }
        Ok(())
    }

    /// Another event comes before the pulses `raised` in the call (with a timer) end at
    /// `fall`: they stay high and fall as events, from `fall` on and by their deadline (see
    /// [`Executor`]'s cost notes; one with no sequence running exactly at `fall`). Returns
    /// `wake` with those deadlines.
    #[inline(never)]
    fn leave_high(&mut self, raised: u32, fall: u32, mut wake: u32) -> u32 {
        self.stats.fall_events += 1;
        // Those whose sequence ended take their commands after their fall, in a later pass.
        self.ended = 0;
        for (i, a) in self.axes.iter_mut().enumerate() {
            if raised & (1 << i) == 0 {
                continue;
            }
            a.high = true;
            a.armed = true;
            a.fall_from = fall;
            a.at = fall_deadline(a, fall, self.low_ticks);
            earliest(&mut wake, a.at);
        }
        self.left_high |= raised;
        wake
    }

    /// Stalled, or at the horizon: rest (idle), stall (underrun) or poll; at a rest point
    /// with work left the next event, a poll at the latest.
    #[inline(never)]
    fn at_horizon(&mut self, now: u32, word: u32) -> Wake {
        let (h_gen, at_rest) = (word & !1, word & 1 != 0);
        let h_exec = h_gen.wrapping_add(self.offset);
        let poll = now.wrapping_add(self.poll);
        // The events' wake-up without those beyond the horizon (unless it is a rest point).
        let mut wake = None;
        for a in &self.axes {
            if a.high || (a.active && (at_rest || !is_before(h_exec, a.next_at))) {
                earliest_of(&mut wake, a.at);
            }
        }
        let polled = Wake::At(wake.filter(|&w| is_before(w, poll)).unwrap_or(poll));
        if let State::Stalled(_) = self.state {
            return polled;
        }
        if at_rest {
            if !self.axes.iter().any(|a| a.armed) && !self.q.has_data() {
                self.state = State::Idle;
                self.rest_gen = h_gen;
                return Wake::Idle;
            }
            polled
        } else {
            self.state = State::Stalled(h_gen);
            self.q.set_stalled_at(word);
            self.stats.underruns += 1;
            self.stats.first_underrun_tick.get_or_insert(now);
            polled
        }
    }

    /// Every axis at `now` (no step later than `limit` if `LIMITED`).
    #[inline(always)]
    fn pass<const LIMITED: bool, P: OutputPin, T: StepTimer>(
        &mut self,
        now: u32,
        limit: u32,
        pins: &mut Pins<P>,
        timer: &mut T,
        ev: &mut Events,
    ) -> Result<(), P::Error> {
        self.axis::<0, LIMITED, P, T>(now, limit, pins, timer, ev)?;
        self.axis::<1, LIMITED, P, T>(now, limit, pins, timer, ev)?;
        self.axis::<2, LIMITED, P, T>(now, limit, pins, timer, ev)?;
        self.axis::<3, LIMITED, P, T>(now, limit, pins, timer, ev)
    }

    /// Axis `A`: falling edge, next commands, rising edge; adds its next event to `ev.wake`.
    /// With a timer a pin left high that may fall has fallen before ([`Executor::fall_due`]),
    /// and a rising edge goes to `ev.raised` (and `ev.fall`) with the axis left as after its
    /// fall: the call ends the pulse or marks it high. Without one STEP stays high, left to a
    /// later call.
    #[inline(always)]
    fn axis<const A: usize, const LIMITED: bool, P: OutputPin, T: StepTimer>(
        &mut self,
        now: u32,
        limit: u32,
        pins: &mut Pins<P>,
        timer: &mut T,
        ev: &mut Events,
    ) -> Result<(), P::Error> {
        let mut armed = self.axes[A].armed;
        if !T::WAITS && armed && self.axes[A].high {
            // Without a timer STEP falls here, from its high time on (by `at`).
            if is_before(now, self.axes[A].fall_from) {
                earliest(&mut ev.wake, self.axes[A].at);
                return Ok(());
            }
            self.fall(A, now, pins)?;
            armed = self.axes[A].armed;
        }
        let a = &mut self.axes[A];
        if armed {
            if is_before(now, a.at) {
                // Not yet (or STEP high till then).
                earliest(&mut ev.wake, a.at);
                return Ok(());
            }
        } else if !self.q.q[A].ready() || !self.take_commands(A, now, pins)? {
            // No sequence: the next commands (a direction change is set right away).
            return Ok(());
        } else if is_before(now, self.axes[A].at) {
            earliest(&mut ev.wake, self.axes[A].at);
            return Ok(());
        }
        let a = &mut self.axes[A];
        let due = a.next_at;
        if LIMITED && is_before(limit, due) {
            // Beyond the horizon (which then wakes first).
            earliest(&mut ev.wake, a.at);
            return Ok(());
        }
        if a.dir_fresh {
            a.dir_fresh = false;
            if a.at != due {
                self.stats.late_dir_steps += 1;
            }
        }
        pins.step[A].set_high()?;
        if T::WAITS {
            // The pulse counts from a timer read after the edge.
            ev.fall = timer.now().wrapping_add(self.high_ticks);
            ev.raised |= 1 << A;
            let a = &mut self.axes[A];
            a.remaining -= 1;
            if a.remaining != 0 {
                a.interval = a.interval.wrapping_add(a.add);
                let next = due.wrapping_add(a.interval);
                a.next_at = next;
                a.at = next;
                earliest(&mut ev.wake, next);
            } else {
                match self.sequence_done::<A>(due) {
                    SeqEnd::Chained => earliest(&mut ev.wake, self.axes[A].at),
                    // Set when STEP has fallen ([`Executor::after_falls`]).
                    SeqEnd::DirFirst => self.ended |= 1 << A,
                    SeqEnd::Empty => {}
                }
            }
            return Ok(());
        }
        let fall = now.wrapping_add(self.high_ticks);
        let a = &mut self.axes[A];
        a.remaining -= 1;
        if a.remaining != 0 {
            a.interval = a.interval.wrapping_add(a.add);
            a.next_at = due.wrapping_add(a.interval);
        } else {
            self.sequence_done::<A>(due);
        }
        let a = &mut self.axes[A];
        a.high = true;
        a.armed = true;
        a.fall_from = fall;
        a.at = fall_deadline(a, fall, self.low_ticks);
        earliest(&mut ev.wake, a.at);
        Ok(())
    }

    /// The last step of axis `A`'s sequence (due at `due`) is out: books it and takes the next
    /// commands up to the next sequence unless a direction change comes first (waits and
    /// sequences set no pin, so they need not wait for STEP to fall).
    #[inline(never)]
    fn sequence_done<const A: usize>(&mut self, due: u32) -> SeqEnd {
        let a = &mut self.axes[A];
        a.reference = due;
        self.done[A][a.positive as usize] += a.count as u64;
        let end = loop {
            match self.q.dequeue(A) {
                None => break SeqEnd::Empty,
                Some(StepCmd::Dir(positive)) => {
                    self.axes[A].held_dir = Some(positive);
                    break SeqEnd::DirFirst;
                }
                // A sequence sets `active` (and `armed`) again.
                Some(cmd) => {
                    if self.axes[A].load(cmd, self.setup_ticks) {
                        return SeqEnd::Chained;
                    }
                }
            }
        };
        let a = &mut self.axes[A];
        a.active = false;
        a.armed = false;
        end
    }

    /// Takes the commands of `axis` (no sequence running) at `now` up to the next sequence;
    /// true when one starts.
    #[inline(never)]
    fn take_commands<P: OutputPin>(
        &mut self,
        axis: usize,
        now: u32,
        pins: &mut Pins<P>,
    ) -> Result<bool, P::Error> {
        while let Some(cmd) = self.q.dequeue(axis) {
            if self.command(axis, cmd, now, pins)? {
                return Ok(true);
            }
        }
        Ok(false)
    }

    /// Takes one command of `axis` (no sequence running) at `now`; true when a sequence starts.
    #[inline]
    fn command<P: OutputPin>(
        &mut self,
        axis: usize,
        cmd: StepCmd,
        now: u32,
        pins: &mut Pins<P>,
    ) -> Result<bool, P::Error> {
        let a = &mut self.axes[axis];
        if let StepCmd::Dir(positive) = cmd {
            set_dir(a, &mut pins.dir[axis], positive, self.invert[axis], now)?;
            return Ok(false);
        }
        Ok(a.load(cmd, self.setup_ticks))
    }
}

/// Sets DIR of `a` to `positive` at `now` (`pin` high for positive unless `invert`).
#[inline]
fn set_dir<P: OutputPin>(
    a: &mut AxisExec,
    pin: &mut P,
    positive: bool,
    invert: bool,
    now: u32,
) -> Result<(), P::Error> {
    pin.set_state(PinState::from(positive != invert))?;
    a.positive = positive;
    a.dir_fresh = true;
    a.dir_at = now;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::{SimBoard, SimTiming};
    use crate::step::{pack_horizon, DriverTiming, StepQueue};

    /// Runs the executor on `board` until it idles, stalls or passes `until`; `timed`: with
    /// the board's clock as the [`StepTimer`] (pulses end in the call), else without.
    fn run<O: crate::sim::EdgeObserver, const N: usize>(
        e: &mut Executor<'_, N>,
        b: &SimBoard<O>,
        pins: &mut Pins<crate::sim::SimPin<'_, O>>,
        until: u64,
        timed: bool,
    ) -> Wake {
        loop {
            let w = if timed {
                e.on_timer_with(b.now_u32(), pins, &mut &*b).unwrap()
            } else {
                e.on_timer(b.now_u32(), pins).unwrap()
            };
            match w {
                Wake::At(t) if b.now() < until && !e.is_stalled() => b.advance_to_u32(t),
                _ => return w,
            }
        }
    }

    #[derive(Default)]
    struct Rises(std::vec::Vec<(usize, u64)>);

    impl crate::sim::EdgeObserver for Rises {
        fn on_step(&mut self, axis: usize, _: bool, tick: u64, _: i64) {
            self.0.push((axis, tick));
        }
    }

    #[test]
    fn idle_without_commands_then_exact_sequence_timing() {
        idle_without_commands_then_exact_sequence_timing_in(false);
        idle_without_commands_then_exact_sequence_timing_in(true);
    }

    fn idle_without_commands_then_exact_sequence_timing_in(timed: bool) {
        let cfg = StepConfig::default();
        let board = SimBoard::new(SimTiming::from_config(&cfg), 10, Rises::default());
        let mut pins = board.pins();
        let mut q: StepQueue<8> = StepQueue::new();
        let (mut p, c) = q.split();
        let mut e = Executor::new(&cfg, c);
        assert_eq!(e.on_timer(board.now_u32(), &mut pins).unwrap(), Wake::Idle);
        assert!(!board.enabled());
        p.enqueue(0, StepCmd::Dir(true)).unwrap();
        p.enqueue(0, StepCmd::Steps { interval: 1000, count: 5, add: 100 }).unwrap();
        p.enqueue(0, StepCmd::Wait(5_000)).unwrap();
        p.enqueue(0, StepCmd::Steps { interval: 300, count: 1, add: 0 }).unwrap();
        p.publish(pack_horizon(20_000, true));
        assert_eq!(run(&mut e, &board, &mut pins, u64::MAX, timed), Wake::Idle);
        assert!(board.enabled());
        let t0 = 10 + cfg.start_lead_ticks as u64;
        let got: std::vec::Vec<u64> = board.observer().0.iter().map(|&(_, t)| t - t0).collect();
        assert_eq!(got, [1000, 2100, 3300, 4600, 6000, 11_300]);
        assert_eq!(board.violation_count(), 0);
        assert_eq!(e.position_steps(), [6, 0, 0, 0]);
        assert_eq!(e.stats().starts, 1);
        assert!(e.disable(&mut pins).unwrap());
        assert!(!board.enabled());
    }

    #[test]
    fn late_direction_command_delays_the_step_by_the_setup_time() {
        late_direction_command_delays_the_step_by_the_setup_time_in(false);
        late_direction_command_delays_the_step_by_the_setup_time_in(true);
    }

    fn late_direction_command_delays_the_step_by_the_setup_time_in(timed: bool) {
        let cfg = StepConfig::default();
        let board = SimBoard::new(SimTiming::from_config(&cfg), 0, Rises::default());
        let mut pins = board.pins();
        let mut q: StepQueue<8> = StepQueue::new();
        let (mut p, c) = q.split();
        let mut e = Executor::new(&cfg, c);
        // X keeps the executor busy; Y's commands arrive late.
        p.enqueue(0, StepCmd::Dir(true)).unwrap();
        p.enqueue(0, StepCmd::Steps { interval: 1000, count: 100, add: 0 }).unwrap();
        p.publish(pack_horizon(200_000, false));
        let lead = cfg.start_lead_ticks as u64;
        run(&mut e, &board, &mut pins, lead + 10_000, timed);
        // Now at lead + 10_000 (an X step). Y: first step due in 5 ticks, DIR with it.
        let now_gen = board.now() - lead;
        p.enqueue(1, StepCmd::Dir(true)).unwrap();
        p.enqueue(1, StepCmd::Steps { interval: now_gen as u32 + 5, count: 1, add: 0 }).unwrap();
        run(&mut e, &board, &mut pins, lead + 20_000, timed);
        assert_eq!(e.stats().late_dir_steps, 1);
        assert_eq!(board.violation_count(), 0, "{:?}", board.first_violation());
        let y = board.observer().0.iter().find(|s| s.0 == 1).unwrap().1;
        assert!(y - (lead + now_gen) >= 15, "DIR setup of 200 ns kept");
    }

    #[test]
    fn underrun_stalls_every_axis_and_resumes_with_one_shift() {
        underrun_stalls_every_axis_and_resumes_with_one_shift_in(false);
        underrun_stalls_every_axis_and_resumes_with_one_shift_in(true);
    }

    fn underrun_stalls_every_axis_and_resumes_with_one_shift_in(timed: bool) {
        let cfg = StepConfig::default();
        let board = SimBoard::new(SimTiming::from_config(&cfg), 0, Rises::default());
        let mut pins = board.pins();
        let mut q: StepQueue<8> = StepQueue::new();
        let (mut p, c) = q.split();
        let mut e = Executor::new(&cfg, c);
        p.enqueue(0, StepCmd::Dir(true)).unwrap();
        p.enqueue(0, StepCmd::Steps { interval: 1000, count: 10, add: 0 }).unwrap();
        p.enqueue(1, StepCmd::Dir(false)).unwrap();
        p.enqueue(1, StepCmd::Steps { interval: 1500, count: 10, add: 0 }).unwrap();
        // Queued up to 10_000 for X and 15_000 for Y, but the generator vouches for 9_800 only.
        p.publish(pack_horizon(9_800, false));
        run(&mut e, &board, &mut pins, u64::MAX, timed);
        assert!(e.is_stalled());
        let s = e.stats();
        assert_eq!(s.underruns, 1);
        let lead = cfg.start_lead_ticks as u64;
        assert_eq!(s.first_underrun_tick, Some((lead + 9_800) as u32));
        assert_eq!(e.position_steps(), [9, -6, 0, 0]);
        // Still stalled while nothing new comes: polls.
        let w = e.on_timer(board.now_u32(), &mut pins).unwrap();
        assert_eq!(w, Wake::At(board.now_u32() + cfg.stall_poll_ticks));
        board.advance_to(board.now() + 1_000_000);
        p.publish(pack_horizon(30_000, true));
        assert_eq!(run(&mut e, &board, &mut pins, u64::MAX, timed), Wake::Idle);
        assert_eq!(e.position_steps(), [10, -10, 0, 0]);
        assert_eq!(board.violation_count(), 0);
        // After the stall, both axes continue on their old rhythm, shifted alike.
        let resume = lead + 9_800 + 1_000_000 + lead;
        let steps = &board.observer().0;
        let x10 = steps.iter().filter(|s| s.0 == 0).nth(9).unwrap().1;
        let y7 = steps.iter().filter(|s| s.0 == 1).nth(6).unwrap().1;
        assert_eq!(x10 - resume, 10_000 - 9_800);
        assert_eq!(y7 - resume, 10_500 - 9_800);
    }

    /// Every edge `(pin, high, tick)`.
    #[derive(Default)]
    struct Edges(std::vec::Vec<(crate::sim::PinId, bool, u64)>);

    impl crate::sim::EdgeObserver for Edges {
        fn on_edge(&mut self, e: &crate::sim::Edge) {
            self.0.push((e.pin, e.high, e.tick));
        }
    }

    impl Edges {
        /// `(rise, fall)` ticks of `axis`' STEP pulses.
        fn pulses(&self, axis: u8) -> std::vec::Vec<(u64, u64)> {
            let mut out = std::vec::Vec::new();
            let mut rise = None;
            for &(pin, high, tick) in &self.0 {
                if pin == crate::sim::PinId::Step(axis) {
                    match (high, rise.take()) {
                        (true, None) => rise = Some(tick),
                        (false, Some(r)) => out.push((r, tick)),
                        _ => panic!("STEP of axis {axis}: edge out of order at {tick}"),
                    }
                }
            }
            assert!(rise.is_none(), "axis {axis} ends high");
            out
        }
    }

    /// The rising-edge ticks (from the sequence start) of `(interval, count, add)` sequences
    /// run back to back, each after a wait of the given ticks.
    fn commanded(seqs: &[(u32, u32, u16, i32)]) -> std::vec::Vec<u64> {
        let (mut t, mut out) = (0u64, std::vec::Vec::new());
        for &(wait, interval, count, add) in seqs {
            t += wait as u64;
            let mut iv = interval as i64;
            for _ in 0..count {
                t = (t as i64 + iv) as u64;
                out.push(t);
                iv += add as i64;
            }
        }
        out
    }

    /// Queues the sequences of `commanded` for `axis`, with a direction before each.
    fn queue_seqs<const N: usize>(
        p: &mut crate::step::StepProducer<'_, N>,
        axis: usize,
        seqs: &[(u32, u32, u16, i32)],
        dirs: &[bool],
    ) {
        for (&(wait, interval, count, add), &dir) in seqs.iter().zip(dirs) {
            if wait > 0 {
                p.enqueue(axis, StepCmd::Wait(wait)).unwrap();
            }
            p.enqueue(axis, StepCmd::Dir(dir)).unwrap();
            p.enqueue(axis, StepCmd::Steps { interval, count, add }).unwrap();
        }
    }

    #[test]
    fn pulses_end_in_the_call_that_raises_them() {
        for driver in [DriverTiming::A4988, DriverTiming::TMC2208] {
            let cfg = StepConfig { driver, ..StepConfig::default() };
            let high = cfg.step_high_ticks() as u64;
            let board = SimBoard::new(SimTiming::from_config(&cfg), 7, Edges::default());
            let mut pins = board.pins();
            let mut q: StepQueue<16> = StepQueue::new();
            let (mut p, c) = q.split();
            let mut e = Executor::new(&cfg, c);
            // X: on, reversal at the shortest gap, accelerating; Y decelerating, apart from X.
            let rev = cfg.min_reversal_ticks();
            let x = [(0, 1000, 40, 0), (0, rev, 20, 3), (5_000, 2_000, 10, -7)];
            let y = [(0, 1_517, 30, 11), (0, rev + 1_000, 5, 0)];
            queue_seqs(&mut p, 0, &x, &[true, false, true]);
            queue_seqs(&mut p, 1, &y, &[false, true]);
            p.publish(pack_horizon(200_000, true));
            let mut calls = 0u32;
            loop {
                calls += 1;
                match e.on_timer_with(board.now_u32(), &mut pins, &mut &board).unwrap() {
                    Wake::At(t) => board.advance_to_u32(t),
                    Wake::Idle => break,
                }
            }
            assert_eq!(board.violation_count(), 0, "{:?}", board.first_violation());
            let t0 = 7 + cfg.start_lead_ticks as u64;
            let edges = board.observer();
            let all = [edges.pulses(0), edges.pulses(1)];
            for (axis, seqs) in [(0u8, &x[..]), (1, &y[..])] {
                let pulses = &all[axis as usize];
                let rises: std::vec::Vec<u64> = pulses.iter().map(|p| p.0 - t0).collect();
                assert_eq!(rises, commanded(seqs), "axis {axis}: every rise at its tick");
                // Each falls exactly at the driver's high time, unless the other axis rose
                // during it: then both fall at the end of the later pulse.
                let other = &all[1 - axis as usize];
                for &(r, f) in pulses {
                    match other.iter().find(|o| o.0 > r && o.0 < r + high) {
                        None => assert_eq!(f - r, high, "axis {axis} at {r}"),
                        Some(&(_, f2)) => assert_eq!(f, f2, "axis {axis} at {r}"),
                    }
                }
            }
            // DIR changes at the fall of a sequence's last pulse, the setup time before
            // the next rise at least (the board checks it; here: it happened at a fall).
            for &(pin, _, tick) in edges.0.iter() {
                if let crate::sim::PinId::Dir(a) = pin {
                    let falls = edges.pulses(a);
                    assert!(
                        tick <= t0 || falls.iter().any(|&(_, f)| f == tick),
                        "DIR of {a} at {tick}"
                    );
                }
            }
            // One call per step, the start and a last poll; a crowded pulse (left high) may
            // cost one more, at its fall deadline.
            let s = e.stats();
            let steps = s.steps.iter().sum::<u64>() as u32;
            assert_eq!(steps, 70 + 35);
            assert!(s.fall_events <= 10, "{s:?}");
            assert!(calls <= steps + 2 + s.fall_events, "{calls} calls for {steps} steps");
        }
    }

    #[test]
    fn crowded_pulses_fall_as_events_and_keep_their_times() {
        let cfg = StepConfig::default();
        let board = SimBoard::new(SimTiming::from_config(&cfg), 0, Edges::default());
        let mut pins = board.pins();
        let mut q: StepQueue<16> = StepQueue::new();
        let (mut p, c) = q.split();
        let mut e = Executor::new(&cfg, c);
        // Y's steps come 30 ticks after X's (inside X's pulse of 72 ticks), Z's 1 to 120
        // ticks after X's.
        let x = [(0, 1_000, 80, 0)];
        let y = [(30, 1_000, 80, 0)];
        let z = [(0, 1_001, 15, 1)];
        queue_seqs(&mut p, 0, &x, &[true]);
        queue_seqs(&mut p, 1, &y, &[true]);
        queue_seqs(&mut p, 2, &z, &[false]);
        p.publish(pack_horizon(100_000, true));
        assert_eq!(run(&mut e, &board, &mut pins, u64::MAX, true), Wake::Idle);
        assert_eq!(board.violation_count(), 0, "{:?}", board.first_violation());
        let t0 = cfg.start_lead_ticks as u64;
        let edges = board.observer();
        for (axis, seqs) in [(0u8, &x[..]), (1, &y[..]), (2, &z[..])] {
            let pulses = edges.pulses(axis);
            let rises: std::vec::Vec<u64> = pulses.iter().map(|p| p.0 - t0).collect();
            assert_eq!(rises, commanded(seqs));
            assert!(pulses.iter().all(|&(r, f)| f - r >= 72));
        }
        let s = e.stats();
        assert!(s.fall_events >= 80, "{s:?}");
        assert_eq!(s.steps, [80, 80, 15, 0]);
    }

    /// Queues `seqs` of `commanded` for `axis`, a direction before a sequence only where
    /// `dirs` changes (and before the first), so sequences of one direction follow each
    /// other directly.
    fn queue_runs<const N: usize>(
        p: &mut crate::step::StepProducer<'_, N>,
        axis: usize,
        seqs: &[(u32, u32, u16, i32)],
        dirs: &[bool],
    ) {
        for (i, (&(wait, interval, count, add), &dir)) in seqs.iter().zip(dirs).enumerate() {
            if wait > 0 {
                p.enqueue(axis, StepCmd::Wait(wait)).unwrap();
            }
            if i == 0 || dirs[i - 1] != dir {
                p.enqueue(axis, StepCmd::Dir(dir)).unwrap();
            }
            p.enqueue(axis, StepCmd::Steps { interval, count, add }).unwrap();
        }
    }

    #[test]
    fn sequences_follow_at_the_last_step_and_directions_at_its_fall() {
        let cfg = StepConfig::default();
        let high = cfg.step_high_ticks() as u64;
        let rev = cfg.min_reversal_ticks();
        // X: runs of one direction (one after a wait), then reversals at the shortest gap.
        let x = [
            (0, 1_000, 5, 0),
            (0, 900, 4, 10),
            (2_000, 800, 3, 0),
            (0, rev, 5, 0),
            (0, rev, 3, 7),
            (0, 600, 2, 0),
        ];
        let x_dirs = [true, true, true, false, true, true];
        // Y: X's steps 30 ticks later (inside X's pulses), so every pulse is crowded.
        let mut y = x;
        y[0].0 = 30;
        let x_steps: u64 = x.iter().map(|s| s.2 as u64).sum();
        let signed: i64 =
            x.iter().zip(&x_dirs).map(|(s, &d)| if d { 1 } else { -1 } * s.2 as i64).sum();
        for (crowded, timed) in [(false, true), (true, true), (false, false), (true, false)] {
            let board = SimBoard::new(SimTiming::from_config(&cfg), 0, Edges::default());
            let mut pins = board.pins();
            let mut q: StepQueue<32> = StepQueue::new();
            let (mut p, c) = q.split();
            let mut e = Executor::new(&cfg, c);
            queue_runs(&mut p, 0, &x, &x_dirs);
            if crowded {
                queue_runs(&mut p, 1, &y, &x_dirs);
            }
            p.publish(pack_horizon(100_000, true));
            let mut calls = 0u32;
            loop {
                calls += 1;
                let w = if timed {
                    e.on_timer_with(board.now_u32(), &mut pins, &mut &board).unwrap()
                } else {
                    e.on_timer(board.now_u32(), &mut pins).unwrap()
                };
                match w {
                    Wake::At(t) => board.advance_to_u32(t),
                    Wake::Idle => break,
                }
            }
            let what = format!("crowded {crowded}, timed {timed}");
            assert_eq!(board.violation_count(), 0, "{what}: {:?}", board.first_violation());
            let t0 = cfg.start_lead_ticks as u64;
            let edges = board.observer();
            for (axis, seqs) in [(0u8, &x), (1, &y)].into_iter().take(1 + crowded as usize) {
                let pulses = edges.pulses(axis);
                let rises: std::vec::Vec<u64> = pulses.iter().map(|p| p.0 - t0).collect();
                assert_eq!(rises, commanded(seqs), "{what}: axis {axis}, every rise at its tick");
                for &(r, f) in &pulses {
                    assert!(f - r >= high, "{what}: axis {axis} pulse at {r}");
                    if timed && !crowded {
                        assert_eq!(f - r, high, "{what}: the pulse ends in its call");
                    }
                }
                // DIR changes only when the last pulse before it has fallen, before the next
                // rise (the board checks the setup time).
                for &(pin, _, tick) in &edges.0 {
                    if pin == crate::sim::PinId::Dir(axis) && tick > t0 {
                        let before = pulses.iter().rfind(|p| p.0 < tick).unwrap();
                        assert!(before.1 <= tick, "{what}: DIR of {axis} at {tick} during a pulse");
                        if !crowded {
                            assert_eq!(before.1, tick, "{what}: DIR of {axis} at the fall");
                        }
                    }
                }
            }
            let mut want = [x_steps, 0, 0, 0];
            let mut pos = [signed, 0, 0, 0];
            if crowded {
                want[1] = x_steps;
                pos[1] = signed;
            }
            assert_eq!(e.stats().steps, want, "{what}");
            assert_eq!(e.position_steps(), pos, "{what}");
            if timed && !crowded {
                // One call per step, the start and the rest: the next sequence and a
                // direction change need no call of their own.
                assert!(calls as u64 <= x_steps + 2, "{what}: {calls} calls");
            }
        }
    }

    /// A board clock that moves on by `per_read` ticks at every read, as a real one does
    /// while the interrupt runs: rises come late, and pulses must still be long enough.
    struct SlowTimer<'b, O> {
        board: &'b SimBoard<O>,
        per_read: u64,
    }

    impl<O: crate::sim::EdgeObserver> StepTimer for SlowTimer<'_, O> {
        fn now(&mut self) -> u32 {
            self.board.advance_to(self.board.now() + self.per_read);
            self.board.now_u32()
        }
    }

    #[test]
    fn pulses_count_from_the_timer_read_after_the_edge() {
        let cfg = StepConfig::default();
        let board = SimBoard::new(SimTiming::from_config(&cfg), 0, Edges::default());
        let mut pins = board.pins();
        let mut q: StepQueue<16> = StepQueue::new();
        let (mut p, c) = q.split();
        let mut e = Executor::new(&cfg, c);
        queue_seqs(&mut p, 0, &[(0, 1_000, 30, 0)], &[true]);
        queue_seqs(&mut p, 1, &[(0, 1_010, 30, 0)], &[true]);
        queue_seqs(&mut p, 3, &[(0, 1_003, 30, 0)], &[false]);
        p.publish(pack_horizon(100_000, true));
        let mut timer = SlowTimer { board: &board, per_read: 5 };
        loop {
            // The call starts a little late, as an interrupt does.
            let now = timer.now();
            match e.on_timer_with(now, &mut pins, &mut timer).unwrap() {
                Wake::At(t) => board.advance_to_u32(t),
                Wake::Idle => break,
            }
        }
        let v = board.violations();
        let short = v[crate::sim::ViolationKind::PulseTooShort as usize];
        assert_eq!(short, 0, "{:?}", board.first_violation());
        for axis in [0, 1, 3] {
            let pulses = board.observer().pulses(axis);
            assert_eq!(pulses.len(), 30);
            assert!(pulses.iter().all(|&(r, f)| f - r >= 72), "axis {axis}: {pulses:?}");
        }
    }
}
