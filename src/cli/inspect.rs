//! `marionette info` and `fk`: describe a skeleton and a motion; bone tip positions per frame.

use std::io::{self, BufWriter, Write};
use std::path::Path;

use super::args::{asf_beside, extension, BvhUnit, RoundedHz, TableFormat};
use super::error::CliError;
use crate::fk::{forward_kinematics, Pose};
use crate::formats::asf::AsfFile;
use crate::formats::{amc, asf, bvh};
use crate::motion::Motion;
use crate::motion::CMU_FRAME_RATE;
use crate::skeleton::MAX_CHANNELS;
use clap::Args;
use std::path::PathBuf;

pub(super) fn info(path: &Path, amc_path: Option<&Path>, fps: f64, unit: BvhUnit) -> Result<(), CliError> {
    if !(fps.is_finite() && fps > 0.0) {
        return Err(CliError::Usage(format!(
            "--fps must be a positive number, got {fps}"
        )));
    }
    // An AMC alone: its skeleton is the ASF beside it.
    let beside;
    let (path, amc_path) = match (extension(path).as_str(), amc_path) {
        ("amc", None) => {
            beside = asf_beside(path).ok_or_else(|| {
                CliError::Usage(format!(
                    "{}: an AMC file is a motion; give its skeleton first: marionette info SKELETON.asf {}",
                    path.display(),
                    path.display()
                ))
            })?;
            (beside.as_path(), Some(path))
        }
        _ => (path, amc_path),
    };
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
            RoundedHz(m.frame_rate),
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

pub(super) fn fk(
    asf_path: &Path,
    amc_path: &Path,
    every: usize,
    frames: Option<&str>,
    meters: bool,
    format: TableFormat,
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
        TableFormat::Csv => writeln!(w, "frame,bone,x,y,z")?,
        TableFormat::Json => {
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
        forward_kinematics(s, &channels, &mut pose)?;
        let number = motion.first_frame + i as i64;
        match format {
            TableFormat::Csv => {
                for (b, bone) in s.bones().iter().enumerate() {
                    let p = pose.tip[b] * scale;
                    writeln!(w, "{number},{},{:.6},{:.6},{:.6}", bone.name(), p.x, p.y, p.z)?;
                }
            }
            TableFormat::Json => {
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
    if format == TableFormat::Json {
        writeln!(w, "]}}")?;
    }
    w.flush()?;
    Ok(())
}

/// The arguments of `marionette info`.
#[derive(Debug, Args)]
pub(super) struct InfoArgs {
    /// Skeleton: an .asf file, or a .bvh file (skeleton and motion).
    pub(super) skeleton: PathBuf,
    /// Motion: an .amc file for the skeleton.
    pub(super) amc: Option<PathBuf>,
    /// Frame rate of the AMC file (AMC files do not state it; CMU captures are 120 Hz).
    #[arg(long, default_value_t = CMU_FRAME_RATE)]
    pub(super) fps: f64,
    /// Length unit of a BVH file.
    #[arg(long, value_enum, default_value_t = BvhUnit::Cm)]
    pub(super) bvh_unit: BvhUnit,
}

impl InfoArgs {
    /// Runs it.
    ///
    /// # Errors
    /// [`CliError`].
    pub(super) fn run(self) -> Result<(), CliError> {
        let InfoArgs {
            skeleton,
            amc,
            fps,
            bvh_unit,
        } = self;
        info(&skeleton, amc.as_deref(), fps, bvh_unit)
    }
}

/// The arguments of `marionette fk`.
#[derive(Debug, Args)]
pub(super) struct FkArgs {
    /// Skeleton (.asf).
    pub(super) asf: PathBuf,
    /// Motion (.amc).
    pub(super) amc: PathBuf,
    /// Every N-th frame: A, A+N, A+2N, … (A: the first frame of the range).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..))]
    pub(super) every: u64,
    /// Frame range, inclusive, in the AMC's frame numbers: `A..B`, `A..` or `..B`.
    #[arg(long)]
    pub(super) frames: Option<String>,
    /// Positions in metres instead of ASF file units.
    #[arg(long)]
    pub(super) meters: bool,
    /// Output format.
    #[arg(long, value_enum, default_value_t = TableFormat::Csv)]
    pub(super) format: TableFormat,
}

impl FkArgs {
    /// Runs it.
    ///
    /// # Errors
    /// [`CliError`].
    pub(super) fn run(self) -> Result<(), CliError> {
        let FkArgs {
            asf,
            amc,
            every,
            frames,
            meters,
            format,
        } = self;
        fk(&asf, &amc, every as usize, frames.as_deref(), meters, format)
    }
}
