//! A streamed job whose host went silent: it prints what it has, parks, and waits.
//!
//! A dead link no longer ends the job on the spot (the nozzle would stay on the part, the
//! heaters go off and the print is lost). The messages already received are taken as usual;
//! then the job's input ends: a G-code job's at its last complete line (a line cut short is
//! dropped, never run), a sliced job's with the layers its triangles completed (the slicer
//! cuts nothing more). The motion runs to the end
//! of that input, then the nozzle parks off the part: the filament is retracted by
//! [`GCODE_PARK_RETRACT_UM`] (a sliced job: its own retraction), the nozzle lifts
//! [`PARK_LIFT_UM`] (within the build volume) and goes to [`PARK_XY_UM`] from the back left
//! corner, as Marlin's `NOZZLE_PARK_FEATURE` does. The job is then paused: the heaters hold
//! their targets for [`DEFAULT_HEAT_HOLD_MS`] (or what the board set) so that it can be
//! resumed, then go off. Where the input ended (the layer and the position before parking)
//! is kept ([`ResumePoint`]). A job the user had paused stays where it is, paused, with the
//! same heater hold.
//!
//! A new host that opens a session hears of the parked job ([`Message::Parked`]: its layer,
//! the triangles taken and the job's fingerprint) and may resume it with the rest of the
//! same job ([`Message::Resume`]): the heaters reach their targets again, the nozzle goes
//! back over the part, down and primes (the park moves undone), and the triangles after the
//! ones taken continue the job as if nothing had happened. A sliced job's input ends with
//! its last complete layer and a layer starts at rest with steps of its own
//! ([`crate::step::StepGenerator`]); the park and unpark moves carry [`PARK_TAG`], whose
//! steps are hashed apart and never reported: the resumed job's layers have the steps, and
//! the hashes, of an uninterrupted run. A G-code job stops at its last complete line,
//! mid-layer as a rule: its motion stops there as the uninterrupted run's does not, so the
//! hash of that one layer differs; it resumes with the text after that line, its reader's
//! state (positions, modes, feed) kept.
//!
//! [`Message::Parked`]: crate::protocol::Message::Parked
//! [`Message::Resume`]: crate::protocol::Message::Resume

use super::{MotionAccess, Printer, Stages};
use crate::machine::{Rate, AXES};
use crate::move_ring::PackedMove;
use crate::plan::{Move, MoveKind};
use crate::protocol::{DeviceState, ParkedJob};
use crate::slot::Slot;

/// Lift of the nozzle when it parks, um (Marlin's `NOZZLE_PARK_Z_RAISE_MIN` is 2 mm; 10 mm
/// clears any blob and a part's top).
pub const PARK_LIFT_UM: i32 = 10_000;
/// Where the nozzle parks, um from X's minimum and from Y's maximum (Marlin's Ender-3
/// `NOZZLE_PARK_POINT`: 10 mm in from the back left corner, clear of the part).
pub const PARK_XY_UM: [i32; 2] = [10_000, 10_000];
/// Retraction before parking in a G-code job (it names none), um: the Ender-3's Bowden
/// retraction of its slicer profiles.
pub const GCODE_PARK_RETRACT_UM: i32 = 5_000;
/// Speeds of the park moves in a G-code job, mm/s: retraction, lift (Z's limit lowers it),
/// travel.
const GCODE_PARK_SPEEDS_MM_S: [u32; 3] = [45, 5, 100];
/// The tag of the park and unpark moves in place of a layer: their steps are hashed apart
/// and never reported (layers are below it: moves carry 16-bit layers).
pub const PARK_TAG: u32 = u16::MAX as u32;
/// How long the heaters hold their targets once parked, ms, unless the board sets another.
pub const DEFAULT_HEAT_HOLD_MS: u32 = 10 * 60 * 1000;

/// Where an orphaned job stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Orphan {
    /// The messages received before the link died are taken.
    Receiving,
    /// The input has ended; the motion runs to its end.
    Draining,
    /// The park moves run.
    Parking,
    /// Paused since this time (ms of `service`'s clock), the heaters holding.
    Parked {
        /// When it parked.
        since_ms: u32,
    },
    /// Paused, the heaters off.
    Cooled,
}

/// Where an orphaned job's input ended: a resume starts there.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ResumePoint {
    /// The layer of the last move printed.
    pub layer: u32,
    /// The position before parking, um (X, Y, Z, E as the planner had them).
    pub position_um: [i32; AXES],
    /// Filament retracted for parking, um.
    pub retracted_um: i32,
}

impl<Pl: Stages, const MOVE_BYTES: usize, const P: usize> Printer<Pl, MOVE_BYTES, P> {
    /// The host went silent for `silent_ms`: an active job takes the messages it received,
    /// prints what they hold, parks the nozzle off the part ([`PARK_LIFT_UM`],
    /// [`PARK_XY_UM`]) and pauses, its heaters holding their targets for the hold time
    /// ([`set_heat_hold_ms`](Self::set_heat_hold_ms)); where its input ended is kept
    /// ([`resume_point`](Self::resume_point)). A job whose whole input came, or that reads
    /// it from the card, runs to its end; anything else has nothing to lose.
    pub fn link_lost(&mut self, silent_ms: u32, now_ms: u32) {
        let needs_host = !self.model_ended && !self.card_job;
        if self.orphan.get().is_some() || !self.is_active() || !needs_host {
            return;
        }
        self.orphan_silent_ms = silent_ms;
        self.orphan = Slot::Full(if self.state == DeviceState::Paused {
            Orphan::Parked { since_ms: now_ms }
        } else {
            Orphan::Receiving
        });
    }

    /// Where an orphaned job's input ended (once it parked).
    pub fn resume_point(&self) -> Option<ResumePoint> {
        self.resume.get().copied()
    }

    /// How long the heaters hold their targets once an orphaned job parked, ms.
    pub fn set_heat_hold_ms(&mut self, ms: u32) {
        self.heat_hold_ms = Slot::Full(ms);
    }

    /// The orphaned job's next step: its input ends once no message is left
    /// (`received_all`), it parks once the input has run, pauses once parked, and its heaters
    /// go off once the hold is over.
    pub(super) fn tend_orphan<const Q: usize>(
        &mut self,
        now_ms: u32,
        received_all: bool,
        motion: &mut impl MotionAccess<MOVE_BYTES, P, Q>,
    ) {
        let hold_ms = self.heat_hold_ms.get().copied().unwrap_or(DEFAULT_HEAT_HOLD_MS);
        match self.orphan.get().copied() {
            // The whole input came before the link died: nothing is lost, the job ends as
            // it would have.
            Some(Orphan::Receiving) if self.model_ended => self.orphan = Slot::Empty,
            Some(Orphan::Receiving) if self.is_active() && received_all => {
                if let (true, Some(g)) = (self.gcode_job, self.pipeline.gcode()) {
                    g.abandon();
                }
                self.model_ended = true;
                self.orphan = Slot::Full(Orphan::Draining);
            }
            Some(Orphan::Draining) if self.is_active() => {
                if !self.input_drained(motion) || !motion.with(|m, _| m.is_idle()) {
                    return;
                }
                self.park(motion);
                self.orphan = Slot::Full(Orphan::Parking);
            }
            Some(Orphan::Parking) if self.is_active() && motion.with(|m, _| m.is_idle()) => {
                self.state = DeviceState::Paused;
                self.orphan = Slot::Full(Orphan::Parked { since_ms: now_ms });
            }
            Some(Orphan::Parked { since_ms }) if now_ms.wrapping_sub(since_ms) >= hold_ms => {
                self.orphan = Slot::Full(Orphan::Cooled);
            }
            _ => {}
        }
    }

    /// Every move the input had is in the move buffer: a G-code job's pending move went in,
    /// a sliced job's layer is all emitted.
    fn input_drained<const Q: usize>(
        &mut self,
        motion: &mut impl MotionAccess<MOVE_BYTES, P, Q>,
    ) -> bool {
        if !self.gcode_job {
            return !self.pipeline.emitting();
        }
        let (heaters, allowed) = (self.heaters, self.motion_allowed());
        let Some(input) = self.pipeline.gcode() else { return true };
        let mut sink = super::GcodeMotion { motion, heaters, allowed, ended: true };
        input.take(&[], &mut 0, false, &mut sink)
    }

    /// The retraction for parking, um, and the speeds of the park moves (retraction, lift,
    /// travel), mm/s: a sliced job's own, a G-code job's defaults.
    fn park_settings(&self) -> (i32, [Rate; 3]) {
        match self.job_settings.get() {
            Some(s) if !self.gcode_job => (
                s.retract_length_um,
                [s.retract_speed_mm_s, Rate::from_num(5), s.travel_speed_mm_s],
            ),
            _ => (GCODE_PARK_RETRACT_UM, GCODE_PARK_SPEEDS_MM_S.map(Rate::from_num)),
        }
    }

    /// The park moves into the move buffer (it is empty: they fit), the resume point kept.
    /// Not inlined (nor is [`unpark`](Self::unpark)): cold paths stay off the deepest stack.
    #[inline(never)]
    fn park<const Q: usize>(&mut self, motion: &mut impl MotionAccess<MOVE_BYTES, P, Q>) {
        let (retract_um, speeds) = self.park_settings();
        let volume = self.machine.build_volume_um;
        let (at, layer) = motion.with(|m, _| (m.planner().position_um(), m.generator().tag()));
        let layer = layer.unwrap_or(0);
        self.resume = Slot::Full(ResumePoint { layer, position_um: at, retracted_um: retract_um });
        let mut to = at;
        to[3] = to[3].saturating_sub(retract_um);
        let retract = Move::new(to, speeds[0], MoveKind::Retract);
        to[2] = to[2].saturating_add(PARK_LIFT_UM).min(volume[2]).max(at[2]);
        let lift = Move::new(to, speeds[1], MoveKind::Travel);
        to[0] = PARK_XY_UM[0];
        to[1] = volume[1] - PARK_XY_UM[1];
        let travel = Move::new(to, speeds[2], MoveKind::Travel);
        push_park_moves(motion, [retract, lift, travel]);
    }

    /// The orphaned job is parked and paused (its heaters holding or off).
    pub(super) fn parked(&self) -> bool {
        matches!(self.orphan.get(), Some(Orphan::Parked { .. } | Orphan::Cooled))
    }

    /// What a new host hears of a parked job.
    pub(super) fn parked_job(&self) -> Option<ParkedJob> {
        let point = self.resume.get().filter(|_| self.parked())?;
        let taken = match self.pipeline.gcode_ref() {
            Some(g) if self.gcode_job => g.lines_bytes(),
            _ => self.triangles,
        };
        Some(ParkedJob { layer: point.layer, taken, fingerprint: self.fingerprint })
    }

    /// A new host resumes the parked job: the park moves undone (over the part, down,
    /// primed) once the heaters are back at their targets, then the job takes its input
    /// again from where it ended (the triangles, or the G-code text after its last complete
    /// line).
    #[inline(never)]
    pub(super) fn unpark<const Q: usize>(
        &mut self,
        motion: &mut impl MotionAccess<MOVE_BYTES, P, Q>,
    ) {
        let Some(point) = self.resume.get().copied() else { return };
        let (_, speeds) = self.park_settings();
        let mut to = motion.with(|m, _| m.planner().position_um());
        to[0] = point.position_um[0];
        to[1] = point.position_um[1];
        let travel = Move::new(to, speeds[2], MoveKind::Travel);
        to[2] = point.position_um[2];
        let lower = Move::new(to, speeds[1], MoveKind::Travel);
        to[3] = point.position_um[3];
        let prime = Move::new(to, speeds[0], MoveKind::Retract);
        push_park_moves(motion, [travel, lower, prime]);
        if let (true, Some(g)) = (self.gcode_job, self.pipeline.gcode()) {
            g.resume();
        }
        self.orphan = Slot::Empty;
        self.resume = Slot::Empty;
        self.model_ended = false;
        self.reheat = true;
        self.state = DeviceState::Printing;
    }
}

/// Park or unpark moves into the move buffer, tagged [`PARK_TAG`]. The buffer is empty (the
/// motion is idle): three records fit any buffer a job can run with.
fn push_park_moves<const MOVE_BYTES: usize, const P: usize, const Q: usize>(
    motion: &mut impl MotionAccess<MOVE_BYTES, P, Q>,
    moves: [Move; 3],
) {
    motion.with(|m, _| {
        for mv in moves {
            let _ = m.moves_mut().push(&PackedMove::pack(PARK_TAG, &mv));
        }
    });
}
