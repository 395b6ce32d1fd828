//! The motion-editing commands: `connect`, `loop`, `transform`, `blend` (help note §III).

use std::io::{self, Write};
use std::path::Path;

use super::args::extension;
use super::error::CliError;
use super::DirectionArg;
use super::MethodArg;
use super::MetricArg;
use crate::formats::asf::AsfFile;
use crate::formats::{amc, asf};
use crate::motion::clip::{bend, heading, transform};
use crate::motion::connect::{blend, connect, loop_clip, ConnectParams, Direction, Method};
use crate::motion::matching::MatchParams;
use crate::motion::plot::{ConnectionPicture, ConnectionPlot};
use crate::motion::seam::seam_report;
use crate::motion::Motion;
use crate::plot::{draw, Format};
use crate::skeleton::Skeleton;
use clap::Args;
use std::path::PathBuf;

/// Loads the skeleton and the clips, each clip's calibration pose before the capture left out
/// and its capture dropouts filled (and said so): an edit should not carry a capture's glitch
/// into its seams.
fn load_clip(asf_path: &Path, amc_paths: &[&Path]) -> Result<(AsfFile, Vec<Motion>), CliError> {
    let file = asf::load(asf_path)?;
    let mut motions = Vec::with_capacity(amc_paths.len());
    for p in amc_paths {
        let mut m = amc::load(&file.skeleton, p)?;
        if let Some(pose) = crate::motion::calibration::leave_out(&file.skeleton, &mut m) {
            writeln!(io::stdout().lock(), "{}: {pose}; left out", p.display())?;
        }
        for d in crate::motion::dropouts::repair(&file.skeleton, &mut m) {
            writeln!(
                io::stdout().lock(),
                "{}: capture dropout filled: {d}",
                p.display()
            )?;
        }
        motions.push(m);
    }
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

/// Draws a connection picture and says so.
fn draw_connection(
    w: &mut impl Write,
    skeleton: &Skeleton,
    plot: &ConnectionPlot<'_>,
    path: &Path,
) -> Result<(), CliError> {
    let picture = ConnectionPicture { skeleton, plot };
    draw(&picture, ConnectionPicture::SIZE, path)?;
    writeln!(w, "drew      {}", path.display())?;
    Ok(())
}

/// Refuses a `--plot` file type before any work is done.
fn check_plot(plot: Option<&Path>) -> Result<(), CliError> {
    match plot.map(Format::of) {
        Some(Err(e)) => Err(CliError::Usage(format!("--plot {e}"))),
        _ => Ok(()),
    }
}

pub(super) fn connect_cmd(
    asf_path: &Path,
    a_path: &Path,
    b_path: &Path,
    params: &ConnectParams,
    output: &Path,
    plot: Option<&Path>,
) -> Result<(), CliError> {
    check_plot(plot)?;
    let (file, clips) = load_clip(asf_path, &[a_path, b_path])?;
    let (s, a, b) = (&file.skeleton, &clips[0], &clips[1]);
    let c = connect(s, a, b, params)?;
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
    let worst: Vec<String> = c
        .bones
        .iter()
        .take(3)
        .map(|b| format!("{} {:.2}", b.name, b.ratio))
        .collect();
    writeln!(
        w,
        "bones     worst change per frame across the seam against each bone's own allowance (1.5× its p99 in the inputs + 1°): {} — {}",
        worst.join(", "),
        if c.worst_ratio() <= 1.0 {
            "every bone within it"
        } else {
            "the clips end before a longer transition"
        }
    )?;
    writeln!(w, "wrote     {}", output.display())?;
    if let Some(p) = plot {
        let plot = ConnectionPlot {
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
        };
        draw_connection(&mut w, s, &plot, p)?;
    }
    Ok(())
}

pub(super) fn write_seam(w: &mut impl Write, r: &crate::motion::seam::SeamReport) -> io::Result<()> {
    writeln!(w, "seam      {r}")
}

pub(super) fn loop_cmd(
    asf_path: &Path,
    input: &Path,
    matching: &MatchParams,
    cycles: usize,
    output: &Path,
    plot: Option<&Path>,
) -> Result<(), CliError> {
    check_plot(plot)?;
    if cycles == 0 {
        return Err(CliError::Usage("--cycles must be at least 1".into()));
    }
    let (file, clips) = load_clip(asf_path, &[input])?;
    let (s, a) = (&file.skeleton, &clips[0]);
    let l = loop_clip(s, a, matching, cycles)?;
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
        let plot = ConnectionPlot {
            title: format!("loop {} ({} cycles)", stem(input), cycles),
            inputs: vec![("clip", a)],
            result: &l.motion,
            seam: l.seam.clone(),
            distances: &l.matching.distances,
            distance_axis: "start frame of the window (0-based)".into(),
            best: l.matching.best,
        };
        draw_connection(&mut w, s, &plot, p)?;
    }
    Ok(())
}

pub(super) fn transform_cmd(
    asf_path: &Path,
    input: &Path,
    facing: Option<f64>,
    turn: f64,
    start: Option<&str>,
    output: &Path,
) -> Result<(), CliError> {
    if !facing.is_none_or(f64::is_finite) {
        return Err(CliError::Usage("--facing must be a number of degrees".into()));
    }
    if !turn.is_finite() {
        return Err(CliError::Usage("--turn must be a number of degrees".into()));
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
    let facing = facing.map_or_else(|| heading(s, &clips[0], 0).0, f64::to_radians);
    let out = transform(s, &bend(s, &clips[0], turn.to_radians()), facing, start);
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

pub(super) fn blend_cmd(
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

/// The arguments of `marionette connect`.
#[derive(Debug, Args)]
pub(super) struct ConnectArgs {
    /// Skeleton (.asf) of both clips.
    pub(super) asf: PathBuf,
    /// First clip (.amc).
    pub(super) a: PathBuf,
    /// Second clip (.amc).
    pub(super) b: PathBuf,
    /// Interpolate between the end poses, or blend the overlapping windows.
    #[arg(long, value_enum, default_value_t = MethodArg::Interp)]
    pub(super) method: MethodArg,
    /// Forward: match A's end in B (A kept whole); backward: B's start in A.
    #[arg(long = "match", value_enum, default_value_t = DirectionArg::Forward)]
    pub(super) direction: DirectionArg,
    /// Matching window, frames.
    #[arg(long, default_value_t = 30)]
    pub(super) window: usize,
    /// Joint distance for matching.
    #[arg(long, value_enum, default_value_t = MetricArg::Quat)]
    pub(super) metric: MetricArg,
    /// Frames to insert (interp); default: as few as keep every bone, and the root, within
    /// 1.5× its own 99th-percentile speed in the inputs (+1°).
    #[arg(long)]
    pub(super) insert: Option<usize>,
    /// Frames to blend over (blend); default: from the matching window up, as few as keep
    /// every bone within its own speeds in the inputs.
    #[arg(long)]
    pub(super) blend_window: Option<usize>,
    /// Output clip (.amc).
    #[arg(short, long)]
    pub(super) output: PathBuf,
    /// Picture of the root paths and the matching curve (.svg or .png).
    #[arg(long)]
    pub(super) plot: Option<PathBuf>,
}

impl ConnectArgs {
    /// Runs it.
    ///
    /// # Errors
    /// [`CliError`].
    pub(super) fn run(self) -> Result<(), CliError> {
        let ConnectArgs {
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
        } = self;
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
        connect_cmd(&asf, &a, &b, &params, &output, plot.as_deref())
    }
}

/// The arguments of `marionette loop`.
#[derive(Debug, Args)]
pub(super) struct LoopCmd {
    /// Skeleton (.asf).
    pub(super) asf: PathBuf,
    /// Clip (.amc).
    pub(super) input: PathBuf,
    /// Output clip (.amc).
    #[arg(short, long)]
    pub(super) output: PathBuf,
    /// Matching window, frames.
    #[arg(long, default_value_t = 30)]
    pub(super) window: usize,
    /// Joint distance for matching.
    #[arg(long, value_enum, default_value_t = MetricArg::Quat)]
    pub(super) metric: MetricArg,
    /// How many cycles to write, the root carried on from one to the next.
    #[arg(long, default_value_t = 2)]
    pub(super) cycles: usize,
    /// Picture of the root path and the matching curve (.svg or .png).
    #[arg(long)]
    pub(super) plot: Option<PathBuf>,
}

impl LoopCmd {
    /// Runs it.
    ///
    /// # Errors
    /// [`CliError`].
    pub(super) fn run(self) -> Result<(), CliError> {
        let LoopCmd {
            asf,
            input,
            output,
            window,
            metric,
            cycles,
            plot,
        } = self;
        loop_cmd(
            &asf,
            &input,
            &MatchParams::new(window, metric.metric()),
            cycles,
            &output,
            plot.as_deref(),
        )
    }
}

/// The arguments of `marionette transform`.
#[derive(Debug, Args)]
pub(super) struct TransformArgs {
    /// Skeleton (.asf).
    pub(super) asf: PathBuf,
    /// Clip (.amc).
    pub(super) input: PathBuf,
    /// Facing of the first frame, degrees (0: +z, 90: +x); default: as captured.
    #[arg(long, allow_hyphen_values = true)]
    pub(super) facing: Option<f64>,
    /// Bend the path: turn the clip progressively by this many degrees over its length
    /// (positive: to the left, about the vertical), each frame's step over the ground turned
    /// with it — a straight walk becomes a walk with a turn.
    #[arg(long, allow_hyphen_values = true, default_value_t = 0.0)]
    pub(super) turn: f64,
    /// New start position of the root on the ground, `X,Z` (file units).
    #[arg(long, allow_hyphen_values = true)]
    pub(super) start: Option<String>,
    /// Output clip (.amc).
    #[arg(short, long)]
    pub(super) output: PathBuf,
}

impl TransformArgs {
    /// Runs it.
    ///
    /// # Errors
    /// [`CliError`].
    pub(super) fn run(self) -> Result<(), CliError> {
        let TransformArgs {
            asf,
            input,
            facing,
            turn,
            start,
            output,
        } = self;
        transform_cmd(&asf, &input, facing, turn, start.as_deref(), &output)
    }
}

/// The arguments of `marionette blend`.
#[derive(Debug, Args)]
pub(super) struct BlendArgs {
    /// Skeleton (.asf) of both clips.
    pub(super) asf: PathBuf,
    /// First clip (.amc).
    pub(super) a: PathBuf,
    /// Second clip (.amc).
    pub(super) b: PathBuf,
    /// Weight of B, 0 to 1.
    #[arg(long)]
    pub(super) weight: f64,
    /// Output clip (.amc).
    #[arg(short, long)]
    pub(super) output: PathBuf,
}

impl BlendArgs {
    /// Runs it.
    ///
    /// # Errors
    /// [`CliError`].
    pub(super) fn run(self) -> Result<(), CliError> {
        let BlendArgs {
            asf,
            a,
            b,
            weight,
            output,
        } = self;
        blend_cmd(&asf, &a, &b, weight, &output)
    }
}
