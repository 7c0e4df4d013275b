//! Helpers for the slicer tests: a runner that collects every layer into owned data, and the
//! check of a layer against the f64 section-area oracle (meshes and oracle: `strata_testkit`).
#![allow(dead_code)] // each test crate uses a different subset

use strata::geom::{Point2, Triangle};
use strata::machine::PrintSettings;
use strata::slice::{
    LayerRepairs, SliceConfig, SliceError, SliceScratch, SliceStats, SlicedLayer, Slicer,
};

/// `toolpath_props` takes these two from here.
#[allow(unused_imports)]
pub use strata_testkit::mesh::{cuboid, to_um};

/// Highest z of the triangles (the placed model's top).
pub fn top(tris: &[Triangle]) -> i32 {
    tris.iter().map(Triangle::z_max).max().unwrap_or(0)
}

/// The default 0.2 mm config for these triangles, with `min_loop_area_um2` as given.
pub fn config(tris: &[Triangle], min_loop_area_um2: i64) -> SliceConfig {
    let mut c = SliceConfig::new(&PrintSettings::default(), top(tris)).unwrap();
    c.min_loop_area_um2 = min_loop_area_um2;
    c
}

/// A loop copied out of a layer.
#[derive(Debug, Clone)]
pub struct OwnedLoop {
    pub points: Vec<Point2>,
    pub hole: bool,
    pub parent: Option<u32>,
    pub area_um2: i64,
}

/// A layer copied out of the sink.
#[derive(Debug, Clone)]
pub struct OwnedLayer {
    pub index: u32,
    pub z_um: i32,
    pub loops: Vec<OwnedLoop>,
    pub repairs: LayerRepairs,
    pub dropped_small_loops: u32,
    pub segments: u32,
    pub active: u32,
}

impl OwnedLayer {
    /// Sum of signed loop areas (outer minus holes), um^2.
    pub fn area_um2(&self) -> i64 {
        self.loops.iter().map(|l| l.area_um2).sum()
    }

    pub fn holes(&self) -> usize {
        self.loops.iter().filter(|l| l.hole).count()
    }
}

/// Runs a `Slicer<ACTIVE, SEGMENTS, LOOPS>` over sorted triangles on a thread with a large
/// stack (the slicer value is big in debug builds) and collects every layer.
pub fn run<const A: usize, const S: usize, const L: usize>(
    tris: &[Triangle],
    config: SliceConfig,
) -> Result<(Vec<OwnedLayer>, SliceStats), SliceError> {
    strata_testkit::on_big_stack(|| {
        let mut slicer = Slicer::<A, S, L>::new(config)?;
        let mut work = Box::new(SliceScratch::new());
        let mut layers = Vec::new();
        let mut sink = |l: SlicedLayer<'_, S, SliceScratch<S>>| {
            let l = l.layer();
            layers.push(OwnedLayer {
                index: l.index,
                z_um: l.z_um,
                loops: l
                    .loops
                    .iter()
                    .map(|info| OwnedLoop {
                        points: l.loop_points(info).to_vec(),
                        hole: info.hole,
                        parent: info.parent,
                        area_um2: info.area_um2,
                    })
                    .collect(),
                repairs: l.repairs,
                dropped_small_loops: l.dropped_small_loops,
                segments: l.segments,
                active: l.active_triangles,
            })
        };
        for t in tris {
            slicer.push(t, &mut *work, &mut sink)?;
        }
        let stats = slicer.finish(&mut *work, &mut sink)?;
        Ok((layers, stats))
    })
}

/// Default test capacities.
pub fn slice(tris: &[Triangle], config: SliceConfig) -> (Vec<OwnedLayer>, SliceStats) {
    run::<8192, 8192, 512>(tris, config).expect("slicing failed")
}

/// Checks one layer against the oracle: area within 0.1 % (or 1 um x the cut length for
/// slivers), every loop oriented as its `hole` flag says, holes having a parent.
pub fn check_layer(layer: &OwnedLayer, tris: &[Triangle], what: &str) {
    check_layer_within(layer, tris, what, 0.0);
}

/// [`check_layer`] with `extra_um2` more area tolerance (for loops dropped as too small).
pub fn check_layer_within(layer: &OwnedLayer, tris: &[Triangle], what: &str, extra_um2: f64) {
    let got = layer.area_um2() as f64;
    let what_layer = format!("{what} layer {}", layer.index);
    strata_testkit::check::assert_section_area(&what_layer, got, tris, layer.z_um, extra_um2);
    for l in &layer.loops {
        let doubled = strata::geom::doubled_signed_area(&l.points);
        assert_eq!(doubled > 0, !l.hole, "{what} layer {}: orientation", layer.index);
        assert!(l.points.len() >= 3);
        if l.hole {
            assert!(l.parent.is_some(), "{what} layer {}: hole without parent", layer.index);
        }
    }
}
