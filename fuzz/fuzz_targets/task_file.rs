//! Task files as `TaskDef::from_text` reads them (the TOML keys, the expression parser, the
//! binding of every name to the model, the limits), and the environment the file makes
//! (reset and a few steps, the expressions evaluated). Errors must be one line naming the
//! file; an accepted file has sizes within the limits and, while it runs, either finite
//! rewards and observations or a one-line error naming the file and key.
#![no_main]

use std::path::{Path, PathBuf};

use libfuzzer_sys::fuzz_target;
use mpo_fuzz::task_file;
use sim_bridge::taskfile::{MAX_ACT, MAX_OBS};
use sim_bridge::{Environment, Origin, SimError, TaskDef};

const FILE: &str = "fuzz.toml";

fn tasks_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../tasks")
}

/// A task file's error: one line, naming the file.
fn check_error(e: &SimError) {
    let msg = e.to_string();
    assert!(!msg.contains('\n'), "not one line: {msg:?}");
    if matches!(e, SimError::TaskFile { .. } | SimError::NonFinite { .. }) {
        assert!(
            msg.starts_with("fuzz.toml: "),
            "does not name the file: {msg}"
        );
    }
}

fuzz_target!(|data: &[u8]| {
    let Some(text) = task_file::decode(data) else {
        return;
    };
    // Only the models of the two named folders: a path would let the fuzzer read (and hash)
    // any file of the machine, which is not what is tested here.
    if let Ok(t) = text.parse::<toml::Table>()
        && let Some(m) = t.get("model").and_then(|m| m.as_str())
        && !(m.starts_with("suite:") || m.starts_with("gymnasium:"))
    {
        return;
    }
    let origin = Origin::File(PathBuf::from(FILE));
    let def = match TaskDef::from_text(&text, "fuzz", origin, &tasks_dir()) {
        Ok(d) => d,
        Err(e) => return check_error(&e),
    };
    let spec = def.spec().clone();
    assert!((1..=MAX_OBS).contains(&spec.obs_dim));
    assert!((1..=MAX_ACT).contains(&spec.act_dim));
    assert!(spec.episode_steps >= 1);
    assert_eq!(def.sha256().len(), 64);
    assert_eq!(def.action_bounds().len(), spec.act_dim);
    if def.is_external() {
        assert!(def.make(0).is_err());
        return;
    }
    // Slow files (thousands of physics steps per control step) are valid but not run here.
    if spec.control_timestep > 0.2 {
        return;
    }
    let mut env = def.make(1).expect("an accepted file makes its environment");
    let mut obs = vec![0.0; spec.obs_dim];
    if let Err(e) = env.try_reset(&mut obs) {
        return check_error(&e);
    }
    assert!(obs.iter().all(|x| x.is_finite()));
    for t in 0..4 {
        let action: Vec<f64> = (0..spec.act_dim)
            .map(|k| [0.5, -1.5, 0.0, 1.0][(t + k) % 4])
            .collect();
        match env.try_step(&action, &mut obs) {
            Ok(s) => {
                assert!(s.reward.is_finite());
                assert!(obs.iter().all(|x| x.is_finite()));
                assert!(s.discount == 0.0 || s.discount == 1.0);
                if s.last {
                    break;
                }
            }
            Err(e) => return check_error(&e),
        }
    }
});
