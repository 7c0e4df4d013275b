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

/// One G-code extrusion: layer, `;TYPE:` name, from, to (mm).
type Extrusion = (u32, String, (f64, f64), (f64, f64));

/// Extrusions of a G-code text: (layer, `;TYPE:` name, from, to) in mm, from its `;LAYER:`
/// and `;TYPE:` comments and its `G0`/`G1` words (relative E: an extrusion has `E` > 0);
/// those before the first layer (the prime line) are left out.
fn gcode_extrusions(gcode: &str) -> Vec<Extrusion> {
    let (mut layer, mut ty, mut pos) = (None, String::new(), (0.0, 0.0));
    let mut out = Vec::new();
    for line in gcode.lines() {
        if let Some(n) = line.strip_prefix(";LAYER:") {
            layer = Some(n.parse().unwrap());
        } else if let Some(t) = line.strip_prefix(";TYPE:") {
            ty = t.to_string();
        }
        let code = line.split(';').next().unwrap().trim();
        let mut words = code.split_whitespace();
        if !matches!(words.next(), Some("G0" | "G1")) {
            continue;
        }
        let (mut to, mut e) = (pos, 0.0);
        for w in words {
            let v: f64 = w[1..].parse().unwrap();
            match &w[..1] {
                "X" => to.0 = v,
                "Y" => to.1 = v,
                "E" => e = v,
                _ => {}
            }
        }
        if let Some(l) = layer.filter(|_| e > 0.0 && to != pos) {
            out.push((l, ty.clone(), pos, to));
        }
        pos = to;
    }
    out
}

#[test]
fn brim_loops_surround_the_first_layer_and_bad_widths_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("holed.stl");
    write_mesh(&model, &holed_block(-10.0, 10.0, -4.0, 4.0, 10.0));
    let out = dir.path().join("holed.gcode");
    Command::cargo_bin("strata")
        .unwrap()
        .args(["slice", model.to_str().unwrap(), "-o", out.to_str().unwrap(), "--brim", "4"])
        .assert()
        .success();
    let gcode = std::fs::read_to_string(&out).unwrap();
    let ex = gcode_extrusions(&gcode);
    // Distance (mm) from the block's 20 mm square, centred on the bed: 100..120 mm.
    let dist = |p: (f64, f64)| {
        let dx = (100.0 - p.0).max(p.0 - 120.0).max(0.0);
        let dy = (100.0 - p.1).max(p.1 - 120.0).max(0.0);
        dx.hypot(dy)
    };
    let brim: Vec<_> = ex.iter().filter(|e| e.1 == "Skirt/Brim").collect();
    assert!(brim.iter().all(|e| e.0 == 0), "brim on the first layer only");
    // floor(4 / 0.45) = 8 loops, their centre lines 0.225 to 3.375 mm out (none in the 8 mm
    // hole: inside the square the distance is 0).
    let ends: Vec<(f64, f64)> = brim.iter().map(|e| e.3).collect();
    let (near, far) =
        ends.iter().map(|&p| dist(p)).fold((f64::MAX, 0.0f64), |(a, b), d| (a.min(d), b.max(d)));
    assert!((near - 0.225).abs() < 0.005 && (far - 3.375).abs() < 0.005, "{near} .. {far}");
    for side in [
        ends.iter().any(|p| p.0 < 100.0),
        ends.iter().any(|p| p.0 > 120.0),
        ends.iter().any(|p| p.1 < 100.0),
        ends.iter().any(|p| p.1 > 120.0),
    ] {
        assert!(side, "the brim surrounds the part");
    }
    // Whole loops: 8 around a 20 mm square, 80 mm + 2 pi d each (chords a little shorter).
    let len: f64 = brim.iter().map(|e| (e.3 .0 - e.2 .0).hypot(e.3 .1 - e.2 .1)).sum();
    let want: f64 =
        (0..8).map(|k| 80.0 + 2.0 * std::f64::consts::PI * (k as f64 + 0.5) * 0.45).sum();
    assert!((len - want).abs() < want * 0.01, "{len} mm vs {want} mm");
    // The skirt 3 mm beyond the brim's outer edge (3.6 mm), printed before it.
    let skirt: Vec<_> = ex.iter().filter(|e| e.1 == "Skirt").collect();
    assert!(skirt.iter().all(|e| (dist(e.3) - 6.825).abs() < 0.005), "{skirt:?}");
    let first = ex.iter().position(|e| e.1 == "Skirt").unwrap();
    assert!(first < ex.iter().position(|e| e.1 == "Skirt/Brim").unwrap());
    // The part comes after the whole brim.
    let last_brim = ex.iter().rposition(|e| e.1 == "Skirt/Brim").unwrap();
    assert!(ex[..last_brim].iter().all(|e| e.1.starts_with("Skirt")));
    // Negative or wider than 50 mm: refused, naming the flag and the range.
    for width in ["--brim=-1", "--brim=50.5"] {
        let bad = Command::cargo_bin("strata")
            .unwrap()
            .args(["slice", model.to_str().unwrap(), "-o", out.to_str().unwrap(), width])
            .assert()
            .failure();
        let err = text(&bad.get_output().stderr);
        assert!(err.contains("--brim") && err.contains("from 0 to 50 mm"), "{width}: {err}");
    }
}
