//! [`ServoBus`] on a serial port through `dynamixel2` 0.9.1.
//!
//! `dynamixel2` checks header, CRC, instruction, id and error byte. Its byte-stuffing state
//! machine misses the pattern `FF FF FF FD` (FACTS.md): a spec-exact reply containing it comes
//! out one byte too long, which the parameter-count check turns into an error — reported here
//! as [`BusError::Malformed`], never used. After any failed reply the line is drained until
//! quiet, so a late reply cannot answer the next instruction.

use std::io;
use std::time::Duration;

use dynamixel2::{InvalidMessage, ReadError, TransferError, WriteError};

use super::{invalid_request, BusError, PingInfo, ServoBus};
use crate::servo::MAX_SERVOS;

/// Read/write buffer size: a Sync Write to 64 servos with 4 bytes each is 14 + 5·64 bytes.
const BUFFER: usize = 4096;

/// A Dynamixel bus on a serial port.
pub struct Dynamixel2Bus {
    bus: dynamixel2::Bus<Vec<u8>, Vec<u8>>,
    quiet: Duration,
    /// The first id whose reply had the hardware-alert flag since the last
    /// [`ServoBus::take_alert`].
    alert: Option<u8>,
}

impl std::fmt::Debug for Dynamixel2Bus {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Dynamixel2Bus").field("bus", &self.bus).finish()
    }
}

impl Dynamixel2Bus {
    /// Opens `path` at `baud`.
    ///
    /// # Errors
    /// The port cannot be opened or configured.
    pub fn open(path: &str, baud: u32) -> io::Result<Dynamixel2Bus> {
        let bus = dynamixel2::Bus::open_with_buffers(path, baud, vec![0; BUFFER], vec![0; BUFFER])?;
        Ok(Dynamixel2Bus {
            bus,
            quiet: Duration::from_millis(10),
            alert: None,
        })
    }

    /// How long the line must stay quiet after a failed reply before the next instruction
    /// (default 10 ms): a reply later than the timeout plus this window is taken for fresh.
    #[must_use]
    pub fn with_drain(mut self, quiet: Duration) -> Dynamixel2Bus {
        self.quiet = quiet;
        self
    }

    /// Keeps `id` for [`ServoBus::take_alert`] when its reply had the alert flag and none
    /// is kept yet.
    fn note_alert(&mut self, id: u8, alert: bool) {
        if alert && self.alert.is_none() {
            self.alert = Some(id);
        }
    }

    /// The underlying `dynamixel2` bus.
    pub fn inner(&mut self) -> &mut dynamixel2::Bus<Vec<u8>, Vec<u8>> {
        &mut self.bus
    }

    /// Reads until the line is quiet and drops it all; the port's own failure (the adapter
    /// unplugged) ends the wait and is returned.
    fn drain(&mut self) -> Option<io::Error> {
        // Every reply (or noise) that still arrives restarts the wait; silence ends it.
        for _ in 0..64 {
            match self
                .bus
                .read_status_response_deadline(std::time::Instant::now() + self.quiet)
            {
                Err(ReadError::Io(e)) if e.kind() == io::ErrorKind::TimedOut => break,
                Err(ReadError::Io(e)) => {
                    let failed = BusError::Io(e);
                    if let Some(e) = failed.port_failure() {
                        return Some(e);
                    }
                }
                _ => {}
            }
        }
        let discarded = self.bus.serial_port().discard_input_buffer();
        discarded.err().and_then(|e| BusError::Io(e).port_failure())
    }

    /// Reports a failed reply after draining the line (a failing port is not drained); a port
    /// found failing while draining is reported instead of the reply's fault.
    fn fail<T>(&mut self, e: BusError) -> Result<T, BusError> {
        if !matches!(e, BusError::Io(_)) {
            if let Some(io) = self.drain() {
                return Err(BusError::Io(io));
            }
        }
        Err(e)
    }
}

/// Maps a `dynamixel2` read error for a reply expected from `id`.
#[must_use]
pub fn map_read_error(id: u8, e: ReadError) -> BusError {
    match e {
        ReadError::Io(io) if io.kind() == io::ErrorKind::TimedOut => BusError::Timeout { id },
        ReadError::Io(io) => BusError::Io(io),
        ReadError::BufferFull(_) => BusError::Malformed {
            id,
            what: "reply longer than the buffer",
        },
        ReadError::InvalidMessage(m) => match m {
            InvalidMessage::InvalidChecksum(_) => BusError::Crc { id },
            InvalidMessage::InvalidPacketId(p) => BusError::WrongId {
                expected: id,
                got: p.actual,
            },
            InvalidMessage::InvalidHeaderPrefix(_) => BusError::Malformed { id, what: "header" },
            InvalidMessage::InvalidInstruction(_) => BusError::Malformed {
                id,
                what: "instruction",
            },
            InvalidMessage::InvalidParameterCount(_) => BusError::Malformed {
                id,
                what: "parameter count",
            },
        },
        ReadError::MotorError(m) => BusError::Servo {
            id,
            error: m.error_number(),
        },
    }
}

fn map_write_error(e: WriteError) -> BusError {
    match e {
        WriteError::Write(io) | WriteError::DiscardBuffer(io) => BusError::Io(io),
        WriteError::BufferTooSmall(_) => invalid_request("instruction too long"),
    }
}

fn map_transfer_error(id: u8, e: TransferError) -> BusError {
    match e {
        TransferError::WriteError(w) => map_write_error(w),
        TransferError::ReadError(r) => map_read_error(id, r),
    }
}

impl ServoBus for Dynamixel2Bus {
    fn take_alert(&mut self) -> Option<u8> {
        self.alert.take()
    }

    fn ping(&mut self, id: u8) -> Result<PingInfo, BusError> {
        match self.bus.ping(id) {
            Ok(r) => Ok(PingInfo {
                id: r.motor_id,
                model_number: r.data.model,
                firmware: r.data.firmware,
            }),
            Err(e) => self.fail(map_transfer_error(id, e)),
        }
    }

    fn scan(&mut self) -> Result<Vec<PingInfo>, BusError> {
        let found = self.bus.scan().map_err(map_write_error)?;
        let mut out: Vec<PingInfo> = found
            .into_iter()
            .filter_map(Result::ok)
            .map(|r| PingInfo {
                id: r.motor_id,
                model_number: r.data.model,
                firmware: r.data.firmware,
            })
            .collect();
        out.sort_by_key(|p| p.id);
        out.dedup_by_key(|p| p.id);
        Ok(out)
    }

    fn read(&mut self, id: u8, address: u16, out: &mut [u8]) -> Result<(), BusError> {
        let r = self.bus.read(id, address, out.len() as u16);
        if let Ok(r) = &r {
            self.note_alert(r.motor_id, r.alert);
        }
        match r {
            Ok(r) if r.data.len() == out.len() => {
                out.copy_from_slice(&r.data);
                Ok(())
            }
            Ok(_) => self.fail(BusError::Malformed {
                id,
                what: "parameter count",
            }),
            Err(e) => self.fail(map_transfer_error(id, e)),
        }
    }

    fn write(&mut self, id: u8, address: u16, data: &[u8]) -> Result<(), BusError> {
        match self.bus.write(id, address, data) {
            Ok(_) => Ok(()),
            Err(e) => self.fail(map_transfer_error(id, e)),
        }
    }

    fn sync_write(&mut self, address: u16, len: u16, ids: &[u8], data: &[u8]) -> Result<(), BusError> {
        let len_us = usize::from(len);
        if data.len() < ids.len() * len_us {
            return Err(invalid_request("sync write data shorter than ids × len"));
        }
        let records = ids
            .iter()
            .enumerate()
            .map(|(k, &id)| dynamixel2::instructions::SyncWriteData {
                motor_id: id,
                data: &data[k * len_us..(k + 1) * len_us],
            });
        self.bus
            .sync_write(address, len, records)
            .map_err(map_write_error)
    }

    fn sync_read(&mut self, address: u16, len: u16, ids: &[u8], out: &mut [u8]) -> Result<(), BusError> {
        let l = usize::from(len);
        let mut scratch = [0u8; 16 * MAX_SERVOS];
        if ids.len() * l > scratch.len() || out.len() < ids.len() * l {
            return Err(invalid_request(
                "sync read too large, or output shorter than ids × len",
            ));
        }
        let mut first: Option<BusError> = None;
        let mut k = 0usize;
        let mut alert = None;
        let r = self.bus.sync_read_cb(ids, address, len, |reply| {
            let id = ids.get(k).copied().unwrap_or(0);
            if let Ok(resp) = &reply {
                if resp.alert && alert.is_none() {
                    alert = Some(resp.motor_id);
                }
            }
            match reply {
                Ok(resp) if resp.data.len() == l && first.is_none() => {
                    scratch[k * l..(k + 1) * l].copy_from_slice(resp.data)
                }
                Ok(_) => {}
                Err(e) => {
                    if first.is_none() {
                        first = Some(map_read_error(id, e));
                    }
                }
            }
            k += 1;
        });
        if let Some(id) = alert {
            self.note_alert(id, true);
        }
        if let Err(e) = r {
            return self.fail(map_write_error(e));
        }
        if let Some(e) = first {
            return self.fail(e);
        }
        out[..ids.len() * l].copy_from_slice(&scratch[..ids.len() * l]);
        Ok(())
    }

    fn reboot(&mut self, id: u8) -> Result<(), BusError> {
        match self.bus.reboot(id) {
            Ok(_) => Ok(()),
            Err(e) => self.fail(map_transfer_error(id, e)),
        }
    }
}
