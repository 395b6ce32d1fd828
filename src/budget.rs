//! The bus budget: what one control cycle (a Sync Write of goal positions and a read of present
//! values) costs on the wire, and the highest loop rate it allows.
//!
//! Packet sizes (Protocol 2.0, 10-byte frame + parameters, `d` data bytes per servo):
//! Sync Write `14 + (1 + 4)·N`; Sync Read request `14 + N` and `N` replies of `11 + d`; Bulk
//! Read request `10 + 5·N` and `N` replies of `11 + d`; Fast Sync Read request `14 + N` and one
//! reply of `8 + (4 + d)·N`; Fast Bulk Read request `10 + 5·N` and the same one reply. Every
//! byte is 10 bits on the line (start, 8 data, stop). Each replying servo waits its Return
//! Delay Time (one wait for the fast reads), and the host sees
//! the reply only when the USB adapter's latency timer flushes it (once per read).
//!
//! A sensor board read every cycle ([`plan_with_board`], the OP3's OpenCR and its IMU) joins a
//! Sync or Bulk Read as one more Bulk Read entry (request `10 + 5·(N + 1)`, its reply `11 + b`,
//! one more return delay), and a Fast read as one more Fast Bulk Read entry (request
//! `10 + 5·(N + 1)`, its block `4 + b` in the one reply).
//!
//! The loop's health watch ([`crate::control::health`]) reads, every few cycles, one servo's
//! voltage and temperature (a Read: request 14, reply `11 + 3`) or its Hardware Error Status
//! (reply `11 + 1`), with its return delay and a USB latency. A pipelined loop sends it in the
//! position read's slot (that cycle: the Sync Write and the Read); otherwise it comes on top of
//! the cycle. The worst cycle must fit the asked period too.

use serde::Serialize;

use crate::profile::{BusConfig, ReadMode};

/// Bits per byte on the serial line.
pub const BITS_PER_BYTE: u32 = 10;

/// The cost of one cycle.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Budget {
    /// Servos on the bus.
    pub servos: usize,
    /// Bit/s.
    pub baud: u32,
    /// Read pattern.
    pub read_mode: ReadMode,
    /// Data bytes read per servo.
    pub read_bytes_per_servo: u32,
    /// Data bytes read from a sensor board every cycle, if one is read.
    pub board_bytes: Option<u32>,
    /// Whether the board's read is merged into the servos' (a Bulk Read) rather than a Read
    /// of its own.
    pub board_merged: Option<bool>,
    /// Bytes of the goal-position Sync Write.
    pub write_bytes: u32,
    /// Bytes of the read request.
    pub read_request_bytes: u32,
    /// Bytes of all replies.
    pub read_reply_bytes: u32,
    /// Total bytes per cycle.
    pub bytes_per_cycle: u32,
    /// Wire time of those bytes, µs.
    pub wire_time_us: f64,
    /// Return delays, µs.
    pub return_delay_us: f64,
    /// USB latency, µs.
    pub usb_latency_us: f64,
    /// Wire + return delay + USB latency, µs.
    pub cycle_time_us: f64,
    /// 1 / cycle time.
    pub max_rate_hz: f64,
    /// The asked rate, if any.
    pub requested_rate_hz: Option<f64>,
    /// Fraction of the asked period the bus needs (> 1: infeasible).
    pub utilisation: Option<f64>,
    /// Whether the asked rate fits.
    pub feasible: Option<bool>,
    /// The health watch's read, on the cycles that carry it, µs (bytes, return delay, USB
    /// latency).
    pub health_read_us: f64,
    /// A cycle with the health read, µs.
    pub worst_cycle_us: f64,
    /// Whether the asked rate fits the worst cycle too.
    pub worst_feasible: Option<bool>,
}

/// Computes the budget of `servos` servos on `bus`, optionally against a loop rate.
#[must_use]
pub fn plan(bus: &BusConfig, servos: usize, rate_hz: Option<f64>) -> Budget {
    plan_with_board(bus, servos, rate_hz, None)
}

/// [`plan`] with `board_bytes` bytes of a sensor board read every cycle as the loop reads it
/// (module docs).
#[must_use]
pub fn plan_with_board(
    bus: &BusConfig,
    servos: usize,
    rate_hz: Option<f64>,
    board_bytes: Option<u32>,
) -> Budget {
    let n = servos as u32;
    let d = u32::from(bus.read_fields.block().1);
    let write_bytes = 14 + 5 * n;
    let merged = true;
    let (read_request_bytes, read_reply_bytes, delays) = match (bus.read, board_bytes) {
        (ReadMode::Sync | ReadMode::Bulk, Some(b)) => (10 + 5 * (n + 1), n * (11 + d) + 11 + b, n + 1),
        (ReadMode::FastSync | ReadMode::FastBulk, Some(b)) => (10 + 5 * (n + 1), 8 + (4 + d) * n + 4 + b, 1),
        (ReadMode::Sync, None) => (14 + n, n * (11 + d), n),
        (ReadMode::Bulk, None) => (10 + 5 * n, n * (11 + d), n),
        (ReadMode::FastSync, None) => (14 + n, 8 + (4 + d) * n, 1),
        (ReadMode::FastBulk, None) => (10 + 5 * n, 8 + (4 + d) * n, 1),
    };
    let latencies = 1;
    let bytes_per_cycle = write_bytes + read_request_bytes + read_reply_bytes;
    let wire_time_us = f64::from(bytes_per_cycle) * f64::from(BITS_PER_BYTE) * 1e6 / f64::from(bus.baud);
    let return_delay_us = f64::from(delays) * f64::from(bus.return_delay_us);
    let usb_latency_us = f64::from(latencies) * f64::from(bus.usb_latency_us);
    let cycle_time_us = wire_time_us + return_delay_us + usb_latency_us;
    let max_rate_hz = 1e6 / cycle_time_us;
    let utilisation = rate_hz.map(|r| cycle_time_us * r / 1e6);
    let health_read_us = f64::from(HEALTH_READ_BYTES) * f64::from(BITS_PER_BYTE) * 1e6 / f64::from(bus.baud)
        + f64::from(bus.return_delay_us)
        + f64::from(bus.usb_latency_us);
    // Pipelined, the health Read takes a position read's slot; otherwise it comes on top.
    let write_us = f64::from(write_bytes) * f64::from(BITS_PER_BYTE) * 1e6 / f64::from(bus.baud);
    let worst_cycle_us = if bus.pipeline {
        cycle_time_us.max(write_us + health_read_us)
    } else {
        cycle_time_us + health_read_us
    };
    Budget {
        servos,
        baud: bus.baud,
        read_mode: bus.read,
        read_bytes_per_servo: d,
        board_bytes,
        board_merged: board_bytes.map(|_| merged),
        write_bytes,
        read_request_bytes,
        read_reply_bytes,
        bytes_per_cycle,
        wire_time_us,
        return_delay_us,
        usb_latency_us,
        cycle_time_us,
        max_rate_hz,
        requested_rate_hz: rate_hz,
        utilisation,
        feasible: utilisation.map(|u| u <= 1.0),
        health_read_us,
        worst_cycle_us,
        worst_feasible: rate_hz.map(|r| worst_cycle_us * r / 1e6 <= 1.0),
    }
}

/// Bytes of the health watch's larger read: the request (14) and a reply of 11 + 3.
pub const HEALTH_READ_BYTES: u32 = 14 + 11 + 3;

impl std::fmt::Display for Budget {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mode = match self.read_mode {
            ReadMode::Sync => "Sync Read",
            ReadMode::Bulk => "Bulk Read",
            ReadMode::FastSync => "Fast Sync Read",
            ReadMode::FastBulk => "Fast Bulk Read",
        };
        writeln!(
            f,
            "{} servos at {} bit/s, {mode} of {} bytes each",
            self.servos, self.baud, self.read_bytes_per_servo
        )?;
        if let (Some(b), Some(merged)) = (self.board_bytes, self.board_merged) {
            let how = match (merged, self.read_mode) {
                (false, _) => "a Read of its own",
                (true, ReadMode::FastSync | ReadMode::FastBulk) => "one more entry of a Fast Bulk Read",
                (true, _) => "one more entry of a Bulk Read",
            };
            writeln!(f, "  and {b} bytes of the sensor board, {how}")?;
        }
        writeln!(f, "  sync write      {:>6} B", self.write_bytes)?;
        writeln!(f, "  read request    {:>6} B", self.read_request_bytes)?;
        writeln!(f, "  read replies    {:>6} B", self.read_reply_bytes)?;
        writeln!(
            f,
            "  per cycle       {:>6} B  {:>9.1} µs on the wire",
            self.bytes_per_cycle, self.wire_time_us
        )?;
        writeln!(f, "  return delays            {:>9.1} µs", self.return_delay_us)?;
        writeln!(f, "  USB latency              {:>9.1} µs", self.usb_latency_us)?;
        writeln!(
            f,
            "  cycle                    {:>9.1} µs  → at most {:.1} Hz",
            self.cycle_time_us, self.max_rate_hz
        )?;
        writeln!(
            f,
            "  health read              {:>9.1} µs  one cycle in a few, in the read's slot when pipelined (worst cycle {:.1} µs)",
            self.health_read_us, self.worst_cycle_us
        )?;
        if let (Some(r), Some(u)) = (self.requested_rate_hz, self.utilisation) {
            if u <= 1.0 {
                writeln!(
                    f,
                    "  {r} Hz fits: the bus is busy {:.0} % of each period{}",
                    u * 100.0,
                    if self.worst_feasible == Some(false) {
                        " — but not the cycles with the health read: those run late (or give --no-health)"
                    } else {
                        ""
                    }
                )?;
            } else {
                writeln!(
                    f,
                    "  {r} Hz does NOT fit: a cycle needs {:.0} % of the period",
                    u * 100.0
                )?;
            }
        }
        if self.usb_latency_us > 1000.0 {
            writeln!(
                f,
                "  warning: USB latency above 1 ms; set the adapter's latency_timer to 1"
            )?;
        }
        Ok(())
    }
}
