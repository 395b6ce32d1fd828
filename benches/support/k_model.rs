//! The CMU skeleton, or one of its limbs, as a `k` 0.32 chain with the same kinematics as
//! `fk64` (eq. 1–5), for same-input comparisons with `k` (`examples/ik_compare.rs`,
//! `benches/instructions.rs`).
//!
//! A bone becomes a fixed node with its rest frame relative to its parent's local frame
//! (`C_parentᵀ·C`, at the parent's tip: `length_parent · C_parentᵀ·direction_parent`), then one
//! node per rotation DOF, the last Euler factor first, as `C·Rₙ…R₁` composes.

#![allow(dead_code)]

use glam::{DMat3, DQuat, DVec3};
use k::nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use marionette::fk::{fk64, Pose64};
use marionette::skeleton::{Dof, Skeleton};

/// A rotation and a translation as a `k` isometry.
pub fn na_iso(rotation: DMat3, translation: DVec3) -> Isometry3<f64> {
    let q = DQuat::from_mat3(&rotation).normalize();
    Isometry3::from_parts(
        Translation3::new(translation.x, translation.y, translation.z),
        UnitQuaternion::new_normalize(k::nalgebra::Quaternion::new(q.w, q.x, q.y, q.z)),
    )
}

/// A bone's rest frame `C`, re-orthonormalised.
fn rest_frame(skel: &Skeleton, b: usize) -> DMat3 {
    DMat3::from_quat(DQuat::from_mat3(&skel.bones()[b].axis_rotation().as_dmat3()).normalize())
}

/// Where bone `b`'s tip lies in its own local frame: `length · Cᵀ·direction`.
fn tip_in_frame(skel: &Skeleton, b: usize) -> DVec3 {
    let bone = &skel.bones()[b];
    rest_frame(skel, b).transpose()
        * bone.direction().as_dvec3().normalize_or_zero()
        * f64::from(bone.length())
}

/// Adds bone `b`'s rotation DOFs below `parent` (the first with `origin`), each named
/// `bone_k`, and returns the last node with the frame channels they take.
fn add_rotations(
    skel: &Skeleton,
    b: usize,
    parent: &k::Node<f64>,
    origin: Isometry3<f64>,
    channels: &mut Vec<(String, usize)>,
) -> k::Node<f64> {
    let bone = &skel.bones()[b];
    let mut last = parent.clone();
    let mut origin = origin;
    let mut any = false;
    for (kk, d) in bone.dofs().iter().enumerate().rev() {
        let axis = match d {
            Dof::Rx => Vector3::x_axis(),
            Dof::Ry => Vector3::y_axis(),
            Dof::Rz => Vector3::z_axis(),
            _ => continue,
        };
        let l = bone.limits()[kk];
        let name = format!("{}_{kk}", bone.name());
        let node = k::NodeBuilder::new()
            .name(&name)
            .joint_type(k::JointType::Rotational { axis })
            .limits(Some(k::joint::Range::new(f64::from(l.min), f64::from(l.max))))
            .origin(origin)
            .into_node();
        origin = Isometry3::identity();
        node.set_parent(&last);
        last = node;
        channels.push((name, bone.first_channel() + kk));
        any = true;
    }
    if !any {
        let node = k::NodeBuilder::new()
            .name(&format!("{}_fixed", bone.name()))
            .joint_type(k::JointType::Fixed)
            .origin(origin)
            .into_node();
        node.set_parent(&last);
        last = node;
    }
    last
}

/// A two-bone limb (`upper`, `lower`) from the upper bone's start, at the rest pose of the
/// bones above it, ending at the lower bone's tip; with the frame channel of each joint in
/// chain order.
pub fn limb_chain(skel: &Skeleton, upper: usize, lower: usize) -> (k::SerialChain<f64>, Vec<usize>) {
    let mut rest = Pose64::default();
    fk64(skel, &vec![0.0; skel.channel_count()], &mut rest);
    let parent = skel.bones()[upper].parent().expect("a limb bone has a parent");
    let base = k::NodeBuilder::new()
        .name("base")
        .joint_type(k::JointType::Fixed)
        .origin(na_iso(
            rest.world(skel, parent) * rest_frame(skel, upper),
            rest.start[upper],
        ))
        .into_node();
    let mut named = Vec::new();
    let upper_end = add_rotations(skel, upper, &base, Isometry3::identity(), &mut named);
    let cu = rest_frame(skel, upper);
    let lower_end = add_rotations(
        skel,
        lower,
        &upper_end,
        na_iso(
            cu.transpose() * rest_frame(skel, lower),
            tip_in_frame(skel, upper),
        ),
        &mut named,
    );
    let tip = k::NodeBuilder::new()
        .name("tip")
        .joint_type(k::JointType::Fixed)
        .origin(na_iso(DMat3::IDENTITY, tip_in_frame(skel, lower)))
        .into_node();
    tip.set_parent(&lower_end);
    let chain = k::SerialChain::from_end(&tip);
    let channels = chain_channels(&chain, &named);
    (chain, channels)
}

/// The whole skeleton as a `k` tree: the root's translation channels as linear joints along
/// the global axes, its rest orientation, its rotation channels, then every bone below; a tip
/// node on each leaf bone. Returns the chain, the frame channel of each joint in the chain's
/// joint order, and for each bone the name of the node whose origin is the bone's tip.
pub fn skeleton_chain(skel: &Skeleton) -> (k::Chain<f64>, Vec<usize>, Vec<String>) {
    let root = skel.root();
    let origin = k::NodeBuilder::new()
        .name("origin")
        .joint_type(k::JointType::Fixed)
        .origin(na_iso(DMat3::IDENTITY, root.position.as_dvec3()))
        .into_node();
    let mut named = Vec::new();
    let mut last = origin.clone();
    for (kk, d) in skel.bones()[0].dofs().iter().enumerate() {
        let axis = match d {
            Dof::Tx => Vector3::x_axis(),
            Dof::Ty => Vector3::y_axis(),
            Dof::Tz => Vector3::z_axis(),
            _ => continue,
        };
        let name = format!("root_t{kk}");
        let node = k::NodeBuilder::new()
            .name(&name)
            .joint_type(k::JointType::Linear { axis })
            .into_node();
        node.set_parent(&last);
        last = node;
        named.push((name, skel.bones()[0].first_channel() + kk));
    }
    let mut ends: Vec<k::Node<f64>> = Vec::new();
    let mut tips = vec![String::new(); skel.bones().len()];
    for b in 0..skel.bones().len() {
        let bone = &skel.bones()[b];
        assert!(
            b == 0 || bone.dofs().iter().all(|d| d.is_rotation()),
            "bone {} has a translation DOF, which this model leaves out",
            bone.name()
        );
        let end = match bone.parent() {
            None => add_rotations(
                skel,
                b,
                &last,
                na_iso(rest_frame(skel, 0), DVec3::ZERO),
                &mut named,
            ),
            Some(p) => add_rotations(
                skel,
                b,
                &ends[p],
                na_iso(
                    rest_frame(skel, p).transpose() * rest_frame(skel, b),
                    tip_in_frame(skel, p),
                ),
                &mut named,
            ),
        };
        ends.push(end);
    }
    for b in 0..skel.bones().len() {
        let name = format!("{}_tip", skel.bones()[b].name());
        let tip = k::NodeBuilder::new()
            .name(&name)
            .joint_type(k::JointType::Fixed)
            .origin(na_iso(DMat3::IDENTITY, tip_in_frame(skel, b)))
            .into_node();
        tip.set_parent(&ends[b]);
        tips[b] = name;
    }
    let chain = k::Chain::from_root(origin);
    let channels = chain_channels(&chain, &named);
    (chain, channels, tips)
}

/// The frame channel of each joint of `chain`, in its joint order.
fn chain_channels(chain: &k::Chain<f64>, named: &[(String, usize)]) -> Vec<usize> {
    chain
        .iter_joints()
        .map(|j| {
            named
                .iter()
                .find(|(n, _)| *n == j.name)
                .map(|(_, c)| *c)
                .expect("every joint is a frame channel")
        })
        .collect()
}
