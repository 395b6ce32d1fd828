//! Forward kinematics, help note eq. (1)–(5), into caller-provided buffers: no allocation.
//!
//! For bone `i` with parent `p`, rest frame `C` (ASF `axis`, eq. 3) and channel rotation `M`
//! (the bone's rotation channels applied in `dof` order):
//!
//! * frame orientation `Fᵢ = Wₚ · C · M` — eq. (1) written with `ᵢR_asf = Cₚᵀ·C` (eq. 4)
//!   folded into `Wₚ = Fₚ · Cₚᵀ`;
//! * start `Tᵢ` = the parent's tip (plus `Wₚ·C·t` for translation channels), tip
//!   `Tᵢ + (L + l) · Fᵢ · Cᵀ·d` — eq. (2) with the local direction of eq. (5).
//!
//! The root: `W₀ = O · M₀` where `O` is the `:root orientation` (rotating the whole skeleton)
//! and `M₀` its rotation channels; position = `:root position` + translation channels.

use crate::skeleton::{Dof, Skeleton, MAX_BONES};
use glam::{Mat3, Vec3};

/// Global state of every bone for one frame.
#[derive(Clone, Debug)]
pub struct Pose {
    /// Where each bone starts (its joint), file units. The root: its position.
    pub start: [Vec3; MAX_BONES],
    /// Where each bone ends, file units. The root: its position.
    pub tip: [Vec3; MAX_BONES],
    /// The orientation of each bone's local frame in global coordinates, `Fᵢ = ⁱ₀R`.
    pub frame: [Mat3; MAX_BONES],
    /// The rotation each bone applies to global rest vectors, `Wᵢ = Fᵢ·Cᵢᵀ`.
    pub world: [Mat3; MAX_BONES],
}

impl Default for Pose {
    fn default() -> Self {
        Pose::new()
    }
}

impl Pose {
    /// All zeros.
    #[must_use]
    pub const fn new() -> Pose {
        Pose {
            start: [Vec3::ZERO; MAX_BONES],
            tip: [Vec3::ZERO; MAX_BONES],
            frame: [Mat3::IDENTITY; MAX_BONES],
            world: [Mat3::IDENTITY; MAX_BONES],
        }
    }
}

/// The frame vector is shorter than the skeleton's channel count.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ShortFrame {
    /// Channels the skeleton needs.
    pub needed: usize,
    /// Channels given.
    pub given: usize,
}

impl core::fmt::Display for ShortFrame {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(
            f,
            "frame has {} channels, skeleton needs {}",
            self.given, self.needed
        )
    }
}

impl core::error::Error for ShortFrame {}

/// The rotation of a bone's channels, `M = R(last)·…·R(first)`, and its translation and
/// length channels.
#[inline]
#[must_use]
pub fn channel_transform(dofs: &[Dof], values: &[f32]) -> (Mat3, Vec3, f32) {
    let mut m = Mat3::IDENTITY;
    let mut t = Vec3::ZERO;
    let mut l = 0.0;
    for (d, &v) in dofs.iter().zip(values) {
        match d {
            Dof::Rx => m = Mat3::from_rotation_x(v) * m,
            Dof::Ry => m = Mat3::from_rotation_y(v) * m,
            Dof::Rz => m = Mat3::from_rotation_z(v) * m,
            Dof::Tx => t.x = v,
            Dof::Ty => t.y = v,
            Dof::Tz => t.z = v,
            Dof::L => l = v,
        }
    }
    (m, t, l)
}

/// Computes every bone's start, tip and orientation for one frame vector (radians, file
/// units), eq. (1)–(5).
///
/// # Errors
/// [`ShortFrame`] when `channels` is shorter than [`Skeleton::channel_count`].
pub fn forward_kinematics(skeleton: &Skeleton, channels: &[f32], pose: &mut Pose) -> Result<(), ShortFrame> {
    if channels.len() < skeleton.channel_count() {
        return Err(ShortFrame {
            needed: skeleton.channel_count(),
            given: channels.len(),
        });
    }
    for (i, bone) in skeleton.bones().iter().enumerate() {
        let (m, t, l) = channel_transform(bone.dofs(), &channels[bone.channels()]);
        match bone.parent() {
            None => {
                let w = bone.axis_rotation() * m;
                let p = skeleton.root().position + t;
                pose.frame[i] = w;
                pose.world[i] = w;
                pose.start[i] = p;
                pose.tip[i] = p;
            }
            Some(p) => {
                let c = bone.axis_rotation();
                let parent_axes = pose.world[p] * c;
                let f = parent_axes * m;
                let start = pose.tip[p] + parent_axes * t;
                pose.frame[i] = f;
                pose.world[i] = f * c.transpose();
                pose.start[i] = start;
                pose.tip[i] = start + f * (bone.local_direction() * (bone.length() + l));
            }
        }
    }
    Ok(())
}
