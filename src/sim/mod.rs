//! The MuJoCo simulator edge: rig models ([`mjcf`], always available) and, with the `sim`
//! feature, simulated servos behind the bus interfaces ([`plant`]) and tracking reports
//! ([`report`]).

pub mod mjcf;
#[cfg(feature = "sim")]
pub mod plant;
#[cfg(feature = "sim")]
pub mod report;
