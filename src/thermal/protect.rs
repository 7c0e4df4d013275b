//! Marlin-like thermal protection, one state machine per heater.
//!
//! - **Max temperature**: a reading above [`ProtectParams::max_c`] (the machine's highest
//!   settable target plus [`MAXTEMP_MARGIN_C`], like Marlin's `HEATER_MAXTEMP` over
//!   `HOTEND_OVERSHOOT`) trips [`ThermalFault::MaxTemp`]: a heater stuck on, whatever the target.
//! - **Min temperature**: a reading below [`ProtectParams::min_c`] (5 °C, Marlin's
//!   `HEATER_MINTEMP`) means a sensor that is not reading the heater: [`ThermalFault::MinTemp`].
//! - **Heating failed** (`WATCH_TEMP_PERIOD` / `WATCH_TEMP_INCREASE`): after a target is set
//!   more than [`ProtectParams::watch_band_c`] above the reading, the reading must rise by
//!   [`ProtectParams::watch_increase_c`] within every [`ProtectParams::watch_period_ms`] until it
//!   is that close; otherwise [`ThermalFault::HeatingFailed`] (heater cartridge out of its block,
//!   a dead heater, a sensor fallen out).
//! - **Approach** (no Marlin equivalent: Marlin leaves this band unwatched): from the first
//!   reading of a first heat-up inside that band, the reading must reach the target within
//!   [`ProtectParams::approach_period_ms`]; otherwise [`ThermalFault::HeatingFailed`] too (a
//!   heater that stalls a few degrees short: too weak for the target, a failing cartridge, a fan
//!   on the block). This also covers a heater that dies after the heating watch handed over.
//! - **Thermal runaway** (`THERMAL_PROTECTION_PERIOD` / `HYSTERESIS`): once the reading has
//!   reached the target, it may stay more than [`ProtectParams::hysteresis_c`] below it for at
//!   most [`ProtectParams::period_ms`]; otherwise [`ThermalFault::ThermalRunaway`] (a heater that
//!   can no longer hold: loose cartridge, fan blowing on the block).
//!
//! Time is wrapping `u32` milliseconds, compared wrap-safely.

use super::{Heater, Temp, ThermalFault};

/// Margin of the max-temperature cutoff above the highest settable target, °C.
pub const MAXTEMP_MARGIN_C: i16 = 15;
/// Readings below this are a sensor fault, °C.
pub const MINTEMP_C: i16 = 5;
/// Marlin's `TEMP_HYSTERESIS`: the watch is only armed when the target is at least
/// `increase + WATCH_HYSTERESIS_C + 1` above the reading.
pub const WATCH_HYSTERESIS_C: i16 = 3;
/// How long the hotend's first heat-up may take from its first reading inside the watch band to its
/// target, ms.
///
/// Twice the slowest such last stretch of a normal heat-up, rounded up to the minute. The slowest
/// is 78.9 s on the stock Ender-3 model with the stock gains (`tests/thermal_stall.rs` heats to
/// every target from 170 °C to the machine's maximum in rooms at 15 to 35 °C, part fan off and at
/// full, and checks this derivation): the maximum in a 15 °C room with the fan at full, where the
/// cartridge has about 3 W to spare.
pub const HOTEND_APPROACH_MS: u32 = 180_000;
/// The same for the bed, ms.
///
/// Twice its slowest last stretch, rounded up to the minute. The slowest is 154.0 s (targets from
/// 40 °C to the machine's maximum in rooms at 15 to 35 °C): the maximum in a 15 °C room, where the
/// integral term has to build almost full duty.
pub const BED_APPROACH_MS: u32 = 360_000;

/// Thermal protection limits of one heater.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ProtectParams {
    /// How long the reading may stay below `target - hysteresis` once at target, ms.
    pub period_ms: u32,
    /// Allowed droop below the target while holding, °C.
    pub hysteresis_c: i16,
    /// Window in which a heating heater must gain `watch_increase_c`, ms.
    pub watch_period_ms: u32,
    /// Required rise per watch window while heating, °C.
    pub watch_increase_c: i16,
    /// Time from the first reading inside the watch band (first heat-up) to the target, ms.
    pub approach_period_ms: u32,
    /// Max-temperature cutoff, °C.
    pub max_c: i16,
    /// Min-temperature (sensor fault) cutoff, °C.
    pub min_c: i16,
}

impl ProtectParams {
    /// Marlin's hotend values (Ender-3 configuration): 40 s / 4 °C holding, 20 s / +2 °C
    /// heating; [`HOTEND_APPROACH_MS`] to the target; cutoff at `max_target_c + 15`.
    pub const fn hotend(max_target_c: i16) -> Self {
        Self {
            period_ms: 40_000,
            hysteresis_c: 4,
            watch_period_ms: 20_000,
            watch_increase_c: 2,
            approach_period_ms: HOTEND_APPROACH_MS,
            max_c: max_target_c.saturating_add(MAXTEMP_MARGIN_C),
            min_c: MINTEMP_C,
        }
    }

    /// Marlin's bed values: 20 s / 2 °C holding, 60 s / +2 °C heating; [`BED_APPROACH_MS`] to
    /// the target; cutoff at `max_target_c + 15`.
    pub const fn bed(max_target_c: i16) -> Self {
        Self {
            period_ms: 20_000,
            hysteresis_c: 2,
            watch_period_ms: 60_000,
            watch_increase_c: 2,
            approach_period_ms: BED_APPROACH_MS,
            max_c: max_target_c.saturating_add(MAXTEMP_MARGIN_C),
            min_c: MINTEMP_C,
        }
    }

    /// The watch band, °C: the heating watch is armed only when the target is more than this
    /// above the reading (`watch_increase_c + WATCH_HYSTERESIS_C + 1`); inside it the approach
    /// deadline applies.
    pub const fn watch_band_c(&self) -> i32 {
        self.watch_increase_c as i32 + WATCH_HYSTERESIS_C as i32 + 1
    }
}

/// Runaway state (Marlin's `TRState`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RunawayState {
    /// No target.
    Inactive,
    /// Target set, the reading not yet inside the watch band.
    FirstHeating,
    /// First heat-up inside the watch band: the target must be reached by the deadline.
    Approaching,
    /// Target reached: holding.
    Stable,
}

/// Wrap-safe `a` strictly before `b`.
const fn before(a: u32, b: u32) -> bool {
    (a.wrapping_sub(b) as i32) < 0
}

/// Protection state of one heater (16 bytes).
#[derive(Clone, Copy, Debug)]
pub struct Protection {
    state: RunawayState,
    watching: bool,
    /// Approaching: the reading must reach the target by then. Stable: it must be back within
    /// the hysteresis by then. Unused otherwise.
    deadline_ms: u32,
    /// When heating: the reading must have reached `watch_target` by then.
    watch_deadline_ms: u32,
    watch_target: Temp,
}

// The state stays 16 bytes a heater (the approach deadline shares the runaway deadline).
const _: () = assert!(core::mem::size_of::<Protection>() <= 16);

impl Default for Protection {
    fn default() -> Self {
        Self::new()
    }
}

impl Protection {
    /// Inactive protection (no target).
    pub const fn new() -> Self {
        Self {
            state: RunawayState::Inactive,
            watching: false,
            deadline_ms: 0,
            watch_deadline_ms: 0,
            watch_target: Temp::ZERO,
        }
    }

    /// The runaway state.
    pub fn state(&self) -> RunawayState {
        self.state
    }

    /// Whether the heating watch is armed.
    pub fn watching(&self) -> bool {
        self.watching
    }

    /// A new target: restarts the runaway state machine and (re)arms the heating watch (the
    /// approach deadline starts at the first check inside the band).
    pub fn set_target(&mut self, p: &ProtectParams, now_ms: u32, target_c: i16, temp: Temp) {
        self.state = if target_c > 0 { RunawayState::FirstHeating } else { RunawayState::Inactive };
        self.arm_watch(p, now_ms, target_c, temp);
    }

    /// The lowest reading inside the watch band of `target_c`.
    fn band_floor(p: &ProtectParams, target_c: i16) -> Temp {
        Temp::saturating_from_num(i32::from(target_c) - p.watch_band_c())
    }

    fn arm_watch(&mut self, p: &ProtectParams, now_ms: u32, target_c: i16, temp: Temp) {
        if target_c > 0 && temp < Self::band_floor(p, target_c) {
            self.watching = true;
            self.watch_target = temp.saturating_add(Temp::from_num(p.watch_increase_c));
            self.watch_deadline_ms = now_ms.wrapping_add(p.watch_period_ms);
        } else {
            self.watching = false;
        }
    }

    /// Checks one reading of `heater` against every limit.
    pub fn check(
        &mut self,
        p: &ProtectParams,
        heater: Heater,
        now_ms: u32,
        target_c: i16,
        temp: Temp,
    ) -> Result<(), ThermalFault> {
        if temp > Temp::from_num(p.max_c) {
            return Err(ThermalFault::MaxTemp(heater));
        }
        if temp < Temp::from_num(p.min_c) {
            return Err(ThermalFault::MinTemp(heater));
        }
        if self.watching && !before(now_ms, self.watch_deadline_ms) {
            if temp < self.watch_target {
                return Err(ThermalFault::HeatingFailed(heater));
            }
            self.arm_watch(p, now_ms, target_c, temp);
        }
        let target = Temp::from_num(target_c);
        let in_band = temp >= Self::band_floor(p, target_c) || temp >= target;
        if self.state == RunawayState::FirstHeating && in_band {
            self.state = RunawayState::Approaching;
            self.deadline_ms = now_ms.wrapping_add(p.approach_period_ms);
        }
        match self.state {
            RunawayState::Approaching if temp >= target => self.state = RunawayState::Stable,
            RunawayState::Approaching if !before(now_ms, self.deadline_ms) => {
                return Err(ThermalFault::HeatingFailed(heater));
            }
            _ => {}
        }
        if self.state == RunawayState::Stable {
            if temp >= target.saturating_sub(Temp::from_num(p.hysteresis_c)) {
                self.deadline_ms = now_ms.wrapping_add(p.period_ms);
            } else if !before(now_ms, self.deadline_ms) {
                return Err(ThermalFault::ThermalRunaway(heater));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn t(c: i32) -> Temp {
        Temp::from_num(c)
    }

    #[test]
    fn runaway_trips_after_the_period_below_the_hysteresis() {
        let p = ProtectParams::hotend(260);
        let mut pr = Protection::new();
        pr.set_target(&p, 0, 200, t(199));
        assert!(!pr.watching());
        assert_eq!(pr.check(&p, Heater::Hotend, 1000, 200, t(200)), Ok(()));
        assert_eq!(pr.state(), RunawayState::Stable);
        assert_eq!(pr.check(&p, Heater::Hotend, 2000, 200, t(195)), Ok(()));
        assert_eq!(pr.check(&p, Heater::Hotend, 40_999, 200, t(190)), Ok(()));
        assert_eq!(
            pr.check(&p, Heater::Hotend, 41_000, 200, t(190)),
            Err(ThermalFault::ThermalRunaway(Heater::Hotend))
        );
    }

    #[test]
    fn watch_requires_a_rise_per_period_and_rearms() {
        let p = ProtectParams::bed(100);
        let mut pr = Protection::new();
        pr.set_target(&p, 0, 60, t(25));
        assert!(pr.watching());
        assert_eq!(pr.check(&p, Heater::Bed, 60_000, 60, t(30)), Ok(()));
        assert!(pr.watching());
        assert_eq!(
            pr.check(&p, Heater::Bed, 120_000, 60, t(31)),
            Err(ThermalFault::HeatingFailed(Heater::Bed))
        );
    }

    #[test]
    fn approach_deadline_counts_from_the_first_reading_in_the_band() {
        let p = ProtectParams::hotend(260);
        let band = p.watch_band_c();
        let start = u32::MAX - 100_000;
        let at = |ms: u32| start.wrapping_add(ms);
        let mut pr = Protection::new();
        pr.set_target(&p, at(0), 200, t(25));
        // Below the band: the heating watch, no deadline yet.
        assert_eq!(pr.check(&p, Heater::Hotend, at(15_000), 200, t(200 - band - 1)), Ok(()));
        assert_eq!(pr.state(), RunawayState::FirstHeating);
        // First reading inside the band at 16 s: the target is due by 16 s + the period.
        assert_eq!(pr.check(&p, Heater::Hotend, at(16_000), 200, t(200 - band)), Ok(()));
        assert_eq!(pr.state(), RunawayState::Approaching);
        assert_eq!(pr.check(&p, Heater::Hotend, at(20_000), 200, t(197)), Ok(()));
        assert!(!pr.watching());
        let due = 16_000 + p.approach_period_ms;
        assert_eq!(pr.check(&p, Heater::Hotend, at(due - 1), 200, t(197)), Ok(()));
        assert_eq!(
            pr.check(&p, Heater::Hotend, at(due), 200, t(197)),
            Err(ThermalFault::HeatingFailed(Heater::Hotend))
        );
        // Reaching the target in time ends the approach: holding from then on.
        let mut pr = Protection::new();
        pr.set_target(&p, at(0), 200, t(197));
        assert_eq!(pr.check(&p, Heater::Hotend, at(100), 200, t(197)), Ok(()));
        assert_eq!(pr.check(&p, Heater::Hotend, at(due), 200, t(200)), Ok(()));
        assert_eq!(pr.state(), RunawayState::Stable);
        assert_eq!(pr.check(&p, Heater::Hotend, at(due + 10 * p.period_ms), 200, t(199)), Ok(()));
    }

    #[test]
    fn a_heater_that_leaves_the_band_downwards_still_trips_at_the_approach_deadline() {
        // The watch disarmed inside the band; then the heater dies and the reading falls.
        let p = ProtectParams::bed(100);
        let mut pr = Protection::new();
        pr.set_target(&p, 0, 60, t(50));
        assert_eq!(pr.check(&p, Heater::Bed, 1000, 60, t(55)), Ok(()));
        assert_eq!(pr.check(&p, Heater::Bed, 60_000, 60, t(56)), Ok(()));
        assert!(!pr.watching());
        let due = 1000 + p.approach_period_ms;
        assert_eq!(pr.check(&p, Heater::Bed, due - 1, 60, t(30)), Ok(()));
        assert_eq!(
            pr.check(&p, Heater::Bed, due, 60, t(30)),
            Err(ThermalFault::HeatingFailed(Heater::Bed))
        );
    }

    #[test]
    fn a_new_target_restarts_the_approach() {
        let p = ProtectParams::hotend(260);
        let mut pr = Protection::new();
        pr.set_target(&p, 0, 200, t(196));
        assert_eq!(pr.check(&p, Heater::Hotend, 100, 200, t(196)), Ok(()));
        let later = p.approach_period_ms - 100;
        pr.set_target(&p, later, 198, t(196));
        assert_eq!(pr.state(), RunawayState::FirstHeating);
        assert_eq!(pr.check(&p, Heater::Hotend, later + 100, 198, t(196)), Ok(()));
        assert_eq!(pr.check(&p, Heater::Hotend, later + p.approach_period_ms, 198, t(196)), Ok(()));
        assert!(pr
            .check(&p, Heater::Hotend, later + 100 + p.approach_period_ms, 198, t(196))
            .is_err());
        // Off: nothing is due.
        pr.set_target(&p, 0, 0, t(196));
        assert_eq!(pr.check(&p, Heater::Hotend, u32::MAX / 2, 0, t(30)), Ok(()));
    }

    #[test]
    fn limits_and_wrapping_time() {
        let p = ProtectParams::hotend(260);
        let mut pr = Protection::new();
        assert_eq!(
            pr.check(&p, Heater::Hotend, 0, 0, t(276)),
            Err(ThermalFault::MaxTemp(Heater::Hotend))
        );
        assert_eq!(
            pr.check(&p, Heater::Hotend, 0, 0, t(4)),
            Err(ThermalFault::MinTemp(Heater::Hotend))
        );
        let start = u32::MAX - 5_000;
        pr.set_target(&p, start, 200, t(25));
        assert_eq!(pr.check(&p, Heater::Hotend, start.wrapping_add(19_999), 200, t(26)), Ok(()));
        assert_eq!(
            pr.check(&p, Heater::Hotend, start.wrapping_add(20_000), 200, t(26)),
            Err(ThermalFault::HeatingFailed(Heater::Hotend))
        );
    }

    #[test]
    fn arbitrary_inputs_never_panic() {
        let mut next = crate::test_rng::xorshift(0x2545_f491_4f6c_dd1d);
        let mut pr = Protection::new();
        for _ in 0..50_000 {
            let p = ProtectParams {
                period_ms: next() as u32,
                hysteresis_c: next() as i16,
                watch_period_ms: next() as u32,
                watch_increase_c: next() as i16,
                approach_period_ms: next() as u32,
                max_c: next() as i16,
                min_c: next() as i16,
            };
            let (now, target, temp) =
                (next() as u32, next() as i16, Temp::from_bits(next() as i32));
            if next() % 4 == 0 {
                pr.set_target(&p, now, target, temp);
            }
            let _ = pr.check(&p, Heater::Bed, now, target, temp);
        }
    }
}
