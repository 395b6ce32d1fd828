//! `marionette convert`: BVH ⇄ ASF/AMC.

use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use super::args::{asf_beside, extension, BvhUnit};
use super::error::CliError;
use crate::formats::asf::AsfFile;
use crate::formats::{amc, asf, bvh, FileError};
use clap::Args;

pub(super) fn convert(
    input: &Path,
    output: &Path,
    asf_in: Option<&Path>,
    asf_out: Option<&Path>,
    unit: BvhUnit,
) -> Result<(), CliError> {
    let (file, motion) = match extension(input).as_str() {
        "bvh" => {
            let (a, m) = bvh::load(input, unit.inches())?;
            (a, Some(m))
        }
        "amc" => {
            let asf_path = match asf_in {
                Some(p) => p.to_path_buf(),
                None => asf_beside(input).ok_or_else(|| {
                    CliError::Usage(format!(
                        "{}: an AMC file needs its skeleton: pass --asf <FILE>",
                        input.display()
                    ))
                })?,
            };
            let a = asf::load(&asf_path)?;
            let m = amc::load(&a.skeleton, input)?;
            (a, Some(m))
        }
        "asf" => (asf::load(input)?, None),
        other => {
            return Err(CliError::Usage(format!(
                "{}: unknown input type '.{other}' (expected .bvh, .amc or .asf)",
                input.display()
            )))
        }
    };
    let need_motion = || {
        motion
            .as_ref()
            .ok_or_else(|| CliError::Usage(format!("{} holds no motion to write", input.display())))
    };
    match extension(output).as_str() {
        "bvh" => bvh::save(&file.skeleton, need_motion()?, output)?,
        "amc" => {
            let m = need_motion()?;
            let skel_path = asf_out.map_or_else(|| output.with_extension("asf"), Path::to_path_buf);
            if skel_path == input {
                return Err(CliError::Usage("refusing to overwrite the input skeleton".into()));
            }
            save_asf(&file, &skel_path)?;
            amc::save(&file.skeleton, m, output)?;
        }
        "asf" => save_asf(&file, output)?,
        other => {
            return Err(CliError::Usage(format!(
                "{}: unknown output type '.{other}' (expected .bvh, .amc or .asf)",
                output.display()
            )))
        }
    }
    Ok(())
}

fn save_asf(file: &AsfFile, path: &Path) -> Result<(), FileError> {
    let f = std::fs::File::create(path).map_err(|e| FileError::io(path, e))?;
    let mut w = BufWriter::new(f);
    asf::write(file, &mut w)
        .and_then(|()| w.flush())
        .map_err(|e| FileError::io(path, e))
}

/// The arguments of `marionette convert`.
#[derive(Debug, Args)]
pub(super) struct ConvertArgs {
    /// Input: .bvh, or .amc (with its skeleton, see --asf).
    pub(super) input: PathBuf,
    /// Output: .amc (the skeleton goes to --asf-out or beside it as .asf), .bvh or .asf.
    pub(super) output: PathBuf,
    /// Skeleton of an .amc input (default: IN's stem or subject number with .asf).
    #[arg(long)]
    pub(super) asf: Option<PathBuf>,
    /// Where to write the skeleton of an .amc output (default: OUT with .asf).
    #[arg(long)]
    pub(super) asf_out: Option<PathBuf>,
    /// Length unit of a BVH input (BVH files do not state it).
    #[arg(long, value_enum, default_value_t = BvhUnit::Cm)]
    pub(super) bvh_unit: BvhUnit,
}

impl ConvertArgs {
    /// Runs it.
    ///
    /// # Errors
    /// [`CliError`].
    pub(super) fn run(self) -> Result<(), CliError> {
        let ConvertArgs {
            input,
            output,
            asf,
            asf_out,
            bvh_unit,
        } = self;
        convert(&input, &output, asf.as_deref(), asf_out.as_deref(), bvh_unit)
    }
}
