//! Pictures: the file type from the extension (`.svg` or `.png`), the font for their text,
//! and one error type. The motion, loop and simulator pictures implement [`Picture`].

use std::path::{Path, PathBuf};

use plotters::coord::Shift;
use plotters::prelude::*;

/// Font files tried for text (plotters draws text itself), after `$MARIONETTE_FONT`.
const FONTS: &[&str] = &[
    "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/TTF/DejaVuSans.ttf",
    "/usr/share/fonts/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/truetype/liberation/LiberationSans-Regular.ttf",
    "/usr/share/fonts/liberation/LiberationSans-Regular.ttf",
    "/System/Library/Fonts/Supplemental/Arial.ttf",
    "C:\\Windows\\Fonts\\arial.ttf",
];

/// Why a picture was not drawn.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum PlotError {
    /// The file name ends in neither `.svg` nor `.png`.
    #[error("{}: the picture must be .svg or .png", path.display())]
    FileType {
        /// The file asked for.
        path: PathBuf,
    },
    /// No font for the text.
    #[error("no TrueType font found for the picture's text (set MARIONETTE_FONT to a .ttf file)")]
    NoFont,
    /// Drawing or writing failed.
    #[error("{}: {message}", path.display())]
    Draw {
        /// The file being drawn.
        path: PathBuf,
        /// What went wrong.
        message: String,
    },
}

/// The picture formats.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// Scalable vector graphics.
    Svg,
    /// A bitmap.
    Png,
}

impl Format {
    /// The format of a file name, by its extension (any case).
    ///
    /// # Errors
    /// [`PlotError::FileType`] for other extensions: check before a long run.
    pub fn of(path: &Path) -> Result<Format, PlotError> {
        let ext = path.extension().map(|e| e.to_string_lossy().to_ascii_lowercase());
        match ext.as_deref() {
            Some("svg") => Ok(Format::Svg),
            Some("png") => Ok(Format::Png),
            _ => Err(PlotError::FileType {
                path: path.to_path_buf(),
            }),
        }
    }
}

/// A drawing area of any plotters backend.
pub type Area<DB> = DrawingArea<DB, Shift>;

/// What drawing a [`Picture`] gives: plotters' errors, boxed.
pub type Rendered = Result<(), Box<dyn std::error::Error>>;

/// Something that can be drawn on any plotters backend.
pub trait Picture {
    /// Draws on `area` (already sized).
    ///
    /// # Errors
    /// What plotters reported.
    fn render<DB: DrawingBackend<ErrorType: 'static>>(&self, area: &Area<DB>) -> Rendered;
}

/// Draws `picture` to `path`, `size` pixels (width, height), SVG or PNG by the extension.
///
/// # Errors
/// [`PlotError`]: the file type, the font, or drawing.
pub fn draw(picture: &impl Picture, size: (u32, u32), path: &Path) -> Result<(), PlotError> {
    let format = Format::of(path)?;
    register_font()?;
    let result = match format {
        Format::Svg => {
            let area = SVGBackend::new(path, size).into_drawing_area();
            picture.render(&area).and_then(|()| Ok(area.present()?))
        }
        Format::Png => {
            let area = BitMapBackend::new(path, size).into_drawing_area();
            picture.render(&area).and_then(|()| Ok(area.present()?))
        }
    };
    result.map_err(|e| PlotError::Draw {
        path: path.to_path_buf(),
        message: e.to_string(),
    })
}

/// Registers the first font found as plotters' `sans-serif` (once per process).
fn register_font() -> Result<(), PlotError> {
    static FONT: std::sync::OnceLock<Option<&'static [u8]>> = std::sync::OnceLock::new();
    let font = FONT.get_or_init(|| {
        let env = std::env::var("MARIONETTE_FONT").ok();
        let paths = env.iter().map(String::as_str).chain(FONTS.iter().copied());
        for p in paths {
            if let Ok(bytes) = std::fs::read(p) {
                let leaked: &'static [u8] = Box::leak(bytes.into_boxed_slice());
                if plotters::style::register_font("sans-serif", FontStyle::Normal, leaked).is_ok() {
                    return Some(leaked);
                }
            }
        }
        None
    });
    font.map(|_| ()).ok_or(PlotError::NoFont)
}
