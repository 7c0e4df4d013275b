//! Bridges against the parts' own geometry: skin over no material of the layer below prints
//! as straight lines across the gap, anchored on both sides, at the bridge speed and with a
//! round thread's filament.

mod toolpath_support;

use strata::geom::Point2;
use strata::machine::{MachineConfig, PrintSettings, Rate};
use strata::toolpath::{Feature, ToolMove, ToolpathConfig, BRIDGE_SPEED_MM_S};
use strata_testkit::mesh::{bridge_part, to_um, TriMm};
use toolpath_support::{extrusions, layer_starts, run_cfg, run_cfg_bridge_limited, TpRun};

/// Line width and filament diameter of the default settings, um.
const W: f64 = 450.0;
const FILAMENT: f64 = 1750.0;

/// [`bridge_part`] at (100, 100) mm: two 10 x 10 x 10 mm posts 20 mm apart along x (along y
/// when `along_y`: mirrored about x = y), joined by a 2 mm plate on top as wide as the posts.
fn posts_and_plate(along_y: bool) -> Vec<TriMm> {
    let mut mesh = bridge_part(100.0, 100.0);
    if along_y {
        for tri in &mut mesh {
            for v in tri.iter_mut() {
                v.swap(0, 1);
            }
            // Mirrored: the other winding keeps the normals outwards.
            tri.swap(1, 2);
        }
    }
    mesh
}

fn run_with(mesh: &[TriMm], bridges: bool) -> TpRun {
    let settings = PrintSettings::default();
    let mut cfg = ToolpathConfig::new(&MachineConfig::default(), &settings);
    cfg.bridges = bridges;
    run_cfg(&to_um(mesh), &settings, cfg).expect("toolpath run")
}

/// The first layer above `z_um`.
fn layer_above(run: &TpRun, z_um: i32) -> usize {
    run.layers.iter().position(|l| l.z_um > z_um).expect("a layer above")
}

/// The moves of layer `l` that extrude, each with where it starts.
fn extruding_moves(run: &TpRun, l: usize) -> Vec<(Point2, ToolMove)> {
    let mut pos = layer_starts(run)[l];
    let mut out = Vec::new();
    for m in &run.layers[l].moves {
        if m.e_um > 0 && m.to != pos {
            out.push((pos, *m));
        }
        pos = m.to;
    }
    out
}

#[test]
fn a_20mm_bridge_between_two_posts_prints_straight_anchored_lines_at_bridge_speed() {
    for along_y in [false, true] {
        let what = if along_y { "gap along y" } else { "gap along x" };
        let run = run_with(&posts_and_plate(along_y), true);
        // (along the gap, across it) of a point: the gap is 110..130 mm along the first.
        let axes = |p: Point2| if along_y { (p.y, p.x) } else { (p.x, p.y) };
        let l = layer_above(&run, 10_000);
        let moves = extruding_moves(&run, l);
        let bridges: Vec<_> =
            moves.iter().filter(|(_, m)| m.feature == Feature::BridgeInfill).collect();
        assert!(!bridges.is_empty(), "{what}: no bridge on layer {l}");
        // Every extrusion crossing the gap's middle runs straight across it, resting on both
        // posts (its ends at least a line width onto them): the plate's perimeters along its
        // free sides (overhang perimeters, four: two loops a side) and bridge lines.
        let (mut across, mut overhangs) = (Vec::new(), 0);
        for &(from, m) in &moves {
            let ((a, a_side), (b, b_side)) = (axes(from), axes(m.to));
            if (a - 120_000).signum() == (b - 120_000).signum() {
                continue;
            }
            assert_eq!(a_side, b_side, "{what}: not straight: {from:?} -> {:?}", m.to);
            assert!(a.min(b) <= 110_000 - W as i32 && a.max(b) >= 130_000 + W as i32, "{what}");
            if m.feature == Feature::OverhangPerimeter {
                overhangs += 1;
                continue;
            }
            assert_eq!(m.feature, Feature::BridgeInfill, "{what}: {from:?} -> {:?}", m.to);
            across.push(a_side);
        }
        assert_eq!(overhangs, 4, "{what}");
        // The lines side by side, one line width apart, fill the plate between its
        // perimeters: two loops on each side (centres at 0.5 and 1.5 widths in).
        across.sort_unstable();
        across.dedup();
        // Lines on a grid one width apart: floor(inner / W) of them across, or one more.
        let inner = (100_000.0 + 2.0 * W, 110_000.0 - 2.0 * W);
        let fit = ((inner.1 - inner.0) / W).floor() as usize;
        assert!((fit..=fit + 1).contains(&across.len()), "{what}: {across:?}");
        for pair in across.windows(2) {
            assert!((f64::from(pair[1] - pair[0]) - W).abs() <= 2.0, "{what}: {pair:?}");
        }
        assert!(f64::from(across[0]) - inner.0 <= W, "{what}: {across:?}");
        assert!(inner.1 - f64::from(*across.last().unwrap()) <= W, "{what}: {across:?}");
        // Bridge speed, and the filament of a round thread one line wide.
        for (from, m) in &bridges {
            assert_eq!(m.feed_mm_s, Rate::from_num(BRIDGE_SPEED_MM_S), "{what}");
            let len = f64::from(m.to.x - from.x).hypot(f64::from(m.to.y - from.y));
            let want = len * (W / FILAMENT).powi(2);
            assert!((f64::from(m.e_um) - want).abs() <= 1.0 + want * 1e-3, "{what}: {m:?}");
        }
        // The layer above is ordinary solid skin.
        let above: Vec<_> = extrusions(&run.layers[l + 1], layer_starts(&run)[l + 1])
            .into_iter()
            .filter(|e| e.2 == Feature::BridgeInfill)
            .collect();
        assert!(above.is_empty(), "{what}: bridges on layer {}", l + 1);
    }
}

#[test]
fn without_bridges_the_gap_gets_ordinary_solid_skin() {
    let run = run_with(&posts_and_plate(false), false);
    let l = layer_above(&run, 10_000);
    let over_gap: Vec<Feature> = extruding_moves(&run, l)
        .into_iter()
        .filter(|(a, m)| (112_000..128_000).contains(&((a.x + m.to.x) / 2)))
        .map(|(_, m)| m.feature)
        .filter(|f| !matches!(f, Feature::ExternalPerimeter | Feature::Perimeter))
        .collect();
    assert!(!over_gap.is_empty() && over_gap.iter().all(|&f| f == Feature::SolidInfill));
    for layer in &run.layers {
        let bridge = |f| matches!(f, Feature::BridgeInfill | Feature::OverhangPerimeter);
        assert!(layer.moves.iter().all(|m| !bridge(m.feature)));
    }
}

/// A layer whose bridges need more path points or scanline crossings than the stage may use
/// is built without them (as solid skin), and the job goes on: bridges never make a model
/// that fits without them refused. Each limit in turn sits between the job's needs without
/// bridges and with them.
#[test]
fn bridges_beyond_the_limits_give_way_to_solid_skin() {
    let mesh = to_um(&posts_and_plate(false));
    let settings = PrintSettings::default();
    let mut cfg = ToolpathConfig::new(&MachineConfig::default(), &settings);
    let with = run_cfg(&mesh, &settings, cfg).expect("with bridges");
    cfg.bridges = false;
    let without = run_cfg(&mesh, &settings, cfg).expect("without bridges");
    cfg.bridges = true;
    let bridged = |r: &TpRun| {
        r.layers
            .iter()
            .filter(|l| l.moves.iter().any(|m| m.feature == Feature::BridgeInfill))
            .count()
    };
    assert!(bridged(&with) > 0 && bridged(&without) == 0);
    let (n0, n1) = (without.stats.needs, with.stats.needs);
    let cases = [
        ((n0.path_points as usize, usize::MAX), n1.path_points > n0.path_points),
        ((usize::MAX, n0.crossings as usize), n1.crossings > n0.crossings),
    ];
    let mut tried = 0;
    for (limits, bridges_need_more) in cases {
        if !bridges_need_more {
            continue;
        }
        tried += 1;
        let limited = run_cfg_bridge_limited(&mesh, &settings, cfg, limits).expect("limited");
        let l = limited.stats.needs;
        let within = l.path_points as usize <= limits.0 && l.crossings as usize <= limits.1;
        assert!(within, "{limits:?}: {l:?}");
        // Some layers lost their bridges, the others kept them; every layer printed.
        assert!(bridged(&limited) < bridged(&with), "{limits:?}");
        assert_eq!(limited.layers.len(), with.layers.len());
    }
    assert!(tried > 0, "bridges needed no more than solid skin: {n0:?} {n1:?}");
}

/// The printer's own jobs bridge too: the settings it derives from a job (what the 64 KB
/// board and the host's simulation of it run, bit-exact in `qemu_bridge_between_two_posts`)
/// print the plate's first layer as bridge lines at the bridge speed.
#[test]
fn the_printers_jobs_print_bridges() {
    let mut mesh = to_um(&posts_and_plate(false));
    mesh.sort_by_key(strata::geom::Triangle::z_min);
    let job = strata_testkit::drive::job_spec(&mesh);
    let cfg = strata::printer::job_toolpath_config(&MachineConfig::default(), &job);
    let run = run_cfg(&mesh, &job.settings, cfg).expect("toolpath run");
    let plate = layer_above(&run, 10_000);
    let bridge: Vec<_> = extruding_moves(&run, plate)
        .into_iter()
        .filter(|(_, m)| m.feature == Feature::BridgeInfill)
        .collect();
    assert!(!bridge.is_empty(), "no bridge lines on the plate's first layer");
    let speed = Rate::from_num(BRIDGE_SPEED_MM_S);
    assert!(bridge.iter().all(|(_, m)| m.feed_mm_s <= speed), "{bridge:?}");
}
