//! Exact integer square roots and the fixed-point conversions shared by [`plan`](super) and
//! `step`.
//!
//! Both square roots are the digit-by-digit (binary restoring) method: shifts, adds and
//! compares only, no division, so they cost the same on the Cortex-M3 as on the host and are
//! exact (`floor(sqrt(n))`) for every input. `micromath`'s approximate `sqrt` (about 5 %) is
//! never used for motion.

/// `floor(sqrt(n))` for a `u64`, exact.
pub const fn isqrt_u64(n: u64) -> u64 {
    if n < 2 {
        return n;
    }
    let mut rem = n;
    let mut root = 0u64;
    // The highest power of four not above n.
    let mut bit = 1u64 << ((63 - n.leading_zeros()) & !1);
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

/// `floor(sqrt(n))` for a `u128`, exact. Falls back to [`isqrt_u64`] when `n` fits.
pub const fn isqrt_u128(n: u128) -> u128 {
    if n <= u64::MAX as u128 {
        return isqrt_u64(n as u64) as u128;
    }
    let mut rem = n;
    let mut root = 0u128;
    let mut bit = 1u128 << ((127 - n.leading_zeros()) & !1);
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

    #[test]
    fn isqrt_is_exact_floor() {
        for n in 0u64..20_000 {
            let r = isqrt_u64(n);
            assert!(r * r <= n && (r + 1) * (r + 1) > n, "n = {n}");
        }
        for &n in &[u64::MAX, u64::MAX - 1, 1 << 62, (1 << 62) - 1, 4_294_967_295 * 4_294_967_295] {
            let r = isqrt_u64(n) as u128;
            assert!(r * r <= n as u128 && (r + 1) * (r + 1) > n as u128, "n = {n}");
        }
        let mut x = 0x9e37_79b9_7f4a_7c15_u128;
        for _ in 0..2000 {
            x = x.wrapping_mul(0x2545_f491_4f6c_dd1d_9e37_79b9_7f4a_7c15).wrapping_add(7);
            for n in [x, x >> 3, x >> 40, x >> 90, u128::MAX - (x >> 100)] {
                let r = isqrt_u128(n);
                assert!(r * r <= n, "n = {n}");
                let r1 = r + 1;
                assert!(r1.checked_mul(r1).map_or(true, |sq| sq > n), "n = {n}");
            }
        }
    }
}
