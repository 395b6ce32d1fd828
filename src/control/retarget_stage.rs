//! Retargeting inside the tick: each human pose becomes the robot's joint vector.

use glam::DVec3;

use crate::fk::Pose64;
use crate::retarget::{Floor, Options, ReportBuilder, RetargetFrame, RetargetReport, Retargeter, Setup};
use crate::rig::Rig;
use crate::robot::{Robot, RobotPose, MAX_ROBOT_JOINTS};
use crate::skeleton::Skeleton;

/// Standard gravity, m/s².
const GRAVITY: f64 = 9.81;

/// Retargeting inside the tick, for profiles whose servos follow a robot's joints: each new
/// human pose becomes the robot's joint vector, which the rig's servos read.
#[derive(Clone, Debug)]
pub struct RetargetStage {
    robot: Robot,
    retargeter: Retargeter,
    pub(super) frame: RetargetFrame,
    report: ReportBuilder,
    names: Vec<String>,
    last_clip_time: f64,
    pose: Box<RobotPose>,
    present_q: [f64; MAX_ROBOT_JOINTS],
    /// Frames retargeted ahead (the look-ahead's preview) and their due times, reported when
    /// they are played: a frame taken ahead but never played is not the run's.
    pending: std::collections::VecDeque<(u64, RetargetFrame)>,
    /// A whole clip retargeted on a walking plan, one frame per clip frame, and the clip's
    /// frame rate: a pose of the clip is the planned frame at its clip time.
    planned: Option<(Vec<RetargetFrame>, f64)>,
    /// The plan's figures, for the run's report.
    walk: Option<crate::retarget::walk::WalkReport>,
    /// The clip time a pre-roll (negative clip times) holds.
    clip_start: f64,
    /// Per rig servo, its stiffness at the joint (N·m/rad); empty: no load compensation.
    stiffness: Vec<f64>,
    /// Per robot joint, the static load's torque (scratch).
    torque: Vec<f64>,
    /// The largest load offset commanded, radians.
    largest_offset: f64,
}

impl RetargetStage {
    /// A stage for `setup` over `skeleton`, the human floor at `floor`.
    #[must_use]
    pub fn new(setup: &Setup, skeleton: &Skeleton, floor: Floor, options: Options) -> RetargetStage {
        RetargetStage {
            robot: setup.robot.clone(),
            retargeter: setup.retargeter(skeleton, floor, options),
            frame: RetargetFrame::default(),
            report: ReportBuilder::new(setup.robot.joints().len()),
            names: setup.joint_names(),
            last_clip_time: f64::NAN,
            pose: Box::default(),
            present_q: [0.0; MAX_ROBOT_JOINTS],
            pending: std::collections::VecDeque::new(),
            planned: None,
            walk: None,
            clip_start: 0.0,
            stiffness: setup.stiffness.clone(),
            torque: vec![0.0; setup.robot.joints().len()],
            largest_offset: 0.0,
        }
    }

    /// Turns the load compensation off (a robot on a stand, whose feet bear nothing) or on
    /// (the default).
    pub fn set_load_compensation(&mut self, on: bool, setup: &Setup) {
        self.stiffness = if on { setup.stiffness.clone() } else { Vec::new() };
    }

    /// Per servo of `rig`, what its command adds to the current frame's angle so that the
    /// horn ends on it under the pose's static load ([`Retargeter::load_torques`]): the
    /// torque over the servo's stiffness, through the rig's direction of the joint. Zero for
    /// servos that do not drive a joint or whose stiffness is unknown. Allocates nothing.
    pub(super) fn load_offsets(&mut self, rig: &Rig, out: &mut [f64]) {
        out.fill(0.0);
        if self.stiffness.is_empty() {
            return;
        }
        self.retargeter
            .load_torques(&self.robot, &self.frame, GRAVITY, &mut self.torque);
        for ((o, servo), k) in out.iter_mut().zip(&rig.servos).zip(&self.stiffness) {
            if let crate::rig::JointSource::Joint(j) = servo.source {
                if let Some(t) = self.torque.get(j) {
                    if *k > 0.0 && k.is_finite() && t.is_finite() {
                        *o = -t / k;
                        self.largest_offset = self.largest_offset.max(o.abs());
                    }
                }
            }
        }
    }

    /// Plays `frames` (a clip retargeted whole — its arm branches and speeds planned, on a
    /// walking plan when `walk` gives its figures — at `rate` frames a second) in place of
    /// retargeting each pose: a pose at clip time `t` is the frames either side of `t × rate`.
    pub fn set_plan(
        &mut self,
        frames: Vec<RetargetFrame>,
        rate: f64,
        walk: Option<crate::retarget::walk::WalkReport>,
    ) {
        self.planned = (!frames.is_empty() && rate > 0.0).then_some((frames, rate));
        self.walk = walk;
    }

    /// The clip time the run starts at: a pre-roll's samples (negative clip times) hold the
    /// planned frame there.
    pub fn set_clip_start(&mut self, seconds: f64) {
        self.clip_start = if seconds.is_finite() {
            seconds.max(0.0)
        } else {
            0.0
        };
    }

    /// The planned frame's joint angles at the clip time the run starts at (the pose a
    /// pre-roll holds); `None` without a plan.
    #[must_use]
    pub fn planned_start(&self) -> Option<[f64; MAX_ROBOT_JOINTS]> {
        let (frames, rate) = self.planned.as_ref()?;
        let k = (self.clip_start * rate)
            .round()
            .clamp(0.0, (frames.len() - 1) as f64) as usize;
        Some(frames[k].q)
    }

    /// Whether it plays a walking plan.
    #[must_use]
    pub fn walking(&self) -> bool {
        self.walk.is_some() && self.planned.is_some()
    }

    /// The robot's standing stance, joint angles ([`Retargeter::stance`]).
    #[must_use]
    pub fn stance(&self) -> [f64; MAX_ROBOT_JOINTS] {
        self.retargeter.stance()
    }

    /// Room for `frames` frames retargeted ahead (before the first tick).
    pub(super) fn reserve(&mut self, frames: usize) {
        self.pending = crate::resident::deque(frames.max(4), (0, RetargetFrame::default()));
    }

    /// Reports the frames due by `due_ns` (played now).
    pub(super) fn report_until(&mut self, due_ns: u64) {
        while self.pending.front().is_some_and(|(d, _)| *d <= due_ns) {
            if let Some((_, f)) = self.pending.pop_front() {
                self.report.add(&f, f.lowest_sole);
            }
        }
    }

    /// The effectors (hands, soles) at the `present` angles of the rig's servos, the base
    /// where the retargeting put it for that source sample, metres.
    pub(super) fn present_effectors(
        &mut self,
        rig: &Rig,
        present: &[f64],
        base: (DVec3, glam::DQuat),
    ) -> [DVec3; 4] {
        let (pos, rot) = self.retargeter.model_placement(base.0, base.1);
        self.present_q.copy_from_slice(&self.frame.q);
        for (servo, angle) in rig.servos.iter().zip(present) {
            if let crate::rig::JointSource::Joint(j) = servo.source {
                if let Some(q) = self.present_q.get_mut(j) {
                    *q = *angle;
                }
            }
        }
        self.robot.forward(pos, rot, &self.present_q, &mut self.pose);
        self.retargeter.effector_points(&self.robot, &self.pose)
    }

    /// What the run's retargeting measured.
    #[must_use]
    pub fn report(&self) -> RetargetReport {
        let mut r = self.report.finish(&self.retargeter, &self.names, None);
        r.walk.clone_from(&self.walk);
        r.load_offset_max_deg = (!self.stiffness.is_empty()).then_some(self.largest_offset.to_degrees());
        r
    }

    /// The robot's joints for the human pose `channels` as this stage's next step makes them
    /// (`dt` seconds after the one before), the stage used up: on a copy of a stage before its
    /// run, the joints of the run's first sample.
    #[must_use]
    pub fn joints_of(mut self, skeleton: &Skeleton, channels: &[f64], dt: f64) -> [f64; MAX_ROBOT_JOINTS] {
        let mut pose = Pose64::default();
        crate::fk::fk64(skeleton, channels, &mut pose);
        self.step(&pose, f64::NAN, dt, 0);
        self.frame.q
    }

    /// One human pose, `dt` seconds after the previous one (clip time when the input has
    /// it). Allocates nothing.
    pub(super) fn step(&mut self, pose: &Pose64, clip_time: f64, tick_dt: f64, due_ns: u64) {
        let dt =
            if clip_time.is_finite() && self.last_clip_time.is_finite() && clip_time > self.last_clip_time {
                clip_time - self.last_clip_time
            } else {
                tick_dt
            };
        self.last_clip_time = clip_time;
        match &self.planned {
            Some((frames, rate)) if clip_time.is_finite() => {
                // Between the two frames either side of the clip time, linearly (the feet's
                // contacts and the limb figures from the nearer one); a pre-roll holds the
                // start's.
                let t = if clip_time < 0.0 {
                    self.clip_start
                } else {
                    clip_time
                };
                let at = (t * rate).clamp(0.0, (frames.len() - 1) as f64);
                let k = at.floor() as usize;
                let next = (k + 1).min(frames.len() - 1);
                let w = at - k as f64;
                self.frame.clone_from(&frames[if w < 0.5 { k } else { next }]);
                blend(&mut self.frame, &frames[k], &frames[next], w);
            }
            _ => self.retargeter.step(&self.robot, pose, dt, &mut self.frame),
        }
        if self.pending.len() == self.pending.capacity() {
            // Never grown in a tick: the oldest goes to the report now.
            self.report_until(self.pending.front().map_or(0, |(d, _)| *d));
        }
        self.pending.push_back((due_ns, self.frame.clone()));
    }
}

/// Puts the continuous quantities of `out` (joints, base, centre of mass, ZMP, the soles of
/// feet in the air, effectors) at `w` of the way from `a` to `b`; `out` holds the nearer
/// frame, whose planted soles it keeps.
fn blend(out: &mut RetargetFrame, a: &RetargetFrame, b: &RetargetFrame, w: f64) {
    for ((q, qa), qb) in out.q.iter_mut().zip(&a.q).zip(&b.q) {
        *q = qa + w * (qb - qa);
    }
    out.base_pos = a.base_pos.lerp(b.base_pos, w);
    out.base_rot = a.base_rot.slerp(b.base_rot, w);
    out.com = a.com.lerp(b.com, w);
    out.zmp = a.zmp.lerp(b.zmp, w);
    for side in 0..2 {
        // A foot planted in the nearer frame stays where that frame put it (a landing between
        // the two frames is not a slide).
        if !out.planted[side] {
            out.sole[side] = a.sole[side].lerp(b.sole[side], w);
        }
    }
    for ((e, ea), eb) in out.effectors.iter_mut().zip(&a.effectors).zip(&b.effectors) {
        *e = ea.lerp(*eb, w);
    }
}
