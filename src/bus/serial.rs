//! A serial port (or pseudo-terminal) as a [`Transport`] for the project's own Protocol 2.0
//! host ([`super::packet::PacketBus`]), the loop's bus for Sync and Fast Sync Read.

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

impl SerialTransport {
    fn readable_within(&self, timeout: Duration) -> io::Result<bool> {
        use std::os::fd::AsRawFd;
        readable_within(self.port.as_raw_fd(), timeout)
    }
}

/// Waits up to `timeout` (to the microsecond; zero: a look without waiting) for input on `fd`;
/// a hang-up or error on the descriptor counts as readable so that a read reports it.
#[allow(unsafe_code)]
pub(crate) fn readable_within(fd: std::os::fd::RawFd, timeout: Duration) -> io::Result<bool> {
    let mut fd = libc::pollfd {
        fd,
        events: libc::POLLIN,
        revents: 0,
    };
    let ts = libc::timespec {
        tv_sec: timeout.as_secs() as libc::time_t,
        tv_nsec: libc::c_long::from(timeout.subsec_nanos() as i32),
    };
    // SAFETY: one valid pollfd, a valid timespec, no signal mask.
    let r = unsafe { libc::ppoll(&mut fd, 1, &ts, std::ptr::null()) };
    match r {
        0 => Ok(false),
        r if r > 0 => Ok(true),
        _ => {
            let e = io::Error::last_os_error();
            if e.kind() == io::ErrorKind::Interrupted {
                Ok(false)
            } else {
                Err(e)
            }
        }
    }
}

impl Transport for SerialTransport {
    fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
        self.port.clear(ClearBuffer::Input).map_err(io::Error::from)?;
        self.port.write_all(bytes)?;
        self.port.flush()
    }

    fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize> {
        if !self.readable_within(timeout)? {
            return Ok(0);
        }
        // Input is waiting: the read returns at once (its own timeout error, which allocates,
        // is never reached inside a tick).
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
