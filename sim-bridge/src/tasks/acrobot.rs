//! `dm_control/suite/acrobot.py`: Balance with the smooth reward (swingup).

use mujoco_rs::prelude::MjtObjBase;

use super::Task;
use crate::error::SimError;
use crate::numpy_rng::RandomState;
use crate::physics::{Physics, Sync};
use crate::rewards::tolerance;

const ZZ: usize = 8;
const XZ: usize = 2;

pub(crate) struct Balance {
    upper_arm: usize,
    lower_arm: usize,
    /// `qpos` addresses of `shoulder` and `elbow`.
    joints: [usize; 2],
    target: usize,
    tip: usize,
    /// `site_size['target', 0]`, the reward's target radius.
    target_radius: f64,
}

impl Balance {
    pub fn new(physics: &Physics, task: &'static str) -> Result<Self, SimError> {
        let joint = |name| -> Result<usize, SimError> {
            let id = physics.id(task, MjtObjBase::mjOBJ_JOINT, name)?;
            Ok(physics.model().jnt_qposadr()[id] as usize)
        };
        let target = physics.id(task, MjtObjBase::mjOBJ_SITE, "target")?;
        Ok(Self {
            upper_arm: physics.id(task, MjtObjBase::mjOBJ_BODY, "upper_arm")?,
            lower_arm: physics.id(task, MjtObjBase::mjOBJ_BODY, "lower_arm")?,
            joints: [joint("shoulder")?, joint("elbow")?],
            target,
            tip: physics.id(task, MjtObjBase::mjOBJ_SITE, "tip")?,
            target_radius: physics.model().site_size()[target][0],
        })
    }

    /// Distance from the tip to the target (`np.linalg.norm`).
    fn to_target(&self, physics: &Physics) -> f64 {
        let target = physics.site_xpos(self.target);
        let tip = physics.site_xpos(self.tip);
        let d = [target[0] - tip[0], target[1] - tip[1], target[2] - tip[2]];
        (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()
    }
}

impl Task for Balance {
    fn initialize_episode(&mut self, physics: &mut Physics, random: &mut RandomState) {
        use core::f64::consts::PI;
        // `qpos[['shoulder', 'elbow']] = uniform(-pi, pi, 2)`.
        for adr in self.joints {
            physics.qpos_mut()[adr] = random.uniform(-PI, PI);
        }
    }

    fn observe(&self, physics: &Physics, obs: &mut [f64]) {
        // orientations: (horizontal: xz of both arms, vertical: zz of both arms); velocity: qvel.
        let upper = physics.xmat(self.upper_arm);
        let lower = physics.xmat(self.lower_arm);
        obs[0] = upper[XZ];
        obs[1] = lower[XZ];
        obs[2] = upper[ZZ];
        obs[3] = lower[ZZ];
        obs[4..6].copy_from_slice(physics.qvel());
    }

    /// Observation and reward read only qvel, body poses and site positions (RK4 model).
    fn sync(&self) -> Sync {
        Sync::Kinematics
    }

    fn reward(&self, physics: &Physics) -> f64 {
        tolerance(self.to_target(physics), (0.0, self.target_radius), 1.0)
    }
}
