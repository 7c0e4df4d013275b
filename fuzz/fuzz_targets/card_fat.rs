//! Fuzz target for the card's FAT reader. The card is a 4 MiB FAT16 volume (or, with the
//! first input byte odd, 64 MiB FAT32) whose boot sector is a valid template with the next
//! 64 input bytes XORed over its geometry (bytes 11..75) when the first byte's bit 1 is set,
//! and whose every other block is the rest of the input, repeated: directories, long names,
//! FATs and chains are all the fuzzer's. Mount it, list the root directory, open the first
//! entries by name and read every listed file (at most 64 KiB of each of the first 256: a
//! chain that loops within a huge size is read to that size, not detected).
//!
//! With the first byte's bit 2 set, the writer works on it too (its writes kept over the
//! input): the first listed file removed, a new file created, written and closed, the root
//! listed again.
//!
//! Checks: no panic; a listing ends; a file never yields more bytes than its size; reads stay
//! within their block.
#![no_main]

use libfuzzer_sys::fuzz_target;
use std::collections::HashMap;

use strata::card::fat::{BlockRead, BlockWrite, File, Volume, BLOCK_BYTES};
use strata::card::write::WriteBuffers;

struct Card {
    boot: [u8; BLOCK_BYTES],
    rest: Vec<u8>,
    written: HashMap<u32, [u8; BLOCK_BYTES]>,
}

impl BlockWrite for Card {
    fn write(&mut self, block: u32, data: &[u8; BLOCK_BYTES]) -> Result<(), ()> {
        // A bounded card: the writer's blocks up to 64 MiB.
        if self.written.len() > 4096 && !self.written.contains_key(&block) {
            return Err(());
        }
        self.written.insert(block, *data);
        Ok(())
    }
}

impl BlockRead for Card {
    type Error = ();

    fn read(&mut self, block: u32, offset: usize, out: &mut [u8]) -> Result<(), ()> {
        assert!(offset + out.len() <= BLOCK_BYTES, "a read past its block");
        if let Some(b) = self.written.get(&block) {
            out.copy_from_slice(&b[offset..offset + out.len()]);
            return Ok(());
        }
        if block == 0 {
            out.copy_from_slice(&self.boot[offset..offset + out.len()]);
            return Ok(());
        }
        if self.rest.is_empty() {
            return Err(());
        }
        let at = (block as usize - 1) * BLOCK_BYTES + offset;
        for (i, b) in out.iter_mut().enumerate() {
            *b = self.rest[(at + i) % self.rest.len()];
        }
        Ok(())
    }
}

/// A boot sector: jump, 512-byte sectors, one sector per cluster, one reserved sector (32
/// for FAT32), two FATs, 512 root entries (FAT16), the total and FAT
/// sizes, the FAT32 root at cluster 2, the signature.
fn template(fat32: bool) -> [u8; BLOCK_BYTES] {
    let mut b = [0u8; BLOCK_BYTES];
    b[0] = 0xEB;
    b[11..13].copy_from_slice(&512u16.to_le_bytes());
    b[13] = 1;
    let reserved: u16 = if fat32 { 32 } else { 1 };
    b[14..16].copy_from_slice(&reserved.to_le_bytes());
    b[16] = 2;
    if fat32 {
        b[32..36].copy_from_slice(&131_072u32.to_le_bytes());
        b[36..40].copy_from_slice(&1_024u32.to_le_bytes());
        b[44..48].copy_from_slice(&2u32.to_le_bytes());
    } else {
        b[17..19].copy_from_slice(&512u16.to_le_bytes());
        b[19..21].copy_from_slice(&8_192u16.to_le_bytes());
        b[22..24].copy_from_slice(&32u16.to_le_bytes());
    }
    b[510] = 0x55;
    b[511] = 0xAA;
    b
}

/// Bytes read of a file, and files read, at most (a fuzzer's time, not the reader's).
const MOST_BYTES: usize = 64 << 10;
const MOST_FILES: usize = 256;

fuzz_target!(|data: &[u8]| {
    let Some((&mode, data)) = data.split_first() else { return };
    let mut boot = template(mode & 1 != 0);
    let (geometry, rest) = data.split_at(data.len().min(64));
    if mode & 2 != 0 {
        for (b, g) in boot[11..].iter_mut().zip(geometry) {
            *b ^= g;
        }
    }
    let mut card = Card { boot, rest: rest.to_vec(), written: HashMap::new() };
    let Ok(vol) = Volume::mount(&mut card) else { return };
    let mut dir = vol.root();
    let mut entries = 0;
    while let Ok(Some(e)) = dir.next(&vol, &mut card) {
        entries += 1;
        assert!(entries <= 65_536, "a directory of more entries than FAT allows");
        if entries > MOST_FILES {
            continue;
        }
        // The first few by name (each a search from the directory's start), the rest as listed.
        let mut f = File::of(&e);
        if entries <= 16 {
            match vol.open(&mut card, e.name()) {
                Ok(opened) => f = opened,
                Err(_) => continue,
            }
        }
        let mut buf = [0u8; 600];
        let mut total = 0usize;
        while let Ok(n) = f.read(&vol, &mut card, &mut buf) {
            if n == 0 || total > MOST_BYTES {
                break;
            }
            total += n;
        }
        assert!(total <= f.size() as usize);
    }
    // The writer searches the FAT for free clusters: a volume of at most 2^20 of them (a
    // 32 GB card's) keeps an input's time to the fuzzer's, not the writer's, limits.
    if mode & 4 == 0 || vol.clusters() > 1 << 20 {
        return;
    }
    let mut bufs = WriteBuffers::new();
    let mut dir = vol.root();
    if let Ok(Some(first)) = dir.next(&vol, &mut card) {
        let _ = vol.remove(&mut card, &mut bufs, first.name());
    }
    if let Ok(mut w) = vol.create(&mut card, &mut bufs, "fuzzed file.gcode") {
        let body = [b'G'; 1500];
        if w.append(&vol, &mut card, &mut bufs, &body).is_ok() {
            let _ = w.close(&vol, &mut card, &mut bufs);
        }
    }
    let mut dir = vol.root();
    let mut entries = 0;
    while let Ok(Some(_)) = dir.next(&vol, &mut card) {
        entries += 1;
        assert!(entries <= 65_536, "a directory of more entries than FAT allows");
    }
});
