//! QEMU running the firmware: finding QEMU and the image, the process (UART0 on a unix
//! socket, semihosting lines collected, the monitor on a second socket) and its instruction
//! clock as a [`LinkClock`] ([`QemuClock`]).

use std::io::{BufRead, BufReader, Read, Write};
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use super::costs::parse_record;
use crate::clock::{LinkClock, StallCheck, CLOCK_STALL_LIMIT};

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

/// The QEMU machine a firmware image is built for.
///
/// The `strata-qemu-machine=NAME` tag the QEMU boards carry (`lm3s6965evb`, or `mps2-an385` for the
/// `qemu-mps2` build); `lm3s6965evb` when the image has none.
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

/// How long QEMU may take to accept the UART connection, wall time.
///
/// It waits for that connection before it runs anything, so this is process start-up alone
/// (milliseconds on an idle machine, seconds on a saturated one).
pub const QEMU_ACCEPT_LIMIT: Duration = Duration::from_secs(60);

/// A running `qemu-system-arm` with the firmware.
///
/// Its UART0 is a unix socket the caller is connected to, its standard output (semihosting) is
/// collected line by line. Killed on drop and, on Linux, when the thread that started it ends (keep
/// it on that thread).
pub struct Qemu {
    child: Child,
    dir: PathBuf,
    monitor: PathBuf,
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
    /// `-icount shift=0`, semihosting, UART0 on a unix socket QEMU waits on, the monitor on
    /// another) and connects to the UART within [`QEMU_ACCEPT_LIMIT`] of wall time. With
    /// `echo` every line QEMU prints is copied to standard error as it comes.
    pub fn start(qemu: &Path, elf: &Path, echo: bool) -> Result<(Self, UnixStream), String> {
        Self::start_with_card(qemu, elf, echo, None)
    }

    /// [`Qemu::start`] with `card` (a raw image, its size a power of two) in the board's SD
    /// card slot (`lm3s6965evb`: on SSI0).
    pub fn start_with_card(
        qemu: &Path,
        elf: &Path,
        echo: bool,
        card: Option<&Path>,
    ) -> Result<(Self, UnixStream), String> {
        let dir = scratch_dir()?;
        let sock = dir.join("uart0.sock");
        let monitor = dir.join("monitor.sock");
        // A missing image gets QEMU's own error below.
        let machine = qemu_machine(&std::fs::read(elf).unwrap_or_default());
        let mut cmd = Command::new(qemu);
        die_with_parent(&mut cmd);
        let mut child = cmd
            .args(["-cpu", "cortex-m3", "-machine", &machine, "-nographic"])
            .args(["-icount", "shift=0", "-semihosting-config", "enable=on,target=native"])
            .arg("-serial")
            .arg(format!("unix:{},server=on,wait=on", sock.display()))
            .arg("-monitor")
            .arg(format!("unix:{},server=on,wait=off", monitor.display()))
            .args(
                card.map(|c| format!("if=sd,format=raw,file={}", c.display()))
                    .map_or(Vec::new(), |drive| vec!["-drive".to_string(), drive]),
            )
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
        let mut me = Self { child, dir, monitor, out, err, readers, status: None };
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
            if t0.elapsed() > QEMU_ACCEPT_LIMIT {
                return Err(format!(
                    "qemu's UART socket {} did not accept within {:.0} s: {}",
                    sock.display(),
                    QEMU_ACCEPT_LIMIT.as_secs_f64(),
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

    /// Waits until `done(lines)` holds, QEMU exits or `budget_ms` of `clock` pass; whether
    /// `done` held (an error when the clock failed).
    pub fn wait_for(
        &mut self,
        clock: &mut impl LinkClock,
        budget_ms: u32,
        done: impl Fn(&[String]) -> bool,
    ) -> Result<bool, String> {
        let start = clock.now_ms()?;
        loop {
            if done(&self.out.lock().unwrap()) {
                return Ok(true);
            }
            if self.exit_status().is_some() {
                return Ok(self.drained_lines_hold(&done));
            }
            if clock.now_ms()?.wrapping_sub(start) > budget_ms {
                return Ok(false);
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// Whether `done` holds once the readers took what QEMU printed last (it exited).
    fn drained_lines_hold(&mut self, done: &impl Fn(&[String]) -> bool) -> bool {
        for r in self.readers.drain(..) {
            let _ = r.join();
        }
        done(&self.out.lock().unwrap())
    }

    /// Waits up to `limit` of wall time for QEMU to exit (nothing emulated is waited for:
    /// an image QEMU cannot run ends the process); whether it did.
    pub fn wait_exit(&mut self, limit: Duration) -> bool {
        let t0 = Instant::now();
        while self.exit_status().is_none() {
            if t0.elapsed() > limit {
                return false;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        true
    }

    /// The firmware's instruction clock, read through the monitor: waits for the image's
    /// `CLOCK wraps_at=ADDR wrap_ns=NS` line (its SysTick wrap counter and the emulated
    /// nanoseconds of one wrap), for as long as QEMU's clock may stand still.
    pub fn clock(&mut self) -> Result<QemuClock, String> {
        let t0 = Instant::now();
        let announced = |lines: &[String]| {
            lines
                .iter()
                .filter_map(|l| parse_record(l))
                .find(|r| r.tag == "CLOCK")
                .and_then(|r| Some((*r.fields.get("wraps_at")?, *r.fields.get("wrap_ns")?)))
        };
        loop {
            if let Some((addr, wrap_ns)) = announced(&self.out.lock().unwrap()) {
                let addr = u32::try_from(addr).map_err(|_| "CLOCK: address beyond 32 bits")?;
                return QemuClock::connect(&self.monitor, addr, wrap_ns);
            }
            if let Some(s) = self.exit_status() {
                return Err(format!(
                    "qemu exited ({s}) before the firmware announced its clock: {}",
                    self.stderr()
                ));
            }
            if t0.elapsed() > CLOCK_STALL_LIMIT {
                return Err(format!(
                    "no `CLOCK` line from the firmware within {:.0} s (an image older than the \
                     harness? rebuild it with scripts/build_firmware.sh)",
                    CLOCK_STALL_LIMIT.as_secs_f64()
                ));
            }
            std::thread::sleep(Duration::from_millis(5));
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

/// How long one reading of QEMU's clock stays current, wall time: the monitor is asked at
/// most this often however many threads read the clock.
const CLOCK_REFRESH: Duration = Duration::from_millis(1);
/// How long the monitor may take to answer, wall time: a hang guard only (its thread waits
/// for the emulated CPU to yield: seconds on a saturated machine, and a reviewer's run with
/// five busy processes on two cores saw more than 30 s during a card upload).
const MONITOR_ANSWER_LIMIT: Duration = Duration::from_secs(120);

/// QEMU's instruction clock (`-icount shift=0`: 1 ns of emulated time per instruction) as a link
/// clock in emulated milliseconds.
///
/// The firmware's 32-bit SysTick wrap counter, read with the monitor's `xp` (physical memory),
/// wraps accumulated into 64 bits. Shared by clones (the host and the relay read one clock); an
/// error once QEMU is gone or its clock stood still for [`CLOCK_STALL_LIMIT`].
#[derive(Clone)]
pub struct QemuClock {
    inner: Arc<Mutex<MonitorClock>>,
}

struct MonitorClock {
    monitor: UnixStream,
    command: String,
    wrap_ns: u64,
    last_raw: Option<u32>,
    wraps: u64,
    read_at: Option<Instant>,
    stall: StallCheck,
}

impl QemuClock {
    fn connect(path: &Path, addr: u32, wrap_ns: u64) -> Result<Self, String> {
        let monitor = UnixStream::connect(path)
            .map_err(|e| format!("qemu's monitor {}: {e}", path.display()))?;
        monitor.set_read_timeout(Some(MONITOR_ANSWER_LIMIT)).map_err(|e| e.to_string())?;
        let mut m = MonitorClock {
            monitor,
            command: format!("xp /1wx {addr:#x}\n"),
            wrap_ns,
            last_raw: None,
            wraps: 0,
            read_at: None,
            stall: StallCheck::new("qemu", CLOCK_STALL_LIMIT),
        };
        m.until_prompt()?;
        m.read()?;
        Ok(Self { inner: Arc::new(Mutex::new(m)) })
    }
}

impl MonitorClock {
    /// What the monitor wrote up to its next `(qemu) ` prompt.
    fn until_prompt(&mut self) -> Result<String, String> {
        let mut text = Vec::new();
        let mut buf = [0u8; 512];
        while !text.ends_with(b"(qemu) ") {
            match self.monitor.read(&mut buf) {
                Ok(0) => return Err("qemu exited (its monitor closed)".into()),
                Ok(n) => text.extend_from_slice(&buf[..n]),
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e)
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                    ) =>
                {
                    return Err(format!(
                        "qemu's monitor did not answer within {:.0} s",
                        MONITOR_ANSWER_LIMIT.as_secs_f64()
                    ))
                }
                Err(e) => return Err(format!("qemu's monitor: {e}")),
            }
        }
        Ok(String::from_utf8_lossy(&text).into_owned())
    }

    /// Reads the wrap counter: `ADDRESS: 0xVALUE` on the answer's last line.
    fn read(&mut self) -> Result<(), String> {
        self.monitor
            .write_all(self.command.as_bytes())
            .map_err(|e| format!("qemu's monitor: {e}"))?;
        let answer = self.until_prompt()?;
        let raw = answer
            .lines()
            .filter_map(|l| l.split_once(": 0x"))
            .filter_map(|(_, v)| u32::from_str_radix(v.trim(), 16).ok())
            .next_back()
            .ok_or_else(|| format!("qemu's monitor answered {answer:?}"))?;
        let last = self.last_raw.replace(raw).unwrap_or(raw);
        self.wraps += raw.wrapping_sub(last) as u64;
        let now = Instant::now();
        self.read_at = Some(now);
        self.stall.check(self.wraps, now)
    }
}

impl LinkClock for QemuClock {
    fn now_ms(&mut self) -> Result<u32, String> {
        let mut m = self.inner.lock().map_err(|_| "qemu clock poisoned")?;
        if m.read_at.map_or(true, |t| t.elapsed() >= CLOCK_REFRESH) {
            m.read()?;
        }
        Ok((m.wraps * m.wrap_ns / 1_000_000) as u32)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
