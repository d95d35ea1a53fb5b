//! Checkpoint loading as `mpo train --resume`, `mpo eval`, `mpo run` and `mpo export` do it:
//! SHA256SUMS, `meta.json`, the three safetensors files (checkpoint::verify, as `open` after
//! reading the files), the resume's configuration checks and random-stream states, and the
//! restore of networks, optimiser state and replay into the row's learner.
#![no_main]

use std::collections::HashMap;
use std::path::Path;

use libfuzzer_sys::fuzz_target;
use mpo_core::learner::Learner;
use mpo_core::replay::Replay;
use mpo_fuzz::checkpoint::{FIX_SUMS, NAMES, decode};
use mpo_host::checkpoint::{self, Verified};
use mpo_host::commands::{self, Flags};
use mpo_host::tasks::{self, Row, RowVisitor};

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
    let _ = tasks::visit(&v.meta.settings.task, &v.meta.settings.net, Restore(&v));
});

/// Restores the checkpoint into a learner and replay of its row, as `Trainer::new` does.
struct Restore<'a>(&'a Verified);

impl RowVisitor for Restore<'_> {
    type Out = ();
    fn visit<
        const OBS: usize,
        const ACT: usize,
        const TRI: usize,
        const AH1: usize,
        const AH2: usize,
        const QH1: usize,
        const QH2: usize,
        const BC: usize,
        const C: usize,
        const L: usize,
        const M: usize,
        const N: usize,
        const CAP: usize,
    >(
        self,
        _row: &'static Row,
    ) {
        // The larger rows' replays take hundreds of megabytes per input: the tiny row (whose
        // checkpoints the corpus holds) exercises the same code.
        if CAP > 50_000 {
            return;
        }
        let v = self.0;
        let mut learner: Box<Learner<OBS, ACT, TRI, AH1, AH2, QH1, QH2, BC, C, L, M, N>> =
            bytemuck::zeroed_box();
        if learner
            .init(v.meta.settings.mpo.to_config(), v.meta.settings.seed as u64)
            .is_err()
        {
            return;
        }
        let mut replay: Box<Replay<CAP, OBS, ACT>> = bytemuck::zeroed_box();
        if let Err(e) = v.restore(&mut learner, &mut replay) {
            let _ = e.to_string();
        }
    }
}
