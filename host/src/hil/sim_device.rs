//! The in-process simulated printer ([`crate::serial::serve_device`]) behind a unix socket:
//! the harness without QEMU, on the device's own clock (one millisecond a turn of its loop).

use std::os::unix::net::UnixStream;
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use strata::protocol::DeviceState;

use crate::clock::{LinkClock, StallCheck, CLOCK_STALL_LIMIT};
use crate::serial::{serve_device, DeviceClock, ServeOptions};

/// The simulated printer on one end of a [`UnixStream`] pair, on a thread with a large stack.
pub struct SimDevice {
    stop: Arc<AtomicBool>,
    turns: Arc<AtomicU32>,
    ended: Arc<AtomicBool>,
    thread: Option<JoinHandle<Result<DeviceState, String>>>,
}

impl SimDevice {
    /// Starts a device serving with `opts` on its turn clock; returns it and the host's end.
    pub fn start(opts: ServeOptions) -> Result<(Self, UnixStream), String> {
        let (host_end, mut dev) = UnixStream::pair().map_err(|e| e.to_string())?;
        dev.set_read_timeout(Some(Duration::from_millis(1))).map_err(|e| e.to_string())?;
        let stop = Arc::new(AtomicBool::new(false));
        let turns = Arc::new(AtomicU32::new(0));
        let ended = Arc::new(AtomicBool::new(false));
        let (stop2, turns2, ended2) = (stop.clone(), turns.clone(), ended.clone());
        let thread = std::thread::Builder::new()
            .name("hil-sim-device".into())
            .stack_size(512 << 20)
            .spawn(move || {
                let machine = strata::machine::MachineConfig::default();
                let r = serve_device(
                    &mut dev,
                    &machine,
                    opts,
                    DeviceClock::Turns(&turns2),
                    &stop2,
                    None,
                );
                ended2.store(true, Ordering::Release);
                r
            })
            .map_err(|e| e.to_string())?;
        Ok((Self { stop, turns, ended, thread: Some(thread) }, host_end))
    }

    /// The device's clock, for the host and the relay.
    pub fn clock(&self) -> SimClock {
        SimClock {
            turns: self.turns.clone(),
            ended: self.ended.clone(),
            ended_at: None,
            stall: StallCheck::new("the simulated printer", CLOCK_STALL_LIMIT),
        }
    }

    /// Stops the device (if it has not ended by itself); its final state.
    pub fn finish(mut self) -> Result<DeviceState, String> {
        self.stop.store(true, Ordering::Relaxed);
        match self.thread.take().map(|t| t.join()) {
            Some(Ok(r)) => r,
            Some(Err(_)) => Err("the simulated device panicked".into()),
            None => Err("already finished".into()),
        }
    }
}

impl Drop for SimDevice {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// A [`SimDevice`]'s clock: its turns, in milliseconds. The device's loop ends when its job
/// has ended: from then on the clock follows the wall clock, so the host can still time out.
pub struct SimClock {
    turns: Arc<AtomicU32>,
    ended: Arc<AtomicBool>,
    ended_at: Option<Instant>,
    stall: StallCheck,
}

impl LinkClock for SimClock {
    fn now_ms(&mut self) -> Result<u32, String> {
        if self.ended.load(Ordering::Acquire) {
            let at = *self.ended_at.get_or_insert_with(Instant::now);
            let t = self.turns.load(Ordering::Acquire);
            return Ok(t.wrapping_add(at.elapsed().as_millis() as u32));
        }
        let t = self.turns.load(Ordering::Acquire);
        self.stall.check(t as u64, Instant::now())?;
        Ok(t)
    }
}
