//! Layer planes: where each layer is cut, and which planes a triangle crosses.
//!
//! Plane 0 lies at the middle of the first layer (`first / 2`), plane `k >= 1` at
//! `first + (k - 1) * h + h / 2` (integer um). A model has one layer per plane strictly below
//! its top. A triangle crosses plane `p` when `z_min < p <= z_max`: the same rule as the
//! per-vertex classification (below: `z < p`, above: `z >= p`) used for intersections.

use super::SliceConfig;

impl SliceConfig {
    /// Height of plane `index` above the bed in um (planes past the model top included).
    pub fn plane_z_um(&self, index: u32) -> i64 {
        let (first, h) = (i64::from(self.first_layer_height_um), i64::from(self.layer_height_um));
        match index {
            0 => first / 2,
            k => first + (i64::from(k) - 1) * h + h / 2,
        }
    }

    /// Number of layers: planes strictly below `model_height_um`.
    pub fn layer_count(&self) -> u32 {
        self.first_plane_above(i64::from(self.model_height_um) - 1)
    }

    /// Index of the first plane strictly above `z` (um).
    pub(crate) fn first_plane_above(&self, z: i64) -> u32 {
        let (first, h) = (i64::from(self.first_layer_height_um), i64::from(self.layer_height_um));
        let base = first + h / 2; // plane 1
        let k = if z < first / 2 {
            0
        } else if z < base {
            1
        } else {
            2 + (z - base) / h
        };
        u32::try_from(k).unwrap_or(u32::MAX)
    }

    /// The planes `[first, last]` a triangle with this z range crosses, among the model's
    /// layers; `None` when it crosses none (horizontal triangles never cross a plane).
    pub(crate) fn crossed_planes(&self, z_min: i32, z_max: i32) -> Option<(u32, u32)> {
        let first = self.first_plane_above(i64::from(z_min));
        let after = self.first_plane_above(i64::from(z_max)).min(self.layer_count());
        (first < after).then(|| (first, after - 1))
    }
}

#[cfg(test)]
mod tests {
    use crate::machine::PrintSettings;
    use crate::slice::SliceConfig;

    fn config(first: i32, h: i32, top: i32) -> SliceConfig {
        let s = PrintSettings::default();
        let mut c = SliceConfig::new(&s, top).unwrap();
        c.first_layer_height_um = first;
        c.layer_height_um = h;
        c
    }

    #[test]
    fn planes_sit_mid_layer_and_stop_below_the_top() {
        let c = config(200, 200, 20_000);
        assert_eq!((c.plane_z_um(0), c.plane_z_um(1), c.plane_z_um(99)), (100, 300, 19_900));
        assert_eq!(c.layer_count(), 100);
        let c = config(300, 150, 1_000);
        // Planes 150, 375, 525, 675, 825, 975.
        assert_eq!(c.plane_z_um(1), 375);
        assert_eq!(c.layer_count(), 6);
        assert_eq!(config(300, 150, 975).layer_count(), 5);
        assert_eq!(config(200, 200, 100).layer_count(), 0);
        assert_eq!(config(200, 200, 101).layer_count(), 1);
    }

    #[test]
    fn first_plane_above_matches_brute_force() {
        for (first, h) in [(200, 200), (300, 150), (1, 1), (7, 3)] {
            let c = config(first, h, 5_000);
            for z in -5..2_000i64 {
                let brute = (0..).find(|&k| c.plane_z_um(k) > z).unwrap();
                assert_eq!(c.first_plane_above(z), brute, "first {first} h {h} z {z}");
            }
        }
    }

    #[test]
    fn crossed_planes_follow_the_half_open_rule() {
        let c = config(200, 200, 1_000); // planes 100, 300, 500, 700, 900
        assert_eq!(c.crossed_planes(0, 100), Some((0, 0)));
        assert_eq!(c.crossed_planes(100, 300), Some((1, 1)));
        assert_eq!(c.crossed_planes(100, 299), None);
        assert_eq!(c.crossed_planes(300, 300), None);
        assert_eq!(c.crossed_planes(0, 5_000), Some((0, 4)));
        assert_eq!(c.crossed_planes(950, 5_000), None);
    }
}
