//! Walking on the robot's own feet, planned for a whole clip.
//!
//! 1. The clip is retargeted kinematically ([`retarget_clip`]): its planted feet and soles.
//! 2. Those become the robot's footsteps ([`FootstepPlanner`]): the clip's steps relative to
//!    the stance foot, within the robot's reach and speed ([`Retargeter::step_limits`]),
//!    flights and short double supports substituted.
//! 3. The footsteps give a ZMP reference ([`zmp_reference`]); Kajita's preview controller on
//!    the cart-table model ([`PreviewGains`]) gives the centre of mass that keeps the ZMP on
//!    it, at the clip's frame period, previewing [`PREVIEW_S`].
//! 4. A second retargeting pass ([`Retargeter::step_on_plan`]) puts the soles on the plan
//!    (a swing foot lifts [`Retargeter::swing_clearance`] and lands flat, minimum jerk along
//!    the floor) and the robot's centre of mass, all its links' masses counted, over the
//!    planned one; arms and head follow the human as before.
//!
//! The plan's own measures: where the cart-table's ZMP is against the support polygon of the
//! feet on the floor (its margin), how far the plan travels, which steps were substituted.

use glam::DVec2;
use serde::Serialize;

use super::{retarget_clip, ClipRetarget, Options, PlannedStance, RetargetFrame, Setup};
use crate::footstep::{contact, zmp_reference, Footprint, Footstep, FootstepPlanner, StepLimits};
use crate::motion::Motion;
use crate::preview::{AxisState, PreviewError, PreviewGains, MAX_PREVIEW};
use crate::skeleton::Skeleton;
use marionette_core::retarget::{convex_hull, polygon_margin, Retargeter};

/// How long a walk holds the clip's last frame after it, s: the centre of mass, still moving
/// when a walking clip ends, comes to rest between the feet (the preview's time constant is a
/// few tenths of a second).
pub const SETTLE_S: f64 = 1.0;

/// `motion` with its last frame held [`SETTLE_S`] longer: what a walk plans and plays.
#[must_use]
pub fn settled(motion: &Motion) -> Motion {
    let mut out = motion.clone();
    if let Some(last) = motion.frames().last().map(<[f64]>::to_vec) {
        for _ in 0..(SETTLE_S * motion.frame_rate).round() as usize {
            out.push_frame(&last);
        }
    }
    out
}

/// How far ahead the preview controller sees, s (ROBOTIS's online walking module: 1.6 s).
pub const PREVIEW_S: f64 = 1.6;

/// A leg's speed when no servo of the profile drives a leg joint with a velocity limit, rad/s
/// (an XM430-W350's no-load speed at 12 V, 46 rpm).
pub const DEFAULT_LEG_SPEED: f64 = 4.8;

/// The share of the slowest leg servo's velocity limit that footsteps are planned for: the
/// rest is left for what the plan does not see (the swing knee's peak beyond the foot's mean
/// speed, servos slower or weaker than their profile, the feedback's corrections).
pub const STEP_SPEED_SHARE: f64 = 0.7;

/// Standing before the clip's first frame, s: the centre of mass settles over the feet and
/// the preview sees the first step coming.
pub const LEAD_IN_S: f64 = 1.0;

/// The most of its length a leg stretches to on a plan: the base walks at one height, low
/// enough that the longest step keeps the knees bent (about 43°), away from the straight
/// leg where the knee's speed grows without bound and its torque for a given load with it.
pub const WALK_REACH_SHARE: f64 = 0.93;

/// How much lower than the lowest the whole-body pass had to put it the base walks when the
/// plan's first estimate left a foot out of reach, m.
pub const REACH_MARGIN_M: f64 = 0.002;

/// Most plans made for one clip while lowering the base to reach.
const REACH_ATTEMPTS: usize = 4;

/// Most plans made for one clip while lowering swings that ask a leg servo for more than its
/// speed (the knee lifting the foot is the fastest joint of a swing).
const PACE_ATTEMPTS: usize = 6;

/// How much lower the base walks for a swing still faster than its leg's servos at its lowest
/// lift, m.
const PACE_BASE_STEP_M: f64 = 0.005;

/// The lowest share of the foot's speed limit a swing is slowed to for its leg's speed.
pub const MIN_FOOT_SPEED_SHARE: f64 = 0.3;

/// The lowest share of [`Retargeter::swing_clearance`] a swing is lowered to for its leg's
/// speed: below it the foot would scuff the floor, and the swing is left faster than the
/// servos (and counted in the report's continuity).
pub const MIN_CLEARANCE_SHARE: f64 = 0.5;

/// One sample of the plan, at a clip frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlanSample {
    /// Seconds from the clip's start.
    pub t: f64,
    /// The ZMP reference from the footsteps.
    pub zmp_ref: DVec2,
    /// The cart-table's ZMP of the planned centre of mass.
    pub zmp: DVec2,
    /// Signed distance of that ZMP inside the support polygon, m (negative: outside).
    pub zmp_margin: f64,
    /// The ZMP of the whole robot moving as planned, every link counted ([`multibody_zmp`]).
    pub zmp_multibody: DVec2,
    /// Its signed distance inside the support polygon, m.
    pub zmp_multibody_margin: f64,
    /// Where the soles go and where the centre of mass is.
    pub stance: PlannedStance,
}

/// A clip's walking plan.
#[derive(Clone, Debug)]
pub struct WalkPlan {
    /// The footsteps (the first two: the feet where they start).
    pub footsteps: Vec<Footstep>,
    /// The limits they were planned within.
    pub limits: StepLimits,
    /// Half length and half width of each sole, m.
    pub sole_half: [[f64; 2]; 2],
    /// Height of the centre of mass the cart-table model assumes, m.
    pub com_height: f64,
    /// Frame period, s.
    pub dt: f64,
    /// One per clip frame.
    pub samples: Vec<PlanSample>,
    /// Steps changed from the clip's, and the clip's steps left out.
    pub substituted: (u32, u32),
    /// The slowest leg servo's velocity limit the plan used, rad/s.
    pub leg_speed: f64,
    /// The clip's own travel: its pelvis (scaled to the robot), start to end, m.
    pub clip_travel_m: f64,
    /// How high a swing foot lifts at most, m.
    pub clearance: f64,
    /// The swings paced for the leg servos' speed.
    pub pace: SwingPace,
}

/// What a plan made again changes for the swings whose legs were too slow for them, each by
/// the clip time its step lands (the same in every plan of a clip).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SwingPace {
    /// (landing, share of [`Retargeter::swing_clearance`]): lifted lower.
    pub clearance: Vec<(f64, f64)>,
    /// (landing, share of the foot's speed limit): a slower swing, the step shorter or lifted
    /// earlier ([`FootstepPlanner::pace_step`]).
    pub speed: Vec<(f64, f64)>,
}

impl SwingPace {
    /// The share of the clearance of the swing that lands at `land_s`.
    #[must_use]
    pub fn clearance_at(&self, land_s: f64) -> f64 {
        share_at(&self.clearance, land_s)
    }

    /// The share of the foot's speed limit of the swing that lands at `land_s`.
    #[must_use]
    pub fn speed_at(&self, land_s: f64) -> f64 {
        share_at(&self.speed, land_s)
    }

    /// Paces every swing whose leg moved faster than its servos (a ratio over 1 in `ratios`,
    /// from [`swing_speed_ratios`]): first lifted lower by the square of the excess (and 2 %
    /// more) — the knee's speed grows with the lift — down to [`MIN_CLEARANCE_SHARE`]; then
    /// slower along the floor by the excess, down to [`MIN_FOOT_SPEED_SHARE`]. Whether any
    /// swing changed.
    pub fn slow_down(&mut self, ratios: &[(f64, f64)]) -> bool {
        let mut changed = false;
        for &(land, r) in ratios {
            if r <= 1.0 {
                continue;
            }
            // A hair further, so that a swing at its limit to the printed digit ends within it.
            let r = r / 0.98;
            let lift = self.clearance_at(land);
            let speed = self.speed_at(land);
            if lift > MIN_CLEARANCE_SHARE {
                set_share(
                    &mut self.clearance,
                    land,
                    (lift / (r * r)).max(MIN_CLEARANCE_SHARE),
                );
                changed = true;
            } else if speed > MIN_FOOT_SPEED_SHARE {
                set_share(&mut self.speed, land, (speed / r).max(MIN_FOOT_SPEED_SHARE));
                changed = true;
            }
        }
        changed
    }
}

fn share_at(list: &[(f64, f64)], land_s: f64) -> f64 {
    list.iter().find(|p| p.0 == land_s).map_or(1.0, |p| p.1)
}

fn set_share(list: &mut Vec<(f64, f64)>, land_s: f64, share: f64) {
    match list.iter_mut().find(|p| p.0 == land_s) {
        Some(p) => p.1 = share,
        None => list.push((land_s, share)),
    }
}

/// The plan's figures (the `walk` block of a retarget report).
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct WalkReport {
    /// Steps the robot takes (the starting feet not counted).
    pub footsteps: usize,
    /// Steps changed from the clip's (flight, short double support, reach, speed).
    pub substituted_steps: u32,
    /// The clip's steps the robot leaves out (the foot stays down).
    pub dropped_steps: u32,
    /// Horizontal distance of the planned centre of mass, start to end, m.
    pub planned_travel_m: f64,
    /// The clip's own travel (its pelvis, scaled to the robot), m.
    pub clip_travel_m: f64,
    /// The planned ZMP inside the support polygon: the smallest margin over the clip, mm.
    pub zmp_margin_mm: PlannedMargin,
    /// Largest distance of the planned ZMP from its reference, mm.
    pub zmp_tracking_max_mm: f64,
    /// Height of the centre of mass the cart-table model assumes, m.
    pub com_height_m: f64,
    /// Preview, s.
    pub preview_s: f64,
    /// How high a swing foot lifts, mm.
    pub clearance_mm: f64,
    /// Swings lifted lower than that for the servos' speed.
    pub lowered_swings: usize,
    /// The lowest swing's clearance, mm.
    pub lowest_clearance_mm: f64,
    /// Swings slowed along the floor (shorter, or lifted earlier) for the servos' speed.
    pub slowed_swings: usize,
    /// The slowest swing's share of the foot's speed limit.
    pub slowest_foot_speed_share: f64,
    /// The limits steps were planned within.
    pub limits: LimitsReport,
    /// Every footstep: the plan's and the clip's.
    #[serde(rename = "footstep_plan")]
    pub footstep_list: Vec<FootstepReport>,
}

/// One footstep in a report.
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct FootstepReport {
    /// `left` or `right`.
    pub side: &'static str,
    /// Lands, s.
    pub land_s: f64,
    /// Lifts, s (null: stays to the end).
    pub lift_s: Option<f64>,
    /// Where the robot puts it: sole centre x, y (m) and heading (deg).
    pub at: [f64; 3],
    /// Where the clip put it.
    pub clip: [f64; 3],
    /// What was changed: `flight`, `short_double_support`, `too_long`, `too_fast`,
    /// `early_lift`.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub changed: Vec<&'static str>,
}

impl From<&Footstep> for FootstepReport {
    fn from(s: &Footstep) -> FootstepReport {
        let print = |p: &Footprint| [p.centre.x, p.centre.y, p.yaw.to_degrees()];
        let c = s.changed;
        FootstepReport {
            side: marionette_core::retarget::SIDES[s.side],
            land_s: s.land_s,
            lift_s: s.lift_s.is_finite().then_some(s.lift_s),
            at: print(&s.at),
            clip: print(&s.clip),
            changed: [
                (c.flight, "flight"),
                (c.short_double_support, "short_double_support"),
                (c.too_long, "too_long"),
                (c.too_fast, "too_fast"),
                (c.early_lift, "early_lift"),
            ]
            .iter()
            .filter(|(on, _)| *on)
            .map(|(_, name)| *name)
            .collect(),
        }
    }
}

/// The smallest planned margin.
#[derive(Clone, Copy, Debug, Default, Serialize, PartialEq)]
pub struct PlannedMargin {
    /// Planned (the cart-table's ZMP), mm.
    pub planned_min: f64,
    /// The whole robot's ZMP moving as planned, every link counted, mm.
    pub multibody_min: f64,
}

/// [`StepLimits`] for a report, metres, degrees, seconds.
#[derive(Clone, Copy, Debug, Default, Serialize, PartialEq)]
pub struct LimitsReport {
    /// Farthest forward.
    pub forward_m: f64,
    /// Farthest backward.
    pub backward_m: f64,
    /// Narrowest between soles' centres.
    pub width_min_m: f64,
    /// Widest.
    pub width_max_m: f64,
    /// Largest turn.
    pub turn_deg: f64,
    /// Shortest swing.
    pub swing_min_s: f64,
    /// The swing foot's mean speed at most.
    pub foot_speed_m_s: f64,
    /// Shortest double support.
    pub double_support_s: f64,
}

impl From<StepLimits> for LimitsReport {
    fn from(l: StepLimits) -> LimitsReport {
        LimitsReport {
            forward_m: l.forward,
            backward_m: l.backward,
            width_min_m: l.width_min,
            width_max_m: l.width_max,
            turn_deg: l.turn.to_degrees(),
            swing_min_s: l.swing_min_s,
            foot_speed_m_s: l.foot_speed,
            double_support_s: l.double_support_s,
        }
    }
}

/// The slowest velocity limit (rad/s) of the servos that drive a leg joint.
#[must_use]
pub fn leg_speed(setup: &Setup) -> f64 {
    let limits = setup.joint_speed_limits();
    setup
        .map
        .legs
        .iter()
        .flat_map(|l| l.joints)
        .filter_map(|j| limits.get(j).copied())
        .fold(f64::INFINITY, f64::min)
}

/// A walking plan for `run`, a clip retargeted kinematically by `retargeter`'s setup.
///
/// # Errors
/// The preview controller cannot be designed for this clip's frame period (a rate outside
/// what [`MAX_PREVIEW`] samples over [`PREVIEW_S`] allow) or the robot's centre-of-mass height.
pub fn plan_walk(
    setup: &Setup,
    retargeter: &Retargeter,
    run: &ClipRetarget,
    highest_base: f64,
    pace: &SwingPace,
) -> Result<WalkPlan, PreviewError> {
    let speed = leg_speed(setup);
    let limits = retargeter.step_limits(
        STEP_SPEED_SHARE
            * if speed.is_finite() {
                speed
            } else {
                DEFAULT_LEG_SPEED
            },
    );
    let dt = frame_period(run);
    let mut planner = start_planner(setup, retargeter, run, limits);
    for &(land, share) in &pace.speed {
        planner.pace_step(land, share);
    }
    let mut footsteps: Vec<Footstep> = Vec::new();
    for (t, f) in run.times.iter().zip(&run.frames) {
        planner.observe(*t, f.planted, footprints(f));
        keep_steps(&planner, &mut footsteps);
    }
    stand_at_the_end(&mut footsteps);
    let end = run.times.last().copied().unwrap_or(0.0);
    let shift = limits.zmp_shift_s;
    let reference = |t: f64| {
        let t = t.clamp(0.0, end.max(0.0) + 10.0);
        zmp_reference(&footsteps, t, shift).unwrap_or(DVec2::ZERO)
    };
    let frames = run.frames.len();
    // The stance's height first; then as high as every planned step lets the legs reach
    // within WALK_REACH_SHARE (no lower than the stance), the cart-table at that height.
    let (stance_base, stance_com) = retargeter.stance_heights(&setup.robot);
    let clearance = retargeter.swing_clearance();
    let first = preview_com(dt, stance_com, frames, &reference)?;
    let base_height = first
        .iter()
        .enumerate()
        .map(|(k, (c, _))| {
            let t = k as f64 * dt;
            let stance = stance_at(&footsteps, t, (*c, *c), clearance, &pace.clearance, f64::NAN);
            retargeter.reach_height(&setup.robot, &stance, WALK_REACH_SHARE)
        })
        .fold(stance_base.min(highest_base), f64::min);
    let com_height = stance_com - (stance_base - base_height);
    let com = if base_height < stance_base {
        preview_com(dt, com_height, frames, &reference)?
    } else {
        first
    };
    let sole_half = setup.map.legs.map(|l| l.sole_half);
    let samples = (0..frames)
        .map(|k| {
            let t = k as f64 * dt;
            let (c, zmp) = com[k];
            PlanSample {
                t,
                zmp_ref: reference(t),
                zmp,
                zmp_margin: support_margin(&footsteps, t, sole_half, zmp),
                zmp_multibody: zmp,
                zmp_multibody_margin: f64::NAN,
                stance: stance_at(&footsteps, t, (c, zmp), clearance, &pace.clearance, base_height),
            }
        })
        .collect();
    let pelvis = |f: &RetargetFrame| DVec2::new(f.base_pos.x, f.base_pos.y);
    let clip_travel_m = match (run.frames.first(), run.frames.last()) {
        (Some(a), Some(b)) => (pelvis(b) - pelvis(a)).length(),
        _ => 0.0,
    };
    Ok(WalkPlan {
        clip_travel_m,
        footsteps,
        limits,
        sole_half,
        com_height,
        dt,
        samples,
        substituted: planner.substituted(),
        leg_speed: speed,
        clearance,
        pace: pace.clone(),
    })
}

/// The frame period of a retargeted clip, s.
fn frame_period(run: &ClipRetarget) -> f64 {
    run.times.get(1).map_or(1.0 / 120.0, |t| t - run.times[0])
}

/// A footstep planner within `limits`, the robot starting in its stance centred where the
/// clip's first feet are and facing their way.
fn start_planner(
    setup: &Setup,
    retargeter: &Retargeter,
    run: &ClipRetarget,
    limits: StepLimits,
) -> FootstepPlanner {
    let mut planner = FootstepPlanner::new(limits);
    if let Some(first) = run.frames.first() {
        let clip = footprints(first);
        let stance = retargeter.stance_soles(&setup.robot);
        let (from, to) = (midway(&stance), midway(&clip));
        let robot = stance.map(|s| {
            let (offset, turn) = from.relative(&s);
            to.moved(offset, turn)
        });
        planner.start(run.times[0], robot, clip);
    }
    planner
}

/// The planner's steps into `all` (by number: a step revised since replaces its old self).
fn keep_steps(planner: &FootstepPlanner, all: &mut Vec<Footstep>) {
    for s in planner.steps() {
        let n = s.number as usize;
        if n < all.len() {
            all[n] = *s;
        } else {
            all.push(*s);
        }
    }
}

/// A foot the clip lifts and does not put down again before it ends stays down: the robot
/// ends standing on both feet.
fn stand_at_the_end(footsteps: &mut [Footstep]) {
    for side in 0..2 {
        if let Some(last) = footsteps.iter_mut().rev().find(|s| s.side == side) {
            last.lift_s = f64::INFINITY;
        }
    }
}

/// The centre of mass a stream would plan for `run` with `window_s` of look-ahead: at each
/// frame the footstep planner has seen the clip only that far ahead, and the preview
/// controller (at `plan`'s height, frame period and lead-in) sees the ZMP reference of the
/// steps known so far, held at its last known value beyond them; once the window reaches the
/// clip's end the stream knows it ended (the feet stay down). One point per clip frame, to
/// compare with `plan`'s offline one: how long a live input's window must be.
///
/// # Errors
/// As [`plan_walk`].
pub fn streamed_com(
    setup: &Setup,
    retargeter: &Retargeter,
    run: &ClipRetarget,
    plan: &WalkPlan,
    window_s: f64,
) -> Result<Vec<DVec2>, PreviewError> {
    let dt = plan.dt;
    let frames = run.frames.len();
    let mut planner = start_planner(setup, retargeter, run, plan.limits);
    let mut footsteps: Vec<Footstep> = Vec::new();
    let window = (window_s / dt).round().max(0.0) as usize;
    let end = run.times.last().copied().unwrap_or(0.0);
    let shift = plan.limits.zmp_shift_s;
    let lead = (LEAD_IN_S / dt).round() as usize;
    let mut seen = 0;
    let path = preview_path(dt, plan.com_height, frames, |k| {
        // Frames seen by step k: those up to the window ahead of it.
        let upto = (k + window + 1).saturating_sub(lead).min(frames);
        while seen < upto {
            let f = &run.frames[seen];
            planner.observe(run.times[seen], f.planted, footprints(f));
            seen += 1;
        }
        keep_steps(&planner, &mut footsteps);
        let mut steps = footsteps.clone();
        let known = if seen == frames {
            stand_at_the_end(&mut steps);
            end + 10.0
        } else {
            run.times[seen.saturating_sub(1)]
        };
        move |t: f64| zmp_reference(&steps, t.clamp(0.0, known), shift).unwrap_or(DVec2::ZERO)
    })?;
    Ok(path.into_iter().map(|(com, _)| com).collect())
}

/// The preview controller's centre of mass and the cart-table's ZMP at each of `frames`
/// frames `dt` apart, for the ZMP reference `reference(t)` with the cart-table at
/// `com_height`: standing still for [`LEAD_IN_S`] first, previewing [`PREVIEW_S`].
fn preview_com(
    dt: f64,
    com_height: f64,
    frames: usize,
    reference: &impl Fn(f64) -> DVec2,
) -> Result<Vec<(DVec2, DVec2)>, PreviewError> {
    preview_path(dt, com_height, frames, |_| reference)
}

/// [`preview_com`] with the reference as known at each step: `reference_at(k)` is the ZMP
/// reference (a function of time) the controller sees at its `k`-th step, the lead-in's
/// steps first.
fn preview_path<R: Fn(f64) -> DVec2>(
    dt: f64,
    com_height: f64,
    frames: usize,
    mut reference_at: impl FnMut(usize) -> R,
) -> Result<Vec<(DVec2, DVec2)>, PreviewError> {
    let samples_ahead = ((PREVIEW_S / dt).round() as usize).clamp(1, MAX_PREVIEW);
    let gains = PreviewGains::design(dt, com_height, samples_ahead)?;
    let start = reference_at(0)(0.0);
    let mut axes = [AxisState::at(start.x), AxisState::at(start.y)];
    let lead = (LEAD_IN_S / dt).round() as usize;
    let mut com = Vec::with_capacity(frames);
    for k in 0..lead + frames {
        let t = (k as f64 - lead as f64) * dt;
        if k >= lead {
            com.push((
                DVec2::new(axes[0].x[0], axes[1].x[0]),
                DVec2::new(axes[0].zmp(com_height), axes[1].zmp(com_height)),
            ));
        }
        let reference = reference_at(k);
        let now = reference(t);
        for (axis, state) in axes.iter_mut().enumerate() {
            state.step(&gains, now[axis], |j| reference(t + j as f64 * dt)[axis]);
        }
    }
    Ok(com)
}

/// Half way between two footprints, facing between their headings.
fn midway(feet: &[Footprint; 2]) -> Footprint {
    Footprint {
        centre: (feet[0].centre + feet[1].centre) * 0.5,
        yaw: 0.5 * (feet[0].yaw + marionette_core::math::wrap_near(feet[1].yaw, feet[0].yaw)),
    }
}

/// The soles of a retargeted frame as footprints.
#[must_use]
pub fn footprints(f: &RetargetFrame) -> [Footprint; 2] {
    [0, 1].map(|side| Footprint {
        centre: DVec2::new(f.sole[side].x, f.sole[side].y),
        yaw: f.sole_yaw[side],
    })
}

/// Where the plan has each sole at `t`: on its footprint when in contact; in a swing,
/// minimum jerk along the floor from the footprint it left to the one it lands on and
/// lifted `clearance` (times the swing's `share`, by the clip time it lands) at
/// the middle (zero slope and curvature at both ends: it lands flat and soft); the centre of
/// mass and the ZMP as given, the base at `base_height`.
#[must_use]
pub fn stance_at(
    steps: &[Footstep],
    t: f64,
    (com, zmp): (DVec2, DVec2),
    clearance: f64,
    share: &[(f64, f64)],
    base_height: f64,
) -> PlannedStance {
    let mut soles = [(Footprint::default(), 0.0); 2];
    let mut on = [false; 2];
    for side in 0..2 {
        if let Some(s) = contact(steps, side, t) {
            soles[side] = (s.at, 0.0);
            on[side] = true;
            continue;
        }
        let left = steps.iter().rev().find(|s| s.side == side && s.lift_s <= t);
        let next = steps.iter().find(|s| s.side == side && s.land_s > t);
        soles[side] = match (left, next) {
            (Some(a), Some(b)) => {
                let s = ((t - a.lift_s) / (b.land_s - a.lift_s)).clamp(0.0, 1.0);
                let m = s * s * s * (10.0 - 15.0 * s + 6.0 * s * s);
                let turn = marionette_core::math::wrap_near(b.at.yaw - a.at.yaw, 0.0);
                let bump = 64.0 * (s * (1.0 - s)).powi(3);
                (
                    Footprint {
                        centre: a.at.centre + (b.at.centre - a.at.centre) * m,
                        yaw: a.at.yaw + turn * m,
                    },
                    clearance * share_at(share, b.land_s) * bump,
                )
            }
            (Some(a), None) => (a.at, 0.0),
            (None, Some(b)) => (b.at, 0.0),
            (None, None) => (Footprint::default(), 0.0),
        };
    }
    PlannedStance {
        soles,
        contact: on,
        com,
        base_height,
        zmp,
    }
}

/// Signed distance of `p` inside the support polygon of the feet on the floor at `t`, m.
#[must_use]
pub fn support_margin(steps: &[Footstep], t: f64, sole_half: [[f64; 2]; 2], p: DVec2) -> f64 {
    let mut corners = Vec::with_capacity(8);
    for (side, half) in sole_half.into_iter().enumerate() {
        if let Some(s) = contact(steps, side, t) {
            corners.extend(s.at.corners(half));
        }
    }
    polygon_margin(&convex_hull::<8>(&corners), p, 0.0).0
}

/// Writes the plan per frame as CSV: time, which feet bear weight, the ZMP reference, the
/// planned ZMP and its margin, the planned centre of mass (metres).
///
/// # Errors
/// Writing failed.
pub fn write_plan_csv(mut w: impl std::io::Write, plan: &WalkPlan) -> std::io::Result<()> {
    writeln!(
        w,
        "time,left_down,right_down,zmp_ref_x,zmp_ref_y,zmp_x,zmp_y,zmp_margin,com_x,com_y,com_z,zmp_multibody_x,zmp_multibody_y,zmp_multibody_margin"
    )?;
    for s in &plan.samples {
        writeln!(
            w,
            "{:.6},{},{},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6}",
            s.t,
            u8::from(s.stance.contact[0]),
            u8::from(s.stance.contact[1]),
            s.zmp_ref.x,
            s.zmp_ref.y,
            s.zmp.x,
            s.zmp.y,
            s.zmp_margin,
            s.stance.com.x,
            s.stance.com.y,
            plan.com_height,
            s.zmp_multibody.x,
            s.zmp_multibody.y,
            s.zmp_multibody_margin
        )?;
    }
    Ok(())
}

/// Retargets `motion` walking on the plan: the kinematic pass, the plan, and the pass on it.
///
/// # Errors
/// [`plan_walk`]'s.
pub fn retarget_walking(
    setup: &Setup,
    skeleton: &Skeleton,
    motion: &Motion,
    options: Options,
) -> Result<(ClipRetarget, WalkPlan), PreviewError> {
    // The clip's own feet, frame by frame: nothing paced or smoothed before the plan sees them.
    let kinematic = retarget_clip(
        setup,
        skeleton,
        motion,
        Options {
            per_frame: true,
            ..options
        },
    );
    let retargeter = setup.retargeter(skeleton, kinematic.floor, options);
    // The base's height from the plan's footsteps and centre of mass; lowered again where the
    // whole body's pass still found a foot out of the legs' reach. Then each swing that asks
    // its leg's servos for more than their speed lifted lower, and where that is not enough,
    // the whole walk lower.
    let mut highest = f64::INFINITY;
    let mut pace = SwingPace::default();
    let (mut reach_attempts, mut pace_attempts) = (0, 0);
    let (plan, walked) = loop {
        let plan = plan_walk(setup, &retargeter, &kinematic, highest, &pace)?;
        let walked = super::retarget_clip_with(setup, skeleton, motion, options, kinematic.floor, |k| {
            plan.samples.get(k).map(|s| s.stance)
        });
        let planned = plan.samples.first().map_or(0.0, |s| s.stance.base_height);
        let lowest = walked.frames.iter().map(|f| f.base_pos.z).fold(planned, f64::min);
        if lowest < planned - 1e-6 && reach_attempts < REACH_ATTEMPTS {
            reach_attempts += 1;
            highest = lowest - REACH_MARGIN_M;
            continue;
        }
        let over = swing_speed_ratios(setup, &plan, &walked.frames);
        if pace_attempts == PACE_ATTEMPTS {
            break (plan, walked);
        }
        if !pace.slow_down(&over) {
            if over.iter().all(|(_, r)| *r <= 1.0) {
                break (plan, walked);
            }
            // Swings at their lowest lift and speed still too fast: the whole walk lower,
            // the knees more bent.
            highest = planned - PACE_BASE_STEP_M;
        }
        pace_attempts += 1;
    };
    let zmp = multibody_zmp(setup, &retargeter, &walked.frames, plan.dt);
    let mut plan = plan;
    for (sample, z) in plan.samples.iter_mut().zip(zmp) {
        sample.zmp_multibody = z;
        sample.zmp_multibody_margin = support_margin(&plan.footsteps, sample.t, plan.sole_half, z);
    }
    Ok((walked, plan))
}

/// For each step the plan swings a foot to, (its landing, s; the most a joint of that leg
/// moves from the lift to a frame after the landing, as a share of its servo's velocity
/// limit).
#[must_use]
pub fn swing_speed_ratios(setup: &Setup, plan: &WalkPlan, frames: &[RetargetFrame]) -> Vec<(f64, f64)> {
    let limits = setup.joint_speed_limits();
    let dt = plan.dt;
    let mut ratios = Vec::new();
    for (i, b) in plan.footsteps.iter().enumerate() {
        let Some(a) = plan.footsteps[..i].iter().rev().find(|s| s.side == b.side) else {
            continue;
        };
        if !a.lift_s.is_finite() || !b.land_s.is_finite() {
            continue;
        }
        let first = ((a.lift_s / dt).floor() as usize).max(1);
        let last = ((b.land_s / dt).ceil() as usize + 1).min(frames.len().saturating_sub(1));
        let mut most = 0.0f64;
        for k in first..=last {
            for &j in &setup.map.legs[b.side].joints {
                let v = (frames[k].q[j] - frames[k - 1].q[j]).abs() / (limits[j] * dt);
                if v.is_finite() {
                    most = most.max(v);
                }
            }
        }
        ratios.push((b.land_s, most));
    }
    ratios
}

/// The ZMP of the whole robot moving through `frames` (one per `dt`), every link's mass
/// counted, each link a point mass (its rotational inertia left out):
/// p = Σ mᵢ((z̈ᵢ + g) pᵢ − p̈ᵢ zᵢ) / Σ mᵢ(z̈ᵢ + g), the floor at z = 0, accelerations by central
/// differences (the ends take their neighbour's).
#[must_use]
pub fn multibody_zmp(
    setup: &Setup,
    retargeter: &Retargeter,
    frames: &[RetargetFrame],
    dt: f64,
) -> Vec<DVec2> {
    const G: f64 = 9.81;
    let robot = &setup.robot;
    let bodies = robot.bodies();
    let mut pose = marionette_core::robot::RobotPose::default();
    let points: Vec<Vec<glam::DVec3>> = frames
        .iter()
        .map(|f| {
            let (pos, rot) = retargeter.model_placement(f.base_pos, f.base_rot);
            robot.forward(pos, rot, &f.q, &mut pose);
            bodies
                .iter()
                .enumerate()
                .map(|(i, b)| pose.pos[i] + pose.rot[i] * b.com)
                .collect()
        })
        .collect();
    let n = points.len();
    (0..n)
        .map(|k| {
            let k = k.clamp(1, n.saturating_sub(2).max(1));
            if n < 3 {
                let c = frames.get(k.min(n - 1)).map_or(glam::DVec3::ZERO, |f| f.com);
                return DVec2::new(c.x, c.y);
            }
            let (mut num, mut den) = (DVec2::ZERO, 0.0);
            for (i, b) in bodies.iter().enumerate() {
                let p = points[k][i];
                let a = (points[k + 1][i] - 2.0 * p + points[k - 1][i]) / (dt * dt);
                num += b.mass * ((a.z + G) * DVec2::new(p.x, p.y) - DVec2::new(a.x, a.y) * p.z);
                den += b.mass * (a.z + G);
            }
            num / den
        })
        .collect()
}

impl WalkPlan {
    /// The plan's figures.
    #[must_use]
    pub fn report(&self) -> WalkReport {
        let travel = |a: Option<DVec2>, b: Option<DVec2>| match (a, b) {
            (Some(a), Some(b)) => (b - a).length(),
            _ => 0.0,
        };
        let com = |s: &PlanSample| s.stance.com;
        WalkReport {
            footstep_list: self.footsteps.iter().map(FootstepReport::from).collect(),
            footsteps: self.footsteps.len().saturating_sub(2),
            substituted_steps: self.substituted.0,
            dropped_steps: self.substituted.1,
            planned_travel_m: travel(self.samples.first().map(com), self.samples.last().map(com)),
            clip_travel_m: self.clip_travel_m,
            zmp_margin_mm: PlannedMargin {
                planned_min: self
                    .samples
                    .iter()
                    .map(|s| s.zmp_margin * 1000.0)
                    .fold(f64::INFINITY, f64::min),
                multibody_min: self
                    .samples
                    .iter()
                    .map(|s| s.zmp_multibody_margin * 1000.0)
                    .filter(|m| m.is_finite())
                    .fold(f64::INFINITY, f64::min),
            },
            zmp_tracking_max_mm: self
                .samples
                .iter()
                .map(|s| (s.zmp - s.zmp_ref).length() * 1000.0)
                .fold(0.0, f64::max),
            com_height_m: self.com_height,
            preview_s: PREVIEW_S,
            clearance_mm: self.clearance * 1000.0,
            lowered_swings: self.pace.clearance.iter().filter(|s| s.1 < 1.0).count(),
            lowest_clearance_mm: self.pace.clearance.iter().fold(1.0, |a: f64, b| a.min(b.1))
                * self.clearance
                * 1000.0,
            slowed_swings: self.pace.speed.iter().filter(|s| s.1 < 1.0).count(),
            slowest_foot_speed_share: self.pace.speed.iter().fold(1.0, |a: f64, b| a.min(b.1)),
            limits: self.limits.into(),
        }
    }
}
