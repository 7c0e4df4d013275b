//! The SD card's SPI-mode driver against a scripted card: a standard card starts (SDSC and
//! SDHC addressing), reads block parts exactly and writes whole blocks; a missing, refusing,
//! never-ready or failing card gives its typed error after a bounded number of bytes.

use strata::card::fat::{BlockRead, BlockWrite, BLOCK_BYTES};
use strata::card::sd::{SdCard, SdError, SpiLink, BUSY_BYTES, INIT_TRIES, TOKEN_BYTES};

/// How the scripted card behaves.
#[derive(Clone, Copy)]
struct Script {
    /// Answers at all.
    present: bool,
    /// SDHC (CCS set in the OCR): commands address blocks.
    high_capacity: bool,
    /// ACMD41s before it leaves idle (`usize::MAX`: never).
    idle_for: usize,
    /// The data token of a block read.
    token: u8,
    /// The data response to a block written (0x05: accepted).
    write_response: u8,
    /// Bytes the card stays busy after a block written.
    busy_for: usize,
}

const SD: Script = Script {
    present: true,
    high_capacity: false,
    idle_for: 3,
    token: 0xFE,
    write_response: 0x05,
    busy_for: 40,
};

/// A card of 64 blocks whose byte `i` of block `b` is `b * 7 + i` (mod 256).
struct Card {
    script: Script,
    selected: bool,
    cmd: Vec<u8>,
    out: std::collections::VecDeque<u8>,
    acmd: bool,
    acmd41s: usize,
    bytes: usize,
    reads: Vec<u32>,
    /// A CMD24's block, and its data token and bytes as they come.
    writing: Option<(u32, Vec<u8>)>,
    /// Blocks written, with their bytes.
    written: Vec<(u32, Vec<u8>)>,
    /// Bytes left of busy time (0x00) after a block written.
    busy: usize,
}

impl Card {
    fn new(script: Script) -> Self {
        Self {
            script,
            selected: false,
            cmd: Vec::new(),
            out: Default::default(),
            acmd: false,
            acmd41s: 0,
            bytes: 0,
            reads: Vec::new(),
            writing: None,
            written: Vec::new(),
            busy: 0,
        }
    }

    fn answer(&mut self, cmd: u8, arg: u32) {
        // One byte of NCR, then R1 (and more).
        self.out.push_back(0xFF);
        let acmd = std::mem::take(&mut self.acmd);
        match (cmd, acmd) {
            (0, _) => self.out.push_back(0x01),
            (8, _) => self.out.extend([0x01, 0, 0, 0x01, (arg & 0xFF) as u8]),
            (55, _) => {
                self.acmd = true;
                self.out.push_back(0x01);
            }
            (41, true) => {
                self.acmd41s += 1;
                let ready = self.acmd41s > self.script.idle_for;
                self.out.push_back(if ready { 0x00 } else { 0x01 });
            }
            (58, _) => {
                let ocr0 = if self.script.high_capacity { 0xC0 } else { 0x80 };
                self.out.extend([0x00, ocr0, 0xFF, 0x80, 0x00]);
            }
            (16, _) => self.out.push_back(if arg == 512 { 0 } else { 0x40 }),
            (17, _) => {
                let block = if self.script.high_capacity { arg } else { arg / 512 };
                self.reads.push(block);
                self.out.extend([0x00, 0xFF, 0xFF, self.script.token]);
                if self.script.token == 0xFE {
                    self.out.extend((0..512).map(|i| (block as usize * 7 + i) as u8));
                    self.out.extend([0xAB, 0xCD]);
                }
            }
            (24, _) => {
                let block = if self.script.high_capacity { arg } else { arg / 512 };
                self.out.push_back(0x00);
                self.writing = Some((block, Vec::new()));
            }
            _ => self.out.push_back(0x04),
        }
    }

    /// A byte of a block being written: the token first (bytes before it are gaps), then
    /// 512 bytes and two of CRC; then the data response and the busy time.
    fn take_written(&mut self, b: u8) {
        let Some((block, data)) = &mut self.writing else { return };
        if data.is_empty() && b != 0xFE {
            return;
        }
        data.push(b);
        if data.len() == 1 + 512 + 2 {
            let (block, data) = (*block, data[1..513].to_vec());
            self.writing = None;
            self.out.push_back(self.script.write_response);
            if self.script.write_response & 0x1F == 0x05 {
                self.written.push((block, data));
                self.busy = self.script.busy_for;
            }
        }
    }
}

impl SpiLink for Card {
    fn transfer(&mut self, b: u8) -> u8 {
        self.bytes += 1;
        if !self.selected || !self.script.present {
            return 0xFF;
        }
        if let Some(r) = self.out.pop_front() {
            return r;
        }
        if self.busy > 0 {
            self.busy -= 1;
            return 0x00;
        }
        if self.writing.is_some() {
            self.take_written(b);
            return 0xFF;
        }
        if self.cmd.is_empty() && b & 0xC0 != 0x40 {
            return 0xFF;
        }
        self.cmd.push(b);
        if self.cmd.len() == 6 {
            let c = std::mem::take(&mut self.cmd);
            self.answer(c[0] & 0x3F, u32::from_be_bytes([c[1], c[2], c[3], c[4]]));
        }
        0xFF
    }

    fn select(&mut self, selected: bool) {
        self.selected = selected;
        if !selected {
            self.out.clear();
        }
    }
}

#[test]
fn a_card_starts_and_reads_block_parts() {
    for high_capacity in [false, true] {
        let mut sd = SdCard::new(Card::new(Script { high_capacity, ..SD }));
        sd.start().unwrap();
        assert_eq!(sd.is_high_capacity(), high_capacity);
        for (block, offset, len) in
            [(0u32, 0usize, 512usize), (5, 446, 64), (63, 511, 1), (9, 3, 0)]
        {
            let mut out = vec![0u8; len];
            sd.read(block, offset, &mut out).unwrap();
            let want: Vec<u8> =
                (offset..offset + len).map(|i| (block as usize * 7 + i) as u8).collect();
            assert_eq!(out, want, "block {block} from {offset}");
        }
        assert_eq!(sd.release().reads, [0, 5, 63, 9], "SDHC {high_capacity}: blocks read");
    }
}

#[test]
fn a_card_that_fails_says_how_within_bounded_bytes() {
    let cases = [
        (Script { present: false, ..SD }, SdError::NoCard),
        (Script { idle_for: usize::MAX, ..SD }, SdError::StaysIdle),
    ];
    for (script, want) in cases {
        let mut sd = SdCard::new(Card::new(script));
        assert_eq!(sd.start(), Err(want));
        let bytes = sd.release().bytes;
        assert!(bytes < (INIT_TRIES + 2) * 40, "{want:?}: {bytes} bytes");
    }
    // A read before start-up, an error token, no token at all.
    let mut sd = SdCard::new(Card::new(SD));
    assert_eq!(sd.read(0, 0, &mut [0; 4]), Err(SdError::NotStarted));
    for (token, want) in
        [(0x09, SdError::ReadToken { token: 0x09 }), (0xFF, SdError::ReadToken { token: 0xFF })]
    {
        let mut sd = SdCard::new(Card::new(Script { token, ..SD }));
        sd.start().unwrap();
        assert_eq!(sd.read(1, 0, &mut [0; 4]), Err(want));
        assert!(sd.release().bytes < TOKEN_BYTES + 1_000);
    }
    assert_eq!(BLOCK_BYTES, 512);
}

#[test]
fn a_card_writes_whole_blocks_and_says_when_it_cannot() {
    let data: [u8; BLOCK_BYTES] = core::array::from_fn(|i| (i * 13 + 5) as u8);
    for high_capacity in [false, true] {
        let mut sd = SdCard::new(Card::new(Script { high_capacity, ..SD }));
        assert_eq!(sd.write(3, &data), Err(SdError::NotStarted));
        sd.start().unwrap();
        sd.write(3, &data).unwrap();
        sd.write(60, &[0xA5; BLOCK_BYTES]).unwrap();
        let card = sd.release();
        assert_eq!(
            card.written,
            [(3, data.to_vec()), (60, vec![0xA5; 512])],
            "SDHC {high_capacity}"
        );
    }
    // A CRC error, a write error, a card that stays busy: typed errors, bounded bytes.
    for (script, want) in [
        (Script { write_response: 0x0B, ..SD }, SdError::WriteRefused { response: 0x0B }),
        (Script { write_response: 0x0D, ..SD }, SdError::WriteRefused { response: 0x0D }),
        (Script { busy_for: usize::MAX / 2, ..SD }, SdError::StaysBusy),
    ] {
        let mut sd = SdCard::new(Card::new(script));
        sd.start().unwrap();
        assert_eq!(sd.write(1, &data), Err(want));
        assert!(sd.release().bytes < BUSY_BYTES + 2_000, "{want:?}");
    }
}
