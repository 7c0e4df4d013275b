//! Shared helpers of the motion tests: run whole jobs through planner, step generator,
//! executor and the simulated board, record every edge and step, and compare with an
//! independent `f64` reference trajectory.
#![allow(dead_code)] // every test crate uses a different subset
#![allow(clippy::needless_range_loop)] // axis-indexed loops read best as such

pub mod measure;
pub mod reference;

use strata::machine::{MachineConfig, Rate, AXES};
use strata::plan::{Block, Move, MoveKind, PlanConfig, PlanError, Planner};
use strata::sim::{Edge, EdgeObserver, SimBoard, SimTiming};
use strata::step::{
    ExecStats, Executor, GenStats, GenStatus, StepConfig, StepGenerator, StepQueue, Wake,
};

/// One recorded step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepRec {
    /// Board tick of the rising edge.
    pub tick: u64,
    /// Positive direction.
    pub positive: bool,
    /// Position after the step.
    pub position: i64,
}

/// Records every edge and every step (std only).
#[derive(Debug, Default)]
pub struct Recorder {
    pub edges: Vec<Edge>,
    pub steps: [Vec<StepRec>; AXES],
}

impl EdgeObserver for Recorder {
    fn on_edge(&mut self, edge: &Edge) {
        self.edges.push(*edge);
    }
    fn on_step(&mut self, axis: usize, positive: bool, tick: u64, position: i64) {
        self.steps[axis].push(StepRec { tick, positive, position });
    }
}

/// Everything a job runs with.
#[derive(Debug, Clone, Copy)]
pub struct JobConfig {
    pub machine: MachineConfig,
    pub plan: PlanConfig,
    pub step: StepConfig,
    /// Board tick at the start.
    pub start_tick: u64,
    /// Start position X, Y, Z, E in um.
    pub start_um: [i32; AXES],
}

impl Default for JobConfig {
    fn default() -> Self {
        let machine = MachineConfig::default();
        Self {
            machine,
            plan: PlanConfig::from_machine(&machine),
            step: StepConfig::from_machine(&machine),
            start_tick: 1_000,
            start_um: [0; AXES],
        }
    }
}

/// What a job produced.
#[derive(Debug)]
pub struct JobResult {
    pub rec: Recorder,
    pub blocks: Vec<Block>,
    /// Planner's print-time estimate (sum of the released blocks), seconds.
    pub planned_s: f64,
    /// Board tick of generator tick 0 (at the first start).
    pub gen0_tick: u64,
    /// Board tick at which the executor went idle at the end.
    pub end_tick: u64,
    /// Executor offset (executor tick of generator tick 0) at the end; differs from the
    /// start's after a stall or a restart.
    pub final_offset: u32,
    pub gen: GenStats,
    pub exec: ExecStats,
    pub positions: [i64; AXES],
    pub exec_positions: [i64; AXES],
    pub motor: [i64; AXES],
    pub violations: u32,
    pub first_violation: Option<strata::sim::Violation>,
    pub hash: u64,
    pub min_high: Option<u64>,
    pub min_low: Option<u64>,
    pub min_setup: Option<u64>,
    /// `on_timer` calls.
    pub wakes: u64,
}

impl JobResult {
    /// Ticks per second.
    pub fn hz(&self, cfg: &JobConfig) -> f64 {
        cfg.step.timer_hz as f64
    }
    /// Board tick of the last step edge of any axis.
    pub fn last_step_tick(&self) -> Option<u64> {
        self.rec.steps.iter().filter_map(|s| s.last().map(|r| r.tick)).max()
    }
}

/// Runs `moves` through a planner with `P` moves of lookahead, a step queue of `Q` commands
/// per axis and the simulated board, feeding the generator as far ahead as the queues allow.
/// `throttle` (if any) is called before each generator run and may return `false` to starve
/// the generator (underrun tests).
pub fn run_job_with<const P: usize, const Q: usize>(
    moves: &[Move],
    cfg: &JobConfig,
    mut throttle: impl FnMut(u64) -> bool,
) -> JobResult {
    let board =
        SimBoard::new(SimTiming::from_config(&cfg.step), cfg.start_tick, Recorder::default());
    let mut pins = board.pins();
    let mut planner: Planner<P> = Planner::new(&cfg.plan, cfg.start_um);
    let mut queue: StepQueue<Q> = StepQueue::new();
    let (mut prod, cons) = queue.split();
    let mut gen: StepGenerator = StepGenerator::new(&cfg.step, cfg.start_um);
    let mut exec = Executor::new(&cfg.step, cons);
    let mut next = 0usize;
    let mut blocks = Vec::new();
    let mut gen0_tick = None;
    let mut wakes = 0u64;
    let mut guard = 0u64;
    let end_tick = loop {
        guard += 1;
        assert!(guard < 200_000_000, "job does not finish");
        while next < moves.len() {
            match planner.push(moves[next]) {
                Ok(()) => next += 1,
                Err(PlanError::QueueFull) => break,
                Err(e) => panic!("move {next} refused: {e}"),
            }
        }
        let input_done = next == moves.len();
        while gen.wants_block() {
            let b =
                if input_done || planner.is_full() { planner.pop_forced() } else { planner.pop() };
            match b {
                Some(b) => {
                    blocks.push(b);
                    gen.load(b).unwrap();
                }
                None => break,
            }
        }
        if throttle(board.now()) {
            let _: GenStatus = gen.run(&mut prod);
        }
        // The board's clock as the step timer: pulses end in the call that raises them.
        let wake = exec.on_timer_with(board.now_u32(), &mut pins, &mut &board).unwrap();
        wakes += 1;
        if gen0_tick.is_none() && !exec.is_idle() {
            let off = exec.offset();
            let d = off.wrapping_sub(cfg.start_tick as u32) as i32 as i64;
            gen0_tick = Some((cfg.start_tick as i64 + d) as u64);
        }
        match wake {
            Wake::At(t) => board.advance_to_u32(t),
            Wake::Idle => {
                if input_done && planner.is_empty() && gen.is_idle() {
                    break board.now();
                }
            }
        }
    };
    let axes = board.axes();
    let min = |f: fn(&strata::sim::AxisRecord) -> Option<u64>| axes.iter().filter_map(f).min();
    JobResult {
        planned_s: planner.released_ticks_q16() as f64 / 65536.0 / cfg.plan.timer_hz as f64,
        gen0_tick: gen0_tick.unwrap_or(cfg.start_tick),
        end_tick,
        final_offset: exec.offset(),
        gen: gen.stats(),
        exec: exec.stats(),
        positions: board.positions(),
        exec_positions: exec.position_steps(),
        motor: gen.motor_steps(),
        violations: board.violation_count(),
        first_violation: board.first_violation(),
        hash: board.step_hash(),
        min_high: min(|a| a.min_high_seen),
        min_low: min(|a| a.min_low_seen),
        min_setup: min(|a| a.min_setup_seen),
        wakes,
        blocks,
        rec: board.into_observer(),
    }
}

/// [`run_job_with`] without throttling, 32 moves of lookahead, 64-slot step queues.
pub fn run_job(moves: &[Move], cfg: &JobConfig) -> JobResult {
    run_job_with::<32, 64>(moves, cfg, |_| true)
}

/// mm/s as a `Rate`.
pub fn mm_s(v: f64) -> Rate {
    Rate::from_num(v)
}

/// A move to (x, y, z, e) in um.
pub fn mv(target: [i32; 4], feed: f64, kind: MoveKind) -> Move {
    Move::new(target, mm_s(feed), kind)
}

/// Asserts the result is clean: no timing violation, no underrun, one start, final
/// positions equal to what the commanded positions give, nothing clamped or failed.
pub fn assert_clean(r: &JobResult, cfg: &JobConfig, moves: &[Move]) {
    assert_eq!(r.violations, 0, "timing violation: {:?}", r.first_violation);
    assert_eq!(r.exec.underruns, 0, "underrun");
    assert_eq!(r.exec.starts, 1, "the executor restarted");
    assert_eq!(r.gen.check_failures, 0);
    assert_eq!(r.gen.clamped, 0, "steps clamped to driver limits");
    let expect = reference::expected_positions(moves, cfg);
    let start = reference::start_steps(cfg);
    let board: [i64; AXES] = std::array::from_fn(|a| r.positions[a] + start[a]);
    assert_eq!(board, expect, "board positions vs commanded");
    assert_eq!(r.motor, expect, "generator motor positions vs commanded");
    let exec: [i64; AXES] = std::array::from_fn(|a| r.exec_positions[a] + start[a]);
    assert_eq!(exec, expect, "executor positions vs commanded");
}
