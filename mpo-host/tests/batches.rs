//! The batches the trainer feeds the learner, checked against the replay they came from:
//! every n-step row equals `mpo_core::evaluation::nstep` folded over the stored transitions
//! that follow its start in the same episode, and every Retrace row is consecutive stored
//! transitions of one episode with `bootstrap = gamma * discount`. A real replay: 3000 steps
//! of cartpole-balance (tiny row) collected by the trainer itself.

use mpo_core::evaluation::nstep;
use mpo_core::replay::Transition;
use mpo_host::commands::defaults;
use mpo_host::settings::PolicyEvaluation;
use mpo_host::table;
use mpo_host::trainer::MlpTrainer as Trainer;

type Tiny = Trainer<5, 1, 1, 32, 32, 32, 32, 32, 2, 4, 10, 10, 50_000>;

/// A trainer of the tiny row with `evaluation` over `n` steps, after 3000 environment steps.
fn trained(evaluation: PolicyEvaluation, n: u32) -> Box<Tiny> {
    let row = table::row("cartpole-balance", "tiny").unwrap();
    let mut settings = defaults(row);
    settings.mpo.policy_evaluation = evaluation;
    settings.mpo.n_step = n;
    let mut t = Box::new(Tiny::new(&settings, None, 1).unwrap());
    t.collect(3000).unwrap_or_else(|_| panic!("collect failed"));
    t
}

/// The stored transitions in age order with their episode ids.
fn stored(t: &Tiny) -> Vec<(Transition<5, 1>, u64)> {
    let raw = t.agent.replay.raw();
    let len = raw.counters.len as usize;
    (0..len)
        .map(|k| {
            let i = (raw.counters.head as usize + 50_000 - len + k) % 50_000;
            (
                Transition {
                    obs: raw.obs[i],
                    action: raw.action[i],
                    reward: raw.reward[i],
                    next_obs: raw.next_obs[i],
                    discount: raw.discount[i],
                    behaviour_log_prob: raw.behaviour_log_prob[i],
                },
                raw.episode[i],
            )
        })
        .collect()
}

/// The age index of the stored transition with this state and action (continuous values:
/// a match is unique).
fn find(all: &[(Transition<5, 1>, u64)], obs: &[f32; 5], action: &[f32; 1]) -> usize {
    let hits: Vec<usize> = (0..all.len())
        .filter(|&k| all[k].0.obs == *obs && all[k].0.action == *action)
        .collect();
    assert_eq!(
        hits.len(),
        1,
        "state-action pair found {} times",
        hits.len()
    );
    hits[0]
}

#[test]
fn n_step_rows_fold_the_stored_transitions_that_follow() {
    const N: usize = 5;
    let mut t = trained(PolicyEvaluation::NStep, N as u32);
    let gamma = t.agent.learner.cfg.gamma;
    let all = stored(&t);
    let (mut short, mut checked) = (0, 0);
    for _ in 0..20 {
        t.fill_batch().unwrap();
        for chunk in t.agent.learner.batch.iter() {
            for i in 0..32 {
                let k = find(&all, &chunk.obs[0][i], &chunk.action[0][i]);
                let ep = all[k].1;
                let steps: Vec<&Transition<5, 1>> = all[k..]
                    .iter()
                    .take(N)
                    .take_while(|(_, e)| *e == ep)
                    .map(|(tr, _)| tr)
                    .collect();
                short += (steps.len() < N) as usize;
                let rewards: Vec<f32> = steps.iter().map(|tr| tr.reward).collect();
                let discounts: Vec<f32> = steps.iter().map(|tr| tr.discount).collect();
                let (r, b) = nstep(&rewards, &discounts, gamma);
                assert_eq!(
                    chunk.reward[0][i].to_bits(),
                    r.to_bits(),
                    "reward of row {i}"
                );
                assert_eq!(
                    chunk.bootstrap[0][i].to_bits(),
                    b.to_bits(),
                    "bootstrap of row {i}"
                );
                assert_eq!(chunk.next_obs[0][i], steps.last().unwrap().next_obs);
                assert_eq!(
                    chunk.behaviour_log_prob[0][i].to_bits(),
                    all[k].0.behaviour_log_prob.to_bits()
                );
                // Five steps of cartpole reward are more than one.
                assert!(steps.len() < N || r > all[k].0.reward);
                checked += 1;
            }
        }
    }
    eprintln!(
        "{checked} n-step rows checked, {short} cut short by an episode end or the newest data"
    );
    assert!(checked == 20 * 64);
}

#[test]
fn retrace_rows_are_consecutive_transitions_of_one_episode() {
    const L: usize = 4;
    let mut t = trained(PolicyEvaluation::Retrace, L as u32);
    let gamma = t.agent.learner.cfg.gamma;
    let all = stored(&t);
    for _ in 0..10 {
        t.fill_batch().unwrap();
        for chunk in t.agent.learner.batch.iter() {
            for i in 0..32 {
                let k = find(&all, &chunk.obs[0][i], &chunk.action[0][i]);
                for p in 0..L {
                    let (tr, ep) = &all[k + p];
                    assert_eq!(*ep, all[k].1, "position {p} leaves the episode");
                    assert_eq!(chunk.obs[p][i], tr.obs);
                    assert_eq!(chunk.action[p][i], tr.action);
                    assert_eq!(chunk.reward[p][i].to_bits(), tr.reward.to_bits());
                    assert_eq!(chunk.next_obs[p][i], tr.next_obs);
                    assert_eq!(
                        chunk.bootstrap[p][i].to_bits(),
                        (gamma * tr.discount).to_bits()
                    );
                    assert_eq!(
                        chunk.behaviour_log_prob[p][i].to_bits(),
                        tr.behaviour_log_prob.to_bits()
                    );
                }
            }
        }
    }
}
