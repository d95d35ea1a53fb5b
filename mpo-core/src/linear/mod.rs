//! The fully connected layer and its hand-written kernels.
//!
//! Weights are stored input-major (`w[i][o]`), so every kernel is an axpy over outputs that the
//! compiler vectorises without reassociating a sum. Every output is accumulated in the same
//! order on every path (initial value, then inputs in ascending order, one fused multiply-add
//! each: [`mul_add`]), which is why a batch forward gives the same bits as a single-state
//! forward, and why no target CPU changes a result: a fused multiply-add is rounded once,
//! exactly as IEEE 754 defines it, whether an FMA instruction or software computes it.
//!
//! FLOPs: forward `2 B I O`; backward `2 B I O` for the weight gradient plus `2 B I O` for the
//! input gradient when it is asked for.
//!
//! Kernels: [`accumulate`] (forward, and input gradients through transposed weights) keeps a
//! 4-sample x 24-output tile in registers (twelve AVX2 accumulators, enough to cover the
//! latency of two FMA pipes, plus three weight vectors and a broadcast: all 16 registers);
//! what is left of the outputs runs in strips of 16 and 8, and narrow layers (fewer than 8
//! outputs: the policy heads) use an 8-sample tile over the outputs there are.
//! [`weight_grad_chunks`] keeps a 4-input x 24-output tile and sums over samples in
//! ascending order across a list of batch chunks, so the gradient of a batch held in chunks
//! has the same bits as that of one contiguous batch. On a CPU with AVX-512F both hand the
//! outputs up to the last multiple of 16 to the `wide` module's 512-bit forms (same order, so
//! the same bits) and keep the rest.

mod order;
mod tiles;
#[cfg(all(target_arch = "x86_64", target_feature = "fma"))]
pub mod wide;

pub use order::{Start, mul_add, relu_one, sqrt};

use bytemuck::Zeroable;

use crate::params::Params;
use crate::rng::Rng;
#[cfg(feature = "train")]
use tiles::weight_grad_from;
use tiles::{accumulate_one, kernel_from};

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
    fn visit_mut<'a>(&'a mut self, f: &mut dyn FnMut(&'a mut [f32])) {
        f(self.w.as_flattened_mut());
        f(&mut self.b);
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
        kernel::<I, O, false>(x, &self.w, Start::Row(&self.b), y);
    }

    /// `y = max(b + x W, 0)` for every row of `x` (the ReLU fused into the kernel).
    pub fn forward_relu(&self, x: &[[f32; I]], y: &mut [[f32; O]]) {
        kernel::<I, O, true>(x, &self.w, Start::Row(&self.b), y);
    }

    #[cfg(feature = "train")]
    /// Weight and bias gradients of `sum_n dy[n] . y[n]`, written into `grad` (overwriting
    /// it).
    pub fn backward(&self, x: &[[f32; I]], dy: &[[f32; O]], grad: &mut Linear<I, O>) {
        weight_grad(x, dy, &mut grad.w);
        bias_grad_chunks(&[dy], &mut grad.b);
    }

    #[cfg(feature = "train")]
    /// The input gradient `dx = dy W^T`, through a transposed copy of the weights in `wt`
    /// (filled here; see [`transpose`]) so it runs on the forward kernel.
    pub fn input_grad(&self, dy: &[[f32; O]], dx: &mut [[f32; I]], wt: &mut [[f32; I]; O]) {
        transpose(&self.w, wt);
        for row in dx.iter_mut() {
            row.fill(0.0);
        }
        accumulate(dy, wt, dx);
    }
}

/// `y[n] += x[n] W` for every row, each output summed in ascending input order.
pub fn accumulate<const I: usize, const O: usize>(
    x: &[[f32; I]],
    w: &[[f32; O]; I],
    y: &mut [[f32; O]],
) {
    kernel::<I, O, false>(x, w, Start::Y, y);
}

/// `y[n] = start[n] + x[n] W` for every row (each output: the start value, then one fused
/// multiply-add per input in ascending order), passed through a ReLU when `RELU`. Fusing the
/// start and the ReLU into the tiles saves two passes over `y`.
pub fn kernel<const I: usize, const O: usize, const RELU: bool>(
    x: &[[f32; I]],
    w: &[[f32; O]; I],
    start: Start<'_, O>,
    y: &mut [[f32; O]],
) {
    assert_eq!(x.len(), y.len(), "accumulate: batch sizes differ");
    if let Start::Rows(r) = start {
        assert_eq!(r.len(), y.len(), "accumulate: start rows differ");
    }
    if x.len() == 1 {
        accumulate_one::<I, O, RELU>(&x[0], w, start, &mut y[0]);
        return;
    }
    // Output strips outermost: one strip of weights (I x 24 floats) is reused by every sample
    // tile while it is in cache. Strips of 24 outputs, then one of 16 and one of 8 for what is
    // left, then the narrow kernel for fewer than 8. On a CPU with AVX-512 the 512-bit kernel
    // does the outputs up to the last multiple of 16 first (same bits: `wide`).
    #[allow(unused_mut)]
    let mut o0 = 0;
    #[cfg(all(target_arch = "x86_64", target_feature = "fma"))]
    if wide::enabled() {
        // SAFETY: `enabled` is true only where the CPU and OS run AVX-512F code.
        #[allow(unsafe_code)]
        {
            o0 = unsafe { wide::kernel::<I, O, RELU>(x, w, start, y) };
        }
    }
    kernel_from::<I, O, RELU>(x, w, start, y, o0);
}

#[cfg(feature = "train")]
/// `gw[i][o] = sum_n x[n][i] dy[n][o]`, summed in ascending sample order (overwrites `gw`).
pub fn weight_grad<const I: usize, const O: usize>(
    x: &[[f32; I]],
    dy: &[[f32; O]],
    gw: &mut [[f32; O]; I],
) {
    weight_grad_chunks(&[x], &[dy], 0, gw);
}

#[cfg(feature = "train")]
/// Rows `i0 .. i0 + gw.len()` of the weight gradient of a batch held in chunks:
/// `gw[i - i0][o] = sum_c sum_n x[c][n][i] dy[c][n][o]`, chunks in order and samples in
/// ascending order within each, so the bits depend only on the batch, not on how it is
/// chunked or which rows are computed together. Overwrites `gw`.
pub fn weight_grad_chunks<const I: usize, const O: usize>(
    x: &[&[[f32; I]]],
    dy: &[&[[f32; O]]],
    i0: usize,
    gw: &mut [[f32; O]],
) {
    assert_eq!(x.len(), dy.len(), "weight_grad: chunk counts differ");
    for (xc, dc) in x.iter().zip(dy) {
        assert_eq!(xc.len(), dc.len(), "weight_grad: batch sizes differ");
    }
    assert!(i0 + gw.len() <= I, "weight_grad: rows out of range");
    #[allow(unused_mut)]
    let mut o0 = 0;
    #[cfg(all(target_arch = "x86_64", target_feature = "fma"))]
    if wide::enabled() {
        // SAFETY: `enabled` is true only where the CPU and OS run AVX-512F code.
        #[allow(unsafe_code)]
        {
            o0 = unsafe { wide::weight_grad::<I, O>(x, dy, i0, gw) };
        }
    }
    weight_grad_from(x, dy, i0, gw, o0);
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
/// `gb[o] = sum_c sum_n dy[c][n][o]`, chunks in order, samples ascending (overwrites `gb`).
pub fn bias_grad_chunks<const O: usize>(dy: &[&[[f32; O]]], gb: &mut [f32; O]) {
    gb.fill(0.0);
    for dc in dy {
        for d in dc.iter() {
            for o in 0..O {
                gb[o] += d[o];
            }
        }
    }
}

/// `x = max(x, 0)` in place ([`relu_one`]).
pub fn relu<const N: usize>(x: &mut [[f32; N]]) {
    for v in x.as_flattened_mut() {
        *v = relu_one(*v);
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
    extern crate std;
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

    /// The order every kernel promises: bias, then one fused multiply-add per input in
    /// ascending order, written out with `libm::fmaf` (software, independent of the kernels'
    /// instruction selection).
    fn reference_bits<const I: usize, const O: usize>(l: &Linear<I, O>, x: &[f32; I]) -> [f32; O] {
        let mut y = l.b;
        for i in 0..I {
            for o in 0..O {
                y[o] = libm::fmaf(x[i], l.w[i][o], y[o]);
            }
        }
        y
    }

    #[test]
    fn batch_forward_matches_naive_and_single_bits() {
        // Sizes that exercise full tiles, the 4-row and 1-row remainders and narrow outputs.
        const I: usize = 19;
        const O: usize = 37;
        const B: usize = 11;
        let l = layer::<I, O>(1);
        let mut rng = Rng::seed_from_u64(2);
        let mut x = [[0f32; I]; B];
        rng.fill_normal(x.as_flattened_mut());
        let mut y = [[0f32; O]; B];
        l.forward(&x, &mut y);
        for n in 0..B {
            let r = naive_forward(&l, &x[n]);
            let bits = reference_bits(&l, &x[n]);
            let mut y1 = [[0f32; O]; 1];
            l.forward(core::slice::from_ref(&x[n]), &mut y1);
            for o in 0..O {
                assert!((y[n][o] as f64 - r[o]).abs() < 1e-5, "n {n} o {o}");
                assert_eq!(
                    y[n][o].to_bits(),
                    bits[o].to_bits(),
                    "fma order n {n} o {o}"
                );
                assert_eq!(
                    y[n][o].to_bits(),
                    y1[0][o].to_bits(),
                    "batch vs single n {n} o {o}"
                );
            }
        }
    }

    /// The single-state path skips zero inputs: with inputs of both signed zeros (half of
    /// each row, and whole rows), biases of +0 and -0, and outputs wider than one chunk, it
    /// still equals the reference order and the batch kernel bit for bit. Two widths: 70 (one
    /// 64-wide chunk and a narrow rest) and 200 (three chunks and a rest of 8).
    #[test]
    fn single_state_skips_zero_inputs_exactly() {
        single_state_skips_zero_inputs::<70>();
        single_state_skips_zero_inputs::<200>();
    }

    fn single_state_skips_zero_inputs<const O: usize>() {
        const I: usize = 40;
        const B: usize = 6;
        let mut rng = Rng::seed_from_u64(9);
        let mut x = [[0f32; I]; B];
        rng.fill_normal(x.as_flattened_mut());
        for (n, row) in x.iter_mut().enumerate() {
            for (i, v) in row.iter_mut().enumerate() {
                if n >= 4 || (i + n) % 2 == 0 {
                    *v = if i % 3 == 0 { -0.0 } else { 0.0 };
                }
            }
        }
        for bias_zero in [0.0f32, -0.0] {
            let mut l = layer::<I, O>(10);
            for o in (0..O).step_by(5) {
                l.b[o] = bias_zero;
            }
            let mut y = [[0f32; O]; B];
            l.forward(&x, &mut y);
            for n in 0..B {
                let bits = reference_bits(&l, &x[n]);
                let mut y1 = [[0f32; O]; 1];
                l.forward(core::slice::from_ref(&x[n]), &mut y1);
                for o in 0..O {
                    let (b, s, r) = (y[n][o].to_bits(), y1[0][o].to_bits(), bits[o].to_bits());
                    let at = format_args!("O {O}, bias {bias_zero:?}, n {n} o {o}");
                    assert_eq!(s, r, "single vs reference, {at}");
                    assert_eq!(b, s, "batch vs single, {at}");
                }
            }
        }
    }

    /// A batch forward `run(x, w, start, relu, y)` equals the reference order bit for bit:
    /// every start kind, with and without the fused ReLU, pre-activations of both signed zeros,
    /// and sizes that leave 8-wide and narrow outputs (118 = 2 x 48 + 16 + 6) and 8-, 4- and
    /// 1-sample tiles (13 rows).
    fn forward_matches_the_reference_order(
        path: &str,
        run: impl Fn(&[[f32; 21]], &[[f32; 118]; 21], Start<'_, 118>, bool, &mut [[f32; 118]]),
    ) {
        const I: usize = 21;
        const O: usize = 118;
        const B: usize = 13;
        let mut l = layer::<I, O>(31);
        let mut x = [[0f32; I]; B];
        Rng::seed_from_u64(32).fill_normal(x.as_flattened_mut());
        // Row 0's inputs are all +0 and every third output's weights negative, so each of
        // its products there is -0 and a start value of -0 stays -0 to the ReLU; the other
        // outputs start at +0 or a random value.
        x[0] = [0.0; I];
        let mut rows = [[0f32; O]; B];
        Rng::seed_from_u64(33).fill_normal(rows.as_flattened_mut());
        for o in (0..O).step_by(3) {
            for i in 0..I {
                l.w[i][o] = -l.w[i][o].abs();
            }
            l.b[o] = -0.0;
            rows[0][o] = -0.0;
        }
        for o in (1..O).step_by(3) {
            l.b[o] = 0.0;
        }
        for kind in 0..3 {
            let start = match kind {
                0 => Start::Y,
                1 => Start::Row(&l.b),
                _ => Start::Rows(&rows),
            };
            for relu in [false, true] {
                let mut y = rows;
                run(&x, &l.w, start, relu, &mut y);
                for n in 0..B {
                    let mut r = match kind {
                        1 => l.b,
                        _ => rows[n],
                    };
                    for i in 0..I {
                        for o in 0..O {
                            r[o] = libm::fmaf(x[n][i], l.w[i][o], r[o]);
                        }
                    }
                    for o in 0..O {
                        let r = if relu { relu_one(r[o]) } else { r[o] };
                        let at = format_args!("start {kind} relu {relu} n {n} o {o}");
                        assert_eq!(y[n][o].to_bits(), r.to_bits(), "{path} vs reference, {at}");
                    }
                }
            }
        }
    }

    /// The 8-wide kernels (all of [`kernel`] where the 512-bit path is off) keep the order.
    #[test]
    fn tiled_kernel_matches_the_reference_order() {
        forward_matches_the_reference_order("8-wide", |x, w, start, relu, y| {
            if relu {
                kernel_from::<21, 118, true>(x, w, start, y, 0);
            } else {
                kernel_from::<21, 118, false>(x, w, start, y, 0);
            }
        });
    }

    /// The 512-bit kernel, with the 8-wide ones for the outputs it leaves (what [`kernel`]
    /// runs where AVX-512F is on), keeps the order. Compiled only where the CPU that built the
    /// tests has AVX-512F (`mpo-core/build.rs` sets `mpo_avx512f`): elsewhere the 512-bit code
    /// cannot run, so there is no test rather than one that passes without running it.
    #[cfg(all(mpo_avx512f, target_arch = "x86_64", target_feature = "fma"))]
    #[test]
    fn wide_kernel_matches_the_reference_order() {
        assert!(
            wide::detected(),
            "built on a CPU with AVX-512F, run on one without"
        );
        forward_matches_the_reference_order("512-bit", |x, w, start, relu, y| {
            // SAFETY: the CPU has AVX-512F (asserted above).
            #[allow(unsafe_code)]
            let o0 = unsafe {
                if relu {
                    wide::kernel::<21, 118, true>(x, w, start, y)
                } else {
                    wide::kernel::<21, 118, false>(x, w, start, y)
                }
            };
            assert_eq!(o0, 112, "the 512-bit kernel's share of 118 outputs");
            if relu {
                kernel_from::<21, 118, true>(x, w, start, y, o0);
            } else {
                kernel_from::<21, 118, false>(x, w, start, y, o0);
            }
        });
    }

    #[test]
    fn relu_one_gives_positive_zero_for_both_zeros_and_nan() {
        assert_eq!(relu_one(-0.0).to_bits(), 0.0f32.to_bits());
        assert_eq!(relu_one(0.0).to_bits(), 0.0f32.to_bits());
        assert_eq!(relu_one(f32::NAN).to_bits(), 0.0f32.to_bits());
        assert_eq!(relu_one(-2.0), 0.0);
        assert_eq!(relu_one(1.5), 1.5);
    }

    #[test]
    fn narrow_layers_match_the_reference_order() {
        const I: usize = 23;
        const O: usize = 5;
        const B: usize = 13;
        let l = layer::<I, O>(3);
        let mut x = [[0f32; I]; B];
        Rng::seed_from_u64(4).fill_normal(x.as_flattened_mut());
        let mut y = [[0f32; O]; B];
        l.forward(&x, &mut y);
        for n in 0..B {
            let bits = reference_bits(&l, &x[n]);
            for o in 0..O {
                assert_eq!(y[n][o].to_bits(), bits[o].to_bits(), "n {n} o {o}");
            }
        }
    }

    /// Narrow outputs and columns of every width the tiles distinguish (1 and 2: one scalar
    /// chain or padded lanes forward, four row blocks in the gradient; 3-4: two; 5-7: one),
    /// behind a full 8-wide strip, with enough rows for every gradient tile (45 = 32 + 8 + 5)
    /// and samples for the 8-sample tile and single rows (13): the reference order bit for
    /// bit, forward from a bias and the gradient over two chunks.
    #[test]
    fn narrow_widths_match_the_reference_order() {
        narrow_width::<9>();
        narrow_width::<10>();
        narrow_width::<12>();
        narrow_width::<15>();
        narrow_width::<1>();
        narrow_width::<6>();
    }

    fn narrow_width<const O: usize>() {
        const I: usize = 45;
        const B: usize = 13;
        let l = layer::<I, O>(50 + O as u64);
        let mut rng = Rng::seed_from_u64(51);
        let mut x = [[0f32; I]; B];
        let mut dy = [[0f32; O]; B];
        rng.fill_normal(x.as_flattened_mut());
        rng.fill_normal(dy.as_flattened_mut());
        let mut y = [[0f32; O]; B];
        kernel_from::<I, O, false>(&x, &l.w, Start::Row(&l.b), &mut y, 0);
        for n in 0..B {
            let bits = reference_bits(&l, &x[n]);
            for o in 0..O {
                let at = format_args!("O {O} n {n} o {o}");
                assert_eq!(y[n][o].to_bits(), bits[o].to_bits(), "forward, {at}");
            }
        }
        let mut g = [[0f32; O]; I];
        let xs: [&[[f32; I]]; 2] = [&x[..4], &x[4..]];
        let ds: [&[[f32; O]]; 2] = [&dy[..4], &dy[4..]];
        weight_grad_from(&xs, &ds, 0, &mut g, 0);
        for i in 0..I {
            for o in 0..O {
                let mut r = 0f32;
                for n in 0..B {
                    r = libm::fmaf(x[n][i], dy[n][o], r);
                }
                let at = format_args!("O {O} i {i} o {o}");
                assert_eq!(g[i][o].to_bits(), r.to_bits(), "weight gradient, {at}");
            }
        }
    }

    #[test]
    fn chunked_weight_gradient_equals_contiguous_bits() {
        const I: usize = 20;
        const O: usize = 35;
        const B: usize = 12;
        let mut rng = Rng::seed_from_u64(5);
        let mut x = [[0f32; I]; B];
        let mut dy = [[0f32; O]; B];
        rng.fill_normal(x.as_flattened_mut());
        rng.fill_normal(dy.as_flattened_mut());
        let mut whole = [[0f32; O]; I];
        weight_grad(&x, &dy, &mut whole);
        // Three uneven chunks, rows computed in two separate calls.
        let xs: [&[[f32; I]]; 3] = [&x[..5], &x[5..7], &x[7..]];
        let ds: [&[[f32; O]]; 3] = [&dy[..5], &dy[5..7], &dy[7..]];
        let mut parts = [[0f32; O]; I];
        let (a, b) = parts.split_at_mut(7);
        weight_grad_chunks(&xs, &ds, 0, a);
        weight_grad_chunks(&xs, &ds, 7, b);
        for i in 0..I {
            for o in 0..O {
                assert_eq!(whole[i][o].to_bits(), parts[i][o].to_bits(), "i {i} o {o}");
                let mut r = 0f32;
                for n in 0..B {
                    r = libm::fmaf(x[n][i], dy[n][o], r);
                }
                assert_eq!(whole[i][o].to_bits(), r.to_bits(), "order i {i} o {o}");
            }
        }
    }

    /// A chunked weight gradient `run(chunks, dy_chunks, i0, rows)` equals the reference order
    /// bit for bit, on uneven chunks and row ranges that leave 8-row, single-row, 8-wide and
    /// narrow remainders (118 columns = 2 x 48 + 16 + 6; rows 0..11 and 11..21).
    fn weight_gradient_matches_the_reference_order(
        path: &str,
        run: impl Fn(&[&[[f32; 21]]], &[&[[f32; 118]]], usize, &mut [[f32; 118]]),
    ) {
        const I: usize = 21;
        const O: usize = 118;
        const B: usize = 13;
        let mut rng = Rng::seed_from_u64(41);
        let mut x = [[0f32; I]; B];
        let mut dy = [[0f32; O]; B];
        rng.fill_normal(x.as_flattened_mut());
        rng.fill_normal(dy.as_flattened_mut());
        let xs: [&[[f32; I]]; 3] = [&x[..6], &x[6..7], &x[7..]];
        let ds: [&[[f32; O]]; 3] = [&dy[..6], &dy[6..7], &dy[7..]];
        let mut g = [[0f32; O]; I];
        for (i0, i1) in [(0, 11), (11, I)] {
            run(&xs, &ds, i0, &mut g[i0..i1]);
        }
        for i in 0..I {
            for o in 0..O {
                let mut r = 0f32;
                for n in 0..B {
                    r = libm::fmaf(x[n][i], dy[n][o], r);
                }
                let (got, want) = (g[i][o].to_bits(), r.to_bits());
                assert_eq!(got, want, "{path} vs reference i {i} o {o}");
            }
        }
    }

    /// The 8-wide weight gradient (all of [`weight_grad_chunks`] where the 512-bit path is
    /// off) keeps the order.
    #[test]
    fn tiled_weight_gradient_matches_the_reference_order() {
        weight_gradient_matches_the_reference_order("8-wide", |x, dy, i0, g| {
            weight_grad_from(x, dy, i0, g, 0);
        });
    }

    /// The 512-bit weight gradient, with the 8-wide one for the columns it leaves, keeps the
    /// order; compiled only where the building CPU has AVX-512F, like
    /// `wide_kernel_matches_the_reference_order`.
    #[cfg(all(mpo_avx512f, target_arch = "x86_64", target_feature = "fma"))]
    #[test]
    fn wide_weight_gradient_matches_the_reference_order() {
        assert!(
            wide::detected(),
            "built on a CPU with AVX-512F, run on one without"
        );
        weight_gradient_matches_the_reference_order("512-bit", |x, dy, i0, g| {
            // SAFETY: the CPU has AVX-512F (asserted above).
            #[allow(unsafe_code)]
            let o0 = unsafe { wide::weight_grad::<21, 118>(x, dy, i0, g) };
            assert_eq!(o0, 112, "the 512-bit gradient's share of 118 columns");
            weight_grad_from(x, dy, i0, g, o0);
        });
    }
}
