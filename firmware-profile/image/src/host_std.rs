//! The image's input and output files through std: the same tick built for the host (the
//! reference that the QEMU test compares the chip's goals with), with the semihosting
//! module's interface.

use std::io::{Read, Seek, SeekFrom, Write};

/// Open for reading.
pub const READ: usize = 0;
/// Open for writing, truncated.
pub const WRITE: usize = 1;

/// An open host file.
pub struct File {
    file: std::fs::File,
}

impl File {
    /// Opens `path` (NUL-terminated, as semihosting takes it) in `mode`.
    pub fn open(path: &str, mode: usize) -> Result<File, ()> {
        let path = path.strip_suffix('\0').ok_or(())?;
        let file = match mode {
            READ => std::fs::File::open(path),
            _ => std::fs::File::create(path),
        };
        file.map(|file| File { file }).map_err(|_| ())
    }

    /// Fills `buf` from the file.
    pub fn read_exact(&mut self, buf: &mut [u8]) -> Result<(), ()> {
        self.file.read_exact(buf).map_err(|_| ())
    }

    /// Moves to the end of the file.
    #[allow(dead_code)]
    pub fn seek_end(&mut self) -> Result<(), ()> {
        self.file.seek(SeekFrom::End(0)).map(drop).map_err(|_| ())
    }

    /// Writes all of `bytes`.
    pub fn write_all(&mut self, bytes: &[u8]) -> Result<(), ()> {
        self.file.write_all(bytes).map_err(|_| ())
    }
}
