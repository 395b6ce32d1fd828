//! The studio's model: a skeleton posed by effector targets the user drags, solved by the chosen
//! IK method — and, to compare, by a second one from the same start — over the frame of a clip
//! when one is loaded.
//!
//! Targets are kept in world coordinates (the skeleton's FK frame), so a pinned foot stays on
//! the floor while the clip moves the root. The API speaks in the root's frame, as `follow`'s
//! targets: [`Scene::root_to_world`] and [`Scene::world_to_root`] convert.

use std::sync::Arc;
use std::time::Instant;

use glam::{DMat3, DVec3};

use crate::fk::{fk64, Pose64};
use crate::ik::{Limb, Swivel};
use crate::ik_numeric::{chain_mask, BoneMask, Constraint, IkMethod, Settings, Solver};
use crate::motion::{frame_to_radians, Motion};
use crate::skeleton::{Skeleton, MAX_BONES};

/// Why a request cannot be done (the API answers 400 with it).
#[derive(Debug, PartialEq, thiserror::Error)]
pub enum SceneError {
    /// No such bone.
    #[error("no bone named '{0}' in the skeleton")]
    UnknownBone(String),
    /// The root or a bone hanging from it.
    #[error("'{0}' is the root or hangs from it: it cannot be an effector")]
    TooHigh(String),
    /// Not a method.
    #[error("unknown method '{0}': one of analytic, ccd, jt, pinv, dls, cg")]
    UnknownMethod(String),
    /// NaN or infinity.
    #[error("{0} must be finite numbers")]
    NotFinite(&'static str),
    /// No clip loaded.
    #[error("no clip: start the studio with an AMC to use the timeline")]
    NoClip,
    /// Too many effectors.
    #[error("at most {MAX_EFFECTORS} effectors")]
    TooMany,
}

/// Most effectors the scene holds.
pub const MAX_EFFECTORS: usize = 8;

/// Iteration cap of a numerical solve while dragging.
const MAX_ITERATIONS: usize = 1000;
/// Fresh starts of a numerical solve stalled short of the tolerance.
const RESTARTS: usize = 4;
/// Iterations a numerical solve may go on without a 10 % drop of its squared residual.
const PATIENCE: usize = 60;
/// Position tolerance of a numerical solve, file units (CMU: ~6 µm).
const TOLERANCE: f64 = 1e-4;

/// A bone whose tip can be dragged.
#[derive(Clone, Debug)]
pub struct Effector {
    /// Its bone.
    pub bone: usize,
    /// Its name.
    pub name: String,
    /// The analytic limb it ends, when it does.
    limb: Option<Limb>,
    /// The bones a numerical method moves for it.
    mask: BoneMask,
    /// Goal of the tip (world); `None` while it follows the clip.
    pub target: Option<DVec3>,
}

/// What one solve did.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct SolveReport {
    /// The method.
    pub solver: &'static str,
    /// Iterations over all effectors (1 for each analytic limb).
    pub iterations: usize,
    /// Largest distance of a targeted tip from its target, file units.
    pub residual: f64,
    /// Time of the solve, µs.
    pub micros: f64,
    /// The swivel angle of each analytic limb solved, degrees.
    pub swivels: Vec<(String, f64)>,
}

/// One method's pose, kept from solve to solve (the warm start while dragging).
#[derive(Clone, Debug)]
pub struct Solved {
    /// The method.
    pub method: IkMethod,
    /// Channel values (radians).
    pub channels: Vec<f64>,
    /// The last solve.
    pub report: SolveReport,
    swivel: [Option<f64>; MAX_EFFECTORS],
    solvers: Vec<Option<Solver>>,
}

impl Solved {
    fn new(method: IkMethod, channels: Vec<f64>) -> Solved {
        Solved {
            method,
            channels,
            report: SolveReport {
                solver: method.name(),
                ..SolveReport::default()
            },
            swivel: [None; MAX_EFFECTORS],
            solvers: Vec::new(),
        }
    }
}

/// The clip's time.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Timeline {
    /// Clip time, seconds.
    pub time: f64,
    /// Whether it advances.
    pub playing: bool,
    /// Speed factor.
    pub speed: f64,
    /// Whether it wraps at the end.
    pub looping: bool,
    /// Length, seconds.
    pub duration: f64,
}

/// A point of the swivel circle: where the elbow (knee) would be, and whether the limb is then
/// within its joint limits.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct SwivelPoint {
    /// Swivel angle, degrees.
    pub deg: f64,
    /// The elbow's position (world).
    pub elbow: [f64; 3],
    /// Within the shoulder's and the elbow's limits.
    pub legal: bool,
}

/// The scene.
#[derive(Debug)]
pub struct Scene {
    skel: Arc<Skeleton>,
    frames: Vec<Vec<f64>>,
    frame_rate: f64,
    rest_root: (DVec3, DMat3),
    /// The draggable effectors.
    pub effectors: Vec<Effector>,
    /// The method driving the rig.
    pub primary: Solved,
    /// The method compared with it.
    pub ghost: Option<Solved>,
    /// Fixed swivel for analytic limbs, radians; `None` searches it.
    pub swivel: Option<f64>,
    /// The clip's time.
    pub timeline: Timeline,
    base: Vec<f64>,
}

impl Scene {
    /// A scene of `skel` posed by the first frame of `clip` (the rest pose without one), with
    /// the limb ends (bones ending a 2-bone analytic limb) as effectors.
    #[must_use]
    pub fn new(skel: Arc<Skeleton>, clip: Option<&Motion>) -> Scene {
        let frames: Vec<Vec<f64>> = clip
            .map(|m| {
                (0..m.len())
                    .map(|i| frame_to_radians(&skel, m.frame(i)))
                    .collect()
            })
            .unwrap_or_default();
        let frame_rate = clip.map_or(120.0, |m| m.frame_rate);
        let n = skel.channel_count();
        let base = frames.first().cloned().unwrap_or_else(|| vec![0.0; n]);
        let mut pose = Pose64::default();
        fk64(&skel, &vec![0.0; n], &mut pose);
        let rest_root = (pose.start[0], pose.frame[0]);
        let mut scene = Scene {
            frames,
            frame_rate,
            rest_root,
            effectors: Vec::new(),
            primary: Solved::new(IkMethod::Analytic, base.clone()),
            ghost: None,
            swivel: None,
            timeline: Timeline {
                time: 0.0,
                playing: false,
                speed: 1.0,
                looping: true,
                duration: clip.map_or(0.0, Motion::duration),
            },
            base,
            skel,
        };
        // Limb ends: bones ending an analytic 2-bone limb that carry a hand or a foot (a
        // child) and lie above no other limb end (the spine's and neck's pairs do).
        let bones = scene.skel.bones();
        let ends: Vec<usize> = (0..bones.len())
            .filter(|&b| {
                bones[b]
                    .parent()
                    .filter(|&p| bones[p].parent().is_some())
                    .is_some_and(|p| Limb::new(&scene.skel, p, b, None).is_ok())
                    && scene.skel.children(b).next().is_some()
            })
            .collect();
        let above = |a: usize, b: usize| {
            let mut at = bones[b].parent();
            while let Some(p) = at {
                if p == a {
                    return true;
                }
                at = bones[p].parent();
            }
            false
        };
        let limb_ends: Vec<String> = ends
            .iter()
            .filter(|&&a| !ends.iter().any(|&b| above(a, b)))
            .map(|&b| bones[b].name().to_string())
            .collect();
        for name in limb_ends.iter().take(MAX_EFFECTORS) {
            let _ = scene.effector(name);
        }
        scene
    }

    /// The skeleton.
    #[must_use]
    pub fn skeleton(&self) -> &Skeleton {
        &self.skel
    }

    /// Whether a clip is loaded.
    #[must_use]
    pub fn has_clip(&self) -> bool {
        !self.frames.is_empty()
    }

    /// The index of the effector on bone `name`, made one if it is not yet.
    ///
    /// # Errors
    /// [`SceneError::UnknownBone`], [`SceneError::TooHigh`], [`SceneError::TooMany`].
    pub fn effector(&mut self, name: &str) -> Result<usize, SceneError> {
        let skel = &self.skel;
        let bone = skel
            .find(name)
            .ok_or_else(|| SceneError::UnknownBone(name.to_string()))?;
        if let Some(k) = self.effectors.iter().position(|e| e.bone == bone) {
            return Ok(k);
        }
        if self.effectors.len() >= MAX_EFFECTORS {
            return Err(SceneError::TooMany);
        }
        let parent = skel.bones()[bone]
            .parent()
            .filter(|&p| skel.bones()[p].parent().is_some())
            .ok_or_else(|| SceneError::TooHigh(name.to_string()))?;
        let limb = Limb::new(skel, parent, bone, None).ok();
        let mask = if limb.is_some() {
            chain_mask(skel, parent, bone)
        } else {
            // Up the chain until six rotational DOFs or a bone hanging from the root.
            let mut mask = [false; MAX_BONES];
            let mut dofs = 0;
            let mut at = Some(bone);
            while let Some(k) = at.filter(|&k| skel.bones()[k].parent().is_some() && dofs < 6) {
                mask[k] = true;
                dofs += skel.bones()[k].dofs().iter().filter(|d| d.is_rotation()).count();
                at = skel.bones()[k].parent();
            }
            mask
        };
        self.effectors.push(Effector {
            bone,
            name: name.to_string(),
            limb,
            mask,
            target: None,
        });
        Ok(self.effectors.len() - 1)
    }

    /// The root's pose in the base frame against its rest: `(R, t)` with `world = R·(p − p₀) + t`.
    fn root_transform(&self) -> (DMat3, DVec3) {
        let mut pose = Pose64::default();
        fk64(&self.skel, &self.base, &mut pose);
        (pose.frame[0] * self.rest_root.1.transpose(), pose.start[0])
    }

    /// A point of the root's frame (as `follow`'s targets: the FK frame with the root at rest)
    /// in world coordinates of the present base frame.
    #[must_use]
    pub fn root_to_world(&self, p: DVec3) -> DVec3 {
        let (r, t) = self.root_transform();
        r * (p - self.rest_root.0) + t
    }

    /// The inverse of [`Scene::root_to_world`].
    #[must_use]
    pub fn world_to_root(&self, w: DVec3) -> DVec3 {
        let (r, t) = self.root_transform();
        r.transpose() * (w - t) + self.rest_root.0
    }

    /// Sets the target of effector `k` (world); `None` releases it to the clip.
    ///
    /// # Errors
    /// [`SceneError::NotFinite`].
    pub fn set_target(&mut self, k: usize, target: Option<DVec3>) -> Result<(), SceneError> {
        if target.is_some_and(|t| !t.is_finite()) {
            return Err(SceneError::NotFinite("position"));
        }
        if let Some(e) = self.effectors.get_mut(k) {
            e.target = target;
        }
        Ok(())
    }

    /// Pins effector `k` where its tip stands now.
    pub fn pin(&mut self, k: usize) {
        let tips = self.tips(&self.primary.channels);
        if let Some(e) = self.effectors.get_mut(k) {
            e.target = Some(tips[e.bone]);
        }
    }

    /// Chooses the driving method, and the compared one (`None`: no comparison).
    pub fn set_methods(&mut self, primary: IkMethod, compare: Option<IkMethod>) {
        if primary != self.primary.method {
            self.primary = Solved::new(primary, self.primary.channels.clone());
        }
        match (compare, &self.ghost) {
            (Some(m), Some(g)) if g.method == m => {}
            (Some(m), _) => self.ghost = Some(Solved::new(m, self.primary.channels.clone())),
            (None, _) => self.ghost = None,
        }
    }

    /// Sets the clip time (clamped, or wrapped when looping).
    ///
    /// # Errors
    /// [`SceneError::NoClip`], [`SceneError::NotFinite`].
    pub fn seek(&mut self, time: f64) -> Result<(), SceneError> {
        if self.frames.is_empty() {
            return Err(SceneError::NoClip);
        }
        if !time.is_finite() {
            return Err(SceneError::NotFinite("time"));
        }
        let d = self.timeline.duration;
        self.timeline.time = if self.timeline.looping && d > 0.0 {
            time.rem_euclid(d)
        } else {
            time.clamp(0.0, d)
        };
        self.update_base();
        Ok(())
    }

    /// Advances a playing clip by `dt` seconds of wall time; returns whether the pose changed.
    pub fn advance(&mut self, dt: f64) -> bool {
        if !self.timeline.playing || self.frames.is_empty() {
            return false;
        }
        let t = self.timeline.time + dt * self.timeline.speed;
        let d = self.timeline.duration;
        if !self.timeline.looping && t >= d {
            self.timeline.playing = false;
        }
        let _ = self.seek(t.min(if self.timeline.looping { f64::INFINITY } else { d }));
        true
    }

    /// The base pose at the timeline's time: the two frames around it blended linearly (they
    /// are 1/120 s apart).
    fn update_base(&mut self) {
        let x = self.timeline.time * self.frame_rate;
        let i = (x.floor().max(0.0) as usize).min(self.frames.len() - 1);
        let j = (i + 1).min(self.frames.len() - 1);
        let w = (x - i as f64).clamp(0.0, 1.0);
        for (k, b) in self.base.iter_mut().enumerate() {
            let (a, c) = (self.frames[i][k], self.frames[j][k]);
            *b = a + w * (c - a);
        }
    }

    /// Tips of every bone for `channels`.
    #[must_use]
    pub fn tips(&self, channels: &[f64]) -> Vec<DVec3> {
        let mut pose = Pose64::default();
        fk64(&self.skel, channels, &mut pose);
        pose.tip[..self.skel.bones().len()].to_vec()
    }

    /// The primary pose's forward kinematics (the human's world).
    #[must_use]
    pub fn pose64(&self) -> Pose64 {
        let mut pose = Pose64::default();
        fk64(&self.skel, &self.primary.channels, &mut pose);
        pose
    }

    /// Joint (start) and tip of every bone for `channels`.
    #[must_use]
    pub fn segments(&self, channels: &[f64]) -> Vec<(DVec3, DVec3)> {
        let mut pose = Pose64::default();
        fk64(&self.skel, channels, &mut pose);
        (0..self.skel.bones().len())
            .map(|b| (pose.start[b], pose.tip[b]))
            .collect()
    }

    /// Solves the primary method and the compared one from the base frame.
    pub fn solve(&mut self) {
        let mut primary = std::mem::replace(&mut self.primary, Solved::new(IkMethod::Dls, Vec::new()));
        self.solve_one(&mut primary);
        self.primary = primary;
        if let Some(mut g) = self.ghost.take() {
            self.solve_one(&mut g);
            self.ghost = Some(g);
        }
    }

    fn solve_one(&self, solved: &mut Solved) {
        let skel = &*self.skel;
        let started = Instant::now();
        // The base frame, with each targeted chain warm-started from the method's last pose.
        let mut channels = self.base.clone();
        let mut moved = [false; MAX_BONES];
        for e in self.effectors.iter().filter(|e| e.target.is_some()) {
            for (m, &b) in moved.iter_mut().zip(&e.mask) {
                *m |= b;
            }
        }
        if solved.channels.len() == channels.len() {
            for (_, bone) in skel.bones().iter().enumerate().filter(|(b, _)| moved[*b]) {
                for c in bone.channels() {
                    channels[c] = solved.channels[c];
                }
            }
        }
        if solved.solvers.len() != self.effectors.len() {
            solved.solvers = vec![None; self.effectors.len()];
        }
        let mut report = SolveReport {
            solver: solved.method.name(),
            ..SolveReport::default()
        };
        for (k, e) in self.effectors.iter().enumerate() {
            let Some(target) = e.target else {
                solved.swivel[k] = None;
                continue;
            };
            match (solved.method, &e.limb) {
                (IkMethod::Analytic, Some(limb)) => {
                    let swivel = match (self.swivel, solved.swivel[k]) {
                        (Some(fixed), _) => Swivel::Fixed(fixed),
                        (None, previous) => Swivel::Auto { previous },
                    };
                    let s = limb.solve(skel, &mut channels, target, swivel);
                    solved.swivel[k] = Some(s.swivel);
                    report.iterations += 1;
                    report.swivels.push((e.name.clone(), s.swivel.to_degrees()));
                }
                (method, _) => {
                    // A bone that ends no limb takes damped least squares under "analytic".
                    let numeric = method
                        .numeric()
                        .unwrap_or(crate::ik_numeric::Method::DampedLeastSquares);
                    let solver = solved.solvers[k].get_or_insert_with(|| Solver::new(skel, &e.mask, false));
                    let settings = Settings {
                        method: numeric,
                        max_iterations: MAX_ITERATIONS,
                        tolerance: TOLERANCE,
                        damping: 0.05,
                        // Warm-started from the last pose; a solve stalled against the limits
                        // starts over (limit-box centre, then seeded points) rather than stay.
                        restarts: RESTARTS,
                        patience: PATIENCE,
                        ..Settings::default()
                    };
                    let before = channels.clone();
                    let o = solver.solve(
                        skel,
                        &[Constraint {
                            bone: e.bone,
                            position: target,
                            axes: None,
                        }],
                        &mut channels,
                        &settings,
                    );
                    if channels.iter().any(|c| !c.is_finite()) {
                        channels = before;
                    }
                    report.iterations += o.iterations;
                }
            }
        }
        if channels.iter().any(|c| !c.is_finite()) {
            // Never a NaN pose: keep the base.
            channels.clone_from(&self.base);
        }
        let tips = self.tips(&channels);
        report.residual = self
            .effectors
            .iter()
            .filter_map(|e| e.target.map(|t| (tips[e.bone] - t).length()))
            .fold(0.0, f64::max);
        report.micros = started.elapsed().as_secs_f64() * 1e6;
        solved.channels = channels;
        solved.report = report;
    }

    /// The swivel circle of effector `k`'s limb at the primary pose, every 5°: where the elbow
    /// would be and whether the limb is then within its limits (the legal arcs). Empty when
    /// the effector ends no analytic limb.
    #[must_use]
    pub fn swivel_circle(&self, k: usize) -> Vec<SwivelPoint> {
        let Some(e) = self.effectors.get(k) else {
            return Vec::new();
        };
        let Some(limb) = &e.limb else {
            return Vec::new();
        };
        let tips = self.tips(&self.primary.channels);
        let target = e.target.unwrap_or(tips[e.bone]);
        let mut pose = Pose64::default();
        (0..72)
            .map(|i| {
                let deg = f64::from(i) * 5.0 - 180.0;
                let mut c = self.primary.channels.clone();
                let s = limb.solve(&self.skel, &mut c, target, Swivel::Fixed(deg.to_radians()));
                fk64(&self.skel, &c, &mut pose);
                let p = pose.start[limb.lower];
                SwivelPoint {
                    deg,
                    elbow: p.to_array(),
                    legal: s.upper_within_limits && s.elbow_within_limits,
                }
            })
            .collect()
    }

    /// The shoulder's (hip's) limit region of effector `k`'s limb: where the upper bone's tip
    /// can go with its angles inside their ASF limits (a grid of 9 per rotational DOF), at the
    /// primary pose. Empty when the effector ends no analytic limb.
    #[must_use]
    pub fn limit_region(&self, k: usize) -> Vec<[f64; 3]> {
        let Some(limb) = self.effectors.get(k).and_then(|e| e.limb.as_ref()) else {
            return Vec::new();
        };
        let bone = &self.skel.bones()[limb.upper];
        let rot: Vec<(usize, (f64, f64))> = bone
            .dofs()
            .iter()
            .zip(bone.channels())
            .zip(bone.limits())
            .filter(|((d, _), _)| d.is_rotation())
            .map(|((_, c), l)| {
                // Limits are radians; an unlimited DOF is drawn over one turn.
                let lo = f64::from(l.min).max(-std::f64::consts::PI);
                let hi = f64::from(l.max).min(std::f64::consts::PI);
                (c, (lo, hi))
            })
            .collect();
        const STEPS: usize = 9;
        let total = STEPS.pow(rot.len() as u32);
        let mut channels = self.primary.channels.clone();
        let mut pose = Pose64::default();
        let mut points = Vec::with_capacity(total);
        for mut i in 0..total {
            for &(c, (lo, hi)) in &rot {
                let s = (i % STEPS) as f64 / (STEPS - 1) as f64;
                channels[c] = lo + s * (hi - lo);
                i /= STEPS;
            }
            fk64(&self.skel, &channels, &mut pose);
            points.push(pose.tip[limb.upper].to_array());
        }
        points
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::formats::asf;

    fn scene() -> Scene {
        let skel = asf::parse(include_str!("../../data/cmu/16.asf"))
            .unwrap()
            .skeleton;
        Scene::new(Arc::new(skel), None)
    }

    #[test]
    fn the_limb_ends_are_effectors_and_every_method_reaches_a_reachable_target() {
        let mut s = scene();
        let names: Vec<&str> = s.effectors.iter().map(|e| e.name.as_str()).collect();
        for n in ["lradius", "rradius", "ltibia", "rtibia"] {
            assert!(names.contains(&n), "{names:?}");
        }
        let k = s.effector("lradius").unwrap();
        let tip = s.tips(&s.primary.channels)[s.effectors[k].bone];
        let upper = s.effectors[k].limb.as_ref().unwrap().upper;
        let shoulder = s.segments(&s.primary.channels)[upper].0;
        // Three quarters of the way out, and a little up and forward: bent, within reach.
        let goal = shoulder + (tip - shoulder) * 0.75 + DVec3::new(0.0, 2.0, 1.0);
        s.set_target(k, Some(goal)).unwrap();
        for m in IkMethod::ALL {
            s.set_methods(m, None);
            for _ in 0..5 {
                s.solve();
            }
            assert!(s.primary.report.residual < 1e-3, "{m:?}: {:?}", s.primary.report);
            assert_eq!(s.primary.report.solver, m.name());
        }
    }

    #[test]
    fn a_pinned_foot_stays_planted_while_the_clip_plays_and_the_rest_follows_it() {
        let skel = asf::parse(include_str!("../../data/cmu/16.asf"))
            .unwrap()
            .skeleton;
        let clip = crate::formats::amc::parse(&skel, include_str!("../../data/cmu/16_15.amc")).unwrap();
        let mut s = Scene::new(Arc::new(skel), Some(&clip));
        assert!(s.has_clip());
        s.seek(0.5).unwrap();
        s.solve();
        // The stance foot (the lower one) at 0.5 s of the walk.
        let (l, r) = (s.effector("ltibia").unwrap(), s.effector("rtibia").unwrap());
        let tips = s.tips(&s.primary.channels);
        let foot = if tips[s.effectors[l].bone].y < tips[s.effectors[r].bone].y {
            l
        } else {
            r
        };
        let hand = s.effector("rradius").unwrap();
        let bone = s.effectors[foot].bone;
        s.pin(foot);
        let planted = s.effectors[foot].target.unwrap();
        s.timeline.playing = true;
        let mut hand_path = Vec::new();
        for k in 0..15 {
            assert!(s.advance(1.0 / 60.0));
            s.solve();
            let tips = s.tips(&s.primary.channels);
            let slid = (tips[bone] - planted).length();
            assert!(slid < 1e-3, "the pinned foot slid {slid} units at frame {k}");
            hand_path.push(tips[s.effectors[hand].bone]);
        }
        assert!((s.timeline.time - 0.75).abs() < 1e-9);
        let travel = (hand_path[14] - hand_path[0]).length();
        assert!(travel > 1.0, "the free hand follows the clip ({travel} units)");
        // Looping wraps; stopped at the end without it.
        s.seek(s.timeline.duration + 0.25).unwrap();
        assert!((s.timeline.time - 0.25).abs() < 1e-9);
        s.timeline.looping = false;
        s.seek(s.timeline.duration - 0.01).unwrap();
        s.advance(1.0);
        assert!(!s.timeline.playing);
        assert!((s.timeline.time - s.timeline.duration).abs() < 1e-9);
    }

    #[test]
    fn root_frame_round_trips_and_bad_targets_are_refused() {
        let mut s = scene();
        let p = DVec3::new(1.0, 2.0, 3.0);
        assert!((s.world_to_root(s.root_to_world(p)) - p).length() < 1e-12);
        assert_eq!(
            s.set_target(0, Some(DVec3::new(f64::NAN, 0.0, 0.0))),
            Err(SceneError::NotFinite("position"))
        );
        assert!(matches!(s.effector("nose"), Err(SceneError::UnknownBone(_))));
        assert!(matches!(s.effector("lhipjoint"), Err(SceneError::TooHigh(_))));
        assert_eq!(s.seek(1.0), Err(SceneError::NoClip));
    }

    #[test]
    fn an_unreachable_target_gives_the_closest_pose_never_nan() {
        let mut s = scene();
        let k = s.effector("rtibia").unwrap();
        s.set_target(k, Some(DVec3::new(500.0, -300.0, 200.0))).unwrap();
        for m in IkMethod::ALL {
            s.set_methods(m, Some(IkMethod::Ccd));
            s.solve();
            assert!(s.primary.channels.iter().all(|c| c.is_finite()), "{m:?}");
            assert!(s.primary.report.residual.is_finite());
            assert!(s.primary.report.residual > 100.0);
        }
    }

    #[test]
    fn the_swivel_circle_has_legal_and_illegal_arcs_and_the_region_is_round_the_shoulder() {
        let mut s = scene();
        let k = s.effector("lradius").unwrap();
        let circle = s.swivel_circle(k);
        assert_eq!(circle.len(), 72);
        assert!(circle.iter().any(|p| p.legal));
        assert!(circle.iter().any(|p| !p.legal));
        let region = s.limit_region(k);
        assert_eq!(region.len(), 729);
        let upper = s.effectors[k].limb.as_ref().unwrap().upper;
        let len = f64::from(s.skeleton().bones()[upper].length());
        let start = s.segments(&s.primary.channels)[upper].0;
        for p in region {
            assert!(((DVec3::from_array(p) - start).length() - len).abs() < 1e-6);
        }
    }
}
