//! The host side of a print job over a protocol [`Endpoint`], independent of the transport (serial
//! port or the in-memory simulated link).
//!
//! Hello, capacities, job start, triangle batches as fast as the device's credits allow, end of
//! model, then status until done.

use strata::geom::Triangle;
use strata::protocol::frame::wire_len;
use strata::protocol::{
    job_fingerprint, BatchBuilder, Capacities, CardFault, DeviceState, Endpoint, ErrorCode,
    GcodeSpec, JobReport, JobSpec, LinkError, Message, ParkedJob, Status, MAX_PAYLOAD, VERSION,
};
use strata::thermal::ThermalFault;

/// Host endpoint: 8 frames in flight, 8 receive slots.
pub type HostEndpoint = Endpoint<8, 8>;

/// Where the job stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Phase {
    /// Hello sent, waiting for the capacities.
    Hello,
    /// Streaming triangles.
    Streaming,
    /// Every triangle and the end of model sent; waiting for the device to finish.
    Printing,
    /// The device reported the job done.
    Done,
}

/// Progress and results of a job.
#[derive(Debug, Clone, Default)]
pub struct Progress {
    /// Triangles handed to the link.
    pub triangles_sent: usize,
    /// Bytes of G-code text handed to the link.
    pub gcode_bytes_sent: usize,
    /// Wire bytes of the triangle frames (first transmission).
    pub triangle_wire_bytes: u64,
    /// Device capacities, once known.
    pub capacities: Option<Capacities>,
    /// Last status.
    pub status: Option<Status>,
    /// Layer hashes in layer order (index = layer).
    pub layer_hashes: Vec<u64>,
    /// The device's totals, once it reported the job done.
    pub job_report: Option<JobReport>,
    /// Time the end of model was acknowledged, ms.
    pub stream_done_ms: Option<u32>,
    /// Why the job failed, in the failing stage's words (`Message::Failure`).
    pub failure: Option<String>,
    /// The device holds a job parked when its host went silent (`Message::Parked`).
    pub parked: Option<ParkedJob>,
    /// Bytes of the card file the device began printing (`Message::CardStarted`).
    pub card_file_bytes: Option<u32>,
}

/// What a job sends.
#[derive(Debug, Clone, Copy)]
pub enum Source<'a> {
    /// A model: placed triangles, sorted by lowest z, sliced on the device with these settings.
    Model(&'a [Triangle], JobSpec),
    /// G-code text, run as it is.
    Gcode(&'a [u8], GcodeSpec),
    /// The printer's card's file of this name, printed from the card (nothing streams).
    Card {
        /// The file's name on the card.
        name: &'a str,
        /// The host's part ends once the job started (the printer needs no host for it).
        detach: bool,
    },
}

/// The host side of one job.
pub struct HostJob<'a> {
    source: Source<'a>,
    phase: Phase,
    next: usize,
    batch: BatchBuilder,
    end_queued: bool,
    hello_sent: bool,
    abort: bool,
    abort_sent: bool,
    /// The job resumes one the device parked when its host went silent.
    resume: bool,
    /// What the host has seen.
    pub progress: Progress,
    /// Every payload sent, in order (for the lossy-link tests' delivery check).
    pub sent_log: Option<Vec<Vec<u8>>>,
}

impl<'a> HostJob<'a> {
    /// A job streaming `tris` (placed, sorted by lowest z) with `job`.
    pub fn new(tris: &'a [Triangle], job: JobSpec) -> Self {
        Self::of(Source::Model(tris, job))
    }

    /// A job sending `source`.
    pub fn of(source: Source<'a>) -> Self {
        Self {
            source,
            phase: Phase::Hello,
            next: 0,
            batch: BatchBuilder::new(),
            end_queued: false,
            hello_sent: false,
            abort: false,
            abort_sent: false,
            resume: false,
            progress: Progress::default(),
            sent_log: None,
        }
    }

    /// A job on a link whose hello was already answered (see [`handshake`]).
    pub fn after_hello(source: Source<'a>, greeting: &Greeting) -> Self {
        let mut j = Self::of(source);
        j.hello_sent = true;
        j.progress.capacities = Some(greeting.capacities);
        j.progress.status = Some(greeting.status);
        j.progress.parked = greeting.parked;
        j
    }

    /// The same job resumed: the device parked it when its host went silent; this host sends
    /// the triangles after the ones it took (see [`Message::Parked`]), once it checked that
    /// the parked job is this one.
    pub fn resuming(mut self) -> Self {
        self.resume = true;
        self
    }

    /// Current phase.
    pub fn phase(&self) -> Phase {
        self.phase
    }

    /// Asks the device to abort (sent on the next poll).
    pub fn abort(&mut self) {
        self.abort = true;
    }

    fn send(&mut self, ep: &mut HostEndpoint, payload: &[u8]) -> bool {
        if ep.send(payload).is_err() {
            return false;
        }
        if let Some(log) = &mut self.sent_log {
            log.push(payload.to_vec());
        }
        true
    }

    fn send_msg(&mut self, ep: &mut HostEndpoint, m: &Message<'_>) -> bool {
        let mut buf = [0u8; MAX_PAYLOAD];
        let n = m.encode(&mut buf).expect("control messages fit a frame");
        self.send(ep, &buf[..n])
    }

    /// Handles what arrived and queues what can go out. `Err` ends the job with a message
    /// for the user.
    pub fn poll(&mut self, now_ms: u32, ep: &mut HostEndpoint) -> Result<Phase, String> {
        if let Err(LinkError::Dead { silent_ms }) = ep.check(now_ms) {
            let sent = match self.source {
                Source::Model(tris, _) => {
                    format!("{} of {} triangles sent", self.progress.triangles_sent, tris.len())
                }
                Source::Gcode(text, _) => {
                    format!("{} of {} bytes sent", self.progress.gcode_bytes_sent, text.len())
                }
                Source::Card { name, .. } => format!("printing {name} from the card"),
            };
            return Err(format!(
                "the printer stopped answering: no valid frame for {:.1} s (link dead); {sent}",
                silent_ms as f64 / 1000.0,
            ));
        }
        while let Some(p) = ep.peek() {
            let m = Message::decode(p).map_err(|e| format!("the printer sent a bad message: {e}"));
            let m = m?;
            match m {
                Message::Capabilities { version, capacities } => {
                    if version != VERSION {
                        return Err(format!(
                            "the printer speaks protocol version {version}, this host {VERSION}"
                        ));
                    }
                    self.progress.capacities = Some(capacities);
                }
                Message::LayerDone { layer, hash } => {
                    let l = layer as usize;
                    if self.progress.layer_hashes.len() <= l {
                        self.progress.layer_hashes.resize(l + 1, 0);
                    }
                    self.progress.layer_hashes[l] = hash;
                }
                Message::JobReport(j) => self.progress.job_report = Some(j),
                Message::Parked(p) => self.progress.parked = Some(p),
                Message::CardRefused(fault) => {
                    // Taken: the next job on this link does not hear it again.
                    ep.pop();
                    return Err(format!("card: {fault}"));
                }
                // The statuses after it are the card job's.
                Message::CardStarted { bytes } if self.phase == Phase::Streaming => {
                    let detach = matches!(self.source, Source::Card { detach: true, .. });
                    self.phase = if detach { Phase::Done } else { Phase::Printing };
                    self.progress.stream_done_ms = Some(now_ms);
                    self.progress.card_file_bytes = Some(bytes);
                }
                Message::Failure(text) => self.progress.failure = Some(text.to_string()),
                Message::Status(s) => {
                    self.progress.status = Some(s);
                    match s.state {
                        DeviceState::Done if self.phase == Phase::Printing => {
                            self.phase = Phase::Done
                        }
                        DeviceState::Failed => {
                            let text = describe_failure(&s, self.progress.failure.as_deref());
                            return Err(match self.source {
                                Source::Card { name, .. } => with_card_stl_hint(text, name, &s),
                                _ => text,
                            });
                        }
                        DeviceState::Aborted if self.phase != Phase::Hello => {
                            return Err("the job was aborted".into())
                        }
                        DeviceState::Stopped => {
                            return Err("the printer is in emergency stop".into())
                        }
                        _ => {}
                    }
                }
                _ => {}
            }
            ep.pop();
        }
        if self.abort && !self.abort_sent {
            self.abort_sent = self.send_msg(ep, &Message::Abort);
            return Ok(self.phase);
        }
        if !self.hello_sent {
            self.hello_sent = self.send_msg(ep, &Message::Hello { version: VERSION });
        }
        if self.phase == Phase::Hello && self.progress.capacities.is_some() {
            self.begin(ep)?;
        }
        if let Source::Gcode(text, _) = self.source {
            self.stream_text(text, ep);
        } else if let Source::Model(tris, _) = self.source {
            self.stream_triangles(tris, ep)?;
        }
        if self.end_queued && self.phase == Phase::Streaming && ep.all_acked() {
            self.phase = Phase::Printing;
            self.progress.stream_done_ms = Some(now_ms);
        }
        Ok(self.phase)
    }

    /// Starts the job once the device's first status came (a device answers a hello with
    /// its capacities and a status): a new job on a device without one, or the parked job
    /// resumed.
    fn begin(&mut self, ep: &mut HostEndpoint) -> Result<(), String> {
        let Some(status) = self.progress.status else { return Ok(()) };
        let orphaned = status.error == ErrorCode::LinkDead;
        let start = match self.source {
            Source::Model(_, job) => Message::JobStart(job),
            Source::Gcode(_, spec) => Message::GcodeStart(spec),
            Source::Card { name, .. } => Message::CardPrint(name),
        };
        if self.resume && matches!(self.source, Source::Card { .. }) {
            return Err("a job from the card needs no host: there is nothing to resume".into());
        }
        if !self.resume {
            if matches!(status.state, DeviceState::Printing | DeviceState::Paused) && !orphaned {
                return Err(format!(
                    "the printer is busy: it is {} layer {} of {} of another job",
                    state_words(status.state),
                    status.layer,
                    status.layers
                ));
            }
            if orphaned {
                return Err(format!(
                    "the printer holds a job it parked at layer {} when its host went silent: \
                     resume it with the same model and settings and `--resume`, or abort it",
                    status.layer
                ));
            }
            if self.send_msg(ep, &start) {
                self.phase = Phase::Streaming;
            }
            return Ok(());
        }
        if !orphaned {
            return Err(format!(
                "the printer holds no parked job to resume (it is {})",
                state_words(status.state)
            ));
        }
        // An orphaned job still printing what it had parks first, then says so.
        let Some(parked) = self.progress.parked else { return Ok(()) };
        let mut buf = [0u8; MAX_PAYLOAD];
        let n = start.encode(&mut buf).expect("a job start fits a frame");
        if job_fingerprint(&buf[..n]) != parked.fingerprint {
            return Err("the printer's parked job is not this model or file with these \
                 settings: resume it with the same ones, or abort it"
                .into());
        }
        let taken = parked.taken as usize;
        let (total, unit) = match self.source {
            Source::Model(tris, _) => (tris.len(), "triangles"),
            Source::Gcode(text, _) => (text.len(), "bytes"),
            Source::Card { .. } => (0, "bytes"),
        };
        if taken > total {
            return Err(format!(
                "the printer's parked job took {taken} {unit}, this one has {total}"
            ));
        }
        if self.send_msg(ep, &Message::Resume) {
            self.next = taken;
            match self.source {
                Source::Model(..) => self.progress.triangles_sent = taken,
                Source::Gcode(..) | Source::Card { .. } => self.progress.gcode_bytes_sent = taken,
            }
            self.phase = Phase::Streaming;
        }
        Ok(())
    }

    /// The text in messages as large as a frame takes, then the end.
    fn stream_text(&mut self, text: &[u8], ep: &mut HostEndpoint) {
        while self.phase == Phase::Streaming && ep.tx_free() > 0 {
            let rest = &text[self.next..];
            if !rest.is_empty() {
                let chunk = &rest[..rest.len().min(MAX_PAYLOAD - 1)];
                let mut buf = [0u8; MAX_PAYLOAD];
                let n = Message::Gcode(chunk).encode(&mut buf).expect("a chunk fits a frame");
                if !self.send(ep, &buf[..n]) {
                    break;
                }
                self.next += chunk.len();
                self.progress.gcode_bytes_sent += chunk.len();
                self.progress.triangle_wire_bytes += wire_len(&buf[..n]) as u64;
            } else if !self.end_queued {
                self.end_queued = self.send_msg(ep, &Message::EndOfModel);
            } else {
                break;
            }
        }
    }

    /// Triangle batches as large as a frame takes, then the end of the model.
    fn stream_triangles(&mut self, tris: &[Triangle], ep: &mut HostEndpoint) -> Result<(), String> {
        while self.phase == Phase::Streaming && ep.tx_free() > 0 {
            if self.next < tris.len() {
                let n = fill_batch(&mut self.batch, tris, self.next)?;
                self.next += n;
                let payload = self.batch.payload().to_vec();
                if !self.send(ep, &payload) {
                    // Keep the batch for the next poll: rewind.
                    self.next -= n;
                    self.batch.clear();
                    break;
                }
                self.batch.clear();
                self.progress.triangles_sent += n;
                self.progress.triangle_wire_bytes += wire_len(&payload) as u64;
            } else if !self.end_queued {
                self.end_queued = self.send_msg(ep, &Message::EndOfModel);
            } else {
                break;
            }
        }
        Ok(())
    }
}

/// The next batch of `tris` from `next` into the empty `batch`: how many it took (an error
/// names a triangle outside the wire's range).
pub(crate) fn fill_batch(
    batch: &mut BatchBuilder,
    tris: &[Triangle],
    next: usize,
) -> Result<usize, String> {
    match batch.fill(&tris[next..]) {
        0 => Err(format!("triangle {next} is outside the wire range (0..1048 mm)")),
        n => Ok(n),
    }
}

/// A device state in words.
fn state_words(state: DeviceState) -> &'static str {
    match state {
        DeviceState::Idle => "idle",
        DeviceState::Printing => "printing",
        DeviceState::Paused => "paused",
        DeviceState::Done => "done",
        DeviceState::Failed => "failed",
        DeviceState::Aborted => "aborted",
        DeviceState::Stopped => "in emergency stop",
    }
}

/// The user-facing text of a failed status.
pub fn describe_failure(s: &Status, words: Option<&str>) -> String {
    let what = match (words, s.error) {
        (Some(words), _) => words.to_string(),
        (None, code) => describe_code(code, s.detail),
    };
    format!("print failed: {what} (layer {} of {})", s.layer, s.layers)
}

/// `text`, the failure of the card's file `name`, with what to do when it is an STL the
/// printer could not hold (its slicer's, toolpath's or move buffer's capacity): the printer
/// checks its slicer's before it prints, the rest only as it prints.
fn with_card_stl_hint(text: String, name: &str, s: &Status) -> String {
    let stl = name.to_ascii_lowercase().ends_with(".stl");
    if !stl || !matches!(s.error, ErrorCode::Slice | ErrorCode::Toolpath | ErrorCode::Moves) {
        return text;
    }
    format!(
        "{text}: the model does not fit the printer as it is; write its job with `strata \
         upload {name}`, which simplifies it to fit"
    )
}

/// The status' error code and detail in words (a device that did not send its own).
fn describe_code(code: ErrorCode, detail: u32) -> String {
    match code {
        ErrorCode::None => "unknown error".to_string(),
        ErrorCode::BadJob => "the printer refused the job settings".to_string(),
        ErrorCode::Slice => format!("slicing failed on the printer at layer {}", detail),
        ErrorCode::Toolpath => format!("toolpath generation failed at layer {}", detail),
        ErrorCode::Plan => format!("the motion planner refused a move of layer {}", detail),
        ErrorCode::Unexpected => {
            format!("the printer got an unexpected message 0x{:02x}", detail)
        }
        ErrorCode::BadMessage => {
            format!("the printer got an undecodable message 0x{:02x}", detail)
        }
        ErrorCode::Moves => format!(
            "a path of layer {} (with the travel before it) needs more bytes of moves than the \
             printer's move buffer holds",
            detail
        ),
        // A new host's session ends the old one's at once (no silence).
        ErrorCode::LinkDead if detail == 0 => "another host opened a link session: the printer \
             printed what it had, parked and paused"
            .to_string(),
        ErrorCode::LinkDead => format!(
            "the printer lost the link after {} ms of silence: it printed what it had, parked \
             and paused",
            detail
        ),
        ErrorCode::Thermal => match u8::try_from(detail).ok().and_then(ThermalFault::from_code) {
            Some(f) => format!("heater fault {f}: heaters off, motion stopped"),
            None => format!("heater fault (code {}): heaters off, motion stopped", detail),
        },
        ErrorCode::Card => match u8::try_from(detail).ok().and_then(CardFault::from_u8) {
            Some(f) => format!("card: {f}"),
            None => format!("card fault (code {detail})"),
        },
    }
}

/// An entry of the printer's card (its root directory).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CardFile {
    /// Its name (long name).
    pub name: String,
    /// Bytes (0 for a directory).
    pub size: u32,
    /// A directory.
    pub is_dir: bool,
}

/// The host side of listing the printer's card: asks for entries from where the last answer
/// stopped until the printer says the directory ended.
#[derive(Debug, Default)]
pub struct CardListing {
    next: u16,
    asked: bool,
    done: bool,
    /// The entries so far.
    pub entries: Vec<CardFile>,
}

impl CardListing {
    /// Handles what arrived and asks for more; true once the whole directory came. `Err`:
    /// the printer could not list its card (in words), or a bad message.
    pub fn poll(&mut self, now_ms: u32, ep: &mut HostEndpoint) -> Result<bool, String> {
        if let Err(LinkError::Dead { silent_ms }) = ep.check(now_ms) {
            return Err(format!(
                "the printer stopped answering: no valid frame for {:.1} s (link dead)",
                silent_ms as f64 / 1000.0
            ));
        }
        while let Some(p) = ep.peek() {
            match Message::decode(p).map_err(|e| format!("the printer sent a bad message: {e}"))? {
                Message::CardEntry(e) => self.entries.push(CardFile {
                    name: e.name.to_string(),
                    size: e.size,
                    is_dir: e.is_dir,
                }),
                Message::CardListed { next, done } => {
                    (self.next, self.done, self.asked) = (next, done, false);
                }
                Message::CardRefused(fault) => {
                    ep.pop();
                    return Err(format!("card: {fault}"));
                }
                _ => {}
            }
            ep.pop();
        }
        if !self.done && !self.asked {
            let mut buf = [0u8; MAX_PAYLOAD];
            let n = Message::CardList { from: self.next }.encode(&mut buf).expect("fits");
            self.asked = ep.send(&buf[..n]).is_ok();
        }
        Ok(self.done)
    }
}

/// The host side of writing a file to the printer's card, or removing one.
///
/// [`CardWrite::upload`] or [`CardWrite::remove`]: the request, the file's bytes as the
/// link's credits allow, then the printer's answer.
#[derive(Debug)]
pub struct CardWrite<'a> {
    name: &'a str,
    /// The file's bytes (`None`: a removal).
    data: Option<&'a [u8]>,
    /// Bytes handed to the link.
    pub sent: usize,
    started: bool,
    closed: bool,
}

impl<'a> CardWrite<'a> {
    /// Writes `data` as the card's file `name` (replacing one of that name).
    pub fn upload(name: &'a str, data: &'a [u8]) -> Self {
        Self { name, data: Some(data), sent: 0, started: false, closed: false }
    }

    /// Removes the card's file `name`.
    pub fn remove(name: &'a str) -> Self {
        Self { name, data: None, sent: 0, started: false, closed: false }
    }

    /// Handles what arrived and sends what the link takes; the file's bytes on the card
    /// once the printer says it is done (0 for a removal). `Err`: the printer's refusal in
    /// words, a bad message, or a dead link.
    pub fn poll(&mut self, now_ms: u32, ep: &mut HostEndpoint) -> Result<Option<u32>, String> {
        if let Err(LinkError::Dead { silent_ms }) = ep.check(now_ms) {
            return Err(format!(
                "the printer stopped answering: no valid frame for {:.1} s (link dead); {} \
                 bytes sent",
                silent_ms as f64 / 1000.0,
                self.sent
            ));
        }
        while let Some(p) = ep.peek() {
            let m =
                Message::decode(p).map_err(|e| format!("the printer sent a bad message: {e}"))?;
            let answer = match m {
                Message::CardRefused(fault) => Some(Err(format!("card: {fault}"))),
                Message::CardDone { bytes } if self.closed => Some(Ok(Some(bytes))),
                _ => None,
            };
            ep.pop();
            if let Some(answer) = answer {
                return answer;
            }
        }
        let mut buf = [0u8; MAX_PAYLOAD];
        while !self.closed && ep.tx_free() > 0 {
            let m = match self.data {
                _ if !self.started => match self.data {
                    Some(_) => Message::CardCreate(self.name),
                    None => Message::CardRemove(self.name),
                },
                Some(data) if self.sent < data.len() => {
                    let rest = &data[self.sent..];
                    Message::CardData(&rest[..rest.len().min(MAX_PAYLOAD - 1)])
                }
                _ => Message::CardClose,
            };
            let n = m
                .encode(&mut buf)
                .map_err(|_| format!("{}: not a name for the card", self.name))?;
            if ep.send(&buf[..n]).is_err() {
                break;
            }
            match m {
                Message::CardCreate(_) => self.started = true,
                Message::CardRemove(_) => (self.started, self.closed) = (true, true),
                Message::CardData(part) => self.sent += part.len(),
                _ => self.closed = true,
            }
        }
        Ok(None)
    }
}

/// What a device answers to a hello.
#[derive(Debug, Clone, Copy)]
pub struct Greeting {
    /// Its capacities.
    pub capacities: Capacities,
    /// Its status (a parked job's: paused, error `LinkDead`).
    pub status: Status,
    /// The job it parked when its last host went silent, if it said so yet.
    pub parked: Option<ParkedJob>,
}

/// A new session's nonce: from the clock and the process, so that a new host's session
/// differs from the last one the device heard (see `strata::protocol::link`).
pub fn session_nonce() -> u16 {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.subsec_nanos());
    let mixed = nanos ^ std::process::id().rotate_left(16);
    (mixed ^ mixed >> 16) as u16
}

/// Opens a session, sends `Hello` and waits for the device's capacities and first status:
/// `poll_io(ep)` moves bytes both ways and returns the current time in ms; gives up after
/// `timeout_ms`.
pub fn handshake(
    ep: &mut HostEndpoint,
    timeout_ms: u32,
    mut poll_io: impl FnMut(&mut HostEndpoint) -> Result<u32, String>,
) -> Result<Greeting, String> {
    let placeholder = JobSpec {
        settings: strata::machine::PrintSettings::default(),
        options: strata::protocol::JobOptions::default(),
        model_height_um: 0,
        triangles: 0,
    };
    let mut job = HostJob::new(&[], placeholder);
    let start = poll_io(ep)?;
    loop {
        let now = poll_io(ep)?;
        // Only the hello goes out: the phase stays `Hello` until capacities arrive, and then
        // this loop ends before a job start could be queued.
        if let (Some(capacities), Some(status)) = (job.progress.capacities, job.progress.status) {
            return Ok(Greeting { capacities, status, parked: job.progress.parked });
        }
        job.poll_hello(now, ep)?;
        if now.wrapping_sub(start) > timeout_ms {
            return Err(format!(
                "no answer from the printer within {:.1} s (is it a strata printer, at this \
                 baud rate?)",
                timeout_ms as f64 / 1000.0
            ));
        }
    }
}

impl HostJob<'_> {
    /// The hello half of [`HostJob::poll`]: sends `Hello`, takes the capacities.
    fn poll_hello(&mut self, now_ms: u32, ep: &mut HostEndpoint) -> Result<(), String> {
        if let Err(LinkError::Dead { silent_ms }) = ep.check(now_ms) {
            return Err(format!(
                "no answer from the printer within {:.1} s (is it a strata printer, at this \
                 baud rate?)",
                silent_ms as f64 / 1000.0
            ));
        }
        while let Some(p) = ep.peek() {
            match Message::decode(p) {
                Ok(Message::Capabilities { version, capacities }) => {
                    if version != VERSION {
                        return Err(format!(
                            "the printer speaks protocol version {version}, this host {VERSION}"
                        ));
                    }
                    self.progress.capacities = Some(capacities);
                }
                // The first status after the capacities (an older one is another host's).
                Ok(Message::Status(s)) if self.progress.capacities.is_some() => {
                    self.progress.status = Some(s);
                }
                Ok(Message::Parked(p)) => self.progress.parked = Some(p),
                _ => {}
            }
            ep.pop();
        }
        if !self.hello_sent {
            self.hello_sent = self.send_msg(ep, &Message::Hello { version: VERSION });
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use strata::geom::{Point3, Triangle};

    fn job_of(triangles: u32) -> JobSpec {
        JobSpec {
            settings: strata::machine::PrintSettings::default(),
            options: strata::protocol::JobOptions::default(),
            model_height_um: 200,
            triangles,
        }
    }

    /// What a device answers to a hello: a parked job (`fingerprint` of its start), or none.
    fn greeting(parked: Option<ParkedJob>) -> Greeting {
        let status = Status {
            state: if parked.is_some() { DeviceState::Paused } else { DeviceState::Idle },
            error: if parked.is_some() { ErrorCode::LinkDead } else { ErrorCode::None },
            layer: parked.map_or(0, |p| p.layer),
            ..Status::default()
        };
        Greeting { capacities: strata::printer::BOARD_CAPACITIES, status, parked }
    }

    fn fingerprint(job: JobSpec) -> u32 {
        let mut buf = [0u8; MAX_PAYLOAD];
        let n = Message::JobStart(job).encode(&mut buf).unwrap();
        job_fingerprint(&buf[..n])
    }

    /// The first poll of a job after the greeting: what it decided.
    fn first_poll(job: &mut HostJob<'_>) -> Result<Phase, String> {
        let mut ep = HostEndpoint::new(strata::protocol::LinkConfig::default());
        job.poll(0, &mut ep)
    }

    #[test]
    fn a_parked_job_resumes_only_as_the_same_job() {
        let t = Triangle {
            v: [Point3::new(0, 0, 0), Point3::new(1_000, 0, 0), Point3::new(0, 1_000, 200)],
        };
        let tris = vec![t; 10];
        let job = job_of(10);
        let parked = ParkedJob { layer: 3, taken: 6, fingerprint: fingerprint(job) };
        // The same job resumes from the triangles taken.
        let mut same =
            HostJob::after_hello(Source::Model(&tris, job), &greeting(Some(parked))).resuming();
        assert_eq!(first_poll(&mut same), Ok(Phase::Streaming));
        assert_eq!(same.progress.triangles_sent, 10);
        // Other settings (another fingerprint): refused.
        let other = job_of(9);
        let mut job2 =
            HostJob::after_hello(Source::Model(&tris, other), &greeting(Some(parked))).resuming();
        let e = first_poll(&mut job2).unwrap_err();
        assert!(e.contains("not this model or file with these settings"), "{e}");
        // A new job on a printer holding a parked one: refused, with the way out.
        let mut fresh = HostJob::after_hello(Source::Model(&tris, job), &greeting(Some(parked)));
        let e = first_poll(&mut fresh).unwrap_err();
        assert!(e.contains("parked at layer 3") && e.contains("--resume"), "{e}");
        // Nothing to resume.
        let mut none = HostJob::after_hello(Source::Model(&tris, job), &greeting(None)).resuming();
        let e = first_poll(&mut none).unwrap_err();
        assert!(e.contains("no parked job to resume (it is idle)"), "{e}");
    }

    #[test]
    fn a_failure_reads_in_the_devices_words_when_it_sent_them() {
        let s = Status {
            state: DeviceState::Failed,
            layer: 37,
            layers: 120,
            error: ErrorCode::Slice,
            detail: 37,
            ..Status::default()
        };
        let words = "slicer: too many active triangles in layer 37 (capacity 388)";
        assert_eq!(
            describe_failure(&s, Some(words)),
            format!("print failed: {words} (layer 37 of 120)")
        );
        assert_eq!(
            describe_failure(&s, None),
            "print failed: slicing failed on the printer at layer 37 (layer 37 of 120)"
        );
        // An STL printing from the card that the printer could not hold: what to do.
        let hinted = with_card_stl_hint(describe_failure(&s, Some(words)), "Boat.STL", &s);
        assert!(hinted.ends_with("`strata upload Boat.STL`, which simplifies it to fit"));
        let gcode = with_card_stl_hint(describe_failure(&s, None), "boat.gcode", &s);
        assert_eq!(gcode, describe_failure(&s, None), "no hint for G-code");
        // A job orphaned by a new host's session had no silence to report.
        let taken = describe_code(ErrorCode::LinkDead, 0);
        assert!(taken.starts_with("another host opened a link session"), "{taken}");
        assert!(describe_code(ErrorCode::LinkDead, 3_000).contains("after 3000 ms of silence"));
        let card = describe_code(ErrorCode::Card, CardFault::Removed as u32);
        assert_eq!(card, "card: the SD card was removed or failed during the print");
    }
}
