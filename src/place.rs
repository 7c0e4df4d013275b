//! Placement: drop the model onto the bed, centre it in X/Y, quantise to micrometres.
//!
//! Runs once per job on the host (where the file is read); the device receives placed
//! triangles. The arithmetic is `f64` on purpose: it is not a hot path on the device, every
//! `f32` file coordinate converts exactly, and the sum with the offset is off by at most
//! 1e-12 mm for any model inside the 10 m the STL reader accepts, far below the 1 um grid.

use core::fmt;

use crate::geom::{Point3, Triangle, UM_PER_MM};
use crate::machine::MachineConfig;
use crate::stl::RawTriangle;

/// Axis names for error messages.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Axis {
    /// Bed width.
    X,
    /// Bed depth.
    Y,
    /// Height.
    Z,
}

impl fmt::Display for Axis {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Axis::X => "X",
            Axis::Y => "Y",
            Axis::Z => "Z",
        })
    }
}

/// Why a model cannot be placed on the bed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum PlaceError {
    /// The model has no (non-degenerate) triangles.
    EmptyModel,
    /// The model is larger than the build volume along `axis`.
    ExceedsBuildVolume {
        /// The offending axis.
        axis: Axis,
        /// Model size along the axis, in um.
        size_um: i64,
        /// Build volume along the axis, in um.
        limit_um: i64,
    },
}

impl fmt::Display for PlaceError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Self::EmptyModel => f.write_str("the model has no triangles"),
            Self::ExceedsBuildVolume { axis, size_um, limit_um } => write!(
                f,
                "the model is {:.2} mm along {axis}, {:.2} mm more than the build volume ({:.2} mm)",
                size_um as f64 / 1000.0,
                (size_um - limit_um) as f64 / 1000.0,
                limit_um as f64 / 1000.0
            ),
        }
    }
}

/// Axis-aligned bounds of a model in file units (mm).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bounds {
    /// Smallest x, y, z.
    pub min: [f32; 3],
    /// Largest x, y, z.
    pub max: [f32; 3],
}

impl Default for Bounds {
    fn default() -> Self {
        Self::EMPTY
    }
}

impl Bounds {
    /// Bounds of nothing (min above max).
    pub const EMPTY: Bounds = Bounds { min: [f32::INFINITY; 3], max: [f32::NEG_INFINITY; 3] };

    /// Grows the bounds to hold every corner of `t`.
    pub fn include(&mut self, t: &RawTriangle) {
        for v in &t.vertices {
            for ((lo, hi), &c) in self.min.iter_mut().zip(self.max.iter_mut()).zip(v) {
                *lo = lo.min(c);
                *hi = hi.max(c);
            }
        }
    }

    /// True until a triangle was included.
    pub fn is_empty(&self) -> bool {
        self.min[0] > self.max[0]
    }
}

/// Rounds millimetres to the nearest micrometre (half away from zero); `core` has no `round`.
fn mm_to_um(mm: f64) -> i32 {
    let um = mm * f64::from(UM_PER_MM);
    if um >= 0.0 {
        (um + 0.5) as i32
    } else {
        (um - 0.5) as i32
    }
}

/// The translation that puts a model on the bed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Placement {
    /// Added to every file coordinate (mm) before quantising.
    pub offset_mm: [f64; 3],
}

impl Placement {
    /// Centres the model on the bed in X/Y and drops it to z = 0; refuses a model larger than
    /// the build volume, naming the first axis that does not fit.
    pub fn on_bed(bounds: &Bounds, machine: &MachineConfig) -> Result<Self, PlaceError> {
        if bounds.is_empty() {
            return Err(PlaceError::EmptyModel);
        }
        let axes = [Axis::X, Axis::Y, Axis::Z];
        let mut offset_mm = [0.0f64; 3];
        for (i, axis) in axes.into_iter().enumerate() {
            let (lo, hi) = (f64::from(bounds.min[i]), f64::from(bounds.max[i]));
            let size_um = i64::from(mm_to_um(hi - lo));
            let limit_um = i64::from(machine.build_volume_um[i]);
            if size_um > limit_um {
                return Err(PlaceError::ExceedsBuildVolume { axis, size_um, limit_um });
            }
            offset_mm[i] = if axis == Axis::Z {
                -lo
            } else {
                limit_um as f64 / f64::from(UM_PER_MM) / 2.0 - (lo + hi) / 2.0
            };
        }
        Ok(Self { offset_mm })
    }

    /// The triangle in bed coordinates (um), winding kept.
    pub fn apply(&self, t: &RawTriangle) -> Triangle {
        let o = self.offset_mm;
        Triangle {
            v: t.vertices.map(|v| {
                Point3::new(
                    mm_to_um(f64::from(v[0]) + o[0]),
                    mm_to_um(f64::from(v[1]) + o[1]),
                    mm_to_um(f64::from(v[2]) + o[2]),
                )
            }),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tri(a: [f32; 3], b: [f32; 3], c: [f32; 3]) -> RawTriangle {
        RawTriangle { normal: [0.0; 3], vertices: [a, b, c] }
    }

    #[test]
    fn model_is_centred_and_dropped_to_the_bed() {
        let t = tri([-47.95, -4.91, -30.98], [-27.95, 15.09, -10.98], [-27.95, -4.91, -30.98]);
        let mut b = Bounds::EMPTY;
        b.include(&t);
        let p = Placement::on_bed(&b, &MachineConfig::default()).unwrap();
        let placed = p.apply(&t);
        // 20 x 20 x 20 mm centred on a 220 x 220 bed: 100..120 mm in X and Y, 0..20 mm in Z.
        assert_eq!(placed.v[0], Point3::new(100_000, 100_000, 0));
        assert_eq!(placed.v[1], Point3::new(120_000, 120_000, 20_000));
    }

    #[test]
    fn too_large_model_names_axis_and_excess() {
        let mut b = Bounds::EMPTY;
        b.include(&tri([0.0, 0.0, 0.0], [203.2, 304.8, 12.7], [0.0, 1.0, 0.0]));
        let err = Placement::on_bed(&b, &MachineConfig::default()).unwrap_err();
        assert_eq!(
            err,
            PlaceError::ExceedsBuildVolume { axis: Axis::Y, size_um: 304_800, limit_um: 220_000 }
        );
        let msg = err.to_string();
        assert!(msg.contains("along Y") && msg.contains("84.80 mm more"), "{msg}");
        assert_eq!(
            Placement::on_bed(&Bounds::EMPTY, &MachineConfig::default()),
            Err(PlaceError::EmptyModel)
        );
    }

    #[test]
    fn rounding_is_to_nearest_micrometre_both_signs() {
        assert_eq!(mm_to_um(0.0004), 0);
        assert_eq!(mm_to_um(0.0006), 1);
        assert_eq!(mm_to_um(-0.0006), -1);
        assert_eq!(mm_to_um(219.9996), 220_000);
    }
}
