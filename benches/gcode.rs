//! 3DBenchy from file bytes to G-code text, single-threaded, and its split by stage:
//! - `file_to_gcode`: parse (binary STL), place, sort by lowest z, slice (240 layers),
//!   toolpaths, G-code into a `String` (what `strata slice -o` does, minus the file write);
//! - `parse`: parse, place and sort only;
//! - `slice`: the slicer alone over the sorted triangles;
//! - `toolpath`: the toolpath stage alone over the 240 layers sliced beforehand;
//! - `gcode`: the G-code writer alone over the moves built beforehand.
//!
//! Before measuring it prints the sizes of the stage values and, at the end, the process's
//! peak resident memory (VmHWM). Run: `cargo bench --bench gcode`. Skips with a message when
//! `../shared/models` is absent.

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion};
use strata::gcode::{GcodeOptions, GcodeWriter};
use strata::geom::{Point2, Triangle};
use strata::machine::{MachineConfig, PrintSettings};
use strata::slice::{Layer, LayerRepairs, LoopInfo, SliceConfig, SlicedLayer};
use strata::toolpath::{ToolEvent, ToolMove, ToolpathConfig};
use strata_testkit::models::{placed_sorted, shared_models};

strata::slicer_type! {
    /// Capacities comfortably above 3DBenchy's needs (see `examples/toolpath_report.rs`).
    type BenchSlicer = {
        active_triangles: 8192,
        contour_points: 8192,
        contour_loops: 256,
    };
}
strata::toolpath_type! {
    type BenchToolpath = {
        toolpath_points: 8192,
        toolpath_loops: 256,
        scan_crossings: 16384,
        path_points: 32768,
        window_ring_words: 16384,
        window_spans: 16384,
    };
}
strata::scratch_type! {
    /// The scratch both take turns in (SEGMENTS, PTS, CROSS as theirs).
    type BenchScratch = {
        contour_points: 8192,
        toolpath_points: 8192,
        scan_crossings: 16384,
    };
}

/// The stage values, built once on a thread with a big stack (they are megabytes).
struct Stages {
    slicer: Box<BenchSlicer>,
    toolpath: Box<BenchToolpath>,
    work: Box<BenchScratch>,
}

fn stages(slice: SliceConfig, cfg: ToolpathConfig) -> Stages {
    strata_testkit::on_big_stack(move || Stages {
        slicer: Box::new(BenchSlicer::new(slice).expect("slice config")),
        toolpath: Box::new(BenchToolpath::new(cfg).expect("toolpath config")),
        work: Box::new(BenchScratch::new()),
    })
}

/// A layer copied out of the slicer.
struct OwnedLayer {
    index: u32,
    z_um: i32,
    points: Vec<Point2>,
    loops: Vec<LoopInfo>,
}

/// Everything a run needs besides the stage values.
struct Job {
    machine: MachineConfig,
    settings: PrintSettings,
    cfg: ToolpathConfig,
    slice: SliceConfig,
}

/// File bytes to G-code text.
fn file_to_gcode(bytes: &[u8], job: &Job, st: &mut Stages) -> String {
    let tris = placed_sorted(bytes, &job.machine).expect("3DBenchy parses and fits the bed");
    let top = tris.iter().map(Triangle::z_max).max().unwrap_or(0);
    let mut slice = job.slice;
    slice.model_height_um = top;
    st.slicer.reset(slice).expect("slice config");
    st.toolpath.reset(job.cfg).expect("toolpath config");
    let mut gw =
        GcodeWriter::new(String::with_capacity(4 << 20), GcodeOptions::default(), &job.cfg);
    gw.start(&job.machine, &job.settings, &job.cfg).expect("write");
    let (pos, z) = gw.position();
    st.toolpath.set_position(pos, z);
    let tp = &mut st.toolpath;
    let mut events = |e: &ToolEvent<'_>| gw.event(e).expect("write");
    let mut sink = |l: SlicedLayer<'_, _, _>| tp.push_sliced(l, &mut events).expect("toolpaths");
    for t in &tris {
        st.slicer.push(t, &mut *st.work, &mut sink).expect("slices");
    }
    st.slicer.finish(&mut *st.work, &mut sink).expect("slices");
    st.toolpath.finish(&mut *st.work, &mut events).expect("toolpaths");
    gw.end(&job.machine, &job.cfg).expect("write");
    gw.into_inner()
}

fn slice_layers(tris: &[Triangle], st: &mut Stages, slice: SliceConfig) -> Vec<OwnedLayer> {
    st.slicer.reset(slice).expect("slice config");
    let mut out = Vec::new();
    let mut sink = |l: SlicedLayer<'_, _, _>| {
        let l = l.layer();
        out.push(OwnedLayer {
            index: l.index,
            z_um: l.z_um,
            points: l.points.to_vec(),
            loops: l.loops.to_vec(),
        })
    };
    for t in tris {
        st.slicer.push(t, &mut *st.work, &mut sink).expect("slices");
    }
    st.slicer.finish(&mut *st.work, &mut sink).expect("slices");
    out
}

fn toolpaths(
    layers: &[OwnedLayer],
    st: &mut Stages,
    cfg: ToolpathConfig,
    start: (Point2, i32),
) -> Vec<ToolEvent<'static>> {
    st.toolpath.reset(cfg).expect("toolpath config");
    st.toolpath.set_position(start.0, start.1);
    let mut moves: Vec<ToolEvent<'static>> = Vec::with_capacity(80_000);
    let mut events = |e: &ToolEvent<'_>| match *e {
        ToolEvent::Move(m) => moves.push(ToolEvent::Move(m)),
        ToolEvent::LayerStart { index, z_um, height_um } => {
            moves.push(ToolEvent::LayerStart { index, z_um, height_um })
        }
        ToolEvent::LayerEnd(_) | ToolEvent::Progress => {}
    };
    for l in layers {
        let layer = Layer {
            index: l.index,
            z_um: l.z_um,
            points: &l.points,
            loops: &l.loops,
            repairs: LayerRepairs::default(),
            dropped_small_loops: 0,
            active_triangles: 0,
            segments: l.points.len() as u32,
        };
        st.toolpath.push_layer(&layer, &mut *st.work, &mut events).expect("toolpaths");
    }
    st.toolpath.finish(&mut *st.work, &mut events).expect("toolpaths");
    moves
}

fn gcode(events: &[ToolEvent<'static>], job: &Job) -> String {
    let mut gw =
        GcodeWriter::new(String::with_capacity(4 << 20), GcodeOptions::default(), &job.cfg);
    gw.start(&job.machine, &job.settings, &job.cfg).expect("write");
    for e in events {
        gw.event(e).expect("write");
    }
    gw.end(&job.machine, &job.cfg).expect("write");
    gw.into_inner()
}

fn peak_rss_kb() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

fn bench(c: &mut Criterion) {
    let Some(dir) = shared_models() else {
        eprintln!("gcode: ../shared/models not found, nothing to measure");
        return;
    };
    let bytes = std::fs::read(dir.join("3DBenchy.stl")).expect("read 3DBenchy.stl");
    let machine = MachineConfig::default();
    let settings = PrintSettings::default();
    let cfg = ToolpathConfig::new(&machine, &settings);
    let tris = placed_sorted(&bytes, &machine).expect("3DBenchy parses and fits the bed");
    let top = tris.iter().map(Triangle::z_max).max().unwrap_or(0);
    let slice = SliceConfig::new(&settings, top).expect("slice config");
    let job = Job { machine, settings, cfg, slice };
    let mut st = stages(slice, cfg);
    eprintln!(
        "stage values: slicer {} KB, toolpath {} KB, their scratch {} KB",
        std::mem::size_of::<BenchSlicer>() / 1024,
        std::mem::size_of::<BenchToolpath>() / 1024,
        std::mem::size_of::<BenchScratch>() / 1024
    );
    let text = file_to_gcode(&bytes, &job, &mut st);
    let stats = st.toolpath.stats();
    eprintln!(
        "3DBenchy: {} layers, {} bytes of G-code, {} moves, {} retractions, needs {:?}",
        stats.layers,
        text.len(),
        stats.extrusion_moves + stats.travel_moves,
        stats.retractions,
        stats.needs
    );
    let layers = slice_layers(&tris, &mut st, slice);
    // Where the start sequence leaves the nozzle.
    let mut probe = GcodeWriter::new(String::new(), GcodeOptions::default(), &cfg);
    probe.start(&job.machine, &job.settings, &cfg).expect("write");
    let start = probe.position();
    let events = toolpaths(&layers, &mut st, cfg, start);
    assert_eq!(gcode(&events, &job), text, "the split reproduces the whole run");
    let mut group = c.benchmark_group("gcode");
    group
        .sample_size(20)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(8));
    group.bench_function("3DBenchy/file_to_gcode", |b| {
        b.iter(|| file_to_gcode(black_box(&bytes), &job, &mut st).len())
    });
    group.bench_function("3DBenchy/parse", |b| {
        b.iter(|| placed_sorted(black_box(&bytes), &job.machine).map(|t| t.len()))
    });
    group.bench_function("3DBenchy/slice", |b| {
        b.iter(|| {
            st.slicer.reset(slice).expect("slice config");
            let mut n = 0usize;
            let mut sink = |l: SlicedLayer<'_, _, _>| n += black_box(l.layer().points.len());
            for t in &tris {
                st.slicer.push(t, &mut *st.work, &mut sink).expect("slices");
            }
            st.slicer.finish(&mut *st.work, &mut sink).expect("slices");
            n
        })
    });
    group.bench_function("3DBenchy/toolpath", |b| {
        b.iter(|| toolpaths(black_box(&layers), &mut st, cfg, start).len())
    });
    group.bench_function("3DBenchy/gcode", |b| b.iter(|| gcode(black_box(&events), &job).len()));
    group.finish();
    let moves = events.iter().filter(|e| matches!(e, ToolEvent::Move(ToolMove { .. }))).count();
    eprintln!("{moves} moves; peak resident memory {} KB", peak_rss_kb().unwrap_or(0));
}

criterion_group!(benches, bench);
criterion_main!(benches);
