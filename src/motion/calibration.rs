//! A converter's calibration pose written as a clip's first frame.
//!
//! The MotionBuilder-friendly BVH conversions of the CMU database (`data/cmu/01_01.bvh`, and
//! the clips most people download) begin with the converter's T-pose: the root unturned, every
//! joint at a whole number of degrees (most at zero, the upper arms at ±17–21°), the root's
//! position copied from the next frame, and the capture only from the second frame on. Played,
//! that frame is a jump into the first captured pose at thousands of degrees a second; taken
//! for capture dropouts, it is only half repaired (the joints reading zero filled, the arms
//! left out sideways).
//!
//! [`first_frame`] recognises it, [`leave_out`] drops it. Captured frames carry decimals: a frame whose every rotation
//! is a whole degree, root unturned, standing still where the next frame stands but far from its
//! pose, is no capture.

use super::dropouts::MIN_JUMP_DEG;
use super::Motion;
use crate::skeleton::Skeleton;

/// A first frame that is a calibration pose, not motion.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CalibrationFrame {
    /// The largest rotation change to the next frame, degrees.
    pub jump_deg: f64,
    /// The same as a speed at the clip's frame rate, degrees per second.
    pub speed_dps: f64,
}

impl std::fmt::Display for CalibrationFrame {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "frame 1 is a calibration pose, not capture (root unturned, every joint at a whole degree, {:.0}° from frame 2: {:.0}°/s)",
            self.jump_deg, self.speed_dps
        )
    }
}

/// The clip's first frame when it is a converter's calibration pose (module documentation).
#[must_use]
pub fn first_frame(skeleton: &Skeleton, motion: &Motion) -> Option<CalibrationFrame> {
    if motion.len() < 2 {
        return None;
    }
    let (pose, next) = (motion.frame(0), motion.frame(1));
    let mut rotations = Vec::new();
    for (b, bone) in skeleton.bones().iter().enumerate() {
        for (c, d) in bone.channels().zip(bone.dofs()) {
            if d.is_rotation() {
                rotations.push((b == 0, c));
            } else if b == 0 && pose[c] != next[c] {
                // The root moves between the two frames: captured.
                return None;
            }
        }
    }
    let whole = |v: f64| v.is_finite() && v == v.round();
    let root_unturned = rotations
        .iter()
        .filter(|(root, _)| *root)
        .all(|&(_, c)| pose[c] == 0.0);
    let all_whole = rotations.iter().all(|&(_, c)| whole(pose[c]));
    let next_captured = rotations.iter().any(|&(_, c)| !whole(next[c]));
    let jump_deg = rotations
        .iter()
        .map(|&(_, c)| (pose[c] - next[c]).abs())
        .fold(0.0, f64::max);
    (root_unturned && all_whole && next_captured && jump_deg >= MIN_JUMP_DEG).then_some(CalibrationFrame {
        jump_deg,
        speed_dps: jump_deg * motion.frame_rate,
    })
}

/// Leaves out the clip's first frame when it is a converter's calibration pose; returns what
/// was found.
pub fn leave_out(skeleton: &Skeleton, motion: &mut Motion) -> Option<CalibrationFrame> {
    let found = first_frame(skeleton, motion)?;
    *motion = motion.slice(1..motion.len());
    Some(found)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::formats::asf;

    fn walk() -> (Skeleton, Motion) {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("data/cmu");
        let skeleton = asf::load(&dir.join("16.asf")).unwrap().skeleton;
        let motion = crate::formats::amc::load(&skeleton, &dir.join("16_15.amc")).unwrap();
        (skeleton, motion)
    }

    /// The walk with the converter's T-pose written before it: zeros, the upper arms at ±21°,
    /// the root standing where the capture starts.
    fn with_t_pose(skeleton: &Skeleton, motion: &Motion) -> Motion {
        let mut out = Motion::new(motion.channel_count(), motion.frame_rate);
        let first = motion.frame(0).to_vec();
        let pose = out.push_rest_frame();
        let root = &skeleton.bones()[0];
        for (c, d) in root.channels().zip(root.dofs()) {
            if !d.is_rotation() {
                pose[c] = first[c];
            }
        }
        for (name, v) in [("lhumerus", -21.0), ("rhumerus", 21.0)] {
            let b = &skeleton.bones()[skeleton.find(name).unwrap()];
            pose[b.channels().next().unwrap()] = v;
        }
        for f in motion.frames() {
            out.push_frame(f);
        }
        out
    }

    #[test]
    fn a_t_pose_before_the_capture_is_found_and_a_captured_first_frame_is_not() {
        let (skeleton, motion) = walk();
        assert_eq!(first_frame(&skeleton, &motion), None);
        let posed = with_t_pose(&skeleton, &motion);
        let found = first_frame(&skeleton, &posed).expect("the T-pose");
        assert!(found.jump_deg > 60.0, "{found:?}");
        assert!((found.speed_dps - found.jump_deg * 120.0).abs() < 1e-9);
        assert!(
            found.to_string().starts_with("frame 1 is a calibration pose"),
            "{found}"
        );
    }

    #[test]
    fn a_rest_pose_that_eases_into_motion_or_moves_its_root_is_motion() {
        let (skeleton, motion) = walk();
        let posed = with_t_pose(&skeleton, &motion);
        // The root moving between the two frames: captured.
        let mut moved = posed.clone();
        let root = &skeleton.bones()[0];
        let tx = root
            .channels()
            .zip(root.dofs())
            .find(|(_, d)| !d.is_rotation())
            .unwrap()
            .0;
        moved.frame_mut(0)[tx] += 0.5;
        assert_eq!(first_frame(&skeleton, &moved), None);
        // A generated clip that starts at rest and eases out of it: no jump.
        let mut eased = Motion::new(motion.channel_count(), 120.0);
        eased.push_rest_frame();
        let next = eased.push_rest_frame();
        next[root.channels().len() + 1] = 0.25;
        assert_eq!(first_frame(&skeleton, &eased), None);
        // One frame: nothing to compare.
        assert_eq!(first_frame(&skeleton, &posed.slice(0..1)), None);
    }
}
