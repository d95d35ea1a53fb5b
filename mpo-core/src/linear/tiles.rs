//! The 8-wide kernels: the batch forward in tiles of samples by 8-float output strips, the
//! single-state forward, and the chunked weight gradient in tiles of input rows. The
//! workspace's host target is x86-64-v3 (AVX2), so 8 floats are one register; on the
//! freestanding baseline target the same code compiles to narrower vectors, with the same
//! bits.

use super::order::{Start, mul_add, relu_one};

/// Floats per AVX2 register: the kernels' unit of output width.
const LANES: usize = 8;
/// Samples per tile of the batch forward kernel: 4 x 3 accumulators, 3 weight registers and
/// one broadcast fill the 16 AVX2 registers (the other shapes tried were slower:
/// docs/core.md, "Kernels").
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

/// Whether the single-state kernel's narrow head skips zero inputs (x86: yes; a Cortex-M: no,
/// see [`accumulate_one`]). The sums are the same either way.
const NARROW_SKIPS_ZEROS: bool = cfg!(not(target_arch = "arm"));

/// The 8-wide batch kernel for outputs `o0..O` (all of [`kernel`] but its dispatch).
pub(super) fn kernel_from<const I: usize, const O: usize, const RELU: bool>(
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

/// Whether `mul_add` is one instruction here (x86-64 with FMA): then a lane computed and
/// thrown away costs no more than a scalar one, and narrow outputs are padded to a register.
const HW_FMA: bool = cfg!(all(target_arch = "x86_64", target_feature = "fma"));

/// Outputs `o0..O` (the last `O % 8`, fewer than 8) for every row. With a hardware FMA, the
/// narrow columns of each weight row are padded with zeros to a full 8-lane register, so a
/// tile of 8 samples is 8 vector FMAs per input (the padded lanes' results are dropped; each
/// real output is still its start value and one FMA per input in ascending order). A single
/// output column gains nothing from padding, and software FMA (the freestanding baseline
/// target) pays for every lane, so both keep one scalar chain per output.
fn accumulate_narrow<const I: usize, const O: usize, const RELU: bool>(
    x: &[[f32; I]],
    w: &[[f32; O]; I],
    start: Start<'_, O>,
    y: &mut [[f32; O]],
    o0: usize,
) {
    // A compile-time constant in every instance (the strips end at the last multiple of 8).
    let width = O % LANES;
    assert_eq!(
        o0 + width,
        O,
        "narrow outputs start at the last multiple of 8"
    );
    let o0 = O - width;
    let padded = HW_FMA && width >= 2;
    let mut n0 = 0;
    while n0 + TILE_N_NARROW <= x.len() {
        if padded {
            narrow_tile_padded::<I, O, TILE_N_NARROW, RELU>(x, w, start, y, n0, o0);
        } else {
            narrow_tile_scalar::<I, O, TILE_N_NARROW, RELU>(x, w, start, y, n0, o0);
        }
        n0 += TILE_N_NARROW;
    }
    while n0 < x.len() {
        narrow_tile_scalar::<I, O, 1, RELU>(x, w, start, y, n0, o0);
        n0 += 1;
    }
}

/// `TN` samples from `n0` by the narrow outputs `o0..O`, in padded 8-lane registers.
#[inline(always)]
fn narrow_tile_padded<const I: usize, const O: usize, const TN: usize, const RELU: bool>(
    x: &[[f32; I]],
    w: &[[f32; O]; I],
    start: Start<'_, O>,
    y: &mut [[f32; O]],
    n0: usize,
    o0: usize,
) {
    let width = O - o0;
    let xs: &[[f32; I]; TN] = x[n0..n0 + TN].try_into().unwrap();
    let mut acc = [[0f32; LANES]; TN];
    for s in 0..TN {
        acc[s][..width].copy_from_slice(&start.row(y, n0 + s)[o0..]);
    }
    for i in 0..I {
        let mut wr = [0f32; LANES];
        wr[..width].copy_from_slice(&w[i][o0..]);
        for s in 0..TN {
            let xv = xs[s][i];
            for l in 0..LANES {
                acc[s][l] = mul_add(xv, wr[l], acc[s][l]);
            }
        }
    }
    for s in 0..TN {
        for l in 0..width {
            let v = acc[s][l];
            y[n0 + s][o0 + l] = if RELU { relu_one(v) } else { v };
        }
    }
}

/// `TN` samples from `n0` by the narrow outputs `o0..O`, one scalar chain per output.
#[inline(always)]
fn narrow_tile_scalar<const I: usize, const O: usize, const TN: usize, const RELU: bool>(
    x: &[[f32; I]],
    w: &[[f32; O]; I],
    start: Start<'_, O>,
    y: &mut [[f32; O]],
    n0: usize,
    o0: usize,
) {
    let width = O - o0;
    let mut acc = [[0f32; LANES]; TN];
    for s in 0..TN {
        acc[s][..width].copy_from_slice(&start.row(y, n0 + s)[o0..]);
    }
    for i in 0..I {
        let wr = &w[i][o0..];
        for s in 0..TN {
            let xs = x[n0 + s][i];
            for (a, wv) in acc[s][..width].iter_mut().zip(wr) {
                *a = mul_add(xs, *wv, *a);
            }
        }
    }
    for s in 0..TN {
        for l in 0..width {
            let v = acc[s][l];
            y[n0 + s][o0 + l] = if RELU { relu_one(v) } else { v };
        }
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
pub(super) fn accumulate_one<const I: usize, const O: usize, const RELU: bool>(
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
    if O >= CHUNK_1 || NARROW_SKIPS_ZEROS {
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
    if o0 < O && NARROW_SKIPS_ZEROS {
        // The rest of the outputs (a narrow head) together: one chain per output, over the
        // non-zero inputs only. On an out-of-order x86 core a narrow head's few chains are
        // bound by the FMA's latency (four cycles per input, one input after another), so the
        // skipped half of a ReLU layer's inputs is half of its time.
        for &i in nz {
            let i = i as usize;
            let xi = x[i];
            for o in o0..O {
                init[o] = mul_add(xi, w[i][o], init[o]);
            }
        }
    } else if o0 < O {
        // Every input (exactly the same sums as skipping the zeros): on an in-order Cortex-M
        // the index list costs more instructions than the skipped fused multiply-adds save,
        // and the loop's constant trip count unrolls (benches/cortex_m.rs: 10,467 instructions
        // per cartpole inference this way, 11,480 with the skip).
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
/// The 8-wide weight gradient for columns `o0..O` (all of [`weight_grad_chunks`] but its
/// dispatch and checks).
pub(super) fn weight_grad_from<const I: usize, const O: usize>(
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
/// Columns `o0..O` (the last `O % 8`, fewer than 8) of [`weight_grad_chunks`]. The lanes of a
/// register are 8 consecutive input rows (one sample's activations `x[n][i..i + 8]` are
/// contiguous) and each narrow column has its own accumulators, so every lane is one entry
/// `gw[i][o]`, summed over the samples in order as everywhere else; tiles of 8, 16 or 32
/// rows keep enough independent chains in flight. Rows left over (fewer than 8) go one at a
/// time.
fn weight_grad_narrow<const I: usize, const O: usize>(
    x: &[&[[f32; I]]],
    dy: &[&[[f32; O]]],
    i0: usize,
    gw: &mut [[f32; O]],
    o0: usize,
) {
    let width = O % LANES;
    assert_eq!(
        o0 + width,
        O,
        "narrow columns start at the last multiple of 8"
    );
    let o0 = O - width;
    let rows = gw.len();
    let mut r = 0;
    // About eight accumulator registers per tile: 4 blocks of rows for 1-2 columns, 2 for
    // 3-4, 1 for more.
    let k = match width {
        1 | 2 => 4,
        3 | 4 => 2,
        _ => 1,
    };
    while k == 4 && r + 4 * LANES <= rows {
        grad_narrow_tile::<I, O, 4>(x, dy, i0 + r, &mut gw[r..r + 4 * LANES], o0);
        r += 4 * LANES;
    }
    while k >= 2 && r + 2 * LANES <= rows {
        grad_narrow_tile::<I, O, 2>(x, dy, i0 + r, &mut gw[r..r + 2 * LANES], o0);
        r += 2 * LANES;
    }
    while r + LANES <= rows {
        grad_narrow_tile::<I, O, 1>(x, dy, i0 + r, &mut gw[r..r + LANES], o0);
        r += LANES;
    }
    while r < rows {
        let mut acc = [0f32; LANES];
        for (xc, dc) in x.iter().zip(dy) {
            for (xn, dn) in xc.iter().zip(dc.iter()) {
                let xk = xn[i0 + r];
                for (a, dv) in acc[..width].iter_mut().zip(&dn[o0..]) {
                    *a = mul_add(xk, *dv, *a);
                }
            }
        }
        gw[r][o0..].copy_from_slice(&acc[..width]);
        r += 1;
    }
}

#[cfg(feature = "train")]
/// `8 K` input rows from `i` by the narrow columns `o0..O` of the weight gradient, lanes
/// over rows, written into `gw` (`8 K` rows).
#[inline(always)]
fn grad_narrow_tile<const I: usize, const O: usize, const K: usize>(
    x: &[&[[f32; I]]],
    dy: &[&[[f32; O]]],
    i: usize,
    gw: &mut [[f32; O]],
    o0: usize,
) {
    let width = O - o0;
    let mut acc = [[[0f32; LANES]; K]; LANES];
    for (xc, dc) in x.iter().zip(dy) {
        for (xn, dn) in xc.iter().zip(dc.iter()) {
            let mut xv = [[0f32; LANES]; K];
            for k in 0..K {
                xv[k] = xn[i + LANES * k..i + LANES * (k + 1)].try_into().unwrap();
            }
            for o in 0..width {
                let d = dn[o0 + o];
                for k in 0..K {
                    for l in 0..LANES {
                        acc[o][k][l] = mul_add(xv[k][l], d, acc[o][k][l]);
                    }
                }
            }
        }
    }
    for o in 0..width {
        for k in 0..K {
            for l in 0..LANES {
                gw[LANES * k + l][o0 + o] = acc[o][k][l];
            }
        }
    }
}
