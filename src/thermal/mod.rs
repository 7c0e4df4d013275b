//! Heaters, temperature control and thermal safety.
//!
//! One module per concern:
//! - [`thermistor`]: oversampled ADC sums to temperature (EPCOS 100k table), IIR filter,
//!   open/short detection;
//! - [`pid`]: fixed-point PID with anti-windup, derivative on measurement, 8-bit PWM output;
//! - [`protect`]: Marlin-like protection per heater (max/min temperature, heating watch,
//!   runaway while holding);
//! - [`watchdog`]: the main-loop deadline the firmware's heater interrupt checks.
//!
//! [`ThermalController`] ties them together for the hotend and the bed plus the part-cooling
//! fan: the firmware calls [`ThermalController::update`] about ten times a second with the time
//! and the two oversampled ADC sums and writes the returned [`Outputs`] to the PWM pins
//! (hotend PA1, bed PA2, fan PA0). Any [`ThermalFault`] is latched: from the update that detects
//! it on, every output is zero and the fault is reported by name until [`ThermalController::reset`]
//! (in practice a reboot). Stopping motion on a fault is the caller's job. `update` is integer
//! only (`I16F16` and `u32`), time is always an argument.
//!
//! What the caller does around it (the firmware and the job runner):
//! - sample PC5/PC4 and pass 16-conversion sums ([`thermistor::Oversampler`]) only once real
//!   conversions exist (a zero sum is a shorted sensor);
//! - drive PA1/PA2/PA0 with the duties, kick a [`Watchdog`] after each update and have the PWM
//!   interrupt force the heater pins low (and stop feeding the IWDG) once it has expired;
//! - before the first layer, [`ThermalController::apply_settings`] then wait for
//!   [`ThermalController::at_target`] (inside [`HeaterConfig::window_c`] for
//!   [`HeaterConfig::residency_ms`], like M190/M109). A heater that stalls short of its target
//!   trips [`ThermalFault::HeatingFailed`]: more than [`ProtectParams::watch_band_c`] below it
//!   through the heating watch, inside that band (where Marlin watches nothing) through the
//!   approach deadline [`ProtectParams::approach_period_ms`]. The job's own wait limit,
//!   [`HEAT_WAIT_LIMIT_MS`] ([`ThermalFault::HeatingTimeout`]), stays as the last line of
//!   defence (a heater that reaches its target but never settles inside the window);
//!   [`ThermalController::all_off`] at the end, on abort and on emergency stop; on a fault,
//!   stop motion and report [`ThermalFault::name`]; status reports carry
//!   [`ThermalController::status`].

pub mod pid;
pub mod protect;
pub mod thermistor;
pub mod watchdog;

use core::fmt;

use crate::machine::{MachineConfig, PrintSettings};
pub use pid::{Pid, PidGains};
pub use protect::{ProtectParams, Protection};
pub use thermistor::SensorError;
pub use watchdog::Watchdog;

/// A temperature in °C, signed 16.16 fixed point.
pub type Temp = fixed::types::I16F16;

/// Which heater.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Heater {
    /// The hotend (thermistor PC5, heater PA1).
    Hotend,
    /// The bed (thermistor PC4, heater PA2).
    Bed,
}

impl Heater {
    /// Lower-case name.
    pub const fn name(self) -> &'static str {
        match self {
            Self::Hotend => "hotend",
            Self::Bed => "bed",
        }
    }
}

/// A thermal fault: every heater goes off and motion must stop.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ThermalFault {
    /// Thermistor reads full scale: unplugged or broken.
    SensorOpen(Heater),
    /// Thermistor reads near zero: shorted.
    SensorShorted(Heater),
    /// Reading below the min-temperature cutoff (sensor fault).
    MinTemp(Heater),
    /// Reading above the max-temperature cutoff (heater stuck on or runaway).
    MaxTemp(Heater),
    /// While heating, the temperature did not rise enough within the watch period, or did not
    /// reach the target within the approach period once close to it.
    HeatingFailed(Heater),
    /// While holding, the temperature stayed too far below the target for too long.
    ThermalRunaway(Heater),
    /// The main loop stopped kicking the watchdog.
    Watchdog,
    /// A job waited longer than [`HEAT_WAIT_LIMIT_MS`] for its heaters to reach their targets
    /// and settle (the last line of defence behind each heater's own checks).
    HeatingTimeout,
}

/// The longest a job waits for its heaters before the first layer, ms (20 minutes).
///
/// A stock Ender-3 heats its bed to 60 C and its hotend to 200 C in about 3, but a 100 C bed in
/// a 15 C room takes about 9 in the stock model, more with a glass plate; each heater's own
/// checks catch a stall long before this.
pub const HEAT_WAIT_LIMIT_MS: u32 = 1_200_000;

impl ThermalFault {
    /// The fault's name in Marlin's words (`"MAXTEMP"`, `"THERMAL RUNAWAY"`, ...).
    pub const fn name(self) -> &'static str {
        match self {
            Self::SensorOpen(_) => "SENSOR OPEN",
            Self::SensorShorted(_) => "SENSOR SHORTED",
            Self::MinTemp(_) => "MINTEMP",
            Self::MaxTemp(_) => "MAXTEMP",
            Self::HeatingFailed(_) => "HEATING FAILED",
            Self::ThermalRunaway(_) => "THERMAL RUNAWAY",
            Self::Watchdog => "WATCHDOG",
            Self::HeatingTimeout => "HEATING TIMEOUT",
        }
    }

    /// The fault on the wire (the detail of `ErrorCode::Thermal`): kind * 2 + heater (hotend
    /// 0, bed 1); the watchdog is 12, the heating timeout 13.
    pub const fn code(self) -> u8 {
        let (kind, heater) = match self {
            Self::SensorOpen(h) => (0, h),
            Self::SensorShorted(h) => (1, h),
            Self::MinTemp(h) => (2, h),
            Self::MaxTemp(h) => (3, h),
            Self::HeatingFailed(h) => (4, h),
            Self::ThermalRunaway(h) => (5, h),
            Self::Watchdog => return 12,
            Self::HeatingTimeout => return 13,
        };
        kind * 2 + matches!(heater, Heater::Bed) as u8
    }

    /// The fault of a [`ThermalFault::code`].
    pub const fn from_code(code: u8) -> Option<Self> {
        let h = if code % 2 == 0 { Heater::Hotend } else { Heater::Bed };
        Some(match code / 2 {
            _ if code == 12 => Self::Watchdog,
            _ if code == 13 => Self::HeatingTimeout,
            0 => Self::SensorOpen(h),
            1 => Self::SensorShorted(h),
            2 => Self::MinTemp(h),
            3 => Self::MaxTemp(h),
            4 => Self::HeatingFailed(h),
            5 => Self::ThermalRunaway(h),
            _ => return None,
        })
    }

    /// The heater concerned (none for the watchdog).
    pub const fn heater(self) -> Option<Heater> {
        match self {
            Self::SensorOpen(h)
            | Self::SensorShorted(h)
            | Self::MinTemp(h)
            | Self::MaxTemp(h)
            | Self::HeatingFailed(h)
            | Self::ThermalRunaway(h) => Some(h),
            Self::Watchdog | Self::HeatingTimeout => None,
        }
    }
}

impl fmt::Display for ThermalFault {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.heater() {
            Some(h) => write!(f, "{}: {}", self.name(), h.name()),
            None => f.write_str(self.name()),
        }
    }
}

/// A refused request.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ThermalError {
    /// Target outside `0..=max` for that heater.
    TargetOutOfRange {
        /// The heater.
        heater: Heater,
        /// The requested target, °C.
        temp_c: i16,
        /// The highest allowed target, °C.
        max_c: i16,
    },
    /// A fault is latched: no heater may be turned on.
    Faulted(ThermalFault),
}

impl fmt::Display for ThermalError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::TargetOutOfRange { heater, temp_c, max_c } => {
                write!(f, "{} target {temp_c} C is outside 0..={max_c} C", heater.name())
            }
            Self::Faulted(fault) => write!(f, "thermal fault latched: {fault}"),
        }
    }
}

/// Configuration of one heater.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct HeaterConfig {
    /// PID gains.
    pub gains: PidGains,
    /// Protection limits.
    pub protect: ProtectParams,
    /// Highest settable target, °C (the machine's max).
    pub max_target_c: i16,
    /// [`ThermalController::at_target`] window: `|T - target|` at most this, °C (Marlin's
    /// `TEMP_WINDOW`).
    pub window_c: i16,
    /// Leaving the window by more than this restarts the residency, °C (`TEMP_HYSTERESIS`).
    pub residency_hysteresis_c: i16,
    /// Time inside the window before the heater counts as at target, ms
    /// (`TEMP_RESIDENCY_TIME`).
    pub residency_ms: u32,
}

/// Configuration of both heaters.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ThermalConfig {
    /// The hotend.
    pub hotend: HeaterConfig,
    /// The bed.
    pub bed: HeaterConfig,
}

impl ThermalConfig {
    /// Defaults for a machine: its max temperatures (cutoffs 15 °C above), default gains,
    /// Marlin's protection periods, a 1 °C window held for 10 s (hotend) and 10 s (bed).
    pub const fn for_machine(m: &MachineConfig) -> Self {
        Self {
            hotend: HeaterConfig {
                gains: PidGains::HOTEND,
                protect: ProtectParams::hotend(m.max_hotend_temp_c),
                max_target_c: m.max_hotend_temp_c,
                window_c: 1,
                residency_hysteresis_c: 3,
                residency_ms: 10_000,
            },
            bed: HeaterConfig {
                gains: PidGains::BED,
                protect: ProtectParams::bed(m.max_bed_temp_c),
                max_target_c: m.max_bed_temp_c,
                window_c: 1,
                residency_hysteresis_c: 3,
                residency_ms: 10_000,
            },
        }
    }
}

/// What to write to the pins after an update.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Outputs {
    /// Hotend heater duty (PA1), 0..=255.
    pub hotend_pwm: u8,
    /// Bed heater duty (PA2), 0..=255.
    pub bed_pwm: u8,
    /// Part-cooling fan duty (PA0), 0..=255.
    pub fan_pwm: u8,
    /// The latched fault, if any (then every duty is zero).
    pub fault: Option<ThermalFault>,
}

impl Outputs {
    const OFF: Self = Self { hotend_pwm: 0, bed_pwm: 0, fan_pwm: 0, fault: None };
}

/// One heater as a status report shows it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct HeaterStatus {
    /// Filtered reading, °C (zero before the first valid reading).
    pub temp: Temp,
    /// Target, °C (0 = off).
    pub target_c: i16,
    /// Current duty.
    pub pwm: u8,
}

impl HeaterStatus {
    /// The reading in tenths of a degree, rounded.
    pub fn temp_decidegrees(&self) -> i16 {
        self.temp.saturating_mul_int(10).round().saturating_to_num::<i16>()
    }
}

/// Everything a status report needs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ThermalStatus {
    /// The hotend.
    pub hotend: HeaterStatus,
    /// The bed.
    pub bed: HeaterStatus,
    /// Part-cooling fan duty.
    pub fan_pwm: u8,
    /// The latched fault, if any.
    pub fault: Option<ThermalFault>,
}

/// Run-time state of one heater.
#[derive(Clone, Copy, Debug)]
struct Channel {
    filter: thermistor::SensorFilter,
    temp: Temp,
    target_c: i16,
    pwm: u8,
    valid: bool,
    resident: bool,
    resident_since_ms: u32,
    pid: Pid,
    protect: Protection,
}

impl Channel {
    const fn new() -> Self {
        Self {
            filter: thermistor::SensorFilter::new(),
            temp: Temp::ZERO,
            target_c: 0,
            pwm: 0,
            valid: false,
            resident: false,
            resident_since_ms: 0,
            pid: Pid::new(),
            protect: Protection::new(),
        }
    }

    fn status(&self) -> HeaterStatus {
        HeaterStatus { temp: self.temp, target_c: self.target_c, pwm: self.pwm }
    }

    fn set_target(&mut self, cfg: &HeaterConfig, now_ms: u32, target_c: i16) {
        if target_c != self.target_c {
            self.target_c = target_c;
            self.resident = false;
            self.protect.set_target(&cfg.protect, now_ms, target_c, self.temp);
        }
    }

    /// Reads, checks and controls; the duty or the fault.
    fn update(
        &mut self,
        cfg: &HeaterConfig,
        heater: Heater,
        now_ms: u32,
        dt_ms: u32,
        sum: u16,
    ) -> Result<u8, ThermalFault> {
        // The raw sum, unfiltered, decides open/short: a fault is seen in the same update.
        thermistor::check_sum(sum).map_err(|e| match e {
            SensorError::Open => ThermalFault::SensorOpen(heater),
            SensorError::Shorted => ThermalFault::SensorShorted(heater),
        })?;
        let filtered = self.filter.filter(sum);
        self.temp = thermistor::sum_to_temp(filtered).map_err(|e| match e {
            SensorError::Open => ThermalFault::SensorOpen(heater),
            SensorError::Shorted => ThermalFault::SensorShorted(heater),
        })?;
        if !self.valid {
            self.valid = true;
            // A target set before the first reading arms the watch from this reading.
            self.protect.set_target(&cfg.protect, now_ms, self.target_c, self.temp);
        }
        self.protect.check(&cfg.protect, heater, now_ms, self.target_c, self.temp)?;

        let off = self.temp.saturating_sub(Temp::from_num(self.target_c)).saturating_abs();
        if self.target_c > 0 && off <= Temp::from_num(cfg.window_c) {
            if !self.resident {
                self.resident = true;
                self.resident_since_ms = now_ms;
            }
        } else if off > Temp::from_num(cfg.residency_hysteresis_c) || self.target_c <= 0 {
            self.resident = false;
        }

        self.pwm = self.pid.update(&cfg.gains, Temp::from_num(self.target_c), self.temp, dt_ms);
        Ok(self.pwm)
    }

    fn at_target(&self, cfg: &HeaterConfig, now_ms: u32) -> bool {
        self.target_c <= 0
            || (self.resident && now_ms.wrapping_sub(self.resident_since_ms) >= cfg.residency_ms)
    }
}

/// Temperature control and thermal protection of the hotend, the bed and the part fan.
#[derive(Clone, Copy, Debug)]
pub struct ThermalController {
    cfg: ThermalConfig,
    hotend: Channel,
    bed: Channel,
    fan_pwm: u8,
    fault: Option<ThermalFault>,
    last_ms: u32,
    started: bool,
}

impl ThermalController {
    /// A controller with every heater off.
    pub const fn new(cfg: ThermalConfig) -> Self {
        Self {
            cfg,
            hotend: Channel::new(),
            bed: Channel::new(),
            fan_pwm: 0,
            fault: None,
            last_ms: 0,
            started: false,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &ThermalConfig {
        &self.cfg
    }

    /// Sets one heater's target (0 = off), checked against the machine's maximum.
    pub fn set_target(
        &mut self,
        heater: Heater,
        now_ms: u32,
        temp_c: i16,
    ) -> Result<(), ThermalError> {
        if let Some(fault) = self.fault {
            if temp_c != 0 {
                return Err(ThermalError::Faulted(fault));
            }
        }
        let (cfg, ch) = match heater {
            Heater::Hotend => (&self.cfg.hotend, &mut self.hotend),
            Heater::Bed => (&self.cfg.bed, &mut self.bed),
        };
        if !(0..=cfg.max_target_c).contains(&temp_c) {
            return Err(ThermalError::TargetOutOfRange { heater, temp_c, max_c: cfg.max_target_c });
        }
        ch.set_target(cfg, now_ms, temp_c);
        Ok(())
    }

    /// Sets both targets; neither changes if either is refused.
    pub fn set_targets(
        &mut self,
        now_ms: u32,
        hotend_c: i16,
        bed_c: i16,
    ) -> Result<(), ThermalError> {
        let (h, b) = (self.hotend.target_c, self.bed.target_c);
        let result = self
            .set_target(Heater::Hotend, now_ms, hotend_c)
            .and_then(|()| self.set_target(Heater::Bed, now_ms, bed_c));
        if result.is_err() {
            // Restore (always allowed: the old values were accepted before).
            let cfg = self.cfg;
            self.hotend.set_target(&cfg.hotend, now_ms, h);
            self.bed.set_target(&cfg.bed, now_ms, b);
        }
        result
    }

    /// Sets both targets from the print settings (200/60 °C by default).
    pub fn apply_settings(&mut self, now_ms: u32, s: &PrintSettings) -> Result<(), ThermalError> {
        self.set_targets(now_ms, s.hotend_temp_c, s.bed_temp_c)
    }

    /// Sets the part-cooling fan duty (0..=255); ignored while a fault is latched.
    pub fn set_fan(&mut self, duty: u8) {
        if self.fault.is_none() {
            self.fan_pwm = duty;
        }
    }

    /// Heaters and fan off (end of job, abort, emergency stop). A latched fault stays.
    pub fn all_off(&mut self) {
        let Self { cfg, hotend, bed, last_ms, .. } = self;
        hotend.set_target(&cfg.hotend, *last_ms, 0);
        bed.set_target(&cfg.bed, *last_ms, 0);
        self.hotend.pwm = 0;
        self.bed.pwm = 0;
        self.fan_pwm = 0;
    }

    /// Latches `fault` (e.g. [`ThermalFault::Watchdog`], or one found elsewhere): everything off.
    pub fn trip(&mut self, fault: ThermalFault) {
        self.all_off();
        if self.fault.is_none() {
            self.fault = Some(fault);
        }
    }

    /// The latched fault.
    pub fn fault(&self) -> Option<ThermalFault> {
        self.fault
    }

    /// Clears a latched fault and every heater's history (heaters stay off).
    pub fn reset(&mut self) {
        *self = Self::new(self.cfg);
    }

    /// One control step at `now_ms` with the oversampled ADC sums (16 conversions each, see
    /// [`thermistor`]) of the hotend and bed thermistors. Call at a steady rate (about 10 Hz)
    /// and only with real conversions.
    pub fn update(&mut self, now_ms: u32, adc_hotend: u16, adc_bed: u16) -> Outputs {
        if let Some(fault) = self.fault {
            return Outputs { fault: Some(fault), ..Outputs::OFF };
        }
        let dt_ms = if self.started { now_ms.wrapping_sub(self.last_ms) } else { 0 };
        self.started = true;
        self.last_ms = now_ms;
        let Self { cfg, hotend, bed, .. } = self;
        let result =
            hotend.update(&cfg.hotend, Heater::Hotend, now_ms, dt_ms, adc_hotend).and_then(|h| {
                bed.update(&cfg.bed, Heater::Bed, now_ms, dt_ms, adc_bed).map(|b| (h, b))
            });
        match result {
            Ok((hotend_pwm, bed_pwm)) => {
                Outputs { hotend_pwm, bed_pwm, fan_pwm: self.fan_pwm, fault: None }
            }
            Err(fault) => {
                self.trip(fault);
                Outputs { fault: Some(fault), ..Outputs::OFF }
            }
        }
    }

    /// Whether every heater with a target has been within its window for its residency time
    /// (the job's wait before the first layer, like M190 then M109). Heaters that are off count
    /// as at target; a latched fault never is.
    pub fn at_target(&self) -> bool {
        self.fault.is_none()
            && self.hotend.at_target(&self.cfg.hotend, self.last_ms)
            && self.bed.at_target(&self.cfg.bed, self.last_ms)
    }

    /// Whether one heater is at target (see [`Self::at_target`]).
    pub fn heater_at_target(&self, heater: Heater) -> bool {
        self.fault.is_none()
            && match heater {
                Heater::Hotend => self.hotend.at_target(&self.cfg.hotend, self.last_ms),
                Heater::Bed => self.bed.at_target(&self.cfg.bed, self.last_ms),
            }
    }

    /// Temperatures, targets, duties and fault for a status report.
    pub fn status(&self) -> ThermalStatus {
        ThermalStatus {
            hotend: self.hotend.status(),
            bed: self.bed.status(),
            fan_pwm: self.fan_pwm,
            fault: self.fault,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ctl() -> ThermalController {
        ThermalController::new(ThermalConfig::for_machine(&MachineConfig::default()))
    }

    #[test]
    fn ram_size_is_small() {
        // Per heater: 16 B of protection state (asserted in `protect`) and 20 B of limits.
        assert!(core::mem::size_of::<ProtectParams>() <= 20);
        let size = core::mem::size_of::<ThermalController>();
        assert!(size <= 208, "ThermalController is {size} bytes");
        assert!(core::mem::size_of::<Watchdog>() <= 8);
    }

    #[test]
    fn targets_are_checked_against_the_machine() {
        let mut c = ctl();
        assert_eq!(
            c.set_targets(0, 270, 60),
            Err(ThermalError::TargetOutOfRange { heater: Heater::Hotend, temp_c: 270, max_c: 260 })
        );
        assert_eq!(c.status().bed.target_c, 0);
        assert!(c.set_targets(0, 200, 101).is_err());
        assert_eq!((c.status().hotend.target_c, c.status().bed.target_c), (0, 0));
        assert!(c.apply_settings(0, &PrintSettings::default()).is_ok());
        assert_eq!((c.status().hotend.target_c, c.status().bed.target_c), (200, 60));
    }

    #[test]
    fn faults_latch_and_refuse_heating() {
        let mut c = ctl();
        c.set_targets(0, 200, 60).unwrap();
        c.set_fan(255);
        let out = c.update(100, thermistor::SUM_MAX, 40_000);
        assert_eq!(
            out,
            Outputs { fault: Some(ThermalFault::SensorOpen(Heater::Hotend)), ..Outputs::OFF }
        );
        assert_eq!(
            c.update(200, 20_000, 40_000).fault,
            Some(ThermalFault::SensorOpen(Heater::Hotend))
        );
        assert_eq!(
            c.set_target(Heater::Bed, 300, 60),
            Err(ThermalError::Faulted(ThermalFault::SensorOpen(Heater::Hotend)))
        );
        assert_eq!(ThermalFault::SensorOpen(Heater::Hotend).name(), "SENSOR OPEN");
        c.reset();
        assert_eq!(c.fault(), None);
    }

    #[test]
    fn arbitrary_readings_and_times_never_panic() {
        let mut c = ctl();
        let mut next = crate::test_rng::xorshift(0x1234_5678_9abc_def0);
        for round in 0..200 {
            c.reset();
            let _ = c.set_targets(0, (next() % 300) as i16, (next() % 120) as i16);
            let mut now = (next() as u32).wrapping_sub(1000);
            for _ in 0..200 {
                now =
                    now.wrapping_add((next() % if round % 2 == 0 { 300 } else { 100_000 }) as u32);
                let (h, b) = (next() as u16, next() as u16);
                let out = c.update(now, h, b);
                if out.fault.is_some() {
                    assert_eq!((out.hotend_pwm, out.bed_pwm, out.fan_pwm), (0, 0, 0));
                }
                let _ = c.at_target();
                let _ = c.status().hotend.temp_decidegrees();
            }
        }
    }

    #[test]
    fn watchdog_deadline() {
        let mut w = Watchdog::new(u32::MAX - 100, 2000);
        assert!(!w.expired(1000));
        assert_eq!(w.check(1900), Err(ThermalFault::Watchdog));
        w.kick(1900);
        assert!(w.check(3900).is_ok());
        assert!(w.expired(3901));
    }
}
