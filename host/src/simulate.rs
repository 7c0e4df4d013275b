//! `strata simulate`: the whole job through the real protocol into the simulated printer
//! (`strata_host::simjob`), with admission control first, a summary (`--json`) and pictures
//! (`--preview`).

use std::path::{Path, PathBuf};

use serde::Serialize;
use strata::machine::MachineConfig;
use strata::protocol::JobSpec;
use strata_host::admission::{self, Admission};
use strata_host::gcode_file;
use strata_host::model;
use strata_host::pace::Pace;
use strata_host::preview;
use strata_host::session::Source;
use strata_host::simjob::{simulate, simulate_source, Faults, SimOptions, SimReport};

use crate::settings::{job_of, machine_of, PrintArgs};

/// Options of `strata simulate`.
#[derive(Debug, clap::Args)]
pub struct SimulateArgs {
    /// The STL model, or a G-code file (`.gcode`, `.gco`, `.g`) from any slicer.
    pub model: PathBuf,
    /// Print a machine-readable summary (JSON).
    #[arg(long)]
    pub json: bool,
    /// Write a picture per layer and an overview page into this directory.
    #[arg(long, value_name = "DIR")]
    pub preview: Option<PathBuf>,
    /// Link speed of the simulated serial line.
    #[arg(long, default_value_t = 250_000)]
    pub baud: u32,
    /// Largest geometric deviation simplification may introduce, mm.
    #[arg(long, value_name = "MM", default_value_t = 0.02)]
    pub max_deviation: f64,
    /// Loss rate injected on the simulated link (drop, corrupt, duplicate, delay), 0..1.
    #[arg(long, value_name = "RATE", default_value_t = 0.0)]
    pub loss: f64,
    /// Seed of the injected faults.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Print settings.
    #[command(flatten)]
    pub print: Box<PrintArgs>,
}

#[derive(Serialize)]
struct Steps {
    x: u64,
    y: u64,
    z: u64,
    e: u64,
}

#[derive(Serialize)]
struct Simplified {
    triangles_in: usize,
    triangles_out: usize,
    /// Measured (two-sided Hausdorff estimate).
    max_deviation_mm: f64,
    /// The simplifier's error bound.
    error_bound_mm: f64,
}

/// The capacities this job needs, named as `strata::protocol::Capacities` (what admission
/// compares with the device's).
#[derive(Serialize)]
struct DeviceNeeds {
    active_triangles: u32,
    contour_points: u32,
    /// Move buffer, bytes: the largest emission unit's coded moves (a path with the travel
    /// before it; the device emits a layer unit by unit as its buffer has room).
    move_buffer_bytes: u32,
    toolpath_points: u32,
    toolpath_loops: u32,
    scan_crossings: u32,
    path_points: u32,
    window_ring_words: u32,
    window_spans: u32,
    /// RAM of a toolpath stage with exactly these capacities and a scratch of its own
    /// (`ToolpathNeeds::bytes`).
    toolpath_ram_bytes: u64,
}

#[derive(Serialize)]
struct Summary {
    layers: u32,
    print_time_s: f64,
    filament_mm: f64,
    steps: Steps,
    max_step_error_us: f64,
    peak_active_triangles: u32,
    peak_contour_points: u32,
    /// RAM of a device pipeline sized exactly to this job (`simjob::device_ram`: the slicer at
    /// its peaks, the toolpath stage at `device_needs`, the scratch they share, motion).
    device_ram_bytes: u64,
    /// The capacities a device needs for this job, named as the announced `Capacities`.
    device_needs: DeviceNeeds,
    wire_bytes_per_triangle: f64,
    simplified: Option<Simplified>,
    layer_hashes: Vec<String>,
    triangles: usize,
    stream_time_s: f64,
    /// Admission's estimate of how long the printer waits for the link at its worst layer, s
    /// (0 or less: never; `strata_host::pace`).
    link_lag_s: f64,
    underruns: u32,
    /// Stops at a rest point waiting for the link ([`strata_host::simjob::SimReport::rest_waits`]).
    rest_waits: u32,
    retransmits: u64,
}

/// Runs `strata simulate`.
pub fn run(args: &SimulateArgs) -> Result<(), String> {
    let machine = machine_of(&args.print)?;
    if is_gcode(&args.model) {
        return run_gcode_file(args, &machine);
    }
    let loaded = model::load(&args.model)?;
    let tris = loaded.placed_sorted(&machine)?;
    let job = job_of(&args.print, &tris)?;
    let opts = SimOptions {
        baud: args.baud,
        faults: Faults::uniform(args.loss, args.seed),
        preview: args.preview.is_some(),
        ..SimOptions::default()
    };
    let paced = admission::admit_job_paced(
        &tris,
        &machine,
        &job,
        &opts.capacities,
        args.max_deviation,
        args.baud,
    )
    .map_err(|e| format!("{}: {e}", args.model.display()))?;
    let (admitted, peaks, pace) = (paced.admission, paced.peaks, paced.pace);
    if !pace.keeps_ahead() && !args.json {
        println!("{}", pace.warning(&args.model, args.baud));
    }
    let (tris, simplified, slicer) = match admitted {
        Admission::Unchanged(needs) => (tris, None, needs),
        Admission::Simplified(s) => {
            if !args.json {
                println!(
                    "{}: simplified from {} to {} triangles to fit the printer and its link \
                     (error bound {} mm, measured deviation {:.3} mm, peak active triangles \
                     {}, contour points {})",
                    args.model.display(),
                    s.triangles_in,
                    s.triangles.len(),
                    s.error_bound_mm,
                    s.max_deviation_mm,
                    s.needs.active_triangles,
                    s.needs.contour_points
                );
            }
            let info = Simplified {
                triangles_in: s.triangles_in,
                triangles_out: s.triangles.len(),
                max_deviation_mm: s.max_deviation_mm,
                error_bound_mm: s.error_bound_mm,
            };
            (s.triangles, Some(info), s.needs)
        }
    };
    let n = peaks.needs;
    let needs = DeviceNeeds {
        active_triangles: slicer.active_triangles,
        contour_points: slicer.contour_points,
        move_buffer_bytes: peaks.unit_bytes.value,
        toolpath_points: n.layer_points.max(n.offset_edges),
        toolpath_loops: n.layer_loops,
        scan_crossings: n.crossings,
        path_points: n.path_points,
        window_ring_words: n.ring_points,
        window_spans: n.spans,
        toolpath_ram_bytes: n.bytes() as u64,
    };
    let job = JobSpec { triangles: tris.len() as u32, ..job };
    let rep = simulate(&tris, &machine, job, &opts)
        .map_err(|(e, _)| format!("{}: {e}", args.model.display()))?;
    if let (Some(dir), Some(path)) = (&args.preview, &rep.path) {
        let title = format!("strata simulate {}", args.model.display());
        let n = preview::write(dir, path, &title)?;
        if !args.json {
            println!("preview: {n} layer pictures and {}", dir.join("index.html").display());
        }
    }
    report(args, &rep, simplified, needs, &pace)
}

fn report(
    args: &SimulateArgs,
    rep: &SimReport,
    simplified: Option<Simplified>,
    needs: DeviceNeeds,
    pace: &Pace,
) -> Result<(), String> {
    if args.json {
        let s = Summary {
            layers: rep.layers,
            print_time_s: rep.print_time_s,
            filament_mm: rep.filament_mm,
            steps: Steps { x: rep.steps[0], y: rep.steps[1], z: rep.steps[2], e: rep.steps[3] },
            max_step_error_us: rep.max_step_error_us,
            peak_active_triangles: rep.peak_active_triangles,
            peak_contour_points: rep.peak_contour_points,
            device_ram_bytes: rep.device_ram_bytes,
            device_needs: needs,
            wire_bytes_per_triangle: rep.wire_bytes_per_triangle,
            simplified,
            layer_hashes: rep.layer_hashes.iter().map(|h| format!("{h:016x}")).collect(),
            triangles: rep.triangles,
            stream_time_s: rep.stream_time_s,
            link_lag_s: pace.worst_lag_s,
            underruns: rep.underruns,
            rest_waits: rep.rest_waits(),
            retransmits: rep.host_link.retransmits,
        };
        println!("{}", serde_json::to_string_pretty(&s).map_err(|e| e.to_string())?);
    } else {
        println!(
            "{}: {} layers, print time {}, {:.1} mm of filament, streamed {} triangles in {:.1} s \
             ({:.1} bytes per triangle at {} baud)",
            args.model.display(),
            rep.layers,
            hms(rep.print_time_s),
            rep.filament_mm,
            rep.triangles,
            rep.stream_time_s,
            rep.wire_bytes_per_triangle,
            args.baud
        );
        println!(
            "steps X {} Y {} Z {} E {}, each within {:.2} us; peak active triangles {}, \
             peak contour points {}, device RAM needed {:.1} KB; underruns {}, waits for the \
             link {}",
            rep.steps[0],
            rep.steps[1],
            rep.steps[2],
            rep.steps[3],
            rep.max_step_error_us,
            rep.peak_active_triangles,
            rep.peak_contour_points,
            rep.device_ram_bytes as f64 / 1024.0,
            rep.underruns,
            rep.rest_waits()
        );
    }
    Ok(())
}

fn hms(s: f64) -> String {
    let t = s.round() as u64;
    format!("{}:{:02}:{:02}", t / 3600, t / 60 % 60, t % 60)
}

/// A G-code file by its extension (`.gcode`, `.gco`, `.g`, any case).
pub fn is_gcode(path: &Path) -> bool {
    let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase();
    matches!(ext.as_str(), "gcode" | "gco" | "g")
}

#[derive(Serialize)]
struct GcodeSummary {
    lines: u32,
    moves: u32,
    layers: u32,
    /// From the first step to the last, s (heating is not simulated).
    print_time_s: f64,
    /// The planner's print time, s.
    planned_s: f64,
    filament_mm: f64,
    steps: Steps,
    /// Final motor positions X, Y, Z, E, steps.
    positions: [i64; 4],
    layer_hashes: Vec<String>,
    /// Commands the printer skips, with their counts.
    skipped: std::collections::BTreeMap<String, u32>,
    /// Lines refused (malformed, out of range, bad checksum), with the first ones' numbers.
    refused: u32,
    refusals: Vec<String>,
    /// Moves whose target was clamped to the build volume.
    clamped: u32,
    stream_time_s: f64,
    underruns: u32,
    rest_waits: u32,
    violations: u32,
}

/// `strata simulate FILE.gcode`: the file streamed through the real protocol into the
/// simulated printer, which reads it with its G-code reader and runs it on its planner, step
/// generator and simulated steppers.
fn run_gcode_file(args: &SimulateArgs, machine: &MachineConfig) -> Result<(), String> {
    let name = args.model.display();
    let text = std::fs::read(&args.model).map_err(|e| format!("{name}: {e}"))?;
    let scan = gcode_file::scan(&text, machine).map_err(|e| format!("{name}: {e}"))?;
    let opts = SimOptions {
        baud: args.baud,
        faults: Faults::uniform(args.loss, args.seed),
        preview: args.preview.is_some(),
        ..SimOptions::default()
    };
    let rep = simulate_source(Source::Gcode(&text, scan.spec), machine, &opts)
        .map_err(|(e, _)| format!("{name}: {e}"))?;
    if let (Some(dir), Some(path)) = (&args.preview, &rep.path) {
        let n = preview::write(dir, path, &format!("strata simulate {name}"))?;
        if !args.json {
            println!("preview: {n} layer pictures and {}", dir.join("index.html").display());
        }
    }
    if args.json {
        let s = GcodeSummary {
            lines: scan.lines,
            moves: scan.moves,
            layers: scan.spec.layers,
            print_time_s: rep.print_time_s,
            planned_s: rep.planned_s,
            filament_mm: rep.filament_mm,
            steps: Steps { x: rep.steps[0], y: rep.steps[1], z: rep.steps[2], e: rep.steps[3] },
            positions: rep.positions,
            layer_hashes: rep.layer_hashes.iter().map(|h| format!("{h:016x}")).collect(),
            skipped: scan.skipped.clone(),
            refused: scan.refused,
            refusals: scan.refusals.iter().map(|(n, e)| format!("line {n}: {e}")).collect(),
            clamped: scan.clamped,
            stream_time_s: rep.stream_time_s,
            underruns: rep.underruns,
            rest_waits: rep.rest_waits(),
            violations: rep.violations,
        };
        println!("{}", serde_json::to_string_pretty(&s).map_err(|e| e.to_string())?);
        return Ok(());
    }
    println!(
        "{name}: {} lines, {} moves, {} layers, print time {} (heating not included), {:.1} mm \
         of filament, streamed in {:.1} s at {} baud",
        scan.lines,
        scan.moves,
        scan.spec.layers,
        hms(rep.print_time_s),
        rep.filament_mm,
        rep.stream_time_s,
        args.baud
    );
    println!(
        "steps X {} Y {} Z {} E {}; underruns {}, waits for the link {}, timing violations {}",
        rep.steps[0],
        rep.steps[1],
        rep.steps[2],
        rep.steps[3],
        rep.underruns,
        rep.rest_waits(),
        rep.violations
    );
    for w in scan.warnings() {
        println!("warning: {w}");
    }
    Ok(())
}
