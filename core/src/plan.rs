//! Look-ahead planning of one servo's goal path over a preview window.
//!
//! A greedy limiter aims at this tick's target and clamps; when the future of the motion is
//! known (a clip) the goal path can instead start a fast move early and share the unavoidable
//! error before and after it. Per servo and tick, over `n` knots `h` seconds apart, the plan
//! is the path that deviates least (least squares) from the reference `r` (the source, led by
//! the servo's lag):
//!
//! ```text
//! minimise Σⱼ (xⱼ − rⱼ)²   over accelerations |a| ≤ a_max,
//! vⱼ = vⱼ₋₁ + a·h,   xⱼ = xⱼ₋₁ + vⱼ·h,   from the last goal x₀ moving at v₀
//! ```
//!
//! The acceleration is piecewise constant over segments that double in length (1, 2, 4, 8 …
//! knots): fine where this tick's decision is made, coarse further out where only the
//! shape of what comes matters. Without the velocity limit the knots are linear in the `K`
//! segment accelerations, `x = x_free + B·p`, so the plan is a `K`-variable least-squares
//! problem inside a box, solved exactly by a primal active-set method on `BᵀB` (built once per
//! window). The path is then run forward through the velocity and position limits, so the
//! first step is feasible by construction; the command stage still enforces every limit.

use crate::math::Real;
use crate::servo::{brake_and_move, MotionLimits};

/// Most knots in a preview window.
pub const MAX_KNOTS: usize = 32;

/// Most acceleration segments in a window.
pub const MAX_SEGMENTS: usize = 8;

/// The shape of a preview window, shared by every servo planned with it.
#[derive(Clone, Debug, PartialEq)]
pub struct Window {
    knots: usize,
    spacing_s: Real,
    segments: usize,
    /// Segment `k` drives knots `start[k] .. start[k + 1]`.
    start: [usize; MAX_SEGMENTS + 1],
    /// `B[j][k]`: position of knot `j` per unit acceleration over segment `k`.
    response: [[Real; MAX_SEGMENTS]; MAX_KNOTS],
    /// `BᵀB`, with a little ridge for conditioning.
    gram: [[Real; MAX_SEGMENTS]; MAX_SEGMENTS],
    /// Its inverse: the unconstrained plan is `(BᵀB)⁻¹·c`, which most ticks keep.
    gram_inverse: [[Real; MAX_SEGMENTS]; MAX_SEGMENTS],
}

impl Window {
    /// A window of `knots` knots (clamped to 2 … [`MAX_KNOTS`]) `spacing_s` seconds apart.
    #[must_use]
    pub fn new(knots: usize, spacing_s: Real) -> Window {
        let n = knots.clamp(2, MAX_KNOTS);
        let h = if spacing_s.is_finite() && spacing_s > 0.0 {
            spacing_s
        } else {
            1e-3
        };
        let mut start = [n; MAX_SEGMENTS + 1];
        start[0] = 0;
        let mut segments = 0;
        let mut at = 0;
        let mut len = 1;
        while at < n && segments < MAX_SEGMENTS {
            let end = if segments + 1 == MAX_SEGMENTS {
                n
            } else {
                (at + len).min(n)
            };
            segments += 1;
            start[segments] = end;
            at = end;
            len *= 2;
        }
        // A last segment shorter than half its predecessor joins it.
        if segments >= 2 {
            let last = start[segments] - start[segments - 1];
            let before = start[segments - 1] - start[segments - 2];
            if 2 * last < before {
                start[segments - 1] = n;
                segments -= 1;
            }
        }
        let mut response = [[0.0; MAX_SEGMENTS]; MAX_KNOTS];
        for (j, row) in response.iter_mut().enumerate().take(n) {
            for (k, b) in row.iter_mut().enumerate().take(segments) {
                // Σ over the segment's knots m ≤ j of (j − m + 1)·h².
                let hi = start[k + 1].min(j + 1);
                for m in start[k]..hi {
                    *b += (j - m + 1) as Real * h * h;
                }
            }
        }
        let mut gram = [[0.0; MAX_SEGMENTS]; MAX_SEGMENTS];
        for row in response.iter().take(n) {
            for a in 0..segments {
                for b in 0..segments {
                    gram[a][b] += row[a] * row[b];
                }
            }
        }
        let ridge = 1e-9 * (0..segments).map(|k| gram[k][k]).sum::<Real>() / segments as Real;
        for (k, row) in gram.iter_mut().enumerate().take(segments) {
            row[k] += ridge;
        }
        let mut gram_inverse = [[0.0; MAX_SEGMENTS]; MAX_SEGMENTS];
        for k in 0..segments {
            let mut a = gram;
            let mut e = [0.0; MAX_SEGMENTS];
            e[k] = 1.0;
            let column = solve_dense(&mut a, &mut e, segments);
            for (row, v) in gram_inverse.iter_mut().zip(column).take(segments) {
                row[k] = v;
            }
        }
        Window {
            knots: n,
            spacing_s: h,
            segments,
            start,
            response,
            gram,
            gram_inverse,
        }
    }

    /// Knots in the window.
    #[must_use]
    pub fn knots(&self) -> usize {
        self.knots
    }

    /// Seconds between knots.
    #[must_use]
    pub fn spacing_s(&self) -> Real {
        self.spacing_s
    }

    /// Acceleration segments.
    #[must_use]
    pub fn segments(&self) -> usize {
        self.segments
    }

    fn segment_of(&self, knot: usize) -> usize {
        (1..=self.segments)
            .find(|&k| knot < self.start[k])
            .map_or(self.segments - 1, |k| k - 1)
    }
}

/// One step of the double integrator within the limits: the velocity after accelerating at
/// `a` for `dt` (bounded by the velocity limit and by the speed that can still stop at the
/// position limits), and the position it reaches.
fn advance(x: Real, v: Real, a: Real, dt: Real, limits: &MotionLimits) -> (Real, Real) {
    let (vmax, amax, lo, hi) = limits.sane();
    brake_and_move(x, (v + a * dt).clamp(-vmax, vmax), dt, amax, lo, hi)
}

/// Solves `min ½pᵀGp − cᵀp` subject to `|p_k| ≤ bound` by a primal active-set method
/// (exact for the small dense problems of a window; at most `4K` steps), started from `start`
/// clamped into the box with the clamped variables held at their bounds (the unconstrained
/// optimum clamped: usually one or two steps from the answer).
fn box_least_squares(
    g: &[[Real; MAX_SEGMENTS]; MAX_SEGMENTS],
    c: &[Real; MAX_SEGMENTS],
    k: usize,
    bound: Real,
    start: &[Real; MAX_SEGMENTS],
) -> [Real; MAX_SEGMENTS] {
    let mut p = [0.0; MAX_SEGMENTS];
    let mut fixed = [false; MAX_SEGMENTS];
    for i in 0..k {
        if start[i].abs() >= bound {
            p[i] = bound.copysign(start[i]);
            fixed[i] = true;
        }
    }
    for _ in 0..4 * k + 4 {
        // The minimum over the free variables with the fixed ones at their bounds.
        let mut a = [[0.0; MAX_SEGMENTS]; MAX_SEGMENTS];
        let mut rhs = [0.0; MAX_SEGMENTS];
        let mut free = [0usize; MAX_SEGMENTS];
        let mut m = 0;
        for i in (0..k).filter(|&i| !fixed[i]) {
            free[m] = i;
            m += 1;
        }
        for (r, &i) in free[..m].iter().enumerate() {
            rhs[r] = c[i] - (0..k).filter(|&j| fixed[j]).map(|j| g[i][j] * p[j]).sum::<Real>();
            for (s, &j) in free[..m].iter().enumerate() {
                a[r][s] = g[i][j];
            }
        }
        let q = solve_dense(&mut a, &mut rhs, m);
        // Step towards it as far as the box allows.
        let mut alpha: Real = 1.0;
        let mut blocking = None;
        for (r, &i) in free[..m].iter().enumerate() {
            let d = q[r] - p[i];
            let room = if d > 0.0 { bound - p[i] } else { -bound - p[i] };
            if d.abs() > 0.0 && (q[r].abs() > bound) {
                let t = (room / d).clamp(0.0, 1.0);
                if t < alpha {
                    alpha = t;
                    blocking = Some(i);
                }
            }
        }
        for (r, &i) in free[..m].iter().enumerate() {
            p[i] += alpha * (q[r] - p[i]);
        }
        if let Some(i) = blocking {
            p[i] = if p[i] >= 0.0 { bound } else { -bound };
            fixed[i] = true;
            continue;
        }
        // Optimal on this face: release a bound whose multiplier has the wrong sign.
        let mut release = None;
        let mut worst = 0.0;
        for i in (0..k).filter(|&i| fixed[i]) {
            let grad = (0..k).map(|j| g[i][j] * p[j]).sum::<Real>() - c[i];
            // At the upper bound the cost must not fall going down (grad ≤ 0), and the
            // other way round at the lower.
            let wrong = if p[i] > 0.0 { grad } else { -grad };
            if wrong > worst {
                worst = wrong;
                release = Some(i);
            }
        }
        match release {
            Some(i) => fixed[i] = false,
            None => break,
        }
    }
    p
}

/// Solves the `m`×`m` system `a·x = b` by Gaussian elimination with partial pivoting (a
/// singular pivot gives 0 for that unknown).
fn solve_dense(
    a: &mut [[Real; MAX_SEGMENTS]; MAX_SEGMENTS],
    b: &mut [Real; MAX_SEGMENTS],
    m: usize,
) -> [Real; MAX_SEGMENTS] {
    for col in 0..m {
        let pivot = (col..m)
            .max_by(|&x, &y| a[x][col].abs().total_cmp(&a[y][col].abs()))
            .unwrap_or(col);
        a.swap(col, pivot);
        b.swap(col, pivot);
        let d = a[col][col];
        if d.abs() < 1e-300 {
            continue;
        }
        for row in col + 1..m {
            let f = a[row][col] / d;
            let pivot_row = a[col];
            for (x, p) in a[row][col..m].iter_mut().zip(&pivot_row[col..m]) {
                *x -= f * p;
            }
            b[row] -= f * b[col];
        }
    }
    let mut x = [0.0; MAX_SEGMENTS];
    for row in (0..m).rev() {
        let s = b[row] - (row + 1..m).map(|k| a[row][k] * x[k]).sum::<Real>();
        x[row] = if a[row][row].abs() < 1e-300 {
            0.0
        } else {
            s / a[row][row]
        };
    }
    x
}

/// One servo's planner: its limits and its last plan (no allocation).
#[derive(Clone, Debug)]
pub struct ServoPlan {
    limits: MotionLimits,
    /// The last plan: its start and segment accelerations.
    start: (Real, Real),
    accelerations: [Real; MAX_SEGMENTS],
}

impl ServoPlan {
    /// A planner for one servo within `limits`.
    #[must_use]
    pub fn new(limits: MotionLimits) -> ServoPlan {
        ServoPlan {
            limits,
            start: (0.0, 0.0),
            accelerations: [0.0; MAX_SEGMENTS],
        }
    }

    /// The knots of the last [`ServoPlan::plan`] over `window`, run through the limits, into
    /// `out` (as many as both hold).
    pub fn knots(&self, window: &Window, out: &mut [Real]) {
        let (mut x, mut v) = self.start;
        for (j, o) in out.iter_mut().enumerate().take(window.knots) {
            let a = self.accelerations[window.segment_of(j)];
            (x, v) = advance(x, v, a, window.spacing_s, &self.limits);
            *o = x;
        }
    }

    /// The goal `dt` seconds after `x` (moving at `v`) at the last plan's first acceleration:
    /// what the plan commands over its first knot, when the loop ticks faster than the knots.
    #[must_use]
    pub fn go_on(&self, x: Real, v: Real, dt: Real) -> Real {
        let (goal, _) = advance(x, v, self.accelerations[0], dt, &self.limits);
        if goal.is_finite() {
            goal
        } else {
            x
        }
    }

    /// Plans over `window` from the last goal `x0` moving at `v0` (units/s) towards
    /// `reference` (the window's knots: the reference at `x0`'s time + (j+1)·h); returns the
    /// goal `dt` seconds after `x0`. References that are not finite are treated as the last
    /// finite one (or `x0`); all are clamped to the position limits.
    pub fn plan(&mut self, window: &Window, x0: Real, v0: Real, reference: &[Real], dt: Real) -> Real {
        let n = window.knots;
        let h = window.spacing_s;
        let k = window.segments;
        let (vmax, amax, lo, hi) = self.limits.sane();
        let x0 = if x0.is_finite() {
            x0.clamp(lo, hi)
        } else {
            lo.max(0.0).min(hi)
        };
        let v0 = if v0.is_finite() {
            v0.clamp(-vmax, vmax)
        } else {
            0.0
        };
        // What the reference asks beyond coasting at v₀: c = Bᵀ(r − x_free).
        let mut c = [0.0; MAX_SEGMENTS];
        let mut last = x0;
        for j in 0..n {
            let r = reference.get(j).copied().unwrap_or(last);
            if r.is_finite() {
                last = r.clamp(lo, hi);
            }
            let e = last - (x0 + (j + 1) as Real * h * v0);
            for (ck, b) in c.iter_mut().zip(&window.response[j]).take(k) {
                *ck += b * e;
            }
        }
        let bound = if amax.is_finite() {
            amax
        } else {
            crate::math::precision(1e300, 1e30)
        };
        // The unconstrained optimum when it keeps the box (most ticks), else the active set.
        let mut p = [0.0; MAX_SEGMENTS];
        for (pi, row) in p.iter_mut().zip(&window.gram_inverse).take(k) {
            *pi = row.iter().zip(&c).take(k).map(|(g, ci)| g * ci).sum();
        }
        if p[..k].iter().any(|v| v.abs() > bound) {
            // From the last plan's active set when it had one (a servo's plans change little
            // from one to the next: 1.9 steps a plan against 3.0 on the walk at 1 kHz), else
            // from this optimum clamped.
            let boxed = self.accelerations[..k].iter().any(|a| a.abs() >= bound);
            let start = if boxed { self.accelerations } else { p };
            p = box_least_squares(&window.gram, &c, k, bound, &start);
        }
        self.start = (x0, v0);
        self.accelerations = p;
        let dt = if dt.is_finite() && dt > 0.0 { dt } else { h };
        let (goal, _) = advance(x0, v0, p[0], dt, &self.limits);
        if goal.is_finite() {
            goal
        } else {
            x0
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn limits() -> MotionLimits {
        MotionLimits {
            velocity: 100.0,
            acceleration: 1000.0,
            min: -1000.0,
            max: 1000.0,
        }
    }

    #[test]
    fn segments_double_and_cover_the_window() {
        let w = Window::new(24, 0.01);
        assert_eq!(&w.start[..=w.segments], &[0, 1, 3, 7, 15, 24]);
        assert_eq!(w.segment_of(0), 0);
        assert_eq!(w.segment_of(2), 1);
        assert_eq!(w.segment_of(23), 4);
        // B by simulation: unit acceleration over segment 2 only.
        let (mut x, mut v) = (0.0, 0.0);
        for j in 0..24 {
            let a = if w.segment_of(j) == 2 { 1.0 } else { 0.0 };
            v += a * 0.01;
            x += v * 0.01;
            assert!((w.response[j][2] - x).abs() < 1e-15, "{j}");
        }
    }

    #[test]
    fn the_box_solver_matches_brute_force() {
        let w = Window::new(16, 0.01);
        let k = w.segments;
        let mut rng = 12345u64;
        let mut next = || {
            rng = rng
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (rng >> 11) as Real / (1u64 << 53) as Real * 2.0 - 1.0
        };
        for _ in 0..200 {
            let c: [Real; MAX_SEGMENTS] = core::array::from_fn(|i| if i < k { next() * 1e-3 } else { 0.0 });
            let bound = 0.5 + next().abs() * 3.0;
            let p = box_least_squares(&w.gram, &c, k, bound, &[0.0; MAX_SEGMENTS]);
            // From the unconstrained optimum clamped: the same answer.
            let mut free = [0.0; MAX_SEGMENTS];
            for (f, row) in free.iter_mut().zip(&w.gram_inverse).take(k) {
                *f = row.iter().zip(&c).take(k).map(|(g, ci)| g * ci).sum();
            }
            let q = box_least_squares(&w.gram, &c, k, bound, &free);
            // From any active set (a servo's last plan's): the same answer.
            let guess: [Real; MAX_SEGMENTS] = core::array::from_fn(|_| match next() {
                x if x > 0.3 => bound,
                x if x < -0.3 => -bound,
                _ => 0.0,
            });
            let r = box_least_squares(&w.gram, &c, k, bound, &guess);
            for i in 0..k {
                assert!((p[i] - q[i]).abs() <= 1e-9 * bound, "{p:?} {q:?}");
                assert!((p[i] - r[i]).abs() <= 1e-9 * bound, "{p:?} {r:?} from {guess:?}");
            }
            let cost = |p: &[Real; MAX_SEGMENTS]| {
                let mut s = 0.0;
                for i in 0..k {
                    for j in 0..k {
                        s += 0.5 * p[i] * w.gram[i][j] * p[j];
                    }
                    s -= c[i] * p[i];
                }
                s
            };
            assert!(p[..k].iter().all(|v| v.abs() <= bound + 1e-12));
            // No feasible point nearby is better (a local check of the KKT conditions).
            let best = cost(&p);
            for i in 0..k {
                for d in [-1e-4, 1e-4] {
                    let mut q = p;
                    q[i] = (q[i] + d).clamp(-bound, bound);
                    assert!(cost(&q) >= best - 1e-15, "{p:?}");
                }
            }
        }
    }

    #[test]
    fn a_feasible_reference_is_followed_exactly() {
        let w = Window::new(16, 0.01);
        let mut p = ServoPlan::new(limits());
        // A ramp at 50/s from 0 moving at 50/s: coasting is the plan.
        let r: [Real; 16] = core::array::from_fn(|j| 0.5 * (j + 1) as Real);
        let next = p.plan(&w, 0.0, 50.0, &r, 0.01);
        assert!((next - 0.5).abs() < 1e-9, "{next}");
        // A sine within the limits, tick after tick: the goal is the reference.
        let src = |t: Real| 20.0 * crate::math::real::sin(3.0 * t);
        let (mut x, mut v) = (0.0, 60.0);
        let mut worst = 0.0f64;
        for i in 0..300 {
            let t0 = i as Real * 0.01;
            let r: [Real; 16] = core::array::from_fn(|j| src(t0 + (j + 1) as Real * 0.01));
            let g = p.plan(&w, x, v, &r, 0.01);
            v = (g - x) / 0.01;
            x = g;
            worst = worst.max((x - src(t0 + 0.01)).abs());
        }
        assert!(worst < 0.05, "{worst}");
    }

    #[test]
    fn a_step_is_anticipated_within_the_limits() {
        // A step of 5 at knot 10 needs about 14 knots at the acceleration limit: the plan
        // starts before it and arrives; every step keeps the limits.
        let w = Window::new(24, 0.01);
        let l = limits();
        let mut p = ServoPlan::new(l);
        let (mut x, mut v) = (0.0, 0.0);
        let mut path = [0.0; 30];
        for (i, slot) in path.iter_mut().enumerate() {
            let r: [Real; 24] = core::array::from_fn(|j| if i + j + 1 >= 10 { 5.0 } else { 0.0 });
            let g = p.plan(&w, x, v, &r, 0.01);
            let nv = (g - x) / 0.01;
            assert!(nv.abs() <= l.velocity + 1e-9 && (nv - v).abs() <= l.acceleration * 0.01 + 1e-9);
            v = nv;
            x = g;
            *slot = x;
        }
        assert!(path[3] > 0.05, "starts early: {path:?}");
        assert!(path[6] < 2.5 && path[12] > 2.5, "shares the error: {path:?}");
        assert!((path[29] - 5.0).abs() < 0.1, "arrives: {path:?}");
    }

    #[test]
    fn bad_references_give_finite_goals_inside_the_limits() {
        let w = Window::new(8, 0.01);
        let mut p = ServoPlan::new(limits());
        for r in [[Real::NAN; 8], [Real::INFINITY; 8], [-1e300; 8], [1e12; 8]] {
            let g = p.plan(&w, 0.0, 0.0, &r, 0.01);
            assert!(g.is_finite() && g.abs() <= 1000.0, "{g}");
            assert!((g / 0.01).abs() <= 1000.0 * 0.01 / 0.01 + 1e-9);
        }
    }
}
