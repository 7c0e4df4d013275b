//! `strata slice`: run the core on the host and write G-code (`-o`), a summary (`--json`) and
//! contours (JSON, SVG).
//!
//! The model is loaded and placed like every host command (centred on the Ender-3 bed, or a
//! `--bed` of another size, refused if larger), then streamed through the same
//! `strata::slice::Slicer` and `strata::toolpath::Toolpath` the printer runs, with host-sized
//! capacities, and the moves through `strata::gcode::GcodeWriter` into a `String`. Those
//! stages are megabytes, too large for a debug build's main-thread stack, so they run on
//! their own thread with a 256 MB stack (reserved address space; only the touched pages are
//! used).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use serde::Serialize;
use strata::gcode::{GcodeOptions, GcodeStats, GcodeWriter};
use strata::geom::{Point2, Triangle};
use strata::machine::{MachineConfig, PrintSettings};
use strata::slice::{
    peak_needs, Layer, LayerRepairs, PeakNeeds, SliceConfig, SliceScratch, SliceStats, SlicedLayer,
};
use strata::toolpath::{
    LayerStats, ToolEvent, ToolpathConfig, ToolpathError, ToolpathNeeds, ToolpathStats,
};

use strata_host::model;

use strata_host::stages::{HostScratch, HostSlicer, HostToolpath};

use crate::settings::{machine_of, settings_of, toolpath_config_of, PrintArgs};

const SLICER_STACK_BYTES: usize = 256 << 20;

/// Options of `strata slice`.
#[derive(Debug, clap::Args)]
pub struct SliceArgs {
    /// The STL model.
    pub model: PathBuf,
    /// Write the contours of every layer as JSON (mm).
    #[arg(long)]
    pub contours_json: Option<PathBuf>,
    /// Write one SVG per layer into this directory.
    #[arg(long)]
    pub svg: Option<PathBuf>,
    /// Write printable G-code (Marlin, Ender-3) to this file.
    #[arg(short = 'o', long, value_name = "OUT.gcode")]
    pub output: Option<PathBuf>,
    /// Print a machine-readable summary of the toolpaths (JSON) instead of text.
    #[arg(long)]
    pub json: bool,
    /// Print settings.
    #[command(flatten)]
    pub print: Box<PrintArgs>,
}

/// One loop in mm, as written to JSON.
#[derive(Serialize)]
struct LoopOut {
    /// Closed polygon (last point joins the first); outer counter-clockwise, holes clockwise.
    points: Vec<[f64; 2]>,
    hole: bool,
    /// Index of the enclosing loop in this layer.
    parent: Option<u32>,
    area_mm2: f64,
}

#[derive(Serialize)]
struct RepairsOut {
    exact_joins: u32,
    tolerance_joins: u32,
    gaps_closed: u32,
    dropped_chains: u32,
    dropped_segments: u32,
}

impl From<LayerRepairs> for RepairsOut {
    fn from(r: LayerRepairs) -> Self {
        Self {
            exact_joins: r.exact_joins,
            tolerance_joins: r.tolerance_joins,
            gaps_closed: r.gaps_closed,
            dropped_chains: r.dropped_chains,
            dropped_segments: r.dropped_segments,
        }
    }
}

#[derive(Serialize)]
struct LayerOut {
    index: u32,
    /// Plane height above the bed, mm.
    z: f64,
    loops: Vec<LoopOut>,
    repairs: RepairsOut,
    dropped_small_loops: u32,
}

#[derive(Serialize)]
struct SummaryOut {
    triangles: u32,
    triangles_spanning_no_plane: u32,
    layers: u32,
    loops: u32,
    holes: u32,
    dropped_small_loops: u32,
    repairs: RepairsOut,
    peak_active_triangles: u32,
    peak_active_layer: u32,
    peak_contour_points: u32,
    peak_points_layer: u32,
    peak_loops: u32,
}

#[derive(Serialize)]
struct ContoursOut<'a> {
    model: String,
    layer_height_mm: f64,
    first_layer_height_mm: f64,
    summary: &'a SummaryOut,
    layers: &'a [LayerOut],
}

/// Thin (unprinted) cross-section area from which the text output warns, um^2 (the JSON
/// output always has it).
const THIN_WARN_UM2: u64 = 10_000;

/// um^2 to mm^2.
fn mm2(um2: u64) -> f64 {
    um2 as f64 / 1e6
}

fn mm(um: i64) -> f64 {
    um as f64 / 1000.0
}

fn xy(p: Point2) -> [f64; 2] {
    [mm(p.x.into()), mm(p.y.into())]
}

fn layer_out(l: &Layer<'_>) -> LayerOut {
    LayerOut {
        index: l.index,
        z: mm(l.z_um.into()),
        loops: l
            .loops
            .iter()
            .map(|info| LoopOut {
                points: l.loop_points(info).iter().map(|&p| xy(p)).collect(),
                hole: info.hole,
                parent: info.parent,
                area_mm2: info.area_um2 as f64 / 1e6,
            })
            .collect(),
        repairs: l.repairs.into(),
        dropped_small_loops: l.dropped_small_loops,
    }
}

/// Streams the sorted triangles through a host-sized slicer on a thread with a large stack.
fn run_slicer(
    tris: &[Triangle],
    config: SliceConfig,
) -> Result<(Vec<LayerOut>, SliceStats), String> {
    std::thread::scope(|scope| {
        let worker = std::thread::Builder::new()
            .name("slicer".into())
            .stack_size(SLICER_STACK_BYTES)
            .spawn_scoped(scope, || {
                let mut slicer = HostSlicer::new(config).map_err(|e| e.to_string())?;
                let mut work = Box::new(SliceScratch::new());
                let mut layers = Vec::with_capacity(slicer.layer_count() as usize);
                let mut sink = |l: SlicedLayer<'_, _, _>| layers.push(layer_out(&l.layer()));
                for t in tris {
                    slicer.push(t, &mut *work, &mut sink).map_err(|e| e.to_string())?;
                }
                let stats = slicer.finish(&mut *work, &mut sink).map_err(|e| e.to_string())?;
                Ok((layers, stats))
            })
            .map_err(|e| format!("cannot start the slicer thread: {e}"))?;
        worker.join().map_err(|_| "the slicer thread panicked".to_string())?
    })
}

/// The model's XY bounds in mm with a 1 mm margin: (min x, min y, width, height).
fn view_box(tris: &[Triangle]) -> (f64, f64, f64, f64) {
    let (mut lo, mut hi) = (Point2::new(i32::MAX, i32::MAX), Point2::new(i32::MIN, i32::MIN));
    for p in tris.iter().flat_map(|t| t.v) {
        lo = Point2::new(lo.x.min(p.x), lo.y.min(p.y));
        hi = Point2::new(hi.x.max(p.x), hi.y.max(p.y));
    }
    let (x0, y0) = (mm(lo.x.into()) - 1.0, mm(lo.y.into()) - 1.0);
    (x0, y0, mm(hi.x.into()) + 1.0 - x0, mm(hi.y.into()) + 1.0 - y0)
}

/// SVG path data of the selected loops.
fn path_data<'a>(loops: impl Iterator<Item = &'a LoopOut>) -> String {
    let mut d = String::new();
    for l in loops {
        for (i, [x, y]) in l.points.iter().enumerate() {
            let _ = write!(d, "{}{x:.3} {y:.3} ", if i == 0 { 'M' } else { 'L' });
        }
        d.push_str("Z ");
    }
    d
}

/// One SVG per layer: filled with the even-odd rule, outer loops blue, holes red, +y up.
fn write_svgs(dir: &Path, layers: &[LayerOut], tris: &[Triangle]) -> Result<(), String> {
    std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    let (x0, y0, w, h) = view_box(tris);
    for layer in layers {
        let all = path_data(layer.loops.iter());
        let outer = path_data(layer.loops.iter().filter(|l| !l.hole));
        let holes = path_data(layer.loops.iter().filter(|l| l.hole));
        let svg = format!(
            "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{w:.3}mm\" height=\"{h:.3}mm\" \
             viewBox=\"{x0:.3} {ny:.3} {w:.3} {h:.3}\">\n\
             <title>layer {i} z={z:.3} mm</title>\n\
             <g transform=\"scale(1,-1)\" stroke-width=\"0.1\" stroke-linejoin=\"round\">\n\
             <path class=\"fill\" d=\"{all}\" fill=\"#d8d8d8\" fill-rule=\"evenodd\" stroke=\"none\"/>\n\
             <path class=\"outer\" d=\"{outer}\" fill=\"none\" stroke=\"#1f5fbf\"/>\n\
             <path class=\"hole\" d=\"{holes}\" fill=\"none\" stroke=\"#d0302f\"/>\n\
             </g>\n</svg>\n",
            ny = -(y0 + h),
            i = layer.index,
            z = layer.z,
        );
        let path = dir.join(format!("layer_{:04}.svg", layer.index));
        std::fs::write(&path, svg).map_err(|e| format!("{}: {e}", path.display()))?;
    }
    Ok(())
}

fn summary(stats: &SliceStats, needs: &PeakNeeds, layers: &[LayerOut]) -> SummaryOut {
    SummaryOut {
        triangles: stats.triangles,
        triangles_spanning_no_plane: stats.dropped_triangles,
        layers: stats.layers,
        loops: stats.loops,
        holes: layers.iter().map(|l| l.loops.iter().filter(|x| x.hole).count() as u32).sum(),
        dropped_small_loops: stats.dropped_small_loops,
        repairs: stats.repairs.into(),
        peak_active_triangles: needs.active_triangles,
        peak_active_layer: needs.active_layer,
        peak_contour_points: stats.peak_points,
        peak_points_layer: needs.points_layer,
        peak_loops: stats.peak_loops,
    }
}

/// What the toolpath run produced.
struct ToolpathRun {
    gcode: String,
    stats: ToolpathStats,
    gcode_stats: GcodeStats,
    slice: SliceStats,
    layers: Vec<LayerStats>,
}

/// Slices, builds toolpaths and writes G-code on a thread with a large stack.
fn run_toolpaths(
    tris: &[Triangle],
    config: SliceConfig,
    machine: &MachineConfig,
    settings: &PrintSettings,
    cfg: ToolpathConfig,
    opts: GcodeOptions,
) -> Result<ToolpathRun, String> {
    std::thread::scope(|scope| {
        let worker = std::thread::Builder::new()
            .name("toolpath".into())
            .stack_size(SLICER_STACK_BYTES)
            .spawn_scoped(scope, || {
                let mut slicer = Box::new(HostSlicer::new(config).map_err(|e| e.to_string())?);
                let mut tp = Box::new(HostToolpath::new(cfg).map_err(|e| e.to_string())?);
                let mut work = Box::new(HostScratch::new());
                let mut gw = GcodeWriter::new(String::new(), opts, &cfg);
                gw.start(machine, settings, &cfg).map_err(|e| e.to_string())?;
                let (pos, z) = gw.position();
                tp.set_position(pos, z);
                let mut layers = Vec::new();
                let mut write_error = false;
                let mut events = |e: &ToolEvent<'_>| {
                    if let ToolEvent::LayerEnd(s) = e {
                        layers.push(**s);
                    }
                    write_error |= gw.event(e).is_err();
                };
                let mut failed: Option<ToolpathError> = None;
                let mut sink = |l: SlicedLayer<'_, _, _>| {
                    if failed.is_none() {
                        failed = tp.push_sliced(l, &mut events).err();
                    }
                };
                for t in tris {
                    slicer.push(t, &mut *work, &mut sink).map_err(|e| e.to_string())?;
                }
                let slice = slicer.finish(&mut *work, &mut sink).map_err(|e| e.to_string())?;
                if let Some(e) = failed {
                    return Err(e.to_string());
                }
                let stats = tp.finish(&mut *work, &mut events).map_err(|e| e.to_string())?;
                if write_error {
                    return Err("G-code formatting failed".into());
                }
                gw.end(machine, &cfg).map_err(|e| e.to_string())?;
                let gcode_stats = *gw.stats();
                Ok(ToolpathRun { gcode: gw.into_inner(), stats, gcode_stats, slice, layers })
            })
            .map_err(|e| format!("cannot start the toolpath thread: {e}"))?;
        worker.join().map_err(|_| "the toolpath thread panicked".to_string())?
    })
}

#[derive(Serialize)]
struct NeedsOut {
    layer_points: u32,
    layer_loops: u32,
    offset_edges: u32,
    crossings: u32,
    path_points: u32,
    paths: u32,
    ring_points: u32,
    spans: u32,
}

impl From<ToolpathNeeds> for NeedsOut {
    fn from(n: ToolpathNeeds) -> Self {
        Self {
            layer_points: n.layer_points,
            layer_loops: n.layer_loops,
            offset_edges: n.offset_edges,
            crossings: n.crossings,
            path_points: n.path_points,
            paths: n.paths,
            ring_points: n.ring_points,
            spans: n.spans,
        }
    }
}

#[derive(Serialize)]
struct LayerSummaryOut {
    index: u32,
    z: f64,
    retractions: u32,
    travel_mm: f64,
    stops: u32,
    extrusion_moves: u32,
    travel_moves: u32,
    filament_mm: f64,
    thin_islands: u32,
    thin_wall_area_mm2: f64,
}

#[derive(Serialize)]
struct GcodeSummaryOut {
    model: String,
    output: Option<String>,
    layers: u32,
    filament_mm: f64,
    extrusion_moves: u64,
    travel_moves: u64,
    retractions: u64,
    travel_mm: f64,
    stops: u64,
    thin_islands: u64,
    thin_wall_area_mm2: f64,
    max_thin_wall_area_mm2: f64,
    max_thin_wall_layer: u32,
    thin_wall_unmeasured_islands: u64,
    triangles: u32,
    gcode_lines: u64,
    gcode_bytes: usize,
    needs: NeedsOut,
    per_layer: Vec<LayerSummaryOut>,
}

/// Runs `strata slice`.
pub fn run(args: &SliceArgs) -> Result<(), String> {
    let machine = machine_of(&args.print)?;
    let settings = settings_of(&args.print, &machine)?;
    let loaded = model::load(&args.model)?;
    let tris = loaded.placed_sorted(&machine)?;
    let top = tris.iter().map(Triangle::z_max).max().unwrap_or(0);
    let config = SliceConfig::new(&settings, top).map_err(|e| e.to_string())?;
    let toolpaths = args.output.is_some() || args.json;
    if args.contours_json.is_some() || args.svg.is_some() || !toolpaths {
        contours(args, &settings, &tris, config, !toolpaths)?;
    }
    if !toolpaths {
        return Ok(());
    }
    let cfg = toolpath_config_of(&args.print, &machine, &settings)?;
    let mut opts = GcodeOptions::default();
    opts.relative_e = !args.print.absolute_e;
    let run = run_toolpaths(&tris, config, &machine, &settings, cfg, opts)?;
    if let Some(path) = &args.output {
        std::fs::write(path, &run.gcode).map_err(|e| format!("{}: {e}", path.display()))?;
    }
    let st = &run.stats;
    if args.json {
        let doc = GcodeSummaryOut {
            model: args.model.display().to_string(),
            output: args.output.as_ref().map(|p| p.display().to_string()),
            layers: st.layers,
            filament_mm: mm(st.filament_um),
            extrusion_moves: st.extrusion_moves,
            travel_moves: st.travel_moves,
            retractions: st.retractions,
            travel_mm: mm(st.travel_um as i64),
            stops: st.stops,
            thin_islands: st.thin_islands,
            thin_wall_area_mm2: mm2(st.thin_area_um2),
            max_thin_wall_area_mm2: mm2(st.max_thin_area_um2),
            max_thin_wall_layer: st.max_thin_area_layer,
            thin_wall_unmeasured_islands: st.thin_unmeasured,
            triangles: run.slice.triangles,
            gcode_lines: run.gcode_stats.lines,
            gcode_bytes: run.gcode.len(),
            needs: st.needs.into(),
            per_layer: run
                .layers
                .iter()
                .map(|l| LayerSummaryOut {
                    index: l.index,
                    z: mm(l.z_um.into()),
                    retractions: l.retractions,
                    travel_mm: mm(l.travel_um as i64),
                    stops: l.stops,
                    extrusion_moves: l.extrusion_moves,
                    travel_moves: l.travel_moves,
                    filament_mm: mm(l.filament_um),
                    thin_islands: l.thin_islands,
                    thin_wall_area_mm2: mm2(l.thin_area_um2),
                })
                .collect(),
        };
        println!("{}", serde_json::to_string_pretty(&doc).map_err(|e| e.to_string())?);
    } else {
        println!(
            "{}: {} layers, {:.1} mm of filament, {} extrusion moves, {} travel moves \
             ({:.1} mm), {} retractions, {} extrusion stops",
            args.model.display(),
            st.layers,
            mm(st.filament_um),
            st.extrusion_moves,
            st.travel_moves,
            mm(st.travel_um as i64),
            st.retractions,
            st.stops
        );
        if st.thin_islands > 0 {
            println!(
                "warning: {} island cross-sections are thinner than one line width and were \
                 not printed",
                st.thin_islands
            );
        }
        if st.thin_area_um2 >= THIN_WARN_UM2 {
            let layers = run.layers.iter().filter(|l| l.thin_area_um2 > 0).count();
            println!(
                "warning: {:.2} mm^2 of cross-sections (summed over {layers} layers; at most \
                 {:.2} mm^2 in layer {}) are thinner than one line width ({:.2} mm) and were not \
                 printed",
                mm2(st.thin_area_um2),
                mm2(st.max_thin_area_um2),
                st.max_thin_area_layer,
                mm(cfg.line_width_um.into()),
            );
        }
        if st.thin_unmeasured > 0 {
            println!(
                "note: the thin area of {} island cross-sections was not measured (offset \
                 buffers too small for the measurement; their toolpaths are complete)",
                st.thin_unmeasured
            );
        }
        if let Some(path) = &args.output {
            println!("wrote {} ({} lines)", path.display(), run.gcode_stats.lines);
        }
    }
    Ok(())
}

/// The contour outputs (JSON, SVG) and, when `print`, the slicing summary text.
fn contours(
    args: &SliceArgs,
    settings: &PrintSettings,
    tris: &[Triangle],
    config: SliceConfig,
    print: bool,
) -> Result<(), String> {
    let needs = peak_needs(tris, &config).map_err(|e| e.to_string())?;
    let (layers, stats) = run_slicer(tris, config)?;
    let sum = summary(&stats, &needs, &layers);

    if let Some(path) = &args.contours_json {
        let doc = ContoursOut {
            model: args.model.display().to_string(),
            layer_height_mm: mm(settings.layer_height_um.into()),
            first_layer_height_mm: mm(settings.first_layer_height_um.into()),
            summary: &sum,
            layers: &layers,
        };
        let file = std::fs::File::create(path).map_err(|e| format!("{}: {e}", path.display()))?;
        serde_json::to_writer(std::io::BufWriter::new(file), &doc)
            .map_err(|e| format!("{}: {e}", path.display()))?;
    }
    if let Some(dir) = &args.svg {
        write_svgs(dir, &layers, tris)?;
    }
    if !print {
        return Ok(());
    }
    let r = &stats.repairs;
    println!(
        "{}: {} layers, {} loops ({} holes), {} triangles ({} span no plane)",
        args.model.display(),
        sum.layers,
        sum.loops,
        sum.holes,
        sum.triangles,
        sum.triangles_spanning_no_plane
    );
    if r.total() == 0 {
        println!("repairs: none");
    } else {
        println!(
            "repairs: {} exact joins, {} tolerance joins, {} gaps closed, {} open chains dropped \
             ({} segments)",
            r.exact_joins, r.tolerance_joins, r.gaps_closed, r.dropped_chains, r.dropped_segments
        );
    }
    println!(
        "peak active triangles {} (layer {}), peak contour points {} (layer {}), \
         {} small loops dropped",
        sum.peak_active_triangles,
        sum.peak_active_layer,
        sum.peak_contour_points,
        sum.peak_points_layer,
        sum.dropped_small_loops
    );
    Ok(())
}
