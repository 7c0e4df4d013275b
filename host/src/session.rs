//! The host side of a print job over a protocol [`Endpoint`], independent of the transport (serial
//! port or the in-memory simulated link).
//!
//! Hello, capacities, job start, triangle batches as fast as the device's credits allow, end of
//! model, then status until done.

use strata::geom::Triangle;
use strata::protocol::frame::wire_len;
use strata::protocol::{
    BatchBuilder, Capacities, DeviceState, Endpoint, ErrorCode, GcodeSpec, JobReport, JobSpec,
    LinkError, Message, Status, MAX_PAYLOAD, VERSION,
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
}

/// What a job sends.
#[derive(Debug, Clone, Copy)]
pub enum Source<'a> {
    /// A model: placed triangles, sorted by lowest z, sliced on the device with these settings.
    Model(&'a [Triangle], JobSpec),
    /// G-code text, run as it is.
    Gcode(&'a [u8], GcodeSpec),
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
            progress: Progress::default(),
            sent_log: None,
        }
    }

    /// A job on a link whose hello was already answered with `caps` (see [`handshake`]).
    pub fn after_hello(source: Source<'a>, caps: Capacities) -> Self {
        let mut j = Self::of(source);
        j.hello_sent = true;
        j.progress.capacities = Some(caps);
        j
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
                Message::Failure(text) => self.progress.failure = Some(text.to_string()),
                Message::Status(s) => {
                    self.progress.status = Some(s);
                    match s.state {
                        DeviceState::Done if self.phase == Phase::Printing => {
                            self.phase = Phase::Done
                        }
                        DeviceState::Failed => {
                            return Err(describe_failure(&s, self.progress.failure.as_deref()))
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
        let start = match self.source {
            Source::Model(_, job) => Message::JobStart(job),
            Source::Gcode(_, spec) => Message::GcodeStart(spec),
        };
        if self.phase == Phase::Hello
            && self.progress.capacities.is_some()
            && self.send_msg(ep, &start)
        {
            self.phase = Phase::Streaming;
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
                while self.next < tris.len() && self.batch.push(&tris[self.next]).is_ok() {
                    self.next += 1;
                }
                if self.batch.is_empty() {
                    return Err(format!(
                        "triangle {} is outside the wire range (0..1048 mm)",
                        self.next
                    ));
                }
                let n = self.batch.len();
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

/// The user-facing text of a failed status.
pub fn describe_failure(s: &Status, words: Option<&str>) -> String {
    let what = match (words, s.error) {
        (Some(words), _) => words.to_string(),
        (None, code) => describe_code(code, s.detail),
    };
    format!("print failed: {what} (layer {} of {})", s.layer, s.layers)
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
        ErrorCode::LinkDead => format!(
            "the printer lost the link after {} ms of silence: it printed what it had, parked \
             and paused",
            detail
        ),
        ErrorCode::Thermal => match u8::try_from(detail).ok().and_then(ThermalFault::from_code) {
            Some(f) => format!("heater fault {f}: heaters off, motion stopped"),
            None => format!("heater fault (code {}): heaters off, motion stopped", detail),
        },
    }
}

/// Sends `Hello` and waits for the device's capacities: `poll_io(ep)` moves bytes both ways
/// and returns the current time in ms; gives up after `timeout_ms`.
pub fn handshake(
    ep: &mut HostEndpoint,
    timeout_ms: u32,
    mut poll_io: impl FnMut(&mut HostEndpoint) -> Result<u32, String>,
) -> Result<Capacities, String> {
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
        if let Some(c) = job.progress.capacities {
            return Ok(c);
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
            if let Ok(Message::Capabilities { version, capacities }) = Message::decode(p) {
                if version != VERSION {
                    return Err(format!(
                        "the printer speaks protocol version {version}, this host {VERSION}"
                    ));
                }
                self.progress.capacities = Some(capacities);
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
    }
}
