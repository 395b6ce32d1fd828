//! The MuJoCo simulator edge: rig models ([`mjcf`], always available) and, with the `sim`
//! feature, simulated servos behind the bus interfaces (`plant`), tracking reports (`report`)
//! and sizing by inverse dynamics (`size`).

pub mod mjcf;

/// What a build without the `sim` feature says when asked for the simulator.
pub const NOT_BUILT: &str = "needs the MuJoCo simulator, which this build does not have: eval \"$(sim/fetch-mujoco.sh)\" && cargo build --release --features sim";
#[cfg(feature = "sim")]
pub mod footsteps;
#[cfg(feature = "sim")]
pub mod plant;
#[cfg(feature = "sim")]
pub mod report;
#[cfg(feature = "sim")]
pub mod size;
