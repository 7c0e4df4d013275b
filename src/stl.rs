//! Incremental push parser for binary and ASCII STL.
//!
//! [`StlReader`] takes the file in chunks of any size (1 byte .. the whole file) and hands every
//! complete facet to a sink at once; the result never depends on how the input was split. It
//! holds at most one header, one binary record or one ASCII token between chunks (constant
//! memory, under 180 bytes), never allocates and never panics on any input.
//!
//! **Detection.** The first 84 bytes are buffered. If they contain a control byte (below 0x20
//! other than `\t \n \v \f \r`, or 0x7F) the file is binary: a binary count below 2^24 always
//! has a zero top byte. Otherwise the file is ASCII when its first word is `solid` or `facet`
//! (any case) or it has no word yet, else binary. A file shorter than 84 bytes is decided the
//! same way at [`StlReader::finish`]. So a binary header that starts with `solid` is still binary.
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
//! skipped to the end of their line. Vertex coordinates are parsed by `<f32 as FromStr>`, which
//! rounds correctly, so the same mesh as ASCII and as binary gives bit-identical triangles; C99
//! hex floats (`0x1.8p3`), which the slicers' `scanf("%f")` reads too, are rounded to nearest
//! even here. A facet goes to the sink when its `endloop` is read.
//!
//! What the desktop slicers also read is accepted wherever the facet's three corners stay
//! certain (PrusaSlicer's admesh reader, Cura's numpy-stl reader, CuraEngine's line reader):
//! - the normal is free: `normal` may be missing, and its three components may be missing or be
//!   any word (`+inf`, `NaN`, `-1.#IND`, `weirdvalue`); they are not used, and a facet whose
//!   normal is not three finite numbers is counted in [`StlSummary::bad_normals`];
//! - `outer loop` may be written `outerloop`, `outer` or `loop` alone, or be missing;
//! - closing keywords may be split: `end loop`, `end facet`, `end solid`;
//! - words after a complete statement on its line (`endloop foo`, `endfacet bar`) are comments,
//!   counted in [`StlSummary::ignored_words`]; a number there is an error (a fourth coordinate
//!   cannot be told from a misplaced one);
//! - `solid` and `endsolid` lines are optional between facets: facets may come without a
//!   `solid` line, also after an `endsolid`, and a `solid` line may open a new solid without an
//!   `endsolid` for the last one;
//! - NUL or SUB (0x1A, DOS end of file) padding may end the file: counted in
//!   [`StlSummary::trailing_bytes`].
//!
//! A file that ends after complete facets without `endsolid` is accepted and reported in
//! [`StlSummary::missing_endsolid`]; one that ends inside a facet is
//! [`StlErrorKind::UnexpectedEnd`]. Misspelled keywords, text on a line of its own and missing
//! or extra coordinates stay errors: with free layout they cannot be told apart from a lost or
//! extra token, which would shift every later corner.
//!
//! **Checks.** Vertex coordinates must be finite and within [`MAX_COORDINATE`] (10 m in mm): a
//! corner that is not a number has no place, and dropping its facet would cut a hole into the
//! part. Normals are not checked, only counted in [`StlSummary::bad_normals`] when NaN or
//! infinite (both formats). Zero-area facets (the cross product of `b - a` and `c - a`,
//! computed in f64 from the f32 coordinates, is exactly zero: repeated corners or collinear
//! corners) are counted in [`StlSummary::degenerate`] and not passed to the sink. A file without
//! any facet is [`StlErrorKind::Empty`].

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
    /// The stored normal (read, not trusted; may be NaN or infinite, and NaN where an ASCII
    /// component is missing or not a number).
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
    /// ASCII: NUL or SUB padding after the last solid or facet.
    pub trailing_bytes: u32,
    /// ASCII: the file ended after complete facets without a closing `endsolid`.
    pub missing_endsolid: bool,
    /// Facets whose stored normal is not three finite numbers (NaN or infinite values; ASCII:
    /// also words or missing components). Kept: the normal is not used.
    pub bad_normals: u32,
    /// ASCII: comment words after a complete statement on its line (`endloop foo`), skipped.
    pub ignored_words: u32,
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
    /// ASCII: a token where a vertex coordinate belongs that is not a number. Offset: the token.
    BadNumber,
    /// ASCII: a token longer than [`MAX_TOKEN`] bytes. Offset: the token.
    TokenTooLong,
    /// ASCII: the input ended inside a facet. Offset: the end of the input.
    UnexpectedEnd,
    /// ASCII file shorter than the 84-byte detection window that holds a facet: at most one
    /// facet fits, which is no printable solid. Offset: the end of the input.
    TooShort,
    /// `feed` or `finish` was called after `finish` had succeeded. Offset: the end of the input.
    AfterFinish,
    /// An ASCII file, for a reader of binary STL only ([`StlReader::binary_only`]). Offset:
    /// where the format was decided (84, or the end of a shorter file).
    Ascii,
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
            Self::BadNumber => "malformed vertex coordinate in ASCII STL",
            Self::TokenTooLong => "token longer than 64 bytes in ASCII STL",
            Self::UnexpectedEnd => "ASCII STL ends inside a facet",
            Self::TooShort => "ASCII STL under 84 bytes: one facet is no solid",
            Self::AfterFinish => "STL reader used after finish",
            Self::Ascii => "ASCII STL, where only binary STL is read",
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
// A tag of its own, `Detect` = 0: a reader at its start is all zero bytes (the card's sort
// of an STL is cleared in place with it, see `card::zsort`).
#[repr(u8)]
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
// A tag of its own, `Solid` = 0 (see `Phase`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
enum Expect {
    /// `solid` or `facet` (start of file, or after `endsolid`, where the file may also end).
    Solid,
    /// `facet`, `endsolid` or a new `solid` (the file may end here: a missing `endsolid`).
    FacetOrEndsolid,
    /// After `facet`: `normal`, a normal component, or the loop.
    Normal,
    /// Normal component `n` (0..3); a keyword instead ends the normal early.
    Component(u8),
    /// `outer`, `outerloop`, `loop`, or straight the first `vertex`.
    Outer,
    /// `loop` after `outer`, or the first `vertex`.
    Loop,
    /// The `vertex` of corner `k` (0..3).
    Vertex(u8),
    /// Vertex coordinate `n` (0..9: corner `n / 3`, axis `n % 3`).
    Coord(u8),
    /// `endloop` (or `end`).
    EndLoop,
    /// `endfacet` (or `end`).
    EndFacet,
    /// The second half of a split closing keyword.
    End(Closing),
    /// NUL/SUB padding up to the end of the input; `closed`: it follows an `endsolid`.
    Padding { closed: bool },
}

/// The keyword a lone `end` begins: `end loop`, `end facet`, `end solid`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Closing {
    Loop,
    Facet,
    Solid,
}

/// An ASCII token, classified once.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Word {
    Solid,
    Endsolid,
    Facet,
    Normal,
    Outer,
    Loop,
    /// `outer loop` written as one word.
    OuterLoop,
    Vertex,
    Endloop,
    Endfacet,
    /// First half of a split closing keyword.
    End,
    /// Not a keyword: a number, a normal component or a comment.
    Other,
}

/// The keywords (matched in any case), the most frequent first.
const KEYWORDS: [(&[u8], Word); 11] = [
    (b"vertex", Word::Vertex),
    (b"endloop", Word::Endloop),
    (b"endfacet", Word::Endfacet),
    (b"facet", Word::Facet),
    (b"normal", Word::Normal),
    (b"outer", Word::Outer),
    (b"loop", Word::Loop),
    (b"solid", Word::Solid),
    (b"endsolid", Word::Endsolid),
    (b"outerloop", Word::OuterLoop),
    (b"end", Word::End),
];

impl Word {
    /// Keywords start with a letter: numbers other than `inf`/`nan` skip the table.
    fn of(token: &[u8]) -> Self {
        match token.first() {
            Some(b) if b.is_ascii_alphabetic() => {
                KEYWORDS.iter().find(|(k, _)| keyword(token, k)).map_or(Self::Other, |&(_, w)| w)
            }
            _ => Self::Other,
        }
    }
}

/// What a keyword does in the state that expects it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Action {
    /// Go to the state.
    Go(Expect),
    /// A facet begins: its normal is unknown until read.
    Open,
    /// A solid's name or the rest of `endsolid`'s line follows: skip the line, then the state.
    Name(Expect),
    /// The facet's corners are complete: emit it, then `endfacet`.
    Emit,
}

/// The grammar: what keyword `word` does in state `expect`; `None` where it has no place.
fn step(expect: Expect, word: Word) -> Option<Action> {
    use Action::{Emit, Go, Name, Open};
    use Expect as E;
    use Word as W;
    let action = match (expect, word) {
        (E::Solid | E::FacetOrEndsolid, W::Solid) => Name(E::FacetOrEndsolid),
        (E::Solid | E::FacetOrEndsolid, W::Facet) => Open,
        (E::FacetOrEndsolid, W::Endsolid) | (E::End(Closing::Solid), W::Solid) => Name(E::Solid),
        (E::FacetOrEndsolid, W::End) => Go(E::End(Closing::Solid)),
        (E::Normal, W::Normal) => Go(E::Component(0)),
        // A keyword where the normal or one of its components belongs: the normal is short.
        (E::Normal | E::Component(_), _) => return step(E::Outer, word),
        (E::Outer, W::Outer) => Go(E::Loop),
        (E::Outer, W::OuterLoop) | (E::Outer | E::Loop, W::Loop) => Go(E::Vertex(0)),
        (E::Outer | E::Loop, W::Vertex) => Go(E::Coord(0)),
        (E::Vertex(k), W::Vertex) => Go(E::Coord(3 * k)),
        (E::EndLoop, W::Endloop) | (E::End(Closing::Loop), W::Loop) => Emit,
        (E::EndLoop, W::End) => Go(E::End(Closing::Loop)),
        (E::EndFacet, W::Endfacet) | (E::End(Closing::Facet), W::Facet) => Go(E::FacetOrEndsolid),
        (E::EndFacet, W::End) => Go(E::End(Closing::Facet)),
        _ => return None,
    };
    Some(action)
}

/// The push parser. See the [module docs](self) for formats, checks and findings.
///
/// `ASCII = false` ([`StlReader::binary_only`]) refuses ASCII files
/// ([`StlErrorKind::Ascii`]): its build holds no text or float parsing (about 20 KB of a
/// board's flash).
#[derive(Debug, Clone)]
pub struct StlReader<const ASCII: bool = true> {
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
    /// ASCII: a line end came after the last token.
    line_break: bool,
    /// Facets whose normal is not three finite numbers.
    bad_normals: u32,
    /// ASCII: comment words skipped.
    ignored_words: u32,
    /// ASCII: padding bytes at the end.
    padding: u32,
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

impl StlReader<true> {
    /// A reader at the start of a file.
    pub const fn new() -> Self {
        Self::blank()
    }
}

impl StlReader<false> {
    /// A reader of binary STL only, at the start of a file.
    pub const fn binary_only() -> Self {
        Self::blank()
    }
}

impl<const ASCII: bool> StlReader<ASCII> {
    const fn blank() -> Self {
        Self {
            phase: Phase::Detect,
            pos: 0,
            triangles: 0,
            degenerate: 0,
            declared: 0,
            expect: Expect::Solid,
            skip_line: false,
            line_break: false,
            bad_normals: 0,
            ignored_words: 0,
            padding: 0,
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
            Phase::Ascii if ASCII => self.feed_ascii(chunk, sink),
            Phase::Ascii => Err(self.error(StlErrorKind::Ascii)),
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
            // A file shorter than the header, parsed here where no sink is at hand. The lenient
            // grammar fits one facet in 61 bytes (`facet vertex 0 0 0 ... endloop endfacet`):
            // refused rather than counted and not delivered.
            self.start(&mut |_| {})?;
            if self.triangles > 0 {
                return Err(self.error(StlErrorKind::TooShort));
            }
        }
        match self.phase {
            Phase::Failed(kind) => Err(StlError { kind, offset: self.pos }),
            Phase::Done => Err(self.error(StlErrorKind::AfterFinish)),
            Phase::Detect => Err(self.error(StlErrorKind::TruncatedHeader)),
            Phase::Binary => self.finish_binary(),
            Phase::Ascii if ASCII => self.finish_ascii(),
            Phase::Ascii => Err(self.error(StlErrorKind::Ascii)),
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
            bad_normals: self.bad_normals,
            ignored_words: self.ignored_words,
        }
    }

    /// Counts a facet (and a bad normal) and passes it on unless it has zero area.
    #[inline(always)]
    fn emit<F: FnMut(RawTriangle) + ?Sized>(&mut self, t: RawTriangle, sink: &mut F) {
        self.triangles = self.triangles.saturating_add(1);
        if !t.normal.iter().all(|&v| is_finite_bits(v)) {
            self.bad_normals = self.bad_normals.saturating_add(1);
        }
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
            if !ASCII {
                return Err(self.error(StlErrorKind::Ascii));
            }
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
            if let Expect::Padding { .. } = self.expect {
                self.padding(rest, offset_of(rest))?;
                break;
            }
            if self.held == 0 {
                match self.skip_blanks(rest) {
                    Some(word) => rest = &rest[word..],
                    None => break,
                }
                if self.padding_starts(rest) {
                    continue;
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

    /// The length of the blanks `rest` starts with (`None`: all blanks), noting a line end.
    fn skip_blanks(&mut self, rest: &[u8]) -> Option<usize> {
        for (i, &b) in rest.iter().enumerate() {
            match b {
                b'\n' | b'\r' => self.line_break = true,
                b' ' | b'\t' | 0x0b | 0x0c => {}
                _ => return Some(i),
            }
        }
        None
    }

    /// At a token start where the file may end, a NUL or SUB byte begins the end padding.
    fn padding_starts(&mut self, rest: &[u8]) -> bool {
        let may_end = matches!(self.expect, Expect::Solid | Expect::FacetOrEndsolid);
        let starts = may_end && rest.first().is_some_and(|&b| is_padding(b));
        if starts {
            self.expect = Expect::Padding { closed: self.expect == Expect::Solid };
        }
        starts
    }

    /// Padding bytes (and blanks among them) are counted; anything else after them is an error.
    fn padding(&mut self, rest: &[u8], at: u64) -> Result<(), StlError> {
        if let Some(i) = rest.iter().position(|&b| !is_padding(b) && !is_blank(b)) {
            return Err(StlError { kind: StlErrorKind::UnknownToken, offset: at + i as u64 });
        }
        let len = u32::try_from(rest.len()).unwrap_or(u32::MAX);
        self.padding = self.padding.saturating_add(len);
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
        let same_line = !core::mem::take(&mut self.line_break);
        let result = if token.len() > MAX_TOKEN {
            Err(StlErrorKind::TokenTooLong)
        } else {
            self.grammar(token, same_line)
        };
        result.map_err(|kind| StlError { kind, offset: at })
    }

    /// Numbers where the state wants them, else the keyword's [`step`] or a comment.
    fn grammar(
        &mut self,
        token: &[u8],
        same_line: bool,
    ) -> Result<Option<RawTriangle>, StlErrorKind> {
        let word = Word::of(token);
        match (self.expect, word) {
            (Expect::Coord(n), _) => self.coordinate(n, token)?,
            (Expect::Normal, Word::Other) => self.component(0, token),
            (Expect::Component(n), Word::Other) => self.component(n, token),
            _ => match step(self.expect, word) {
                Some(Action::Go(next)) => self.expect = next,
                Some(Action::Open) => {
                    if let Some(normal) = self.facet.get_mut(..3) {
                        normal.fill(f32::NAN);
                    }
                    self.expect = Expect::Normal;
                }
                Some(Action::Name(next)) => {
                    self.skip_line = true;
                    self.expect = next;
                }
                Some(Action::Emit) => {
                    self.expect = Expect::EndFacet;
                    return Ok(Some(self.current_facet()));
                }
                None if same_line && self.is_comment(word, token) => {
                    self.ignored_words = self.ignored_words.saturating_add(1);
                }
                None => return Err(StlErrorKind::UnknownToken),
            },
        }
        Ok(None)
    }

    /// Normal component `n`: a token that is not a number leaves it NaN.
    fn component(&mut self, n: u8, token: &[u8]) {
        if let Some(dst) = self.facet.get_mut(usize::from(n)) {
            *dst = parse_f32(token).unwrap_or(f32::NAN);
        }
        self.expect = if n < 2 { Expect::Component(n + 1) } else { Expect::Outer };
    }

    /// Vertex coordinate `n` (0..9): a checked number.
    fn coordinate(&mut self, n: u8, token: &[u8]) -> Result<(), StlErrorKind> {
        let v = parse_f32(token).ok_or(StlErrorKind::BadNumber)?;
        check_coordinate(v)?;
        if let Some(dst) = self.facet.get_mut(3 + usize::from(n)) {
            *dst = v;
        }
        self.expect = match n {
            2 | 5 => Expect::Vertex(n / 3 + 1),
            8.. => Expect::EndLoop,
            _ => Expect::Coord(n + 1),
        };
        Ok(())
    }

    /// A word with no place here, on the line of the statement just completed (`endloop foo`).
    /// Not a number: a fourth coordinate or normal component is no comment.
    fn is_comment(&self, word: Word, token: &[u8]) -> bool {
        let after_statement = matches!(
            self.expect,
            Expect::Outer
                | Expect::Vertex(_)
                | Expect::EndLoop
                | Expect::EndFacet
                | Expect::FacetOrEndsolid
        );
        after_statement && word == Word::Other && parse_f32(token).is_none()
    }

    /// The facet read so far, normal then corners.
    fn current_facet(&self) -> RawTriangle {
        let [nx, ny, nz, ax, ay, az, bx, by, bz, cx, cy, cz] = self.facet;
        RawTriangle { normal: [nx, ny, nz], vertices: [[ax, ay, az], [bx, by, bz], [cx, cy, cz]] }
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
            Expect::Solid | Expect::Padding { closed: true } => {}
            Expect::FacetOrEndsolid
            | Expect::End(Closing::Solid)
            | Expect::Padding { closed: false } => summary.missing_endsolid = true,
            _ => return Err(self.error(StlErrorKind::UnexpectedEnd)),
        }
        summary.trailing_bytes = self.padding;
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

/// Text without control bytes whose first word is `solid` or `facet`, or that has no word yet.
fn looks_ascii(head: &[u8]) -> bool {
    if head.iter().any(|&b| is_control(b)) {
        return false;
    }
    match head.split(|&b| is_blank(b)).find(|w| !w.is_empty()) {
        Some(word) => keyword(word, b"solid") || keyword(word, b"facet"),
        None => true,
    }
}

/// End-of-file padding: NUL (C writers, block-padded copies) or SUB (0x1A, DOS end of file).
fn is_padding(b: u8) -> bool {
    b == 0 || b == 0x1a
}

fn keyword(token: &[u8], word: &[u8]) -> bool {
    token.eq_ignore_ascii_case(word)
}

/// A float token (`1`, `-0`, `+1.5`, `.5`, `1.`, `1e-5`, `inf`, `nan`, `0x1.8p3`), correctly
/// rounded.
fn parse_f32(token: &[u8]) -> Option<f32> {
    let decimal = core::str::from_utf8(token).ok()?.parse().ok();
    decimal.or_else(|| parse_hex_f32(token))
}

/// A C99 hexadecimal float (`0x1.8p3`, `-0X.4P-2`, `0x10`: binary exponent optional), as the
/// `scanf("%f")` of PrusaSlicer, CuraEngine and numpy-stl reads it; rounded to nearest even.
fn parse_hex_f32(token: &[u8]) -> Option<f32> {
    let (negative, unsigned) = match token.split_first()? {
        (b'-', rest) => (true, rest),
        (b'+', rest) => (false, rest),
        _ => (false, token),
    };
    let body = unsigned.strip_prefix(b"0x").or_else(|| unsigned.strip_prefix(b"0X"))?;
    let (digits, exponent) = match body.iter().position(|&b| b == b'p' || b == b'P') {
        Some(p) => (body.get(..p)?, parse_exponent(body.get(p + 1..)?)?),
        None => (body, 0),
    };
    let (mantissa, scale) = hex_mantissa(digits)?;
    let magnitude = round_to_f32(mantissa, scale.saturating_add(exponent));
    Some(if negative { -magnitude } else { magnitude })
}

/// Hex digits with at most one point: `(m, e)` with value `m * 2^e`. Digits beyond 60 bits
/// only set the lowest bit (sticky: below the rounding position of any f32).
fn hex_mantissa(digits: &[u8]) -> Option<(u64, i32)> {
    let (mut m, mut e, mut point, mut any) = (0u64, 0i32, false, false);
    for &b in digits {
        if b == b'.' && !point {
            point = true;
            continue;
        }
        let d = u64::from(char::from(b).to_digit(16)?);
        any = true;
        if m >> 60 == 0 {
            m = m << 4 | d;
            e -= 4 * i32::from(point);
        } else {
            m |= u64::from(d != 0);
            e += 4 * i32::from(!point);
        }
    }
    any.then_some((m, e))
}

/// A signed decimal exponent, saturated far beyond the f32 range.
fn parse_exponent(text: &[u8]) -> Option<i32> {
    let (negative, digits) = match text.split_first()? {
        (b'-', rest) => (true, rest),
        (b'+', rest) => (false, rest),
        _ => (false, text),
    };
    let mut value = 0i32;
    for &b in digits {
        let d = char::from(b).to_digit(10)?;
        value = (value * 10 + d as i32).min(100_000);
    }
    (!digits.is_empty()).then_some(if negative { -value } else { value })
}

/// `m * 2^e` rounded to the nearest f32, ties to even: keep the bits down to the f32 unit in
/// the last place (2^-149 at least), round on the rest.
fn round_to_f32(m: u64, e: i32) -> f32 {
    if m == 0 {
        return 0.0;
    }
    let lz = m.leading_zeros();
    let (m, e) = (m << lz, e.saturating_sub(lz as i32)); // top bit at 2^(e + 63)
    if e > 127 - 63 {
        return f32::INFINITY; // at least 2^128
    }
    let ulp = (e + 63 - 23).max(-149); // exponent of the unit in the last place
    let shift = u32::try_from(ulp.saturating_sub(e)).unwrap_or(u32::MAX); // >= 40
    let (mut q, rest, half) = match shift {
        1..=63 => (m >> shift, m & ((1u64 << shift) - 1), 1u64 << (shift - 1)),
        64 => (0, m, 1 << 63),
        _ => (0, 1, u64::MAX), // beyond 64: below half of 2^-149
    };
    if rest > half || (rest == half && q & 1 == 1) {
        q += 1;
    }
    f32_from_parts(q, ulp)
}

/// `q * 2^ulp` for `q <= 2^24`, `q < 2^23` only at the subnormal `ulp = -149`.
fn f32_from_parts(q: u64, ulp: i32) -> f32 {
    const HIDDEN: u64 = 1 << 23;
    let (q, ulp) = if q == 2 * HIDDEN { (HIDDEN, ulp.saturating_add(1)) } else { (q, ulp) };
    if q < HIDDEN {
        return f32::from_bits(q as u32); // subnormal or zero
    }
    match u32::try_from(ulp.saturating_add(150)) {
        Ok(biased @ 1..=254) => f32::from_bits(biased << 23 | (q - HIDDEN) as u32),
        _ => f32::INFINITY,
    }
}

/// Not NaN or infinite: the f32 exponent field is not all ones (an integer test: no
/// soft-float call on the Cortex-M3).
#[inline(always)]
fn is_finite_bits(v: f32) -> bool {
    v.to_bits() & 0x7f80_0000 != 0x7f80_0000
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
        assert!(core::mem::size_of::<StlReader>() <= 176, "{}", core::mem::size_of::<StlReader>());
    }

    #[test]
    fn detection() {
        assert!(looks_ascii(b"solid x\n"));
        assert!(looks_ascii(b"  \r\n\tSOLID"));
        assert!(looks_ascii(b"   "));
        assert!(!looks_ascii(b"solid x\0"));
        assert!(!looks_ascii(b"solid x\x7f"));
        assert!(!looks_ascii(b"solidworks export"));
        // PrusaSlicer reads facets without a `solid` line.
        assert!(looks_ascii(b" FACET normal 0 0 1"));
        assert!(!looks_ascii(b"facets"));
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
            ("0x10", Some(16.0)),
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
    fn words_and_grammar() {
        assert_eq!(Word::of(b"VeRtEx"), Word::Vertex);
        assert_eq!(Word::of(b"outerloop"), Word::OuterLoop);
        assert_eq!(Word::of(b"end"), Word::End);
        for other in [&b"inf"[..], b"-1.5", b"endloops", b"", b"weirdvalue", b"\xff"] {
            assert_eq!(Word::of(other), Word::Other);
        }
        // Every split closing keyword leads where the whole one does.
        let pairs = [
            (Expect::EndLoop, Word::Endloop, Closing::Loop, Word::Loop),
            (Expect::EndFacet, Word::Endfacet, Closing::Facet, Word::Facet),
            (Expect::FacetOrEndsolid, Word::Endsolid, Closing::Solid, Word::Solid),
        ];
        for (state, whole, closing, second) in pairs {
            assert_eq!(step(state, Word::End), Some(Action::Go(Expect::End(closing))));
            assert_eq!(step(Expect::End(closing), second), step(state, whole));
        }
        // A keyword ends a short normal; nothing has a place for `Other`.
        assert_eq!(step(Expect::Component(1), Word::Vertex), Some(Action::Go(Expect::Coord(0))));
        assert_eq!(step(Expect::Normal, Word::Endloop), None);
        assert_eq!(step(Expect::EndLoop, Word::Other), None);
    }

    #[test]
    fn finite_bits_match_is_finite() {
        let values = [0.0, -0.0, 1.0, f32::MAX, f32::MIN_POSITIVE, 1e-45, f32::INFINITY];
        for v in values.into_iter().chain([f32::NEG_INFINITY, f32::NAN, -f32::NAN]) {
            assert_eq!(is_finite_bits(v), v.is_finite(), "{v}");
        }
    }

    #[test]
    fn hex_floats_as_c_reads_them() {
        let cases: [(&str, Option<f32>); 17] = [
            ("0x1p4", Some(16.0)),
            ("-0X1.8P1", Some(-3.0)),
            ("+0x.4p-2", Some(0.0625)),
            ("0xA.8", Some(10.5)),
            ("-0x0", Some(-0.0)),
            ("0x1.fffffep127", Some(f32::MAX)),
            ("0x1.ffffffp127", Some(f32::INFINITY)), // rounds up past MAX
            ("0x1p128", Some(f32::INFINITY)),
            ("0x1p-149", Some(f32::from_bits(1))),
            ("0x1p-150", Some(0.0)),                 // a tie: to even, zero
            ("0x1.8p-150", Some(f32::from_bits(1))), // above the tie
            ("0x1.000001p0", Some(1.0)),             // a tie: to even
            ("0x1.000003p0", Some(1.0 + 2.0 * f32::EPSILON)),
            ("0x1p", None),
            ("0x", None),
            ("0x1.2.3", None),
            ("0x1g", None),
        ];
        for (text, want) in cases {
            let got = parse_f32(text.as_bytes()).map(f32::to_bits);
            assert_eq!(got, want.map(f32::to_bits), "{text}");
        }
        // Digits past 60 bits are a sticky bit: just above the tie 1 + 2^-24, so up.
        let long = format!("0x1000001{}1p-{}", "0".repeat(40), 24 + 4 * 41);
        assert_eq!(parse_f32(long.as_bytes()), Some(1.0 + f32::EPSILON));
        assert_eq!(parse_f32(b"0x1p99999999999"), Some(f32::INFINITY));
        assert_eq!(parse_f32(b"0x1p-99999999999"), Some(0.0));
    }

    proptest::proptest! {
        #[test]
        fn hex_floats_round_like_f64_to_f32(m in 0u64..1 << 53, e in -230i32..140) {
            // Below 2^53 the f64 product is exact, and `as f32` rounds it once, to even.
            let want = (m as f64 * 2f64.powi(e)) as f32;
            let text = format!("0x{m:x}p{e}");
            proptest::prop_assert_eq!(parse_f32(text.as_bytes()).map(f32::to_bits), Some(want.to_bits()));
        }
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
        // The lenient grammar fits one facet in 61 bytes: refused, never counted unread.
        let one = b"facet vertex 0 0 0 vertex 1 0 0 vertex 0 1 0 endloop endfacet";
        for size in [1, 7, 100] {
            assert_eq!(parse(one, size), (vec![], err(StlErrorKind::TooShort, 61)));
        }
    }

    #[test]
    fn errors_stick_and_finish_ends_the_reader() {
        // Past the 84-byte detection window, so `feed` itself reports it.
        let text = format!("solid {}\nfacet normal 0 0 1 outer loop vertex 0 q\n", "x".repeat(90));
        let mut r = StlReader::new();
        let e = r.feed(text.as_bytes(), &mut |_| {}).unwrap_err();
        assert_eq!(e, StlError { kind: StlErrorKind::BadNumber, offset: 97 + 39 });
        assert_eq!(r.feed(b"more", &mut |_| {}), Err(e));
        assert_eq!(r.finish(), Err(e));
        assert_eq!(e.to_string(), "malformed vertex coordinate in ASCII STL at byte 136");

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
