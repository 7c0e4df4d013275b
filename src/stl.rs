//! Incremental push parser for binary and ASCII STL.
//!
//! PLACEHOLDER API: being implemented (issue 2). Public names are fixed:
//! [`StlReader`], [`RawTriangle`], [`StlFormat`], [`StlSummary`], [`StlError`], [`read_all`].

use core::fmt;

/// One facet as stored in the file: coordinates in file units (millimetres by convention).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct RawTriangle {
    /// The stored normal (read, not trusted).
    pub normal: [f32; 3],
    /// The three corners in file order.
    pub vertices: [[f32; 3]; 3],
}

/// Detected file format.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StlFormat {
    /// 80-byte header, u32 count, 50-byte records.
    Binary,
    /// `solid ... endsolid` text.
    Ascii,
}

/// What a completed parse saw.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StlSummary {
    /// Detected format.
    pub format: StlFormat,
    /// Facets read (degenerate ones included).
    pub triangles: u32,
    /// Zero-area facets: counted, not passed to the sink.
    pub degenerate: u32,
}

/// A parse failure and the byte offset where it was detected.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StlError {
    /// Byte offset from the start of the file.
    pub offset: u64,
}

impl fmt::Display for StlError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "STL error at byte {}", self.offset)
    }
}

/// The push parser.
#[derive(Debug, Default)]
pub struct StlReader {}

impl StlReader {
    /// A reader at the start of a file.
    pub fn new() -> Self {
        Self {}
    }

    /// Feeds the next chunk; complete non-degenerate facets go to `sink`.
    pub fn feed(
        &mut self,
        _chunk: &[u8],
        _sink: &mut impl FnMut(RawTriangle),
    ) -> Result<(), StlError> {
        Err(StlError { offset: 0 })
    }

    /// Ends the input.
    pub fn finish(&mut self) -> Result<StlSummary, StlError> {
        Err(StlError { offset: 0 })
    }
}

/// Parses a whole in-memory file.
pub fn read_all(bytes: &[u8], sink: &mut impl FnMut(RawTriangle)) -> Result<StlSummary, StlError> {
    let mut reader = StlReader::new();
    reader.feed(bytes, sink)?;
    reader.finish()
}
