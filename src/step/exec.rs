//! The step executor: runs in the step timer interrupt, integer adds and compares only.
//!
//! Per axis it holds the running sequence (`next`, `interval`, `add`, `remaining`). At a due
//! step it raises STEP, schedules the falling edge `step_high` later, and advances with
//! `interval += add; next += interval`. After the falling edge of a sequence's last step it
//! takes the next commands: a direction change sets DIR right then, which is at least the
//! driver's setup time before the next rising edge because the generator keeps that gap
//! ([`StepConfig::min_reversal_ticks`]). Times are wrapping `u32` ticks compared with
//! [`is_before`].
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
}

#[derive(Debug, Clone, Copy, Default)]
struct AxisExec {
    /// STEP is high; falls at `fall_at`.
    high: bool,
    fall_at: u32,
    /// A sequence is running; its next step is at `next_at`.
    active: bool,
    next_at: u32,
    interval: u32,
    add: i32,
    remaining: u16,
    /// Time of the last step (or the end of the last wait): sequences count from here.
    reference: u32,
    /// DIR changed at `dir_at` and no step has followed yet.
    dir_fresh: bool,
    dir_at: u32,
    /// Current direction is positive.
    positive: bool,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum State {
    Idle,
    Running,
    /// Waiting for the horizon to pass this generator time.
    Stalled(u32),
}

/// Drives the pins from a [`StepConsumer`].
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
    setup_ticks: u32,
    lead: u32,
    poll: u32,
    invert: [bool; AXES],
    enable_low: bool,
    position: [i64; AXES],
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
            setup_ticks: config.ns_to_ticks(config.driver.dir_setup_ns),
            lead: config.start_lead_ticks.max(config.ns_to_ticks(config.driver.dir_setup_ns)),
            poll: config.stall_poll_ticks.max(1),
            invert: config.invert_dir,
            enable_low: config.enable_active_low,
            position: [0; AXES],
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

    /// Steps executed per axis, signed by direction, since creation.
    pub fn position_steps(&self) -> [i64; AXES] {
        self.position
    }

    /// Counters.
    pub fn stats(&self) -> ExecStats {
        self.stats
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
        for a in &mut self.axes {
            a.reference = a.reference.wrapping_add(delta);
            a.next_at = a.next_at.wrapping_add(delta);
        }
        self.offset = offset;
    }

    /// Services every due event at `now` and says when to come back.
    pub fn on_timer<P: OutputPin>(
        &mut self,
        now: u32,
        pins: &mut Pins<P>,
    ) -> Result<Wake, P::Error> {
        let word = self.q.horizon();
        let (h_gen, at_rest) = (word & !1, word & 1 != 0);
        match self.state {
            State::Running => {}
            State::Idle => {
                if !self.q.has_data() {
                    return Ok(Wake::Idle);
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
        let h_exec = h_gen.wrapping_add(self.offset);
        let mut wake: Option<u32> = None;
        let mut busy = false;
        for axis in 0..AXES {
            if let Some(t) = self.service(axis, now, h_exec, at_rest, pins)? {
                wake = Some(match wake {
                    Some(w) if is_before(w, t) => w,
                    _ => t,
                });
            }
            busy |= self.axes[axis].high || self.axes[axis].active;
        }
        let at_horizon = !is_before(now, h_exec);
        if let State::Stalled(_) = self.state {
            let poll = now.wrapping_add(self.poll);
            return Ok(Wake::At(wake.filter(|&w| is_before(w, poll)).unwrap_or(poll)));
        }
        if at_horizon {
            if at_rest {
                if !busy && !self.q.has_data() {
                    self.state = State::Idle;
                    self.rest_gen = h_gen;
                    return Ok(Wake::Idle);
                }
            } else {
                self.state = State::Stalled(h_gen);
                self.q.set_stalled_at(word);
                self.stats.underruns += 1;
                self.stats.first_underrun_tick.get_or_insert(now);
                let poll = now.wrapping_add(self.poll);
                return Ok(Wake::At(wake.filter(|&w| is_before(w, poll)).unwrap_or(poll)));
            }
        }
        let horizon_wake = if at_horizon { None } else { Some(h_exec) };
        Ok(Wake::At(match (wake, horizon_wake) {
            (Some(w), Some(h)) => {
                if is_before(h, w) {
                    h
                } else {
                    w
                }
            }
            (Some(w), None) => w,
            (None, Some(h)) => h,
            (None, None) => now.wrapping_add(self.poll),
        }))
    }

    /// One axis: falling edge, next commands, rising edge; returns its next event time.
    #[inline]
    fn service<P: OutputPin>(
        &mut self,
        axis: usize,
        now: u32,
        h_exec: u32,
        at_rest: bool,
        pins: &mut Pins<P>,
    ) -> Result<Option<u32>, P::Error> {
        let a = &mut self.axes[axis];
        if a.high {
            if is_before(now, a.fall_at) {
                return Ok(Some(a.fall_at));
            }
            pins.step[axis].set_low()?;
            a.high = false;
        }
        while !a.active {
            match self.q.dequeue(axis) {
                None => return Ok(None),
                Some(StepCmd::Dir(positive)) => {
                    pins.dir[axis].set_state(PinState::from(positive != self.invert[axis]))?;
                    a.positive = positive;
                    a.dir_fresh = true;
                    a.dir_at = now;
                }
                Some(StepCmd::Wait(ticks)) => a.reference = a.reference.wrapping_add(ticks),
                Some(StepCmd::Steps { interval, count, add }) => {
                    if count > 0 {
                        a.interval = interval;
                        a.add = add;
                        a.remaining = count;
                        a.next_at = a.reference.wrapping_add(interval);
                        a.active = true;
                    }
                }
            }
        }
        let due = a.next_at;
        if !at_rest && is_before(h_exec, due) {
            // Beyond the horizon: the horizon wake-up covers it. (At rest everything is
            // queued already.)
            return Ok(None);
        }
        let mut fire_at = due;
        if a.dir_fresh {
            let ready = a.dir_at.wrapping_add(self.setup_ticks);
            if is_before(due, ready) {
                fire_at = ready;
            }
        }
        if is_before(now, fire_at) {
            return Ok(Some(fire_at));
        }
        if fire_at != due {
            self.stats.late_dir_steps += 1;
        }
        pins.step[axis].set_high()?;
        a.high = true;
        a.dir_fresh = false;
        a.fall_at = now.wrapping_add(self.high_ticks);
        a.reference = due;
        self.stats.steps[axis] += 1;
        self.position[axis] += if a.positive { 1 } else { -1 };
        a.remaining -= 1;
        if a.remaining > 0 {
            a.interval = a.interval.wrapping_add(a.add as u32);
            a.next_at = due.wrapping_add(a.interval);
        } else {
            a.active = false;
        }
        Ok(Some(a.fall_at))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::{SimBoard, SimTiming};
    use crate::step::{pack_horizon, StepQueue};

    /// Runs the executor on `board` until it idles, stalls or passes `until`.
    fn run<O: crate::sim::EdgeObserver, const N: usize>(
        e: &mut Executor<'_, N>,
        b: &SimBoard<O>,
        pins: &mut Pins<crate::sim::SimPin<'_, O>>,
        until: u64,
    ) -> Wake {
        loop {
            let w = e.on_timer(b.now_u32(), pins).unwrap();
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
        assert_eq!(run(&mut e, &board, &mut pins, u64::MAX), Wake::Idle);
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
        run(&mut e, &board, &mut pins, lead + 10_000);
        // Now at lead + 10_000 (an X step). Y: first step due in 5 ticks, DIR with it.
        let now_gen = board.now() - lead;
        p.enqueue(1, StepCmd::Dir(true)).unwrap();
        p.enqueue(1, StepCmd::Steps { interval: now_gen as u32 + 5, count: 1, add: 0 }).unwrap();
        run(&mut e, &board, &mut pins, lead + 20_000);
        assert_eq!(e.stats().late_dir_steps, 1);
        assert_eq!(board.violation_count(), 0, "{:?}", board.first_violation());
        let y = board.observer().0.iter().find(|s| s.0 == 1).unwrap().1;
        assert!(y - (lead + now_gen) >= 15, "DIR setup of 200 ns kept");
    }

    #[test]
    fn underrun_stalls_every_axis_and_resumes_with_one_shift() {
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
        run(&mut e, &board, &mut pins, u64::MAX);
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
        assert_eq!(run(&mut e, &board, &mut pins, u64::MAX), Wake::Idle);
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
}
