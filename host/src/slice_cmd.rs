//! `strata slice`: run the core slicer on the host and write contours (JSON, SVG).
//!
//! The model is loaded and placed like every host command (centred on the default Ender-3
//! bed, refused if larger), then streamed through the same `strata::slice::Slicer` the
//! printer runs, with host-sized capacities. That slicer is about 9 MB, too large for a
//! debug build's main-thread stack, so the slicing runs on its own thread with a 256 MB stack
//! (reserved address space; only the touched pages are used).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use serde::Serialize;
use strata::geom::{Point2, Triangle};
use strata::machine::{MachineConfig, PrintSettings};
use strata::slice::{peak_needs, Layer, LayerRepairs, PeakNeeds, SliceConfig, SliceStats, Slicer};

use crate::model;

/// Host capacities: active triangles, segments (and points) per layer, loops per layer.
type HostSlicer = Slicer<{ 1 << 17 }, { 1 << 17 }, { 1 << 14 }>;
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
    /// Layer height in mm (default: the 0.2 mm profile).
    #[arg(long, value_name = "MM")]
    pub layer_height: Option<f64>,
    /// First layer height in mm (default: the 0.2 mm profile).
    #[arg(long, value_name = "MM")]
    pub first_layer_height: Option<f64>,
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

fn mm(um: i64) -> f64 {
    um as f64 / 1000.0
}

fn xy(p: Point2) -> [f64; 2] {
    [mm(p.x.into()), mm(p.y.into())]
}

/// A height option in mm to um, refused when not a positive finite number.
fn height_um(value: Option<f64>, default_um: i32, flag: &str) -> Result<i32, String> {
    match value {
        None => Ok(default_um),
        Some(v) if v.is_finite() && v > 0.0 && v < 1000.0 => Ok((v * 1000.0).round() as i32),
        Some(v) => Err(format!("--{flag} {v}: must be a positive height in mm")),
    }
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
                let mut layers = Vec::with_capacity(slicer.layer_count() as usize);
                let mut sink = |l: &Layer<'_>| layers.push(layer_out(l));
                for t in tris {
                    slicer.push(t, &mut sink).map_err(|e| e.to_string())?;
                }
                let stats = slicer.finish(&mut sink).map_err(|e| e.to_string())?;
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

/// Runs `strata slice`.
pub fn run(args: &SliceArgs) -> Result<(), String> {
    let machine = MachineConfig::default();
    let defaults = PrintSettings::default();
    let mut settings = defaults;
    settings.layer_height_um =
        height_um(args.layer_height, defaults.layer_height_um, "layer-height")?;
    settings.first_layer_height_um =
        height_um(args.first_layer_height, defaults.first_layer_height_um, "first-layer-height")?;
    settings.validate(&machine).map_err(|e| e.to_string())?;

    let loaded = model::load(&args.model)?;
    let tris = loaded.placed_sorted(&machine)?;
    let top = tris.iter().map(Triangle::z_max).max().unwrap_or(0);
    let config = SliceConfig::new(&settings, top).map_err(|e| e.to_string())?;
    let needs = peak_needs(&tris, &config).map_err(|e| e.to_string())?;
    let (layers, stats) = run_slicer(&tris, config)?;
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
        write_svgs(dir, &layers, &tris)?;
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
