//! The centre of mass from a ZMP preview controller on the cart-table model (Kajita et al.,
//! "Biped walking pattern generation by using preview control of zero-moment point", ICRA
//! 2003; the servo with integral action and preview of Katayama et al., 1985).
//!
//! Per horizontal axis the centre of mass moves at constant height `z_c` with its jerk `u` as
//! the input, sampled every `T` seconds: `X[k+1] = A·X[k] + B·u[k]`, `X = (x, ẋ, ẍ)`,
//! `A = [[1, T, T²/2], [0, 1, T], [0, 0, 1]]`, `B = (T³/6, T²/2, T)`. The zero-moment point of
//! the cart on the table (the linear inverted pendulum) is `p = C·X = x − (z_c/g)·ẍ`.
//!
//! The control `u[k] = −G_i·Σ_{i≤k} e[i] − G_x·X[k] − Σ_{j=1..N} G_d(j)·p_ref[k+j]`,
//! `e = p − p_ref`, minimises `Σ Q_e·e² + R·u²` with the reference known `N` samples ahead.
//! The gains come from the discrete Riccati equation of the system augmented with the
//! integral of the error (`Ã = [[1, C·A], [0, A]]`, `B̃ = (C·B, B)`), solved once by
//! iteration when the controller is designed; a step then costs one dot product of `N` terms
//! per axis and allocates nothing.
//!
//! The design and the state are in f64 whatever [`crate::math::Real`] is: the jerk's input
//! matrix is of order `T³` (2·10⁻⁸ at 200 Hz), too small for single precision.

/// Most preview samples (at 250 Hz, 2 s).
pub const MAX_PREVIEW: usize = 512;

/// Gravity, m/s².
pub const GRAVITY: f64 = 9.81;

/// Weight of the ZMP error against the jerk's (Kajita's `Q_e = 1`, `R = 10⁻⁶`).
pub const JERK_WEIGHT: f64 = 1e-6;

/// Riccati iterations at most when designing.
const MAX_RICCATI: usize = 100_000;

/// Why a controller cannot be designed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PreviewError {
    /// A period, height or weight that is not a positive finite number.
    Parameter(&'static str),
    /// More than [`MAX_PREVIEW`] preview samples, or none.
    Horizon,
    /// The Riccati iteration did not settle.
    NoConvergence,
}

impl core::fmt::Display for PreviewError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            PreviewError::Parameter(what) => write!(f, "{what} must be a positive finite number"),
            PreviewError::Horizon => write!(f, "the preview must be 1 to {MAX_PREVIEW} samples"),
            PreviewError::NoConvergence => {
                f.write_str("the preview controller's Riccati equation did not settle")
            }
        }
    }
}

impl core::error::Error for PreviewError {}

type M4 = [[f64; 4]; 4];
type V4 = [f64; 4];

fn mul(a: &M4, b: &M4) -> M4 {
    let mut out = [[0.0; 4]; 4];
    for (i, row) in out.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = (0..4).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    out
}

fn transpose(a: &M4) -> M4 {
    let mut out = [[0.0; 4]; 4];
    for (i, row) in out.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = a[j][i];
        }
    }
    out
}

fn mul_v(a: &M4, v: &V4) -> V4 {
    let mut out = [0.0; 4];
    for (o, row) in out.iter_mut().zip(a) {
        *o = row.iter().zip(v).map(|(x, y)| x * y).sum();
    }
    out
}

fn dot(a: &V4, b: &V4) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// The gains of one design: period, height, horizon.
#[derive(Clone, Debug)]
pub struct PreviewGains {
    /// Sample period, s.
    pub dt: f64,
    /// Height of the centre of mass above the floor, m.
    pub height: f64,
    /// Integral gain `G_i`.
    pub integral: f64,
    /// State gains `G_x` (position, velocity, acceleration).
    pub state: [f64; 3],
    /// Preview gains `G_d(1..=N)`.
    pub preview: heapless::Vec<f64, MAX_PREVIEW>,
    /// The cart-table's `A` and `B` at this period.
    model: ([[f64; 3]; 3], [f64; 3]),
}

impl PreviewGains {
    /// Designs the controller for period `dt` (s), centre-of-mass height `height` (m) and
    /// `samples` of preview, with Kajita's weights ([`JERK_WEIGHT`]).
    ///
    /// # Errors
    /// [`PreviewError`].
    pub fn design(dt: f64, height: f64, samples: usize) -> Result<PreviewGains, PreviewError> {
        for (v, what) in [(dt, "the period"), (height, "the height of the centre of mass")] {
            if !(v.is_finite() && v > 0.0) {
                return Err(PreviewError::Parameter(what));
            }
        }
        if samples == 0 || samples > MAX_PREVIEW {
            return Err(PreviewError::Horizon);
        }
        let (a, b, c) = model(dt, height);
        // Augmented with the integral of the error: state (Σe, x, ẋ, ẍ).
        let ca = [
            c[0] * a[0][0] + c[1] * a[1][0] + c[2] * a[2][0],
            c[0] * a[0][1] + c[1] * a[1][1] + c[2] * a[2][1],
            c[0] * a[0][2] + c[1] * a[1][2] + c[2] * a[2][2],
        ];
        let cb = c[0] * b[0] + c[1] * b[1] + c[2] * b[2];
        let mut at: M4 = [[0.0; 4]; 4];
        at[0] = [1.0, ca[0], ca[1], ca[2]];
        for i in 0..3 {
            at[i + 1][1..4].copy_from_slice(&a[i]);
        }
        let bt: V4 = [cb, b[0], b[1], b[2]];
        let mut q: M4 = [[0.0; 4]; 4];
        q[0][0] = 1.0;
        let r = JERK_WEIGHT;

        // P = Ãᵀ P Ã − Ãᵀ P B̃ (R + B̃ᵀ P B̃)⁻¹ B̃ᵀ P Ã + Q, iterated to its fixed point.
        let at_t = transpose(&at);
        let mut p = q;
        let mut settled = false;
        for _ in 0..MAX_RICCATI {
            let pa = mul(&p, &at);
            let pb = mul_v(&p, &bt);
            let s = r + dot(&bt, &pb);
            let bpa: V4 = core::array::from_fn(|j| (0..4).map(|k| bt[k] * pa[k][j]).sum());
            let apa = mul(&at_t, &pa);
            let mut next = [[0.0; 4]; 4];
            for i in 0..4 {
                for j in 0..4 {
                    next[i][j] = apa[i][j] - bpa[i] * bpa[j] / s + q[i][j];
                }
            }
            let scale = next.iter().flatten().fold(0.0_f64, |m, v| m.max(v.abs()));
            let change = next
                .iter()
                .flatten()
                .zip(p.iter().flatten())
                .fold(0.0_f64, |m, (x, y)| m.max((x - y).abs()));
            p = next;
            if !scale.is_finite() {
                return Err(PreviewError::NoConvergence);
            }
            if change <= 1e-13 * scale {
                settled = true;
                break;
            }
        }
        if !settled {
            return Err(PreviewError::NoConvergence);
        }
        let pb = mul_v(&p, &bt);
        let s = r + dot(&bt, &pb);
        let pa = mul(&p, &at);
        let k: V4 = core::array::from_fn(|j| (0..4).map(|i| bt[i] * pa[i][j]).sum::<f64>() / s);
        // Closed loop Ãc = Ã − B̃K; X(1) = −Ãcᵀ P Ĩ, X(j) = Ãcᵀ X(j−1); G_d(1) = −G_i,
        // G_d(j) = B̃ᵀ X(j−1) / (R + B̃ᵀ P B̃).
        let mut ac = at;
        for i in 0..4 {
            for j in 0..4 {
                ac[i][j] -= bt[i] * k[j];
            }
        }
        let ac_t = transpose(&ac);
        let p_col: V4 = [p[0][0], p[1][0], p[2][0], p[3][0]];
        let mut x = mul_v(&ac_t, &p_col).map(|v| -v);
        let mut preview = heapless::Vec::new();
        let _ = preview.push(-k[0]);
        for _ in 1..samples {
            let _ = preview.push(dot(&bt, &x) / s);
            x = mul_v(&ac_t, &x);
        }
        Ok(PreviewGains {
            model: (a, b),
            dt,
            height,
            integral: k[0],
            state: [k[1], k[2], k[3]],
            preview,
        })
    }

    /// The preview, samples.
    #[must_use]
    pub fn samples(&self) -> usize {
        self.preview.len()
    }
}

/// `A`, `B` and `C` of the cart-table model.
fn model(dt: f64, height: f64) -> ([[f64; 3]; 3], [f64; 3], [f64; 3]) {
    let a = [[1.0, dt, dt * dt / 2.0], [0.0, 1.0, dt], [0.0, 0.0, 1.0]];
    let b = [dt * dt * dt / 6.0, dt * dt / 2.0, dt];
    let c = [1.0, 0.0, -height / GRAVITY];
    (a, b, c)
}

/// One axis of the cart-table: position, velocity, acceleration of the centre of mass and the
/// summed ZMP error.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct AxisState {
    /// Position, velocity, acceleration (m, m/s, m/s²).
    pub x: [f64; 3],
    /// Σ e, the summed ZMP error (m).
    pub error_sum: f64,
}

impl AxisState {
    /// At rest at `x`.
    #[must_use]
    pub fn at(x: f64) -> AxisState {
        AxisState {
            x: [x, 0.0, 0.0],
            error_sum: 0.0,
        }
    }

    /// The ZMP of this state, `p = x − (z_c/g)·ẍ`.
    #[must_use]
    pub fn zmp(&self, height: f64) -> f64 {
        self.x[0] - height / GRAVITY * self.x[2]
    }

    /// One step: `now` is the reference at this sample, `ahead(j)` the reference `j` samples
    /// ahead (`j` = 1..=N). Returns the jerk applied.
    pub fn step(&mut self, gains: &PreviewGains, now: f64, ahead: impl Fn(usize) -> f64) -> f64 {
        self.error_sum += self.zmp(gains.height) - now;
        let mut u = -gains.integral * self.error_sum
            - gains.state[0] * self.x[0]
            - gains.state[1] * self.x[1]
            - gains.state[2] * self.x[2];
        for (j, g) in gains.preview.iter().enumerate() {
            u -= g * ahead(j + 1);
        }
        let (a, b) = &gains.model;
        let x = self.x;
        for i in 0..3 {
            self.x[i] = a[i][0] * x[0] + a[i][1] * x[1] + a[i][2] * x[2] + b[i] * u;
        }
        u
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A ZMP reference that steps from 0 to 0.1 m at 1 s and back at 3 s.
    fn steps(t: f64) -> f64 {
        if (1.0..3.0).contains(&t) {
            0.1
        } else {
            0.0
        }
    }

    fn run(gains: &PreviewGains, seconds: f64, reference: impl Fn(f64) -> f64) -> (f64, f64, AxisState) {
        let mut s = AxisState::at(reference(0.0));
        let n = (seconds / gains.dt).round() as usize;
        let (mut worst, mut sq) = (0.0_f64, 0.0);
        for k in 0..n {
            let t = k as f64 * gains.dt;
            s.step(gains, reference(t), |j| reference(t + j as f64 * gains.dt));
            // The ZMP at the next sample against its reference.
            let e = s.zmp(gains.height) - reference(t + gains.dt);
            worst = worst.max(e.abs());
            sq += e * e;
        }
        (worst, (sq / n as f64).sqrt(), s)
    }

    #[test]
    fn previewed_steps_are_tracked_and_the_centre_of_mass_settles_on_them() {
        // The OP3's centre of mass at 8 ms (its framework's cycle), 1.6 s of preview.
        let g = PreviewGains::design(0.008, 0.23, 200).unwrap();
        assert_eq!(g.samples(), 200);
        // The preview gains die away: the last is a small share of the first.
        assert!(
            g.preview[199].abs() < 1e-3 * g.preview[0].abs(),
            "{} {}",
            g.preview[0],
            g.preview[199]
        );
        let (worst, rms, end) = run(&g, 5.0, steps);
        // A step of the reference is a discontinuity: the ZMP cannot jump, but it stays within
        // a few mm of it on average and ends on it.
        assert!(rms < 0.006, "rms {rms}");
        assert!(worst < 0.06, "worst {worst}");
        assert!(end.x[0].abs() < 1e-3 && end.x[1].abs() < 1e-3, "{end:?}");
    }

    #[test]
    fn the_preview_is_what_makes_it_track() {
        // The same design with one sample of preview sees the steps too late.
        let long = PreviewGains::design(0.008, 0.23, 200).unwrap();
        let short = PreviewGains::design(0.008, 0.23, 1).unwrap();
        let (_, rms_long, _) = run(&long, 5.0, steps);
        let (_, rms_short, _) = run(&short, 5.0, steps);
        assert!(rms_short > 5.0 * rms_long, "{rms_short} against {rms_long}");
    }

    #[test]
    fn alternating_support_is_followed_with_the_centre_of_mass_inside() {
        // Single supports 0.5 s long alternating ±5 cm: the CoM swings less far than the ZMP.
        let g = PreviewGains::design(0.004, 0.23, 400).unwrap();
        let zig = |t: f64| {
            if t < 1.0 {
                0.0
            } else if ((t - 1.0) / 0.5) as u64 % 2 == 0 {
                0.05
            } else {
                -0.05
            }
        };
        let mut s = AxisState::at(0.0);
        let mut widest: f64 = 0.0;
        for k in 0..1500 {
            let t = k as f64 * g.dt;
            s.step(&g, zig(t), |j| zig(t + j as f64 * g.dt));
            if t > 2.0 {
                widest = widest.max(s.x[0].abs());
            }
        }
        assert!(widest > 0.02 && widest < 0.045, "{widest}");
    }

    #[test]
    fn bad_parameters_are_refused() {
        assert_eq!(
            PreviewGains::design(0.0, 0.2, 10).unwrap_err(),
            PreviewError::Parameter("the period")
        );
        assert!(PreviewGains::design(0.01, f64::NAN, 10).is_err());
        assert_eq!(
            PreviewGains::design(0.01, 0.2, 0).unwrap_err(),
            PreviewError::Horizon
        );
        assert_eq!(
            PreviewGains::design(0.01, 0.2, MAX_PREVIEW + 1).unwrap_err(),
            PreviewError::Horizon
        );
    }
}
