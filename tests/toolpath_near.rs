//! The nearest-path grid ([`strata::toolpath::near`]) returns exactly what a brute-force
//! scan returns (same item, same squared distance, lowest id among equals) on random point
//! sets, with items absent, filtered out and removed, queries inside and far outside the
//! grid, heavy duplicates and every cell budget, over the whole grid and within a box, also
//! when taken up again from its shape; and refuses item buffers that are too short.

use proptest::prelude::*;
use proptest::test_runner::{Config, TestRunner};
use strata::geom::Point2;
use strata::toolpath::near::{nearest_brute, GridFull, NearGrid};

/// Points: clustered on a coarse lattice (many exact ties) or spread over a 200 mm square;
/// `None` for items that are not indexed.
fn arb_points() -> impl Strategy<Value = Vec<Option<(i32, i32)>>> {
    let spread = (0..200_000i32, 0..200_000i32);
    let lattice = (0..6i32, 0..6i32).prop_map(|(x, y)| (50_000 + 700 * x, 80_000 + 700 * y));
    prop::collection::vec(
        prop_oneof![
            3 => spread.prop_map(Some),
            3 => lattice.prop_map(Some),
            1 => Just(None),
        ],
        0..300,
    )
}

#[test]
fn grid_nearest_equals_brute_force() {
    let mut runner = TestRunner::new(Config { cases: 256, ..Config::default() });
    let strategy = (
        arb_points(),
        prop::collection::vec((-100_000..300_000i32, -100_000..300_000i32), 1..40),
        prop::collection::vec(any::<bool>(), 300),
        1usize..400,
        any::<u64>(),
    );
    runner
        .run(&strategy, |(pts, queries, keep, cells, salt)| {
            let n = pts.len();
            let pos = |id: u32| pts[id as usize].map(|(x, y)| Point2::new(x, y));
            let (mut head, mut next) = (vec![0u32; cells], vec![0u32; n]);
            let mut grid = NearGrid::build(n, pos, &mut head, &mut next).expect("fits");
            let (nx, ny) = grid.dims();
            prop_assert!(nx * ny <= cells.max(1));
            // Remove some items (by the salt) from both the grid and the brute-force view.
            let removed: Vec<bool> = (0..n)
                .map(|id| {
                    let p = pos(id as u32).filter(|_| (salt >> (id % 64)) & 1 == 1 && id % 3 == 0);
                    if let Some(p) = p {
                        grid.remove(id as u32, p);
                    }
                    p.is_some()
                })
                .collect();
            // Taken up again over the same buffers (as a layer's emission does between
            // calls): the same grid.
            let shape = grid.shape();
            let grid = NearGrid::resume(shape, &mut head, &mut next).expect("the same buffers");
            prop_assert_eq!(grid.dims(), (nx, ny));
            let live = |id: u32| if removed[id as usize] { None } else { pos(id) };
            for (k, &(x, y)) in queries.iter().enumerate() {
                let q = Point2::new(x, y);
                // Alternate between accepting all and a random subset.
                let accept = |id: u32| k % 2 == 0 || keep[id as usize % keep.len()];
                let got = grid.nearest(q, pos, accept);
                let want = nearest_brute(n, q, live, accept);
                prop_assert_eq!(got, want, "query {:?}", q);
                // Restricted to a box around the next query point: the same as the scan of
                // the items inside it.
                let (bx, by) = queries[(k + 1) % queries.len()];
                let half = 1_000 + ((salt >> 8) % 60_000) as i32;
                let (lo, hi) =
                    (Point2::new(bx - half, by - half), Point2::new(bx + half, by + half));
                let inside = |id: u32| {
                    pos(id)
                        .is_some_and(|p| lo.x <= p.x && p.x <= hi.x && lo.y <= p.y && p.y <= hi.y)
                };
                let got = grid.nearest_in(q, lo, hi, pos, |id| inside(id) && accept(id));
                let want = nearest_brute(n, q, live, |id| inside(id) && accept(id));
                prop_assert_eq!(got, want, "query {:?} in {:?}..{:?}", q, lo, hi);
            }
            Ok(())
        })
        .unwrap();
}

#[test]
fn a_grid_is_not_resumed_over_buffers_too_short_for_it() {
    let pts = [Point2::new(0, 0), Point2::new(5_000, 5_000), Point2::new(9_000, 1_000)];
    let pos = |i: u32| pts.get(i as usize).copied();
    let (mut head, mut next) = ([0u32; 4], [0u32; 3]);
    let shape = NearGrid::build(3, pos, &mut head, &mut next).unwrap().shape();
    assert!(NearGrid::resume(shape, &mut head[..1], &mut next).is_none());
    assert!(NearGrid::resume(shape, &mut head, &mut next[..2]).is_none());
    let g = NearGrid::resume(shape, &mut head, &mut next).unwrap();
    assert_eq!(g.nearest(Point2::new(8_000, 0), pos, |_| true), Some((2_000_000, 2)));
}

#[test]
fn short_item_buffer_is_refused() {
    let pts = [Point2::new(0, 0), Point2::new(5, 5), Point2::new(9, 1)];
    let (mut head, mut next) = ([0u32; 4], [0u32; 2]);
    let e = NearGrid::build(3, |i| pts.get(i as usize).copied(), &mut head, &mut next).err();
    assert_eq!(e, Some(GridFull { items: 3, capacity: 2 }));
    let mut none: [u32; 0] = [];
    let mut next = [0u32; 3];
    assert!(NearGrid::build(3, |i| pts.get(i as usize).copied(), &mut none, &mut next).is_err());
}

#[test]
fn one_cell_and_empty_grids_work() {
    let pts = [Point2::new(10, 10), Point2::new(-4, 7), Point2::new(10, 10)];
    let pos = |i: u32| pts.get(i as usize).copied();
    let (mut head, mut next) = ([0u32; 1], [0u32; 3]);
    let g = NearGrid::build(3, pos, &mut head, &mut next).unwrap();
    assert_eq!(g.dims(), (1, 1));
    // Equal distance: the lowest id.
    assert_eq!(g.nearest(Point2::new(10, 10), pos, |_| true), Some((0, 0)));
    assert_eq!(g.nearest(Point2::new(10, 10), pos, |i| i != 0), Some((0, 2)));
    assert_eq!(g.nearest(Point2::new(10, 10), pos, |_| false), None);
    // Boxes: one holding only id 1, an empty one (lo above hi).
    assert_eq!(
        g.nearest_in(Point2::new(10, 10), Point2::new(-5, 0), Point2::new(0, 8), pos, |i| i == 1),
        Some((205, 1))
    );
    assert_eq!(
        g.nearest_in(Point2::new(10, 10), Point2::new(5, 5), Point2::new(1, 1), pos, |_| true),
        None
    );
    let (mut head, mut next) = ([0u32; 8], [0u32; 0]);
    let g = NearGrid::build(0, |_| None, &mut head, &mut next).unwrap();
    assert_eq!(g.nearest(Point2::new(1, 1), |_| None, |_| true), None);
}

#[test]
fn a_tie_just_beyond_the_searched_cells_goes_to_the_lower_id() {
    // Two cells of 12 um along x (bounding box 0..=21): the query at x = 11 finds id 1 at
    // distance 1 in its own cell; id 0, in the next cell, is exactly as far and wins the tie.
    let pts = [Point2::new(12, 0), Point2::new(10, 0), Point2::new(0, 0), Point2::new(21, 0)];
    let pos = |i: u32| pts.get(i as usize).copied();
    let (mut head, mut next) = ([0u32; 2], [0u32; 4]);
    let g = NearGrid::build(4, pos, &mut head, &mut next).unwrap();
    assert_eq!(g.dims(), (2, 1));
    assert_eq!(g.nearest(Point2::new(11, 0), pos, |_| true), Some((1, 0)));
    assert_eq!(nearest_brute(4, Point2::new(11, 0), pos, |_| true), Some((1, 0)));
}
