//! Writing the card's FAT16/FAT32 volume: a file created in the root directory, appended to
//! and closed, or removed.
//!
//! Writing needs whole blocks (an SD card writes 512 bytes at a time), so the caller lends
//! two ([`WriteBuffers`], 1 KB): the file's block being filled, and a block of metadata (a
//! FAT block or a directory block, read, changed and written back). The printer writes
//! only while no job runs, with the buffers in the scratch a job would use.
//!
//! - [`Volume::create`] removes a file of the same name, then writes the new file's
//!   long-name entries and its 8.3 alias (`BASE~N.EXT`, the lowest free `N`) into one block
//!   of the root directory, growing a FAT32 root by a cluster when it is full.
//! - [`FileWriter::append`] fills the data block and writes it when full, taking a free
//!   cluster (searched from the last one taken) when the file needs one; every change to a
//!   FAT block goes to each copy of the FAT once the writer moves to another FAT block.
//! - [`FileWriter::close`] writes the last part block, the entry's first cluster and size,
//!   and marks FAT32's free-cluster count unknown (the specification's value for "count
//!   again"). A file not closed leaves its clusters taken and its entry empty: lost space,
//!   never a damaged file.
//! - [`Volume::remove`] marks the entry's slots deleted and frees its chain.

use super::fat::{
    le16, le32, short_checksum, BlockWrite, DirEntry, FatError, FatType, Volume, ATTR_LONG_NAME,
    BLOCK_BYTES, ENTRY_BYTES, LFN_CHARS, LFN_OFFSETS, NAME_BYTES,
};

/// A block.
pub type Block = [u8; BLOCK_BYTES];
/// Entries of a directory block.
const ENTRIES_PER_BLOCK: usize = BLOCK_BYTES / ENTRY_BYTES as usize;
/// An 8.3 entry's archive attribute (a file written since the last backup).
const ATTR_ARCHIVE: u8 = 0x20;
/// A deleted entry's first byte.
const DELETED: u8 = 0xE5;
/// The FAT's end-of-chain marks.
const FAT16_END: u32 = 0xFFFF;
const FAT32_END: u32 = 0x0FFF_FFFF;
/// Aliases `BASE~1` to `BASE~N` tried for a new file's 8.3 name.
const ALIAS_TRIES: u32 = 64;
/// FAT32 information block: its signatures' offsets and values, and the free count's offset.
const INFO_LEAD: (usize, u32) = (0, 0x4161_5252);
const INFO_STRUCT: (usize, u32) = (484, 0x6141_7272);
const INFO_FREE: usize = 488;

/// The two blocks a writer works in (see the [module docs](self)).
#[derive(Debug, Clone)]
pub struct WriteBuffers {
    /// The file's block being filled.
    pub data: Block,
    /// A FAT or directory block being changed.
    pub meta: Block,
}

impl WriteBuffers {
    /// Zeroed buffers.
    pub const fn new() -> Self {
        Self { data: [0; BLOCK_BYTES], meta: [0; BLOCK_BYTES] }
    }
}

impl Default for WriteBuffers {
    fn default() -> Self {
        Self::new()
    }
}

/// A file being written (see the [module docs](self)).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FileWriter {
    /// The block and byte of the file's 8.3 entry.
    entry_block: u32,
    entry_offset: u16,
    /// First and last cluster (0: none yet).
    first: u32,
    last: u32,
    /// Bytes appended.
    size: u32,
    /// Where the search for a free cluster starts.
    hint: u32,
    /// The FAT block (index within a FAT) in the meta buffer, and whether it was changed.
    fat_block: Option<u32>,
    dirty: bool,
}

impl FileWriter {
    /// Bytes appended so far.
    pub fn size(&self) -> u32 {
        self.size
    }

    /// Appends `bytes` (the data block is written whenever it fills).
    pub fn append<D: BlockWrite>(
        &mut self,
        vol: &Volume,
        dev: &mut D,
        bufs: &mut WriteBuffers,
        bytes: &[u8],
    ) -> Result<(), FatError<D::Error>> {
        let mut rest = bytes;
        while !rest.is_empty() {
            let at = self.size as usize % BLOCK_BYTES;
            let n = rest.len().min(BLOCK_BYTES - at);
            if at == 0 && self.size.checked_add(BLOCK_BYTES as u32).is_none() {
                // FAT files end below 4 GiB.
                return Err(FatError::Full);
            }
            bufs.data[at..at + n].copy_from_slice(&rest[..n]);
            rest = &rest[n..];
            self.size += n as u32;
            if at + n == BLOCK_BYTES {
                self.write_data(vol, dev, bufs)?;
            }
        }
        Ok(())
    }

    /// Writes the last part block, the entry's cluster and size; the file is complete.
    pub fn close<D: BlockWrite>(
        mut self,
        vol: &Volume,
        dev: &mut D,
        bufs: &mut WriteBuffers,
    ) -> Result<u32, FatError<D::Error>> {
        let part = self.size as usize % BLOCK_BYTES;
        if part != 0 {
            bufs.data[part..].fill(0);
            self.write_data(vol, dev, bufs)?;
        }
        self.flush_fat(vol, dev, bufs)?;
        let block = self.entry_block;
        dev.read(block, 0, &mut bufs.meta).map_err(FatError::Device)?;
        let e = &mut bufs.meta[usize::from(self.entry_offset)..][..ENTRY_BYTES as usize];
        e[20..22].copy_from_slice(&((self.first >> 16) as u16).to_le_bytes());
        e[26..28].copy_from_slice(&(self.first as u16).to_le_bytes());
        e[28..32].copy_from_slice(&self.size.to_le_bytes());
        dev.write(block, &bufs.meta).map_err(FatError::Device)?;
        forget_free_count(vol, dev, &mut bufs.meta)?;
        Ok(self.size)
    }

    /// The data block into the file's current cluster, a new one taken when the last is
    /// full (the block's bytes are `size`'s last, up to a whole block).
    fn write_data<D: BlockWrite>(
        &mut self,
        vol: &Volume,
        dev: &mut D,
        bufs: &mut WriteBuffers,
    ) -> Result<(), FatError<D::Error>> {
        let index = (self.size - 1) / BLOCK_BYTES as u32;
        let in_cluster = index % vol.cluster_blocks;
        if in_cluster == 0 {
            let c = self.take_cluster(vol, dev, bufs)?;
            if self.last != 0 {
                self.set_fat(vol, dev, bufs, self.last, c)?;
            } else {
                self.first = c;
            }
            self.last = c;
        }
        dev.write(vol.block_of(self.last, in_cluster), &bufs.data).map_err(FatError::Device)
    }

    /// A free cluster, marked as a chain's end.
    fn take_cluster<D: BlockWrite>(
        &mut self,
        vol: &Volume,
        dev: &mut D,
        bufs: &mut WriteBuffers,
    ) -> Result<u32, FatError<D::Error>> {
        let per_block = (BLOCK_BYTES / entry_bytes(vol)) as u32;
        let mut c = if vol.is_cluster(self.hint) { self.hint } else { 2 };
        for _ in 0..vol.clusters {
            self.load_fat(vol, dev, bufs, c / per_block)?;
            if fat_entry(vol, &bufs.meta, c % per_block) == 0 {
                self.hint = c + 1;
                self.set_fat(vol, dev, bufs, c, end_mark(vol))?;
                return Ok(c);
            }
            c = if c + 1 < vol.clusters + 2 { c + 1 } else { 2 };
        }
        Err(FatError::Full)
    }

    /// Cluster `c`'s FAT entry set to `value`, in the meta buffer (written to every FAT copy
    /// when the writer moves to another FAT block, or closes).
    fn set_fat<D: BlockWrite>(
        &mut self,
        vol: &Volume,
        dev: &mut D,
        bufs: &mut WriteBuffers,
        c: u32,
        value: u32,
    ) -> Result<(), FatError<D::Error>> {
        let per_block = (BLOCK_BYTES / entry_bytes(vol)) as u32;
        self.load_fat(vol, dev, bufs, c / per_block)?;
        put_fat_entry(vol, &mut bufs.meta, c % per_block, value);
        self.dirty = true;
        Ok(())
    }

    /// FAT block `i` into the meta buffer (the one there written out first if changed).
    fn load_fat<D: BlockWrite>(
        &mut self,
        vol: &Volume,
        dev: &mut D,
        bufs: &mut WriteBuffers,
        i: u32,
    ) -> Result<(), FatError<D::Error>> {
        if self.fat_block == Some(i) {
            return Ok(());
        }
        self.flush_fat(vol, dev, bufs)?;
        dev.read(vol.fat_start + i, 0, &mut bufs.meta).map_err(FatError::Device)?;
        self.fat_block = Some(i);
        Ok(())
    }

    /// The changed FAT block to every copy of the FAT.
    fn flush_fat<D: BlockWrite>(
        &mut self,
        vol: &Volume,
        dev: &mut D,
        bufs: &mut WriteBuffers,
    ) -> Result<(), FatError<D::Error>> {
        if let (Some(i), true) = (self.fat_block, self.dirty) {
            for copy in 0..vol.fats {
                let block = vol.fat_start + copy * vol.fat_blocks + i;
                dev.write(block, &bufs.meta).map_err(FatError::Device)?;
            }
        }
        self.dirty = false;
        Ok(())
    }
}

/// Bytes of a FAT entry.
fn entry_bytes(vol: &Volume) -> usize {
    match vol.fat_type {
        FatType::Fat16 => 2,
        FatType::Fat32 => 4,
    }
}

fn end_mark(vol: &Volume) -> u32 {
    match vol.fat_type {
        FatType::Fat16 => FAT16_END,
        FatType::Fat32 => FAT32_END,
    }
}

/// Entry `i` of a FAT block.
fn fat_entry(vol: &Volume, block: &Block, i: u32) -> u32 {
    let at = i as usize * entry_bytes(vol);
    match vol.fat_type {
        FatType::Fat16 => u32::from(le16(block, at)),
        FatType::Fat32 => le32(block, at) & 0x0FFF_FFFF,
    }
}

/// Entry `i` of a FAT block set to `value` (FAT32 keeps the entry's top four bits).
fn put_fat_entry(vol: &Volume, block: &mut Block, i: u32, value: u32) {
    let at = i as usize * entry_bytes(vol);
    match vol.fat_type {
        FatType::Fat16 => block[at..at + 2].copy_from_slice(&(value as u16).to_le_bytes()),
        FatType::Fat32 => {
            let kept = le32(block, at) & 0xF000_0000;
            block[at..at + 4].copy_from_slice(&(kept | value).to_le_bytes());
        }
    }
}

/// FAT32's free-cluster count marked unknown (readers count again).
fn forget_free_count<D: BlockWrite>(
    vol: &Volume,
    dev: &mut D,
    meta: &mut Block,
) -> Result<(), FatError<D::Error>> {
    if vol.info_block == 0 {
        return Ok(());
    }
    dev.read(vol.info_block, 0, meta).map_err(FatError::Device)?;
    let signed =
        le32(meta, INFO_LEAD.0) == INFO_LEAD.1 && le32(meta, INFO_STRUCT.0) == INFO_STRUCT.1;
    if signed && le32(meta, INFO_FREE) != u32::MAX {
        meta[INFO_FREE..INFO_FREE + 4].copy_from_slice(&u32::MAX.to_le_bytes());
        dev.write(vol.info_block, meta).map_err(FatError::Device)?;
    }
    Ok(())
}

/// Whether `name` can be a file's long name here.
fn valid_name(name: &str) -> bool {
    let b = name.as_bytes();
    let bad = |c: &u8| !(0x20..0x7F).contains(c) || b"\"*/:<>?\\|".contains(c);
    !b.is_empty()
        && b.len() <= NAME_BYTES
        && !b.iter().any(bad)
        && !matches!(b.last(), Some(b'.' | b' '))
        && !b.iter().all(|&c| c == b'.')
}

/// The 8.3 alias's base (up to 6 characters) and extension (up to 3) of a long name:
/// upper case, characters an 8.3 name cannot hold as `_`, spaces and dots dropped.
fn alias_parts(name: &str) -> ([u8; 6], usize, [u8; 3], usize) {
    let b = name.as_bytes();
    let (stem, ext) = match b.iter().rposition(|&c| c == b'.') {
        Some(i) if i > 0 => (&b[..i], &b[i + 1..]),
        _ => (b, &b[..0]),
    };
    let fold = |c: u8| match c {
        b'+' | b',' | b';' | b'=' | b'[' | b']' => Some(b'_'),
        b' ' | b'.' => None,
        c => Some(c.to_ascii_uppercase()),
    };
    let mut base = [b' '; 6];
    let mut nb = 0;
    for c in stem.iter().filter_map(|&c| fold(c)).take(6) {
        base[nb] = c;
        nb += 1;
    }
    if nb == 0 {
        base[0] = b'_';
        nb = 1;
    }
    let mut e = [b' '; 3];
    let mut ne = 0;
    for c in ext.iter().filter_map(|&c| fold(c)).take(3) {
        e[ne] = c;
        ne += 1;
    }
    (base, nb, e, ne)
}

/// The alias `BASE~n.EXT` as an 8.3 entry's 11 bytes (`n` below 100).
fn alias(base: &[u8; 6], nb: usize, ext: &[u8; 3], n: u32) -> [u8; 11] {
    let mut raw = [b' '; 11];
    let digits = if n < 10 { 1 } else { 2 };
    let keep = nb.min(8 - 1 - digits);
    raw[..keep].copy_from_slice(&base[..keep]);
    raw[keep] = b'~';
    if n >= 10 {
        raw[keep + 1] = b'0' + (n / 10) as u8;
    }
    raw[keep + digits] = b'0' + (n % 10) as u8;
    raw[8..].copy_from_slice(ext);
    raw
}

/// The long-name entry `seq` (1-based; `last`: the name's last part) of `name` for the
/// alias with checksum `sum`.
fn long_entry(name: &[u8], seq: usize, last: bool, sum: u8) -> [u8; ENTRY_BYTES as usize] {
    let mut e = [0u8; ENTRY_BYTES as usize];
    e[0] = seq as u8 | if last { 0x40 } else { 0 };
    e[11] = ATTR_LONG_NAME;
    e[13] = sum;
    for (k, &at) in LFN_OFFSETS.iter().enumerate() {
        let i = (seq - 1) * LFN_CHARS + k;
        // The name, a 0 after it, then 0xFFFF.
        let c: u16 = match i.cmp(&name.len()) {
            core::cmp::Ordering::Less => u16::from(name[i]),
            core::cmp::Ordering::Equal => 0,
            core::cmp::Ordering::Greater => 0xFFFF,
        };
        e[at..at + 2].copy_from_slice(&c.to_le_bytes());
    }
    e
}

/// Where a new entry's slots go: a block of the root directory and the first slot; and a
/// block before it whose free slots from `gap.1` on are end marks (0x00) that must become
/// deleted ones, or readers would stop before the new entry.
struct Room {
    block: u32,
    slot: usize,
    gap: Option<(u32, usize)>,
}

impl Volume {
    /// Creates (or replaces) the root directory's file `name`, empty, ready to append to.
    pub fn create<D: BlockWrite>(
        &self,
        dev: &mut D,
        bufs: &mut WriteBuffers,
        name: &str,
    ) -> Result<FileWriter, FatError<D::Error>> {
        if !valid_name(name) {
            return Err(FatError::BadName);
        }
        match self.remove(dev, bufs, name) {
            Ok(()) | Err(FatError::NotFound) => {}
            Err(e) => return Err(e),
        }
        let long = name.len().div_ceil(LFN_CHARS);
        let (base, nb, ext, _) = alias_parts(name);
        let (room, taken) = self.find_room(dev, bufs, long + 1, &base[..nb])?;
        let n = (1..=ALIAS_TRIES).find(|n| taken & 1u64 << (n - 1) == 0);
        let short = alias(&base, nb, &ext, n.ok_or(FatError::DirectoryFull)?);
        let sum = short_checksum(&short);
        if let Some((block, from)) = room.gap {
            dev.read(block, 0, &mut bufs.meta).map_err(FatError::Device)?;
            for slot in from..ENTRIES_PER_BLOCK {
                bufs.meta[slot * ENTRY_BYTES as usize] = DELETED;
            }
            dev.write(block, &bufs.meta).map_err(FatError::Device)?;
        }
        dev.read(room.block, 0, &mut bufs.meta).map_err(FatError::Device)?;
        for k in 0..long {
            let seq = long - k;
            let e = long_entry(name.as_bytes(), seq, k == 0, sum);
            let at = (room.slot + k) * ENTRY_BYTES as usize;
            bufs.meta[at..at + ENTRY_BYTES as usize].copy_from_slice(&e);
        }
        let at = (room.slot + long) * ENTRY_BYTES as usize;
        let e = &mut bufs.meta[at..at + ENTRY_BYTES as usize];
        e.fill(0);
        e[..11].copy_from_slice(&short);
        e[11] = ATTR_ARCHIVE;
        // 1980-01-01, 00:00 (no clock): created, accessed, written.
        for date in [16, 18, 24] {
            e[date..date + 2].copy_from_slice(&0x0021u16.to_le_bytes());
        }
        dev.write(room.block, &bufs.meta).map_err(FatError::Device)?;
        Ok(FileWriter {
            entry_block: room.block,
            entry_offset: at as u16,
            first: 0,
            last: 0,
            size: 0,
            hint: 2,
            fat_block: None,
            dirty: false,
        })
    }

    /// Removes the root directory's file `name`: its slots deleted, its clusters freed.
    pub fn remove<D: BlockWrite>(
        &self,
        dev: &mut D,
        bufs: &mut WriteBuffers,
        name: &str,
    ) -> Result<(), FatError<D::Error>> {
        let mut dir = self.root();
        let entry = loop {
            match dir.next(self, dev)? {
                Some(e) if e.is_named(name) => break e,
                Some(_) => {}
                None => return Err(FatError::NotFound),
            }
        };
        if entry.is_dir {
            return Err(FatError::IsDirectory);
        }
        self.delete_slots(dev, bufs, &entry)?;
        let mut chain = FileWriter::EMPTY;
        let mut c = entry.cluster;
        // The clusters its size takes (at least one): a longer chain is damaged (it loops,
        // or runs into another file's), and what lies past them is left alone.
        let cluster_bytes = self.cluster_blocks * BLOCK_BYTES as u32;
        let mut left = entry.size.div_ceil(cluster_bytes).max(1);
        while self.is_cluster(c) && left > 0 {
            let next = self.next_cluster(dev, c)?;
            chain.set_fat(self, dev, bufs, c, 0)?;
            c = next.unwrap_or(0);
            left -= 1;
        }
        chain.flush_fat(self, dev, bufs)?;
        forget_free_count(self, dev, &mut bufs.meta)
    }

    /// The entry's slots marked deleted, a directory block at a time.
    fn delete_slots<D: BlockWrite>(
        &self,
        dev: &mut D,
        bufs: &mut WriteBuffers,
        entry: &DirEntry,
    ) -> Result<(), FatError<D::Error>> {
        let mut at = entry.slots_at;
        let mut loaded: Option<u32> = None;
        for k in 0..entry.slots {
            let (block, in_block, _) = at.place(self);
            if loaded != Some(block) {
                if let Some(b) = loaded {
                    dev.write(b, &bufs.meta).map_err(FatError::Device)?;
                }
                dev.read(block, 0, &mut bufs.meta).map_err(FatError::Device)?;
                loaded = Some(block);
            }
            bufs.meta[in_block] = DELETED;
            if k + 1 < entry.slots && !at.advance(self, dev, ENTRY_BYTES)? {
                break;
            }
        }
        if let Some(b) = loaded {
            dev.write(b, &bufs.meta).map_err(FatError::Device)?;
        }
        Ok(())
    }

    /// A root directory block with `slots` free slots in a row, and the aliases `BASE~n`
    /// (bit `n - 1`) of `base` that are taken; a FAT32 root grows by a cluster when full.
    fn find_room<D: BlockWrite>(
        &self,
        dev: &mut D,
        bufs: &mut WriteBuffers,
        slots: usize,
        base: &[u8],
    ) -> Result<(Room, u64), FatError<D::Error>> {
        let mut taken = 0u64;
        let mut room: Option<Room> = None;
        // The first end mark: the block and slot.
        let mut end: Option<(u32, usize)> = None;
        let mut last_cluster = self.root_start;
        let mut blocks = 0u32;
        loop {
            let block = match self.fat_type {
                FatType::Fat16 if blocks >= self.root_blocks => break,
                FatType::Fat16 => self.root_start + blocks,
                FatType::Fat32 => {
                    let i = blocks % self.cluster_blocks;
                    if i == 0 && blocks > 0 {
                        match self.next_cluster(dev, last_cluster)? {
                            Some(c) => last_cluster = c,
                            None => break,
                        }
                    }
                    self.block_of(last_cluster, i)
                }
            };
            blocks += 1;
            if blocks > super::fat::MAX_DIR_BLOCKS {
                return Err(FatError::Corrupt { block });
            }
            dev.read(block, 0, &mut bufs.meta).map_err(FatError::Device)?;
            let mut run = 0;
            for slot in 0..ENTRIES_PER_BLOCK {
                let e = &bufs.meta[slot * ENTRY_BYTES as usize..][..ENTRY_BYTES as usize];
                if e[0] == 0 && end.is_none() {
                    end = Some((block, slot));
                }
                if e[0] == 0 || e[0] == DELETED {
                    run += 1;
                    if run == slots && room.is_none() {
                        let first = slot + 1 - slots;
                        let gap = end.filter(|&(b, _)| b != block);
                        room = Some(Room { block, slot: first, gap });
                    }
                    continue;
                }
                run = 0;
                if e[11] & ATTR_LONG_NAME != ATTR_LONG_NAME {
                    taken |= alias_taken(&e[..11], base);
                }
            }
        }
        if let Some(room) = room {
            return Ok((room, taken));
        }
        if self.fat_type == FatType::Fat16 {
            return Err(FatError::DirectoryFull);
        }
        // A new cluster for the root, zeroed, after its last.
        let mut grow = FileWriter { hint: last_cluster, ..FileWriter::EMPTY };
        let c = grow.take_cluster(self, dev, bufs)?;
        grow.set_fat(self, dev, bufs, last_cluster, c)?;
        grow.flush_fat(self, dev, bufs)?;
        bufs.meta.fill(0);
        for i in 0..self.cluster_blocks {
            dev.write(self.block_of(c, i), &bufs.meta).map_err(FatError::Device)?;
        }
        Ok((Room { block: self.block_of(c, 0), slot: 0, gap: end }, taken))
    }
}

impl FileWriter {
    /// A writer of nothing (the chain operations of [`Volume::remove`] and the root's
    /// growth use its FAT block handling; a place holder before [`Volume::create`]).
    pub const EMPTY: Self = Self {
        entry_block: 0,
        entry_offset: 0,
        first: 0,
        last: 0,
        size: 0,
        hint: 2,
        fat_block: None,
        dirty: false,
    };

    /// A place holder only (all zero bytes: cleared in place with what holds it), replaced
    /// by [`Volume::create`] before any use.
    pub const PLACE_HOLDER: Self = Self { hint: 0, ..Self::EMPTY };
}

/// The bit of alias number `n` (`n - 1`) when the 8.3 name `raw` is `BASE~n` of `base`.
fn alias_taken(raw: &[u8], base: &[u8]) -> u64 {
    let Some(tilde) = raw[..8].iter().position(|&c| c == b'~') else { return 0 };
    let digits = &raw[tilde + 1..8];
    let end = digits.iter().position(|&c| c == b' ').unwrap_or(digits.len());
    let digits = &digits[..end];
    let keep = base.len().min(tilde);
    if tilde != keep || raw[..tilde] != base[..keep] || digits.is_empty() {
        return 0;
    }
    let n = digits
        .iter()
        .try_fold(0u32, |n, &d| d.is_ascii_digit().then(|| n * 10 + u32::from(d - b'0')));
    match n {
        Some(n) if (1..=ALIAS_TRIES).contains(&n) => 1 << (n - 1),
        _ => 0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn aliases_are_upper_case_eight_three() {
        let (b, nb, e, ne) = alias_parts("xyz 20mm+cube.gcode");
        assert_eq!((&b[..nb], &e[..ne]), (&b"XYZ20M"[..], &b"GCO"[..]));
        assert_eq!(&alias(&b, nb, &e, 1), b"XYZ20M~1GCO");
        assert_eq!(&alias(&b, nb, &e, 12), b"XYZ20~12GCO");
        let (b, nb, e, ne) = alias_parts(".hidden");
        assert_eq!((&b[..nb], ne), (&b"HIDDEN"[..], 0));
        assert_eq!(alias_taken(b"XYZ20M~1GCO", b"XYZ20M"), 1);
        assert_eq!(alias_taken(b"XYZ20~12GCO", b"XYZ20M"), 1 << 11);
        assert_eq!(alias_taken(b"OTHER~1 GCO", b"XYZ20M"), 0);
        let _ = (e, ne);
    }

    #[test]
    fn names_a_card_cannot_hold_are_refused() {
        for ok in ["a", "cube.gcode", "My Part (v2).gcode", &"x".repeat(NAME_BYTES)] {
            assert!(valid_name(ok), "{ok}");
        }
        for bad in [
            "",
            ".",
            "..",
            "a/b",
            "what?",
            "trailing.",
            "trailing ",
            "caf\u{e9}",
            &"x".repeat(NAME_BYTES + 1),
        ] {
            assert!(!valid_name(bad), "{bad}");
        }
    }
}
