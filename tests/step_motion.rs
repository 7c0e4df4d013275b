//! Acceptance figures through the simulated board: corner speed, circle speed (lookahead),
//! print time, the `u32` timer wrap, driver timing (A4988 and TMC), direction changes.

mod motion_support;

use motion_support::measure::{
    check_limits, compare_steps, position_at, speed_at_position, STEP_TOL_S,
};
use motion_support::{assert_clean, mv, reference, run_job, JobConfig, JobResult};
use strata::plan::Move;
use strata::plan::MoveKind::{Print, Retract, Travel};
use strata::step::DriverTiming;

/// Runs, checks cleanliness, timing against the reference and the limits; returns the result.
fn run_checked(moves: &[Move], cfg: &JobConfig) -> (JobResult, Vec<reference::RefMove>) {
    let r = run_job(moves, cfg);
    assert_clean(&r, cfg, moves);
    let plan = reference::plan(moves, cfg);
    let t = compare_steps(&r, &plan, cfg);
    assert!(t.max_err_s <= STEP_TOL_S, "{t:?}");
    check_limits(&r, &plan, cfg, 1e-3);
    (r, plan)
}

/// Corner speed from the recorded steps: a quadratic through the last crossings of the
/// incoming axis and the first of the outgoing one, evaluated where each reaches the corner.
fn corner_speeds(
    r: &JobResult,
    ax_in: usize,
    corner_in: f64,
    ax_out: usize,
    corner_out: f64,
    n: usize,
) -> ((f64, f64), (f64, f64)) {
    let cross = |s: &motion_support::StepRec| {
        (s.tick as f64 / 72e6, s.position as f64 - if s.positive { 0.5 } else { -0.5 })
    };
    let before: Vec<(f64, f64)> = {
        let s = &r.rec.steps[ax_in];
        // Last n crossings before the incoming axis reaches the corner.
        let k = s.iter().position(|x| (x.position as f64) >= corner_in).unwrap();
        s[k + 1 - n..=k].iter().map(cross).collect()
    };
    let after: Vec<(f64, f64)> = {
        let s = &r.rec.steps[ax_out];
        s[..n].iter().map(cross).collect()
    };
    (speed_at_position(&before, corner_in), speed_at_position(&after, corner_out))
}

#[test]
fn corners_pass_at_the_junction_deviation_speed() {
    let cfg = JobConfig::default();
    let scv = 5.0f64;
    for deg in [90.0f64, 45.0, 135.0, 60.0] {
        // In along +X for 20 mm, out at `deg` degrees of turn for 20 mm, at 60 mm/s.
        let turn = deg.to_radians();
        let out = [
            20_000 + (20_000.0 * turn.cos()).round() as i32,
            (20_000.0 * turn.sin()).round() as i32,
        ];
        let moves = [mv([20_000, 0, 0, 0], 60.0, Travel), mv([out[0], out[1], 0, 0], 60.0, Travel)];
        let (r, plan) = run_checked(&moves, &cfg);
        // Klipper: theta between the reversed incoming and the outgoing direction.
        let theta = std::f64::consts::PI - turn;
        let sin_half = (theta / 2.0).sin();
        let want = (scv * scv * (2f64.sqrt() - 1.0) * sin_half / (1.0 - sin_half)).sqrt();
        assert!(
            (plan[1].v0 - want).abs() < 1e-3 * want,
            "reference corner {} vs {want}",
            plan[1].v0
        );
        let planned = r.blocks[0].end_speed_mm_s().to_num::<f64>();
        // Measure along Y (the outgoing component is sin(turn) of the path speed) and along X
        // for the incoming leg.
        let ((vx, tx), (vy, ty)) = corner_speeds(&r, 0, 1600.0, 1, 0.0, 6);
        let meas_in = vx / 80.0;
        let meas_out = vy / 80.0 / turn.sin();
        eprintln!(
            "turn {deg} deg: formula {want:.4} planned {planned:.4} measured in {meas_in:.4} out {meas_out:.4} mm/s; corner times differ {:.2} us",
            (tx - ty) * 1e6
        );
        assert!(
            (planned - plan[1].v0).abs() < 1e-6 * want,
            "planned {planned} vs reference {}",
            plan[1].v0
        );
        assert!((meas_in / want - 1.0).abs() < 0.02, "incoming {meas_in} vs {want}");
        assert!((meas_out / want - 1.0).abs() < 0.02, "outgoing {meas_out} vs {want}");
    }
}

/// Moves of a circle of `d_mm` diameter in `n` segments around (cx, cy) mm, extruding.
fn circle(cx: f64, cy: f64, d_mm: f64, n: usize, feed: f64) -> (Vec<Move>, [i32; 4]) {
    let r = d_mm / 2.0;
    let pt = |i: usize| {
        let a = i as f64 / n as f64 * std::f64::consts::TAU;
        [((cx + r * a.cos()) * 1000.0).round() as i32, ((cy + r * a.sin()) * 1000.0).round() as i32]
    };
    let start = pt(0);
    let seg = std::f64::consts::PI * d_mm / n as f64;
    let moves = (1..=n)
        .map(|i| {
            let p = pt(i);
            let e = (i as f64 * seg * 33.3).round() as i32; // 0.0333 mm E per mm
            mv([p[0], p[1], 200, e], feed, Print)
        })
        .collect();
    (moves, [start[0], start[1], 200, 0])
}

#[test]
fn circle_of_360_segments_reaches_95_percent_of_60_mm_s() {
    let (moves, start) = circle(100.0, 100.0, 20.0, 360, 60.0);
    let cfg = JobConfig { start_um: start, ..JobConfig::default() };
    let (r, plan) = run_checked(&moves, &cfg);
    let planned_peak =
        r.blocks.iter().map(|b| b.cruise_speed_mm_s().to_num::<f64>()).fold(0.0, f64::max);
    let ref_peak = plan.iter().map(|m| m.vc).fold(0.0, f64::max);
    // Path speed from the recorded steps: positions sampled every 2 ms, speed over 10 ms.
    let (x, y) = (&r.rec.steps[0], &r.rec.steps[1]);
    // The board counts from 0 at the start position.
    let s0 = [0i64; 2];
    let t_end = r.last_step_tick().unwrap() as f64;
    let dt = 2e-3 * 72e6;
    let mut pts = Vec::new();
    let mut t = r.gen0_tick as f64;
    while t < t_end {
        pts.push([position_at(x, s0[0], t) / 80.0, position_at(y, s0[1], t) / 80.0]);
        t += dt;
    }
    let seg: Vec<f64> = pts
        .windows(2)
        .map(|w| ((w[1][0] - w[0][0]).powi(2) + (w[1][1] - w[0][1]).powi(2)).sqrt())
        .collect();
    let speeds: Vec<f64> = seg.windows(5).map(|w| w.iter().sum::<f64>() / 10e-3).collect();
    let peak = speeds.iter().cloned().fold(0.0, f64::max);
    let fast = speeds.iter().filter(|&&v| v >= 0.95 * 60.0).count() as f64 / speeds.len() as f64;
    eprintln!(
        "circle: planned peak {planned_peak:.3} reference {ref_peak:.3} measured peak {peak:.3} mm/s; {:.1} % of the time at >= 95 %",
        fast * 100.0
    );
    assert!(planned_peak >= 0.95 * 60.0);
    assert!(peak >= 0.95 * 60.0, "measured peak {peak}");
    assert!(peak <= 60.0 * 1.01, "measured peak {peak}");
}

#[test]
fn print_time_estimate_equals_simulated_duration() {
    // About 12 s of mixed motion: circles, long travels, retracts, a Z hop.
    let (mut moves, start) = circle(60.0, 60.0, 30.0, 200, 45.0);
    let e = moves.last().unwrap().target_um[3];
    moves.push(mv([94_000, 60_000, 200, e - 5000], 40.0, Retract));
    moves.push(mv([94_000, 60_000, 600, e - 5000], 5.0, Travel));
    moves.push(mv([180_000, 170_000, 600, e - 5000], 150.0, Travel));
    moves.push(mv([180_000, 170_000, 600, e], 40.0, Retract));
    for i in 0..20 {
        let y = 170_000 - i * 2_000;
        moves.push(mv(
            [if i % 2 == 0 { 40_000 } else { 180_000 }, y, 600, e + 1000 * (i + 1)],
            80.0,
            Print,
        ));
        moves.push(mv(
            [if i % 2 == 0 { 40_000 } else { 180_000 }, y - 2_000, 600, e + 1000 * (i + 1) + 30],
            80.0,
            Print,
        ));
    }
    let cfg = JobConfig { start_um: start, ..JobConfig::default() };
    let (r, plan) = run_checked(&moves, &cfg);
    let hz = 72e6;
    let sim_last = (r.last_step_tick().unwrap() - r.gen0_tick) as f64 / hz;
    let sim_end = (r.end_tick - r.gen0_tick) as f64 / hz;
    let refd = reference::total_time(&plan);
    eprintln!(
        "print time: planner {:.6} s, reference {:.6} s, simulated last step {:.6} s, executor idle {:.6} s",
        r.planned_s, refd, sim_last, sim_end
    );
    assert!(r.planned_s > 10.0);
    assert!((r.planned_s - sim_last).abs() / r.planned_s < 1e-3);
    assert!((r.planned_s - sim_end).abs() / r.planned_s < 1e-6);
    assert!((r.planned_s - refd).abs() / refd < 1e-8);
}

#[test]
fn runs_across_the_u32_timer_wrap() {
    // Half a second before the 32-bit timer wraps (it wraps every 59.65 s at 72 MHz).
    let cfg = JobConfig { start_tick: (1u64 << 32) - 36_000_000, ..JobConfig::default() };
    let moves = [
        mv([60_000, 20_000, 0, 0], 120.0, Travel),
        mv([0, 40_000, 0, 0], 120.0, Travel),
        mv([30_000, 0, 0, 0], 80.0, Travel),
    ];
    let (r, _) = run_checked(&moves, &cfg);
    let first = r.rec.steps[0][0].tick;
    assert!(first < 1 << 32 && r.last_step_tick().unwrap() > 1 << 32, "job must straddle the wrap");
}

#[test]
fn tmc_timing_is_honoured_and_a4988_margins_hold() {
    let moves = [
        mv([10_000, 0, 0, 0], 100.0, Travel),
        mv([0, 0, 0, 0], 100.0, Travel),
        mv([10_000, 10_000, 0, 0], 100.0, Travel),
        mv([0, 0, 0, 0], 100.0, Travel),
    ];
    let a4988 = JobConfig::default();
    let (r, _) = run_checked(&moves, &a4988);
    eprintln!("A4988: min high {:?} low {:?} setup {:?} ticks", r.min_high, r.min_low, r.min_setup);
    assert!(r.min_high.unwrap() >= 72 && r.min_setup.unwrap() >= 15);
    let mut tmc = JobConfig::default();
    tmc.step.driver = DriverTiming::TMC2208;
    let (r, _) = run_checked(&moves, &tmc);
    eprintln!(
        "TMC2208: min high {:?} low {:?} setup {:?} ticks",
        r.min_high, r.min_low, r.min_setup
    );
    assert_eq!(r.min_high, Some(8));
}

#[test]
fn direction_changes_between_moves_keep_setup_and_counts() {
    // Zig-zags on every axis, reversals at rest and at speed (a shallow V through the
    // junction reverses Y while moving).
    let mut moves = Vec::new();
    for i in 0..6 {
        let x = if i % 2 == 0 { 15_000 } else { 0 };
        moves.push(mv([x, 1_000 * i, 100 * (i % 2), 0], 100.0, Travel));
    }
    moves.push(mv([20_000, 8_000, 0, 0], 100.0, Travel));
    moves.push(mv([40_000, 6_000, 0, 0], 100.0, Travel));
    moves.push(mv([60_000, 8_000, 0, 0], 100.0, Travel));
    let (r, plan) = run_checked(&moves, &JobConfig::default());
    let reversing =
        plan.windows(2).filter(|w| w[0].d[1] * w[1].d[1] < 0.0 && w[1].v0 > 1.0).count();
    assert!(reversing >= 2, "Y must reverse at speed somewhere");
    assert!(r.min_setup.unwrap() >= 15);
}

#[test]
fn extruder_ties_and_touches_make_no_step() {
    // 93 steps/mm: 93 q / 1000 is exactly k + 1/2 for q = 500 / 93 (mod 1000).
    let q = (0..1000).find(|q| 93 * q % 1000 == 500).unwrap();
    let moves = [
        mv([10_000, 0, 0, q], 30.0, Print),
        mv([10_000, 0, 0, q - 2000], 40.0, Retract),
        mv([10_000, 0, 0, q], 40.0, Retract),
        mv([10_000, 0, 0, q + 1000], 20.0, Retract),
        mv([10_000, 0, 0, q], 20.0, Retract),
    ];
    let (r, _) = run_checked(&moves, &JobConfig::default());
    assert_eq!(r.gen.clamped, 0);
}
