//! Reference STL writers that share no code with the parser (`strata::stl`).
//!
//! Binary files, ASCII files in several layouts, and ASCII files in the odd forms the desktop
//! slicers read. Numbers are written in Rust's shortest round-trip form, so they parse back to the
//! same bits.

use std::path::Path;

use strata::stl::RawTriangle;

use crate::mesh::{to_f32, StlTri, TriMm};

/// Facets with zero normals (what most writers of test models put there).
pub fn raw(tris: &[StlTri]) -> Vec<RawTriangle> {
    tris.iter().map(|&vertices| RawTriangle { normal: [0.0; 3], vertices }).collect()
}

/// A binary STL: `header` padded with spaces to 80 bytes, the `count` field (which may
/// disagree with the facets, for the parser's tests), 50-byte records with a zero attribute.
pub fn binary(header: &[u8], count: u32, triangles: &[RawTriangle]) -> Vec<u8> {
    let mut out = header.to_vec();
    out.resize(80, b' ');
    out.extend_from_slice(&count.to_le_bytes());
    for t in triangles {
        for v in t.normal.iter().chain(t.vertices.iter().flatten()) {
            out.extend_from_slice(&v.to_le_bytes());
        }
        out.extend_from_slice(&[0, 0]);
    }
    out
}

/// Writes `tris` to `path` as a binary STL: a zero header, zero normals (panics on an I/O
/// error).
pub fn write_file(path: &Path, tris: &[StlTri]) {
    let bytes = binary(&[0; 80], tris.len() as u32, &raw(tris));
    std::fs::write(path, bytes).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
}

/// Writes the mesh (mm) to `path` as a binary STL: [`write_file`] of its [`to_f32`] facets.
pub fn write_mesh(path: &Path, mesh: &[TriMm]) {
    write_file(path, &to_f32(mesh));
}

/// How [`ascii`] lays out the text.
#[derive(Debug, Clone, Copy, Default)]
pub struct AsciiStyle {
    /// CRLF line ends instead of LF.
    pub crlf: bool,
    /// Keywords in upper case.
    pub upper: bool,
    /// Numbers in exponent form (`1.5e0`) instead of plain shortest form.
    pub exponent: bool,
    /// Blanks before every line.
    pub indent: &'static str,
}

impl AsciiStyle {
    fn eol(&self) -> &'static str {
        if self.crlf {
            "\r\n"
        } else {
            "\n"
        }
    }

    fn keyword(&self, k: &str) -> String {
        if self.upper {
            k.to_uppercase()
        } else {
            k.to_string()
        }
    }

    fn number(&self, v: f32) -> String {
        if self.exponent {
            format!("{v:e}")
        } else {
            format!("{v}")
        }
    }
}

/// An ASCII STL of one solid named `name`.
pub fn ascii(name: &str, triangles: &[RawTriangle], style: AsciiStyle) -> Vec<u8> {
    let (eol, ind) = (style.eol(), style.indent);
    let kw = |k: &str| style.keyword(k);
    let mut s = format!("{ind}{} {name}{eol}", kw("solid"));
    for t in triangles {
        let [x, y, z] = t.normal.map(|v| style.number(v));
        s += &format!("{ind}{} {} {x} {y} {z}{eol}", kw("facet"), kw("normal"));
        s += &format!("{ind}  {} {}{eol}", kw("outer"), kw("loop"));
        for v in &t.vertices {
            let [x, y, z] = v.map(|v| style.number(v));
            s += &format!("{ind}    {} {x} {y} {z}{eol}", kw("vertex"));
        }
        s += &format!("{ind}  {}{eol}{ind}{}{eol}", kw("endloop"), kw("endfacet"));
    }
    s += &format!("{ind}{} {name}{eol}", kw("endsolid"));
    s.into_bytes()
}

/// What [`ascii_nonstandard`] put into a file, as the reader should report it.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Oddities {
    /// Facets written without three numbers as the normal.
    pub bad_normals: u32,
    /// Comment words after statements.
    pub comments: u32,
    /// NUL/SUB bytes at the end.
    pub padding: u32,
}

/// An ASCII STL in the odd forms the desktop slicers read, one form per facet in turn.
///
/// The forms: words and missing parts in the normal, `outer loop` variants, split closing
/// keywords, comments, facets after `endsolid`, a `solid` without `endsolid`; the file ends in
/// NUL/SUB padding.
///
/// Corners are written exactly as [`ascii`] does (`style.indent` is not used).
pub fn ascii_nonstandard(
    name: &str,
    triangles: &[RawTriangle],
    style: AsciiStyle,
) -> (Vec<u8>, Oddities) {
    let eol = style.eol();
    let kw = |k: &str| style.keyword(k);
    let mut odd = Oddities::default();
    let mut s = format!("{} {name}{eol}", kw("solid"));
    for (i, t) in triangles.iter().enumerate() {
        let [x, y, z] = t.normal.map(|v| style.number(v));
        let (normal, open, close, bad, comments) = match i % 8 {
            0 => ("normal +inf -inf weirdvalue".into(), "outer loop", "endloop foo", 1, 1),
            1 => (format!("normal {x} {y}"), "outerloop", "endloop", 1, 0),
            2 => (String::new(), "", "end loop", 1, 0),
            3 => (format!("{x} {y} {z} c1 c2"), "outer", "endloop", 0, 2),
            4 => ("normal -1.#IND00 NaN 1e39".into(), "loop", "end\tloop", 1, 0),
            _ => (format!("normal {x} {y} {z}"), "outer loop", "endloop", 0, 0),
        };
        odd.bad_normals += bad;
        odd.comments += comments;
        match i % 8 {
            5 => s += &format!("{}{eol}", kw("endsolid")),
            7 => s += &format!("{} part{i}{eol}", kw("solid")),
            _ => {}
        }
        s += &format!("{} {normal}{eol}{open}{eol}", kw("facet"));
        // Facet 6 of 8: a comment after its second corner and after `end facet`.
        let (note, end) =
            if i % 8 == 6 { (" (corner)", "end facet bar") } else { ("", "endfacet") };
        odd.comments += 2 * u32::from(i % 8 == 6);
        for (k, v) in t.vertices.iter().enumerate() {
            let [x, y, z] = v.map(|v| style.number(v));
            let note = if k == 1 { note } else { "" };
            s += &format!("  {} {x} {y} {z}{note}{eol}", kw("vertex"));
        }
        s += &format!("{close}{eol}{end}{eol}");
    }
    s += &format!("{} {name}{eol}", kw("end solid"));
    let mut out = s.into_bytes();
    out.extend_from_slice(b"\0\0\x1a");
    odd.padding = 3;
    (out, odd)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_binary_file_is_80_bytes_of_header_the_count_and_50_bytes_a_facet() {
        let t = [[[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [7.0, 8.0, 9.5]]];
        let b = binary(&[0; 80], 1, &raw(&t));
        assert_eq!(b.len(), 84 + 50);
        assert_eq!(&b[80..84], &1u32.to_le_bytes());
        assert_eq!(&b[84..96], &[0; 12]);
        assert_eq!(&b[96..100], &1.0f32.to_le_bytes());
        assert_eq!(&b[128..132], &9.5f32.to_le_bytes());
        assert_eq!(&b[132..], &[0, 0]);
    }

    #[test]
    fn ascii_layouts() {
        let t = raw(&[[[1.0, 0.0, 0.0], [0.0, 1.5, 0.0], [0.0, 0.0, 2.0]]]);
        let plain = String::from_utf8(ascii("x", &t, AsciiStyle::default())).unwrap();
        assert!(plain.starts_with("solid x\nfacet normal 0 0 0\n  outer loop\n"), "{plain}");
        assert!(plain.contains("    vertex 0 1.5 0\n") && plain.ends_with("endsolid x\n"));
        let style = AsciiStyle { crlf: true, upper: true, exponent: true, indent: " " };
        let odd = String::from_utf8(ascii("x", &t, style)).unwrap();
        assert!(odd.starts_with(" SOLID x\r\n FACET NORMAL 0e0 0e0 0e0\r\n"), "{odd}");
    }
}
