//! Integer arithmetic shared by the stages (the planner, the step generator, the toolpath stage).
//!
//! Exact square roots, divisions the Cortex-M3 has no instruction for, and saturating fixed-point
//! conversions.
//!
//! Both square roots are exact (`floor(sqrt(n))`) for every input and use no floating point.
//! They normalize the argument (shift left by an even count so that one of its two top bits
//! is set), take the root of the upper half, and extend it to the full width with one
//! division: Zimmermann's "Karatsuba square root" step, `s = s' b + q` with
//! `(q, u) = divrem(r' b + a1, 2 s')`, `r = u b + a0 - q^2`, and one correction when `r < 0`.
//! On the Cortex-M3 the 32-bit root is a few Newton steps on the hardware divider, so a
//! 64-bit root costs about as much as five divisions instead of 32 shift-and-subtract rounds.
//! `micromath`'s approximate `sqrt` (about 5 %) is never used for motion.

/// First estimates of the root of `h` in `[2^30, 2^32)` by its top 8 bits `i = h >> 24` (64 to
/// 255; the entries below 64 are unused, there only so that a `u8` index needs no bounds
/// check): `floor(2^12 sqrt(i + 1/2))`, the root at the middle of the interval, within 129 of
/// the root of every `h` in it (half the interval's root width, `2^10 / sqrt(i)`, plus 1).
const ROOT_GUESS: [u16; 256] = {
    let mut t = [0u16; 256];
    let mut k = 0;
    while k < 256 {
        // floor(sqrt((2 i + 1) 2^23)), at compile time.
        t[k] = digit_root(((2 * k as u128) + 1) << 23) as u16;
        k += 1;
    }
    t
};

/// `floor(sqrt(n))` by the plain digit-by-digit method (one bit of the root per round): the
/// table's builder at compile time and the tests' independent oracle, never a motion path.
const fn digit_root(n: u128) -> u128 {
    let (mut rem, mut root) = (n, 0u128);
    let mut bit = 1u128 << 126;
    while bit > n {
        bit >>= 2;
    }
    while bit != 0 {
        if rem >= root + bit {
            rem -= root + bit;
            root = (root >> 1) + bit;
        } else {
            root >>= 1;
        }
        bit >>= 2;
    }
    root
}

/// `floor(sqrt(h))` for `h` in `[2^30, 2^32)` (so the root is in `[2^15, 2^16)`): one integer
/// Newton step from the table's guess `x0`, `x1 = (x0 + h / x0) / 2`. `x1 >= floor(sqrt(h))`
/// for any `x0` (arithmetic-geometric mean), and `x1 - sqrt(h) <= (x0 - sqrt(h))^2 / (2 x0)
/// <= 129^2 / (2^16 - 258) < 1/2`, so `x1` is the floor root or one above it (then
/// `x1^2 > h`).
const fn isqrt_norm_u32(h: u32) -> u32 {
    let x0 = ROOT_GUESS[(h >> 24) as usize] as u32;
    let x1 = (x0 + h / x0) >> 1; // <= 2^16: its square needs 64 bits
    x1 - ((x1 as u64 * x1 as u64 > h as u64) as u32)
}

/// `floor(sqrt(n))` for a `u32`, exact.
pub const fn isqrt_u32(n: u32) -> u32 {
    if n == 0 {
        return 0;
    }
    // Even shift into [2^30, 2^32): floor(floor(sqrt(n 4^k)) / 2^k) = floor(sqrt(n)).
    let z = n.leading_zeros() & !1;
    isqrt_norm_u32(n << z) >> (z / 2)
}

/// `floor(sqrt(n))` for a `u64`, exact.
pub const fn isqrt_u64(n: u64) -> u64 {
    if n <= u32::MAX as u64 {
        return isqrt_u32(n as u32) as u64;
    }
    let z = n.leading_zeros() & !1;
    // floor(floor(sqrt(n 4^k)) / 2^k) = floor(sqrt(n)).
    (isqrt_norm_u64(n << z) >> (z / 2)) as u64
}

/// `floor(sqrt(w 2^shift))` for an even `shift` and `w <= u64::MAX >> shift`, exact: the
/// shift joins [`isqrt_u64`]'s normalization (one 64-bit shift instead of two).
// Inlined: its one call runs for every ramp step.
#[inline(always)]
pub const fn isqrt_u64_shl(w: u64, shift: u32) -> u64 {
    if w == 0 {
        return 0;
    }
    // z >= shift (w 2^shift fits), both even: the root of w 2^z over 2^((z - shift) / 2).
    let z = w.leading_zeros() & !1;
    (isqrt_norm_u64(w << z) >> ((z - shift) / 2)) as u64
}

/// `floor(sqrt(m))` for `m >= 2^62` (so the root is in `[2^31, 2^32)`), in 32-bit
/// arithmetic but for the final comparison.
// Inlined into its two callers: one of them runs for every ramp step.
#[inline(always)]
const fn isqrt_norm_u64(m: u64) -> u32 {
    // m = a3 b^3 + a2 b^2 + a1 b + a0 with b = 2^16 and a3 >= b / 4.
    let hi = (m >> 32) as u32;
    let s1 = isqrt_norm_u32(hi);
    let r1 = hi - s1 * s1; // <= 2 s1 < 2^17
    let a1 = (m >> 16) as u32 & 0xffff;
    let a0 = m as u32 & 0xffff;
    // q = floor((r1 b + a1) / (2 s1)) = floor(floor((r1 b + a1) / 2) / s1) <= 2^16; the
    // halved numerator is below 2^32.
    let half = (r1 << 15) | (a1 >> 1);
    let q = half / s1;
    // u = r1 b + a1 - 2 s1 q = 2 (half - s1 q) + (a1 & 1) < 2 s1.
    let u = 2 * (half - q * s1) + (a1 & 1);
    // s = s1 b + q, once 2^32 (q = b) before the correction below brings it under: mod 2^32.
    let s = (s1 << 16).wrapping_add(q);
    // r = u b + a0 - q^2 < 0: one step too far.
    let over = ((u as u64) << 16 | a0 as u64) < q as u64 * q as u64;
    // s = floor(sqrt(m)) < 2^32.
    s.wrapping_sub(over as u32)
}

/// `floor(sqrt(n))` for a `u128`, exact. [`isqrt_u64`] when `n` fits, else the same
/// extension step with `b = 2^32` (one 64-by-32-bit division).
pub fn isqrt_u128(n: u128) -> u128 {
    if n <= u64::MAX as u128 {
        return isqrt_u64(n as u64) as u128;
    }
    let z = n.leading_zeros() & !1;
    let m = n << z;
    let hi = (m >> 64) as u64;
    let s1 = isqrt_norm_u64(hi) as u64; // in [2^31, 2^32)
    let r1 = hi - s1 * s1; // <= 2 s1 < 2^33
    let a1 = (m >> 32) as u64 & 0xffff_ffff;
    let a0 = m as u64 & 0xffff_ffff;
    // q = floor((r1 b + a1) / 2 / s1) <= b; the halved numerator is below 2^64.
    let half = (r1 << 31) | (a1 >> 1);
    let q = if half >> 32 >= s1 { 1 << 32 } else { div_64by32(half, s1 as u32) as u64 };
    // u = r1 b + a1 - 2 s1 q = 2 (half - s1 q) + (a1 & 1) < 2 s1.
    let u = 2 * (half - q * s1) + (a1 & 1);
    // s = s1 b + q, once 2^64 (q = b) before the correction below brings it under.
    let s = (s1 << 32).wrapping_add(q);
    // r = u b + a0 - q^2 < 0 (one step too far): never for u >= b (q^2 <= b^2); for q = b
    // whenever u < b.
    let over = u >> 32 == 0 && (q >> 32 != 0 || (u << 32 | a0) < q * q);
    (s.wrapping_sub(over as u64) >> (z / 2)) as u128
}

/// `n / d` for a normalized `d` (`d >= 2^31`) and `n < d 2^32` (so the quotient fits in 32
/// bits): two 16-bit quotient digits, each estimated with the hardware's 32-bit division by
/// the divisor's top digit and corrected with its low digit (Knuth's algorithm D).
fn div_64by32(n: u64, d: u32) -> u32 {
    const B: u32 = 1 << 16;
    let (d1, d0) = (d >> 16, d & (B - 1));
    // One quotient digit of (top B + next) / d, and the remainder; top < d.
    let digit = |top: u32, next: u32| -> (u32, u32) {
        let mut q = top / d1;
        let mut rhat = top - q * d1;
        // rhat < B whenever the product is formed, so nothing overflows.
        while q >= B || q * d0 > (rhat << 16) + next {
            q -= 1;
            rhat += d1;
            if rhat >= B {
                break;
            }
        }
        (q, (top << 16).wrapping_add(next).wrapping_sub(q.wrapping_mul(d)))
    };
    let (q1, r) = digit((n >> 32) as u32, (n >> 16) as u32 & (B - 1));
    let (q0, _) = digit(r, n as u32 & (B - 1));
    (q1 << 16) | q0
}

/// A nonzero `u64` divisor prepared once for several divisions: from 2^32 on normalized
/// (`d = v 2^s >= 2^63`) with its [`reciprocal_3by2`].
#[derive(Clone, Copy, Debug)]
pub(crate) struct Divisor {
    v: u64,
    d: u64,
    s: u32,
    r: u32,
}

impl Divisor {
    /// Panics if `v` is 0, as a division by it would.
    // Inlined: for a 32-bit `v` it is a test and a copy.
    #[inline(always)]
    pub(crate) fn new(v: u64) -> Self {
        assert!(v != 0, "division by zero");
        if v >> 32 == 0 {
            // Divided by div_by_u32: nothing to prepare.
            return Self { v, d: 0, s: 0, r: 0 };
        }
        let s = v.leading_zeros();
        let d = v << s;
        Self { v, d, s, r: reciprocal_3by2(d) }
    }

    /// `n / v`, exactly as `u128` division.
    #[inline]
    pub(crate) fn div(&self, n: u128) -> u128 {
        if self.v >> 32 == 0 {
            return div_by_u32(n, self.v as u32);
        }
        let (hi, lo) = ((n >> 64) as u64, n as u64);
        if hi < self.v {
            return self.div_2by1(hi, lo) as u128;
        }
        let qh = self.div_2by1(0, hi);
        ((qh as u128) << 64) | self.div_2by1(hi - qh * self.v, lo) as u128
    }

    /// `sat_u64(n / v)`, without dividing when the quotient saturates: `n / v >= 2^64`
    /// exactly when `floor(n / 2^64) >= v`.
    #[inline]
    pub(crate) fn div_sat(&self, n: u128) -> u64 {
        let hi = (n >> 64) as u64;
        if hi >= self.v {
            u64::MAX
        } else if self.v >> 32 == 0 {
            div_by_u32(n, self.v as u32) as u64
        } else {
            self.div_2by1(hi, n as u64)
        }
    }

    /// `(u1 2^64 + u0) / v` for `2^32 <= v` and `u1 < v` (so the quotient fits): long
    /// division of the normalized operands with 32-bit digits, each digit one 3-by-2-word
    /// step of Möller and Granlund ("Improved division by invariant integers", 2011,
    /// algorithm 5) with the reciprocal: two multiplications and at most two corrections
    /// instead of a division. No `u64` or `u128` division routine (long loops on 32-bit
    /// targets).
    fn div_2by1(&self, u1: u64, u0: u64) -> u64 {
        let (d, s) = (self.d, self.s);
        // (u1 2^64 + u0) 2^s = (n3, n2, n1, n0) in 32-bit words, (n3, n2) < d. Word by word,
        // as s < 32 (v >= 2^32): `lo >> 1 >> (31 - s)` is `lo >> (32 - s)`, and 0 for s = 0.
        let shl = |hi: u64, lo: u64| ((hi as u32) << s) | ((lo as u32) >> 1 >> (31 - s));
        let n3 = shl(u1 >> 32, u1);
        let n2 = shl(u1, u0 >> 32);
        let n1 = shl(u0 >> 32, u0);
        let n0 = (u0 as u32) << s;
        let (q1, rem) = div_3by2((n3 as u64) << 32 | n2 as u64, n1, d, self.r);
        let (q0, _) = div_3by2(rem, n0, d, self.r);
        (q1 as u64) << 32 | q0 as u64
    }
}

/// `floor((2^96 - 1) / d) - 2^32` for a normalized `d` (`d >= 2^63`): Möller and Granlund's
/// algorithm 6, the 2-by-1 reciprocal of the top word (one [`div_64by32`]) corrected for the
/// low word.
fn reciprocal_3by2(d: u64) -> u32 {
    let (d1, d0) = ((d >> 32) as u32, d as u32);
    // floor((2^64 - 1) / d1) - 2^32 = floor(((2^32 - 1 - d1) 2^32 + 2^32 - 1) / d1).
    let mut v = div_64by32(((!d1 as u64) << 32) | 0xffff_ffff, d1);
    let mut p = d1.wrapping_mul(v).wrapping_add(d0);
    if p < d0 {
        v = v.wrapping_sub(1);
        if p >= d1 {
            v = v.wrapping_sub(1);
            p = p.wrapping_sub(d1);
        }
        p = p.wrapping_sub(d1);
    }
    let t = v as u64 * d0 as u64;
    let (t1, t0) = ((t >> 32) as u32, t as u32);
    p = p.wrapping_add(t1);
    if p < t1 {
        v = v.wrapping_sub(1);
        if ((p as u64) << 32 | t0 as u64) >= d {
            v = v.wrapping_sub(1);
        }
    }
    v
}

/// `(u 2^32 + u0) / d` and its remainder for a normalized `d`, `u < d` (so the quotient is one
/// word) and `r = reciprocal_3by2(d)`: Möller and Granlund's algorithm 5. The estimate
/// `q = floor(r u2 / 2^32) + u2 2^32 + u1` (`u = u2 2^32 + u1`; below 2^64) is the quotient
/// or one above it, more rarely one below.
#[inline(always)]
fn div_3by2(u: u64, u0: u32, d: u64, r: u32) -> (u32, u64) {
    let (d1, u2, u1) = ((d >> 32) as u32, (u >> 32) as u32, u as u32);
    let q = r as u64 * u2 as u64 + u;
    let (mut q1, q0) = ((q >> 32) as u32, q as u32);
    let r1 = u1.wrapping_sub(q1.wrapping_mul(d1));
    // The remainder for q1 + 1, mod 2^64.
    let mut rem =
        ((r1 as u64) << 32 | u0 as u64).wrapping_sub(d as u32 as u64 * q1 as u64).wrapping_sub(d);
    q1 = q1.wrapping_add(1);
    if (rem >> 32) as u32 >= q0 {
        q1 = q1.wrapping_sub(1);
        rem = rem.wrapping_add(d);
    }
    if rem >= d {
        q1 += 1;
        rem -= d;
    }
    (q1, rem)
}

/// `n / d` (floor), exactly as `u128` division: [`Divisor::div`] when `d` fits in 64 bits.
/// Panics if `d` is 0, as the `u128` division does.
pub(crate) fn div_u128(n: u128, d: u128) -> u128 {
    match u64::try_from(d) {
        Ok(d64) => Divisor::new(d64).div(n),
        Err(_) => div_wide(n, d),
    }
}

/// `sat_u64(div_u128(n, d))` ([`Divisor::div_sat`]).
pub(crate) fn div_sat_u64(n: u128, d: u128) -> u64 {
    match u64::try_from(d) {
        Ok(d64) => Divisor::new(d64).div_sat(n),
        // Below 2^64.
        Err(_) => div_wide(n, d) as u64,
    }
}

/// `n / d` for `d >= 2^64` (no caller in the planner's own units): the `u128` operator,
/// out of line so that [`div_u128`] stays short.
#[cold]
#[inline(never)]
fn div_wide(n: u128, d: u128) -> u128 {
    n / d
}

/// `n / d` for `0 < d < 2^32` (the steps per mm scale's 1000, speeds below 65 mm/s): long
/// division with 32-bit digits. A digit with no remainder carried in (the leading ones) is
/// one hardware division; the others divide `rem 2^32 + word` with `0 < rem < d`: for
/// `d < 2^16` as two 16-bit digits, each one hardware division (`rem 2^16 + half word` fits
/// in 32 bits), else with [`div_64by32`] after shifting both by the divisor's normalization
/// (which keeps the quotient).
#[inline(never)]
fn div_by_u32(n: u128, d: u32) -> u128 {
    let s = d.leading_zeros();
    // The digit of rem 2^32 + w and the new remainder, below d < 2^32 (exact mod 2^32).
    let digit = |rem: u32, w: u32| {
        let q = if rem == 0 {
            w / d
        } else if d < 1 << 16 {
            let hi = (rem << 16) | (w >> 16);
            let qh = hi / d;
            let lo = ((hi - qh * d) << 16) | (w & 0xffff);
            (qh << 16) | (lo / d)
        } else {
            div_64by32(((rem as u64) << 32 | w as u64) << s, d << s)
        };
        (q, w.wrapping_sub(q.wrapping_mul(d)))
    };
    let (q3, rem) = digit(0, (n >> 96) as u32);
    let (q2, rem) = digit(rem, (n >> 64) as u32);
    let (q1, rem) = digit(rem, (n >> 32) as u32);
    let (q0, _) = digit(rem, n as u32);
    (q3 as u128) << 96 | (q2 as u128) << 64 | (q1 as u128) << 32 | q0 as u128
}

/// `n / d` truncated toward zero, exactly as `i128` division by a positive `d`.
pub(crate) fn div_i128_pos(n: i128, d: &Divisor) -> i128 {
    let q = d.div(n.unsigned_abs()) as i128;
    if n < 0 {
        -q
    } else {
        q
    }
}

/// `floor(x y / 2^shift)` saturated to `u64`, for `shift` in `1..=64`: the 128-bit product
/// split into 64-bit halves, so that only 64-bit shifts remain (a variable 128-bit shift is
/// long on a 32-bit core).
#[inline]
pub(crate) fn mul_shr_sat(x: u64, y: u64, shift: u32) -> u64 {
    let p = x as u128 * y as u128;
    let (hi, lo) = ((p >> 64) as u64, p as u64);
    if shift >= 64 {
        // shift == 64.
        hi
    } else if hi >> shift != 0 {
        u64::MAX
    } else {
        (hi << (64 - shift)) | (lo >> shift)
    }
}

/// Saturating `u128 -> u64`.
#[inline]
pub(crate) const fn sat_u64(v: u128) -> u64 {
    if v > u64::MAX as u128 {
        u64::MAX
    } else {
        v as u64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `r` is the floor root of `n`: `r^2 <= n < (r + 1)^2`.
    fn is_floor_root(n: u128, r: u128) -> bool {
        r.checked_mul(r).is_some_and(|sq| sq <= n)
            && (r + 1).checked_mul(r + 1).map_or(true, |sq| sq > n)
    }

    #[test]
    fn normalized_32_bit_root_is_exact_at_every_square_and_guess_interval() {
        let check = |h: u32| {
            assert!(is_floor_root(h.into(), isqrt_norm_u32(h).into()), "h = {h}");
        };
        // Where a root is most easily off by one: around every square of the range, and at
        // both ends of every table interval (the guess's largest error).
        for r in 1u64 << 15..1 << 16 {
            for h in [r * r - 1, r * r, r * r + 1, r * r + 2 * r] {
                check(h.clamp(1 << 30, u32::MAX as u64) as u32);
            }
        }
        for i in 64u32..256 {
            for h in [i << 24, (i << 24) + 1, (i << 24) | 0xff_ffff, ((i << 24) | 0xff_ffff) - 1] {
                check(h);
            }
        }
        let mut next = crate::test_rng::xorshift(0x0123_4567_89ab_cdef);
        for _ in 0..1_000_000 {
            check((next() as u32) | 1 << 30);
        }
    }

    #[test]
    fn normalized_64_bit_root_is_exact_around_every_carry_of_its_low_half() {
        let check = |m: u64| {
            assert!(is_floor_root(m.into(), isqrt_norm_u64(m).into()), "m = {m}");
        };
        // Roots s1 b - 1, s1 b, s1 b + 1 (where q is 0 or b) and squares around them.
        for k in 1u64 << 15..1 << 16 {
            for s in [(k << 16) - 1, k << 16, (k << 16) + 1] {
                for m in [s * s - 1, s * s, s * s + 2 * s, (s + 1) * (s + 1)] {
                    if m >= 1 << 62 {
                        check(m);
                    }
                }
            }
        }
        let top = u32::MAX as u64;
        for m in [top * top - 1, top * top, u64::MAX, 1 << 62] {
            check(m);
        }
        let mut next = crate::test_rng::xorshift(0x0f1e_2d3c_4b5a_6978);
        for _ in 0..1_000_000 {
            let s = next() >> 32 | 1 << 31;
            check(next() | 1 << 63);
            check(s * s);
            check(s * s - 1);
            check(s * s + 2 * s);
        }
    }

    #[test]
    fn wide_root_is_exact_around_every_carry_of_its_low_half() {
        let mut next = crate::test_rng::xorshift(0x7f4a_7c15_9e37_79b9);
        let check = |n: u128| assert_eq!(isqrt_u128(n), digit_root(n), "n = {n}");
        for i in 0..100_000u64 {
            // Roots k b - 1, k b, k b + 1 with b = 2^32 (q is 0 or b), and random ones.
            let k = (next() >> 33) | 1 << 31;
            let s = match i % 4 {
                0 => (k << 32) - 1,
                1 => k << 32,
                2 => (k << 32) + 1,
                _ => next() | 1 << 63,
            } as u128;
            for n in [s * s - 1, s * s, s * s + 2 * s] {
                check(n);
                check(n >> (2 * (i % 32)));
            }
        }
    }

    /// All 3 2^30 inputs (about 10 s in release: `cargo test --release -- --ignored`).
    #[test]
    #[ignore]
    fn normalized_32_bit_root_is_exact_everywhere() {
        for h in 1u32 << 30..=u32::MAX {
            assert!(is_floor_root(h.into(), isqrt_norm_u32(h).into()), "h = {h}");
        }
    }

    #[test]
    fn roots_match_the_bitwise_oracle_near_squares_and_at_every_width() {
        let mut next = crate::test_rng::xorshift(0x1234_5678_9abc_def0);
        for _ in 0..20_000 {
            let x = next();
            for shift in [0, 1, 2, 17, 31, 32, 33, 40, 62, 63] {
                let n = x >> shift;
                assert_eq!(isqrt_u64(n) as u128, digit_root(n as u128), "n = {n}");
                assert_eq!(isqrt_u32(n as u32) as u128, digit_root(n as u32 as u128));
                // Squares and their neighbours, where a root is most easily off by one.
                let r = (n >> 32).max(1);
                for d in [-1i64, 0, 1] {
                    let sq = (r * r).wrapping_add(d as u64);
                    assert_eq!(isqrt_u64(sq) as u128, digit_root(sq as u128), "n = {sq}");
                }
                let wide = ((x as u128) << 64 | x.rotate_left(19) as u128) >> (2 * shift);
                assert_eq!(isqrt_u128(wide), digit_root(wide), "n = {wide}");
                let r = wide >> 64 | 1;
                for d in [-1i128, 0, 1] {
                    let sq = (r * r).wrapping_add(d as u128);
                    assert_eq!(isqrt_u128(sq), digit_root(sq), "n = {sq}");
                }
            }
        }
        for n in [u64::MAX, u64::MAX - 1, 1 << 62, (1 << 62) - 1, 1 << 32, (1 << 32) - 1] {
            assert_eq!(isqrt_u64(n) as u128, digit_root(n as u128), "n = {n}");
        }
        for n in [u128::MAX, u128::MAX - 1, 1 << 126, (1 << 126) - 1, 1 << 64, (1 << 64) + 1] {
            assert_eq!(isqrt_u128(n), digit_root(n), "n = {n}");
        }
        let e = u32::MAX as u128;
        assert_eq!(isqrt_u32(u32::MAX) as u128, digit_root(e));
    }

    #[test]
    fn wide_division_equals_the_native_one() {
        let mut next = crate::test_rng::xorshift(0x9e37_79b9_7f4a_7c15);
        for _ in 0..200_000 {
            let (a, b, c) = (next(), next(), next());
            let n = ((a as u128) << 64 | b as u128) >> (a % 128);
            // Divisors of every width, including ones just below and above a power of two.
            let d = match c % 5 {
                0 => (c >> (c % 64)).max(1) as u128,
                // Divisors of the 32-bit digit path (1000: the steps per mm scale).
                4 => [1, 1000, 65_535, c & 0xffff, (1 << 16) - 1 - (c & 0xff), 1 << 16, c >> 32]
                    [(b % 7) as usize] as u128,
                1 => (1u128 << (c % 64)) - (c % 2) as u128,
                2 => (c as u128) << (b % 64),
                _ => n >> (b % 128),
            }
            .max(1);
            assert_eq!(div_u128(n, d), n / d, "{n} / {d}");
            assert_eq!(div_sat_u64(n, d), sat_u64(n / d), "{n} / {d}");
            let sn = if a % 2 == 0 { n as i128 } else { -((n >> 1) as i128) };
            if let Ok(d64) = u64::try_from(d) {
                assert_eq!(div_i128_pos(sn, &Divisor::new(d64)), sn / d as i128, "{sn} / {d}");
            }
        }
        for (n, d) in [(u64::MAX >> 1, 1u32 << 31), ((1 << 63) - 1, u32::MAX), (0, 1 << 31)] {
            assert_eq!(div_64by32(n, d) as u64, n / d as u64, "{n} / {d}");
        }
        for _ in 0..200_000 {
            let d = (next() as u32) | 1 << 31;
            let n = next() % ((d as u64) << 32);
            assert_eq!(div_64by32(n, d) as u64, n / d as u64, "{n} / {d}");
        }
        // Words of zeros above, between and below, and divisors at every edge of the paths.
        let ns = [0, 1, 999, u32::MAX as u128, 1 << 32, 1 << 64, 1 << 96, (1 << 96) + 7, u128::MAX];
        let ds =
            [1u128, 2, 3, 1000, 65_535, 65_536, 65_537, 1 << 31, (1 << 31) + 1, u32::MAX as u128];
        for (n, d) in ns.iter().flat_map(|&n| ds.iter().map(move |&d| (n, d))) {
            for n in [n, n.wrapping_sub(1), n.wrapping_add(d)] {
                assert_eq!(div_u128(n, d), n / d, "{n} / {d}");
                assert_eq!(div_u128(n, d + (1 << 32)), n / (d + (1 << 32)), "{n} / {d} + 2^32");
                for d in [d, d + (1 << 32), d << 64, d.wrapping_neg()] {
                    assert_eq!(div_sat_u64(n, d), sat_u64(n / d), "{n} / {d}");
                    let e = d << 32 | 1;
                    assert_eq!(div_sat_u64(n, e), sat_u64(n / e), "{n} / {e}");
                }
            }
        }
        assert_eq!(div_u128(u128::MAX, 1), u128::MAX);
        assert_eq!(div_u128(u128::MAX, 1000), u128::MAX / 1000);
        assert_eq!(div_u128(u128::MAX, 65_535), u128::MAX / 65_535);
        assert_eq!(div_u128(u128::MAX, 65_536), u128::MAX / 65_536);
        assert_eq!(div_u128(999, 1000), 0);
        assert_eq!(div_u128(u128::MAX, u64::MAX as u128), u128::MAX / u64::MAX as u128);
        assert_eq!(div_u128(u128::MAX, (1 << 63) + 1), u128::MAX / ((1 << 63) + 1));
    }

    #[test]
    fn two_by_one_division_equals_the_native_one_at_its_corners() {
        let mut next = crate::test_rng::xorshift(0x1405_7b7e_f767_814f);
        for i in 0..300_000u64 {
            let v = match i % 4 {
                0 => next() >> (next() % 32),
                1 => (next() | 1 << 63) & !0xffff_ffff,
                2 => next() | 0xffff_ffff,
                _ => (1 << (32 + next() % 32)) - (next() % 3),
            }
            .max(1 << 32);
            let u1 = [v - 1, next() % v, 0, v >> 1][(i / 4 % 4) as usize];
            for u0 in [next(), u64::MAX, 0] {
                let n = (u1 as u128) << 64 | u0 as u128;
                let q = Divisor::new(v).div_2by1(u1, u0);
                assert_eq!(q as u128, n / v as u128, "{n} / {v}");
            }
        }
    }

    #[test]
    fn reciprocal_is_the_floor_of_the_wide_quotient() {
        let mut next = crate::test_rng::xorshift(0x5851_f42d_4c95_7f2d);
        let check = |d: u64| {
            let want = (u128::MAX >> 32) / d as u128 - (1 << 32);
            assert_eq!(reciprocal_3by2(d) as u128, want, "d = {d}");
        };
        for d in [1 << 63, u64::MAX, (1 << 63) | 1, (1 << 63) | 0xffff_ffff, 0xffff_ffff_0000_0000]
        {
            check(d);
        }
        for _ in 0..200_000 {
            let d = next() | 1 << 63;
            check(d);
            // Low words of 0 and all ones, where the corrections are taken.
            check(d & !0xffff_ffff);
            check(d | 0xffff_ffff);
        }
    }

    #[test]
    fn shifted_root_equals_the_root_of_the_shifted_value() {
        let mut next = crate::test_rng::xorshift(0x9e37_79b9_7f4a_7c15);
        for shift in (0..64).step_by(2) {
            let limit = u64::MAX >> shift;
            let check = |w: u64| {
                assert_eq!(isqrt_u64_shl(w, shift), isqrt_u64(w << shift), "{w} << {shift}");
            };
            for w in [0, 1, 2, 3, 4, limit, limit - 1, limit / 2, limit >> 1 << 1] {
                check(w.min(limit));
            }
            for _ in 0..20_000 {
                let w = (next() >> (next() % 64)) & limit;
                check(w);
                // Near squares: r^2 - 1, r^2, r^2 + 1 (within the limit).
                let r = isqrt_u64(w);
                for v in [r * r, (r * r).saturating_sub(1), r * r + 1] {
                    check(v.min(limit));
                }
            }
        }
    }

    #[test]
    fn split_multiply_shift_equals_the_128_bit_one() {
        let mut next = crate::test_rng::xorshift(0x2545_f491_4f6c_dd1d);
        for i in 0..200_000u32 {
            let (a, b) = (next() >> (next() % 64), next() >> (next() % 64));
            let shift = 1 + i % 64;
            let want = sat_u64((a as u128 * b as u128) >> shift);
            assert_eq!(mul_shr_sat(a, b, shift), want, "{a} {b} {shift}");
        }
        for shift in 1..=64 {
            for (a, b) in [(u64::MAX, u64::MAX), (0, u64::MAX), (1, 1), (u64::MAX, 1)] {
                assert_eq!(mul_shr_sat(a, b, shift), sat_u64((a as u128 * b as u128) >> shift));
            }
        }
    }

    #[test]
    fn isqrt_is_exact_floor() {
        for n in 0u64..20_000 {
            assert!(is_floor_root(n.into(), isqrt_u64(n).into()), "n = {n}");
        }
        for &n in &[
            u64::MAX,
            u64::MAX - 1,
            1 << 62,
            (1 << 62) - 1,
            (1 << 32) - 1,
            4_294_967_295 * 4_294_967_295,
        ] {
            assert!(is_floor_root(n.into(), isqrt_u64(n).into()), "n = {n}");
        }
        let mut x = 0x9e37_79b9_7f4a_7c15_u128;
        for _ in 0..2000 {
            x = x.wrapping_mul(0x2545_f491_4f6c_dd1d_9e37_79b9_7f4a_7c15).wrapping_add(7);
            for n in [x, x >> 3, x >> 40, x >> 90, u128::MAX - (x >> 100)] {
                assert!(is_floor_root(n, isqrt_u128(n)), "n = {n}");
            }
        }
    }
}
