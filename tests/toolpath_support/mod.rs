//! Helpers for the toolpath and G-code tests: run the slicer and the toolpath stage on a
//! thread with a big stack and collect every layer's moves.
#![allow(dead_code)] // each test crate uses a different subset

use strata::geom::{Point2, Triangle};
use strata::machine::{MachineConfig, PrintSettings};
use strata::scratch::Scratch;
use strata::slice::{SliceConfig, SlicedLayer, Slicer};
use strata::toolpath::{
    Feature, LayerStats, ToolEvent, ToolMove, Toolpath, ToolpathConfig, ToolpathError,
    ToolpathStats,
};

/// Host-sized capacities for tests: PTS, LOOPS, CROSS, PATH, RING, SPANS.
pub type TestToolpath = Toolpath<16384, 1024, 32768, 65536, 65536, 65536>;
/// Slicer capacities for tests.
pub type TestSlicer = Slicer<16384, 16384, 1024>;
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
    let top = tris.iter().map(Triangle::z_max).max().unwrap_or(0);
    let slice_cfg = SliceConfig::new(settings, top).map_err(|e| e.to_string())?;
    std::thread::scope(|scope| {
        std::thread::Builder::new()
            .stack_size(512 << 20)
            .spawn_scoped(scope, move || -> Result<TpRun, String> {
                let mut slicer = Box::new(TestSlicer::new(slice_cfg).map_err(|e| e.to_string())?);
                let mut tp = Box::new(
                    Toolpath::<PTS, LOOPS, CROSS, PATH, RING, SPANS>::new(cfg)
                        .map_err(|e| e.to_string())?,
                );
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
                        contours.push(
                            l.loops.iter().map(|i| (l.loop_points(i).to_vec(), i.hole)).collect(),
                        );
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
            .expect("spawn toolpath thread")
            .join()
            .expect("toolpath thread panicked")
    })
}

/// [`run_cfg`] with the configuration derived from `settings` on the default machine.
pub fn run(tris: &[Triangle], settings: &PrintSettings) -> TpRun {
    let cfg = ToolpathConfig::new(&MachineConfig::default(), settings);
    run_cfg(tris, settings, cfg).expect("toolpath run")
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

/// A point as f64 (um).
pub fn pt(p: Point2) -> (f64, f64) {
    (f64::from(p.x), f64::from(p.y))
}

/// Non-zero winding of `p` in the loops (f64).
pub fn inside(loops: &[(Vec<Point2>, bool)], p: (f64, f64)) -> bool {
    let mut w = 0;
    for (l, _) in loops {
        for k in 0..l.len() {
            let (a, b) = (pt(l[k]), pt(l[(k + 1) % l.len()]));
            if (a.1 <= p.1) != (b.1 <= p.1) {
                let x = a.0 + (p.1 - a.1) / (b.1 - a.1) * (b.0 - a.0);
                if x > p.0 {
                    w += if b.1 > a.1 { 1 } else { -1 };
                }
            }
        }
    }
    w != 0
}

/// Distance from `p` to the segment a-b (f64).
pub fn point_seg_dist(p: (f64, f64), a: (f64, f64), b: (f64, f64)) -> f64 {
    let (dx, dy) = (b.0 - a.0, b.1 - a.1);
    let l2 = dx * dx + dy * dy;
    let t =
        if l2 == 0.0 { 0.0 } else { (((p.0 - a.0) * dx + (p.1 - a.1) * dy) / l2).clamp(0.0, 1.0) };
    ((p.0 - a.0 - t * dx).powi(2) + (p.1 - a.1 - t * dy).powi(2)).sqrt()
}
