//! A rig: which joint angle drives which servo, and how angles become ticks.
//!
//! A servo is driven by one of three sources: a skeleton channel (an AMC DOF such as
//! `lhumerus.rz`), one angle of a bone's local rotation re-decomposed into the rig's own Euler
//! order (help note §II, the YXZ→XYZ conversion, for any pair of the 12 orders), or a named
//! robot joint (an index into a joint-angle vector). Angles are radians throughout.

use crate::math::{real, Real, RealMat3};

use crate::math::{euler_near, EulerOrder};
use crate::servo::{ServoModel, MAX_SERVOS, TICKS_PER_TURN};
use crate::skeleton::{dof_rotation, Skeleton};

/// What drives a servo.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum JointSource {
    /// A skeleton channel (index into the frame vector).
    Channel(usize),
    /// Angle `slot` (0, 1 or 2) of bone `bone`'s local rotation written in `order`.
    Redecomposed {
        /// Bone index in the skeleton.
        bone: usize,
        /// The rig's axis order for this bone.
        order: EulerOrder,
        /// Which of the three angles.
        slot: usize,
    },
    /// Index into a robot's joint-angle vector.
    Joint(usize),
}

/// One servo of a rig, in the core's terms.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ServoMap {
    /// Bus id.
    pub id: u8,
    /// The servo model.
    pub model: &'static ServoModel,
    /// What drives it.
    pub source: JointSource,
    /// +1 or −1: whether a positive joint angle turns the horn the positive way.
    pub direction: Real,
    /// The tick that stands for joint angle 0.
    pub zero_tick: Real,
    /// Servo turns per joint turn (belts, linkages).
    pub gear: Real,
    /// Lowest allowed tick (software limit, inside the servo's range).
    pub min_tick: i32,
    /// Highest allowed tick.
    pub max_tick: i32,
    /// Most ticks per second the command may move.
    pub max_velocity: Real,
    /// Most ticks per second² the command may accelerate.
    pub max_acceleration: Real,
}

impl ServoMap {
    /// Ticks per radian of joint angle, signed by the direction.
    #[must_use]
    pub fn ticks_per_radian(&self) -> Real {
        self.direction * self.gear * (TICKS_PER_TURN as Real) / crate::math::consts::TAU
    }

    /// The exact (unrounded) tick for a joint angle.
    #[must_use]
    pub fn angle_to_ticks_exact(&self, angle: Real) -> Real {
        self.zero_tick + angle * self.ticks_per_radian()
    }

    /// The nearest whole tick for a joint angle (saturating at the i32 range; NaN gives 0 —
    /// the command stage rejects non-finite angles before this is used on a bus).
    #[must_use]
    pub fn angle_to_ticks(&self, angle: Real) -> i32 {
        real::round(self.angle_to_ticks_exact(angle)) as i32
    }

    /// The rest position: the tick of joint angle 0, inside the limits (where a run eases to
    /// when it stops).
    #[must_use]
    pub fn rest_tick(&self) -> i32 {
        self.angle_to_ticks(0.0).clamp(self.min_tick, self.max_tick)
    }

    /// The joint angle of a tick.
    #[must_use]
    pub fn ticks_to_angle(&self, ticks: Real) -> Real {
        (ticks - self.zero_tick) / self.ticks_per_radian()
    }
}

/// A rig's servos over a skeleton (or a robot's joint vector).
#[derive(Clone, Debug, Default)]
pub struct Rig {
    /// The servos in bus order.
    pub servos: heapless::Vec<ServoMap, MAX_SERVOS>,
}

impl Rig {
    /// Number of servos.
    #[must_use]
    pub fn len(&self) -> usize {
        self.servos.len()
    }

    /// True when the rig has no servos.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.servos.is_empty()
    }

    /// Joint angles (radians) for every servo from a skeleton frame vector (rotations in
    /// radians) and an optional robot joint vector.
    ///
    /// `angles` holds the previous angles on entry: re-decomposed angles are chosen next to
    /// them (of the two Euler solutions and their 2π turns), so a stream stays continuous.
    /// Sources that index past `channels` or `joints` give NaN, which the command stage
    /// rejects.
    pub fn joint_angles(&self, skeleton: &Skeleton, channels: &[Real], joints: &[Real], angles: &mut [Real]) {
        // Servos on the same bone and order share one decomposition, computed when the first
        // of them is met (while the others still hold their previous angles).
        let mut solved: heapless::Vec<(usize, EulerOrder, [Real; 3]), MAX_SERVOS> = heapless::Vec::new();
        for k in 0..self.servos.len().min(angles.len()) {
            angles[k] = match self.servos[k].source {
                JointSource::Channel(c) => channels.get(c).copied().unwrap_or(Real::NAN),
                JointSource::Joint(j) => joints.get(j).copied().unwrap_or(Real::NAN),
                JointSource::Redecomposed { bone, order, slot } => {
                    if let Some((_, _, a)) = solved.iter().find(|(b, o, _)| *b == bone && *o == order) {
                        a[slot]
                    } else if let Some(m) = bone_rotation(skeleton, bone, channels) {
                        let mut reference = [0.0; 3];
                        for (servo, prev) in self.servos.iter().zip(angles.iter()).skip(k) {
                            if let JointSource::Redecomposed {
                                bone: b,
                                order: o,
                                slot: s,
                            } = servo.source
                            {
                                if b == bone && o == order && prev.is_finite() {
                                    reference[s] = *prev;
                                }
                            }
                        }
                        let a = euler_near(order, &m, reference);
                        // Capacity equals MAX_SERVOS, so this never fails.
                        let _ = solved.push((bone, order, a));
                        a[slot]
                    } else {
                        Real::NAN
                    }
                }
            };
        }
    }
}

impl Rig {
    /// The skeleton frame a pose of the servos stands for: `source` (the frame they were driven
    /// from, radians) with each servo's channel replaced by its angle `angles[k]` — a channel
    /// directly; a re-decomposed bone's rotation recomposed in the rig's order from its servos'
    /// angles (slots no servo drives kept from the source) and written back in the bone's own
    /// DOF order (bones with fewer than three rotation DOFs keep the source). The inverse of
    /// [`Rig::joint_angles`], for comparing what the servos do with what they were asked.
    pub fn channels_from_angles(
        &self,
        skeleton: &Skeleton,
        angles: &[Real],
        source: &[Real],
        out: &mut [Real],
    ) {
        let n = source.len().min(out.len());
        out[..n].copy_from_slice(&source[..n]);
        let mut done: heapless::Vec<(usize, EulerOrder), MAX_SERVOS> = heapless::Vec::new();
        for (k, servo) in self.servos.iter().enumerate() {
            let Some(&angle) = angles.get(k) else { break };
            match servo.source {
                JointSource::Channel(c) => {
                    if let Some(o) = out.get_mut(c) {
                        *o = angle;
                    }
                }
                JointSource::Joint(_) => {}
                JointSource::Redecomposed { bone, order, .. } => {
                    if done.contains(&(bone, order)) {
                        continue;
                    }
                    let _ = done.push((bone, order));
                    let (Some(b), Some(m)) =
                        (skeleton.bones().get(bone), bone_rotation(skeleton, bone, source))
                    else {
                        continue;
                    };
                    let mut a = euler_near(order, &m, [0.0; 3]);
                    for (j, s) in self.servos.iter().enumerate() {
                        if let JointSource::Redecomposed {
                            bone: b2,
                            order: o2,
                            slot,
                        } = s.source
                        {
                            if b2 == bone && o2 == order {
                                if let Some(v) = angles.get(j) {
                                    a[slot] = *v;
                                }
                            }
                        }
                    }
                    let Some(own) = crate::skeleton::dof_order(b.dofs()) else {
                        continue;
                    };
                    let rotations: heapless::Vec<usize, 3> = b
                        .dofs()
                        .iter()
                        .zip(b.channels())
                        .filter(|(d, _)| d.is_rotation())
                        .map(|(_, c)| c)
                        .collect();
                    let reference: [Real; 3] = core::array::from_fn(|i| {
                        rotations
                            .get(i)
                            .and_then(|c| source.get(*c))
                            .copied()
                            .unwrap_or(0.0)
                    });
                    let back = euler_near(own, &order.to_mat3_f64(a), reference);
                    for (i, c) in rotations.iter().enumerate() {
                        if let Some(o) = out.get_mut(*c) {
                            *o = back[i];
                        }
                    }
                }
            }
        }
    }
}

/// A bone's local rotation `M = R(last)·…·R(first)` from its rotation channels (radians), or
/// `None` when the frame is too short.
#[must_use]
pub fn bone_rotation(skeleton: &Skeleton, bone: usize, channels: &[Real]) -> Option<RealMat3> {
    let b = skeleton.bones().get(bone)?;
    Some(dof_rotation(
        b.dofs(),
        channels.get(b.channels())?.iter().copied(),
    ))
}

/// Re-writes angles given in `from` order as angles in `to` order (the same rotation), the
/// solution nearest `reference`. Help note §II's YXZ→XYZ conversion, for any two orders.
#[must_use]
pub fn redecompose(from: EulerOrder, angles: [Real; 3], to: EulerOrder, reference: [Real; 3]) -> [Real; 3] {
    euler_near(to, &from.to_mat3_f64(angles), reference)
}
