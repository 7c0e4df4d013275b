//! A card image in memory as the simulated printer's SD card (`strata simulate --card IMG`).

use strata::card::fat::{BlockRead, BlockWrite, BLOCK_BYTES};

/// A card image: the bytes of a whole card (a partition table or a bare FAT volume).
#[derive(Debug, Clone)]
pub struct ImageCard {
    bytes: Vec<u8>,
    /// Reads left before the card is pulled out (every access fails from then on).
    reads_left: Option<u64>,
}

/// A read beyond the image's end (or of a card pulled out).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BeyondImage {
    /// The block asked for.
    pub block: u32,
}

impl ImageCard {
    /// The card holding `bytes`.
    pub fn new(bytes: Vec<u8>) -> Self {
        Self { bytes, reads_left: None }
    }

    /// The card is pulled out after `reads` more reads: every access fails from then on.
    pub fn removed_after(mut self, reads: u64) -> Self {
        self.reads_left = Some(reads);
        self
    }

    /// The card is still in its slot.
    fn present(&mut self, block: u32) -> Result<(), BeyondImage> {
        match &mut self.reads_left {
            Some(0) => Err(BeyondImage { block }),
            Some(n) => {
                *n -= 1;
                Ok(())
            }
            None => Ok(()),
        }
    }

    /// The card's bytes (as written).
    pub fn bytes(&self) -> &[u8] {
        &self.bytes
    }

    /// The image file at `path`.
    pub fn open(path: &std::path::Path) -> Result<Self, String> {
        std::fs::read(path).map(Self::new).map_err(|e| format!("{}: {e}", path.display()))
    }
}

impl BlockRead for ImageCard {
    type Error = BeyondImage;

    fn read(&mut self, block: u32, offset: usize, out: &mut [u8]) -> Result<(), Self::Error> {
        self.present(block)?;
        let at = block as usize * BLOCK_BYTES + offset;
        let src = self.bytes.get(at..at + out.len()).ok_or(BeyondImage { block })?;
        out.copy_from_slice(src);
        Ok(())
    }
}

impl BlockWrite for ImageCard {
    fn write(&mut self, block: u32, data: &[u8; BLOCK_BYTES]) -> Result<(), Self::Error> {
        if self.reads_left == Some(0) {
            return Err(BeyondImage { block });
        }
        let at = block as usize * BLOCK_BYTES;
        let dst = self.bytes.get_mut(at..at + BLOCK_BYTES).ok_or(BeyondImage { block })?;
        dst.copy_from_slice(data);
        Ok(())
    }
}
