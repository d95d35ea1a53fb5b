//! A task file's logic bound to its model: the [`Task`] the environment runs.

use mujoco_rs::prelude::{MjtJoint, MjtObjBase};

use super::expr::{self, Expr, Statement};
use super::program::{BindError, Binder, Defines, Model, Op, Phase, Program, Src, State};
use crate::physics::{Physics, Sync};
use crate::task::{Random, Task};

/// A part of the file that failed to bind: which key, and why.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct KeyError {
    /// The key, e.g. `reward` or `observation 'touch'` or `init[2]`.
    pub key: String,
    /// One line: what is wrong and where.
    pub message: String,
}

/// What the file's text says, parsed (names not yet resolved).
#[derive(Clone, Debug)]
pub(crate) struct Parsed {
    pub defines: Defines,
    /// `(name, source, expression)` of each part, in order.
    pub observation: Vec<(String, String, Expr)>,
    pub reward: (String, Expr),
    pub terminate: Option<(String, Expr)>,
    pub init: Vec<(String, Statement)>,
}

fn located(key: &str, src: &str, e: expr::SyntaxError) -> KeyError {
    KeyError {
        key: key.to_string(),
        message: format!("{} in \"{src}\"", e),
    }
}

fn bind_error(key: &str, src: &str, e: BindError) -> KeyError {
    KeyError {
        key: key.to_string(),
        message: match e.pos {
            Some(p) => format!("{} (at character {} of \"{src}\")", e.message, p + 1),
            None => format!("{} (in \"{src}\")", e.message),
        },
    }
}

/// Parses every expression of the file (no model needed).
pub(crate) fn parse(t: &super::format::TaskToml) -> Result<Parsed, KeyError> {
    let mut defines = Defines::new();
    for (name, src) in &t.define {
        if !name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
            || name.starts_with(|c: char| c.is_ascii_digit())
        {
            return Err(KeyError {
                key: format!("define.{name}"),
                message: "a defined name is letters, digits and `_`, not starting with a digit"
                    .into(),
            });
        }
        let key = format!("define.{name}");
        if super::program::BUILTIN_NAMES.contains(&name.as_str()) {
            return Err(KeyError {
                key,
                message: format!(
                    "`{name}` is a built-in name (built-in names: {}); choose another",
                    super::program::BUILTIN_NAMES.join(", ")
                ),
            });
        }
        let e = expr::parse(src).map_err(|e| located(&key, src, e))?;
        defines.insert(name.clone(), (src.clone(), e));
    }
    let mut observation = Vec::new();
    for part in &t.observation {
        let key = format!("observation '{}'", part.name);
        if observation.iter().any(|(n, _, _)| *n == part.name) {
            return Err(KeyError {
                key,
                message: "two observation parts have this name".into(),
            });
        }
        let e = expr::parse(&part.value).map_err(|e| located(&key, &part.value, e))?;
        observation.push((part.name.clone(), part.value.clone(), e));
    }
    let reward_src = t.reward.as_deref().ok_or_else(|| KeyError {
        key: "reward".into(),
        message: "missing: every MuJoCo task needs a reward expression".into(),
    })?;
    let reward = (
        reward_src.to_string(),
        expr::parse(reward_src).map_err(|e| located("reward", reward_src, e))?,
    );
    let terminate = match &t.terminate {
        Some(s) => Some((
            s.clone(),
            expr::parse(s).map_err(|e| located("terminate", s, e))?,
        )),
        None => None,
    };
    let mut init = Vec::new();
    for (i, s) in t.init.iter().enumerate() {
        let key = format!("init[{i}]");
        let st = expr::parse_statement(s).map_err(|e| located(&key, s, e))?;
        init.push((s.clone(), st));
    }
    Ok(Parsed {
        defines,
        observation,
        reward,
        terminate,
        init,
    })
}

/// One initial-state statement, bound.
#[derive(Clone, Debug)]
enum Init {
    /// Nodes `range` of the init program compute `value`, written to `target` at `idx`.
    Assign {
        range: std::ops::Range<usize>,
        value: usize,
        target: Src,
        idx: Vec<usize>,
    },
    /// dm_control's `randomize_limited_and_rotational_joints` (hinge and slide joints).
    RandomizeLimitedAndRotational,
    /// dm_control cheetah's `qpos[is_limited] = uniform(lower, upper)`.
    RandomizeLimited,
    /// Physics steps with the task's stepping (cheetah settles for 200).
    Step(usize),
    /// The model's keyframe.
    Keyframe(usize),
}

/// The task logic of a file: observation, reward, termination and initial state as bound
/// programs, plus the action of the step being taken.
pub(crate) struct FileTask {
    prog: Program,
    obs: Vec<usize>,
    /// Each observation part's name (for messages).
    obs_names: Vec<String>,
    reward: usize,
    terminate: Option<usize>,
    init_prog: Program,
    init: Vec<Init>,
    /// The step's action in the actuators' units (what `action` reads).
    action: Vec<f64>,
    /// Physics steps per control step with the gymnasium convention (`step(n)` in init).
    gymnasium: bool,
    obs_dim: usize,
}

impl FileTask {
    /// Binds the parsed file to `physics`'s model.
    pub fn bind(
        parsed: &Parsed,
        physics: &Physics,
        dt: f64,
        act_dim: usize,
        gymnasium: bool,
    ) -> Result<Self, KeyError> {
        let m = physics.model();
        let model = Model {
            model: m,
            dt,
            act_dim,
        };
        let mut prog = Program::new();
        let mut b = Binder::new(&mut prog, &model, &parsed.defines, Phase::After);
        let mut obs = Vec::new();
        let obs_names = parsed
            .observation
            .iter()
            .map(|(n, _, _)| n.clone())
            .collect();
        for (name, src, e) in &parsed.observation {
            let key = format!("observation '{name}'");
            obs.push(b.bind(e).map_err(|err| bind_error(&key, src, err))?);
        }
        let (src, e) = &parsed.reward;
        let reward = b.bind(e).map_err(|err| bind_error("reward", src, err))?;
        let terminate = match &parsed.terminate {
            Some((src, e)) => Some(b.bind(e).map_err(|err| bind_error("terminate", src, err))?),
            None => None,
        };
        for (key, node) in [("reward", Some(reward)), ("terminate", terminate)] {
            if let Some(n) = node
                && prog.nodes[n].len != 1
            {
                return Err(KeyError {
                    key: key.into(),
                    message: format!(
                        "is {} numbers; it must be one (reduce it with sum(), mean(), min() or max())",
                        prog.nodes[n].len
                    ),
                });
            }
        }
        let obs_dim = obs.iter().map(|&i| prog.nodes[i].len).sum();
        let mut init_prog = Program::new();
        let mut init = Vec::new();
        for (i, (src, st)) in parsed.init.iter().enumerate() {
            let key = format!("init[{i}]");
            init.push(
                bind_init(&mut init_prog, &model, &parsed.defines, st)
                    .map_err(|err| bind_error(&key, src, err))?,
            );
        }
        Ok(Self {
            prog,
            obs,
            obs_names,
            reward,
            terminate,
            init_prog,
            init,
            action: vec![0.0; act_dim],
            gymnasium,
            obs_dim,
        })
    }

    /// Length of the observation.
    pub fn obs_dim(&self) -> usize {
        self.obs_dim
    }

    /// Each observation part's name and length, in order.
    pub fn obs_parts(&self) -> Vec<(String, usize)> {
        self.obs_names
            .iter()
            .zip(&self.obs)
            .map(|(n, &i)| (n.clone(), self.prog.nodes[i].len))
            .collect()
    }

    /// Whether the last evaluated state is terminal.
    pub fn terminated(&self) -> bool {
        self.terminate.is_some_and(|t| self.prog.value(t)[0] != 0.0)
    }

    fn evaluate(&mut self, phase: Phase, physics: &mut Physics) {
        if phase == Phase::After && self.prog.needs_subtree_vel {
            physics.subtree_vel();
        }
        let state = State {
            physics,
            action: &self.action,
        };
        self.prog.eval(phase, &state, None);
    }

    fn run_init(&mut self, physics: &mut Physics, random: &mut Random) {
        for k in 0..self.init.len() {
            match &self.init[k] {
                Init::Assign {
                    range,
                    value,
                    target,
                    idx,
                } => {
                    let state = State {
                        physics,
                        action: &self.action,
                    };
                    self.init_prog
                        .eval_range(range.clone(), &state, Some(random));
                    let v = self.init_prog.value(*value);
                    let dst: &mut [f64] = match target {
                        Src::Qpos => physics.qpos_mut(),
                        Src::Qvel => physics.qvel_mut(),
                        Src::Ctrl => physics.ctrl_mut(),
                        Src::Act => physics.act_mut(),
                        _ => {
                            physics.set_time(v[0]);
                            continue;
                        }
                    };
                    for (j, &d) in idx.iter().enumerate() {
                        dst[d] = v[if v.len() == 1 { 0 } else { j }];
                    }
                }
                Init::RandomizeLimitedAndRotational => {
                    crate::randomizers::randomize_limited_and_rotational_joints(physics, random)
                }
                Init::RandomizeLimited => {
                    let njnt = physics.model().jnt_limited().len();
                    for id in 0..njnt {
                        let model = physics.model();
                        if model.jnt_limited()[id] {
                            let [low, high] = model.jnt_range()[id];
                            let adr = model.jnt_qposadr()[id] as usize;
                            physics.qpos_mut()[adr] = random.uniform(low, high);
                        }
                    }
                }
                &Init::Step(n) => {
                    if self.gymnasium {
                        physics.step_gymnasium(n);
                    } else {
                        physics.step(n);
                    }
                }
                &Init::Keyframe(key) => physics.reset_keyframe(key),
            }
        }
    }
}

fn bind_init(
    prog: &mut Program,
    model: &Model<'_>,
    defines: &Defines,
    st: &Statement,
) -> Result<Init, BindError> {
    let err = |pos, m: String| BindError {
        pos: Some(pos),
        message: m,
    };
    match st {
        Statement::Call(Expr::Call {
            func, args, pos, ..
        }) => {
            let m = model.model;
            match func.as_str() {
                "randomize_limited_and_rotational_joints" => {
                    for (id, kind) in m.jnt_type().iter().enumerate() {
                        if !matches!(kind, MjtJoint::mjJNT_HINGE | MjtJoint::mjJNT_SLIDE) {
                            return Err(err(
                                *pos,
                                format!(
                                    "{func}(): joint '{}' is {kind:?}; only hinge and slide joints are supported",
                                    m.id_to_name(MjtObjBase::mjOBJ_JOINT, id).unwrap_or("?")
                                ),
                            ));
                        }
                    }
                    Ok(Init::RandomizeLimitedAndRotational)
                }
                "randomize_limited_joints" => {
                    if m.ffi().nq != m.ffi().njnt {
                        return Err(err(
                            *pos,
                            format!(
                                "{func}() needs one qpos entry per joint (nq == njnt), as dm_control's cheetah asserts"
                            ),
                        ));
                    }
                    Ok(Init::RandomizeLimited)
                }
                "step" | "keyframe" => {
                    let [a] = &args[..] else {
                        return Err(err(*pos, format!("{func}() takes one argument")));
                    };
                    if func == "keyframe" {
                        let Expr::Str(name, p) = a else {
                            return Err(err(
                                a.pos(),
                                "keyframe() takes the keyframe's name".into(),
                            ));
                        };
                        let ids = super::program::objects(
                            m,
                            MjtObjBase::mjOBJ_KEY,
                            &Expr::Str(name.clone(), *p),
                        )?;
                        let [id] = ids[..] else {
                            return Err(err(
                                a.pos(),
                                format!(
                                    "keyframe() takes one keyframe's name, not '{name}' ({})",
                                    super::program::names(m, MjtObjBase::mjOBJ_KEY)
                                ),
                            ));
                        };
                        return Ok(Init::Keyframe(id));
                    }
                    let mut b = Binder::new(prog, model, defines, Phase::Init);
                    let i = b.bind(a)?;
                    let v = match (&prog.nodes[i].op, prog.value(i)) {
                        (Op::Const, [v]) => *v,
                        _ => return Err(err(a.pos(), "step(n): n must be a constant".into())),
                    };
                    if v.fract() != 0.0 || !(1.0..=1e6).contains(&v) {
                        return Err(err(
                            a.pos(),
                            format!("step({v}): a whole number of steps from 1"),
                        ));
                    }
                    Ok(Init::Step(v as usize))
                }
                _ => Err(err(
                    *pos,
                    format!(
                        "unknown statement {func}() (randomize_limited_and_rotational_joints(), randomize_limited_joints(), step(n), keyframe('name'), or `target = value`)"
                    ),
                )),
            }
        }
        Statement::Call(e) => Err(err(e.pos(), "not a statement".into())),
        Statement::Assign { target, value } => {
            let start = prog.nodes.len();
            let mut b = Binder::new(prog, model, defines, Phase::Init);
            let t = b.bind(target)?;
            let v = b.bind(value)?;
            let (src, idx) = match &prog.nodes[t].op {
                Op::Gather(src, idx)
                    if matches!(
                        src,
                        Src::Qpos | Src::Qvel | Src::Ctrl | Src::Act | Src::Time
                    ) =>
                {
                    (*src, idx.to_vec())
                }
                _ => {
                    return Err(err(
                        target.pos(),
                        "the target must be qpos, qvel, ctrl, act or time, or a part of one (qpos('slider'), qvel[1:])".into(),
                    ));
                }
            };
            let (lt, lv) = (idx.len(), prog.nodes[v].len);
            if lv != 1 && lv != lt {
                return Err(err(
                    value.pos(),
                    format!("the value has {lv} numbers for a target of {lt}"),
                ));
            }
            Ok(Init::Assign {
                range: start..prog.nodes.len(),
                value: v,
                target: src,
                idx,
            })
        }
    }
}

impl Task for FileTask {
    fn initialize_episode(&mut self, physics: &mut Physics, random: &mut Random) {
        self.run_init(physics, random);
    }

    fn before_step(&mut self, physics: &mut Physics, action: &[f64]) {
        self.action.copy_from_slice(action);
        self.evaluate(Phase::Before, physics);
    }

    fn after_step(&mut self, physics: &mut Physics) {
        self.evaluate(Phase::After, physics);
    }

    fn observe(&self, _physics: &Physics, obs: &mut [f64]) {
        let mut k = 0;
        for &i in &self.obs {
            let v = self.prog.value(i);
            obs[k..k + v.len()].copy_from_slice(v);
            k += v.len();
        }
    }

    fn reward(&self, _physics: &Physics) -> f64 {
        self.prog.value(self.reward)[0]
    }

    fn terminated(&self) -> bool {
        FileTask::terminated(self)
    }

    fn observation_key(&self, index: usize) -> String {
        let mut start = 0;
        for (name, &i) in self.obs_names.iter().zip(&self.obs) {
            let len = self.prog.nodes[i].len;
            if index < start + len {
                return if len == 1 {
                    format!("observation '{name}'")
                } else {
                    format!("observation '{name}'[{}]", index - start)
                };
            }
            start += len;
        }
        "observation".into()
    }

    fn sync(&self) -> Sync {
        if self.prog.kinematic_only {
            Sync::Kinematics
        } else {
            Sync::Full
        }
    }
}
