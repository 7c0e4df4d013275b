//! `strata inspect` end to end: JSON contract, closedness, findings, errors.

use std::path::PathBuf;

use assert_cmd::Command;
use serde_json::Value;

fn data(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../tests/data").join(name)
}

fn inspect_json(path: &std::path::Path) -> Value {
    let out = Command::cargo_bin("strata")
        .unwrap()
        .arg("inspect")
        .arg(path)
        .arg("--json")
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&out.stdout).expect("stdout is JSON")
}

#[test]
fn json_keys_and_values_of_the_binary_cube() {
    let v = inspect_json(&data("cube10_binary.stl"));
    let keys: Vec<&str> = v.as_object().unwrap().keys().map(String::as_str).collect();
    let mut expected =
        vec!["format", "triangles", "degenerate", "bbox_min", "bbox_max", "closed", "findings"];
    expected.sort_unstable();
    let mut keys_sorted = keys.clone();
    keys_sorted.sort_unstable();
    assert_eq!(keys_sorted, expected);
    assert_eq!(v["format"], "binary");
    assert_eq!(v["triangles"], 12);
    assert_eq!(v["degenerate"], 0);
    assert_eq!(v["bbox_min"], serde_json::json!([0.0, 0.0, 0.0]));
    assert_eq!(v["bbox_max"], serde_json::json!([10.0, 10.0, 10.0]));
    assert_eq!(v["closed"], true);
    assert_eq!(v["findings"]["count_mismatch"], Value::Null);
    assert_eq!(v["findings"]["open_edges"], 0);
}

#[test]
fn ascii_cube_and_block_with_hole_are_closed() {
    let v = inspect_json(&data("cube10_ascii_crlf.stl"));
    assert_eq!((v["format"].as_str(), v["triangles"].as_u64()), (Some("ascii"), Some(12)));
    assert_eq!(v["closed"], true);

    let v = inspect_json(&data("cube_with_hole_20mm.stl"));
    assert_eq!(v["triangles"], 32);
    assert_eq!(v["closed"], true);
    assert_eq!(v["bbox_min"], serde_json::json!([0.0, 0.0, 0.0]));
    assert_eq!(v["bbox_max"], serde_json::json!([20.0, 20.0, 10.0]));
}

#[test]
fn cube_with_a_facet_removed_is_open() {
    let v = inspect_json(&data("cube10_open_ascii.stl"));
    assert_eq!(v["triangles"], 11);
    assert_eq!(v["closed"], false);
    assert_eq!(v["findings"]["open_edges"], 3);
}

#[test]
fn findings_count_mismatch_and_trailing_bytes() {
    let mut bytes = std::fs::read(data("cube10_binary.stl")).unwrap();
    bytes[80] = 11; // header says 11, the file holds 12 records
    bytes.extend_from_slice(b"xyz");
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("odd.stl");
    std::fs::write(&path, &bytes).unwrap();
    let v = inspect_json(&path);
    assert_eq!(v["findings"]["count_mismatch"], serde_json::json!({"declared": 11, "found": 12}));
    assert_eq!(v["findings"]["trailing_bytes"], 3);
    assert_eq!(v["closed"], true);

    let out = Command::cargo_bin("strata").unwrap().arg("inspect").arg(&path).output().unwrap();
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(text.contains("header declares 11 facets, file holds 12"), "{text}");
    assert!(text.contains("3 bytes after the last facet"), "{text}");
}

#[test]
fn human_output_has_aligned_lines() {
    let out = Command::cargo_bin("strata")
        .unwrap()
        .arg("inspect")
        .arg(data("cube10_open_ascii.stl"))
        .output()
        .unwrap();
    assert!(out.status.success());
    let text = String::from_utf8(out.stdout).unwrap();
    for line in ["format     ascii", "triangles  11 (0 degenerate)", "closed     no"] {
        assert!(text.lines().any(|l| l == line), "missing {line:?} in\n{text}");
    }
    assert!(text.contains("bbox       (0.000, 0.000, 0.000) .. (10.000, 10.000, 10.000) mm"));
    assert!(text.contains("finding    3 open edges"), "{text}");
}

#[test]
fn a_broken_file_exits_non_zero_with_path_and_offset() {
    let bytes = std::fs::read(data("cube10_binary.stl")).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("cut.stl");
    std::fs::write(&path, &bytes[..84 + 50 * 3 + 20]).unwrap();
    let out = Command::cargo_bin("strata").unwrap().arg("inspect").arg(&path).output().unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8(out.stderr).unwrap();
    let want = format!(
        "strata: error: {}: binary STL ends inside a facet record (fewer than declared) at byte 234",
        path.display()
    );
    assert_eq!(err.trim_end(), want);

    let out = Command::cargo_bin("strata")
        .unwrap()
        .args(["inspect", "--json"])
        .arg(dir.path().join("missing.stl"))
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8(out.stderr).unwrap().starts_with("strata: error: "));
}

/// PrusaSlicer's nonstandard box (normals `+inf -inf weirdvalue`) loads with its odd normals
/// and skipped words as findings.
#[test]
fn normals_that_are_not_numbers_load_as_findings() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("weird.stl");
    let facet = |n: &str, z: f32| {
        format!(
            "facet normal {n}\n outer loop\n  vertex 0 0 {z}\n  vertex 10 0 {z}\n  vertex 0 10 {z}\n \
             endloop\nendfacet\n"
        )
    };
    let text = format!(
        "solid weird\n{}{}endsolid weird\n",
        facet("+inf -inf weirdvalue", 0.0),
        facet("0 0 1", 5.0)
    );
    std::fs::write(&path, text).unwrap();
    let v = inspect_json(&path);
    assert_eq!(v["triangles"], 2);
    assert_eq!(v["findings"]["bad_normals"], 1);
    let out = Command::cargo_bin("strata").unwrap().arg("inspect").arg(&path).output().unwrap();
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(text.contains("1 facets with a normal that is not a number (not used)"), "{text}");
}
