//! One MuJoCo model + data, stepped with dm_control's call sequence.
//!
//! Bit-identical states need the same sequence of MuJoCo calls as dm_control's
//! `mujoco.Physics` (`dm_control/mujoco/engine.py`), not just the same model:
//! - construction and `reset` run `mj_forward` with actuation disabled (no meaningful controls
//!   yet), after `mj_resetData` for a reset;
//! - a control step is the "legacy step": with the Euler integrator `mj_step2` (finishing the
//!   `mj_step1` of the previous step), `mj_step` x (n - 1), then `mj_step1`; with RK4
//!   `mj_step` x n, then `mj_step1`. Position- and velocity-dependent fields are therefore current
//!   after a step, while acceleration-stage sensors (hopper's touch) lag one substep, exactly as in
//!   dm_control.

use mujoco_rs::mujoco_c::{mjtDisableBit, mjtIntegrator};
use mujoco_rs::prelude::{MjData, MjModel};

use crate::assets;
use crate::error::SimError;

/// The names of MuJoCo's warning counters (`mjtWarning`), in index order.
const WARNING_NAMES: [&str; WARNINGS] = [
    "mjWARN_INERTIA",
    "mjWARN_CONTACTFULL",
    "mjWARN_CNSTRFULL",
    "mjWARN_BADQPOS",
    "mjWARN_BADQVEL",
    "mjWARN_BADQACC",
    "mjWARN_BADCTRL",
];
/// `mjNWARNING`.
pub const WARNINGS: usize = 7;

/// How much of `mjData` a control step brings up to date for the new state.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Sync {
    /// dm_control's final `mj_step1`: every position- and velocity-dependent field.
    Full,
    /// Only `mj_kinematics` (body and site poses) after an RK4 step. The next RK4 `mj_step` starts
    /// with a full `mj_forward`, so the state trajectory is unchanged; tasks whose observation and
    /// reward read only poses, `qpos`, `qvel` and `ctrl` (cartpole, acrobot) skip the rest of the
    /// `mj_step1` work. With the Euler integrator the full `mj_step1` is always run: the next
    /// `mj_step2` builds on it.
    Kinematics,
}

/// A loaded Control Suite model and its simulation state.
pub struct Physics {
    data: MjData<Box<MjModel>>,
    rk4: bool,
}

impl std::fmt::Debug for Physics {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Physics")
            .field("rk4", &self.rk4)
            .finish_non_exhaustive()
    }
}

impl Physics {
    /// Loads `<domain>.xml` from the suite directory and, like dm_control's constructor, runs a
    /// forward pass with actuation disabled.
    pub fn load(domain: &str) -> Result<Self, SimError> {
        Ok(Self::from_model(assets::load_model(domain)?))
    }

    /// [`Physics::load`] of a suite file named with its extension (`cartpole.xml`).
    pub fn load_suite(file: &str) -> Result<Self, SimError> {
        Ok(Self::from_model(assets::load_suite_file(file)?))
    }

    /// An MJCF file from disk, with the same forward pass.
    pub fn load_file(path: &std::path::Path) -> Result<Self, SimError> {
        Ok(Self::from_model(assets::load_model_file(path)?))
    }

    fn from_model(model: MjModel) -> Self {
        let data = MjData::new(Box::new(model));
        let rk4 = data.model_opt().integrator == mjtIntegrator::mjINT_RK4 as i32;
        let mut physics = Self { data, rk4 };
        physics.forward_without_actuation();
        physics
    }

    pub fn model(&self) -> &MjModel {
        self.data.model()
    }

    pub fn data(&self) -> &MjData<Box<MjModel>> {
        &self.data
    }

    /// `mj_forward` with the actuation flag disabled (`with model.disable('actuation')`).
    pub fn forward_without_actuation(&mut self) {
        let opt = self.data.model_opt_mut();
        let saved = opt.disableflags;
        opt.disableflags = saved | mjtDisableBit::mjDSBL_ACTUATION as i32;
        self.data.forward();
        self.data.model_opt_mut().disableflags = saved;
    }

    /// dm_control's `Physics.reset()`: `mj_resetData`, then a forward pass without actuation.
    pub fn reset(&mut self) {
        self.data.reset();
        self.forward_without_actuation();
    }

    /// dm_control's legacy `Physics.step(n)` (see the module documentation).
    pub fn step(&mut self, n_sub_steps: usize) {
        self.step_synced(n_sub_steps, Sync::Full);
    }

    /// The legacy step, ending with the given [`Sync`] instead of always `mj_step1`.
    pub fn step_synced(&mut self, n_sub_steps: usize, sync: Sync) {
        if self.rk4 {
            for _ in 0..n_sub_steps {
                self.data.step();
            }
            match sync {
                Sync::Full => self.data.step1(),
                Sync::Kinematics => self.data.kinematics(),
            }
        } else {
            self.data.step2();
            for _ in 1..n_sub_steps {
                self.data.step();
            }
            self.data.step1();
        }
    }

    /// Gymnasium's `MujocoEnv` step: `mj_step` x n, then `mj_rnePostConstraint` (so
    /// `cacc`, `cfrc_int` and `cfrc_ext` are current; positions are those of the last
    /// substep's forward pass, as Gymnasium reads them).
    pub fn step_gymnasium(&mut self, n_sub_steps: usize) {
        for _ in 0..n_sub_steps {
            self.data.step();
        }
        self.data.rne_post_constraint();
    }

    /// `mj_forward` (Gymnasium's `set_state` after writing the initial state).
    pub fn forward(&mut self) {
        self.data.forward();
    }

    /// `mj_subtreeVel`: brings `subtree_linvel` up to date (it changes no state).
    pub fn subtree_vel(&mut self) {
        self.data.subtree_vel();
    }

    /// `mj_resetDataKeyframe`.
    pub fn reset_keyframe(&mut self, key: usize) {
        self.data
            .reset_keyframe(key)
            .expect("keyframe ids are checked when the task is bound");
    }

    pub fn act_mut(&mut self) -> &mut [f64] {
        self.data.act_mut()
    }

    /// Plain `mj_step` x n: the baseline the benchmark compares the legacy step against.
    pub fn raw_step(&mut self, n_sub_steps: usize) {
        for _ in 0..n_sub_steps {
            self.data.step();
        }
    }

    /// MuJoCo's warning counters (`data.warning[i].number`).
    pub fn warning_counts(&self) -> [i32; WARNINGS] {
        let warnings = &self.data.ffi().warning;
        core::array::from_fn(|i| warnings[i].number)
    }

    /// The names of the warnings whose counters grew since `before`, or None. dm_control treats
    /// any new warning during a step as an invalid physics state (`PhysicsError`).
    pub fn new_warnings(&self, before: &[i32; WARNINGS]) -> Option<String> {
        let after = self.warning_counts();
        let names: Vec<&str> = (0..WARNINGS)
            .filter(|&i| after[i] > before[i])
            .map(|i| WARNING_NAMES[i])
            .collect();
        (!names.is_empty()).then(|| names.join(", "))
    }

    pub fn timestep(&self) -> f64 {
        self.data.model_opt().timestep
    }

    pub fn qpos(&self) -> &[f64] {
        self.data.qpos()
    }

    pub fn qpos_mut(&mut self) -> &mut [f64] {
        self.data.qpos_mut()
    }

    pub fn qvel(&self) -> &[f64] {
        self.data.qvel()
    }

    pub fn qvel_mut(&mut self) -> &mut [f64] {
        self.data.qvel_mut()
    }

    pub fn ctrl(&self) -> &[f64] {
        self.data.ctrl()
    }

    pub fn ctrl_mut(&mut self) -> &mut [f64] {
        self.data.ctrl_mut()
    }

    pub fn set_time(&mut self, time: f64) {
        // SAFETY: `time` is a plain number that no MuJoCo invariant depends on.
        unsafe { self.data.ffi_mut().time = time };
    }

    /// Body orientation, row-major 3x3 (`xmat[body]`: `xx xy xz yx yy yz zx zy zz`).
    pub fn xmat(&self, body: usize) -> &[f64; 9] {
        &self.data.xmat()[body]
    }

    pub fn xpos(&self, body: usize) -> &[f64; 3] {
        &self.data.xpos()[body]
    }

    pub fn xipos(&self, body: usize) -> &[f64; 3] {
        &self.data.xipos()[body]
    }

    pub fn site_xpos(&self, site: usize) -> &[f64; 3] {
        &self.data.site_xpos()[site]
    }

    pub fn sensordata(&self) -> &[f64] {
        self.data.sensordata()
    }
}
