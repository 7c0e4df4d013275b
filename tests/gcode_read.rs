//! The G-code reader against hand-computed values: numbers exact to the nanometre, Marlin's
//! modal state, line numbers and checksums, targets exact to the motor step, and typed
//! refusals that leave the state as it was.

use proptest::prelude::*;
use strata::gcode::read::{
    target_um, Action, Heater, LineError, LineSplitter, Reader, Report, LINE_BYTES,
};
use strata::machine::{MachineConfig, Rate};
use strata::plan::{Move, MoveKind};
use strata::step::{nearest_step, step_position_q32};

const ENDER3: MachineConfig = MachineConfig::ENDER3;

/// Reads `text` line by line; every line's result.
fn run(reader: &mut Reader, text: &str) -> Vec<Result<Option<String>, LineError>> {
    text.lines().map(|l| reader.line(l.as_bytes()).map(|a| a.map(|a| format!("{a:?}")))).collect()
}

/// The single action of one line.
fn one<'l>(reader: &mut Reader, line: &'l str) -> Result<Option<Action<'l>>, LineError> {
    reader.line(line.as_bytes())
}

fn moved(reader: &mut Reader, line: &str) -> Move {
    match one(reader, line) {
        Ok(Some(Action::Move(m))) => m,
        other => panic!("{line}: {other:?}"),
    }
}

fn mm_s(r: Rate) -> f64 {
    r.to_num::<f64>()
}

#[test]
fn a_move_reaches_its_decimal_target_with_the_modal_feed() {
    let mut r = Reader::new(&ENDER3);
    let m = moved(&mut r, "G1 X12.345 Y67.8 Z0.2 F6000");
    // X 12.345 mm = 12,345 um; 6000 mm/min = 100 mm/s.
    assert_eq!(m.target_um, [12_345, 67_800, 200, 0]);
    assert_eq!(mm_s(m.feed_mm_s), 100.0);
    assert_eq!(m.kind, MoveKind::Travel);
    // The feed rate is modal; spaces between words are optional; lower case is read.
    let m = moved(&mut r, "g1x20y70");
    assert_eq!(m.target_um, [20_000, 70_000, 200, 0]);
    assert_eq!(mm_s(m.feed_mm_s), 100.0);
}

#[test]
fn extrusion_kinds_follow_the_axes_that_move() {
    let mut r = Reader::new(&ENDER3);
    assert_eq!(moved(&mut r, "G1 X10 E1 F1200").kind, MoveKind::Print);
    assert_eq!(moved(&mut r, "G1 E-4 F2700").kind, MoveKind::Retract);
    assert_eq!(moved(&mut r, "G0 X20 F9000").kind, MoveKind::Travel);
}

#[test]
fn relative_extrusion_summed_over_a_print_does_not_drift() {
    let mut r = Reader::new(&ENDER3);
    run(&mut r, "M83\nG1 F1800");
    // 10,000 moves of 0.00123 mm: 12.3 mm exactly, 1143.9 -> step 1144 at 93 steps/mm.
    let mut last = None;
    for i in 0..10_000 {
        let line = format!("G1 X{} E0.00123", 1 + i % 2);
        last = Some(moved(&mut r, &line));
    }
    let e_um = last.unwrap().target_um[3];
    let step = nearest_step(step_position_q32(e_um, ENDER3.steps_per_mm[3]));
    assert_eq!(step, 1144);
    assert!((e_um - 12_300).abs() <= 2, "E {e_um} um");
}

#[test]
fn g92_moves_the_logical_position_not_the_motor() {
    let mut r = Reader::new(&ENDER3);
    run(&mut r, "G1 X10 E5 F1200\nG92 E0 X0");
    // Logical X 5 after G92 X0 at machine 10: machine 15. E continues from 5 mm.
    let m = moved(&mut r, "G1 X5 E2");
    assert_eq!(m.target_um[0], 15_000);
    assert_eq!(nearest_step(step_position_q32(m.target_um[3], ENDER3.steps_per_mm[3])), 651);
    // 7 mm x 93
}

#[test]
fn g91_makes_every_axis_relative_and_g90_every_axis_absolute() {
    let mut r = Reader::new(&ENDER3);
    run(&mut r, "M83\nG1 X10 E1 F600\nG90");
    // After G90 the extruder is absolute again (Marlin 2): E2 goes to 2 mm, not 1 + 2.
    assert_eq!(moved(&mut r, "G1 E2").target_um[3], target_um(2_000_000, ENDER3.steps_per_mm[3]));
    run(&mut r, "G91");
    let m = moved(&mut r, "G1 X1 Y2 Z0.5 E1");
    assert_eq!(&m.target_um[..3], &[11_000, 2_000, 500]);
    assert_eq!(m.target_um[3], target_um(3_000_000, ENDER3.steps_per_mm[3]));
}

#[test]
fn inches_are_25_4_mm() {
    let mut r = Reader::new(&ENDER3);
    run(&mut r, "G20");
    let m = moved(&mut r, "G1 X1 Y0.5 F60");
    assert_eq!(&m.target_um[..2], &[25_400, 12_700]);
    // 60 in/min = 25.4 mm/s.
    assert!((mm_s(m.feed_mm_s) - 25.4).abs() < 1e-6);
    run(&mut r, "G21");
    assert_eq!(moved(&mut r, "G1 X1").target_um[0], 1_000);
}

#[test]
fn targets_beyond_the_bed_are_clamped_and_counted() {
    let mut r = Reader::new(&ENDER3);
    let m = moved(&mut r, "G1 X-3 Y300 Z5 F3000");
    assert_eq!(&m.target_um[..3], &[0, 220_000, 5_000]);
    assert_eq!(r.stats().clamped, 1);
}

#[test]
fn speed_and_flow_factors_scale_feed_and_extrusion() {
    let mut r = Reader::new(&ENDER3);
    run(&mut r, "M220 S50\nM221 S200\nM83");
    let m = moved(&mut r, "G1 X10 E1 F6000");
    assert!((mm_s(m.feed_mm_s) - 50.0).abs() < 1e-6);
    // 1 mm of filament at 200 % flow: 2 mm = 186 steps.
    assert_eq!(nearest_step(step_position_q32(m.target_um[3], ENDER3.steps_per_mm[3])), 186);
    assert_eq!(one(&mut r, "M220 S5"), Err(LineError::OutOfRange { letter: b'S' }));
}

#[test]
fn dwell_homing_heaters_fan_and_reports() {
    let mut r = Reader::new(&ENDER3);
    let d = moved(&mut r, "G4 P500");
    assert_eq!((d.kind, mm_s(d.feed_mm_s)), (MoveKind::Dwell, 0.5));
    assert_eq!(mm_s(moved(&mut r, "G4 S2").feed_mm_s), 2.0);
    assert_eq!(one(&mut r, "G4"), Ok(None));

    run(&mut r, "G1 X50 Y60 Z7 F3000");
    match one(&mut r, "G28 X") {
        Ok(Some(Action::Home { axes, travel })) => {
            assert_eq!(axes, 0b001);
            assert_eq!(&travel.target_um[..3], &[0, 60_000, 7_000]);
        }
        other => panic!("{other:?}"),
    }
    assert!(matches!(one(&mut r, "G28"), Ok(Some(Action::Home { axes: 0b111, .. }))));

    let heat = |h, t, wait, cool| Ok(Some(Action::Heat { heater: h, target_c: t, wait, cool }));
    assert_eq!(one(&mut r, "M104 S200"), heat(Heater::Hotend, 200, false, false));
    assert_eq!(one(&mut r, "M109 R180"), heat(Heater::Hotend, 180, true, true));
    assert_eq!(one(&mut r, "M190 S60"), heat(Heater::Bed, 60, true, false));
    assert_eq!(one(&mut r, "M140 S0"), heat(Heater::Bed, 0, false, false));
    // Above the machine's maximum (260 degC hotend): refused, never clamped.
    assert_eq!(one(&mut r, "M104 S300"), Err(LineError::OutOfRange { letter: b'S' }));
    assert_eq!(one(&mut r, "M104"), Err(LineError::MissingValue { letter: b'S' }));

    assert_eq!(one(&mut r, "M106"), Ok(Some(Action::Fan(255))));
    assert_eq!(one(&mut r, "M106 S127.5"), Ok(Some(Action::Fan(127))));
    assert_eq!(one(&mut r, "M107"), Ok(Some(Action::Fan(0))));
    assert!(matches!(one(&mut r, "M106 P1 S255"), Ok(Some(Action::Skipped { code: 106, .. }))));
    assert_eq!(one(&mut r, "M84"), Ok(Some(Action::MotorsOff)));
    assert!(matches!(one(&mut r, "M84 S600"), Ok(Some(Action::Skipped { .. }))));
    assert_eq!(one(&mut r, "M105"), Ok(Some(Action::Report(Report::Temperatures))));
    assert_eq!(one(&mut r, "M114"), Ok(Some(Action::Report(Report::Position))));
    assert_eq!(one(&mut r, "M115"), Ok(Some(Action::Report(Report::Firmware))));
    assert_eq!(one(&mut r, "M400"), Ok(Some(Action::Sync)));
    assert_eq!(
        one(&mut r, "M117 Printing  cube; done"),
        Ok(Some(Action::Message(b"Printing  cube")))
    );
    assert_eq!(
        one(&mut r, "M73 P42 R17"),
        Ok(Some(Action::Progress { percent: Some(42), minutes_left: Some(17) }))
    );
}

#[test]
fn unknown_commands_are_skipped_whatever_they_carry() {
    let mut r = Reader::new(&ENDER3);
    for line in
        ["M201 X500 Y500 Z100 E5000", "M23 my.file~1.gco", "G29.1", "M204 P500 R1000 T500", "T1"]
    {
        assert!(matches!(one(&mut r, line), Ok(Some(Action::Skipped { .. }))), "{line}");
    }
    assert_eq!(r.stats().skipped, 5);
    assert_eq!(r.stats().refused, 0);
}

#[test]
fn malformed_numbers_are_typed_errors_that_change_nothing() {
    let mut r = Reader::new(&ENDER3);
    run(&mut r, "G1 X10 Y10 F3000");
    let bad = |l| LineError::BadNumber { letter: l };
    for (line, err) in [
        ("G1 X20 YNaN", LineError::MissingValue { letter: b'Y' }),
        ("G1 X20 Y1e5", bad(b'Y')),
        ("G1 X20 Y-", bad(b'Y')),
        ("G1 X20 Y1.2.3", bad(b'Y')),
        ("G1 X20 Y1234567890", bad(b'Y')),
        ("G1 X20 Y", LineError::MissingValue { letter: b'Y' }),
        ("G1 X20 Y5 F0", LineError::OutOfRange { letter: b'F' }),
        ("G1 X20 #", LineError::Unexpected { byte: b'#' }),
        ("G", LineError::MissingValue { letter: b'G' }),
        ("G99999", bad(b'G')),
        ("hello", LineError::Unexpected { byte: b'h' }),
    ] {
        assert_eq!(one(&mut r, line), Err(err), "{line}");
    }
    // The position is still (10, 10): a relative-free check of the next move.
    assert_eq!(&moved(&mut r, "G1 Z1").target_um[..3], &[10_000, 10_000, 1_000]);
    assert_eq!(r.stats().refused, 11);
}

#[test]
fn numbers_keep_six_decimals_and_round_the_seventh() {
    let mut r = Reader::new(&ENDER3);
    run(&mut r, "M83\nG1 F60");
    // 0.0000015 mm rounds to 2 nm, ten thousand times: 20 um, not 10 or 15.
    for _ in 0..10_000 {
        moved(&mut r, "G1 E0.0000015");
    }
    assert_eq!(r.machine_um()[3], 20);
    // Signs, leading points, trailing points.
    assert_eq!(moved(&mut r, "G1 X.5 Y+5. Z0").target_um[..3], [500, 5_000, 0]);
}

/// XOR of the bytes: Marlin's checksum, computed here independently of the reader.
fn checksum(s: &str) -> u8 {
    s.bytes().fold(0, |a, b| a ^ b)
}

#[test]
fn line_numbers_need_checksums_and_follow_each_other() {
    let mut r = Reader::new(&ENDER3);
    let numbered = |n: u32, cmd: &str| {
        let body = format!("N{n} {cmd}");
        format!("{body}*{}", checksum(&body))
    };
    assert_eq!(one(&mut r, &numbered(1, "G1 X5 F600")).map(|a| a.is_some()), Ok(true));
    assert_eq!(one(&mut r, &numbered(3, "G1 X6")), Err(LineError::LineNumber { expected: 2 }));
    assert_eq!(one(&mut r, "N2 G1 X6"), Err(LineError::MissingChecksum));
    let body = "N2 G1 X6";
    let wrong = checksum(body) ^ 1;
    assert_eq!(
        one(&mut r, &format!("{body}*{wrong}")),
        Err(LineError::Checksum { computed: checksum(body) })
    );
    assert_eq!(moved(&mut r, &numbered(2, "G1 X6")).target_um[0], 6_000);
    // M110 sets the next number; unnumbered lines are not counted.
    assert_eq!(one(&mut r, &numbered(100, "M110")), Ok(None));
    assert_eq!(moved(&mut r, "G1 X7").target_um[0], 7_000);
    assert_eq!(moved(&mut r, &numbered(101, "G1 X8")).target_um[0], 8_000);
}

#[test]
fn layer_markers_of_prusaslicer_cura_and_strata() {
    let mut r = Reader::new(&ENDER3);
    let markers = |r: &mut Reader, text: &str| -> Vec<String> {
        run(r, text).into_iter().filter_map(|a| a.ok().flatten()).collect()
    };
    assert_eq!(
        markers(
            &mut r,
            ";LAYER_COUNT:100\n;LAYER:-2\n;LAYER:0\n;LAYER_CHANGE\n;Z:0.4\n; LAYER_CHANGE"
        ),
        ["LayerCount(100)", "Layer(0)", "Layer(0)", "Layer(1)", "Layer(2)"]
    );
}

#[test]
fn the_splitter_cuts_lines_across_chunks_and_refuses_long_ones() {
    let long_comment = format!("G1 X4 ;{}", "c".repeat(LINE_BYTES));
    let text = format!("G1 X1\r\nG1 X2\n{}\n{long_comment}\nG1 X3", "X".repeat(LINE_BYTES + 1));
    // Every chunk size gives the same lines.
    for chunk in [1, 2, 7, 64, 1000] {
        let mut s = LineSplitter::new();
        let mut lines: Vec<Result<String, LineError>> = Vec::new();
        for piece in text.as_bytes().chunks(chunk) {
            let mut rest = piece;
            while !rest.is_empty() {
                let (taken, line) = s.take(rest);
                rest = &rest[taken..];
                if let Some(l) = line {
                    lines.push(l.map(|()| String::from_utf8_lossy(s.line()).into_owned()));
                }
            }
        }
        if let Some(l) = s.finish() {
            lines.push(l.map(|()| String::from_utf8_lossy(s.line()).into_owned()));
        }
        let want: Vec<Result<String, LineError>> = vec![
            Ok("G1 X1".into()),
            Ok("".into()),
            Ok("G1 X2".into()),
            Err(LineError::TooLong),
            // A long comment is cut to the line's bytes; a long command is refused.
            Ok(long_comment[..LINE_BYTES].into()),
            Ok("G1 X3".into()),
        ];
        assert_eq!(lines, want, "chunks of {chunk}");
    }
    // A line of exactly LINE_BYTES bytes is taken.
    let mut s = LineSplitter::new();
    let full = "G".repeat(LINE_BYTES) + "\n";
    assert_eq!(s.take(full.as_bytes()), (LINE_BYTES + 1, Some(Ok(()))));
}

proptest! {
    /// The um target lands on the motor step nearest the exact position, on every axis.
    #[test]
    fn targets_are_exact_to_the_step(nm in -2_000_000_000_000i64..2_000_000_000_000, axis in 0usize..4) {
        let spm = ENDER3.steps_per_mm[axis];
        let spm_int = spm.to_num::<i64>() as i128;
        // Nearest step of nm * spm / 10^6 (half up), in exact integers.
        let want = (2 * nm as i128 * spm_int + 1_000_000).div_euclid(2_000_000) as i64;
        let um = target_um(nm, spm);
        prop_assert_eq!(nearest_step(step_position_q32(um, spm)), want);
        prop_assert!((um as i64 * 1000 - nm).abs() <= 2_500, "{} um for {} nm", um, nm);
    }
}

#[test]
fn the_slowest_feed_is_marlins_slowest_planned_speed() {
    let mut r = Reader::new(&ENDER3);
    // F0.000001 mm/min would take 2 years a mm; Marlin plans nothing slower than 0.05 mm/s.
    let m = moved(&mut r, "G1 X1 F0.000001");
    assert!((mm_s(m.feed_mm_s) - 0.05).abs() < 1e-9, "{}", mm_s(m.feed_mm_s));
    assert!((mm_s(moved(&mut r, "G1 X2 F3.6").feed_mm_s) - 0.06).abs() < 1e-9);
}

/// Every segment of the arc `line` (after `setup`), as (x, y, z, e) in mm.
fn arc_points(setup: &str, line: &str) -> Vec<[f64; 4]> {
    let mut r = Reader::new(&ENDER3);
    run(&mut r, setup);
    let first = moved(&mut r, line);
    let mut out = vec![first];
    out.extend(std::iter::from_fn(|| r.continuation()));
    out.iter().map(|m| m.target_um.map(|um| f64::from(um) / 1000.0)).collect()
}

/// The point lies on the circle of `radius` mm around (`cx`, `cy`) to within the um the
/// targets are rounded to and the half step they are moved by (6.25 um at 80 steps/mm).
fn assert_on_circle(p: &[f64; 4], cx: f64, cy: f64, radius: f64) {
    let d = ((p[0] - cx).powi(2) + (p[1] - cy).powi(2)).sqrt();
    assert!((d - radius).abs() < 0.008, "{p:?} is {d} mm from the centre");
}

#[test]
fn arcs_are_cut_into_millimetre_segments_on_their_circle() {
    // Half a circle of radius 10 mm anticlockwise over the top: pi x 10 mm, 31 segments.
    let up = arc_points("G1 X110 Y100 F3000", "G3 X90 Y100 I-10 J0");
    assert_eq!(up.len(), 31);
    let mut last_angle = 0.0;
    for p in &up {
        assert_on_circle(p, 100.0, 100.0, 10.0);
        assert!(p[1] >= 100.0 - 0.007, "{p:?} below the centre");
        let angle = (p[1] - 100.0).atan2(p[0] - 100.0).rem_euclid(std::f64::consts::TAU);
        assert!(angle + 1e-6 >= last_angle, "not anticlockwise: {angle} after {last_angle}");
        last_angle = angle;
    }
    assert_eq!(up.last().unwrap()[..2], [90.0, 100.0]);
    // Clockwise between the same points: under the centre.
    let down = arc_points("G1 X110 Y100 F3000", "G2 X90 Y100 I-10 J0");
    assert_eq!(down.len(), 31);
    assert!(down.iter().all(|p| p[1] <= 100.0 + 0.007));
    // The same start and end: a whole circle, 2 pi x 10 mm.
    let whole = arc_points("G1 X110 Y100 F3000", "G2 X110 Y100 I-10 J0");
    assert_eq!(whole.len(), 62);
    whole.iter().for_each(|p| assert_on_circle(p, 100.0, 100.0, 10.0));
    assert!(whole.iter().any(|p| p[1] < 91.0) && whole.iter().any(|p| p[1] > 109.0));
}

#[test]
fn a_helix_rises_and_extrudes_in_proportion() {
    // A quarter circle of radius 20 mm (31.4 mm of arc, 31 segments) rising 1 mm with 2 mm
    // of filament, relative extrusion.
    let pts = arc_points("G1 X120 Y100 Z1 F3000\nM83", "G3 X100 Y120 Z2 E2 I-20 J0");
    let n = pts.len();
    assert_eq!(n, 31);
    for (k, p) in pts.iter().enumerate() {
        let share = (k + 1) as f64 / n as f64;
        assert_on_circle(p, 100.0, 100.0, 20.0);
        // Z within a step (2.5 um), E within a step (10.8 um) of the proportion.
        assert!((p[2] - (1.0 + share)).abs() < 0.0026, "Z {} at {share}", p[2]);
        assert!((p[3] - 2.0 * share).abs() < 0.011, "E {} at {share}", p[3]);
    }
}

#[test]
fn the_radius_form_takes_the_short_way_unless_negative() {
    // From (110, 100) to (100, 110), radius 10: anticlockwise the short way is around
    // (100, 100), a quarter circle (15.7 mm, 15 segments); R-10 goes the long way round
    // (110, 110): three quarters (47.1 mm, 47 segments).
    let short = arc_points("G1 X110 Y100 F3000", "G3 X100 Y110 R10");
    assert_eq!(short.len(), 15);
    short.iter().for_each(|p| assert_on_circle(p, 100.0, 100.0, 10.0));
    let long = arc_points("G1 X110 Y100 F3000", "G3 X100 Y110 R-10");
    assert_eq!(long.len(), 47);
    long.iter().for_each(|p| assert_on_circle(p, 110.0, 110.0, 10.0));
    // Clockwise, the short way is around (110, 110).
    let cw = arc_points("G1 X110 Y100 F3000", "G2 X100 Y110 R10");
    assert_eq!(cw.len(), 15);
    cw.iter().for_each(|p| assert_on_circle(p, 110.0, 110.0, 10.0));
    // Ends further apart than the diameter: refused, nothing moves.
    let mut r = Reader::new(&ENDER3);
    run(&mut r, "G1 X110 Y100 F3000");
    assert_eq!(one(&mut r, "G2 X80 Y100 R10"), Err(LineError::OutOfRange { letter: b'R' }));
    assert_eq!(one(&mut r, "G2 X80 Y100"), Err(LineError::MissingValue { letter: b'I' }));
    assert_eq!(r.continuation(), None);
    assert_eq!(&moved(&mut r, "G1 Z1").target_um[..2], &[110_000, 100_000]);
}
