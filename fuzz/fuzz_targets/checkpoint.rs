//! Checkpoint loading as `mpo train --resume`, `mpo eval`, `mpo run` and `mpo export` do it:
//! SHA256SUMS, `meta.json`, the three safetensors files (checkpoint::verify, as `open` after
//! reading the files), the resume's configuration checks and random-stream states, and the
//! restore of networks, optimiser state and replay into the row's learner.
#![no_main]

use std::collections::HashMap;
use std::path::Path;

use libfuzzer_sys::fuzz_target;
use mpo_fuzz::checkpoint::{FIX_SUMS, NAMES, decode};
use mpo_host::checkpoint::{self, Verified};
use mpo_host::commands::{self, Flags};
use mpo_host::registry;
use mpo_host::rows;
use mpo_host::training::TrainingInit;

fuzz_target!(|data: &[u8]| {
    let (flags, given) = decode(data);
    let mut files: HashMap<&str, Vec<u8>> = NAMES
        .iter()
        .zip(given)
        .filter_map(|(n, f)| Some((*n, f?.to_vec())))
        .collect();
    if flags & FIX_SUMS != 0 {
        let mut sums = String::new();
        for n in &NAMES[1..] {
            if let Some(b) = files.get(n) {
                let h = checkpoint::sha256_hex(b);
                sums.push_str(&format!("{h}  {n}\n"));
            }
        }
        files.insert("SHA256SUMS", sums.into_bytes());
    }
    let dir = Path::new("/fuzz/run/checkpoint");
    let v = match checkpoint::verify(dir, |name| {
        files
            .get(name)
            .cloned()
            .ok_or_else(|| std::io::ErrorKind::NotFound.into())
    }) {
        Ok(v) => v,
        Err(e) => {
            let _ = e.to_string();
            return;
        }
    };
    // `mpo train --resume`: the configuration checks, then the random streams.
    let layers = commands::layers_from(None, &[], &Flags::default()).unwrap();
    if let Err(e) = commands::resolve_resumed(&v.meta, dir, &layers) {
        let _ = e.to_string();
    }
    let _ = checkpoint::unhex32(&v.meta.collector_rng);
    let _ = checkpoint::unhex32(&v.meta.sampler_rng);
    restore(&v);
});

/// Restores the checkpoint into a trainer of its sizes, as `mpo train --resume` does.
fn restore(v: &Verified) {
    // The larger rows' replays take hundreds of megabytes per input: the tiny row (whose
    // checkpoints the corpus holds) exercises the same code.
    if v.meta.sizes.replay_capacity > 50_000 {
        return;
    }
    let (Ok(instance), Ok(task)) = (
        registry::find(&v.meta.sizes),
        rows::task_of_checkpoint(&v.meta, &v.dir),
    ) else {
        return;
    };
    let init = TrainingInit {
        settings: &v.meta.settings,
        task: &task,
        resume: Some(v),
        threads: 1,
    };
    if let Err(e) = (instance.trainer)(init) {
        let _ = e.to_string();
    }
}
