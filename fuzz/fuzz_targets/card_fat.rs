//! Fuzz target for the card's FAT reader: the input is a card image (blocks past its end
//! fail to read). Mount it, list the root directory, open every entry by name and read it
//! (at most 64 KiB of each of the first 256: a chain that loops within a huge size is
//! read to that size, not detected).
//!
//! Checks: no panic; a listing ends; a file never yields more bytes than its size; reads stay
//! within their block.
#![no_main]

use libfuzzer_sys::fuzz_target;
use strata::card::fat::{BlockRead, File, Volume, BLOCK_BYTES};

struct Image<'a>(&'a [u8]);

impl BlockRead for Image<'_> {
    type Error = ();

    fn read(&mut self, block: u32, offset: usize, out: &mut [u8]) -> Result<(), ()> {
        assert!(offset + out.len() <= BLOCK_BYTES, "a read past its block");
        let at = block as usize * BLOCK_BYTES + offset;
        out.copy_from_slice(self.0.get(at..at + out.len()).ok_or(())?);
        Ok(())
    }
}

/// Bytes read of a file, and files opened, at most (a fuzzer's time, not the reader's).
const MOST_BYTES: usize = 64 << 10;
const MOST_FILES: usize = 256;

fuzz_target!(|data: &[u8]| {
    let mut card = Image(data);
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
});
