//! Argument types and parsers shared by several commands.

use std::path::{Path, PathBuf};

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

/// The ASF beside an AMC: `<stem>.asf`, then `<subject>.asf` for CMU names like `16_15.amc`.
pub fn asf_beside(amc_path: &Path) -> Option<PathBuf> {
    let stem = amc_path.file_stem()?.to_string_lossy().to_string();
    let dir = amc_path.parent().unwrap_or(Path::new(""));
    let mut candidates = vec![dir.join(format!("{stem}.asf"))];
    if let Some((subject, _)) = stem.split_once('_') {
        candidates.push(dir.join(format!("{subject}.asf")));
    }
    candidates.into_iter().find(|p| p.is_file())
}

/// A rate in Hz as a person writes it: at most three decimals, without trailing zeros (a BVH
/// frame time of 0.0083333 s is 120 Hz, not 120.00048000192001).
pub struct RoundedHz(pub f64);

impl std::fmt::Display for RoundedHz {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let s = format!("{:.3}", self.0);
        let s = if s.contains('.') {
            s.trim_end_matches('0').trim_end_matches('.')
        } else {
            &s
        };
        f.write_str(s)
    }
}

#[cfg(test)]
mod tests {
    use super::RoundedHz;

    #[test]
    fn rates_print_with_at_most_three_decimals() {
        assert_eq!(RoundedHz(1.0 / 0.008_333_3).to_string(), "120");
        assert_eq!(RoundedHz(120.0).to_string(), "120");
        assert_eq!(RoundedHz(29.97).to_string(), "29.97");
        assert_eq!(RoundedHz(1000.0 / 3.0).to_string(), "333.333");
        assert_eq!(RoundedHz(f64::NAN).to_string(), "NaN");
    }
}
