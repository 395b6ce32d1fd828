//! `marionette play`, `follow` and `targets`: the control loop from the command line.
//!
//! The loop runs in its own thread on the machine clock ([`SystemClock`]: sleep, then spin to
//! the deadline); producers (the clip player, target sources) and the status line run in other
//! threads and talk to it over bounded channels only.

use std::io::{IsTerminal, Write};
use std::net::{SocketAddr, UdpSocket};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use clap::{Args, ValueEnum};

use super::args::{BvhUnit, RoundedHz};
use super::error::CliError;
use super::FrameArg;
use crate::control::live::LiveView;
use crate::control::plot::Histograms;
use crate::control::source::{ClipSource, LineSource, Source, TrackSource, UdpSource};
use crate::control::sources::{
    clip_track, clip_track_pointing, write_csv, ClipPlayer, PlayerCommand, TargetTrack, TrackFrame,
    MAX_DATAGRAM_BYTES,
};
use crate::control::stats::{ClipFigures, RunReport};
use crate::control::{Follower, RunEnd, Solve, StopMode};
use crate::formats::{amc, asf};
use crate::motion::seam::wrap_jump;
use crate::motion::{calibration, Motion};
use crate::plot::{draw, Format};
use crate::profile::Profile;
use crate::retarget::Options as RetargetOptions;
use crate::rt::RealTime;
use crate::session::{self, BusChoice, ImuUse, Lead, Outcome, Session, SessionSpec, SimSpec, Sinks};
use crate::skeleton::Skeleton;

/// What to do when a run ends (end of input, `--duration`, Ctrl-C).
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum OnStop {
    /// Ease to the rest pose over --ramp seconds, then torque off: every joint angle 0 for a
    /// rig of bones; a robot's standing stance (knees bent, soles flat; with --walk, the
    /// plan's last frame, on both feet).
    Rest,
    /// Hold the last command for --ramp seconds, then torque off.
    Hold,
}

/// What `--imu` asks of the robot's IMU board on a walk.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum ImuArg {
    /// Not read: the walk plays open loop.
    Off,
    /// Read every tick, reported in the statistics.
    Read,
    /// Read, and its gyro fed back to the legs.
    Feedback,
}

/// What `--bus` names.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum BusArg {
    /// A virtual servo chain on a pseudo-terminal.
    Virtual,
    /// The MuJoCo simulator in lockstep.
    Sim,
    /// A serial port.
    Port(String),
}

impl std::str::FromStr for BusArg {
    type Err = String;

    fn from_str(s: &str) -> Result<BusArg, String> {
        match s {
            "" => Err("give `virtual`, `sim` or a serial port path".into()),
            "virtual" => Ok(BusArg::Virtual),
            "sim" => Ok(BusArg::Sim),
            port => Ok(BusArg::Port(port.to_string())),
        }
    }
}

/// Seconds the servos spend moving from where they stand to a clip's first frame before the
/// clip starts, at least (without `--pre-roll`, longer when the move needs it).
pub const DEFAULT_PRE_ROLL_S: f64 = 1.0;

/// Options shared by `play` and `follow`.
#[derive(Clone, Debug, Args)]
pub struct LoopArgs {
    /// The bus: `virtual` (a virtual servo chain on a pseudo-terminal, driven through the real
    /// serial code), `sim` (MuJoCo, built with --features sim) or a serial port path.
    #[arg(long, default_value = "virtual")]
    pub bus: BusArg,
    /// Bit rate of a serial port (default: the profile's).
    #[arg(long)]
    pub baud: Option<u32>,
    /// Loop rate, Hz.
    #[arg(long, default_value_t = 120.0)]
    pub rate: f64,
    /// Stop after this many seconds.
    #[arg(long)]
    pub duration: Option<f64>,
    /// Write the statistics as JSON here.
    #[arg(long)]
    pub stats_json: Option<PathBuf>,
    /// Draw the latency histograms (.svg or .png).
    #[arg(long)]
    pub histogram: Option<PathBuf>,
    /// What happens at the end.
    #[arg(long, value_enum, default_value_t = OnStop::Rest)]
    pub on_stop: OnStop,
    /// Seconds of the ramp to rest (or of the hold) at the end.
    #[arg(long, default_value_t = 1.0)]
    pub ramp: f64,
    /// Consecutive failed reads after which the last command sent is held.
    #[arg(long, default_value_t = 3)]
    pub hold_after: u32,
    /// Milliseconds without a valid read after which torque goes off and the run stops.
    #[arg(long, default_value_t = 100.0)]
    pub torque_off_after: f64,
    /// SCHED_FIFO priority of the loop thread (needs CAP_SYS_NICE or an rtprio limit).
    #[arg(long)]
    pub rt_priority: Option<i32>,
    /// Pin the loop thread to this CPU.
    #[arg(long)]
    pub cpu: Option<usize>,
    /// Lock the process's memory (mlockall).
    #[arg(long)]
    pub mlock: bool,
    /// No live status line.
    #[arg(long, short)]
    pub quiet: bool,
    /// With --bus sim: the MJCF model to simulate (default: the puppet generated from the
    /// profile and the ASF skeleton).
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// With --bus sim and a generated puppet: model metres per subject metre.
    #[arg(long, default_value_t = 0.3)]
    pub scale: f64,
    /// With --bus sim: write the tracking report (per servo RMS, max, lag, saturation; per
    /// effector error) as JSON here.
    #[arg(long)]
    pub sim_report: Option<PathBuf>,
    /// With --bus sim and a robot on the floor: write the torso's path, the centre of mass and
    /// the centre of pressure of the floor's forces (the measured ZMP) per sample as CSV.
    #[arg(long)]
    pub sim_trace: Option<PathBuf>,
    /// With --bus sim and a robot on the floor: push its torso, `AT,IMPULSE,DIRECTION` —
    /// at AT simulated seconds, IMPULSE N·s over 0.1 s, towards DIRECTION degrees on the floor
    /// from +x (forward on the OP3) towards +y (its left).
    #[arg(long, value_delimiter = ',', num_args = 1, allow_hyphen_values = true)]
    pub sim_push: Option<Vec<f64>>,
    /// With --bus sim: every simulated servo's joint damping times this, so it follows its goal
    /// more slowly than the profile's model (1.5: 50 % slower).
    #[arg(long, default_value_t = 1.0)]
    pub sim_lag_scale: f64,
    /// With --bus sim: every simulated servo's torque limit times this (0.8: 20 % weaker).
    #[arg(long, default_value_t = 1.0)]
    pub sim_torque_scale: f64,
    /// With --bus sim: every simulated servo starts this warm, °C (from an earlier run); each
    /// heats from the current it draws and cools towards 25 °C (a first-order thermal model).
    #[arg(long, value_name = "CELSIUS")]
    pub sim_servo_temp: Option<f64>,
    /// With --bus sim and a model with an IMU: `SCALE[,SEED]` — its readings with the
    /// OpenCR's MPU-9250 errors times SCALE (1: its specification's zero-rate and zero-g
    /// offsets, 5 °/s and 60 mg, and noise, 0.1 °/s and 3 mg RMS), drawn from SEED (1).
    #[arg(long, value_delimiter = ',', num_args = 1)]
    pub sim_imu_errors: Option<Vec<f64>>,
    /// With --bus sim: draw commanded vs simulated angles and the per-servo RMS (.png or .svg).
    #[arg(long)]
    pub sim_plot: Option<PathBuf>,
    /// Servos drawn by --sim-plot (default: the four with the largest RMS).
    #[arg(long, value_delimiter = ',')]
    pub plot_servos: Vec<String>,
    /// Seconds over which the first commands blend from where the servos stand to the input
    /// (a robot on the floor should not jump into a clip's first pose).
    #[arg(long, default_value_t = 0.0)]
    pub ease_in: f64,
    /// Profiles of robot joints: keep the legs in a standing stance and retarget arms, head
    /// and torso only.
    #[arg(long)]
    pub upper_body: bool,
    /// Profiles of robot joints: do not move the pelvis to keep the centre of mass over the
    /// planted feet.
    #[arg(long)]
    pub no_balance: bool,
    /// Profiles of robot joints, a whole-body clip: walk on the robot's own feet (footsteps
    /// from the clip within its reach and speed, the centre of mass from a ZMP preview
    /// controller, the legs on that plan).
    #[arg(long)]
    pub walk: bool,
    /// With --walk and an IMU board in the profile: `read` reads it every tick (one more
    /// transaction on the bus) and reports what it read; `feedback` also feeds its gyro back to
    /// the legs as ROBOTIS's walking module does (hip roll, knee, ankle pitch and roll).
    #[arg(long, value_enum, default_value_t = ImuArg::Off)]
    pub imu: ImuArg,
    /// Profiles of robot joints: command each servo at its joint's angle, not past it by what
    /// the servo sags under the pose's static load (for a robot on a stand: its feet bear
    /// nothing).
    #[arg(long)]
    pub no_load_compensation: bool,
    /// Do not watch the servos' temperature, supply and hardware errors (by default one servo's
    /// figures are read every few ticks, and a servo near its Temperature Limit, off its supply
    /// range or in a hardware error ends the run: eased to rest, torque off).
    #[arg(long)]
    pub no_health: bool,
    /// Command each tick's target through the greedy limiter instead of planning the goal
    /// path over a preview of the input (the look-ahead).
    #[arg(long)]
    pub no_lookahead: bool,
    /// Take every servo's lag as this many ms instead of the profile's `lag_ms` (the look-ahead
    /// plans the goal that far, and a period, ahead of the source, so the horn arrives on time).
    #[arg(long)]
    pub lead_ms: Option<f64>,
    /// Do not make the next tick's limb solve ahead while the loop waits for its deadline
    /// (by default it is, on a copy of the pose, so that the tick finds the solve's code and
    /// data in the caches: about half the solve's time in the tick, for one solve's CPU a tick).
    #[arg(long)]
    pub no_rehearsal: bool,
    /// The virtual chain answers as soon as it can instead of keeping line time (the wire's
    /// baud, return delays, the adapter's latency): for loop rates beyond what the bus allows.
    #[arg(long)]
    pub no_line_time: bool,
    /// Join ROS 2 in the domain of ROS_DOMAIN_ID (default 0) as the node /marionette and
    /// publish the servos' present positions on /joint_states (sensor_msgs/msg/JointState).
    /// Needs a build with `--features ros2`.
    #[arg(long)]
    pub ros2: bool,
    /// Rate of /joint_states, Hz (each message the newest read; independent of --rate).
    #[arg(long, default_value_t = 100.0)]
    pub ros2_rate: f64,
    /// Message type of the target topics of `follow --targets ros2`.
    #[arg(long, value_enum, default_value_t = Ros2TargetsArg::Point)]
    pub ros2_targets: Ros2TargetsArg,
}

/// `--ros2-targets`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Ros2TargetsArg {
    /// geometry_msgs/msg/PointStamped: a position.
    Point,
    /// geometry_msgs/msg/PoseStamped: a position, and its orientation's +x as the direction of
    /// the bone after the effector (hand, foot).
    Pose,
}

impl LoopArgs {
    /// The session these arguments ask for; `ros2` (`--ros2`, or targets from ROS 2) joins ROS 2
    /// and publishes `/joint_states`, `live` is the studio's view of the loop.
    ///
    /// # Errors
    /// [`CliError::Usage`] for options that do not fit; ROS 2 failing to start.
    pub fn spec(
        &self,
        ros2: bool,
        live: Option<Arc<LiveView>>,
        allocations: Option<fn() -> u64>,
        out: &mut dyn Write,
    ) -> Result<SessionSpec, CliError> {
        for (option, picture) in [("--sim-plot", &self.sim_plot), ("--histogram", &self.histogram)] {
            if let Some(Err(e)) = picture.as_deref().map(Format::of) {
                return Err(CliError::Usage(format!("{option} {e}")));
            }
        }
        if self.no_lookahead && self.lead_ms.is_some() {
            return Err(CliError::Usage(
                "--lead-ms needs the look-ahead: leave out --no-lookahead".into(),
            ));
        }
        if let Some(p) = &self.sim_push {
            if self.bus != BusArg::Sim {
                return Err(CliError::Usage(
                    "--sim-push pushes the simulated robot: give --bus sim".into(),
                ));
            }
            if !(p.len() == 3 && p.iter().all(|v| v.is_finite()) && p[0] >= 0.0 && p[1] >= 0.0) {
                return Err(CliError::Usage(
                    "--sim-push takes AT,IMPULSE,DIRECTION: seconds ≥ 0, N·s ≥ 0, degrees".into(),
                ));
            }
        }
        if let Some(c) = self.sim_servo_temp {
            if self.bus != BusArg::Sim {
                return Err(CliError::Usage(
                    "--sim-servo-temp warms the simulated servos: give --bus sim".into(),
                ));
            }
            if !(c.is_finite() && (0.0..=100.0).contains(&c)) {
                return Err(CliError::Usage(format!(
                    "--sim-servo-temp takes 0…100 °C, got {c}"
                )));
            }
        }
        for (option, value) in [
            ("--sim-lag-scale", self.sim_lag_scale),
            ("--sim-torque-scale", self.sim_torque_scale),
        ] {
            if value != 1.0 && self.bus != BusArg::Sim {
                return Err(CliError::Usage(format!(
                    "{option} changes the simulated servos: give --bus sim"
                )));
            }
            if !(value.is_finite() && value > 0.0 && value <= 10.0) {
                return Err(CliError::Usage(format!(
                    "{option} takes a factor above 0 and at most 10, got {value}"
                )));
            }
        }
        let imu_errors = match self.sim_imu_errors.as_deref() {
            None => None,
            Some(_) if self.bus != BusArg::Sim => {
                return Err(CliError::Usage(
                    "--sim-imu-errors changes the simulated IMU: give --bus sim".into(),
                ))
            }
            Some(&[scale]) if scale.is_finite() && scale >= 0.0 => Some((scale, 1)),
            Some(&[scale, seed])
                if scale.is_finite() && scale >= 0.0 && seed >= 0.0 && seed.fract() == 0.0 && seed < 1e15 =>
            {
                Some((scale, seed as u64))
            }
            Some(_) => {
                return Err(CliError::Usage(
                    "--sim-imu-errors takes SCALE[,SEED]: a scale ≥ 0 and a whole seed ≥ 0".into(),
                ))
            }
        };
        let mut spec = SessionSpec {
            rate_hz: self.rate,
            duration_s: self.duration,
            bus: match &self.bus {
                BusArg::Virtual => BusChoice::Virtual {
                    line_time: !self.no_line_time,
                },
                BusArg::Sim => BusChoice::Sim,
                BusArg::Port(p) => BusChoice::Port(p.clone()),
            },
            baud: self.baud,
            stop: match self.on_stop {
                OnStop::Rest => StopMode::Rest { ramp_s: self.ramp },
                OnStop::Hold => StopMode::Hold { hold_s: self.ramp },
            },
            hold_after: self.hold_after,
            torque_off_after_ms: self.torque_off_after,
            ease_in_s: self.ease_in,
            clip_start_s: 0.0,
            size_start_move: false,
            lead: match (self.no_lookahead, self.lead_ms) {
                (true, _) => Lead::Off,
                (false, Some(ms)) => Lead::Fixed(ms),
                (false, None) => Lead::Profile,
            },
            retarget: RetargetOptions {
                upper_body: self.upper_body,
                balance: !self.no_balance,
                per_frame: false,
            },
            walk: self.walk,
            load_compensation: !self.no_load_compensation,
            rehearse: !self.no_rehearsal,
            health: !self.no_health,
            imu: match self.imu {
                ImuArg::Off => ImuUse::Off,
                ImuArg::Read => ImuUse::Read,
                ImuArg::Feedback => ImuUse::Feedback,
            },
            scale: self.scale,
            real_time: RealTime {
                priority: self.rt_priority,
                cpu: self.cpu,
                lock_memory: self.mlock,
            },
            sim: SimSpec {
                model: self.model.clone(),
                report: self.sim_report.clone(),
                plot: self.sim_plot.clone(),
                plot_servos: self.plot_servos.clone(),
                trace: self.sim_trace.clone(),
                push: self.sim_push.as_deref().map(|p| [p[0], p[1], p[2]]),
                lag_scale: self.sim_lag_scale,
                torque_scale: self.sim_torque_scale,
                servo_temp_c: self.sim_servo_temp,
                imu_errors,
            },
            sinks: Sinks {
                status_line: !self.quiet,
                live,
                ros2: None,
            },
            allocations,
        };
        // The figures first, then ROS 2 (which starts DDS).
        spec.check()?;
        if ros2 || self.ros2 {
            let node = session::ros2::node(out)?;
            spec.sinks.ros2 = Some((node, self.ros2_rate));
            spec.check()?;
        }
        Ok(spec)
    }
}

/// `follow` adds nothing to the [`RunReport`].
#[derive(serde::Serialize)]
pub(super) struct NoFigures {}

pub(super) fn finish(
    outcome: &Outcome,
    args: &LoopArgs,
    extra: impl serde::Serialize,
    out: &mut dyn Write,
) -> Result<(), CliError> {
    let end = match outcome.end {
        RunEnd::InputEnded => "end of input",
        RunEnd::Duration => "duration reached",
        RunEnd::Interrupted => "interrupted",
        RunEnd::ReadsFailed => "reads failed",
        RunEnd::PortLost => "port lost",
        RunEnd::Health => "servo health",
    };
    // Files first: after a hang-up (the terminal closed) printing may fail, the files not.
    let mut written = Vec::new();
    if let Some(path) = &args.stats_json {
        let report = RunReport {
            stats: outcome.stats.report(),
            end,
            inputs_produced: outcome.producer.sent,
            inputs_dropped_by_producer: outcome.producer.dropped,
            bad_input_lines: outcome.producer.bad_lines,
            oversized_datagrams: outcome.producer.oversized,
            extra,
        };
        let text = serde_json::to_string_pretty(&report)?;
        std::fs::write(path, text + "\n").map_err(|e| crate::formats::FileError::io(path, e))?;
        written.push(format!("statistics written to {}", path.display()));
    }
    if let Some(path) = &args.histogram {
        draw(&Histograms(&outcome.stats), Histograms::SIZE, path)?;
        written.push(format!("histograms drawn in {}", path.display()));
    }
    writeln!(out, "{}", outcome.stats)?;
    let servos = outcome.stats.torque_off_acknowledged;
    match outcome.end {
        RunEnd::PortLost => writeln!(out, "ended: {end}; one torque-off Sync Write tried")?,
        _ => writeln!(
            out,
            "ended: {end}; torque off, acknowledged by {} servos",
            servos.unwrap_or(0)
        )?,
    }
    if let Some(h) = &outcome.stats.health {
        for w in &h.warnings {
            writeln!(out, "health warning: {w}")?;
        }
    }
    for line in written {
        writeln!(out, "{line}")?;
    }
    match outcome.end {
        RunEnd::Health => {
            let health = outcome.stats.health.as_ref();
            Err(CliError::ServoHealth {
                why: health
                    .and_then(|h| h.stopped.clone())
                    .unwrap_or_else(|| "a servo's health".into()),
                hardware_error: health.is_some_and(|h| h.servos.iter().any(|s| s.hardware_error != 0)),
            })
        }
        RunEnd::ReadsFailed => Err(CliError::ServosSilent {
            ms: args.torque_off_after,
        }),
        RunEnd::PortLost => Err(CliError::PortLost {
            port: match &args.bus {
                BusArg::Port(p) => p.clone(),
                BusArg::Virtual => "the virtual chain".into(),
                BusArg::Sim => "the simulator".into(),
            },
            reason: outcome
                .port_error
                .as_ref()
                .map_or_else(|| "I/O error".to_string(), ToString::to_string),
        }),
        _ => Ok(()),
    }
}

/// `marionette play`.
///
/// # Errors
/// [`CliError`].
fn play_cmd(a: &PlayArgs, allocations: Option<fn() -> u64>, out: &mut dyn Write) -> Result<(), CliError> {
    let (profile_path, asf_path, args) = (&a.profile, &a.asf, &a.loop_args);
    // The clip's file: the AMC, or the BVH that holds skeleton and motion.
    let amc_path = a.amc.as_ref().unwrap_or(asf_path);
    let (looping, speed, start_at, pre_roll) = (a.looping, a.speed, a.start, a.pre_roll);
    if !(speed.is_finite() && speed > 0.0) {
        return Err(CliError::Usage("--speed must be a positive number".into()));
    }
    if pre_roll.is_some_and(|p| !(p.is_finite() && (0.0..=60.0).contains(&p))) {
        return Err(CliError::Usage(
            "--pre-roll must be between 0 and 60 seconds".into(),
        ));
    }
    let profile = Profile::load(profile_path)?;
    let pre_roll = pre_roll.unwrap_or(DEFAULT_PRE_ROLL_S);
    // A loaded motion has at least one frame.
    let (skeleton, mut motion) = if a.amc.is_none() {
        super::retarget::load_clip(asf_path, None, 0.0, a.bvh_unit)?
    } else {
        let skeleton = asf::load(asf_path)?.skeleton;
        let motion = amc::load(&skeleton, amc_path)?;
        (skeleton, motion)
    };
    let skeleton = Arc::new(skeleton);
    clean_clip(
        &skeleton,
        &mut motion,
        KeepAsRecorded {
            first_frame: a.keep_first_frame,
            dropouts: a.keep_dropouts,
        },
        &amc_path.display(),
        ("played", "plays"),
        out,
    )?;
    if looping {
        warn_if_not_a_cycle(&skeleton, &motion, out)?;
    }
    if args.walk && !args.upper_body {
        motion = crate::retarget::walk::settled(&motion);
        writeln!(
            out,
            "walking: the last frame held {} s after the clip while the robot comes to rest",
            crate::retarget::walk::SETTLE_S
        )?;
    }
    let motion = Arc::new(motion);
    if !(start_at.is_finite() && (0.0..=motion.duration()).contains(&start_at)) {
        return Err(CliError::Usage(format!(
            "--start must be within the clip's 0…{:.3} s",
            motion.duration()
        )));
    }
    let mut spec = args.spec(false, None, allocations, out)?;
    spec.clip_start_s = start_at;
    // Without a --pre-roll, one long enough for the servos' move to the first pose.
    spec.size_start_move = a.pre_roll.is_none();
    // The move to the first frame is eased in from where the servos stand.
    if pre_roll > 0.0 && spec.ease_in_s == 0.0 {
        spec.ease_in_s = pre_roll;
    }
    let mut player = ClipPlayer::new(Arc::clone(&skeleton), Arc::clone(&motion), args.rate, looping);
    player.control(PlayerCommand::Speed(speed));
    player.control(PlayerCommand::Seek(start_at));
    player.set_pre_roll(pre_roll);
    // The pre-roll's samples come first: the first pass is that much longer.
    let pre_roll_samples = player.pre_roll_samples();
    let pass = player.samples_per_pass();
    writeln!(
        out,
        "{}: {} frames at {} Hz ({:.2} s) → {} samples a pass at {} Hz{}{}",
        amc_path.display(),
        motion.len(),
        RoundedHz(motion.frame_rate),
        motion.duration(),
        player.samples_per_pass(),
        args.rate,
        if pre_roll_samples > 0 {
            format!(", after {pre_roll_samples} on its first frame ({pre_roll} s pre-roll)")
        } else {
            String::new()
        },
        if looping { ", looping" } else { "" }
    )?;
    // Keys on a terminal steer a run in real time; a simulated run plays the clip as given.
    let commands = if args.bus == BusArg::Sim {
        None
    } else {
        keyboard_commands(out)?
    };
    let source = Box::new(ClipSource::new(player, commands));
    let outcome = Session::new(spec)?.run(&profile, skeleton, Solve::Frames, Some(&motion), source, out)?;
    let all = outcome.producer.sent == outcome.stats.inputs_used;
    writeln!(
        out,
        "samples: {} produced, {} used by the loop{}",
        outcome.producer.sent,
        outcome.stats.inputs_used,
        if all {
            " — every sample sent to the servos"
        } else {
            ""
        }
    )?;
    let figures = ClipFigures {
        clip_frames: motion.len(),
        // The first pass with its pre-roll, as long as the move to the first pose made it.
        samples_per_pass: pass + outcome.producer.pre_roll,
        all_samples_sent: all,
    };
    finish(&outcome, args, figures, out)
}

/// Player commands typed on a terminal: `p` pause/resume, `s SECONDS` seek, `x SPEED` speed.
fn keyboard_commands(
    out: &mut dyn Write,
) -> Result<Option<crossbeam_channel::Receiver<PlayerCommand>>, CliError> {
    if !std::io::stdin().is_terminal() {
        return Ok(None);
    }
    writeln!(
        out,
        "keys (then Enter): p pause/resume · s SECONDS seek · x SPEED speed · Ctrl-C stop"
    )?;
    let (tx, rx) = crossbeam_channel::bounded(16);
    std::thread::Builder::new()
        .name("keyboard".into())
        .spawn(move || {
            for line in std::io::stdin().lines().map_while(Result::ok) {
                let mut w = line.split_whitespace();
                let cmd = match (w.next(), w.next().and_then(|x| x.parse::<f64>().ok())) {
                    (Some("p"), _) => PlayerCommand::Toggle,
                    (Some("s"), Some(t)) => PlayerCommand::Seek(t),
                    (Some("x"), Some(s)) => PlayerCommand::Speed(s),
                    _ => continue,
                };
                if tx.send(cmd).is_err() {
                    break;
                }
            }
        })
        .map_err(CliError::Output)?;
    Ok(Some(rx))
}

/// The source `spec` names for `effectors` (`-` stdin, `udp://ADDR`, a file) and the line
/// that says so; `ros2` is made once the session's node exists. A UDP address off loopback only
/// when `any_host` says so.
fn target_source(
    spec: &str,
    effectors: &[String],
    any_host: bool,
    looping: bool,
) -> Result<(Box<dyn Source>, String), CliError> {
    let list = effectors.join(", ");
    if spec == "-" {
        let line = format!("reading target lines from stdin for {list}");
        return Ok((Box::new(LineSource::stdin(effectors.to_vec())), line));
    }
    if let Some(addr) = spec.strip_prefix("udp://") {
        let addr: SocketAddr = addr
            .parse()
            .map_err(|_| CliError::Usage(format!("--targets {spec}: expected udp://127.0.0.1:PORT")))?;
        if !addr.ip().is_loopback() && !any_host {
            return Err(CliError::Usage(format!(
                "--targets {spec}: targets move servos, so only a loopback address is taken unless --targets-from-network says otherwise"
            )));
        }
        let socket = UdpSocket::bind(addr).map_err(CliError::at_port(&format!("--targets {spec}")))?;
        let source = UdpSource::new(socket, effectors.to_vec()).map_err(CliError::Output)?;
        let local = source.local_addr().ok();
        let mut line = format!(
            "listening for target lines on udp://{} for {list}",
            local.map_or_else(|| spec.to_string(), |a| a.to_string())
        );
        if local.is_some_and(|a| !a.ip().is_loopback()) {
            line += &format!(
                "\nwarning: not loopback: any host that reaches this port moves the servos (no authentication; datagrams over {MAX_DATAGRAM_BYTES} bytes refused)"
            );
        }
        return Ok((Box::new(source), line));
    }
    let track = TargetTrack::load(Path::new(spec), effectors)?;
    let mut line = format!(
        "{spec}: {} samples over {:.2} s for {list}{}",
        track.samples.len(),
        track.duration(),
        if looping { ", looping" } else { "" }
    );
    if let Some(jump) = track.wrap_jump().filter(|j| looping && !j.is_seamless()) {
        line += &format!(
            "\nwarning: --loop: the targets are not a cycle: from the last sample to the first, {}'s target moves {:.3} units (from one sample to the next, {:.4} at the 99th percentile); each pass starts with that jump, as fast as the servos' limits allow",
            effectors.get(jump.effector).map_or("an effector", String::as_str),
            jump.distance,
            jump.effector_p99
        );
    }
    Ok((Box::new(TrackSource::new(track, looping)), line))
}

/// Says so when a clip played over and over jumps at each start: its last frame is not close
/// to its first ([`wrap_jump`]).
fn warn_if_not_a_cycle(skeleton: &Skeleton, motion: &Motion, out: &mut dyn Write) -> Result<(), CliError> {
    let Some(jump) = wrap_jump(skeleton, motion).filter(|j| !j.is_seamless()) else {
        return Ok(());
    };
    writeln!(
        out,
        "warning: --loop: the clip is not a cycle: from its last frame to its first, `{}` turns {:.0}° (from one frame to the next, {:.1}° at the 99th percentile); each pass starts with that jump, as fast as the servos' limits allow (`marionette loop` makes a seamless cycle)",
        skeleton.bones().get(jump.bone).map_or("root", |b| b.name()),
        jump.rotation.to_degrees(),
        jump.bone_p99.to_degrees()
    )?;
    Ok(())
}

/// What a command takes from a clip as recorded instead of cleaning it.
#[derive(Clone, Copy, Debug)]
pub(super) struct KeepAsRecorded {
    /// A converter's calibration pose written as the first frame ([`calibration`]).
    pub first_frame: bool,
    /// Capture dropouts ([`crate::motion::dropouts`]).
    pub dropouts: bool,
}

/// Cleans a clip for driving a rig: leaves out a first frame that is a converter's calibration
/// pose, then fills capture dropouts (a bone, or the root, reading exactly zero between
/// far-away frames) from their neighbours; what `keep` names is only found. Says each on `out`
/// as `clip`'s, with what the command does with it (`done`: "played", `does`: "plays").
pub(super) fn clean_clip(
    skeleton: &Skeleton,
    motion: &mut Motion,
    keep: KeepAsRecorded,
    clip: &dyn std::fmt::Display,
    (done, does): (&str, &str),
    out: &mut dyn Write,
) -> std::io::Result<()> {
    if keep.first_frame {
        if let Some(pose) = calibration::first_frame(skeleton, motion) {
            writeln!(out, "{clip}: {pose}; {done} as recorded")?;
        }
    } else if let Some(pose) = calibration::leave_out(skeleton, motion) {
        writeln!(out, "{clip}: {pose}; left out (--keep-first-frame {does} it)")?;
    }
    let dropouts = if keep.dropouts {
        crate::motion::dropouts::find(skeleton, motion)
    } else {
        crate::motion::dropouts::repair(skeleton, motion)
    };
    for d in &dropouts {
        if keep.dropouts {
            writeln!(out, "{clip}: capture dropout: {d}; {done} as recorded")?;
        } else {
            writeln!(
                out,
                "{clip}: capture dropout: {d}; filled from its neighbours (--keep-dropouts {does} it as recorded)"
            )?;
        }
    }
    Ok(())
}

/// `marionette follow`.
///
/// # Errors
/// [`CliError`].
fn follow_cmd(a: &FollowArgs, allocations: Option<fn() -> u64>, out: &mut dyn Write) -> Result<(), CliError> {
    let (profile_path, asf_path, targets, effectors, args) = (
        &a.profile,
        &a.asf,
        a.targets.as_str(),
        &a.effectors[..],
        &a.loop_args,
    );
    let (targets_from_network, looping) = (a.targets_from_network, a.looping);
    let profile = Profile::load(profile_path)?;
    let skeleton = Arc::new(asf::load(asf_path)?.skeleton);
    let follower =
        Follower::new(&skeleton, effectors).map_err(|e| CliError::Usage(format!("--effectors: {e}")))?;
    let from_ros2 = targets == "ros2";
    if looping && args.bus == BusArg::Sim && !from_ros2 && targets != "-" && !targets.starts_with("udp://") {
        return Err(CliError::Usage(
            "--loop with --bus sim would never end: give --duration instead of looping a simulated run"
                .into(),
        ));
    }
    let mut spec = args.spec(from_ros2, None, allocations, out)?;
    // The first targets' pose is known once they are solved: the loop sizes the move to it.
    spec.size_start_move = true;
    let source = match (&spec.sinks.ros2, from_ros2) {
        (Some((node, _)), true) => {
            let root = skeleton
                .bones()
                .first()
                .map_or_else(String::new, |b| b.name().to_string());
            let metres_per_unit = args.scale * f64::from(skeleton.units().meters_per_unit());
            let (kind, name) = match args.ros2_targets {
                Ros2TargetsArg::Point => (session::Ros2Targets::Point, "geometry_msgs/msg/PointStamped"),
                Ros2TargetsArg::Pose => (session::Ros2Targets::Pose, "geometry_msgs/msg/PoseStamped"),
            };
            writeln!(
                out,
                "ros2: targets on /marionette/targets/{{{}}} ({name}, metres on the rig, frame '{root}')",
                effectors.join(",")
            )?;
            session::ros2::targets(node, effectors, &root, kind, metres_per_unit)?
        }
        _ => {
            let (source, line) = target_source(targets, effectors, targets_from_network, looping)?;
            writeln!(out, "{line}")?;
            source
        }
    };
    let outcome = Session::new(spec)?.run(
        &profile,
        skeleton,
        Solve::Follow(Box::new(follower)),
        None,
        source,
        out,
    )?;
    writeln!(
        out,
        "targets: {} messages produced ({} dropped for newer, {} unreadable lines{}), {} used by the loop, {} refused by it",
        outcome.producer.sent,
        outcome.producer.dropped,
        outcome.producer.bad_lines,
        if outcome.producer.oversized > 0 {
            format!(", {} datagrams over {MAX_DATAGRAM_BYTES} bytes", outcome.producer.oversized)
        } else {
            String::new()
        },
        outcome.stats.inputs_used,
        outcome.stats.inputs_rejected
    )?;
    finish(&outcome, args, NoFigures {}, out)
}

/// Output format of `targets`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum TargetFormat {
    /// `t,effector,x,y,z` lines.
    Csv,
    /// One JSON object per line.
    Jsonl,
}

/// `marionette targets`: effector paths of a clip as a target file.
///
/// # Errors
/// [`CliError`].
fn targets_cmd(a: &TargetsArgs, out: &mut dyn Write) -> Result<(), CliError> {
    let (asf_path, amc_path, effectors, output) = (&a.asf, &a.amc, &a.effectors[..], &a.output);
    let (format, directions) = (a.format, a.directions);
    let frame = match a.frame {
        FrameArg::Limb => TrackFrame::Limb,
        FrameArg::Root => TrackFrame::Root,
    };
    let skeleton = asf::load(asf_path)?.skeleton;
    let mut motion = amc::load(&skeleton, amc_path)?;
    clean_clip(
        &skeleton,
        &mut motion,
        KeepAsRecorded {
            first_frame: a.keep_first_frame,
            dropouts: a.keep_dropouts,
        },
        &amc_path.display(),
        ("written", "writes"),
        out,
    )?;
    let track = if directions {
        clip_track_pointing(&skeleton, &motion, effectors, frame)
    } else {
        clip_track(&skeleton, &motion, effectors, frame)
    }
    .map_err(|e| CliError::Usage(format!("--effectors: {e}")))?;
    let mut text = Vec::new();
    match format {
        TargetFormat::Csv => write_csv(&track, effectors, &mut text)?,
        TargetFormat::Jsonl => {
            for (t, targets) in &track.samples {
                let list: Vec<serde_json::Value> = targets
                    .iter()
                    .map(|x| {
                        let mut o = serde_json::json!({
                            "effector": effectors[x.effector],
                            "position": [x.position.x, x.position.y, x.position.z],
                        });
                        if let Some(d) = x.direction {
                            o["direction"] = serde_json::json!([d.x, d.y, d.z]);
                        }
                        o
                    })
                    .collect();
                writeln!(text, "{}", serde_json::json!({ "t": t, "targets": list }))?;
            }
        }
    }
    std::fs::write(output, text).map_err(|e| crate::formats::FileError::io(output, e))?;
    writeln!(
        out,
        "{}: {} samples of {} ({:?} frame) written to {}",
        amc_path.display(),
        track.samples.len(),
        effectors.join(", "),
        frame,
        output.display()
    )?;
    Ok(())
}

/// The arguments of `marionette play`.
#[derive(Debug, Args)]
pub(super) struct PlayArgs {
    /// The rig profile, e.g. firmware-profile/cmu-puppet.toml.
    pub(super) profile: PathBuf,
    /// Skeleton (.asf), or a .bvh file (skeleton and motion).
    pub(super) asf: PathBuf,
    /// Clip (.amc); none with a .bvh file.
    pub(super) amc: Option<PathBuf>,
    /// Length unit of a .bvh file.
    #[arg(long, value_enum, default_value_t = BvhUnit::Cm)]
    pub(super) bvh_unit: BvhUnit,
    /// Start over at the end of the clip (stop with Ctrl-C or --duration).
    #[arg(long = "loop")]
    pub(super) looping: bool,
    /// Playback speed (1 = as captured).
    #[arg(long, default_value_t = 1.0)]
    pub(super) speed: f64,
    /// Clip time to start at, seconds.
    #[arg(long, default_value_t = 0.0)]
    pub(super) start: f64,
    /// Seconds to move to the clip's first frame before it starts (eased in from where the
    /// servos stand, unless --ease-in says otherwise); not counted in the fidelity. 0: the
    /// clip starts at once, from wherever the servos stand (each servo's speed and
    /// acceleration limits still apply). Default: 1 s, or longer when the servos stand further
    /// from the first frame than a quarter of their speed covers in it.
    #[arg(long)]
    pub(super) pre_roll: Option<f64>,
    /// Play capture dropouts (a bone reading exactly zero between far-away frames) as
    /// recorded instead of filling them from their neighbours.
    #[arg(long)]
    pub(super) keep_dropouts: bool,
    /// Play a first frame that is a converter's calibration pose (the T-pose that CMU's BVH
    /// conversions write before the capture) instead of leaving it out.
    #[arg(long)]
    pub(super) keep_first_frame: bool,
    #[command(flatten)]
    pub(super) loop_args: LoopArgs,
}

impl PlayArgs {
    /// Runs it.
    ///
    /// # Errors
    /// [`CliError`].
    pub(super) fn run(self, allocations: Option<fn() -> u64>) -> Result<(), CliError> {
        play_cmd(&self, allocations, &mut std::io::stdout().lock())
    }
}

/// The arguments of `marionette follow`.
#[derive(Debug, Args)]
pub(super) struct FollowArgs {
    /// The rig profile.
    pub(super) profile: PathBuf,
    /// Skeleton (.asf).
    pub(super) asf: PathBuf,
    /// Targets: a CSV or JSON-lines file, `-` for stdin, udp://127.0.0.1:PORT, or `ros2`
    /// (the topics /marionette/targets/<effector>, metres on the rig in the root's frame;
    /// implies --ros2).
    #[arg(long)]
    pub(super) targets: String,
    /// Take UDP targets on an address other than loopback (then any host that reaches the
    /// port moves the servos: a trusted network only).
    #[arg(long)]
    pub(super) targets_from_network: bool,
    /// The effector bones (their tips follow the targets).
    #[arg(long, value_delimiter = ',', default_value = "lradius,rradius,ltibia,rtibia")]
    pub(super) effectors: Vec<String>,
    /// Start a target file over at its end.
    #[arg(long = "loop")]
    pub(super) looping: bool,
    #[command(flatten)]
    pub(super) loop_args: LoopArgs,
}

impl FollowArgs {
    /// Runs it.
    ///
    /// # Errors
    /// [`CliError`].
    pub(super) fn run(self, allocations: Option<fn() -> u64>) -> Result<(), CliError> {
        follow_cmd(&self, allocations, &mut std::io::stdout().lock())
    }
}

/// The arguments of `marionette targets`.
#[derive(Debug, Args)]
pub(super) struct TargetsArgs {
    /// Skeleton (.asf).
    pub(super) asf: PathBuf,
    /// Clip (.amc).
    pub(super) amc: PathBuf,
    /// The effector bones.
    #[arg(long, value_delimiter = ',', default_value = "lradius,rradius,ltibia,rtibia")]
    pub(super) effectors: Vec<String>,
    /// limb: each path relative to its limb's parent bone, placed on the rest pose (what a
    /// rig with its other joints at rest can reach); root: as captured, in the root's frame.
    #[arg(long, value_enum, default_value_t = FrameArg::Limb)]
    pub(super) frame: FrameArg,
    /// File format.
    #[arg(long, value_enum, default_value_t = TargetFormat::Csv)]
    pub(super) format: TargetFormat,
    /// Add each target's pointing direction: the captured direction of the bone after the
    /// effector (the hand, the foot), which `follow` turns that bone to.
    #[arg(long)]
    pub(super) directions: bool,
    /// Write capture dropouts (a bone reading exactly zero between far-away frames) as
    /// recorded instead of filling them from their neighbours.
    #[arg(long)]
    pub(super) keep_dropouts: bool,
    /// Write a first frame that is a converter's calibration pose (a T-pose written before
    /// the capture) instead of leaving it out.
    #[arg(long)]
    pub(super) keep_first_frame: bool,
    /// Output file.
    #[arg(short, long)]
    pub(super) output: PathBuf,
}

impl TargetsArgs {
    /// Runs it.
    ///
    /// # Errors
    /// [`CliError`].
    pub(super) fn run(self) -> Result<(), CliError> {
        targets_cmd(&self, &mut std::io::stdout().lock())
    }
}
