//! Hardware in the loop.
//!
//! The firmware's QEMU build (`lm3s6965evb`, UART0 on a unix socket) driven by the real host code
//! ([`crate::serial`]), a seeded fault-injecting relay between the two ([`Relay`], built on the
//! simulated link's [`crate::simjob::Wire`]), and the firmware's cost lines on QEMU's standard
//! output ([`Costs`]). The same harness serves the in-process simulated printer ([`SimDevice`]):
//! see `host/tests/hil_qemu.rs` and `host/examples/job_cost.rs`.
//!
//! Every timer runs on the device's clock: QEMU's instruction clock ([`QemuClock`]) or the
//! simulated printer's turns ([`SimClock`]). The host's link (retransmission, keepalive, the
//! dead link), the relay's baud rate and delays and every job's budget ([`print_job`]) follow
//! the emulated time, so a machine whose cores are busy elsewhere slows the whole exchange
//! without changing what either side decides. Wall time only bounds what emulates nothing:
//! QEMU's start-up ([`QEMU_ACCEPT_LIMIT`]) and a clock that stands still
//! ([`crate::clock::CLOCK_STALL_LIMIT`]).

mod costs;
mod qemu;
mod relay;
mod sim_device;

use std::io::{Read, Write};

use strata::geom::{Point3, Triangle};
use strata::protocol::{Capacities, JobSpec, LinkConfig};

use crate::admission::{admit_job_paced, Admission};
use crate::clock::{Budget, LinkClock};
use crate::serial::Port;
use crate::session::{Greeting, HostEndpoint, Progress, Source};

pub use costs::{
    parse_record, CostSummary, Costs, LayerCost, Record, StepsLine, CPU_HZ, CYCLES_PER_INSN,
};
pub use qemu::{
    build_output, find_qemu, firmware_elf, locate, locate_image, qemu_machine, repo_root, Qemu,
    QemuClock, QEMU_ACCEPT_LIMIT,
};
pub use relay::{Relay, RelayStats};
pub use sim_device::{SimClock, SimDevice};

/// The link timing of the harness: the protocol's own (what `strata print` uses with a real
/// printer), on the device's clock.
pub fn hil_link() -> LinkConfig {
    LinkConfig::default()
}

/// A connected host: its endpoint and the device's answer to its hello.
pub struct Connected {
    /// Host endpoint.
    pub ep: HostEndpoint,
    /// The device's answer to the hello: its capacities, status and a parked job.
    pub greeting: Greeting,
}

/// Hello and capacities over `port` (with a read timeout set, e.g. 1 ms), on `clock`.
pub fn connect<P: Read + Write>(
    port: &mut Port<P>,
    clock: &mut impl LinkClock,
) -> Result<Connected, String> {
    let mut ep = HostEndpoint::new(hil_link());
    let greeting = crate::serial::connect(port, &mut ep, clock)?;
    Ok(Connected { ep, greeting })
}

/// [`admitted`] while the link is kept alive, as `strata print` does.
pub fn admitted_on_link<P: Read + Write>(
    port: &mut Port<P>,
    conn: &mut Connected,
    clock: &mut impl LinkClock,
    tris: &[Triangle],
    job: JobSpec,
    max_deviation_mm: f64,
) -> Result<(Vec<Triangle>, JobSpec, Option<String>), String> {
    let caps = conn.greeting.capacities;
    crate::serial::keeping_link_alive(port, &mut conn.ep, clock, || {
        admitted(tris, job, &caps, max_deviation_mm)
    })?
}

/// The link's baud rate in the hardware-in-the-loop runs (the relay's; `strata print`'s default).
pub const BAUD: u32 = 250_000;

/// The triangles to stream for `tris` to a device with `caps`, the job for them, and a note when
/// they were simplified, decided as `strata print` decides.
///
/// [`admit_job_paced`]: the slicer's needs, simplified within the measured deviation
/// `max_deviation_mm` if need be, then the toolpath stage's needs and the moves per layer, then
/// the link's pace at [`BAUD`].
///
/// A refusal is an error: the hardware-in-the-loop test streams exactly what the real tool would.
pub fn admitted(
    tris: &[Triangle],
    job: JobSpec,
    caps: &Capacities,
    max_deviation_mm: f64,
) -> Result<(Vec<Triangle>, JobSpec, Option<String>), String> {
    let machine = strata::machine::MachineConfig::default();
    let paced = admit_job_paced(tris, &machine, &job, caps, max_deviation_mm, BAUD)?;
    let (t, note) = match paced.admission {
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

/// Streams the job with [`crate::serial::print`] on `clock` and waits for the device to report it
/// done.
///
/// Past `budget_ms` of the clock the job ends with an error saying so. An error ends with what the
/// host saw last (triangles sent, layer reports, status). `on_progress` is called about every 100
/// ms of the clock.
pub fn print_job<P: Read + Write>(
    port: &mut Port<P>,
    conn: &mut Connected,
    clock: impl LinkClock,
    source: Source<'_>,
    budget_ms: u32,
    on_progress: impl FnMut(&Progress),
) -> Result<Progress, String> {
    let never = std::sync::atomic::AtomicBool::new(false);
    print_job_or_abort(port, conn, clock, source, budget_ms, &never, on_progress)
}

/// [`print_job`]; once `abort` is set (say by `on_progress`) the host aborts the job as
/// `strata print` does on Ctrl-C.
#[allow(clippy::too_many_arguments)]
pub fn print_job_or_abort<P: Read + Write>(
    port: &mut Port<P>,
    conn: &mut Connected,
    clock: impl LinkClock,
    source: Source<'_>,
    budget_ms: u32,
    abort: &std::sync::atomic::AtomicBool,
    on_progress: impl FnMut(&Progress),
) -> Result<Progress, String> {
    run_job(port, conn, clock, source, false, budget_ms, abort, on_progress)
}

/// [`print_job`] of the job the device parked when its last host went silent, as
/// `strata print --resume` does: the triangles after the ones it took.
pub fn resume_job<P: Read + Write>(
    port: &mut Port<P>,
    conn: &mut Connected,
    clock: impl LinkClock,
    source: Source<'_>,
    budget_ms: u32,
    on_progress: impl FnMut(&Progress),
) -> Result<Progress, String> {
    let never = std::sync::atomic::AtomicBool::new(false);
    run_job(port, conn, clock, source, true, budget_ms, &never, on_progress)
}

#[allow(clippy::too_many_arguments)]
fn run_job<P: Read + Write>(
    port: &mut Port<P>,
    conn: &mut Connected,
    clock: impl LinkClock,
    source: Source<'_>,
    resume: bool,
    budget_ms: u32,
    abort: &std::sync::atomic::AtomicBool,
    mut on_progress: impl FnMut(&Progress),
) -> Result<Progress, String> {
    let mut last = Progress::default();
    let mut clock = Budget::new(clock, budget_ms);
    let greeting = conn.greeting;
    let r = crate::serial::print(
        port,
        &mut conn.ep,
        &mut clock,
        &greeting,
        source,
        resume,
        abort,
        |p| {
            last = p.clone();
            on_progress(p);
        },
    );
    r.map_err(|e| {
        let sent = match source {
            Source::Model(tris, _) => {
                format!("{} of {} triangles", last.triangles_sent, tris.len())
            }
            Source::Gcode(text, _) => format!("{} of {} bytes", last.gcode_bytes_sent, text.len()),
            Source::Card { name, .. } => format!("the card's {name}: nothing"),
        };
        format!(
            "{e}; last seen: {sent} sent, {} layer reports, status {:?}, host link {:?}",
            last.layer_hashes.len(),
            last.status,
            conn.ep.stats()
        )
    })
}

/// A closed cylinder of radius `r` and height `h` um with `n` sides at (100 mm, 100 mm), its side
/// cut into bands `band` um high, zmin-sorted: a test model of any size.
///
/// No face spans many layers, so no triangle batch completes many layers at once.
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
