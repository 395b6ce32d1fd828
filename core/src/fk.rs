//! Forward kinematics, help note eq. (1)–(5), into caller-provided buffers: no allocation.
//!
//! For bone `i` with parent `p`, rest frame `C` (ASF `axis`, eq. 3), `K = Cₚᵀ·C` (eq. 4's
//! `ⁱR_asf`, kept by the skeleton) and channel rotation `M` (the bone's rotation channels
//! applied in `dof` order):
//!
//! * frame orientation `Fᵢ = Fₚ · K · M` — eq. (1), one product per bone, none where the bone's
//!   `axis` is its parent's (`K = I`);
//! * start `Tᵢ` = the parent's tip (plus `Fₚ·K·t` for translation channels), tip
//!   `Tᵢ + (L + l) · Fᵢ · Cᵀ·d` — eq. (2) with the local direction of eq. (5).
//!
//! The root: `F₀ = O · M₀` where `O` is the `:root orientation` (rotating the whole skeleton)
//! and `M₀` its rotation channels; position = `:root position` + translation channels. Under
//! the root `K = C`: the root's frame is its world rotation.
//!
//! A pose keeps one rotation per bone, its frame; the rotation a bone applies to global rest
//! vectors, `Wᵢ = Fᵢ·Cᵢᵀ`, is [`Pose64::world`] (the root's: `F₀`).
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
        }
    }

    /// The rotation bone `i` applies to global rest vectors, `Wᵢ = Fᵢ·Cᵢᵀ` (the root's:
    /// `F₀`).
    #[must_use]
    pub fn world(&self, skeleton: &Skeleton, i: usize) -> Mat3A {
        let bone = &skeleton.bones()[i];
        if bone.parent().is_none() || bone.axis_is_identity() {
            self.frame[i]
        } else {
            mul_by_transpose(&self.frame[i], &bone.axis_rotation())
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

/// How many channels' sines and cosines a [`TrigWindow`] holds: a CMU skeleton's 62 in one
/// batch.
const TRIG_WINDOW: usize = 64;

/// Indexes within a [`TrigWindow`] (a power of two less one): no bounds check.
const WINDOW_MASK: usize = TRIG_WINDOW - 1;

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

    /// Where the `len` channels from `first` start in the window (`len` at most
    /// [`MAX_BONE_DOFS`](crate::skeleton::MAX_BONE_DOFS); bones asked for in the order of
    /// their channels): channel `first + j` is at `(at + j) & WINDOW_MASK`. The window moves
    /// to start at `first` when they are not all in it.
    #[inline(always)]
    fn bone(&mut self, channels: &[T], first: usize, len: usize) -> usize {
        if first + len > self.end || first < self.start {
            self.move_to(channels, first);
        }
        first - self.start
    }

    /// The sine and cosine at `at` (from [`TrigWindow::bone`]), masked into the window.
    #[inline(always)]
    fn at(&self, at: usize) -> (T, T) {
        (self.sin[at & WINDOW_MASK], self.cos[at & WINDOW_MASK])
    }

    /// Fills the window from channel `first` on.
    #[inline(never)]
    fn move_to(&mut self, channels: &[T], first: usize) {
        self.start = first;
        self.end = first + TRIG_WINDOW;
        let given = channels.get(first..).unwrap_or(&[]);
        let n = given.len().min(TRIG_WINDOW);
        (self.fill)(&given[..n], &mut self.sin[..n], &mut self.cos[..n]);
        // Channels the frame does not have count as 0.
        self.sin[n..].fill(T::from(0));
        self.cos[n..].fill(T::from(1));
    }
}

/// Computes every bone's start, tip and orientation for one frame vector (radians, file
/// units), eq. (1)–(5).
///
/// The channel rotations are taken into the frame from the right, `F = (Fₚ·K)·R(last)·…·R(first)`,
/// two columns at a time, rather than built into `M` and multiplied: per bone one product for
/// `Fₚ·K` (none where `K` is the identity) and a pair of column updates per rotation channel.
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
        let parent = bone.parent().map(|p| (pose.frame[p], pose.tip[p]));
        // The bone's axes, `Fₚ·K` (the root: the `:root orientation` `O`).
        let axes = match parent {
            Some((parent_frame, _)) if bone.axis_in_parent_is_identity() => parent_frame,
            Some((parent_frame, _)) => mul_by(&parent_frame, &bone.axis_in_parent()),
            None => Mat3A::from(bone.axis_rotation()),
        };
        // Last channel first. A channel at 0 turns by (sin, cos) = (0, 1), which leaves the
        // columns as they were (no test for it: the four-lane turn costs less than one).
        let dofs = bone.dofs();
        let first = bone.first_channel();
        let at = trig.bone(channels, first, dofs.len());
        let mut f = axes;
        let mut offsets = false;
        // The commonest ASF bones (`dof rx ry rz`, `dof rx rz`) in straight line, without a
        // dispatch a channel; the rest channel by channel.
        if dofs == [Dof::Rx, Dof::Ry, Dof::Rz] {
            let ((sx, cx), (sy, cy), (sz, cz)) = (trig.at(at), trig.at(at + 1), trig.at(at + 2));
            turn_columns_f32_by(&mut f, Axis::Z, sz, cz);
            turn_columns_f32_by(&mut f, Axis::Y, sy, cy);
            turn_columns_f32_by(&mut f, Axis::X, sx, cx);
        } else if dofs == [Dof::Rx, Dof::Rz] {
            let ((sx, cx), (sz, cz)) = (trig.at(at), trig.at(at + 1));
            turn_columns_f32_by(&mut f, Axis::Z, sz, cz);
            turn_columns_f32_by(&mut f, Axis::X, sx, cx);
        } else {
            for (j, dof) in dofs.iter().enumerate().rev() {
                let (s, c) = trig.at(at + j);
                match dof {
                    Dof::Rx => turn_columns_f32_by(&mut f, Axis::X, s, c),
                    Dof::Ry => turn_columns_f32_by(&mut f, Axis::Y, s, c),
                    Dof::Rz => turn_columns_f32_by(&mut f, Axis::Z, s, c),
                    Dof::Tx | Dof::Ty | Dof::Tz | Dof::L => offsets = true,
                }
            }
        }
        // Translation and length channels (the root's, as a rule) apart.
        let (t, l) = if offsets {
            channel_offsets(dofs, &channels[first..][..dofs.len()])
        } else {
            (Vec3A::ZERO, 0.0)
        };
        let (start, tip) = match parent {
            None => {
                // The root is a point: it starts and ends at its position.
                let p = Vec3A::from(skeleton.root().position) + t;
                (p, p)
            }
            Some((_, parent_tip)) => {
                let start = if offsets {
                    parent_tip + axes * t
                } else {
                    parent_tip
                };
                let direction = Vec3A::from(bone.local_direction()) * (bone.length() + l);
                (start, start + f * direction)
            }
        };
        pose.frame[i] = f;
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
    /// Local frames in world coordinates, `Fᵢ = Fₚ·K·M`.
    pub frame: [RealMat3; MAX_BONES],
}

impl Default for Pose64 {
    fn default() -> Self {
        Pose64 {
            start: [RealVec3::ZERO; MAX_BONES],
            tip: [RealVec3::ZERO; MAX_BONES],
            frame: [RealMat3::IDENTITY; MAX_BONES],
        }
    }
}

impl Pose64 {
    /// The rotation bone `i` applies to global rest vectors, `Wᵢ = Fᵢ·Cᵢᵀ` (the root's:
    /// `F₀`).
    #[must_use]
    pub fn world(&self, skeleton: &Skeleton, i: usize) -> RealMat3 {
        world_of(skeleton, i, &self.frame[i])
    }

    /// Bone `i`'s parent's frame and tip, as the step functions take them (`None` for the
    /// root).
    #[must_use]
    pub fn parent_of(&self, skeleton: &Skeleton, i: usize) -> Option<(&RealMat3, RealVec3)> {
        skeleton.bones()[i]
            .parent()
            .map(|p| (&self.frame[p], self.tip[p]))
    }

    /// Bone `i`'s axes at rest in the world, `Fₚ·K = Wₚ·C` (the root: `C`): where its rotation
    /// channels turn from.
    #[must_use]
    pub fn axes(&self, skeleton: &Skeleton, i: usize) -> RealMat3 {
        axes_of(skeleton, i, self.parent_of(skeleton, i).map(|(f, _)| f))
    }
}

/// `Wᵢ = Fᵢ·Cᵢᵀ` of bone `i` from its frame (the root's: its frame).
#[must_use]
pub fn world_of(skeleton: &Skeleton, i: usize, frame: &RealMat3) -> RealMat3 {
    let bone = &skeleton.bones()[i];
    if bone.parent().is_none() || bone.axis_is_identity() {
        *frame
    } else {
        *frame * bone.axis_rotation_f64().transpose()
    }
}

/// Bone `i`'s axes from its parent's frame, `Fₚ·K` (the root: `K = C`).
#[inline(always)]
fn axes_of(skeleton: &Skeleton, i: usize, parent_frame: Option<&RealMat3>) -> RealMat3 {
    let bone = &skeleton.bones()[i];
    match parent_frame {
        None => bone.axis_in_parent_f64(),
        Some(f) if bone.axis_in_parent_is_identity() => *f,
        Some(f) => *f * bone.axis_in_parent_f64(),
    }
}

/// Forward kinematics in f64, eq. (1)–(5). Missing channels count as 0.
///
/// The same bone by bone as [`fk64_step`], with the frame's sines and cosines taken in lanes.
pub fn fk64(skeleton: &Skeleton, channels: &[Real], pose: &mut Pose64) {
    let mut trig = TrigWindow::new(real::sincos_many);
    for (i, bone) in skeleton.bones().iter().enumerate() {
        let parent = bone.parent().map(|p| (pose.frame[p], pose.tip[p]));
        // `axes_of`, written out: through it (a borrow of the copied parent frame) this loop
        // took 2.7 % more instructions.
        let axes = match parent {
            None => bone.axis_in_parent_f64(),
            Some((f, _)) if bone.axis_in_parent_is_identity() => f,
            Some((f, _)) => f * bone.axis_in_parent_f64(),
        };
        let dofs = bone.dofs();
        let first = bone.first_channel();
        let at = trig.bone(channels, first, dofs.len());
        // Last channel first, as in `step`; a channel at 0 is left out as there.
        let mut f = axes;
        let mut offsets = false;
        for (j, dof) in dofs.iter().enumerate().rev() {
            let (s, c) = trig.at(at + j);
            let axis = match dof {
                Dof::Rx => Axis::X,
                Dof::Ry => Axis::Y,
                Dof::Rz => Axis::Z,
                Dof::Tx | Dof::Ty | Dof::Tz | Dof::L => {
                    offsets = true;
                    continue;
                }
            };
            // `sin a` is 0 only for `a = ±0` (no multiple of π is one in floating point).
            if s != 0.0 {
                turn_columns_by(&mut f, axis, s, c);
            }
        }
        let (t, l) = if offsets {
            translation_and_stretch(bone, channels)
        } else {
            (RealVec3::ZERO, 0.0)
        };
        let (start, tip) = match parent {
            None => {
                let p = skeleton.root().position.to_real() + t;
                (p, p)
            }
            Some((_, parent_tip)) => {
                let start = if t == RealVec3::ZERO {
                    parent_tip
                } else {
                    parent_tip + axes * t
                };
                let v = if offsets {
                    bone.vector_f64(l)
                } else {
                    bone.rest_vector_f64()
                };
                let tip = start + f * v;
                (start, tip)
            }
        };
        store(pose, i, (f, start, tip));
    }
}

/// [`fk64`] for the listed bones only (ascending, each after its parent — e.g. from
/// [`ancestors`]); the other entries of `pose` are left as they were.
///
/// The sines and cosines are taken channel by channel: a chain's bones lie far apart in the
/// frame, and a window of them in lanes would compute many that no listed bone needs.
pub fn fk64_bones(skeleton: &Skeleton, channels: &[Real], pose: &mut Pose64, bones: &[usize]) {
    for &i in bones {
        let parent = pose.parent_of(skeleton, i);
        let stepped = step(skeleton, channels, i, parent);
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

/// One bone's pose in f64 from its parent's frame and tip (`None` for the root):
/// `(frame, start, tip)` as in [`Pose64`], eq. (1)–(5). The channel rotations are taken into
/// the frame from the right, as [`forward_kinematics`] does. A bone at rest (every channel 0)
/// whose axis is its parent's costs a vector product: its frame is its parent's.
#[must_use]
pub fn fk64_step(
    skeleton: &Skeleton,
    channels: &[Real],
    i: usize,
    parent: Option<(&RealMat3, RealVec3)>,
) -> (RealMat3, RealVec3, RealVec3) {
    let bone = &skeleton.bones()[i];
    if let Some((parent_frame, parent_tip)) = parent {
        let still = || bone.channels().all(|k| channels.get(k).is_none_or(|&v| v == 0.0));
        if bone.axis_in_parent_is_identity() && still() {
            let tip = parent_tip + *parent_frame * bone.rest_vector_f64();
            return (*parent_frame, parent_tip, tip);
        }
    }
    moving_step(skeleton, channels, i, parent)
}

/// [`fk64_step`] of a bone that turns or moves, apart from its test for one that does not.
#[inline(never)]
fn moving_step(
    skeleton: &Skeleton,
    channels: &[Real],
    i: usize,
    parent: Option<(&RealMat3, RealVec3)>,
) -> (RealMat3, RealVec3, RealVec3) {
    step(skeleton, channels, i, parent)
}

/// [`fk64_step`]'s pose of one bone, each rotation channel's sine and cosine taken as it is
/// turned (only for channels the frame has, at non-zero angles); inlined where [`fk64_bones`]
/// stores its results straight into the pose.
#[inline(always)]
fn step(
    skeleton: &Skeleton,
    channels: &[Real],
    i: usize,
    parent: Option<(&RealMat3, RealVec3)>,
) -> (RealMat3, RealVec3, RealVec3) {
    let bone = &skeleton.bones()[i];
    let axes = axes_of(skeleton, i, parent.map(|(f, _)| f));
    // One pass over the DOFs, last first: `F = axes·R(last)·…·R(first)` (eq. 2), the
    // translations and the length change apart. `moved`: a translation channel is not 0 (NaN
    // included), noted as it is read rather than by comparing `t` after the loop.
    let mut f = axes;
    let mut l = 0.0;
    let mut moved = false;
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
            let (s, c) = real::sincos(v);
            turn_columns_by(&mut f, axis, s, c);
        }
    }
    match parent {
        None => {
            let p = skeleton.root().position.to_real() + t;
            (f, p, p)
        }
        Some((_, parent_tip)) => {
            let start = if moved { parent_tip + axes * t } else { parent_tip };
            let tip = start + f * bone.vector_f64(l);
            (f, start, tip)
        }
    }
}

/// Where bone `i` ends, as [`fk64_step`] has it, without its frame: its rotation channels
/// turn the bone's vector, `Cᵀ·d·(L + l)` (eq. 5), first channel first, instead of turning a
/// matrix, and the bone's axes `Fₚ·K` take it to the world (eq. 2).
#[must_use]
pub fn fk64_tip(
    skeleton: &Skeleton,
    channels: &[Real],
    i: usize,
    parent: Option<(&RealMat3, RealVec3)>,
) -> RealVec3 {
    let bone = &skeleton.bones()[i];
    let (t, l) = translation_and_stretch(bone, channels);
    let mut v = bone.vector_f64(l);
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
    let axes = axes_of(skeleton, i, parent.map(|(f, _)| f));
    let start = match parent {
        None => skeleton.root().position.to_real() + t,
        Some((_, parent_tip)) => parent_tip + axes * t,
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
/// channels along its axes `Fₚ·K`; the root's position plus them), without its rotation.
#[must_use]
pub fn fk64_start(
    skeleton: &Skeleton,
    channels: &[Real],
    i: usize,
    parent: Option<(&RealMat3, RealVec3)>,
) -> RealVec3 {
    let (t, _) = translation_and_stretch(&skeleton.bones()[i], channels);
    match parent {
        None => skeleton.root().position.to_real() + t,
        Some((parent_frame, parent_tip)) => parent_tip + axes_of(skeleton, i, Some(parent_frame)) * t,
    }
}

/// Bone `i`'s `(frame, start, tip)` into the pose.
#[inline(always)]
fn store(pose: &mut Pose64, i: usize, (frame, start, tip): (RealMat3, RealVec3, RealVec3)) {
    pose.frame[i] = frame;
    pose.start[i] = start;
    pose.tip[i] = tip;
}
