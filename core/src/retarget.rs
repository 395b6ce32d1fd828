//! Retargeting a human pose onto a robot whose kinematics differ from the human's (a humanoid
//! such as the ROBOTIS OP3: 3-DOF arms, 6-DOF legs, a pan/tilt head), frame by frame, in fixed
//! capacity and without allocation.
//!
//! Frames. The human's *pelvis frame* (forward, left, up) comes from the rest pose: left from the
//! right hip to the left hip, up from the pelvis towards the head, forward = left × up; the robot's
//! from its zero pose the same way. Directions are compared in these frames, so a robot whose
//! base axes differ from the capture's world axes (z up against y up) needs no setting.
//!
//! Per frame ([`Retargeter::step`]):
//! * **Pelvis**: the base turns as the human pelvis turns; its height and path are the human's,
//!   scaled by the leg-length ratio (floor at z = 0, from the clip's lowest feet).
//! * **Arms** follow *where the hands go*: the hand's target is the human's shoulder-to-wrist
//!   vector at the robot's arm scale, from the robot's shoulder. The 3-DOF arm reaches it in
//!   closed form (the elbow from the distance — subproblem 3, the help note's eq. 16 —, the
//!   shoulder from the direction — subproblem 2), refined on the hand's position within the
//!   limits; out of reach or past a limit, the nearest point it can reach. Of the solutions
//!   (two elbow and two shoulder branches) the one whose upper arm lies nearest the human's is
//!   taken ([`ArmSolution::cost`]); a stream keeps its branch until staying has cost more than
//!   the jump to another (at the servos' speeds); a whole clip plans its branches over time
//!   instead (the std edge).
//! * **Legs** follow *end points*: the ankle at the scaled human ankle, the sole flat on the floor
//!   while the foot is planted, solved in closed form in product-of-exponentials form (knee from
//!   the hip–ankle distance — subproblem 3 —, ankle pitch and roll by subproblem 2, hip yaw, roll
//!   and pitch by subproblems 2 and 1), exact when the hip axes meet in a point and the ankle axes
//!   in another.
//! * **Head**: pan and tilt point the head where the human head faces.
//! * **Feet**: a foot is planted when it is low and slow (with hysteresis); a planted foot stays
//!   where it landed (position and heading), flat; a foot never goes below the floor; after
//!   lift-off the locked offset fades out over [`RELEASE_S`].
//! * **Balance**: the pelvis moves over the ground so the centre of mass stays over the support
//!   polygon of the planted feet with a margin; the arms keep following.
//!
//! Joint limits clamp each joint on its own: a joint at its limit does not move its neighbours.
//! A leg takes, of its two ankle and two hip solutions, the one nearest its previous frame (a
//! leg whose foot is out of reach would otherwise flip hip and ankle for a frame); the arms keep
//! a branch memory; planted feet are locked where they landed. All three settle within a step,
//! so a clip gives the same joints wherever it starts once its feet have stepped.

use crate::math::{real, Real, RealMat3, RealQuat, RealVec2, RealVec3};

use crate::fk::{fk64, Pose64};
use crate::footstep::{Footprint, StepLimits};
use crate::robot::{Robot, RobotPose, MAX_ROBOT_JOINTS};
use crate::skeleton::Skeleton;

/// Left and right.
pub const SIDES: [&str; 2] = ["left", "right"];

/// Extra cost ([`ArmSolution::cost`]) another arm branch must save, beyond the jump to it,
/// before a stream switches to it.
pub const BRANCH_HYSTERESIS: Real = 1.0;

/// The hand error that costs an arm solution as much as [`ELBOW_TOLERANCE`] of upper-arm
/// direction, metres.
pub const HAND_TOLERANCE_M: Real = 0.003;

/// The upper arm's direction error that costs an arm solution as much as
/// [`HAND_TOLERANCE_M`] of hand error, radians.
pub const ELBOW_TOLERANCE: Real = 0.5;

/// Weight of an arm joint's step between frames (its share of the servo's speed limit,
/// squared) in the cost of a path through the arm's solutions: a slow path is preferred among
/// equally good poses.
pub const STEP_WEIGHT: Real = 0.01;

/// Weight of the part of a step beyond the servo's speed limit (as a share of the limit,
/// squared): a branch changes where it costs the robot least to get there.
pub const OVERSPEED_WEIGHT: Real = 1.0;

/// What moving an arm from angles `a` to `b` in one frame costs, each joint's step against
/// `step_limit` (radians a frame): `STEP_WEIGHT·s² + OVERSPEED_WEIGHT·max(0, s − 1)²` for the
/// step's share `s` of its limit, summed. Zero without limits (infinite).
#[must_use]
pub fn arm_step_cost(a: [Real; 3], b: [Real; 3], step_limit: [Real; 3]) -> Real {
    let mut cost = 0.0;
    for k in 0..3 {
        if step_limit[k].is_finite() && step_limit[k] > 0.0 {
            let share = (b[k] - a[k]).abs() / step_limit[k];
            let over = (share - 1.0).max(0.0);
            cost += STEP_WEIGHT * share * share + OVERSPEED_WEIGHT * over * over;
        }
    }
    cost
}

/// Most distinct solutions an arm gives for one hand target.
pub const MAX_ARM_SOLUTIONS: usize = 8;

/// The solutions of an arm for one frame.
pub type ArmSolutions = heapless::Vec<ArmSolution, MAX_ARM_SOLUTIONS>;

/// One way a 3-DOF arm puts its hand on (or nearest) its target.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ArmSolution {
    /// Shoulder, shoulder and elbow angles, radians, within the joints' limits.
    pub q: [Real; 3],
    /// Distance of the hand from its target, metres.
    pub hand_error: Real,
    /// Angle between the robot's upper arm and the human's, radians.
    pub elbow_error: Real,
}

impl ArmSolution {
    /// What taking this solution costs: the hand error in [`HAND_TOLERANCE_M`] and the upper
    /// arm's direction error in [`ELBOW_TOLERANCE`], squared and summed.
    #[must_use]
    pub fn cost(&self) -> Real {
        let h = self.hand_error / HAND_TOLERANCE_M;
        let e = self.elbow_error / ELBOW_TOLERANCE;
        h * h + e * e
    }
}

/// The share of a leg's full length (hip to ankle, straight) a foot target may be away.
pub const REACH_SHARE: Real = 0.995;

/// Most fixed-point corrections of a leg's closed form (each shrinks the ankle's miss about
/// a hundredfold on the OP3).
pub const LEG_CORRECTIONS: usize = 4;

/// Damped-least-squares iterations for a leg without the closed form.
pub const NUMERIC_LEG_ITERATIONS: usize = 40;

/// Damping of those iterations (metres).
pub const NUMERIC_LEG_DAMPING: Real = 1e-3;

/// Seconds over which a released foot's locked offset fades out.
pub const RELEASE_S: Real = 0.25;

/// A foot is planted when lower than this (metres above its floor height, human scale)…
pub const PLANT_HEIGHT_M: Real = 0.03;
/// …and slower than this (m/s, human scale, horizontal).
pub const PLANT_SPEED_M_S: Real = 0.3;
/// A planted foot is released when higher than this…
pub const RELEASE_HEIGHT_M: Real = 0.05;
/// …or faster than this.
pub const RELEASE_SPEED_M_S: Real = 0.6;

/// The centre of mass is kept this far inside the support polygon (metres, robot scale).
pub const BALANCE_MARGIN_M: Real = 0.01;

/// Fastest the balance shift of the pelvis may change, m/s (robot scale).
pub const BALANCE_SPEED_M_S: Real = 0.25;

/// The stance's hips sit this share of the leg lower than straight.
pub const STANCE_DROP: Real = 0.08;

/// Share of the legs' geometric reach a planned step may use.
pub const STEP_REACH_SHARE: Real = 0.8;

/// Gap between the soles' edges at the narrowest step, metres.
pub const SOLE_GAP_M: Real = 0.01;

/// Largest turn of one step against the stance foot (radians, 30°).
pub const STEP_TURN: Real = crate::math::consts::FRAC_PI_6;

/// Peak over mean speed of a minimum-jerk motion.
pub const MIN_JERK_PEAK: Real = 1.875;

/// Shortest double support of a plan, s (ROBOTIS's walking module: 20 % of a 600 ms step).
pub const MIN_DOUBLE_SUPPORT_S: Real = 0.12;

/// Time the ZMP takes from one foot to the middle in a long double support, s.
pub const ZMP_SHIFT_S: Real = 0.3;

/// A swing foot's lift, as a share of the leg's length.
pub const CLEARANCE_SHARE: Real = 0.12;

/// Most corrections of the pelvis that bring the centre of mass over a plan's.
pub const PLAN_COM_ITERATIONS: usize = 8;

/// Where a walking plan puts the feet and the centre of mass at one instant.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlannedStance {
    /// Each sole: where on the floor (its centre and heading, as [`RetargetFrame::sole`] and
    /// [`RetargetFrame::sole_yaw`] measure them) and how high above it, metres.
    pub soles: [(Footprint, Real); 2],
    /// Which feet bear weight.
    pub contact: [bool; 2],
    /// The centre of mass on the floor, metres.
    pub com: RealVec2,
    /// The base's height above the floor, metres: one height for a whole walk, as the
    /// cart-table model's constant height asks (NaN: the human's, lowered to reach).
    pub base_height: Real,
    /// The planned ZMP, metres.
    pub zmp: RealVec2,
}

/// Limbs in reports: left arm, right arm, left leg, right leg, head.
pub const LIMBS: [&str; 5] = ["left_arm", "right_arm", "left_leg", "right_leg", "head"];

/// The human bones a map uses (indices into the skeleton).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct HumanBones {
    /// The pelvis (the root).
    pub pelvis: usize,
    /// Per side: upper arm (shoulder → elbow) and forearm (elbow → wrist).
    pub arms: [Option<[usize; 2]>; 2],
    /// Per side: thigh (hip → knee), shin (knee → ankle), foot (ankle → toe).
    pub legs: [[usize; 3]; 2],
    /// The head (its rotation is where the face points).
    pub head: Option<usize>,
}

/// A robot arm: two shoulder joints and an elbow (indices into the robot's joints).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ArmChain {
    /// Shoulder, shoulder, elbow.
    pub joints: [usize; 3],
    /// The hand point, in the body the elbow turns (metres).
    pub tip: RealVec3,
}

/// A robot leg: hip (three joints), knee, ankle (two joints).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LegChain {
    /// Hip ×3 (from the pelvis), knee, ankle ×2.
    pub joints: [usize; 6],
    /// Centre of the sole's bottom face, in the body of the last ankle joint (metres).
    pub sole_centre: RealVec3,
    /// Half length and half width of the sole (along that body's x and y, metres).
    pub sole_half: [Real; 2],
}

/// A pan/tilt head.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HeadChain {
    /// Pan, then tilt.
    pub joints: [usize; 2],
}

/// Which human bones drive which robot chain.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RetargetMap {
    /// The human side.
    pub human: HumanBones,
    /// The robot's pelvis body (the base; body 0 in MJCF models).
    pub base: usize,
    /// Arms, left then right.
    pub arms: [Option<ArmChain>; 2],
    /// Legs, left then right.
    pub legs: [LegChain; 2],
    /// The head.
    pub head: Option<HeadChain>,
    /// Leg scale override (robot leg length / human leg length).
    pub leg_scale: Option<Real>,
    /// Arm scale overrides.
    pub arm_scale: [Option<Real>; 2],
}

/// Where the human's floor is: heights (along the human's up, file units) of the ankle and of
/// the toe when the foot is on the floor.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Floor {
    /// Ankle height with the foot down (left, right).
    pub ankle: [Real; 2],
    /// Toe height with the foot down (left, right).
    pub toe: [Real; 2],
    /// Elevation of the ankle-to-toe line (radians, negative: the toe lower) with the foot flat
    /// on the floor (left, right): the human foot's arch, which the robot's flat sole does
    /// not have.
    pub foot_pitch: [Real; 2],
}

/// Options of a run.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Options {
    /// Keep the legs in a standing stance; retarget arms and head only.
    pub upper_body: bool,
    /// Keep the centre of mass over the planted feet.
    pub balance: bool,
    /// Retarget a whole clip frame by frame as a stream would (the arms' branches by
    /// hysteresis, no speed limits), not planned over the clip (the std edge).
    pub per_frame: bool,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            upper_body: false,
            balance: true,
            per_frame: false,
        }
    }
}

/// Why a map does not fit a robot or a skeleton.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RetargetError {
    /// A joint index past the robot's joints, or a body index past its bodies.
    NoSuchJoint,
    /// A chain's joints are not one after another down one branch of the tree.
    NotAChain(&'static str),
    /// A chain's geometry does not allow the closed form (hip or ankle axes that do not meet,
    /// an elbow on a shoulder axis, parallel shoulder axes…).
    Geometry(&'static str),
    /// A bone index past the skeleton, or a rest pose without width or height.
    Skeleton(&'static str),
}

impl core::fmt::Display for RetargetError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            RetargetError::NoSuchJoint => f.write_str("a joint or body the robot does not have"),
            RetargetError::NotAChain(what) => write!(f, "{what}: the joints are not one chain from the base"),
            RetargetError::Geometry(what) => write!(f, "{what}"),
            RetargetError::Skeleton(what) => write!(f, "{what}"),
        }
    }
}

impl core::error::Error for RetargetError {}

/// One retargeted frame.
#[derive(Clone, Debug)]
pub struct RetargetFrame {
    /// Joint angles, radians, in the robot's joint order.
    pub q: [Real; MAX_ROBOT_JOINTS],
    /// The base's position in the robot's world (metres, floor at z = 0).
    pub base_pos: RealVec3,
    /// The base's orientation in the robot's world.
    pub base_rot: RealQuat,
    /// Per limb ([`LIMBS`]): the largest angle (degrees) between a human segment and the robot
    /// segment it drives, in the pelvis frame, and the sum of squares over its segments with
    /// their count (for RMS). NaN / 0 when the limb is not mapped.
    pub limb_error_deg: [Real; 5],
    /// Per limb: sum of squared segment errors (degrees²) and the number of segments.
    pub limb_error_sq: [(Real, u32); 5],
    /// Per arm (left, right): how far the robot's hand is from the human's hand placed on the
    /// robot — the human's shoulder-to-hand vector, at the robot's arm scale, from the robot's
    /// shoulder, in the pelvis frame — metres (NaN for an unmapped arm).
    pub hand_error: [Real; 2],
    /// Per arm: that placed human hand, in the robot's world (metres; NaN for an unmapped arm).
    pub hand_target: [RealVec3; 2],
    /// Whether each foot is planted.
    pub planted: [bool; 2],
    /// Each sole's centre in the robot's world (metres).
    pub sole: [RealVec3; 2],
    /// Each sole's heading: its long axis about the vertical, radians.
    pub sole_yaw: [Real; 2],
    /// The robot's centre of mass in its world.
    pub com: RealVec3,
    /// Where on the floor the robot's weight bears (metres, its world): a walking plan's ZMP,
    /// otherwise the centre of mass below (standing still).
    pub zmp: RealVec2,
    /// Signed distance of the centre of mass (on the floor) inside the support polygon of the
    /// planted feet, metres (negative: outside); NaN when no foot is planted.
    pub com_margin: Real,
    /// Joint values held at a limit in this frame.
    pub clamps: u32,
    /// Feet whose target was out of reach (the pelvis was lowered or the leg stretched).
    pub out_of_reach: u32,
    /// The lowest sole corner's height above the floor, metres.
    pub lowest_sole: Real,
    /// The effectors at the retargeted pose: left hand, right hand, left sole, right sole
    /// (NaN for an unmapped arm), metres, the robot's world.
    pub effectors: [RealVec3; 4],
}

impl Default for RetargetFrame {
    fn default() -> Self {
        RetargetFrame {
            q: [0.0; MAX_ROBOT_JOINTS],
            base_pos: RealVec3::ZERO,
            base_rot: RealQuat::IDENTITY,
            limb_error_deg: [Real::NAN; 5],
            limb_error_sq: [(0.0, 0); 5],
            hand_error: [Real::NAN; 2],
            hand_target: [RealVec3::NAN; 2],
            planted: [false; 2],
            sole: [RealVec3::ZERO; 2],
            sole_yaw: [0.0; 2],
            com: RealVec3::ZERO,
            zmp: RealVec2::ZERO,
            com_margin: Real::NAN,
            clamps: 0,
            out_of_reach: 0,
            lowest_sole: 0.0,
            effectors: [RealVec3::NAN; 4],
        }
    }
}

/// Angle about unit axis `a` that turns `v` nearest to `t` (Paden–Kahan subproblem 1).
#[must_use]
pub fn angle_about(a: RealVec3, v: RealVec3, t: RealVec3) -> Real {
    let vp = v - a * a.dot(v);
    let tp = t - a * a.dot(t);
    real::atan2(a.dot(vp.cross(tp)), vp.dot(tp))
}

/// Angles `(q1, q2)` with `rot(a1, q1)·rot(a2, q2)·v` pointing along `t` (Paden–Kahan
/// subproblem 2, axes through one point, `a2` as it lies at `q1 = 0`): the two solutions, or
/// twice the nearest direction when `t` cannot be reached.
#[must_use]
pub fn angles_about_two(a1: RealVec3, a2: RealVec3, v: RealVec3, t: RealVec3) -> [(Real, Real); 2] {
    let t = t.normalize_or_zero() * v.length();
    let along = a2 * a2.dot(v);
    let perp = v - along;
    let side = a2.cross(perp);
    let (c0, cc, cs) = (a1.dot(along), a1.dot(perp), a1.dot(side));
    let r = real::hypot(cc, cs);
    let phi = real::atan2(cs, cc);
    let k = a1.dot(t) - c0;
    let delta = if r > 1e-12 {
        real::acos((k / r).clamp(-1.0, 1.0))
    } else {
        0.0
    };
    let mut out = [(0.0, 0.0); 2];
    for (o, q2) in out.iter_mut().zip([phi + delta, phi - delta]) {
        let q2 = wrap(q2);
        let v2 = crate::math::quat_from_axis_angle(a2, q2) * v;
        *o = (angle_about(a1, v2, t), q2);
    }
    out
}

/// Distance from a point rotated about a line to a fixed point (Paden–Kahan subproblem 3, the
/// law of cosines of the help note's eq. 16 for an axis in general position): the angles
/// about unit `axis` through `at` that put `p` at distance `d` from `c`, the nearest distance
/// twice when `d` cannot be reached.
#[must_use]
pub fn angles_for_distance(axis: RealVec3, at: RealVec3, p: RealVec3, c: RealVec3, d: Real) -> [Real; 2] {
    let (u, v) = (p - at, c - at);
    let (up, vp) = (u - axis * axis.dot(u), v - axis * axis.dot(v));
    let along = axis.dot(p - c);
    let dp2 = (d * d - along * along).max(0.0);
    let theta0 = real::atan2(axis.dot(up.cross(vp)), up.dot(vp));
    let (lu, lv) = (up.length(), vp.length());
    let spread = if lu * lv > 1e-12 {
        real::acos(((lu * lu + lv * lv - dp2) / (2.0 * lu * lv)).clamp(-1.0, 1.0))
    } else {
        0.0
    };
    [wrap(theta0 - spread), wrap(theta0 + spread)]
}

/// An angle in (−π, π].
fn wrap(a: Real) -> Real {
    crate::math::wrap_near(a, 0.0)
}

/// The angle between two vectors, radians (0 when either is zero).
fn angle_between(a: RealVec3, b: RealVec3) -> Real {
    let d = a.length() * b.length();
    if d <= 0.0 {
        return 0.0;
    }
    real::atan2(a.cross(b).length(), a.dot(b))
}

/// The point nearest (least squares) to lines through `points` along unit `axes`.
fn nearest_point(points: &[RealVec3], axes: &[RealVec3]) -> Option<RealVec3> {
    let mut m = RealMat3::ZERO;
    let mut b = RealVec3::ZERO;
    for (p, a) in points.iter().zip(axes) {
        let proj = RealMat3::IDENTITY - outer(*a, *a);
        m += proj;
        b += proj * *p;
    }
    let det = m.determinant();
    (det.abs() > 1e-9).then(|| m.inverse() * b)
}

fn outer(a: RealVec3, b: RealVec3) -> RealMat3 {
    RealMat3::from_cols(a * b.x, a * b.y, a * b.z)
}

fn dist_to_line(p: RealVec3, point: RealVec3, axis: RealVec3) -> Real {
    let d = p - point;
    (d - axis * axis.dot(d)).length()
}

/// A joint's axis and a point on it, in the base's frame at the zero pose.
#[derive(Clone, Copy, Debug, Default)]
struct Screw {
    axis: RealVec3,
    point: RealVec3,
    range: Option<(Real, Real)>,
    index: usize,
}

impl Screw {
    fn rot(&self, q: Real) -> RealQuat {
        crate::math::quat_from_axis_angle(self.axis, q)
    }

    /// Moves a point by this joint turned by `q`.
    fn apply(&self, q: Real, p: RealVec3) -> RealVec3 {
        self.point + self.rot(q) * (p - self.point)
    }

    /// `q` at its limits, and whether it was clamped. An angle outside the range is first
    /// tried a turn away.
    fn limit(&self, q: Real, reference: Real) -> (Real, bool) {
        let q = crate::math::wrap_near(q, reference);
        match self.range {
            None => (q, false),
            Some((lo, hi)) => {
                for k in [0.0, -crate::math::consts::TAU, crate::math::consts::TAU] {
                    if (lo..=hi).contains(&(q + k)) {
                        return (q + k, false);
                    }
                }
                let mid = 0.5 * (lo + hi);
                let q = crate::math::wrap_near(q, mid);
                (q.clamp(lo, hi), true)
            }
        }
    }
}

#[derive(Clone, Copy, Debug, Default)]
struct ArmGeometry {
    joints: [Screw; 3],
    upper: RealVec3,
    fore: RealVec3,
    length: Real,
    /// The hand at the zero pose.
    tip: RealVec3,
    /// The shoulder: the point of the first axis nearest the second (fixed in the base).
    centre: RealVec3,
}

impl ArmGeometry {
    /// The hand at angles `q`.
    fn hand(&self, q: [Real; 3]) -> RealVec3 {
        let [s1, s2, s3] = self.joints;
        s1.apply(q[0], s2.apply(q[1], s3.apply(q[2], self.tip)))
    }

    /// The upper arm's direction at angles `q`.
    fn upper_at(&self, q: [Real; 3]) -> RealVec3 {
        let [s1, s2, _] = self.joints;
        s1.rot(q[0]) * (s2.rot(q[1]) * self.upper)
    }

    fn clamp(&self, q: [Real; 3]) -> [Real; 3] {
        let c = |s: &Screw, v: Real| match s.range {
            Some((lo, hi)) => v.clamp(lo, hi),
            None => v,
        };
        let [s1, s2, s3] = &self.joints;
        [c(s1, q[0]), c(s2, q[1]), c(s3, q[2])]
    }

    /// The closed form's four starts for a hand at `target`: the elbow angles that put the
    /// hand at the target's distance from the shoulder (subproblem 3), and for each the two
    /// shoulder turns that point it at the target (subproblem 2). Exact when the shoulder axes
    /// meet; [`ArmGeometry::reach`] finishes them when they do not.
    fn closed_form(&self, target: RealVec3) -> [[Real; 3]; 4] {
        let [s1, s2, s3] = self.joints;
        let to_target = target - self.centre;
        let mut out = [[0.0; 3]; 4];
        let elbows = angles_for_distance(s3.axis, s3.point, self.tip, self.centre, to_target.length());
        for (i, q3) in elbows.into_iter().enumerate() {
            let w = s3.apply(q3, self.tip) - self.centre;
            for (k, (q1, q2)) in angles_about_two(s1.axis, s2.axis, w, to_target)
                .into_iter()
                .enumerate()
            {
                out[2 * i + k] = [q1, q2, q3];
            }
        }
        out
    }

    /// Levenberg–Marquardt on the hand's position from `start`, each step clamped into the
    /// limits: the angles and the hand's distance from `target` (metres).
    fn reach(&self, start: [Real; 3], target: RealVec3) -> ([Real; 3], Real) {
        let [s1, s2, s3] = self.joints;
        let mut q = self.clamp(start);
        let mut hand = self.hand(q);
        let mut cost = (hand - target).length_squared();
        let mut lambda = 1e-3;
        for _ in 0..40 {
            if cost < 1e-14 {
                break;
            }
            // A turn about axis a through p moves the hand by a × (hand − p).
            let r1 = s1.rot(q[0]);
            let a2 = r1 * s2.axis;
            let p2 = s1.apply(q[0], s2.point);
            let a3 = r1 * (s2.rot(q[1]) * s3.axis);
            let p3 = s1.apply(q[0], s2.apply(q[1], s3.point));
            let j = RealMat3::from_cols(
                s1.axis.cross(hand - s1.point),
                a2.cross(hand - p2),
                a3.cross(hand - p3),
            );
            let jt = j.transpose();
            let mut jtj = jt * j;
            let mut jtr = jt * (hand - target);
            // A joint at a limit that the step would push past is held there: the others
            // converge on the limit's face instead of crawling along it.
            for (i, s) in [s1, s2, s3].iter().enumerate() {
                if let Some((lo, hi)) = s.range {
                    if (q[i] <= lo && jtr[i] > 0.0) || (q[i] >= hi && jtr[i] < 0.0) {
                        jtr[i] = 0.0;
                        for k in 0..3 {
                            jtj.col_mut(i)[k] = 0.0;
                            jtj.col_mut(k)[i] = 0.0;
                        }
                        jtj.col_mut(i)[i] = 1.0;
                    }
                }
            }
            let mut improved = false;
            for _ in 0..8 {
                let diag =
                    RealVec3::new(jtj.x_axis.x, jtj.y_axis.y, jtj.z_axis.z) * lambda + RealVec3::splat(1e-12);
                let damped = jtj + RealMat3::from_diagonal(diag);
                if damped.determinant().abs() < 1e-24 {
                    break;
                }
                let dq = -(damped.inverse() * jtr);
                let trial = self.clamp([q[0] + dq.x, q[1] + dq.y, q[2] + dq.z]);
                let h = self.hand(trial);
                let c = (h - target).length_squared();
                if c < cost {
                    improved = cost - c > 1e-16 + 1e-6 * cost;
                    (q, hand, cost) = (trial, h, c);
                    lambda = (lambda * 0.3).max(1e-9);
                    break;
                }
                lambda *= 10.0;
            }
            if !improved {
                break;
            }
        }
        (q, real::sqrt(cost))
    }
}

#[derive(Clone, Copy, Debug, Default)]
struct LegGeometry {
    joints: [Screw; 6],
    hip: RealVec3,
    knee: RealVec3,
    ankle: RealVec3,
    /// The foot body's zero-pose orientation and the sole's corners relative to the ankle
    /// centre, in that body's frame.
    foot_rot: RealQuat,
    corners: [RealVec3; 4],
    sole_from_ankle: RealVec3,
    /// Sign of knee angles that bend the knee the human way (the shin backwards).
    knee_sign: Real,
    reach: Real,
    thigh_len: Real,
    shin_len: Real,
    /// Whether the hip axes meet in a point and the ankle axes in another (the closed form);
    /// otherwise the leg is solved by damped least squares from its previous angles.
    closed_form: bool,
}

#[derive(Clone, Copy, Debug, Default)]
struct HeadGeometry {
    joints: [Screw; 2],
    forward: RealVec3,
}

#[derive(Clone, Copy, Debug, Default)]
struct FootState {
    planted: bool,
    /// Where the foot was locked: ankle position and heading (world).
    lock: Option<(RealVec3, Real)>,
    /// After release: the locked offset and the time since release.
    release: Option<(RealVec3, Real, Real)>,
    previous: Option<RealVec3>,
}

/// The retargeter: constants derived from the map, the robot and the skeleton once, and the
/// little state a stream needs (planted feet, the arms' branches, the balance shift).
#[derive(Clone, Debug)]
pub struct Retargeter {
    map: RetargetMap,
    /// Human world → robot world, rotation.
    world: RealMat3,
    /// The human pelvis frame at rest (columns forward, left, up) in human world coordinates.
    human_frame: RealMat3,
    /// The robot pelvis frame (columns forward, left, up) in base coordinates.
    robot_frame: RealMat3,
    /// The base's orientation at the zero pose (model frame).
    base_rest: RealQuat,
    base_rest_pos: RealVec3,
    /// The human's frames at rest (pelvis, head): `F·F₀ᵀ` is the rotation a bone made from
    /// rest, its `W·W₀ᵀ` with `C` cancelled.
    human_rest_frame: [RealMat3; 5],
    units: Real,
    leg_scale: Real,
    arm_scale: [Real; 2],
    arms: [Option<ArmGeometry>; 2],
    legs: [LegGeometry; 2],
    head: Option<HeadGeometry>,
    floor: Floor,
    hip_mid: RealVec3,
    stance: [Real; MAX_ROBOT_JOINTS],
    stance_base: RealVec3,
    options: Options,
    feet: [FootState; 2],
    arm_prev: [Option<[Real; 3]>; 2],
    /// Per arm joint, its servo's speed limit (rad/s; infinite: none).
    arm_speed: [[Real; 3]; 2],
    /// Per arm: what staying on its branch has cost over the best other since it last was the
    /// best (see [`Retargeter::solve_arm`]).
    arm_regret: [Real; 2],
    /// The legs' last angles: where a leg without the closed form starts its iterations.
    leg_prev: [[Real; 6]; 2],
    shift: RealVec2,
    pose: RobotPose,
    /// Every body at the zero pose (model frame).
    rest: RobotPose,
}

/// Rest-pose indices into `human_rest_frame`.
const REST_PELVIS: usize = 0;
const REST_HEAD: usize = 1;

impl Retargeter {
    /// Prepares a map for `robot` and `skeleton`, with the human floor `floor` (see
    /// [`floor_of_rest`] and the std edge's clip calibration).
    ///
    /// # Errors
    /// [`RetargetError`] when the map's indices or geometry do not fit.
    pub fn new(
        robot: &Robot,
        skeleton: &Skeleton,
        map: RetargetMap,
        floor: Floor,
        options: Options,
    ) -> Result<Retargeter, RetargetError> {
        let nb = skeleton.bones().len();
        let h = &map.human;
        let bones_ok = h.pelvis < nb
            && h.legs.iter().flatten().all(|b| *b < nb)
            && h.arms.iter().flatten().flatten().all(|b| *b < nb)
            && h.head.is_none_or(|b| b < nb);
        if !bones_ok {
            return Err(RetargetError::Skeleton("a bone the skeleton does not have"));
        }
        let nj = robot.joints().len();
        let joints_ok = map.base < robot.bodies().len()
            && map.legs.iter().flat_map(|l| l.joints).all(|j| j < nj)
            && map.arms.iter().flatten().flat_map(|a| a.joints).all(|j| j < nj)
            && map.head.iter().flat_map(|hd| hd.joints).all(|j| j < nj);
        if !joints_ok {
            return Err(RetargetError::NoSuchJoint);
        }
        // Human rest pose.
        let mut rest = Pose64::default();
        fk64(skeleton, &[], &mut rest);
        let units = Real::from(skeleton.units().meters_per_unit());
        let hips = [rest.start[h.legs[0][0]], rest.start[h.legs[1][0]]];
        let hip_mid_h = 0.5 * (hips[0] + hips[1]);
        let top = match (h.head, h.arms[0], h.arms[1]) {
            (Some(b), _, _) => rest.start[b],
            (None, Some(l), Some(r)) => 0.5 * (rest.start[l[0]] + rest.start[r[0]]),
            _ => {
                return Err(RetargetError::Skeleton(
                    "neither a head nor two arms to tell up from",
                ))
            }
        };
        let human_frame = frame_from(hips[0] - hips[1], top - hip_mid_h).ok_or(RetargetError::Skeleton(
            "the rest pose has no width between the hips or no height",
        ))?;

        // Robot zero pose, in the model frame; then in the base's frame.
        let mut pose = RobotPose::default();
        robot.forward(RealVec3::ZERO, RealQuat::IDENTITY, &[], &mut pose);
        let base_rest = pose.rot[map.base];
        let base_rest_pos = pose.pos[map.base];
        let to_base = |p: RealVec3| base_rest.inverse() * (p - base_rest_pos);
        let screw = |j: usize| -> Screw {
            let joint = &robot.joints()[j];
            let body = joint.body;
            Screw {
                axis: (base_rest.inverse() * (pose.rot[body] * joint.axis)).normalize(),
                point: to_base(pose.pos[body] + pose.rot[body] * joint.anchor),
                range: joint.range,
                index: j,
            }
        };
        for (what, chain) in [
            ("left leg", &map.legs[0].joints[..]),
            ("right leg", &map.legs[1].joints[..]),
        ] {
            check_chain(robot, map.base, chain, what)?;
        }
        let mut legs = [LegGeometry::default(); 2];
        for (side, leg) in map.legs.iter().enumerate() {
            let s: [Screw; 6] = core::array::from_fn(|k| screw(leg.joints[k]));
            // The closed form needs hip axes that meet in a point and ankle axes that meet in
            // another (within 2 mm; the corrections absorb the rest); other legs are solved
            // numerically.
            let hip_point = nearest_point(
                &[s[0].point, s[1].point, s[2].point],
                &[s[0].axis, s[1].axis, s[2].axis],
            );
            let ankle_point = nearest_point(&[s[4].point, s[5].point], &[s[4].axis, s[5].axis]);
            let hip = hip_point.unwrap_or(s[2].point);
            let ankle = ankle_point.unwrap_or(s[4].point);
            let closed_form = hip_point.is_some()
                && ankle_point.is_some()
                && s[..3].iter().all(|j| dist_to_line(hip, j.point, j.axis) <= 2e-3)
                && s[4..]
                    .iter()
                    .all(|j| dist_to_line(ankle, j.point, j.axis) <= 2e-3);
            let knee_axis = s[3].axis;
            let along = |p: RealVec3| knee_axis.dot(p - s[3].point);
            let knee = s[3].point + knee_axis * along(hip);
            let thigh_len = dist_to_line(hip, s[3].point, knee_axis);
            let shin_len = dist_to_line(ankle, s[3].point, knee_axis);
            if thigh_len < 1e-3 || shin_len < 1e-3 {
                return Err(RetargetError::Geometry(
                    "the knee axis passes through the hip or the ankle",
                ));
            }
            let foot_body = robot.joints()[leg.joints[5]].body;
            let foot_rot = base_rest.inverse() * pose.rot[foot_body];
            let foot_pos = to_base(pose.pos[foot_body]);
            let ankle_local = foot_rot.inverse() * (ankle - foot_pos);
            let [hx, hy] = leg.sole_half;
            let corners = [(1.0, 1.0), (1.0, -1.0), (-1.0, -1.0), (-1.0, 1.0)]
                .map(|(a, b)| leg.sole_centre + RealVec3::new(a * hx, b * hy, 0.0) - ankle_local);
            legs[side] = LegGeometry {
                joints: s,
                hip,
                knee,
                ankle,
                foot_rot,
                corners,
                sole_from_ankle: leg.sole_centre - ankle_local,
                knee_sign: 1.0,
                reach: 0.0,
                thigh_len,
                shin_len,
                closed_form,
            };
        }
        let hip_mid = 0.5 * (legs[0].hip + legs[1].hip);
        let head_point = map.head.map(|hd| screw(hd.joints[0]).point);
        let arm_top = match (map.arms[0], map.arms[1]) {
            (Some(l), Some(r)) => Some(0.5 * (screw(l.joints[0]).point + screw(r.joints[0]).point)),
            _ => None,
        };
        let up_point = head_point.or(arm_top).ok_or(RetargetError::Geometry(
            "neither a head nor two arms to tell up from",
        ))?;
        let robot_frame = frame_from(legs[0].hip - legs[1].hip, up_point - hip_mid)
            .ok_or(RetargetError::Geometry("the robot's hips have no width"))?;
        let forward = robot_frame.col(0);
        for leg in &mut legs {
            // The knee bends the human way when a positive angle moves the ankle backwards.
            let k = leg.joints[3];
            let moved = k.axis.cross(leg.ankle - k.point);
            leg.knee_sign = if moved.dot(forward) < 0.0 { 1.0 } else { -1.0 };
            leg.reach = (leg.ankle - leg.hip).length();
        }
        let mut arms = [None; 2];
        for (side, arm) in map.arms.iter().enumerate() {
            let Some(arm) = arm else { continue };
            check_chain(robot, map.base, &arm.joints, "arm")?;
            let s: [Screw; 3] = core::array::from_fn(|k| screw(arm.joints[k]));
            let elbow_body = robot.joints()[arm.joints[2]].body;
            let tip = to_base(pose.pos[elbow_body] + pose.rot[elbow_body] * arm.tip);
            let upper = s[2].point - s[1].point;
            // The forearm's direction in the plane the elbow turns it in (an offset of the
            // hand along the elbow's axis moves the hand sideways; it is not a direction).
            let fore = tip - s[2].point;
            let fore = fore - s[2].axis * s[2].axis.dot(fore);
            if upper.length() < 1e-4 || fore.length() < 1e-4 {
                return Err(RetargetError::Geometry("an arm segment of zero length"));
            }
            if s[0].axis.cross(s[1].axis).length() < 1e-6 {
                return Err(RetargetError::Geometry("the two shoulder axes are parallel"));
            }
            // The shoulder: the first axis's point nearest the second.
            let (a1, a2) = (s[0].axis, s[1].axis);
            let w0 = s[0].point - s[1].point;
            let b = a1.dot(a2);
            let t = (b * a2.dot(w0) - a1.dot(w0)) / (1.0 - b * b);
            let centre = s[0].point + a1 * t;
            // The reach: the hand's greatest distance from the shoulder as the elbow turns.
            let (u, v) = (tip - s[2].point, centre - s[2].point);
            let a3 = s[2].axis;
            let (up, vp) = (u - a3 * a3.dot(u), v - a3 * a3.dot(v));
            let along = a3.dot(tip - centre);
            let span = up.length() + vp.length();
            let reach = real::sqrt(along * along + span * span);
            arms[side] = Some(ArmGeometry {
                joints: s,
                upper: upper.normalize(),
                fore: fore.normalize(),
                length: reach,
                tip,
                centre,
            });
        }
        let head = match map.head {
            Some(hd) => {
                check_chain(robot, map.base, &hd.joints, "head")?;
                let s = [screw(hd.joints[0]), screw(hd.joints[1])];
                if s[0].axis.cross(s[1].axis).length() < 1e-6 {
                    return Err(RetargetError::Geometry("the pan and tilt axes are parallel"));
                }
                Some(HeadGeometry { joints: s, forward })
            }
            None => None,
        };
        // Human ↔ robot.
        let human_leg = |side: usize| {
            let [t, s, _] = h.legs[side];
            (rest.tip[t] - rest.start[t]).length() + (rest.tip[s] - rest.start[s]).length()
        };
        let leg_h = 0.5 * (human_leg(0) + human_leg(1)) * units;
        let leg_r = 0.5 * (legs[0].thigh_len + legs[0].shin_len + legs[1].thigh_len + legs[1].shin_len);
        let leg_scale = map.leg_scale.unwrap_or(leg_r / leg_h.max(1e-9));
        let mut arm_scale = [1.0; 2];
        for side in 0..2 {
            if let (Some(a), Some(ha)) = (&arms[side], h.arms[side]) {
                let lh = ((rest.tip[ha[0]] - rest.start[ha[0]]).length()
                    + (rest.tip[ha[1]] - rest.start[ha[1]]).length())
                    * units;
                arm_scale[side] = map.arm_scale[side].unwrap_or(a.length / lh.max(1e-9));
            }
        }
        let robot_world_frame = RealMat3::from_quat(base_rest) * robot_frame;
        let world = robot_world_frame * human_frame.transpose();
        let mut human_rest_frame = [RealMat3::IDENTITY; 5];
        human_rest_frame[REST_PELVIS] = rest.frame[h.pelvis];
        if let Some(b) = h.head {
            human_rest_frame[REST_HEAD] = rest.frame[b];
        }

        let mut r = Retargeter {
            map,
            world,
            human_frame,
            robot_frame,
            base_rest,
            base_rest_pos,
            human_rest_frame,
            units,
            leg_scale,
            arm_scale,
            arms,
            legs,
            head,
            floor,
            hip_mid,
            stance: [0.0; MAX_ROBOT_JOINTS],
            stance_base: RealVec3::ZERO,
            options,
            feet: [FootState::default(); 2],
            arm_prev: [None; 2],
            arm_speed: [[Real::INFINITY; 3]; 2],
            arm_regret: [0.0; 2],
            leg_prev: [[0.0; 6]; 2],
            shift: RealVec2::ZERO,
            rest: pose.clone(),
            pose,
        };
        r.leg_prev = r.neutral_legs();
        r.make_stance();
        Ok(r)
    }

    /// Legs straight but for a slightly bent knee: where numerical legs start.
    fn neutral_legs(&self) -> [[Real; 6]; 2] {
        let mut q = [[0.0; 6]; 2];
        for (side, g) in self.legs.iter().enumerate() {
            q[side][3] = 0.3 * g.knee_sign;
        }
        q
    }

    /// Leg length ratio robot / human.
    #[must_use]
    pub fn leg_scale(&self) -> Real {
        self.leg_scale
    }

    /// Arm length ratios robot / human (left, right; 1 where unmapped).
    #[must_use]
    pub fn arm_scale(&self) -> [Real; 2] {
        self.arm_scale
    }

    /// The options in use.
    #[must_use]
    pub fn options(&self) -> Options {
        self.options
    }

    /// The leg's joint angles (clamped to the limits) that put foot `side`'s body at
    /// orientation `rot` and its ankle centre at `ankle`, both in the base's frame: the closed
    /// form of [`Retargeter::step`], for tests and benchmarks.
    #[must_use]
    pub fn leg_ik(&self, side: usize, rot: RealQuat, ankle: RealVec3) -> [Real; 6] {
        self.solve_leg(side & 1, rot, ankle, &mut 0)
    }

    /// Where the ankle centre of leg `side` sits: its foot body and the point in that body's
    /// frame (metres).
    #[must_use]
    pub fn ankle_centre(&self, robot: &Robot, side: usize) -> (usize, RealVec3) {
        let body = robot.joints()[self.map.legs[side & 1].joints[5]].body;
        (body, self.body_local(body, self.legs[side & 1].ankle))
    }

    /// The human arm's segment directions (upper arm, forearm; unit) in the robot base's frame,
    /// as [`Retargeter::step`] aims them, for a pose from [`fk64`]; `None` when unmapped.
    #[must_use]
    pub fn human_arm(&self, pose: &Pose64, side: usize) -> Option<(RealVec3, RealVec3)> {
        let bones = self.map.human.arms[side & 1]?;
        let rel = pose.frame[self.map.human.pelvis] * self.human_rest_frame[REST_PELVIS].transpose();
        let to_base = self.robot_frame * (rel * self.human_frame).transpose();
        let dir = |b: usize| (to_base * (pose.tip[b] - pose.start[b])).normalize_or_zero();
        Some((dir(bones[0]), dir(bones[1])))
    }

    /// The direction error of arm `side` at joint angles `q` (shoulder, shoulder, elbow)
    /// against unit segment directions: the RMS of the two segments' angles, degrees (NaN when
    /// the arm is unmapped).
    #[must_use]
    pub fn arm_error_deg(&self, side: usize, q: [Real; 3], upper: RealVec3, fore: RealVec3) -> Real {
        let Some(g) = self.arms[side & 1] else {
            return Real::NAN;
        };
        let [s1, s2, s3] = g.joints;
        let r12 = s1.rot(q[0]) * s2.rot(q[1]);
        let u = angle_between(r12 * g.upper, upper).to_degrees();
        let f = angle_between(r12 * s3.rot(q[2]) * g.fore, fore).to_degrees();
        real::sqrt(0.5 * (u * u + f * f))
    }

    /// The speed limits of arm `side`'s joints (shoulder, shoulder, elbow; rad/s, infinite for
    /// none): a stream changes an arm's branch only when staying has cost more than the jump.
    pub fn set_arm_speed_limits(&mut self, side: usize, limits: [Real; 3]) {
        self.arm_speed[side & 1] = limits;
    }

    /// The arm joints of arm `side` in the robot's joint order (shoulder, shoulder, elbow).
    #[must_use]
    pub fn arm_joints(&self, side: usize) -> Option<[usize; 3]> {
        self.map.arms[side & 1].map(|a| a.joints)
    }

    /// The effectors in `pose` (the robot's forward kinematics): left hand, right hand, left
    /// sole, right sole (NaN for an unmapped arm), metres.
    #[must_use]
    pub fn effector_points(&self, robot: &Robot, pose: &RobotPose) -> [RealVec3; 4] {
        let mut out = [RealVec3::NAN; 4];
        for side in 0..2 {
            if let Some(arm) = self.map.arms[side] {
                let b = robot.joints()[arm.joints[2]].body;
                out[side] = pose.pos[b] + pose.rot[b] * arm.tip;
            }
            let leg = &self.map.legs[side];
            let b = robot.joints()[leg.joints[5]].body;
            out[2 + side] = pose.pos[b] + pose.rot[b] * leg.sole_centre;
        }
        out
    }

    /// What the robot's feet can do ([`StepLimits`]), from the legs' geometry and `speed`,
    /// the slowest leg servo's velocity limit (rad/s): a step reaches at most
    /// [`STEP_REACH_SHARE`] of twice the horizontal reach of a leg at the stance's height
    /// forward and once backward; the soles keep [`SOLE_GAP_M`] apart and at most a leg's
    /// horizontal reach wider than the hips; a turn of at most [`STEP_TURN`]; the foot moves at
    /// `speed` × leg length over 1.875 on average (a minimum-jerk swing's peak-to-mean ratio),
    /// and lifting it [`Retargeter::swing_clearance`] and putting it down takes that distance at
    /// that speed.
    #[must_use]
    pub fn step_limits(&self, speed: Real) -> StepLimits {
        let reach = self.legs[0].reach.min(self.legs[1].reach);
        let drop = STANCE_DROP * reach;
        let height = reach - drop;
        let longest = REACH_SHARE * reach;
        let horizontal = real::sqrt((longest * longest - height * height).max(0.0));
        let hips = (self.legs[0].hip - self.legs[1].hip).length();
        let sole_width = 2.0 * self.map.legs[0].sole_half[1].max(self.map.legs[1].sole_half[1]);
        let foot_speed = speed.max(1e-3) * reach / MIN_JERK_PEAK;
        StepLimits {
            forward: STEP_REACH_SHARE * 2.0 * horizontal,
            backward: STEP_REACH_SHARE * horizontal,
            width_min: sole_width + SOLE_GAP_M,
            width_max: hips + horizontal,
            turn: STEP_TURN,
            swing_min_s: 2.0 * self.swing_clearance() / foot_speed,
            foot_speed,
            double_support_s: MIN_DOUBLE_SUPPORT_S,
            zmp_shift_s: ZMP_SHIFT_S,
        }
    }

    /// The standing stance's joint angles (`--upper-body`'s legs: knees bent so the hips sit
    /// [`STANCE_DROP`] of a leg lower than straight, soles flat; every other joint 0).
    #[must_use]
    pub fn stance(&self) -> [Real; MAX_ROBOT_JOINTS] {
        self.stance
    }

    /// The soles of the standing stance ([`Options::upper_body`]'s), the base at the world's
    /// origin facing as at rest: where a walking plan starts the robot's feet.
    #[must_use]
    pub fn stance_soles(&self, robot: &Robot) -> [Footprint; 2] {
        let (mp, mr) = self.model_placement(RealVec3::new(0.0, 0.0, self.stance_base.z), self.base_rest);
        let mut pose = RobotPose::default();
        robot.forward(mp, mr, &self.stance, &mut pose);
        core::array::from_fn(|side| {
            let g = &self.legs[side];
            let fb = robot.joints()[self.map.legs[side].joints[5]].body;
            let local = self.rest.rot[fb].inverse()
                * (self.base_rest_pos + self.base_rest * (g.ankle + g.foot_rot * g.sole_from_ankle)
                    - self.rest.pos[fb]);
            let sole = pose.pos[fb] + pose.rot[fb] * local;
            Footprint {
                centre: RealVec2::new(sole.x, sole.y),
                yaw: heading(pose.rot[fb]),
            }
        })
    }

    /// The standing stance's base height above the floor and its centre of mass's, metres.
    #[must_use]
    pub fn stance_heights(&self, robot: &Robot) -> (Real, Real) {
        let (mp, mr) = self.model_placement(RealVec3::new(0.0, 0.0, self.stance_base.z), self.base_rest);
        let mut pose = RobotPose::default();
        robot.forward(mp, mr, &self.stance, &mut pose);
        (self.stance_base.z, robot.centre_of_mass(&pose).z)
    }

    /// The highest base above the floor from which both legs reach `plan`'s soles (flat) with
    /// at most `share` of their length, the base upright over the planned centre of mass and
    /// turned half way between the soles' headings, off the centre of mass as in the stance,
    /// metres.
    #[must_use]
    pub fn reach_height(&self, robot: &Robot, plan: &PlannedStance, share: Real) -> Real {
        let [(a, _), (b, _)] = plan.soles;
        let yaw = 0.5 * (a.yaw + crate::math::wrap_near(b.yaw, a.yaw));
        let rest_yaw = heading(self.base_rest * self.legs[0].foot_rot);
        let turn = RealQuat::from_rotation_z(yaw - rest_yaw);
        let base_rot = turn * self.base_rest;
        // The base sits off the centre of mass as it does in the stance.
        let (mp, mr) = self.model_placement(RealVec3::ZERO, self.base_rest);
        let mut pose = RobotPose::default();
        robot.forward(mp, mr, &self.stance, &mut pose);
        let off = turn * -robot.centre_of_mass(&pose);
        let base = RealVec2::new(plan.com.x + off.x, plan.com.y + off.y);
        let mut height = Real::INFINITY;
        for (side, g) in self.legs.iter().enumerate() {
            let (print, lift) = plan.soles[side];
            let rest_foot = self.base_rest * g.foot_rot;
            let rot = RealQuat::from_rotation_z(print.yaw - heading(rest_foot)) * rest_foot;
            let ankle =
                RealVec3::new(print.centre.x, print.centre.y, lift.max(0.0)) - rot * g.sole_from_ankle;
            let hip = base_rot * g.hip;
            let horizontal = RealVec2::new(base.x + hip.x - ankle.x, base.y + hip.y - ankle.y).length();
            let longest = share * g.reach;
            let up = real::sqrt((longest * longest - horizontal * horizontal).max(0.0));
            height = height.min(ankle.z + up - hip.z);
        }
        height
    }

    /// How high a swing foot lifts on a plan: [`CLEARANCE_SHARE`] of the leg, metres.
    #[must_use]
    pub fn swing_clearance(&self) -> Real {
        CLEARANCE_SHARE * self.legs[0].reach.min(self.legs[1].reach)
    }

    /// Forgets the stream's state (planted feet, branches, balance shift): the next frame is
    /// treated as a first one.
    pub fn reset(&mut self) {
        self.feet = [FootState::default(); 2];
        self.arm_prev = [None; 2];
        self.arm_regret = [0.0; 2];
        self.leg_prev = self.neutral_legs();
        self.shift = RealVec2::ZERO;
    }

    /// The standing stance `--upper-body` keeps: knees bent so the hips sit 8 % of the leg
    /// lower than straight, feet under the hips, soles flat.
    fn make_stance(&mut self) {
        let mut clamps = 0;
        let mut q = [0.0; MAX_ROBOT_JOINTS];
        let drop = STANCE_DROP * self.legs[0].reach;
        for side in 0..2 {
            let g = self.legs[side];
            let ankle = g.ankle + self.robot_frame.col(2) * drop;
            let sol = self.solve_leg(side, g.foot_rot, ankle, &mut clamps);
            for (k, s) in g.joints.iter().enumerate() {
                q[s.index] = sol[k];
            }
        }
        // The base high enough that the soles touch z = 0.
        let up = self.robot_frame.col(2) * drop;
        let lowest = self
            .legs
            .iter()
            .flat_map(|g| {
                g.corners
                    .map(|c| (self.base_rest * (g.ankle + up + g.foot_rot * c)).z)
            })
            .fold(Real::INFINITY, Real::min);
        self.stance = q;
        self.stance_base = RealVec3::new(0.0, 0.0, -lowest);
    }

    /// The model-frame placement (for [`Robot::forward`]) that puts the base at `pos`, `rot`.
    #[must_use]
    pub fn model_placement(&self, pos: RealVec3, rot: RealQuat) -> (RealVec3, RealQuat) {
        let model_rot = rot * self.base_rest.inverse();
        (pos - model_rot * self.base_rest_pos, model_rot)
    }

    /// Retargets one human pose (`pose` from [`fk64`] of the frame) taken `dt` seconds after the
    /// previous one, into `out`.
    pub fn step(&mut self, robot: &Robot, pose: &Pose64, dt: Real, out: &mut RetargetFrame) {
        self.step_with(robot, pose, dt, None, out);
    }

    /// Retargets one human pose with the legs and the pelvis on a walking plan: each sole where
    /// `plan` puts it (flat), the robot's centre of mass over the plan's; arms and head as
    /// [`Retargeter::step`] does.
    pub fn step_on_plan(
        &mut self,
        robot: &Robot,
        pose: &Pose64,
        dt: Real,
        plan: &PlannedStance,
        out: &mut RetargetFrame,
    ) {
        self.step_with(robot, pose, dt, Some(plan), out);
    }

    fn step_with(
        &mut self,
        robot: &Robot,
        pose: &Pose64,
        dt: Real,
        plan: Option<&PlannedStance>,
        out: &mut RetargetFrame,
    ) {
        let h = self.map.human;
        out.clamps = 0;
        out.out_of_reach = 0;
        let rel = pose.frame[h.pelvis] * self.human_rest_frame[REST_PELVIS].transpose();
        let pelvis = rel * self.human_frame;
        // Human world vector → base coordinates (pelvis frame to pelvis frame).
        let to_base = self.robot_frame * pelvis.transpose();
        let mut q = if self.options.upper_body {
            self.stance
        } else {
            [0.0; MAX_ROBOT_JOINTS]
        };

        // Arms.
        for side in 0..2 {
            let Some(g) = self.arms[side] else {
                continue;
            };
            let sol = self.solve_arm(side, &g, pose, to_base, dt, &mut out.clamps);
            for (k, s) in g.joints.iter().enumerate() {
                q[s.index] = sol[k];
            }
        }
        // Head.
        if let (Some(g), Some(b)) = (self.head, h.head) {
            let rel_head = pose.frame[b] * self.human_rest_frame[REST_HEAD].transpose();
            let face = to_base * (rel_head * self.human_frame.col(0));
            let c = angles_about_two(g.joints[0].axis, g.joints[1].axis, g.forward, face);
            let pick = |(a, b): (Real, Real)| a.abs() + b.abs();
            let (pan, tilt) = if pick(c[0]) <= pick(c[1]) { c[0] } else { c[1] };
            let (pan, c1) = g.joints[0].limit(pan, 0.0);
            let (tilt, c2) = g.joints[1].limit(tilt, 0.0);
            out.clamps += u32::from(c1) + u32::from(c2);
            q[g.joints[0].index] = pan;
            q[g.joints[1].index] = tilt;
        }

        // Pelvis and legs.
        let (base_pos, base_rot) = if self.options.upper_body {
            out.planted = [true; 2];
            (self.stance_base, self.base_rest)
        } else if let Some(plan) = plan {
            self.planned_body(robot, pose, pelvis, plan, &mut q, out)
        } else {
            self.whole_body(robot, pose, pelvis, dt, &mut q, out)
        };
        out.q = q;
        out.base_pos = base_pos;
        out.base_rot = base_rot;
        for (side, g) in self.legs.iter().enumerate() {
            self.leg_prev[side] = g.joints.map(|j| out.q[j.index]);
        }
        self.measure(robot, pose, to_base, out);
        if let (Some(plan), false) = (plan, self.options.upper_body) {
            out.zmp = plan.zmp;
        }
    }

    /// Measures `out` again after its joints were changed (direction and hand errors, soles,
    /// centre of mass and its margin, effectors; the ZMP is the centre of mass's), for the
    /// human `pose` it was retargeted from.
    pub fn remeasure(&mut self, robot: &Robot, pose: &Pose64, out: &mut RetargetFrame) {
        let to_base = self.to_base(pose);
        self.measure(robot, pose, to_base, out);
    }

    /// The torque the static load of `frame`'s pose puts on each joint (N·m, joint order,
    /// into `torque`; [`Robot::static_torques`]): the links' weights, and the robot's weight
    /// borne by its planted feet at [`RetargetFrame::zmp`] — one foot down: all of it there;
    /// both: shared by where the ZMP lies between the soles, each foot's share at its sole
    /// moved as the ZMP is off the line between them; none (on a stand): the links' weights
    /// only. A servo of stiffness k sags by −τ/k under it.
    pub fn load_torques(&mut self, robot: &Robot, frame: &RetargetFrame, g: Real, torque: &mut [Real]) {
        let (pos, rot) = self.model_placement(frame.base_pos, frame.base_rot);
        robot.forward(pos, rot, &frame.q, &mut self.pose);
        let weight = robot.mass() * g;
        let zmp = RealVec3::new(frame.zmp.x, frame.zmp.y, 0.0);
        let foot = |side: usize| robot.joints()[self.map.legs[side].joints[5]].body;
        let sole = |side: usize| RealVec3::new(frame.sole[side].x, frame.sole[side].y, 0.0);
        let up = |share: Real| RealVec3::new(0.0, 0.0, share * weight);
        let mut forces = [(0, RealVec3::ZERO, RealVec3::ZERO); 2];
        let count = match frame.planted {
            [true, true] => {
                let (a, b) = (sole(0), sole(1));
                let ab = b - a;
                let share = ((zmp - a).dot(ab) / ab.length_squared().max(1e-12)).clamp(0.0, 1.0);
                let off = zmp - (a + ab * share);
                forces = [(foot(0), a + off, up(1.0 - share)), (foot(1), b + off, up(share))];
                2
            }
            [true, false] => {
                forces[0] = (foot(0), zmp, up(1.0));
                1
            }
            [false, true] => {
                forces[0] = (foot(1), zmp, up(1.0));
                1
            }
            [false, false] => 0,
        };
        robot.static_torques(&self.pose, g, &forces[..count], torque);
    }

    /// A human point (file units, the capture's world) in the robot's world: turned, scaled by
    /// the leg ratio, the human floor onto z = 0.
    #[must_use]
    pub fn human_point_in_world(&self, p: RealVec3) -> RealVec3 {
        self.to_world(p)
    }

    /// A robot world point (metres) in the human's world (file units): the inverse of
    /// [`Retargeter::human_point_in_world`], to draw the robot beside the human.
    #[must_use]
    pub fn robot_point_in_human(&self, p: RealVec3) -> RealVec3 {
        let up_h = self.human_frame.col(2);
        let floor = 0.5 * (self.floor.ankle[0] + self.floor.ankle[1]);
        let v = self.world.transpose() * (p - RealVec3::new(0.0, 0.0, self.flat_ankle_height(0)));
        v / (self.units * self.leg_scale) + up_h * floor
    }

    /// Half length and half width of each sole (the map's), metres.
    #[must_use]
    pub fn sole_half(&self) -> [[Real; 2]; 2] {
        self.map.legs.map(|l| l.sole_half)
    }

    /// Human world point → robot world point (metres; the human floor onto z = 0 at the ankle).
    fn to_world(&self, p: RealVec3) -> RealVec3 {
        let up_h = self.human_frame.col(2);
        let floor = 0.5 * (self.floor.ankle[0] + self.floor.ankle[1]);
        let v = (p - up_h * floor) * self.units * self.leg_scale;
        self.world * v + RealVec3::new(0.0, 0.0, self.flat_ankle_height(0))
    }

    #[allow(clippy::too_many_lines)]
    fn whole_body(
        &mut self,
        robot: &Robot,
        pose: &Pose64,
        pelvis: RealMat3,
        dt: Real,
        q: &mut [Real; MAX_ROBOT_JOINTS],
        out: &mut RetargetFrame,
    ) -> (RealVec3, RealQuat) {
        let h = self.map.human;
        let up_h = self.human_frame.col(2);
        // Base orientation: the human pelvis's turn, seen in the robot's world.
        let base_world = self.world * pelvis * self.robot_frame.transpose();
        let base_rot = RealQuat::from_mat3(&base_world).normalize();
        let hips_h = 0.5 * (pose.start[h.legs[0][0]] + pose.start[h.legs[1][0]]);
        let mut base_pos = self.to_world(hips_h) - base_rot * self.hip_mid;

        // Feet: targets in the world, stance, locks.
        let mut ankle = [RealVec3::ZERO; 2];
        let mut foot_rot = [RealQuat::IDENTITY; 2];
        for side in 0..2 {
            let [_, shin, foot] = h.legs[side];
            let a_h = pose.tip[shin];
            let toe_h = pose.tip[foot];
            let height = ((a_h.dot(up_h) - self.floor.ankle[side])
                .min(toe_h.dot(up_h) - self.floor.toe[side]))
                * self.units;
            let mut st = self.feet[side];
            let speed = match st.previous {
                Some(p) if dt > 0.0 => {
                    let d = (a_h - p) * self.units;
                    (d - up_h * d.dot(up_h)).length() / dt
                }
                _ => 0.0,
            };
            st.previous = Some(a_h);
            let was = st.planted;
            st.planted = if was {
                !(height > RELEASE_HEIGHT_M || speed > RELEASE_SPEED_M_S)
            } else {
                height < PLANT_HEIGHT_M && speed < PLANT_SPEED_M_S
            };
            // The foot's heading, its pitch from the flat-foot pitch, its roll — from where its
            // joints are, in the robot's world.
            let frame = self.world * foot_frame(pose, h.legs[side]);
            let (fwd, left) = (frame.col(0), frame.col(1));
            let yaw_now = real::atan2(fwd.y, fwd.x);
            let pitch = real::asin(fwd.z.clamp(-1.0, 1.0)) - self.floor.foot_pitch[side];
            let roll = real::asin(left.z.clamp(-1.0, 1.0));
            let g = self.legs[side];
            let rest_foot = self.base_rest * g.foot_rot;
            let swing_rot = RealQuat::from_rotation_z(yaw_now)
                * RealQuat::from_rotation_y(-pitch)
                * RealQuat::from_rotation_x(roll)
                * rest_foot;
            let mapped = self.to_world(a_h);
            let (target, rot) = if st.planted {
                let (p, yaw) = match st.lock {
                    Some(l) if was => l,
                    _ => {
                        let yaw = yaw_now;
                        let mut p = mapped;
                        p.z = self.flat_ankle_height(side);
                        st.lock = Some((p, yaw));
                        st.release = None;
                        (p, yaw)
                    }
                };
                (p, RealQuat::from_rotation_z(yaw) * rest_foot)
            } else {
                if was {
                    if let Some((p, _)) = st.lock.take() {
                        st.release = Some((p - mapped, 0.0, 0.0));
                    }
                }
                let mut p = mapped;
                if let Some((offset, t, _)) = &mut st.release {
                    *t += dt;
                    let w = 1.0 - smoothstep(*t / RELEASE_S);
                    p += *offset * w;
                    if *t >= RELEASE_S {
                        st.release = None;
                    }
                }
                (p, swing_rot)
            };
            // Never below the floor.
            let lowest = g
                .corners
                .iter()
                .map(|c| (rot * *c).z)
                .fold(Real::INFINITY, Real::min);
            let mut target = target;
            if target.z + lowest < 0.0 {
                target.z = -lowest;
            }
            ankle[side] = target;
            foot_rot[side] = rot;
            out.planted[side] = st.planted;
            self.feet[side] = st;
        }

        // Reach: lower the pelvis until both ankles are within reach.
        out.out_of_reach += self.lower_to_reach(&mut base_pos, base_rot, &ankle);

        // Balance: move the pelvis over the support polygon.
        let planted = [self.feet[0].planted, self.feet[1].planted];
        let mut shift = RealVec2::ZERO;
        if self.options.balance && (planted[0] || planted[1]) {
            for _ in 0..4 {
                let p = base_pos + RealVec3::new(shift.x, shift.y, 0.0);
                self.solve_legs(base_rot, p, &ankle, &foot_rot, q, &mut 0);
                let (mp, mr) = self.model_placement(p, base_rot);
                robot.forward(mp, mr, q, &mut self.pose);
                let com = robot.centre_of_mass(&self.pose);
                let (margin, inside) = self.support(&ankle, &foot_rot, planted, RealVec2::new(com.x, com.y));
                if margin >= BALANCE_MARGIN_M {
                    break;
                }
                shift += inside - RealVec2::new(com.x, com.y);
            }
        }
        // The shift changes at a bounded speed.
        let step = BALANCE_SPEED_M_S * dt.max(0.0);
        let first = self.feet.iter().all(|f| f.previous.is_none());
        let d = shift - self.shift;
        self.shift = if first || d.length() <= step || dt <= 0.0 {
            shift
        } else {
            self.shift + d * (step / d.length())
        };
        base_pos += RealVec3::new(self.shift.x, self.shift.y, 0.0);
        // The shift may have taken a foot out of reach again.
        self.lower_to_reach(&mut base_pos, base_rot, &ankle);
        self.solve_legs(base_rot, base_pos, &ankle, &foot_rot, q, &mut out.clamps);
        (base_pos, base_rot)
    }

    /// The legs and the pelvis on a plan: the soles flat where it says, the pelvis at the
    /// human's height (lowered to reach) and moved sideways until the robot's centre of mass
    /// is over the plan's.
    fn planned_body(
        &mut self,
        robot: &Robot,
        pose: &Pose64,
        pelvis: RealMat3,
        plan: &PlannedStance,
        q: &mut [Real; MAX_ROBOT_JOINTS],
        out: &mut RetargetFrame,
    ) -> (RealVec3, RealQuat) {
        let h = self.map.human;
        // The torso upright, turned as the human pelvis turns about the vertical.
        let forward = self.world * pelvis.col(0);
        let rest = self.world * self.human_frame.col(0);
        let turn = real::atan2(forward.y, forward.x) - real::atan2(rest.y, rest.x);
        let base_rot = RealQuat::from_rotation_z(turn) * self.base_rest;
        let hips_h = 0.5 * (pose.start[h.legs[0][0]] + pose.start[h.legs[1][0]]);
        let mut base_pos = self.to_world(hips_h) - base_rot * self.hip_mid;
        let mut ankle = [RealVec3::ZERO; 2];
        let mut foot_rot = [RealQuat::IDENTITY; 2];
        for side in 0..2 {
            let g = self.legs[side];
            let rest_foot = self.base_rest * g.foot_rot;
            let (print, height) = plan.soles[side];
            let rot = RealQuat::from_rotation_z(print.yaw - heading(rest_foot)) * rest_foot;
            let sole = RealVec3::new(print.centre.x, print.centre.y, height.max(0.0));
            ankle[side] = sole - rot * g.sole_from_ankle;
            foot_rot[side] = rot;
        }
        out.planted = plan.contact;
        // The pelvis starts over the planned centre of mass (the human's may be far from the
        // plan's feet); each correction starts again from the human's height, lowered to reach.
        let height = if plan.base_height.is_finite() {
            plan.base_height
        } else {
            base_pos.z
        };
        base_pos.x = plan.com.x;
        base_pos.y = plan.com.y;
        for _ in 0..PLAN_COM_ITERATIONS {
            base_pos.z = height;
            self.lower_to_reach(&mut base_pos, base_rot, &ankle);
            self.solve_legs(base_rot, base_pos, &ankle, &foot_rot, q, &mut 0);
            let (mp, mr) = self.model_placement(base_pos, base_rot);
            robot.forward(mp, mr, q, &mut self.pose);
            let com = robot.centre_of_mass(&self.pose);
            let miss = plan.com - RealVec2::new(com.x, com.y);
            base_pos += RealVec3::new(miss.x, miss.y, 0.0);
            if miss.length() < 1e-5 {
                break;
            }
        }
        base_pos.z = height;
        out.out_of_reach += self.lower_to_reach(&mut base_pos, base_rot, &ankle);
        self.solve_legs(base_rot, base_pos, &ankle, &foot_rot, q, &mut out.clamps);
        (base_pos, base_rot)
    }

    /// Lowers the pelvis until both ankle targets lie within the legs' reach (a little short
    /// of straight); returns how many were out of reach.
    fn lower_to_reach(&self, base_pos: &mut RealVec3, base_rot: RealQuat, ankle: &[RealVec3; 2]) -> u32 {
        let mut count = 0;
        for (g, target) in self.legs.iter().zip(ankle) {
            let hip = *base_pos + base_rot * g.hip;
            let d = *target - hip;
            let max = REACH_SHARE * g.reach;
            if d.length() > max {
                count += 1;
                let horizontal = RealVec2::new(d.x, d.y).length().min(max);
                let dz = real::sqrt(max * max - horizontal * horizontal);
                base_pos.z -= hip.z - (target.z + dz);
            }
        }
        count
    }

    /// Ankle height (world z) with the sole flat on the floor.
    fn flat_ankle_height(&self, side: usize) -> Real {
        let g = &self.legs[side];
        -g.corners
            .iter()
            .map(|c| (self.base_rest * g.foot_rot * *c).z)
            .fold(Real::INFINITY, Real::min)
    }

    /// Signed distance of `p` inside the support polygon of the planted feet, and the point
    /// [`BALANCE_MARGIN_M`] inside the polygon nearest `p`.
    fn support(
        &self,
        ankle: &[RealVec3; 2],
        rot: &[RealQuat; 2],
        planted: [bool; 2],
        p: RealVec2,
    ) -> (Real, RealVec2) {
        polygon_margin(&self.support_polygon(ankle, rot, planted), p, BALANCE_MARGIN_M)
    }

    /// The convex hull (on the floor) of the planted soles' corners, the feet's ankle centres
    /// at `ankle` and their bodies turned by `rot`.
    fn support_polygon(
        &self,
        ankle: &[RealVec3; 2],
        rot: &[RealQuat; 2],
        planted: [bool; 2],
    ) -> heapless::Vec<RealVec2, 8> {
        let mut pts = heapless::Vec::<RealVec2, 8>::new();
        for side in (0..2).filter(|&s| planted[s]) {
            for c in self.legs[side].corners {
                let w = ankle[side] + rot[side] * c;
                let _ = pts.push(RealVec2::new(w.x, w.y));
            }
        }
        convex_hull::<8>(&pts)
    }

    fn solve_legs(
        &self,
        base_rot: RealQuat,
        base_pos: RealVec3,
        ankle: &[RealVec3; 2],
        foot_rot: &[RealQuat; 2],
        q: &mut [Real; MAX_ROBOT_JOINTS],
        clamps: &mut u32,
    ) {
        let inv = base_rot.inverse();
        for side in 0..2 {
            let g = self.legs[side];
            // The foot body's target orientation and the ankle, in the base frame.
            let a = inv * (ankle[side] - base_pos);
            let sol = self.solve_leg(side, inv * foot_rot[side], a, clamps);
            for (k, s) in g.joints.iter().enumerate() {
                q[s.index] = sol[k];
            }
        }
    }

    /// The leg for foot body orientation `rot` and ankle centre `ankle` (base frame): the
    /// closed form, then up to [`LEG_CORRECTIONS`] fixed-point corrections of the target by the ankle's miss (the
    /// hip axes of a real robot meet only nearly — the OP3's within 0.1 mm).
    fn solve_leg(&self, side: usize, rot: RealQuat, ankle: RealVec3, clamps: &mut u32) -> [Real; 6] {
        let g = &self.legs[side];
        if !g.closed_form {
            let (q, clamped) = self.solve_leg_numeric(side, rot, ankle, self.leg_prev[side]);
            *clamps += clamped;
            return q;
        }
        let mut aim = ankle;
        let prev = self.leg_prev[side];
        let mut q = self.solve_leg_closed(side, rot, aim, prev);
        for _ in 0..LEG_CORRECTIONS {
            let s = &g.joints;
            let reached = s[0].apply(
                q[0],
                s[1].apply(q[1], s[2].apply(q[2], s[3].apply(q[3], g.ankle))),
            );
            let miss = ankle - reached;
            if miss.length() < 1e-9 {
                break;
            }
            aim += miss;
            q = self.solve_leg_closed(side, rot, aim, prev);
        }
        let mut out = [0.0; 6];
        for k in 0..6 {
            let (v, clamped) = g.joints[k].limit(q[k], 0.0);
            out[k] = v;
            *clamps += u32::from(clamped);
        }
        out
    }

    /// A leg whose axes do not allow the closed form: damped least squares on the ankle's
    /// position and the foot's orientation (six equations, six joints), from `start`, each
    /// step clamped into the limits. Returns the angles and how many sit at a limit.
    fn solve_leg_numeric(
        &self,
        side: usize,
        rot: RealQuat,
        ankle: RealVec3,
        start: [Real; 6],
    ) -> ([Real; 6], u32) {
        let g = &self.legs[side];
        let s = &g.joints;
        let clamp = |k: usize, v: Real| match s[k].range {
            Some((lo, hi)) => v.clamp(lo, hi),
            None => v,
        };
        let mut q: [Real; 6] = core::array::from_fn(|k| clamp(k, start[k]));
        for _ in 0..NUMERIC_LEG_ITERATIONS {
            // The chain's rigid motion joint by joint (product of exponentials), the joints'
            // axes and points where they are now.
            let (mut r, mut t) = (RealQuat::IDENTITY, RealVec3::ZERO);
            let mut axes = [RealVec3::ZERO; 6];
            let mut points = [RealVec3::ZERO; 6];
            for k in 0..6 {
                axes[k] = r * s[k].axis;
                points[k] = r * s[k].point + t;
                let rk = s[k].rot(q[k]);
                t += r * s[k].point - r * (rk * s[k].point);
                r *= rk;
            }
            let now = r * g.ankle + t;
            let e_pos = ankle - now;
            let e_rot = (rot * (r * g.foot_rot).inverse()).to_scaled_axis();
            if e_pos.length() < 1e-9 && e_rot.length() < 1e-8 {
                break;
            }
            // Rows: position (m) and orientation weighted to metres by the leg's length.
            let w = g.reach.max(0.05);
            let mut jtj = [[0.0; 6]; 6];
            let mut jte = [0.0; 6];
            let cols: [[Real; 6]; 6] = core::array::from_fn(|k| {
                let lin = axes[k].cross(now - points[k]);
                let ang = axes[k] * w;
                [lin.x, lin.y, lin.z, ang.x, ang.y, ang.z]
            });
            let err = [e_pos.x, e_pos.y, e_pos.z, e_rot.x * w, e_rot.y * w, e_rot.z * w];
            for i in 0..6 {
                for k in 0..6 {
                    jtj[i][k] = (0..6).map(|m| cols[i][m] * cols[k][m]).sum::<Real>();
                }
                jtj[i][i] += NUMERIC_LEG_DAMPING * NUMERIC_LEG_DAMPING;
                jte[i] = (0..6).map(|m| cols[i][m] * err[m]).sum::<Real>();
            }
            let Some(dq) = solve6(jtj, jte) else { break };
            for k in 0..6 {
                q[k] = clamp(k, q[k] + dq[k].clamp(-0.5, 0.5));
            }
        }
        let at_limit = (0..6)
            .filter(|&k| s[k].range.is_some_and(|(lo, hi)| q[k] <= lo || q[k] >= hi))
            .count();
        (q, at_limit as u32)
    }

    /// The closed form (see the module's notes), unclamped.
    fn solve_leg_closed(&self, side: usize, rot: RealQuat, ankle: RealVec3, prev: [Real; 6]) -> [Real; 6] {
        let g = &self.legs[side];
        let s = &g.joints;
        // g = e1·…·e6 as a rigid motion: rotation rg, and the ankle centre carried to `ankle`.
        let rg = rot * g.foot_rot.inverse();
        let delta = (ankle - g.hip).length();
        // Knee (subproblem 3).
        let k = s[3];
        let v = g.ankle - k.point;
        let w = g.hip - k.point;
        let (v_par, w_par) = (k.axis.dot(v), k.axis.dot(w));
        let (vp, wp) = (v - k.axis * v_par, w - k.axis * w_par);
        let c = (vp.length_squared() + wp.length_squared() + (v_par - w_par) * (v_par - w_par)
            - delta * delta)
            / (2.0 * vp.length() * wp.length());
        let theta0 = angle_about(k.axis, wp, vp);
        let bend = real::acos(c.clamp(-1.0, 1.0));
        let cand = [wrap(bend - theta0), wrap(-bend - theta0)];
        let q4 = if cand[0] * g.knee_sign >= cand[1] * g.knee_sign {
            cand[0]
        } else {
            cand[1]
        };
        // Ankle (subproblem 2): e5·e6·(g⁻¹·hip) = e4⁻¹·hip.
        let p = rg.inverse() * (g.hip - ankle) + g.ankle;
        let target = k.apply(-q4, g.hip);
        let (a5, a6) = (s[4], s[5]);
        let c56 = angles_about_two(a5.axis, a6.axis, p - g.ankle, target - g.ankle);
        // Of the two ankle and two hip solutions, the one nearest the leg's previous frame
        // (`prev`), a joint's way past its limit counting double: a leg that changes branch
        // where a foot is out of reach flips its hip and ankle in one frame.
        let cost = |q: &[Real; 6]| {
            (0..6)
                .map(|k| {
                    let past = s[k]
                        .range
                        .map_or(0.0, |(lo, hi)| (lo - q[k]).max(q[k] - hi).max(0.0));
                    (q[k] - prev[k]).abs() + 2.0 * past
                })
                .sum::<Real>()
        };
        let probe = s[2].axis.any_orthonormal_vector();
        let mut best = ([0.0; 6], Real::INFINITY);
        for (q5, q6) in c56 {
            // Hip: e1·e2·e3 = rg·(e4·e5·e6)⁻¹.
            let r456 = k.rot(q4) * a5.rot(q5) * a6.rot(q6);
            let r_hip = rg * r456.inverse();
            let (a1, a2, a3) = (s[0], s[1], s[2]);
            for (q1, q2) in angles_about_two(a1.axis, a2.axis, a3.axis, r_hip * a3.axis) {
                let r12 = a1.rot(q1) * a2.rot(q2);
                let q3 = angle_about(a3.axis, probe, r12.inverse() * r_hip * probe);
                let q = [q1, q2, q3, q4, q5, q6];
                let c = cost(&q);
                if c < best.1 {
                    best = (q, c);
                }
            }
        }
        best.0
    }

    /// The arm in a stream, `dt` after the previous frame: the solution continuing the previous
    /// frame's is kept until what it has cost over the best other, summed over the frames since
    /// it was last the best, exceeds the jump to that other ([`arm_step_cost`] at the joints'
    /// speed limits) plus [`BRANCH_HYSTERESIS`] — a stream cannot know whether the other stays
    /// better, so it pays at most twice what the clip's plan would (the rent-or-buy rule).
    fn solve_arm(
        &mut self,
        side: usize,
        g: &ArmGeometry,
        pose: &Pose64,
        to_base: RealMat3,
        dt: Real,
        clamps: &mut u32,
    ) -> [Real; 3] {
        let mut sols = ArmSolutions::new();
        let prev = self.arm_prev[side];
        let from_prev = self.solutions_in(side, pose, to_base, prev, &mut sols);
        let best = sols
            .iter()
            .min_by(|a, b| a.cost().total_cmp(&b.cost()))
            .copied()
            .unwrap_or_default();
        let q = match (from_prev.and_then(|i| sols.get(i)), prev) {
            (Some(stay), Some(prev)) => {
                let extra = stay.cost() - best.cost();
                if extra <= 0.0 {
                    self.arm_regret[side] = 0.0;
                    stay.q
                } else {
                    self.arm_regret[side] += extra;
                    let limit = self.arm_speed[side].map(|v| v * dt.max(1e-6));
                    if self.arm_regret[side] > arm_step_cost(prev, best.q, limit) + BRANCH_HYSTERESIS {
                        self.arm_regret[side] = 0.0;
                        best.q
                    } else {
                        stay.q
                    }
                }
            }
            _ => best.q,
        };
        for (k, s) in g.joints.iter().enumerate() {
            if s.range
                .is_some_and(|(lo, hi)| q[k] <= lo + 1e-9 || q[k] >= hi - 1e-9)
            {
                *clamps += 1;
            }
        }
        self.arm_prev[side] = Some(q);
        q
    }

    /// Human world vectors → the robot base's frame (pelvis frame to pelvis frame) at `pose`.
    fn to_base(&self, pose: &Pose64) -> RealMat3 {
        let rel = pose.frame[self.map.human.pelvis] * self.human_rest_frame[REST_PELVIS].transpose();
        self.robot_frame * (rel * self.human_frame).transpose()
    }

    /// Where arm `side`'s hand should be at `pose`: the human's shoulder-to-wrist vector at the
    /// robot's arm scale from the robot's shoulder, base frame, with the human's upper-arm
    /// direction (unit); `None` when the arm is unmapped.
    fn hand_goal(&self, side: usize, pose: &Pose64, to_base: RealMat3) -> Option<(RealVec3, RealVec3)> {
        let g = self.arms[side & 1]?;
        let bones = self.map.human.arms[side & 1]?;
        let upper = to_base * (pose.tip[bones[0]] - pose.start[bones[0]]);
        let fore = to_base * (pose.tip[bones[1]] - pose.start[bones[1]]);
        let target = g.centre + (upper + fore) * (self.units * self.arm_scale[side & 1]);
        Some((target, upper.normalize_or_zero()))
    }

    /// Every distinct way arm `side` reaches its hand target at `pose` (empty when unmapped):
    /// from the closed form's four starts, the two that point the upper arm along the human's,
    /// and `prev` (the arm's angles a frame before) when given, each finished on the hand's
    /// position within the limits. Angles are taken a turn away where that keeps them inside
    /// their range nearer `prev`. Allocates nothing.
    pub fn arm_solutions(&self, pose: &Pose64, side: usize, prev: Option<[Real; 3]>, out: &mut ArmSolutions) {
        self.solutions_in(side, pose, self.to_base(pose), prev, out);
    }

    /// [`Retargeter::arm_solutions`]; returns which of them continues `prev`.
    fn solutions_in(
        &self,
        side: usize,
        pose: &Pose64,
        to_base: RealMat3,
        prev: Option<[Real; 3]>,
        out: &mut ArmSolutions,
    ) -> Option<usize> {
        out.clear();
        let g = self.arms[side & 1]?;
        let (target, human_upper) = self.hand_goal(side, pose, to_base)?;
        let [s1, s2, s3] = g.joints;
        let reference = prev.unwrap_or([0.0; 3]);
        let mut starts = [[0.0; 3]; 7];
        starts[..4].copy_from_slice(&g.closed_form(target));
        for (k, (q1, q2)) in angles_about_two(s1.axis, s2.axis, g.upper, human_upper)
            .into_iter()
            .enumerate()
        {
            let r12 = s1.rot(q1) * s2.rot(q2);
            let fore = target - g.centre - r12 * (g.upper * g.length * 0.5);
            starts[4 + k] = [q1, q2, angle_about(r12 * s3.axis, r12 * g.fore, fore)];
        }
        starts[6] = reference;
        let count = if prev.is_some() { 7 } else { 6 };
        let mut from_prev = None;
        for (k, start) in starts.iter().take(count).enumerate() {
            let start = [
                s1.limit(start[0], reference[0]).0,
                s2.limit(start[1], reference[1]).0,
                s3.limit(start[2], reference[2]).0,
            ];
            let (q, hand_error) = g.reach(start, target);
            let sol = ArmSolution {
                q,
                hand_error,
                elbow_error: angle_between(g.upper_at(q), human_upper),
            };
            let same = out
                .iter()
                .position(|o| (0..3).all(|i| (o.q[i] - q[i]).abs() < 1e-3));
            let at = match same {
                Some(i) => {
                    if sol.hand_error < out[i].hand_error {
                        out[i] = sol;
                    }
                    Some(i)
                }
                None => out.push(sol).ok().map(|()| out.len() - 1),
            };
            if k == 6 {
                from_prev = at;
            }
        }
        from_prev
    }

    /// Direction errors per limb, the soles, the centre of mass and its margin.
    fn measure(&mut self, robot: &Robot, pose: &Pose64, to_base: RealMat3, out: &mut RetargetFrame) {
        let h = self.map.human;
        let (mp, mr) = self.model_placement(out.base_pos, out.base_rot);
        robot.forward(mp, mr, &out.q, &mut self.pose);
        let inv = out.base_rot.inverse();
        let base = |p: RealVec3| inv * (p - out.base_pos);
        let human = |b: usize| to_base * (pose.tip[b] - pose.start[b]);
        let mut errs = [(0.0, 0.0, 0u32); 5];
        let mut add = |limb: usize, a: RealVec3, b: RealVec3| {
            let e = angle_between(a, b).to_degrees();
            errs[limb].0 = Real::max(errs[limb].0, e);
            errs[limb].1 += e * e;
            errs[limb].2 += 1;
        };
        for side in 0..2 {
            if let (Some(g), Some(bones), Some(chain)) = (self.arms[side], h.arms[side], self.map.arms[side])
            {
                let at = |k: usize| {
                    let j = &robot.joints()[g.joints[k].index];
                    base(self.pose.pos[j.body] + self.pose.rot[j.body] * j.anchor)
                };
                let elbow = &robot.joints()[chain.joints[2]];
                let eb = elbow.body;
                let tip = base(self.pose.pos[eb] + self.pose.rot[eb] * chain.tip);
                let axis = inv * (self.pose.rot[eb] * elbow.axis);
                let fore = tip - at(2);
                add(side, at(2) - at(1), human(bones[0]));
                add(side, fore - axis * axis.dot(fore), human(bones[1]));
                let (target, _) = self.hand_goal(side, pose, to_base).unwrap_or_default();
                out.hand_error[side] = (tip - target).length();
                out.hand_target[side] = out.base_pos + out.base_rot * target;
            } else {
                out.hand_error[side] = Real::NAN;
                out.hand_target[side] = RealVec3::NAN;
            }
            let g = &self.legs[side];
            let [thigh, shin, _] = h.legs[side];
            let chain = &self.map.legs[side];
            let body = |k: usize| robot.joints()[chain.joints[k]].body;
            // Hip centre (fixed in the base), knee and ankle centres through their bodies.
            // A point given where it sits at the zero pose (base coordinates), carried by body k.
            let point = |k: usize, p_rest: RealVec3| -> RealVec3 {
                let b = body(k);
                base(self.pose.pos[b] + self.pose.rot[b] * self.body_local(b, p_rest))
            };
            let knee = point(3, g.knee);
            let ankle = point(5, g.ankle);
            add(2 + side, knee - g.hip, human(thigh));
            add(2 + side, ankle - knee, human(shin));
            let fb = body(5);
            let sole = self.pose.pos[fb]
                + self.pose.rot[fb] * self.body_local(fb, g.ankle + g.foot_rot * g.sole_from_ankle);
            out.sole[side] = sole;
        }
        if let (Some(g), Some(b)) = (self.head, h.head) {
            let rel_head = pose.frame[b] * self.human_rest_frame[REST_HEAD].transpose();
            let face = to_base * (rel_head * self.human_frame.col(0));
            let tilt_body = robot.joints()[g.joints[1].index].body;
            let fwd = inv
                * (self.pose.rot[tilt_body]
                    * (self.rest.rot[tilt_body].inverse() * (self.base_rest * g.forward)));
            add(4, fwd, face);
        }
        for (k, (max, sq, n)) in errs.iter().enumerate() {
            out.limb_error_deg[k] = if *n > 0 { *max } else { Real::NAN };
            out.limb_error_sq[k] = (*sq, *n);
        }
        out.com = robot.centre_of_mass(&self.pose);
        out.zmp = RealVec2::new(out.com.x, out.com.y);
        out.effectors = self.effector_points(robot, &self.pose);
        let mut ankles = [RealVec3::ZERO; 2];
        let mut rots = [RealQuat::IDENTITY; 2];
        for side in 0..2 {
            let fb = robot.joints()[self.map.legs[side].joints[5]].body;
            let g = &self.legs[side];
            ankles[side] = self.pose.pos[fb] + self.pose.rot[fb] * self.body_local(fb, g.ankle);
            rots[side] = self.pose.rot[fb];
            out.sole_yaw[side] = heading(rots[side]);
        }
        out.lowest_sole = (0..2)
            .flat_map(|side| self.legs[side].corners.map(|c| (ankles[side] + rots[side] * c).z))
            .fold(Real::INFINITY, Real::min);
        out.com_margin = if out.planted.iter().any(|p| *p) {
            // Soles where the solved pose put them.
            let polygon = self.support_polygon(&ankles, &rots, out.planted);
            polygon_margin(&polygon, RealVec2::new(out.com.x, out.com.y), 0.0).0
        } else {
            Real::NAN
        };
    }

    /// A point given in base coordinates at the zero pose, in body `b`'s own frame.
    fn body_local(&self, b: usize, p_base: RealVec3) -> RealVec3 {
        self.rest.rot[b].inverse() * (self.base_rest_pos + self.base_rest * p_base - self.rest.pos[b])
    }
}

/// Solves the 6×6 system `a·x = b` by Gaussian elimination with partial pivoting (`None` when
/// singular).
fn solve6(mut a: [[Real; 6]; 6], mut b: [Real; 6]) -> Option<[Real; 6]> {
    for c in 0..6 {
        let p = (c..6).max_by(|&i, &j| a[i][c].abs().total_cmp(&a[j][c].abs()))?;
        if a[p][c].abs() < 1e-15 {
            return None;
        }
        a.swap(c, p);
        b.swap(c, p);
        let pivot = a[c];
        for r in c + 1..6 {
            let f = a[r][c] / pivot[c];
            for (x, p) in a[r][c..].iter_mut().zip(&pivot[c..]) {
                *x -= f * p;
            }
            b[r] -= f * b[c];
        }
    }
    let mut x = [0.0; 6];
    for c in (0..6).rev() {
        let sum: Real = (c + 1..6).map(|k| a[c][k] * x[k]).sum();
        x[c] = (b[c] - sum) / a[c][c];
    }
    Some(x)
}

/// A foot's frame from where its joints are (not from its bone's axes, which formats and
/// tools set differently): forward from the ankle to the toe, left square to it and to the
/// shin, up completing them.
fn foot_frame(pose: &Pose64, leg: [usize; 3]) -> RealMat3 {
    let [_, shin, foot] = leg;
    let forward = (pose.tip[foot] - pose.start[foot]).normalize_or(RealVec3::X);
    let down = pose.tip[shin] - pose.start[shin];
    let left = forward.cross(down).normalize_or(RealVec3::Y);
    let up = left.cross(forward);
    RealMat3::from_cols(forward, left, up)
}

/// The heading of a body's x axis about the vertical.
fn heading(rot: RealQuat) -> Real {
    let x = rot * RealVec3::X;
    real::atan2(x.y, x.x)
}

fn smoothstep(t: Real) -> Real {
    let t = t.clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// Orthonormal (forward, left, up) from a left vector and a rough up vector. Up is snapped to
/// the nearest coordinate axis (captures and models are made with an axis up; a rest pose that
/// leans a little must not tilt the floor); left is made square to it.
fn frame_from(left: RealVec3, up: RealVec3) -> Option<RealMat3> {
    let up = snap_axis(up.try_normalize()?);
    let left = (left - up * up.dot(left)).try_normalize()?;
    let forward = left.cross(up);
    Some(RealMat3::from_cols(forward, left, up))
}

/// The signed coordinate axis nearest a unit vector.
fn snap_axis(v: RealVec3) -> RealVec3 {
    let a = v.abs();
    if a.x >= a.y && a.x >= a.z {
        RealVec3::X * v.x.signum()
    } else if a.y >= a.z {
        RealVec3::Y * v.y.signum()
    } else {
        RealVec3::Z * v.z.signum()
    }
}

/// Checks that `joints` lie one below another on one branch below `base`.
fn check_chain(
    robot: &Robot,
    base: usize,
    joints: &[usize],
    what: &'static str,
) -> Result<(), RetargetError> {
    let body = |j: usize| robot.joints()[j].body;
    let descends = |mut b: usize, from: usize| loop {
        if b == from {
            return true;
        }
        match robot.bodies()[b].parent {
            Some(p) => b = p,
            None => return false,
        }
    };
    let mut above = base;
    for &j in joints {
        let b = body(j);
        if b == above || !descends(b, above) {
            return Err(RetargetError::NotAChain(what));
        }
        above = b;
    }
    Ok(())
}

/// Convex hull (counter-clockwise, Andrew's monotone chain) of up to `N` points (further
/// ones are left out).
#[must_use]
pub fn convex_hull<const N: usize>(points: &[RealVec2]) -> heapless::Vec<RealVec2, N> {
    let mut pts: heapless::Vec<RealVec2, N> = points.iter().copied().take(N).collect();
    pts.sort_unstable_by(|a, b| a.x.total_cmp(&b.x).then(a.y.total_cmp(&b.y)));
    let n = pts.len();
    let mut hull = heapless::Vec::<RealVec2, N>::new();
    let cross = |o: RealVec2, a: RealVec2, b: RealVec2| (a - o).perp_dot(b - o);
    for p in pts.iter() {
        while hull.len() >= 2 && cross(hull[hull.len() - 2], hull[hull.len() - 1], *p) <= 0.0 {
            hull.pop();
        }
        let _ = hull.push(*p);
    }
    let lower = hull.len() + 1;
    for (k, p) in pts.iter().rev().skip(1).enumerate() {
        while hull.len() >= lower && cross(hull[hull.len() - 2], hull[hull.len() - 1], *p) <= 0.0 {
            hull.pop();
        }
        // The last point is the first: it closes the hull, it is not added again.
        if k + 2 < n {
            let _ = hull.push(*p);
        }
    }
    hull
}

/// Signed distance of `p` inside a convex counter-clockwise polygon (negative outside), and
/// the point nearest `p` that lies at least `margin` inside (the centroid when the polygon is
/// thinner than that).
#[must_use]
pub fn polygon_margin(poly: &[RealVec2], p: RealVec2, margin: Real) -> (Real, RealVec2) {
    let n = poly.len();
    if n < 3 {
        return (Real::NAN, p);
    }
    let mut dist = Real::INFINITY;
    for i in 0..n {
        let (a, b) = (poly[i], poly[(i + 1) % n]);
        let e = (b - a).normalize_or_zero();
        let inward = e.perp();
        dist = dist.min((p - a).dot(inward));
    }
    if dist >= margin {
        return (dist, p);
    }
    // Project onto the polygon shrunk by `margin`: clip p towards the centroid until inside.
    let centroid = poly.iter().copied().sum::<RealVec2>() / n as Real;
    let mut lo = 0.0;
    let mut hi = 1.0;
    let inside = |x: RealVec2| {
        (0..n).all(|i| {
            let (a, b) = (poly[i], poly[(i + 1) % n]);
            (x - a).dot((b - a).normalize_or_zero().perp()) >= margin
        })
    };
    if !inside(centroid) {
        return (dist, centroid);
    }
    for _ in 0..40 {
        let mid = 0.5 * (lo + hi);
        if inside(p + (centroid - p) * mid) {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    (dist, p + (centroid - p) * hi)
}

/// The human's up direction: the coordinate axis nearest the rest pose's pelvis-to-head (or
/// shoulders) direction.
#[must_use]
pub fn human_up(skeleton: &Skeleton, human: &HumanBones) -> RealVec3 {
    let mut rest = Pose64::default();
    fk64(skeleton, &[], &mut rest);
    let hips = [rest.start[human.legs[0][0]], rest.start[human.legs[1][0]]];
    let top = match (human.head, human.arms[0]) {
        (Some(b), _) | (None, Some([b, _])) => rest.start[b],
        _ => rest.start[human.pelvis] + RealVec3::Y,
    };
    frame_from(hips[0] - hips[1], top - 0.5 * (hips[0] + hips[1])).map_or(RealVec3::Y, |f| f.col(2))
}

/// The human floor from the rest pose alone (for live streams): the ankle and toe heights of
/// the rest pose (the rest pose stands on the floor).
#[must_use]
pub fn floor_of_rest(skeleton: &Skeleton, human: &HumanBones) -> Floor {
    let mut rest = Pose64::default();
    fk64(skeleton, &[], &mut rest);
    let up = human_up(skeleton, human);
    Floor {
        ankle: human.legs.map(|l| rest.tip[l[1]].dot(up)),
        toe: human.legs.map(|l| rest.tip[l[2]].dot(up)),
        foot_pitch: human.legs.map(|l| foot_elevation(&rest, l, up)),
    }
}

/// Elevation of a foot's ankle-to-toe line above the floor plane (radians), between −60° and 0°
/// (a rest pose with the foot pointing down says nothing about the arch).
#[must_use]
pub fn foot_elevation(pose: &Pose64, leg: [usize; 3], up: RealVec3) -> Real {
    let f = (pose.tip[leg[2]] - pose.start[leg[2]]).normalize_or_zero();
    real::asin(f.dot(up).clamp(-1.0, 1.0)).clamp(-crate::math::consts::FRAC_PI_3, 0.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit(x: Real, y: Real, z: Real) -> RealVec3 {
        RealVec3::new(x, y, z).normalize()
    }

    /// Subproblem 1 turns a vector onto the target's cone; subproblem 2 reaches any direction
    /// two perpendicular axes can reach, with both solutions.
    #[test]
    fn paden_kahan_subproblems() {
        let a = RealVec3::Z;
        let q = angle_about(a, RealVec3::X, unit(0.0, 1.0, 0.3));
        assert!((q - crate::math::consts::FRAC_PI_2).abs() < 1e-12);
        let (a1, a2, v) = (RealVec3::Y, -RealVec3::X, RealVec3::Y);
        for t in [unit(0.3, -0.2, -0.9), unit(1.0, 0.5, 0.2), unit(-0.2, 0.9, 0.1)] {
            for (q1, q2) in angles_about_two(a1, a2, v, t) {
                let got = RealQuat::from_axis_angle(a1, q1) * RealQuat::from_axis_angle(a2, q2) * v;
                assert!((got - t).length() < 1e-12, "{got} {t}");
            }
        }
        // Unreachable: both axes along z cannot lift x; the nearest direction comes back.
        let [(q1, q2), _] = angles_about_two(RealVec3::Z, RealVec3::Z, RealVec3::X, RealVec3::Z);
        assert!(q1.is_finite() && q2.is_finite());
    }

    /// The support polygon: the hull of two soles, the margin inside and outside, the point a
    /// margin inside.
    #[test]
    fn support_polygon_margin() {
        let pts = [
            RealVec2::new(0.0, 0.0),
            RealVec2::new(1.0, 0.0),
            RealVec2::new(1.0, 1.0),
            RealVec2::new(0.0, 1.0),
            RealVec2::new(0.5, 0.5),
        ];
        let hull = convex_hull::<8>(&pts);
        assert_eq!(hull.len(), 4);
        let (m, p) = polygon_margin(&hull, RealVec2::new(0.5, 0.2), 0.0);
        assert!((m - 0.2).abs() < 1e-12 && p == RealVec2::new(0.5, 0.2));
        let (m, p) = polygon_margin(&hull, RealVec2::new(0.5, -0.3), 0.1);
        assert!((m + 0.3).abs() < 1e-12);
        assert!((p.y - 0.1).abs() < 1e-6 && p.x > 0.0 && p.x < 1.0, "{p}");
        assert!(polygon_margin(&hull[..2], RealVec2::ZERO, 0.0).0.is_nan());
    }

    /// A rest pose that leans does not tilt the floor: up snaps to the nearest axis.
    #[test]
    fn pelvis_frame_snaps_up_to_an_axis() {
        let f = frame_from(RealVec3::new(1.0, 0.05, 0.0), RealVec3::new(0.1, 1.0, -0.05)).unwrap();
        assert_eq!(f.col(2), RealVec3::Y);
        assert!((f.col(1) - RealVec3::X).length() < 1e-12);
        assert!((f.col(0) - RealVec3::Z).length() < 1e-12);
        assert!(frame_from(RealVec3::Y, RealVec3::Y).is_none());
    }
}
