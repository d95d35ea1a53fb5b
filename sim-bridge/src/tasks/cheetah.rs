//! `dm_control/suite/cheetah.py`: Cheetah (run).

use super::Task;
use crate::error::SimError;
use crate::numpy_rng::RandomState;
use crate::physics::Physics;
use crate::rewards::{Sigmoid, Tolerance};

const RUN_SPEED: f64 = 10.0;
/// dm_control lets the randomly posed cheetah settle for 200 physics steps before the episode.
const SETTLE_STEPS: usize = 200;

pub(crate) struct Cheetah {
    subtreelinvel: usize,
}

impl Cheetah {
    pub fn new(physics: &Physics, task: &'static str) -> Result<Self, SimError> {
        let model = physics.model().ffi();
        // dm_control asserts this: the limited joints' qpos addresses are their joint ids.
        if model.nq != model.njnt {
            return Err(SimError::ModelMismatch {
                task,
                detail: "nq != njnt".into(),
            });
        }
        Ok(Self {
            subtreelinvel: physics.sensor_adr(task, "torso_subtreelinvel")?,
        })
    }
}

impl Task for Cheetah {
    fn initialize_episode(&mut self, physics: &mut Physics, random: &mut RandomState) {
        // `qpos[is_limited] = uniform(lower, upper)`: one draw per limited joint, in joint order.
        let njnt = physics.model().jnt_limited().len();
        for id in 0..njnt {
            let model = physics.model();
            if model.jnt_limited()[id] {
                let [low, high] = model.jnt_range()[id];
                physics.qpos_mut()[id] = random.uniform(low, high);
            }
        }
        // `physics.step(nstep=200)` (the legacy step sequence, from the reset forward pass's
        // state), then `data.time = 0`.
        physics.step(SETTLE_STEPS);
        physics.set_time(0.0);
    }

    fn observe(&self, physics: &Physics, obs: &mut [f64]) {
        // position: qpos[1:] (8); velocity: qvel (9).
        obs[..8].copy_from_slice(&physics.qpos()[1..]);
        obs[8..17].copy_from_slice(physics.qvel());
    }

    fn reward(&self, physics: &Physics) -> f64 {
        Tolerance {
            bounds: (RUN_SPEED, f64::INFINITY),
            margin: RUN_SPEED,
            value_at_margin: 0.0,
            sigmoid: Sigmoid::Linear,
        }
        .eval(physics.sensordata()[self.subtreelinvel])
    }
}
