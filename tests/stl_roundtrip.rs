//! Property tests: random meshes written by the test writers (not the parser) round-trip
//! exactly through binary and ASCII, in any chunking; arbitrary bytes never panic and parse the
//! same in any split.

mod stl_support;

use proptest::prelude::*;
use stl_support::{bits, parse_chunked, parse_split, vertex_bits};
use strata::stl::{RawTriangle, StlError, StlErrorKind, StlFormat, StlSummary, MAX_COORDINATE};
use strata_testkit::stl::{self as write, AsciiStyle};

/// Coordinates: anything finite within 10 m, biased towards the values that make collinear or
/// repeated corners (and so degenerate facets) likely, plus -0.0 and subnormals.
fn coordinate() -> impl Strategy<Value = f32> {
    prop_oneof![
        4 => -MAX_COORDINATE..=MAX_COORDINATE,
        2 => (-1000i32..=1000).prop_map(|v| v as f32 / 8.0),
        1 => prop::sample::select(vec![0.0, -0.0, 1.0, MAX_COORDINATE, -MAX_COORDINATE, 1e-40]),
    ]
}

fn triangle(normal: BoxedStrategy<f32>) -> impl Strategy<Value = RawTriangle> {
    let point = || [coordinate(), coordinate(), coordinate()];
    ([normal.clone(), normal.clone(), normal], [point(), point(), point()], 0..8u8).prop_map(
        |(normal, mut vertices, shape)| {
            // One facet in eight repeats a corner: certainly degenerate.
            if shape == 0 {
                vertices[2] = vertices[0];
            }
            RawTriangle { normal, vertices }
        },
    )
}

/// Zero area by the reader's documented definition, restated independently here.
fn zero_area(t: &RawTriangle) -> bool {
    let p = t.vertices.map(|v| v.map(f64::from));
    let u: Vec<f64> = (0..3).map(|i| p[1][i] - p[0][i]).collect();
    let w: Vec<f64> = (0..3).map(|i| p[2][i] - p[0][i]).collect();
    u[1] * w[2] - u[2] * w[1] == 0.0
        && u[2] * w[0] - u[0] * w[2] == 0.0
        && u[0] * w[1] - u[1] * w[0] == 0.0
}

fn mesh(normal: BoxedStrategy<f32>) -> impl Strategy<Value = Vec<RawTriangle>> {
    prop::collection::vec(triangle(normal), 1..40)
}

fn ascii_style() -> impl Strategy<Value = AsciiStyle> {
    (any::<bool>(), any::<bool>(), any::<bool>(), prop::sample::select(vec!["", " ", "\t  "]))
        .prop_map(|(crlf, upper, exponent, indent)| AsciiStyle { crlf, upper, exponent, indent })
}

/// Increasing cut positions inside `0..=len`.
/// A parse as bit patterns and its result: a damaged file can carry NaN normals, which `==`
/// on the floats would call different from themselves.
fn exact(p: stl_support::Parsed) -> (Vec<[u32; 12]>, Result<StlSummary, StlError>) {
    (p.bits(), p.result)
}

fn cuts(len: usize) -> impl Strategy<Value = Vec<usize>> {
    prop::collection::vec(0..=len, 0..20).prop_map(|mut c| {
        c.sort_unstable();
        c
    })
}

/// Checks one parse of `mesh` written as `format`.
fn check_round_trip(file: &[u8], mesh: &[RawTriangle], format: StlFormat, cut: &[usize]) {
    let expected: Vec<[u32; 12]> = mesh.iter().filter(|t| !zero_area(t)).map(bits).collect();
    let degenerate = mesh.len() - expected.len();
    for parsed in [parse_split(file, cut), parse_chunked(file, 1), parse_chunked(file, usize::MAX)]
    {
        let summary = parsed.result.unwrap();
        assert_eq!(summary.format, format);
        assert_eq!(summary.triangles as usize, mesh.len());
        assert_eq!(summary.degenerate as usize, degenerate);
        assert_eq!((summary.count_mismatch, summary.trailing_bytes), (None, 0));
        let bad_normals = mesh.iter().filter(|t| t.normal.iter().any(|v| !v.is_finite())).count();
        assert_eq!(summary.bad_normals as usize, bad_normals);
        assert_eq!(summary.ignored_words, 0);
        assert!(parsed.bits() == expected, "facets differ");
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 200, ..ProptestConfig::default() })]

    #[test]
    fn binary_round_trip(
        mesh in mesh(any::<f32>().boxed()),
        header in prop::collection::vec(any::<u8>(), 80),
        cut in cuts(2100),
    ) {
        let file = write::binary(&header, mesh.len() as u32, &mesh);
        check_round_trip(&file, &mesh, StlFormat::Binary, &cut);
    }

    #[test]
    fn ascii_round_trip(
        mesh in mesh(prop::num::f32::NORMAL.boxed()),
        style in ascii_style(),
        name in "[a-zA-Z0-9 _äö中-]{0,20}",
        cut in cuts(4000),
    ) {
        let file = write::ascii(&name, &mesh, style);
        check_round_trip(&file, &mesh, StlFormat::Ascii, &cut);
    }

    #[test]
    fn ascii_and_binary_of_one_mesh_agree(mesh in mesh(prop::num::f32::NORMAL.boxed()), style in ascii_style()) {
        let a = parse_chunked(&write::ascii("m", &mesh, style), 13);
        let b = parse_chunked(&write::binary(b"m", mesh.len() as u32, &mesh), 13);
        prop_assert!(a.bits() == b.bits());
        let (sa, sb) = (a.result.unwrap(), b.result.unwrap());
        prop_assert_eq!((sa.triangles, sa.degenerate), (sb.triangles, sb.degenerate));
    }

    #[test]
    fn nonstandard_ascii_reads_like_binary(
        mesh in mesh(prop::num::f32::NORMAL.boxed()),
        style in ascii_style(),
        cut in cuts(5000),
    ) {
        let (file, odd) = write::ascii_nonstandard("n", &mesh, style);
        let b = parse_chunked(&write::binary(b"n", mesh.len() as u32, &mesh), usize::MAX);
        let corners = |p: &stl_support::Parsed| p.triangles.iter().map(vertex_bits).collect::<Vec<_>>();
        for a in [parse_split(&file, &cut), parse_chunked(&file, 1), parse_chunked(&file, usize::MAX)] {
            prop_assert!(corners(&a) == corners(&b), "corners differ");
            let (sa, sb) = (a.result.unwrap(), b.result.unwrap());
            prop_assert_eq!((sa.format, sa.triangles, sa.degenerate), (StlFormat::Ascii, sb.triangles, sb.degenerate));
            prop_assert_eq!((sa.bad_normals, sa.ignored_words), (odd.bad_normals, odd.comments));
            prop_assert_eq!((sa.trailing_bytes, sa.missing_endsolid), (odd.padding, false));
        }
    }

    #[test]
    fn arbitrary_bytes_parse_the_same_in_any_split(bytes in prop::collection::vec(any::<u8>(), 0..600), cut in cuts(600)) {
        let whole = parse_chunked(&bytes, usize::MAX);
        prop_assert_eq!(exact(parse_split(&bytes, &cut)), exact(whole.clone()));
        if let Err(e) = whole.result {
            prop_assert!(e.offset <= bytes.len() as u64);
        }
    }

    #[test]
    fn damaged_files_parse_the_same_in_any_split(
        mesh in mesh(prop::num::f32::NORMAL.boxed()),
        ascii in any::<bool>(),
        damage in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..4),
        truncate in any::<prop::sample::Index>(),
        cut in cuts(3000),
    ) {
        let mut file = if ascii {
            write::ascii("d", &mesh, AsciiStyle::default())
        } else {
            write::binary(b"d", mesh.len() as u32, &mesh)
        };
        for (at, byte) in damage {
            let i = at.index(file.len());
            file[i] = byte;
        }
        file.truncate(truncate.index(file.len() + 1));
        let whole = parse_chunked(&file, usize::MAX);
        prop_assert_eq!(exact(parse_split(&file, &cut)), exact(whole.clone()));
        prop_assert_eq!(exact(parse_chunked(&file, 1)), exact(whole));
    }
}

#[test]
fn an_empty_mesh_is_empty_in_both_formats() {
    for file in [write::binary(b"e", 0, &[]), write::ascii("e", &[], AsciiStyle::default())] {
        let r = parse_chunked(&file, 3).result;
        assert_eq!(r.map_err(|e| e.kind), Err(StlErrorKind::Empty));
    }
}
