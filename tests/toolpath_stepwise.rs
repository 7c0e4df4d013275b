//! Stepwise emission: a layer's moves emitted unit by unit (`accept_layer`, `build_next`,
//! `emit_next`) as a small room allows are exactly the moves `push_layer` emits at once, each
//! unit's move count is exact, and the stage takes no layer while one is being emitted.

mod slice_support;
mod toolpath_support;

use std::path::Path;

use slice_support::{cuboid, holed_prism, load_placed, ngon, to_um};
use strata::geom::Triangle;
use strata::machine::{MachineConfig, PrintSettings};
use strata::slice::{Layer, SliceConfig};
use strata::toolpath::{
    Emitted, LayerStats, Seam, ToolEvent, ToolpathConfig, ToolpathError, ToolpathStats,
};
use toolpath_support::{run_cfg, TestSlicer, TestToolpath, TpLayer, TpRun};

/// One `emit_next` call: the room given, the moves emitted, what it returned.
#[derive(Debug, Clone, Copy)]
struct Call {
    room: usize,
    moves: usize,
    got: Emitted,
}

/// Records the stage's events into layers (as `toolpath_support` does).
fn record(layers: &mut Vec<TpLayer>, e: &ToolEvent<'_>) {
    match e {
        ToolEvent::LayerStart { index, z_um, height_um } => layers.push(TpLayer {
            index: *index,
            z_um: *z_um,
            height_um: *height_um,
            moves: Vec::new(),
            stats: LayerStats::default(),
            contours: Vec::new(),
        }),
        ToolEvent::Move(m) => layers.last_mut().expect("a move before any layer").moves.push(*m),
        ToolEvent::LayerEnd(s) => layers.last_mut().expect("an end before any layer").stats = **s,
        ToolEvent::Progress => {}
    }
}

/// Emits the built layer, each call with `room(needed)` moves of room (`needed`: what the
/// waiting unit needs, 0 before the first call), until it is complete.
fn drain(
    tp: &mut TestToolpath,
    layers: &mut Vec<TpLayer>,
    calls: &mut Vec<Call>,
    room: &mut dyn FnMut(u32) -> usize,
) {
    let mut needed = 0;
    loop {
        let r = room(needed);
        let mut moves = 0;
        let got = tp
            .emit_next(r, &mut |e: &ToolEvent<'_>| {
                moves += usize::from(matches!(e, ToolEvent::Move(_)));
                record(layers, e);
            })
            .expect("emit_next");
        calls.push(Call { room: r, moves, got });
        assert!(moves <= r, "{moves} moves emitted into a room of {r}");
        match got {
            Emitted::Complete => {
                assert!(!tp.emitting());
                return;
            }
            Emitted::NeedsRoom { moves: m, layer } => {
                assert!(m as usize > r - moves, "a unit of {m} fit {} moves left", r - moves);
                assert_eq!(layers.last().map(|l| l.index), Some(layer));
                assert!(tp.emitting());
                needed = m;
            }
        }
    }
}

/// Slices `tris` and runs the toolpath stage as the printer does: a plane is cut only once
/// the stage has emitted the layer before, unit by unit with the rooms `room` gives; every
/// `emit_next` call is returned too.
fn run_stepwise(
    tris: &[Triangle],
    settings: &PrintSettings,
    cfg: ToolpathConfig,
    mut room: impl FnMut(u32) -> usize + Send,
) -> (TpRun, Vec<Call>) {
    let top = tris.iter().map(Triangle::z_max).max().unwrap_or(0);
    let slice_cfg = SliceConfig::new(settings, top).unwrap();
    std::thread::scope(|scope| {
        std::thread::Builder::new()
            .stack_size(512 << 20)
            .spawn_scoped(scope, move || {
                let mut slicer = Box::new(TestSlicer::new(slice_cfg).unwrap());
                let mut tp = Box::new(TestToolpath::new(cfg).unwrap());
                let (mut layers, mut calls) = (Vec::new(), Vec::new());
                let accept = |tp: &mut TestToolpath, layers: &mut Vec<TpLayer>, l: &Layer| {
                    assert!(!tp.emitting());
                    tp.accept_layer(l, &mut |e: &ToolEvent<'_>| record(layers, e)).unwrap();
                };
                for t in tris {
                    while slicer.would_cut(t.z_min()) {
                        slicer.cut_one(&mut |l: &Layer| accept(&mut tp, &mut layers, l)).unwrap();
                        if tp.emitting() {
                            // Neither another layer nor a flush while this one is emitted.
                            let sink = &mut |_: &ToolEvent<'_>| panic!("no event expected");
                            let busy = ToolpathError::Emitting { layer: tp.layers_emitted() };
                            assert_eq!(tp.build_next(sink), Err(busy));
                            assert_eq!(tp.accept_layer(&empty_layer(u32::MAX), sink), Err(busy));
                        }
                        drain(&mut tp, &mut layers, &mut calls, &mut room);
                    }
                    slicer.push(t, &mut |_: &Layer| panic!("push cut a layer")).unwrap();
                }
                while slicer.cut_one(&mut |l: &Layer| accept(&mut tp, &mut layers, l)).unwrap() {
                    drain(&mut tp, &mut layers, &mut calls, &mut room);
                }
                slicer.finish(&mut |_: &Layer| panic!("finish cut a layer")).unwrap();
                while tp.build_next(&mut |e: &ToolEvent<'_>| record(&mut layers, e)).unwrap() {
                    drain(&mut tp, &mut layers, &mut calls, &mut room);
                }
                let stats = tp.finish(&mut |e: &ToolEvent<'_>| record(&mut layers, e)).unwrap();
                (TpRun { layers, stats, stray: 0 }, calls)
            })
            .unwrap()
            .join()
            .unwrap()
    })
}

fn empty_layer(index: u32) -> Layer<'static> {
    Layer {
        index,
        z_um: 0,
        points: &[],
        loops: &[],
        repairs: Default::default(),
        dropped_small_loops: 0,
        active_triangles: 0,
        segments: 0,
    }
}

/// The layers and totals of two runs are identical.
fn assert_same(a: &TpRun, b: &TpRun, what: &str) {
    assert_eq!(a.layers.len(), b.layers.len(), "{what}: layers");
    for (x, y) in a.layers.iter().zip(&b.layers) {
        let l = x.index;
        assert_eq!((x.index, x.z_um, x.height_um), (y.index, y.z_um, y.height_um), "{what}");
        assert_eq!(x.moves, y.moves, "{what}: moves of layer {l}");
        assert_eq!(x.stats, y.stats, "{what}: counters of layer {l}");
    }
    let totals = |s: &ToolpathStats| ToolpathStats { needs: Default::default(), ..*s };
    assert_eq!(totals(&a.stats), totals(&b.stats), "{what}: totals");
}

/// Shapes with several islands, holes, combing, retraction and a skirt.
fn shapes() -> Vec<(&'static str, Vec<Triangle>, ToolpathConfig)> {
    let settings = PrintSettings::default();
    let machine = MachineConfig::default();
    let default = ToolpathConfig::new(&machine, &settings);
    let c = 110.0;
    let mut plate = Vec::new();
    for (dx, dy) in [(-6.0, -6.0), (6.0, -6.0), (-6.0, 6.0), (6.0, 6.0)] {
        let (hx, hy) = (c + dx, c + dy);
        plate.extend(holed_prism(
            &ngon(24, hx, hy, 5.9, 0.0),
            &ngon(24, hx, hy, 2.0, 0.0),
            0.0,
            1.6,
        ));
    }
    let mut nearest = default;
    nearest.seam = Seam::Nearest;
    nearest.outer_perimeter_last = false;
    nearest.skirt_loops = 2;
    let holed = holed_prism(&ngon(8, c, c, 12.0, 0.3), &ngon(8, c, c, 5.0, 0.1), 0.0, 2.0);
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/cube_with_hole_20mm.stl");
    let cube_with_hole = load_placed(&data, &machine);
    vec![
        ("cube", to_um(&cuboid([100.0, 100.0, 0.0], [115.0, 112.0, 2.0])), default),
        ("four holed discs", to_um(&plate), default),
        ("four holed discs, nearest seams", to_um(&plate), nearest),
        ("holed octagon", to_um(&holed), default),
        ("cube with a hole", cube_with_hole, default),
    ]
}

#[test]
fn emitting_unit_by_unit_gives_the_moves_of_whole_layers() {
    let settings = PrintSettings::default();
    for (what, tris, cfg) in shapes() {
        let whole = run_cfg(&tris, &settings, cfg).unwrap();
        assert!(whole.layers.len() >= 8, "{what}");
        // Room for exactly the waiting unit: each call emits exactly that many moves.
        let (exact, calls) = run_stepwise(&tris, &settings, cfg, |needed| needed as usize);
        assert_same(&whole, &exact, what);
        for c in calls.iter().filter(|c| c.room > 0) {
            assert_eq!(c.moves, c.room, "{what}: a unit's moves are counted exactly: {c:?}");
        }
        // Each layer's first call (no room) waits.
        let refused = calls.iter().filter(|c| matches!(c.got, Emitted::NeedsRoom { .. })).count();
        assert!(refused >= whole.layers.len(), "{what}: {refused} calls waited for room");
        // The largest room asked for is the largest unit, and it is a fraction of a layer.
        let largest = calls.iter().map(|c| c.room).max().unwrap_or(0) as u32;
        assert_eq!(largest, whole.stats.max_unit_moves, "{what}");
        let per_layer = whole.layers.iter().map(|l| l.stats.max_unit_moves).max();
        assert_eq!(per_layer, Some(largest), "{what}");
        let most = whole.layers.iter().map(|l| l.moves.len()).max().unwrap_or(0);
        assert!(largest > 0 && (largest as usize) < most, "{what}: {largest} of {most}");
        // Random rooms, often too small for the waiting unit.
        let mut rng = 0x9e37_79b9_7f4a_7c15u64;
        let (random, calls) = run_stepwise(&tris, &settings, cfg, move |needed| {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            match rng % 3 {
                0 => (rng >> 8) as usize % (needed as usize + 1),
                _ => needed as usize + (rng >> 8) as usize % 64,
            }
        });
        assert_same(&whole, &random, what);
        assert!(calls.iter().any(|c| matches!(c.got, Emitted::NeedsRoom { .. })), "{what}");
    }
}

#[test]
fn a_layer_waits_whole_for_room_and_nothing_is_lost_meanwhile() {
    // A stage given no room emits nothing but the units of no moves, and keeps the layer.
    let settings = PrintSettings::default();
    let cfg = ToolpathConfig::new(&MachineConfig::default(), &settings);
    let tris = to_um(&cuboid([100.0, 100.0, 0.0], [110.0, 110.0, 0.6]));
    let (run, calls) = run_stepwise(&tris, &settings, cfg, {
        let mut turn = 0u32;
        move |needed| {
            // Ten refusals for every unit before its room comes.
            turn += 1;
            if turn % 11 == 0 {
                needed as usize
            } else {
                0
            }
        }
    });
    let whole = run_cfg(&tris, &settings, cfg).unwrap();
    assert_same(&whole, &run, "cube");
    assert!(calls.iter().filter(|c| c.room == 0).all(|c| c.moves == 0));
    // Every layer got its own end: none started before the one before it ended.
    assert!(run.layers.iter().all(|l| l.stats.index == l.index));
}
