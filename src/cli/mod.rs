//! The `marionette` command line: [`Cli`] parses it, [`run`] runs it. One file per command or
//! close group; this file only names the commands and hands each to its file.

mod args;
mod convert;
mod edit;
mod error;
mod identify;
mod ik;
mod inspect;
mod play;
mod retarget;
mod rig;
mod sim;
mod soak;
#[cfg(feature = "studio")]
mod studio;

pub use error::CliError;

use crate::motion::connect::{ConnectParams, Direction, Method};
use crate::motion::matching::{MatchParams, Metric};
use crate::motion::CMU_FRAME_RATE;
use args::{BvhUnit, TableFormat};
use clap::{Parser, Subcommand, ValueEnum};
use std::io;
use std::path::PathBuf;

/// Drive servo rigs from motion capture: ASF/AMC and BVH, forward and inverse kinematics.
#[derive(Debug, Parser)]
#[command(name = "marionette", version, about, long_about = None)]
pub struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Stream a clip to the servos at a fixed rate (the control loop), SLERP-resampled.
    Play {
        /// The rig profile, e.g. firmware-profile/cmu-puppet.toml.
        profile: PathBuf,
        /// Skeleton (.asf).
        asf: PathBuf,
        /// Clip (.amc).
        amc: PathBuf,
        /// Start over at the end of the clip (stop with Ctrl-C or --duration).
        #[arg(long = "loop")]
        looping: bool,
        /// Playback speed (1 = as captured).
        #[arg(long, default_value_t = 1.0)]
        speed: f64,
        /// Clip time to start at, seconds.
        #[arg(long, default_value_t = 0.0)]
        start: f64,
        /// Seconds to move to the clip's first frame before it starts (eased in from where the
        /// servos stand, unless --ease-in says otherwise); not counted in the fidelity. 0: the
        /// clip starts at once, from wherever the servos stand. Default: 1 s for a rig of the
        /// skeleton's bones; 0 for a robot retargeted on its floor (a joint-space blend into a
        /// clip's first pose, a crouch say, can tip it: give --ease-in, or --pre-roll, knowingly).
        #[arg(long)]
        pre_roll: Option<f64>,
        /// Play capture dropouts (a bone reading exactly zero between far-away frames) as
        /// recorded instead of filling them from their neighbours.
        #[arg(long)]
        keep_dropouts: bool,
        #[command(flatten)]
        loop_args: play::LoopArgs,
    },
    /// Identify each servo's response (a step and a chirp, small and inside its limits): lag,
    /// rise, bandwidth; `--write` puts the lags into the profile as `lag_ms`, which the
    /// look-ahead leads each servo by.
    Identify {
        /// The rig profile.
        profile: PathBuf,
        /// Skeleton (.asf): for profiles of bones, and the generated puppet of --bus sim.
        asf: Option<PathBuf>,
        #[command(flatten)]
        args: identify::IdentifyArgs,
    },
    /// Serve the studio on 127.0.0.1: drag IK targets in a browser, compare the solvers, and
    /// drive the rig live (the virtual chain by default, --bus sim or a port). Only its own page
    /// drives it: other host names, other origins, non-JSON posts and oversized input are
    /// refused.
    #[cfg(feature = "studio")]
    Studio {
        /// The rig profile.
        profile: PathBuf,
        /// Skeleton (.asf).
        asf: PathBuf,
        /// A clip (.amc) for the timeline: play, scrub, pin limbs while it plays.
        amc: Option<PathBuf>,
        /// Port to serve on (0: any free one; the URL is printed).
        #[arg(long, default_value_t = 8080)]
        port: u16,
        /// Listen on this address instead of loopback; other machines then need the token
        /// (printed in the URL once).
        #[arg(long)]
        listen: Option<std::net::IpAddr>,
        /// Another host name the page may be reached by (NAME or NAME:PORT; a proxy's, an SSH
        /// tunnel's); repeatable.
        #[arg(long, value_name = "NAME")]
        allow_host: Vec<String>,
        /// Another origin whose pages may drive the rig (scheme://host[:port]); repeatable.
        #[arg(long, value_name = "ORIGIN")]
        allow_origin: Vec<String>,
        /// The token requests must carry (default: a random one per run when --listen is not
        /// loopback, none on loopback); better given in the environment than on the command
        /// line.
        #[arg(long, env = "MARIONETTE_STUDIO_TOKEN", hide_env_values = true)]
        token: Option<String>,
        #[command(flatten)]
        loop_args: play::LoopArgs,
    },
    /// Follow effector targets (file, stdin or UDP) with inverse kinematics at a fixed rate.
    Follow {
        /// The rig profile.
        profile: PathBuf,
        /// Skeleton (.asf).
        asf: PathBuf,
        /// Targets: a CSV or JSON-lines file, `-` for stdin, udp://127.0.0.1:PORT, or `ros2`
        /// (the topics /marionette/targets/<effector>, metres on the rig in the root's frame;
        /// implies --ros2).
        #[arg(long)]
        targets: String,
        /// Take UDP targets on an address other than loopback (then any host that reaches the
        /// port moves the servos: a trusted network only).
        #[arg(long)]
        targets_from_network: bool,
        /// The effector bones (their tips follow the targets).
        #[arg(long, value_delimiter = ',', default_value = "lradius,rradius,ltibia,rtibia")]
        effectors: Vec<String>,
        /// Start a target file over at its end.
        #[arg(long = "loop")]
        looping: bool,
        #[command(flatten)]
        loop_args: play::LoopArgs,
    },
    /// Write the effector paths of a clip as a target file for `follow`.
    Targets {
        /// Skeleton (.asf).
        asf: PathBuf,
        /// Clip (.amc).
        amc: PathBuf,
        /// The effector bones.
        #[arg(long, value_delimiter = ',', default_value = "lradius,rradius,ltibia,rtibia")]
        effectors: Vec<String>,
        /// limb: each path relative to its limb's parent bone, placed on the rest pose (what a
        /// rig with its other joints at rest can reach); root: as captured, in the root's frame.
        #[arg(long, value_enum, default_value_t = FrameArg::Limb)]
        frame: FrameArg,
        /// File format.
        #[arg(long, value_enum, default_value_t = play::TargetFormat::Csv)]
        format: play::TargetFormat,
        /// Add each target's pointing direction: the captured direction of the bone after the
        /// effector (the hand, the foot), which `follow` turns that bone to.
        #[arg(long)]
        directions: bool,
        /// Output file.
        #[arg(short, long)]
        output: PathBuf,
    },
    /// Check a rig profile (TOML) and list its servos; with --asf, its bones too.
    Profile {
        /// The profile, e.g. firmware-profile/cmu-puppet.toml.
        profile: PathBuf,
        /// The skeleton the profile's bones refer to.
        #[arg(long)]
        asf: Option<PathBuf>,
    },
    /// The MuJoCo simulator: export a puppet model, serve simulated servos on a pseudo-terminal.
    Sim {
        #[command(subcommand)]
        command: sim::SimCommand,
    },
    /// Bus time per control cycle for a profile, and the highest loop rate it allows.
    Budget {
        /// The profile.
        profile: PathBuf,
        /// A loop rate to check, Hz.
        #[arg(long)]
        rate: Option<f64>,
        /// Print JSON.
        #[arg(long)]
        json: bool,
        /// Measure this many cycles on the profile's virtual chain served with line time (baud,
        /// return delay, USB latency) through the real client, against the plan.
        #[arg(long)]
        measure: Option<usize>,
    },
    /// Serve the profile's servos as a virtual chain on a pseudo-terminal (no MuJoCo; `sim
    /// serve` adds physics), keeping line time: bytes at the profile's baud, return delays, the
    /// USB adapter's latency. Prints the device path to give any Protocol 2.0 client.
    Serve {
        /// The profile.
        profile: PathBuf,
        /// Answer at once instead of at line speed.
        #[arg(long)]
        no_line_time: bool,
        /// Stop after this many seconds (default: at Ctrl-C).
        #[arg(long)]
        duration: Option<f64>,
        /// Serve at this `SCHED_FIFO` priority (1–99; needs CAP_SYS_NICE), as hardware keeps
        /// its own time whatever else the machine does.
        #[arg(long)]
        rt_priority: Option<i32>,
    },
    /// A fault soak in virtual time: the whole loop on the in-process virtual chain, playing a
    /// clip through seeded bursts of every bus fault; prints what it counted (panics, corrupt
    /// values used, goals outside limits, ticks to recover after each burst).
    Soak {
        /// The profile.
        profile: PathBuf,
        /// Skeleton (.asf).
        asf: PathBuf,
        /// Clip (.amc), played on a loop.
        amc: PathBuf,
        /// Faults to apply before stopping.
        #[arg(long, default_value_t = 1_000_000)]
        faults: u64,
        /// Seed of the faults and the bursts (the same seed replays the same soak).
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Loop rate, Hz.
        #[arg(long, default_value_t = 100.0)]
        rate: f64,
        /// Longest burst of faults, ticks.
        #[arg(long, default_value_t = 30)]
        max_burst: u64,
        /// Also write the figures as JSON to this file.
        #[arg(long)]
        json: Option<PathBuf>,
    },
    /// Retarget a clip onto a robot (the profile's [retarget] map): joint trajectory as CSV,
    /// a report, a picture.
    Retarget {
        /// The rig profile with a [retarget] map, e.g. firmware-profile/robotis-op3.toml.
        profile: PathBuf,
        /// Skeleton: an .asf file, or a .bvh file (skeleton and motion).
        skeleton: PathBuf,
        /// Clip (.amc) for an ASF skeleton.
        amc: Option<PathBuf>,
        /// Joint trajectory: time, then one column per robot joint (radians).
        #[arg(short, long)]
        output: PathBuf,
        /// Also write the report as JSON.
        #[arg(long)]
        report: Option<PathBuf>,
        /// Draw human and robot side by side at a few frames, and the error curves (.svg/.png).
        #[arg(long)]
        plot: Option<PathBuf>,
        /// Keep the legs in a standing stance; retarget arms, head and torso only.
        #[arg(long)]
        upper_body: bool,
        /// Do not move the pelvis to keep the centre of mass over the planted feet.
        #[arg(long)]
        no_balance: bool,
        /// Frame rate of the AMC file.
        #[arg(long, default_value_t = CMU_FRAME_RATE)]
        fps: f64,
        /// Length unit of a BVH file.
        #[arg(long, value_enum, default_value_t = BvhUnit::Cm)]
        bvh_unit: BvhUnit,
    },
    /// Inverse kinematics: move a bone's tip to a target and print the result.
    Ik {
        /// Skeleton (.asf).
        asf: PathBuf,
        /// Starting motion (.amc); the start is its frame --frame (default: the rest pose).
        #[arg(long)]
        amc: Option<PathBuf>,
        /// AMC frame number to start from.
        #[arg(long)]
        frame: Option<i64>,
        /// The bone whose tip must reach the target (lradius: wrist, ltibia: ankle).
        #[arg(long)]
        effector: String,
        /// Target position X,Y,Z in ASF file units (global).
        #[arg(long, allow_hyphen_values = true)]
        target: String,
        /// Pointing direction X,Y,Z of the next bone (hand, foot).
        #[arg(long, allow_hyphen_values = true)]
        point_dir: Option<String>,
        /// Roll about the pointing direction, degrees.
        #[arg(long, allow_hyphen_values = true)]
        roll: Option<f64>,
        /// Solver (default: analytic where the effector ends a 2-bone limb, else dls).
        #[arg(long, value_parser = ik::method_arg())]
        method: Option<crate::ik_numeric::IkMethod>,
        /// Write the solved pose as a one-frame AMC.
        #[arg(short = 'o', long)]
        output: Option<PathBuf>,
    },
    /// Keep a bone's tip where it was at one frame over a range of frames (foot planting),
    /// blended in and out; writes the edited motion.
    IkEdit {
        /// Skeleton (.asf).
        asf: PathBuf,
        /// Motion to edit (.amc).
        amc: PathBuf,
        /// BONE@FRAME: the bone's tip stays where it was at that frame (repeatable; e.g.
        /// ltibia@120 for the left ankle).
        #[arg(long, required = true)]
        pin: Vec<String>,
        /// A..B: AMC frame numbers (inclusive) over which the pins hold.
        #[arg(long)]
        frames: String,
        /// Frames of ease-in before A and ease-out after B.
        #[arg(long, default_value_t = 12)]
        blend: usize,
        /// Output motion (.amc).
        #[arg(short = 'o', long)]
        output: PathBuf,
    },
    /// List serial adapters (USB VID/PID, U2D2/FTDI, latency timer).
    Ports,
    /// Ping every id on a bus: ids, models, firmware, hardware error status.
    Scan {
        /// Serial port, e.g. /dev/ttyUSB0.
        #[arg(long, conflicts_with = "virtual")]
        port: Option<String>,
        /// Baud rate of --port.
        #[arg(long, default_value_t = 57_600)]
        baud: u32,
        /// Scan a virtual chain built from this profile (served on a pseudo-terminal).
        #[arg(long = "virtual", value_name = "PROFILE")]
        r#virtual: Option<PathBuf>,
    },
    /// Describe a skeleton (ASF or BVH) and, given one, a motion: bones, DOFs, limits, frames.
    Info {
        /// Skeleton: an .asf file, or a .bvh file (skeleton and motion).
        skeleton: PathBuf,
        /// Motion: an .amc file for the skeleton.
        amc: Option<PathBuf>,
        /// Frame rate of the AMC file (AMC files do not state it; CMU captures are 120 Hz).
        #[arg(long, default_value_t = CMU_FRAME_RATE)]
        fps: f64,
        /// Length unit of a BVH file.
        #[arg(long, value_enum, default_value_t = BvhUnit::Cm)]
        bvh_unit: BvhUnit,
    },
    /// Global position of every bone's tip (the root: its position) per frame.
    Fk {
        /// Skeleton (.asf).
        asf: PathBuf,
        /// Motion (.amc).
        amc: PathBuf,
        /// Every N-th frame: A, A+N, A+2N, … (A: the first frame of the range).
        #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..))]
        every: u64,
        /// Frame range, inclusive, in the AMC's frame numbers: `A..B`, `A..` or `..B`.
        #[arg(long)]
        frames: Option<String>,
        /// Positions in metres instead of ASF file units.
        #[arg(long)]
        meters: bool,
        /// Output format.
        #[arg(long, value_enum, default_value_t = TableFormat::Csv)]
        format: TableFormat,
    },
    /// Convert between BVH and ASF/AMC: IN.bvh → OUT.amc (+ OUT.asf) or IN.amc → OUT.bvh.
    Convert {
        /// Input: .bvh, or .amc (with its skeleton, see --asf).
        input: PathBuf,
        /// Output: .amc (the skeleton goes to --asf-out or beside it as .asf), .bvh or .asf.
        output: PathBuf,
        /// Skeleton of an .amc input (default: IN's stem or subject number with .asf).
        #[arg(long)]
        asf: Option<PathBuf>,
        /// Where to write the skeleton of an .amc output (default: OUT with .asf).
        #[arg(long)]
        asf_out: Option<PathBuf>,
        /// Length unit of a BVH input (BVH files do not state it).
        #[arg(long, value_enum, default_value_t = BvhUnit::Cm)]
        bvh_unit: BvhUnit,
    },
    /// Connect clip A to clip B through their best-matching windows (help note §III).
    Connect {
        /// Skeleton (.asf) of both clips.
        asf: PathBuf,
        /// First clip (.amc).
        a: PathBuf,
        /// Second clip (.amc).
        b: PathBuf,
        /// Interpolate between the end poses, or blend the overlapping windows.
        #[arg(long, value_enum, default_value_t = MethodArg::Interp)]
        method: MethodArg,
        /// Forward: match A's end in B (A kept whole); backward: B's start in A.
        #[arg(long = "match", value_enum, default_value_t = DirectionArg::Forward)]
        direction: DirectionArg,
        /// Matching window, frames.
        #[arg(long, default_value_t = 30)]
        window: usize,
        /// Joint distance for matching.
        #[arg(long, value_enum, default_value_t = MetricArg::Quat)]
        metric: MetricArg,
        /// Frames to insert (interp); default: as few as keep every bone, and the root, within
        /// 1.5× its own 99th-percentile speed in the inputs (+1°).
        #[arg(long)]
        insert: Option<usize>,
        /// Frames to blend over (blend); default: from the matching window up, as few as keep
        /// every bone within its own speeds in the inputs.
        #[arg(long)]
        blend_window: Option<usize>,
        /// Output clip (.amc).
        #[arg(short, long)]
        output: PathBuf,
        /// Picture of the root paths and the matching curve (.svg or .png).
        #[arg(long)]
        plot: Option<PathBuf>,
    },
    /// Make a seamless cycle of a clip by connecting it to itself, repeated --cycles times.
    Loop {
        /// Skeleton (.asf).
        asf: PathBuf,
        /// Clip (.amc).
        input: PathBuf,
        /// Output clip (.amc).
        #[arg(short, long)]
        output: PathBuf,
        /// Matching window, frames.
        #[arg(long, default_value_t = 30)]
        window: usize,
        /// Joint distance for matching.
        #[arg(long, value_enum, default_value_t = MetricArg::Quat)]
        metric: MetricArg,
        /// How many cycles to write, the root carried on from one to the next.
        #[arg(long, default_value_t = 2)]
        cycles: usize,
        /// Picture of the root path and the matching curve (.svg or .png).
        #[arg(long)]
        plot: Option<PathBuf>,
    },
    /// Turn a clip about its first frame's root to a facing angle and move it (eq. 6–10).
    Transform {
        /// Skeleton (.asf).
        asf: PathBuf,
        /// Clip (.amc).
        input: PathBuf,
        /// Facing of the first frame, degrees (0: +z, 90: +x).
        #[arg(long, allow_hyphen_values = true)]
        facing: f64,
        /// New start position of the root on the ground, `X,Z` (file units).
        #[arg(long, allow_hyphen_values = true)]
        start: Option<String>,
        /// Output clip (.amc).
        #[arg(short, long)]
        output: PathBuf,
    },
    /// Blend two clips frame by frame with a constant weight (0: A, 1: B).
    Blend {
        /// Skeleton (.asf) of both clips.
        asf: PathBuf,
        /// First clip (.amc).
        a: PathBuf,
        /// Second clip (.amc).
        b: PathBuf,
        /// Weight of B, 0 to 1.
        #[arg(long)]
        weight: f64,
        /// Output clip (.amc).
        #[arg(short, long)]
        output: PathBuf,
    },
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum MethodArg {
    /// Insert interpolated frames between the end poses.
    Interp,
    /// Blend the overlapping matched windows.
    Blend,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum DirectionArg {
    /// Match A's end in B; A is kept whole.
    Forward,
    /// Match B's start in A; B is kept whole.
    Backward,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum MetricArg {
    /// Euler angles.
    Euler,
    /// Quaternion log distance.
    Quat,
    /// Normalised joint positions.
    Position,
}

impl MetricArg {
    fn metric(self) -> Metric {
        match self {
            MetricArg::Euler => Metric::Euler,
            MetricArg::Quat => Metric::Quat,
            MetricArg::Position => Metric::Position,
        }
    }
}

/// Where `targets` puts the paths.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum FrameArg {
    /// Relative to each limb's parent bone, on the rest pose.
    Limb,
    /// As captured, in the root's frame.
    Root,
}

/// Runs the command line; the process exit code is 0 on `Ok`.
///
/// # Errors
/// [`CliError`], to be printed on one line.
pub fn run(cli: Cli) -> Result<(), CliError> {
    run_with(cli, None)
}

/// [`run`], with the counter of a counting global allocator (allocations so far on the calling
/// thread) so the control loop can report `allocations_in_tick`.
///
/// # Errors
/// [`CliError`], to be printed on one line.
pub fn run_with(cli: Cli, allocations: Option<fn() -> u64>) -> Result<(), CliError> {
    let result = match cli.command {
        Command::Play {
            profile,
            asf,
            amc,
            looping,
            speed,
            start,
            pre_roll,
            keep_dropouts,
            loop_args,
        } => play::play_cmd(
            &profile,
            &asf,
            &amc,
            play::Playback {
                looping,
                speed,
                start,
                pre_roll,
                keep_dropouts,
            },
            &loop_args,
            allocations,
            &mut io::stdout().lock(),
        ),
        Command::Identify { profile, asf, args } => {
            identify::identify_cmd(&profile, asf.as_deref(), &args, &mut io::stdout().lock())
        }
        #[cfg(feature = "studio")]
        Command::Studio {
            profile,
            asf,
            amc,
            port,
            listen,
            allow_host,
            allow_origin,
            token,
            loop_args,
        } => studio::studio_cmd(
            &studio::StudioArgs {
                profile: &profile,
                asf: &asf,
                amc: amc.as_deref(),
                port,
                listen,
                access: crate::studio::access::AccessOptions {
                    allow_hosts: allow_host,
                    allow_origins: allow_origin,
                    token,
                },
            },
            &loop_args,
            allocations,
            &mut io::stdout().lock(),
        ),
        Command::Follow {
            profile,
            asf,
            targets,
            targets_from_network,
            effectors,
            looping,
            loop_args,
        } => play::follow_cmd(
            &profile,
            &asf,
            &targets,
            targets_from_network,
            &effectors,
            looping,
            &loop_args,
            allocations,
            &mut io::stdout().lock(),
        ),
        Command::Targets {
            asf,
            amc,
            effectors,
            frame,
            format,
            directions,
            output,
        } => play::targets_cmd(
            &asf,
            &amc,
            &effectors,
            match frame {
                FrameArg::Limb => crate::control::sources::TrackFrame::Limb,
                FrameArg::Root => crate::control::sources::TrackFrame::Root,
            },
            format,
            directions,
            &output,
            &mut io::stdout().lock(),
        ),
        Command::Profile { profile, asf } => {
            rig::profile_cmd(&profile, asf.as_deref(), &mut io::stdout().lock())
        }
        Command::Sim { command } => sim::sim_cmd(&command, &mut io::stdout().lock()),
        Command::Serve {
            profile,
            no_line_time,
            duration,
            rt_priority,
        } => rig::serve_cmd(
            &profile,
            (!no_line_time).then_some(rt_priority),
            duration,
            &mut io::stdout().lock(),
        ),
        Command::Budget {
            profile,
            rate,
            json,
            measure,
        } => rig::budget_cmd(&profile, rate, json, measure, &mut io::stdout().lock()),
        Command::Soak {
            profile,
            asf,
            amc,
            faults,
            seed,
            rate,
            max_burst,
            json,
        } => soak::soak_cmd(
            &profile,
            &asf,
            &amc,
            soak::SoakArgs {
                faults,
                seed,
                rate,
                max_burst,
                json,
            },
            &mut io::stdout().lock(),
        ),
        Command::Retarget {
            profile,
            skeleton,
            amc,
            output,
            report,
            plot,
            upper_body,
            no_balance,
            fps,
            bvh_unit,
        } => retarget::retarget_cmd(
            &retarget::RetargetArgs {
                profile: &profile,
                skeleton: &skeleton,
                amc: amc.as_deref(),
                output: &output,
                report,
                plot,
                upper_body,
                balance: !no_balance,
                fps,
                bvh_unit,
            },
            &mut io::stdout().lock(),
        ),
        Command::Ik {
            asf,
            amc,
            frame,
            effector,
            target,
            point_dir,
            roll,
            method,
            output,
        } => ik::ik_cmd(
            &ik::IkArgs {
                asf: &asf,
                amc: amc.as_deref(),
                frame,
                effector: &effector,
                target: &target,
                point_dir: point_dir.as_deref(),
                roll,
                method,
                output: output.as_deref(),
            },
            &mut io::stdout().lock(),
        ),
        Command::IkEdit {
            asf,
            amc,
            pin,
            frames,
            blend,
            output,
        } => ik::ik_edit_cmd(
            &ik::IkEditArgs {
                asf: &asf,
                amc: &amc,
                pins: &pin,
                frames: &frames,
                blend,
                output: &output,
            },
            &mut io::stdout().lock(),
        ),
        Command::Ports => rig::ports_cmd(&mut io::stdout().lock()),
        Command::Scan {
            port,
            baud,
            r#virtual,
        } => rig::scan_cmd(
            port.as_deref(),
            baud,
            r#virtual.as_deref(),
            &mut io::stdout().lock(),
        ),
        Command::Info {
            skeleton,
            amc,
            fps,
            bvh_unit,
        } => inspect::info(&skeleton, amc.as_deref(), fps, bvh_unit),
        Command::Fk {
            asf,
            amc,
            every,
            frames,
            meters,
            format,
        } => inspect::fk(&asf, &amc, every as usize, frames.as_deref(), meters, format),
        Command::Convert {
            input,
            output,
            asf,
            asf_out,
            bvh_unit,
        } => convert::convert(&input, &output, asf.as_deref(), asf_out.as_deref(), bvh_unit),
        Command::Connect {
            asf,
            a,
            b,
            method,
            direction,
            window,
            metric,
            insert,
            blend_window,
            output,
            plot,
        } => {
            let params = ConnectParams {
                method: match method {
                    MethodArg::Interp => Method::Interpolate,
                    MethodArg::Blend => Method::Blend,
                },
                direction: match direction {
                    DirectionArg::Forward => Direction::Forward,
                    DirectionArg::Backward => Direction::Backward,
                },
                matching: MatchParams::new(window, metric.metric()),
                insert,
                blend: blend_window,
            };
            edit::connect_cmd(&asf, &a, &b, &params, &output, plot.as_deref())
        }
        Command::Loop {
            asf,
            input,
            output,
            window,
            metric,
            cycles,
            plot,
        } => edit::loop_cmd(
            &asf,
            &input,
            &MatchParams::new(window, metric.metric()),
            cycles,
            &output,
            plot.as_deref(),
        ),
        Command::Transform {
            asf,
            input,
            facing,
            start,
            output,
        } => edit::transform_cmd(&asf, &input, facing, start.as_deref(), &output),
        Command::Blend {
            asf,
            a,
            b,
            weight,
            output,
        } => edit::blend_cmd(&asf, &a, &b, weight, &output),
    };
    match result {
        // A closed pipe (`marionette fk … | head`) is not a failure.
        Err(CliError::Output(e)) if e.kind() == io::ErrorKind::BrokenPipe => Ok(()),
        other => other,
    }
}
