//! Test models for the CLI tests: a holed block written as binary STL.

use std::path::Path;

pub type Tri = [[f32; 3]; 3];

/// Closed block [x0,x1]x[y0,y1]x[0,h] with a square hole [i0,i1]^2 (outward winding).
pub fn holed_block(x0: f32, x1: f32, i0: f32, i1: f32, h: f32) -> Vec<Tri> {
    let outer = [[x0, x0], [x1, x0], [x1, x1], [x0, x1]];
    let inner = [[i0, i0], [i1, i0], [i1, i1], [i0, i1]];
    let at = |r: &[[f32; 2]; 4], j: usize, z: f32| [r[j % 4][0], r[j % 4][1], z];
    let mut t = Vec::new();
    for j in 0..4 {
        let (o, i) = (&outer, &inner);
        t.push([at(o, j, 0.0), at(o, j + 1, 0.0), at(o, j + 1, h)]);
        t.push([at(o, j, 0.0), at(o, j + 1, h), at(o, j, h)]);
        t.push([at(i, j, 0.0), at(i, j + 1, h), at(i, j + 1, 0.0)]);
        t.push([at(i, j, 0.0), at(i, j, h), at(i, j + 1, h)]);
        t.push([at(o, j, h), at(o, j + 1, h), at(i, j + 1, h)]);
        t.push([at(o, j, h), at(i, j + 1, h), at(i, j, h)]);
        t.push([at(o, j, 0.0), at(i, j + 1, 0.0), at(o, j + 1, 0.0)]);
        t.push([at(o, j, 0.0), at(i, j, 0.0), at(i, j + 1, 0.0)]);
    }
    t
}

/// Minimal binary STL writer (zero normals).
pub fn write_stl(path: &Path, tris: &[Tri]) {
    let mut b = vec![0u8; 80];
    b.extend_from_slice(&(tris.len() as u32).to_le_bytes());
    for t in tris {
        b.extend_from_slice(&[0u8; 12]);
        for c in t.iter().flatten() {
            b.extend_from_slice(&c.to_le_bytes());
        }
        b.extend_from_slice(&[0, 0]);
    }
    std::fs::write(path, b).unwrap();
}
