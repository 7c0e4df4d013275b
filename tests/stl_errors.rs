//! Hand-made broken and odd STL files: each error kind with its exact byte offset, the
//! non-fatal findings, and the same outcome in every chunking.

mod stl_support;

use stl_support::{parse_chunked, vertex_bits, Parsed};
use strata::stl::{CountMismatch, RawTriangle, StlError, StlErrorKind as K, StlFormat, StlSummary};
use strata_testkit::stl as write;

/// Chunk sizes every case is fed in: whole, bytes, odd, a record, a page.
const CHUNKINGS: [usize; 6] = [usize::MAX, 1, 2, 7, 50, 4096];

/// Parses in every chunking, checks they agree, returns the whole-buffer parse.
fn parse_all_ways(bytes: &[u8]) -> Parsed {
    let whole = parse_chunked(bytes, usize::MAX);
    for size in CHUNKINGS {
        let p = parse_chunked(bytes, size);
        assert_eq!(p.result, whole.result, "{size}-byte chunks");
        assert!(p.bits() == whole.bits(), "{size}-byte chunks: facets differ");
    }
    whole
}

#[track_caller]
fn assert_error(bytes: &[u8], kind: K, offset: u64) {
    assert_eq!(parse_all_ways(bytes).result, Err(StlError { kind, offset }));
}

#[track_caller]
fn assert_ok(bytes: &[u8]) -> (StlSummary, Vec<RawTriangle>) {
    let p = parse_all_ways(bytes);
    (p.result.unwrap_or_else(|e| panic!("{e}")), p.triangles)
}

fn tri(a: [f32; 3], b: [f32; 3], c: [f32; 3]) -> RawTriangle {
    RawTriangle { normal: [0.0, 0.0, 1.0], vertices: [a, b, c] }
}

/// Three distinct non-degenerate facets.
fn three() -> Vec<RawTriangle> {
    (0..3).map(|i| tri([i as f32, 0.0, 0.0], [i as f32 + 1.0, 0.0, 0.0], [0.0, 1.0, 0.5])).collect()
}

/// Offset of coordinate `coord` (0..9 over the three vertices) of record `k`.
fn coord_offset(k: u64, coord: u64) -> u64 {
    84 + 50 * k + 12 + 4 * coord
}

/// An ASCII file: `solid` line padded past the 84-byte detection window, then `body`.
fn ascii(body: &str) -> (Vec<u8>, u64) {
    let head = format!("solid {}\n", "n".repeat(90));
    (format!("{head}{body}").into_bytes(), head.len() as u64)
}

const FACET: &str = "facet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\n\
                     endloop\nendfacet\n";

// ---- Empty and truncated ----

#[test]
fn empty_inputs() {
    assert_error(b"", K::Empty, 0);
    assert_error(b"solid x\nendsolid x\n", K::Empty, 19);
    assert_error(b"solid a\nendsolid a\nSOLID b\r\nENDSOLID b", K::Empty, 38);
    let blank = " \n".repeat(60);
    assert_error(blank.as_bytes(), K::Empty, 120);
    // A valid binary file with no records.
    assert_error(&write::binary(b"empty", 0, &[]), K::Empty, 84);
}

#[test]
fn truncated_binary_header() {
    let file = write::binary(b"x", 3, &three());
    assert_error(&file[..83], K::TruncatedHeader, 83);
    assert_error(&file[..1], K::TruncatedHeader, 1);
    assert_error(b"\0", K::TruncatedHeader, 1);
    assert_error(b"STL exported by something", K::TruncatedHeader, 25);
}

#[test]
fn truncated_binary_record() {
    let file = write::binary(b"x", 3, &three());
    // Two complete records and 30 bytes of the third.
    assert_error(&file[..84 + 100 + 30], K::TruncatedRecord, 184);
    assert_error(&file[..84 + 1], K::TruncatedRecord, 84);
    assert_error(&file[..file.len() - 1], K::TruncatedRecord, 184);
}

// ---- Binary findings (not errors) ----

#[test]
fn count_mismatch_keeps_the_intact_records() {
    let (s, tris) = assert_ok(&write::binary(b"x", 5, &three()));
    assert_eq!(s.count_mismatch, Some(CountMismatch { declared: 5, found: 3 }));
    assert_eq!((s.triangles, tris), (3, three()));

    // Some exporters write 0.
    let (s, tris) = assert_ok(&write::binary(b"x", 0, &three()));
    assert_eq!(s.count_mismatch, Some(CountMismatch { declared: 0, found: 3 }));
    assert_eq!(tris.len(), 3);
}

#[test]
fn trailing_bytes_after_the_declared_records() {
    let mut file = write::binary(b"solid but binary", 3, &three());
    file.extend_from_slice(&[0xAA; 7]);
    let (s, tris) = assert_ok(&file);
    assert_eq!((s.format, s.trailing_bytes, s.count_mismatch), (StlFormat::Binary, 7, None));
    assert_eq!(tris, three());

    // More records than declared and a tail: both reported.
    let mut file = write::binary(b"x", 2, &three());
    file.push(0);
    let (s, _) = assert_ok(&file);
    assert_eq!(s.trailing_bytes, 1);
    assert_eq!(s.count_mismatch, Some(CountMismatch { declared: 2, found: 3 }));
}

// ---- Binary coordinates ----

#[test]
fn binary_non_finite_coordinates() {
    let mut t = three();
    t[1].vertices[1][1] = f32::NAN;
    assert_error(&write::binary(b"x", 3, &t), K::NonFiniteCoordinate, coord_offset(1, 4));
    let mut t = three();
    t[0].vertices[2][2] = f32::NEG_INFINITY;
    assert_error(&write::binary(b"x", 3, &t), K::NonFiniteCoordinate, coord_offset(0, 8));
    // The first bad coordinate of a record is named.
    let mut t = three();
    t[2].vertices[0][0] = 1e9;
    t[2].vertices[0][1] = f32::NAN;
    assert_error(&write::binary(b"x", 3, &t), K::AbsurdCoordinate, coord_offset(2, 0));
}

#[test]
fn binary_absurd_coordinates() {
    let mut t = three();
    t[1].vertices[0][2] = 10_000.001;
    assert_error(&write::binary(b"x", 3, &t), K::AbsurdCoordinate, coord_offset(1, 2));
    let mut t = three();
    t[0].vertices[2][0] = -20_000.0;
    assert_error(&write::binary(b"x", 3, &t), K::AbsurdCoordinate, coord_offset(0, 6));
    // Exactly 10 m is accepted.
    let mut t = three();
    t[0].vertices[2] = [10_000.0, -10_000.0, 10_000.0];
    assert_eq!(assert_ok(&write::binary(b"x", 3, &t)).1, t);
}

#[test]
fn nan_normals_are_kept_not_rejected() {
    let mut t = three();
    t[0].normal = [f32::NAN, f32::INFINITY, 1e30];
    t[2].normal = [0.0, f32::NEG_INFINITY, 0.0];
    let (s, tris) = assert_ok(&write::binary(b"x", 3, &t));
    assert!(tris[0].normal[0].is_nan() && tris[0].normal[1].is_infinite());
    // The same finding as in ASCII: facets whose normal is not three finite numbers.
    assert_eq!((s.triangles, s.bad_normals), (3, 2));

    let (file, _) = ascii(&format!("{}endsolid\n", FACET.replace("0 0 1", "nan -inf 1e300")));
    let (s, tris) = assert_ok(&file);
    assert!(tris[0].normal[0].is_nan() && tris[0].normal[2].is_infinite());
    assert_eq!(s.bad_normals, 1);
    // A zero normal (written by many exporters) is a number: no finding.
    let (file, _) = ascii(&FACET.replace("0 0 1", "0 0 0"));
    assert_eq!(assert_ok(&file).0.bad_normals, 0);
}

/// `FACET` with its normal line replaced; the corners stay `[0,0,0] [1,0,0] [0,1,0]`.
fn with_normal(line: &str) -> String {
    FACET.replace("facet normal 0 0 1", line)
}

const CORNERS: [[f32; 3]; 3] = [[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];

#[test]
fn ascii_normals_that_are_not_numbers_are_a_finding() {
    // PrusaSlicer's own test box has `+inf  -inf  weirdvalue`; old MSVC runtimes printed NaN
    // as `-1.#IND00`; an overflow reads as infinity; components may be missing, or all of the
    // normal, or only the word `normal`.
    let cases: [(&str, [Option<f32>; 3]); 7] = [
        (
            "facet normal +inf  -inf  weirdvalue",
            [Some(f32::INFINITY), Some(f32::NEG_INFINITY), None],
        ),
        ("facet normal NaN nan -1.#IND00", [None; 3]),
        ("facet normal 1e39 0 0", [Some(f32::INFINITY), Some(0.0), Some(0.0)]),
        ("facet normal 0 1", [Some(0.0), Some(1.0), None]),
        ("facet normal", [None; 3]),
        ("facet", [None; 3]),
        ("FACET\t-1.#QNAN0 0 0", [None, Some(0.0), Some(0.0)]),
    ];
    for (line, normal) in cases {
        let (file, _) = ascii(&format!("{}endsolid\n", with_normal(line)));
        let (s, tris) = assert_ok(&file);
        assert_eq!((s.triangles, s.bad_normals, s.ignored_words), (1, 1, 0), "{line}");
        assert_eq!(tris[0].vertices, CORNERS, "{line}");
        for (got, want) in tris[0].normal.iter().zip(normal) {
            assert_eq!(got.to_bits(), want.unwrap_or(f32::NAN).to_bits(), "{line}");
        }
    }
    // Without the word `normal`, three numbers are still the normal.
    let (file, _) = ascii(&with_normal("facet 0 0 1"));
    let (s, tris) = assert_ok(&file);
    assert_eq!((s.bad_normals, tris[0].normal), (0, [0.0, 0.0, 1.0]));
    // A fourth number stands where `outer` belongs.
    let (file, at) = ascii(&with_normal("facet normal 0 0 1 1"));
    assert_error(&file, K::UnknownToken, at + 19);
}

#[test]
fn ascii_outer_loop_variants() {
    // admesh (PrusaSlicer) matches `outer loop` with scanf: any blanks, one word, or no loop
    // line at all; numpy-stl (Cura) does not read that line. Only the corners count.
    for line in ["outerloop", "OUTER\r\n\t LOOP", "outer", "loop", "", "outer loop\nloop"] {
        let (file, _) = ascii(&FACET.replace("outer loop", line));
        let parsed = parse_all_ways(&file);
        if line == "outer loop\nloop" {
            assert_eq!(parsed.result.unwrap_err().kind, K::UnknownToken);
            continue;
        }
        let s = parsed.result.unwrap_or_else(|e| panic!("{line:?}: {e}"));
        assert_eq!((s.triangles, s.bad_normals, s.ignored_words), (1, 0, 0), "{line:?}");
        assert_eq!(parsed.triangles[0].vertices, CORNERS);
    }
}

#[test]
fn ascii_split_closing_keywords() {
    // `end loop` (MeshLab's issue 194) and `end solid` (numpy-stl's issue 206) in the wild.
    let body = format!(
        "{}END\r\nSOLID name\n",
        FACET.replace("endloop", "end loop").replace("endfacet", "end\tfacet")
    );
    let (file, _) = ascii(&body);
    let (s, tris) = assert_ok(&file);
    assert_eq!((s.triangles, s.missing_endsolid, s.ignored_words), (1, false, 0));
    assert_eq!(tris[0].vertices, CORNERS);
    // A lone `end` at the end of the input: a cut `end solid`.
    let (file, _) = ascii(&format!("{FACET}end"));
    assert!(assert_ok(&file).0.missing_endsolid);
}

#[test]
fn ascii_comments_after_statements() {
    // PrusaSlicer's test box has text after `endloop` and `endfacet`; numpy-stl and CuraEngine
    // read vertex and facet lines with scanf, which leaves the rest of the line unread.
    let body = "facet normal 0 0 1 n\nouter loop o\nvertex 0 0 0 a\nvertex 1 0 0 b c\n\
                vertex 0 1 0 d\nendloop foo\nendfacet bar baz\r\nendsolid x y\n";
    let (file, _) = ascii(body);
    let (s, tris) = assert_ok(&file);
    assert_eq!((s.triangles, s.ignored_words, s.bad_normals), (1, 9, 0));
    assert_eq!((tris[0].normal, tris[0].vertices), ([0.0, 0.0, 1.0], CORNERS));
    // A word on a line of its own is an error, and so is a number after a statement.
    let (file, at) = ascii(&FACET.replace("endloop\n", "endloop\nfoo\n"));
    assert_error(&file, K::UnknownToken, at + FACET.find("endfacet").unwrap() as u64);
    let (file, at) = ascii(&FACET.replace("endloop", "endloop 7"));
    assert_error(&file, K::UnknownToken, at + FACET.find("endloop").unwrap() as u64 + 8);
    // A keyword out of place is never a comment.
    let (file, at) = ascii(&FACET.replace("endloop", "endloop facet"));
    assert_error(&file, K::UnknownToken, at + FACET.find("endloop").unwrap() as u64 + 8);
}

#[test]
fn ascii_facets_without_a_solid_line() {
    // admesh skips `solid` and `endsolid` lines where they are, so it reads facets before any
    // `solid` and after an `endsolid`.
    let text = format!("\r\n  {FACET}{FACET}endsolid a\n{FACET}");
    let (s, tris) = assert_ok(text.as_bytes());
    assert_eq!((s.format, s.triangles, s.missing_endsolid), (StlFormat::Ascii, 3, true));
    assert!(tris.iter().all(|t| t.vertices == CORNERS));
    let text = format!("{FACET}endsolid\n");
    assert!(!assert_ok(text.as_bytes()).0.missing_endsolid);
    // A new `solid` line without an `endsolid` for the last one.
    let (file, _) = ascii(&format!("{FACET}solid b\n{FACET}endsolid b\n"));
    let (s, _) = assert_ok(&file);
    assert_eq!((s.triangles, s.missing_endsolid, s.ignored_words), (2, false, 0));
}

#[test]
fn ascii_end_padding_is_trailing_bytes() {
    // NUL (C writers, block-padded copies) and SUB (DOS end of file) after the last solid.
    let (file, _) = ascii(&format!("{FACET}endsolid x\n\0\0\r\n\x1a"));
    let (s, _) = assert_ok(&file);
    assert_eq!((s.triangles, s.trailing_bytes, s.missing_endsolid), (1, 5, false));
    // Right after a facet: the endsolid is missing too.
    let (file, _) = ascii(&format!("{FACET}\0"));
    let (s, _) = assert_ok(&file);
    assert_eq!((s.trailing_bytes, s.missing_endsolid), (1, true));
    // Nothing but padding may follow it.
    let body = format!("{FACET}endsolid\n\0\0solid b\n{FACET}");
    let (file, at) = ascii(&body);
    assert_error(&file, K::UnknownToken, at + FACET.len() as u64 + 11);
    // Inside a facet a NUL is no padding.
    let (file, at) = ascii(&FACET.replace("endloop", "\0"));
    assert_error(&file, K::UnknownToken, at + FACET.find("endloop").unwrap() as u64);
}

#[test]
fn degenerate_facets_are_counted_not_emitted() {
    let mut t = three();
    t.push(tri([1.0, 1.0, 1.0], [1.0, 1.0, 1.0], [2.0, 0.0, 0.0])); // repeated corner
    t.push(tri([0.0, 0.0, 0.0], [1.0, 2.0, 3.0], [2.0, 4.0, 6.0])); // collinear
    let (s, tris) = assert_ok(&write::binary(b"x", 5, &t));
    assert_eq!((s.triangles, s.degenerate), (5, 2));
    assert_eq!(tris, three());
    // Only degenerate facets: read, but nothing emitted (not Empty: the file has facets).
    let (s, tris) = assert_ok(&write::binary(b"x", 2, &t[3..]));
    assert_eq!((s.triangles, s.degenerate, tris.len()), (2, 2, 0));
}

// ---- ASCII ----

#[test]
fn ascii_coordinates() {
    let (file, at) = ascii(&FACET.replace("vertex 1 0 0", "vertex 1 nan 0"));
    let nan_at = at + FACET.find("vertex 1 0 0").unwrap() as u64 + 9;
    assert_error(&file, K::NonFiniteCoordinate, nan_at);
    let (file, _) = ascii(&FACET.replace("vertex 1 0 0", "vertex 1 0 -Infinity"));
    assert_error(&file, K::NonFiniteCoordinate, nan_at + 2);
    let (file, _) = ascii(&FACET.replace("vertex 1 0 0", "vertex 1 1e5 0"));
    assert_error(&file, K::AbsurdCoordinate, nan_at);
    // Overflow to infinity while parsing is non-finite, not a bad number.
    let (file, _) = ascii(&FACET.replace("vertex 1 0 0", "vertex 1 1e39 0"));
    assert_error(&file, K::NonFiniteCoordinate, nan_at);
    let (file, _) = ascii(&FACET.replace("vertex 1 0 0", "vertex 1 0x1p200 0"));
    assert_error(&file, K::NonFiniteCoordinate, nan_at);
    // C99 hex floats, as the slicers' scanf("%f") reads them: the same corner as `1 0 0`.
    let (file, _) = ascii(&FACET.replace("vertex 1 0 0", "vertex 0x1p0 -0X0 0x.8P1"));
    let (_, tris) = assert_ok(&file);
    assert_eq!(tris[0].vertices[1].map(f32::to_bits), [1.0, -0.0, 1.0f32].map(f32::to_bits));
}

#[test]
fn ascii_unknown_tokens() {
    // A misspelled keyword.
    let (file, at) = ascii(&FACET.replace("endloop", "endloops"));
    assert_error(&file, K::UnknownToken, at + FACET.find("endloop").unwrap() as u64);
    // Four numbers after `vertex`: the fourth stands where `vertex` belongs.
    let (file, at) = ascii(&FACET.replace("vertex 0 1 0", "vertex 0 1 0 7"));
    assert_error(&file, K::UnknownToken, at + FACET.find("vertex 0 1 0").unwrap() as u64 + 13);
    // Text after the last endsolid: it could be a mangled further solid.
    let body = format!("{FACET}endsolid x\nexported by y");
    let (file, at) = ascii(&body);
    assert_error(&file, K::UnknownToken, at + body.len() as u64 - 13);
    // The first word is `solid` but what follows is not a facet.
    assert_error(b"solid x\nfacets normal", K::UnknownToken, 8);
    // `solid` or `facet` expected after `endsolid`.
    let body = format!("{FACET}endsolid\nvertex");
    let (file, at) = ascii(&body);
    assert_error(&file, K::UnknownToken, at + body.len() as u64 - 6);
    // `end` followed by another closing word than the one due.
    let (file, at) = ascii(&FACET.replace("endloop", "end facet"));
    assert_error(&file, K::UnknownToken, at + FACET.find("endloop").unwrap() as u64 + 4);
    // `outer loop` in the wrong order.
    let (file, at) = ascii(&FACET.replace("outer loop", "loop outer"));
    assert_error(&file, K::UnknownToken, at + FACET.find("outer loop").unwrap() as u64 + 5);
}

#[test]
fn ascii_bad_numbers() {
    let (file, at) = ascii(&FACET.replace("vertex 0 1 0", "vertex 0 1.2.3 0"));
    let number_at = at + FACET.find("vertex 0 1 0").unwrap() as u64 + 9;
    assert_error(&file, K::BadNumber, number_at);
    let (file, _) = ascii(&FACET.replace("vertex 0 1 0", "vertex 0 endloop"));
    assert_error(&file, K::BadNumber, number_at);
    let (file, _) = ascii(&FACET.replace("vertex 0 1 0", "vertex 0 0x1q 0"));
    assert_error(&file, K::BadNumber, number_at);
    // A missing coordinate: the keyword stands where the number belongs.
    let (file, _) = ascii(&FACET.replace("vertex 0 1 0", "vertex 0 1\nendloop"));
    assert_error(&file, K::BadNumber, number_at + 2);
    // Invalid UTF-8 where a number belongs.
    let (mut file, _) = ascii(FACET);
    file[number_at as usize] = 0xFF;
    assert_error(&file, K::BadNumber, number_at);
}

#[test]
fn ascii_token_too_long() {
    let long = format!("0.{}", "0".repeat(63));
    let (file, at) = ascii(&FACET.replace("vertex 1 0 0", &format!("vertex {long} 0 0")));
    assert_error(&file, K::TokenTooLong, at + FACET.find("vertex 1 0 0").unwrap() as u64 + 7);
    // A long solid name is skipped, never buffered.
    let name = "x".repeat(10_000);
    let file = format!("solid {name}\n{FACET}endsolid {name}\n");
    assert_eq!(assert_ok(file.as_bytes()).0.triangles, 1);
}

#[test]
fn ascii_ending_inside_a_facet() {
    let (file, at) = ascii(FACET);
    // Ends after `facet`, after the normal, inside a vertex, after the last vertex.
    for end in ["facet", "0 0 1\n", "vertex 1 0", "vertex 0 1 0\n"] {
        let cut = at as usize + FACET.find(end).unwrap() + end.len();
        assert_error(&file[..cut], K::UnexpectedEnd, cut as u64);
    }
    // Ends inside a keyword: that word is unknown; `end` alone is half of `end loop`.
    let cut = at as usize + FACET.find("endloop").unwrap() + 4;
    assert_error(&file[..cut], K::UnknownToken, cut as u64 - 4);
    assert_error(&file[..cut - 1], K::UnexpectedEnd, cut as u64 - 1);
    // Cut after `endloop`: the facet went to the sink, but the file is still broken.
    let cut_file = &file[..file.len() - "endfacet\n".len()];
    assert_error(cut_file, K::UnexpectedEnd, cut_file.len() as u64);
}

#[test]
fn ascii_missing_endsolid_is_a_finding() {
    let (file, _) = ascii(&format!("{FACET}{FACET}"));
    let (s, tris) = assert_ok(&file);
    assert!(s.missing_endsolid);
    assert_eq!((s.format, s.triangles, tris.len()), (StlFormat::Ascii, 2, 2));
    let (file, _) = ascii(&format!("{FACET}endsolid"));
    assert!(!assert_ok(&file).0.missing_endsolid);
}

#[test]
fn ascii_layout_variants() {
    // Several solids, CR-only line ends, tabs, upper case, no final line end.
    let text = format!(
        "\t solid A\r{}ENDSOLID A\rsolid\r{}endsolid",
        FACET.replace('\n', "\r").to_uppercase(),
        FACET.replace(' ', "\t  ")
    );
    let (s, tris) = assert_ok(text.as_bytes());
    assert_eq!((s.format, s.triangles, s.missing_endsolid), (StlFormat::Ascii, 2, false));
    assert_eq!(tris[0], tris[1]);
    assert_eq!(tris[0].vertices, [[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]);
}

#[test]
fn detection_edge_cases() {
    // A binary header that starts with "solid": the count's zero top byte makes it binary.
    let (s, _) = assert_ok(&write::binary(b"solid looks like text", 3, &three()));
    assert_eq!(s.format, StlFormat::Binary);
    // An all-zero header.
    let (s, _) = assert_ok(&write::binary(&[0; 80], 3, &three()));
    assert_eq!(s.format, StlFormat::Binary);
    // Leading blank lines before `solid` are fine; text starting with another word is binary.
    let (file, _) = ascii(FACET);
    let mut padded = b"\r\n\r\n   ".to_vec();
    padded.extend_from_slice(&file);
    assert_eq!(assert_ok(&padded).0.format, StlFormat::Ascii);
}

#[test]
fn repo_cube_nonstandard_ascii_reads_like_the_binary_twin() {
    // Every facet of the 10 mm cube in another odd form the desktop slicers read: words as
    // normals, missing normals, `outer loop` variants, `end loop`, comments after statements,
    // facets after `endsolid`, a `solid` without `endsolid`, `end solid`, NUL/SUB padding.
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data");
    let odd = std::fs::read(dir.join("cube10_nonstandard.stl")).unwrap();
    let binary = std::fs::read(dir.join("cube10_binary.stl")).unwrap();
    let (a, b) = (parse_all_ways(&odd), parse_all_ways(&binary));
    let s = a.result.unwrap();
    assert_eq!((s.format, s.triangles, s.degenerate), (StlFormat::Ascii, 12, 0));
    assert_eq!((s.bad_normals, s.ignored_words), (5, 5));
    assert_eq!((s.trailing_bytes, s.missing_endsolid), (4, false));
    let vertices = |p: &Parsed| p.triangles.iter().map(vertex_bits).collect::<Vec<_>>();
    assert!(vertices(&a) == vertices(&b), "the odd and the binary cube differ");
    // Normals that were numbers are read as numbers.
    let binary_normals: Vec<_> = b.triangles.iter().map(|t| t.normal).collect();
    for (i, t) in a.triangles.iter().enumerate() {
        if t.normal.iter().all(|v| v.is_finite()) {
            assert_eq!(t.normal, binary_normals[i], "facet {i}");
        }
    }
}

#[test]
fn repo_cube_ascii_and_binary_twins_are_identical() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data");
    let ascii = std::fs::read(dir.join("cube10_ascii_crlf.stl")).unwrap();
    let binary = std::fs::read(dir.join("cube10_binary.stl")).unwrap();
    let (a, b) = (parse_all_ways(&ascii), parse_all_ways(&binary));
    let (sa, sb) = (a.result.unwrap(), b.result.unwrap());
    assert_eq!((sa.format, sa.triangles, sa.degenerate), (StlFormat::Ascii, 12, 0));
    assert_eq!((sb.format, sb.triangles, sb.count_mismatch), (StlFormat::Binary, 12, None));
    assert!(a.bits() == b.bits(), "the ASCII and binary cube differ");
    // The geometry: every corner is 0 or 10 mm, and all 8 corners occur.
    let mut corners: Vec<[f32; 3]> = a.triangles.iter().flat_map(|t| t.vertices).collect();
    assert!(corners.iter().flatten().all(|&v| v == 0.0 || v == 10.0));
    corners.sort_by(|p, q| p.partial_cmp(q).unwrap());
    corners.dedup();
    assert_eq!(corners.len(), 8);
}
