//! The executor catching up with the generator, as on the accelerated QEMU board: its clock
//! waits at the horizon and makes the call due there once the horizon has moved past it. A
//! direction change then reaches an axis the executor left idle as late as the horizon, and
//! its setup time must still end before the step after it: every step rises at the tick of
//! a run where the generator is always ahead, and none waits for DIR.

mod motion_support;

use motion_support::{mv, run_job_with, JobConfig, Recorder};
use strata::plan::MoveKind::{Print, Retract, Travel};
use strata::plan::{Move, PlanError, Planner};
use strata::sim::{SimBoard, SimTiming};
use strata::step::{is_before, ExecStats, Executor, GenStatus, StepGenerator, StepQueue, Wake};
use strata_testkit::rng::Rng;

/// Short moves turning back on X, Y and E every few steps, retractions and travels.
fn reversing_job(seed: u64, n: usize) -> Vec<Move> {
    let mut r = Rng::new(seed);
    let (mut x, mut y, mut e) = (100_000i32, 100_000i32, 0i32);
    let mut moves = Vec::new();
    while moves.len() < n {
        if r.range(0..=15) == 0 {
            moves.push(mv([x, y, 200, e - 800], 35.0, Retract));
            x = r.range(60_000..=140_000) as i32;
            y = r.range(60_000..=140_000) as i32;
            moves.push(mv([x, y, 200, e - 800], 120.0, Travel));
            moves.push(mv([x, y, 200, e], 35.0, Retract));
            continue;
        }
        // 5 um to 0.4 mm (a step is 12.5 um), back and forth.
        x += r.range(-400..=400) as i32;
        y += r.range(-400..=400) as i32;
        e += r.range(0..=12) as i32;
        moves.push(mv([x, y, 200, e], r.range(5..=100) as f64, Print));
    }
    moves
}

/// Runs `moves` with the generator filling the queue only when the executor waits at the
/// horizon (or idles); returns the step hash and the executor's figures.
fn run_catching_up(moves: &[Move], cfg: &JobConfig) -> (u64, ExecStats) {
    let board =
        SimBoard::new(SimTiming::from_config(&cfg.step), cfg.start_tick, Recorder::default());
    let mut pins = board.pins();
    let mut planner: Planner<32> = Planner::new(&cfg.plan, cfg.start_um);
    let mut queue: StepQueue<64> = StepQueue::new();
    let (mut prod, cons) = queue.split();
    let mut gen: StepGenerator = StepGenerator::new(&cfg.step, cfg.start_um);
    let mut exec = Executor::new(&cfg.step, cons);
    let (mut next, mut wake, mut blocked) = (0usize, None::<u32>, false);
    for _ in 0..50_000_000u64 {
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
            let Some(b) = b else { break };
            gen.load(b).unwrap();
        }
        let h0 = exec.horizon();
        let status = gen.run(&mut prod);
        // Held at the horizon, and the generator could not move it: a full queue behind it
        // waits for the executor, which only a stall resolves (as on the board).
        let deadlock = blocked
            && exec.horizon() == h0
            && status == GenStatus::QueueFull
            && gen.waits_on_a_full_queue();
        blocked = false;
        // Every event before the horizon; at it, the executor waits (stalls in a deadlock),
        // and it comes to rest there only after the last block.
        let last_block_in = input_done && planner.is_empty();
        loop {
            if let Some(t) = wake {
                let (h, rest) = exec.horizon();
                let may_run = is_before(t, h) || (rest && last_block_in) || deadlock;
                if !may_run {
                    blocked = true;
                    break;
                }
                board.advance_to_u32(t);
            }
            match exec.on_timer_with(board.now_u32(), &mut pins, &mut &board).unwrap() {
                Wake::At(t) => wake = Some(t),
                Wake::Idle => {
                    wake = None;
                    break;
                }
            }
            if exec.is_stalled() {
                break;
            }
        }
        if wake.is_none() && input_done && planner.is_empty() && gen.is_idle() {
            assert_eq!(board.violation_count(), 0, "{:?}", board.first_violation());
            return (board.step_hash(), exec.stats());
        }
    }
    panic!("the job does not finish");
}

#[test]
fn an_executor_that_catches_up_keeps_every_step_at_its_tick() {
    let cfg = JobConfig { start_um: [100_000, 100_000, 200, 0], ..JobConfig::default() };
    for seed in 1..=4u64 {
        let moves = reversing_job(seed, 400);
        let ahead = run_job_with::<32, 64>(&moves, &cfg, |_| true);
        let (hash, stats) = run_catching_up(&moves, &cfg);
        assert_eq!(stats.late_dir_steps, 0, "seed {seed}: steps waited for DIR: {stats:?}");
        assert_eq!(stats.underruns, ahead.exec.underruns, "seed {seed}");
        assert_eq!(stats.steps, ahead.exec.steps, "seed {seed}");
        assert_eq!(hash, ahead.hash, "seed {seed}: the steps' ticks differ");
    }
}
