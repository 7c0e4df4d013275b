//! Fixtures shared by the integration tests of `strata` (`tests/`) and `strata-host`
//! (`host/tests/`), and by the benches and examples: one copy of each, so that a fix or a new
//! shape reaches every test.
//!
//! - [`mesh`]: analytic shapes in mm (`f64`), quantised to the core's um
//!   [`Triangle`](strata::geom::Triangle)s ([`mesh::to_um`]) or to the `f32` corners of an
//!   STL file ([`mesh::to_f32`]);
//! - [`stl`]: reference STL writers (binary and ASCII, standard and odd) that share no code
//!   with the parser;
//! - [`rng`]: the one seeded generator;
//! - [`drive`]: the printer drive loop: a job's messages into a [`Printer`], polls, the
//!   step queue drained (counted, recorded, or executed on a [`SimBoard`]), layer hashes out;
//! - [`models`]: the shared model files (`../shared/models` beside the checkout), placed;
//! - [`card`]: SD card images written by the `fatfs` crate;
//! - [`check`]: `f64` geometry oracles independent of the core's integer code;
//! - [`coverage`]: top and bottom surface coverage, the instrument for skins and gap fill;
//! - [`overhang`]: extrusion over air, the instrument for bridges and supports;
//! - [`on_big_stack`]: a closure on a thread with room for host-sized pipeline values.
//!
//! Only integration tests, benches and examples may use the kit: they link the same `strata`
//! library the kit does. A unit test inside `strata`'s `src/` is compiled into a second copy
//! of `strata` (with `cfg(test)`), whose types are not the kit's.
//!
//! [`Printer`]: strata::printer::Printer
//! [`SimBoard`]: strata::sim::SimBoard
#![forbid(unsafe_code)]
#![deny(missing_docs)]

pub mod card;
pub mod check;
pub mod coverage;
pub mod drive;
pub mod mesh;
pub mod models;
pub mod overhang;
pub mod rng;
pub mod stl;

/// Stack of [`on_big_stack`]'s thread, bytes: a host-sized slicer, toolpath stage or printer
/// is megabytes in a debug build, and only the pages touched are committed.
pub const BIG_STACK_BYTES: usize = 512 << 20;

/// Runs `f` on a thread with a [`BIG_STACK_BYTES`] stack and returns what it returns (a panic
/// in `f` panics here).
pub fn on_big_stack<R: Send>(f: impl FnOnce() -> R + Send) -> R {
    std::thread::scope(|scope| {
        std::thread::Builder::new()
            .stack_size(BIG_STACK_BYTES)
            .spawn_scoped(scope, f)
            .expect("spawn a big-stack thread")
            .join()
            .unwrap_or_else(|panic| std::panic::resume_unwind(panic))
    })
}
