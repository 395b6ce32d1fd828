//! The embedded build of marionette's core: `no_std`, no heap, for Cortex-M
//! (`thumbv7em-none-eabihf`).
//!
//! It bundles the CMU subject-16 skeleton as text and reads it with the core ASF reader at
//! start-up, then computes forward kinematics per frame into a caller-owned [`Pose`]. Rig and
//! servo profiles live beside this crate in `firmware-profile/`.
#![no_std]
#![deny(unsafe_code)]
#![warn(missing_docs)]

pub use marionette::asf::{parse_asf, AsfError};
pub use marionette::fk::{forward_kinematics, Pose, ShortFrame};
pub use marionette::skeleton::{Skeleton, MAX_CHANNELS};

/// The bundled skeleton (CMU subject 16; see `data/cmu/README.md` for its attribution).
pub const BUNDLED_ASF: &str = include_str!("../../data/cmu/16.asf");

/// Reads the bundled skeleton.
///
/// # Errors
/// Never for the bundled file; the error type is the core reader's.
pub fn bundled_skeleton() -> Result<Skeleton, AsfError<'static>> {
    parse_asf(BUNDLED_ASF).map(|a| a.skeleton)
}

/// One frame (radians, file units) to bone positions: the core's FK, eq. (1)–(5).
///
/// # Errors
/// [`ShortFrame`] when the frame vector is shorter than the skeleton needs.
pub fn pose_frame(skeleton: &Skeleton, channels: &[f32], pose: &mut Pose) -> Result<(), ShortFrame> {
    forward_kinematics(skeleton, channels, pose)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bundled_skeleton_reads_and_poses() {
        let s = bundled_skeleton().unwrap();
        assert_eq!(s.len(), 31);
        let channels = [0.0f32; MAX_CHANNELS];
        let mut pose = Pose::new();
        pose_frame(&s, &channels, &mut pose).unwrap();
        // At rest the head is above the feet.
        let head = s.find("head").unwrap();
        let toes = s.find("ltoes").unwrap();
        assert!(pose.tip[head].y > pose.tip[toes].y + 20.0);
        assert!(pose_frame(&s, &channels[..10], &mut pose).is_err());
    }
}
