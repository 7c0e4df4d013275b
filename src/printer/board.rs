//! Every capacity of the firmware build (the Creality 4.2.x boards and QEMU's lm3s6965evb,
//! 64 KB of RAM each) in one place: the firmware builds [`BoardPrinter`], which
//! announces [`BOARD_CAPACITIES`].
//!
//! The capacities are the largest of what embodier_hotend_v2 needs at the default settings
//! (it prints unsimplified), what embodier_LM8UU_8p2pi needs simplified for the slicer (742
//! active triangles unsimplified; admission simplifies it within the default 0.02 mm) with its
//! offsets done in bands, and what 3DBenchy, scaled_mm/stanford_bunny_x60 and
//! scaled_mm/fertility_genus4_x80 need admitted within 0.05 mm (3DBenchy: 225,135 triangles
//! simplified to 4,375, measured deviation 0.049 mm: `strata simulate
//! ../shared/models/3DBenchy.stl --max-deviation 0.05 --json`, its `device_needs`; every model's
//! peaks with their layers: `host/examples/layer_needs.rs`); embodier_asc and xyz_20mm_cube need
//! far less of each. RAM on the board = the `Printer`
//! (slicer + toolpath + their scratch + move buffer + planner + generator) + the protocol
//! endpoint, the step queue, the executor and the UART buffers + the stack; the firmware
//! prints `.data + .bss` and the stack's high-water mark after every job, and
//! `scripts/build_firmware.sh` fails when the static part leaves less than the stack reserve
//! (see there).
//! Per-unit bytes, each asserted beside its constant: the slicer's
//! ([`slicer_bytes`](crate::slice::slicer_bytes)); the scratch the slicer and the toolpath
//! stage take turns in holds the largest of the cut
//! ([`CutScratch::BYTES_PER_SEGMENT`](crate::slice::CutScratch::BYTES_PER_SEGMENT) per
//! segment, the layer's loop points taking the dead hash's place), the offset engine with its
//! result's points ([`ToolpathNeeds::ENGINE_BYTES`](crate::toolpath::ToolpathNeeds::ENGINE_BYTES)
//! per `PTS`) and the infill scratch
//! ([`ToolpathNeeds::CROSS_BYTES`](crate::toolpath::ToolpathNeeds::CROSS_BYTES) per `CROSS`)
//! ([`crate::scratch`]); the rest of the toolpath stage see
//! [`ToolpathNeeds`](crate::toolpath::ToolpathNeeds); the move buffer holds the largest path
//! with its travel (a unit) whole ([`MOVE_BUFFER_BYTES`]).

use crate::machine::MachineConfig;
use crate::protocol::{Capacities, JobSpec};
use crate::toolpath::{Seam, ToolpathConfig};

/// Slicer: active triangles (3DBenchy within 0.05 mm: 426, the walls of the lettering under its
/// hull; embodier_hotend_v2: 388).
pub const ACTIVE_TRIANGLES: usize = 432;
/// Slicer: segments and contour points per layer (3DBenchy: 426; hotend: 388).
pub const CONTOUR_POINTS: usize = 432;
/// Slicer: loops per layer (3DBenchy: 10).
pub const CONTOUR_LOOPS: usize = 10;
/// Toolpath.
///
/// Loop points per layer and offset edges per island (scaled_mm/stanford_bunny_x60 within
/// 0.05 mm: 290 loop points at 53.8 mm; 3DBenchy: 270 in its first layer, its offsets in bands;
/// an island's offset that needs more edges is done in bands; hotend: 202 edges, whole).
pub const TOOLPATH_POINTS: usize = 290;
/// Toolpath: loops per layer (LM8UU: 14; hotend: 6).
pub const TOOLPATH_LOOPS: usize = 14;
/// Toolpath: scanline crossings, infill segments and paths per layer
/// (scaled_mm/fertility_genus4_x80 within 0.05 mm: 598 in layer 59; hotend: 512).
pub const SCAN_CROSSINGS: usize = 598;
/// Toolpath: path points per layer (stanford_bunny_x60: 1,110 in layer 267; 3DBenchy: 1,010;
/// hotend: 1,000).
pub const PATH_POINTS: usize = 1_110;
/// Toolpath: words of the skin window's stored contours.
///
/// Its built layers are kept within half a line ([`job_toolpath_config`]): stanford_bunny_x60
/// 1,719 at layer 272 (2,217 with every layer at 25 um), fertility_genus4_x80 1,658, hotend
/// 1,409, 3DBenchy 1,201.
pub const WINDOW_RING_WORDS: usize = 1_728;
/// Toolpath: the skin window's crossings with one scanline (hotend 27; the banded
/// cylinders of the HIL test more).
pub const WINDOW_SPANS: usize = 48;
/// Bytes of the move buffer (toolpath moves waiting for the planner, delta-coded).
///
/// The toolpath stage fills it a unit (a path with the travel before it) at a time, each once its
/// coded bytes fit, so the largest unit must fit whole: at the default settings embodier_asc 693 B,
/// xyz_20mm_cube 1,051 B, embodier_hotend_v2 1,059 B, embodier_LM8UU_8p2pi 1,089 B, about 6 B a
/// move. 2.25 KB is 2.1 times the largest. The rest keeps the motion fed while the next layer is
/// computed: the stage refills the buffer as the planner takes moves, so it is about full when a
/// layer's last unit goes in, and those ~370 moves (seconds of printing, still ~0.7 s of 2 ms
/// segments) carry the motion through the next layer's cut and build (about 0.5 s for a large layer
/// on the Cortex-M3), lent the motion half at its progress points.
pub const MOVE_BUFFER_BYTES: usize = 2_304;
/// Commands per axis in the step queue between the generator and the step interrupt (a power
/// of two; 12 B each, 4 axes: 1.5 KB; the host simulation's).
///
/// The queue's size does not change the commands (the generator's output depends on the blocks
/// only), only how far ahead of the executor the generator may run: the board's feed interrupt
/// refills it at least every millisecond, above thread mode, so a few milliseconds of commands
/// are enough. The real-time HIL test (`qemu_realtime_first_layers`, its `RT ... min_slack`)
/// shows the margin.
pub const STEP_QUEUE_COMMANDS: usize = 32;
/// Planner lookahead, moves (the host simulation plans with the same).
pub const LOOKAHEAD_MOVES: usize = 32;

crate::printer_type! {
    /// The job runner of the firmware build.
    pub type BoardPrinter = {
        active_triangles: ACTIVE_TRIANGLES,
        contour_points: CONTOUR_POINTS,
        contour_loops: CONTOUR_LOOPS,
        toolpath_points: TOOLPATH_POINTS,
        toolpath_loops: TOOLPATH_LOOPS,
        scan_crossings: SCAN_CROSSINGS,
        path_points: PATH_POINTS,
        window_ring_words: WINDOW_RING_WORDS,
        window_spans: WINDOW_SPANS,
        move_buffer_bytes: MOVE_BUFFER_BYTES,
        lookahead_moves: LOOKAHEAD_MOVES,
    };
}

/// The capacities the firmware build (this module) announces.
pub const BOARD_CAPACITIES: Capacities = BoardPrinter::CAPACITIES;

/// What the host's simulated printer announces by default.
///
/// The slicer capacities the protocol was specified with (1024 active triangles, 768 contour
/// points, 48 loops) and host-sized toolpath capacities. The real 64 KB build holds far less:
/// [`BOARD_CAPACITIES`].
pub const CREALITY_CAPACITIES: Capacities = Capacities {
    active_triangles: 1024,
    contour_points: 768,
    contour_loops: 48,
    move_buffer_bytes: 1 << 16,
    layer_window: 4,
    ram_bytes: 64 * 1024,
    toolpath_points: 1 << 15,
    toolpath_loops: 1 << 11,
    scan_crossings: 1 << 15,
    path_points: 1 << 17,
    window_ring_words: 1 << 17,
    window_spans: 1 << 16,
};

/// Contour simplification of the printer's toolpath stage, um (the host's G-code export keeps
/// `ToolpathConfig`'s 10 um).
///
/// CuraEngine's default maximum deviation, two X/Y steps: fewer loop points, path points and
/// stored contours per layer in the same RAM (3DBenchy admitted within 0.05 mm: 270 loop points
/// in its worst layer instead of 329 at 10 um, `host/examples` probe of the session note).
pub const SIMPLIFY_TOLERANCE_UM: i32 = 25;

/// The printer's minimum layer time, ms.
///
/// A smaller layer's extrusions are slowed (not below `ToolpathConfig`'s 10 mm/s) to take this
/// long, and one still shorter waits the rest at its end, retracted with the nozzle lifted off
/// the part.
///
/// PrusaSlicer's default (`slowdown_below_layer_time`, and 10 mm/s its `min_print_speed`; the
/// wait is Cura's "lift head"): the layer below cools, and the top of a small part no longer
/// prints faster than the board computes the next layer 20 times over (3DBenchy's chimney top,
/// layers 201 and 203, printed in 1.26 s and 0.89 s at full speed: 11.3x and 13.8x; the
/// slowdown alone left stanford_bunny_x60's ear tip, layer 309, at 0.28 s and 2.1x, the wait
/// at 5.35 s and 46x: `tools/job-cost/run.sh --max-deviation 0.05 MODEL`).
pub const MIN_LAYER_TIME_MS: u32 = 5_000;

/// The toolpath settings the printer derives from `job` (the host's admission control sizes
/// the job with the same).
pub fn job_toolpath_config(machine: &MachineConfig, job: &JobSpec) -> ToolpathConfig {
    let mut cfg = ToolpathConfig::new(machine, &job.settings);
    cfg.outer_perimeter_last = job.options.outer_perimeter_last;
    cfg.seam = if job.options.seam == 1 { Seam::Nearest } else { Seam::Rear };
    cfg.skirt_loops = job.options.skirt_loops;
    cfg.skirt_distance_um = job.options.skirt_distance_um;
    // The loops the host counted, as the width that holds exactly them.
    cfg.brim_width_um = i32::from(job.options.brim_loops) * cfg.line_width_um;
    // The thin-area figures are a host report (`strata slice`); the printer makes the same
    // toolpaths without them and saves an offset per island and layer.
    cfg.measure_thin_area = false;
    cfg.simplify_tolerance_um = SIMPLIFY_TOLERANCE_UM;
    // Built layers stay in the skin window for the bottom skins above only: their regions
    // within half a line, the infill's reach into the perimeters (3DBenchy's window: 1,370
    // words at 25 um, 1,201 so; stanford_bunny_x60: 2,217, 1,719 so).
    cfg.below_tolerance_um = cfg.line_width_um / 2;
    cfg.min_layer_time_ms = MIN_LAYER_TIME_MS;
    // Bridges and overhang perimeters as in `strata slice`'s G-code; a layer whose bridges
    // need more path points or scanline crossings than the board holds goes without them
    // (`Toolpath::set_bridge_limits`: the board's own capacities).
    cfg
}
