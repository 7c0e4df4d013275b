//! Step-time compression: pending exact step times of one axis become `(interval, count, add)`
//! sequences, each checked step by step before it is committed.
//!
//! Step `i` (from 0) of a sequence is at `last + (i + 1) interval + add i (i + 1) / 2`, where
//! `last` is the executed time of the axis' previous step. For a fixed `add` every step bounds
//! `interval` to an integer range; walking the steps and intersecting the ranges gives the
//! longest run that `add` can cover, and which side the first failing step fell off says
//! whether a larger or a smaller `add` would go further. The search starts at an estimate
//! from the pending steps' second differences, gallops outward until the miss turns and
//! bisects between the last two candidates; it stops early when the first probe covers as
//! many steps as the last sequence or a later one no longer lengthens it. Interval limits
//! (driver high + low time, the reversal gap after a direction change,
//! [`MAX_INTERVAL_TICKS`]) are constraints of the same range.

use super::{StepCmd, StepProducer, MAX_INTERVAL_TICKS};

/// The axis' queue is full: try again after the executor has taken some commands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Full;

/// Compression limits in ticks.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Tune {
    /// Largest error of a compressed step against its exact time.
    pub tol: i64,
    /// Shortest interval between steps in one direction.
    pub min_step: i64,
    /// Shortest interval across a direction change.
    pub min_rev: i64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Miss {
    /// Every pending step fits.
    Fits,
    /// A later step needed a longer interval: a larger `add` would go further.
    Larger,
    /// A later step needed a shorter interval: a smaller `add` would go further.
    Smaller,
}

#[derive(Debug, Clone, Copy)]
struct Fit {
    count: usize,
    add: i64,
    imin: i64,
    imax: i64,
    miss: Miss,
    /// How far (ticks) the failing step fell outside its window when that measures the miss,
    /// else 0.
    over: u32,
}

/// Signed integers for [`Compressor::check_in`]: the low bits
/// of a tick and wrapping arithmetic (exact while the true values fit).
trait Wrapping: Copy + Ord {
    /// `v`, which fits.
    fn of(v: i64) -> Self;
    fn low(t: u64) -> Self;
    fn add(self, other: Self) -> Self;
    fn sub(self, other: Self) -> Self;
    fn wide(self) -> i64;
}

impl Wrapping for i32 {
    #[inline(always)]
    fn of(v: i64) -> Self {
        v as i32
    }
    #[inline(always)]
    fn low(t: u64) -> Self {
        t as i32
    }
    #[inline(always)]
    fn add(self, other: Self) -> Self {
        self.wrapping_add(other)
    }
    #[inline(always)]
    fn sub(self, other: Self) -> Self {
        self.wrapping_sub(other)
    }
    #[inline(always)]
    fn wide(self) -> i64 {
        self as i64
    }
}

impl Wrapping for i64 {
    #[inline(always)]
    fn of(v: i64) -> Self {
        v
    }
    #[inline(always)]
    fn low(t: u64) -> Self {
        t as i64
    }
    #[inline(always)]
    fn add(self, other: Self) -> Self {
        self.wrapping_add(other)
    }
    #[inline(always)]
    fn sub(self, other: Self) -> Self {
        self.wrapping_sub(other)
    }
    #[inline(always)]
    fn wide(self) -> i64 {
        self
    }
}

/// The DIR command an axis queued last: a fieldless enum with `None` first, so that a new
/// compressor is all zero bytes (an `Option<bool>` would store `None` as 2).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum QueuedDir {
    /// No DIR command yet.
    None,
    /// `StepCmd::Dir(false)`: negative..
    Negative,
    /// `StepCmd::Dir(true)`: positive..
    Positive,
}

impl QueuedDir {
    /// The DIR command for the level `dir`.
    const fn of(dir: bool) -> Self {
        if dir {
            Self::Positive
        } else {
            Self::Negative
        }
    }
}

/// Half-longest-interval waits one `Wait` command carries at most: 7 x 2^29 ticks (52 s at
/// 72 MHz) is under 2^32.
const WAITS_PER_COMMAND: u64 = 7;

/// One axis' pending steps and its committed reference time.
#[derive(Debug, Clone)]
pub(crate) struct Compressor<const B: usize> {
    /// Pending exact step times (generator ticks), ring buffer: the low 32 bits of each. The
    /// newest, `prev_tick`, is less than 2^32 ticks after every other pending one (see
    /// [`Compressor::push_step`]), which restores them ([`Compressor::tick_at`]).
    buf: [u32; B],
    head: usize,
    len: usize,
    /// Time of the last committed step (or the end of the last wait).
    last: u64,
    /// Direction of the pending steps (the DIR command already queued).
    dir: QueuedDir,
    /// The next sequence is the first after a DIR command.
    after_dir: bool,
    /// The last accepted step (its direction is `dir`): the newest pending one, if any.
    prev_tick: u64,
    /// The oldest pending step's tick (while any is pending): what the generator asks for
    /// after every step, kept whole.
    head_tick: u64,
    /// Steps moved later to respect the driver's minimum intervals.
    pub clamped: u32,
    /// Sequences committed.
    pub sequences: u64,
    /// Step count of the last sequence committed (0: none yet).
    prev_count: usize,
    /// Sequences that failed the final check (must stay 0; the fallback is a one-step
    /// sequence).
    pub check_failures: u32,
}

impl<const B: usize> Compressor<B> {
    pub(crate) const fn new() -> Self {
        Self {
            buf: [0; B],
            head: 0,
            len: 0,
            last: 0,
            dir: QueuedDir::None,
            after_dir: false,
            prev_tick: 0,
            head_tick: 0,
            clamped: 0,
            sequences: 0,
            prev_count: 0,
            check_failures: 0,
        }
    }

    /// Back to [`Compressor::new`] in place (the step buffer is not cleared: `len` is 0).
    pub(crate) fn reset(&mut self) {
        *self = Self { buf: self.buf, ..Self::new() };
    }

    pub(crate) fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Steps pending.
    #[inline(always)]
    pub(crate) fn pending(&self) -> usize {
        self.len
    }

    pub(crate) fn first_pending(&self) -> Option<u64> {
        (self.len > 0).then_some(self.head_tick)
    }

    /// The exact tick of the pending step at ring position `j % B`: `prev_tick` less the
    /// 32-bit distance back to it (exact, as no pending step lies 2^32 ticks or more before
    /// `prev_tick`).
    #[inline(always)]
    fn tick_at(&self, j: usize) -> u64 {
        // (`% B` spares the bounds check, a mask for the usual powers of two.)
        self.prev_tick - (self.prev_tick as u32).wrapping_sub(self.buf[j % B]) as u64
    }

    /// Time of the last committed step.
    pub(crate) fn last(&self) -> u64 {
        self.last
    }

    /// The axis rests (nothing pending): its reference moves on to `t` (waits) and it starts
    /// afresh, as at the start of a job: its next step queues its direction and is fitted
    /// with no memory of the sequences before. Repeating the call after `Err` finishes it.
    pub(crate) fn rest_at<const N: usize>(
        &mut self,
        axis: usize,
        t: u64,
        out: &mut StepProducer<'_, N>,
    ) -> Result<(), Full> {
        debug_assert!(self.is_empty(), "an axis rests with nothing pending");
        let most = WAITS_PER_COMMAND * (MAX_INTERVAL_TICKS as u64 / 2);
        while self.last < t {
            let ticks = (t - self.last).min(most);
            out.enqueue(axis, StepCmd::Wait(ticks as u32)).map_err(|_| Full)?;
            self.last += ticks;
        }
        self.dir = QueuedDir::None;
        self.after_dir = false;
        self.prev_tick = t;
        self.prev_count = 0;
        Ok(())
    }

    /// Accepts the step at exact time `tick` in direction `dir`. On `Err` nothing about the
    /// step was recorded and the same call may simply be repeated.
    pub(crate) fn push_step<const N: usize>(
        &mut self,
        axis: usize,
        tick: u64,
        dir: bool,
        out: &mut StepProducer<'_, N>,
        tune: &Tune,
    ) -> Result<(), Full> {
        // The last accepted step went the same way exactly when the pending direction is
        // `dir` (both change together, below).
        let same_dir = self.dir == QueuedDir::of(dir);
        if !same_dir {
            while !self.is_empty() {
                self.emit(axis, out, tune)?;
            }
            out.enqueue(axis, StepCmd::Dir(dir)).map_err(|_| Full)?;
            self.dir = QueuedDir::of(dir);
            self.after_dir = true;
        }
        if self.len == B {
            self.emit(axis, out, tune)?;
        }
        let gap = if same_dir { tune.min_step } else { tune.min_rev } as u64;
        let tick = if tick < self.prev_tick + gap {
            self.clamped += 1;
            self.prev_tick + gap
        } else {
            tick
        };
        // The ring keeps the low 32 bits of each tick: pending steps 2^32 ticks (59.6 s at
        // 72 MHz) or more before this one go out first. Pending steps come after `last`, so
        // within 2^32 of it none needs checking. Never taken in the generator: it sends a
        // pending step before the next step once any axis steps more than `pending_ticks`
        // (20 ms) after it, so this needs a pause of 2^32 - `pending_ticks` between two
        // consecutive steps of the machine within a motion (a stop sends everything).
        if tick - self.last > u32::MAX as u64 {
            while self.first_pending().is_some_and(|first| tick - first > u32::MAX as u64) {
                self.emit(axis, out, tune)?;
            }
        }
        self.buf[(self.head + self.len) % B] = tick as u32;
        if self.len == 0 {
            self.head_tick = tick;
        }
        self.len += 1;
        self.prev_tick = tick;
        Ok(())
    }

    /// Commits one sequence (preceded by waits if the first step is far away).
    pub(crate) fn emit<const N: usize>(
        &mut self,
        axis: usize,
        out: &mut StepProducer<'_, N>,
        tune: &Tune,
    ) -> Result<(), Full> {
        let Some(first) = self.first_pending() else {
            return Ok(());
        };
        // Waits of half the longest interval until the first step is in reach, up to
        // `WAITS_PER_COMMAND` of them in one command: the interrupt takes a pause's waits in
        // one go, so few commands keep its worst call short.
        let max = MAX_INTERVAL_TICKS as u64;
        let reach = max - tune.tol as u64;
        while first > self.last + reach {
            let needed = (first - self.last - reach).div_ceil(max / 2);
            let waits = needed.min(WAITS_PER_COMMAND);
            let ticks = (waits * (max / 2)) as u32;
            out.enqueue(axis, StepCmd::Wait(ticks)).map_err(|_| Full)?;
            self.last += waits * (max / 2);
        }
        if out.free(axis) == 0 {
            return Err(Full);
        }
        let (mut fit, small_add) = self.fit(tune);
        let mut interval = fit.imin + (fit.imax - fit.imin) / 2;
        if !self.check(interval, fit.add, fit.count, tune, small_add) {
            // Unreachable by construction; a single step is always valid.
            self.check_failures += 1;
            fit.count = 1;
            fit.add = 0;
            let d0 = (first - self.last) as i64;
            interval = d0.max(self.first_min(tune));
        }
        let cmd = StepCmd::Steps {
            interval: interval as u32,
            count: fit.count as u16,
            add: fit.add as i32,
        };
        out.enqueue(axis, cmd).map_err(|_| Full)?;
        let n = fit.count as i64;
        // n (n - 1) / 2 < 2^31 in a word (n < 2^16), then one 64-bit product with `add`.
        let steps_sum = (fit.count as u32 * (fit.count as u32).wrapping_sub(1) / 2) as i64;
        self.last = (self.last as i64 + n * interval + fit.add * steps_sum) as u64;
        self.head = (self.head + fit.count) % B;
        self.len -= fit.count;
        if self.len > 0 {
            self.head_tick = self.tick_at(self.head);
        }
        self.after_dir = false;
        self.sequences += 1;
        self.prev_count = fit.count;
        Ok(())
    }

    #[inline(always)]
    fn first_min(&self, tune: &Tune) -> i64 {
        if self.after_dir {
            tune.min_rev
        } else {
            tune.min_step
        }
    }

    /// Replays the executor's arithmetic and checks every step against its exact time.
    /// `small_add` is [`Compressor::small_add_bound`] of at least `count` pending steps.
    fn check(&self, interval: i64, add: i64, count: usize, tune: &Tune, small_add: u64) -> bool {
        // In i32 when every model time and interval stays below 2^30 in magnitude (the ranges
        // of `eval_small`, with the interval itself bounded too).
        // interval count < 2^29, compared as a quotient (count < 2^16; no 64-bit product).
        let small = add.unsigned_abs() < small_add
            && interval > 0
            && (count == 0 || interval <= (((1u32 << 29) - 1) / count as u32) as i64);
        if small {
            // `eval_small` intersects the exact integer ranges of these steps (tested equal
            // to `eval_wide` and to this replay), so its fits need no replay: only debug
            // builds (the tests) replay them.
            debug_assert!(count == 0 || self.check_in::<i32>(interval, add, count, tune));
            count > 0
        } else {
            self.check_in::<i64>(interval, add, count, tune)
        }
    }

    /// [`Compressor::check`] in `T`: the executor's `interval += add; t += interval`.
    ///
    /// The intervals change linearly, so the first step's and the rest's extremes (the
    /// second and the last interval) decide the interval limits; the walk compares times.
    fn check_in<T: Wrapping>(&self, interval: i64, add: i64, count: usize, tune: &Tune) -> bool {
        let max_iv = MAX_INTERVAL_TICKS as i64;
        if count == 0 || interval < self.first_min(tune) || interval > max_iv {
            return false;
        }
        if count > 1 {
            let (second, end) = (interval + add, interval + add * (count as i64 - 1));
            if second.min(end) < tune.min_step || second.max(end) > max_iv {
                return false;
            }
        }
        let add_t = T::of(add);
        let mut iv = T::of(interval);
        let mut t = T::low(self.last).add(iv);
        if t.sub(T::low(self.head_tick)).wide().abs() > tune.tol {
            return false;
        }
        for j in self.head + 1..self.head + count {
            iv = iv.add(add_t);
            t = t.add(iv);
            if t.sub(T::low(self.tick_at(j))).wide().abs() > tune.tol {
                return false;
            }
        }
        true
    }

    /// A first estimate of `add`: the second difference of the pending steps over a span of
    /// `m` steps, `(d_2m - 2 d_m + d_0) / m^2`, rounded, with `m` a power of two (a shift)
    /// near half the previous sequence's length (the curvature around the middle of a
    /// sequence as long as the last). Exact for steps on one quadratic; the rounding of the
    /// exact times errs by at most `2 / m^2`.
    ///
    /// Differences of pending steps are taken in 32 bits (exact: below 2^32 and
    /// non-negative).
    fn guess_add(&self, n: usize) -> i64 {
        if n < 3 {
            // Second difference with the first interval counted from `last`.
            return if n == 2 {
                let t0 = self.buf[self.head % B];
                let t1 = self.buf[(self.head + 1) % B];
                let d0 = self.head_tick.wrapping_sub(self.last);
                (t1.wrapping_sub(t0) as i64).wrapping_sub(d0 as i64)
            } else {
                0
            };
        }
        // Largest power of two m with 2 m <= min(n - 1, prev_count).
        let span = (n - 1).min(self.prev_count.max(2)) as u32;
        let shift = span.ilog2() - 1;
        let m = 1usize << shift;
        let t0 = self.buf[self.head % B];
        let t1 = self.buf[(self.head + m) % B];
        let t2 = self.buf[(self.head + 2 * m) % B];
        let dd = (t2.wrapping_sub(t1) as i64).wrapping_sub(t1.wrapping_sub(t0) as i64);
        let s = 2 * shift;
        // s <= 28 (n < 2^16). In 32 bits when `dd` leaves room for the rounding half (as
        // usual): the same value.
        let half = (1i32 << s) >> 1;
        match i32::try_from(dd) {
            Ok(d) if d <= i32::MAX - half => ((d + half) >> s) as i64,
            _ => (dd.saturating_add(half as i64)) >> s,
        }
    }

    /// How far `add` must move (in the miss's direction) before the failing step can fit:
    /// step `i` (`k = i + 1`) `over` ticks outside the model times reachable needs
    /// `|change| i k / 2 >= over`, as the interval range of the steps before it only
    /// narrows that way (their bounds `(d_j -+ tol - add j (j + 1) / 2) / (j + 1)` move
    /// against the change). At least 1.
    fn reach(f: &Fit) -> i64 {
        let i = f.count as u32;
        if i == 0 || i >= 1 << 12 {
            return 1;
        }
        let ik = i * (i + 1);
        ((2 * f.over).div_ceil(ik)).max(1) as i64
    }

    /// A long sequence from the front of the pending steps (the longest the probes found),
    /// and the 32-bit range of `add` for all of them ([`Compressor::small_add_bound`]).
    ///
    /// Starts at [`Compressor::guess_add`]. Each miss moves a bound past every `add` that
    /// fails the same step ([`Compressor::reach`]; the `add`s behind the candidate are taken
    /// to miss the same way, as the bisection always did). While only one bound is known the
    /// candidates gallop in the miss's direction (at least doubling each move), then the
    /// search bisects between the bounds. A first probe that covers as many steps as the
    /// last sequence, or a later one that covers no more than the best so far, ends it.
    fn fit(&self, tune: &Tune) -> (Fit, u64) {
        let n = self.len.min(u16::MAX as usize);
        let small_add = self.small_add_bound(n, tune);
        let (amin, amax) = (i32::MIN as i64, i32::MAX as i64);
        let mut best: Option<Fit> = None;
        // Keeps the better of `best` and `f`; true when `f` covers more steps.
        let consider = |best: &mut Option<Fit>, f: Fit| {
            let (better, longer) = match *best {
                None => (true, f.count > 0),
                Some(b) => (
                    f.count > b.count || (f.count == b.count && f.add.abs() < b.add.abs()),
                    f.count > b.count,
                ),
            };
            if better && f.count > 0 {
                *best = Some(f);
            }
            longer
        };
        // No add <= lo or >= hi covers more steps than `best` (bounds just outside the i32
        // range until a miss sets them).
        let (mut lo, mut hi) = (amin - 1, amax + 1);
        let mut c = self.guess_add(n).clamp(amin, amax);
        // Distance of the last move while the search is one-sided (it at least doubles).
        let mut step = 0i64;
        let mut evals = 0;
        loop {
            evals += 1;
            let f = self.eval(c, n, tune, small_add);
            // (The same value: the search goes on from the probe's own copy.)
            c = f.add;
            let improved = consider(&mut best, f);
            // The search ends when every step fits, when the first probe already covers as
            // many steps as the last sequence (lengths change slowly along a ramp), when a
            // later probe does not lengthen the sequence (each probe is a walk over the
            // pending steps and rarely gains more than a step), or when the bounds meet.
            let enough = if evals == 1 { f.count >= self.prev_count.max(4) } else { !improved };
            if f.miss == Miss::Fits || enough {
                break;
            }
            // Every add short of c + reach (in the miss's direction) fails the same step.
            let reach = Self::reach(&f);
            if f.miss == Miss::Larger {
                lo = lo.max(c + reach - 1).min(amax);
            } else {
                hi = hi.min(c - reach + 1).max(amin);
            }
            if hi - lo <= 1 {
                break;
            }
            let next = if hi > amax {
                (c + 2 * step).max(lo + 1)
            } else if lo < amin {
                (c - 2 * step).min(hi - 1)
            } else {
                // floor((lo + hi) / 2), as a shift.
                (lo + hi) >> 1
            };
            step = (next - c).abs();
            c = next;
        }
        let best = best.unwrap_or_else(|| self.eval(0, 1, tune, self.small_add_bound(1, tune)));
        (best, small_add)
    }

    /// How many pending steps `add` covers, and the interval range that does it.
    ///
    /// Step `i` (with `k = i + 1`, offset `d_i` from `last`) bounds the interval `x` by
    /// `k x + add i (i + 1) / 2` within `d_i +- tol`, and its own interval `x + add i` by the
    /// driver's minimum and [`MAX_INTERVAL_TICKS`]. Intersecting these ranges step by step
    /// gives the longest covered prefix; which bound the first failing step broke says which
    /// way a better `add` lies. `small_add` is [`Compressor::small_add_bound`] of `n`.
    // Inlined into `fit` (its probes' loop); the rare `eval_wide` stays out of line.
    #[inline(always)]
    fn eval(&self, add: i64, n: usize, tune: &Tune, small_add: u64) -> Fit {
        if n == 0 {
            return Fit {
                count: 0,
                add,
                imin: i64::MIN,
                imax: i64::MAX,
                miss: Miss::Fits,
                over: 0,
            };
        }
        if add.unsigned_abs() < small_add {
            self.eval_small(add, n, tune)
        } else {
            self.eval_wide(add, n, tune)
        }
    }

    /// The `add`s (in magnitude, exclusive) for which [`Compressor::eval`] of the first `n`
    /// pending steps may run in 32 bits (see [`Compressor::eval_small`]); 0 for none.
    #[inline(always)]
    fn small_add_bound(&self, n: usize, tune: &Tune) -> u64 {
        if n == 0 || n >= 1 << 12 {
            return 0;
        }
        let first = self.head_tick as i64 - self.last as i64;
        let end = self.tick_at(self.head + n - 1) as i64 - self.last as i64;
        // (end + tol + 1) n < 2^29, that is end + tol + 1 <= floor((2^29 - 1) / n), compared
        // as a quotient (no 64-bit product).
        let span_max = (((1u32 << 29) - 1) / n as u32) as i64;
        let ok = first > -(1 << 28)
            && end + tune.tol < span_max
            && tune.tol < 1 << 20
            && (0..1 << 20).contains(&tune.min_step)
            && self.first_min(tune) < 1 << 20;
        // |add| < 2^29 / n^2 keeps |add| n^2 below 2^29.
        if ok {
            ((1u32 << 29) / (n * n) as u32) as u64
        } else {
            0
        }
    }

    /// [`Compressor::eval`] in `i64`, dividing at every step.
    #[inline(never)]
    fn eval_wide(&self, add: i64, n: usize, tune: &Tune) -> Fit {
        let (mut imin, mut imax) = (i64::MIN, i64::MAX);
        let last = self.last as i64;
        for i in 0..n {
            let ii = i as i64;
            let d = self.tick_at(self.head + i) as i64 - last;
            let k = ii + 1;
            let at = add * (ii * k / 2);
            let mut lo = -(-(d - tune.tol - at)).div_euclid(k);
            let mut hi = (d + tune.tol - at).div_euclid(k);
            let min_iv = if i == 0 { self.first_min(tune) } else { tune.min_step };
            lo = lo.max(min_iv - add * ii);
            hi = hi.min(MAX_INTERVAL_TICKS as i64 - add * ii);
            let (nlo, nhi) = (imin.max(lo), imax.min(hi));
            if nlo > nhi {
                // The tolerance window's distance from the model times reachable (as in
                // `eval_small`), when the walk has an interval range.
                let (miss, over) = if lo > imax {
                    (Miss::Larger, (d - tune.tol - at).saturating_sub(k.saturating_mul(imax)))
                } else {
                    (Miss::Smaller, k.saturating_mul(imin).saturating_add(at - d - tune.tol))
                };
                let over = if i == 0 { 0 } else { over.clamp(0, 1 << 30) as u32 };
                return Fit { count: i, add, imin, imax, miss, over };
            }
            (imin, imax) = (nlo, nhi);
        }
        Fit { count: n, add, imin, imax, miss: Miss::Fits, over: 0 }
    }

    /// [`Compressor::eval`] in `i32` (registers and hardware divider of the Cortex-M3), with
    /// the same result as [`Compressor::eval_wide`].
    ///
    /// Step `i`'s model time ranges over `last + k x + at` for `x` in `imin..=imax`
    /// (`at = add i (i + 1) / 2`). The walk carries the two edges shifted by the tolerance,
    /// `up = last + k imin + at + tol` and `down = last + k imax + at - tol`, forward by
    /// additions (wrapping `u32`, compared as differences): a step at `down <= t <= up` whose
    /// own interval cannot fall below the minimum narrows nothing. Any other step takes the
    /// exact path, with a division only for a bound that narrows.
    ///
    /// Ranges (from [`Compressor::small_add_bound`]): offsets below 2^28 in magnitude,
    /// `n (end + tol) < 2^29` and `|add| n^2 < 2^29`. Then `0 < imin <= imax <= end + tol`
    /// (imin starts at the first step's minimum interval or above and only grows), so
    /// `k imin`, `k imax`, `at`, `add i` and every difference compared stay below 2^30, and
    /// the [`MAX_INTERVAL_TICKS`] (2^30) bound `2^30 - add i > imax` never binds.
    #[inline(always)]
    fn eval_small(&self, add: i64, n: usize, tune: &Tune) -> Fit {
        let last = self.last as u32;
        let (tol, min_step, add32) = (tune.tol as i32, tune.min_step as i32, add as i32);
        // (`add` fits in i32: rebuilt from `add32`, the i64 need not live through the walk.)
        let fit = |count: usize, imin: i32, imax: i32, miss: Miss, over: i32| Fit {
            count,
            add: add32 as i64,
            imin: imin as i64,
            imax: imax as i64,
            miss,
            over: over as u32,
        };
        let d = self.buf[self.head % B].wrapping_sub(last) as i32;
        let (imin, imax) = ((d - tol).max(self.first_min(tune) as i32), d + tol);
        if imin > imax {
            return Fit {
                count: 0,
                add,
                imin: i64::MIN,
                imax: i64::MAX,
                miss: Miss::Smaller,
                over: 0,
            };
        }
        let mut up = last.wrapping_add((imin + tol) as u32);
        let mut down = last.wrapping_add((imax - tol) as u32);
        // The walk carries step i's own intervals at the range's ends, `lo_iv = imin + add i`
        // and `hi_iv = imax + add i` (the edges advance by them), instead of imin and imax
        // (recovered as `lo_iv - add i` where needed): fewer values live in the loop.
        let (mut lo_iv, mut hi_iv) = (imin, imax);
        // Steps by their unwrapped buffer position (`% B`: a mask for the usual powers of
        // two).
        let (start, end) = (self.head, self.head + n);
        for j in start + 1..end {
            lo_iv += add32;
            hi_iv += add32;
            up = up.wrapping_add(lo_iv as u32);
            down = down.wrapping_add(hi_iv as u32);
            let t = self.buf[j % B];
            let (above, below) = (up.wrapping_sub(t) as i32, t.wrapping_sub(down) as i32);
            // Inside both edges, and the interval at imin (the shortest) not below the
            // minimum: nothing narrows.
            if (above | below) >= 0 && lo_iv >= min_step {
                continue;
            }
            let i = j - start;
            let range = |lo_iv: i32, hi_iv: i32| {
                let add_i = add32.wrapping_mul(i as i32);
                (lo_iv - add_i, hi_iv - add_i)
            };
            // above = k imin + at + tol - d and below = d + tol - k imax - at.
            // ceil((d - tol - at) / k) > imax, or the minimum interval above imax.
            if below > 2 * tol {
                let (imin, imax) = range(lo_iv, hi_iv);
                return fit(i, imin, imax, Miss::Larger, below - 2 * tol);
            }
            if min_step > hi_iv {
                let (imin, imax) = range(lo_iv, hi_iv);
                return fit(i, imin, imax, Miss::Larger, 0);
            }
            if above > 2 * tol {
                let (imin, imax) = range(lo_iv, hi_iv);
                return fit(i, imin, imax, Miss::Smaller, above - 2 * tol);
            }
            // A bound that narrows moves by the whole intervals its window edge is away:
            // ceil((d - tol - at) / k) = imin + ceil(-above / k) and
            // floor((d + tol - at) / k) = imax - ceil(-below / k); the edges move with it.
            // (i < n < 2^16: through u16, k is visibly nonzero and the divisions need no
            // zero check; `(|v| + i) / k` rounds up, its numerator below 2^31.)
            let i16 = i as u16 as u32;
            let k = i16 + 1;
            let ceil = |v: i32| if v < 0 { ((v.unsigned_abs() + i16) / k) as i32 } else { 0 };
            let lo = (lo_iv + ceil(above)).max(min_step);
            let hi = hi_iv - ceil(below);
            if lo > hi {
                let (imin, imax) = range(lo_iv, hi_iv);
                return fit(i, imin, imax, Miss::Smaller, 0);
            }
            up = up.wrapping_add(k.wrapping_mul((lo - lo_iv) as u32));
            down = down.wrapping_sub(k.wrapping_mul((hi_iv - hi) as u32));
            (lo_iv, hi_iv) = (lo, hi);
        }
        let add_i = add32.wrapping_mul(n as i32 - 1);
        fit(n, lo_iv - add_i, hi_iv - add_i, Miss::Fits, 0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::step::StepQueue;

    fn tune() -> Tune {
        Tune { tol: 36, min_step: 144, min_rev: 144 }
    }

    /// Runs the executor's recurrence over the queued commands of axis 0.
    fn replay(q: &mut StepQueue<256>) -> Vec<i64> {
        let (_, mut c) = q.split();
        let mut t = 0i64;
        let mut out = Vec::new();
        while let Some(cmd) = c.dequeue(0) {
            match cmd {
                StepCmd::Steps { interval, count, add } => {
                    let mut iv = interval as i64;
                    for i in 0..count {
                        if i > 0 {
                            iv += add as i64;
                        }
                        t += iv;
                        out.push(t);
                    }
                }
                StepCmd::Wait(w) => t += w as i64,
                StepCmd::Dir(_) => {}
            }
        }
        out
    }

    #[test]
    fn accelerating_steps_compress_within_tolerance() {
        // x = a t^2 / 2 from rest at 500 mm/s^2 * 80 steps/mm = 40000 steps/s^2, 72 MHz.
        let exact: Vec<u64> = (1..=2000u64)
            .map(|k| {
                let t = ((k as f64 - 0.5) * 2.0 / 40_000.0).sqrt();
                (t * 72e6).round() as u64 + 1000
            })
            .collect();
        let mut q = StepQueue::<256>::new();
        let mut c = Compressor::<64>::new();
        {
            let (mut p, _) = q.split();
            for &t in &exact {
                c.push_step(0, t, true, &mut p, &tune()).unwrap();
            }
            while !c.is_empty() {
                c.emit(0, &mut p, &tune()).unwrap();
            }
        }
        assert_eq!(c.check_failures, 0);
        assert_eq!(c.clamped, 0);
        let got = replay(&mut q);
        assert_eq!(got.len(), exact.len());
        for (g, e) in got.iter().zip(&exact) {
            assert!((g - *e as i64).abs() <= 36, "{g} vs {e}");
        }
        assert!(c.sequences < 2000 / 8, "poor compression: {} sequences", c.sequences);
    }

    #[test]
    fn the_32_bit_walk_equals_the_64_bit_one() {
        let mut next = crate::test_rng::xorshift(0x2545_f491_4f6c_dd1d);
        let mut rnd = |m: u64| next() % m;
        let mut reached = 0;
        for round in 0..4000 {
            let mut c = Compressor::<64>::new();
            c.last = 1_000_000 + rnd(1 << 40);
            c.head = rnd(64) as usize;
            c.after_dir = rnd(2) == 0;
            c.len = 1 + rnd(64) as usize;
            // Accelerating, decelerating or noisy intervals, some far from `last`.
            let mut t = c.last + if round % 7 == 0 { rnd(1 << 27) } else { rnd(3000) };
            let mut iv = 144 + rnd(20_000) as i64;
            let acc = rnd(400) as i64 - 200;
            c.head_tick = t;
            for i in 0..c.len {
                c.buf[(c.head + i) % 64] = t as u32;
                c.prev_tick = t;
                iv = (iv + acc + rnd(80) as i64 - 40).max(144);
                t += iv as u64;
            }
            let tune =
                Tune { tol: 1 + rnd(60) as i64, min_step: 144, min_rev: 144 + rnd(50) as i64 };
            for _ in 0..8 {
                let add = if rnd(4) == 0 {
                    rnd(1 << 20) as i64 - (1 << 19)
                } else {
                    acc + rnd(60) as i64 - 30
                };
                let n = 1 + rnd(c.len as u64) as usize;
                let small = c.small_add_bound(n, &tune);
                let (a, b) = (c.eval_wide(add, n, &tune), c.eval(add, n, &tune, small));
                if b.count > 0 {
                    let iv = b.imin + rnd(1 + (b.imax - b.imin) as u64) as i64;
                    let count = 1 + rnd(b.count as u64) as usize;
                    assert_eq!(
                        c.check(iv, add, count, &tune, small),
                        c.check_in::<i64>(iv, add, count, &tune),
                        "check of {iv} {add} {count}"
                    );
                }
                assert_eq!(
                    (a.count, a.imin, a.imax, a.miss),
                    (b.count, b.imin, b.imax, b.miss),
                    "add {add} n {n} round {round}"
                );
                // No add short of `reach` in the miss's direction covers more steps.
                for f in [a, b] {
                    let reach = Compressor::<64>::reach(&f);
                    if f.miss != Miss::Fits && reach > 1 {
                        let delta = 1 + rnd(reach as u64 - 1) as i64;
                        let other = if f.miss == Miss::Larger { add + delta } else { add - delta };
                        let o = c.eval_wide(other, n, &tune);
                        assert!(o.count <= f.count, "add {add} -> {other}: {o:?} vs {f:?}");
                        reached += 1;
                    }
                }
            }
        }
        assert!(reached > 20_000, "{reached} bounds checked");
    }

    /// Steps whose ticks cross multiples of 2^32, an idle of two minutes between bursts,
    /// and pending steps 59 s apart (within 2^32 ticks of each other); commands of axis 0.
    fn steps_across_32_bit_ticks() -> (Vec<StepCmd>, Vec<u64>, Compressor<8>) {
        let mut exact = Vec::new();
        // Accelerating through 2^32, then everything sent (as the generator does at a stop).
        let mut t = (1u64 << 32) - 15_000;
        for i in 0..24 {
            exact.push((t, true, i == 23));
            t += 1500 - 20 * i;
        }
        // Two minutes later, through 3 2^32, then a step 59 s after the burst's first one
        // while the burst is still pending, a few more and a reversal.
        let start = (3u64 << 32) - 5000;
        for i in 0..12 {
            exact.push((start + 700 * i, true, false));
        }
        let late = start + (1 << 32) - 50_000;
        for i in 0..6 {
            exact.push((late + 1000 * i, true, false));
        }
        for i in 0..5 {
            exact.push((late + 9000 + 800 * i, false, i == 4));
        }
        let mut q = StepQueue::<256>::new();
        let mut c = Compressor::<8>::new();
        {
            let (mut p, _) = q.split();
            for &(tick, dir, flush) in &exact {
                c.push_step(0, tick, dir, &mut p, &tune()).unwrap();
                while flush && !c.is_empty() {
                    c.emit(0, &mut p, &tune()).unwrap();
                }
            }
        }
        let (_, mut cons) = q.split();
        let cmds = core::iter::from_fn(|| cons.dequeue(0)).collect();
        (cmds, exact.iter().map(|e| e.0).collect(), c)
    }

    #[test]
    fn ticks_past_32_bits_compress_as_before() {
        let (cmds, exact, c) = steps_across_32_bit_ticks();
        assert_eq!(c.check_failures, 0);
        // `n` waits of half the longest interval, up to seven a command.
        let waits = |n: u32| {
            let full = vec![StepCmd::Wait(7 * (MAX_INTERVAL_TICKS / 2)); n as usize / 7];
            let rest = (n % 7 > 0).then_some(StepCmd::Wait(n % 7 * (MAX_INTERVAL_TICKS / 2)));
            full.into_iter().chain(rest).collect::<Vec<_>>()
        };
        let steps = |interval, count, add| StepCmd::Steps { interval, count, add };
        // The commands of the compressor that kept whole 64-bit ticks (its waits one by one).
        let expected = [
            vec![StepCmd::Dir(true)],
            waits(6),
            vec![
                steps(1_073_726_788, 2, -1_073_725_216),
                steps(1475, 8, -20),
                steps(1320, 8, -20),
                steps(1160, 6, -20),
            ],
            waits(14),
            vec![steps(1_073_722_352, 2, -1_073_721_580), steps(695, 8, 0), steps(740, 2, -112)],
            waits(6),
            vec![
                steps(1_073_684_124, 2, -1_073_683_052),
                steps(991, 4, 0),
                StepCmd::Dir(false),
                steps(3964, 2, -3092),
                steps(788, 3, 0),
            ],
        ]
        .concat();
        assert_eq!(cmds, expected);
        // Replayed, every step is within the tolerance of its exact time.
        let mut q = StepQueue::<256>::new();
        {
            let (mut p, _) = q.split();
            for &cmd in &cmds {
                p.enqueue(0, cmd).unwrap();
            }
        }
        assert_replays_within_tolerance(&mut q, &exact);
    }

    /// The queued commands replayed step for step: every step within the tolerance of its
    /// exact tick.
    fn assert_replays_within_tolerance(q: &mut StepQueue<256>, exact: &[u64]) {
        let got = replay(q);
        assert_eq!(got.len(), exact.len());
        for (g, e) in got.iter().zip(exact) {
            assert!((g - *e as i64).abs() <= tune().tol, "{g} vs {e}");
        }
    }

    #[test]
    fn steps_2_pow_32_ticks_apart_never_share_the_ring() {
        // Steps 0.95 s apart with nothing sent in between: 64 of them would span more than
        // 2^32 ticks, so the oldest go out before a step that far after them comes in.
        let exact: Vec<u64> = (0..200u64).map(|i| 10_000 + i * 68_500_000 + i * i).collect();
        let mut q = StepQueue::<256>::new();
        let mut c = Compressor::<64>::new();
        {
            let (mut p, _) = q.split();
            for &t in &exact {
                c.push_step(0, t, true, &mut p, &tune()).unwrap();
                let first = c.first_pending().unwrap();
                assert!(t - first < 1 << 32, "{first} pending at {t}");
            }
            while !c.is_empty() {
                c.emit(0, &mut p, &tune()).unwrap();
            }
        }
        assert_eq!(c.check_failures, 0);
        assert_replays_within_tolerance(&mut q, &exact);
    }

    /// A five-minute pause (21.6 G ticks: 39 waits of 2^29 bring the step within the longest
    /// interval) is six commands (seven waits each, then four), and the steps after it replay
    /// within the tolerance.
    #[test]
    fn a_long_pause_takes_few_commands() {
        let mut q = StepQueue::<256>::new();
        let mut c = Compressor::<8>::new();
        let exact = [5_000u64, 5_000 + 300 * 72_000_000, 5_000 + 300 * 72_000_000 + 900];
        {
            let (mut p, _) = q.split();
            for &t in &exact {
                c.push_step(0, t, true, &mut p, &tune()).unwrap();
            }
            while !c.is_empty() {
                c.emit(0, &mut p, &tune()).unwrap();
            }
        }
        let cmds: Vec<StepCmd> = {
            let (_, mut cons) = q.split();
            core::iter::from_fn(|| cons.dequeue(0)).collect()
        };
        let waits: Vec<u32> = cmds
            .iter()
            .filter_map(|c| if let StepCmd::Wait(w) = c { Some(*w) } else { None })
            .collect();
        let half = MAX_INTERVAL_TICKS / 2;
        assert_eq!(waits, [7 * half, 7 * half, 7 * half, 7 * half, 7 * half, 4 * half]);
        let mut q = StepQueue::<256>::new();
        {
            let (mut p, _) = q.split();
            for &cmd in &cmds {
                p.enqueue(0, cmd).unwrap();
            }
        }
        assert_replays_within_tolerance(&mut q, &exact);
    }

    #[test]
    fn long_pause_becomes_waits() {
        let mut q = StepQueue::<256>::new();
        let mut c = Compressor::<8>::new();
        let t = [5_000u64, 3_000_000_000, 3_000_000_500];
        {
            let (mut p, _) = q.split();
            for &x in &t {
                c.push_step(0, x, true, &mut p, &tune()).unwrap();
            }
            while !c.is_empty() {
                c.emit(0, &mut p, &tune()).unwrap();
            }
        }
        let got = replay(&mut q);
        for (g, e) in got.iter().zip(&t) {
            assert!((g - *e as i64).abs() <= 36);
        }
    }
}
