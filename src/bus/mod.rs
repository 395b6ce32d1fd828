//! Servo buses: the [`ServoBus`] trait, its implementations and the start-up sequence.
//!
//! * [`dxl::Dynamixel2Bus`] — a serial port (or a pseudo-terminal) through the `dynamixel2`
//!   crate.
//! * [`packet::PacketBus`] — the project's own host side over any byte [`packet::Transport`];
//!   with [`virtual_chain::InProcess`] it drives a [`crate::device::Chain`] in virtual time.
//! * [`virtual_chain::PtyChain`] — a chain served on a pseudo-terminal for real clients.
//! * [`faults::FaultInjector`] — seeded corruption of the replies a chain sends.

pub mod dxl;
pub mod faults;
pub mod packet;
pub mod serial;
pub mod virtual_chain;

use std::fmt;

use crate::profile::BusSection;
use crate::servo::{self, addr, ServoModel};

/// The kind of a bus error, for counting.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum ErrorKind {
    /// No (complete) reply in time.
    Timeout,
    /// A reply with a wrong CRC.
    Crc,
    /// A reply from another id than asked.
    WrongId,
    /// The servo answered with an error number.
    Servo,
    /// A reply that decodes but is malformed (length, stuffing, instruction, parameter count).
    Malformed,
    /// The port failed.
    Io,
}

impl ErrorKind {
    /// All kinds, in a fixed order.
    pub const ALL: [ErrorKind; 6] = [
        ErrorKind::Timeout,
        ErrorKind::Crc,
        ErrorKind::WrongId,
        ErrorKind::Servo,
        ErrorKind::Malformed,
        ErrorKind::Io,
    ];

    /// Lower-case name.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            ErrorKind::Timeout => "timeout",
            ErrorKind::Crc => "crc",
            ErrorKind::WrongId => "wrong_id",
            ErrorKind::Servo => "servo",
            ErrorKind::Malformed => "malformed",
            ErrorKind::Io => "io",
        }
    }
}

/// A failed bus transaction.
#[derive(Debug, thiserror::Error)]
pub enum BusError {
    /// No reply in time.
    #[error("servo {id}: no reply in time")]
    Timeout {
        /// The id asked.
        id: u8,
    },
    /// A reply with a bad CRC.
    #[error("servo {id}: reply with a bad CRC")]
    Crc {
        /// The id asked.
        id: u8,
    },
    /// A reply from the wrong servo.
    #[error("asked servo {expected}, servo {got} answered")]
    WrongId {
        /// The id asked.
        expected: u8,
        /// The id in the reply.
        got: u8,
    },
    /// The servo reported an error.
    #[error("servo {id}: {}", servo_error_text(*.error))]
    Servo {
        /// The servo.
        id: u8,
        /// Its error number (bit 7, the alert flag, removed).
        error: u8,
    },
    /// A reply that does not fit the request.
    #[error("servo {id}: malformed reply ({what})")]
    Malformed {
        /// The id asked.
        id: u8,
        /// What is wrong.
        what: &'static str,
    },
    /// The port failed.
    #[error("bus I/O: {0}")]
    Io(#[from] std::io::Error),
}

/// A request the caller got wrong (too long for a packet, buffers of the wrong size).
pub(crate) fn invalid_request(what: &'static str) -> BusError {
    BusError::Io(std::io::Error::new(std::io::ErrorKind::InvalidInput, what))
}

fn servo_error_text(e: u8) -> &'static str {
    match e {
        servo::status_error::RESULT_FAIL => "result fail",
        servo::status_error::INSTRUCTION => "instruction error",
        servo::status_error::CRC => "CRC error (in the instruction it received)",
        servo::status_error::DATA_RANGE => "data range error",
        servo::status_error::DATA_LENGTH => "data length error",
        servo::status_error::DATA_LIMIT => "data limit error",
        servo::status_error::ACCESS => "access error",
        _ => "unknown error",
    }
}

impl BusError {
    /// What went wrong, when the port itself failed (the adapter unplugged, the device gone:
    /// EIO, ENXIO, a hang-up) rather than one transaction; `None` otherwise. Time-outs and
    /// requests the caller got wrong are not port failures. Allocates nothing (it is asked
    /// inside the tick).
    #[must_use]
    pub fn port_failure(&self) -> Option<std::io::Error> {
        use std::io::ErrorKind as K;
        match self {
            BusError::Io(e)
                if !matches!(
                    e.kind(),
                    K::TimedOut | K::Interrupted | K::WouldBlock | K::InvalidInput
                ) =>
            {
                Some(
                    e.raw_os_error()
                        .map_or_else(|| e.kind().into(), std::io::Error::from_raw_os_error),
                )
            }
            _ => None,
        }
    }

    /// Its kind.
    #[must_use]
    pub fn kind(&self) -> ErrorKind {
        match self {
            BusError::Timeout { .. } => ErrorKind::Timeout,
            BusError::Crc { .. } => ErrorKind::Crc,
            BusError::WrongId { .. } => ErrorKind::WrongId,
            BusError::Servo { .. } => ErrorKind::Servo,
            BusError::Malformed { .. } => ErrorKind::Malformed,
            BusError::Io(_) => ErrorKind::Io,
        }
    }
}

/// A servo's answer to a ping.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PingInfo {
    /// Its id.
    pub id: u8,
    /// Model number.
    pub model_number: u16,
    /// Firmware version.
    pub firmware: u8,
}

impl PingInfo {
    /// The known model, if any.
    #[must_use]
    pub fn model(&self) -> Option<&'static ServoModel> {
        servo::model_by_number(self.model_number)
    }
}

impl fmt::Display for PingInfo {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let model = match self.model() {
            Some(m) => m.name,
            None if self.model_number == crate::sensor_board::OPENCR_OP3_MODEL_NUMBER => {
                "OpenCR, OP3 firmware: IMU board"
            }
            None => "unknown model",
        };
        write!(
            f,
            "id {:>3}  model {:>5} ({model})  firmware {}",
            self.id, self.model_number, self.firmware
        )
    }
}

/// A Protocol 2.0 bus of servos. Reads never return data from a reply that failed any check.
pub trait ServoBus {
    /// Pings one id.
    ///
    /// # Errors
    /// [`BusError`].
    fn ping(&mut self, id: u8) -> Result<PingInfo, BusError>;

    /// Broadcast ping: every servo that answers, in id order.
    ///
    /// # Errors
    /// [`BusError`] when the bus fails (silence is not an error).
    fn scan(&mut self) -> Result<Vec<PingInfo>, BusError>;

    /// Reads `out.len()` bytes from `address` of one servo.
    ///
    /// # Errors
    /// [`BusError`].
    fn read(&mut self, id: u8, address: u16, out: &mut [u8]) -> Result<(), BusError>;

    /// Writes bytes at `address` of one servo.
    ///
    /// # Errors
    /// [`BusError`].
    fn write(&mut self, id: u8, address: u16, data: &[u8]) -> Result<(), BusError>;

    /// Sync Write: `data` holds `ids.len()` records of `len` bytes, in id order.
    ///
    /// # Errors
    /// [`BusError`].
    fn sync_write(&mut self, address: u16, len: u16, ids: &[u8], data: &[u8]) -> Result<(), BusError>;

    /// Sync Read of `len` bytes from each id into `out` (`ids.len()·len` bytes). Fails as a
    /// whole — `out` must then not be used — if any servo's reply fails; the first error is
    /// returned after all replies were collected.
    ///
    /// # Errors
    /// [`BusError`].
    fn sync_read(&mut self, address: u16, len: u16, ids: &[u8], out: &mut [u8]) -> Result<(), BusError>;

    /// Reboots one servo (RAM back to defaults, hardware errors cleared).
    ///
    /// # Errors
    /// [`BusError`].
    fn reboot(&mut self, id: u8) -> Result<(), BusError>;

    /// Reads a little-endian value of 1, 2 or 4 bytes.
    ///
    /// # Errors
    /// [`BusError`].
    fn read_value(&mut self, id: u8, address: u16, size: usize) -> Result<u32, BusError> {
        let mut b = [0u8; 4];
        self.read(id, address, &mut b[..size.min(4)])?;
        Ok(u32::from_le_bytes(b))
    }

    /// Turns torque on or off.
    ///
    /// # Errors
    /// [`BusError`].
    fn set_torque(&mut self, id: u8, on: bool) -> Result<(), BusError> {
        self.write(id, addr::TORQUE_ENABLE, &[u8::from(on)])
    }

    /// Hardware Error Status.
    ///
    /// # Errors
    /// [`BusError`].
    fn hardware_error(&mut self, id: u8) -> Result<u8, BusError> {
        Ok(self.read_value(id, addr::HARDWARE_ERROR_STATUS, 1)? as u8)
    }

    /// Sync Write of goal positions (ticks), one per id.
    ///
    /// # Errors
    /// [`BusError`].
    fn write_goals(&mut self, ids: &[u8], ticks: &[i32]) -> Result<(), BusError> {
        let mut data = [0u8; 4 * crate::servo::MAX_SERVOS];
        for (k, t) in ticks
            .iter()
            .enumerate()
            .take(ids.len().min(crate::servo::MAX_SERVOS))
        {
            data[4 * k..4 * k + 4].copy_from_slice(&t.to_le_bytes());
        }
        let n = ids.len().min(crate::servo::MAX_SERVOS);
        self.sync_write(addr::GOAL_POSITION, 4, &ids[..n], &data[..4 * n])
    }

    /// Sync Read of present positions (ticks), one per id.
    ///
    /// # Errors
    /// [`BusError`]; `out` is untouched then.
    fn read_positions(&mut self, ids: &[u8], out: &mut [i32]) -> Result<(), BusError> {
        let n = ids.len().min(crate::servo::MAX_SERVOS).min(out.len());
        let mut data = [0u8; 4 * crate::servo::MAX_SERVOS];
        self.sync_read(addr::PRESENT_POSITION, 4, &ids[..n], &mut data[..4 * n])?;
        for (k, o) in out.iter_mut().enumerate().take(n) {
            *o = i32::from_le_bytes([data[4 * k], data[4 * k + 1], data[4 * k + 2], data[4 * k + 3]]);
        }
        Ok(())
    }

    /// Sends a read of present positions and returns without waiting: the servos answer while
    /// the host computes, and [`ServoBus::collect_positions`] takes the replies (a pipelined
    /// read). Any other transaction first waits out the replies. Buses that cannot split a
    /// read do nothing here and read in full when collecting.
    ///
    /// # Errors
    /// [`BusError`].
    fn request_positions(&mut self, ids: &[u8]) -> Result<(), BusError> {
        let _ = ids;
        Ok(())
    }

    /// The present positions asked by the last [`ServoBus::request_positions`] for the same
    /// ids, each reply due by its wire time and the bus's margin counted from the request; a
    /// read now when none is pending.
    ///
    /// # Errors
    /// [`BusError`]; `out` is untouched then.
    fn collect_positions(&mut self, ids: &[u8], out: &mut [i32]) -> Result<(), BusError> {
        self.read_positions(ids, out)
    }

    /// Sends a Read of `len` bytes at `address` of `id` and returns without waiting, in the
    /// slot of a position read ([`ServoBus::request_positions`]): [`ServoBus::collect_read`]
    /// takes the reply next tick. Buses that cannot split a read do nothing here and read in
    /// full when collecting.
    ///
    /// # Errors
    /// [`BusError`].
    fn request_read(&mut self, id: u8, address: u16, len: u16) -> Result<(), BusError> {
        let _ = (id, address, len);
        Ok(())
    }

    /// The reply to the last [`ServoBus::request_read`] of the same item, due by its wire
    /// time and the bus's margin counted from the request; a read now when none is pending.
    ///
    /// # Errors
    /// [`BusError`]; `out` is untouched then.
    fn collect_read(&mut self, id: u8, address: u16, out: &mut [u8]) -> Result<(), BusError> {
        self.read(id, address, out)
    }

    /// Reads `len` bytes at `address` of device `id` (e.g. the IMU board) in the loop's
    /// position read from now on, as one more entry after the servos': of a Bulk Read (as
    /// ROBOTIS's OP3 framework reads its OpenCR), or of a Fast Bulk Read where the bus reads
    /// fast. `false` when this bus cannot: read it on its own then.
    fn merge_into_reads(&mut self, id: u8, address: u16, len: u16) -> bool {
        let _ = (id, address, len);
        false
    }

    /// A servo whose reply since the last call carried the hardware-alert flag (bit 7 of a
    /// status packet's error byte: its Hardware Error Status is not 0, so it has shut its
    /// torque off): the first such id, and the flag cleared. Every reply carries the flag, so
    /// the loop learns of an overload or overheating shutdown at the next position read.
    fn take_alert(&mut self) -> Option<u8> {
        None
    }

    /// The merged block of the position read collected last: `None` when no read was
    /// collected since the last call, `Some(false)` when the device's reply failed (`out`
    /// untouched; the positions may still have been good), `Some(true)` with `out` filled.
    fn take_merged(&mut self, out: &mut [u8]) -> Option<bool> {
        let _ = out;
        None
    }
}

/// A servo the profile names that is missing or of the wrong model.
#[derive(Debug, thiserror::Error)]
pub enum StartupError {
    /// The bus failed.
    #[error(transparent)]
    Bus(#[from] BusError),
    /// A profiled id did not answer.
    #[error("servo {id} (`{name}`) does not answer")]
    Missing {
        /// Id.
        id: u8,
        /// Profile name.
        name: String,
    },
    /// A profiled id answered with another model.
    #[error("servo {id} (`{name}`) is a model {found}, the profile says {want}")]
    WrongModel {
        /// Id.
        id: u8,
        /// Profile name.
        name: String,
        /// Model number found.
        found: u16,
        /// Model expected.
        want: &'static str,
    },
    /// A servo rests outside its software limits: torque-on would make it jump.
    #[error(
        "servo {id} (`{name}`) rests at tick {tick}, outside its limits {lo}…{hi}; move it inside by hand"
    )]
    OutsideLimits {
        /// Id.
        id: u8,
        /// Profile name.
        name: String,
        /// Present position.
        tick: i32,
        /// Lowest allowed tick.
        lo: i32,
        /// Highest allowed tick.
        hi: i32,
    },
    /// A servo reports a hardware error.
    #[error(
        "servo {id} (`{name}`) reports hardware error status {status:#04x}; remove the cause, then `marionette doctor PROFILE --fix` reboots it (or power-cycle the rig)"
    )]
    HardwareError {
        /// Id.
        id: u8,
        /// Profile name.
        name: String,
        /// Hardware Error Status.
        status: u8,
    },
}

/// Brings a profiled rig up safely and returns the present positions (ticks):
/// scan; check every profiled id answers with the right model and no hardware error; torque
/// off (EEPROM is writable only then); Return Delay Time, Status Return Level 2, the profile's
/// Homing Offset (when it gives one), the position limits, the profile's Position P Gain (when it gives one); read present positions and copy
/// them into the goals; only then torque on — so no servo jumps; last, the Bus Watchdog on all
/// servos at once (the caller's first command must follow within it). Each transaction that
/// meets a busy line or host is tried again, as [`retried`] does.
///
/// # Errors
/// [`StartupError`]; torque stays off on every servo.
pub fn start_up(bus: &mut dyn ServoBus, profile: BusSection<'_>) -> Result<Vec<i32>, StartupError> {
    let mut found = bus.scan()?;
    // A broadcast ping's replies come back to back; one that arrives after the scan's window
    // (a loaded host, a USB adapter's latency timer) is not a missing servo: a profiled id the
    // scan did not see is pinged on its own, as [`retried`] does, before it counts as missing.
    for s in profile.servos {
        if !found.iter().any(|p| p.id == s.id) {
            if let Ok(p) = retried(|| bus.ping(s.id)) {
                found.push(p);
            }
        }
    }
    for s in profile.servos {
        match found.iter().find(|p| p.id == s.id) {
            None => {
                return Err(StartupError::Missing {
                    id: s.id,
                    name: s.name.clone(),
                })
            }
            Some(p) if p.model_number != s.model.model_number => {
                return Err(StartupError::WrongModel {
                    id: s.id,
                    name: s.name.clone(),
                    found: p.model_number,
                    want: s.model.name,
                })
            }
            Some(_) => {}
        }
    }
    let rig_limits: Vec<(i32, i32)> = profile
        .servos
        .iter()
        .map(crate::profile::ServoSpec::tick_limits)
        .collect();
    for (s, (lo, hi)) in profile.servos.iter().zip(&rig_limits) {
        retried(|| bus.set_torque(s.id, false))?;
        let status = retried(|| bus.hardware_error(s.id))?;
        if status != 0 {
            return Err(StartupError::HardwareError {
                id: s.id,
                name: s.name.clone(),
                status,
            });
        }
        let delay = [(profile.config.return_delay_us / 2) as u8];
        retried(|| bus.write(s.id, addr::RETURN_DELAY_TIME, &delay))?;
        // Before the limits: they are in the offset's frame.
        if let Some(offset) = s.homing_offset {
            retried(|| bus.write(s.id, addr::HOMING_OFFSET, &offset.to_le_bytes()))?;
        }
        retried(|| bus.write(s.id, addr::STATUS_RETURN_LEVEL, &[2]))?;
        retried(|| bus.write(s.id, addr::MAX_POSITION_LIMIT, &hi.to_le_bytes()))?;
        retried(|| bus.write(s.id, addr::MIN_POSITION_LIMIT, &lo.to_le_bytes()))?;
        if let Some(gain) = s.position_p_gain {
            retried(|| bus.write(s.id, addr::POSITION_P_GAIN, &gain.to_le_bytes()))?;
        }
        // Clear an expired watchdog (writing 0), then arm it.
        retried(|| bus.write(s.id, addr::BUS_WATCHDOG, &[0]))?;
    }
    let ids = profile.ids();
    let mut present = vec![0i32; ids.len()];
    retried(|| bus.read_positions(&ids, &mut present))?;
    for (s, (p, (lo, hi))) in profile.servos.iter().zip(present.iter().zip(&rig_limits)) {
        if p < lo || p > hi {
            return Err(StartupError::OutsideLimits {
                id: s.id,
                name: s.name.clone(),
                tick: *p,
                lo: *lo,
                hi: *hi,
            });
        }
    }
    bus.write_goals(&ids, &present)?;
    for (s, p) in profile.servos.iter().zip(&present) {
        // Read back: the goal must equal the present position before torque goes on.
        let goal = retried(|| bus.read_value(s.id, addr::GOAL_POSITION, 4))? as i32;
        if goal != *p {
            return Err(StartupError::Bus(BusError::Malformed {
                id: s.id,
                what: "goal read back differs from present",
            }));
        }
    }
    if let Err(e) = torque_on_and_arm(bus, profile, &ids) {
        // Torque off again everywhere (best effort; the error that stopped start-up is the one
        // to report).
        let _ = shut_down(bus, profile);
        return Err(e);
    }
    Ok(present)
}

/// The Bus Watchdog register's value for `ms` (20 ms units, at most 127; 0: off).
#[must_use]
pub fn watchdog_units(ms: u32) -> u8 {
    (ms / 20).min(127) as u8
}

/// Torque on every servo, then the Bus Watchdog armed on all of them at once and read back.
fn torque_on_and_arm(
    bus: &mut dyn ServoBus,
    profile: BusSection<'_>,
    ids: &[u8],
) -> Result<(), StartupError> {
    for s in profile.servos {
        retried(|| bus.set_torque(s.id, true))?;
    }
    // The watchdog armed on every servo at once, last: armed one by one, the first servos'
    // would run out while the others are still being set up (28 acknowledged writes take
    // longer than 100 ms on a bus with a 1 ms adapter latency). Read back, as a Sync Write is
    // not acknowledged.
    let wd = watchdog_units(profile.config.watchdog_ms);
    if wd > 0 {
        let n = ids.len();
        bus.sync_write(addr::BUS_WATCHDOG, 1, ids, &vec![wd; n])?;
        let mut armed = vec![0u8; n];
        retried(|| bus.sync_read(addr::BUS_WATCHDOG, 1, ids, &mut armed))?;
        if let Some(k) = armed.iter().position(|a| *a != wd) {
            return Err(StartupError::Bus(BusError::Malformed {
                id: ids[k],
                what: "bus watchdog read back differs from the one written",
            }));
        }
    }
    Ok(())
}

/// The names of Hardware Error Status's bits (e-manual, X series).
#[must_use]
pub fn hardware_error_names(bits: u8) -> String {
    const NAMES: [(u8, &str); 5] = [
        (0x01, "input voltage"),
        (0x04, "overheating"),
        (0x08, "motor encoder"),
        (0x10, "electrical shock"),
        (0x20, "overload"),
    ];
    let names: Vec<&str> = NAMES
        .iter()
        .filter(|(b, _)| bits & b != 0)
        .map(|(_, n)| *n)
        .collect();
    if names.is_empty() {
        format!("{bits:#04x}")
    } else {
        format!("{bits:#04x} ({})", names.join(", "))
    }
}

/// How many times, at the least, an idempotent transaction is tried on a busy line
/// ([`retried`]).
pub const TRIES: usize = 3;

/// How long [`retried`] goes on trying a transaction that meets a busy line: a host paused by
/// its scheduler (ours, or the one serving a chain on a loaded machine) answers late for a
/// while, and three replies 34 ms late are only a tenth of a second.
pub const PATIENCE: std::time::Duration = std::time::Duration::from_millis(300);

/// The most tries [`retried`] makes, however fast the faults come back.
const MAX_TRIES: usize = 16;

/// Runs an idempotent transaction (a read, or a write of a fixed value), and again when it
/// meets a busy line or host — no reply in time, a bad CRC, the late reply of the one before
/// (another servo's, or the same servo's to another instruction: a write's empty status taken
/// for a read's) — [`TRIES`] times in all and on until [`PATIENCE`] has passed since the first
/// try. A servo's own error answer is not retried. Start-up, `doctor` and `calibrate` run their
/// transactions through it; a stop, which must reach every servo soon, uses [`retried_quickly`].
///
/// # Errors
/// The last attempt's [`BusError`].
pub fn retried<T>(transaction: impl FnMut() -> Result<T, BusError>) -> Result<T, BusError> {
    retried_within(PATIENCE, transaction)
}

/// [`retried`] without the patience: [`TRIES`] tries in all, so a silent servo costs about
/// a tenth of a second.
///
/// # Errors
/// The last attempt's [`BusError`].
pub fn retried_quickly<T>(transaction: impl FnMut() -> Result<T, BusError>) -> Result<T, BusError> {
    retried_within(std::time::Duration::ZERO, transaction)
}

fn retried_within<T>(
    patience: std::time::Duration,
    mut transaction: impl FnMut() -> Result<T, BusError>,
) -> Result<T, BusError> {
    let first = std::time::Instant::now();
    let mut outcome = transaction();
    let mut tries = 1;
    while tries < MAX_TRIES && (tries < TRIES || first.elapsed() < patience) {
        match outcome {
            Err(
                BusError::Timeout { .. }
                | BusError::Crc { .. }
                | BusError::WrongId { .. }
                | BusError::Malformed { .. },
            ) => {
                outcome = transaction();
                tries += 1;
            }
            _ => break,
        }
    }
    outcome
}

/// Bytes of control table [`Registers`] holds: addresses 0…147, Model Number to Present
/// Temperature (X series, and MX on Protocol 2.0).
pub const REGISTERS_LEN: usize = 148;

/// A snapshot of one servo's control table from address 0, read in one transaction. A
/// status packet does not say which address it answers, so a late reply to one 4-byte read
/// passes for the next one's; reading the items together leaves no next one. Reserved bytes
/// inside the table read as data (what X-series firmware answers).
#[derive(Clone, Debug)]
pub struct Registers {
    bytes: [u8; REGISTERS_LEN],
}

impl Registers {
    /// Reads servo `id`'s addresses 0…147 ([`retried`]).
    ///
    /// # Errors
    /// [`BusError`].
    pub fn read(bus: &mut dyn ServoBus, id: u8) -> Result<Registers, BusError> {
        let mut bytes = [0u8; REGISTERS_LEN];
        retried(|| bus.read(id, 0, &mut bytes))?;
        Ok(Registers { bytes })
    }

    /// The `size`-byte (at most 4) little-endian item at `address`; bytes past the snapshot
    /// read 0.
    #[must_use]
    pub fn value(&self, address: u16, size: usize) -> u32 {
        let a = usize::from(address).min(REGISTERS_LEN);
        let b = &self.bytes[a..(a + size.min(4)).min(REGISTERS_LEN)];
        b.iter().rev().fold(0, |v, &x| (v << 8) | u32::from(x))
    }

    /// The 4-byte signed item at `address`.
    #[must_use]
    pub fn signed(&self, address: u16) -> i32 {
        self.value(address, 4) as i32
    }
}

/// Torque off on every profiled servo (all are tried, each write again on a busy line; the
/// first error is returned).
///
/// # Errors
/// [`BusError`].
pub fn shut_down(bus: &mut dyn ServoBus, profile: BusSection<'_>) -> Result<(), BusError> {
    let mut first = None;
    for s in profile.servos {
        if let Err(e) = retried_quickly(|| bus.set_torque(s.id, false)) {
            first.get_or_insert(e);
        }
    }
    first.map_or(Ok(()), Err)
}

/// How much later than its wire time the loop waits for a read's replies on `bus`: the
/// adapter's latency timer, every servo's Return Delay Time and 1 ms for the host's scheduling
/// — so a silent servo costs at most about a tick.
#[must_use]
pub fn reply_margin(bus: &crate::profile::BusConfig, servos: usize) -> std::time::Duration {
    std::time::Duration::from_micros(
        u64::from(bus.usb_latency_us) + servos as u64 * u64::from(bus.return_delay_us) + 1000,
    )
}

/// What a bus runs over.
#[derive(Debug)]
pub enum Wire {
    /// A serial port (a USB adapter, or a pseudo-terminal serving a virtual chain), at the bus
    /// section's baud.
    Port(String),
    /// A virtual chain in process, keeping the line time of the bus section in real time.
    Chain(Box<crate::device::Chain>),
}

/// Opens the project's host ([`packet::PacketBus`]) for `servos` servos on `wire`, reading
/// positions as `config` says (Sync, Bulk, Fast Sync or Fast Bulk Read — `dynamixel2` 0.9.1 has
/// no fast reads and builds a wrong Bulk Read for more than one servo); its reads can be
/// pipelined and wait only their wire time and [`reply_margin`]. Start-up's single transactions
/// wait four times the margin.
///
/// # Errors
/// The port cannot be opened.
pub fn open(
    wire: Wire,
    config: &crate::profile::BusConfig,
    servos: usize,
) -> std::io::Result<Box<dyn ServoBus + Send>> {
    Ok(match wire {
        Wire::Port(path) => Box::new(host(
            serial::SerialTransport::open(&path, config.baud)?,
            config,
            servos,
        )),
        Wire::Chain(chain) => Box::new(line_timed_chain(*chain, config)),
    })
}

/// The project's host on `link` for `servos` servos on `bus`: reads as the bus section says,
/// each waiting its wire time and [`reply_margin`]; start-up's single transactions four times
/// the margin.
pub fn host<T: packet::Transport>(
    link: T,
    bus: &crate::profile::BusConfig,
    servos: usize,
) -> packet::PacketBus<T> {
    let margin = reply_margin(bus, servos);
    packet::PacketBus::new(link, margin)
        .with_read_mode(bus.read)
        .with_single_margin(4 * margin)
}

/// A virtual chain in process that keeps the line time of `bus` in real time (its baud, the USB
/// adapter's latency), with the project's host on it as on a port ([`host`]).
#[must_use]
pub fn line_timed_chain(
    chain: crate::device::Chain,
    bus: &crate::profile::BusConfig,
) -> packet::PacketBus<virtual_chain::InProcess> {
    let servos = chain.servos().len();
    let link = virtual_chain::InProcess::new(chain, bus.baud)
        .with_usb_latency(std::time::Duration::from_micros(u64::from(bus.usb_latency_us)))
        .real_time();
    host(link, bus, servos)
}

/// The latency timer (ms) of a Linux USB serial port, if the kernel exposes it (FTDI adapters
/// such as the U2D2: 16 ms by default, 1 ms for a control loop).
#[must_use]
pub fn latency_timer_ms(port: &str) -> Option<u32> {
    let name = std::path::Path::new(port).file_name()?.to_str()?;
    let text = std::fs::read_to_string(format!("/sys/bus/usb-serial/devices/{name}/latency_timer")).ok()?;
    text.trim().parse().ok()
}

#[cfg(test)]
mod tests {
    use super::{retried, retried_quickly, BusError, Registers, REGISTERS_LEN, TRIES};
    use crate::servo::addr;
    use std::time::{Duration, Instant};

    /// Items come out of the snapshot little-endian, signed where asked, 0 past its end.
    #[test]
    fn registers_give_each_item_from_its_address() {
        let mut bytes = [0u8; REGISTERS_LEN];
        bytes[usize::from(addr::HOMING_OFFSET)..][..4].copy_from_slice(&(-913i32).to_le_bytes());
        bytes[usize::from(addr::PRESENT_POSITION)..][..4].copy_from_slice(&2630i32.to_le_bytes());
        bytes[usize::from(addr::PRESENT_TEMPERATURE)] = 41;
        let r = Registers { bytes };
        assert_eq!(r.signed(addr::HOMING_OFFSET), -913);
        assert_eq!(r.signed(addr::PRESENT_POSITION), 2630);
        assert_eq!(r.value(addr::PRESENT_TEMPERATURE, 1), 41);
        assert_eq!(r.value(addr::PRESENT_TEMPERATURE, 4), 41);
        assert_eq!(r.value(addr::TORQUE_ENABLE, 1), 0);
        assert_eq!(r.value(600, 4), 0);
    }

    /// What a busy line does to a transaction is tried again; what a servo answers is not.
    #[test]
    fn start_up_tries_again_after_a_line_fault_but_not_after_a_servos_error() {
        let line_faults = [
            BusError::Timeout { id: 4 },
            BusError::Crc { id: 4 },
            BusError::WrongId { expected: 4, got: 3 },
            BusError::Malformed {
                id: 4,
                what: "parameter count",
            },
        ];
        for fault in line_faults {
            let mut calls = 0;
            let mut first = Some(fault);
            let got = retried(|| {
                calls += 1;
                first.take().map_or(Ok(7), Err)
            });
            assert_eq!(got.ok(), Some(7));
            assert_eq!(calls, 2);
        }
        let mut calls = 0;
        let got: Result<(), BusError> = retried_quickly(|| {
            calls += 1;
            Err(BusError::Timeout { id: 4 })
        });
        assert!(matches!(got, Err(BusError::Timeout { id: 4 })));
        assert_eq!(calls, TRIES);
        // Faults that come back at once are not tried without end.
        let mut calls = 0;
        let got: Result<(), BusError> = retried(|| {
            calls += 1;
            Err(BusError::Crc { id: 4 })
        });
        assert!(matches!(got, Err(BusError::Crc { id: 4 })));
        assert!((TRIES..=16).contains(&calls), "{calls}");
        let mut calls = 0;
        let got: Result<(), BusError> = retried(|| {
            calls += 1;
            Err(BusError::Servo { id: 4, error: 7 })
        });
        assert!(matches!(got, Err(BusError::Servo { id: 4, error: 7 })));
        assert_eq!(calls, 1);
    }

    /// A host that pauses for 150 ms (every reply in that time missing, each try waiting
    /// its 34 ms) does not fail a patient transaction.
    #[test]
    fn a_transaction_outlasts_a_paused_host() {
        let paused = Instant::now();
        let mut calls = 0;
        let got = retried(|| {
            calls += 1;
            if paused.elapsed() < Duration::from_millis(150) {
                std::thread::sleep(Duration::from_millis(34));
                Err(BusError::Timeout { id: 4 })
            } else {
                Ok(7)
            }
        });
        assert_eq!(got.ok(), Some(7), "{calls} tries");
        assert!(calls > 1);
    }
}
