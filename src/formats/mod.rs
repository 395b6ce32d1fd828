//! Files: loading with `file:line:column` errors, AMC read/write, ASF load/write, BVH
//! import/export.

pub mod amc;
pub mod asf;
pub mod bvh;
pub mod mjcf;

use std::fmt;
use std::path::{Path, PathBuf};

/// A position in a text file and what is wrong there.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TextError {
    /// 1-based line (0: the whole file).
    pub line: u32,
    /// 1-based column (0: unknown).
    pub column: u32,
    /// What is wrong, saying what was expected.
    pub message: String,
}

impl TextError {
    /// An error at `line:column`.
    pub fn new(line: u32, column: u32, message: impl Into<String>) -> TextError {
        TextError {
            line,
            column,
            message: message.into(),
        }
    }
}

/// The line an error found at the end of `text` points at: its last line (1 for an empty file).
#[must_use]
pub fn last_line(text: &str) -> u32 {
    u32::try_from(text.lines().count().max(1)).unwrap_or(u32::MAX)
}

impl From<crate::asf::AsfError<'_>> for TextError {
    fn from(e: crate::asf::AsfError<'_>) -> Self {
        TextError::new(e.line, e.column, e.kind.to_string())
    }
}

/// An error reading or writing a file: which file, where, and what.
#[derive(Debug, thiserror::Error)]
pub enum FileError {
    /// The file could not be opened, read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The operating system's error.
        source: std::io::Error,
    },
    /// The file's content is wrong.
    #[error("{}", display_at(.path, .error))]
    Parse {
        /// The file.
        path: PathBuf,
        /// Where and what.
        error: TextError,
    },
}

fn display_at(path: &Path, e: &TextError) -> String {
    let name = path.display();
    match (e.line, e.column) {
        (0, _) => format!("{name}: {}", e.message),
        (l, 0) => format!("{name}:{l}: {}", e.message),
        (l, c) => format!("{name}:{l}:{c}: {}", e.message),
    }
}

impl FileError {
    /// Attaches a file name to a [`TextError`].
    pub fn parse(path: impl Into<PathBuf>, error: TextError) -> FileError {
        FileError::Parse {
            path: path.into(),
            error,
        }
    }

    /// An I/O error on `path`.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> FileError {
        FileError::Io {
            path: path.into(),
            source,
        }
    }

    /// The position, for parse errors.
    #[must_use]
    pub fn text_error(&self) -> Option<&TextError> {
        match self {
            FileError::Parse { error, .. } => Some(error),
            FileError::Io { .. } => None,
        }
    }
}

/// Reads a whole file as UTF-8 text.
///
/// # Errors
/// I/O errors, or the line and column of the first byte that is not UTF-8.
pub fn read_text(path: &Path) -> Result<String, FileError> {
    let bytes = std::fs::read(path).map_err(|e| FileError::io(path, e))?;
    text_from_bytes(bytes).map_err(|e| FileError::parse(path, e))
}

/// UTF-8 text from bytes, or where the first invalid byte is.
///
/// # Errors
/// The line and column of the first byte that is not UTF-8.
pub fn text_from_bytes(bytes: Vec<u8>) -> Result<String, TextError> {
    String::from_utf8(bytes).map_err(|e| {
        let good = e.utf8_error().valid_up_to();
        let bytes = e.as_bytes();
        let line = bytes[..good].iter().filter(|&&b| b == b'\n').count() as u32 + 1;
        let line_start = bytes[..good]
            .iter()
            .rposition(|&b| b == b'\n')
            .map_or(0, |p| p + 1);
        TextError::new(
            line,
            (good - line_start) as u32 + 1,
            "expected UTF-8 text, found a byte that is not",
        )
    })
}

/// Splits text into lines numbered from 1, without `\r`.
pub(crate) fn numbered_lines(text: &str) -> impl Iterator<Item = (u32, &str)> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    text.split('\n')
        .enumerate()
        .map(|(i, l)| (i as u32 + 1, l.strip_suffix('\r').unwrap_or(l)))
}

/// White-space separated tokens of a line with their 1-based columns.
pub(crate) fn tokens(line: &str) -> impl Iterator<Item = (u32, &str)> {
    let base = line.as_ptr() as usize;
    line.split_ascii_whitespace()
        .map(move |t| ((t.as_ptr() as usize - base) as u32 + 1, t))
}

/// Formats an f64 so that reading it back gives the same value (shortest form).
pub(crate) fn exact(v: f64) -> String {
    let s = format!("{v}");
    if s == "-0" {
        "0".into()
    } else {
        s
    }
}

/// Formats an angle converted back to file degrees: rounded to 1e-6 so that values read
/// from a file come back as written (f32 storage would otherwise add noise digits).
pub(crate) fn tidy(v: f64) -> String {
    let r = (v * 1e6).round() / 1e6;
    exact(if r == 0.0 { 0.0 } else { r })
}

impl fmt::Display for TextError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}:{}: {}", self.line, self.column, self.message)
    }
}
