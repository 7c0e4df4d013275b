//! The card's FAT reader against volumes made by another implementation (the `fatfs` crate:
//! formatted, written, fragmented and with files deleted by it): every entry it lists, with
//! the same names, sizes and kinds, and every file's bytes; FAT16 and FAT32, with and without
//! a partition table; unformatted and damaged cards give typed errors, never a hang.

use std::io::{Cursor, Seek, SeekFrom, Write};

use strata::card::fat::{BlockRead, FatError, FatType, Volume, BLOCK_BYTES, NAME_BYTES};

/// A card image in memory, counting its reads.
struct Image {
    bytes: Vec<u8>,
    reads: u64,
}

impl BlockRead for Image {
    type Error = &'static str;

    fn read(&mut self, block: u32, offset: usize, out: &mut [u8]) -> Result<(), Self::Error> {
        assert!(offset + out.len() <= BLOCK_BYTES, "a read past its block");
        self.reads += 1;
        let at = block as usize * BLOCK_BYTES + offset;
        let src = self.bytes.get(at..at + out.len()).ok_or("beyond the card")?;
        out.copy_from_slice(src);
        Ok(())
    }
}

/// The files of the test volume: names (short, long, very long, mixed case), sizes across
/// cluster and block boundaries.
fn files() -> Vec<(String, Vec<u8>)> {
    let body = |n: usize, seed: u8| (0..n).map(|i| (i as u8).wrapping_mul(31) ^ seed).collect();
    vec![
        ("CUBE.STL".into(), body(684, 1)),
        ("xyz_20mm_cube_prusaslicer.gcode".into(), body(70_001, 2)),
        ("empty.gcode".into(), Vec::new()),
        ("a".repeat(NAME_BYTES + 20) + ".gcode", body(513, 3)),
        ("Mixed Case Name.GCODE".into(), body(4096, 4)),
        ("one-block.bin".into(), body(512, 5)),
    ]
}

/// A volume of `mb` megabytes made by `fatfs` (`fat`), its files written in interleaved
/// slices (so that their cluster chains are fragmented), one file deleted, one directory;
/// with `partition`, behind a master boot record at block 2048.
fn volume(fat: fatfs::FatType, mb: usize, cluster: u32, partition: bool) -> Vec<u8> {
    let mut vol = Cursor::new(vec![0u8; mb << 20]);
    let opts = fatfs::FormatVolumeOptions::new().fat_type(fat).bytes_per_cluster(cluster);
    fatfs::format_volume(&mut vol, opts).unwrap();
    {
        let fs = fatfs::FileSystem::new(&mut vol, fatfs::FsOptions::new()).unwrap();
        let root = fs.root_dir();
        root.create_dir("models").unwrap();
        let mut doomed = root.create_file("deleted.gcode").unwrap();
        doomed.write_all(&[7; 3000]).unwrap();
        drop(doomed);
        let files = files();
        let mut handles: Vec<_> =
            files.iter().map(|(name, _)| root.create_file(name).unwrap()).collect();
        for slice in 0..8 {
            for ((_, data), f) in files.iter().zip(&mut handles) {
                let per = data.len().div_ceil(8);
                let part =
                    &data[(slice * per).min(data.len())..((slice + 1) * per).min(data.len())];
                f.write_all(part).unwrap();
            }
        }
        drop(handles);
        root.remove("deleted.gcode").unwrap();
    }
    let vol = vol.into_inner();
    if !partition {
        return vol;
    }
    strata_testkit::card::partitioned(vol, fat == fatfs::FatType::Fat32)
}

/// What `fatfs` lists in the root directory: name, size, directory.
fn listing(image: &[u8], partition: bool) -> Vec<(String, u32, bool)> {
    let mut c = Cursor::new(image.to_vec());
    if partition {
        c.seek(SeekFrom::Start(2048 * BLOCK_BYTES as u64)).unwrap();
        let rest = c.get_ref()[2048 * BLOCK_BYTES..].to_vec();
        c = Cursor::new(rest);
    }
    let fs = fatfs::FileSystem::new(c, fatfs::FsOptions::new()).unwrap();
    let mut out: Vec<_> = fs
        .root_dir()
        .iter()
        .map(|e| e.unwrap())
        .filter(|e| e.file_name() != "." && e.file_name() != "..")
        .map(|e| (e.file_name(), e.len() as u32, e.is_dir()))
        .collect();
    out.sort();
    out
}

fn check(fat: fatfs::FatType, mb: usize, cluster: u32, partition: bool, want: FatType) {
    let what = format!("{fat:?} {mb} MB, {cluster} B clusters, partition {partition}");
    let bytes = volume(fat, mb, cluster, partition);
    let theirs = listing(&bytes, partition);
    let mut card = Image { bytes, reads: 0 };
    let vol = Volume::mount(&mut card).unwrap_or_else(|e| panic!("{what}: {e}"));
    assert_eq!(vol.fat_type, want, "{what}");
    // The listing: the same entries, names cut at NAME_BYTES.
    let mut ours = Vec::new();
    let mut dir = vol.root();
    while let Some(e) = dir.next(&vol, &mut card).unwrap() {
        ours.push((e.name().to_string(), e.size, e.is_dir, e.name_cut));
    }
    ours.sort();
    assert_eq!(ours.len(), theirs.len(), "{what}: {ours:?} vs {theirs:?}");
    for ((name, size, is_dir, cut), (t_name, t_size, t_dir)) in ours.iter().zip(&theirs) {
        let t_cut = t_name.len() > NAME_BYTES;
        assert_eq!(name.as_str(), &t_name[..t_name.len().min(NAME_BYTES)], "{what}");
        assert_eq!((*size, *is_dir, *cut), (*t_size, *t_dir, t_cut), "{what}: {t_name}");
    }
    // Every file's bytes, by every read size (1 byte to more than a block).
    for (name, data) in files().iter().filter(|(n, _)| n.len() <= NAME_BYTES) {
        for chunk in [1usize, 7, 96, 512, 1000] {
            let mut f = vol.open(&mut card, name).unwrap_or_else(|e| panic!("{what}: {name}: {e}"));
            assert_eq!(f.size() as usize, data.len());
            let mut got = Vec::new();
            let mut buf = vec![0u8; chunk];
            loop {
                let n = f.read(&vol, &mut card, &mut buf).unwrap();
                if n == 0 {
                    break;
                }
                got.extend_from_slice(&buf[..n]);
            }
            assert!(got == *data, "{what}: {name} read {chunk} bytes at a time");
        }
    }
    // Names in any case, 8.3 names too.
    assert!(vol.open(&mut card, "cube.stl").is_ok());
    assert!(vol.open(&mut card, "MIXED CASE NAME.gcode").is_ok());
    assert_eq!(vol.open(&mut card, "deleted.gcode").unwrap_err(), FatError::NotFound);
    assert_eq!(vol.open(&mut card, "models").unwrap_err(), FatError::IsDirectory);
}

#[test]
fn fat16_volumes_read_as_fatfs_wrote_them() {
    check(fatfs::FatType::Fat16, 32, 2048, false, FatType::Fat16);
    check(fatfs::FatType::Fat16, 32, 4096, true, FatType::Fat16);
}

#[test]
fn fat32_volumes_read_as_fatfs_wrote_them() {
    check(fatfs::FatType::Fat32, 40, 512, false, FatType::Fat32);
    check(fatfs::FatType::Fat32, 40, 512, true, FatType::Fat32);
}

#[test]
fn an_unformatted_card_is_said_so() {
    let mut blank = Image { bytes: vec![0u8; 1 << 20], reads: 0 };
    assert_eq!(Volume::mount(&mut blank).unwrap_err(), FatError::NoVolume);
    let mut ones = Image { bytes: vec![0xFF; 1 << 20], reads: 0 };
    assert_eq!(Volume::mount(&mut ones).unwrap_err(), FatError::NoVolume);
    let mut short = Image { bytes: vec![0u8; 100], reads: 0 };
    assert_eq!(Volume::mount(&mut short).unwrap_err(), FatError::Device("beyond the card"));
}

/// A FAT whose chain points outside the volume, at a reserved cluster, or ends before the
/// file does: the reader stops with `Corrupt`. A chain that loops is read to the file's size
/// and no further (a loop within the size is not detected: that would take a second pass
/// over the chain).
#[test]
fn a_damaged_fat_gives_corrupt_never_a_hang() {
    let bytes = volume(fatfs::FatType::Fat32, 40, 512, false);
    let mut card = Image { bytes, reads: 0 };
    let vol = Volume::mount(&mut card).unwrap();
    let name = "xyz_20mm_cube_prusaslicer.gcode";
    let first = {
        let mut dir = vol.root();
        std::iter::from_fn(|| dir.next(&vol, &mut card).unwrap())
            .find(|e| e.name() == name)
            .unwrap()
            .cluster
    };
    // The FAT starts after the reserved blocks (boot sector bytes 14..16).
    let reserved = u16::from_le_bytes([card.bytes[14], card.bytes[15]]) as usize;
    let fat_entry = |c: u32| reserved * BLOCK_BYTES + c as usize * 4;
    for bad in [first, 0x0FFF_FF00, 1, 0x0FFF_FFFF] {
        let mut damaged = Image { bytes: card.bytes.clone(), reads: 0 };
        let at = fat_entry(first);
        damaged.bytes[at..at + 4].copy_from_slice(&bad.to_le_bytes());
        let mut f = vol.open(&mut damaged, name).unwrap();
        let mut buf = [0u8; 4096];
        let end = loop {
            match f.read(&vol, &mut damaged, &mut buf) {
                Ok(0) => break Ok(f.position()),
                Ok(_) => {}
                Err(e) => break Err(e),
            }
        };
        if bad == first {
            assert_eq!(end, Ok(70_001), "a loop is read to the file's size");
        } else {
            assert!(matches!(end, Err(FatError::Corrupt { .. })), "{bad:#x}: {end:?}");
        }
        assert!(damaged.reads < 10_000, "{bad:#x}: {} reads", damaged.reads);
    }
}

/// Reading a file costs one device read per block part (sequential parts of a block are
/// what a card driver streams in one transfer) and one per cluster for the chain.
#[test]
fn a_file_reads_with_a_read_per_block() {
    let bytes = volume(fatfs::FatType::Fat16, 32, 2048, false);
    let mut card = Image { bytes, reads: 0 };
    let vol = Volume::mount(&mut card).unwrap();
    let mut f = vol.open(&mut card, "xyz_20mm_cube_prusaslicer.gcode").unwrap();
    card.reads = 0;
    let mut buf = [0u8; 512];
    while f.read(&vol, &mut card, &mut buf).unwrap() > 0 {}
    let blocks = 70_001u64.div_ceil(512);
    let clusters = 70_001u64.div_ceil(2048);
    // Fragmented: a 512-byte read spans two blocks at most.
    assert!(card.reads <= 2 * blocks + clusters, "{} reads", card.reads);
}
