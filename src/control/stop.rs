//! Running ticks to the end of a run, and stopping safely: the ramp to rest (or the hold), then
//! torque off on every servo.

use super::{stats, watchdog, Controller, RunEnd, StopMode, StopRequests, Telemetry};
use crate::bus::{BusError, ServoBus};
use crate::schedule::{Clock, Schedule};
use crate::servo::{addr, MAX_SERVOS};

/// The longest a stopped walk goes on to put its swinging foot down, s (the OP3's plans
/// swing for 0.14–0.6 s).
pub const FINISH_STEP_S: f64 = 1.0;

/// How long before a tick's deadline its solve is rehearsed, ns.
pub const REHEARSAL_LEAD_NS: u64 = 40_000;

impl Controller {
    /// Runs ticks on `schedule` until the input ends, `max_ticks` pass, a stop is requested,
    /// reads fail for the torque-off time or the port fails; then (except after a fault) ramps
    /// to rest or holds, and turns torque off.
    pub fn run(
        &mut self,
        schedule: &mut Schedule,
        bus: &mut dyn ServoBus,
        clock: &mut dyn Clock,
        stop: &StopRequests,
    ) -> RunEnd {
        let faults_before = self
            .config
            .count_page_faults
            .then(crate::rt::thread_minor_faults)
            .flatten();
        let why = loop {
            if stop.made() > 0 {
                break RunEnd::Interrupted;
            }
            if self.config.rehearse {
                let deadline = schedule.next_deadline();
                clock.wait_until(deadline.saturating_sub(REHEARSAL_LEAD_NS));
                self.rehearse(deadline);
            }
            let tick = schedule.wait(clock);
            if stop.made() > 0 {
                break RunEnd::Interrupted;
            }
            if self.config.max_ticks.is_some_and(|m| self.stats.ticks >= m) {
                break RunEnd::Duration;
            }
            if let Some(end) = self.tick(&tick, bus, clock) {
                break end;
            }
        };
        self.stats.page_faults_in_loop = faults_before
            .zip(crate::rt::thread_minor_faults())
            .map(|(before, after)| after.saturating_sub(before));
        let why = match why {
            RunEnd::Interrupted | RunEnd::Duration | RunEnd::Health => {
                match self.finish_step(schedule, bus, clock, stop) {
                    Some(fault @ (RunEnd::ReadsFailed | RunEnd::PortLost)) => fault,
                    _ => why,
                }
            }
            _ => why,
        };
        self.input.stop_producers();
        if let Some(r) = &self.retarget {
            self.stats.retarget = Some(r.report());
        }
        if let Some(b) = &self.balance {
            self.stats.imu = Some(b.report());
        }
        if let Some(h) = &self.health {
            self.stats.health = Some(h.report());
        }
        self.stats.fidelity = Some(self.fidelity_report());
        if matches!(why, RunEnd::ReadsFailed | RunEnd::PortLost) {
            self.record_final_present();
            return why;
        }
        self.finish(schedule, bus, clock, stop);
        self.record_final_present();
        // The port may fail during the ramp: that, not the reason the ramp began, is the end.
        if self.port_error.is_some() {
            return RunEnd::PortLost;
        }
        why
    }

    /// A walk stopped with a foot in the air goes on with its plan until both feet are down,
    /// for at most [`FINISH_STEP_S`] (a further stop request cuts it short): the ramp to the
    /// stance then starts from a double support, not from one leg. What ended the ticks when
    /// one did.
    fn finish_step(
        &mut self,
        schedule: &mut Schedule,
        bus: &mut dyn ServoBus,
        clock: &mut dyn Clock,
        stop: &StopRequests,
    ) -> Option<RunEnd> {
        if !self.retarget.as_ref().is_some_and(|r| r.walking()) {
            return None;
        }
        let requests = stop.made();
        let limit = (FINISH_STEP_S * self.config.rate_hz).ceil() as usize;
        for _ in 0..limit {
            if self.preview.current().is_none_or(|c| c.contact == [true, true]) {
                break;
            }
            let tick = schedule.wait(clock);
            if stop.made() > requests {
                break;
            }
            if let Some(end) = self.tick(&tick, bus, clock) {
                return Some(end);
            }
        }
        None
    }

    /// The end of a run: ramp to the rest pose (every angle 0, or the one set: a walk's
    /// stance) or hold, then torque off. A stop request
    /// made during the ramp (the second, when a request ended the loop) cuts it short; so does
    /// the port failing.
    fn finish(
        &mut self,
        schedule: &mut Schedule,
        bus: &mut dyn ServoBus,
        clock: &mut dyn Clock,
        stop: &StopRequests,
    ) {
        let (ticks, to_rest) = match self.config.stop {
            // Nothing was commanded yet: the servos stand where they started.
            _ if !self.have_input => (0, false),
            StopMode::Rest { ramp_s } => ((ramp_s.max(0.0) * self.config.rate_hz).ceil() as usize, true),
            StopMode::Hold { hold_s } => ((hold_s.max(0.0) * self.config.rate_hz).ceil() as usize, false),
        };
        // From the last command (what the servos were sent, the plan's lead included).
        let from: Vec<f64> = self
            .rig
            .servos
            .iter()
            .zip(self.stage.last())
            .map(|(s, t)| s.ticks_to_angle(f64::from(*t)))
            .collect();
        let dt = self.period_ns as f64 * 1e-9;
        // No feedback is read while stopping: its last correction fades out within the limits.
        self.stage.set_correction(&[]);
        let requests_at_start = stop.made();
        // After the ramp, up to two more seconds for the rate limits to arrive at rest.
        let extra = if to_rest {
            (2.0 * self.config.rate_hz).ceil() as usize
        } else {
            0
        };
        for k in 1..=ticks + extra {
            let tick = schedule.wait(clock);
            if stop.made() > requests_at_start {
                break;
            }
            if k > ticks && !to_rest {
                break;
            }
            let mut arrived = false;
            let goals: Vec<i32> = if to_rest && self.have_input {
                let w = crate::interp::ease_weight(k.min(ticks), ticks + 1);
                let angles: Vec<f64> = match &self.rest_pose {
                    Some(rest) => from.iter().zip(rest).map(|(a, r)| a + w * (r - a)).collect(),
                    None => from.iter().map(|a| a * (1.0 - w)).collect(),
                };
                match self.stage.command(&self.rig, &angles, dt) {
                    Ok((g, limited)) => {
                        arrived = k >= ticks && limited.rate_limited == 0;
                        g.to_vec()
                    }
                    Err(_) => self.stage.last().to_vec(),
                }
            } else {
                self.stage.last().to_vec()
            };
            // Stalled past the watchdog, the servos refuse the ramp: recovered, they go on
            // from where they stopped (the stage restarted there, within its limits).
            let now = clock.now_ns();
            let goals = match self.check_watchdog(&tick, bus, clock, now, false) {
                Some(watchdog::Checked { hold: Some(h), .. }) => h[..self.ids.len()].to_vec(),
                _ => goals,
            };
            let written = bus.write_goals(&self.ids, &goals);
            if let Some(why) = written.as_ref().err().and_then(BusError::port_failure) {
                self.port_error = Some(why);
                break;
            }
            let read_ok = bus.read_positions(&self.ids, &mut self.reads.read_buf).is_ok();
            self.note_sent(clock.now_ns());
            if read_ok {
                self.reads.present.copy_from_slice(&self.reads.read_buf);
                self.reads.last_valid_ns = clock.now_ns();
            }
            if !self.sinks.telemetry.is_empty() {
                let len = self.reads.present.len().min(MAX_SERVOS);
                let mut t = Telemetry {
                    index: tick.index,
                    deadline_ns: tick.deadline_ns,
                    woke_ns: tick.woke_ns,
                    read_ok,
                    servos: len,
                    read_ns: self.reads.last_valid_ns,
                    stopping: true,
                    ..Telemetry::default()
                };
                t.present[..len].copy_from_slice(&self.reads.present[..len]);
                self.emit(&t);
            }
            if arrived {
                break;
            }
        }
        self.stats.torque_off_acknowledged = Some(torque_off(bus, &self.ids).acknowledged);
    }

    /// Puts the last valid read's positions, by servo name, into the statistics.
    fn record_final_present(&mut self) {
        let angles = self.present_angles();
        self.stats.final_present = angles
            .into_iter()
            .enumerate()
            .map(|(k, rad)| stats::ServoAngle {
                name: self
                    .servo_names
                    .get(k)
                    .cloned()
                    .unwrap_or_else(|| format!("servo {}", k + 1)),
                rad,
            })
            .collect();
    }
}

/// What a torque-off achieved.
#[derive(Debug)]
pub struct TorqueOff {
    /// Servos that acknowledged their torque-off write.
    pub acknowledged: usize,
    /// The first error, if any.
    pub error: Option<BusError>,
}

/// Torque off on every servo: one Sync Write (no replies needed, so it gets through a bus whose
/// reads fail), then each servo on its own, acknowledged: asked again as
/// [`crate::bus::retried_quickly`] does when the acknowledgement is lost or late on a busy line. Not
/// when the port itself failed.
pub fn torque_off(bus: &mut dyn ServoBus, ids: &[u8]) -> TorqueOff {
    let zeros = [0u8; MAX_SERVOS];
    let n = ids.len().min(MAX_SERVOS);
    let mut error = bus
        .sync_write(addr::TORQUE_ENABLE, 1, &ids[..n], &zeros[..n])
        .err();
    let mut acknowledged = 0;
    if error.as_ref().and_then(BusError::port_failure).is_none() {
        for &id in &ids[..n] {
            match crate::bus::retried_quickly(|| bus.set_torque(id, false)) {
                Ok(()) => acknowledged += 1,
                Err(e) => {
                    error.get_or_insert(e);
                }
            }
        }
    }
    TorqueOff { acknowledged, error }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bus::PingInfo;

    /// A bus whose servo 5 loses its first acknowledgement, and whose servo 9 never answers.
    #[derive(Default)]
    struct LossyBus {
        writes: Vec<u8>,
    }

    impl ServoBus for LossyBus {
        fn ping(&mut self, id: u8) -> Result<PingInfo, BusError> {
            Err(BusError::Timeout { id })
        }
        fn scan(&mut self) -> Result<Vec<PingInfo>, BusError> {
            Ok(Vec::new())
        }
        fn read(&mut self, id: u8, _: u16, _: &mut [u8]) -> Result<(), BusError> {
            Err(BusError::Timeout { id })
        }
        fn write(&mut self, id: u8, _: u16, _: &[u8]) -> Result<(), BusError> {
            self.writes.push(id);
            let tries = self.writes.iter().filter(|&&w| w == id).count();
            match id {
                5 if tries == 1 => Err(BusError::Timeout { id }),
                9 => Err(BusError::Timeout { id }),
                _ => Ok(()),
            }
        }
        fn sync_write(&mut self, _: u16, _: u16, _: &[u8], _: &[u8]) -> Result<(), BusError> {
            Ok(())
        }
        fn sync_read(&mut self, _: u16, _: u16, ids: &[u8], _: &mut [u8]) -> Result<(), BusError> {
            Err(BusError::Timeout { id: ids[0] })
        }
        fn reboot(&mut self, _: u8) -> Result<(), BusError> {
            Ok(())
        }
    }

    #[test]
    fn a_lost_torque_off_acknowledgement_is_asked_for_again() {
        let mut bus = LossyBus::default();
        let done = torque_off(&mut bus, &[1, 5, 7]);
        assert_eq!(done.acknowledged, 3, "{done:?}");
        assert_eq!(bus.writes, vec![1, 5, 5, 7]);

        // A servo that never answers is asked a bounded number of times and reported.
        let mut bus = LossyBus::default();
        let done = torque_off(&mut bus, &[9, 1]);
        assert_eq!(done.acknowledged, 1);
        assert!(matches!(done.error, Some(BusError::Timeout { id: 9 })));
        assert_eq!(bus.writes.iter().filter(|&&w| w == 9).count(), crate::bus::TRIES);
    }
}
