//! Thermistor reading: ADC counts to temperature, oversampling, filtering, sensor faults.
//!
//! The Ender-3's stock sensor is a 100 kΩ NTC (EPCOS B57560G104F, Marlin's thermistor type 1)
//! read through a 4.7 kΩ pull-up by the STM32's 12-bit ADC (hotend PC5, bed PC4). The divider
//! gives `counts = 4096 * R / (R + 4700)`: a cold sensor reads near full scale, a hot one low.
//!
//! Every reading the core takes is the **sum of [`OVERSAMPLE`] conversions** (16 × 12 bits,
//! `0..=65520`): four extra bits of resolution and noise averaged before anything else sees it.
//! [`Oversampler`] builds those sums from single conversions, [`SensorFilter`] smooths them
//! with a light IIR filter, and [`sum_to_temp`] turns a sum into a temperature by linear
//! interpolation in [`TABLE`], after checking for an open (full scale) or shorted (near zero)
//! sensor.
//!
//! # The table
//!
//! [`TABLE`] holds the expected oversampled sum every [`TABLE_STEP_C`] degrees from
//! [`TABLE_FIRST_C`] to 350 °C, computed offline from the beta equation
//! `R(T) = R0 * exp(B * (1/T - 1/T0))` with `R0 = 100 kΩ`, `T0 = 298.15 K`, `B = 4092 K`, and
//! `sum = round(16 * 4096 * R / (R + 4700))`. The generator is `generate_table` in
//! `tests/thermal_table.rs` (run `cargo test --test thermal_table -- --ignored --nocapture
//! print_table` to print it); a test there checks that this table is exactly what it produces
//! and that the interpolated temperature stays within 0.5 °C of the equation over 0–300 °C
//! (measured: 0.15 °C).

use super::Temp;

/// Conversions summed into one reading.
pub const OVERSAMPLE: u16 = 16;
/// Largest 12-bit conversion.
pub const ADC_MAX: u16 = 4095;
/// Largest oversampled sum (`16 * 4095`).
pub const SUM_MAX: u16 = OVERSAMPLE * ADC_MAX;
/// Sums at or above this are an open sensor (4080 of 4095 counts: about 1.2 MΩ, -27 °C).
pub const OPEN_SUM: u16 = OVERSAMPLE * 4080;
/// Sums at or below this are a shorted sensor (32 counts: about 37 Ω, far above 400 °C).
pub const SHORT_SUM: u16 = OVERSAMPLE * 32;

/// Temperature of [`TABLE`]'s first entry, °C.
pub const TABLE_FIRST_C: i16 = -10;
/// Temperature step between [`TABLE`] entries, °C.
pub const TABLE_STEP_C: i16 = 5;
/// Entries in [`TABLE`] (-10 °C to 350 °C).
pub const TABLE_LEN: usize = 73;
/// Temperature of [`TABLE`]'s last entry, °C.
pub const TABLE_LAST_C: i16 = TABLE_FIRST_C + TABLE_STEP_C * (TABLE_LEN as i16 - 1);

/// Expected oversampled ADC sum at `TABLE_FIRST_C + i * TABLE_STEP_C` °C for the EPCOS 100k
/// (beta 4092) with a 4.7 kΩ pull-up; strictly decreasing. See the module docs for its origin.
pub const TABLE: [u16; TABLE_LEN] = [
    65043, 64879, 64670, 64408, 64080, 63677, 63186, 62594, 61888, 61056, 60086, 58968, 57695,
    56263, 54670, 52923, 51029, 49003, 46863, 44630, 42329, 39988, 37632, 35287, 32979, 30727,
    28552, 26466, 24482, 22607, 20845, 19199, 17668, 16249, 14939, 13732, 12623, 11606, 10675,
    9823, 9045, 8334, 7685, 7092, 6551, 6057, 5606, 5193, 4816, 4471, 4155, 3866, 3600, 3356, 3132,
    2926, 2737, 2562, 2401, 2252, 2115, 1988, 1870, 1761, 1660, 1566, 1479, 1398, 1323, 1252, 1187,
    1125, 1068,
];

/// A sensor reading that is not a temperature.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SensorError {
    /// The reading is at full scale: thermistor unplugged or a broken wire.
    Open,
    /// The reading is near zero: thermistor or its wiring shorted.
    Shorted,
}

/// Checks an oversampled sum for an open or shorted sensor.
pub const fn check_sum(sum: u16) -> Result<(), SensorError> {
    if sum >= OPEN_SUM {
        Err(SensorError::Open)
    } else if sum <= SHORT_SUM {
        Err(SensorError::Shorted)
    } else {
        Ok(())
    }
}

/// Converts an oversampled sum to a temperature, after [`check_sum`].
///
/// Readings beyond the table's ends clamp to -10 °C or 350 °C (both far outside the
/// min/max-temperature cutoffs).
pub fn sum_to_temp(sum: u16) -> Result<Temp, SensorError> {
    check_sum(sum)?;
    // The first entry at or below `sum`: TABLE[hi - 1] > sum >= TABLE[hi].
    let hi = TABLE.partition_point(|&v| v > sum);
    let (upper, lower) = match (hi.checked_sub(1).and_then(|lo| TABLE.get(lo)), TABLE.get(hi)) {
        (Some(&upper), Some(&lower)) => (upper, lower),
        // Colder than the first entry or hotter than the last: clamp.
        (None, _) => return Ok(Temp::from_num(TABLE_FIRST_C)),
        (_, None) => return Ok(Temp::from_num(TABLE_LAST_C)),
    };
    let lo = hi.saturating_sub(1);
    let span = i32::from(upper) - i32::from(lower);
    let into = i32::from(upper) - i32::from(sum);
    // Fraction of one step in 16.16 bits: into <= span < 2600, so (into * 5) << 16 fits.
    let frac_bits = ((into * i32::from(TABLE_STEP_C)) << 16) / span.max(1);
    let base = i32::from(TABLE_FIRST_C) + i32::from(TABLE_STEP_C) * lo as i32;
    Ok(Temp::from_bits((base << 16) + frac_bits))
}

/// Sums [`OVERSAMPLE`] single 12-bit conversions into one reading.
#[derive(Clone, Copy, Debug, Default)]
pub struct Oversampler {
    sum: u16,
    count: u8,
}

impl Oversampler {
    /// An empty accumulator.
    pub const fn new() -> Self {
        Self { sum: 0, count: 0 }
    }

    /// Adds one conversion (clamped to 12 bits); returns the sum after every
    /// [`OVERSAMPLE`]th and starts over.
    pub fn push(&mut self, raw: u16) -> Option<u16> {
        self.sum += raw.min(ADC_MAX);
        self.count += 1;
        if u16::from(self.count) == OVERSAMPLE {
            let sum = self.sum;
            *self = Self::new();
            Some(sum)
        } else {
            None
        }
    }
}

/// Extra fraction bits kept by [`SensorFilter`].
const FILTER_FRAC: u32 = 4;
/// IIR weight of a new reading: `1 / 2^FILTER_SHIFT` (one half: about 0.15 s at 10 Hz, small
/// next to the thermistor's own lag of a few seconds).
const FILTER_SHIFT: u32 = 1;

/// First-order IIR low-pass on oversampled sums.
#[derive(Clone, Copy, Debug, Default)]
pub struct SensorFilter {
    /// Filtered sum with [`FILTER_FRAC`] fraction bits; 0 before the first reading.
    state: u32,
    primed: bool,
}

impl SensorFilter {
    /// A filter that starts at its first reading.
    pub const fn new() -> Self {
        Self { state: 0, primed: false }
    }

    /// Feeds one sum, returns the filtered sum.
    pub fn filter(&mut self, sum: u16) -> u16 {
        let x = u32::from(sum) << FILTER_FRAC;
        if self.primed {
            self.state = self.state - (self.state >> FILTER_SHIFT) + (x >> FILTER_SHIFT);
        } else {
            self.state = x;
            self.primed = true;
        }
        ((self.state + (1 << (FILTER_FRAC - 1))) >> FILTER_FRAC).min(u32::from(SUM_MAX)) as u16
    }

    /// Forgets the history (the next reading is taken as is).
    pub fn reset(&mut self) {
        *self = Self::new();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn table_is_strictly_decreasing_and_inside_the_fault_bands() {
        assert!(TABLE.windows(2).all(|w| w[0] > w[1]));
        assert!(TABLE[0] < OPEN_SUM && TABLE[TABLE_LEN - 1] > SHORT_SUM);
    }

    #[test]
    fn table_points_convert_exactly() {
        for (i, &s) in TABLE.iter().enumerate() {
            let t = sum_to_temp(s).unwrap();
            assert_eq!(t, Temp::from_num(TABLE_FIRST_C + TABLE_STEP_C * i as i16));
        }
    }

    #[test]
    fn open_and_short_are_typed() {
        assert_eq!(sum_to_temp(SUM_MAX), Err(SensorError::Open));
        assert_eq!(sum_to_temp(0), Err(SensorError::Shorted));
        assert!(sum_to_temp(OPEN_SUM - 1).is_ok());
        assert!(sum_to_temp(SHORT_SUM + 1).is_ok());
    }

    #[test]
    fn oversampler_sums_sixteen() {
        let mut o = Oversampler::new();
        for _ in 0..15 {
            assert_eq!(o.push(5000), None);
        }
        assert_eq!(o.push(4095), Some(SUM_MAX));
        assert_eq!(o.push(1), None);
    }

    #[test]
    fn filter_converges() {
        let mut f = SensorFilter::new();
        assert_eq!(f.filter(1000), 1000);
        let mut y = 0;
        for _ in 0..30 {
            y = f.filter(2000);
        }
        assert_eq!(y, 2000);
        assert_eq!(f.filter(SUM_MAX), 33760);
    }
}
