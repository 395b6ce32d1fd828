//! The tick's phases, in order: the timing of the tick, the pipelined replies, the input (a
//! source sample solved, retargeted and mapped), the command (mapping and the command stage, or
//! a hold), the bus (Sync Write, then Sync Read or its request), the telemetry.

use glam::DVec3;

use super::lookahead::EaseIn;
use super::stats::Stage;
use super::{torque_off, Absorbed, Controller, ReadContext, RunEnd, Telemetry};
use crate::bus::{BusError, ServoBus};
use crate::rig::Rig;
use crate::schedule::{Clock, Tick};
use crate::servo::MAX_SERVOS;

/// This tick's source sample, as the phases after the input read it.
pub(super) struct Current {
    /// Its due time and the time it was made (0: none).
    due_ns: u64,
    made_ns: u64,
    /// The effectors' tips it asked for (NaN: none).
    tips: [DVec3; 4],
    clip_time: f64,
    /// A new sample became current this tick.
    pub(super) fresh: bool,
}

/// The command phase's goals, and when the bus phase began.
pub(super) struct Command {
    pub(super) goals: [i32; MAX_SERVOS],
    /// The last command again (failed reads).
    pub(super) holding: bool,
    pub(super) t_write: u64,
}

/// What the bus phase did.
pub(super) struct BusDone {
    written: bool,
    read_ok: bool,
    tracking: f64,
    /// ns on the bus this tick: the write, the read or its request, the pipelined replies.
    bus_ns: u64,
    pub(super) end: Option<RunEnd>,
}

/// The ease-in from where the servos stood: its start (joint angles), its length and the
/// commanded ticks so far, and when it began (the first tick with a source), ns.
pub(super) struct Ease {
    pub(super) from: Vec<f64>,
    pub(super) ticks: u64,
    pub(super) done: u64,
    pub(super) start_ns: Option<u64>,
}

/// The share of each servo's velocity limit the move to a run's first pose reaches at its
/// fastest: a gentle start, a quarter of the servos' speed.
pub const START_MOVE_SPEED_SHARE: f64 = 0.25;

/// How long an eased move (smoothstep, the help note's eq. 13: its peak speed 1.5 times its
/// mean) from `present` (ticks) to `pose` (radians per servo, clamped to each servo's range)
/// takes when no servo goes faster than [`START_MOVE_SPEED_SHARE`] of its velocity limit, s;
/// with the servo that takes longest and how far it goes, degrees of joint. `None` when no
/// servo has a finite target and a velocity limit.
#[must_use]
pub fn start_move_s(rig: &Rig, present: &[i32], pose: &[f64]) -> Option<(f64, usize, f64)> {
    eased_move_s(rig, present.iter().map(|&p| f64::from(p)), pose)
}

/// [`start_move_s`] from fractional ticks. Allocates nothing.
fn eased_move_s(rig: &Rig, present: impl Iterator<Item = f64>, pose: &[f64]) -> Option<(f64, usize, f64)> {
    rig.servos
        .iter()
        .zip(present)
        .zip(pose)
        .enumerate()
        .filter_map(|(k, ((s, p), &a))| {
            let to = s.angle_to_ticks_exact(a);
            if !(to.is_finite() && p.is_finite() && s.max_velocity > 0.0) {
                return None;
            }
            let ticks = (to.clamp(f64::from(s.min_tick), f64::from(s.max_tick)) - p).abs();
            let seconds = 1.5 * ticks / (START_MOVE_SPEED_SHARE * s.max_velocity);
            Some((seconds, k, (ticks / s.ticks_per_radian().abs()).to_degrees()))
        })
        .max_by(|a, b| a.0.total_cmp(&b.0))
}

impl Controller {
    /// The tick's own timing: wake lateness, period error; the start of the torque-off clock.
    pub(super) fn begin(&mut self, tick: &Tick, clock: &mut dyn Clock) -> u64 {
        let start = clock.now_ns();
        self.stats.ticks += 1;
        self.stats.skipped_ticks += tick.skipped;
        self.stats.wake_late.record(tick.lateness_ns());
        if let Some((index, at)) = self.last_tick {
            let expected = (tick.index - index) * self.period_ns;
            let got = start.saturating_sub(at);
            self.stats.period_error.record(got.abs_diff(expected));
        }
        self.last_tick = Some((tick.index, start));
        if self.reads.last_valid_ns == 0 {
            self.reads.last_valid_ns = start;
        }
        start
    }

    /// Pipelined: the replies to the last tick's request (they came in while the loop slept),
    /// taken before deciding whether to hold; with the ns it took. `Err`: the run ends.
    pub(super) fn collect_replies(
        &mut self,
        bus: &mut dyn ServoBus,
        clock: &mut dyn Clock,
    ) -> Result<(Option<Absorbed>, u64), RunEnd> {
        if let Some(item) = self.health_in_flight.take() {
            // Last tick's read was the health watch's: its reply, and no positions this tick.
            let t0 = clock.now_ns();
            let mut buf = [0u8; 4];
            let out = &mut buf[..usize::from(item.len).min(4)];
            let got = bus.collect_read(item.id, item.address, out);
            let t1 = clock.now_ns();
            if let Some(why) = got.as_ref().err().and_then(BusError::port_failure) {
                self.port_error = Some(why);
                self.stats.torque_off_acknowledged = Some(torque_off(bus, &self.ids).acknowledged);
                return Err(RunEnd::PortLost);
            }
            if let Err(e) = &got {
                self.stats.bus_error(e.kind());
            }
            if let Some(h) = &mut self.health {
                h.absorb(item, got.ok().map(|()| &*out));
            }
            return Ok((None, t1 - t0));
        }
        let Some(context) = self.reads.in_flight.take() else {
            return Ok((None, 0));
        };
        let t0 = clock.now_ns();
        let read = bus.collect_positions(&self.ids, &mut self.reads.read_buf);
        let t1 = clock.now_ns();
        let (r, lost) = self.absorb_read(read, t1, &context, bus);
        if let Some(why) = lost {
            // The port is gone: command nothing more.
            self.port_error = Some(why);
            self.stats.torque_off_acknowledged = Some(torque_off(bus, &self.ids).acknowledged);
            return Err(RunEnd::PortLost);
        }
        if let Some(end) = r.end {
            return Err(end);
        }
        Ok((Some(r), t1 - t0))
    }

    /// Input: every one due by the look-ahead's horizon becomes a source sample (solved,
    /// retargeted, mapped); the newest due in this tick's half-period window is current
    /// (inputs stamped with their ideal times, such as a 120 Hz file at 120 Hz, land on the
    /// nearest tick).
    pub(super) fn take_current(&mut self, tick: &Tick, start: u64, dt: f64) -> Current {
        let due_now = tick.deadline_ns + self.period_ns / 2;
        self.ingest(due_now, due_now + self.preview_ns, start, dt);
        let fresh = self.preview.advance(due_now);
        if fresh {
            self.have_input = true;
            if self.ease.start_ns.is_none() {
                self.ease.start_ns = Some(tick.deadline_ns);
                self.size_start_move();
            }
        } else if self.have_input {
            self.stats.inputs_stale += 1;
        }
        // This tick's sample stays in the preview: only what the tick reads is copied.
        let (due_ns, made_ns, tips, clip_time) = self
            .preview
            .current()
            .map_or((0, 0, [DVec3::NAN; 4], f64::NAN), |c| {
                (c.due_ns, c.made_ns, c.tips, c.clip_time)
            });
        if let (true, Some(r)) = (fresh, &mut self.retarget) {
            r.report_until(due_ns);
        }
        self.clip_time = clip_time;
        Current {
            due_ns,
            made_ns,
            tips,
            clip_time,
            fresh,
        }
    }

    /// At the first input, when the configuration asks for it
    /// ([`super::LoopConfig::size_start_move`]): lengthens the ease-in to the eased move from
    /// where the servos stood to the input's pose ([`start_move_s`]) when that takes longer, so
    /// that no servo starts faster than [`START_MOVE_SPEED_SHARE`] of its speed. The ease is
    /// not counted in the fidelity. Allocates nothing.
    fn size_start_move(&mut self) {
        if !self.config.size_start_move {
            return;
        }
        let Some((ticks, seconds)) = self.eased_move_ticks() else {
            return;
        };
        if ticks > self.ease.ticks {
            self.ease.ticks = ticks;
            self.stats.start_move_s = Some(seconds);
        }
    }

    /// Ticks (and seconds) of the eased move from the ease's start angles to the current
    /// sample's pose ([`start_move_s`]); `None` without a current sample or a servo to move.
    /// Allocates nothing.
    pub(super) fn eased_move_ticks(&self) -> Option<(u64, f64)> {
        let c = self.preview.current()?;
        let from = self
            .rig
            .servos
            .iter()
            .zip(&self.ease.from)
            .map(|(s, &a)| s.angle_to_ticks_exact(a));
        let (seconds, _, _) = eased_move_s(&self.rig, from, c.angles)?;
        Some(((seconds * 1e9 / self.period_ns as f64).ceil() as u64, seconds))
    }

    /// The goals: the current sample through the look-ahead's planned path (or the greedy
    /// limiter with the ease-in) and the command stage — or, holding or without input, the last
    /// command again.
    pub(super) fn encode(&mut self, tick: &Tick, dt: f64, holding: bool) -> [i32; MAX_SERVOS] {
        let mut goals = [0i32; MAX_SERVOS];
        let len = self.ids.len();
        if holding {
            self.stats.held_ticks += 1;
            goals[..len].copy_from_slice(self.stage.last());
            return goals;
        }
        if !self.have_input {
            // No input yet: keep the servos where they are (and their watchdog fed).
            goals[..len].copy_from_slice(self.stage.last());
            return goals;
        }
        // What a perfect rig would do this tick: the fidelity's reference.
        match self.preview.current() {
            Some(c) => self.measure.source_angles.copy_from_slice(&c.angles[..len]),
            None => self.measure.source_angles.fill(f64::NAN),
        }
        if self.measure.source_log.len() < self.measure.source_log.capacity() {
            let mut a = [f64::NAN; MAX_SERVOS];
            a[..len].copy_from_slice(&self.measure.source_angles[..len]);
            self.measure.source_log.push((tick.deadline_ns, a));
        }
        if self.ease.done < self.ease.ticks {
            self.ease.done += 1;
        }
        if let Some(b) = &mut self.balance {
            // The gyro feedback rides on the goals sent, not on the path.
            let contact = self.preview.current().map_or([true; 2], |c| c.contact);
            b.correct(&self.rig, contact, &mut self.stage);
        }
        let command = if let Some(la) = &mut self.lookahead {
            // The goal path planned over the preview, each servo led by its lag.
            let ease = (self.ease.ticks > 0).then(|| EaseIn {
                from: &self.ease.from,
                start_ns: self.ease.start_ns.unwrap_or(tick.deadline_ns),
                length_ns: self.ease.ticks * self.period_ns,
            });
            self.preview.live = !self.input.finished();
            let targets = la.targets(&self.rig, &self.stage, &self.preview, tick.deadline_ns, dt, ease);
            self.stage.command_planned(&self.rig, targets, dt)
        } else {
            self.angles.copy_from_slice(&self.measure.source_angles);
            if let Some(c) = self.preview.current() {
                for (a, o) in self.angles.iter_mut().zip(c.load_offset) {
                    *a += o;
                }
            }
            if self.ease.done <= self.ease.ticks && self.ease.ticks > 0 {
                // Ease in: blend from where the servos stood (smoothstep weight).
                let t = self.ease.done as f64 / self.ease.ticks as f64;
                let w = t * t * (3.0 - 2.0 * t);
                for (a, from) in self.angles.iter_mut().zip(&self.ease.from) {
                    *a = from + w * (*a - from);
                }
            }
            self.stage.command(&self.rig, &self.angles, dt)
        };
        match command {
            Ok((g, limited)) => {
                goals[..len].copy_from_slice(g);
                self.stats.clamped += limited.clamped as u64;
                self.stats.rate_limited += limited.rate_limited as u64;
            }
            // Refused as a whole: the last command stands.
            Err(_) => {
                self.stats.commands_refused += 1;
                goals[..len].copy_from_slice(self.stage.last());
            }
        }
        goals
    }

    /// The bus: the goals' Sync Write, then the read — used only when every reply passed every
    /// check; pipelined, its request goes out now and the replies are taken at the start of the
    /// next tick. A failed port ends the run with one torque-off try.
    pub(super) fn exchange(
        &mut self,
        tick: &Tick,
        bus: &mut dyn ServoBus,
        clock: &mut dyn Clock,
        command: &Command,
        current: &Current,
        (absorbed, collect_ns): (Option<Absorbed>, u64),
    ) -> BusDone {
        let len = self.ids.len();
        let (goals, holding, t_write) = (&command.goals, command.holding, command.t_write);
        let written = bus.write_goals(&self.ids, &goals[..len]);
        match &written {
            Ok(()) => self.stats.commands_sent += 1,
            Err(e) => self.stats.bus_error(e.kind()),
        }
        let mut lost = written.as_ref().err().and_then(BusError::port_failure);
        let t_read = clock.now_ns();
        self.stats.stage_mut(Stage::BusWrite).record(t_read - t_write);

        // Not in a pre-roll (negative clip times; targets have none).
        let pre_roll = current.clip_time < 0.0;
        let mut context = ReadContext {
            sample_due: current.due_ns,
            holding,
            goals: *goals,
            tracked: None,
            record: self.have_input && !holding && self.ease.done >= self.ease.ticks && !pre_roll,
            tick: tick.index,
        };
        if self.reads.have_previous {
            let mut g = [0i32; MAX_SERVOS];
            g[..len].copy_from_slice(&self.reads.previous_goals);
            context.tracked = Some(g);
        }
        let read_ok;
        let mut tracking = f64::NAN;
        let mut end = None;
        let t_after;
        if self.config.pipelined {
            // Every few ticks the health watch's Read takes the position read's slot.
            let health = self.health.as_mut().and_then(|h| h.due());
            let requested = match health {
                Some(item) => bus.request_read(item.id, item.address, item.len),
                None => bus.request_positions(&self.ids),
            };
            t_after = clock.now_ns();
            let request_ok = requested.is_ok();
            match (requested, health) {
                (Ok(()), Some(item)) => self.health_in_flight = Some(item),
                (Ok(()), None) => self.reads.in_flight = Some(context),
                (Err(e), _) => {
                    if let (Some(item), Some(h)) = (health, &mut self.health) {
                        h.absorb(item, None);
                    }
                    let (r, l) = self.absorb_read(Err(e), t_after, &context, bus);
                    (end, lost) = (r.end, lost.or(l));
                }
            }
            match absorbed {
                Some(r) => {
                    (read_ok, tracking) = (r.ok && request_ok, r.tracking);
                    end = end.or(r.end);
                }
                // The first tick has no replies to take: only its request can fail.
                None => read_ok = request_ok,
            }
        } else {
            let read = bus.read_positions(&self.ids, &mut self.reads.read_buf);
            t_after = clock.now_ns();
            let (r, l) = self.absorb_read(read, t_after, &context, bus);
            (read_ok, tracking, end) = (r.ok, r.tracking, r.end);
            lost = lost.or(l);
        }
        self.stats
            .stage_mut(Stage::BusRead)
            .record(t_after - t_read + collect_ns);
        if let Some(why) = lost {
            // The port is gone: command nothing more; one torque-off (its Sync Write fails
            // too, so no servo is asked on its own).
            self.port_error = Some(why);
            self.stats.torque_off_acknowledged = Some(torque_off(bus, &self.ids).acknowledged);
            end = Some(RunEnd::PortLost);
        }
        if written.is_ok() {
            self.reads.previous_goals.copy_from_slice(&goals[..len]);
            self.reads.have_previous = true;
        }
        BusDone {
            written: written.is_ok(),
            read_ok,
            tracking,
            bus_ns: t_after - t_write + collect_ns,
            end,
        }
    }

    /// Telemetry: the tick's timing and deadline, the live view (goals, present angles, the
    /// input carried to the bus), a record to each telemetry sink.
    pub(super) fn report(
        &mut self,
        tick: &Tick,
        start: u64,
        done: u64,
        command: &Command,
        current: &Current,
        bus: &BusDone,
    ) {
        let len = self.ids.len();
        let total = done - start;
        let compute = total.saturating_sub(bus.bus_ns);
        self.stats.tick_total.record(total);
        self.stats.tick_compute.record(compute);
        let missed = done > tick.deadline_ns + self.period_ns;
        if missed {
            self.stats.deadline_misses += 1;
        }
        if let Some(mut view) = self.sinks.live.as_ref().and_then(|v| v.try_update()) {
            view.record_tick(done, compute, missed);
            view.len = len;
            for (k, (s, (g, p))) in self
                .rig
                .servos
                .iter()
                .zip(command.goals[..len].iter().zip(&self.reads.present))
                .enumerate()
            {
                view.goal_rad[k] = s.ticks_to_angle(f64::from(*g));
                view.present_rad[k] = s.ticks_to_angle(f64::from(*p));
            }
            if bus.written && self.have_input && !command.holding {
                view.record_carried(current.made_ns, command.t_write);
            }
        }
        if !self.sinks.telemetry.is_empty() {
            let mut t = Telemetry {
                index: tick.index,
                deadline_ns: tick.deadline_ns,
                woke_ns: tick.woke_ns,
                compute_ns: compute,
                total_ns: total,
                missed,
                read_ok: bus.read_ok,
                held: command.holding,
                tracking_rms_deg: bus.tracking,
                tips: current.tips,
                clip_time: self.clip_time,
                present: [0; MAX_SERVOS],
                servos: len,
                read_ns: self.reads.last_valid_ns,
                stopping: false,
                hottest: self.health.as_ref().and_then(|h| h.hottest()),
            };
            t.present[..len].copy_from_slice(&self.reads.present);
            self.emit(&t);
        }
    }
}
