//! `dm_control/suite/utils/randomizers.py`: random joint configurations (hopper and walker use
//! it; a task file calls it as `randomize_limited_and_rotational_joints()`).

use mujoco_rs::prelude::MjtJoint;

use crate::physics::Physics;
use crate::task::Random;

/// `randomize_limited_and_rotational_joints` for hinge and slide joints, in joint order: a limited
/// joint is drawn uniformly in its range, an unlimited hinge in [-pi, pi), an unlimited slide is
/// left alone.
pub(crate) fn randomize_limited_and_rotational_joints(physics: &mut Physics, random: &mut Random) {
    use core::f64::consts::PI;
    let njnt = physics.model().jnt_type().len();
    for id in 0..njnt {
        let model = physics.model();
        let kind = model.jnt_type()[id];
        let limited = model.jnt_limited()[id];
        let [low, high] = model.jnt_range()[id];
        let adr = model.jnt_qposadr()[id] as usize;
        let value = match (limited, kind) {
            (true, _) => random.uniform(low, high),
            (false, MjtJoint::mjJNT_HINGE) => random.uniform(-PI, PI),
            _ => continue,
        };
        physics.qpos_mut()[adr] = value;
    }
}
