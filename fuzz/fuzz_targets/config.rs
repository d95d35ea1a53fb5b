//! Configuration as `mpo train` resolves it: a `--config` TOML file, `--set KEY=VALUE`
//! arguments and flags over the task table's defaults (settings::parse_table, parse_set,
//! commands::layers_from, resolve_fresh), optionally as a resume of a checkpoint's settings
//! (resolve_resumed). A resolved configuration must survive the round trip through the
//! `config.toml` a run writes.
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use mpo_fuzz::config::{NET, RESUME, SEED, STEPS, TASK};
use mpo_host::checkpoint::{Counters, FORMAT, Meta, VERSION};
use mpo_host::commands::{self, Flags};
use mpo_host::settings::{self, Settings};
use mpo_host::table;

fuzz_target!(|data: &[u8]| {
    let Some((&flags, rest)) = data.split_first() else {
        return;
    };
    // Files are read with read_to_string and arguments are Strings: UTF-8 only.
    let Ok(text) = std::str::from_utf8(rest) else {
        return;
    };
    let mut parts = text.split('\0');
    let file = parts.next().unwrap_or_default();
    let sets: Vec<String> = parts.map(str::to_string).collect();
    let file = if file.is_empty() {
        None
    } else {
        match settings::parse_table(file, "fuzz.toml") {
            Ok(t) => Some(("fuzz.toml".to_string(), t)),
            Err(e) => {
                let _ = e.to_string();
                return;
            }
        }
    };
    let f = Flags {
        task: (flags & TASK != 0).then(|| "hopper-stand".into()),
        task_file: None,
        net: (flags & NET != 0).then(|| "tiny".into()),
        seed: (flags & SEED != 0).then_some(7),
        steps: (flags & STEPS != 0).then_some(4000),
    };
    let layers = match commands::layers_from(file, &sets, &f) {
        Ok(l) => l,
        Err(e) => {
            let _ = e.to_string();
            return;
        }
    };
    match commands::resolve_fresh(&layers) {
        Ok(r) => round_trip(&r.settings),
        Err(e) => {
            let _ = e.to_string();
        }
    }
    if flags & RESUME != 0 {
        let row = table::row("cartpole-balance", "tiny").unwrap();
        let meta = Meta {
            format: FORMAT.into(),
            version: VERSION,
            settings: commands::defaults(row),
            task_file: None,
            sizes: row.sizes,
            env_steps: 2000,
            episodes: 2,
            updates: 0,
            wall_s: 0.0,
            learner_rng: String::new(),
            collector_rng: String::new(),
            sampler_rng: String::new(),
            replay: Counters {
                head: 0,
                len: 0,
                inserted: 0,
                current_episode: 0,
            },
            stats: Default::default(),
            fleet: None,
            metrics: Vec::new(),
            params_sha256: String::new(),
        };
        match commands::resolve_resumed(&meta, Path::new("/fuzz/run/checkpoint"), &layers) {
            Ok(r) => round_trip(&r.settings),
            Err(e) => {
                let _ = e.to_string();
            }
        }
    }
});

/// The run's `config.toml` (as `mpo train` writes it) reads back to the same settings.
fn round_trip(s: &Settings) {
    let text = toml::to_string(s).expect("resolved settings serialise");
    let back = settings::parse_table(&text, "config.toml").expect("config.toml parses");
    let back = Settings::from_table(back, "config.toml").expect("config.toml deserialises");
    assert_eq!(
        toml::to_string(&back).unwrap(),
        text,
        "config.toml does not round-trip"
    );
}
