//! The slicer writes a layer's loop points over its cut's endpoint hash table, in the shared
//! scratch, once the table is dead: nothing is lost. Every layer's points are exactly the
//! crossings of an independent f64 cut of the mesh (each within rounding, one for one), also
//! when the table filled every slot of the segment capacity, and when repairs bridge gaps
//! (a layer then has more points than segments: exactly at the capacity it is sliced, one
//! below it is the typed `ContourPoints` error, not an overwrite).

mod slice_support;

use std::f64::consts::PI;

use slice_support::{config, run, OwnedLayer};
use strata::geom::{Point2, Triangle};
use strata::slice::{Resource, SliceError};
use strata_testkit::check::{assert_section_area, section_segments_f64};
use strata_testkit::mesh::{holed_prism, loft, ngon, sphere, to_um, TriMm};

const C: f64 = 110.0; // bed centre, mm

/// The cut points of `tris` by plane `z` computed independently in f64: where each crossing
/// triangle's section enters it (one per segment, so on a closed mesh every point of the
/// section once).
fn crossings_f64(tris: &[Triangle], z: f64) -> Vec<[f64; 2]> {
    section_segments_f64(tris, z).into_iter().map(|[enter, _]| enter).collect()
}

/// Asserts that the layer's points and `want` match one for one, each within 1 um (the
/// slicer rounds every crossing to the nearest um).
fn assert_same_points(layer: &OwnedLayer, want: &[[f64; 2]], what: &str) {
    let got: Vec<Point2> = layer.loops.iter().flat_map(|l| l.points.iter().copied()).collect();
    assert_eq!(got.len(), want.len(), "{what} layer {}: point count", layer.index);
    let mut unused: Vec<[f64; 2]> = want.to_vec();
    for p in &got {
        let (x, y) = (f64::from(p.x), f64::from(p.y));
        let nearest = unused
            .iter()
            .enumerate()
            .map(|(i, q)| (i, (q[0] - x).abs().max((q[1] - y).abs())))
            .min_by(|a, b| a.1.total_cmp(&b.1));
        match nearest {
            Some((i, d)) if d <= 1.0 => {
                unused.swap_remove(i);
            }
            _ => panic!("{what} layer {}: {p:?} is no crossing of the mesh", layer.index),
        }
    }
}

/// Checks every layer of a closed mesh against the f64 cut: the same points, the same area
/// (0.1 % or 1 um x the cut length), loops oriented as their hole flag says.
fn check_closed(layers: &[OwnedLayer], tris: &[Triangle], what: &str) {
    for l in layers {
        let z = f64::from(l.z_um);
        assert_same_points(l, &crossings_f64(tris, z), what);
        let what_layer = format!("{what} layer {}", l.index);
        assert_section_area(&what_layer, l.area_um2() as f64, tris, l.z_um, 0.0);
        for lp in &l.loops {
            let doubled = strata::geom::doubled_signed_area(&lp.points);
            assert_eq!(doubled > 0, !lp.hole, "{what} layer {}: orientation", l.index);
        }
    }
}

/// The largest number of segments (= crossing triangles) of a layer, from the f64 cut.
fn peak_f64(tris: &[Triangle], layers: &[OwnedLayer]) -> usize {
    layers.iter().map(|l| crossings_f64(tris, f64::from(l.z_um)).len()).max().unwrap_or(0)
}

#[test]
fn points_over_a_full_table_are_the_sections_of_an_independent_cut() {
    // A 48 x 24 sphere: 96 segments in its fullest layers, so with a capacity of 96 the hash
    // table takes every slot before the points are written over it.
    let tris = to_um(&sphere([C, C, 10.0], 10.0, 48, 24));
    let (layers, stats) = run::<128, 96, 4>(&tris, config(&tris, 0)).expect("sphere slices");
    assert_eq!(peak_f64(&tris, &layers), 96);
    assert_eq!((stats.peak_segments, stats.peak_points), (96, 96));
    assert_eq!(layers.len(), 100);
    check_closed(&layers, &tris, "sphere");
    // A 12-gon ring with a 12-gon hole: two loops a layer (24 + 24 segments), the hole's
    // points after the outer loop's in the same slots.
    let ring = holed_prism(&ngon(12, C, C, 8.0, 0.1), &ngon(12, C, C, 3.0, 0.2), 0.0, 3.0);
    let tris = to_um(&ring);
    let (layers, _) = run::<64, 48, 2>(&tris, config(&tris, 0)).expect("ring slices");
    assert_eq!(peak_f64(&tris, &layers), 48);
    assert!(layers.iter().all(|l| l.loops.len() == 2 && l.holes() == 1));
    check_closed(&layers, &tris, "ring");
}

/// A 64-gon prism (r 10 mm, 4 mm high: 128 segments a layer, two per wall facet) and the
/// same with wall triangles of facets 0, 21 and 42 missing: three gaps a layer.
fn prism_with_gaps() -> (Vec<TriMm>, Vec<TriMm>) {
    let ring = ngon(64, C, C, 10.0, 0.0);
    let prism = loft(&[(0.0, ring.clone()), (4.0, ring)]);
    let mut holed = prism.clone();
    // The walls come first, two triangles per facet.
    for i in [2 * 42, 2 * 21 + 1, 0] {
        holed.remove(i);
    }
    (prism, holed)
}

#[test]
fn bridged_gaps_add_points_that_fill_the_capacity_exactly() {
    let (prism, holed) = prism_with_gaps();
    let (full, tris) = (to_um(&prism), to_um(&holed));
    let cfg = config(&tris, 0);
    let (layers, stats) = run::<256, 128, 4>(&tris, cfg).expect("repaired prism slices");
    assert_eq!(layers.len(), 20);
    // The regular 64-gon's area; its corners are rounded to 1 um (at most 1 um x perimeter).
    let (n, r_um) = (64.0, 10_000.0);
    let area = n / 2.0 * r_um * r_um * (2.0 * PI / n).sin();
    let perimeter = n * 2.0 * r_um * (PI / n).sin();
    for l in &layers {
        let z = f64::from(l.z_um);
        // 125 segments, and the 128 points of the whole prism's section: each bridge keeps
        // both ends of its gap.
        assert_eq!(l.segments as usize, crossings_f64(&tris, z).len());
        assert_eq!(l.segments, 125, "layer {}", l.index);
        assert_same_points(l, &crossings_f64(&full, z), "repaired prism");
        assert_eq!(l.loops.len(), 1);
        assert!(!l.loops[0].hole);
        assert!((l.area_um2() as f64 - area).abs() <= perimeter, "layer {}", l.index);
        let r = l.repairs;
        assert_eq!((r.dropped_chains, r.gaps_closed + r.tolerance_joins), (0, 3), "{r:?}");
    }
    assert_eq!((stats.peak_segments, stats.peak_points), (125, 128));
    assert!(stats.repairs.gaps_closed >= 40, "{:?}", stats.repairs);
    // One point short: the typed error, in the first layer; the segments alone fit.
    let short = SliceError::Capacity { what: Resource::ContourPoints, capacity: 127, layer: 0 };
    assert_eq!(run::<256, 127, 4>(&tris, cfg).map(|_| ()), Err(short));
    let short = SliceError::Capacity { what: Resource::ContourPoints, capacity: 125, layer: 0 };
    assert_eq!(run::<256, 125, 4>(&tris, cfg).map(|_| ()), Err(short));
    let full_cut = SliceError::Capacity { what: Resource::Segments, capacity: 124, layer: 0 };
    assert_eq!(run::<256, 124, 4>(&tris, cfg).map(|_| ()), Err(full_cut));
}
