//! Long random move sequences through the whole pipeline: final step counts equal the
//! commanded positions exactly, every step within 1 us of the independent reference, no
//! speed or acceleration above the limits, no driver timing violation.
//!
//! The reference plans with full knowledge of the move list; the planner's 32-move queue is
//! not the binding constraint here because every XY move is at least 1 mm long and feeds stay
//! at or below 150 mm/s (stopping distance at 500 mm/s^2: 22.5 mm < 32 mm).

mod motion_support;

use motion_support::measure::{check_limits, compare_steps, STEP_TOL_S};
use motion_support::{assert_clean, mv, reference, run_job, JobConfig};
use proptest::prelude::*;
use strata::plan::Move;
use strata::plan::MoveKind::{Print, Retract, Travel};
use strata_testkit::rng::Rng;

/// A plausible print: extruding lines and arcs, travels with retraction, Z steps, within the
/// bed; `n` moves.
fn random_job(seed: u64, n: usize) -> (Vec<Move>, [i32; 4]) {
    let mut r = Rng::new(seed);
    let start = [110_000, 110_000, 200, 0];
    let (mut x, mut y, mut z, mut e) = (start[0] as i64, start[1] as i64, 200i64, 0i64);
    let mut moves = Vec::new();
    while moves.len() < n {
        match r.range(0..=9) {
            0 => {
                // Retract, travel, unretract.
                let feed = r.range(20..=45) as f64;
                moves.push(mv([x as i32, y as i32, z as i32, (e - 4000) as i32], feed, Retract));
                x = r.range(5_000..=215_000);
                y = r.range(5_000..=215_000);
                moves.push(mv(
                    [x as i32, y as i32, z as i32, (e - 4000) as i32],
                    r.range(60..=150) as f64,
                    Travel,
                ));
                moves.push(mv([x as i32, y as i32, z as i32, e as i32], feed, Retract));
            }
            1 => {
                z += r.range(1..=3) * 100;
                moves.push(mv(
                    [x as i32, y as i32, z as i32, e as i32],
                    r.range(2..=5) as f64,
                    Travel,
                ));
            }
            _ => {
                // A polyline of extruding moves, 1..25 mm each, turning by random angles.
                let feed = r.range(10..=120) as f64;
                let mut heading = r.range(0..=359) as f64;
                for _ in 0..r.range(1..=12) {
                    heading += r.range(-100..=100) as f64;
                    let len = r.range(1_000..=25_000) as f64;
                    let (nx, ny) = (
                        (x as f64 + len * heading.to_radians().cos()).clamp(2_000.0, 218_000.0),
                        (y as f64 + len * heading.to_radians().sin()).clamp(2_000.0, 218_000.0),
                    );
                    let d = ((nx - x as f64).powi(2) + (ny - y as f64).powi(2)).sqrt();
                    if d < 1_000.0 {
                        heading += 180.0;
                        continue;
                    }
                    (x, y) = (nx as i64, ny as i64);
                    e += (d * 0.0333) as i64;
                    moves.push(mv([x as i32, y as i32, z as i32, e as i32], feed, Print));
                }
            }
        }
    }
    moves.truncate(n);
    (moves, start)
}

fn check_job(moves: &[Move], start: [i32; 4], start_tick: u64) -> (f64, usize) {
    let cfg = JobConfig { start_um: start, start_tick, ..JobConfig::default() };
    let r = run_job(moves, &cfg);
    assert_clean(&r, &cfg, moves);
    let plan = reference::plan(moves, &cfg);
    // The bounded lookahead must not have been binding: same speeds as full knowledge.
    for (b, m) in r.blocks.iter().zip(&plan) {
        let v = b.end_speed_mm_s().to_num::<f64>();
        assert!(
            (v - m.v1).abs() < 1e-6 * (1.0 + m.v1),
            "move {}: end speed {v} vs {}",
            m.index,
            m.v1
        );
    }
    let t = compare_steps(&r, &plan, &cfg);
    assert!(t.max_err_s <= STEP_TOL_S, "{t:?}");
    check_limits(&r, &plan, &cfg, 1e-3);
    let refd = reference::total_time(&plan);
    assert!((r.planned_s - refd).abs() < 1e-6 * refd, "time {} vs {refd}", r.planned_s);
    (t.max_err_s, t.steps)
}

#[test]
fn seeded_long_job_is_exact() {
    let (moves, start) = random_job(0x5eed_0001, 300);
    let (err, steps) = check_job(&moves, start, 12_345);
    eprintln!("300 random moves: {steps} steps, max step error {:.3} us", err * 1e6);
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 6, ..ProptestConfig::default() })]

    #[test]
    fn random_jobs_are_exact(seed in any::<u64>(), n in 20usize..60, start_tick in any::<u32>()) {
        let (moves, start) = random_job(seed, n);
        check_job(&moves, start, start_tick as u64);
    }
}
