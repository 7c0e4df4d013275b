//! Stepwise emission: a layer's moves emitted unit by unit (`accept_layer`, `build_next`,
//! `emit_next`) as a small room allows are exactly the moves `push_layer` emits at once, each
//! unit's move count is exact, and the stage takes no layer while one is being emitted; the
//! move ring's byte room counts each unit's coded bytes exactly.

mod slice_support;
mod toolpath_support;

use std::path::Path;

use slice_support::{cuboid, four_holed_discs, holed_prism, load_placed, ngon, to_um};
use strata::geom::Triangle;
use strata::machine::{MachineConfig, PrintSettings};
use strata::move_ring::{ByteRoom, MoveRing, MoveStream};
use strata::slice::{Layer, SliceConfig, SlicedLayer};
use strata::toolpath::{
    Emitted, Replay, Room, Seam, ToolEvent, ToolpathConfig, ToolpathError, ToolpathStats,
};
use toolpath_support::{run_cfg, TestScratch, TestSlicer, TestToolpath, TpLayer, TpRun};

/// The scratch of the stepwise runs (the test stage's PTS and CROSS).
type Work = TestScratch<16384, 32768>;
/// A layer the test slicer cut into a [`Work`].
type Sliced<'a> = SlicedLayer<'a, 16384, 16384, 32768>;

/// One `emit_next` call: the room given, the moves emitted, what it returned.
#[derive(Debug, Clone, Copy)]
struct Call {
    room: usize,
    moves: usize,
    got: Emitted,
}

/// Records the stage's events into layers; a move or layer end before any layer fails.
fn record(layers: &mut Vec<TpLayer>, e: &ToolEvent<'_>) {
    assert!(toolpath_support::record(layers, e), "an event before any layer: {e:?}");
}

/// Emits the built layer, each call with `room(needed)` moves of room (`needed`: what the
/// waiting unit needs, 0 before the first call), until it is complete.
fn drain(
    tp: &mut TestToolpath,
    work: &mut Work,
    layers: &mut Vec<TpLayer>,
    calls: &mut Vec<Call>,
    room: &mut dyn FnMut(u32) -> usize,
) {
    let mut needed = 0;
    loop {
        let r = room(needed);
        let (mut moves, mut left) = (0, r);
        let got = tp
            .emit_next(work, &mut left, &mut |e: &ToolEvent<'_>| {
                moves += usize::from(matches!(e, ToolEvent::Move(_)));
                record(layers, e);
            })
            .expect("emit_next");
        calls.push(Call { room: r, moves, got });
        assert!(moves <= r, "{moves} moves emitted into a room of {r}");
        assert_eq!(left, r - moves, "the room counts down by the moves emitted");
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

/// [`run_with`] emitting unit by unit with the rooms `room` gives; every `emit_next` call is
/// returned too.
fn run_stepwise(
    tris: &[Triangle],
    settings: &PrintSettings,
    cfg: ToolpathConfig,
    mut room: impl FnMut(u32) -> usize + Send,
) -> (TpRun, Vec<Call>) {
    let mut calls = Vec::new();
    let run = run_with(tris, settings, cfg, |tp, work, layers| {
        drain(tp, work, layers, &mut calls, &mut room)
    });
    (run, calls)
}

/// Slices `tris` and runs the toolpath stage as the printer does: a plane is cut only once
/// the stage has emitted the layer before, which `emit` does (until the stage is no longer
/// emitting).
fn run_with(
    tris: &[Triangle],
    settings: &PrintSettings,
    cfg: ToolpathConfig,
    mut emit: impl FnMut(&mut TestToolpath, &mut Work, &mut Vec<TpLayer>) + Send,
) -> TpRun {
    let top = tris.iter().map(Triangle::z_max).max().unwrap_or(0);
    let slice_cfg = SliceConfig::new(settings, top).unwrap();
    std::thread::scope(|scope| {
        std::thread::Builder::new()
            .stack_size(512 << 20)
            .spawn_scoped(scope, move || {
                let mut slicer = Box::new(TestSlicer::new(slice_cfg).unwrap());
                let mut tp = Box::new(TestToolpath::new(cfg).unwrap());
                let mut work = Box::new(Work::new());
                let mut layers = Vec::new();
                let accept = |tp: &mut TestToolpath, layers: &mut Vec<TpLayer>, l: Sliced<'_>| {
                    assert!(!tp.emitting());
                    tp.accept_sliced(l, &mut |e: &ToolEvent<'_>| record(layers, e)).unwrap();
                };
                for t in tris {
                    while slicer.would_cut(t.z_min()) {
                        slicer
                            .cut_one(&mut work, &mut |l| accept(&mut tp, &mut layers, l))
                            .unwrap();
                        if tp.emitting() {
                            // Neither another layer nor a flush while this one is emitted.
                            let sink = &mut |_: &ToolEvent<'_>| panic!("no event expected");
                            let busy = ToolpathError::Emitting { layer: tp.layers_emitted() };
                            assert_eq!(tp.build_next(&mut work, sink), Err(busy));
                            let refused = tp.accept_layer(&empty_layer(u32::MAX), &mut work, sink);
                            assert_eq!(refused, Err(busy));
                        }
                        emit(&mut tp, &mut work, &mut layers);
                    }
                    slicer.push(t, &mut work, &mut |_| panic!("push cut a layer")).unwrap();
                }
                while slicer.cut_one(&mut work, &mut |l| accept(&mut tp, &mut layers, l)).unwrap() {
                    emit(&mut tp, &mut work, &mut layers);
                }
                slicer.finish(&mut work, &mut |_| panic!("finish cut a layer")).unwrap();
                while tp
                    .build_next(&mut work, &mut |e: &ToolEvent<'_>| record(&mut layers, e))
                    .unwrap()
                {
                    emit(&mut tp, &mut work, &mut layers);
                }
                let stats =
                    tp.finish(&mut work, &mut |e: &ToolEvent<'_>| record(&mut layers, e)).unwrap();
                TpRun { layers, stats, stray: 0 }
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
    let plate = four_holed_discs(c, 1.6);
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

/// A [`ByteRoom`] that logs the bytes of every unit it takes.
struct Logged {
    room: ByteRoom,
    units: Vec<usize>,
}

impl Room for Logged {
    fn take(&mut self, moves: u32, replay: &mut Replay<'_>) -> bool {
        let before = self.room.taken();
        let taken = self.room.take(moves, replay);
        if taken {
            self.units.push((self.room.taken() - before) as usize);
        }
        taken
    }
}

/// What [`through_ring`] saw.
#[derive(Default)]
struct RingRun {
    /// Bytes of every unit taken, in order.
    units: Vec<usize>,
    /// Calls refused for room.
    refused: usize,
    /// Refusals of a unit whose bytes exceed the whole ring.
    never: usize,
}

/// Emits the built layer into `ring` as the printer does (each `emit_next` with the ring's
/// room, the moves pushed through `stream`), popping `pop(refusals)` moves after each
/// refusal (the planner taking moves): checks that every unit's bytes are the bytes its moves
/// take in the ring, and that a refused unit's bytes stay the same until it goes in.
fn through_ring<const B: usize>(
    tp: &mut TestToolpath,
    work: &mut Work,
    layers: &mut Vec<TpLayer>,
    ring: &mut MoveRing<B>,
    stream: &mut MoveStream,
    seen: &mut RingRun,
    pop: &mut dyn FnMut(usize) -> usize,
) {
    if !tp.emitting() {
        return;
    }
    // The layer's start went by outside the units: the stream is at its layer.
    stream.start_layer(layers.last().expect("a layer is being emitted").index);
    let mut waiting: Option<usize> = None;
    loop {
        let mut room = Logged { room: ring.room(stream), units: Vec::new() };
        let mut pushed = Vec::new();
        let got = tp
            .emit_next(work, &mut room, &mut |e: &ToolEvent<'_>| {
                if let ToolEvent::Move(m) = e {
                    let used = ring.used_bytes();
                    ring.push(&stream.next(m)).expect("a unit taken fits the ring");
                    pushed.push(ring.used_bytes() - used);
                }
                record(layers, e);
            })
            .expect("emit_next");
        // The bytes the room counted are the bytes the moves took, unit by unit.
        assert_eq!(room.units.iter().sum::<usize>(), pushed.iter().sum::<usize>());
        assert_eq!(room.room.taken(), pushed.iter().sum::<usize>() as u64);
        if let (Some(w), Some(&first)) = (waiting, room.units.first()) {
            assert_eq!(first, w, "the unit refused took the bytes it was refused for");
        }
        seen.units.extend(&room.units);
        match got {
            Emitted::Complete => {
                assert_eq!(room.room.refused(), None);
                return;
            }
            Emitted::NeedsRoom { .. } => {
                seen.refused += 1;
                let bytes = room.room.refused().expect("a refusal names the unit's bytes");
                assert!(
                    bytes > ring.free_bytes(),
                    "{bytes} refused with {} free",
                    ring.free_bytes()
                );
                if room.units.is_empty() {
                    if let Some(w) = waiting {
                        assert_eq!(bytes, w, "a waiting unit's bytes do not change");
                    }
                }
                waiting = Some(bytes);
                if room.room.never_fits() {
                    assert!(bytes > ring.capacity());
                    seen.never += 1;
                    return;
                }
                assert!(!ring.is_empty(), "an empty ring refused a unit that fits it");
                for _ in 0..pop(seen.refused).max(1) {
                    if ring.pop_front().is_none() {
                        break;
                    }
                }
            }
        }
    }
}

/// The byte rings of the test: room for every shape's whole job.
type Ring = MoveRing<{ 1 << 18 }>;

#[test]
fn a_byte_room_takes_a_unit_exactly_when_its_coded_moves_fit() {
    // The rings are large values: built on a thread with a big stack (debug builds copy them).
    std::thread::Builder::new()
        .stack_size(64 << 20)
        .spawn(byte_room_checks)
        .unwrap()
        .join()
        .unwrap();
}

fn byte_room_checks() {
    let settings = PrintSettings::default();
    for (what, tris, cfg) in shapes() {
        let whole = run_cfg(&tris, &settings, cfg).unwrap();
        // Unbounded: every unit in one call per layer; its bytes are those of its moves.
        let mut big: Box<Ring> = Box::new(MoveRing::new());
        let (mut stream, mut free) = (MoveStream::new(), RingRun::default());
        let run = run_with(&tris, &settings, cfg, |tp, work, layers| {
            through_ring(tp, work, layers, &mut big, &mut stream, &mut free, &mut |_| 0)
        });
        assert_same(&whole, &run, what);
        assert_eq!(free.refused, 0, "{what}");
        let largest = free.units.iter().copied().max().unwrap_or(0);
        let total: usize = free.units.iter().sum();
        assert_eq!(big.used_bytes(), total, "{what}: every move is in a unit");
        assert!(largest > 0 && largest * 4 < total, "{what}: {largest} of {total}");
        // A ring of exactly the largest unit's bytes, drained a few moves at a time: the same
        // moves, the same unit bytes (the coding does not depend on what waits), many waits.
        let mut exact: Box<Ring> = Box::new(MoveRing::new());
        exact.limit(largest);
        let (mut stream, mut tight) = (MoveStream::new(), RingRun::default());
        let mut rng = 0x2545_f491_4f6c_dd1du64;
        let run = run_with(&tris, &settings, cfg, |tp, work, layers| {
            let pop = &mut |_| {
                rng ^= rng << 13;
                rng ^= rng >> 7;
                rng ^= rng << 17;
                (rng % 8) as usize
            };
            through_ring(tp, work, layers, &mut exact, &mut stream, &mut tight, pop)
        });
        assert_same(&whole, &run, what);
        assert_eq!(tight.units, free.units, "{what}");
        assert_eq!(tight.never, 0, "{what}");
        assert!(tight.refused > whole.layers.len(), "{what}: {} waits", tight.refused);
        // One byte less: the largest unit never fits, and it is refused as such.
        let mut short: Box<Ring> = Box::new(MoveRing::new());
        short.limit(largest - 1);
        let (mut stream, mut cut) = (MoveStream::new(), RingRun::default());
        let mut stopped = false;
        run_with(&tris, &settings, cfg, |tp, work, layers| {
            if stopped {
                // The owner fails the job; here the rest is emitted without the ring.
                let mut all = usize::MAX;
                tp.emit_next(work, &mut all, &mut |e: &ToolEvent<'_>| record(layers, e)).unwrap();
                return;
            }
            through_ring(tp, work, layers, &mut short, &mut stream, &mut cut, &mut |_| usize::MAX);
            if cut.never > 0 {
                stopped = true;
                let mut all = usize::MAX;
                tp.emit_next(work, &mut all, &mut |e: &ToolEvent<'_>| record(layers, e)).unwrap();
            }
        });
        assert_eq!(cut.never, 1, "{what}");
        let first_largest = free.units.iter().position(|&b| b == largest).unwrap();
        assert_eq!(cut.units[..], free.units[..first_largest], "{what}");
    }
}
