//! Every capacity of the firmware build in one place (64 KB of RAM on every board: the
//! Creality boards' STM32F103RET6 and QEMU's lm3s6965evb).
//!
//! RAM = the `Printer` (slicer + toolpath + the scratch they take turns in, where the slicer
//! also leaves each layer's loop points for the toolpath stage to copy + move buffer +
//! planner + generator) + the protocol endpoint + the step queue + the executor + the stack.
//! `.data + .bss` and the stack's high-water mark are printed at the end of each job (`MEM
//! ...`, see `stack.rs`), and `scripts/build_firmware.sh` prints the static part.
//!
//! The pipeline's capacities, what each is sized for and the bytes each unit takes are
//! documented once, beside the constants, in `strata::printer::board`: the host admits models
//! against exactly what this build holds (host/tests/hil_qemu.rs prints the sample models on
//! it).
//!
//! The planner lookahead (`LOOKAHEAD_MOVES`) must stay the host simulation's (`strata
//! simulate`, the HIL test plans with the same), as the per-layer hashes compare step
//! commands.
//! (The step queue's size does not change the commands: the generator's output depends on
//! the blocks only.)

use strata::protocol::Endpoint;

/// The pipeline's capacities live in the core (`strata::printer::board`), so that the host
/// admits models against exactly what this build holds.
#[cfg(not(feature = "qemu-mps2"))]
pub use strata::printer::board::BoardPrinter as FwPrinter;

#[cfg(feature = "qemu-mps2")]
strata::printer_type! {
    /// QEMU mps2-an385 (4 MB of RAM, not a real board): room for every HIL sample model at the
    /// default 0.02 mm, unsimplified and their offsets whole (embodier_LM8UU_8p2pi: 742 active
    /// triangles, 1,740 loop points; the 64 KB build prints it simplified, its offsets in bands),
    /// so that it runs so on the Cortex-M3 instruction set too, for its cost figures and the
    /// bit-exact comparison with the host. The move buffer is the 64 KB
    /// board's (`MOVE_BUFFER_BYTES`; the largest unit of any sample model is 1,089 B): the slicer cuts a
    /// layer once the previous one is all in the buffer, so a larger buffer would let the
    /// pipeline run layers ahead of the motion and the per-layer costs would not be the board's.
    pub type FwPrinter = {
        active_triangles: 1024,
        contour_points: 1024,
        contour_loops: 48,
        toolpath_points: 2048,
        toolpath_loops: 64,
        scan_crossings: 1024,
        path_points: 2048,
        window_ring_words: 4096,
        window_spans: 256,
        move_buffer_bytes: strata::printer::board::MOVE_BUFFER_BYTES,
        lookahead_moves: strata::printer::board::LOOKAHEAD_MOVES,
    };
}

/// Commands per axis in the step queue (the host simulation's; see there).
pub use strata::printer::board::STEP_QUEUE_COMMANDS as STEP_QUEUE;

/// The device's protocol endpoint: 2 frames in flight, 1 receive slot (the host simulation's
/// device has 4 and 4; the link adapts through its credits). One slot keeps the host to one
/// data frame in flight: while thread mode computes a layer and reads nothing, the Creality's
/// 512-byte receive ring takes that frame and the host's probes and keepalives for seconds
/// (`tests/link_endpoints.rs`, `a_busy_device_buffers_no_more_than_its_receive_ring`).
pub type FwEndpoint = Endpoint<2, 1>;

/// `Printer::poll` calls per main-loop turn (each is bounded work).
pub const POLLS_PER_LOOP: usize = 16;

/// A status report at least this often, ms.
pub const STATUS_EVERY_MS: u32 = 200;
