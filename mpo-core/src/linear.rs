//! The fully connected layer and its hand-written kernels.
//!
//! Weights are stored input-major (`w[i][o]`), so every kernel is an axpy over outputs that the
//! compiler vectorises without reassociating a sum. Every output is accumulated in the same
//! order on every path (initial value, then inputs in ascending order), which is why a batch
//! forward gives the same bits as a single-state forward, and why no target CPU changes a
//! result (Rust never contracts `a * b + c` into an FMA).
//!
//! FLOPs: forward `2 B I O`; backward `2 B I O` for the weight gradient plus `2 B I O` for the
//! input gradient when it is asked for.
//!
//! Kernels: [`accumulate`] (forward, and input gradients through transposed weights) keeps a
//! 4-sample x 16-output tile in registers; [`weight_grad`] a 4-input x 16-output tile.

use bytemuck::Zeroable;

use crate::params::Params;
use crate::rng::Rng;

/// Output tile width of the batch kernels (two AVX2 registers).
const TILE_O: usize = 16;
/// Samples per tile of the batch kernels.
const TILE_N: usize = 4;
/// Input rows per tile of the weight-gradient kernel.
#[cfg(feature = "train")]
const TILE_I: usize = 4;
/// Output chunk of the single-sample kernel: eight AVX2 registers of independent accumulators,
/// enough to hide the add latency.
const CHUNK_1: usize = 64;

/// A dense layer `y = b + x W` with `I` inputs and `O` outputs.
#[derive(Clone, Zeroable)]
#[repr(C)]
pub struct Linear<const I: usize, const O: usize> {
    /// Input-major weights: `w[i][o]` multiplies input `i` into output `o`.
    pub w: [[f32; O]; I],
    /// Bias.
    pub b: [f32; O],
}

impl<const I: usize, const O: usize> Params for Linear<I, O> {
    const TENSORS: usize = 2;
    fn tensor(&self, k: usize) -> &[f32] {
        match k {
            0 => self.w.as_flattened(),
            1 => &self.b,
            _ => panic!("Linear has 2 tensors, asked for {k}"),
        }
    }
    fn tensor_mut(&mut self, k: usize) -> &mut [f32] {
        match k {
            0 => self.w.as_flattened_mut(),
            1 => &mut self.b,
            _ => panic!("Linear has 2 tensors, asked for {k}"),
        }
    }
}

impl<const I: usize, const O: usize> Linear<I, O> {
    /// Fills weights and biases uniformly in `[-1/sqrt(I), 1/sqrt(I)]` (the common default
    /// for ReLU networks; keeps the first updates well scaled whatever the width).
    pub fn init_uniform(&mut self, rng: &mut Rng) {
        let bound = 1.0 / libm::sqrtf(I as f32);
        for x in self.w.as_flattened_mut() {
            *x = rng.uniform_range(-bound, bound);
        }
        for x in &mut self.b {
            *x = rng.uniform_range(-bound, bound);
        }
    }

    /// `y = b + x W` for every row of `x`.
    pub fn forward(&self, x: &[[f32; I]], y: &mut [[f32; O]]) {
        for row in y.iter_mut() {
            *row = self.b;
        }
        accumulate(x, &self.w, y);
    }

    #[cfg(feature = "train")]
    /// As [`Self::backward`] with the input gradient computed through a transposed copy of
    /// the weights in `wt` (scratch): the fast path for wide layers, where it turns the input
    /// gradient into the same register-tiled kernel as the forward pass.
    pub fn backward_wide(
        &self,
        x: &[[f32; I]],
        dy: &[[f32; O]],
        grad: &mut Linear<I, O>,
        dx: &mut [[f32; I]],
        wt: &mut [[f32; I]; O],
    ) {
        weight_grad(x, dy, &mut grad.w);
        bias_grad(dy, &mut grad.b);
        transpose(&self.w, wt);
        for row in dx.iter_mut() {
            row.fill(0.0);
        }
        accumulate(dy, wt, dx);
    }

    #[cfg(feature = "train")]
    /// Weight and bias gradients of `sum_n dy[n] . y[n]`, written into `grad` (overwriting
    /// it), and optionally the input gradient `dx = dy W^T`.
    pub fn backward(
        &self,
        x: &[[f32; I]],
        dy: &[[f32; O]],
        grad: &mut Linear<I, O>,
        dx: Option<&mut [[f32; I]]>,
    ) {
        weight_grad(x, dy, &mut grad.w);
        bias_grad(dy, &mut grad.b);
        if let Some(dx) = dx {
            input_grad(&self.w, dy, dx);
        }
    }
}

/// `y[n] += x[n] W` for every row, each output summed in ascending input order.
pub fn accumulate<const I: usize, const O: usize>(
    x: &[[f32; I]],
    w: &[[f32; O]; I],
    y: &mut [[f32; O]],
) {
    assert_eq!(x.len(), y.len(), "accumulate: batch sizes differ");
    let n_full = x.len() / TILE_N * TILE_N;
    let (x_full, x_rest) = x.split_at(n_full);
    let (y_full, y_rest) = y.split_at_mut(n_full);
    // Output strips outermost: one strip of weights (I x 16 floats, 16 KiB at I = 256) stays
    // in L1 while every sample tile passes over it, instead of streaming all of W from L2
    // once per sample tile.
    let o_full = O / TILE_O * TILE_O;
    let mut o0 = 0;
    while o0 < o_full {
        for (xs, ys) in x_full
            .chunks_exact(TILE_N)
            .zip(y_full.chunks_exact_mut(TILE_N))
        {
            accumulate_tile(xs, w, ys, o0);
        }
        o0 += TILE_O;
    }
    if o_full < O {
        for (xs, ys) in x_full.iter().zip(y_full.iter_mut()) {
            for i in 0..I {
                let xi = xs[i];
                for o in o_full..O {
                    ys[o] += xi * w[i][o];
                }
            }
        }
    }
    for (xr, yr) in x_rest.iter().zip(y_rest) {
        accumulate_one(xr, w, yr);
    }
}

/// Four samples by sixteen outputs from `o0`: 4 x 16 accumulators stay in registers while
/// the inputs stream.
#[inline(always)]
fn accumulate_tile<const I: usize, const O: usize>(
    x: &[[f32; I]],
    w: &[[f32; O]; I],
    y: &mut [[f32; O]],
    o0: usize,
) {
    let mut acc = [[0f32; TILE_O]; TILE_N];
    for s in 0..TILE_N {
        acc[s].copy_from_slice(&y[s][o0..o0 + TILE_O]);
    }
    for i in 0..I {
        let wr: &[f32; TILE_O] = w[i][o0..o0 + TILE_O].try_into().unwrap();
        for s in 0..TILE_N {
            let xs = x[s][i];
            for l in 0..TILE_O {
                acc[s][l] += xs * wr[l];
            }
        }
    }
    for s in 0..TILE_N {
        y[s][o0..o0 + TILE_O].copy_from_slice(&acc[s]);
    }
}

/// One sample: output chunks of 32 accumulators, inputs streaming.
#[inline(always)]
fn accumulate_one<const I: usize, const O: usize>(
    x: &[f32; I],
    w: &[[f32; O]; I],
    y: &mut [f32; O],
) {
    let o_full = O / CHUNK_1 * CHUNK_1;
    let mut o0 = 0;
    while o0 < o_full {
        let mut acc = [0f32; CHUNK_1];
        acc.copy_from_slice(&y[o0..o0 + CHUNK_1]);
        for i in 0..I {
            let wr: &[f32; CHUNK_1] = w[i][o0..o0 + CHUNK_1].try_into().unwrap();
            let xi = x[i];
            for l in 0..CHUNK_1 {
                acc[l] += xi * wr[l];
            }
        }
        y[o0..o0 + CHUNK_1].copy_from_slice(&acc);
        o0 += CHUNK_1;
    }
    if o_full < O {
        for i in 0..I {
            let xi = x[i];
            for o in o_full..O {
                y[o] += xi * w[i][o];
            }
        }
    }
}

#[cfg(feature = "train")]
/// `gw[i][o] = sum_n x[n][i] dy[n][o]`, summed in ascending sample order.
pub fn weight_grad<const I: usize, const O: usize>(
    x: &[[f32; I]],
    dy: &[[f32; O]],
    gw: &mut [[f32; O]; I],
) {
    assert_eq!(x.len(), dy.len(), "weight_grad: batch sizes differ");
    let o_full = O / TILE_O * TILE_O;
    let i_full = I / TILE_I * TILE_I;
    let mut i0 = 0;
    while i0 < i_full {
        let mut o0 = 0;
        while o0 < o_full {
            let mut acc = [[0f32; TILE_O]; TILE_I];
            for (xn, dyn_) in x.iter().zip(dy) {
                let d: &[f32; TILE_O] = dyn_[o0..o0 + TILE_O].try_into().unwrap();
                for k in 0..TILE_I {
                    let xk = xn[i0 + k];
                    for l in 0..TILE_O {
                        acc[k][l] += xk * d[l];
                    }
                }
            }
            for k in 0..TILE_I {
                gw[i0 + k][o0..o0 + TILE_O].copy_from_slice(&acc[k]);
            }
            o0 += TILE_O;
        }
        i0 += TILE_I;
    }
    // Rows past the last full input tile, and columns past the last full output tile: the
    // same per-element order (samples ascending), samples in the outer loop so each input row
    // is read once and the small block of gradients stays in L1.
    let rest = |i: usize| if i < i_full { o_full } else { 0 };
    for i in 0..I {
        gw[i][rest(i)..].fill(0.0);
    }
    if o_full < O || i_full < I {
        for (xn, dyn_) in x.iter().zip(dy) {
            for i in 0..I {
                let xi = xn[i];
                let o_start = rest(i);
                for (g, d) in gw[i][o_start..].iter_mut().zip(&dyn_[o_start..]) {
                    *g += xi * d;
                }
            }
        }
    }
}

#[cfg(feature = "train")]
/// `wt = w^T`, in 8 x 8 blocks so both sides stay in cache.
pub fn transpose<const I: usize, const O: usize>(w: &[[f32; O]; I], wt: &mut [[f32; I]; O]) {
    const BLK: usize = 8;
    let mut i0 = 0;
    while i0 < I {
        let i1 = (i0 + BLK).min(I);
        let mut o0 = 0;
        while o0 < O {
            let o1 = (o0 + BLK).min(O);
            for i in i0..i1 {
                for o in o0..o1 {
                    wt[o][i] = w[i][o];
                }
            }
            o0 = o1;
        }
        i0 = i1;
    }
}

#[cfg(feature = "train")]
/// `gb[o] = sum_n dy[n][o]`, in ascending sample order.
pub fn bias_grad<const O: usize>(dy: &[[f32; O]], gb: &mut [f32; O]) {
    gb.fill(0.0);
    for d in dy {
        for o in 0..O {
            gb[o] += d[o];
        }
    }
}

#[cfg(feature = "train")]
/// `dx[n][i] = sum_o w[i][o] dy[n][o]`, one accumulator per element in ascending `o`: the
/// path for narrow layers (the heads). Wide layers use [`Linear::backward_wide`], which turns
/// this product into the register-tiled forward kernel on transposed weights.
pub fn input_grad<const I: usize, const O: usize>(
    w: &[[f32; O]; I],
    dy: &[[f32; O]],
    dx: &mut [[f32; I]],
) {
    assert_eq!(dx.len(), dy.len(), "input_grad: batch sizes differ");
    for (d, x) in dy.iter().zip(dx.iter_mut()) {
        for i in 0..I {
            let mut v = 0.0;
            for o in 0..O {
                v += w[i][o] * d[o];
            }
            x[i] = v;
        }
    }
}

/// `x = max(x, 0)` in place.
pub fn relu<const N: usize>(x: &mut [[f32; N]]) {
    for v in x.as_flattened_mut() {
        *v = v.max(0.0);
    }
}

#[cfg(feature = "train")]
/// Backpropagates through a ReLU given its output: `d *= (out > 0)`.
pub fn relu_backward<const N: usize>(out: &[[f32; N]], d: &mut [[f32; N]]) {
    for (g, &a) in d.as_flattened_mut().iter_mut().zip(out.as_flattened()) {
        if a <= 0.0 {
            *g = 0.0;
        }
    }
}

#[cfg(all(test, feature = "train"))]
mod tests {
    use super::*;

    fn naive_forward<const I: usize, const O: usize>(l: &Linear<I, O>, x: &[f32; I]) -> [f64; O] {
        let mut y = [0f64; O];
        for o in 0..O {
            y[o] = l.b[o] as f64;
            for i in 0..I {
                y[o] += x[i] as f64 * l.w[i][o] as f64;
            }
        }
        y
    }

    fn layer<const I: usize, const O: usize>(seed: u64) -> Linear<I, O> {
        let mut l = Linear::<I, O>::zeroed();
        l.init_uniform(&mut Rng::seed_from_u64(seed));
        l
    }

    #[test]
    fn batch_forward_matches_naive_and_single_bits() {
        // Sizes that exercise full tiles and every remainder path.
        const I: usize = 19;
        const O: usize = 37;
        const B: usize = 7;
        let l = layer::<I, O>(1);
        let mut rng = Rng::seed_from_u64(2);
        let mut x = [[0f32; I]; B];
        rng.fill_normal(x.as_flattened_mut());
        let mut y = [[0f32; O]; B];
        l.forward(&x, &mut y);
        for n in 0..B {
            let r = naive_forward(&l, &x[n]);
            let mut y1 = [[0f32; O]; 1];
            l.forward(core::slice::from_ref(&x[n]), &mut y1);
            for o in 0..O {
                assert!((y[n][o] as f64 - r[o]).abs() < 1e-5, "n {n} o {o}");
                assert_eq!(
                    y[n][o].to_bits(),
                    y1[0][o].to_bits(),
                    "batch vs single n {n} o {o}"
                );
            }
        }
    }
}
