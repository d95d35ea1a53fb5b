//! `dm_control/suite/utils/randomizers.py`: random joint configurations for hopper and walker.

use mujoco_rs::prelude::MjtJoint;

use crate::error::SimError;
use crate::numpy_rng::RandomState;
use crate::physics::Physics;

/// Checks that `randomize_limited_and_rotational_joints` needs only what is implemented here:
/// hinge and slide joints (the planar Control Suite bodies have no ball or free joints).
pub(crate) fn check_planar(physics: &Physics, task: &'static str) -> Result<(), SimError> {
    let model = physics.model();
    for (id, kind) in model.jnt_type().iter().enumerate() {
        if !matches!(kind, MjtJoint::mjJNT_HINGE | MjtJoint::mjJNT_SLIDE) {
            return Err(SimError::ModelMismatch {
                task,
                detail: format!("joint {id} is {kind:?}"),
            });
        }
    }
    Ok(())
}

/// `randomize_limited_and_rotational_joints` for hinge and slide joints, in joint order: a limited
/// joint is drawn uniformly in its range, an unlimited hinge in [-pi, pi), an unlimited slide is
/// left alone.
pub(crate) fn randomize_limited_and_rotational_joints(
    physics: &mut Physics,
    random: &mut RandomState,
) {
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
