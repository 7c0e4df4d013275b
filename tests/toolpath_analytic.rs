//! Toolpaths of analytic parts against independent f64 models: extruded volume, containment
//! of every extrusion in the contour shrunk by half a line width, coverage of top surfaces,
//! solid first and last layers, a bridge and bottom skins over a gap, skins around a pocket.

mod toolpath_support;

use std::f64::consts::PI;

use strata::geom::Point2;
use strata::machine::{InfillPattern, MachineConfig, PrintSettings};
use strata::toolpath::{Feature, ToolpathConfig};
use strata_testkit::check::{pt, seg_seg_dist};
use strata_testkit::mesh::{cuboid, four_holed_discs, holed_block, holed_prism, loft, ngon, to_um};
use toolpath_support::{default_run, extrusions, layer_starts, run, run_cfg, TpLayer, TpRun};

const W: f64 = 450.0; // line width, um
const H: f64 = 200.0; // layer height, um

/// Filament cross-section in um^2 (1.75 mm).
fn filament_area() -> f64 {
    PI * 875.0 * 875.0
}

/// [`toolpath_support::check_containment`] at the line width.
fn check_containment(run: &TpRun, what: &str, tol: f64, every: usize) {
    toolpath_support::check_containment(run, what, W, tol, every);
}

/// Covered fraction and area (mm^2) of layer `l`'s top surface, lines one line width wide.
fn top_coverage(run: &TpRun, l: usize) -> (f64, f64) {
    let c = toolpath_support::top_coverage(run, l, W);
    (c.fraction, c.area_mm2)
}

fn features(l: &TpLayer) -> Vec<Feature> {
    let mut f: Vec<Feature> = l.moves.iter().filter(|m| m.e_um > 0).map(|m| m.feature).collect();
    f.sort_by_key(|x| *x as u8);
    f.dedup();
    f
}

/// First and last layers: infill only solid (no sparse lines).
fn check_solid_ends(run: &TpRun, what: &str) {
    for l in [run.layers.first().unwrap(), run.layers.last().unwrap()] {
        let f = features(l);
        assert!(
            !f.contains(&Feature::InternalInfill),
            "{what} layer {}: sparse infill {f:?}",
            l.index
        );
    }
}

#[test]
fn cube_20mm_extrudes_the_volume_of_its_perimeters_skins_and_infill() {
    let r = default_run(&cuboid([100.0, 100.0, 0.0], [120.0, 120.0, 20.0]));
    assert_eq!(r.layers.len(), 100);
    assert_eq!(r.stray, 0);
    // The model (um): two square perimeter loops per layer at 0.5 w and 1.5 w inside the
    // 20 mm square; the infill domain is the square shrunk by the infill inset (2 w + w/2 -
    // overlap, overlap w/4); lines across it one line spacing apart (solid) or every 5th
    // (20 %), each line as long as its chord, plus zigzag connectors along the domain
    // boundary that cover half of it. Solid: the 4 bottom and 4 top layers.
    let cfg = ToolpathConfig::new(&MachineConfig::default(), &PrintSettings::default());
    let side = 20_000.0;
    let perims = 4.0 * (side - W) + 4.0 * (side - 3.0 * W);
    let a = side - 2.0 * f64::from(cfg.infill_inset_um());
    let spacing = 636.0 / 2f64.sqrt(); // round(450 sqrt 2) along the diagonal
    let connectors = 2.0 * a;
    let solid = a * a / spacing + connectors;
    let sparse = a * a / (5.0 * spacing) + connectors;
    let expect = 100.0 * perims * W * H + (8.0 * solid + 92.0 * sparse) * W * H;
    let mut got = 0.0;
    let mut per_feature = std::collections::BTreeMap::<u8, f64>::new();
    for l in &r.layers {
        for m in &l.moves {
            if m.e_um > 0 && m.feature != Feature::Skirt && m.feature != Feature::Unretract {
                got += f64::from(m.e_um) * filament_area();
                *per_feature.entry(m.feature as u8).or_default() +=
                    f64::from(m.e_um) * filament_area();
            }
        }
    }
    let perim_got =
        per_feature[&(Feature::ExternalPerimeter as u8)] + per_feature[&(Feature::Perimeter as u8)];
    let perim_expect = 100.0 * perims * W * H;
    assert!(
        (perim_got - perim_expect).abs() < perim_expect * 0.005,
        "perimeters {perim_got:.4e} vs {perim_expect:.4e}"
    );
    let err = (got - expect) / expect;
    eprintln!(
        "cube volume {:.1} mm^3, model {:.1} mm^3 ({:+.2} %)",
        got / 1e9,
        expect / 1e9,
        err * 100.0
    );
    assert!(err.abs() < 0.03, "volume {got:.4e} vs {expect:.4e} ({:+.2} %)", err * 100.0);
    // Every layer: two perimeter loops and one continuous infill run (the skirt on layer 0).
    for l in &r.layers {
        let want = if l.index == 0 { 4 } else { 3 };
        assert_eq!(l.stats.paths, want, "layer {}", l.index);
        assert_eq!(l.stats.stops, want, "layer {}", l.index);
    }
    assert_eq!(r.stats.retractions, 1, "only the skirt-to-part travel leaves the part");
    check_solid_ends(&r, "cube");
}

#[test]
fn extrusions_stay_inside_the_contour_shrunk_by_half_a_line() {
    let c = 110.0;
    let cube = to_um(&cuboid([100.0, 100.0, 0.0], [120.0, 120.0, 6.0]));
    let r = run(&cube, &PrintSettings::default());
    check_containment(&r, "cube", 15.0, 1);
    // A hexagonal prism with a round hole, a cylinder, a thin-walled tube and a comb.
    let outer = ngon(6, c, c, 12.0, 0.2);
    let hole = ngon(6, c + 2.0, c - 1.0, 4.0, 0.7);
    let r = run(&to_um(&holed_prism(&outer, &hole, 0.0, 3.0)), &PrintSettings::default());
    check_containment(&r, "holed hexagon", 15.0, 1);
    let cyl = loft(&[(0.0, ngon(64, c, c, 8.0, 0.0)), (3.0, ngon(64, c, c, 8.0, 0.0))]);
    let r = run(&to_um(&cyl), &PrintSettings::default());
    check_containment(&r, "cylinder", 15.0, 1);
    let tube = holed_prism(&ngon(48, c, c, 6.0, 0.0), &ngon(48, c, c, 5.2, 0.0), 0.0, 2.0);
    let r = run(&to_um(&tube), &PrintSettings::default());
    check_containment(&r, "tube", 15.0, 1);
    let mut comb = Vec::new();
    for (k, w) in [0.3, 0.6, 0.9, 1.2, 2.0].iter().enumerate() {
        let x = 100.0 + 4.0 * k as f64;
        comb.extend(cuboid([x, 100.0, 0.0], [x + w, 110.0, 2.0]));
    }
    comb.extend(cuboid([100.0, 95.0, 0.0], [120.0, 100.0, 2.0]));
    let r = run(&to_um(&comb), &PrintSettings::default());
    check_containment(&r, "comb", 15.0, 1);
}

#[test]
fn top_surfaces_of_a_cube_and_a_stepped_block_are_covered() {
    let r = default_run(&cuboid([100.0, 100.0, 0.0], [120.0, 120.0, 5.0]));
    let last = r.layers.len() - 1;
    let (cov, area) = top_coverage(&r, last);
    eprintln!("cube top: {:.3} % of {area:.1} mm^2", cov * 100.0);
    assert!(cov >= 0.99, "cube top coverage {cov}");
    assert!((area - 400.0).abs() < 2.0, "{area}");
    // Steps: 30 x 30 x 3, 20 x 20 x 3 on it, 10 x 10 x 3 on top.
    let mut steps = cuboid([95.0, 95.0, 0.0], [125.0, 125.0, 3.0]);
    steps.extend(cuboid([100.0, 100.0, 3.0], [120.0, 120.0, 6.0]));
    steps.extend(cuboid([105.0, 105.0, 6.0], [115.0, 115.0, 9.0]));
    let r = default_run(&steps);
    assert_eq!(r.layers.len(), 45);
    let mut tops = 0;
    for l in 0..r.layers.len() {
        let (cov, area) = top_coverage(&r, l);
        if area < 1.0 {
            continue;
        }
        tops += 1;
        eprintln!("steps layer {l}: top {area:.1} mm^2 covered {:.3} %", cov * 100.0);
        assert!(cov >= 0.99, "steps layer {l}: top coverage {cov}");
        // The layer right under each step's top is all top solid where exposed.
        assert!(features(&r.layers[l]).contains(&Feature::TopSolidInfill), "layer {l}");
    }
    assert_eq!(tops, 3, "three top surfaces (14, 29, 44)");
    // Solid skins: the top layer of each step and the 3 under it are solid where exposed
    // (the top one labelled top solid, the lowest one an internal bridge over the sparse
    // infill below); the layer below them has sparse infill only.
    assert!(features(&r.layers[11]).contains(&Feature::BridgeInfill), "layer 11");
    assert!(!features(&r.layers[11]).contains(&Feature::SolidInfill), "layer 11");
    for l in [12, 13] {
        assert!(features(&r.layers[l]).contains(&Feature::SolidInfill), "layer {l}");
        assert!(!features(&r.layers[l]).contains(&Feature::BridgeInfill), "layer {l}");
    }
    let f10 = features(&r.layers[10]);
    assert!(!f10.contains(&Feature::SolidInfill) && f10.contains(&Feature::InternalInfill));
    check_solid_ends(&r, "steps");
    check_containment(&r, "steps", 15.0, 3);
}

#[test]
fn bridge_plate_gets_bottom_skins_and_pocket_gets_top_skins() {
    // Two pillars with a plate on top: the plate's first 4 layers are solid over the gap.
    let mut bridge = cuboid([100.0, 100.0, 0.0], [104.0, 110.0, 4.0]);
    bridge.extend(cuboid([116.0, 100.0, 0.0], [120.0, 110.0, 4.0]));
    bridge.extend(cuboid([100.0, 100.0, 4.0], [120.0, 110.0, 8.0]));
    let r = default_run(&bridge);
    assert_eq!(r.layers.len(), 40);
    // Layers 20..24 are the plate's bottom over the gap (x in 104..116 mm): a bridge on the
    // first (over air), solid on the rest.
    let starts = layer_starts(&r);
    for (l, &start) in starts.iter().enumerate().take(24).skip(20) {
        let mid: Vec<_> = extrusions(&r.layers[l], start)
            .into_iter()
            .filter(|(a, b, _, _)| (106_000..114_000).contains(&((a.x + b.x) / 2)))
            .map(|s| s.2)
            .filter(|f| {
                matches!(f, Feature::InternalInfill | Feature::SolidInfill | Feature::BridgeInfill)
            })
            .collect();
        let want = if l == 20 { Feature::BridgeInfill } else { Feature::SolidInfill };
        assert!(!mid.is_empty() && mid.iter().all(|&f| f == want), "layer {l}: {mid:?}");
    }
    // Layer 27 (3 mm into the 4 mm plate): sparse in the middle.
    assert!(features(&r.layers[27]).contains(&Feature::InternalInfill));
    // A cube with a 10 x 10 mm pocket 4 mm deep from the top: the pocket floor (layer
    // under z = 6 mm) is a top surface, covered, and solid 4 layers down.
    let mut pocket = cuboid([100.0, 100.0, 0.0], [120.0, 120.0, 6.0]);
    let ring = |r: f64| {
        vec![
            [110.0 - r, 110.0 - r],
            [110.0 + r, 110.0 - r],
            [110.0 + r, 110.0 + r],
            [110.0 - r, 110.0 + r],
        ]
    };
    pocket.extend(holed_prism(&ring(10.0), &ring(5.0), 6.0, 10.0));
    let r = default_run(&pocket);
    assert_eq!(r.layers.len(), 50);
    let (cov, area) = top_coverage(&r, 29);
    eprintln!("pocket floor: {area:.1} mm^2 covered {:.3} %", cov * 100.0);
    assert!((area - 100.0).abs() < 2.0 && cov >= 0.99, "{area} {cov}");
    let (cov, area) = top_coverage(&r, 49);
    assert!((area - 300.0).abs() < 3.0 && cov >= 0.99, "{area} {cov}");
    // Under the pocket floor: an internal bridge over the sparse infill, then solid.
    assert!(features(&r.layers[26]).contains(&Feature::BridgeInfill), "layer 26");
    for l in 27..29 {
        assert!(features(&r.layers[l]).contains(&Feature::SolidInfill), "layer {l}");
    }
    assert!(features(&r.layers[29]).contains(&Feature::TopSolidInfill));
    assert!(!features(&r.layers[25]).contains(&Feature::SolidInfill));
    check_solid_ends(&r, "pocket");
}

#[test]
fn patterns_first_layer_and_settings() {
    let tris = to_um(&cuboid([100.0, 100.0, 0.0], [130.0, 130.0, 3.0]));
    for pattern in [InfillPattern::Lines, InfillPattern::Zigzag, InfillPattern::Grid] {
        let mut s = PrintSettings::default();
        s.infill_pattern = pattern;
        s.top_layers = 2;
        s.bottom_layers = 2;
        let r = run(&tris, &s);
        let sparse = &r.layers[7];
        let stops = sparse.stats.stops;
        eprintln!("{pattern:?}: layer 7 stops {stops}, retractions {}", r.stats.retractions);
        match pattern {
            // Lines: every line on its own, all in the same direction.
            InfillPattern::Lines => {
                assert!(stops > 10, "{stops}");
                let starts = layer_starts(&r);
                let dirs: Vec<i64> = extrusions(sparse, starts[7])
                    .iter()
                    .filter(|s| s.2 == Feature::InternalInfill)
                    .map(|(a, b, _, _)| {
                        i64::from(b.x - a.x).signum() + 2 * i64::from(b.y - a.y).signum()
                    })
                    .collect();
                assert!(dirs.windows(2).all(|w| w[0] == w[1]), "{dirs:?}");
            }
            // Zigzag: one continuous run.
            InfillPattern::Zigzag => assert_eq!(stops, 3),
            InfillPattern::Grid => assert!(stops <= 6, "{stops}"),
        }
        check_containment(&r, "patterns", 15.0, 3);
    }
    // First layer: 20 mm/s for every extrusion; skirt 3 mm out; other layers faster.
    let r = run(&tris, &PrintSettings::default());
    let l0 = &r.layers[0];
    assert_eq!(l0.height_um, 200);
    for m in l0.moves.iter().filter(|m| m.e_um > 0 && m.feature != Feature::Unretract) {
        assert_eq!(m.feed_mm_s, 20, "{m:?}");
    }
    let skirt: Vec<_> = l0.moves.iter().filter(|m| m.feature == Feature::Skirt).collect();
    assert!(!skirt.is_empty());
    for m in &skirt {
        // Outside the 100..130 mm square by 3 mm + w/2 (round corners further out).
        let (x, y) = (f64::from(m.to.x), f64::from(m.to.y));
        let dx = (100_000.0 - x).max(x - 130_000.0).max(0.0);
        let dy = (100_000.0 - y).max(y - 130_000.0).max(0.0);
        let d = (dx * dx + dy * dy).sqrt();
        assert!((d - 3_225.0).abs() < 20.0, "skirt point {x},{y} at {d}");
    }
    assert!(r.layers[5].moves.iter().any(|m| m.e_um > 0 && m.feed_mm_s > 20));
    // Outer perimeter last by default: within each island the external loop ends the walls.
    let walls: Vec<Feature> = r.layers[5]
        .moves
        .iter()
        .filter(|m| {
            m.e_um > 0 && matches!(m.feature, Feature::ExternalPerimeter | Feature::Perimeter)
        })
        .map(|m| m.feature)
        .collect();
    assert_eq!(walls.first(), Some(&Feature::Perimeter));
    assert_eq!(walls.last(), Some(&Feature::ExternalPerimeter));
    let mut cfg = ToolpathConfig::new(&MachineConfig::default(), &PrintSettings::default());
    cfg.outer_perimeter_last = false;
    let r = run_cfg(&tris, &PrintSettings::default(), cfg).unwrap();
    let first =
        r.layers[5].moves.iter().find(|m| m.e_um > 0 && m.feature != Feature::Unretract).unwrap();
    assert_eq!(first.feature, Feature::ExternalPerimeter);
}

#[test]
fn thin_parts_get_no_broken_perimeter_and_are_reported() {
    // A 0.3 mm fin next to a 5 mm block: the fin has no room for a 0.45 mm line.
    let mut parts = cuboid([100.0, 100.0, 0.0], [105.0, 105.0, 1.0]);
    parts.extend(cuboid([110.0, 100.0, 0.0], [110.3, 110.0, 1.0]));
    let r = default_run(&parts);
    for l in &r.layers {
        assert_eq!(l.stats.islands, 2);
        assert_eq!(l.stats.thin_islands, 1, "layer {}", l.index);
    }
    assert_eq!(r.stats.thin_islands, 5);
    check_containment(&r, "fin", 15.0, 1);
    // Nothing extruded near the fin.
    let starts = layer_starts(&r);
    for (l, s) in r.layers.iter().zip(starts) {
        for (a, b, f, _) in extrusions(l, s) {
            if f != Feature::Skirt {
                assert!(a.x < 106_000 && b.x < 106_000, "layer {}: {a:?}-{b:?}", l.index);
            }
        }
    }
}

/// Does travel a-b touch any contour edge of the layer?
fn crosses(loops: &[(Vec<Point2>, bool)], a: (f64, f64), b: (f64, f64)) -> bool {
    loops.iter().any(|(c, _)| {
        (0..c.len()).any(|k| seg_seg_dist(a, b, pt(c[k]), pt(c[(k + 1) % c.len()])) == 0.0)
    })
}

#[test]
fn travels_inside_the_part_need_no_retraction_and_leaving_it_retracts() {
    // Four separate holed discs (24-gons, 11.8 mm across, 2 mm holes), 12 mm apart.
    let c = 110.0;
    let plate = four_holed_discs(c, 2.0);
    let r = default_run(&plate);
    // Four separate rings (tiles do not touch): one island each per layer.
    assert_eq!(r.layers[3].stats.islands, 4);
    let retractions: u32 = r.layers.iter().map(|l| l.stats.retractions).sum();
    // 3 travels between islands per layer (10 layers) and the skirt's.
    assert_eq!(retractions, 3 * 10 + 1, "travels between islands retract");
    // A single holed part: no retraction after the skirt.
    let outer = ngon(8, c, c, 12.0, 0.3);
    let hole = ngon(8, c, c, 5.0, 0.1);
    let r = default_run(&holed_prism(&outer, &hole, 0.0, 4.0));
    assert_eq!(r.stats.retractions, 1, "only the skirt-to-part travel");
    // Every travel that crosses a contour happens while retracted or is combed around.
    for r in [default_run(&plate), r] {
        let starts = layer_starts(&r);
        for (l, start) in r.layers.iter().zip(starts) {
            let (mut pos, mut retracted) = (start, false);
            for m in &l.moves {
                match m.feature {
                    Feature::Retract => retracted = true,
                    Feature::Unretract => retracted = false,
                    Feature::Travel if m.to != pos => {
                        let long =
                            (f64::from(m.to.x - pos.x)).hypot(f64::from(m.to.y - pos.y)) >= 1_500.0;
                        if long && !retracted && l.index > 0 {
                            assert!(
                                !crosses(&l.contours, pt(pos), pt(m.to)),
                                "layer {}: travel {pos:?} -> {:?} crosses a contour unretracted",
                                l.index,
                                m.to
                            );
                        }
                    }
                    _ => {}
                }
                pos = m.to;
            }
        }
    }
}

/// Each layer's extrusions: time at their feeds (f64, from the moves' lengths), the slowest
/// and the fastest feed, mm/s.
fn extrusion_time_s(l: &TpLayer, start: Point2) -> (f64, f64, f64) {
    let (mut t, mut slow, mut fast, mut at) = (0.0, f64::MAX, 0.0f64, start);
    for m in &l.moves {
        let feed = m.feed_mm_s.to_num::<f64>();
        if m.e_um > 0 && m.to != at {
            let (a, b) = (pt(at), pt(m.to));
            t += ((b.0 - a.0).hypot(b.1 - a.1) / 1000.0) / feed;
            (slow, fast) = (slow.min(feed), fast.max(feed));
        }
        at = m.to;
    }
    (t, slow, fast)
}

#[test]
fn a_small_layer_is_slowed_to_the_minimum_layer_time() {
    // A 6 mm cube (its layers print in about 2 s at full speed) and a 40 mm plate (about 40 s).
    let settings = PrintSettings::default();
    let machine = MachineConfig::default();
    let min_s = 5.0;
    let mut cfg = ToolpathConfig::new(&machine, &settings);
    cfg.min_layer_time_ms = 5_000;
    let floor = cfg.min_print_speed_mm_s.to_num::<f64>();
    let small = to_um(&cuboid([107.0, 107.0, 0.0], [113.0, 113.0, 2.0]));
    let (fast, slow) = (run(&small, &settings), run_cfg(&small, &settings, cfg).unwrap());
    let (starts_fast, starts_slow) = (layer_starts(&fast), layer_starts(&slow));
    for k in 1..fast.layers.len() {
        let (t_full, _, full_feed) = extrusion_time_s(&fast.layers[k], starts_fast[k]);
        let (t, lowest, highest) = extrusion_time_s(&slow.layers[k], starts_slow[k]);
        assert!(t_full < min_s, "layer {k}: the cube's layer takes {t_full:.2} s at full speed");
        // Slowed to the minimum time (its estimate leaves travels out: at least as long), or to
        // the floor feed; never faster than at full speed.
        assert!(t >= min_s * 0.999 || lowest <= floor * 1.001, "layer {k}: {t:.2} s");
        assert!(t < min_s * 1.2, "layer {k}: slowed more than asked, {t:.2} s");
        assert!(lowest >= floor * 0.999 && highest <= full_feed * 1.001, "layer {k}");
    }
    let plate = to_um(&cuboid([90.0, 90.0, 0.0], [130.0, 130.0, 1.0]));
    let (a, b) = (run(&plate, &settings), run_cfg(&plate, &settings, cfg).unwrap());
    for (la, lb) in a.layers.iter().zip(&b.layers) {
        assert_eq!(la.moves, lb.moves, "a layer longer than the minimum time is not slowed");
    }
}

#[test]
fn a_layer_too_small_for_the_minimum_time_waits_the_rest_lifted_off_the_part() {
    // A 2 mm square column: about 1.5 s of extrusion per layer at the 10 mm/s floor.
    let settings = PrintSettings::default();
    let machine = MachineConfig::default();
    let mut cfg = ToolpathConfig::new(&machine, &settings);
    cfg.min_layer_time_ms = 5_000;
    let min_s = 5.0;
    let column = to_um(&cuboid([109.0, 109.0, 0.0], [111.0, 111.0, 2.0]));
    let r = run_cfg(&column, &settings, cfg).unwrap();
    let starts = layer_starts(&r);
    let floor = cfg.min_print_speed_mm_s.to_num::<f64>();
    for (k, l) in r.layers.iter().enumerate() {
        let (t, lowest, _) = extrusion_time_s(l, starts[k]);
        assert!(lowest <= floor * 1.001, "layer {k}: not at the floor feed ({lowest} mm/s)");
        // The layer ends: retraction, lift, wait.
        let n = l.moves.len();
        let [retract, lift, wait] = [l.moves[n - 3], l.moves[n - 2], l.moves[n - 1]];
        assert_eq!((retract.feature, retract.e_um), (Feature::Retract, -cfg.retract_length_um));
        assert_eq!(
            (lift.feature, lift.to, lift.z_um),
            (Feature::Travel, retract.to, l.z_um + 3_000)
        );
        assert_eq!(
            (wait.feature, wait.to, wait.z_um, wait.e_um),
            (Feature::Dwell, lift.to, lift.z_um, 0)
        );
        // Extrusions at their feeds plus the wait: the minimum time, more by at most the whole
        // ms the wait is rounded up to and the um each segment's length is rounded down to in
        // the estimate (at the floor feed).
        let total = t + wait.feed_mm_s.to_num::<f64>();
        let segments = l.moves.iter().filter(|m| m.e_um > 0).count() as f64;
        let over = 0.001 + segments * 0.001 / floor;
        assert!(total >= min_s - 1e-6 && total <= min_s + over, "layer {k}: {total:.4} s");
        // The next layer goes back down before it extrudes.
        if let Some(next) = r.layers.get(k + 1) {
            let first_print =
                next.moves.iter().find(|m| m.e_um > 0 && m.feature != Feature::Unretract);
            assert_eq!(first_print.map(|m| m.z_um), Some(next.z_um));
        }
    }
    // Below the build volume's top: the lift stops there.
    cfg.max_z_um = 1_000;
    let r = run_cfg(&column, &settings, cfg).unwrap();
    for l in &r.layers {
        let top = l.moves.iter().map(|m| m.z_um).max().unwrap();
        assert_eq!(top, (l.z_um + 3_000).min(1_000).max(l.z_um), "layer {}", l.index);
    }
}

/// The infill density is the percentage's, not the nearest "every k-th line": each percentage
/// from 5 to 100 puts more sparse infill into a plate than the one below it, for lines,
/// zigzag and grid. The oracle: the plate is a square turned 45 degrees, so every infill line
/// (45 and 135 degrees) crosses it at one length, and a direction's sparse lines among its n
/// solid-spacing lines grow by more than n * f - 2 > 0 from one percentage to the next, f the
/// share of a percent a direction takes (1 / 100; a grid's two directions 1 / 200 each):
/// n = 212 at 0.4 mm lines on the 85 mm plate, 480 at 0.25 mm on the 120 mm one for the grid.
#[test]
fn every_infill_percentage_prints_more_sparse_infill_than_the_one_below() {
    let cases = [
        (InfillPattern::Lines, 60.0, 400),
        (InfillPattern::Zigzag, 60.0, 400),
        (InfillPattern::Grid, 85.0, 250),
    ];
    for (pattern, half_diagonal_mm, line_width_um) in cases {
        let (c, r) = (110.0, half_diagonal_mm);
        let corners = [[c + r, c], [c, c + r], [c - r, c], [c, c - r]];
        let plate = to_um(&strata_testkit::mesh::prism(&corners, 0.0, 0.6));
        let mut settings = PrintSettings::default();
        (settings.top_layers, settings.bottom_layers) = (1, 1);
        (settings.infill_pattern, settings.line_width_um) = (pattern, line_width_um);
        let mut below = 0i64;
        for percent in 5..=100u8 {
            settings.infill_percent = percent;
            let sparse: i64 = run(&plate, &settings)
                .layers
                .iter()
                .flat_map(|l| &l.moves)
                .filter(|m| m.feature == Feature::InternalInfill && m.e_um > 0)
                .map(|m| i64::from(m.e_um))
                .sum();
            assert!(sparse > below, "{pattern:?} {percent} %: {sparse} um of filament");
            below = sparse;
        }
    }
}

/// Distance (um) from `p` to the axis-aligned square [`lo`, `hi`]^2 (um), 0 inside: the
/// distance to a square is the distance to its nearest edge or corner.
fn square_dist(p: (f64, f64), lo: (f64, f64), hi: (f64, f64)) -> f64 {
    let dx = (lo.0 - p.0).max(p.0 - hi.0).max(0.0);
    let dy = (lo.1 - p.1).max(p.1 - hi.1).max(0.0);
    dx.hypot(dy)
}

/// The loops one feature's extrusions draw on a layer, in print order: each a run of
/// consecutive extrusions of `feature` (its first point where the run starts), and whether it
/// ends where it starts.
fn feature_loops(l: &TpLayer, start: Point2, feature: Feature) -> Vec<(Vec<(f64, f64)>, bool)> {
    let (mut out, mut pos, mut open) = (Vec::new(), start, false);
    for m in &l.moves {
        let draws = m.e_um > 0 && m.feature == feature && m.to != pos;
        if draws {
            if !open {
                out.push(vec![pt(pos)]);
            }
            out.last_mut().unwrap().push(pt(m.to));
        }
        // Priming in place (an unretraction) does not break a run.
        open = draws || (open && m.to == pos && m.feature == Feature::Unretract);
        pos = m.to;
    }
    out.into_iter()
        .map(|mut p| {
            let closed = p.len() > 3 && p.first() == p.last();
            if closed {
                p.pop();
            }
            (p, closed)
        })
        .collect()
}

/// Length (um) of a closed loop.
fn loop_len(p: &[(f64, f64)]) -> f64 {
    (0..p.len())
        .map(|i| (p[(i + 1) % p.len()].0 - p[i].0).hypot(p[(i + 1) % p.len()].1 - p[i].1))
        .sum()
}

/// The brim (`--brim`): on the first layer only, floor(width / line width) closed loops around
/// a 20 mm cube, loop k's every vertex (k + 1/2) line widths from the square (round corners:
/// the distance to the square, f64), its chords no closer than the tolerances allow (10 um
/// simplification, 4 um arcs), outermost first and before the part; their length the rounded
/// squares' 4 s + 2 pi d each within 1 %. With a skirt, the skirt goes first, its distance
/// counted from the brim's outer edge.
#[test]
fn a_brim_rings_the_first_layer_with_whole_loops_outermost_first() {
    let (lo, hi) = ((100_000.0, 100_000.0), (120_000.0, 120_000.0));
    let cube = to_um(&cuboid([100.0, 100.0, 0.0], [120.0, 120.0, 1.0]));
    let settings = PrintSettings::default();
    let mut cfg = ToolpathConfig::new(&MachineConfig::default(), &settings);
    (cfg.brim_width_um, cfg.skirt_loops) = (5_000, 0);
    assert_eq!(cfg.line_width_um, 450);
    // 11 x 0.45 = 4.95 mm fit in 5 mm; a 12th would reach 5.4 mm.
    let n = 11;
    assert_eq!(cfg.brim_loops(), n);
    let r = run_cfg(&cube, &settings, cfg).unwrap();
    let starts = layer_starts(&r);
    let loops = feature_loops(&r.layers[0], starts[0], Feature::Brim);
    assert_eq!(loops.len(), n as usize, "one run per loop");
    let mut want_len = 0.0;
    for (i, (p, closed)) in loops.iter().enumerate() {
        assert!(closed, "loop {i} is not closed");
        // Outermost first: loop i is k = n - 1 - i.
        let d = (f64::from(n - 1 - i as i32) + 0.5) * W;
        for (j, &q) in p.iter().enumerate() {
            let got = square_dist(q, lo, hi);
            assert!((got - d).abs() <= 3.0, "loop {i} vertex {q:?} at {got:.1} um, not {d}");
            let b = p[(j + 1) % p.len()];
            let mid = square_dist(((q.0 + b.0) / 2.0, (q.1 + b.1) / 2.0), lo, hi);
            assert!(mid >= d - 15.0 && mid <= d + 3.0, "loop {i} chord at {mid:.1} um, not {d}");
        }
        want_len += 4.0 * 20_000.0 + 2.0 * PI * d;
    }
    let got_len: f64 = loops.iter().map(|(p, _)| loop_len(p)).sum();
    assert!((got_len - want_len).abs() < want_len * 0.01, "{got_len:.0} um vs {want_len:.0} um");
    // Before the part, on the first layer only.
    let l0 = &r.layers[0].moves;
    let last_brim = l0.iter().rposition(|m| m.feature == Feature::Brim).unwrap();
    let first_part = l0
        .iter()
        .position(|m| m.e_um > 0 && m.feature != Feature::Brim && m.feature != Feature::Unretract);
    assert!(first_part.unwrap() > last_brim);
    for l in &r.layers[1..] {
        assert!(l.moves.iter().all(|m| m.feature != Feature::Brim), "layer {}", l.index);
    }
    // With the default skirt: one loop 3 mm + w/2 beyond the brim's outer edge (11 w out),
    // printed first; the brim as before.
    cfg.skirt_loops = 1;
    let r = run_cfg(&cube, &settings, cfg).unwrap();
    let skirt = feature_loops(&r.layers[0], starts[0], Feature::Skirt);
    assert_eq!(skirt.len(), 1);
    let d = 3_000.0 + f64::from(n) * W + W / 2.0;
    for &q in &skirt[0].0 {
        let got = square_dist(q, lo, hi);
        assert!((got - d).abs() <= 3.0, "skirt vertex {q:?} at {got:.1} um, not {d}");
    }
    let first = r.layers[0].moves.iter().find(|m| m.e_um > 0 && m.feature != Feature::Unretract);
    assert_eq!(first.map(|m| m.feature), Some(Feature::Skirt));
    let with_skirt = feature_loops(&r.layers[0], starts[0], Feature::Brim);
    assert_eq!(with_skirt.len(), loops.len());
    for ((a, _), (b, _)) in with_skirt.iter().zip(&loops) {
        let mut b_sorted = b.clone();
        let mut a_sorted = a.clone();
        a_sorted.sort_by(|x, y| x.partial_cmp(y).unwrap());
        b_sorted.sort_by(|x, y| x.partial_cmp(y).unwrap());
        assert_eq!(a_sorted, b_sorted, "the same loops (entered elsewhere)");
    }
}

/// Two 10 mm cubes 1 mm apart with a 3 mm brim (6 loops): their brims merge (from the
/// second loop, 675 um out, on: 2 x 675 > 1,000), no brim point lies in either cube, every
/// one is within the brim width of one, each loop's vertices at their loop's distance from
/// the nearer cube, and no two loops come closer than 0.9 line widths.
#[test]
fn brims_of_close_islands_merge_without_overlapping() {
    let a = ((100_000.0, 100_000.0), (110_000.0, 110_000.0));
    let b = ((111_000.0, 100_000.0), (121_000.0, 110_000.0));
    let mut parts = cuboid([100.0, 100.0, 0.0], [110.0, 110.0, 1.0]);
    parts.extend(cuboid([111.0, 100.0, 0.0], [121.0, 110.0, 1.0]));
    let settings = PrintSettings::default();
    let mut cfg = ToolpathConfig::new(&MachineConfig::default(), &settings);
    (cfg.brim_width_um, cfg.skirt_loops) = (3_000, 0);
    let r = run_cfg(&to_um(&parts), &settings, cfg).unwrap();
    assert_eq!(r.layers[0].stats.islands, 2);
    let loops = feature_loops(&r.layers[0], layer_starts(&r)[0], Feature::Brim);
    let dist = |q: (f64, f64)| square_dist(q, a.0, a.1).min(square_dist(q, b.0, b.1));
    // Loops 5..1 around both cubes, then loop 0 around each: 7 runs.
    assert_eq!(loops.len(), 7);
    let mut merged = 0;
    for (p, closed) in &loops {
        assert!(closed);
        let d = dist(p[0]);
        let k = (d / W - 0.5).round();
        for (j, &q) in p.iter().enumerate() {
            let got = dist(q);
            assert!(got > W / 2.0 - 3.0, "{q:?} in or at a cube ({got:.1} um)");
            assert!(got <= 3_000.0, "{q:?} beyond the brim ({got:.1} um)");
            assert!((got - (k + 0.5) * W).abs() <= 3.0, "{q:?} at {got:.1} um, loop {k}");
            let e = p[(j + 1) % p.len()];
            let mid = dist(((q.0 + e.0) / 2.0, (q.1 + e.1) / 2.0));
            assert!(mid > W / 2.0 - 20.0 && mid <= 3_000.0, "chord from {q:?} at {mid:.1} um");
        }
        let around_both = p.iter().any(|q| q.0 < a.1 .0) && p.iter().any(|q| q.0 > b.0 .0);
        merged += usize::from(around_both);
    }
    assert_eq!(merged, 5, "loops 1 to 5 go around both cubes");
    let mut closest = f64::MAX;
    for (i, (p, _)) in loops.iter().enumerate() {
        for (q, _) in &loops[i + 1..] {
            for s in 0..p.len() {
                for t in 0..q.len() {
                    let d = seg_seg_dist(p[s], p[(s + 1) % p.len()], q[t], q[(t + 1) % q.len()]);
                    closest = closest.min(d);
                }
            }
        }
    }
    assert!(closest >= 0.9 * W, "loops {closest:.1} um apart");
}

/// A 20 mm square tube with a 10 mm hole: the brim goes around the outside only (every brim
/// point outside the outer square), one loop per 0.45 mm of the 3 mm.
#[test]
fn no_brim_inside_a_hole() {
    let tube = to_um(&holed_block(100.0, 120.0, 105.0, 115.0, 1.0));
    let settings = PrintSettings::default();
    let mut cfg = ToolpathConfig::new(&MachineConfig::default(), &settings);
    (cfg.brim_width_um, cfg.skirt_loops) = (3_000, 0);
    let r = run_cfg(&tube, &settings, cfg).unwrap();
    let loops = feature_loops(&r.layers[0], layer_starts(&r)[0], Feature::Brim);
    assert_eq!(loops.len(), 6);
    for (p, closed) in &loops {
        assert!(closed);
        for &q in p {
            let d = square_dist(q, (100_000.0, 100_000.0), (120_000.0, 120_000.0));
            assert!(
                d >= W / 2.0 - 3.0,
                "{q:?} {d:.1} um from the outside: in the tube or its hole"
            );
        }
    }
}

/// No brim by default, and a brim narrower than a line (0.4 mm at 0.45 mm lines: no loop fits)
/// changes nothing: the moves are those of the default run, whose only first-layer loops
/// besides the part's are its one skirt loop.
#[test]
fn a_brim_of_zero_or_under_a_line_adds_nothing() {
    let cube = to_um(&cuboid([100.0, 100.0, 0.0], [120.0, 120.0, 1.0]));
    let settings = PrintSettings::default();
    let cfg = ToolpathConfig::new(&MachineConfig::default(), &settings);
    assert_eq!((cfg.brim_width_um, cfg.brim_loops(), cfg.skirt_loops), (0, 0, 1));
    let plain = run_cfg(&cube, &settings, cfg).unwrap();
    let l0 = &plain.layers[0];
    assert!(l0.moves.iter().all(|m| m.feature != Feature::Brim));
    assert_eq!(feature_loops(l0, Point2::new(0, 0), Feature::Skirt).len(), 1);
    // Skirt, two perimeters, the infill run.
    assert_eq!(l0.stats.paths, 4);
    let mut narrow = cfg;
    narrow.brim_width_um = 400;
    assert_eq!(narrow.brim_loops(), 0);
    let r = run_cfg(&cube, &settings, narrow).unwrap();
    let moves = |r: &TpRun| r.layers.iter().flat_map(|l| l.moves.clone()).collect::<Vec<_>>();
    assert_eq!(moves(&r), moves(&plain));
}
