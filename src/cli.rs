//! The `marionette` command line.

use crate::fk::{forward_kinematics, Pose};
use crate::formats::asf::AsfFile;
use crate::formats::{amc, asf, bvh, FileError};
use crate::motion::clip::{heading, transform};
use crate::motion::connect::{blend, connect, loop_clip, ConnectParams, Direction, Method};
use crate::motion::matching::{MatchParams, Metric};
use crate::motion::plot::{draw, ConnectionPlot};
use crate::motion::seam::seam_report;
use crate::motion::{Motion, CMU_FRAME_RATE};
use crate::skeleton::MAX_CHANNELS;
use clap::{Parser, Subcommand, ValueEnum};
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};

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
        #[command(flatten)]
        loop_args: crate::play_cli::LoopArgs,
    },
    /// Follow effector targets (file, stdin or UDP) with inverse kinematics at a fixed rate.
    Follow {
        /// The rig profile.
        profile: PathBuf,
        /// Skeleton (.asf).
        asf: PathBuf,
        /// Targets: a CSV or JSON-lines file, `-` for stdin, or udp://127.0.0.1:PORT.
        #[arg(long)]
        targets: String,
        /// The effector bones (their tips follow the targets).
        #[arg(long, value_delimiter = ',', default_value = "lradius,rradius,ltibia,rtibia")]
        effectors: Vec<String>,
        /// Start a target file over at its end.
        #[arg(long = "loop")]
        looping: bool,
        #[command(flatten)]
        loop_args: crate::play_cli::LoopArgs,
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
        #[arg(long, value_enum, default_value_t = crate::play_cli::TargetFormat::Csv)]
        format: crate::play_cli::TargetFormat,
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
        command: crate::sim_cli::SimCommand,
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
        #[arg(long, value_enum)]
        method: Option<crate::ik_cli::IkMethod>,
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
        #[arg(long, value_enum, default_value_t = Format::Csv)]
        format: Format,
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
        /// Frames to insert (interp); default: enough to keep joint speeds within the inputs'.
        #[arg(long)]
        insert: Option<usize>,
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

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum Format {
    Csv,
    Json,
}

/// Length units a BVH file may be in.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum BvhUnit {
    /// Millimetres.
    Mm,
    /// Centimetres.
    Cm,
    /// Metres.
    M,
    /// Inches.
    In,
    /// CMU ASF units (1/0.45 inch), as in the CMU BVH conversions that keep ASF lengths.
    Cmu,
}

impl BvhUnit {
    fn inches(self) -> f64 {
        match self {
            BvhUnit::Mm => 1.0 / 25.4,
            BvhUnit::Cm => 1.0 / 2.54,
            BvhUnit::M => 1.0 / 0.0254,
            BvhUnit::In => 1.0,
            BvhUnit::Cmu => 1.0 / 0.45,
        }
    }
}

/// Why a command failed; printed as one line.
#[derive(Debug, thiserror::Error)]
pub enum CliError {
    /// A file could not be read, parsed or written.
    #[error(transparent)]
    File(#[from] FileError),
    /// The arguments do not fit together.
    #[error("{0}")]
    Usage(String),
    /// Writing the output failed.
    #[error("writing output: {0}")]
    Output(#[from] io::Error),
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
            loop_args,
        } => crate::play_cli::play_cmd(
            &profile,
            &asf,
            &amc,
            looping,
            speed,
            start,
            &loop_args,
            allocations,
            &mut io::stdout().lock(),
        ),
        Command::Follow {
            profile,
            asf,
            targets,
            effectors,
            looping,
            loop_args,
        } => crate::play_cli::follow_cmd(
            &profile,
            &asf,
            &targets,
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
            output,
        } => crate::play_cli::targets_cmd(
            &asf,
            &amc,
            &effectors,
            match frame {
                FrameArg::Limb => crate::control::sources::TrackFrame::Limb,
                FrameArg::Root => crate::control::sources::TrackFrame::Root,
            },
            format,
            &output,
            &mut io::stdout().lock(),
        ),
        Command::Profile { profile, asf } => {
            crate::rig_cli::profile_cmd(&profile, asf.as_deref(), &mut io::stdout().lock())
        }
        Command::Sim { command } => crate::sim_cli::sim_cmd(&command, &mut io::stdout().lock()),
        Command::Budget { profile, rate, json } => {
            crate::rig_cli::budget_cmd(&profile, rate, json, &mut io::stdout().lock())
        }
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
        } => (|| {
            let target = crate::ik_cli::parse_vec3(&target, "--target")?;
            let point_dir = point_dir
                .as_deref()
                .map(|p| crate::ik_cli::parse_vec3(p, "--point-dir"))
                .transpose()?;
            if point_dir.is_some_and(|d| d.length() < 1e-12) {
                return Err(CliError::Usage("--point-dir must not be zero".into()));
            }
            if roll.is_some_and(|r| !r.is_finite()) {
                return Err(CliError::Usage(
                    "--roll must be a finite number of degrees".into(),
                ));
            }
            let args = crate::ik_cli::IkArgs {
                asf: &asf,
                amc: amc.as_deref(),
                frame,
                effector: &effector,
                target,
                point_dir,
                roll,
                method,
                output: output.as_deref(),
            };
            crate::ik_cli::ik_cmd(&args, &mut io::stdout().lock())
        })(),
        Command::IkEdit {
            asf,
            amc,
            pin,
            frames,
            blend,
            output,
        } => crate::ik_cli::ik_edit_cmd(
            &crate::ik_cli::IkEditArgs {
                asf: &asf,
                amc: &amc,
                pins: &pin,
                frames: &frames,
                blend,
                output: &output,
            },
            &mut io::stdout().lock(),
        ),
        Command::Ports => crate::rig_cli::ports_cmd(&mut io::stdout().lock()),
        Command::Scan {
            port,
            baud,
            r#virtual,
        } => crate::rig_cli::scan_cmd(
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
        } => info(&skeleton, amc.as_deref(), fps, bvh_unit),
        Command::Fk {
            asf,
            amc,
            every,
            frames,
            meters,
            format,
        } => fk(&asf, &amc, every as usize, frames.as_deref(), meters, format),
        Command::Convert {
            input,
            output,
            asf,
            asf_out,
            bvh_unit,
        } => convert(&input, &output, asf.as_deref(), asf_out.as_deref(), bvh_unit),
        Command::Connect {
            asf,
            a,
            b,
            method,
            direction,
            window,
            metric,
            insert,
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
            };
            connect_cmd(&asf, &a, &b, &params, &output, plot.as_deref())
        }
        Command::Loop {
            asf,
            input,
            output,
            window,
            metric,
            cycles,
            plot,
        } => loop_cmd(
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
        } => transform_cmd(&asf, &input, facing, start.as_deref(), &output),
        Command::Blend {
            asf,
            a,
            b,
            weight,
            output,
        } => blend_cmd(&asf, &a, &b, weight, &output),
    };
    match result {
        // A closed pipe (`marionette fk … | head`) is not a failure.
        Err(CliError::Output(e)) if e.kind() == io::ErrorKind::BrokenPipe => Ok(()),
        other => other,
    }
}

fn extension(p: &Path) -> String {
    p.extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default()
}

fn info(path: &Path, amc_path: Option<&Path>, fps: f64, unit: BvhUnit) -> Result<(), CliError> {
    if !(fps.is_finite() && fps > 0.0) {
        return Err(CliError::Usage(format!(
            "--fps must be a positive number, got {fps}"
        )));
    }
    let (file, motion) = if extension(path) == "bvh" {
        if amc_path.is_some() {
            return Err(CliError::Usage(
                "a BVH file holds its own motion: give no AMC".into(),
            ));
        }
        let (a, m) = bvh::load(path, unit.inches())?;
        (a, Some((path.to_path_buf(), m)))
    } else {
        let a = asf::load(path)?;
        let m = match amc_path {
            Some(p) => {
                let mut m = amc::load(&a.skeleton, p)?;
                m.frame_rate = fps;
                Some((p.to_path_buf(), m))
            }
            None => None,
        };
        (a, m)
    };
    let out = io::stdout();
    let mut w = BufWriter::new(out.lock());
    write_info(
        &mut w,
        path,
        &file,
        motion.as_ref().map(|(p, m)| (p.as_path(), m)),
    )?;
    w.flush()?;
    Ok(())
}

fn write_info(
    w: &mut impl Write,
    path: &Path,
    file: &AsfFile,
    motion: Option<(&Path, &Motion)>,
) -> io::Result<()> {
    let s = &file.skeleton;
    let u = s.units();
    writeln!(
        w,
        "skeleton  {}  (name '{}', version '{}')",
        path.display(),
        file.name,
        file.version
    )?;
    writeln!(
        w,
        "units     length {} (1 unit = {:.4} in = {:.6} m), angle {}, mass {}",
        u.length,
        1.0 / u.length,
        u.meters_per_unit(),
        if u.degrees { "deg" } else { "rad" },
        u.mass
    )?;
    let root = s.root();
    let order: Vec<String> = root.order.iter().map(|d| d.name().to_uppercase()).collect();
    let o = root.orientation.map(|a| f64::from(a).to_degrees());
    writeln!(
        w,
        "root      order {}, axis {}, position {} {} {}, orientation {:.3} {:.3} {:.3} deg",
        order.join(" "),
        root.axis_order.name(),
        root.position.x,
        root.position.y,
        root.position.z,
        o[0],
        o[1],
        o[2]
    )?;
    let dof_count: usize = s.bones().iter().map(|b| b.dofs().len()).sum();
    let rot: usize = s
        .bones()
        .iter()
        .flat_map(|b| b.dofs())
        .filter(|d| d.is_rotation())
        .count();
    writeln!(
        w,
        "bones     {} (root included), {} DOFs ({} rotations), frame vector of {} channels",
        s.len(),
        dof_count,
        rot,
        s.channel_count()
    )?;
    let name_w = s.bones().iter().map(|b| b.name().len()).max().unwrap_or(4).max(4);
    writeln!(
        w,
        "  {:>2}  {:<name_w$}  {:<name_w$}  {:>8}  {:<6}  {:<17}  limits (deg; translations in units)",
        "#", "bone", "parent", "length", "axis", "dofs"
    )?;
    for (i, b) in s.bones().iter().enumerate() {
        let parent = b.parent().map_or("-", |p| s.bones()[p].name());
        let dofs: Vec<&str> = b.dofs().iter().map(|d| d.name()).collect();
        let limits: Vec<String> = b
            .dofs()
            .iter()
            .zip(b.limits())
            .filter(|(_, l)| l.min.is_finite() || l.max.is_finite())
            .map(|(d, l)| {
                let f = |v: f32| {
                    if v.is_infinite() {
                        if v > 0.0 {
                            "inf".into()
                        } else {
                            "-inf".into()
                        }
                    } else if d.is_rotation() {
                        format!("{:.1}", f64::from(v).to_degrees())
                    } else {
                        format!("{v}")
                    }
                };
                format!("{}[{},{}]", d.name(), f(l.min), f(l.max))
            })
            .collect();
        writeln!(
            w,
            "  {:>2}  {:<name_w$}  {:<name_w$}  {:>8.4}  {:<6}  {:<17}  {}",
            i,
            b.name(),
            parent,
            b.length(),
            b.spec().axis_order.name(),
            if dofs.is_empty() {
                "-".into()
            } else {
                dofs.join(" ")
            },
            limits.join(" ")
        )?;
    }
    if let Some((p, m)) = motion {
        let last = m.first_frame + m.len() as i64 - 1;
        writeln!(
            w,
            "motion    {}: {} frames ({}..{}) at {} Hz = {:.3} s",
            p.display(),
            m.len(),
            m.first_frame,
            last,
            m.frame_rate,
            m.duration()
        )?;
    }
    Ok(())
}

/// Parses `A..B`, `A..`, `..B` against a clip's frame numbers; returns 0-based indices.
fn frame_range(spec: Option<&str>, motion: &Motion) -> Result<(usize, usize), CliError> {
    let first = motion.first_frame;
    let last = first + motion.len() as i64 - 1;
    let Some(spec) = spec else {
        return Ok((0, motion.len() - 1));
    };
    let bad = || CliError::Usage(format!("--frames must look like A..B, A.. or ..B, got '{spec}'"));
    let (a, b) = spec.split_once("..").ok_or_else(bad)?;
    let b = b.strip_prefix('=').unwrap_or(b);
    let a: i64 = if a.trim().is_empty() {
        first
    } else {
        a.trim().parse().map_err(|_| bad())?
    };
    let b: i64 = if b.trim().is_empty() {
        last
    } else {
        b.trim().parse().map_err(|_| bad())?
    };
    if a > b || a < first || b > last {
        return Err(CliError::Usage(format!(
            "--frames {a}..{b} is not inside the clip's frames {first}..{last}"
        )));
    }
    Ok(((a - first) as usize, (b - first) as usize))
}

fn fk(
    asf_path: &Path,
    amc_path: &Path,
    every: usize,
    frames: Option<&str>,
    meters: bool,
    format: Format,
) -> Result<(), CliError> {
    let file = asf::load(asf_path)?;
    let s = &file.skeleton;
    let motion = amc::load(s, amc_path)?;
    let (from, to) = frame_range(frames, &motion)?;
    let scale = if meters { s.units().meters_per_unit() } else { 1.0 };
    let out = io::stdout();
    let mut w = BufWriter::with_capacity(1 << 16, out.lock());
    let mut channels = [0.0f32; MAX_CHANNELS];
    let mut pose = Pose::new();
    match format {
        Format::Csv => writeln!(w, "frame,bone,x,y,z")?,
        Format::Json => {
            write!(
                w,
                "{{\"units\":\"{}\",\"frame_rate\":{},\"bones\":[",
                if meters { "m" } else { "file" },
                motion.frame_rate
            )?;
            for (i, b) in s.bones().iter().enumerate() {
                let sep = if i == 0 { "" } else { "," };
                write!(w, "{sep}{}", serde_json::to_string(b.name()).unwrap_or_default())?;
            }
            write!(w, "],\"frames\":[")?;
        }
    }
    for (k, i) in (from..=to).step_by(every).enumerate() {
        motion.channels_into(s, i, &mut channels);
        forward_kinematics(s, &channels, &mut pose).map_err(|e| CliError::Usage(e.to_string()))?;
        let number = motion.first_frame + i as i64;
        match format {
            Format::Csv => {
                for (b, bone) in s.bones().iter().enumerate() {
                    let p = pose.tip[b] * scale;
                    writeln!(w, "{number},{},{:.6},{:.6},{:.6}", bone.name(), p.x, p.y, p.z)?;
                }
            }
            Format::Json => {
                let sep = if k == 0 { "" } else { "," };
                write!(w, "{sep}{{\"frame\":{number},\"tips\":[")?;
                for b in 0..s.len() {
                    let p = pose.tip[b] * scale;
                    let sep = if b == 0 { "" } else { "," };
                    write!(w, "{sep}[{:.6},{:.6},{:.6}]", p.x, p.y, p.z)?;
                }
                write!(w, "]}}")?;
            }
        }
    }
    if format == Format::Json {
        writeln!(w, "]}}")?;
    }
    w.flush()?;
    Ok(())
}

/// The ASF beside an AMC: `<stem>.asf`, then `<subject>.asf` for CMU names like `16_15.amc`.
fn find_asf(amc_path: &Path) -> Option<PathBuf> {
    let stem = amc_path.file_stem()?.to_string_lossy().to_string();
    let dir = amc_path.parent().unwrap_or(Path::new(""));
    let mut candidates = vec![dir.join(format!("{stem}.asf"))];
    if let Some((subject, _)) = stem.split_once('_') {
        candidates.push(dir.join(format!("{subject}.asf")));
    }
    candidates.into_iter().find(|p| p.is_file())
}

fn convert(
    input: &Path,
    output: &Path,
    asf_in: Option<&Path>,
    asf_out: Option<&Path>,
    unit: BvhUnit,
) -> Result<(), CliError> {
    let (file, motion) = match extension(input).as_str() {
        "bvh" => {
            let (a, m) = bvh::load(input, unit.inches())?;
            (a, Some(m))
        }
        "amc" => {
            let asf_path = match asf_in {
                Some(p) => p.to_path_buf(),
                None => find_asf(input).ok_or_else(|| {
                    CliError::Usage(format!(
                        "{}: an AMC file needs its skeleton: pass --asf <FILE>",
                        input.display()
                    ))
                })?,
            };
            let a = asf::load(&asf_path)?;
            let m = amc::load(&a.skeleton, input)?;
            (a, Some(m))
        }
        "asf" => (asf::load(input)?, None),
        other => {
            return Err(CliError::Usage(format!(
                "{}: unknown input type '.{other}' (expected .bvh, .amc or .asf)",
                input.display()
            )))
        }
    };
    let need_motion = || {
        motion
            .as_ref()
            .ok_or_else(|| CliError::Usage(format!("{} holds no motion to write", input.display())))
    };
    match extension(output).as_str() {
        "bvh" => bvh::save(&file.skeleton, need_motion()?, output)?,
        "amc" => {
            let m = need_motion()?;
            let skel_path = asf_out.map_or_else(|| output.with_extension("asf"), Path::to_path_buf);
            if skel_path == input {
                return Err(CliError::Usage("refusing to overwrite the input skeleton".into()));
            }
            save_asf(&file, &skel_path)?;
            amc::save(&file.skeleton, m, output)?;
        }
        "asf" => save_asf(&file, output)?,
        other => {
            return Err(CliError::Usage(format!(
                "{}: unknown output type '.{other}' (expected .bvh, .amc or .asf)",
                output.display()
            )))
        }
    }
    Ok(())
}

fn save_asf(file: &AsfFile, path: &Path) -> Result<(), FileError> {
    let f = std::fs::File::create(path).map_err(|e| FileError::io(path, e))?;
    let mut w = BufWriter::new(f);
    asf::write(file, &mut w)
        .and_then(|()| w.flush())
        .map_err(|e| FileError::io(path, e))
}

fn load_clip(asf_path: &Path, amc_paths: &[&Path]) -> Result<(AsfFile, Vec<Motion>), CliError> {
    let file = asf::load(asf_path)?;
    let motions = amc_paths
        .iter()
        .map(|p| amc::load(&file.skeleton, p))
        .collect::<Result<Vec<_>, _>>()?;
    Ok((file, motions))
}

fn save_clip(file: &AsfFile, motion: &Motion, output: &Path) -> Result<(), CliError> {
    if extension(output) != "amc" {
        return Err(CliError::Usage(format!(
            "{}: the output must be an .amc file",
            output.display()
        )));
    }
    amc::save(&file.skeleton, motion, output)?;
    Ok(())
}

fn stem(p: &Path) -> String {
    p.file_stem()
        .map_or_else(|| p.display().to_string(), |s| s.to_string_lossy().to_string())
}

fn connect_cmd(
    asf_path: &Path,
    a_path: &Path,
    b_path: &Path,
    params: &ConnectParams,
    output: &Path,
    plot: Option<&Path>,
) -> Result<(), CliError> {
    let (file, clips) = load_clip(asf_path, &[a_path, b_path])?;
    let (s, a, b) = (&file.skeleton, &clips[0], &clips[1]);
    let c = connect(s, a, b, params).map_err(|e| CliError::Usage(e.to_string()))?;
    let mut out = c.motion.clone();
    out.first_frame = 1;
    save_clip(&file, &out, output)?;
    let (searched, kept_whole) = match params.direction {
        Direction::Forward => ("B", "A"),
        Direction::Backward => ("A", "B"),
    };
    let mut w = io::stdout().lock();
    writeln!(
        w,
        "matched   {:?} matching, window {} frames, metric {:?}: best window of {searched} starts at its frame {} (distance {:.4}); {kept_whole} kept whole",
        params.direction,
        params.matching.window,
        params.matching.metric,
        c.matching.best + 1,
        c.matching.best_distance
    )?;
    let how = match params.method {
        Method::Interpolate => "interpolated",
        Method::Blend => "blended",
    };
    writeln!(
        w,
        "result    {} frames: A {}..{}, {} {how}, B {}..{}",
        out.len(),
        c.a_kept.start + 1,
        c.a_kept.end,
        c.seam.len(),
        c.b_kept.start + 1,
        c.b_kept.end
    )?;
    write_seam(&mut w, &seam_report(s, &[a, b], &out, c.seam.clone()))?;
    writeln!(w, "wrote     {}", output.display())?;
    if let Some(p) = plot {
        draw(
            s,
            &ConnectionPlot {
                title: format!(
                    "connect {} → {} ({how}, {:?} matching)",
                    stem(a_path),
                    stem(b_path),
                    params.direction
                ),
                inputs: vec![("A", a), ("B", b)],
                result: &out,
                seam: c.seam.clone(),
                distances: &c.matching.distances,
                distance_axis: format!("start frame of the window in {searched} (0-based)"),
                best: c.matching.best,
            },
            p,
        )
        .map_err(CliError::Usage)?;
        writeln!(w, "drew      {}", p.display())?;
    }
    Ok(())
}

fn write_seam(w: &mut impl Write, r: &crate::motion::seam::SeamReport) -> io::Result<()> {
    writeln!(w, "seam      {r}")
}

fn loop_cmd(
    asf_path: &Path,
    input: &Path,
    matching: &MatchParams,
    cycles: usize,
    output: &Path,
    plot: Option<&Path>,
) -> Result<(), CliError> {
    if cycles == 0 {
        return Err(CliError::Usage("--cycles must be at least 1".into()));
    }
    let (file, clips) = load_clip(asf_path, &[input])?;
    let (s, a) = (&file.skeleton, &clips[0]);
    let l = loop_clip(s, a, matching, cycles).map_err(|e| CliError::Usage(e.to_string()))?;
    save_clip(&file, &l.motion, output)?;
    let mut w = io::stdout().lock();
    writeln!(
        w,
        "matched   the last {} frames against the clip: best window starts at frame {} (distance {:.4})",
        matching.window,
        l.start + 1,
        l.matching.best_distance
    )?;
    writeln!(
        w,
        "cycle     frames {}..{} with the end blended back, {} frames = {:.3} s; {} cycles = {} frames",
        l.start + matching.window + 1,
        a.len(),
        l.period,
        l.period as f64 / a.frame_rate,
        cycles,
        l.motion.len()
    )?;
    // The wrap from one cycle into the next.
    let wrap = if cycles > 1 {
        l.period..l.period
    } else {
        l.seam.clone()
    };
    write_seam(&mut w, &seam_report(s, &[a], &l.motion, wrap.clone()))?;
    writeln!(w, "wrote     {}", output.display())?;
    if let Some(p) = plot {
        draw(
            s,
            &ConnectionPlot {
                title: format!("loop {} ({} cycles)", stem(input), cycles),
                inputs: vec![("clip", a)],
                result: &l.motion,
                seam: l.seam.clone(),
                distances: &l.matching.distances,
                distance_axis: "start frame of the window (0-based)".into(),
                best: l.matching.best,
            },
            p,
        )
        .map_err(CliError::Usage)?;
        writeln!(w, "drew      {}", p.display())?;
    }
    Ok(())
}

fn transform_cmd(
    asf_path: &Path,
    input: &Path,
    facing: f64,
    start: Option<&str>,
    output: &Path,
) -> Result<(), CliError> {
    if !facing.is_finite() {
        return Err(CliError::Usage("--facing must be a number of degrees".into()));
    }
    let start = match start {
        None => None,
        Some(t) => {
            let bad = || CliError::Usage(format!("--start must look like X,Z, got '{t}'"));
            let (x, z) = t.split_once(',').ok_or_else(bad)?;
            let x: f64 = x.trim().parse().map_err(|_| bad())?;
            let z: f64 = z.trim().parse().map_err(|_| bad())?;
            if !(x.is_finite() && z.is_finite()) {
                return Err(bad());
            }
            Some((x, z))
        }
    };
    let (file, clips) = load_clip(asf_path, &[input])?;
    let s = &file.skeleton;
    let out = transform(s, &clips[0], facing.to_radians(), start);
    save_clip(&file, &out, output)?;
    let (f0, p0) = heading(s, &clips[0], 0);
    let (f1, p1) = heading(s, &out, 0);
    let mut w = io::stdout().lock();
    writeln!(
        w,
        "first frame: facing {:.3}° → {:.3}°, root ({:.4}, {:.4}, {:.4}) → ({:.4}, {:.4}, {:.4})",
        f0.to_degrees(),
        f1.to_degrees(),
        p0.x,
        p0.y,
        p0.z,
        p1.x,
        p1.y,
        p1.z
    )?;
    writeln!(w, "wrote {} ({} frames)", output.display(), out.len())?;
    Ok(())
}

fn blend_cmd(
    asf_path: &Path,
    a_path: &Path,
    b_path: &Path,
    weight: f64,
    output: &Path,
) -> Result<(), CliError> {
    if !(0.0..=1.0).contains(&weight) {
        return Err(CliError::Usage(format!(
            "--weight must be between 0 and 1, got {weight}"
        )));
    }
    let (file, clips) = load_clip(asf_path, &[a_path, b_path])?;
    let out = blend(&file.skeleton, &clips[0], &clips[1], weight);
    save_clip(&file, &out, output)?;
    writeln!(
        io::stdout().lock(),
        "wrote {} ({} frames, {:.0}% A + {:.0}% B)",
        output.display(),
        out.len(),
        (1.0 - weight) * 100.0,
        weight * 100.0
    )?;
    Ok(())
}
