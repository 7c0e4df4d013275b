//! Hardware in the loop: the firmware's QEMU build (`lm3s6965evb`, UART0 on a unix socket)
//! driven by the real host code ([`crate::serial`]), a seeded fault-injecting relay between
//! the two ([`Relay`], built on the simulated link's [`Wire`]), and the firmware's cost lines
//! on QEMU's standard output ([`Costs`]).
//!
//! The same harness serves the in-process simulated printer ([`crate::serial::serve_device`])
//! over a [`UnixStream`] pair: see `host/tests/hil_qemu.rs` and `host/examples/m3_cost.rs`.

use std::collections::BTreeMap;
use std::io::{BufRead, BufReader, ErrorKind, Read, Write};
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use strata::geom::{Point3, Triangle};
use strata::protocol::frame::MAX_WIRE;
use strata::protocol::{Capacities, DeviceState, JobSpec, LinkConfig};

use crate::admission::{admit_job, Admission};
use crate::session::{HostEndpoint, Progress};
use crate::simjob::{Faults, Wire};

/// The repository root (the host crate's parent).
pub fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The firmware's QEMU image: `$STRATA_FIRMWARE_ELF`, else what
/// `scripts/build_firmware.sh qemu` writes (`target/firmware/qemu/strata-firmware.elf`).
pub fn firmware_elf() -> PathBuf {
    match std::env::var_os("STRATA_FIRMWARE_ELF") {
        Some(p) => PathBuf::from(p),
        None => build_output("qemu"),
    }
}

/// The image `scripts/build_firmware.sh BOARD` writes.
pub fn build_output(board: &str) -> PathBuf {
    repo_root().join("target/firmware").join(board).join("strata-firmware.elf")
}

/// The QEMU machine a firmware image is built for: the `strata-qemu-machine=NAME` tag the
/// QEMU boards carry (`lm3s6965evb`, or `mps2-an385` for the `qemu-mps2` build);
/// `lm3s6965evb` when the image has none.
pub fn qemu_machine(elf: &[u8]) -> String {
    const TAG: &[u8] = b"strata-qemu-machine=";
    elf.windows(TAG.len())
        .position(|w| w == TAG)
        .map(|at| {
            let name = &elf[at + TAG.len()..];
            let n = name.iter().take_while(|c| c.is_ascii_alphanumeric() || **c == b'-').count();
            String::from_utf8_lossy(&name[..n]).into_owned()
        })
        .filter(|m| !m.is_empty())
        .unwrap_or_else(|| "lm3s6965evb".into())
}

/// `$STRATA_QEMU`, else `qemu-system-arm` on the `PATH`.
pub fn find_qemu() -> Option<PathBuf> {
    if let Some(p) = std::env::var_os("STRATA_QEMU") {
        return Some(PathBuf::from(p));
    }
    let path = std::env::var_os("PATH")?;
    std::env::split_paths(&path).map(|d| d.join("qemu-system-arm")).find(|p| p.is_file())
}

/// QEMU and the firmware image ([`firmware_elf`]), or why they cannot be used.
pub fn locate() -> Result<(PathBuf, PathBuf), String> {
    locate_image(firmware_elf(), "qemu")
}

/// QEMU and `elf` (what `scripts/build_firmware.sh board` writes), or why they cannot be
/// used.
pub fn locate_image(elf: PathBuf, board: &str) -> Result<(PathBuf, PathBuf), String> {
    let qemu = find_qemu()
        .ok_or("qemu-system-arm not found (apt-get install qemu-system-arm, or set STRATA_QEMU)")?;
    if !elf.is_file() {
        return Err(format!(
            "firmware image {} missing (build it with scripts/build_firmware.sh {board}, or set \
             STRATA_FIRMWARE_ELF)",
            elf.display()
        ));
    }
    Ok((qemu, elf))
}

/// A running `qemu-system-arm` with the firmware; its UART0 is a unix socket the caller is
/// connected to, its standard output (semihosting) is collected line by line. Killed on drop
/// and, on Linux, when the thread that started it ends (keep it on that thread).
pub struct Qemu {
    child: Child,
    dir: PathBuf,
    out: Arc<Mutex<Vec<String>>>,
    err: Arc<Mutex<String>>,
    readers: Vec<JoinHandle<()>>,
    status: Option<ExitStatus>,
}

fn scratch_dir() -> Result<PathBuf, String> {
    use std::sync::atomic::AtomicU32;
    static N: AtomicU32 = AtomicU32::new(0);
    let n = N.fetch_add(1, Ordering::Relaxed);
    let dir = std::env::temp_dir().join(format!("strata-hil-{}-{n}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    Ok(dir)
}

/// On Linux, QEMU gets SIGKILL when the thread that started it ends (`PR_SET_PDEATHSIG`):
/// a test run that is killed (a CI timeout, Ctrl-C) leaves no emulator spinning behind.
#[cfg(target_os = "linux")]
fn die_with_parent(cmd: &mut Command) {
    use std::os::unix::process::CommandExt;
    extern "C" {
        fn prctl(option: i32, ...) -> i32;
    }
    const PR_SET_PDEATHSIG: i32 = 1;
    const SIGKILL: u64 = 9;
    // SAFETY: `prctl(PR_SET_PDEATHSIG, SIGKILL)` only sets a flag of the forked child; it is
    // async-signal-safe and touches no memory of the parent.
    unsafe {
        cmd.pre_exec(|| {
            prctl(PR_SET_PDEATHSIG, SIGKILL);
            Ok(())
        });
    }
}

#[cfg(not(target_os = "linux"))]
fn die_with_parent(_: &mut Command) {}

impl Qemu {
    /// Starts `qemu` on `elf` (Cortex-M3, the image's machine: [`qemu_machine`];
    /// `-icount shift=0`, semihosting, UART0 on a unix socket QEMU waits on) and connects to
    /// the UART within `timeout`. With `echo`
    /// every line QEMU prints is copied to standard error as it comes.
    pub fn start(
        qemu: &Path,
        elf: &Path,
        echo: bool,
        timeout: Duration,
    ) -> Result<(Self, UnixStream), String> {
        let dir = scratch_dir()?;
        let sock = dir.join("uart0.sock");
        // A missing image gets QEMU's own error below.
        let machine = qemu_machine(&std::fs::read(elf).unwrap_or_default());
        let mut cmd = Command::new(qemu);
        die_with_parent(&mut cmd);
        let mut child = cmd
            .args(["-cpu", "cortex-m3", "-machine", &machine, "-nographic"])
            .args(["-icount", "shift=0", "-semihosting-config", "enable=on,target=native"])
            .arg("-serial")
            .arg(format!("unix:{},server=on,wait=on", sock.display()))
            .arg("-kernel")
            .arg(elf)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(|e| format!("{}: {e}", qemu.display()))?;
        let out = Arc::new(Mutex::new(Vec::new()));
        let err = Arc::new(Mutex::new(String::new()));
        let mut readers = Vec::new();
        if let Some(stdout) = child.stdout.take() {
            let out = out.clone();
            readers.push(std::thread::spawn(move || {
                for line in BufReader::new(stdout).lines() {
                    let Ok(line) = line else { break };
                    // The monitor's prompt (QEMU's monitor shares standard output).
                    let line = line.trim_start_matches("(qemu) ").to_string();
                    if echo {
                        eprintln!("qemu| {line}");
                    }
                    out.lock().unwrap().push(line);
                }
            }));
        }
        if let Some(mut stderr) = child.stderr.take() {
            let err = err.clone();
            readers.push(std::thread::spawn(move || {
                let mut buf = [0u8; 1024];
                while let Ok(n) = stderr.read(&mut buf) {
                    if n == 0 {
                        break;
                    }
                    let s = String::from_utf8_lossy(&buf[..n]);
                    if echo {
                        eprint!("qemu! {s}");
                    }
                    err.lock().unwrap().push_str(&s);
                }
            }));
        }
        let mut me = Self { child, dir, out, err, readers, status: None };
        let t0 = Instant::now();
        loop {
            if let Some(s) = me.exit_status() {
                return Err(format!(
                    "qemu exited before its UART was connected ({s}): {}",
                    me.stderr()
                ));
            }
            if let Ok(stream) = UnixStream::connect(&sock) {
                return Ok((me, stream));
            }
            if t0.elapsed() > timeout {
                return Err(format!(
                    "qemu's UART socket {} did not accept within {:.0} s: {}",
                    sock.display(),
                    timeout.as_secs_f64(),
                    me.stderr()
                ));
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// The lines QEMU printed so far.
    pub fn lines(&self) -> Vec<String> {
        self.out.lock().unwrap().clone()
    }

    /// What QEMU wrote on its standard error so far.
    pub fn stderr(&self) -> String {
        self.err.lock().unwrap().trim().to_string()
    }

    /// The exit status, once QEMU ended.
    pub fn exit_status(&mut self) -> Option<ExitStatus> {
        if self.status.is_none() {
            self.status = self.child.try_wait().ok().flatten();
        }
        self.status
    }

    /// Waits until `done(lines)` holds, QEMU exits or `timeout` passes; returns whether
    /// `done` held.
    pub fn wait_for(&mut self, timeout: Duration, done: impl Fn(&[String]) -> bool) -> bool {
        let t0 = Instant::now();
        loop {
            if done(&self.out.lock().unwrap()) {
                return true;
            }
            if self.exit_status().is_some() {
                // Let the reader drain what QEMU printed last.
                std::thread::sleep(Duration::from_millis(100));
                return done(&self.out.lock().unwrap());
            }
            if t0.elapsed() > timeout {
                return false;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

impl Drop for Qemu {
    fn drop(&mut self) {
        if self.exit_status().is_none() {
            let _ = self.child.kill();
        }
        let _ = self.child.wait();
        for r in self.readers.drain(..) {
            let _ = r.join();
        }
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

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

/// A fault-injecting relay between a device's UART socket and the host: every frame (split
/// at its `0x00` delimiter) goes through a [`Wire`] per direction with seeded [`Faults`]
/// (frame drop, byte corruption, byte loss, duplication, delay) at `baud`, timed on the wall
/// clock's milliseconds. Runs on its own thread until dropped or either side closes.
pub struct Relay {
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<Result<RelayStats, String>>>,
}

struct Direction {
    /// `STRATA_HIL_TRACE`: each frame's header on standard error, with this label.
    trace: Option<&'static str>,
    wire: Wire,
    partial: Vec<u8>,
    out: Vec<u8>,
    frames: u64,
    delivered: u64,
}

impl Direction {
    /// Reads what is available; false when the peer closed.
    fn read_from(&mut self, s: &mut UnixStream, now_ms: u64) -> Result<bool, String> {
        let mut buf = [0u8; 4096];
        loop {
            match s.read(&mut buf) {
                Ok(0) => return Ok(false),
                Ok(n) => {
                    for &b in &buf[..n] {
                        self.partial.push(b);
                        // A frame ends at its delimiter; garbage without one is passed on in
                        // pieces (the decoder resynchronises).
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
                Err(e) if e.kind() == ErrorKind::WouldBlock => return Ok(true),
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(e) => return Err(format!("relay: {e}")),
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
    /// Relays `device` (e.g. QEMU's UART socket) to the returned host end.
    pub fn spawn(
        mut device: UnixStream,
        faults: Faults,
        baud: u32,
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
                    partial: Vec::new(),
                    out: Vec::new(),
                    frames: 0,
                    delivered: 0,
                };
                let (mut h2d, mut d2h) = (dir(11, "host->dev"), dir(12, "dev->host"));
                let t0 = Instant::now();
                let mut last = 0u64;
                let result = loop {
                    if stop2.load(Ordering::Relaxed) {
                        break Ok(());
                    }
                    let now = t0.elapsed().as_millis() as u64 + 1;
                    match (h2d.read_from(&mut near, now), d2h.read_from(&mut device, now)) {
                        (Ok(true), Ok(true)) => {}
                        (Err(e), _) | (_, Err(e)) => break Err(e),
                        _ => break Ok(()),
                    }
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

/// The in-process simulated printer ([`crate::serial::serve_device`]) on one end of a
/// [`UnixStream`] pair, on a thread with a large stack: the same harness without QEMU.
pub struct SimDevice {
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<Result<DeviceState, String>>>,
}

impl SimDevice {
    /// Starts a device announcing `caps`, its motion `speedup` times faster than real time;
    /// returns it and the host's end.
    pub fn start(caps: Capacities, speedup: u64) -> Result<(Self, UnixStream), String> {
        let (host_end, mut dev) = UnixStream::pair().map_err(|e| e.to_string())?;
        dev.set_read_timeout(Some(Duration::from_millis(1))).map_err(|e| e.to_string())?;
        let stop = Arc::new(AtomicBool::new(false));
        let stop2 = stop.clone();
        let thread = std::thread::Builder::new()
            .name("hil-sim-device".into())
            .stack_size(512 << 20)
            .spawn(move || {
                let machine = strata::machine::MachineConfig::default();
                crate::serial::serve_device(&mut dev, &machine, caps, speedup, &stop2)
            })
            .map_err(|e| e.to_string())?;
        Ok((Self { stop, thread: Some(thread) }, host_end))
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

/// A closed cylinder of radius `r` and height `h` um with `n` sides at (100 mm, 100 mm), its
/// side cut into bands `band` um high (no face spans many layers, so no triangle batch
/// completes many layers at once), zmin-sorted: a test model of any size.
pub fn banded_cylinder(r: f64, h: i32, n: usize, band: i32) -> Vec<Triangle> {
    let o = 100_000;
    let p = |k: usize, z: i32| {
        let a = std::f64::consts::TAU * (k % n) as f64 / n as f64;
        Point3::new(o + (r * a.cos()).round() as i32, o + (r * a.sin()).round() as i32, z)
    };
    let (c0, c1) = (Point3::new(o, o, 0), Point3::new(o, o, h));
    let mut t = Vec::new();
    let zs: Vec<i32> = (0..h).step_by(band as usize).chain([h]).collect();
    for k in 0..n {
        for w in zs.windows(2) {
            let (a, b) = (w[0], w[1]);
            t.push(Triangle { v: [p(k, a), p(k + 1, a), p(k + 1, b)] });
            t.push(Triangle { v: [p(k, a), p(k + 1, b), p(k, b)] });
        }
        t.push(Triangle { v: [c0, p(k + 1, 0), p(k, 0)] });
        t.push(Triangle { v: [c1, p(k, h), p(k + 1, h)] });
    }
    t.sort_by_key(Triangle::z_min);
    t
}

/// The link timing of the harness: the protocol's retransmission and keepalive, and 20 s
/// before the link counts as dead (an emulated device under load may fall silent for
/// seconds of wall time while it slices).
pub fn hil_link() -> LinkConfig {
    let mut c = LinkConfig::default();
    c.dead_ms = 20_000;
    c
}

/// A connected host: its endpoint, clock origin and the device's capacities.
pub struct Connected {
    /// Host endpoint.
    pub ep: HostEndpoint,
    /// Origin of the link's millisecond clock.
    pub t0: Instant,
    /// What the device announced.
    pub caps: Capacities,
}

/// Hello and capacities over `port` (with a read timeout set, e.g. 1 ms).
pub fn connect<P: Read + Write>(port: &mut P) -> Result<Connected, String> {
    let t0 = Instant::now();
    let mut ep = HostEndpoint::new(hil_link());
    let caps = crate::serial::connect(port, &mut ep, t0)?;
    Ok(Connected { ep, t0, caps })
}

/// The triangles to stream for `tris` to a device with `caps`, decided as `strata print`
/// decides ([`admit_job`]: the slicer's needs, simplified within the measured deviation
/// `max_deviation_mm` if need be, then the toolpath stage's needs and the moves per layer),
/// the job for them, and a note when they were simplified. A refusal is an error: the
/// hardware-in-the-loop test streams exactly what the real tool would.
pub fn admitted(
    tris: &[Triangle],
    job: JobSpec,
    caps: &Capacities,
    max_deviation_mm: f64,
) -> Result<(Vec<Triangle>, JobSpec, Option<String>), String> {
    let machine = strata::machine::MachineConfig::default();
    let (t, note) = match admit_job(tris, &machine, &job, caps, max_deviation_mm)? {
        Admission::Unchanged(_) => (tris.to_vec(), None),
        Admission::Simplified(s) => {
            let note = format!(
                "simplified from {} to {} triangles (measured deviation {:.3} mm)",
                s.triangles_in,
                s.triangles.len(),
                s.max_deviation_mm
            );
            (s.triangles, Some(note))
        }
    };
    let job = JobSpec { triangles: t.len() as u32, ..job };
    Ok((t, job, note))
}

/// Streams the job with [`crate::serial::print`] and waits for the device to report it
/// done; past `timeout` the host aborts it (and the result is an error saying so). An error
/// ends with what the host saw last (triangles sent, layer reports, status). `on_progress`
/// is called about every 100 ms.
pub fn print_job<P: Read + Write>(
    port: &mut P,
    conn: &mut Connected,
    tris: &[Triangle],
    job: JobSpec,
    timeout: Duration,
    mut on_progress: impl FnMut(&Progress),
) -> Result<Progress, String> {
    let mut last = Progress::default();
    let abort = AtomicBool::new(false);
    let finished = AtomicBool::new(false);
    let timed_out = AtomicBool::new(false);
    let r = std::thread::scope(|s| {
        s.spawn(|| {
            let t0 = Instant::now();
            while !finished.load(Ordering::Relaxed) {
                if t0.elapsed() > timeout {
                    timed_out.store(true, Ordering::Relaxed);
                    abort.store(true, Ordering::Relaxed);
                    break;
                }
                std::thread::sleep(Duration::from_millis(50));
            }
        });
        let r =
            crate::serial::print(port, &mut conn.ep, conn.t0, conn.caps, tris, job, &abort, |p| {
                last = p.clone();
                on_progress(p);
            });
        finished.store(true, Ordering::Relaxed);
        r
    });
    let seen = || {
        format!(
            "; last seen: {} of {} triangles sent, {} layer reports, status {:?}, host link {:?}",
            last.triangles_sent,
            tris.len(),
            last.layer_hashes.len(),
            last.status,
            conn.ep.stats()
        )
    };
    if timed_out.load(Ordering::Relaxed) {
        return Err(format!(
            "the job did not end within {:.0} s (aborted){}",
            timeout.as_secs_f64(),
            seen()
        ));
    }
    r.map_err(|e| e + &seen())
}

/// One `TAG key=value ...` line of the firmware's standard output.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Record {
    /// The first word (`COST`, `MEM`, `STEPS`, `JOB`).
    pub tag: String,
    /// The `key=value` pairs with decimal integer values.
    pub fields: BTreeMap<String, u64>,
    /// Every `key=value` pair as written.
    pub text: BTreeMap<String, String>,
}

/// Parses `TAG k=v k=v` (a tag in capitals, then only `key=value` words); `None` for other
/// lines.
pub fn parse_record(line: &str) -> Option<Record> {
    let mut words = line.split_whitespace();
    let tag = words.next()?;
    if !tag.chars().all(|c| c.is_ascii_uppercase() || c == '_') {
        return None;
    }
    let mut fields = BTreeMap::new();
    let mut text = BTreeMap::new();
    for w in words {
        let (k, v) = w.split_once('=')?;
        if let Ok(n) = v.parse::<u64>() {
            fields.insert(k.to_string(), n);
        }
        text.insert(k.to_string(), v.to_string());
    }
    (!text.is_empty()).then(|| Record { tag: tag.to_string(), fields, text })
}

/// The firmware's cost, step and memory lines of one job.
#[derive(Debug, Clone, Default)]
pub struct Costs {
    /// Per layer (`COST layer=K ...`): layer, instructions for toolpath and planning, print
    /// time in timer ticks.
    pub layers: Vec<LayerCost>,
    /// Every other record (job, interrupt, steps and memory lines).
    pub records: Vec<Record>,
}

/// One layer's cost.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LayerCost {
    /// Layer index.
    pub layer: u64,
    /// Instructions spent on the layer's toolpath and planning.
    pub compute_insns: u64,
    /// The slicing and toolpath part of `compute_insns` (the rest: planning, steps).
    pub service_insns: u64,
    /// The layer's print time, timer ticks.
    pub print_ticks: u64,
}

impl Costs {
    /// Collects the records of `lines`.
    pub fn parse(lines: &[String]) -> Self {
        let mut c = Self::default();
        for r in lines.iter().filter_map(|l| parse_record(l)) {
            match (r.fields.get("layer"), r.tag.as_str()) {
                (Some(&layer), "COST") => c.layers.push(LayerCost {
                    layer,
                    compute_insns: first(&r, &["compute_insns", "insns"]).unwrap_or(0),
                    service_insns: first(&r, &["service_insns"]).unwrap_or(0),
                    print_ticks: first(&r, &["print_ticks", "ticks"]).unwrap_or(0),
                }),
                _ => c.records.push(r),
            }
        }
        c
    }

    /// The last value of the first of `keys` a record tagged `tag` has.
    pub fn get(&self, tag: &str, keys: &[&str]) -> Option<u64> {
        self.record(tag, keys).and_then(|(r, k)| r.fields.get(k).copied())
    }

    /// The same as written (e.g. a hexadecimal hash).
    pub fn text(&self, tag: &str, keys: &[&str]) -> Option<&str> {
        self.record(tag, keys).and_then(|(r, k)| r.text.get(k).map(String::as_str))
    }

    fn record<'k>(&self, tag: &str, keys: &[&'k str]) -> Option<(&Record, &'k str)> {
        keys.iter().find_map(|&k| {
            self.records
                .iter()
                .rev()
                .find(|r| r.tag == tag && r.text.contains_key(k))
                .map(|r| (r, k))
        })
    }

    /// The firmware's `STEPS` line: steps per axis and final positions (X, Y, Z, E), the
    /// executed print time in timer ticks.
    pub fn steps(&self) -> Option<StepsLine> {
        let axes = ["x", "y", "z", "e"];
        let mut s = StepsLine::default();
        for (a, k) in axes.iter().enumerate() {
            s.steps[a] = self.get("STEPS", &[k])?;
            s.positions[a] = self.text("STEPS", &[&format!("pos_{k}")])?.parse().ok()?;
        }
        s.print_ticks = self.get("STEPS", &["print_ticks"]);
        s.hash = self.text("STEPS", &["hash"]).and_then(|h| u64::from_str_radix(h, 16).ok());
        Some(s)
    }
}

/// What the firmware's `STEPS` line says.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct StepsLine {
    /// Steps per axis.
    pub steps: [u64; 4],
    /// Final positions, steps.
    pub positions: [i64; 4],
    /// Executed print time, timer ticks.
    pub print_ticks: Option<u64>,
    /// Hash of every step (axis, direction, tick).
    pub hash: Option<u64>,
}

fn first(r: &Record, keys: &[&str]) -> Option<u64> {
    keys.iter().find_map(|k| r.fields.get(*k).copied())
}

/// Clock of the cost model: the Creality board's 72 MHz Cortex-M3.
pub const CPU_HZ: f64 = 72e6;
/// Cycles per instruction assumed (flash wait states, loads, branches).
pub const CYCLES_PER_INSN: f64 = 1.5;

/// The cost figures of one job.
#[derive(Debug, Clone, Copy, Default)]
pub struct CostSummary {
    /// Triangles sliced.
    pub triangles: u64,
    /// Slicing instructions per triangle.
    pub insns_per_triangle: f64,
    /// Layers with a cost line.
    pub layers: usize,
    /// Toolpath and planning instructions per layer, mean.
    pub layer_insns_mean: f64,
    /// The same, largest.
    pub layer_insns_max: u64,
    /// Interrupt instructions per step, mean.
    pub isr_insns_per_step: f64,
    /// Interrupt invocations (with the QEMU board's virtual clock, also those without a step).
    pub isr_calls: u64,
    /// Interrupt instructions per invocation, mean.
    pub isr_insns_per_call: f64,
    /// The most instructions of one interrupt.
    pub isr_insns_max: u64,
    /// Steps the interrupt made.
    pub steps: u64,
    /// Worst layer's real-time factor at [`CPU_HZ`] and [`CYCLES_PER_INSN`]: its print time
    /// over its compute time.
    pub worst_rtf: f64,
    /// Which layer.
    pub worst_rtf_layer: u64,
    /// The longest stretch of slicing and toolpath work without step generation in thread
    /// mode (the step queue must cover it), instructions.
    pub gen_gap_max_insns: u64,
    /// RAM in `.data` and `.bss`, bytes.
    pub data_bss: Option<u64>,
    /// Deepest stack use seen, bytes.
    pub stack_hwm: Option<u64>,
}

impl CostSummary {
    /// The figures of `c`, with print ticks at `timer_hz`.
    pub fn of(c: &Costs, timer_hz: f64) -> Self {
        let triangles = c.get("COST", &["triangles"]).unwrap_or(0);
        let slice = c.get("COST", &["slice_insns"]).unwrap_or(0);
        let steps = c.get("COST", &["steps"]).unwrap_or(0);
        let isr_total = c.get("COST", &["isr_insns_total", "isr_insns"]).unwrap_or(0);
        let isr_calls = c.get("COST", &["isr_calls"]).unwrap_or(0);
        let n = c.layers.len();
        let total: u64 = c.layers.iter().map(|l| l.compute_insns).sum();
        let mut worst = (f64::INFINITY, 0);
        for l in &c.layers {
            let compute_s = l.compute_insns as f64 * CYCLES_PER_INSN / CPU_HZ;
            let print_s = l.print_ticks as f64 / timer_hz;
            if compute_s > 0.0 && print_s / compute_s < worst.0 {
                worst = (print_s / compute_s, l.layer);
            }
        }
        Self {
            triangles,
            insns_per_triangle: slice as f64 / triangles.max(1) as f64,
            layers: n,
            layer_insns_mean: total as f64 / n.max(1) as f64,
            layer_insns_max: c.layers.iter().map(|l| l.compute_insns).max().unwrap_or(0),
            isr_insns_per_step: isr_total as f64 / steps.max(1) as f64,
            isr_calls,
            isr_insns_per_call: isr_total as f64 / isr_calls.max(1) as f64,
            isr_insns_max: c.get("COST", &["isr_insns_max", "isr_max"]).unwrap_or(0),
            steps,
            worst_rtf: worst.0,
            worst_rtf_layer: worst.1,
            gen_gap_max_insns: c.get("COST", &["gen_gap_max_insns"]).unwrap_or(0),
            data_bss: c.get("MEM", &["data_bss"]),
            stack_hwm: c.get("MEM", &["stack_hwm"]),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cost_lines_parse_and_summarise() {
        let lines: Vec<String> = [
            "strata firmware qemu",
            "COST layer=0 compute_insns=1000 print_ticks=72000000",
            "COST layer=1 compute_insns=4000 print_ticks=7200000",
            "COST triangles=12 slice_insns=1200",
            "COST isr_calls=10 isr_insns_total=1000 isr_insns_max=300 steps=8",
            "STEPS x=5 y=3 z=0 e=0 pos_x=-1 pos_y=3 pos_z=0 pos_e=0 hash=00ff print_ticks=9",
            "MEM data_bss=60000 stack_hwm=2000 stack_size=4096",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        let c = Costs::parse(&lines);
        assert_eq!(c.layers.len(), 2);
        let s = CostSummary::of(&c, 72e6);
        assert_eq!(s.triangles, 12);
        assert_eq!(s.insns_per_triangle, 100.0);
        assert_eq!(s.layer_insns_max, 4000);
        assert_eq!(s.isr_insns_per_step, 125.0);
        assert_eq!(s.isr_insns_per_call, 100.0);
        assert_eq!(s.isr_insns_max, 300);
        // Layer 1: 0.1 s of print over 4000 * 1.5 / 72e6 s of compute.
        assert_eq!(s.worst_rtf_layer, 1);
        assert!((s.worst_rtf - 1200.0).abs() < 1e-6, "{}", s.worst_rtf);
        assert_eq!(s.data_bss, Some(60000));
        let st = c.steps().unwrap();
        assert_eq!(st.steps, [5, 3, 0, 0]);
        assert_eq!(st.positions, [-1, 3, 0, 0]);
        assert_eq!((st.print_ticks, st.hash), (Some(9), Some(255)));
        assert!(parse_record("hello world").is_none());
        assert!(parse_record("SOFT LIMIT axis=1").is_none());
    }

    #[test]
    fn the_machine_comes_from_the_images_tag() {
        let mut elf = vec![0u8; 64];
        elf.extend_from_slice(b"strata-qemu-machine=mps2-an385\0more");
        assert_eq!(qemu_machine(&elf), "mps2-an385");
        assert_eq!(qemu_machine(b"\x7fELF no tag here"), "lm3s6965evb");
        // A tag without a name is no tag.
        assert_eq!(qemu_machine(b"strata-qemu-machine=\0"), "lm3s6965evb");
    }
}
