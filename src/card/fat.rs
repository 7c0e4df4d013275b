//! A FAT16/FAT32 reader that holds no block: the volume's geometry (28 B), a directory or
//! file cursor (16 B) and the bytes asked for.
//!
//! Every read names a block and a byte range within it ([`BlockRead`]): an SD card in SPI
//! mode streams a whole block and keeps the range (sequential ranges of one block cost one
//! transfer when the driver keeps the block's read open). So a file prints from the card
//! with no 512-byte buffer: the printer's RAM has none to spare while it slices.
//!
//! Read: a master boot record's first FAT partition (types 0x04, 0x06, 0x0E, 0x0B, 0x0C) or
//! a volume without partitions; 512-byte sectors; FAT16 or FAT32 by the cluster count, as
//! the specification decides (FAT12 is refused: no SD card is formatted so); the root
//! directory with long names (up to [`NAME_BYTES`] characters, non-ASCII ones as `?`); files
//! by their cluster chains. A corrupt volume (a cluster outside it, a directory longer than
//! the specification's 65,536 entries, a chain shorter than its file) gives
//! [`FatError::Corrupt`], never a panic or an endless loop.

use core::fmt;

/// Bytes of a block (an SD card's sector; the only sector size read).
pub const BLOCK_BYTES: usize = 512;
/// Characters of a name kept (longer long names are cut: [`DirEntry::name_cut`]).
pub const NAME_BYTES: usize = 64;
/// Bytes of a directory entry.
pub(super) const ENTRY_BYTES: u32 = 32;
/// Attribute bits of a directory entry.
pub(super) const ATTR_VOLUME: u8 = 0x08;
pub(super) const ATTR_DIR: u8 = 0x10;
pub(super) const ATTR_LONG_NAME: u8 = 0x0F;
/// Characters in one long-name entry, and their byte offsets in it (UCS-2, little-endian).
pub(super) const LFN_CHARS: usize = 13;
pub(super) const LFN_OFFSETS: [usize; LFN_CHARS] = [1, 3, 5, 7, 9, 14, 16, 18, 20, 22, 24, 28, 30];
/// Entries a directory may have (the specification's limit: 2 MiB of entries).
const MAX_DIR_ENTRIES: u32 = 65_536;
/// Blocks such a directory takes.
pub(super) const MAX_DIR_BLOCKS: u32 = MAX_DIR_ENTRIES * ENTRY_BYTES / BLOCK_BYTES as u32;
/// Fewer clusters than this is FAT12, fewer than the next FAT16 (the specification's rule).
const FAT16_MIN_CLUSTERS: u32 = 4085;
const FAT32_MIN_CLUSTERS: u32 = 65525;

/// A device of 512-byte blocks, read by parts.
pub trait BlockRead {
    /// Why a read failed.
    type Error: fmt::Debug;

    /// Reads `out.len()` bytes of block `block` from byte `offset` (`offset + out.len()` is
    /// at most [`BLOCK_BYTES`]).
    fn read(&mut self, block: u32, offset: usize, out: &mut [u8]) -> Result<(), Self::Error>;
}

/// A device of 512-byte blocks that is also written, a whole block at a time.
pub trait BlockWrite: BlockRead {
    /// Writes `data` to block `block`.
    fn write(&mut self, block: u32, data: &[u8; BLOCK_BYTES]) -> Result<(), Self::Error>;
}

/// Why the card could not be read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FatError<E> {
    /// The device failed.
    Device(E),
    /// No FAT volume: the card is not formatted (or not as FAT16/FAT32).
    NoVolume,
    /// A volume this reader does not read.
    Unsupported(Unsupported),
    /// The volume contradicts itself at this block: the card is damaged.
    Corrupt {
        /// The block read last.
        block: u32,
    },
    /// No such file.
    NotFound,
    /// The name is a directory.
    IsDirectory,
    /// No free cluster is left: the card is full.
    Full,
    /// The root directory has no room for another entry (FAT16's is fixed).
    DirectoryFull,
    /// A name a FAT volume cannot hold here: empty, longer than [`NAME_BYTES`], or with a
    /// character other than printable ASCII or one of `"*/:<>?\|`, or ending in a dot or a
    /// space.
    BadName,
}

/// Volumes this reader does not read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Unsupported {
    /// Sectors of this many bytes (only 512 are).
    SectorBytes(u16),
    /// FAT12 (floppies; no SD card is formatted so).
    Fat12,
}

impl<E: fmt::Debug> fmt::Display for FatError<E> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Device(e) => write!(f, "card read failed: {e:?}"),
            Self::NoVolume => write!(f, "no FAT16/FAT32 volume: the card is not formatted"),
            Self::Unsupported(Unsupported::SectorBytes(n)) => {
                write!(f, "sectors of {n} bytes are not supported (512 are)")
            }
            Self::Unsupported(Unsupported::Fat12) => write!(f, "FAT12 is not supported"),
            Self::Corrupt { block } => {
                write!(f, "the card's file system is damaged (block {block})")
            }
            Self::NotFound => write!(f, "no such file"),
            Self::Full => write!(f, "the card is full"),
            Self::DirectoryFull => write!(f, "the card's root directory is full"),
            Self::BadName => write!(f, "a name the card cannot hold"),
            Self::IsDirectory => write!(f, "a directory, not a file"),
        }
    }
}

/// FAT16 or FAT32.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FatType {
    /// 16-bit cluster numbers, a fixed root directory.
    Fat16,
    /// 28-bit cluster numbers, the root directory a cluster chain.
    Fat32,
}

/// A mounted volume: where its tables and clusters are.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Volume {
    /// FAT16 or FAT32 (see [`Volume::EMPTY`] for a place holder).
    pub fat_type: FatType,
    /// First block of the first FAT.
    pub(super) fat_start: u32,
    /// Blocks per cluster.
    pub(super) cluster_blocks: u32,
    /// Block of cluster 2.
    pub(super) data_start: u32,
    /// Clusters on the volume (numbered from 2).
    pub(super) clusters: u32,
    /// FAT16's root directory: its first block and blocks; FAT32's: its first cluster.
    pub(super) root_start: u32,
    pub(super) root_blocks: u32,
    /// Copies of the FAT, and blocks of each.
    pub(super) fats: u32,
    pub(super) fat_blocks: u32,
    /// FAT32's information block (its free-cluster count), 0 when none.
    pub(super) info_block: u32,
}

/// Little-endian fields of a block read whole into a small buffer.
pub(super) fn le16(b: &[u8], at: usize) -> u16 {
    u16::from_le_bytes([b[at], b[at + 1]])
}

pub(super) fn le32(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}

/// The BIOS parameter block's fields this reader uses: bytes 11..=49 and 82..=89 of a boot
/// sector, and its signature.
struct Bpb {
    head: [u8; 50],
    sig: [u8; 2],
}

impl Bpb {
    fn read<D: BlockRead>(dev: &mut D, block: u32) -> Result<Self, FatError<D::Error>> {
        let mut head = [0u8; 50];
        let mut sig = [0u8; 2];
        dev.read(block, 0, &mut head).map_err(FatError::Device)?;
        dev.read(block, 510, &mut sig).map_err(FatError::Device)?;
        Ok(Self { head, sig })
    }

    /// A FAT boot sector: the signature, a jump, and a plausible geometry.
    fn is_fat(&self) -> bool {
        let h = &self.head;
        let spc = h[13];
        self.sig == [0x55, 0xAA]
            && matches!(h[0], 0xEB | 0xE9)
            && spc != 0
            && spc.is_power_of_two()
            && le16(h, 14) != 0
            && h[16] != 0
    }
}

impl Volume {
    /// A place holder before a volume is mounted (no blocks).
    pub const EMPTY: Self = Self {
        fat_type: FatType::Fat16,
        fat_start: 0,
        cluster_blocks: 0,
        data_start: 0,
        clusters: 0,
        root_start: 0,
        root_blocks: 0,
        fats: 0,
        fat_blocks: 0,
        info_block: 0,
    };
}

impl Volume {
    /// Finds and reads the volume: the first FAT partition of a master boot record, or a
    /// volume that starts at block 0.
    pub fn mount<D: BlockRead>(dev: &mut D) -> Result<Self, FatError<D::Error>> {
        let first = Bpb::read(dev, 0)?;
        if first.is_fat() {
            return Self::of(&first, 0);
        }
        if first.sig != [0x55, 0xAA] {
            return Err(FatError::NoVolume);
        }
        let mut table = [0u8; 64];
        dev.read(0, 446, &mut table).map_err(FatError::Device)?;
        for entry in table.chunks_exact(16) {
            let start = le32(entry, 8);
            if matches!(entry[4], 0x04 | 0x06 | 0x0E | 0x0B | 0x0C) && start != 0 {
                let bpb = Bpb::read(dev, start)?;
                if !bpb.is_fat() {
                    return Err(FatError::NoVolume);
                }
                return Self::of(&bpb, start);
            }
        }
        Err(FatError::NoVolume)
    }

    fn of<E>(bpb: &Bpb, start: u32) -> Result<Self, FatError<E>> {
        let h = &bpb.head;
        let sector_bytes = le16(h, 11);
        if usize::from(sector_bytes) != BLOCK_BYTES {
            return Err(FatError::Unsupported(Unsupported::SectorBytes(sector_bytes)));
        }
        let cluster_blocks = u32::from(h[13]);
        let reserved = u32::from(le16(h, 14));
        let fats = u32::from(h[16]);
        let root_entries = u32::from(le16(h, 17));
        let total = match le16(h, 19) {
            0 => le32(h, 32),
            n => u32::from(n),
        };
        let fat_blocks = match le16(h, 22) {
            0 => le32(h, 36),
            n => u32::from(n),
        };
        let root_blocks = (root_entries * ENTRY_BYTES).div_ceil(BLOCK_BYTES as u32);
        let meta =
            u64::from(reserved) + u64::from(fats) * u64::from(fat_blocks) + u64::from(root_blocks);
        let corrupt = || FatError::Corrupt { block: start };
        let data_blocks = u64::from(total).checked_sub(meta).ok_or_else(corrupt)?;
        let clusters =
            u32::try_from(data_blocks / u64::from(cluster_blocks)).map_err(|_| corrupt())?;
        let fat_type = match clusters {
            c if c < FAT16_MIN_CLUSTERS => return Err(FatError::Unsupported(Unsupported::Fat12)),
            c if c < FAT32_MIN_CLUSTERS => FatType::Fat16,
            _ => FatType::Fat32,
        };
        // The FAT must hold an entry for every cluster.
        let entry_bytes = if fat_type == FatType::Fat16 { 2 } else { 4 };
        let fat_bytes = u64::from(fat_blocks) * BLOCK_BYTES as u64;
        if fat_bytes < (u64::from(clusters) + 2) * entry_bytes {
            return Err(corrupt());
        }
        // Every block of the volume has a 32-bit number.
        if u64::from(start) + u64::from(total) > u64::from(u32::MAX) {
            return Err(corrupt());
        }
        let fat_start = start.checked_add(reserved).ok_or_else(corrupt)?;
        let meta = u32::try_from(meta).map_err(|_| corrupt())?;
        let data_start = start.checked_add(meta).ok_or_else(corrupt)?;
        let (root_start, root_blocks) = match fat_type {
            FatType::Fat16 => (data_start - root_blocks, root_blocks),
            FatType::Fat32 => (le32(h, 44), 0),
        };
        let info_block = match (fat_type, le16(h, 48)) {
            (FatType::Fat32, n) if n != 0 && u32::from(n) < reserved => start + u32::from(n),
            _ => 0,
        };
        let vol = Self {
            fat_type,
            fat_start,
            cluster_blocks,
            data_start,
            clusters,
            root_start,
            root_blocks,
            fats,
            fat_blocks,
            info_block,
        };
        if fat_type == FatType::Fat32 && !vol.is_cluster(root_start) {
            return Err(corrupt());
        }
        Ok(vol)
    }

    /// Clusters on the volume.
    pub fn clusters(&self) -> u32 {
        self.clusters
    }

    pub(super) fn is_cluster(&self, c: u32) -> bool {
        (2..self.clusters + 2).contains(&c)
    }

    /// Block `i` of cluster `c` (a valid cluster, `i` below the cluster's blocks).
    pub(super) fn block_of(&self, c: u32, i: u32) -> u32 {
        self.data_start + (c - 2) * self.cluster_blocks + i
    }

    /// The cluster after `c` in its chain (`None`: the chain ends).
    pub(super) fn next_cluster<D: BlockRead>(
        &self,
        dev: &mut D,
        c: u32,
    ) -> Result<Option<u32>, FatError<D::Error>> {
        let (bytes, end) = match self.fat_type {
            FatType::Fat16 => (2u32, 0xFFF8),
            FatType::Fat32 => (4, 0x0FFF_FFF8),
        };
        // Within the FAT (checked at mount: it has an entry for every cluster).
        let at = u64::from(c) * u64::from(bytes);
        let block = self.fat_start + (at / BLOCK_BYTES as u64) as u32;
        let mut raw = [0u8; 4];
        let raw = &mut raw[..bytes as usize];
        dev.read(block, (at % BLOCK_BYTES as u64) as usize, raw).map_err(FatError::Device)?;
        let next = match self.fat_type {
            FatType::Fat16 => u32::from(le16(raw, 0)),
            FatType::Fat32 => le32(raw, 0) & 0x0FFF_FFFF,
        };
        if next >= end {
            return Ok(None);
        }
        if !self.is_cluster(next) {
            return Err(FatError::Corrupt { block });
        }
        Ok(Some(next))
    }

    /// The root directory, from its first entry.
    pub fn root(&self) -> Dir {
        let start = match self.fat_type {
            FatType::Fat16 => Cursor::fixed(self.root_start),
            FatType::Fat32 => Cursor::chain(self.root_start),
        };
        Dir { at: start, visited: 0 }
    }

    /// The root directory's file named `name` (its long name or its 8.3 name, ASCII letters
    /// in either case), ready to read.
    pub fn open<D: BlockRead>(&self, dev: &mut D, name: &str) -> Result<File, FatError<D::Error>> {
        let mut dir = self.root();
        while let Some(e) = dir.next(self, dev)? {
            if e.is_named(name) {
                if e.is_dir {
                    return Err(FatError::IsDirectory);
                }
                return Ok(File::of(&e));
            }
        }
        Err(FatError::NotFound)
    }
}

/// Where a directory or file is read: a block of the fixed FAT16 root, or a cluster, and
/// the byte within it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct Cursor {
    /// The cluster (0: FAT16's fixed root region, from `block`).
    pub(super) cluster: u32,
    /// The fixed region's first block.
    block: u32,
    /// Bytes into the cluster (or the fixed region).
    offset: u32,
}

impl Cursor {
    pub(super) fn fixed(block: u32) -> Self {
        Self { cluster: 0, block, offset: 0 }
    }

    pub(super) fn chain(cluster: u32) -> Self {
        Self { cluster, block: 0, offset: 0 }
    }

    /// The block and byte the cursor is at, and the bytes left in that block.
    pub(super) fn place(&self, vol: &Volume) -> (u32, usize, usize) {
        let in_block = (self.offset % BLOCK_BYTES as u32) as usize;
        let i = self.offset / BLOCK_BYTES as u32;
        let block = if self.cluster == 0 { self.block + i } else { vol.block_of(self.cluster, i) };
        (block, in_block, BLOCK_BYTES - in_block)
    }

    /// Bytes in the cursor's cluster (or the fixed region).
    pub(super) fn extent(&self, vol: &Volume) -> u32 {
        let blocks = if self.cluster == 0 { vol.root_blocks } else { vol.cluster_blocks };
        blocks * BLOCK_BYTES as u32
    }

    /// Moves on `n` bytes (within the extent); at its end, to the next cluster. False when
    /// the chain (or the fixed region) ended.
    pub(super) fn advance<D: BlockRead>(
        &mut self,
        vol: &Volume,
        dev: &mut D,
        n: u32,
    ) -> Result<bool, FatError<D::Error>> {
        self.offset += n;
        if self.offset < self.extent(vol) {
            return Ok(true);
        }
        if self.cluster == 0 {
            return Ok(false);
        }
        match vol.next_cluster(dev, self.cluster)? {
            Some(c) => {
                *self = Self::chain(c);
                Ok(true)
            }
            None => Ok(false),
        }
    }
}

/// An entry of a directory.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DirEntry {
    name: [u8; NAME_BYTES],
    name_len: u8,
    /// The long name was longer than [`NAME_BYTES`]: the name is its beginning.
    pub name_cut: bool,
    /// The 8.3 name as stored (11 bytes, space-padded).
    pub short_name: [u8; 11],
    /// A directory.
    pub is_dir: bool,
    /// Bytes of a file.
    pub size: u32,
    /// First cluster (0: empty).
    pub cluster: u32,
    /// Where the entry's slots start (its first long-name entry, or its 8.3 entry), and
    /// how many it has.
    pub(super) slots_at: Cursor,
    pub(super) slots: u8,
}

impl DirEntry {
    /// The name: the long one if any, else the 8.3 one as `NAME.EXT`.
    pub fn name(&self) -> &str {
        // Only ASCII is ever stored.
        core::str::from_utf8(&self.name[..usize::from(self.name_len)]).unwrap_or("")
    }

    /// The name or the 8.3 name is `name` (ASCII letters in either case).
    pub fn is_named(&self, name: &str) -> bool {
        if !self.name_cut && self.name().eq_ignore_ascii_case(name) {
            return true;
        }
        let mut short = [0u8; 12];
        let n = short_display(&self.short_name, 0, &mut short);
        short[..n].eq_ignore_ascii_case(name.as_bytes())
    }
}

/// The 8.3 name as `NAME.EXT` into `out` (lower case where the `case` flags of byte 12 say:
/// 0x08 the base, 0x10 the extension, as Windows writes them); returns its length.
fn short_display(raw: &[u8; 11], case: u8, out: &mut [u8]) -> usize {
    let mut n = 0;
    let mut put = |b: u8, lower: bool| {
        if let Some(slot) = out.get_mut(n) {
            *slot = if lower { b.to_ascii_lowercase() } else { b };
            n += 1;
        }
    };
    let base = raw[..8].iter().rposition(|&b| b != b' ').map_or(0, |i| i + 1);
    let ext = raw[8..].iter().rposition(|&b| b != b' ').map_or(0, |i| i + 1);
    for (i, &b) in raw[..base].iter().enumerate() {
        // 0x05 stands for a first byte 0xE5 (not ASCII: shown as `?`).
        let b = if i == 0 && b == 0x05 { b'?' } else { b };
        put(ascii_or_mark(b), case & 0x08 != 0);
    }
    if ext > 0 {
        put(b'.', false);
        for &b in &raw[8..8 + ext] {
            put(ascii_or_mark(b), case & 0x10 != 0);
        }
    }
    n
}

fn ascii_or_mark(b: u8) -> u8 {
    if b.is_ascii_graphic() || b == b' ' {
        b
    } else {
        b'?'
    }
}

/// The 8.3 name's checksum that its long-name entries carry.
pub(super) fn short_checksum(raw: &[u8; 11]) -> u8 {
    raw.iter().fold(0u8, |sum, &b| sum.rotate_right(1).wrapping_add(b))
}

/// A directory being read, entry by entry.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Dir {
    at: Cursor,
    /// Entries read (a directory of more is corrupt: its chain loops).
    visited: u32,
}

/// A long name being gathered from its entries (they precede the 8.3 entry, last part first).
struct LongName {
    name: [u8; NAME_BYTES],
    len: usize,
    cut: bool,
    /// The next part expected (counting down to 1), and the checksum they all carry.
    next: u8,
    checksum: u8,
    valid: bool,
}

impl LongName {
    fn new() -> Self {
        Self { name: [0; NAME_BYTES], len: 0, cut: false, next: 0, checksum: 0, valid: false }
    }

    /// One long-name entry: its part of the name in place.
    fn part(&mut self, e: &[u8; ENTRY_BYTES as usize]) {
        let seq = e[0] & 0x1F;
        if e[0] & 0x40 != 0 {
            *self = Self::new();
            self.next = seq;
            self.checksum = e[13];
            self.valid = seq >= 1;
        }
        if !self.valid || seq == 0 || seq != self.next || e[13] != self.checksum {
            self.valid = false;
            return;
        }
        self.next -= 1;
        let first = (usize::from(seq) - 1) * LFN_CHARS;
        for (k, &at) in LFN_OFFSETS.iter().enumerate() {
            let c = le16(e, at);
            if c == 0 || c == 0xFFFF {
                break;
            }
            let i = first + k;
            match self.name.get_mut(i) {
                Some(slot) => {
                    *slot = u8::try_from(c).ok().filter(u8::is_ascii).map_or(b'?', ascii_or_mark);
                    self.len = self.len.max(i + 1);
                }
                None => self.cut = true,
            }
        }
    }

    /// The gathered name, if it belongs to the 8.3 entry `short` (all parts, same checksum).
    fn finish(&self, short: &[u8; 11]) -> Option<(&[u8], bool)> {
        let whole = self.valid && self.next == 0 && self.checksum == short_checksum(short);
        whole.then(|| (&self.name[..self.len], self.cut))
    }
}

impl Dir {
    /// The next entry that names a file or a directory (`None`: the directory ends). Volume
    /// labels, deleted entries and `.`/`..` are passed over.
    pub fn next<D: BlockRead>(
        &mut self,
        vol: &Volume,
        dev: &mut D,
    ) -> Result<Option<DirEntry>, FatError<D::Error>> {
        let mut long = LongName::new();
        let mut run = (self.at, 0u8);
        loop {
            if self.at.cluster == 0 && self.at.offset >= self.at.extent(vol) {
                return Ok(None);
            }
            let (block, in_block, _) = self.at.place(vol);
            self.visited += 1;
            if self.visited > MAX_DIR_ENTRIES {
                return Err(FatError::Corrupt { block });
            }
            let mut e = [0u8; ENTRY_BYTES as usize];
            dev.read(block, in_block, &mut e).map_err(FatError::Device)?;
            let here = self.at;
            if e[0] == 0 {
                return Ok(None);
            }
            if !self.at.advance(vol, dev, ENTRY_BYTES)? {
                // The directory's last entry: the next call ends it.
                self.at = Cursor { cluster: 0, block: 0, offset: u32::MAX };
            }
            let attr = e[11];
            if attr & ATTR_LONG_NAME == ATTR_LONG_NAME {
                if e[0] != 0xE5 {
                    if e[0] & 0x40 != 0 {
                        run = (here, 0);
                    }
                    long.part(&e);
                    run.1 = run.1.saturating_add(1);
                }
                continue;
            }
            if e[0] == 0xE5 || attr & ATTR_VOLUME != 0 || e[0] == b'.' {
                long = LongName::new();
                continue;
            }
            let mut short = [0u8; 11];
            short.copy_from_slice(&e[..11]);
            let mut entry = DirEntry {
                name: [0; NAME_BYTES],
                name_len: 0,
                name_cut: false,
                short_name: short,
                is_dir: attr & ATTR_DIR != 0,
                size: le32(&e, 28),
                cluster: u32::from(le16(&e, 26)) | u32::from(le16(&e, 20)) << 16,
                slots_at: here,
                slots: 1,
            };
            let len = match long.finish(&short) {
                Some((name, cut)) => {
                    entry.name[..name.len()].copy_from_slice(name);
                    entry.name_cut = cut;
                    (entry.slots_at, entry.slots) = (run.0, run.1.saturating_add(1));
                    name.len()
                }
                None => short_display(&short, e[12], &mut entry.name),
            };
            entry.name_len = len as u8;
            return Ok(Some(entry));
        }
    }
}

/// A file being read from its start.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct File {
    at: Cursor,
    /// Bytes of the file, and read so far.
    size: u32,
    pos: u32,
}

impl File {
    /// A place holder before a file is opened (empty).
    pub const EMPTY: Self =
        Self { at: Cursor { cluster: 0, block: 0, offset: 0 }, size: 0, pos: 0 };
}

impl File {
    /// The file of entry `e`, at its start.
    pub fn of(e: &DirEntry) -> Self {
        Self { at: Cursor::chain(e.cluster), size: e.size, pos: 0 }
    }

    /// Bytes of the file.
    pub fn size(&self) -> u32 {
        self.size
    }

    /// Bytes read so far.
    pub fn position(&self) -> u32 {
        self.pos
    }

    /// Reads the next bytes into `out`: as many as it holds or the file has left, so 0 at
    /// the end (one block's part per device read).
    pub fn read<D: BlockRead>(
        &mut self,
        vol: &Volume,
        dev: &mut D,
        out: &mut [u8],
    ) -> Result<usize, FatError<D::Error>> {
        let mut n = 0;
        self.walk(vol, dev, out.len() as u32, |dev, block, in_block, want| {
            let part = &mut out[n..n + want];
            n += want;
            dev.read(block, in_block, part).map_err(FatError::Device)
        })?;
        Ok(n)
    }

    /// Moves on `n` bytes (at most to the end) without reading them; the bytes moved.
    pub fn skip<D: BlockRead>(
        &mut self,
        vol: &Volume,
        dev: &mut D,
        n: u32,
    ) -> Result<u32, FatError<D::Error>> {
        let start = self.pos;
        self.walk(vol, dev, n, |_, _, _, _| Ok(()))?;
        Ok(self.pos - start)
    }

    /// Goes through the next `n` bytes (at most to the end) a block's part at a time:
    /// `visit(dev, block, byte in the block, bytes)` for each part, before moving past it.
    fn walk<D: BlockRead>(
        &mut self,
        vol: &Volume,
        dev: &mut D,
        n: u32,
        mut visit: impl FnMut(&mut D, u32, usize, usize) -> Result<(), FatError<D::Error>>,
    ) -> Result<(), FatError<D::Error>> {
        let end = self.pos.saturating_add(n).min(self.size);
        while self.pos < end {
            if !vol.is_cluster(self.at.cluster) {
                return Err(FatError::Corrupt { block: vol.fat_start });
            }
            let (block, in_block, left) = self.at.place(vol);
            let want = ((end - self.pos) as usize).min(left);
            visit(dev, block, in_block, want)?;
            self.pos += want as u32;
            let more = self.at.advance(vol, dev, want as u32)?;
            if !more && self.pos < self.size {
                // The chain ended before the file did.
                return Err(FatError::Corrupt { block });
            }
        }
        Ok(())
    }
}
