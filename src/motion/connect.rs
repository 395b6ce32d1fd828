//! Connecting clips (help note §III): by interpolation (fig. 3, eq. 12, 14) or by blending
//! (fig. 4, eq. 13, 15), after forward or backward matching (eq. 11); loops (a clip connected
//! to itself); and frame-by-frame blends of two clips.

use super::clip::{heading, move_to, GroundMove};
use super::matching::{backward_match, forward_match, MatchError, MatchParams, MatchResult};
use super::seam::{bone_seam, BoneLimits, BoneSeam};
use super::Motion;
use crate::interp::{ease_weight, interpolate_frames};
use crate::math::wrap_near;
use crate::skeleton::Skeleton;
use glam::DVec3;
use std::ops::Range;

/// How the transition is made.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Method {
    /// Insert SLERP-interpolated frames between the two end poses (fig. 3).
    Interpolate,
    /// Ease-in/ease-out blend of the overlapping matched windows (fig. 4).
    Blend,
}

/// Which clip is kept whole.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Direction {
    /// Match the end of A in B; A is kept whole.
    Forward,
    /// Match the start of B in A; B is kept whole.
    Backward,
}

/// Connection parameters.
#[derive(Clone, Debug, PartialEq)]
pub struct ConnectParams {
    /// Interpolation or blending.
    pub method: Method,
    /// Forward or backward matching.
    pub direction: Direction,
    /// Matching window and metric.
    pub matching: MatchParams,
    /// Frames to insert when interpolating (`None`: as few as keep every bone, and the root,
    /// within its own speeds in the inputs — [`BoneLimits`]).
    pub insert: Option<usize>,
    /// Frames to blend over (`None`: from the matching window up, as few as keep every bone
    /// within its own speeds in the inputs, as far as the clips allow).
    pub blend: Option<usize>,
}

/// A connected clip and how it was made.
#[derive(Clone, Debug)]
pub struct Connection {
    /// The result.
    pub motion: Motion,
    /// The matching's distance curve (over B's windows when forward, A's when backward).
    pub matching: MatchResult,
    /// Output frames made by the transition (interpolated or blended).
    pub seam: Range<usize>,
    /// Frames of A kept at the start of the output.
    pub a_kept: Range<usize>,
    /// Frames of B kept after the seam.
    pub b_kept: Range<usize>,
    /// The move applied to B.
    pub b_move: GroundMove,
    /// Every bone across the seam against its own speeds in the inputs, worst first.
    pub bones: Vec<BoneSeam>,
}

impl Connection {
    /// The largest per-bone ratio across the seam (at most 1: as smooth as the inputs).
    #[must_use]
    pub fn worst_ratio(&self) -> f64 {
        self.bones.first().map_or(0.0, |b| b.ratio)
    }
}

/// Why a connection cannot be made.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum ConnectError {
    /// Matching failed.
    #[error(transparent)]
    Match(#[from] MatchError),
    /// Too little of a clip remains around the match.
    #[error("{0}")]
    TooShort(String),
}

fn too_short(what: &str) -> ConnectError {
    ConnectError::TooShort(what.to_string())
}

/// Linear extrapolation of facing and position, eq. (14): `x[N−1] + k·(x[N−1] − x[N−2])`.
fn extrapolate(skeleton: &Skeleton, a: &Motion, last: usize, k: f64) -> (f64, DVec3) {
    let (f1, t1) = heading(skeleton, a, last);
    let (f0, t0) = heading(skeleton, a, last.saturating_sub(1));
    let df = wrap_near(f1, f0) - f0;
    (f1 + k * df, t1 + (t1 - t0) * k)
}

/// Matches in the direction asked and keeps the best window among the starts that leave
/// frames to connect: forward, at least one frame of B after the window; backward, `before`
/// frames of A before it.
fn best_match(
    skeleton: &Skeleton,
    a: &Motion,
    b: &Motion,
    p: &ConnectParams,
    before: usize,
) -> Result<MatchResult, ConnectError> {
    let n = p.matching.window;
    match p.direction {
        Direction::Forward => forward_match(skeleton, a, b, &p.matching)?
            .best_within(forward_starts(a, b, n))
            .ok_or_else(|| too_short("no window of B leaves frames after it: use a smaller window")),
        Direction::Backward => backward_match(skeleton, a, b, &p.matching)?
            .best_within(backward_starts(a, b, n, before))
            .ok_or_else(|| {
                ConnectError::TooShort(format!(
                    "no window of A leaves {before} frame(s) before it: use a smaller window"
                ))
            }),
    }
}

/// Window starts in B allowed by forward matching: at least one frame of B after the window
/// and, when B is A itself, no window overlapping A's own end window (the trivial match).
fn forward_starts(a: &Motion, b: &Motion, n: usize) -> Range<usize> {
    let mut end = (b.len() + 1).saturating_sub(n + 1);
    if a == b {
        end = end.min((a.len() + 1).saturating_sub(2 * n));
    }
    0..end
}

/// Window starts in A allowed by backward matching: `before` frames of A before the window
/// and, when B is A itself, no window overlapping A's own start window.
fn backward_starts(a: &Motion, b: &Motion, n: usize, before: usize) -> Range<usize> {
    let start = if a == b { before.max(n) } else { before };
    start..(a.len() + 1).saturating_sub(n)
}

/// Connects `a` and `b`.
///
/// # Errors
/// [`ConnectError`] when the window does not fit or too little of a clip remains.
pub fn connect(
    skeleton: &Skeleton,
    a: &Motion,
    b: &Motion,
    p: &ConnectParams,
) -> Result<Connection, ConnectError> {
    let n = p.matching.window;
    if a.len() < 2 {
        return Err(too_short("clip A needs at least 2 frames"));
    }
    match p.method {
        Method::Interpolate => {
            // Forward: B's matched window is "pseudo-overlapped" with A's end, so it and all
            // before it are dropped. Backward: A is cut before the matched window, and the
            // extrapolation of eq. (14) needs 2 of its frames.
            let m = best_match(skeleton, a, b, p, 2)?;
            let (a_keep, b_keep) = match p.direction {
                Direction::Forward => (0..a.len(), m.best + n..b.len()),
                Direction::Backward => (0..m.best, 0..b.len()),
            };
            let a_part = a.slice(a_keep.clone());
            let b_part = b.slice(b_keep.clone());
            let last = a_part.len() - 1;
            // The requested count, or the automatic one from the real end poses: B's placement
            // depends on the count (eq. 14 extrapolates over it), so until they agree.
            let limits = BoneLimits::of(skeleton, &[a, b]);
            let mut ni = p.insert.unwrap_or(0);
            let mut mv = GroundMove::IDENTITY;
            for _ in 0..8 {
                let (facing, pos) = extrapolate(skeleton, &a_part, last, (ni + 1) as f64);
                let start = DVec3::new(pos.x, heading(skeleton, &b_part, 0).1.y, pos.z);
                mv = move_to(skeleton, &b_part, 0, facing, start);
                if p.insert.is_some() {
                    break;
                }
                let b0 = mv.apply_to(skeleton, &b_part.slice(0..1));
                let wanted = limits.frames_between(skeleton, a_part.frame(last), b0.frame(0));
                if wanted == ni {
                    break;
                }
                ni = wanted;
            }
            let b_moved = mv.apply_to(skeleton, &b_part);
            let mut out = a_part.clone();
            let mut buf = vec![0.0; skeleton.channel_count()];
            for k in 1..=ni {
                let u = k as f64 / (ni + 1) as f64;
                interpolate_frames(skeleton, a_part.frame(last), b_moved.frame(0), u, &mut buf);
                out.push_frame(&buf);
            }
            out.append(&b_moved);
            let seam = a_part.len()..a_part.len() + ni;
            let bones = bone_seam(skeleton, &out, seam.clone(), &limits);
            Ok(Connection {
                motion: out,
                matching: m,
                seam,
                a_kept: a_keep,
                b_kept: b_keep,
                b_move: mv,
                bones,
            })
        }
        Method::Blend => {
            let m = best_match(skeleton, a, b, p, 1)?;
            let limits = BoneLimits::of(skeleton, &[a, b]);
            // The longest blend the clips allow with the matched windows still aligned at its
            // end (forward: B's frames before its window; backward: A's frames after it).
            let longest = match p.direction {
                Direction::Forward => (m.best + n).min(a.len()),
                Direction::Backward => (a.len() - m.best).min(b.len()),
            };
            let blended = |len: usize| blend_over(skeleton, a, b, p.direction, m.best, n, len, &limits);
            let mut best = blended(p.blend.unwrap_or(n).clamp(1, longest.max(1)));
            if p.blend.is_none() {
                // Longer blends spread the change between the clips over more frames: grow
                // the window until every bone is within its speeds, or the clips end.
                let mut len = n;
                while best.1.first().is_some_and(|w| w.ratio > 1.0) && len < longest {
                    let ratio = best.1.first().map_or(1.0, |w| w.ratio);
                    len = ((len as f64 * ratio.min(2.0)).ceil() as usize)
                        .max(len + 1)
                        .min(longest);
                    let next = blended(len);
                    if next.1.first().map_or(0.0, |w| w.ratio) < ratio {
                        best = next;
                    }
                }
            }
            let (parts, bones) = best;
            Ok(Connection {
                motion: parts.motion,
                matching: m,
                seam: parts.seam,
                a_kept: parts.a_kept,
                b_kept: parts.b_kept,
                b_move: parts.b_move,
                bones,
            })
        }
    }
}

/// A blended connection before its report.
struct Blended {
    motion: Motion,
    seam: Range<usize>,
    a_kept: Range<usize>,
    b_kept: Range<usize>,
    b_move: GroundMove,
}

/// Blends A into B over `len` frames and reports every bone across it. Forward, the blend ends
/// where A and B's matched window (`n` frames from `best`) end; backward, it starts where A's
/// matched window and B start.
#[allow(clippy::too_many_arguments)]
fn blend_over(
    skeleton: &Skeleton,
    a: &Motion,
    b: &Motion,
    direction: Direction,
    best: usize,
    n: usize,
    len: usize,
    limits: &BoneLimits,
) -> (Blended, Vec<BoneSeam>) {
    let (a_start, b_start) = match direction {
        Direction::Forward => (a.len() - len, best + n - len),
        Direction::Backward => (best, 0),
    };
    // eq. (15): B's first overlapping frame takes the facing and place of A's.
    let (facing, pos) = heading(skeleton, a, a_start);
    let b_part = b.slice(b_start..b.len());
    let start = DVec3::new(pos.x, heading(skeleton, &b_part, 0).1.y, pos.z);
    let mv = move_to(skeleton, &b_part, 0, facing, start);
    let b_moved = mv.apply_to(skeleton, &b_part);
    let mut out = a.slice(0..a_start);
    push_ease_blend(skeleton, &mut out, &a.slice(a_start..a_start + len), &b_moved);
    out.append(&b_moved.slice(len..b_moved.len()));
    let seam = a_start..a_start + len;
    let bones = bone_seam(skeleton, &out, seam.clone(), limits);
    (
        Blended {
            motion: out,
            seam,
            a_kept: 0..a_start,
            b_kept: b_start + len..b.len(),
            b_move: mv,
        },
        bones,
    )
}

/// Appends to `out` the ease-in/ease-out blend (eq. 13) of `from` into `to`, frame by frame
/// over `from`'s length: weight 0 on the first frame (all `from`), 1 on the last (all `to`).
fn push_ease_blend(skeleton: &Skeleton, out: &mut Motion, from: &Motion, to: &Motion) {
    let n = from.len();
    let mut buf = vec![0.0; skeleton.channel_count()];
    for f in 0..n {
        interpolate_frames(skeleton, from.frame(f), to.frame(f), ease_weight(f, n), &mut buf);
        out.push_frame(&buf);
    }
}

/// A seamless cycle of a clip, repeated `cycles` times with the root carried on.
#[derive(Clone, Debug)]
pub struct Loop {
    /// The repeated cycle.
    pub motion: Motion,
    /// Frames in one cycle.
    pub period: usize,
    /// The matching of the clip's end against its own windows (cut to the legal starts).
    pub matching: MatchResult,
    /// Where the cycle starts in the input.
    pub start: usize,
    /// The blended frames at the end of each cycle (first cycle).
    pub seam: Range<usize>,
}

/// Connects a clip to itself: the end window is matched against the clip's earlier windows
/// (starts leaving a cycle of at least `2·N` frames), the end blended into the matched window
/// (eq. 13, 15), and the cycle repeated with facing and position carried on.
///
/// # Errors
/// [`ConnectError`] when the clip is shorter than four windows.
pub fn loop_clip(
    skeleton: &Skeleton,
    a: &Motion,
    matching: &MatchParams,
    cycles: usize,
) -> Result<Loop, ConnectError> {
    let n = matching.window;
    if n == 0 || a.len() < 4 * n {
        return Err(too_short("a loop needs a clip of at least four matching windows"));
    }
    let full = forward_match(skeleton, a, a, matching)?;
    // Starts j with a cycle (from j + N to the end window) of at least 2N frames.
    let legal = a.len() - 4 * n + 1;
    let truncated = MatchResult {
        distances: full.distances[..legal].to_vec(),
        ..full
    };
    let m = truncated
        .best_within(0..legal)
        .ok_or_else(|| too_short("a loop needs a clip of at least four matching windows"))?;
    let best = m.best;
    // One cycle: A[j+N .. len−N], then A's end window blended into the (moved) window A[j..j+N].
    let a_start = a.len() - n;
    let (facing, pos) = heading(skeleton, a, a_start);
    let start = DVec3::new(pos.x, heading(skeleton, a, best).1.y, pos.z);
    let mv = move_to(skeleton, a, best, facing, start);
    let moved_window = mv.apply_to(skeleton, &a.slice(best..best + n));
    let mut cycle = a.slice(best + n..a_start);
    push_ease_blend(skeleton, &mut cycle, &a.slice(a_start..a.len()), &moved_window);
    let period = cycle.len();
    let seam = period - n..period;
    // Cycle k is the first cycle moved k times: frame best+N of the input maps to the frame
    // after the blend, i.e. `mv` applied once per cycle.
    let mut out = cycle.clone();
    let mut step = mv;
    for _ in 1..cycles.max(1) {
        out.append(&step.apply_to(skeleton, &cycle));
        step = step.then(&mv);
    }
    out.first_frame = 1;
    Ok(Loop {
        motion: out,
        period,
        matching: m,
        start: best,
        seam,
    })
}

/// Blends two clips frame by frame with a constant weight (0: A, 1: B) over the shorter
/// length: root position linearly, rotations by SLERP (eq. 12).
#[must_use]
pub fn blend(skeleton: &Skeleton, a: &Motion, b: &Motion, weight: f64) -> Motion {
    let mut out = Motion::new(skeleton.channel_count(), a.frame_rate);
    out.first_frame = a.first_frame;
    let mut buf = vec![0.0; skeleton.channel_count()];
    for i in 0..a.len().min(b.len()) {
        interpolate_frames(skeleton, a.frame(i), b.frame(i), weight, &mut buf);
        out.push_frame(&buf);
    }
    out
}
