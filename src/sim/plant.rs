//! Simulated servos: a virtual chain whose horns are moved by MuJoCo.
//!
//! The chain keeps what a servo's firmware does (control table, torque, watchdog, status
//! packets); each physics step the plant turns every servo's goal tick into its position
//! actuator's control (through the rig's tick↔angle map), steps, and hands the hinge angle and
//! velocity back as Present Position and Present Velocity. A limp servo (torque off) gets no
//! actuator force. Time is whatever the transport lets pass — virtual in lockstep
//! ([`SimBus`]), the wall clock on a pseudo-terminal.

use std::path::Path;

use marionette_sim::World;

use crate::bus::virtual_chain::{chain_for, Plant, VirtualRig};
use crate::device::{Chain, VirtualServo};
use crate::profile::Profile;
use crate::retarget::{convex_hull, polygon_margin};
use crate::rig::{Rig, ServoMap};
use crate::sensor_board::ImuReading;
use crate::servo::TICKS_PER_TURN;
use glam::DVec2;

/// Most physics samples kept by a recorder (an hour at 1 kHz would be too many to plot).
const MAX_SAMPLES: usize = 2_000_000;

/// One profiled servo in the simulated model.
#[derive(Clone, Debug)]
struct SimServo {
    actuator: usize,
    joint: usize,
    map: ServoMap,
    force_limit: f64,
    /// The model's gain, which stands for the servo's factory Position P Gain.
    base_kp: f64,
    /// The Position P Gain the actuator was last set for.
    p_gain: u16,
}

/// Why a model does not fit a profile.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    /// MuJoCo refused the model.
    #[error("MuJoCo: {0}")]
    Load(#[from] marionette_sim::LoadError),
    /// A servo has no actuator in the model.
    #[error("servo {id} (`{name}`) has no actuator in the model (looked for an actuator named `{name}`{joint}); the model's actuators: {known}")]
    NoActuator {
        /// Id.
        id: u8,
        /// Servo name.
        name: String,
        /// `, or one driving joint …` when the servo follows a joint.
        joint: String,
        /// The actuators the model has.
        known: String,
    },
    /// An actuator does not drive a joint directly.
    #[error("actuator `{0}` does not drive a joint (tendon and site transmissions are not servos)")]
    NotAJoint(String),
    /// The puppet model could not be generated.
    #[error(transparent)]
    Puppet(#[from] super::mjcf::MjcfError),
    /// A model file could not be read or MuJoCo refused it.
    #[error(transparent)]
    ModelFile(marionette_sim::LoadError),
    /// MuJoCo refused the generated puppet.
    #[error("the generated model: {0}")]
    Generated(marionette_sim::LoadError),
    /// Neither a model file nor a skeleton to generate one from.
    #[error("a model is needed: give an MJCF file (--model) or an ASF skeleton to generate one")]
    NoModel,
}

/// What was recorded at one physics sample.
#[derive(Clone, Debug, Default)]
pub struct Sample {
    /// Simulated time, seconds.
    pub time: f64,
    /// Per servo: the commanded angle (the goal register), radians; NaN while limp.
    pub commanded: Vec<f64>,
    /// Per servo: the simulated hinge angle, radians.
    pub simulated: Vec<f64>,
    /// Per servo: the actuator torque, N·m.
    pub torque: Vec<f64>,
    /// Per effector site: distance between the simulated site and the site at the commanded
    /// angles, metres.
    pub effector_error: Vec<f64>,
    /// Per site: where it is in the simulated world, metres.
    pub site_pos: Vec<[f64; 3]>,
    /// A floating base's position and tilt, when the model has one.
    pub torso: Option<Torso>,
}

/// A push of the torso: a horizontal impulse spread over [`PUSH_S`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Push {
    /// When it starts, simulated seconds.
    pub at_s: f64,
    /// The impulse, N·s.
    pub impulse_ns: f64,
    /// Its direction on the floor, degrees from +x towards +y (0: forward on the OP3).
    pub direction_deg: f64,
}

/// How long a push lasts, s: a shove, short against the robot's own motion.
pub const PUSH_S: f64 = 0.1;

impl Push {
    /// Its force while it lasts, N (world frame).
    #[must_use]
    pub fn force(&self) -> [f64; 3] {
        let (s, c) = self.direction_deg.to_radians().sin_cos();
        let f = self.impulse_ns / PUSH_S;
        [f * c, f * s, 0.0]
    }
}

/// Where a floating base is, and what holds it up.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Torso {
    /// Position in the world, metres (z up).
    pub pos: [f64; 3],
    /// Tilt from upright, degrees.
    pub tilt_deg: f64,
    /// The whole model's centre of mass, metres.
    pub com: [f64; 3],
    /// The centre of pressure of the floor's contact forces (the measured ZMP on flat
    /// ground), metres; `None` in the air.
    pub pressure_centre: Option<[f64; 2]>,
    /// Signed distance of that centre inside the convex hull of the floor contacts, metres
    /// (0 on its edge: about to tip; `None` with fewer than three contacts in a line or none).
    pub pressure_margin: Option<f64>,
    /// Vertical floor force, newtons.
    pub floor_force: f64,
}

/// Contacts lower than this are the floor's (metres).
pub const FLOOR_CONTACT_M: f64 = 0.01;

/// Most floor contacts a centre of pressure's margin is taken over.
const MAX_FLOOR_CONTACTS: usize = 64;

/// The centre of pressure of `contacts` (position, vertical force) and its signed distance
/// inside their convex hull (`None` with fewer than three contacts off one line).
#[must_use]
pub fn pressure(contacts: &[([f64; 3], f64)]) -> (Option<[f64; 2]>, Option<f64>, f64) {
    let force: f64 = contacts.iter().map(|c| c.1).sum();
    if force <= 1e-9 {
        return (None, None, force);
    }
    let centre = contacts
        .iter()
        .fold(DVec2::ZERO, |a, (p, f)| a + DVec2::new(p[0], p[1]) * *f)
        / force;
    let points: Vec<DVec2> = contacts.iter().map(|(p, _)| DVec2::new(p[0], p[1])).collect();
    let hull = convex_hull::<MAX_FLOOR_CONTACTS>(&points);
    let margin = polygon_margin(&hull, centre, 0.0).0;
    (
        Some(centre.to_array()),
        margin.is_finite().then_some(margin),
        force,
    )
}

/// The MuJoCo plant of a chain.
pub struct SimPlant {
    world: World,
    /// A copy for kinematics at the commanded angles (effector error).
    twin: World,
    servos: Vec<SimServo>,
    sites: Vec<usize>,
    /// Time let pass but not yet stepped, seconds.
    pending: f64,
    steps: u64,
    saturated: Vec<u64>,
    /// Physics steps × servos at the torque limit in the first second of recording.
    saturated_first_s: u64,
    /// Simulated time recording first started.
    recording_since: Option<f64>,
    record_every: u64,
    recording: bool,
    /// A push of the torso, if one is given.
    push: Option<Push>,
    samples: Vec<Sample>,
    /// The model's IMU (`imu_gyro`, `imu_acc`) and the body it rides on, for a chain's sensor
    /// board.
    imu: Option<(usize, usize, usize)>,
    /// What the IMU's reading is made worse by, if anything.
    imu_errors: Option<ImuErrors>,
    /// No torque has been on yet: the world stands still.
    held: bool,
}

impl std::fmt::Debug for SimPlant {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SimPlant")
            .field("world", &self.world)
            .field("servos", &self.servos.len())
            .field("steps", &self.steps)
            .finish_non_exhaustive()
    }
}

/// Each profiled servo's actuator and the joint it drives: the actuator named as the servo,
/// else (a joint-driven servo) the actuator that drives the joint of that name.
///
/// # Errors
/// [`SimError`] for a servo without an actuator.
pub fn servo_actuators(world: &World, profile: &Profile) -> Result<Vec<(usize, usize)>, SimError> {
    let mut out = Vec::with_capacity(profile.servos.len());
    for spec in &profile.servos {
        let joint_name = match &spec.drive {
            crate::profile::Drive::Joint(j) => Some(j.as_str()),
            crate::profile::Drive::Bone { .. } => None,
        };
        let by_joint = || {
            let j = world.joint(joint_name?)?;
            (0..world.actuator_count()).find(|a| world.actuator_joint(*a) == Some(j))
        };
        let Some(actuator) = world.actuator(&spec.name).or_else(by_joint) else {
            let known: Vec<&str> = (0..world.actuator_count())
                .filter_map(|a| world.actuator_name(a))
                .collect();
            return Err(SimError::NoActuator {
                id: spec.id,
                name: spec.name.clone(),
                joint: joint_name.map_or(String::new(), |j| format!(", or one driving joint `{j}`")),
                known: known.join(" "),
            });
        };
        let joint = world
            .actuator_joint(actuator)
            .ok_or_else(|| SimError::NotAJoint(world.actuator_name(actuator).unwrap_or("?").into()))?;
        out.push((actuator, joint));
    }
    Ok(out)
}

impl SimPlant {
    /// Maps each profiled servo to its actuator ([`servo_actuators`]).
    ///
    /// # Errors
    /// [`SimError`] for a servo without an actuator.
    pub fn new(world: World, profile: &Profile, rig: &Rig) -> Result<SimPlant, SimError> {
        let mut servos = Vec::with_capacity(profile.servos.len());
        let driven = servo_actuators(&world, profile)?;
        for ((spec, map), (actuator, joint)) in profile.servos.iter().zip(&rig.servos).zip(driven) {
            let force_limit = world
                .force_range(actuator)
                .map_or(f64::INFINITY, |(lo, hi)| lo.abs().min(hi.abs()));
            servos.push(SimServo {
                actuator,
                joint,
                map: *map,
                force_limit,
                base_kp: world.position_gain(actuator),
                p_gain: spec.model.position_p_gain,
            });
        }
        let sites = (0..world.site_count()).collect();
        let record_every = ((0.001 / world.timestep()).round() as u64).max(1);
        let n = servos.len();
        let imu = match (
            world.sensor("imu_gyro"),
            world.sensor("imu_acc"),
            world.free_body(),
        ) {
            (Some(g), Some(a), Some(b)) => Some((g, a, b)),
            _ => None,
        };
        Ok(SimPlant {
            twin: world.clone(),
            world,
            servos,
            sites,
            pending: 0.0,
            steps: 0,
            saturated: vec![0; n],
            saturated_first_s: 0,
            recording_since: None,
            record_every,
            recording: false,
            samples: Vec::new(),
            imu,
            imu_errors: None,
            held: true,
            push: None,
        })
    }

    /// Makes every simulated servo unlike its profile, as a rig's servos may be: `lag_scale`
    /// times the joint damping (the gear train's viscous loss, which with the position gain
    /// sets how fast the horn follows: 1.5 is 50 % slower) and `torque_scale` times the
    /// actuator's force limits (0.8: a servo 20 % weaker). 1 and 1 leave the model as it is.
    pub fn vary_servos(&mut self, lag_scale: f64, torque_scale: f64) {
        for s in &mut self.servos {
            if let Some(dof) = self.world.joint_dof(s.joint) {
                let damping = self.world.dof_damping(dof);
                self.world.set_dof_damping(dof, damping * lag_scale);
            }
            if let Some((lo, hi)) = self.world.force_range(s.actuator) {
                self.world
                    .set_force_range(s.actuator, lo * torque_scale, hi * torque_scale);
                s.force_limit = lo.abs().min(hi.abs()) * torque_scale;
            }
        }
    }

    /// Gives the model's IMU `errors` (none: the exact reading).
    pub fn set_imu_errors(&mut self, errors: Option<ImuErrors>) {
        self.imu_errors = errors;
    }

    /// The servos' present ticks in the model's present state (for powering the chain up).
    #[must_use]
    pub fn present_ticks(&self) -> Vec<i32> {
        self.servos
            .iter()
            .map(|s| s.map.angle_to_ticks(self.world.joint_position(s.joint)))
            .collect()
    }

    /// Places every servo's hinge at a joint angle (radians), at rest, before a run.
    pub fn set_angles(&mut self, angles: &[f64]) {
        for (s, a) in self.servos.iter().zip(angles) {
            self.world.set_joint_position(s.joint, *a);
            self.world.set_ctrl(s.actuator, *a);
        }
        self.world.forward();
    }

    /// Starts (or stops) recording a sample every millisecond of simulated time.
    pub fn record(&mut self, on: bool) {
        self.recording = on;
        if on && self.recording_since.is_none() {
            self.recording_since = Some(self.world.time());
        }
    }

    /// Physics steps × servos at the torque limit in the first second after recording started
    /// (the move to a clip's first pose, and its start).
    #[must_use]
    pub fn saturated_first_second(&self) -> u64 {
        self.saturated_first_s
    }

    /// The samples recorded so far.
    #[must_use]
    pub fn samples(&self) -> &[Sample] {
        &self.samples
    }

    /// Physics steps taken.
    #[must_use]
    pub fn steps(&self) -> u64 {
        self.steps
    }

    /// Per servo: physics steps during which the actuator was at its torque limit.
    #[must_use]
    pub fn saturated_steps(&self) -> &[u64] {
        &self.saturated
    }

    /// The effector sites' names (for reports).
    #[must_use]
    pub fn site_names(&self) -> Vec<String> {
        self.sites
            .iter()
            .map(|s| self.world.site_name(*s).unwrap_or("?").to_string())
            .collect()
    }

    /// The simulated world.
    #[must_use]
    pub fn world(&self) -> &World {
        &self.world
    }

    /// Pushes the floating base (its torso) with `push` (none when the model has no floating
    /// base).
    pub fn set_push(&mut self, push: Option<Push>) {
        self.push = push;
    }

    /// One physics step with the chain's present goals. A written Position P Gain scales the
    /// actuator's gain (the firmware's `K_P = gain / 128` is linear in it).
    fn step_physics(&mut self, chain: &mut Chain) {
        let h = self.world.timestep();
        for (s, servo) in self.servos.iter_mut().zip(chain.servos_mut()) {
            let gain = servo.position_p_gain();
            if gain != s.p_gain {
                s.p_gain = gain;
                let factory = f64::from(servo.model().position_p_gain.max(1));
                self.world
                    .set_position_gain(s.actuator, s.base_kp * f64::from(gain) / factory);
            }
            // The firmware's motion profile (Profile Velocity/Acceleration) between the goal
            // and the motor, as on the servo.
            let ctrl = match servo.profile_target(h) {
                Some(target) => s.map.ticks_to_angle(target),
                // Limp: the actuator's spring is relaxed where the joint is.
                None => self.world.joint_position(s.joint),
            };
            self.world.set_ctrl(s.actuator, ctrl);
        }
        if let (Some(p), Some(body)) = (self.push, self.world.free_body()) {
            let t = self.world.time();
            let on = t >= p.at_s && t < p.at_s + PUSH_S;
            self.world
                .set_body_force(body, if on { p.force() } else { [0.0; 3] });
        }
        self.world.step();
        self.steps += 1;
        for (k, s) in self.servos.iter().enumerate() {
            if self.world.actuator_force(s.actuator).abs() >= s.force_limit * 0.999 {
                self.saturated[k] += 1;
                if self
                    .recording_since
                    .is_some_and(|t0| self.world.time() - t0 < 1.0)
                {
                    self.saturated_first_s += 1;
                }
            }
        }
        if self.recording && self.steps % self.record_every == 0 && self.samples.len() < MAX_SAMPLES {
            self.sample(chain);
        }
    }

    fn sample(&mut self, chain: &Chain) {
        let mut s = Sample {
            time: self.world.time(),
            ..Sample::default()
        };
        self.twin.set_qpos(self.world.qpos());
        for (servo, sim) in chain.servos().iter().zip(&self.servos) {
            let q = self.world.joint_position(sim.joint);
            let cmd = servo
                .drive_goal()
                .map_or(f64::NAN, |g| sim.map.ticks_to_angle(f64::from(g)));
            s.commanded.push(cmd);
            s.simulated.push(q);
            s.torque.push(self.world.actuator_force(sim.actuator));
            self.twin
                .set_joint_position(sim.joint, if cmd.is_finite() { cmd } else { q });
        }
        self.twin.forward();
        for &site in &self.sites {
            let a = self.world.site_position(site);
            let b = self.twin.site_position(site);
            let d = ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt();
            s.effector_error.push(d);
            s.site_pos.push(a);
        }
        if let Some(b) = self.world.free_body() {
            let p = self.world.body_position(b);
            let r = self.world.body_rotation(b);
            // Row-major: the body's z axis in the world is the third column; its z component r[8].
            let (pressure_centre, pressure_margin, floor_force) =
                pressure(&self.world.floor_contacts(FLOOR_CONTACT_M));
            s.torso = Some(Torso {
                pos: p,
                tilt_deg: r[8].clamp(-1.0, 1.0).acos().to_degrees(),
                com: self.world.subtree_com(0),
                pressure_centre,
                pressure_margin,
                floor_force,
            });
        }
        self.samples.push(s);
    }
}

impl Plant for SimPlant {
    fn advance(&mut self, chain: &mut Chain, dt: f64) {
        // Held until the controller first turns a torque on, as a robot is held (or hangs on its
        // stand) while the controller starts: limp servos would let it fold where it stands in
        // the real time a client takes to connect and configure them. Time runs on (the
        // servos' clocks, the simulated time the loop's ticks are matched with).
        self.held = self.held && !chain.servos().iter().any(VirtualServo::torque_on);
        if self.held {
            self.world.pass_time(dt);
        } else {
            self.pending += dt;
        }
        let h = self.world.timestep();
        // Whole physics steps only: the same bus traffic gives the same steps, every run.
        while self.pending >= h * (1.0 - 1e-9) {
            self.step_physics(chain);
            self.pending -= h;
        }
        for (servo, s) in chain.servos_mut().iter_mut().zip(&self.servos) {
            let q = self.world.joint_position(s.joint);
            let v = self.world.joint_velocity(s.joint);
            // The actuator's torque on the joint, as the horn feels it (per tick of the horn:
            // the gear and direction of the mapping).
            let per_tick = s.map.ticks_per_radian();
            let horn_nm = self.world.actuator_force(s.actuator) * f64::from(TICKS_PER_TURN)
                / core::f64::consts::TAU
                / per_tick;
            servo.set_load(horn_nm);
            servo.step_driven(dt, s.map.angle_to_ticks_exact(q), v * per_tick);
        }
        if let (Some(board), Some(imu)) = (chain.board_mut(), self.imu) {
            let mut reading = self.imu_reading(imu);
            if let Some(e) = &mut self.imu_errors {
                e.apply(&mut reading);
            }
            board.set_imu(&reading);
        }
    }
}

impl SimPlant {
    /// What the model's IMU reads, in the OpenCR board's axes (the robot's body axes with x
    /// and y negated, as the OP3 framework undoes): °/s, g, and roll, pitch, yaw (Z-Y-X, °).
    fn imu_reading(&self, (gyro, acc, body): (usize, usize, usize)) -> ImuReading {
        let g = self.world.sensor_values(gyro);
        let a = self.world.sensor_values(acc);
        let at = |v: &[f64], k: usize| v.get(k).copied().unwrap_or(0.0);
        let r = self.world.body_rotation(body);
        let rpy = [
            r[7].atan2(r[8]),
            (-r[6]).clamp(-1.0, 1.0).asin(),
            r[3].atan2(r[0]),
        ];
        ImuReading {
            gyro_dps: [-at(g, 0), -at(g, 1), at(g, 2)].map(f64::to_degrees),
            acc_g: [-at(a, 0), -at(a, 1), at(a, 2)].map(|x| x / STANDARD_GRAVITY),
            rpy_deg: rpy.map(f64::to_degrees),
        }
    }
}

/// The errors of the OpenCR's IMU (an InvenSense MPU-9250) at its product specification's
/// figures times a scale: a zero-rate offset of 5 °/s and a zero-g offset of 60 mg on each
/// axis (their initial tolerances, each axis's sign drawn once), white noise of 0.1 °/s and
/// 3 mg RMS on every reading (its total RMS noise, and 300 µg/√Hz over its ~100 Hz band), and
/// roll and pitch tilted by what the accelerometer's offset makes gravity look like. Seeded:
/// the same seed gives the same errors.
#[derive(Clone, Debug)]
pub struct ImuErrors {
    gyro_bias_dps: [f64; 3],
    acc_bias_g: [f64; 3],
    gyro_noise_dps: f64,
    acc_noise_g: f64,
    rng: crate::bus::faults::Rng,
}

/// The MPU-9250's gyro zero-rate offset tolerance, °/s.
pub const GYRO_OFFSET_DPS: f64 = 5.0;
/// Its accelerometer zero-g offset tolerance (x, y), g.
pub const ACC_OFFSET_G: f64 = 0.060;
/// Its gyro's total RMS noise, °/s.
pub const GYRO_NOISE_DPS: f64 = 0.1;
/// Its accelerometer's RMS noise over its band, g.
pub const ACC_NOISE_G: f64 = 0.003;

impl ImuErrors {
    /// The specification's errors times `scale` (1: at its limits), drawn from `seed`.
    #[must_use]
    pub fn datasheet(scale: f64, seed: u64) -> ImuErrors {
        let mut rng = crate::bus::faults::Rng::new(seed);
        let mut sign = || if rng.chance(0.5) { 1.0 } else { -1.0 };
        let gyro_bias_dps = [0; 3].map(|_| sign() * GYRO_OFFSET_DPS * scale);
        let acc_bias_g = [0; 3].map(|_| sign() * ACC_OFFSET_G * scale);
        ImuErrors {
            gyro_bias_dps,
            acc_bias_g,
            gyro_noise_dps: GYRO_NOISE_DPS * scale,
            acc_noise_g: ACC_NOISE_G * scale,
            rng: crate::bus::faults::Rng::new(seed ^ 0x5EED_1A0E),
        }
    }

    /// A standard normal number (Box–Muller).
    fn normal(&mut self) -> f64 {
        let u = |r: &mut crate::bus::faults::Rng| ((r.next_u64() >> 11) as f64 + 0.5) / (1u64 << 53) as f64;
        let (a, b) = (u(&mut self.rng), u(&mut self.rng));
        (-2.0 * a.ln()).sqrt() * (core::f64::consts::TAU * b).cos()
    }

    /// `reading` as the sensor would give it.
    pub fn apply(&mut self, reading: &mut ImuReading) {
        for k in 0..3 {
            reading.gyro_dps[k] += self.gyro_bias_dps[k] + self.gyro_noise_dps * self.normal();
            reading.acc_g[k] += self.acc_bias_g[k] + self.acc_noise_g * self.normal();
        }
        // Gravity seen through the offset: a level board's roll and pitch tilted.
        reading.rpy_deg[0] += self.acc_bias_g[1].atan().to_degrees();
        reading.rpy_deg[1] -= self.acc_bias_g[0].atan().to_degrees();
    }
}

/// Standard gravity, m/s² (an accelerometer's g).
pub const STANDARD_GRAVITY: f64 = 9.806_65;

/// Where simulated servos power up: joint angle 0, clamped into each servo's limits.
#[must_use]
pub fn rest_angles(rig: &Rig) -> Vec<f64> {
    rig.servos
        .iter()
        .map(|m| {
            let (lo, hi) = super::mjcf::angle_range(m);
            0.0f64.clamp(lo, hi)
        })
        .collect()
}

/// Simulated servos in lockstep: the loop's bus and its clock. Bus transactions take their wire
/// time and waiting for a deadline steps the physics until then — deterministic (the same
/// inputs give the same bytes and the same physics, every run), no threads.
pub type SimBus = VirtualRig<SimPlant>;

/// A lockstep simulated rig powered up with every servo where the model rests (clamped into
/// its limits), keeping the line time of the profile's bus.
///
/// # Errors
/// [`SimError`] when the model does not fit the profile.
pub fn sim_bus(world: World, profile: &Profile, rig: &Rig) -> Result<SimBus, SimError> {
    let mut plant = SimPlant::new(world, profile, rig)?;
    plant.set_angles(&rest_angles(rig));
    let present = plant.present_ticks();
    let chain = chain_for(profile.bus_section(), |k| present[k]);
    Ok(VirtualRig::keeping_time_of(chain, plant, &profile.bus))
}

/// Loads a model: a given MJCF file, or the puppet generated from the skeleton and profile.
///
/// # Errors
/// [`SimError`] naming the file or the servo at fault.
pub fn load_world(
    model: Option<&Path>,
    skeleton: Option<&crate::skeleton::Skeleton>,
    profile: &Profile,
    rig: &Rig,
    options: &super::mjcf::PuppetOptions,
) -> Result<World, SimError> {
    match (model, skeleton) {
        (Some(path), _) => World::from_file(path).map_err(SimError::ModelFile),
        (None, Some(sk)) => {
            let xml = super::mjcf::puppet(sk, profile, rig, options)?;
            World::from_xml_str(&xml).map_err(SimError::Generated)
        }
        (None, None) => Err(SimError::NoModel),
    }
}

#[cfg(test)]
mod pressure_tests {
    use super::pressure;

    #[test]
    fn the_centre_of_pressure_is_the_force_weighted_mean_and_its_margin_the_distance_to_the_hull() {
        // A 0.1 × 0.06 sole, more weight on its front corners.
        let c = [
            ([0.05, 0.03, 0.0], 30.0),
            ([0.05, -0.03, 0.0], 30.0),
            ([-0.05, 0.03, 0.0], 10.0),
            ([-0.05, -0.03, 0.0], 10.0),
        ];
        let (centre, margin, force) = pressure(&c);
        let centre = centre.unwrap();
        assert!((centre[0] - 0.025).abs() < 1e-12 && centre[1].abs() < 1e-12);
        assert!((margin.unwrap() - 0.025).abs() < 1e-12, "{margin:?}");
        assert_eq!(force, 80.0);
        assert_eq!(pressure(&[]), (None, None, 0.0));
        // Two contacts: a line, no hull.
        assert!(pressure(&c[..2]).1.is_none());
    }
}

#[cfg(test)]
mod imu_error_tests {
    use super::*;

    /// Over many readings of a still, level sensor: the mean error is the offset (the
    /// specification's on every axis, sign drawn), the spread the noise, roll and pitch tilted
    /// by the accelerometer's offset (60 mg: 3.43°); the same seed, the same errors.
    #[test]
    fn imu_errors_have_the_specifications_offsets_and_noise() {
        let level = ImuReading {
            gyro_dps: [0.0; 3],
            acc_g: [0.0, 0.0, 1.0],
            rpy_deg: [0.0; 3],
        };
        let mut e = ImuErrors::datasheet(1.0, 7);
        let n = 20_000;
        let (mut sum, mut sq) = ([0.0f64; 6], [0.0f64; 6]);
        let mut rp = [0.0; 2];
        for _ in 0..n {
            let mut r = level;
            e.apply(&mut r);
            let v = [
                r.gyro_dps[0],
                r.gyro_dps[1],
                r.gyro_dps[2],
                r.acc_g[0],
                r.acc_g[1],
                r.acc_g[2] - 1.0,
            ];
            for k in 0..6 {
                sum[k] += v[k];
                sq[k] += v[k] * v[k];
            }
            rp = [r.rpy_deg[0], r.rpy_deg[1]];
        }
        for k in 0..6 {
            let mean = sum[k] / f64::from(n);
            let sd = (sq[k] / f64::from(n) - mean * mean).sqrt();
            let (offset, noise) = if k < 3 {
                (GYRO_OFFSET_DPS, GYRO_NOISE_DPS)
            } else {
                (ACC_OFFSET_G, ACC_NOISE_G)
            };
            assert!(
                (mean.abs() - offset).abs() < 0.05 * noise,
                "axis {k}: mean {mean}"
            );
            assert!((sd - noise).abs() < 0.03 * noise, "axis {k}: sd {sd}");
        }
        let tilt = ACC_OFFSET_G.atan().to_degrees();
        assert!(rp.iter().all(|a| (a.abs() - tilt).abs() < 1e-9), "{rp:?}");
        let (mut a, mut b) = (ImuErrors::datasheet(1.0, 7), ImuErrors::datasheet(1.0, 7));
        let (mut ra, mut rb) = (level, level);
        a.apply(&mut ra);
        b.apply(&mut rb);
        assert_eq!(ra, rb);
        let mut off = ImuErrors::datasheet(0.0, 7);
        let mut r = level;
        off.apply(&mut r);
        assert_eq!(r, level);
    }
}
