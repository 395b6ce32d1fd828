//! ROS 2 over DDS (the `ros2` feature): the rig's joint states out, effector targets in, with
//! no ROS installation (`ros2-client` over RustDDS, pure Rust).
//!
//! * **Out**: `sensor_msgs/msg/JointState` on `/joint_states` (DDS topic `rt/joint_states`,
//!   type `sensor_msgs::msg::dds_::JointState_`), reliable, keep-last 10, volatile — what
//!   robot_state_publisher subscribes with. Names are the profile's servo names, positions the
//!   present positions of the last valid read in radians (the rig's joint angles), velocities
//!   the change of those positions over the publish interval, the stamp the wall-clock time
//!   of that read. A thread of its own publishes at its own rate: the loop hands each tick's
//!   record to it through a bounded channel without waiting ([`crate::control::Telemetry`]),
//!   and the thread polls that channel, so no tick blocks on the network, wakes a thread or
//!   allocates. The last record of the run (after the ramp to rest) is always published.
//! * **In**: one topic per effector, `/marionette/targets/<effector>`, of
//!   `geometry_msgs/msg/PointStamped` or `PoseStamped` ([`TargetKind`]), best effort or
//!   reliable (the subscription accepts both). Positions are metres on the rig in the root's
//!   frame (`header.frame_id` empty or the root bone's name; anything else is refused: there is
//!   no tf here); a pose's orientation turns the root's +x into the pointing direction of the
//!   bone after the effector (hand, foot). Each message becomes a live input, due at once, the
//!   oldest dropped when the loop is behind — the rules of UDP lines: a non-finite number, an
//!   unknown frame or a zero quaternion is refused and counted, never sent to the loop.
//!
//! The domain is `ROS_DOMAIN_ID` (default 0; ROS 2's range 0–232), and
//! `ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST` (or the older `ROS_LOCALHOST_ONLY=1`) keeps
//! discovery and traffic on the loopback interface, as ROS 2 does.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crossbeam_channel::{Receiver, TryRecvError};
use futures::StreamExt;
use glam::{DQuat, DVec3};
use ros2_client::dds::rustdds::DomainParticipantBuilder;
use ros2_client::qos::{Durability, History, Reliability, WhenFull};
use ros2_client::{
    Context, MessageTypeName, Name, Node, NodeName, NodeOptions, Publisher, QosProfile, Subscription,
};

use crate::clock::SystemClock;
use crate::control::input::{Input, Payload, Target, MAX_EFFECTORS};
use crate::control::source::{Grid, Sink, Source};
use crate::control::sources::ProducerReport;
use crate::control::Telemetry;
use crate::rig::Rig;
use crate::schedule::Clock;

/// ROS 2 message types, as their IDL lays them out (field order is the wire order: CDR).
pub mod msg {
    use serde::{Deserialize, Serialize};

    /// `builtin_interfaces/msg/Time`.
    #[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
    pub struct Time {
        /// Seconds since the Unix epoch.
        pub sec: i32,
        /// Nanoseconds within the second.
        pub nanosec: u32,
    }

    impl Time {
        /// From nanoseconds since the Unix epoch.
        #[must_use]
        pub fn from_ns(ns: u64) -> Time {
            Time {
                sec: i32::try_from(ns / 1_000_000_000).unwrap_or(i32::MAX),
                nanosec: (ns % 1_000_000_000) as u32,
            }
        }

        /// Nanoseconds since the Unix epoch (negative times give 0).
        #[must_use]
        pub fn to_ns(self) -> u64 {
            u64::try_from(self.sec).unwrap_or(0) * 1_000_000_000 + u64::from(self.nanosec)
        }
    }

    /// `std_msgs/msg/Header`.
    #[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
    pub struct Header {
        /// When the data was measured.
        pub stamp: Time,
        /// The frame the data is in.
        pub frame_id: String,
    }

    /// `sensor_msgs/msg/JointState`.
    #[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
    pub struct JointState {
        /// Stamp: when the positions were read.
        pub header: Header,
        /// Joint names.
        pub name: Vec<String>,
        /// Radians.
        pub position: Vec<f64>,
        /// Radians per second.
        pub velocity: Vec<f64>,
        /// Newton metres (empty: not measured).
        pub effort: Vec<f64>,
    }

    /// `geometry_msgs/msg/Point`.
    #[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
    pub struct Point {
        /// x, metres.
        pub x: f64,
        /// y, metres.
        pub y: f64,
        /// z, metres.
        pub z: f64,
    }

    /// `geometry_msgs/msg/PointStamped`.
    #[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
    pub struct PointStamped {
        /// Stamp and frame.
        pub header: Header,
        /// The point.
        pub point: Point,
    }

    /// `geometry_msgs/msg/Quaternion` (x, y, z, w).
    #[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
    pub struct Quaternion {
        /// x.
        pub x: f64,
        /// y.
        pub y: f64,
        /// z.
        pub z: f64,
        /// w.
        pub w: f64,
    }

    /// `geometry_msgs/msg/Pose`.
    #[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
    pub struct Pose {
        /// Position, metres.
        pub position: Point,
        /// Orientation.
        pub orientation: Quaternion,
    }

    /// `geometry_msgs/msg/PoseStamped`.
    #[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
    pub struct PoseStamped {
        /// Stamp and frame.
        pub header: Header,
        /// The pose.
        pub pose: Pose,
    }
}

/// What went wrong setting ROS 2 up.
#[derive(Debug, thiserror::Error)]
pub enum Ros2Error {
    /// `ROS_DOMAIN_ID` is not a domain id.
    #[error("ROS_DOMAIN_ID='{0}': expected a whole number from 0 to 232")]
    DomainId(String),
    /// A name ROS 2 does not accept (a node, a topic from an effector's name).
    #[error("'{0}' is not a valid ROS 2 name")]
    Name(String),
    /// The DDS participant, a topic, a reader or a writer could not be made.
    #[error("DDS: {0}")]
    Dds(String),
    /// A thread could not be started.
    #[error("cannot start a thread: {0}")]
    Thread(#[from] std::io::Error),
}

/// The message type of the target topics.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum TargetKind {
    /// `geometry_msgs/msg/PointStamped`: a position.
    #[default]
    Point,
    /// `geometry_msgs/msg/PoseStamped`: a position and the direction of the next bone.
    Pose,
}

/// The domain id from `ROS_DOMAIN_ID` (unset or empty: 0), as ROS 2 reads it.
///
/// # Errors
/// [`Ros2Error::DomainId`] for anything but a number from 0 to 232.
pub fn domain_id_from_env() -> Result<u16, Ros2Error> {
    match std::env::var("ROS_DOMAIN_ID") {
        Err(_) => Ok(0),
        Ok(v) if v.trim().is_empty() => Ok(0),
        Ok(v) => match v.trim().parse::<u16>() {
            Ok(d) if d <= 232 => Ok(d),
            _ => Err(Ros2Error::DomainId(v)),
        },
    }
}

/// Whether the environment keeps ROS 2 on this host (`ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`,
/// or `ROS_LOCALHOST_ONLY=1` as before Iron).
#[must_use]
pub fn localhost_only_from_env() -> bool {
    std::env::var("ROS_AUTOMATIC_DISCOVERY_RANGE").is_ok_and(|v| v.trim().eq_ignore_ascii_case("LOCALHOST"))
        || std::env::var("ROS_LOCALHOST_ONLY").is_ok_and(|v| v.trim() == "1")
}

/// The QoS of `/joint_states`: reliable, keep last 10, volatile (rclcpp's default profile,
/// which robot_state_publisher and `ros2 topic echo` match).
#[must_use]
pub fn joint_states_qos() -> QosProfile {
    QosProfile::publisher_default()
        .history(History::KeepLast { depth: 10 })
        .reliability(Reliability::Reliable {
            when_full: WhenFull::Fail,
        })
        .durability(Durability::Volatile)
}

/// The QoS the target subscriptions ask for: best effort, keep last 1 (the newest target is
/// the one that counts; a best-effort reader matches reliable and best-effort writers alike).
#[must_use]
pub fn targets_qos() -> QosProfile {
    QosProfile::subscription_default()
        .history(History::KeepLast { depth: 1 })
        .reliability(Reliability::BestEffort)
        .durability(Durability::Volatile)
}

/// A ROS 2 node in the environment's domain: the DDS participant and the node `marionette`.
pub struct Ros2Node {
    // The node before the context: dropped first, it leaves the graph cleanly.
    node: Node,
    context: Context,
}

impl std::fmt::Debug for Ros2Node {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "Ros2Node({} in domain {})",
            self.node.fully_qualified_name(),
            self.domain_id()
        )
    }
}

fn dds<E: std::fmt::Display>(e: E) -> Ros2Error {
    Ros2Error::Dds(e.to_string())
}

impl Ros2Node {
    /// Joins `domain_id` as the node `/<name>`; with `localhost_only`, on the loopback
    /// interface only.
    ///
    /// # Errors
    /// [`Ros2Error`] when the name is not a ROS 2 name or DDS cannot start (no free ports).
    pub fn new(domain_id: u16, name: &str, localhost_only: bool) -> Result<Ros2Node, Ros2Error> {
        let mut builder = DomainParticipantBuilder::new(domain_id);
        if localhost_only {
            builder = builder.with_only_networks([std::net::Ipv4Addr::LOCALHOST]);
        }
        let participant = builder.build().map_err(dds)?;
        let context = Context::from_domain_participant(participant).map_err(dds)?;
        let node_name = NodeName::new("/", name).map_err(|_| Ros2Error::Name(name.to_string()))?;
        let node = context
            .new_node(node_name, NodeOptions::new().enable_rosout(false))
            .map_err(dds)?;
        Ok(Ros2Node { node, context })
    }

    /// The node from the environment: `ROS_DOMAIN_ID` and the discovery range.
    ///
    /// # Errors
    /// As [`Ros2Node::new`], and a bad `ROS_DOMAIN_ID`.
    pub fn from_env(name: &str) -> Result<Ros2Node, Ros2Error> {
        Ros2Node::new(domain_id_from_env()?, name, localhost_only_from_env())
    }

    /// The DDS domain id.
    #[must_use]
    pub fn domain_id(&self) -> u16 {
        self.context.domain_id()
    }

    /// The node's full name.
    #[must_use]
    pub fn name(&self) -> String {
        self.node.fully_qualified_name()
    }

    /// Publishes the rig's joint states on `/joint_states` from a thread, at `rate_hz`, from
    /// the telemetry records on `records` (a channel of the loop's, polled), until that
    /// channel's sender is dropped (the loop ended); then the last record is published and
    /// the thread returns what it did.
    ///
    /// # Errors
    /// [`Ros2Error`] when the topic or the writer cannot be made, or the thread started.
    pub fn spawn_joint_states(
        &mut self,
        records: Receiver<Telemetry>,
        rig: Rig,
        names: Vec<String>,
        clock: SystemClock,
        rate_hz: f64,
    ) -> Result<JoinHandle<PublishReport>, Ros2Error> {
        let qos = joint_states_qos();
        let topic = self
            .node
            .create_topic(
                &Name::new("/", "joint_states").map_err(|_| Ros2Error::Name("joint_states".into()))?,
                MessageTypeName::new("sensor_msgs", "JointState"),
                &qos,
            )
            .map_err(dds)?;
        let publisher: Publisher<msg::JointState> =
            self.node.create_publisher(&topic, Some(qos)).map_err(dds)?;
        let period = Duration::from_secs_f64(1.0 / rate_hz.clamp(0.1, 10_000.0));
        Ok(std::thread::Builder::new()
            .name("ros2-joint-states".into())
            .spawn(move || {
                let mut states = JointStates::new(rig, names, WallClock::new(clock));
                let mut report = PublishReport::default();
                let mut next = Instant::now();
                loop {
                    next += period;
                    if let Some(wait) = next.checked_duration_since(Instant::now()) {
                        std::thread::sleep(wait);
                    } else {
                        next = Instant::now();
                    }
                    let mut ended = false;
                    let mut newest = None;
                    loop {
                        match records.try_recv() {
                            Ok(t) => {
                                report.records += 1;
                                if t.read_ns > 0 && t.servos > 0 {
                                    newest = Some(t);
                                }
                            }
                            Err(TryRecvError::Empty) => break,
                            Err(TryRecvError::Disconnected) => {
                                ended = true;
                                break;
                            }
                        }
                    }
                    if let Some(message) = newest.and_then(|t| states.message(&t)) {
                        match publisher.publish(message) {
                            Ok(()) => report.published += 1,
                            Err(_) => report.failed += 1,
                        }
                    }
                    if ended {
                        break;
                    }
                }
                // Give the reliable writer a moment to get the last samples acknowledged.
                std::thread::sleep(Duration::from_millis(200));
                report
            })?)
    }

    /// Subscribes to `/marionette/targets/<effector>` for each of `effectors`: a live source
    /// of target inputs (positions in metres on the rig turned into file units by
    /// `metres_per_unit`), until the loop stops.
    ///
    /// # Errors
    /// [`Ros2Error`] for an effector name that makes no ROS 2 topic name, or DDS failing.
    pub fn targets(
        &mut self,
        effectors: &[String],
        root: &str,
        kind: TargetKind,
        metres_per_unit: f64,
    ) -> Result<TargetSource, Ros2Error> {
        let qos = targets_qos();
        let type_name = match kind {
            TargetKind::Point => MessageTypeName::new("geometry_msgs", "PointStamped"),
            TargetKind::Pose => MessageTypeName::new("geometry_msgs", "PoseStamped"),
        };
        let mut points = Vec::new();
        let mut poses = Vec::new();
        for (k, e) in effectors.iter().enumerate().take(MAX_EFFECTORS) {
            let name = Name::new("/marionette/targets", e).map_err(|_| Ros2Error::Name(e.clone()))?;
            let topic = self
                .node
                .create_topic(&name, type_name.clone(), &qos)
                .map_err(dds)?;
            match kind {
                TargetKind::Point => {
                    let s: Subscription<msg::PointStamped> = self
                        .node
                        .create_subscription(&topic, Some(qos.clone()))
                        .map_err(dds)?;
                    points.push((k, s));
                }
                TargetKind::Pose => {
                    let s: Subscription<msg::PoseStamped> = self
                        .node
                        .create_subscription(&topic, Some(qos.clone()))
                        .map_err(dds)?;
                    poses.push((k, s));
                }
            }
        }
        Ok(TargetSource {
            points,
            poses,
            reader: TargetReader {
                root: root.to_string(),
                metres_per_unit,
            },
            clock: None,
            seq: 0,
            report: ProducerReport::default(),
        })
    }
}

/// Target topics as the loop's live source (made by [`Ros2Node::targets`]; real time only).
pub struct TargetSource {
    points: Vec<(usize, Subscription<msg::PointStamped>)>,
    poses: Vec<(usize, Subscription<msg::PoseStamped>)>,
    reader: TargetReader,
    clock: Option<SystemClock>,
    seq: u64,
    report: ProducerReport,
}

impl std::fmt::Debug for TargetSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TargetSource")
            .field("topics", &(self.points.len() + self.poses.len()))
            .finish_non_exhaustive()
    }
}

impl TargetSource {
    /// Sends a target (or counts a refusal); false once the loop has stopped.
    fn send(&mut self, target: Result<Target, String>, sink: &Sink<'_>) -> bool {
        let Ok(target) = target else {
            self.report.bad_lines += 1;
            return true;
        };
        let mut targets = heapless::Vec::new();
        let _ = targets.push(target);
        let msg = Input {
            seq: self.seq,
            due_ns: 0,
            made_ns: self.clock.as_mut().map_or(0, Clock::now_ns),
            payload: Payload::Targets(targets),
        };
        self.seq += 1;
        match sink.send_newest(msg) {
            Ok(dropped) => {
                self.report.sent += 1;
                self.report.dropped += u64::from(dropped);
                true
            }
            Err(_) => false,
        }
    }
}

impl Source for TargetSource {
    fn name(&self) -> &'static str {
        "ros2-targets"
    }
    fn live(&self) -> bool {
        true
    }
    fn runs_in_lockstep(&self) -> bool {
        false
    }
    fn next_due(&self, _grid: Grid) -> Option<u64> {
        None
    }
    fn begin(&mut self, clock: SystemClock) {
        self.clock = Some(clock);
    }
    fn feed(&mut self, _grid: Grid, _until_ns: u64, _now_ns: u64, sink: &Sink<'_>) -> bool {
        // The streams wake this thread when a sample arrives; a watcher ends the wait when the
        // loop stops (the loop's stop is a flag, not a waker).
        let stop = Arc::new(AtomicBool::new(false));
        let (done_tx, done_rx) = futures::channel::oneshot::channel::<()>();
        let watch_stop = Arc::clone(&stop);
        let stopped = sink.stop_flag();
        let watcher = std::thread::Builder::new()
            .name("ros2-targets-stop".into())
            .spawn(move || {
                while !stopped.load(Ordering::Relaxed) && !watch_stop.load(Ordering::Relaxed) {
                    std::thread::sleep(Duration::from_millis(20));
                }
                let _ = done_tx.send(());
            });
        if watcher.is_err() {
            return false;
        }
        let points = std::mem::take(&mut self.points);
        let poses = std::mem::take(&mut self.poses);
        {
            let point_streams = points.iter().map(|(k, s)| {
                s.async_stream()
                    .map(move |r| (*k, r.map(|(m, _)| Incoming::Point(m))))
            });
            let pose_streams = poses.iter().map(|(k, s)| {
                s.async_stream()
                    .map(move |r| (*k, r.map(|(m, _)| Incoming::Pose(m))))
            });
            let mut all = futures::stream::select_all(
                point_streams
                    .map(futures::StreamExt::boxed)
                    .chain(pose_streams.map(futures::StreamExt::boxed)),
            );
            futures::executor::block_on(async {
                let mut done = done_rx;
                loop {
                    futures::select! {
                        item = all.next() => match item {
                            Some((k, Ok(m))) => {
                                let target = self.reader.target(k, &m);
                                if !self.send(target, sink) {
                                    break;
                                }
                            }
                            Some((_, Err(_))) => self.report.bad_lines += 1,
                            None => break,
                        },
                        _ = done => break,
                    }
                }
            });
        }
        stop.store(true, Ordering::Relaxed);
        false
    }
    fn report(&self) -> ProducerReport {
        self.report
    }
}

/// What the joint-state thread did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PublishReport {
    /// Telemetry records taken.
    pub records: u64,
    /// Messages published.
    pub published: u64,
    /// Publications that failed.
    pub failed: u64,
}

/// The loop clock against the wall clock: a read's loop-clock time as a ROS stamp.
#[derive(Clone, Copy, Debug)]
pub struct WallClock {
    /// Wall-clock ns since the Unix epoch at loop-clock 0.
    offset_ns: i128,
}

impl WallClock {
    /// Measures the offset now.
    #[must_use]
    pub fn new(mut clock: SystemClock) -> WallClock {
        let loop_ns = clock.now_ns();
        let wall_ns = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos());
        WallClock {
            offset_ns: i128::try_from(wall_ns).unwrap_or(0) - i128::from(loop_ns),
        }
    }

    /// The wall-clock time of loop-clock time `loop_ns`.
    #[must_use]
    pub fn stamp(&self, loop_ns: u64) -> msg::Time {
        let ns = (i128::from(loop_ns) + self.offset_ns).max(0);
        msg::Time::from_ns(u64::try_from(ns).unwrap_or(u64::MAX))
    }
}

/// Telemetry records into `JointState` messages.
#[derive(Debug)]
pub struct JointStates {
    rig: Rig,
    names: Vec<String>,
    wall: WallClock,
    /// The positions and read time of the last message, for the velocities.
    last: Option<(u64, Vec<f64>)>,
}

impl JointStates {
    /// For `rig`'s servos named `names` (rig order).
    #[must_use]
    pub fn new(rig: Rig, names: Vec<String>, wall: WallClock) -> JointStates {
        JointStates {
            rig,
            names,
            wall,
            last: None,
        }
    }

    /// The message for record `t`: positions in radians, velocities over the time since the
    /// last message (zero for the first); `None` when `t` holds no new read.
    pub fn message(&mut self, t: &Telemetry) -> Option<msg::JointState> {
        if self.last.as_ref().is_some_and(|(ns, _)| *ns == t.read_ns) {
            return None;
        }
        let position: Vec<f64> = self
            .rig
            .servos
            .iter()
            .zip(t.present())
            .map(|(s, p)| s.ticks_to_angle(f64::from(*p)))
            .collect();
        let velocity = match &self.last {
            Some((ns, before)) if t.read_ns > *ns && before.len() == position.len() => {
                let dt = (t.read_ns - ns) as f64 * 1e-9;
                position.iter().zip(before).map(|(p, b)| (p - b) / dt).collect()
            }
            _ => vec![0.0; position.len()],
        };
        let message = msg::JointState {
            header: msg::Header {
                stamp: self.wall.stamp(t.read_ns),
                frame_id: String::new(),
            },
            name: self.names.iter().take(position.len()).cloned().collect(),
            position: position.clone(),
            velocity,
            effort: Vec::new(),
        };
        self.last = Some((t.read_ns, position));
        Some(message)
    }
}

/// A target message as received.
#[derive(Clone, Debug, PartialEq)]
pub enum Incoming {
    /// `PointStamped`.
    Point(msg::PointStamped),
    /// `PoseStamped`.
    Pose(msg::PoseStamped),
}

/// Target messages into the loop's targets, by the UDP lines' rules.
#[derive(Clone, Debug)]
pub struct TargetReader {
    /// The root bone's name: the one frame id accepted besides the empty one.
    pub root: String,
    /// Metres on the rig per skeleton file unit.
    pub metres_per_unit: f64,
}

impl TargetReader {
    /// Effector `k`'s target from `m`, in file units in the root's frame.
    ///
    /// # Errors
    /// Why the message is refused: a frame other than the root, a number that is not finite,
    /// a quaternion of zero length.
    pub fn target(&self, k: usize, m: &Incoming) -> Result<Target, String> {
        let (header, p, q) = match m {
            Incoming::Point(m) => (&m.header, m.point, None),
            Incoming::Pose(m) => (&m.header, m.pose.position, Some(m.pose.orientation)),
        };
        if !header.frame_id.is_empty() && header.frame_id != self.root {
            return Err(format!(
                "frame '{}': targets are in the root's frame ('{}' or empty)",
                header.frame_id, self.root
            ));
        }
        let metres = DVec3::new(p.x, p.y, p.z);
        if !metres.is_finite() {
            return Err("position: expected finite numbers".into());
        }
        if !(self.metres_per_unit.is_finite() && self.metres_per_unit > 0.0) {
            return Err("no scale from metres to the skeleton's units".into());
        }
        let direction = match q {
            None => None,
            Some(q) => {
                let q = DQuat::from_xyzw(q.x, q.y, q.z, q.w);
                if !q.is_finite() {
                    return Err("orientation: expected finite numbers".into());
                }
                let n = q.length();
                if n < 1e-6 {
                    return Err("orientation: a quaternion of zero length".into());
                }
                Some((q / n) * DVec3::X)
            }
        };
        let target = Target {
            effector: k,
            position: metres / self.metres_per_unit,
            direction,
        };
        if !target.is_finite() {
            return Err("target: not finite in the skeleton's units".into());
        }
        Ok(target)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn reader() -> TargetReader {
        TargetReader {
            root: "root".into(),
            metres_per_unit: 0.5,
        }
    }

    fn point(frame: &str, x: f64) -> Incoming {
        Incoming::Point(msg::PointStamped {
            header: msg::Header {
                stamp: msg::Time::default(),
                frame_id: frame.into(),
            },
            point: msg::Point { x, y: 1.0, z: -2.0 },
        })
    }

    #[test]
    fn points_become_targets_in_file_units() {
        for frame in ["", "root"] {
            let t = reader().target(2, &point(frame, 0.25)).unwrap();
            assert_eq!(t.effector, 2);
            assert_eq!(t.position, DVec3::new(0.5, 2.0, -4.0));
            assert_eq!(t.direction, None);
        }
    }

    #[test]
    fn refusals_say_why() {
        let r = reader();
        assert!(r
            .target(0, &point("map", 0.0))
            .unwrap_err()
            .contains("frame 'map'"));
        assert!(r.target(0, &point("", f64::NAN)).unwrap_err().contains("finite"));
        assert!(r
            .target(0, &point("", f64::INFINITY))
            .unwrap_err()
            .contains("finite"));
        let pose = |q: msg::Quaternion| {
            Incoming::Pose(msg::PoseStamped {
                header: msg::Header::default(),
                pose: msg::Pose {
                    position: msg::Point::default(),
                    orientation: q,
                },
            })
        };
        let zero = msg::Quaternion::default();
        assert!(r.target(0, &pose(zero)).unwrap_err().contains("zero length"));
        let nan = msg::Quaternion { w: f64::NAN, ..zero };
        assert!(r.target(0, &pose(nan)).unwrap_err().contains("finite"));
        let no_scale = TargetReader {
            metres_per_unit: 0.0,
            ..r.clone()
        };
        assert!(no_scale.target(0, &point("", 0.0)).is_err());
    }

    #[test]
    fn a_pose_points_the_next_bone_along_its_x_axis() {
        // A quarter turn about z, unnormalised (×2): +x turns to +y.
        let h = std::f64::consts::FRAC_1_SQRT_2 * 2.0;
        let m = Incoming::Pose(msg::PoseStamped {
            header: msg::Header::default(),
            pose: msg::Pose {
                position: msg::Point {
                    x: 1.0,
                    y: 2.0,
                    z: 3.0,
                },
                orientation: msg::Quaternion {
                    x: 0.0,
                    y: 0.0,
                    z: h,
                    w: h,
                },
            },
        });
        let t = reader().target(1, &m).unwrap();
        assert_eq!(t.position, DVec3::new(2.0, 4.0, 6.0));
        let d = t.direction.unwrap();
        assert!((d - DVec3::Y).length() < 1e-12, "{d}");
    }

    #[test]
    fn domain_ids_are_read_as_ros_2_does() {
        // The only test here that touches the environment variable.
        std::env::remove_var("ROS_DOMAIN_ID");
        assert_eq!(domain_id_from_env().unwrap(), 0);
        for (v, want) in [
            ("", Some(0)),
            ("7", Some(7)),
            (" 232 ", Some(232)),
            ("233", None),
            ("x", None),
            ("-1", None),
        ] {
            std::env::set_var("ROS_DOMAIN_ID", v);
            match want {
                Some(d) => assert_eq!(domain_id_from_env().unwrap(), d, "{v:?}"),
                None => assert!(
                    domain_id_from_env().unwrap_err().to_string().contains("0 to 232"),
                    "{v:?}"
                ),
            }
        }
        std::env::remove_var("ROS_DOMAIN_ID");
    }

    #[test]
    fn joint_states_carry_the_reads_in_radians_with_stamps_and_velocities() {
        assert_eq!(msg::Time::from_ns(3_000_000_007).to_ns(), 3_000_000_007);
        assert_eq!(
            msg::Time::from_ns(3_000_000_007),
            msg::Time { sec: 3, nanosec: 7 }
        );
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
        let skel = crate::formats::asf::load(&root.join("data/cmu/16.asf"))
            .unwrap()
            .skeleton;
        let profile = crate::profile::Profile::load(&root.join("firmware-profile/cmu-puppet.toml")).unwrap();
        let rig = profile.rig(Some(&skel)).unwrap();
        let names: Vec<String> = profile.servos.iter().map(|s| s.name.clone()).collect();
        let wall = WallClock {
            offset_ns: 1_000_000_000_000,
        };
        let mut states = JointStates::new(rig.clone(), names.clone(), wall);
        let mut t = Telemetry {
            servos: rig.len(),
            read_ns: 5_000_000,
            ..Telemetry::default()
        };
        for (k, p) in t.present[..rig.len()].iter_mut().enumerate() {
            *p = 2048 + 10 * k as i32;
        }
        let first = states.message(&t).unwrap();
        assert_eq!(first.name, names);
        assert_eq!(first.header.stamp.to_ns(), 1_000_005_000_000);
        assert_eq!(first.header.frame_id, "");
        for (k, s) in rig.servos.iter().enumerate() {
            assert_eq!(first.position[k], s.ticks_to_angle(f64::from(t.present[k])));
        }
        assert!(first.velocity.iter().all(|v| *v == 0.0));
        assert!(first.effort.is_empty());
        // The same read again: nothing new to publish.
        assert_eq!(states.message(&t), None);
        // 10 ms later, each servo 4 ticks further: the velocity over those 10 ms.
        t.read_ns += 10_000_000;
        for p in &mut t.present[..rig.len()] {
            *p += 4;
        }
        let second = states.message(&t).unwrap();
        for k in 0..rig.len() {
            let want = (second.position[k] - first.position[k]) / 0.01;
            assert!((second.velocity[k] - want).abs() < 1e-9, "{k}");
            assert!(second.velocity[k] != 0.0);
        }
    }
}
