//! Inverse kinematics in f64 (help note §IV): an analytic 2-bone limb solver with a swivel-angle
//! search inside quaternion joint-limit regions, and numerical solvers (CCD, Jacobian
//! transpose, pseudoinverse, damped least squares, conjugate gradient) on fixed-size buffers.
//!
//! FK in f64 is [`crate::fk::fk64`]. Frames follow [`crate::fk`]: a bone's world rotation is
//! `Wᵢ = Wₚ·Qᵢ` with `Qᵢ = C·M·Cᵀ`; channel vectors hold radians for rotations and file units for
//! translations.

use crate::math::{precision, real, Real, RealMat3, RealQuat, RealVec3, ToReal};

use crate::fk::{ancestors, fk64, fk64_bones, fk64_start, fk64_step, fk64_tip, world_of, Pose64};
use crate::math::{
    euler_near, length, normalize, normalize_or_zero, quat_distance_fast, rotation_arc, sort_by_real,
    wrap_near, EulerOrder,
};
use crate::skeleton::{dof_order, Dof, Skeleton, MAX_BONES};
use crate::swivel::{self, LimitForms, SwivelCircle};

/// How far rounding may leave a value past a bound it meets exactly (an angle on its limit, a
/// cosine at ±1): 1e-12 in f64; in f32, whose step at π is 2.4e-7 rad, 1e-6.
const ROUNDING: Real = precision(1e-12, 1e-6);
/// A quantity treated as zero, or two solutions treated as one.
const NEAR_ZERO: Real = precision(1e-9, 1e-5);
/// The bracket at which a golden-section search of the swivel stops, radians.
const SWIVEL_TOLERANCE: Real = precision(1e-10, 1e-6);

/// The world axis of a bone's rotation DOF number `k` (index into its DOF list), eq. (43)'s `uᵢ`:
/// `Wₚ·C·R(last)…R(k+1)·e_k`, with the bone's axes `Wₚ·C = Fₚ·K`. For a translation DOF, the
/// translation axis (eq. 46).
#[must_use]
pub fn dof_axis(skeleton: &Skeleton, pose: &Pose64, bone: usize, k: usize, channels: &[Real]) -> RealVec3 {
    let b = &skeleton.bones()[bone];
    let axes = pose.axes(skeleton, bone);
    let dofs = b.dofs();
    let first = b.first_channel();
    if !dofs[k].is_rotation() {
        let e = dofs[k].axis().map_or(RealVec3::ZERO, |a| a.unit().to_real());
        return if b.parent().is_none() { e } else { axes * e };
    }
    let mut after = RealMat3::IDENTITY;
    for j in (k + 1..dofs.len()).rev() {
        if let Some(a) = dofs[j].rotation_axis() {
            after *= a.rotation_f64(channels.get(first + j).copied().unwrap_or(0.0));
        }
    }
    let e = dofs[k].axis().map_or(RealVec3::ZERO, |a| a.unit().to_real());
    axes * after * e
}

/// Rotation taking unit vector `a` to unit vector `b` by the shortest arc. Past 90° it is
/// composed of two arcs through the perpendicular in the a–b plane: a single arc loses
/// precision as the vectors become opposite.
fn rotation_between(a: RealVec3, b: RealVec3) -> RealQuat {
    let a = normalize_or_zero(a);
    let b = normalize_or_zero(b);
    if a.dot(b) >= 0.0 {
        return rotation_arc(a, b);
    }
    let mut m = b - a * a.dot(b);
    if m.length_squared() < 1e-24 {
        m = a.any_orthonormal_vector();
    }
    let m = normalize(m);
    rotation_arc(m, b) * rotation_arc(a, m)
}

/// Why a limb cannot be set up.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum LimbError {
    /// The lower bone is not a child of the upper bone.
    NotAChain,
    /// The upper bone needs three rotation DOFs.
    UpperNeeds3Dofs,
    /// The lower bone needs one or three rotation DOFs.
    LowerDofs,
    /// A bone has zero length.
    ZeroLength,
    /// The elbow axis cannot be found (straight at rest and in the given frame).
    NoElbowAxis,
}

impl core::fmt::Display for LimbError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            LimbError::NotAChain => "the lower bone is not a child of the upper bone",
            LimbError::UpperNeeds3Dofs => "the upper bone (shoulder/hip) needs rx ry rz",
            LimbError::LowerDofs => "the lower bone (elbow/knee) needs one or three rotation DOFs",
            LimbError::ZeroLength => "a limb bone has zero length",
            LimbError::NoElbowAxis => {
                "the elbow axis cannot be found: the limb is straight at rest and in the given frame"
            }
        })
    }
}

impl core::error::Error for LimbError {}

/// How the swivel angle is chosen.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Swivel {
    /// Searched inside the joint limits (eq. 27–30), optionally kept near a previous value.
    Auto {
        /// The previous solution's swivel angle, for streams.
        previous: Option<Real>,
    },
    /// Given (radians, help note eq. 18–22 convention).
    Fixed(Real),
    /// The legal swivel nearest the given one (the given one when legal): keeps a captured
    /// elbow or knee direction where the limits allow, and moves it continuously to the
    /// nearest legal one where they do not.
    Nearest(Real),
    /// For streams: eq. 30 searched only within `window` radians of the previous swivel (9
    /// samples and golden section instead of the whole circle), so the elbow cannot flip
    /// between frames; the whole circle ([`Swivel::Auto`]) when that window holds no legal
    /// swivel.
    Track {
        /// The previous frame's swivel.
        previous: Real,
        /// Half-width of the searched window, radians.
        window: Real,
    },
}

/// Samples of the swivel circle in the coarse scan before refinement (every 10°).
const SWIVEL_SAMPLES: u32 = 36;

/// A 2-bone limb of a skeleton (arm: humerus–radius, leg: femur–tibia), help note §IV steps 1–8.
#[derive(Clone, Debug)]
pub struct Limb {
    /// Upper bone (shoulder/hip joint at its start).
    pub upper: usize,
    /// Lower bone (elbow/knee joint at its start); the effector is its tip.
    pub lower: usize,
    upper_order: EulerOrder,
    upper_rot_dofs: [usize; 3],
    /// Elbow axis in the upper bone's rest (world-at-rest) coordinates, and how the elbow angle
    /// maps to the lower bone's channels.
    elbow_axis: RealVec3,
    elbow: Elbow,
    d1: RealVec3,
    d2: RealVec3,
    l1: Real,
    l2: Real,
    corners: heapless::Vec<RealQuat, 8>,
    center: [Real; 3],
    limits: [(Real, Real); 3],
    elbow_limit: (Real, Real),
    /// `C` of the upper bone as a quaternion.
    c_upper: RealQuat,
    /// The swivel's zero direction `â` in the parent's rest frame: of −y (the help note's
    /// default) and −z, the one more perpendicular to the limb at rest, so that a leg hanging
    /// along −y does not make the swivel ill-defined.
    swivel_reference: RealVec3,
    /// The root…lower bones, for FK of just the limb.
    chain: heapless::Vec<usize, MAX_BONES>,
    /// The shoulder limits as conditions on the swivel circle.
    limit_forms: LimitForms,
}

#[derive(Clone, Copy, Debug)]
enum Elbow {
    /// One DOF: channel offset into the lower bone's DOFs.
    One(usize),
    /// Three DOFs in this order: the elbow rotation is written as Euler angles.
    Three(EulerOrder, [usize; 3]),
}

/// The result of a limb solve.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LimbSolution {
    /// Whether the target is within reach (else the limb is stretched or folded towards it).
    pub reachable: bool,
    /// Distance from the effector to the target after the solve, file units.
    pub error: Real,
    /// The swivel angle used (radians, eq. 18–22: the elbow axis's angle about the shoulder–
    /// effector line from û).
    pub swivel: Real,
    /// Whether the shoulder angles are within the ASF limits.
    pub upper_within_limits: bool,
    /// Whether the elbow angle is within its limit.
    pub elbow_within_limits: bool,
    /// Sum of limit violations, radians (0 when within).
    pub violation: Real,
}

fn rot_dofs(dofs: &[Dof]) -> heapless::Vec<usize, 3> {
    let mut v = heapless::Vec::new();
    for (k, d) in dofs.iter().enumerate() {
        if d.is_rotation() {
            let _ = v.push(k);
        }
    }
    v
}

impl Limb {
    /// Sets up the limb `upper`→`lower`. The elbow axis comes from the lower bone's single DOF,
    /// or — for a 3-DOF elbow — from the rest pose (cross product of the two bone directions),
    /// or, when the limb is straight at rest, from `frame` (a mocap frame, radians).
    ///
    /// # Errors
    /// [`LimbError`].
    pub fn new(
        skeleton: &Skeleton,
        upper: usize,
        lower: usize,
        frame: Option<&[Real]>,
    ) -> Result<Limb, LimbError> {
        let bones = skeleton.bones();
        let (u, lo) = (
            bones.get(upper).ok_or(LimbError::NotAChain)?,
            bones.get(lower).ok_or(LimbError::NotAChain)?,
        );
        if lo.parent() != Some(upper) {
            return Err(LimbError::NotAChain);
        }
        let upper_order = dof_order(u.dofs()).ok_or(LimbError::UpperNeeds3Dofs)?;
        let ur = rot_dofs(u.dofs());
        let upper_rot_dofs = [ur[0], ur[1], ur[2]];
        let (l1, l2) = ((u.length() as Real), (lo.length() as Real));
        if l1 <= 1e-9 || l2 <= 1e-9 {
            return Err(LimbError::ZeroLength);
        }
        let d1 = u.direction_f64();
        let d2 = lo.direction_f64();
        let lr = rot_dofs(lo.dofs());
        let c_lower = lo.axis_rotation_f64();
        let (elbow_axis, elbow) = match lr.len() {
            1 => {
                let axis = lo.dofs()[lr[0]]
                    .axis()
                    .map_or(RealVec3::X, |a| a.unit().to_real());
                (c_lower * axis, Elbow::One(lr[0]))
            }
            3 => {
                let mut axis = d1.cross(d2);
                if axis.length() < 1e-6 {
                    let f = frame.ok_or(LimbError::NoElbowAxis)?;
                    let mut pose = Pose64::default();
                    fk64(skeleton, f, &mut pose);
                    let upper_dir = pose.tip[upper] - pose.start[upper];
                    let lower_dir = pose.tip[lower] - pose.start[lower];
                    // Into the upper bone's rest coordinates.
                    axis = pose.world(skeleton, upper).transpose() * upper_dir.cross(lower_dir);
                    if axis.length() < 1e-6 {
                        return Err(LimbError::NoElbowAxis);
                    }
                }
                let order = dof_order(lo.dofs()).ok_or(LimbError::LowerDofs)?;
                (axis.normalize(), Elbow::Three(order, [lr[0], lr[1], lr[2]]))
            }
            _ => return Err(LimbError::LowerDofs),
        };
        let lim = |b: &crate::skeleton::Bone, k: usize| {
            b.limits()
                .get(k)
                .map_or((Real::NEG_INFINITY, Real::INFINITY), |l| {
                    ((l.min as Real), (l.max as Real))
                })
        };
        let limits = [lim(u, ur[0]), lim(u, ur[1]), lim(u, ur[2])];
        // The 8 corners of the limit box as quaternions (fewer when a DOF is unlimited).
        let mut corners = heapless::Vec::new();
        let finite = |x: Real, fallback: Real| if x.is_finite() { x } else { fallback };
        for mask in 0..8u8 {
            let pick = |k: usize| {
                let (a, b) = limits[k];
                if mask & (1 << k) == 0 {
                    finite(a, -crate::math::consts::PI)
                } else {
                    finite(b, crate::math::consts::PI)
                }
            };
            let angles = [pick(0), pick(1), pick(2)];
            let _ = corners.push(RealQuat::from_mat3(&upper_order.to_mat3_f64(angles)));
        }
        let center = [0, 1, 2].map(|k| {
            let (a, b) = limits[k];
            if a.is_finite() && b.is_finite() {
                0.5 * (a + b)
            } else {
                0.0
            }
        });
        let elbow_limit = match elbow {
            Elbow::One(k) => lim(lo, k),
            Elbow::Three(..) => (Real::NEG_INFINITY, Real::INFINITY),
        };
        Ok(Limb {
            upper,
            lower,
            upper_order,
            upper_rot_dofs,
            elbow_axis,
            elbow,
            d1,
            d2,
            l1,
            l2,
            corners,
            center,
            limits,
            elbow_limit,
            c_upper: RealQuat::from_mat3(&u.axis_rotation_f64()).normalize(),
            swivel_reference: {
                let rest = (d1 * l1 + d2 * l2).normalize_or_zero();
                if rest.dot(RealVec3::Y).abs() <= rest.dot(RealVec3::Z).abs() {
                    RealVec3::NEG_Y
                } else {
                    RealVec3::NEG_Z
                }
            },
            chain: ancestors(skeleton, lower),
            limit_forms: LimitForms::new(upper_order, &limits),
        })
    }

    /// The swivel angle of the limb as posed in `channels` (eq. 18–22, the convention of
    /// [`Swivel::Fixed`]): the angle of the elbow axis about the shoulder–effector line,
    /// from `û`. Solving for
    /// the present effector position with `Swivel::Fixed` of this angle gives the same pose
    /// back, which is how an edit keeps a capture's knee or elbow direction.
    #[must_use]
    pub fn swivel_of(&self, skeleton: &Skeleton, channels: &[Real]) -> Real {
        let mut pose = Pose64::default();
        fk64_bones(skeleton, channels, &mut pose, &self.chain);
        let s = pose.start[self.upper];
        let n = (pose.tip[self.lower] - s).normalize_or_zero();
        if n == RealVec3::ZERO {
            return 0.0;
        }
        let parent_world = skeleton.bones()[self.upper]
            .parent()
            .map_or(RealMat3::IDENTITY, |p| pose.world(skeleton, p));
        let (u_hat, v_hat) = self.swivel_basis(parent_world, n);
        let k = pose.world(skeleton, self.upper) * self.elbow_axis;
        real::atan2(v_hat.dot(k), u_hat.dot(k))
    }

    /// The swivel circle's axes for the shoulder→target direction `n` (eq. 18–22): `û` is the
    /// limb's reference `â` (in the parent's frame) made perpendicular to `n`, `v̂ = n × û`.
    fn swivel_basis(&self, parent_world: RealMat3, n: RealVec3) -> (RealVec3, RealVec3) {
        let mut a = parent_world * self.swivel_reference;
        if length(n.cross(a)) < 1e-3 {
            // Within 0.06° of the reference: the other of −y and −z.
            let other = if self.swivel_reference == RealVec3::NEG_Y {
                RealVec3::NEG_Z
            } else {
                RealVec3::NEG_Y
            };
            a = parent_world * other;
        }
        let u_hat = normalize(a - n * a.dot(n));
        (u_hat, n.cross(u_hat))
    }

    /// Longest reach (shoulder to effector), file units.
    #[must_use]
    pub fn reach(&self) -> (Real, Real) {
        // |v1 + R(θ)v2| over θ: extremes of the closed form in `elbow_for_distance`.
        let (a, b, c) = self.coefficients();
        let amp = real::sqrt(b * b + c * c);
        let lo = real::sqrt((self.l1 * self.l1 + self.l2 * self.l2 + 2.0 * (a - amp)).max(0.0));
        let hi = real::sqrt(self.l1 * self.l1 + self.l2 * self.l2 + 2.0 * (a + amp));
        (lo, hi)
    }

    /// `v1·R(θ)v2 = A + B cos θ + C sin θ` for the elbow rotation about its axis.
    fn coefficients(&self) -> (Real, Real, Real) {
        let v1 = self.d1 * self.l1;
        let v2 = self.d2 * self.l2;
        let a = self.elbow_axis;
        let aa = v1.dot(a) * a.dot(v2);
        (aa, v1.dot(v2) - aa, v1.dot(a.cross(v2)))
    }

    /// Elbow angles giving shoulder–effector distance `dist` (eq. 16 generalised to any rest
    /// offset and axis): both branches, clamped to the reachable range.
    fn elbow_for_distance(&self, dist: Real) -> ([Real; 2], bool) {
        let (a, b, c) = self.coefficients();
        let k = 0.5 * (dist * dist - self.l1 * self.l1 - self.l2 * self.l2) - a;
        let amp = real::sqrt(b * b + c * c);
        let base = real::atan2(c, b);
        if amp < ROUNDING {
            return ([0.0, 0.0], (k.abs() < NEAR_ZERO));
        }
        let ratio = k / amp;
        let reachable = (-1.0 - ROUNDING..=1.0 + ROUNDING).contains(&ratio);
        let delta = real::acos(ratio.clamp(-1.0, 1.0));
        ([base + delta, base - delta], reachable)
    }

    fn elbow_rotation(&self, theta: Real) -> RealMat3 {
        crate::math::mat3_from_axis_angle(self.elbow_axis, theta)
    }

    /// Writes the elbow angle into the channels.
    fn set_elbow(&self, skeleton: &Skeleton, channels: &mut [Real], theta: Real) {
        let lo = &skeleton.bones()[self.lower];
        match self.elbow {
            Elbow::One(k) => channels[lo.first_channel() + k] = theta,
            Elbow::Three(order, ks) => {
                let c = lo.axis_rotation_f64();
                let m = c.transpose() * self.elbow_rotation(theta) * c;
                let prev = ks.map(|k| channels[lo.first_channel() + k]);
                let a = euler_near(order, &m, prev);
                for (j, k) in ks.iter().enumerate() {
                    channels[lo.first_channel() + k] = a[j];
                }
            }
        }
    }

    /// [`Limb::shoulder_angles_near`] the limit range's centre.
    fn shoulder_angles(&self, m: &RealMat3) -> ([Real; 3], Real) {
        self.shoulder_angles_near(m, &self.center)
    }

    /// Euler angles of a shoulder rotation `M = Cᵀ·Q·C` (the bone's own frame) and their limit
    /// violation: of the two Euler solutions (each angle taken modulo 2π next to its limit
    /// range), the one violating the limits least, then the one nearest `reference` (the
    /// present angles, so a stream does not flip between equivalent solutions).
    fn shoulder_angles_near(&self, m: &RealMat3, reference: &[Real; 3]) -> ([Real; 3], Real) {
        legal_euler(self.upper_order, m, &self.limits, &self.center, reference)
    }

    /// Solves the limb so that the lower bone's tip reaches `target` (world, file units),
    /// writing the shoulder and elbow channels. The parents' pose is taken from `channels`.
    pub fn solve(
        &self,
        skeleton: &Skeleton,
        channels: &mut [Real],
        target: RealVec3,
        swivel: Swivel,
    ) -> LimbSolution {
        // A non-finite swivel means none given.
        let swivel = match swivel {
            Swivel::Fixed(p) | Swivel::Nearest(p) | Swivel::Track { previous: p, .. } if !p.is_finite() => {
                Swivel::Auto { previous: None }
            }
            Swivel::Track { window, .. } if !(window.is_finite() && window > 0.0) => {
                Swivel::Auto { previous: None }
            }
            Swivel::Track { previous, window } => Swivel::Track {
                previous: swivel::wrap(previous),
                window: real::min(window, crate::math::consts::PI),
            },
            Swivel::Nearest(p) => Swivel::Nearest(swivel::wrap(p)),
            Swivel::Fixed(p) => Swivel::Fixed(swivel::wrap(p)),
            Swivel::Auto { previous } => Swivel::Auto {
                previous: previous.filter(|p| p.is_finite()).map(swivel::wrap),
            },
        };
        // FK down the limb's chain (a path from the root) to the shoulder's parent, keeping
        // only the last bone's frame and tip; then where the shoulder starts.
        let ub = &skeleton.bones()[self.upper];
        let mut above: Option<(RealMat3, RealVec3)> = None;
        for &b in self.chain.iter().take_while(|&&b| b != self.upper) {
            let (frame, _, tip) = fk64_step(skeleton, channels, b, above.as_ref().map(|(f, t)| (f, *t)));
            above = Some((frame, tip));
        }
        let parent = above.as_ref().map(|(f, t)| (f, *t));
        let s = fk64_start(skeleton, channels, self.upper, parent);
        let parent_world = match (ub.parent(), parent) {
            (Some(p), Some((f, _))) => world_of(skeleton, p, f),
            _ => RealMat3::IDENTITY,
        };
        let mut to_target = target - s;
        // The limb's present direction (zero when its channels hold garbage): the fallback for
        // a target that is not finite, or one at the shoulder; the limb's FK only then.
        let dist = length(to_target);
        let degenerate = !(dist.is_finite() && dist >= precision(1e-6, 1e-4));
        let present_dir = if degenerate {
            let (upper_frame, _, upper_tip) = fk64_step(skeleton, channels, self.upper, parent);
            let (_, _, tip) = fk64_step(skeleton, channels, self.lower, Some((&upper_frame, upper_tip)));
            let d = tip - s;
            if d.is_finite() {
                d
            } else {
                RealVec3::ZERO
            }
        } else {
            // (Not read: `shoulder_for` falls back to it only for a degenerate target.)
            RealVec3::ZERO
        };
        let dist = if to_target.is_finite() {
            dist
        } else {
            to_target = present_dir;
            length(to_target)
        };
        // Elbow (steps 1–3): the branch inside the elbow limit, nearest the present angle.
        let present = match self.elbow {
            Elbow::One(k) => channels[skeleton.bones()[self.lower].first_channel() + k],
            Elbow::Three(..) => 0.0,
        };
        let (lo, hi) = self.elbow_limit;
        let present = if present.is_finite() {
            present.clamp(lo.max(-1e3), hi.min(1e3))
        } else {
            0.0
        };
        let (cands, reachable) = self.elbow_for_distance(dist);
        let mut best = (Real::INFINITY, 0.0, false);
        let mut inside_angles: heapless::Vec<Real, 6> = heapless::Vec::new();
        for c in cands {
            for turn in [-1.0, 0.0, 1.0] {
                let t = c + turn * crate::math::consts::TAU;
                let inside = t >= lo - ROUNDING && t <= hi + ROUNDING;
                let clamped = real::clamp(t, lo, hi);
                if inside {
                    let _ = inside_angles.push(clamped);
                }
                // Inside the limit first, nearest the present angle; else least outside.
                let cost = if inside {
                    (t - present).abs()
                } else {
                    1e9 + (clamped - t).abs()
                };
                if cost < best.0 {
                    best = (cost, clamped, inside);
                }
            }
        }
        let other_branch = inside_angles
            .iter()
            .copied()
            .filter(|t| (t - best.1).abs() > NEAR_ZERO)
            .min_by(|a, b| (a - present).abs().total_cmp(&(b - present).abs()));
        // The present shoulder angles (the centre of the limits when they are garbage).
        let mut reference = self.center;
        for (j, k) in self.upper_rot_dofs.iter().enumerate() {
            let x = channels[ub.first_channel() + k];
            if x.is_finite() && x.abs() < 100.0 {
                reference[j] = x;
            }
        }
        // Candidates sorted by cost: the first is the branch nearest the present angle; the
        // next admissible one is tried when the first leaves no legal swivel.
        let (theta, elbow_ok) = (best.1, best.2);
        let (mut phi, mut angles, mut violation) =
            self.shoulder_for(theta, parent_world, to_target, present_dir, swivel, &reference);
        let (mut theta, mut elbow_ok) = (theta, elbow_ok);
        if violation > ROUNDING {
            if let Some(other) = other_branch {
                let (p2, a2, v2) =
                    self.shoulder_for(other, parent_world, to_target, present_dir, swivel, &reference);
                if v2 < violation {
                    (phi, angles, violation, theta, elbow_ok) = (p2, a2, v2, other, true);
                }
            }
        }
        let inside = violation <= ROUNDING;
        let first = ub.first_channel();
        for (j, k) in self.upper_rot_dofs.iter().enumerate() {
            // A legal solution is legal exactly (rounding may leave it `ROUNDING` outside).
            channels[first + k] = if inside {
                real::clamp(angles[j], self.limits[j].0, self.limits[j].1)
            } else {
                angles[j]
            };
        }
        self.set_elbow(skeleton, channels, theta);
        // The ancestors' pose stands: only the limb's two bones moved.
        let (upper_frame, _, upper_tip) = fk64_step(skeleton, channels, self.upper, parent);
        let tip = fk64_tip(skeleton, channels, self.lower, Some((&upper_frame, upper_tip)));
        let error = length(tip - target);
        LimbSolution {
            reachable: reachable && error.is_finite(),
            error: if error.is_finite() { error } else { Real::INFINITY },
            swivel: wrap_near(phi, 0.0),
            upper_within_limits: inside,
            elbow_within_limits: elbow_ok,
            violation,
        }
    }
    /// Steps 4–8 for elbow angle `theta`: the swivel (given, or searched inside the limits,
    /// eq. 27–30) and the shoulder's Euler angles with their limit violation.
    fn shoulder_for(
        &self,
        theta: Real,
        parent_world: RealMat3,
        to_target: RealVec3,
        present_dir: RealVec3,
        swivel: Swivel,
        reference: &[Real; 3],
    ) -> (Real, [Real; 3], Real) {
        let w0 = self.d1 * self.l1 + self.elbow_rotation(theta) * (self.d2 * self.l2);
        // Direction to the target in the parent's rest coordinates (degenerate: keep the limb's
        // present direction).
        let mut d = parent_world.transpose() * to_target;
        if !d.is_finite() || length(d) < 1e-9 {
            d = parent_world.transpose() * present_dir;
            if !d.is_finite() || length(d) < 1e-9 {
                d = w0;
            }
        }
        let dhat = normalize(d);
        let base_q = rotation_between(w0, dhat);
        let base = RealMat3::from_quat(base_q);
        // Swivel convention (eq. 18–22): n̂ towards the target, û from the limb's â.
        let n_world = parent_world * dhat;
        let (u_hat, v_hat) = self.swivel_basis(parent_world, n_world);
        // The swivel is read from the elbow axis, which a straight limb defines too (the elbow
        // position does not).
        let elbow_phi = |q: &RealMat3| {
            let k = parent_world * (*q * self.elbow_axis);
            real::atan2(v_hat.dot(k), u_hat.dot(k))
        };
        let phi0 = elbow_phi(&base);
        // The shoulder rotation in the bone's own frame, `Cᵀ·Q(φ)·C` (eq. 23–26), as a
        // quaternion.
        let c_upper = self.c_upper;
        let local_q = |phi: Real| {
            c_upper.conjugate() * crate::math::quat_from_axis_angle(dhat, phi - phi0) * base_q * c_upper
        };
        let local = |phi: Real| RealMat3::from_quat(local_q(phi));
        // The swivel circle in closed form: legal arcs and eq. 30's global minimum over them
        // ([`crate::swivel`]); the sampled search below stays for what it cannot settle (no
        // legal swivel, an arc list too long, a result the Euler extraction disagrees with).
        if !matches!(swivel, Swivel::Fixed(_)) {
            if let Some((phi, angles, violation)) =
                self.closed_form_swivel(c_upper, base_q, dhat, phi0, swivel, reference)
            {
                if violation <= ROUNDING {
                    return (phi, angles, violation);
                }
            }
        }
        // Legal: inside the limits up to rounding.
        let legal = |v: Real| v <= ROUNDING;
        // Bisection between a legal and an illegal swivel: the legal one next to the limit.
        let to_boundary = |mut good: Real, mut bad: Real| {
            for _ in 0..30 {
                let mid = 0.5 * (good + bad);
                if legal(self.shoulder_angles(&local(mid)).1) {
                    good = mid;
                } else {
                    bad = mid;
                }
            }
            good
        };
        // The swivel's score and the shoulder's limit violation.
        let eval = |phi: Real, previous: Option<Real>| {
            let quat = local_q(phi);
            let (_, v) = self.shoulder_angles(&RealMat3::from_quat(quat));
            // Eq. (30): summed distance (eq. 27–28) to the corners of the limit region.
            let spread: Real = self.corners.iter().map(|c| quat_distance_fast(quat, *c)).sum();
            let keep = previous.map_or(0.0, |p| {
                let d = wrap_near(phi, p) - p;
                0.5 * d * d
            });
            // Inside the limits first (eq. 30's centrality among legal swivels), else least
            // violation.
            let penalty = if legal(v) { 0.0 } else { 1e3 * (1.0 + v) };
            (penalty + spread + keep, v)
        };
        let phi = match swivel {
            Swivel::Fixed(p) => p,
            Swivel::Nearest(p) => {
                let violation = |p: Real| self.shoulder_angles(&local(p)).1;
                let v0 = violation(p);
                if legal(v0) {
                    p
                } else {
                    // Outwards in 2° steps both ways to the first legal sample, then bisection
                    // to the limit boundary; with none legal, the least violating sample.
                    let step = crate::math::consts::PI / 90.0;
                    let mut found = None;
                    let mut least = (v0, p);
                    'scan: for i in 1..=90 {
                        for sign in [1.0, -1.0] {
                            let q = p + sign * step * (i as Real);
                            let v = violation(q);
                            if legal(v) {
                                found = Some((q, q - sign * step));
                                break 'scan;
                            }
                            if v < least.0 {
                                least = (v, q);
                            }
                        }
                    }
                    match found {
                        Some((good, bad)) => to_boundary(good, bad),
                        None => golden(violation, least.1 - step, least.1 + step, SWIVEL_TOLERANCE),
                    }
                }
            }
            Swivel::Track { previous, window } => {
                const M: usize = 9;
                let step = 2.0 * window / (M - 1) as Real;
                let mut best = (Real::INFINITY, previous);
                let mut best_legal: Option<(Real, Real)> = None;
                for i in 0..M {
                    let p = previous - window + step * i as Real;
                    let (f, v) = eval(p, Some(previous));
                    if f < best.0 {
                        best = (f, p);
                    }
                    if legal(v) && best_legal.is_none_or(|(bf, _)| f < bf) {
                        best_legal = Some((f, p));
                    }
                }
                match best_legal {
                    None => {
                        return self.shoulder_for(
                            theta,
                            parent_world,
                            to_target,
                            present_dir,
                            Swivel::Auto {
                                previous: Some(previous),
                            },
                            reference,
                        )
                    }
                    Some((_, inside)) => {
                        let lo = (best.1 - step).max(previous - window);
                        let hi = (best.1 + step).min(previous + window);
                        let found = golden(|p| eval(p, Some(previous)).0, lo, hi, 1e-3);
                        if legal(self.shoulder_angles(&local(found)).1) {
                            found
                        } else {
                            to_boundary(inside, found)
                        }
                    }
                }
            }
            Swivel::Auto { previous } => {
                // Coarse scan of the swivel circle, then golden-section refinement (step 7).
                const N: usize = SWIVEL_SAMPLES as usize;
                let step = crate::math::consts::TAU / N as Real;
                let mut best = (Real::INFINITY, 0.0);
                let mut best_legal: Option<(Real, Real)> = None;
                let mut sampled = [(0.0 as Real); N];
                let violation = |p: Real| self.shoulder_angles(&local(p)).1;
                for (i, v_out) in sampled.iter_mut().enumerate() {
                    let p = -crate::math::consts::PI + step * i as Real;
                    let (f, v) = eval(p, previous);
                    *v_out = v;
                    if f < best.0 {
                        best = (f, p);
                    }
                    if legal(v) && best_legal.is_none_or(|(bf, _)| f < bf) {
                        best_legal = Some((f, p));
                    }
                }
                let found = golden(|p| eval(p, previous).0, best.1 - step, best.1 + step, 1e-4);
                match best_legal {
                    // The optimum lies on the limit boundary: step back inside, towards the
                    // best legal sample, by bisection on legality.
                    Some((_, inside)) if !legal(violation(found)) => to_boundary(inside, found),
                    Some(_) => found,
                    // No legal sample: a legal arc, if there is one, is narrower than the scan
                    // step (near the shoulder's gimbal lock). Minimise the violation itself
                    // around the lowest local minima of the samples.
                    None => {
                        let mut result = (violation(found), found);
                        let mut minima: heapless::Vec<(Real, usize), N> = heapless::Vec::new();
                        for i in 0..N {
                            let (before, after) = (sampled[(i + N - 1) % N], sampled[(i + 1) % N]);
                            if sampled[i] <= before && sampled[i] <= after {
                                let _ = minima.push((sampled[i], i));
                            }
                        }
                        sort_by_real(&mut minima, |m| m.0);
                        for &(_, i) in minima.iter().take(3) {
                            let centre = -crate::math::consts::PI + step * i as Real;
                            let p = golden(violation, centre - step, centre + step, SWIVEL_TOLERANCE);
                            let v = violation(p);
                            if v < result.0 {
                                result = (v, p);
                            }
                            if legal(result.0) {
                                break;
                            }
                        }
                        result.1
                    }
                }
            }
        };
        let (angles, violation) = self.shoulder_angles_near(&local(phi), reference);
        (phi, angles, violation)
    }
}

impl Limb {
    /// The swivel of a non-fixed `swivel` from the closed-form circle: `q(ψ) = cos(ψ/2)·P +
    /// sin(ψ/2)·Q` with `P = Cᵀ·B·C`, `Q = Cᵀ·n̂·B·C` (`B` the base rotation, `n̂` the
    /// shoulder–target axis as a pure quaternion, `ψ = φ − φ₀`), with the shoulder's Euler
    /// angles there (nearest `reference`) and their violation. `None` when there is no legal
    /// swivel or the arcs do not fit.
    fn closed_form_swivel(
        &self,
        c: RealQuat,
        base: RealQuat,
        axis: RealVec3,
        phi0: Real,
        swivel: Swivel,
        reference: &[Real; 3],
    ) -> Option<(Real, [Real; 3], Real)> {
        let n = RealQuat::from_xyzw(axis.x, axis.y, axis.z, 0.0);
        let p = c.conjugate() * base * c;
        let q = c.conjugate() * n * base * c;
        let circle = SwivelCircle::new(p, q, &self.corners);
        // The swivel `φ` of `ψ`, the Euler angles there and their violation: legal as the
        // Euler extraction reads it (exact).
        let at = |psi: Real| {
            let (s, c) = real::sincos(0.5 * psi);
            let (angles, violation) =
                self.shoulder_angles_near(&RealMat3::from_quat(p * c + q * s), reference);
            (wrap_near(psi + phi0, 0.0), angles, violation)
        };
        match swivel {
            // A stream: the optimum within the window, when legal, is the optimum over the
            // legal swivels there — no arcs needed.
            Swivel::Track { previous, window } => {
                let keep = Some(previous - phi0);
                let free = circle.minimise(&swivel::window(previous - phi0, window), keep)?;
                let solution = at(free);
                if solution.2 <= ROUNDING {
                    return Some(solution);
                }
            }
            Swivel::Nearest(p) => {
                let solution = at(p - phi0);
                if solution.2 <= ROUNDING {
                    return Some((p, solution.1, solution.2));
                }
            }
            _ => {}
        }
        let legal = circle.legal_arcs(&self.limit_forms)?;
        if legal.is_empty() {
            return None;
        }
        let psi = match swivel {
            Swivel::Fixed(p) => p - phi0,
            Swivel::Nearest(p) => swivel::nearest(&legal, p - phi0)?,
            Swivel::Auto { previous } => circle.minimise(&legal, previous.map(|p| p - phi0))?,
            Swivel::Track { previous, window } => {
                let keep = Some(previous - phi0);
                let near = swivel::intersect(&legal, &swivel::window(previous - phi0, window))?;
                // Nothing legal in the window: the whole circle, as the sampled search does.
                circle.minimise(if near.is_empty() { &legal } else { &near }, keep)?
            }
        };
        Some(at(psi))
    }
}

/// Euler angles of the local rotation `m` in `order` and their summed excess over `limits`: of
/// the two Euler solutions, each angle taken in the turn nearest `centre`, the one violating the
/// limits least, then the one nearest `reference`.
fn legal_euler(
    order: EulerOrder,
    m: &RealMat3,
    limits: &[(Real, Real); 3],
    centre: &[Real; 3],
    reference: &[Real; 3],
) -> ([Real; 3], Real) {
    let a = order.from_mat3_f64(m);
    let pi = crate::math::consts::PI;
    let b2 = if order.is_proper() { -a[1] } else { pi - a[1] };
    let mut best = ([0.0; 3], Real::INFINITY, Real::INFINITY);
    for cand in [a, [a[0] + pi, b2, a[2] + pi]] {
        let (mut w, mut v, mut off) = ([0.0; 3], 0.0, 0.0);
        for k in 0..3 {
            w[k] = wrap_near(cand[k], centre[k]);
            v += real::max(limits[k].0 - w[k], 0.0) + real::max(w[k] - limits[k].1, 0.0);
            off += (w[k] - reference[k]).abs();
        }
        if v < best.1 - ROUNDING || (v <= best.1 + ROUNDING && off < best.2) {
            best = (w, v, off);
        }
    }
    (best.0, best.1)
}

/// What [`point_bone`] achieved.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pointing {
    /// Angle between the bone's direction and the asked one afterwards, radians.
    pub direction_error: Real,
    /// Summed excess of the bone's angles over their ASF limits, radians (0: legal). The
    /// angles are written as solved, not clamped.
    pub violation: Real,
}

/// Why [`point_bone`] cannot point a bone.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum PointError {
    /// The bone does not have three rotation DOFs (use the numerical solvers).
    Needs3Dofs,
    /// The bone has zero length or no direction.
    NoDirection,
    /// The asked direction is zero or not finite.
    BadDirection,
}

impl core::fmt::Display for PointError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            PointError::Needs3Dofs => "the bone needs rx ry rz to be pointed (use a numerical method)",
            PointError::NoDirection => "the bone has zero length or no direction",
            PointError::BadDirection => "the direction is zero or not finite",
        })
    }
}

impl core::error::Error for PointError {}

/// Eq. (31)–(34): turns a 3-DOF bone (a wrist, a neck) so that it points along `direction`
/// (world) rolled by `roll` radians about it. With `A = Wₚ·C` (parent world times the bone's
/// rest frame) and `V̂ₕ = Cᵀ·d` the rest direction in the bone's frame, the local rotation is
/// `M = ΔR·R_roll(θ, V̂ₕ)` where `ΔR` is the shortest rotation from `V̂ₕ` to `Aᵀ·V̂_hd`
/// (eq. 32–33 written in the bone's frame) and the roll turns about the local pointing axis
/// (eq. 34). `M` is written as the bone's Euler angles, of the equivalent solutions the one
/// nearest the present angles. The parents' pose is taken from `channels`.
///
/// # Errors
/// [`PointError`].
pub fn point_bone(
    skeleton: &Skeleton,
    channels: &mut [Real],
    bone: usize,
    direction: RealVec3,
    roll: Real,
) -> Result<Pointing, PointError> {
    let b = skeleton.bones().get(bone).ok_or(PointError::Needs3Dofs)?;
    let order = dof_order(b.dofs()).ok_or(PointError::Needs3Dofs)?;
    let ks = rot_dofs(b.dofs());
    if ks.len() != 3 {
        return Err(PointError::Needs3Dofs);
    }
    let rest = b.direction_f64();
    if rest == RealVec3::ZERO || b.length() <= 0.0 {
        return Err(PointError::NoDirection);
    }
    if !direction.is_finite() || direction.length() < 1e-12 || !roll.is_finite() {
        return Err(PointError::BadDirection);
    }
    let mut pose = Pose64::default();
    fk64_bones(skeleton, channels, &mut pose, &ancestors(skeleton, bone));
    let c = b.axis_rotation_f64();
    let a = pose.axes(skeleton, bone);
    let v_h = c.transpose() * rest;
    let wanted = (a.transpose() * direction.normalize()).normalize();
    let delta = RealMat3::from_quat(rotation_between(v_h, wanted));
    let m = delta * crate::math::mat3_from_axis_angle(v_h, real::remainder(roll, crate::math::consts::TAU));
    let first = b.first_channel();
    let present = [0, 1, 2].map(|j| {
        let x = channels[first + ks[j]];
        if x.is_finite() {
            x
        } else {
            0.0
        }
    });
    let limits = [0, 1, 2].map(|j| {
        b.limits()
            .get(ks[j])
            .map_or((Real::NEG_INFINITY, Real::INFINITY), |l| {
                ((l.min as Real), (l.max as Real))
            })
    });
    let centre = [0, 1, 2].map(|j| {
        let (lo, hi) = limits[j];
        if lo.is_finite() && hi.is_finite() {
            0.5 * (lo + hi)
        } else {
            present[j]
        }
    });
    let (angles, violation) = legal_euler(order, &m, &limits, &centre, &present);
    for (j, &k) in ks.iter().enumerate() {
        channels[first + k] = angles[j];
    }
    fk64_bones(skeleton, channels, &mut pose, &ancestors(skeleton, bone));
    let got = (pose.tip[bone] - pose.start[bone]).normalize_or_zero();
    let want = direction.normalize();
    let direction_error = real::atan2(got.cross(want).length(), got.dot(want));
    Ok(Pointing {
        direction_error,
        violation,
    })
}

/// Golden-section minimisation of `f` on `[a, b]`.
pub fn golden(mut f: impl FnMut(Real) -> Real, mut a: Real, mut b: Real, tol: Real) -> Real {
    let r = 0.5 * (real::sqrt(5.0) - 1.0);
    let mut c = b - r * (b - a);
    let mut d = a + r * (b - a);
    let (mut fc, mut fd) = (f(c), f(d));
    for _ in 0..200 {
        if (b - a).abs() < tol {
            break;
        }
        if fc < fd {
            b = d;
            d = c;
            fd = fc;
            c = b - r * (b - a);
            fc = f(c);
        } else {
            a = c;
            c = d;
            fc = fd;
            d = a + r * (b - a);
            fd = f(d);
        }
    }
    0.5 * (a + b)
}
