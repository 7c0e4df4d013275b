//! Marlin-like thermal protection, one state machine per heater.
//!
//! - **Max temperature**: a reading above [`ProtectParams::max_c`] (the machine's highest
//!   settable target plus [`MAXTEMP_MARGIN_C`], like Marlin's `HEATER_MAXTEMP` over
//!   `HOTEND_OVERSHOOT`) trips [`ThermalFault::MaxTemp`]: a heater stuck on, whatever the target.
//! - **Min temperature**: a reading below [`ProtectParams::min_c`] (5 °C, Marlin's
//!   `HEATER_MINTEMP`) means a sensor that is not reading the heater: [`ThermalFault::MinTemp`].
//! - **Heating failed** (`WATCH_TEMP_PERIOD` / `WATCH_TEMP_INCREASE`): after a target is set
//!   more than `increase + 4` °C above the reading, the reading must rise by
//!   [`ProtectParams::watch_increase_c`] within every [`ProtectParams::watch_period_ms`] until it
//!   is that close; otherwise [`ThermalFault::HeatingFailed`] (heater cartridge out of its block,
//!   a dead heater, a sensor fallen out).
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
    /// Max-temperature cutoff, °C.
    pub max_c: i16,
    /// Min-temperature (sensor fault) cutoff, °C.
    pub min_c: i16,
}

impl ProtectParams {
    /// Marlin's hotend values (Ender-3 configuration): 40 s / 4 °C holding, 20 s / +2 °C
    /// heating; cutoff at `max_target_c + 15`.
    pub const fn hotend(max_target_c: i16) -> Self {
        Self {
            period_ms: 40_000,
            hysteresis_c: 4,
            watch_period_ms: 20_000,
            watch_increase_c: 2,
            max_c: max_target_c.saturating_add(MAXTEMP_MARGIN_C),
            min_c: MINTEMP_C,
        }
    }

    /// Marlin's bed values: 20 s / 2 °C holding, 60 s / +2 °C heating; cutoff at
    /// `max_target_c + 15`.
    pub const fn bed(max_target_c: i16) -> Self {
        Self {
            period_ms: 20_000,
            hysteresis_c: 2,
            watch_period_ms: 60_000,
            watch_increase_c: 2,
            max_c: max_target_c.saturating_add(MAXTEMP_MARGIN_C),
            min_c: MINTEMP_C,
        }
    }
}

/// Runaway state (Marlin's `TRState`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RunawayState {
    /// No target.
    Inactive,
    /// Target set, not yet reached.
    FirstHeating,
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
    /// When holding: the reading must be back within the hysteresis by then.
    runaway_deadline_ms: u32,
    /// When heating: the reading must have reached `watch_target` by then.
    watch_deadline_ms: u32,
    watch_target: Temp,
}

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
            runaway_deadline_ms: 0,
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

    /// A new target: restarts the runaway state machine and (re)arms the heating watch.
    pub fn set_target(&mut self, p: &ProtectParams, now_ms: u32, target_c: i16, temp: Temp) {
        self.state = if target_c > 0 { RunawayState::FirstHeating } else { RunawayState::Inactive };
        self.runaway_deadline_ms = now_ms.wrapping_add(p.period_ms);
        self.arm_watch(p, now_ms, target_c, temp);
    }

    fn arm_watch(&mut self, p: &ProtectParams, now_ms: u32, target_c: i16, temp: Temp) {
        let band = i32::from(p.watch_increase_c) + i32::from(WATCH_HYSTERESIS_C) + 1;
        let far = Temp::saturating_from_num(i32::from(target_c) - band);
        if target_c > 0 && temp < far {
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
        if self.state == RunawayState::FirstHeating && temp >= target {
            self.state = RunawayState::Stable;
        }
        if self.state == RunawayState::Stable {
            if temp >= target.saturating_sub(Temp::from_num(p.hysteresis_c)) {
                self.runaway_deadline_ms = now_ms.wrapping_add(p.period_ms);
            } else if !before(now_ms, self.runaway_deadline_ms) {
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
