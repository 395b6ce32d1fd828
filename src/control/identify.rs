//! Servo identification: how a servo's horn follows its goal, measured one servo at a time
//! with small motions inside its limits — a step and a chirp (a sine sweeping up in frequency)
//! about a centre, the other servos holding where they stood.
//!
//! From the records: the lag that best aligns the present position with the goal over the
//! chirp's band of human motion (up to [`Excitation::lag_band_hz`]; least squares over
//! candidate lags, the goal interpolated between ticks), the step's
//! delay to half way, its 10–90 % rise time and overshoot, and the gain and phase against
//! frequency (a sine fitted to each stretch of the chirp) with the −3 dB bandwidth. The lag
//! written into a profile (`lag_ms`) is the servo's own: the loop's one period between writing a
//! goal and reading the position back is taken out, and added again by the look-ahead at the
//! loop's rate.

use serde::Serialize;

use crate::bus::{BusError, ServoBus};
use crate::rig::Rig;
use crate::schedule::{Clock, Schedule};
use crate::servo::MAX_SERVOS;

/// The motion a servo is put through.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Excitation {
    /// Amplitude of the step and the chirp, joint degrees.
    pub amplitude_deg: f64,
    /// Rest before, between and after the parts, seconds.
    pub settle_s: f64,
    /// Length of the step, seconds.
    pub step_s: f64,
    /// Length of the chirp, seconds.
    pub chirp_s: f64,
    /// The chirp's first and last frequency, Hz.
    pub from_hz: f64,
    /// The chirp's last frequency, Hz.
    pub to_hz: f64,
    /// The lag is fitted over the chirp up to this frequency, Hz: where captured human motion
    /// has its energy (a servo's lag grows towards its resonance, which mocap seldom reaches).
    pub lag_band_hz: f64,
}

impl Default for Excitation {
    fn default() -> Self {
        Excitation {
            amplitude_deg: 5.0,
            settle_s: 0.3,
            step_s: 0.6,
            chirp_s: 4.0,
            from_hz: 0.3,
            to_hz: 8.0,
            lag_band_hz: 3.0,
        }
    }
}

/// Seconds spent moving to the centre before the excitation and back after it.
const MOVE_S: f64 = 0.5;

impl Excitation {
    /// The whole excitation's length, seconds.
    #[must_use]
    pub fn duration_s(&self) -> f64 {
        3.0 * self.settle_s + self.step_s + self.chirp_s
    }

    fn chirp_start(&self) -> f64 {
        2.0 * self.settle_s + self.step_s
    }

    /// The chirp's phase `τ` seconds into it, radians.
    fn phase(&self, tau: f64) -> f64 {
        let rate = (self.to_hz - self.from_hz) / self.chirp_s;
        core::f64::consts::TAU * (self.from_hz * tau + 0.5 * rate * tau * tau)
    }

    /// When the chirp's phase reaches `cycles` whole turns, seconds into it.
    fn time_of_cycle(&self, cycles: f64) -> f64 {
        // f0·τ + ½·r·τ² = cycles.
        let rate = (self.to_hz - self.from_hz) / self.chirp_s;
        if rate.abs() < 1e-12 {
            return cycles / self.from_hz;
        }
        (-self.from_hz + (self.from_hz * self.from_hz + 2.0 * rate * cycles).sqrt()) / rate
    }

    /// The chirp's frequency `τ` seconds into it, Hz.
    fn frequency(&self, tau: f64) -> f64 {
        self.from_hz + (self.to_hz - self.from_hz) * tau / self.chirp_s
    }

    /// The goal's offset from the centre at `t` seconds, as a fraction of the amplitude.
    #[must_use]
    pub fn at(&self, t: f64) -> f64 {
        let s = self.settle_s;
        if t < s {
            0.0
        } else if t < s + self.step_s {
            1.0
        } else if t < self.chirp_start() {
            0.0
        } else if t < self.chirp_start() + self.chirp_s {
            self.phase(t - self.chirp_start()).sin()
        } else {
            0.0
        }
    }
}

/// One frequency of the chirp: how much of the motion arrives and how late.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct FrequencyPoint {
    /// Hz.
    pub hz: f64,
    /// Present amplitude over goal amplitude.
    pub gain: f64,
    /// Phase lag as time, ms.
    pub lag_ms: f64,
}

/// What one servo's records show.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ServoResponse {
    /// The servo's name.
    pub name: String,
    /// The lag that best aligns present with goal over the chirp's band, the loop's period
    /// taken out (what the profile's `lag_ms` holds), ms.
    pub lag_ms: f64,
    /// The same as measured, the loop's period included, ms.
    pub measured_lag_ms: f64,
    /// RMS of present − goal after that alignment, degrees.
    pub rms_after_lag_deg: f64,
    /// From the step's command to the horn half way, ms (the loop's period included).
    pub step_delay_ms: Option<f64>,
    /// 10 % to 90 % of the step, ms.
    pub rise_ms: Option<f64>,
    /// Beyond the step's end, % of the step.
    pub overshoot_pct: f64,
    /// Where the gain first falls below 1/√2, Hz (`None`: not within the chirp).
    pub bandwidth_hz: Option<f64>,
    /// Gain and lag along the chirp.
    pub frequency_response: Vec<FrequencyPoint>,
    /// The amplitude used, degrees (smaller than asked where the limits are close).
    pub amplitude_deg: f64,
}

/// Analyses one servo's records: `goal` and `present` offsets from the centre (radians), one
/// per tick at `rate_hz` from the excitation's start, the present read after the goal of the
/// same tick was written.
#[must_use]
pub fn analyse(
    name: &str,
    e: &Excitation,
    rate_hz: f64,
    amplitude: f64,
    goal: &[f64],
    present: &[f64],
) -> ServoResponse {
    let period = 1.0 / rate_hz;
    let n = goal.len().min(present.len());
    let t = |k: usize| k as f64 * period;
    let goal_at = |time: f64| -> f64 {
        let f = time / period;
        if f <= 0.0 {
            return goal.first().copied().unwrap_or(0.0);
        }
        let i = f.floor() as usize;
        if i + 1 >= n {
            return goal.get(n.saturating_sub(1)).copied().unwrap_or(0.0);
        }
        goal[i] + (f - i as f64) * (goal[i + 1] - goal[i])
    };
    // The lag over the chirp's band, by 0.5 ms steps from −20 to 300 ms.
    let (c0, c1) = (e.chirp_start(), e.chirp_start() + e.chirp_s);
    let band_end = if e.lag_band_hz > e.from_hz {
        c0 + ((e.lag_band_hz - e.from_hz) / (e.to_hz - e.from_hz) * e.chirp_s).min(e.chirp_s)
    } else {
        c1
    };
    let chirp: Vec<usize> = (0..n).filter(|&k| t(k) >= c0 + 0.3 && t(k) < band_end).collect();
    let sse = |lag: f64| -> f64 {
        chirp
            .iter()
            .map(|&k| {
                let d = present[k] - goal_at(t(k) - lag);
                d * d
            })
            .sum()
    };
    let mut best = (0.0, f64::INFINITY);
    for step in -40..=600 {
        let lag = f64::from(step) * 0.5e-3;
        let s = sse(lag);
        if s < best.1 {
            best = (lag, s);
        }
    }
    let rms_after = if chirp.is_empty() {
        f64::NAN
    } else {
        (best.1 / chirp.len() as f64).sqrt().to_degrees()
    };
    // The step.
    let (s0, s1) = (e.settle_s, e.settle_s + e.step_s);
    let step: Vec<(f64, f64)> = (0..n)
        .filter(|&k| t(k) >= s0 && t(k) < s1)
        .map(|k| (t(k) - s0, present[k]))
        .collect();
    let crossing = |level: f64| {
        step.iter()
            .find(|(_, p)| *p >= level * amplitude)
            .map(|(time, _)| *time)
    };
    let step_delay_ms = crossing(0.5).map(|x| x * 1e3);
    let rise_ms = match (crossing(0.1), crossing(0.9)) {
        (Some(a), Some(b)) => Some((b - a) * 1e3),
        _ => None,
    };
    let peak = step.iter().map(|(_, p)| *p).fold(f64::NEG_INFINITY, f64::max);
    let overshoot_pct = if amplitude > 0.0 {
        ((peak - amplitude) / amplitude * 100.0).max(0.0)
    } else {
        0.0
    };
    // Gain and phase over each whole cycle of the chirp.
    let mut frequency_response = Vec::new();
    let cycles = e.phase(e.chirp_s) / core::f64::consts::TAU;
    for w in 0..cycles.floor() as usize {
        let (a, b) = (e.time_of_cycle(w as f64), e.time_of_cycle(w as f64 + 1.0));
        let ks: Vec<usize> = (0..n).filter(|&k| t(k) - c0 >= a && t(k) - c0 < b).collect();
        if ks.len() < 8 {
            continue;
        }
        // present ≈ p·sin φ + q·cos φ + r (least squares, 3×3 normal equations).
        let mut m = [[0.0f64; 3]; 3];
        let mut v = [0.0f64; 3];
        for &k in &ks {
            let phi = e.phase(t(k) - c0);
            let row = [phi.sin(), phi.cos(), 1.0];
            for i in 0..3 {
                for j in 0..3 {
                    m[i][j] += row[i] * row[j];
                }
                v[i] += row[i] * present[k];
            }
        }
        let Some([p, q, _]) = solve3(m, v) else { continue };
        let hz = e.frequency(0.5 * (a + b));
        let theta = (-q).atan2(p);
        frequency_response.push(FrequencyPoint {
            hz,
            gain: p.hypot(q) / amplitude,
            lag_ms: theta / (core::f64::consts::TAU * hz) * 1e3,
        });
    }
    let bandwidth_hz = frequency_response.windows(2).find_map(|w| {
        let (x, y) = (w[0], w[1]);
        let cut = core::f64::consts::FRAC_1_SQRT_2;
        (x.gain >= cut && y.gain < cut).then(|| x.hz + (x.gain - cut) / (x.gain - y.gain) * (y.hz - x.hz))
    });
    ServoResponse {
        name: name.to_string(),
        lag_ms: ((best.0 - period) * 1e3).max(0.0),
        measured_lag_ms: best.0 * 1e3,
        rms_after_lag_deg: rms_after,
        step_delay_ms,
        rise_ms,
        overshoot_pct,
        bandwidth_hz,
        frequency_response,
        amplitude_deg: amplitude.to_degrees(),
    }
}

/// Solves a 3×3 system by Cramer's rule (`None` when singular).
fn solve3(m: [[f64; 3]; 3], v: [f64; 3]) -> Option<[f64; 3]> {
    let det = |a: [[f64; 3]; 3]| {
        a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1]) - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
            + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0])
    };
    let d = det(m);
    if d.abs() < 1e-12 {
        return None;
    }
    let mut out = [0.0; 3];
    for (c, o) in out.iter_mut().enumerate() {
        let mut a = m;
        for r in 0..3 {
            a[r][c] = v[r];
        }
        *o = det(a) / d;
    }
    Some(out)
}

/// Why identification stopped.
#[derive(Debug, thiserror::Error)]
pub enum IdentifyError {
    /// The bus failed (a write, or reads for longer than the hold-off).
    #[error("servo `{servo}`: {error}")]
    Bus {
        /// The servo being identified.
        servo: String,
        /// What failed.
        error: BusError,
    },
    /// The host fell behind the schedule while a servo was put through its motion: the
    /// record would pair goals and reads a stall apart (and a stall past the Bus Watchdog
    /// stops the servos).
    #[error(
        "servo `{servo}`: the host fell {skipped} ticks ({late_ms:.0} ms) behind the {rate_hz} Hz schedule during its motion, so its record would be wrong; torque is off — run again on a quieter machine, or at a lower --rate"
    )]
    FellBehind {
        /// The servo being identified.
        servo: String,
        /// Deadlines passed over.
        skipped: u64,
        /// How late the tick was, ms.
        late_ms: f64,
        /// The loop's rate, Hz.
        rate_hz: f64,
    },
    /// A servo reported a hardware error (overload, overheating) and shut its torque off:
    /// the record would show it limp.
    #[error(
        "servo `{servo}` (id {id}) reported hardware error {} while `{during}` was identified, and shut its torque off; torque is off on every servo — remove the cause, then `marionette doctor PROFILE --fix` reboots it",
        crate::bus::hardware_error_names(*.bits)
    )]
    HardwareError {
        /// The servo that reported it.
        servo: String,
        /// Its id.
        id: u8,
        /// Its Hardware Error Status (0 when it could not be read).
        bits: u8,
        /// The servo being identified.
        during: String,
    },
}

/// Reads that may fail in a row before identification gives up (torque is turned off).
const MAX_FAILED_READS: u32 = 10;

/// Puts each servo in `which` through the excitation on `bus` at `rate_hz` (ticks on
/// `clock`), the others holding the positions in `present`: moved to a centre inside the
/// limits, excited, moved back. Goals never leave the servo's limits. On a failure (the bus's,
/// or a tick passed over while a servo moves) torque goes off and the error is returned.
///
/// # Errors
/// [`IdentifyError`].
#[allow(clippy::too_many_arguments)]
pub fn identify(
    bus: &mut dyn ServoBus,
    clock: &mut dyn Clock,
    rig: &Rig,
    ids: &[u8],
    names: &[String],
    present: &[i32],
    which: &[usize],
    e: &Excitation,
    rate_hz: f64,
) -> Result<Vec<ServoResponse>, IdentifyError> {
    let n = rig.len().min(MAX_SERVOS);
    let period_ns = (1e9 / rate_hz).round() as u64;
    let mut goals: Vec<i32> = present[..n].to_vec();
    let mut read = vec![0i32; n];
    let mut schedule = Schedule::new(clock.now_ns() + period_ns, period_ns);
    let mut out = Vec::new();
    for &k in which {
        let servo = &rig.servos[k];
        let name = names.get(k).cloned().unwrap_or_default();
        let fail = |error: BusError, bus: &mut dyn ServoBus| {
            let _ = super::torque_off(bus, ids);
            IdentifyError::Bus {
                servo: name.clone(),
                error,
            }
        };
        // The centre: where it stands, moved inwards so the motion stays 2° inside the limits.
        let per_rad = servo.ticks_per_radian().abs();
        let margin = 2f64.to_radians() * per_rad;
        let (lo, hi) = (f64::from(servo.min_tick), f64::from(servo.max_tick));
        let room = ((hi - lo) / 2.0 - margin).max(0.0);
        let amplitude_ticks = (e.amplitude_deg.to_radians() * per_rad).min(room);
        let start = f64::from(goals[k]);
        let centre = start.clamp(lo + margin + amplitude_ticks, hi - margin - amplitude_ticks);
        let sign = servo.direction.signum();
        let move_ticks = (MOVE_S * rate_hz).round() as usize;
        let excite_ticks = (e.duration_s() * rate_hz).round() as usize;
        let mut goal_rec = Vec::with_capacity(excite_ticks);
        let mut present_rec = Vec::with_capacity(excite_ticks);
        let mut failed = 0u32;
        let total = 2 * move_ticks + excite_ticks;
        for step in 0..total {
            let target = if step < move_ticks {
                let w = crate::interp::ease_weight(step + 1, move_ticks + 1);
                start + w * (centre - start)
            } else if step < move_ticks + excite_ticks {
                let time = (step - move_ticks) as f64 / rate_hz;
                centre + sign * amplitude_ticks * e.at(time)
            } else {
                let w = crate::interp::ease_weight(step - move_ticks - excite_ticks + 1, move_ticks + 1);
                centre + w * (start - centre)
            };
            goals[k] = (target.round() as i32).clamp(servo.min_tick, servo.max_tick);
            let tick = schedule.wait(clock);
            if tick.skipped > 0 {
                let _ = super::torque_off(bus, ids);
                return Err(IdentifyError::FellBehind {
                    servo: name,
                    skipped: tick.skipped,
                    late_ms: (tick.skipped * period_ns + tick.lateness_ns()) as f64 * 1e-6,
                    rate_hz,
                });
            }
            if let Err(error) = bus.write_goals(&ids[..n], &goals) {
                return Err(fail(error, bus));
            }
            match bus.read_positions(&ids[..n], &mut read) {
                Ok(()) => failed = 0,
                Err(error) => {
                    failed += 1;
                    if failed > MAX_FAILED_READS || error.port_failure().is_some() {
                        return Err(fail(error, bus));
                    }
                }
            }
            if let Some(id) = bus.take_alert() {
                // A servo that shut itself down: what it says, then every torque off.
                let bits = bus.hardware_error(id).unwrap_or(0);
                let _ = super::torque_off(bus, ids);
                return Err(IdentifyError::HardwareError {
                    servo: ids
                        .iter()
                        .position(|&i| i == id)
                        .and_then(|j| names.get(j).cloned())
                        .unwrap_or_default(),
                    id,
                    bits,
                    during: name,
                });
            }
            if (move_ticks..move_ticks + excite_ticks).contains(&step) {
                let to_angle = |ticks: f64| (ticks - centre) / per_rad * sign;
                goal_rec.push(to_angle(f64::from(goals[k])));
                present_rec.push(if failed == 0 {
                    to_angle(f64::from(read[k]))
                } else {
                    f64::NAN
                });
            }
        }
        // Gaps (failed reads) take the previous value.
        for i in 1..present_rec.len() {
            if !present_rec[i].is_finite() {
                present_rec[i] = present_rec[i - 1];
            }
        }
        out.push(analyse(
            &name,
            e,
            rate_hz,
            amplitude_ticks / per_rad,
            &goal_rec,
            &present_rec,
        ));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A horn that follows its goal through a first-order lag of 20 ms and one period of
    /// reading: the lag comes out near the model's, the step and the bandwidth too.
    #[test]
    fn a_first_order_servo_is_identified() {
        let e = Excitation::default();
        let rate = 500.0;
        let dt = 1.0 / rate;
        let tau = 0.02;
        let n = (e.duration_s() * rate) as usize;
        let amplitude = 5f64.to_radians();
        let goal: Vec<f64> = (0..n).map(|k| amplitude * e.at(k as f64 * dt)).collect();
        let mut present = vec![0.0; n];
        let mut x = 0.0;
        for k in 1..n {
            // The read at tick k sees the goal of tick k − 1 followed for one period.
            x += (goal[k - 1] - x) * (1.0 - (-dt / tau).exp());
            present[k] = x;
        }
        let r = analyse("s", &e, rate, amplitude, &goal, &present);
        // A first-order lag's delay at low frequency is τ (a little less up to 3 Hz).
        assert!((r.lag_ms - 19.0).abs() < 3.0, "{r:?}");
        // Its −3 dB bandwidth is 1/(2πτ) = 8 Hz: at the chirp's top the gain is near 0.7.
        let last = r.frequency_response.last().unwrap();
        assert!(last.gain > 0.6 && last.gain < 0.8, "{last:?}");
        let first = r.frequency_response[0];
        assert!((first.gain - 1.0).abs() < 0.05, "{first:?}");
        // Half way after τ·ln 2 (+ one period), 10–90 % in τ·ln 9.
        let half = r.step_delay_ms.unwrap();
        assert!((half - (tau * 2f64.ln() + dt) * 1e3).abs() < 2.5, "{half}");
        assert!((r.rise_ms.unwrap() - tau * 9f64.ln() * 1e3).abs() < 2.5, "{r:?}");
        assert!(r.overshoot_pct < 0.5);
    }
}
