//! Strata firmware (skeleton): links the core for the Creality board's memory map.
//!
//! The board support, main loop and step ISR arrive with the firmware issue; for now this
//! proves that the core links into a Cortex-M3 image at 0x0800_7000 with 64 KB of RAM.
#![no_std]
#![no_main]

use cortex_m_rt::entry;
use panic_halt as _;
use strata::machine::{MachineConfig, PrintSettings};

#[entry]
fn main() -> ! {
    let machine = MachineConfig::default();
    let settings = PrintSettings::default();
    let _valid = settings.validate(&machine).is_ok();
    loop {
        cortex_m::asm::wfi();
    }
}
