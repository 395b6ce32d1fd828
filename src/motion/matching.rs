//! Window distance matching, eq. (11):
//! `dist = Σ_f W_frame[f] · Σ_j W_joint[j] · joint_dist(q_j[f], q'_j[f])`
//! over all joints but the root, with the joint distance on Euler angles (Euclidean, radians),
//! on quaternions (`‖log(q₁⁻¹q₂)‖`, eq. 27–28) or on joint positions normalised for the root's
//! place and facing and for the skeleton's size.
//!
//! Per-frame features are computed once per clip; the distance of every window is then a
//! weighted sum along a diagonal of the frame-pair distances.

use super::clip::heading;
use super::Motion;
use crate::fk::{forward_kinematics, Pose};
use crate::interp::channel_rotation;
use crate::skeleton::{Skeleton, MAX_CHANNELS};
use glam::{DMat3, DQuat, DVec3};

/// How two poses of one joint are compared.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Metric {
    /// Euclidean distance of the joint's Euler angles (radians), as the help note does.
    Euler,
    /// `‖log(q₁⁻¹q₂)‖` of the joint's rotations (eq. 27–28).
    Quat,
    /// Distance of the joint's position relative to the root, with the root's facing removed,
    /// divided by the skeleton's rest height.
    Position,
}

/// Matching parameters.
#[derive(Clone, Debug, PartialEq)]
pub struct MatchParams {
    /// Frames in a window.
    pub window: usize,
    /// The joint distance.
    pub metric: Metric,
    /// `W_frame`, one per window frame (default: all 1).
    pub frame_weights: Option<Vec<f64>>,
    /// `W_joint`, one per bone, root first (default: 1 for every bone with rotation
    /// channels, 0 for the root).
    pub joint_weights: Option<Vec<f64>>,
}

impl MatchParams {
    /// Uniform weights.
    #[must_use]
    pub fn new(window: usize, metric: Metric) -> MatchParams {
        MatchParams {
            window,
            metric,
            frame_weights: None,
            joint_weights: None,
        }
    }
}

/// The distance curve of a matching and its global minimum.
#[derive(Clone, Debug, PartialEq)]
pub struct MatchResult {
    /// `distances[j]`: the window distance of the candidate window starting at frame `j`.
    pub distances: Vec<f64>,
    /// The index of the smallest distance (the first one, on ties).
    pub best: usize,
    /// The smallest distance.
    pub best_distance: f64,
}

impl MatchResult {
    /// Restricts the minimum to window starts in `allowed` (the curve is kept whole);
    /// `None` when no start is allowed.
    #[must_use]
    pub fn best_within(mut self, allowed: std::ops::Range<usize>) -> Option<MatchResult> {
        let end = allowed.end.min(self.distances.len());
        let (best, d) = (allowed.start..end).map(|i| (i, self.distances[i])).fold(
            None,
            |acc: Option<(usize, f64)>, (i, d)| match acc {
                Some((_, bd)) if bd <= d => acc,
                _ => Some((i, d)),
            },
        )?;
        self.best = best;
        self.best_distance = d;
        Some(self)
    }
}

/// Why a matching cannot be done.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum MatchError {
    /// The window is empty or longer than a clip.
    #[error("window of {window} frames does not fit a clip of {frames} frames")]
    Window {
        /// Asked window.
        window: usize,
        /// Frames of the shorter clip.
        frames: usize,
    },
    /// Weights of the wrong length or not finite and non-negative.
    #[error("{0}")]
    Weights(&'static str),
    /// The clips do not have the skeleton's channels.
    #[error("clip has {got} channels, the skeleton {want}")]
    Channels {
        /// The clip's.
        got: usize,
        /// The skeleton's.
        want: usize,
    },
}

/// Per-frame features of a clip for one metric.
pub struct Features {
    metric: Metric,
    bones: usize,
    euler: Vec<[f64; 3]>,
    quat: Vec<DQuat>,
    position: Vec<DVec3>,
}

impl Features {
    /// Features of every frame of `motion`.
    #[must_use]
    pub fn new(skeleton: &Skeleton, motion: &Motion, metric: Metric) -> Features {
        let n = skeleton.len();
        let mut f = Features {
            metric,
            bones: n,
            euler: Vec::new(),
            quat: Vec::new(),
            position: Vec::new(),
        };
        let scale = rest_height(skeleton);
        let mut channels = [0.0f32; MAX_CHANNELS];
        let mut pose = Pose::new();
        for i in 0..motion.len() {
            let frame = motion.frame(i);
            match metric {
                Metric::Euler => {
                    for b in skeleton.bones() {
                        let mut e = [0.0; 3];
                        let rot = b.dofs().iter().zip(b.channels()).filter(|(d, _)| d.is_rotation());
                        for (k, (_, c)) in rot.enumerate() {
                            e[k] = frame[c].to_radians();
                        }
                        f.euler.push(e);
                    }
                }
                Metric::Quat => {
                    for b in skeleton.bones() {
                        f.quat.push(DQuat::from_mat3(&channel_rotation(b, frame)));
                    }
                }
                Metric::Position => {
                    motion.channels_into(skeleton, i, &mut channels);
                    // A frame that does not fit the skeleton was rejected by the caller.
                    let _ = forward_kinematics(skeleton, &channels, &mut pose);
                    let (facing, root) = heading(skeleton, motion, i);
                    let unturn = DMat3::from_rotation_y(-facing);
                    for b in 0..n {
                        f.position.push(unturn * (pose.tip[b].as_dvec3() - root) / scale);
                    }
                }
            }
        }
        f
    }

    /// `joint_dist` of bone `b` between frame `i` of these features and frame `k` of `other`.
    #[inline]
    #[must_use]
    pub fn joint_distance(&self, i: usize, other: &Features, k: usize, b: usize) -> f64 {
        let (x, y) = (i * self.bones + b, k * other.bones + b);
        match self.metric {
            Metric::Euler => {
                let (p, q) = (self.euler[x], other.euler[y]);
                ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt()
            }
            // For unit quaternions the scalar part of q₁⁻¹q₂ is q₁·q₂, so eq. (28) is
            // acos(|q₁·q₂|) (the shorter of q and −q).
            Metric::Quat => libm::acos(libm::fabs(self.quat[x].dot(other.quat[y])).min(1.0)),
            Metric::Position => (self.position[x] - other.position[y]).length(),
        }
    }
}

/// The skeleton's rest height (highest minus lowest bone tip), used to normalise positions.
fn rest_height(skeleton: &Skeleton) -> f64 {
    let channels = [0.0f32; MAX_CHANNELS];
    let mut pose = Pose::new();
    let _ = forward_kinematics(skeleton, &channels, &mut pose);
    let ys = pose.tip[..skeleton.len()].iter().map(|p| f64::from(p.y));
    let (lo, hi) = ys.fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), y| {
        (l.min(y), h.max(y))
    });
    if hi > lo {
        hi - lo
    } else {
        1.0
    }
}

fn weights(skeleton: &Skeleton, params: &MatchParams) -> Result<(Vec<f64>, Vec<f64>), MatchError> {
    let frame_w = match &params.frame_weights {
        Some(w) if w.len() != params.window => {
            return Err(MatchError::Weights("need one frame weight per window frame"))
        }
        Some(w) => w.clone(),
        None => vec![1.0; params.window],
    };
    let joint_w = match &params.joint_weights {
        Some(w) if w.len() != skeleton.len() => {
            return Err(MatchError::Weights("need one joint weight per bone"))
        }
        Some(w) => w.clone(),
        None => skeleton
            .bones()
            .iter()
            .enumerate()
            .map(|(i, b)| f64::from(u8::from(i > 0 && b.dofs().iter().any(|d| d.is_rotation()))))
            .collect(),
    };
    if frame_w.iter().chain(&joint_w).any(|w| !w.is_finite() || *w < 0.0) {
        return Err(MatchError::Weights("weights must be finite and not negative"));
    }
    Ok((frame_w, joint_w))
}

/// Distances of the window `reference[ref_start .. ref_start + N]` against every window
/// `candidates[j .. j + N]`.
///
/// # Errors
/// [`MatchError`] when the window does not fit or the weights are malformed.
pub fn window_distances(
    skeleton: &Skeleton,
    reference: &Motion,
    ref_start: usize,
    candidates: &Motion,
    params: &MatchParams,
) -> Result<MatchResult, MatchError> {
    let n = params.window;
    for m in [reference, candidates] {
        if m.channel_count() != skeleton.channel_count() {
            return Err(MatchError::Channels {
                got: m.channel_count(),
                want: skeleton.channel_count(),
            });
        }
    }
    if n == 0 || ref_start + n > reference.len() || n > candidates.len() {
        return Err(MatchError::Window {
            window: n,
            frames: reference.len().min(candidates.len()),
        });
    }
    let (frame_w, joint_w) = weights(skeleton, params)?;
    let ref_window = reference.slice(ref_start..ref_start + n);
    let fr = Features::new(skeleton, &ref_window, params.metric);
    let fc = Features::new(skeleton, candidates, params.metric);
    let windows = candidates.len() - n + 1;
    let mut distances = vec![0.0; windows];
    let joints: Vec<(usize, f64)> = joint_w
        .iter()
        .copied()
        .enumerate()
        .filter(|(_, w)| *w > 0.0)
        .collect();
    for (f, wf) in frame_w.iter().enumerate() {
        if *wf == 0.0 {
            continue;
        }
        // Candidate frame k = j + f for every window j.
        for (j, d) in distances.iter_mut().enumerate() {
            let k = j + f;
            let mut pair = 0.0;
            for &(b, wj) in &joints {
                pair += wj * fr.joint_distance(f, &fc, k, b);
            }
            *d += wf * pair;
        }
    }
    let (best, best_distance) =
        distances
            .iter()
            .copied()
            .enumerate()
            .fold(
                (0, f64::INFINITY),
                |(bi, bd), (i, d)| if d < bd { (i, d) } else { (bi, bd) },
            );
    Ok(MatchResult {
        distances,
        best,
        best_distance,
    })
}

/// Forward matching: the last `N` frames of `a` against every window of `b`.
///
/// # Errors
/// See [`window_distances`].
pub fn forward_match(
    skeleton: &Skeleton,
    a: &Motion,
    b: &Motion,
    params: &MatchParams,
) -> Result<MatchResult, MatchError> {
    let start = a.len().checked_sub(params.window).ok_or(MatchError::Window {
        window: params.window,
        frames: a.len(),
    })?;
    window_distances(skeleton, a, start, b, params)
}

/// Backward matching: the first `N` frames of `b` against every window of `a`.
///
/// # Errors
/// See [`window_distances`].
pub fn backward_match(
    skeleton: &Skeleton,
    a: &Motion,
    b: &Motion,
    params: &MatchParams,
) -> Result<MatchResult, MatchError> {
    window_distances(skeleton, b, 0, a, params)
}
