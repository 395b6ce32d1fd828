//! Numerical IK on fixed-size buffers (help note §IV "Numerical IK"): CCD, Jacobian transpose,
//! pseudoinverse `J⁺ = Jᵀ(JJᵀ)⁻¹`, damped least squares `Jᵀ(JJᵀ + λ²I)⁻¹`, and conjugate
//! gradient on the objective eq. (35) with gradient eq. (42). Several constraints at once, a bone
//! mask, root translation off by default; joint limits are enforced inside every iteration.

use glam::{DMat3, DVec3};

use crate::ik::{dof_axis, fk64, Pose64};
use crate::skeleton::{Skeleton, MAX_BONES};

/// Most constraints solved together.
pub const MAX_CONSTRAINTS: usize = 4;
/// Most rows of the Jacobian (3 position + 6 orientation per constraint).
pub const MAX_ROWS: usize = 9 * MAX_CONSTRAINTS;
/// Most variables (DOFs) moved.
pub const MAX_VARS: usize = 96;

/// A goal for one bone's tip: a position and optionally its frame's x and y axes (eq. 35).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Constraint {
    /// The bone whose tip is the effector.
    pub bone: usize,
    /// Goal position, file units.
    pub position: DVec3,
    /// Goal x̂ and ŷ of the bone's local frame (world), if orientation matters.
    pub axes: Option<(DVec3, DVec3)>,
}

/// The method.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Method {
    /// Cyclic coordinate descent.
    Ccd,
    /// Jacobian transpose (step size of Buss & Kim).
    Transpose,
    /// Pseudoinverse `Jᵀ(JJᵀ)⁻¹`.
    Pseudoinverse,
    /// Damped least squares `Jᵀ(JJᵀ + λ²I)⁻¹`.
    DampedLeastSquares,
    /// Conjugate gradient (Polak–Ribière, projected) on eq. (35).
    ConjugateGradient,
}

/// Jacobian by eq. (43)–(47), or by finite differences.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum JacobianKind {
    /// `u × (Tₑ − Tᵢ)`, `u × x̂ₑ`, translation axes for the root.
    Analytic,
    /// Central differences of FK.
    FiniteDifference,
}

/// Solver settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Settings {
    /// The method.
    pub method: Method,
    /// How the Jacobian is formed.
    pub jacobian: JacobianKind,
    /// Stop when every position error is below this (file units) and orientation errors below
    /// `tolerance / c_d`.
    pub tolerance: f64,
    /// Iteration cap.
    pub max_iterations: usize,
    /// Degrees that weigh like one length unit: `c_d = 180/(π·d)` (eq. 36).
    pub degrees_per_unit: f64,
    /// Damping λ of DLS (file units).
    pub damping: f64,
    /// Largest joint change per iteration, radians.
    pub max_step: f64,
    /// Whether the root may translate.
    pub move_root: bool,
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            method: Method::DampedLeastSquares,
            jacobian: JacobianKind::Analytic,
            tolerance: 1e-3,
            max_iterations: 500,
            degrees_per_unit: 10.0,
            damping: 0.5,
            max_step: 0.3,
            move_root: false,
        }
    }
}

/// The outcome of a numerical solve.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Outcome {
    /// Iterations used.
    pub iterations: usize,
    /// Largest position error left, file units.
    pub position_error: f64,
    /// Largest orientation axis error left (|x̂g − x̂e|, |ŷg − ŷe|).
    pub orientation_error: f64,
    /// Whether the tolerance was met.
    pub converged: bool,
}

/// Which bones may move.
pub type BoneMask = [bool; MAX_BONES];

/// A numerical solver with its buffers.
#[derive(Clone, Debug)]
pub struct Solver {
    vars: heapless::Vec<Var, MAX_VARS>,
    jac: [[f64; MAX_VARS]; MAX_ROWS],
    err: [f64; MAX_ROWS],
    rows: usize,
    pose: Pose64,
    lo: [f64; MAX_VARS],
    hi: [f64; MAX_VARS],
}

#[derive(Clone, Copy, Debug)]
struct Var {
    bone: usize,
    dof: usize,
    channel: usize,
    rotation: bool,
}

impl Solver {
    /// A solver for the DOFs of the masked bones (rotations; the root's translations too when
    /// `move_root`). Variables beyond [`MAX_VARS`] are left out.
    #[must_use]
    pub fn new(skeleton: &Skeleton, mask: &BoneMask, move_root: bool) -> Solver {
        let mut s = Solver {
            vars: heapless::Vec::new(),
            jac: [[0.0; MAX_VARS]; MAX_ROWS],
            err: [0.0; MAX_ROWS],
            rows: 0,
            pose: Pose64::default(),
            lo: [0.0; MAX_VARS],
            hi: [0.0; MAX_VARS],
        };
        for (b, bone) in skeleton.bones().iter().enumerate() {
            if !mask[b] {
                continue;
            }
            for (k, d) in bone.dofs().iter().enumerate() {
                let root = bone.parent().is_none();
                let usable = d.is_rotation() || (root && move_root && d.axis().is_some());
                if !usable {
                    continue;
                }
                let n = s.vars.len();
                let (lo, hi) = bone
                    .limits()
                    .get(k)
                    .map_or((f64::NEG_INFINITY, f64::INFINITY), |l| {
                        (f64::from(l.min), f64::from(l.max))
                    });
                if s.vars
                    .push(Var {
                        bone: b,
                        dof: k,
                        channel: bone.first_channel() + k,
                        rotation: d.is_rotation(),
                    })
                    .is_ok()
                {
                    s.lo[n] = lo;
                    s.hi[n] = hi;
                }
            }
        }
        s
    }

    /// Number of variables.
    #[must_use]
    pub fn variables(&self) -> usize {
        self.vars.len()
    }

    /// Whether every variable is within its limits in `channels`.
    #[must_use]
    pub fn within_limits(&self, channels: &[f64]) -> bool {
        self.vars.iter().enumerate().all(|(i, v)| {
            channels[v.channel] >= self.lo[i] - 1e-9 && channels[v.channel] <= self.hi[i] + 1e-9
        })
    }

    /// Forms the Jacobian (eq. 38–47) at `channels` and returns its number of rows; read them
    /// with [`Solver::jacobian_row`].
    pub fn jacobian_at(
        &mut self,
        skeleton: &Skeleton,
        constraints: &[Constraint],
        channels: &mut [f64],
        degrees_per_unit: f64,
        kind: JacobianKind,
    ) -> usize {
        let constraints = &constraints[..constraints.len().min(MAX_CONSTRAINTS)];
        let cd = 180.0 / (core::f64::consts::PI * degrees_per_unit.max(1e-9));
        fk64(skeleton, channels, &mut self.pose);
        self.errors(constraints, cd);
        self.jacobian(skeleton, constraints, channels, cd, kind);
        self.rows
    }

    /// Row `r` of the last Jacobian, one entry per variable.
    #[must_use]
    pub fn jacobian_row(&self, r: usize) -> &[f64] {
        &self.jac[r.min(MAX_ROWS - 1)][..self.vars.len()]
    }

    fn clamp(&self, i: usize, x: f64) -> f64 {
        x.clamp(self.lo[i], self.hi[i])
    }

    /// Error vector `b` (eq. 41, orientation rows scaled by `c_d`) and the largest errors.
    fn errors(&mut self, constraints: &[Constraint], cd: f64) -> (f64, f64) {
        let mut rows = 0;
        let (mut pe, mut oe) = (0.0f64, 0.0f64);
        for c in constraints {
            let d = c.position - self.pose.tip[c.bone];
            pe = pe.max(d.length());
            self.err[rows..rows + 3].copy_from_slice(&d.to_array());
            rows += 3;
            if let Some((xg, yg)) = c.axes {
                let f = self.pose.frame[c.bone];
                let dx = xg - f.x_axis;
                let dy = yg - f.y_axis;
                oe = oe.max(dx.length()).max(dy.length());
                self.err[rows..rows + 3].copy_from_slice(&(dx * cd).to_array());
                self.err[rows + 3..rows + 6].copy_from_slice(&(dy * cd).to_array());
                rows += 6;
            }
        }
        self.rows = rows;
        (pe, oe)
    }

    fn affects(skeleton: &Skeleton, var_bone: usize, effector: usize) -> bool {
        let mut b = Some(effector);
        while let Some(i) = b {
            if i == var_bone {
                return true;
            }
            b = skeleton.bones()[i].parent();
        }
        false
    }

    /// Jacobian eq. (38)–(47) (rows as in [`Solver::errors`]).
    fn jacobian(
        &mut self,
        skeleton: &Skeleton,
        constraints: &[Constraint],
        channels: &mut [f64],
        cd: f64,
        kind: JacobianKind,
    ) {
        match kind {
            JacobianKind::Analytic => {
                for (i, v) in self.vars.iter().enumerate() {
                    let u = dof_axis(skeleton, &self.pose, v.bone, v.dof, channels);
                    let pivot = self.pose.start[v.bone];
                    let mut r = 0;
                    for c in constraints {
                        let on = Self::affects(skeleton, v.bone, c.bone);
                        let dp = if !on {
                            DVec3::ZERO
                        } else if v.rotation {
                            u.cross(self.pose.tip[c.bone] - pivot)
                        } else {
                            u
                        };
                        for k in 0..3 {
                            self.jac[r + k][i] = dp[k];
                        }
                        r += 3;
                        if c.axes.is_some() {
                            let f = self.pose.frame[c.bone];
                            let (dx, dy) = if on && v.rotation {
                                (u.cross(f.x_axis), u.cross(f.y_axis))
                            } else {
                                (DVec3::ZERO, DVec3::ZERO)
                            };
                            for k in 0..3 {
                                self.jac[r + k][i] = dx[k] * cd;
                                self.jac[r + 3 + k][i] = dy[k] * cd;
                            }
                            r += 6;
                        }
                    }
                }
            }
            JacobianKind::FiniteDifference => {
                let h = 1e-6;
                let mut plus = Pose64::default();
                let mut minus = Pose64::default();
                for i in 0..self.vars.len() {
                    let ch = self.vars[i].channel;
                    let x = channels[ch];
                    channels[ch] = x + h;
                    fk64(skeleton, channels, &mut plus);
                    channels[ch] = x - h;
                    fk64(skeleton, channels, &mut minus);
                    channels[ch] = x;
                    let mut r = 0;
                    for c in constraints {
                        let dp = (plus.tip[c.bone] - minus.tip[c.bone]) / (2.0 * h);
                        for k in 0..3 {
                            self.jac[r + k][i] = dp[k];
                        }
                        r += 3;
                        if c.axes.is_some() {
                            let dx = (plus.frame[c.bone].x_axis - minus.frame[c.bone].x_axis) / (2.0 * h);
                            let dy = (plus.frame[c.bone].y_axis - minus.frame[c.bone].y_axis) / (2.0 * h);
                            for k in 0..3 {
                                self.jac[r + k][i] = dx[k] * cd;
                                self.jac[r + 3 + k][i] = dy[k] * cd;
                            }
                            r += 6;
                        }
                    }
                }
            }
        }
    }

    /// Objective eq. (35) summed over the constraints.
    fn objective(
        &mut self,
        skeleton: &Skeleton,
        constraints: &[Constraint],
        channels: &[f64],
        cd: f64,
    ) -> f64 {
        fk64(skeleton, channels, &mut self.pose);
        let mut p = 0.0;
        for c in constraints {
            p += (c.position - self.pose.tip[c.bone]).length_squared();
            if let Some((xg, yg)) = c.axes {
                let f = self.pose.frame[c.bone];
                p += cd * cd * ((xg - f.x_axis).length_squared() + (yg - f.y_axis).length_squared());
            }
        }
        p
    }

    /// Applies `Δθ` scaled so no joint moves more than `max_step`, projected onto the limits.
    fn apply(&self, channels: &mut [f64], delta: &[f64], max_step: f64) {
        let n = self.vars.len();
        let big = delta[..n]
            .iter()
            .enumerate()
            .filter(|(i, _)| self.vars[*i].rotation)
            .fold(0.0f64, |m, (_, d)| m.max(d.abs()));
        let scale = if big > max_step { max_step / big } else { 1.0 };
        for (i, v) in self.vars.iter().enumerate() {
            let x = channels[v.channel] + scale * delta[i];
            channels[v.channel] = self.clamp(i, x);
        }
    }

    /// Solves for `constraints` starting from (and writing into) `channels`.
    pub fn solve(
        &mut self,
        skeleton: &Skeleton,
        constraints: &[Constraint],
        channels: &mut [f64],
        settings: &Settings,
    ) -> Outcome {
        let constraints = &constraints[..constraints.len().min(MAX_CONSTRAINTS)];
        let cd = 180.0 / (core::f64::consts::PI * settings.degrees_per_unit.max(1e-9));
        let otol = settings.tolerance / cd;
        // Start inside the limits.
        for (i, v) in self.vars.iter().enumerate() {
            channels[v.channel] = self.clamp(i, channels[v.channel]);
        }
        let n = self.vars.len();
        let mut delta = [0.0f64; MAX_VARS];
        let mut grad_prev = [0.0f64; MAX_VARS];
        let mut dir = [0.0f64; MAX_VARS];
        let mut it = 0;
        let (mut pe, mut oe);
        loop {
            fk64(skeleton, channels, &mut self.pose);
            (pe, oe) = self.errors(constraints, cd);
            if (pe <= settings.tolerance && oe <= otol) || it >= settings.max_iterations || n == 0 {
                break;
            }
            it += 1;
            match settings.method {
                Method::Ccd => self.ccd_sweep(skeleton, constraints, channels, cd),
                Method::Transpose => {
                    self.jacobian(skeleton, constraints, channels, cd, settings.jacobian);
                    // Δθ = α Jᵀe with α = ⟨e, JJᵀe⟩ / ⟨JJᵀe, JJᵀe⟩.
                    self.jt_e(&mut delta);
                    let mut jjte = [0.0f64; MAX_ROWS];
                    for (r, out) in jjte.iter_mut().enumerate().take(self.rows) {
                        *out = (0..n).map(|i| self.jac[r][i] * delta[i]).sum();
                    }
                    let num: f64 = (0..self.rows).map(|r| self.err[r] * jjte[r]).sum();
                    let den: f64 = (0..self.rows).map(|r| jjte[r] * jjte[r]).sum();
                    let alpha = if den > 1e-30 { num / den } else { 0.0 };
                    for d in delta.iter_mut().take(n) {
                        *d *= alpha;
                    }
                    self.apply(channels, &delta, settings.max_step);
                }
                Method::Pseudoinverse | Method::DampedLeastSquares => {
                    self.jacobian(skeleton, constraints, channels, cd, settings.jacobian);
                    let lambda2 = if settings.method == Method::DampedLeastSquares {
                        settings.damping * settings.damping
                    } else {
                        1e-10
                    };
                    if !self.least_squares_step(lambda2, &mut delta) {
                        break;
                    }
                    self.apply(channels, &delta, settings.max_step);
                }
                Method::ConjugateGradient => {
                    self.jacobian(skeleton, constraints, channels, cd, settings.jacobian);
                    // ∇P = −2Jᵀb (eq. 42); descend along the Polak–Ribière direction.
                    let mut grad = [0.0f64; MAX_VARS];
                    self.jt_e(&mut grad);
                    for g in grad.iter_mut().take(n) {
                        *g *= -2.0;
                    }
                    let gg_prev: f64 = grad_prev[..n].iter().map(|g| g * g).sum();
                    let beta = if it == 1 || gg_prev < 1e-30 || it % n.max(1) == 0 {
                        0.0
                    } else {
                        ((0..n).map(|i| grad[i] * (grad[i] - grad_prev[i])).sum::<f64>() / gg_prev).max(0.0)
                    };
                    for i in 0..n {
                        dir[i] = -grad[i] + beta * dir[i];
                    }
                    if (0..n).map(|i| dir[i] * grad[i]).sum::<f64>() >= 0.0 {
                        for i in 0..n {
                            dir[i] = -grad[i];
                        }
                    }
                    grad_prev = grad;
                    if !self.line_search(skeleton, constraints, channels, &dir, cd, settings.max_step) {
                        // No decrease along the direction: restart from steepest descent.
                        for i in 0..n {
                            dir[i] = -grad[i];
                        }
                        if !self.line_search(skeleton, constraints, channels, &dir, cd, settings.max_step) {
                            break;
                        }
                    }
                }
            }
        }
        Outcome {
            iterations: it,
            position_error: pe,
            orientation_error: oe,
            converged: pe <= settings.tolerance && oe <= otol,
        }
    }

    fn jt_e(&self, out: &mut [f64; MAX_VARS]) {
        for (i, o) in out.iter_mut().enumerate().take(self.vars.len()) {
            *o = (0..self.rows).map(|r| self.jac[r][i] * self.err[r]).sum();
        }
    }

    /// `Δθ = Jᵀ (JJᵀ + λ²I)⁻¹ e`; false when the system is singular.
    #[allow(clippy::needless_range_loop)]
    fn least_squares_step(&self, lambda2: f64, delta: &mut [f64; MAX_VARS]) -> bool {
        let (m, n) = (self.rows, self.vars.len());
        let mut a = [[0.0f64; MAX_ROWS]; MAX_ROWS];
        let mut y = [0.0f64; MAX_ROWS];
        for r in 0..m {
            for c in 0..=r {
                let v: f64 = (0..n).map(|i| self.jac[r][i] * self.jac[c][i]).sum();
                a[r][c] = v;
                a[c][r] = v;
            }
            a[r][r] += lambda2;
            y[r] = self.err[r];
        }
        if !solve_linear(&mut a, &mut y, m) {
            return false;
        }
        for (i, d) in delta.iter_mut().enumerate().take(n) {
            *d = (0..m).map(|r| self.jac[r][i] * y[r]).sum();
        }
        true
    }

    /// Backtracking line search along `dir` with projection onto the limits; true on decrease.
    fn line_search(
        &mut self,
        skeleton: &Skeleton,
        constraints: &[Constraint],
        channels: &mut [f64],
        dir: &[f64; MAX_VARS],
        cd: f64,
        max_step: f64,
    ) -> bool {
        let n = self.vars.len();
        let f0 = self.objective(skeleton, constraints, channels, cd);
        let big = dir[..n].iter().fold(0.0f64, |m, d| m.max(d.abs()));
        if big < 1e-300 {
            return false;
        }
        let mut t = max_step / big;
        let mut saved = [0.0f64; MAX_VARS];
        for (i, v) in self.vars.iter().enumerate() {
            saved[i] = channels[v.channel];
        }
        for _ in 0..40 {
            for (i, v) in self.vars.iter().enumerate() {
                channels[v.channel] = self.clamp(i, saved[i] + t * dir[i]);
            }
            if self.objective(skeleton, constraints, channels, cd) < f0 {
                return true;
            }
            t *= 0.5;
        }
        for (i, v) in self.vars.iter().enumerate() {
            channels[v.channel] = saved[i];
        }
        false
    }

    /// One CCD sweep from the effector end: each DOF turned to best align the effectors with
    /// their goals about its own axis, clamped to its limits.
    fn ccd_sweep(&mut self, skeleton: &Skeleton, constraints: &[Constraint], channels: &mut [f64], cd: f64) {
        for i in (0..self.vars.len()).rev() {
            let v = self.vars[i];
            fk64(skeleton, channels, &mut self.pose);
            let u = dof_axis(skeleton, &self.pose, v.bone, v.dof, channels);
            if v.rotation {
                let pivot = self.pose.start[v.bone];
                let (mut num, mut den) = (0.0, 0.0);
                for c in constraints
                    .iter()
                    .filter(|c| Self::affects(skeleton, v.bone, c.bone))
                {
                    let mut acc = |a: DVec3, b: DVec3, w: f64| {
                        let a = a - u * u.dot(a);
                        let b = b - u * u.dot(b);
                        num += w * u.dot(a.cross(b));
                        den += w * a.dot(b);
                    };
                    acc(self.pose.tip[c.bone] - pivot, c.position - pivot, 1.0);
                    if let Some((xg, yg)) = c.axes {
                        let f: DMat3 = self.pose.frame[c.bone];
                        acc(f.x_axis, xg, cd * cd);
                        acc(f.y_axis, yg, cd * cd);
                    }
                }
                if num != 0.0 || den != 0.0 {
                    let delta = libm::atan2(num, den);
                    channels[v.channel] = self.clamp(i, channels[v.channel] + delta);
                }
            } else {
                let mut step = 0.0;
                let mut count = 0.0;
                for c in constraints
                    .iter()
                    .filter(|c| Self::affects(skeleton, v.bone, c.bone))
                {
                    step += u.dot(c.position - self.pose.tip[c.bone]);
                    count += 1.0;
                }
                if count > 0.0 {
                    channels[v.channel] = self.clamp(i, channels[v.channel] + step / count);
                }
            }
        }
    }
}

#[allow(clippy::needless_range_loop)]
/// Solves `A·x = y` in place (Gaussian elimination, partial pivoting) for the leading `m`×`m`
/// block; `y` becomes `x`. False when singular.
fn solve_linear(a: &mut [[f64; MAX_ROWS]; MAX_ROWS], y: &mut [f64; MAX_ROWS], m: usize) -> bool {
    for col in 0..m {
        let piv = (col..m)
            .max_by(|&i, &j| a[i][col].abs().total_cmp(&a[j][col].abs()))
            .unwrap_or(col);
        if a[piv][col].abs() < 1e-14 {
            return false;
        }
        a.swap(col, piv);
        y.swap(col, piv);
        for r in col + 1..m {
            let f = a[r][col] / a[col][col];
            if f != 0.0 {
                for c in col..m {
                    a[r][c] -= f * a[col][c];
                }
                y[r] -= f * y[col];
            }
        }
    }
    for col in (0..m).rev() {
        let s: f64 = (col + 1..m).map(|c| a[col][c] * y[c]).sum();
        y[col] = (y[col] - s) / a[col][col];
    }
    true
}

/// A mask with the bones from `from` down to `to` (the chain between them) set.
#[must_use]
pub fn chain_mask(skeleton: &Skeleton, from: usize, to: usize) -> BoneMask {
    let mut mask = [false; MAX_BONES];
    let mut b = Some(to);
    while let Some(i) = b {
        mask[i] = true;
        if i == from {
            break;
        }
        b = skeleton.bones()[i].parent();
    }
    mask
}
