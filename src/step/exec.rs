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
    /// an underrun-late direction command, or a rising edge later after its tick than
    /// [`StepConfig::edge_latency_ns`]).
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
