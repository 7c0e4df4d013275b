//! The quadric simplifier (`strata_host::simplify`) against analytic oracles: a finely
//! tessellated box (planar faces collapse to a handful of triangles, the volume and surface
//! stay exact), a UV sphere (vertices stay near the radius, volume between the shell's balls,
//! normals outward), a torus (genus kept), an open patch (boundary loop length kept) and the
//! measured two-sided deviation (`admission::hausdorff_mm`) within the bound for all of them.

use std::collections::BTreeMap;
use std::f64::consts::PI;

use strata::geom::{Point3, Triangle};
use strata_host::admission::hausdorff_mm;
use strata_host::simplify::{simplify, weld, Options};
use strata_testkit::mesh::{sphere, to_um, torus, TriMm};

type V = [f64; 3];

fn mm(p: Point3) -> V {
    [p.x as f64 / 1e3, p.y as f64 / 1e3, p.z as f64 / 1e3]
}
fn sub(a: V, b: V) -> V {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
fn dot(a: V, b: V) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn cross(a: V, b: V) -> V {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

/// Directed edges of the welded mesh, counted.
fn directed_edges(tris: &[Triangle]) -> BTreeMap<(u32, u32), u32> {
    let (_, idx) = weld(tris);
    let mut out = BTreeMap::new();
    for f in idx.chunks_exact(3) {
        for k in 0..3 {
            *out.entry((f[k], f[(k + 1) % 3])).or_insert(0) += 1;
        }
    }
    out
}

/// Every edge in exactly two triangles, wound once each way.
fn assert_watertight(tris: &[Triangle]) {
    let edges = directed_edges(tris);
    for (&(a, b), &n) in &edges {
        assert_eq!(n, 1, "edge {a}-{b} wound {n} times the same way");
        assert_eq!(edges.get(&(b, a)), Some(&1), "edge {a}-{b} has no opposite");
    }
}

/// V - E + F of the welded mesh.
fn euler(tris: &[Triangle]) -> i64 {
    let (points, _) = weld(tris);
    let edges = directed_edges(tris);
    let e = edges.keys().filter(|(a, b)| a < b || !edges.contains_key(&(*b, *a))).count();
    points.len() as i64 - e as i64 + tris.len() as i64
}

/// Enclosed volume, mm^3 (divergence theorem; outward winding gives a positive volume).
fn volume(tris: &[Triangle]) -> f64 {
    tris.iter().map(|t| dot(mm(t.v[0]), cross(mm(t.v[1]), mm(t.v[2]))) / 6.0).sum()
}

/// A box [0, s]^3 mm, each face an `n` x `n` grid of squares cut in two, outward winding.
fn fine_box(s: f64, n: usize) -> Vec<TriMm> {
    // (normal axis, side, tangent s, tangent t) with s x t outward.
    let faces: [(usize, f64, usize, usize); 6] = [
        (0, 1.0, 1, 2),
        (0, 0.0, 2, 1),
        (1, 1.0, 2, 0),
        (1, 0.0, 0, 2),
        (2, 1.0, 0, 1),
        (2, 0.0, 1, 0),
    ];
    let mut out = Vec::new();
    for (axis, side, ts, tt) in faces {
        let p = |i: usize, j: usize| {
            let mut v = [0.0; 3];
            v[axis] = side * s;
            v[ts] = s * i as f64 / n as f64;
            v[tt] = s * j as f64 / n as f64;
            v
        };
        for i in 0..n {
            for j in 0..n {
                out.push([p(i, j), p(i + 1, j), p(i + 1, j + 1)]);
                out.push([p(i, j), p(i + 1, j + 1), p(i, j + 1)]);
            }
        }
    }
    out
}

#[test]
fn a_finely_tessellated_box_collapses_to_its_faces() {
    let tris = to_um(&fine_box(20.0, 20));
    assert_eq!(tris.len(), 6 * 800);
    assert_watertight(&tris);
    let out = simplify(&tris, 0.05, Options::default());
    assert!(out.len() <= 24, "{} triangles", out.len());
    assert_watertight(&out);
    assert!(hausdorff_mm(&tris, &out) < 1e-6);
    let v = volume(&out);
    assert!((v - 8000.0).abs() <= 8000.0 * 1e-6, "volume {v}");
}

#[test]
fn a_sphere_stays_within_the_bound_of_its_radius() {
    let (c, r, nu, nv) = ([50.0, 50.0, 50.0], 10.0, 96, 48);
    let tris = to_um(&sphere(c, r, nu, nv));
    // The original's faces lie inside the sphere by at most the sag of the largest triangle
    // (corners on the sphere; its diagonal spans at most one step in longitude plus one in
    // latitude), plus the um rounding.
    let alpha = 2.0 * PI / nu as f64 + PI / nv as f64;
    let sag = r * (1.0 - (alpha / 2.0).cos()) + 0.001;
    for d in [0.02, 0.05, 0.2] {
        let out = simplify(&tris, d, Options::default());
        assert!(out.len() < tris.len() / 3, "{d}: {} of {} triangles", out.len(), tris.len());
        assert_watertight(&out);
        assert_eq!(euler(&out), 2);
        let h = hausdorff_mm(&tris, &out);
        assert!(h <= d, "{d}: measured {h}");
        for t in &out {
            for p in t.v {
                let rho = dot(sub(mm(p), c), sub(mm(p), c)).sqrt();
                assert!((rho - r).abs() <= d + sag, "{d}: vertex at radius {rho}");
            }
            let [a, b, e] = t.v.map(mm);
            let n = cross(sub(b, a), sub(e, a));
            let centroid = [0, 1, 2].map(|k| (a[k] + b[k] + e[k]) / 3.0 - c[k]);
            assert!(dot(n, centroid) > 0.0, "{d}: face {t:?} points inwards");
        }
        // The surface lies in the shell [r - sag - d, r + d]: so does its volume's radius.
        let ball = |x: f64| 4.0 / 3.0 * PI * x * x * x;
        let v = volume(&out);
        assert!(ball(r - sag - d) <= v && v <= ball(r + d), "{d}: volume {v}");
    }
}

#[test]
fn a_torus_keeps_its_genus() {
    let tris = to_um(&torus([50.0, 50.0, 20.0], 20.0, 6.0, 96, 48));
    assert_eq!(euler(&tris), 0);
    let d = 0.05;
    let out = simplify(&tris, d, Options::default());
    assert!(out.len() < tris.len() / 3, "{} of {} triangles", out.len(), tris.len());
    assert_watertight(&out);
    assert_eq!(euler(&out), 0);
    assert!(hausdorff_mm(&tris, &out) <= d);
    // A coarse bound keeps the hole too.
    let out = simplify(&tris, 3.0, Options::default());
    assert_watertight(&out);
    assert_eq!(euler(&out), 0, "{} triangles", out.len());
}

/// The boundary edges' total length, mm.
fn boundary_length(tris: &[Triangle]) -> f64 {
    let (points, _) = weld(tris);
    let edges = directed_edges(tris);
    edges
        .keys()
        .filter(|(a, b)| !edges.contains_key(&(*b, *a)))
        .map(|&(a, b)| {
            let e = sub(mm(points[a as usize]), mm(points[b as usize]));
            dot(e, e).sqrt()
        })
        .sum()
}

#[test]
fn an_open_patch_keeps_its_boundary() {
    // A bump on a 20 mm square, flat along its edges: one boundary loop of 80 mm.
    let bump = |u: f64, v: f64| {
        let (x, y) = (20.0 * u, 20.0 * v);
        [x + 10.0, y + 10.0, 5.0 + 2.0 * (PI * u).sin() * (PI * v).sin()]
    };
    // testkit's `grid` wraps u: the open patch is built here.
    let n = 40;
    let p = |i: usize, j: usize| bump(i as f64 / n as f64, j as f64 / n as f64);
    let mut mesh = Vec::new();
    for i in 0..n {
        for j in 0..n {
            mesh.push([p(i, j), p(i + 1, j), p(i + 1, j + 1)]);
            mesh.push([p(i, j), p(i + 1, j + 1), p(i, j + 1)]);
        }
    }
    let tris = to_um(&mesh);
    let before = boundary_length(&tris);
    assert!((before - 80.0).abs() < 1e-6, "{before}");
    let d = 0.05;
    let out = simplify(&tris, d, Options::default());
    assert!(out.len() < tris.len() / 4, "{} of {} triangles", out.len(), tris.len());
    let after = boundary_length(&out);
    assert!((after - before).abs() <= d, "boundary {before} mm before, {after} mm after");
    assert!(hausdorff_mm(&tris, &out) <= d);
    assert_eq!(euler(&out), 1);
}

#[test]
fn degenerate_and_empty_input_give_no_panic_and_same_output_twice() {
    assert!(simplify(&[], 0.05, Options::default()).is_empty());
    let p = |x: i32, y: i32, z: i32| Point3::new(x, y, z);
    let mut tris = to_um(&sphere([20.0, 20.0, 20.0], 5.0, 24, 12));
    // A repeated corner, a needle without area, a lone triangle.
    tris.push(Triangle { v: [p(1, 1, 1), p(1, 1, 1), p(2, 2, 2)] });
    tris.push(Triangle { v: [p(0, 0, 0), p(1000, 0, 0), p(2000, 0, 0)] });
    tris.push(Triangle { v: [p(0, 5000, 0), p(1000, 5000, 0), p(0, 6000, 0)] });
    let a = simplify(&tris, 0.1, Options::default());
    let b = simplify(&tris, 0.1, Options::default());
    assert_eq!(a, b);
    assert!(a.len() < tris.len());
    assert!(simplify(&tris, f64::NAN, Options::default()).len() >= tris.len() - 1);
}
