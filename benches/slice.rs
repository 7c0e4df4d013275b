//! Slicing throughput: 3DBenchy (225k triangles, parsed, placed and sorted before timing) cut
//! into all 240 layers of closed contours at 0.2 mm, single-threaded, with `peak_needs` (the
//! host's admission check) alongside. Run: `cargo bench --bench slice`. Skips with a message
//! when `../shared/models` is absent.

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use strata::geom::Triangle;
use strata::machine::{MachineConfig, PrintSettings};
use strata::slice::{peak_needs, SliceConfig, SliceScratch, SlicedLayer};
use strata_testkit::models::{placed_sorted, shared_models};

strata::slicer_type! {
    /// Bench capacities: comfortably above 3DBenchy's peaks (4,685 active, 4,681 segments).
    type BenchSlicer = {
        active_triangles: 8192,
        contour_points: 8192,
        contour_loops: 256,
    };
}
type BenchScratch = SliceScratch<8192>;

/// One full run; returns the points emitted so nothing is optimised out.
fn slice_all(
    slicer: &mut BenchSlicer,
    work: &mut BenchScratch,
    tris: &[Triangle],
    config: SliceConfig,
) -> usize {
    slicer.reset(config).expect("valid config");
    let mut points = 0usize;
    let mut sink = |l: SlicedLayer<'_, _, _>| points += black_box(l.layer().points.len());
    for t in tris {
        slicer.push(t, work, &mut sink).expect("slices");
    }
    slicer.finish(work, &mut sink).expect("slices");
    points
}

fn slice(c: &mut Criterion) {
    let Some(dir) = shared_models() else {
        eprintln!("slice: ../shared/models not found, nothing to measure");
        return;
    };
    let bytes = std::fs::read(dir.join("3DBenchy.stl")).expect("read 3DBenchy.stl");
    let tris = placed_sorted(&bytes, &MachineConfig::default()).expect("3DBenchy fits the bed");
    let top = tris.iter().map(Triangle::z_max).max().unwrap_or(0);
    let config = SliceConfig::new(&PrintSettings::default(), top).expect("config");
    let mut slicer = Box::new(BenchSlicer::new(config).expect("config"));
    let mut work = Box::new(BenchScratch::new());
    let mut group = c.benchmark_group("slice");
    group
        .sample_size(20)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(5))
        .throughput(Throughput::Elements(tris.len() as u64));
    group.bench_function("3DBenchy/240_layers", |b| {
        b.iter(|| slice_all(&mut slicer, &mut work, black_box(&tris), config))
    });
    group.bench_function("3DBenchy/peak_needs", |b| {
        b.iter(|| peak_needs(black_box(&tris), &config).expect("needs"))
    });
    group.finish();
}

criterion_group!(benches, slice);
criterion_main!(benches);
