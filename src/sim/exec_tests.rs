//! The step executor on the simulated board: exact step times, driver timing, underruns,
//! direction setup and enable handling, checked edge by edge.

use super::{SimBoard, SimTiming};
use crate::step::{is_before, pack_horizon, DriverTiming, StepQueue};
use crate::step::{Executor, Pins, StepCmd, StepConfig, StepTimer, Wake};

/// The rig of a test: `board` (timing of `cfg`, clock at `start`, `observer`), its `pins`, the
/// producer `p` of an `N`-command step queue and the executor `e` on its consumer.
macro_rules! rig {
    ($cfg:expr, $start:expr, $observer:expr, $n:literal => $board:ident, $pins:ident, $p:ident, $e:ident) => {
        let $board = SimBoard::new(SimTiming::from_config(&$cfg), $start, $observer);
        let mut $pins = $board.pins();
        let mut queue: StepQueue<$n> = StepQueue::new();
        let (mut $p, consumer) = queue.split();
        let mut $e = Executor::new(&$cfg, consumer);
    };
}

/// Runs the executor on `board` until it idles, stalls or passes `until`; `timed`: with
/// the board's clock as the [`StepTimer`] (pulses end in the call), else without.
fn run<O: super::EdgeObserver, const N: usize>(
    e: &mut Executor<'_, N>,
    b: &SimBoard<O>,
    pins: &mut Pins<super::SimPin<'_, O>>,
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

impl super::EdgeObserver for Rises {
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
    rig!(cfg, 10, Rises::default(), 8 => board, pins, p, e);
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
    rig!(cfg, 0, Rises::default(), 8 => board, pins, p, e);
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
    rig!(cfg, 0, Rises::default(), 8 => board, pins, p, e);
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
struct Edges(std::vec::Vec<(super::PinId, bool, u64)>);

impl super::EdgeObserver for Edges {
    fn on_edge(&mut self, e: &super::Edge) {
        self.0.push((e.pin, e.high, e.tick));
    }
}

impl Edges {
    /// `(rise, fall)` ticks of `axis`' STEP pulses.
    fn pulses(&self, axis: u8) -> std::vec::Vec<(u64, u64)> {
        let mut out = std::vec::Vec::new();
        let mut rise = None;
        for &(pin, high, tick) in &self.0 {
            if pin == super::PinId::Step(axis) {
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
        rig!(cfg, 7, Edges::default(), 16 => board, pins, p, e);
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
            if let super::PinId::Dir(a) = pin {
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
    rig!(cfg, 0, Edges::default(), 16 => board, pins, p, e);
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
        rig!(cfg, 0, Edges::default(), 32 => board, pins, p, e);
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
                if pin == super::PinId::Dir(axis) && tick > t0 {
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

impl<O: super::EdgeObserver> StepTimer for SlowTimer<'_, O> {
    fn now(&mut self) -> u32 {
        self.board.advance_to(self.board.now() + self.per_read);
        self.board.now_u32()
    }
}

#[test]
fn pulses_count_from_the_timer_read_after_the_edge() {
    let cfg = StepConfig::default();
    rig!(cfg, 0, Edges::default(), 16 => board, pins, p, e);
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
    let short = v[super::ViolationKind::PulseTooShort as usize];
    assert_eq!(short, 0, "{:?}", board.first_violation());
    for axis in [0, 1, 3] {
        let pulses = board.observer().pulses(axis);
        assert_eq!(pulses.len(), 30);
        assert!(pulses.iter().all(|&(r, f)| f - r >= 72), "axis {axis}: {pulses:?}");
    }
}

/// Runs a reversal at the shortest gap the generator leaves ([`StepConfig::min_reversal_ticks`])
/// with every call entered `lag` ticks after its tick (the board's clock, and so its edges,
/// run late; the executor is told the tick); returns the driver timing violations, the late
/// DIR steps and the rises, less the lag.
fn reversal_with_edge_lag(lag: u64) -> (u32, u32, std::vec::Vec<u64>) {
    let cfg = StepConfig::default();
    rig!(cfg, 0, Edges::default(), 16 => board, pins, p, e);
    let rev = cfg.min_reversal_ticks();
    queue_seqs(&mut p, 0, &[(0, 1_000, 3, 0), (0, rev, 3, 0)], &[true, false]);
    p.publish(pack_horizon(100_000, true));
    let mut tick = board.now_u32();
    loop {
        board.advance_to(tick as u64 + lag);
        match e.on_timer_with(tick, &mut pins, &mut &board).unwrap() {
            Wake::At(t) => tick = t,
            Wake::Idle => break,
        }
    }
    let rises = board.observer().pulses(0).iter().map(|p| p.0 - lag).collect();
    (board.violation_count(), e.stats().late_dir_steps, rises)
}

#[test]
fn edges_as_late_as_the_latency_allowance_keep_a_reversal_on_time() {
    let cfg = StepConfig::default();
    let lead = cfg.start_lead_ticks as u64;
    let rev = cfg.min_reversal_ticks() as u64;
    // Three steps 1,000 ticks apart, then three back `rev` apart.
    let want: std::vec::Vec<u64> =
        [1_000, 2_000, 3_000, 3_000 + rev, 3_000 + 2 * rev, 3_000 + 3 * rev]
            .iter()
            .map(|t| t + lead)
            .collect();
    let allowed = cfg.edge_latency_ticks() as u64;
    for lag in [0, allowed / 2, allowed] {
        assert_eq!(reversal_with_edge_lag(lag), (0, 0, want.clone()), "edges {lag} ticks late");
    }
    // Beyond the allowance, DIR's setup after the late fall delays the first step back.
    let (_, late, rises) = reversal_with_edge_lag(allowed + 100);
    assert_eq!(late, 1);
    assert!(rises[3] > want[3], "{rises:?}");
}

#[test]
fn a_direction_change_taken_at_the_horizon_keeps_its_step_on_time() {
    let cfg = StepConfig::default();
    rig!(cfg, 0, Edges::default(), 16 => board, pins, p, e);
    // Y steps up three times; the generator's next step for it goes down, due at `exact`,
    // and bounds the horizon it publishes.
    let exact = 8_000;
    queue_seqs(&mut p, 1, &[(0, 1_000, 3, 0)], &[true]);
    p.publish(pack_horizon((exact - cfg.horizon_margin_ticks()) as u64, false));
    // The executor runs up to the horizon, Y idle since its last step, and waits there
    // (the accelerated board's clock: the call due there is made once it has moved on).
    let mut tick = board.now_u32();
    let wake = loop {
        board.advance_to_u32(tick);
        match e.on_timer_with(tick, &mut pins, &mut &board).unwrap() {
            Wake::At(t) if is_before(t, e.horizon().0) => tick = t,
            w => break w,
        }
    };
    let Wake::At(wake) = wake else { panic!("the executor idled at {tick}") };
    // The step back, compressed as early as the error bound lets it run, and the rest.
    let early = exact - cfg.max_error_ticks;
    p.enqueue(1, StepCmd::Dir(false)).unwrap();
    p.enqueue(1, StepCmd::Steps { interval: early - 3_000, count: 1, add: 0 }).unwrap();
    p.publish(pack_horizon(100_000, true));
    let mut tick = wake;
    loop {
        board.advance_to_u32(tick);
        match e.on_timer_with(tick, &mut pins, &mut &board).unwrap() {
            Wake::At(t) => tick = t,
            Wake::Idle => break,
        }
    }
    assert_eq!(board.violation_count(), 0, "{:?}", board.first_violation());
    assert_eq!(e.stats().late_dir_steps, 0, "the step back waited for DIR");
    let lead = cfg.start_lead_ticks as u64;
    let rises: std::vec::Vec<u64> = board.observer().pulses(1).iter().map(|p| p.0).collect();
    assert_eq!(rises, [1_000, 2_000, 3_000, early as u64].map(|t| t + lead));
}
