//! Stepwise emission: a layer's moves emitted unit by unit (`accept_layer`, `build_next`,
//! `emit_next`) as a small room allows are exactly the moves `push_layer` emits at once, each
//! unit's move count is exact, and the stage takes no layer while one is being emitted; the
//! move ring's room takes a unit exactly when its coded moves fit, and a unit it undoes
//! leaves the ring as it was.

mod toolpath_support;

use std::collections::VecDeque;
use std::path::Path;

use strata::geom::Triangle;
use strata::machine::{MachineConfig, PrintSettings};

use strata::move_ring::{MoveEncoder, MoveRing, MoveStream, PackedMove, RingRoom, RoomMemory};
use strata::slice::{Layer, SliceConfig, SlicedLayer};
use strata::toolpath::{
    Emitted, Moves, Room, Seam, ToolEvent, ToolMove, ToolpathConfig, ToolpathError, ToolpathStats,
};
use strata_testkit::mesh::{cuboid, four_holed_discs, holed_prism, ngon, to_um};
use strata_testkit::models::load_placed;
use strata_testkit::rng::Rng;
use toolpath_support::{run_cfg, TestScratch, TestSlicer, TestToolpath, TpLayer, TpRun};

/// The scratch of the stepwise runs (the test stage's PTS and CROSS).
type Work = TestScratch<16384, 32768>;
/// A layer the test slicer cut into a [`Work`].
type Sliced<'a> = SlicedLayer<'a, 16384, strata::scratch::Scratch<16384, 16384, 32768>>;

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
        let mut moves = 0;
        let mut counted = Moves {
            left: r,
            sink: |e: &ToolEvent<'_>| {
                moves += usize::from(matches!(e, ToolEvent::Move(_)));
                record(layers, e);
            },
        };
        let got = tp.emit_next(work, &mut counted).expect("emit_next");
        let left = counted.left;
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
    strata_testkit::on_big_stack(move || {
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
                slicer.cut_one(&mut *work, &mut |l| accept(&mut tp, &mut layers, l)).unwrap();
                if tp.emitting() {
                    // Neither another layer nor a flush while this one is emitted.
                    let sink = &mut |_: &ToolEvent<'_>| panic!("no event expected");
                    let busy = ToolpathError::Emitting { layer: tp.layers_emitted() };
                    assert_eq!(tp.build_next(&mut *work, sink), Err(busy));
                    let refused = tp.accept_layer(&empty_layer(u32::MAX), &mut *work, sink);
                    assert_eq!(refused, Err(busy));
                }
                emit(&mut tp, &mut work, &mut layers);
            }
            slicer.push(t, &mut *work, &mut |_| panic!("push cut a layer")).unwrap();
        }
        while slicer.cut_one(&mut *work, &mut |l| accept(&mut tp, &mut layers, l)).unwrap() {
            emit(&mut tp, &mut work, &mut layers);
        }
        slicer.finish(&mut *work, &mut |_| panic!("finish cut a layer")).unwrap();
        while tp.build_next(&mut *work, &mut |e: &ToolEvent<'_>| record(&mut layers, e)).unwrap() {
            emit(&mut tp, &mut work, &mut layers);
        }
        let stats = tp.finish(&mut *work, &mut |e: &ToolEvent<'_>| record(&mut layers, e)).unwrap();
        TpRun { layers, stats, stray: 0 }
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
        let mut rng = Rng::new(0x9e37_79b9_7f4a_7c15);
        let (random, calls) = run_stepwise(&tris, &settings, cfg, move |needed| {
            let x = rng.u64();
            match x % 3 {
                0 => (x >> 8) as usize % (needed as usize + 1),
                _ => needed as usize + (x >> 8) as usize % 64,
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

/// The ring's room, checked against an independent coding of the moves: logs the bytes of
/// every unit kept and of the unit undone, and records the kept units' events.
struct Logged<'a, 'r, const B: usize> {
    room: RingRoom<'r, B>,
    run: &'a mut RingRun,
    layers: &'a mut Vec<TpLayer>,
    /// The open unit: the coding after its moves, its moves (as sent and packed), its bytes.
    open: (MoveStream, MoveEncoder, Vec<ToolMove>, Vec<PackedMove>, usize),
    /// Bytes of the unit undone in this call, as the independent coding counts them.
    undone: Option<usize>,
    /// Bytes of the units kept in this call.
    kept: Vec<usize>,
}

impl<const B: usize> Room for Logged<'_, '_, B> {
    fn open(&mut self, moves: u32) -> bool {
        let taken = self.room.open(moves);
        if taken {
            self.open = (self.run.stream, self.run.coder, Vec::new(), Vec::new(), 0);
        }
        taken
    }

    fn event(&mut self, e: &ToolEvent<'_>) {
        self.room.event(e);
        match e {
            ToolEvent::Move(m) => {
                let (stream, coder, sent, packed, bytes) = &mut self.open;
                let mv = stream.next(m);
                *bytes += coder.encode(&mv, &mut [0; strata::move_ring::MAX_RECORD]);
                sent.push(*m);
                packed.push(mv);
            }
            _ => record(self.layers, e),
        }
    }

    fn close(&mut self) -> bool {
        let kept = self.room.close();
        let (stream, coder, sent, packed, bytes) = core::mem::take(&mut self.open);
        if kept {
            (self.run.stream, self.run.coder) = (stream, coder);
            for m in sent {
                record(self.layers, &ToolEvent::Move(m));
            }
            self.run.queued.extend(packed);
            self.kept.push(bytes);
        } else {
            self.undone = Some(bytes);
        }
        kept
    }
}

/// What [`through_ring`] saw, and the independent coding it checks the ring against.
struct RingRun {
    /// Bytes of every unit taken, in order.
    units: Vec<usize>,
    /// Calls refused for room.
    refused: usize,
    /// Units undone at their close (they ran out of bytes).
    undone: usize,
    /// Refusals of a unit whose bytes exceed the whole ring.
    never: usize,
    /// What the ring's rooms learnt.
    memory: RoomMemory,
    /// Each room starts from nothing learnt (no estimate, no known bytes).
    forget: bool,
    /// The stream and coder of the moves kept, run independently of the ring's.
    stream: MoveStream,
    coder: MoveEncoder,
    /// The moves kept and not popped yet: what the ring must hold.
    queued: VecDeque<PackedMove>,
}

impl RingRun {
    fn new() -> Self {
        Self {
            units: Vec::new(),
            refused: 0,
            undone: 0,
            never: 0,
            memory: RoomMemory::EMPTY,
            forget: false,
            stream: MoveStream::new(),
            coder: MoveEncoder::new(),
            queued: VecDeque::new(),
        }
    }
}

/// Emits the built layer into `ring` as the printer does (each `emit_next` with the ring's
/// room, the moves going through `stream`), popping `pop(refusals)` moves after each
/// refusal (the planner taking moves): checks that every unit kept took the bytes its moves
/// take, that a unit undone left the ring holding exactly the moves kept before it, and
/// that a refused unit's bytes are exact and stay the same until it goes in.
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
    // The layer's start went by outside the units: the streams are at its layer.
    let layer = layers.last().expect("a layer is being emitted").index;
    stream.start_layer(layer);
    seen.stream.start_layer(layer);
    let mut waiting: Option<usize> = None;
    loop {
        let used = ring.used_bytes();
        let mut memory = if seen.forget { RoomMemory::EMPTY } else { seen.memory };
        let mut room = Logged {
            room: ring.room(stream, &mut memory),
            run: &mut *seen,
            layers: &mut *layers,
            open: Default::default(),
            undone: None,
            kept: Vec::new(),
        };
        let got = tp.emit_next(work, &mut room).expect("emit_next");
        let (refused, never) = (room.room.refused(), room.room.never_fits());
        let (undone, kept) = (room.undone, room.kept);
        seen.memory = memory;
        // The ring took the bytes of the units kept, and holds exactly their moves.
        assert_eq!(ring.used_bytes() - used, kept.iter().sum::<usize>());
        if let (Some(w), Some(&first)) = (waiting, kept.first()) {
            assert_eq!(first, w, "the unit refused took the bytes it was refused for");
        }
        if !kept.is_empty() {
            waiting = None;
        }
        seen.units.extend(&kept);
        match got {
            Emitted::Complete => {
                assert_eq!((refused, undone), (None, None));
                return;
            }
            Emitted::NeedsRoom { .. } => {
                seen.refused += 1;
                let free = ring.free_bytes();
                match refused {
                    Some(bytes) => {
                        assert!(bytes > free, "{bytes} refused with {free} free");
                        // Undone at its close, or refused on its bytes known from that.
                        match (undone, waiting) {
                            (Some(u), _) => {
                                seen.undone += 1;
                                assert_eq!(bytes, u, "a unit undone names its exact bytes");
                            }
                            (None, w) => assert!(kept.is_empty() && w == Some(bytes)),
                        }
                        if let Some(w) = waiting {
                            assert_eq!(bytes, w, "a waiting unit's bytes do not change");
                        }
                        assert_eq!(memory.waits_for(), bytes);
                        waiting = Some(bytes);
                        if never {
                            assert!(bytes > ring.capacity());
                            seen.never += 1;
                            return;
                        }
                    }
                    None => {
                        // Refused on the estimate: not run, and only while moves wait.
                        assert_eq!(undone, None);
                        assert!(memory.waits_for() > free && !ring.is_empty());
                    }
                }
                assert!(!ring.is_empty(), "an empty ring refused a unit that fits it");
                for _ in 0..pop(seen.refused).max(1) {
                    let Some(mv) = ring.pop_front() else { break };
                    assert_eq!(Some(mv), seen.queued.pop_front());
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
    strata_testkit::on_big_stack(byte_room_checks);
}

fn byte_room_checks() {
    let settings = PrintSettings::default();
    for (what, tris, cfg) in shapes() {
        let whole = run_cfg(&tris, &settings, cfg).unwrap();
        // Unbounded: every unit in one call per layer; its bytes are those of its moves.
        let mut big: Box<Ring> = Box::new(MoveRing::new());
        let (mut stream, mut free) = (MoveStream::new(), RingRun::new());
        let run = run_with(&tris, &settings, cfg, |tp, work, layers| {
            through_ring(tp, work, layers, &mut big, &mut stream, &mut free, &mut |_| 0)
        });
        assert_same(&whole, &run, what);
        assert_eq!(free.refused, 0, "{what}");
        let largest = free.units.iter().copied().max().unwrap_or(0);
        let total: usize = free.units.iter().sum();
        assert_eq!(big.used_bytes(), total, "{what}: every move is in a unit");
        assert!(largest > 0 && largest * 4 < total, "{what}: {largest} of {total}");
        assert_rings_hold(&mut big, &mut free, what);
        // A ring of exactly the largest unit's bytes, drained a few moves at a time: the same
        // moves, the same unit bytes (the coding does not depend on what waits), many waits;
        // rooms that forget what the ones before learnt run the first unit they are offered
        // (no known bytes, no estimate), so units run out of bytes and are undone.
        for forget in [false, true] {
            let mut exact: Box<Ring> = Box::new(MoveRing::new());
            exact.limit(largest);
            let (mut stream, mut tight) = (MoveStream::new(), RingRun::new());
            tight.forget = forget;
            let mut rng = Rng::new(0x2545_f491_4f6c_dd1d);
            let run = run_with(&tris, &settings, cfg, |tp, work, layers| {
                let pop = &mut |_| rng.below(8) as usize;
                through_ring(tp, work, layers, &mut exact, &mut stream, &mut tight, pop)
            });
            assert_same(&whole, &run, what);
            assert_eq!(tight.units, free.units, "{what}");
            assert_eq!(tight.never, 0, "{what}");
            assert!(tight.refused > whole.layers.len(), "{what}: {} waits", tight.refused);
            if forget {
                assert!(tight.undone * 2 > tight.refused, "{what}: {}", tight.undone);
            }
            assert_rings_hold(&mut exact, &mut tight, what);
        }
        // One byte less: the largest unit never fits, and it is refused as such.
        let mut short: Box<Ring> = Box::new(MoveRing::new());
        short.limit(largest - 1);
        let (mut stream, mut cut) = (MoveStream::new(), RingRun::new());
        let mut stopped = false;
        run_with(&tris, &settings, cfg, |tp, work, layers| {
            if stopped {
                // The owner fails the job; here the rest is emitted without the ring.
                tp.emit_next(work, &mut |e: &ToolEvent<'_>| record(layers, e)).unwrap();
                return;
            }
            through_ring(tp, work, layers, &mut short, &mut stream, &mut cut, &mut |_| usize::MAX);
            if cut.never > 0 {
                stopped = true;
                tp.emit_next(work, &mut |e: &ToolEvent<'_>| record(layers, e)).unwrap();
            }
        });
        assert_eq!(cut.never, 1, "{what}");
        let first_largest = free.units.iter().position(|&b| b == largest).unwrap();
        assert_eq!(cut.units[..], free.units[..first_largest], "{what}");
    }
}

/// `ring` holds exactly the moves `run` kept and did not pop, in order.
fn assert_rings_hold<const B: usize>(ring: &mut MoveRing<B>, run: &mut RingRun, what: &str) {
    while let Some(mv) = ring.pop_front() {
        assert_eq!(Some(mv), run.queued.pop_front(), "{what}");
    }
    assert!(run.queued.is_empty(), "{what}: {} moves missing", run.queued.len());
}
