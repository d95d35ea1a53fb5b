//! The input formats of the fuzz targets, shared by the targets (`fuzz_targets/`) and the
//! corpus generator (`src/bin/make_corpus.rs`), which writes real encoders' output in them.

/// `checkpoint`: a flags byte, then the five files of a checkpoint directory, each as a
/// little-endian u32 length and its bytes, in [`checkpoint::NAMES`] order. A file the input
/// ends before is missing (reading it fails with "not found").
pub mod checkpoint {
    /// The files, in input order.
    pub const NAMES: [&str; 5] = [
        "SHA256SUMS",
        "meta.json",
        "params.safetensors",
        "optimizer.safetensors",
        "replay.safetensors",
    ];
    /// Flag: replace SHA256SUMS by the sums of the other files as given, so that mutated
    /// files get past the checksums to the parsers behind them.
    pub const FIX_SUMS: u8 = 1;

    /// Packs `files` (in [`NAMES`] order).
    pub fn encode(flags: u8, files: &[Vec<u8>; 5]) -> Vec<u8> {
        let mut out = vec![flags];
        for f in files {
            out.extend((f.len() as u32).to_le_bytes());
            out.extend(f);
        }
        out
    }

    /// Unpacks an input: the flags and each file (None if missing).
    pub fn decode(data: &[u8]) -> (u8, [Option<&[u8]>; 5]) {
        let Some((&flags, mut rest)) = data.split_first() else {
            return (0, [None; 5]);
        };
        let mut files = [None; 5];
        for f in &mut files {
            if rest.len() < 4 {
                break;
            }
            let n = u32::from_le_bytes(rest[..4].try_into().unwrap()) as usize;
            rest = &rest[4..];
            let n = n.min(rest.len());
            *f = Some(&rest[..n]);
            rest = &rest[n..];
        }
        (flags, files)
    }
}

/// `config`: a flags byte, then UTF-8 text: the `--config` file's contents (empty: no file),
/// then each `--set` argument, separated by NUL bytes.
pub mod config {
    /// Flag: also resolve the layers as a resume of a `cartpole-balance`/`tiny` checkpoint.
    pub const RESUME: u8 = 1;
    /// Flag: `--task hopper-stand`.
    pub const TASK: u8 = 2;
    /// Flag: `--net tiny`.
    pub const NET: u8 = 4;
    /// Flag: `--seed 7`.
    pub const SEED: u8 = 8;
    /// Flag: `--steps 4000`.
    pub const STEPS: u8 = 16;

    /// Packs a configuration.
    pub fn encode(flags: u8, file: &str, sets: &[&str]) -> Vec<u8> {
        let mut out = vec![flags];
        out.extend(file.as_bytes());
        for s in sets {
            out.push(0);
            out.extend(s.as_bytes());
        }
        out
    }
}

/// `actions_csv`: a byte choosing the action width (`1 + b % 6`), then the file's bytes.
pub mod actions_csv {
    /// Packs an action file for `width` actions per row (1 to 6).
    pub fn encode(width: usize, csv: &str) -> Vec<u8> {
        let mut out = vec![(width - 1) as u8];
        out.extend(csv.as_bytes());
        out
    }
}

/// `link_messages`: a flags byte, then messages, each a tag byte and the message's bytes
/// (`#[repr(C)]`, as in shared memory; an input that ends early leaves the rest zero).
pub mod link {
    /// Flag: set each parameter block's own checksum to match its payload, so mutated blocks
    /// reach the assembly (the whole-vector checksum is left as given).
    pub const FIX_CHECKSUMS: u8 = 1;
    /// Tag: an observation request (`ObsMsg`), answered by the controller's `respond`.
    pub const OBS: u8 = 0;
    /// Tag: an action reply (`ActMsg`), validated by the plant against the last request.
    pub const ACT: u8 = 1;
    /// Tag: a parameter block (`ParamChunk`), added to the controller's assembler.
    pub const CHUNK: u8 = 2;

    /// Appends a message.
    pub fn push(out: &mut Vec<u8>, tag: u8, bytes: &[u8]) {
        out.push(tag);
        out.extend(bytes);
    }
}

/// `firmware_records`: a byte choosing the policy (even: 5 observations and 1 action, the
/// cartpole profile; odd: 15 and 4, the hopper profile), then the firmware's stdin.
pub mod records {}

/// `device_frames`: a mode byte (even: a raw byte stream; odd: records of kind, sequence
/// number, u16 little-endian length and payload, each encoded by `mpo_frames::encode`).
pub mod frames {
    /// Appends a (kind, seq, payload) record of mode 1.
    pub fn push_record(out: &mut Vec<u8>, kind: u8, seq: u8, payload: &[u8]) {
        out.extend([kind, seq]);
        out.extend((payload.len() as u16).to_le_bytes());
        out.extend(payload);
    }
}

/// `task_file`: a mode byte, then UTF-8 text. Mode 0: the text is a whole task file. Other
/// modes: the text is one expression, put as the `reward` of a template task file on one of
/// [`task_file::TEMPLATES`]' models (`mode % 4`), which also uses it as an observation part
/// and (odd modes) as `terminate`.
pub mod task_file {
    /// Models for the expression templates: two Control Suite models, two of Gymnasium's.
    pub const TEMPLATES: [&str; 4] = [
        "suite:cartpole.xml",
        "suite:walker.xml",
        "gymnasium:half_cheetah.xml",
        "gymnasium:inverted_double_pendulum.xml",
    ];

    /// Packs a whole task file (mode 0).
    pub fn encode_file(text: &str) -> Vec<u8> {
        let mut out = vec![0u8];
        out.extend(text.as_bytes());
        out
    }

    /// Packs an expression for the template of `mode` (1 to 255).
    pub fn encode_expression(mode: u8, expr: &str) -> Vec<u8> {
        assert_ne!(mode, 0, "mode 0 is a whole file");
        let mut out = vec![mode];
        out.extend(expr.as_bytes());
        out
    }

    /// The task file an input stands for, or None when it is not one (not UTF-8, or an
    /// expression TOML cannot hold in a string).
    pub fn decode(data: &[u8]) -> Option<String> {
        let (&mode, rest) = data.split_first()?;
        let text = std::str::from_utf8(rest).ok()?;
        if mode == 0 {
            return Some(text.to_string());
        }
        // A TOML literal string ('...') holds anything but `'` and control characters; the
        // expression language's strings take either quote, so `'` becomes `"`.
        if text.chars().any(|c| c.is_control() && c != '\t') {
            return None;
        }
        Some(template(mode, &text.replace('\'', "\"")))
    }

    fn template(mode: u8, expr: &str) -> String {
        let model = TEMPLATES[mode as usize % TEMPLATES.len()];
        let convention = if model.starts_with("gymnasium:") {
            "convention = \"gymnasium\"\n"
        } else {
            ""
        };
        let terminate = if mode % 2 == 1 {
            format!("terminate = '{expr}'\n")
        } else {
            String::new()
        };
        format!(
            "model = \"{model}\"\n{convention}episode_steps = 5\nreward = '{expr}'\n{terminate}\
             init = ['qpos = qpos + uniform(-0.1, 0.1, nq)', 'qvel = 0.1 * randn(nv)']\n\
             observation = [{{ name = \"q\", value = \"qpos\" }}, {{ name = \"e\", value = '{expr}' }}]\n"
        )
    }
}
