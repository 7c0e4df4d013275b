//! Robustness of the toolpath stage: arbitrary (self-intersecting, degenerate, badly nested)
//! layers never panic, every extrusion stays within the input's bounding box, small
//! capacities give typed errors naming the buffer and the layer, and misuse is reported.

mod slice_support;
mod toolpath_support;

use proptest::prelude::*;
use proptest::test_runner::{Config, RngAlgorithm, TestCaseError, TestRng, TestRunner};
use slice_support::{cuboid, to_um};
use strata::geom::Point2;
use strata::machine::{MachineConfig, PrintSettings};
use strata::slice::{Layer, LayerRepairs, LoopInfo, SlicedLayer};
use strata::toolpath::scan::{line_spans, Angle, Span};
use strata::toolpath::window::{Encoder, Fifo, StoredRings};
use strata::toolpath::{Buffer, ToolEvent, ToolpathConfig, ToolpathError, ToolpathScratch};
use toolpath_support::{run_cfg, TestScratch};

strata::toolpath_type! {
    type PropToolpath = {
        toolpath_points: 4096,
        toolpath_loops: 64,
        scan_crossings: 4096,
        path_points: 16384,
        window_ring_words: 8192,
        window_spans: 8192,
    };
}
type PropScratch = ToolpathScratch<4096, 4096>;

/// One arbitrary loop: points in a 30 mm square around the bed centre, a hole flag and a
/// parent index (possibly nonsense).
fn arb_loop() -> impl Strategy<Value = (Vec<(i32, i32)>, bool, Option<u32>)> {
    (
        prop::collection::vec((95_000..125_000i32, 95_000..125_000i32), 0..40),
        any::<bool>(),
        prop::option::of(0u32..8),
    )
}

/// Loops on a 1.5 mm grid: many collinear and coincident edges, touching and overlapping
/// loops.
fn grid_loop() -> impl Strategy<Value = (Vec<(i32, i32)>, bool, Option<u32>)> {
    (prop::collection::vec((0..20i32, 0..20i32), 3..16), any::<bool>(), prop::option::of(0u32..4))
        .prop_map(|(pts, hole, parent)| {
            let pts =
                pts.into_iter().map(|(x, y)| (95_000 + 1_500 * x, 95_000 + 1_500 * y)).collect();
            (pts, hole, parent)
        })
}

type Layers = Vec<Vec<(Vec<(i32, i32)>, bool, Option<u32>)>>;

fn arb_layers() -> impl Strategy<Value = Layers> {
    prop_oneof![
        prop::collection::vec(prop::collection::vec(arb_loop(), 0..6), 1..7),
        prop::collection::vec(prop::collection::vec(grid_loop(), 1..5), 1..7),
    ]
}

fn cfg() -> ToolpathConfig {
    ToolpathConfig::new(&MachineConfig::default(), &PrintSettings::default())
}

#[test]
fn arbitrary_layers_never_panic_and_extrusions_stay_in_the_box() {
    std::thread::Builder::new()
        .stack_size(256 << 20)
        .spawn(|| {
            let cell = std::cell::RefCell::new(Box::new(PropToolpath::new(cfg()).unwrap()));
            // More cases with e.g. `TOOLPATH_CASES=5000 cargo test --release --test toolpath_props`.
            let cases = std::env::var("TOOLPATH_CASES").ok().and_then(|v| v.parse().ok());
            // Seeded: CI runs the same cases every time; widen with TOOLPATH_CASES.
            let mut runner = TestRunner::new_with_rng(
                Config::with_cases(cases.unwrap_or(160)),
                TestRng::deterministic_rng(RngAlgorithm::ChaCha),
            );
            runner
                .run(&arb_layers(), |layers| check_layers(&mut cell.borrow_mut(), &layers))
                .unwrap();
        })
        .unwrap()
        .join()
        .unwrap();
}

#[test]
fn small_capacities_give_typed_errors_and_misuse_is_reported() {
    std::thread::Builder::new()
        .stack_size(64 << 20)
        .spawn(|| {
            // A 20 mm cube: its layers need more than 8 crossings per line set.
            let tris = to_um(&cuboid([100.0, 100.0, 0.0], [120.0, 120.0, 2.0]));
            let settings = PrintSettings::default();
            let err = run_cfg_small(&tris, &settings);
            match err {
                Err(ToolpathError::Capacity { what, capacity, layer }) => {
                    assert_eq!((what, capacity, layer), (Buffer::Crossings, 8, 0));
                    let msg = ToolpathError::Capacity { what, capacity, layer }.to_string();
                    assert_eq!(
                        msg,
                        "too many scanline crossings per layer in layer 0 (capacity 8)"
                    );
                }
                other => panic!("{other:?}"),
            }
            // Out of order, then the same error again, then finish refused.
            let mut tp = Box::new(PropToolpath::new(cfg()).unwrap());
            let pts = [Point2::new(0, 0), Point2::new(1000, 0), Point2::new(0, 1000)];
            let info = [LoopInfo { start: 0, len: 3, ..LoopInfo::default() }];
            let layer = Layer {
                index: 1,
                z_um: 300,
                points: &pts,
                loops: &info,
                repairs: LayerRepairs::default(),
                dropped_small_loops: 0,
                active_triangles: 0,
                segments: 3,
            };
            let mut work = Box::new(PropScratch::new());
            let mut sink = |_: &ToolEvent<'_>| {};
            let e = ToolpathError::OutOfOrder { expected: 0, got: 1 };
            assert_eq!(tp.push_layer(&layer, &mut *work, &mut sink), Err(e));
            assert_eq!(tp.finish(&mut *work, &mut sink), Err(e));
            tp.reset(cfg()).unwrap();
            assert!(tp.finish(&mut *work, &mut sink).is_ok());
            assert_eq!(tp.finish(&mut *work, &mut sink), Err(ToolpathError::Finished));
            // Settings out of range are refused by name.
            let mut bad = cfg();
            bad.top_layers = 17;
            assert_eq!(
                PropToolpath::new(bad).err(),
                Some(ToolpathError::InvalidConfig { field: "top_layers" })
            );
            // The default settings run the cube fine with test capacities.
            assert!(run_cfg(&tris, &settings, cfg()).is_ok());
        })
        .unwrap()
        .join()
        .unwrap();
}

/// The cube through a stage with only 8 crossings.
fn run_cfg_small(
    tris: &[strata::geom::Triangle],
    settings: &PrintSettings,
) -> Result<(), ToolpathError> {
    strata::toolpath_type! {
        type Tiny = {
            toolpath_points: 256,
            toolpath_loops: 8,
            scan_crossings: 8,
            path_points: 256,
            window_ring_words: 256,
            window_spans: 256,
        };
    }
    let top = tris.iter().map(|t| t.z_max()).max().unwrap();
    let slice_cfg = strata::slice::SliceConfig::new(settings, top).unwrap();
    let mut slicer = Box::new(toolpath_support::TestSlicer::new(slice_cfg).unwrap());
    let mut tp = Box::new(Tiny::new(cfg())?);
    let mut work = Box::new(TestScratch::<256, 8>::new());
    let mut first = None;
    let mut events = |_: &ToolEvent<'_>| {};
    let mut sink = |l: SlicedLayer<'_, _, _>| {
        if first.is_none() {
            first = tp.push_sliced(l, &mut events).err();
        }
    };
    for t in tris {
        slicer.push(t, &mut *work, &mut sink).unwrap();
    }
    slicer.finish(&mut *work, &mut sink).unwrap();
    match first {
        Some(e) => Err(e),
        None => tp.finish(&mut *work, &mut events).map(|_| ()),
    }
}

/// Runs the toolpath stage over `layers`: boundary chains all close, only typed capacity errors,
/// extrusions (skirt aside) inside the input box.
fn check_layers(tp: &mut PropToolpath, layers: &Layers) -> Result<(), TestCaseError> {
    tp.reset(cfg()).unwrap();
    let mut work = Box::new(PropScratch::new());
    let mut moves = Vec::new();
    let mut events = |e: &ToolEvent<'_>| {
        if let ToolEvent::Move(m) = e {
            moves.push(*m);
        }
    };
    let mut result = Ok(());
    for (index, loops) in layers.iter().enumerate() {
        let mut points = Vec::new();
        let mut infos = Vec::new();
        for (pts, hole, parent) in loops {
            let start = points.len() as u32;
            points.extend(pts.iter().map(|&(x, y)| Point2::new(x, y)));
            infos.push(LoopInfo {
                start,
                len: pts.len() as u32,
                hole: *hole,
                parent: *parent,
                ..LoopInfo::default()
            });
        }
        let layer = Layer {
            index: index as u32,
            z_um: 100 + 200 * index as i32,
            points: &points,
            loops: &infos,
            repairs: LayerRepairs::default(),
            dropped_small_loops: 0,
            active_triangles: 0,
            segments: 0,
        };
        result = tp.push_layer(&layer, &mut *work, &mut events);
        if result.is_err() {
            break;
        }
    }
    if result.is_ok() {
        result = tp.finish(&mut *work, &mut events).map(|_| ());
    }
    // The offset arrangement closes every boundary chain.
    prop_assert_eq!(tp.stats().open_chains, 0);
    match result {
        Ok(()) => {}
        Err(ToolpathError::Capacity { layer, .. }) => {
            prop_assert!((layer as usize) < layers.len())
        }
        Err(e) => prop_assert!(false, "unexpected error {e:?}"),
    }
    // Extrusions (but the skirt) inside the input box.
    for m in moves.iter().filter(|m| m.e_um > 0) {
        if m.feature == strata::toolpath::Feature::Skirt
            || m.feature == strata::toolpath::Feature::Unretract
        {
            continue;
        }
        prop_assert!(
            (95_000..=125_000).contains(&m.to.x) && (95_000..=125_000).contains(&m.to.y),
            "{m:?}"
        );
    }
    Ok(())
}

/// Found by the unseeded property run: self-intersecting loops with repeated corners left one
/// boundary chain of an offset union open (the thin-area measurement's, which grows the
/// perimeters back: their edges, offsets of one input line cut into several loops, run nearly
/// parallel through nearly one point, and the rounded crossings never settled).
#[test]
fn self_intersecting_loops_with_repeated_corners_close_every_chain() {
    std::thread::Builder::new()
        .stack_size(256 << 20)
        .spawn(move || {
            let mut tp = Box::new(PropToolpath::new(cfg()).unwrap());
            check_layers(&mut tp, &self_intersecting_layer()).unwrap();
        })
        .unwrap()
        .join()
        .unwrap();
}

/// The same layer with the offsets done in bands (engines of a fraction of what the unions
/// need): every chain closes too, and the small engines give only typed capacity errors.
#[test]
fn self_intersecting_loops_close_every_chain_in_bands() {
    std::thread::Builder::new()
        .stack_size(256 << 20)
        .spawn(move || {
            let layers = self_intersecting_layer();
            let mut tp = Box::new(PropToolpath::new(cfg()).unwrap());
            check_layers(&mut tp, &layers).unwrap();
            let need = tp.stats().needs.offset_edges as usize;
            let mut banded = 0;
            for limit in (need / 4..need).step_by(7) {
                tp.set_offset_limit(limit);
                check_layers(&mut tp, &layers).unwrap();
                banded += usize::from(tp.stats().layers == 1);
            }
            assert!(banded > 0, "need {need}: no limit ran in bands");
        })
        .unwrap()
        .join()
        .unwrap();
}

/// A layer of self-intersecting loops, one with repeated corners.
fn self_intersecting_layer() -> Layers {
    vec![vec![
        (
            vec![
                (112318, 98665),
                (102017, 111252),
                (95000, 95000),
                (95000, 95000),
                (95000, 95000),
                (108478, 97917),
                (113701, 108633),
                (95199, 102869),
                (117258, 102063),
                (112927, 95000),
                (95000, 95000),
                (95708, 117453),
            ],
            true,
            Some(5),
        ),
        (
            vec![
                (99185, 98055),
                (109308, 102922),
                (95408, 113898),
                (115604, 114475),
                (109257, 102112),
                (101631, 115411),
                (95000, 111110),
                (110021, 104074),
                (97144, 95090),
            ],
            true,
            Some(1),
        ),
        (
            vec![
                (106454, 115924),
                (110248, 108782),
                (111188, 124864),
                (122568, 103140),
                (121031, 108479),
                (114343, 104345),
                (106905, 116995),
                (111261, 101018),
                (113322, 100394),
                (120778, 106954),
                (99437, 99526),
                (98102, 99674),
                (114358, 105489),
                (117342, 109213),
                (101042, 113144),
                (116215, 104768),
                (102145, 102136),
                (123723, 96243),
                (112338, 119837),
                (116968, 119477),
                (104423, 109642),
                (101371, 98684),
                (114789, 106177),
            ],
            false,
            None,
        ),
    ]]
}

/// One loop for the window scan: up to 14 points around a centre, spread from 3 mm (every
/// point an offset) to 1.2 m (escapes, and `t` beyond the header's packed range).
fn scan_loop() -> impl Strategy<Value = Vec<Point2>> {
    (prop::sample::select(vec![3_000i32, 60_000, 400_000, 1_200_000]), any::<(i16, i16)>())
        .prop_flat_map(|(spread, (cx, cy))| {
            let c = (i32::from(cx) * 16, i32::from(cy) * 16);
            prop::collection::vec((-spread..=spread, -spread..=spread), 0..14).prop_map(
                move |pts| pts.into_iter().map(|(x, y)| Point2::new(c.0 + x, c.1 + y)).collect(),
            )
        })
}

/// The spans along line `t` of the loops (those of at least three points), from every edge
/// of every loop: crossings where `min(t(p), t(q)) <= t < max`, at `u` rounded to nearest
/// (halves away from zero), sorted by `(u, dir)`, then the runs of non-zero winding.
fn reference_spans(loops: &[Vec<Point2>], angle: Angle, t: i64) -> (Vec<(i32, i32)>, usize) {
    let key = |p: Point2| {
        let (x, y) = (i64::from(p.x), i64::from(p.y));
        match angle {
            Angle::D45 => (y - x, x + y),
            Angle::D135 => (x + y, y - x),
            Angle::D0 => (y, x),
            Angle::D90 => (x, y),
        }
    };
    let mut cross = Vec::new();
    for pts in loops.iter().filter(|l| l.len() >= 3) {
        for (i, &p) in pts.iter().enumerate() {
            let ((tp, up), (tq, uq)) = (key(p), key(pts[(i + 1) % pts.len()]));
            if tp.min(tq) <= t && t < tp.max(tq) {
                let (num, den) = (i128::from(uq - up) * i128::from(t - tp), i128::from(tq - tp));
                let mag = (2 * num.abs() + den.abs()) / (2 * den.abs());
                let d = if (num < 0) != (den < 0) { -mag } else { mag };
                cross.push(((i128::from(up) + d) as i32, if tq > tp { 1 } else { -1 }));
            }
        }
    }
    cross.sort();
    let (mut spans, mut w, mut start) = (Vec::new(), 0, 0);
    for &(u, dir) in &cross {
        if w == 0 {
            start = u;
        }
        w += dir;
        if w == 0 && u > start {
            spans.push((start, u));
        }
    }
    (spans, cross.len())
}

#[test]
fn window_line_spans_skipping_loops_match_every_edge_of_every_loop() {
    let strategy = (
        prop::collection::vec(scan_loop(), 0..7),
        0usize..2048,
        prop::sample::select(vec![1i64, 636, 1414, 40_000]),
        any::<(u8, u16, i32)>(),
    );
    let mut runner = TestRunner::new_with_rng(
        Config::with_cases(400),
        TestRng::deterministic_rng(RngAlgorithm::ChaCha),
    );
    runner
        .run(&strategy, |(loops, skip, step, (dir, pick, line))| {
            // The loops stored as the window stores a layer, from anywhere in its storage.
            let mut fifo = Fifo::<u32, 2048>::new(0);
            fifo.reserve(skip).unwrap();
            fifo.commit(0, skip);
            fifo.pop();
            let mut enc = Encoder::new(fifo.reserve(2048).unwrap());
            for (island, pts) in loops.iter().enumerate() {
                enc.begin(island as u16).unwrap();
                pts.iter().for_each(|&p| enc.push(p).unwrap());
                enc.end(true);
            }
            let words = enc.finish(loops.len() as u32, loops.len() as u16);
            fifo.commit(1, words);
            let data = fifo.data(&fifo.find(1).unwrap());
            let angle = [Angle::D45, Angle::D135, Angle::D0, Angle::D90][usize::from(dir % 4)];
            // Lines through vertices (step 1), near them, and anywhere.
            let vertex_t: Vec<i64> = loops.iter().flatten().map(|&p| angle.key(p).0).collect();
            let mut lines = vec![i64::from(line / 4096)];
            if let Some(&t) = vertex_t.get(usize::from(pick) % vertex_t.len().max(1)) {
                let on = t.div_euclid(step);
                lines.extend([on - 1, on, on + 1]);
            }
            for line in lines {
                let line = line as i32;
                let t = i64::from(line) * step;
                let mut out = [Span::default(); 128];
                let near = StoredRings::new(data).near_line(angle, t);
                let (k, used) = line_spans(near, angle, line, step, &mut out).unwrap();
                let got: Vec<(i32, i32)> = out[..k].iter().map(|s| (s.u0, s.u1)).collect();
                let (want, crossings) = reference_spans(&loops, angle, t);
                prop_assert_eq!(&got, &want, "line {} step {}", line, step);
                prop_assert_eq!(used, crossings);
            }
            Ok(())
        })
        .unwrap();
}
