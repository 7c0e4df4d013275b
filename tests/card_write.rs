//! The card's FAT writer against volumes made by another implementation (the `fatfs` crate):
//! files this writer creates, replaces and removes read back through `fatfs` with their
//! names, sizes and bytes, every FAT copy the same, no cluster shared with a file `fatfs`
//! writes afterwards; a full card, a full FAT16 root and names a card cannot hold give typed
//! errors.

use std::io::{Cursor, Read, Write};

use strata::card::fat::{BlockRead, BlockWrite, FatError, Volume, BLOCK_BYTES};
use strata::card::write::WriteBuffers;
use strata_testkit::card::{partitioned, PARTITION_START_BLOCK};

/// A card image in memory.
struct Image {
    bytes: Vec<u8>,
    reads: u64,
    writes: u64,
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

impl BlockWrite for Image {
    fn write(&mut self, block: u32, data: &[u8; BLOCK_BYTES]) -> Result<(), Self::Error> {
        let at = block as usize * BLOCK_BYTES;
        self.writes += 1;
        self.bytes.get_mut(at..at + BLOCK_BYTES).ok_or("beyond the card")?.copy_from_slice(data);
        Ok(())
    }
}

/// Bytes of a test file: a pattern no two files share.
fn body(n: usize, seed: u8) -> Vec<u8> {
    (0..n).map(|i| ((i * 31 + i / 251) as u8) ^ seed).collect()
}

/// A volume `fatfs` formatted and filled: files written interleaved, then some deleted, so
/// that its free clusters are scattered.
fn volume(fat: fatfs::FatType, mb: usize, cluster: u32) -> Vec<u8> {
    let mut vol = Cursor::new(vec![0u8; mb << 20]);
    let opts = fatfs::FormatVolumeOptions::new().fat_type(fat).bytes_per_cluster(cluster);
    fatfs::format_volume(&mut vol, opts).unwrap();
    {
        let fs = fatfs::FileSystem::new(&mut vol, fatfs::FsOptions::new()).unwrap();
        let root = fs.root_dir();
        root.create_dir("old prints").unwrap();
        let names = ["keep.gcode", "gone1.gcode", "replace me.gcode", "gone2.gcode", "KEEP2.STL"];
        let mut files: Vec<_> = names.iter().map(|n| root.create_file(n).unwrap()).collect();
        for slice in 0..6 {
            for (k, f) in files.iter_mut().enumerate() {
                f.write_all(&body(3000 + 700 * k, k as u8 + slice)).unwrap();
            }
        }
        drop(files);
        root.remove("gone1.gcode").unwrap();
        root.remove("gone2.gcode").unwrap();
    }
    vol.into_inner()
}

/// `image`'s volume as `fatfs` sees it.
fn with_fatfs<R>(
    image: &[u8],
    partition: bool,
    f: impl FnOnce(&fatfs::FileSystem<&mut Cursor<Vec<u8>>>) -> R,
) -> R {
    let mut c = Cursor::new(image.to_vec());
    if partition {
        c = Cursor::new(image[PARTITION_START_BLOCK as usize * BLOCK_BYTES..].to_vec());
    }
    let fs = fatfs::FileSystem::new(&mut c, fatfs::FsOptions::new()).unwrap();
    f(&fs)
}

/// Every file in the root, as `fatfs` reads it: name, bytes.
fn files_of(fs: &fatfs::FileSystem<&mut Cursor<Vec<u8>>>) -> Vec<(String, Vec<u8>)> {
    let mut out = Vec::new();
    for e in fs.root_dir().iter().map(|e| e.unwrap()).filter(|e| e.is_file()) {
        let mut bytes = Vec::new();
        e.to_file().read_to_end(&mut bytes).unwrap();
        assert_eq!(bytes.len() as u64, e.len(), "{}", e.file_name());
        out.push((e.file_name(), bytes));
    }
    out.sort();
    out
}

/// The FAT copies of the volume at `start` are byte for byte the same.
fn assert_fat_copies_equal(vol_bytes: &[u8]) {
    let le16 = |at: usize| u16::from_le_bytes([vol_bytes[at], vol_bytes[at + 1]]) as usize;
    let reserved = le16(14);
    let fats = vol_bytes[16] as usize;
    let fat_blocks = match le16(22) {
        0 => u32::from_le_bytes(vol_bytes[36..40].try_into().unwrap()) as usize,
        n => n,
    };
    let fat = |k: usize| {
        let at = (reserved + k * fat_blocks) * BLOCK_BYTES;
        &vol_bytes[at..at + fat_blocks * BLOCK_BYTES]
    };
    assert_eq!(fats, 2);
    assert!(fat(0) == fat(1), "the FAT copies differ");
}

/// Writes `data` as `name` with appends of `chunk` bytes.
fn write_file(card: &mut Image, vol: &Volume, name: &str, data: &[u8], chunk: usize) {
    let mut bufs = WriteBuffers::new();
    let mut w = vol.create(card, &mut bufs, name).unwrap_or_else(|e| panic!("{name}: {e}"));
    for part in data.chunks(chunk) {
        w.append(vol, card, &mut bufs, part).unwrap();
    }
    assert_eq!(w.size() as usize, data.len());
    assert_eq!(w.close(vol, card, &mut bufs).unwrap() as usize, data.len());
}

fn check(fat: fatfs::FatType, mb: usize, cluster: u32, partition: bool) {
    let what = format!("{fat:?} {mb} MB, {cluster} B clusters, partition {partition}");
    let vol_bytes = volume(fat, mb, cluster);
    let bytes =
        if partition { partitioned(vol_bytes, fat == fatfs::FatType::Fat32) } else { vol_bytes };
    let before = with_fatfs(&bytes, partition, files_of);
    let mut card = Image { bytes, reads: 0, writes: 0 };
    let vol = Volume::mount(&mut card).unwrap();
    // New files of every size around blocks and clusters, appended in odd parts; one
    // replacing a file `fatfs` wrote; one removed.
    let c = cluster as usize;
    let mut ours: Vec<(String, Vec<u8>)> = Vec::new();
    for (k, (size, chunk)) in [
        (0, 1),
        (1, 1),
        (511, 7),
        (512, 400),
        (513, 1000),
        (c, 512),
        (3 * c + 5, 333),
        (70_001, 4096),
    ]
    .into_iter()
    .enumerate()
    {
        let name = format!("part {k} of the set.gcode");
        let data = body(size, 0x40 + k as u8);
        write_file(&mut card, &vol, &name, &data, chunk);
        ours.push((name, data));
    }
    let replaced = body(9_999, 0x77);
    write_file(&mut card, &vol, "replace me.gcode", &replaced, 100);
    let mut bufs = WriteBuffers::new();
    vol.remove(&mut card, &mut bufs, "KEEP2.STL").unwrap();
    assert_eq!(vol.remove(&mut card, &mut bufs, "KEEP2.STL"), Err(FatError::NotFound));
    assert_eq!(vol.remove(&mut card, &mut bufs, "old prints"), Err(FatError::IsDirectory));
    // `fatfs` reads every file as written, the others unchanged.
    let mut want: Vec<(String, Vec<u8>)> = before
        .into_iter()
        .filter(|(n, _)| n != "KEEP2.STL" && n != "replace me.gcode")
        .chain(ours.iter().cloned())
        .chain([("replace me.gcode".to_string(), replaced.clone())])
        .collect();
    want.sort();
    let got = with_fatfs(&card.bytes, partition, files_of);
    let names = |v: &[(String, Vec<u8>)]| v.iter().map(|f| f.0.clone()).collect::<Vec<_>>();
    assert_eq!(names(&got), names(&want), "{what}");
    for ((gn, gd), (wn, wd)) in got.iter().zip(&want) {
        assert_eq!(gn, wn, "{what}");
        assert!(gd == wd, "{what}: {gn}: {} bytes read, {} written", gd.len(), wd.len());
    }
    // The 8.3 aliases are distinct.
    let mut shorts: Vec<String> = with_fatfs(&card.bytes, partition, |fs| {
        fs.root_dir().iter().map(|e| e.unwrap().short_file_name()).collect()
    });
    let n = shorts.len();
    shorts.sort();
    shorts.dedup();
    assert_eq!(shorts.len(), n, "{what}: aliases {shorts:?}");
    let start = if partition { PARTITION_START_BLOCK as usize * BLOCK_BYTES } else { 0 };
    assert_fat_copies_equal(&card.bytes[start..]);
    // A file `fatfs` writes now takes none of our clusters: ours read back unchanged.
    let mut after = Cursor::new(card.bytes[start..].to_vec());
    {
        let fs = fatfs::FileSystem::new(&mut after, fatfs::FsOptions::new()).unwrap();
        let mut f = fs.root_dir().create_file("later.bin").unwrap();
        f.write_all(&body(200_000, 0x99)).unwrap();
    }
    let mut after = after.into_inner();
    let mut full = card.bytes[..start].to_vec();
    full.append(&mut after);
    let got = with_fatfs(&full, partition, files_of);
    for (name, data) in &ours {
        let g = got.iter().find(|(n, _)| n == name).unwrap_or_else(|| panic!("{what}: {name}"));
        assert!(g.1 == *data, "{what}: {name} changed by a later fatfs write");
    }
    // And our reader reads them too.
    for (name, data) in &ours {
        let mut f = vol.open(&mut card, name).unwrap();
        let mut got = vec![0u8; data.len() + 1];
        let n = f.read(&vol, &mut card, &mut got).unwrap();
        assert!(n == data.len() && got[..n] == data[..], "{what}: {name}");
    }
}

#[test]
fn fat16_files_written_read_back_through_fatfs() {
    check(fatfs::FatType::Fat16, 32, 2048, false);
    check(fatfs::FatType::Fat16, 32, 4096, true);
}

#[test]
fn fat32_files_written_read_back_through_fatfs() {
    check(fatfs::FatType::Fat32, 40, 512, false);
    check(fatfs::FatType::Fat32, 40, 1024, true);
}

/// A FAT32 root of one cluster grows by a cluster when its entries run out; FAT16's fixed
/// root says it is full.
#[test]
fn a_full_root_grows_or_says_so() {
    for (fat, mb, cluster) in [(fatfs::FatType::Fat32, 40, 512), (fatfs::FatType::Fat16, 16, 512)] {
        let mut vol_bytes = Cursor::new(vec![0u8; mb << 20]);
        let opts = fatfs::FormatVolumeOptions::new().fat_type(fat).bytes_per_cluster(cluster);
        fatfs::format_volume(&mut vol_bytes, opts).unwrap();
        let mut card = Image { bytes: vol_bytes.into_inner(), reads: 0, writes: 0 };
        let vol = Volume::mount(&mut card).unwrap();
        let mut made = 0;
        for k in 0..600 {
            let mut bufs = WriteBuffers::new();
            match vol.create(&mut card, &mut bufs, &format!("f{k}.g")) {
                Ok(w) => {
                    w.close(&vol, &mut card, &mut bufs).unwrap();
                    made += 1;
                }
                Err(FatError::DirectoryFull) if fat == fatfs::FatType::Fat16 => break,
                Err(e) => panic!("{fat:?}: file {k}: {e}"),
            }
        }
        let listed = with_fatfs(&card.bytes, false, |fs| fs.root_dir().iter().count());
        assert_eq!(listed, made, "{fat:?}");
        if fat == fatfs::FatType::Fat16 {
            // 512 root entries, two slots a file (a long name and its alias).
            assert_eq!(made, 256);
        } else {
            assert_eq!(made, 600);
        }
    }
}

/// Appending to a full card gives `Full` (the file's clusters so far stay its own); names a
/// card cannot hold are refused before anything is written.
#[test]
fn a_full_card_and_bad_names_give_typed_errors() {
    let mut vol_bytes = Cursor::new(vec![0u8; 16 << 20]);
    let opts =
        fatfs::FormatVolumeOptions::new().fat_type(fatfs::FatType::Fat16).bytes_per_cluster(4096);
    fatfs::format_volume(&mut vol_bytes, opts).unwrap();
    let mut card = Image { bytes: vol_bytes.into_inner(), reads: 0, writes: 0 };
    let vol = Volume::mount(&mut card).unwrap();
    let mut bufs = WriteBuffers::new();
    let mut w = vol.create(&mut card, &mut bufs, "big.bin").unwrap();
    let block = body(BLOCK_BYTES, 1);
    let mut written = 0usize;
    let e = loop {
        match w.append(&vol, &mut card, &mut bufs, &block) {
            Ok(()) => written += BLOCK_BYTES,
            Err(e) => break e,
        }
        assert!(written <= 16 << 20, "the card never filled");
    };
    assert_eq!(e, FatError::Full);
    assert!(written > 15 << 20, "{written} bytes before full");
    let writes = card.writes;
    for bad in ["", "a/b.gcode", "what?.gcode", "caf\u{e9}.gcode", "dot."] {
        assert_eq!(
            vol.create(&mut card, &mut bufs, bad).unwrap_err(),
            FatError::BadName,
            "{bad:?}"
        );
    }
    assert_eq!(card.writes, writes, "a refused name wrote nothing");
}

/// Removing a file whose chain loops (a damaged FAT) frees the clusters its size takes and
/// stops: no endless walk, no other file touched.
#[test]
fn removing_a_file_whose_chain_loops_stops_at_its_size() {
    let mut vol_bytes = Cursor::new(vec![0u8; 32 << 20]);
    let opts =
        fatfs::FormatVolumeOptions::new().fat_type(fatfs::FatType::Fat16).bytes_per_cluster(2048);
    fatfs::format_volume(&mut vol_bytes, opts).unwrap();
    {
        let fs = fatfs::FileSystem::new(&mut vol_bytes, fatfs::FsOptions::new()).unwrap();
        let root = fs.root_dir();
        root.create_file("loop.gcode").unwrap().write_all(&body(4096, 1)).unwrap();
        root.create_file("other.gcode").unwrap().write_all(&body(5000, 2)).unwrap();
    }
    let mut bytes = vol_bytes.into_inner();
    // loop.gcode has clusters 2 and 3 (the first file on a fresh volume): 3 points back to 2.
    let fat = u16::from_le_bytes([bytes[14], bytes[15]]) as usize * BLOCK_BYTES;
    for copy in 0..2 {
        let fat_blocks = u16::from_le_bytes([bytes[22], bytes[23]]) as usize;
        let at = fat + copy * fat_blocks * BLOCK_BYTES + 3 * 2;
        assert_eq!(
            u16::from_le_bytes([bytes[at], bytes[at + 1]]),
            0xFFFF,
            "cluster 3 ends its chain"
        );
        bytes[at..at + 2].copy_from_slice(&2u16.to_le_bytes());
    }
    let mut card = Image { bytes, reads: 0, writes: 0 };
    let vol = Volume::mount(&mut card).unwrap();
    let mut bufs = WriteBuffers::new();
    let reads = card.reads;
    vol.remove(&mut card, &mut bufs, "loop.gcode").unwrap();
    assert!(card.reads - reads < 100, "{} reads", card.reads - reads);
    assert!(card.writes < 20, "{} block writes", card.writes);
    let got = with_fatfs(&card.bytes, false, files_of);
    assert_eq!(got, [("other.gcode".to_string(), body(5000, 2))]);
}
