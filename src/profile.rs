//! Rig profiles: TOML files describing a bus and its servos, validated on load with
//! `file:line:column` errors.
//!
//! ```toml
//! [rig]
//! name = "CMU puppet"
//!
//! [bus]
//! baud = 4_000_000          # bit/s, a Dynamixel rate every servo supports
//! return_delay_us = 0       # Return Delay Time written at start-up (0…508, even)
//! read = "sync"             # sync | bulk | fast-sync | fast-bulk
//! read_fields = ["position"] # position, velocity, current
//! usb_latency_us = 1000     # the adapter's latency timer
//! pipeline = true           # request the read after the write, take it next tick
//! watchdog_ms = 100         # Bus Watchdog armed at start-up (20…2540, 0 = off)
//! imu_board_id = 200        # optional: a sensor board on this bus (the OP3's OpenCR, its IMU)
//!
//! [[bone]]                  # optional: the rig's own axis order for a bone
//! name = "lhumerus"
//! order = "ZYX"
//!
//! [[servo]]
//! id = 1
//! name = "l_shoulder_z"
//! model = "XL430-W250"
//! bone = "lhumerus.rz"      # or: joint = "r_sho_pitch" for a robot joint
//! direction = 1             # +1 or −1
//! zero = 2048               # tick at joint angle 0 (`marionette calibrate` measures it)
//! homing_offset = 0         # optional: the servo's Homing Offset (ticks), written at start-up;
//!                           # `calibrate` sets it where the joint's range would wrap past 0/4095
//! gear = 1.0                # servo turns per joint turn
//! min_deg = -90             # software limits (joint degrees)
//! max_deg = 90
//! max_velocity_dps = 360
//! max_acceleration_dps2 = 3600
//! position_p_gain = 1600    # optional: Position P Gain written at start-up (factory value otherwise)
//! lag_ms = 25               # optional: how far the horn lags its goal (`marionette identify`);
//!                           # the look-ahead leads the servo by it
//! supply_v = 12.0           # optional: the servo's supply (default: the model's recommended);
//!                           # speed and torque scale with it
//! ```
//!
//! A profile whose servos follow robot joints (`joint = …`) may say how a human drives them
//! (the retarget map; see [`RetargetSpec`] and `firmware-profile/robotis-op3.toml`):
//!
//! ```toml
//! [retarget]
//! model = "../sim/models/robotis_op3/op3.xml"   # MJCF, relative to the profile
//! base = "body_link"                            # the robot's pelvis body
//! # leg_scale = 0.3                             # robot / human leg length (default: measured)
//!
//! [retarget.names]          # optional: the skeleton's names for bones named otherwise
//! lhumerus = "mixamorig:LeftArm"
//!
//! [retarget.left_arm]       # upper arm, forearm → shoulder, shoulder, elbow
//! human = ["lhumerus", "lradius"]
//! robot = ["l_sho_pitch", "l_sho_roll", "l_el"]
//! tip = "l_hand"                                # a site, or [x, y, z] in the elbow's body
//!
//! [retarget.left_leg]       # thigh, shin, foot → hip ×3, knee, ankle ×2
//! human = ["lfemur", "ltibia", "lfoot"]
//! robot = ["l_hip_yaw", "l_hip_roll", "l_hip_pitch", "l_knee", "l_ank_pitch", "l_ank_roll"]
//! sole_centre = "l_foot"                        # a site, or [x, y, z] in the last ankle body
//! sole_half_size = [0.057, 0.039]
//!
//! [retarget.head]           # head → pan, tilt
//! human = ["head"]
//! robot = ["head_pan", "head_tilt"]
//! ```
//!
//! Human bones are named as in CMU's ASF files; a BVH skeleton with CMU's BVH names
//! (`LeftArm`, `LeftForeArm`, …) is understood as well, and `[retarget.names]` names others.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use serde::Deserialize;
use toml::Spanned;

use crate::formats::{read_text, FileError, TextError};
use crate::math::EulerOrder;
use crate::rig::{JointSource, Rig, ServoMap};
use crate::servo::MAX_SERVOS;
use crate::servo::{self, ServoModel, MAX_TICK};
use crate::skeleton::{Dof, Skeleton};

/// Baud rates a Dynamixel X servo can be set to.
pub const DYNAMIXEL_BAUDS: [u32; 8] = [
    9_600, 57_600, 115_200, 1_000_000, 2_000_000, 3_000_000, 4_000_000, 4_500_000,
];

/// How present values are read each cycle.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum ReadMode {
    /// Sync Read (0x82): one request, one status packet per servo.
    Sync,
    /// Bulk Read (0x92): one request naming each servo's address, one status packet per servo.
    Bulk,
    /// Fast Sync Read (0x8A, X firmware ≥ 45): one request, one combined reply.
    FastSync,
    /// Fast Bulk Read (0x9A, X firmware ≥ 45): one request naming each servo's address, one
    /// combined reply.
    FastBulk,
}

impl ReadMode {
    /// Its name in profiles (`sync`, `bulk`, `fast-sync`, `fast-bulk`).
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            ReadMode::Sync => "sync",
            ReadMode::Bulk => "bulk",
            ReadMode::FastSync => "fast-sync",
            ReadMode::FastBulk => "fast-bulk",
        }
    }
}

/// Which present values are read each cycle (one contiguous block of the control table).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct ReadFields {
    /// Present Velocity (128, 4 B).
    pub velocity: bool,
    /// Present Current (126, 2 B).
    pub current: bool,
}

impl ReadFields {
    /// Start address and length of the block holding Present Position and the asked fields.
    #[must_use]
    pub fn block(self) -> (u16, u16) {
        let end = servo::addr::PRESENT_POSITION + 4;
        let start = if self.current {
            servo::addr::PRESENT_CURRENT
        } else if self.velocity {
            servo::addr::PRESENT_VELOCITY
        } else {
            servo::addr::PRESENT_POSITION
        };
        (start, end - start)
    }
}

/// The bus section.
#[derive(Clone, Debug, PartialEq)]
pub struct BusConfig {
    /// Bit/s.
    pub baud: u32,
    /// Return Delay Time to configure, µs.
    pub return_delay_us: u32,
    /// Read pattern.
    pub read: ReadMode,
    /// Fields read besides the position.
    pub read_fields: ReadFields,
    /// USB adapter latency timer, µs.
    pub usb_latency_us: u32,
    /// Bus Watchdog, ms (0 = off).
    pub watchdog_ms: u32,
    /// Pipelined reads: the read is requested after each tick's Sync Write and its replies
    /// taken at the start of the next tick (default on).
    pub pipeline: bool,
    /// The id of a sensor board on the same bus (the OP3's OpenCR and its IMU, 200 from the
    /// factory), when the robot has one (`imu_board_id`).
    pub imu_board: Option<u8>,
}

impl BusConfig {
    /// A bus nothing is known about but its baud (a scan): the servos' factory Return Delay
    /// Time (250 × 2 µs), an FTDI adapter's default latency timer (16 ms), Sync Read, no
    /// pipelining, the watchdog off.
    #[must_use]
    pub fn unknown(baud: u32) -> BusConfig {
        BusConfig {
            baud,
            return_delay_us: 500,
            read: ReadMode::Sync,
            read_fields: ReadFields::default(),
            usb_latency_us: 16_000,
            watchdog_ms: 0,
            pipeline: false,
            imu_board: None,
        }
    }
}

/// What drives a servo, as written in the profile.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Drive {
    /// A bone's DOF, e.g. `lhumerus.rz`.
    Bone {
        /// Bone name.
        bone: String,
        /// DOF.
        dof: Dof,
    },
    /// A named robot joint.
    Joint(String),
}

/// One servo as the profile gives it.
#[derive(Clone, Debug, PartialEq)]
pub struct ServoSpec {
    /// Bus id (0…252).
    pub id: u8,
    /// Name (unique in the profile).
    pub name: String,
    /// Model.
    pub model: &'static ServoModel,
    /// What drives it.
    pub drive: Drive,
    /// +1 or −1.
    pub direction: f64,
    /// Tick at joint angle 0.
    pub zero: f64,
    /// Servo turns per joint turn.
    pub gear: f64,
    /// Lowest joint angle, degrees.
    pub min_deg: f64,
    /// Highest joint angle, degrees.
    pub max_deg: f64,
    /// Most joint degrees per second.
    pub max_velocity_dps: f64,
    /// Most joint degrees per second².
    pub max_acceleration_dps2: f64,
    /// Position P Gain written at start-up (`None`: the servo keeps its own).
    pub position_p_gain: Option<u16>,
    /// How far the horn lags its goal, ms (`marionette identify` measures it); the look-ahead
    /// leads the servo by it. `None`: not identified (no lead).
    pub lag_ms: Option<f64>,
    /// The servo's supply, volts (the model's recommended one unless given): its no-load speed
    /// and stall torque scale with it ([`ServoModel::voltage_factor`]).
    pub supply_v: f64,
    /// The servo's Homing Offset, ticks (Present Position = the horn's + it), written at
    /// start-up when given; `zero` is in the offset's frame. `None`: the servo's own, expected 0.
    pub homing_offset: Option<i32>,
    /// Line of its `[[servo]]` entry.
    pub line: u32,
}

impl ServoSpec {
    /// The software limits in ticks, `(lowest, highest)`: the joint limits through direction,
    /// zero and gear, rounded inwards.
    #[must_use]
    pub fn tick_limits(&self) -> (i32, i32) {
        let m = self.map(JointSource::Joint(0));
        (m.min_tick, m.max_tick)
    }

    /// The core's view of this servo, with the source resolved by the caller.
    #[must_use]
    pub fn map(&self, source: JointSource) -> ServoMap {
        let mut m = ServoMap {
            id: self.id,
            model: self.model,
            source,
            direction: self.direction,
            zero_tick: self.zero,
            gear: self.gear,
            min_tick: 0,
            max_tick: 0,
            max_velocity: 0.0,
            max_acceleration: 0.0,
        };
        let a = m.angle_to_ticks_exact(self.min_deg.to_radians());
        let b = m.angle_to_ticks_exact(self.max_deg.to_radians());
        m.min_tick = libm::ceil(a.min(b)) as i32;
        m.max_tick = libm::floor(a.max(b)) as i32;
        let per_rad = m.ticks_per_radian().abs();
        m.max_velocity = self.max_velocity_dps.to_radians() * per_rad;
        m.max_acceleration = self.max_acceleration_dps2.to_radians() * per_rad;
        m
    }
}

/// A loaded, validated profile.
#[derive(Clone, Debug, PartialEq)]
pub struct Profile {
    /// The file it came from.
    pub path: PathBuf,
    /// The rig's name.
    pub name: String,
    /// How the rig stands with every joint at 0°, in words (`[rig] reference_pose`), for
    /// `marionette calibrate` to ask for; `None`: described from the servos' drives.
    pub reference_pose: Option<String>,
    /// The bus.
    pub bus: BusConfig,
    /// Bones whose servos follow another axis order than the ASF DOFs: name, order, line.
    pub bone_orders: Vec<(String, EulerOrder, u32)>,
    /// The servos in file order.
    pub servos: Vec<ServoSpec>,
    /// How a human drives the robot joints (`[retarget]`), when given.
    pub retarget: Option<RetargetSpec>,
}

/// What the bus layer needs of a profile: the bus section and the servos on it.
#[derive(Clone, Copy, Debug)]
pub struct BusSection<'a> {
    /// The bus.
    pub config: &'a BusConfig,
    /// The servos in file order.
    pub servos: &'a [ServoSpec],
}

impl BusSection<'_> {
    /// Servo ids in bus order.
    #[must_use]
    pub fn ids(&self) -> Vec<u8> {
        self.servos.iter().map(|s| s.id).collect()
    }
}

/// A name in a profile and where it was written (1-based line and column).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Named {
    /// The name.
    pub name: String,
    /// Line.
    pub line: u32,
    /// Column.
    pub column: u32,
}

/// A point of a robot chain: one of the model's sites, or a position in the chain's last body.
#[derive(Clone, Debug, PartialEq)]
pub enum PointSpec {
    /// A site of the model, by name (it must be fixed in the chain's last body).
    Site(Named),
    /// A position in the chain's last body, metres.
    At([f64; 3]),
}

#[derive(Deserialize)]
#[serde(untagged)]
enum RawPoint {
    Site(String),
    At(Vec<f64>),
}

/// One chain of a retarget map (`[retarget.left_arm]` …), checked for shape.
#[derive(Clone, Debug, PartialEq)]
pub struct ChainSpec {
    /// Human bones, in the order the chain wants them.
    pub human: Vec<Named>,
    /// Robot joints, from the base outwards.
    pub robot: Vec<Named>,
    /// Arms: the hand point in the elbow's body.
    pub tip: PointSpec,
    /// Legs: the sole's centre in the last ankle joint's body.
    pub sole_centre: PointSpec,
    /// Legs: the sole's half length and half width, metres.
    pub sole_half_size: [f64; 2],
    /// Scale override (robot / human length).
    pub scale: Option<f64>,
    /// Line of the table's header.
    pub line: u32,
}

/// The retarget map (`[retarget]`): the robot's model and which human bones drive which of
/// its chains. Names are resolved against the model and the skeleton by
/// [`crate::retarget::Setup::new`], with errors at the line and column written here.
#[derive(Clone, Debug, PartialEq)]
pub struct RetargetSpec {
    /// The MJCF model, resolved against the profile's folder.
    pub model: PathBuf,
    /// Where `model` was written.
    pub model_at: (u32, u32),
    /// The robot's pelvis body.
    pub base: Named,
    /// The human pelvis bone (`None`: the skeleton's root).
    pub pelvis: Option<Named>,
    /// Names of bones in skeletons that name them otherwise: the map's name → the skeleton's.
    pub names: Vec<(String, Named)>,
    /// Leg scale override.
    pub leg_scale: Option<f64>,
    /// Arms, left then right.
    pub arms: [Option<ChainSpec>; 2],
    /// Legs, left then right.
    pub legs: [ChainSpec; 2],
    /// Pan/tilt head.
    pub head: Option<ChainSpec>,
    /// Line of `[retarget]`.
    pub line: u32,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawProfile {
    rig: RawRig,
    bus: Spanned<RawBus>,
    #[serde(default)]
    bone: Vec<Spanned<RawBone>>,
    #[serde(default)]
    servo: Vec<Spanned<RawServo>>,
    #[serde(default)]
    retarget: Option<Spanned<RawRetarget>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawRetarget {
    model: Spanned<String>,
    base: Spanned<String>,
    #[serde(default)]
    pelvis: Option<Spanned<String>>,
    #[serde(default)]
    leg_scale: Option<Spanned<f64>>,
    #[serde(default)]
    names: Option<std::collections::BTreeMap<String, Spanned<String>>>,
    #[serde(default)]
    left_arm: Option<Spanned<RawChain>>,
    #[serde(default)]
    right_arm: Option<Spanned<RawChain>>,
    #[serde(default)]
    left_leg: Option<Spanned<RawChain>>,
    #[serde(default)]
    right_leg: Option<Spanned<RawChain>>,
    #[serde(default)]
    head: Option<Spanned<RawChain>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawChain {
    human: Spanned<Vec<Spanned<String>>>,
    robot: Spanned<Vec<Spanned<String>>>,
    #[serde(default)]
    tip: Option<Spanned<RawPoint>>,
    #[serde(default)]
    sole_centre: Option<Spanned<RawPoint>>,
    #[serde(default)]
    sole_half_size: Option<Spanned<Vec<f64>>>,
    #[serde(default)]
    scale: Option<Spanned<f64>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawRig {
    name: String,
    #[serde(default)]
    #[allow(dead_code)]
    description: Option<String>,
    #[serde(default)]
    reference_pose: Option<String>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawBus {
    baud: Spanned<i64>,
    #[serde(default)]
    protocol: Option<Spanned<f64>>,
    #[serde(default)]
    return_delay_us: Option<Spanned<i64>>,
    #[serde(default)]
    read: Option<Spanned<String>>,
    #[serde(default)]
    read_fields: Option<Spanned<Vec<String>>>,
    #[serde(default)]
    usb_latency_us: Option<Spanned<i64>>,
    #[serde(default)]
    watchdog_ms: Option<Spanned<i64>>,
    #[serde(default)]
    pipeline: Option<bool>,
    #[serde(default)]
    imu_board_id: Option<Spanned<i64>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawBone {
    name: Spanned<String>,
    order: Spanned<String>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawServo {
    id: Spanned<i64>,
    name: Spanned<String>,
    model: Spanned<String>,
    #[serde(default)]
    bone: Option<Spanned<String>>,
    #[serde(default)]
    joint: Option<Spanned<String>>,
    #[serde(default)]
    direction: Option<Spanned<i64>>,
    #[serde(default)]
    zero: Option<Spanned<f64>>,
    #[serde(default)]
    gear: Option<Spanned<f64>>,
    min_deg: Spanned<f64>,
    max_deg: Spanned<f64>,
    max_velocity_dps: Spanned<f64>,
    max_acceleration_dps2: Spanned<f64>,
    #[serde(default)]
    position_p_gain: Option<Spanned<i64>>,
    #[serde(default)]
    lag_ms: Option<Spanned<f64>>,
    #[serde(default)]
    supply_v: Option<Spanned<f64>>,
    #[serde(default)]
    homing_offset: Option<Spanned<i64>>,
}

/// Line and column (1-based) of a byte offset.
fn line_col(text: &str, offset: usize) -> (u32, u32) {
    let offset = offset.min(text.len());
    let before = &text.as_bytes()[..offset];
    let line = before.iter().filter(|&&b| b == b'\n').count() + 1;
    let col = offset - before.iter().rposition(|&b| b == b'\n').map_or(0, |p| p + 1) + 1;
    (line as u32, col as u32)
}

struct Checker<'t> {
    text: &'t str,
}

impl Checker<'_> {
    fn at<T>(&self, s: &Spanned<T>, message: impl Into<String>) -> TextError {
        let (l, c) = line_col(self.text, s.span().start);
        TextError::new(l, c, message)
    }

    fn line<T>(&self, s: &Spanned<T>) -> u32 {
        line_col(self.text, s.span().start).0
    }

    fn named(&self, s: &Spanned<String>) -> Named {
        let (line, column) = line_col(self.text, s.span().start);
        Named {
            name: s.get_ref().trim().to_string(),
            line,
            column,
        }
    }
}

/// The shape each chain of a retarget map must have: human bones, robot joints.
const CHAIN_SHAPES: [(&str, usize, usize, &str, &str); 3] = [
    ("arm", 2, 3, "[upper arm, forearm]", "[shoulder, shoulder, elbow]"),
    (
        "leg",
        3,
        6,
        "[thigh, shin, foot]",
        "[hip, hip, hip, knee, ankle, ankle]",
    ),
    ("head", 1, 2, "[head]", "[pan, tilt]"),
];

fn check_retarget(
    ck: &Checker<'_>,
    raw: &Spanned<RawRetarget>,
    path: &Path,
) -> Result<RetargetSpec, TextError> {
    let r = raw.get_ref();
    let model_text = r.model.get_ref().trim();
    if model_text.is_empty() {
        return Err(ck.at(&r.model, "expected the path of the robot's MJCF model"));
    }
    let model = path.parent().unwrap_or(Path::new(".")).join(model_text);
    let chain = |c: &Option<Spanned<RawChain>>,
                 key: &str,
                 kind: usize|
     -> Result<Option<ChainSpec>, TextError> {
        let Some(c) = c else { return Ok(None) };
        let (what, nh, nr, hdesc, rdesc) = CHAIN_SHAPES[kind];
        let raw_c = c.get_ref();
        if raw_c.human.get_ref().len() != nh {
            return Err(ck.at(
                &raw_c.human,
                format!(
                    "expected {nh} human bone(s) for a{} {what}: {hdesc}",
                    if what == "arm" { "n" } else { "" }
                ),
            ));
        }
        if raw_c.robot.get_ref().len() != nr {
            return Err(ck.at(
                &raw_c.robot,
                format!("expected {nr} robot joints for the {what}: {rdesc}"),
            ));
        }
        let vector = |v: &Option<Spanned<Vec<f64>>>,
                      n: usize,
                      name: &str,
                      needed: bool|
         -> Result<Vec<f64>, TextError> {
            match v {
                None if needed => Err(ck.at(
                    c,
                    format!("[retarget.{key}] needs `{name}` ({n} numbers, metres)"),
                )),
                None => Ok(vec![0.0; n]),
                Some(v) if v.get_ref().len() == n && v.get_ref().iter().all(|x| x.is_finite()) => {
                    Ok(v.get_ref().clone())
                }
                Some(v) => Err(ck.at(v, format!("expected {n} finite numbers (metres)"))),
            }
        };
        let point =
            |v: &Option<Spanned<RawPoint>>, name: &str, needed: bool| -> Result<PointSpec, TextError> {
                match v {
                    None if needed => Err(ck.at(
                        c,
                        format!("[retarget.{key}] needs `{name}`: a site of the model or [x, y, z] metres"),
                    )),
                    None => Ok(PointSpec::At([0.0; 3])),
                    Some(p) => match p.get_ref() {
                        RawPoint::Site(site) if !site.trim().is_empty() => {
                            let (line, column) = line_col(ck.text, p.span().start);
                            Ok(PointSpec::Site(Named {
                                name: site.trim().to_string(),
                                line,
                                column,
                            }))
                        }
                        RawPoint::At(v) if v.len() == 3 && v.iter().all(|x| x.is_finite()) => {
                            Ok(PointSpec::At([v[0], v[1], v[2]]))
                        }
                        _ => Err(ck.at(p, "expected a site's name or 3 finite numbers (metres)")),
                    },
                }
            };
        let tip = point(&raw_c.tip, "tip", kind == 0)?;
        let sole_centre = point(&raw_c.sole_centre, "sole_centre", kind == 1)?;
        let sole_half_size = vector(&raw_c.sole_half_size, 2, "sole_half_size", kind == 1)?;
        if kind == 1 && sole_half_size.iter().any(|x| *x <= 0.0) {
            let at = raw_c.sole_half_size.as_ref().map_or(ck.line(c), |v| ck.line(v));
            return Err(TextError::new(
                at,
                0,
                "expected a positive half length and half width",
            ));
        }
        let scale = match &raw_c.scale {
            None => None,
            Some(v) if v.get_ref().is_finite() && *v.get_ref() > 0.0 => Some(*v.get_ref()),
            Some(v) => return Err(ck.at(v, format!("expected a positive scale, found {}", v.get_ref()))),
        };
        Ok(Some(ChainSpec {
            human: raw_c.human.get_ref().iter().map(|n| ck.named(n)).collect(),
            robot: raw_c.robot.get_ref().iter().map(|n| ck.named(n)).collect(),
            tip,
            sole_centre,
            sole_half_size: [sole_half_size[0], sole_half_size[1]],
            scale,
            line: ck.line(c),
        }))
    };
    let leg = |c: &Option<Spanned<RawChain>>, key: &str| -> Result<ChainSpec, TextError> {
        chain(c, key, 1)?.ok_or_else(|| ck.at(raw, format!("[retarget] needs a [retarget.{key}] table")))
    };
    let leg_scale = match &r.leg_scale {
        None => None,
        Some(v) if v.get_ref().is_finite() && *v.get_ref() > 0.0 => Some(*v.get_ref()),
        Some(v) => return Err(ck.at(v, format!("expected a positive scale, found {}", v.get_ref()))),
    };
    let names = r
        .names
        .iter()
        .flatten()
        .map(|(k, v)| (k.clone(), ck.named(v)))
        .collect();
    Ok(RetargetSpec {
        model,
        model_at: line_col(ck.text, r.model.span().start),
        base: ck.named(&r.base),
        pelvis: r.pelvis.as_ref().map(|p| ck.named(p)),
        names,
        leg_scale,
        arms: [
            chain(&r.left_arm, "left_arm", 0)?,
            chain(&r.right_arm, "right_arm", 0)?,
        ],
        legs: [leg(&r.left_leg, "left_leg")?, leg(&r.right_leg, "right_leg")?],
        head: chain(&r.head, "head", 2)?,
        line: ck.line(raw),
    })
}

impl Profile {
    /// Reads and validates a profile file.
    ///
    /// # Errors
    /// [`FileError`]: unreadable file, TOML syntax, unknown or missing keys, or a value that
    /// fails validation, with the line and what was expected.
    pub fn load(path: &Path) -> Result<Profile, FileError> {
        let text = read_text(path)?;
        Profile::parse(&text, path).map_err(|e| FileError::parse(path, e))
    }

    /// Parses and validates profile text; `path` is recorded as its origin.
    ///
    /// # Errors
    /// [`TextError`] with the line of the offending entry.
    pub fn parse(text: &str, path: &Path) -> Result<Profile, TextError> {
        let raw: RawProfile = toml::from_str(text).map_err(|e| {
            let (l, c) = e.span().map_or((1, 0), |s| line_col(text, s.start));
            let message = e.message().trim();
            let message = match message.strip_prefix("missing field ") {
                Some(field) => format!("expected {field} here, found none"),
                None => message.to_string(),
            };
            TextError::new(l, c, message)
        })?;
        let ck = Checker { text };
        let bus = check_bus(&ck, &raw.bus)?;
        let mut bone_orders = Vec::new();
        for b in &raw.bone {
            let order = EulerOrder::parse(b.get_ref().order.get_ref()).ok_or_else(|| {
                ck.at(
                    &b.get_ref().order,
                    "expected an Euler order such as \"XYZ\" or \"ZXZ\"",
                )
            })?;
            let name = b.get_ref().name.get_ref().clone();
            if bone_orders
                .iter()
                .any(|(n, _, _): &(String, EulerOrder, u32)| *n == name)
            {
                return Err(ck.at(&b.get_ref().name, format!("bone `{name}` is listed twice")));
            }
            bone_orders.push((name, order, ck.line(b)));
        }
        if raw.servo.is_empty() {
            return Err(TextError::new(
                crate::formats::last_line(text),
                0,
                "expected [[servo]] entries, found none",
            ));
        }
        if raw.servo.len() > MAX_SERVOS {
            return Err(ck.at(&raw.servo[MAX_SERVOS], format!("more than {MAX_SERVOS} servos")));
        }
        let mut servos: Vec<ServoSpec> = Vec::new();
        let mut ids: HashMap<u8, u32> = HashMap::new();
        let mut names: HashMap<String, u32> = HashMap::new();
        let mut drives: HashMap<String, u32> = HashMap::new();
        for s in &raw.servo {
            let spec = check_servo(&ck, s)?;
            if spec.model.max_baud < bus.baud {
                return Err(ck.at(
                    &s.get_ref().model,
                    format!(
                        "{} runs at most {} bit/s, the bus is set to {}",
                        spec.model.name, spec.model.max_baud, bus.baud
                    ),
                ));
            }
            if bus.imu_board == Some(spec.id) {
                return Err(ck.at(
                    &s.get_ref().id,
                    format!("id {} is the IMU board's (imu_board_id in [bus])", spec.id),
                ));
            }
            if let Some(first) = ids.insert(spec.id, spec.line) {
                return Err(ck.at(
                    &s.get_ref().id,
                    format!("duplicate id {} (first used on line {first})", spec.id),
                ));
            }
            if let Some(first) = names.insert(spec.name.clone(), spec.line) {
                return Err(ck.at(
                    &s.get_ref().name,
                    format!("duplicate servo name `{}` (line {first})", spec.name),
                ));
            }
            let key = match &spec.drive {
                Drive::Bone { bone, dof } => format!("{bone}.{}", dof.name()),
                Drive::Joint(j) => format!("joint {j}"),
            };
            if let Some(first) = drives.insert(key.clone(), spec.line) {
                let at = s
                    .get_ref()
                    .bone
                    .as_ref()
                    .or(s.get_ref().joint.as_ref())
                    .map_or(ck.line(s), |x| ck.line(x));
                return Err(TextError::new(
                    at,
                    0,
                    format!("`{key}` already drives the servo on line {first}"),
                ));
            }
            servos.push(spec);
        }
        let retarget = match &raw.retarget {
            Some(r) => Some(check_retarget(&ck, r, path)?),
            None => None,
        };
        Ok(Profile {
            path: path.to_path_buf(),
            name: raw.rig.name,
            reference_pose: raw.rig.reference_pose,
            bus,
            bone_orders,
            servos,
            retarget,
        })
    }

    /// Names of the robot joints the profile drives, in servo order (the layout of the joint
    /// vector passed to [`Rig::joint_angles`]).
    #[must_use]
    pub fn joint_names(&self) -> Vec<&str> {
        self.servos
            .iter()
            .filter_map(|s| match &s.drive {
                Drive::Joint(j) => Some(j.as_str()),
                Drive::Bone { .. } => None,
            })
            .collect()
    }

    /// Servo ids in bus order.
    #[must_use]
    pub fn ids(&self) -> Vec<u8> {
        self.servos.iter().map(|s| s.id).collect()
    }

    /// The bus section and its servos, for the bus layer.
    #[must_use]
    pub fn bus_section(&self) -> BusSection<'_> {
        BusSection {
            config: &self.bus,
            servos: &self.servos,
        }
    }

    /// Resolves bone DOFs against a skeleton and builds the core's rig.
    ///
    /// # Errors
    /// [`FileError`] at the servo's line: an unknown bone, a DOF the bone lacks, a bone drive
    /// without a skeleton, a `[[bone]]` entry naming an unknown bone.
    pub fn rig(&self, skeleton: Option<&Skeleton>) -> Result<Rig, FileError> {
        let err = |line: u32, msg: String| FileError::parse(&self.path, TextError::new(line, 0, msg));
        for (name, _, line) in &self.bone_orders {
            if let Some(sk) = skeleton {
                if sk.find(name).is_none() {
                    return Err(err(
                        *line,
                        format!(
                            "unknown bone `{name}` in [[bone]]; the skeleton has: {}",
                            sk.bone_names()
                        ),
                    ));
                }
            }
        }
        let joints = self.joint_names();
        let mut rig = Rig::default();
        for s in &self.servos {
            let source = match &s.drive {
                Drive::Joint(j) => JointSource::Joint(joints.iter().position(|n| n == j).unwrap_or(0)),
                Drive::Bone { bone, dof } => {
                    let Some(sk) = skeleton else {
                        return Err(err(
                            s.line,
                            format!(
                                "servo `{}` follows bone `{bone}`: an ASF skeleton is needed",
                                s.name
                            ),
                        ));
                    };
                    let Some(b) = sk.find(bone) else {
                        return Err(err(
                            s.line,
                            format!("unknown bone `{bone}`; the skeleton has: {}", sk.bone_names()),
                        ));
                    };
                    let bone_ref = &sk.bones()[b];
                    let order = self
                        .bone_orders
                        .iter()
                        .find(|(n, _, _)| n == bone)
                        .map(|(_, o, _)| *o);
                    match order {
                        Some(order) => {
                            let axis = dof.axis().filter(|_| dof.is_rotation());
                            let slot = order.axes().iter().position(|a| Some(*a) == axis);
                            let Some(slot) = slot.filter(|_| !order.is_proper()) else {
                                return Err(err(
                                    s.line,
                                    format!(
                                        "`{bone}.{}` is not one of the three axes of the rig order {}",
                                        dof.name(),
                                        order.name()
                                    ),
                                ));
                            };
                            JointSource::Redecomposed { bone: b, order, slot }
                        }
                        None => {
                            let Some(k) = bone_ref.dofs().iter().position(|d| d == dof) else {
                                let has: Vec<&str> = bone_ref.dofs().iter().map(|d| d.name()).collect();
                                return Err(err(
                                    s.line,
                                    format!(
                                        "bone `{bone}` has no DOF `{}`; it has: {}",
                                        dof.name(),
                                        has.join(" ")
                                    ),
                                ));
                            };
                            if !dof.is_rotation() {
                                return Err(err(
                                    s.line,
                                    format!("`{bone}.{}` is not a rotation", dof.name()),
                                ));
                            }
                            JointSource::Channel(bone_ref.first_channel() + k)
                        }
                    }
                }
            };
            // Capacity was checked on load.
            let _ = rig.servos.push(s.map(source));
        }
        Ok(rig)
    }
}

fn check_bus(ck: &Checker<'_>, raw: &Spanned<RawBus>) -> Result<BusConfig, TextError> {
    let b = raw.get_ref();
    let baud = *b.baud.get_ref();
    let Some(baud) = u32::try_from(baud).ok().filter(|v| DYNAMIXEL_BAUDS.contains(v)) else {
        return Err(ck.at(
            &b.baud,
            format!("expected a Dynamixel baud rate, one of {DYNAMIXEL_BAUDS:?}, found {baud}"),
        ));
    };
    if let Some(p) = &b.protocol {
        if *p.get_ref() != 2.0 {
            return Err(ck.at(p, "only Dynamixel Protocol 2.0 is supported (protocol = 2.0)"));
        }
    }
    let return_delay_us = match &b.return_delay_us {
        None => 0,
        Some(v) => {
            let x = *v.get_ref();
            if !(0..=508).contains(&x) || x % 2 != 0 {
                return Err(ck.at(v, format!("expected an even number of µs in 0…508, found {x}")));
            }
            x as u32
        }
    };
    let read = match b.read.as_ref().map(|r| (r, r.get_ref().as_str())) {
        None | Some((_, "sync")) => ReadMode::Sync,
        Some((_, "bulk")) => ReadMode::Bulk,
        Some((_, "fast-sync")) => ReadMode::FastSync,
        Some((_, "fast-bulk")) => ReadMode::FastBulk,
        Some((r, other)) => {
            return Err(ck.at(
                r,
                format!(
                    "expected read = \"sync\", \"bulk\", \"fast-sync\" or \"fast-bulk\", found \"{other}\""
                ),
            ))
        }
    };
    let mut read_fields = ReadFields::default();
    if let Some(fields) = &b.read_fields {
        for f in fields.get_ref() {
            match f.as_str() {
                "position" => {}
                "velocity" => read_fields.velocity = true,
                "current" => read_fields.current = true,
                other => {
                    return Err(ck.at(
                        fields,
                        format!("expected read fields among position, velocity, current; found `{other}`"),
                    ))
                }
            }
        }
    }
    let usb_latency_us = match &b.usb_latency_us {
        None => 1000,
        Some(v) => u32::try_from(*v.get_ref())
            .ok()
            .filter(|x| *x <= 255_000)
            .ok_or_else(|| ck.at(v, "expected a latency in µs, 0…255000"))?,
    };
    let watchdog_ms = match &b.watchdog_ms {
        None => 100,
        Some(v) => {
            let x = *v.get_ref();
            if x != 0 && !(20..=2540).contains(&x) {
                return Err(ck.at(
                    v,
                    format!("expected 0 (off) or 20…2540 ms (20 ms steps), found {x}"),
                ));
            }
            x as u32
        }
    };
    let imu_board = match &b.imu_board_id {
        None => None,
        Some(v) => Some(
            u8::try_from(*v.get_ref())
                .ok()
                .filter(|i| *i <= 252)
                .ok_or_else(|| {
                    ck.at(
                        v,
                        format!("expected the IMU board's id in 0…252, found {}", v.get_ref()),
                    )
                })?,
        ),
    };
    Ok(BusConfig {
        baud,
        return_delay_us,
        read,
        read_fields,
        usb_latency_us,
        watchdog_ms,
        pipeline: b.pipeline.unwrap_or(true),
        imu_board,
    })
}

fn check_servo(ck: &Checker<'_>, raw: &Spanned<RawServo>) -> Result<ServoSpec, TextError> {
    let s = raw.get_ref();
    let id = *s.id.get_ref();
    let Some(id) = u8::try_from(id).ok().filter(|i| *i <= 252) else {
        return Err(ck.at(&s.id, format!("expected an id in 0…252, found {id}")));
    };
    let name = s.name.get_ref().trim().to_string();
    if name.is_empty() {
        return Err(ck.at(&s.name, "expected a non-empty servo name"));
    }
    let model = servo::model_by_name(s.model.get_ref()).ok_or_else(|| {
        let known: Vec<&str> = servo::MODELS.iter().map(|m| m.name).collect();
        ck.at(
            &s.model,
            format!(
                "unknown servo model `{}`; known: {}",
                s.model.get_ref(),
                known.join(", ")
            ),
        )
    })?;
    let drive = match (&s.bone, &s.joint) {
        (Some(b), None) => {
            let (bone, dof) = b
                .get_ref()
                .rsplit_once('.')
                .and_then(|(bone, d)| Some((bone, Dof::parse(d)?)))
                .filter(|(bone, d)| !bone.is_empty() && d.is_rotation())
                .ok_or_else(|| {
                    ck.at(
                        b,
                        format!(
                            "expected `bone.rx|ry|rz` such as `lhumerus.rz`, found `{}`",
                            b.get_ref()
                        ),
                    )
                })?;
            Drive::Bone {
                bone: bone.to_string(),
                dof,
            }
        }
        (None, Some(j)) if !j.get_ref().trim().is_empty() => Drive::Joint(j.get_ref().trim().to_string()),
        (Some(_), Some(j)) => return Err(ck.at(j, "give either `bone` or `joint`, not both")),
        _ => {
            return Err(ck.at(
                raw,
                format!("servo `{name}` needs `bone = \"<bone>.<dof>\"` or `joint = \"<name>\"`"),
            ))
        }
    };
    let direction = match &s.direction {
        None => 1.0,
        Some(d) if *d.get_ref() == 1 || *d.get_ref() == -1 => *d.get_ref() as f64,
        Some(d) => return Err(ck.at(d, format!("expected direction 1 or -1, found {}", d.get_ref()))),
    };
    let zero = match &s.zero {
        None => 2048.0,
        Some(z) if (0.0..=f64::from(MAX_TICK)).contains(z.get_ref()) => *z.get_ref(),
        Some(z) => {
            return Err(ck.at(
                z,
                format!("expected a zero tick in 0…{MAX_TICK}, found {}", z.get_ref()),
            ))
        }
    };
    let gear = match &s.gear {
        None => 1.0,
        Some(g) if g.get_ref().is_finite() && *g.get_ref() > 0.0 && *g.get_ref() <= 100.0 => *g.get_ref(),
        Some(g) => {
            return Err(ck.at(
                g,
                format!("expected a gear ratio in (0, 100], found {}", g.get_ref()),
            ))
        }
    };
    let (lo, hi) = (*s.min_deg.get_ref(), *s.max_deg.get_ref());
    if !lo.is_finite() {
        return Err(ck.at(&s.min_deg, "expected a finite angle"));
    }
    if !hi.is_finite() || hi <= lo {
        return Err(ck.at(
            &s.max_deg,
            format!("expected max_deg > min_deg ({lo}), found {hi}"),
        ));
    }
    for (v, what) in [
        (&s.max_velocity_dps, "velocity"),
        (&s.max_acceleration_dps2, "acceleration"),
    ] {
        let x = *v.get_ref();
        if !(x.is_finite() && x > 0.0) {
            return Err(ck.at(v, format!("expected a positive max {what}, found {x}")));
        }
    }
    let position_p_gain = match &s.position_p_gain {
        None => None,
        Some(g) => match u16::try_from(*g.get_ref()) {
            Ok(v) if v <= 16383 => Some(v),
            _ => {
                return Err(ck.at(
                    g,
                    format!("expected a Position P Gain in 0…16383, found {}", g.get_ref()),
                ))
            }
        },
    };
    let lag_ms = match &s.lag_ms {
        None => None,
        Some(l) => {
            let v = *l.get_ref();
            if !(v.is_finite() && (0.0..=1000.0).contains(&v)) {
                return Err(ck.at(l, format!("expected a lag in 0…1000 ms, found {v}")));
            }
            Some(v)
        }
    };
    let supply_v = match &s.supply_v {
        None => model.rated_v,
        Some(v) => {
            let x = *v.get_ref();
            if !(x.is_finite() && (model.min_v..=model.max_v).contains(&x)) {
                return Err(ck.at(
                    v,
                    format!(
                        "expected a supply of {}…{} V for the {}, found {x}",
                        model.min_v, model.max_v, model.name
                    ),
                ));
            }
            x
        }
    };
    let homing_offset = match &s.homing_offset {
        None => None,
        Some(h) => match i32::try_from(*h.get_ref()) {
            Ok(v) if (-HOMING_OFFSET_MAX..=HOMING_OFFSET_MAX).contains(&v) => Some(v),
            _ => {
                return Err(ck.at(
                    h,
                    format!(
                    "expected a Homing Offset in -{HOMING_OFFSET_MAX}…{HOMING_OFFSET_MAX} ticks, found {}",
                    h.get_ref()
                ),
                ))
            }
        },
    };
    let spec = ServoSpec {
        id,
        name,
        model,
        drive,
        direction,
        zero,
        gear,
        min_deg: lo,
        max_deg: hi,
        max_velocity_dps: *s.max_velocity_dps.get_ref(),
        max_acceleration_dps2: *s.max_acceleration_dps2.get_ref(),
        position_p_gain,
        lag_ms,
        supply_v,
        homing_offset,
        line: ck.line(raw),
    };
    // The software limits must map inside the servo's own range.
    let probe = spec.map(JointSource::Joint(0));
    for (v, deg) in [(&s.min_deg, lo), (&s.max_deg, hi)] {
        let t = probe.angle_to_ticks_exact(deg.to_radians());
        if !(0.0..=f64::from(MAX_TICK)).contains(&t) {
            return Err(ck.at(
                v,
                format!("limit {deg}° maps to tick {t:.0}, outside the servo's range 0…{MAX_TICK} (zero {zero}, gear {gear})"),
            ));
        }
    }
    let top = model.max_speed_rad_s_at(supply_v).to_degrees() / gear;
    if spec.max_velocity_dps > top {
        return Err(ck.at(
            &s.max_velocity_dps,
            format!(
                "{} reaches at most {top:.0} joint °/s at gear {gear} and {supply_v} V, found {}",
                model.name, spec.max_velocity_dps
            ),
        ));
    }
    Ok(spec)
}

/// The largest Homing Offset an X-series servo takes (e-manual: ±1,044,479 ticks, ±255 turns).
pub const HOMING_OFFSET_MAX: i32 = 1_044_479;

/// The profile text with `lag_ms = …` set in the `[[servo]]` entries named in `lags`: an
/// existing `lag_ms` line is replaced, otherwise one is added at the end of the entry.
/// Everything else — comments, order, layout — stays as it was.
#[must_use]
pub fn set_servo_lags(text: &str, lags: &[(String, f64)]) -> String {
    let keys: Vec<(String, Vec<(&str, String)>)> = lags
        .iter()
        .map(|(name, lag)| (name.clone(), vec![("lag_ms", lag.to_string())]))
        .collect();
    set_servo_keys(text, &keys)
}

/// The profile text with keys set in the `[[servo]]` entries named in `values` (each a servo's
/// name and its `(key, value as TOML)` pairs): an existing line of the key is replaced (its
/// trailing comment kept), otherwise one is added at the end of the entry. Everything else —
/// comments, order, layout — stays as it was.
#[must_use]
pub fn set_servo_keys(text: &str, values: &[(String, Vec<(&str, String)>)]) -> String {
    let lines: Vec<&str> = text.lines().collect();
    let mut out: Vec<String> = Vec::with_capacity(lines.len() + values.len());
    let mut i = 0;
    while i < lines.len() {
        let line = lines[i];
        out.push(line.to_string());
        i += 1;
        if line.trim() != "[[servo]]" {
            continue;
        }
        // The entry runs to the next table header.
        let start = out.len();
        while i < lines.len() && !lines[i].trim_start().starts_with('[') {
            out.push(lines[i].to_string());
            i += 1;
        }
        let key = |l: &str| {
            l.split('=')
                .next()
                .map(|k| k.trim().to_string())
                .unwrap_or_default()
        };
        let name = out[start..]
            .iter()
            .find(|l| key(l) == "name")
            .and_then(|l| l.split('=').nth(1))
            .map(|v| {
                v.split('#')
                    .next()
                    .unwrap_or("")
                    .trim()
                    .trim_matches('"')
                    .to_string()
            });
        let Some(pairs) = name
            .and_then(|n| values.iter().find(|(m, _)| *m == n))
            .map(|(_, p)| p)
        else {
            continue;
        };
        for (k, v) in pairs {
            let entry = format!("{k} = {v}");
            if let Some(l) = out[start..].iter_mut().find(|l| key(l) == *k) {
                // Keep the line's comment, aligned where it was when it fits.
                *l = match l.find('#') {
                    Some(at) if !l[..at].contains('"') || l[..at].matches('"').count() % 2 == 0 => {
                        let width = at.max(entry.len() + 1);
                        format!("{entry:<width$}{}", &l[at..])
                    }
                    _ => entry,
                };
            } else {
                // After the entry's last key, before its trailing blank lines and comments.
                let last = (start..out.len())
                    .rev()
                    .find(|&k| {
                        let t = out[k].trim();
                        !t.is_empty() && !t.starts_with('#')
                    })
                    .map_or(start, |k| k + 1);
                out.insert(last, entry);
            }
        }
    }
    let mut s = out.join("\n");
    if text.ends_with('\n') {
        s.push('\n');
    }
    s
}
