//! A fault-injecting relay between a device's UART socket and the host, timed on the
//! device's clock.

use std::io::{ErrorKind, Read, Write};
use std::os::unix::net::UnixStream;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

use strata::protocol::frame::MAX_WIRE;

use crate::clock::LinkClock;
use crate::simjob::{Faults, Wire};

/// What crossed a [`Relay`] (after the faults).
#[derive(Debug, Clone, Copy, Default)]
pub struct RelayStats {
    /// Frames the host wrote.
    pub frames_from_host: u64,
    /// Frames the device wrote.
    pub frames_from_device: u64,
    /// Bytes delivered to the device.
    pub bytes_to_device: u64,
    /// Bytes delivered to the host.
    pub bytes_to_host: u64,
}

/// A fault-injecting relay between a device's UART socket and the host.
///
/// Every frame (split at its `0x00` delimiter) goes through a [`Wire`] per direction with seeded
/// [`Faults`] (frame drop, byte corruption, byte loss, duplication, delay) at `baud`, timed on the
/// device's clock (QEMU's instruction clock, or the in-process printer's), so the line runs at
/// `baud` in the device's time however fast the machine runs it. Runs on its own thread until
/// dropped, either side closes, or the clock fails.
pub struct Relay {
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<Result<RelayStats, String>>>,
}

struct Direction {
    /// `STRATA_HIL_TRACE`: each frame's header on standard error, with this label.
    trace: Option<&'static str>,
    wire: Wire,
    /// Bytes read, not yet split into frames.
    inbox: Vec<u8>,
    partial: Vec<u8>,
    out: Vec<u8>,
    frames: u64,
    delivered: u64,
}

impl Direction {
    /// Reads what is available into the inbox; false when the peer closed.
    fn pull(&mut self, s: &mut UnixStream) -> Result<bool, String> {
        let mut buf = [0u8; 4096];
        loop {
            match s.read(&mut buf) {
                Ok(0) => return Ok(false),
                Ok(n) => self.inbox.extend_from_slice(&buf[..n]),
                Err(e) if e.kind() == ErrorKind::WouldBlock => return Ok(true),
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(e) => return Err(format!("relay: {e}")),
            }
        }
    }

    /// Splits the inbox into frames sent onto the wire at `now_ms`.
    fn send(&mut self, now_ms: u64) {
        for b in std::mem::take(&mut self.inbox) {
            self.partial.push(b);
            // A frame ends at its delimiter; garbage without one is passed on in pieces (the
            // decoder resynchronises).
            if b == 0 || self.partial.len() >= 2 * MAX_WIRE {
                if let Some(label) = self.trace {
                    trace_frame(label, now_ms, &self.partial);
                }
                self.wire.send_frame(now_ms, &self.partial);
                self.partial.clear();
                self.frames += 1;
            }
        }
    }

    fn tick(&mut self, ms: u64) {
        self.wire.tick(ms);
        self.out.extend_from_slice(self.wire.arrived());
    }

    fn write_to(&mut self, s: &mut UnixStream) -> Result<(), String> {
        while !self.out.is_empty() {
            match s.write(&self.out) {
                Ok(0) => return Err("relay: peer closed".into()),
                Ok(n) => {
                    self.delivered += n as u64;
                    self.out.drain(..n);
                }
                Err(e) if e.kind() == ErrorKind::WouldBlock => break,
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(e) => return Err(format!("relay: {e}")),
            }
        }
        Ok(())
    }
}

/// One frame's header and message type (as sent, before the faults).
fn trace_frame(label: &str, now_ms: u64, wire: &[u8]) {
    let mut raw = wire.to_vec();
    if raw.last() == Some(&0) {
        raw.pop();
    }
    let what = match strata::protocol::frame::cobs_decode_in_place(&mut raw)
        .map(|n| strata::protocol::frame::parse(&raw[..n]))
    {
        Some(Ok(f)) => {
            // Control messages in full; triangle batches by size.
            let msg = match strata::protocol::Message::decode(f.payload) {
                Ok(strata::protocol::Message::Triangles(_)) => "Triangles".to_string(),
                Ok(m) => format!("{m:?}"),
                Err(_) => format!("{:02x?}", f.payload.first()),
            };
            format!(
                "{:?} seq={} ack={} credits={} len={} {msg}",
                f.kind,
                f.seq,
                f.ack,
                f.credits,
                f.payload.len()
            )
        }
        Some(Err(e)) => format!("bad frame {e:?}"),
        None => "bad COBS".into(),
    };
    eprintln!("relay {now_ms:>7} ms {label}: {what}");
}

impl Relay {
    /// Relays `device` (e.g. QEMU's UART socket) to the returned host end, on `clock`.
    pub fn spawn(
        mut device: UnixStream,
        faults: Faults,
        baud: u32,
        mut clock: impl LinkClock + Send + 'static,
    ) -> Result<(Self, UnixStream), String> {
        let (host_end, mut near) = UnixStream::pair().map_err(|e| format!("relay: {e}"))?;
        device.set_nonblocking(true).map_err(|e| format!("relay: {e}"))?;
        near.set_nonblocking(true).map_err(|e| format!("relay: {e}"))?;
        let stop = Arc::new(AtomicBool::new(false));
        let stop2 = stop.clone();
        let thread = std::thread::Builder::new()
            .name("hil-relay".into())
            .spawn(move || {
                let trace = std::env::var_os("STRATA_HIL_TRACE").is_some();
                let dir = |salt, label| Direction {
                    trace: trace.then_some(label),
                    wire: Wire::new(faults, salt, baud),
                    inbox: Vec::new(),
                    partial: Vec::new(),
                    out: Vec::new(),
                    frames: 0,
                    delivered: 0,
                };
                let (mut h2d, mut d2h) = (dir(11, "host->dev"), dir(12, "dev->host"));
                // Milliseconds of the clock since the relay started, from 1.
                let (mut origin, mut last) = (None, 0u64);
                let result = loop {
                    if stop2.load(Ordering::Relaxed) {
                        break Ok(());
                    }
                    // Both sides are read before the clock: QEMU's UART blocks the emulator
                    // (and its monitor, which the clock asks) once its socket is full.
                    match (h2d.pull(&mut near), d2h.pull(&mut device)) {
                        (Ok(true), Ok(true)) => {}
                        (Err(e), _) | (_, Err(e)) => break Err(e),
                        _ => break Ok(()),
                    }
                    let now = match clock.now_ms() {
                        Ok(ms) => ms.wrapping_sub(*origin.get_or_insert(ms)) as u64 + 1,
                        Err(e) => break Err(format!("relay: {e}")),
                    };
                    h2d.send(now);
                    d2h.send(now);
                    while last < now {
                        last += 1;
                        h2d.tick(last);
                        d2h.tick(last);
                    }
                    if let Err(e) = h2d.write_to(&mut device).and(d2h.write_to(&mut near)) {
                        break Err(e);
                    }
                    std::thread::sleep(Duration::from_micros(300));
                };
                // Either side closing closes the other.
                let _ = device.shutdown(std::net::Shutdown::Both);
                let _ = near.shutdown(std::net::Shutdown::Both);
                result.map(|()| RelayStats {
                    frames_from_host: h2d.frames,
                    frames_from_device: d2h.frames,
                    bytes_to_device: h2d.delivered,
                    bytes_to_host: d2h.delivered,
                })
            })
            .map_err(|e| format!("relay: {e}"))?;
        Ok((Self { stop, thread: Some(thread) }, host_end))
    }

    /// Stops the relay; what crossed it.
    pub fn finish(mut self) -> Result<RelayStats, String> {
        self.stop.store(true, Ordering::Relaxed);
        match self.thread.take().map(|t| t.join()) {
            Some(Ok(r)) => r,
            Some(Err(_)) => Err("relay panicked".into()),
            None => Ok(RelayStats::default()),
        }
    }
}

impl Drop for Relay {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}
