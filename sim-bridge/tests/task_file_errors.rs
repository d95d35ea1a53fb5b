//! Bad task files: each mistake is one line naming the file and the key, and says what is
//! valid (the model's names of that kind, the models of a folder, the limits), before anything
//! runs; an expression that leaves its domain while running is reported at the step it
//! happens, naming the key.

use std::path::{Path, PathBuf};

use sim_bridge::taskfile::{MAX_ACT, MAX_FILE_BYTES, MAX_OBS};
use sim_bridge::{Environment, SimError, TaskDef};

/// A fresh folder for one test's files.
fn folder(test: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!(
        "sim-bridge-task-errors-{}-{test}",
        std::process::id()
    ));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A cartpole task file with `extra` appended (TOML keys before any table).
fn cartpole(extra: &str) -> String {
    format!(
        "model = \"suite:cartpole.xml\"\ntime_limit = 10.0\n\
         observation = [{{ name = \"position\", value = \"qpos\" }}]\nreward = \"1\"\n{extra}"
    )
}

/// Loads `text` as `<dir>/<name>.toml`; returns the error's one line.
fn error_of(dir: &Path, name: &str, text: &str) -> String {
    let path = dir.join(format!("{name}.toml"));
    std::fs::write(&path, text).unwrap();
    let e = TaskDef::from_file(&path).expect_err(&format!("{name} must not load"));
    let msg = e.to_string();
    assert!(!msg.contains('\n'), "{name}: not one line: {msg}");
    assert!(
        msg.starts_with(&format!("{}: ", path.display())),
        "{name}: does not start with the file: {msg}"
    );
    msg
}

fn has(msg: &str, parts: &[&str]) {
    for p in parts {
        assert!(msg.contains(p), "`{p}` missing from: {msg}");
    }
}

/// Replaces the `observation = ...` line of [`cartpole`]'s text.
fn cartpole_obs(value: &str) -> String {
    cartpole("").replace(
        "observation = [{ name = \"position\", value = \"qpos\" }]",
        &format!("observation = [{{ name = \"x\", value = \"{value}\" }}]"),
    )
}

#[test]
fn an_unknown_name_lists_the_models_names_of_its_kind() {
    let dir = folder("names");
    let msg = error_of(&dir, "body", &cartpole_obs("xpos('cartt')"));
    has(
        &msg,
        &[
            "observation 'x': ",
            "no body named 'cartt'",
            "bodies: world, cart, pole_1",
        ],
    );
    let msg = error_of(&dir, "joint", &cartpole_obs("qpos('slide')"));
    has(
        &msg,
        &[
            "observation 'x': ",
            "no joint named 'slide'",
            "joints: slider, hinge_1",
        ],
    );
    let msg = error_of(&dir, "site", &cartpole_obs("site_xpos('tip')"));
    has(&msg, &["no site named 'tip'", "the model has no sites"]);
    let msg = error_of(
        &dir,
        "sensor",
        &cartpole("reward = \"sensor('touch')\"\n").replacen("reward = \"1\"\n", "", 1),
    );
    has(
        &msg,
        &[
            "reward: ",
            "no sensor named 'touch'",
            "the model has no sensors",
        ],
    );
    let walker = "model = \"suite:walker.xml\"\ntime_limit = 25.0\n\
                  observation = [{ name = \"v\", value = \"sensor('torso_subtreelinvl')\" }]\nreward = \"1\"\n";
    let msg = error_of(&dir, "walker-sensor", walker);
    has(
        &msg,
        &[
            "observation 'v': ",
            "no sensor named 'torso_subtreelinvl'",
            "sensors: torso_subtreelinvel",
        ],
    );
    let msg = error_of(&dir, "actuator", &cartpole("actuators = [\"slider\"]\n"));
    has(
        &msg,
        &[
            "actuators: ",
            "no actuator named 'slider'",
            "actuators: slide",
        ],
    );
    let msg = error_of(&dir, "ctrl", &cartpole_obs("ctrl('motor')"));
    has(&msg, &["no actuator named 'motor'", "actuators: slide"]);
    let msg = error_of(
        &dir,
        "define",
        &cartpole("terminate = \"fallen\"\n[define]\nfallen = \"xpos('pole', 'z') < 0\"\n"),
    );
    has(
        &msg,
        &[
            "terminate: in the definition of `fallen` (\"xpos('pole', 'z') < 0\", at character 6): ",
            "no body named 'pole'",
        ],
    );
    let msg = error_of(
        &dir,
        "keyframe",
        &cartpole("init = [\"keyframe('home')\"]\n"),
    );
    has(
        &msg,
        &[
            "init[0]: ",
            "no keyframe named 'home'",
            "the model has no keyframes",
        ],
    );
    let msg = error_of(&dir, "unknown-name", &cartpole_obs("qpos + speed"));
    has(&msg, &["unknown name `speed`"]);
    let msg = error_of(&dir, "unknown-function", &cartpole_obs("qpos_of('slider')"));
    has(&msg, &["unknown function qpos_of()", "qpos, qvel"]);
    // Text quoted from the file stays on one line (TOML strings may hold newlines).
    let msg = error_of(
        &dir,
        "newline",
        &cartpole("[define]\nx = \"(1 + \\nsum(\"\n"),
    );
    has(&msg, &["define.x: ", "in \"(1 + \\nsum(\""]);
    // A definition cannot shadow a built-in name (it would never be read).
    let msg = error_of(&dir, "shadow", &cartpole("[define]\ndt = \"0.05\"\n"));
    has(&msg, &["define.dt: `dt` is a built-in name"]);
    let msg = error_of(&dir, "unknown-key", &cartpole("rewrad = \"2\"\n"));
    has(&msg, &["unknown field `rewrad`", "reward"]);
}

#[test]
fn a_missing_model_says_where_it_looked_and_what_exists() {
    let dir = folder("models");
    let no_model =
        "time_limit = 10.0\nobservation = [{ name = \"q\", value = \"qpos\" }]\nreward = \"1\"\n";
    let msg = error_of(&dir, "no-key", no_model);
    has(&msg, &["model: missing"]);
    let path = format!("model = \"robot/robot.xml\"\n{no_model}");
    let msg = error_of(&dir, "path", &path);
    has(
        &msg,
        &[
            "model: ",
            &format!("{}", dir.join("robot/robot.xml").display()),
            "does not exist",
        ],
    );
    let msg = error_of(
        &dir,
        "suite",
        &format!("model = \"suite:cartpol.xml\"\n{no_model}"),
    );
    has(
        &msg,
        &[
            "model: suite:cartpol.xml: no such model",
            "cartpole.xml",
            "walker.xml",
        ],
    );
    // A `suite:` name is a file of that folder, not a path out of it.
    let msg = error_of(
        &dir,
        "suite-escape",
        &format!("model = \"suite:../suite/cartpole.xml\"\n{no_model}"),
    );
    has(&msg, &["model: suite:../suite/cartpole.xml: no such model"]);
    let msg = error_of(
        &dir,
        "gymnasium",
        &format!("model = \"gymnasium:half_cheetah_v5.xml\"\n{no_model}"),
    );
    has(
        &msg,
        &[
            "model: gymnasium:half_cheetah_v5.xml: no such model",
            "half_cheetah.xml",
        ],
    );
    // A file MuJoCo rejects: MuJoCo's reason, under the model key, on one line.
    std::fs::write(
        dir.join("broken.xml"),
        "<mujoco>\n  <worldbody>\n    <body name=\"a\">\n</mujoco>\n",
    )
    .unwrap();
    let msg = error_of(
        &dir,
        "broken",
        &format!("model = \"broken.xml\"\n{no_model}"),
    );
    has(&msg, &["model: MuJoCo cannot load", "broken.xml"]);
}

/// Steps `def`'s environment with zero actions until an error; returns it and its step.
fn first_error(def: &TaskDef) -> (usize, SimError) {
    let mut env = def.make(0).unwrap();
    let mut obs = vec![0.0; def.spec().obs_dim];
    if let Err(e) = env.try_reset(&mut obs) {
        return (0, e);
    }
    let action = vec![0.0; def.spec().act_dim];
    for step in 1..=def.spec().episode_steps {
        if let Err(e) = env.try_step(&action, &mut obs) {
            return (step, e);
        }
    }
    panic!("no error in a whole episode");
}

#[test]
fn a_value_that_turns_non_finite_is_reported_at_its_step_and_key() {
    let dir = folder("nan");
    // sqrt(0.305 - time): NaN from the 31st step of 0.01 s on.
    let path = dir.join("reward.toml");
    std::fs::write(
        &path,
        cartpole("").replace("reward = \"1\"", "reward = \"sqrt(0.305 - time)\""),
    )
    .unwrap();
    let (step, e) = first_error(&TaskDef::from_file(&path).unwrap());
    assert_eq!(step, 31, "{e}");
    let msg = e.to_string();
    has(
        &msg,
        &[
            &format!("{}: reward: became NaN at step 31", path.display()),
            "the state is finite",
        ],
    );
    // An observation part: named with its element.
    let path = dir.join("obs.toml");
    std::fs::write(
        &path,
        cartpole("").replace(
            "[{ name = \"position\", value = \"qpos\" }]",
            "[{ name = \"position\", value = \"qpos\" }, { name = \"odd\", value = \"[1, 1 / time]\" }]",
        ),
    )
    .unwrap();
    let (step, e) = first_error(&TaskDef::from_file(&path).unwrap());
    assert_eq!(step, 0, "{e}");
    has(
        &e.to_string(),
        &[&format!(
            "{}: observation 'odd'[1]: became inf at step 0",
            path.display()
        )],
    );
    // The initial state: `try_reset` refuses it and no episode starts.
    let path = dir.join("init.toml");
    std::fs::write(&path, cartpole("init = [\"qpos('slider') = log(-1)\"]\n")).unwrap();
    let def = TaskDef::from_file(&path).unwrap();
    let (step, e) = first_error(&def);
    assert_eq!(step, 0);
    has(
        &e.to_string(),
        &[
            &format!(
                "{}: observation 'position'[0]: became NaN at step 0",
                path.display()
            ),
            "the initial state is not finite",
        ],
    );
    let mut env = def.make(0).unwrap();
    let mut obs = vec![0.0; def.spec().obs_dim];
    assert!(env.try_reset(&mut obs).is_err());
    assert!(matches!(
        env.try_step(&[0.0], &mut obs),
        Err(SimError::EpisodeOver { .. })
    ));
}

/// An MJCF model with `n` motors on one slide joint.
fn motors(n: usize) -> String {
    let mut s = String::from(
        "<mujoco><worldbody><body name=\"b\"><joint name=\"j\" type=\"slide\"/><geom size=\"0.1\" mass=\"1\"/></body></worldbody><actuator>",
    );
    for i in 0..n {
        s.push_str(&format!(
            "<motor name=\"m{i}\" joint=\"j\" ctrlrange=\"-1 1\"/>"
        ));
    }
    s + "</actuator></mujoco>"
}

#[test]
fn sizes_past_the_limits_are_refused_with_the_limit() {
    let dir = folder("sizes");
    // Observation: walker's 63 body orientations (7 bodies), 17 times.
    let big = vec!["xmat('*')"; 17].join(", ");
    let walker = format!(
        "model = \"suite:walker.xml\"\ntime_limit = 25.0\nobservation = [{{ name = \"all\", value = \"concat({big})\" }}]\nreward = \"1\"\n"
    );
    let msg = error_of(&dir, "obs", &walker);
    has(
        &msg,
        &[
            "observation: 1071 numbers (all 1071); at most ",
            &MAX_OBS.to_string(),
        ],
    );
    // Action: one motor more than the limit.
    std::fs::write(dir.join("motors.xml"), motors(MAX_ACT + 1)).unwrap();
    let text = "model = \"motors.xml\"\nepisode_steps = 10\nobservation = [{ name = \"q\", value = \"qpos\" }]\nreward = \"1\"\n";
    let msg = error_of(&dir, "act", text);
    has(
        &msg,
        &[&format!(
            "actuators: {} action dimensions; at most {MAX_ACT}",
            MAX_ACT + 1
        )],
    );
    std::fs::write(dir.join("motors.xml"), motors(MAX_ACT)).unwrap();
    let path = dir.join("act-ok.toml");
    std::fs::write(&path, text).unwrap();
    assert_eq!(TaskDef::from_file(&path).unwrap().spec().act_dim, MAX_ACT);
    // Episode length, substeps, draws, names, the file itself.
    for (name, extra, want) in [
        (
            "steps-0",
            "episode_steps = 0",
            "episode_steps: 0: from 1 to 10^7",
        ),
        (
            "steps-big",
            "episode_steps = 100000000",
            "episode_steps: 100000000: from 1 to 10^7",
        ),
        (
            "substeps",
            "substeps = 1000000",
            "substeps: 1000000 is more than 100000",
        ),
        ("substeps-0", "substeps = 0", "substeps: must be at least 1"),
        (
            "timestep",
            "control_timestep = 0.015",
            "control_timestep: 0.015 s is not a whole number",
        ),
        (
            "draws",
            "init = [\"qvel = uniform(0, 1, 2000000)\"]",
            "init[0]: size 2000000 must be a whole number from 1 to 10^6",
        ),
        (
            "name",
            &format!("name = \"{}\"", "n".repeat(65)),
            "name: `nnnn",
        ),
    ] {
        let text = cartpole(extra).replace(
            "time_limit = 10.0\n",
            if name.starts_with("steps") {
                ""
            } else {
                "time_limit = 10.0\n"
            },
        );
        has(&error_of(&dir, name, &text), &[want]);
    }
    // An external plant's sizes have the same limits.
    let external = |obs: usize, act: usize| {
        format!(
            "plant = \"external\"\nepisode_steps = 200\n[external]\nobs = {obs}\nact = {act}\naction_low = [-2]\naction_high = [2]\n"
        )
    };
    has(
        &error_of(&dir, "external-obs", &external(MAX_OBS + 1, 1)),
        &[&format!(
            "external.obs: {}: from 1 to {MAX_OBS}",
            MAX_OBS + 1
        )],
    );
    has(
        &error_of(&dir, "external-act", &external(3, 0)),
        &[&format!("external.act: 0: from 1 to {MAX_ACT}")],
    );
    let path = dir.join("external-ok.toml");
    std::fs::write(&path, external(MAX_OBS, MAX_ACT)).unwrap();
    let def = TaskDef::from_file(&path).unwrap();
    assert_eq!((def.spec().obs_dim, def.spec().act_dim), (MAX_OBS, MAX_ACT));
    let huge = cartpole(&format!("# {}\n", "x".repeat(MAX_FILE_BYTES)));
    has(
        &error_of(&dir, "huge", &huge),
        &[
            "(file): ",
            &format!("a task file has at most {MAX_FILE_BYTES}"),
        ],
    );
    // Definitions nested deeper than binding follows.
    let mut deep = cartpole("reward = \"d0\"\n[define]\n").replacen("reward = \"1\"\n", "", 1);
    for i in 0..100 {
        deep.push_str(&format!("d{i} = \"d{} + 1\"\n", i + 1));
    }
    deep.push_str("d100 = \"1\"\n");
    let msg = error_of(&dir, "deep", &deep);
    has(
        &msg,
        &[
            "reward: in the definition of `d0` -> `d1` -> ",
            "definitions nested deeper than 64",
        ],
    );
    assert!(msg.len() < 1200, "{} characters: {msg}", msg.len());
}
