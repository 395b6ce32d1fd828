//! Forward kinematics, help note eq. (1)–(5), into caller-provided buffers: no allocation.
//!
//! For bone `i` with parent `p`, rest frame `C` (ASF `axis`, eq. 3) and channel rotation `M`
//! (the bone's rotation channels applied in `dof` order):
//!
//! * frame orientation `Fᵢ = Wₚ · C · M` — eq. (1) written with `ᵢR_asf = Cₚᵀ·C` (eq. 4)
//!   folded into `Wₚ = Fₚ · Cₚᵀ`;
//! * start `Tᵢ` = the parent's tip (plus `Wₚ·C·t` for translation channels), tip
//!   `Tᵢ + (L + l) · Fᵢ · Cᵀ·d` — eq. (2) with the local direction of eq. (5).
//!
//! The root: `W₀ = O · M₀` where `O` is the `:root orientation` (rotating the whole skeleton)
//! and `M₀` its rotation channels; position = `:root position` + translation channels.
//!
//! [`forward_kinematics`] works in f32 on file frames (the display and the f32 pose);
//! [`fk64`] in f64 on channel vectors in radians (what IK and the control loop use).

use crate::math::{real, Real, RealMat3, RealVec3, ToReal};
use crate::math::{sincos_f32, sincos_f32_many, Axis};
use crate::skeleton::{turn_columns_by, Bone, Dof, Skeleton, MAX_BONES};
use glam::{Mat3, Mat3A, Vec3, Vec3A};

/// Global state of every bone for one frame.
#[derive(Clone, Debug)]
pub struct Pose {
    /// Where each bone starts (its joint), file units. The root: its position.
    pub start: [Vec3A; MAX_BONES],
    /// Where each bone ends, file units. The root: its position.
    pub tip: [Vec3A; MAX_BONES],
    /// The orientation of each bone's local frame in global coordinates, `Fᵢ = ⁱ₀R`.
    pub frame: [Mat3A; MAX_BONES],
    /// The rotation each bone applies to global rest vectors, `Wᵢ = Fᵢ·Cᵢᵀ`.
    pub world: [Mat3A; MAX_BONES],
}

impl Default for Pose {
    fn default() -> Self {
        Pose::new()
    }
}

impl Pose {
    /// All zeros.
    #[must_use]
    pub const fn new() -> Pose {
        Pose {
            start: [Vec3A::ZERO; MAX_BONES],
            tip: [Vec3A::ZERO; MAX_BONES],
            frame: [Mat3A::IDENTITY; MAX_BONES],
            world: [Mat3A::IDENTITY; MAX_BONES],
        }
    }
}

/// The frame vector is shorter than the skeleton's channel count.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ShortFrame {
    /// Channels the skeleton needs.
    pub needed: usize,
    /// Channels given.
    pub given: usize,
}

impl core::fmt::Display for ShortFrame {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(
            f,
            "frame has {} channels, skeleton needs {}",
            self.given, self.needed
        )
    }
}

impl core::error::Error for ShortFrame {}

/// The rotation of a bone's channels, `M = R(last)·…·R(first)`, and its translation and
/// length channels.
#[must_use]
pub fn channel_transform(dofs: &[Dof], values: &[f32]) -> (Mat3, Vec3, f32) {
    let (mut m, mut offset, mut l) = (Mat3A::IDENTITY, [0.0; 3], 0.0);
    for (d, &v) in dofs.iter().zip(values).rev() {
        match d.rotation_axis() {
            Some(axis) => turn_columns_f32(&mut m, axis, v),
            None => d.set_offset(v, &mut offset, &mut l),
        }
    }
    (Mat3::from(m), Vec3::from_array(offset), l)
}

/// `m ← m·R_axis(a)` in f32, one factor of eq. (2) taken from the right: only the two columns
/// across the axis change (four vector products in glam's aligned columns). A zero angle leaves
/// `m` as it is.
#[inline]
fn turn_columns_f32(m: &mut Mat3A, axis: Axis, a: f32) {
    if a != 0.0 {
        let (s, c) = sincos_f32(a);
        turn_columns_f32_by(m, axis, s, c);
    }
}

/// [`turn_columns_f32`] with the angle's sine and cosine given.
#[inline]
fn turn_columns_f32_by(m: &mut Mat3A, axis: Axis, s: f32, c: f32) {
    // One arm per axis, as `turn_columns_by` has.
    let turn = |u: Vec3A, v: Vec3A| (c * u + s * v, c * v - s * u);
    match axis {
        Axis::X => (m.y_axis, m.z_axis) = turn(m.y_axis, m.z_axis),
        Axis::Y => (m.z_axis, m.x_axis) = turn(m.z_axis, m.x_axis),
        Axis::Z => (m.x_axis, m.y_axis) = turn(m.x_axis, m.y_axis),
    }
}

/// A bone's translation channels and its length channel from its channel values.
#[cold]
fn channel_offsets(dofs: &[Dof], values: &[f32]) -> (Vec3A, f32) {
    let (mut offset, mut l) = ([0.0; 3], 0.0);
    for (d, &v) in dofs.iter().zip(values) {
        d.set_offset(v, &mut offset, &mut l);
    }
    (Vec3A::from_array(offset), l)
}

/// `a·b`, `b` read element by element where it lies (a bone's `C`): each column of the
/// product is `a`'s columns weighted by one column of `b`.
#[inline(always)]
fn mul_by(a: &Mat3A, b: &Mat3) -> Mat3A {
    let column = |v: Vec3| a.x_axis * v.x + a.y_axis * v.y + a.z_axis * v.z;
    Mat3A::from_cols(column(b.x_axis), column(b.y_axis), column(b.z_axis))
}

/// `a·bᵀ` without forming `bᵀ`: column `j` of the product is `a`'s columns weighted by row `j`
/// of `b`.
#[inline(always)]
fn mul_by_transpose(a: &Mat3A, b: &Mat3) -> Mat3A {
    let column = |x: f32, y: f32, z: f32| a.x_axis * x + a.y_axis * y + a.z_axis * z;
    Mat3A::from_cols(
        column(b.x_axis.x, b.y_axis.x, b.z_axis.x),
        column(b.x_axis.y, b.y_axis.y, b.z_axis.y),
        column(b.x_axis.z, b.y_axis.z, b.z_axis.z),
    )
}

/// How many channels' sines and cosines a [`TrigWindow`] holds.
const TRIG_WINDOW: usize = 32;

/// The sines and cosines of a frame's channels, computed a window at a time by a branch-free
/// batch ([`sincos_f32_many`], [`real::sincos_many`]: four or two lanes at once) as the bones
/// ask for them in order. A channel the frame does not have counts as 0.
struct TrigWindow<T> {
    start: usize,
    end: usize,
    sin: [T; TRIG_WINDOW],
    cos: [T; TRIG_WINDOW],
    fill: fn(&[T], &mut [T], &mut [T]),
}

impl<T: Copy + From<u8>> TrigWindow<T> {
    fn new(fill: fn(&[T], &mut [T], &mut [T])) -> TrigWindow<T> {
        let zero = T::from(0);
        TrigWindow {
            start: 0,
            end: 0,
            sin: [zero; TRIG_WINDOW],
            cos: [zero; TRIG_WINDOW],
            fill,
        }
    }

    /// The sines and cosines of a bone's channels `range` (at most [`TRIG_WINDOW`] of them);
    /// the window moves to start at the bone when the bone's channels are not all in it.
    #[inline]
    fn bone(&mut self, channels: &[T], range: core::ops::Range<usize>) -> (&[T], &[T]) {
        if range.start < self.start || range.end > self.end {
            self.start = range.start;
            self.end = self.start + TRIG_WINDOW;
            let given = channels.get(self.start..).unwrap_or(&[]);
            let n = given.len().min(TRIG_WINDOW);
            (self.fill)(&given[..n], &mut self.sin[..n], &mut self.cos[..n]);
            // Channels the frame does not have count as 0.
            self.sin[n..].fill(T::from(0));
            self.cos[n..].fill(T::from(1));
        }
        let (from, to) = (range.start - self.start, range.end - self.start);
        (&self.sin[from..to], &self.cos[from..to])
    }
}

/// Computes every bone's start, tip and orientation for one frame vector (radians, file
/// units), eq. (1)–(5).
///
/// The channel rotations are taken into the frame from the right, `F = (Wₚ·C)·R(last)·…·R(first)`,
/// two columns at a time, rather than built into `M` and multiplied: per bone one product for
/// `Wₚ·C`, one for `W = F·Cᵀ` (neither where `C` is the identity) and a pair of column updates
/// per rotation channel.
///
/// # Errors
/// [`ShortFrame`] when `channels` is shorter than [`Skeleton::channel_count`].
pub fn forward_kinematics(skeleton: &Skeleton, channels: &[f32], pose: &mut Pose) -> Result<(), ShortFrame> {
    if channels.len() < skeleton.channel_count() {
        return Err(ShortFrame {
            needed: skeleton.channel_count(),
            given: channels.len(),
        });
    }
    let mut trig = TrigWindow::new(sincos_f32_many);
    for (i, bone) in skeleton.bones().iter().enumerate() {
        let parent = bone.parent().map(|p| (pose.world[p], pose.tip[p]));
        // The parent's axes, `Wₚ·C` (the root: the `:root orientation` `O`).
        let axes = match parent {
            Some((parent_world, _)) if bone.axis_is_identity() => parent_world,
            Some((parent_world, _)) => mul_by(&parent_world, &bone.axis_rotation()),
            None => Mat3A::from(bone.axis_rotation()),
        };
        let mut f = axes;
        let (mut turned, mut offsets) = (false, false);
        let (sin, cos) = trig.bone(channels, bone.channels());
        let values = &channels[bone.channels()];
        for ((d, &v), (&s, &c)) in bone.dofs().iter().zip(values).zip(sin.iter().zip(cos)).rev() {
            match d.rotation_axis() {
                Some(_) if v == 0.0 => {}
                Some(axis) => {
                    turn_columns_f32_by(&mut f, axis, s, c);
                    turned = true;
                }
                None => offsets = true,
            }
        }
        // Translation and length channels (the root's, as a rule) apart.
        let (t, l) = if offsets {
            channel_offsets(bone.dofs(), values)
        } else {
            (Vec3A::ZERO, 0.0)
        };
        let (world, start, tip) = match parent {
            None => {
                // The root is a point: it starts and ends at its position.
                let p = Vec3A::from(skeleton.root().position) + t;
                (f, p, p)
            }
            Some((parent_world, parent_tip)) => {
                let start = if t == Vec3A::ZERO {
                    parent_tip
                } else {
                    parent_tip + axes * t
                };
                // No rotation (no rotation DOFs, or all at zero): `W = Wₚ·C·Cᵀ = Wₚ`.
                let world = match (turned, bone.axis_is_identity()) {
                    (false, _) => parent_world,
                    (true, true) => f,
                    (true, false) => mul_by_transpose(&f, &bone.axis_rotation()),
                };
                let direction = Vec3A::from(bone.local_direction()) * (bone.length() + l);
                (world, start, start + f * direction)
            }
        };
        pose.frame[i] = f;
        pose.world[i] = world;
        pose.start[i] = start;
        pose.tip[i] = tip;
    }
    Ok(())
}

/// Global state of every bone, f64.
#[derive(Clone, Debug)]
pub struct Pose64 {
    /// Joint (start) positions.
    pub start: [RealVec3; MAX_BONES],
    /// Tip positions.
    pub tip: [RealVec3; MAX_BONES],
    /// Local frames in world coordinates, `Fᵢ = Wₚ·C·M`.
    pub frame: [RealMat3; MAX_BONES],
    /// World rotations of rest vectors, `Wᵢ = Fᵢ·Cᵀ`.
    pub world: [RealMat3; MAX_BONES],
}

impl Default for Pose64 {
    fn default() -> Self {
        Pose64 {
            start: [RealVec3::ZERO; MAX_BONES],
            tip: [RealVec3::ZERO; MAX_BONES],
            frame: [RealMat3::IDENTITY; MAX_BONES],
            world: [RealMat3::IDENTITY; MAX_BONES],
        }
    }
}

/// Forward kinematics in f64, eq. (1)–(5). Missing channels count as 0.
pub fn fk64(skeleton: &Skeleton, channels: &[Real], pose: &mut Pose64) {
    let mut trig = TrigWindow::new(real::sincos_many);
    for i in 0..skeleton.bones().len() {
        fk64_bone(skeleton, channels, pose, i, &mut trig);
    }
}

/// [`fk64`] for the listed bones only (ascending, each after its parent — e.g. from
/// [`ancestors`]); the other entries of `pose` are left as they were.
///
/// The sines and cosines are taken channel by channel: a chain's bones lie far apart in the
/// frame, and a window of them in lanes would compute many that no listed bone needs.
pub fn fk64_bones(skeleton: &Skeleton, channels: &[Real], pose: &mut Pose64, bones: &[usize]) {
    for &i in bones {
        let parent = skeleton.bones()[i]
            .parent()
            .map(|p| (&pose.world[p], pose.tip[p]));
        let stepped = step(skeleton, channels, i, parent, |k| real::sincos(channels[k]));
        store(pose, i, stepped);
    }
}

/// The bones from the root down to `bone` (ascending; bones are stored parents first).
#[must_use]
pub fn ancestors(skeleton: &Skeleton, bone: usize) -> heapless::Vec<usize, MAX_BONES> {
    let mut v = heapless::Vec::new();
    let mut b = Some(bone);
    while let Some(i) = b {
        let _ = v.push(i);
        b = skeleton.bones().get(i).and_then(Bone::parent);
    }
    v.reverse();
    v
}

/// One bone's pose in f64 from its parent's world rotation and tip (`None` for the root):
/// `(frame, world, start, tip)` as in [`Pose64`], eq. (1)–(5). The channel rotations are taken
/// into the frame from the right, as [`forward_kinematics`] does.
#[must_use]
pub fn fk64_step(
    skeleton: &Skeleton,
    channels: &[Real],
    i: usize,
    parent: Option<(&RealMat3, RealVec3)>,
) -> (RealMat3, RealMat3, RealVec3, RealVec3) {
    step(skeleton, channels, i, parent, |k| real::sincos(channels[k]))
}

/// [`fk64_step`] with each channel's `(sin, cos)` from `trig` (asked only for rotation channels
/// the frame has, at non-zero angles), inlined where [`fk64`] stores its results straight into
/// the pose.
#[inline(always)]
fn step(
    skeleton: &Skeleton,
    channels: &[Real],
    i: usize,
    parent: Option<(&RealMat3, RealVec3)>,
    mut trig: impl FnMut(usize) -> (Real, Real),
) -> (RealMat3, RealMat3, RealVec3, RealVec3) {
    let bone = &skeleton.bones()[i];
    let c = bone.axis_rotation_f64();
    let axes = match parent {
        None => c,
        Some((parent_world, _)) if bone.axis_is_identity() => *parent_world,
        Some((parent_world, _)) => *parent_world * c,
    };
    // One pass over the DOFs, last first: `F = axes·R(last)·…·R(first)` (eq. 2), the
    // translations and the length change apart. `moved`: a translation channel is not 0 (NaN
    // included), noted as it is read rather than by comparing `t` after the loop.
    let mut f = axes;
    let mut l = 0.0;
    let (mut turned, mut moved) = (false, false);
    let mut t = RealVec3::ZERO;
    for (d, k) in bone.dofs().iter().zip(bone.channels()).rev() {
        let v = channels.get(k).copied().unwrap_or(0.0);
        let axis = match d {
            Dof::Rx => Axis::X,
            Dof::Ry => Axis::Y,
            Dof::Rz => Axis::Z,
            Dof::Tx => {
                (t.x, moved) = (v, moved | (v != 0.0));
                continue;
            }
            Dof::Ty => {
                (t.y, moved) = (v, moved | (v != 0.0));
                continue;
            }
            Dof::Tz => {
                (t.z, moved) = (v, moved | (v != 0.0));
                continue;
            }
            Dof::L => {
                l = v;
                continue;
            }
        };
        if v != 0.0 {
            let (s, c) = trig(k);
            turn_columns_by(&mut f, axis, s, c);
            turned = true;
        }
    }
    match parent {
        None => {
            let p = skeleton.root().position.to_real() + t;
            (f, f, p, p)
        }
        Some((parent_world, parent_tip)) => {
            let start = if moved { parent_tip + axes * t } else { parent_tip };
            // No rotation (no rotation DOFs, or all at zero): `W = Wₚ·C·Cᵀ = Wₚ`.
            let world = match (turned, bone.axis_is_identity()) {
                (false, _) => *parent_world,
                (true, true) => f,
                (true, false) => f * c.transpose(),
            };
            let tip = start + world * (bone.direction_f64() * ((bone.length() as Real) + l));
            (f, world, start, tip)
        }
    }
}

/// Where bone `i` ends, as [`fk64_step`] has it, without its frame: its rotation channels
/// turn the bone's vector, `Cᵀ·d·(L + l)` (eq. 5), first channel first, instead of turning a
/// matrix, and the parent's axes `Wₚ·C` take it to the world (eq. 2).
#[must_use]
pub fn fk64_tip(
    skeleton: &Skeleton,
    channels: &[Real],
    i: usize,
    parent: Option<(&RealMat3, RealVec3)>,
) -> RealVec3 {
    let bone = &skeleton.bones()[i];
    let c = bone.axis_rotation_f64();
    let (t, l) = translation_and_stretch(bone, channels);
    let dir = bone.direction_f64();
    let mut v = RealVec3::new(c.x_axis.dot(dir), c.y_axis.dot(dir), c.z_axis.dot(dir))
        * ((bone.length() as Real) + l);
    let first = bone.first_channel();
    for (k, d) in bone.dofs().iter().enumerate() {
        let a = channels.get(first + k).copied().unwrap_or(0.0);
        let Some(axis) = d.rotation_axis() else {
            continue;
        };
        if a != 0.0 {
            let (s, c) = real::sincos(a);
            turn_vector(&mut v, axis, s, c);
        }
    }
    let (start, axes) = match parent {
        None => (skeleton.root().position.to_real() + t, c),
        Some((parent_world, parent_tip)) => {
            let axes = if bone.axis_is_identity() {
                *parent_world
            } else {
                *parent_world * c
            };
            (parent_tip + axes * t, axes)
        }
    };
    start + axes * v
}

/// `v ← R_axis(a)·v` given `sin a` and `cos a`: the two components across the axis turn.
#[inline]
fn turn_vector(v: &mut RealVec3, axis: Axis, s: Real, c: Real) {
    // One arm per axis (the pairs of `Axis::across`), its components known.
    let turn = |x: Real, y: Real| (c * x - s * y, s * x + c * y);
    match axis {
        Axis::X => (v.y, v.z) = turn(v.y, v.z),
        Axis::Y => (v.z, v.x) = turn(v.z, v.x),
        Axis::Z => (v.x, v.y) = turn(v.x, v.y),
    }
}

/// A bone's translation channels and its length channel (missing channels count as 0).
#[inline]
fn translation_and_stretch(bone: &Bone, channels: &[Real]) -> (RealVec3, Real) {
    let (mut offset, mut l) = ([0.0; 3], 0.0);
    for (d, k) in bone.dofs().iter().zip(bone.channels()) {
        d.set_offset(channels.get(k).copied().unwrap_or(0.0), &mut offset, &mut l);
    }
    (RealVec3::from_array(offset), l)
}

/// Where bone `i` starts, as [`fk64_step`] has it (its parent's tip, moved by its translation
/// channels in the parent's frame; the root's position plus them), without its rotation.
#[must_use]
pub fn fk64_start(
    skeleton: &Skeleton,
    channels: &[Real],
    i: usize,
    parent: Option<(&RealMat3, RealVec3)>,
) -> RealVec3 {
    let bone = &skeleton.bones()[i];
    let (t, _) = translation_and_stretch(bone, channels);
    match parent {
        None => skeleton.root().position.to_real() + t,
        Some((parent_world, parent_tip)) => parent_tip + (*parent_world * bone.axis_rotation_f64()) * t,
    }
}

/// [`fk64_step`] without the local frame: `(world, start, tip)`. A bone that does not rotate
/// (no rotation DOFs, or all at zero) and does not translate costs a vector product.
#[must_use]
pub fn fk64_world_step(
    skeleton: &Skeleton,
    channels: &[Real],
    i: usize,
    parent: Option<(&RealMat3, RealVec3)>,
) -> (RealMat3, RealVec3, RealVec3) {
    let bone = &skeleton.bones()[i];
    let value = |c: usize| channels.get(c).copied().unwrap_or(0.0);
    let still = bone.channels().all(|c| value(c) == 0.0);
    let Some((parent_world, parent_tip)) = parent else {
        if still {
            // The root at rest: `W = C`, at the root's position.
            let p = skeleton.root().position.to_real();
            return (bone.axis_rotation_f64(), p, p);
        }
        let (_, world, start, tip) = fk64_step(skeleton, channels, i, None);
        return (world, start, tip);
    };
    if still {
        let tip = parent_tip + *parent_world * (bone.direction_f64() * (bone.length() as Real));
        return (*parent_world, parent_tip, tip);
    }
    let (_, world, start, tip) = fk64_step(skeleton, channels, i, Some((parent_world, parent_tip)));
    (world, start, tip)
}

/// One bone of [`fk64`], its parent already computed.
fn fk64_bone(
    skeleton: &Skeleton,
    channels: &[Real],
    pose: &mut Pose64,
    i: usize,
    trig: &mut TrigWindow<Real>,
) {
    let bone = &skeleton.bones()[i];
    let parent = bone.parent().map(|p| (&pose.world[p], pose.tip[p]));
    let (sin, cos) = trig.bone(channels, bone.channels());
    let first = bone.first_channel();
    let stepped = step(skeleton, channels, i, parent, |k| {
        (sin[k - first], cos[k - first])
    });
    store(pose, i, stepped);
}

/// Bone `i`'s `(frame, world, start, tip)` into the pose.
#[inline(always)]
fn store(pose: &mut Pose64, i: usize, (frame, world, start, tip): (RealMat3, RealMat3, RealVec3, RealVec3)) {
    pose.frame[i] = frame;
    pose.world[i] = world;
    pose.start[i] = start;
    pose.tip[i] = tip;
}
