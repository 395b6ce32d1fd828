//! `marionette ik`: solve one pose for an effector target and print what was achieved.

use std::io::Write;
use std::path::Path;

use glam::{DMat3, DQuat, DVec3};

use super::error::CliError;
use crate::fk::{fk64, Pose64};
use crate::formats::{amc, asf};
use crate::ik::{Limb, Swivel};
use crate::ik_numeric::{chain_mask, Constraint, IkMethod, Method, Settings, Solver};
use crate::motion::{frame_to_radians, radians_to_frame, Motion, CMU_FRAME_RATE};
use clap::Args;
use std::path::PathBuf;

/// `--method NAME`: one of [`IkMethod::NAMES`] (listed in `--help`).
pub fn method_arg() -> impl clap::builder::TypedValueParser<Value = IkMethod> {
    use clap::builder::TypedValueParser;
    clap::builder::PossibleValuesParser::new(IkMethod::NAMES)
        .map(|name: String| IkMethod::parse(&name).unwrap_or(IkMethod::Dls))
}

/// Parses `X,Y,Z`.
pub fn parse_vec3(text: &str, what: &str) -> Result<DVec3, CliError> {
    let v: Vec<f64> = text
        .split(',')
        .map(|t| t.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|_| CliError::Usage(format!("{what} must be X,Y,Z (three numbers), got '{text}'")))?;
    if v.len() != 3 || v.iter().any(|x| !x.is_finite()) {
        return Err(CliError::Usage(format!(
            "{what} must be three finite numbers X,Y,Z, got '{text}'"
        )));
    }
    Ok(DVec3::new(v[0], v[1], v[2]))
}

/// Options of `marionette ik`.
#[derive(Debug)]
pub struct IkArgs<'a> {
    /// Skeleton.
    pub asf: &'a Path,
    /// Starting motion.
    pub amc: Option<&'a Path>,
    /// AMC frame number of the start.
    pub frame: Option<i64>,
    /// Effector bone (its tip reaches the target).
    pub effector: &'a str,
    /// Target `X,Y,Z`, file units.
    pub target: &'a str,
    /// Pointing direction `X,Y,Z` of the bone after the effector (the hand, the foot).
    pub point_dir: Option<&'a str>,
    /// Roll about the pointing direction, degrees.
    pub roll: Option<f64>,
    /// Method.
    pub method: Option<IkMethod>,
    /// Output pose.
    pub output: Option<&'a Path>,
}

/// Runs `marionette ik`.
pub fn ik_cmd(args: &IkArgs<'_>, out: &mut dyn Write) -> Result<(), CliError> {
    let target = parse_vec3(args.target, "--target")?;
    let point_dir = args.point_dir.map(|p| parse_vec3(p, "--point-dir")).transpose()?;
    if point_dir.is_some_and(|d| d.length() < 1e-12) {
        return Err(CliError::Usage("--point-dir must not be zero".into()));
    }
    if args.roll.is_some_and(|r| !r.is_finite()) {
        return Err(CliError::Usage(
            "--roll must be a finite number of degrees".into(),
        ));
    }
    let file = asf::load(args.asf)?;
    let skel = &file.skeleton;
    let mut channels = vec![0.0; skel.channel_count()];
    if let Some(amc_path) = args.amc {
        let motion = amc::load(skel, amc_path)?;
        let n = args.frame.unwrap_or(motion.first_frame);
        let last = motion.first_frame + motion.len() as i64 - 1;
        if n < motion.first_frame || n > last {
            return Err(CliError::Usage(format!(
                "--frame {n} is not in the clip's frames {}..{last}",
                motion.first_frame
            )));
        }
        channels = frame_to_radians(skel, motion.frame((n - motion.first_frame) as usize));
    } else if args.frame.is_some() {
        return Err(CliError::Usage("--frame needs --amc".into()));
    }
    let eff = skel.find(args.effector).ok_or_else(|| {
        CliError::Usage(format!(
            "unknown bone '{}'; the skeleton has: {}",
            args.effector,
            skel.bone_names()
        ))
    })?;
    let parent = skel.bones()[eff].parent();
    let limb = parent.and_then(|p| Limb::new(skel, p, eff, Some(&channels)).ok());
    let method = match (args.method, &limb) {
        (Some(IkMethod::Analytic), None) => {
            return Err(CliError::Usage(format!(
                "'{}' does not end a 2-bone limb (3-DOF parent, 1- or 3-DOF bone): pick a numerical --method",
                args.effector
            )));
        }
        (Some(m), _) => m,
        (None, Some(_)) => IkMethod::Analytic,
        (None, None) => IkMethod::Dls,
    };
    // The bone to point (hand, foot): down the first-child chain from the effector until the
    // bones passed have the DOFs a direction needs (2), or direction and roll (3).
    let need = if args.roll.is_some() { 3 } else { 2 };
    let mut hand = None;
    let mut dofs = 0;
    let mut at = skel.children(eff).next();
    while let Some(c) = at {
        dofs += skel.bones()[c].dofs().iter().filter(|d| d.is_rotation()).count();
        hand = Some(c);
        if dofs >= need {
            break;
        }
        at = skel.children(c).next();
    }
    let orient = match (point_dir, hand) {
        (Some(dir), Some(h)) => {
            let hand_bone = &skel.bones()[h];
            let rest = hand_bone.direction().as_dvec3().normalize();
            let dir = dir.normalize();
            let roll = args.roll.unwrap_or(0.0).to_radians();
            let w = DMat3::from_quat(DQuat::from_axis_angle(dir, roll) * DQuat::from_rotation_arc(rest, dir));
            let c = DMat3::from_quat(DQuat::from_mat3(&hand_bone.axis_rotation().as_dmat3()).normalize());
            let goal_frame = w * c;
            Some((h, dir, goal_frame, args.roll.is_some()))
        }
        (Some(_), None) => {
            return Err(CliError::Usage(format!(
                "'{}' has no child bone to point",
                args.effector
            )))
        }
        (None, _) => None,
    };
    let mut pose = Pose64::default();
    let mut report = String::new();
    let settings = |m: Method| Settings {
        method: m,
        max_iterations: 2000,
        damping: 0.1,
        ..Settings::default()
    };
    let mut limits_met;
    match method {
        IkMethod::Analytic => {
            let Some(limb) = &limb else {
                unreachable!("checked above")
            };
            let s = limb.solve(skel, &mut channels, target, Swivel::Auto { previous: None });
            report.push_str(&format!(
                "analytic limb {}→{}: swivel {:.2}°, {}\n",
                skel.bones()[limb.upper].name(),
                args.effector,
                s.swivel.to_degrees(),
                if s.reachable {
                    "target within reach"
                } else {
                    "target OUT OF REACH: limb stretched towards it"
                }
            ));
            limits_met = s.upper_within_limits && s.elbow_within_limits;
            if !s.upper_within_limits {
                report.push_str(&format!(
                    "  shoulder/hip outside its limits by {:.2}° in total\n",
                    s.violation.to_degrees()
                ));
            }
            if !s.elbow_within_limits {
                report.push_str("  elbow/knee needed an angle outside its limit (clamped)\n");
            }
        }
        m => {
            let method = m.numeric().unwrap_or(Method::DampedLeastSquares);
            let from = parent.unwrap_or(eff);
            let mask = chain_mask(skel, from, eff);
            let mut solver = Solver::new(skel, &mask, false);
            let o = solver.solve(
                skel,
                &[Constraint {
                    bone: eff,
                    position: target,
                    axes: None,
                }],
                &mut channels,
                &settings(method),
            );
            report.push_str(&format!(
                "{method:?}: {} iterations, {}\n",
                o.iterations,
                if o.converged { "converged" } else { "NOT converged" }
            ));
            limits_met = solver.within_limits(&channels);
        }
    }
    // Wrist/ankle: point the next bone. A 3-DOF bone in closed form (eq. 31–34), with the roll
    // measured from the rest direction's shortest turn onto `dir` (world) like the numerical
    // path; fewer DOFs numerically over the bones down to it.
    let three_dofs = |b: usize| skel.bones()[b].dofs().iter().filter(|d| d.is_rotation()).count() == 3;
    let closed = orient.filter(|o| three_dofs(o.0));
    if let Some((h, dir, goal_frame, with_roll)) = closed {
        let cannot_point = |source| CliError::Point {
            bone: skel.bones()[h].name().to_string(),
            source,
        };
        let mut p = crate::ik::point_bone(skel, &mut channels, h, dir, 0.0).map_err(cannot_point)?;
        if with_roll {
            fk64(skel, &channels, &mut pose);
            let (axis, angle) = DQuat::from_mat3(&(pose.frame[h].transpose() * goal_frame)).to_axis_angle();
            let local = skel.bones()[h].local_direction().as_dvec3();
            let roll = if axis.dot(local) < 0.0 { -angle } else { angle };
            p = crate::ik::point_bone(skel, &mut channels, h, dir, roll).map_err(cannot_point)?;
        }
        report.push_str(&format!(
            "  {} points {:.4}° off the asked direction (closed form, eq. 31–34){}\n",
            skel.bones()[h].name(),
            p.direction_error.to_degrees(),
            if p.violation > 0.0 {
                ", outside its limits"
            } else {
                ""
            }
        ));
        limits_met &= p.violation == 0.0;
    }
    if let Some((h, dir, goal_frame, with_roll)) = orient.filter(|o| !three_dofs(o.0)) {
        fk64(skel, &channels, &mut pose);
        let len = (pose.tip[h] - pose.start[h]).length();
        let axes = with_roll.then_some((goal_frame.x_axis, goal_frame.y_axis));
        let mut mask = [false; crate::skeleton::MAX_BONES];
        let mut b = Some(h);
        while let Some(i) = b {
            if i == eff {
                break;
            }
            mask[i] = true;
            b = skel.bones()[i].parent();
        }
        let mut solver = Solver::new(skel, &mask, false);
        let c = Constraint {
            bone: h,
            position: pose.start[h] + dir * len,
            axes,
        };
        let o = solver.solve(
            skel,
            &[c],
            &mut channels,
            &Settings {
                max_iterations: 500,
                damping: 0.05,
                // A direction to ≤ 0.01°: the tip within 1e-7 of a bone about a unit long.
                tolerance: 1e-7,
                ..Settings::default()
            },
        );
        fk64(skel, &channels, &mut pose);
        let got = (pose.tip[h] - pose.start[h]).normalize_or_zero();
        let off = got.cross(dir).length().atan2(got.dot(dir)).to_degrees();
        report.push_str(&format!(
            "  {} points {off:.4}° off the asked direction{}\n",
            skel.bones()[h].name(),
            if o.converged || (off <= 0.01 && !with_roll) {
                ""
            } else if with_roll {
                " (its DOFs cannot meet direction and roll together)"
            } else {
                " (its DOFs cannot do better)"
            }
        ));
        limits_met &= solver.within_limits(&channels);
    }
    fk64(skel, &channels, &mut pose);
    let err = (pose.tip[eff] - target).length();
    writeln!(
        out,
        "{report}residual {err:.6} units ({:.6} m); joint limits {}",
        err * f64::from(skel.units().meters_per_unit()),
        if limits_met { "met" } else { "NOT met" }
    )?;
    let t = pose.tip[eff];
    writeln!(out, "{} tip at {:.4},{:.4},{:.4}", args.effector, t.x, t.y, t.z)?;
    if let Some(path) = args.output {
        let mut m = Motion::new(skel.channel_count(), CMU_FRAME_RATE);
        m.push_frame(&radians_to_frame(skel, &channels));
        amc::save(skel, &m, path)?;
        writeln!(out, "pose written to {}", path.display())?;
    }
    Ok(())
}

/// Options of `marionette ik-edit`.
#[derive(Debug)]
pub struct IkEditArgs<'a> {
    /// Skeleton.
    pub asf: &'a Path,
    /// Motion to edit.
    pub amc: &'a Path,
    /// `BONE@FRAME` pins: the bone's tip stays where it was at that AMC frame.
    pub pins: &'a [String],
    /// `A..B`: the AMC frames (inclusive) over which the pins hold.
    pub frames: &'a str,
    /// Frames of ease-in before `A` and ease-out after `B` (eq. 13).
    pub blend: usize,
    /// Output motion.
    pub output: &'a Path,
}

/// How one pin is solved.
enum PinSolver {
    /// The bone ends a 2-bone limb: analytic, the capture's swivel kept where legal.
    Limb(Box<Limb>),
    /// Otherwise damped least squares over the bone and its two parents.
    Numeric(Box<Solver>),
}

/// One pin and what happened to it.
struct PinArg {
    bone: usize,
    frame: i64,
    position: DVec3,
    solver: PinSolver,
    /// Channels the pin may change.
    channels: Vec<usize>,
    drift_before: f64,
    drift_after: f64,
    missed: usize,
    outside_limits: usize,
    swivel_moved: usize,
}

fn parse_frame_range(text: &str) -> Result<(i64, i64), CliError> {
    let bad = || {
        CliError::Usage(format!(
            "--frames must be A..B (AMC frame numbers, A ≤ B), got '{text}'"
        ))
    };
    let (a, b) = text.split_once("..").ok_or_else(bad)?;
    let b = b.strip_prefix('=').unwrap_or(b);
    let (a, b): (i64, i64) = (
        a.trim().parse().map_err(|_| bad())?,
        b.trim().parse().map_err(|_| bad())?,
    );
    if a > b {
        return Err(bad());
    }
    Ok((a, b))
}

/// Runs `marionette ik-edit`: keeps each pinned bone's tip where it was at its frame over the
/// frame range, blended in and out with the ease weights of eq. (13); limbs are solved
/// analytically per frame with the capture's own swivel (so the knee keeps pointing where it
/// did), or the legal swivel nearest it where that would leave the limits.
pub fn ik_edit_cmd(args: &IkEditArgs<'_>, out: &mut dyn Write) -> Result<(), CliError> {
    let file = asf::load(args.asf)?;
    let skel = &file.skeleton;
    let mut motion = amc::load(skel, args.amc)?;
    let first = motion.first_frame;
    let last = first + motion.len() as i64 - 1;
    let (a, b) = parse_frame_range(args.frames)?;
    if a < first || b > last {
        return Err(CliError::Usage(format!(
            "--frames {a}..{b} is not inside the clip's frames {first}..{last}"
        )));
    }
    if args.pins.is_empty() {
        return Err(CliError::Usage("give at least one --pin BONE@FRAME".into()));
    }
    let original = motion.clone();
    let radians = |f: i64| frame_to_radians(skel, original.frame((f - first) as usize));
    let mut pins = Vec::new();
    let mut pose = Pose64::default();
    for text in args.pins {
        let (name, frame) = text
            .rsplit_once('@')
            .and_then(|(n, f)| f.trim().parse::<i64>().ok().map(|f| (n, f)))
            .ok_or_else(|| CliError::Usage(format!("--pin must be BONE@FRAME, got '{text}'")))?;
        let bone = skel.find(name).ok_or_else(|| {
            CliError::Usage(format!(
                "unknown bone '{name}' in --pin; the skeleton has: {}",
                skel.bone_names()
            ))
        })?;
        if frame < first || frame > last {
            return Err(CliError::Usage(format!(
                "--pin {text}: frame {frame} is not in the clip's frames {first}..{last}"
            )));
        }
        let parent = skel.bones()[bone]
            .parent()
            .filter(|&p| skel.bones()[p].parent().is_some());
        let Some(parent) = parent else {
            return Err(CliError::Usage(format!(
                "--pin {text}: the root and its direct children cannot be pinned"
            )));
        };
        let at = radians(frame);
        fk64(skel, &at, &mut pose);
        let (solver, moving) = match Limb::new(skel, parent, bone, Some(&at)) {
            Ok(limb) => (PinSolver::Limb(Box::new(limb)), vec![parent, bone]),
            Err(_) => {
                let mut mask = [false; crate::skeleton::MAX_BONES];
                let mut moving = Vec::new();
                let mut i = Some(bone);
                while let Some(k) = i.filter(|&k| skel.bones()[k].parent().is_some() && moving.len() < 3) {
                    mask[k] = true;
                    moving.push(k);
                    i = skel.bones()[k].parent();
                }
                (
                    PinSolver::Numeric(Box::new(Solver::new(skel, &mask, false))),
                    moving,
                )
            }
        };
        let channels = moving
            .iter()
            .flat_map(|&m| skel.bones()[m].channels())
            .filter(|&c| skel.channel_owner(c).is_some_and(|(_, d)| d.is_rotation()))
            .collect();
        pins.push(PinArg {
            bone,
            frame,
            position: pose.tip[bone],
            solver,
            channels,
            drift_before: 0.0,
            drift_after: 0.0,
            missed: 0,
            outside_limits: 0,
            swivel_moved: 0,
        });
    }
    // Weight of the pin at frame f: 1 inside A..B, eased over `blend` frames on either side.
    let n = args.blend as i64;
    let weight = |f: i64| -> f64 {
        if f >= a && f <= b {
            1.0
        } else if f < a && f >= a - n {
            crate::interp::ease_weight((f - (a - n)) as usize, args.blend + 1)
        } else if f > b && f <= b + n {
            crate::interp::ease_weight(((b + n) - f) as usize, args.blend + 1)
        } else {
            0.0
        }
    };
    let settings = Settings {
        max_iterations: 200,
        tolerance: 1e-5,
        restarts: 0,
        ..Settings::default()
    };
    let (from, to) = ((a - n).max(first), (b + n).min(last));
    let mut edited = 0;
    for f in from..=to {
        let w = weight(f);
        if w <= 0.0 {
            continue;
        }
        let mut ch = radians(f);
        for pin in &mut pins {
            fk64(skel, &ch, &mut pose);
            let tip = pose.tip[pin.bone];
            let target = tip.lerp(pin.position, w);
            if (a..=b).contains(&f) {
                pin.drift_before = pin.drift_before.max((tip - pin.position).length());
            }
            let within = match &mut pin.solver {
                PinSolver::Limb(limb) => {
                    let captured = limb.swivel_of(skel, &ch);
                    let s = limb.solve(skel, &mut ch, target, Swivel::Nearest(captured));
                    if (crate::math::wrap_near(s.swivel, captured) - captured).abs() > 1e-9 {
                        pin.swivel_moved += 1;
                    }
                    s.upper_within_limits && s.elbow_within_limits
                }
                PinSolver::Numeric(solver) => {
                    let c = Constraint {
                        bone: pin.bone,
                        position: target,
                        axes: None,
                    };
                    solver.solve(skel, &[c], &mut ch, &settings);
                    solver.within_limits(&ch)
                }
            };
            if !within {
                // Written out legal: each moved angle clamped into its ASF limits.
                for &c in &pin.channels {
                    if let Some((b, _)) = skel.channel_owner(c) {
                        let bone = &skel.bones()[b];
                        let l = bone.limits()[c - bone.first_channel()];
                        ch[c] = ch[c].clamp(f64::from(l.min), f64::from(l.max));
                    }
                }
            }
            fk64(skel, &ch, &mut pose);
            let miss = (pose.tip[pin.bone] - target).length();
            pin.missed += usize::from(miss > 1e-4);
            pin.outside_limits += usize::from(!within);
            if (a..=b).contains(&f) {
                pin.drift_after = pin.drift_after.max((pose.tip[pin.bone] - pin.position).length());
            }
        }
        // Write back only the channels the pins may move; the rest stay bit for bit.
        let values = radians_to_frame(skel, &ch);
        let row = motion.frame_mut((f - first) as usize);
        for pin in &pins {
            for &c in &pin.channels {
                row[c] = values[c];
            }
        }
        edited += 1;
    }
    // Largest frame-to-frame change of the edited channels, before and after.
    let step = |m: &Motion, pin: &PinArg| -> f64 {
        let lo = (from - first).max(1) as usize;
        let hi = ((to - first) as usize + 1).min(m.len() - 1);
        (lo..=hi)
            .flat_map(|i| pin.channels.iter().map(move |&c| (i, c)))
            .map(|(i, c)| (m.frame(i)[c] - m.frame(i - 1)[c]).abs())
            .fold(0.0, f64::max)
    };
    writeln!(
        out,
        "edited frames {from}..{to} of {first}..{last} ({edited} frames; pins hold over {a}..{b}, {} blend frames each side)",
        args.blend
    )?;
    let mpu = f64::from(skel.units().meters_per_unit());
    for pin in &pins {
        let p = pin.position;
        writeln!(
            out,
            "pin {}@{} at {:.4},{:.4},{:.4} ({}): drift over {a}..{b} {:.4} → {:.2e} units ({:.1} mm → {:.4} mm)",
            skel.bones()[pin.bone].name(),
            pin.frame,
            p.x,
            p.y,
            p.z,
            match pin.solver {
                PinSolver::Limb(_) => "analytic limb",
                PinSolver::Numeric(_) => "damped least squares",
            },
            pin.drift_before,
            pin.drift_after,
            pin.drift_before * mpu * 1e3,
            pin.drift_after * mpu * 1e3,
        )?;
        writeln!(
            out,
            "  largest frame-to-frame change of its joints {:.2}° (capture {:.2}°); target missed on {} frames, limits reached (angles clamped) on {}, swivel moved off the capture's to stay legal on {}",
            step(&motion, pin),
            step(&original, pin),
            pin.missed,
            pin.outside_limits,
            pin.swivel_moved
        )?;
    }
    amc::save(skel, &motion, args.output)?;
    writeln!(out, "written to {}", args.output.display())?;
    Ok(())
}

/// The arguments of `marionette ik`.
#[derive(Debug, Args)]
pub(super) struct IkCmd {
    /// Skeleton (.asf).
    pub(super) asf: PathBuf,
    /// Starting motion (.amc); the start is its frame --frame (default: the rest pose).
    #[arg(long)]
    pub(super) amc: Option<PathBuf>,
    /// AMC frame number to start from.
    #[arg(long)]
    pub(super) frame: Option<i64>,
    /// The bone whose tip must reach the target (lradius: wrist, ltibia: ankle).
    #[arg(long)]
    pub(super) effector: String,
    /// Target position X,Y,Z in ASF file units (global).
    #[arg(long, allow_hyphen_values = true)]
    pub(super) target: String,
    /// Pointing direction X,Y,Z of the next bone (hand, foot).
    #[arg(long, allow_hyphen_values = true)]
    pub(super) point_dir: Option<String>,
    /// Roll about the pointing direction, degrees.
    #[arg(long, allow_hyphen_values = true)]
    pub(super) roll: Option<f64>,
    /// Solver (default: analytic where the effector ends a 2-bone limb, else dls).
    #[arg(long, value_parser = method_arg())]
    pub(super) method: Option<crate::ik_numeric::IkMethod>,
    /// Write the solved pose as a one-frame AMC.
    #[arg(short = 'o', long)]
    pub(super) output: Option<PathBuf>,
}

impl IkCmd {
    /// Runs it.
    ///
    /// # Errors
    /// [`CliError`].
    pub(super) fn run(self) -> Result<(), CliError> {
        let IkCmd {
            asf,
            amc,
            frame,
            effector,
            target,
            point_dir,
            roll,
            method,
            output,
        } = self;
        ik_cmd(
            &IkArgs {
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
            &mut std::io::stdout().lock(),
        )
    }
}

/// The arguments of `marionette ik-edit`.
#[derive(Debug, Args)]
pub(super) struct IkEditCmd {
    /// Skeleton (.asf).
    pub(super) asf: PathBuf,
    /// Motion to edit (.amc).
    pub(super) amc: PathBuf,
    /// BONE@FRAME: the bone's tip stays where it was at that frame (repeatable; e.g.
    /// ltibia@120 for the left ankle).
    #[arg(long, required = true)]
    pub(super) pin: Vec<String>,
    /// A..B: AMC frame numbers (inclusive) over which the pins hold.
    #[arg(long)]
    pub(super) frames: String,
    /// Frames of ease-in before A and ease-out after B.
    #[arg(long, default_value_t = 12)]
    pub(super) blend: usize,
    /// Output motion (.amc).
    #[arg(short = 'o', long)]
    pub(super) output: PathBuf,
}

impl IkEditCmd {
    /// Runs it.
    ///
    /// # Errors
    /// [`CliError`].
    pub(super) fn run(self) -> Result<(), CliError> {
        let IkEditCmd {
            asf,
            amc,
            pin,
            frames,
            blend,
            output,
        } = self;
        ik_edit_cmd(
            &IkEditArgs {
                asf: &asf,
                amc: &amc,
                pins: &pin,
                frames: &frames,
                blend,
                output: &output,
            },
            &mut std::io::stdout().lock(),
        )
    }
}
