//! Strata firmware: the core's `Printer` (slicer, toolpaths, planner, step generator) behind
//! the protocol on the UART, the step executor in a timer interrupt.
//!
//! One board per build: `--features creality-v422`, `creality-v427` or `qemu` (see
//! README.md). Everything above `board/` is shared.
#![no_std]
#![no_main]

#[cfg(not(any(feature = "creality-v422", feature = "creality-v427", feature = "qemu")))]
compile_error!("select a board: --features creality-v422, creality-v427 or qemu");
#[cfg(any(
    all(feature = "creality-v422", feature = "creality-v427"),
    all(feature = "creality", feature = "qemu")
))]
compile_error!("select exactly one board feature");

#[cfg(feature = "creality")]
use defmt_rtt as _;
use panic_halt as _;

mod app;
mod board;
mod capacities;
#[cfg(feature = "qemu")]
mod cost;
mod heat;
mod log;
mod motion;
mod pipeline_motion;
mod stack;

use cortex_m_rt::entry;
use static_cell::{ConstStaticCell, StaticCell};

use capacities::{FwEndpoint, FwPrinter};
use strata::protocol::{Endpoint, LinkConfig};

/// The whole pipeline, built at compile time in place (no stack temporary). `Printer::empty`
/// is all zero bytes, so it lives in `.bss` (zeroed at boot, no flash image);
/// `scripts/build_firmware.sh` fails the build if it lands in `.data`.
static PRINTER: ConstStaticCell<FwPrinter> = ConstStaticCell::new(FwPrinter::empty());
/// The printer's motion half (move buffer, planner, generator), all zero bytes too.
static MOTION: ConstStaticCell<pipeline_motion::FwMotionHalf> =
    ConstStaticCell::new(pipeline_motion::FwMotionHalf::EMPTY);
/// The protocol endpoint (3.3 KB; `LinkConfig::default()` is not const, so it is built at
/// start-up, in place where the optimiser manages).
static ENDPOINT: StaticCell<FwEndpoint> = StaticCell::new();

#[entry]
fn main() -> ! {
    stack::paint();
    let printer = PRINTER.take();
    // `Printer::empty` is unconfigured (zero limits and steps/mm): configure it in place
    // before anything reads its step configuration.
    printer.configure(&app::MACHINE);
    let ep = ENDPOINT.init_with(|| Endpoint::new(LinkConfig::device()));
    let board = board::init(printer.step_config());
    app::run(board, printer, MOTION.take(), ep)
}
