//! An STL file on the card, placed on the bed and sorted by its triangles' lowest z in
//! bounded RAM: how the printer prints an STL copied to its card (the slicer takes triangles
//! in zmin order).
//!
//! Three passes, each a bounded amount of work per [`StlSort::step`] (the main loop turns
//! between):
//! 1. **bounds**: the file through the STL reader; its bounds give the placement on the bed
//!    ([`Placement::on_bed`], as the host places a model);
//! 2. **runs**: the file again; each placed triangle, with its index in the file, into RAM
//!    ([`RUN_RECORDS`] at a time), sorted by (lowest z, index) and written as a run of
//!    [`RECORD_BYTES`]-byte records to a temporary file ([`RUNS_NAME`]);
//! 3. **merge**: the head of every run (up to [`MAX_RUNS`], in the RAM a run took, beside
//!    where each run goes on), the least taken in turn ([`StlSort::next`]).
//!
//! The order is the host's stable sort by lowest z: the same triangles in the same order as
//! `strata print` streams them. Binary STL only (an ASCII file is refused,
//! [`StlErrorKind::Ascii`](crate::stl::StlErrorKind::Ascii): parsing text floats would take
//! 20 KB of the board's flash). A model of more than `RUN_RECORDS * MAX_RUNS` triangles is
//! refused ([`SortError::TooManyTriangles`]: one merge pass only).

use crate::card::fat::{BlockWrite, FatError, File, Volume, BLOCK_BYTES};
use crate::card::write::{FileWriter, WriteBuffers};
use crate::geom::{Point3, Triangle};
use crate::machine::MachineConfig;
use crate::place::{Bounds, PlaceError, Placement};
use crate::stl::{StlError, StlReader};

/// Bytes of a run's record: the nine coordinates (um) and the index in the file, LE.
pub const RECORD_BYTES: usize = 40;
/// Triangles sorted in RAM at a time (a run: 8.6 KB).
pub const RUN_RECORDS: usize = 216;
/// Runs merged at once (their heads take the run's first places; where each goes on, 24
/// bytes, is kept beside).
pub const MAX_RUNS: usize = 72;
const _: () = assert!(MAX_RUNS <= RUN_RECORDS);
/// Blocks of the STL file read per [`StlSort::step`].
const BLOCKS_PER_STEP: usize = 4;
/// The temporary file of the runs (removed once merged: [`StlSort::remove_runs`]).
pub const RUNS_NAME: &str = "strata-sort.tmp";

/// Why the model cannot be sorted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SortError<E> {
    /// The card failed, or has no room for the runs.
    Card(FatError<E>),
    /// The file is not a readable STL.
    Stl(StlError),
    /// The model does not fit the bed (or has no triangles).
    Place(PlaceError),
    /// More triangles than one merge pass sorts (their count).
    TooManyTriangles(u32),
}

impl<E> From<FatError<E>> for SortError<E> {
    fn from(e: FatError<E>) -> Self {
        Self::Card(e)
    }
}

/// Where the sort stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Phase {
    /// Reading the bounds.
    Bounds,
    /// Writing the runs.
    Runs,
    /// The triangles come out in order ([`StlSort::next`]).
    Merge,
}

/// A triangle with its index in the file, as words: the nine coordinates (um), then the
/// index. Words, so that the records' RAM is also plain words once the merge needs only the
/// runs' heads ([`StlSort::spare_words`]). The sort key is (lowest z, index).
type Keyed = [i32; KEYED_WORDS];
/// Words of a [`Keyed`] triangle.
const KEYED_WORDS: usize = 10;
const _: () = assert!(KEYED_WORDS * 4 == RECORD_BYTES);
const NO_KEYED: Keyed = [0; KEYED_WORDS];

fn keyed(tri: &Triangle, index: u32) -> Keyed {
    let mut k = NO_KEYED;
    for (w, c) in k.iter_mut().zip(tri.v.iter().flat_map(|p| [p.x, p.y, p.z])) {
        *w = c;
    }
    k[KEYED_WORDS - 1] = index as i32;
    k
}

fn key(k: &Keyed) -> (i32, u32) {
    (k[2].min(k[5]).min(k[8]), k[KEYED_WORDS - 1] as u32)
}

fn keyed_triangle(k: &Keyed) -> Triangle {
    let p = |i: usize| Point3 { x: k[3 * i], y: k[3 * i + 1], z: k[3 * i + 2] };
    Triangle { v: [p(0), p(1), p(2)] }
}

fn encode(k: &Keyed) -> [u8; RECORD_BYTES] {
    let mut out = [0u8; RECORD_BYTES];
    for (chunk, w) in out.chunks_exact_mut(4).zip(k) {
        chunk.copy_from_slice(&w.to_le_bytes());
    }
    out
}

fn decode(b: &[u8; RECORD_BYTES]) -> Keyed {
    let mut k = NO_KEYED;
    for (w, chunk) in k.iter_mut().zip(b.chunks_exact(4)) {
        *w = i32::from_le_bytes([chunk[0], chunk[1], chunk[2], chunk[3]]);
    }
    k
}

/// Where a run being merged goes on: its next record, and how many are left (its head
/// included; 0: the run is done).
#[derive(Debug, Clone, Copy)]
struct RunCursor {
    at: File,
    left: u32,
}

const NO_CURSOR: RunCursor = RunCursor { at: File::EMPTY, left: 0 };

/// An STL file being placed and sorted (see the [module docs](self)); about 11.6 KB.
pub struct StlSort {
    /// The card's volume.
    pub volume: Volume,
    /// The STL file, at its start.
    stl: File,
    /// Where the pass reads it.
    at: File,
    reader: StlReader<false>,
    bounds: Bounds,
    placement: Placement,
    phase: Phase,
    /// Triangles of the model (known after the bounds), and read in the runs pass.
    triangles: u32,
    read: u32,
    /// The placed model's highest z, um.
    top_um: i32,
    /// Triangles in the run being filled; runs written.
    run_len: usize,
    runs: usize,
    runs_writer: FileWriter,
    /// The blocks the card's writers work in (the runs, then the output file).
    bufs: WriteBuffers,
    /// The output file, once the merge began ([`StlSort::create_output`]; a place holder
    /// before: no `Option`, whose empty value is not zero bytes).
    out: FileWriter,
    has_out: bool,
    /// The run being filled; in the merge, run `r`'s head at `r`.
    run: [Keyed; RUN_RECORDS],
    /// In the merge, where each run goes on.
    cursors: [RunCursor; MAX_RUNS],
}

impl StlSort {
    /// No sort, all zero bytes (a test checks it): cleared where it lives, then
    /// [`begin`](Self::begin).
    pub const EMPTY: Self = Self {
        volume: Volume::EMPTY,
        stl: File::EMPTY,
        at: File::EMPTY,
        reader: StlReader::binary_only(),
        bounds: Bounds { min: [0.0; 3], max: [0.0; 3] },
        placement: Placement { offset_mm: [0.0; 3] },
        phase: Phase::Bounds,
        triangles: 0,
        read: 0,
        top_um: 0,
        run_len: 0,
        runs: 0,
        runs_writer: FileWriter::PLACE_HOLDER,
        bufs: WriteBuffers::new(),
        out: FileWriter::PLACE_HOLDER,
        has_out: false,
        run: [NO_KEYED; RUN_RECORDS],
        cursors: [NO_CURSOR; MAX_RUNS],
    };

    /// Starts sorting `stl` on `volume`: its bounds are read first (the run's and the
    /// cursors' places are overwritten as they are used).
    pub fn begin(&mut self, volume: Volume, stl: File) {
        self.volume = volume;
        self.stl = stl;
        self.at = stl;
        self.reader = StlReader::binary_only();
        self.bounds = Bounds::EMPTY;
        self.phase = Phase::Bounds;
        self.triangles = 0;
        self.read = 0;
        self.top_um = 0;
        self.run_len = 0;
        self.runs = 0;
        self.runs_writer = FileWriter::PLACE_HOLDER;
        self.has_out = false;
    }

    /// Where the sort stands.
    pub fn phase(&self) -> Phase {
        self.phase
    }

    /// Triangles of the model (once the bounds are read).
    pub fn triangles(&self) -> u32 {
        self.triangles
    }

    /// The placed model's highest z, um (once the runs are written).
    pub fn top_um(&self) -> i32 {
        self.top_um
    }

    /// Does the next bounded part of the bounds and runs passes (`machine`: the bed the model
    /// is placed on); nothing in the merge.
    pub fn step<D: BlockWrite>(
        &mut self,
        dev: &mut D,
        machine: &MachineConfig,
    ) -> Result<Phase, SortError<D::Error>> {
        match self.phase {
            Phase::Bounds => self.bounds_step(dev, machine)?,
            Phase::Runs => self.runs_step(dev)?,
            Phase::Merge => {}
        }
        Ok(self.phase)
    }

    /// The next chunk of the STL file (to the end of its block) into `chunk`: its bytes (0 at
    /// the end).
    fn read_chunk<D: BlockWrite>(
        &mut self,
        dev: &mut D,
        chunk: &mut [u8; BLOCK_BYTES],
    ) -> Result<usize, SortError<D::Error>> {
        let len = BLOCK_BYTES - self.at.position() as usize % BLOCK_BYTES;
        Ok(self.at.read(&self.volume, dev, &mut chunk[..len])?)
    }

    fn bounds_step<D: BlockWrite>(
        &mut self,
        dev: &mut D,
        machine: &MachineConfig,
    ) -> Result<(), SortError<D::Error>> {
        let mut chunk = [0u8; BLOCK_BYTES];
        for _ in 0..BLOCKS_PER_STEP {
            let n = self.read_chunk(dev, &mut chunk)?;
            if n == 0 {
                self.reader.finish().map_err(SortError::Stl)?;
                self.placement =
                    Placement::on_bed(&self.bounds, machine).map_err(SortError::Place)?;
                if self.triangles as usize > RUN_RECORDS * MAX_RUNS {
                    return Err(SortError::TooManyTriangles(self.triangles));
                }
                self.at = self.stl;
                self.reader = StlReader::binary_only();
                self.runs_writer = self.volume.create(dev, &mut self.bufs, RUNS_NAME)?;
                self.phase = Phase::Runs;
                return Ok(());
            }
            let Self { reader, bounds, triangles, .. } = self;
            reader
                .feed(&chunk[..n], &mut |t| {
                    bounds.include(&t);
                    *triangles += 1;
                })
                .map_err(SortError::Stl)?;
        }
        Ok(())
    }

    fn runs_step<D: BlockWrite>(&mut self, dev: &mut D) -> Result<(), SortError<D::Error>> {
        let mut chunk = [0u8; BLOCK_BYTES];
        for _ in 0..BLOCKS_PER_STEP {
            let n = self.read_chunk(dev, &mut chunk)?;
            let Self { reader, placement, run, read, run_len, top_um, runs, .. } = self;
            let mut out = RunsOut {
                volume: &self.volume,
                writer: &mut self.runs_writer,
                bufs: &mut self.bufs,
                runs,
            };
            if n == 0 {
                reader.finish().map_err(SortError::Stl)?;
                out.write(dev, &mut run[..*run_len])?;
                *run_len = 0;
                return self.start_merge(dev);
            }
            let mut failed = Ok(());
            reader
                .feed(&chunk[..n], &mut |t| {
                    let tri = placement.apply(&t);
                    *top_um = (*top_um).max(tri.z_max());
                    run[*run_len] = keyed(&tri, *read);
                    *read += 1;
                    *run_len += 1;
                    // Every run but the last has RUN_RECORDS triangles.
                    if *run_len == RUN_RECORDS {
                        *run_len = 0;
                        if failed.is_ok() {
                            failed = out.write(dev, run);
                        }
                    }
                })
                .map_err(SortError::Stl)?;
            failed?;
        }
        Ok(())
    }

    /// The runs file closed and reopened, each run's head read.
    fn start_merge<D: BlockWrite>(&mut self, dev: &mut D) -> Result<(), SortError<D::Error>> {
        if self.runs > MAX_RUNS {
            return Err(SortError::TooManyTriangles(self.read));
        }
        let writer = core::mem::replace(&mut self.runs_writer, FileWriter::PLACE_HOLDER);
        writer.close(&self.volume, dev, &mut self.bufs)?;
        let mut at = self.volume.open(dev, RUNS_NAME)?;
        let total = self.read;
        let runs = self.runs;
        for (r, (head, cursor)) in self.run.iter_mut().zip(&mut self.cursors).take(runs).enumerate()
        {
            let left = (total - (r * RUN_RECORDS) as u32).min(RUN_RECORDS as u32);
            let mut next = at;
            at.skip(&self.volume, dev, left * RECORD_BYTES as u32)?;
            *head = read_record(&self.volume, dev, &mut next)?;
            *cursor = RunCursor { at: next, left };
        }
        self.phase = Phase::Merge;
        Ok(())
    }

    /// The next triangle in order (lowest z, then index in the file); `None` once all came.
    pub fn next<D: BlockWrite>(
        &mut self,
        dev: &mut D,
    ) -> Result<Option<Triangle>, SortError<D::Error>> {
        if self.phase != Phase::Merge {
            return Ok(None);
        }
        let live = self.run.iter().zip(&self.cursors).take(self.runs).enumerate();
        let Some((r, _)) = live.filter(|(_, (_, c))| c.left > 0).min_by_key(|(_, (h, _))| key(h))
        else {
            return Ok(None);
        };
        let tri = keyed_triangle(&self.run[r]);
        let cursor = &mut self.cursors[r];
        cursor.left -= 1;
        if cursor.left > 0 {
            self.run[r] = read_record(&self.volume, dev, &mut cursor.at)?;
        }
        Ok(Some(tri))
    }

    /// The record RAM the merge leaves free (the runs' heads take the first places), as
    /// words; none before the merge. Its user keeps what it needs there between calls.
    pub fn spare_words(&mut self) -> &mut [i32] {
        match self.phase {
            Phase::Merge => self.run[self.runs..].as_flattened_mut(),
            _ => &mut [],
        }
    }

    /// Removes the runs file (once merged and the output file is closed).
    pub fn remove_runs<D: BlockWrite>(&mut self, dev: &mut D) -> Result<(), SortError<D::Error>> {
        self.remove(dev, RUNS_NAME)
    }

    /// Removes the card's file `name` (through the sort's blocks: none on the stack).
    pub fn remove<D: BlockWrite>(
        &mut self,
        dev: &mut D,
        name: &str,
    ) -> Result<(), SortError<D::Error>> {
        Ok(self.volume.remove(dev, &mut self.bufs, name)?)
    }

    /// Creates the output file `name` (replacing one of that name): what the merge gives goes
    /// there ([`append_output`](Self::append_output)). Only once the runs are written (they
    /// share the writer's blocks).
    pub fn create_output<D: BlockWrite>(
        &mut self,
        dev: &mut D,
        name: &str,
    ) -> Result<(), SortError<D::Error>> {
        self.out = self.volume.create(dev, &mut self.bufs, name)?;
        self.has_out = true;
        Ok(())
    }

    /// Whether the output file was created.
    pub fn has_output(&self) -> bool {
        self.has_out
    }

    /// Appends `bytes` to the output file (none created: nothing is written).
    pub fn append_output<D: BlockWrite>(
        &mut self,
        dev: &mut D,
        bytes: &[u8],
    ) -> Result<(), SortError<D::Error>> {
        if self.has_out {
            self.out.append(&self.volume, dev, &mut self.bufs, bytes)?;
        }
        Ok(())
    }

    /// Closes the output file: its bytes.
    pub fn close_output<D: BlockWrite>(&mut self, dev: &mut D) -> Result<u32, SortError<D::Error>> {
        if !core::mem::take(&mut self.has_out) {
            return Ok(0);
        }
        let out = core::mem::replace(&mut self.out, FileWriter::PLACE_HOLDER);
        Ok(out.close(&self.volume, dev, &mut self.bufs)?)
    }
}

/// Where runs go: the runs file's writer and its blocks, and the count of runs written.
struct RunsOut<'a> {
    volume: &'a Volume,
    writer: &'a mut FileWriter,
    bufs: &'a mut WriteBuffers,
    runs: &'a mut usize,
}

impl RunsOut<'_> {
    /// `run`, sorted by (lowest z, index), onto the runs file (nothing when empty).
    fn write<D: BlockWrite>(
        &mut self,
        dev: &mut D,
        run: &mut [Keyed],
    ) -> Result<(), SortError<D::Error>> {
        if run.is_empty() {
            return Ok(());
        }
        heap_sort(run);
        for k in run.iter() {
            self.writer.append(self.volume, dev, self.bufs, &encode(k))?;
        }
        *self.runs += 1;
        Ok(())
    }
}

/// Sorts `run` by (lowest z, index) in place: a heap sort (a few hundred bytes of code;
/// `sort_unstable` takes 10 KB of the board's flash).
fn heap_sort(run: &mut [Keyed]) {
    // Moves the entry at `root` down the max-heap of the first `end` entries.
    fn sift(run: &mut [Keyed], mut root: usize, end: usize) {
        loop {
            let mut child = 2 * root + 1;
            if child >= end {
                return;
            }
            if child + 1 < end && key(&run[child + 1]) > key(&run[child]) {
                child += 1;
            }
            if key(&run[root]) >= key(&run[child]) {
                return;
            }
            run.swap(root, child);
            root = child;
        }
    }
    for root in (0..run.len() / 2).rev() {
        sift(run, root, run.len());
    }
    for end in (1..run.len()).rev() {
        run.swap(0, end);
        sift(run, 0, end);
    }
}

/// The record at `at`, which moves past it.
fn read_record<D: BlockWrite>(
    volume: &Volume,
    dev: &mut D,
    at: &mut File,
) -> Result<Keyed, FatError<D::Error>> {
    let mut b = [0u8; RECORD_BYTES];
    let n = at.read(volume, dev, &mut b)?;
    if n != RECORD_BYTES {
        // The runs file is shorter than its runs: changed under the sort.
        return Err(FatError::Corrupt { block: 0 });
    }
    Ok(decode(&b))
}
