//! An SD card in SPI mode, read with no block buffer.
//!
//! Start-up is CMD0, CMD8, ACMD41, CMD58 and CMD16; block reads (CMD17) stream each block
//! through and keep only the part asked for, so no 512-byte buffer is held (see
//! [`super::fat`]); block writes (CMD24) take a whole block from the caller. The board provides the bus ([`SpiLink`]: one byte each way, the chip select). Every wait
//! is a bounded number of bytes (the card answers within [`RESPONSE_BYTES`], sends a block
//! within [`TOKEN_BYTES`], leaves its idle state within [`INIT_TRIES`] ACMD41s): a card
//! that does not answer gives a typed error, never a hang. Commands go without CRC (SPI
//! mode ignores it) except CMD0 and CMD8, which carry their fixed ones.

use core::fmt;

use super::fat::{BlockRead, BlockWrite, BLOCK_BYTES};

/// Bytes within which a command's response (R1) comes (the specification's NCR is 1 to 8).
pub const RESPONSE_BYTES: usize = 16;
/// Bytes within which a block's data token comes (100 ms at 400 kHz is 5,000).
pub const TOKEN_BYTES: usize = 65_536;
/// ACMD41s a card may take to leave its idle state (about a second on a real card).
pub const INIT_TRIES: usize = 10_000;
/// Clock bytes with the card released before the first command (at least 74 clocks).
const WAKE_BYTES: usize = 10;
/// R1 bits: idle, illegal command.
const R1_IDLE: u8 = 0x01;
const R1_ILLEGAL: u8 = 0x04;
/// The token that starts a block's data.
const DATA_TOKEN: u8 = 0xFE;
/// A data response's status bits (`xxx0sss1`), and the status of accepted data.
const DATA_RESPONSE_MASK: u8 = 0x1F;
const DATA_ACCEPTED: u8 = 0x05;
/// Bytes within which a card finishes writing a block (it holds the line low meanwhile; 250
/// ms at 25 MHz is about 780,000).
pub const BUSY_BYTES: usize = 1 << 20;

/// The card's bus: SPI mode 0, 8-bit frames, and its chip select.
pub trait SpiLink {
    /// Sends `out` and returns the byte the card sent meanwhile.
    fn transfer(&mut self, out: u8) -> u8;
    /// Selects the card (chip select low) or releases it.
    fn select(&mut self, selected: bool);
}

/// Why the card could not be used.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SdError {
    /// Nothing answers: no card in the slot.
    NoCard,
    /// The card refused a start-up command (`r1` its answer): not a usable SD card.
    Refused {
        /// The command.
        cmd: u8,
        /// The card's answer.
        r1: u8,
    },
    /// The card stayed idle through [`INIT_TRIES`] ACMD41s.
    StaysIdle,
    /// The card did not answer command `cmd` within [`RESPONSE_BYTES`].
    NoResponse {
        /// The command.
        cmd: u8,
    },
    /// A block read gave an error token (or none within [`TOKEN_BYTES`]: 0xFF).
    ReadToken {
        /// The token.
        token: u8,
    },
    /// A read or write before start-up succeeded.
    NotStarted,
    /// The card did not take a block's data (`response` its data response: CRC or write
    /// error), or gave none.
    WriteRefused {
        /// The data response.
        response: u8,
    },
    /// The card stayed busy writing a block beyond [`BUSY_BYTES`].
    StaysBusy,
}

impl fmt::Display for SdError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::NoCard => write!(f, "no card in the slot"),
            Self::Refused { cmd, r1 } => {
                write!(f, "the card refused CMD{cmd} (R1 {r1:#04x}): not a usable SD card")
            }
            Self::StaysIdle => write!(f, "the card did not finish starting up"),
            Self::NoResponse { cmd } => write!(f, "the card did not answer CMD{cmd}"),
            Self::ReadToken { token } => {
                write!(f, "the card failed a block read (token {token:#04x})")
            }
            Self::NotStarted => write!(f, "the card was not started"),
            Self::WriteRefused { response } => {
                write!(f, "the card refused a block write (response {response:#04x})")
            }
            Self::StaysBusy => write!(f, "the card stayed busy after a block write"),
        }
    }
}

/// An SD card on an SPI bus.
#[derive(Debug)]
pub struct SdCard<S> {
    spi: S,
    /// Started (CMD0 to CMD16 done).
    started: bool,
    /// SDHC/SDXC: commands address blocks, not bytes.
    block_addressing: bool,
}

impl<S: SpiLink> SdCard<S> {
    /// A card on `spi`, not started.
    pub const fn new(spi: S) -> Self {
        Self { spi, started: false, block_addressing: false }
    }

    /// The bus back.
    pub fn release(self) -> S {
        self.spi
    }

    /// SDHC/SDXC (block addressing), once started.
    pub fn is_high_capacity(&self) -> bool {
        self.block_addressing
    }

    /// Starts the card: SPI mode, its voltage checked, out of idle, its addressing known.
    pub fn start(&mut self) -> Result<(), SdError> {
        self.started = false;
        self.spi.select(false);
        for _ in 0..WAKE_BYTES {
            self.spi.transfer(0xFF);
        }
        let r = self.start_selected();
        self.release_bus();
        r
    }

    fn start_selected(&mut self) -> Result<(), SdError> {
        // CMD0: to SPI mode, idle.
        match self.command(0, 0) {
            Err(SdError::NoResponse { .. }) => return Err(SdError::NoCard),
            Err(e) => return Err(e),
            Ok(R1_IDLE) => {}
            Ok(r1) => return Err(SdError::Refused { cmd: 0, r1 }),
        }
        // CMD8: 2.7-3.6 V, check pattern 0xAA; an old card calls it illegal.
        let r1 = self.command(8, 0x1AA)?;
        let v2 = r1 & R1_ILLEGAL == 0;
        if v2 {
            let mut r7 = [0u8; 4];
            for b in &mut r7 {
                *b = self.spi.transfer(0xFF);
            }
            if r7[2] & 0x0F != 0x01 || r7[3] != 0xAA {
                return Err(SdError::Refused { cmd: 8, r1: r7[3] });
            }
        }
        // ACMD41 (host supports high capacity on a v2 card) until the card leaves idle.
        let hcs = if v2 { 1 << 30 } else { 0 };
        let mut tries = 0;
        loop {
            self.command(55, 0)?;
            match self.command(41, hcs)? {
                0 => break,
                R1_IDLE if tries < INIT_TRIES => tries += 1,
                R1_IDLE => return Err(SdError::StaysIdle),
                r1 => return Err(SdError::Refused { cmd: 41, r1 }),
            }
        }
        // CMD58: the OCR's CCS bit says block addressing.
        self.block_addressing = false;
        if v2 {
            // (QEMU's card answers CMD58 with the idle bit set even after start-up.)
            let r1 = self.command(58, 0)?;
            if r1 & !R1_IDLE != 0 {
                return Err(SdError::Refused { cmd: 58, r1 });
            }
            let ocr0 = self.spi.transfer(0xFF);
            for _ in 0..3 {
                self.spi.transfer(0xFF);
            }
            self.block_addressing = ocr0 & 0x40 != 0;
        }
        if !self.block_addressing {
            let r1 = self.command(16, BLOCK_BYTES as u32)?;
            if r1 != 0 {
                return Err(SdError::Refused { cmd: 16, r1 });
            }
        }
        self.started = true;
        Ok(())
    }

    /// Sends command `cmd` with `arg` (the card selected) and returns its R1.
    fn command(&mut self, cmd: u8, arg: u32) -> Result<u8, SdError> {
        self.spi.select(true);
        // The card is ready when it sends 0xFF.
        for _ in 0..RESPONSE_BYTES {
            if self.spi.transfer(0xFF) == 0xFF {
                break;
            }
        }
        let crc = match cmd {
            0 => 0x95,
            8 => 0x87,
            _ => 0x01,
        };
        self.spi.transfer(0x40 | cmd);
        for b in arg.to_be_bytes() {
            self.spi.transfer(b);
        }
        self.spi.transfer(crc);
        for _ in 0..RESPONSE_BYTES {
            let r1 = self.spi.transfer(0xFF);
            if r1 & 0x80 == 0 {
                return Ok(r1);
            }
        }
        Err(SdError::NoResponse { cmd })
    }

    /// The card released, and the eight clocks it needs after that.
    fn release_bus(&mut self) {
        self.spi.select(false);
        self.spi.transfer(0xFF);
    }

    /// Block `block`'s bytes from `offset` into `out`: the whole block is clocked through.
    fn read_part(&mut self, block: u32, offset: usize, out: &mut [u8]) -> Result<(), SdError> {
        if !self.started {
            return Err(SdError::NotStarted);
        }
        let addr =
            if self.block_addressing { block } else { block.wrapping_mul(BLOCK_BYTES as u32) };
        let r1 = self.command(17, addr)?;
        if r1 != 0 {
            return Err(SdError::Refused { cmd: 17, r1 });
        }
        let mut token = 0xFF;
        for _ in 0..TOKEN_BYTES {
            token = self.spi.transfer(0xFF);
            if token != 0xFF {
                break;
            }
        }
        if token != DATA_TOKEN {
            return Err(SdError::ReadToken { token });
        }
        let end = offset + out.len();
        for i in 0..BLOCK_BYTES + 2 {
            let b = self.spi.transfer(0xFF);
            if (offset..end).contains(&i) {
                out[i - offset] = b;
            }
        }
        Ok(())
    }
}

impl<S: SpiLink> SdCard<S> {
    /// Writes `data` to block `block` (CMD24) and waits until the card has written it.
    fn write_block(&mut self, block: u32, data: &[u8; BLOCK_BYTES]) -> Result<(), SdError> {
        if !self.started {
            return Err(SdError::NotStarted);
        }
        let addr =
            if self.block_addressing { block } else { block.wrapping_mul(BLOCK_BYTES as u32) };
        let r1 = self.command(24, addr)?;
        if r1 != 0 {
            return Err(SdError::Refused { cmd: 24, r1 });
        }
        // A gap byte, the token, the data and a CRC the card ignores in SPI mode.
        self.spi.transfer(0xFF);
        self.spi.transfer(DATA_TOKEN);
        for &b in data {
            self.spi.transfer(b);
        }
        self.spi.transfer(0xFF);
        self.spi.transfer(0xFF);
        let mut response = 0xFF;
        for _ in 0..RESPONSE_BYTES {
            response = self.spi.transfer(0xFF);
            if response != 0xFF {
                break;
            }
        }
        if response & DATA_RESPONSE_MASK != DATA_ACCEPTED {
            return Err(SdError::WriteRefused { response });
        }
        for _ in 0..BUSY_BYTES {
            if self.spi.transfer(0xFF) == 0xFF {
                return Ok(());
            }
        }
        Err(SdError::StaysBusy)
    }
}

impl<S: SpiLink> BlockWrite for SdCard<S> {
    fn write(&mut self, block: u32, data: &[u8; BLOCK_BYTES]) -> Result<(), SdError> {
        let r = self.write_block(block, data);
        self.release_bus();
        r
    }
}

impl<S: SpiLink> BlockRead for SdCard<S> {
    type Error = SdError;

    fn read(&mut self, block: u32, offset: usize, out: &mut [u8]) -> Result<(), SdError> {
        let r = self.read_part(block, offset, out);
        self.release_bus();
        r
    }
}
