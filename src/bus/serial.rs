//! A serial port (or pseudo-terminal) as a [`Transport`] for the project's own Protocol 2.0
//! host ([`super::packet::PacketBus`]): what the loop uses where `dynamixel2` 0.9.1 cannot go
//! (Fast Sync Read).

use std::io::{self, Read, Write};
use std::time::{Duration, Instant};

use serialport::{ClearBuffer, SerialPort, TTYPort};

use super::packet::Transport;

/// An open serial port.
#[derive(Debug)]
pub struct SerialTransport {
    port: TTYPort,
    baud: u32,
    origin: Instant,
}

impl SerialTransport {
    /// Opens `path` at `baud`, 8N1.
    ///
    /// # Errors
    /// The port cannot be opened or configured.
    pub fn open(path: &str, baud: u32) -> io::Result<SerialTransport> {
        let port = serialport::new(path, baud)
            .timeout(Duration::from_millis(1))
            .open_native()
            .map_err(io::Error::from)?;
        Ok(SerialTransport {
            port,
            baud,
            origin: Instant::now(),
        })
    }
}

impl Transport for SerialTransport {
    fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
        self.port.clear(ClearBuffer::Input).map_err(io::Error::from)?;
        self.port.write_all(bytes)?;
        self.port.flush()
    }

    fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize> {
        if timeout.is_zero() {
            return Ok(0);
        }
        self.port.set_timeout(timeout).map_err(io::Error::from)?;
        match self.port.read(buf) {
            Ok(n) => Ok(n),
            Err(e) if matches!(e.kind(), io::ErrorKind::TimedOut | io::ErrorKind::Interrupted) => Ok(0),
            Err(e) => Err(e),
        }
    }

    fn now(&self) -> Duration {
        self.origin.elapsed()
    }

    fn baud(&self) -> u32 {
        self.baud
    }
}
