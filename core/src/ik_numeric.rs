//! Numerical IK on fixed-size buffers (help note §IV "Numerical IK"): CCD, Jacobian transpose,
//! pseudoinverse `J⁺ = Jᵀ(JJᵀ)⁻¹`, damped least squares `Jᵀ(JJᵀ + λ²I)⁻¹`, and conjugate
//! gradient on the objective eq. (35) with gradient eq. (42). Several constraints at once, a bone
//! mask, root translation off by default; joint limits are enforced inside every iteration.

use crate::math::{real, Real, RealMat3, RealVec3};

use crate::fk::{fk64_bones, Pose64};
use crate::ik::dof_axis;
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
    pub position: RealVec3,
    /// Goal x̂ and ŷ of the bone's local frame (world), if orientation matters.
    pub axes: Option<(RealVec3, RealVec3)>,
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

impl Method {
    /// Every method, in the order of the help note.
    pub const ALL: [Method; 5] = [
        Method::Ccd,
        Method::Transpose,
        Method::Pseudoinverse,
        Method::DampedLeastSquares,
        Method::ConjugateGradient,
    ];
}

/// An IK method as a user names it (`marionette ik --method`, the studio): the analytic limb
/// or one of the numerical [`Method`]s.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum IkMethod {
    /// Analytic 2-bone limb with the swivel searched inside the joint limits (eq. 27–30).
    Analytic,
    /// Cyclic coordinate descent.
    Ccd,
    /// Jacobian transpose.
    Jt,
    /// Pseudoinverse.
    Pinv,
    /// Damped least squares.
    Dls,
    /// Conjugate gradient on eq. (35).
    Cg,
}

impl IkMethod {
    /// Every method.
    pub const ALL: [IkMethod; 6] = [
        IkMethod::Analytic,
        IkMethod::Ccd,
        IkMethod::Jt,
        IkMethod::Pinv,
        IkMethod::Dls,
        IkMethod::Cg,
    ];

    /// Every method's name, in the order of [`IkMethod::ALL`].
    pub const NAMES: [&'static str; 6] = ["analytic", "ccd", "jt", "pinv", "dls", "cg"];

    /// The name (`ik --method`).
    #[must_use]
    pub fn name(self) -> &'static str {
        Self::NAMES[self as usize]
    }

    /// The method called `name`.
    #[must_use]
    pub fn parse(name: &str) -> Option<IkMethod> {
        IkMethod::ALL.into_iter().find(|m| m.name() == name)
    }

    /// The numerical method, `None` for the analytic limb.
    #[must_use]
    pub fn numeric(self) -> Option<Method> {
        match self {
            IkMethod::Analytic => None,
            IkMethod::Ccd => Some(Method::Ccd),
            IkMethod::Jt => Some(Method::Transpose),
            IkMethod::Pinv => Some(Method::Pseudoinverse),
            IkMethod::Dls => Some(Method::DampedLeastSquares),
            IkMethod::Cg => Some(Method::ConjugateGradient),
        }
    }
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
    pub tolerance: Real,
    /// Iteration cap.
    pub max_iterations: usize,
    /// Degrees that weigh like one length unit: `c_d = 180/(π·d)` (eq. 36).
    pub degrees_per_unit: Real,
    /// Damping λ of DLS (file units).
    pub damping: Real,
    /// Largest joint change per iteration, radians.
    pub max_step: Real,
    /// Whether the root may translate.
    pub move_root: bool,
    /// Restarts allowed when a solve stalls short of the tolerance (a local minimum against the
    /// limits): first from the centre of the limit box, then from seeded random points inside
    /// it. The best result is kept; the iteration cap counts all attempts. `0` for warm-started
    /// streams, where a jump to another pose is worse than a small residual.
    pub restarts: usize,
    /// Iterations without a 10 % drop of the squared residual after which a solve counts as
    /// stalled. CCD and the Jacobian transpose converge linearly, slowly near a straight limb or
    /// a limit: an interactive solve gives them longer than a batch one.
    pub patience: usize,
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
            restarts: 8,
            patience: 6,
        }
    }
}

/// The outcome of a numerical solve.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Outcome {
    /// Iterations used.
    pub iterations: usize,
    /// Largest position error left, file units.
    pub position_error: Real,
    /// Largest orientation axis error left (|x̂g − x̂e|, |ŷg − ŷe|).
    pub orientation_error: Real,
    /// Whether the tolerance was met.
    pub converged: bool,
}

/// Which bones may move.
pub type BoneMask = [bool; MAX_BONES];

/// A numerical solver with its buffers.
#[derive(Clone, Debug)]
pub struct Solver {
    vars: heapless::Vec<Var, MAX_VARS>,
    jac: [[Real; MAX_VARS]; MAX_ROWS],
    err: [Real; MAX_ROWS],
    rows: usize,
    pose: Pose64,
    lo: [Real; MAX_VARS],
    hi: [Real; MAX_VARS],
    /// The constraint bones and their ancestors, ascending: all FK has to compute.
    needed: heapless::Vec<usize, MAX_BONES>,
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
            needed: heapless::Vec::new(),
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
                    .map_or((Real::NEG_INFINITY, Real::INFINITY), |l| {
                        ((l.min as Real), (l.max as Real))
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
    pub fn within_limits(&self, channels: &[Real]) -> bool {
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
        channels: &mut [Real],
        degrees_per_unit: Real,
        kind: JacobianKind,
    ) -> usize {
        let constraints = &constraints[..constraints.len().min(MAX_CONSTRAINTS)];
        self.set_needed(skeleton, constraints);
        let cd = 180.0 / (crate::math::consts::PI * degrees_per_unit.max(1e-9));
        fk64_bones(skeleton, channels, &mut self.pose, &self.needed);
        self.errors(constraints, cd);
        self.jacobian(skeleton, constraints, channels, cd, kind);
        self.rows
    }

    /// Row `r` of the last Jacobian, one entry per variable.
    #[must_use]
    pub fn jacobian_row(&self, r: usize) -> &[Real] {
        &self.jac[r.min(MAX_ROWS - 1)][..self.vars.len()]
    }

    fn clamp(&self, i: usize, x: Real) -> Real {
        x.clamp(self.lo[i], self.hi[i])
    }

    /// Error vector `b` (eq. 41, orientation rows scaled by `c_d`) and the largest errors.
    fn errors(&mut self, constraints: &[Constraint], cd: Real) -> (Real, Real) {
        let mut rows = 0;
        let (mut pe, mut oe) = ((0.0 as Real), (0.0 as Real));
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
        channels: &mut [Real],
        cd: Real,
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
                            RealVec3::ZERO
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
                                (RealVec3::ZERO, RealVec3::ZERO)
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
                    fk64_bones(skeleton, channels, &mut plus, &self.needed);
                    channels[ch] = x - h;
                    fk64_bones(skeleton, channels, &mut minus, &self.needed);
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
        channels: &[Real],
        cd: Real,
    ) -> Real {
        fk64_bones(skeleton, channels, &mut self.pose, &self.needed);
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
    /// Applies `Δθ`; false when nothing moved.
    fn apply(&self, channels: &mut [Real], delta: &[Real], max_step: Real) -> bool {
        let n = self.vars.len();
        let big = delta[..n]
            .iter()
            .enumerate()
            .filter(|(i, _)| self.vars[*i].rotation)
            .fold(0.0 as Real, |m, (_, d)| m.max(d.abs()));
        let scale = if big > max_step { max_step / big } else { 1.0 };
        let mut moved = false;
        for (i, v) in self.vars.iter().enumerate() {
            let old = channels[v.channel];
            let x = self.clamp(i, old + scale * delta[i]);
            moved |= x != old;
            channels[v.channel] = x;
        }
        moved
    }

    /// Solves for `constraints` starting from (and writing into) `channels`.
    ///
    /// Every iterate stays inside the limits: a variable resting on a limit that the step would
    /// push further out is taken out of the step (its Jacobian column zeroed) and the step is
    /// formed again, so a stuck joint does not drag its neighbours. A solve that stops improving
    /// restarts (see [`Settings::restarts`]); the best iterate is what is returned.
    pub fn solve(
        &mut self,
        skeleton: &Skeleton,
        constraints: &[Constraint],
        channels: &mut [Real],
        settings: &Settings,
    ) -> Outcome {
        let constraints = &constraints[..constraints.len().min(MAX_CONSTRAINTS)];
        self.set_needed(skeleton, constraints);
        let cd = 180.0 / (crate::math::consts::PI * settings.degrees_per_unit.max(1e-9));
        let otol = settings.tolerance / cd;
        for (i, v) in self.vars.iter().enumerate() {
            channels[v.channel] = self.clamp(i, channels[v.channel]);
        }
        let n = self.vars.len();
        let mut best = [(0.0 as Real); MAX_VARS];
        let mut best_score = Real::INFINITY;
        let mut state = StepState::new(settings.damping);
        let mut restarts_left = settings.restarts;
        let mut rng = SplitMix(0x6d61_7269_6f6e_6574);
        let (mut window, mut since) = (Real::INFINITY, 0);
        let mut it = 0;
        let (mut pe, mut oe);
        loop {
            fk64_bones(skeleton, channels, &mut self.pose, &self.needed);
            (pe, oe) = self.errors(constraints, cd);
            let score = self.residual();
            if score < best_score {
                best_score = score;
                for (i, v) in self.vars.iter().enumerate() {
                    best[i] = channels[v.channel];
                }
            }
            if (pe <= settings.tolerance && oe <= otol) || it >= settings.max_iterations || n == 0 {
                break;
            }
            if score < 0.9 * window {
                (window, since) = (score, 0);
            } else {
                since += 1;
            }
            let moved = since < settings.patience.max(1) && {
                it += 1;
                self.step(skeleton, constraints, channels, cd, settings, &mut state)
            };
            if !moved {
                if restarts_left == 0 {
                    break;
                }
                restarts_left -= 1;
                let first = restarts_left + 1 == settings.restarts;
                for (i, v) in self.vars.iter().enumerate() {
                    let (lo, hi) = (self.lo[i], self.hi[i]);
                    channels[v.channel] = if !lo.is_finite() || !hi.is_finite() {
                        best[i]
                    } else if first {
                        0.5 * (lo + hi)
                    } else {
                        lo + (hi - lo) * rng.unit()
                    };
                }
                (window, since) = (Real::INFINITY, 0);
                state = StepState::new(settings.damping);
            }
        }
        if !(pe <= settings.tolerance && oe <= otol) && best_score.is_finite() {
            for (i, v) in self.vars.iter().enumerate() {
                channels[v.channel] = best[i];
            }
            fk64_bones(skeleton, channels, &mut self.pose, &self.needed);
            (pe, oe) = self.errors(constraints, cd);
        }
        Outcome {
            iterations: it,
            position_error: pe,
            orientation_error: oe,
            converged: pe <= settings.tolerance && oe <= otol,
        }
    }

    /// The bones FK must compute for `constraints`.
    fn set_needed(&mut self, skeleton: &Skeleton, constraints: &[Constraint]) {
        let mut on = [false; MAX_BONES];
        for c in constraints {
            let mut b = Some(c.bone);
            while let Some(i) = b.filter(|&i| i < skeleton.bones().len()) {
                on[i] = true;
                b = skeleton.bones()[i].parent();
            }
        }
        self.needed.clear();
        for (i, _) in on.iter().enumerate().filter(|(_, o)| **o) {
            let _ = self.needed.push(i);
        }
    }

    /// Squared norm of the error vector of the last [`Solver::errors`].
    fn residual(&self) -> Real {
        self.err[..self.rows].iter().map(|e| e * e).sum()
    }

    /// One iteration of the chosen method from the pose in `self.pose` (errors formed); false
    /// when the method can make no more progress from here.
    #[allow(clippy::needless_range_loop)]
    fn step(
        &mut self,
        skeleton: &Skeleton,
        constraints: &[Constraint],
        channels: &mut [Real],
        cd: Real,
        settings: &Settings,
        state: &mut StepState,
    ) -> bool {
        let n = self.vars.len();
        let mut delta = [(0.0 as Real); MAX_VARS];
        match settings.method {
            Method::Ccd => {
                self.ccd_sweep(skeleton, constraints, channels, cd);
                true
            }
            Method::Transpose => {
                self.jacobian(skeleton, constraints, channels, cd, settings.jacobian);
                for _ in 0..2 {
                    // Δθ = α Jᵀe with α = ⟨e, JJᵀe⟩ / ⟨JJᵀe, JJᵀe⟩ (Buss & Kim).
                    self.jt_e(&mut delta);
                    let mut jjte = [(0.0 as Real); MAX_ROWS];
                    for (r, out) in jjte.iter_mut().enumerate().take(self.rows) {
                        *out = (0..n).map(|i| self.jac[r][i] * delta[i]).sum();
                    }
                    let num: Real = (0..self.rows).map(|r| self.err[r] * jjte[r]).sum();
                    let den: Real = (0..self.rows).map(|r| jjte[r] * jjte[r]).sum();
                    let alpha = if den > 1e-30 { num / den } else { 0.0 };
                    for d in delta.iter_mut().take(n) {
                        *d *= alpha;
                    }
                    if !self.freeze_blocked(channels, &delta) {
                        break;
                    }
                }
                self.apply(channels, &delta, settings.max_step)
            }
            Method::Pseudoinverse => {
                self.jacobian(skeleton, constraints, channels, cd, settings.jacobian);
                for _ in 0..2 {
                    if !self.least_squares_step(1e-10, &mut delta) {
                        return false;
                    }
                    if !self.freeze_blocked(channels, &delta) {
                        break;
                    }
                }
                self.apply(channels, &delta, settings.max_step)
            }
            Method::DampedLeastSquares => {
                // Levenberg–Marquardt damping: λ shrinks after a step that lowers eq. (35) and
                // grows (the step undone) after one that does not.
                self.jacobian(skeleton, constraints, channels, cd, settings.jacobian);
                let before = self.residual();
                let mut saved = [(0.0 as Real); MAX_VARS];
                for (i, v) in self.vars.iter().enumerate() {
                    saved[i] = channels[v.channel];
                }
                for _ in 0..2 {
                    if !self.least_squares_step(state.lambda * state.lambda, &mut delta) {
                        return false;
                    }
                    if !self.freeze_blocked(channels, &delta) {
                        break;
                    }
                }
                if !self.apply(channels, &delta, settings.max_step) {
                    return false;
                }
                if self.objective(skeleton, constraints, channels, cd) < before {
                    state.lambda = (state.lambda * 0.5).max(1e-6);
                } else {
                    for (i, v) in self.vars.iter().enumerate() {
                        channels[v.channel] = saved[i];
                    }
                    state.lambda *= 4.0;
                    if state.lambda > 1e6 {
                        return false;
                    }
                }
                true
            }
            Method::ConjugateGradient => {
                self.jacobian(skeleton, constraints, channels, cd, settings.jacobian);
                // ∇P = −2Jᵀb (eq. 42), zero along limits that block descent; Polak–Ribière
                // directions, reset every n iterations and whenever not a descent direction.
                let mut grad = [(0.0 as Real); MAX_VARS];
                self.jt_e(&mut grad);
                for (i, g) in grad.iter_mut().enumerate().take(n) {
                    *g *= -2.0;
                    let x = channels[self.vars[i].channel];
                    if (x <= self.lo[i] && *g > 0.0) || (x >= self.hi[i] && *g < 0.0) {
                        *g = 0.0;
                    }
                }
                let gg_prev: Real = state.grad_prev[..n].iter().map(|g| g * g).sum();
                let beta = if state.k % n.max(1) == 0 || gg_prev < 1e-30 {
                    0.0
                } else {
                    ((0..n)
                        .map(|i| grad[i] * (grad[i] - state.grad_prev[i]))
                        .sum::<Real>()
                        / gg_prev)
                        .max(0.0)
                };
                state.k += 1;
                for i in 0..n {
                    state.dir[i] = -grad[i] + beta * state.dir[i];
                }
                if (0..n).map(|i| state.dir[i] * grad[i]).sum::<Real>() >= 0.0 {
                    for i in 0..n {
                        state.dir[i] = -grad[i];
                    }
                }
                state.grad_prev = grad;
                // Along the CG direction, else (no decrease there) steepest descent.
                for attempt in 0..2 {
                    if attempt == 1 {
                        for i in 0..n {
                            state.dir[i] = -grad[i];
                        }
                    }
                    let dir = state.dir;
                    let slope = (0..n).map(|i| dir[i] * grad[i]).sum();
                    if self.line_search(
                        skeleton,
                        constraints,
                        channels,
                        &dir,
                        slope,
                        cd,
                        settings.max_step,
                    ) {
                        return true;
                    }
                }
                false
            }
        }
    }

    /// Zeroes the Jacobian columns of variables resting on a limit that `delta` pushes further
    /// out; true when any was zeroed (the step must be formed again).
    fn freeze_blocked(&mut self, channels: &[Real], delta: &[Real; MAX_VARS]) -> bool {
        let mut any = false;
        for (i, v) in self.vars.iter().enumerate() {
            let x = channels[v.channel];
            let blocked = (x <= self.lo[i] && delta[i] < 0.0) || (x >= self.hi[i] && delta[i] > 0.0);
            if blocked && (0..self.rows).any(|r| self.jac[r][i] != 0.0) {
                for row in self.jac.iter_mut().take(self.rows) {
                    row[i] = 0.0;
                }
                any = true;
            }
        }
        any
    }

    fn jt_e(&self, out: &mut [Real; MAX_VARS]) {
        for (i, o) in out.iter_mut().enumerate().take(self.vars.len()) {
            *o = (0..self.rows).map(|r| self.jac[r][i] * self.err[r]).sum();
        }
    }

    /// `Δθ = Jᵀ (JJᵀ + λ²I)⁻¹ e`; false when the system is singular.
    #[allow(clippy::needless_range_loop)]
    fn least_squares_step(&self, lambda2: Real, delta: &mut [Real; MAX_VARS]) -> bool {
        let (m, n) = (self.rows, self.vars.len());
        let mut a = [[(0.0 as Real); MAX_ROWS]; MAX_ROWS];
        let mut y = [(0.0 as Real); MAX_ROWS];
        for r in 0..m {
            for c in 0..=r {
                let v: Real = (0..n).map(|i| self.jac[r][i] * self.jac[c][i]).sum();
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

    /// Line search along `dir` with projection onto the limits: backtracking from a step that
    /// moves no joint more than `max_step`, then the minimiser of the quadratic through `f(0)`,
    /// the slope `f′(0)` and the accepted step, when that is lower. True on decrease.
    #[allow(clippy::too_many_arguments)]
    fn line_search(
        &mut self,
        skeleton: &Skeleton,
        constraints: &[Constraint],
        channels: &mut [Real],
        dir: &[Real; MAX_VARS],
        slope: Real,
        cd: Real,
        max_step: Real,
    ) -> bool {
        let n = self.vars.len();
        let f0 = self.objective(skeleton, constraints, channels, cd);
        let big = dir[..n].iter().fold(0.0 as Real, |m, d| m.max(d.abs()));
        if big < 1e-300 {
            return false;
        }
        let t_max = max_step / big;
        let mut t = t_max;
        let mut saved = [(0.0 as Real); MAX_VARS];
        for (i, v) in self.vars.iter().enumerate() {
            saved[i] = channels[v.channel];
        }
        let set = |s: &Self, channels: &mut [Real], t: Real| {
            for (i, v) in s.vars.iter().enumerate() {
                channels[v.channel] = s.clamp(i, saved[i] + t * dir[i]);
            }
        };
        for _ in 0..40 {
            set(self, channels, t);
            let f = self.objective(skeleton, constraints, channels, cd);
            if f < f0 {
                let curvature = 2.0 * (f - f0 - slope * t);
                if slope < 0.0 && curvature > 0.0 {
                    let ts = (-slope * t * t / curvature).min(t_max);
                    if (ts - t).abs() > 1e-3 * t {
                        set(self, channels, ts);
                        if self.objective(skeleton, constraints, channels, cd) >= f {
                            set(self, channels, t);
                        }
                    }
                }
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
    fn ccd_sweep(
        &mut self,
        skeleton: &Skeleton,
        constraints: &[Constraint],
        channels: &mut [Real],
        cd: Real,
    ) {
        for i in (0..self.vars.len()).rev() {
            let v = self.vars[i];
            fk64_bones(skeleton, channels, &mut self.pose, &self.needed);
            let u = dof_axis(skeleton, &self.pose, v.bone, v.dof, channels);
            if v.rotation {
                let pivot = self.pose.start[v.bone];
                let (mut num, mut den) = (0.0, 0.0);
                for c in constraints
                    .iter()
                    .filter(|c| Self::affects(skeleton, v.bone, c.bone))
                {
                    let mut acc = |a: RealVec3, b: RealVec3, w: Real| {
                        let a = a - u * u.dot(a);
                        let b = b - u * u.dot(b);
                        num += w * u.dot(a.cross(b));
                        den += w * a.dot(b);
                    };
                    acc(self.pose.tip[c.bone] - pivot, c.position - pivot, 1.0);
                    if let Some((xg, yg)) = c.axes {
                        let f: RealMat3 = self.pose.frame[c.bone];
                        acc(f.x_axis, xg, cd * cd);
                        acc(f.y_axis, yg, cd * cd);
                    }
                }
                if num != 0.0 || den != 0.0 {
                    let delta = real::atan2(num, den);
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

/// Per-solve state of the iterative methods.
#[derive(Clone, Copy)]
struct StepState {
    /// DLS damping λ now.
    lambda: Real,
    /// CG: the previous gradient and direction, and iterations since the last reset.
    grad_prev: [Real; MAX_VARS],
    dir: [Real; MAX_VARS],
    k: usize,
}

impl StepState {
    fn new(lambda: Real) -> StepState {
        StepState {
            lambda: lambda.max(1e-6),
            grad_prev: [0.0; MAX_VARS],
            dir: [0.0; MAX_VARS],
            k: 0,
        }
    }
}

/// SplitMix64, for the restart points (deterministic: the same solve gives the same result).
struct SplitMix(u64);

impl SplitMix {
    fn unit(&mut self) -> Real {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as Real / (1u64 << 53) as Real
    }
}

#[allow(clippy::needless_range_loop)]
/// Solves `A·x = y` in place (Gaussian elimination, partial pivoting) for the leading `m`×`m`
/// block; `y` becomes `x`. False when singular.
fn solve_linear(a: &mut [[Real; MAX_ROWS]; MAX_ROWS], y: &mut [Real; MAX_ROWS], m: usize) -> bool {
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
        let s: Real = (col + 1..m).map(|c| a[col][c] * y[c]).sum();
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
