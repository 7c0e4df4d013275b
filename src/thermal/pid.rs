//! Fixed-point PID heater control with anti-windup, output as an 8-bit PWM duty.
//!
//! `duty = Kp * e + I + D`, `e = target - T`, all in duty counts (`0..=255`):
//! - **I** accumulates `Ki * e * dt`, is clamped to `0..=255` and only integrates while the
//!   output is not saturated in the direction the error pushes (conditional integration);
//! - **D** is `-Kd * dT/dt` on the *measurement* (no kick when the target changes), low-passed
//!   over about four updates against ADC noise;
//! - outside [`FUNCTIONAL_RANGE_C`] of the target the heater runs bang-bang (full on below, off
//!   above) with the integral cleared, like Marlin's `PID_FUNCTIONAL_RANGE`, so a heat-up from
//!   cold never winds the integral up.
//!
//! Everything is `I16F16` (integer) arithmetic; time steps are integer milliseconds.

use super::Temp;

/// Largest duty.
pub const PWM_MAX: u8 = 255;
/// Half-width of the band around the target where the PID runs, °C.
pub const FUNCTIONAL_RANGE_C: i16 = 10;
/// Derivative low-pass weight of a new sample: `1 / 2^D_SHIFT`.
const D_SHIFT: u32 = 2;

/// PID gains in duty counts (of 255): per °C, per °C·s, per °C/s.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PidGains {
    /// Proportional gain, counts per °C.
    pub kp: Temp,
    /// Integral gain, counts per °C per second.
    pub ki: Temp,
    /// Derivative gain, counts per (°C/s).
    pub kd: Temp,
}

impl PidGains {
    /// Hotend defaults, tuned on the Ender-3 hotend model of `tests/thermal_model` (40 W,
    /// 25 J/K, 0.12 W/K loss, 3 s sensor lag): SIMC rules for a lag-dominant plant as the
    /// starting point, then the sweep in `tests/thermal_tune.rs` (fastest settle with the
    /// overshoot well under 5 °C). Close to Marlin's Ender-3 defaults (21.7 / 1.54 / 76.6).
    pub const HOTEND: Self =
        Self { kp: Temp::const_from_int(30), ki: Temp::lit("1.5"), kd: Temp::const_from_int(80) };
    /// Bed defaults, tuned the same way on the bed model (220 W, 550 J/K, 2 W/K, 4 s lag).
    pub const BED: Self =
        Self { kp: Temp::const_from_int(90), ki: Temp::lit("2.5"), kd: Temp::const_from_int(300) };
}

/// PID state of one heater (12 bytes).
#[derive(Clone, Copy, Debug, Default)]
pub struct Pid {
    integral: Temp,
    d_filt: Temp,
    last_temp: Temp,
    primed: bool,
}

impl Pid {
    /// A controller with no history.
    pub const fn new() -> Self {
        Self { integral: Temp::ZERO, d_filt: Temp::ZERO, last_temp: Temp::ZERO, primed: false }
    }

    /// Forgets the integral and derivative history.
    pub fn reset(&mut self) {
        *self = Self::new();
    }

    /// The current integral term, in duty counts.
    pub fn integral(&self) -> Temp {
        self.integral
    }

    /// One control step: the duty for the next `dt_ms`, given the measured `temp` after
    /// `dt_ms` milliseconds since the last step. A `target` of zero or less is off.
    pub fn update(&mut self, gains: &PidGains, target: Temp, temp: Temp, dt_ms: u32) -> u8 {
        // Derivative of the measurement, low-passed, kept current even when off or bang-bang.
        if self.primed && dt_ms > 0 {
            let dt = dt_ms.min(60_000) as i32;
            let dtemp = temp.saturating_sub(self.last_temp);
            let rate = dtemp.saturating_mul_int(1000) / dt;
            self.d_filt += (rate.saturating_sub(self.d_filt)) >> D_SHIFT;
        }
        self.last_temp = temp;
        let was_primed = self.primed;
        self.primed = true;

        if target <= 0 {
            self.integral = Temp::ZERO;
            return 0;
        }
        let error = target.saturating_sub(temp);
        let range = Temp::from_num(FUNCTIONAL_RANGE_C);
        if error > range {
            self.integral = Temp::ZERO;
            return PWM_MAX;
        }
        if error < -range {
            self.integral = Temp::ZERO;
            return 0;
        }
        let max = Temp::from_num(PWM_MAX);
        let p = gains.kp.saturating_mul(error);
        let d = if was_primed { gains.kd.saturating_mul(self.d_filt) } else { Temp::ZERO };
        let unclamped = p.saturating_add(self.integral).saturating_sub(d);
        // Conditional integration: not while the output is pinned and the error pushes on.
        let pinned_high = unclamped >= max && error > 0;
        let pinned_low = unclamped <= 0 && error < 0;
        if !pinned_high && !pinned_low && dt_ms > 0 {
            // At most 10 s (longer gaps are a stalled loop): fits I16F16.
            let dt_s = Temp::from_num(dt_ms.min(10_000)) / 1000;
            let step = gains.ki.saturating_mul(error).saturating_mul(dt_s);
            self.integral = self.integral.saturating_add(step).clamp(Temp::ZERO, max);
        }
        let out = p.saturating_add(self.integral).saturating_sub(d);
        out.clamp(Temp::ZERO, max).to_num::<i32>() as u8
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn t(c: i32) -> Temp {
        Temp::from_num(c)
    }

    #[test]
    fn bang_bang_outside_the_band_and_off_at_zero_target() {
        let mut pid = Pid::new();
        assert_eq!(pid.update(&PidGains::HOTEND, t(200), t(25), 100), PWM_MAX);
        assert_eq!(pid.update(&PidGains::HOTEND, t(200), t(230), 100), 0);
        assert_eq!(pid.update(&PidGains::HOTEND, t(0), t(25), 100), 0);
    }

    #[test]
    fn integral_is_clamped_and_does_not_wind_up_when_pinned() {
        let mut pid = Pid::new();
        // 7 C low: P gives 210, the integral only fills the rest up to 255, then stops.
        for _ in 0..1000 {
            pid.update(&PidGains::HOTEND, t(200), t(193), 100);
        }
        assert!(pid.integral() <= Temp::from_num(46), "{}", pid.integral());
        // 1 C low for a long time: the integral grows but stops at the clamp.
        for _ in 0..100_000 {
            pid.update(&PidGains::HOTEND, t(200), t(199), 100);
        }
        assert!(pid.integral() <= Temp::from_num(PWM_MAX));
        // 1 C high: the integral comes down until the output reaches zero, no further.
        for _ in 0..100_000 {
            pid.update(&PidGains::HOTEND, t(200), t(201), 100);
        }
        assert!((pid.integral() - Temp::from_num(30)).abs() < 1, "{}", pid.integral());
        // Far above: bang-bang off, integral cleared.
        pid.update(&PidGains::HOTEND, t(200), t(215), 100);
        assert_eq!(pid.integral(), Temp::ZERO);
    }

    #[test]
    fn derivative_acts_on_measurement_only() {
        let mut a = Pid::new();
        a.update(&PidGains::HOTEND, t(200), t(195), 100);
        let steady = a.update(&PidGains::HOTEND, t(200), t(195), 100);
        // A target change gives no derivative kick: only P changes.
        let moved = a.update(&PidGains::HOTEND, t(201), t(195), 100);
        assert!((30..=31).contains(&(i32::from(moved) - i32::from(steady))));
        // A rising measurement brakes.
        let mut b = Pid::new();
        b.update(&PidGains::HOTEND, t(200), t(195), 100);
        let rising = b.update(&PidGains::HOTEND, t(200), t(195) + Temp::lit("0.1"), 100);
        assert!(rising < steady);
    }

    #[test]
    fn arbitrary_inputs_never_panic() {
        let mut next = crate::test_rng::xorshift(0x9e37_79b9_7f4a_7c15);
        let mut pid = Pid::new();
        let gains = PidGains { kp: Temp::MAX, ki: Temp::MAX, kd: Temp::MAX };
        for i in 0..100_000 {
            let g = if i % 2 == 0 { &gains } else { &PidGains::BED };
            let target = Temp::from_bits(next() as i32);
            let temp = Temp::from_bits(next() as i32);
            let near = target.saturating_add(Temp::from_bits((next() as i32) >> 12));
            let dt = if i % 3 == 0 { next() as u32 } else { (next() % 1000) as u32 };
            pid.update(g, target, if i % 5 == 0 { temp } else { near }, dt);
        }
    }
}
