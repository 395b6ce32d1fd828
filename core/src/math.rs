//! Rotation maths shared by every layer: axes, the 12 Euler orders, and the quaternion
//! distance of the help note, eq. (27)–(28).
//!
//! Convention: an [`EulerOrder`] names the axes in the order the rotations are *applied*
//! (first = innermost). `EulerOrder::XYZ` with angles `[a, b, c]` is `Rz(c)·Ry(b)·Rx(a)`, the
//! ASF `axis … XYZ` convention (help note eq. 3). Angles are radians.

mod sincos_table;

use consts::{PI, TAU};
use glam::{Mat3, Quat, Vec3, Vec4};

/// The core's floating-point type: `f64`, or `f32` with the `f32` feature (a firmware image
/// for a chip whose FPU is single precision, such as the STM32F7 of ROBOTIS's OpenCR). The std
/// crate needs `f64`; the feature is for images built on their own.
#[cfg(not(feature = "f32"))]
pub type Real = f64;
/// The core's floating-point type: `f32` (the `f32` feature).
#[cfg(feature = "f32")]
pub type Real = f32;
/// True when [`Real`] is `f32`.
pub const SINGLE_PRECISION: bool = cfg!(feature = "f32");

#[cfg(not(feature = "f32"))]
pub use glam::{DMat3 as RealMat3, DQuat as RealQuat, DVec2 as RealVec2, DVec3 as RealVec3};
#[cfg(feature = "f32")]
pub use glam::{Mat3 as RealMat3, Quat as RealQuat, Vec2 as RealVec2, Vec3 as RealVec3};

/// The constants of [`Real`] (π, τ, π/2, …).
pub mod consts {
    #[cfg(feature = "f32")]
    pub use core::f32::consts::*;
    #[cfg(not(feature = "f32"))]
    pub use core::f64::consts::*;
}

/// `double` in an f64 build, `single` in an f32 build: a tolerance stated for each precision.
#[must_use]
pub const fn precision(double: f64, single: f32) -> Real {
    #[cfg(not(feature = "f32"))]
    {
        let _ = single;
        double
    }
    #[cfg(feature = "f32")]
    {
        let _ = double;
        single
    }
}

/// libm's functions in [`Real`]'s precision.
pub mod real {
    use super::Real;

    macro_rules! real_fns {
        ($($name:ident / $f32:ident ($($arg:ident),*) -> $ret:ty;)*) => {$(
            #[doc = concat!("libm's `", stringify!($name), "` in [`Real`].")]
            #[inline]
            #[must_use]
            pub fn $name($($arg: Real),*) -> $ret {
                #[cfg(not(feature = "f32"))]
                {
                    libm::$name($($arg),*)
                }
                #[cfg(feature = "f32")]
                {
                    libm::$f32($($arg),*)
                }
            }
        )*};
    }
    real_fns! {
        atan / atanf (x) -> Real;
        atan2 / atan2f (y, x) -> Real;
        fmod / fmodf (x, y) -> Real;
        hypot / hypotf (x, y) -> Real;
        remainder / remainderf (x, y) -> Real;
    }

    /// `x` rounded to f32 (for f32 lanes; nothing to do in the f32 build).
    #[inline]
    #[must_use]
    #[allow(clippy::unnecessary_cast)]
    pub fn to_f32(x: Real) -> f32 {
        x as f32
    }

    /// An f32 value in [`Real`] (exact).
    #[inline]
    #[must_use]
    #[allow(clippy::useless_conversion)]
    pub fn from_f32(x: f32) -> Real {
        Real::from(x)
    }

    /// `|x|`: the sign bit cleared (core's; one instruction, where libm's is a call).
    #[inline]
    #[must_use]
    pub fn fabs(x: Real) -> Real {
        x.abs()
    }

    /// `x` with the sign of `y` (core's; a bit operation, where libm's is a call).
    #[inline]
    #[must_use]
    pub fn copysign(x: Real, y: Real) -> Real {
        x.copysign(y)
    }

    /// The nearest integer, halves away from zero: libm's in f64; in f32, [`super::round_f32`]
    /// (libm's `roundf` works on the bits, some fifty instructions).
    #[inline]
    #[must_use]
    pub fn round(x: Real) -> Real {
        #[cfg(not(feature = "f32"))]
        {
            libm::round(x)
        }
        #[cfg(feature = "f32")]
        {
            super::round_f32(x)
        }
    }

    /// `√x`: libm's in f64; in f32, [`super::sqrt_f32`] (the FPU's instruction on a Cortex-M).
    #[inline]
    #[must_use]
    pub fn sqrt(x: Real) -> Real {
        #[cfg(not(feature = "f32"))]
        {
            libm::sqrt(x)
        }
        #[cfg(feature = "f32")]
        {
            super::sqrt_f32(x)
        }
    }

    /// The larger of `a` and `b`, the other when one is NaN (`f64::max`). In f32 by comparison:
    /// `f32::max` is a library call on a chip without a max instruction (Armv7-M).
    #[inline]
    #[must_use]
    pub fn max(a: Real, b: Real) -> Real {
        #[cfg(not(feature = "f32"))]
        {
            a.max(b)
        }
        #[cfg(feature = "f32")]
        {
            if a.is_nan() || a < b {
                b
            } else {
                a
            }
        }
    }

    /// `x` limited to `[lo, hi]`, NaN staying NaN: `f64::clamp` without its panic for
    /// `lo > hi` (then `lo` below `lo`, `hi` above `hi`) and without its check's instructions.
    #[inline]
    #[must_use]
    pub fn clamp(x: Real, lo: Real, hi: Real) -> Real {
        if x < lo {
            lo
        } else if x > hi {
            hi
        } else {
            x
        }
    }

    /// The smaller of `a` and `b`, the other when one is NaN (`f64::min`; see [`max`]).
    #[inline]
    #[must_use]
    pub fn min(a: Real, b: Real) -> Real {
        #[cfg(not(feature = "f32"))]
        {
            a.min(b)
        }
        #[cfg(feature = "f32")]
        {
            if a.is_nan() || a > b {
                b
            } else {
                a
            }
        }
    }

    /// `(sin x, cos x)`: [`super::sincos_f64`] in f64; in f32, [`super::sincos_f32`] (libm's
    /// `sincosf` works in f64 inside, which a single-precision FPU does in software).
    #[inline]
    #[must_use]
    pub fn sincos(x: Real) -> (Real, Real) {
        #[cfg(not(feature = "f32"))]
        {
            super::sincos_f64(x)
        }
        #[cfg(feature = "f32")]
        {
            super::sincos_f32(x)
        }
    }

    /// [`sincos`] of every `x`, branch-free lanes: [`super::sincos_f64_many`] in f64,
    /// [`super::sincos_f32_many`] in f32.
    #[inline]
    pub fn sincos_many(x: &[Real], sin: &mut [Real], cos: &mut [Real]) {
        #[cfg(not(feature = "f32"))]
        {
            super::sincos_f64_many(x, sin, cos);
        }
        #[cfg(feature = "f32")]
        {
            super::sincos_f32_many(x, sin, cos);
        }
    }

    /// `acos x`: libm's in f64; in f32, `atan2(√((1 − x)(1 + x)), x)` (as [`asin`]; one libm
    /// function fewer in a firmware image). NaN outside `[−1, 1]`.
    #[inline]
    #[must_use]
    pub fn acos(x: Real) -> Real {
        #[cfg(not(feature = "f32"))]
        {
            libm::acos(x)
        }
        #[cfg(feature = "f32")]
        {
            libm::atan2f(super::sqrt_f32((1.0 - x) * (1.0 + x)), x)
        }
    }

    /// `asin x`: libm's in f64; in f32, `atan2(x, √((1 − x)(1 + x)))` (libm's `asinf` works in
    /// f64 inside; `1 − x` is exact near ±1, so nothing is lost there). NaN outside `[−1, 1]`.
    #[inline]
    #[must_use]
    pub fn asin(x: Real) -> Real {
        #[cfg(not(feature = "f32"))]
        {
            libm::asin(x)
        }
        #[cfg(feature = "f32")]
        {
            libm::atan2f(x, super::sqrt_f32((1.0 - x) * (1.0 + x)))
        }
    }

    /// `sin x` (see [`sincos`]).
    #[inline]
    #[must_use]
    pub fn sin(x: Real) -> Real {
        #[cfg(not(feature = "f32"))]
        {
            super::sincos_f64(x).0
        }
        #[cfg(feature = "f32")]
        {
            super::sincos_f32(x).0
        }
    }

    /// `cos x` (see [`sincos`]).
    #[inline]
    #[must_use]
    pub fn cos(x: Real) -> Real {
        #[cfg(not(feature = "f32"))]
        {
            super::sincos_f64(x).1
        }
        #[cfg(feature = "f32")]
        {
            super::sincos_f32(x).1
        }
    }
}

/// `(sin x, cos x)` in f32 without f64 inside: `x` reduced by the nearest multiple `q` of π/2
/// (π/2 split in three parts, Cody–Waite, so `q·part` is exact for `|q| < 2¹⁶`), then minimax
/// polynomials of degree 7 (sine) and 8 (cosine) on `[−π/4, π/4]` (Cephes' single-precision
/// coefficients). Error at most 1.2e-7 (9.2e-8 measured) for `|x| ≤ 1000`
/// (`tests::sincos_f32_stays_within_its_bound`), within an ulp of `x` up to `6·10⁶`; beyond that
/// (where f32 cannot tell angles apart by less than half a radian) after whole turns are taken
/// off in f32; NaN for a non-finite `x`.
#[must_use]
pub fn sincos_f32(x: f32) -> (f32, f32) {
    // One comparison, true for NaN too.
    #[allow(clippy::neg_cmp_op_on_partial_ord)]
    let x = if !(x.abs() <= SINCOS_F32_RANGE) {
        match whole_turns_off_f32(x) {
            Some(r) => r,
            None => return (f32::NAN, f32::NAN),
        }
    } else {
        x
    };
    let (s, c, quadrant) = sincos_f32_quarter(x);
    match quadrant & 3 {
        0 => (s, c),
        1 => (c, -s),
        2 => (-s, -c),
        _ => (-c, s),
    }
}

/// How far [`sincos_f32`] reduces: its quarter turns stay below 2²² (the rounding trick's
/// reach). Past 10⁵ the reduction's products are no longer exact, but its error stays below an
/// ulp of `x` itself.
const SINCOS_F32_RANGE: f32 = 6.0e6;

/// A finite `x` beyond [`SINCOS_F32_RANGE`] less whole turns, in f32 (no f64 or libm in a
/// firmware image): each pass leaves a remainder of a few ulps of what it started from, so two
/// or three passes bring any finite f32 into range; the result is as meaningful as `x`, whose
/// ulp is already half a radian or more. `None` for ∞, NaN, or a pass that overflows.
#[cold]
fn whole_turns_off_f32(mut x: f32) -> Option<f32> {
    for _ in 0..4 {
        if x.abs() <= SINCOS_F32_RANGE {
            return Some(x);
        }
        x -= round_f32(x * (0.5 / core::f32::consts::PI)) * core::f32::consts::TAU;
    }
    None
}

/// [`sincos_f32`]'s reduction and polynomials for `|x| ≤ 6·10⁶`: `(sin r, cos r, k)` where
/// `x = r + k·π/2`.
#[inline(always)]
#[allow(clippy::excessive_precision)]
fn sincos_f32_quarter(x: f32) -> (f32, f32, u32) {
    const FRAC_2_PI: f32 = core::f32::consts::FRAC_2_PI;
    const PIO2_1: f32 = 1.570_312_5;
    const PIO2_2: f32 = 4.837_512_969_970_703_125e-4;
    const PIO2_3: f32 = 7.549_789_954_891_882_16e-8;
    // The nearest quarter turn: adding 1.5·2²³ leaves `x·2/π` rounded to an integer in the low
    // mantissa bits (the FPU's rounding to nearest), without a conversion to an integer.
    const ROUNDER: f32 = 12_582_912.0;
    let n = x * FRAC_2_PI + ROUNDER;
    let q = n - ROUNDER;
    let r = ((x - q * PIO2_1) - q * PIO2_2) - q * PIO2_3;
    let z = r * r;
    let s = r + r * z * (-1.666_665_461_1e-1 + z * (8.332_160_873_6e-3 + z * -1.951_529_589_1e-4));
    let c = 1.0 - 0.5 * z
        + z * z * (4.166_664_568_298_827e-2 + z * (-1.388_731_625_493_765e-3 + z * 2.443_315_711_809_948e-5));
    (s, c, n.to_bits())
}

/// `(sin, cos)` of every `x` (as many as the shortest of the three slices), each the same bits
/// as [`sincos_f32`]'s. The quadrant is applied with integer masks instead of a jump, so the
/// loop has no branch and the compiler runs it four lanes at a time (SSE2 on x86-64): one
/// frame's rotation channels at once in forward kinematics. The rare `|x| > 6·10⁶`, ∞ or NaN
/// are redone one by one afterwards.
pub fn sincos_f32_many(x: &[f32], sin: &mut [f32], cos: &mut [f32]) {
    let mut reduced = true;
    for ((&x, sin), cos) in x.iter().zip(sin.iter_mut()).zip(cos.iter_mut()) {
        let (s, c, k) = sincos_f32_quarter(x);
        // Odd quadrants swap sine and cosine; the sine is negated in quadrants 2 and 3, the
        // cosine in 1 and 2.
        let swap = (k & 1).wrapping_neg();
        let (s, c) = (s.to_bits(), c.to_bits());
        *sin = f32::from_bits(((s & !swap) | (c & swap)) ^ ((k & 2) << 30));
        *cos = f32::from_bits(((c & !swap) | (s & swap)) ^ ((k.wrapping_add(1) & 2) << 30));
        reduced &= x.abs() <= SINCOS_F32_RANGE;
    }
    if !reduced {
        for ((&x, sin), cos) in x.iter().zip(sin.iter_mut()).zip(cos.iter_mut()) {
            (*sin, *cos) = sincos_f32(x);
        }
    }
}

/// `(sin x, cos x)` in f64 in one small function: `x = a + r` with `a` the nearest of 128 steps
/// of a turn (`j·π/64`, reduced Cody–Waite with π/64 in three 33-bit parts, so `q·part` is exact
/// for `|q| < 2²⁰`), `|r| ≤ π/128`; then the angle-sum formula with `(sin a, cos a)` from a
/// table of the nearest f64s and Taylor polynomials of `r` (degree 7 for `sin r`, 6 for
/// `cos r − 1`, whose next terms are below 10⁻¹⁷). Within 2.3e-16 of libm's for `|x| ≤ 5·10⁴`
/// (`tests::sincos_f64_is_libms_within_an_ulp`); beyond that libm's own reduction; NaN for a
/// non-finite `x`.
///
/// One code path for both values with no quadrant to apply, for every rotation channel of FK
/// and the swivel search's corners: libm's `sincos` with its general reduction was 19 lines of
/// the 593 a cold arm solve touched; the table is 2 KB.
#[must_use]
pub fn sincos_f64(x: f64) -> (f64, f64) {
    // One comparison, true for NaN too.
    #[allow(clippy::neg_cmp_op_on_partial_ord)]
    if !(x.abs() <= SINCOS_F64_REDUCED) {
        return if x.is_finite() {
            libm::sincos(x)
        } else {
            (f64::NAN, f64::NAN)
        };
    }
    sincos_f64_reduced(x)
}

/// Where [`sincos_f64`]'s own reduction ends and libm's takes over: its step count stays below
/// 2²⁰ (`|x|·64/π` for the table's 128 steps).
const SINCOS_F64_REDUCED: f64 = 5.0e4;
const _: () =
    assert!(SINCOS_F64_REDUCED * (sincos_table::STEPS as f64) / core::f64::consts::TAU < 1_048_576.0);

/// [`sincos_f64`] for `|x| ≤ 5·10⁴`, without a branch.
#[inline(always)]
#[allow(
    clippy::excessive_precision,
    clippy::unreadable_literal,
    clippy::cast_possible_truncation
)]
fn sincos_f64_reduced(x: f64) -> (f64, f64) {
    use sincos_table::{SIN_COS, STEPS};
    // The table's steps a quarter turn, a power of two: scaling by it is exact.
    const QUARTER: f64 = (STEPS / 4) as f64;
    const _: () = assert!(STEPS.is_power_of_two() && STEPS >= 4);
    // Steps a radian (2/π scaled), and a step in three parts: fdlibm's split of π/2 scaled.
    const STEPS_PER_RADIAN: f64 = core::f64::consts::FRAC_2_PI * QUARTER;
    const STEP_1: f64 = 1.570_796_326_734_125_614_17 / QUARTER;
    const STEP_2: f64 = 6.077_100_506_303_965_976_6e-11 / QUARTER;
    const STEP_3: f64 = 2.022_266_248_711_166_455_8e-21 / QUARTER;
    // The nearest step: adding 1.5·2⁵² leaves `x·STEPS/2π` rounded to an integer in the low
    // mantissa bits (the FPU's rounding to nearest), without a conversion to an integer.
    const ROUNDER: f64 = 6_755_399_441_055_744.0;
    let n = x * STEPS_PER_RADIAN + ROUNDER;
    let q = n - ROUNDER;
    let (sin_a, cos_a) = SIN_COS[(n.to_bits() as usize) & (STEPS - 1)];
    let r = ((x - q * STEP_1) - q * STEP_2) - q * STEP_3;
    let z = r * r;
    let sin_r = r + r * z * (-1.0 / 6.0 + z * (1.0 / 120.0 + z * (-1.0 / 5040.0)));
    let cos_r_less_1 = z * (-0.5 + z * (1.0 / 24.0 + z * (-1.0 / 720.0)));
    // sin(a + r) and cos(a + r), the table's value added last: its rounding is the only one
    // at full size.
    (
        sin_a + (sin_a * cos_r_less_1 + cos_a * sin_r),
        cos_a + (cos_a * cos_r_less_1 - sin_a * sin_r),
    )
}

/// `(sin, cos)` of every `x` (as many as the shortest of the three slices), each the same bits
/// as [`sincos_f64`]'s: the loop has no branch; the rare `|x| > 5·10⁴` or NaN are redone one by
/// one afterwards.
pub fn sincos_f64_many(x: &[f64], sin: &mut [f64], cos: &mut [f64]) {
    let mut reduced = true;
    for ((&x, sin), cos) in x.iter().zip(sin.iter_mut()).zip(cos.iter_mut()) {
        (*sin, *cos) = sincos_f64_reduced(x);
        reduced &= x.abs() <= SINCOS_F64_REDUCED;
    }
    if !reduced {
        for ((&x, sin), cos) in x.iter().zip(sin.iter_mut()).zip(cos.iter_mut()) {
            (*sin, *cos) = sincos_f64(x);
        }
    }
}

/// The nearest integer to `x`, halves away from zero (libm's `roundf`, bit for bit, signed
/// zeros included; NaN for NaN: `tests::round_f32_is_libms`), through the FPU's conversion to `i32`:
/// below 2²³ the truncation and `x` minus it are exact; from 2²³ on every f32 is an integer.
#[must_use]
#[inline]
#[allow(clippy::cast_possible_truncation, clippy::cast_precision_loss)]
pub fn round_f32(x: f32) -> f32 {
    if x.abs() >= 8_388_608.0 || x.is_nan() {
        // An integer already, ±∞ or NaN.
        return x;
    }
    let t = x as i32 as f32;
    let fraction = x - t;
    let r = if fraction >= 0.5 {
        t + 1.0
    } else if fraction <= -0.5 {
        t - 1.0
    } else {
        t
    };
    libm::copysignf(r, x)
}

/// `√x` in f32, correctly rounded, so that every build computes the same bits: the FPU's
/// `vsqrt.f32` on Arm with hardware floating point (a Cortex-M4F/M7: one instruction, where
/// libm's `sqrtf` is ~100 instructions of integer arithmetic, because libm has no Arm path
/// and `f32::sqrt` is not in `core`), libm's `sqrtf` elsewhere (`sqrtss` on x86-64).
/// 0 for ±0 (keeping the sign), NaN below 0, ∞ for ∞.
#[must_use]
#[inline]
pub fn sqrt_f32(x: f32) -> f32 {
    #[cfg(all(target_arch = "arm", target_abi = "eabihf"))]
    {
        vsqrt_f32(x)
    }
    #[cfg(not(all(target_arch = "arm", target_abi = "eabihf")))]
    {
        libm::sqrtf(x)
    }
}

/// `vsqrt.f32`, the one instruction the core writes in assembly. The value travels in a core
/// register and `s15` is declared clobbered, because rustc offers the FPU's register class only
/// with its `vfp2` feature, which an `eabihf` Cortex-M target does not name.
#[cfg(all(target_arch = "arm", target_abi = "eabihf"))]
#[inline]
#[allow(unsafe_code)]
fn vsqrt_f32(x: f32) -> f32 {
    let root: u32;
    // SAFETY: three register moves and a square root on `s15`, which is declared clobbered:
    // no memory, no stack, no flags; every input has a defined result (IEEE 754).
    unsafe {
        core::arch::asm!(
            "vmov s15, {x}",
            "vsqrt.f32 s15, s15",
            "vmov {root}, s15",
            x = in(reg) x.to_bits(),
            root = lateout(reg) root,
            out("s15") _,
            options(pure, nomem, nostack, preserves_flags),
        );
    }
    f32::from_bits(root)
}

/// The rotation by `angle` about the unit `axis` (Rodrigues), through [`real::sincos`].
#[must_use]
pub fn mat3_from_axis_angle(axis: RealVec3, angle: Real) -> RealMat3 {
    let (s, c) = real::sincos(angle);
    let t = 1.0 - c;
    let (x, y, z) = (axis.x, axis.y, axis.z);
    RealMat3::from_cols(
        RealVec3::new(t * x * x + c, t * x * y + s * z, t * x * z - s * y),
        RealVec3::new(t * x * y - s * z, t * y * y + c, t * y * z + s * x),
        RealVec3::new(t * x * z + s * y, t * y * z - s * x, t * z * z + c),
    )
}

/// The rotation by `angle` about the unit `axis` as a quaternion, through [`real::sincos`].
#[must_use]
pub fn quat_from_axis_angle(axis: RealVec3, angle: Real) -> RealQuat {
    let (s, c) = real::sincos(0.5 * angle);
    let v = axis * s;
    RealQuat::from_xyzw(v.x, v.y, v.z, c)
}

/// `|v|` through [`real::sqrt`]: glam's `length`, whose f32 square root is libm's.
#[inline]
#[must_use]
pub fn length(v: RealVec3) -> Real {
    real::sqrt(v.dot(v))
}

/// `v / |v|`: glam's `normalize` through [`length`] (not finite for a zero `v`).
#[inline]
#[must_use]
pub fn normalize(v: RealVec3) -> RealVec3 {
    v * (1.0 / length(v))
}

/// `v / |v|`, or zero when that is not finite: glam's `normalize_or_zero` through [`length`].
#[inline]
#[must_use]
pub fn normalize_or_zero(v: RealVec3) -> RealVec3 {
    let rcp = 1.0 / length(v);
    if rcp.is_finite() && rcp > 0.0 {
        v * rcp
    } else {
        RealVec3::ZERO
    }
}

/// The shortest rotation taking unit `from` to unit `to`: the normalised `(from × to,
/// 1 + from·to)`, well conditioned up to parallel vectors (glam's `from_rotation_arc` returns
/// the identity within `2ε` of parallel: within 7e-4 rad in f32, which left a 4.7e-3 reach
/// error on a leg), normalised through [`real::sqrt`]. Near-opposite vectors (within `2ε`)
/// get glam's half turn about a perpendicular.
#[must_use]
pub fn rotation_arc(from: RealVec3, to: RealVec3) -> RealQuat {
    let dot = from.dot(to);
    if dot < -1.0 + 2.0 * Real::EPSILON {
        return RealQuat::from_rotation_arc(from, to);
    }
    let c = from.cross(to);
    let q = RealQuat::from_xyzw(c.x, c.y, c.z, 1.0 + dot);
    q * (1.0 / real::sqrt(q.dot(q)))
}

/// Sorts a short slice by a [`Real`] key, ascending in `total_cmp` order (stable insertion
/// sort: the solver's lists hold a few dozen entries, and core's general sort costs 7 KB of
/// a firmware image's flash).
pub fn sort_by_real<T: Copy>(v: &mut [T], key: impl Fn(&T) -> Real) {
    for i in 1..v.len() {
        let x = v[i];
        let k = key(&x);
        let mut j = i;
        while j > 0 && key(&v[j - 1]).total_cmp(&k).is_gt() {
            v[j] = v[j - 1];
            j -= 1;
        }
        v[j] = x;
    }
}

/// glam's f32 types in [`Real`]'s precision (`as_dvec3` and the like, or nothing).
pub trait ToReal {
    /// The value in [`Real`]'s precision.
    type Real;
    /// The value in [`Real`]'s precision.
    fn to_real(self) -> Self::Real;
}

/// `impl ToReal for F32Type { type Real = RealType; … }`, widening with glam's `as_d…` in f64.
macro_rules! to_real {
    ($($f32:ty => $real:ty, $widen:ident;)*) => {$(
        impl ToReal for $f32 {
            type Real = $real;
            #[inline]
            fn to_real(self) -> $real {
                #[cfg(not(feature = "f32"))]
                {
                    self.$widen()
                }
                #[cfg(feature = "f32")]
                {
                    self
                }
            }
        }
    )*};
}
to_real! {
    Vec3 => RealVec3, as_dvec3;
    Mat3 => RealMat3, as_dmat3;
}

/// A principal axis.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Axis {
    /// The x axis.
    X,
    /// The y axis (up in ASF/AMC and BVH).
    Y,
    /// The z axis.
    Z,
}

impl Axis {
    /// The two coordinates a turn about this axis mixes, in the turn's order: `(y, z)`,
    /// `(z, x)`, `(x, y)`.
    #[inline]
    #[must_use]
    pub const fn across(self) -> (usize, usize) {
        match self {
            Axis::X => (1, 2),
            Axis::Y => (2, 0),
            Axis::Z => (0, 1),
        }
    }

    /// 0, 1 or 2.
    #[inline]
    #[must_use]
    pub const fn index(self) -> usize {
        match self {
            Axis::X => 0,
            Axis::Y => 1,
            Axis::Z => 2,
        }
    }

    /// The unit vector along this axis.
    #[inline]
    #[must_use]
    pub fn unit(self) -> Vec3 {
        match self {
            Axis::X => Vec3::X,
            Axis::Y => Vec3::Y,
            Axis::Z => Vec3::Z,
        }
    }

    /// The rotation by `angle` radians about this axis.
    #[inline]
    #[must_use]
    pub fn rotation(self, angle: f32) -> Mat3 {
        match self {
            Axis::X => Mat3::from_rotation_x(angle),
            Axis::Y => Mat3::from_rotation_y(angle),
            Axis::Z => Mat3::from_rotation_z(angle),
        }
    }

    /// The rotation by `angle` radians about this axis, in [`Real`] (f64 unless the `f32`
    /// feature is on, as for every `_f64` name here).
    #[inline]
    #[must_use]
    pub fn rotation_f64(self, angle: Real) -> RealMat3 {
        let (s, c) = real::sincos(angle);
        let (i, j) = self.across();
        let mut m = RealMat3::IDENTITY;
        m.col_mut(i)[i] = c;
        m.col_mut(i)[j] = s;
        m.col_mut(j)[i] = -s;
        m.col_mut(j)[j] = c;
        m
    }
}

/// One of the 12 Euler orders: six Tait–Bryan (three distinct axes) and six proper Euler
/// orders (first axis repeated). The letters are the axes in the order they are applied.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[allow(missing_docs)]
pub enum EulerOrder {
    XYZ,
    XZY,
    YXZ,
    YZX,
    ZXY,
    ZYX,
    XYX,
    XZX,
    YXY,
    YZY,
    ZXZ,
    ZYZ,
}

impl EulerOrder {
    /// All 12 orders.
    pub const ALL: [EulerOrder; 12] = [
        EulerOrder::XYZ,
        EulerOrder::XZY,
        EulerOrder::YXZ,
        EulerOrder::YZX,
        EulerOrder::ZXY,
        EulerOrder::ZYX,
        EulerOrder::XYX,
        EulerOrder::XZX,
        EulerOrder::YXY,
        EulerOrder::YZY,
        EulerOrder::ZXZ,
        EulerOrder::ZYZ,
    ];

    /// The axes in application order.
    #[must_use]
    pub const fn axes(self) -> [Axis; 3] {
        use Axis::*;
        match self {
            EulerOrder::XYZ => [X, Y, Z],
            EulerOrder::XZY => [X, Z, Y],
            EulerOrder::YXZ => [Y, X, Z],
            EulerOrder::YZX => [Y, Z, X],
            EulerOrder::ZXY => [Z, X, Y],
            EulerOrder::ZYX => [Z, Y, X],
            EulerOrder::XYX => [X, Y, X],
            EulerOrder::XZX => [X, Z, X],
            EulerOrder::YXY => [Y, X, Y],
            EulerOrder::YZY => [Y, Z, Y],
            EulerOrder::ZXZ => [Z, X, Z],
            EulerOrder::ZYZ => [Z, Y, Z],
        }
    }

    /// The order whose axes are these, if any (three distinct axes, or first == last).
    #[must_use]
    pub fn from_axes(axes: [Axis; 3]) -> Option<EulerOrder> {
        EulerOrder::ALL.into_iter().find(|o| o.axes() == axes)
    }

    /// Parses `XYZ`, `zyx`, … (case-insensitive).
    #[must_use]
    pub fn parse(text: &str) -> Option<EulerOrder> {
        let b = text.as_bytes();
        if b.len() != 3 {
            return None;
        }
        let mut axes = [Axis::X; 3];
        for (slot, c) in axes.iter_mut().zip(b) {
            *slot = match c.to_ascii_uppercase() {
                b'X' => Axis::X,
                b'Y' => Axis::Y,
                b'Z' => Axis::Z,
                _ => return None,
            };
        }
        EulerOrder::from_axes(axes)
    }

    /// The order's name, e.g. `"XYZ"`.
    #[must_use]
    pub const fn name(self) -> &'static str {
        match self {
            EulerOrder::XYZ => "XYZ",
            EulerOrder::XZY => "XZY",
            EulerOrder::YXZ => "YXZ",
            EulerOrder::YZX => "YZX",
            EulerOrder::ZXY => "ZXY",
            EulerOrder::ZYX => "ZYX",
            EulerOrder::XYX => "XYX",
            EulerOrder::XZX => "XZX",
            EulerOrder::YXY => "YXY",
            EulerOrder::YZY => "YZY",
            EulerOrder::ZXZ => "ZXZ",
            EulerOrder::ZYZ => "ZYZ",
        }
    }

    /// True for the six proper Euler orders (first axis repeated).
    #[must_use]
    pub const fn is_proper(self) -> bool {
        let a = self.axes();
        a[0].index() == a[2].index()
    }

    /// The rotation `R3(c)·R2(b)·R1(a)` for angles `[a, b, c]` in radians.
    #[must_use]
    pub fn to_mat3(self, angles: [f32; 3]) -> Mat3 {
        let [i, j, k] = self.axes();
        k.rotation(angles[2]) * j.rotation(angles[1]) * i.rotation(angles[0])
    }

    /// The rotation `R3(c)·R2(b)·R1(a)` as a quaternion.
    #[must_use]
    pub fn to_quat(self, angles: [f32; 3]) -> Quat {
        let [i, j, k] = self.axes();
        Quat::from_axis_angle(k.unit(), angles[2])
            * Quat::from_axis_angle(j.unit(), angles[1])
            * Quat::from_axis_angle(i.unit(), angles[0])
    }

    /// The rotation `R3(c)·R2(b)·R1(a)` in [`Real`].
    #[must_use]
    pub fn to_mat3_f64(self, angles: [Real; 3]) -> RealMat3 {
        let [i, j, k] = self.axes();
        k.rotation_f64(angles[2]) * j.rotation_f64(angles[1]) * i.rotation_f64(angles[0])
    }

    /// Angles `[a, b, c]` (radians) with `self.to_mat3(angles) == m`, for a rotation matrix `m`.
    ///
    /// The middle angle is in `[-π/2, π/2]` (Tait–Bryan) or `[0, π]` (proper Euler); at gimbal
    /// lock the first angle is set to 0.
    #[must_use]
    pub fn from_mat3(self, m: &Mat3) -> [f32; 3] {
        let r = |i: usize, j: usize| m.col(j)[i];
        let [a, b, c] = self.extract(&r, 1.0e-6f32, libm::atan2f, libm::asinf, libm::acosf);
        [a, b, c]
    }

    /// Angles of a quaternion (see [`EulerOrder::from_mat3`]).
    #[must_use]
    pub fn from_quat(self, q: Quat) -> [f32; 3] {
        self.from_mat3(&Mat3::from_quat(q.normalize()))
    }

    /// Angles `[a, b, c]` (radians) with `self.to_mat3_f64(angles) == m`, in [`Real`].
    #[must_use]
    pub fn from_mat3_f64(self, m: &RealMat3) -> [Real; 3] {
        let r = |i: usize, j: usize| m.col(j)[i];
        self.extract(
            &r,
            precision(1.0e-12, 1.0e-6),
            real::atan2,
            real::asin,
            real::acos,
        )
    }

    /// Angles of an f64 quaternion.
    #[must_use]
    pub fn from_quat_f64(self, q: RealQuat) -> [Real; 3] {
        self.from_mat3_f64(&RealMat3::from_quat(q.normalize()))
    }

    /// The extraction shared by f32 and f64. `r(i, j)` is the element in row i, column j.
    ///
    /// Tait–Bryan `Rk(c)Rj(b)Ri(a)` with parity `s` (+1 for cyclic i→j→k):
    /// `R[k][i] = −s·sin b`, `a = atan2(s·R[k][j], R[k][k])`, `c = atan2(s·R[j][i], R[i][i])`.
    /// Proper `Ri(c)Rj(b)Ri(a)` with third axis m and parity s of (i, j, m):
    /// `R[i][i] = cos b`, `a = atan2(R[i][j], s·R[i][m])`, `c = atan2(R[j][i], −s·R[m][i])`.
    fn extract<T: Float>(
        self,
        r: &dyn Fn(usize, usize) -> T,
        eps: T,
        atan2: fn(T, T) -> T,
        asin: fn(T) -> T,
        acos: fn(T) -> T,
    ) -> [T; 3] {
        let [ai, aj, ak] = self.axes();
        let (i, j) = (ai.index(), aj.index());
        let one = T::ONE;
        if !self.is_proper() {
            let k = ak.index();
            let s = if (j + 3 - i) % 3 == 1 { one } else { -one };
            let sb = -(s * r(k, i));
            if sb.abs_r() < one - eps {
                let a = atan2(s * r(k, j), r(k, k));
                let b = asin(sb);
                let c = atan2(s * r(j, i), r(i, i));
                [a, b, c]
            } else {
                // Gimbal lock: a = 0, so R = Rk(c)·Rj(b); c from R·Rj(b)ᵀ = Rk(c).
                let b = asin(sb.clamp_r(-one, one));
                let c = single_axis_angle(r, aj, b, ak, atan2);
                [T::ZERO, b, c]
            }
        } else {
            let m = 3 - i - j;
            let s = if (j + 3 - i) % 3 == 1 { one } else { -one };
            let cb = r(i, i).clamp_r(-one, one);
            let b = acos(cb);
            if cb.abs_r() < one - eps {
                let a = atan2(r(i, j), s * r(i, m));
                let c = atan2(r(j, i), -(s * r(m, i)));
                [a, b, c]
            } else {
                let c = single_axis_angle(r, aj, b, ai, atan2);
                [T::ZERO, b, c]
            }
        }
    }
}

/// A signed element `sign · R[row][col]` of a rotation matrix.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Element {
    /// Row.
    pub row: usize,
    /// Column.
    pub col: usize,
    /// ±1.
    pub sign: Real,
}

/// How one angle of [`EulerOrder::from_mat3_f64`] comes from the matrix, outside gimbal lock.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum AngleOf {
    /// `atan2(y, x)`.
    Atan2(Element, Element),
    /// `asin(e)` (the middle angle of a Tait–Bryan order, in `[−π/2, π/2]`).
    Asin(Element),
    /// `acos(e)` (the middle angle of a proper Euler order, in `[0, π]`).
    Acos(Element),
}

impl EulerOrder {
    /// The matrix elements each of the three angles is read from (the formulas of
    /// [`EulerOrder::from_mat3_f64`] outside gimbal lock). The other solution of the same
    /// matrix is `[a + π, π − b, c + π]` (Tait–Bryan) or `[a + π, −b, c + π]` (proper).
    #[must_use]
    pub fn angle_forms(self) -> [AngleOf; 3] {
        let [ai, aj, ak] = self.axes();
        let (i, j) = (ai.index(), aj.index());
        let s = if (j + 3 - i) % 3 == 1 { 1.0 } else { -1.0 };
        let e = |row, col, sign| Element { row, col, sign };
        if self.is_proper() {
            let m = 3 - i - j;
            [
                AngleOf::Atan2(e(i, j, 1.0), e(i, m, s)),
                AngleOf::Acos(e(i, i, 1.0)),
                AngleOf::Atan2(e(j, i, 1.0), e(m, i, -s)),
            ]
        } else {
            let k = ak.index();
            [
                AngleOf::Atan2(e(k, j, s), e(k, k, 1.0)),
                AngleOf::Asin(e(k, i, -s)),
                AngleOf::Atan2(e(j, i, s), e(i, i, 1.0)),
            ]
        }
    }
}

/// The angle `c` of `M = R·Rj(b)ᵀ`, assumed to be a rotation about `k` (gimbal-lock case).
fn single_axis_angle<T: Float>(
    r: &dyn Fn(usize, usize) -> T,
    j: Axis,
    b: T,
    k: Axis,
    atan2: fn(T, T) -> T,
) -> T {
    // Rj(b)ᵀ columns: element (p, q) of Rj(-b).
    let rj_t = |p: usize, q: usize| T::axis_rotation_element(j.index(), -b, p, q);
    let mm = |p: usize, q: usize| {
        let mut acc = T::ZERO;
        for n in 0..3 {
            acc = acc + r(p, n) * rj_t(n, q);
        }
        acc
    };
    let n1 = (k.index() + 1) % 3;
    let n2 = (k.index() + 2) % 3;
    atan2(mm(n2, n1), mm(n1, n1))
}

/// The few scalar operations the Euler extraction needs, for f32 and f64.
trait Float:
    Copy
    + PartialOrd
    + core::ops::Add<Output = Self>
    + core::ops::Sub<Output = Self>
    + core::ops::Mul<Output = Self>
    + core::ops::Neg<Output = Self>
{
    const ONE: Self;
    const ZERO: Self;
    fn abs_r(self) -> Self;
    fn clamp_r(self, lo: Self, hi: Self) -> Self;
    /// Element (p, q) of the rotation by `angle` about axis `axis`.
    fn axis_rotation_element(axis: usize, angle: Self, p: usize, q: usize) -> Self;
}

macro_rules! impl_real {
    ($t:ty, $sin:path, $cos:path) => {
        impl Float for $t {
            const ONE: Self = 1.0;
            const ZERO: Self = 0.0;
            fn abs_r(self) -> Self {
                if self < 0.0 {
                    -self
                } else {
                    self
                }
            }
            fn clamp_r(self, lo: Self, hi: Self) -> Self {
                if self < lo {
                    lo
                } else if self > hi {
                    hi
                } else {
                    self
                }
            }
            fn axis_rotation_element(axis: usize, angle: Self, p: usize, q: usize) -> Self {
                let (s, c) = ($sin(angle), $cos(angle));
                let n1 = (axis + 1) % 3;
                let n2 = (axis + 2) % 3;
                match (p, q) {
                    _ if p == axis && q == axis => 1.0,
                    _ if p == axis || q == axis => 0.0,
                    _ if p == q => c,
                    _ if p == n2 && q == n1 => s,
                    _ => -s,
                }
            }
        }
    };
}
#[cfg(not(feature = "f32"))]
impl_real!(f32, libm::sinf, libm::cosf);
// (The f32 build keeps libm's f64-based `sinf`/`cosf` out of the image.)
#[cfg(feature = "f32")]
impl_real!(f32, real::sin, real::cos);
#[cfg(not(feature = "f32"))]
impl_real!(f64, real::sin, real::cos);
#[cfg(feature = "f32")]
impl_real!(f64, libm::sin, libm::cos);

/// The geodesic distance of eq. (27)–(28): `‖log(q1⁻¹·q2)‖`, taking the shorter of `q` and
/// `−q`; half the rotation angle between the two, in `[0, π/2]`.
#[inline]
#[must_use]
pub fn quat_distance(q1: Quat, q2: Quat) -> f32 {
    let d = q1.conjugate() * q2;
    let v = Vec3::new(d.x, d.y, d.z).length();
    libm::atan2f(v, libm::fabsf(d.w))
}

/// [`quat_distance_f64`] with a polynomial arctangent (error below 1e-7 rad; 3.8e-8 measured by the `ik` tests): for scores
/// evaluated many times per solve (the swivel search's eq. 30), where libm's `atan2` dominated
/// the cost.
#[inline]
#[must_use]
pub fn quat_distance_fast(q1: RealQuat, q2: RealQuat) -> Real {
    let d = q1.conjugate() * q2;
    atan_ratio_fast(RealVec3::new(d.x, d.y, d.z).length(), real::fabs(d.w))
}

/// The polynomial of [`atan_ratio_fast`]: `atan x ≈ x·(c₀ + c₁·x² + … + c₇·x¹⁴)` on `[0, 1]`
/// (Abramowitz & Stegun 4.4.49).
#[allow(clippy::excessive_precision)] // (the coefficients as published; f32 rounds them)
const ATAN_COEFFICIENTS: [Real; 8] = [
    0.999_999_332_9,
    -0.333_298_560_5,
    0.199_465_359_9,
    -0.139_085_335_1,
    0.096_420_044_1,
    -0.055_909_886_1,
    0.021_861_228_8,
    -0.004_054_058_0,
];

/// `atan2(v, w)` for `v, w ≥ 0` with a polynomial arctangent, error below 1e-7 rad
/// (Abramowitz & Stegun 4.4.49 on `[0, 1]`; the other octant by `π/2 − atan(1/x)`). One copy in the
/// f32 build (a firmware image's flash).
#[cfg_attr(not(feature = "f32"), inline)]
#[cfg_attr(feature = "f32", inline(never))]
#[must_use]
pub fn atan_ratio_fast(v: Real, w: Real) -> Real {
    let c = &ATAN_COEFFICIENTS;
    let poly = |x: Real| {
        let z = x * x;
        x * (c[0] + z * (c[1] + z * (c[2] + z * (c[3] + z * (c[4] + z * (c[5] + z * (c[6] + z * c[7])))))))
    };
    if v <= w {
        if w == 0.0 {
            0.0
        } else {
            poly(v / w)
        }
    } else {
        consts::FRAC_PI_2 - poly(w / v)
    }
}

/// [`atan_ratio_fast`] on four lanes of f32 (glam's `Vec4`: one SSE2 instruction per step on
/// x86-64): `atan2(v, w)` for `v, w ≥ 0`, 0 where both are 0. Error below 1e-7 rad plus f32's
/// rounding (2.4e-7 at π/2).
#[inline]
#[must_use]
#[cfg(not(feature = "f32"))]
pub fn atan_ratio_lanes(v: Vec4, w: Vec4) -> Vec4 {
    let c = ATAN_COEFFICIENTS.map(|k| Vec4::splat(real::to_f32(k)));
    let x = v.min(w) / v.max(w).max(Vec4::splat(f32::MIN_POSITIVE));
    let z = x * x;
    let p =
        x * (c[0] + z * (c[1] + z * (c[2] + z * (c[3] + z * (c[4] + z * (c[5] + z * (c[6] + z * c[7])))))));
    Vec4::select(v.cmple(w), p, Vec4::splat(core::f32::consts::FRAC_PI_2) - p)
}

/// [`atan_ratio_lanes`] in the f32 build, whose `Vec4` is four scalars (glam's scalar maths):
/// [`atan_ratio_fast`] lane by lane, a quarter of the code in a firmware image.
#[inline]
#[must_use]
#[cfg(feature = "f32")]
pub fn atan_ratio_lanes(v: Vec4, w: Vec4) -> Vec4 {
    let (v, w) = (v.to_array(), w.to_array());
    Vec4::from_array(core::array::from_fn(|i| atan_ratio_fast(v[i], w[i])))
}

/// `√x` on four lanes of f32, correctly rounded: glam's with SSE2 (one instruction); where
/// `Vec4` is four scalars, [`sqrt_f32`] lane by lane (glam's scalar `sqrt` is libm's, done in
/// software on a Cortex-M).
#[inline]
#[must_use]
pub fn sqrt_lanes(x: Vec4) -> Vec4 {
    #[cfg(all(target_feature = "sse2", not(feature = "f32")))]
    {
        x.sqrt()
    }
    #[cfg(not(all(target_feature = "sse2", not(feature = "f32"))))]
    {
        Vec4::from_array(x.to_array().map(sqrt_f32))
    }
}

/// The sum of four lanes, `((x + y) + z) + w`: the same order, so the same bits, with SSE2 and
/// with glam's scalar maths (glam's `element_sum` adds in a different order on each).
#[inline]
#[must_use]
pub fn sum_lanes(x: Vec4) -> f32 {
    let [a, b, c, d] = x.to_array();
    ((a + b) + c) + d
}

/// [`atan2_fast`] on four lanes of f32: `atan2(y, x)` in `[−π, π]`, error below 1e-7 rad plus
/// f32's rounding.
#[inline]
#[must_use]
pub fn atan2_lanes(y: Vec4, x: Vec4) -> Vec4 {
    let a = atan_ratio_lanes(y.abs(), x.abs());
    let a = Vec4::select(x.cmplt(Vec4::ZERO), Vec4::splat(core::f32::consts::PI) - a, a);
    Vec4::select(y.cmplt(Vec4::ZERO), -a, a)
}

/// `atan2(y, x)` through [`atan_ratio_fast`] (error below 1e-7 rad), in `[−π, π]`.
#[inline]
#[must_use]
pub fn atan2_fast(y: Real, x: Real) -> Real {
    let a = atan_ratio_fast(real::fabs(y), real::fabs(x));
    let a = if x < 0.0 { consts::PI - a } else { a };
    if y < 0.0 {
        -a
    } else {
        a
    }
}

/// `acos(x)` for `|x| ≤ 1` (clamped) through [`atan_ratio_fast`] (error below 1e-7 rad).
#[inline]
#[must_use]
pub fn acos_fast(x: Real) -> Real {
    let x = x.clamp(-1.0, 1.0);
    atan2_fast(real::sqrt(((1.0 - x) * (1.0 + x)).max(0.0)), x)
}

/// `acos(|x|)` for `|x| ≤ 1` through [`atan_ratio_fast`] (error below 1e-7 rad): eq. (27)–(28)'s
/// distance `acos(|q₁·q₂|)` between unit quaternions from their 4-D dot product.
#[inline]
#[must_use]
pub fn acos_abs_fast(x: Real) -> Real {
    let w = real::fabs(x).min(1.0);
    atan_ratio_fast(real::sqrt(((1.0 - w) * (1.0 + w)).max(0.0)), w)
}

/// [`quat_distance`] in [`Real`].
#[inline]
#[must_use]
pub fn quat_distance_f64(q1: RealQuat, q2: RealQuat) -> Real {
    let d = q1.conjugate() * q2;
    let v = RealVec3::new(d.x, d.y, d.z).length();
    real::atan2(v, real::fabs(d.w))
}

/// Degrees to radians.
#[inline]
#[must_use]
pub fn deg_to_rad(d: f32) -> f32 {
    d * (core::f32::consts::PI / 180.0)
}

/// Radians to degrees.
#[inline]
#[must_use]
pub fn rad_to_deg(r: f32) -> f32 {
    r * (180.0 / core::f32::consts::PI)
}

/// `angle + 2πk` closest to `reference`.
#[must_use]
pub fn wrap_near(angle: Real, reference: Real) -> Real {
    let d = reference - angle;
    // The common case (within a turn or two) without libm's software `round`.
    if d.abs() <= 2.5 * TAU {
        let mut a = angle;
        while reference - a > PI {
            a += TAU;
        }
        while a - reference > PI {
            a -= TAU;
        }
        return a;
    }
    angle + TAU * real::round(d / TAU)
}

/// Euler angles of `m` in `order`, of the two equivalent solutions and all 2π shifts the
/// one closest to `reference` (radians).
#[must_use]
pub fn euler_near(order: EulerOrder, m: &RealMat3, reference: [Real; 3]) -> [Real; 3] {
    let a = order.from_mat3_f64(m);
    // The other solution: (a + π, π − b, c + π) for Tait–Bryan, (a + π, −b, c + π) proper.
    let b2 = if order.is_proper() { -a[1] } else { PI - a[1] };
    let candidates = [a, [a[0] + PI, b2, a[2] + PI]];
    let mut best = a;
    let mut best_cost = Real::INFINITY;
    for cand in candidates {
        let w = [0, 1, 2].map(|k| wrap_near(cand[k], reference[k]));
        let cost: Real = (0..3).map(|k| real::fabs(w[k] - reference[k])).sum();
        if cost < best_cost {
            best_cost = cost;
            best = w;
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    fn angles_f64(seed: &mut u64) -> [Real; 3] {
        let mut next = || {
            *seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((*seed >> 11) as Real / (1u64 << 53) as Real) * 2.0 - 1.0
        };
        [next() * consts::PI, next() * 1.5, next() * consts::PI]
    }

    #[test]
    fn parse_and_name_round_trip() {
        for o in EulerOrder::ALL {
            assert_eq!(EulerOrder::parse(o.name()), Some(o));
            assert_eq!(EulerOrder::parse(&o.name().to_lowercase()), Some(o));
        }
        assert_eq!(EulerOrder::parse("XXY"), None);
        assert_eq!(EulerOrder::parse("XY"), None);
    }

    #[test]
    fn xyz_is_rz_ry_rx() {
        let m = EulerOrder::XYZ.to_mat3_f64([0.3, -0.2, 1.1]);
        let want =
            RealMat3::from_rotation_z(1.1) * RealMat3::from_rotation_y(-0.2) * RealMat3::from_rotation_x(0.3);
        assert!(m.abs_diff_eq(want, 1e-15));
    }

    #[test]
    fn euler_matrix_round_trip_all_orders_f64() {
        let mut seed = 7;
        for o in EulerOrder::ALL {
            for _ in 0..2000 {
                let mut a = angles_f64(&mut seed);
                if o.is_proper() {
                    a[1] = a[1].abs() * 2.0; // (0, 3) within [0, π]
                }
                let m = o.to_mat3_f64(a);
                let back = o.from_mat3_f64(&m);
                let m2 = o.to_mat3_f64(back);
                assert!(m.abs_diff_eq(m2, 1e-12), "{o:?} {a:?} -> {back:?}");
                for (x, y) in a.iter().zip(back) {
                    assert!((x - y).abs() < 1e-9, "{o:?} {a:?} -> {back:?}");
                }
            }
        }
    }

    #[test]
    fn euler_gimbal_lock_all_orders() {
        for o in EulerOrder::ALL {
            let mids: &[Real] = if o.is_proper() {
                &[0.0, consts::PI]
            } else {
                &[consts::FRAC_PI_2, -consts::FRAC_PI_2]
            };
            for &b in mids {
                let m = o.to_mat3_f64([0.4, b, -0.7]);
                let back = o.from_mat3_f64(&m);
                assert!(
                    m.abs_diff_eq(o.to_mat3_f64(back), 1e-9),
                    "{o:?} b={b} -> {back:?}"
                );
                let mf = o.to_mat3([0.4, b as f32, -0.7]);
                let backf = o.from_mat3(&mf);
                assert!(mf.abs_diff_eq(o.to_mat3(backf), 1e-5), "{o:?} f32 b={b}");
            }
        }
    }

    #[test]
    fn euler_quat_agrees_with_matrix() {
        let mut seed = 11;
        for o in EulerOrder::ALL {
            for _ in 0..200 {
                let a = angles_f64(&mut seed).map(|x| x as f32);
                let q = o.to_quat(a);
                assert!(Mat3::from_quat(q).abs_diff_eq(o.to_mat3(a), 1e-5));
                let back = o.from_quat(q);
                assert!(o.to_quat(back).dot(q).abs() > 1.0 - 1e-6);
            }
        }
    }

    #[test]
    fn quat_distance_short_arc_and_symmetry() {
        let a = Quat::from_rotation_y(0.4);
        let b = Quat::from_rotation_y(1.0);
        assert!((quat_distance(a, b) - 0.3).abs() < 1e-6);
        assert!((quat_distance(a, -b) - 0.3).abs() < 1e-6);
        assert_eq!(quat_distance(b, b), 0.0);
        let far = Quat::from_rotation_x(3.0);
        assert!((quat_distance(Quat::IDENTITY, far) - 1.5).abs() < 1e-6);
    }

    #[test]
    fn euler_near_picks_the_continuous_solution() {
        let order = EulerOrder::XYZ;
        let want = [3.0, 0.2, -3.0];
        let m = order.to_mat3_f64(want);
        let got = euler_near(order, &m, [3.05, 0.25, -3.05]);
        for k in 0..3 {
            assert!((got[k] - want[k]).abs() < 1e-9, "{got:?}");
        }
        let shifted = euler_near(order, &m, [3.0 + TAU, 0.2, -3.0 - TAU]);
        assert!((shifted[0] - (3.0 + TAU)).abs() < 1e-9 && (shifted[2] + 3.0 + TAU).abs() < 1e-9);
    }

    #[test]
    fn angle_forms_read_the_angles_from_mat3_f64_gives() {
        let mut seed = 7u64;
        for order in EulerOrder::ALL {
            for _ in 0..200 {
                let mut a = angles_f64(&mut seed);
                if order.is_proper() {
                    a[1] = a[1].abs() + 0.05;
                }
                let m = order.to_mat3_f64(a);
                let want = order.from_mat3_f64(&m);
                let r = |e: Element| e.sign * m.col(e.col)[e.row];
                for (k, form) in order.angle_forms().iter().enumerate() {
                    let got = match *form {
                        AngleOf::Atan2(y, x) => real::atan2(r(y), r(x)),
                        AngleOf::Asin(e) => real::asin(r(e)),
                        AngleOf::Acos(e) => real::acos(r(e)),
                    };
                    assert!(
                        (got - want[k]).abs() < 1e-9,
                        "{} angle {k}: {got} vs {}",
                        order.name(),
                        want[k]
                    );
                }
            }
        }
    }

    #[test]
    fn fast_arctangents_stay_within_their_bound() {
        let mut worst = 0.0f64;
        for i in 1..2001 {
            let x = -1.0 + (i as Real) * 1e-3;
            worst = worst.max((acos_fast(x) - real::acos(x)).abs());
            worst = worst.max((acos_abs_fast(x) - real::acos(x.abs())).abs());
            for j in 0..64 {
                let t = (j as Real) * consts::TAU / 64.0;
                let (y, x2) = (real::sin(t) * (1.0 + x), real::cos(t) * (1.0 + x));
                let d = (atan2_fast(y, x2) - real::atan2(y, x2)).abs();
                worst = worst.max(d.min((d - consts::TAU).abs()));
            }
        }
        assert!(worst < 1e-7, "{worst:e}");
    }

    #[test]
    fn sincos_f32_stays_within_its_bound() {
        let mut worst = 0.0f64;
        for k in -2_000_000..=2_000_000 {
            let x = k as f32 * 5.0e-4;
            let (s, c) = sincos_f32(x);
            let (es, ec) = libm::sincos(f64::from(x));
            worst = worst
                .max((f64::from(s) - es).abs())
                .max((f64::from(c) - ec).abs());
        }
        for x in [1000.0f32, -1000.0, 999.99, 0.0, -0.0, f32::MIN_POSITIVE] {
            let (s, c) = sincos_f32(x);
            let (es, ec) = libm::sincos(f64::from(x));
            worst = worst
                .max((f64::from(s) - es).abs())
                .max((f64::from(c) - ec).abs());
        }
        assert!(worst <= 1.2e-7, "{worst:e}");
        assert!(sincos_f32(f32::NAN).0.is_nan() && sincos_f32(f32::INFINITY).1.is_nan());
        // Beyond 10⁵ within an ulp of `x`.
        for x in [1.000_01e5f32, -2.5e5, 3_141_592.8, -5.9e6] {
            let (s, c) = sincos_f32(x);
            let (es, ec) = libm::sincos(f64::from(x));
            let wide = (f64::from(s) - es).abs().max((f64::from(c) - ec).abs());
            let ulp = f64::from(f32::from_bits(x.abs().to_bits() + 1) - x.abs());
            assert!(wide <= ulp, "{x:e}: {wide:e} against an ulp of {ulp:e}");
        }
        // Past 6·10⁶ a sine and cosine of a unit circle, for every finite f32.
        for x in [6.1e6f32, -1.7e7, 1.0e9, 3.0e20, -1.0e30, f32::MAX, f32::MIN] {
            let (s, c) = sincos_f32(x);
            assert!((s * s + c * c - 1.0).abs() < 1e-6, "{x:e}: {s}, {c}");
        }
        assert!(sincos_f32(f32::NAN).0.is_nan() && sincos_f32(f32::NEG_INFINITY).1.is_nan());
    }

    /// Values around every quadrant boundary, the reductions' ends and what lies past them.
    fn sincos_probes() -> std::vec::Vec<f64> {
        let mut v: std::vec::Vec<f64> = (-4000..=4000).map(|k| f64::from(k) * 0.0123).collect();
        for q in -8..=8 {
            let edge = f64::from(q) * core::f64::consts::FRAC_PI_4;
            v.extend([edge, edge + 1e-7, edge - 1e-7]);
        }
        v.extend([
            0.0, -0.0, 5.0e4, -5.0e4, 5.000_1e4, 1.0e5, -1.0e5, 1.000_1e5, 2.0e6, -3.0e9, 1.0e16, 1.0e300,
        ]);
        v.extend([f64::NAN, f64::INFINITY, f64::NEG_INFINITY]);
        v
    }

    #[test]
    fn sincos_many_are_the_scalars_bit_for_bit() {
        let bits32 = |v: (f32, f32)| (v.0.to_bits(), v.1.to_bits());
        let bits64 = |v: (f64, f64)| (v.0.to_bits(), v.1.to_bits());
        let x64 = sincos_probes();
        #[allow(clippy::cast_possible_truncation)]
        let x32: std::vec::Vec<f32> = x64.iter().map(|&x| x as f32).collect();
        let (mut s32, mut c32) = (std::vec![0.0f32; x32.len()], std::vec![0.0f32; x32.len()]);
        sincos_f32_many(&x32, &mut s32, &mut c32);
        for (k, &x) in x32.iter().enumerate() {
            let (want, got) = (sincos_f32(x), (s32[k], c32[k]));
            let same = bits32(want) == bits32(got) || (want.0.is_nan() && got.0.is_nan() && got.1.is_nan());
            assert!(same, "f32 {x:e}: {want:?} against {got:?}");
        }
        let (mut s64, mut c64) = (std::vec![0.0f64; x64.len()], std::vec![0.0f64; x64.len()]);
        sincos_f64_many(&x64, &mut s64, &mut c64);
        for (k, &x) in x64.iter().enumerate() {
            let (want, got) = (sincos_f64(x), (s64[k], c64[k]));
            let same = bits64(want) == bits64(got) || (want.0.is_nan() && got.0.is_nan() && got.1.is_nan());
            assert!(same, "f64 {x:e}: {want:?} against {got:?}");
        }
        // Without the rare values, the one pass alone.
        let plain: std::vec::Vec<f64> = x64.iter().copied().filter(|x| x.abs() <= 5.0e4).collect();
        let n = plain.len();
        sincos_f64_many(&plain, &mut s64[..n], &mut c64[..n]);
        for (k, &x) in plain.iter().enumerate() {
            assert_eq!(bits64(sincos_f64(x)), bits64((s64[k], c64[k])), "{x:e}");
        }
    }
    #[test]
    fn sincos_f64_is_libms_within_an_ulp() {
        // A dense sweep of the range the fast path covers, the quadrant boundaries, and both
        // sides of where it hands over to libm.
        let mut worst = 0.0f64;
        let mut check = |x: f64| {
            let (s, c) = sincos_f64(x);
            let (es, ec) = libm::sincos(x);
            worst = worst.max((s - es).abs()).max((c - ec).abs());
        };
        for k in -1_000_000..=1_000_000 {
            check(f64::from(k) * 1.0e-1 + 0.012_345);
            check(f64::from(k) * 1.0e-6);
        }
        for q in -64..=64 {
            for d in [-1.0e-9, 0.0, 1.0e-9] {
                check(f64::from(q) * core::f64::consts::FRAC_PI_4 + d);
            }
        }
        for x in [
            5.0e4,
            -5.0e4,
            49_999.9,
            5.0e4 + 1.0,
            1.0e5,
            1.0e12,
            0.0,
            -0.0,
            f64::MIN_POSITIVE,
        ] {
            check(x);
        }
        assert!(worst <= 2.3e-16, "{worst:e}");
        assert_eq!(sincos_f64(0.0), (0.0, 1.0));
        assert!(sincos_f64(f64::NAN).0.is_nan() && sincos_f64(f64::INFINITY).1.is_nan());
    }

    #[test]
    fn sqrt_f32_is_correctly_rounded() {
        // f64's root rounded once to f32 is the correctly rounded f32 root (53 ≥ 2·24 + 2).
        let check = |x: f32| {
            let exact = libm::sqrt(f64::from(x)) as f32;
            assert_eq!(sqrt_f32(x).to_bits(), exact.to_bits(), "√{x:e}");
        };
        // Every f32 in [1, 4), subnormals, the extreme normals, every exponent at a few
        // mantissas.
        (1.0f32.to_bits()..4.0f32.to_bits())
            .step_by(7)
            .map(f32::from_bits)
            .for_each(check);
        for x in [f32::MIN_POSITIVE, f32::MAX, 1.0e-45, 1.17e-38, 3.0e-39] {
            check(x);
        }
        (1..1u32 << 23).step_by(4099).map(f32::from_bits).for_each(check);
        for e in 0..255u32 {
            for m in [0u32, 1, 0x2A_AAAA, 0x7F_FFFF] {
                check(f32::from_bits(e << 23 | m));
            }
        }
        assert_eq!(sqrt_f32(0.0).to_bits(), 0.0f32.to_bits());
        assert_eq!(sqrt_f32(-0.0).to_bits(), (-0.0f32).to_bits());
        assert_eq!(sqrt_f32(f32::INFINITY), f32::INFINITY);
        assert!(
            sqrt_f32(-1.0).is_nan() && sqrt_f32(f32::NAN).is_nan() && sqrt_f32(-f32::MIN_POSITIVE).is_nan()
        );
    }

    #[test]
    fn rotation_arc_is_exact_near_parallel() {
        // 1e-4 rad apart: inside glam's f32 "parallel" band (2ε of the dot product), well
        // outside f64's; either way the arc turns `from` onto `to`.
        let from = RealVec3::new(0.3, -0.8, 0.52).normalize();
        let axis = from.any_orthonormal_vector();
        for angle in [0.0, 1.0e-7, 1.0e-4, 0.3, 2.0] {
            let to = mat3_from_axis_angle(axis, angle) * from;
            let q = rotation_arc(from, to);
            let miss = (q * from - to).length();
            assert!(miss < precision(1.0e-15, 3.0e-7), "{angle}: {miss:e}");
            assert!((q.length() - 1.0).abs() < precision(1.0e-15, 2.0e-7));
        }
        // Opposite: a half turn.
        let q = rotation_arc(from, -from);
        assert!((q * from + from).length() < precision(1.0e-12, 1.0e-6));
    }

    #[test]
    fn round_f32_is_libms() {
        let check = |x: f32| {
            if x.is_nan() {
                assert!(round_f32(x).is_nan());
            } else {
                assert_eq!(round_f32(x).to_bits(), libm::roundf(x).to_bits(), "round({x:e})");
            }
        };
        // A sample of every sign and exponent, and the halves and their neighbours.
        (0..=u32::MAX).step_by(997).map(f32::from_bits).for_each(check);
        for k in -100_000..100_000 {
            let half = k as f32 + 0.5;
            for x in [
                half,
                f32::from_bits(half.to_bits() - 1),
                f32::from_bits(half.to_bits() + 1),
            ] {
                check(x);
            }
        }
        for x in [
            0.0,
            -0.0,
            0.5,
            -0.5,
            0.499_999_97,
            -0.499_999_97,
            8_388_607.5,
            -8_388_607.5,
        ] {
            check(x);
        }
        for x in [
            8_388_608.0,
            1.0e30,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::MIN_POSITIVE,
        ] {
            check(x);
        }
        assert!(round_f32(f32::NAN).is_nan());
    }

    #[test]
    fn asin_through_atan2_stays_within_f32s_resolution() {
        let mut worst = 0.0f64;
        for k in -100_000..=100_000 {
            let x = k as f32 * 1.0e-5;
            let a = libm::atan2f(x, super::sqrt_f32((1.0 - x) * (1.0 + x)));
            worst = worst.max((f64::from(a) - libm::asin(f64::from(x))).abs());
        }
        assert!(worst <= 2.5e-7, "{worst:e}");
        assert!(libm::atan2f(1.5, libm::sqrtf((1.0 - 1.5) * (1.0 + 1.5))).is_nan());
    }

    #[test]
    fn acos_through_atan2_stays_within_f32s_resolution() {
        let mut worst = 0.0f64;
        for k in -100_000..=100_000 {
            let x = k as f32 * 1.0e-5;
            let a = libm::atan2f(super::sqrt_f32((1.0 - x) * (1.0 + x)), x);
            worst = worst.max((f64::from(a) - libm::acos(f64::from(x))).abs());
        }
        // About an ulp of π in f32 (2.4e-7); 2.53e-7 measured.
        assert!(worst <= 2.6e-7, "{worst:e}");
        assert!(libm::atan2f(super::sqrt_f32((1.0 - 1.5) * (1.0 + 1.5)), 1.5).is_nan());
    }
}
