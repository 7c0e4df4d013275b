//! Integer geometry in micrometres, the unit of every position in the core.
//!
//! One X/Y step of the Ender-3 is 12.5 um and one Z step 2.5 um, so 1 um resolution is below
//! one step on every axis. Coordinates are relative to the bed origin (front-left corner, bed
//! surface at z = 0); products and areas are computed in `i64`.

/// Micrometres per millimetre.
pub const UM_PER_MM: i32 = 1000;

/// A point in a layer plane, in micrometres.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Point2 {
    /// X in um.
    pub x: i32,
    /// Y in um.
    pub y: i32,
}

impl Point2 {
    /// Creates a point from coordinates in um.
    pub const fn new(x: i32, y: i32) -> Self {
        Self { x, y }
    }
}

/// A point in space, in micrometres.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Point3 {
    /// X in um.
    pub x: i32,
    /// Y in um.
    pub y: i32,
    /// Z in um (0 = bed surface).
    pub z: i32,
}

impl Point3 {
    /// Creates a point from coordinates in um.
    pub const fn new(x: i32, y: i32, z: i32) -> Self {
        Self { x, y, z }
    }

    /// The projection onto the XY plane.
    pub const fn xy(self) -> Point2 {
        Point2 { x: self.x, y: self.y }
    }
}

/// A mesh triangle in bed coordinates (um). The winding is counter-clockwise seen from
/// outside the solid (right-hand rule gives the outward normal); the STL normal is not kept.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Triangle {
    /// The three corners, in winding order.
    pub v: [Point3; 3],
}

impl Triangle {
    /// Lowest z of the three corners, in um.
    pub fn z_min(&self) -> i32 {
        self.v[0].z.min(self.v[1].z).min(self.v[2].z)
    }

    /// Highest z of the three corners, in um.
    pub fn z_max(&self) -> i32 {
        self.v[0].z.max(self.v[1].z).max(self.v[2].z)
    }
}

/// Twice the signed area of a closed polygon (shoelace formula), in um^2; positive when the
/// points run counter-clockwise. `i64` holds it for any polygon inside a 2 m square.
pub fn doubled_signed_area(points: &[Point2]) -> i64 {
    let Some(&last) = points.last() else {
        return 0;
    };
    let mut prev = last;
    let mut sum = 0i64;
    for &p in points {
        sum += i64::from(prev.x) * i64::from(p.y) - i64::from(p.x) * i64::from(prev.y);
        prev = p;
    }
    sum
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shoelace_gives_positive_area_for_counter_clockwise_square() {
        let square = [
            Point2::new(0, 0),
            Point2::new(2000, 0),
            Point2::new(2000, 2000),
            Point2::new(0, 2000),
        ];
        assert_eq!(doubled_signed_area(&square), 2 * 4_000_000);
        let mut reversed = square;
        reversed.reverse();
        assert_eq!(doubled_signed_area(&reversed), -2 * 4_000_000);
        assert_eq!(doubled_signed_area(&[]), 0);
    }

    #[test]
    fn triangle_z_range_covers_all_corners() {
        let t = Triangle { v: [Point3::new(0, 0, 5), Point3::new(1, 0, -3), Point3::new(0, 1, 9)] };
        assert_eq!((t.z_min(), t.z_max()), (-3, 9));
    }
}
