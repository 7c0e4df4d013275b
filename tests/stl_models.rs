//! Every STL under `../shared/models` against the numbers in its README (triangle count, format
//! and bounding box, as measured there with trimesh), in several chunkings; and the models that
//! exist as both ASCII and binary against each other.

mod stl_support;

use std::collections::BTreeSet;
use std::path::Path;

use stl_support::{parse_chunked, vertex_bits, Parsed};
use strata::stl::{StlFormat, StlSummary};
use strata_testkit::models::{readme_table, shared_models, stl_files_below};

/// One README table row.
#[derive(Debug)]
struct Row {
    /// Path relative to the models folder, `/`-separated.
    file: String,
    /// "binary" or "ASCII".
    format: String,
    triangles: u32,
    /// min and max corner, each coordinate as printed (`{:.2}`); None when the cell is empty.
    bbox: Option<[String; 6]>,
}

/// The README's rows: file, format, triangle count, printed bounding box.
fn readme_rows(dir: &Path) -> Vec<Row> {
    let mut rows = Vec::new();
    for cells in readme_table(dir) {
        // file | bytes | format | triangles | size | bbox min..max | ...
        if cells.len() < 6 {
            continue;
        }
        let line = cells.join(" | ");
        let digits: String = cells[3].chars().take_while(char::is_ascii_digit).collect();
        let triangles = digits.parse().unwrap_or_else(|_| panic!("triangles cell: {line}"));
        let format = cells[2].split_whitespace().next().unwrap_or("").to_string();
        let bbox = (!cells[5].is_empty()).then(|| {
            let numbers: Vec<String> = cells[5]
                .split(")..(")
                .flat_map(|corner| corner.trim_matches(['(', ')']).split(','))
                .map(|n| n.trim().to_string())
                .collect();
            numbers.try_into().unwrap_or_else(|_| panic!("bbox cell: {line}"))
        });
        rows.push(Row { file: cells[0].clone(), format, triangles, bbox });
    }
    rows
}

/// Every `.stl` below `dir`, as `/`-separated relative paths.
fn stl_files(dir: &Path) -> BTreeSet<String> {
    let relative = |p: &Path| {
        let parts = p.strip_prefix(dir).expect("below the folder").iter();
        parts.map(|s| s.to_string_lossy().into_owned()).collect::<Vec<_>>().join("/")
    };
    stl_files_below(dir).iter().map(|p| relative(p)).collect()
}

/// Bounding box of the emitted facets, printed like the README (`{:.2}` of the f64 value,
/// with "-0.00" written "0.00").
fn printed_bbox(parsed: &Parsed) -> [String; 6] {
    let mut min = [f32::INFINITY; 3];
    let mut max = [f32::NEG_INFINITY; 3];
    for v in parsed.triangles.iter().flat_map(|t| t.vertices) {
        for axis in 0..3 {
            min[axis] = min[axis].min(v[axis]);
            max[axis] = max[axis].max(v[axis]);
        }
    }
    let all = [min, max].concat();
    let printed: Vec<String> =
        all.iter().map(|&v| print2(&format!("{:.2}", f64::from(v)))).collect();
    printed.try_into().unwrap()
}

fn print2(s: &str) -> String {
    if s == "-0.00" {
        "0.00".to_string()
    } else {
        s.to_string()
    }
}

#[test]
fn every_model_matches_the_readme_in_every_chunking() {
    let Some(dir) = shared_models() else { return };
    let rows = readme_rows(&dir);
    assert!(rows.len() >= 30, "README parse found only {} rows", rows.len());

    let on_disk = stl_files(&dir);
    let listed: BTreeSet<String> = rows.iter().map(|r| r.file.clone()).collect();
    assert_eq!(on_disk, listed, "files on disk vs rows in README.md");

    for row in &rows {
        let bytes = std::fs::read(dir.join(&row.file)).unwrap();
        // All files in all chunkings: about 5 s in a debug build, 1-byte 3DBenchy included.
        let chunkings = [bytes.len().max(1), 4096, 7, 1];
        let whole = parse_chunked(&bytes, chunkings[0]);
        let summary: StlSummary = whole.result.unwrap_or_else(|e| panic!("{}: {e}", row.file));
        let ctx = &row.file;
        assert_eq!(summary.triangles, row.triangles, "{ctx}: triangles");
        let format = match summary.format {
            StlFormat::Binary => "binary",
            StlFormat::Ascii => "ASCII",
        };
        assert_eq!(format, row.format, "{ctx}: format");
        assert_eq!(
            whole.triangles.len() as u32,
            summary.triangles - summary.degenerate,
            "{ctx}: emitted = read - degenerate"
        );
        // Well-formed files: no normal that is not a number, no skipped word.
        assert_eq!((summary.bad_normals, summary.ignored_words), (0, 0), "{ctx}: findings");
        if let Some(bbox) = &row.bbox {
            assert_eq!(&printed_bbox(&whole), bbox, "{ctx}: bbox");
        }
        for &size in &chunkings[1..] {
            let chunked = parse_chunked(&bytes, size);
            assert_eq!(chunked.result, whole.result, "{ctx}: summary in {size}-byte chunks");
            assert!(chunked.bits() == whole.bits(), "{ctx}: facets in {size}-byte chunks");
        }
    }
}

#[test]
fn findings_of_the_tricky_models() {
    let Some(dir) = shared_models() else { return };
    let parse = |name: &str| parse_chunked(&std::fs::read(dir.join(name)).unwrap(), 4096);

    // Header starts with "solid ", 1 byte after the 288 records: binary with a trailing byte.
    let half = parse("numpy-stl/stl_binary__HalfDonut.stl").result.unwrap();
    assert_eq!((half.format, half.triangles, half.trailing_bytes), (StlFormat::Binary, 288, 1));
    assert_eq!(half.count_mismatch, None);

    for name in ["numpy-stl/stl_binary__CubeInvalidUnicode.stl", "numpy-stl/stl_binary__Cube.stl"] {
        let s = parse(name).result.unwrap();
        assert_eq!((s.format, s.triangles, s.trailing_bytes), (StlFormat::Binary, 12, 0), "{name}");
    }
    let star = parse("numpy-stl/stl_binary__StarWithEmptyHeader.stl").result.unwrap();
    assert_eq!((star.format, star.triangles), (StlFormat::Binary, 68));

    // trimesh counts 19 degenerate faces in 3DBenchy; we count exact zero-area facets.
    let benchy = parse("3DBenchy.stl").result.unwrap();
    assert_eq!((benchy.triangles, benchy.degenerate), (225_154, 19));

    let mixed_case = parse("numpy-stl/stl_ascii__HalfDonut.stl").result.unwrap();
    assert_eq!((mixed_case.format, mixed_case.triangles), (StlFormat::Ascii, 288));
    assert!(!mixed_case.missing_endsolid);
}

#[test]
fn ascii_and_binary_copies_hold_identical_vertices() {
    let Some(dir) = shared_models() else { return };
    let parse = |name: &str| {
        let p = parse_chunked(&std::fs::read(dir.join("numpy-stl").join(name)).unwrap(), 4096);
        assert!(p.result.is_ok(), "{name}: {:?}", p.result);
        p
    };
    let pairs = [
        ("stl_tests__dos.stl", "stl_binary__Moon.stl"),
        ("stl_tests__unix.stl", "stl_binary__Moon.stl"),
        ("stl_ascii__Moon.stl", "stl_binary__Moon.stl"),
        ("stl_ascii__Moon_Chinese.stl", "stl_binary__Moon.stl"),
        ("stl_ascii__Star.stl", "stl_binary__Star.stl"),
        ("stl_ascii__Star.stl", "stl_binary__StarWithEmptyHeader.stl"),
        ("stl_ascii__Cube.stl", "stl_binary__Cube.stl"),
        ("stl_ascii__HalfDonut.stl", "stl_binary__HalfDonut.stl"),
    ];
    for (ascii, binary) in pairs {
        let (a, b) = (parse(ascii), parse(binary));
        assert_eq!(a.triangles.len(), b.triangles.len(), "{ascii} vs {binary}");
        let va: Vec<_> = a.triangles.iter().map(vertex_bits).collect();
        let vb: Vec<_> = b.triangles.iter().map(vertex_bits).collect();
        assert!(va == vb, "{ascii} vs {binary}: vertices differ");
        // The ASCII normals are printed with 6 decimals: equal to the binary ones within 1e-6.
        for (ta, tb) in a.triangles.iter().zip(&b.triangles) {
            for (na, nb) in ta.normal.iter().zip(tb.normal) {
                assert!((na - nb).abs() <= 1e-6, "{ascii} vs {binary}: normal {na} vs {nb}");
            }
        }
    }
    // The cube's normals are small integers: bit-identical too.
    assert!(parse("stl_ascii__Cube.stl").bits() == parse("stl_binary__Cube.stl").bits());
}
