//! Layer normalisation: the critic's optional first-layer activation (followed by `tanh`) and
//! the pre-normalisation of the residual networks' blocks ([`crate::residual`]).
//!
//! Acme's `LayerNormMLP` (the critic torso of its MPO agents) puts `LayerNorm` and `tanh` after
//! the first linear layer, which bounds the first hidden layer whatever the scale of the
//! observations (the Control Suite's are not normalised here). Per row of pre-activations `x`
//! of width `N`: `xhat = (x - mean(x)) / sqrt(var(x) + EPS)`, `y = g xhat + b`, `h = tanh(y)`.
//!
//! Every operation is an IEEE-exact one (`+`, `*`, fma, `sqrtf`) or [`crate::mathf::tanh`]
//! (written from those, branch-free: the `tanh` loop vectorises, where `libm::tanhf` ran one
//! unit at a time), and sums run in index order, so the results are bit-identical across
//! builds, CPUs and thread counts like the rest of the core.
//!
//! The residual networks' form ([`LayerNorm::forward_rows`], [`LayerNorm::backward_rows`]) has
//! no `tanh` and sums each row in eight lanes ([`crate::lanes`]: lane `l` adds the entries
//! `i = l mod 8` in ascending order, then the lanes are added pairwise in a fixed tree): one
//! 8-wide register of partial sums on the host, and a device without vector units computes
//! the same bits one lane at a time.

use bytemuck::Zeroable;

#[cfg(feature = "train")]
use crate::lanes::dot8;
use crate::lanes::{normalize_into, sq_dev8, sum8};
use crate::linear::{mul_add, sqrt};
use crate::mathf::tanh;
use crate::params::Params;

/// Added to the variance (PyTorch's and Haiku's default).
pub const EPS: f32 = 1e-5;

/// The affine part of a layer norm: gain `g` and bias `b`.
#[derive(Clone, Zeroable)]
#[repr(C)]
pub struct LayerNorm<const N: usize> {
    /// Gain (initialised to 1).
    pub g: [f32; N],
    /// Bias (initialised to 0).
    pub b: [f32; N],
}

impl<const N: usize> Params for LayerNorm<N> {
    const TENSORS: usize = 2;
    fn tensor(&self, k: usize) -> &[f32] {
        match k {
            0 => &self.g,
            1 => &self.b,
            _ => panic!("LayerNorm has 2 tensors"),
        }
    }
    fn tensor_mut(&mut self, k: usize) -> &mut [f32] {
        match k {
            0 => &mut self.g,
            1 => &mut self.b,
            _ => panic!("LayerNorm has 2 tensors"),
        }
    }
    fn visit_mut<'a>(&'a mut self, f: &mut dyn FnMut(&'a mut [f32])) {
        f(&mut self.g);
        f(&mut self.b);
    }
}

impl<const N: usize> LayerNorm<N> {
    /// The identity affine map (gain 1, bias 0), as Acme and PyTorch initialise it.
    pub fn init(&mut self) {
        self.g.fill(1.0);
        self.b.fill(0.0);
    }

    /// Replaces each row of pre-activations `x` by `tanh(g xhat + b)`, keeping `xhat` and
    /// `1 / sqrt(var + EPS)` of each row for [`Self::backward`].
    pub fn forward_tanh(&self, x: &mut [[f32; N]], xhat: &mut [[f32; N]], rstd: &mut [f32]) {
        for ((row, xh), r) in x.iter_mut().zip(xhat.iter_mut()).zip(rstd.iter_mut()) {
            let inv_n = 1.0 / N as f32;
            let mean = row.iter().sum::<f32>() * inv_n;
            let var = row.iter().map(|&v| (v - mean) * (v - mean)).sum::<f32>() * inv_n;
            *r = 1.0 / sqrt(var + EPS);
            for o in 0..N {
                xh[o] = (row[o] - mean) * *r;
                row[o] = tanh(mul_add(self.g[o], xh[o], self.b[o]));
            }
        }
    }

    #[cfg(feature = "train")]
    /// Given `d` = the gradient at the `tanh` outputs `h` (one row per sample), stores the
    /// gradient at `y = g xhat + b` in `d_y` (for the gain and bias gradients) and replaces
    /// `d` by the gradient at the pre-activations `x`:
    /// `dx = rstd (dxhat - mean(dxhat) - xhat mean(dxhat xhat))` with `dxhat = g d_y`.
    pub fn backward(
        &self,
        h: &[[f32; N]],
        xhat: &[[f32; N]],
        rstd: &[f32],
        d: &mut [[f32; N]],
        d_y: &mut [[f32; N]],
    ) {
        let inv_n = 1.0 / N as f32;
        for n in 0..d.len() {
            let (mut s1, mut s2) = (0f32, 0f32);
            for o in 0..N {
                d_y[n][o] = d[n][o] * (1.0 - h[n][o] * h[n][o]);
                let dxh = d_y[n][o] * self.g[o];
                s1 += dxh;
                s2 += dxh * xhat[n][o];
            }
            let (m1, m2) = (s1 * inv_n, s2 * inv_n);
            for o in 0..N {
                let dxh = d_y[n][o] * self.g[o];
                d[n][o] = rstd[n] * (dxh - m1 - xhat[n][o] * m2);
            }
        }
    }
}

#[cfg(feature = "train")]
/// Gain and bias gradients over chunks (chunks in order, rows ascending; overwrites `grad`):
/// `dg = sum d_y xhat`, `db = sum d_y`.
pub fn param_grad_chunks<const N: usize>(
    xhat: &[&[[f32; N]]],
    d_y: &[&[[f32; N]]],
    grad: &mut LayerNorm<N>,
) {
    grad.g.fill(0.0);
    grad.b.fill(0.0);
    for (xc, dc) in xhat.iter().zip(d_y) {
        for (x, d) in xc.iter().zip(dc.iter()) {
            for o in 0..N {
                grad.g[o] = mul_add(d[o], x[o], grad.g[o]);
                grad.b[o] += d[o];
            }
        }
    }
}

impl<const N: usize> LayerNorm<N> {
    /// One row: `xhat = (x - mean) rstd` with `rstd = 1 / sqrt(var + EPS)`, `y = g xhat + b`;
    /// returns `rstd`. Mean and variance are [`sum8`]-ordered sums times `1 / N`.
    #[inline]
    pub fn normalize(&self, x: &[f32; N], xhat: &mut [f32; N], y: &mut [f32; N]) -> f32 {
        let inv_n = 1.0 / N as f32;
        let mean = sum8(x) * inv_n;
        let var = sq_dev8(x, mean) * inv_n;
        let r = 1.0 / sqrt(var + EPS);
        normalize_into(x, mean, r, &self.g, &self.b, xhat, y);
        r
    }

    /// [`Self::normalize`] for every row (the residual blocks' pre-normalisation).
    pub fn forward_rows(
        &self,
        x: &[[f32; N]],
        xhat: &mut [[f32; N]],
        rstd: &mut [f32],
        y: &mut [[f32; N]],
    ) {
        for (((x, xh), r), y) in x.iter().zip(xhat.iter_mut()).zip(rstd.iter_mut()).zip(y) {
            *r = self.normalize(x, xh, y);
        }
    }

    #[cfg(feature = "train")]
    /// Given `d_y`, the gradient at the outputs of [`Self::forward_rows`], adds the gradient at
    /// its inputs to `dx`: `dx += rstd (dxhat - mean(dxhat) - xhat mean(dxhat xhat))` with
    /// `dxhat = g d_y` (the means [`sum8`]- and [`dot8`]-ordered). Adding, not overwriting,
    /// is what a residual block needs: its input's gradient is the skip's plus this one.
    pub fn backward_rows(
        &self,
        xhat: &[[f32; N]],
        rstd: &[f32],
        d_y: &[[f32; N]],
        dx: &mut [[f32; N]],
    ) {
        let inv_n = 1.0 / N as f32;
        for (((xh, &r), dy), dx) in xhat.iter().zip(rstd).zip(d_y).zip(dx.iter_mut()) {
            let mut dxh = [0f32; N];
            for o in 0..N {
                dxh[o] = self.g[o] * dy[o];
            }
            let m1 = sum8(&dxh) * inv_n;
            let m2 = dot8(&dxh, xh) * inv_n;
            for o in 0..N {
                dx[o] += r * (dxh[o] - m1 - xh[o] * m2);
            }
        }
    }
}
