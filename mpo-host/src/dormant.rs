//! Dormant units (Sokar et al., 2023): the `metrics.csv` columns `actor_dormant` and
//! `critic_dormant`, the fraction of a network's ReLU units that have all but stopped firing.
//!
//! Why: a unit whose activation is zero on every state gets no gradient, so no later step
//! revives it; a network that keeps losing units trains on less and less of itself, the other
//! sign of lost plasticity beside grown weights ([`crate::weight_growth`]). Measured at every
//! evaluation, it shows when units die (the MLP policy's second layer on hopper-hop had 48%
//! dead at 500k, the residual policy's blocks almost none: docs/experiments.md, "Dormant units
//! and grown weights"), where `docs/results/plasticity.py` reads a checkpoint after the fact.
//!
//! The figure: the online networks run on [`ROWS`] transitions of the replay buffer (evenly
//! spaced over its stored order, so no random draw is taken from the run's streams and the
//! run's bits do not change), the states normalised as the learner normalises a batch and the
//! critic at the stored behaviour actions. A unit's score is its mean `|activation|` over the
//! rows divided by its layer's mean score; a unit scoring at most [`TAU`] is dormant. The
//! column is the dormant units' share of all the network's ReLU units, in percent.

use mpo_core::config::MpoConfig;
use mpo_core::network::{PolicyTrain, ValueNet};
use mpo_core::replay::Replay;

/// Sokar et al.'s threshold: a unit below 2.5% of its layer's average activity is dormant.
pub const TAU: f64 = 0.025;

/// Transitions each measurement runs the networks on (fewer while the buffer holds fewer).
pub const ROWS: usize = 1024;

/// The summed `|activation|` of every unit of a network's ReLU layers over the rows seen.
#[derive(Default)]
pub struct UnitActivity {
    /// Per layer (in the order visited), per unit.
    layers: Vec<Vec<f64>>,
}

impl UnitActivity {
    /// Adds the activations of layer `layer` (rows of `width` units one after another).
    pub fn add(&mut self, layer: usize, h: &[f32], width: usize) {
        assert_eq!(h.len() % width, 0, "activations of another width");
        if self.layers.len() <= layer {
            self.layers.resize(layer + 1, Vec::new());
        }
        let sums = &mut self.layers[layer];
        if sums.is_empty() {
            sums.resize(width, 0.0);
        }
        assert_eq!(sums.len(), width, "layer {layer} changed width");
        for row in h.chunks_exact(width) {
            for (s, &v) in sums.iter_mut().zip(row) {
                *s += f64::from(v.abs());
            }
        }
    }

    /// A visitor for `relu_layers` that adds the first `n` rows of each layer it is handed,
    /// the layers numbered in the order they come.
    fn first_rows(&mut self, n: usize) -> impl FnMut(&[f32], usize) + '_ {
        let mut layer = 0;
        move |h, width| {
            self.add(layer, &h[..n * width], width);
            layer += 1;
        }
    }

    /// The dormant units' share of all units, in percent (module doc); 0 with no units.
    pub fn dormant_percent(&self) -> f64 {
        let (mut dormant, mut units) = (0usize, 0usize);
        for sums in &self.layers {
            let mean = sums.iter().sum::<f64>() / sums.len().max(1) as f64;
            // A layer silent on every row: every unit is dormant.
            dormant += sums.iter().filter(|&&s| s <= TAU * mean).count();
            units += sums.len();
        }
        if units == 0 {
            0.0
        } else {
            100.0 * dormant as f64 / units as f64
        }
    }
}

/// The replay positions a measurement reads: [`ROWS`] evenly spaced over `len` stored
/// transitions (every one while fewer are stored).
pub fn positions(len: usize) -> impl Iterator<Item = usize> {
    let n = len.min(ROWS);
    (0..n).map(move |i| i * len / n)
}

/// Rows of one forward pass.
const CHUNK: usize = 256;

/// The dormant units of the online networks, `[actor, critic]` in percent (module doc); `None`
/// while the buffer is empty.
pub fn measure<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    P: PolicyTrain<OBS, ACT, TRI>,
    Q: ValueNet<OBS, ACT>,
    const CAP: usize,
>(
    actor: &P,
    critic: &Q,
    cfg: &MpoConfig,
    replay: &Replay<CAP, OBS, ACT>,
) -> Option<[f64; 2]> {
    let at: Vec<usize> = positions(replay.len()).collect();
    if at.is_empty() {
        return None;
    }
    let mut obs: Box<[[f32; OBS]; CHUNK]> = bytemuck::zeroed_box();
    let mut act: Box<[[f32; ACT]; CHUNK]> = bytemuck::zeroed_box();
    let mut mean: Box<[[f32; ACT]; CHUNK]> = bytemuck::zeroed_box();
    let mut chol: Box<[[f32; TRI]; CHUNK]> = bytemuck::zeroed_box();
    let mut q = [0f32; CHUNK];
    let mut actor_tape: Box<P::Tape<CHUNK>> = bytemuck::zeroed_box();
    let mut critic_tape: Box<Q::Tape<CHUNK>> = bytemuck::zeroed_box();
    let (mut a, mut c) = (UnitActivity::default(), UnitActivity::default());
    for rows in at.chunks(CHUNK) {
        // A short last chunk leaves the previous rows behind it; only its own are counted.
        let n = rows.len();
        for (i, &k) in rows.iter().enumerate() {
            let t = replay.get(k);
            (obs[i], act[i]) = (t.obs, t.action);
        }
        actor.input().apply_rows(&mut obs[..n]);
        actor.forward(&obs, &mut actor_tape, &mut mean, &mut chol);
        P::relu_layers(&actor_tape, &mut a.first_rows(n));
        critic.values(&obs, &act, &mut critic_tape, &mut q, cfg);
        Q::relu_layers(&critic_tape, cfg, &mut c.first_rows(n));
    }
    Some([a.dormant_percent(), c.dormant_percent()])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_unit_below_tau_of_its_layers_mean_is_dormant_and_others_are_not() {
        // Layer 0, width 4, two rows: unit 0 never fires, unit 1 at 2% of the layer's mean,
        // units 2 and 3 busy. Layer 1, width 2: both alive.
        let mut a = UnitActivity::default();
        let busy = 10.0f32;
        // Unit sums: 0, 0.02 m, busy, busy, with m the layer's mean (solved below).
        // m = (0.02 m + 2 * 2 busy) / 4  =>  m (4 - 0.02) = 4 busy  =>  m = 4 busy / 3.98.
        let m = 4.0 * f64::from(busy) / 3.98;
        let small = (0.02 * m / 2.0) as f32;
        a.add(0, &[0.0, small, busy, busy, 0.0, -small, busy, -busy], 4);
        a.add(1, &[1.0, 2.0, 3.0, 0.5], 2);
        // One of six units dormant by score 0, one at 2% <= 2.5%: 2 of 6.
        assert!((a.dormant_percent() - 100.0 * 2.0 / 6.0).abs() < 1e-9);
        // At 3% of the mean the second unit is no longer dormant.
        let mut b = UnitActivity::default();
        let m = 4.0 * f64::from(busy) / 3.97;
        let small = (0.03 * m / 2.0) as f32;
        b.add(0, &[0.0, small, busy, busy, 0.0, small, busy, busy], 4);
        b.add(1, &[1.0, 2.0, 3.0, 0.5], 2);
        assert!((b.dormant_percent() - 100.0 / 6.0).abs() < 1e-9);
    }

    #[test]
    fn positions_spread_over_the_buffer_and_take_all_of_a_small_one() {
        assert_eq!(positions(5).collect::<Vec<_>>(), vec![0, 1, 2, 3, 4]);
        let p: Vec<usize> = positions(100_000).collect();
        assert_eq!(p.len(), ROWS);
        assert_eq!(p[0], 0);
        assert!(*p.last().unwrap() > 100_000 - 2 * 100_000 / ROWS);
        assert!(p.windows(2).all(|w| w[0] < w[1]));
    }
}
