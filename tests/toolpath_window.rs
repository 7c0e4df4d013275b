//! The skin window keeps a built layer's contours, needed only for the bottom skins above
//! it, simplified again within `below_tolerance_um`: the window's words drop, the toolpaths
//! of a part whose bottom skins lie inside its perimeters stay the same move for move, and an
//! overhang still gets its bottom skins.

mod toolpath_support;

use strata::geom::Point2;
use strata::machine::{MachineConfig, PrintSettings};
use strata::toolpath::{Feature, ToolpathConfig};
use strata_testkit::check;
use strata_testkit::mesh::{holed_prism, loft, ngon, to_um, torus, TriMm};
use toolpath_support::{extrusions, layer_starts, run_cfg, TpRun};

/// A finely tessellated upright cylinder (a 400-gon, 20 mm across), `h` mm tall, at (110, 110).
fn cylinder(r: f64, z0: f64, z1: f64) -> Vec<TriMm> {
    let ring = ngon(400, 110.0, 110.0, r, 0.0);
    loft(&[(z0, ring.clone()), (z1, ring)])
}

/// The stage's configuration for `settings`, built layers kept within `below` um.
fn config(settings: &PrintSettings, below: i32) -> ToolpathConfig {
    let mut cfg = ToolpathConfig::new(&MachineConfig::default(), settings);
    cfg.below_tolerance_um = below;
    cfg
}

fn run(mesh: &[TriMm], below: i32) -> TpRun {
    let mut tris = to_um(mesh);
    tris.sort_by_key(|t| t.z_min());
    let settings = PrintSettings::default();
    run_cfg(&tris, &settings, config(&settings, below)).expect("toolpath run")
}

#[test]
fn coarser_built_layers_take_fewer_words_and_leave_a_cylinder_as_it_was() {
    let mesh = cylinder(10.0, 0.0, 4.0);
    let (fine, coarse) = (run(&mesh, 0), run(&mesh, 200));
    let words = |r: &TpRun| r.stats.needs.ring_points;
    // 4 of the 10 layers in the window are built ones: the 400 points of each (10 um
    // apart in chord height) come down to a few dozen.
    assert!(
        (words(&coarse) as f64) < 0.75 * words(&fine) as f64,
        "{} words, {} without",
        words(&coarse),
        words(&fine)
    );
    // The region below differs from the layer by slivers under the perimeters: the same
    // infill, the same moves.
    assert_eq!(fine.layers.len(), coarse.layers.len());
    for (a, b) in fine.layers.iter().zip(&coarse.layers) {
        assert!(a.moves == b.moves, "layer {} differs", a.index);
    }
}

#[test]
fn an_overhang_over_a_coarsened_layer_still_gets_its_bottom_skins() {
    // A ring 8..16 mm in radius from 4 mm to 6 mm, standing on a cylinder of 10 mm radius:
    // the ring's part beyond 10 mm is over air for its first layers.
    let mut mesh = cylinder(10.0, 0.0, 4.0);
    mesh.extend(holed_prism(
        &ngon(400, 110.0, 110.0, 16.0, 0.0),
        &ngon(400, 110.0, 110.0, 8.0, 0.0),
        4.0,
        6.0,
    ));
    for below in [0, 200] {
        let r = run(&mesh, below);
        assert_eq!(r.layers.len(), 30);
        let starts = layer_starts(&r);
        // Layers 20..24 (the ring's first four): every infill line over the air (radius
        // 11 to 14 mm, clear of the perimeters) is a bridge on the first, solid on the rest.
        for (l, &start) in starts.iter().enumerate().take(24).skip(20) {
            let over_air: Vec<Feature> = extrusions(&r.layers[l], start)
                .into_iter()
                .filter(|(a, b, _, _)| {
                    let (x, y) =
                        ((a.x + b.x) as f64 / 2e3 - 110.0, (a.y + b.y) as f64 / 2e3 - 110.0);
                    (11.0..14.0).contains(&x.hypot(y))
                })
                .map(|s| s.2)
                .filter(|f| {
                    matches!(
                        f,
                        Feature::InternalInfill | Feature::SolidInfill | Feature::BridgeInfill
                    )
                })
                .collect();
            let want = if l == 20 { Feature::BridgeInfill } else { Feature::SolidInfill };
            assert!(
                !over_air.is_empty() && over_air.iter().all(|&f| f == want),
                "below {below} um, layer {l}: {over_air:?}"
            );
        }
    }
}

/// Exposed bottom surface of layer `l` (its region outside the layer below) of `r`, mm^2,
/// and the part of it the layer's extrusions cover, lines 0.45 mm wide.
fn bottom_cover(r: &TpRun, l: usize) -> (f64, f64) {
    let layer = &r.layers[l];
    let lines: Vec<(Point2, Point2)> = extrusions(layer, layer_starts(r)[l])
        .into_iter()
        .filter(|e| e.2 != Feature::Skirt)
        .map(|(a, b, _, _)| (a, b))
        .collect();
    let below = &r.layers[l - 1].contours[..];
    let c = check::top_coverage(&layer.contours, Some(below), &lines, 450.0);
    (c.area_mm2, c.area_mm2 * c.fraction)
}

#[test]
fn a_torus_lower_half_keeps_its_bottom_surfaces_covered() {
    // Every layer of the lower half overhangs the one below it (a 12 mm ring of 3 mm tube).
    let mesh = torus([110.0, 110.0, 3.0], 6.0, 3.0, 96, 48);
    let (fine, coarse) = (run(&mesh, 0), run(&mesh, 225));
    let (mut area, mut covered) = ([0.0; 2], [0.0; 2]);
    for l in (2..15).step_by(3) {
        for (k, r) in [&fine, &coarse].into_iter().enumerate() {
            let (a, c) = bottom_cover(r, l);
            area[k] += a;
            covered[k] += c;
        }
    }
    let share = |k: usize| covered[k] / area[k];
    eprintln!(
        "bottom surfaces: {:.1} mm^2, covered {:.2} % ({:.2} % with every layer kept whole)",
        area[1],
        100.0 * share(1),
        100.0 * share(0)
    );
    assert!(area[0] > 20.0 && (area[0] - area[1]).abs() < 1e-9);
    assert!(share(1) >= share(0) - 0.005, "{:.4} against {:.4}", share(1), share(0));
}
