//! The residual policy: observation normalisation, a linear embedding, a [`Trunk`], and the
//! mean and Cholesky heads of the two-layer actor ([`crate::actor::Actor`]).

use bytemuck::Zeroable;

use super::trunk::Trunk;
#[cfg(feature = "train")]
use super::trunk::TrunkTape;
use crate::gaussian::{softplus_inverse, tri_index};
use crate::linear::Linear;
use crate::network::PolicyNet;
use crate::obs_norm::InputNorm;
use crate::params::Params;
use crate::rng::Rng;
use crate::squash::MeanSquash;

#[cfg(feature = "train")]
use super::trunk::{MAX_PARTS, TrunkPart, TrunkTransposed};
#[cfg(feature = "train")]
use crate::actor::sum_squares;
#[cfg(feature = "train")]
use crate::hypersphere::normalize_columns;
#[cfg(feature = "train")]
use crate::linear::{accumulate, bias_grad_chunks, transpose, weight_grad_chunks};
#[cfg(feature = "train")]
use crate::network::{PolicyGradInputs, PolicyTrain, chunk_slices};
#[cfg(feature = "train")]
use crate::parallel::Parallel;

/// A residual policy for `OBS` observations and `ACT` actions (`TRI = ACT (ACT + 1) / 2`):
/// width `W`, blocks of inner width `F`, `D` blocks.
#[derive(Clone, Zeroable)]
#[repr(C)]
pub struct ResidualActor<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    const W: usize,
    const F: usize,
    const D: usize,
> {
    /// Observation normalisation (the identity unless fit; never trained by gradients).
    pub input: InputNorm<OBS>,
    /// The embedding.
    pub embed: Linear<OBS, W>,
    /// Blocks and final norm.
    pub trunk: Trunk<W, F, D>,
    /// Mean head.
    pub mean: Linear<W, ACT>,
    /// Cholesky head (packed lower triangle; diagonal before softplus).
    pub chol: Linear<W, TRI>,
    /// The mean's bound (unbounded unless set; never trained by gradients).
    pub squash: MeanSquash<ACT>,
}

crate::impl_params_for_fields!(ResidualActor<const OBS: usize, const ACT: usize, const TRI: usize, const W: usize, const F: usize, const D: usize> {
    input: InputNorm<OBS>,
    embed: Linear<OBS, W>,
    trunk: Trunk<W, F, D>,
    mean: Linear<W, ACT>,
    chol: Linear<W, TRI>,
    squash: MeanSquash<ACT>,
});

impl<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    const W: usize,
    const F: usize,
    const D: usize,
> ResidualActor<OBS, ACT, TRI, W, F, D>
{
    /// Initialises in place as [`crate::actor::Actor::init`] does: uniform fan-in layers,
    /// identity normalisations, heads scaled down so the initial policy is close to
    /// `N(0, init_std^2 I)`.
    pub fn init(&mut self, rng: &mut Rng, init_std: f32, std_floor: f32) {
        const { assert!(TRI == ACT * (ACT + 1) / 2, "TRI must be ACT(ACT+1)/2") };
        self.input.init();
        self.squash.init(0.0);
        self.embed.init_uniform(rng);
        self.trunk.init(rng);
        self.mean.init_uniform(rng);
        self.chol.init_uniform(rng);
        self.mean.scale(0.01);
        self.chol.scale(0.01);
        let diag = softplus_inverse((init_std - std_floor).max(1e-3));
        for j in 0..ACT {
            self.chol.b[tri_index(j, j)] += diag;
        }
    }

    /// The trunk's output for one state (normalised here).
    fn features(&self, obs: &[f32; OBS], z: &mut [f32; W]) {
        let x = self.input.apply(obs);
        let mut e = [[0f32; W]; 1];
        self.embed.forward(core::slice::from_ref(&x), &mut e);
        self.trunk.forward_one(&mut e[0], z);
    }

    /// Head outputs for one state: the squashed mean and the raw Cholesky entries.
    pub fn forward_one(&self, obs: &[f32; OBS], mean: &mut [f32; ACT], chol: &mut [f32; TRI]) {
        let mut z = [0f32; W];
        self.features(obs, &mut z);
        let z = core::slice::from_ref(&z);
        self.mean.forward(z, core::slice::from_mut(mean));
        self.squash.apply(mean);
        self.chol.forward(z, core::slice::from_mut(chol));
    }

    /// The mean action for one state: what a deployed controller executes.
    pub fn mean_action(&self, obs: &[f32; OBS], action: &mut [f32; ACT]) {
        let mut z = [0f32; W];
        self.features(obs, &mut z);
        self.mean
            .forward(core::slice::from_ref(&z), core::slice::from_mut(action));
        self.squash.apply(action);
    }

    /// Multiply-adds of one forward pass for one state.
    pub const fn forward_macs() -> usize {
        OBS * W + D * 2 * W * F + W * (ACT + TRI)
    }
}

impl<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    const W: usize,
    const F: usize,
    const D: usize,
> PolicyNet<OBS, ACT, TRI> for ResidualActor<OBS, ACT, TRI, W, F, D>
{
    const HIDDEN: [usize; 2] = [W, F];
    const BLOCKS: usize = D;

    fn init(&mut self, rng: &mut Rng, init_std: f32, std_floor: f32) {
        ResidualActor::init(self, rng, init_std, std_floor);
    }
    fn input(&self) -> &InputNorm<OBS> {
        &self.input
    }
    fn input_mut(&mut self) -> &mut InputNorm<OBS> {
        &mut self.input
    }
    fn squash(&self) -> &MeanSquash<ACT> {
        &self.squash
    }
    fn squash_mut(&mut self) -> &mut MeanSquash<ACT> {
        &mut self.squash
    }
    fn forward_one(&self, obs: &[f32; OBS], mean: &mut [f32; ACT], chol: &mut [f32; TRI]) {
        ResidualActor::forward_one(self, obs, mean, chol);
    }
    fn mean_action(&self, obs: &[f32; OBS], action: &mut [f32; ACT]) {
        ResidualActor::mean_action(self, obs, action);
    }
    fn forward_macs() -> usize {
        Self::forward_macs()
    }
}

#[cfg(feature = "train")]
/// A residual policy's weights transposed.
#[derive(Clone, Zeroable)]
#[repr(C)]
pub struct ResidualActorTransposed<
    const ACT: usize,
    const TRI: usize,
    const W: usize,
    const F: usize,
    const D: usize,
> {
    /// Mean head.
    pub mean: [[f32; W]; ACT],
    /// Cholesky head.
    pub chol: [[f32; W]; TRI],
    /// The trunk.
    pub trunk: TrunkTransposed<W, F, D>,
}

#[cfg(feature = "train")]
/// One independent block of a residual policy's weight gradient.
enum Part<'a, const OBS: usize, const ACT: usize, const TRI: usize, const W: usize, const F: usize>
{
    Embed(&'a mut Linear<OBS, W>),
    Trunk(TrunkPart<'a, W, F>),
    Heads {
        mean: &'a mut Linear<W, ACT>,
        chol: &'a mut Linear<W, TRI>,
    },
}

#[cfg(feature = "train")]
impl<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    const W: usize,
    const F: usize,
    const D: usize,
> PolicyTrain<OBS, ACT, TRI> for ResidualActor<OBS, ACT, TRI, W, F, D>
{
    type Tape<const B: usize> = TrunkTape<B, W, F, D>;
    type Transposed = ResidualActorTransposed<ACT, TRI, W, F, D>;
    const PROJECTS: bool = true;

    fn project_weights(&mut self) {
        normalize_columns(&mut [&mut self.embed.w[..]]);
        self.trunk.project_weights();
    }

    fn forward<const B: usize>(
        &self,
        obs: &[[f32; OBS]; B],
        tape: &mut TrunkTape<B, W, F, D>,
        mean: &mut [[f32; ACT]; B],
        chol: &mut [[f32; TRI]; B],
    ) {
        self.embed.forward(obs, &mut tape.stream);
        self.trunk.forward(tape);
        self.mean.forward(&tape.z, mean);
        self.squash.apply_rows(mean);
        self.chol.forward(&tape.z, chol);
    }

    fn transpose_into(&self, t: &mut ResidualActorTransposed<ACT, TRI, W, F, D>) {
        transpose(&self.mean.w, &mut t.mean);
        transpose(&self.chol.w, &mut t.chol);
        self.trunk.transpose_into(&mut t.trunk);
    }

    fn backprop<const B: usize>(
        &self,
        tape: &mut TrunkTape<B, W, F, D>,
        d_mean: &[[f32; ACT]; B],
        d_chol: &[[f32; TRI]; B],
        t: &ResidualActorTransposed<ACT, TRI, W, F, D>,
    ) {
        for row in tape.d_z.iter_mut() {
            row.fill(0.0);
        }
        accumulate(d_mean, &t.mean, &mut tape.d_z);
        accumulate(d_chol, &t.chol, &mut tape.d_z);
        self.trunk.backprop(tape, &t.trunk);
    }

    fn weight_grads<Par: Parallel, const B: usize>(
        grad: &mut Self,
        par: &Par,
        x: &PolicyGradInputs<'_, OBS, ACT, TRI, TrunkTape<B, W, F, D>>,
    ) -> f64 {
        let mut parts: heapless::Vec<(Part<'_, OBS, ACT, TRI, W, F>, f64), MAX_PARTS> =
            heapless::Vec::new();
        let ResidualActor {
            embed,
            trunk,
            mean,
            chol,
            ..
        } = grad;
        let _ = parts.push((Part::Embed(embed), 0.0));
        trunk.push_parts(&mut parts, |p| (Part::Trunk(p), 0.0));
        if parts.push((Part::Heads { mean, chol }, 0.0)).is_err() {
            panic!("more than {MAX_PARTS} gradient blocks");
        }
        par.for_each(&mut parts, &|_, (p, sq)| {
            *sq = match p {
                Part::Embed(l) => {
                    let d_x0 = chunk_slices(x.tapes, |t| &t.d_x0[..]);
                    weight_grad_chunks(x.obs, &d_x0, 0, &mut l.w);
                    bias_grad_chunks(&d_x0, &mut l.b);
                    sum_squares(l.w.as_flattened()) + sum_squares(&l.b)
                }
                Part::Trunk(p) => p.compute(x.tapes),
                Part::Heads { mean, chol } => {
                    let z = chunk_slices(x.tapes, |t| &t.z[..]);
                    weight_grad_chunks(&z, x.d_mean, 0, &mut mean.w);
                    bias_grad_chunks(x.d_mean, &mut mean.b);
                    weight_grad_chunks(&z, x.d_chol, 0, &mut chol.w);
                    bias_grad_chunks(x.d_chol, &mut chol.b);
                    sum_squares(mean.w.as_flattened())
                        + sum_squares(&mean.b)
                        + sum_squares(chol.w.as_flattened())
                        + sum_squares(&chol.b)
                }
            }
        });
        parts.iter().map(|(_, sq)| *sq).sum::<f64>()
    }

    fn backward_macs() -> usize {
        2 * Self::forward_macs() - OBS * W
    }
    fn relu_layers<const B: usize>(tape: &Self::Tape<B>, visit: &mut dyn FnMut(&[f32], usize)) {
        for h in &tape.h {
            visit(h.as_flattened(), F);
        }
    }
}
