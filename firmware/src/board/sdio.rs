//! The Creality 4.2.x boards' microSD slot: the STM32F103's SDIO (D0-D3 PC8-PC11, CK PC12,
//! CMD PD2; card detect PC7, low with a card in, Marlin's `pins_CREALITY_V4.h`), 4-bit bus,
//! polled (no DMA).
//!
//! Start-up follows the SD physical layer's: CMD0, CMD8 (a version 2 card echoes the check
//! pattern), ACMD41 until the card is ready (its OCR says whether it addresses blocks or bytes),
//! CMD2, CMD3 (its relative address), CMD7 (selected), ACMD6 (4-bit bus), CMD16 (512-byte
//! blocks), at 400 kHz until the bus is wide. Blocks are read with CMD17 and written with
//! CMD24; a write waits (CMD13) until the card is back in the transfer state.
//!
//! The data clock is SDIOCLK / (CLKDIV + 2) = 72 / 12 = 6 MHz: 3 MB/s on the 4-bit bus, a FIFO
//! word every 96 CPU cycles, which a polling loop keeps up with even when the step interrupt
//! (a few microseconds) takes the core meanwhile (the 32-word FIFO covers 43 us). The SDIO
//! register bits are RM0008's (section 22.9); every wait is bounded by a count of polls.
//!
//! Not run on a board yet (the QEMU boards have no SDIO): the sequence and registers are the
//! reference manual's and the SD specification's.

use stm32f1xx_hal::pac;
use strata::card::fat::{BlockRead, BlockWrite, BLOCK_BYTES};

/// Why the card did not answer as it should.
#[derive(Debug, Clone, Copy, PartialEq, Eq, defmt::Format)]
pub enum SdioError {
    /// Command `0` got no answer.
    Timeout(u8),
    /// Command `0`'s answer failed its CRC.
    Crc(u8),
    /// Command `0`'s answer (an R1 card status) reports an error: its bits.
    Rejected(u8, u32),
    /// The card did not become ready (ACMD41) in time.
    NotReady,
    /// A data block failed its CRC, timed out, or the FIFO ran over or under.
    Data(u32),
    /// The card stayed busy after a write.
    StaysBusy,
}

impl core::fmt::Display for SdioError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Timeout(c) => write!(f, "CMD{c}: no answer"),
            Self::Crc(c) => write!(f, "CMD{c}: answer CRC"),
            Self::Rejected(c, s) => write!(f, "CMD{c}: card status {s:#010x}"),
            Self::NotReady => f.write_str("the card stays busy at start-up"),
            Self::Data(s) => write!(f, "data transfer failed (SDIO_STA {s:#010x})"),
            Self::StaysBusy => f.write_str("the card stays busy after a write"),
        }
    }
}

// SDIO_STA (and SDIO_ICR at the same positions).
const STA_CCRCFAIL: u32 = 1 << 0;
const STA_DCRCFAIL: u32 = 1 << 1;
const STA_CTIMEOUT: u32 = 1 << 2;
const STA_DTIMEOUT: u32 = 1 << 3;
const STA_TXUNDERR: u32 = 1 << 4;
const STA_RXOVERR: u32 = 1 << 5;
const STA_CMDREND: u32 = 1 << 6;
const STA_CMDSENT: u32 = 1 << 7;
const STA_STBITERR: u32 = 1 << 9;
const STA_DBCKEND: u32 = 1 << 10;
const STA_TXFIFOHE: u32 = 1 << 14;
const STA_RXDAVL: u32 = 1 << 21;
/// Every static flag of SDIO_ICR.
const ICR_ALL: u32 = 0x00C0_07FF;
const STA_DATA_ERRORS: u32 =
    STA_DCRCFAIL | STA_DTIMEOUT | STA_TXUNDERR | STA_RXOVERR | STA_STBITERR;
// SDIO_CMD: WAITRESP (bits 7:6) and CPSMEN.
const CMD_SHORT: u32 = 0b01 << 6;
const CMD_LONG: u32 = 0b11 << 6;
const CMD_CPSMEN: u32 = 1 << 10;
// SDIO_CLKCR.
const CLKCR_CLKEN: u32 = 1 << 8;
const CLKCR_WIDBUS_4: u32 = 0b01 << 11;
/// 72 MHz / (178 + 2) = 400 kHz: the start-up clock.
const CLKDIV_START: u32 = 178;
/// 72 MHz / (10 + 2) = 6 MHz: the data clock (see the module docs).
const CLKDIV_DATA: u32 = 10;
// SDIO_DCTRL: DTEN, DTDIR (card to controller), DBLOCKSIZE = 2^9 bytes.
const DCTRL_DTEN: u32 = 1 << 0;
const DCTRL_DTDIR: u32 = 1 << 1;
const DCTRL_BLOCK_512: u32 = 9 << 4;
/// Data timeout, SDIO_CK cycles: 250 ms at 6 MHz (the SD limits are 100 ms to read a block
/// and 250 ms to write one).
const DATA_TIMEOUT_CK: u32 = 1_500_000;
/// R1 card status bits that report an error (out of range, address, block length, erase,
/// write protect, lock, CRC, illegal command, ECC, controller, general, overrun and others).
const R1_ERRORS: u32 = 0xFDF9_8008;
/// CMD8's argument: 2.7-3.6 V and the check pattern echoed by a version 2 card.
const CMD8_CHECK: u32 = 0x1AA;
/// ACMD41's argument: high capacity supported, 3.2-3.4 V.
const ACMD41_HCS: u32 = 0x4030_0000;
/// OCR bits: the card finished its start-up; it addresses blocks (SDHC/SDXC).
const OCR_READY: u32 = 1 << 31;
const OCR_CCS: u32 = 1 << 30;
/// ACMD41 tries, 1 ms apart: the specification gives a card 1 s to start.
const START_TRIES: u32 = 1000;
/// Status register polls for a command's answer (64 clocks at 400 kHz are 160 us: far more).
const CMD_POLLS: u32 = 200_000;
/// Status register polls for a block's data (the data timeout ends it before).
const DATA_POLLS: u32 = 4_000_000;
/// CMD13 polls for the card to finish programming a block (250 ms and more).
const BUSY_POLLS: u32 = 100_000;
/// The card's state in the R1 status (bits 12:9) once it may take a new command: transfer.
const STATE_TRAN: u32 = 4;
const R1_READY_FOR_DATA: u32 = 1 << 8;
/// Core cycles in a millisecond (72 MHz).
const CYCLES_PER_MS: u32 = 72_000;

/// The SDIO registers (owned by this driver: nothing else on the board uses SDIO).
fn regs() -> &'static pac::sdio::RegisterBlock {
    // SAFETY: the SDIO block is used only here, from thread mode.
    unsafe { &*pac::SDIO::ptr() }
}

/// What a command answers.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Answer {
    None,
    /// 48 bits with a CRC (R1, R6, R7).
    Short,
    /// 48 bits without a valid CRC (R3: the OCR): the controller reports a CRC failure.
    ShortNoCrc,
    /// 136 bits (R2).
    Long,
}

/// Sends command `index` with `arg`; its first response word (0 without one).
fn command(index: u8, arg: u32, answer: Answer) -> Result<u32, SdioError> {
    let s = regs();
    // SAFETY (the `bits` writes here and below): ICR takes any flags to clear, ARG any
    // argument, CMD an index below 64 with the response and enable bits of RM0008.
    s.icr().write(|w| unsafe { w.bits(ICR_ALL) });
    s.arg().write(|w| unsafe { w.bits(arg) });
    let wait = match answer {
        Answer::None => 0,
        Answer::Short | Answer::ShortNoCrc => CMD_SHORT,
        Answer::Long => CMD_LONG,
    };
    s.cmd().write(|w| unsafe { w.bits(u32::from(index) | wait | CMD_CPSMEN) });
    let done = if answer == Answer::None { STA_CMDSENT } else { STA_CMDREND };
    for _ in 0..CMD_POLLS {
        let sta = s.sta().read().bits();
        if sta & STA_CTIMEOUT != 0 {
            return Err(SdioError::Timeout(index));
        }
        if sta & STA_CCRCFAIL != 0 {
            return match answer {
                Answer::ShortNoCrc => Ok(s.resp1().read().bits()),
                _ => Err(SdioError::Crc(index)),
            };
        }
        if sta & done != 0 {
            return Ok(s.resp1().read().bits());
        }
    }
    Err(SdioError::Timeout(index))
}

/// A command answered by an R1 card status, its error bits checked.
fn command_r1(index: u8, arg: u32) -> Result<u32, SdioError> {
    let status = command(index, arg, Answer::Short)?;
    if status & R1_ERRORS != 0 {
        return Err(SdioError::Rejected(index, status));
    }
    Ok(status)
}

/// The card in the slot, started.
pub struct Sdio {
    /// Its relative address, shifted into a command argument's top half.
    rca_arg: u32,
    /// It addresses 512-byte blocks (SDHC/SDXC), not bytes (SDSC).
    block_addressed: bool,
}

impl Sdio {
    /// Powers the SDIO block and starts the card (about 0.1-1 s while it gets ready). The
    /// pins and the SDIO clock are set up by the board's `init`.
    pub fn start() -> Result<Self, SdioError> {
        let s = regs();
        // SAFETY: POWER takes 0b11 (on); CLKCR a divider and its enable and bus bits.
        s.power().write(|w| unsafe { w.bits(0b11) });
        cortex_m::asm::delay(CYCLES_PER_MS);
        s.clkcr().write(|w| unsafe { w.bits(CLKDIV_START | CLKCR_CLKEN) });
        // The card needs 74 clocks before its first command: 185 us at 400 kHz.
        cortex_m::asm::delay(CYCLES_PER_MS);
        command(0, 0, Answer::None)?;
        let version2 = match command(8, CMD8_CHECK, Answer::Short) {
            Ok(echo) => echo & 0xFFF == CMD8_CHECK,
            Err(SdioError::Timeout(_)) => false,
            Err(e) => return Err(e),
        };
        let hcs = if version2 { ACMD41_HCS } else { ACMD41_HCS & !OCR_CCS };
        let mut ocr = 0;
        for _ in 0..START_TRIES {
            // Not checked: a version 1 card reports CMD8 as illegal in this status.
            command(55, 0, Answer::Short)?;
            ocr = command(41, hcs, Answer::ShortNoCrc)?;
            if ocr & OCR_READY != 0 {
                break;
            }
            cortex_m::asm::delay(CYCLES_PER_MS);
        }
        if ocr & OCR_READY == 0 {
            return Err(SdioError::NotReady);
        }
        command(2, 0, Answer::Long)?;
        let rca_arg = command(3, 0, Answer::Short)? & 0xFFFF_0000;
        command_r1(7, rca_arg)?;
        command_r1(55, rca_arg)?;
        command_r1(6, 0b10)?;
        s.clkcr().write(|w| unsafe { w.bits(CLKDIV_DATA | CLKCR_CLKEN | CLKCR_WIDBUS_4) });
        command_r1(16, BLOCK_BYTES as u32)?;
        Ok(Self { rca_arg, block_addressed: ocr & OCR_CCS != 0 })
    }

    /// The address argument of block `block`.
    fn address(&self, block: u32) -> u32 {
        if self.block_addressed {
            block
        } else {
            block.wrapping_mul(BLOCK_BYTES as u32)
        }
    }

    /// Sets the data path up for one block (`read`: from the card).
    fn data(read: bool) {
        let s = regs();
        let dir = if read { DCTRL_DTDIR } else { 0 };
        // SAFETY: DTIMER and DLEN take any count; DCTRL the enable, direction and size bits.
        s.dtimer().write(|w| unsafe { w.bits(DATA_TIMEOUT_CK) });
        s.dlen().write(|w| unsafe { w.bits(BLOCK_BYTES as u32) });
        s.dctrl().write(|w| unsafe { w.bits(DCTRL_DTEN | dir | DCTRL_BLOCK_512) });
    }

    /// Waits until the card finished programming and takes commands again.
    fn wait_ready(&self) -> Result<(), SdioError> {
        for _ in 0..BUSY_POLLS {
            let status = command_r1(13, self.rca_arg)?;
            if (status >> 9) & 0xF == STATE_TRAN && status & R1_READY_FOR_DATA != 0 {
                return Ok(());
            }
        }
        Err(SdioError::StaysBusy)
    }
}

impl BlockRead for Sdio {
    type Error = SdioError;

    fn read(&mut self, block: u32, offset: usize, out: &mut [u8]) -> Result<(), SdioError> {
        let s = regs();
        Self::data(true);
        command_r1(17, self.address(block))?;
        // Every word of the block comes through the FIFO; the bytes in `offset..` are kept.
        let mut at = 0usize;
        for _ in 0..DATA_POLLS {
            let sta = s.sta().read().bits();
            if sta & STA_DATA_ERRORS != 0 {
                return Err(SdioError::Data(sta));
            }
            if sta & STA_RXDAVL != 0 {
                let word = s.fifo().read().bits().to_le_bytes();
                for b in word {
                    if let Some(o) = at.checked_sub(offset).and_then(|i| out.get_mut(i)) {
                        *o = b;
                    }
                    at += 1;
                }
            } else if sta & STA_DBCKEND != 0 {
                break;
            }
        }
        // SAFETY: as in `command`.
        s.icr().write(|w| unsafe { w.bits(ICR_ALL) });
        if at < BLOCK_BYTES {
            return Err(SdioError::Data(s.sta().read().bits()));
        }
        Ok(())
    }
}

impl BlockWrite for Sdio {
    fn write(&mut self, block: u32, data: &[u8; BLOCK_BYTES]) -> Result<(), SdioError> {
        let s = regs();
        command_r1(24, self.address(block))?;
        Self::data(false);
        let mut words = data.chunks_exact(4).map(|w| u32::from_le_bytes([w[0], w[1], w[2], w[3]]));
        let mut ended = false;
        for _ in 0..DATA_POLLS {
            let sta = s.sta().read().bits();
            if sta & STA_DATA_ERRORS != 0 {
                return Err(SdioError::Data(sta));
            }
            if sta & STA_DBCKEND != 0 {
                ended = true;
                break;
            }
            // Half the FIFO is free: 8 words go in.
            if sta & STA_TXFIFOHE != 0 {
                for w in words.by_ref().take(8) {
                    // SAFETY: the FIFO takes any word.
                    s.fifo().write(|f| unsafe { f.bits(w) });
                }
            }
        }
        // SAFETY: as in `command`.
        s.icr().write(|w| unsafe { w.bits(ICR_ALL) });
        if !ended {
            return Err(SdioError::Data(s.sta().read().bits()));
        }
        self.wait_ready()
    }
}
