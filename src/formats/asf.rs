//! ASF files at the std edge: [`load`] reads a path through the core's text reader
//! ([`crate::asf`]) and reports `file:line:column`; [`write()`] writes a skeleton as ASF text.

use super::{read_text, tidy, FileError, TextError};
use crate::skeleton::{Dof, Skeleton};
use std::io::{self, Write};
use std::path::Path;

/// A loaded ASF skeleton with the file's descriptive fields.
#[derive(Clone, Debug)]
pub struct AsfFile {
    /// The skeleton.
    pub skeleton: Skeleton,
    /// `:name`.
    pub name: String,
    /// `:version`.
    pub version: String,
    /// `:documentation`, lines trimmed and joined with `\n`.
    pub documentation: String,
}

/// Parses ASF text into an [`AsfFile`].
///
/// # Errors
/// The line and column of the first problem.
pub fn parse(text: &str) -> Result<AsfFile, TextError> {
    let asf = crate::asf::parse_asf(text)?;
    Ok(AsfFile {
        skeleton: asf.skeleton,
        name: asf.name.to_string(),
        version: asf.version.to_string(),
        documentation: asf
            .documentation
            .lines()
            .map(str::trim)
            .collect::<Vec<_>>()
            .join("\n"),
    })
}

/// Loads an ASF file.
///
/// # Errors
/// I/O errors, or `file:line:column` and what was expected.
pub fn load(path: &Path) -> Result<AsfFile, FileError> {
    let text = read_text(path)?;
    parse(&text).map_err(|e| FileError::parse(path, e))
}

fn dof_upper(d: Dof) -> &'static str {
    match d {
        Dof::Rx => "RX",
        Dof::Ry => "RY",
        Dof::Rz => "RZ",
        Dof::Tx => "TX",
        Dof::Ty => "TY",
        Dof::Tz => "TZ",
        Dof::L => "L",
    }
}

/// Writes an ASF file that [`parse`] reads back to the same skeleton.
///
/// # Errors
/// I/O errors of `w`.
pub fn write(asf: &AsfFile, mut w: impl Write) -> io::Result<()> {
    let s = &asf.skeleton;
    let u = s.units();
    let angle = |rad: f32| {
        if u.degrees {
            tidy(f64::from(rad).to_degrees())
        } else {
            format!("{rad}")
        }
    };
    writeln!(w, "# ASF skeleton written by marionette")?;
    writeln!(
        w,
        ":version {}",
        if asf.version.is_empty() {
            "1.10"
        } else {
            &asf.version
        }
    )?;
    writeln!(
        w,
        ":name {}",
        if asf.name.is_empty() {
            "marionette"
        } else {
            &asf.name
        }
    )?;
    writeln!(w, ":units")?;
    writeln!(w, "  mass {}", u.mass)?;
    writeln!(w, "  length {}", u.length)?;
    writeln!(w, "  angle {}", if u.degrees { "deg" } else { "rad" })?;
    if !asf.documentation.is_empty() {
        writeln!(w, ":documentation")?;
        for l in asf.documentation.lines() {
            // Control characters become spaces, and no line may start like a section keyword.
            let clean: String = l.chars().map(|c| if c.is_control() { ' ' } else { c }).collect();
            let mut text = clean.trim();
            while let Some(rest) = text.strip_prefix(':') {
                text = rest.trim_start();
            }
            writeln!(w, "  {text}")?;
        }
    }
    let root = s.root();
    writeln!(w, ":root")?;
    let order: Vec<&str> = root.order.iter().map(|d| dof_upper(*d)).collect();
    writeln!(w, "  order {}", order.join(" "))?;
    writeln!(w, "  axis {}", root.axis_order.name())?;
    writeln!(
        w,
        "  position {} {} {}",
        root.position.x, root.position.y, root.position.z
    )?;
    let o = root.orientation;
    writeln!(w, "  orientation {} {} {}", angle(o[0]), angle(o[1]), angle(o[2]))?;
    writeln!(w, ":bonedata")?;
    for (i, bone) in s.bones().iter().enumerate().skip(1) {
        let spec = bone.spec();
        writeln!(w, "  begin")?;
        writeln!(w, "    id {}", if spec.id == 0 { i as u32 } else { spec.id })?;
        writeln!(w, "    name {}", spec.name)?;
        let d = spec.direction;
        writeln!(w, "    direction {} {} {}", d.x, d.y, d.z)?;
        writeln!(w, "    length {}", spec.length)?;
        let a = spec.axis;
        writeln!(
            w,
            "    axis {} {} {} {}",
            angle(a[0]),
            angle(a[1]),
            angle(a[2]),
            spec.axis_order.name()
        )?;
        if !spec.dofs.is_empty() {
            let names: Vec<&str> = spec.dofs.iter().map(|d| d.name()).collect();
            writeln!(w, "    dof {}", names.join(" "))?;
            for (k, (l, dof)) in spec.limits.iter().zip(&spec.dofs).enumerate() {
                let bound = |v: f32| {
                    if v.is_infinite() {
                        if v > 0.0 {
                            "inf".to_string()
                        } else {
                            "-inf".to_string()
                        }
                    } else if dof.is_rotation() {
                        angle(v)
                    } else {
                        format!("{v}")
                    }
                };
                let head = if k == 0 { "    limits " } else { "           " };
                writeln!(w, "{head}({} {})", bound(l.min), bound(l.max))?;
            }
        }
        writeln!(w, "  end")?;
    }
    writeln!(w, ":hierarchy")?;
    writeln!(w, "  begin")?;
    for i in 0..s.len() {
        let children: Vec<&str> = s.children(i).map(|c| s.bones()[c].name()).collect();
        if !children.is_empty() {
            writeln!(w, "    {} {}", s.bones()[i].name(), children.join(" "))?;
        }
    }
    writeln!(w, "  end")?;
    Ok(())
}
