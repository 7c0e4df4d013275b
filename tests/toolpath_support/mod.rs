//! Helpers for the toolpath and G-code tests: run the slicer and the toolpath stage on a
//! thread with a big stack and collect every layer's moves; check a run's extrusions against
//! its contours with the f64 oracles of `strata_testkit::check`.
#![allow(dead_code)] // each test crate uses a different subset

use strata::geom::{Point2, Triangle};
use strata::machine::{MachineConfig, PrintSettings};
use strata::scratch::Scratch;
use strata::slice::{SliceConfig, SlicedLayer};
use strata::toolpath::{
    Feature, LayerStats, ToolEvent, ToolMove, Toolpath, ToolpathConfig, ToolpathError,
    ToolpathStats,
};
use strata_testkit::check::{self, TopCoverage};
use strata_testkit::mesh::{to_um, TriMm};

strata::toolpath_type! {
    /// Host-sized capacities for tests: PTS, LOOPS, CROSS, PATH, RING, SPANS.
    pub type TestToolpath = {
        toolpath_points: 16384,
        toolpath_loops: 1024,
        scan_crossings: 32768,
        path_points: 65536,
        window_ring_words: 65536,
        window_spans: 65536,
    };
}
strata::slicer_type! {
    /// Slicer capacities for tests.
    pub type TestSlicer = {
        active_triangles: 16384,
        contour_points: 16384,
        contour_loops: 1024,
    };
}
/// The scratch a [`TestSlicer`] and a toolpath stage of `PTS` and `CROSS` take turns in.
pub type TestScratch<const PTS: usize, const CROSS: usize> = Scratch<16384, PTS, CROSS>;

/// Records one of the stage's events into `layers` (a layer per `LayerStart`, its moves and
/// its counters); false for a move or a layer end that came before any layer.
pub fn record(layers: &mut Vec<TpLayer>, e: &ToolEvent<'_>) -> bool {
    match e {
        ToolEvent::LayerStart { index, z_um, height_um } => layers.push(TpLayer {
            index: *index,
            z_um: *z_um,
            height_um: *height_um,
            moves: Vec::new(),
            stats: LayerStats::default(),
            contours: Vec::new(),
        }),
        ToolEvent::Move(m) => match layers.last_mut() {
            Some(l) => l.moves.push(*m),
            None => return false,
        },
        ToolEvent::LayerEnd(s) => match layers.last_mut() {
            Some(l) => l.stats = **s,
            None => return false,
        },
        ToolEvent::Progress => {}
    }
    true
}

/// One layer's output.
#[derive(Debug, Clone)]
pub struct TpLayer {
    pub index: u32,
    pub z_um: i32,
    pub height_um: i32,
    pub moves: Vec<ToolMove>,
    pub stats: LayerStats,
    /// The slicer's loops of this layer (points, hole flag).
    pub contours: Vec<(Vec<Point2>, bool)>,
}

/// Everything a run produced.
pub struct TpRun {
    pub layers: Vec<TpLayer>,
    pub stats: ToolpathStats,
    /// Moves before the first layer (none expected).
    pub stray: usize,
}

/// Slices `tris` (sorted, placed) and builds toolpaths with `cfg`.
pub fn run_cfg(
    tris: &[Triangle],
    settings: &PrintSettings,
    cfg: ToolpathConfig,
) -> Result<TpRun, String> {
    run_sized::<16384, 1024, 32768, 65536, 65536, 65536>(tris, settings, cfg)
}

/// [`run_cfg`] with layers with bridges limited to `path_points` and `crossings`
/// ([`Toolpath::set_bridge_limits`]).
#[allow(dead_code)]
pub fn run_cfg_bridge_limited(
    tris: &[Triangle],
    settings: &PrintSettings,
    cfg: ToolpathConfig,
    (path_points, crossings): (usize, usize),
) -> Result<TpRun, String> {
    run_sized_limited::<16384, 1024, 32768, 65536, 65536, 65536>(
        tris,
        settings,
        cfg,
        Some((path_points, crossings)),
    )
}

/// [`run_cfg`] with a toolpath stage of the given capacities (PTS, LOOPS, CROSS, PATH,
/// RING, SPANS).
pub fn run_sized<
    const PTS: usize,
    const LOOPS: usize,
    const CROSS: usize,
    const PATH: usize,
    const RING: usize,
    const SPANS: usize,
>(
    tris: &[Triangle],
    settings: &PrintSettings,
    cfg: ToolpathConfig,
) -> Result<TpRun, String> {
    run_sized_limited::<PTS, LOOPS, CROSS, PATH, RING, SPANS>(tris, settings, cfg, None)
}

/// [`run_sized`], with bridge limits if any.
fn run_sized_limited<
    const PTS: usize,
    const LOOPS: usize,
    const CROSS: usize,
    const PATH: usize,
    const RING: usize,
    const SPANS: usize,
>(
    tris: &[Triangle],
    settings: &PrintSettings,
    cfg: ToolpathConfig,
    bridge_limits: Option<(usize, usize)>,
) -> Result<TpRun, String> {
    let top = tris.iter().map(Triangle::z_max).max().unwrap_or(0);
    let slice_cfg = SliceConfig::new(settings, top).map_err(|e| e.to_string())?;
    strata_testkit::on_big_stack(move || -> Result<TpRun, String> {
        let mut slicer = Box::new(TestSlicer::new(slice_cfg).map_err(|e| e.to_string())?);
        let mut tp = Box::new(
            Toolpath::<PTS, LOOPS, CROSS, PATH, RING, SPANS>::new(cfg)
                .map_err(|e| e.to_string())?,
        );
        if let Some((path_points, crossings)) = bridge_limits {
            tp.set_bridge_limits(path_points, crossings);
        }
        let mut work = Box::new(TestScratch::<PTS, CROSS>::new());
        let mut layers: Vec<TpLayer> = Vec::new();
        let mut contours: Vec<Vec<(Vec<Point2>, bool)>> = Vec::new();
        let mut stray = 0usize;
        let mut err: Option<ToolpathError> = None;
        {
            let mut events = |e: &ToolEvent<'_>| {
                if !record(&mut layers, e) {
                    stray += 1;
                }
            };
            let mut sink = |sliced: SlicedLayer<'_, _, _>| {
                let l = sliced.layer();
                contours
                    .push(l.loops.iter().map(|i| (l.loop_points(i).to_vec(), i.hole)).collect());
                if err.is_none() {
                    if let Err(e) = tp.push_sliced(sliced, &mut events) {
                        err = Some(e);
                    }
                }
            };
            for t in tris {
                slicer.push(t, &mut *work, &mut sink).map_err(|e| e.to_string())?;
            }
            slicer.finish(&mut *work, &mut sink).map_err(|e| e.to_string())?;
            if let Some(e) = err {
                return Err(e.to_string());
            }
            let stats = tp.finish(&mut *work, &mut events).map_err(|e| e.to_string())?;
            for (l, c) in layers.iter_mut().zip(contours) {
                l.contours = c;
            }
            Ok(TpRun { layers, stats, stray })
        }
    })
}

/// [`run_cfg`] with the configuration derived from `settings` on the default machine.
pub fn run(tris: &[Triangle], settings: &PrintSettings) -> TpRun {
    let cfg = ToolpathConfig::new(&MachineConfig::default(), settings);
    run_cfg(tris, settings, cfg).expect("toolpath run")
}

/// [`run`] of a mesh (mm) with the default settings.
pub fn default_run(mesh: &[TriMm]) -> TpRun {
    run(&to_um(mesh), &PrintSettings::default())
}

/// Extrusion segments of a layer: (from, to, feature, e_um).
pub fn extrusions(layer: &TpLayer, start: Point2) -> Vec<(Point2, Point2, Feature, i32)> {
    let mut pos = start;
    let mut out = Vec::new();
    for m in &layer.moves {
        if m.e_um > 0 && m.to != pos {
            out.push((pos, m.to, m.feature, m.e_um));
        }
        pos = m.to;
    }
    out
}

/// Position at the end of each layer (start of the next).
pub fn layer_starts(run: &TpRun) -> Vec<Point2> {
    let mut pos = Point2::new(0, 0);
    let mut out = Vec::new();
    for l in &run.layers {
        out.push(pos);
        if let Some(m) = l.moves.last() {
            pos = m.to;
        }
    }
    out
}

/// Asserts that every extrusion but the skirt (of every `every`-th layer) lies inside the
/// layer's contour and at least `w/2 - tol` from it (`w`: `width_um`); returns the extrusions
/// checked.
pub fn check_containment(run: &TpRun, what: &str, width_um: f64, tol: f64, every: usize) -> usize {
    let starts = layer_starts(run);
    let mut checked = 0;
    for (l, &start) in run.layers.iter().zip(&starts).step_by(every.max(1)) {
        let lines: Vec<_> = extrusions(l, start)
            .into_iter()
            .filter(|e| e.2 != Feature::Skirt)
            .map(|(a, b, f, _)| (a, b, f))
            .collect();
        let what = format!("{what} layer {}", l.index);
        checked += check::assert_lines_inside(&what, &l.contours, &lines, width_um / 2.0 - tol);
    }
    assert!(checked > 0, "{what}: nothing checked");
    checked
}

/// How much of layer `l`'s top surface (its region minus the next layer's) the layer's
/// extrusions but the skirt cover, each a rectangle `width_um` wide.
pub fn top_coverage(run: &TpRun, l: usize, width_um: f64) -> TopCoverage {
    let layer = &run.layers[l];
    let lines: Vec<(Point2, Point2)> = extrusions(layer, layer_starts(run)[l])
        .into_iter()
        .filter(|e| e.2 != Feature::Skirt)
        .map(|(a, b, _, _)| (a, b))
        .collect();
    let above = run.layers.get(l + 1).map(|n| &n.contours[..]);
    let coverage = check::top_coverage(&layer.contours, above, &lines, width_um);
    // STRATA_DUMP=prefix writes the raster as prefix_<layer>.pgm.
    if let Ok(path) = std::env::var("STRATA_DUMP") {
        std::fs::write(format!("{path}_{l}.pgm"), coverage.pgm()).unwrap();
    }
    coverage
}
