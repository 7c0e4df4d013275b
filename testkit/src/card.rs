//! SD card images written by another FAT implementation (the `fatfs` crate), for the card
//! reader's tests and the printer's card jobs.

use std::io::{Cursor, Write};

use strata::card::fat::BLOCK_BYTES;

/// The block where [`partitioned`] puts the volume (1 MiB in, as card formatters do).
pub const PARTITION_START_BLOCK: u32 = 2048;

/// A card of `mb` megabytes formatted by `fatfs` as `fat`, holding `files` (name, bytes).
///
/// Its clusters are 512 bytes, its root also holds a directory `old prints`; with
/// `partition`, the volume sits behind a master boot record ([`partitioned`]) within the same
/// size (a power of two makes an image QEMU's SD card takes).
pub fn image(fat: fatfs::FatType, mb: usize, files: &[(&str, &[u8])], partition: bool) -> Vec<u8> {
    let lead = if partition { PARTITION_START_BLOCK as usize * BLOCK_BYTES } else { 0 };
    let mut vol = Cursor::new(vec![0u8; (mb << 20) - lead]);
    let opts = fatfs::FormatVolumeOptions::new().fat_type(fat).bytes_per_cluster(512);
    fatfs::format_volume(&mut vol, opts).expect("fatfs formats the volume");
    {
        let fs = fatfs::FileSystem::new(&mut vol, fatfs::FsOptions::new()).expect("mounts");
        fs.root_dir().create_dir("old prints").expect("a directory");
        for (name, data) in files {
            let mut f = fs.root_dir().create_file(name).expect("a file");
            f.write_all(data).expect("the file's bytes");
        }
    }
    let vol = vol.into_inner();
    if partition {
        partitioned(vol, fat == fatfs::FatType::Fat32)
    } else {
        vol
    }
}

/// `vol` behind a master boot record whose first partition (FAT32 LBA or FAT16 type) starts
/// at [`PARTITION_START_BLOCK`].
pub fn partitioned(vol: Vec<u8>, fat32: bool) -> Vec<u8> {
    let mut card = vec![0u8; PARTITION_START_BLOCK as usize * BLOCK_BYTES];
    let entry = &mut card[446..462];
    entry[4] = if fat32 { 0x0C } else { 0x06 };
    entry[8..12].copy_from_slice(&PARTITION_START_BLOCK.to_le_bytes());
    entry[12..16].copy_from_slice(&((vol.len() / BLOCK_BYTES) as u32).to_le_bytes());
    card[510] = 0x55;
    card[511] = 0xAA;
    card.extend_from_slice(&vol);
    card
}
