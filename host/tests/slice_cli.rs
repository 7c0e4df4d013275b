//! `strata slice` end to end on a model written by the test: a 20 x 20 x 10 mm block with an
//! 8 x 8 mm square through-hole, as binary STL.

use assert_cmd::Command;
use serde_json::Value;
use strata_testkit::check;
use strata_testkit::mesh::holed_block;
use strata_testkit::stl::write_mesh;

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// Signed area of a JSON loop's `[x, y]` points.
fn signed_area(points: &[Value]) -> f64 {
    let p: Vec<(f64, f64)> =
        points.iter().map(|q| (q[0].as_f64().unwrap(), q[1].as_f64().unwrap())).collect();
    check::signed_area(&p)
}

#[test]
fn slice_writes_oriented_contours_and_one_svg_per_layer() {
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("holed.stl");
    write_mesh(&model, &holed_block(-10.0, 10.0, -4.0, 4.0, 10.0));
    let json = dir.path().join("contours.json");
    let svg = dir.path().join("svg");
    let out = Command::cargo_bin("strata")
        .unwrap()
        .args(["slice", model.to_str().unwrap(), "--contours-json"])
        .arg(&json)
        .arg("--svg")
        .arg(&svg)
        .assert()
        .success()
        .get_output()
        .stdout
        .clone();
    let stdout = String::from_utf8(out).unwrap();
    assert!(stdout.contains("50 layers, 100 loops (50 holes)"), "{stdout}");
    assert!(stdout.contains("repairs: none"), "{stdout}");
    assert!(stdout.contains("peak active triangles 16"), "{stdout}");

    let doc: Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    let layers = doc["layers"].as_array().unwrap();
    assert_eq!(layers.len(), 50);
    assert_eq!(layers[0]["z"].as_f64(), Some(0.1));
    assert_eq!(layers[49]["z"].as_f64(), Some(9.9));
    for layer in layers {
        let loops = layer["loops"].as_array().unwrap();
        assert_eq!(loops.len(), 2);
        let mut total = 0.0;
        for l in loops {
            let a = signed_area(l["points"].as_array().unwrap());
            // Outer counter-clockwise, hole clockwise; centred on the 220 mm bed.
            assert_eq!(l["hole"].as_bool().unwrap(), a < 0.0, "{a}");
            total += a;
            let x = l["points"][0][0].as_f64().unwrap();
            assert!((100.0..=120.0).contains(&x), "{x}");
        }
        assert!((total - 336.0).abs() < 1e-6, "{total}");
    }
    // Each wall quad is two triangles: 16 cut segments, 16 points (collinear pairs kept).
    assert_eq!(doc["summary"]["peak_contour_points"], 16);

    let names: Vec<String> = std::fs::read_dir(&svg)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(names.len(), 50);
    let first = std::fs::read_to_string(svg.join("layer_0000.svg")).unwrap();
    assert!(first.starts_with("<svg") && first.contains("fill-rule=\"evenodd\""));
    assert!(first.contains("class=\"hole\" d=\"M"), "{first}");
}

#[test]
fn layer_height_options_change_the_layer_count() {
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("holed.stl");
    write_mesh(&model, &holed_block(-10.0, 10.0, -4.0, 4.0, 10.0));
    // Planes at 0.15, then 0.35, 0.45, ... 9.95 mm: 1 + 97 layers.
    let ok = Command::cargo_bin("strata")
        .unwrap()
        .args(["slice", model.to_str().unwrap(), "--layer-height", "0.1"])
        .args(["--first-layer-height", "0.3"])
        .assert()
        .success();
    assert!(text(&ok.get_output().stdout).contains("98 layers"));
    let bad = Command::cargo_bin("strata")
        .unwrap()
        .args(["slice", model.to_str().unwrap(), "--layer-height", "0"])
        .assert()
        .failure();
    assert!(text(&bad.get_output().stderr).contains("--layer-height"));
}

#[test]
fn model_larger_than_the_bed_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("wide.stl");
    write_mesh(&model, &holed_block(0.0, 230.0, 100.0, 110.0, 1.0));
    let bad = Command::cargo_bin("strata")
        .unwrap()
        .args(["slice", model.to_str().unwrap()])
        .assert()
        .failure();
    let err = text(&bad.get_output().stderr);
    assert!(err.contains("along X"), "{err}");
}
