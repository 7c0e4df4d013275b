//! Every capacity of the firmware build in one place (64 KB of RAM on every board: the
//! Creality boards' STM32F103RET6 and QEMU's lm3s6965evb).
//!
//! RAM = the `Printer` (slicer + toolpath + move buffer + planner + generator) + the protocol
//! endpoint + the step queue + the executor + the stack. `.data + .bss` and the stack's
//! high-water mark are printed at the end of each job (`MEM ...`, see `stack.rs`), and
//! `scripts/build_firmware.sh` prints the static part.
//!
//! Measured with these values (QEMU, opt-level "s", small cylinder job): Printer ~40 KB,
//! `.data + .bss` ~46.5 KB (Creality ~47 KB: its 512-byte receive ring and RTT buffer), stack
//! high-water 16.2 KB. About 8 KB of that stack is `Printer::handle` (the job start builds
//! the planner and the step generator as stack temporaries), so the stack must keep ~17 KB
//! until that changes.
//!
//! What the sample models need today (host `strata slice --json` needs): xyz_20mm_cube 72
//! active triangles, CROSS 182, RING 120-369; embodier_asc CROSS 114, RING 81. Beyond the
//! toolpath, every model whose tall faces complete many layers in one batch overflows
//! `MOVES` (the slicer emits all those layers at once).
//!
//! The planner lookahead `P` must stay 32: the host simulation (`strata simulate`, the HIL
//! test) plans with 32 moves of lookahead, and the per-layer hashes compare step commands.
//! The step queue must stay 64 for the same reason (when the generator waits on a full queue
//! depends on its size).

use strata::printer::Printer;
use strata::protocol::Endpoint;

/// Slicer: active triangles (24 B each).
pub const A: usize = 96;
/// Slicer: segments and contour points per layer (37 B each).
pub const S: usize = 160;
/// Slicer: loops per layer (72 B each).
pub const L: usize = 8;
/// Toolpath: loop points per layer and offset edges per island (74 B each).
pub const PTS: usize = 80;
/// Toolpath: loops per layer (124 B each).
pub const LOOPS: usize = 4;
/// Toolpath: scanline crossings, infill segments and paths per layer (22 B each).
pub const CROSS: usize = 128;
/// Toolpath: path points per layer (9 B each).
pub const PATH: usize = 320;
/// Toolpath: contour points of the layers waiting for the layers above (4 B each).
pub const RING: usize = 192;
/// Toolpath: scanline spans of the skin window (8 B each).
pub const SPANS: usize = 64;
/// Toolpath moves waiting for the planner, 40 B each (a layer must fit half of it; today the
/// slicer emits every layer a batch completes at once, so a model whose tall faces complete
/// many layers in one batch needs them all here).
pub const MOVES: usize = 320;
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
