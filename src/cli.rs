//! The `marionette` command line.

use crate::fk::{forward_kinematics, Pose};
use crate::formats::asf::AsfFile;
use crate::formats::{amc, asf, bvh, FileError};
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

/// Runs the command line; the process exit code is 0 on `Ok`.
///
/// # Errors
/// [`CliError`], to be printed on one line.
pub fn run(cli: Cli) -> Result<(), CliError> {
    let result = match cli.command {
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
