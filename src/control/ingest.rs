//! The input side of a tick: inputs taken in order up to the look-ahead's horizon, solved (or
//! played), retargeted and mapped through the rig into the preview's source samples.

use super::input::Payload;
use super::lookahead::SampleHead;
use super::stats::Stage;
use super::{Controller, Solve};
use crate::fk::{fk64, fk64_bones};
use crate::servo::MAX_SERVOS;

/// Most inputs turned into source samples in one tick (a look-ahead's preview fills over a few
/// ticks at the start rather than in one long tick).
pub(super) const MAX_INGEST: usize = 16;

/// An input taken and being solved (over one tick or several).
#[derive(Clone, Copy, Debug)]
pub(super) struct Solving {
    /// When its sample is due, ns.
    pub(super) due: u64,
    pub(super) clip_time: f64,
    pub(super) made_ns: u64,
    /// The first effector not yet solved.
    pub(super) next_effector: usize,
}

/// What [`Controller::take_input`] found.
pub(super) enum Taken {
    /// An input to solve.
    Input(Solving),
    /// One passed over (superseded or refused).
    PassedOver,
    /// None due.
    Nothing,
}

impl Controller {
    /// Takes the inputs due by `horizon` in order (the look-ahead's preview; without one, the
    /// tick's own window), at most [`MAX_INGEST`] a tick, and turns each into a source sample:
    /// the solve, forward kinematics, retargeting and the rig's angles — what a perfect rig
    /// would do at its time. An input already due by `due_now` with a newer one also due is
    /// passed over (only the newest counts). Ages are measured at `now`. Allocates nothing.
    ///
    /// Targets taken ahead of their time with no other input waiting are solved one effector a
    /// tick (the same solves in the same order, so the same sample, a few ticks later but still
    /// before it is due): a fast loop's ticks share the work of a slower input's solve. Live
    /// inputs and inputs due within that time are solved whole.
    pub(super) fn ingest(&mut self, due_now: u64, horizon: u64, now: u64, tick_dt: f64) {
        let n = self.skeleton.channel_count();
        for _ in 0..MAX_INGEST {
            let mut p = match self.solving.take() {
                Some(p) => p,
                None => match self.take_input(due_now, horizon, now) {
                    Taken::Input(p) => p,
                    Taken::PassedOver => continue,
                    Taken::Nothing => break,
                },
            };
            if let Solve::Follow(f) = &mut self.solve {
                // Steps: each effector, then the sample.
                let count = f.effectors.len();
                let left = (count + 1).saturating_sub(p.next_effector) as u64;
                let spread =
                    p.due > due_now + (left + 1) * self.period_ns && !self.input.next_is_due(horizon);
                if p.next_effector < count {
                    let end = if spread { p.next_effector + 1 } else { count };
                    f.solve_some(
                        &self.skeleton,
                        &mut self.channels[..n],
                        &mut self.pose,
                        &mut self.stats,
                        p.next_effector..end,
                    );
                    if spread && p.next_effector == 0 {
                        self.stats.inputs_spread += 1;
                    }
                    p.next_effector = end;
                    if spread {
                        self.solving = Some(p);
                        break;
                    }
                }
            }
            self.add_sample(p, tick_dt);
        }
    }

    /// The forward kinematics of the pose solved (or played) into the controller's pose: the
    /// whole pose when a retargeting reads it, otherwise only the watched chains.
    pub(super) fn sample_kinematics(&mut self) {
        let n = self.skeleton.channel_count();
        if self.retarget.is_some() {
            fk64(&self.skeleton, &self.channels[..n], &mut self.pose);
        } else {
            fk64_bones(
                &self.skeleton,
                &self.channels[..n],
                &mut self.pose,
                &self.watched_chains,
            );
        }
    }

    /// The next input due by `horizon`, checked and put in place (a frame's channels, the
    /// follower's targets).
    fn take_input(&mut self, due_now: u64, horizon: u64, now: u64) -> Taken {
        let n = self.skeleton.channel_count();
        {
            let Some(due_ns) = self.input.next_due(horizon).map(|m| m.due_ns) else {
                return Taken::Nothing;
            };
            let superseded = due_ns <= due_now && self.input.next_is_due(due_now);
            let Some(msg) = self.input.current() else {
                return Taken::Nothing;
            };
            if superseded {
                // Not solved, but its targets stand: a newer message may name other effectors
                // (live sources send one effector a line or a topic).
                if let (Payload::Targets(targets), Solve::Follow(f)) = (&msg.payload, &mut self.solve) {
                    if targets.iter().all(|t| f.accepts(t)) {
                        for t in targets {
                            f.targets[t.effector] = Some(*t);
                        }
                    } else {
                        self.stats.inputs_rejected += 1;
                    }
                }
                self.input.superseded += 1;
                return Taken::PassedOver;
            }
            let mut clip_time = f64::NAN;
            let ok = match (&msg.payload, &mut self.solve) {
                (
                    Payload::Frame {
                        channels,
                        len,
                        clip_time: t,
                    },
                    Solve::Frames,
                ) if *len >= n && channels[..n].iter().all(|v| v.is_finite()) => {
                    self.channels[..n].copy_from_slice(&channels[..n]);
                    clip_time = *t;
                    true
                }
                (Payload::Targets(targets), Solve::Follow(f)) => {
                    let valid = targets.iter().all(|t| f.accepts(t));
                    if valid {
                        for t in targets {
                            f.targets[t.effector] = Some(*t);
                        }
                    }
                    valid
                }
                _ => false,
            };
            if !ok {
                self.stats.inputs_rejected += 1;
                return Taken::PassedOver;
            }
            self.stats.inputs_used += 1;
            self.stats
                .stage_mut(Stage::InputAge)
                .record(now.saturating_sub(msg.made_ns));
            // Live inputs are due at once: they stand for the time they were made.
            let due = if msg.due_ns == 0 {
                msg.made_ns.min(due_now)
            } else {
                msg.due_ns
            };
            Taken::Input(Solving {
                due,
                clip_time,
                made_ns: msg.made_ns,
                next_effector: 0,
            })
        }
    }

    /// The solved (or played) pose of the input `p` as a source sample in the preview: its
    /// forward kinematics, retargeting and the rig's angles.
    fn add_sample(&mut self, p: Solving, tick_dt: f64) {
        let n = self.skeleton.channel_count();
        let Solving {
            due,
            clip_time,
            made_ns,
            ..
        } = p;
        {
            self.sample_kinematics();
            let mut head = SampleHead {
                due_ns: due,
                clip_time,
                made_ns,
                ..SampleHead::default()
            };
            for (t, w) in head.tips.iter_mut().zip(self.watch) {
                if let Some(b) = w {
                    *t = self.pose.tip[b];
                }
            }
            if let Some(r) = &mut self.retarget {
                let dt = match self.last_due {
                    Some(d) if due > d => (due - d) as f64 * 1e-9,
                    _ => tick_dt,
                };
                r.step(&self.pose, clip_time, dt, due);
                head.effectors = r.frame.effectors;
                head.base = (r.frame.base_pos, r.frame.base_rot);
                head.contact = r.frame.planted;
            }
            self.last_due = Some(due);
            let joints: &[f64] = match &self.retarget {
                Some(r) => &r.frame.q,
                None => &[],
            };
            self.rig
                .joint_angles(&self.skeleton, &self.channels[..n], joints, &mut self.angles);
            if self.angles.iter().any(|a| !a.is_finite()) {
                // Refused as a whole: the servos go on with the samples they have.
                self.stats.commands_refused += 1;
                return;
            }
            // Load offsets only with a retargeting (the preview fills missing ones with 0).
            let channels = &self.channels[..n];
            if let Some(r) = &mut self.retarget {
                let len = self.angles.len();
                let mut load_offsets = [0.0; MAX_SERVOS];
                r.load_offsets(&self.rig, &mut load_offsets[..len]);
                self.preview
                    .push(head, &self.angles, &load_offsets[..len], channels);
            } else {
                self.preview.push(head, &self.angles, &[], channels);
            }
        }
    }
}
