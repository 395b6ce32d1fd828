//! End-to-end fidelity: does the rig do what the source motion did? Per servo the source angle
//! (the input of this tick mapped through the rig — what a perfect rig would do) against the
//! present position read back in the same tick: RMS, largest error, the lag that best aligns
//! the two (positive: the servos behind the source; negative: ahead of it) and the RMS after
//! that alignment; and effector positions (forward kinematics of the
//! source against that of the present angles) in millimetres at the rig's scale.
//!
//! Everything is accumulated in place: the last [`MAX_LAG_TICKS`] source and present angles in
//! rings, and per servo and candidate lag a sum of squares, so a tick allocates nothing and a run of any
//! length costs the same memory. A real-time loop hands its records to a [`FidelityWorker`]
//! (the lag search is ~28 × 129 sums a tick: measurement, not control, so it stays off the tick).

use std::sync::Arc;
use std::thread::JoinHandle;

use crossbeam_channel::{Sender, TryRecvError, TrySendError};
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

/// The accumulator.
#[derive(Clone, Debug)]
pub struct Fidelity {
    servos: usize,
    period_s: f64,
    /// The last source and present angles, newest at `head`.
    ring: Box<[[f64; MAX_SERVOS]; MAX_LAG_TICKS + 1]>,
    present_ring: Box<[[f64; MAX_SERVOS]; MAX_LAG_TICKS + 1]>,
    head: usize,
    filled: usize,
    /// The tick of the newest ring row (gaps are filled with rows that compare nothing).
    last_tick: Option<u64>,
    /// Per lag (index `MAX_LAG_TICKS + lag`) and servo: sum of squared differences and their
    /// count (lag-major: a tick's update runs along contiguous servo rows, without branches).
    sse: Box<[[f64; MAX_SERVOS]; LAGS]>,
    count: Box<[[f64; MAX_SERVOS]; LAGS]>,
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
    /// Ticks left out because the fidelity worker's queue was full.
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
            head: 0,
            filled: 0,
            last_tick: None,
            sse: Box::new([[0.0; MAX_SERVOS]; LAGS]),
            count: Box::new([[0.0; MAX_SERVOS]; LAGS]),
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
                    self.filled = (self.filled + 1).min(MAX_LAG_TICKS + 1);
                }
            }
            // Too long ago to pair with (or not after the last: a new run of ticks).
            Some(last) if tick != last + 1 => self.filled = 0,
            _ => {}
        }
        self.last_tick = Some(tick);
        self.head = (self.head + 1) % (MAX_LAG_TICKS + 1);
        self.ring[self.head][..n].copy_from_slice(&source[..n]);
        self.present_ring[self.head][..n].copy_from_slice(&present[..n]);
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
            accumulate(
                &present[..n],
                &self.ring[at][..n],
                &mut self.sse[MAX_LAG_TICKS + back],
                &mut self.count[MAX_LAG_TICKS + back],
            );
            if back > 0 {
                accumulate(
                    &self.present_ring[at][..n],
                    &source[..n],
                    &mut self.sse[MAX_LAG_TICKS - back],
                    &mut self.count[MAX_LAG_TICKS - back],
                );
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
        let mut servos = Vec::with_capacity(self.servos);
        let lag_ms = |d: usize| (d as f64 - MAX_LAG_TICKS as f64) * self.period_s * 1e3;
        let zero = MAX_LAG_TICKS;
        for k in 0..self.servos {
            let best = (0..LAGS)
                .filter(|&d| self.count[d][k] > 0.0)
                .min_by(|&a, &b| {
                    (self.sse[a][k] / self.count[a][k]).total_cmp(&(self.sse[b][k] / self.count[b][k]))
                })
                .unwrap_or(zero);
            servos.push(ServoFidelity {
                name: names.get(k).cloned().unwrap_or_default(),
                rms_deg: rms(self.sse[zero][k], self.count[zero][k] as u64),
                max_deg: self.max_abs[k].to_degrees(),
                lag_ms: lag_ms(best),
                rms_after_lag_deg: rms(self.sse[best][k], self.count[best][k] as u64),
            });
        }
        let total = |d: usize| -> (f64, u64) {
            (0..self.servos).fold((0.0, 0), |(s, c), k| {
                (s + self.sse[d][k], c + self.count[d][k] as u64)
            })
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
            samples: self.count[zero][..self.servos]
                .iter()
                .map(|&c| c as u64)
                .max()
                .unwrap_or(0),
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

/// One tick's figures for a [`FidelityWorker`].
#[derive(Clone, Copy, Debug)]
pub struct FidelityRecord {
    /// The tick's index.
    pub tick: u64,
    /// Servos in `source` and `present`.
    pub servos: usize,
    /// Source angles, radians (rig order).
    pub source: [f64; MAX_SERVOS],
    /// Present angles read back, radians.
    pub present: [f64; MAX_SERVOS],
    /// Effector positions at the source and at the present angles, metres (NaN: none).
    pub effectors: [(DVec3, DVec3); MAX_EFFECTORS],
    /// The number of the source pose whose effectors are still to be found
    /// ([`EffectorPose::fill`]): the worker has had the pose itself as a [`SourcePose`].
    pub pose: Option<u64>,
}

/// A source sample's pose for the effectors at the present angles: sent to a
/// [`FidelityWorker`] once per sample (4.3 KB), not with every tick's record.
#[derive(Clone, Copy, Debug)]
pub struct SourcePose {
    /// Its number: poses are numbered in the order they are sent, and records refer to them
    /// by it.
    pub seq: u64,
    /// The source's channels (the skeleton's first ones).
    pub channels: [f64; MAX_CHANNELS],
    /// The source's watched tips, file units.
    pub tips: [DVec3; MAX_EFFECTORS],
}

impl FidelityRecord {
    /// A record of `servos` servos with nothing in it yet.
    #[must_use]
    pub fn new(tick: u64, servos: usize) -> FidelityRecord {
        FidelityRecord {
            tick,
            servos: servos.min(MAX_SERVOS),
            source: [f64::NAN; MAX_SERVOS],
            present: [f64::NAN; MAX_SERVOS],
            effectors: [(DVec3::NAN, DVec3::NAN); MAX_EFFECTORS],
            pose: None,
        }
    }
}

/// Effector positions at the present angles by forward kinematics of the skeleton: what the
/// servos do put back into the source's pose (the joints no servo drives as the source had
/// them), the watched bones' tips at the rig's scale.
#[derive(Clone, Debug)]
pub struct EffectorPose {
    skeleton: Arc<Skeleton>,
    rig: Rig,
    watch: [Option<usize>; MAX_EFFECTORS],
    metres_per_unit: f64,
    channels: Box<[f64; MAX_CHANNELS]>,
    pose: Box<Pose64>,
}

impl EffectorPose {
    /// For the `watch`ed bones of `skeleton` driven through `rig`, `metres_per_unit` metres per
    /// file unit.
    #[must_use]
    pub fn new(
        skeleton: Arc<Skeleton>,
        rig: Rig,
        watch: [Option<usize>; MAX_EFFECTORS],
        metres_per_unit: f64,
    ) -> Self {
        EffectorPose {
            skeleton,
            rig,
            watch,
            metres_per_unit,
            channels: Box::new([0.0; MAX_CHANNELS]),
            pose: Box::default(),
        }
    }

    /// Fills a record's effectors (source and present, metres) from `source`, the pose it
    /// refers to (left NaN when it refers to another). Allocates nothing.
    pub fn fill(&mut self, r: &mut FidelityRecord, source: &SourcePose) {
        if r.pose.take() != Some(source.seq) {
            return;
        }
        let n = self.skeleton.channel_count();
        self.rig.channels_from_angles(
            &self.skeleton,
            &r.present[..r.servos],
            &source.channels[..n],
            &mut self.channels[..n],
        );
        fk64(&self.skeleton, &self.channels[..n], &mut self.pose);
        let scale = self.metres_per_unit;
        for ((e, w), s) in r.effectors.iter_mut().zip(self.watch).zip(source.tips) {
            if let Some(b) = w {
                *e = (s * scale, self.pose.tip[b] * scale);
            }
        }
    }
}

impl Fidelity {
    /// Takes one record (joints and effectors).
    pub fn take(&mut self, r: &FidelityRecord) {
        self.record_tick(r.tick, &r.source[..r.servos], &r.present[..r.servos]);
        for (s, p) in &r.effectors {
            self.record_effector(*s, *p);
        }
    }
}

/// A thread that accumulates [`FidelityRecord`]s sent to it through a bounded channel: the
/// tick only copies one record in (no allocation, never waits; a record that finds the
/// channel full is counted and dropped, its tick left as a gap).
#[derive(Debug)]
pub struct FidelityWorker {
    tx: Option<Sender<FidelityRecord>>,
    poses: Option<Sender<SourcePose>>,
    handle: Option<JoinHandle<Fidelity>>,
    /// Records dropped because the channel was full.
    pub dropped: u64,
}

/// Records the channel holds (1.3 KB each): a quarter second at 1 kHz (the worker takes one in
/// a few µs).
const WORKER_QUEUE: usize = 256;

/// Source poses the channel holds (4.3 KB each; one a sample).
const POSE_QUEUE: usize = 64;

/// How long the worker sleeps when it has taken every record.
const WORKER_POLL: std::time::Duration = std::time::Duration::from_millis(4);

impl FidelityWorker {
    /// Starts the worker with `fidelity` as its accumulator (and `pose` for records whose
    /// effectors come from the skeleton's pose).
    ///
    /// # Errors
    /// When the thread cannot be started.
    pub fn spawn(mut fidelity: Fidelity, mut pose: Option<EffectorPose>) -> std::io::Result<FidelityWorker> {
        let (tx, rx) = crossbeam_channel::bounded::<FidelityRecord>(WORKER_QUEUE);
        let (pose_tx, pose_rx) = crossbeam_channel::bounded::<SourcePose>(POSE_QUEUE);
        let handle = std::thread::Builder::new()
            .name("fidelity".into())
            .spawn(move || {
                let mut source: Option<Box<SourcePose>> = None;
                loop {
                    // Polled, never waited on: a receiver blocked in the channel would have each
                    // tick's send wake it (a futex call, ~2 µs of the tick).
                    match rx.try_recv() {
                        Ok(mut r) => {
                            if let (Some(p), Some(seq)) = (&mut pose, r.pose) {
                                // A record's pose was sent before it, the poses in order.
                                while source.as_ref().is_none_or(|s| s.seq < seq) {
                                    match pose_rx.try_recv() {
                                        Ok(s) => **source.get_or_insert_with(|| Box::new(s)) = s,
                                        Err(_) => break,
                                    }
                                }
                                if let Some(s) = &source {
                                    p.fill(&mut r, s);
                                }
                            }
                            fidelity.take(&r);
                        }
                        Err(TryRecvError::Empty) => std::thread::sleep(WORKER_POLL),
                        Err(TryRecvError::Disconnected) => break fidelity,
                    }
                }
            })?;
        Ok(FidelityWorker {
            tx: Some(tx),
            poses: Some(pose_tx),
            handle: Some(handle),
            dropped: 0,
        })
    }

    /// Hands a source pose over without waiting (false when the channel is full: records
    /// must not refer to it).
    pub fn send_pose(&mut self, pose: &SourcePose) -> bool {
        self.poses.as_ref().is_some_and(|tx| tx.try_send(*pose).is_ok())
    }

    /// Hands one record over without waiting.
    pub fn send(&mut self, record: FidelityRecord) {
        if let Some(tx) = &self.tx {
            if let Err(TrySendError::Full(_) | TrySendError::Disconnected(_)) = tx.try_send(record) {
                self.dropped += 1;
            }
        }
    }

    /// Records sent and not yet taken.
    #[must_use]
    pub fn queued(&self) -> usize {
        self.tx.as_ref().map_or(0, Sender::len)
    }

    /// Closes the channel and returns the accumulator once every record sent is taken (`None`
    /// when the worker died).
    pub fn finish(&mut self) -> Option<Fidelity> {
        self.tx = None;
        self.poses = None;
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

    /// Ticks without a record (failed reads, holds) keep their place: the lag is still found
    /// exactly, and the worker gives what the tick would have.
    #[test]
    fn gaps_keep_the_lag_and_the_worker_agrees() {
        let src = |t: f64| (t * 3.0).sin();
        let mut inline = Fidelity::new(1, 0.01);
        let mut worker = FidelityWorker::spawn(Fidelity::new(1, 0.01), None).unwrap();
        let mut sent = 0;
        for i in 0..600u64 {
            // Every seventh tick and a run of ten are missing; a run of 80 starts the ring over.
            if i % 7 == 3 || (200..210).contains(&i) || (400..480).contains(&i) {
                continue;
            }
            let t = i as f64 * 0.01;
            let mut r = FidelityRecord::new(i, 1);
            r.source[0] = src(t);
            r.present[0] = src(t - 0.04);
            inline.take(&r);
            // (The test does not depend on how soon the worker's thread runs.)
            while worker.queued() > WORKER_QUEUE / 2 {
                std::thread::yield_now();
            }
            worker.send(r);
            sent += 1;
        }
        let a = inline.report(&["a".into()]);
        assert!((a.lag_ms - 40.0).abs() < 1e-9, "{a:?}");
        assert!(a.rms_after_lag_deg < 1e-9, "{a:?}");
        assert_eq!(a.samples, sent);
        let b = worker.finish().unwrap().report(&["a".into()]);
        assert_eq!(worker.dropped, 0);
        assert_eq!(a, b);
    }

    /// The effectors at the present angles: the worker, given each pose once, finds what the
    /// tick finds with the pose at hand; a record whose pose never came has no effectors.
    #[test]
    fn the_worker_finds_the_effectors_from_poses_sent_once() {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
        let skel = Arc::new(
            crate::formats::asf::load(&root.join("data/cmu/16.asf"))
                .unwrap()
                .skeleton,
        );
        let profile = crate::profile::Profile::load(&root.join("firmware-profile/cmu-puppet.toml")).unwrap();
        let rig = profile.rig(Some(&skel)).unwrap();
        let watch = ["lradius", "rradius", "ltibia", "rtibia"].map(|n| skel.find(n));
        let n = rig.len();
        let pose = EffectorPose::new(Arc::clone(&skel), rig.clone(), watch, 0.0254);
        let mut inline_pose = pose.clone();
        let mut inline = Fidelity::new(n, 0.001);
        let mut worker = FidelityWorker::spawn(Fidelity::new(n, 0.001), Some(pose)).unwrap();
        let mut fk = Pose64::default();
        let mut source = SourcePose {
            seq: 0,
            channels: [0.0; MAX_CHANNELS],
            tips: [DVec3::NAN; MAX_EFFECTORS],
        };
        let mut angles = vec![0.0; n];
        for tick in 0..400u64 {
            // A new sample every eight ticks; the present lags the source by a little.
            let sample = tick / 8;
            let c = skel.channel_count();
            for (i, ch) in source.channels[..c].iter_mut().enumerate() {
                *ch = 0.3 * ((sample as f64) * 0.05 + i as f64).sin();
            }
            source.seq = sample;
            fk64(&skel, &source.channels[..c], &mut fk);
            for (t, w) in source.tips.iter_mut().zip(watch) {
                *t = fk.tip[w.unwrap()];
            }
            rig.joint_angles(&skel, &source.channels[..c], &[], &mut angles);
            let mut r = FidelityRecord::new(tick, n);
            r.source[..n].copy_from_slice(&angles);
            for (p, a) in r.present[..n].iter_mut().zip(&angles) {
                *p = a - 0.01;
            }
            // Sample 20's pose could not be sent: its records have no effectors.
            if sample != 20 {
                r.pose = Some(source.seq);
            }
            if tick % 8 == 0 && sample != 20 {
                while worker.queued() > WORKER_QUEUE / 2 {
                    std::thread::yield_now();
                }
                assert!(worker.send_pose(&source));
            }
            let mut mine = r;
            inline_pose.fill(&mut mine, &source);
            inline.take(&mine);
            worker.send(r);
        }
        let a = inline.report(&[]);
        let b = worker.finish().unwrap().report(&[]);
        assert_eq!(worker.dropped, 0);
        assert_eq!(a, b);
        assert!(a.effector_rms_mm.unwrap() > 0.1, "{a:?}");
        // Eight records without effectors, four effectors each.
        assert_eq!(inline.effector_count, (400 - 8) * 4);
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
