//! A run of the loop, assembled in one place from one typed [`SessionSpec`]: open the bus, bring
//! the servos up, build the controller, drive the source (in real time, or in lockstep with the
//! simulator), run to the end and give back the [`Outcome`].
//!
//! The command line only turns its arguments into a spec, a source and a solve; `play`,
//! `follow`, `studio`, the soak and the benches build their controllers through
//! [`controller`], so a run is set up the same way wherever it starts.

pub mod ros2;
pub mod soak;

use std::io::{IsTerminal, Write};
use std::path::PathBuf;
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crate::budget::plan_with_board;
use crate::bus::virtual_chain::{chain_for, PtyChain};
use crate::bus::{start_up, ServoBus, StartupError, Wire};
use crate::clock::{SystemClock, LOOP_SPIN_NS};
use crate::control::input::{input_channel, InputPort, InputSender};
use crate::control::live::LiveView;
use crate::control::lookahead::{Lookahead, LookaheadSettings};
use crate::control::source::{spawn_real_time, Grid, Source};
use crate::control::sources::ProducerReport;
use crate::control::stats::LoopStats;
use crate::control::{
    Controller, LoopConfig, RetargetStage, RunEnd, Solve, StopMode, StopRequests, Telemetry,
};
use crate::formats::FileError;
use crate::motion::Motion;
use crate::profile::{BusConfig, Drive, Profile};
use crate::resident;
use crate::retarget::{floor_of_clip, floor_of_rest, Options as RetargetOptions, Setup};
use crate::rig::Rig;
use crate::rt::RealTime;
use crate::schedule::{Clock, Schedule};
use crate::skeleton::Skeleton;

pub use crate::control::{start_move_s, START_MOVE_SPEED_SHARE};
pub use ros2::{Ros2Handle, Ros2Targets};

/// Messages an input channel holds beyond the look-ahead's preview: paced sources run up to
/// [`crate::control::source::LEAD_NS`] (10 ms) ahead, which is 10 ticks at 1 kHz.
const INPUT_CAPACITY: usize = 16;

/// A live source given to the simulator.
pub const SIM_TAKES_NO_LIVE_INPUT: &str = "--bus sim runs in simulated time: it takes a clip or a target file, not live input (stdin, UDP); serve the simulator on a pseudo-terminal instead (`marionette sim serve`)";

/// Why a session could not run (or ended on a fault); one line each.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SessionError {
    /// The spec does not fit itself, the rig or the input.
    #[error("{0}")]
    Invalid(String),
    /// A file (profile, retargeting model) could not be read or parsed.
    #[error(transparent)]
    File(#[from] FileError),
    /// The serial port could not be opened.
    #[error("{port}: {source}")]
    Port {
        /// The port.
        port: String,
        /// What the system said.
        source: std::io::Error,
    },
    /// The servos could not be started as the profile says.
    #[error("start-up: {0}")]
    StartUp(#[from] StartupError),
    /// Writing the run's narration, or starting a thread, failed.
    #[error("writing output: {0}")]
    Output(#[from] std::io::Error),
    /// The loop's thread ended by a panic.
    #[error("the control loop thread panicked")]
    LoopPanicked,
    /// The simulator failed (model, actuators).
    #[cfg(feature = "sim")]
    #[error(transparent)]
    Sim(#[from] crate::sim::plant::SimError),
    /// The simulator was asked for in a build without it.
    #[error("{0} {not_built}", not_built = crate::sim::NOT_BUILT)]
    NoSimulator(&'static str),
    /// A picture was not drawn.
    #[error(transparent)]
    Plot(#[from] crate::plot::PlotError),
    /// A report could not be written as JSON.
    #[error("JSON: {0}")]
    Json(#[from] serde_json::Error),
}

/// Which bus a session drives.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum BusChoice {
    /// A virtual servo chain: in process keeping line time, or (`line_time: false`) on a
    /// pseudo-terminal answering at once.
    Virtual {
        /// Keep the wire's timing (baud, return delays, the adapter's latency).
        line_time: bool,
    },
    /// The MuJoCo simulator, in lockstep on simulated time.
    Sim,
    /// A serial port.
    Port(String),
}

impl BusChoice {
    /// How the end of a run names the bus.
    #[must_use]
    pub fn describe(&self) -> String {
        match self {
            BusChoice::Port(p) => p.clone(),
            BusChoice::Virtual { .. } => "the virtual chain".into(),
            BusChoice::Sim => "the simulator".into(),
        }
    }
}

/// How far ahead of the source each servo's goal is planned.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Lead {
    /// No look-ahead: each tick's target through the greedy limiter.
    Off,
    /// Each servo led by the profile's `lag_ms` (0 where it gives none) and a period.
    Profile,
    /// Every servo led by this many ms and a period.
    Fixed(f64),
}

/// The simulator's settings and outputs (`--bus sim`).
#[derive(Clone, Debug)]
pub struct SimSpec {
    /// The MJCF model (default: the puppet generated from the profile and the skeleton).
    pub model: Option<PathBuf>,
    /// Write the tracking report as JSON here.
    pub report: Option<PathBuf>,
    /// Draw commanded against simulated angles here.
    pub plot: Option<PathBuf>,
    /// Servos drawn (default: the four with the largest RMS).
    pub plot_servos: Vec<String>,
    /// Write a floating base's path as CSV here (torso, centre of mass, centre of pressure).
    pub trace: Option<PathBuf>,
    /// Push the floating base's torso: when (simulated s), the impulse (N·s) and its direction
    /// on the floor (degrees from +x towards +y).
    pub push: Option<[f64; 3]>,
    /// Every simulated servo's joint damping times this (1.5: 50 % slower than the profile's).
    pub lag_scale: f64,
    /// Every simulated servo's torque limit times this (0.8: 20 % weaker).
    pub torque_scale: f64,
    /// The model's IMU with its sensor's errors times this scale (1: the MPU-9250's
    /// specification) drawn from this seed.
    pub imu_errors: Option<(f64, u64)>,
    /// Every simulated servo's motor temperature at the start, °C (warm from an earlier run;
    /// `None`: the air's).
    pub servo_temp_c: Option<f64>,
}

impl Default for SimSpec {
    fn default() -> SimSpec {
        SimSpec {
            model: None,
            report: None,
            plot: None,
            plot_servos: Vec::new(),
            trace: None,
            push: None,
            lag_scale: 1.0,
            torque_scale: 1.0,
            imu_errors: None,
            servo_temp_c: None,
        }
    }
}

/// What a walk does with the robot's IMU board.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ImuUse {
    /// Not read: open loop.
    #[default]
    Off,
    /// Read every tick and reported (the stats JSON's `imu` block).
    Read,
    /// Read, and its gyro fed back to the legs.
    Feedback,
}

/// Where the loop's telemetry goes while it runs.
#[derive(Clone, Debug, Default)]
pub struct Sinks {
    /// A status line on stderr.
    pub status_line: bool,
    /// The studio's view of goals, present angles and timing.
    pub live: Option<Arc<LiveView>>,
    /// `/joint_states` on this node at this rate, Hz.
    pub ros2: Option<(Ros2Handle, f64)>,
}

/// Everything a run is, decided before it starts.
#[derive(Clone, Debug)]
pub struct SessionSpec {
    /// Loop rate, Hz (1…2000).
    pub rate_hz: f64,
    /// Stop after this long, seconds.
    pub duration_s: Option<f64>,
    /// The bus.
    pub bus: BusChoice,
    /// A serial port's bit rate (default: the profile's).
    pub baud: Option<u32>,
    /// What happens at the end.
    pub stop: StopMode,
    /// Consecutive failed reads after which the last command sent is held.
    pub hold_after: u32,
    /// Milliseconds without a valid read after which torque goes off and the run stops.
    pub torque_off_after_ms: f64,
    /// Seconds over which the first commands blend from where the servos stand.
    pub ease_in_s: f64,
    /// Where in the clip the run starts, seconds (the pose a pre-roll holds).
    pub clip_start_s: f64,
    /// A clip's pre-roll and the ease-in are lengthened when the servos stand further from
    /// the clip's first pose than they can travel in `ease_in_s` at
    /// [`START_MOVE_SPEED_SHARE`] of their velocity limits ([`start_move_s`]). When that pose
    /// is not known before the run (targets to follow), the loop sizes the ease-in at its
    /// first input ([`LoopConfig::size_start_move`]).
    pub size_start_move: bool,
    /// The look-ahead.
    pub lead: Lead,
    /// Retargeting onto a robot's joints (profiles of robot joints).
    pub retarget: RetargetOptions,
    /// A whole-body clip walks on a plan (footsteps, ZMP preview) rather than frame by frame.
    pub walk: bool,
    /// Walking, with an IMU board in the profile: whether the tick reads it, and feeds its gyro
    /// back to the legs.
    pub imu: ImuUse,
    /// Robot joints: each servo commanded past its joint's angle by what it sags under the
    /// pose's static load (its stiffness from its model and Position P Gain), so that the
    /// horn ends on the angle. Off for a robot on a stand.
    pub load_compensation: bool,
    /// In a real-time run, make the next tick's limb solve ahead while the loop waits for its
    /// deadline ([`crate::control::Controller::rehearse`]), so that the tick finds its code and
    /// data in the caches.
    pub rehearse: bool,
    /// Watch the servos' temperature, supply and hardware errors from the loop
    /// ([`crate::control::health`]).
    pub health: bool,
    /// Model metres per subject metre (the generated puppet; effector errors in metres).
    pub scale: f64,
    /// Scheduling of the loop's thread.
    pub real_time: RealTime,
    /// The simulator's settings and outputs.
    pub sim: SimSpec,
    /// Telemetry while it runs.
    pub sinks: Sinks,
    /// Counts the loop thread's allocations (the counting allocator's reader).
    pub allocations: Option<fn() -> u64>,
}

impl Default for SessionSpec {
    /// `play`'s defaults: 120 Hz on the virtual chain keeping line time, the look-ahead led by
    /// the profile's lags, a 1 s ramp to rest.
    fn default() -> SessionSpec {
        let config = LoopConfig::default();
        SessionSpec {
            rate_hz: config.rate_hz,
            duration_s: None,
            bus: BusChoice::Virtual { line_time: true },
            baud: None,
            stop: config.stop,
            hold_after: config.hold_after,
            torque_off_after_ms: config.torque_off_after_ms,
            ease_in_s: config.ease_in_s,
            clip_start_s: 0.0,
            size_start_move: false,
            lead: Lead::Profile,
            retarget: RetargetOptions {
                upper_body: false,
                balance: true,
                per_frame: false,
            },
            walk: false,
            imu: ImuUse::Off,
            load_compensation: true,
            rehearse: true,
            health: true,
            scale: 0.3,
            real_time: RealTime::default(),
            sim: SimSpec::default(),
            sinks: Sinks::default(),
            allocations: None,
        }
    }
}

impl SessionSpec {
    /// Checks the figures against their ranges.
    ///
    /// # Errors
    /// [`SessionError::Invalid`] naming the option.
    pub fn check(&self) -> Result<(), SessionError> {
        let invalid = |s: String| Err(SessionError::Invalid(s));
        if !(self.rate_hz.is_finite() && (1.0..=2000.0).contains(&self.rate_hz)) {
            return invalid(format!(
                "--rate must be between 1 and 2000 Hz, got {}",
                self.rate_hz
            ));
        }
        if self.duration_s.is_some_and(|d| !(d.is_finite() && d > 0.0)) {
            return invalid("--duration must be a positive number of seconds".into());
        }
        if !(self.ease_in_s.is_finite() && (0.0..=60.0).contains(&self.ease_in_s)) {
            return invalid("--ease-in must be between 0 and 60 seconds".into());
        }
        let ramp = match self.stop {
            StopMode::Rest { ramp_s } => ramp_s,
            StopMode::Hold { hold_s } => hold_s,
        };
        if !(ramp.is_finite() && (0.0..=60.0).contains(&ramp)) {
            return invalid("--ramp must be between 0 and 60 seconds".into());
        }
        if !(self.torque_off_after_ms.is_finite() && self.torque_off_after_ms > 0.0) {
            return invalid("--torque-off-after must be a positive number of ms".into());
        }
        if self.hold_after == 0 {
            return invalid("--hold-after must be at least 1".into());
        }
        if self.imu != ImuUse::Off && !self.walk {
            return invalid("--imu is the walk's: give --walk too".into());
        }
        if self.walk && self.retarget.upper_body {
            return invalid("--walk plans the legs; --upper-body keeps them in a stance: give one".into());
        }
        if let Lead::Fixed(l) = self.lead {
            if !(l.is_finite() && (0.0..=1000.0).contains(&l)) {
                return invalid("--lead-ms must be between 0 and 1000".into());
            }
        }
        if let Some((_, hz)) = &self.sinks.ros2 {
            if !(hz.is_finite() && (0.1..=1000.0).contains(hz)) {
                return invalid(format!("--ros2-rate must be between 0.1 and 1000 Hz, got {hz}"));
            }
        }
        Ok(())
    }

    /// The loop's settings; `real_time` puts the fidelity's lag search on a thread of its own.
    #[must_use]
    pub fn loop_config(&self, profile: &Profile, skeleton: &Skeleton, real_time: bool) -> LoopConfig {
        LoopConfig {
            rate_hz: self.rate_hz,
            hold_after: self.hold_after,
            torque_off_after_ms: self.torque_off_after_ms,
            stop: self.stop,
            max_ticks: self
                .duration_s
                .map(|d| (d * self.rate_hz).round().max(1.0) as u64),
            ease_in_s: self.ease_in_s,
            effector_metres_per_unit: self.scale * f64::from(skeleton.units().meters_per_unit()),
            // Dynamixel2 (Bulk Read) cannot split a read: its request does nothing, its collect
            // reads.
            pipelined: profile.bus.pipeline,
            fidelity_worker: real_time,
            rehearse: real_time && self.rehearse,
            size_start_move: self.size_start_move,
            allocations: if real_time { self.allocations } else { None },
            count_page_faults: real_time,
            bus_watchdog_ms: profile.bus.watchdog_ms,
        }
    }

    /// The look-ahead (none with [`Lead::Off`]): each servo led by its lag and the loop's period
    /// (a goal written now is read back a tick later).
    #[must_use]
    pub fn lookahead(&self, profile: &Profile, rig: &Rig) -> Option<Lookahead> {
        let fixed = match self.lead {
            Lead::Off => return None,
            Lead::Profile => None,
            Lead::Fixed(ms) => Some(ms),
        };
        let leads: Vec<f64> = profile
            .servos
            .iter()
            .map(|s| fixed.or(s.lag_ms).unwrap_or(0.0) * 1e-3 + 1.0 / self.rate_hz)
            .collect();
        Some(Lookahead::new(
            rig,
            self.rate_hz,
            &leads,
            LookaheadSettings::default(),
        ))
    }

    /// Messages the input channel holds: a few ticks, plus the look-ahead's longest preview (a
    /// lead of up to a second and the window) so that a lockstep feed never drops one.
    #[must_use]
    pub fn input_capacity(&self) -> usize {
        INPUT_CAPACITY + (1.25 * self.rate_hz).ceil() as usize
    }
}

/// How the rig is driven: its mapping, and for a profile of robot joints the retargeting stage
/// that turns the human pose into the robot's inside the tick.
#[derive(Debug)]
pub struct RigDrive {
    /// The skeleton the input poses.
    pub skeleton: Arc<Skeleton>,
    /// Servo mapping.
    pub rig: Rig,
    /// Retargeting onto a robot (profiles of robot joints).
    pub retarget: Option<RetargetStage>,
    /// The IMU board's reading and the legs' feedback (walking, with a board in the profile).
    pub balance: Option<crate::control::balance::Balance>,
    /// Where the ramp to rest ends (radians per servo) when not at every angle 0: a robot's
    /// standing stance (a walk's: its plan's last frame, on both feet).
    pub rest_pose: Option<Vec<f64>>,
    /// The clip's pose where the run starts (radians per servo), when it is known before the
    /// run: a bone rig's frame, a robot's planned frame.
    pub start_pose: Option<Vec<f64>>,
}

impl RigDrive {
    /// The rig's angles for the human pose `channels` as the run's first sample makes them:
    /// the bones' own, or the joints a copy of the retargeting (not yet run) gives them, `dt`
    /// seconds being the loop's period.
    #[must_use]
    pub fn first_angles(&self, channels: &[f64], dt: f64) -> Vec<f64> {
        let joints = self
            .retarget
            .as_ref()
            .map(|stage| stage.clone().joints_of(&self.skeleton, channels, dt));
        let mut angles = vec![0.0; self.rig.servos.len()];
        let joints = joints.as_ref().map_or(&[][..], |q| &q[..]);
        self.rig
            .joint_angles(&self.skeleton, channels, joints, &mut angles);
        angles
    }

    /// The drive of `profile` over `skeleton`: its bones' rig, or the robot's joints retargeted
    /// with the floor from `clip` (else from the rest pose). Says what it retargets onto.
    ///
    /// # Errors
    /// The profile's rig or retargeting model does not fit the skeleton.
    pub fn new(
        spec: &SessionSpec,
        profile: &Profile,
        skeleton: Arc<Skeleton>,
        clip: Option<&Motion>,
        log: &mut dyn Write,
    ) -> Result<RigDrive, SessionError> {
        let joint_driven = profile.servos.iter().any(|s| matches!(s.drive, Drive::Joint(_)));
        if !joint_driven {
            let rig = profile.rig(Some(&skeleton))?;
            let start_pose = clip.and_then(|m| {
                let k = (spec.clip_start_s * m.frame_rate).round().max(0.0) as usize;
                let frame = m.frames().nth(k).or_else(|| m.frames().last())?;
                let channels = crate::motion::frame_to_radians(&skeleton, frame);
                let mut angles = vec![0.0; rig.servos.len()];
                rig.joint_angles(&skeleton, &channels, &[], &mut angles);
                Some(angles)
            });
            return Ok(RigDrive {
                rig,
                skeleton,
                retarget: None,
                balance: None,
                rest_pose: None,
                start_pose,
            });
        }
        let setup = Setup::new(profile, &skeleton)?;
        let floor = match clip {
            Some(m) => floor_of_clip(&skeleton, m, &setup.map.human),
            None => floor_of_rest(&skeleton, &setup.map.human),
        };
        let mut stage = RetargetStage::new(&setup, &skeleton, floor, spec.retarget);
        stage.set_load_compensation(spec.load_compensation, &setup);
        // A stop ramps to the standing stance (knees bent, soles flat, feet under the hips),
        // not to every joint at 0 (straight legs).
        let mut angles = vec![0.0; setup.rig.servos.len()];
        setup
            .rig
            .joint_angles(&skeleton, &[], &stage.stance(), &mut angles);
        let mut rest_pose = Some(angles);
        if let (true, false, Some(m)) = (spec.walk, spec.retarget.upper_body, clip) {
            let (walked, plan) = crate::retarget::walk::retarget_walking(&setup, &skeleton, m, spec.retarget)
                .map_err(|e| SessionError::Invalid(format!("cannot plan the walk: {e}")))?;
            let w = plan.report();
            writeln!(
                log,
                "walking on a plan: {} footsteps ({} substituted, {} of the clip's left out), {:.3} m planned against {:.3} m in the clip, planned ZMP ≥ {:.1} mm inside the feet",
                w.footsteps, w.substituted_steps, w.dropped_steps, w.planned_travel_m, w.clip_travel_m, w.zmp_margin_mm.planned_min
            )?;
            // A stop ramps to the plan's last frame: standing on both feet, the centre of mass
            // between them (not every joint at 0, straight legs on which the robot tips).
            if let Some(f) = walked.frames.last() {
                let mut angles = vec![0.0; setup.rig.servos.len()];
                setup.rig.joint_angles(&skeleton, &[], &f.q, &mut angles);
                rest_pose = Some(angles);
            }
            stage.set_plan(walked.frames, m.frame_rate, Some(w));
        } else if let (Some(m), false) = (clip, spec.retarget.per_frame) {
            // The whole clip retargeted before the run: arm branches planned over it, every
            // joint within its servo's speed and acceleration.
            let run = crate::retarget::retarget_clip(&setup, &skeleton, m, spec.retarget);
            if let Some(f) = &run.report.continuity.faster_than_servos {
                writeln!(
                    log,
                    "retargeted the clip whole: arm branches planned, joints within their servos' speed and acceleration{}",
                    if f.frames > 0 {
                        format!(
                            "; the human moves faster than the servos in {} frames, where the robot lags",
                            f.frames
                        )
                    } else {
                        String::new()
                    }
                )?;
            }
            stage.set_plan(run.frames, m.frame_rate, None);
        }
        if clip.is_some() {
            stage.set_clip_start(spec.clip_start_s);
        }
        let start_pose = stage.planned_start().map(|q| {
            let mut angles = vec![0.0; setup.rig.servos.len()];
            setup.rig.joint_angles(&skeleton, &[], &q, &mut angles);
            angles
        });
        let balance = match (spec.walk, spec.imu, profile.bus.imu_board) {
            (false, _, _) => None,
            (true, _, None) => {
                writeln!(
                    log,
                    "no IMU board in the profile ([bus] imu_board_id): the walk plays open loop"
                )?;
                None
            }
            (true, ImuUse::Off, Some(id)) => {
                writeln!(
                    log,
                    "IMU board at id {id}: not read, the walk plays open loop (--imu read|feedback)"
                )?;
                None
            }
            (true, use_, Some(id)) => {
                let feedback = use_ == ImuUse::Feedback;
                writeln!(
                    log,
                    "IMU board at id {id}: read every tick with the servos' positions (one more entry of their Bulk Read, or Fast Bulk Read where the profile reads fast){}",
                    if feedback {
                        ", its gyro fed back to the legs"
                    } else {
                        ""
                    }
                )?;
                Some(crate::control::balance::Balance::new(
                    id, &setup, &setup.rig, feedback,
                ))
            }
        };
        writeln!(
            log,
            "retargeting onto {} ({} joints){}",
            setup.model.display(),
            setup.robot.joints().len(),
            if spec.retarget.upper_body {
                ", upper body (legs in a stance)"
            } else {
                ""
            }
        )?;
        Ok(RigDrive {
            skeleton,
            rig: setup.rig,
            retarget: Some(stage),
            balance,
            rest_pose,
            start_pose,
        })
    }
}

/// The controller of a run: `drive`'s skeleton, rig and retargeting, `spec`'s loop settings and
/// look-ahead, the profile's servo names, the studio's view when there is one; the servos stand
/// at `present`. `real_time`: [`SessionSpec::loop_config`].
#[must_use]
pub fn controller(
    spec: &SessionSpec,
    profile: &Profile,
    drive: RigDrive,
    present: &[i32],
    port: InputPort,
    solve: Solve,
    real_time: bool,
) -> Controller {
    let mut config = spec.loop_config(profile, &drive.skeleton, real_time);
    // The session sizes the move to a pose it knows; the loop, to the first input's.
    config.size_start_move &= drive.start_pose.is_none();
    let planner = spec.lookahead(profile, &drive.rig);
    let mut c = Controller::new(
        drive.skeleton,
        drive.rig,
        profile.ids(),
        present,
        port,
        solve,
        config,
    );
    c.set_servo_names(profile.servos.iter().map(|s| s.name.clone()).collect());
    if let Some(r) = drive.retarget {
        c.set_retarget(r);
    }
    if let Some(b) = drive.balance {
        c.set_balance(b);
    }
    if let Some(r) = drive.rest_pose {
        c.set_rest_pose(r);
    }
    if let Some(p) = planner {
        c.set_lookahead(p);
    }
    if let Some(v) = &spec.sinks.live {
        c.set_live_view(Arc::clone(v));
    }
    if spec.health {
        c.set_health(crate::control::health::HealthWatch::of_profile(
            profile,
            spec.rate_hz,
        ));
    }
    c
}

/// What a run gave back.
#[derive(Debug)]
pub struct Outcome {
    /// The loop's statistics.
    pub stats: LoopStats,
    /// Why it ended.
    pub end: RunEnd,
    /// What the source sent.
    pub producer: ProducerReport,
    /// Why the port failed ([`RunEnd::PortLost`]).
    pub port_error: Option<std::io::Error>,
}

/// A session: its spec and its input channel, made before the source (a source that sends by
/// itself, like the studio's drags, takes [`Session::input`]).
#[derive(Debug)]
pub struct Session {
    spec: SessionSpec,
    tx: InputSender,
    port: InputPort,
}

impl Session {
    /// A session of `spec`.
    ///
    /// # Errors
    /// [`SessionError::Invalid`] when the spec's figures are out of range.
    pub fn new(spec: SessionSpec) -> Result<Session, SessionError> {
        spec.check()?;
        let (tx, port) = input_channel(spec.input_capacity());
        Ok(Session { spec, tx, port })
    }

    /// The spec.
    #[must_use]
    pub fn spec(&self) -> &SessionSpec {
        &self.spec
    }

    /// The input channel's sending end.
    #[must_use]
    pub fn input(&self) -> InputSender {
        self.tx.clone()
    }

    /// Runs `source` through `profile`'s rig driven from `skeleton` (`clip`, when there is one,
    /// places a robot's floor) until the input ends, the duration is reached or a stop is
    /// requested; the servos end safe (ramp or hold, then torque off) every way. Narrates
    /// start-up and the end on `log`.
    ///
    /// # Errors
    /// [`SessionError`]; by then every servo that was started has torque off.
    pub fn run(
        self,
        profile: &Profile,
        skeleton: Arc<Skeleton>,
        solve: Solve,
        clip: Option<&Motion>,
        source: Box<dyn Source>,
        log: &mut dyn Write,
    ) -> Result<Outcome, SessionError> {
        let Session { spec, tx, port } = self;
        // From here on a signal stops the run safely (during start-up too).
        let stop = crate::signals::stop_requests()?;
        let mut drive = RigDrive::new(&spec, profile, skeleton, clip, log)?;
        if let (true, None, Solve::Follow(f), Some(targets)) = (
            spec.size_start_move,
            &drive.start_pose,
            &solve,
            source.first_targets(),
        ) {
            // Following a target file: its first targets, solved (and retargeted) as the loop
            // will, are the pose the run starts towards.
            drive.start_pose = f
                .first_pose(&drive.skeleton, targets)
                .map(|channels| drive.first_angles(&channels, 1.0 / spec.rate_hz));
        }
        let run = Run {
            spec: &spec,
            profile,
            drive,
            solve,
            port,
            stop,
        };
        if spec.bus == BusChoice::Sim {
            if spec.sinks.ros2.is_some() {
                return Err(SessionError::Invalid(
                    "--ros2 runs in real time and --bus sim in simulated time: serve the simulator on a pseudo-terminal (`marionette sim serve`) and give its path to --bus".into(),
                ));
            }
            if !source.runs_in_lockstep() {
                return Err(SessionError::Invalid(SIM_TAKES_NO_LIVE_INPUT.into()));
            }
            return run.in_lockstep(source, tx, log);
        }
        run.in_real_time(source, tx, log)
    }
}

/// The parts of a run, between its spec and its loop.
struct Run<'a> {
    spec: &'a SessionSpec,
    profile: &'a Profile,
    drive: RigDrive,
    solve: Solve,
    port: InputPort,
    stop: StopRequests,
}

/// An opened bus: the virtual chain (kept alive while the bus is used) or a port.
pub struct OpenBus {
    /// The project's host on it.
    pub bus: Box<dyn ServoBus + Send>,
    _chain: Option<PtyChain>,
    /// How the run names it.
    pub label: String,
}

impl std::fmt::Debug for OpenBus {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OpenBus")
            .field("label", &self.label)
            .finish_non_exhaustive()
    }
}

/// Opens the bus `spec` names for `profile` (a real-time bus: not `--bus sim`), the servos of a
/// virtual chain at their zero angle (`rig`'s rest); warns on `log` when a bus cycle does not
/// fit the period.
///
/// # Errors
/// The port cannot be opened; [`BusChoice::Sim`].
pub fn open_bus(
    spec: &SessionSpec,
    profile: &Profile,
    rig: &Rig,
    log: &mut dyn Write,
) -> Result<OpenBus, SessionError> {
    let n = profile.servos.len();
    let mut config = profile.bus.clone();
    config.baud = spec.baud.unwrap_or(profile.bus.baud);
    let read = format!(
        "{} read{}",
        profile.bus.read.name(),
        if profile.bus.pipeline { ", pipelined" } else { "" }
    );
    let at_port = |port: &str| {
        let port = port.to_string();
        move |source| SessionError::Port { port, source }
    };
    match &spec.bus {
        BusChoice::Virtual { line_time } => {
            let rest: Vec<i32> = rig.servos.iter().map(crate::rig::ServoMap::rest_tick).collect();
            let chain = chain_for(profile.bus_section(), |k| rest[k]);
            if !line_time {
                // On a pty, answering as soon as the serving thread can.
                let chain = PtyChain::serve(chain, None)?;
                let path = chain.path().to_string();
                let bus = crate::bus::open(Wire::Port(path.clone()), &config, n).map_err(at_port(&path))?;
                return Ok(OpenBus {
                    bus,
                    label: format!("virtual chain of {n} servos on {path} (answering at once, {read})"),
                    _chain: Some(chain),
                });
            }
            // In process and in real time, keeping line time exactly: the loop's own host on
            // it, as on a port.
            warn_if_over_budget(spec, &config, n, log)?;
            let bus = crate::bus::open(Wire::Chain(Box::new(chain)), &config, n)?;
            Ok(OpenBus {
                bus,
                label: format!(
                    "virtual chain of {n} servos at {} bit/s, {} µs USB latency (line time kept, {read})",
                    config.baud, config.usb_latency_us
                ),
                _chain: None,
            })
        }
        BusChoice::Sim => Err(SessionError::Invalid(SIM_TAKES_NO_LIVE_INPUT.into())),
        BusChoice::Port(port) => {
            warn_if_over_budget(spec, &config, n, log)?;
            let bus = crate::bus::open(Wire::Port(port.clone()), &config, n).map_err(at_port(port))?;
            Ok(OpenBus {
                bus,
                label: format!(
                    "{port} at {} bit/s ({} read)",
                    config.baud,
                    profile.bus.read.name()
                ),
                _chain: None,
            })
        }
    }
}

/// Warns when a bus cycle (with the IMU board's read when a walk reads it) does not fit the
/// loop's period, or the period is half the Bus Watchdog or more (the loop then checks the
/// watchdog every tick, and one late tick lets it stop the servos).
fn warn_if_over_budget(
    spec: &SessionSpec,
    bus: &BusConfig,
    servos: usize,
    log: &mut dyn Write,
) -> std::io::Result<()> {
    let rate_hz = spec.rate_hz;
    let board = (spec.walk && spec.imu != ImuUse::Off && bus.imu_board.is_some())
        .then_some(crate::sensor_board::IMU_BYTES as u32);
    let b = plan_with_board(bus, servos, Some(rate_hz), board);
    if b.feasible == Some(false) {
        writeln!(
            log,
            "warning: a bus cycle takes {:.0} µs ({:.0} % of the {:.0} µs period): expect deadline misses (`marionette budget`)",
            b.cycle_time_us,
            100.0 * b.utilisation.unwrap_or(0.0),
            1e6 / rate_hz
        )?;
    } else if spec.health && b.worst_feasible == Some(false) {
        writeln!(
            log,
            "warning: the cycles with the health read take {:.0} µs, over the {:.0} µs period: one tick in {:.0} runs late (--no-health, or a lower --rate)",
            b.worst_cycle_us,
            1e6 / rate_hz,
            (rate_hz / crate::control::health::READS_PER_S).round().max(1.0)
        )?;
    }
    let period_ms = 1e3 / rate_hz;
    if bus.watchdog_ms > 0 && 2.0 * period_ms >= f64::from(bus.watchdog_ms) {
        writeln!(
            log,
            "warning: at {rate_hz} Hz the servos hear the loop every {period_ms:.0} ms, half their Bus Watchdog ({} ms, the profile's watchdog_ms) or more: each tick reads the watchdog, and a late tick lets it stop them (a rate above {:.0} Hz, or a longer watchdog_ms)",
            bus.watchdog_ms,
            2e3 / f64::from(bus.watchdog_ms)
        )?;
    }
    Ok(())
}

/// How long the move to the clip's first pose takes when `spec` sizes it and it is longer
/// than the ease-in ([`start_move_s`]); says so on `log`.
fn sized_start_move(
    spec: &SessionSpec,
    profile: &Profile,
    drive: &RigDrive,
    present: &[i32],
    log: &mut dyn Write,
) -> std::io::Result<Option<f64>> {
    if !spec.size_start_move {
        return Ok(None);
    }
    let Some((seconds, servo, degrees)) = drive
        .start_pose
        .as_deref()
        .and_then(|pose| start_move_s(&drive.rig, present, pose))
    else {
        return Ok(None);
    };
    if seconds <= spec.ease_in_s {
        return Ok(None);
    }
    writeln!(
        log,
        "moving to the first pose over {seconds:.2} s, not {} s: {} is {degrees:.0}° from it (at most {:.0} % of each servo's speed)",
        spec.ease_in_s,
        profile.servos.get(servo).map_or("a servo", |s| s.name.as_str()),
        100.0 * START_MOVE_SPEED_SHARE
    )?;
    Ok(Some(seconds))
}

/// The move to the first pose: the ease-in lengthened to `start_move` seconds when the session
/// sized it, and (when `spec` sizes the move) the source's first input held through the whole
/// ease-in, so that the input starts where the servos arrive.
fn ease_into_first_pose(
    spec: &SessionSpec,
    start_move: Option<f64>,
    controller: &mut Controller,
    source: &mut dyn Source,
) {
    if let Some(seconds) = start_move {
        controller.set_ease_in(seconds);
    }
    if spec.size_start_move {
        source.hold_first(start_move.unwrap_or(spec.ease_in_s));
    }
}

impl Run<'_> {
    /// The loop in its own thread on the machine clock (sleep, then spin to the deadline), the
    /// source in another, the telemetry sinks in others; waits for the end.
    fn in_real_time(
        self,
        source: Box<dyn Source>,
        tx: InputSender,
        log: &mut dyn Write,
    ) -> Result<Outcome, SessionError> {
        let Run {
            spec,
            profile,
            drive,
            solve,
            port,
            stop,
        } = self;
        let OpenBus {
            mut bus,
            _chain,
            label,
        } = open_bus(spec, profile, &drive.rig, log)?;
        let present = start_up(bus.as_mut(), profile.bus_section())?;
        writeln!(log, "{label}: {} servos up, torque on", present.len())?;
        let rig = drive.rig.clone();
        let start_move = sized_start_move(spec, profile, &drive, &present, log)?;
        let mut controller = controller(spec, profile, drive, &present, port, solve, true);
        let mut source = source;
        ease_into_first_pose(spec, start_move, &mut controller, source.as_mut());
        let (ttx, trx) = resident::channel(4096, Telemetry::default());
        let _ = controller.add_telemetry(ttx);
        let period = controller.period_ns();
        let mut clock = SystemClock::new(LOOP_SPIN_NS);
        let names: Vec<String> = profile.servos.iter().map(|s| s.name.clone()).collect();
        let publishing = ros2::publish(
            spec.sinks.ros2.as_ref().map(|(n, _)| n),
            spec.sinks.ros2.as_ref().map_or(0.0, |(_, hz)| *hz),
            &mut controller,
            &rig,
            names,
            clock,
            log,
        )?;
        // The first tick a little ahead, so the source has filled the channel (at most half
        // the Bus Watchdog away: it was armed at the end of the start-up).
        let lead_ns = match profile.bus.watchdog_ms {
            0 => 50_000_000,
            w => (u64::from(w) * 500_000).min(50_000_000),
        };
        let start = clock.now_ns() + lead_ns;
        let grid = Grid {
            start_ns: start,
            period_ns: period,
        };
        let producer = spawn_real_time(source, tx, clock, grid, controller.preview_ns())?;
        let rt = spec.real_time;
        let handle = std::thread::Builder::new()
            .name("control-loop".into())
            .spawn(move || {
                let warnings = rt.apply();
                crate::rt::prefault();
                let mut schedule = Schedule::new(start, period);
                let end = controller.run(&mut schedule, bus.as_mut(), &mut clock, &stop);
                (controller.stats, end, controller.port_error, warnings)
            })?;
        let status = status_line(&trx, &handle, period, spec.sinks.status_line);
        let (stats, end, port_error, warnings) = handle.join().map_err(|_| SessionError::LoopPanicked)?;
        if status {
            let _ = writeln!(std::io::stderr());
        }
        for w in warnings {
            writeln!(log, "{w}")?;
        }
        let producer = producer.join().unwrap_or_default();
        ros2::finish(publishing, log)?;
        Ok(Outcome {
            stats,
            end,
            producer,
            port_error,
        })
    }

    /// `--bus sim` in a build without the simulator.
    #[cfg(not(feature = "sim"))]
    #[allow(clippy::needless_pass_by_value, clippy::unused_self)]
    fn in_lockstep(
        self,
        _source: Box<dyn Source>,
        _tx: InputSender,
        _log: &mut dyn Write,
    ) -> Result<Outcome, SessionError> {
        Err(SessionError::NoSimulator("--bus sim"))
    }

    /// The loop in lockstep with MuJoCo, on simulated time, in this thread; then the tracking
    /// report (and its JSON and picture when asked for).
    #[cfg(feature = "sim")]
    fn in_lockstep(
        self,
        source: Box<dyn Source>,
        tx: InputSender,
        log: &mut dyn Write,
    ) -> Result<Outcome, SessionError> {
        use crate::control::lockstep::FeedingClock;
        use crate::plot::draw;
        use crate::sim::{mjcf::PuppetOptions, plant, report};
        let Run {
            spec,
            profile,
            drive,
            solve,
            port,
            stop,
        } = self;
        let options = PuppetOptions {
            scale: spec.scale,
            ..PuppetOptions::default()
        };
        let world = plant::load_world(
            spec.sim.model.as_deref(),
            Some(&drive.skeleton),
            profile,
            &drive.rig,
            &options,
        )?;
        let mut bus = plant::sim_bus(world, profile, &drive.rig)?;
        let present = start_up(&mut bus, profile.bus_section())?;
        writeln!(
            log,
            "MuJoCo: {} ({}), {} servos up, torque on; lockstep on simulated time",
            spec.sim.model.as_ref().map_or_else(
                || "puppet generated from the skeleton".to_string(),
                |m| m.display().to_string()
            ),
            bus.with(|t| format!("time step {} ms", t.plant().world().timestep() * 1e3)),
            present.len()
        )?;
        // The simulated bus keeps line time: a rate it cannot carry runs late (in simulated time).
        warn_if_over_budget(spec, &profile.bus, present.len(), log)?;
        bus.with(|t| t.plant_mut().record(true));
        let (lag, torque) = (spec.sim.lag_scale, spec.sim.torque_scale);
        if (lag, torque) != (1.0, 1.0) {
            bus.with(|t| t.plant_mut().vary_servos(lag, torque));
            writeln!(
                log,
                "simulated servos unlike the profile: joint damping ×{lag}, torque limits ×{torque}"
            )?;
        }
        if let Some(celsius) = spec.sim.servo_temp_c {
            let ids = profile.ids();
            bus.with(|t| {
                for &id in &ids {
                    if let Some(s) = t.chain_mut().servo_mut(id) {
                        s.set_temperature(celsius);
                    }
                }
            });
            writeln!(log, "simulated servos warm from an earlier run: {celsius} °C")?;
        }
        if let Some((scale, seed)) = spec.sim.imu_errors {
            bus.with(|t| {
                t.plant_mut()
                    .set_imu_errors(Some(plant::ImuErrors::datasheet(scale, seed)));
            });
            writeln!(
                log,
                "the IMU's reading with {scale} × the MPU-9250's offsets and noise (seed {seed})"
            )?;
        }
        if let Some([at_s, impulse_ns, direction_deg]) = spec.sim.push {
            bus.with(|t| {
                t.plant_mut().set_push(Some(plant::Push {
                    at_s,
                    impulse_ns,
                    direction_deg,
                }));
            });
            writeln!(
                log,
                "push: {impulse_ns} N·s towards {direction_deg}° at {at_s} s (over {} s)",
                plant::PUSH_S
            )?;
        }
        // In lockstep the physics (and its recorder) runs inside the bus calls of each tick, so
        // an allocation count would be the simulator's: the loop's own ticks are counted on the
        // other buses.
        let start_move = sized_start_move(spec, profile, &drive, &present, log)?;
        let mut controller = controller(spec, profile, drive, &present, port, solve, false);
        let mut source = source;
        ease_into_first_pose(spec, start_move, &mut controller, source.as_mut());
        let period = controller.period_ns();
        let start = bus.now_ns() + period;
        let grid = Grid {
            start_ns: start,
            period_ns: period,
        };
        let mut clock =
            FeedingClock::new(bus.clone(), source, tx, grid).with_preview(controller.preview_ns());
        let mut schedule = Schedule::new(start, period);
        if spec.sim.plot.is_some() {
            // Up to ten minutes of ticks for the picture's source curves.
            controller.log_source(((600.0 * spec.rate_hz) as usize).min(600_000));
        }
        let end = controller.run(&mut schedule, &mut bus, &mut clock, &stop);
        let producer = clock.report();
        let names: Vec<String> = profile.servos.iter().map(|s| s.name.clone()).collect();
        let mut tracking = bus.with(|t| {
            let p = t.plant();
            let mut r = report::TrackingReport::new(
                p.samples(),
                &names,
                p.saturated_steps(),
                &p.site_names(),
                p.steps(),
            );
            r.saturated_steps_first_s = p.saturated_first_second();
            r
        });
        if let Some(f) = &controller.stats.fidelity {
            tracking.add_fidelity(f);
        }
        if let Some(walk) = controller.stats.retarget.as_ref().and_then(|r| r.walk.as_ref()) {
            bus.with(|t| {
                let p = t.plant();
                let sites = p.site_names();
                let soles = sole_sites(profile).and_then(|[l, r]| {
                    let at = |n: &str| sites.iter().position(|s| s == n);
                    Some([at(&l)?, at(&r)?])
                });
                tracking.add_walk(walk, p.samples(), soles);
            });
        }
        write!(log, "{tracking}")?;
        controller.stats.sim = serde_json::to_value(&tracking).ok();
        if let Some(path) = &spec.sim.report {
            let text = serde_json::to_string_pretty(&tracking)?;
            std::fs::write(path, text + "\n").map_err(|e| FileError::io(path, e))?;
            writeln!(log, "tracking report written to {}", path.display())?;
        }
        if let Some(path) = &spec.sim.trace {
            let mut text = Vec::new();
            bus.with(|t| report::write_trace(&mut text, t.plant().samples()))?;
            std::fs::write(path, text).map_err(|e| FileError::io(path, e))?;
            writeln!(log, "torso trace written to {}", path.display())?;
        }
        if let Some(path) = &spec.sim.plot {
            let chosen = plot_choice(&spec.sim.plot_servos, &tracking)?;
            let source: Vec<(f64, Vec<f64>)> = controller
                .source_log()
                .iter()
                .map(|(t, a)| (*t as f64 * 1e-9, a[..names.len()].to_vec()))
                .collect();
            bus.with(|t| {
                let picture = report::TrackingPicture {
                    samples: t.plant().samples(),
                    report: &tracking,
                    chosen: &chosen,
                    source: &source,
                };
                draw(&picture, picture.size(), path)
            })?;
            writeln!(
                log,
                "source, commanded and simulated angles drawn in {}",
                path.display()
            )?;
        }
        Ok(Outcome {
            stats: controller.stats,
            end,
            producer,
            port_error: controller.port_error,
        })
    }
}

/// The servos to draw: those named, else the four with the largest RMS.
#[cfg(feature = "sim")]
fn plot_choice(
    names: &[String],
    tracking: &crate::sim::report::TrackingReport,
) -> Result<Vec<usize>, SessionError> {
    if names.is_empty() {
        let mut order: Vec<usize> = (0..tracking.servos.len()).collect();
        order.sort_by(|a, b| {
            tracking.servos[*b]
                .rms_deg
                .total_cmp(&tracking.servos[*a].rms_deg)
        });
        order.truncate(4);
        return Ok(order);
    }
    names
        .iter()
        .map(|n| {
            tracking.servos.iter().position(|s| &s.name == n).ok_or_else(|| {
                SessionError::Invalid(format!("--plot-servos: no servo named `{n}` in the profile"))
            })
        })
        .collect()
}

/// Takes the telemetry until the loop thread ends and, when `print`, shows it as a status line
/// (on a terminal: rewritten in place four times a second; otherwise once a second). Returns
/// whether it printed in place.
fn status_line<T>(
    rx: &crossbeam_channel::Receiver<Telemetry>,
    handle: &JoinHandle<T>,
    period_ns: u64,
    print: bool,
) -> bool {
    let tty = std::io::stderr().is_terminal();
    let every = if tty {
        Duration::from_millis(250)
    } else {
        Duration::from_secs(1)
    };
    let mut window: Vec<Telemetry> = Vec::with_capacity(4096);
    let mut last = Instant::now();
    let (mut ticks, mut misses) = (0u64, 0u64);
    let mut printed = false;
    while !handle.is_finished() {
        // Polled, never waited on: a receiver blocked in the channel would have every tick's
        // send wake it (a futex call in the loop thread, and a wake-up competing for a core).
        std::thread::sleep(Duration::from_millis(20));
        while let Ok(t) = rx.try_recv() {
            // The ramp to rest after the run is not the loop's work.
            if t.stopping {
                continue;
            }
            ticks += 1;
            misses += u64::from(t.missed);
            window.push(t);
        }
        if last.elapsed() < every || window.is_empty() {
            continue;
        }
        let secs = last.elapsed().as_secs_f64();
        last = Instant::now();
        if !print {
            window.clear();
            continue;
        }
        let mut compute: Vec<u64> = window.iter().map(|t| t.compute_ns).collect();
        compute.sort_unstable();
        let p99 = compute[(compute.len() * 99 / 100).min(compute.len() - 1)] as f64 / 1000.0;
        let track: Vec<f64> = window
            .iter()
            .map(|t| t.tracking_rms_deg)
            .filter(|x| x.is_finite())
            .collect();
        let rms = if track.is_empty() {
            f64::NAN
        } else {
            (track.iter().map(|x| x * x).sum::<f64>() / track.len() as f64).sqrt()
        };
        let fails = window.iter().filter(|t| !t.read_ok).count();
        let clip = window.last().map_or(f64::NAN, |t| t.clip_time);
        let hottest = window.last().and_then(|t| t.hottest);
        let line = format!(
            "{:>7.1} Hz  ticks {ticks:>7}  misses {misses:>4}  compute p99 {p99:>7.1} µs ({:.2} % of period)  tracking {rms:>6.3}°  failed reads {fails}{}{}",
            window.len() as f64 / secs,
            p99 * 1e3 / period_ns as f64 * 100.0,
            if clip.is_finite() { format!("  clip {clip:6.2} s") } else { String::new() },
            hottest.map_or(String::new(), |(id, c)| format!("  hottest id {id} {c} °C"))
        );
        // Writes may fail after a hang-up (the terminal closed): the loop goes on to its safe
        // stop regardless.
        let mut err = std::io::stderr();
        let _ = if tty {
            write!(err, "\r{line}")
        } else {
            writeln!(err, "{line}")
        };
        printed = tty;
        window.clear();
    }
    printed
}

/// The names of the left and right sole sites of a profile's retarget map (`None` when a
/// sole is given as a point instead).
#[cfg(feature = "sim")]
fn sole_sites(profile: &Profile) -> Option<[String; 2]> {
    let spec = profile.retarget.as_ref()?;
    let name = |side: usize| match &spec.legs[side].sole_centre {
        crate::profile::PointSpec::Site(n) => Some(n.name.clone()),
        crate::profile::PointSpec::At(_) => None,
    };
    Some([name(0)?, name(1)?])
}
