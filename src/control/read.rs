//! A read taken after a tick's Sync Write: the present positions, tracking against the goals the
//! servos had a period to reach, fidelity against that tick's source, and the fault policy (a
//! failure counted; torque off after the torque-off time without a valid read).

use super::{fidelity, torque_off, Controller, RunEnd};
use crate::bus::{BusError, ServoBus};
use crate::servo::{MAX_SERVOS, TICKS_PER_TURN};

/// What a read taken after a tick's Sync Write belongs to (kept until a pipelined read's
/// replies are taken).
#[derive(Clone, Copy)]
pub(super) struct ReadContext {
    /// Due time of the tick's source sample (the fidelity's reference, in the preview).
    pub(super) sample_due: u64,
    /// Whether the tick held its last command.
    pub(super) holding: bool,
    /// The goals it wrote.
    pub(super) goals: [i32; MAX_SERVOS],
    /// The goals written a tick before, which the servos had a period to reach.
    pub(super) tracked: Option<[i32; MAX_SERVOS]>,
    /// Whether the read counts for fidelity (input flowing, not held, eased in, past the
    /// pre-roll).
    pub(super) record: bool,
    /// The tick's index.
    pub(super) tick: u64,
}

/// What a read gave.
pub(super) struct Absorbed {
    pub(super) ok: bool,
    pub(super) tracking: f64,
    pub(super) end: Option<RunEnd>,
}

/// What the servos reported, and what the reads are paired with.
pub(super) struct Reads {
    /// The last valid read's positions.
    pub(super) present: Vec<i32>,
    pub(super) read_buf: Vec<i32>,
    /// A pipelined read on the wire and the tick it belongs to.
    pub(super) in_flight: Option<ReadContext>,
    /// Goals of the previous tick's write: what the servos had a period to reach.
    pub(super) previous_goals: Vec<i32>,
    pub(super) have_previous: bool,
    /// Consecutive failed reads.
    pub(super) failures: u32,
    /// When the last valid read was taken, ns.
    pub(super) last_valid_ns: u64,
}

/// Source against present, end to end: accumulated by the worker when there is one, or here.
pub(super) struct Measure {
    /// The accumulation in the tick (without a worker; a worker's, once it has finished).
    pub(super) sink: Box<fidelity::FidelitySink>,
    pub(super) worker: Option<fidelity::FidelityWorker>,
    /// This tick's source angles (the input mapped through the rig).
    pub(super) source_angles: Vec<f64>,
    /// The present angles (for the retargeting's effectors).
    pub(super) present_angles: Vec<f64>,
    /// The due time of the last sample handed over whole, and the number of the last one
    /// begun.
    pub(super) sample_sent: (Option<u64>, u64),
    /// Reads not compared: refused by a full channel, or their sample was.
    pub(super) dropped: u64,
    /// Each tick's source angles with its deadline (ns), up to the capacity reserved by
    /// [`Controller::log_source`]; never grown in a tick.
    pub(super) source_log: Vec<(u64, [f64; MAX_SERVOS])>,
}

impl Measure {
    /// Hands `m` to the worker, or takes it here without one (false: refused).
    fn send(&mut self, m: fidelity::Message) -> bool {
        match &mut self.worker {
            Some(w) => w.send(m),
            None => {
                self.sink.take(&m);
                true
            }
        }
    }
}

impl Controller {
    /// Takes a read made after the Sync Write of the tick described by `context`: the present
    /// positions, tracking against the goals the servos had a period to reach, fidelity
    /// against that tick's source; a failure counted, and torque off after the torque-off
    /// time without a valid read. Returns what it found and why the port failed, if it did.
    pub(super) fn absorb_read(
        &mut self,
        read: Result<(), BusError>,
        at_ns: u64,
        context: &ReadContext,
        bus: &mut dyn ServoBus,
    ) -> (Absorbed, Option<std::io::Error>) {
        let len = self.ids.len();
        let mut found = Absorbed {
            ok: read.is_ok(),
            tracking: f64::NAN,
            end: None,
        };
        match read {
            Ok(()) => {
                self.reads.present.copy_from_slice(&self.reads.read_buf);
                self.stats.reads_ok += 1;
                self.reads.failures = 0;
                self.reads.last_valid_ns = at_ns;
                if context.holding {
                    // Back from a hold: the next command starts, at rest, from the one held.
                    self.stage.start_from(&self.rig, &context.goals[..len]);
                }
                if let Some(goals) = &context.tracked {
                    let mut sq = 0.0;
                    for (s, (g, p)) in self.rig.servos.iter().zip(goals.iter().zip(&self.reads.present)) {
                        let deg =
                            f64::from(g - p) * 360.0 / f64::from(TICKS_PER_TURN) / s.gear.abs().max(1e-9);
                        self.stats.tracking(deg);
                        sq += deg * deg;
                    }
                    found.tracking = (sq / len.max(1) as f64).sqrt();
                }
                if context.record {
                    self.record_fidelity(context.tick, context.sample_due);
                }
                (found, None)
            }
            Err(e) => {
                self.stats.bus_error(e.kind());
                self.reads.failures = self.reads.failures.saturating_add(1);
                let lost = e.port_failure();
                let silent_ms = (at_ns.saturating_sub(self.reads.last_valid_ns)) as f64 * 1e-6;
                if lost.is_none() && silent_ms >= self.config.torque_off_after_ms {
                    self.stats.torque_off_acknowledged = Some(torque_off(bus, &self.ids).acknowledged);
                    found.end = Some(RunEnd::ReadsFailed);
                }
                (found, lost)
            }
        }
    }

    /// Source against present for this tick (after a valid read): the tick's sample, once,
    /// then the read against it; the angles, effectors and lags are found by the sink.
    /// Allocates nothing.
    fn record_fidelity(&mut self, tick: u64, sample_due: u64) {
        // The tick's sample is still in the preview (current, or just behind it); not after a
        // restart, which nothing is compared across.
        let Some(sample) = self.preview.find(sample_due) else {
            return;
        };
        let n = self.ids.len();
        let measure = &mut self.measure;
        if measure.sample_sent.0 != Some(sample.due_ns) {
            let seq = measure.sample_sent.1 + 1;
            // The effectors from the skeleton's pose (with a scale, without a retargeting).
            let channels = (self.config.effector_metres_per_unit > 0.0 && self.retarget.is_none())
                .then(|| &sample.channels[..self.skeleton.channel_count()]);
            let whole = fidelity::send_sample(
                seq,
                &sample.angles[..n],
                channels,
                sample.tips,
                sample.effectors,
                |m| measure.send(m),
            );
            measure.sample_sent = (whole.then_some(sample.due_ns), seq);
        }
        if measure.sample_sent.0 != Some(sample.due_ns) {
            measure.dropped += 1;
            return;
        }
        let mut read = fidelity::TickRead::new(tick, measure.sample_sent.1, &self.reads.present);
        if let Some(r) = &mut self.retarget {
            fidelity::angles_of_ticks(&self.rig, &self.reads.present, &mut measure.present_angles);
            read.effectors = r.present_effectors(&self.rig, &measure.present_angles, sample.base);
        }
        if !measure.send(fidelity::Message::Read(read)) {
            measure.dropped += 1;
        }
    }
}
