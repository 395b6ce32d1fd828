//! The follower: effector targets solved by IK inside the tick — an analytic 2-bone limb
//! (help note §IV) where the effector ends one, damped least squares up the chain elsewhere,
//! and a pointing bone for a direction target.

use glam::DVec3;

use super::input::{Target, MAX_EFFECTORS};
use super::stats::LoopStats;
use super::SWIVEL_WINDOW;
use crate::fk::{fk64, Pose64};
use crate::ik::{point_bone, Limb, Swivel};
use crate::ik_numeric::{Constraint, Settings, Solver};
use crate::skeleton::{Skeleton, MAX_BONES};

/// How one effector is solved.
#[derive(Debug)]
enum EffectorSolver {
    /// Analytic 2-bone limb (help note §IV) with the swivel kept near the previous one.
    Limb(Box<Limb>),
    /// Damped least squares up the chain to six rotational DOFs (bones of analytic limbs left
    /// out).
    Numeric(Box<Solver>),
}

/// One effector of a follower.
#[derive(Debug)]
pub struct Effector {
    /// Bone name (its tip is the effector).
    pub name: String,
    bone: usize,
    solver: EffectorSolver,
    swivel: Option<f64>,
    /// The bone pointed by a direction target (hand, foot) and its solver when not 3-DOF.
    pointer: Option<(usize, Option<Box<Solver>>)>,
}

/// The swivel a limb's next solve searches after `previous` (its last solve's): the first
/// the whole circle, later ones a window around the previous swivel (no elbow flips, a quarter
/// of the work).
fn next_swivel(previous: Option<f64>) -> Swivel {
    match previous {
        Some(previous) => Swivel::Track {
            previous,
            window: SWIVEL_WINDOW,
        },
        None => Swivel::Auto { previous: None },
    }
}

/// Why a follower cannot be set up.
#[derive(Debug, thiserror::Error)]
pub enum FollowError {
    /// Unknown bone.
    #[error("no bone named '{0}' in the skeleton")]
    UnknownBone(String),
    /// The root or its direct children.
    #[error("'{0}' is the root or hangs from it: it cannot be an effector")]
    TooHigh(String),
    /// Too many.
    #[error("at most {MAX_EFFECTORS} effectors")]
    TooMany,
}

/// The bone a direction target of effector `bone` points (the hand after the forearm, the foot
/// after the shin): down the first children until two rotation DOFs are passed.
#[must_use]
pub fn pointer_bone(skeleton: &Skeleton, bone: usize) -> Option<usize> {
    let mut dofs = 0;
    let mut at = skeleton.children(bone).next();
    while let Some(c) = at {
        dofs += rotations(skeleton, c);
        if dofs >= 2 {
            return Some(c);
        }
        at = skeleton.children(c).next();
    }
    None
}

fn rotations(skeleton: &Skeleton, bone: usize) -> usize {
    skeleton.bones()[bone]
        .dofs()
        .iter()
        .filter(|d| d.is_rotation())
        .count()
}

/// IK targets → joint angles, all state prepared before the loop.
#[derive(Debug)]
pub struct Follower {
    pub(super) effectors: Vec<Effector>,
    pub(super) targets: [Option<Target>; MAX_EFFECTORS],
    numeric: Settings,
    range: f64,
}

/// How many times the skeleton's reach a target may lie from the root before it is refused.
pub const TARGET_RANGE_REACHES: f64 = 10.0;

/// The farthest from the root a target is taken, file units: [`TARGET_RANGE_REACHES`] times
/// the longest chain of bones from the root. A target beyond it is no pose a limb could reach
/// towards but a wrong unit or a corrupt message, refused like a NaN.
#[must_use]
pub fn target_range(skeleton: &Skeleton) -> f64 {
    let bones = skeleton.bones();
    let mut chain = vec![0.0f64; bones.len()];
    let mut longest = 0.0f64;
    // Parents come before their children.
    for (k, b) in bones.iter().enumerate() {
        let up = b.parent().map_or(0.0, |p| chain[p]);
        chain[k] = up + f64::from(b.length());
        longest = longest.max(chain[k]);
    }
    TARGET_RANGE_REACHES * longest
}

impl Follower {
    /// Effectors by bone name: each ends a 2-bone limb (analytic) or is solved numerically.
    ///
    /// # Errors
    /// [`FollowError`].
    pub fn new(skeleton: &Skeleton, names: &[String]) -> Result<Follower, FollowError> {
        if names.len() > MAX_EFFECTORS {
            return Err(FollowError::TooMany);
        }
        // Analytic limbs first: the bones they own are left out of numerical chains.
        let mut owned = [false; MAX_BONES];
        let mut limbs = Vec::new();
        for name in names {
            let bone = skeleton
                .find(name)
                .ok_or_else(|| FollowError::UnknownBone(name.clone()))?;
            let parent = skeleton.bones()[bone]
                .parent()
                .filter(|&p| skeleton.bones()[p].parent().is_some())
                .ok_or_else(|| FollowError::TooHigh(name.clone()))?;
            let limb = Limb::new(skeleton, parent, bone, None).ok();
            if limb.is_some() {
                owned[parent] = true;
                owned[bone] = true;
            }
            limbs.push((bone, limb));
        }
        let mut effectors = Vec::new();
        for (name, (bone, limb)) in names.iter().zip(limbs) {
            let solver = match limb {
                Some(l) => EffectorSolver::Limb(Box::new(l)),
                None => {
                    // Up the chain until six rotational DOFs (a position and some slack) or a
                    // bone hanging from the root, skipping bones an analytic limb moves.
                    let mut mask = [false; MAX_BONES];
                    let mut dofs = 0;
                    let mut i = Some(bone);
                    while let Some(k) = i.filter(|&k| skeleton.bones()[k].parent().is_some() && dofs < 6) {
                        if !owned[k] {
                            mask[k] = true;
                            dofs += skeleton.bones()[k]
                                .dofs()
                                .iter()
                                .filter(|d| d.is_rotation())
                                .count();
                        }
                        i = skeleton.bones()[k].parent();
                    }
                    EffectorSolver::Numeric(Box::new(Solver::new(skeleton, &mask, false)))
                }
            };
            // The bone a direction points, and a numerical solver over the bones down to it
            // unless it turns on three axes of its own.
            let pointer = pointer_bone(skeleton, bone).map(|c| {
                let mut mask = [false; MAX_BONES];
                let mut at = skeleton.children(bone).next();
                while let Some(b) = at {
                    mask[b] = true;
                    if b == c {
                        break;
                    }
                    at = skeleton.children(b).next();
                }
                let numeric =
                    (rotations(skeleton, c) != 3).then(|| Box::new(Solver::new(skeleton, &mask, false)));
                (c, numeric)
            });
            effectors.push(Effector {
                name: name.clone(),
                bone,
                solver,
                swivel: None,
                pointer,
            });
        }
        Ok(Follower {
            effectors,
            targets: [None; MAX_EFFECTORS],
            numeric: Settings {
                max_iterations: 30,
                restarts: 0,
                tolerance: 1e-4,
                damping: 0.05,
                ..Settings::default()
            },
            range: target_range(skeleton),
        })
    }

    /// Whether the loop takes `t`: finite, one of the effectors, within [`target_range`] of
    /// the root.
    #[must_use]
    pub fn accepts(&self, t: &Target) -> bool {
        t.is_finite()
            && t.effector < self.effectors.len()
            && t.position.length_squared() <= self.range * self.range
    }

    /// The effector names, in order.
    pub fn names(&self) -> impl Iterator<Item = &str> {
        self.effectors.iter().map(|e| e.name.as_str())
    }

    /// The channels the loop's first solve gives for `targets`: a fresh follower of the same
    /// effectors solving them from the rest pose (every channel 0), as the loop starts. `None`
    /// when the loop would refuse them.
    #[must_use]
    pub fn first_pose(&self, skeleton: &Skeleton, targets: &[Target]) -> Option<Vec<f64>> {
        if !targets.iter().all(|t| self.accepts(t)) {
            return None;
        }
        let names: Vec<String> = self.names().map(String::from).collect();
        let mut fresh = Follower::new(skeleton, &names).ok()?;
        for t in targets {
            fresh.targets[t.effector] = Some(*t);
        }
        let mut channels = vec![0.0; skeleton.channel_count()];
        let mut pose = Pose64::default();
        let count = fresh.effectors.len();
        fresh.solve_some(
            skeleton,
            &mut channels,
            &mut pose,
            &mut LoopStats::default(),
            0..count,
        );
        Some(channels)
    }

    /// Solves effector `k` for `target` (its present one when `None`) on `scratch` (a copy of
    /// the pose, changed) and keeps nothing: the solve the next tick makes, made ahead while
    /// the loop waits, so that its code and data are in the caches when the tick comes. A limb
    /// only; returns whether it solved.
    pub(super) fn rehearse(
        &self,
        skeleton: &Skeleton,
        scratch: &mut [f64],
        k: usize,
        target: Option<DVec3>,
    ) -> bool {
        let Some(e) = self.effectors.get(k) else {
            return false;
        };
        let Some(target) = target.or_else(|| self.targets.get(k).copied().flatten().map(|t| t.position))
        else {
            return false;
        };
        if let EffectorSolver::Limb(limb) = &e.solver {
            std::hint::black_box(limb.solve(skeleton, scratch, target, next_swivel(e.swivel)));
            return true;
        }
        false
    }

    /// Solves the effectors in `which` that have a target, in place on `channels`, counting
    /// unreachable ones and residuals in `stats`. An input's effectors may be solved a few at
    /// a time, in order, on the same channels: the result is the same.
    pub(super) fn solve_some(
        &mut self,
        skeleton: &Skeleton,
        channels: &mut [f64],
        pose: &mut Pose64,
        stats: &mut LoopStats,
        which: std::ops::Range<usize>,
    ) {
        for (k, e) in self
            .effectors
            .iter_mut()
            .enumerate()
            .take(which.end)
            .skip(which.start)
        {
            let Some(t) = self.targets[k] else { continue };
            let swivel = next_swivel(e.swivel);
            let residual = match &mut e.solver {
                EffectorSolver::Limb(limb) => {
                    let s = limb.solve(skeleton, channels, t.position, swivel);
                    e.swivel = Some(s.swivel);
                    if !s.reachable {
                        stats.unreachable += 1;
                    }
                    s.error
                }
                EffectorSolver::Numeric(solver) => {
                    let c = Constraint {
                        bone: e.bone,
                        position: t.position,
                        axes: None,
                    };
                    solver
                        .solve(skeleton, &[c], channels, &self.numeric)
                        .position_error
                }
            };
            stats.ik_error(residual);
            if let (Some(dir), Some((hand, numeric))) = (t.direction, &mut e.pointer) {
                let dir = dir.normalize();
                match numeric {
                    None => {
                        let _ = point_bone(skeleton, channels, *hand, dir, 0.0);
                    }
                    Some(solver) => {
                        fk64(skeleton, channels, pose);
                        let len = (pose.tip[*hand] - pose.start[*hand]).length();
                        let c = Constraint {
                            bone: *hand,
                            position: pose.start[*hand] + dir * len,
                            axes: None,
                        };
                        solver.solve(skeleton, &[c], channels, &self.numeric);
                    }
                }
            }
        }
    }
}
