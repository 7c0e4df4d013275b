//! The printer's microSD card: its file system, read with bounded memory.
//!
//! - [`fat`]: a FAT16/FAT32 reader that holds no block buffer (the volume's geometry and a
//!   cursor), so that a file can feed a print while the slicer has the RAM.
//! - [`sd`]: an SD card in SPI mode (the QEMU board's): start-up, block reads that keep
//!   only the bytes asked for, whole-block writes.
//! - [`write`](mod@write): files created, appended to, closed and removed, in two lent blocks.

pub mod fat;
pub mod sd;
pub mod write;
pub mod zsort;

/// A file open for reading on its volume: what a print from the card keeps between reads
/// (48 bytes, in the scratch a G-code job leaves free).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct OpenFile {
    /// The volume the file is on.
    pub volume: fat::Volume,
    /// The file, where the next read starts.
    pub file: fat::File,
}

/// A file being written on its volume, with the writer's blocks: what an upload to the card
/// keeps between messages (1.1 KB, in the scratch an idle printer leaves free).
#[derive(Debug, Clone)]
pub struct WritingFile {
    /// The volume the file is on.
    pub volume: fat::Volume,
    /// The file.
    pub writer: write::FileWriter,
    /// The writer's blocks.
    pub bufs: write::WriteBuffers,
}

/// The card of a board without a card slot: there is never one
/// ([`Printer::card_service`](crate::printer::Printer::card_service) with `None`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NoCard {}

impl fat::BlockRead for NoCard {
    type Error = core::convert::Infallible;

    fn read(&mut self, _: u32, _: usize, _: &mut [u8]) -> Result<(), Self::Error> {
        match *self {}
    }
}

impl fat::BlockWrite for NoCard {
    fn write(&mut self, _: u32, _: &[u8; fat::BLOCK_BYTES]) -> Result<(), Self::Error> {
        match *self {}
    }
}
