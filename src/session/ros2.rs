//! The run's ROS 2 node: `/joint_states` published from the loop's telemetry, and target
//! topics as a source (the `ros2` feature; without it asking for them says how to build it).

use std::io::Write;

use super::SessionError;
use crate::clock::SystemClock;
use crate::control::source::Source;
use crate::control::Controller;
use crate::rig::Rig;

/// The node shared by the run's publisher and its target subscriptions.
#[cfg(feature = "ros2")]
pub type Ros2Handle = std::sync::Arc<std::sync::Mutex<crate::ros2::Ros2Node>>;

/// The node of a build without ROS 2: there is none.
#[cfg(not(feature = "ros2"))]
#[derive(Clone, Debug)]
pub enum Ros2Handle {}

/// The message type of `/marionette/targets/<effector>`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Ros2Targets {
    /// geometry_msgs/msg/PointStamped: a position.
    #[default]
    Point,
    /// geometry_msgs/msg/PoseStamped: a position, and its orientation's +x as the direction of
    /// the bone after the effector (hand, foot).
    Pose,
}

/// The joint-state publisher of a run, to join when the loop has ended.
pub struct Publishing {
    #[cfg(feature = "ros2")]
    thread: std::thread::JoinHandle<crate::ros2::PublishReport>,
}

#[cfg(not(feature = "ros2"))]
fn not_built() -> SessionError {
    SessionError::Invalid(
        "--ros2 and --targets ros2 need a build with ROS 2: cargo build --release --features ros2".into(),
    )
}

/// A new node `/marionette` in the domain of `ROS_DOMAIN_ID`.
///
/// # Errors
/// A build without the `ros2` feature; a bad `ROS_DOMAIN_ID`; DDS failing to start.
pub fn node(out: &mut dyn Write) -> Result<Ros2Handle, SessionError> {
    #[cfg(feature = "ros2")]
    {
        let node = crate::ros2::Ros2Node::from_env("marionette")
            .map_err(|e| SessionError::Invalid(format!("--ros2: {e}")))?;
        writeln!(
            out,
            "ros2: node {} in domain {}{}",
            node.name(),
            node.domain_id(),
            if crate::ros2::localhost_only_from_env() {
                " (this host only)"
            } else {
                ""
            }
        )?;
        Ok(std::sync::Arc::new(std::sync::Mutex::new(node)))
    }
    #[cfg(not(feature = "ros2"))]
    {
        let _ = out;
        Err(not_built())
    }
}

/// Starts publishing `/joint_states` from `controller`'s telemetry, when the run has a node.
///
/// # Errors
/// DDS failing to make the topic or the writer; the thread not starting.
pub(super) fn publish(
    node: Option<&Ros2Handle>,
    rate_hz: f64,
    controller: &mut Controller,
    rig: &Rig,
    names: Vec<String>,
    clock: SystemClock,
    out: &mut dyn Write,
) -> Result<Option<Publishing>, SessionError> {
    let Some(node) = node else {
        return Ok(None);
    };
    #[cfg(feature = "ros2")]
    {
        // A second of records at 1 kHz: the publisher polls at its own rate and takes the newest.
        let (tx, rx) = crate::resident::channel(1024, crate::control::Telemetry::default());
        if controller.add_telemetry(tx).is_err() {
            return Err(SessionError::Invalid(
                "--ros2: no telemetry slot left on the loop".into(),
            ));
        }
        let thread = node
            .lock()
            .map_err(|_| SessionError::Invalid("--ros2: the node was poisoned".into()))?
            .spawn_joint_states(rx, rig.clone(), names, clock, rate_hz)
            .map_err(|e| SessionError::Invalid(format!("--ros2: {e}")))?;
        writeln!(
            out,
            "ros2: /joint_states at {rate_hz} Hz (sensor_msgs/msg/JointState, reliable)"
        )?;
        Ok(Some(Publishing { thread }))
    }
    #[cfg(not(feature = "ros2"))]
    {
        let _ = (rate_hz, controller, rig, names, clock, out);
        match *node {}
    }
}

/// Waits for the publisher's last message and says what it did.
///
/// # Errors
/// Output errors.
pub(super) fn finish(publishing: Option<Publishing>, out: &mut dyn Write) -> Result<(), SessionError> {
    let Some(p) = publishing else {
        return Ok(());
    };
    #[cfg(feature = "ros2")]
    {
        let r = p.thread.join().unwrap_or_default();
        writeln!(
            out,
            "ros2: {} joint states published on /joint_states ({} failed) from {} tick records",
            r.published, r.failed, r.records
        )?;
    }
    #[cfg(not(feature = "ros2"))]
    {
        let _ = (p, out);
    }
    Ok(())
}

/// The target topics `/marionette/targets/<effector>` on `node` as a live source (positions in
/// metres on the rig, `metres_per_unit` to the skeleton's units, in the frame of `root`).
///
/// # Errors
/// An effector name that makes no topic name; DDS failing.
pub fn targets(
    node: &Ros2Handle,
    effectors: &[String],
    root: &str,
    kind: Ros2Targets,
    metres_per_unit: f64,
) -> Result<Box<dyn Source>, SessionError> {
    #[cfg(feature = "ros2")]
    {
        let kind = match kind {
            Ros2Targets::Point => crate::ros2::TargetKind::Point,
            Ros2Targets::Pose => crate::ros2::TargetKind::Pose,
        };
        let source = node
            .lock()
            .map_err(|_| SessionError::Invalid("--targets ros2: the node was poisoned".into()))?
            .targets(effectors, root, kind, metres_per_unit)
            .map_err(|e| SessionError::Invalid(format!("--targets ros2: {e}")))?;
        Ok(Box::new(source))
    }
    #[cfg(not(feature = "ros2"))]
    {
        let _ = (effectors, root, kind, metres_per_unit);
        match *node {}
    }
}
