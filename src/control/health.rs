//! The servos' health, watched from the loop: Present Input Voltage and Present Temperature
//! (one Read of 3 bytes at 144) and Hardware Error Status (70), one servo at a time, a read
//! every few ticks. A pipelined loop reads it in the position read's slot — that tick's
//! request is the health Read, its reply taken next tick, so it costs one tick's positions
//! and no time; otherwise it is a Read of its own in the bus's idle slot. Thresholds
//! per model: a warning first; then the run ends, eased to rest and torque off, naming the
//! servo and why — before the servo's own shutdown drops a limb mid-motion. A servo that did
//! shut itself down sets the alert flag in every reply; the loop hands it on
//! ([`HealthWatch::alert`]) and its Hardware Error Status is read at the next slot.

use serde::Serialize;

use crate::bus::ServoBus;
use crate::servo::{addr, ServoModel};

/// Health reads per second the watch makes (each one servo's voltage and temperature, or its
/// Hardware Error Status): a 28-servo rig has every servo's figures every 5.6 s.
pub const READS_PER_S: f64 = 10.0;

/// Below the model's Temperature Limit (where the servo shuts itself down), °C: warn here…
pub const WARN_BELOW_LIMIT_C: u8 = 15;
/// …and ease to rest here.
pub const STOP_BELOW_LIMIT_C: u8 = 5;

/// A supply this far below the profile's warns (a battery sagging), as a share.
pub const WARN_SUPPLY_SAG: f64 = 0.1;

/// The data bytes of the voltage and temperature read (144: 2 bytes of 0.1 V, 146: 1 byte °C).
const VITALS_BYTES: usize = 3;

/// One read of the watch: a servo's voltage and temperature, or its Hardware Error Status.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct HealthItem {
    /// The servo's place in the watch.
    pub servo: usize,
    /// Its id.
    pub id: u8,
    /// The address read.
    pub address: u16,
    /// Bytes read.
    pub len: u16,
}

/// One servo's figures as last read.
#[derive(Clone, Debug, Default, Serialize)]
pub struct ServoHealth {
    /// Bus id.
    pub id: u8,
    /// Name.
    pub name: String,
    /// Present Temperature as last read, °C.
    pub temperature_c: Option<u8>,
    /// The hottest read, °C.
    pub hottest_c: Option<u8>,
    /// Present Input Voltage as last read, V.
    pub voltage_v: Option<f64>,
    /// The lowest read, V.
    pub lowest_v: Option<f64>,
    /// Hardware Error Status as last read.
    pub hardware_error: u8,
    /// Whether it crossed a warning threshold.
    pub warned: bool,
}

/// What the watch saw in a run (the stats JSON's `health` block).
#[derive(Clone, Debug, Default, Serialize)]
pub struct HealthReport {
    /// Reads made.
    pub reads: u64,
    /// Reads that failed (the position reads' faults count there; a failed health read is
    /// tried again at the servo's next turn).
    pub reads_failed: u64,
    /// Hardware Error Status reads made out of turn because a reply had the alert flag
    /// (counted in `reads` too).
    pub alert_reads: u64,
    /// Every servo's figures.
    pub servos: Vec<ServoHealth>,
    /// The warnings, a line each (the first per servo and cause).
    pub warnings: Vec<String>,
    /// Why the run was ended, when the watch ended it: which servo and why.
    pub stopped: Option<String>,
}

/// The thresholds of one servo.
#[derive(Clone, Copy, Debug)]
struct Thresholds {
    limit_c: u8,
    warn_c: u8,
    stop_c: u8,
    warn_below_v: f64,
    min_v: f64,
    max_v: f64,
}

impl Thresholds {
    fn of(model: &ServoModel, supply_v: f64) -> Thresholds {
        Thresholds {
            limit_c: model.temperature_limit,
            warn_c: model.temperature_limit.saturating_sub(WARN_BELOW_LIMIT_C),
            stop_c: model.temperature_limit.saturating_sub(STOP_BELOW_LIMIT_C),
            warn_below_v: supply_v * (1.0 - WARN_SUPPLY_SAG),
            min_v: model.min_v,
            max_v: model.max_v,
        }
    }
}

/// What the watch saw, kept as figures in the tick (no text is made there).
#[derive(Clone, Copy, Debug, PartialEq)]
enum Event {
    Warm { servo: usize, celsius: u8 },
    Sagging { servo: usize, volts: f64 },
    Hot { servo: usize, celsius: u8 },
    Supply { servo: usize, volts: f64 },
    HardwareError { servo: usize, bits: u8 },
}

/// The watch: [`HealthWatch::read`] once a tick; every `every` ticks it reads the next item.
/// Nothing in it allocates after [`HealthWatch::new`].
#[derive(Debug)]
pub struct HealthWatch {
    every: u32,
    countdown: u32,
    /// The servo whose turn it is, and whether its error status (rather than its vitals) is
    /// read next.
    next: usize,
    error_next: bool,
    /// The last read failed: the same item once more.
    retrying: bool,
    limits: Vec<Thresholds>,
    servos: Vec<ServoHealth>,
    reads: u64,
    reads_failed: u64,
    /// The warnings (room for one of each kind per servo).
    events: Vec<Event>,
    stopped: Option<Event>,
    /// The hottest servo's (id, °C) by the last readings, kept as they arrive.
    hottest: Option<(u8, u8)>,
    /// Per servo: warned of heat, of the supply.
    warned: Vec<(bool, bool)>,
    /// The servo whose Hardware Error Status is read at the next slot, out of turn: a reply
    /// of its had the alert flag ([`HealthWatch::alert`]).
    alerted: Option<usize>,
    /// That read, on the wire; and whether it is the second try.
    alert_in_flight: Option<HealthItem>,
    alert_retried: bool,
    /// Per servo: a read out of turn found no error, so its alerts are not followed until its
    /// next read in turn (a flag that stays on cannot take every other position read).
    alert_cleared: Vec<bool>,
    alert_reads: u64,
}

impl HealthWatch {
    /// A watch over `servos` (id, name, model, supply) at a loop of `rate_hz`, reading
    /// [`READS_PER_S`] items a second.
    #[must_use]
    pub fn new(servos: &[(u8, String, &'static ServoModel, f64)], rate_hz: f64) -> HealthWatch {
        let every = (rate_hz / READS_PER_S).round().max(1.0) as u32;
        HealthWatch {
            every,
            countdown: every,
            next: 0,
            error_next: false,
            retrying: false,
            hottest: None,
            limits: servos.iter().map(|(_, _, m, v)| Thresholds::of(m, *v)).collect(),
            servos: servos
                .iter()
                .map(|(id, name, _, _)| ServoHealth {
                    id: *id,
                    name: name.clone(),
                    ..ServoHealth::default()
                })
                .collect(),
            reads: 0,
            reads_failed: 0,
            events: Vec::with_capacity(2 * servos.len()),
            stopped: None,
            warned: vec![(false, false); servos.len()],
            alerted: None,
            alert_in_flight: None,
            alert_retried: false,
            alert_cleared: vec![false; servos.len()],
            alert_reads: 0,
        }
    }

    /// A reply of servo `id` had the hardware-alert flag: its Hardware Error Status is read at
    /// the next slot rather than at its turn (up to a round of reads away: 5.6 s for 28
    /// servos), so that a servo that shut itself down ends the run within a few ticks. Ids the
    /// watch does not have, and servos whose last read out of turn found no error, are passed
    /// over.
    pub fn alert(&mut self, id: u8) {
        if self.stopped.is_some() || self.alerted.is_some() || self.alert_in_flight.is_some() {
            return;
        }
        if let Some(k) = self.servos.iter().position(|s| s.id == id) {
            if !self.alert_cleared[k] {
                self.alerted = Some(k);
            }
        }
    }

    /// A watch over every servo of `profile` (with its model and supply) at a loop of
    /// `rate_hz`.
    #[must_use]
    pub fn of_profile(profile: &crate::profile::Profile, rate_hz: f64) -> HealthWatch {
        let servos: Vec<_> = profile
            .servos
            .iter()
            .map(|s| (s.id, s.name.clone(), s.model, s.supply_v))
            .collect();
        HealthWatch::new(&servos, rate_hz)
    }

    /// Ticks between reads.
    #[must_use]
    pub fn every(&self) -> u32 {
        self.every
    }

    /// Reads the next item when its tick has come (a Read of its own, in the bus's idle slot);
    /// `true` when a servo's health ends the run.
    pub fn read(&mut self, bus: &mut dyn ServoBus) -> bool {
        if let Some(item) = self.due() {
            let mut b = [0u8; VITALS_BYTES];
            let out = &mut b[..usize::from(item.len)];
            let got = bus.read(item.id, item.address, out);
            self.absorb(item, got.map(|()| &*out).ok());
        }
        self.stopped.is_some()
    }

    /// Counts a tick; the item to read when its tick has come (`None` otherwise, and once the
    /// watch has ended the run).
    pub fn due(&mut self) -> Option<HealthItem> {
        if self.servos.is_empty() || self.stopped.is_some() {
            return None;
        }
        if let Some(k) = self.alerted.take() {
            let item = HealthItem {
                servo: k,
                id: self.servos[k].id,
                address: addr::HARDWARE_ERROR_STATUS,
                len: 1,
            };
            self.alert_in_flight = Some(item);
            return Some(item);
        }
        self.countdown -= 1;
        if self.countdown > 0 {
            return None;
        }
        self.countdown = self.every;
        let id = self.servos[self.next].id;
        Some(if self.error_next {
            HealthItem {
                servo: self.next,
                id,
                address: addr::HARDWARE_ERROR_STATUS,
                len: 1,
            }
        } else {
            HealthItem {
                servo: self.next,
                id,
                address: addr::PRESENT_INPUT_VOLTAGE,
                len: VITALS_BYTES as u16,
            }
        })
    }

    /// Judges what `item`'s read gave (`None`: the read failed — the same item is read once
    /// more at the next slot, then the watch moves on); `true` when a servo's health ends the
    /// run.
    pub fn absorb(&mut self, item: HealthItem, data: Option<&[u8]>) -> bool {
        let k = item.servo;
        self.reads += 1;
        if self.alert_in_flight == Some(item) {
            self.absorb_alert_read(k, data);
            return self.stopped.is_some();
        }
        match data {
            Some(d) if item.address == addr::HARDWARE_ERROR_STATUS && !d.is_empty() => {
                self.alert_cleared[k] = false;
                self.judge_error(k, d[0]);
            }
            Some(d) if d.len() >= VITALS_BYTES => {
                self.judge_vitals(k, f64::from(u16::from_le_bytes([d[0], d[1]])) / 10.0, d[2]);
            }
            _ => {
                self.reads_failed += 1;
                if !self.retrying {
                    self.retrying = true;
                    return self.stopped.is_some();
                }
            }
        }
        self.retrying = false;
        if self.error_next {
            self.next = (self.next + 1) % self.servos.len();
        }
        self.error_next = !self.error_next;
        self.stopped.is_some()
    }

    /// The reply to a read out of turn ([`HealthWatch::alert`]); the rotation goes on where it
    /// was. A failed read is tried once more at the next slot.
    fn absorb_alert_read(&mut self, k: usize, data: Option<&[u8]>) {
        self.alert_in_flight = None;
        self.alert_reads += 1;
        match data.and_then(|d| d.first()) {
            Some(&bits) => {
                self.alert_retried = false;
                self.alert_cleared[k] = bits == 0;
                self.judge_error(k, bits);
            }
            None => {
                self.reads_failed += 1;
                if !self.alert_retried {
                    self.alert_retried = true;
                    self.alerted = Some(k);
                } else {
                    self.alert_retried = false;
                }
            }
        }
    }

    fn judge_error(&mut self, k: usize, bits: u8) {
        self.servos[k].hardware_error = bits;
        if bits != 0 {
            self.servos[k].warned = true;
            self.stopped = Some(Event::HardwareError { servo: k, bits });
        }
    }

    fn judge_vitals(&mut self, k: usize, volts: f64, celsius: u8) {
        let t = self.limits[k];
        let s = &mut self.servos[k];
        s.voltage_v = Some(volts);
        s.temperature_c = Some(celsius);
        s.hottest_c = Some(s.hottest_c.map_or(celsius, |h| h.max(celsius)));
        s.lowest_v = Some(s.lowest_v.map_or(volts, |l| l.min(volts)));
        // Once per reading, not per tick: the hottest may be this one, or, when it cooled,
        // another.
        self.hottest = self
            .servos
            .iter()
            .filter_map(|s| s.temperature_c.map(|t| (s.id, t)))
            .max_by_key(|&(_, t)| t);
        let s = &mut self.servos[k];
        if celsius >= t.stop_c {
            s.warned = true;
            self.stopped = Some(Event::Hot { servo: k, celsius });
            return;
        }
        if !(t.min_v..=t.max_v).contains(&volts) {
            s.warned = true;
            self.stopped = Some(Event::Supply { servo: k, volts });
            return;
        }
        let (heat, supply) = &mut self.warned[k];
        if celsius >= t.warn_c && !*heat {
            *heat = true;
            s.warned = true;
            self.events.push(Event::Warm { servo: k, celsius });
        }
        if volts < t.warn_below_v && !*supply {
            *supply = true;
            s.warned = true;
            self.events.push(Event::Sagging { servo: k, volts });
        }
    }

    /// Whether a servo's health has ended the run.
    #[must_use]
    pub fn has_stopped(&self) -> bool {
        self.stopped.is_some()
    }

    /// The hottest servo read so far: (id, °C).
    #[must_use]
    pub fn hottest(&self) -> Option<(u8, u8)> {
        self.hottest
    }

    /// Why the watch ended the run, in words, when it did.
    #[must_use]
    pub fn stopped(&self) -> Option<String> {
        self.stopped.map(|e| self.describe(e))
    }

    fn describe(&self, e: Event) -> String {
        let who = |k: usize| format!("id {} {}", self.servos[k].id, self.servos[k].name);
        match e {
            Event::Warm { servo, celsius } => format!(
                "{}: {celsius} °C, warm (it eases to rest at {} °C)",
                who(servo),
                self.limits[servo].stop_c
            ),
            Event::Sagging { servo, volts } => format!(
                "{}: supply {volts:.1} V, more than {:.0} % below the profile's",
                who(servo),
                WARN_SUPPLY_SAG * 100.0
            ),
            Event::Hot { servo, celsius } => format!(
                "{}: {celsius} °C, {} °C below its Temperature Limit of {} °C",
                who(servo),
                self.limits[servo].limit_c.saturating_sub(celsius),
                self.limits[servo].limit_c
            ),
            Event::Supply { servo, volts } => format!(
                "{}: supply {volts:.1} V, outside the model's {}…{} V",
                who(servo),
                self.limits[servo].min_v,
                self.limits[servo].max_v
            ),
            Event::HardwareError { servo, bits } => format!(
                "{}: hardware error {}",
                who(servo),
                crate::bus::hardware_error_names(bits)
            ),
        }
    }

    /// What it saw.
    #[must_use]
    pub fn report(&self) -> HealthReport {
        HealthReport {
            reads: self.reads,
            reads_failed: self.reads_failed,
            alert_reads: self.alert_reads,
            servos: self.servos.clone(),
            warnings: self.events.iter().map(|&e| self.describe(e)).collect(),
            stopped: self.stopped(),
        }
    }
}
