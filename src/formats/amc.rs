//! AMC motion files: reading (any bone order, absent bones at rest, `:DEGREES`/`:RADIANS`)
//! and writing (round-trips exactly).

use super::{exact, numbered_lines, read_text, tokens, FileError, TextError};
use crate::motion::{Motion, CMU_FRAME_RATE};
use crate::skeleton::Skeleton;
use std::io::{self, Write};
use std::path::Path;

/// Largest magnitude accepted for a value; anything larger is taken as a corrupt file.
pub const MAX_VALUE: f64 = 1.0e9;

/// Parses AMC text for `skeleton`. Angles without `:DEGREES`/`:RADIANS` follow the skeleton's
/// ASF unit. The motion holds degrees whatever the file used, and at least one frame.
///
/// # Errors
/// The line and column of the first problem, saying what was expected (a file without frames
/// is one).
pub fn parse(skeleton: &Skeleton, text: &str) -> Result<Motion, TextError> {
    let mut degrees = skeleton.units().degrees;
    let mut motion = Motion::new(skeleton.channel_count(), CMU_FRAME_RATE);
    let mut in_frames = false;
    let mut expected_frame: Option<i64> = None;
    let mut seen: u64 = 0;
    for (n, line) in numbered_lines(text) {
        let mut toks = tokens(line);
        let Some((col, first)) = toks.next() else { continue };
        if first.starts_with('#') {
            continue;
        }
        if let Some(kw) = first.strip_prefix(':') {
            if in_frames {
                return Err(TextError::new(
                    n,
                    col,
                    format!("expected a frame number or a bone line, found ':{kw}' after the first frame"),
                ));
            }
            match kw.to_ascii_uppercase().as_str() {
                "FULLY-SPECIFIED" => {}
                "DEGREES" => degrees = true,
                "RADIANS" => degrees = false,
                _ => {
                    return Err(TextError::new(
                        n,
                        col,
                        format!("expected :FULLY-SPECIFIED, :DEGREES or :RADIANS, found '{first}'"),
                    ))
                }
            }
            if let Some((c, t)) = toks.next() {
                return Err(TextError::new(n, c, format!("expected end of line, found '{t}'")));
            }
            continue;
        }
        if first.bytes().all(|b| b.is_ascii_digit()) {
            let number: i64 = first
                .parse()
                .map_err(|_| TextError::new(n, col, format!("expected a frame number, found '{first}'")))?;
            if let Some(want) = expected_frame {
                if number != want {
                    return Err(TextError::new(
                        n,
                        col,
                        format!("expected frame {want}, found frame {number}"),
                    ));
                }
            } else {
                motion.first_frame = number;
            }
            if let Some((c, t)) = toks.next() {
                return Err(TextError::new(
                    n,
                    c,
                    format!("expected end of line after the frame number, found '{t}'"),
                ));
            }
            expected_frame = Some(number + 1);
            in_frames = true;
            seen = 0;
            motion.push_rest_frame();
            continue;
        }
        if !in_frames {
            return Err(TextError::new(
                n,
                col,
                format!("expected a frame number, found '{first}'"),
            ));
        }
        let Some(bone_index) = skeleton.find(first) else {
            return Err(TextError::new(
                n,
                col,
                format!("unknown bone '{first}' (not in the skeleton)"),
            ));
        };
        if seen & (1u64 << bone_index) != 0 {
            return Err(TextError::new(
                n,
                col,
                format!(
                    "bone '{first}' appears twice in frame {}",
                    expected_frame.unwrap_or(0) - 1
                ),
            ));
        }
        seen |= 1u64 << bone_index;
        let bone = &skeleton.bones()[bone_index];
        let frame_index = motion.len() - 1;
        let frame = motion.frame_mut(frame_index);
        let given = tokens(line).count() - 1;
        if given != bone.dofs().len() {
            return Err(TextError::new(
                n,
                col,
                format!("bone '{first}' has {} DOFs but {given} values", bone.dofs().len()),
            ));
        }
        for ((c, t), (k, dof)) in toks.zip(bone.dofs().iter().enumerate()) {
            let radians = dof.is_rotation() && !degrees;
            // Kept in degrees: the bound holds for what is stored (and written back).
            let v: f64 = match t.parse::<f64>() {
                Ok(v) if radians && v.to_degrees().abs() <= MAX_VALUE => v.to_degrees(),
                Ok(v) if !radians && v.is_finite() && v.abs() <= MAX_VALUE => v,
                Ok(_) => {
                    let range = if radians {
                        "-1.7e7 and 1.7e7 radians"
                    } else {
                        "-1e9 and 1e9"
                    };
                    return Err(TextError::new(
                        n,
                        c,
                        format!("expected a value between {range}, found '{t}'"),
                    ));
                }
                Err(_) => return Err(TextError::new(n, c, format!("expected a number, found '{t}'"))),
            };
            frame[bone.first_channel() + k] = v;
        }
    }
    if motion.is_empty() {
        return Err(TextError::new(
            super::last_line(text),
            0,
            "expected at least one frame (a frame number, then a line per bone), found none",
        ));
    }
    Ok(motion)
}

/// Loads an AMC file for `skeleton` (at least one frame, see [`parse`]).
///
/// # Errors
/// I/O errors, or `file:line:column` and what was expected.
pub fn load(skeleton: &Skeleton, path: &Path) -> Result<Motion, FileError> {
    let text = read_text(path)?;
    parse(skeleton, &text).map_err(|e| FileError::parse(path, e))
}

/// Writes `motion` as AMC (`:FULLY-SPECIFIED`, `:DEGREES`), every bone with channels in
/// skeleton order, values in their shortest exact form.
///
/// # Errors
/// I/O errors of `w`.
pub fn write(skeleton: &Skeleton, motion: &Motion, mut w: impl Write) -> io::Result<()> {
    writeln!(w, "# AMC motion written by marionette")?;
    writeln!(w, ":FULLY-SPECIFIED")?;
    writeln!(w, ":DEGREES")?;
    let mut line = String::new();
    for (i, frame) in motion.frames().enumerate() {
        writeln!(w, "{}", motion.first_frame + i as i64)?;
        for bone in skeleton.bones() {
            if bone.dofs().is_empty() {
                continue;
            }
            line.clear();
            line.push_str(bone.name());
            for c in bone.channels() {
                line.push(' ');
                line.push_str(&exact(frame[c]));
            }
            writeln!(w, "{line}")?;
        }
    }
    Ok(())
}

/// Writes `motion` to an AMC file.
///
/// # Errors
/// I/O errors, with the file name.
pub fn save(skeleton: &Skeleton, motion: &Motion, path: &Path) -> Result<(), FileError> {
    let f = std::fs::File::create(path).map_err(|e| FileError::io(path, e))?;
    let mut w = io::BufWriter::new(f);
    write(skeleton, motion, &mut w)
        .and_then(|()| w.flush())
        .map_err(|e| FileError::io(path, e))
}
