//! Task-file expressions bound to a loaded model and evaluated without allocating.
//!
//! Binding resolves every name (a joint, a body, a sensor, a defined quantity) to indices
//! into MuJoCo's arrays once, infers every value's length, folds constants, and lays the
//! expressions out as a flat list of nodes in evaluation order (children before parents,
//! left to right, as Python evaluates). Each node owns a fixed slice of one `f64` buffer, so
//! evaluating is one pass over the nodes writing their slices: nothing is allocated after
//! binding.
//!
//! Arithmetic is done operation by operation in `f64` as numpy does it for these shapes
//! (scalar and short-vector operations, `np.sum`'s pairwise summation, dm_control's
//! `tolerance`), so a task written as a file gives the bits of the same task written in
//! Python or Rust.

use std::collections::BTreeMap;

use mujoco_rs::prelude::{MjModel, MjtJoint, MjtObjBase};

use super::expr::{BinOp, Expr, Index, Pos, UnOp};
use crate::physics::Physics;
use crate::rewards::{Sigmoid, Tolerance};
use crate::task::Random;

/// A binding error: what is wrong, and where in the expression when known.
#[derive(Clone, Debug, PartialEq)]
pub struct BindError {
    /// Byte offset in the expression.
    pub pos: Option<Pos>,
    /// The message.
    pub message: String,
}

impl BindError {
    fn at(pos: Pos, message: impl Into<String>) -> Self {
        Self {
            pos: Some(pos),
            message: message.into(),
        }
    }
}

type Result<T> = std::result::Result<T, BindError>;

/// A state array of `mjData` (or the step's action) that expressions read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Src {
    Qpos,
    Qvel,
    Qacc,
    Ctrl,
    Act,
    Action,
    Sensordata,
    QfrcConstraint,
    QfrcActuator,
    ActuatorForce,
    Xpos,
    Xmat,
    Xquat,
    Xipos,
    Ximat,
    SubtreeCom,
    SubtreeLinvel,
    Cvel,
    SiteXpos,
    SiteXmat,
    GeomXpos,
    GeomXmat,
    Time,
}

impl Src {
    /// True for what `mj_kinematics` (or the state itself) keeps current: an RK4 task that
    /// reads only these may skip the rest of the final `mj_step1` (see [`crate::physics::Sync`]).
    fn kinematic(self) -> bool {
        use Src::*;
        matches!(
            self,
            Qpos | Qvel
                | Ctrl
                | Action
                | Time
                | Xpos
                | Xmat
                | Xquat
                | Xipos
                | Ximat
                | SiteXpos
                | SiteXmat
                | GeomXpos
                | GeomXmat
        )
    }
}

/// The data a node reads from: the physics and the action of the step being taken.
pub(crate) struct State<'a> {
    pub physics: &'a Physics,
    pub action: &'a [f64],
}

impl State<'_> {
    fn slice(&self, s: Src) -> &[f64] {
        let d = self.physics.data();
        match s {
            Src::Qpos => d.qpos(),
            Src::Qvel => d.qvel(),
            Src::Qacc => d.qacc(),
            Src::Ctrl => d.ctrl(),
            Src::Act => d.act(),
            Src::Action => self.action,
            Src::Sensordata => d.sensordata(),
            Src::QfrcConstraint => d.qfrc_constraint(),
            Src::QfrcActuator => d.qfrc_actuator(),
            Src::ActuatorForce => d.actuator_force(),
            Src::Xpos => d.xpos().as_flattened(),
            Src::Xmat => d.xmat().as_flattened(),
            Src::Xquat => d.xquat().as_flattened(),
            Src::Xipos => d.xipos().as_flattened(),
            Src::Ximat => d.ximat().as_flattened(),
            Src::SubtreeCom => d.subtree_com().as_flattened(),
            Src::SubtreeLinvel => d.subtree_linvel().as_flattened(),
            Src::Cvel => d.cvel().as_flattened(),
            Src::SiteXpos => d.site_xpos().as_flattened(),
            Src::SiteXmat => d.site_xmat().as_flattened(),
            Src::GeomXpos => d.geom_xpos().as_flattened(),
            Src::GeomXmat => d.geom_xmat().as_flattened(),
            Src::Time => std::slice::from_ref(&d.ffi().time),
        }
    }
}

/// Elementwise functions of one value.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Fn1 {
    Neg,
    Not,
    Abs,
    Sqrt,
    Exp,
    Log,
    Log1p,
    Sin,
    Cos,
    Tan,
    Tanh,
    Arctan,
    Square,
    Sign,
    Radians,
}

impl Fn1 {
    fn apply(self, x: f64) -> f64 {
        match self {
            Fn1::Neg => -x,
            Fn1::Not => f64::from(x == 0.0),
            Fn1::Abs => x.abs(),
            Fn1::Sqrt => x.sqrt(),
            Fn1::Exp => x.exp(),
            Fn1::Log => x.ln(),
            Fn1::Log1p => x.ln_1p(),
            Fn1::Sin => x.sin(),
            Fn1::Cos => x.cos(),
            Fn1::Tan => x.tan(),
            Fn1::Tanh => x.tanh(),
            Fn1::Arctan => x.atan(),
            Fn1::Square => x * x,
            Fn1::Sign => {
                if x > 0.0 {
                    1.0
                } else if x < 0.0 {
                    -1.0
                } else {
                    x
                }
            }
            // numpy's deg2rad multiplies by pi/180, as `to_radians` does.
            Fn1::Radians => x.to_radians(),
        }
    }
}

/// Elementwise functions of two values (broadcasting a scalar against a vector).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Fn2 {
    Bin(BinOp),
    Min,
    Max,
    Arctan2,
}

impl Fn2 {
    fn apply(self, a: f64, b: f64) -> f64 {
        match self {
            Fn2::Bin(op) => match op {
                BinOp::Add => a + b,
                BinOp::Sub => a - b,
                BinOp::Mul => a * b,
                BinOp::Div => a / b,
                // Python's `float ** float` and numpy's scalar `**`: the C library's `pow`,
                // also for `x ** 2` (glibc's `pow(x, 2)` differs from `x * x` in about one
                // case in a thousand; `square(x)` is `x * x`, numpy's `np.square`).
                BinOp::Pow => a.powf(b),
                BinOp::Lt => f64::from(a < b),
                BinOp::Le => f64::from(a <= b),
                BinOp::Gt => f64::from(a > b),
                BinOp::Ge => f64::from(a >= b),
                BinOp::Eq => f64::from(a == b),
                BinOp::Ne => f64::from(a != b),
                BinOp::And => f64::from(a != 0.0 && b != 0.0),
                BinOp::Or => f64::from(a != 0.0 || b != 0.0),
            },
            // np.minimum / np.maximum: NaN propagates.
            Fn2::Min => {
                if a.is_nan() || b.is_nan() {
                    f64::NAN
                } else {
                    a.min(b)
                }
            }
            Fn2::Max => {
                if a.is_nan() || b.is_nan() {
                    f64::NAN
                } else {
                    a.max(b)
                }
            }
            Fn2::Arctan2 => a.atan2(b),
        }
    }
}

/// Reductions of a vector to a scalar.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Red {
    Sum,
    Mean,
    Min,
    Max,
    Prod,
    Norm,
}

/// `np.sum` of a contiguous float64 vector: numpy's pairwise summation (a plain loop below 8
/// elements, 8 interleaved partial sums up to 128, halves above).
pub(crate) fn np_sum(a: &[f64]) -> f64 {
    let n = a.len();
    if n < 8 {
        let mut s = 0.0;
        for &x in a {
            s += x;
        }
        s
    } else if n <= 128 {
        let mut r = [0.0; 8];
        r.copy_from_slice(&a[..8]);
        let mut i = 8;
        while i < n - n % 8 {
            for (j, rj) in r.iter_mut().enumerate() {
                *rj += a[i + j];
            }
            i += 8;
        }
        let mut s = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]));
        for &x in &a[i..] {
            s += x;
        }
        s
    } else {
        let mut n2 = n / 2;
        n2 -= n2 % 8;
        np_sum(&a[..n2]) + np_sum(&a[n2..])
    }
}

impl Red {
    fn apply(self, a: &[f64]) -> f64 {
        match self {
            Red::Sum => np_sum(a),
            Red::Mean => np_sum(a) / a.len() as f64,
            Red::Min => a.iter().fold(f64::INFINITY, |m, &x| Fn2::Min.apply(m, x)),
            Red::Max => a
                .iter()
                .fold(f64::NEG_INFINITY, |m, &x| Fn2::Max.apply(m, x)),
            Red::Prod => a.iter().fold(1.0, |p, &x| p * x),
            // In order, as a plain loop (dm_control's acrobot distance, three terms).
            Red::Norm => a.iter().fold(0.0, |s, &x| s + x * x).sqrt(),
        }
    }
}

/// What a node computes.
#[derive(Clone, Debug)]
pub(crate) enum Op {
    /// Its slice was filled at binding.
    Const,
    /// Elements of a state array.
    Gather(Src, Box<[usize]>),
    /// Elements of another node.
    Pick(usize, Box<[usize]>),
    /// Other nodes one after another.
    Concat(Box<[usize]>),
    Map(Fn1, usize),
    Zip(Fn2, usize, usize),
    Reduce(Red, usize),
    Tolerance(Tolerance, usize),
    Clip(usize, usize, usize),
    Where(usize, usize, usize),
    /// `prev(x)`: the value node `x` had before the step (it is evaluated then).
    Copy(usize),
    /// A body's linear (or angular) velocity, in its own frame or the world's
    /// (`mj_objectVelocity`).
    Velocity {
        body: usize,
        local: bool,
        linear: bool,
    },
    /// `uniform(low, high, n)`: the task stream's `uniform`, element by element.
    Uniform(usize, usize),
    /// `normal(loc, scale, n)`: `loc + scale * g` for each of the stream's Gaussians `g`.
    Normal(usize, usize),
    /// `randn(n)`: the Gaussians themselves.
    Randn,
}

/// One value of the program: what it computes and where its elements live.
#[derive(Clone, Debug)]
pub(crate) struct Node {
    pub op: Op,
    pub off: usize,
    pub len: usize,
    /// When it is evaluated: before the step (`prev` arguments), after it, or in the
    /// initial state.
    pub phase: Phase,
}

/// Bound nodes and their values.
#[derive(Clone, Debug, Default)]
pub(crate) struct Program {
    pub nodes: Vec<Node>,
    pub vals: Vec<f64>,
    /// The program reads `subtree_linvel` (`mj_subtreeVel` must run first).
    pub needs_subtree_vel: bool,
    /// Every state array read is kept current by `mj_kinematics` (see [`Src::kinematic`]).
    pub kinematic_only: bool,
    /// It draws random numbers (only initial-state statements may).
    pub random: bool,
}

impl Program {
    pub fn new() -> Self {
        Self {
            kinematic_only: true,
            ..Self::default()
        }
    }

    /// The value of node `i`.
    pub fn value(&self, i: usize) -> &[f64] {
        let n = &self.nodes[i];
        &self.vals[n.off..n.off + n.len]
    }

    fn push(&mut self, op: Op, len: usize, phase: Phase) -> usize {
        let off = self.vals.len();
        self.vals.resize(off + len, 0.0);
        self.nodes.push(Node {
            op,
            off,
            len,
            phase,
        });
        self.nodes.len() - 1
    }

    fn constant(&mut self, v: &[f64]) -> usize {
        let i = self.push(Op::Const, v.len(), Phase::After);
        let off = self.nodes[i].off;
        self.vals[off..off + v.len()].copy_from_slice(v);
        i
    }

    fn is_const(&self, i: usize) -> bool {
        matches!(self.nodes[i].op, Op::Const)
    }

    /// Evaluates the nodes of `phase`, in order. `random` is needed iff one of them draws.
    pub fn eval(&mut self, phase: Phase, state: &State<'_>, mut random: Option<&mut Random>) {
        for i in 0..self.nodes.len() {
            if self.nodes[i].phase == phase {
                self.eval_node(i, Some(state), random.as_deref_mut());
            }
        }
    }

    /// Evaluates nodes `range` in order (one initial-state statement).
    pub fn eval_range(
        &mut self,
        range: std::ops::Range<usize>,
        state: &State<'_>,
        mut random: Option<&mut Random>,
    ) {
        for i in range {
            self.eval_node(i, Some(state), random.as_deref_mut());
        }
    }

    /// Evaluates node `i` (its inputs are current). `state` is only read by nodes that read
    /// the simulation; constant folding passes None for nodes of constants.
    fn eval_node(&mut self, i: usize, state: Option<&State<'_>>, random: Option<&mut Random>) {
        let (off, len) = (self.nodes[i].off, self.nodes[i].len);
        {
            match &self.nodes[i].op {
                Op::Const => {}
                Op::Gather(src, idx) => {
                    let s = state
                        .expect("a state node folded as a constant")
                        .slice(*src);
                    for (k, &j) in idx.iter().enumerate() {
                        self.vals[off + k] = s[j];
                    }
                }
                Op::Pick(a, idx) => {
                    let ao = self.nodes[*a].off;
                    for (k, &j) in idx.iter().enumerate() {
                        self.vals[off + k] = self.vals[ao + j];
                    }
                }
                Op::Concat(parts) => {
                    let mut k = off;
                    for &p in parts.iter() {
                        let (po, pl) = (self.nodes[p].off, self.nodes[p].len);
                        self.vals.copy_within(po..po + pl, k);
                        k += pl;
                    }
                }
                &Op::Map(f, a) => {
                    let ao = self.nodes[a].off;
                    for k in 0..len {
                        self.vals[off + k] = f.apply(self.vals[ao + k]);
                    }
                }
                &Op::Zip(f, a, b) => {
                    let (na, nb) = (&self.nodes[a], &self.nodes[b]);
                    let (ao, sa) = (na.off, usize::from(na.len > 1));
                    let (bo, sb) = (nb.off, usize::from(nb.len > 1));
                    for k in 0..len {
                        self.vals[off + k] =
                            f.apply(self.vals[ao + k * sa], self.vals[bo + k * sb]);
                    }
                }
                &Op::Reduce(r, a) => {
                    let (ao, al) = (self.nodes[a].off, self.nodes[a].len);
                    self.vals[off] = r.apply(&self.vals[ao..ao + al]);
                }
                &Op::Tolerance(t, a) => {
                    let ao = self.nodes[a].off;
                    for k in 0..len {
                        self.vals[off + k] = t.eval(self.vals[ao + k]);
                    }
                }
                &Op::Clip(a, lo, hi) => {
                    let get = |p: &Self, n: usize, k: usize| {
                        let nd = &p.nodes[n];
                        p.vals[nd.off + if nd.len > 1 { k } else { 0 }]
                    };
                    for k in 0..len {
                        let (x, l, h) = (get(self, a, k), get(self, lo, k), get(self, hi, k));
                        // np.clip: minimum(maximum(x, lo), hi).
                        self.vals[off + k] = Fn2::Min.apply(Fn2::Max.apply(x, l), h);
                    }
                }
                &Op::Where(c, a, b) => {
                    let get = |p: &Self, n: usize, k: usize| {
                        let nd = &p.nodes[n];
                        p.vals[nd.off + if nd.len > 1 { k } else { 0 }]
                    };
                    for k in 0..len {
                        let v = if get(self, c, k) != 0.0 {
                            get(self, a, k)
                        } else {
                            get(self, b, k)
                        };
                        self.vals[off + k] = v;
                    }
                }
                &Op::Copy(a) => {
                    let ao = self.nodes[a].off;
                    self.vals.copy_within(ao..ao + len, off);
                }
                &Op::Velocity {
                    body,
                    local,
                    linear,
                } => {
                    let v = state
                        .expect("a state node folded as a constant")
                        .physics
                        .data()
                        .object_velocity(MjtObjBase::mjOBJ_BODY, body, local);
                    let part = if linear { &v[3..] } else { &v[..3] };
                    self.vals[off..off + 3].copy_from_slice(part);
                }
                Op::Randn => {
                    let rng = random.expect("a random node outside the initial state");
                    for k in 0..len {
                        self.vals[off + k] = rng.standard_normal();
                    }
                }
                &Op::Uniform(lo, hi) | &Op::Normal(lo, hi) => {
                    let normal = matches!(self.nodes[i].op, Op::Normal(..));
                    let rng = random.expect("a random node outside the initial state");
                    for k in 0..len {
                        let get = |n: usize| {
                            let nd = &self.nodes[n];
                            self.vals[nd.off + if nd.len > 1 { k } else { 0 }]
                        };
                        let (a, b) = (get(lo), get(hi));
                        self.vals[off + k] = if normal {
                            a + b * rng.standard_normal()
                        } else {
                            rng.uniform(a, b)
                        };
                    }
                }
            }
        }
    }
}

/// Which part of a step a binding is for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Phase {
    /// Observation, reward and termination after the step.
    After,
    /// `prev(...)` arguments, evaluated before the step.
    Before,
    /// Initial-state statements (may draw random numbers).
    Init,
}

/// The model facts that binding reads.
pub(crate) struct Model<'a> {
    pub model: &'a MjModel,
    /// Seconds per control step.
    pub dt: f64,
    /// Action size (the actuators the action drives).
    pub act_dim: usize,
}

/// Names a file may define, each with its source text and expression (defines may use one
/// another).
pub(crate) type Defines = BTreeMap<String, (String, Expr)>;

/// Definitions may use definitions this deep (binding recurses through them).
const MAX_DEFINE_DEPTH: usize = 64;

/// Binds expressions into one [`Program`], each define once per phase.
pub(crate) struct Binder<'a> {
    pub prog: &'a mut Program,
    pub model: &'a Model<'a>,
    pub defines: &'a Defines,
    /// The phase of the nodes being bound (`prev(...)` binds its argument as `Before`).
    pub phase: Phase,
    memo: BTreeMap<(String, bool), usize>,
    stack: Vec<String>,
}

/// Shape of a per-object field: its state array, elements per object and component names.
struct Field {
    src: Src,
    kind: MjtObjBase,
    width: usize,
}

const XYZ: [&str; 3] = ["x", "y", "z"];
const MAT: [&str; 9] = ["xx", "xy", "xz", "yx", "yy", "yz", "zx", "zy", "zz"];
const QUAT: [&str; 4] = ["w", "x", "y", "z"];

fn field(name: &str) -> Option<Field> {
    use mujoco_rs::mujoco_c::_mjtObjBase::*;
    let (src, kind, width) = match name {
        "xpos" => (Src::Xpos, mjOBJ_BODY, 3),
        "xmat" => (Src::Xmat, mjOBJ_BODY, 9),
        "xquat" => (Src::Xquat, mjOBJ_BODY, 4),
        "xipos" => (Src::Xipos, mjOBJ_BODY, 3),
        "ximat" => (Src::Ximat, mjOBJ_BODY, 9),
        "subtree_com" => (Src::SubtreeCom, mjOBJ_BODY, 3),
        "subtree_linvel" => (Src::SubtreeLinvel, mjOBJ_BODY, 3),
        "cvel" => (Src::Cvel, mjOBJ_BODY, 6),
        "site_xpos" => (Src::SiteXpos, mjOBJ_SITE, 3),
        "site_xmat" => (Src::SiteXmat, mjOBJ_SITE, 9),
        "geom_xpos" => (Src::GeomXpos, mjOBJ_GEOM, 3),
        "geom_xmat" => (Src::GeomXmat, mjOBJ_GEOM, 9),
        _ => return None,
    };
    Some(Field { src, kind, width })
}

/// The state arrays addressed by joint, actuator or sensor (a whole array when called
/// without a name, or named bare: `qvel`).
fn array(name: &str) -> Option<(Src, MjtObjBase)> {
    use mujoco_rs::mujoco_c::_mjtObjBase::*;
    Some(match name {
        "qpos" => (Src::Qpos, mjOBJ_JOINT),
        "qvel" => (Src::Qvel, mjOBJ_JOINT),
        "qacc" => (Src::Qacc, mjOBJ_JOINT),
        "qfrc_constraint" => (Src::QfrcConstraint, mjOBJ_JOINT),
        "qfrc_actuator" => (Src::QfrcActuator, mjOBJ_JOINT),
        "ctrl" => (Src::Ctrl, mjOBJ_ACTUATOR),
        "act" => (Src::Act, mjOBJ_ACTUATOR),
        "actuator_force" => (Src::ActuatorForce, mjOBJ_ACTUATOR),
        "sensordata" | "sensor" => (Src::Sensordata, mjOBJ_SENSOR),
        _ => return None,
    })
}

/// The names an expression gives a meaning of its own (constants, the step's action and
/// time, the state arrays, the operators' words): a definition may not take one.
pub(crate) const BUILTIN_NAMES: &[&str] = &[
    "pi",
    "e",
    "inf",
    "dt",
    "timestep",
    "nq",
    "nv",
    "nu",
    "nbody",
    "time",
    "action",
    "qpos",
    "qvel",
    "qacc",
    "qfrc_constraint",
    "qfrc_actuator",
    "ctrl",
    "act",
    "actuator_force",
    "sensordata",
    "sensor",
    "and",
    "or",
    "not",
];

/// Every function a file may call, for the "unknown function" message.
pub(crate) const FUNCTIONS: &[&str] = &[
    "qpos",
    "qvel",
    "qacc",
    "qfrc_constraint",
    "qfrc_actuator",
    "ctrl",
    "act",
    "actuator_force",
    "sensor",
    "xpos",
    "xmat",
    "xquat",
    "xipos",
    "ximat",
    "subtree_com",
    "subtree_linvel",
    "cvel",
    "site_xpos",
    "site_xmat",
    "geom_xpos",
    "geom_xmat",
    "body_linvel",
    "body_angvel",
    "site_size",
    "geom_size",
    "body_mass",
    "body_subtreemass",
    "jnt_range",
    "ctrlrange",
    "abs",
    "sqrt",
    "exp",
    "log",
    "log1p",
    "sin",
    "cos",
    "tan",
    "tanh",
    "arctan",
    "square",
    "sign",
    "radians",
    "arctan2",
    "minimum",
    "maximum",
    "sum",
    "mean",
    "min",
    "max",
    "prod",
    "norm",
    "tolerance",
    "clip",
    "where",
    "concat",
    "prev",
    "uniform",
    "randn",
    "normal",
];

fn kind_name(k: MjtObjBase) -> &'static str {
    use mujoco_rs::mujoco_c::_mjtObjBase::*;
    match k {
        mjOBJ_BODY => "body",
        mjOBJ_JOINT => "joint",
        mjOBJ_SITE => "site",
        mjOBJ_GEOM => "geom",
        mjOBJ_ACTUATOR => "actuator",
        mjOBJ_SENSOR => "sensor",
        mjOBJ_KEY => "keyframe",
        _ => "object",
    }
}

/// How many objects of a kind the model has.
fn count(m: &MjModel, k: MjtObjBase) -> usize {
    use mujoco_rs::mujoco_c::_mjtObjBase::*;
    let f = m.ffi();
    (match k {
        mjOBJ_BODY => f.nbody,
        mjOBJ_JOINT => f.njnt,
        mjOBJ_SITE => f.nsite,
        mjOBJ_GEOM => f.ngeom,
        mjOBJ_ACTUATOR => f.nu,
        mjOBJ_SENSOR => f.nsensor,
        mjOBJ_KEY => f.nkey,
        _ => 0,
    }) as usize
}

/// The names of the objects of a kind, for error messages (the first 50; a line stays
/// readable for a large model).
pub(crate) fn names(m: &MjModel, k: MjtObjBase) -> String {
    const SHOWN: usize = 50;
    let n = count(m, k);
    let v: Vec<String> = (0..n.min(SHOWN))
        .map(|i| m.id_to_name(k, i).unwrap_or("(unnamed)").to_string())
        .collect();
    let more = if n > SHOWN {
        format!(", and {} more", n - SHOWN)
    } else {
        String::new()
    };
    let kinds = match kind_name(k) {
        "body" => "bodies".to_string(),
        kind => format!("{kind}s"),
    };
    if v.is_empty() {
        format!("the model has no {kinds}")
    } else {
        format!("{kinds}: {}{more}", v.join(", "))
    }
}

/// Object ids named by `sel`: a name, a list of names, or `'*'` (every object of the kind,
/// the world body excepted, as dm_control's `[1:]`).
pub(crate) fn objects(m: &MjModel, k: MjtObjBase, sel: &Expr) -> Result<Vec<usize>> {
    let one = |name: &str, pos: Pos| -> Result<usize> {
        if name.contains('\0') {
            return Err(BindError::at(pos, "a name cannot contain a NUL character"));
        }
        m.name_to_id(k, name).ok_or_else(|| {
            BindError::at(
                pos,
                format!("no {} named '{name}' ({})", kind_name(k), names(m, k)),
            )
        })
    };
    match sel {
        Expr::Str(s, _) if s == "*" => {
            let from = usize::from(k == MjtObjBase::mjOBJ_BODY);
            Ok((from..count(m, k)).collect())
        }
        Expr::Str(s, p) => Ok(vec![one(s, *p)?]),
        Expr::List(items, _) => items
            .iter()
            .map(|e| match e {
                Expr::Str(s, p) => one(s, *p),
                e => Err(BindError::at(
                    e.pos(),
                    format!("expected a {} name", kind_name(k)),
                )),
            })
            .collect(),
        e => Err(BindError::at(
            e.pos(),
            format!("expected a {} name, a list of names, or '*'", kind_name(k)),
        )),
    }
}

/// `(start, len)` in `src` of object `id` (a joint's qpos or dof entries, an actuator's
/// entry, a sensor's values).
fn span(m: &MjModel, src: Src, id: usize) -> (usize, usize) {
    let qpos_len = |t: MjtJoint| match t {
        MjtJoint::mjJNT_FREE => 7,
        MjtJoint::mjJNT_BALL => 4,
        _ => 1,
    };
    let dof_len = |t: MjtJoint| match t {
        MjtJoint::mjJNT_FREE => 6,
        MjtJoint::mjJNT_BALL => 3,
        _ => 1,
    };
    match src {
        Src::Qpos => (m.jnt_qposadr()[id] as usize, qpos_len(m.jnt_type()[id])),
        Src::Qvel | Src::Qacc | Src::QfrcConstraint | Src::QfrcActuator => {
            (m.jnt_dofadr()[id] as usize, dof_len(m.jnt_type()[id]))
        }
        Src::Sensordata => (m.sensor_adr()[id] as usize, m.sensor_dim()[id] as usize),
        Src::Act => {
            let adr = m.actuator_actadr()[id];
            if adr < 0 {
                (0, 0)
            } else {
                (adr as usize, m.actuator_actnum()[id] as usize)
            }
        }
        _ => (id, 1),
    }
}

fn state_len(m: &MjModel, src: Src) -> usize {
    let f = m.ffi();
    (match src {
        Src::Qpos => f.nq,
        Src::Qvel | Src::Qacc | Src::QfrcConstraint | Src::QfrcActuator => f.nv,
        Src::Ctrl | Src::ActuatorForce | Src::Action => f.nu,
        Src::Act => f.na,
        Src::Sensordata => f.nsensordata,
        Src::Time => 1,
        _ => 0,
    }) as usize
}

/// A string argument's text.
fn string(e: &Expr, what: &str) -> Result<String> {
    match e {
        Expr::Str(s, _) => Ok(s.clone()),
        e => Err(BindError::at(e.pos(), format!("{what} must be a string"))),
    }
}

fn sigmoid(name: &str, pos: Pos) -> Result<Sigmoid> {
    Ok(match name {
        "gaussian" => Sigmoid::Gaussian,
        "hyperbolic" => Sigmoid::Hyperbolic,
        "long_tail" => Sigmoid::LongTail,
        "reciprocal" => Sigmoid::Reciprocal,
        "cosine" => Sigmoid::Cosine,
        "linear" => Sigmoid::Linear,
        "quadratic" => Sigmoid::Quadratic,
        "tanh_squared" => Sigmoid::TanhSquared,
        _ => {
            return Err(BindError::at(
                pos,
                format!(
                    "unknown sigmoid '{name}' (gaussian, hyperbolic, long_tail, reciprocal, cosine, linear, quadratic, tanh_squared)"
                ),
            ));
        }
    })
}

/// Resolves a Python-style index (negative from the end) against a length.
fn resolve_index(v: f64, len: usize, pos: Pos, slice_bound: bool) -> Result<usize> {
    if v.fract() != 0.0 || !v.is_finite() {
        return Err(BindError::at(pos, format!("index {v} is not an integer")));
    }
    let i = if v < 0.0 { len as f64 + v } else { v };
    if slice_bound {
        // Slices clamp, as Python's do.
        return Ok(i.clamp(0.0, len as f64) as usize);
    }
    if i < 0.0 || i >= len as f64 {
        return Err(BindError::at(
            pos,
            format!("index {v} is out of range for a value of {len} elements"),
        ));
    }
    Ok(i as usize)
}

impl<'a> Binder<'a> {
    pub fn new(
        prog: &'a mut Program,
        model: &'a Model<'a>,
        defines: &'a Defines,
        phase: Phase,
    ) -> Self {
        Self {
            prog,
            model,
            defines,
            phase,
            memo: BTreeMap::new(),
            stack: Vec::new(),
        }
    }

    fn m(&self) -> &MjModel {
        self.model.model
    }

    /// A constant's value (folded at binding), or an error naming what must be constant.
    fn constant(&mut self, e: &Expr, what: &str) -> Result<Vec<f64>> {
        let i = self.bind(e)?;
        if !self.prog.is_const(i) {
            return Err(BindError::at(
                e.pos(),
                format!("{what} must be a constant (numbers and model constants only)"),
            ));
        }
        Ok(self.prog.value(i).to_vec())
    }

    fn scalar_constant(&mut self, e: &Expr, what: &str) -> Result<f64> {
        let v = self.constant(e, what)?;
        match v[..] {
            [x] => Ok(x),
            _ => Err(BindError::at(e.pos(), format!("{what} must be one number"))),
        }
    }

    /// Folds node `i` if every input is constant (evaluating it once now).
    fn fold(&mut self, i: usize, inputs: &[usize]) -> usize {
        let random = matches!(
            self.prog.nodes[i].op,
            Op::Uniform(..) | Op::Normal(..) | Op::Randn
        );
        if random || !inputs.iter().all(|&j| self.prog.is_const(j)) {
            return i;
        }
        // A node of constants reads no state: evaluate it once, now.
        self.prog.eval_node(i, None, None);
        self.prog.nodes[i].op = Op::Const;
        i
    }

    /// Binds an expression; returns its node.
    pub fn bind(&mut self, e: &Expr) -> Result<usize> {
        match e {
            Expr::Num(v, _) => Ok(self.prog.constant(&[*v])),
            Expr::Str(s, p) => Err(BindError::at(
                *p,
                format!(
                    "the string '{s}' is not a value here (names go inside a call, e.g. qpos('{s}'))"
                ),
            )),
            Expr::List(items, _) => {
                let parts = items
                    .iter()
                    .map(|x| self.bind(x))
                    .collect::<Result<Vec<_>>>()?;
                self.concat(parts)
            }
            Expr::Name(n, p) => self.name(n, *p),
            Expr::Unary(op, x, _) => {
                let a = self.bind(x)?;
                let f = match op {
                    UnOp::Neg => Fn1::Neg,
                    UnOp::Not => Fn1::Not,
                };
                Ok(self.map(f, a))
            }
            Expr::Binary(op, l, r, p) => {
                let (a, b) = (self.bind(l)?, self.bind(r)?);
                self.zip(Fn2::Bin(*op), a, b, *p)
            }
            Expr::Index { base, index, pos } => {
                let a = self.bind(base)?;
                let len = self.prog.nodes[a].len;
                let idx = self.index(index, len, *pos)?;
                self.pick(a, idx)
            }
            Expr::Call {
                func,
                args,
                kwargs,
                pos,
            } => self.call(func, args, kwargs, *pos),
        }
    }

    fn concat(&mut self, parts: Vec<usize>) -> Result<usize> {
        if parts.len() == 1 {
            return Ok(parts[0]);
        }
        let len = parts.iter().map(|&p| self.prog.nodes[p].len).sum();
        let i = self
            .prog
            .push(Op::Concat(parts.clone().into()), len, self.phase);
        Ok(self.fold(i, &parts))
    }

    fn map(&mut self, f: Fn1, a: usize) -> usize {
        let i = self
            .prog
            .push(Op::Map(f, a), self.prog.nodes[a].len, self.phase);
        self.fold(i, &[a])
    }

    fn zip(&mut self, f: Fn2, a: usize, b: usize, pos: Pos) -> Result<usize> {
        let (la, lb) = (self.prog.nodes[a].len, self.prog.nodes[b].len);
        let len = match (la, lb) {
            (x, y) if x == y => x,
            (1, y) => y,
            (x, 1) => x,
            _ => {
                return Err(BindError::at(
                    pos,
                    format!(
                        "operands of {la} and {lb} elements (one must be a single number, or both the same length)"
                    ),
                ));
            }
        };
        let i = self.prog.push(Op::Zip(f, a, b), len, self.phase);
        Ok(self.fold(i, &[a, b]))
    }

    fn pick(&mut self, a: usize, idx: Vec<usize>) -> Result<usize> {
        // Picking from a gather is a narrower gather.
        if let Op::Gather(src, from) = &self.prog.nodes[a].op {
            let g = idx.iter().map(|&k| from[k]).collect::<Vec<_>>();
            let src = *src;
            return Ok(self
                .prog
                .push(Op::Gather(src, g.into()), idx.len(), self.phase));
        }
        let i = self
            .prog
            .push(Op::Pick(a, idx.clone().into()), idx.len(), self.phase);
        Ok(self.fold(i, &[a]))
    }

    fn index(&mut self, index: &Index, len: usize, pos: Pos) -> Result<Vec<usize>> {
        match index {
            Index::At(e) => {
                let v = self.scalar_constant(e, "an index")?;
                Ok(vec![resolve_index(v, len, e.pos(), false)?])
            }
            Index::Slice(lo, hi) => {
                let mut bound = |b: &Option<Box<Expr>>, default: usize| -> Result<usize> {
                    match b {
                        None => Ok(default),
                        Some(e) => {
                            let v = self.scalar_constant(e, "a slice bound")?;
                            resolve_index(v, len, e.pos(), true)
                        }
                    }
                };
                let (a, b) = (bound(lo, 0)?, bound(hi, len)?);
                if a >= b {
                    return Err(BindError::at(
                        pos,
                        format!("the slice selects nothing of {len} elements"),
                    ));
                }
                Ok((a..b).collect())
            }
        }
    }

    fn gather(&mut self, src: Src, idx: Vec<usize>) -> usize {
        self.prog.kinematic_only &= src.kinematic();
        self.prog.needs_subtree_vel |= src == Src::SubtreeLinvel;
        let n = idx.len();
        self.prog.push(Op::Gather(src, idx.into()), n, self.phase)
    }

    fn name(&mut self, n: &str, p: Pos) -> Result<usize> {
        let m = self.m();
        let f = m.ffi();
        let c = |v: f64| Ok::<_, BindError>(Some(v));
        let constant = match n {
            "pi" => c(std::f64::consts::PI)?,
            "e" => c(std::f64::consts::E)?,
            "inf" => c(f64::INFINITY)?,
            "dt" => c(self.model.dt)?,
            "timestep" => c(m.opt().timestep)?,
            "nq" => c(f.nq as f64)?,
            "nv" => c(f.nv as f64)?,
            "nu" => c(f.nu as f64)?,
            "nbody" => c(f.nbody as f64)?,
            _ => None,
        };
        if let Some(v) = constant {
            return Ok(self.prog.constant(&[v]));
        }
        if n == "time" {
            return Ok(self.gather(Src::Time, vec![0]));
        }
        if n == "action" {
            if self.phase == Phase::Init {
                return Err(BindError::at(
                    p,
                    "`action` is not defined in the initial state",
                ));
            }
            return Ok(self.gather(Src::Action, (0..self.model.act_dim).collect()));
        }
        if let Some((src, _)) = array(n) {
            let len = state_len(self.m(), src);
            return Ok(self.gather(src, (0..len).collect()));
        }
        if let Some((src, e)) = self.defines.get(n) {
            return self.define(n, src, e, p);
        }
        Err(BindError::at(
            p,
            format!(
                "unknown name `{n}`: not a defined quantity ({}), a constant (pi, e, inf, dt, timestep, nq, nv, nu, nbody) or a state array (qpos, qvel, qacc, ctrl, act, sensordata, action, time)",
                if self.defines.is_empty() {
                    "this file defines none".to_string()
                } else {
                    self.defines.keys().cloned().collect::<Vec<_>>().join(", ")
                }
            ),
        ))
    }

    fn define(&mut self, n: &str, src: &str, e: &Expr, p: Pos) -> Result<usize> {
        let key = (n.to_string(), self.phase == Phase::Before);
        if let Some(&i) = self.memo.get(&key) {
            return Ok(i);
        }
        if self.stack.len() >= MAX_DEFINE_DEPTH {
            return Err(BindError::at(
                p,
                format!(
                    "definitions nested deeper than {MAX_DEFINE_DEPTH} (`{n}` inside {})",
                    self.stack.join(" -> ")
                ),
            ));
        }
        if self.stack.iter().any(|s| s == n) {
            return Err(BindError::at(
                p,
                format!(
                    "`{n}` is defined in terms of itself ({} -> {n})",
                    self.stack.join(" -> ")
                ),
            ));
        }
        self.stack.push(n.to_string());
        // An error inside the definition points into the definition's text (the innermost
        // definition's, with the chain of names that led there).
        const CONTEXT: &str = "in the definition of ";
        let r = self.bind(e).map_err(|err| BindError {
            pos: Some(p),
            message: match (err.message.strip_prefix(CONTEXT), err.pos) {
                (Some(inner), _) => format!("{CONTEXT}`{n}` -> {inner}"),
                (None, Some(q)) => format!(
                    "{CONTEXT}`{n}` (\"{src}\", at character {}): {}",
                    q + 1,
                    err.message
                ),
                (None, None) => format!("{CONTEXT}`{n}` (\"{src}\"): {}", err.message),
            },
        });
        self.stack.pop();
        let i = r?;
        self.memo.insert(key, i);
        Ok(i)
    }

    fn call(
        &mut self,
        func: &str,
        args: &[Expr],
        kwargs: &[(String, Expr)],
        pos: Pos,
    ) -> Result<usize> {
        let arity = |lo: usize, hi: usize| -> Result<()> {
            if args.len() < lo || args.len() > hi {
                let want = if lo == hi {
                    format!("{lo}")
                } else {
                    format!("{lo} to {hi}")
                };
                return Err(BindError::at(
                    pos,
                    format!(
                        "{func}() takes {want} positional arguments, got {}",
                        args.len()
                    ),
                ));
            }
            Ok(())
        };
        let allowed = |names: &[&str]| -> Result<()> {
            for (k, v) in kwargs {
                if !names.contains(&k.as_str()) {
                    return Err(BindError::at(
                        v.pos(),
                        format!(
                            "{func}() has no keyword argument `{k}`{}",
                            if names.is_empty() {
                                String::new()
                            } else {
                                format!(" (it takes {})", names.join(", "))
                            }
                        ),
                    ));
                }
            }
            Ok(())
        };
        if let Some(f) = field(func) {
            allowed(&[])?;
            return self.field(func, &f, args, pos);
        }
        if let Some((src, kind)) = array(func) {
            allowed(&[])?;
            arity(if func == "sensor" { 1 } else { 0 }, 1)?;
            let m = self.m();
            let idx = match args.first() {
                None => (0..state_len(m, src)).collect(),
                Some(sel) => {
                    let mut idx = Vec::new();
                    for id in objects(m, kind, sel)? {
                        let (start, len) = span(m, src, id);
                        idx.extend(start..start + len);
                    }
                    idx
                }
            };
            if src == Src::Act && idx.is_empty() {
                return Err(BindError::at(
                    pos,
                    "act(): no actuator with activation state",
                ));
            }
            return Ok(self.gather(src, idx));
        }
        let one = |s: &mut Self| -> Result<usize> {
            arity(1, 1)?;
            allowed(&[])?;
            s.bind(&args[0])
        };
        let f1 = match func {
            "abs" => Some(Fn1::Abs),
            "sqrt" => Some(Fn1::Sqrt),
            "exp" => Some(Fn1::Exp),
            "log" => Some(Fn1::Log),
            "log1p" => Some(Fn1::Log1p),
            "sin" => Some(Fn1::Sin),
            "cos" => Some(Fn1::Cos),
            "tan" => Some(Fn1::Tan),
            "tanh" => Some(Fn1::Tanh),
            "arctan" => Some(Fn1::Arctan),
            "square" => Some(Fn1::Square),
            "sign" => Some(Fn1::Sign),
            "radians" => Some(Fn1::Radians),
            _ => None,
        };
        if let Some(f) = f1 {
            let a = one(self)?;
            return Ok(self.map(f, a));
        }
        let red = match func {
            "sum" => Some(Red::Sum),
            "mean" => Some(Red::Mean),
            "prod" => Some(Red::Prod),
            "norm" => Some(Red::Norm),
            "min" if args.len() == 1 => Some(Red::Min),
            "max" if args.len() == 1 => Some(Red::Max),
            _ => None,
        };
        if let Some(r) = red {
            let a = one(self)?;
            let i = self.prog.push(Op::Reduce(r, a), 1, self.phase);
            return Ok(self.fold(i, &[a]));
        }
        match func {
            "minimum" | "maximum" | "arctan2" | "min" | "max" => {
                arity(2, 2)?;
                allowed(&[])?;
                let f = match func {
                    "minimum" | "min" => Fn2::Min,
                    "maximum" | "max" => Fn2::Max,
                    _ => Fn2::Arctan2,
                };
                let (a, b) = (self.bind(&args[0])?, self.bind(&args[1])?);
                self.zip(f, a, b, pos)
            }
            "concat" => {
                allowed(&[])?;
                let parts = args
                    .iter()
                    .map(|x| self.bind(x))
                    .collect::<Result<Vec<_>>>()?;
                if parts.is_empty() {
                    return Err(BindError::at(pos, "concat() of nothing"));
                }
                self.concat(parts)
            }
            "tolerance" => self.tolerance(args, kwargs, pos),
            "clip" | "where" => {
                arity(3, 3)?;
                allowed(&[])?;
                let v = args
                    .iter()
                    .map(|x| self.bind(x))
                    .collect::<Result<Vec<_>>>()?;
                let len = v.iter().map(|&i| self.prog.nodes[i].len).max().unwrap_or(1);
                for (&i, e) in v.iter().zip(args) {
                    let l = self.prog.nodes[i].len;
                    if l != 1 && l != len {
                        return Err(BindError::at(
                            e.pos(),
                            format!("{func}(): arguments of {l} and {len} elements"),
                        ));
                    }
                }
                let op = if func == "clip" {
                    Op::Clip(v[0], v[1], v[2])
                } else {
                    Op::Where(v[0], v[1], v[2])
                };
                let i = self.prog.push(op, len, self.phase);
                Ok(self.fold(i, &v))
            }
            "prev" => self.prev(args, pos, &arity),
            "uniform" | "normal" | "randn" => self.random(func, args, kwargs, pos),
            "body_linvel" | "body_angvel" => {
                arity(1, 1)?;
                allowed(&["frame"])?;
                let local = match kwargs.first() {
                    None => true,
                    Some((_, v)) => match string(v, "frame")?.as_str() {
                        "local" => true,
                        "world" => false,
                        other => {
                            return Err(BindError::at(
                                v.pos(),
                                format!(
                                    "frame '{other}': 'local' (the body's own axes) or 'world'"
                                ),
                            ));
                        }
                    },
                };
                let ids = objects(self.m(), MjtObjBase::mjOBJ_BODY, &args[0])?;
                let [body] = ids[..] else {
                    return Err(BindError::at(
                        args[0].pos(),
                        format!("{func}() takes one body"),
                    ));
                };
                self.prog.kinematic_only = false;
                Ok(self.prog.push(
                    Op::Velocity {
                        body,
                        local,
                        linear: func == "body_linvel",
                    },
                    3,
                    self.phase,
                ))
            }
            "site_size" | "geom_size" | "body_mass" | "body_subtreemass" | "jnt_range"
            | "ctrlrange" => {
                arity(1, 1)?;
                allowed(&[])?;
                let v = self.model_constant(func, &args[0])?;
                Ok(self.prog.constant(&v))
            }
            _ => Err(BindError::at(
                pos,
                format!(
                    "unknown function {func}() (functions: {})",
                    FUNCTIONS.join(", ")
                ),
            )),
        }
    }

    /// `xmat('torso', 'zz')`, `xpos(['a', 'b'])`, `xmat('*', 'xx', 'xz')`: per object, the
    /// named components in the order given (all of them when none is named).
    fn field(&mut self, func: &str, f: &Field, args: &[Expr], pos: Pos) -> Result<usize> {
        let Some(sel) = args.first() else {
            return Err(BindError::at(
                pos,
                format!(
                    "{func}() needs a {} name (or a list of names, or '*')",
                    kind_name(f.kind)
                ),
            ));
        };
        let ids = objects(self.m(), f.kind, sel)?;
        let comp_names: &[&str] = match f.width {
            3 => &XYZ,
            4 => &QUAT,
            9 => &MAT,
            _ => &[],
        };
        let mut comps = Vec::new();
        for a in &args[1..] {
            let s = string(a, "a component")?;
            match comp_names.iter().position(|c| *c == s) {
                Some(k) => comps.push(k),
                None => {
                    return Err(BindError::at(
                        a.pos(),
                        format!(
                            "{func}() has no component '{s}'{}",
                            if comp_names.is_empty() {
                                " (index it instead, e.g. [0])".to_string()
                            } else {
                                format!(" (components: {})", comp_names.join(", "))
                            }
                        ),
                    ));
                }
            }
        }
        if comps.is_empty() {
            comps = (0..f.width).collect();
        }
        let idx = ids
            .iter()
            .flat_map(|&id| comps.iter().map(move |&k| id * f.width + k))
            .collect();
        Ok(self.gather(f.src, idx))
    }

    fn model_constant(&mut self, func: &str, sel: &Expr) -> Result<Vec<f64>> {
        use mujoco_rs::mujoco_c::_mjtObjBase::*;
        let m = self.model.model;
        let kind = match func {
            "site_size" => mjOBJ_SITE,
            "geom_size" => mjOBJ_GEOM,
            "body_mass" | "body_subtreemass" => mjOBJ_BODY,
            "jnt_range" => mjOBJ_JOINT,
            _ => mjOBJ_ACTUATOR,
        };
        let ids = objects(m, kind, sel)?;
        let mut v = Vec::new();
        for id in ids {
            match func {
                "site_size" => v.extend(m.site_size()[id]),
                "geom_size" => v.extend(m.geom_size()[id]),
                "body_mass" => v.push(m.body_mass()[id]),
                "body_subtreemass" => v.push(m.body_subtreemass()[id]),
                "jnt_range" => v.extend(m.jnt_range()[id]),
                _ => v.extend(m.actuator_ctrlrange()[id]),
            }
        }
        Ok(v)
    }

    fn tolerance(&mut self, args: &[Expr], kwargs: &[(String, Expr)], pos: Pos) -> Result<usize> {
        const KEYS: [&str; 4] = ["bounds", "margin", "sigmoid", "value_at_margin"];
        if args.is_empty() || args.len() > 1 + KEYS.len() {
            return Err(BindError::at(
                pos,
                "tolerance(x, bounds=(0, 0), margin=0, sigmoid='gaussian', value_at_margin=0.1)",
            ));
        }
        let x = self.bind(&args[0])?;
        let mut given: Vec<(&str, &Expr)> = KEYS.iter().copied().zip(&args[1..]).collect();
        for (k, v) in kwargs {
            if !KEYS.contains(&k.as_str()) {
                return Err(BindError::at(
                    v.pos(),
                    format!(
                        "tolerance() has no keyword argument `{k}` (it takes bounds, margin, sigmoid, value_at_margin)"
                    ),
                ));
            }
            if given.iter().any(|(g, _)| g == k) {
                return Err(BindError::at(
                    v.pos(),
                    format!("tolerance(): `{k}` given twice"),
                ));
            }
            given.push((k.as_str(), v));
        }
        let mut t = Tolerance::default();
        for (k, v) in given {
            match k {
                "bounds" => match self.constant(v, "bounds")?[..] {
                    [lo, hi] if lo <= hi => t.bounds = (lo, hi),
                    [lo, hi] => {
                        return Err(BindError::at(
                            v.pos(),
                            format!("bounds ({lo}, {hi}): the lower bound must be <= the upper"),
                        ));
                    }
                    _ => return Err(BindError::at(v.pos(), "bounds must be (lower, upper)")),
                },
                "margin" => {
                    t.margin = self.scalar_constant(v, "margin")?;
                    if t.margin.is_nan() || t.margin < 0.0 {
                        return Err(BindError::at(v.pos(), "margin must be >= 0"));
                    }
                }
                "sigmoid" => t.sigmoid = sigmoid(&string(v, "sigmoid")?, v.pos())?,
                _ => t.value_at_margin = self.scalar_constant(v, "value_at_margin")?,
            }
        }
        let lax = matches!(
            t.sigmoid,
            Sigmoid::Cosine | Sigmoid::Linear | Sigmoid::Quadratic
        );
        let ok = if lax {
            (0.0..1.0).contains(&t.value_at_margin)
        } else {
            t.value_at_margin > 0.0 && t.value_at_margin < 1.0
        };
        if t.margin > 0.0 && !ok {
            return Err(BindError::at(
                pos,
                format!(
                    "value_at_margin {} must be in {} for this sigmoid",
                    t.value_at_margin,
                    if lax { "[0, 1)" } else { "(0, 1)" }
                ),
            ));
        }
        let i = self
            .prog
            .push(Op::Tolerance(t, x), self.prog.nodes[x].len, self.phase);
        Ok(self.fold(i, &[x]))
    }

    /// `prev(x)`: `x` bound as a `Before` node (evaluated before the step), copied into
    /// an `After` node.
    fn prev(
        &mut self,
        args: &[Expr],
        pos: Pos,
        arity: &dyn Fn(usize, usize) -> Result<()>,
    ) -> Result<usize> {
        arity(1, 1)?;
        if self.phase != Phase::After {
            return Err(BindError::at(
                pos,
                "prev() is the value before the step: only observations, rewards and termination can use it, and not inside another prev()",
            ));
        }
        self.phase = Phase::Before;
        let r = self.bind(&args[0]);
        self.phase = Phase::After;
        let b = r?;
        if self.prog.is_const(b) {
            return Ok(b);
        }
        let len = self.prog.nodes[b].len;
        Ok(self.prog.push(Op::Copy(b), len, self.phase))
    }

    fn random(
        &mut self,
        func: &str,
        args: &[Expr],
        kwargs: &[(String, Expr)],
        pos: Pos,
    ) -> Result<usize> {
        if self.phase != Phase::Init {
            return Err(BindError::at(
                pos,
                format!("{func}() draws random numbers: only the initial state (`init`) can"),
            ));
        }
        let keys: &[&str] = match func {
            "uniform" => &["low", "high", "size"],
            "normal" => &["loc", "scale", "size"],
            _ => &["size"],
        };
        if args.len() > keys.len() {
            return Err(BindError::at(
                pos,
                format!(
                    "{func}({}) takes at most {} arguments",
                    keys.join(", "),
                    keys.len()
                ),
            ));
        }
        let mut given: Vec<(&str, &Expr)> = keys.iter().copied().zip(args).collect();
        for (k, v) in kwargs {
            if !keys.contains(&k.as_str()) || given.iter().any(|(g, _)| g == k) {
                return Err(BindError::at(
                    v.pos(),
                    format!("{func}(): unexpected or repeated `{k}`"),
                ));
            }
            given.push((k.as_str(), v));
        }
        let get = |k: &str| given.iter().find(|(g, _)| *g == k).map(|(_, v)| *v);
        // uniform(0, 1) and normal(0, 1), as numpy's defaults.
        let defaults = (0.0, 1.0);
        let (a_key, b_key) = if func == "uniform" {
            ("low", "high")
        } else {
            ("loc", "scale")
        };
        let operand = |s: &mut Self, k: &str, d: f64| -> Result<usize> {
            match get(k) {
                Some(e) => s.bind(e),
                None => Ok(s.prog.constant(&[d])),
            }
        };
        let a = operand(self, a_key, defaults.0)?;
        let b = operand(self, b_key, defaults.1)?;
        let (la, lb) = (self.prog.nodes[a].len, self.prog.nodes[b].len);
        let size = match get("size") {
            None => la.max(lb),
            Some(e) => {
                let v = self.scalar_constant(e, "size")?;
                if v.fract() != 0.0 || !(1.0..=1e6).contains(&v) {
                    return Err(BindError::at(
                        e.pos(),
                        format!("size {v} must be a whole number from 1 to 10^6"),
                    ));
                }
                v as usize
            }
        };
        for l in [la, lb] {
            if l != 1 && l != size {
                return Err(BindError::at(
                    pos,
                    format!("{func}(): parameters of {l} elements for {size} draws"),
                ));
            }
        }
        self.prog.random = true;
        let op = match func {
            "uniform" => Op::Uniform(a, b),
            "normal" => Op::Normal(a, b),
            _ => Op::Randn,
        };
        Ok(self.prog.push(op, size, self.phase))
    }
}
