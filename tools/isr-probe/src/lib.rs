//! The step interrupt as the firmware will build it: `Executor::on_timer` with pins that are
//! single register writes (BSRR-style set/reset), exported under fixed names for
//! `scripts/check_isr_asm.sh`.
#![no_std]

use core::convert::Infallible;

use embedded_hal::digital::{ErrorType, OutputPin};
use strata::step::{Executor, Pins, StepTimer, Wake};

/// Stand-in for a GPIO port's bit set/reset register (written with volatile stores, as a
/// register is: the compiler may not merge them).
static mut BSRR: u32 = 0;

/// A GPIO pin: one register write per edge.
pub struct RegPin {
    mask: u32,
}

impl ErrorType for RegPin {
    type Error = Infallible;
}

impl OutputPin for RegPin {
    #[inline]
    fn set_low(&mut self) -> Result<(), Infallible> {
        // SAFETY: a plain static written only here, standing in for the GPIO register.
        unsafe { core::ptr::write_volatile(core::ptr::addr_of_mut!(BSRR), self.mask << 16) };
        Ok(())
    }
    #[inline]
    fn set_high(&mut self) -> Result<(), Infallible> {
        // SAFETY: as above.
        unsafe { core::ptr::write_volatile(core::ptr::addr_of_mut!(BSRR), self.mask) };
        Ok(())
    }
}

/// The Cortex-M3's DWT cycle counter (CYCCNT), read as the board's step timer.
pub struct CycleCounter;

impl StepTimer for CycleCounter {
    #[inline]
    fn now(&mut self) -> u32 {
        // SAFETY: DWT_CYCCNT is a readable 32-bit register on every Cortex-M3.
        unsafe { core::ptr::read_volatile(0xE000_1004 as *const u32) }
    }
}

/// The timer interrupt body: service due edges (STEP pulses end inside, on the cycle
/// counter), return the next compare value (0 = idle).
#[no_mangle]
pub fn strata_step_isr(exec: &mut Executor<'static, 64>, pins: &mut Pins<RegPin>, now: u32) -> u32 {
    match exec.on_timer_with(now, pins, &mut CycleCounter) {
        Ok(Wake::At(t)) => t,
        Ok(Wake::Idle) => 0,
        Err(e) => match e {},
    }
}

/// Deliberately divides: the check's self-test must flag it.
#[no_mangle]
pub fn strata_probe_divides(a: u32, b: u32) -> u32 {
    a / b.max(1)
}

/// Deliberately uses floating point: the check's self-test must flag it.
#[no_mangle]
pub fn strata_probe_floats(a: u32) -> u32 {
    (a as f32 * 1.5) as u32
}

#[panic_handler]
fn panic(_: &core::panic::PanicInfo) -> ! {
    loop {}
}
