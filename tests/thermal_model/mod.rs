//! An independent f64 thermal model of the Ender-3 hotend and bed, used to drive the
//! `strata::thermal` controller in the `thermal_*` tests.
//!
//! Each heater is first order: `C dT/dt = P * duty - k (T - T_amb) - k_fan * fan * (T - T_amb)`
//! for the block temperature `T`; the thermistor follows it with a first-order lag
//! (`tau dTs/dt = T - Ts`). ADC readings are computed from `Ts` through the beta equation
//! (EPCOS 100k, B 4092, 4.7 kΩ pull-up, 12-bit) here, independently of the firmware table, plus
//! seeded uniform noise on each of the 16 conversions that make a reading.
//!
//! Numbers (stock Ender-3): hotend 40 W cartridge, 25 J/K, 0.12 W/K loss (a 1.6 °C/s initial
//! rise, 358 °C at full power), 3 s sensor lag, part fan at 100 % adds 0.03 W/K; bed 220 W,
//! 550 J/K, 2 W/K (0.4 °C/s initial rise, 135 °C at full power), 4 s sensor lag; both in a
//! room at [`AMBIENT`] unless [`HeaterModel::in_room`] puts them elsewhere.
#![allow(dead_code)]

use strata::machine::MachineConfig;
use strata::thermal::{Outputs, ThermalConfig, ThermalController, ThermalFault};
use strata_testkit::rng::Rng;

/// Default ambient temperature, °C.
pub const AMBIENT: f64 = 25.0;
/// Simulation and control step, ms.
pub const STEP_MS: u32 = 100;

/// Expected 12-bit reading (fractional) of the thermistor at `t` °C.
pub fn adc_of_temp(t: f64) -> f64 {
    let r = 100e3 * (4092.0 * (1.0 / (t + 273.15) - 1.0 / 298.15)).exp();
    4096.0 * r / (r + 4700.0)
}

/// Temperature (°C) of a 16-conversion sum by the beta equation.
pub fn temp_of_sum(sum: f64) -> f64 {
    let r = 4700.0 * sum / (65536.0 - sum);
    1.0 / (1.0 / 298.15 + (r / 100e3).ln() / 4092.0) - 273.15
}

/// One heater.
#[derive(Clone, Copy, Debug)]
pub struct HeaterModel {
    /// Heat capacity, J/K.
    pub capacity: f64,
    /// Heater power at full duty, W.
    pub power: f64,
    /// Loss to ambient, W/K.
    pub loss: f64,
    /// Extra loss with the fan at 100 %, W/K.
    pub fan_loss: f64,
    /// Sensor lag time constant, s.
    pub sensor_tau: f64,
    /// Block temperature, °C.
    pub block: f64,
    /// Sensor temperature, °C.
    pub sensor: f64,
    /// Ambient temperature, °C.
    pub ambient: f64,
    /// Fraction of the power that reaches the block (1 normal, ~0 for a loose cartridge).
    pub power_scale: f64,
    /// Heater forced fully on whatever the duty (a stuck MOSFET).
    pub stuck_on: bool,
    /// Sensor disconnected (reads full scale) or shorted (reads zero).
    pub open: bool,
    /// Sensor shorted.
    pub shorted: bool,
}

impl HeaterModel {
    /// The stock hotend at ambient.
    pub fn hotend() -> Self {
        Self {
            capacity: 25.0,
            power: 40.0,
            loss: 0.12,
            fan_loss: 0.03,
            sensor_tau: 3.0,
            block: AMBIENT,
            sensor: AMBIENT,
            ambient: AMBIENT,
            power_scale: 1.0,
            stuck_on: false,
            open: false,
            shorted: false,
        }
    }

    /// The stock bed at ambient.
    pub fn bed() -> Self {
        Self {
            capacity: 550.0,
            power: 220.0,
            loss: 2.0,
            fan_loss: 0.0,
            sensor_tau: 4.0,
            ..Self::hotend()
        }
    }

    /// The same heater in a room at `t` °C, at room temperature.
    pub fn in_room(self, t: f64) -> Self {
        Self { ambient: t, block: t, sensor: t, ..self }
    }

    /// Advances `dt` seconds at `duty` (0..=1) with the fan at `fan` (0..=1).
    pub fn step(&mut self, dt: f64, duty: f64, fan: f64) {
        let duty = if self.stuck_on { 1.0 } else { duty };
        // Substeps keep Euler accurate.
        let n = 4;
        let h = dt / f64::from(n);
        for _ in 0..n {
            let p = self.power * self.power_scale * duty;
            let loss = (self.loss + self.fan_loss * fan) * (self.block - self.ambient);
            self.block += h * (p - loss) / self.capacity;
            self.sensor += h * (self.block - self.sensor) / self.sensor_tau;
        }
    }
}

/// The controller driving both models.
pub struct Sim {
    /// Controller under test.
    pub ctl: ThermalController,
    /// Hotend model.
    pub hotend: HeaterModel,
    /// Bed model.
    pub bed: HeaterModel,
    /// Current time, ms.
    pub now_ms: u32,
    /// Noise amplitude per conversion, counts.
    pub noise: f64,
    rng: Rng,
    /// The last outputs.
    pub out: Outputs,
}

impl Sim {
    /// Both heaters at ambient, default machine, seeded noise of ±2 counts per conversion.
    pub fn new(seed: u64) -> Self {
        let ctl = ThermalController::new(ThermalConfig::for_machine(&MachineConfig::default()));
        Self {
            ctl,
            hotend: HeaterModel::hotend(),
            bed: HeaterModel::bed(),
            now_ms: 0,
            noise: 2.0,
            rng: Rng::new(seed | 1),
            out: Outputs { hotend_pwm: 0, bed_pwm: 0, fan_pwm: 0, fault: None },
        }
    }

    fn reading(&mut self, m: HeaterModel) -> u16 {
        if m.open {
            return 16 * 4095;
        }
        if m.shorted {
            return 0;
        }
        let mean = adc_of_temp(m.sensor);
        (0..16)
            .map(|_| (mean + self.noise * self.rng.signed_unit()).round().clamp(0.0, 4095.0) as u16)
            .sum()
    }

    /// One control step: readings, controller, then the models advance under its outputs.
    pub fn step(&mut self) -> Outputs {
        self.now_ms += STEP_MS;
        let (h, b) = (self.reading(self.hotend), self.reading(self.bed));
        self.out = self.ctl.update(self.now_ms, h, b);
        let dt = f64::from(STEP_MS) / 1000.0;
        let fan = f64::from(self.out.fan_pwm) / 255.0;
        self.hotend.step(dt, f64::from(self.out.hotend_pwm) / 255.0, fan);
        self.bed.step(dt, f64::from(self.out.bed_pwm) / 255.0, fan);
        self.out
    }

    /// Runs `seconds`, calling `each` after every step; stops at the first fault and returns it.
    pub fn run(&mut self, seconds: f64, mut each: impl FnMut(&Self)) -> Option<ThermalFault> {
        let steps = (seconds * 1000.0 / f64::from(STEP_MS)).round() as u32;
        for _ in 0..steps {
            let out = self.step();
            each(self);
            if out.fault.is_some() {
                return out.fault;
            }
        }
        None
    }

    /// Seconds since the start.
    pub fn secs(&self) -> f64 {
        f64::from(self.now_ms) / 1000.0
    }
}
