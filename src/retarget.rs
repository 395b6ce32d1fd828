//! Retargeting at the std edge: a profile's `[retarget]` map resolved against the robot's MJCF
//! model and a skeleton (errors at the profile's line and column), the human floor measured
//! from a clip, and whole clips retargeted with the report `retarget` prints and `play` keeps.
//!
//! The core's per-frame retargeting ([`Retargeter`]) is re-exported here.

use std::path::{Path, PathBuf};
use std::time::Instant;

use glam::DVec3;
use serde::Serialize;

use crate::fk::{fk64, Pose64};
use crate::formats::{mjcf, FileError, TextError};
use crate::motion::{frame_to_radians, Motion};
use crate::profile::{ChainSpec, Drive, Named, PointSpec, Profile, RetargetSpec};
pub use marionette_core::retarget::*;

pub mod continuity;
pub mod plot;
pub mod walk;
use crate::rig::{JointSource, Rig};
use crate::robot::Robot;
use crate::skeleton::Skeleton;

/// CMU's ASF bone names and the names CMU's BVH conversions give the same bones (a BVH joint
/// sits where the ASF bone of the same name starts).
pub const CMU_BVH_NAMES: &[(&str, &str)] = &[
    ("root", "Hips"),
    ("lhipjoint", "LHipJoint"),
    ("lfemur", "LeftUpLeg"),
    ("ltibia", "LeftLeg"),
    ("lfoot", "LeftFoot"),
    ("ltoes", "LeftToeBase"),
    ("rhipjoint", "RHipJoint"),
    ("rfemur", "RightUpLeg"),
    ("rtibia", "RightLeg"),
    ("rfoot", "RightFoot"),
    ("rtoes", "RightToeBase"),
    ("lowerback", "LowerBack"),
    ("upperback", "Spine"),
    ("thorax", "Spine1"),
    ("lowerneck", "Neck"),
    ("upperneck", "Neck1"),
    ("head", "Head"),
    ("lclavicle", "LeftShoulder"),
    ("lhumerus", "LeftArm"),
    ("lradius", "LeftForeArm"),
    ("lwrist", "LeftHand"),
    ("lhand", "LeftFingerBase"),
    ("lfingers", "LeftHandIndex1"),
    ("lthumb", "LThumb"),
    ("rclavicle", "RightShoulder"),
    ("rhumerus", "RightArm"),
    ("rradius", "RightForeArm"),
    ("rwrist", "RightHand"),
    ("rhand", "RightFingerBase"),
    ("rfingers", "RightHandIndex1"),
    ("rthumb", "RThumb"),
];

/// A profile's retarget map made ready: the robot (limits from the profile's servos), the map
/// in indices, the rig whose servos read the robot's joint vector.
#[derive(Clone, Debug)]
pub struct Setup {
    /// The robot's kinematic tree (joint limits from the profile).
    pub robot: Robot,
    /// The map in skeleton and robot indices.
    pub map: RetargetMap,
    /// The model it came from.
    pub model: PathBuf,
    /// The rig: servo `k` reads robot joint `JointSource::Joint(j)`.
    pub rig: Rig,
    /// Per rig servo: how stiffly it holds its joint, N·m/rad at the joint
    /// ([`crate::servo_dynamics::joint_stiffness`]).
    pub stiffness: Vec<f64>,
}

fn at(profile: &Path, n: &Named, message: String) -> FileError {
    FileError::parse(profile, TextError::new(n.line, n.column, message))
}

impl Setup {
    /// Per robot joint, the velocity limit of the servo that drives it (rad/s; infinite for a
    /// joint no servo drives or whose servo gives no limit).
    #[must_use]
    pub fn joint_speed_limits(&self) -> Vec<f64> {
        self.joint_limits(|s| s.max_velocity)
    }

    /// Per robot joint, the acceleration limit of the servo that drives it (rad/s²; infinite
    /// for a joint no servo drives or whose servo gives no limit).
    #[must_use]
    pub fn joint_acceleration_limits(&self) -> Vec<f64> {
        self.joint_limits(|s| s.max_acceleration)
    }

    /// Per robot joint, the smallest `limit` (ticks per second or second²) of the servos that
    /// drive it, in radians.
    fn joint_limits(&self, limit: impl Fn(&marionette_core::rig::ServoMap) -> f64) -> Vec<f64> {
        let mut limits = vec![f64::INFINITY; self.robot.joints().len()];
        for s in &self.rig.servos {
            if let marionette_core::rig::JointSource::Joint(j) = s.source {
                let v = limit(s) / s.ticks_per_radian().abs();
                if let Some(l) = limits.get_mut(j) {
                    if v.is_finite() && v > 0.0 {
                        *l = l.min(v);
                    }
                }
            }
        }
        limits
    }

    /// Resolves `profile`'s `[retarget]` against its model and `skeleton`.
    ///
    /// # Errors
    /// [`FileError`]: no `[retarget]` section, an unreadable model (naming the model's file,
    /// line and element), a body, joint or bone that does not exist (at the profile's line
    /// and column), a chain whose geometry does not fit, servos that follow bones.
    pub fn new(profile: &Profile, skeleton: &Skeleton) -> Result<Setup, FileError> {
        let path = &profile.path;
        let Some(spec) = &profile.retarget else {
            return Err(FileError::parse(
                path,
                TextError::new(
                    0,
                    0,
                    "its servos follow robot joints but it has no [retarget] section saying which human bones drive them",
                ),
            ));
        };
        let model = mjcf::load(&spec.model).map_err(|e| match e {
            FileError::Io { path: p, source } => FileError::parse(
                path,
                TextError::new(
                    spec.model_at.0,
                    spec.model_at.1,
                    format!("cannot read the model {}: {source}", p.display()),
                ),
            ),
            other => other,
        })?;
        let mut robot = model.robot;
        let model_robot = robot.clone();
        let joint = |n: &Named| -> Result<usize, FileError> {
            let robot = &model_robot;
            robot.joint(&n.name).ok_or_else(|| {
                let known: Vec<&str> = robot.joints().iter().map(|j| j.name.as_str()).collect();
                at(
                    path,
                    n,
                    format!(
                        "no joint `{}` in {}; it has: {}",
                        n.name,
                        spec.model.display(),
                        known.join(" ")
                    ),
                )
            })
        };
        // Servos: robot joints only; their limits become the joints' limits.
        let mut rig = Rig::default();
        for s in &profile.servos {
            let Drive::Joint(name) = &s.drive else {
                return Err(FileError::parse(
                    path,
                    TextError::new(
                        s.line,
                        0,
                        format!(
                            "servo `{}` follows a bone, but the profile retargets onto robot joints: give it `joint = \"…\"`",
                            s.name
                        ),
                    ),
                ));
            };
            let j = joint(&Named {
                name: name.clone(),
                line: s.line,
                column: 0,
            })?;
            let (lo, hi) = (s.min_deg.to_radians(), s.max_deg.to_radians());
            let range = match robot.joints()[j].range {
                Some((a, b)) => (a.max(lo), b.min(hi)),
                None => (lo, hi),
            };
            robot.set_range(j, Some(range));
            // Capacity was checked when the profile was read.
            let _ = rig.servos.push(s.map(JointSource::Joint(j)));
        }
        let base = robot.body(&spec.base.name).ok_or_else(|| {
            let known: Vec<&str> = robot.bodies().iter().map(|b| b.name.as_str()).collect();
            at(
                path,
                &spec.base,
                format!(
                    "no body `{}` in {}; it has: {}",
                    spec.base.name,
                    spec.model.display(),
                    known.join(" ")
                ),
            )
        })?;
        let bone = |n: &Named| find_bone(path, spec, skeleton, n);
        let joints =
            |c: &ChainSpec| -> Result<Vec<usize>, FileError> { c.robot.iter().map(&joint).collect() };
        let pelvis = match &spec.pelvis {
            Some(n) => bone(n)?,
            None => 0,
        };
        let mut arms = [None; 2];
        let mut human_arms = [None; 2];
        for (side, c) in spec.arms.iter().enumerate() {
            if let Some(c) = c {
                let j = joints(c)?;
                arms[side] = Some(ArmChain {
                    joints: [j[0], j[1], j[2]],
                    tip: point_in(path, spec, &robot, robot.joints()[j[2]].body, &c.tip)?,
                });
                human_arms[side] = Some([bone(&c.human[0])?, bone(&c.human[1])?]);
            }
        }
        let mut legs = [LegChain {
            joints: [0; 6],
            sole_centre: DVec3::ZERO,
            sole_half: [0.0; 2],
        }; 2];
        let mut human_legs = [[0; 3]; 2];
        for (side, c) in spec.legs.iter().enumerate() {
            let j = joints(c)?;
            legs[side] = LegChain {
                joints: [j[0], j[1], j[2], j[3], j[4], j[5]],
                sole_centre: point_in(path, spec, &robot, robot.joints()[j[5]].body, &c.sole_centre)?,
                sole_half: c.sole_half_size,
            };
            human_legs[side] = [bone(&c.human[0])?, bone(&c.human[1])?, bone(&c.human[2])?];
        }
        let (head, human_head) = match &spec.head {
            Some(c) => {
                let j = joints(c)?;
                (Some(HeadChain { joints: [j[0], j[1]] }), Some(bone(&c.human[0])?))
            }
            None => (None, None),
        };
        let map = RetargetMap {
            human: HumanBones {
                pelvis,
                arms: human_arms,
                legs: human_legs,
                head: human_head,
            },
            base,
            arms,
            legs,
            head,
            leg_scale: spec.leg_scale,
            arm_scale: [
                spec.arms[0].as_ref().and_then(|c| c.scale),
                spec.arms[1].as_ref().and_then(|c| c.scale),
            ],
        };
        // The geometry check: build once (errors at the chain's table).
        Retargeter::new(
            &robot,
            skeleton,
            map,
            floor_of_rest(skeleton, &map.human),
            Options::default(),
        )
        .map_err(|e| {
            FileError::parse(
                path,
                TextError::new(
                    spec.line,
                    0,
                    format!("the retarget map does not fit {}: {e}", spec.model.display()),
                ),
            )
        })?;
        Ok(Setup {
            robot,
            map,
            model: spec.model.clone(),
            rig,
            stiffness: profile
                .servos
                .iter()
                .map(crate::servo_dynamics::joint_stiffness)
                .collect(),
        })
    }

    /// A retargeter for a stream over `skeleton` with the human floor `floor`.
    ///
    /// # Panics
    /// Never for a setup made by [`Setup::new`] with the same skeleton (checked there).
    #[must_use]
    pub fn retargeter(&self, skeleton: &Skeleton, floor: Floor, options: Options) -> Retargeter {
        let mut r =
            Retargeter::new(&self.robot, skeleton, self.map, floor, options).expect("checked in Setup::new");
        let speed = self.joint_speed_limits();
        for side in 0..2 {
            if let Some(joints) = r.arm_joints(side) {
                r.set_arm_speed_limits(side, joints.map(|j| speed[j]));
            }
        }
        r
    }

    /// Names of the robot's joints, in joint-vector order.
    #[must_use]
    pub fn joint_names(&self) -> Vec<String> {
        self.robot.joints().iter().map(|j| j.name.to_string()).collect()
    }
}

/// A chain's point in `body`'s frame: a site fixed in that body, or the position given.
fn point_in(
    profile: &Path,
    spec: &RetargetSpec,
    robot: &Robot,
    body: usize,
    p: &PointSpec,
) -> Result<DVec3, FileError> {
    match p {
        PointSpec::At(v) => Ok(DVec3::from_array(*v)),
        PointSpec::Site(n) => {
            let Some(site) = robot.site(&n.name) else {
                let known: Vec<&str> = robot.sites().iter().map(|s| s.name.as_str()).collect();
                return Err(at(
                    profile,
                    n,
                    format!(
                        "no site `{}` in {}; it has: {}",
                        n.name,
                        spec.model.display(),
                        if known.is_empty() {
                            "none".to_string()
                        } else {
                            known.join(" ")
                        }
                    ),
                ));
            };
            let s = &robot.sites()[site];
            if s.body != body {
                return Err(at(
                    profile,
                    n,
                    format!(
                        "site `{}` is on body `{}`; the chain ends in body `{}`",
                        n.name,
                        robot.bodies()[s.body].name,
                        robot.bodies()[body].name
                    ),
                ));
            }
            Ok(s.pos)
        }
    }
}

/// The skeleton's bone for a name the map uses: `[retarget.names]` first, then the name
/// itself, then CMU's BVH name for a CMU ASF name.
fn find_bone(
    profile: &Path,
    spec: &RetargetSpec,
    skeleton: &Skeleton,
    n: &Named,
) -> Result<usize, FileError> {
    if let Some((_, alias)) = spec.names.iter().find(|(k, _)| *k == n.name) {
        return skeleton.find(&alias.name).ok_or_else(|| {
            at(
                profile,
                alias,
                format!(
                    "the skeleton has no bone `{}` (named for `{}`)",
                    alias.name, n.name
                ),
            )
        });
    }
    if let Some(b) = skeleton.find(&n.name) {
        return Ok(b);
    }
    let bvh = CMU_BVH_NAMES
        .iter()
        .find(|(asf, _)| *asf == n.name)
        .map(|(_, b)| *b);
    if let Some(b) = bvh.and_then(|b| skeleton.find(b)) {
        return Ok(b);
    }
    let also = bvh.map_or(String::new(), |b| format!(" (nor CMU's BVH name `{b}`)"));
    Err(at(
        profile,
        n,
        format!(
            "the skeleton has no bone `{}`{also}; name the skeleton's bone in [retarget.names], e.g. {} = \"<bone>\"",
            n.name, n.name
        ),
    ))
}

/// The human floor from a clip: the ankle and toe heights (along the rest pose's up) that the
/// lowest foot reaches, taken as the 2nd percentile over the frames so a stray frame does not
/// set it.
#[must_use]
pub fn floor_of_clip(skeleton: &Skeleton, motion: &Motion, human: &HumanBones) -> Floor {
    let rest = floor_of_rest(skeleton, human);
    if motion.is_empty() {
        return rest;
    }
    let up = marionette_core::retarget::human_up(skeleton, human);
    let mut pose = Pose64::default();
    let mut ankles = [Vec::with_capacity(motion.len()), Vec::with_capacity(motion.len())];
    let mut toes = ankles.clone();
    let mut pitches = ankles.clone();
    for frame in motion.frames() {
        let ch = frame_to_radians(skeleton, frame);
        fk64(skeleton, &ch, &mut pose);
        for (side, leg) in human.legs.iter().enumerate() {
            ankles[side].push(pose.tip[leg[1]].dot(up));
            toes[side].push(pose.tip[leg[2]].dot(up));
            pitches[side].push(foot_elevation(&pose, *leg, up));
        }
    }
    let ankle = [
        percentile(&mut ankles[0].clone(), 0.02),
        percentile(&mut ankles[1].clone(), 0.02),
    ];
    let toe = [
        percentile(&mut toes[0].clone(), 0.02),
        percentile(&mut toes[1].clone(), 0.02),
    ];
    // The flat foot's pitch: the median over frames with the foot down (both ends low).
    let units = f64::from(skeleton.units().meters_per_unit());
    let mut foot_pitch = rest.foot_pitch;
    for side in 0..2 {
        let mut down: Vec<f64> = (0..motion.len())
            .filter(|&i| {
                (ankles[side][i] - ankle[side]) * units < PLANT_HEIGHT_M
                    && (toes[side][i] - toe[side]) * units < PLANT_HEIGHT_M
            })
            .map(|i| pitches[side][i])
            .collect();
        if !down.is_empty() {
            foot_pitch[side] = percentile(&mut down, 0.5);
        }
    }
    Floor {
        ankle,
        toe,
        foot_pitch,
    }
}

fn percentile(v: &mut [f64], p: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    let k = ((v.len() as f64 - 1.0) * p).round() as usize;
    v[k.min(v.len() - 1)]
}

/// Root-mean-square and largest value.
#[derive(Clone, Copy, Debug, Default, Serialize, PartialEq)]
pub struct RmsMax {
    /// RMS.
    pub rms: f64,
    /// Largest.
    pub max: f64,
}

/// Direction errors per limb and overall, degrees.
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct LimbErrors {
    /// Every mapped segment.
    pub overall: RmsMax,
    /// Left arm (upper arm, forearm).
    pub left_arm: Option<RmsMax>,
    /// Right arm.
    pub right_arm: Option<RmsMax>,
    /// Left leg (thigh, shin).
    pub left_leg: Option<RmsMax>,
    /// Right leg.
    pub right_leg: Option<RmsMax>,
    /// Head (where the face points).
    pub head: Option<RmsMax>,
}

/// Hand errors per arm (absent for an unmapped arm), mm.
#[derive(Clone, Copy, Debug, Default, Serialize, PartialEq)]
pub struct HandErrors {
    /// Left hand.
    pub left: Option<RmsMax>,
    /// Right hand.
    pub right: Option<RmsMax>,
}

/// The largest joint change between two frames, and the steps faster than a servo can turn.
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct Continuity {
    /// Degrees.
    pub max_joint_step_deg: f64,
    /// The joint.
    pub joint: String,
    /// The frame (index from 0) it happened at.
    pub frame: usize,
    /// Joint steps between frames (summed over joints) faster than the velocity limit of the
    /// servo that drives the joint (clips retargeted whole; absent in a live run).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub steps_over_velocity_limit: Option<u64>,
    /// The fastest joint step against its servo's velocity limit (1: at the limit), with the
    /// joint and the frame (clips retargeted whole).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fastest_step: Option<FastestStep>,
    /// Where the human moved faster than the servos can follow, before the planned trajectory
    /// slowed it (clips planned whole; not with `--per-frame`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub faster_than_servos: Option<FasterThanServos>,
}

/// Where a clip's human moved faster than the robot's servos can follow (the planned
/// trajectory slows there).
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct FasterThanServos {
    /// Joint values of capture glitches (a jump away and back within two frames, or a first
    /// frame unlike the next) taken from their neighbours first.
    pub glitches: u64,
    /// Frames where some joint the human's motion asks for steps faster than its servo can.
    pub frames: u64,
    /// Those frames as spans `[start, end]`, seconds (frames 0.1 s apart or closer joined).
    pub spans_s: Vec<[f64; 2]>,
    /// Frames where a leg that follows the human's feet (not a walking plan) steps faster than
    /// its servos: kept to the feet, not slowed (the command stage limits them; a walking plan
    /// paces the legs).
    pub legs_frames: u64,
}

/// The joint step that asked most of its servo's speed.
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct FastestStep {
    /// Its speed over the servo's velocity limit.
    pub limit_share: f64,
    /// The joint.
    pub joint: String,
    /// The frame (index from 0) it ended at.
    pub frame: usize,
}

/// Counts the joint steps of `frames` (`dt` apart) faster than their servo's velocity limit
/// into `report`, and names the fastest.
fn count_fast_steps(
    report: &mut Continuity,
    frames: &[RetargetFrame],
    dt: f64,
    limits: &[f64],
    names: &[String],
) {
    let mut over = 0;
    let mut fastest = FastestStep::default();
    for (k, w) in frames.windows(2).enumerate() {
        for (j, limit) in limits.iter().enumerate() {
            let share = (w[1].q[j] - w[0].q[j]).abs() / dt / limit;
            if share > 1.0 {
                over += 1;
            }
            if share > fastest.limit_share {
                fastest = FastestStep {
                    limit_share: share,
                    joint: names.get(j).cloned().unwrap_or_default(),
                    frame: k + 1,
                };
            }
        }
    }
    report.steps_over_velocity_limit = Some(over);
    report.fastest_step = Some(fastest);
}

/// What a retargeting run measured (the `retarget` block of the stats JSON, `--report`).
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct RetargetReport {
    /// Frames retargeted.
    pub frames: u64,
    /// Angle between each human segment and the robot segment it drives, in the pelvis frame.
    pub limb_direction_error_deg: LimbErrors,
    /// Distance of each robot hand from the human's hand placed on the robot (the human's
    /// shoulder-to-hand vector at the robot's arm scale from the robot's shoulder, in the
    /// pelvis frame), mm.
    pub hand_error_mm: HandErrors,
    /// How far a planted foot's sole moved during a stance phase (largest, mm).
    pub foot_slide_mm: MaxMm,
    /// Centre of mass inside the support polygon of the planted feet (smallest margin, mm).
    pub com_margin_mm: MinMm,
    /// Joint values held at a limit (summed over frames).
    pub limit_clamps: u64,
    /// Foot targets out of the leg's reach (summed over frames).
    pub out_of_reach: u64,
    /// Lowest sole corner over the run, mm above the floor (never below 0 by design).
    pub lowest_sole_mm: f64,
    /// The largest joint step between frames.
    pub continuity: Continuity,
    /// Share of frames each foot was planted (left, right).
    pub planted_fraction: [f64; 2],
    /// Robot / human leg length.
    pub leg_scale: f64,
    /// Robot / human arm length (left, right).
    pub arm_scale: [f64; 2],
    /// Frames retargeted per second of computer time (with the human's forward kinematics).
    pub frames_per_second: Option<f64>,
    /// Stretches of at least a second with both feet planted, `[start, end]` seconds (clips
    /// retargeted whole; empty in a live run).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub standing_s: Vec<[f64; 2]>,
    /// The walking plan the legs followed (whole-body clips on the floor).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub walk: Option<walk::WalkReport>,
    /// The largest angle a servo was commanded past its joint's to hold it under the static
    /// load (the load compensation; absent when it is off), degrees.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub load_offset_max_deg: Option<f64>,
}

/// The largest value, mm.
#[derive(Clone, Copy, Debug, Default, Serialize, PartialEq)]
pub struct MaxMm {
    /// Largest, mm.
    pub max: f64,
}

/// The smallest value, mm.
#[derive(Clone, Copy, Debug, Default, Serialize, PartialEq)]
pub struct MinMm {
    /// Smallest, mm (null when no foot was ever planted).
    pub min: Option<f64>,
}

/// Accumulates [`RetargetFrame`]s into a [`RetargetReport`], without allocating per frame.
#[derive(Clone, Debug)]
pub struct ReportBuilder {
    frames: u64,
    limb: [(f64, f64, u64); 5],
    slide: f64,
    stance_start: [Option<DVec3>; 2],
    margin: Option<f64>,
    clamps: u64,
    reach: u64,
    lowest: f64,
    previous_q: Vec<f64>,
    step: (f64, usize, usize),
    planted: [u64; 2],
    /// Per arm: sum of squared hand errors (mm²), the largest (mm), frames.
    hand: [(f64, f64, u64); 2],
}

impl ReportBuilder {
    /// An empty report for a robot with `joints` joints.
    #[must_use]
    pub fn new(joints: usize) -> ReportBuilder {
        ReportBuilder {
            frames: 0,
            limb: [(0.0, 0.0, 0); 5],
            slide: 0.0,
            stance_start: [None; 2],
            margin: None,
            clamps: 0,
            reach: 0,
            lowest: f64::INFINITY,
            previous_q: vec![f64::NAN; joints],
            step: (0.0, 0, 0),
            planted: [0; 2],
            hand: [(0.0, 0.0, 0); 2],
        }
    }

    /// Adds one frame; `lowest_sole` is the lowest sole corner's height (metres).
    pub fn add(&mut self, f: &RetargetFrame, lowest_sole: f64) {
        for (k, (sq, n)) in f.limb_error_sq.iter().enumerate() {
            if *n > 0 {
                self.limb[k].0 += sq;
                self.limb[k].1 = self.limb[k].1.max(f.limb_error_deg[k]);
                self.limb[k].2 += u64::from(*n);
            }
        }
        for (h, e) in self.hand.iter_mut().zip(f.hand_error) {
            if e.is_finite() {
                let mm = e * 1000.0;
                *h = (h.0 + mm * mm, h.1.max(mm), h.2 + 1);
            }
        }
        for side in 0..2 {
            if f.planted[side] {
                self.planted[side] += 1;
                let start = *self.stance_start[side].get_or_insert(f.sole[side]);
                self.slide = self.slide.max((f.sole[side] - start).length() * 1000.0);
            } else {
                self.stance_start[side] = None;
            }
        }
        if f.com_margin.is_finite() {
            let m = f.com_margin * 1000.0;
            self.margin = Some(self.margin.map_or(m, |x: f64| x.min(m)));
        }
        self.clamps += u64::from(f.clamps);
        self.reach += u64::from(f.out_of_reach);
        self.lowest = self.lowest.min(lowest_sole * 1000.0);
        for (j, (p, q)) in self.previous_q.iter_mut().zip(f.q.iter()).enumerate() {
            let d = (q - *p).abs().to_degrees();
            if d > self.step.0 {
                self.step = (d, j, self.frames as usize);
            }
            *p = *q;
        }
        self.frames += 1;
    }

    /// The report, with joint names for the continuity entry.
    #[must_use]
    pub fn finish(
        &self,
        retargeter: &Retargeter,
        joint_names: &[String],
        fps: Option<f64>,
    ) -> RetargetReport {
        let rms_max = |k: usize| {
            let (sq, max, n) = self.limb[k];
            (n > 0).then(|| RmsMax {
                rms: (sq / n as f64).sqrt(),
                max,
            })
        };
        let (sq, n) = self.limb.iter().fold((0.0, 0), |(s, c), l| (s + l.0, c + l.2));
        let overall = RmsMax {
            rms: if n > 0 { (sq / n as f64).sqrt() } else { 0.0 },
            max: self.limb.iter().map(|l| l.1).fold(0.0, f64::max),
        };
        let frames = self.frames.max(1) as f64;
        let hand = |side: usize| {
            let (sq, max, n) = self.hand[side];
            (n > 0).then(|| RmsMax {
                rms: (sq / n as f64).sqrt(),
                max,
            })
        };
        RetargetReport {
            frames: self.frames,
            hand_error_mm: HandErrors {
                left: hand(0),
                right: hand(1),
            },
            limb_direction_error_deg: LimbErrors {
                overall,
                left_arm: rms_max(0),
                right_arm: rms_max(1),
                left_leg: rms_max(2),
                right_leg: rms_max(3),
                head: rms_max(4),
            },
            foot_slide_mm: MaxMm { max: self.slide },
            com_margin_mm: MinMm { min: self.margin },
            limit_clamps: self.clamps,
            out_of_reach: self.reach,
            lowest_sole_mm: if self.lowest.is_finite() { self.lowest } else { 0.0 },
            continuity: Continuity {
                max_joint_step_deg: self.step.0,
                joint: joint_names.get(self.step.1).cloned().unwrap_or_default(),
                frame: self.step.2,
                ..Continuity::default()
            },
            planted_fraction: [self.planted[0] as f64 / frames, self.planted[1] as f64 / frames],
            leg_scale: retargeter.leg_scale(),
            arm_scale: retargeter.arm_scale(),
            frames_per_second: fps,
            standing_s: Vec::new(),
            walk: None,
            load_offset_max_deg: None,
        }
    }
}

/// A clip retargeted: the joint trajectory and per-frame results.
#[derive(Clone, Debug)]
pub struct ClipRetarget {
    /// Seconds from the clip's start, per frame.
    pub times: Vec<f64>,
    /// Per frame: the full result (joints, base pose, errors, feet).
    pub frames: Vec<RetargetFrame>,
    /// The human floor the run measured on the clip.
    pub floor: Floor,
    /// The report.
    pub report: RetargetReport,
}

/// Retargets every frame of `motion`.
#[must_use]
pub fn retarget_clip(setup: &Setup, skeleton: &Skeleton, motion: &Motion, options: Options) -> ClipRetarget {
    let floor = floor_of_clip(skeleton, motion, &setup.map.human);
    retarget_clip_with(setup, skeleton, motion, options, floor, |_| None)
}

/// Retargets every frame of `motion` over the human floor `floor`, frame `k` with the legs and
/// pelvis on `plan(k)` when it gives a stance ([`Retargeter::step_on_plan`]).
pub fn retarget_clip_with(
    setup: &Setup,
    skeleton: &Skeleton,
    motion: &Motion,
    options: Options,
    floor: Floor,
    plan: impl Fn(usize) -> Option<PlannedStance>,
) -> ClipRetarget {
    let mut r = setup.retargeter(skeleton, floor, options);
    let n = setup.robot.joints().len();
    let dt = 1.0 / motion.frame_rate;
    let frames_in: Vec<Vec<f64>> = motion.frames().map(|f| frame_to_radians(skeleton, f)).collect();
    let mut pose = Pose64::default();
    let mut out = RetargetFrame::default();
    let mut frames = Vec::with_capacity(motion.len());
    let started = Instant::now();
    let mut solutions: [Vec<ArmSolutions>; 2] = Default::default();
    let mut planned_legs = false;
    for (k, ch) in frames_in.iter().enumerate() {
        fk64(skeleton, ch, &mut pose);
        match plan(k) {
            Some(stance) => {
                planned_legs = true;
                r.step_on_plan(&setup.robot, &pose, dt, &stance, &mut out);
            }
            None => r.step(&setup.robot, &pose, dt, &mut out),
        }
        frames.push(out.clone());
        if !options.per_frame {
            for (side, sols) in solutions.iter_mut().enumerate() {
                let mut s = ArmSolutions::new();
                r.arm_solutions(&pose, side, None, &mut s);
                sols.push(s);
            }
        }
    }
    let faster_than_servos = if options.per_frame {
        None
    } else {
        Some(plan_clip(
            setup,
            &mut r,
            skeleton,
            &frames_in,
            dt,
            &solutions,
            planned_legs,
            &mut frames,
        ))
    };
    let elapsed = started.elapsed().as_secs_f64();
    let mut report = ReportBuilder::new(n);
    for f in &frames {
        report.add(f, f.lowest_sole);
    }
    let fps = (elapsed > 0.0).then(|| frames.len() as f64 / elapsed);
    let names = setup.joint_names();
    let mut report = report.finish(&r, &names, fps);
    count_fast_steps(
        &mut report.continuity,
        &frames,
        dt,
        &setup.joint_speed_limits(),
        &names,
    );
    report.continuity.faster_than_servos = faster_than_servos;
    let mut start = None;
    for (i, f) in frames.iter().enumerate() {
        let both = f.planted[0] && f.planted[1];
        match (both, start) {
            (true, None) => start = Some(i),
            (false, Some(s0)) => {
                if (i - s0) as f64 * dt >= 1.0 {
                    report.standing_s.push([s0 as f64 * dt, (i - 1) as f64 * dt]);
                }
                start = None;
            }
            _ => {}
        }
    }
    if let Some(s0) = start {
        if (frames.len() - s0) as f64 * dt >= 1.0 {
            report
                .standing_s
                .push([s0 as f64 * dt, (frames.len() - 1) as f64 * dt]);
        }
    }
    ClipRetarget {
        times: (0..frames.len()).map(|i| i as f64 * dt).collect(),
        report,
        frames,
        floor,
    }
}

/// Makes a clip's per-frame retargeting one the servos can play: each arm's branches planned
/// over the clip ([`continuity::plan_branches`]), then every joint a servo drives but the legs'
/// (which follow their feet, or a walking plan that paces them) cleared of capture glitches
/// ([`continuity::remove_glitches`]) and kept within its servo's velocity and acceleration
/// ([`continuity::limit_speed`]), and the frames measured again (`planned_legs`: the ZMP is the
/// walking plan's, kept). Returns where the human moved faster than the servos can follow.
#[allow(clippy::too_many_arguments)]
fn plan_clip(
    setup: &Setup,
    r: &mut Retargeter,
    skeleton: &Skeleton,
    frames_in: &[Vec<f64>],
    dt: f64,
    solutions: &[Vec<ArmSolutions>; 2],
    planned_legs: bool,
    frames: &mut [RetargetFrame],
) -> FasterThanServos {
    let speed = setup.joint_speed_limits();
    let accel = setup.joint_acceleration_limits();
    let step: Vec<f64> = speed.iter().map(|v| v * dt).collect();
    for (side, sols) in solutions.iter().enumerate() {
        let Some(joints) = r.arm_joints(side) else {
            continue;
        };
        let Some(path) = continuity::plan_branches(sols, joints.map(|j| step[j])) else {
            continue;
        };
        for ((f, s), &b) in frames.iter_mut().zip(sols).zip(&path) {
            for (k, j) in joints.iter().enumerate() {
                f.q[*j] = s[b].q[k];
            }
        }
    }
    let legs: Vec<usize> = setup.map.legs.iter().flat_map(|l| l.joints).collect();
    let limited: Vec<usize> = (0..setup.robot.joints().len())
        .filter(|j| speed[*j].is_finite() && !legs.contains(j))
        .collect();
    let mut x = vec![0.0; frames.len()];
    let mut glitches = 0;
    for &j in &limited {
        glitches += on_joint(frames, j, &mut x, |x| continuity::remove_glitches(x, step[j])) as u64;
    }
    let q: Vec<Vec<f64>> = frames
        .iter()
        .map(|f| limited.iter().map(|&j| f.q[j]).collect())
        .collect();
    let fast = continuity::fast_frames(&q, &limited.iter().map(|&j| step[j]).collect::<Vec<_>>());
    let free_legs: Vec<usize> = if planned_legs {
        Vec::new()
    } else {
        legs.iter().copied().filter(|j| speed[*j].is_finite()).collect()
    };
    let legs_q: Vec<Vec<f64>> = frames
        .iter()
        .map(|f| free_legs.iter().map(|&j| f.q[j]).collect())
        .collect();
    let legs_fast = continuity::fast_frames(&legs_q, &free_legs.iter().map(|&j| step[j]).collect::<Vec<_>>());
    // A hair inside the limits, so rounding never puts a step over them.
    let share = 1.0 - 1e-6;
    for &j in &limited {
        on_joint(frames, j, &mut x, |x| {
            continuity::limit_speed(
                x,
                step[j] * share,
                accel[j] * dt * dt * share,
                setup.robot.joints()[j].range,
            );
        });
    }
    let mut pose = Pose64::default();
    for (f, ch) in frames.iter_mut().zip(frames_in) {
        let zmp = f.zmp;
        fk64(skeleton, ch, &mut pose);
        r.remeasure(&setup.robot, &pose, f);
        if planned_legs {
            f.zmp = zmp;
        }
    }
    FasterThanServos {
        glitches,
        legs_frames: legs_fast.len() as u64,
        frames: fast.len() as u64,
        spans_s: continuity::spans(&fast, (0.1 / dt).round() as usize)
            .into_iter()
            .map(|[a, b]| [a as f64 * dt, b as f64 * dt])
            .collect(),
    }
}

/// Runs `edit` on joint `j`'s values over `frames`, through the scratch `x` (one per frame).
fn on_joint<R>(
    frames: &mut [RetargetFrame],
    j: usize,
    x: &mut [f64],
    edit: impl FnOnce(&mut [f64]) -> R,
) -> R {
    for (x, f) in x.iter_mut().zip(frames.iter()) {
        *x = f.q[j];
    }
    let r = edit(x);
    for (x, f) in x.iter().zip(frames.iter_mut()) {
        f.q[j] = *x;
    }
    r
}

/// Writes the joint trajectory as CSV: `time` then one column per joint (radians).
///
/// # Errors
/// Writing failed.
pub fn write_csv(mut w: impl std::io::Write, names: &[String], run: &ClipRetarget) -> std::io::Result<()> {
    write!(w, "time")?;
    for n in names {
        write!(w, ",{n}")?;
    }
    writeln!(w)?;
    for (t, f) in run.times.iter().zip(&run.frames) {
        write!(w, "{t:.6}")?;
        for v in &f.q[..names.len()] {
            write!(w, ",{v:.9}")?;
        }
        writeln!(w)?;
    }
    Ok(())
}
