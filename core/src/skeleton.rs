//! The skeleton: fixed-capacity bones addressed by index, parents before children, and the
//! channel layout of a frame vector.
//!
//! Bone 0 is the root. Its channels come first in a frame vector, in the ASF `:root order`;
//! every other bone follows in skeleton order with its channels in its `dof` order. Rotation
//! channels are radians inside the library (files hold degrees), translations are file units.

use crate::math::{real, Real, RealMat3, RealQuat, RealVec3, ToReal};
use crate::math::{Axis, EulerOrder};
use glam::{Mat3, Vec3};

/// Most bones a skeleton holds, the root included: 64, or 32 with the feature `max-bones-32`
/// (a firmware image's skeleton is compiled in at full capacity: every bone of it is flash).
pub const MAX_BONES: usize = if cfg!(feature = "max-bones-32") { 32 } else { 64 };
/// Most channels one bone has: `rx ry rz tx ty tz l`.
pub const MAX_BONE_DOFS: usize = 7;
/// Most channels in a frame vector.
pub const MAX_CHANNELS: usize = MAX_BONES * MAX_BONE_DOFS;
/// Longest bone name, in bytes.
pub const MAX_NAME_LEN: usize = 48;

/// A bone name: up to [`MAX_NAME_LEN`] bytes of UTF-8, in place (no heap), and buildable in a
/// `const` (a skeleton compiled into a firmware image).
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct BoneName {
    bytes: [u8; MAX_NAME_LEN],
    len: u8,
}

impl BoneName {
    /// The name `name`, `None` when it is longer than [`MAX_NAME_LEN`] bytes.
    #[must_use]
    pub const fn new(name: &str) -> Option<BoneName> {
        let b = name.as_bytes();
        if b.len() > MAX_NAME_LEN {
            return None;
        }
        let mut bytes = [0u8; MAX_NAME_LEN];
        let mut i = 0;
        while i < b.len() {
            bytes[i] = b[i];
            i += 1;
        }
        Some(BoneName {
            bytes,
            len: b.len() as u8,
        })
    }

    /// The name as text.
    #[must_use]
    pub fn as_str(&self) -> &str {
        // Always whole UTF-8: only `new` fills the bytes, from a `str`, within the length.
        core::str::from_utf8(&self.bytes[..usize::from(self.len)]).unwrap_or("")
    }
}

impl Default for BoneName {
    fn default() -> Self {
        BoneName {
            bytes: [0; MAX_NAME_LEN],
            len: 0,
        }
    }
}

impl TryFrom<&str> for BoneName {
    type Error = NameTooLong;
    fn try_from(name: &str) -> Result<Self, Self::Error> {
        BoneName::new(name).ok_or(NameTooLong)
    }
}

/// A bone name longer than [`MAX_NAME_LEN`] bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct NameTooLong;

impl core::ops::Deref for BoneName {
    type Target = str;
    fn deref(&self) -> &str {
        self.as_str()
    }
}

impl core::fmt::Debug for BoneName {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        core::fmt::Debug::fmt(self.as_str(), f)
    }
}

impl core::fmt::Display for BoneName {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(self.as_str())
    }
}

impl PartialEq<str> for BoneName {
    fn eq(&self, other: &str) -> bool {
        self.as_str() == other
    }
}

impl PartialEq<&str> for BoneName {
    fn eq(&self, other: &&str) -> bool {
        self.as_str() == *other
    }
}

/// One degree of freedom (channel) of a bone.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Dof {
    /// Rotation about the bone's local x axis.
    Rx,
    /// Rotation about the bone's local y axis.
    Ry,
    /// Rotation about the bone's local z axis.
    Rz,
    /// Translation along x (the root: global x).
    Tx,
    /// Translation along y.
    Ty,
    /// Translation along z.
    Tz,
    /// Change of the bone's length.
    L,
}

impl Dof {
    /// Parses `rx`, `TX`, `l`, … (case-insensitive).
    #[must_use]
    pub fn parse(text: &str) -> Option<Dof> {
        Some(match text.as_bytes() {
            [r, x] if r.eq_ignore_ascii_case(&b'r') || r.eq_ignore_ascii_case(&b't') => {
                let t = r.eq_ignore_ascii_case(&b't');
                match (t, x.to_ascii_lowercase()) {
                    (false, b'x') => Dof::Rx,
                    (false, b'y') => Dof::Ry,
                    (false, b'z') => Dof::Rz,
                    (true, b'x') => Dof::Tx,
                    (true, b'y') => Dof::Ty,
                    (true, b'z') => Dof::Tz,
                    _ => return None,
                }
            }
            [l] if l.eq_ignore_ascii_case(&b'l') => Dof::L,
            _ => return None,
        })
    }

    /// The lower-case ASF name (`rx`, …, `l`).
    #[must_use]
    pub const fn name(self) -> &'static str {
        match self {
            Dof::Rx => "rx",
            Dof::Ry => "ry",
            Dof::Rz => "rz",
            Dof::Tx => "tx",
            Dof::Ty => "ty",
            Dof::Tz => "tz",
            Dof::L => "l",
        }
    }

    /// True for `rx`, `ry`, `rz`.
    #[must_use]
    pub const fn is_rotation(self) -> bool {
        matches!(self, Dof::Rx | Dof::Ry | Dof::Rz)
    }

    /// The axis of a rotation channel (`None` for translation and length channels).
    #[must_use]
    pub const fn rotation_axis(self) -> Option<Axis> {
        match self {
            Dof::Rx => Some(Axis::X),
            Dof::Ry => Some(Axis::Y),
            Dof::Rz => Some(Axis::Z),
            Dof::Tx | Dof::Ty | Dof::Tz | Dof::L => None,
        }
    }

    /// A translation or length channel's value `v` into the offset `t` or the length change
    /// `l`; a rotation channel changes neither.
    #[inline]
    pub fn set_offset<T>(self, v: T, t: &mut [T; 3], l: &mut T) {
        match self {
            Dof::Tx => t[0] = v,
            Dof::Ty => t[1] = v,
            Dof::Tz => t[2] = v,
            Dof::L => *l = v,
            Dof::Rx | Dof::Ry | Dof::Rz => {}
        }
    }

    /// The axis of a rotation or translation channel (`None` for `l`).
    #[must_use]
    pub const fn axis(self) -> Option<Axis> {
        match self {
            Dof::Rx | Dof::Tx => Some(Axis::X),
            Dof::Ry | Dof::Ty => Some(Axis::Y),
            Dof::Rz | Dof::Tz => Some(Axis::Z),
            Dof::L => None,
        }
    }
}

/// The channel rotation `M = R(last)·…·R(first)` of a bone's rotation DOFs (help note eq. 2),
/// in f64. `angles` holds one value per DOF, radians for rotations; the values of translation
/// and length DOFs are skipped.
#[must_use]
pub fn dof_rotation(dofs: &[Dof], angles: impl IntoIterator<Item = Real>) -> RealMat3 {
    let mut m = RealMat3::IDENTITY;
    for (d, a) in dofs.iter().zip(angles) {
        if let Some(axis) = d.rotation_axis() {
            rotate_about(&mut m, axis, a);
        }
    }
    m
}

/// `m ← R_axis(a)·m` (one factor of eq. 2): only the two rows across the axis change; a zero
/// angle leaves `m` as it is.
#[inline]
pub fn rotate_about(m: &mut RealMat3, axis: crate::math::Axis, a: Real) {
    if a == 0.0 {
        return;
    }
    let (s, c) = real::sincos(a);
    let (i, j) = axis.across();
    for col in [&mut m.x_axis, &mut m.y_axis, &mut m.z_axis] {
        let (u, v) = (col[i], col[j]);
        col[i] = c * u - s * v;
        col[j] = s * u + c * v;
    }
}

/// `m ← m·R_axis(a)` (one factor of eq. 2 taken from the right) given `sin a` and `cos a`: only
/// the two columns across the axis change.
#[inline]
pub fn turn_columns_by(m: &mut RealMat3, axis: crate::math::Axis, s: Real, c: Real) {
    // One arm per axis (the pairs of `Axis::across`), so that each inlined copy moves known
    // columns rather than indexing them.
    let turn = |u: RealVec3, v: RealVec3| (c * u + s * v, c * v - s * u);
    match axis {
        Axis::X => (m.y_axis, m.z_axis) = turn(m.y_axis, m.z_axis),
        Axis::Y => (m.z_axis, m.x_axis) = turn(m.z_axis, m.x_axis),
        Axis::Z => (m.x_axis, m.y_axis) = turn(m.x_axis, m.y_axis),
    }
}

/// `const` tests that a matrix's columns (`to_cols_array`) are exactly the identity's.
macro_rules! identity_test {
    ($($name:ident: $t:ty),*) => {$(
        const fn $name(e: [$t; 9]) -> bool {
            let mut i = 0;
            while i < 9 {
                if e[i] != if i % 4 == 0 { 1.0 } else { 0.0 } {
                    return false;
                }
                i += 1;
            }
            true
        }
    )*};
}
identity_test!(is_identity: f32, is_identity_real: Real);

/// `c` in f64, re-orthonormalised through a quaternion.
fn orthonormal_f64(c: Mat3) -> RealMat3 {
    RealMat3::from_quat(RealQuat::from_mat3(&c.to_real()).normalize())
}

/// The rotation DOFs as an Euler order, when there are all three.
#[must_use]
pub fn dof_order(dofs: &[Dof]) -> Option<EulerOrder> {
    let mut axes = heapless::Vec::<_, 3>::new();
    for d in dofs.iter().filter(|d| d.is_rotation()) {
        axes.push(d.axis()?).ok()?;
    }
    EulerOrder::from_axes(axes.into_array().ok()?)
}

/// The legal range of one channel: radians for rotations, file units otherwise. Either end
/// may be infinite.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Limit {
    /// Lower bound.
    pub min: f32,
    /// Upper bound.
    pub max: f32,
}

impl Limit {
    /// No limit.
    pub const UNLIMITED: Limit = Limit {
        min: f32::NEG_INFINITY,
        max: f32::INFINITY,
    };

    /// True when `min ≤ value ≤ max`.
    #[must_use]
    pub fn contains(&self, value: f32) -> bool {
        self.min <= value && value <= self.max
    }

    /// The value moved inside the range.
    #[must_use]
    pub fn clamp(&self, value: f32) -> f32 {
        value.max(self.min).min(self.max)
    }
}

/// The length and angle units of a skeleton's files (ASF `:units`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Units {
    /// ASF `mass`.
    pub mass: f32,
    /// ASF `length`: one file unit is `1 / length` inch (CMU: 0.45).
    pub length: f32,
    /// True when the ASF angles (axis, limits, root orientation) are in degrees.
    pub degrees: bool,
}

impl Default for Units {
    fn default() -> Self {
        Units {
            mass: 1.0,
            length: 1.0,
            degrees: true,
        }
    }
}

impl Units {
    /// Metres per file unit: `(1 / length) · 0.0254`.
    #[must_use]
    pub fn meters_per_unit(&self) -> f32 {
        0.0254 / self.length
    }
}

/// The description of one bone, as a file states it, before it joins a [`Skeleton`].
#[derive(Clone, Debug, PartialEq)]
pub struct BoneSpec {
    /// Name, unique within the skeleton.
    pub name: BoneName,
    /// The ASF `id` (kept for writing; not used otherwise).
    pub id: u32,
    /// Direction from the bone's start to its tip at rest, in global coordinates. Unit length
    /// or zero.
    pub direction: Vec3,
    /// Length in file units.
    pub length: f32,
    /// The ASF `axis` angles, radians: the orientation of the bone's local frame at rest.
    pub axis: [f32; 3],
    /// The Euler order of `axis`.
    pub axis_order: EulerOrder,
    /// Channels in file order; rotations are applied in this order (first = innermost).
    pub dofs: heapless::Vec<Dof, MAX_BONE_DOFS>,
    /// One limit per channel.
    pub limits: heapless::Vec<Limit, MAX_BONE_DOFS>,
}

impl BoneSpec {
    /// A bone with no channels and no limits.
    #[must_use]
    pub fn new(name: BoneName, direction: Vec3, length: f32) -> BoneSpec {
        BoneSpec {
            name,
            id: 0,
            direction,
            length,
            axis: [0.0; 3],
            axis_order: EulerOrder::XYZ,
            dofs: heapless::Vec::new(),
            limits: heapless::Vec::new(),
        }
    }
}

/// A bone inside a [`Skeleton`]: its spec plus what the skeleton derives from it.
#[derive(Clone, Debug, PartialEq)]
pub struct Bone {
    spec: BoneSpec,
    parent: Option<usize>,
    first_channel: usize,
    /// `C`: the local frame at rest (the `axis` rotation), help note eq. (3). In an f32 core,
    /// `axis_rotation_f64` itself: one copy (a firmware image's skeleton is flash).
    axis_rotation: Mat3,
    /// The direction in the bone's local frame, eq. (5): `Cᵀ · direction`.
    local_direction: Vec3,
    /// `C` in f64, re-orthonormalised once (FK reads it for every bone of every pose).
    #[cfg(not(feature = "f32"))]
    axis_rotation_f64: RealMat3,
    /// The rest direction in f64, unit length (zero for a zero direction).
    direction_f64: RealVec3,
    /// The rest direction in the bone's local frame in f64, `Cᵀ·d` (eq. 5), unit length. In an
    /// f32 core, `local_direction` itself.
    #[cfg(not(feature = "f32"))]
    local_direction_f64: RealVec3,
    /// The bone in its local frame at rest in f64, `Cᵀ·d·L` (eq. 5): where FK's tip comes
    /// from when no length channel stretches it.
    #[cfg(not(feature = "f32"))]
    rest_vector_f64: RealVec3,
    /// `K = Cₚᵀ·C`, the rest frame in the parent's local frame (eq. 4's `ⁱR_asf`), so that FK
    /// takes a bone's axes from its parent's frame with one product, `Fₚ·K`. Under the root,
    /// whose frame is its world rotation, `C`; the root's own: `C`.
    axis_in_parent: Mat3,
    /// `K` in f64, from the re-orthonormalised `C`s.
    #[cfg(not(feature = "f32"))]
    axis_in_parent_f64: RealMat3,
    /// Whether `C` is the identity (an ASF `axis 0 0 0`): FK skips its products.
    axis_is_identity: bool,
    /// Whether `K` is the identity (the bone's `axis` is its parent's): the bone's axes are
    /// its parent's frame.
    axis_in_parent_is_identity: bool,
}

impl Bone {
    /// A bone from the parts a skeleton made by [`Skeleton::new`] holds (its accessors give
    /// them): for a build step that writes a validated skeleton out as `const` data, such as
    /// the firmware image's. Nothing is checked here.
    #[must_use]
    #[allow(clippy::too_many_arguments)]
    pub const fn from_parts(
        spec: BoneSpec,
        parent: Option<usize>,
        first_channel: usize,
        axis_rotation: Mat3,
        local_direction: Vec3,
        axis_rotation_f64: RealMat3,
        direction_f64: RealVec3,
        local_direction_f64: RealVec3,
        axis_in_parent: Mat3,
        axis_in_parent_f64: RealMat3,
    ) -> Bone {
        #[cfg(feature = "f32")]
        let (axis_rotation, axis_in_parent, local_direction) = {
            let _ = (axis_rotation, axis_in_parent, local_direction);
            (axis_rotation_f64, axis_in_parent_f64, local_direction_f64)
        };
        let axis_is_identity =
            is_identity(axis_rotation.to_cols_array()) && is_identity_real(axis_rotation_f64.to_cols_array());
        let axis_in_parent_is_identity = is_identity(axis_in_parent.to_cols_array())
            && is_identity_real(axis_in_parent_f64.to_cols_array());
        #[cfg(not(feature = "f32"))]
        let rest_vector_f64 = {
            let length = spec.length as Real;
            RealVec3::new(
                local_direction_f64.x * length,
                local_direction_f64.y * length,
                local_direction_f64.z * length,
            )
        };
        Bone {
            spec,
            parent,
            first_channel,
            axis_rotation,
            local_direction,
            #[cfg(not(feature = "f32"))]
            axis_rotation_f64,
            direction_f64,
            #[cfg(not(feature = "f32"))]
            local_direction_f64,
            #[cfg(not(feature = "f32"))]
            rest_vector_f64,
            axis_in_parent,
            #[cfg(not(feature = "f32"))]
            axis_in_parent_f64,
            axis_is_identity,
            axis_in_parent_is_identity,
        }
    }

    /// Whether the rest frame in the parent's, `K = Cₚᵀ·C`, is the identity (in both
    /// precisions): the bone's `axis` is its parent's, and its axes are its parent's frame.
    #[must_use]
    pub fn axis_in_parent_is_identity(&self) -> bool {
        self.axis_in_parent_is_identity
    }

    /// `K = Cₚᵀ·C`, the rest frame in the parent's local frame (eq. 4; under the root, and
    /// for the root, `C`).
    #[must_use]
    pub fn axis_in_parent(&self) -> Mat3 {
        self.axis_in_parent
    }

    /// `K` in f64.
    #[must_use]
    pub fn axis_in_parent_f64(&self) -> RealMat3 {
        #[cfg(not(feature = "f32"))]
        {
            self.axis_in_parent_f64
        }
        #[cfg(feature = "f32")]
        {
            self.axis_in_parent
        }
    }

    /// The rest direction in the local frame in f64, `Cᵀ·d` (eq. 5), unit length (zero for a
    /// zero direction).
    #[must_use]
    pub fn local_direction_f64(&self) -> RealVec3 {
        #[cfg(not(feature = "f32"))]
        {
            self.local_direction_f64
        }
        #[cfg(feature = "f32")]
        {
            self.local_direction
        }
    }

    /// The bone in its local frame at rest in f64, `Cᵀ·d·L` (eq. 5), the same bits as
    /// `local_direction_f64() * length`.
    #[must_use]
    pub fn rest_vector_f64(&self) -> RealVec3 {
        #[cfg(not(feature = "f32"))]
        {
            self.rest_vector_f64
        }
        #[cfg(feature = "f32")]
        {
            self.local_direction * self.spec.length
        }
    }

    /// The bone in its local frame in f64 with its length channel's `l` added, `Cᵀ·d·(L + l)`
    /// (eq. 5).
    #[must_use]
    #[inline]
    pub fn vector_f64(&self, l: Real) -> RealVec3 {
        if l == 0.0 {
            self.rest_vector_f64()
        } else {
            self.local_direction_f64() * ((self.spec.length as Real) + l)
        }
    }

    /// Whether the rest frame `C` is the identity (in both precisions), so that `W·C = W`.
    #[must_use]
    pub fn axis_is_identity(&self) -> bool {
        self.axis_is_identity
    }

    /// The bone's name.
    #[must_use]
    pub fn name(&self) -> &str {
        &self.spec.name
    }
    /// The file's description of the bone.
    #[must_use]
    pub fn spec(&self) -> &BoneSpec {
        &self.spec
    }
    /// The parent's index (`None` for the root).
    #[must_use]
    pub fn parent(&self) -> Option<usize> {
        self.parent
    }
    /// The channels, in frame order.
    #[must_use]
    pub fn dofs(&self) -> &[Dof] {
        &self.spec.dofs
    }
    /// The limits, one per channel.
    #[must_use]
    pub fn limits(&self) -> &[Limit] {
        &self.spec.limits
    }
    /// Index of the bone's first channel in a frame vector.
    #[must_use]
    pub fn first_channel(&self) -> usize {
        self.first_channel
    }
    /// The range of the bone's channels in a frame vector.
    #[must_use]
    pub fn channels(&self) -> core::ops::Range<usize> {
        self.first_channel..self.first_channel + self.spec.dofs.len()
    }
    /// Length in file units.
    #[must_use]
    pub fn length(&self) -> f32 {
        self.spec.length
    }
    /// Unit direction at rest, global (zero for the root or a zero-length bone).
    #[must_use]
    pub fn direction(&self) -> Vec3 {
        self.spec.direction
    }
    /// `C`, the rest orientation of the bone's local frame.
    #[must_use]
    pub fn axis_rotation(&self) -> Mat3 {
        self.axis_rotation
    }
    /// The rest direction in the local frame (eq. 5).
    #[must_use]
    pub fn local_direction(&self) -> Vec3 {
        self.local_direction
    }
    /// `C` in f64, re-orthonormalised: the skeleton stores it in f32, and a slightly skewed `C`
    /// would make `Cᵀ·Q·C` no rotation, which Euler extraction amplifies near gimbal lock.
    #[must_use]
    pub fn axis_rotation_f64(&self) -> RealMat3 {
        #[cfg(not(feature = "f32"))]
        {
            self.axis_rotation_f64
        }
        #[cfg(feature = "f32")]
        {
            self.axis_rotation
        }
    }
    /// The rest direction (global) in f64, unit length (zero for a zero direction).
    #[must_use]
    pub fn direction_f64(&self) -> RealVec3 {
        self.direction_f64
    }
}

/// Why a set of bones does not make a skeleton. Indices refer to the `bones` slice given to
/// [`Skeleton::new`]; `usize::MAX` means the root.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum SkeletonError {
    /// More than [`MAX_BONES`] bones (root included).
    TooManyBones,
    /// Two bones share a name, or a bone is called `root`.
    DuplicateName(usize),
    /// A bone is not reached from the root: no parent given, or part of a cycle.
    Detached(usize),
    /// A parent index is out of range or names the bone itself.
    BadParent(usize),
    /// A bone's direction is not finite, or zero while its length is not.
    BadDirection(usize),
    /// A length is negative or not finite.
    BadLength(usize),
    /// Channels and limits differ in number, a channel is repeated, or a limit is
    /// inverted or NaN.
    BadChannels(usize),
}

impl SkeletonError {
    /// The index of the bone at fault (`usize::MAX`: the root), `None` when no one bone is.
    #[must_use]
    pub fn bone(&self) -> Option<usize> {
        match *self {
            SkeletonError::TooManyBones => None,
            SkeletonError::DuplicateName(i)
            | SkeletonError::Detached(i)
            | SkeletonError::BadParent(i)
            | SkeletonError::BadDirection(i)
            | SkeletonError::BadLength(i)
            | SkeletonError::BadChannels(i) => Some(i),
        }
    }
}

/// A skeleton's bone names, displayed separated by spaces ([`Skeleton::bone_names`]).
#[derive(Clone, Copy, Debug)]
pub struct BoneNames<'a>(&'a [Bone]);

impl core::fmt::Display for BoneNames<'_> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        for (k, b) in self.0.iter().enumerate() {
            if k > 0 {
                f.write_str(" ")?;
            }
            f.write_str(b.name())?;
        }
        Ok(())
    }
}

impl core::fmt::Display for SkeletonError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            SkeletonError::TooManyBones => write!(f, "more than {MAX_BONES} bones"),
            SkeletonError::DuplicateName(i) => write!(f, "bone {i}: name used twice (or 'root')"),
            SkeletonError::Detached(i) => write!(f, "bone {i}: not connected to the root"),
            SkeletonError::BadParent(i) => write!(f, "bone {i}: parent out of range or itself"),
            SkeletonError::BadDirection(i) => {
                write!(f, "bone {i}: direction not finite, or zero with a length")
            }
            SkeletonError::BadLength(i) => write!(f, "bone {i}: length negative or not finite"),
            SkeletonError::BadChannels(i) => write!(f, "bone {i}: channels repeat or limits inverted"),
        }
    }
}

impl core::error::Error for SkeletonError {}

/// The root's description: ASF `:root`.
#[derive(Clone, Debug, PartialEq)]
pub struct RootSpec {
    /// Channel order (`order TX TY TZ RX RY RZ`); rotations applied in this order.
    pub order: heapless::Vec<Dof, 6>,
    /// Euler order of `orientation`.
    pub axis_order: EulerOrder,
    /// Rest position added to the translation channels.
    pub position: Vec3,
    /// Rest orientation, radians; rotates the whole skeleton.
    pub orientation: [f32; 3],
}

impl Default for RootSpec {
    fn default() -> Self {
        let mut order = heapless::Vec::new();
        for d in [Dof::Tx, Dof::Ty, Dof::Tz, Dof::Rx, Dof::Ry, Dof::Rz] {
            let _ = order.push(d);
        }
        RootSpec {
            order,
            axis_order: EulerOrder::XYZ,
            position: Vec3::ZERO,
            orientation: [0.0; 3],
        }
    }
}

/// A validated skeleton: bone 0 is the root and every parent comes before its children.
#[derive(Clone, Debug, PartialEq)]
pub struct Skeleton {
    bones: heapless::Vec<Bone, MAX_BONES>,
    root: RootSpec,
    units: Units,
    channel_count: usize,
}

impl Skeleton {
    /// Builds a skeleton from a root, bones in any order, and each bone's parent (an index into
    /// `bones`, or `None` for the root). Bones are reordered depth first from the root, children
    /// in the order given.
    ///
    /// # Errors
    /// [`SkeletonError`] names the offending bone.
    pub fn new(
        root: RootSpec,
        units: Units,
        bones: &[BoneSpec],
        parents: &[Option<usize>],
    ) -> Result<Skeleton, SkeletonError> {
        if bones.len() + 1 > MAX_BONES || parents.len() != bones.len() {
            return Err(SkeletonError::TooManyBones);
        }
        for (i, b) in bones.iter().enumerate() {
            if b.name.as_str().eq_ignore_ascii_case("root") || bones[..i].iter().any(|o| o.name == b.name) {
                return Err(SkeletonError::DuplicateName(i));
            }
            if !b.length.is_finite() || b.length < 0.0 {
                return Err(SkeletonError::BadLength(i));
            }
            let d = b.direction;
            if !d.is_finite() || (d == Vec3::ZERO && b.length != 0.0) {
                return Err(SkeletonError::BadDirection(i));
            }
            if b.dofs.len() != b.limits.len()
                || b.limits
                    .iter()
                    .any(|l| l.min.is_nan() || l.max.is_nan() || l.min > l.max)
                || b.dofs.iter().enumerate().any(|(k, d)| b.dofs[..k].contains(d))
                || b.axis.iter().any(|a| !a.is_finite())
            {
                return Err(SkeletonError::BadChannels(i));
            }
            if let Some(p) = parents[i] {
                if p >= bones.len() || p == i {
                    return Err(SkeletonError::BadParent(i));
                }
            }
        }
        if root
            .order
            .iter()
            .enumerate()
            .any(|(k, d)| *d == Dof::L || root.order[..k].contains(d))
            || !root.position.is_finite()
            || root.orientation.iter().any(|a| !a.is_finite())
        {
            return Err(SkeletonError::BadChannels(usize::MAX));
        }

        // Depth-first order from the root; `order[k]` is the input index of skeleton bone k+1.
        let mut order: heapless::Vec<usize, MAX_BONES> = heapless::Vec::new();
        let mut stack: heapless::Vec<(Option<usize>, usize), MAX_BONES> = heapless::Vec::new();
        // Each stack entry: (parent, next child position to scan from).
        let _ = stack.push((None, 0));
        while let Some(top) = stack.last_mut() {
            let (parent, from) = *top;
            match (from..bones.len()).find(|&c| parents[c] == parent) {
                Some(child) => {
                    top.1 = child + 1;
                    if order.push(child).is_err() || stack.push((Some(child), 0)).is_err() {
                        return Err(SkeletonError::TooManyBones);
                    }
                }
                None => {
                    stack.pop();
                }
            }
        }
        if order.len() != bones.len() {
            let missing = (0..bones.len()).find(|i| !order.contains(i)).unwrap_or(0);
            return Err(SkeletonError::Detached(missing));
        }

        let mut out: heapless::Vec<Bone, MAX_BONES> = heapless::Vec::new();
        let mut root_spec = BoneSpec::new(BoneName::try_from("root").unwrap_or_default(), Vec3::ZERO, 0.0);
        root_spec.axis = root.orientation;
        root_spec.axis_order = root.axis_order;
        for d in &root.order {
            let _ = root_spec.dofs.push(*d);
            let _ = root_spec.limits.push(Limit::UNLIMITED);
        }
        let root_rot = root.axis_order.to_mat3(root.orientation);
        let root_rot_f64 = orthonormal_f64(root_rot);
        let mut channel = root.order.len();
        let _ = out.push(Bone::from_parts(
            root_spec,
            None,
            0,
            root_rot,
            Vec3::ZERO,
            root_rot_f64,
            RealVec3::ZERO,
            RealVec3::ZERO,
            root_rot,
            root_rot_f64,
        ));
        for &input in &order {
            let spec = bones[input].clone();
            let parent = match parents[input] {
                None => 0,
                Some(p) => 1 + order.iter().position(|&o| o == p).unwrap_or(0),
            };
            let c = spec.axis_order.to_mat3(spec.axis);
            let c_f64 = orthonormal_f64(c);
            let local_direction = c.transpose() * spec.direction;
            let n = spec.dofs.len();
            let direction_f64 = spec.direction.to_real().normalize_or_zero();
            let local_direction_f64 = (c_f64.transpose() * direction_f64).normalize_or_zero();
            // `K = Cₚᵀ·C`; `C` under the root, whose frame is its world rotation. Where the
            // bone's axis is its parent's (to 1e-12 rad in f64, 1e-6 in f32: CMU's `lhand` and
            // `lwrist` differ by the file's rounding, 2e-17 rad) exactly the identity, and FK
            // skips its product.
            let above = &out[parent];
            let (k, k_f64) = if parent == 0 {
                (c, c_f64)
            } else {
                let k_f64 = above.axis_rotation_f64().transpose() * c_f64;
                if k_f64.abs_diff_eq(RealMat3::IDENTITY, crate::math::precision(1e-12, 1e-6)) {
                    (Mat3::IDENTITY, RealMat3::IDENTITY)
                } else {
                    (above.axis_rotation.transpose() * c, k_f64)
                }
            };
            let _ = out.push(Bone::from_parts(
                spec,
                Some(parent),
                channel,
                c,
                local_direction,
                c_f64,
                direction_f64,
                local_direction_f64,
                k,
                k_f64,
            ));
            channel += n;
        }
        Ok(Skeleton {
            bones: out,
            root,
            units,
            channel_count: channel,
        })
    }

    /// A skeleton from the parts one made by [`Skeleton::new`] holds ([`Skeleton::bones`],
    /// [`Skeleton::root`], [`Skeleton::units`], [`Skeleton::channel_count`]): for a build
    /// step that writes a validated skeleton out as `const` data. Nothing is checked here.
    #[must_use]
    pub const fn from_parts(
        bones: heapless::Vec<Bone, MAX_BONES>,
        root: RootSpec,
        units: Units,
        channel_count: usize,
    ) -> Skeleton {
        Skeleton {
            bones,
            root,
            units,
            channel_count,
        }
    }

    /// All bones, root first, parents before children.
    #[must_use]
    pub fn bones(&self) -> &[Bone] {
        &self.bones
    }

    /// The bones' names in that order, separated by spaces when displayed (for messages that
    /// list what a skeleton has).
    #[must_use]
    pub fn bone_names(&self) -> BoneNames<'_> {
        BoneNames(&self.bones)
    }

    /// Number of bones, the root included.
    #[must_use]
    pub fn len(&self) -> usize {
        self.bones.len()
    }

    /// Never true: a skeleton always has its root.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.bones.is_empty()
    }

    /// The bone with this name (`root` for the root).
    #[must_use]
    pub fn find(&self, name: &str) -> Option<usize> {
        self.bones.iter().position(|b| b.name() == name)
    }

    /// Children of bone `i`, in order.
    pub fn children(&self, i: usize) -> impl Iterator<Item = usize> + '_ {
        self.bones
            .iter()
            .enumerate()
            .filter(move |(_, b)| b.parent == Some(i))
            .map(|(k, _)| k)
    }

    /// The root section.
    #[must_use]
    pub fn root(&self) -> &RootSpec {
        &self.root
    }

    /// The file units.
    #[must_use]
    pub fn units(&self) -> Units {
        self.units
    }

    /// Length of a frame vector.
    #[must_use]
    pub fn channel_count(&self) -> usize {
        self.channel_count
    }

    /// The bones other than the root, as specs, with their parents as indices into that same
    /// list; what [`Skeleton::new`] takes back.
    pub fn specs(&self) -> impl Iterator<Item = (&BoneSpec, Option<usize>)> + '_ {
        self.bones[1..].iter().map(|b| {
            let p = b.parent.and_then(|p| p.checked_sub(1));
            (&b.spec, p)
        })
    }

    /// The bone and DOF that own channel `c`.
    #[must_use]
    pub fn channel_owner(&self, c: usize) -> Option<(usize, Dof)> {
        self.bones
            .iter()
            .enumerate()
            .find(|(_, b)| b.channels().contains(&c))
            .map(|(i, b)| (i, b.dofs()[c - b.first_channel]))
    }
}
