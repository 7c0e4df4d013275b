//! The scratch the slicer and the toolpath stage take turns in: a slicer that cuts in a
//! scratch the toolpath stage has just used (offset engine, infill, ordering grid) gives the
//! same layers as a slicer with a scratch of its own (and the sections' areas of an
//! independent f64 cut), the toolpath stage the same moves and needs as with a scratch of its
//! own, and overflowing a tenant's capacity in the shared scratch is the same typed error.

mod slice_support;

use std::cell::Cell;

use slice_support::config;
use strata::geom::{Point2, Triangle};
use strata::machine::{MachineConfig, PrintSettings};
use strata::scratch::Scratch;
use strata::slice::{
    Layer, LayerRepairs, LoopInfo, Resource, SliceConfig, SliceError, SliceScratch, SlicedLayer,
    Slicer,
};
use strata::toolpath::{
    Buffer, ToolEvent, ToolMove, Toolpath, ToolpathConfig, ToolpathError, ToolpathScratch,
    ToolpathStats,
};
use strata_testkit::check::assert_section_area;
use strata_testkit::mesh::{cuboid, holed_prism, loft, ngon, sphere, to_um, TriMm};
use strata_testkit::on_big_stack;

/// Slicer capacities: active triangles, loops (segments per test).
const A: usize = 512;
const L: usize = 16;
/// Toolpath capacities: PTS, and LOOPS, CROSS, PATH, RING, SPANS in `Stage`.
const PTS: usize = 4096;
type Stage<const CROSS: usize> = Toolpath<PTS, 16, CROSS, 8192, 8192, 1024>;

/// A layer copied out of the slicer's sink, every field kept.
#[derive(Debug, Clone, PartialEq)]
struct RawLayer {
    index: u32,
    z_um: i32,
    points: Vec<Point2>,
    loops: Vec<LoopInfo>,
    repairs: LayerRepairs,
    dropped_small_loops: u32,
    active_triangles: u32,
    segments: u32,
}

impl RawLayer {
    fn copy(l: &Layer<'_>) -> Self {
        Self {
            index: l.index,
            z_um: l.z_um,
            points: l.points.to_vec(),
            loops: l.loops.to_vec(),
            repairs: l.repairs,
            dropped_small_loops: l.dropped_small_loops,
            active_triangles: l.active_triangles,
            segments: l.segments,
        }
    }

    fn layer(&self) -> Layer<'_> {
        Layer {
            index: self.index,
            z_um: self.z_um,
            points: &self.points,
            loops: &self.loops,
            repairs: self.repairs,
            dropped_small_loops: self.dropped_small_loops,
            active_triangles: self.active_triangles,
            segments: self.segments,
        }
    }
}

/// What one run produced: the layers (and the slicer's error), the moves and the toolpath
/// stage's totals (or error).
struct Run {
    layers: Vec<RawLayer>,
    slice_error: Option<SliceError>,
    moves: Vec<ToolMove>,
    toolpath: Result<ToolpathStats, ToolpathError>,
    /// Per layer cut: how many layers the toolpath stage had finished in the scratch before.
    finished_before_cut: Vec<u32>,
}

fn toolpath_config() -> ToolpathConfig {
    ToolpathConfig::new(&MachineConfig::default(), &PrintSettings::default())
}

/// Slicer and toolpath stage taking turns in one scratch (as the printer runs them).
fn shared<const S: usize, const CROSS: usize>(tris: &[Triangle], slice_cfg: SliceConfig) -> Run {
    let mut slicer = Box::new(Slicer::<A, S, L>::new(slice_cfg).unwrap());
    let mut tp = Box::new(Stage::<CROSS>::new(toolpath_config()).unwrap());
    let mut work = Box::new(Scratch::<S, PTS, CROSS>::new());
    let (mut moves, finished) = (Vec::new(), Cell::new(0u32));
    let mut events = |e: &ToolEvent<'_>| match e {
        ToolEvent::Move(m) => moves.push(*m),
        ToolEvent::LayerEnd(_) => finished.set(finished.get() + 1),
        _ => {}
    };
    let (mut layers, mut finished_before_cut, mut failed) = (Vec::new(), Vec::new(), None);
    let mut sink = |l: SlicedLayer<'_, S, Scratch<S, PTS, CROSS>>| {
        layers.push(RawLayer::copy(&l.layer()));
        finished_before_cut.push(finished.get());
        if failed.is_none() {
            failed = tp.push_sliced(l, &mut events).err();
        }
    };
    let sliced = tris
        .iter()
        .try_for_each(|t| slicer.push(t, &mut *work, &mut sink))
        .and_then(|()| slicer.finish(&mut *work, &mut sink));
    let toolpath = match failed {
        Some(e) => Err(e),
        None if sliced.is_ok() => tp.finish(&mut *work, &mut events),
        None => Ok(tp.stats()),
    };
    Run { layers, slice_error: sliced.err(), moves, toolpath, finished_before_cut }
}

/// A slicer alone, in a scratch of its own.
fn slice_alone<const S: usize>(
    tris: &[Triangle],
    slice_cfg: SliceConfig,
) -> (Vec<RawLayer>, Option<SliceError>) {
    let mut slicer = Box::new(Slicer::<A, S, L>::new(slice_cfg).unwrap());
    let mut work = Box::new(SliceScratch::<S>::new());
    let mut layers = Vec::new();
    let mut sink = |l: SlicedLayer<'_, S, SliceScratch<S>>| layers.push(RawLayer::copy(&l.layer()));
    let sliced = tris
        .iter()
        .try_for_each(|t| slicer.push(t, &mut *work, &mut sink))
        .and_then(|()| slicer.finish(&mut *work, &mut sink));
    (layers, sliced.err())
}

/// A toolpath stage alone, in a scratch of its own, over `layers`.
fn toolpath_alone<const CROSS: usize>(
    layers: &[RawLayer],
) -> (Vec<ToolMove>, Result<ToolpathStats, ToolpathError>) {
    let mut tp = Box::new(Stage::<CROSS>::new(toolpath_config()).unwrap());
    let mut work = Box::new(ToolpathScratch::<PTS, CROSS>::new());
    let mut moves = Vec::new();
    let mut events = |e: &ToolEvent<'_>| {
        if let ToolEvent::Move(m) = e {
            moves.push(*m);
        }
    };
    let pushed = layers.iter().try_for_each(|l| tp.push_layer(&l.layer(), &mut *work, &mut events));
    let result = pushed.and_then(|()| tp.finish(&mut *work, &mut events));
    (moves, result)
}

/// A sphere beside a ring with a hole: loops of many sizes, holes, infill and skins.
fn parts() -> Vec<TriMm> {
    let mut mesh = sphere([110.0, 110.0, 4.0], 4.0, 40, 20);
    mesh.extend(holed_prism(
        &ngon(12, 125.0, 110.0, 6.0, 0.1),
        &ngon(12, 125.0, 110.0, 2.5, 0.1),
        0.0,
        3.0,
    ));
    mesh
}

#[test]
fn a_cut_after_the_toolpath_stage_slices_and_prints_as_with_scratches_of_their_own() {
    on_big_stack(|| {
        let tris = to_um(&parts());
        let cfg = config(&tris, 0);
        let run = shared::<256, 2048>(&tris, cfg);
        assert_eq!(run.slice_error, None);
        // From layer `top + 1` on, every cut follows layers the toolpath stage built in the
        // scratch.
        let top = usize::from(toolpath_config().top_layers);
        assert!(run.finished_before_cut[top + 1..].iter().all(|&n| n > 0));
        let (alone, error) = slice_alone::<256>(&tris, cfg);
        assert_eq!(error, None);
        assert_eq!(run.layers.len(), cfg.layer_count() as usize);
        assert_eq!(run.layers, alone);
        // And the sections are right (independent f64 cut, 0.1 % or 1 um x the cut length).
        for l in &run.layers {
            let got: i64 = l.loops.iter().map(|i| i.area_um2).sum();
            assert_section_area(&format!("layer {}", l.index), got as f64, &tris, l.z_um, 0.0);
        }
        let (moves, stats) = toolpath_alone::<2048>(&alone);
        let stats = stats.unwrap();
        assert!(stats.layers > 0 && stats.needs.crossings > 0 && stats.needs.offset_edges > 0);
        assert_eq!(run.toolpath, Ok(stats));
        assert_eq!(run.moves, moves);
    });
}

#[test]
fn a_full_tenant_in_the_shared_scratch_is_the_same_typed_error() {
    on_big_stack(|| {
        // 8 segments a layer up to 2 mm, then 80: the cut of layer 10 overflows 64 segments
        // after the toolpath stage has built layers in the scratch.
        let mut mesh = cuboid([100.0, 100.0, 0.0], [120.0, 120.0, 2.0]);
        let ring = ngon(40, 110.0, 110.0, 8.0, 0.0);
        mesh.extend(loft(&[(2.0, ring.clone()), (3.0, ring)]));
        let tris = to_um(&mesh);
        let cfg = config(&tris, 0);
        let run = shared::<64, 2048>(&tris, cfg);
        let full = SliceError::Capacity { what: Resource::Segments, capacity: 64, layer: 10 };
        assert_eq!(run.slice_error, Some(full));
        assert!(run.finished_before_cut.last().is_some_and(|&n| n > 0));
        let (alone, error) = slice_alone::<64>(&tris, cfg);
        assert_eq!((&run.layers, run.slice_error), (&alone, error));
        assert_eq!(alone.len(), 10);
        // The toolpath stage's crossings overflow in the shared scratch; the slicer goes on
        // cutting in it.
        let tris = to_um(&parts());
        let cfg = config(&tris, 0);
        let run = shared::<256, 8>(&tris, cfg);
        let full = ToolpathError::Capacity { what: Buffer::Crossings, capacity: 8, layer: 0 };
        assert_eq!(run.toolpath, Err(full));
        let (alone, error) = slice_alone::<256>(&tris, cfg);
        assert_eq!((&run.layers, run.slice_error), (&alone, error));
        assert_eq!(toolpath_alone::<8>(&alone).1, Err(full));
    });
}
