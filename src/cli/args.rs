//! Argument types and parsers shared by several commands.

use std::path::Path;

use clap::ValueEnum;

/// How `fk` writes its table.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum TableFormat {
    Csv,
    Json,
}

/// Length units a BVH file may be in.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum BvhUnit {
    /// Millimetres.
    Mm,
    /// Centimetres.
    Cm,
    /// Metres.
    M,
    /// Inches.
    In,
    /// CMU ASF units (1/0.45 inch), as in the CMU BVH conversions that keep ASF lengths.
    Cmu,
}

impl BvhUnit {
    /// Inches per file unit.
    #[must_use]
    pub fn inches(self) -> f64 {
        match self {
            BvhUnit::Mm => 1.0 / 25.4,
            BvhUnit::Cm => 1.0 / 2.54,
            BvhUnit::M => 1.0 / 0.0254,
            BvhUnit::In => 1.0,
            BvhUnit::Cmu => 1.0 / 0.45,
        }
    }
}

/// The lower-case extension of a path (empty without one).
pub fn extension(p: &Path) -> String {
    p.extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default()
}
