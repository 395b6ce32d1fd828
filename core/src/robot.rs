//! A robot's own kinematic tree, as its model (MJCF) describes it: bodies at fixed offsets from
//! their parents, hinge joints turning them, and each body's mass at its centre of mass.
//! Forward kinematics and the centre of mass of the whole robot, in fixed capacity.
//!
//! The conventions are MuJoCo's: a body's frame is its parent's frame moved by `pos` and turned
//! by `quat`; a hinge at `anchor` (body frame) about `axis` then turns the body by the joint
//! angle about that line, so the anchor stays where it was: with `R` and `p` the body's
//! orientation and position before the hinge, `R' = R·rot(axis, q)` and
//! `p' = p + R·anchor − R'·anchor`.

use crate::math::{Real, RealQuat, RealVec3};

/// Most bodies in a robot (the world not counted).
pub const MAX_ROBOT_BODIES: usize = 64;

/// Most hinge joints in a robot.
pub const MAX_ROBOT_JOINTS: usize = 64;

/// Longest body or joint name kept.
pub const MAX_NAME: usize = 32;

/// A name of fixed capacity.
pub type Name = heapless::String<MAX_NAME>;

/// One body.
#[derive(Clone, Debug, PartialEq)]
pub struct RobotBody {
    /// Its name.
    pub name: Name,
    /// Its parent body (`None`: attached to the base frame).
    pub parent: Option<usize>,
    /// Offset of its frame in its parent's frame, metres.
    pub pos: RealVec3,
    /// Orientation of its frame in its parent's frame.
    pub quat: RealQuat,
    /// Mass, kg.
    pub mass: Real,
    /// Centre of mass in its own frame, metres.
    pub com: RealVec3,
}

/// One hinge joint.
#[derive(Clone, Debug, PartialEq)]
pub struct RobotJoint {
    /// Its name.
    pub name: Name,
    /// The body it turns.
    pub body: usize,
    /// Unit axis in the body's frame.
    pub axis: RealVec3,
    /// A point on the axis in the body's frame, metres.
    pub anchor: RealVec3,
    /// Limits, radians (`None`: unlimited).
    pub range: Option<(Real, Real)>,
}

/// A named point fixed in a body (an MJCF site): a hand, a sole.
#[derive(Clone, Debug, PartialEq)]
pub struct RobotSite {
    /// Its name.
    pub name: Name,
    /// The body it is fixed in.
    pub body: usize,
    /// Its position in that body's frame, metres.
    pub pos: RealVec3,
}

/// Most sites in a robot.
pub const MAX_ROBOT_SITES: usize = 32;

/// Why a body or joint cannot be added.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RobotError {
    /// More than [`MAX_ROBOT_BODIES`] bodies or [`MAX_ROBOT_JOINTS`] joints.
    Full,
    /// A name longer than [`MAX_NAME`] bytes.
    NameTooLong,
    /// A parent that is not an earlier body.
    BadParent,
    /// A second hinge on one body (one per body is supported).
    SecondJoint,
    /// A zero-length joint axis.
    ZeroAxis,
}

impl core::fmt::Display for RobotError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            RobotError::Full => "too many bodies or joints",
            RobotError::NameTooLong => "a name longer than 32 bytes",
            RobotError::BadParent => "a parent that is not an earlier body",
            RobotError::SecondJoint => "a second joint on one body",
            RobotError::ZeroAxis => "a joint axis of zero length",
        })
    }
}

impl core::error::Error for RobotError {}

/// A robot: bodies listed parents first, hinge joints (at most one per body).
#[derive(Clone, Debug, Default)]
pub struct Robot {
    bodies: heapless::Vec<RobotBody, MAX_ROBOT_BODIES>,
    joints: heapless::Vec<RobotJoint, MAX_ROBOT_JOINTS>,
    joint_of_body: heapless::Vec<Option<usize>, MAX_ROBOT_BODIES>,
    sites: heapless::Vec<RobotSite, MAX_ROBOT_SITES>,
}

/// Where every body of a robot is, in the base's frame.
#[derive(Clone, Debug)]
pub struct RobotPose {
    /// Body frame positions, metres.
    pub pos: [RealVec3; MAX_ROBOT_BODIES],
    /// Body frame orientations.
    pub rot: [RealQuat; MAX_ROBOT_BODIES],
}

impl Default for RobotPose {
    fn default() -> Self {
        RobotPose {
            pos: [RealVec3::ZERO; MAX_ROBOT_BODIES],
            rot: [RealQuat::IDENTITY; MAX_ROBOT_BODIES],
        }
    }
}

fn name(text: &str) -> Result<Name, RobotError> {
    Name::try_from(text).map_err(|_| RobotError::NameTooLong)
}

impl Robot {
    /// An empty robot.
    #[must_use]
    pub fn new() -> Robot {
        Robot::default()
    }

    /// Adds a body after its parent; returns its index.
    ///
    /// # Errors
    /// [`RobotError`].
    pub fn add_body(
        &mut self,
        body_name: &str,
        parent: Option<usize>,
        pos: RealVec3,
        quat: RealQuat,
        mass: Real,
        com: RealVec3,
    ) -> Result<usize, RobotError> {
        if parent.is_some_and(|p| p >= self.bodies.len()) {
            return Err(RobotError::BadParent);
        }
        let body = RobotBody {
            name: name(body_name)?,
            parent,
            pos,
            quat: quat.normalize(),
            mass,
            com,
        };
        self.bodies.push(body).map_err(|_| RobotError::Full)?;
        self.joint_of_body.push(None).map_err(|_| RobotError::Full)?;
        Ok(self.bodies.len() - 1)
    }

    /// Adds a hinge turning `body`; returns its index (its place in a joint-angle vector).
    ///
    /// # Errors
    /// [`RobotError`].
    pub fn add_hinge(
        &mut self,
        joint_name: &str,
        body: usize,
        axis: RealVec3,
        anchor: RealVec3,
        range: Option<(Real, Real)>,
    ) -> Result<usize, RobotError> {
        let slot = self.joint_of_body.get_mut(body).ok_or(RobotError::BadParent)?;
        if slot.is_some() {
            return Err(RobotError::SecondJoint);
        }
        let axis = axis.try_normalize().ok_or(RobotError::ZeroAxis)?;
        let joint = RobotJoint {
            name: name(joint_name)?,
            body,
            axis,
            anchor,
            range,
        };
        self.joints.push(joint).map_err(|_| RobotError::Full)?;
        *slot = Some(self.joints.len() - 1);
        Ok(self.joints.len() - 1)
    }

    /// The bodies, parents first.
    #[must_use]
    pub fn bodies(&self) -> &[RobotBody] {
        &self.bodies
    }

    /// The hinge joints, in the order they were added.
    #[must_use]
    pub fn joints(&self) -> &[RobotJoint] {
        &self.joints
    }

    /// The body with this name.
    #[must_use]
    pub fn body(&self, body_name: &str) -> Option<usize> {
        self.bodies.iter().position(|b| b.name == body_name)
    }

    /// The joint with this name.
    #[must_use]
    pub fn joint(&self, joint_name: &str) -> Option<usize> {
        self.joints.iter().position(|j| j.name == joint_name)
    }

    /// Adds a named point fixed in `body`; returns its index.
    ///
    /// # Errors
    /// [`RobotError`]: a body that does not exist, a long name, too many sites.
    pub fn add_site(&mut self, site_name: &str, body: usize, pos: RealVec3) -> Result<usize, RobotError> {
        if body >= self.bodies.len() {
            return Err(RobotError::BadParent);
        }
        let site = RobotSite {
            name: name(site_name)?,
            body,
            pos,
        };
        self.sites.push(site).map_err(|_| RobotError::Full)?;
        Ok(self.sites.len() - 1)
    }

    /// The sites.
    #[must_use]
    pub fn sites(&self) -> &[RobotSite] {
        &self.sites
    }

    /// The site with this name.
    #[must_use]
    pub fn site(&self, site_name: &str) -> Option<usize> {
        self.sites.iter().position(|s| s.name == site_name)
    }

    /// Where a site is in `pose` (NaN for a site that does not exist).
    #[must_use]
    pub fn site_position(&self, pose: &RobotPose, site: usize) -> RealVec3 {
        self.sites
            .get(site)
            .map_or(RealVec3::NAN, |s| pose.pos[s.body] + pose.rot[s.body] * s.pos)
    }

    /// Sets a joint's limits (radians; `None`: unlimited). Out-of-range indices are ignored.
    pub fn set_range(&mut self, joint: usize, range: Option<(Real, Real)>) {
        if let Some(j) = self.joints.get_mut(joint) {
            j.range = range;
        }
    }

    /// Total mass, kg.
    #[must_use]
    pub fn mass(&self) -> Real {
        self.bodies.iter().map(|b| b.mass).sum()
    }

    /// Forward kinematics: every body's frame for joint angles `q` (radians, in joint order;
    /// missing angles count as 0), the base at `base_pos` turned by `base_rot`.
    pub fn forward(&self, base_pos: RealVec3, base_rot: RealQuat, q: &[Real], pose: &mut RobotPose) {
        for (i, b) in self.bodies.iter().enumerate() {
            let (pp, pr) = match b.parent {
                Some(p) => (pose.pos[p], pose.rot[p]),
                None => (base_pos, base_rot),
            };
            let mut rot = pr * b.quat;
            let mut pos = pp + pr * b.pos;
            if let Some(j) = self.joint_of_body[i] {
                let joint = &self.joints[j];
                let angle = q.get(j).copied().unwrap_or(0.0);
                let anchor = pos + rot * joint.anchor;
                rot *= crate::math::quat_from_axis_angle(joint.axis, angle);
                pos = anchor - rot * joint.anchor;
            }
            pose.pos[i] = pos;
            pose.rot[i] = rot;
        }
    }

    /// The centre of mass of the whole robot in `pose` (the base frame's origin when it has no
    /// mass).
    #[must_use]
    pub fn centre_of_mass(&self, pose: &RobotPose) -> RealVec3 {
        let mut sum = RealVec3::ZERO;
        let mut mass = 0.0;
        for (i, b) in self.bodies.iter().enumerate() {
            sum += b.mass * (pose.pos[i] + pose.rot[i] * b.com);
            mass += b.mass;
        }
        if mass > 0.0 {
            sum / mass
        } else {
            RealVec3::ZERO
        }
    }

    /// The torque about each joint's axis (N·m, in joint order, into `torque`) that gravity
    /// (`g` m/s² along −z) and the external `forces` (each: the body it acts on, the point, the
    /// force, world frame) exert on the bodies the joint turns, in `pose`. A servo holds the
    /// pose still by exerting the opposite: τⱼ = aⱼ · Σ_{b turned by j} (pᵢ − oⱼ) × fᵢ over the
    /// bodies' weights and the forces on them, oⱼ and aⱼ the joint's anchor and axis.
    pub fn static_torques(
        &self,
        pose: &RobotPose,
        g: Real,
        forces: &[(usize, RealVec3, RealVec3)],
        torque: &mut [Real],
    ) {
        let n = self.bodies.len();
        // Per body, the sum over its subtree: force and moment about the world's origin.
        let mut force = [RealVec3::ZERO; MAX_ROBOT_BODIES];
        let mut moment = [RealVec3::ZERO; MAX_ROBOT_BODIES];
        for (i, b) in self.bodies.iter().enumerate() {
            let weight = RealVec3::new(0.0, 0.0, -g * b.mass);
            force[i] = weight;
            moment[i] = (pose.pos[i] + pose.rot[i] * b.com).cross(weight);
        }
        for &(body, point, f) in forces {
            if body < n {
                force[body] += f;
                moment[body] += point.cross(f);
            }
        }
        for i in (0..n).rev() {
            if let Some(p) = self.bodies[i].parent {
                let (f, m) = (force[i], moment[i]);
                force[p] += f;
                moment[p] += m;
            }
        }
        for t in torque.iter_mut() {
            *t = 0.0;
        }
        for (j, joint) in self.joints.iter().enumerate() {
            let Some(t) = torque.get_mut(j) else { break };
            let b = joint.body;
            let anchor = pose.pos[b] + pose.rot[b] * joint.anchor;
            let axis = pose.rot[b] * joint.axis;
            *t = axis.dot(moment[b] - anchor.cross(force[b]));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two 1 m links along x, 1 kg and 2 kg at their middles, hinged about `axis` at the origin
    /// and at the first link's end; the robot and the second link's body.
    fn two_link_arm(axis: RealVec3) -> (Robot, usize) {
        let mut r = Robot::new();
        let half = RealVec3::new(0.5, 0.0, 0.0);
        let a = r
            .add_body("upper", None, RealVec3::ZERO, RealQuat::IDENTITY, 1.0, half)
            .unwrap();
        let b = r
            .add_body("lower", Some(a), RealVec3::X, RealQuat::IDENTITY, 2.0, half)
            .unwrap();
        r.add_hinge("shoulder", a, axis, RealVec3::ZERO, None).unwrap();
        r.add_hinge("elbow", b, axis, RealVec3::ZERO, None).unwrap();
        (r, b)
    }

    /// A two-link arm in a vertical plane (hinges about y, links along x, 1 kg and 2 kg at their
    /// middles): gravity's torque about each joint, and with a force at the tip.
    #[test]
    fn static_torques_of_a_two_link_arm() {
        let (r, b) = two_link_arm(RealVec3::Y);
        let g = 9.81;
        let mut pose = RobotPose::default();
        let mut tau = [0.0; 2];
        // Level: the weights' lever arms are their x (about +y, a weight at +x turns +y-wise).
        r.forward(RealVec3::ZERO, RealQuat::IDENTITY, &[0.0, 0.0], &mut pose);
        r.static_torques(&pose, g, &[], &mut tau);
        assert!((tau[0] - g * (0.5 + 2.0 * 1.5)).abs() < 1e-9, "{tau:?}");
        assert!((tau[1] - g * 2.0 * 0.5).abs() < 1e-9, "{tau:?}");
        // Held up at the tip by half the weight: the shoulder carries nothing, the elbow less.
        let tip = (b, RealVec3::new(2.0, 0.0, 0.0), RealVec3::new(0.0, 0.0, 1.75 * g));
        r.static_torques(&pose, g, &[tip], &mut tau);
        assert!(tau[0].abs() < 1e-9, "{tau:?}");
        assert!((tau[1] - (g - 1.75 * g)).abs() < 1e-9, "{tau:?}");
        // Turned 60° down at the shoulder: every lever arm by cos 60°.
        let q = core::f64::consts::FRAC_PI_3;
        r.forward(RealVec3::ZERO, RealQuat::IDENTITY, &[q, 0.0], &mut pose);
        r.static_torques(&pose, g, &[], &mut tau);
        assert!((tau[0] - 0.5 * g * 3.5).abs() < 1e-9, "{tau:?}");
        assert!((tau[1] - 0.5 * g).abs() < 1e-9, "{tau:?}");
    }

    /// A two-link arm in a plane: FK against the closed form, and the centre of mass.
    #[test]
    fn planar_two_link_arm() {
        let (mut r, b) = two_link_arm(RealVec3::Z);
        let (t1, t2) = (0.3_f64, -0.7_f64);
        let mut pose = RobotPose::default();
        r.forward(RealVec3::ZERO, RealQuat::IDENTITY, &[t1, t2], &mut pose);
        let elbow = RealVec3::new(crate::math::real::cos(t1), crate::math::real::sin(t1), 0.0);
        assert!((pose.pos[b] - elbow).length() < 1e-12);
        let mid_lower = elbow
            + 0.5
                * RealVec3::new(
                    crate::math::real::cos(t1 + t2),
                    crate::math::real::sin(t1 + t2),
                    0.0,
                );
        let mid_upper = 0.5 * RealVec3::new(crate::math::real::cos(t1), crate::math::real::sin(t1), 0.0);
        let com = (mid_upper + 2.0 * mid_lower) / 3.0;
        assert!((r.centre_of_mass(&pose) - com).length() < 1e-12);
        assert_eq!(
            r.add_hinge("again", b, RealVec3::X, RealVec3::ZERO, None),
            Err(RobotError::SecondJoint)
        );
    }

    /// A hinge off the body's origin keeps its anchor fixed.
    #[test]
    fn a_hinge_turns_about_its_anchor() {
        let mut r = Robot::new();
        let a = r
            .add_body("b", None, RealVec3::ZERO, RealQuat::IDENTITY, 1.0, RealVec3::ZERO)
            .unwrap();
        let anchor = RealVec3::new(0.0, 1.0, 0.0);
        r.add_hinge("j", a, RealVec3::Z, anchor, None).unwrap();
        let mut pose = RobotPose::default();
        r.forward(
            RealVec3::ZERO,
            RealQuat::IDENTITY,
            &[crate::math::consts::FRAC_PI_2],
            &mut pose,
        );
        // The origin swings about (0, 1, 0): to (1, 1, 0).
        assert!((pose.pos[a] - RealVec3::new(1.0, 1.0, 0.0)).length() < 1e-12);
        assert!((pose.pos[a] + pose.rot[a] * anchor - anchor).length() < 1e-12);
    }
}
