//! Generates the learner instantiations `sizes/local.toml` asks for: one `spec!` line each and
//! `LOCAL`, the list of their instances (`src/spec.rs` includes the file).
//!
//! `mpo train --task-file` appends a task file's sizes to `sizes/local.toml` when the build
//! has no learner of them; the next build (which `./mpo` starts by itself) compiles them. The
//! file is the user's: not tracked by git, absent in a fresh clone.

use std::fmt::Write as _;
use std::path::Path;

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct Local {
    #[serde(default)]
    spec: Vec<Entry>,
}

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct Entry {
    sizes: Sizes,
}

#[derive(serde::Deserialize, PartialEq, Clone, Copy)]
#[serde(deny_unknown_fields)]
struct Sizes {
    obs: usize,
    act: usize,
    actor: [usize; 2],
    critic: [usize; 2],
    batch: usize,
    chunks: usize,
    seq: usize,
    m: usize,
    n: usize,
    replay_capacity: usize,
    #[serde(default)]
    actor_blocks: usize,
    #[serde(default)]
    critic_blocks: usize,
    #[serde(default = "one")]
    bins: usize,
}

fn one() -> usize {
    1
}

/// `[A, B]`, or with blocks `[W, F] x D` (the `spec!` syntax of a residual network).
fn net(w: [usize; 2], blocks: usize) -> String {
    match blocks {
        0 => format!("[{}, {}]", w[0], w[1]),
        d => format!("[{}, {}] x {d}", w[0], w[1]),
    }
}

fn main() {
    let dir = Path::new(&std::env::var("CARGO_MANIFEST_DIR").unwrap()).join("sizes");
    // The directory, not the file: a file that does not exist would make cargo run this
    // script on every build.
    println!("cargo:rerun-if-changed={}", dir.display());
    let path = dir.join("local.toml");
    let entries = match std::fs::read_to_string(&path) {
        Ok(text) => match toml::from_str::<Local>(&text) {
            Ok(l) => l.spec,
            Err(e) => panic!("{}: {e}", path.display()),
        },
        Err(_) => Vec::new(),
    };
    let mut unique: Vec<Sizes> = Vec::new();
    for e in entries {
        if !unique.contains(&e.sizes) {
            unique.push(e.sizes);
        }
    }
    let mut out = String::from("crate::spec! {\n");
    for (i, s) in unique.iter().enumerate() {
        check(s, &path);
        let bins = match s.bins {
            1 => String::new(),
            k => format!(" bins {k},"),
        };
        writeln!(
            out,
            "    /// `sizes/local.toml`, entry {i}.\n    pub Local{i} = obs {}, act {}, actor {}, critic {},{bins} batch {} / {}, seq {}, samples {} {}, replay {};",
            s.obs, s.act, net(s.actor, s.actor_blocks), net(s.critic, s.critic_blocks), s.batch,
            s.chunks, s.seq, s.m, s.n, s.replay_capacity
        )
        .unwrap();
    }
    out.push_str(
        "}\n\n/// The instances of `sizes/local.toml`.\nstatic LOCAL: &[fn() -> Instance] = &[",
    );
    for i in 0..unique.len() {
        write!(out, "<Local{i} as crate::spec::Spec>::instance, ").unwrap();
    }
    out.push_str("];\n");
    let dest = Path::new(&std::env::var("OUT_DIR").unwrap()).join("local_specs.rs");
    std::fs::write(dest, out).unwrap();
}

/// The limits `mpo` checks before it asks for sizes (`Sizes::check`), so a hand-edited file
/// fails here with its entry named rather than deep in the compiler.
fn check(s: &Sizes, path: &Path) {
    let ok = [
        s.obs,
        s.act,
        s.actor[0],
        s.actor[1],
        s.critic[0],
        s.critic[1],
        s.batch,
        s.chunks,
    ]
    .iter()
    .chain(&[s.seq, s.m, s.n, s.replay_capacity])
    .all(|&v| v > 0)
        && s.batch.is_multiple_of(s.chunks)
        && s.act <= 64
        && s.replay_capacity <= 10_000_000
        && s.actor_blocks <= 8
        && s.critic_blocks <= 8
        && (1..=1024).contains(&s.bins);
    if !ok {
        panic!(
            "{}: sizes obs {} act {} batch {} / {}: every size at least 1, act at most 64, the batch a multiple of chunks, at most 8 blocks, 1 to 1024 bins",
            path.display(),
            s.obs,
            s.act,
            s.batch,
            s.chunks
        );
    }
}
