//! The ASF skeleton reader, `no_std` and allocation free: text in, [`Skeleton`] out.
//!
//! Reads every section (`:version :name :units :documentation :root :bonedata :hierarchy`,
//! and skips `:skin`), CRLF or LF, tabs, `#` comments, blank lines and scientific notation.
//! Units are honoured (`angle deg|rad` applies to `axis`, `limits` and the root orientation),
//! bone axes may use any of the 12 Euler orders, `dof` any subset and order of
//! `rx ry rz tx ty tz l`, and `limits` may span lines and use `inf`.

use crate::math::EulerOrder;
use crate::skeleton::{
    BoneName, BoneSpec, Dof, Limit, RootSpec, Skeleton, SkeletonError, Units, MAX_BONES, MAX_BONE_DOFS,
};
use core::fmt;
use glam::Vec3;

/// A parsed ASF file. Text fields borrow from the input.
#[derive(Clone, Debug)]
pub struct Asf<'a> {
    /// The skeleton.
    pub skeleton: Skeleton,
    /// `:version`.
    pub version: &'a str,
    /// `:name`.
    pub name: &'a str,
    /// The `:documentation` lines, as they stand in the file.
    pub documentation: &'a str,
}

/// Where an ASF file is wrong and what was expected there.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct AsfError<'a> {
    /// 1-based line.
    pub line: u32,
    /// 1-based column (bytes).
    pub column: u32,
    /// What is wrong.
    pub kind: AsfErrorKind<'a>,
}

/// What is wrong in an ASF file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum AsfErrorKind<'a> {
    /// Something else stood where `expected` should have (`found` is empty at end of line).
    Expected {
        /// What the reader wanted.
        expected: &'static str,
        /// What it found.
        found: &'a str,
    },
    /// A bone name that was already used.
    DuplicateBone(&'a str),
    /// A name in `:hierarchy` that no bone has.
    UnknownBone(&'a str),
    /// A bone given a parent twice in `:hierarchy`.
    TwoParents(&'a str),
    /// A bone not connected to the root (missing from `:hierarchy`, or in a cycle).
    Detached(&'a str),
    /// A bone block without a required field.
    Missing {
        /// The field.
        field: &'static str,
        /// The bone's name, when the block has one.
        bone: &'a str,
    },
    /// A bone's fields contradict each other (e.g. fewer limits than DOFs).
    Invalid(&'static str),
    /// A fixed capacity was exceeded.
    TooMany {
        /// Of what.
        what: &'static str,
        /// The capacity.
        max: usize,
    },
}

impl fmt::Display for AsfErrorKind<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            AsfErrorKind::Expected { expected, found: "" } => {
                write!(f, "expected {expected}, found end of line")
            }
            AsfErrorKind::Expected { expected, found } => write!(f, "expected {expected}, found '{found}'"),
            AsfErrorKind::DuplicateBone(n) => write!(f, "bone '{n}' is defined twice"),
            AsfErrorKind::UnknownBone(n) => write!(f, "unknown bone '{n}' in :hierarchy"),
            AsfErrorKind::TwoParents(n) => write!(f, "bone '{n}' is given a second parent in :hierarchy"),
            AsfErrorKind::Detached(n) => write!(
                f,
                "bone '{n}' is not connected to the root (missing from :hierarchy or part of a cycle)"
            ),
            AsfErrorKind::Missing { field, bone: "" } => {
                write!(f, "bone block has no '{field}'")
            }
            AsfErrorKind::Missing { field, bone } => write!(f, "bone '{bone}' has no '{field}'"),
            AsfErrorKind::Invalid(what) => write!(f, "{what}"),
            AsfErrorKind::TooMany { what, max } => write!(f, "too many {what} (at most {max})"),
        }
    }
}

impl fmt::Display for AsfError<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}:{}: {}", self.line, self.column, self.kind)
    }
}

impl core::error::Error for AsfError<'_> {}

#[derive(Clone, Copy, Debug)]
struct Token<'a> {
    text: &'a str,
    line: u32,
    column: u32,
}

/// One line of the file, comments removed.
#[derive(Clone, Copy, Debug)]
struct Line<'a> {
    text: &'a str,
    number: u32,
    /// Byte offset of the line in the file.
    offset: usize,
}

impl<'a> Line<'a> {
    fn tokens(self) -> Tokens<'a> {
        Tokens { line: self, pos: 0 }
    }
    fn first(self) -> Option<Token<'a>> {
        self.tokens().next()
    }
    fn end(self) -> Token<'a> {
        Token {
            text: "",
            line: self.number,
            column: self.text.len() as u32 + 1,
        }
    }
}

/// Splits a line on white space; `(` and `)` are tokens of their own; `#` starts a comment.
struct Tokens<'a> {
    line: Line<'a>,
    pos: usize,
}

impl<'a> Iterator for Tokens<'a> {
    type Item = Token<'a>;
    fn next(&mut self) -> Option<Token<'a>> {
        let bytes = self.line.text.as_bytes();
        while self.pos < bytes.len() && bytes[self.pos].is_ascii_whitespace() {
            self.pos += 1;
        }
        if self.pos >= bytes.len() || bytes[self.pos] == b'#' {
            self.pos = bytes.len();
            return None;
        }
        let start = self.pos;
        if matches!(bytes[start], b'(' | b')') {
            self.pos += 1;
        } else {
            while self.pos < bytes.len()
                && !bytes[self.pos].is_ascii_whitespace()
                && !matches!(bytes[self.pos], b'(' | b')' | b'#')
            {
                self.pos += 1;
            }
        }
        // Token boundaries fall on ASCII bytes, so they are char boundaries.
        let text = self.line.text.get(start..self.pos).unwrap_or("");
        Some(Token {
            text,
            line: self.line.number,
            column: start as u32 + 1,
        })
    }
}

struct Lines<'a> {
    text: &'a str,
    pos: usize,
    number: u32,
    peeked: Option<Line<'a>>,
}

impl<'a> Lines<'a> {
    /// Lines of `text` (a byte-order mark already removed: offsets count from its start).
    fn new(text: &'a str) -> Self {
        Lines {
            text,
            pos: 0,
            number: 0,
            peeked: None,
        }
    }

    fn raw_next(&mut self) -> Option<Line<'a>> {
        if self.pos >= self.text.len() {
            return None;
        }
        let rest = &self.text[self.pos..];
        let len = rest.find('\n').unwrap_or(rest.len());
        let raw = &rest[..len];
        let line = Line {
            text: raw.strip_suffix('\r').unwrap_or(raw),
            number: self.number + 1,
            offset: self.pos,
        };
        self.number += 1;
        self.pos += (len + 1).min(rest.len());
        Some(line)
    }

    /// The next line that has a token.
    fn next(&mut self) -> Option<Line<'a>> {
        if let Some(l) = self.peeked.take() {
            return Some(l);
        }
        loop {
            let l = self.raw_next()?;
            if l.first().is_some() {
                return Some(l);
            }
        }
    }

    fn peek(&mut self) -> Option<Line<'a>> {
        if self.peeked.is_none() {
            self.peeked = self.next();
        }
        self.peeked
    }

    /// True when the next non-blank line starts a new section (or the file ends).
    fn at_section(&mut self) -> bool {
        match self.peek() {
            None => true,
            Some(l) => l.first().is_some_and(|t| t.text.starts_with(':')),
        }
    }

    fn end_of_file(&self) -> Token<'a> {
        Token {
            text: "",
            line: self.number.max(1),
            column: 1,
        }
    }
}

fn err<'a>(at: Token<'a>, kind: AsfErrorKind<'a>) -> AsfError<'a> {
    AsfError {
        line: at.line,
        column: at.column,
        kind,
    }
}

fn expected<'a>(at: Token<'a>, what: &'static str) -> AsfError<'a> {
    err(
        at,
        AsfErrorKind::Expected {
            expected: what,
            found: at.text,
        },
    )
}

fn next_token<'a>(toks: &mut Tokens<'a>, what: &'static str) -> Result<Token<'a>, AsfError<'a>> {
    let end = toks.line.end();
    toks.next().ok_or_else(|| expected(end, what))
}

/// Largest magnitude accepted for a number; anything larger is taken as a corrupt file (and
/// would overflow f32 positions).
pub const MAX_MAGNITUDE: f32 = 1.0e9;

fn number<'a>(toks: &mut Tokens<'a>, what: &'static str) -> Result<f32, AsfError<'a>> {
    let t = next_token(toks, what)?;
    match t.text.parse::<f32>() {
        Ok(v) if v.abs() <= MAX_MAGNITUDE => Ok(v),
        Ok(_) => Err(expected(t, "a number between -1e9 and 1e9")),
        _ => Err(expected(t, what)),
    }
}

fn vec3<'a>(toks: &mut Tokens<'a>) -> Result<[f32; 3], AsfError<'a>> {
    Ok([
        number(toks, "a number")?,
        number(toks, "a number")?,
        number(toks, "a number")?,
    ])
}

fn end_of_line<'a>(toks: &mut Tokens<'a>) -> Result<(), AsfError<'a>> {
    match toks.next() {
        None => Ok(()),
        Some(t) => Err(expected(t, "end of line")),
    }
}

/// A limit bound: a finite number or ±inf.
fn bound<'a>(t: Token<'a>) -> Result<f32, AsfError<'a>> {
    match t.text.parse::<f32>() {
        Ok(v) if v.is_infinite() || v.abs() <= MAX_MAGNITUDE => Ok(v),
        _ => Err(expected(t, "a limit (number between -1e9 and 1e9, or inf)")),
    }
}

/// The rest of the line after `kw`, trimmed.
fn rest_of_line<'a>(line: Line<'a>, kw: Token<'a>) -> &'a str {
    let start = (kw.column as usize - 1 + kw.text.len()).min(line.text.len());
    line.text[start..].trim()
}

struct RawBone<'a> {
    spec: BoneSpec,
    /// Limits as written (file angle unit for rotations).
    raw_axis: [f32; 3],
    begin: Token<'a>,
    name: &'a str,
    parent: Option<Option<usize>>,
}

/// Parses ASF text.
///
/// # Errors
/// [`AsfError`] with the line and column of the first problem.
pub fn parse_asf(text: &str) -> Result<Asf<'_>, AsfError<'_>> {
    // Offsets into the text (the documentation) count from after a byte-order mark.
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let mut lines = Lines::new(text);
    let mut version = "";
    let mut name = "";
    let mut documentation = "";
    let mut units = Units::default();
    let mut root = RootSpec::default();
    let mut raw_orientation = [0.0f32; 3];
    let mut bones: heapless::Vec<RawBone<'_>, { MAX_BONES - 1 }> = heapless::Vec::new();
    let mut seen_any = false;

    while let Some(line) = lines.next() {
        let mut toks = line.tokens();
        let Some(kw) = toks.next() else { continue };
        seen_any = true;
        match kw.text {
            ":version" => version = rest_of_line(line, kw),
            ":name" => name = rest_of_line(line, kw),
            ":units" => {
                parse_units(&mut toks, &mut units)?;
                while !lines.at_section() {
                    let Some(l) = lines.next() else { break };
                    parse_units(&mut l.tokens(), &mut units)?;
                }
            }
            ":documentation" => {
                let mut first: Option<Line<'_>> = None;
                let mut last: Option<Line<'_>> = None;
                while !lines.at_section() {
                    let Some(l) = lines.next() else { break };
                    first.get_or_insert(l);
                    last = Some(l);
                }
                if let (Some(a), Some(b)) = (first, last) {
                    documentation = &text[a.offset..b.offset + b.text.len()];
                }
            }
            ":root" => {
                end_of_line(&mut toks)?;
                while !lines.at_section() {
                    let Some(l) = lines.next() else { break };
                    parse_root_line(l, &mut root, &mut raw_orientation)?;
                }
            }
            ":bonedata" => {
                end_of_line(&mut toks)?;
                while !lines.at_section() {
                    let Some(l) = lines.next() else { break };
                    let bone = parse_bone(l, &mut lines)?;
                    if let Some(prev) = bones.iter().find(|b| b.name == bone.name) {
                        let _ = prev;
                        return Err(err(bone.begin, AsfErrorKind::DuplicateBone(bone.name)));
                    }
                    if bone.name.eq_ignore_ascii_case("root") {
                        return Err(err(
                            bone.begin,
                            AsfErrorKind::Invalid("a bone may not be called 'root'"),
                        ));
                    }
                    let begin = bone.begin;
                    if bones.push(bone).is_err() {
                        return Err(err(
                            begin,
                            AsfErrorKind::TooMany {
                                what: "bones",
                                max: MAX_BONES - 1,
                            },
                        ));
                    }
                }
            }
            ":hierarchy" => {
                end_of_line(&mut toks)?;
                parse_hierarchy(&mut lines, &mut bones)?;
            }
            ":skin" => {
                while !lines.at_section() {
                    lines.next();
                }
            }
            _ => {
                return Err(expected(
                    kw,
                    "an ASF section (:version, :name, :units, :documentation, :root, :bonedata, :hierarchy)",
                ))
            }
        }
    }
    if !seen_any {
        return Err(expected(
            lines.end_of_file(),
            "an ASF skeleton (the file is empty)",
        ));
    }

    // Angles are converted once every section, :units included, has been read.
    let to_rad = |v: f32| {
        if units.degrees {
            crate::math::deg_to_rad(v)
        } else {
            v
        }
    };
    root.orientation = raw_orientation.map(to_rad);
    let mut specs: heapless::Vec<BoneSpec, { MAX_BONES - 1 }> = heapless::Vec::new();
    let mut parents: heapless::Vec<Option<usize>, { MAX_BONES - 1 }> = heapless::Vec::new();
    for b in &bones {
        let mut spec = b.spec.clone();
        spec.axis = b.raw_axis.map(to_rad);
        for (l, d) in spec.limits.iter_mut().zip(spec.dofs.iter()) {
            if d.is_rotation() {
                l.min = to_rad(l.min);
                l.max = to_rad(l.max);
            }
        }
        let _ = specs.push(spec);
        let _ = parents.push(b.parent.unwrap_or(None));
    }
    // A bone that never appeared as a child in :hierarchy is detached, even though the
    // skeleton builder would read `None` as "child of the root".
    if let Some(b) = bones.iter().find(|b| b.parent.is_none()) {
        return Err(err(b.begin, AsfErrorKind::Detached(b.name)));
    }
    let skeleton = Skeleton::new(root, units, &specs, &parents).map_err(|e| {
        let (i, kind) = match e {
            SkeletonError::TooManyBones => (
                0,
                AsfErrorKind::TooMany {
                    what: "bones",
                    max: MAX_BONES - 1,
                },
            ),
            SkeletonError::DuplicateName(i) => (i, AsfErrorKind::DuplicateBone(bones[i].name)),
            SkeletonError::Detached(i) => (i, AsfErrorKind::Detached(bones[i].name)),
            SkeletonError::BadParent(i) => (i, AsfErrorKind::Invalid("bad parent")),
            SkeletonError::BadDirection(i) => {
                (i, AsfErrorKind::Invalid("direction is zero but length is not"))
            }
            SkeletonError::BadLength(i) => {
                (i, AsfErrorKind::Invalid("length must be finite and not negative"))
            }
            SkeletonError::BadChannels(i) => (
                i,
                AsfErrorKind::Invalid("channels repeat, or a limit has min > max"),
            ),
        };
        let at = bones.get(i).map(|b| b.begin).unwrap_or(Token {
            text: "",
            line: 1,
            column: 1,
        });
        err(at, kind)
    })?;
    Ok(Asf {
        skeleton,
        version,
        name,
        documentation,
    })
}

fn parse_units<'a>(toks: &mut Tokens<'a>, units: &mut Units) -> Result<(), AsfError<'a>> {
    while let Some(key) = toks.next() {
        match key.text {
            "mass" => units.mass = positive(toks, "a positive mass")?,
            "length" => units.length = positive(toks, "a positive length unit")?,
            "angle" => {
                let t = next_token(toks, "deg or rad")?;
                units.degrees = match t.text {
                    "deg" | "degrees" | "DEG" => true,
                    "rad" | "radians" | "RAD" => false,
                    _ => return Err(expected(t, "deg or rad")),
                };
            }
            _ => return Err(expected(key, "mass, length or angle")),
        }
    }
    Ok(())
}

fn positive<'a>(toks: &mut Tokens<'a>, what: &'static str) -> Result<f32, AsfError<'a>> {
    let t = next_token(toks, what)?;
    match t.text.parse::<f32>() {
        Ok(v) if v > 0.0 && v <= MAX_MAGNITUDE => Ok(v),
        _ => Err(expected(t, what)),
    }
}

fn parse_root_line<'a>(
    line: Line<'a>,
    root: &mut RootSpec,
    raw_orientation: &mut [f32; 3],
) -> Result<(), AsfError<'a>> {
    let mut toks = line.tokens();
    let Some(key) = toks.next() else { return Ok(()) };
    match key.text {
        "order" => {
            root.order.clear();
            for t in toks.by_ref() {
                match Dof::parse(t.text) {
                    Some(d) if d != Dof::L && !root.order.contains(&d) => {
                        let _ = root.order.push(d);
                    }
                    _ => return Err(expected(t, "a root channel (TX TY TZ RX RY RZ), each once")),
                }
            }
        }
        "axis" => {
            let t = next_token(&mut toks, "an Euler order such as XYZ")?;
            root.axis_order =
                EulerOrder::parse(t.text).ok_or_else(|| expected(t, "an Euler order such as XYZ"))?;
        }
        "position" => root.position = Vec3::from(vec3(&mut toks)?),
        "orientation" => *raw_orientation = vec3(&mut toks)?,
        _ => return Err(expected(key, "order, axis, position or orientation")),
    }
    end_of_line(&mut toks)
}

fn parse_bone<'a>(begin_line: Line<'a>, lines: &mut Lines<'a>) -> Result<RawBone<'a>, AsfError<'a>> {
    let mut toks = begin_line.tokens();
    let begin = next_token(&mut toks, "begin")?;
    if begin.text != "begin" {
        return Err(expected(begin, "begin"));
    }
    end_of_line(&mut toks)?;
    let mut name: Option<Token<'a>> = None;
    let mut id = 0u32;
    let mut direction: Option<Vec3> = None;
    let mut length: Option<f32> = None;
    let mut axis = [0.0f32; 3];
    let mut axis_order = EulerOrder::XYZ;
    let mut dofs: heapless::Vec<Dof, MAX_BONE_DOFS> = heapless::Vec::new();
    let mut limits: heapless::Vec<Limit, MAX_BONE_DOFS> = heapless::Vec::new();
    let mut limits_at: Option<Token<'a>> = None;
    loop {
        let Some(line) = lines.next() else {
            return Err(expected(lines.end_of_file(), "'end' of the bone block"));
        };
        let mut toks = line.tokens();
        let Some(key) = toks.next() else { continue };
        match key.text {
            "end" => {
                end_of_line(&mut toks)?;
                break;
            }
            "id" => {
                let t = next_token(&mut toks, "a bone id")?;
                id = t
                    .text
                    .parse()
                    .map_err(|_| expected(t, "a whole-number bone id"))?;
            }
            "name" => {
                let t = next_token(&mut toks, "a bone name")?;
                if BoneName::try_from(t.text).is_err() {
                    return Err(err(
                        t,
                        AsfErrorKind::TooMany {
                            what: "bytes in a bone name",
                            max: crate::skeleton::MAX_NAME_LEN,
                        },
                    ));
                }
                name = Some(t);
            }
            "direction" => direction = Some(Vec3::from(vec3(&mut toks)?)),
            "length" => {
                let t = next_token(&mut toks, "a bone length")?;
                match t.text.parse::<f32>() {
                    Ok(v) if (0.0..=MAX_MAGNITUDE).contains(&v) => length = Some(v),
                    _ => return Err(expected(t, "a bone length from 0 to 1e9")),
                }
            }
            "axis" => {
                axis = vec3(&mut toks)?;
                let t = next_token(&mut toks, "an Euler order such as XYZ")?;
                axis_order =
                    EulerOrder::parse(t.text).ok_or_else(|| expected(t, "an Euler order such as XYZ"))?;
            }
            "dof" => {
                dofs.clear();
                for t in toks.by_ref() {
                    match Dof::parse(t.text) {
                        Some(d) if !dofs.contains(&d) => {
                            let _ = dofs.push(d);
                        }
                        _ => return Err(expected(t, "a DOF (rx ry rz tx ty tz l), each once")),
                    }
                }
            }
            "limits" => {
                limits_at = Some(key);
                limits.clear();
                parse_limits(&mut toks, lines, &mut limits)?;
            }
            "bodymass" | "cofmass" => {
                number(&mut toks, "a number")?;
            }
            _ => {
                return Err(expected(
                    key,
                    "a bone field (id, name, direction, length, axis, dof, limits) or 'end'",
                ))
            }
        }
        end_of_line(&mut toks)?;
    }
    let Some(name_tok) = name else {
        return Err(err(
            begin,
            AsfErrorKind::Missing {
                field: "name",
                bone: "",
            },
        ));
    };
    let Some(direction) = direction else {
        return Err(err(
            begin,
            AsfErrorKind::Missing {
                field: "direction",
                bone: name_tok.text,
            },
        ));
    };
    let Some(length) = length else {
        return Err(err(
            begin,
            AsfErrorKind::Missing {
                field: "length",
                bone: name_tok.text,
            },
        ));
    };
    if limits_at.is_none() {
        for _ in 0..dofs.len() {
            let _ = limits.push(Limit::UNLIMITED);
        }
    } else if limits.len() != dofs.len() {
        return Err(err(
            limits_at.unwrap_or(begin),
            AsfErrorKind::Invalid("the number of limits differs from the number of DOFs"),
        ));
    }
    let len = direction.length();
    let direction = if len > 0.0 {
        direction / len
    } else if length == 0.0 {
        Vec3::ZERO
    } else {
        return Err(err(
            begin,
            AsfErrorKind::Invalid("direction is zero but length is not"),
        ));
    };
    if !direction.is_finite() {
        return Err(err(begin, AsfErrorKind::Invalid("direction is not finite")));
    }
    let mut spec = BoneSpec::new(
        BoneName::try_from(name_tok.text).unwrap_or_default(),
        direction,
        length,
    );
    spec.id = id;
    spec.axis_order = axis_order;
    spec.dofs = dofs;
    spec.limits = limits;
    Ok(RawBone {
        spec,
        raw_axis: axis,
        begin: name_tok,
        name: name_tok.text,
        parent: None,
    })
}

/// `(min max)` pairs, possibly continued on following lines that start with `(`.
fn parse_limits<'a>(
    toks: &mut Tokens<'a>,
    lines: &mut Lines<'a>,
    limits: &mut heapless::Vec<Limit, MAX_BONE_DOFS>,
) -> Result<(), AsfError<'a>> {
    loop {
        match toks.next() {
            Some(open) if open.text == "(" => {
                let lo = bound(next_token(toks, "a limit (number or inf)")?)?;
                let hi = bound(next_token(toks, "a limit (number or inf)")?)?;
                let close = next_token(toks, "')'")?;
                if close.text != ")" {
                    return Err(expected(close, "')'"));
                }
                if lo > hi {
                    return Err(err(
                        open,
                        AsfErrorKind::Invalid("limit minimum is above its maximum"),
                    ));
                }
                if limits.push(Limit { min: lo, max: hi }).is_err() {
                    return Err(err(
                        open,
                        AsfErrorKind::TooMany {
                            what: "limits",
                            max: MAX_BONE_DOFS,
                        },
                    ));
                }
            }
            Some(t) => return Err(expected(t, "'(' starting a limit pair")),
            None => {
                // Continue on the next line if it holds more pairs.
                let continues = lines
                    .peek()
                    .and_then(|l| l.first())
                    .is_some_and(|t| t.text == "(");
                if !continues {
                    return Ok(());
                }
                let Some(next) = lines.next() else { return Ok(()) };
                *toks = next.tokens();
            }
        }
    }
}

fn parse_hierarchy<'a>(lines: &mut Lines<'a>, bones: &mut [RawBone<'a>]) -> Result<(), AsfError<'a>> {
    let Some(first) = lines.next() else {
        return Err(expected(lines.end_of_file(), "begin"));
    };
    let mut toks = first.tokens();
    let begin = next_token(&mut toks, "begin")?;
    if begin.text != "begin" {
        return Err(expected(begin, "begin"));
    }
    end_of_line(&mut toks)?;
    loop {
        let Some(line) = lines.next() else {
            return Err(expected(lines.end_of_file(), "'end' of :hierarchy"));
        };
        let mut toks = line.tokens();
        let Some(parent_tok) = toks.next() else { continue };
        if parent_tok.text == "end" {
            return end_of_line(&mut toks);
        }
        let parent = if parent_tok.text == "root" {
            None
        } else {
            Some(
                bones
                    .iter()
                    .position(|b| b.name == parent_tok.text)
                    .ok_or_else(|| err(parent_tok, AsfErrorKind::UnknownBone(parent_tok.text)))?,
            )
        };
        let mut any = false;
        for child in toks {
            any = true;
            if child.text == "root" {
                return Err(err(child, AsfErrorKind::Invalid("the root cannot be a child")));
            }
            let c = bones
                .iter()
                .position(|b| b.name == child.text)
                .ok_or_else(|| err(child, AsfErrorKind::UnknownBone(child.text)))?;
            if bones[c].parent.is_some() {
                return Err(err(child, AsfErrorKind::TwoParents(child.text)));
            }
            if parent == Some(c) {
                return Err(err(child, AsfErrorKind::Detached(child.text)));
            }
            bones[c].parent = Some(parent);
        }
        if !any {
            return Err(expected(line.end(), "child bone names after the parent"));
        }
    }
}
