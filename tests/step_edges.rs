//! Step times at the edges of the generator's integer ranges, through the whole pipeline
//! and against the independent `f64` reference: long and very slow moves, blocks shorter
//! than a step, reversals every few steps, long and steep ramps, fast stepping, extruder-only
//! moves. Every step must be within 1 us of the ideal time, with nothing clamped, no
//! sequence failing its check, and the motors where the moves put them.

mod motion_support;

use motion_support::measure::{compare_steps, STEP_TOL_S};
use motion_support::{assert_clean, mm_s, mv, reference, run_job, JobConfig};
use strata::plan::Move;
use strata::plan::MoveKind::{Print, Retract, Travel};

/// Runs `moves`, checks the result is clean and every step time; returns (steps, sequences).
fn run_checked(moves: &[Move], cfg: &JobConfig) -> (u64, u64) {
    let r = run_job(moves, cfg);
    assert_clean(&r, cfg, moves);
    let plan = reference::plan(moves, cfg);
    let t = compare_steps(&r, &plan, cfg);
    assert!(t.max_err_s <= STEP_TOL_S, "{t:?}");
    let steps: u64 = r.gen.steps.iter().sum();
    let seqs: u64 = r.gen.sequences.iter().sum();
    eprintln!("{steps} steps, {seqs} sequences, worst error {:.3} us", t.max_err_s * 1e6);
    (steps, seqs)
}

#[test]
fn long_cruise_and_long_diagonal() {
    let cfg = JobConfig::default();
    let moves = [
        mv([220_000, 0, 0, 0], 200.0, Travel),
        mv([0, 220_000, 0, 0], 300.0, Travel),
        mv([1, 1, 0, 0], 250.0, Travel),
    ];
    let (steps, seqs) = run_checked(&moves, &cfg);
    // Cruise compresses into long sequences.
    assert!(steps > 20 * seqs, "{steps} steps in {seqs} sequences");
}

#[test]
fn very_slow_moves_with_steps_far_apart() {
    let cfg = JobConfig::default();
    // 0.05 mm/s at 80 steps/mm: a step every 0.25 s (18 M ticks), waits in between.
    let moves = [
        mv([600, 0, 0, 0], 0.05, Print),
        mv([600, 300, 0, 0], 0.2, Print),
        mv([0, 0, 0, 0], 1.0, Travel),
    ];
    run_checked(&moves, &cfg);
}

#[test]
fn blocks_shorter_than_a_step_and_reversals_every_few_steps() {
    let cfg = JobConfig::default();
    let mut moves = Vec::new();
    let (mut x, mut y, mut e) = (50_000, 50_000, 0);
    for i in 0..300 {
        // 3 um to 40 um moves (a step is 12.5 um), turning back every other move.
        let d = 3 + (i * 7919 % 38);
        x += if i % 4 < 2 { d } else { -d };
        y += if i % 3 == 0 { -(d / 2) } else { d / 3 };
        e += i % 5;
        moves.push(mv([x, y, 200, e], 20.0 + (i % 7) as f64 * 15.0, Print));
    }
    run_checked(&moves, &cfg);
}

#[test]
fn long_gentle_ramps_and_steep_short_ones() {
    let mut cfg = JobConfig::default();
    // 4 mm/s^2: two-second ramps where the step times come from the square root alone.
    cfg.plan.print_accel_mm_s2 = mm_s(4.0);
    let moves = [mv([30_000, 0, 0, 0], 50.0, Print), mv([30_000, 8_000, 0, 0], 50.0, Print)];
    run_checked(&moves, &cfg);

    let mut cfg = JobConfig::default();
    cfg.plan.travel_accel_mm_s2 = mm_s(20_000.0);
    cfg.plan.max_accel_mm_s2 = [mm_s(20_000.0); 4];
    let moves = [
        mv([1_000, 0, 0, 0], 300.0, Travel),
        mv([1_000, 700, 0, 0], 300.0, Travel),
        mv([0, 0, 0, 0], 300.0, Travel),
    ];
    run_checked(&moves, &cfg);
}

#[test]
fn fast_stepping_at_high_resolution() {
    let mut cfg = JobConfig::default();
    // 1600 steps/mm at 150 mm/s: 240 kHz on X, 17 us between steps at the driver's limits.
    cfg.step.steps_per_mm[0] = mm_s(1600.0);
    cfg.step.steps_per_mm[1] = mm_s(1600.0);
    cfg.step.driver = strata::step::DriverTiming::TMC2208;
    let moves = [
        mv([60_000, 0, 0, 0], 150.0, Travel),
        mv([60_000, 30_000, 0, 0], 150.0, Travel),
        mv([0, 0, 0, 0], 150.0, Travel),
    ];
    run_checked(&moves, &cfg);
}

#[test]
fn extruder_only_moves_and_extrusion_dominated_prints() {
    let cfg = JobConfig::default();
    let moves = [
        mv([0, 0, 0, -6_000], 40.0, Retract),
        mv([0, 0, 0, 0], 30.0, Retract),
        // 0.5 mm of XY with 4 mm of E: E steps more than X.
        mv([500, 0, 0, 4_000], 5.0, Print),
        mv([500, 300, 0, 4_100], 60.0, Print),
        mv([500, 300, 0, 3_000], 25.0, Retract),
    ];
    run_checked(&moves, &cfg);
}
