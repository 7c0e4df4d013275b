//! The toolpath stage's settings, in its units.

use crate::machine::{InfillPattern, MachineConfig, PrintSettings, Rate};

use super::ToolpathError;
#[cfg(doc)]
#[allow(unused_imports)]
use super::*;

/// The nozzle's lift while a small layer waits out its minimum time, um: Cura's 3 mm
/// ("Lift Head"), clear of the part's tip.
pub const COOL_LIFT_UM: u16 = 3_000;

/// The bridge and overhang perimeter speed, mm/s.
///
/// Slow enough for a thread over air to set under the fan (about half the default infill
/// speed). A constant, not a setting: every copy of the settings on the board's stack stays
/// as it was.
pub const BRIDGE_SPEED_MM_S: u16 = 25;

/// The widest brim [`ToolpathConfig::validate`] takes, um (PrusaSlicer's brim width is
/// typically 3-10 mm; 50 mm is already a plate's worth of loops).
pub const MAX_BRIM_WIDTH_UM: i32 = 50_000;

/// The part-cooling fan by layer time.
///
/// PrusaSlicer's cooling logic and its built-in defaults: off on the first layers; a layer whose extrusions take at least `slow_below_s` at full
/// speed gets `min_duty`, one that takes at most the minimum layer time
/// ([`ToolpathConfig::min_layer_time_ms`]) `max_duty`, linearly in between; bridges and
/// overhang perimeters `bridge_duty`. Duties 0..=255.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Cooling {
    /// Duty of layers of `slow_below_s` or more.
    pub min_duty: u8,
    /// Duty of layers of the minimum layer time or less.
    pub max_duty: u8,
    /// Duty while printing bridges and overhang perimeters.
    pub bridge_duty: u8,
    /// Layers from the bed up with the fan off (adhesion).
    pub off_layers: u8,
    /// Layers shorter than this (s) get more than `min_duty`.
    pub slow_below_s: u16,
}

impl Cooling {
    /// PrusaSlicer's defaults: 35 % from 60 s up, 100 % at the minimum layer time and on
    /// bridges, the first layer without fan.
    pub const DEFAULT: Self = Self {
        min_duty: duty_of_percent(35),
        max_duty: 255,
        bridge_duty: 255,
        off_layers: 1,
        slow_below_s: 60,
    };

    /// The fan duty of layer `index` whose extrusions take `layer_us` at full speed, with a
    /// minimum layer time of `min_layer_us`.
    pub fn layer_duty(&self, index: u32, layer_us: u64, min_layer_us: u64) -> u8 {
        let slow_us = u64::from(self.slow_below_s) * 1_000_000;
        if index < u32::from(self.off_layers) {
            0
        } else if layer_us >= slow_us {
            self.min_duty
        } else if layer_us <= min_layer_us {
            self.max_duty
        } else {
            // From `max_duty` at `min_layer_us` down to `min_duty` at `slow_us`, rounded.
            let (lo, hi) = (i64::from(self.min_duty), i64::from(self.max_duty));
            let (span, left) = ((slow_us - min_layer_us) as i64, (slow_us - layer_us) as i64);
            (lo + ((hi - lo) * left * 2 + span).div_euclid(2 * span)).clamp(0, 255) as u8
        }
    }
}

/// A fan duty (0..=255) of `percent`, rounded.
pub const fn duty_of_percent(percent: u32) -> u8 {
    ((percent * 255 + 50) / 100) as u8
}

/// Where loops start.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Seam {
    /// The rear-most vertex (largest Y): seams line up at the back of the part.
    Rear,
    /// The vertex nearest to the nozzle: shortest travel, scattered seams.
    Nearest,
}

/// Everything the toolpath stage needs to know, in its units.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub struct ToolpathConfig {
    /// Extrusion line width, um.
    pub line_width_um: i32,
    /// First layer height, um.
    pub first_layer_height_um: i32,
    /// Layer height, um.
    pub layer_height_um: i32,
    /// Perimeter loops.
    pub perimeters: u8,
    /// Sparse infill density, percent.
    pub infill_percent: u8,
    /// Sparse infill pattern.
    pub infill_pattern: InfillPattern,
    /// Solid layers under a top surface (at most 16).
    pub top_layers: u8,
    /// Solid layers over a bottom surface (at most 16).
    pub bottom_layers: u8,
    /// Perimeter and skirt speed, mm/s.
    pub perimeter_speed_mm_s: Rate,
    /// Infill speed (sparse and solid), mm/s.
    pub infill_speed_mm_s: Rate,
    /// Travel speed, mm/s.
    pub travel_speed_mm_s: Rate,
    /// Speed of every extrusion on the first layer, mm/s.
    pub first_layer_speed_mm_s: Rate,
    /// Retraction length, um (0: never retract).
    pub retract_length_um: i32,
    /// Retraction speed, mm/s.
    pub retract_speed_mm_s: Rate,
    /// Filament diameter, um.
    pub filament_diameter_um: i32,
    /// Print the external perimeter after the inner ones.
    pub outer_perimeter_last: bool,
    /// How far infill lines reach into the innermost perimeter, um.
    pub infill_overlap_um: u16,
    /// Gap between the first layer and the skirt, um.
    pub skirt_distance_um: i32,
    /// Skirt loops (0: no skirt).
    pub skirt_loops: u8,
    /// Brim width around the first layer's islands, um (0: no brim): as many loops as fit
    /// ([`brim_loops`](Self::brim_loops)); the skirt goes around the brim.
    pub brim_width_um: i32,
    /// Where loops start.
    pub seam: Seam,
    /// Skin over no material of the layer below prints as bridges: straight lines in the
    /// direction that anchors most of them on both sides, at [`BRIDGE_SPEED_MM_S`], each a
    /// round thread one line wide ([`Feature::BridgeInfill`]); so does the lowest layer of a
    /// top skin over sparse infill (an internal bridge); perimeters over no material slow to
    /// the bridge speed ([`Feature::OverhangPerimeter`]).
    pub bridges: bool,
    /// Contour simplification tolerance, um.
    pub simplify_tolerance_um: i32,
    /// Once a layer is built, its contours stay in the skin window only for the bottom skins
    /// of the layers above; they are simplified again within this tolerance there, um (0 or
    /// not above `simplify_tolerance_um`: kept as they are).
    pub below_tolerance_um: i32,
    /// Travels that leave the part retract only from this length on, um.
    pub min_retract_travel_um: i32,
    /// Travel inside the part without retraction.
    pub comb: bool,
    /// A layer whose extrusions would take less than this is printed slower, its extrusion
    /// feeds scaled down (not below `min_print_speed_mm_s`) so that they take this long, ms
    /// (0: never): the layer below cools and the layer's computing stays far ahead of it.
    pub min_layer_time_ms: u32,
    /// The slowest extrusion feed the minimum layer time may ask for, mm/s.
    pub min_print_speed_mm_s: Rate,
    /// A layer still shorter than `min_layer_time_ms` at `min_print_speed_mm_s` waits for
    /// the rest at its end, retracted and with the nozzle lifted this much off the part
    /// (Cura's "lift head"), um.
    pub cool_lift_um: u16,
    /// The build volume's height, um: the lift stays below it.
    pub max_z_um: i32,
    /// The part-cooling fan.
    pub cooling: Cooling,
    /// Measure each island's area thinner than a line ([`LayerStats::thin_area_um2`]): one
    /// more offset per island and layer, for reports only (the toolpaths do not depend on
    /// it); the printer leaves it out.
    pub measure_thin_area: bool,
}

impl ToolpathConfig {
    /// The toolpath settings of `settings` on `machine`, with this stage's defaults: outer
    /// perimeter last, infill overlap half a line (infill lines reach the innermost
    /// perimeter's inner edge), a 3 mm skirt of one loop, no brim, rear seams,
    /// 10 um simplification, combing, retraction for travels over 1.5 mm that leave the part,
    /// PrusaSlicer's cooling ([`Cooling::DEFAULT`]).
    pub fn new(machine: &MachineConfig, settings: &PrintSettings) -> Self {
        Self {
            line_width_um: settings.line_width_um,
            first_layer_height_um: settings.first_layer_height_um,
            layer_height_um: settings.layer_height_um,
            perimeters: settings.perimeters,
            infill_percent: settings.infill_percent,
            infill_pattern: settings.infill_pattern,
            top_layers: settings.top_layers,
            bottom_layers: settings.bottom_layers,
            perimeter_speed_mm_s: settings.perimeter_speed_mm_s,
            infill_speed_mm_s: settings.infill_speed_mm_s,
            travel_speed_mm_s: settings.travel_speed_mm_s,
            first_layer_speed_mm_s: settings.first_layer_speed_mm_s,
            retract_length_um: settings.retract_length_um,
            retract_speed_mm_s: settings.retract_speed_mm_s,
            filament_diameter_um: machine.filament_diameter_um,
            outer_perimeter_last: true,
            // Within u16: the line width is validated at most 5 mm.
            infill_overlap_um: (settings.line_width_um / 2).clamp(0, i32::from(u16::MAX)) as u16,
            skirt_distance_um: 3_000,
            skirt_loops: 1,
            brim_width_um: 0,
            seam: Seam::Rear,
            bridges: true,
            simplify_tolerance_um: 10,
            below_tolerance_um: 0,
            min_retract_travel_um: 1_500,
            comb: true,
            min_layer_time_ms: 0,
            min_print_speed_mm_s: Rate::from_num(10),
            cool_lift_um: COOL_LIFT_UM,
            max_z_um: machine.build_volume_um[2],
            cooling: Cooling::DEFAULT,
            measure_thin_area: true,
        }
    }

    /// Checks ranges: positive widths and heights, at most 16 top/bottom layers and 20
    /// perimeters, density at most 100 %, non-negative distances, a brim of at most
    /// [`MAX_BRIM_WIDTH_UM`].
    pub fn validate(&self) -> Result<(), ToolpathError> {
        let checks = [
            ("line_width_um", (100..=5_000).contains(&self.line_width_um)),
            ("first_layer_height_um", (1..=5_000).contains(&self.first_layer_height_um)),
            ("layer_height_um", (1..=5_000).contains(&self.layer_height_um)),
            ("perimeters", self.perimeters <= 20),
            ("infill_percent", self.infill_percent <= 100),
            ("top_layers", self.top_layers <= 16),
            ("bottom_layers", self.bottom_layers <= 16),
            ("retract_length_um", (0..=50_000).contains(&self.retract_length_um)),
            ("filament_diameter_um", (100..=10_000).contains(&self.filament_diameter_um)),
            ("infill_overlap_um", i32::from(self.infill_overlap_um) <= self.line_width_um),
            ("skirt_distance_um", (0..=100_000).contains(&self.skirt_distance_um)),
            ("skirt_loops", self.skirt_loops <= 20),
            ("brim_width_um", (0..=MAX_BRIM_WIDTH_UM).contains(&self.brim_width_um)),
            ("simplify_tolerance_um", (0..=200).contains(&self.simplify_tolerance_um)),
            ("below_tolerance_um", (0..=self.line_width_um).contains(&self.below_tolerance_um)),
            ("min_retract_travel_um", self.min_retract_travel_um >= 0),
            ("travel_speed_mm_s", self.travel_speed_mm_s > 0),
            ("perimeter_speed_mm_s", self.perimeter_speed_mm_s > 0),
            ("infill_speed_mm_s", self.infill_speed_mm_s > 0),
            ("first_layer_speed_mm_s", self.first_layer_speed_mm_s > 0),
            ("retract_speed_mm_s", self.retract_speed_mm_s > 0),
            ("min_layer_time_ms", self.min_layer_time_ms <= 600_000),
            ("min_print_speed_mm_s", self.min_print_speed_mm_s > 0),
            ("cool_lift_um", self.cool_lift_um <= 50_000),
            ("cooling.slow_below_s", self.cooling.slow_below_s <= 3_600),
            ("max_z_um", self.max_z_um > 0),
        ];
        match checks.iter().find(|(_, ok)| !ok) {
            Some(&(field, _)) => Err(ToolpathError::InvalidConfig { field }),
            None => Ok(()),
        }
    }

    /// Nozzle height of layer `index` (top of the layer), um.
    pub fn layer_z_um(&self, index: u32) -> i32 {
        self.first_layer_height_um + self.layer_height_um * index as i32
    }

    /// Thickness of layer `index`, um.
    pub fn layer_height_of(&self, index: u32) -> i32 {
        if index == 0 {
            self.first_layer_height_um
        } else {
            self.layer_height_um
        }
    }

    /// Which solid-spacing lines are sparse infill lines (per direction): the infill
    /// percentage exactly, a grid's half of it in each of its two directions.
    pub fn sparse_lines(&self) -> SparseLines {
        let den = if self.infill_pattern == InfillPattern::Grid { 200 } else { 100 };
        SparseLines { num: self.infill_percent, den }
    }

    /// Brim loops: as many as fit in the brim width, floor(width / line width)
    /// (PrusaSlicer's count), so the outermost loop's outer edge is at most the width out.
    pub fn brim_loops(&self) -> i32 {
        if self.line_width_um > 0 {
            self.brim_width_um.max(0) / self.line_width_um
        } else {
            0
        }
    }

    /// How far the brim reaches out from the part, um: its loops' outer edge (0 without).
    pub fn brim_extent_um(&self) -> i32 {
        self.brim_loops() * self.line_width_um
    }

    /// Offset of the infill domain from the contour, um.
    pub fn infill_inset_um(&self) -> i32 {
        let w = self.line_width_um;
        let p = i32::from(self.perimeters);
        if p == 0 {
            w / 2
        } else {
            p * w + w / 2 - i32::from(self.infill_overlap_um)
        }
    }
}

/// The sparse infill lines among the solid-spacing lines: a fraction `num / den` of them,
/// spread evenly.
///
/// Line `i` is sparse when `floor(i * num / den)` steps up at it, so that any
/// run of `n` lines holds `n * num / den` of them (rounded either way) and the spacing is
/// `den / num` lines on average (alternating between its floor and ceiling): the density is
/// the percentage's, not the nearest "every k-th line". With `num / den = 1 / k` the sparse
/// lines are those with `i % k == 0`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SparseLines {
    /// Sparse lines per `den` lines (0: no sparse infill; at most `den`).
    pub num: u8,
    /// Lines the fraction counts over, at least 1 (line indices times it stay far inside
    /// `i32`: a line is at least 0.1 mm, the bed under 2^31 / 255 of them). One byte each
    /// keeps the infill pass's stack frame as it was.
    pub den: u8,
}

impl SparseLines {
    /// Whether there are sparse lines at all.
    pub fn any(&self) -> bool {
        self.num > 0
    }

    /// Sparse lines before line `i`, counted from line 0 (negative below it).
    fn count(&self, i: i32) -> i32 {
        (i * i32::from(self.num)).div_euclid(i32::from(self.den))
    }

    /// Whether line `i` is a sparse line.
    pub fn is_sparse(&self, i: i32) -> bool {
        self.any() && self.count(i) != self.count(i - 1)
    }

    /// The nearest sparse line above line `i` (`up`) or below it; `None` without sparse
    /// lines.
    pub fn next(&self, i: i32, up: bool) -> Option<i32> {
        if !self.any() {
            return None;
        }
        // The first line whose count reaches `c`: ceil(c * den / num).
        let first = |c: i32| -(-c * i32::from(self.den)).div_euclid(i32::from(self.num));
        Some(if up { first(self.count(i) + 1) } else { first(self.count(i - 1)) })
    }
}

/// The configuration of a [`Toolpath::empty`] stage until its [`reset`](Toolpath::reset):
/// never used to build a layer. Every field is zero (the first variant of the enums), so
/// that an empty stage is all zero bytes.
pub(super) const IDLE_CONFIG: ToolpathConfig = ToolpathConfig {
    line_width_um: 0,
    first_layer_height_um: 0,
    layer_height_um: 0,
    perimeters: 0,
    infill_percent: 0,
    infill_pattern: InfillPattern::Lines,
    top_layers: 0,
    bottom_layers: 0,
    perimeter_speed_mm_s: Rate::ZERO,
    infill_speed_mm_s: Rate::ZERO,
    travel_speed_mm_s: Rate::ZERO,
    first_layer_speed_mm_s: Rate::ZERO,
    retract_length_um: 0,
    retract_speed_mm_s: Rate::ZERO,
    filament_diameter_um: 0,
    outer_perimeter_last: false,
    infill_overlap_um: 0,
    skirt_distance_um: 0,
    skirt_loops: 0,
    brim_width_um: 0,
    seam: Seam::Rear,
    bridges: false,
    simplify_tolerance_um: 0,
    below_tolerance_um: 0,
    min_retract_travel_um: 0,
    comb: false,
    min_layer_time_ms: 0,
    min_print_speed_mm_s: Rate::ZERO,
    cool_lift_um: 0,
    max_z_um: 0,
    cooling: Cooling { min_duty: 0, max_duty: 0, bridge_duty: 0, off_layers: 0, slow_below_s: 0 },
    measure_thin_area: false,
};

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_brim_is_whole_loops_within_its_width_and_at_most_50_mm() {
        let mut cfg = ToolpathConfig::new(&MachineConfig::default(), &PrintSettings::default());
        assert_eq!((cfg.line_width_um, cfg.brim_width_um, cfg.brim_loops()), (450, 0, 0));
        for (width, loops) in [(449, 0), (450, 1), (899, 1), (900, 2), (5_000, 11)] {
            cfg.brim_width_um = width;
            assert_eq!((cfg.brim_loops(), cfg.brim_extent_um()), (loops, loops * 450), "{width}");
        }
        for (width, ok) in [(-1, false), (0, true), (50_000, true), (50_001, false)] {
            cfg.brim_width_um = width;
            let want = if ok {
                Ok(())
            } else {
                Err(ToolpathError::InvalidConfig { field: "brim_width_um" })
            };
            assert_eq!(cfg.validate(), want, "{width}");
        }
        assert_eq!(IDLE_CONFIG.brim_loops(), 0);
    }

    /// The settings are copied on the stack at a job's start; the layer's build reads them
    /// in place (it copied them once, on the board's deepest stack). 120 B with the cooling.
    #[test]
    fn the_settings_keep_their_size() {
        assert!(core::mem::size_of::<super::ToolpathConfig>() <= 120);
    }

    #[test]
    fn sparse_lines_are_the_fraction_spread_evenly() {
        // One in k: the lines with i % k == 0, as "every k-th line" had them.
        for k in 1..=20u8 {
            let s = SparseLines { num: 1, den: k };
            let every_kth = |i: i32| i.rem_euclid(i32::from(k)) == 0;
            assert!((-500..500).all(|i| s.is_sparse(i) == every_kth(i)), "1/{k}");
        }
        for (num, den) in [(3u8, 10u8), (7, 20), (37, 100), (99, 100), (100, 100), (13, 200)] {
            let s = SparseLines { num, den };
            let sparse: Vec<i32> = (-1000..1000).filter(|&i| s.is_sparse(i)).collect();
            // Any window of n lines holds n * num / den of them, rounded either way.
            for n in [1, 7, 50, 333] {
                for a in (-900..600).step_by(37) {
                    let got = sparse.iter().filter(|&&i| i >= a && i < a + n).count() as f64;
                    let want = f64::from(n) * f64::from(num) / f64::from(den);
                    assert!((got - want).abs() < 1.0, "{num}/{den}: {got} in {n} from {a}");
                }
            }
            // The nearest ones either way, from any line.
            for i in -800..800 {
                let up = sparse.iter().copied().find(|&j| j > i);
                let down = sparse.iter().copied().rev().find(|&j| j < i);
                assert_eq!((s.next(i, true), s.next(i, false)), (up, down), "{num}/{den} at {i}");
            }
        }
        let none = SparseLines { num: 0, den: 100 };
        assert!(!none.any() && !none.is_sparse(0) && none.next(3, true).is_none());
    }
}
