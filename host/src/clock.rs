//! The clocks the host side of a link runs on.
//!
//! Against a real printer the link's timers (retransmission, keepalive, the dead link, the
//! abort confirmation) run on the wall clock ([`WallClock`]). Against an emulator or a
//! simulated printer that runs slower or faster than real time they run on the device's own
//! clock (QEMU's instruction clock, a simulation's virtual milliseconds): host and device then
//! share one timeline, and a busy machine that slows the device slows the host's timers with
//! it. Such a clock is read from elsewhere, so it can stop (the emulator hung or exited):
//! [`StallCheck`] turns a clock that has not moved for a stated stretch of wall time into an
//! error, the one wall-clock decision left, and one about the emulator, never about the link.
//! [`Budget`] ends a job that runs past a budget of its clock's time.

use std::time::{Duration, Instant};

/// A millisecond clock for a link.
pub trait LinkClock {
    /// Milliseconds since the clock's origin (wrapping), or why the clock cannot go on.
    fn now_ms(&mut self) -> Result<u32, String>;
}

impl<C: LinkClock + ?Sized> LinkClock for &mut C {
    fn now_ms(&mut self) -> Result<u32, String> {
        (**self).now_ms()
    }
}

impl<C: LinkClock + ?Sized> LinkClock for Box<C> {
    fn now_ms(&mut self) -> Result<u32, String> {
        (**self).now_ms()
    }
}

/// The wall clock, from its creation: the clock of a real printer's link.
#[derive(Debug, Clone, Copy)]
pub struct WallClock {
    t0: Instant,
}

impl WallClock {
    /// A clock at 0 now.
    pub fn new() -> Self {
        Self { t0: Instant::now() }
    }
}

impl Default for WallClock {
    fn default() -> Self {
        Self::new()
    }
}

impl LinkClock for WallClock {
    fn now_ms(&mut self) -> Result<u32, String> {
        Ok(self.t0.elapsed().as_millis() as u32)
    }
}

/// How long a device's clock may stand still, in wall time, before it counts as stopped.
///
/// An emulator on a machine whose cores are both saturated still moves its clock every few
/// milliseconds (QEMU's moves every 10 us of emulated time), so a minute of standstill is a hung or
/// dead emulator, not a slow one.
pub const CLOCK_STALL_LIMIT: Duration = Duration::from_secs(60);

/// Watches a clock read from elsewhere: an error once its value has not changed for
/// `limit` of wall time.
#[derive(Debug, Clone)]
pub struct StallCheck {
    what: &'static str,
    last: Option<u64>,
    since: Instant,
    limit: Duration,
}

impl StallCheck {
    /// A check of the clock named `what` (for the message), allowed to stand still for
    /// `limit`.
    pub fn new(what: &'static str, limit: Duration) -> Self {
        Self { what, last: None, since: Instant::now(), limit }
    }

    /// Notes a reading taken at `wall`; an error when the clock stood still for longer than
    /// the limit.
    pub fn check(&mut self, value: u64, wall: Instant) -> Result<(), String> {
        if self.last != Some(value) {
            self.last = Some(value);
            self.since = wall;
            return Ok(());
        }
        let still = wall.saturating_duration_since(self.since);
        if still > self.limit {
            return Err(format!(
                "{}'s clock stood still for {:.0} s of wall time (hung or stopped)",
                self.what,
                still.as_secs_f64()
            ));
        }
        Ok(())
    }
}

/// A clock that ends with an error once `budget_ms` of it passed since its first reading: the
/// hang guard of a job on an emulator, in the emulator's own time.
#[derive(Debug)]
pub struct Budget<C> {
    inner: C,
    start: Option<u32>,
    budget_ms: u32,
}

impl<C: LinkClock> Budget<C> {
    /// `inner`, limited to `budget_ms` from now.
    pub fn new(inner: C, budget_ms: u32) -> Self {
        Self { inner, start: None, budget_ms }
    }
}

impl<C: LinkClock> LinkClock for Budget<C> {
    fn now_ms(&mut self) -> Result<u32, String> {
        let now = self.inner.now_ms()?;
        let start = *self.start.get_or_insert(now);
        if now.wrapping_sub(start) > self.budget_ms {
            return Err(format!(
                "the job did not end within {:.0} s of the device's clock (aborted)",
                self.budget_ms as f64 / 1000.0
            ));
        }
        Ok(now)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Manual(u32);

    impl LinkClock for Manual {
        fn now_ms(&mut self) -> Result<u32, String> {
            Ok(self.0)
        }
    }

    #[test]
    fn a_budget_ends_past_its_time_of_the_inner_clock() {
        let mut b = Budget::new(Manual(1_000), 500);
        assert_eq!(b.now_ms(), Ok(1_000));
        b.inner.0 = 1_500;
        assert_eq!(b.now_ms(), Ok(1_500));
        b.inner.0 = 1_501;
        let e = b.now_ms().unwrap_err();
        assert!(e.contains("within 0 s") || e.contains("within 1 s"), "{e}");
    }

    #[test]
    fn a_clock_that_stands_still_past_the_limit_is_an_error() {
        let t0 = Instant::now();
        let at = |ms| t0 + Duration::from_millis(ms);
        let mut s = StallCheck::new("qemu", Duration::from_millis(30));
        assert!(s.check(5, at(0)).is_ok());
        assert!(s.check(5, at(30)).is_ok());
        let e = s.check(5, at(31)).unwrap_err();
        assert!(e.starts_with("qemu's clock stood still"), "{e}");
        // A moving clock is fine again, and its standstill counts from its last move.
        assert!(s.check(6, at(40)).is_ok());
        assert!(s.check(6, at(70)).is_ok());
        assert!(s.check(6, at(71)).is_err());
    }
}
