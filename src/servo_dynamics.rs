//! How each servo model moves under load: its stiffness, torque limit, damping, reflected
//! inertia and friction (MuJoCo's position actuator models a servo with them; a walk's
//! compliance compensation uses the stiffness).

use crate::profile::ServoSpec;
use crate::servo::ServoModel;

/// How a servo model behaves as a MuJoCo position actuator on a hinge, at its factory
/// Position P Gain (the simulated servo scales `kp` with the gain written to it).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ServoDynamics {
    /// Position gain, N·m/rad.
    pub kp: f64,
    /// Torque limit, N·m.
    pub force: f64,
    /// Joint damping, N·m·s/rad.
    pub damping: f64,
    /// Reflected rotor inertia, kg·m².
    pub armature: f64,
    /// Dry friction, N·m.
    pub frictionloss: f64,
    /// The servo's mass, kg (e-manual).
    pub mass: f64,
}

/// XM430-W350 values identified for the ROBOTIS OP3 model (MuJoCo Menagerie): kp 21.1, force
/// ±5 N·m, damping 1.084, armature 0.045, frictionloss 0.03; 82 g.
pub const XM430_W350: ServoDynamics = ServoDynamics {
    kp: 21.1,
    force: 5.0,
    damping: 1.084,
    armature: 0.045,
    frictionloss: 0.03,
    mass: 0.082,
};

/// Stall torque of the XM430-W350 at 12 V (N·m), the reference of [`dynamics`].
const XM430_W350_STALL_NM: f64 = 4.1;

/// A servo model's dynamics: the XM430-W350's identified values; another XM430 (the same
/// motor behind another gearhead) scaled by its gear ratio `r` against the W350's — gain and
/// friction by `r`, damping (back-EMF) and reflected rotor inertia by `r²`, the torque limit by
/// its stall torque; the other series scaled by their stall torque (same time constant
/// `damping/kp` ≈ 51 ms), each with its own mass.
#[must_use]
pub fn dynamics(model: &ServoModel) -> ServoDynamics {
    let mass = match model.name {
        "XL330-M288" => 0.018,
        "XL430-W250" => 0.0572,
        "XH540-W270" => 0.165,
        _ => XM430_W350.mass,
    };
    if model.name == "XM430-W350" {
        return XM430_W350;
    }
    if model.name.starts_with("XM430") {
        let r = model.gear_ratio / 353.5;
        return ServoDynamics {
            kp: XM430_W350.kp * r,
            force: XM430_W350.force * model.stall_torque_nm / XM430_W350_STALL_NM,
            damping: XM430_W350.damping * r * r,
            armature: XM430_W350.armature * r * r,
            frictionloss: XM430_W350.frictionloss * r,
            mass,
        };
    }
    let r = model.stall_torque_nm / XM430_W350_STALL_NM;
    ServoDynamics {
        kp: XM430_W350.kp * r,
        force: XM430_W350.force * r,
        damping: XM430_W350.damping * r,
        armature: XM430_W350.armature * r,
        frictionloss: XM430_W350.frictionloss * r,
        mass,
    }
}

/// A servo model's dynamics at a supply of `volts`: the torque limit scales with the voltage
/// (so does the no-load speed; the back-EMF damping, the torque–speed line's slope, does not).
#[must_use]
pub fn dynamics_at(model: &ServoModel, volts: f64) -> ServoDynamics {
    let d = dynamics(model);
    ServoDynamics {
        force: d.force * model.voltage_factor(volts),
        ..d
    }
}

/// How stiffly `servo` holds its joint, N·m/rad at the joint: its model's position gain
/// ([`dynamics`]) scaled by the Position P Gain the profile writes against the factory's (the
/// position loop's torque grows with the gain), times the gear ratio squared (a joint turn is
/// `gear` horn turns, each horn N·m is `gear` joint N·m).
#[must_use]
pub fn joint_stiffness(servo: &ServoSpec) -> f64 {
    let gain = servo.position_p_gain.map_or(1.0, |g| {
        f64::from(g) / f64::from(servo.model.position_p_gain.max(1))
    });
    dynamics(servo.model).kp * gain * servo.gear * servo.gear
}
