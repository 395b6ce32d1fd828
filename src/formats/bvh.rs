//! BVH import into the skeleton + motion model, and export from it, both pose-exact.
//!
//! **Import.** Each BVH joint becomes a bone that starts at the joint and points at its child
//! (or End Site); a joint whose children sit at different offsets becomes a zero-length bone
//! with one channel-less connector bone per child (`<joint>_to_<child>`), which moves rigidly
//! with it. Rotation channels keep their values; their order is reversed, because BVH lists the
//! outermost rotation first and ASF the innermost. Root position channels are absolute (the
//! root OFFSET is then ignored, as in MotionBuilder's CMU conversions, whose root OFFSET equals
//! the first frame's position). Position channels on other joints have no exact ASF form and
//! are refused.
//!
//! **Export.** Each bone becomes a joint at the bone's start; its children sit at the bone's
//! rest vector; its rotation is `C·M·Cᵀ` (the root: `O·M`) written as `Zrotation Yrotation
//! Xrotation`. Bones with translation or length channels are refused.

use super::asf::AsfFile;
use super::{exact, read_text, FileError, TextError};
use crate::math::{Axis, EulerOrder};
use crate::motion::Motion;
use crate::skeleton::{
    dof_rotation, BoneName, BoneSpec, Dof, Limit, RootSpec, Skeleton, SkeletonError, Units, MAX_BONES,
};
use glam::{DMat3, DVec3, Vec3};
use std::io::{self, Write};
use std::path::Path;

#[derive(Clone, Copy, Debug, PartialEq)]
enum Channel {
    Position(Axis),
    Rotation(Axis),
}

#[derive(Debug)]
struct Joint<'a> {
    name: &'a str,
    line: u32,
    column: u32,
    parent: Option<usize>,
    offset: [f64; 3],
    channels: Vec<Channel>,
    end_site: Option<[f64; 3]>,
    /// Index of the joint's first value in a frame line.
    first_value: usize,
}

#[derive(Clone, Copy)]
struct Tok<'a> {
    text: &'a str,
    line: u32,
    column: u32,
}

struct Cursor<'a> {
    toks: Vec<Tok<'a>>,
    pos: usize,
    last_line: u32,
}

impl<'a> Cursor<'a> {
    fn next(&mut self, what: &str) -> Result<Tok<'a>, TextError> {
        let t = self.toks.get(self.pos).copied().ok_or_else(|| {
            TextError::new(self.last_line, 0, format!("expected {what}, found end of file"))
        })?;
        self.pos += 1;
        Ok(t)
    }
    fn expect(&mut self, word: &str) -> Result<Tok<'a>, TextError> {
        let t = self.next(&format!("'{word}'"))?;
        if t.text.eq_ignore_ascii_case(word) {
            Ok(t)
        } else {
            Err(TextError::new(
                t.line,
                t.column,
                format!("expected '{word}', found '{}'", t.text),
            ))
        }
    }
    fn number(&mut self) -> Result<f64, TextError> {
        let t = self.next("a number")?;
        match t.text.parse::<f64>() {
            Ok(v) if v.is_finite() && v.abs() <= super::amc::MAX_VALUE => Ok(v),
            _ => Err(TextError::new(
                t.line,
                t.column,
                format!("expected a number, found '{}'", t.text),
            )),
        }
    }
    fn vec3(&mut self) -> Result<[f64; 3], TextError> {
        Ok([self.number()?, self.number()?, self.number()?])
    }
}

fn channel(t: Tok<'_>) -> Result<Channel, TextError> {
    let lower = t.text.to_ascii_lowercase();
    let axis = match lower.as_bytes().first() {
        Some(b'x') => Axis::X,
        Some(b'y') => Axis::Y,
        Some(b'z') => Axis::Z,
        _ => None.ok_or_else(|| bad_channel(t))?,
    };
    match &lower[1..] {
        "position" => Ok(Channel::Position(axis)),
        "rotation" => Ok(Channel::Rotation(axis)),
        _ => Err(bad_channel(t)),
    }
}

fn bad_channel(t: Tok<'_>) -> TextError {
    TextError::new(
        t.line,
        t.column,
        format!("expected a channel (Xposition … Zrotation), found '{}'", t.text),
    )
}

enum Ctx {
    Joint(usize),
    EndSite(usize),
}

/// Parses the HIERARCHY section into joints; the cursor is left at `MOTION`.
fn parse_hierarchy<'a>(cur: &mut Cursor<'a>) -> Result<Vec<Joint<'a>>, TextError> {
    cur.expect("HIERARCHY")?;
    cur.expect("ROOT")?;
    let name = cur.next("the root joint's name")?;
    cur.expect("{")?;
    let mut joints = vec![Joint {
        name: name.text,
        line: name.line,
        column: name.column,
        parent: None,
        offset: [0.0; 3],
        channels: Vec::new(),
        end_site: None,
        first_value: 0,
    }];
    let mut stack = vec![Ctx::Joint(0)];
    let mut values = 0usize;
    while let Some(top) = stack.last() {
        let t = cur.next("OFFSET, CHANNELS, JOINT, End Site or '}'")?;
        let word = t.text.to_ascii_uppercase();
        match (word.as_str(), top) {
            ("OFFSET", Ctx::Joint(j)) => {
                let j = *j;
                joints[j].offset = cur.vec3()?;
            }
            ("OFFSET", Ctx::EndSite(j)) => {
                let j = *j;
                joints[j].end_site = Some(cur.vec3()?);
            }
            ("CHANNELS", Ctx::Joint(j)) => {
                let j = *j;
                let n = cur.next("a channel count")?;
                let count: usize = n.text.parse().ok().filter(|&c| c <= 6).ok_or_else(|| {
                    TextError::new(
                        n.line,
                        n.column,
                        format!("expected a channel count from 0 to 6, found '{}'", n.text),
                    )
                })?;
                if !joints[j].channels.is_empty() {
                    return Err(TextError::new(
                        t.line,
                        t.column,
                        "expected one CHANNELS line per joint, found a second",
                    ));
                }
                joints[j].first_value = values;
                for _ in 0..count {
                    let c = channel(cur.next("a channel name")?)?;
                    if joints[j].channels.contains(&c) {
                        return Err(TextError::new(
                            n.line,
                            n.column,
                            "expected each channel once, found a repeat",
                        ));
                    }
                    joints[j].channels.push(c);
                }
                values += count;
            }
            ("JOINT", Ctx::Joint(j)) => {
                let parent = *j;
                let name = cur.next("a joint name")?;
                cur.expect("{")?;
                if joints.len() >= MAX_BONES {
                    return Err(TextError::new(
                        name.line,
                        name.column,
                        format!("too many joints (at most {MAX_BONES})"),
                    ));
                }
                joints.push(Joint {
                    name: name.text,
                    line: name.line,
                    column: name.column,
                    parent: Some(parent),
                    offset: [0.0; 3],
                    channels: Vec::new(),
                    end_site: None,
                    first_value: values,
                });
                stack.push(Ctx::Joint(joints.len() - 1));
            }
            ("END", Ctx::Joint(j)) => {
                let j = *j;
                cur.expect("Site")?;
                cur.expect("{")?;
                if joints[j].end_site.is_some() {
                    return Err(TextError::new(
                        t.line,
                        t.column,
                        "expected one End Site per joint, found a second",
                    ));
                }
                joints[j].end_site = Some([0.0; 3]);
                stack.push(Ctx::EndSite(j));
            }
            ("}", _) => {
                stack.pop();
            }
            _ => {
                return Err(TextError::new(
                    t.line,
                    t.column,
                    format!(
                        "expected OFFSET, CHANNELS, JOINT, End Site or '}}', found '{}'",
                        t.text
                    ),
                ))
            }
        }
    }
    Ok(joints)
}

/// How one bone's channels take their values from a BVH frame line.
struct ValueMap {
    /// For each ASF channel of the bone, the index of its value in the frame line.
    from: Vec<usize>,
}

/// Parses BVH text. `inches_per_unit` says what one BVH length unit is (BVH files do not say):
/// `1.0 / 2.54` for centimetres.
///
/// # Errors
/// The line and column of the first problem, saying what was expected.
pub fn parse(text: &str, inches_per_unit: f64) -> Result<(AsfFile, Motion), TextError> {
    let mut toks = Vec::new();
    for (n, line) in super::numbered_lines(text) {
        for (c, t) in super::tokens(line) {
            toks.push(Tok {
                text: t,
                line: n,
                column: c,
            });
        }
    }
    let last_line = toks.last().map_or(1, |t| t.line);
    let mut cur = Cursor {
        toks,
        pos: 0,
        last_line,
    };
    let joints = parse_hierarchy(&mut cur)?;
    let total_values: usize = joints.iter().map(|j| j.channels.len()).sum();

    // Bones and connectors.
    let root = &joints[0];
    let mut root_spec = RootSpec::default();
    root_spec.order.clear();
    let has_root_position = root.channels.iter().any(|c| matches!(c, Channel::Position(_)));
    if !has_root_position {
        root_spec.position = Vec3::from(root.offset.map(|v| v as f32));
    }
    let mut specs: Vec<BoneSpec> = Vec::new();
    // The joint each bone was made for (its line and column locate errors).
    let mut spec_joint: Vec<usize> = Vec::new();
    let mut parents: Vec<Option<usize>> = Vec::new();
    let mut spec_of_joint: Vec<Option<usize>> = vec![None; joints.len()];
    let mut attach_of_joint: Vec<Option<usize>> = vec![None; joints.len()]; // where children hang
    let mut maps: Vec<(String, ValueMap)> = Vec::new();

    let name_of = |s: &str, t: (u32, u32)| {
        BoneName::try_from(s).map_err(|_| {
            TextError::new(
                t.0,
                t.1,
                format!(
                    "joint name '{s}' is longer than {} bytes",
                    crate::skeleton::MAX_NAME_LEN
                ),
            )
        })
    };
    let children_of = |j: usize| -> Vec<usize> {
        (0..joints.len())
            .filter(|&k| joints[k].parent == Some(j))
            .collect()
    };

    // Root channels: rotation sub-sequence reversed in place.
    {
        let rot_slots: Vec<usize> = (0..root.channels.len())
            .filter(|&k| matches!(root.channels[k], Channel::Rotation(_)))
            .collect();
        let mut from = Vec::new();
        for (k, c) in root.channels.iter().enumerate() {
            let src = match c {
                Channel::Position(_) => k,
                Channel::Rotation(_) => {
                    let r = rot_slots.iter().position(|&s| s == k).unwrap_or(0);
                    rot_slots[rot_slots.len() - 1 - r]
                }
            };
            let d = match root.channels[src] {
                Channel::Position(a) => [Dof::Tx, Dof::Ty, Dof::Tz][a.index()],
                Channel::Rotation(a) => [Dof::Rx, Dof::Ry, Dof::Rz][a.index()],
            };
            let _ = root_spec.order.push(d);
            from.push(root.first_value + src);
        }
        maps.push(("root".to_string(), ValueMap { from }));
    }

    for j in 0..joints.len() {
        let joint = &joints[j];
        let at = (joint.line, joint.column);
        if j > 0 {
            if joint.channels.iter().any(|c| matches!(c, Channel::Position(_))) {
                return Err(TextError::new(
                    joint.line,
                    joint.column,
                    format!(
                        "joint '{}' has position channels: only the root may (no exact ASF mapping)",
                        joint.name
                    ),
                ));
            }
            if joint.name.eq_ignore_ascii_case("root") {
                return Err(TextError::new(
                    joint.line,
                    joint.column,
                    "expected a joint name other than 'root' below the root",
                ));
            }
        }
        let kids = children_of(j);
        let offsets: Vec<[f64; 3]> = kids.iter().map(|&k| joints[k].offset).collect();
        let shared = if kids.is_empty() {
            Some(joint.end_site.unwrap_or([0.0; 3]))
        } else if offsets.iter().all(|o| *o == offsets[0]) && (j > 0 || offsets[0] == [0.0; 3]) {
            Some(offsets[0])
        } else {
            None
        };
        if j > 0 {
            let v = DVec3::from(shared.unwrap_or([0.0; 3]));
            let len = v.length();
            let dir = if len > 0.0 {
                (v / len).as_vec3()
            } else {
                Vec3::ZERO
            };
            let mut spec = BoneSpec::new(name_of(joint.name, at)?, dir, len as f32);
            let rots: Vec<Axis> = joint
                .channels
                .iter()
                .rev()
                .filter_map(|c| match c {
                    Channel::Rotation(a) => Some(*a),
                    Channel::Position(_) => None,
                })
                .collect();
            let mut from = Vec::new();
            for (k, a) in rots.iter().enumerate() {
                let _ = spec.dofs.push([Dof::Rx, Dof::Ry, Dof::Rz][a.index()]);
                let _ = spec.limits.push(Limit::UNLIMITED);
                from.push(joint.first_value + joint.channels.len() - 1 - k);
            }
            maps.push((joint.name.to_string(), ValueMap { from }));
            let parent_attach = attach_of_joint[j];
            specs.push(spec);
            spec_joint.push(j);
            parents.push(parent_attach);
            spec_of_joint[j] = Some(specs.len() - 1);
        }
        let own = spec_of_joint[j]; // None for the root
        if shared.is_some() {
            // Children hang at this bone's tip.
            for &k in &kids {
                attach_of_joint[k] = own;
            }
        } else {
            for &k in &kids {
                let o = DVec3::from(joints[k].offset);
                if o == DVec3::ZERO {
                    attach_of_joint[k] = own;
                    continue;
                }
                let parent_name = if j == 0 { "root" } else { joint.name };
                let name = format!("{}_to_{}", parent_name, joints[k].name);
                let len = o.length();
                let spec = BoneSpec::new(name_of(&name, at)?, (o / len).as_vec3(), len as f32);
                specs.push(spec);
                spec_joint.push(k);
                parents.push(own);
                attach_of_joint[k] = Some(specs.len() - 1);
            }
        }
    }
    // `attach_of_joint[k]` is set while k's parent is visited, before k itself: the parser
    // lists joints in pre-order, parents first.
    let units = Units {
        mass: 1.0,
        length: (1.0 / inches_per_unit) as f32,
        degrees: true,
    };
    let skeleton = Skeleton::new(root_spec, units, &specs, &parents).map_err(|e| {
        let i = e.bone().unwrap_or(usize::MAX);
        let name = specs.get(i).map_or("", |s| s.name.as_str());
        // The joint the bone was made for (a connector: the child it leads to); else the root.
        let j = &joints[spec_joint.get(i).copied().unwrap_or(0)];
        TextError::new(
            j.line,
            j.column,
            match e {
                SkeletonError::DuplicateName(_) => format!("joint name '{name}' is used twice"),
                SkeletonError::TooManyBones => {
                    format!("too many joints and connectors (at most {MAX_BONES} bones)")
                }
                _ => format!("joint '{name}' does not make a valid bone: {e:?}"),
            },
        )
    })?;

    // MOTION.
    cur.expect("MOTION")?;
    cur.expect("Frames:")?;
    let n_tok = cur.next("a frame count")?;
    let frames: usize = n_tok.text.parse().map_err(|_| {
        TextError::new(
            n_tok.line,
            n_tok.column,
            format!("expected a frame count, found '{}'", n_tok.text),
        )
    })?;
    cur.expect("Frame")?;
    cur.expect("Time:")?;
    let ft_tok = cur.next("the frame time in seconds")?;
    let frame_time: f64 = match ft_tok.text.parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 => v,
        _ => {
            return Err(TextError::new(
                ft_tok.line,
                ft_tok.column,
                format!("expected a positive frame time, found '{}'", ft_tok.text),
            ))
        }
    };
    let mut motion = Motion::new(skeleton.channel_count(), 1.0 / frame_time);
    motion.first_frame = 1;
    // Bone index -> value map, resolved by name once.
    let mut bone_maps: Vec<&ValueMap> = Vec::with_capacity(skeleton.len());
    for b in skeleton.bones() {
        let m = maps.iter().find(|(n, _)| n == b.name()).map(|(_, m)| m);
        static EMPTY: ValueMap = ValueMap { from: Vec::new() };
        bone_maps.push(m.unwrap_or(&EMPTY));
    }
    let mut row = vec![0.0f64; total_values];
    let mut read = 0usize;
    while cur.pos < cur.toks.len() {
        let line = cur.toks[cur.pos].line;
        let mut k = 0;
        while cur.pos < cur.toks.len() && cur.toks[cur.pos].line == line {
            let t = cur.toks[cur.pos];
            if k >= total_values {
                return Err(TextError::new(
                    t.line,
                    t.column,
                    format!("expected {total_values} values on a frame line, found more"),
                ));
            }
            row[k] = cur.number()?;
            k += 1;
        }
        if k != total_values {
            return Err(TextError::new(
                line,
                0,
                format!("expected {total_values} values on a frame line, found {k}"),
            ));
        }
        if read == frames {
            return Err(TextError::new(
                line,
                1,
                format!("expected {frames} frames (Frames:), found more"),
            ));
        }
        let frame = motion.push_rest_frame();
        for (b, m) in skeleton.bones().iter().zip(&bone_maps) {
            for (c, &src) in b.channels().zip(&m.from) {
                frame[c] = row[src];
            }
        }
        read += 1;
    }
    if read != frames {
        return Err(TextError::new(
            last_line,
            0,
            format!("expected {frames} frames (Frames:), found {read}"),
        ));
    }
    let asf = AsfFile {
        skeleton,
        name: root.name.to_string(),
        version: "1.10".into(),
        documentation: "imported from BVH by marionette".into(),
    };
    Ok((asf, motion))
}

/// Loads a BVH file (see [`parse`]).
///
/// # Errors
/// I/O errors, or `file:line:column` and what was expected.
pub fn load(path: &Path, inches_per_unit: f64) -> Result<(AsfFile, Motion), FileError> {
    let text = read_text(path)?;
    parse(&text, inches_per_unit).map_err(|e| FileError::parse(path, e))
}

/// Why a skeleton has no exact BVH form.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    /// A bone has translation or length channels.
    #[error(
        "bone '{0}' has translation or length channels, which BVH joints below the root cannot hold exactly"
    )]
    Translation(String),
    /// Writing failed.
    #[error(transparent)]
    Io(#[from] io::Error),
}

/// Writes a skeleton and motion as BVH (pose-exact; see the module docs).
///
/// # Errors
/// [`ExportError::Translation`] when a bone below the root has translation or length channels.
pub fn write(skeleton: &Skeleton, motion: &Motion, mut w: impl Write) -> Result<(), ExportError> {
    for b in &skeleton.bones()[1..] {
        if b.dofs().iter().any(|d| !d.is_rotation()) {
            return Err(ExportError::Translation(b.name().to_string()));
        }
    }
    let bones = skeleton.bones();
    let rest = |i: usize| bones[i].direction().as_dvec3() * f64::from(bones[i].length());
    writeln!(w, "HIERARCHY")?;
    // Pre-order walk; the skeleton is already in pre-order with parents first.
    fn walk(
        s: &Skeleton,
        i: usize,
        depth: usize,
        rest: &dyn Fn(usize) -> DVec3,
        w: &mut dyn Write,
    ) -> io::Result<()> {
        let pad = "  ".repeat(depth);
        let b = &s.bones()[i];
        if i == 0 {
            writeln!(w, "ROOT {}", b.name())?;
        } else {
            writeln!(w, "{pad}JOINT {}", b.name())?;
        }
        writeln!(w, "{pad}{{")?;
        let offset = match b.parent() {
            None => DVec3::ZERO,
            Some(p) => rest(p),
        };
        writeln!(
            w,
            "{pad}  OFFSET {} {} {}",
            exact(offset.x),
            exact(offset.y),
            exact(offset.z)
        )?;
        if i == 0 {
            writeln!(
                w,
                "{pad}  CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation"
            )?;
        } else {
            writeln!(w, "{pad}  CHANNELS 3 Zrotation Yrotation Xrotation")?;
        }
        let kids: Vec<usize> = s.children(i).collect();
        if kids.is_empty() {
            let e = rest(i);
            writeln!(w, "{pad}  End Site")?;
            writeln!(w, "{pad}  {{")?;
            writeln!(w, "{pad}    OFFSET {} {} {}", exact(e.x), exact(e.y), exact(e.z))?;
            writeln!(w, "{pad}  }}")?;
        }
        for k in kids {
            walk(s, k, depth + 1, rest, w)?;
        }
        writeln!(w, "{pad}}}")
    }
    walk(skeleton, 0, 0, &rest, &mut w)?;
    writeln!(w, "MOTION")?;
    writeln!(w, "Frames: {}", motion.len())?;
    writeln!(w, "Frame Time: {}", exact(1.0 / motion.frame_rate))?;
    let root = skeleton.root();
    let o = root.axis_order.to_mat3_f64(root.orientation.map(f64::from));
    let axes: Vec<DMat3> = bones
        .iter()
        .map(|b| b.spec().axis_order.to_mat3_f64(b.spec().axis.map(f64::from)))
        .collect();
    let mut line = String::new();
    for frame in motion.frames() {
        line.clear();
        for (i, b) in bones.iter().enumerate() {
            let values = &frame[b.channels()];
            let m = dof_rotation(b.dofs(), values.iter().map(|v| v.to_radians()));
            let q = if i == 0 {
                let mut t = root.position.as_dvec3();
                for (d, v) in b.dofs().iter().zip(values) {
                    match d {
                        Dof::Tx => t.x += v,
                        Dof::Ty => t.y += v,
                        Dof::Tz => t.z += v,
                        _ => {}
                    }
                }
                for v in [t.x, t.y, t.z] {
                    line.push_str(&exact(v));
                    line.push(' ');
                }
                o * m
            } else {
                axes[i] * m * axes[i].transpose()
            };
            let [x, y, z] = EulerOrder::XYZ.from_mat3_f64(&q);
            for v in [z, y, x] {
                line.push_str(&exact(v.to_degrees()));
                line.push(' ');
            }
        }
        writeln!(w, "{}", line.trim_end())?;
    }
    Ok(())
}

/// Writes a BVH file.
///
/// # Errors
/// See [`write()`]; I/O errors name the file.
pub fn save(skeleton: &Skeleton, motion: &Motion, path: &Path) -> Result<(), FileError> {
    let f = std::fs::File::create(path).map_err(|e| FileError::io(path, e))?;
    let mut w = io::BufWriter::new(f);
    match write(skeleton, motion, &mut w) {
        Ok(()) => w.flush().map_err(|e| FileError::io(path, e)),
        Err(ExportError::Io(e)) => Err(FileError::io(path, e)),
        Err(e) => Err(FileError::parse(path, TextError::new(0, 0, e.to_string()))),
    }
}
