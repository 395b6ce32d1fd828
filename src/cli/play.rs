//! `marionette play`, `follow` and `targets`: the control loop from the command line.
//!
//! The loop runs in its own thread on the machine clock ([`SystemClock`]: sleep, then spin to
//! the deadline); producers (the clip player, target sources) and the status line run in other
//! threads and talk to it over bounded channels only.

use std::io::{IsTerminal, Write};
use std::net::{SocketAddr, UdpSocket};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use clap::{Args, ValueEnum};

use super::error::CliError;
use crate::budget::plan;
use crate::bus::start_up;
use crate::bus::virtual_chain::{chain_for, PtyChain};
use crate::clock::SystemClock;
use crate::control::input::{input_channel, InputPort, InputSender};
use crate::control::lockstep::{LockstepSource, PlayerFeed, TrackFeed};
use crate::control::lookahead::{Lookahead, LookaheadSettings};
use crate::control::plot::Histograms;
use crate::control::sources::{
    clip_track, clip_track_pointing, spawn_player, spawn_stdin, spawn_track, spawn_udp, write_csv,
    ClipPlayer, PlayerCommand, ProducerReport, TargetTrack, TrackFrame, MAX_DATAGRAM_BYTES,
};
use crate::control::stats::{ClipFigures, LoopStats, RunReport};
use crate::control::{
    Controller, Follower, LoopConfig, RetargetStage, RunEnd, Solve, StopMode, StopRequests, Telemetry,
};
use crate::formats::{amc, asf};
use crate::motion::Motion;
use crate::plot::{draw, Format};
use crate::profile::Profile;
use crate::retarget::{floor_of_clip, floor_of_rest, Options as RetargetOptions, Setup};
use crate::rt::RealTime;
use crate::schedule::{Clock, Schedule};
use crate::skeleton::Skeleton;

/// Messages an input channel holds: paced producers run up to `LEAD_NS` (10 ms) ahead, which
/// is 10 ticks at 1 kHz.
const INPUT_CAPACITY: usize = 16;

/// What to do when a run ends (end of input, `--duration`, Ctrl-C).
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum OnStop {
    /// Ease to the rest pose (all joint angles 0) over --ramp seconds, then torque off.
    Rest,
    /// Hold the last command for --ramp seconds, then torque off.
    Hold,
}

/// `--bus sim` with stdin or UDP targets.
const SIM_TAKES_NO_LIVE_INPUT: &str = "--bus sim runs in simulated time: it takes a clip or a target file, not live input (stdin, UDP); serve the simulator on a pseudo-terminal instead (`marionette sim serve`)";

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

/// Seconds a rig of bones spends moving to a clip's first frame before the clip starts.
pub const DEFAULT_PRE_ROLL_S: f64 = 1.0;

/// How `play` plays its clip.
#[derive(Clone, Copy, Debug)]
pub struct Playback {
    /// Start over at the end.
    pub looping: bool,
    /// Playback speed (1 = as captured).
    pub speed: f64,
    /// Clip time to start at, seconds.
    pub start: f64,
    /// Seconds on the first frame before the clip starts (`None`: 1 s for a rig of bones, 0
    /// for a retargeted robot).
    pub pre_roll: Option<f64>,
    /// Play capture dropouts as recorded.
    pub keep_dropouts: bool,
}

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
    /// Command each tick's target through the greedy limiter instead of planning the goal
    /// path over a preview of the input (the look-ahead).
    #[arg(long)]
    pub no_lookahead: bool,
    /// Take every servo's lag as this many ms instead of the profile's `lag_ms` (the look-ahead
    /// plans the goal that far, and a period, ahead of the source, so the horn arrives on time).
    #[arg(long)]
    pub lead_ms: Option<f64>,
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
    #[arg(long, value_enum, default_value_t = super::ros2::Ros2Targets::Point)]
    pub ros2_targets: super::ros2::Ros2Targets,
    /// Where the loop publishes its goals, present angles and timing (the studio).
    #[arg(skip)]
    pub live: Option<Arc<crate::control::live::LiveView>>,
    /// The run's ROS 2 node, when a target source made it before the loop.
    #[arg(skip)]
    pub ros2_node: Option<super::ros2::Ros2Handle>,
}

/// The opened bus: the virtual chain (kept alive while the bus is used) or a port.
struct OpenBus {
    bus: Box<dyn crate::bus::ServoBus + Send>,
    _chain: Option<PtyChain>,
    label: String,
}

fn check(args: &LoopArgs) -> Result<(), CliError> {
    if !(args.rate.is_finite() && (1.0..=2000.0).contains(&args.rate)) {
        return Err(CliError::Usage(format!(
            "--rate must be between 1 and 2000 Hz, got {}",
            args.rate
        )));
    }
    if args.duration.is_some_and(|d| !(d.is_finite() && d > 0.0)) {
        return Err(CliError::Usage(
            "--duration must be a positive number of seconds".into(),
        ));
    }
    if !(args.ease_in.is_finite() && (0.0..=60.0).contains(&args.ease_in)) {
        return Err(CliError::Usage(
            "--ease-in must be between 0 and 60 seconds".into(),
        ));
    }
    if !(args.ramp.is_finite() && (0.0..=60.0).contains(&args.ramp)) {
        return Err(CliError::Usage("--ramp must be between 0 and 60 seconds".into()));
    }
    if !(args.torque_off_after.is_finite() && args.torque_off_after > 0.0) {
        return Err(CliError::Usage(
            "--torque-off-after must be a positive number of ms".into(),
        ));
    }
    for (option, picture) in [("--sim-plot", &args.sim_plot), ("--histogram", &args.histogram)] {
        if let Some(Err(e)) = picture.as_deref().map(Format::of) {
            return Err(CliError::Usage(format!("{option} {e}")));
        }
    }
    if !(args.ros2_rate.is_finite() && (0.1..=1000.0).contains(&args.ros2_rate)) {
        return Err(CliError::Usage(format!(
            "--ros2-rate must be between 0.1 and 1000 Hz, got {}",
            args.ros2_rate
        )));
    }
    if args.hold_after == 0 {
        return Err(CliError::Usage("--hold-after must be at least 1".into()));
    }
    if args
        .lead_ms
        .is_some_and(|l| !(l.is_finite() && (0.0..=1000.0).contains(&l)))
    {
        return Err(CliError::Usage("--lead-ms must be between 0 and 1000".into()));
    }
    if args.no_lookahead && args.lead_ms.is_some() {
        return Err(CliError::Usage(
            "--lead-ms needs the look-ahead: leave out --no-lookahead".into(),
        ));
    }
    Ok(())
}

/// Messages an input channel holds: a few ticks, plus the look-ahead's longest preview (a
/// lead of up to a second and the window) so that a lockstep feed never drops one.
pub(super) fn input_capacity(rate_hz: f64) -> usize {
    INPUT_CAPACITY + (1.25 * rate_hz).ceil() as usize
}

/// The look-ahead of a run (none with `--no-lookahead`): each servo led by its own lag
/// (`--lead-ms`, else the profile's `lag_ms`) and the loop's period (a goal written now is read
/// back a tick later).
fn lookahead(args: &LoopArgs, profile: &Profile, rig: &crate::rig::Rig) -> Option<Lookahead> {
    if args.no_lookahead {
        return None;
    }
    let leads: Vec<f64> = profile
        .servos
        .iter()
        .map(|s| args.lead_ms.or(s.lag_ms).unwrap_or(0.0) * 1e-3 + 1.0 / args.rate)
        .collect();
    Some(Lookahead::new(
        rig,
        args.rate,
        &leads,
        LookaheadSettings::default(),
    ))
}

fn open_bus(
    args: &LoopArgs,
    profile: &Profile,
    rig: &crate::rig::Rig,
    out: &mut dyn Write,
) -> Result<OpenBus, CliError> {
    match &args.bus {
        BusArg::Virtual => {
            // Servos powered up at their zero angle (inside their limits).
            let rest: Vec<i32> = rig.servos.iter().map(crate::rig::ServoMap::rest_tick).collect();
            let chain = chain_for(profile, |k| rest[k]);
            let n = profile.servos.len();
            let read = format!(
                "{} read{}",
                profile.bus.read.name(),
                if profile.bus.pipeline { ", pipelined" } else { "" }
            );
            if args.no_line_time {
                // On a pty, answering as soon as the serving thread can.
                let chain = PtyChain::serve(chain, None).map_err(CliError::Output)?;
                let path = chain.path().to_string();
                let baud = args.baud.unwrap_or(profile.bus.baud);
                let bus = crate::bus::open_port(&path, baud, profile).map_err(CliError::at_port(&path))?;
                return Ok(OpenBus {
                    bus,
                    label: format!("virtual chain of {n} servos on {path} (answering at once, {read})"),
                    _chain: Some(chain),
                });
            }
            // In process and in real time, keeping line time exactly: the loop's own host on
            // it, as on a port.
            warn_if_over_budget(args, &profile.bus, n, out)?;
            let mut bus_config = profile.bus.clone();
            bus_config.baud = args.baud.unwrap_or(profile.bus.baud);
            let bus = crate::bus::line_timed_chain(chain, &bus_config);
            Ok(OpenBus {
                bus: Box::new(bus),
                label: format!(
                    "virtual chain of {n} servos at {} bit/s, {} µs USB latency (line time kept, {read})",
                    bus_config.baud, bus_config.usb_latency_us
                ),
                _chain: None,
            })
        }
        // Clips and target files reach the simulator in lockstep (`run_sim`) before this.
        BusArg::Sim => Err(CliError::Usage(SIM_TAKES_NO_LIVE_INPUT.into())),
        BusArg::Port(port) => {
            let baud = args.baud.unwrap_or(profile.bus.baud);
            let mut cfg = profile.bus.clone();
            cfg.baud = baud;
            warn_if_over_budget(args, &cfg, profile.servos.len(), out)?;
            let bus = crate::bus::open_port(port, baud, profile).map_err(CliError::at_port(port))?;
            Ok(OpenBus {
                bus,
                label: format!("{port} at {baud} bit/s ({} read)", profile.bus.read.name()),
                _chain: None,
            })
        }
    }
}

/// Warns when a bus cycle does not fit the loop's period.
fn warn_if_over_budget(
    args: &LoopArgs,
    bus: &crate::profile::BusConfig,
    servos: usize,
    out: &mut dyn Write,
) -> Result<(), CliError> {
    let b = plan(bus, servos, Some(args.rate));
    if b.feasible == Some(false) {
        writeln!(
            out,
            "warning: a bus cycle takes {:.0} µs ({:.0} % of the {:.0} µs period): expect deadline misses (`marionette budget`)",
            b.cycle_time_us,
            100.0 * b.utilisation.unwrap_or(0.0),
            1e6 / args.rate
        )?;
    }
    Ok(())
}

/// What a run of the loop gives back.
pub(super) struct Outcome {
    pub(super) stats: LoopStats,
    pub(super) end: RunEnd,
    pub(super) producer: ProducerReport,
    /// Why the port failed ([`RunEnd::PortLost`]).
    port_error: Option<std::io::Error>,
}

/// Starts a producer thread: (clock, first tick, period, how far ahead the loop takes inputs).
pub(super) type StartProducer =
    Box<dyn FnOnce(SystemClock, u64, u64, u64) -> std::io::Result<JoinHandle<ProducerReport>>>;

/// Where a run's input comes from.
pub(super) enum Producer {
    /// A thread paced by the machine clock, started with (clock, first tick, period, how far
    /// ahead the loop takes inputs).
    Thread(StartProducer),
    /// A source fed in simulated time (`--bus sim`) into the sender, made once the period is
    /// known.
    Lockstep(InputSender, Box<dyn FnOnce(u64) -> Box<dyn LockstepSource>>),
}

/// `--bus sim`: the loop in lockstep with MuJoCo, on simulated time, in this thread.
#[cfg(not(feature = "sim"))]
#[allow(clippy::too_many_arguments, clippy::needless_pass_by_value)]
fn run_sim(
    _args: &LoopArgs,
    _profile: &Profile,
    _skeleton: Arc<Skeleton>,
    _rig: crate::rig::Rig,
    _solve: Solve,
    _port: InputPort,
    _tx: InputSender,
    _make_source: Box<dyn FnOnce(u64) -> Box<dyn LockstepSource>>,
    _allocations: Option<fn() -> u64>,
    _stop: &StopRequests,
    _retarget: Option<RetargetStage>,
    _out: &mut dyn Write,
) -> Result<Outcome, CliError> {
    Err(CliError::NoSimulator("--bus sim"))
}

/// `--bus sim`: the loop in lockstep with MuJoCo, on simulated time, in this thread; then the
/// tracking report.
#[cfg(feature = "sim")]
#[allow(clippy::too_many_arguments)]
fn run_sim(
    args: &LoopArgs,
    profile: &Profile,
    skeleton: Arc<Skeleton>,
    rig: crate::rig::Rig,
    solve: Solve,
    port: InputPort,
    tx: InputSender,
    make_source: Box<dyn FnOnce(u64) -> Box<dyn LockstepSource>>,
    allocations: Option<fn() -> u64>,
    stop: &StopRequests,
    retarget: Option<RetargetStage>,
    out: &mut dyn Write,
) -> Result<Outcome, CliError> {
    use crate::control::lockstep::FeedingClock;
    use crate::sim::{mjcf::PuppetOptions, plant, report};
    let options = PuppetOptions {
        scale: args.scale,
        ..PuppetOptions::default()
    };
    let world = plant::load_world(args.model.as_deref(), Some(&skeleton), profile, &rig, &options)?;
    let mut bus = plant::sim_bus(world, profile, &rig)?;
    let present = start_up(&mut bus, profile)?;
    writeln!(
        out,
        "MuJoCo: {} ({}), {} servos up, torque on; lockstep on simulated time",
        args.model.as_ref().map_or_else(
            || "puppet generated from the skeleton".to_string(),
            |m| m.display().to_string()
        ),
        bus.with(|t| format!("time step {} ms", t.plant().world().timestep() * 1e3)),
        present.len()
    )?;
    // The simulated bus keeps line time: a rate it cannot carry runs late (in simulated time).
    warn_if_over_budget(args, &profile.bus, present.len(), out)?;
    bus.with(|t| t.plant_mut().record(true));
    // In lockstep the physics (and its recorder) runs inside the bus calls of each tick, so a
    // count would be the simulator's; the loop's own ticks are counted on the other buses.
    let _ = allocations;
    let mut config = loop_config(args, None);
    config.pipelined = profile.bus.pipeline;
    config.effector_metres_per_unit = args.scale * f64::from(skeleton.units().meters_per_unit());
    let planner = lookahead(args, profile, &rig);
    let mut controller = Controller::new(skeleton, rig, profile.ids(), &present, port, solve, config);
    controller.set_servo_names(profile.servos.iter().map(|s| s.name.clone()).collect());
    if let Some(r) = retarget {
        controller.set_retarget(r);
    }
    if let Some(p) = planner {
        controller.set_lookahead(p);
    }
    if let Some(v) = &args.live {
        controller.set_live_view(Arc::clone(v));
    }
    let period = controller.period_ns();
    let start = bus.now_ns() + period;
    let mut clock = FeedingClock::new(bus.clone(), make_source(period), tx, start, period)
        .with_preview(controller.preview_ns());
    let mut schedule = Schedule::new(start, period);
    if args.sim_plot.is_some() {
        // Up to ten minutes of ticks for the picture's source curves.
        controller.log_source(((600.0 * args.rate) as usize).min(600_000));
    }
    let end = controller.run(&mut schedule, &mut bus, &mut clock, stop);
    let producer = clock.report();
    let names: Vec<String> = profile.servos.iter().map(|s| s.name.clone()).collect();
    let mut tracking = bus.with(|t| {
        let p = t.plant();
        report::TrackingReport::new(
            p.samples(),
            &names,
            p.saturated_steps(),
            &p.site_names(),
            p.steps(),
        )
    });
    if let Some(f) = &controller.stats.fidelity {
        tracking.add_fidelity(f);
    }
    write!(out, "{tracking}")?;
    if let Some(path) = &args.sim_report {
        let text = serde_json::to_string_pretty(&tracking)?;
        std::fs::write(path, text + "\n").map_err(|e| crate::formats::FileError::io(path, e))?;
        writeln!(out, "tracking report written to {}", path.display())?;
    }
    if let Some(path) = &args.sim_plot {
        let chosen = plot_choice(&args.plot_servos, &tracking)?;
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
            out,
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

/// The servos to draw: those named, else the four with the largest RMS.
#[cfg(feature = "sim")]
fn plot_choice(
    names: &[String],
    tracking: &crate::sim::report::TrackingReport,
) -> Result<Vec<usize>, CliError> {
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
            tracking
                .servos
                .iter()
                .position(|s| &s.name == n)
                .ok_or_else(|| CliError::Usage(format!("--plot-servos: no servo named `{n}` in the profile")))
        })
        .collect()
}

fn loop_config(args: &LoopArgs, allocations: Option<fn() -> u64>) -> LoopConfig {
    LoopConfig {
        rate_hz: args.rate,
        hold_after: args.hold_after,
        torque_off_after_ms: args.torque_off_after,
        stop: match args.on_stop {
            OnStop::Rest => StopMode::Rest { ramp_s: args.ramp },
            OnStop::Hold => StopMode::Hold { hold_s: args.ramp },
        },
        max_ticks: args.duration.map(|d| (d * args.rate).round().max(1.0) as u64),
        ease_in_s: args.ease_in,
        effector_metres_per_unit: 0.0,
        pipelined: false,
        fidelity_worker: false,
        allocations,
    }
}

/// Starts the bus, the loop thread and the status line, and waits for the end.
#[allow(clippy::too_many_arguments)]
pub(super) fn run_loop(
    args: &LoopArgs,
    profile: &Profile,
    skeleton: Arc<Skeleton>,
    solve: Solve,
    port: InputPort,
    producer: Producer,
    allocations: Option<fn() -> u64>,
    clip: Option<&Motion>,
    out: &mut dyn Write,
) -> Result<Outcome, CliError> {
    check(args)?;
    // From here on a signal stops the run safely (during start-up too).
    let stop = crate::signals::stop_requests().map_err(CliError::Output)?;
    // A profile of robot joints retargets the human pose onto the robot inside the tick.
    let joint_driven = profile
        .servos
        .iter()
        .any(|s| matches!(s.drive, crate::profile::Drive::Joint(_)));
    let (rig, retarget) = if joint_driven {
        let setup = Setup::new(profile, &skeleton)?;
        let floor = match clip {
            Some(m) => floor_of_clip(&skeleton, m, &setup.map.human),
            None => floor_of_rest(&skeleton, &setup.map.human),
        };
        let options = RetargetOptions {
            upper_body: args.upper_body,
            balance: !args.no_balance,
        };
        let stage = RetargetStage::new(&setup, &skeleton, floor, options);
        writeln!(
            out,
            "retargeting onto {} ({} joints){}",
            setup.model.display(),
            setup.robot.joints().len(),
            if args.upper_body {
                ", upper body (legs in a stance)"
            } else {
                ""
            }
        )?;
        (setup.rig, Some(stage))
    } else {
        (profile.rig(Some(&skeleton))?, None)
    };
    let start_producer = match producer {
        Producer::Lockstep(..) if args.ros2 || args.ros2_node.is_some() => {
            return Err(CliError::Usage(
                "--ros2 runs in real time and --bus sim in simulated time: serve the simulator on a pseudo-terminal (`marionette sim serve`) and give its path to --bus".into(),
            ))
        }
        Producer::Lockstep(tx, make_source) => {
            return run_sim(
                args,
                profile,
                skeleton,
                rig,
                solve,
                port,
                tx,
                make_source,
                allocations,
                &stop,
                retarget,
                out,
            )
        }
        Producer::Thread(start) => start,
    };
    let ros2_node = super::ros2::node(args.ros2, args.ros2_node.as_ref(), out)?;
    let OpenBus {
        mut bus,
        _chain,
        label,
    } = open_bus(args, profile, &rig, out)?;
    let present = start_up(bus.as_mut(), profile)?;
    writeln!(out, "{label}: {} servos up, torque on", present.len())?;
    let mut config = loop_config(args, allocations);
    // Dynamixel2 (Bulk Read) cannot split a read: its request does nothing, its collect reads.
    config.pipelined = profile.bus.pipeline;
    config.effector_metres_per_unit = args.scale * f64::from(skeleton.units().meters_per_unit());
    // Real time: the fidelity's lag search on a thread of its own, off the tick.
    config.fidelity_worker = true;
    let planner = lookahead(args, profile, &rig);
    let rig_for_ros2 = rig.clone();
    let mut controller = Controller::new(skeleton, rig, profile.ids(), &present, port, solve, config);
    controller.set_servo_names(profile.servos.iter().map(|s| s.name.clone()).collect());
    if let Some(r) = retarget {
        controller.set_retarget(r);
    }
    if let Some(p) = planner {
        controller.set_lookahead(p);
    }
    if let Some(v) = &args.live {
        controller.set_live_view(Arc::clone(v));
    }
    let (ttx, trx) = crossbeam_channel::bounded::<Telemetry>(4096);
    let _ = controller.add_telemetry(ttx);
    let period = controller.period_ns();
    let mut clock = SystemClock::new(200_000);
    let publishing = super::ros2::publish(
        ros2_node.as_ref(),
        args.ros2_rate,
        &mut controller,
        &rig_for_ros2,
        profile.servos.iter().map(|s| s.name.clone()).collect(),
        clock,
        out,
    )?;
    // The first tick a little ahead, so the producer has filled the channel.
    // (At most half the Bus Watchdog away: it was armed at the end of the start-up.)
    let lead_ns = match profile.bus.watchdog_ms {
        0 => 50_000_000,
        w => (u64::from(w) * 500_000).min(50_000_000),
    };
    let start = clock.now_ns() + lead_ns;
    let producer = start_producer(clock, start, period, controller.preview_ns()).map_err(CliError::Output)?;
    let rt = RealTime {
        priority: args.rt_priority,
        cpu: args.cpu,
        lock_memory: args.mlock,
    };
    let handle = std::thread::Builder::new()
        .name("control-loop".into())
        .spawn(move || {
            let warnings = rt.apply();
            let mut schedule = Schedule::new(start, period);
            let end = controller.run(&mut schedule, bus.as_mut(), &mut clock, &stop);
            (controller.stats, end, controller.port_error, warnings)
        })
        .map_err(CliError::Output)?;
    let status = status_line(&trx, args, &handle, period);
    let (stats, end, port_error, warnings) = handle.join().map_err(|_| CliError::LoopPanicked)?;
    if status {
        let _ = writeln!(std::io::stderr());
    }
    for w in warnings {
        writeln!(out, "{w}")?;
    }
    let producer = producer.join().unwrap_or_default();
    super::ros2::finish(publishing, out)?;
    Ok(Outcome {
        stats,
        end,
        producer,
        port_error,
    })
}

/// Prints a status line from the telemetry (on a terminal: rewritten in place four times a
/// second; otherwise once a second) until the loop thread ends. Returns whether it printed.
fn status_line<T>(
    rx: &crossbeam_channel::Receiver<Telemetry>,
    args: &LoopArgs,
    handle: &JoinHandle<T>,
    period_ns: u64,
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
        if !args.quiet {
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
            let line = format!(
                "{:>7.1} Hz  ticks {ticks:>7}  misses {misses:>4}  compute p99 {p99:>7.1} µs ({:.2} % of period)  tracking {rms:>6.3}°  failed reads {fails}{}",
                window.len() as f64 / secs,
                p99 * 1e3 / period_ns as f64 * 100.0,
                if clip.is_finite() { format!("  clip {clip:6.2} s") } else { String::new() }
            );
            // Writes may fail after a hang-up (the terminal closed): the loop goes on to its
            // safe stop regardless.
            let mut err = std::io::stderr();
            let _ = if tty {
                write!(err, "\r{line}")
            } else {
                writeln!(err, "{line}")
            };
            printed = tty;
        }
        window.clear();
    }
    printed
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
    for line in written {
        writeln!(out, "{line}")?;
    }
    match outcome.end {
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
#[allow(clippy::too_many_arguments)]
pub fn play_cmd(
    profile_path: &Path,
    asf_path: &Path,
    amc_path: &Path,
    playback: Playback,
    args: &LoopArgs,
    allocations: Option<fn() -> u64>,
    out: &mut dyn Write,
) -> Result<(), CliError> {
    let Playback {
        looping,
        speed,
        start: start_at,
        pre_roll,
        keep_dropouts,
    } = playback;
    if !(speed.is_finite() && speed > 0.0) {
        return Err(CliError::Usage("--speed must be a positive number".into()));
    }
    if pre_roll.is_some_and(|p| !(p.is_finite() && (0.0..=60.0).contains(&p))) {
        return Err(CliError::Usage(
            "--pre-roll must be between 0 and 60 seconds".into(),
        ));
    }
    let profile = Profile::load(profile_path)?;
    let joint_driven = profile
        .servos
        .iter()
        .any(|s| matches!(s.drive, crate::profile::Drive::Joint(_)));
    let pre_roll = pre_roll.unwrap_or(if joint_driven { 0.0 } else { DEFAULT_PRE_ROLL_S });
    // The move to the first frame is eased in from where the servos stand.
    let mut eased;
    let args = if pre_roll > 0.0 && args.ease_in == 0.0 {
        eased = args.clone();
        eased.ease_in = pre_roll;
        &eased
    } else {
        args
    };
    let skeleton = Arc::new(asf::load(asf_path)?.skeleton);
    // A loaded motion has at least one frame.
    let mut motion = amc::load(&skeleton, amc_path)?;
    let dropouts = if keep_dropouts {
        crate::motion::dropouts::find(&skeleton, &motion)
    } else {
        crate::motion::dropouts::repair(&skeleton, &mut motion)
    };
    for d in &dropouts {
        writeln!(
            out,
            "{}: capture dropout: {d}{}",
            amc_path.display(),
            if keep_dropouts {
                "; played as recorded"
            } else {
                "; filled from its neighbours (--keep-dropouts plays it as recorded)"
            }
        )?;
    }
    let motion = Arc::new(motion);
    if !(start_at.is_finite() && (0.0..=motion.duration()).contains(&start_at)) {
        return Err(CliError::Usage(format!(
            "--start must be within the clip's 0…{:.3} s",
            motion.duration()
        )));
    }
    check(args)?;
    let mut player = ClipPlayer::new(Arc::clone(&skeleton), Arc::clone(&motion), args.rate, looping);
    player.control(PlayerCommand::Speed(speed));
    player.control(PlayerCommand::Seek(start_at));
    player.set_pre_roll(pre_roll);
    // The pre-roll's samples come first: the first pass is that much longer.
    let pre_roll_samples = player.pre_roll_samples();
    let samples = player.samples_per_pass() + pre_roll_samples;
    writeln!(
        out,
        "{}: {} frames at {} Hz ({:.2} s) → {} samples a pass at {} Hz{}{}",
        amc_path.display(),
        motion.len(),
        motion.frame_rate,
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
    let (tx, port) = input_channel(input_capacity(args.rate));
    let producer = if args.bus == BusArg::Sim {
        let channels = skeleton.channel_count();
        Producer::Lockstep(
            tx,
            Box::new(move |period| Box::new(PlayerFeed::new(player, period, channels))),
        )
    } else {
        let commands = keyboard_commands(out)?;
        Producer::Thread(Box::new(move |clock, start, period, preview| {
            spawn_player(player, tx, clock, start, period, preview, commands)
        }))
    };
    let outcome = run_loop(
        args,
        &profile,
        skeleton,
        Solve::Frames,
        port,
        producer,
        allocations,
        Some(&motion),
        out,
    )?;
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
        samples_per_pass: samples,
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

/// Where targets come from.
enum TargetSource {
    File(TargetTrack),
    Stdin,
    Udp(UdpSocket),
    Ros2,
}

/// The source `spec` names; a UDP address off loopback only when `any_host` says so.
fn target_source(spec: &str, effectors: &[String], any_host: bool) -> Result<TargetSource, CliError> {
    if spec == "-" {
        return Ok(TargetSource::Stdin);
    }
    if spec == "ros2" {
        return Ok(TargetSource::Ros2);
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
        return Ok(TargetSource::Udp(socket));
    }
    Ok(TargetSource::File(TargetTrack::load(Path::new(spec), effectors)?))
}

/// `marionette follow`.
///
/// # Errors
/// [`CliError`].
#[allow(clippy::too_many_arguments)]
pub fn follow_cmd(
    profile_path: &Path,
    asf_path: &Path,
    targets: &str,
    targets_from_network: bool,
    effectors: &[String],
    looping: bool,
    args: &LoopArgs,
    allocations: Option<fn() -> u64>,
    out: &mut dyn Write,
) -> Result<(), CliError> {
    let profile = Profile::load(profile_path)?;
    let skeleton = Arc::new(asf::load(asf_path)?.skeleton);
    let follower =
        Follower::new(&skeleton, effectors).map_err(|e| CliError::Usage(format!("--effectors: {e}")))?;
    check(args)?;
    let source = target_source(targets, effectors, targets_from_network)?;
    match &source {
        TargetSource::File(t) => writeln!(
            out,
            "{targets}: {} samples over {:.2} s for {}{}",
            t.samples.len(),
            t.duration(),
            effectors.join(", "),
            if looping { ", looping" } else { "" }
        )?,
        TargetSource::Stdin => writeln!(
            out,
            "reading target lines from stdin for {}",
            effectors.join(", ")
        )?,
        TargetSource::Udp(s) => {
            let local = s.local_addr().ok();
            writeln!(
                out,
                "listening for target lines on udp://{} for {}",
                local.map_or_else(|| targets.to_string(), |a| a.to_string()),
                effectors.join(", ")
            )?;
            if local.is_some_and(|a| !a.ip().is_loopback()) {
                writeln!(
                    out,
                    "warning: not loopback: any host that reaches this port moves the servos (no authentication; datagrams over {MAX_DATAGRAM_BYTES} bytes refused)"
                )?;
            }
        }
        TargetSource::Ros2 => {}
    }
    let mut args = args.clone();
    let ros2_node = if matches!(source, TargetSource::Ros2) {
        args.ros2 = true;
        let node = super::ros2::node(true, args.ros2_node.as_ref(), out)?;
        args.ros2_node.clone_from(&node);
        node
    } else {
        None
    };
    let args = &args;
    let (tx, port): (InputSender, InputPort) = input_channel(input_capacity(args.rate));
    let names = effectors.to_vec();
    let root = skeleton
        .bones()
        .first()
        .map_or_else(String::new, |b| b.name().to_string());
    let metres_per_unit = args.scale * f64::from(skeleton.units().meters_per_unit());
    let kind = args.ros2_targets;
    if ros2_node.is_some() {
        writeln!(
            out,
            "ros2: targets on /marionette/targets/{{{}}} ({}, metres on the rig, frame '{root}')",
            effectors.join(","),
            match kind {
                super::ros2::Ros2Targets::Point => "geometry_msgs/msg/PointStamped",
                super::ros2::Ros2Targets::Pose => "geometry_msgs/msg/PoseStamped",
            }
        )?;
    }
    let producer = match source {
        TargetSource::File(track) if args.bus == BusArg::Sim => {
            if looping {
                return Err(CliError::Usage(
                    "--loop with --bus sim would never end: give --duration instead of looping a simulated run".into(),
                ));
            }
            Producer::Lockstep(tx, Box::new(move |_| Box::new(TrackFeed::new(track))))
        }
        source => Producer::Thread(Box::new(move |clock, start, _period, preview| match source {
            TargetSource::File(track) => spawn_track(track, tx, clock, start, preview, looping),
            TargetSource::Stdin => spawn_stdin(names, tx, clock),
            TargetSource::Udp(socket) => spawn_udp(socket, names, tx, clock),
            TargetSource::Ros2 => match &ros2_node {
                Some(node) => {
                    super::ros2::spawn_targets(node, &names, &root, kind, metres_per_unit, tx, clock)
                }
                None => Err(std::io::Error::other("no ROS 2 node")),
            },
        })),
    };
    let outcome = run_loop(
        args,
        &profile,
        skeleton,
        Solve::Follow(Box::new(follower)),
        port,
        producer,
        allocations,
        None,
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
#[allow(clippy::too_many_arguments)]
pub fn targets_cmd(
    asf_path: &Path,
    amc_path: &Path,
    effectors: &[String],
    frame: TrackFrame,
    format: TargetFormat,
    directions: bool,
    output: &Path,
    out: &mut dyn Write,
) -> Result<(), CliError> {
    let skeleton = asf::load(asf_path)?.skeleton;
    let motion = amc::load(&skeleton, amc_path)?;
    let track = if directions {
        clip_track_pointing(&skeleton, &motion, effectors, frame)
    } else {
        clip_track(&skeleton, &motion, effectors, frame)
    }
    .map_err(CliError::Usage)?;
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
