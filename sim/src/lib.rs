//! MuJoCo for marionette: load a rig model, step it, drive its position actuators and read its
//! joints, bodies and sites.
//!
//! This crate is the one place that talks to MuJoCo (through `mujoco-rs`). It knows nothing of
//! servos or profiles: `marionette`'s `sim` feature builds simulated servos on top of it.
//! Indices are MuJoCo's own (actuator, joint, body and site ids).

use std::fmt;
use std::path::Path;

use mujoco_rs::prelude::*;

/// A model that failed to load: MuJoCo's own message (it names the element and line).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct LoadError(pub String);

impl fmt::Display for LoadError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for LoadError {}

/// A MuJoCo model and its simulation state.
pub struct World {
    data: MjData<Box<MjModel>>,
}

impl fmt::Debug for World {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("World")
            .field("nq", &self.model().nq())
            .field("nu", &self.model().nu())
            .field("time", &self.time())
            .finish_non_exhaustive()
    }
}

impl Clone for World {
    /// An independent copy of the model and its state (for kinematics at other poses).
    fn clone(&self) -> World {
        World {
            data: self.data.clone(),
        }
    }
}

fn id(n: i32) -> Option<usize> {
    usize::try_from(n).ok()
}

impl World {
    /// Loads MJCF text (includes are resolved against the working directory).
    ///
    /// # Errors
    /// [`LoadError`] with MuJoCo's message.
    pub fn from_xml_str(xml: &str) -> Result<World, LoadError> {
        let model = MjModel::from_xml_string(xml).map_err(|e| LoadError(e.to_string()))?;
        Ok(World::with_model(model))
    }

    /// Loads an MJCF file (includes are resolved against its directory).
    ///
    /// # Errors
    /// [`LoadError`] with the path and MuJoCo's message.
    pub fn from_file(path: &Path) -> Result<World, LoadError> {
        if !path.is_file() {
            return Err(LoadError(format!("{}: no such file", path.display())));
        }
        let model = MjModel::from_xml(path).map_err(|e| LoadError(format!("{}: {e}", path.display())))?;
        Ok(World::with_model(model))
    }

    fn with_model(model: MjModel) -> World {
        let mut data = MjData::new(Box::new(model));
        data.forward();
        World { data }
    }

    fn model(&self) -> &MjModel {
        self.data.model()
    }

    /// The physics time step, seconds.
    #[must_use]
    pub fn timestep(&self) -> f64 {
        self.model().opt().timestep
    }

    /// Simulated time, seconds.
    #[must_use]
    pub fn time(&self) -> f64 {
        self.data.time()
    }

    /// Lets `dt` seconds of simulated time pass with nothing moving (the world held).
    pub fn pass_time(&mut self, dt: f64) {
        let t = self.data.time();
        self.data.set_time(t + dt);
    }

    /// One physics step.
    pub fn step(&mut self) {
        self.data.step();
    }

    /// Recomputes positions, forces and sensors from the present state (no time passes).
    pub fn forward(&mut self) {
        self.data.forward();
    }

    /// Back to the model's initial state (time 0, `qpos0`, zero velocities and controls).
    pub fn reset(&mut self) {
        self.data.reset();
        self.data.forward();
    }

    /// Number of actuators.
    #[must_use]
    pub fn actuator_count(&self) -> usize {
        self.model().nu() as usize
    }

    /// The actuator with this name.
    #[must_use]
    pub fn actuator(&self, name: &str) -> Option<usize> {
        self.model().name_to_id(MjtObjBase::mjOBJ_ACTUATOR, name)
    }

    /// An actuator's name.
    #[must_use]
    pub fn actuator_name(&self, actuator: usize) -> Option<&str> {
        self.model().id_to_name(MjtObjBase::mjOBJ_ACTUATOR, actuator)
    }

    /// The joint an actuator drives, when its transmission is a joint.
    #[must_use]
    pub fn actuator_joint(&self, actuator: usize) -> Option<usize> {
        let m = self.model();
        if m.actuator_trntype().get(actuator)? != &MjtTrn::mjTRN_JOINT {
            return None;
        }
        id(m.actuator_trnid().get(actuator)?[0])
    }

    /// An actuator's force limits (N·m for a hinge), when it has them.
    #[must_use]
    pub fn force_range(&self, actuator: usize) -> Option<(f64, f64)> {
        let m = self.model();
        if !*m.actuator_forcelimited().get(actuator)? {
            return None;
        }
        let r = m.actuator_forcerange().get(actuator)?;
        Some((r[0], r[1]))
    }

    /// Sets an actuator's control (the goal angle of a position actuator).
    pub fn set_ctrl(&mut self, actuator: usize, value: f64) {
        if let Some(c) = self.data.ctrl_mut().get_mut(actuator) {
            *c = value;
        }
    }

    /// A position actuator's gain `kp` (force = kp·(ctrl − q)), N·m/rad for a hinge.
    #[must_use]
    pub fn position_gain(&self, actuator: usize) -> f64 {
        self.model()
            .actuator_gainprm()
            .get(actuator)
            .map_or(f64::NAN, |g| g[0])
    }

    /// Sets a position actuator's gain (`gainprm[0] = kp`, `biasprm[1] = −kp`), as a servo's
    /// firmware does when its position P gain is written. Ignored for a non-finite or negative
    /// gain or an unknown actuator.
    pub fn set_position_gain(&mut self, actuator: usize, kp: f64) {
        if actuator >= self.actuator_count() || !(kp.is_finite() && kp >= 0.0) {
            return;
        }
        // SAFETY: only two numbers of an existing actuator change (checked above); MuJoCo reads
        // gain and bias parameters as plain numbers at every step, not as sizes or indices,
        // and its documentation lists them among the fields safe to change between steps.
        unsafe {
            let m = self.data.model_mut();
            m.actuator_gainprm_mut()[actuator][0] = kp;
            m.actuator_biasprm_mut()[actuator][1] = -kp;
        }
    }

    /// Sets an actuator's force limits (N·m for a hinge) and turns its force limiting on.
    /// Ignored for an unknown actuator or limits that are not finite with `lo ≤ 0 ≤ hi`.
    pub fn set_force_range(&mut self, actuator: usize, lo: f64, hi: f64) {
        if actuator >= self.actuator_count() || !(lo.is_finite() && hi.is_finite() && lo <= 0.0 && 0.0 <= hi)
        {
            return;
        }
        // SAFETY: two numbers and a flag of an existing actuator change (checked above);
        // MuJoCo reads them at every step when it clamps the actuator's force.
        unsafe {
            let m = self.data.model_mut();
            m.actuator_forcerange_mut()[actuator] = [lo, hi];
            m.actuator_forcelimited_mut()[actuator] = true;
        }
    }

    /// A degree of freedom's linear damping (N·m·s/rad for a hinge).
    #[must_use]
    pub fn dof_damping(&self, dof: usize) -> f64 {
        self.model().dof_damping().get(dof).copied().unwrap_or(f64::NAN)
    }

    /// Sets a degree of freedom's linear damping. Ignored for an unknown degree of freedom or a
    /// damping that is not finite and non-negative.
    pub fn set_dof_damping(&mut self, dof: usize, damping: f64) {
        if dof >= self.dof_count() || !(damping.is_finite() && damping >= 0.0) {
            return;
        }
        // SAFETY: one number of an existing degree of freedom changes (checked above); MuJoCo
        // reads it at every step for the passive force.
        unsafe {
            self.data.model_mut().dof_damping_mut()[dof] = damping;
        }
    }

    /// An actuator's control.
    #[must_use]
    pub fn ctrl(&self, actuator: usize) -> f64 {
        self.data.ctrl().get(actuator).copied().unwrap_or(f64::NAN)
    }

    /// The force an actuator applied in the last step (N·m for a hinge).
    #[must_use]
    pub fn actuator_force(&self, actuator: usize) -> f64 {
        self.data
            .actuator_force()
            .get(actuator)
            .copied()
            .unwrap_or(f64::NAN)
    }

    /// The joint with this name.
    #[must_use]
    pub fn joint(&self, name: &str) -> Option<usize> {
        self.model().name_to_id(MjtObjBase::mjOBJ_JOINT, name)
    }

    /// A joint's name.
    #[must_use]
    pub fn joint_name(&self, joint: usize) -> Option<&str> {
        self.model().id_to_name(MjtObjBase::mjOBJ_JOINT, joint)
    }

    /// A joint's limits, when it is limited.
    #[must_use]
    pub fn joint_range(&self, joint: usize) -> Option<(f64, f64)> {
        let m = self.model();
        if !*m.jnt_limited().get(joint)? {
            return None;
        }
        let r = m.jnt_range().get(joint)?;
        Some((r[0], r[1]))
    }

    fn qpos_address(&self, joint: usize) -> Option<usize> {
        id(*self.model().jnt_qposadr().get(joint)?)
    }

    fn dof_address(&self, joint: usize) -> Option<usize> {
        id(*self.model().jnt_dofadr().get(joint)?)
    }

    /// The first coordinate of a joint (the angle of a hinge), radians.
    #[must_use]
    pub fn joint_position(&self, joint: usize) -> f64 {
        self.qpos_address(joint)
            .and_then(|a| self.data.qpos().get(a).copied())
            .unwrap_or(f64::NAN)
    }

    /// The first velocity of a joint, rad/s for a hinge.
    #[must_use]
    pub fn joint_velocity(&self, joint: usize) -> f64 {
        self.dof_address(joint)
            .and_then(|a| self.data.qvel().get(a).copied())
            .unwrap_or(f64::NAN)
    }

    /// Places a hinge at an angle, at rest (call [`World::forward`] before reading positions).
    pub fn set_joint_position(&mut self, joint: usize, angle: f64) {
        if let Some(a) = self.qpos_address(joint) {
            if let Some(q) = self.data.qpos_mut().get_mut(a) {
                *q = angle;
            }
        }
        if let Some(a) = self.dof_address(joint) {
            if let Some(v) = self.data.qvel_mut().get_mut(a) {
                *v = 0.0;
            }
        }
    }

    /// Degrees of freedom (the length of velocity and force vectors).
    #[must_use]
    pub fn dof_count(&self) -> usize {
        usize::try_from(self.model().nv()).unwrap_or(0)
    }

    /// The first degree of freedom of a joint (its index in velocity and force vectors).
    #[must_use]
    pub fn joint_dof(&self, joint: usize) -> Option<usize> {
        self.dof_address(joint)
    }

    /// Inverse dynamics (`mj_inverse`): the generalised force per degree of freedom that gives
    /// the acceleration `qacc` at `qpos` and `qvel` (whole vectors; missing values are zero)
    /// with the model's own passive forces (joint damping and springs) and constraint forces
    /// (joint limits, contacts) added back — `M(q)·q̈ + c(q, q̇)`, what the actuators must
    /// supply to a body that nothing else holds. The state is left at `qpos`, `qvel`.
    pub fn load_forces(&mut self, qpos: &[f64], qvel: &[f64], qacc: &[f64]) -> Vec<f64> {
        let fill = |dst: &mut [f64], src: &[f64]| {
            for (i, d) in dst.iter_mut().enumerate() {
                *d = src.get(i).copied().unwrap_or(0.0);
            }
        };
        fill(self.data.qpos_mut(), qpos);
        fill(self.data.qvel_mut(), qvel);
        fill(self.data.qacc_mut(), qacc);
        self.data.inverse();
        self.data
            .qfrc_inverse()
            .iter()
            .zip(self.data.qfrc_passive())
            .zip(self.data.qfrc_constraint())
            .map(|((f, p), c)| f + p + c)
            .collect()
    }

    /// All generalised coordinates.
    #[must_use]
    pub fn qpos(&self) -> &[f64] {
        self.data.qpos()
    }

    /// Sets all generalised coordinates (extra values ignored).
    pub fn set_qpos(&mut self, qpos: &[f64]) {
        for (q, v) in self.data.qpos_mut().iter_mut().zip(qpos) {
            *q = *v;
        }
    }

    /// The body of the model's first free joint (a floating base), if it has one.
    #[must_use]
    pub fn free_body(&self) -> Option<usize> {
        let m = self.model();
        let j = m
            .jnt_type()
            .iter()
            .position(|t| *t == mujoco_rs::prelude::MjtJoint::mjJNT_FREE)?;
        id(*m.jnt_bodyid().get(j)?)
    }

    /// The body with this name.
    #[must_use]
    pub fn body(&self, name: &str) -> Option<usize> {
        self.model().name_to_id(MjtObjBase::mjOBJ_BODY, name)
    }

    /// A body frame's position in the world, metres.
    #[must_use]
    pub fn body_position(&self, body: usize) -> [f64; 3] {
        self.data.xpos().get(body).copied().unwrap_or([f64::NAN; 3])
    }

    /// A body frame's orientation in the world, a row-major 3×3 matrix.
    #[must_use]
    pub fn body_rotation(&self, body: usize) -> [f64; 9] {
        self.data.xmat().get(body).copied().unwrap_or([f64::NAN; 9])
    }

    /// Pushes a body with `force` (N, world frame) at its centre of mass from now until it is
    /// set again (zero: no push).
    pub fn set_body_force(&mut self, body: usize, force: [f64; 3]) {
        if let Some(f) = self.data.xfrc_applied_mut().get_mut(body) {
            *f = [force[0], force[1], force[2], 0.0, 0.0, 0.0];
        }
    }

    /// The centre of mass of a body and all bodies below it, in the world, metres.
    #[must_use]
    pub fn subtree_com(&self, body: usize) -> [f64; 3] {
        self.data
            .subtree_com()
            .get(body)
            .copied()
            .unwrap_or([f64::NAN; 3])
    }

    /// Number of sites.
    #[must_use]
    pub fn site_count(&self) -> usize {
        self.model().nsite() as usize
    }

    /// The site with this name.
    #[must_use]
    pub fn site(&self, name: &str) -> Option<usize> {
        self.model().name_to_id(MjtObjBase::mjOBJ_SITE, name)
    }

    /// A site's name.
    #[must_use]
    pub fn site_name(&self, site: usize) -> Option<&str> {
        self.model().id_to_name(MjtObjBase::mjOBJ_SITE, site)
    }

    /// A site's position in the world, metres.
    #[must_use]
    pub fn site_position(&self, site: usize) -> [f64; 3] {
        self.data.site_xpos().get(site).copied().unwrap_or([f64::NAN; 3])
    }

    /// The model's total mass, kg.
    #[must_use]
    pub fn total_mass(&self) -> f64 {
        self.model().totalmass()
    }

    /// A sensor's id by name.
    #[must_use]
    pub fn sensor(&self, name: &str) -> Option<usize> {
        self.model().name_to_id(MjtObjBase::mjOBJ_SENSOR, name)
    }

    /// A sensor's present values (after a step or `forward`): a gyro's angular velocity
    /// (rad/s) or an accelerometer's specific force (m/s²), in its site's frame.
    #[must_use]
    pub fn sensor_values(&self, sensor: usize) -> &[f64] {
        let (Some(&adr), Some(&dim)) = (
            self.model().sensor_adr().get(sensor),
            self.model().sensor_dim().get(sensor),
        ) else {
            return &[];
        };
        let (adr, dim) = (
            usize::try_from(adr).unwrap_or(0),
            usize::try_from(dim).unwrap_or(0),
        );
        self.data.sensordata().get(adr..adr + dim).unwrap_or(&[])
    }

    /// Number of contacts in the present state.
    #[must_use]
    pub fn contact_count(&self) -> usize {
        usize::try_from(self.data.ncon()).unwrap_or(0)
    }

    /// The contacts lower than `below` (world z, metres): each one's position and the vertical
    /// component of its force on the body above it, newtons (after a step or `forward`).
    #[must_use]
    pub fn floor_contacts(&self, below: f64) -> Vec<([f64; 3], f64)> {
        let n = self.contact_count();
        let contacts = self.data.contact();
        (0..n.min(contacts.len()))
            .filter(|&i| contacts[i].pos[2] < below)
            .filter_map(|i| {
                let c = &contacts[i];
                let f = self.data.try_contact_force(i).ok()?;
                // The force in the contact frame (rows: normal, two tangents) to world z.
                let fz = f[0] * c.frame[2] + f[1] * c.frame[5] + f[2] * c.frame[8];
                Some((c.pos, fz.abs()))
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const PENDULUM: &str = r#"
<mujoco>
  <option timestep="0.001"/>
  <worldbody>
    <body name="arm">
      <joint name="hinge" axis="0 1 0" damping="1.084" armature="0.045"/>
      <geom type="capsule" fromto="0 0 0 0.1 0 0" size="0.01" mass="0.1"/>
      <site name="tip" pos="0.1 0 0"/>
    </body>
  </worldbody>
  <actuator>
    <position name="servo" joint="hinge" kp="21.1" forcerange="-5 5"/>
  </actuator>
</mujoco>"#;

    #[test]
    fn a_position_actuator_moves_its_hinge_to_the_goal() {
        let mut w = World::from_xml_str(PENDULUM).unwrap();
        let a = w.actuator("servo").unwrap();
        let j = w.actuator_joint(a).unwrap();
        assert_eq!(w.joint_name(j), Some("hinge"));
        assert_eq!(w.force_range(a), Some((-5.0, 5.0)));
        assert_eq!(w.position_gain(a), 21.1);
        w.set_position_gain(a, 42.2);
        assert_eq!(w.position_gain(a), 42.2);
        w.set_ctrl(a, 0.5);
        for _ in 0..2000 {
            w.step();
        }
        // Gravity pulls the tip down (+q about y lowers +x) by m·g·(L/2)·cos q / kp.
        let q = w.joint_position(j);
        let sag = 0.1 * 9.81 * 0.05 * q.cos() / 42.2;
        assert!((q - (0.5 + sag)).abs() < 2e-4, "{q}");
        assert!((w.time() - 2.0).abs() < 1e-9);
        let tip = w.site_position(w.site("tip").unwrap());
        assert!((tip[0] - 0.1 * q.cos()).abs() < 1e-9 && (tip[2] + 0.1 * q.sin()).abs() < 1e-9);
    }

    #[test]
    fn bad_xml_is_an_error_with_mujocos_message() {
        let e = World::from_xml_str(
            "<mujoco><worldbody><body><joint type=\"nope\"/></body></worldbody></mujoco>",
        )
        .unwrap_err();
        assert!(!e.0.is_empty());
        assert!(World::from_file(Path::new("/nonexistent.xml")).is_err());
    }
}
