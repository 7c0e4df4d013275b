//! STL test helpers: chunked parsing and bit-exact comparison (the reference writers are
//! `strata_testkit::stl`).
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
