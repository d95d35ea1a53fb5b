//! How far a network's hidden weights have grown since initialisation: the `metrics.csv`
//! columns `actor_weight_growth` and `critic_weight_growth`.
//!
//! Why: Adam's steps have a fixed size per weight, so as weights grow each step becomes a
//! smaller fraction of them, and where a layer norm downstream undoes their scale (the residual
//! networks' next block and final norm) that fraction is all the step changes: the effective
//! learning rate decays as the run goes, one of the two signs of lost plasticity
//! (docs/experiments.md, "Dormant units and grown weights"; `mpo.weight_norm` holds it
//! constant, at `sqrt(3)`: every column at unit norm; `mpo.reset_interval` sets it back to
//! about 1). Logged at every evaluation, it shows when the growth happens, not only where a
//! run ended.
//!
//! The figure: for each hidden layer (every weight matrix but the heads: the policy's mean and
//! Cholesky factor, the critic's output), the mean over its output units of the L2 norm of the
//! unit's incoming weights, divided by that norm's expectation at the learner's initialisation;
//! then the mean over the network's hidden layers. Every hidden layer starts uniform in
//! `+-1/sqrt(n)` over its `n` inputs (the critic's first layer over state and action together,
//! so its two stored parts are one matrix here), which gives a unit `E|w|^2 = n (1/n) / 3`:
//! a norm of about `sqrt(1/3)` whatever the width, so a fresh network reads about 1.

use mpo_core::params::Params;

use crate::checkpoint::Layout;

/// `sqrt(1/3)`: a unit's incoming weight norm at initialisation (module doc).
const INIT_NORM: f64 = 0.577_350_269_189_625_8;

/// Weight matrices that are heads, not hidden layers (their initialisation is scaled down).
const HEADS: [&str; 3] = ["mean.w", "chol.w", "out.w"];

/// The action rows of the critic's first layer: stored after its state rows, one matrix.
const ACTION_PARTS: [&str; 2] = ["l1a.w", "embed_a.w"];

/// The growth of `net`'s hidden weights (module doc), reading its tensors in `layout`'s order
/// (`checkpoint::actor_layout` or `critic_layout` of its sizes; shapes `[in, out]`).
pub fn growth<P: Params>(net: &P, layout: &Layout) -> f64 {
    assert_eq!(layout.len(), P::TENSORS, "layout of another network");
    // Per hidden layer, per output unit: the sum of squares of its incoming weights.
    let mut layers: Vec<Vec<f64>> = Vec::new();
    for (k, (name, shape)) in layout.iter().enumerate() {
        if !name.ends_with(".w") || HEADS.contains(&name.as_str()) {
            continue;
        }
        let sq = column_squares(net.tensor(k), shape[1]);
        if ACTION_PARTS.contains(&name.as_str()) {
            let state_part = layers.last_mut().expect("the state rows come first");
            for (s, a) in state_part.iter_mut().zip(sq) {
                *s += a;
            }
        } else {
            layers.push(sq);
        }
    }
    assert!(!layers.is_empty(), "a network without hidden layers");
    let per_layer = layers
        .iter()
        .map(|units| units.iter().map(|s| s.sqrt()).sum::<f64>() / units.len() as f64);
    per_layer.sum::<f64>() / layers.len() as f64 / INIT_NORM
}

/// The sum of squares of each column of an input-major `[in, out]` matrix stored row by row.
fn column_squares(w: &[f32], out: usize) -> Vec<f64> {
    let mut sq = vec![0f64; out];
    for row in w.chunks_exact(out) {
        for (s, &x) in sq.iter_mut().zip(row) {
            *s += f64::from(x) * f64::from(x);
        }
    }
    sq
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two tensors a test builds by hand: a `[3, 2]` hidden layer and a head.
    struct Tiny {
        hidden: [f32; 6],
        head: [f32; 2],
    }

    impl Params for Tiny {
        const TENSORS: usize = 2;
        fn tensor(&self, k: usize) -> &[f32] {
            [&self.hidden[..], &self.head[..]][k]
        }
        fn tensor_mut(&mut self, k: usize) -> &mut [f32] {
            match k {
                0 => &mut self.hidden,
                _ => &mut self.head,
            }
        }
        fn visit_mut<'a>(&'a mut self, f: &mut dyn FnMut(&'a mut [f32])) {
            f(&mut self.hidden);
            f(&mut self.head);
        }
    }

    #[test]
    fn the_columns_norms_are_read_from_an_input_major_matrix_and_the_head_is_left_out() {
        // Rows (inputs) [1, 0], [2, 0], [2, 3]: column 0 is (1, 2, 2), norm 3; column 1 is
        // (0, 0, 3), norm 3. The head, huge, must not count.
        let net = Tiny {
            hidden: [1.0, 0.0, 2.0, 0.0, 2.0, 3.0],
            head: [1e6, 1e6],
        };
        let layout = vec![
            ("l1.w".to_string(), vec![3, 2]),
            ("mean.w".to_string(), vec![1, 2]),
        ];
        let g = growth(&net, &layout);
        assert!((g - 3.0 / INIT_NORM).abs() < 1e-12, "{g}");
    }
}
