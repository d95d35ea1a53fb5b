//! The device trainer's input frames for the benches (`benches/firmware.rs` on x86_64,
//! `benches/cortex_m.rs` under QEMU): one definition, included by both with `#[path]`.

use mpo_core::rng::Rng;
use mpo_frames::{START_LEN, encode, kind};

/// The frames a host sends for a fresh mcu run with the row's configuration, warm-up `warmup`
/// and then `steps` environment steps (one update every `interval`), in one episode of random
/// observations, rewards 1 (what the device does with them costs the same whatever they are);
/// with `end_last`, the last step ends the episode.
pub fn trainer_input(warmup: u64, interval: u64, steps: u64, end_last: bool) -> Vec<u8> {
    let row = mpo_host::table::row("cartpole-balance", "mcu").unwrap();
    let settings = mpo_host::commands::defaults(row);
    let mut schedule = mpo_host::trainer::agent_schedule(&settings);
    schedule.warmup_steps = warmup;
    schedule.update_interval = interval;
    let mut out = Vec::new();
    let mut seq = 0u8;
    let mut frame = |k: u8, p: &[u8]| {
        seq = seq.wrapping_add(1);
        let mut b = vec![0u8; p.len() + 64];
        let n = encode(k, seq, p, &mut b);
        out.extend_from_slice(&b[..n]);
    };
    let mut start = vec![0u8; START_LEN];
    start[0..8].copy_from_slice(&schedule.warmup_steps.to_le_bytes());
    start[8..16].copy_from_slice(&schedule.update_interval.to_le_bytes());
    start[16..24].copy_from_slice(&schedule.updates_per_interval.to_le_bytes());
    start[24..28].copy_from_slice(&schedule.n_step.to_le_bytes());
    for (i, w) in settings.mpo.to_config().to_words().iter().enumerate() {
        start[32 + 4 * i..36 + 4 * i].copy_from_slice(&w.to_le_bytes());
    }
    frame(kind::HELLO, &[]);
    frame(kind::START, &start);
    let mut rng = Rng::seed_from_u64(3);
    let mut obs = [0f32; 5];
    rng.fill_normal(&mut obs);
    let mut b = [0u8; 20];
    mpo_frames::put_f32s(&obs, &mut b);
    frame(kind::BEGIN, &b);
    for t in 0..steps {
        rng.fill_normal(&mut obs);
        let mut s = [0u8; 29];
        s[0..4].copy_from_slice(&1f32.to_le_bytes());
        s[4..8].copy_from_slice(&1f32.to_le_bytes());
        s[8] = (end_last && t + 1 == steps) as u8;
        mpo_frames::put_f32s(&obs, &mut s[9..]);
        frame(kind::STEP, &s);
    }
    out
}
