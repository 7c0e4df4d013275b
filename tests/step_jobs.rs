//! Whole jobs through planner, step generator, executor and the simulated board, checked
//! against the independent `f64` reference: step counts, step times, speeds, accelerations.

mod motion_support;

use motion_support::measure::{check_limits, compare_steps, STEP_TOL_S};
use motion_support::{assert_clean, mv, reference, run_job, JobConfig};
use strata::plan::Move;
use strata::plan::MoveKind::{Print, Retract, Travel};

#[test]
fn single_move_matches_reference() {
    let cfg = JobConfig::default();
    let moves = [mv([30_000, 0, 0, 0], 100.0, Travel)];
    let r = run_job(&moves, &cfg);
    assert_clean(&r, &cfg, &moves);
    let plan = reference::plan(&moves, &cfg);
    let t = compare_steps(&r, &plan, &cfg);
    eprintln!("single move: {t:?} seq {:?} wakes {}", r.gen.sequences, r.wakes);
    assert!(t.max_err_s <= STEP_TOL_S, "{t:?}");
    let l = check_limits(&r, &plan, &cfg, 1e-3);
    eprintln!("{l:?}");
}

#[test]
fn mixed_moves_match_reference() {
    let cfg = JobConfig::default();
    let moves = [
        mv([20_000, 0, 0, 0], 60.0, Travel),
        mv([20_000, 20_000, 0, 800], 40.0, Print),
        mv([5_000, 30_000, 0, 1500], 45.0, Print),
        mv([5_000, 30_000, 0, -3500], 45.0, Retract),
        mv([40_000, 2_000, 200, -3500], 150.0, Travel),
        mv([40_000, 2_000, 200, 1500], 45.0, Retract),
        mv([41_000, 12_000, 200, 1900], 30.0, Print),
        mv([0, 0, 0, 1900], 200.0, Travel),
    ];
    let r = run_job(&moves, &cfg);
    assert_clean(&r, &cfg, &moves);
    let plan = reference::plan(&moves, &cfg);
    let t = compare_steps(&r, &plan, &cfg);
    eprintln!("mixed: {t:?} seq {:?} steps {:?}", r.gen.sequences, r.gen.steps);
    assert!(t.max_err_s <= STEP_TOL_S, "{t:?}");
    let l = check_limits(&r, &plan, &cfg, 1e-3);
    eprintln!("{l:?}");
    let total = reference::total_time(&plan);
    eprintln!(
        "planned {} ref {} end {}",
        r.planned_s,
        total,
        (r.end_tick - r.gen0_tick) as f64 / 72e6
    );
}

#[test]
fn memory_footprint_is_bounded() {
    use std::mem::size_of;
    use strata::plan::{Block, Planner};
    use strata::step::{Executor, StepCmd, StepGenerator, StepQueue};
    let sizes = [
        ("Planner<32>", size_of::<Planner<32>>()),
        ("Block", size_of::<Block>()),
        ("StepGenerator<64>", size_of::<StepGenerator<64>>()),
        ("StepQueue<64>", size_of::<StepQueue<64>>()),
        ("StepCmd", size_of::<StepCmd>()),
        ("Executor<64>", size_of::<Executor<'static, 64>>()),
    ];
    eprintln!("host sizes (bytes): {sizes:?}");
    assert_eq!(size_of::<StepCmd>(), 12);
    let total: usize =
        sizes.iter().filter(|s| s.0 != "Block" && s.0 != "StepCmd").map(|s| s.1).sum();
    assert!(total < 12 * 1024, "motion state {total} bytes");
}

#[test]
fn compression_ratio_of_a_print_like_job() {
    let cfg = JobConfig::default();
    let mut moves = Vec::new();
    for i in 0..20 {
        let y = 50_000 + 450 * i;
        moves.push(mv(
            [if i % 2 == 0 { 100_000 } else { 50_000 }, y, 200, 1_700 * (i + 1)],
            60.0,
            Print,
        ));
    }
    moves.push(mv([10_000, 10_000, 200, 1_700 * 20], 150.0, Travel));
    let r = run_job(&moves, &cfg);
    assert_clean(&r, &cfg, &moves);
    let steps: u64 = r.gen.steps.iter().sum();
    let seqs: u64 = r.gen.sequences.iter().sum();
    eprintln!(
        "{steps} steps in {seqs} sequences: {:.1} steps per 12-byte command, {:.2} on-timer calls per step",
        steps as f64 / seqs as f64,
        r.wakes as f64 / steps as f64
    );
    assert!(steps > 10 * seqs);
}

#[test]
fn the_generator_says_when_it_waits_on_a_full_step_queue() {
    use strata::plan::Planner;
    use strata::step::{GenStatus, StepGenerator, StepQueue};
    // One 30 mm move into 4-command queues: the generator stops at a full queue, and says
    // so (the emulated board lets its executor stall only then); once everything is taken,
    // it stops for want of blocks and says it does not wait on a queue.
    let cfg = JobConfig::default();
    let mut planner: Planner<4> = Planner::new(&cfg.plan, cfg.start_um);
    planner.push(mv([30_000, 0, 0, 0], 100.0, Travel)).unwrap();
    let block = planner.pop_forced().expect("one block");
    let mut q: StepQueue<4> = StepQueue::new();
    let (mut prod, mut cons) = q.split();
    let mut gen: StepGenerator = StepGenerator::new(&cfg.step, cfg.start_um);
    assert!(!gen.waits_on_a_full_queue());
    gen.load(block).unwrap();
    assert_eq!(gen.run(&mut prod), GenStatus::QueueFull);
    assert!(gen.waits_on_a_full_queue());
    let mut status = GenStatus::QueueFull;
    for _ in 0..100_000 {
        for axis in 0..4 {
            while cons.dequeue(axis).is_some() {}
        }
        status = gen.run(&mut prod);
        if status != GenStatus::QueueFull {
            break;
        }
        assert!(gen.waits_on_a_full_queue());
    }
    assert_eq!(status, GenStatus::Idle, "the move is generated and ends at rest");
    assert!(!gen.waits_on_a_full_queue());
}

#[test]
fn a_dwell_holds_every_axis_still_for_its_time() {
    let cfg = JobConfig::default();
    let wait_s = 0.35;
    let moves = [
        mv([20_000, 5_000, 0, 0], 120.0, Travel),
        mv([30_000, 15_000, 0, 600], 40.0, Print),
        // Its target is not read by the planner: the reference reads none either.
        Move::dwell([0; 4], strata::machine::Rate::from_num(wait_s)),
        mv([40_000, 15_000, 0, 1_000], 40.0, Print),
    ];
    let r = run_job(&moves, &cfg);
    assert_clean(&r, &cfg, &moves);
    let plan = reference::plan(&moves, &cfg);
    let t = compare_steps(&r, &plan, &cfg);
    assert!(t.max_err_s <= STEP_TOL_S, "{t:?}");
    // No step of any axis inside the wait: the last before ends the second move, the first
    // after starts the third.
    let (d0, d1) = (plan[2].t0, plan[2].t0 + wait_s);
    let hz = f64::from(cfg.step.timer_hz);
    for steps in &r.rec.steps {
        for s in steps {
            let at = (s.tick - r.gen0_tick) as f64 / hz;
            assert!(at <= d0 + STEP_TOL_S || at >= d1 - STEP_TOL_S, "a step at {at} s");
        }
    }
    let total = reference::total_time(&plan);
    assert!((r.planned_s - total).abs() < 1e-6, "planned {} vs {total}", r.planned_s);
}
