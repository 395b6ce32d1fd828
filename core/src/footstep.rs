//! Footsteps from a retargeted clip, and the ZMP reference they give.
//!
//! [`FootstepPlanner::observe`] takes, frame by frame, which feet the retargeted clip has
//! planted and where its soles are (centre on the floor, heading), and keeps the robot's own
//! plan: each landing becomes a [`Footstep`] (where, when it lands, when it lifts again). A
//! step is the clip's step *relative to the stance foot*, placed on the plan's stance foot,
//! so a step the robot had to change does not drag every later one with it. What the robot
//! cannot do is replaced by the nearest thing it can, and each such step says why
//! ([`Substitution`]):
//! * a **flight** (no foot on the floor: a run, a jump) — the foot that would lift into it
//!   stays planted until the other lands, then lifts after [`StepLimits::double_support_s`];
//! * a **double support too short** to shift the weight — the lift waits until the other foot
//!   has stood [`StepLimits::double_support_s`];
//! * a step **beyond reach** — clamped in the stance foot's frame (forward, backward, width,
//!   turn);
//! * a step **faster than the servos allow** — first given more time: the foot lifts earlier,
//!   taking up to half of the double support before its swing (never leaving less than
//!   [`StepLimits::double_support_s`], and never before the foot itself has stood that long);
//!   then, if that is not enough, shortened to what the swing's time allows at
//!   [`StepLimits::foot_speed`], or dropped (the foot stays) when the swing is shorter than
//!   [`StepLimits::swing_min_s`].
//!
//! A step may be changed after it was first planned (a lift cancelled when the swing turns
//! out too short), so a stream reads the plan a look-ahead behind the newest frame observed;
//! the look-ahead needed is the preview plus the longest swing.
//!
//! [`zmp_reference`] turns the plan into the ZMP path the preview controller
//! ([`crate::preview`]) follows: the sole's centre in single support; in double support a
//! smooth shift from the foot stood on before to the one stood on after, resting half way
//! when the double support is long (standing).

use crate::math::{real, Real, RealVec2};

/// Alternating projections at most when a step is both too fast and against a limit.
const FEASIBLE_ITERATIONS: usize = 32;

/// Footsteps a planner keeps (a stream forgets the ones it has played).
pub const MAX_FOOTSTEPS: usize = 64;

/// Most steps a plan gives a foot speed of their own ([`FootstepPlanner::pace_step`]).
pub const MAX_PACED_STEPS: usize = 32;

/// Where a sole is on the floor.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Footprint {
    /// The sole's centre, metres.
    pub centre: RealVec2,
    /// Its heading (the sole's long axis), radians about the vertical.
    pub yaw: Real,
}

impl Footprint {
    /// `offset` (x forward, y left, metres) and `turn` (radians) in this footprint's frame.
    #[must_use]
    pub fn moved(&self, offset: RealVec2, turn: Real) -> Footprint {
        let (s, c) = real::sincos(self.yaw);
        Footprint {
            centre: self.centre + RealVec2::new(c * offset.x - s * offset.y, s * offset.x + c * offset.y),
            yaw: crate::math::wrap_near(self.yaw + turn, 0.0),
        }
    }

    /// `other` in this footprint's frame: offset and turn.
    #[must_use]
    pub fn relative(&self, other: &Footprint) -> (RealVec2, Real) {
        let (s, c) = real::sincos(self.yaw);
        let d = other.centre - self.centre;
        (
            RealVec2::new(c * d.x + s * d.y, -s * d.x + c * d.y),
            crate::math::wrap_near(other.yaw - self.yaw, 0.0),
        )
    }

    /// The sole's corners (counter-clockwise), `half` its half length and half width.
    #[must_use]
    pub fn corners(&self, half: [Real; 2]) -> [RealVec2; 4] {
        [(1.0, 1.0), (-1.0, 1.0), (-1.0, -1.0), (1.0, -1.0)]
            .map(|(x, y)| self.moved(RealVec2::new(x * half[0], y * half[1]), 0.0).centre)
    }
}

/// Why a step of the plan is not the clip's.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Substitution {
    /// Its lift waited for the other foot to land (the clip had both feet in the air).
    pub flight: bool,
    /// Its lift waited until the other foot had stood long enough to take the weight.
    pub short_double_support: bool,
    /// Clamped to the reach in the stance foot's frame.
    pub too_long: bool,
    /// Shortened: the swing was too short for the distance at the servos' speed.
    pub too_fast: bool,
    /// Lifted earlier than the clip's foot, out of the double support before the swing, to
    /// give the swing the time its distance needs at the servos' speed.
    pub early_lift: bool,
}

impl Substitution {
    /// Whether anything was changed.
    #[must_use]
    pub fn any(&self) -> bool {
        self.flight || self.short_double_support || self.too_long || self.too_fast || self.early_lift
    }
}

/// One footstep of the plan.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Footstep {
    /// Its number in the plan (0 and 1: the feet where they start).
    pub number: u32,
    /// 0 left, 1 right.
    pub side: usize,
    /// Where the robot puts the foot.
    pub at: Footprint,
    /// Where the clip put it.
    pub clip: Footprint,
    /// When it lands, s.
    pub land_s: Real,
    /// When it lifts again, s (infinite: not yet).
    pub lift_s: Real,
    /// What was changed from the clip.
    pub changed: Substitution,
}

impl Footstep {
    /// Whether the foot is on the floor at `t`.
    #[must_use]
    pub fn in_contact(&self, t: Real) -> bool {
        self.land_s <= t && t < self.lift_s
    }
}

/// What the robot's feet can do, in the stance foot's frame (x forward, y towards the
/// swing foot's side), metres, radians, seconds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepLimits {
    /// Farthest forward from the stance foot.
    pub forward: Real,
    /// Farthest backward.
    pub backward: Real,
    /// Narrowest sideways distance between the soles' centres (the soles must not touch).
    pub width_min: Real,
    /// Widest.
    pub width_max: Real,
    /// Largest turn of a step against the stance foot.
    pub turn: Real,
    /// Shortest swing: time to lift the foot clear and put it down again.
    pub swing_min_s: Real,
    /// The swing foot's mean horizontal speed at most, m/s.
    pub foot_speed: Real,
    /// Shortest double support: a foot lifts only this long after the other landed (the
    /// weight must shift); inserted where the clip has a flight.
    pub double_support_s: Real,
    /// Time the ZMP takes to shift from one foot to the middle in a long double support.
    pub zmp_shift_s: Real,
}

/// Builds the robot's footstep plan from a clip, frame by frame, in fixed capacity.
#[derive(Clone, Debug)]
pub struct FootstepPlanner {
    limits: StepLimits,
    steps: heapless::Vec<Footstep, MAX_FOOTSTEPS>,
    /// Steps planned with a share of [`StepLimits::foot_speed`]: (the clip's landing, share).
    paced: heapless::Vec<(Real, Real), MAX_PACED_STEPS>,
    next_number: u32,
    started: bool,
    /// The clip's planted feet at the previous frame.
    clip_planted: [bool; 2],
    /// The clip's last landing of each foot.
    clip_last: [Footprint; 2],
    /// The plan's feet on the floor.
    planted: [bool; 2],
    /// The plan's swinging foot: when it lifted and from where.
    swing: [(Real, Footprint); 2],
    /// A lift the clip made while the other foot was in the air, waiting for its landing.
    waiting: [bool; 2],
    /// A deferred lift's time, once the other foot has landed.
    lift_due: [Option<Real>; 2],
    /// What the next step of each foot inherits from a delayed lift.
    carry: [Substitution; 2],
    substituted: u32,
    dropped: u32,
}

impl FootstepPlanner {
    /// An empty plan.
    #[must_use]
    pub fn new(limits: StepLimits) -> FootstepPlanner {
        FootstepPlanner {
            limits,
            steps: heapless::Vec::new(),
            paced: heapless::Vec::new(),
            next_number: 0,
            started: false,
            clip_planted: [true; 2],
            clip_last: [Footprint::default(); 2],
            planted: [true; 2],
            swing: [(0.0, Footprint::default()); 2],
            waiting: [false; 2],
            lift_due: [None; 2],
            carry: [Substitution::default(); 2],
            substituted: 0,
            dropped: 0,
        }
    }

    /// The limits it plans within.
    #[must_use]
    pub fn limits(&self) -> &StepLimits {
        &self.limits
    }

    /// Plans the step the clip lands at `land_s` with `share` of [`StepLimits::foot_speed`]
    /// (a slower swing: the step shortened, or lifted earlier), for a plan made again after
    /// that swing asked its leg for more than its servos' speed. False when
    /// [`MAX_PACED_STEPS`] steps are paced already.
    pub fn pace_step(&mut self, land_s: Real, share: Real) -> bool {
        let share = if share.is_finite() {
            share.clamp(1e-3, 1.0)
        } else {
            1.0
        };
        if let Some(p) = self.paced.iter_mut().find(|p| p.0 == land_s) {
            p.1 = share;
            return true;
        }
        self.paced.push((land_s, share)).is_ok()
    }

    /// The footsteps kept, in the order they land.
    #[must_use]
    pub fn steps(&self) -> &[Footstep] {
        &self.steps
    }

    /// Steps changed from the clip's, and the clip's steps left out (the foot stayed).
    #[must_use]
    pub fn substituted(&self) -> (u32, u32) {
        (self.substituted, self.dropped)
    }

    /// Forgets footsteps that lifted before `t` (a stream that has played them).
    pub fn forget_before(&mut self, t: Real) {
        // Keep each side's last step whatever its lift: the ZMP reference starts from it.
        let mut keep = [false; MAX_FOOTSTEPS];
        for side in 0..2 {
            if let Some(k) = self.steps.iter().rposition(|s| s.side == side) {
                keep[k] = true;
            }
        }
        let mut k = 0;
        self.steps.retain(|s| {
            let kept = keep[k] || s.lift_s >= t;
            k += 1;
            kept
        });
    }

    /// Starts the plan at `t` with the robot standing on `robot` while the clip's soles are at
    /// `clip` (a clip may start mid-stride; the robot starts from its stance). Without it the
    /// first [`FootstepPlanner::observe`] starts the robot where the clip's feet are.
    pub fn start(&mut self, t: Real, robot: [Footprint; 2], clip: [Footprint; 2]) {
        if self.started {
            return;
        }
        self.started = true;
        for side in 0..2 {
            self.push(Footstep {
                number: 0,
                side,
                at: robot[side],
                clip: clip[side],
                land_s: t,
                lift_s: Real::INFINITY,
                changed: Substitution::default(),
            });
        }
        self.clip_last = clip;
        self.clip_planted = [true; 2];
    }

    /// The clip at time `t`: which feet it has planted and where its soles are.
    pub fn observe(&mut self, t: Real, planted: [bool; 2], feet: [Footprint; 2]) {
        self.start(t, feet, feet);
        for side in 0..2 {
            if let Some(due) = self.lift_due[side] {
                if t >= due {
                    self.lift_due[side] = None;
                    if !self.clip_planted[side] && self.planted[side] && self.planted[1 - side] {
                        self.lift(side, t);
                    }
                }
            }
        }
        for side in 0..2 {
            if planted[side] && !self.clip_planted[side] {
                self.land(side, t, feet[side]);
            }
        }
        for (side, down) in planted.into_iter().enumerate() {
            if !down && self.clip_planted[side] {
                let other = 1 - side;
                if self.planted[other] {
                    let stood = self.current(other).map_or(t, |s| s.land_s);
                    let earliest = stood + self.limits.double_support_s;
                    if t >= earliest {
                        self.lift(side, t);
                    } else {
                        self.lift_due[side] = Some(earliest);
                        self.carry[side].short_double_support = true;
                    }
                } else {
                    self.waiting[side] = true;
                }
            }
        }
        self.clip_planted = planted;
    }

    fn push(&mut self, mut step: Footstep) {
        step.number = self.next_number;
        self.next_number += 1;
        if self.steps.is_full() {
            // The oldest finished step goes first; a full plan of unfinished ones cannot be
            // (at most one per foot is on the floor).
            if let Some(k) = self.steps.iter().position(|s| s.lift_s.is_finite()) {
                self.steps.remove(k);
            }
        }
        let _ = self.steps.push(step);
    }

    fn current(&mut self, side: usize) -> Option<&mut Footstep> {
        self.steps.iter_mut().rev().find(|s| s.side == side)
    }

    fn lift(&mut self, side: usize, t: Real) {
        let Some(step) = self.current(side) else {
            return;
        };
        step.lift_s = t;
        let from = step.at;
        self.planted[side] = false;
        self.swing[side] = (t, from);
    }

    fn land(&mut self, side: usize, t: Real, clip: Footprint) {
        let other = 1 - side;
        if self.planted[side] {
            // The plan kept this foot down (its lift waited for a flight to end): the clip's
            // step is left out.
            if self.waiting[side] || self.lift_due[side].is_some() {
                self.dropped += 1;
            }
            self.waiting[side] = false;
            self.lift_due[side] = None;
            self.carry[side] = Substitution::default();
            self.clip_last[side] = clip;
            return;
        }
        let l = self.limits;
        let mut changed = core::mem::take(&mut self.carry[side]);
        // The clip's step relative to its stance foot, on the plan's stance foot.
        let (rel, turn) = self.clip_last[other].relative(&clip);
        let sign = if side == 0 { 1.0 } else { -1.0 };
        let x = rel.x.clamp(-l.backward, l.forward);
        let y = (rel.y * sign).clamp(l.width_min, l.width_max);
        let turn_clamped = turn.clamp(-l.turn, l.turn);
        changed.too_long = x != rel.x || y != rel.y * sign || turn_clamped != turn;
        let fallback = self.clip_last[other];
        let stance = self.current(other).map_or(fallback, |s| s.at);
        let mut at = stance.moved(RealVec2::new(x, y * sign), turn_clamped);
        // The swing's time against the distance; a swing too short for it lifts earlier.
        let (mut lifted, from) = self.swing[side];
        let distance = (at.centre - from.centre).length();
        let foot_speed = l.foot_speed * self.paced.iter().find(|p| p.0 == t).map_or(1.0, |p| p.1);
        let needed = l.swing_min_s + distance / foot_speed;
        if t - lifted < needed - 1e-9 {
            let earlier = self.earliest_lift(side, lifted).max(t - needed);
            if earlier < lifted - 1e-9 {
                lifted = earlier;
                self.swing[side].0 = lifted;
                if let Some(step) = self.current(side) {
                    step.lift_s = lifted;
                }
                changed.early_lift = true;
            }
        }
        let time = t - lifted;
        let allowed = (time - l.swing_min_s) * foot_speed;
        self.clip_last[side] = clip;
        if allowed <= 0.0 {
            // Too short a swing to lift the foot at all: it stays where it was.
            if let Some(step) = self.current(side) {
                step.lift_s = Real::INFINITY;
            }
            self.planted[side] = true;
            self.dropped += 1;
            self.release_other(other, t);
            return;
        }
        if distance > allowed + 1e-9 {
            changed.too_fast = true;
            // The nearest step inside both the swing's reach (a disc round where the foot
            // lifted) and the stance foot's limits (a box in its frame): alternating projections,
            // the limits last so that they hold exactly.
            for _ in 0..FEASIBLE_ITERATIONS {
                let d = (at.centre - from.centre).length();
                if d > allowed {
                    let share = allowed / d;
                    let turn = crate::math::wrap_near(at.yaw - from.yaw, 0.0);
                    at = Footprint {
                        centre: from.centre + (at.centre - from.centre) * share,
                        yaw: crate::math::wrap_near(from.yaw + turn * share, 0.0),
                    };
                }
                let (rel, turn) = stance.relative(&at);
                let inside = Footprint {
                    centre: RealVec2::ZERO,
                    yaw: 0.0,
                }
                .moved(
                    RealVec2::new(
                        rel.x.clamp(-l.backward, l.forward),
                        (rel.y * sign).clamp(l.width_min, l.width_max) * sign,
                    ),
                    turn.clamp(-l.turn, l.turn),
                );
                let clamped = stance.moved(inside.centre, inside.yaw);
                let moved = (clamped.centre - at.centre).length();
                at = clamped;
                if moved < 1e-9 {
                    break;
                }
            }
        }
        if changed.any() {
            self.substituted += 1;
        }
        self.push(Footstep {
            number: 0,
            side,
            at,
            clip,
            land_s: t,
            lift_s: Real::INFINITY,
            changed,
        });
        self.planted[side] = true;
        self.release_other(other, t);
    }

    /// The earliest the foot of `side`, which lifted at `lifted`, could have lifted instead:
    /// no sooner than half way through the double support before it, leaving at least
    /// [`StepLimits::double_support_s`] of it, and after the foot itself stood that long.
    /// `lifted` itself when the other foot was not standing throughout.
    fn earliest_lift(&mut self, side: usize, lifted: Real) -> Real {
        let ds = self.limits.double_support_s;
        let stood_other = match self.current(1 - side) {
            Some(s) if s.land_s <= lifted && s.lift_s > lifted => s.land_s,
            _ => return lifted,
        };
        let Some(own) = self.current(side).map(|s| s.land_s) else {
            return lifted;
        };
        let start = stood_other.max(own);
        (lifted - 0.5 * (lifted - start)).max(start + ds).min(lifted)
    }

    /// The other foot's lift that waited for this landing happens after the double support.
    fn release_other(&mut self, other: usize, t: Real) {
        if core::mem::take(&mut self.waiting[other]) {
            self.lift_due[other] = Some(t + self.limits.double_support_s);
            self.carry[other].flight = true;
        }
    }
}

/// The step of `side` on the floor at `t` in `steps` (landing order).
#[must_use]
pub fn contact(steps: &[Footstep], side: usize, t: Real) -> Option<&Footstep> {
    steps.iter().rev().find(|s| s.side == side && s.in_contact(t))
}

/// The ZMP reference at `t` (module docs); `shift_s` is [`StepLimits::zmp_shift_s`]. `None`
/// when no foot of the plan is on the floor at `t` (before the plan starts).
#[must_use]
pub fn zmp_reference(steps: &[Footstep], t: Real, shift_s: Real) -> Option<RealVec2> {
    match (contact(steps, 0, t), contact(steps, 1, t)) {
        (None, None) => None,
        (Some(a), None) | (None, Some(a)) => Some(a.at.centre),
        (Some(a), Some(b)) => {
            let mid = (a.at.centre + b.at.centre) * 0.5;
            let start = a.land_s.max(b.land_s);
            let end = a.lift_s.min(b.lift_s);
            // Stood on before: the foot that did not just land; after: the one that stays.
            let from = if a.land_s > b.land_s {
                b.at.centre
            } else if b.land_s > a.land_s {
                a.at.centre
            } else {
                mid
            };
            let to = if a.lift_s < b.lift_s {
                b.at.centre
            } else if b.lift_s < a.lift_s {
                a.at.centre
            } else {
                mid
            };
            let length = end - start;
            Some(if length <= 2.0 * shift_s {
                from + (to - from) * smooth((t - start) / length)
            } else if t < start + shift_s {
                from + (mid - from) * smooth((t - start) / shift_s)
            } else if t >= end - shift_s {
                mid + (to - mid) * smooth((t - (end - shift_s)) / shift_s)
            } else {
                mid
            })
        }
    }
}

/// 0 → 1 with zero slope at both ends.
fn smooth(s: Real) -> Real {
    let s = if s.is_finite() { s.clamp(0.0, 1.0) } else { 0.0 };
    s * s * (3.0 - 2.0 * s)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn limits() -> StepLimits {
        StepLimits {
            forward: 0.12,
            backward: 0.06,
            width_min: 0.07,
            width_max: 0.16,
            turn: 0.6,
            swing_min_s: 0.12,
            foot_speed: 0.5,
            double_support_s: 0.1,
            zmp_shift_s: 0.3,
        }
    }

    fn at(x: Real, y: Real) -> Footprint {
        Footprint {
            centre: RealVec2::new(x, y),
            yaw: 0.0,
        }
    }

    /// A clip standing 0.3 s, then walking straight along x: steps of `stride` every
    /// `period` s, single supports of 60 % of the period; frames at 100 Hz.
    fn walk(planner: &mut FootstepPlanner, stride: Real, period: Real, steps: usize) -> Real {
        walk_with_swing(planner, stride, period, 0.6, steps)
    }

    /// [`walk`] with single supports of `swing_share` of the period.
    fn walk_with_swing(
        planner: &mut FootstepPlanner,
        stride: Real,
        period: Real,
        swing_share: Real,
        steps: usize,
    ) -> Real {
        let mut feet = [at(0.0, 0.05), at(0.0, -0.05)];
        let dt = 0.01;
        let mut t = 0.0;
        while t < 0.3 - 1e-9 {
            planner.observe(t, [true; 2], feet);
            t += dt;
        }
        for k in 0..steps {
            let side = k % 2;
            let reach = if k == 0 { stride / 2.0 } else { stride };
            let swing = swing_share * period;
            let end = t + period;
            while t < end - 1e-9 {
                t += dt;
                let local = t - (end - period);
                let mut planted = [true; 2];
                if local < swing {
                    planted[side] = false;
                    feet[side].centre.x += reach / (swing / dt);
                }
                planner.observe(t, planted, feet);
            }
        }
        t
    }

    #[test]
    fn a_clip_walk_within_reach_is_planned_as_it_is() {
        let mut p = FootstepPlanner::new(limits());
        walk(&mut p, 0.08, 0.5, 6);
        let steps = p.steps();
        assert_eq!(steps.len(), 8, "{steps:#?}");
        for (k, s) in steps[2..].iter().enumerate() {
            assert_eq!(s.side, k % 2);
            assert!(!s.changed.any(), "{s:?}");
            assert!((s.at.centre - s.clip.centre).length() < 1e-9, "{s:?}");
        }
        // Every foot but the last of each side has lifted again.
        assert!(steps[..6].iter().all(|s| s.lift_s.is_finite()));
        assert_eq!(p.substituted(), (0, 0));
    }

    #[test]
    fn a_paced_step_is_planned_at_its_share_of_the_foot_speed_and_no_other() {
        // 0.1 m steps in 0.3 s swings (0.5 s period): within reach and speed as they are.
        let mut free = FootstepPlanner::new(limits());
        walk(&mut free, 0.1, 0.5, 4);
        let steps = free.steps();
        assert!(steps[2..].iter().all(|s| !s.changed.too_fast), "{steps:#?}");
        // The third step (landing at the same clip time) at a fifth of the foot's speed: it
        // lifts earlier and still reaches only what its swing allows at 0.1 m/s.
        let mut paced = FootstepPlanner::new(limits());
        assert!(paced.pace_step(steps[4].land_s, 0.2));
        walk(&mut paced, 0.1, 0.5, 4);
        let slow = paced.steps();
        assert_eq!(slow.len(), steps.len());
        assert!(slow[4].changed.too_fast, "{:?}", slow[4]);
        let swing = slow[4].land_s - slow[2].lift_s;
        let reach = (swing - limits().swing_min_s) * 0.2 * limits().foot_speed;
        let went = (slow[4].at.centre - slow[2].at.centre).length();
        let free_went = (steps[4].at.centre - steps[2].at.centre).length();
        assert!(
            went <= reach + 1e-9 && went < free_went,
            "{went} {reach} {free_went}"
        );
        assert_eq!(slow[3].at, steps[3].at);
        // Pacing the same step again replaces its share; a plan has room for MAX_PACED_STEPS.
        assert!(paced.pace_step(steps[4].land_s, 0.5));
        let mut full = FootstepPlanner::new(limits());
        for k in 0..MAX_PACED_STEPS {
            assert!(full.pace_step(k as Real, 0.5));
        }
        assert!(!full.pace_step(-1.0, 0.5));
    }

    #[test]
    fn long_steps_are_clamped_in_the_stance_frame_and_later_steps_stay_relative() {
        let mut p = FootstepPlanner::new(limits());
        walk(&mut p, 0.3, 0.8, 4);
        let steps = p.steps();
        assert_eq!(steps.len(), 6);
        for w in steps[2..].windows(2) {
            let (rel, _) = w[0].at.relative(&w[1].at);
            assert!(rel.x <= 0.12 + 1e-9, "{rel}");
            assert!(w[1].changed.too_long);
        }
        assert_eq!(p.substituted().0, 4);
    }

    #[test]
    fn fast_steps_are_shortened_and_a_swing_too_short_keeps_the_foot_down() {
        let mut p = FootstepPlanner::new(limits());
        // 0.1 m in a 0.18 s swing: 0.06 s above the minimum allows 0.03 m.
        walk(&mut p, 0.1, 0.3, 3);
        let s = p.steps()[3];
        assert!(s.changed.too_fast, "{s:?}");
        let (rel, _) = p.steps()[2].at.relative(&s.at);
        assert!(rel.x < 0.1, "{rel}");
        // A 0.06 s swing cannot lift the foot: no step, the foot stays — but for the first,
        // which lifts earlier out of the standing before it.
        let mut p = FootstepPlanner::new(limits());
        walk(&mut p, 0.05, 0.1, 2);
        assert_eq!(p.steps().len(), 3, "{:#?}", p.steps());
        assert!(p.steps()[2].changed.early_lift);
        assert!(p.steps()[1].lift_s.is_infinite() && p.steps()[2].lift_s.is_infinite());
        assert_eq!(p.substituted().1, 1);
    }

    #[test]
    fn a_swing_too_short_for_its_step_lifts_earlier_out_of_a_long_double_support() {
        // 0.1 m in a 0.2 s swing needs 0.12 + 0.1 / 0.5 = 0.32 s; 0.6 s of double support
        // before it gives the 0.12 s missing, so the step keeps its length.
        let mut p = FootstepPlanner::new(limits());
        walk_with_swing(&mut p, 0.1, 0.8, 0.25, 4);
        let steps = p.steps();
        for w in steps[2..].windows(2) {
            let (previous, s) = (w[0], w[1]);
            assert!(s.changed.early_lift && !s.changed.too_fast, "{s:?}");
            assert!((s.at.centre - s.clip.centre).length() < 1e-9, "{s:?}");
            // The foot it stepped from lifted 0.12 s before the clip's (0.2 s swing).
            let own_last = steps
                .iter()
                .rev()
                .find(|x| x.side == s.side && x.land_s < s.land_s)
                .unwrap();
            let swing = s.land_s - own_last.lift_s;
            assert!((swing - 0.32).abs() < 0.011, "{swing}");
            // The other foot stood at least the shortest double support before the lift.
            assert!(own_last.lift_s - previous.land_s.max(own_last.land_s) >= 0.1 - 1e-9);
        }
        // Double supports too short to lend time (after the standing start's): shortened.
        let mut p = FootstepPlanner::new(limits());
        walk_with_swing(&mut p, 0.1, 0.25, 0.8, 4);
        let later = &p.steps()[3..];
        assert!(
            later.iter().all(|s| !s.changed.early_lift) && later.iter().any(|s| s.changed.too_fast),
            "{:#?}",
            p.steps()
        );
    }

    #[test]
    fn a_jump_becomes_standing_and_a_run_gets_double_supports() {
        // Both feet up together for 0.3 s, landing 0.2 m on.
        let mut p = FootstepPlanner::new(limits());
        let mut feet = [at(0.0, 0.05), at(0.0, -0.05)];
        let mut t = 0.0;
        p.observe(t, [true; 2], feet);
        for k in 1..=60 {
            t = Real::from(k as u8) * 0.01;
            let air = (0.1..0.4).contains(&t);
            if air {
                feet[0].centre.x += 0.2 / 30.0;
                feet[1].centre.x += 0.2 / 30.0;
            }
            p.observe(t, [!air; 2], feet);
        }
        // The left foot lifted (the right was down) and landed ≤ its reach ahead; the right's
        // lift waited for it and its swing came too late: it stays.
        for t in [0.05, 0.2, 0.35, 0.5] {
            assert!(
                contact(p.steps(), 0, t).is_some() || contact(p.steps(), 1, t).is_some(),
                "flight at {t}"
            );
        }
        assert!(p.substituted().0 + p.substituted().1 >= 1);

        // Running: each foot lifts before the other lands.
        let mut p = FootstepPlanner::new(limits());
        let mut feet = [at(0.0, 0.05), at(0.0, -0.05)];
        p.observe(0.0, [true; 2], feet);
        let mut t: Real = 0.0;
        let mut k = 0;
        while t < 3.0 {
            k += 1;
            t = Real::from(k as u16) * 0.01;
            let phase = (t / 0.35) as u32;
            let side = (phase % 2) as usize;
            let local = t - Real::from(phase as u16) * 0.35;
            let mut planted = [false; 2];
            // Stance 0.25 s of each 0.35 s, the rest flight.
            planted[1 - side] = local < 0.25;
            feet[side].centre.x += 0.002;
            p.observe(t, planted, feet);
        }
        let mut flights = 0;
        for k in 0..300 {
            let t = Real::from(k as u16) * 0.01;
            if contact(p.steps(), 0, t).is_none() && contact(p.steps(), 1, t).is_none() {
                flights += 1;
            }
        }
        assert_eq!(flights, 0);
        assert!(p.steps().iter().any(|s| s.changed.flight), "{:#?}", p.steps());
    }

    #[test]
    fn the_zmp_reference_moves_from_foot_to_foot_and_rests_between_them_when_standing() {
        let mut p = FootstepPlanner::new(limits());
        let end = walk(&mut p, 0.08, 0.5, 2);
        let steps = p.steps();
        let shift = p.limits().zmp_shift_s;
        // Standing at the start: between the feet.
        let z0 = zmp_reference(steps, 0.0, shift).unwrap();
        assert!(z0.y.abs() < 1e-9);
        // While the left swings (from 0.3 to 0.6 s), on the right foot.
        let z = zmp_reference(steps, 0.4, shift).unwrap();
        assert!((z - steps[1].at.centre).length() < 1e-9, "{z}");
        // In the double support after the left lands, moving towards the left foot.
        let a = zmp_reference(steps, 0.61, shift).unwrap();
        let b = zmp_reference(steps, 0.79, shift).unwrap();
        assert!(a.y < b.y && b.y <= steps[2].at.centre.y + 1e-9, "{a} {b}");
        // It never jumps: 1 ms apart, at most a millimetre apart.
        let mut previous = z0;
        let mut t: Real = 0.0;
        while t < end + 1.0 {
            let z = zmp_reference(steps, t, shift).unwrap();
            assert!((z - previous).length() < 2e-3, "at {t}: {previous} → {z}");
            previous = z;
            t += 0.001;
        }
        // After the clip: both feet down for good, half way between them.
        let last = zmp_reference(steps, end + 5.0, shift).unwrap();
        let mid = (contact(steps, 0, end + 5.0).unwrap().at.centre
            + contact(steps, 1, end + 5.0).unwrap().at.centre)
            * 0.5;
        assert!((last - mid).length() < 1e-9);
    }

    #[test]
    fn a_stream_forgets_played_steps_and_keeps_planning() {
        let mut p = FootstepPlanner::new(limits());
        let end = walk(&mut p, 0.08, 0.5, 40);
        p.forget_before(end - 1.0);
        assert!(p.steps().len() <= 8, "{}", p.steps().len());
        assert!(zmp_reference(p.steps(), end - 0.5, 0.3).is_some());
        assert_eq!(p.steps().last().unwrap().number, 41);
    }
}
