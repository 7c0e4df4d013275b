//! Per-model toolpath report for every model in `../shared/models` (or the directory given):
//! layers, retractions, travel and extrusion stops (totals, per-layer mean and maximum), thin
//! islands and the area thinner than a line (summed over layers, and the largest layer's), the host time of the whole run (parse to G-code text), and the RAM the toolpath
//! stage needs for the model's largest layer (a `Toolpath` sized to the model's peak needs,
//! window included). Default settings (0.2 mm, 0.45 mm lines, 2 perimeters, 20 % zigzag,
//! 4 top/bottom layers, 5 mm retraction); plate_holes (203 x 305 mm) on a 400 mm bed.
//!
//! Run: `cargo run --release --example toolpath_report [MODELS_DIR] [--markdown]`.

use std::path::PathBuf;
use std::time::Instant;

use strata::gcode::{GcodeOptions, GcodeWriter};
use strata::geom::Triangle;
use strata::machine::{MachineConfig, PrintSettings};
use strata::slice::{SliceConfig, SlicedLayer};
use strata::toolpath::{LayerStats, ToolEvent, ToolpathConfig, ToolpathStats};
use strata_testkit::models::{self, placed_sorted};

strata::slicer_type! {
    type HostSlicer = {
        active_triangles: 1 << 16,
        contour_points: 1 << 16,
        contour_loops: 4096,
    };
}
strata::toolpath_type! {
    type HostToolpath = {
        toolpath_points: 1 << 15,
        toolpath_loops: 4096,
        scan_crossings: 1 << 16,
        path_points: 1 << 17,
        window_ring_words: 1 << 17,
        window_spans: 1 << 17,
    };
}
strata::scratch_type! {
    /// The scratch both take turns in (SEGMENTS, PTS, CROSS as theirs).
    type HostScratch = {
        contour_points: 1 << 16,
        toolpath_points: 1 << 15,
        scan_crossings: 1 << 16,
    };
}
/// The stage values.
type Stages = (Box<HostSlicer>, Box<HostToolpath>, Box<HostScratch>);

struct Row {
    stats: ToolpathStats,
    layers: Vec<LayerStats>,
    seconds: f64,
    gcode_bytes: usize,
}

fn run(bytes: &[u8], machine: &MachineConfig, st: &mut Stages) -> Option<Row> {
    let t0 = Instant::now();
    let tris = placed_sorted(bytes, machine).ok()?;
    let settings = PrintSettings::default();
    let top = tris.iter().map(Triangle::z_max).max().unwrap_or(0);
    let slice = SliceConfig::new(&settings, top).ok()?;
    let cfg = ToolpathConfig::new(machine, &settings);
    let (slicer, tp, work) = st;
    let work: &mut HostScratch = work;
    slicer.reset(slice).ok()?;
    tp.reset(cfg).ok()?;
    let mut gw = GcodeWriter::new(String::new(), GcodeOptions::default(), &cfg);
    gw.start(machine, &settings, &cfg).ok()?;
    let (pos, z) = gw.position();
    tp.set_position(pos, z);
    let mut layers = Vec::new();
    let mut events = |e: &ToolEvent<'_>| {
        if let ToolEvent::LayerEnd(s) = e {
            layers.push(**s);
        }
        let _ = gw.event(e);
    };
    let mut failed = None;
    let mut sink = |l: SlicedLayer<'_, _, HostScratch>| {
        if failed.is_none() {
            failed = tp.push_sliced(l, &mut events).err();
        }
    };
    for t in &tris {
        slicer.push(t, work, &mut sink).ok()?;
    }
    slicer.finish(work, &mut sink).ok()?;
    if let Some(e) = failed {
        eprintln!("toolpath error: {e}");
        return None;
    }
    let stats = tp.finish(work, &mut events).ok()?;
    gw.end(machine, &cfg).ok()?;
    let gcode_bytes = gw.into_inner().len();
    Some(Row { stats, layers, seconds: t0.elapsed().as_secs_f64(), gcode_bytes })
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let dir =
        args.iter().find(|a| !a.starts_with("--")).map(PathBuf::from).unwrap_or_else(models::dir);
    let files = models::stl_files_below(&dir);
    // Build the stage values on a thread with a big stack, then work there.
    strata_testkit::on_big_stack(move || {
        let mut st: Stages = (
            Box::new(
                HostSlicer::new(SliceConfig::new(&PrintSettings::default(), 1000).expect("config"))
                    .expect("slicer"),
            ),
            Box::new(
                HostToolpath::new(ToolpathConfig::new(
                    &MachineConfig::default(),
                    &PrintSettings::default(),
                ))
                .expect("toolpath"),
            ),
            Box::new(HostScratch::new()),
        );
        println!(
            "| model | layers | retractions | per layer (mean / max) | travel mm | per layer \
                 (mean) | extrusion stops | per layer (mean / max) | thin islands | thin area mm^2 \
                 (max layer: mm^2 @ layer) | time ms | toolpath RAM KB (window KB) |"
        );
        println!("|---|---|---|---|---|---|---|---|---|---|---|---|");
        let mut total_ram_device = Vec::new();
        for f in &files {
            let name = f.strip_prefix(&dir).unwrap_or(f).display().to_string();
            let bytes = std::fs::read(f).expect("read model");
            let machine = if name == "plate_holes.stl" {
                models::big_machine()
            } else {
                MachineConfig::default()
            };
            let Some(r) = run(&bytes, &machine, &mut st) else {
                println!("| {name} | (not sliced) ||||||||||");
                continue;
            };
            let s = &r.stats;
            let n = s.layers.max(1) as f64;
            let max_retr = r.layers.iter().map(|l| l.retractions).max().unwrap_or(0);
            let max_stops = r.layers.iter().map(|l| l.stops).max().unwrap_or(0);
            let ram = s.needs.bytes();
            total_ram_device.push((name.clone(), ram, s.needs, s.thin_pts));
            println!(
                    "| {name} | {} | {} | {:.2} / {max_retr} | {:.0} | {:.1} | {} | {:.1} / {max_stops} \
                     | {} | {:.2} ({:.3} @ {}) | {:.1} | {:.1} ({:.1}) |",
                    s.layers,
                    s.retractions,
                    s.retractions as f64 / n,
                    s.travel_um as f64 / 1000.0,
                    s.travel_um as f64 / 1000.0 / n,
                    s.stops,
                    s.stops as f64 / n,
                    s.thin_islands,
                    s.thin_area_um2 as f64 / 1e6,
                    s.max_thin_area_um2 as f64 / 1e6,
                    s.max_thin_area_layer,
                    r.seconds * 1000.0,
                    ram as f64 / 1024.0,
                    s.needs.window_bytes() as f64 / 1024.0,
                );
            let _ = r.gcode_bytes;
        }
        println!();
        println!("Peak needs (capacities) per model:");
        for (name, ram, n, thin_pts) in &total_ram_device {
            println!(
                "  {name}: PTS {} LOOPS {} CROSS {} PATH {} RING {} SPANS {} -> {} bytes \
                     (thin-area measurement: PTS {})",
                n.layer_points.max(n.offset_edges),
                n.layer_loops,
                n.crossings,
                n.path_points,
                n.ring_points,
                n.spans,
                ram,
                thin_pts
            );
        }
    });
}
