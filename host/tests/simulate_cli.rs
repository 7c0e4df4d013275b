//! `strata simulate` end to end on a small model written by the test: the JSON contract
//! (exact keys), a model that fits streamed unchanged, and the human summary.

use assert_cmd::Command;
use serde_json::Value;
use strata_testkit::mesh::holed_block;
use strata_testkit::stl::write_mesh;

#[test]
fn simulate_json_has_the_contract_keys() {
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("holed.stl");
    write_mesh(&model, &holed_block(-5.0, 5.0, -2.0, 2.0, 1.2));
    let out = Command::cargo_bin("strata")
        .unwrap()
        .args(["simulate", model.to_str().unwrap(), "--json", "--skirt-loops", "0"])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: Value = serde_json::from_slice(&out.stdout).unwrap();
    let keys: Vec<&str> = v.as_object().unwrap().keys().map(String::as_str).collect();
    for k in [
        "layers",
        "print_time_s",
        "filament_mm",
        "steps",
        "max_step_error_us",
        "peak_active_triangles",
        "peak_contour_points",
        "device_ram_bytes",
        "wire_bytes_per_triangle",
        "simplified",
        "layer_hashes",
    ] {
        assert!(keys.contains(&k), "missing {k} in {keys:?}");
    }
    assert_eq!(v["layers"], 6);
    assert!(v["simplified"].is_null(), "a small model is streamed unchanged");
    let hashes = v["layer_hashes"].as_array().unwrap();
    assert_eq!(hashes.len(), 6);
    assert!(hashes.iter().all(|h| h.as_str().unwrap().len() == 16));
    for axis in ["x", "y", "z", "e"] {
        assert!(v["steps"][axis].as_u64().unwrap() > 0, "{axis}");
    }
    // 1.2 mm at 400 steps/mm, up and (end of job) nowhere else: Z steps = last layer's z.
    assert_eq!(v["steps"]["z"], 480);
    let wire = v["wire_bytes_per_triangle"].as_f64().unwrap();
    assert!(wire > 20.0 && wire <= 25.0, "{wire}");
    assert!(v["print_time_s"].as_f64().unwrap() > 10.0);
    assert!(v["peak_active_triangles"].as_u64().unwrap() <= 32);
    assert_eq!(v["max_step_error_us"], 0.5);

    // Identical jobs give identical hashes.
    let again = Command::cargo_bin("strata")
        .unwrap()
        .args(["simulate", model.to_str().unwrap(), "--json", "--skirt-loops", "0"])
        .output()
        .unwrap();
    let w: Value = serde_json::from_slice(&again.stdout).unwrap();
    assert_eq!(w["layer_hashes"], v["layer_hashes"]);

    let preview = dir.path().join("preview");
    let human = Command::cargo_bin("strata")
        .unwrap()
        .args(["simulate", model.to_str().unwrap(), "--skirt-loops", "0", "--loss", "0.03"])
        .arg("--preview")
        .arg(&preview)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&human.stdout);
    assert!(human.status.success());
    assert!(text.contains("6 layers") && text.contains("bytes per triangle"), "{text}");
    assert!(text.contains("preview: 6 layer pictures"), "{text}");
    let html = std::fs::read_to_string(preview.join("index.html")).unwrap();
    assert!(html.contains("layer_0005.svg"));
    for i in 0..6 {
        let svg = std::fs::read_to_string(preview.join(format!("layer_{i:04}.svg"))).unwrap();
        // Extrusion drawn in blue, inside the 10 mm block around (110, 110).
        let ext = svg.lines().find(|l| l.contains("#1f5fbf")).unwrap();
        assert!(ext.len() > 200, "layer {i}: {ext}");
        assert!(ext.contains("M10") || ext.contains("M11"), "layer {i}");
    }
}

#[test]
fn simulate_refuses_a_model_off_the_bed() {
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("big.stl");
    write_mesh(&model, &holed_block(-150.0, 150.0, -2.0, 2.0, 1.0));
    let out = Command::cargo_bin("strata")
        .unwrap()
        .args(["simulate", model.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("build volume"), "{err}");
}

/// A G-code file whose motion has a closed form: one 100 mm travel at 10 mm/s from rest to
/// rest, then a 2 s dwell; an unknown command and a malformed line are reported, not fatal.
#[test]
fn simulate_runs_a_gcode_file_with_a_closed_form_time() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("line.gcode");
    let text = "G28\nG90\nM201 X500\nG1 X100 F600\nG1 Y1e5\nG4 P2000\n";
    std::fs::write(&file, text).unwrap();
    let out = Command::cargo_bin("strata")
        .unwrap()
        .args(["simulate", file.to_str().unwrap(), "--json"])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: Value = serde_json::from_slice(&out.stdout).unwrap();
    // L / v + v / a: 100 mm at 10 mm/s, the travel acceleration lowered to X's 500 mm/s^2
    // (accelerating and braking each take v / 2a longer than cruising), plus the dwell.
    let want = 100.0 / 10.0 + 10.0 / 500.0 + 2.0;
    let got = v["planned_s"].as_f64().unwrap();
    assert!((got - want).abs() < 1e-6, "{got} s, want {want} s");
    // 100 mm at 80 steps/mm.
    assert_eq!(v["steps"]["x"], 8000);
    assert_eq!(v["positions"][0], 8000);
    assert_eq!(v["skipped"]["M201"], 1);
    assert_eq!(v["refused"], 1);
    assert_eq!(v["refusals"][0], "line 5: Y has a malformed number");
}
