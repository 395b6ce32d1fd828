//! How smooth a clip is from frame to frame: the largest joint rotation change (geodesic
//! angle, any bone, the root included), the root's displacement and its facing change — and,
//! bone by bone, each bone's own change against that bone's own speeds in the inputs
//! ([`BoneLimits`], [`bone_seam`]).

use super::Motion;
use crate::interp::{
    channel_rotation, facing_angle, largest_joint_change, root_position, root_rotation, rotation_angle,
};
use crate::math::wrap_near;
use crate::skeleton::Skeleton;
use std::ops::Range;

/// Per-frame changes: entry `i` is between frames `i` and `i + 1`.
#[derive(Clone, Debug, PartialEq)]
pub struct Steps {
    /// Largest joint rotation change over all bones, radians.
    pub rotation: Vec<f64>,
    /// Root displacement, file units.
    pub root: Vec<f64>,
    /// Absolute facing change, radians.
    pub facing: Vec<f64>,
}

/// The per-frame changes of a clip.
#[must_use]
pub fn steps(skeleton: &Skeleton, motion: &Motion) -> Steps {
    let mut s = Steps {
        rotation: Vec::new(),
        root: Vec::new(),
        facing: Vec::new(),
    };
    for i in 1..motion.len() {
        let (a, b) = (motion.frame(i - 1), motion.frame(i));
        s.rotation.push(largest_joint_change(skeleton, a, b));
        s.root
            .push((root_position(skeleton, b) - root_position(skeleton, a)).length());
        let (fa, fb) = (
            facing_angle(&root_rotation(skeleton, a)),
            facing_angle(&root_rotation(skeleton, b)),
        );
        s.facing.push((wrap_near(fb, fa) - fa).abs());
    }
    s
}

/// What a clip played over and over does at each start: from its last frame back to its
/// first.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WrapJump {
    /// The bone that jumps most beyond its own steps (0: the root's global rotation).
    pub bone: usize,
    /// Its change at the wrap, radians (geodesic angle).
    pub rotation: f64,
    /// Its own change from one frame to the next in the clip, 99th percentile, radians.
    pub bone_p99: f64,
}

impl WrapJump {
    /// Whether the clip is a cycle: at the wrap no joint turns more than three times its own
    /// 99th-percentile step, or 2° if that is more.
    #[must_use]
    pub fn is_seamless(&self) -> bool {
        self.beyond_its_steps() <= 1.0
    }

    fn beyond_its_steps(&self) -> f64 {
        beyond_its_steps(self.rotation, self.bone_p99, 2f64.to_radians())
    }
}

/// How far a change at a wrap (a clip's or a target track's, played over and over) lies
/// beyond the steps of its own: `change` against three times its 99th-percentile step `p99`,
/// or against `floor` if that is more. Over 1: a jump.
#[must_use]
pub fn beyond_its_steps(change: f64, p99: f64, floor: f64) -> f64 {
    change / (3.0 * p99).max(floor)
}

/// The jump of a clip played over and over ([`WrapJump`]): the joint whose change at the wrap
/// lies furthest [`beyond_its_steps`]. `None` for a clip of one frame.
#[must_use]
pub fn wrap_jump(skeleton: &Skeleton, motion: &Motion) -> Option<WrapJump> {
    let last = motion.len().checked_sub(1).filter(|&l| l > 0)?;
    let change = |bone: usize, a: &[f64], b: &[f64]| match bone {
        0 => rotation_angle(&root_rotation(skeleton, a), &root_rotation(skeleton, b)),
        i => rotation_angle(
            &channel_rotation(&skeleton.bones()[i], a),
            &channel_rotation(&skeleton.bones()[i], b),
        ),
    };
    (0..skeleton.len())
        .map(|bone| {
            let steps: Vec<f64> = (1..motion.len())
                .map(|i| change(bone, motion.frame(i - 1), motion.frame(i)))
                .collect();
            WrapJump {
                bone,
                rotation: change(bone, motion.frame(last), motion.frame(0)),
                bone_p99: quantile(&steps, 0.99),
            }
        })
        .max_by(|x, y| x.beyond_its_steps().total_cmp(&y.beyond_its_steps()))
}

/// The `p`-th quantile (0..1) by nearest rank; 0 for an empty list.
#[must_use]
pub fn quantile(values: &[f64], p: f64) -> f64 {
    if values.is_empty() {
        return 0.0;
    }
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * p).round() as usize]
}

/// The seam of a connection against its inputs.
#[derive(Clone, Debug, PartialEq)]
pub struct SeamReport {
    /// Largest joint rotation change across the seam, radians.
    pub rotation: f64,
    /// Largest root displacement across the seam, units.
    pub root: f64,
    /// Largest facing change across the seam, radians.
    pub facing: f64,
    /// The larger of the inputs' 99th-percentile rotation changes.
    pub input_rotation_p99: f64,
    /// The larger of the inputs' 99th-percentile root displacements.
    pub input_root_p99: f64,
    /// The larger of the inputs' 99th-percentile facing changes.
    pub input_facing_p99: f64,
}

impl SeamReport {
    /// Both seam figures within `factor` times the inputs' 99th percentiles.
    #[must_use]
    pub fn within(&self, factor: f64) -> bool {
        self.rotation <= factor * self.input_rotation_p99 && self.root <= factor * self.input_root_p99
    }
}

impl std::fmt::Display for SeamReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "joint change ≤ {:.2}°/frame (inputs' p99 {:.2}°), root ≤ {:.4} units/frame (p99 {:.4}), facing ≤ {:.2}°/frame (p99 {:.2}°)",
            self.rotation.to_degrees(),
            self.input_rotation_p99.to_degrees(),
            self.root,
            self.input_root_p99,
            self.facing.to_degrees(),
            self.input_facing_p99.to_degrees()
        )
    }
}

/// Measures the changes between consecutive output frames from the last frame before the
/// seam to the first frame after it (`seam` is the range of transition frames; an empty
/// range is a cut between two frames).
#[must_use]
pub fn seam_report(skeleton: &Skeleton, inputs: &[&Motion], out: &Motion, seam: Range<usize>) -> SeamReport {
    let s = steps(skeleton, out);
    let from = seam.start.saturating_sub(1);
    let to = seam.end.min(s.rotation.len().saturating_sub(1));
    let max_in = |v: &[f64]| {
        v[from..=to.max(from).min(v.len().saturating_sub(1))]
            .iter()
            .copied()
            .fold(0.0, f64::max)
    };
    let (mut rp, mut tp, mut fp) = (0.0f64, 0.0f64, 0.0f64);
    for m in inputs {
        let st = steps(skeleton, m);
        rp = rp.max(quantile(&st.rotation, 0.99));
        tp = tp.max(quantile(&st.root, 0.99));
        fp = fp.max(quantile(&st.facing, 0.99));
    }
    SeamReport {
        rotation: max_in(&s.rotation),
        root: max_in(&s.root),
        facing: max_in(&s.facing),
        input_rotation_p99: rp,
        input_root_p99: tp,
        input_facing_p99: fp,
    }
}

/// A seam may move a bone per frame up to this many times its own 99th percentile in the
/// inputs ...
pub const BONE_FACTOR: f64 = 1.5;

/// ... plus this much (degrees), so that a bone the inputs barely move may still settle.
pub const BONE_SLACK_DEG: f64 = 1.0;

/// ... and the root's position up to [`BONE_FACTOR`] times its p99 plus this much (metres).
pub const ROOT_SLACK_M: f64 = 0.001;

/// Each bone's rotation change between two frames (radians): entry 0 the root's orientation,
/// entry `b` bone `b`'s channel rotation.
#[must_use]
pub fn bone_changes(skeleton: &Skeleton, a: &[f64], b: &[f64]) -> Vec<f64> {
    let mut out = Vec::with_capacity(skeleton.len());
    out.push(rotation_angle(
        &root_rotation(skeleton, a),
        &root_rotation(skeleton, b),
    ));
    for bone in &skeleton.bones()[1..] {
        out.push(rotation_angle(
            &channel_rotation(bone, a),
            &channel_rotation(bone, b),
        ));
    }
    out
}

/// How far each bone, and the root's position, may move per frame across a seam: from the
/// inputs' own speeds, bone by bone.
#[derive(Clone, Debug, PartialEq)]
pub struct BoneLimits {
    /// Per bone (0: the root's orientation): the larger of the inputs' 99th-percentile change
    /// per frame, radians.
    pub p99: Vec<f64>,
    /// The root's position: the larger of the inputs' 99th-percentile displacement per frame,
    /// file units.
    pub root_p99: f64,
    /// Per bone: [`BONE_FACTOR`] × p99 + [`BONE_SLACK_DEG`], radians.
    pub allowed: Vec<f64>,
    /// The root's position: [`BONE_FACTOR`] × p99 + [`ROOT_SLACK_M`], file units.
    pub root_allowed: f64,
}

impl BoneLimits {
    /// The limits from `inputs`.
    #[must_use]
    pub fn of(skeleton: &Skeleton, inputs: &[&Motion]) -> BoneLimits {
        let bones = skeleton.len();
        let mut p99 = vec![0.0f64; bones];
        let mut root_p99 = 0.0f64;
        for m in inputs {
            let mut per_bone: Vec<Vec<f64>> = vec![Vec::with_capacity(m.len()); bones];
            let mut root = Vec::with_capacity(m.len());
            for i in 1..m.len() {
                let (a, b) = (m.frame(i - 1), m.frame(i));
                for (v, c) in per_bone.iter_mut().zip(bone_changes(skeleton, a, b)) {
                    v.push(c);
                }
                root.push((root_position(skeleton, b) - root_position(skeleton, a)).length());
            }
            for (p, v) in p99.iter_mut().zip(&per_bone) {
                *p = p.max(quantile(v, 0.99));
            }
            root_p99 = root_p99.max(quantile(&root, 0.99));
        }
        let slack = BONE_SLACK_DEG.to_radians();
        let unit = f64::from(skeleton.units().meters_per_unit()).max(1e-9);
        BoneLimits {
            allowed: p99.iter().map(|p| BONE_FACTOR * p + slack).collect(),
            root_allowed: BONE_FACTOR * root_p99 + ROOT_SLACK_M / unit,
            p99,
            root_p99,
        }
    }

    /// Frames to insert between poses `a` and `b` (interpolated at even steps) so that no bone
    /// and not the root moves more per frame than allowed.
    #[must_use]
    pub fn frames_between(&self, skeleton: &Skeleton, a: &[f64], b: &[f64]) -> usize {
        let mut steps = 1.0f64;
        for (c, limit) in bone_changes(skeleton, a, b).iter().zip(&self.allowed) {
            steps = steps.max(c / limit);
        }
        let d = (root_position(skeleton, b) - root_position(skeleton, a)).length();
        steps = steps.max(d / self.root_allowed);
        (steps.ceil() as usize).saturating_sub(1)
    }
}

/// One bone across a seam.
#[derive(Clone, Debug, PartialEq)]
pub struct BoneSeam {
    /// The bone (`root` for the root's orientation, `root position` for its place).
    pub name: String,
    /// Its largest change per frame across the seam (radians; file units for the position).
    pub change: f64,
    /// What it may do ([`BoneLimits`]).
    pub allowed: f64,
    /// `change / allowed`: at most 1 for a seam as smooth as its inputs.
    pub ratio: f64,
}

/// Every bone's largest change per frame across `seam` of `out` (from the step into its first
/// frame to the step out of its last; an empty range is the cut between two frames) against
/// `limits`, worst first.
#[must_use]
pub fn bone_seam(
    skeleton: &Skeleton,
    out: &Motion,
    seam: Range<usize>,
    limits: &BoneLimits,
) -> Vec<BoneSeam> {
    // Step i goes from frame i − 1 to frame i.
    let from = seam.start.max(1);
    let to = seam.end.min(out.len().saturating_sub(1));
    let mut worst = vec![0.0f64; skeleton.len()];
    let mut root = 0.0f64;
    for i in from..=to {
        let (a, b) = (out.frame(i - 1), out.frame(i));
        for (w, c) in worst.iter_mut().zip(bone_changes(skeleton, a, b)) {
            *w = w.max(c);
        }
        root = root.max((root_position(skeleton, b) - root_position(skeleton, a)).length());
    }
    let mut bones: Vec<BoneSeam> = worst
        .iter()
        .zip(&limits.allowed)
        .enumerate()
        .map(|(k, (&change, &allowed))| BoneSeam {
            name: if k == 0 {
                "root".to_string()
            } else {
                skeleton.bones()[k].name().to_string()
            },
            change,
            allowed,
            ratio: change / allowed,
        })
        .collect();
    bones.push(BoneSeam {
        name: "root position".to_string(),
        change: root,
        allowed: limits.root_allowed,
        ratio: root / limits.root_allowed,
    });
    bones.sort_by(|a, b| b.ratio.total_cmp(&a.ratio));
    bones
}
