//! A rig checked against its profile before its first motion: one finding a line, each with
//! what to do, and the writes that can be made safely (`--fix`).
//!
//! What is read (X-series control table, the e-manual's units): every profiled id's ping
//! (missing, other model, ids the profile does not name), Hardware Error Status (70), Return
//! Delay Time (9, 2 µs), Operating Mode (11), Status Return Level (68), the EEPROM limits
//! (position 48/52, velocity 44 in 0.229 rev/min, current 38, PWM 36, voltage 32/34 in 0.1 V,
//! temperature 31 in °C) against the profile's and the model's factory values, Present Input
//! Voltage (144) and Present Temperature (146) against the model's range, and the loop's cycle
//! measured on the bus against the planner ([`crate::budget`]).

use std::time::Instant;

use serde::Serialize;

use crate::budget;
use crate::bus::{retried, BusError, PingInfo, Registers, ServoBus, PATIENCE};
use crate::profile::{BusConfig, Profile, ServoSpec};
use crate::servo::addr;

/// How bad a finding is.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Level {
    /// As the profile wants it.
    Ok,
    /// The rig runs, but not as well or as safely as it could.
    Warn,
    /// The rig cannot run the profile until this is fixed.
    Fault,
}

/// What puts a finding right, on one servo.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Fix {
    /// The servo.
    pub id: u8,
    /// What is done to it.
    pub action: FixAction,
    /// The baud the servo answers at, when not the profile's (a servo found by
    /// [`search_bauds`]): the write is made there ([`apply_baud_fixes`]).
    pub at_baud: Option<u32>,
}

/// A fix's transaction.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum FixAction {
    /// Bytes written at an address, little-endian (EEPROM items with torque off).
    Write {
        /// The address.
        address: u16,
        /// The bytes.
        data: Vec<u8>,
    },
    /// The Reboot instruction: the servo restarts with its RAM at its defaults (torque off)
    /// and its Hardware Error Status cleared — what a hardware error needs once its cause is
    /// gone.
    Reboot,
}

/// How long a rebooted servo is given to answer again.
const REBOOT_WAIT: std::time::Duration = std::time::Duration::from_secs(2);

/// One thing found.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Finding {
    /// How bad.
    pub level: Level,
    /// The servo's id, when it is about one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub id: Option<u8>,
    /// The profile's name for it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub servo: Option<String>,
    /// What was found.
    pub what: String,
    /// What to do (empty when nothing is to be done).
    #[serde(skip_serializing_if = "String::is_empty")]
    pub todo: String,
    /// Whether `--fix` can put it right.
    pub fixable: bool,
    /// The write that would.
    #[serde(skip)]
    pub fix: Option<Fix>,
    /// For a profiled servo that does not answer at the profile's baud: whether it was found
    /// at another.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub unreachable: Option<Unreachable>,
}

/// A profiled servo that does not answer at the profile's baud.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Unreachable {
    /// Not found (at the profile's baud, or at any baud searched).
    Silent,
    /// Found answering at this baud.
    AtBaud(u32),
}

/// The whole check.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Report {
    /// Every finding, in the order checked.
    pub findings: Vec<Finding>,
    /// What `--fix` wrote.
    pub fixed: Vec<String>,
    /// The loop's cycle measured on this bus (a Sync Write and the profile's read), µs, p50.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub measured_cycle_us: Option<f64>,
    /// The planner's cycle for the profile, µs.
    pub planned_cycle_us: f64,
}

impl Report {
    /// Whether the rig can run the profile: no fault.
    #[must_use]
    pub fn can_run(&self) -> bool {
        self.findings.iter().all(|f| f.level != Level::Fault)
    }

    /// Findings at `level`.
    pub fn at(&self, level: Level) -> impl Iterator<Item = &Finding> {
        self.findings.iter().filter(move |f| f.level == level)
    }

    fn push(&mut self, level: Level, servo: Option<&ServoSpec>, what: String, todo: &str, fix: Option<Fix>) {
        self.findings.push(Finding {
            level,
            id: servo.map(|s| s.id),
            servo: servo.map(|s| s.name.clone()),
            what,
            todo: todo.to_string(),
            fixable: fix.is_some(),
            fix,
            unreachable: None,
        });
    }

    /// Whether any profiled servo is silent at every baud looked at.
    #[must_use]
    pub fn has_silent(&self) -> bool {
        self.findings
            .iter()
            .any(|f| f.unreachable == Some(Unreachable::Silent))
    }

    /// How many profiled servos do not answer at the profile's baud.
    #[must_use]
    pub fn unreachable(&self) -> usize {
        self.findings.iter().filter(|f| f.unreachable.is_some()).count()
    }

    fn mark_last(&mut self, unreachable: Unreachable) {
        if let Some(f) = self.findings.last_mut() {
            f.unreachable = Some(unreachable);
        }
    }
}

/// Velocity Limit's unit, rev/min.
const VELOCITY_UNIT_RPM: f64 = 0.229;

/// The highest PWM Limit (36) of the X series: full output.
const FULL_PWM: u32 = 885;

/// How far below its limit a servo's temperature is worth a warning, °C.
const TEMPERATURE_MARGIN_C: u32 = 10;

/// Loop cycles timed for the measured cycle.
const TIMED_CYCLES: usize = 40;

/// The bus settings to open a rig with as it stands, before start-up sets it: `bus` with
/// replies allowed the longest Return Delay Time (254 × 2 µs) and an adapter's default
/// latency timer, and no pipelining.
#[must_use]
pub fn bus_as_found(bus: &BusConfig) -> BusConfig {
    let mut lenient = bus.clone();
    lenient.return_delay_us = 508;
    lenient.usb_latency_us = lenient.usb_latency_us.max(16_000);
    lenient.pipeline = false;
    lenient
}

/// Checks the rig on `bus` (opened with [`bus_as_found`]) against `profile`.
///
/// # Errors
/// [`BusError`] when the bus itself fails (a servo that does not answer is a finding).
pub fn examine(bus: &mut dyn ServoBus, profile: &Profile) -> Result<Report, BusError> {
    // The cycle measured below is the servos' (the board's read is not in it).
    let plan = budget::plan(&profile.bus, profile.servos.len(), None);
    let mut report = Report {
        planned_cycle_us: plan.cycle_time_us,
        ..Report::default()
    };
    let mut found = bus.scan()?;
    for s in &profile.servos {
        if !found.iter().any(|p| p.id == s.id) {
            if let Some(p) = (0..2).find_map(|_| bus.ping(s.id).ok()) {
                found.push(p);
            }
        }
    }
    let mut present = Vec::new();
    for s in &profile.servos {
        match found.iter().find(|p| p.id == s.id) {
            None => {
                report.push(
                    Level::Fault,
                    Some(s),
                    format!("id {} does not answer at {} bit/s", s.id, profile.bus.baud),
                    "check its cable and power; it may be at another baud or id (`marionette scan --port PORT --baud B`)",
                    None,
                );
                report.mark_last(Unreachable::Silent);
            }
            Some(p) if p.model_number != s.model.model_number => report.push(
                Level::Fault,
                Some(s),
                format!(
                    "id {} is model {} ({}), the profile says {}",
                    s.id,
                    p.model_number,
                    p.model().map_or("unknown", |m| m.name),
                    s.model.name
                ),
                "put the right servo at this id, or the right model in the profile",
                None,
            ),
            Some(p) => present.push((s, *p)),
        }
    }
    for p in &found {
        let named = profile.servos.iter().any(|s| s.id == p.id) || profile.bus.imu_board == Some(p.id);
        if !named {
            report.findings.push(Finding {
                level: Level::Warn,
                id: Some(p.id),
                servo: None,
                what: format!(
                    "id {} ({}) answers but the profile does not name it",
                    p.id,
                    model_name(p)
                ),
                todo: "add it to the profile, or give it an id the bus does not use".into(),
                fixable: false,
                fix: None,
                unreachable: None,
            });
        }
    }
    if let Some(board) = profile.bus.imu_board {
        if !found.iter().any(|p| p.id == board) {
            report.push(
                Level::Warn,
                None,
                format!("the IMU board at id {board} does not answer"),
                "check the sub-controller's power and its bus; walking runs open loop without it",
                None,
            );
        }
    }
    for (s, _) in &present {
        if let Err(e) = check_servo(bus, profile, s, &mut report) {
            report.push(
                Level::Fault,
                Some(s),
                format!(
                    "its registers could not be read ({e}; tried again for {} ms)",
                    PATIENCE.as_millis()
                ),
                "check the cable and the adapter; `marionette scan` shows what answers",
                None,
            );
        }
    }
    if report.can_run() {
        let (measured, failed) = measure_cycle(bus, profile)?;
        report.measured_cycle_us = measured;
        if failed > 0 {
            report.push(
                if measured.is_some() { Level::Warn } else { Level::Fault },
                None,
                format!("{failed} of the {TIMED_CYCLES} timed cycles lost their read (a reply late, garbled or missing)"),
                "the loop holds after a lost read and stops after several: check the cable, the power and the adapter; `marionette budget PROFILE --measure N` counts them",
                None,
            );
        }
        if let Some(m) = report.measured_cycle_us {
            let ratio = m / plan.cycle_time_us.max(1.0);
            if ratio > 1.25 {
                report.push(
                    Level::Warn,
                    None,
                    format!(
                        "the loop's cycle takes {m:.0} µs on this bus, {ratio:.2}× the planner's {:.0} µs",
                        plan.cycle_time_us
                    ),
                    "lower the adapter's latency timer, Return Delay Time or --rate (`marionette budget PROFILE`)",
                    None,
                );
            } else {
                report.push(
                    Level::Ok,
                    None,
                    format!(
                        "the loop's cycle takes {m:.0} µs on this bus (planned {:.0} µs)",
                        plan.cycle_time_us
                    ),
                    "",
                    None,
                );
            }
        }
    }
    Ok(report)
}

fn model_name(p: &PingInfo) -> &'static str {
    p.model().map_or("unknown model", |m| m.name)
}

/// One servo's registers against the profile and its model.
fn check_servo(
    bus: &mut dyn ServoBus,
    profile: &Profile,
    s: &ServoSpec,
    report: &mut Report,
) -> Result<(), BusError> {
    let id = s.id;
    let m = s.model;
    // The whole table in one read (each tried again on a busy line).
    let registers = Registers::read(bus, id)?;
    let read = |address: u16, n: usize| registers.value(address, n);
    let le = |v: u32, n: usize| v.to_le_bytes()[..n].to_vec();
    let fix = |address: u16, data: Vec<u8>| {
        Some(Fix {
            id,
            action: FixAction::Write { address, data },
            at_baud: None,
        })
    };

    let hw = read(addr::HARDWARE_ERROR_STATUS, 1) as u8;
    if hw != 0 {
        report.push(
            Level::Fault,
            Some(s),
            format!("hardware error {}", crate::bus::hardware_error_names(hw)),
            "remove the cause (load, supply, heat); then --fix reboots it (its torque stays off), or power-cycle the rig",
            Some(Fix {
                id,
                action: FixAction::Reboot,
                at_baud: None,
            }),
        );
    }
    let rdt_us = read(addr::RETURN_DELAY_TIME, 1) * 2;
    if rdt_us > profile.bus.return_delay_us {
        report.push(
            Level::Warn,
            Some(s),
            format!(
                "Return Delay Time {rdt_us} µs, the profile plans {} µs: every read waits longer",
                profile.bus.return_delay_us
            ),
            "--fix writes the profile's (start-up does too)",
            fix(
                addr::RETURN_DELAY_TIME,
                vec![(profile.bus.return_delay_us / 2).min(254) as u8],
            ),
        );
    }
    let srl = read(addr::STATUS_RETURN_LEVEL, 1);
    if srl != 2 {
        report.push(
            Level::Warn,
            Some(s),
            format!("Status Return Level {srl}: writes are not acknowledged"),
            "--fix writes 2 (start-up does too)",
            fix(addr::STATUS_RETURN_LEVEL, vec![2]),
        );
    }
    let mode = read(addr::OPERATING_MODE, 1);
    if mode != 3 {
        report.push(
            Level::Fault,
            Some(s),
            format!("Operating Mode {mode}, not position control (3): goal positions would not move it as planned"),
            "--fix writes 3 with torque off",
            fix(addr::OPERATING_MODE, vec![3]),
        );
    }
    let homing = read(addr::HOMING_OFFSET, 4) as i32;
    match s.homing_offset {
        Some(want) if homing != want => report.push(
            Level::Fault,
            Some(s),
            format!(
                "Homing Offset {homing} ticks, the profile's zero assumes {want}: every angle would be off"
            ),
            "--fix writes the profile's with torque off (start-up does too)",
            fix(addr::HOMING_OFFSET, want.to_le_bytes().to_vec()),
        ),
        None if homing != 0 => report.push(
            Level::Warn,
            Some(s),
            format!("Homing Offset {homing} ticks: the profile's zero was not measured with it"),
            "run `marionette calibrate` (it records the offset it uses), or write 0",
            None,
        ),
        _ => {}
    }
    let (lo, hi) = s.tick_limits();
    let at = read(addr::PRESENT_POSITION, 4) as i32;
    if at < lo || at > hi {
        report.push(
            Level::Fault,
            Some(s),
            format!(
                "present position {at} ticks ({:.0}° by the profile), outside its {lo}…{hi} ({}…{}°): start-up refuses it",
                f64::from(at - s.zero as i32) / (s.direction * s.gear * 4096.0 / 360.0),
                s.min_deg,
                s.max_deg
            ),
            "move the joint inside its range by hand; if it is inside, the zero is wrong: `marionette calibrate`",
            None,
        );
    }
    let max = read(addr::MAX_POSITION_LIMIT, 4) as i32;
    let min = read(addr::MIN_POSITION_LIMIT, 4) as i32;
    if min > lo || max < hi {
        let mut data = le(hi as u32, 4);
        data.extend(le(lo as u32, 4));
        report.push(
            Level::Warn,
            Some(s),
            format!("position limits {min}…{max} ticks, narrower than the profile's {lo}…{hi}: goals past them are refused"),
            "--fix writes the profile's (start-up does too)",
            fix(addr::MAX_POSITION_LIMIT, data),
        );
    }
    let velocity = read(addr::VELOCITY_LIMIT, 4);
    let wanted = (s.max_velocity_dps / 6.0 / VELOCITY_UNIT_RPM).ceil() as u32;
    if velocity < wanted {
        let to = wanted.min(u32::from(m.velocity_limit.1));
        report.push(
            Level::Warn,
            Some(s),
            format!(
                "Velocity Limit {velocity} ({:.0}°/s), below the profile's {:.0}°/s",
                f64::from(velocity) * VELOCITY_UNIT_RPM * 6.0,
                s.max_velocity_dps
            ),
            "--fix raises it to the profile's (within the model's)",
            fix(addr::VELOCITY_LIMIT, le(to, 4)),
        );
    }
    if m.current_limit > 0 {
        let current = read(addr::CURRENT_LIMIT, 2);
        if current < u32::from(m.current_limit) {
            report.push(
                Level::Warn,
                Some(s),
                format!(
                    "Current Limit {current}, below the model's {}: it is weaker than the profile assumes",
                    m.current_limit
                ),
                "--fix writes the model's factory value",
                fix(addr::CURRENT_LIMIT, le(u32::from(m.current_limit), 2)),
            );
        }
    }
    let pwm = read(addr::PWM_LIMIT, 2);
    if pwm < FULL_PWM {
        report.push(
            Level::Warn,
            Some(s),
            format!("PWM Limit {pwm} of {FULL_PWM}: it is weaker and slower than the profile assumes"),
            "--fix writes full output",
            fix(addr::PWM_LIMIT, le(FULL_PWM, 2)),
        );
    }
    let temperature_limit = read(31, 1);
    if temperature_limit != u32::from(m.temperature_limit) {
        report.push(
            Level::Warn,
            Some(s),
            format!(
                "Temperature Limit {temperature_limit} °C, the model's is {} °C",
                m.temperature_limit
            ),
            "--fix writes the model's",
            fix(31, vec![m.temperature_limit]),
        );
    }
    let (vmax, vmin) = (read(32, 2), read(34, 2));
    if (vmax, vmin) != (u32::from(m.voltage_limits.0), u32::from(m.voltage_limits.1)) {
        let mut data = le(u32::from(m.voltage_limits.0), 2);
        data.extend(le(u32::from(m.voltage_limits.1), 2));
        report.push(
            Level::Warn,
            Some(s),
            format!(
                "voltage limits {:.1}–{:.1} V, the model's are {:.1}–{:.1} V",
                f64::from(vmin) / 10.0,
                f64::from(vmax) / 10.0,
                f64::from(m.voltage_limits.1) / 10.0,
                f64::from(m.voltage_limits.0) / 10.0
            ),
            "--fix writes the model's",
            fix(32, data),
        );
    }
    let volts = f64::from(read(addr::PRESENT_INPUT_VOLTAGE, 2)) / 10.0;
    if volts < m.min_v || volts > m.max_v {
        report.push(
            Level::Fault,
            Some(s),
            format!(
                "supply {volts:.1} V, outside the model's {:.1}–{:.1} V",
                m.min_v, m.max_v
            ),
            "check the power supply and its cable before torque on",
            None,
        );
    } else if (volts - s.supply_v).abs() > 0.1 * s.supply_v {
        report.push(
            Level::Warn,
            Some(s),
            format!(
                "supply {volts:.1} V, the profile plans {:.1} V: speed and torque differ",
                s.supply_v
            ),
            "set the supply, or `supply_v` in the profile",
            None,
        );
    }
    let celsius = read(addr::PRESENT_TEMPERATURE, 1);
    let limit = temperature_limit.min(u32::from(m.temperature_limit));
    if celsius >= limit {
        report.push(
            Level::Fault,
            Some(s),
            format!("at {celsius} °C, its limit is {limit} °C"),
            "let it cool with torque off",
            None,
        );
    } else if celsius + TEMPERATURE_MARGIN_C >= limit {
        report.push(
            Level::Warn,
            Some(s),
            format!("at {celsius} °C, within {TEMPERATURE_MARGIN_C} °C of its limit {limit} °C"),
            "let it cool before a long run",
            None,
        );
    }
    Ok(())
}

/// The USB adapter behind `port`: its latency timer, which holds every reply back that long.
pub fn check_adapter(port: &str, report: &mut Report) {
    let name = std::path::Path::new(port)
        .file_name()
        .map_or_else(String::new, |n| n.to_string_lossy().into_owned());
    match crate::bus::latency_timer_ms(port) {
        Some(ms) if ms > 1 => report.push(
            Level::Warn,
            None,
            format!("{port}: the adapter's latency timer is {ms} ms: every read waits up to that long"),
            &format!(
                "`echo 1 | sudo tee /sys/bus/usb-serial/devices/{name}/latency_timer` (a udev rule keeps it)"
            ),
            None,
        ),
        Some(ms) => report.push(
            Level::Ok,
            None,
            format!("{port}: latency timer {ms} ms"),
            "",
            None,
        ),
        None => {}
    }
}

/// The loop's cycle on `bus`, µs (median of [`TIMED_CYCLES`]): the goal Sync Write of every
/// servo's present position (torque off: nothing moves) and the profile's position read.
/// The loop's cycle on `bus` — a Sync Write of the goals (where the servos stand) and the
/// profile's read — timed [`TIMED_CYCLES`] times: the median of the cycles whose read came
/// back (`None` when none did), and how many did not. A busy host or a noisy line loses a read
/// now and then; that is counted, not taken for a broken bus.
///
/// # Errors
/// [`BusError::Io`] when the port itself fails, or the servos' positions cannot be read to
/// start with.
fn measure_cycle(bus: &mut dyn ServoBus, profile: &Profile) -> Result<(Option<f64>, usize), BusError> {
    let ids = profile.ids();
    if ids.is_empty() {
        return Ok((None, 0));
    }
    let mut present = vec![0i32; ids.len()];
    retried(|| bus.read_positions(&ids, &mut present))?;
    let mut times = Vec::with_capacity(TIMED_CYCLES);
    let mut failed = 0;
    for _ in 0..TIMED_CYCLES {
        let t0 = Instant::now();
        let cycle = bus
            .write_goals(&ids, &present)
            .and_then(|()| bus.read_positions(&ids, &mut present));
        match cycle {
            Ok(()) => times.push(t0.elapsed().as_secs_f64() * 1e6),
            Err(e @ BusError::Io(_)) => return Err(e),
            Err(_) => failed += 1,
        }
    }
    times.sort_by(f64::total_cmp);
    Ok((times.get(times.len() / 2).copied(), failed))
}

/// Makes every fixable finding's fix and returns what was done, a line each.
///
/// A write goes with torque off first on the servo (EEPROM items take writes only then), as a
/// Sync Write to the one servo, which no servo acknowledges: a servo at Status Return Level 0
/// or 1 takes it too. A reboot is waited out (up to 2 s) and its Hardware Error
/// Status read again: the line says whether the error came back (its cause is still there).
/// [`examine`] again tells whether the writes took.
///
/// # Errors
/// [`BusError`] of a write.
pub fn apply_fixes(bus: &mut dyn ServoBus, report: &Report) -> Result<Vec<String>, BusError> {
    let mut done = Vec::new();
    let mut torque_off: Vec<u8> = Vec::new();
    for f in &report.findings {
        let Some(fix) = f.fix.as_ref().filter(|f| f.at_baud.is_none()) else {
            continue;
        };
        let who = format!(
            "id {}{}",
            fix.id,
            f.servo.as_deref().map_or(String::new(), |n| format!(" {n}"))
        );
        match &fix.action {
            FixAction::Write { address, data } => {
                if !torque_off.contains(&fix.id) {
                    bus.sync_write(addr::TORQUE_ENABLE, 1, &[fix.id], &[0])?;
                    torque_off.push(fix.id);
                }
                let len = u16::try_from(data.len()).unwrap_or(u16::MAX);
                bus.sync_write(*address, len, &[fix.id], data)?;
                done.push(format!(
                    "{who}: wrote {} byte(s) at {address} ({})",
                    data.len(),
                    f.what
                ));
            }
            FixAction::Reboot => done.push(format!("{who}: {}", reboot(bus, fix.id, &f.what))),
        }
    }
    Ok(done)
}

/// Reboots servo `id` (whose finding was `what`) and says how it came back.
fn reboot(bus: &mut dyn ServoBus, id: u8, what: &str) -> String {
    // A servo below Status Return Level 2 reboots without a reply: its error status says.
    let _ = bus.reboot(id);
    let since = Instant::now();
    let after = loop {
        match retried(|| bus.hardware_error(id)) {
            Ok(bits) => break Some(bits),
            Err(_) if since.elapsed() < REBOOT_WAIT => {}
            Err(_) => break None,
        }
    };
    match after {
        Some(0) => format!("rebooted; the {what} is cleared"),
        Some(bits) => format!(
            "rebooted, but hardware error {} again: its cause is still there",
            crate::bus::hardware_error_names(bits)
        ),
        None => format!(
            "rebooted ({what}), and it has not answered in {} s",
            REBOOT_WAIT.as_secs()
        ),
    }
}

/// The bauds an X-series servo can be set to (Baud Rate, 8), in the order they are tried for
/// a servo that does not answer at the profile's: the factory 57,600 first, the slowest last
/// (a scan at 9,600 waits about 4 s for an empty bus).
pub const SEARCH_BAUDS: [u32; 8] = [
    57_600, 1_000_000, 2_000_000, 3_000_000, 4_000_000, 4_500_000, 115_200, 9_600,
];

/// Looks on `port` at every other baud for the profiled servos that did not answer at the
/// profile's, until all are found: each found turns its "does not answer" fault into one
/// naming its baud, with the fix (its Baud Rate register set to the profile's, written at its
/// own baud). Returns the bauds tried.
///
/// # Errors
/// The port cannot be opened at a baud, or the bus fails there.
pub fn search_bauds(port: &str, profile: &Profile, report: &mut Report) -> Result<Vec<u32>, BusError> {
    let mut missing: Vec<u8> = report
        .findings
        .iter()
        .filter(|f| f.unreachable == Some(Unreachable::Silent))
        .filter_map(|f| f.id)
        .collect();
    let mut tried = Vec::new();
    let Some(code) = crate::device::BAUD_CODES
        .iter()
        .position(|&b| b == profile.bus.baud)
    else {
        return Ok(tried);
    };
    for baud in SEARCH_BAUDS.into_iter().filter(|&b| b != profile.bus.baud) {
        if missing.is_empty() {
            break;
        }
        tried.push(baud);
        let mut config = bus_as_found(&profile.bus);
        config.baud = baud;
        let mut bus = crate::bus::open(
            crate::bus::Wire::Port(port.to_string()),
            &config,
            profile.servos.len(),
        )
        .map_err(BusError::Io)?;
        let mut found = bus.scan()?;
        found.retain(|p| missing.contains(&p.id));
        for p in &found {
            let Some(s) = profile.servos.iter().find(|s| s.id == p.id) else {
                continue;
            };
            missing.retain(|&m| m != p.id);
            report
                .findings
                .retain(|f| !(f.id == Some(p.id) && f.unreachable.is_some()));
            report.push(
                Level::Fault,
                Some(s),
                format!(
                    "answers at {baud} bit/s ({}), not the profile's {}",
                    model_name(p),
                    profile.bus.baud
                ),
                "--fix sets its Baud Rate (8) to the profile's, with torque off, at its own baud",
                Some(Fix {
                    id: p.id,
                    action: FixAction::Write {
                        address: addr::BAUD_RATE,
                        data: vec![code as u8],
                    },
                    at_baud: Some(baud),
                }),
            );
            report.mark_last(Unreachable::AtBaud(baud));
        }
    }
    Ok(tried)
}

/// Makes the fixes [`search_bauds`] found — each servo's Baud Rate set to the profile's, at
/// the baud it answers at, torque off first — and returns what was written, a line each.
/// The servo takes the new baud after its reply.
///
/// # Errors
/// The port cannot be opened at a baud, or a write fails.
pub fn apply_baud_fixes(port: &str, profile: &Profile, report: &Report) -> Result<Vec<String>, BusError> {
    let mut done = Vec::new();
    for f in &report.findings {
        let Some(fix) = &f.fix else {
            continue;
        };
        let (Some(baud), FixAction::Write { address, data }) = (fix.at_baud, &fix.action) else {
            continue;
        };
        let mut config = bus_as_found(&profile.bus);
        config.baud = baud;
        let mut bus =
            crate::bus::open(crate::bus::Wire::Port(port.to_string()), &config, 1).map_err(BusError::Io)?;
        bus.set_torque(fix.id, false)?;
        bus.write(fix.id, *address, data)?;
        done.push(format!(
            "id {}{}: Baud Rate set to {} bit/s (written at {baud})",
            fix.id,
            f.servo.as_deref().map_or(String::new(), |n| format!(" {n}")),
            profile.bus.baud
        ));
    }
    Ok(done)
}
