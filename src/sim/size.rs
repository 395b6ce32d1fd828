//! Sizing: what a clip asks of each servo of a rig, by inverse dynamics on the rig's model.
//!
//! The clip is mapped through the rig frame by frame (its capture dropouts filled), each
//! servo's joint angle low-passed without phase shift (a second-order Butterworth run forwards
//! and backwards, 6 Hz by default: Winter's cut-off for gait kinematics — above it a capture's
//! angles are mostly marker noise, which differentiation would turn into accelerations no
//! body made) and differentiated by a Savitzky–Golay fit (quadratic over seven frames:
//! `v = Σ k·x_k / 28h`, `a = Σ (k² − 4)·x_k / 42h²`), and MuJoCo's `mj_inverse` gives the torque
//! every joint needs at each frame (gravity, inertia, the motor's reflected inertia; the model's
//! own damping, which stands for the motor's back-EMF, left out; the source clamped to the
//! servo's limits, as the command stage clamps it). Contacts are not the servos' to supply, so
//! a model standing on a floor is sized as if held at its base. Each servo is then held
//! against its model's e-manual line: a DC servo gives at most `τ_stall·(1 − ω/ω₀)` at speed
//! `ω`, so the demand uses `|τ|/τ_stall + |ω|/ω₀` of it — above 1 it saturates. The profile's
//! own velocity and acceleration limits are checked against the same demand.

use serde::Serialize;

use super::mjcf::dynamics;
use super::plant::{servo_actuators, SimError};
use crate::motion::Motion;
use crate::profile::Profile;
use crate::rig::Rig;
use crate::servo::{ServoModel, MODELS};
use crate::skeleton::Skeleton;
use marionette_sim::World;

/// Largest share of the torque–speed line a servo may use and count as sized (the rest is
/// margin for what the model leaves out: friction, a heavier build, a faster take).
pub const MARGIN_SHARE: f64 = 0.8;

/// One servo's demand over the clip.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ServoDemand {
    /// The servo's name.
    pub name: String,
    /// Its model.
    pub model: String,
    /// Largest and RMS torque at the horn, N·m.
    pub peak_torque_nm: f64,
    /// RMS torque, N·m.
    pub rms_torque_nm: f64,
    /// The model's stall torque at the servo's supply, N·m.
    pub stall_torque_nm: f64,
    /// The servo's supply, volts.
    pub supply_v: f64,
    /// Largest horn speed, degrees per second.
    pub peak_speed_dps: f64,
    /// The model's no-load speed at the servo's supply, degrees per second.
    pub no_load_dps: f64,
    /// Largest joint acceleration, degrees per second².
    pub peak_acceleration_dps2: f64,
    /// Largest `|τ|/τ_stall + |ω|/ω₀` over the clip (1: on the torque–speed line).
    pub line_share: f64,
    /// Clip time of that frame, seconds.
    pub worst_at_s: f64,
    /// Frames beyond the line (share above 1).
    pub frames_beyond: usize,
    /// Whether it saturates (share above 1).
    pub saturates: bool,
    /// The profile's velocity limit, degrees per second, and whether the clip exceeds it.
    pub profile_velocity_dps: f64,
    /// The profile's acceleration limit, degrees per second².
    pub profile_acceleration_dps2: f64,
    /// Whether the clip is faster than the profile allows.
    pub exceeds_profile: bool,
    /// The first known model (lightest first) that would use at most [`MARGIN_SHARE`] of its
    /// line for the same load, if the servo does not.
    pub would_fit: Option<String>,
}

/// The clip's demand on every servo.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SizeReport {
    /// Frames evaluated.
    pub frames: usize,
    /// Per servo, profile order.
    pub servos: Vec<ServoDemand>,
}

impl SizeReport {
    /// The servos that saturate.
    #[must_use]
    pub fn saturating(&self) -> Vec<&ServoDemand> {
        self.servos.iter().filter(|s| s.saturates).collect()
    }
}

/// The share of `model`'s torque–speed line at `volts` that `torque` at `speed_rad_s` uses.
fn line_share(model: &ServoModel, volts: f64, torque: f64, speed_rad_s: f64) -> f64 {
    torque.abs() / model.stall_torque_at(volts) + speed_rad_s.abs() / model.max_speed_rad_s_at(volts)
}

/// Winter's cut-off for the kinematics of gait, Hz.
pub const DEFAULT_CUTOFF_HZ: f64 = 6.0;

/// `x` low-passed at `cutoff_hz` (sampled at `rate_hz`) without phase shift: a second-order
/// Butterworth (bilinear transform) run forwards then backwards, the ends padded by
/// reflection so that they do not ring. A cut-off at or above Nyquist leaves `x` as it is.
#[must_use]
pub fn zero_phase_low_pass(x: &[f64], cutoff_hz: f64, rate_hz: f64) -> Vec<f64> {
    let n = x.len();
    if n < 4 || !(cutoff_hz > 0.0 && cutoff_hz < rate_hz / 2.0) {
        return x.to_vec();
    }
    let k = (core::f64::consts::PI * cutoff_hz / rate_hz).tan();
    let q = core::f64::consts::SQRT_2;
    let norm = 1.0 / (1.0 + q * k + k * k);
    let (b0, b1, b2) = (k * k * norm, 2.0 * k * k * norm, k * k * norm);
    let (a1, a2) = (2.0 * (k * k - 1.0) * norm, (1.0 - q * k + k * k) * norm);
    let pad = n.min(3 * (rate_hz / cutoff_hz).ceil() as usize).min(n - 1);
    // Odd reflection about each end.
    let mut y: Vec<f64> = Vec::with_capacity(n + 2 * pad);
    y.extend((1..=pad).rev().map(|i| 2.0 * x[0] - x[i]));
    y.extend_from_slice(x);
    y.extend((1..=pad).map(|i| 2.0 * x[n - 1] - x[n - 1 - i]));
    let run = |v: &mut Vec<f64>| {
        let (mut x1, mut x2, mut y1, mut y2) = (v[0], v[0], v[0], v[0]);
        for s in v.iter_mut() {
            let x0 = *s;
            let y0 = b0 * x0 + b1 * x1 + b2 * x2 - a1 * y1 - a2 * y2;
            (x2, x1, y2, y1) = (x1, x0, y1, y0);
            *s = y0;
        }
    };
    run(&mut y);
    y.reverse();
    run(&mut y);
    y.reverse();
    y[pad..pad + n].to_vec()
}

/// Evaluates `motion` on `world` (the rig's model) for every servo of `profile`, the clip
/// low-passed at `cutoff_hz` ([`DEFAULT_CUTOFF_HZ`]; 0 or above Nyquist: as captured).
///
/// # Errors
/// [`SimError`] when a servo has no actuator in the model.
pub fn size(
    world: &mut World,
    profile: &Profile,
    rig: &Rig,
    skeleton: &Skeleton,
    motion: &Motion,
    cutoff_hz: f64,
) -> Result<SizeReport, SimError> {
    let joints = servo_actuators(world, profile)?;
    let n = motion.len();
    let h = 1.0 / motion.frame_rate;
    // Joint angles per servo per frame.
    let mut angles = vec![vec![0.0; n]; rig.len()];
    let mut frame_angles = vec![0.0; rig.len()];
    for (i, frame) in motion.frames().enumerate() {
        let channels = crate::motion::frame_to_radians(skeleton, frame);
        rig.joint_angles(skeleton, &channels, &[], &mut frame_angles);
        for (k, (a, m)) in frame_angles.iter().zip(&rig.servos).enumerate() {
            // Where the servo can go: the source clamped to its limits.
            let (lo, hi) = (
                m.ticks_to_angle(f64::from(m.min_tick)),
                m.ticks_to_angle(f64::from(m.max_tick)),
            );
            angles[k][i] = a.clamp(lo.min(hi), lo.max(hi));
        }
    }
    for a in &mut angles {
        *a = zero_phase_low_pass(a, cutoff_hz, motion.frame_rate);
    }
    // Savitzky–Golay derivatives (quadratic, seven frames; the ends use the nearest full window).
    let derive = |x: &[f64], i: usize| -> (f64, f64) {
        if x.len() < 7 {
            return (0.0, 0.0);
        }
        let c = i.clamp(3, x.len() - 4);
        let (mut v, mut a) = (0.0, 0.0);
        for k in -3i64..=3 {
            let xk = x[(c as i64 + k) as usize];
            v += k as f64 * xk;
            a += (k * k - 4) as f64 * xk;
        }
        (v / (28.0 * h), a / (42.0 * h * h))
    };
    let base_qpos = world.qpos().to_vec();
    let nv = world.dof_count();
    let mut torques = vec![vec![0.0; n]; rig.len()];
    let mut speeds = vec![vec![0.0; n]; rig.len()];
    let mut accels = vec![vec![0.0; n]; rig.len()];
    for i in 0..n {
        let mut qpos = base_qpos.clone();
        let mut qvel = vec![0.0; nv];
        let mut qacc = vec![0.0; nv];
        for (k, &(_, joint)) in joints.iter().enumerate() {
            let (v, a) = derive(&angles[k], i);
            speeds[k][i] = v;
            accels[k][i] = a;
            if let Some(d) = world.joint_dof(joint) {
                qvel[d] = v;
                qacc[d] = a;
            }
            // Hinges: one coordinate each, at the joint's qpos address (as its dof for a
            // model of hinges on a fixed stand; the floating base, if any, stays put).
            world.set_joint_position(joint, angles[k][i]);
        }
        for (q, w) in qpos.iter_mut().zip(world.qpos()) {
            *q = *w;
        }
        let load = world.load_forces(&qpos, &qvel, &qacc);
        for (k, &(_, joint)) in joints.iter().enumerate() {
            torques[k][i] = world
                .joint_dof(joint)
                .and_then(|d| load.get(d).copied())
                .unwrap_or(0.0);
        }
    }
    world.set_qpos(&base_qpos);
    let mut servos = Vec::with_capacity(rig.len());
    for (k, (spec, map)) in profile.servos.iter().zip(&rig.servos).enumerate() {
        let gear = map.gear.abs().max(1e-9);
        // At the horn: the joint's torque divided by the gear, its speed multiplied.
        let horn_torque = |i: usize| torques[k][i] / gear;
        let horn_speed = |i: usize| speeds[k][i] * gear;
        let mut worst = (0.0f64, 0usize);
        let mut beyond = 0;
        let (mut peak_t, mut sq, mut peak_w, mut peak_a) = (0.0f64, 0.0, 0.0f64, 0.0f64);
        for (i, acceleration) in accels[k].iter().enumerate() {
            let (t, w) = (horn_torque(i), horn_speed(i));
            let share = line_share(spec.model, spec.supply_v, t, w);
            if share > worst.0 {
                worst = (share, i);
            }
            beyond += usize::from(share > 1.0);
            peak_t = peak_t.max(t.abs());
            sq += t * t;
            peak_w = peak_w.max(w.abs());
            peak_a = peak_a.max(acceleration.abs());
        }
        // Another model carries the same load with its own rotor: the joint torque less this
        // model's reflected inertia times the acceleration, plus the other's (its mass left
        // as it is).
        let own = dynamics(spec.model).armature;
        let would_fit = (worst.0 > MARGIN_SHARE)
            .then(|| {
                let mut by_torque: Vec<&ServoModel> = MODELS.iter().collect();
                by_torque.sort_by(|a, b| a.stall_torque_nm.total_cmp(&b.stall_torque_nm));
                by_torque
                    .into_iter()
                    .find(|m| {
                        let other = dynamics(m).armature;
                        (0..n).all(|i| {
                            let t = (torques[k][i] + (other - own) * accels[k][i]) / gear;
                            // At the same supply, as far as the other model allows it.
                            line_share(m, spec.supply_v, t, horn_speed(i)) <= MARGIN_SHARE
                        })
                    })
                    .map(|m| m.name.to_string())
            })
            .flatten();
        let peak_speed_dps = peak_w.to_degrees();
        let peak_acceleration_dps2 = peak_a.to_degrees();
        servos.push(ServoDemand {
            name: spec.name.clone(),
            model: spec.model.name.to_string(),
            peak_torque_nm: peak_t,
            rms_torque_nm: if n > 0 { (sq / n as f64).sqrt() } else { 0.0 },
            stall_torque_nm: spec.model.stall_torque_at(spec.supply_v),
            supply_v: spec.supply_v,
            peak_speed_dps,
            no_load_dps: spec.model.max_speed_rad_s_at(spec.supply_v).to_degrees(),
            peak_acceleration_dps2,
            line_share: worst.0,
            worst_at_s: worst.1 as f64 * h,
            frames_beyond: beyond,
            saturates: worst.0 > 1.0,
            profile_velocity_dps: spec.max_velocity_dps,
            profile_acceleration_dps2: spec.max_acceleration_dps2,
            exceeds_profile: peak_speed_dps / gear > spec.max_velocity_dps
                || peak_acceleration_dps2 > spec.max_acceleration_dps2,
            would_fit,
        });
    }
    Ok(SizeReport { frames: n, servos })
}

impl std::fmt::Display for SizeReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "{:<14} {:<17} {:>14} {:>7} {:>16} {:>11} {:>6} {:>9}  verdict",
            "servo", "model", "torque peak/rms", "stall", "speed peak/no-load", "accel", "line", "worst at"
        )?;
        for s in &self.servos {
            let verdict = match (s.saturates, &s.would_fit, s.exceeds_profile) {
                (true, Some(m), _) => format!("SATURATES — {m} would not"),
                (true, None, _) => "SATURATES — no known model fits".to_string(),
                (false, Some(m), _) => format!("under {:.0} % margin — {m} has it", MARGIN_SHARE * 100.0),
                (false, None, true) => "fits; faster than the profile's limits".to_string(),
                (false, None, false) => "fits".to_string(),
            };
            writeln!(
                f,
                "{:<14} {:<17} {:>6.2}/{:<5.2}Nm {:>5.2}Nm {:>7.0}/{:<5.0}°/s {:>7.0}°/s² {:>5.0}% {:>8.2}s  {verdict}",
                s.name,
                format!("{} {}V", s.model, s.supply_v),
                s.peak_torque_nm,
                s.rms_torque_nm,
                s.stall_torque_nm,
                s.peak_speed_dps,
                s.no_load_dps,
                s.peak_acceleration_dps2,
                s.line_share * 100.0,
                s.worst_at_s
            )?;
        }
        let sat: Vec<&str> = self.saturating().iter().map(|s| s.name.as_str()).collect();
        if sat.is_empty() {
            writeln!(f, "no servo saturates over the {} frames", self.frames)
        } else {
            writeln!(f, "saturating: {}", sat.join(", "))
        }
    }
}
