//! Main-loop watchdog: the core half of "a stalled loop leaves the heaters off".
//!
//! The firmware kicks a [`Watchdog`] from its main loop after each thermal update and asks
//! [`Watchdog::check`] from a place that keeps running when the loop does not (the PWM timer
//! interrupt that drives the heater pins): once the deadline has passed, that interrupt forces the
//! heater pins low and stops refreshing the hardware IWDG, which then resets the board; after the
//! reset every heater starts off. The deadline arithmetic is here, the IWDG is the firmware's.

use super::ThermalFault;

/// Default allowed gap between kicks, ms (the thermal loop runs at 10 Hz).
pub const DEFAULT_TIMEOUT_MS: u32 = 2_000;

/// A deadline that each kick pushes back.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Watchdog {
    timeout_ms: u32,
    last_kick_ms: u32,
}

impl Watchdog {
    /// A watchdog kicked at `now_ms` that expires `timeout_ms` after the last kick.
    pub const fn new(now_ms: u32, timeout_ms: u32) -> Self {
        Self { timeout_ms, last_kick_ms: now_ms }
    }

    /// The main loop is alive at `now_ms`.
    pub fn kick(&mut self, now_ms: u32) {
        self.last_kick_ms = now_ms;
    }

    /// Whether more than the timeout has passed since the last kick (wrap-safe for gaps below
    /// 2^31 ms).
    pub const fn expired(&self, now_ms: u32) -> bool {
        let since = now_ms.wrapping_sub(self.last_kick_ms) as i32;
        since > self.timeout_ms as i32
    }

    /// [`ThermalFault::Watchdog`] once expired.
    pub const fn check(&self, now_ms: u32) -> Result<(), ThermalFault> {
        if self.expired(now_ms) {
            Err(ThermalFault::Watchdog)
        } else {
            Ok(())
        }
    }
}
