//! Cost figures on QEMU (`-icount shift=0`: one instruction = 1 ns of virtual time), one
//! semihosting line each:
//! - per layer `COST layer=K compute_insns=N service_insns=S print_ticks=M` (`S`: the
//!   slicing and toolpath part of `N`);
//! - per job `COST triangles=N slice_insns=N gen_gap_max_insns=N` (the longest stretch of a
//!   `service` call between two step generations: slicing and toolpaths hold the step
//!   generator that long), and the board's `COST isr_calls=...`. The steps generated at
//!   the toolpath stage's progress points inside a `service` call (the printer lends its
//!   motion half there) count with the layer whose blocks they are (the generator's tag at
//!   the last of them), not as slicing.
//!
//! Approximations:
//! - `compute_insns` are the thread-mode instructions (SysTick's and the feed interrupt's
//!   taken out) spent in `Printer::service` calls that had a message to handle, attributed to
//!   the layer the *slicer* is on when the call starts (slicing and toolpaths: the toolpath
//!   stage runs in the slicer's layer sink; a batch that completes several layers is counted
//!   to the first), less the step generation lent inside them (counted to the layer being
//!   *generated*), plus the `Printer::poll` calls that did work, attributed to the layer
//!   being *planned* (planning and step generation), plus every feed interrupt (PendSV:
//!   planning and step generation wherever it preempts thread mode), attributed to the layer
//!   whose blocks the generator had at its end;
//! - `print_ticks` is the growth of the planner's released print time (72 MHz ticks) between
//!   the reports of layer K-1 and layer K (a layer closes when the first block of the next
//!   one is released, which is counted with the earlier layer);
//! - `slice_insns` is the sum over the job of the `service` part (decoding, slicing,
//!   toolpaths: the toolpath stage runs inside the slicer's layer sink).
//!
//! A `service` call that moved nothing through the pipeline (no triangle taken, no layer cut,
//! no toolpath layer completed) waited: for room in the move buffer, or for the heaters (the
//! paths it emitted meanwhile are few; most of a layer's paths go into the move buffer in
//! `poll` calls, counted with planning, each unit's moves made twice: once replayed for the
//! buffer's byte room, which codes them to count the unit's bytes exactly, once into the
//! buffer; a unit is first offered once the job's bytes per move so far, plus a quarter, fit,
//! and one the room refused goes in on its known bytes, without a second replay). The message
//! stays at the head of the link and the printer looks at it again on the next turn, so such
//! a call is left out of both figures: it is waiting, not work (a board could sleep there
//! until the next interrupt).

use crate::board;
use crate::capacities::FwPrinter;
use crate::pipeline_motion::{FwMotion, Generation};

/// Instructions so far outside the SysTick handler (one consistent reading: a SysTick
/// between the two counters' reads retries).
pub fn outside_systick_now() -> u64 {
    loop {
        let isr = board::isr_insns_total();
        let now = board::insns_now();
        if board::isr_insns_total() == isr {
            return now - isr;
        }
    }
}

/// Thread-mode instructions so far (all instructions minus the SysTick handler's and the
/// feed interrupt's; a feed interrupt between the two counters' reads retries).
pub fn thread_now() -> u64 {
    loop {
        let feed = crate::pipeline_motion::feed_insns_total();
        let outside = outside_systick_now();
        if crate::pipeline_motion::feed_insns_total() == feed {
            return outside - feed;
        }
    }
}
use crate::log;

/// Marks the start of a measured region for `tools/job-profile/run.sh --counted` (its QEMU plugin
/// counts only between this and [`strata_counted_off`]; no effect otherwise).
#[no_mangle]
#[inline(never)]
pub extern "C" fn strata_counted_on() {
    core::hint::black_box(1u32);
}

/// Marks the end of a measured region (see [`strata_counted_on`]).
#[no_mangle]
#[inline(never)]
pub extern "C" fn strata_counted_off() {
    core::hint::black_box(2u32);
}

/// Keeps the measured region that just ended for `tools/job-profile/run.sh --counted` (called
/// after [`strata_counted_off`] when the region counts in the figures: a `service` call
/// that moved the pipeline, a `poll` that worked).
#[no_mangle]
#[inline(never)]
pub extern "C" fn strata_counted_keep() {
    core::hint::black_box(3u32);
}

/// Per-layer buckets kept (the slicer runs at most a few layers ahead of the planner).
const RING: usize = 32;

/// Cost accounting of one job.
pub struct Cost {
    /// Instructions per layer (a layer's stay below 2^32: hundreds of millions at most).
    ring: [u32; RING],
    /// The `service` part of each layer's bucket (slicing and toolpaths, lent motion work
    /// left out).
    ring_service: [u32; RING],
    /// Next layer to report.
    reported: u32,
    /// Released print time at the last report, ticks.
    planned_ticks: u64,
    slice_insns: u64,
    /// The longest stretch of a `service` call without step generation (slicing and
    /// toolpaths between the progress points where the printer lends its motion half: the
    /// step queue must cover it on a real board).
    gap_max: u64,
    active: bool,
}

/// A measurement in progress: start time (thread instructions), slicer layer, pipeline
/// progress ([`progress`]).
pub type Mark = Option<(u64, u32, (u32, u32, u32))>;

/// Triangles the slicer took, layers it cut and layers the toolpath stage emitted.
fn progress(p: &FwPrinter) -> (u32, u32, u32) {
    let s = p.slicer().stats();
    (s.triangles, s.layers, p.toolpath().layers_emitted())
}

impl Cost {
    /// Nothing measured yet.
    pub const fn new() -> Self {
        Self {
            ring: [0; RING],
            ring_service: [0; RING],
            reported: 0,
            planned_ticks: 0,
            slice_insns: 0,
            gap_max: 0,
            active: false,
        }
    }

    /// Starts measuring a `service` call when it has a message to handle; `g`: where the
    /// motion half generates steps meanwhile.
    pub fn begin(&mut self, pending: bool, p: &FwPrinter, g: &mut Generation) -> Mark {
        (self.active && pending).then(|| {
            let before = progress(p);
            let layer = p.slicer().stats().layers;
            strata_counted_on();
            let t = thread_now();
            *g = Generation {
                measuring: true,
                lent: 0,
                generated_at: t,
                gap_max: 0,
                lent_layer: layer,
            };
            (t, layer, before)
        })
    }

    fn add(&mut self, layer: u32, insns: u64, service: u64) {
        let l = layer.clamp(self.reported, self.reported + RING as u32 - 1) as usize % RING;
        let sat = |v: u64| u32::try_from(v).unwrap_or(u32::MAX);
        self.ring[l] = self.ring[l].saturating_add(sat(insns));
        self.ring_service[l] = self.ring_service[l].saturating_add(sat(service));
    }

    /// Ends a `service` measurement.
    pub fn end_service(&mut self, m: Mark, p: &FwPrinter, motion: &mut FwMotion) {
        let g = core::mem::take(&mut motion.generation);
        if let Some((t, layer, before)) = m {
            let now = thread_now();
            let d = now - t;
            strata_counted_off();
            if progress(p) == before {
                self.report(p, motion);
                return;
            }
            strata_counted_keep();
            let service = d - g.lent.min(d);
            self.slice_insns += service;
            self.gap_max = self.gap_max.max(g.gap_max).max(now - g.generated_at.max(t));
            self.add(layer, service, service);
            // The steps generated meanwhile are the work of the layer whose blocks they are.
            self.add(g.lent_layer, d - service, 0);
        }
        self.report(p, motion);
    }

    /// Starts measuring a `poll` call.
    pub fn begin_poll(&self) -> u64 {
        if self.active {
            strata_counted_on();
        }
        thread_now()
    }

    /// Ends a `poll` measurement (started at `t`); counted when the poll `worked`.
    pub fn end_poll(&mut self, t: u64, worked: bool, p: &FwPrinter, motion: &mut FwMotion) {
        if self.active {
            let d = thread_now() - t;
            strata_counted_off();
            if !worked {
                return;
            }
            strata_counted_keep();
            self.add(p.status(motion, 0).layer, d, 0);
            self.report(p, motion);
        }
    }

    /// Counts the feed interrupt's work since the last call to the layers it generated.
    fn take_feed(&mut self) {
        let (layer, insns) = crate::pipeline_motion::take_feed_work();
        self.add(layer, u64::from(insns), 0);
    }

    /// Prints the layers the planner has closed.
    fn report(&mut self, p: &FwPrinter, motion: &mut FwMotion) {
        let closed = p.status(motion, 0).layer;
        self.report_to(p, motion, closed);
    }

    /// Prints the layers before `closed`.
    fn report_to(&mut self, p: &FwPrinter, motion: &mut FwMotion, closed: u32) {
        if !self.active {
            return;
        }
        self.take_feed();
        while self.reported < closed {
            let ticks = (p.planned_s(motion) * 72e6) as u64;
            let k = self.reported as usize % RING;
            log!(
                "COST layer={} compute_insns={} service_insns={} print_ticks={}",
                self.reported,
                self.ring[k],
                self.ring_service[k],
                ticks - self.planned_ticks.min(ticks)
            );
            self.planned_ticks = ticks;
            self.ring[k] = 0;
            self.ring_service[k] = 0;
            self.reported += 1;
        }
    }

    /// A job started.
    pub fn job_started(&mut self) {
        *self = Self::new();
        crate::pipeline_motion::take_lock_max();
        crate::pipeline_motion::take_feed_work();
        self.active = true;
    }

    /// A job ended: the remaining layers (all of them when it is done) and the job's totals.
    pub fn job_ended(&mut self, p: &FwPrinter, motion: &mut FwMotion) {
        let all = p.state() == strata::protocol::DeviceState::Done;
        let closed = if all { p.layer_count() } else { p.status(motion, 0).layer };
        self.report_to(p, motion, closed);
        log!(
            "COST triangles={} slice_insns={} gen_gap_max_insns={} lock_insns_max={}",
            p.status(motion, 0).triangles,
            self.slice_insns,
            self.gap_max,
            crate::pipeline_motion::take_lock_max()
        );
        self.active = false;
    }
}
