//! Analytic test shapes.
//!
//! Every shape is built in mm as `f64` triangles ([`TriMm`]), corners counter-clockwise seen from
//! outside, and then quantised: to the core's um [`Triangle`]s with [`to_um`] (what the slicer and
//! the printer take), or to the `f32` corners of an STL file with [`to_f32`] (what the host's CLI
//! reads, see [`crate::stl`]). Both drop the triangles whose corners coincide (the pole triangles
//! of a [`sphere`]), so the um and the STL forms of a shape have the same triangles.
//!
//! The shapes are closed (watertight) unless said otherwise: rings lofted into walls with
//! fan caps ([`loft`], [`prism`], [`cuboid`]), a prism with a hole ([`holed_prism`],
//! [`holed_block`]), parametric grids ([`sphere`], [`torus`]), profiles swept along y
//! ([`sweep_y`]) for the overhang parts ([`bridge_part`], [`tee_part`], [`wedge_part`],
//! [`arch_part`], [`tunnel_part`]; all of them: [`overhang_parts`]).

use std::f64::consts::PI;

use strata::geom::{Point3, Triangle};

/// A triangle in mm, corners counter-clockwise seen from outside.
pub type TriMm = [[f64; 3]; 3];

/// A triangle as an STL file stores it: `f32` corners (mm).
pub type StlTri = [[f32; 3]; 3];

/// Walls between consecutive rings plus fan caps from the centre of the first and the last ring.
///
/// The rings have the same point count, counter-clockwise from above; the caps need rings
/// star-shaped from their centre (convex rings, and the fin blocks of the thin-wall tests).
///
/// Each ring: (z, points) in mm.
pub fn loft(rings: &[(f64, Vec<[f64; 2]>)]) -> Vec<TriMm> {
    let mut out = Vec::new();
    let p = |r: usize, j: usize| {
        let (z, pts) = &rings[r];
        let [x, y] = pts[j % pts.len()];
        [x, y, *z]
    };
    let n = rings[0].1.len();
    for r in 0..rings.len() - 1 {
        for j in 0..n {
            // east x up = outward
            out.push([p(r, j), p(r, j + 1), p(r + 1, j + 1)]);
            out.push([p(r, j), p(r + 1, j + 1), p(r + 1, j)]);
        }
    }
    let centre = |r: usize| {
        let pts = &rings[r].1;
        let c = pts.iter().fold([0.0, 0.0], |a, q| [a[0] + q[0], a[1] + q[1]]);
        [c[0] / pts.len() as f64, c[1] / pts.len() as f64, rings[r].0]
    };
    let (bottom, top) = (0, rings.len() - 1);
    for j in 0..n {
        out.push([centre(bottom), p(bottom, j + 1), p(bottom, j)]);
        out.push([centre(top), p(top, j), p(top, j + 1)]);
    }
    out
}

/// Prism over a counter-clockwise polygon (mm) between `z0` and `z1`: a [`loft`] of two rings.
pub fn prism(poly: &[[f64; 2]], z0: f64, z1: f64) -> Vec<TriMm> {
    loft(&[(z0, poly.to_vec()), (z1, poly.to_vec())])
}

/// Regular `n`-gon around (`cx`, `cy`) of circumradius `r` (mm), counter-clockwise, its first
/// corner at angle `phase` (radians).
pub fn ngon(n: usize, cx: f64, cy: f64, r: f64, phase: f64) -> Vec<[f64; 2]> {
    (0..n)
        .map(|j| {
            let a = phase + 2.0 * PI * j as f64 / n as f64;
            [cx + r * a.cos(), cy + r * a.sin()]
        })
        .collect()
}

/// The axis-aligned square [`lo`, `hi`]^2 (mm), counter-clockwise from (`lo`, `lo`).
pub fn square(lo: f64, hi: f64) -> Vec<[f64; 2]> {
    vec![[lo, lo], [hi, lo], [hi, hi], [lo, hi]]
}

/// Axis-aligned box from `min` to `max` (mm): four walls of two triangles, caps of four
/// (16 triangles; the 8 horizontal ones span no slicing plane).
pub fn cuboid(min: [f64; 3], max: [f64; 3]) -> Vec<TriMm> {
    let ring = vec![[min[0], min[1]], [max[0], min[1]], [max[0], max[1]], [min[0], max[1]]];
    loft(&[(min[2], ring.clone()), (max[2], ring)])
}

/// Prism over a polygon ring with a same-sized polygon hole (both counter-clockwise, points
/// matched by index) between `z0` and `z1` (mm): 8 triangles per corner.
pub fn holed_prism(outer: &[[f64; 2]], inner: &[[f64; 2]], z0: f64, z1: f64) -> Vec<TriMm> {
    let mut out = Vec::new();
    let n = outer.len();
    let at = |ring: &[[f64; 2]], j: usize, z: f64| [ring[j % n][0], ring[j % n][1], z];
    for j in 0..n {
        let (o0, o1, i0, i1) = (j, j + 1, j, j + 1);
        // Outer wall outward, inner wall facing the hole.
        out.push([at(outer, o0, z0), at(outer, o1, z0), at(outer, o1, z1)]);
        out.push([at(outer, o0, z0), at(outer, o1, z1), at(outer, o0, z1)]);
        out.push([at(inner, i0, z0), at(inner, i1, z1), at(inner, i1, z0)]);
        out.push([at(inner, i0, z0), at(inner, i0, z1), at(inner, i1, z1)]);
        // Caps: top faces up, bottom faces down.
        out.push([at(outer, o0, z1), at(outer, o1, z1), at(inner, i1, z1)]);
        out.push([at(outer, o0, z1), at(inner, i1, z1), at(inner, i0, z1)]);
        out.push([at(outer, o0, z0), at(inner, i1, z0), at(outer, o1, z0)]);
        out.push([at(outer, o0, z0), at(inner, i0, z0), at(inner, i1, z0)]);
    }
    out
}

/// The block [`x0`, `x1`]^2 x [0, `h`] (mm) with the square through-hole [`i0`, `i1`]^2: a
/// [`holed_prism`] of two squares, 32 triangles (the CLI tests' model).
pub fn holed_block(x0: f64, x1: f64, i0: f64, i1: f64, h: f64) -> Vec<TriMm> {
    holed_prism(&square(x0, x1), &square(i0, i1), 0.0, h)
}

/// Four separate holed discs (24-gons 11.8 mm across with 2 mm holes, 12 mm apart) around
/// (`c`, `c`) mm, from z 0 to `height` mm: several islands, holes and travels between them.
pub fn four_holed_discs(c: f64, height: f64) -> Vec<TriMm> {
    let mut plate = Vec::new();
    for (dx, dy) in [(-6.0, -6.0), (6.0, -6.0), (-6.0, 6.0), (6.0, 6.0)] {
        let (hx, hy) = (c + dx, c + dy);
        plate.extend(holed_prism(
            &ngon(24, hx, hy, 5.9, 0.0),
            &ngon(24, hx, hy, 2.0, 0.0),
            0.0,
            height,
        ));
    }
    plate
}

/// A closed parametric surface on a `nu` x `nv` grid.
///
/// `f(u, v)` with u, v in [0, 1]; u wraps, v wraps too when `wrap_v` (torus) and otherwise runs
/// pole to pole (sphere: the triangles at the poles are degenerate, [`to_um`] and [`to_f32`] drop
/// them). Orientation: df/du x df/dv must point outward.
pub fn grid(nu: usize, nv: usize, wrap_v: bool, f: impl Fn(f64, f64) -> [f64; 3]) -> Vec<TriMm> {
    let p = |i: usize, j: usize| f((i % nu) as f64 / nu as f64, j as f64 / nv as f64);
    let mut out = Vec::new();
    for i in 0..nu {
        for j in 0..nv {
            let jw = if wrap_v { (j + 1) % nv } else { j + 1 };
            out.push([p(i, j), p(i + 1, j), p(i + 1, jw)]);
            out.push([p(i, j), p(i + 1, jw), p(i, jw)]);
        }
    }
    out
}

/// UV sphere of radius `r` around `c` (mm), `nu` segments around, `nv` from pole to pole:
/// `2 nu (nv - 1)` triangles once the degenerate pole triangles are dropped.
pub fn sphere(c: [f64; 3], r: f64, nu: usize, nv: usize) -> Vec<TriMm> {
    grid(nu, nv, false, |u, v| {
        let (phi, theta) = (2.0 * PI * u, PI * v - PI / 2.0);
        // Poles exactly on the axis.
        let ring = if v == 0.0 || v == 1.0 { 0.0 } else { r * theta.cos() };
        [c[0] + ring * phi.cos(), c[1] + ring * phi.sin(), c[2] + r * theta.sin()]
    })
}

/// Torus around a vertical axis through `c`: tube radius `r` at distance `big_r` (mm).
pub fn torus(c: [f64; 3], big_r: f64, r: f64, nu: usize, nv: usize) -> Vec<TriMm> {
    grid(nu, nv, true, |u, v| {
        let (phi, psi) = (2.0 * PI * u, 2.0 * PI * v);
        let rho = big_r + r * psi.cos();
        [c[0] + rho * phi.cos(), c[1] + rho * phi.sin(), c[2] + r * psi.sin()]
    })
}

/// Triangles (corner indices, counter-clockwise) of a simple counter-clockwise polygon, by ear
/// clipping (no new corners: a cap that shares its edges with the walls).
pub fn triangulate(poly: &[[f64; 2]]) -> Vec<[usize; 3]> {
    let turn = |o: [f64; 2], a: [f64; 2], b: [f64; 2]| {
        (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])
    };
    let mut left: Vec<usize> = (0..poly.len()).collect();
    let mut out = Vec::new();
    while left.len() > 3 {
        let n = left.len();
        let ear = (0..n)
            .find(|&k| {
                let (i, j, l) = (left[(k + n - 1) % n], left[k], left[(k + 1) % n]);
                let (a, b, c) = (poly[i], poly[j], poly[l]);
                turn(a, b, c) > 0.0
                    && left.iter().filter(|&&m| m != i && m != j && m != l).all(|&m| {
                        let p = poly[m];
                        turn(a, b, p) < 0.0 || turn(b, c, p) < 0.0 || turn(c, a, p) < 0.0
                    })
            })
            .expect("a simple counter-clockwise polygon has an ear");
        out.push([left[(ear + n - 1) % n], left[ear], left[(ear + 1) % n]]);
        left.remove(ear);
    }
    out.push([left[0], left[1], left[2]]);
    out
}

/// A profile in the XZ plane (points (x, z) in mm, a simple polygon counter-clockwise with x
/// to the right and z up) swept along y from `y0` to `y1`: walls and ear-clipped caps.
pub fn sweep_y(profile: &[[f64; 2]], y0: f64, y1: f64) -> Vec<TriMm> {
    let n = profile.len();
    let at = |j: usize, y: f64| [profile[j % n][0], y, profile[j % n][1]];
    let mut out = Vec::new();
    for j in 0..n {
        // Edge j -> j+1 turns its outside to the right (counter-clockwise profile).
        out.push([at(j, y0), at(j + 1, y1), at(j + 1, y0)]);
        out.push([at(j, y0), at(j, y1), at(j + 1, y1)]);
    }
    for [i, j, k] in triangulate(profile) {
        // Seen from -y, x right and z up: counter-clockwise faces -y.
        out.push([at(i, y0), at(j, y0), at(k, y0)]);
        out.push([at(i, y1), at(k, y1), at(j, y1)]);
    }
    out
}

/// `profile` moved by (`dx`, `dz`) mm.
fn shifted(profile: &[[f64; 2]], dx: f64, dz: f64) -> Vec<[f64; 2]> {
    profile.iter().map(|&[x, z]| [x + dx, z + dz]).collect()
}

/// Overhang part: a plain bridge, corner (`x`, `y`) mm. Two 10 x 10 x 10 mm posts 20 mm apart
/// (x 0..10 and 30..40) joined by a 40 x 10 x 2 mm slab on top (z 10..12); one body.
pub fn bridge_part(x: f64, y: f64) -> Vec<TriMm> {
    let profile = [
        [0.0, 0.0],
        [10.0, 0.0],
        [10.0, 10.0],
        [30.0, 10.0],
        [30.0, 0.0],
        [40.0, 0.0],
        [40.0, 12.0],
        [0.0, 12.0],
    ];
    sweep_y(&shifted(&profile, x, 0.0), y, y + 10.0)
}

/// Overhang part: a T, corner (`x`, `y`) mm. A 10 mm square stem 15 mm tall (x 15..25)
/// under a 40 x 10 x 3 mm bar (z 15..18): 15 mm of bar overhangs on each side.
pub fn tee_part(x: f64, y: f64) -> Vec<TriMm> {
    let profile = [
        [15.0, 0.0],
        [25.0, 0.0],
        [25.0, 15.0],
        [40.0, 15.0],
        [40.0, 18.0],
        [0.0, 18.0],
        [0.0, 15.0],
        [15.0, 15.0],
    ];
    sweep_y(&shifted(&profile, x, 0.0), y, y + 10.0)
}

/// Overhang part: a wedge, corner (`x`, `y`) mm, 10 mm deep (y) and 8 mm tall: a 5 mm base
/// whose +x face leans out at `deg` degrees from vertical.
pub fn wedge_part(x: f64, y: f64, deg: f64) -> Vec<TriMm> {
    let reach = 8.0 * deg.to_radians().tan();
    let profile = [[0.0, 0.0], [5.0, 0.0], [5.0 + reach, 8.0], [0.0, 8.0]];
    sweep_y(&shifted(&profile, x, 0.0), y, y + 10.0)
}

/// Overhang part: three [`wedge_part`]s 15 mm apart in y, leaning out at 45, 60 and 75 degrees.
pub fn wedges_part(x: f64, y: f64) -> Vec<TriMm> {
    [45.0, 60.0, 75.0]
        .into_iter()
        .enumerate()
        .flat_map(|(k, deg)| wedge_part(x, y + 15.0 * k as f64, deg))
        .collect()
}

/// Overhang part: an arch, corner (`x`, `y`) mm. A 30 x 10 x 15 mm block with a half-cylinder
/// tunnel of radius 10 mm along y through it (axis at x 15 on the bed, a 48-gon half).
pub fn arch_part(x: f64, y: f64) -> Vec<TriMm> {
    let mut profile = vec![[0.0, 0.0]];
    let n = 48;
    for k in 0..=n {
        let a = PI * k as f64 / n as f64;
        profile.push([15.0 - 10.0 * a.cos(), 10.0 * a.sin()]);
    }
    profile.extend([[30.0, 0.0], [30.0, 15.0], [0.0, 15.0]]);
    sweep_y(&shifted(&profile, x, 0.0), y, y + 10.0)
}

/// Overhang part: an upside-down U, corner (`x`, `y`) mm. Two 2 mm walls 10 mm tall and 30 mm
/// long (y), 20 mm apart (x 0..2 and 22..24), under a 2 mm roof (z 10..12): a bridge held
/// along both its sides.
pub fn tunnel_part(x: f64, y: f64) -> Vec<TriMm> {
    let profile = [
        [0.0, 0.0],
        [2.0, 0.0],
        [2.0, 10.0],
        [22.0, 10.0],
        [22.0, 0.0],
        [24.0, 0.0],
        [24.0, 12.0],
        [0.0, 12.0],
    ];
    sweep_y(&shifted(&profile, x, 0.0), y, y + 30.0)
}

/// The overhang parts with their corner at (`x`, `y`) mm, named: the bridge, the T, the
/// three wedges apart, the arch and the upside-down U.
pub fn overhang_parts(x: f64, y: f64) -> Vec<(&'static str, Vec<TriMm>)> {
    vec![
        ("bridge", bridge_part(x, y)),
        ("T", tee_part(x, y)),
        ("wedge 45 deg", wedge_part(x, y, 45.0)),
        ("wedge 60 deg", wedge_part(x, y, 60.0)),
        ("wedge 75 deg", wedge_part(x, y, 75.0)),
        ("arch r10", arch_part(x, y)),
        ("upside-down U", tunnel_part(x, y)),
    ]
}

/// The same surface with every triangle's winding reversed (normals inward: a cavity).
pub fn inverted(mesh: Vec<TriMm>) -> Vec<TriMm> {
    mesh.into_iter().map(|[a, b, c]| [a, c, b]).collect()
}

/// mm to um, rounded to the nearest.
pub fn um(mm: f64) -> i32 {
    (mm * 1000.0).round() as i32
}

/// Quantises to um (no offset), drops triangles whose corners coincide after rounding, and
/// sorts by lowest z (stable): the order the slicer and the printer take triangles in.
pub fn to_um(mesh: &[TriMm]) -> Vec<Triangle> {
    let mut out: Vec<Triangle> = mesh
        .iter()
        .map(|t| Triangle { v: t.map(|[x, y, z]| Point3::new(um(x), um(y), um(z))) })
        .filter(|t| t.v[0] != t.v[1] && t.v[1] != t.v[2] && t.v[2] != t.v[0])
        .collect();
    out.sort_by_key(Triangle::z_min);
    out
}

/// The corners as `f32` (mm), in the mesh's order, without the triangles whose corners
/// coincide: the facets of an STL file of the shape.
pub fn to_f32(mesh: &[TriMm]) -> Vec<StlTri> {
    mesh.iter()
        .map(|t| t.map(|p| p.map(|c| c as f32)))
        .filter(|t| t[0] != t[1] && t[1] != t[2] && t[2] != t[0])
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shapes_have_the_documented_triangle_counts() {
        assert_eq!(to_um(&cuboid([0.0; 3], [1.0; 3])).len(), 16);
        assert_eq!(holed_block(-5.0, 5.0, -2.0, 2.0, 1.2).len(), 32);
        assert_eq!(to_um(&sphere([0.0, 0.0, 5.0], 5.0, 96, 48)).len(), 2 * 96 * 47);
        assert_eq!(to_f32(&sphere([0.0, 0.0, 5.0], 5.0, 96, 48)).len(), 2 * 96 * 47);
    }

    #[test]
    fn every_edge_is_shared_by_two_triangles_in_opposite_directions() {
        let closed = |mesh: &[Triangle]| {
            let mut edges = std::collections::HashMap::new();
            for t in mesh {
                for k in 0..3 {
                    let (a, b) = (t.v[k], t.v[(k + 1) % 3]);
                    *edges.entry((a, b)).or_insert(0) += 1;
                }
            }
            edges.iter().all(|(&(a, b), &n)| n == 1 && edges.get(&(b, a)) == Some(&1))
        };
        assert!(closed(&to_um(&cuboid([1.0, 2.0, 0.0], [4.0, 5.0, 2.0]))));
        assert!(closed(&to_um(&holed_block(-5.0, 5.0, -2.0, 2.0, 1.2))));
        assert!(closed(&to_um(&sphere([10.0, 10.0, 5.0], 5.0, 24, 12))));
        assert!(closed(&to_um(&torus([20.0, 20.0, 4.0], 8.0, 3.0, 32, 12))));
        assert!(closed(&to_um(&four_holed_discs(30.0, 1.0))));
        for (name, part) in overhang_parts(100.0, 100.0) {
            assert!(closed(&to_um(&part)), "{name}");
        }
    }

    /// Enclosed volume (divergence theorem): positive when the triangles face outward.
    fn volume(mesh: &[TriMm]) -> f64 {
        let det = |[a, b, c]: &TriMm| {
            a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
                + a[2] * (b[0] * c[1] - b[1] * c[0])
        };
        mesh.iter().map(det).sum::<f64>() / 6.0
    }

    #[test]
    fn overhang_parts_face_outward_and_enclose_their_volumes() {
        let tan = |deg: f64| deg.to_radians().tan();
        // Half a 48-gon of radius 10 mm inscribed in the half circle.
        let half_48gon = 0.5 * 100.0 * 48.0 * (PI / 48.0).sin();
        let wedge = |deg: f64| (5.0 * 8.0 + 0.5 * 8.0 * 8.0 * tan(deg)) * 10.0;
        let want = [
            2.0 * 1000.0 + 40.0 * 10.0 * 2.0,
            10.0 * 10.0 * 15.0 + 40.0 * 10.0 * 3.0,
            wedge(45.0),
            wedge(60.0),
            wedge(75.0),
            (30.0 * 15.0 - half_48gon) * 10.0,
            (2.0 * 2.0 * 10.0 + 24.0 * 2.0) * 30.0,
        ];
        let parts = overhang_parts(100.0, 100.0);
        assert_eq!(parts.len(), want.len());
        for ((name, part), want) in parts.iter().zip(want) {
            let v = volume(part);
            assert!((v - want).abs() < 1e-6 * want, "{name}: {v} mm^3, want {want}");
        }
        let three: f64 = [45.0, 60.0, 75.0].map(wedge).iter().sum();
        assert!((volume(&wedges_part(0.0, 0.0)) - three).abs() < 1e-6 * three);
    }
}
