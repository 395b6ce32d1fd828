//! Capture dropouts: frames where a bone's rotation reads exactly zero on every degree of
//! freedom while the frames beside it are far away — what an optical capture writes when it
//! lost the bone's markers (CMU 16_15's left humerus reads 0, 0, 0 in its first two frames,
//! then −38.6°, 25.4°, 76.2°: 9,141°/s, which no arm does and no servo can follow).
//!
//! [`find`] lists them; [`repair`] fills each run from its valid neighbours: linear between
//! the two sides inside the clip, the nearest valid frame at its ends.

use super::Motion;
use crate::skeleton::Skeleton;

/// Smallest jump (degrees, on some rotation) between a zero frame and its valid neighbour for
/// the zeros to count as a dropout: at 120 Hz, 1,200°/s.
pub const MIN_JUMP_DEG: f64 = 10.0;

/// One run of dropped frames of one bone.
#[derive(Clone, Debug, PartialEq)]
pub struct Dropout {
    /// The bone's name.
    pub bone: String,
    /// First and last dropped frame (0-based indices into the motion).
    pub frames: (usize, usize),
    /// The largest jump to a valid neighbour, degrees per second.
    pub speed_dps: f64,
}

impl std::fmt::Display for Dropout {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (a, b) = self.frames;
        if a == b {
            write!(f, "{} frame {}", self.bone, a + 1)?;
        } else {
            write!(f, "{} frames {}–{}", self.bone, a + 1, b + 1)?;
        }
        write!(f, " read zero ({:.0}°/s to the next valid frame)", self.speed_dps)
    }
}

/// The rotation channels of bone `b` (file order), and whether every one is exactly zero in
/// frame `i`.
fn rotation_channels(skeleton: &Skeleton, b: usize) -> Vec<usize> {
    let bone = &skeleton.bones()[b];
    bone.channels()
        .zip(bone.dofs())
        .filter(|(_, d)| d.is_rotation())
        .map(|(c, _)| c)
        .collect()
}

fn all_zero(motion: &Motion, i: usize, channels: &[usize]) -> bool {
    channels.iter().all(|&c| motion.frame(i)[c] == 0.0)
}

fn jump(motion: &Motion, a: usize, b: usize, channels: &[usize]) -> f64 {
    channels
        .iter()
        .map(|&c| (motion.frame(a)[c] - motion.frame(b)[c]).abs())
        .fold(0.0, f64::max)
}

/// Every dropout of the clip's bones and of its root's rotation (a root reading zero while
/// the captured body faces elsewhere; its position is left as recorded). A converter's T-pose
/// written as the first frame is no dropout but no capture either: [`super::calibration`].
#[must_use]
pub fn find(skeleton: &Skeleton, motion: &Motion) -> Vec<Dropout> {
    let mut out = Vec::new();
    let n = motion.len();
    for b in 0..skeleton.len() {
        let channels = rotation_channels(skeleton, b);
        if channels.is_empty() {
            continue;
        }
        let mut i = 0;
        while i < n {
            if !all_zero(motion, i, &channels) {
                i += 1;
                continue;
            }
            let start = i;
            while i < n && all_zero(motion, i, &channels) {
                i += 1;
            }
            let end = i - 1;
            let before = start.checked_sub(1);
            let after = (i < n).then_some(i);
            let largest = [
                before.map(|p| jump(motion, p, start, &channels)),
                after.map(|q| jump(motion, q, end, &channels)),
            ]
            .into_iter()
            .flatten()
            .fold(0.0, f64::max);
            // A bone that rests at zero the whole clip, or eases out of zero, is no dropout.
            if largest >= MIN_JUMP_DEG {
                out.push(Dropout {
                    bone: skeleton.bones()[b].name().to_string(),
                    frames: (start, end),
                    speed_dps: largest * motion.frame_rate,
                });
            }
        }
    }
    out
}

/// Fills every dropout from its valid neighbours (module documentation); returns what it
/// repaired.
pub fn repair(skeleton: &Skeleton, motion: &mut Motion) -> Vec<Dropout> {
    let found = find(skeleton, motion);
    let n = motion.len();
    for d in &found {
        let Some(b) = skeleton.find(&d.bone) else { continue };
        let channels = rotation_channels(skeleton, b);
        let (start, end) = d.frames;
        let before = start.checked_sub(1);
        let after = (end + 1 < n).then_some(end + 1);
        for i in start..=end {
            for &c in &channels {
                let v = match (before, after) {
                    (Some(p), Some(q)) => {
                        let t = (i - p) as f64 / (q - p) as f64;
                        motion.frame(p)[c] + t * (motion.frame(q)[c] - motion.frame(p)[c])
                    }
                    (Some(p), None) => motion.frame(p)[c],
                    (None, Some(q)) => motion.frame(q)[c],
                    (None, None) => 0.0,
                };
                motion.frame_mut(i)[c] = v;
            }
        }
    }
    found
}
