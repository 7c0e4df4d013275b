//! The one seeded generator of the tests.
//!
//! Xorshift64 (Marsaglia 2003, shifts 13, 7, 17), a full-period generator over the non-zero `u64`s.
//! Tests need reproducible noise, fault patterns and random models, not statistical quality; this
//! is the generator most of the tests' former private copies were, so their sequences stayed as
//! they were.
//!
//! Helpers take the state as it is after a step ([`Rng::u64`]); [`Rng::below`] and
//! [`Rng::range`] reduce it modulo the span (a bias of at most span / 2^64).

use std::ops::RangeInclusive;

/// A seeded xorshift64 generator.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Rng(u64);

/// The state a zero seed stands for (zero is xorshift's fixed point): the 64-bit golden ratio.
const ZERO_SEED: u64 = 0x9e37_79b9_7f4a_7c15;

impl Rng {
    /// A generator whose state is `seed` (0 is replaced by a fixed non-zero state).
    pub const fn new(seed: u64) -> Self {
        Self(if seed == 0 { ZERO_SEED } else { seed })
    }

    /// The next state: `x ^= x << 13; x ^= x >> 7; x ^= x << 17`.
    pub fn u64(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }

    /// `0..n` (`n` > 0): the next [`u64`](Self::u64) modulo `n`.
    pub fn below(&mut self, n: u64) -> u64 {
        self.u64() % n
    }

    /// A value in `range` (inclusive at both ends): `lo` plus the next state modulo the span.
    pub fn range(&mut self, range: RangeInclusive<i64>) -> i64 {
        let (lo, hi) = range.into_inner();
        lo + (self.u64() % (hi - lo + 1) as u64) as i64
    }

    /// True with probability `p` per mille: the next state modulo 1000 below `p`.
    pub fn per_mille(&mut self, p: u64) -> bool {
        self.u64() % 1000 < p
    }

    /// Uniform in `[0, 1)`: the top 53 bits of the next state.
    pub fn f64(&mut self) -> f64 {
        (self.u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Uniform in `[-1, 1)`: `2 f64() - 1` (exact: the 53 bits scaled by a power of two).
    pub fn signed_unit(&mut self) -> f64 {
        2.0 * self.f64() - 1.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_sequence_is_xorshift64() {
        let mut r = Rng::new(1);
        // Marsaglia's xorshift64 (13, 7, 17) from state 1.
        assert_eq!(r.u64(), 1_082_269_761);
        assert_eq!(r.u64(), 1_152_992_998_833_853_505);
        assert_eq!(Rng::new(0), Rng::new(ZERO_SEED));
    }

    #[test]
    fn helpers_stay_in_their_ranges() {
        let mut r = Rng::new(0x5eed);
        for _ in 0..10_000 {
            assert!((-3..=4).contains(&r.range(-3..=4)));
            assert!(r.below(7) < 7);
            assert!((0.0..1.0).contains(&r.f64()));
            assert!((-1.0..1.0).contains(&r.signed_unit()));
        }
        assert!((0..1000).all(|_| !r.per_mille(0)) && (0..1000).all(|_| r.per_mille(1000)));
    }

    #[test]
    fn signed_unit_is_the_former_noise_formula() {
        let (mut a, mut b) = (Rng::new(0x1234_5678_9abc_def1), 0x1234_5678_9abc_def1u64);
        for _ in 0..1000 {
            b ^= b << 13;
            b ^= b >> 7;
            b ^= b << 17;
            let former = (b >> 11) as f64 / (1u64 << 52) as f64 - 1.0;
            assert_eq!(a.signed_unit().to_bits(), former.to_bits());
        }
    }
}
