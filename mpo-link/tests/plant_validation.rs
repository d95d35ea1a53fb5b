//! The plant's own checks, against a misbehaving controller played by a thread: replies with
//! the wrong sequence number, a NaN action or the wrong length are counted and never acted on.

use std::time::Duration;

use mpo_link::messages::ActMsg;
use mpo_link::service::ControllerPorts;
use mpo_link::{Miss, Plant, PlantConfig, RunId, WaitMode};

#[test]
fn malformed_replies_are_rejected_and_counted() {
    let run = RunId::new();
    let mut plant = Plant::open(
        &run,
        PlantConfig {
            obs_len: 3,
            act_len: 2,
            wait: WaitMode::Event,
            deadline: Duration::from_millis(300),
            spin: Duration::ZERO,
        },
    )
    .unwrap();
    let fake_run = run.clone();
    let (ready_tx, ready_rx) = std::sync::mpsc::channel();
    // ipc ports are !Send: the fake controller opens its own in its thread.
    let fake = std::thread::spawn(move || {
        let ports = ControllerPorts::open(&fake_run).unwrap();
        ready_tx.send(()).unwrap();
        for round in 0..2 {
            let obs = loop {
                if let Some(s) = ports.obs.receive().unwrap() {
                    break *s;
                }
                std::thread::sleep(Duration::from_micros(100));
            };
            let mut m: ActMsg = bytemuck::Zeroable::zeroed();
            m.len = 2;
            // Wrong sequence number, then NaN, then wrong length...
            m.seq = obs.seq + 1;
            ports.act.send_copy(m).unwrap();
            m.seq = obs.seq;
            m.action[1] = f32::NAN;
            ports.act.send_copy(m).unwrap();
            m.action[1] = 0.0;
            m.len = 3;
            ports.act.send_copy(m).unwrap();
            let _ = ports.notify.notify();
            if round == 1 {
                // ... and finally a good one (buffer of 4: it fits after the three bad ones).
                m.len = 2;
                m.action[0] = 0.25;
                ports.act.send_copy(m).unwrap();
                let _ = ports.notify.notify();
            }
        }
    });
    ready_rx.recv().unwrap();
    let mut out = [5f32; 2];
    // Round 0: only bad replies: a timeout, zero action.
    assert_eq!(plant.act(&[0.0; 3], &mut out).unwrap_err(), Miss::Timeout);
    assert_eq!(out, [0.0, 0.0]);
    // Round 1: three bad, then the good one is taken.
    let a = plant.act(&[0.0; 3], &mut out).unwrap();
    assert_eq!(out, [0.25, 0.0]);
    assert_eq!(a.seq, 2);
    fake.join().unwrap();
    let s = plant.stats();
    assert_eq!(s.rejections.sequence, 2);
    assert_eq!(s.rejections.non_finite, 2);
    assert_eq!(s.rejections.length, 2);
    assert_eq!((s.replies, s.misses, s.timeouts), (1, 1, 1));
}
