//! `dm_control/suite/cartpole.py`: Balance with `swing_up` false (balance) or true (swingup),
//! smooth (non-sparse) reward, one pole.

use mujoco_rs::prelude::MjtObjBase;

use super::{Task, small_control};
use crate::error::SimError;
use crate::numpy_rng::RandomState;
use crate::physics::{Physics, Sync};
use crate::rewards::tolerance;

/// Row-major `xmat` indices of the `zz` and `xz` entries.
const ZZ: usize = 8;
const XZ: usize = 2;

pub(crate) struct Balance {
    swing_up: bool,
    /// `qpos` address of the `slider` joint (the cart position).
    slider: usize,
    /// `qpos` address of `hinge_1`.
    hinge: usize,
    /// Body id of `pole_1` (dm_control reads `xmat[2:]`, the poles).
    pole: usize,
}

impl Balance {
    pub fn new(physics: &Physics, task: &'static str, swing_up: bool) -> Result<Self, SimError> {
        let adr = |name| -> Result<usize, SimError> {
            let id = physics.id(task, MjtObjBase::mjOBJ_JOINT, name)?;
            Ok(physics.model().jnt_qposadr()[id] as usize)
        };
        let pole = physics.id(task, MjtObjBase::mjOBJ_BODY, "pole_1")?;
        if pole != 2 || physics.qvel().len() != 2 {
            return Err(SimError::ModelMismatch {
                task,
                detail: "expected one pole".into(),
            });
        }
        Ok(Self {
            swing_up,
            slider: adr("slider")?,
            hinge: adr("hinge_1")?,
            pole,
        })
    }

    fn cart_position(&self, physics: &Physics) -> f64 {
        physics.qpos()[self.slider]
    }

    fn pole_angle_cosine(&self, physics: &Physics) -> f64 {
        physics.xmat(self.pole)[ZZ]
    }
}

impl Task for Balance {
    fn initialize_episode(&mut self, physics: &mut Physics, random: &mut RandomState) {
        let nv = physics.qvel().len();
        if self.swing_up {
            physics.qpos_mut()[self.slider] = 0.01 * random.standard_normal();
            physics.qpos_mut()[self.hinge] =
                core::f64::consts::PI + 0.01 * random.standard_normal();
            // `qpos[2:] = .1 * randn(nv - 2)`: no further poles, no draws.
        } else {
            physics.qpos_mut()[self.slider] = random.uniform(-0.1, 0.1);
            // `qpos[1:] = uniform(-.034, .034, nv - 1)`.
            for i in 1..nv {
                physics.qpos_mut()[i] = random.uniform(-0.034, 0.034);
            }
        }
        for i in 0..nv {
            physics.qvel_mut()[i] = 0.01 * random.standard_normal();
        }
    }

    fn observe(&self, physics: &Physics, obs: &mut [f64]) {
        // position: (cart, pole zz, pole xz); velocity: qvel.
        let xmat = physics.xmat(self.pole);
        obs[0] = self.cart_position(physics);
        obs[1] = xmat[ZZ];
        obs[2] = xmat[XZ];
        obs[3..5].copy_from_slice(physics.qvel());
    }

    /// Observation and reward read only qpos, qvel, ctrl and the pole pose (RK4 model).
    fn sync(&self) -> Sync {
        Sync::Kinematics
    }

    fn reward(&self, physics: &Physics) -> f64 {
        let upright = (self.pole_angle_cosine(physics) + 1.0) / 2.0;
        let centered = (1.0 + tolerance(self.cart_position(physics), (0.0, 0.0), 2.0)) / 2.0;
        let small_control = (4.0 + small_control(physics.ctrl()[0])) / 5.0;
        // `tolerance(angular_vel, margin=5).min()` over the single pole.
        let small_velocity = (1.0 + tolerance(physics.qvel()[1], (0.0, 0.0), 5.0)) / 2.0;
        upright * small_control * small_velocity * centered
    }
}
