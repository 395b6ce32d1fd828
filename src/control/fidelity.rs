//! End-to-end fidelity: does the rig do what the source motion did? Per servo the source angle
//! (the input of this tick mapped through the rig — what a perfect rig would do) against the
//! present position read back in the same tick: RMS, largest error, the lag that best aligns
//! the two (positive: the servos behind the source; negative: ahead of it) and the RMS after
//! that alignment; and effector positions (forward kinematics of the
//! source against that of the present angles) in millimetres at the rig's scale.
//!
//! Everything is accumulated in place: the last [`MAX_LAG_TICKS`] source and present angles in
//! rings, and per servo and candidate lag a sum of squares, so a tick allocates nothing and a run of any
//! length costs the same memory.

use glam::DVec3;
use serde::Serialize;

use crate::servo::MAX_SERVOS;

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
        let n = self.servos.min(source.len()).min(present.len());
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
            let d = (*s - *p).length();
            if d.is_finite() {
                self.effector_sse += d * d;
                self.effector_count += 1;
                self.effector_max = self.effector_max.max(d);
            }
        }
    }

    /// Forgets the ring (a seek or a loop: the next source does not follow the last).
    pub fn restart(&mut self) {
        self.filled = 0;
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
        }
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
