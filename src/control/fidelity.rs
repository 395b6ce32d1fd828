//! End-to-end fidelity: does the rig do what the source motion did? Per servo the source angle
//! (the input of this tick mapped through the rig — what a perfect rig would do) against the
//! present position read back in the same tick: RMS, largest error, the lag that best aligns
//! the two (positive: the servos behind the source; negative: ahead of it) and the RMS after
//! that alignment; and effector positions (forward kinematics of the
//! source against that of the present angles) in millimetres at the rig's scale.
//!
//! Everything is accumulated in place: the last [`MAX_LAG_TICKS`] source and present angles in
//! rings, and per servo and candidate lag a sum of squares, so a tick allocates nothing and a run of any
//! length costs the same memory. A real-time loop hands each sample once and each tick's read
//! to a [`FidelityWorker`] as [`Message`]s (the lag search is ~28 × 129 sums a tick:
//! measurement, not control, so it stays off the tick).

use std::sync::Arc;
use std::thread::JoinHandle;

use crossbeam_channel::{Sender, TryRecvError};
use glam::DVec3;
use serde::Serialize;

use crate::fk::{fk64, Pose64};
use crate::rig::Rig;
use crate::servo::MAX_SERVOS;
use crate::skeleton::{Skeleton, MAX_CHANNELS};

/// Longest lag looked for either way, ticks (at 120 Hz: 0.53 s; at 500 Hz: 128 ms).
pub const MAX_LAG_TICKS: usize = 64;

/// Candidate lags: −[`MAX_LAG_TICKS`] … [`MAX_LAG_TICKS`].
const LAGS: usize = 2 * MAX_LAG_TICKS + 1;

/// Most effectors compared.
pub const MAX_EFFECTORS: usize = 4;

/// Adds `(a − b)²` to `sse` and one to `count`, servo by servo, where the difference is finite.
fn accumulate(a: &[f64], b: &[f64], sse: &mut [f64; MAX_SERVOS], count: &mut [f64; MAX_SERVOS]) {
    for (((a, b), s), c) in a.iter().zip(b).zip(sse.iter_mut()).zip(count.iter_mut()) {
        let e = a - b;
        let ok = e.is_finite();
        *s += if ok { e * e } else { 0.0 };
        *c += if ok { 1.0 } else { 0.0 };
    }
}

/// Adds `(a − b)²` to `sse`, servo by servo, all of `a` and `b` being finite (the common case:
/// no test per value, and the count kept once for the row).
fn accumulate_finite(a: &[f64], b: &[f64], sse: &mut [f64; MAX_SERVOS]) {
    // Slices of one length, so that the loop runs in vector lanes.
    let n = a.len().min(b.len()).min(MAX_SERVOS);
    let (a, b, sse) = (&a[..n], &b[..n], &mut sse[..n]);
    for i in 0..n {
        let e = a[i] - b[i];
        sse[i] += e * e;
    }
}

/// The accumulator.
#[derive(Clone, Debug)]
pub struct Fidelity {
    servos: usize,
    period_s: f64,
    /// The last source and present angles, newest at `head`.
    ring: Box<[[f64; MAX_SERVOS]; MAX_LAG_TICKS + 1]>,
    present_ring: Box<[[f64; MAX_SERVOS]; MAX_LAG_TICKS + 1]>,
    /// Whether each ring row is finite (and not near overflowing) in every servo.
    ring_finite: [bool; MAX_LAG_TICKS + 1],
    present_finite: [bool; MAX_LAG_TICKS + 1],
    head: usize,
    filled: usize,
    /// The tick of the newest ring row (gaps are filled with rows that compare nothing).
    last_tick: Option<u64>,
    /// Per lag (index `MAX_LAG_TICKS + lag`) and servo: sum of squared differences and their
    /// count (lag-major: a tick's update runs along contiguous servo rows, without branches).
    /// A pair of rows finite in every servo is counted once for the lag, in `rows`; the
    /// servo's count is `count + rows`.
    sse: Box<[[f64; MAX_SERVOS]; LAGS]>,
    count: Box<[[f64; MAX_SERVOS]; LAGS]>,
    rows: [f64; LAGS],
    max_abs: [f64; MAX_SERVOS],
    effector_sse: f64,
    effector_count: u64,
    effector_max: f64,
}

/// One servo's figures, degrees and milliseconds.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct ServoFidelity {
    /// The servo's name.
    pub name: String,
    /// RMS of present − source.
    pub rms_deg: f64,
    /// Largest |present − source|.
    pub max_deg: f64,
    /// The lag of present behind source that aligns them best (negative: ahead).
    pub lag_ms: f64,
    /// RMS with that lag taken out.
    pub rms_after_lag_deg: f64,
}

/// The `fidelity` block of the statistics.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct FidelityReport {
    /// Ticks compared (a source angle and a valid read).
    pub samples: u64,
    /// RMS of present − source over every servo and tick, degrees.
    pub joint_rms_deg: f64,
    /// Largest |present − source|, degrees.
    pub joint_max_deg: f64,
    /// The one lag (present behind source; negative: ahead) that best aligns all servos
    /// together, ms.
    pub lag_ms: f64,
    /// RMS over all servos with that lag taken out, degrees.
    pub rms_after_lag_deg: f64,
    /// RMS distance between the effectors at the source pose and at the present angles, mm at
    /// the rig's scale (null when not measured).
    pub effector_rms_mm: Option<f64>,
    /// The largest such distance, mm.
    pub effector_max_mm: Option<f64>,
    /// Per servo.
    pub servos: Vec<ServoFidelity>,
    /// Reads left out because the fidelity worker's queue was full (for the read, or for its
    /// sample).
    pub records_dropped: u64,
}

impl Fidelity {
    /// An accumulator for `servos` servos at a period of `period_s` seconds.
    #[must_use]
    pub fn new(servos: usize, period_s: f64) -> Fidelity {
        Fidelity {
            servos: servos.min(MAX_SERVOS),
            period_s,
            ring: Box::new([[0.0; MAX_SERVOS]; MAX_LAG_TICKS + 1]),
            present_ring: Box::new([[f64::NAN; MAX_SERVOS]; MAX_LAG_TICKS + 1]),
            ring_finite: [false; MAX_LAG_TICKS + 1],
            present_finite: [false; MAX_LAG_TICKS + 1],
            head: 0,
            filled: 0,
            last_tick: None,
            sse: Box::new([[0.0; MAX_SERVOS]; LAGS]),
            count: Box::new([[0.0; MAX_SERVOS]; LAGS]),
            rows: [0.0; LAGS],
            max_abs: [0.0; MAX_SERVOS],
            effector_sse: 0.0,
            effector_count: 0,
            effector_max: 0.0,
        }
    }

    /// One tick: this tick's source angles and the present angles read back (radians, rig
    /// order). Non-finite values are skipped.
    pub fn record(&mut self, source: &[f64], present: &[f64]) {
        let next = self.last_tick.map_or(0, |t| t + 1);
        self.record_tick(next, source, present);
    }

    /// [`Fidelity::record`] for tick `tick`: ticks skipped since the last record (a failed
    /// read, a hold) keep their place in the rings, so lags stay counted in ticks.
    pub fn record_tick(&mut self, tick: u64, source: &[f64], present: &[f64]) {
        let n = self.servos.min(source.len()).min(present.len());
        match self.last_tick {
            Some(last) if tick > last + 1 && tick - last - 1 <= MAX_LAG_TICKS as u64 => {
                for _ in last + 1..tick {
                    self.head = (self.head + 1) % (MAX_LAG_TICKS + 1);
                    self.ring[self.head] = [f64::NAN; MAX_SERVOS];
                    self.present_ring[self.head] = [f64::NAN; MAX_SERVOS];
                    self.ring_finite[self.head] = false;
                    self.present_finite[self.head] = false;
                    self.filled = (self.filled + 1).min(MAX_LAG_TICKS + 1);
                }
            }
            // Too long ago to pair with (or not after the last: a new run of ticks).
            Some(last) if tick != last + 1 => self.filled = 0,
            _ => {}
        }
        self.last_tick = Some(tick);
        self.head = (self.head + 1) % (MAX_LAG_TICKS + 1);
        let (source, present) = (&source[..n], &present[..n]);
        self.ring[self.head][..n].copy_from_slice(source);
        self.present_ring[self.head][..n].copy_from_slice(present);
        // (Bounded well inside f64, so that no difference of two of them overflows.)
        let tame = |v: &f64| v.abs() < 1e150;
        let source_finite = source.iter().all(tame);
        let present_finite = present.iter().all(tame);
        self.ring_finite[self.head] = source_finite;
        self.present_finite[self.head] = present_finite;
        self.filled = (self.filled + 1).min(MAX_LAG_TICKS + 1);
        for k in 0..n {
            let e = present[k] - source[k];
            if e.is_finite() {
                self.max_abs[k] = self.max_abs[k].max(e.abs());
            }
        }
        for back in 0..self.filled {
            let at = (self.head + MAX_LAG_TICKS + 1 - back) % (MAX_LAG_TICKS + 1);
            // Behind: this present against the source `back` ticks ago; ahead: the present
            // `back` ticks ago against this source.
            let d = MAX_LAG_TICKS + back;
            if present_finite && self.ring_finite[at] {
                accumulate_finite(present, &self.ring[at][..n], &mut self.sse[d]);
                self.rows[d] += 1.0;
            } else {
                accumulate(present, &self.ring[at][..n], &mut self.sse[d], &mut self.count[d]);
            }
            if back > 0 {
                let d = MAX_LAG_TICKS - back;
                if source_finite && self.present_finite[at] {
                    accumulate_finite(&self.present_ring[at][..n], source, &mut self.sse[d]);
                    self.rows[d] += 1.0;
                } else {
                    accumulate(
                        &self.present_ring[at][..n],
                        source,
                        &mut self.sse[d],
                        &mut self.count[d],
                    );
                }
            }
        }
    }

    /// Effector distances of one tick (metres).
    pub fn record_effectors(&mut self, source: &[DVec3], present: &[DVec3]) {
        for (s, p) in source.iter().zip(present).take(MAX_EFFECTORS) {
            self.record_effector(*s, *p);
        }
    }

    /// One effector's distance (skipped when not finite).
    fn record_effector(&mut self, source: DVec3, present: DVec3) {
        let d = (source - present).length();
        if d.is_finite() {
            self.effector_sse += d * d;
            self.effector_count += 1;
            self.effector_max = self.effector_max.max(d);
        }
    }

    /// Forgets the ring (a seek or a loop: the next source does not follow the last).
    pub fn restart(&mut self) {
        self.filled = 0;
        self.last_tick = None;
    }

    /// The figures, servos named by `names` (rig order).
    #[must_use]
    pub fn report(&self, names: &[String]) -> FidelityReport {
        let rms = |ss: f64, c: u64| {
            if c == 0 {
                0.0
            } else {
                (ss / c as f64).sqrt().to_degrees()
            }
        };
        let count = |d: usize, k: usize| self.count[d][k] + self.rows[d];
        let mut servos = Vec::with_capacity(self.servos);
        let lag_ms = |d: usize| (d as f64 - MAX_LAG_TICKS as f64) * self.period_s * 1e3;
        let zero = MAX_LAG_TICKS;
        for k in 0..self.servos {
            let best = (0..LAGS)
                .filter(|&d| count(d, k) > 0.0)
                .min_by(|&a, &b| (self.sse[a][k] / count(a, k)).total_cmp(&(self.sse[b][k] / count(b, k))))
                .unwrap_or(zero);
            servos.push(ServoFidelity {
                name: names.get(k).cloned().unwrap_or_default(),
                rms_deg: rms(self.sse[zero][k], count(zero, k) as u64),
                max_deg: self.max_abs[k].to_degrees(),
                lag_ms: lag_ms(best),
                rms_after_lag_deg: rms(self.sse[best][k], count(best, k) as u64),
            });
        }
        let total = |d: usize| -> (f64, u64) {
            (0..self.servos).fold((0.0, 0), |(s, c), k| (s + self.sse[d][k], c + count(d, k) as u64))
        };
        let best = (0..LAGS)
            .filter(|&d| total(d).1 > 0)
            .min_by(|&a, &b| {
                let (sa, ca) = total(a);
                let (sb, cb) = total(b);
                (sa / ca as f64).total_cmp(&(sb / cb as f64))
            })
            .unwrap_or(zero);
        let (s0, c0) = total(zero);
        let (sb, cb) = total(best);
        let effector =
            (self.effector_count > 0).then(|| (self.effector_sse / self.effector_count as f64).sqrt() * 1e3);
        FidelityReport {
            samples: (0..self.servos).map(|k| count(zero, k) as u64).max().unwrap_or(0),
            joint_rms_deg: rms(s0, c0),
            joint_max_deg: self.max_abs[..self.servos]
                .iter()
                .fold(0.0f64, |m, x| m.max(*x))
                .to_degrees(),
            lag_ms: lag_ms(best),
            rms_after_lag_deg: rms(sb, cb),
            effector_rms_mm: effector,
            effector_max_mm: effector.map(|_| self.effector_max * 1e3),
            servos,
            records_dropped: 0,
        }
    }
}

/// Values in one [`Message::Values`]: a 28-servo rig's angles and a CMU skeleton's 62 channels
/// go in three, each no larger than a [`Message::Read`].
pub const VALUES_PER_PART: usize = 44;

/// What a [`FidelitySink`] is handed: each source sample once (a [`Message::Sample`], then its
/// values in parts), then every tick's read compared with it. The largest variant, a read, is
/// under 400 B, so a tick hands a few cache lines over to the worker's core, and a sample
/// only the values it has (a 28-servo rig over a 62-channel skeleton: 90 of them) — not the
/// fixed-size tables sized for the largest rig and skeleton.
#[derive(Clone, Copy, Debug)]
pub enum Message {
    /// A source sample begins: its number (numbers rise with each one sent; reads refer to
    /// it) and the values that follow.
    Sample {
        /// Its number.
        seq: u64,
        /// How many values follow: its angles (one per servo, rig order), then, when
        /// `channels`, the skeleton's channels.
        values: u16,
        /// Whether its channels follow: the effectors at the present angles are then found by
        /// forward kinematics of the source pose with the servos' angles put back.
        channels: bool,
        /// Tips of the watched bones (root frame, file units).
        tips: [DVec3; MAX_EFFECTORS],
        /// Robot effectors at the source (retargeting), metres; NaN without.
        effectors: [DVec3; MAX_EFFECTORS],
    },
    /// Some of the sample `seq`'s values, from index `first` on.
    Values {
        /// The sample's number.
        seq: u64,
        /// Index of the first value.
        first: u16,
        /// Values used.
        len: u16,
        /// The values.
        values: [f64; VALUES_PER_PART],
    },
    /// One tick's read.
    Read(TickRead),
}

/// One tick's valid read, against the sample `sample`.
#[derive(Clone, Copy, Debug)]
pub struct TickRead {
    /// The tick's index.
    pub tick: u64,
    /// The number of the sample it is compared with.
    pub sample: u64,
    /// Present positions, ticks (rig order).
    pub present: [i32; MAX_SERVOS],
    /// Robot effectors at the present angles, metres, when the loop found them (retargeting);
    /// NaN otherwise.
    pub effectors: [DVec3; MAX_EFFECTORS],
}

impl TickRead {
    /// A read of tick `tick` against sample `sample`, positions `present`.
    #[must_use]
    pub fn new(tick: u64, sample: u64, present: &[i32]) -> TickRead {
        let mut r = TickRead {
            tick,
            sample,
            present: [0; MAX_SERVOS],
            effectors: [DVec3::NAN; MAX_EFFECTORS],
        };
        let n = present.len().min(MAX_SERVOS);
        r.present[..n].copy_from_slice(&present[..n]);
        r
    }
}

/// Hands a sample to `send` as [`Message`]s: its start, then `angles` followed by `channels`
/// in parts. False as soon as one is refused (reads must not refer to it then).
pub fn send_sample(
    seq: u64,
    angles: &[f64],
    channels: Option<&[f64]>,
    tips: [DVec3; MAX_EFFECTORS],
    effectors: [DVec3; MAX_EFFECTORS],
    mut send: impl FnMut(Message) -> bool,
) -> bool {
    let count = angles.len() + channels.map_or(0, <[f64]>::len);
    if count > MAX_SERVOS + MAX_CHANNELS {
        return false;
    }
    if !send(Message::Sample {
        seq,
        values: count as u16,
        channels: channels.is_some(),
        tips,
        effectors,
    }) {
        return false;
    }
    let mut all = angles.iter().chain(channels.unwrap_or(&[])).copied();
    let mut first = 0;
    while first < count {
        let mut values = [0.0; VALUES_PER_PART];
        let mut len = 0;
        for (v, x) in values.iter_mut().zip(all.by_ref()) {
            *v = x;
            len += 1;
        }
        if !send(Message::Values {
            seq,
            first: first as u16,
            len: len as u16,
            values,
        }) {
            return false;
        }
        first += len;
    }
    true
}

/// The joint angles (radians) of servo positions `ticks` through `rig`, as far as `out` goes.
pub(super) fn angles_of_ticks(rig: &Rig, ticks: &[i32], out: &mut [f64]) {
    for ((a, s), t) in out.iter_mut().zip(&rig.servos).zip(ticks) {
        *a = s.ticks_to_angle(f64::from(*t));
    }
}

/// Effector positions at the present angles by forward kinematics of the skeleton: what the
/// servos do put back into the source's pose (the joints no servo drives as the source had
/// them), the watched bones' tips at the rig's scale.
#[derive(Clone, Debug)]
pub struct EffectorPose {
    skeleton: Arc<Skeleton>,
    watch: [Option<usize>; MAX_EFFECTORS],
    metres_per_unit: f64,
    channels: Box<[f64; MAX_CHANNELS]>,
    pose: Box<Pose64>,
}

impl EffectorPose {
    /// For the `watch`ed bones of `skeleton`, `metres_per_unit` metres per file unit.
    #[must_use]
    pub fn new(skeleton: Arc<Skeleton>, watch: [Option<usize>; MAX_EFFECTORS], metres_per_unit: f64) -> Self {
        EffectorPose {
            skeleton,
            watch,
            metres_per_unit,
            channels: Box::new([0.0; MAX_CHANNELS]),
            pose: Box::default(),
        }
    }

    /// The watched effectors (metres) at the source (`tips`, file units) and at the `present`
    /// angles put back into the source pose `channels` through `rig`; NaN where nothing is
    /// watched, and everywhere when `channels` is not the skeleton's. Allocates nothing.
    pub fn pair(
        &mut self,
        rig: &Rig,
        present: &[f64],
        channels: &[f64],
        tips: &[DVec3; MAX_EFFECTORS],
    ) -> [(DVec3, DVec3); MAX_EFFECTORS] {
        let mut out = [(DVec3::NAN, DVec3::NAN); MAX_EFFECTORS];
        let n = self.skeleton.channel_count();
        if channels.len() != n || present.len() != rig.len() {
            return out;
        }
        rig.channels_from_angles(&self.skeleton, present, channels, &mut self.channels[..n]);
        fk64(&self.skeleton, &self.channels[..n], &mut self.pose);
        let scale = self.metres_per_unit;
        for ((e, w), s) in out.iter_mut().zip(self.watch).zip(tips) {
            if let Some(b) = w {
                *e = (*s * scale, self.pose.tip[b] * scale);
            }
        }
        out
    }
}

/// Turns [`Message`]s into figures: keeps the sample being compared with, converts each read's
/// ticks to angles through the rig and accumulates them in a [`Fidelity`] — on the
/// [`FidelityWorker`]'s thread, or in the tick without one.
#[derive(Clone, Debug)]
pub struct FidelitySink {
    /// The accumulator.
    pub fidelity: Fidelity,
    rig: Rig,
    effector_pose: Option<EffectorPose>,
    /// The sample's number, once its start has come.
    seq: Option<u64>,
    /// Values it has, and has come.
    expected: usize,
    received: usize,
    with_channels: bool,
    /// Its angles (one per servo), then its channels.
    values: Box<[f64; MAX_SERVOS + MAX_CHANNELS]>,
    tips: [DVec3; MAX_EFFECTORS],
    effectors: [DVec3; MAX_EFFECTORS],
    present: [f64; MAX_SERVOS],
    /// Reads whose sample had not come whole.
    pub unpaired: u64,
}

impl FidelitySink {
    /// A sink for `rig`'s servos at a period of `period_s` seconds (with `effector_pose` for
    /// samples that come with their channels).
    #[must_use]
    pub fn new(rig: Rig, period_s: f64, effector_pose: Option<EffectorPose>) -> FidelitySink {
        FidelitySink {
            fidelity: Fidelity::new(rig.len(), period_s),
            rig,
            effector_pose,
            seq: None,
            expected: 0,
            received: 0,
            with_channels: false,
            values: Box::new([0.0; MAX_SERVOS + MAX_CHANNELS]),
            tips: [DVec3::NAN; MAX_EFFECTORS],
            effectors: [DVec3::NAN; MAX_EFFECTORS],
            present: [f64::NAN; MAX_SERVOS],
            unpaired: 0,
        }
    }

    /// Takes one message. Allocates nothing.
    pub fn take(&mut self, m: &Message) {
        match m {
            Message::Sample {
                seq,
                values,
                channels,
                tips,
                effectors,
            } => {
                self.seq = Some(*seq);
                self.expected = usize::from(*values).min(self.values.len());
                self.received = 0;
                self.with_channels = *channels;
                self.tips = *tips;
                self.effectors = *effectors;
            }
            Message::Values {
                seq,
                first,
                len,
                values,
            } => {
                let (first, len) = (usize::from(*first), usize::from(*len).min(VALUES_PER_PART));
                // In order, or not at all (a part refused leaves the sample incomplete).
                if self.seq == Some(*seq) && first == self.received && first + len <= self.expected {
                    self.values[first..first + len].copy_from_slice(&values[..len]);
                    self.received += len;
                }
            }
            Message::Read(r) => self.read(r),
        }
    }

    /// One read against the sample it names: joints, and effectors.
    fn read(&mut self, r: &TickRead) {
        let n = self.rig.len();
        if self.seq != Some(r.sample) || self.received < self.expected || self.expected < n {
            self.unpaired += 1;
            return;
        }
        angles_of_ticks(&self.rig, &r.present, &mut self.present);
        self.fidelity
            .record_tick(r.tick, &self.values[..n], &self.present[..n]);
        match &mut self.effector_pose {
            Some(pose) if self.with_channels => {
                let channels = &self.values[n..self.expected];
                for (s, p) in pose.pair(&self.rig, &self.present[..n], channels, &self.tips) {
                    self.fidelity.record_effector(s, p);
                }
            }
            _ => {
                for (s, p) in self.effectors.iter().zip(&r.effectors) {
                    self.fidelity.record_effector(*s, *p);
                }
            }
        }
    }

    /// The figures, servos named by `names` (rig order); reads that found no sample count as
    /// dropped.
    #[must_use]
    pub fn report(&self, names: &[String]) -> FidelityReport {
        let mut r = self.fidelity.report(names);
        r.records_dropped = self.unpaired;
        r
    }
}

/// A thread that takes [`Message`]s through a bounded channel into a [`FidelitySink`]: the
/// tick only copies a message in (no allocation, never waits; a message that finds the
/// channel full is refused).
#[derive(Debug)]
pub struct FidelityWorker {
    tx: Option<Sender<Message>>,
    handle: Option<JoinHandle<Box<FidelitySink>>>,
}

/// Messages the channel holds (under 400 B each): half a second of reads at 1 kHz (the worker
/// takes one in a few µs).
const WORKER_QUEUE: usize = 512;

/// How long the worker sleeps when it has taken every message.
const WORKER_POLL: std::time::Duration = std::time::Duration::from_millis(4);

impl FidelityWorker {
    /// Starts the worker with `sink`.
    ///
    /// # Errors
    /// When the thread cannot be started.
    pub fn spawn(mut sink: Box<FidelitySink>) -> std::io::Result<FidelityWorker> {
        let filler = Message::Values {
            seq: 0,
            first: 0,
            len: 0,
            values: [0.0; VALUES_PER_PART],
        };
        let (tx, rx) = crate::resident::channel(WORKER_QUEUE, filler);
        let handle = std::thread::Builder::new()
            .name("fidelity".into())
            .spawn(move || loop {
                // Polled, never waited on: a receiver blocked in the channel would have each
                // tick's send wake it (a futex call, ~2 µs of the tick).
                match rx.try_recv() {
                    Ok(m) => sink.take(&m),
                    Err(TryRecvError::Empty) => std::thread::sleep(WORKER_POLL),
                    Err(TryRecvError::Disconnected) => break sink,
                }
            })?;
        Ok(FidelityWorker {
            tx: Some(tx),
            handle: Some(handle),
        })
    }

    /// Hands one message over without waiting (false: refused, the channel full or the
    /// worker gone).
    pub fn send(&mut self, m: Message) -> bool {
        self.tx.as_ref().is_some_and(|tx| tx.try_send(m).is_ok())
    }

    /// Messages sent and not yet taken.
    #[must_use]
    pub fn queued(&self) -> usize {
        self.tx.as_ref().map_or(0, Sender::len)
    }

    /// Closes the channel and returns the sink once every message sent is taken (`None` when
    /// the worker died).
    pub fn finish(&mut self) -> Option<Box<FidelitySink>> {
        self.tx = None;
        self.handle.take().and_then(|h| h.join().ok())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A present that follows a sine three ticks late: the lag is found, and with it taken out
    /// the error is zero.
    #[test]
    fn a_delayed_copy_is_found_and_aligned() {
        let mut f = Fidelity::new(2, 0.01);
        let src = |t: f64| (t * 3.0).sin();
        for i in 0..500 {
            let t = i as f64 * 0.01;
            let source = [src(t), 0.5];
            let present = [src(t - 0.03), 0.5 + 0.01];
            f.record(&source, &present);
        }
        let r = f.report(&["a".into(), "b".into()]);
        assert!((r.servos[0].lag_ms - 30.0).abs() < 1e-9, "{r:?}");
        assert!((r.lag_ms - 30.0).abs() < 1e-9, "{r:?}");
        assert!(r.servos[0].rms_after_lag_deg < 1e-9);
        assert!(r.servos[0].rms_deg > 1.0);
        assert!((r.servos[1].rms_deg - 0.01f64.to_degrees()).abs() < 1e-9);
        assert_eq!(r.samples, 500);
        assert!(r.effector_rms_mm.is_none());
        f.record_effectors(&[DVec3::ZERO], &[DVec3::new(0.003, 0.004, 0.0)]);
        let r = f.report(&[]);
        assert!((r.effector_rms_mm.unwrap() - 5.0).abs() < 1e-9);
    }

    /// The CMU puppet: subject 16's skeleton, the rig over it, and its wrists and ankles.
    fn puppet() -> (Arc<Skeleton>, Rig, [Option<usize>; MAX_EFFECTORS]) {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
        let skel = Arc::new(
            crate::formats::asf::load(&root.join("data/cmu/16.asf"))
                .unwrap()
                .skeleton,
        );
        let profile = crate::profile::Profile::load(&root.join("firmware-profile/cmu-puppet.toml")).unwrap();
        let rig = profile.rig(Some(&skel)).unwrap();
        let watch = ["lradius", "rradius", "ltibia", "rtibia"].map(|n| skel.find(n));
        (skel, rig, watch)
    }

    /// A one-servo rig geared to 65,190 ticks a radian, zero at tick 0.
    fn fine_rig() -> Rig {
        let mut servo = puppet().1.servos[0];
        servo.zero_tick = 0.0;
        servo.gear = 100.0;
        servo.direction = 1.0;
        let mut rig = Rig::default();
        rig.servos.push(servo).unwrap();
        rig
    }

    /// Ticks without a read (failed reads, holds) keep their place: the lag is still found
    /// exactly (to the ticks' resolution), and the worker gives what the sink in the tick does.
    #[test]
    fn gaps_keep_the_lag_and_the_worker_agrees() {
        let rig = fine_rig();
        let ticks_of = |a: f64| rig.servos[0].angle_to_ticks(a);
        let src = |t: f64| rig.servos[0].ticks_to_angle(f64::from(ticks_of((t * 3.0).sin())));
        let mut inline = FidelitySink::new(rig.clone(), 0.01, None);
        let mut worker = FidelityWorker::spawn(Box::new(FidelitySink::new(rig.clone(), 0.01, None))).unwrap();
        let mut sent = 0;
        for i in 0..600u64 {
            let t = i as f64 * 0.01;
            // One sample a tick, a read of the present four ticks behind it.
            let mut both = |m: Message| {
                inline.take(&m);
                // (The test does not depend on how soon the worker's thread runs.)
                while worker.queued() > WORKER_QUEUE / 2 {
                    std::thread::yield_now();
                }
                assert!(worker.send(m));
                true
            };
            assert!(send_sample(
                i,
                &[src(t)],
                None,
                [DVec3::NAN; MAX_EFFECTORS],
                [DVec3::NAN; MAX_EFFECTORS],
                &mut both
            ));
            // Every seventh tick and a run of ten are missing; a run of 80 starts the ring over.
            if i % 7 == 3 || (200..210).contains(&i) || (400..480).contains(&i) {
                continue;
            }
            both(Message::Read(TickRead::new(
                i,
                i,
                &[ticks_of(((t - 0.04) * 3.0).sin())],
            )));
            sent += 1;
        }
        let a = inline.report(&["a".into()]);
        assert!((a.lag_ms - 40.0).abs() < 1e-9, "{a:?}");
        assert!(a.rms_after_lag_deg < 1e-9, "{a:?}");
        assert_eq!(a.samples, sent);
        assert_eq!(a.records_dropped, 0);
        let b = worker.finish().unwrap().report(&["a".into()]);
        assert_eq!(a, b);
    }

    /// A sample is taken in parts and in order: a read against a sample whose values stopped
    /// part way, or against one never begun, compares nothing and is counted.
    #[test]
    fn a_read_against_an_incomplete_sample_compares_nothing() {
        let rig = fine_rig();
        let mut sink = FidelitySink::new(rig.clone(), 0.01, None);
        let nan = [DVec3::NAN; MAX_EFFECTORS];
        assert!(send_sample(1, &[0.5], None, nan, nan, |m| {
            sink.take(&m);
            true
        }));
        let half = rig.servos[0].angle_to_ticks(0.5);
        sink.take(&Message::Read(TickRead::new(0, 1, &[half])));
        // Sample 2: begun, its values refused.
        let mut parts = 0;
        assert!(!send_sample(2, &[0.7], None, nan, nan, |m| {
            parts += 1;
            if parts == 1 {
                sink.take(&m);
            }
            parts == 1
        }));
        sink.take(&Message::Read(TickRead::new(1, 2, &[half])));
        sink.take(&Message::Read(TickRead::new(2, 3, &[half])));
        let r = sink.report(&[]);
        assert_eq!(r.samples, 1);
        assert_eq!(r.records_dropped, 2);
        assert!(r.joint_rms_deg < 1e-3, "{r:?}");
    }

    /// A sample larger than a part (a 28-servo rig with a 62-channel skeleton's channels) goes
    /// in parts, and the worker finds the effectors at the present angles that the forward
    /// kinematics of the source pose with those angles put back gives.
    #[test]
    fn the_worker_finds_the_effectors_from_samples_sent_once() {
        let (skel, rig, watch) = puppet();
        let n = rig.len();
        let c = skel.channel_count();
        assert!(n + c > 2 * VALUES_PER_PART, "{n} + {c}");
        let pose = EffectorPose::new(Arc::clone(&skel), watch, 0.0254);
        let mut worker =
            FidelityWorker::spawn(Box::new(FidelitySink::new(rig.clone(), 0.001, Some(pose)))).unwrap();
        // What the sink must find, computed here without it.
        let mut expected = Fidelity::new(n, 0.001);
        let mut fk = Pose64::default();
        let mut channels = vec![0.0; c];
        let mut back = vec![0.0; c];
        let mut tips = [DVec3::NAN; MAX_EFFECTORS];
        let mut angles = vec![0.0; n];
        let mut present = vec![0.0; n];
        let mut ticks = vec![0i32; n];
        for tick in 0..400u64 {
            // A new sample every eight ticks; the present lags the source by a little.
            let sample = tick / 8;
            if tick % 8 == 0 {
                for (i, ch) in channels.iter_mut().enumerate() {
                    *ch = 0.3 * ((sample as f64) * 0.05 + i as f64).sin();
                }
                fk64(&skel, &channels, &mut fk);
                for (t, w) in tips.iter_mut().zip(watch) {
                    *t = fk.tip[w.unwrap()];
                }
                rig.joint_angles(&skel, &channels, &[], &mut angles);
                while worker.queued() > WORKER_QUEUE / 2 {
                    std::thread::yield_now();
                }
                let mut parts = 0;
                assert!(send_sample(
                    sample,
                    &angles,
                    Some(&channels),
                    tips,
                    [DVec3::NAN; MAX_EFFECTORS],
                    |m| {
                        parts += 1;
                        worker.send(m)
                    }
                ));
                assert_eq!(parts, 1 + (n + c).div_ceil(VALUES_PER_PART));
            }
            for ((t, s), a) in ticks.iter_mut().zip(&rig.servos).zip(&angles) {
                *t = s.angle_to_ticks(a - 0.01);
            }
            for ((p, s), t) in present.iter_mut().zip(&rig.servos).zip(&ticks) {
                *p = s.ticks_to_angle(f64::from(*t));
            }
            expected.record_tick(tick, &angles, &present);
            rig.channels_from_angles(&skel, &present, &channels, &mut back);
            fk64(&skel, &back, &mut fk);
            for (t, w) in tips.iter().zip(watch) {
                expected.record_effector(*t * 0.0254, fk.tip[w.unwrap()] * 0.0254);
            }
            assert!(worker.send(Message::Read(TickRead::new(tick, sample, &ticks))));
        }
        let a = expected.report(&[]);
        let b = worker.finish().unwrap().report(&[]);
        assert_eq!(a, b);
        assert!(a.effector_rms_mm.unwrap() > 0.1, "{a:?}");
        assert_eq!(expected.effector_count, 400 * 4);
    }

    /// Messages the loop would never send — values past the sample's count, out of order,
    /// for another sample, a sample claiming more values than exist, too few channels, reads
    /// of unknown samples and wild positions — in any order: the sink panics on none, and a
    /// read it compares is one whose sample came whole.
    #[test]
    fn any_messages_leave_the_sink_whole() {
        static COMPARED: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
        use proptest::prelude::*;
        let (skel, rig, watch) = puppet();
        let pose = EffectorPose::new(Arc::clone(&skel), watch, 0.0254);
        let value = prop_oneof![Just(f64::NAN), Just(f64::INFINITY), -10.0..10.0f64];
        let message = prop_oneof![
            // The counts the loop sends (28 angles, and 62 channels), and others.
            (
                0..4u64,
                prop_oneof![Just(28u16), Just(90), 0..200u16],
                any::<bool>(),
                value.clone()
            )
                .prop_map(|(seq, values, channels, v)| Message::Sample {
                    seq,
                    values,
                    channels,
                    tips: [DVec3::splat(v); MAX_EFFECTORS],
                    effectors: [DVec3::splat(v); MAX_EFFECTORS],
                }),
            (
                0..4u64,
                prop_oneof![Just(0u16), Just(44), Just(88), 0..200u16],
                prop_oneof![Just(28u16), Just(44), Just(2), any::<u16>()],
                value
            )
                .prop_map(|(seq, first, len, v)| Message::Values {
                    seq,
                    first,
                    len,
                    values: [v; VALUES_PER_PART],
                }),
            (0..100u64, 0..4u64, any::<i32>()).prop_map(|(tick, sample, p)| {
                Message::Read(TickRead::new(tick, sample, &[p; MAX_SERVOS]))
            }),
        ];
        // Whole samples as the loop sends them, among the rest.
        let whole = (0..4u64, any::<bool>(), -3.0..3.0f64).prop_map(|(seq, channels, v)| {
            let (angles, values) = ([v; 28], [v; 62]);
            let mut out = Vec::new();
            let nan = [DVec3::NAN; MAX_EFFECTORS];
            send_sample(seq, &angles, channels.then_some(&values[..]), nan, nan, |m| {
                out.push(m);
                true
            });
            out
        });
        let part = prop_oneof![1 => whole, 3 => message.prop_map(|m| vec![m])];
        proptest!(ProptestConfig::with_cases(200), |(parts in proptest::collection::vec(part, 0..40))| {
            let messages: Vec<Message> = parts.into_iter().flatten().collect();
            let mut sink = FidelitySink::new(rig.clone(), 0.001, Some(pose.clone()));
            let reads = messages.iter().filter(|m| matches!(m, Message::Read(_))).count() as u64;
            for m in &messages {
                sink.take(m);
            }
            let r = sink.report(&[]);
            COMPARED.fetch_add(r.samples, std::sync::atomic::Ordering::Relaxed);
            prop_assert!(r.samples + r.records_dropped <= reads);
            prop_assert!(r.joint_rms_deg.is_finite() && r.effector_rms_mm.is_none_or(f64::is_finite));
        });
        // The streams had reads to compare, not only ones refused.
        assert!(COMPARED.load(std::sync::atomic::Ordering::Relaxed) > 0);
    }

    /// The sums kept per lag and servo are the direct ones: every pair of recorded ticks `lag`
    /// apart within a run (a gap longer than the ring starts a new one), non-finite
    /// differences left out — with some values NaN, rows whole and rows not.
    #[test]
    fn the_lag_sums_are_the_direct_sums() {
        let servos = 3;
        let mut f = Fidelity::new(servos, 0.01);
        let mut history: Vec<(u64, usize, Vec<f64>, Vec<f64>)> = Vec::new();
        let (mut run, mut last) = (0, None::<u64>);
        let mut tick = 0u64;
        for i in 0..400u64 {
            // Gaps of 3 and, once, of 100 ticks (a new run).
            tick += if i == 200 {
                100
            } else if i % 37 == 5 {
                3
            } else {
                1
            };
            let t = tick as f64 * 0.01;
            let mut source: Vec<f64> = (0..servos).map(|k| (t * (1.0 + k as f64)).sin()).collect();
            let mut present: Vec<f64> = (0..servos)
                .map(|k| ((t - 0.03) * (1.0 + k as f64)).sin() + 0.01)
                .collect();
            if i % 11 == 0 {
                source[(i as usize) % servos] = f64::NAN;
            }
            if i % 13 == 0 {
                present[(i as usize + 1) % servos] = f64::INFINITY;
            }
            if last.is_some_and(|l| tick - l - 1 > MAX_LAG_TICKS as u64) {
                run += 1;
            }
            last = Some(tick);
            f.record_tick(tick, &source, &present);
            history.push((tick, run, source, present));
        }
        for back in 0..=MAX_LAG_TICKS as u64 {
            for k in 0..servos {
                let (mut behind, mut ahead) = ((0.0, 0.0), (0.0, 0.0));
                for (t, r, s_now, p_now) in &history {
                    let Some((_, _, s_then, p_then)) = history.iter().find(|h| h.0 + back == *t && h.1 == *r)
                    else {
                        continue;
                    };
                    let e = p_now[k] - s_then[k];
                    if e.is_finite() {
                        behind = (behind.0 + e * e, behind.1 + 1.0);
                    }
                    let e = p_then[k] - s_now[k];
                    if back > 0 && e.is_finite() {
                        ahead = (ahead.0 + e * e, ahead.1 + 1.0);
                    }
                }
                let at = |d: usize| (f.sse[d][k], f.count[d][k] + f.rows[d]);
                let d = MAX_LAG_TICKS + back as usize;
                assert_eq!(at(d).1, behind.1, "lag +{back}, servo {k}");
                assert!(
                    (at(d).0 - behind.0).abs() <= 1e-12 * behind.0.max(1.0),
                    "lag +{back}, servo {k}"
                );
                if back > 0 {
                    let d = MAX_LAG_TICKS - back as usize;
                    assert_eq!(at(d).1, ahead.1, "lag -{back}, servo {k}");
                    assert!(
                        (at(d).0 - ahead.0).abs() <= 1e-12 * ahead.0.max(1.0),
                        "lag -{back}, servo {k}"
                    );
                }
            }
        }
    }

    /// A present that runs two ticks ahead of the source: a negative lag.
    #[test]
    fn a_lead_is_a_negative_lag() {
        let mut f = Fidelity::new(1, 0.01);
        for i in 0..300 {
            let t = i as f64 * 0.01;
            f.record(&[(t * 2.0).sin()], &[((t + 0.02) * 2.0).sin()]);
        }
        let r = f.report(&["a".into()]);
        assert!((r.lag_ms + 20.0).abs() < 1e-9, "{r:?}");
        assert!(r.rms_after_lag_deg < 1e-9 && r.joint_rms_deg > 0.1);
    }
}
