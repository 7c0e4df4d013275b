//! Jobs from the printer's SD card: its listing, and G-code files printed with no host.
//!
//! A card request ([`Message::CardList`], [`Message::CardPrint`]) waits at the head of the
//! link until the board lends the card ([`Printer::card_service`], called beside
//! [`Printer::service`], not under it: the card's code and its read buffer stay off the
//! deepest stack, a layer's computation inside `service`). A listing answers with the
//! entries the send queue has room for and where it stopped; the host asks again from there
//! (the device keeps no listing state).
//!
//! A G-code file prints as a streamed G-code job does: the same reader, planner and steps,
//! its text read from the card up to a block at a time ([`CARD_CHUNK_BYTES`], a buffer on the
//! stack) once the move buffer has room for most of it. The open file lives in the scratch
//! the G-code job leaves free. Where the reader stops in a part (the move buffer is full, a
//! heater wait), the file moves on by what was read and the rest is read again later;
//! nothing is read while the reader waits. The job
//! needs no host: a dead link or a new host does not park it (there is nothing to resend).
//! A read that fails mid-print fails the job ([`CardFault::Removed`]): the heaters go off
//! with it.
//!
//! A model job written by the host ([`crate::protocol::job_file`]: the job start and triangle
//! batches it would stream) prints as it prints streamed. Its first record starts the job;
//! each next record goes into the link's receive queue while that is empty
//! ([`Endpoint::deliver_local`]), and [`Printer::service`] takes it there as it takes a
//! host's message: the layers are computed on their usual stack, not under the card's code.
//! The file stays at the record until the printer took it ([`CardRecords`], outside the
//! scratch, which the slicer has); a new host's session empties the receive queue, and the
//! record is read again (a batch taken in part resumes where it stopped). The volume is
//! mounted again for each record (a few block reads): keeping it would cost 40 bytes of RAM.

use super::{Failure, MotionAccess, Printer, Stages};
use crate::card::fat::{BlockWrite, FatError, File, Unsupported, Volume};
use crate::card::write::WriteBuffers;
use crate::card::zsort::{Phase, SortError, StlSort};
use crate::card::OpenFile;
use crate::card::WritingFile;
use crate::geom::Triangle;
use crate::machine::{MachineConfig, PrintSettings};
use crate::place::PlaceError;
use crate::protocol::job_file::{self, ReadError, MAGIC, RECORD_OVERHEAD};
use crate::protocol::msg::ty;
use crate::protocol::{
    job_fingerprint, CardEntry, CardFault, DeviceState, Endpoint, GcodeSpec, JobSpec, Message,
    MAX_PAYLOAD,
};
use crate::protocol::{BatchBuilder, JobOptions};
use crate::slice::{ActiveCount, SliceConfig, WordsFull};
use crate::slot::Slot;
use crate::stl::StlErrorKind;

/// Bytes of a card file read at a time at most (a buffer on the stack while it is read): a
/// block, so that each block of the file is read through once.
pub const CARD_CHUNK_BYTES: usize = crate::card::fat::BLOCK_BYTES;
/// A part is read only once the move buffer has this share of its bytes free (1/4), so
/// that the reader takes most of it: read too early, the reader would stop after a line
/// and the rest of the block be read again.
const CARD_READ_ROOM_DIV: usize = 4;
/// Parts of a card file read per [`Printer::card_service`] call at most (1 KB: the main loop
/// turns between them).
const CARD_CHUNKS_PER_CALL: usize = 4;
/// The job file an STL on the card is prepared into (replaced by the next one).
pub const STL_JOB_NAME: &str = "strata-stl.sjob";
/// Triangles of a batch of a prepared STL's job (at most 24 bytes each: a frame's payload).
const STL_BATCH: usize = 16;
/// Batches of a prepared STL's job written per [`Printer::card_service`] call.
const STL_BATCHES_PER_CALL: usize = 4;
/// Bytes of a binary STL's header and triangle count.
const STL_HEAD_BYTES: usize = 84;
/// Bytes of a binary STL triangle record.
const STL_RECORD_BYTES: u32 = 50;

/// Whether `payload` is a card request (handled by [`Printer::card_service`]).
pub fn is_card_request(payload: &[u8]) -> bool {
    matches!(
        payload.first(),
        Some(
            &(ty::CARD_LIST
                | ty::CARD_PRINT
                | ty::CARD_REMOVE
                | ty::CARD_CREATE
                | ty::CARD_DATA
                | ty::CARD_CLOSE)
        )
    )
}

/// What the card's reader error means to the user.
fn fault<E>(e: &FatError<E>) -> CardFault {
    match e {
        FatError::Device(_) => CardFault::Unreadable,
        FatError::NoVolume => CardFault::Unformatted,
        FatError::Unsupported(Unsupported::Fat12 | Unsupported::SectorBytes(_)) => {
            CardFault::Unsupported
        }
        FatError::Corrupt { .. } => CardFault::Damaged,
        FatError::NotFound => CardFault::NotFound,
        FatError::IsDirectory => CardFault::IsDirectory,
        FatError::Full | FatError::DirectoryFull => CardFault::Full,
        FatError::BadName => CardFault::BadName,
    }
}

/// What a file holds, from its first bytes and its size.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FileKind {
    /// A model job the host wrote ([`crate::protocol::job_file`]).
    Job,
    /// Text: G-code.
    Gcode,
    /// An STL, binary (its size matches its triangle count) or text (`solid`).
    Stl,
    /// Neither (binary data, or empty).
    Other,
}

/// What a file of `size` bytes whose first bytes are `head` (up to 84: a binary STL's header
/// and triangle count) holds.
pub fn file_kind(head: &[u8], size: u32) -> FileKind {
    if job_file::is_job_file(head) {
        return FileKind::Job;
    }
    if let Some(count) = head.get(80..STL_HEAD_BYTES) {
        let count = u32::from_le_bytes([count[0], count[1], count[2], count[3]]);
        let records = count.checked_mul(STL_RECORD_BYTES);
        if records.and_then(|r| r.checked_add(STL_HEAD_BYTES as u32)) == Some(size) {
            return FileKind::Stl;
        }
    }
    let text = head.trim_ascii_start();
    if text.starts_with(b"solid") {
        return FileKind::Stl;
    }
    // Text (G-code comments may hold UTF-8): no control bytes but tab, line feed, return.
    let is_text =
        head.iter().all(|&b| (b >= 0x20 && b != 0x7f) || matches!(b, b'\t' | b'\n' | b'\r'));
    if head.is_empty() || !is_text {
        return FileKind::Other;
    }
    FileKind::Gcode
}

/// Where a model job from the card stands in its file (see the [module docs](self)).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct CardRecords {
    /// The file, at the first record the printer has not passed.
    file: File,
    /// Where that record is.
    record: Record,
}

/// Where the file's next record is; its bytes (length, payload, CRC) once read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Record {
    /// Still on the card.
    OnCard,
    /// In the link's receive queue, waiting to be taken.
    InLink(u16),
    /// Taken by the printer: the file moves past it.
    Taken(u16),
}

/// A job file's magic and first record, the job start: the job and its fingerprint. Never
/// inlined: its record buffer is off the stack when the job starts.
#[inline(never)]
fn job_start<C: BlockWrite>(
    volume: &Volume,
    dev: &mut C,
    file: &mut File,
) -> Result<(JobSpec, u32), CardFault> {
    let mut magic = [0u8; MAGIC.len()];
    let n = file.read(volume, dev, &mut magic).map_err(|e| fault(&e))?;
    job_file::check_magic(&magic[..n]).map_err(|_| CardFault::BadJob)?;
    let mut payload = [0u8; MAX_PAYLOAD];
    let n = read_record(volume, dev, file, &mut payload)?;
    let Ok(Message::JobStart(job)) = Message::decode(&payload[..n]) else {
        return Err(CardFault::BadJob);
    };
    Ok((job, job_fingerprint(&payload[..n])))
}

/// The record of `payload` onto the sort's output file.
fn append_record<C: BlockWrite>(
    sort: &mut StlSort,
    dev: &mut C,
    payload: &[u8],
) -> Result<(), CardFault> {
    let mut rec = [0u8; MAX_PAYLOAD + RECORD_OVERHEAD];
    let n = job_file::encode_record(payload, &mut rec).ok_or(CardFault::BadJob)?;
    sort.append_output(dev, &rec[..n]).map_err(|e| sort_fault(&e))
}

/// The next bounded part of the sort's bounds and runs passes: where it stands. Never inlined:
/// its block buffer is off the stack of the job file's writing.
#[inline(never)]
fn sort_step<C: BlockWrite>(
    sort: &mut StlSort,
    dev: &mut C,
    machine: &MachineConfig,
) -> Result<Phase, CardFault> {
    sort.step(dev, machine).map_err(|e| sort_fault(&e))
}

/// `t`, the sort's next triangle, into the active set counted in the words the merge leaves
/// free; refused when the set grows beyond `capacity`. Never inlined: its frame (the job's
/// slicing) is off the stack when the job file is written.
#[inline(never)]
fn count_active(sort: &mut StlSort, t: &Triangle, capacity: u32) -> Result<(), CardFault> {
    // The job's slicing: default settings, the placed model's height.
    let slicing = SliceConfig::new(&PrintSettings::default(), sort.top_um())
        .map_err(|_| CardFault::TooLarge)?;
    let words = sort.spare_words();
    let holds = words.len() as u32;
    match ActiveCount::resume(words).push(&slicing, t) {
        Ok(n) if n > capacity => Err(CardFault::TooComplex),
        // More active triangles than the words hold: refused when that is more than the
        // slicer holds too (else, a printer of a larger slicer, the slicer's own check stands).
        Err(WordsFull) if holds > capacity => Err(CardFault::TooComplex),
        _ => Ok(()),
    }
}

/// What the sort's error means to the user.
fn sort_fault<E>(e: &SortError<E>) -> CardFault {
    match e {
        SortError::Card(e) => fault(e),
        SortError::Stl(e) if e.kind == StlErrorKind::Ascii => CardFault::AsciiStl,
        SortError::Stl(_) | SortError::Place(PlaceError::EmptyModel) => CardFault::BadStl,
        SortError::Place(_) => CardFault::TooLarge,
        SortError::TooManyTriangles(_) => CardFault::TooManyTriangles,
    }
}

/// Reads the record at `file` (its payload into `payload`: its bytes), its CRC checked.
fn read_record<C: BlockWrite>(
    volume: &Volume,
    dev: &mut C,
    file: &mut File,
    payload: &mut [u8; MAX_PAYLOAD],
) -> Result<usize, CardFault> {
    job_file::read_record(|out| file.read(volume, dev, out), payload).map_err(|e| match e {
        ReadError::File(_) => CardFault::BadJob,
        ReadError::Device(_) => CardFault::Removed,
    })
}

/// The outcome of a card request, once its message is no longer borrowed.
enum Request {
    List {
        from: u16,
    },
    /// A print started (its file's bytes), begun (an STL being sorted: answered once it
    /// starts), or refused.
    Print(Result<Option<u32>, CardFault>),
    /// A removal, or a file closed (its bytes).
    Done(Result<u32, CardFault>),
    /// A file created, or bytes written: no answer unless it failed.
    Written(Result<(), CardFault>),
    Undecodable(u8),
}

impl<Pl: Stages, const MOVE_BYTES: usize, const P: usize> Printer<Pl, MOVE_BYTES, P> {
    /// Whether the card is wanted now: a card request heads the link, or a job from the card
    /// reads its file. (A board starts its card only then.)
    pub fn wants_card<const TX: usize, const RX: usize>(&self, ep: &Endpoint<TX, RX>) -> bool {
        ep.peek().is_some_and(is_card_request) || self.card_reading() || self.preparing
    }

    /// A job from the card reads its file.
    fn card_reading(&self) -> bool {
        self.card_job && self.is_active() && !self.model_ended
    }

    /// The card's part of the link and of a job from the card: a card request at the head
    /// of the link is answered (`card`: the board's card, `None` when the slot is empty), and
    /// a job printing from the card reads its next parts. Call it beside
    /// [`service`](Self::service) every turn (a card request waits for it).
    #[inline(never)]
    pub fn card_service<C: BlockWrite, const TX: usize, const RX: usize, const Q: usize>(
        &mut self,
        ep: &mut Endpoint<TX, RX>,
        mut card: Option<&mut C>,
        motion: &mut impl MotionAccess<MOVE_BYTES, P, Q>,
    ) {
        if ep.tx_free() > 1 {
            if let Some(request) = self.card_request(ep, card.as_deref_mut(), motion) {
                // A job just started reads its file from the next call on: the board sees
                // the new job (clears its step queue, homes) before its first move.
                let started = matches!(request, Request::Print(Ok(_)));
                match request {
                    Request::List { from } => self.card_list(ep, card.as_deref_mut(), from),
                    Request::Print(Ok(Some(bytes))) => {
                        super::send(ep, &Message::CardStarted { bytes });
                    }
                    Request::Print(Ok(None)) => {}
                    Request::Print(Err(f)) | Request::Done(Err(f)) | Request::Written(Err(f)) => {
                        super::send(ep, &Message::CardRefused(f));
                    }
                    Request::Done(Ok(bytes)) => {
                        super::send(ep, &Message::CardDone { bytes });
                    }
                    Request::Written(Ok(())) => {}
                    Request::Undecodable(first_byte) => {
                        self.fail(Failure::BadMessage { first_byte })
                    }
                }
                ep.pop();
                if started {
                    return;
                }
            }
        }
        if self.preparing {
            self.prepare_stl(ep, card, motion);
        } else if self.gcode_job {
            self.feed_from_card(card, motion);
        } else {
            self.feed_records(ep, card);
        }
    }

    /// The card request at the head of the link, decoded (a print started or refused).
    fn card_request<C: BlockWrite, const TX: usize, const RX: usize, const Q: usize>(
        &mut self,
        ep: &Endpoint<TX, RX>,
        card: Option<&mut C>,
        motion: &mut impl MotionAccess<MOVE_BYTES, P, Q>,
    ) -> Option<Request> {
        let p = ep.peek().filter(|p| is_card_request(p))?;
        Some(match Message::decode(p) {
            Ok(Message::CardList { from }) => Request::List { from },
            Ok(Message::CardPrint(name)) => {
                let fingerprint = job_fingerprint(p);
                Request::Print(self.card_print(name, card, motion, fingerprint))
            }
            Ok(Message::CardRemove(name)) => Request::Done(self.card_remove(name, card)),
            Ok(Message::CardCreate(name)) => Request::Written(self.card_create(name, card)),
            Ok(Message::CardData(bytes)) => Request::Written(self.card_append(bytes, card)),
            Ok(Message::CardClose) => Request::Done(self.card_close(card)),
            _ => Request::Undecodable(p[0]),
        })
    }

    /// The root directory's entries from the `from`-th, as many as the send queue takes with
    /// room for the closing [`Message::CardListed`].
    fn card_list<C: BlockWrite, const TX: usize, const RX: usize>(
        &mut self,
        ep: &mut Endpoint<TX, RX>,
        card: Option<&mut C>,
        from: u16,
    ) {
        let Some(dev) = card else {
            super::send(ep, &Message::CardRefused(CardFault::Absent));
            return;
        };
        let vol = match Volume::mount(dev) {
            Ok(v) => v,
            Err(e) => {
                super::send(ep, &Message::CardRefused(fault(&e)));
                return;
            }
        };
        let mut dir = vol.root();
        let mut index = 0u16;
        loop {
            let entry = match dir.next(&vol, dev) {
                Ok(Some(e)) => e,
                Ok(None) => break,
                Err(e) => {
                    super::send(ep, &Message::CardRefused(fault(&e)));
                    return;
                }
            };
            if index >= from {
                // Entries are counted in 16 bits: a listing ends at the 65,535th (`from` is
                // at most that, so the count never goes past it).
                if index == u16::MAX {
                    break;
                }
                // Room for this entry and the closing message (`card_service` starts with
                // both: an answer holds an entry at least).
                if ep.tx_free() < 2 {
                    super::send(ep, &Message::CardListed { next: index, done: false });
                    return;
                }
                let name = entry.name();
                let e = CardEntry { size: entry.size, is_dir: entry.is_dir, name };
                super::send(ep, &Message::CardEntry(e));
            }
            index += 1;
        }
        super::send(ep, &Message::CardListed { next: index, done: true });
    }

    /// The card and its volume, for a request that needs the printer idle (a job may read or
    /// hold the card's files).
    fn idle_volume<'c, C: BlockWrite>(
        &self,
        card: Option<&'c mut C>,
    ) -> Result<(&'c mut C, Volume), CardFault> {
        if self.is_active() || self.preparing {
            return Err(CardFault::Busy);
        }
        let dev = card.ok_or(CardFault::Absent)?;
        let volume = Volume::mount(dev).map_err(|e| fault(&e))?;
        Ok((dev, volume))
    }

    /// Starts printing the card's file `name` (its bytes), or says why not.
    fn card_print<C: BlockWrite, const Q: usize>(
        &mut self,
        name: &str,
        card: Option<&mut C>,
        motion: &mut impl MotionAccess<MOVE_BYTES, P, Q>,
        fingerprint: u32,
    ) -> Result<Option<u32>, CardFault> {
        let (dev, volume) = self.idle_volume(card)?;
        let file = volume.open(dev, name).map_err(|e| fault(&e))?;
        let mut head = [0u8; STL_HEAD_BYTES];
        let mut peek = file;
        let n = peek.read(&volume, dev, &mut head).map_err(|e| fault(&e))?;
        match file_kind(&head[..n], file.size()) {
            FileKind::Gcode => {}
            FileKind::Job => return self.card_print_job(&volume, dev, file, motion).map(Some),
            FileKind::Stl => {
                // The scratch sorts it (a file being written to the card is abandoned).
                self.uploading = false;
                self.pipeline.start_stl(volume, file);
                self.preparing = true;
                return Ok(None);
            }
            FileKind::Other => return Err(CardFault::NotPrintable),
        }
        let spec = GcodeSpec { bytes: file.size(), layers: 0 };
        self.start_gcode(&spec, Some(OpenFile { volume, file }), motion);
        self.card_job = true;
        self.fingerprint = fingerprint;
        let (allowed, flush) = self.motion_gate();
        motion.gate(allowed, flush);
        Ok(Some(spec.bytes))
    }

    /// Starts the model job of a job file from its first record (the job start): the records
    /// after it go through the link's receive queue ([`feed_records`](Self::feed_records)).
    #[inline(never)]
    fn card_print_job<C: BlockWrite, const Q: usize>(
        &mut self,
        volume: &Volume,
        dev: &mut C,
        mut file: File,
        motion: &mut impl MotionAccess<MOVE_BYTES, P, Q>,
    ) -> Result<u32, CardFault> {
        let (job, fingerprint) = job_start(volume, dev, &mut file)?;
        self.start(&job, motion);
        self.card_job = true;
        self.fingerprint = fingerprint;
        self.card_records = Slot::Full(CardRecords { file, record: Record::OnCard });
        Ok(file.size())
    }

    /// Removes the card's file `name` (no job may run: a job's own file could go).
    #[inline(never)]
    fn card_remove<C: BlockWrite>(
        &mut self,
        name: &str,
        card: Option<&mut C>,
    ) -> Result<u32, CardFault> {
        let (dev, volume) = self.idle_volume(card)?;
        let mut bufs = WriteBuffers::new();
        volume.remove(dev, &mut bufs, name).map_err(|e| fault(&e))?;
        Ok(0)
    }

    /// Creates the card's file `name`, empty: the upload takes the scratch (no job may run).
    #[inline(never)]
    fn card_create<C: BlockWrite>(
        &mut self,
        name: &str,
        card: Option<&mut C>,
    ) -> Result<(), CardFault> {
        let (dev, volume) = self.idle_volume(card)?;
        let empty = crate::card::write::FileWriter::EMPTY;
        self.pipeline.start_upload(WritingFile {
            volume,
            writer: empty,
            bufs: WriteBuffers::new(),
        });
        let up = self.pipeline.upload().ok_or(CardFault::NoUpload)?;
        match volume.create(dev, &mut up.bufs, name) {
            Ok(w) => {
                up.writer = w;
                self.uploading = true;
                Ok(())
            }
            Err(e) => Err(fault(&e)),
        }
    }

    /// The next bytes of the file being written; a failure ends the upload (the bytes that
    /// follow are dropped unanswered: the host heard of it).
    #[inline(never)]
    fn card_append<C: BlockWrite>(
        &mut self,
        bytes: &[u8],
        card: Option<&mut C>,
    ) -> Result<(), CardFault> {
        if !self.uploading {
            return Ok(());
        }
        let r = match (self.pipeline.upload(), card) {
            (Some(up), Some(dev)) => {
                up.writer.append(&up.volume, dev, &mut up.bufs, bytes).map_err(|e| fault(&e))
            }
            (None, _) => Err(CardFault::NoUpload),
            (_, None) => Err(CardFault::Absent),
        };
        self.uploading &= r.is_ok();
        r
    }

    /// The file being written is complete: its bytes.
    #[inline(never)]
    fn card_close<C: BlockWrite>(&mut self, card: Option<&mut C>) -> Result<u32, CardFault> {
        let uploading = core::mem::take(&mut self.uploading);
        match (self.pipeline.upload().filter(|_| uploading), card) {
            (Some(up), Some(dev)) => {
                up.writer.close(&up.volume, dev, &mut up.bufs).map_err(|e| fault(&e))
            }
            (None, _) => Err(CardFault::NoUpload),
            (_, None) => Err(CardFault::Absent),
        }
    }

    /// A job from the card reads its next parts while its reader takes them (see the
    /// [module docs](self)).
    fn feed_from_card<C: BlockWrite, const Q: usize>(
        &mut self,
        mut card: Option<&mut C>,
        motion: &mut impl MotionAccess<MOVE_BYTES, P, Q>,
    ) {
        for _ in 0..CARD_CHUNKS_PER_CALL {
            // What the reader holds goes first: nothing is read while it waits.
            if !self.card_reading() || self.take_gcode(&[], false, motion) == super::Accept::Busy {
                return;
            }
            let room = motion.with(|m, _| m.moves().free_bytes() * CARD_READ_ROOM_DIV);
            if room < MOVE_BYTES {
                return;
            }
            let (Some(open), Some(dev)) = (self.pipeline.card_file().copied(), card.as_deref_mut())
            else {
                return self.card_failed(motion);
            };
            let mut ahead = open;
            let mut chunk = [0u8; CARD_CHUNK_BYTES];
            // To the end of the block the file is in.
            let len = CARD_CHUNK_BYTES - ahead.file.position() as usize % CARD_CHUNK_BYTES;
            let Ok(n) = ahead.file.read(&ahead.volume, dev, &mut chunk[..len]) else {
                return self.card_failed(motion);
            };
            let end = ahead.file.position() == ahead.file.size();
            let accept = self.take_gcode(&chunk[..n], end, motion);
            if accept == super::Accept::Busy {
                // The file moves on by what was read; the rest is read again.
                ahead = open;
                let read = core::mem::take(&mut self.batch_pos);
                if ahead.file.skip(&ahead.volume, dev, read).is_err() {
                    return self.card_failed(motion);
                }
            }
            if let Some(f) = self.pipeline.card_file() {
                *f = ahead;
            }
            let (allowed, flush) = self.motion_gate();
            motion.gate(allowed, flush);
            if accept == super::Accept::Busy || end {
                return;
            }
        }
    }

    /// A model job from the card: the record the printer took is passed, and the next goes
    /// into the link's receive queue once that is empty (see the [module docs](self)).
    #[inline(never)]
    fn feed_records<C: BlockWrite, const TX: usize, const RX: usize>(
        &mut self,
        ep: &mut Endpoint<TX, RX>,
        card: Option<&mut C>,
    ) {
        let reading = self.card_reading();
        let Some(at) = self.card_records.get_mut() else { return };
        if matches!(at.record, Record::InLink(_)) || !reading || ep.rx_len() > 0 {
            return;
        }
        let Some(dev) = card else { return self.fail(Failure::Card(CardFault::Removed)) };
        let mut records = *at;
        let r = (|| {
            let volume = Volume::mount(dev).map_err(|_| CardFault::Removed)?;
            if let Record::Taken(bytes) = records.record {
                records
                    .file
                    .skip(&volume, dev, u32::from(bytes))
                    .map_err(|_| CardFault::Removed)?;
                records.record = Record::OnCard;
            }
            let mut ahead = records.file;
            let mut payload = [0u8; MAX_PAYLOAD];
            let n = read_record(&volume, dev, &mut ahead, &mut payload)?;
            // Only the model's triangles and its end come after the job start.
            if !matches!(payload[0], ty::TRIANGLES | ty::END_OF_MODEL) {
                return Err(CardFault::BadJob);
            }
            ep.deliver_local(&payload[..n]).map_err(|_| CardFault::Busy)?;
            records.record = Record::InLink((n + RECORD_OVERHEAD) as u16);
            Ok(())
        })();
        self.card_records = Slot::Full(records);
        if let Err(f) = r {
            self.fail(Failure::Card(f));
        }
    }

    /// An STL on the card being placed and sorted for a print: the next bounded part of its
    /// passes, then of its job file ([`STL_JOB_NAME`]: the job start, batches of
    /// [`STL_BATCH`] triangles in order, the end), which then prints as a job file does; the
    /// request is answered then, or refused in words.
    #[inline(never)]
    fn prepare_stl<C: BlockWrite, const TX: usize, const RX: usize, const Q: usize>(
        &mut self,
        ep: &mut Endpoint<TX, RX>,
        card: Option<&mut C>,
        motion: &mut impl MotionAccess<MOVE_BYTES, P, Q>,
    ) {
        let Some(dev) = card else {
            self.preparing = false;
            super::send(ep, &Message::CardRefused(CardFault::Absent));
            return;
        };
        let machine = self.machine;
        let sorted = match self.pipeline.stl() {
            Some(sort) => sort_step(sort, dev, &machine).map(|phase| phase == Phase::Merge),
            None => Err(CardFault::NoUpload),
        };
        let step = match sorted {
            Ok(true) => self.stl_job_step(dev, motion),
            Ok(false) => Ok(None),
            Err(f) => Err(f),
        };
        match step {
            Ok(None) => {}
            Ok(Some(bytes)) => {
                self.preparing = false;
                super::send(ep, &Message::CardStarted { bytes });
            }
            Err(f) => {
                self.preparing = false;
                // What the sort wrote is of no use now (a card that failed may refuse this).
                if let Some(sort) = self.pipeline.stl() {
                    let _ = sort.close_output(dev);
                    let _ = sort.remove(dev, STL_JOB_NAME);
                    let _ = sort.remove_runs(dev);
                }
                super::send(ep, &Message::CardRefused(f));
            }
        }
    }

    /// One bounded part of the sorted STL's job file; the job file's bytes once its job
    /// started. Never inlined: its buffers are off the stack of the sort's passes.
    #[inline(never)]
    fn stl_job_step<C: BlockWrite, const Q: usize>(
        &mut self,
        dev: &mut C,
        motion: &mut impl MotionAccess<MOVE_BYTES, P, Q>,
    ) -> Result<Option<u32>, CardFault> {
        // A layer's active triangles bound its cut segments: the two capacities' smaller one
        // (on the boards they are equal; a larger segment capacity would refuse a model that
        // cuts fewer segments than it crosses triangles, which the host's admission takes).
        let caps = Self::CAPACITIES;
        let active_capacity = caps.active_triangles.min(caps.contour_points);
        let sort = self.pipeline.stl().ok_or(CardFault::NoUpload)?;
        let mut payload = [0u8; MAX_PAYLOAD];
        let mut message = |sort: &mut StlSort, dev: &mut C, m: &Message<'_>| {
            let n = m.encode(&mut payload).map_err(|_| CardFault::BadJob)?;
            append_record(sort, dev, &payload[..n])
        };
        if !sort.has_output() {
            sort.create_output(dev, STL_JOB_NAME).map_err(|e| sort_fault(&e))?;
            sort.append_output(dev, &MAGIC).map_err(|e| sort_fault(&e))?;
            let job = JobSpec {
                settings: PrintSettings::default(),
                options: JobOptions::default(),
                model_height_um: sort.top_um(),
                triangles: sort.triangles(),
            };
            message(sort, dev, &Message::JobStart(job))?;
            ActiveCount::start(sort.spare_words());
        }
        for _ in 0..STL_BATCHES_PER_CALL {
            let mut batch = BatchBuilder::new();
            for _ in 0..STL_BATCH {
                let Some(t) = sort.next(dev).map_err(|e| sort_fault(&e))? else { break };
                count_active(sort, &t, active_capacity)?;
                // Within the wire's range: the model is on the bed.
                batch.push(&t).map_err(|_| CardFault::TooLarge)?;
            }
            if batch.is_empty() {
                message(sort, dev, &Message::EndOfModel)?;
                sort.close_output(dev).map_err(|e| sort_fault(&e))?;
                sort.remove_runs(dev).map_err(|e| sort_fault(&e))?;
                let volume = sort.volume;
                let file = volume.open(dev, STL_JOB_NAME).map_err(|e| fault(&e))?;
                return self.card_print_job(&volume, dev, file, motion).map(Some);
            }
            append_record(sort, dev, batch.payload())?;
        }
        Ok(None)
    }

    /// The record at the head of the link's receive queue is from the card (it is taken or
    /// dropped now).
    pub(super) fn card_record_at_head(&self) -> bool {
        self.card_records.get().is_some_and(|r| matches!(r.record, Record::InLink(_)))
    }

    /// The message at the head of the link's receive queue is taken: a card record is passed.
    pub(super) fn head_taken(&mut self) {
        if let Some(r) = self.card_records.get_mut() {
            if let Record::InLink(bytes) = r.record {
                r.record = Record::Taken(bytes);
            }
        }
    }

    /// A new session emptied the link's receive queue: a card record that waited there is
    /// read again (true: a batch taken in part resumes where it stopped).
    pub(super) fn card_record_lost(&mut self) -> bool {
        let Some(r) = self.card_records.get_mut() else { return false };
        let lost = matches!(r.record, Record::InLink(_));
        if lost {
            r.record = Record::OnCard;
        }
        lost
    }

    /// The card failed under a job printing from it: the job fails, its moves dropped.
    #[inline(never)]
    fn card_failed<const Q: usize>(&mut self, motion: &mut impl MotionAccess<MOVE_BYTES, P, Q>) {
        if self.state == DeviceState::Printing || self.state == DeviceState::Paused {
            self.fail(Failure::Card(CardFault::Removed));
            motion.with(|m, _| m.moves_mut().clear());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn files_are_told_apart_by_their_first_bytes() {
        let mut binary = [0u8; STL_HEAD_BYTES];
        binary[80] = 2;
        assert_eq!(file_kind(&binary, 84 + 2 * 50), FileKind::Stl);
        assert_eq!(file_kind(&binary, 84 + 3 * 50), FileKind::Other);
        assert_eq!(file_kind(b"  solid cube\n facet normal", 1000), FileKind::Stl);
        assert_eq!(file_kind(b"; generated by PrusaSlicer\nG28\nG1 X1", 1000), FileKind::Gcode);
        assert_eq!(file_kind(b"G1 X1 ; caf\xc3\xa9\r\n", 1000), FileKind::Gcode);
        assert_eq!(file_kind(b"", 0), FileKind::Other);
        assert_eq!(file_kind(b"PK\x03\x04", 1000), FileKind::Other);
    }
}
