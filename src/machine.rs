//! Printer profile ([`MachineConfig`]) and print settings ([`PrintSettings`]), with validation.
//!
//! Lengths are integer micrometres, temperatures whole degrees Celsius, and rates
//! (steps/mm, mm/s, mm/s^2) unsigned fixed point with 32 fractional bits. Defaults are the
//! stock Ender-3 (Creality 4.2.2 board, Marlin limits) and a 0.2 mm PLA profile.

use core::fmt;

use fixed::types::U32F32;

/// A rate in unsigned 32.32 fixed point (steps/mm, mm/s or mm/s^2 by context).
pub type Rate = U32F32;

/// Axis order used by every per-axis array: X, Y, Z, E.
pub const AXES: usize = 4;

const fn rate(int: u32) -> Rate {
    Rate::const_from_int(int as u64)
}

/// The printer: kinematics, limits and geometry.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub struct MachineConfig {
    /// Steps per mm for X, Y, Z, E.
    pub steps_per_mm: [Rate; AXES],
    /// Build volume X, Y, Z in um.
    pub build_volume_um: [i32; 3],
    /// Maximum feed rate per axis X, Y, Z, E in mm/s.
    pub max_feed_mm_s: [Rate; AXES],
    /// Maximum acceleration per axis X, Y, Z, E in mm/s^2.
    pub max_accel_mm_s2: [Rate; AXES],
    /// Acceleration for printing moves in mm/s^2.
    pub print_accel_mm_s2: Rate,
    /// Acceleration for travel moves in mm/s^2.
    pub travel_accel_mm_s2: Rate,
    /// Square-corner velocity for junction deviation, in mm/s.
    pub square_corner_velocity_mm_s: Rate,
    /// Nozzle diameter in um.
    pub nozzle_diameter_um: i32,
    /// Filament diameter in um.
    pub filament_diameter_um: i32,
    /// Highest hotend target accepted, in degrees C.
    pub max_hotend_temp_c: i16,
    /// Highest bed target accepted, in degrees C.
    pub max_bed_temp_c: i16,
}

impl Default for MachineConfig {
    /// [`MachineConfig::ENDER3`].
    fn default() -> Self {
        Self::ENDER3
    }
}

impl MachineConfig {
    /// No machine: every field zero, a placeholder until a real configuration replaces it
    /// (a `static` built from it stays all zero bytes, in `.bss`).
    pub const EMPTY: Self = Self {
        steps_per_mm: [Rate::ZERO; AXES],
        build_volume_um: [0; 3],
        max_feed_mm_s: [Rate::ZERO; AXES],
        max_accel_mm_s2: [Rate::ZERO; AXES],
        print_accel_mm_s2: Rate::ZERO,
        travel_accel_mm_s2: Rate::ZERO,
        square_corner_velocity_mm_s: Rate::ZERO,
        nozzle_diameter_um: 0,
        filament_diameter_um: 0,
        max_hotend_temp_c: 0,
        max_bed_temp_c: 0,
    };

    /// The stock Ender-3: 16 microsteps, 220 x 220 x 250 mm, Marlin's limits.
    pub const ENDER3: Self = Self {
        steps_per_mm: [rate(80), rate(80), rate(400), rate(93)],
        build_volume_um: [220_000, 220_000, 250_000],
        max_feed_mm_s: [rate(500), rate(500), rate(5), rate(25)],
        max_accel_mm_s2: [rate(500), rate(500), rate(100), rate(1000)],
        print_accel_mm_s2: rate(500),
        travel_accel_mm_s2: rate(1000),
        square_corner_velocity_mm_s: rate(5),
        nozzle_diameter_um: 400,
        filament_diameter_um: 1750,
        max_hotend_temp_c: 260,
        max_bed_temp_c: 100,
    };
}

/// Infill pattern.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum InfillPattern {
    /// Parallel lines, all in the same direction within a layer.
    Lines,
    /// Parallel lines joined at their ends into continuous runs.
    Zigzag,
    /// Two crossing line sets in every layer.
    Grid,
}

/// How one print is sliced and printed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub struct PrintSettings {
    /// Layer height in um.
    pub layer_height_um: i32,
    /// First layer height in um.
    pub first_layer_height_um: i32,
    /// Extrusion line width in um.
    pub line_width_um: i32,
    /// Number of perimeter loops.
    pub perimeters: u8,
    /// Infill density in percent (0..=100).
    pub infill_percent: u8,
    /// Infill pattern.
    pub infill_pattern: InfillPattern,
    /// Solid layers at the top of every surface.
    pub top_layers: u8,
    /// Solid layers at the bottom of every surface.
    pub bottom_layers: u8,
    /// Hotend temperature in degrees C.
    pub hotend_temp_c: i16,
    /// Bed temperature in degrees C.
    pub bed_temp_c: i16,
    /// Perimeter speed in mm/s.
    pub perimeter_speed_mm_s: Rate,
    /// Infill speed in mm/s.
    pub infill_speed_mm_s: Rate,
    /// Travel speed in mm/s.
    pub travel_speed_mm_s: Rate,
    /// Speed of every extrusion on the first layer, in mm/s (travels keep their speed).
    pub first_layer_speed_mm_s: Rate,
    /// Retraction length in um (Bowden extruder).
    pub retract_length_um: i32,
    /// Retraction speed in mm/s.
    pub retract_speed_mm_s: Rate,
    /// Loops with an area below this are dropped by the slicer, in um^2.
    pub min_loop_area_um2: i64,
}

impl Default for PrintSettings {
    /// A 0.2 mm PLA profile for the Ender-3.
    fn default() -> Self {
        Self {
            layer_height_um: 200,
            first_layer_height_um: 200,
            line_width_um: 450,
            perimeters: 2,
            infill_percent: 20,
            infill_pattern: InfillPattern::Zigzag,
            top_layers: 4,
            bottom_layers: 4,
            hotend_temp_c: 200,
            bed_temp_c: 60,
            perimeter_speed_mm_s: rate(45),
            infill_speed_mm_s: rate(60),
            travel_speed_mm_s: rate(150),
            first_layer_speed_mm_s: rate(20),
            retract_length_um: 5000,
            retract_speed_mm_s: rate(45),
            // 0.01 mm^2.
            min_loop_area_um2: 10_000,
        }
    }
}

/// A setting that cannot be printed with this machine, named by field.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ConfigError {
    /// A machine value that must be positive is zero or negative.
    NonPositiveMachineValue {
        /// The `MachineConfig` field.
        field: &'static str,
    },
    /// A length setting that must be positive is zero or negative.
    NonPositiveLength {
        /// The `PrintSettings` field.
        field: &'static str,
    },
    /// Layer height (or first layer height) above 0.8 x nozzle diameter.
    LayerTooThick {
        /// The `PrintSettings` field.
        field: &'static str,
        /// The requested height in um.
        height_um: i32,
        /// The largest height this nozzle prints well, in um.
        max_um: i32,
    },
    /// Line width outside 0.6 .. 2.5 x nozzle diameter.
    LineWidthOutOfRange {
        /// The requested width in um.
        width_um: i32,
        /// Smallest accepted width in um.
        min_um: i32,
        /// Largest accepted width in um.
        max_um: i32,
    },
    /// Infill density above 100 %.
    InfillAbove100 {
        /// The requested density in percent.
        percent: u8,
    },
    /// No infill and no solid skins and no perimeters: nothing would be printed inside.
    NothingToPrint,
    /// A speed of zero.
    ZeroSpeed {
        /// The `PrintSettings` field.
        field: &'static str,
    },
    /// A print or travel speed above what the machine's X/Y axes allow.
    SpeedAboveMachineMax {
        /// The `PrintSettings` field.
        field: &'static str,
        /// The machine maximum in mm/s (integer part).
        max_mm_s: u32,
    },
    /// A temperature above the machine maximum (or below zero).
    TemperatureOutOfRange {
        /// The `PrintSettings` field.
        field: &'static str,
        /// The requested temperature in degrees C.
        temp_c: i16,
        /// The machine maximum in degrees C.
        max_c: i16,
    },
}

impl fmt::Display for ConfigError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Self::NonPositiveMachineValue { field } => {
                write!(f, "machine setting `{field}` must be positive")
            }
            Self::NonPositiveLength { field } => write!(f, "`{field}` must be positive"),
            Self::LayerTooThick { field, height_um, max_um } => {
                write!(f, "`{field}` {height_um} um is above 0.8 x nozzle diameter ({max_um} um)")
            }
            Self::LineWidthOutOfRange { width_um, min_um, max_um } => write!(
                f,
                "line width {width_um} um is outside {min_um}..{max_um} um for this nozzle"
            ),
            Self::InfillAbove100 { percent } => {
                write!(f, "infill density {percent} % is above 100 %")
            }
            Self::NothingToPrint => write!(
                f,
                "no perimeters, no infill and no solid top/bottom layers: nothing would be printed"
            ),
            Self::ZeroSpeed { field } => write!(f, "`{field}` must be above 0 mm/s"),
            Self::SpeedAboveMachineMax { field, max_mm_s } => {
                write!(f, "`{field}` is above the machine maximum of {max_mm_s} mm/s")
            }
            Self::TemperatureOutOfRange { field, temp_c, max_c } => {
                write!(f, "`{field}` {temp_c} C is outside 0..={max_c} C")
            }
        }
    }
}

impl MachineConfig {
    /// Checks that every value is physically meaningful.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let positive = |ok: bool, field| {
            if ok {
                Ok(())
            } else {
                Err(ConfigError::NonPositiveMachineValue { field })
            }
        };
        positive(self.steps_per_mm.iter().all(|r| *r > 0), "steps_per_mm")?;
        positive(self.build_volume_um.iter().all(|&v| v > 0), "build_volume_um")?;
        positive(self.max_feed_mm_s.iter().all(|r| *r > 0), "max_feed_mm_s")?;
        positive(self.max_accel_mm_s2.iter().all(|r| *r > 0), "max_accel_mm_s2")?;
        positive(self.print_accel_mm_s2 > 0, "print_accel_mm_s2")?;
        positive(self.travel_accel_mm_s2 > 0, "travel_accel_mm_s2")?;
        positive(self.nozzle_diameter_um > 0, "nozzle_diameter_um")?;
        positive(self.filament_diameter_um > 0, "filament_diameter_um")?;
        positive(self.max_hotend_temp_c > 0, "max_hotend_temp_c")?;
        positive(self.max_bed_temp_c > 0, "max_bed_temp_c")
    }
}

impl PrintSettings {
    /// Checks these settings against the machine; the first problem found is returned.
    pub fn validate(&self, machine: &MachineConfig) -> Result<(), ConfigError> {
        machine.validate()?;
        for (field, value) in [
            ("layer_height_um", self.layer_height_um),
            ("first_layer_height_um", self.first_layer_height_um),
            ("line_width_um", self.line_width_um),
        ] {
            if value <= 0 {
                return Err(ConfigError::NonPositiveLength { field });
            }
        }
        // Retraction may ask for more than the E axis allows (45 mm/s on a 25 mm/s Ender-3 E):
        // like Marlin, the planner clamps it to the axis limit, so only zero is refused.
        if self.retract_speed_mm_s == 0 {
            return Err(ConfigError::ZeroSpeed { field: "retract_speed_mm_s" });
        }
        if self.retract_length_um < 0 {
            return Err(ConfigError::NonPositiveLength { field: "retract_length_um" });
        }
        // 0.8 x nozzle: the usual upper bound for a layer to bond (PrusaSlicer warns above it).
        let max_layer_um = machine.nozzle_diameter_um * 4 / 5;
        for (field, height_um) in [
            ("layer_height_um", self.layer_height_um),
            ("first_layer_height_um", self.first_layer_height_um),
        ] {
            if height_um > max_layer_um {
                return Err(ConfigError::LayerTooThick { field, height_um, max_um: max_layer_um });
            }
        }
        let (min_um, max_um) =
            (machine.nozzle_diameter_um * 3 / 5, machine.nozzle_diameter_um * 5 / 2);
        if !(min_um..=max_um).contains(&self.line_width_um) {
            return Err(ConfigError::LineWidthOutOfRange {
                width_um: self.line_width_um,
                min_um,
                max_um,
            });
        }
        if self.infill_percent > 100 {
            return Err(ConfigError::InfillAbove100 { percent: self.infill_percent });
        }
        if self.infill_percent == 0
            && self.top_layers == 0
            && self.bottom_layers == 0
            && self.perimeters == 0
        {
            return Err(ConfigError::NothingToPrint);
        }
        let xy_max = machine.max_feed_mm_s[0].min(machine.max_feed_mm_s[1]);
        for (field, speed, max) in [
            ("perimeter_speed_mm_s", self.perimeter_speed_mm_s, xy_max),
            ("infill_speed_mm_s", self.infill_speed_mm_s, xy_max),
            ("travel_speed_mm_s", self.travel_speed_mm_s, xy_max),
            ("first_layer_speed_mm_s", self.first_layer_speed_mm_s, xy_max),
        ] {
            if speed == 0 {
                return Err(ConfigError::ZeroSpeed { field });
            }
            if speed > max {
                return Err(ConfigError::SpeedAboveMachineMax {
                    field,
                    max_mm_s: max.to_num::<u32>(),
                });
            }
        }
        for (field, temp_c, max_c) in [
            ("hotend_temp_c", self.hotend_temp_c, machine.max_hotend_temp_c),
            ("bed_temp_c", self.bed_temp_c, machine.max_bed_temp_c),
        ] {
            if !(0..=max_c).contains(&temp_c) {
                return Err(ConfigError::TemperatureOutOfRange { field, temp_c, max_c });
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ender3_defaults_are_the_stock_numbers() {
        let m = MachineConfig::default();
        let ints = |a: [Rate; AXES]| a.map(|r| r.to_num::<u32>());
        assert_eq!(ints(m.steps_per_mm), [80, 80, 400, 93]);
        assert_eq!(ints(m.max_feed_mm_s), [500, 500, 5, 25]);
        assert_eq!(ints(m.max_accel_mm_s2), [500, 500, 100, 1000]);
        assert_eq!(m.build_volume_um, [220_000, 220_000, 250_000]);
        assert_eq!((m.nozzle_diameter_um, m.filament_diameter_um), (400, 1750));
        let s = PrintSettings::default();
        assert_eq!((s.layer_height_um, s.first_layer_height_um, s.line_width_um), (200, 200, 450));
        assert_eq!((s.perimeters, s.infill_percent, s.top_layers, s.bottom_layers), (2, 20, 4, 4));
        assert_eq!((s.hotend_temp_c, s.bed_temp_c), (200, 60));
        assert_eq!(s.validate(&m), Ok(()));
    }

    #[test]
    fn layer_above_four_fifths_of_nozzle_is_refused() {
        let m = MachineConfig::default();
        let s = PrintSettings { layer_height_um: 330, ..Default::default() };
        assert_eq!(
            s.validate(&m),
            Err(ConfigError::LayerTooThick {
                field: "layer_height_um",
                height_um: 330,
                max_um: 320
            })
        );
        let s = PrintSettings { layer_height_um: 320, ..Default::default() };
        assert_eq!(s.validate(&m), Ok(()));
        let s = PrintSettings { first_layer_height_um: 0, ..Default::default() };
        assert_eq!(
            s.validate(&m),
            Err(ConfigError::NonPositiveLength { field: "first_layer_height_um" })
        );
    }

    #[test]
    fn empty_interior_and_bad_density_are_refused() {
        let m = MachineConfig::default();
        let s = PrintSettings {
            infill_percent: 0,
            top_layers: 0,
            bottom_layers: 0,
            perimeters: 0,
            ..Default::default()
        };
        assert_eq!(s.validate(&m), Err(ConfigError::NothingToPrint));
        let s = PrintSettings { infill_percent: 101, ..Default::default() };
        assert_eq!(s.validate(&m), Err(ConfigError::InfillAbove100 { percent: 101 }));
    }

    #[test]
    fn speeds_and_temperatures_respect_machine_limits() {
        let m = MachineConfig::default();
        let s = PrintSettings { travel_speed_mm_s: rate(501), ..Default::default() };
        assert_eq!(
            s.validate(&m),
            Err(ConfigError::SpeedAboveMachineMax { field: "travel_speed_mm_s", max_mm_s: 500 })
        );
        let s = PrintSettings { retract_speed_mm_s: rate(0), ..Default::default() };
        assert_eq!(s.validate(&m), Err(ConfigError::ZeroSpeed { field: "retract_speed_mm_s" }));
        let s = PrintSettings { infill_speed_mm_s: rate(0), ..Default::default() };
        assert_eq!(s.validate(&m), Err(ConfigError::ZeroSpeed { field: "infill_speed_mm_s" }));
        let s = PrintSettings { hotend_temp_c: 270, ..Default::default() };
        assert_eq!(
            s.validate(&m),
            Err(ConfigError::TemperatureOutOfRange {
                field: "hotend_temp_c",
                temp_c: 270,
                max_c: 260
            })
        );
        let bad_machine = MachineConfig { nozzle_diameter_um: 0, ..Default::default() };
        assert_eq!(
            PrintSettings::default().validate(&bad_machine),
            Err(ConfigError::NonPositiveMachineValue { field: "nozzle_diameter_um" })
        );
    }

    #[test]
    fn line_width_range_follows_nozzle() {
        let m = MachineConfig::default();
        let s = PrintSettings { line_width_um: 200, ..Default::default() };
        assert_eq!(
            s.validate(&m),
            Err(ConfigError::LineWidthOutOfRange { width_um: 200, min_um: 240, max_um: 1000 })
        );
    }
}
