//! The swivel circle in closed form (help note §IV, eq. 18–30), for a search that costs little
//! more than one solve.
//!
//! For a fixed elbow angle the shoulder's local rotation along the swivel circle is
//! `q(ψ) = cos(ψ/2)·P + sin(ψ/2)·Q` (eq. 23–26 with `R(n̂, ψ) = cos(ψ/2) + sin(ψ/2)·n̂`; `P`, `Q`
//! orthogonal unit quaternions, `ψ = φ − φ₀`). Hence:
//!
//! * its rotation matrix is `M(ψ) = M₀ + M₁·cos ψ + M₂·sin ψ`, so each Euler angle's limit is a
//!   condition `α + β·cos ψ + γ·sin ψ ≥ 0` (or a union of two) and the legal swivels are arcs
//!   found in closed form — as Tolani, Goswami and Badler do for Euler limits — [`SwivelCircle::legal_arcs`];
//! * eq. 30's distance to limit corner `qᵢ` is `acos|aᵢ·cos(ψ/2) + bᵢ·sin(ψ/2)|` with
//!   `aᵢ = P·qᵢ`, `bᵢ = Q·qᵢ` (4-D dot products), all eight computed together. Each term is
//!   convex in `ψ` between its one kink (its maximum, where the dot product is zero), so eq. 30
//!   is convex on the pieces between kinks and arc ends: [`SwivelCircle::minimise`] takes the
//!   global minimum over allowed arcs exactly, piece by piece (pieces whose lower bound cannot
//!   beat the best end are skipped; inside a piece, Newton's method on the slope kept inside its
//!   bracket).
//!
//! The eight terms and their slopes are evaluated together in f32 lanes, four corners to a vector
//! instruction, with a polynomial arccosine ([`crate::math::atan_ratio_lanes`]): each term within
//! about 3e-7 rad, except where a corner is almost touched (`|d| → 1`, where acos's slope is
//! unbounded and f32's rounding of `d` counts most). The choice of swivel may differ from the
//! exact optimum by that much in eq. 30's value; any swivel reaches the target exactly, and
//! whether it is legal is decided in f64.

use crate::math::consts::{PI, TAU};

use crate::math::{precision, real, Real, RealQuat};

use crate::math::{
    acos_abs_fast, acos_fast, atan2_fast, atan2_lanes, atan_ratio_lanes, sincos_f32, sort_by_real,
    sqrt_lanes, sum_lanes, AngleOf, Element, EulerOrder,
};
use glam::Vec4;

/// Arcs of the circle, `(start, length)`: start in `[−π, π)`, length in `(0, 2π]`.
pub type Arcs = heapless::Vec<(Real, Real), 8>;

/// How far inside its computed ends a legal arc is kept, radians (1e-6; 4e-6 in f32).
const MARGIN: Real = precision(1e-6, 4e-6);
/// How far rounding may leave a value past a bound it meets exactly: 1e-12 in f64, 1e-6 in
/// f32 (its step at 2π is 4.8e-7).
const ROUNDING: Real = precision(1e-12, 1e-6);
/// How close to the end of the middle Euler angle's range a limit counts as that end, radians:
/// the ASF's limits are f32 degrees (a step of 1.3e-7 rad at 90°), so a limit of ±90° allows a
/// sliver of 4.4e-8 rad past it, in the gimbal lock.
const LIMIT_SLIVER: Real = 1e-6;
/// Newton's step on the swivel at which it stops, radians: 1e-6, two steps of f32 at 2π (the
/// slopes are f32, [`CornerLanes`]); the step taken last leaves the zero nearer still.
const NEWTON_STOP: Real = 1e-6;
/// How far eq. 30's value in f32 lanes may be off: eight terms, each within 1e-7 rad of its
/// arccosine plus f32's rounding.
const VALUE_ROUNDING: Real = 1e-5;

/// `a + b·cos ψ + c·sin ψ`.
type Lin = [Real; 3];

/// The whole circle.
#[must_use]
pub fn full() -> Arcs {
    let mut a = Arcs::new();
    let _ = a.push((-PI, TAU));
    a
}

/// `x` in `[−π, π)`.
#[must_use]
pub fn wrap(x: Real) -> Real {
    if (-PI..PI).contains(&x) {
        return x;
    }
    if !x.is_finite() {
        return x;
    }
    if x.abs() > 8.0 * TAU {
        let r = real::remainder(x, TAU);
        return if r >= PI { r - TAU } else { r };
    }
    turn(x + PI) - PI
}

/// Where `l[0] + l[1]·cos ψ + l[2]·sin ψ ≥ 0`: one arc, the whole circle or nothing.
fn arcs_where(l: Lin) -> Arcs {
    let r = real::sqrt(l[1] * l[1] + l[2] * l[2]);
    let mut out = Arcs::new();
    if r <= 1e-15 * (1.0 + l[0].abs()) {
        if l[0] >= 0.0 {
            return full();
        }
        return out;
    }
    let k = -l[0] / r;
    if k <= -1.0 {
        return full();
    }
    if k >= 1.0 {
        return out;
    }
    let half = acos_fast(k);
    let centre = atan2_fast(l[2], l[1]);
    let _ = out.push((wrap(centre - half), 2.0 * half));
    out
}

/// The intersection of two arcs (at most two arcs).
fn meet(a: (Real, Real), b: (Real, Real), out: &mut Arcs) -> Option<()> {
    if a.1 >= TAU {
        return out.push(b).ok();
    }
    if b.1 >= TAU {
        return out.push(a).ok();
    }
    // In a's frame a is [0, a.1]; b starts at d and once more at d − 2π.
    let d = turn(b.0 - a.0);
    for start in [d, d - TAU] {
        let lo = start.max(0.0);
        let hi = (start + b.1).min(a.1);
        if hi > lo {
            out.push((wrap(a.0 + lo), hi - lo)).ok()?;
        }
    }
    Some(())
}

/// `a ∩ b`; `None` when the result does not fit (the caller falls back).
#[must_use]
pub fn intersect(a: &Arcs, b: &Arcs) -> Option<Arcs> {
    let mut out = Arcs::new();
    for &x in a {
        for &y in b {
            meet(x, y, &mut out)?;
        }
    }
    Some(out)
}

/// `a ∪ b` (arcs may overlap); `None` when it does not fit.
fn unite(a: &Arcs, b: &Arcs) -> Option<Arcs> {
    let mut out = a.clone();
    for &y in b {
        if y.1 >= TAU {
            return Some(full());
        }
        out.push(y).ok()?;
    }
    Some(out)
}

/// Whether `psi` lies on one of the arcs.
#[must_use]
pub fn contains(arcs: &Arcs, psi: Real) -> bool {
    arcs.iter().any(|&(s, l)| l >= TAU || turn(psi - s) <= l)
}

/// The window `[centre − half, centre + half]` as arcs.
#[must_use]
pub fn window(centre: Real, half: Real) -> Arcs {
    if half >= PI {
        return full();
    }
    let mut a = Arcs::new();
    let _ = a.push((wrap(centre - half), 2.0 * half));
    a
}

/// The point of `arcs` nearest `psi` on the circle (`psi` itself when on one).
#[must_use]
pub fn nearest(arcs: &Arcs, psi: Real) -> Option<Real> {
    if contains(arcs, psi) {
        return Some(psi);
    }
    let gap = |x: Real| wrap(x - psi).abs();
    arcs.iter()
        .flat_map(|&(s, l)| [s, s + l])
        .min_by(|a, b| gap(*a).total_cmp(&gap(*b)))
        .map(|x| psi + wrap(x - psi))
}

/// The homogeneous rotation matrix of a (not necessarily unit) quaternion, row-major: quadratic
/// in its components, so `M(cP + sQ)` splits into the three matrices of [`SwivelCircle`].
fn rotation_rows(q: RealQuat) -> [[Real; 3]; 3] {
    let (x, y, z, w) = (q.x, q.y, q.z, q.w);
    [
        [
            w * w + x * x - y * y - z * z,
            2.0 * (x * y - w * z),
            2.0 * (x * z + w * y),
        ],
        [
            2.0 * (x * y + w * z),
            w * w - x * x + y * y - z * z,
            2.0 * (y * z - w * x),
        ],
        [
            2.0 * (x * z - w * y),
            2.0 * (y * z + w * x),
            w * w - x * x - y * y + z * z,
        ],
    ]
}

/// One limb's swivel circle for one elbow angle.
#[derive(Clone, Debug)]
pub struct SwivelCircle {
    /// `(aᵢ, bᵢ)` of each limit corner, in f32 lanes.
    lanes: CornerLanes,
    corners: usize,
    /// `P` and `Q`.
    p: RealQuat,
    q: RealQuat,
}

/// The corners' `aᵢ`, `bᵢ` in f32, four to a lane vector (glam's `Vec4`: SSE2 on x86-64,
/// scalar on a microcontroller), so that eq. 30's eight terms and slopes at a swivel take a few
/// vector instructions each. An unused slot has `a = b = 0`: no slope, no curvature, and its
/// term is masked.
#[derive(Clone, Debug)]
struct CornerLanes {
    a: [Vec4; 2],
    b: [Vec4; 2],
    /// `max(1 − aᵢ² − bᵢ², 0)`, the curvature's factor.
    flat: [Vec4; 2],
    /// 1 on a corner, 0 on an unused slot.
    used: [Vec4; 2],
}

impl CornerLanes {
    /// `aᵢ = P·qᵢ`, `bᵢ = Q·qᵢ` of the first eight `corners`.
    fn new(p: RealQuat, q: RealQuat, corners: &[RealQuat]) -> CornerLanes {
        let (mut a, mut b, mut flat, mut used) = ([0.0f32; 8], [0.0f32; 8], [0.0f32; 8], [0.0f32; 8]);
        for (k, c) in corners.iter().take(8).enumerate() {
            let (x, y) = (p.dot(*c), q.dot(*c));
            (a[k], b[k]) = (real::to_f32(x), real::to_f32(y));
            flat[k] = real::to_f32(real::max(1.0 - x * x - y * y, 0.0));
            used[k] = 1.0;
        }
        let lanes = |v: [f32; 8]| [Vec4::from_slice(&v[..4]), Vec4::from_slice(&v[4..])];
        CornerLanes {
            a: lanes(a),
            b: lanes(b),
            flat: lanes(flat),
            used: lanes(used),
        }
    }

    /// Corner `k`'s `(aₖ, bₖ)`.
    fn corner(&self, k: usize) -> (Real, Real) {
        let (h, i) = (k / 4, k % 4);
        (
            real::from_f32(self.a[h].to_array()[i]),
            real::from_f32(self.b[h].to_array()[i]),
        )
    }

    /// Each corner's dot product `dᵢ = aᵢ·cos(ψ/2) + bᵢ·sin(ψ/2)` and its slope in `ψ`,
    /// `½(bᵢ·cos(ψ/2) − aᵢ·sin(ψ/2))`, given `(sin, cos)` of `ψ/2`.
    #[inline]
    fn dots(&self, h: usize, s: Vec4, c: Vec4) -> (Vec4, Vec4) {
        let (a, b) = (self.a[h], self.b[h]);
        (a * c + b * s, 0.5 * (b * c - a * s))
    }

    /// Eq. 30's corner terms `acos|dᵢ|` (0 on unused slots) and their slopes in `ψ`, each
    /// `−sign(dᵢ)·ḋᵢ/√(1 − dᵢ²)` (0 where `|dᵢ| = 1`, the term's corner-touching minimum).
    fn terms_and_slopes(&self, (s, c): (Real, Real)) -> ([Vec4; 2], [Vec4; 2]) {
        let (s, c) = (Vec4::splat(real::to_f32(s)), Vec4::splat(real::to_f32(c)));
        let (mut terms, mut slopes) = ([Vec4::ZERO; 2], [Vec4::ZERO; 2]);
        for h in 0..2 {
            let (d, dd) = self.dots(h, s, c);
            let w = d.abs().min(Vec4::ONE);
            let root = sqrt_lanes((Vec4::ONE - w) * (Vec4::ONE + w));
            terms[h] = atan_ratio_lanes(root, w) * self.used[h];
            slopes[h] = Vec4::select(
                root.cmpgt(Vec4::ZERO),
                -(Vec4::ONE.copysign(d) * dd) / root,
                Vec4::ZERO,
            );
        }
        (terms, slopes)
    }

    /// Each corner term's centre `2·atan2(bᵢ, aᵢ)` (where it is least, `acos rᵢ`; its kink lies
    /// opposite) and its radius `rᵢ = √(aᵢ² + bᵢ²)`.
    fn shapes(&self) -> [[f32; 8]; 2] {
        let mut out = [[0.0; 8]; 2];
        for h in 0..2 {
            let (a, b) = (self.a[h], self.b[h]);
            for (slot, v) in out
                .iter_mut()
                .zip([atan2_lanes(b, a) * 2.0, sqrt_lanes(a * a + b * b)])
            {
                slot[4 * h..4 * h + 4].copy_from_slice(&v.to_array());
            }
        }
        out
    }

    /// The corner terms' summed slope and curvature in `ψ`; the curvature of `acos|d|` is
    /// `|d|·(1 − r²)/(4(1 − d²)^{3/2}) ≥ 0` (`r² = a² + b²`).
    fn slope_and_curvature(&self, (s, c): (Real, Real)) -> (Real, Real) {
        let (s, c) = (Vec4::splat(real::to_f32(s)), Vec4::splat(real::to_f32(c)));
        let (mut g, mut k) = (Vec4::ZERO, Vec4::ZERO);
        for h in 0..2 {
            let (d, dd) = self.dots(h, s, c);
            let one = (Vec4::ONE - d) * (Vec4::ONE + d);
            let live = one.cmpgt(Vec4::ZERO);
            let root = sqrt_lanes(one.max(Vec4::splat(f32::MIN_POSITIVE)));
            g -= Vec4::select(live, Vec4::ONE.copysign(d) * dd / root, Vec4::ZERO);
            k += Vec4::select(live, d.abs() * self.flat[h] / (4.0 * one * root), Vec4::ZERO);
        }
        (real::from_f32(sum_lanes(g)), real::from_f32(sum_lanes(k)))
    }
}

/// `M₀`, `M₁`, `M₂` of `M(ψ) = M₀ + M₁·cos ψ + M₂·sin ψ`, row-major.
struct CircleMatrices([[[Real; 3]; 3]; 3]);

impl CircleMatrices {
    /// The matrices of the circle `cos(ψ/2)·p + sin(ψ/2)·q`.
    fn new(p: RealQuat, q: RealQuat) -> CircleMatrices {
        let (rp, rq, rs) = (rotation_rows(p), rotation_rows(q), rotation_rows(p + q));
        let mut m = [[[0.0; 3]; 3]; 3];
        for i in 0..3 {
            for j in 0..3 {
                m[0][i][j] = 0.5 * (rp[i][j] + rq[i][j]);
                m[1][i][j] = 0.5 * (rp[i][j] - rq[i][j]);
                m[2][i][j] = 0.5 * (rs[i][j] - rp[i][j] - rq[i][j]);
            }
        }
        CircleMatrices(m)
    }

    /// One element of `M(ψ)` as `a + b·cos ψ + c·sin ψ`.
    fn element(&self, e: Element) -> Lin {
        [0, 1, 2].map(|k| e.sign * self.0[k][e.row][e.col])
    }
}

/// Eq. 30 (plus the continuity term), its terms and its slope at one swivel.
struct Probe {
    total: Real,
    /// The corner terms, in [`CornerLanes`]' order.
    terms: [Vec4; 2],
    /// The continuity term.
    keep_term: Real,
    /// The slope; at a kink, without the kinked term.
    slope: Real,
    /// At a kink: the kinked term's slope is `−jump` just after it, `+jump` just before.
    jump: Real,
}

impl SwivelCircle {
    /// The circle `q(ψ) = cos(ψ/2)·p + sin(ψ/2)·q` against the limit `corners`.
    #[must_use]
    pub fn new(p: RealQuat, q: RealQuat, corners: &[RealQuat]) -> SwivelCircle {
        SwivelCircle {
            lanes: CornerLanes::new(p, q, corners),
            corners: corners.len().min(8),
            p,
            q,
        }
    }

    /// Eq. 30 at `psi`, with `0.5·(ψ − keep)²` (wrapped) when a previous swivel is kept, term
    /// by term, and its slope, in one pass over the corners. At a kink (`kink`: the corner, or
    /// 8 for the continuity term, whose kink lies at `psi`) the slope jumps: the slope without
    /// that term and the size of its one-sided slope are returned apart.
    fn probe_at(&self, psi: Real, keep: Option<Real>, kink: Option<usize>) -> Probe {
        let half = half_turn(psi);
        let (terms, slopes) = self.lanes.terms_and_slopes(half);
        let mut slope = real::from_f32(sum_lanes(slopes[0] + slopes[1]));
        let mut jump = 0.0;
        if let Some(k) = kink.filter(|&k| k < 8) {
            // The kinked term's slope left out; past its zero the dot product takes the sign
            // of its slope.
            slope -= real::from_f32(slopes[k / 4].to_array()[k % 4]);
            let (s, c) = half;
            let (a, b) = self.lanes.corner(k);
            let d = a * c + b * s;
            let root = real::sqrt(real::max((1.0 - d) * (1.0 + d), 0.0));
            jump = real::fabs(0.5 * (b * c - a * s)) / real::max(root, Real::MIN_POSITIVE);
        }
        let mut keep_term = 0.0;
        if let Some(k) = keep {
            let d = wrap(psi - k);
            keep_term = 0.5 * d * d;
            if kink == Some(8) {
                jump = PI;
            } else {
                slope += d;
            }
        }
        Probe {
            total: real::from_f32(sum_lanes(terms[0] + terms[1])) + keep_term,
            terms,
            keep_term,
            slope,
            jump,
        }
    }

    /// [`SwivelCircle::probe_at`] off any kink.
    fn probe(&self, psi: Real, keep: Option<Real>) -> Probe {
        self.probe_at(psi, keep, None)
    }

    /// The slope and curvature of [`SwivelCircle::value`] at `psi` (inside a piece).
    fn slope(&self, psi: Real, keep: Option<Real>) -> (Real, Real) {
        self.slope_at(half_turn(psi), psi, keep)
    }

    /// [`SwivelCircle::slope`] with `(sin, cos)` of `ψ/2` given.
    fn slope_at(&self, half: (Real, Real), psi: Real, keep: Option<Real>) -> (Real, Real) {
        let (g, h) = self.lanes.slope_and_curvature(half);
        match keep {
            Some(k) => (g + wrap(psi - k), h + 1.0),
            None => (g, h),
        }
    }

    /// The legal swivels under `limits` (a limb's Euler limits, [`LimitForms`]): the union
    /// over the two Euler solutions of the arcs where all three angles are inside. `None` when
    /// the arc lists do not fit (the caller searches by sampling instead).
    #[must_use]
    pub fn legal_arcs(&self, limits: &LimitForms) -> Option<Arcs> {
        let m = CircleMatrices::new(self.p, self.q);
        let mut legal = Arcs::new();
        for solution in &limits.solutions[..limits.possible] {
            let mut set = full();
            for angle in solution {
                let cond = match *angle {
                    AngleLimit::Free => continue,
                    AngleLimit::Sector { y, x, lo, hi, narrow } => {
                        let (y, x) = (m.element(y), m.element(x));
                        // Counter-clockwise of the lower edge, clockwise of the upper.
                        let after_lo = [0, 1, 2].map(|k| lo.1 * y[k] - lo.0 * x[k]);
                        let before_hi = [0, 1, 2].map(|k| hi.0 * x[k] - hi.1 * y[k]);
                        let (a, b) = (arcs_where(after_lo), arcs_where(before_hi));
                        if narrow {
                            intersect(&a, &b)?
                        } else {
                            unite(&a, &b)?
                        }
                    }
                    AngleLimit::Middle { e, stretches, count } => {
                        let e = m.element(e);
                        let mut out = Arcs::new();
                        for &(lower, upper) in &stretches[..count] {
                            let mut part = full();
                            if lower.is_finite() {
                                part = intersect(&part, &arcs_where([e[0] - lower, e[1], e[2]]))?;
                            }
                            if upper.is_finite() {
                                part = intersect(&part, &arcs_where([upper - e[0], -e[1], -e[2]]))?;
                            }
                            out = unite(&out, &part)?;
                        }
                        out
                    }
                };
                set = intersect(&set, &cond)?;
                if set.is_empty() {
                    break;
                }
            }
            legal = unite(&legal, &set)?;
        }
        // The arc ends carry the arctangents' error (1e-7 rad): kept 1e-6 inside, so a swivel
        // on an end is legal to rounding.
        let mut inside = Arcs::new();
        for &(s, l) in &legal {
            if l >= TAU {
                return Some(full());
            }
            if l > 2.0 * MARGIN {
                inside.push((wrap(s + MARGIN), l - 2.0 * MARGIN)).ok()?;
            }
        }
        Some(inside)
    }

    /// The global minimum of eq. 30 (plus the continuity term towards `keep`, in `ψ`) over
    /// `allowed`; `None` when nothing is allowed.
    #[must_use]
    pub fn minimise(&self, allowed: &Arcs, keep: Option<Real>) -> Option<Real> {
        if allowed.is_empty() {
            return None;
        }
        // One allowed arc with no kink inside (a stream's window, mostly): eq. 30 is convex
        // over it, so its minimum is where the slope crosses zero, or the end the slope
        // falls towards. Slopes only: no value is needed to choose.
        if let [(l, length)] = allowed[..] {
            let h = l + length;
            let keep_kink_outside = keep.is_none_or(|k| !contains(allowed, wrap(k + PI)));
            let ends = (half_turn(l), half_turn(h));
            if length < TAU && keep_kink_outside && self.kink_free(ends) {
                let (gl, gh) = (self.slope_at(ends.0, l, keep).0, self.slope_at(ends.1, h, keep).0);
                // (Slopes that are not numbers: the general search below decides.)
                if gl.is_finite() && gh.is_finite() {
                    let x = if gl >= 0.0 {
                        l
                    } else if gh <= 0.0 {
                        h
                    } else {
                        self.slope_zero(l, h, gl, gh, keep)
                    };
                    return Some(wrap(x));
                }
            }
        }
        // Breakpoints: each term's kink (its maximum), the continuity term's, arc ends; with
        // the term kinked there (9: none).
        let mut points: heapless::Vec<(Real, usize), 48> = heapless::Vec::new();
        let mut centres = [Real::NAN; 9];
        // Each term's radius; its floor acos(r) is taken only where a bound needs it.
        let [lane_centres, radii] = self.lanes.shapes();
        // (A kink outside the allowed arcs only splits a piece that is not allowed: left out.)
        for k in 0..self.corners {
            if real::from_f32(radii[k]) > ROUNDING {
                let centre = real::from_f32(lane_centres[k]);
                centres[k] = wrap(centre);
                let kink = wrap(centre + PI);
                if contains(allowed, kink) {
                    points.push((kink, k)).ok()?;
                }
            }
        }
        if let Some(k) = keep {
            centres[8] = wrap(k);
            let kink = wrap(k + PI);
            if contains(allowed, kink) {
                points.push((kink, 8)).ok()?;
            }
        }
        for &(s, l) in allowed {
            if l < TAU {
                points.push((wrap(s), 9)).ok()?;
                points.push((wrap(s + l), 9)).ok()?;
            }
        }
        if points.is_empty() {
            points.push((-PI, 9)).ok()?;
        }
        let n = points.len();
        sort_by_real(&mut points, |p| p.0);
        let end = |i: usize| {
            if i + 1 < n {
                points[i + 1].0
            } else {
                points[0].0 + TAU
            }
        };
        // Each breakpoint probed once, when a piece next to it is allowed.
        let mut probes: heapless::Vec<(usize, Probe), 48> = heapless::Vec::new();
        let probe_of = |i: usize, probes: &mut heapless::Vec<(usize, Probe), 48>| -> Option<usize> {
            if let Some(at) = probes.iter().position(|(j, _)| *j == i) {
                return Some(at);
            }
            let (x, kink) = points[i];
            probes
                .push((i, self.probe_at(x, keep, (kink < 9).then_some(kink))))
                .ok()?;
            Some(probes.len() - 1)
        };
        // The allowed pieces, each convex, with a lower bound of eq. 30 over them.
        let mut pieces: heapless::Vec<(Real, Real, Real, Real, Real), 24> = heapless::Vec::new();
        let mut best = (Real::INFINITY, 0.0);
        for i in 0..n {
            let (l, h) = (points[i].0, end(i));
            if (h - l < ROUNDING && n > 1) || !contains(allowed, 0.5 * (l + h)) {
                continue;
            }
            let (pl, ph) = (probe_of(i, &mut probes)?, probe_of((i + 1) % n, &mut probes)?);
            let (pa, pb) = (&probes[pl].1, &probes[ph].1);
            for (v, x) in [(pa.total, l), (pb.total, h)] {
                if v < best.0 {
                    best = (v, x);
                }
            }
            // Slopes inside the piece: just after its lower end, just before its upper.
            let (ga, gb) = (pa.slope - pa.jump, pb.slope + pb.jump);
            if !(ga < 0.0 && gb > 0.0) {
                // Convex: the minimum is at an end.
                continue;
            }
            // Each term is convex here: its minimum is its floor when its centre lies inside,
            // else the lower end value.
            let lower = [0, 1].map(|h| pa.terms[h].min(pb.terms[h]).to_array());
            let mut bound = 0.0;
            for k in 0..9 {
                let c = centres[k];
                bound += if c.is_finite() && turn(c - l) <= h - l {
                    if k == 8 {
                        0.0
                    } else {
                        acos_abs_fast(real::from_f32(radii[k]))
                    }
                } else if k == 8 {
                    real::min(pa.keep_term, pb.keep_term)
                } else {
                    real::from_f32(lower[k / 4][k % 4])
                };
            }
            pieces.push((bound, l, h, ga, gb)).ok()?;
        }
        sort_by_real(&mut pieces, |p| p.0);
        for &(bound, l, h, gl, gh) in &pieces {
            if bound >= best.0 - VALUE_ROUNDING {
                break;
            }
            let x = self.slope_zero(l, h, gl, gh, keep);
            let v = self.probe(x, keep).total;
            if v < best.0 {
                best = (v, x);
            }
        }
        if best.0 == Real::INFINITY {
            return None;
        }
        Some(wrap(best.1))
    }

    /// True when no corner term has its kink in `[l, h]` (`h − l < 2π`; given `(sin, cos)` of
    /// `l/2` and `h/2`): each dot product
    /// `aᵢ·cos(ψ/2) + bᵢ·sin(ψ/2)` keeps its sign there (over less than π of `ψ/2` it has
    /// at most one zero, so the ends' signs tell).
    fn kink_free(&self, ends: ((Real, Real), (Real, Real))) -> bool {
        let [(sl, cl), (sh, ch)] =
            [ends.0, ends.1].map(|(s, c)| (Vec4::splat(real::to_f32(s)), Vec4::splat(real::to_f32(c))));
        (0..2).all(|h| {
            let ((low, _), (high, _)) = (self.lanes.dots(h, sl, cl), self.lanes.dots(h, sh, ch));
            // (Unused slots count as kink-free.)
            Vec4::select(self.lanes.used[h].cmpgt(Vec4::ZERO), low * high, Vec4::ONE)
                .cmpgt(Vec4::ZERO)
                .all()
        })
    }

    /// Where the slope of eq. 30 crosses zero in `[l, h]`, a piece where it rises from `gl < 0`
    /// to `gh > 0`: Newton's method inside the bracket, else halving.
    fn slope_zero(&self, l: Real, h: Real, gl: Real, gh: Real, keep: Option<Real>) -> Real {
        let (mut a, mut b) = (l, h);
        let mut x = a - gl * (b - a) / (gh - gl);
        for _ in 0..60 {
            let (g, curvature) = self.slope(x, keep);
            if g == 0.0 {
                break;
            }
            if g < 0.0 {
                a = x;
            } else {
                b = x;
            }
            let next = x - g / curvature;
            // 1e-8 rad of swivel: eq. 30 is flat there to ~1e-16.
            if next.is_finite() && (next - x).abs() < NEWTON_STOP {
                x = real::clamp(next, a, b);
                break;
            }
            x = if next.is_finite() && next > a && next < b {
                next
            } else {
                0.5 * (a + b)
            };
            if b - a < NEWTON_STOP {
                break;
            }
        }
        x
    }
}

/// `(sin, cos)` of `ψ/2` for [`CornerLanes`], in f32 ([`sincos_f32`]): the lanes take them
/// in f32.
#[inline]
fn half_turn(psi: Real) -> (Real, Real) {
    let (s, c) = sincos_f32(real::to_f32(0.5 * psi));
    (real::from_f32(s), real::from_f32(c))
}

/// `x` in `[0, 2π)` (for `x` within a few turns).
fn turn(mut x: Real) -> Real {
    while x < 0.0 {
        x += TAU;
    }
    while x >= TAU {
        x -= TAU;
    }
    x
}

/// One Euler angle's limit for one of the two Euler solutions, with its trigonometry done.
#[derive(Clone, Copy, Debug)]
enum AngleLimit {
    /// No limit (or one 2π wide).
    Free,
    /// `atan2(y, x)` in `[lo, hi]` modulo 2π: the direction `(x, y)` in a sector, two
    /// half-planes that meet (`narrow`: up to π wide) or join; `(sin, cos)` of each edge.
    Sector {
        y: Element,
        x: Element,
        lo: (Real, Real),
        hi: (Real, Real),
        narrow: bool,
    },
    /// The middle angle (`asin e` in `[−π/2, π/2]` or `acos e` in `[0, π]`) in `[lo, hi]`
    /// modulo 2π: each stretch of the limit inside the angle's own range as bounds on `e`,
    /// `(lower, upper)` (infinite: none).
    Middle {
        e: Element,
        stretches: [(Real, Real); 2],
        count: usize,
    },
}

/// A limb's Euler limits as conditions on the swivel circle's matrix, per Euler solution
/// (`[a, b, c]` and `[a + π, π − b, c + π]`, or `−b` for proper orders), computed once per limb.
/// Only the solutions the limits allow at all are kept: one whose middle angle the limits leave
/// no room for is dropped, and a middle angle allowed over its whole range is no condition.
#[derive(Clone, Copy, Debug)]
pub struct LimitForms {
    solutions: [[AngleLimit; 3]; 2],
    possible: usize,
}

impl LimitForms {
    /// The conditions of `limits` (one per angle, radians, either end infinite) in `order`.
    #[must_use]
    pub fn new(order: EulerOrder, limits: &[(Real, Real); 3]) -> LimitForms {
        let forms = order.angle_forms();
        let mut out = LimitForms {
            solutions: [[AngleLimit::Free; 3]; 2],
            possible: 0,
        };
        for s in 0..2 {
            let solution = &mut out.solutions[out.possible];
            *solution = [AngleLimit::Free; 3];
            let second = s == 1;
            for (k, form) in forms.iter().enumerate() {
                let (lo, hi) = limits[k];
                // No limit, or one a turn wide (NaN-safe: infinite ends give NaN widths too).
                if (hi - lo).partial_cmp(&TAU) != Some(core::cmp::Ordering::Less) {
                    continue;
                }
                solution[k] = match *form {
                    AngleOf::Atan2(y, x) => {
                        let shift = if second { PI } else { 0.0 };
                        let (lo, hi) = (lo - shift, hi - shift);
                        AngleLimit::Sector {
                            y,
                            x,
                            lo: real::sincos(lo),
                            hi: real::sincos(hi),
                            narrow: hi - lo <= PI,
                        }
                    }
                    AngleOf::Asin(e) => {
                        let (l, h) = if second { (PI - hi, PI - lo) } else { (lo, hi) };
                        middle(e, l, h, false)
                    }
                    AngleOf::Acos(e) => {
                        let (l, h) = if second { (-hi, -lo) } else { (lo, hi) };
                        middle(e, l, h, true)
                    }
                };
            }
            let never = solution
                .iter()
                .any(|a| matches!(a, AngleLimit::Middle { count: 0, .. }));
            if !never {
                out.possible += 1;
            }
        }
        out
    }
}

/// [`AngleLimit::Middle`] for `[lo, hi]`: the stretches inside `[−π/2, π/2]` (sine, rising)
/// or `[0, π]` (cosine, falling) as bounds on the matrix element.
fn middle(e: Element, lo: Real, hi: Real, cosine: bool) -> AngleLimit {
    let (first, last) = if cosine { (0.0, PI) } else { (-0.5 * PI, 0.5 * PI) };
    let mut stretches = [(Real::NEG_INFINITY, Real::INFINITY); 2];
    let mut count = 0;
    for turn in -2..=2 {
        let shift = (turn as Real) * TAU;
        // (Within `LIMIT_SLIVER` of the range's ends counts as the end, and a narrower stretch
        // as none: limits of ±90° read as f32 come out 4.4e-8 past π/2.)
        let (l, h) = ((lo + shift).max(first), (hi + shift).min(last));
        let (l, h) = (
            if l <= first + LIMIT_SLIVER { first } else { l },
            if h >= last - LIMIT_SLIVER { last } else { h },
        );
        if h <= l + LIMIT_SLIVER || count == stretches.len() {
            continue;
        }
        let (mut lower, mut upper) = (Real::NEG_INFINITY, Real::INFINITY);
        if cosine {
            if h < last {
                lower = real::cos(h);
            }
            if l > first {
                upper = real::cos(l);
            }
        } else {
            if l > first {
                lower = real::sin(l);
            }
            if h < last {
                upper = real::sin(h);
            }
        }
        if lower == Real::NEG_INFINITY && upper == Real::INFINITY {
            // The angle's whole range: no condition.
            return AngleLimit::Free;
        }
        stretches[count] = (lower, upper);
        count += 1;
    }
    AngleLimit::Middle { e, stretches, count }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn arcs_meet_and_contain() {
        let a = window(3.0, 0.5);
        assert!(contains(&a, -3.1) && contains(&a, 2.6) && !contains(&a, 2.0));
        let b = window(-2.9, 0.3);
        let both = intersect(&a, &b).unwrap();
        assert_eq!(both.len(), 1);
        assert!(contains(&both, -3.0) && !contains(&both, 3.0));
        assert_eq!(nearest(&b, 0.0).map(|x| (x - (-2.6)).abs() < 1e-12), Some(true));
        let half = arcs_where([0.0, 1.0, 0.0]);
        assert!(contains(&half, 1.5) && !contains(&half, 1.6) && contains(&half, -1.5));
    }

    #[test]
    fn terms_slope_and_curvature_match_f64_and_finite_differences() {
        let p = RealQuat::from_xyzw(0.1, 0.7, -0.3, 0.5).normalize();
        let mut q = RealQuat::from_xyzw(0.4, -0.2, 0.6, 0.1);
        q = (q - p * p.dot(q)).normalize();
        let corners: [RealQuat; 8] = core::array::from_fn(|k| {
            RealQuat::from_xyzw(0.3 * k as Real - 1.0, 0.5, 0.2 - 0.1 * k as Real, 0.9).normalize()
        });
        let circle = SwivelCircle::new(p, q, &corners);
        // Eq. 30 in f64 with libm's arccosine, from the corners themselves.
        let exact = |x: Real, keep: Option<Real>| -> Real {
            let (s, c) = real::sincos(0.5 * x);
            let r = p * c + q * s;
            let terms: Real = corners
                .iter()
                .map(|k| real::acos(real::min(r.dot(*k).abs(), 1.0)))
                .sum();
            terms + keep.map_or(0.0, |k| 0.5 * wrap(x - k) * wrap(x - k))
        };
        let (mut worst_value, mut worst_slope, mut worst_curvature): (Real, Real, Real) = (0.0, 0.0, 0.0);
        for keep in [None, Some(0.3)] {
            for k in 0..50 {
                let x = -3.0 + 0.12 * (k as Real);
                let probe = circle.probe(x, keep);
                worst_value = worst_value.max((probe.total - exact(x, keep)).abs());
                let h = 1e-5;
                let fd = (exact(x + h, keep) - exact(x - h, keep)) / (2.0 * h);
                let (g, c) = circle.slope(x, keep);
                assert!(
                    (probe.slope - g).abs() < 1e-5 * (1.0 + g.abs()),
                    "{} against {g}",
                    probe.slope
                );
                worst_slope = worst_slope.max((g - fd).abs() / (1.0 + g.abs()));
                let h = 1e-3;
                let fd2 = (circle.slope(x + h, keep).0 - circle.slope(x - h, keep).0) / (2.0 * h);
                worst_curvature = worst_curvature.max((c - fd2).abs() / (1.0 + c.abs()));
                assert!(c >= 0.0, "convex between kinks");
            }
        }
        assert!(worst_value < 8.0 * 3e-7, "eq. 30 off by {worst_value:e}");
        assert!(worst_slope < 1e-5, "slope off by {worst_slope:e}");
        assert!(worst_curvature < 1e-3, "curvature off by {worst_curvature:e}");
    }
}
