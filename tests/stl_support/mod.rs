//! STL test helpers: chunked parsing, bit-exact comparison, and reference writers for binary
//! and ASCII STL that do not share code with the parser.
#![allow(dead_code)] // each test crate uses a different subset

use strata::stl::{RawTriangle, StlError, StlReader, StlSummary};

/// What one parse produced: the facets passed to the sink, and the outcome.
#[derive(Debug, Clone, PartialEq)]
pub struct Parsed {
    /// Facets in sink order.
    pub triangles: Vec<RawTriangle>,
    /// `finish`'s summary, or the first error of `feed`/`finish`.
    pub result: Result<StlSummary, StlError>,
}

impl Parsed {
    /// The facets as bit patterns, so that NaN normals and -0.0 compare exactly.
    pub fn bits(&self) -> Vec<[u32; 12]> {
        self.triangles.iter().map(bits).collect()
    }
}

/// Feeds `bytes` split at the given increasing cut positions.
pub fn parse_split(bytes: &[u8], cuts: &[usize]) -> Parsed {
    let mut reader = StlReader::new();
    let mut triangles = Vec::new();
    let mut from = 0;
    for &to in cuts.iter().chain([bytes.len()].iter()) {
        let to = to.clamp(from, bytes.len());
        if let Err(e) = reader.feed(&bytes[from..to], &mut |t| triangles.push(t)) {
            return Parsed { triangles, result: Err(e) };
        }
        from = to;
    }
    let result = reader.finish();
    Parsed { triangles, result }
}

/// Feeds `bytes` in chunks of `size` bytes (the last one shorter).
pub fn parse_chunked(bytes: &[u8], size: usize) -> Parsed {
    let cuts: Vec<usize> = (size.max(1)..bytes.len()).step_by(size.max(1)).collect();
    parse_split(bytes, &cuts)
}

/// Normal then vertices as f32 bit patterns.
pub fn bits(t: &RawTriangle) -> [u32; 12] {
    let mut out = [0u32; 12];
    let values = t.normal.iter().chain(t.vertices.iter().flatten());
    for (o, v) in out.iter_mut().zip(values) {
        *o = v.to_bits();
    }
    out
}

/// The vertices only, as bit patterns.
pub fn vertex_bits(t: &RawTriangle) -> [u32; 9] {
    let mut out = [0u32; 9];
    for (o, v) in out.iter_mut().zip(t.vertices.iter().flatten()) {
        *o = v.to_bits();
    }
    out
}

/// A binary STL: `header` padded with spaces to 80 bytes, the count, 50-byte records.
pub fn write_binary(header: &[u8], count: u32, triangles: &[RawTriangle]) -> Vec<u8> {
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

/// How `write_ascii` lays out the text.
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

/// An ASCII STL of one solid. Numbers are written in Rust's shortest round-trip form, so they
/// parse back to the same bits.
pub fn write_ascii(name: &str, triangles: &[RawTriangle], style: AsciiStyle) -> Vec<u8> {
    let eol = if style.crlf { "\r\n" } else { "\n" };
    let kw = |k: &str| if style.upper { k.to_uppercase() } else { k.to_string() };
    let num = |v: f32| if style.exponent { format!("{v:e}") } else { format!("{v}") };
    let ind = style.indent;
    let mut s = format!("{ind}{} {name}{eol}", kw("solid"));
    for t in triangles {
        let [x, y, z] = t.normal.map(num);
        s += &format!("{ind}{} {} {x} {y} {z}{eol}", kw("facet"), kw("normal"));
        s += &format!("{ind}  {} {}{eol}", kw("outer"), kw("loop"));
        for v in &t.vertices {
            let [x, y, z] = v.map(num);
            s += &format!("{ind}    {} {x} {y} {z}{eol}", kw("vertex"));
        }
        s += &format!("{ind}  {}{eol}{ind}{}{eol}", kw("endloop"), kw("endfacet"));
    }
    s += &format!("{ind}{} {name}{eol}", kw("endsolid"));
    s.into_bytes()
}

/// What [`write_ascii_nonstandard`] put into a file, as the reader should report it.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Oddities {
    /// Facets written without three numbers as the normal.
    pub bad_normals: u32,
    /// Comment words after statements.
    pub comments: u32,
    /// NUL/SUB bytes at the end.
    pub padding: u32,
}

/// An ASCII STL in the odd forms the desktop slicers read, one form per facet in turn (words
/// and missing parts in the normal, `outer loop` variants, split closing keywords, comments,
/// facets after `endsolid`, a `solid` without `endsolid`), ending in NUL/SUB padding. Corners
/// are written exactly as [`write_ascii`] does.
pub fn write_ascii_nonstandard(
    name: &str,
    triangles: &[RawTriangle],
    style: AsciiStyle,
) -> (Vec<u8>, Oddities) {
    let eol = if style.crlf { "\r\n" } else { "\n" };
    let kw = |k: &str| if style.upper { k.to_uppercase() } else { k.to_string() };
    let num = |v: f32| if style.exponent { format!("{v:e}") } else { format!("{v}") };
    let mut odd = Oddities::default();
    let mut s = format!("{} {name}{eol}", kw("solid"));
    for (i, t) in triangles.iter().enumerate() {
        let [x, y, z] = t.normal.map(num);
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
            let [x, y, z] = v.map(num);
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
