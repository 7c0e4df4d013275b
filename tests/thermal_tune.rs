//! How the default PID gains were chosen: a sweep on the f64 model (ignored by default, it only
//! prints). Run `cargo test --release --test thermal_tune -- --ignored --nocapture`.
//!
//! Starting point: SIMC rules for a lag-dominant first-order plant. Hotend: gain
//! 40 W / 255 / 0.12 W/K = 1.31 °C per duty count, time constant 25 / 0.12 = 208 s, effective
//! delay ≈ 3.2 s (sensor lag plus filter) → integrating slope k' = 0.0063 °C/s per count,
//! `Kc = 1 / (k' · 2θ) ≈ 25`, `τI = 8θ ≈ 26 s` → `Ki ≈ 1`, `Kd ≈ Kc · θ` ≈ 80. Bed: 0.43 °C per
//! count, 275 s, θ ≈ 4 s → `Kc ≈ 80`, `Ki ≈ 2.5`, `Kd ≈ 300`. The sweep around those points
//! picks the fastest settle with overshoot well under 5 °C and a hold within ±1 °C.

mod thermal_model;

use strata::thermal::{Heater, PidGains, Temp, ThermalFault};
use thermal_model::Sim;

/// Heat-up from 25 °C.
///
/// (seconds to within 0.5 °C for good, overshoot, worst deviation in the last 60 s of `total_s`),
/// or the fault it tripped (gains too slow for the approach period trip `HEATING FAILED`).
pub fn score(
    heater: Heater,
    target: i16,
    gains: PidGains,
    total_s: f64,
) -> Result<(f64, f64, f64), ThermalFault> {
    let mut sim = Sim::new(42);
    let mut cfg = *sim.ctl.config();
    match heater {
        Heater::Hotend => cfg.hotend.gains = gains,
        Heater::Bed => cfg.bed.gains = gains,
    }
    sim.ctl = strata::thermal::ThermalController::new(cfg);
    sim.ctl.set_target(heater, 0, target).unwrap();
    let tgt = f64::from(target);
    let (mut settled, mut os, mut dev) = (None::<f64>, f64::MIN, 0.0f64);
    let fault = sim.run(total_s, |s| {
        let t = match heater {
            Heater::Hotend => s.hotend.sensor,
            Heater::Bed => s.bed.sensor,
        };
        os = os.max(t - tgt);
        if (t - tgt).abs() > 0.5 {
            settled = None;
        } else if settled.is_none() {
            settled = Some(s.secs());
        }
        if s.secs() > total_s - 60.0 {
            dev = dev.max((t - tgt).abs());
        }
    });
    match fault {
        Some(f) => Err(f),
        None => Ok((settled.unwrap_or(f64::INFINITY), os, dev)),
    }
}

#[test]
#[ignore]
fn sweep_gains() {
    for (heater, target, kps, kis, kds) in [
        (Heater::Hotend, 200, [15.0, 22.0, 30.0, 40.0], [0.5, 0.9, 1.5, 2.5], [40.0, 80.0, 150.0]),
        (Heater::Bed, 60, [40.0, 60.0, 90.0, 130.0], [1.0, 1.5, 2.5, 4.0], [150.0, 300.0, 600.0]),
    ] {
        for kp in kps {
            for ki in kis {
                for kd in kds {
                    let g = PidGains {
                        kp: Temp::from_num(kp),
                        ki: Temp::from_num(ki),
                        kd: Temp::from_num(kd),
                    };
                    match score(heater, target, g, 400.0) {
                        Ok((settle, os, dev)) => println!(
                            "{heater:?} kp {kp:5} ki {ki:4} kd {kd:5}: settled {settle:6.1} s \
                             overshoot {os:5.2} C hold {dev:4.2} C"
                        ),
                        Err(f) => println!("{heater:?} kp {kp:5} ki {ki:4} kd {kd:5}: {f}"),
                    }
                }
            }
        }
    }
}
