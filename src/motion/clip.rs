//! Clip operations: cut, reverse, append, resample, and the transformation of eq. (6)–(10).

use super::Motion;
use crate::interp::{facing_angle, interpolate_frames, root_position, root_rotation, set_root};
use crate::skeleton::Skeleton;
use glam::{DMat3, DVec3};

/// A turn about the vertical axis through `from`, then a move of `from` to `to`, in the x–z
/// plane; heights are left as captured. This is what eq. (8)–(10) apply to a clip's root.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GroundMove {
    /// Turn about +y, radians.
    pub yaw: f64,
    /// Pivot (x, z used).
    pub from: DVec3,
    /// Where the pivot goes (x, z used).
    pub to: DVec3,
}

impl GroundMove {
    /// No change.
    pub const IDENTITY: GroundMove = GroundMove {
        yaw: 0.0,
        from: DVec3::ZERO,
        to: DVec3::ZERO,
    };

    /// Applies the move to a root rotation and position.
    #[must_use]
    pub fn apply(&self, rotation: &DMat3, position: DVec3) -> (DMat3, DVec3) {
        let r = DMat3::from_rotation_y(self.yaw);
        let d = r * DVec3::new(position.x - self.from.x, 0.0, position.z - self.from.z);
        (
            r * *rotation,
            DVec3::new(d.x + self.to.x, position.y, d.z + self.to.z),
        )
    }

    /// This move followed by `next`.
    #[must_use]
    pub fn then(&self, next: &GroundMove) -> GroundMove {
        // p ↦ next(self(p)); the composite pivots at self.from.
        let (_, mid) = self.apply(&DMat3::IDENTITY, self.from);
        let (_, to) = next.apply(&DMat3::IDENTITY, mid);
        GroundMove {
            yaw: self.yaw + next.yaw,
            from: self.from,
            to,
        }
    }

    /// Applies the move to every frame of a clip.
    #[must_use]
    pub fn apply_to(&self, skeleton: &Skeleton, motion: &Motion) -> Motion {
        let mut out = motion.clone();
        for i in 0..out.len() {
            let f = out.frame_mut(i);
            let (r, p) = self.apply(&root_rotation(skeleton, f), root_position(skeleton, f));
            set_root(skeleton, f, &r, p);
        }
        out
    }
}

/// Facing angle (eq. 7) and root position of frame `i`.
#[must_use]
pub fn heading(skeleton: &Skeleton, motion: &Motion, i: usize) -> (f64, DVec3) {
    let f = motion.frame(i);
    (
        facing_angle(&root_rotation(skeleton, f)),
        root_position(skeleton, f),
    )
}

/// The move that gives frame `i` of `motion` the facing `facing` (radians) and places its root
/// at `start` (x, z; its height is kept): eq. (8)–(10) with the first frame's facing `θ₀`.
#[must_use]
pub fn move_to(skeleton: &Skeleton, motion: &Motion, i: usize, facing: f64, start: DVec3) -> GroundMove {
    let (theta0, t0) = heading(skeleton, motion, i);
    GroundMove {
        yaw: facing - theta0,
        from: t0,
        to: start,
    }
}

/// Transformation of eq. (6)–(10): turns the whole clip about its first frame's root so that
/// the first frame faces `facing` (radians), and moves that root to `start` (x, z), or
/// leaves it where it is.
#[must_use]
pub fn transform(skeleton: &Skeleton, motion: &Motion, facing: f64, start: Option<(f64, f64)>) -> Motion {
    if motion.is_empty() {
        return motion.clone();
    }
    let (_, t0) = heading(skeleton, motion, 0);
    let target = start.map_or(t0, |(x, z)| DVec3::new(x, t0.y, z));
    move_to(skeleton, motion, 0, facing, target).apply_to(skeleton, motion)
}

/// The clip's path bent by `turn` radians (about +y, the vertical): frame `i` of `n` turned
/// by `turn × i / (n − 1)` about its root, and each frame's move of the root over the ground
/// turned as its frame is, so that the path curves as the body turns (a walk becomes a walk
/// with a turn). The first frame stays where it is; heights are left as captured.
#[must_use]
pub fn bend(skeleton: &Skeleton, motion: &Motion, turn: f64) -> Motion {
    let mut out = motion.clone();
    let n = motion.len();
    if n < 2 {
        return out;
    }
    let mut place = root_position(skeleton, motion.frame(0));
    for i in 0..n {
        let f = motion.frame(i);
        let yaw = turn * i as f64 / (n - 1) as f64;
        let turned = DMat3::from_rotation_y(yaw);
        let p = root_position(skeleton, f);
        if i > 0 {
            let step = p - root_position(skeleton, motion.frame(i - 1));
            place += turned * DVec3::new(step.x, 0.0, step.z);
        }
        set_root(
            skeleton,
            out.frame_mut(i),
            &(turned * root_rotation(skeleton, f)),
            DVec3::new(place.x, p.y, place.z),
        );
    }
    out
}

impl Motion {
    /// The frames in reverse order.
    #[must_use]
    pub fn reversed(&self) -> Motion {
        let mut out = Motion::new(self.channel_count(), self.frame_rate);
        out.first_frame = self.first_frame;
        for i in (0..self.len()).rev() {
            out.push_frame(self.frame(i));
        }
        out
    }

    /// Appends another clip's frames (same channels).
    ///
    /// # Panics
    /// When the channel counts differ.
    pub fn append(&mut self, other: &Motion) {
        assert_eq!(
            self.channel_count(),
            other.channel_count(),
            "channel counts differ"
        );
        for f in other.frames() {
            self.push_frame(f);
        }
    }

    /// The clip at another frame rate, rotations by SLERP (eq. 12): frames at `k / rate`
    /// seconds for every `k` with `k / rate` within the clip.
    ///
    /// # Panics
    /// When `rate` is not a positive finite number.
    #[must_use]
    pub fn resampled(&self, skeleton: &Skeleton, rate: f64) -> Motion {
        assert!(rate.is_finite() && rate > 0.0, "rate must be positive");
        let mut out = Motion::new(self.channel_count(), rate);
        out.first_frame = self.first_frame;
        if self.is_empty() {
            return out;
        }
        let duration = self.duration();
        let count = (duration * rate + 1e-9).floor() as usize + 1;
        let mut buf = vec![0.0; self.channel_count()];
        for k in 0..count {
            let mut t = (k as f64 / rate) * self.frame_rate;
            if (t - t.round()).abs() < 1e-9 {
                // On a source frame (up to rounding of k / rate): take it as it is.
                t = t.round();
            }
            let i = (t.floor() as usize).min(self.len() - 1);
            let j = (i + 1).min(self.len() - 1);
            let u = (t - i as f64).clamp(0.0, 1.0);
            if u < 1e-12 || i == j {
                out.push_frame(self.frame(i));
            } else {
                interpolate_frames(skeleton, self.frame(i), self.frame(j), u, &mut buf);
                out.push_frame(&buf);
            }
        }
        out
    }
}
