//! A task file of an external plant: its `[external]` keys (sizes, bounds, the plant's
//! program and deadlines) are read and checked; an external plant is never made here.

use std::path::Path;

use sim_bridge::{Origin, TaskDef};

const GOOD: &str = r#"
plant = "external"
episode_steps = 200
[external]
obs = 3
act = 2
action_low = [-2.0]
action_high = [2.0, 3.0]
command = ["./serve.sh", "--fast"]
"#;

fn load(text: &str) -> Result<TaskDef, String> {
    TaskDef::from_text(
        text,
        "robot",
        Origin::File("/x/robot.toml".into()),
        Path::new("/x"),
    )
    .map_err(|e| e.to_string())
}

#[test]
fn the_external_keys_are_read_with_their_defaults() {
    let t = load(GOOD).unwrap();
    assert!(t.is_external());
    assert_eq!(
        (t.spec().obs_dim, t.spec().act_dim, t.spec().episode_steps),
        (3, 2, 200)
    );
    assert_eq!(t.action_bounds(), &[(-2.0, 2.0), (-2.0, 3.0)]);
    let e = t.external_plant().unwrap();
    assert_eq!(
        e.command.as_deref(),
        Some(&["./serve.sh".to_string(), "--fast".into()][..])
    );
    assert_eq!(e.dir, Path::new("/x"));
    assert_eq!((e.timeout, e.connect_timeout), (10.0, 60.0));
    let t = load(&format!("{GOOD}timeout = 0.5\nconnect_timeout = 5\n")).unwrap();
    let e = t.external_plant().unwrap();
    assert_eq!((e.timeout, e.connect_timeout), (0.5, 5.0));
    // Without a command the plant is attached to (`--attach-plant`).
    let t = load(&GOOD.replace("command = [\"./serve.sh\", \"--fast\"]\n", "")).unwrap();
    assert_eq!(t.external_plant().unwrap().command, None);
    // A simulated task has none, and an external one cannot be made here.
    assert!(
        TaskDef::builtin("cartpole-balance")
            .unwrap()
            .external_plant()
            .is_none()
    );
    let m = load(GOOD).unwrap().make(0).unwrap_err().to_string();
    assert!(m.contains("stepped by its own program"), "{m}");
}

#[test]
fn bad_external_keys_are_one_line_errors_naming_the_key() {
    for (change, key, says) in [
        ("command = []", "external.command", "empty"),
        (
            "timeout = 0",
            "external.timeout",
            "positive number of seconds",
        ),
        (
            "connect_timeout = -1",
            "external.connect_timeout",
            "positive",
        ),
        ("timeout = nan", "external.timeout", "positive"),
        ("tiemout = 3", "line", "unknown field `tiemout`"),
    ] {
        let text = format!("{GOOD}{change}\n").replace(
            "command = [\"./serve.sh\", \"--fast\"]\ncommand = []",
            "command = []",
        );
        let m = load(&text).unwrap_err();
        assert!(m.starts_with("/x/robot.toml: "), "{m}");
        assert!(m.contains(key) && m.contains(says), "{change}: {m}");
        assert!(!m.contains('\n'), "{m}");
    }
}
