//! `marionette ik`: solve one pose for an effector target and print what was achieved.

use std::io::Write;
use std::path::Path;

use glam::{DMat3, DQuat, DVec3};

use crate::cli::CliError;
use crate::formats::{amc, asf};
use crate::ik::{fk64, Limb, Pose64, Swivel};
use crate::ik_numeric::{chain_mask, Constraint, Method, Settings, Solver};
use crate::motion::{frame_to_radians, radians_to_frame, Motion, CMU_FRAME_RATE};

/// The solver asked for on the command line.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum IkMethod {
    /// Analytic 2-bone limb with swivel search (default where the effector ends a limb).
    Analytic,
    /// Cyclic coordinate descent.
    Ccd,
    /// Jacobian transpose.
    Jt,
    /// Pseudoinverse.
    Pinv,
    /// Damped least squares.
    Dls,
    /// Conjugate gradient on eq. (35).
    Cg,
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
    /// Target, file units.
    pub target: DVec3,
    /// Pointing direction of the bone after the effector (the hand, the foot).
    pub point_dir: Option<DVec3>,
    /// Roll about the pointing direction, degrees.
    pub roll: Option<f64>,
    /// Method.
    pub method: Option<IkMethod>,
    /// Output pose.
    pub output: Option<&'a Path>,
}

/// Runs `marionette ik`.
pub fn ik_cmd(args: &IkArgs<'_>, out: &mut dyn Write) -> Result<(), CliError> {
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
        let names: Vec<&str> = skel.bones().iter().map(|b| b.name()).collect();
        CliError::Usage(format!(
            "unknown bone '{}'; the skeleton has: {}",
            args.effector,
            names.join(" ")
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
    let orient = match (args.point_dir, hand) {
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
            let s = limb.solve(skel, &mut channels, args.target, Swivel::Auto { previous: None });
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
            let method = match m {
                IkMethod::Ccd => Method::Ccd,
                IkMethod::Jt => Method::Transpose,
                IkMethod::Pinv => Method::Pseudoinverse,
                IkMethod::Cg => Method::ConjugateGradient,
                _ => Method::DampedLeastSquares,
            };
            let from = parent.unwrap_or(eff);
            let mask = chain_mask(skel, from, eff);
            let mut solver = Solver::new(skel, &mask, false);
            let o = solver.solve(
                skel,
                &[Constraint {
                    bone: eff,
                    position: args.target,
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
    // Wrist/ankle: point the next bone (eq. 31–34), numerically over its own DOFs.
    if let Some((h, dir, goal_frame, with_roll)) = orient {
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
                ..Settings::default()
            },
        );
        fk64(skel, &channels, &mut pose);
        let got = (pose.tip[h] - pose.start[h]).normalize_or_zero();
        report.push_str(&format!(
            "  {} points {:.2}° off the asked direction{}\n",
            skel.bones()[h].name(),
            got.dot(dir).clamp(-1.0, 1.0).acos().to_degrees(),
            if o.converged {
                ""
            } else {
                " (its DOFs cannot do better)"
            }
        ));
        limits_met &= solver.within_limits(&channels);
    }
    fk64(skel, &channels, &mut pose);
    let err = (pose.tip[eff] - args.target).length();
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
