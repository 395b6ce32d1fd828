//! A robot's kinematic tree from its MuJoCo model (MJCF) into the core's [`Robot`]: bodies'
//! `pos` and orientation (`quat`, `euler` with the compiler's `eulerseq`, `axisangle`), hinge
//! joints' `axis`, `pos` and `range`, named sites' `pos`, `<inertial>` masses and centres, the compiler's angle
//! unit, `<default>` classes and `childclass` resolved as MuJoCo resolves them, and top-level
//! `<include>` files. What a kinematic tree cannot hold (slide and ball joints, frames, a free
//! joint below the root) is an error naming the file, line and element.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use glam::{DQuat, DVec3};
use roxmltree::{Document, Node};

use super::{FileError, TextError};
use crate::robot::Robot;

/// A robot read from MJCF.
#[derive(Clone, Debug)]
pub struct MjcfRobot {
    /// The kinematic tree; the first body hangs from the world (its `pos`/`quat` place it).
    pub robot: Robot,
    /// Whether the first body has a free joint (a floating base).
    pub floating: bool,
    /// Bodies without an `<inertial>` (MuJoCo would infer their mass from geoms; here 0).
    pub without_inertial: Vec<String>,
}

/// Reads the robot in `path` (and the files it includes).
///
/// # Errors
/// [`FileError`] naming the file (the included one where the problem is), the line and the
/// element.
pub fn load(path: &Path) -> Result<MjcfRobot, FileError> {
    let mut reader = Reader {
        classes: HashMap::new(),
        degrees: true,
        eulerseq: *b"xyz",
        robot: Robot::new(),
        floating: false,
        without_inertial: Vec::new(),
    };
    let mut bodies = Vec::new();
    reader.read_file(path, &mut bodies)?;
    for (file, text) in &bodies {
        let doc = Document::parse(text).map_err(|e| xml_error(file, &e))?;
        let at = |n: Node<'_, '_>, m: String| FileError::parse(file, located(&doc, n, m));
        for world in doc
            .root_element()
            .children()
            .filter(|n| n.has_tag_name("worldbody"))
        {
            for body in world.children().filter(|n| n.has_tag_name("body")) {
                reader.body(body, None, "main", &at)?;
            }
        }
    }
    if reader.robot.bodies().is_empty() {
        return Err(FileError::parse(
            path,
            TextError::new(
                1,
                0,
                "expected a <worldbody> with at least one <body>, found none",
            ),
        ));
    }
    Ok(MjcfRobot {
        robot: reader.robot,
        floating: reader.floating,
        without_inertial: reader.without_inertial,
    })
}

/// A default class: its parent and its joint attributes.
struct Class {
    parent: Option<String>,
    joint: HashMap<String, String>,
    site: HashMap<String, String>,
}

struct Reader {
    classes: HashMap<String, Class>,
    degrees: bool,
    eulerseq: [u8; 3],
    robot: Robot,
    floating: bool,
    without_inertial: Vec<String>,
}

fn xml_error(file: &Path, e: &roxmltree::Error) -> FileError {
    let p = e.pos();
    let text = e.to_string();
    // The position is in the error's own text too; it is said once, as file:line:column.
    let what = text
        .strip_suffix(&format!(" at {}:{}", p.row, p.col))
        .unwrap_or(&text);
    FileError::parse(
        file,
        TextError::new(p.row, p.col, format!("expected well-formed XML: {what}")),
    )
}

fn located(doc: &Document<'_>, n: Node<'_, '_>, message: String) -> TextError {
    let p = doc.text_pos_at(n.range().start);
    TextError::new(p.row, p.col, format!("<{}>: {message}", n.tag_name().name()))
}

fn numbers<const N: usize>(text: &str) -> Option<[f64; N]> {
    let mut out = [0.0; N];
    let mut it = text.split_ascii_whitespace();
    for o in &mut out {
        *o = it.next()?.parse().ok().filter(|v: &f64| v.is_finite())?;
    }
    it.next().is_none().then_some(out)
}

impl Reader {
    /// Reads one file's `<compiler>`, `<default>` and includes; keeps its text for the bodies
    /// (read once every default is known, as MuJoCo does).
    fn read_file(&mut self, path: &Path, bodies: &mut Vec<(PathBuf, String)>) -> Result<(), FileError> {
        if bodies.len() > 32 {
            return Err(FileError::parse(
                path,
                TextError::new(1, 0, "expected at most 32 included files"),
            ));
        }
        let text = super::read_text(path)?;
        let doc = Document::parse(&text).map_err(|e| xml_error(path, &e))?;
        let at = |n: Node<'_, '_>, m: String| FileError::parse(path, located(&doc, n, m));
        let root = doc.root_element();
        if !root.has_tag_name("mujoco") {
            return Err(at(root, "expected the root element <mujoco>".into()));
        }
        let mut included = Vec::new();
        for n in root.children().filter(Node::is_element) {
            match n.tag_name().name() {
                "compiler" => {
                    if let Some(a) = n.attribute("angle") {
                        self.degrees = match a {
                            "degree" => true,
                            "radian" => false,
                            _ => {
                                return Err(at(
                                    n,
                                    format!("expected angle \"degree\" or \"radian\", found \"{a}\""),
                                ))
                            }
                        };
                    }
                    if let Some(s) = n.attribute("eulerseq") {
                        let b = s.as_bytes();
                        if b.len() != 3 || !b.iter().all(|c| b"xyzXYZ".contains(c)) {
                            return Err(at(
                                n,
                                format!("expected eulerseq of three of xyzXYZ, found \"{s}\""),
                            ));
                        }
                        self.eulerseq = [b[0], b[1], b[2]];
                    }
                }
                "default" => self.defaults(n, None, &at)?,
                "include" => {
                    let Some(file) = n.attribute("file") else {
                        return Err(at(n, "expected a file attribute".into()));
                    };
                    included.push(path.parent().unwrap_or(Path::new(".")).join(file));
                }
                _ => {}
            }
        }
        bodies.push((path.to_path_buf(), text.clone()));
        for file in included {
            self.read_file(&file, bodies)?;
        }
        Ok(())
    }

    fn defaults(
        &mut self,
        n: Node<'_, '_>,
        parent: Option<&str>,
        at: &dyn Fn(Node<'_, '_>, String) -> FileError,
    ) -> Result<(), FileError> {
        let name = match (n.attribute("class"), parent) {
            (Some(c), _) => c.to_string(),
            (None, None) => "main".to_string(),
            (None, Some(_)) => return Err(at(n, "expected a class attribute on a nested <default>".into())),
        };
        let mut joint = HashMap::new();
        for j in n.children().filter(|c| c.has_tag_name("joint")) {
            for a in j.attributes() {
                joint.insert(a.name().to_string(), a.value().to_string());
            }
        }
        let mut site = HashMap::new();
        for j in n.children().filter(|c| c.has_tag_name("site")) {
            for a in j.attributes() {
                site.insert(a.name().to_string(), a.value().to_string());
            }
        }
        self.classes.insert(
            name.clone(),
            Class {
                parent: parent.map(str::to_string),
                joint,
                site,
            },
        );
        for child in n.children().filter(|c| c.has_tag_name("default")) {
            self.defaults(child, Some(&name), at)?;
        }
        Ok(())
    }

    /// A joint attribute: the element's own, else its class's, else the class's parents'.
    fn joint_attr<'a>(&'a self, n: Node<'a, '_>, class: &str, key: &str) -> Option<&'a str> {
        self.class_attr(n, class, key, |c| &c.joint)
    }

    /// An attribute of an element whose defaults `of` picks from a class.
    fn class_attr<'a>(
        &'a self,
        n: Node<'a, '_>,
        class: &str,
        key: &str,
        of: impl Fn(&Class) -> &HashMap<String, String>,
    ) -> Option<&'a str> {
        if let Some(v) = n.attribute(key) {
            return Some(v);
        }
        let mut c = Some(n.attribute("class").unwrap_or(class));
        while let Some(name) = c {
            let class = self.classes.get(name)?;
            if let Some(v) = of(class).get(key) {
                return Some(v);
            }
            c = class.parent.as_deref().or((name != "main").then_some("main"));
        }
        None
    }

    fn angle(&self, v: f64) -> f64 {
        if self.degrees {
            v.to_radians()
        } else {
            v
        }
    }

    /// A body's orientation in its parent: `quat` (w x y z), `euler` or `axisangle`.
    fn orientation(
        &self,
        n: Node<'_, '_>,
        at: &dyn Fn(Node<'_, '_>, String) -> FileError,
    ) -> Result<DQuat, FileError> {
        if let Some(q) = n.attribute("quat") {
            let [w, x, y, z] =
                numbers::<4>(q).ok_or_else(|| at(n, format!("expected quat=\"w x y z\", found \"{q}\"")))?;
            let q = DQuat::from_xyzw(x, y, z, w);
            if q.length() == 0.0 {
                return Err(at(n, "expected a non-zero quat".into()));
            }
            return Ok(q.normalize());
        }
        if let Some(e) = n.attribute("euler") {
            let a =
                numbers::<3>(e).ok_or_else(|| at(n, format!("expected euler=\"a b c\", found \"{e}\"")))?;
            let mut q = DQuat::IDENTITY;
            for (k, &axis) in self.eulerseq.iter().enumerate() {
                let v = match axis.to_ascii_lowercase() {
                    b'x' => DVec3::X,
                    b'y' => DVec3::Y,
                    _ => DVec3::Z,
                };
                let r = DQuat::from_axis_angle(v, self.angle(a[k]));
                // Lower case: axes that turn with the frame (intrinsic); upper case: fixed axes.
                q = if axis.is_ascii_lowercase() { q * r } else { r * q };
            }
            return Ok(q);
        }
        if let Some(aa) = n.attribute("axisangle") {
            let [x, y, z, a] = numbers::<4>(aa)
                .ok_or_else(|| at(n, format!("expected axisangle=\"x y z a\", found \"{aa}\"")))?;
            let axis = DVec3::new(x, y, z)
                .try_normalize()
                .ok_or_else(|| at(n, "expected a non-zero axis".into()))?;
            return Ok(DQuat::from_axis_angle(axis, self.angle(a)));
        }
        for other in ["xyaxes", "zaxis"] {
            if n.attribute(other).is_some() {
                return Err(at(
                    n,
                    format!("{other} is not supported; expected quat, euler or axisangle"),
                ));
            }
        }
        Ok(DQuat::IDENTITY)
    }

    fn body(
        &mut self,
        n: Node<'_, '_>,
        parent: Option<usize>,
        class: &str,
        at: &dyn Fn(Node<'_, '_>, String) -> FileError,
    ) -> Result<(), FileError> {
        let name = n.attribute("name").unwrap_or("");
        let pos = match n.attribute("pos") {
            Some(p) => DVec3::from_array(
                numbers::<3>(p).ok_or_else(|| at(n, format!("expected pos=\"x y z\", found \"{p}\"")))?,
            ),
            None => DVec3::ZERO,
        };
        let quat = self.orientation(n, at)?;
        let class = n.attribute("childclass").unwrap_or(class).to_string();
        if !self.classes.contains_key(&class) && class != "main" {
            return Err(at(
                n,
                format!("expected a defined class, found childclass \"{class}\""),
            ));
        }
        let (mass, com) = match n.children().find(|c| c.has_tag_name("inertial")) {
            Some(i) => {
                let mass = i
                    .attribute("mass")
                    .and_then(|m| m.parse::<f64>().ok())
                    .filter(|m| m.is_finite() && *m >= 0.0)
                    .ok_or_else(|| at(i, "expected a mass of 0 or more".into()))?;
                let com = match i.attribute("pos") {
                    Some(p) => DVec3::from_array(
                        numbers::<3>(p)
                            .ok_or_else(|| at(i, format!("expected pos=\"x y z\", found \"{p}\"")))?,
                    ),
                    None => DVec3::ZERO,
                };
                (mass, com)
            }
            None => {
                self.without_inertial.push(name.to_string());
                (0.0, DVec3::ZERO)
            }
        };
        let index = self
            .robot
            .add_body(name, parent, pos, quat, mass, com)
            .map_err(|e| at(n, format!("cannot add body \"{name}\": {e}")))?;
        for c in n.children().filter(Node::is_element) {
            match c.tag_name().name() {
                "freejoint" => {
                    if parent.is_some() {
                        return Err(at(c, "expected a free joint on the first body only".into()));
                    }
                    self.floating = true;
                }
                "joint" => self.joint(c, index, &class, parent.is_none(), at)?,
                "site" => {
                    if let Some(site) = c.attribute("name") {
                        let pos = match self.class_attr(c, &class, "pos", |k| &k.site) {
                            Some(p) => DVec3::from_array(
                                numbers::<3>(p)
                                    .ok_or_else(|| at(c, format!("expected pos=\"x y z\", found \"{p}\"")))?,
                            ),
                            None => DVec3::ZERO,
                        };
                        self.robot
                            .add_site(site, index, pos)
                            .map_err(|e| at(c, format!("cannot add site \"{site}\": {e}")))?;
                    }
                }
                "body" => self.body(c, Some(index), &class, at)?,
                "frame" | "replicate" | "attach" => {
                    return Err(at(c, "is not supported in a robot's kinematic tree".into()));
                }
                _ => {}
            }
        }
        Ok(())
    }

    fn joint(
        &mut self,
        n: Node<'_, '_>,
        body: usize,
        class: &str,
        root: bool,
        at: &dyn Fn(Node<'_, '_>, String) -> FileError,
    ) -> Result<(), FileError> {
        if let Some(c) = n.attribute("class") {
            if !self.classes.contains_key(c) {
                return Err(at(n, format!("expected a defined class, found class \"{c}\"")));
            }
        }
        let name = n.attribute("name").unwrap_or("").to_string();
        match self.joint_attr(n, class, "type").unwrap_or("hinge") {
            "hinge" => {}
            "free" if root => {
                self.floating = true;
                return Ok(());
            }
            t => {
                return Err(at(
                    n,
                    format!("joint \"{name}\": expected a hinge, found type \"{t}\""),
                ))
            }
        }
        let vec3 = |key: &str, default: DVec3| -> Result<DVec3, FileError> {
            match self.joint_attr(n, class, key) {
                Some(v) => numbers::<3>(v)
                    .map(DVec3::from_array)
                    .ok_or_else(|| at(n, format!("expected {key}=\"x y z\", found \"{v}\""))),
                None => Ok(default),
            }
        };
        let axis = vec3("axis", DVec3::Z)?;
        let anchor = vec3("pos", DVec3::ZERO)?;
        let limited = self.joint_attr(n, class, "limited").unwrap_or("auto") != "false";
        let range = match self.joint_attr(n, class, "range") {
            Some(r) if limited => {
                let [lo, hi] = numbers::<2>(r)
                    .ok_or_else(|| at(n, format!("expected range=\"low high\", found \"{r}\"")))?;
                if lo > hi {
                    return Err(at(n, format!("expected range low ≤ high, found \"{r}\"")));
                }
                Some((self.angle(lo), self.angle(hi)))
            }
            _ => None,
        };
        self.robot
            .add_hinge(&name, body, axis, anchor, range)
            .map_err(|e| at(n, format!("joint \"{name}\": {e}")))?;
        Ok(())
    }
}
