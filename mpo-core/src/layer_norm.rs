//! Layer normalisation followed by `tanh`: the critic's optional first-layer activation.
//!
//! Acme's `LayerNormMLP` (the critic torso of its MPO agents) puts `LayerNorm` and `tanh` after
//! the first linear layer, which bounds the first hidden layer whatever the scale of the
//! observations (the Control Suite's are not normalised here). Per row of pre-activations `x`
//! of width `N`: `xhat = (x - mean(x)) / sqrt(var(x) + EPS)`, `y = g xhat + b`, `h = tanh(y)`.
//!
//! Every operation is an IEEE-exact one (`+`, `*`, fma, `sqrtf`) or `libm::tanhf` (portable
//! software, the same bits on every CPU), and sums run in index order, so the results are
//! bit-identical across builds and thread counts like the rest of the core.

use bytemuck::Zeroable;

use crate::linear::mul_add;
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
            *r = 1.0 / libm::sqrtf(var + EPS);
            for o in 0..N {
                xh[o] = (row[o] - mean) * *r;
                row[o] = libm::tanhf(mul_add(self.g[o], xh[o], self.b[o]));
            }
        }
    }

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
