//! Look-ahead commands: the loop takes inputs ahead of their time into a preview of source
//! samples (each already solved, retargeted and mapped through the rig), and plans each
//! servo's goal path over it with [`crate::plan`], leading the servo by its lag so that its
//! *position* follows the source. Live inputs have no future: their reference is a bounded
//! extrapolation from the newest two samples (never further ahead than the servo's lead,
//! never faster than its velocity limit). Everything is allocated before the first tick.

use std::collections::VecDeque;

use glam::{DQuat, DVec3};

use crate::command::CommandStage;
use crate::plan::{ServoPlan, Window, MAX_KNOTS};
use crate::rig::{Rig, ServoMap};
use crate::servo::MotionLimits;
use crate::servo::MAX_SERVOS;
use crate::skeleton::MAX_CHANNELS;

/// What a source sample is besides its per-servo and per-channel values: when it is due, where
/// it came from, the tips and effectors the fidelity and the retargeting read.
#[derive(Clone, Copy, Debug)]
pub struct SampleHead {
    /// Loop-clock time it stands for, ns.
    pub due_ns: u64,
    /// Clip time (play), seconds; NaN for targets.
    pub clip_time: f64,
    /// Loop-clock time the input behind it was made, ns (0 when unknown).
    pub made_ns: u64,
    /// Tips of the watched bones (root frame, file units).
    pub tips: [DVec3; 4],
    /// Robot effectors at the source (retargeting), metres.
    pub effectors: [DVec3; 4],
    /// Where the retargeting placed the robot's base.
    pub base: (DVec3, DQuat),
    /// Which feet (left, right) bear weight at the source (both without retargeting).
    pub contact: [bool; 2],
}

impl Default for SampleHead {
    fn default() -> Self {
        SampleHead {
            due_ns: 0,
            clip_time: f64::NAN,
            made_ns: 0,
            tips: [DVec3::NAN; 4],
            effectors: [DVec3::NAN; 4],
            base: (DVec3::ZERO, DQuat::IDENTITY),
            contact: [true; 2],
        }
    }
}

/// A sample in the [`Preview`]: one input ready for the servos (what a perfect rig would do at
/// `due_ns`), its per-servo and per-channel values borrowed from the preview's tables.
#[derive(Clone, Copy, Debug)]
pub struct Sample<'a> {
    /// Loop-clock time it stands for, ns.
    pub due_ns: u64,
    /// Clip time (play), seconds; NaN for targets.
    pub clip_time: f64,
    /// Loop-clock time the input behind it was made, ns (0 when unknown).
    pub made_ns: u64,
    /// Joint angle per servo of the rig, radians.
    pub angles: &'a [f64],
    /// Per servo of the rig, what its command adds to the angle so that the horn, sagging
    /// under the pose's static load, ends on it (radians; 0 without load compensation).
    pub load_offset: &'a [f64],
    /// The pose's channels (rotations in radians), as many as the skeleton has: what the
    /// servos do not drive comes from here when the present angles are put back into a pose.
    pub channels: &'a [f64],
    /// Tips of the watched bones (root frame, file units).
    pub tips: [DVec3; 4],
    /// Robot effectors at the source (retargeting), metres.
    pub effectors: [DVec3; 4],
    /// Where the retargeting placed the robot's base.
    pub base: (DVec3, DQuat),
    /// Which feet (left, right) bear weight at the source.
    pub contact: [bool; 2],
}

/// Samples in time order: a little history (for extrapolation), the current one and the
/// future ones taken ahead. Fixed capacity: when full, the oldest goes.
///
/// The values are kept as compactly as the rig and the skeleton allow: each sample's angles and
/// load offsets (two per servo of the rig) in one row of one table, its channels (as many as
/// the skeleton has) in a row of another, rows taken in turn, so that the `i`th sample kept has
/// the `i`th row after the oldest's. A sample sized for the largest rig and skeleton would take
/// 4.6 KB, and the loop would touch a page per sample it planned over.
#[derive(Debug)]
pub struct Preview {
    entries: VecDeque<SampleHead>,
    /// Per row: the servos' angles, then their load offsets.
    servo_rows: Vec<f64>,
    /// Per row: the channels.
    channel_rows: Vec<f64>,
    servos: usize,
    channels: usize,
    /// The row the next sample takes (rows are taken in turn and let go oldest first, so the
    /// oldest sample's row is the next one when the preview is full).
    next_row: usize,
    capacity: usize,
    /// Index of the current sample, when there is one.
    current: Option<usize>,
    /// Whether more input may come after the newest sample (a live source: the reference
    /// past it is extrapolated); false once the input has ended (held).
    pub live: bool,
}

/// Copies `from` into `to` as far as both go, and `missing` into the rest of `to`.
fn fill_from(to: &mut [f64], from: &[f64], missing: f64) {
    let n = from.len().min(to.len());
    to[..n].copy_from_slice(&from[..n]);
    to[n..].fill(missing);
}

/// Past samples kept behind the current one.
const HISTORY: usize = 2;

impl Preview {
    /// Room for `capacity` samples (at least four) of `servos` servos (at most
    /// [`MAX_SERVOS`]) and `channels` channels (at most [`MAX_CHANNELS`]).
    #[must_use]
    pub fn new(capacity: usize, servos: usize, channels: usize) -> Preview {
        let capacity = capacity.max(HISTORY + 2);
        let (servos, channels) = (servos.min(MAX_SERVOS), channels.min(MAX_CHANNELS));
        Preview {
            entries: crate::resident::deque(capacity, SampleHead::default()),
            // Written now (NaN: no sample), so that the rows' first lap takes no page fault.
            servo_rows: vec![f64::NAN; capacity * 2 * servos],
            channel_rows: vec![f64::NAN; capacity * channels],
            servos,
            channels,
            next_row: 0,
            capacity,
            current: None,
            live: true,
        }
    }

    /// Adds the newest sample: `head`, and per servo its angle and load offset, per channel its
    /// value (as many as the preview was made for; missing angles are NaN, missing offsets and
    /// channels 0). A sample older than the newest (a producer that started over) starts the
    /// preview anew. Never grows the storage.
    pub fn push(&mut self, head: SampleHead, angles: &[f64], load_offset: &[f64], channels: &[f64]) {
        if self.entries.back().is_some_and(|b| head.due_ns < b.due_ns) {
            self.clear();
        }
        if self.entries.len() == self.capacity {
            self.entries.pop_front();
            self.current = self.current.and_then(|c| c.checked_sub(1));
        }
        let row = self.next_row;
        self.next_row = (row + 1) % self.capacity;
        let n = self.servos;
        let (row_angles, row_offsets) = self.servo_rows[row * 2 * n..(row + 1) * 2 * n].split_at_mut(n);
        fill_from(row_angles, angles, f64::NAN);
        fill_from(row_offsets, load_offset, 0.0);
        let c = self.channels;
        fill_from(&mut self.channel_rows[row * c..(row + 1) * c], channels, 0.0);
        self.entries.push_back(head);
    }

    /// Makes the newest sample due by `due_by` current; returns whether it is a new one.
    /// Samples older than the history are let go.
    pub fn advance(&mut self, due_by: u64) -> bool {
        let newest_due = self.entries.iter().rposition(|s| s.due_ns <= due_by);
        let fresh = newest_due.is_some() && newest_due != self.current;
        if let Some(c) = newest_due {
            let drop = c.saturating_sub(HISTORY);
            self.entries.drain(..drop);
            self.current = Some(c - drop);
        }
        fresh
    }

    /// The row of the `i`th sample kept: rows are taken in turn, so it is `i` after the
    /// oldest's, which is `len` before the next one.
    #[inline]
    fn row(&self, i: usize) -> usize {
        let row = self.next_row + self.capacity - self.entries.len() + i;
        if row >= self.capacity {
            row - self.capacity
        } else {
            row
        }
    }

    /// The `i`th sample kept, `e` its head.
    fn sample(&self, i: usize, e: &SampleHead) -> Sample<'_> {
        let (n, c, row) = (self.servos, self.channels, self.row(i));
        let servo_row = &self.servo_rows[row * 2 * n..(row + 1) * 2 * n];
        Sample {
            due_ns: e.due_ns,
            clip_time: e.clip_time,
            made_ns: e.made_ns,
            angles: &servo_row[..n],
            load_offset: &servo_row[n..],
            channels: &self.channel_rows[row * c..(row + 1) * c],
            tips: e.tips,
            effectors: e.effectors,
            base: e.base,
            contact: e.contact,
        }
    }

    /// The current sample.
    #[must_use]
    pub fn current(&self) -> Option<Sample<'_>> {
        self.current
            .and_then(|c| Some((c, self.entries.get(c)?)))
            .map(|(c, e)| self.sample(c, e))
    }

    /// The sample due at `due_ns`, searched from the oldest kept (the current one is at most
    /// two from the front).
    #[must_use]
    pub fn find(&self, due_ns: u64) -> Option<Sample<'_>> {
        self.entries
            .iter()
            .enumerate()
            .take_while(|(_, s)| s.due_ns <= due_ns)
            .find(|(_, s)| s.due_ns == due_ns)
            .map(|(i, e)| self.sample(i, e))
    }

    /// Whether samples after the current one wait.
    #[must_use]
    pub fn has_future(&self) -> bool {
        self.entries.len() > self.current.map_or(0, |c| c + 1)
    }

    /// Forgets everything (a restart).
    pub fn clear(&mut self) {
        self.entries.clear();
        self.current = None;
        self.next_row = 0;
    }

    /// The newest sample.
    #[must_use]
    pub fn newest(&self) -> Option<Sample<'_>> {
        let last = self.entries.len().checked_sub(1)?;
        Some(self.sample(last, &self.entries[last]))
    }

    /// Servo `k`'s commanded angle (its angle and its load offset) in entry `i`; NaN for a
    /// servo the preview was not made for.
    #[inline]
    fn command(&self, i: usize, k: usize) -> f64 {
        let n = self.servos;
        if k >= n {
            return f64::NAN;
        }
        let at = self.row(i) * 2 * n + k;
        self.servo_rows[at] + self.servo_rows[at + n]
    }

    /// Servo `k`'s source angle at `t_ns`: interpolated between samples; before the first,
    /// the first; after the newest, the newest moved on by its last slope for at most
    /// `extrapolate_ns` (0: held), the slope bounded by `max_rate` (radians/s).
    #[cfg(test)]
    fn angle_at(&self, k: usize, t_ns: u64, extrapolate_ns: u64, max_rate: f64) -> f64 {
        let place = self.locate(t_ns, &mut 0);
        self.angle(k, place, extrapolate_ns, max_rate)
    }

    /// Where `t_ns` falls, searching forward from sample `cursor` (updated) — for times in
    /// increasing order.
    fn locate(&self, t_ns: u64, cursor: &mut usize) -> Place {
        let n = self.entries.len();
        let Some(last) = self.entries.back() else {
            return Place::Empty;
        };
        if t_ns >= last.due_ns {
            return Place::Past(t_ns - last.due_ns);
        }
        // The first sample at or after t.
        let mut i = (*cursor).min(n - 1);
        if i > 0 && self.entries[i - 1].due_ns >= t_ns {
            i = self.entries.partition_point(|s| s.due_ns < t_ns);
        }
        while self.entries[i].due_ns < t_ns {
            i += 1;
        }
        *cursor = i;
        if i == 0 {
            return Place::Between(0, 0.0);
        }
        let (a, b) = (&self.entries[i - 1], &self.entries[i]);
        Place::Between(
            i - 1,
            (t_ns - a.due_ns) as f64 / (b.due_ns - a.due_ns).max(1) as f64,
        )
    }

    /// Servo `k`'s commanded angle (its angle and its load offset) at `place`
    /// ([`Preview::angle_at`]).
    fn angle(&self, k: usize, place: Place, extrapolate_ns: u64, max_rate: f64) -> f64 {
        let n = self.entries.len();
        match place {
            Place::Empty => f64::NAN,
            Place::Between(i, f) => {
                let a = self.command(i, k);
                if f == 0.0 {
                    a
                } else {
                    a + f * (self.command(i + 1, k) - a)
                }
            }
            Place::Past(beyond) => {
                let a = self.command(n - 1, k);
                if extrapolate_ns == 0 || n < 2 {
                    return a;
                }
                let span = self.entries[n - 1]
                    .due_ns
                    .saturating_sub(self.entries[n - 2].due_ns);
                if span == 0 {
                    return a;
                }
                let rate = ((a - self.command(n - 2, k)) / (span as f64 * 1e-9)).clamp(-max_rate, max_rate);
                a + rate * beyond.min(extrapolate_ns) as f64 * 1e-9
            }
        }
    }
}

/// Where a time falls in a preview.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Place {
    /// No samples.
    Empty,
    /// Between sample `i` and the next, at fraction `f` (before the first: sample 0).
    Between(usize, f64),
    /// After the newest, by this many ns.
    Past(u64),
}

/// How the look-ahead plans.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LookaheadSettings {
    /// Knots in the window.
    pub knots: usize,
    /// Shortest spacing of knots, seconds (a fast loop plans on a coarser grid than its ticks).
    pub min_spacing_s: f64,
    /// Shortest window, seconds: a move the servos' acceleration limits stretch is seen
    /// coming this far ahead, whatever the loop's rate.
    pub min_window_s: f64,
}

impl Default for LookaheadSettings {
    fn default() -> Self {
        LookaheadSettings {
            knots: 24,
            min_spacing_s: 0.004,
            min_window_s: 0.19,
        }
    }
}

/// The planner of a rig's servos.
///
/// Each servo's plan holds its first acceleration for one knot spacing (`ticks_per_knot`
/// ticks): a loop faster than the knots replans each servo once a knot, the servos in turn (a
/// share of them each tick), and between its replans a servo goes on at its plan's
/// acceleration — what the plan itself would command over the first knot.
#[derive(Debug)]
pub struct Lookahead {
    window: Window,
    ticks_per_knot: u64,
    /// Ticks planned so far (the servos' turns), and the time of the last.
    tick: u64,
    last_now_ns: Option<u64>,
    /// Whether servo `k` has a plan to go on with.
    planned: Vec<bool>,
    plans: Vec<ServoPlan>,
    leads_ns: Vec<u64>,
    targets: Vec<f64>,
    reference: [f64; MAX_KNOTS],
    /// Per knot, where the last lead's times fall in the preview (servos with the same lead
    /// share them).
    places: [Place; MAX_KNOTS],
}

/// Blending the first commands from where the servos stood (the ease-in): the angles, its
/// start and length, ns.
#[derive(Clone, Copy, Debug)]
pub struct EaseIn<'a> {
    /// Angles the servos stood at, radians.
    pub from: &'a [f64],
    /// Loop-clock time the blend starts.
    pub start_ns: u64,
    /// Its length.
    pub length_ns: u64,
}

impl EaseIn<'_> {
    /// The smoothstep weight of the source at `t_ns` (1 after the blend).
    fn weight(&self, t_ns: u64) -> f64 {
        if self.length_ns == 0 {
            return 1.0;
        }
        let t = (t_ns.saturating_sub(self.start_ns) as f64 / self.length_ns as f64).clamp(0.0, 1.0);
        t * t * (3.0 - 2.0 * t)
    }
}

impl Lookahead {
    /// A planner for `rig` at `rate_hz`, servo `k` led by `leads_s[k]` seconds (its lag).
    #[must_use]
    pub fn new(rig: &Rig, rate_hz: f64, leads_s: &[f64], settings: LookaheadSettings) -> Lookahead {
        let period = 1.0 / rate_hz;
        // Knots a whole number of ticks apart, at least the shortest spacing and together at
        // least the shortest window (a hair's tolerance: 4 ms at 250 Hz is one tick).
        let ticks = |span: f64| (span / period - 1e-9).ceil();
        let ticks_per_knot = ticks(settings.min_spacing_s)
            .max(ticks(settings.min_window_s / settings.knots.max(1) as f64))
            .max(1.0);
        let window = Window::new(settings.knots, ticks_per_knot * period);
        let n = rig.len();
        Lookahead {
            window,
            ticks_per_knot: ticks_per_knot as u64,
            tick: 0,
            last_now_ns: None,
            planned: vec![false; n],
            plans: rig
                .servos
                .iter()
                .map(|s| {
                    ServoPlan::new(MotionLimits {
                        velocity: s.max_velocity,
                        acceleration: s.max_acceleration,
                        min: f64::from(s.min_tick),
                        max: f64::from(s.max_tick),
                    })
                })
                .collect(),
            leads_ns: (0..n)
                .map(|k| {
                    let s = leads_s.get(k).copied().unwrap_or(0.0);
                    if s.is_finite() && s > 0.0 {
                        (s.min(1.0) * 1e9) as u64
                    } else {
                        0
                    }
                })
                .collect(),
            targets: vec![0.0; n],
            reference: [0.0; MAX_KNOTS],
            places: [Place::Empty; MAX_KNOTS],
        }
    }

    /// How far ahead of a tick the plan looks: the largest lead and the window, ns.
    #[must_use]
    pub fn preview_ns(&self) -> u64 {
        let lead = self.leads_ns.iter().copied().max().unwrap_or(0);
        lead + (self.window.knots() as f64 * self.window.spacing_s() * 1e9) as u64
    }

    /// Servo `k`'s lead, ns.
    #[must_use]
    pub fn lead_ns(&self, k: usize) -> u64 {
        self.leads_ns.get(k).copied().unwrap_or(0)
    }

    /// This tick's target per servo (fractional ticks) for the goal written at `now_ns`, `dt`
    /// seconds after the previous one. Past the preview's newest sample the reference is
    /// extrapolated (bounded) while the preview is live, held once it is not. Allocates
    /// nothing.
    pub fn targets(
        &mut self,
        rig: &Rig,
        stage: &CommandStage,
        preview: &Preview,
        now_ns: u64,
        dt: f64,
        ease: Option<EaseIn<'_>>,
    ) -> &[f64] {
        let dt_ns = (dt * 1e9).round() as u64;
        let knot_times = KnotTimes::new(&self.window, now_ns, dt_ns);
        let knots = knot_times.knots;
        // Ticks in step (not after a skip or a restart): servos go on between their turns.
        let in_step = self.last_now_ns.is_some_and(|t| now_ns == t + dt_ns);
        if !in_step {
            self.planned.fill(false);
        }
        self.last_now_ns = Some(now_ns);
        self.tick = self.tick.wrapping_add(1);
        let mut placed: Option<u64> = None;
        for (k, servo) in rig.servos.iter().enumerate() {
            let state = stage.state(k);
            let turn = (self.tick + k as u64) % self.ticks_per_knot == 0;
            if let (false, true, Some((x, v))) = (turn, self.planned[k], state) {
                self.targets[k] = self.plans[k].go_on(x, v, dt);
                continue;
            }
            let lead = self.leads_ns[k];
            let located = placed == Some(lead);
            placed = Some(lead);
            reference_at_knots(
                (preview, ease.as_ref()),
                (k, servo, lead),
                knot_times,
                (&mut self.places, located),
                &mut self.reference,
            );
            let (x0, v0) = state.unwrap_or((self.reference[0], 0.0));
            self.targets[k] = self.plans[k].plan(&self.window, x0, v0, &self.reference[..knots], dt);
            self.planned[k] = state.is_some();
        }
        &self.targets
    }

    /// Drops every servo's plan: after the command stage restarts (from where the servos
    /// stand, at rest), each is planned afresh at its next tick.
    pub fn forget_plans(&mut self) {
        self.planned.fill(false);
    }

    /// Makes ahead, on a copy of its planner, and keeps nothing, the plan of the first servo
    /// whose turn the next tick (at `now_ns`, `dt` after the one before) is: called while the
    /// loop waits for that tick, it leaves the planner's code and the preview's rows the tick
    /// reads in the caches. Allocates nothing.
    pub fn rehearse(&self, rig: &Rig, stage: &CommandStage, preview: &Preview, now_ns: u64, dt: f64) {
        let tick = self.tick.wrapping_add(1);
        let Some((k, servo)) = rig
            .servos
            .iter()
            .enumerate()
            .find(|&(k, _)| (tick + k as u64) % self.ticks_per_knot == 0)
        else {
            return;
        };
        let knot_times = KnotTimes::new(&self.window, now_ns, (dt * 1e9).round() as u64);
        let knots = knot_times.knots;
        let (mut places, mut reference) = ([Place::Empty; MAX_KNOTS], [0.0; MAX_KNOTS]);
        reference_at_knots(
            (preview, None),
            (k, servo, self.leads_ns[k]),
            knot_times,
            (&mut places, false),
            &mut reference,
        );
        let (x0, v0) = stage.state(k).unwrap_or((reference[0], 0.0));
        let mut plan = self.plans[k].clone();
        std::hint::black_box(plan.plan(&self.window, x0, v0, &reference[..knots], dt));
    }
}

/// The knots' times: the `j`th at `t0 + (j + 1)·h_ns`, `knots` of them.
#[derive(Clone, Copy, Debug)]
struct KnotTimes {
    t0: u64,
    h_ns: u64,
    knots: usize,
}

impl KnotTimes {
    /// The knots of `window` for the tick at `now_ns`, `dt_ns` after the one before: `t0` is
    /// the previous goal's time.
    fn new(window: &Window, now_ns: u64, dt_ns: u64) -> KnotTimes {
        KnotTimes {
            t0: now_ns.saturating_sub(dt_ns),
            h_ns: (window.spacing_s() * 1e9).round() as u64,
            knots: window.knots(),
        }
    }
}

/// Servo `k`'s reference at the knots (ticks, into `reference`): the preview's angle at each
/// knot's time led by `lead` (its place found into `places`, unless `located` says they hold
/// it for this lead already), extrapolated while the preview is live, blended by the ease-in.
fn reference_at_knots(
    (preview, ease): (&Preview, Option<&EaseIn<'_>>),
    (k, servo, lead): (usize, &ServoMap, u64),
    KnotTimes { t0, h_ns, knots }: KnotTimes,
    (places, located): (&mut [Place; MAX_KNOTS], bool),
    reference: &mut [f64; MAX_KNOTS],
) {
    let tpr = servo.ticks_per_radian().abs().max(1e-12);
    let max_rate = if servo.max_velocity > 0.0 {
        servo.max_velocity / tpr
    } else {
        f64::INFINITY
    };
    let extrapolate = if preview.live { lead.min(100_000_000) } else { 0 };
    if !located {
        let mut cursor = 0;
        for (j, place) in places.iter_mut().enumerate().take(knots) {
            *place = preview.locate(t0 + (j as u64 + 1) * h_ns + lead, &mut cursor);
        }
    }
    for j in 0..knots {
        let t = t0 + (j as u64 + 1) * h_ns;
        let mut a = preview.angle(k, places[j], extrapolate, max_rate);
        if let Some(e) = ease {
            if let Some(from) = e.from.get(k) {
                a = from + e.weight(t) * (a - from);
            }
        }
        reference[j] = servo.angle_to_ticks_exact(a);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A sample of 28 servos and 62 channels due at `due_ns`: servos 0 and 27 at `a`, 27's
    /// load offset `-a`, channel 61 `a`; the rest 0.
    fn push(p: &mut Preview, due_ns: u64, a: f64) {
        let (mut angles, mut offsets, mut channels) = ([0.0; 28], [0.0; 28], [0.0; 62]);
        (angles[0], angles[27], offsets[27], channels[61]) = (a, a, -a, a);
        let head = SampleHead {
            due_ns,
            ..SampleHead::default()
        };
        p.push(head, &angles, &offsets, &channels);
    }

    #[test]
    fn the_preview_interpolates_and_extrapolates_within_bounds() {
        let mut p = Preview::new(8, 28, 62);
        for i in 0..5u64 {
            push(&mut p, i * 10, i as f64);
        }
        assert!(p.advance(12));
        assert_eq!(p.current().unwrap().due_ns, 10);
        assert!(!p.advance(15));
        assert!(p.has_future());
        assert!((p.angle_at(0, 25, 0, 1e9) - 2.5).abs() < 1e-12);
        // Past the newest (40 ns, angle 4): held, or extrapolated at 0.1/ns for at most 5 ns,
        // the slope bounded.
        assert_eq!(p.angle_at(0, 60, 0, 1e9), 4.0);
        assert!((p.angle_at(0, 60, 5, 1e9) - 4.5).abs() < 1e-9);
        assert!((p.angle_at(0, 60, 5, 1e6) - (4.0 + 1e6 * 5e-9)).abs() < 1e-12);
        // Full: the oldest goes, the storage does not grow.
        let room = (
            p.entries.capacity(),
            p.servo_rows.capacity(),
            p.channel_rows.capacity(),
        );
        for i in 5..20u64 {
            push(&mut p, i * 10, i as f64);
        }
        assert_eq!(p.entries.len(), 8);
        assert_eq!(
            (
                p.entries.capacity(),
                p.servo_rows.capacity(),
                p.channel_rows.capacity()
            ),
            room
        );
        // Each kept sample reads back its own values from its rows.
        for (i, e) in p.entries.iter().enumerate() {
            let s = p.sample(i, e);
            assert_eq!(s.angles.len(), 28);
            assert_eq!(s.channels.len(), 62);
            assert_eq!(s.angles[0], (e.due_ns / 10) as f64);
            assert_eq!(s.channels[61], (e.due_ns / 10) as f64);
            assert_eq!(s.load_offset[27], -((e.due_ns / 10) as f64));
            assert_eq!(p.command(i, 27), 0.0);
        }
        // A producer that starts over starts the preview anew.
        p.advance(150);
        push(&mut p, 5, -1.0);
        assert_eq!(p.newest().unwrap().angles[0], -1.0);
        assert!(p.current().is_none());
        assert!(p.advance(5));
        // Values a sample does not give: angles NaN, load offsets and channels 0.
        p.push(
            SampleHead {
                due_ns: 6,
                ..SampleHead::default()
            },
            &[1.0],
            &[],
            &[],
        );
        let s = p.newest().unwrap();
        assert_eq!((s.angles[0], s.load_offset[0], s.channels[0]), (1.0, 0.0, 0.0));
        assert!(s.angles[1..].iter().all(|a| a.is_nan()));
        assert!(s.load_offset.iter().chain(s.channels).all(|&v| v == 0.0));
    }
}
