//! Analytic meshes against independent oracles: per-layer area (f64 Green's-theorem sum over
//! the triangles' cuts, no chaining, plus closed forms where they exist), exact loop and hole
//! counts, orientation, and the on-plane rule.

mod slice_support;

use std::f64::consts::PI;

use slice_support::{check_layer, config, run, slice, OwnedLayer};
use strata::geom::{Point3, Triangle};
use strata::slice::{LayerRepairs, Resource, SliceError, SliceScratch, SlicedLayer};
use strata_testkit::mesh::{
    cuboid, holed_prism, inverted, loft, ngon, sphere, to_um, torus, TriMm,
};

const C: f64 = 110.0; // bed centre, mm

/// Slices, checks every layer against the oracle and zero repairs, returns the layers.
fn slice_checked(mesh: &[TriMm], what: &str) -> Vec<OwnedLayer> {
    let tris = to_um(mesh);
    let (layers, stats) = slice(&tris, config(&tris, 0));
    assert_eq!(layers.len() as u32, config(&tris, 0).layer_count());
    for (k, l) in layers.iter().enumerate() {
        assert_eq!(l.index as usize, k);
        assert_eq!(l.repairs, LayerRepairs::default(), "{what} layer {k}: repairs");
        assert_eq!(l.dropped_small_loops, 0, "{what} layer {k}");
        check_layer(l, &tris, what);
    }
    assert_eq!(stats.repairs, LayerRepairs::default());
    layers
}

#[test]
fn cube_20mm_gives_100_layers_of_400_mm2() {
    let layers = slice_checked(&cuboid([100.0, 100.0, 0.0], [120.0, 120.0, 20.0]), "cube");
    assert_eq!(layers.len(), 100);
    for l in &layers {
        assert_eq!(l.loops.len(), 1);
        assert!(!l.loops[0].hole);
        assert_eq!(l.area_um2(), 400_000_000, "layer {}", l.index);
    }
    assert_eq!((layers[0].z_um, layers[99].z_um), (100, 19_900));
}

#[test]
fn heptagonal_prism_matches_closed_form() {
    let (n, r) = (7, 10.0);
    let ring = ngon(n, C, C, r, 0.3);
    let layers = slice_checked(&loft(&[(0.0, ring.clone()), (15.0, ring)]), "prism");
    let exact = n as f64 / 2.0 * r * r * (2.0 * PI / n as f64).sin() * 1e6;
    assert_eq!(layers.len(), 75);
    for l in &layers {
        assert_eq!(l.loops.len(), 1);
        assert!((l.area_um2() as f64 - exact).abs() < exact * 1e-4, "{} vs {exact}", l.area_um2());
    }
}

#[test]
fn uv_sphere_sections_match_oracle() {
    let layers = slice_checked(&sphere([C, C, 10.0], 10.0, 48, 24), "sphere");
    assert_eq!(layers.len(), 100);
    for l in &layers {
        assert_eq!((l.loops.len(), l.holes()), (1, 0), "layer {}", l.index);
    }
    // Mid-plane section of a 48-gon of radius 10 mm (the equator ring at z = 10 mm sits on
    // no plane, the closest planes cut just off it).
    let equator = 48.0 / 2.0 * 100.0 * (2.0 * PI / 48.0).sin() * 1e6;
    let mid = layers[49].area_um2() as f64;
    assert!((mid - equator).abs() < equator * 2e-3, "{mid} vs {equator}");
}

#[test]
fn torus_sections_are_annuli() {
    let layers = slice_checked(&torus([C, C, 6.0], 15.0, 6.0, 64, 32), "torus");
    assert_eq!(layers.len(), 60);
    for l in &layers {
        assert_eq!((l.loops.len(), l.holes()), (2, 1), "layer {}", l.index);
        let hole = l.loops.iter().position(|x| x.hole).unwrap();
        let outer = 1 - hole;
        assert_eq!(l.loops[hole].parent, Some(outer as u32));
        assert_eq!(l.loops[outer].parent, None);
    }
}

#[test]
fn cube_with_square_through_hole() {
    let outer = ngon(4, C, C, 10.0 * 2f64.sqrt(), PI / 4.0);
    let inner = ngon(4, C, C, 4.0 * 2f64.sqrt(), PI / 4.0);
    let layers = slice_checked(&holed_prism(&outer, &inner, 0.0, 20.0), "holed cube");
    assert_eq!(layers.len(), 100);
    for l in &layers {
        assert_eq!((l.loops.len(), l.holes()), (2, 1));
        // 20 x 20 minus 8 x 8 mm (corners quantised to whole um).
        assert!((l.area_um2() - 336_000_000).abs() < 100, "{}", l.area_um2());
    }
}

#[test]
fn two_disjoint_bodies() {
    let mut mesh = cuboid([60.0, 100.0, 0.0], [80.0, 120.0, 10.0]);
    mesh.extend(sphere([140.0, 110.0, 8.0], 8.0, 32, 16));
    let layers = slice_checked(&mesh, "two bodies");
    assert_eq!(layers.len(), 80);
    for l in &layers {
        let expected = if l.z_um < 10_000 { 2 } else { 1 };
        assert_eq!((l.loops.len(), l.holes()), (expected, 0), "layer {}", l.index);
    }
}

#[test]
fn shell_inside_a_shell() {
    let mut mesh = cuboid([100.0, 100.0, 0.0], [120.0, 120.0, 20.0]);
    mesh.extend(inverted(sphere([C, C, 10.0], 6.0, 32, 16)));
    let layers = slice_checked(&mesh, "hollow cube");
    for l in &layers {
        let inside = (4_000..16_000).contains(&l.z_um);
        let expected = if inside { (2, 1) } else { (1, 0) };
        assert_eq!((l.loops.len(), l.holes()), expected, "layer {}", l.index);
    }
    // A solid sphere inside the void of the hollow cube: depth 2, outer again.
    mesh.extend(sphere([C, C, 10.0], 3.0, 24, 12));
    let layers = slice_checked(&mesh, "ball in a hollow cube");
    let mid = &layers[50];
    assert_eq!((mid.loops.len(), mid.holes()), (3, 1));
    let ball = mid.loops.iter().position(|l| !l.hole && l.parent.is_some()).unwrap();
    let hole = mid.loops[ball].parent.unwrap() as usize;
    assert!(mid.loops[hole].hole);
    assert!(mid.loops[ball].area_um2 > 0);
}

#[test]
fn vertices_exactly_on_planes() {
    // A twisted 9-gon tower whose rings sit exactly on the planes (z = 0.1, 0.3, ... mm).
    let mut rings = vec![(0.0, ngon(9, C, C, 8.0, 0.0))];
    for k in 0..40 {
        let z = 0.1 + 0.2 * f64::from(k);
        rings.push((z, ngon(9, C, C, 8.0, 0.05 * f64::from(k + 1))));
    }
    rings.push((8.0, ngon(9, C, C, 8.0, 2.1)));
    let tris = to_um(&loft(&rings));
    assert!(tris.iter().any(|t| t.v.iter().any(|p| p.z == 300)));
    let layers = slice_checked(&loft(&rings), "twisted tower");
    assert_eq!(layers.len(), 40);
    let ring_area = 9.0 / 2.0 * 64.0 * (2.0 * PI / 9.0).sin() * 1e6;
    for l in &layers {
        assert_eq!(l.loops.len(), 1);
        // On a ring the section is the ring polygon itself (9 points, as many as the ring).
        assert_eq!(l.loops[0].points.len(), 9, "layer {}", l.index);
        assert!((l.area_um2() as f64 - ring_area).abs() < ring_area * 1e-4);
    }
    // A bipyramid whose equator and apexes lie on planes 0.1 and 2.1 / 4.1 mm.
    let (eq, lo, hi) = (2.1, 0.1, 4.1);
    let ring = ngon(6, C, C, 5.0, 0.0);
    let mut mesh = Vec::new();
    for j in 0..6 {
        let (a, b) = (ring[j], ring[(j + 1) % 6]);
        mesh.push([[a[0], a[1], eq], [b[0], b[1], eq], [C, C, hi]]);
        mesh.push([[b[0], b[1], eq], [a[0], a[1], eq], [C, C, lo]]);
    }
    let layers = slice_checked(&mesh, "bipyramid");
    // Planes 0.1 (bottom apex: nothing), 0.3 .. 3.9; the top apex at 4.1 is the model top.
    assert_eq!(layers.len(), 20);
    assert!(layers[0].loops.is_empty());
    assert_eq!(layers[10].loops[0].points.len(), 6);
}

#[test]
fn empty_layers_keep_index_continuity() {
    let mut mesh = cuboid([100.0, 100.0, 0.0], [110.0, 110.0, 2.0]);
    // A floating second cube from 5 to 7 mm (a real slicer would print air, but indices
    // must stay continuous).
    mesh.extend(cuboid([100.0, 100.0, 5.0], [110.0, 110.0, 7.0]));
    let layers = slice_checked(&mesh, "two stacked cubes");
    assert_eq!(layers.len(), 35);
    let counts: Vec<usize> = layers.iter().map(|l| l.loops.len()).collect();
    assert!(counts[..10].iter().all(|&c| c == 1));
    assert!(counts[10..25].iter().all(|&c| c == 0));
    assert!(counts[25..].iter().all(|&c| c == 1));
}

#[test]
fn flipped_face_and_missing_face_are_repaired_and_reported() {
    let cube = cuboid([100.0, 100.0, 0.0], [120.0, 120.0, 4.0]);
    // One wall triangle with reversed winding: its segment runs backwards.
    let mut flipped = cube.clone();
    let w = flipped.iter().position(|t| t[0][2] != t[2][2]).unwrap();
    let [a, b, c] = flipped[w];
    flipped[w] = [a, c, b];
    let tris = to_um(&flipped);
    let (layers, stats) = slice(&tris, config(&tris, 0));
    for l in &layers {
        assert_eq!(l.loops.len(), 1);
        assert!(l.repairs.exact_joins > 0);
        assert_eq!(l.area_um2(), 400_000_000);
    }
    assert!(stats.repairs.exact_joins >= 20);
    // One wall triangle of a 64-gon prism missing (facets about 1 mm wide): a gap, bridged
    // straight along the flat facet, so the area is still the polygon's.
    let ring = ngon(64, C, C, 10.0, 0.0);
    let prism = loft(&[(0.0, ring.clone()), (4.0, ring)]);
    let exact = to_um(&prism);
    let (reference, _) = slice(&exact, config(&exact, 0));
    let mut holed = prism;
    holed.remove(0);
    let tris = to_um(&holed);
    let (layers, stats) = slice(&tris, config(&tris, 0));
    for (l, r) in layers.iter().zip(&reference) {
        assert_eq!(l.loops.len(), 1);
        assert_eq!(l.repairs.gaps_closed, 1);
        assert!((l.area_um2() - r.area_um2()).abs() <= 1, "{} vs {}", l.area_um2(), r.area_um2());
    }
    assert_eq!((stats.repairs.gaps_closed, stats.repairs.dropped_chains), (20, 0));
}

#[test]
fn small_loops_are_dropped_and_counted() {
    let mut mesh = cuboid([100.0, 100.0, 0.0], [120.0, 120.0, 1.0]);
    mesh.extend(cuboid([130.0, 100.0, 0.0], [130.05, 100.1, 1.0])); // 0.005 mm^2
    let tris = to_um(&mesh);
    let (layers, stats) = slice(&tris, config(&tris, 10_000));
    assert!(layers.iter().all(|l| l.loops.len() == 1 && l.dropped_small_loops == 1));
    assert_eq!(stats.dropped_small_loops, 5);
}

fn cube_tris() -> Vec<Triangle> {
    to_um(&cuboid([100.0, 100.0, 0.0], [120.0, 120.0, 20.0]))
}

#[test]
fn unsorted_input_is_refused_with_indices() {
    let mut tris = cube_tris();
    let last = tris.len() - 1;
    tris.swap(0, last);
    let err = run::<64, 64, 8>(&tris, config(&tris, 0)).unwrap_err();
    assert_eq!(err, SliceError::Unsorted { index: 1, z_min: 0, previous: 20_000 });
    assert!(err.to_string().contains("out of order"), "{err}");
}

#[test]
fn coordinates_off_the_bed_are_refused() {
    let mut tris = cube_tris();
    tris[3].v[1] = Point3::new(-5, 0, 0);
    let err = run::<64, 64, 8>(&tris, config(&tris, 0)).unwrap_err();
    assert_eq!(err, SliceError::OutOfRange { index: 3 });
}

#[test]
fn capacities_are_exact_and_overflow_is_typed() {
    let tris = to_um(&sphere([C, C, 10.0], 10.0, 48, 24));
    let cfg = config(&tris, 0);
    let needs = strata::slice::peak_needs(&tris, &cfg).unwrap();
    let (_, stats) = slice(&tris, cfg);
    assert_eq!(needs.active_triangles, stats.peak_active);
    assert_eq!(needs.contour_points, stats.peak_segments);
    assert_eq!(needs.layers, stats.layers);
    // The 48 x 24 sphere: 96 triangles (two per quad) cut by every plane but the equator's.
    assert_eq!((needs.active_triangles, needs.contour_points), (96, 96));
    assert!(run::<96, 96, 1>(&tris, cfg).is_ok());
    let err = run::<95, 96, 1>(&tris, cfg).unwrap_err();
    assert!(matches!(
        err,
        SliceError::Capacity { what: Resource::ActiveTriangles, capacity: 95, .. }
    ));
    let err = run::<96, 95, 1>(&tris, cfg).unwrap_err();
    assert!(matches!(err, SliceError::Capacity { what: Resource::Segments, capacity: 95, .. }));
    let two = to_um(
        &[
            cuboid([60.0, 60.0, 0.0], [70.0, 70.0, 1.0]),
            cuboid([80.0, 60.0, 0.0], [90.0, 70.0, 1.0]),
        ]
        .concat(),
    );
    let err = run::<64, 64, 1>(&two, config(&two, 0)).unwrap_err();
    assert_eq!(err, SliceError::Capacity { what: Resource::Loops, capacity: 1, layer: 0 });
}

#[test]
fn every_plane_gives_one_sink_call_and_finish_is_final() {
    let tris = cube_tris();
    let cfg = config(&tris, 0);
    let mut slicer = Box::new(SmallSlicer::new(cfg).unwrap());
    let mut work = SliceScratch::new();
    let mut seen = Vec::new();
    let mut sink = |l: SlicedLayer<'_, _, _>| seen.push(l.layer().index);
    for t in &tris {
        slicer.push(t, &mut work, &mut sink).unwrap();
    }
    let stats = slicer.finish(&mut work, &mut sink).unwrap();
    assert_eq!(seen, (0..100).collect::<Vec<_>>());
    assert_eq!(stats.layers, 100);
    // 16 triangles (fan caps of 4 each): the 8 horizontal ones span no plane.
    assert_eq!((stats.triangles, stats.dropped_triangles, stats.peak_active), (16, 8, 8));
    assert_eq!(slicer.push(&tris[0], &mut work, &mut |_| {}), Err(SliceError::Finished));
    slicer.reset(cfg).unwrap();
    assert_eq!(slicer.finish(&mut work, &mut |_| {}).map(|s| s.layers), Ok(100));
}

#[test]
fn nearly_shared_vertex_is_joined_within_tolerance() {
    // One wall triangle of a cube sees its top corner 15 um off (an unshared duplicate
    // vertex): its cuts miss the neighbours' by up to 15 um (growing with height; near the
    // bottom the difference rounds away) and are joined by the near pass.
    let mut mesh = cuboid([100.0, 100.0, 0.0], [120.0, 120.0, 4.0]);
    let w = mesh.iter().position(|t| t[0][2] != t[2][2]).unwrap();
    for v in mesh[w].iter_mut().filter(|v| v[2] == 4.0) {
        v[0] += 0.015;
    }
    let tris = to_um(&mesh);
    let (layers, stats) = slice(&tris, config(&tris, 0));
    assert!(layers.iter().all(|l| l.loops.len() == 1));
    assert!(layers[10..].iter().all(|l| l.repairs.tolerance_joins > 0));
    assert_eq!((stats.repairs.gaps_closed, stats.repairs.dropped_chains), (0, 0));
    for l in &layers {
        assert!((l.area_um2() - 400_000_000).abs() < 200_000, "{}", l.area_um2());
    }
}

#[test]
fn open_strip_shorter_than_its_gap_is_dropped_not_closed() {
    // A lone vertical quad (an open surface 1 mm wide): one straight chain whose ends are as
    // far apart as it is long. It must not be closed into a sliver: dropped and counted.
    let strip = vec![
        [[100.0, 100.0, 0.0], [101.0, 100.0, 0.0], [101.0, 100.0, 1.0]],
        [[100.0, 100.0, 0.0], [101.0, 100.0, 1.0], [100.0, 100.0, 1.0]],
    ];
    let tris = to_um(&strip);
    let (layers, stats) = slice(&tris, config(&tris, 0));
    assert_eq!(layers.len(), 5);
    for l in &layers {
        assert!(l.loops.is_empty());
        assert_eq!((l.repairs.dropped_chains, l.repairs.gaps_closed), (1, 0));
    }
    assert_eq!(stats.repairs.dropped_segments, 10);
}

strata::slicer_type! {
    type SmallSlicer = { active_triangles: 64, contour_points: 64, contour_loops: 8 };
}
