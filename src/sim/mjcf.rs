//! A MuJoCo model (MJCF) of a servo puppet, generated from an ASF skeleton and a rig profile.
//!
//! One body per bone, its frame the bone's rest frame `C` (help note eq. 3) placed at the
//! parent's tip, so that a body's world orientation is `F_parent · (C_parentᵀ C) · M` — the
//! skeleton's `G = G_parent · C · M · Cᵀ` written in body frames (eq. 6). Each servo is one
//! hinge about its DOF's local axis; the hinges of a bone are listed last-applied first, so
//! MuJoCo's product of joint rotations is the bone's `M = R(last)·…·R(first)`. DOFs without a
//! servo are rigid at 0. Capsules for bones, each servo's mass at its joint, position actuators
//! with the servo model's gains, joint ranges and actuator ranges from the servo limits, the
//! root fixed on a stand above a floor, and a site at the tip of every leaf bone (the end
//! effectors). Generating needs no MuJoCo.

use std::fmt::Write as _;

use glam::{DMat3, DQuat, DVec3};

use crate::profile::Profile;
use crate::rig::{JointSource, Rig};
use crate::skeleton::Skeleton;

pub use crate::servo_dynamics::{dynamics, dynamics_at, ServoDynamics, XM430_W350};

/// Choices of the generated model.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PuppetOptions {
    /// Model metres per subject metre (0.3: a 1.7 m subject becomes a 0.5 m puppet, the size
    /// of a ROBOTIS OP3).
    pub scale: f64,
    /// Physics time step, seconds.
    pub timestep: f64,
    /// Mass of the structure per metre of bone, kg/m (printed or aluminium links).
    pub link_density: f64,
}

impl Default for PuppetOptions {
    fn default() -> Self {
        PuppetOptions {
            scale: 0.3,
            timestep: 0.001,
            link_density: 0.25,
        }
    }
}

/// Why no model could be generated.
#[derive(Debug, thiserror::Error)]
pub enum MjcfError {
    /// A servo follows a robot joint: such rigs come with their own model.
    #[error("servo {id} (`{name}`) is driven by the robot joint `{joint}`, not a bone: give that robot's MJCF model instead of generating one")]
    JointDrive {
        /// Id.
        id: u8,
        /// Servo name.
        name: String,
        /// Joint name.
        joint: String,
    },
    /// Bad options.
    #[error("{0}")]
    Options(String),
}

fn v3(v: DVec3) -> String {
    format!("{} {} {}", f(v.x), f(v.y), f(v.z))
}

fn f(x: f64) -> String {
    let s = format!("{x:.6}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s == "-0" || s.is_empty() {
        "0".into()
    } else {
        s.to_string()
    }
}

fn quat(q: DQuat) -> String {
    // MJCF writes w x y z.
    format!("{} {} {} {}", f(q.w), f(q.x), f(q.y), f(q.z))
}

/// The hinge axis (a unit local axis) of a servo source, and the bone it turns.
fn hinge(skeleton: &Skeleton, source: JointSource) -> Option<(usize, DVec3, usize)> {
    let axis = |a: crate::math::Axis| match a {
        crate::math::Axis::X => DVec3::X,
        crate::math::Axis::Y => DVec3::Y,
        crate::math::Axis::Z => DVec3::Z,
    };
    match source {
        JointSource::Channel(c) => {
            let (bone, dof) = skeleton.channel_owner(c)?;
            let k = skeleton.bones()[bone].dofs().iter().position(|d| *d == dof)?;
            Some((bone, axis(dof.axis()?), k))
        }
        JointSource::Redecomposed { bone, order, slot } => Some((bone, axis(order.axes()[slot]), slot)),
        JointSource::Joint(_) => None,
    }
}

/// The MJCF text of a puppet: the skeleton's bones, the profile's servos as hinges and
/// position actuators (named after the servos), on a stand.
///
/// # Errors
/// [`MjcfError`] for a servo driven by a robot joint or bad options.
pub fn puppet(
    skeleton: &Skeleton,
    profile: &Profile,
    rig: &Rig,
    options: &PuppetOptions,
) -> Result<String, MjcfError> {
    if !(options.scale.is_finite() && options.scale > 0.0) {
        return Err(MjcfError::Options(format!(
            "scale must be positive, got {}",
            options.scale
        )));
    }
    if !(options.timestep.is_finite() && options.timestep > 0.0 && options.timestep <= 0.01) {
        return Err(MjcfError::Options(format!(
            "the time step must be in (0, 0.01] s, got {}",
            options.timestep
        )));
    }
    // Hinges per bone: (servo index, axis, slot), listed last-applied first.
    let bones = skeleton.bones();
    let mut hinges: Vec<Vec<(usize, DVec3, usize)>> = vec![Vec::new(); bones.len()];
    for (k, (spec, map)) in profile.servos.iter().zip(&rig.servos).enumerate() {
        let Some((bone, axis, slot)) = hinge(skeleton, map.source) else {
            let joint = match &spec.drive {
                crate::profile::Drive::Joint(j) => j.clone(),
                crate::profile::Drive::Bone { bone, .. } => bone.clone(),
            };
            return Err(MjcfError::JointDrive {
                id: spec.id,
                name: spec.name.clone(),
                joint,
            });
        };
        hinges[bone].push((k, axis, slot));
    }
    for h in &mut hinges {
        h.sort_by_key(|x| core::cmp::Reverse(x.2));
    }
    let unit = f64::from(skeleton.units().meters_per_unit()) * options.scale;
    let tip = |b: usize| bones[b].direction().as_dvec3() * f64::from(bones[b].length()) * unit;
    // Rest positions of bone tips (subject's global frame), to hang the puppet above the floor.
    let mut start = vec![DVec3::ZERO; bones.len()];
    let mut lowest = 0.0f64;
    for b in 1..bones.len() {
        let p = bones[b].parent().map_or(DVec3::ZERO, |p| start[p] + tip(p));
        start[b] = p;
        lowest = lowest.min((p + tip(b)).y);
    }
    let height = -lowest + 0.05 * options.scale / 0.3;
    let radius = |len: f64| (0.12 * len).clamp(0.006, 0.02);

    let mut x = String::new();
    let _ = writeln!(
        x,
        "<!-- {}: generated by marionette from {} and its ASF skeleton (scale {}). -->",
        profile.name,
        profile.path.display(),
        f(options.scale)
    );
    let _ = writeln!(x, "<mujoco model=\"{}\">", xml_escape(&profile.name));
    let _ = writeln!(x, "  <compiler angle=\"radian\" autolimits=\"true\"/>");
    let _ = writeln!(
        x,
        "  <option timestep=\"{}\" integrator=\"implicitfast\"/>",
        f(options.timestep)
    );
    let _ = writeln!(x, "  <default>");
    let _ = writeln!(
        x,
        "    <geom contype=\"0\" conaffinity=\"0\" rgba=\"0.75 0.6 0.4 1\"/>"
    );
    let _ = writeln!(x, "    <site size=\"0.005\" rgba=\"1 0.2 0.2 1\"/>");
    let _ = writeln!(x, "  </default>");
    let _ = writeln!(x, "  <worldbody>");
    let _ = writeln!(x, "    <light pos=\"0 -1 2\" dir=\"0 0.5 -1\"/>");
    let _ = writeln!(
        x,
        "    <geom name=\"floor\" type=\"plane\" size=\"2 2 0.05\" rgba=\"0.3 0.35 0.4 1\" contype=\"1\" conaffinity=\"1\"/>"
    );
    let _ = writeln!(
        x,
        "    <geom name=\"stand\" type=\"cylinder\" fromto=\"0 0.08 0 0 0.08 {}\" size=\"0.01\" rgba=\"0.4 0.4 0.4 1\"/>",
        f(height)
    );
    // The subject's y is up: turn it to MuJoCo's z (a quarter turn about x).
    let up = DQuat::from_rotation_x(core::f64::consts::FRAC_PI_2);
    let _ = writeln!(
        x,
        "    <body name=\"{}\" pos=\"0 0 {}\" quat=\"{}\">",
        xml_escape(bones[0].name()),
        f(height),
        quat(up)
    );
    let _ = writeln!(
        x,
        "      <geom type=\"sphere\" size=\"0.02\" mass=\"0.2\" rgba=\"0.4 0.4 0.4 1\"/>"
    );
    let mut text = x;
    write_children(
        &mut text, skeleton, 0, 3, &hinges, profile, rig, &tip, &radius, options,
    );
    let _ = writeln!(text, "    </body>");
    let _ = writeln!(text, "  </worldbody>");
    let _ = writeln!(text, "  <actuator>");
    for (spec, map) in profile.servos.iter().zip(&rig.servos) {
        let d = dynamics_at(spec.model, spec.supply_v);
        let (lo, hi) = angle_range(map);
        let _ = writeln!(
            text,
            "    <position name=\"{n}\" joint=\"{n}\" kp=\"{}\" forcerange=\"{} {}\" ctrlrange=\"{} {}\"/>",
            f(d.kp),
            f(-d.force),
            f(d.force),
            f(lo),
            f(hi),
            n = xml_escape(&spec.name)
        );
    }
    let _ = writeln!(text, "  </actuator>");
    let _ = writeln!(text, "</mujoco>");
    Ok(text)
}

/// The joint-angle range of a servo's tick limits, radians.
#[must_use]
pub fn angle_range(map: &crate::rig::ServoMap) -> (f64, f64) {
    let a = map.ticks_to_angle(f64::from(map.min_tick));
    let b = map.ticks_to_angle(f64::from(map.max_tick));
    (a.min(b), a.max(b))
}

#[allow(clippy::too_many_arguments)]
fn write_children(
    x: &mut String,
    skeleton: &Skeleton,
    parent: usize,
    depth: usize,
    hinges: &[Vec<(usize, DVec3, usize)>],
    profile: &Profile,
    rig: &Rig,
    tip: &dyn Fn(usize) -> DVec3,
    radius: &dyn Fn(f64) -> f64,
    options: &PuppetOptions,
) {
    let bones = skeleton.bones();
    let pad = "  ".repeat(depth);
    let c_parent = if parent == 0 {
        DMat3::IDENTITY
    } else {
        bones[parent].axis_rotation_f64()
    };
    for b in skeleton.children(parent) {
        let c = bones[b].axis_rotation_f64();
        let pos = c_parent.transpose() * tip(parent);
        let rel = DQuat::from_mat3(&(c_parent.transpose() * c)).normalize();
        let _ = writeln!(
            x,
            "{pad}<body name=\"{}\" pos=\"{}\" quat=\"{}\">",
            xml_escape(bones[b].name()),
            v3(pos),
            quat(rel)
        );
        for &(k, axis, _) in &hinges[b] {
            let spec = &profile.servos[k];
            let d = dynamics(spec.model);
            let (lo, hi) = angle_range(&rig.servos[k]);
            let _ = writeln!(
                x,
                "{pad}  <joint name=\"{}\" axis=\"{}\" range=\"{} {}\" damping=\"{}\" armature=\"{}\" frictionloss=\"{}\"/>",
                xml_escape(&spec.name),
                v3(axis),
                f(lo),
                f(hi),
                f(d.damping),
                f(d.armature),
                f(d.frictionloss)
            );
        }
        // The servos of this bone's joints sit at its start.
        let servo_mass: f64 = hinges[b]
            .iter()
            .map(|(k, _, _)| dynamics(profile.servos[*k].model).mass)
            .sum();
        if servo_mass > 0.0 {
            let _ = writeln!(
                x,
                "{pad}  <geom type=\"box\" size=\"0.012 0.012 0.012\" mass=\"{}\" rgba=\"0.15 0.15 0.15 1\"/>",
                f(servo_mass)
            );
        }
        let local_tip = c.transpose() * tip(b);
        let len = local_tip.length();
        if len > 1e-6 {
            let _ = writeln!(
                x,
                "{pad}  <geom type=\"capsule\" fromto=\"0 0 0 {}\" size=\"{}\" mass=\"{}\"/>",
                v3(local_tip),
                f(radius(len)),
                f((options.link_density * len).max(0.001))
            );
        }
        if skeleton.children(b).next().is_none() {
            let _ = writeln!(
                x,
                "{pad}  <site name=\"{}\" pos=\"{}\"/>",
                xml_escape(bones[b].name()),
                v3(local_tip)
            );
        }
        write_children(
            x,
            skeleton,
            b,
            depth + 1,
            hinges,
            profile,
            rig,
            tip,
            radius,
            options,
        );
        let _ = writeln!(x, "{pad}</body>");
    }
}

fn xml_escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}
