//! Printing from the printer's SD card in the simulated printer: PrusaSlicer's G-code of
//! `xyz_20mm_cube.stl` on a card image the `fatfs` crate wrote prints step for step as the
//! same file streamed over the link (every layer hash, the job report, the board's step
//! hash), with the host there to the end or gone after the start, and so does a model's job
//! `strata upload` wrote (as the model streamed); what cannot print from the card is refused
//! in words and starts nothing, and a damaged job file fails where its damage is.

use std::path::PathBuf;

use strata::machine::MachineConfig;
use strata::protocol::DeviceState;
use strata_host::card_image::ImageCard;
use strata_host::gcode_file;
use strata_host::session::Source;
use strata_host::simjob::{simulate_source, simulate_with_card, Faults, SimOptions, SimReport};

const ENDER3: MachineConfig = MachineConfig::ENDER3;
const GCODE: &str = "xyz_20mm_cube_prusaslicer.gcode";

fn fixture(path: &str) -> Vec<u8> {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(path);
    std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// A FAT32 card behind a partition table with the cube's G-code, the cube's STL, a binary
/// file and a directory.
fn card() -> ImageCard {
    let gcode = fixture("../tests/data/gcode/xyz_20mm_cube_prusaslicer.gcode");
    let stl = fixture("../../shared/models/xyz_20mm_cube.stl");
    let files: [(&str, &[u8]); 3] = [
        (GCODE, &gcode),
        ("xyz_20mm_cube.stl", &stl),
        ("photo.jpg", b"\xff\xd8\xff\xe0\0\x10JFIF"),
    ];
    ImageCard::new(strata_testkit::card::image(fatfs::FatType::Fat32, 64, &files, true))
}

/// The same file streamed over the link: the reference.
fn streamed() -> SimReport {
    let text = fixture("../tests/data/gcode/xyz_20mm_cube_prusaslicer.gcode");
    let scan = gcode_file::scan(&text, &ENDER3).unwrap();
    simulate_source(Source::Gcode(&text, scan.spec), &ENDER3, &SimOptions::default()).unwrap()
}

/// The motion of `got` is the reference's, step for step.
fn assert_same_motion(what: &str, got: &SimReport, want: &SimReport) {
    assert_eq!(got.device_state, Some(DeviceState::Done), "{what}: final state");
    assert_eq!(got.steps, want.steps, "{what}: steps per axis");
    assert_eq!(got.positions, want.positions, "{what}: final positions");
    assert_eq!(got.print_ticks, want.print_ticks, "{what}: print time, ticks");
    assert_eq!(got.board_hash, want.board_hash, "{what}: every step edge (axis, direction, tick)");
    assert_eq!((got.underruns, got.violations), (0, 0), "{what}: underruns, violations");
}

#[test]
fn a_gcode_file_prints_from_the_card_as_it_does_streamed() {
    let want = streamed();
    let source = Source::Card { name: GCODE, detach: false };
    let got = simulate_with_card(source, &ENDER3, &SimOptions::default(), Some(card()))
        .unwrap_or_else(|(e, _)| panic!("{e}"));
    assert_same_motion("from the card", &got, &want);
    assert!(want.layer_hashes.len() > 90, "{} layers", want.layer_hashes.len());
    assert_eq!(got.layer_hashes, want.layer_hashes, "every layer's hash");
    assert_eq!(got.job_report, want.job_report, "the job report");
    eprintln!(
        "{GCODE} from the card: {} layers, {:.1} s of print, as streamed",
        got.layer_hashes.len(),
        got.print_time_s
    );
}

/// The host goes away 5 s after the start (its link cut): the job from the card prints to
/// its end as if it were there (a streamed job would park).
#[test]
fn a_job_from_the_card_finishes_without_its_host() {
    let want = streamed();
    let opts = SimOptions {
        faults: Faults { cut_at_ms: Some(5_000), ..Faults::default() },
        device_outlives_host: true,
        ..SimOptions::default()
    };
    let source = Source::Card { name: GCODE, detach: false };
    let (e, got) = simulate_with_card(source, &ENDER3, &opts, Some(card())).unwrap_err();
    assert!(e.contains("link dead"), "{e}");
    assert_same_motion("host gone", &got, &want);
    assert!(got.parked_ms.is_none(), "a job from the card does not park");
    let seen = got.layer_hashes.len();
    assert!(seen < want.layer_hashes.len(), "the host saw {seen} layers");
    assert_eq!(got.layer_hashes[..seen], want.layer_hashes[..seen]);
}

/// `--detach`: the host's part ends once the printer says it started.
#[test]
fn a_detached_host_leaves_once_the_job_started() {
    let want = streamed();
    let source = Source::Card { name: GCODE, detach: true };
    let got = simulate_with_card(source, &ENDER3, &SimOptions::default(), Some(card()))
        .unwrap_or_else(|(e, _)| panic!("{e}"));
    assert_same_motion("detached", &got, &want);
}

/// What cannot print from the card is refused in the printer's words, and nothing moves.
#[test]
fn what_cannot_print_from_the_card_is_refused_in_words() {
    let blank = ImageCard::new(vec![0; 8 << 20]);
    let cases: [(&str, Option<ImageCard>, &str); 4] = [
        ("photo.jpg", Some(card()), "neither G-code nor STL"),
        ("nothing.gcode", Some(card()), "no such file"),
        (GCODE, Some(blank), "not formatted"),
        (GCODE, None, "no SD card"),
    ];
    for (name, card, words) in cases {
        let source = Source::Card { name, detach: false };
        let opts = SimOptions { max_ms: 20_000, ..SimOptions::default() };
        let (e, rep) = simulate_with_card(source, &ENDER3, &opts, card).unwrap_err();
        assert!(e.starts_with("card: ") && e.contains(words), "{name}: {e}");
        assert_eq!(rep.steps, [0; 4], "{name}: no step");
        assert_eq!(rep.device_state, Some(DeviceState::Idle), "{name}");
    }
}

/// The card pulled out in the middle of the print: the job fails in words (the heaters go
/// off with it), having run only part of the file.
#[test]
fn a_card_pulled_out_mid_print_fails_the_job_in_words() {
    let want = streamed();
    let source = Source::Card { name: GCODE, detach: false };
    let card = card().removed_after(400);
    let (e, got) =
        simulate_with_card(source, &ENDER3, &SimOptions::default(), Some(card)).unwrap_err();
    assert!(e.contains("card: the SD card was removed or failed during the print"), "{e}");
    assert_eq!(got.device_state, Some(DeviceState::Failed));
    let (ran, all): (u64, u64) = (got.steps.iter().sum(), want.steps.iter().sum());
    assert!(ran > 0 && ran < all, "{ran} of {all} steps");
}

/// A model's job on the card (`strata upload MODEL`): `embodier_hotend_v2.stl` placed as
/// `strata print` places it, its job file beside the cube's G-code.
fn model_job() -> (Vec<strata::geom::Triangle>, strata::protocol::JobSpec, Vec<u8>) {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/models/");
    let m = strata_host::model::load(&path.join("embodier_hotend_v2.stl")).unwrap();
    let tris = m.placed_sorted(&ENDER3).unwrap();
    let job = strata_testkit::drive::job_spec(&tris);
    let file = strata_host::job_file::encode(&job, &tris).unwrap();
    (tris, job, file)
}

const JOB: &str = "embodier_hotend_v2.sjob";

fn card_with_job(file: &[u8]) -> ImageCard {
    let files: [(&str, &[u8]); 1] = [(JOB, file)];
    ImageCard::new(strata_testkit::card::image(fatfs::FatType::Fat16, 32, &files, false))
}

/// The job file prints from the card step for step as the model streamed (every layer's
/// hash, the job report, every step edge), with its host there to the end or gone 5 s after
/// the start.
#[test]
fn a_models_job_prints_from_the_card_as_it_does_streamed() {
    let (tris, job, file) = model_job();
    let want = simulate_source(Source::Model(&tris, job), &ENDER3, &SimOptions::default()).unwrap();
    let source = Source::Card { name: JOB, detach: false };
    let got =
        simulate_with_card(source, &ENDER3, &SimOptions::default(), Some(card_with_job(&file)))
            .unwrap_or_else(|(e, _)| panic!("{e}"));
    assert_eq!(got.device_triangles as usize, tris.len(), "triangles taken");
    assert_same_motion("the job from the card", &got, &want);
    assert!(want.layer_hashes.len() > 30, "{} layers", want.layer_hashes.len());
    assert_eq!(got.layer_hashes, want.layer_hashes, "every layer's hash");
    assert_eq!(got.job_report, want.job_report, "the job report");
    let records = file.len().div_ceil(strata::protocol::MAX_PAYLOAD);
    eprintln!(
        "{JOB}: {} triangles, {} bytes (>= {records} records), {} layers as streamed",
        tris.len(),
        file.len(),
        got.layer_hashes.len()
    );
    let opts = SimOptions {
        faults: Faults { cut_at_ms: Some(5_000), ..Faults::default() },
        device_outlives_host: true,
        ..SimOptions::default()
    };
    let (e, gone) =
        simulate_with_card(source, &ENDER3, &opts, Some(card_with_job(&file))).unwrap_err();
    assert!(e.contains("link dead"), "{e}");
    assert_same_motion("host gone", &gone, &want);
    assert!(gone.parked_ms.is_none(), "a job from the card does not park");
}

/// A job file damaged on the card (a flipped byte in a triangle batch, or cut short before the
/// model's end) fails the job in words once it reaches the damage; the records before it ran.
#[test]
fn a_damaged_job_file_fails_in_words_where_the_damage_is() {
    let (tris, job, file) = model_job();
    let want = simulate_source(Source::Model(&tris, job), &ENDER3, &SimOptions::default()).unwrap();
    let mut flipped = file.clone();
    flipped[file.len() * 2 / 3] ^= 0x10;
    let cut = &file[..file.len() * 2 / 3];
    let mut other_version = file.clone();
    other_version[7] ^= 0x0f;
    for (what, bytes, runs) in
        [("flipped", &flipped[..], true), ("cut", cut, true), ("version", &other_version, false)]
    {
        let source = Source::Card { name: JOB, detach: false };
        let opts = SimOptions { max_ms: 3_600_000, ..SimOptions::default() };
        let (e, got) =
            simulate_with_card(source, &ENDER3, &opts, Some(card_with_job(bytes))).unwrap_err();
        assert!(e.contains("the job file is damaged or from another version"), "{what}: {e}");
        let (ran, all): (u64, u64) = (got.steps.iter().sum(), want.steps.iter().sum());
        if runs {
            assert_eq!(got.device_state, Some(DeviceState::Failed), "{what}");
            assert!(ran > 0 && ran < all, "{what}: {ran} of {all} steps");
            let seen = got.layer_hashes.len();
            assert_eq!(got.layer_hashes[..seen], want.layer_hashes[..seen], "{what}");
        } else {
            assert_eq!(got.device_state, Some(DeviceState::Idle), "{what}: refused");
            assert_eq!(ran, 0, "{what}");
        }
    }
}

/// Another host opens its own session in the middle of the job from the card (it finds the
/// printer busy): the link's receive queue is emptied under the record waiting there, which is
/// read again (its batch resumes where it stopped), and the print is the streamed one.
#[test]
fn a_new_host_mid_job_loses_no_record_of_a_job_from_the_card() {
    let (tris, job, file) = model_job();
    let want = simulate_source(Source::Model(&tris, job), &ENDER3, &SimOptions::default()).unwrap();
    for at_ms in [2_000, 9_000, 30_000, 61_000] {
        let opts = SimOptions {
            new_host_at_ms: Some(at_ms),
            device_outlives_host: true,
            ..SimOptions::default()
        };
        let source = Source::Card { name: JOB, detach: false };
        let (e, got) =
            simulate_with_card(source, &ENDER3, &opts, Some(card_with_job(&file))).unwrap_err();
        assert!(e.contains("the printer is busy"), "{at_ms} ms: {e}");
        let what = format!("a new host at {at_ms} ms");
        assert_eq!(got.device_triangles as usize, tris.len(), "{what}: triangles taken");
        assert_same_motion(&what, &got, &want);
    }
}

/// An STL copied to the card: the printer places it and sorts it on the card (runs and a
/// merge), writes its job (default settings) and prints it step for step as the host's
/// placement streamed, its host gone a minute after the start. What cannot be sorted is
/// refused in words, nothing moving.
#[test]
fn an_stl_on_the_card_prints_as_the_host_places_and_streams_it() {
    for (name, fat, partition) in [
        ("xyz_20mm_cube.stl", fatfs::FatType::Fat32, true),
        ("embodier_LM8UU_8p2pi.stl", fatfs::FatType::Fat16, false),
    ] {
        let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/models").join(name);
        let stl = std::fs::read(&path).unwrap();
        let tris = strata_host::model::load(&path).unwrap().placed_sorted(&ENDER3).unwrap();
        let job = strata_testkit::drive::job_spec(&tris);
        let want =
            simulate_source(Source::Model(&tris, job), &ENDER3, &SimOptions::default()).unwrap();
        let files: [(&str, &[u8]); 1] = [(name, &stl)];
        let card = ImageCard::new(strata_testkit::card::image(fat, 64, &files, partition));
        let opts = SimOptions {
            faults: Faults { cut_at_ms: Some(60_000), ..Faults::default() },
            device_outlives_host: true,
            ..SimOptions::default()
        };
        let source = Source::Card { name, detach: false };
        let (e, got) = simulate_with_card(source, &ENDER3, &opts, Some(card)).unwrap_err();
        assert!(e.contains("link dead"), "{name}: {e}");
        assert_eq!(got.device_triangles as usize, tris.len(), "{name}: triangles taken");
        assert_same_motion(name, &got, &want);
        let seen = got.layer_hashes.len();
        assert!(seen > 0, "{name}: the host saw layers before it went");
        assert_eq!(got.layer_hashes[..seen], want.layer_hashes[..seen], "{name}");
        eprintln!(
            "{name}: {} triangles sorted on the card, {} layers as streamed",
            tris.len(),
            want.layers
        );
    }
}

/// A binary STL of a prism of `sides` sides around (110, 110) mm, radius 30 mm, 0.8 mm tall:
/// each side two triangles that cross every plane, the caps fans that cross none.
fn prism_stl(sides: u32) -> Vec<u8> {
    let corner = |k: u32| {
        let a = std::f32::consts::TAU * k as f32 / sides as f32;
        (110.0 + 30.0 * a.cos(), 110.0 + 30.0 * a.sin())
    };
    let mut tris = Vec::new();
    for k in 0..sides {
        let ((x0, y0), (x1, y1)) = (corner(k), corner(k + 1));
        tris.push([[x0, y0, 0.0], [x1, y1, 0.0], [x1, y1, 0.8]]);
        tris.push([[x0, y0, 0.0], [x1, y1, 0.8], [x0, y0, 0.8]]);
        tris.push([[110.0, 110.0, 0.0], [x1, y1, 0.0], [x0, y0, 0.0]]);
        tris.push([[110.0, 110.0, 0.8], [x0, y0, 0.8], [x1, y1, 0.8]]);
    }
    let mut b = vec![0u8; 80];
    b.extend_from_slice(&(tris.len() as u32).to_le_bytes());
    for t in tris {
        b.extend_from_slice(&[0u8; 12]);
        for c in t.iter().flatten() {
            b.extend_from_slice(&c.to_le_bytes());
        }
        b.extend_from_slice(&[0u8; 2]);
    }
    b
}

/// An STL whose layers cross more triangles than the printer's slicer holds is refused before
/// it prints (counted as the card's merge gives its triangles), in words that name the
/// resource and `strata upload`; one of just as many as the slicer holds prints as streamed.
/// The oracle: a prism of `sides` sides crosses `2 * sides` triangles in each layer, and
/// cuts as many segments.
#[test]
fn an_stl_beyond_the_slicer_is_refused_before_it_prints() {
    // Each side cuts each plane in two segments: the contour points bound them too.
    let caps = strata_host::simjob::SimPrinter::CAPACITIES;
    let holds = caps.active_triangles.min(caps.contour_points);
    for (sides, fits) in [(holds / 2, true), (holds / 2 + 1, false)] {
        let name = "prism.stl";
        let stl = prism_stl(sides);
        let files: [(&str, &[u8]); 1] = [(name, &stl)];
        let card =
            ImageCard::new(strata_testkit::card::image(fatfs::FatType::Fat32, 64, &files, true));
        let source = Source::Card { name, detach: false };
        let got = simulate_with_card(source, &ENDER3, &SimOptions::default(), Some(card));
        let model = strata_host::model::load_bytes(&stl).unwrap();
        let tris = model.placed_sorted(&ENDER3).unwrap();
        let job = strata_testkit::drive::job_spec(&tris);
        let config = strata::slice::SliceConfig::new(&job.settings, job.model_height_um).unwrap();
        let needs = strata::slice::peak_needs(&tris, &config).unwrap();
        assert_eq!(needs.active_triangles, 2 * sides, "{sides} sides: the oracle");
        if fits {
            let got = got.unwrap_or_else(|(e, _)| panic!("{sides} sides: {e}"));
            let want = simulate_source(Source::Model(&tris, job), &ENDER3, &SimOptions::default())
                .unwrap();
            assert_same_motion(name, &got, &want);
            assert_eq!(got.layer_hashes, want.layer_hashes, "{sides} sides");
        } else {
            let (e, rep) = got.unwrap_err();
            assert!(e.contains("active triangles") && e.contains("strata upload"), "{e}");
            assert_eq!(rep.steps, [0; 4], "{sides} sides: no step");
            assert_eq!(rep.device_state, Some(DeviceState::Idle));
        }
    }
}

/// An STL that cannot print from the card is refused in words before anything moves: wider
/// than the bed, a corner that is not a number, ASCII, and a card without room for its sort.
#[test]
fn an_stl_that_cannot_print_from_the_card_is_refused_in_words() {
    let mut wide = vec![0u8; 80];
    wide.extend_from_slice(&1u32.to_le_bytes());
    wide.extend_from_slice(&[0u8; 12]);
    for v in [-150.0f32, 0.0, 0.0, 150.0, 0.0, 0.0, 0.0, 10.0, 1.0] {
        wide.extend_from_slice(&v.to_le_bytes());
    }
    wide.extend_from_slice(&[0u8; 2]);
    // A corner that is not a number.
    let mut nan = wide.clone();
    nan[84 + 12..84 + 16].copy_from_slice(&f32::NAN.to_le_bytes());
    let text = b"solid x\nfacet normal 0 0 1\nouter loop\nvertex 1 2 3\n".repeat(3);
    for (name, stl, words) in [
        ("wide.stl", wide, "larger than the bed"),
        ("nan.stl", nan, "cannot be read"),
        ("text.stl", text, "the STL is ASCII"),
    ] {
        let files: [(&str, &[u8]); 1] = [(name, &stl)];
        let card =
            ImageCard::new(strata_testkit::card::image(fatfs::FatType::Fat16, 32, &files, false));
        let opts = SimOptions { max_ms: 20_000, ..SimOptions::default() };
        let (e, rep) =
            simulate_with_card(Source::Card { name, detach: false }, &ENDER3, &opts, Some(card))
                .unwrap_err();
        assert!(e.starts_with("card: ") && e.contains(words), "{name}: {e}");
        assert_eq!(rep.steps, [0; 4], "{name}: no step");
        assert_eq!(rep.device_state, Some(DeviceState::Idle), "{name}");
    }
    // A card with room for the cube but not for its sort's runs (40 B a triangle).
    let name = "xyz_20mm_cube.stl";
    let stl = std::fs::read(strata_testkit::models::dir().join(name)).unwrap();
    let cube_only = strata_testkit::card::image(fatfs::FatType::Fat16, 32, &[(name, &stl)], false);
    let free = {
        let mut vol = std::io::Cursor::new(cube_only);
        let fs = fatfs::FileSystem::new(&mut vol, fatfs::FsOptions::new()).unwrap();
        let stats = fs.stats().unwrap();
        u64::from(stats.free_clusters()) * u64::from(stats.cluster_size())
    };
    let runs_bytes = (stl.len() as u64 - 84) / 50 * 40;
    let filler = vec![0u8; (free - runs_bytes / 2) as usize];
    let files: [(&str, &[u8]); 2] = [(name, &stl), ("filler.bin", &filler)];
    let card =
        ImageCard::new(strata_testkit::card::image(fatfs::FatType::Fat16, 32, &files, false));
    let (e, rep) = simulate_with_card(
        Source::Card { name, detach: false },
        &ENDER3,
        &SimOptions::default(),
        Some(card),
    )
    .unwrap_err();
    assert!(e.contains("the SD card is full"), "{e}");
    assert_eq!(rep.steps, [0; 4], "a full card: no step");
}
