//! The protocol over a byte stream (a serial port, or a pseudo-terminal in the tests): the
//! host side of `strata print`, and a simulated printer serving a port.
//!
//! Neither direction blocks the link: a read that times out is no data, and bytes the port
//! refuses for now (`WouldBlock`, `TimedOut`, `Interrupted`: a busy PC, a printer that reads
//! slowly) wait in an outbox while reads go on ([`Port`]). Only a port that takes no byte for
//! the link's dead time ([`LinkConfig::dead_ms`], on the link's clock) ends the job.

use std::io::{ErrorKind, Read, Write};
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use std::time::{Duration, Instant};

use strata::machine::MachineConfig;
use strata::printer::MotionHalf;
use strata::protocol::{Capacities, DeviceState, Endpoint, LinkConfig, MAX_WIRE};
use strata::sim::{SimBoard, SimTiming};
use strata::step::{is_before, Executor, StepQueue, Wake};

use crate::clock::LinkClock;
use crate::session::{
    handshake, session_nonce, Greeting, HostEndpoint, HostJob, Phase, Progress, Source,
};
use crate::simjob::{announce_posed, device_turn, DeviceEndpoint, SimMotion, SimPrinter};

/// Whether an I/O error means "not now" rather than "never".
fn is_transient(e: &std::io::Error) -> bool {
    matches!(e.kind(), ErrorKind::TimedOut | ErrorKind::WouldBlock | ErrorKind::Interrupted)
}

/// Reads what is available (a timed-out read is no data).
fn read_some(port: &mut impl Read, buf: &mut [u8]) -> Result<usize, String> {
    match port.read(buf) {
        Ok(n) => Ok(n),
        Err(e) if is_transient(&e) => Ok(0),
        Err(e) => Err(format!("serial port: {e}")),
    }
}

/// A port (unbuffered: a serial port, a pseudo-terminal, a socket) with an outbox for the
/// bytes it refused for now.
pub struct Port<P> {
    inner: P,
    outbox: Vec<u8>,
    /// Link time since which the outbox has been waiting without taking a byte, ms.
    blocked_since_ms: Option<u32>,
}

impl<P: Read + Write> Port<P> {
    /// Wraps `inner`.
    pub fn new(inner: P) -> Self {
        Self { inner, outbox: Vec::new(), blocked_since_ms: None }
    }

    /// The port itself.
    pub fn get_mut(&mut self) -> &mut P {
        &mut self.inner
    }

    /// Writes what the port takes of the outbox at `now_ms`; an error for a port that failed,
    /// or took no byte for `deadline_ms`.
    fn drain(&mut self, now_ms: u32, deadline_ms: u32) -> Result<(), String> {
        while !self.outbox.is_empty() {
            match self.inner.write(&self.outbox) {
                Ok(0) => return Err("serial port: closed".into()),
                Ok(n) => {
                    self.outbox.drain(..n);
                    self.blocked_since_ms = None;
                }
                Err(e) if is_transient(&e) => break,
                Err(e) => return Err(format!("serial port: {e}")),
            }
        }
        if self.outbox.is_empty() {
            return Ok(());
        }
        let since = *self.blocked_since_ms.get_or_insert(now_ms);
        if now_ms.wrapping_sub(since) > deadline_ms {
            return Err(format!(
                "serial port: the printer took no data for {:.1} s",
                now_ms.wrapping_sub(since) as f64 / 1000.0
            ));
        }
        Ok(())
    }

    /// Moves bytes both ways once at the clock's time: what arrived into `ep`, then `ep`'s
    /// frames out (new ones only once the outbox is empty, so a stalled port holds at most
    /// one round of frames). Returns the time, ms.
    pub fn pump(
        &mut self,
        ep: &mut HostEndpoint,
        clock: &mut impl LinkClock,
    ) -> Result<u32, String> {
        let now = clock.now_ms()?;
        let mut buf = [0u8; 4096];
        let n = read_some(&mut self.inner, &mut buf)?;
        ep.receive(&buf[..n], now);
        let deadline = ep.config().dead_ms;
        self.drain(now, deadline)?;
        if self.outbox.is_empty() {
            let mut frame = [0u8; MAX_WIRE];
            loop {
                let n = ep.poll_transmit(now, &mut frame);
                if n == 0 {
                    break;
                }
                self.outbox.extend_from_slice(&frame[..n]);
            }
            self.drain(now, deadline)?;
        }
        Ok(now)
    }
}

/// Runs `work` on another thread while this one keeps the link alive.
///
/// Frames in (acked, kept for the job), acks and keepalives out, so neither end declares the link
/// dead (admission control can take longer than the link's dead time).
pub fn keeping_link_alive<P: Read + Write, T: Send>(
    port: &mut Port<P>,
    ep: &mut HostEndpoint,
    clock: &mut impl LinkClock,
    work: impl FnOnce() -> T + Send,
) -> Result<T, String> {
    std::thread::scope(|s| {
        let worker = s.spawn(work);
        while !worker.is_finished() {
            // The port's read timeout paces the loop.
            port.pump(ep, clock)?;
        }
        worker.join().map_err(|_| "the work beside the link panicked".to_string())
    })
}

/// Connects: a new session, hello, the device's capacities and status (within 5 s of the
/// clock).
pub fn connect<P: Read + Write>(
    port: &mut Port<P>,
    ep: &mut HostEndpoint,
    clock: &mut impl LinkClock,
) -> Result<Greeting, String> {
    ep.open(session_nonce());
    handshake(ep, 5_000, |ep| port.pump(ep, clock))
}

/// The printer's card's root directory, on a connected port.
pub fn card_list<P: Read + Write>(
    port: &mut Port<P>,
    ep: &mut HostEndpoint,
    clock: &mut impl LinkClock,
) -> Result<Vec<crate::session::CardFile>, String> {
    let mut listing = crate::session::CardListing::default();
    loop {
        let now = port.pump(ep, clock)?;
        if listing.poll(now, ep)? {
            return Ok(listing.entries);
        }
        port.pump(ep, clock)?;
    }
}

/// Writes (or removes) a file on the printer's card, on a connected port: the file's bytes
/// on the card once done (0 for a removal); `on_progress(bytes sent)` about every 100 ms.
pub fn card_write<P: Read + Write>(
    port: &mut Port<P>,
    ep: &mut HostEndpoint,
    clock: &mut impl LinkClock,
    mut write: crate::session::CardWrite<'_>,
    mut on_progress: impl FnMut(usize),
) -> Result<u32, String> {
    let mut last_report = 0u32;
    loop {
        let now = port.pump(ep, clock)?;
        if let Some(bytes) = write.poll(now, ep)? {
            return Ok(bytes);
        }
        port.pump(ep, clock)?;
        if now.wrapping_sub(last_report) >= 100 {
            last_report = now;
            on_progress(write.sent);
        }
    }
}

/// Runs a job on a connected port until the device reports it done.
///
/// `on_progress` is called about every 100 ms of the clock; `abort` (Ctrl-C) sends an abort and
/// ends with an error once the device confirms (or after [`ABORT_CONFIRM_MS`] or the link's dead
/// time, the longer, of the clock).
#[allow(clippy::too_many_arguments)]
pub fn print<P: Read + Write>(
    port: &mut Port<P>,
    ep: &mut HostEndpoint,
    clock: &mut impl LinkClock,
    greeting: &Greeting,
    source: Source<'_>,
    resume: bool,
    abort: &AtomicBool,
    mut on_progress: impl FnMut(&Progress),
) -> Result<Progress, String> {
    let mut host = HostJob::after_hello(source, greeting);
    if resume {
        host = host.resuming();
    }
    let mut last_report = 0u32;
    let mut abort_at: Option<u32> = None;
    let confirm_ms = ABORT_CONFIRM_MS.max(ep.config().dead_ms);
    loop {
        let now = port.pump(ep, clock)?;
        if abort.load(Ordering::Relaxed) && abort_at.is_none() {
            host.abort();
            abort_at = Some(now);
        }
        let phase = host.poll(now, ep);
        // Once the device reported the job done, a device that closes the port at once (the
        // simulated one does) does not turn the job into a failure.
        let sent = port.pump(ep, clock);
        if !matches!(phase, Ok(Phase::Done)) {
            sent?;
        }
        let confirmed = host.progress.status.is_some_and(|s| s.state == DeviceState::Aborted);
        match (phase, abort_at) {
            (Ok(Phase::Done), _) => return Ok(host.progress),
            (_, Some(_)) if confirmed => {
                return Err("aborted by the user: the printer confirmed".into())
            }
            (Err(e), None) => return Err(e),
            (Err(_), Some(_)) => return Err(aborted_unconfirmed(confirm_ms)),
            (Ok(_), Some(a)) if now.wrapping_sub(a) > confirm_ms => {
                return Err(aborted_unconfirmed(confirm_ms))
            }
            (Ok(_), _) => {}
        }
        if now.wrapping_sub(last_report) >= 100 {
            last_report = now;
            on_progress(&host.progress);
        }
    }
}

/// How long [`print()`] waits at least for the device to confirm an abort, ms of the link's
/// clock.
pub const ABORT_CONFIRM_MS: u32 = 5_000;

/// [`print()`]'s error when the device did not confirm the user's abort within `ms`.
fn aborted_unconfirmed(ms: u32) -> String {
    format!(
        "aborted by the user: the printer did not confirm within {:.0} s (it was told to abort)",
        ms as f64 / 1000.0
    )
}

/// How a simulated printer ([`serve_device`]) serves its port.
#[derive(Debug, Clone, Copy)]
#[non_exhaustive]
pub struct ServeOptions {
    /// Capacities the device announces.
    pub capacities: Capacities,
    /// The motion runs this many times faster than the device's clock.
    pub speedup: u64,
    /// The device's link timers.
    pub link: LinkConfig,
    /// Once a job starts, the device reads nothing for this long (a printer busy elsewhere:
    /// the host's writes back up), ms of the device's clock.
    pub stall_reads_ms: u32,
}

impl ServeOptions {
    /// A device announcing `capacities`, its motion `speedup` times faster than its clock, on
    /// the protocol's default link timers.
    pub fn new(capacities: Capacities, speedup: u64) -> Self {
        Self { capacities, speedup, link: LinkConfig::device(), stall_reads_ms: 0 }
    }
}

/// The clock a simulated printer runs on.
#[derive(Debug, Clone, Copy)]
pub enum DeviceClock<'a> {
    /// Real time: the device serves a host on the wall clock (`strata print`).
    Wall,
    /// Its own progress: every turn of its loop is one millisecond, published in the counter
    /// for a host that runs on the same clock.
    Turns(&'a AtomicU32),
}

/// A simulated printer serving `port` on `clock` (the link's timers and, `speedup` times faster,
/// the board's motion), with `card` in its slot.
///
/// Returns when the job ended (done, failed, aborted, stopped) and the last reports went out, or
/// when `stop` is set. Runs on the calling thread, which needs a large stack (512 MB reserved).
pub fn serve_device<P: Read + Write>(
    port: &mut P,
    machine: &MachineConfig,
    opts: ServeOptions,
    clock: DeviceClock<'_>,
    stop: &AtomicBool,
    mut card: Option<crate::card_image::ImageCard>,
) -> Result<DeviceState, String> {
    let mut printer: Box<SimPrinter> = Box::new(SimPrinter::new(machine));
    printer.set_offset_limit(opts.capacities.toolpath_points as usize);
    let caps = &opts.capacities;
    printer.set_bridge_limits(caps.path_points as usize, caps.scan_crossings as usize);
    let step_cfg = *printer.step_config();
    let ticks_per_ms = step_cfg.timer_hz as u64 / 1000;
    let start_tick = 1_000u64;
    let board = SimBoard::new(SimTiming::from_config(&step_cfg), start_tick, ());
    let mut pins = board.pins();
    let mut queue: StepQueue<64> = StepQueue::new();
    let (prod, cons) = queue.split();
    let mut motion: Box<SimMotion<'_, 64>> = Box::new(MotionHalf::new(prod));
    let mut exec = Executor::new(&step_cfg, cons);
    let mut ep: DeviceEndpoint = Endpoint::new(opts.link);
    let mut next_wake: Option<u32> = None;
    let mut first_step: Option<u64> = None;
    let mut ended_at: Option<u32> = None;
    let mut buf = [0u8; 4096];
    let t0 = Instant::now();
    let mut turns = 0u32;
    let mut job_started_at: Option<u32> = None;
    while !stop.load(Ordering::Relaxed) {
        let now = match clock {
            DeviceClock::Wall => t0.elapsed().as_millis() as u32,
            DeviceClock::Turns(shared) => {
                turns = turns.wrapping_add(1);
                shared.store(turns, Ordering::Release);
                turns
            }
        };
        if job_started_at.is_none() && printer.state() != DeviceState::Idle {
            job_started_at = Some(now);
        }
        let stalled = job_started_at.is_some_and(|t| now.wrapping_sub(t) < opts.stall_reads_ms);
        // Like a UART, the device neither fails when no one is connected nor when the host
        // goes away: errors are a line without data.
        let n = if stalled {
            std::thread::sleep(Duration::from_millis(1));
            0
        } else {
            port.read(&mut buf).unwrap_or_else(|_| {
                std::thread::sleep(Duration::from_millis(1));
                0
            })
        };
        ep.receive(&buf[..n], now);
        let done_ms = first_step.map_or(0, |f| ((board.now() - f) / ticks_per_ms) as u32);
        announce_posed(&opts.capacities, &mut ep, &mut printer, now);
        let card = card.as_mut();
        device_turn(&mut printer, &mut ep, &mut motion, &mut None, card, now, done_ms, 200, |f| {
            let _ = port.write_all(f);
        });
        let end_tick = start_tick + now as u64 * opts.speedup * ticks_per_ms;
        if printer.state() != DeviceState::Stopped {
            if next_wake.is_none() {
                next_wake = wake(exec.on_timer(board.now_u32(), &mut pins));
                if first_step.is_none() && !exec.is_idle() {
                    first_step = Some(board.now());
                }
            }
            while let Some(w) = next_wake {
                if !is_before(w, end_tick as u32) && w != end_tick as u32 {
                    break;
                }
                board.advance_to_u32(w);
                next_wake = wake(exec.on_timer(board.now_u32(), &mut pins));
                printer.poll(&mut *motion);
            }
        }
        board.advance_to(end_tick.max(board.now()));
        let ended = match printer.state() {
            DeviceState::Done => exec.is_idle(),
            DeviceState::Failed | DeviceState::Aborted | DeviceState::Stopped => true,
            _ => false,
        };
        if ended && ended_at.is_none() {
            ended_at = Some(now);
        }
        if ended_at.is_some_and(|e| now.wrapping_sub(e) > 1_000 && ep.all_acked()) {
            return Ok(printer.state());
        }
        if n == 0 {
            std::thread::sleep(Duration::from_micros(500));
        }
    }
    Ok(printer.state())
}

fn wake(w: Result<Wake, core::convert::Infallible>) -> Option<u32> {
    match w {
        Ok(Wake::At(t)) => Some(t),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use strata::protocol::Message;

    /// A port that refuses writes (`kind`) until `open`, then takes at most `piece` bytes a
    /// write; reads nothing.
    struct Refusing {
        kind: ErrorKind,
        open: bool,
        piece: usize,
        taken: Vec<u8>,
    }

    impl Read for Refusing {
        fn read(&mut self, _: &mut [u8]) -> std::io::Result<usize> {
            Err(ErrorKind::TimedOut.into())
        }
    }

    impl Write for Refusing {
        fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
            if !self.open {
                return Err(self.kind.into());
            }
            let n = b.len().min(self.piece);
            self.taken.extend_from_slice(&b[..n]);
            Ok(n)
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    struct Manual(u32);

    impl LinkClock for Manual {
        fn now_ms(&mut self) -> Result<u32, String> {
            Ok(self.0)
        }
    }

    /// A host endpoint holding three messages and the credits to send them (a device's
    /// keepalive received).
    fn loaded_endpoint() -> HostEndpoint {
        let mut ep = HostEndpoint::new(LinkConfig::default());
        let mut device: DeviceEndpoint = Endpoint::new(LinkConfig::device());
        let mut frame = [0u8; MAX_WIRE];
        device.poll_transmit(0, &mut frame);
        let n = device.poll_transmit(LinkConfig::default().keepalive_ms, &mut frame);
        assert!(n > 0, "the device's keepalive");
        ep.receive(&frame[..n], 0);
        let mut payload = [0u8; 64];
        for v in 0..3u8 {
            let n = Message::Hello { version: v }.encode(&mut payload).unwrap();
            ep.send(&payload[..n]).unwrap();
        }
        ep
    }

    /// The frames `ep` would write at `now` on a port that takes everything.
    fn frames_of(mut ep: HostEndpoint, now: u32) -> Vec<u8> {
        let mut out = Vec::new();
        let mut frame = [0u8; MAX_WIRE];
        loop {
            let n = ep.poll_transmit(now, &mut frame);
            if n == 0 {
                return out;
            }
            out.extend_from_slice(&frame[..n]);
        }
    }

    #[test]
    fn refused_writes_wait_in_the_outbox_and_arrive_whole_and_in_order() {
        for kind in [ErrorKind::WouldBlock, ErrorKind::TimedOut, ErrorKind::Interrupted] {
            let mut ep = loaded_endpoint();
            let expected = frames_of(ep.clone(), 0);
            assert!(expected.len() > 3 * 4, "three frames: {expected:?}");
            let mut port = Port::new(Refusing { kind, open: false, piece: 5, taken: Vec::new() });
            let mut clock = Manual(0);
            // Refused for the whole dead time (3 s of the link's clock): not an error yet.
            let dead_ms = LinkConfig::default().dead_ms;
            for t in (0..=dead_ms).step_by(100) {
                clock.0 = t;
                port.pump(&mut ep, &mut clock).unwrap_or_else(|e| panic!("{kind:?} at {t}: {e}"));
            }
            assert!(port.get_mut().taken.is_empty());
            // Once the port takes bytes again (5 at a time), the frames go out as they were.
            port.get_mut().open = true;
            while !port.outbox.is_empty() {
                port.pump(&mut ep, &mut clock).unwrap();
            }
            let taken = &port.get_mut().taken;
            assert_eq!(&taken[..expected.len()], &expected[..], "{kind:?}");
        }
    }

    #[test]
    fn a_port_that_takes_nothing_past_the_dead_time_is_an_error() {
        let mut ep = loaded_endpoint();
        let mut port =
            Port::new(Refusing { kind: ErrorKind::TimedOut, open: false, piece: 1, taken: vec![] });
        let dead_ms = LinkConfig::default().dead_ms;
        let mut clock = Manual(1_000);
        port.pump(&mut ep, &mut clock).unwrap();
        clock.0 = 1_000 + dead_ms;
        port.pump(&mut ep, &mut clock).unwrap();
        clock.0 = 1_000 + dead_ms + 1;
        let e = port.pump(&mut ep, &mut clock).unwrap_err();
        assert!(e.contains("the printer took no data for 3.0 s"), "{e}");
    }
}
