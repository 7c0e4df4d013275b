//! The planner against the independent `f64` full-knowledge planner: junction speeds,
//! per-axis limits along the direction, lookahead, the behaviour of short queues, block
//! times, errors.

mod motion_support;

use motion_support::reference::{self, RefMove};
use motion_support::{mm_s, mv, JobConfig};
use proptest::prelude::*;
use strata::plan::MoveKind::{Print, Retract, Travel};
use strata::plan::{Block, Move, PlanError, Planner};
use strata_testkit::rng::Rng;

/// Plans `moves` with an `N`-move queue the way a streaming caller does: push while there is
/// room, release final blocks, force the head out only when the queue is full or the input
/// has ended.
fn plan_all<const N: usize>(moves: &[Move], cfg: &JobConfig) -> Vec<Block> {
    let mut p: Planner<N> = Planner::new(&cfg.plan, cfg.start_um);
    let mut out = Vec::new();
    for m in moves {
        if p.is_full() {
            let b = p.pop().or_else(|| p.pop_forced()).unwrap();
            out.push(b);
        }
        p.push(*m).unwrap();
        while let Some(b) = p.pop() {
            out.push(b);
        }
    }
    while let Some(b) = p.pop_forced() {
        out.push(b);
    }
    out
}

fn v(r: strata::machine::Rate) -> f64 {
    r.to_num::<f64>()
}

fn rel(a: f64, b: f64) -> f64 {
    (a - b).abs() / b.abs().max(1.0)
}

/// Random moves: XYZ directions anywhere, E sometimes, kinds mixed, lengths `lo..hi` um.
fn random_moves(seed: u64, n: usize, lo: i64, hi: i64) -> Vec<Move> {
    let mut rng = Rng::new(seed | 1);
    let mut rnd = |a: i64, b: i64| rng.range(a..=b);
    let mut p = [100_000i64, 100_000, 10_000, 0];
    let mut out = Vec::new();
    for _ in 0..n {
        let len = rnd(lo, hi) as f64;
        let ang = rnd(0, 359) as f64;
        let dz = if rnd(0, 9) == 0 { rnd(-400, 400) } else { 0 };
        p[0] += (len * ang.to_radians().cos()) as i64;
        p[1] += (len * ang.to_radians().sin()) as i64;
        p[2] += dz;
        let kind = match rnd(0, 5) {
            0 => Travel,
            _ => Print,
        };
        if kind == Print {
            p[3] += (len * 0.0333) as i64;
        }
        let feed = rnd(5, 200) as f64;
        out.push(mv([p[0] as i32, p[1] as i32, p[2] as i32, p[3] as i32], feed, kind));
        if rnd(0, 12) == 0 {
            p[3] -= 3000;
            out.push(mv([p[0] as i32, p[1] as i32, p[2] as i32, p[3] as i32], 40.0, Retract));
            p[3] += 3000;
            out.push(mv([p[0] as i32, p[1] as i32, p[2] as i32, p[3] as i32], 40.0, Retract));
        }
    }
    out
}

/// The start of [`random_moves`].
fn cfg_at() -> JobConfig {
    JobConfig { start_um: [100_000, 100_000, 10_000, 0], ..JobConfig::default() }
}

/// Every block: speeds as the reference, duration as the reference.
fn assert_same_plan(blocks: &[Block], plan: &[RefMove]) {
    assert_eq!(blocks.len(), plan.len());
    for (b, m) in blocks.iter().zip(plan) {
        let i = m.index;
        assert!(
            rel(v(b.start_speed_mm_s()), m.v0) < 1e-7,
            "move {i}: start {:?} vs {}",
            b.start_speed_mm_s(),
            m.v0
        );
        assert!(
            rel(v(b.cruise_speed_mm_s()), m.vc) < 1e-7,
            "move {i}: cruise {:?} vs {}",
            b.cruise_speed_mm_s(),
            m.vc
        );
        assert!(
            rel(v(b.end_speed_mm_s()), m.v1) < 1e-7,
            "move {i}: end {:?} vs {}",
            b.end_speed_mm_s(),
            m.v1
        );
        assert!(rel(v(b.accel_mm_s2()), m.accel) < 1e-7, "move {i}: accel");
        let d = b.duration_s().to_num::<f64>();
        assert!(
            (d - m.duration()).abs() < 1e-8 + 1e-8 * m.duration(),
            "move {i}: duration {d} vs {}",
            m.duration()
        );
    }
}

#[test]
fn long_enough_queue_equals_full_knowledge() {
    for seed in 1..40u64 {
        // 2..30 mm moves up to 200 mm/s: 32 queued moves always cover the stopping distance.
        let moves = random_moves(seed, 120, 2_000, 30_000);
        let cfg = cfg_at();
        let blocks = plan_all::<32>(&moves, &cfg);
        assert_same_plan(&blocks, &reference::plan(&moves, &cfg));
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    /// Corner speed of two long moves in any directions (E included) equals Klipper's
    /// formula computed in `f64`.
    #[test]
    fn junction_speed_matches_the_f64_formula(
        a in (-100_000i32..100_000, -100_000i32..100_000, -2_000i32..2_000, 0i32..3_000),
        b in (-100_000i32..100_000, -100_000i32..100_000, -2_000i32..2_000, 0i32..3_000),
        feed in 20u32..300,
    ) {
        let start = [110_000, 110_000, 20_000, 0];
        let p1 = [start[0] + a.0, start[1] + a.1, start[2] + a.2, a.3];
        let p2 = [p1[0] + b.0, p1[1] + b.1, p1[2] + b.2, p1[3] + b.3];
        prop_assume!(p1[..3] != start[..3] && p2[..3] != p1[..3]);
        let moves = [mv(p1, feed as f64, Print), mv(p2, feed as f64, Travel)];
        let cfg = JobConfig { start_um: start, ..JobConfig::default() };
        let blocks = plan_all::<4>(&moves, &cfg);
        assert_same_plan(&blocks, &reference::plan(&moves, &cfg));
    }

    /// Any queue length: blocks chain, respect every limit, and never go faster than full
    /// knowledge allows; a shorter queue only costs time.
    #[test]
    fn short_queues_only_slow_down(seed in any::<u64>()) {
        let moves = random_moves(seed, 60, 200, 8_000);
        let cfg = cfg_at();
        let full = reference::plan(&moves, &cfg);
        let full_t = reference::total_time(&full);
        let mut times = Vec::new();
        for blocks in [plan_all::<2>(&moves, &cfg), plan_all::<4>(&moves, &cfg), plan_all::<8>(&moves, &cfg), plan_all::<64>(&moves, &cfg)] {
            prop_assert_eq!(blocks.len(), full.len());
            let mut prev_end = 0.0;
            for (b, m) in blocks.iter().zip(&full) {
                let (s, c, e) = (v(b.start_speed_mm_s()), v(b.cruise_speed_mm_s()), v(b.end_speed_mm_s()));
                let a = v(b.accel_mm_s2());
                prop_assert!((s - prev_end).abs() < 1e-6, "blocks must chain");
                prop_assert!(s <= m.v0 * (1.0 + 1e-7) + 1e-6 && e <= m.v1 * (1.0 + 1e-7) + 1e-6);
                prop_assert!(c <= m.vc * (1.0 + 1e-7) + 1e-6);
                prop_assert!(s * s <= m.max_start_v2 * (1.0 + 1e-7) + 1e-6);
                prop_assert!(c <= m.max_cruise_v2.sqrt() * (1.0 + 1e-7));
                prop_assert!(rel(a, m.accel) < 1e-7);
                // Reachable within the move at its acceleration.
                prop_assert!(e * e <= s * s + 2.0 * a * m.len * (1.0 + 1e-7) + 1e-6);
                prop_assert!(s * s <= e * e + 2.0 * a * m.len * (1.0 + 1e-7) + 1e-6);
                prev_end = e;
            }
            prop_assert!(prev_end == 0.0, "the last block stops");
            times.push(blocks.iter().map(|b| b.duration_s().to_num::<f64>()).sum::<f64>());
        }
        for w in times.windows(2) {
            prop_assert!(w[0] >= w[1] - 1e-6, "longer queue slower: {times:?}");
        }
        prop_assert!(times[3] >= full_t - 1e-6);
    }
}

#[test]
fn circle_needs_enough_lookahead() {
    // 20 mm circle in 360 segments at 60 mm/s: reaching 60 mm/s needs 3.6 mm (21 segments)
    // of stopping distance queued.
    let n = 360;
    let pt = |i: usize| {
        let a = i as f64 / n as f64 * std::f64::consts::TAU;
        [
            (100_000.0 + 10_000.0 * a.cos()).round() as i32,
            (100_000.0 + 10_000.0 * a.sin()).round() as i32,
        ]
    };
    let moves: Vec<Move> = (1..=n).map(|i| mv([pt(i)[0], pt(i)[1], 0, 0], 60.0, Print)).collect();
    let cfg = JobConfig { start_um: [pt(0)[0], pt(0)[1], 0, 0], ..JobConfig::default() };
    let peak = |b: &[Block]| b.iter().map(|b| v(b.cruise_speed_mm_s())).fold(0.0, f64::max);
    let (p8, p16, p24, p32) = (
        peak(&plan_all::<8>(&moves, &cfg)),
        peak(&plan_all::<16>(&moves, &cfg)),
        peak(&plan_all::<24>(&moves, &cfg)),
        peak(&plan_all::<32>(&moves, &cfg)),
    );
    eprintln!("circle peak with 8/16/24/32 queued moves: {p8:.2} {p16:.2} {p24:.2} {p32:.2} mm/s");
    assert!(p16 < 0.95 * 60.0 && p32 >= 0.95 * 60.0);
    assert_same_plan(&plan_all::<32>(&moves, &cfg), &reference::plan(&moves, &cfg));
}

#[test]
fn per_axis_limits_apply_along_the_direction() {
    let cfg = JobConfig::default();
    let plan = |moves: &[Move]| plan_all::<8>(moves, &cfg);
    // Z alone: 5 mm/s, 100 mm/s^2.
    let b = plan(&[mv([0, 0, 10_000, 0], 50.0, Travel)]);
    assert!(
        rel(v(b[0].cruise_speed_mm_s()), 5.0) < 1e-9 && rel(v(b[0].accel_mm_s2()), 100.0) < 1e-9
    );
    // XY diagonal at 600 mm/s: each axis may do 500, so the path 500 sqrt2 > 600: feed wins;
    // travel accel 1000 > 500 sqrt2 = 707 per the axes.
    let b = plan(&[mv([200_000, 200_000, 0, 0], 600.0, Travel)]);
    assert!(rel(v(b[0].accel_mm_s2()), 500.0 * 2f64.sqrt()) < 1e-9);
    // Extruder-only: 25 mm/s, 1000 mm/s^2.
    let b = plan(&[mv([0, 0, 0, -6_000], 45.0, Retract)]);
    assert!(rel(v(b[0].cruise_speed_mm_s()), 25.0) < 1e-9);
    // A short XY move with a lot of E: the E axis (25 mm/s) limits the path speed.
    let b = plan(&[mv([10_000, 0, 0, 2_000], 100.0, Print)]);
    let c = v(b[0].cruise_speed_mm_s());
    assert!(c * 0.2 <= 25.0 * (1.0 + 1e-9), "E speed {}", c * 0.2);
}

#[test]
fn only_final_blocks_leave_without_forcing() {
    let cfg = JobConfig::default();
    let mut p: Planner<16> = Planner::new(&cfg.plan, [0; 4]);
    p.push(mv([50_000, 0, 0, 0], 100.0, Travel)).unwrap();
    assert!(p.pop().is_none(), "alone it must assume a stop");
    p.push(mv([100_000, 0, 0, 0], 100.0, Travel)).unwrap();
    // Straight on at 100 mm/s: reachable within 50 mm (10 mm needed), so the head is final.
    let b = p.pop().unwrap();
    assert!(rel(v(b.end_speed_mm_s()), 100.0) < 1e-9);
    assert!(p.pop().is_none());
    let b = p.pop_forced().unwrap();
    assert!(b.ends_at_rest());
    assert!(p.is_empty());
    // Print time bookkeeping.
    let total = p.released_ticks_q16() as f64 / 65536.0 / 72e6;
    // 100 mm at 100 mm/s, 500 mm/s^2: 0.2 s up, 0.8 s cruise, 0.2 s down.
    assert!((total - 1.2).abs() < 1e-9, "{total}");
}

#[test]
fn errors_and_no_ops() {
    let cfg = JobConfig::default();
    let mut p: Planner<2> = Planner::new(&cfg.plan, [0; 4]);
    assert_eq!(p.push(Move::new([1000, 0, 0, 0], mm_s(0.0), Travel)), Err(PlanError::ZeroFeed));
    assert_eq!(
        p.push(mv([0, 20_000_000, 0, 0], 10.0, Travel)),
        Err(PlanError::MoveTooLong { axis: 1 })
    );
    p.push(mv([0, 0, 0, 0], 10.0, Travel)).unwrap();
    assert!(p.is_empty(), "a move to where we are is dropped");
    p.push(mv([1000, 0, 0, 0], 10.0, Travel)).unwrap();
    p.push(mv([2000, 0, 0, 0], 10.0, Travel)).unwrap();
    assert_eq!(p.push(mv([3000, 0, 0, 0], 10.0, Travel)), Err(PlanError::QueueFull));
    assert_eq!(p.position_um(), [2000, 0, 0, 0]);
    assert_eq!(PlanError::QueueFull.to_string(), "planner queue is full");
}

#[test]
fn block_time_at_distance_is_the_trapezoid() {
    let cfg = JobConfig::default();
    let moves = [mv([40_000, 30_000, 0, 0], 120.0, Travel), mv([40_000, 0, 0, 0], 80.0, Travel)];
    let blocks = plan_all::<4>(&moves, &cfg);
    let plan = reference::plan(&moves, &cfg);
    for (b, m) in blocks.iter().zip(&plan) {
        for k in 0..=100 {
            let s = m.len * k as f64 / 100.0;
            let t = b.time_at_q16((s * 1000.0 * 2f64.powi(32)) as u64) as f64 / 65536.0 / 72e6;
            assert!((t - m.time_at(s)).abs() < 2e-9, "s {s}: {t} vs {}", m.time_at(s));
            // The generator's division-free version: within 2^-8 um/s / a.
            let fast = b.step_time_q16((s * 1000.0 * 2f64.powi(32)) as u64) as f64 / 65536.0 / 72e6;
            let bound = 1.0 / 256.0 / (m.accel * 1000.0) + 1e-9;
            assert!((fast - t).abs() <= bound, "s {s}: fast {fast} vs {t} (bound {bound})");
        }
    }
}

#[test]
fn a_dwell_stops_the_head_and_waits_its_exact_time() {
    let cfg = JobConfig::default();
    // Collinear prints that would run through at speed, a 1.25 s dwell after the second.
    let line: Vec<Move> = (1..=4).map(|k| mv([k * 10_000, 0, 0, k * 400], 60.0, Print)).collect();
    let wait = strata::machine::Rate::from_num(1.25);
    let mut moves = line[..2].to_vec();
    moves.push(Move::dwell([0; 4], wait));
    moves.extend_from_slice(&line[2..]);
    let blocks = plan_all::<8>(&moves, &cfg);
    assert_eq!(blocks.len(), 5);
    let d = &blocks[2];
    assert!(d.is_dwell() && !blocks.iter().enumerate().any(|(i, b)| i != 2 && b.is_dwell()));
    // 1.25 s at the planner's clock, exactly, in ticks q16.
    let hz = u64::from(cfg.plan.timer_hz);
    assert_eq!(d.duration_ticks_q16(), hz * 5 / 4 * 65_536);
    // In place (its own target is not read), at rest on both sides.
    assert_eq!((d.start_um(), d.end_um()), (blocks[1].end_um(), blocks[1].end_um()));
    assert!(blocks[1].ends_at_rest() && v(blocks[3].start_speed_mm_s()) == 0.0);
    // Either side is the plan of its own job, from rest to rest.
    let after = JobConfig { start_um: blocks[1].end_um(), ..JobConfig::default() };
    assert_same_plan(&blocks[..2], &reference::plan(&line[..2], &cfg));
    assert_same_plan(&blocks[3..], &reference::plan(&line[2..], &after));
    // A dwell of no time is no block.
    let mut p: Planner<4> = Planner::new(&cfg.plan, [0; 4]);
    p.push(Move::dwell([0; 4], strata::machine::Rate::ZERO)).unwrap();
    assert!(p.is_empty());
}
