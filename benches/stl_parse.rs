//! STL parsing throughput: binary 3DBenchy (11 MB) and the 1.2 MB ASCII bwb model from
//! `../shared/models`, parsed from memory whole and in 4096-byte chunks (the streaming case).
//! Run: `cargo bench --bench stl_parse`. Skips with a message when the models are absent.

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use strata::stl::{RawTriangle, StlReader};
use strata_testkit::models::shared_models;

/// Parses `bytes` fed in `chunk`-byte pieces; returns the facet count so nothing is optimised out.
fn parse(bytes: &[u8], chunk: usize) -> usize {
    let mut n = 0usize;
    let mut sink = |t: RawTriangle| {
        black_box(&t);
        n += 1;
    };
    let mut reader = StlReader::new();
    for piece in bytes.chunks(chunk) {
        reader.feed(piece, &mut sink).expect("model parses");
    }
    reader.finish().expect("model parses");
    n
}

fn stl_parse(c: &mut Criterion) {
    let Some(dir) = shared_models() else {
        eprintln!("stl_parse: ../shared/models not found, nothing to measure");
        return;
    };
    let models =
        [("binary/3DBenchy", "3DBenchy.stl"), ("ascii/bwb", "numpy-stl/stl_tests__bwb.stl")];
    let mut group = c.benchmark_group("stl_parse");
    group
        .sample_size(20)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(4));
    for (name, file) in models {
        let bytes = std::fs::read(dir.join(file)).expect("read model");
        group.throughput(Throughput::Bytes(bytes.len() as u64));
        for chunk in [usize::MAX, 4096] {
            let label = if chunk == usize::MAX { "whole".to_string() } else { format!("{chunk}") };
            group.bench_with_input(BenchmarkId::new(name, label), &bytes, |b, bytes| {
                b.iter(|| parse(black_box(bytes), chunk))
            });
        }
    }
    group.finish();
}

criterion_group!(benches, stl_parse);
criterion_main!(benches);
