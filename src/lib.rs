//! Strata core: an on-board streaming slicer, motion planner and step generator.
//!
//! Everything between "an STL triangle arrives" and "a step pulse leaves" lives here, as
//! bounded-memory state machines that run unchanged on the printer's Cortex-M3 (no FPU, 64 KB
//! RAM) and on the host (G-code export, the simulated printer, tests).
//!
//! Stages (one module each), in data-flow order:
//! - [`stl`]: incremental push parser for binary and ASCII STL (any chunking, typed errors).
//! - [`place`]: drop the model onto the bed, centre it, quantise to micrometres.
//! - [`slice`](mod@slice): sweep-plane slicer over a zmin-sorted triangle stream, one layer at a time.
//! - [`plan`]: lookahead motion planner (junction deviation, trapezoids, exact print time).
//! - [`step`]: exact step times compressed to `(interval, count, add)` sequences, and the
//!   timer-interrupt executor driving `embedded-hal` step/dir/enable pins.
//! - [`toolpath`]: perimeters, infill, skins, skirt, ordering and retraction as a stream of moves.
//! - [`gcode`]: Marlin-flavoured G-code writer (PrusaSlicer-compatible comments) and reader.
//! - [`protocol`]: the host-device link: COBS frames with CRC-32, sequence numbers, acks,
//!   credits and retransmission; messages and the compact triangle encoding.
//! - [`card`]: the printer's microSD card: a FAT16/FAT32 reader with no block buffer.
//! - [`printer`]: the device-side job runner: protocol messages in, slicer, toolpaths,
//!   planner and step generator driven with bounded work per poll, status reports out.
//!
//! Shared foundations: [`geom`] (integer micrometre geometry), [`math`] (exact integer roots
//! and divisions), [`machine`] (printer profile and print settings with validation) and
//! [`scratch`] (the per-layer working memory the
//! slicer and the toolpath stage take turns in);
//! [`sim`] is the simulated stepper backend (pins, hand-advanced clock, timing checks, step hash).
//!
//! Guarantees:
//! - `no_std`, no allocator: every buffer has a capacity fixed at compile time (const generics);
//!   exceeding one returns a typed error naming what overflowed, never a panic.
//! - No panic is reachable from input bytes (the parsers are fuzzed).
//! - Positions are integer micrometres (`i32`), products in `i64`; rates use `fixed`.
//! - Time is always an argument; nothing reads a clock.
#![cfg_attr(not(test), no_std)]
#![forbid(unsafe_code)]
#![deny(missing_docs)]

pub mod card;
pub mod gcode;
pub mod geom;
pub mod machine;
pub mod math;
pub mod move_ring;
pub mod place;
pub mod plan;
pub mod printer;
pub mod protocol;
pub mod scratch;
pub mod sim;
pub mod slice;
pub mod slot;
pub mod step;
pub mod stl;
pub mod thermal;
pub mod toolpath;

/// Test helpers shared by the modules' unit tests.
#[cfg(test)]
pub(crate) mod test_rng {
    /// A xorshift64 generator from `seed` (not 0): deterministic pseudo-random `u64`s for
    /// randomised unit tests.
    pub(crate) fn xorshift(mut x: u64) -> impl FnMut() -> u64 {
        move || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x
        }
    }
}
