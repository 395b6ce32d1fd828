//! A whole clip's joint trajectory made one the servos can play: the arms' branches chosen over
//! the clip (a shortest path through each frame's solutions), then every joint kept within its
//! servo's velocity and acceleration without lag.

use marionette_core::retarget::{arm_step_cost, ArmSolutions};

/// The branch of each frame (an index into its solutions) that minimises the sum of the
/// solutions' own costs ([`marionette_core::retarget::ArmSolution::cost`]) and of the steps
/// between them ([`arm_step_cost`] at `step_limit`, radians a frame) — the Viterbi recursion.
/// `None` when a frame has no solution.
#[must_use]
pub fn plan_branches(solutions: &[ArmSolutions], step_limit: [f64; 3]) -> Option<Vec<usize>> {
    if solutions.iter().any(|s| s.is_empty()) {
        return None;
    }
    let step_cost = |a: &[f64; 3], b: &[f64; 3]| arm_step_cost(*a, *b, step_limit);
    let mut cost: Vec<f64> = solutions.first()?.iter().map(|s| s.cost()).collect();
    let mut back: Vec<Vec<usize>> = Vec::with_capacity(solutions.len());
    back.push(vec![0; cost.len()]);
    for w in solutions.windows(2) {
        let (prev, now) = (&w[0], &w[1]);
        let mut next = Vec::with_capacity(now.len());
        let mut from = Vec::with_capacity(now.len());
        for s in now {
            let (i, c) = prev
                .iter()
                .enumerate()
                .map(|(i, p)| (i, cost[i] + step_cost(&p.q, &s.q)))
                .min_by(|a, b| a.1.total_cmp(&b.1))?;
            next.push(c + s.cost());
            from.push(i);
        }
        cost = next;
        back.push(from);
    }
    let (mut at, _) = cost.iter().enumerate().min_by(|a, b| a.1.total_cmp(b.1))?;
    let mut path = vec![0; solutions.len()];
    for k in (0..solutions.len()).rev() {
        path[k] = at;
        at = back[k][at];
    }
    Some(path)
}

/// Frames (index ≥ 1) where a joint's step from the frame before is faster than its limit
/// (`step_limit[j]`, radians a frame), for the joint trajectories `q[frame][joint]`.
#[must_use]
pub fn fast_frames(q: &[Vec<f64>], step_limit: &[f64]) -> Vec<usize> {
    q.windows(2)
        .enumerate()
        .filter(|(_, w)| {
            w[0].iter()
                .zip(&w[1])
                .zip(step_limit)
                .any(|((a, b), l)| (b - a).abs() > *l)
        })
        .map(|(k, _)| k + 1)
        .collect()
}

/// `frames` as spans `[first, last]`, neighbours `gap` frames apart or closer joined.
#[must_use]
pub fn spans(frames: &[usize], gap: usize) -> Vec<[usize; 2]> {
    let mut out: Vec<[usize; 2]> = Vec::new();
    for &f in frames {
        match out.last_mut() {
            Some(last) if f <= last[1] + gap => last[1] = f,
            _ => out.push([f, f]),
        }
    }
    out
}

/// Frames of a capture glitch taken from their neighbours: a value further than `2·v` (two
/// frames at the servo's speed) from the median of the five frames around it — a jump away and
/// back within two frames, which no servo could follow and no body made — becomes that median.
/// Returns how many values were replaced. A trajectory without such spikes is unchanged.
pub fn remove_glitches(x: &mut [f64], v: f64) -> usize {
    let n = x.len();
    if n < 3 || v.is_nan() || v <= 0.0 || !v.is_finite() {
        return 0;
    }
    let source = x.to_vec();
    let mut replaced = 0;
    for (k, x) in x.iter_mut().enumerate() {
        let mut window: heapless::Vec<f64, 5> = source[k.saturating_sub(2)..(k + 3).min(n)]
            .iter()
            .copied()
            .collect();
        window.sort_unstable_by(f64::total_cmp);
        let median = window[window.len() / 2];
        if (*x - median).abs() > 2.0 * v {
            *x = median;
            replaced += 1;
        }
    }
    replaced
}

/// Keeps one joint's trajectory `x` (radians, one value a frame) within a step of `v` and a
/// change of step of `a` a frame (the servo's velocity × dt and acceleration × dt²) and inside
/// `range`, without lag: first the nearest trajectory within the velocity in the largest
/// deviation (the mean of its upper and lower envelopes, `min/max_i x_i ± v·|k − i|`), then the
/// mean of an acceleration-limited follower run forwards and one run backwards. Each part
/// meets both limits, so their mean does; a trajectory already within them is unchanged.
pub fn limit_speed(x: &mut [f64], v: f64, a: f64, range: Option<(f64, f64)>) {
    let n = x.len();
    if n < 2 || v.is_nan() || a.is_nan() || v <= 0.0 || a <= 0.0 {
        return;
    }
    if v.is_finite() {
        let mut upper = x.to_vec();
        let mut lower = x.to_vec();
        for k in 1..n {
            upper[k] = upper[k].min(upper[k - 1] + v);
            lower[k] = lower[k].max(lower[k - 1] - v);
        }
        for k in (0..n - 1).rev() {
            upper[k] = upper[k].min(upper[k + 1] + v);
            lower[k] = lower[k].max(lower[k + 1] - v);
        }
        for ((x, u), l) in x.iter_mut().zip(&upper).zip(&lower) {
            *x = 0.5 * (u + l);
        }
    }
    if a.is_finite() {
        let forward = follow(x, v, a);
        let reversed: Vec<f64> = x.iter().rev().copied().collect();
        let backward = follow(&reversed, v, a);
        for (k, x) in x.iter_mut().enumerate() {
            *x = 0.5 * (forward[k] + backward[n - 1 - k]);
        }
    }
    if let Some((lo, hi)) = range {
        for x in x.iter_mut() {
            *x = x.clamp(lo, hi);
        }
    }
}

/// A follower of `y` whose step stays within `v` and changes by at most `a` a frame: it steps
/// as `y` does and closes its gap no faster than it can stop (`√(2·a·gap)`), starting on
/// `y`'s first value at rest. Exact on a `y` within both limits.
fn follow(y: &[f64], v: f64, a: f64) -> Vec<f64> {
    let mut out = Vec::with_capacity(y.len());
    let Some(&first) = y.first() else {
        return out;
    };
    let (mut p, mut step) = (first, 0.0);
    out.push(p);
    for w in y.windows(2) {
        let gap = w[0] - p;
        let close = gap.signum() * gap.abs().min((2.0 * a * gap.abs()).sqrt());
        let wanted = (w[1] - w[0]) + close;
        step = wanted.clamp(step - a, step + a).clamp(-v, v);
        p += step;
        out.push(p);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use marionette_core::retarget::ArmSolution;

    fn sol(q: f64, hand_mm: f64) -> ArmSolution {
        ArmSolution {
            q: [q, 0.0, 0.0],
            hand_error: hand_mm / 1000.0,
            elbow_error: 0.0,
        }
    }

    fn steps(x: &[f64]) -> (f64, f64) {
        let v = x.windows(2).map(|w| (w[1] - w[0]).abs()).fold(0.0, f64::max);
        let a = x
            .windows(3)
            .map(|w| (w[2] - 2.0 * w[1] + w[0]).abs())
            .fold(0.0, f64::max);
        (v, a)
    }

    #[test]
    fn a_trajectory_within_the_limits_is_unchanged() {
        let x: Vec<f64> = (0..200).map(|k| 0.5 * (k as f64 * 0.02).sin()).collect();
        let mut y = x.clone();
        limit_speed(&mut y, 0.05, 0.01, None);
        assert!(x.iter().zip(&y).all(|(a, b)| (a - b).abs() < 1e-12));
    }

    /// A jump (a branch switch) becomes a ramp within both limits, centred on the jump (no
    /// lag: half before, half after), reaching both sides' values away from it.
    #[test]
    fn a_jump_becomes_a_centred_ramp_within_both_limits() {
        let mut x: Vec<f64> = (0..400).map(|k| if k < 200 { 0.0 } else { 1.0 }).collect();
        let (v, a) = (0.02, 0.002);
        limit_speed(&mut x, v, a, Some((-2.0, 2.0)));
        let (sv, sa) = steps(&x);
        assert!(sv <= v + 1e-12 && sa <= a + 1e-12, "{sv} {sa}");
        assert!((x[0]).abs() < 1e-9 && (x[399] - 1.0).abs() < 1e-9);
        // The half-way crossing sits at the jump.
        let cross = x.iter().position(|v| *v >= 0.5).unwrap();
        assert!((199..=201).contains(&cross), "{cross}");
    }

    /// A first frame in a T-pose, or one noisy frame, is taken from its neighbours; a fast
    /// but real motion (within two frames' travel of its median) is not touched.
    #[test]
    fn glitches_are_taken_from_their_neighbours() {
        let mut x: Vec<f64> = (0..100).map(|k| 0.01 * k as f64).collect();
        let clean = x.clone();
        x[0] = 1.5;
        x[50] = -1.0;
        assert_eq!(remove_glitches(&mut x, 0.05), 2);
        assert!(
            x.iter().zip(&clean).all(|(a, b)| (a - b).abs() < 0.05),
            "{:?}",
            &x[..3]
        );
        let mut fast: Vec<f64> = (0..100).map(|k| 0.08 * k as f64).collect();
        let before = fast.clone();
        assert_eq!(remove_glitches(&mut fast, 0.05), 0);
        assert_eq!(fast, before);
    }

    #[test]
    fn spans_join_near_frames() {
        assert_eq!(spans(&[3, 4, 5, 9, 20, 21], 4), vec![[3, 9], [20, 21]]);
        assert!(spans(&[], 3).is_empty());
    }

    /// The branch plan stays on a branch through a frame where the other is slightly better
    /// (switching there and back would outrun the servo), and moves to the other where it is
    /// better for long.
    #[test]
    fn branches_switch_only_where_it_pays() {
        let limit = [0.05, 1.0, 1.0];
        let mut frames: Vec<ArmSolutions> = Vec::new();
        for k in 0..300 {
            let mut s = ArmSolutions::new();
            // Branch at q = 0: on target, but at frame 100 a limit keeps it 1 mm off, and from
            // frame 200 on 20 mm off. Branch at q = 2: always on target, its elbow 1.5 rad from
            // the human's until frame 200, then 0.3 rad.
            let off = match k {
                100 => 1.0,
                200.. => 20.0,
                _ => 0.0,
            };
            s.push(sol(0.0, off)).unwrap();
            s.push(ArmSolution {
                elbow_error: if k < 200 { 1.5 } else { 0.3 },
                ..sol(2.0, 0.0)
            })
            .unwrap();
            frames.push(s);
        }
        let path = plan_branches(&frames, limit).unwrap();
        assert!(path[..200].iter().all(|b| *b == 0), "{:?}", &path[95..105]);
        assert!(path[200..].iter().all(|b| *b == 1));
        assert_eq!(path.iter().zip(&path[1..]).filter(|(a, b)| a != b).count(), 1);
        let mut empty = frames.clone();
        empty[5].clear();
        assert!(plan_branches(&empty, limit).is_none());
    }
}
