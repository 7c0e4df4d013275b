//! Parts thinner than a line width are reported, per layer and in total, as the area of the
//! layer's cross-section minus its opening by half a line width (inwards w/2, outwards w/2,
//! both exact integer offsets with square corners).
//!
//! Tolerance: the contours of these prisms have um-exact vertices and square corners, so the
//! opening of a rectangle is the rectangle itself; the only error is that each offset pass
//! rounds its output vertices to the um grid (at most 0.5 um per coordinate, and the
//! clean-up pass removes only points within 2 um of a straight edge), so every edge of the
//! opening moves by at most ~1 um and its area by at most `perimeter x 1 um` (per layer).

mod toolpath_support;

use strata::machine::{MachineConfig, PrintSettings};
use strata::toolpath::{Feature, ToolpathConfig};
use strata_testkit::mesh::{cuboid, prism, to_um};
use strata_testkit::models::{load_placed, shared_models};
use toolpath_support::{default_run, extrusions, layer_starts, run_cfg, run_sized};

/// A 10 mm block with a 0.3 mm x 5 mm fin on its right side (mm, counter-clockwise).
const FIN_BLOCK: [[f64; 2]; 8] = [
    [100.0, 100.0],
    [110.0, 100.0],
    [110.0, 104.85],
    [115.0, 104.85],
    [115.0, 105.15],
    [110.0, 105.15],
    [110.0, 110.0],
    [100.0, 110.0],
];

#[test]
fn a_fin_on_a_block_is_reported_with_its_area() {
    // A 10 mm block with a 0.3 mm x 5 mm fin on its right side (one island, one loop), 1 mm
    // tall: 5 layers. The fin is thinner than the 0.45 mm line: nothing can print it.
    let poly = FIN_BLOCK;
    let r = default_run(&prism(&poly, 0.0, 1.0));
    assert_eq!(r.layers.len(), 5);
    // Fin area 5 mm x 0.3 mm; tolerance: the block-and-fin outline (50.6 mm) x 1 um.
    let fin = 1.5e6;
    let tol = 50_600.0;
    for l in &r.layers {
        assert_eq!((l.stats.islands, l.stats.thin_islands), (1, 0), "layer {}", l.index);
        let a = l.stats.thin_area_um2 as f64;
        assert!((a - fin).abs() <= tol, "layer {}: thin area {a} um^2", l.index);
    }
    let total = r.stats.thin_area_um2 as f64;
    eprintln!(
        "fin: per layer {:?} um^2",
        r.layers.iter().map(|l| l.stats.thin_area_um2).collect::<Vec<_>>()
    );
    assert!((total - 5.0 * fin).abs() <= 5.0 * tol, "total {total}");
    assert!((r.stats.max_thin_area_um2 as f64 - fin).abs() <= tol);
    // And indeed nothing is extruded in the fin (beyond the block's edge plus rounding).
    let starts = layer_starts(&r);
    for (l, s) in r.layers.iter().zip(starts) {
        for (a, b, f, _) in extrusions(l, s) {
            if f != Feature::Skirt {
                assert!(a.x <= 110_000 && b.x <= 110_000, "layer {}: {a:?}-{b:?}", l.index);
            }
        }
    }
}

#[test]
fn a_wide_fin_is_printed_and_not_reported() {
    // The same block with a 1 mm fin (more than two lines): printable, nothing thin.
    let poly = [
        [100.0, 100.0],
        [110.0, 100.0],
        [110.0, 104.5],
        [115.0, 104.5],
        [115.0, 105.5],
        [110.0, 105.5],
        [110.0, 110.0],
        [100.0, 110.0],
    ];
    let r = default_run(&prism(&poly, 0.0, 1.0));
    // Outline 52 mm x 1 um.
    for l in &r.layers {
        assert!(l.stats.thin_area_um2 <= 52_000, "layer {}: {}", l.index, l.stats.thin_area_um2);
    }
    eprintln!("wide fin: total {} um^2", r.stats.thin_area_um2);
    let starts = layer_starts(&r);
    let reaches_fin = r.layers.iter().zip(starts).any(|(l, s)| {
        extrusions(l, s).iter().any(|&(a, _, f, _)| f != Feature::Skirt && a.x > 114_000)
    });
    assert!(reaches_fin);
}

#[test]
fn a_plain_cube_reports_no_thin_area() {
    // 20 mm cube: the opening of a square is the square; bound: outline 80 mm x 1 um.
    let r = default_run(&cuboid([100.0, 100.0, 0.0], [120.0, 120.0, 20.0]));
    assert_eq!(r.layers.len(), 100);
    for l in &r.layers {
        assert!(l.stats.thin_area_um2 <= 80_000, "layer {}: {}", l.index, l.stats.thin_area_um2);
    }
    eprintln!("cube: total {} um^2", r.stats.thin_area_um2);
    assert!(r.stats.thin_area_um2 <= 100 * 80_000, "{}", r.stats.thin_area_um2);
    assert_eq!(r.stats.thin_islands, 0);
}

#[test]
fn an_isolated_thin_wall_is_counted_as_an_island_and_by_area() {
    // A 0.3 mm x 10 mm wall next to a 5 mm block (two islands): the wall is a thin island
    // and its whole cross-section (3 mm^2 per layer) is thin area.
    let mut parts = cuboid([100.0, 100.0, 0.0], [105.0, 105.0, 1.0]);
    parts.extend(cuboid([110.0, 100.0, 0.0], [110.3, 110.0, 1.0]));
    let r = default_run(&parts);
    for l in &r.layers {
        assert_eq!((l.stats.islands, l.stats.thin_islands), (2, 1), "layer {}", l.index);
        // Wall 3 mm^2 exactly (nothing of it is opened); the block's outline 20 mm x 1 um.
        let a = l.stats.thin_area_um2 as f64;
        assert!((a - 3.0e6).abs() <= 20_000.0, "layer {}: {a}", l.index);
    }
    eprintln!("wall island: total {} um^2", r.stats.thin_area_um2);
    assert_eq!(r.stats.thin_islands, 5);
}

#[test]
fn a_stage_sized_to_the_printing_needs_prints_the_same_and_measures_in_bands() {
    // embodier_LM8UU_8p2pi: thin spiral fins. Printing needs PTS 690; growing the fins'
    // slivers back for the measurement needs 1,740. A stage with PTS 700 (the other
    // capacities well above the model's needs) prints exactly the same moves and measures
    // the fins in bands: the thin area is that of the host-sized run up to the output
    // loops' clean-up tolerance (2 um along the outlines: a few thousand um^2 a layer).
    let Some(dir) = shared_models() else { return };
    let machine = MachineConfig::default();
    let tris = load_placed(&dir.join("embodier_LM8UU_8p2pi.stl"), &machine);
    let settings = PrintSettings::default();
    let cfg = ToolpathConfig::new(&machine, &settings);
    let big = run_cfg(&tris, &settings, cfg).expect("host-sized run");
    assert_eq!(big.stats.thin_unmeasured, 0);
    assert!(big.stats.thin_pts > 1_000, "{}", big.stats.thin_pts);
    assert!(big.stats.needs.layer_points.max(big.stats.needs.offset_edges) <= 700);
    let small = run_sized::<700, 64, 1024, 4096, 8192, 8192>(&tris, &settings, cfg)
        .expect("a stage sized to the printing needs prints the model");
    assert_eq!(small.layers.len(), big.layers.len());
    let mut banded = 0;
    for (a, b) in small.layers.iter().zip(&big.layers) {
        assert_eq!(a.moves, b.moves, "layer {}", a.index);
        assert_eq!(a.stats.thin_unmeasured, 0, "layer {}", a.index);
        let (ta, tb) = (a.stats.thin_area_um2 as f64, b.stats.thin_area_um2 as f64);
        assert!((ta - tb).abs() <= 5_000.0 + 0.005 * tb, "layer {}: {ta} vs {tb}", a.index);
        banded += usize::from(ta != tb);
    }
    assert_eq!(small.stats.thin_unmeasured, 0);
    assert!(small.stats.thin_pts <= 700, "{}", small.stats.thin_pts);
    assert_eq!(small.stats.needs, big.stats.needs);
    eprintln!(
        "LM8UU: thin area {} um^2 (host), {} um^2 with PTS 700 ({banded} layers measured in \
         bands)",
        big.stats.thin_area_um2, small.stats.thin_area_um2
    );
}

#[test]
fn the_measurement_leaves_the_toolpaths_unchanged() {
    // The fin block of the first test and a model with thin slivers: the printer leaves the
    // measurement out (`measure_thin_area: false`), which must change only the figures.
    let poly = FIN_BLOCK;
    let fin = to_um(&prism(&poly, 0.0, 1.0));
    let machine = MachineConfig::default();
    let mut models = vec![("fin block", fin)];
    if let Some(dir) = shared_models() {
        models.push(("LM8UU", load_placed(&dir.join("embodier_LM8UU_8p2pi.stl"), &machine)));
    }
    let settings = PrintSettings::default();
    for (name, tris) in &models {
        let on = ToolpathConfig::new(&machine, &settings);
        assert!(on.measure_thin_area, "measured by default");
        let mut off = on;
        off.measure_thin_area = false;
        let a = run_cfg(tris, &settings, on).expect("measured run");
        let b = run_cfg(tris, &settings, off).expect("unmeasured run");
        assert!(a.stats.thin_area_um2 > 0, "{name}: the measured run finds thin area");
        assert_eq!(b.stats.thin_area_um2, 0, "{name}");
        assert_eq!(b.stats.thin_unmeasured, 0, "{name}");
        assert_eq!(a.layers.len(), b.layers.len(), "{name}");
        for (la, lb) in a.layers.iter().zip(&b.layers) {
            assert_eq!(la.moves, lb.moves, "{name}: layer {}", la.index);
        }
    }
}
