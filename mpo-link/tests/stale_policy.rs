//! An answer computed with parameters older than the newest push is never acted on: the plant
//! asks again and takes the answer of the pushed policy. (A busy-polling controller can read a
//! request between two looks at its parameter port; a lockstep `mpo run` through it then gave
//! another return than `mpo eval` in one of a few runs.) The controller here is written out in
//! the test so that it answers the first request with the old generation every time.

use std::time::Duration;

use mpo_core::actor::Actor;
use mpo_core::rng::Rng;
use mpo_link::controller::{ControllerStats, respond};
use mpo_link::messages::{ActMsg, ObsMsg};
use mpo_link::service::{ControllerPorts, monotonic_ns};
use mpo_link::{Plant, PlantConfig, RunId, WaitMode};

type Small = Actor<3, 2, 3, 8, 8>;

fn policy(seed: u64) -> Box<Small> {
    let mut p: Box<Small> = bytemuck::zeroed_box();
    p.init(&mut Rng::seed_from_u64(seed), 1.0, 1e-4);
    p
}

/// Answers `answers` requests: the first with generation 0 (the old policy, `old`), the rest
/// with generation 1 (`new`). Returns the generations it answered with.
fn controller(run: RunId, answers: usize, ready: std::sync::mpsc::Sender<()>) -> Vec<u64> {
    let ports = ControllerPorts::open(&run).unwrap();
    ready.send(()).unwrap();
    let (old, new) = (policy(1), policy(2));
    let mut stats = ControllerStats::default();
    let mut reply: ActMsg = bytemuck::Zeroable::zeroed();
    let mut used = Vec::new();
    let give_up = monotonic_ns() + 20_000_000_000;
    while used.len() < answers && monotonic_ns() < give_up {
        while let Ok(Some(_)) = ports.params.receive() {}
        let Ok(Some(sample)) = ports.obs.receive() else {
            std::thread::sleep(Duration::from_micros(50));
            continue;
        };
        let request: ObsMsg = *sample;
        let (p, generation) = if used.is_empty() {
            (&old, 0)
        } else {
            (&new, 1)
        };
        respond(p, &request, generation, &mut stats, &mut reply);
        ports.act.send_copy(reply).unwrap();
        used.push(generation);
    }
    used
}

#[test]
fn an_answer_of_an_older_policy_is_asked_again_and_never_used() {
    let run = RunId::new();
    let mut plant = Plant::open(
        &run,
        PlantConfig {
            obs_len: 3,
            act_len: 2,
            wait: WaitMode::BusyPoll,
            deadline: Duration::from_secs(5),
            spin: Duration::ZERO,
        },
    )
    .unwrap();
    let ctl_run = run.clone();
    let (tx, rx) = std::sync::mpsc::channel();
    let ctl = std::thread::spawn(move || controller(ctl_run, 2, tx));
    // As `mpo run` waits for its controller's ports before the first push.
    rx.recv().unwrap();
    let new = policy(2);
    assert_eq!(plant.push_params(new.as_ref()).unwrap(), 1);

    let obs = [0.3f32, -0.7, 1.1];
    let got = plant
        .request_action(&obs, None, 1e-4, Duration::from_secs(5))
        .expect("an answer within the deadline");
    assert_eq!(ctl.join().unwrap(), vec![0, 1], "the controller's answers");
    assert_eq!(
        got.generation, 1,
        "the answer acted on is the pushed policy's"
    );
    let mut want = [0f32; 2];
    new.mean_action(&obs, &mut want);
    assert_eq!(
        [got.action[0].to_bits(), got.action[1].to_bits()],
        [want[0].to_bits(), want[1].to_bits()]
    );
    let s = plant.stats();
    assert_eq!((s.requests, s.replies, s.stale_policy), (1, 1, 1), "{s:?}");
    assert_eq!(s.misses, 0);
}
