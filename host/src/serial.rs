//! The protocol over a byte stream (a serial port, or a pseudo-terminal in the tests): the
//! host side of `strata print`, and a simulated printer serving a port in real time.

use std::io::{ErrorKind, Read, Write};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use strata::geom::Triangle;
use strata::machine::MachineConfig;
use strata::protocol::{Capacities, DeviceState, Endpoint, JobSpec, LinkConfig, MAX_WIRE};
use strata::sim::{SimBoard, SimTiming};
use strata::step::{is_before, Executor, StepQueue, Wake};

use crate::session::{handshake, HostEndpoint, HostJob, Phase, Progress};
use crate::simjob::{device_turn, DeviceEndpoint, SimPrinter};

/// Reads what is available (a timed-out read is no data).
fn read_some(port: &mut impl Read, buf: &mut [u8]) -> Result<usize, String> {
    match port.read(buf) {
        Ok(n) => Ok(n),
        Err(e)
            if matches!(
                e.kind(),
                ErrorKind::TimedOut | ErrorKind::WouldBlock | ErrorKind::Interrupted
            ) =>
        {
            Ok(0)
        }
        Err(e) => Err(format!("serial port: {e}")),
    }
}

/// Moves bytes both ways once; returns the time in ms since `t0`.
fn pump<P: Read + Write>(port: &mut P, ep: &mut HostEndpoint, t0: Instant) -> Result<u32, String> {
    let now = t0.elapsed().as_millis() as u32;
    let mut buf = [0u8; 4096];
    let n = read_some(port, &mut buf)?;
    ep.receive(&buf[..n], now);
    let mut frame = [0u8; MAX_WIRE];
    loop {
        let n = ep.poll_transmit(now, &mut frame);
        if n == 0 {
            break;
        }
        port.write_all(&frame[..n]).map_err(|e| format!("serial port: {e}"))?;
    }
    port.flush().map_err(|e| format!("serial port: {e}"))?;
    Ok(now)
}

/// Connects: hello and the device's capacities.
pub fn connect<P: Read + Write>(
    port: &mut P,
    ep: &mut HostEndpoint,
    t0: Instant,
) -> Result<Capacities, String> {
    handshake(ep, 5_000, |ep| pump(port, ep, t0))
}

/// Runs a job on a connected port until the device reports it done. `on_progress` is called
/// about every 100 ms; `abort` (Ctrl-C) sends an abort and ends with an error once the
/// device confirms (or after 5 s).
#[allow(clippy::too_many_arguments)]
pub fn print<P: Read + Write>(
    port: &mut P,
    ep: &mut HostEndpoint,
    t0: Instant,
    caps: Capacities,
    tris: &[Triangle],
    job: JobSpec,
    abort: &AtomicBool,
    mut on_progress: impl FnMut(&Progress),
) -> Result<Progress, String> {
    let mut host = HostJob::after_hello(tris, job, caps);
    let mut last_report = 0u32;
    let mut abort_at: Option<u32> = None;
    loop {
        let now = pump(port, ep, t0)?;
        if abort.load(Ordering::Relaxed) && abort_at.is_none() {
            host.abort();
            abort_at = Some(now);
        }
        let phase = host.poll(now, ep);
        // Once the device reported the job done, a device that closes the port at once (the
        // simulated one does) does not turn the job into a failure.
        let sent = pump(port, ep, t0);
        if !matches!(phase, Ok(Phase::Done)) {
            sent?;
        }
        match phase {
            Ok(Phase::Done) => return Ok(host.progress),
            Ok(_) => {}
            Err(e) => {
                return Err(if abort_at.is_some() { "aborted by the user".into() } else { e })
            }
        }
        if let Some(a) = abort_at {
            let aborted = host.progress.status.is_some_and(|s| s.state == DeviceState::Aborted);
            if aborted || now.wrapping_sub(a) > 5_000 {
                return Err("aborted by the user".into());
            }
        }
        if now.wrapping_sub(last_report) >= 100 {
            last_report = now;
            on_progress(&host.progress);
        }
    }
}

/// A simulated printer serving `port` in real time (link timers on the wall clock), its motion
/// running `speedup` times faster than real time on the board's virtual clock. Returns when
/// the job ended (done, failed, aborted, stopped) and the last reports went out, or when
/// `stop` is set. Runs on the calling thread, which needs a large stack (512 MB reserved).
pub fn serve_device<P: Read + Write>(
    port: &mut P,
    machine: &MachineConfig,
    capacities: Capacities,
    speedup: u64,
    stop: &AtomicBool,
) -> Result<DeviceState, String> {
    let mut printer: Box<SimPrinter> = Box::new(SimPrinter::new(machine));
    printer.set_capacities(capacities);
    let step_cfg = *printer.step_config();
    let ticks_per_ms = step_cfg.timer_hz as u64 / 1000;
    let start_tick = 1_000u64;
    let board = SimBoard::new(SimTiming::from_config(&step_cfg), start_tick, ());
    let mut pins = board.pins();
    let mut queue: StepQueue<64> = StepQueue::new();
    let (mut prod, cons) = queue.split();
    let mut exec = Executor::new(&step_cfg, cons);
    let mut ep: DeviceEndpoint = Endpoint::new(LinkConfig::default());
    let mut next_wake: Option<u32> = None;
    let mut first_step: Option<u64> = None;
    let mut ended_at: Option<u32> = None;
    let mut buf = [0u8; 4096];
    let t0 = Instant::now();
    while !stop.load(Ordering::Relaxed) {
        let now = t0.elapsed().as_millis() as u32;
        // Like a UART, the device neither fails when no one is connected nor when the host
        // goes away: errors are a line without data.
        let n = port.read(&mut buf).unwrap_or_else(|_| {
            std::thread::sleep(Duration::from_millis(1));
            0
        });
        ep.receive(&buf[..n], now);
        let done_ms = first_step.map_or(0, |f| ((board.now() - f) / ticks_per_ms) as u32);
        device_turn(&mut printer, &mut ep, &mut prod, now, done_ms, 200, |f| {
            let _ = port.write_all(f);
        });
        let _ = port.flush();
        let end_tick = start_tick + now as u64 * speedup * ticks_per_ms;
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
                printer.poll(&mut prod);
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
