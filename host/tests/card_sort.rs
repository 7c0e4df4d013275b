//! An STL on the card placed and sorted by the printer in bounded RAM
//! (`strata::card::zsort`): the triangles come out as the host's `placed_sorted` gives them
//! (same placement, same stable zmin order), over runs written to and merged from the card,
//! whose temporary file goes again; models beyond the bed, ASCII and unreadable STLs and
//! models beyond one merge pass are refused with their reason.

use strata::card::fat::{BlockRead, Volume};
use strata::card::zsort::{Phase, SortError, StlSort, MAX_RUNS, RUNS_NAME, RUN_RECORDS};
use strata::geom::Triangle;
use strata::machine::MachineConfig;
use strata::stl::StlErrorKind;
use strata_host::card_image::ImageCard;

const ENDER3: MachineConfig = MachineConfig::ENDER3;

fn model_bytes(name: &str) -> Vec<u8> {
    let path = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/models");
    std::fs::read(path.join(name)).unwrap_or_else(|e| panic!("{name}: {e}"))
}

/// The triangles in order, the model's top (um), the steps taken and the card after it.
type Sorted = (Vec<Triangle>, i32, usize, ImageCard);

/// Sorts `name` from a FAT16 card holding `stl`: the triangles, the model's top, the steps
/// taken, and the card after it.
fn sort_on_card(
    name: &str,
    stl: &[u8],
) -> Result<Sorted, SortError<<ImageCard as BlockRead>::Error>> {
    let files: [(&str, &[u8]); 1] = [(name, stl)];
    let mut card =
        ImageCard::new(strata_testkit::card::image(fatfs::FatType::Fat16, 32, &files, true));
    let volume = Volume::mount(&mut card).unwrap();
    let file = volume.open(&mut card, name).unwrap();
    let mut sort = Box::new(StlSort::EMPTY);
    sort.begin(volume, file);
    let mut steps = 0;
    while sort.step(&mut card, &ENDER3)? != Phase::Merge {
        steps += 1;
    }
    let mut out = Vec::new();
    while let Some(t) = sort.next(&mut card)? {
        out.push(t);
    }
    assert_eq!(out.len() as u32, sort.triangles());
    sort.remove_runs(&mut card)?;
    Ok((out, sort.top_um(), steps, card))
}

#[test]
fn models_sort_on_the_card_as_the_host_sorts_them() {
    for name in ["xyz_20mm_cube.stl", "embodier_bin.stl", "embodier_LM8UU_8p2pi.stl"] {
        let stl = model_bytes(name);
        let path = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("../../shared/models")
            .join(name);
        let want = strata_host::model::load(&path).unwrap().placed_sorted(&ENDER3).unwrap();
        let (got, top, steps, card) = sort_on_card(name, &stl).unwrap();
        assert_eq!(got.len(), want.len(), "{name}: triangles");
        assert!(got == want, "{name}: the host's placement and order");
        assert_eq!(top, want.iter().map(Triangle::z_max).max().unwrap(), "{name}: top");
        // The runs' file is gone: only the model is left (and fatfs reads the volume).
        let bytes = card.bytes();
        let start = strata_testkit::card::PARTITION_START_BLOCK as usize * 512;
        let mut vol = std::io::Cursor::new(bytes[start..].to_vec());
        let fs = fatfs::FileSystem::new(&mut vol, fatfs::FsOptions::new()).unwrap();
        let names: Vec<String> = fs.root_dir().iter().map(|e| e.unwrap().file_name()).collect();
        assert!(!names.iter().any(|n| n == RUNS_NAME), "{name}: {names:?}");
        assert!(names.iter().any(|n| n == name), "{name}: {names:?}");
        let runs = want.len().div_ceil(RUN_RECORDS);
        eprintln!("{name}: {} triangles in {runs} runs, {steps} steps", want.len());
    }
}

/// A binary STL of `n` small triangles at heights going down (the sort has work).
fn binary_stl(n: u32) -> Vec<u8> {
    let mut b = vec![0u8; 80];
    b.extend_from_slice(&n.to_le_bytes());
    for i in 0..n {
        let z = ((n - i) % 997) as f32 * 0.01;
        let x = (i % 100) as f32 * 0.5;
        let corners = [[x, 0.0, z], [x + 0.4, 0.0, z + 0.3], [x, 0.4, z + 0.1]];
        b.extend_from_slice(&[0u8; 12]);
        for c in corners {
            for v in c {
                b.extend_from_slice(&v.to_le_bytes());
            }
        }
        b.extend_from_slice(&[0u8; 2]);
    }
    b
}

/// `StlSort::EMPTY` is all zero bytes: where it lives it is cleared with a memset, not copied
/// from a constant of its size.
#[test]
fn an_empty_sort_is_zero_bytes() {
    let empty = Box::new(StlSort::EMPTY);
    let n = std::mem::size_of::<StlSort>();
    // SAFETY: reads the bytes of a live value of `n` bytes; every field is plain data.
    let bytes = unsafe { std::slice::from_raw_parts(&*empty as *const StlSort as *const u8, n) };
    let nonzero: Vec<usize> = (0..n).filter(|&i| bytes[i] != 0).collect();
    assert!(nonzero.is_empty(), "non-zero bytes at {nonzero:?} of {n}");
}

#[test]
fn what_cannot_be_sorted_is_refused_with_its_reason() {
    // Several runs merged: as the host sorts them.
    let n = (RUN_RECORDS * 7 + 3) as u32;
    let stl = binary_stl(n);
    let (got, _, _, _) = sort_on_card("many.stl", &stl).unwrap();
    let model = strata_host::model::load_bytes(&stl).unwrap();
    assert!(got == model.placed_sorted(&ENDER3).unwrap(), "{n} triangles in 8 runs");
    // Beyond one merge pass.
    let over = (RUN_RECORDS * MAX_RUNS + 1) as u32;
    let e = sort_on_card("huge.stl", &binary_stl(over)).unwrap_err();
    assert!(matches!(e, SortError::TooManyTriangles(t) if t == over), "{e:?}");
    // Beyond the bed: 300 mm along X.
    let mut wide = binary_stl(1);
    wide[84 + 12..84 + 16].copy_from_slice(&(-150.0f32).to_le_bytes());
    wide[84 + 24..84 + 28].copy_from_slice(&150.0f32.to_le_bytes());
    assert!(matches!(sort_on_card("wide.stl", &wide), Err(SortError::Place(_))));
    // ASCII (binary only on the card), and a binary file cut inside a record.
    let text = model_bytes("embodier_hotend_v2.stl");
    let ascii = sort_on_card("text.stl", &text).unwrap_err();
    assert!(matches!(ascii, SortError::Stl(e) if e.kind == StlErrorKind::Ascii), "{ascii:?}");
    let cut = &binary_stl(40)[..84 + 50 * 20 + 7];
    let e = sort_on_card("cut.stl", cut).unwrap_err();
    assert!(matches!(e, SortError::Stl(e) if e.kind == StlErrorKind::TruncatedRecord), "{e:?}");
}
