//! Incremental push parser for binary and ASCII STL.
//!
//! [`StlReader`] takes the file in chunks of any size (1 byte .. the whole file) and hands every
//! complete facet to a sink at once; the result never depends on how the input was split. It
//! holds at most one header, one binary record or one ASCII token between chunks (constant
//! memory, about 160 bytes), never allocates and never panics on any input.
//!
//! **Detection.** The first 84 bytes are buffered. If they contain a control byte (below 0x20
//! other than `\t \n \v \f \r`, or 0x7F) the file is binary: a binary count below 2^24 always
//! has a zero top byte. Otherwise the file is ASCII when its first word is `solid` (any case) or
//! it has no word yet, else binary. A file shorter than 84 bytes is decided the same way at
//! [`StlReader::finish`]. So a binary header that starts with `solid` is still binary.
//!
//! **Binary.** 80-byte header, u32 LE facet count, then 50-byte records (normal, three vertices
//! as f32 LE, u16 attribute). Every complete record present is read, whatever the count says;
//! at the end, with `k` complete records and `r` bytes left over:
//! `r != 0, k < count` -> [`StlErrorKind::TruncatedRecord`] at the cut record; otherwise the
//! records are intact and kept, `k != count` is reported in [`StlSummary::count_mismatch`] and
//! `r != 0` in [`StlSummary::trailing_bytes`].
//!
//! **ASCII.** `solid NAME`, then facets `facet normal f f f` `outer loop` `vertex f f f` (x3)
//! `endloop` `endfacet`, then `endsolid NAME`; several solids may follow each other. Keywords
//! in any case, tokens separated by any blanks (LF, CRLF or CR line ends), names (any bytes) are
//! skipped to the end of their line. Numbers are parsed by `<f32 as FromStr>`, which rounds
//! correctly, so the same mesh as ASCII and as binary gives bit-identical triangles. A file that
//! ends after complete facets without `endsolid` is accepted and reported in
//! [`StlSummary::missing_endsolid`]; one that ends inside a facet is
//! [`StlErrorKind::UnexpectedEnd`]. A facet goes to the sink when its `endloop` is read.
//!
//! **Checks.** Vertex coordinates must be finite and within [`MAX_COORDINATE`] (10 m in mm);
//! normals are not checked (not trusted). Zero-area facets (the cross product of `b - a` and
//! `c - a`, computed in f64 from the f32 coordinates, is exactly zero: repeated corners or
//! collinear corners) are counted in [`StlSummary::degenerate`] and not passed to the sink. A file
//! without any facet is [`StlErrorKind::Empty`].

use core::fmt;

/// Largest accepted |vertex coordinate| in file units: 10 m in millimetres. Anything beyond is
/// taken for a unit or export error.
pub const MAX_COORDINATE: f32 = 10_000.0;

/// Longest accepted ASCII token (keyword or number), in bytes.
pub const MAX_TOKEN: usize = 64;

/// Binary header: 80 free bytes, then the u32 LE facet count.
const HEADER_LEN: usize = 84;
/// Binary record: 12 f32 (normal, 3 vertices) and a u16 attribute.
const RECORD_LEN: usize = 50;
/// Offset of the first vertex coordinate inside a binary record (after the normal).
const RECORD_VERTEX_OFFSET: u64 = 12;

/// One facet as stored in the file: coordinates in file units (millimetres by convention).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct RawTriangle {
    /// The stored normal (read, not trusted; may be NaN).
    pub normal: [f32; 3],
    /// The three corners in file order.
    pub vertices: [[f32; 3]; 3],
}

/// Detected file format.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StlFormat {
    /// 80-byte header, u32 count, 50-byte records.
    Binary,
    /// `solid ... endsolid` text.
    Ascii,
}

/// A binary file whose header count differs from the complete records it holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct CountMismatch {
    /// Facet count written in the header.
    pub declared: u32,
    /// Complete records found (all of them were read).
    pub found: u32,
}

/// What a completed parse saw.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StlSummary {
    /// Detected format.
    pub format: StlFormat,
    /// Facets read (degenerate ones included).
    pub triangles: u32,
    /// Zero-area facets: counted, not passed to the sink.
    pub degenerate: u32,
    /// Binary: the header count disagrees with the complete records (all of them kept).
    pub count_mismatch: Option<CountMismatch>,
    /// Binary: bytes after the last complete record, when at least the declared count is there.
    pub trailing_bytes: u32,
    /// ASCII: the file ended after complete facets without a closing `endsolid`.
    pub missing_endsolid: bool,
}

/// Why a file could not be read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StlErrorKind {
    /// No facet at all: empty file, blank text, empty solid, or a binary file without records.
    /// Offset: the end of the input.
    Empty,
    /// Binary file shorter than its 84-byte header. Offset: the end of the input.
    TruncatedHeader,
    /// Binary: a partial record at the end while fewer records than declared are complete.
    /// Offset: the start of that record.
    TruncatedRecord,
    /// A vertex coordinate is NaN or infinite. Offset: the coordinate's first byte (binary) or
    /// its token (ASCII).
    NonFiniteCoordinate,
    /// A vertex coordinate is beyond [`MAX_COORDINATE`]. Offset as for `NonFiniteCoordinate`.
    AbsurdCoordinate,
    /// ASCII: a token other than the keyword the grammar expects. Offset: the token.
    UnknownToken,
    /// ASCII: a token where a number belongs that is not one. Offset: the token.
    BadNumber,
    /// ASCII: a token longer than [`MAX_TOKEN`] bytes. Offset: the token.
    TokenTooLong,
    /// ASCII: the input ended inside a facet. Offset: the end of the input.
    UnexpectedEnd,
    /// `feed` or `finish` was called after `finish` had succeeded. Offset: the end of the input.
    AfterFinish,
}

impl StlErrorKind {
    /// A short human description.
    pub const fn message(self) -> &'static str {
        match self {
            Self::Empty => "no facets (empty file or empty solid)",
            Self::TruncatedHeader => "binary STL shorter than its 84-byte header",
            Self::TruncatedRecord => "binary STL ends inside a facet record (fewer than declared)",
            Self::NonFiniteCoordinate => "vertex coordinate is NaN or infinite",
            Self::AbsurdCoordinate => "vertex coordinate beyond 10 m (10000 mm)",
            Self::UnknownToken => "unexpected token in ASCII STL",
            Self::BadNumber => "malformed number in ASCII STL",
            Self::TokenTooLong => "token longer than 64 bytes in ASCII STL",
            Self::UnexpectedEnd => "ASCII STL ends inside a facet",
            Self::AfterFinish => "STL reader used after finish",
        }
    }
}

/// A parse failure and the byte offset where it was detected.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StlError {
    /// What went wrong.
    pub kind: StlErrorKind,
    /// Byte offset from the start of the file (see each [`StlErrorKind`] for which byte).
    pub offset: u64,
}

impl fmt::Display for StlError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} at byte {}", self.kind.message(), self.offset)
    }
}

/// Where the reader is in the file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Phase {
    /// Buffering the first 84 bytes.
    Detect,
    /// Binary records.
    Binary,
    /// ASCII text; `expect` says which token comes next.
    Ascii,
    /// `finish` succeeded.
    Done,
    /// Stopped at an error; its offset is in `pos`.
    Failed(StlErrorKind),
}

/// The ASCII token the grammar expects next.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Expect {
    /// `solid` (start of file, or after `endsolid`, where the file may also end).
    Solid,
    /// `facet` or `endsolid`.
    FacetOrEndsolid,
    /// Step `n` of [`FACET`].
    Facet(u8),
}

/// One token of a facet after `facet`.
#[derive(Debug, Clone, Copy)]
enum Step {
    /// This keyword.
    Keyword(&'static [u8]),
    /// A number stored in `facet[slot]` (0..3 normal, 3..12 vertices).
    Number(u8),
    /// This keyword, and the facet's geometry is complete: emit it.
    Close(&'static [u8]),
}

/// The facet grammar after `facet`.
const FACET: [Step; 20] = {
    use Step::{Close, Keyword as K, Number as N};
    [
        K(b"normal"),
        N(0),
        N(1),
        N(2),
        K(b"outer"),
        K(b"loop"),
        K(b"vertex"),
        N(3),
        N(4),
        N(5),
        K(b"vertex"),
        N(6),
        N(7),
        N(8),
        K(b"vertex"),
        N(9),
        N(10),
        N(11),
        Close(b"endloop"),
        K(b"endfacet"),
    ]
};

/// The push parser. See the [module docs](self) for formats, checks and findings.
#[derive(Debug, Clone)]
pub struct StlReader {
    phase: Phase,
    /// Bytes consumed so far (the offset of the next byte); the error offset once failed.
    pos: u64,
    /// Facets read, degenerate included.
    triangles: u32,
    /// Zero-area facets.
    degenerate: u32,
    /// Binary: the header's facet count.
    declared: u32,
    /// ASCII: the next token.
    expect: Expect,
    /// ASCII: skipping a solid name up to the end of its line.
    skip_line: bool,
    /// Bytes held in `buf`: the header (detection), a partial record (binary) or a partial
    /// token (ASCII), always the bytes just before `pos`.
    held: u8,
    buf: [u8; HEADER_LEN],
    /// ASCII: the facet being read, normal then three vertices.
    facet: [f32; 12],
}

impl Default for StlReader {
    fn default() -> Self {
        Self::new()
    }
}

impl StlReader {
    /// A reader at the start of a file.
    pub const fn new() -> Self {
        Self {
            phase: Phase::Detect,
            pos: 0,
            triangles: 0,
            degenerate: 0,
            declared: 0,
            expect: Expect::Solid,
            skip_line: false,
            held: 0,
            buf: [0; HEADER_LEN],
            facet: [0.0; 12],
        }
    }

    /// Feeds the next chunk; complete non-degenerate facets go to `sink` at once. After an
    /// error every further call returns the same error.
    pub fn feed(
        &mut self,
        chunk: &[u8],
        sink: &mut impl FnMut(RawTriangle),
    ) -> Result<(), StlError> {
        let result = self.feed_inner(chunk, sink);
        self.fail_on(result)
    }

    fn feed_inner(
        &mut self,
        chunk: &[u8],
        sink: &mut impl FnMut(RawTriangle),
    ) -> Result<(), StlError> {
        let mut chunk = chunk;
        if self.phase == Phase::Detect {
            chunk = self.feed_detect(chunk, sink)?;
        }
        match self.phase {
            Phase::Failed(kind) => Err(StlError { kind, offset: self.pos }),
            Phase::Done => Err(self.error(StlErrorKind::AfterFinish)),
            Phase::Detect => Ok(()),
            Phase::Binary => self.feed_binary(chunk, sink),
            // One non-generic copy of the ASCII parser: a dynamic call per facet is nothing
            // next to parsing its twelve numbers.
            Phase::Ascii => self.feed_ascii(chunk, sink),
        }
    }

    /// Ends the input: reports what the file held, or why it is not a usable STL.
    pub fn finish(&mut self) -> Result<StlSummary, StlError> {
        let result = self.finish_inner();
        if result.is_ok() {
            self.phase = Phase::Done;
        }
        self.fail_on(result)
    }

    /// Remembers an error so that later calls return it again.
    fn fail_on<T>(&mut self, result: Result<T, StlError>) -> Result<T, StlError> {
        if let Err(e) = &result {
            self.phase = Phase::Failed(e.kind);
            self.pos = e.offset;
        }
        result
    }

    fn error(&self, kind: StlErrorKind) -> StlError {
        StlError { kind, offset: self.pos }
    }

    /// The bytes held between chunks.
    fn held_bytes(&self) -> &[u8] {
        self.buf.get(..usize::from(self.held)).unwrap_or(&[])
    }

    fn finish_inner(&mut self) -> Result<StlSummary, StlError> {
        if self.phase == Phase::Detect {
            if self.pos == 0 {
                return Err(self.error(StlErrorKind::Empty));
            }
            // A file shorter than the header. It cannot hold a complete ASCII facet (that takes
            // at least 91 bytes), so a facet emitted here is always followed by an error.
            self.start(&mut |_| {})?;
        }
        match self.phase {
            Phase::Failed(kind) => Err(StlError { kind, offset: self.pos }),
            Phase::Done => Err(self.error(StlErrorKind::AfterFinish)),
            Phase::Detect => Err(self.error(StlErrorKind::TruncatedHeader)),
            Phase::Binary => self.finish_binary(),
            Phase::Ascii => self.finish_ascii(),
        }
    }

    fn summary(&self, format: StlFormat) -> StlSummary {
        StlSummary {
            format,
            triangles: self.triangles,
            degenerate: self.degenerate,
            count_mismatch: None,
            trailing_bytes: 0,
            missing_endsolid: false,
        }
    }

    /// Counts a facet and passes it on unless it has zero area.
    #[inline(always)]
    fn emit<F: FnMut(RawTriangle) + ?Sized>(&mut self, t: RawTriangle, sink: &mut F) {
        self.triangles = self.triangles.saturating_add(1);
        if is_degenerate(&t.vertices) {
            self.degenerate = self.degenerate.saturating_add(1);
        } else {
            sink(t);
        }
    }

    // ---- detection ----

    /// Buffers header bytes; once there are 84, picks the format. Returns the unused rest.
    fn feed_detect<'c>(
        &mut self,
        chunk: &'c [u8],
        sink: &mut dyn FnMut(RawTriangle),
    ) -> Result<&'c [u8], StlError> {
        let held = usize::from(self.held);
        let take = HEADER_LEN.saturating_sub(held).min(chunk.len());
        let (head, rest) = chunk.split_at(take);
        if let Some(dst) = self.buf.get_mut(held..held + take) {
            dst.copy_from_slice(head);
        }
        self.held += take as u8; // <= 84
        self.pos += take as u64;
        if usize::from(self.held) == HEADER_LEN {
            self.start(sink)?;
        }
        Ok(rest)
    }

    /// Decides the format from the held header bytes (84, or fewer at the end of a short file)
    /// and starts that parser on them.
    fn start(&mut self, sink: &mut dyn FnMut(RawTriangle)) -> Result<(), StlError> {
        let header = self.buf;
        let head = header.get(..usize::from(self.held)).unwrap_or(&[]);
        self.held = 0;
        if looks_ascii(head) {
            // Replay the header through the ASCII parser from offset 0.
            self.phase = Phase::Ascii;
            self.pos = 0;
            return self.feed_ascii(head, sink);
        }
        match head.get(80..HEADER_LEN) {
            Some(&[a, b, c, d]) => {
                self.declared = u32::from_le_bytes([a, b, c, d]);
                self.phase = Phase::Binary;
                Ok(())
            }
            _ => Err(self.error(StlErrorKind::TruncatedHeader)),
        }
    }

    // ---- binary ----

    fn feed_binary(
        &mut self,
        chunk: &[u8],
        sink: &mut impl FnMut(RawTriangle),
    ) -> Result<(), StlError> {
        let mut chunk = chunk;
        if self.held > 0 {
            // Complete the record that spans chunks.
            let held = usize::from(self.held);
            let take = RECORD_LEN.saturating_sub(held).min(chunk.len());
            let (part, rest) = chunk.split_at(take);
            if let Some(dst) = self.buf.get_mut(held..held + take) {
                dst.copy_from_slice(part);
            }
            self.held += take as u8; // <= 50
            self.pos += take as u64;
            chunk = rest;
            if usize::from(self.held) < RECORD_LEN {
                return Ok(());
            }
            self.held = 0;
            let mut record = [0u8; RECORD_LEN];
            if let Some(src) = self.buf.get(..RECORD_LEN) {
                record.copy_from_slice(src);
            }
            self.binary_record(&record, self.pos - RECORD_LEN as u64, sink)?;
        }
        // Whole records straight from the chunk.
        let mut records = chunk.chunks_exact(RECORD_LEN);
        for r in &mut records {
            if let Ok(record) = <&[u8; RECORD_LEN]>::try_from(r) {
                self.binary_record(record, self.pos, sink)?;
            }
            self.pos += RECORD_LEN as u64;
        }
        let rest = records.remainder();
        if let Some(dst) = self.buf.get_mut(..rest.len()) {
            dst.copy_from_slice(rest);
        }
        self.held = rest.len() as u8; // < 50
        self.pos += rest.len() as u64;
        Ok(())
    }

    /// One 50-byte record starting at file offset `at`.
    #[inline(always)]
    fn binary_record(
        &mut self,
        record: &[u8; RECORD_LEN],
        at: u64,
        sink: &mut impl FnMut(RawTriangle),
    ) -> Result<(), StlError> {
        let mut f = [0f32; 12];
        for (v, b) in f.iter_mut().zip(record.chunks_exact(4)) {
            *v = f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
        }
        let [nx, ny, nz, ax, ay, az, bx, by, bz, cx, cy, cz] = f;
        let coords = [ax, ay, az, bx, by, bz, cx, cy, cz];
        // Branch-free fast test; NaN fails `<=` too.
        if !coords.iter().fold(true, |ok, v| ok & (v.abs() <= MAX_COORDINATE)) {
            for (i, &v) in coords.iter().enumerate() {
                if let Err(kind) = check_coordinate(v) {
                    let offset = at + RECORD_VERTEX_OFFSET + 4 * i as u64;
                    return Err(StlError { kind, offset });
                }
            }
        }
        let t = RawTriangle {
            normal: [nx, ny, nz],
            vertices: [[ax, ay, az], [bx, by, bz], [cx, cy, cz]],
        };
        self.emit(t, sink);
        Ok(())
    }

    fn finish_binary(&mut self) -> Result<StlSummary, StlError> {
        let mut summary = self.summary(StlFormat::Binary);
        let (found, declared, left) = (self.triangles, self.declared, u32::from(self.held));
        if left != 0 {
            if found < declared {
                let record_start = self.pos - u64::from(left);
                return Err(StlError { kind: StlErrorKind::TruncatedRecord, offset: record_start });
            }
            summary.trailing_bytes = left;
        }
        if found != declared {
            summary.count_mismatch = Some(CountMismatch { declared, found });
        }
        if found == 0 {
            return Err(self.error(StlErrorKind::Empty));
        }
        Ok(summary)
    }

    // ---- ASCII ----

    fn feed_ascii(
        &mut self,
        chunk: &[u8],
        sink: &mut dyn FnMut(RawTriangle),
    ) -> Result<(), StlError> {
        let start = self.pos;
        let offset_of = |rest: &[u8]| start + (chunk.len() - rest.len()) as u64;
        let mut rest = chunk;
        while !rest.is_empty() {
            if self.skip_line {
                // A solid name: everything up to the line end.
                match rest.iter().position(|&b| b == b'\n' || b == b'\r') {
                    Some(eol) => {
                        self.skip_line = false;
                        rest = &rest[eol..];
                    }
                    None => break,
                }
            }
            if self.held == 0 {
                match rest.iter().position(|&b| !is_blank(b)) {
                    Some(word) => rest = &rest[word..],
                    None => break,
                }
            }
            let Some(end) = rest.iter().position(|&b| is_blank(b)) else {
                // The token goes on in the next chunk.
                self.hold_token(rest, offset_of(rest))?;
                break;
            };
            let (tail, after) = rest.split_at(end);
            let facet = if self.held == 0 {
                self.token(tail, offset_of(rest))?
            } else {
                // Only at the chunk start: the held bytes end right before `tail`.
                let at = start - u64::from(self.held);
                let (buf, len) = self.take_token(tail, at)?;
                self.token(buf.get(..len).unwrap_or(&[]), at)?
            };
            if let Some(t) = facet {
                self.emit(t, sink);
            }
            rest = after;
        }
        self.pos = start + chunk.len() as u64;
        Ok(())
    }

    /// Keeps the start of a token that continues in the next chunk; `at` is where `part` is.
    fn hold_token(&mut self, part: &[u8], at: u64) -> Result<(), StlError> {
        let held = usize::from(self.held);
        let token_start = at - held as u64;
        let len = held + part.len();
        match self.buf.get_mut(held..len) {
            Some(dst) if len <= MAX_TOKEN => dst.copy_from_slice(part),
            _ => return Err(StlError { kind: StlErrorKind::TokenTooLong, offset: token_start }),
        }
        self.held = len as u8; // <= 64
        Ok(())
    }

    /// The held start of a token joined with its `tail`, and the token's length.
    fn take_token(&mut self, tail: &[u8], at: u64) -> Result<([u8; MAX_TOKEN], usize), StlError> {
        let held = usize::from(self.held);
        let len = held + tail.len();
        let mut token = [0u8; MAX_TOKEN];
        match token.get_mut(..len).map(|t| t.split_at_mut(held)) {
            Some((head, dst)) => {
                head.copy_from_slice(self.held_bytes());
                dst.copy_from_slice(tail);
            }
            None => return Err(StlError { kind: StlErrorKind::TokenTooLong, offset: at }),
        }
        self.held = 0;
        Ok((token, len))
    }

    /// One complete token starting at file offset `at`, checked against the grammar; returns
    /// the facet its `endloop` completes.
    fn token(&mut self, token: &[u8], at: u64) -> Result<Option<RawTriangle>, StlError> {
        let fail = |kind| Err(StlError { kind, offset: at });
        let mut complete = None;
        if token.len() > MAX_TOKEN {
            return fail(StlErrorKind::TokenTooLong);
        }
        match self.expect {
            Expect::Solid if keyword(token, b"solid") => {
                self.skip_line = true;
                self.expect = Expect::FacetOrEndsolid;
            }
            Expect::FacetOrEndsolid if keyword(token, b"facet") => {
                self.expect = Expect::Facet(0);
            }
            Expect::FacetOrEndsolid if keyword(token, b"endsolid") => {
                self.skip_line = true;
                self.expect = Expect::Solid;
            }
            Expect::Facet(step) => {
                match FACET.get(usize::from(step)) {
                    Some(Step::Keyword(k)) if keyword(token, k) => {}
                    Some(Step::Close(k)) if keyword(token, k) => {
                        let [nx, ny, nz, ax, ay, az, bx, by, bz, cx, cy, cz] = self.facet;
                        complete = Some(RawTriangle {
                            normal: [nx, ny, nz],
                            vertices: [[ax, ay, az], [bx, by, bz], [cx, cy, cz]],
                        });
                    }
                    Some(&Step::Number(slot)) => {
                        let Some(v) = parse_f32(token) else {
                            return fail(StlErrorKind::BadNumber);
                        };
                        if slot >= 3 {
                            if let Err(kind) = check_coordinate(v) {
                                return fail(kind);
                            }
                        }
                        if let Some(dst) = self.facet.get_mut(usize::from(slot)) {
                            *dst = v;
                        }
                    }
                    _ => return fail(StlErrorKind::UnknownToken),
                }
                let next = step + 1;
                self.expect = if usize::from(next) < FACET.len() {
                    Expect::Facet(next)
                } else {
                    Expect::FacetOrEndsolid
                };
            }
            _ => return fail(StlErrorKind::UnknownToken),
        }
        Ok(complete)
    }

    fn finish_ascii(&mut self) -> Result<StlSummary, StlError> {
        if self.held > 0 {
            // The last token ends with the input. A facet completed by it (`endloop`) still
            // lacks its `endfacet`: an error follows, so the facet is dropped.
            let at = self.pos - u64::from(self.held);
            let (buf, len) = self.take_token(&[], at)?;
            self.token(buf.get(..len).unwrap_or(&[]), at)?;
        }
        let mut summary = self.summary(StlFormat::Ascii);
        match self.expect {
            Expect::Facet(_) => return Err(self.error(StlErrorKind::UnexpectedEnd)),
            Expect::FacetOrEndsolid => summary.missing_endsolid = true,
            Expect::Solid => {}
        }
        if self.triangles == 0 {
            return Err(self.error(StlErrorKind::Empty));
        }
        Ok(summary)
    }
}

/// Parses a whole in-memory file.
pub fn read_all(bytes: &[u8], sink: &mut impl FnMut(RawTriangle)) -> Result<StlSummary, StlError> {
    let mut reader = StlReader::new();
    reader.feed(bytes, sink)?;
    reader.finish()
}

/// ASCII token separators: space and `\t \n \v \f \r`.
#[inline(always)]
fn is_blank(b: u8) -> bool {
    matches!(b, b' ' | b'\t' | b'\n' | 0x0b | 0x0c | b'\r')
}

/// Bytes that do not occur in text.
fn is_control(b: u8) -> bool {
    (b < 0x20 && !is_blank(b)) || b == 0x7f
}

/// Text without control bytes whose first word is `solid`, or that has no word yet.
fn looks_ascii(head: &[u8]) -> bool {
    if head.iter().any(|&b| is_control(b)) {
        return false;
    }
    match head.split(|&b| is_blank(b)).find(|w| !w.is_empty()) {
        Some(word) => keyword(word, b"solid"),
        None => true,
    }
}

fn keyword(token: &[u8], word: &[u8]) -> bool {
    token.eq_ignore_ascii_case(word)
}

/// A decimal float token (`1`, `-0`, `+1.5`, `.5`, `1.`, `1e-5`, `inf`, `nan`), correctly rounded.
fn parse_f32(token: &[u8]) -> Option<f32> {
    core::str::from_utf8(token).ok()?.parse().ok()
}

/// A vertex coordinate must be finite and within 10 m.
fn check_coordinate(v: f32) -> Result<(), StlErrorKind> {
    if !v.is_finite() {
        Err(StlErrorKind::NonFiniteCoordinate)
    } else if v.abs() > MAX_COORDINATE {
        Err(StlErrorKind::AbsurdCoordinate)
    } else {
        Ok(())
    }
}

/// Zero area: `(b - a) x (c - a)` computed in f64 is exactly zero. The differences of f32
/// values of similar magnitude and their products are exact in f64.
#[inline(always)]
fn is_degenerate(v: &[[f32; 3]; 3]) -> bool {
    let [a, b, c] = v.map(|p| p.map(f64::from));
    let u = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
    let w = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
    let n = [u[1] * w[2] - u[2] * w[1], u[2] * w[0] - u[0] * w[2], u[0] * w[1] - u[1] * w[0]];
    n == [0.0; 3]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Feeds `bytes` in chunks of `size`, collecting emitted facets.
    fn parse(bytes: &[u8], size: usize) -> (Vec<RawTriangle>, Result<StlSummary, StlError>) {
        let mut out = Vec::new();
        let mut reader = StlReader::new();
        for chunk in bytes.chunks(size.max(1)) {
            if let Err(e) = reader.feed(chunk, &mut |t| out.push(t)) {
                return (out, Err(e));
            }
        }
        let result = reader.finish();
        (out, result)
    }

    fn err(kind: StlErrorKind, offset: u64) -> Result<StlSummary, StlError> {
        Err(StlError { kind, offset })
    }

    const FACET_TEXT: &str = "facet normal 0 0 1\n outer loop\n  vertex 0 0 0\n  vertex 1 0 0\n  \
                              vertex 0 1 0\n endloop\nendfacet\n";

    #[test]
    fn reader_is_small() {
        // RAM of one reader on the Cortex-M3 (same layout there: no pointers inside).
        assert!(core::mem::size_of::<StlReader>() <= 160, "{}", core::mem::size_of::<StlReader>());
    }

    #[test]
    fn detection() {
        assert!(looks_ascii(b"solid x\n"));
        assert!(looks_ascii(b"  \r\n\tSOLID"));
        assert!(looks_ascii(b"   "));
        assert!(!looks_ascii(b"solid x\0"));
        assert!(!looks_ascii(b"solid x\x7f"));
        assert!(!looks_ascii(b"solidworks export"));
        assert!(!looks_ascii(b"binary header"));
        // The count bytes of a binary file with a `solid` header (numpy-stl HalfDonut).
        let mut head = [b' '; 84];
        head[..6].copy_from_slice(b"solid ");
        head[80..].copy_from_slice(&[0x20, 0x01, 0x00, 0x00]);
        assert!(!looks_ascii(&head));
    }

    #[test]
    fn float_forms_follow_from_str() {
        let cases: [(&str, Option<f32>); 11] = [
            ("1e-5", Some(1e-5)),
            ("-0", Some(-0.0)),
            ("+1.5", Some(1.5)),
            (".5", Some(0.5)),
            ("1.", Some(1.0)),
            ("1E3", Some(1000.0)),
            ("inf", Some(f32::INFINITY)),
            ("-Infinity", Some(f32::NEG_INFINITY)),
            ("1e", None),
            ("0x10", None),
            ("1,5", None),
        ];
        for (text, want) in cases {
            assert_eq!(parse_f32(text.as_bytes()), want, "{text}");
        }
        assert!(parse_f32(b"nan").is_some_and(f32::is_nan));
        assert!(parse_f32(&[0xff]).is_none());
        assert_eq!(parse_f32(b"-0").map(f32::to_bits), Some((-0.0f32).to_bits()));
    }

    #[test]
    fn degenerate_means_zero_cross_product() {
        assert!(is_degenerate(&[[0.0; 3], [0.0; 3], [1.0, 2.0, 3.0]]));
        assert!(is_degenerate(&[[0.0; 3], [1.0, 1.0, 1.0], [2.0, 2.0, 2.0]])); // collinear
        assert!(!is_degenerate(&[[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1e-30, 0.0]]));
    }

    #[test]
    fn ascii_facet_in_every_chunking() {
        let text = format!("solid t\n{FACET_TEXT}endsolid t\n");
        for size in [1, 2, 3, 5, 64, 1000] {
            let (tris, summary) = parse(text.as_bytes(), size);
            assert_eq!(tris.len(), 1, "chunk {size}");
            assert_eq!(tris[0].vertices[1], [1.0, 0.0, 0.0]);
            assert_eq!(tris[0].normal, [0.0, 0.0, 1.0]);
            let s = summary.unwrap();
            assert_eq!((s.format, s.triangles, s.missing_endsolid), (StlFormat::Ascii, 1, false));
        }
    }

    #[test]
    fn ascii_without_endsolid_is_a_finding_and_cr_line_ends_work() {
        let text = format!("solid t\r{}", FACET_TEXT.replace('\n', "\r"));
        let (tris, summary) = parse(text.as_bytes(), 7);
        assert_eq!(tris.len(), 1);
        assert!(summary.unwrap().missing_endsolid);
        // The last keyword at the very end of the input, no line end.
        let text = format!("solid t\n{}", FACET_TEXT.trim_end());
        assert_eq!(parse(text.as_bytes(), 3).1.unwrap().triangles, 1);
    }

    #[test]
    fn ascii_cut_inside_a_facet() {
        let text = format!("solid t\n{}", &FACET_TEXT[..FACET_TEXT.len() - 10]);
        let len = text.len() as u64;
        for size in [1, 4, 500] {
            assert_eq!(parse(text.as_bytes(), size).1, err(StlErrorKind::UnexpectedEnd, len));
        }
    }

    #[test]
    fn short_inputs() {
        assert_eq!(parse(b"", 1).1, err(StlErrorKind::Empty, 0));
        assert_eq!(parse(b"solid x\nendsolid x\n", 1).1, err(StlErrorKind::Empty, 19));
        assert_eq!(parse(b"  \n ", 1).1, err(StlErrorKind::Empty, 4));
        assert_eq!(parse(b"\0\0\0", 2).1, err(StlErrorKind::TruncatedHeader, 3));
        assert_eq!(parse(b"hello", 2).1, err(StlErrorKind::TruncatedHeader, 5));
        assert_eq!(parse(b"solid x\nfoo", 2).1, err(StlErrorKind::UnknownToken, 8));
    }

    #[test]
    fn errors_stick_and_finish_ends_the_reader() {
        // Past the 84-byte detection window, so `feed` itself reports it.
        let text = format!("solid {}\nfacet normal 0 0 q\n", "x".repeat(90));
        let mut r = StlReader::new();
        let e = r.feed(text.as_bytes(), &mut |_| {}).unwrap_err();
        assert_eq!(e, StlError { kind: StlErrorKind::BadNumber, offset: 97 + 6 + 7 + 4 });
        assert_eq!(r.feed(b"more", &mut |_| {}), Err(e));
        assert_eq!(r.finish(), Err(e));
        assert_eq!(e.to_string(), "malformed number in ASCII STL at byte 114");

        let mut r = StlReader::new();
        let text = format!("solid t\n{FACET_TEXT}endsolid t\n");
        r.feed(text.as_bytes(), &mut |_| {}).unwrap();
        assert!(r.finish().is_ok());
        let after = StlError { kind: StlErrorKind::AfterFinish, offset: text.len() as u64 };
        assert_eq!(r.finish(), Err(after));
        assert_eq!(r.feed(b"x", &mut |_| {}), Err(after));
    }

    #[test]
    fn long_tokens_fail_at_their_start_in_any_chunking() {
        let long = "1".repeat(MAX_TOKEN + 1);
        let text = format!("solid t\nfacet normal {long} 0 0\n");
        for size in [1, 10, 1000] {
            assert_eq!(parse(text.as_bytes(), size).1, err(StlErrorKind::TokenTooLong, 21));
        }
        // Exactly MAX_TOKEN bytes is fine.
        let ok = format!("0.{}", "0".repeat(MAX_TOKEN - 2));
        let text = format!("solid t\n{}", FACET_TEXT.replacen("1\n", &format!("{ok}\n"), 1));
        assert_eq!(parse(text.as_bytes(), 1).1.unwrap().triangles, 1);
    }
}
