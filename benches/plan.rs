//! Planner throughput on the host: moves planned per second (push, lookahead, release).
//!
//! `cargo bench --bench plan`; the figure is criterion's `thrpt` in moves (elements) per
//! second.

use criterion::{black_box, criterion_group, criterion_main, Criterion, Throughput};
use strata::machine::Rate;
use strata::plan::{Move, MoveKind, PlanConfig, Planner};

/// A 20 mm circle in `n` segments at 60 mm/s, extruding, repeated `laps` times.
fn circle(n: usize, laps: usize) -> ([i32; 4], Vec<Move>) {
    let pt = |i: usize| {
        let a = i as f64 / n as f64 * std::f64::consts::TAU;
        [
            (100_000.0 + 10_000.0 * a.cos()).round() as i32,
            (100_000.0 + 10_000.0 * a.sin()).round() as i32,
        ]
    };
    let mut moves = Vec::new();
    for i in 1..=n * laps {
        let p = pt(i % n);
        moves.push(Move::new(
            [p[0], p[1], 200, (i * 6) as i32],
            Rate::from_num(60),
            MoveKind::Print,
        ));
    }
    ([pt(0)[0], pt(0)[1], 200, 0], moves)
}

/// Infill-like zig-zag with travels and retractions (0.45 mm line spacing, 40 mm lines).
fn zigzag(lines: usize) -> ([i32; 4], Vec<Move>) {
    let mut moves = Vec::new();
    let mut e = 0;
    for i in 0..lines {
        let y = 80_000 + 450 * i as i32;
        let x = if i % 2 == 0 { 120_000 } else { 80_000 };
        e += 1_330;
        moves.push(Move::new([x, y, 200, e], Rate::from_num(80), MoveKind::Print));
        e += 15;
        moves.push(Move::new([x, y + 450, 200, e], Rate::from_num(80), MoveKind::Print));
        if i % 25 == 24 {
            moves.push(Move::new(
                [x, y + 450, 200, e - 5000],
                Rate::from_num(45),
                MoveKind::Retract,
            ));
            moves.push(Move::new([x, y + 450, 200, e], Rate::from_num(45), MoveKind::Retract));
        }
    }
    ([80_000, 80_000, 200, 0], moves)
}

fn plan_all<const N: usize>(start: [i32; 4], moves: &[Move], cfg: &PlanConfig) -> u64 {
    let mut p: Planner<N> = Planner::new(cfg, start);
    for m in moves {
        if p.is_full() {
            black_box(p.pop().or_else(|| p.pop_forced()));
        }
        p.push(*m).unwrap();
        while let Some(b) = p.pop() {
            black_box(b);
        }
    }
    while let Some(b) = p.pop_forced() {
        black_box(b);
    }
    p.released_ticks_q16()
}

fn bench(c: &mut Criterion) {
    let cfg = PlanConfig::default();
    let mut g = c.benchmark_group("plan");
    for (name, (start, moves)) in [("circle_360x4", circle(360, 4)), ("zigzag_infill", zigzag(400))]
    {
        g.throughput(Throughput::Elements(moves.len() as u64));
        g.bench_function(format!("{name}/queue32"), |b| {
            b.iter(|| plan_all::<32>(start, &moves, &cfg))
        });
        g.bench_function(format!("{name}/queue16"), |b| {
            b.iter(|| plan_all::<16>(start, &moves, &cfg))
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
