//! Fuzz target for an STL copied to the card: the input is the file (binary STL or not) on a
//! blank 4 MiB FAT16 card, written there through the card's own writer. The printer's sort
//! places it and sorts it on the card (bounds, runs, merge) and its triangles are counted
//! into the slicer's active set as they come.
//!
//! Checks: no panic; the sort ends (in bounded steps) with the model refused in a typed
//! error or every triangle out once, in non-decreasing lowest z, each on the bed.
#![no_main]

use libfuzzer_sys::fuzz_target;
use std::collections::HashMap;

use strata::card::fat::{BlockRead, BlockWrite, Volume, BLOCK_BYTES};
use strata::card::write::WriteBuffers;
use strata::card::zsort::{Phase, StlSort};
use strata::machine::{MachineConfig, PrintSettings};
use strata::slice::{ActiveCount, SliceConfig};

/// A blank card: the boot sector, every other block zero until written.
struct Card {
    boot: [u8; BLOCK_BYTES],
    written: HashMap<u32, [u8; BLOCK_BYTES]>,
}

impl BlockWrite for Card {
    fn write(&mut self, block: u32, data: &[u8; BLOCK_BYTES]) -> Result<(), ()> {
        self.written.insert(block, *data);
        Ok(())
    }
}

impl BlockRead for Card {
    type Error = ();

    fn read(&mut self, block: u32, offset: usize, out: &mut [u8]) -> Result<(), ()> {
        assert!(offset + out.len() <= BLOCK_BYTES, "a read past its block");
        let b = match (block, self.written.get(&block)) {
            (_, Some(b)) => b,
            (0, None) => &self.boot,
            _ => {
                out.fill(0);
                return Ok(());
            }
        };
        out.copy_from_slice(&b[offset..offset + out.len()]);
        Ok(())
    }
}

/// A FAT16 boot sector: 512-byte sectors, one per cluster, one reserved, two FATs of 32
/// sectors, 512 root entries, 8,192 sectors (4 MiB), the signature.
fn boot_sector() -> [u8; BLOCK_BYTES] {
    let mut b = [0u8; BLOCK_BYTES];
    b[0] = 0xEB;
    b[11..13].copy_from_slice(&512u16.to_le_bytes());
    b[13] = 1;
    b[14..16].copy_from_slice(&1u16.to_le_bytes());
    b[16] = 2;
    b[17..19].copy_from_slice(&512u16.to_le_bytes());
    b[19..21].copy_from_slice(&8_192u16.to_le_bytes());
    b[22..24].copy_from_slice(&32u16.to_le_bytes());
    b[510] = 0x55;
    b[511] = 0xAA;
    b
}

/// Sort steps at most: every pass reads 4 blocks a step, and a 64 KiB input is 128 blocks.
const MOST_STEPS: usize = 1_000;

fuzz_target!(|data: &[u8]| {
    let mut card = Card { boot: boot_sector(), written: HashMap::new() };
    let vol = Volume::mount(&mut card).expect("the blank card mounts");
    let mut bufs = WriteBuffers::new();
    let mut w = vol.create(&mut card, &mut bufs, "model.stl").expect("room for the file");
    w.append(&vol, &mut card, &mut bufs, data).expect("room for the file");
    w.close(&vol, &mut card, &mut bufs).expect("the file closes");
    let file = vol.open(&mut card, "model.stl").expect("the file just written");
    let machine = MachineConfig::default();
    let mut sort = Box::new(StlSort::EMPTY);
    sort.begin(vol, file);
    let mut steps = 0;
    loop {
        match sort.step(&mut card, &machine) {
            Ok(Phase::Merge) => break,
            Ok(_) => {}
            Err(_) => return,
        }
        steps += 1;
        assert!(steps <= MOST_STEPS, "the sort's passes do not end");
    }
    let config = SliceConfig::new(&PrintSettings::default(), sort.top_um()).ok();
    ActiveCount::start(sort.spare_words());
    let (mut out, mut last_z) = (0u32, i32::MIN);
    loop {
        let t = match sort.next(&mut card) {
            Ok(Some(t)) => t,
            Ok(None) => break,
            Err(_) => return,
        };
        out += 1;
        assert!(out <= sort.triangles(), "more triangles out than in");
        assert!(t.z_min() >= last_z, "out of order");
        last_z = t.z_min();
        assert!(t.v.iter().all(|p| p.z >= 0), "below the bed");
        if let Some(config) = &config {
            let _ = ActiveCount::resume(sort.spare_words()).push(config, &t);
        }
    }
    assert_eq!(out, sort.triangles(), "every triangle out once");
});
