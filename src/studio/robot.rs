//! The robot beside the human, for a profile of robot joints: the studio's pose retargeted as
//! the loop retargets it (the base, the feet, the ZMP), the robot drawn at its servos' present
//! angles where the loop has read them (the retargeted angles until then), with its soles, the
//! support polygon of the planted ones, its centre of mass and the ZMP on the floor.

use glam::{DQuat, DVec2, DVec3};
use serde_json::{json, Value};

use crate::fk::Pose64;
use crate::retarget::{Floor, Options, RetargetFrame, Retargeter, Setup};
use crate::rig::{JointSource, Rig};
use crate::robot::{Robot, RobotPose};
use crate::skeleton::Skeleton;
use marionette_core::retarget::convex_hull;

/// How far to the human's left the robot stands, in the robot's metres (beside, not on it).
pub const BESIDE_M: f64 = 0.25;

/// The robot's half of the studio's view.
#[derive(Debug)]
pub struct RobotView {
    robot: Robot,
    rig: Rig,
    retargeter: Retargeter,
    frame: RetargetFrame,
    pose: Box<RobotPose>,
    q: Vec<f64>,
}

impl RobotView {
    /// The view of `setup`'s robot for poses of `skeleton` over the human floor `floor`.
    #[must_use]
    pub fn new(setup: &Setup, skeleton: &Skeleton, floor: Floor) -> RobotView {
        RobotView {
            robot: setup.robot.clone(),
            rig: setup.rig.clone(),
            retargeter: setup.retargeter(skeleton, floor, Options::default()),
            frame: RetargetFrame::default(),
            pose: Box::default(),
            q: vec![0.0; setup.robot.joints().len()],
        }
    }

    /// The robot for the human pose `human` (`dt` s after the last), its servos at `present`
    /// (radians, rig order; NaN where not read), each point mapped by `to_page` from the
    /// human's world: `links` (each body from its parent's frame to its own), `soles` (four
    /// corners each and whether planted), `support` (the planted soles' hull), `com` and `zmp`
    /// (on the floor), `present` (whether the servos' angles were drawn).
    pub fn view(
        &mut self,
        human: &Pose64,
        dt: f64,
        present: &[f64],
        to_page: impl Fn(DVec3) -> DVec3,
    ) -> Value {
        self.retargeter.step(&self.robot, human, dt, &mut self.frame);
        let n = self.q.len();
        self.q.copy_from_slice(&self.frame.q[..n]);
        let mut read = false;
        for (servo, angle) in self.rig.servos.iter().zip(present) {
            if let (JointSource::Joint(j), true) = (servo.source, angle.is_finite()) {
                if let Some(q) = self.q.get_mut(j) {
                    *q = *angle;
                    read = true;
                }
            }
        }
        let (pos, rot) = self
            .retargeter
            .model_placement(self.frame.base_pos, self.frame.base_rot);
        self.robot.forward(pos, rot, &self.q, &mut self.pose);
        let beside = DVec3::new(0.0, BESIDE_M, 0.0);
        let page = |p: DVec3| to_page(self.retargeter.robot_point_in_human(p + beside)).to_array();
        let links: Vec<[[f64; 3]; 2]> = self
            .robot
            .bodies()
            .iter()
            .enumerate()
            .filter_map(|(b, body)| {
                body.parent
                    .map(|p| [page(self.pose.pos[p]), page(self.pose.pos[b])])
            })
            .collect();
        let half = self.retargeter.sole_half();
        let mut planted_corners = Vec::with_capacity(8);
        let soles: Vec<Value> = (0..2)
            .map(|side| {
                let c = self.frame.sole[side];
                let turn = DQuat::from_rotation_z(self.frame.sole_yaw[side]);
                let [l, w] = half[side];
                let corners = [(l, w), (-l, w), (-l, -w), (l, -w)]
                    .map(|(x, y)| DVec3::new(c.x, c.y, 0.0) + turn * DVec3::new(x, y, 0.0));
                if self.frame.planted[side] {
                    planted_corners.extend(corners.iter().map(|p| DVec2::new(p.x, p.y)));
                }
                json!({
                    "corners": corners.map(page),
                    "planted": self.frame.planted[side],
                })
            })
            .collect();
        let support: Vec<[f64; 3]> = convex_hull::<8>(&planted_corners)
            .iter()
            .map(|p| page(DVec3::new(p.x, p.y, 0.0)))
            .collect();
        let com = self.robot.centre_of_mass(&self.pose);
        json!({
            "links": links,
            "soles": soles,
            "support": support,
            "com": page(DVec3::new(com.x, com.y, 0.0)),
            "com_height_m": com.z,
            "zmp": page(DVec3::new(self.frame.zmp.x, self.frame.zmp.y, 0.0)),
            "present": read,
        })
    }
}
