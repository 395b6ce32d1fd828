//! Host files through ARM semihosting (QEMU `-semihosting-config enable=on`): the image's input
//! and output under emulation, where a board would use its UARTs.
#![allow(unsafe_code)]

use cortex_m_semihosting::nr;

/// Open for reading (binary).
pub const READ: usize = nr::open::R_BINARY;
/// Open for writing, truncated (binary).
pub const WRITE: usize = nr::open::W_TRUNC_BINARY;
/// Open for appending (binary).
pub const APPEND: usize = nr::open::W_APPEND_BINARY;

/// An open host file.
pub struct File {
    handle: usize,
}

impl File {
    /// Opens `path` (NUL-terminated) in `mode`.
    pub fn open(path: &str, mode: usize) -> Result<File, ()> {
        if !path.ends_with('\0') {
            return Err(());
        }
        // SAFETY: SYS_OPEN reads `path.len() - 1` bytes from the pointer, which is a live,
        // NUL-terminated string for the call's duration.
        let handle = unsafe { cortex_m_semihosting::syscall!(OPEN, path.as_ptr(), mode, path.len() - 1) };
        if handle == usize::MAX {
            Err(())
        } else {
            Ok(File { handle })
        }
    }

    /// Fills `buf` from the file (an error at its end).
    pub fn read_exact(&mut self, buf: &mut [u8]) -> Result<(), ()> {
        let mut at = 0;
        while at < buf.len() {
            let rest = &mut buf[at..];
            // SAFETY: SYS_READ writes at most `rest.len()` bytes to the pointer, a live
            // mutable slice; it returns how many were not read.
            let left =
                unsafe { cortex_m_semihosting::syscall!(READ, self.handle, rest.as_mut_ptr(), rest.len()) };
            if left >= rest.len() {
                return Err(());
            }
            at += rest.len() - left;
        }
        Ok(())
    }

    /// Moves to the end of the file (QEMU opens "append" files at their start).
    pub fn seek_end(&mut self) -> Result<(), ()> {
        // SAFETY: SYS_FLEN and SYS_SEEK take the handle SYS_OPEN gave and a position.
        let len = unsafe { cortex_m_semihosting::syscall!(FLEN, self.handle) };
        if len == usize::MAX {
            return Err(());
        }
        // SAFETY: as above.
        match unsafe { cortex_m_semihosting::syscall!(SEEK, self.handle, len) } {
            0 => Ok(()),
            _ => Err(()),
        }
    }

    /// Writes all of `bytes`.
    pub fn write_all(&mut self, bytes: &[u8]) -> Result<(), ()> {
        // SAFETY: SYS_WRITE reads `bytes.len()` bytes from the pointer, a live slice; it
        // returns how many were not written.
        let left = unsafe { cortex_m_semihosting::syscall!(WRITE, self.handle, bytes.as_ptr(), bytes.len()) };
        if left == 0 {
            Ok(())
        } else {
            Err(())
        }
    }
}

impl Drop for File {
    fn drop(&mut self) {
        // SAFETY: SYS_CLOSE takes the handle SYS_OPEN gave.
        let _ = unsafe { cortex_m_semihosting::syscall!(CLOSE, self.handle) };
    }
}
