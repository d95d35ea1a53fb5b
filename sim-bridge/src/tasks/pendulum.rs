//! `dm_control/suite/pendulum.py`: SwingUp.

use mujoco_rs::prelude::MjtObjBase;

use super::Task;
use crate::error::SimError;
use crate::numpy_rng::RandomState;
use crate::physics::Physics;
use crate::rewards::tolerance;

const ZZ: usize = 8;
const XZ: usize = 2;
/// `_ANGLE_BOUND` in degrees; the reward is 1 within it of upright.
const ANGLE_BOUND: f64 = 8.0;

pub(crate) struct SwingUp {
    pole: usize,
    hinge_qpos: usize,
    hinge_dof: usize,
    /// `np.cos(np.deg2rad(_ANGLE_BOUND))`.
    cosine_bound: f64,
}

impl SwingUp {
    pub fn new(physics: &Physics, task: &'static str) -> Result<Self, SimError> {
        let hinge = physics.id(task, MjtObjBase::mjOBJ_JOINT, "hinge")?;
        Ok(Self {
            pole: physics.id(task, MjtObjBase::mjOBJ_BODY, "pole")?,
            hinge_qpos: physics.model().jnt_qposadr()[hinge] as usize,
            hinge_dof: physics.model().jnt_dofadr()[hinge] as usize,
            // numpy's deg2rad multiplies by pi/180, as `to_radians` does.
            cosine_bound: ANGLE_BOUND.to_radians().cos(),
        })
    }
}

impl Task for SwingUp {
    fn initialize_episode(&mut self, physics: &mut Physics, random: &mut RandomState) {
        use core::f64::consts::PI;
        physics.qpos_mut()[self.hinge_qpos] = random.uniform(-PI, PI);
    }

    fn observe(&self, physics: &Physics, obs: &mut [f64]) {
        // orientation: pole (zz, xz); velocity: qvel['hinge'].
        let xmat = physics.xmat(self.pole);
        obs[0] = xmat[ZZ];
        obs[1] = xmat[XZ];
        obs[2] = physics.qvel()[self.hinge_dof];
    }

    fn reward(&self, physics: &Physics) -> f64 {
        tolerance(physics.xmat(self.pole)[ZZ], (self.cosine_bound, 1.0), 0.0)
    }
}
