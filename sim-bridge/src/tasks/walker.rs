//! `dm_control/suite/walker.py`: PlanarWalker with `move_speed` 0 (stand), 1 (walk) or 8 (run).

use mujoco_rs::prelude::MjtObjBase;

use super::{Task, randomizers};
use crate::error::SimError;
use crate::numpy_rng::RandomState;
use crate::physics::Physics;
use crate::rewards::{Sigmoid, Tolerance};

pub(crate) const WALK_SPEED: f64 = 1.0;
pub(crate) const RUN_SPEED: f64 = 8.0;
const STAND_HEIGHT: f64 = 1.2;
const ZZ: usize = 8;
const XZ: usize = 2;
const XX: usize = 0;

pub(crate) struct PlanarWalker {
    move_speed: f64,
    torso: usize,
    nbody: usize,
    subtreelinvel: usize,
}

impl PlanarWalker {
    pub fn new(physics: &Physics, task: &'static str, move_speed: f64) -> Result<Self, SimError> {
        randomizers::check_planar(physics, task)?;
        let nbody = physics.model().ffi().nbody as usize;
        if nbody != 8 {
            return Err(SimError::ModelMismatch {
                task,
                detail: format!("{nbody} bodies, expected 8"),
            });
        }
        Ok(Self {
            move_speed,
            torso: physics.id(task, MjtObjBase::mjOBJ_BODY, "torso")?,
            nbody,
            subtreelinvel: physics.sensor_adr(task, "torso_subtreelinvel")?,
        })
    }

    fn torso_height(&self, physics: &Physics) -> f64 {
        physics.xpos(self.torso)[2]
    }
}

impl Task for PlanarWalker {
    fn initialize_episode(&mut self, physics: &mut Physics, random: &mut RandomState) {
        randomizers::randomize_limited_and_rotational_joints(physics, random);
    }

    fn observe(&self, physics: &Physics, obs: &mut [f64]) {
        // orientations: xmat[1:, ['xx', 'xz']].ravel() (14); height (1); velocity: qvel (9).
        for body in 1..self.nbody {
            let xmat = physics.xmat(body);
            obs[2 * (body - 1)] = xmat[XX];
            obs[2 * (body - 1) + 1] = xmat[XZ];
        }
        obs[14] = self.torso_height(physics);
        obs[15..24].copy_from_slice(physics.qvel());
    }

    fn reward(&self, physics: &Physics) -> f64 {
        let standing = Tolerance {
            bounds: (STAND_HEIGHT, f64::INFINITY),
            margin: STAND_HEIGHT / 2.0,
            ..Tolerance::default()
        }
        .eval(self.torso_height(physics));
        let upright = (1.0 + physics.xmat(self.torso)[ZZ]) / 2.0;
        let stand_reward = (3.0 * standing + upright) / 4.0;
        if self.move_speed == 0.0 {
            stand_reward
        } else {
            let move_reward = Tolerance {
                bounds: (self.move_speed, f64::INFINITY),
                margin: self.move_speed / 2.0,
                value_at_margin: 0.5,
                sigmoid: Sigmoid::Linear,
            }
            .eval(physics.sensordata()[self.subtreelinvel]);
            // Python evaluates `stand_reward * (5*move_reward + 1) / 6` left to right.
            stand_reward * (5.0 * move_reward + 1.0) / 6.0
        }
    }
}
