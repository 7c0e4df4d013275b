//! The step queue running empty: an underrun is reported, every axis holds, and motion
//! resumes with all later steps delayed by the same amount; a stop with nothing after it is
//! not an underrun, and new moves restart the executor.

mod motion_support;

use motion_support::measure::{compare_steps, STEP_TOL_S};
use motion_support::{mv, reference, run_job, run_job_with, JobConfig, Recorder};
use strata::plan::MoveKind::{Print, Travel};
use strata::plan::Planner;
use strata::sim::{SimBoard, SimTiming};
use strata::step::{Executor, GenStatus, StepGenerator, StepQueue, Wake};

fn moves() -> Vec<strata::plan::Move> {
    vec![
        mv([80_000, 0, 0, 0], 120.0, Travel),
        mv([80_000, 60_000, 0, 2_000], 60.0, Print),
        mv([0, 60_000, 0, 4_600], 60.0, Print),
        mv([0, 0, 0, 4_600], 150.0, Travel),
    ]
}

#[test]
fn underrun_is_reported_and_motion_resumes() {
    let cfg = JobConfig::default();
    let moves = moves();
    // The generator is not run between 0.40 s and 0.55 s of board time: the queues (7
    // commands per axis, about 50 ms at speed) run dry while the head moves.
    let (a, b) = (cfg.start_tick + 28_800_000, cfg.start_tick + 39_600_000);
    let r = run_job_with::<32, 8>(&moves, &cfg, |now| now < a || now >= b);
    assert_eq!(r.exec.underruns, 1, "{:?}", r.exec);
    let stall = r.exec.first_underrun_tick.unwrap() as u64;
    assert!(stall > a as u32 as u64 && stall < b as u32 as u64);
    // Resumed correctly: counts exact, no timing violation, every axis held (no step in the
    // stalled span).
    assert_eq!(r.violations, 0, "{:?}", r.first_violation);
    let expect = reference::expected_positions(&moves, &cfg);
    assert_eq!(r.positions, expect);
    for steps in &r.rec.steps {
        assert!(!steps.iter().any(|s| s.tick > stall && s.tick < b), "a step while stalled");
    }
    // Before the stall every step is on time; after it every step is late by the same shift.
    let shift = r.final_offset.wrapping_sub(r.gen0_tick as u32) as i32 as i64;
    assert!(shift as u64 > b - stall, "shift {shift}");
    let plan = reference::plan(&moves, &cfg);
    let ideal = reference::ideal_steps(&plan, &cfg);
    let (mut before, mut after) = (0, 0);
    for (axis, steps) in r.rec.steps.iter().enumerate() {
        assert_eq!(steps.len(), ideal[axis].len());
        for (s, &(t, up)) in steps.iter().zip(&ideal[axis]) {
            assert_eq!(s.positive, up);
            let late = if s.tick > stall {
                after += 1;
                shift
            } else {
                before += 1;
                0
            };
            let err = (s.tick as i64 - r.gen0_tick as i64 - late) as f64 / 72e6 - t;
            assert!(err.abs() <= STEP_TOL_S, "axis {axis}: error {err}");
        }
    }
    eprintln!(
        "underrun at {:.3} s, resumed with a shift of {:.3} ms; {before} steps before, {after} after",
        (stall - cfg.start_tick) as f64 / 72e6,
        shift as f64 / 72e3
    );
    assert!(before > 1000 && after > 1000);
}

#[test]
fn without_starvation_there_is_no_underrun() {
    let cfg = JobConfig::default();
    let r = run_job(&moves(), &cfg);
    assert_eq!((r.exec.underruns, r.exec.starts), (0, 1));
    let plan = reference::plan(&moves(), &cfg);
    assert!(compare_steps(&r, &plan, &cfg).max_err_s <= STEP_TOL_S);
}

#[test]
fn a_stop_idles_and_new_moves_restart() {
    let cfg = JobConfig::default();
    let board = SimBoard::new(SimTiming::from_config(&cfg.step), 500, Recorder::default());
    let mut pins = board.pins();
    let mut planner: Planner<16> = Planner::new(&cfg.plan, [0; 4]);
    let mut queue: StepQueue<64> = StepQueue::new();
    let (mut prod, cons) = queue.split();
    let mut gen: StepGenerator = StepGenerator::new(&cfg.step, [0; 4]);
    let mut exec = Executor::new(&cfg.step, cons);
    // Nothing queued: idle, drivers untouched.
    assert_eq!(exec.on_timer(board.now_u32(), &mut pins).unwrap(), Wake::Idle);
    let parts = [
        vec![mv([20_000, 0, 0, 0], 80.0, Travel), mv([20_000, 20_000, 0, 0], 80.0, Travel)],
        vec![mv([0, 0, 0, 0], 100.0, Travel)],
    ];
    let mut idle_at = Vec::new();
    for part in &parts {
        for m in part {
            planner.push(*m).unwrap();
        }
        // End of input for now: flush the planner, the last block stops.
        loop {
            if gen.wants_block() {
                if let Some(b) = planner.pop_forced() {
                    gen.load(b).unwrap();
                }
            }
            let st = gen.run(&mut prod);
            match exec.on_timer(board.now_u32(), &mut pins).unwrap() {
                Wake::At(t) => board.advance_to_u32(t),
                Wake::Idle => {
                    assert_eq!(st, GenStatus::Idle);
                    assert!(planner.is_empty());
                    idle_at.push(board.now());
                    break;
                }
            }
        }
        // A pause of two seconds at rest.
        board.advance_to(board.now() + 144_000_000);
    }
    let s = exec.stats();
    assert_eq!((s.starts, s.underruns), (2, 0), "{s:?}");
    assert_eq!(board.violation_count(), 0, "{:?}", board.first_violation());
    assert_eq!(board.positions(), [0, 0, 0, 0]);
    assert_eq!(exec.position_steps(), [0, 0, 0, 0]);
    let rec = board.into_observer();
    // The second part's first step comes after the pause, not at its old generator time.
    let first_after = rec.steps[0].iter().find(|x| x.tick > idle_at[0]).unwrap();
    assert!(first_after.tick >= idle_at[0] + 144_000_000);
}
