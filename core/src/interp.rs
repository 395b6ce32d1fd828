//! Per-frame motion maths for editing and playback, `no_std`, in f64.
//!
//! Frames here are *file frames*: a skeleton's channels as files hold them (rotations in
//! degrees, translations in file units), the representation of [`crate::skeleton`]'s channel
//! layout that `motion::Motion` stores. Implements the facing angle (help note eq. 6–7),
//! SLERP on the shorter arc (eq. 12), ease-in/ease-out weights (eq. 13) and frame
//! interpolation; Euler angles written back are chosen continuous with a reference so that
//! edited channels never jump by 360°.

use crate::math::consts::{FRAC_PI_2, PI};
use crate::math::{euler_near, wrap_near, Axis, EulerOrder};
use crate::math::{real, Real, RealMat3, RealQuat, RealVec3, ToReal};
use crate::skeleton::{dof_rotation, Bone, Dof, Skeleton};

/// The rotation of a bone's rotation channels, `M` (radians from file degrees).
#[must_use]
pub fn channel_rotation(bone: &Bone, frame: &[Real]) -> RealMat3 {
    dof_rotation(bone.dofs(), frame[bone.channels()].iter().map(|v| v.to_radians()))
}

/// The root's global rotation `W₀ = O·M₀`.
#[must_use]
pub fn root_rotation(skeleton: &Skeleton, frame: &[Real]) -> RealMat3 {
    let root = skeleton.root();
    root.axis_order.to_mat3_f64(root.orientation.map(Real::from))
        * channel_rotation(&skeleton.bones()[0], frame)
}

/// The root's global position: `:root position` + translation channels.
#[must_use]
pub fn root_position(skeleton: &Skeleton, frame: &[Real]) -> RealVec3 {
    let mut p = skeleton.root().position.to_real();
    let bone = &skeleton.bones()[0];
    for (d, c) in bone.dofs().iter().zip(bone.channels()) {
        match d {
            Dof::Tx => p.x += frame[c],
            Dof::Ty => p.y += frame[c],
            Dof::Tz => p.z += frame[c],
            _ => {}
        }
    }
    p
}

/// Facing angle of a root rotation, eq. (7): the local z axis projected on the x–z plane,
/// measured from global z towards x: `atan2(R₀₂, R₂₂)`.
#[must_use]
pub fn facing_angle(root: &RealMat3) -> Real {
    let z = root.col(2);
    real::atan2(z.x, z.z)
}

/// Writes the root's channels so that its global rotation is `rotation` and its position
/// `position`. Rotation angles are chosen near the frame's current ones. Channels the root
/// lacks are left out (a root without TY keeps its height).
pub fn set_root(skeleton: &Skeleton, frame: &mut [Real], rotation: &RealMat3, position: RealVec3) {
    let root = skeleton.root();
    let o = root.axis_order.to_mat3_f64(root.orientation.map(Real::from));
    let m = o.transpose() * *rotation;
    let bone = &skeleton.bones()[0];
    set_channel_rotation(bone, frame, &m);
    let offset = root.position.to_real();
    for (d, c) in bone.dofs().iter().zip(bone.channels()) {
        match d {
            Dof::Tx => frame[c] = position.x - offset.x,
            Dof::Ty => frame[c] = position.y - offset.y,
            Dof::Tz => frame[c] = position.z - offset.z,
            _ => {}
        }
    }
}

/// Writes a bone's rotation channels for the rotation `m`, angles near the current values.
/// Exact for three rotation channels; with fewer, the closest rotation about those axes in the
/// sense of the Euler decomposition (exact when `m` is reachable with them).
pub fn set_channel_rotation(bone: &Bone, frame: &mut [Real], m: &RealMat3) {
    let mut axes = [Axis::X; 3];
    let mut slots = [0usize; 3];
    let mut n = 0;
    for (d, c) in bone.dofs().iter().zip(bone.channels()) {
        if let Some(a) = d.rotation_axis() {
            axes[n] = a;
            slots[n] = c;
            n += 1;
        }
    }
    match n {
        0 => {}
        1 => {
            let q = RealQuat::from_mat3(m);
            let axis = axes[0].unit().to_real();
            let angle = 2.0 * real::atan2(q.xyz().dot(axis), q.w);
            frame[slots[0]] = wrap_near(angle, frame[slots[0]].to_radians()).to_degrees();
        }
        2 => {
            // Complete the two axes to a Tait–Bryan order with the third axis applied last
            // and drop that third angle.
            let third = [Axis::X, Axis::Y, Axis::Z]
                .into_iter()
                .find(|a| *a != axes[0] && *a != axes[1])
                .unwrap_or(Axis::Z);
            let order = EulerOrder::from_axes([axes[0], axes[1], third]).unwrap_or(EulerOrder::XYZ);
            let reference = [frame[slots[0]].to_radians(), frame[slots[1]].to_radians(), 0.0];
            let a = euler_near(order, m, reference);
            frame[slots[0]] = a[0].to_degrees();
            frame[slots[1]] = a[1].to_degrees();
        }
        _ => {
            let order = EulerOrder::from_axes(axes).unwrap_or(EulerOrder::XYZ);
            let reference = [slots[0], slots[1], slots[2]].map(|c| frame[c].to_radians());
            let a = euler_near(order, m, reference);
            for k in 0..3 {
                frame[slots[k]] = a[k].to_degrees();
            }
        }
    }
}

/// Spherical linear interpolation on the shorter arc, eq. (12): `q₂` is negated when
/// `q₁·q₂ < 0`. Falls back to normalised linear interpolation when the arc is tiny.
#[must_use]
pub fn slerp(q1: RealQuat, q2: RealQuat, u: Real) -> RealQuat {
    let mut q2 = q2;
    let mut cos = q1.dot(q2);
    if cos < 0.0 {
        q2 = -q2;
        cos = -cos;
    }
    if cos > 1.0 - 1e-12 {
        return (q1 * (1.0 - u) + q2 * u).normalize();
    }
    let theta = real::acos(cos.min(1.0));
    let s = real::sin(theta);
    (q1 * (real::sin((1.0 - u) * theta) / s) + q2 * (real::sin(u * theta) / s)).normalize()
}

/// Ease-in/ease-out weight of frame `f` of an `n`-frame window, eq. (13), from 0 to 1:
/// `½·sin(f/(n−1)·π − π/2) + ½`.
#[must_use]
pub fn ease_weight(f: usize, n: usize) -> Real {
    if n <= 1 {
        return 1.0;
    }
    0.5 * real::sin(f as Real / (n - 1) as Real * PI - FRAC_PI_2) + 0.5
}

/// Interpolates two file frames at `u ∈ [0, 1]` into `out`: root position and translation
/// channels linearly, the root and every 3-DOF joint by SLERP (eq. 12) written back in the
/// bone's own Euler order, 1- and 2-DOF joints angle by angle on the shorter way round.
/// `interpolate_frames(s, a, a, u, out)` gives `a` exactly.
///
/// # Panics
/// When a slice is shorter than the skeleton's channel count.
pub fn interpolate_frames(skeleton: &Skeleton, a: &[Real], b: &[Real], u: Real, out: &mut [Real]) {
    let n = skeleton.channel_count();
    for c in 0..n {
        out[c] = a[c] + (b[c] - a[c]) * u;
    }
    for bone in skeleton.bones() {
        let rot: usize = bone.dofs().iter().filter(|d| d.is_rotation()).count();
        if rot == 3 {
            let qa = RealQuat::from_mat3(&channel_rotation(bone, a));
            let qb = RealQuat::from_mat3(&channel_rotation(bone, b));
            let q = slerp(qa, qb, u);
            // `out` holds the linear interpolation of the angles: the reference for continuity.
            set_channel_rotation(bone, out, &RealMat3::from_quat(q));
            if a[bone.channels()] == b[bone.channels()] {
                out[bone.channels()].copy_from_slice(&a[bone.channels()]);
            }
        } else {
            for (d, c) in bone.dofs().iter().zip(bone.channels()) {
                if d.is_rotation() {
                    let diff = wrap_near(b[c].to_radians(), a[c].to_radians()) - a[c].to_radians();
                    out[c] = a[c] + diff.to_degrees() * u;
                }
            }
        }
    }
}

/// The geodesic angle (radians) between two rotations: `2·‖log(q₁⁻¹q₂)‖` (eq. 27–28).
#[must_use]
pub fn rotation_angle(a: &RealMat3, b: &RealMat3) -> Real {
    2.0 * crate::math::quat_distance_f64(RealQuat::from_mat3(a), RealQuat::from_mat3(b))
}

/// The largest geodesic rotation change between two frames over all joints: the root's
/// global rotation and every bone's channel rotation (radians).
#[must_use]
pub fn largest_joint_change(skeleton: &Skeleton, a: &[Real], b: &[Real]) -> Real {
    let mut worst = rotation_angle(&root_rotation(skeleton, a), &root_rotation(skeleton, b));
    for bone in &skeleton.bones()[1..] {
        worst = worst.max(rotation_angle(
            &channel_rotation(bone, a),
            &channel_rotation(bone, b),
        ));
    }
    worst
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slerp_takes_the_short_arc() {
        let a = RealQuat::from_rotation_y(0.1);
        let b = -RealQuat::from_rotation_y(0.5); // same rotation as +, far in 4-D
        let mid = slerp(a, b, 0.5);
        let angle = 2.0 * crate::math::quat_distance_f64(mid, RealQuat::from_rotation_y(0.3));
        assert!(angle < 1e-12, "{angle}");
        assert_eq!(slerp(a, a, 0.37), a);
    }

    #[test]
    fn ease_weights_run_from_zero_to_one_symmetrically() {
        assert!(ease_weight(0, 10).abs() < 1e-15);
        assert!((ease_weight(9, 10) - 1.0).abs() < 1e-15);
        for f in 0..10 {
            assert!((ease_weight(f, 10) + ease_weight(9 - f, 10) - 1.0).abs() < 1e-12);
        }
    }
}
