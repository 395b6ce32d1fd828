//! The command stage: the last gate between angles and the bus.
//!
//! Per tick it rejects a command holding any NaN or infinity (the whole command: a rig must
//! not move half its joints), clamps to the software position limits, limits velocity and
//! acceleration per servo (braking early enough to stop at the target), and remembers what it
//! sent. Positions are kept in fractional ticks so slow motions are not lost to rounding.
//!
//! A correction ([`CommandStage::set_correction`], e.g. feedback from an IMU) rides on the
//! goals sent without entering the path the stage keeps: a planner that continues from the
//! stage's state ([`CommandStage::state`]) does not take it for motion to go on with. What is
//! sent, path and correction together, still keeps within the position and velocity limits.

use crate::math::{real, Real};
use crate::rig::Rig;
use crate::servo::{step_along, step_towards, MotionLimits, MAX_SERVOS};

/// Why a command was refused. Nothing is sent; the last command stands.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum CommandError {
    /// The angle of servo index `servo` was NaN or infinite.
    NotFinite {
        /// Index of the servo in the rig.
        servo: usize,
    },
    /// The command has a different number of servos than the rig.
    WrongLength {
        /// Servos in the command.
        got: usize,
        /// Servos in the rig.
        want: usize,
    },
    /// The time step was not a positive finite number.
    BadTimeStep,
}

impl core::fmt::Display for CommandError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            CommandError::NotFinite { servo } => write!(f, "servo #{servo}: angle is not a finite number"),
            CommandError::WrongLength { got, want } => write!(f, "command has {got} servos, rig has {want}"),
            CommandError::BadTimeStep => f.write_str("time step is not a positive finite number"),
        }
    }
}

impl core::error::Error for CommandError {}

/// What the stage changed in one accepted command.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Limited {
    /// Servos whose target lay outside their position limits.
    pub clamped: usize,
    /// Servos slowed by the velocity or acceleration limit.
    pub rate_limited: usize,
}

/// The command stage of one rig.
#[derive(Clone, Debug)]
pub struct CommandStage {
    position: [Real; MAX_SERVOS],
    velocity: [Real; MAX_SERVOS],
    ticks: [i32; MAX_SERVOS],
    /// The correction asked for, fractional ticks.
    correction: [Real; MAX_SERVOS],
    /// The part of it sent with the last command (within the limits), fractional ticks.
    applied: [Real; MAX_SERVOS],
    len: usize,
    started: bool,
}

impl CommandStage {
    /// A stage for `servos` servos with no command yet.
    #[must_use]
    pub fn new(servos: usize) -> CommandStage {
        CommandStage {
            position: [0.0; MAX_SERVOS],
            velocity: [0.0; MAX_SERVOS],
            ticks: [0; MAX_SERVOS],
            correction: [0.0; MAX_SERVOS],
            applied: [0.0; MAX_SERVOS],
            len: servos.min(MAX_SERVOS),
            started: false,
        }
    }

    /// Starts from where the servos are (present positions, at rest), e.g. at torque-on, so the
    /// first command moves from there within the limits.
    pub fn start_from(&mut self, rig: &Rig, present: &[i32]) {
        for (k, servo) in rig.servos.iter().enumerate().take(self.len) {
            let p = present
                .get(k)
                .copied()
                .unwrap_or(servo.min_tick)
                .clamp(servo.min_tick, servo.max_tick);
            self.position[k] = p as Real;
            self.velocity[k] = 0.0;
            self.ticks[k] = p;
            self.applied[k] = 0.0;
        }
        self.started = true;
    }

    /// Sets the correction added to the goals from the next command on, fractional ticks per
    /// servo (missing or non-finite values: none). It is not part of the path
    /// ([`CommandStage::state`]); the goal sent is the path plus as much of it as the position
    /// limits and the velocity limit (against the goal sent before) allow.
    pub fn set_correction(&mut self, ticks: &[Real]) {
        for (k, c) in self.correction.iter_mut().enumerate().take(self.len) {
            *c = ticks.get(k).copied().filter(|t| t.is_finite()).unwrap_or(0.0);
        }
    }

    /// The correction sent with the last command (within the limits), fractional ticks.
    #[must_use]
    pub fn applied_correction(&self) -> &[Real] {
        &self.applied[..self.len]
    }

    /// The last command sent, in ticks (empty before the first).
    #[must_use]
    pub fn last(&self) -> &[i32] {
        if self.started {
            &self.ticks[..self.len]
        } else {
            &[]
        }
    }

    /// Where servo `k`'s command stands: position (fractional ticks) and velocity (ticks/s);
    /// `None` before the first command or past the rig.
    #[must_use]
    pub fn state(&self, k: usize) -> Option<(Real, Real)> {
        (self.started && k < self.len).then(|| (self.position[k], self.velocity[k]))
    }

    /// The next goal positions along planned paths: `targets` (fractional ticks, e.g. from
    /// [`crate::plan`]) are points of paths that go on, so the stage limits velocity and
    /// acceleration without braking towards them (it still brakes for the position limits),
    /// `dt` seconds after the previous command. Before any start the first command is only
    /// clamped.
    ///
    /// # Errors
    /// [`CommandError`]: the command is refused as a whole and the last one stands.
    pub fn command_planned(
        &mut self,
        rig: &Rig,
        targets: &[Real],
        dt: Real,
    ) -> Result<(&[i32], Limited), CommandError> {
        self.advance(rig, targets, dt, Goal::PlannedTicks)
    }

    /// Turns joint angles (radians) into the next goal positions, `dt` seconds after the
    /// previous command. Before any start the first command is only clamped.
    ///
    /// # Errors
    /// [`CommandError`]: the command is refused as a whole and the last one stands.
    pub fn command(
        &mut self,
        rig: &Rig,
        angles: &[Real],
        dt: Real,
    ) -> Result<(&[i32], Limited), CommandError> {
        self.advance(rig, angles, dt, Goal::Angles)
    }

    /// One command: checked whole, each servo's goal clamped to its limits, then stepped
    /// towards it within its velocity and acceleration (as `goal` says how), rounded to ticks.
    fn advance(
        &mut self,
        rig: &Rig,
        inputs: &[Real],
        dt: Real,
        goal: Goal,
    ) -> Result<(&[i32], Limited), CommandError> {
        if inputs.len() != rig.len() || rig.len() != self.len {
            return Err(CommandError::WrongLength {
                got: inputs.len(),
                want: rig.len(),
            });
        }
        if !(dt.is_finite() && dt > 0.0) {
            return Err(CommandError::BadTimeStep);
        }
        if let Some(servo) = inputs.iter().position(|a| !a.is_finite()) {
            return Err(CommandError::NotFinite { servo });
        }
        let mut limited = Limited::default();
        for (k, (servo, &input)) in rig.servos.iter().zip(inputs).enumerate() {
            let (lo, hi) = ((servo.min_tick as Real), (servo.max_tick as Real));
            let wanted = match goal {
                Goal::Angles => servo.angle_to_ticks_exact(input),
                Goal::PlannedTicks => input,
            };
            let target = real::clamp(wanted, lo, hi);
            if target != wanted {
                limited.clamped += 1;
            }
            let sent_before = self.position[k] + self.applied[k];
            if !self.started {
                self.position[k] = target;
                self.velocity[k] = 0.0;
                self.applied[k] = 0.0;
                continue;
            }
            let (p, v) = match goal {
                Goal::Angles => step_towards(
                    self.position[k],
                    self.velocity[k],
                    target,
                    servo.max_velocity,
                    servo.max_acceleration,
                    dt,
                ),
                Goal::PlannedTicks => {
                    let limits = MotionLimits {
                        velocity: servo.max_velocity,
                        acceleration: servo.max_acceleration,
                        min: lo,
                        max: hi,
                    };
                    step_along(self.position[k], self.velocity[k], target, dt, &limits)
                }
            };
            if (p - target).abs() > 1e-9 {
                limited.rate_limited += 1;
            }
            // A planned step keeps within the limits itself (it brakes for them).
            self.position[k] = match goal {
                Goal::Angles => real::clamp(p, lo, hi),
                Goal::PlannedTicks => p,
            };
            self.velocity[k] = v;
            let wanted = self.correction[k];
            if wanted != 0.0 || self.applied[k] != 0.0 {
                // The path plus the correction, no faster than the servo against the goal sent
                // before, inside the position limits.
                let mut sent = self.position[k] + wanted;
                let step = servo.max_velocity * dt;
                if step.is_finite() && step > 0.0 {
                    sent = real::clamp(sent, sent_before - step, sent_before + step);
                }
                sent = real::clamp(sent, lo, hi);
                self.applied[k] = sent - self.position[k];
            }
        }
        self.started = true;
        for k in 0..self.len {
            self.ticks[k] = real::round(self.position[k] + self.applied[k]) as i32;
        }
        Ok((&self.ticks[..self.len], limited))
    }
}

/// What a command's inputs are and how the stage moves towards them.
#[derive(Clone, Copy)]
enum Goal {
    /// Joint angles (radians), each a target to stop at: braking towards it.
    Angles,
    /// Fractional ticks, points of planned paths: no braking towards them.
    PlannedTicks,
}
