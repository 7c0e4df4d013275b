//! The printer's microSD card: its file system, read with bounded memory.
//!
//! - [`fat`]: a FAT16/FAT32 reader that holds no block buffer (the volume's geometry and a
//!   cursor), so that a file can feed a print while the slicer has the RAM.
//! - [`sd`]: an SD card in SPI mode (the QEMU board's): start-up and block reads that keep
//!   only the bytes asked for.

pub mod fat;
pub mod sd;
