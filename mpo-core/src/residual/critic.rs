//! The residual critic: an embedding of `(s, a)` with separate observation and action blocks
//! (as the two-layer critic's first layer, so the E-step computes the observation part once
//! per state), a [`Trunk`], and an output of `K` units: a value, or the logits of a categorical
//! value ([`crate::value_head`]).

use bytemuck::Zeroable;

use super::trunk::{MAX_PARTS, Trunk, TrunkPart, TrunkTape, TrunkTransposed};
use crate::actor::sum_squares;
use crate::config::MpoConfig;
use crate::critic::Weights;
use crate::hypersphere::normalize_columns;
use crate::linear::{
    Linear, Start, accumulate, bias_grad_chunks, kernel, transpose, weight_grad_chunks,
};
use crate::network::{ValueGradInputs, ValueNet, chunk_slices};
use crate::parallel::Parallel;
use crate::rng::Rng;
use crate::value_head::{self, Support};

/// A residual critic for `OBS` observations and `ACT` actions: width `W`, blocks of inner
/// width `F`, `D` blocks, `K` outputs.
#[derive(Clone, Zeroable)]
#[repr(C)]
pub struct ResidualCritic<
    const OBS: usize,
    const ACT: usize,
    const W: usize,
    const F: usize,
    const D: usize,
    const K: usize,
> {
    /// The embedding's observation block and bias.
    pub embed_s: Linear<OBS, W>,
    /// The embedding's action block.
    pub embed_a: Weights<ACT, W>,
    /// Blocks and final norm.
    pub trunk: Trunk<W, F, D>,
    /// The output layer.
    pub out: Linear<W, K>,
}

crate::impl_params_for_fields!(ResidualCritic<const OBS: usize, const ACT: usize, const W: usize, const F: usize, const D: usize, const K: usize> {
    embed_s: Linear<OBS, W>,
    embed_a: Weights<ACT, W>,
    trunk: Trunk<W, F, D>,
    out: Linear<W, K>,
});

/// A batch's activations through a [`ResidualCritic`], its outputs and the loss's gradient.
#[derive(Clone, Zeroable)]
#[repr(C)]
pub struct ResidualCriticTape<
    const B: usize,
    const W: usize,
    const F: usize,
    const D: usize,
    const K: usize,
> {
    /// The trunk's activations.
    pub trunk: TrunkTape<B, W, F, D>,
    /// The outputs.
    pub out: [[f32; K]; B],
    /// A categorical head's probabilities (unused when `K = 1`).
    pub probs: [[f32; K]; B],
    /// The loss's gradient at the outputs.
    pub d_out: [[f32; K]; B],
}

/// A residual critic's weights transposed.
#[derive(Clone, Zeroable)]
#[repr(C)]
pub struct ResidualCriticTransposed<const W: usize, const F: usize, const D: usize, const K: usize>
{
    /// The output layer.
    pub out: [[f32; W]; K],
    /// The trunk.
    pub trunk: TrunkTransposed<W, F, D>,
}

/// One independent block of a residual critic's weight gradient.
enum Part<'a, const OBS: usize, const ACT: usize, const W: usize, const F: usize, const K: usize> {
    Embed {
        s: &'a mut Linear<OBS, W>,
        a: &'a mut Weights<ACT, W>,
    },
    Trunk(TrunkPart<'a, W, F>),
    Out(&'a mut Linear<W, K>),
}

impl<
    const OBS: usize,
    const ACT: usize,
    const W: usize,
    const F: usize,
    const D: usize,
    const K: usize,
> ResidualCritic<OBS, ACT, W, F, D, K>
{
    /// The trunk and the head on `tape.trunk.stream` (the embedding).
    fn finish<const B: usize>(
        &self,
        tape: &mut ResidualCriticTape<B, W, F, D, K>,
        q: &mut [f32; B],
        cfg: &MpoConfig,
    ) {
        self.trunk.forward(&mut tape.trunk);
        self.out.forward(&tape.trunk.z, &mut tape.out);
        value_head::values(&Support::of(cfg), &tape.out, &mut tape.probs, q);
    }

    /// Multiply-adds of one forward pass for one pair.
    pub const fn forward_macs() -> usize {
        (OBS + ACT) * W + D * 2 * W * F + W * K
    }
}

impl<
    const OBS: usize,
    const ACT: usize,
    const W: usize,
    const F: usize,
    const D: usize,
    const K: usize,
> ValueNet<OBS, ACT> for ResidualCritic<OBS, ACT, W, F, D, K>
{
    const HIDDEN: [usize; 2] = [W, F];
    const BLOCKS: usize = D;
    const BINS: usize = K;
    type StatePart<const B: usize> = [[f32; W]; B];
    type Tape<const B: usize> = ResidualCriticTape<B, W, F, D, K>;
    type Transposed = ResidualCriticTransposed<W, F, D, K>;
    const PROJECTS: bool = true;

    /// The embedding is one layer on the concatenation `(s, a)`: each unit's vector is its
    /// state and action weights together.
    fn project_weights(&mut self) {
        normalize_columns(&mut [&mut self.embed_s.w[..], &mut self.embed_a.w[..]]);
        self.trunk.project_weights();
    }

    /// Uniform fan-in layers (the embedding's fan-in is `OBS + ACT`, as one layer on the
    /// concatenation), identity normalisations.
    fn init(&mut self, rng: &mut Rng) {
        let bound = 1.0 / libm::sqrtf((OBS + ACT) as f32);
        for x in self.embed_s.w.as_flattened_mut() {
            *x = rng.uniform_range(-bound, bound);
        }
        for x in &mut self.embed_s.b {
            *x = rng.uniform_range(-bound, bound);
        }
        for x in self.embed_a.w.as_flattened_mut() {
            *x = rng.uniform_range(-bound, bound);
        }
        self.trunk.init(rng);
        self.out.init_uniform(rng);
    }

    fn state_part<const B: usize>(&self, obs: &[[f32; OBS]; B], part: &mut [[f32; W]; B]) {
        self.embed_s.forward(obs, part);
    }

    fn values_from_state_part<const B: usize>(
        &self,
        part: &[[f32; W]; B],
        act: &[[f32; ACT]; B],
        tape: &mut ResidualCriticTape<B, W, F, D, K>,
        q: &mut [f32; B],
        cfg: &MpoConfig,
    ) {
        kernel::<ACT, W, false>(
            act,
            &self.embed_a.w,
            Start::Rows(part),
            &mut tape.trunk.stream,
        );
        self.finish(tape, q, cfg);
    }

    fn values<const B: usize>(
        &self,
        obs: &[[f32; OBS]; B],
        act: &[[f32; ACT]; B],
        tape: &mut ResidualCriticTape<B, W, F, D, K>,
        q: &mut [f32; B],
        cfg: &MpoConfig,
    ) {
        self.embed_s.forward(obs, &mut tape.trunk.stream);
        accumulate(act, &self.embed_a.w, &mut tape.trunk.stream);
        self.finish(tape, q, cfg);
    }

    fn loss<const B: usize>(
        &self,
        tape: &mut ResidualCriticTape<B, W, F, D, K>,
        q: &[f32; B],
        y: &[f32; B],
        inv_b: f32,
        cfg: &MpoConfig,
        loss: &mut [f32; B],
    ) {
        let s = Support::of(cfg);
        value_head::loss(
            &s,
            &tape.out,
            &tape.probs,
            q,
            y,
            inv_b,
            &mut tape.d_out,
            loss,
        );
    }

    fn transpose_into(&self, t: &mut ResidualCriticTransposed<W, F, D, K>) {
        transpose(&self.out.w, &mut t.out);
        self.trunk.transpose_into(&mut t.trunk);
    }

    fn backprop<const B: usize>(
        &self,
        tape: &mut ResidualCriticTape<B, W, F, D, K>,
        t: &ResidualCriticTransposed<W, F, D, K>,
        _cfg: &MpoConfig,
    ) {
        for row in tape.trunk.d_z.iter_mut() {
            row.fill(0.0);
        }
        accumulate(&tape.d_out, &t.out, &mut tape.trunk.d_z);
        self.trunk.backprop(&mut tape.trunk, &t.trunk);
    }

    fn weight_grads<Par: Parallel, const B: usize>(
        grad: &mut Self,
        par: &Par,
        x: &ValueGradInputs<'_, OBS, ACT, ResidualCriticTape<B, W, F, D, K>>,
        _cfg: &MpoConfig,
    ) -> f64 {
        let mut parts: heapless::Vec<(Part<'_, OBS, ACT, W, F, K>, f64), MAX_PARTS> =
            heapless::Vec::new();
        let ResidualCritic {
            embed_s,
            embed_a,
            trunk,
            out,
        } = grad;
        let _ = parts.push((
            Part::Embed {
                s: embed_s,
                a: embed_a,
            },
            0.0,
        ));
        trunk.push_parts(&mut parts, |p| (Part::Trunk(p), 0.0));
        if parts.push((Part::Out(out), 0.0)).is_err() {
            panic!("more than {MAX_PARTS} gradient blocks");
        }
        let trunks: heapless::Vec<&TrunkTape<B, W, F, D>, { crate::network::MAX_CHUNKS }> =
            x.tapes.iter().map(|t| &t.trunk).collect();
        par.for_each(&mut parts, &|_, (p, sq)| {
            *sq = match p {
                Part::Embed { s, a } => {
                    let d_x0 = chunk_slices(&trunks, |t| &t.d_x0[..]);
                    weight_grad_chunks(x.obs, &d_x0, 0, &mut s.w);
                    bias_grad_chunks(&d_x0, &mut s.b);
                    weight_grad_chunks(x.act, &d_x0, 0, &mut a.w);
                    sum_squares(s.w.as_flattened())
                        + sum_squares(&s.b)
                        + sum_squares(a.w.as_flattened())
                }
                Part::Trunk(p) => p.compute(&trunks),
                Part::Out(l) => {
                    let z = chunk_slices(&trunks, |t| &t.z[..]);
                    let d_out = chunk_slices(x.tapes, |t| &t.d_out[..]);
                    weight_grad_chunks(&z, &d_out, 0, &mut l.w);
                    bias_grad_chunks(&d_out, &mut l.b);
                    sum_squares(l.w.as_flattened()) + sum_squares(&l.b)
                }
            }
        });
        parts.iter().map(|(_, sq)| *sq).sum::<f64>()
    }

    fn forward_macs() -> usize {
        Self::forward_macs()
    }

    fn state_macs() -> usize {
        OBS * W
    }

    fn backward_macs() -> usize {
        2 * Self::forward_macs() - (OBS + ACT) * W
    }
    fn relu_layers<const B: usize>(
        tape: &Self::Tape<B>,
        _cfg: &MpoConfig,
        visit: &mut dyn FnMut(&[f32], usize),
    ) {
        for h in &tape.trunk.h {
            visit(h.as_flattened(), F);
        }
    }
}
