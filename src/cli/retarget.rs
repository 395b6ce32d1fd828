//! `marionette retarget`: a clip (ASF + AMC, or BVH) onto a robot through the profile's retarget
//! map: the joint trajectory as CSV, a report (printed; `--report` as JSON), a picture.

use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use super::args::{extension, BvhUnit};
use super::error::CliError;
use crate::formats::{amc, asf, bvh, FileError};
use crate::motion::Motion;
use crate::motion::CMU_FRAME_RATE;
use crate::profile::Profile;
use crate::retarget::walk::{retarget_walking, write_plan_csv, WalkPlan};
use crate::retarget::{retarget_clip, write_csv, Options, RetargetReport, Setup};
use crate::skeleton::Skeleton;
use clap::Args;

/// The command's settings.
pub struct RetargetArgs<'a> {
    pub profile: &'a Path,
    pub skeleton: &'a Path,
    pub amc: Option<&'a Path>,
    pub output: &'a Path,
    pub report: Option<PathBuf>,
    pub plot: Option<PathBuf>,
    pub upper_body: bool,
    pub balance: bool,
    pub walk: bool,
    pub plan: Option<PathBuf>,
    pub fps: f64,
    pub bvh_unit: BvhUnit,
    pub keep_dropouts: bool,
    pub keep_first_frame: bool,
    pub per_frame: bool,
}

/// Reads a skeleton and its clip: `.bvh` alone, or `.asf` with an `.amc` at `fps`.
pub(super) fn load_clip(
    skeleton: &Path,
    amc_path: Option<&Path>,
    fps: f64,
    unit: BvhUnit,
) -> Result<(Skeleton, Motion), CliError> {
    if extension(skeleton) == "bvh" {
        if amc_path.is_some() {
            return Err(CliError::Usage(
                "a BVH file holds its own motion: give no AMC".into(),
            ));
        }
        let (a, m) = bvh::load(skeleton, unit.inches())?;
        return Ok((a.skeleton, m));
    }
    let Some(amc_path) = amc_path else {
        return Err(CliError::Usage(
            "give the clip: SKELETON.asf CLIP.amc, or one .bvh file".into(),
        ));
    };
    let a = asf::load(skeleton)?;
    let mut m = amc::load(&a.skeleton, amc_path)?;
    m.frame_rate = fps;
    Ok((a.skeleton, m))
}

/// `marionette retarget`.
///
/// # Errors
/// [`CliError`].
pub fn retarget_cmd(args: &RetargetArgs<'_>, out: &mut dyn Write) -> Result<(), CliError> {
    if !(args.fps.is_finite() && args.fps > 0.0) {
        return Err(CliError::Usage(format!(
            "--fps must be a positive number, got {}",
            args.fps
        )));
    }
    if let Some(p) = &args.plot {
        crate::plot::Format::of(p)?;
    }
    let profile = Profile::load(args.profile)?;
    let (skeleton, mut motion) = load_clip(args.skeleton, args.amc, args.fps, args.bvh_unit)?;
    // As `play` plays it: a calibration pose before the capture left out, a capture dropout (a
    // bone, or the root, reading exactly zero between far-away frames) filled from its
    // neighbours.
    super::play::clean_clip(
        &skeleton,
        &mut motion,
        super::play::KeepAsRecorded {
            first_frame: args.keep_first_frame,
            dropouts: args.keep_dropouts,
        },
        &args.amc.unwrap_or(args.skeleton).display(),
        ("retargeted", "retargets"),
        out,
    )?;
    let setup = Setup::new(&profile, &skeleton)?;
    let options = Options {
        upper_body: args.upper_body,
        balance: args.balance,
        per_frame: args.per_frame,
    };
    if args.walk && args.upper_body {
        return Err(CliError::Usage(
            "--walk plans the legs; --upper-body keeps them in a stance: give one".into(),
        ));
    }
    if args.plan.is_some() && !args.walk {
        return Err(CliError::Usage(
            "--plan writes the walking plan: give --walk too".into(),
        ));
    }
    // A walk comes to rest after the clip: its last frame held.
    let motion = if args.walk {
        crate::retarget::walk::settled(&motion)
    } else {
        motion
    };
    let (mut run, plan) = if args.walk {
        let (run, plan) = retarget_walking(&setup, &skeleton, &motion, options)
            .map_err(|e| CliError::Usage(format!("cannot plan the walk: {e}")))?;
        (run, Some(plan))
    } else {
        (retarget_clip(&setup, &skeleton, &motion, options), None)
    };
    run.report.walk = plan.as_ref().map(WalkPlan::report);
    let names = setup.joint_names();
    let file = std::fs::File::create(args.output).map_err(|source| FileError::Io {
        path: args.output.to_path_buf(),
        source,
    })?;
    let mut w = BufWriter::new(file);
    write_csv(&mut w, &names, &run)
        .and_then(|()| w.flush())
        .map_err(|source| FileError::Io {
            path: args.output.to_path_buf(),
            source,
        })?;
    if let Some(path) = &args.report {
        let text = serde_json::to_string_pretty(&run.report).map_err(|e| CliError::Usage(e.to_string()))?;
        std::fs::write(path, text + "\n").map_err(|source| FileError::Io {
            path: path.clone(),
            source,
        })?;
    }
    if let (Some(path), Some(plan)) = (&args.plan, &plan) {
        let file = std::fs::File::create(path).map_err(|source| FileError::Io {
            path: path.clone(),
            source,
        })?;
        let mut w = BufWriter::new(file);
        write_plan_csv(&mut w, plan)
            .and_then(|()| w.flush())
            .map_err(|source| FileError::Io {
                path: path.clone(),
                source,
            })?;
    }
    if let Some(path) = &args.plot {
        let picture = crate::retarget::plot::RetargetPicture {
            plan: plan.as_ref(),
            title: format!(
                "{} → {}",
                args.amc.unwrap_or(args.skeleton).display(),
                profile.name
            ),
            skeleton: &skeleton,
            motion: &motion,
            setup: &setup,
            run: &run,
        };
        crate::plot::draw(&picture, (1400, 900), path)?;
    }
    writeln!(
        out,
        "retarget: {} frames of {} onto {} ({} joints){}",
        run.report.frames,
        args.amc.unwrap_or(args.skeleton).display(),
        profile.name,
        names.len(),
        if args.upper_body {
            ", upper body (legs in a stance)"
        } else {
            ""
        }
    )?;
    print_report(&run.report, out)?;
    writeln!(out, "wrote {}", args.output.display())?;
    if let Some(p) = &args.plan {
        writeln!(out, "wrote {}", p.display())?;
    }
    if let Some(p) = &args.report {
        writeln!(out, "wrote {}", p.display())?;
    }
    if let Some(p) = &args.plot {
        writeln!(out, "wrote {}", p.display())?;
    }
    Ok(())
}

/// The report as lines of text.
///
/// # Errors
/// Writing failed.
pub fn print_report(r: &RetargetReport, out: &mut dyn Write) -> std::io::Result<()> {
    let e = &r.limb_direction_error_deg;
    writeln!(
        out,
        "  scale: legs {:.3}, arms {:.3} / {:.3} (robot / human)",
        r.leg_scale, r.arm_scale[0], r.arm_scale[1]
    )?;
    writeln!(
        out,
        "  direction error (deg, in the pelvis frame)      RMS     max"
    )?;
    for (name, v) in [
        ("left arm", &e.left_arm),
        ("right arm", &e.right_arm),
        ("left leg", &e.left_leg),
        ("right leg", &e.right_leg),
        ("head", &e.head),
    ] {
        if let Some(v) = v {
            writeln!(out, "    {name:<44}{:>6.2}  {:>6.2}", v.rms, v.max)?;
        }
    }
    writeln!(
        out,
        "    {:<44}{:>6.2}  {:>6.2}",
        "overall", e.overall.rms, e.overall.max
    )?;
    let h = &r.hand_error_mm;
    if h.left.is_some() || h.right.is_some() {
        writeln!(
            out,
            "  hand error (mm, the human's hand scaled)        RMS     max"
        )?;
        for (name, v) in [("left hand", &h.left), ("right hand", &h.right)] {
            if let Some(v) = v {
                writeln!(out, "    {name:<44}{:>6.1}  {:>6.1}", v.rms, v.max)?;
            }
        }
    }
    writeln!(
        out,
        "  feet: planted {:.0} % / {:.0} % of frames, slide at most {:.2} mm, lowest sole {:.2} mm above the floor",
        100.0 * r.planted_fraction[0],
        100.0 * r.planted_fraction[1],
        r.foot_slide_mm.max,
        // Rounding noise (a few nanometres below) prints as 0.
        if r.lowest_sole_mm.abs() < 0.005 { 0.0 } else { r.lowest_sole_mm }
    )?;
    match r.com_margin_mm.min {
        Some(m) => writeln!(
            out,
            "  balance: centre of mass at least {m:.1} mm inside the support polygon"
        )?,
        None => writeln!(out, "  balance: no foot planted")?,
    }
    writeln!(
        out,
        "  limits: {} joint values held at a limit, {} foot targets out of reach",
        r.limit_clamps, r.out_of_reach
    )?;
    writeln!(
        out,
        "  continuity: largest joint step {:.2}° ({} at frame {})",
        r.continuity.max_joint_step_deg, r.continuity.joint, r.continuity.frame
    )?;
    if let (Some(over), Some(f)) = (r.continuity.steps_over_velocity_limit, &r.continuity.fastest_step) {
        writeln!(
            out,
            "  servo speed: {over} joint steps faster than their servo's velocity limit; the fastest {:.2}× its limit ({} at frame {})",
            f.limit_share, f.joint, f.frame
        )?;
    }
    match &r.continuity.faster_than_servos {
        Some(f) if f.frames > 0 => {
            let list: Vec<String> = f
                .spans_s
                .iter()
                .take(6)
                .map(|[a, b]| format!("{a:.2}–{b:.2}"))
                .collect();
            writeln!(
                out,
                "  the human's arms and head moved faster than the servos can follow in {} frames ({} stretches: {}{} s); the robot lags there",
                f.frames,
                f.spans_s.len(),
                list.join(", "),
                if f.spans_s.len() > 6 { ", …" } else { "" }
            )?;
        }
        Some(_) => writeln!(
            out,
            "  the human's arms and head never moved faster than the servos can follow"
        )?,
        None => writeln!(
            out,
            "  retargeted frame by frame (--per-frame): arm branches by hysteresis, speeds not limited"
        )?,
    }
    if let Some(f) = r
        .continuity
        .faster_than_servos
        .as_ref()
        .filter(|f| f.legs_frames > 0)
    {
        writeln!(
            out,
            "  the legs, on the human's feet, step faster than their servos in {} frames: the servos' limits cut those steps (--walk plans steps the legs can make)",
            f.legs_frames
        )?;
    }
    if !r.standing_s.is_empty() {
        let list: Vec<String> = r
            .standing_s
            .iter()
            .map(|[a, b]| format!("{a:.2}–{b:.2}"))
            .collect();
        writeln!(out, "  standing (both feet planted ≥ 1 s): {} s", list.join(", "))?;
    }
    if let Some(w) = &r.walk {
        writeln!(
            out,
            "  walk: {} footsteps ({} substituted, {} of the clip's left out), travel {:.3} m planned against {:.3} m in the clip",
            w.footsteps, w.substituted_steps, w.dropped_steps, w.planned_travel_m, w.clip_travel_m
        )?;
        writeln!(
            out,
            "  planned ZMP: {:.1} mm inside the support polygon at least, {:.1} mm from its reference at most (preview {:.1} s, centre of mass at {:.3} m)",
            w.zmp_margin_mm.planned_min, w.zmp_tracking_max_mm, w.preview_s, w.com_height_m
        )?;
        let l = &w.limits;
        writeln!(
            out,
            "  step limits: forward {:.3} m, backward {:.3} m, width {:.3}–{:.3} m, turn {:.0}°, swing ≥ {:.2} s, foot ≤ {:.2} m/s, double support ≥ {:.2} s",
            l.forward_m, l.backward_m, l.width_min_m, l.width_max_m, l.turn_deg, l.swing_min_s, l.foot_speed_m_s, l.double_support_s
        )?;
        let mut swings = format!("  swings: the foot lifts {:.0} mm", w.clearance_mm);
        if w.lowered_swings > 0 {
            swings += &format!(
                "; {} lifted lower for the leg servos' speed, the lowest {:.0} mm",
                w.lowered_swings, w.lowest_clearance_mm
            );
        }
        if w.slowed_swings > 0 {
            swings += &format!(
                "; {} slower along the floor, the slowest at {:.0} % of the foot's speed limit",
                w.slowed_swings,
                100.0 * w.slowest_foot_speed_share
            );
        }
        writeln!(out, "{swings}")?;
    }
    if let Some(fps) = r.frames_per_second {
        writeln!(out, "  speed: {fps:.0} frames per second")?;
    }
    Ok(())
}

/// The arguments of `marionette retarget`.
#[derive(Debug, Args)]
pub(super) struct RetargetCmd {
    /// The rig profile with a [retarget] map, e.g. firmware-profile/robotis-op3.toml.
    pub(super) profile: PathBuf,
    /// Skeleton: an .asf file, or a .bvh file (skeleton and motion).
    pub(super) skeleton: PathBuf,
    /// Clip (.amc) for an ASF skeleton.
    pub(super) amc: Option<PathBuf>,
    /// Joint trajectory: time, then one column per robot joint (radians).
    #[arg(short, long)]
    pub(super) output: PathBuf,
    /// Also write the report as JSON.
    #[arg(long)]
    pub(super) report: Option<PathBuf>,
    /// Draw human and robot side by side at a few frames, and the error curves (.svg/.png).
    #[arg(long)]
    pub(super) plot: Option<PathBuf>,
    /// Keep the legs in a standing stance; retarget arms, head and torso only.
    #[arg(long)]
    pub(super) upper_body: bool,
    /// Do not move the pelvis to keep the centre of mass over the planted feet.
    #[arg(long)]
    pub(super) no_balance: bool,
    /// Walk on the robot's own feet: footsteps from the clip (within the robot's reach and
    /// speed), the centre of mass from a ZMP preview controller, the legs on that plan.
    #[arg(long)]
    pub(super) walk: bool,
    /// Write the walking plan per frame (feet down, ZMP reference, planned ZMP and margin,
    /// centre of mass) as CSV; with --walk.
    #[arg(long)]
    pub(super) plan: Option<PathBuf>,
    /// Frame rate of the AMC file.
    #[arg(long, default_value_t = CMU_FRAME_RATE)]
    pub(super) fps: f64,
    /// Length unit of a BVH file.
    #[arg(long, value_enum, default_value_t = BvhUnit::Cm)]
    pub(super) bvh_unit: BvhUnit,
    /// Retarget capture dropouts (a bone or the root reading exactly zero between far-away
    /// frames) as recorded instead of filling them from their neighbours.
    #[arg(long)]
    pub(super) keep_dropouts: bool,
    /// Retarget a first frame that is a converter's calibration pose (the T-pose that CMU's BVH
    /// conversions write before the capture) instead of leaving it out.
    #[arg(long)]
    pub(super) keep_first_frame: bool,
    /// Retarget each frame on its own, as a live stream is (the arms' branches kept by
    /// hysteresis, joint speeds unlimited), instead of planning the branches over the clip
    /// and keeping every joint within its servo's speed and acceleration.
    #[arg(long)]
    pub(super) per_frame: bool,
}

impl RetargetCmd {
    /// Runs it.
    ///
    /// # Errors
    /// [`CliError`].
    pub(super) fn run(self) -> Result<(), CliError> {
        let RetargetCmd {
            profile,
            skeleton,
            amc,
            output,
            report,
            plot,
            upper_body,
            no_balance,
            walk,
            plan,
            fps,
            bvh_unit,
            keep_dropouts,
            keep_first_frame,
            per_frame,
        } = self;
        retarget_cmd(
            &RetargetArgs {
                profile: &profile,
                skeleton: &skeleton,
                amc: amc.as_deref(),
                output: &output,
                report,
                plot,
                upper_body,
                balance: !no_balance,
                walk,
                plan,
                fps,
                bvh_unit,
                keep_dropouts,
                keep_first_frame,
                per_frame,
            },
            &mut std::io::stdout().lock(),
        )
    }
}
