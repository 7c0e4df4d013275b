//! Step generation and execution throughput on the host: steps per second.
//!
//! `cargo bench --bench step`; the figure is criterion's `thrpt` in steps (elements) per
//! second:
//! - `generate`: exact step times + compression into the queue (queue drained without
//!   executing);
//! - `generate_execute`: the same plus the executor driving no-op pins for every step, as
//!   the timer interrupt would (its share is the difference).

use core::convert::Infallible;

use criterion::{black_box, criterion_group, criterion_main, Criterion, Throughput};
use embedded_hal::digital::{ErrorType, OutputPin};
use strata::machine::{Rate, AXES};
use strata::plan::{Block, Move, MoveKind, PlanConfig, Planner};
use strata::step::{Executor, Pins, StepConfig, StepGenerator, StepQueue, Wake};

struct NullPin;

impl ErrorType for NullPin {
    type Error = Infallible;
}

impl OutputPin for NullPin {
    fn set_low(&mut self) -> Result<(), Infallible> {
        Ok(())
    }
    fn set_high(&mut self) -> Result<(), Infallible> {
        Ok(())
    }
}

/// A printing job: a 20 mm circle (360 segments, 60 mm/s) twice, then infill lines at
/// 80 mm/s and long travels at 200 mm/s.
fn job() -> ([i32; 4], Vec<Block>, u64) {
    let n = 360;
    let pt = |i: usize| {
        let a = i as f64 / n as f64 * std::f64::consts::TAU;
        [
            (100_000.0 + 10_000.0 * a.cos()).round() as i32,
            (100_000.0 + 10_000.0 * a.sin()).round() as i32,
        ]
    };
    let mut moves = Vec::new();
    let mut e = 0;
    for i in 1..=2 * n {
        let p = pt(i % n);
        e += 6;
        moves.push(Move::new([p[0], p[1], 200, e], Rate::from_num(60), MoveKind::Print));
    }
    for i in 0..60 {
        let y = 80_000 + 450 * i;
        let x = if i % 2 == 0 { 130_000 } else { 70_000 };
        e += 2_000;
        moves.push(Move::new([x, y, 200, e], Rate::from_num(80), MoveKind::Print));
        moves.push(Move::new([x, y + 450, 200, e + 15], Rate::from_num(80), MoveKind::Print));
    }
    moves.push(Move::new([10_000, 10_000, 200, e], Rate::from_num(200), MoveKind::Travel));
    moves.push(Move::new([200_000, 180_000, 200, e], Rate::from_num(200), MoveKind::Travel));
    let start = [pt(0)[0], pt(0)[1], 200, 0];
    let mut p: Planner<32> = Planner::new(&PlanConfig::default(), start);
    let mut blocks = Vec::new();
    for m in &moves {
        if p.is_full() {
            blocks.push(p.pop().or_else(|| p.pop_forced()).unwrap());
        }
        p.push(*m).unwrap();
        while let Some(b) = p.pop() {
            blocks.push(b);
        }
    }
    while let Some(b) = p.pop_forced() {
        blocks.push(b);
    }
    let steps = generate(start, &blocks);
    (start, blocks, steps)
}

/// Generates every step, draining the queues as they fill; returns the step count.
fn generate(start: [i32; 4], blocks: &[Block]) -> u64 {
    let cfg = StepConfig::default();
    let mut q: StepQueue<64> = StepQueue::new();
    let (mut prod, mut cons) = q.split();
    let mut gen: StepGenerator = StepGenerator::new(&cfg, start);
    let mut next = blocks.iter();
    let mut pending = next.next();
    loop {
        if gen.wants_block() {
            if let Some(b) = pending {
                gen.load(*b).unwrap();
                pending = next.next();
            }
        }
        let st = gen.run(&mut prod);
        for axis in 0..AXES {
            while let Some(c) = cons.dequeue(axis) {
                black_box(c);
            }
        }
        if pending.is_none() && gen.is_idle() && st == strata::step::GenStatus::Idle {
            break;
        }
    }
    gen.stats().steps.iter().sum()
}

/// Generates and executes every step on no-op pins; returns the executed step count.
fn generate_execute(start: [i32; 4], blocks: &[Block]) -> u64 {
    let cfg = StepConfig::default();
    let mut q: StepQueue<64> = StepQueue::new();
    let (mut prod, cons) = q.split();
    let mut gen: StepGenerator = StepGenerator::new(&cfg, start);
    let mut exec = Executor::new(&cfg, cons);
    let mut pins = Pins {
        step: [NullPin, NullPin, NullPin, NullPin],
        dir: [NullPin, NullPin, NullPin, NullPin],
        enable: NullPin,
    };
    let mut next = blocks.iter();
    let mut pending = next.next();
    let mut now = 0u32;
    loop {
        if gen.wants_block() {
            if let Some(b) = pending {
                gen.load(*b).unwrap();
                pending = next.next();
            }
        }
        gen.run(&mut prod);
        // Run the interrupt until half a queue's worth has been consumed, as the firmware's
        // main loop would get to refill it.
        for _ in 0..256 {
            match exec.on_timer(now, &mut pins).unwrap() {
                Wake::At(t) => now = t,
                Wake::Idle => break,
            }
        }
        if pending.is_none() && gen.is_idle() && exec.is_idle() {
            break;
        }
    }
    exec.stats().steps.iter().sum()
}

fn bench(c: &mut Criterion) {
    let (start, blocks, steps) = job();
    let mut g = c.benchmark_group("step");
    g.throughput(Throughput::Elements(steps));
    g.sample_size(20);
    g.bench_function("generate", |b| b.iter(|| generate(start, &blocks)));
    g.bench_function("generate_execute", |b| {
        b.iter(|| assert_eq!(generate_execute(start, &blocks), steps))
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
