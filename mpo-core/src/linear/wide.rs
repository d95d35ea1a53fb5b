//! The batch forward and weight-gradient kernels in 512-bit registers, for x86-64 CPUs that
//! have AVX-512F.
//!
//! The workspace builds for x86-64-v3 (AVX2), so [`crate::linear`]'s kernels are 8 floats wide.
//! On a CPU with two 512-bit FMA pipes (Intel Xeon since Skylake-SP) a 16-wide fused
//! multiply-add does twice the work per instruction: `cargo bench --bench kernels` measures
//! both peaks (docs/core.md, "512-bit kernels on an AVX-512 CPU"). This module holds those
//! kernels, chosen at run time ([`enabled`]), so one binary runs everywhere.
//!
//! **Same bits.** Every output is computed exactly as in [`crate::linear::kernel`]: its start
//! value, then one fused multiply-add per input in ascending input order
//! (`_mm512_fmadd_ps` rounds each lane once, as `linear::mul_add` does), then the ReLU as
//! `max(v, +0)` with `_mm512_max_ps`, whose result is `v` if `v > 0` and `+0` otherwise, the
//! definition [`crate::linear::relu_one`] spells out for the 8-wide path. Only which outputs
//! share a register changes, and lanes never mix. `linear`'s tests compare the two paths bit
//! for bit on the CPU running them.
//!
//! The weight gradient likewise ([`weight_grad`]): each entry summed from zero over the
//! chunks in order and their samples in ascending order, one fused multiply-add each.
//!
//! Tiles: 8 samples (or, for the weight gradient, 8 input rows) x 48 outputs (24 accumulators,
//! 3 weight or gradient registers and a broadcast: 28 of the 32 registers), then 32- and
//! 16-wide strips; outputs left over (fewer than 16) and the narrow heads go to the 8-wide
//! kernels.
#![allow(unsafe_code)]

use core::arch::x86_64::{
    __cpuid, __cpuid_count, __m512, _mm512_fmadd_ps, _mm512_loadu_ps, _mm512_max_ps,
    _mm512_set1_ps, _mm512_setzero_ps, _mm512_storeu_ps, _xgetbv,
};
use core::sync::atomic::{AtomicU8, Ordering};

use super::order::Start;

/// Floats per 512-bit register.
const W: usize = 16;
/// Samples per tile.
const TILE_N: usize = 8;

/// 0: not yet probed; 1: off; 2: on.
static STATE: AtomicU8 = AtomicU8::new(0);

/// Whether this CPU and operating system run AVX-512F code: CPUID leaf 7 reports the
/// instructions, and XCR0 says the OS saves the opmask and all 512-bit register state.
pub fn detected() -> bool {
    // Leaf 7 is read only after leaf 0 says it exists.
    let (max_leaf, osxsave) = (__cpuid(0).eax, __cpuid(1).ecx & (1 << 27) != 0);
    if max_leaf < 7 || !osxsave {
        return false;
    }
    let avx512f = __cpuid_count(7, 0).ebx & (1 << 16) != 0;
    // XCR0 bits 1, 2 (SSE, AVX state), 5, 6, 7 (opmask, upper halves of ZMM0-15, ZMM16-31).
    avx512f && xcr0() & 0xE6 == 0xE6
}

/// XCR0, readable because the OS set CPUID.1:ECX.OSXSAVE (the caller checked it).
fn xcr0() -> u64 {
    #[target_feature(enable = "xsave")]
    unsafe fn read() -> u64 {
        // SAFETY: the caller's contract (OSXSAVE set).
        unsafe { _xgetbv(0) }
    }
    // SAFETY: OSXSAVE is set, so XGETBV is enabled and the `xsave` feature exists.
    unsafe { read() }
}

/// Whether [`crate::linear::kernel`] takes the 512-bit path: on wherever [`detected`], unless
/// turned off with [`set_enabled`].
#[inline]
pub fn enabled() -> bool {
    match STATE.load(Ordering::Relaxed) {
        2 => true,
        1 => false,
        _ => {
            let on = detected();
            STATE.store(if on { 2 } else { 1 }, Ordering::Relaxed);
            on
        }
    }
}

/// Turns the 512-bit path off (`false`) or back on where the CPU has it (`true`). Results are
/// the same bits either way; benches use it to time both paths in one process.
pub fn set_enabled(on: bool) {
    STATE.store(if on && detected() { 2 } else { 1 }, Ordering::Relaxed);
}

/// `y[n] = start[n] + x[n] W` (then ReLU when `RELU`) for outputs `0 .. 16 * (O / 16)`;
/// returns the first output it did not compute (the caller's 8-wide kernels do the rest).
///
/// # Safety
/// The CPU must have AVX-512F ([`detected`]).
#[target_feature(enable = "avx512f,fma")]
pub unsafe fn kernel<const I: usize, const O: usize, const RELU: bool>(
    x: &[[f32; I]],
    w: &[[f32; O]; I],
    start: Start<'_, O>,
    y: &mut [[f32; O]],
) -> usize {
    let mut o0 = 0;
    while o0 + 3 * W <= O {
        strip::<I, O, 3, RELU>(x, w, start, y, o0);
        o0 += 3 * W;
    }
    if o0 + 2 * W <= O {
        strip::<I, O, 2, RELU>(x, w, start, y, o0);
        o0 += 2 * W;
    }
    if o0 + W <= O {
        strip::<I, O, 1, RELU>(x, w, start, y, o0);
        o0 += W;
    }
    o0
}

/// Outputs `o0 .. o0 + 16 K` of every row: tiles of 8 samples, then of 4, then single rows.
#[inline(always)]
fn strip<const I: usize, const O: usize, const K: usize, const RELU: bool>(
    x: &[[f32; I]],
    w: &[[f32; O]; I],
    start: Start<'_, O>,
    y: &mut [[f32; O]],
    o0: usize,
) {
    let mut n0 = 0;
    while n0 + TILE_N <= x.len() {
        tile::<I, O, TILE_N, K, RELU>(x, w, start, y, n0, o0);
        n0 += TILE_N;
    }
    if n0 + 4 <= x.len() {
        tile::<I, O, 4, K, RELU>(x, w, start, y, n0, o0);
        n0 += 4;
    }
    while n0 < x.len() {
        tile::<I, O, 1, K, RELU>(x, w, start, y, n0, o0);
        n0 += 1;
    }
}

/// `TN` samples from `n0` by `16 K` outputs from `o0`, accumulators in registers while the
/// inputs stream. Every pointer comes from a slice of the exact length read or written, so
/// the bounds are checked once per tile and row.
#[inline(always)]
fn tile<const I: usize, const O: usize, const TN: usize, const K: usize, const RELU: bool>(
    x: &[[f32; I]],
    w: &[[f32; O]; I],
    start: Start<'_, O>,
    y: &mut [[f32; O]],
    n0: usize,
    o0: usize,
) {
    let xs: &[[f32; I]; TN] = x[n0..n0 + TN].try_into().unwrap();
    // SAFETY (every block below): the caller guarantees AVX-512F; each load or store reads or
    // writes `16 K` floats inside a slice of exactly that length.
    let mut acc = [[unsafe { _mm512_setzero_ps() }; K]; TN];
    for s in 0..TN {
        let src = &start.row(y, n0 + s)[o0..o0 + W * K];
        for k in 0..K {
            acc[s][k] = unsafe { _mm512_loadu_ps(src[W * k..].as_ptr()) };
        }
    }
    for i in 0..I {
        let wr = &w[i][o0..o0 + W * K];
        let mut wv = [unsafe { _mm512_setzero_ps() }; K];
        for k in 0..K {
            wv[k] = unsafe { _mm512_loadu_ps(wr[W * k..].as_ptr()) };
        }
        for s in 0..TN {
            let xb = unsafe { _mm512_set1_ps(xs[s][i]) };
            for k in 0..K {
                acc[s][k] = unsafe { _mm512_fmadd_ps(xb, wv[k], acc[s][k]) };
            }
        }
    }
    let zero = unsafe { _mm512_setzero_ps() };
    for s in 0..TN {
        let dst = &mut y[n0 + s][o0..o0 + W * K];
        for k in 0..K {
            let v: __m512 = if RELU {
                unsafe { _mm512_max_ps(acc[s][k], zero) }
            } else {
                acc[s][k]
            };
            unsafe { _mm512_storeu_ps(dst[W * k..].as_mut_ptr(), v) };
        }
    }
}

/// Columns `0 .. 16 * (O / 16)` of `linear::weight_grad_chunks` (rows `i0 .. i0 + gw.len()`);
/// returns the first column it did not compute.
///
/// # Safety
/// The CPU must have AVX-512F ([`detected`]).
#[cfg(feature = "train")]
#[target_feature(enable = "avx512f,fma")]
pub unsafe fn weight_grad<const I: usize, const O: usize>(
    x: &[&[[f32; I]]],
    dy: &[&[[f32; O]]],
    i0: usize,
    gw: &mut [[f32; O]],
) -> usize {
    let mut o0 = 0;
    while o0 + 3 * W <= O {
        grad_strip::<I, O, 3>(x, dy, i0, gw, o0);
        o0 += 3 * W;
    }
    if o0 + 2 * W <= O {
        grad_strip::<I, O, 2>(x, dy, i0, gw, o0);
        o0 += 2 * W;
    }
    if o0 + W <= O {
        grad_strip::<I, O, 1>(x, dy, i0, gw, o0);
        o0 += W;
    }
    o0
}

/// Columns `o0 .. o0 + 16 K` of the weight gradient: tiles of 8 input rows, then single rows.
#[cfg(feature = "train")]
#[inline(always)]
fn grad_strip<const I: usize, const O: usize, const K: usize>(
    x: &[&[[f32; I]]],
    dy: &[&[[f32; O]]],
    i0: usize,
    gw: &mut [[f32; O]],
    o0: usize,
) {
    let rows = gw.len();
    let mut r = 0;
    while r + TILE_N <= rows {
        grad_tile::<I, O, TILE_N, K>(x, dy, i0 + r, &mut gw[r..r + TILE_N], o0);
        r += TILE_N;
    }
    while r < rows {
        grad_tile::<I, O, 1, K>(x, dy, i0 + r, &mut gw[r..r + 1], o0);
        r += 1;
    }
}

/// `TI` input rows from `i` by `16 K` columns from `o0`, summed over every sample of every
/// chunk in order, written into `gw` (`TI` rows).
#[cfg(feature = "train")]
#[inline(always)]
fn grad_tile<const I: usize, const O: usize, const TI: usize, const K: usize>(
    x: &[&[[f32; I]]],
    dy: &[&[[f32; O]]],
    i: usize,
    gw: &mut [[f32; O]],
    o0: usize,
) {
    // SAFETY (every block below): the caller guarantees AVX-512F; each load or store reads or
    // writes `16 K` floats inside a slice of exactly that length.
    let mut acc = [[unsafe { _mm512_setzero_ps() }; K]; TI];
    for (xc, dc) in x.iter().zip(dy) {
        for (xn, dn) in xc.iter().zip(dc.iter()) {
            let dr = &dn[o0..o0 + W * K];
            let mut d = [unsafe { _mm512_setzero_ps() }; K];
            for k in 0..K {
                d[k] = unsafe { _mm512_loadu_ps(dr[W * k..].as_ptr()) };
            }
            let xs: &[f32; TI] = xn[i..i + TI].try_into().unwrap();
            for t in 0..TI {
                let xb = unsafe { _mm512_set1_ps(xs[t]) };
                for k in 0..K {
                    acc[t][k] = unsafe { _mm512_fmadd_ps(xb, d[k], acc[t][k]) };
                }
            }
        }
    }
    for t in 0..TI {
        let dst = &mut gw[t][o0..o0 + W * K];
        for k in 0..K {
            unsafe { _mm512_storeu_ps(dst[W * k..].as_mut_ptr(), acc[t][k]) };
        }
    }
}
