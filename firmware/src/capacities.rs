//! Every capacity of the firmware build in one place (64 KB of RAM on every board: the
//! Creality boards' STM32F103RET6 and QEMU's lm3s6965evb).
//!
//! RAM = the `Printer` (slicer + toolpath + move buffer + planner + generator) + the protocol
//! endpoint + the step queue + the executor + the stack. `.data + .bss` and the stack's
//! high-water mark are printed at the end of each job (`MEM ...`, see `stack.rs`), and
//! `scripts/build_firmware.sh` prints the static part.
//!
//! Measured with these values (QEMU, opt-level "s"): `.data + .bss` 51.6 KB (the Printer is
//! most of it), leaving 13.9 KB of stack; the planner and the step generator are reset in
//! place when a job starts (no stack temporaries). `embodier_asc.stl` and `xyz_20mm_cube.stl`
//! print end to end on QEMU (host/tests/hil_qemu.rs). Per-unit bytes: see each constant.
//!
//! What the larger sample models need beyond this (host `cargo run --release --example
//! toolpath_report`): embodier_hotend_v2 373 active triangles, CROSS 512, PATH 1010, RING
//! 1928 and about 1,100 moves in its largest layer; embodier_LM8UU_8p2pi 283 active
//! triangles, PTS 690 (1,740 for its thin-wall measurement), RING 1600. The move buffer
//! (a layer's moves) and the toolpath scratch do not fit 64 KB for them yet.
//!
//! The planner lookahead `P` must stay 32: the host simulation (`strata simulate`, the HIL
//! test) plans with 32 moves of lookahead, and the per-layer hashes compare step commands.
//! (The step queue's size does not change the commands: the generator's output depends on
//! the blocks only.)

use strata::printer::Printer;
use strata::protocol::Endpoint;

/// Slicer: active triangles (24 B each).
pub const A: usize = 128;
/// Slicer: segments and contour points per layer (37 B each).
pub const S: usize = 192;
/// Slicer: loops per layer (72 B each).
pub const L: usize = 8;
/// Toolpath: loop points per layer and offset edges per island (74 B each).
pub const PTS: usize = 128;
/// Toolpath: loops per layer (124 B each).
pub const LOOPS: usize = 4;
/// Toolpath: scanline crossings, infill segments and paths per layer (22 B each).
pub const CROSS: usize = 224;
/// Toolpath: path points per layer (9 B each).
pub const PATH: usize = 384;
/// Toolpath: contour points of the layers waiting for the layers above (4 B each).
pub const RING: usize = 512;
/// Toolpath: scanline spans of the skin window (8 B each).
pub const SPANS: usize = 48;
/// Toolpath moves waiting for the planner, 24 B each: the slicer cuts a layer while at most a
/// quarter is in use, so a layer's moves must fit the other three quarters.
pub const MOVES: usize = 448;
/// Planner lookahead, moves (must equal the host simulation's: 32).
pub const P: usize = 32;

/// The job runner of this build.
pub type FwPrinter = Printer<A, S, L, PTS, LOOPS, CROSS, PATH, RING, SPANS, MOVES, P>;

/// Commands per axis in the step queue (a power of two; 12 B each, 4 axes; the host
/// simulation's).
pub const STEP_QUEUE: usize = 64;

/// The device's protocol endpoint: 2 frames in flight, 2 receive slots (the host simulation's
/// device has 4 and 4; the link adapts through its credits).
pub type FwEndpoint = Endpoint<2, 2>;

/// `Printer::poll` calls per main-loop turn (each is bounded work).
pub const POLLS_PER_LOOP: usize = 16;

/// A status report at least this often, ms.
pub const STATUS_EVERY_MS: u32 = 200;
