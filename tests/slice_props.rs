//! Property tests: closed meshes in random orientations and positions slice into closed loops
//! with zero repairs, correct orientation, and per-layer areas matching the f64 oracle.

mod slice_support;

use proptest::prelude::*;
use slice_support::{check_layer, config, run, slice};
use strata::slice::LayerRepairs;
use strata_testkit::mesh::{cuboid, holed_prism, inverted, ngon, sphere, to_um, torus, TriMm};

/// Rotates `mesh` about its bounding-box centre (angles in radians, about x then y then z),
/// then moves it so its minimum corner sits at `offset` (mm).
fn rotate_and_place(mesh: &[TriMm], angles: [f64; 3], offset: [f64; 3]) -> Vec<TriMm> {
    let (sa, ca) = angles[0].sin_cos();
    let (sb, cb) = angles[1].sin_cos();
    let (sc, cc) = angles[2].sin_cos();
    let rot = |[x, y, z]: [f64; 3]| {
        let (y, z) = (ca * y - sa * z, sa * y + ca * z);
        let (x, z) = (cb * x + sb * z, -sb * x + cb * z);
        [cc * x - sc * y, sc * x + cc * y, z]
    };
    let turned: Vec<TriMm> = mesh.iter().map(|t| t.map(rot)).collect();
    let mut min = [f64::INFINITY; 3];
    for p in turned.iter().flatten() {
        for a in 0..3 {
            min[a] = min[a].min(p[a]);
        }
    }
    turned.iter().map(|t| t.map(|p| [0, 1, 2].map(|a| p[a] - min[a] + offset[a]))).collect()
}

fn check(mesh: &[TriMm]) -> Result<(), TestCaseError> {
    let tris = to_um(mesh);
    let (layers, stats) = slice(&tris, config(&tris, 0));
    prop_assert_eq!(stats.repairs, LayerRepairs::default());
    for l in &layers {
        check_layer(l, &tris, "rotated");
    }
    Ok(())
}

/// Snaps every coordinate to a 0.1 mm grid, so many corners lie exactly on the planes
/// (z = 0.1, 0.3, ... mm). Shared corners snap alike, so the mesh stays closed.
fn snapped(mesh: Vec<TriMm>) -> Vec<TriMm> {
    mesh.into_iter().map(|t| t.map(|p| p.map(|c| (c * 10.0).round() / 10.0))).collect()
}

fn angles() -> impl Strategy<Value = [f64; 3]> {
    [0.0..std::f64::consts::TAU, 0.0..std::f64::consts::TAU, 0.0..std::f64::consts::TAU]
}

fn offset() -> impl Strategy<Value = [f64; 3]> {
    [50.0..150.0f64, 50.0..150.0f64, 0.0..0.5f64]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    #[test]
    fn rotated_torus_stays_closed(a in angles(), o in offset()) {
        check(&rotate_and_place(&torus([0.0, 0.0, 0.0], 8.0, 3.0, 32, 12), a, o))?;
    }

    #[test]
    fn rotated_holed_block_stays_closed(a in angles(), o in offset()) {
        let outer = ngon(4, 0.0, 0.0, 10.0, 0.3);
        let inner = ngon(4, 0.0, 0.0, 4.0, 0.3);
        check(&rotate_and_place(&holed_prism(&outer, &inner, 0.0, 6.0), a, o))?;
    }

    #[test]
    fn rotated_sphere_in_hollow_cube_stays_closed(a in angles(), o in offset()) {
        let mut mesh = cuboid([-8.0, -8.0, -8.0], [8.0, 8.0, 8.0]);
        mesh.extend(inverted(sphere([0.0, 0.0, 0.0], 6.0, 16, 8)));
        mesh.extend(sphere([0.0, 0.0, 0.0], 3.0, 12, 6));
        check(&rotate_and_place(&mesh, a, o))?;
    }

    #[test]
    fn torus_snapped_to_the_plane_grid_stays_closed(a in angles(), o in offset()) {
        let mesh = rotate_and_place(&torus([0.0, 0.0, 0.0], 8.0, 3.0, 32, 12), a, o);
        let mesh = snapped(mesh);
        prop_assert!(to_um(&mesh).iter().any(|t| t.v.iter().any(|p| p.z % 200 == 100)));
        check(&mesh)?;
    }
}

fn any_triangle() -> impl Strategy<Value = strata::geom::Triangle> {
    // Corners on a coarse grid (so edges are shared, cuts chain, meet and need repairs),
    // sometimes just outside the packable range.
    let coord = prop_oneof![
        20 => (0..8i32).prop_map(|k| k * 400),
        1 => Just(-1i32),
        1 => Just(strata::slice::MAX_COORD_UM + 1),
    ];
    let corner = (coord.clone(), coord.clone(), coord)
        .prop_map(|(x, y, z)| strata::geom::Point3::new(x, y, z));
    [corner.clone(), corner.clone(), corner].prop_map(|v| strata::geom::Triangle { v })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// Arbitrary (sorted, broken) triangle soups: an `Ok` or a typed error, never a panic,
    /// whatever the capacities.
    #[test]
    fn arbitrary_soup_never_panics(mut soup in proptest::collection::vec(any_triangle(), 0..60)) {
        soup.sort_by_key(strata::geom::Triangle::z_min);
        let top = 3_000; // the grid's top corner is at 2.8 mm
        let cfg = strata::slice::SliceConfig::new(&strata::machine::PrintSettings::default(), top)
            .unwrap();
        let _ = run::<16, 16, 4>(&soup, cfg);
        if let Ok((layers, _)) = run::<256, 256, 64>(&soup, cfg) {
            // Whatever came in, what comes out is well formed.
            prop_assert_eq!(layers.len() as u32, cfg.layer_count());
            for l in &layers {
                for lp in &l.loops {
                    let doubled = strata::geom::doubled_signed_area(&lp.points);
                    prop_assert!(lp.points.len() >= 3 && doubled != 0);
                    prop_assert_eq!(doubled > 0, !lp.hole);
                }
            }
        }
        let _ = strata::slice::peak_needs(&soup, &cfg);
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// The active set counted as the triangles stream in z_min order, in lent words, peaks
    /// where `peak_needs` says (its own pass per band of planes); lent one word fewer than
    /// that peak needs (the count and a heap of the peak), it says the words are full.
    #[test]
    fn streamed_active_count_peaks_as_peak_needs_says(
        mut soup in proptest::collection::vec(any_triangle(), 1..120),
        layer_um in 50..400i32,
    ) {
        use strata::slice::{ActiveCount, SliceConfig, WordsFull};
        soup.retain(|t| t.v.iter().all(|p| [p.x, p.y, p.z].iter().all(|c| (0..=3_000).contains(c))));
        soup.sort_by_key(strata::geom::Triangle::z_min);
        let mut settings = strata::machine::PrintSettings::default();
        settings.layer_height_um = layer_um;
        let Ok(cfg) = SliceConfig::new(&settings, 3_000) else { return Ok(()) };
        let want = strata::slice::peak_needs(&soup, &cfg).unwrap().active_triangles;
        let mut words = vec![-1; want as usize + 1];
        let mut count = ActiveCount::start(&mut words);
        let peak = soup.iter().map(|t| count.push(&cfg, t).unwrap()).max().unwrap_or(0);
        prop_assert_eq!(peak, want);
        if want > 0 {
            let mut words = vec![-1; want as usize];
            let mut count = ActiveCount::start(&mut words);
            let full = soup.iter().map(|t| count.push(&cfg, t)).find(|r| r.is_err());
            prop_assert_eq!(full, Some(Err(WordsFull)));
        }
    }
}
