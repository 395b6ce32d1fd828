//! How smooth a clip is from frame to frame: the largest joint rotation change (geodesic
//! angle, any bone, the root included), the root's displacement and its facing change.

use super::Motion;
use crate::interp::{facing_angle, largest_joint_change, root_position, root_rotation};
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
