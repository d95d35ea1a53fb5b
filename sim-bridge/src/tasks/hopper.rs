//! `dm_control/suite/hopper.py`: Hopper with `hopping` false (stand) or true (hop).

use mujoco_rs::prelude::MjtObjBase;

use super::{Task, randomizers, small_control};
use crate::error::SimError;
use crate::numpy_rng::RandomState;
use crate::physics::Physics;
use crate::rewards::{Sigmoid, Tolerance};

const STAND_HEIGHT: f64 = 0.6;
const HOP_SPEED: f64 = 2.0;

pub(crate) struct Hopper {
    hopping: bool,
    torso: usize,
    foot: usize,
    /// `sensordata` addresses of `torso_subtreelinvel`, `touch_toe`, `touch_heel`.
    subtreelinvel: usize,
    touch: [usize; 2],
}

impl Hopper {
    pub fn new(physics: &Physics, task: &'static str, hopping: bool) -> Result<Self, SimError> {
        randomizers::check_planar(physics, task)?;
        Ok(Self {
            hopping,
            torso: physics.id(task, MjtObjBase::mjOBJ_BODY, "torso")?,
            foot: physics.id(task, MjtObjBase::mjOBJ_BODY, "foot")?,
            subtreelinvel: physics.sensor_adr(task, "torso_subtreelinvel")?,
            touch: [
                physics.sensor_adr(task, "touch_toe")?,
                physics.sensor_adr(task, "touch_heel")?,
            ],
        })
    }

    /// Torso height above the foot (body centres of mass).
    fn height(&self, physics: &Physics) -> f64 {
        physics.xipos(self.torso)[2] - physics.xipos(self.foot)[2]
    }

    fn speed(&self, physics: &Physics) -> f64 {
        physics.sensordata()[self.subtreelinvel]
    }
}

impl Task for Hopper {
    fn initialize_episode(&mut self, physics: &mut Physics, random: &mut RandomState) {
        randomizers::randomize_limited_and_rotational_joints(physics, random);
    }

    fn observe(&self, physics: &Physics, obs: &mut [f64]) {
        // position: qpos[1:] (6); velocity: qvel (7); touch: log1p(touch sensors) (2).
        let qpos = physics.qpos();
        obs[..6].copy_from_slice(&qpos[1..]);
        obs[6..13].copy_from_slice(physics.qvel());
        let sensors = physics.sensordata();
        obs[13] = sensors[self.touch[0]].ln_1p();
        obs[14] = sensors[self.touch[1]].ln_1p();
    }

    fn reward(&self, physics: &Physics) -> f64 {
        let standing = Tolerance {
            bounds: (STAND_HEIGHT, 2.0),
            ..Tolerance::default()
        }
        .eval(self.height(physics));
        if self.hopping {
            let hopping = Tolerance {
                bounds: (HOP_SPEED, f64::INFINITY),
                margin: HOP_SPEED / 2.0,
                value_at_margin: 0.5,
                sigmoid: Sigmoid::Linear,
            }
            .eval(self.speed(physics));
            standing * hopping
        } else {
            // `.mean()` over the four actuators: numpy sums in order, then divides.
            let ctrl = physics.ctrl();
            let mut sum = 0.0;
            for &c in ctrl {
                sum += small_control(c);
            }
            let small_control = (sum / ctrl.len() as f64 + 4.0) / 5.0;
            standing * small_control
        }
    }
}
