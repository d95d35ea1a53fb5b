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

use bytemuck::Zeroable;

use crate::params::Params;
use crate::rng::Rng;

/// Floats per AVX2 register: the kernels' unit of output width.
const LANES: usize = 8;
/// Samples per tile of the batch forward kernel: 4 x 3 accumulators, 3 weight registers and
/// one broadcast fill the 16 AVX2 registers (measured best of 4x16, 5x16, 6x16, 8x8, 3x32,
/// 2x32 on this machine).
#[cfg(not(target_arch = "arm"))]
const TILE_N: usize = 4;
/// Output vectors (of [`LANES`]) per strip of the batch kernels: 3 (twelve AVX2 accumulators).
#[cfg(not(target_arch = "arm"))]
const STRIP: usize = 3;
/// Samples per tile of the narrow-output kernel.
const TILE_N_NARROW: usize = 8;
/// Input rows per tile of the weight-gradient kernel (same register budget).
#[cfg(all(feature = "train", not(target_arch = "arm")))]
const TILE_I: usize = 4;
/// Output chunk of the single-sample kernel: eight AVX2 registers of independent accumulators,
/// enough to hide the FMA latency.
#[cfg(not(target_arch = "arm"))]
const CHUNK_1: usize = 64;

// A Cortex-M4F has 32 single-precision registers and no SIMD: tiles of 2 samples (input rows)
// by 8 outputs keep 16 accumulators, 8 weights and the inputs in registers (the x86 tiles, 96
// accumulators, spill every one of them to the stack), and the single-sample kernel keeps 16
// accumulators. Every output is still summed in the same order, so the bits are the same
// (tests/cortex_m.rs, mpo-host/tests/device.rs); only the instruction count changes
// (benches/cortex_m.rs).
#[cfg(target_arch = "arm")]
const TILE_N: usize = 2;
#[cfg(target_arch = "arm")]
const STRIP: usize = 1;
#[cfg(all(feature = "train", target_arch = "arm"))]
const TILE_I: usize = 2;
#[cfg(target_arch = "arm")]
const CHUNK_1: usize = 16;

/// `a * b + c` with one rounding (IEEE 754 fusedMultiplyAdd).
///
/// On x86-64 builds with the `fma` target feature (the workspace's x86-64-v3 host target) this
/// is the FMA instruction, which the compiler vectorises; on a Cortex-M with an FPU (every
/// M-profile FPU, FPv4-SP onwards, has it) the `vfma.f32` instruction; elsewhere (the baseline
/// target of the x86-64 freestanding binaries) `libm::fmaf`, correctly rounded in software.
/// All give the same bits for the same inputs (tests/cortex_m.rs runs the Cortex-M4F build).
#[inline(always)]
pub fn mul_add(a: f32, b: f32, c: f32) -> f32 {
    #[cfg(all(
        target_arch = "arm",
        target_feature = "mclass",
        target_feature = "fpregs"
    ))]
    {
        // Stable Rust has no fused multiply-add in `core`, and its inline assembly offers no FPU
        // register on this target; the Cortex-M build is a nightly-feature build anyway (it
        // builds `core` from source), so `core`'s unstable one, which is the instruction.
        core::f32::math::mul_add(a, b, c)
    }
    #[cfg(all(target_arch = "x86_64", target_feature = "fma"))]
    {
        use core::arch::x86_64::{_mm_cvtss_f32, _mm_fmadd_ss, _mm_set_ss};
        // SAFETY: the `fma` target feature is enabled for the whole build (checked by the cfg
        // above), so every CPU this binary may run on has the instruction; the intrinsics only
        // touch registers.
        #[allow(unsafe_code)]
        unsafe {
            _mm_cvtss_f32(_mm_fmadd_ss(_mm_set_ss(a), _mm_set_ss(b), _mm_set_ss(c)))
        }
    }
    #[cfg(not(any(
        all(target_arch = "x86_64", target_feature = "fma"),
        all(
            target_arch = "arm",
            target_feature = "mclass",
            target_feature = "fpregs"
        )
    )))]
    {
        libm::fmaf(a, b, c)
    }
}

/// The square root, correctly rounded (so the same bits everywhere): on a Cortex-M with an FPU
/// the `vsqrt.f32` instruction, elsewhere `libm::sqrtf` (which uses the instruction on x86).
/// For the hot loops (Adam: one per parameter per update).
#[inline(always)]
pub fn sqrt(x: f32) -> f32 {
    #[cfg(all(
        target_arch = "arm",
        target_feature = "mclass",
        target_feature = "fpregs"
    ))]
    {
        core::f32::math::sqrt(x)
    }
    #[cfg(not(all(
        target_arch = "arm",
        target_feature = "mclass",
        target_feature = "fpregs"
    )))]
    {
        libm::sqrtf(x)
    }
}

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

/// Where each output's sum starts.
#[derive(Clone, Copy)]
pub enum Start<'a, const O: usize> {
    /// From `y` itself (accumulate into it).
    Y,
    /// From one row for every sample (a bias).
    Row(&'a [f32; O]),
    /// From row `n` of the given rows for sample `n` (a precomputed partial sum).
    Rows(&'a [[f32; O]]),
}

impl<const O: usize> Start<'_, O> {
    /// The start values of sample `n` (`y` is the output, for [`Start::Y`]).
    #[inline(always)]
    pub(crate) fn row<'a>(&'a self, y: &'a [[f32; O]], n: usize) -> &'a [f32; O] {
        match self {
            Self::Y => &y[n],
            Self::Row(b) => b,
            Self::Rows(r) => &r[n],
        }
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
    if crate::wide::enabled() {
        // SAFETY: `enabled` is true only where the CPU and OS run AVX-512F code.
        #[allow(unsafe_code)]
        {
            o0 = unsafe { crate::wide::kernel::<I, O, RELU>(x, w, start, y) };
        }
    }
    kernel_from::<I, O, RELU>(x, w, start, y, o0);
}

/// The 8-wide batch kernel for outputs `o0..O` (all of [`kernel`] but its dispatch).
pub(crate) fn kernel_from<const I: usize, const O: usize, const RELU: bool>(
    x: &[[f32; I]],
    w: &[[f32; O]; I],
    start: Start<'_, O>,
    y: &mut [[f32; O]],
    mut o0: usize,
) {
    while o0 + STRIP * LANES <= O {
        accumulate_strip::<I, O, STRIP, RELU>(x, w, start, y, o0);
        o0 += STRIP * LANES;
    }
    if STRIP > 2 && o0 + 2 * LANES <= O {
        accumulate_strip::<I, O, 2, RELU>(x, w, start, y, o0);
        o0 += 2 * LANES;
    }
    if STRIP > 1 && o0 + LANES <= O {
        accumulate_strip::<I, O, 1, RELU>(x, w, start, y, o0);
        o0 += LANES;
    }
    if o0 < O {
        accumulate_narrow::<I, O, RELU>(x, w, start, y, o0);
    }
}

/// Outputs `o0 .. o0 + 8 K` of every row: tiles of 4 samples, then single rows.
#[inline(always)]
fn accumulate_strip<const I: usize, const O: usize, const K: usize, const RELU: bool>(
    x: &[[f32; I]],
    w: &[[f32; O]; I],
    start: Start<'_, O>,
    y: &mut [[f32; O]],
    o0: usize,
) {
    let mut n0 = 0;
    while n0 + TILE_N <= x.len() {
        let xs: &[[f32; I]; TILE_N] = x[n0..n0 + TILE_N].try_into().unwrap();
        accumulate_tile::<I, O, TILE_N, K, RELU>(xs, w, start, y, n0, o0);
        n0 += TILE_N;
    }
    while n0 < x.len() {
        let xs: &[[f32; I]; 1] = x[n0..n0 + 1].try_into().unwrap();
        accumulate_tile::<I, O, 1, K, RELU>(xs, w, start, y, n0, o0);
        n0 += 1;
    }
}

/// `TN` samples from `n0` by `8 K` outputs from `o0`: the accumulators (`TN K` vectors) and
/// the `K` weight vectors of the current input stay in registers while the inputs stream.
/// Fixed-size rows, so the compiler checks bounds once per tile, not per input.
#[inline(always)]
fn accumulate_tile<
    const I: usize,
    const O: usize,
    const TN: usize,
    const K: usize,
    const RELU: bool,
>(
    x: &[[f32; I]; TN],
    w: &[[f32; O]; I],
    start: Start<'_, O>,
    y: &mut [[f32; O]],
    n0: usize,
    o0: usize,
) {
    let mut acc = [[[0f32; LANES]; K]; TN];
    for s in 0..TN {
        let src = start.row(y, n0 + s);
        for k in 0..K {
            acc[s][k].copy_from_slice(&src[o0 + LANES * k..o0 + LANES * (k + 1)]);
        }
    }
    for i in 0..I {
        let mut wr = [[0f32; LANES]; K];
        for k in 0..K {
            wr[k] = w[i][o0 + LANES * k..o0 + LANES * (k + 1)]
                .try_into()
                .unwrap();
        }
        for s in 0..TN {
            let xs = x[s][i];
            for k in 0..K {
                for l in 0..LANES {
                    acc[s][k][l] = mul_add(xs, wr[k][l], acc[s][k][l]);
                }
            }
        }
    }
    let ys: &mut [[f32; O]; TN] = (&mut y[n0..n0 + TN]).try_into().unwrap();
    for s in 0..TN {
        for k in 0..K {
            for l in 0..LANES {
                let v = acc[s][k][l];
                ys[s][o0 + LANES * k + l] = if RELU { relu_one(v) } else { v };
            }
        }
    }
}

/// Outputs `o0..O` (fewer than 8) for every row: eight samples at a time keep eight
/// independent accumulator vectors busy, which a single narrow row could not.
fn accumulate_narrow<const I: usize, const O: usize, const RELU: bool>(
    x: &[[f32; I]],
    w: &[[f32; O]; I],
    start: Start<'_, O>,
    y: &mut [[f32; O]],
    o0: usize,
) {
    let width = O - o0;
    let mut n0 = 0;
    while n0 < x.len() {
        let tn = TILE_N_NARROW.min(x.len() - n0);
        let mut acc = [[0f32; LANES]; TILE_N_NARROW];
        for s in 0..tn {
            acc[s][..width].copy_from_slice(&start.row(y, n0 + s)[o0..]);
        }
        for i in 0..I {
            let wr = &w[i][o0..];
            for s in 0..tn {
                let xs = x[n0 + s][i];
                for (a, wv) in acc[s][..width].iter_mut().zip(wr) {
                    *a = mul_add(xs, *wv, *a);
                }
            }
        }
        for s in 0..tn {
            for l in 0..width {
                let v = acc[s][l];
                y[n0 + s][o0 + l] = if RELU { relu_one(v) } else { v };
            }
        }
        n0 += tn;
    }
}

/// One sample: output chunks of 64 accumulators (eight registers, enough to hide the FMA
/// latency), inputs streaming; the rest of the outputs in chunks of 8, then singly.
///
/// Inputs that are exactly zero are skipped: a ReLU layer's inactive units, about half of a
/// hidden layer, so the weight rows read (the single state's cost: they stream from L2) drop by
/// about as much. Skipping is exact: `fma(±0, w, acc)` is `acc` bit for bit for finite `w` unless
/// `acc` is `-0.0`, and a chain can only be `-0.0` if it starts at a bias of exactly `-0.0`
/// (an exact cancellation rounds to `+0.0`); a start value of `-0.0` turns skipping off for
/// the layer. So the result equals the batch kernel's bit for bit for every finite weight.
#[inline(always)]
fn accumulate_one<const I: usize, const O: usize, const RELU: bool>(
    x: &[f32; I],
    w: &[[f32; O]; I],
    start: Start<'_, O>,
    y: &mut [f32; O],
) {
    let mut init = *start.row(core::slice::from_ref(y), 0);
    // Indices of the inputs that contribute, written without branches (`n` advances only
    // past a non-zero input), so random sparsity costs no mispredictions.
    let skip = !init.iter().any(|v| v.to_bits() == (-0.0f32).to_bits());
    let mut nz = [0u32; I];
    let mut n = 0;
    if O >= CHUNK_1 {
        for (i, &xi) in x.iter().enumerate() {
            nz[n] = i as u32;
            n += (!skip || xi != 0.0) as usize;
        }
    }
    let nz = &nz[..n];
    let mut o0 = 0;
    while o0 + CHUNK_1 <= O {
        let mut acc: [f32; CHUNK_1] = init[o0..o0 + CHUNK_1].try_into().unwrap();
        for &i in nz {
            let i = i as usize;
            let wr: &[f32; CHUNK_1] = w[i][o0..o0 + CHUNK_1].try_into().unwrap();
            let xi = x[i];
            for l in 0..CHUNK_1 {
                acc[l] = mul_add(xi, wr[l], acc[l]);
            }
        }
        init[o0..o0 + CHUNK_1].copy_from_slice(&acc);
        o0 += CHUNK_1;
    }
    if o0 < O {
        // The rest of the outputs (a narrow head) together: one chain per output. Every
        // input (exactly the same as skipping zeros, above): a narrow head's weights are few
        // and stay in L1, and the full loop has a constant trip count the compiler unrolls.
        for i in 0..I {
            let xi = x[i];
            for o in o0..O {
                init[o] = mul_add(xi, w[i][o], init[o]);
            }
        }
    }
    for o in 0..O {
        y[o] = if RELU { relu_one(init[o]) } else { init[o] };
    }
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
    if crate::wide::enabled() {
        // SAFETY: `enabled` is true only where the CPU and OS run AVX-512F code.
        #[allow(unsafe_code)]
        {
            o0 = unsafe { crate::wide::weight_grad::<I, O>(x, dy, i0, gw) };
        }
    }
    weight_grad_from(x, dy, i0, gw, o0);
}

#[cfg(feature = "train")]
/// The 8-wide weight gradient for columns `o0..O` (all of [`weight_grad_chunks`] but its
/// dispatch and checks).
pub(crate) fn weight_grad_from<const I: usize, const O: usize>(
    x: &[&[[f32; I]]],
    dy: &[&[[f32; O]]],
    i0: usize,
    gw: &mut [[f32; O]],
    mut o0: usize,
) {
    while o0 + STRIP * LANES <= O {
        weight_grad_strip::<I, O, STRIP>(x, dy, i0, gw, o0);
        o0 += STRIP * LANES;
    }
    if STRIP > 2 && o0 + 2 * LANES <= O {
        weight_grad_strip::<I, O, 2>(x, dy, i0, gw, o0);
        o0 += 2 * LANES;
    }
    if STRIP > 1 && o0 + LANES <= O {
        weight_grad_strip::<I, O, 1>(x, dy, i0, gw, o0);
        o0 += LANES;
    }
    if o0 < O {
        weight_grad_narrow(x, dy, i0, gw, o0);
    }
}

#[cfg(feature = "train")]
/// Columns `o0 .. o0 + 8 K` of [`weight_grad_chunks`]: tiles of 4 input rows, then single
/// rows.
#[inline(always)]
fn weight_grad_strip<const I: usize, const O: usize, const K: usize>(
    x: &[&[[f32; I]]],
    dy: &[&[[f32; O]]],
    i0: usize,
    gw: &mut [[f32; O]],
    o0: usize,
) {
    let rows = gw.len();
    let mut r = 0;
    while r + TILE_I <= rows {
        let acc = weight_grad_tile::<I, O, TILE_I, K>(x, dy, i0 + r, o0);
        for t in 0..TILE_I {
            for k in 0..K {
                gw[r + t][o0 + LANES * k..o0 + LANES * (k + 1)].copy_from_slice(&acc[t][k]);
            }
        }
        r += TILE_I;
    }
    while r < rows {
        let acc = weight_grad_tile::<I, O, 1, K>(x, dy, i0 + r, o0);
        for k in 0..K {
            gw[r][o0 + LANES * k..o0 + LANES * (k + 1)].copy_from_slice(&acc[0][k]);
        }
        r += 1;
    }
}

#[cfg(feature = "train")]
/// `TI` input rows from `i` by `8 K` outputs from `o0` of the chunked weight gradient.
#[inline(always)]
fn weight_grad_tile<const I: usize, const O: usize, const TI: usize, const K: usize>(
    x: &[&[[f32; I]]],
    dy: &[&[[f32; O]]],
    i: usize,
    o0: usize,
) -> [[[f32; LANES]; K]; TI] {
    let mut acc = [[[0f32; LANES]; K]; TI];
    for (xc, dc) in x.iter().zip(dy) {
        for (xn, dn) in xc.iter().zip(dc.iter()) {
            let mut d = [[0f32; LANES]; K];
            for k in 0..K {
                d[k] = dn[o0 + LANES * k..o0 + LANES * (k + 1)].try_into().unwrap();
            }
            let xs: &[f32; TI] = xn[i..i + TI].try_into().unwrap();
            for t in 0..TI {
                let xv = xs[t];
                for k in 0..K {
                    for l in 0..LANES {
                        acc[t][k][l] = mul_add(xv, d[k][l], acc[t][k][l]);
                    }
                }
            }
        }
    }
    acc
}

#[cfg(feature = "train")]
/// Columns `o0..O` (fewer than 8) of [`weight_grad_chunks`]: eight input rows at a time.
fn weight_grad_narrow<const I: usize, const O: usize>(
    x: &[&[[f32; I]]],
    dy: &[&[[f32; O]]],
    i0: usize,
    gw: &mut [[f32; O]],
    o0: usize,
) {
    const TI: usize = 8;
    let width = O - o0;
    let mut r = 0;
    while r < gw.len() {
        let ti = TI.min(gw.len() - r);
        let mut acc = [[0f32; LANES]; TI];
        for (xc, dc) in x.iter().zip(dy) {
            for (xn, dn) in xc.iter().zip(dc.iter()) {
                let d = &dn[o0..];
                for k in 0..ti {
                    let xk = xn[i0 + r + k];
                    for (a, dv) in acc[k][..width].iter_mut().zip(d) {
                        *a = mul_add(xk, *dv, *a);
                    }
                }
            }
        }
        for k in 0..ti {
            gw[r + k][o0..].copy_from_slice(&acc[k][..width]);
        }
        r += ti;
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

/// The ReLU of one value, defined for every input: `v` if `v > 0`, else `+0` (so `-0.0` and
/// NaN give `+0`). Spelled out rather than `f32::max`, which may return either zero for
/// `max(-0.0, 0.0)`: every kernel path (8-wide, 512-bit, single state, software FMA) must
/// agree bit for bit.
#[inline(always)]
pub fn relu_one(v: f32) -> f32 {
    if v > 0.0 { v } else { 0.0 }
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

    /// The 512-bit kernel (`wide`, taken where the CPU has AVX-512F) equals the 8-wide one and
    /// the reference order bit for bit: every start kind, with and without the fused ReLU,
    /// pre-activations of both signed zeros, and sizes that leave 8-wide and narrow outputs
    /// (118 = 2 x 48 + 16 + 6) and 8-, 4- and 1-sample tiles (13 rows). On a CPU without
    /// AVX-512 both calls take the 8-wide path, which the test says on stderr.
    #[test]
    fn wide_kernel_equals_the_8_wide_kernel_bits() {
        const I: usize = 21;
        const O: usize = 118;
        const B: usize = 13;
        #[cfg(all(target_arch = "x86_64", target_feature = "fma"))]
        let wide = crate::wide::enabled();
        #[cfg(not(all(target_arch = "x86_64", target_feature = "fma")))]
        let wide = false;
        if !wide {
            std::eprintln!(
                "wide_kernel_equals_the_8_wide_kernel_bits: no AVX-512 on this CPU, only the 8-wide path ran"
            );
        }
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
                let (mut a, mut b) = (rows, rows);
                if relu {
                    kernel::<I, O, true>(&x, &l.w, start, &mut a);
                    kernel_from::<I, O, true>(&x, &l.w, start, &mut b, 0);
                } else {
                    kernel::<I, O, false>(&x, &l.w, start, &mut a);
                    kernel_from::<I, O, false>(&x, &l.w, start, &mut b, 0);
                }
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
                        assert_eq!(a[n][o].to_bits(), b[n][o].to_bits(), "wide vs 8-wide, {at}");
                        assert_eq!(b[n][o].to_bits(), r.to_bits(), "8-wide vs reference, {at}");
                    }
                }
            }
        }
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

    /// The 512-bit weight gradient (where the CPU has AVX-512F) equals the 8-wide one and the
    /// reference order bit for bit, on uneven chunks and row ranges that leave 8-row, single-row,
    /// 8-wide and narrow remainders (118 columns = 2 x 48 + 16 + 6; rows 0..11 and 11..21). On a
    /// CPU without AVX-512 both calls take the 8-wide path, which the test says on stderr.
    #[test]
    fn wide_weight_gradient_equals_the_8_wide_bits() {
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
        #[cfg(all(target_arch = "x86_64", target_feature = "fma"))]
        if !crate::wide::enabled() {
            std::eprintln!(
                "wide_weight_gradient_equals_the_8_wide_bits: no AVX-512 on this CPU, only the 8-wide path ran"
            );
        }
        let (mut a, mut b) = ([[0f32; O]; I], [[0f32; O]; I]);
        for (i0, i1) in [(0, 11), (11, I)] {
            weight_grad_chunks(&xs, &ds, i0, &mut a[i0..i1]);
            weight_grad_from(&xs, &ds, i0, &mut b[i0..i1], 0);
        }
        for i in 0..I {
            for o in 0..O {
                let mut r = 0f32;
                for n in 0..B {
                    r = libm::fmaf(x[n][i], dy[n][o], r);
                }
                assert_eq!(
                    a[i][o].to_bits(),
                    b[i][o].to_bits(),
                    "wide vs 8-wide i {i} o {o}"
                );
                assert_eq!(
                    b[i][o].to_bits(),
                    r.to_bits(),
                    "8-wide vs reference i {i} o {o}"
                );
            }
        }
    }
}
