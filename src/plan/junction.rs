//! Corner speed between two moves: junction deviation (Klipper's formulation), the cap that
//! keeps the approximating arc inside the shorter half of each move, the extruder's allowed
//! velocity jump, and both moves' cruise limits.
//!
//! Directions are unit vectors in q62 (`i64`, 62 fraction bits). The half-angle terms are
//! formed without cancellation: with `d = u_prev . u_next` and `x = |u_prev x u_next|^2`,
//! `sin^2(theta/2) = (1 + d)/2` and `cos^2(theta/2) = x / (2 (1 + d))` for `d >= 0` (near
//! straight), and the mirror pair for `d < 0` (sharp turns), where `theta` is the angle between
//! the reversed previous direction and the next one (Klipper's `junction_cos_theta = -d`).

use super::math::{div_sat_u64, div_u128, isqrt_u128, sat_u64, Divisor};
use super::{Geom, Limits};

/// One in q62.
const ONE_Q62: i128 = 1 << 62;

/// The largest start speed squared (um^2/s^2, q16) of `next` after `prev`; both kinematic.
pub(super) fn junction_v2(prev: &Geom, next: &Geom, lim: &Limits) -> u64 {
    let mut v2 = prev.cruise_v2.min(next.cruise_v2);
    let (p, n) = (prev.unit, next.unit);
    // Skips the (long, on a 32-bit core) 128-bit product of a zero: Z of planar moves.
    let m = |a: i64, b: i64| if a == 0 || b == 0 { 0 } else { a as i128 * b as i128 };
    let dot = (m(p[0], n[0]) + m(p[1], n[1]) + m(p[2], n[2])) >> 62;
    let cross = [
        (m(p[1], n[2]) - m(p[2], n[1])) >> 62,
        (m(p[2], n[0]) - m(p[0], n[2])) >> 62,
        (m(p[0], n[1]) - m(p[1], n[0])) >> 62,
    ];
    let cross2 =
        cross.iter().map(|&c| if c == 0 { 0 } else { (c * c) as u128 }).sum::<u128>() >> 62;
    // sin^2 and cos^2 of half the corner angle, q62.
    let (s2, k) = if dot >= 0 {
        let opd = (ONE_Q62 + dot) as u128;
        (opd / 2, div_u128(cross2 << 61, opd))
    } else {
        let omd = (ONE_Q62 - dot) as u128;
        (div_u128(cross2 << 61, omd), omd / 2)
    };
    if s2 == 0 || dot < -(ONE_Q62 - ONE_Q62 / 1_000_000) {
        // (Nearly) a full reversal, within 0.08 degrees as Klipper's `0.999999`: stop.
        return 0;
    }
    let s = isqrt_u128(s2 << 62);
    // Junction deviation: r = jd sin/(1 - sin), v^2 = a r with jd = scv^2 (sqrt2 - 1) / a, so
    // v^2 = scv^2 (sqrt2 - 1) sin/(1 - sin) = scv^2 (sqrt2 - 1) sin (1 + sin) / cos^2:
    // a square corner passes at exactly the square-corner velocity, whatever the accel.
    // cos^2 = 0 (straight on) sets no limit.
    let x = (s * (ONE_Q62 as u128 + s)) >> 62;
    if k != 0 {
        v2 = v2.min(div_sat_u64(lim.scv2_jd_q16 as u128 * x, k));
        // The arc of that radius must fit in the shorter half of each move:
        // v^2 <= 1/2 len accel tan(theta/2), tan = sin / cos.
        // cos < 2^63 (k < 2^63): 2 cos fits.
        let by_2cos = Divisor::new(2 * isqrt_u128(k << 62) as u64);
        for g in [prev, next] {
            let la = sat_u64((g.len_q32 as u128 * g.accel_q16 as u128) >> 32);
            v2 = v2.min(by_2cos.div_sat(la as u128 * s));
        }
    }
    // Extruder: its velocity may jump by at most the extruder corner velocity.
    let dr = (next.e_ratio_q62 - prev.e_ratio_q62).unsigned_abs();
    if dr != 0 {
        let vmax_q16 = div_sat_u64((lim.ecv_q16 as u128) << 62, dr) as u128;
        if vmax_q16 < 1 << 56 {
            v2 = v2.min(sat_u64((vmax_q16 * vmax_q16) >> 16));
        }
    }
    v2
}
