//! Fixed-order row sums in eight lanes: the reductions of the layer norms and of the
//! categorical head's softmax.
//!
//! Lane `l` adds the entries `i = l mod 8` in ascending order, then the lanes are added
//! pairwise in a fixed tree (`fold`). Every build computes exactly that, so the sums have the
//! same bits on every target; what differs is only how many lanes one instruction carries.
//! On x86-64 builds with AVX and FMA (the host target) a lane group is one 256-bit register
//! (`F8` over `core::arch` intrinsics): written as eight scalar statements instead, the
//! compiler unrolled a 128-wide row completely and put most of it back together from scalars,
//! and a layer norm of 256 rows of 128 took a third of the 128 x 256 layer after it (`cargo
//! bench --bench kernels -- norm`, docs/core.md). Elsewhere (the freestanding baseline build,
//! Cortex-M) the same arithmetic runs one lane at a time.

use crate::linear::mul_add;

/// Lanes of the fixed-order row sums.
pub const LANES: usize = 8;

/// Eight lanes of partial sums.
#[derive(Clone, Copy)]
struct F8(
    #[cfg(all(target_arch = "x86_64", target_feature = "avx", target_feature = "fma"))]
    core::arch::x86_64::__m256,
    #[cfg(not(all(target_arch = "x86_64", target_feature = "avx", target_feature = "fma")))]
    [f32; LANES],
);

#[cfg(all(target_arch = "x86_64", target_feature = "avx", target_feature = "fma"))]
// SAFETY (every block below): the `avx` and `fma` target features are enabled for the whole
// build (the cfg above), so every CPU this binary may run on has the instructions; loads and
// stores go through `[f32; 8]` references, which are valid for eight `f32`s, and the
// unaligned forms need no alignment.
#[allow(unsafe_code)]
impl F8 {
    #[inline(always)]
    fn zero() -> Self {
        Self(unsafe { core::arch::x86_64::_mm256_setzero_ps() })
    }
    #[inline(always)]
    fn splat(v: f32) -> Self {
        Self(unsafe { core::arch::x86_64::_mm256_set1_ps(v) })
    }
    #[inline(always)]
    fn load(x: &[f32; LANES]) -> Self {
        Self(unsafe { core::arch::x86_64::_mm256_loadu_ps(x.as_ptr()) })
    }
    #[inline(always)]
    fn lanes(self) -> [f32; LANES] {
        let mut out = [0f32; LANES];
        unsafe { core::arch::x86_64::_mm256_storeu_ps(out.as_mut_ptr(), self.0) };
        out
    }
    #[inline(always)]
    fn add(self, o: Self) -> Self {
        Self(unsafe { core::arch::x86_64::_mm256_add_ps(self.0, o.0) })
    }
    #[inline(always)]
    fn sub(self, o: Self) -> Self {
        Self(unsafe { core::arch::x86_64::_mm256_sub_ps(self.0, o.0) })
    }
    #[inline(always)]
    fn mul(self, o: Self) -> Self {
        Self(unsafe { core::arch::x86_64::_mm256_mul_ps(self.0, o.0) })
    }
    /// `self * b + c` per lane, one rounding.
    #[inline(always)]
    fn mul_add(self, b: Self, c: Self) -> Self {
        Self(unsafe { core::arch::x86_64::_mm256_fmadd_ps(self.0, b.0, c.0) })
    }
    /// Per lane `self` if `self > o`, else `o` (`vmaxps`'s definition).
    #[inline(always)]
    fn max(self, o: Self) -> Self {
        Self(unsafe { core::arch::x86_64::_mm256_max_ps(self.0, o.0) })
    }
}

#[cfg(not(all(target_arch = "x86_64", target_feature = "avx", target_feature = "fma")))]
impl F8 {
    #[inline(always)]
    fn zero() -> Self {
        Self([0.0; LANES])
    }
    #[inline(always)]
    fn splat(v: f32) -> Self {
        Self([v; LANES])
    }
    #[inline(always)]
    fn load(x: &[f32; LANES]) -> Self {
        Self(*x)
    }
    #[inline(always)]
    fn lanes(self) -> [f32; LANES] {
        self.0
    }
    #[inline(always)]
    fn add(self, o: Self) -> Self {
        Self(core::array::from_fn(|l| self.0[l] + o.0[l]))
    }
    #[inline(always)]
    fn sub(self, o: Self) -> Self {
        Self(core::array::from_fn(|l| self.0[l] - o.0[l]))
    }
    #[inline(always)]
    fn mul(self, o: Self) -> Self {
        Self(core::array::from_fn(|l| self.0[l] * o.0[l]))
    }
    #[inline(always)]
    fn mul_add(self, b: Self, c: Self) -> Self {
        Self(core::array::from_fn(|l| mul_add(self.0[l], b.0[l], c.0[l])))
    }
    #[inline(always)]
    fn max(self, o: Self) -> Self {
        Self(core::array::from_fn(|l| gt_or(self.0[l], o.0[l])))
    }
}

/// Adds eight lanes pairwise: `((l0 + l1) + (l2 + l3)) + ((l4 + l5) + (l6 + l7))`.
#[inline(always)]
fn fold(a: [f32; LANES]) -> f32 {
    ((a[0] + a[1]) + (a[2] + a[3])) + ((a[4] + a[5]) + (a[6] + a[7]))
}

/// `a` if `a > b`, else `b`: a running maximum's step, the same on every path.
#[inline(always)]
fn gt_or(a: f32, b: f32) -> f32 {
    if a > b { a } else { b }
}

/// The full lane groups of `x` and the entries after them.
#[inline(always)]
fn groups(x: &[f32]) -> (&[[f32; LANES]], &[f32]) {
    x.as_chunks::<LANES>()
}

/// `sum_i x[i]` in the fixed eight-lane order (module doc).
#[inline]
pub fn sum8(x: &[f32]) -> f32 {
    let (full, rest) = groups(x);
    let mut acc = F8::zero();
    for c in full {
        acc = acc.add(F8::load(c));
    }
    let mut acc = acc.lanes();
    for (l, &v) in rest.iter().enumerate() {
        acc[l] += v;
    }
    fold(acc)
}

/// The largest entry of a non-empty `x` (each lane keeps its running maximum, then the lanes
/// meet in `fold`'s tree). Without NaNs the same number as a running maximum in index order
/// and every other order; only the sign of a zero maximum may differ between orders.
#[inline]
pub fn max8(x: &[f32]) -> f32 {
    let (full, rest) = groups(x);
    let mut acc = F8::splat(x[0]);
    for c in full {
        acc = F8::load(c).max(acc);
    }
    let mut a = acc.lanes();
    for (l, &v) in rest.iter().enumerate() {
        a[l] = gt_or(v, a[l]);
    }
    gt_or(
        gt_or(gt_or(a[0], a[1]), gt_or(a[2], a[3])),
        gt_or(gt_or(a[4], a[5]), gt_or(a[6], a[7])),
    )
}

/// `sum_i a[i] b[i]` in the fixed eight-lane order, one fma per term.
#[inline]
pub fn dot8(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len(), "dot8: lengths differ");
    let ((fa, ra), (fb, rb)) = (groups(a), groups(b));
    let mut acc = F8::zero();
    for (x, y) in fa.iter().zip(fb) {
        acc = F8::load(x).mul_add(F8::load(y), acc);
    }
    let mut acc = acc.lanes();
    for (l, (&x, &y)) in ra.iter().zip(rb).enumerate() {
        acc[l] = mul_add(x, y, acc[l]);
    }
    fold(acc)
}

/// `sum_i (x[i] - c)^2` in the fixed eight-lane order, one fma per term.
#[inline]
pub fn sq_dev8(x: &[f32], c: f32) -> f32 {
    let (full, rest) = groups(x);
    let cv = F8::splat(c);
    let mut acc = F8::zero();
    for g in full {
        let d = F8::load(g).sub(cv);
        acc = d.mul_add(d, acc);
    }
    let mut acc = acc.lanes();
    for (l, &v) in rest.iter().enumerate() {
        let d = v - c;
        acc[l] = mul_add(d, d, acc[l]);
    }
    fold(acc)
}

/// `out[i] = g[i] (x[i] - mean) r + b[i]` and `xhat[i] = (x[i] - mean) r`, each with the
/// layer norm's roundings: `xhat` rounded once after the product, then one fma.
#[inline]
pub fn normalize_into(
    x: &[f32],
    mean: f32,
    r: f32,
    g: &[f32],
    b: &[f32],
    xhat: &mut [f32],
    out: &mut [f32],
) {
    let n = x.len();
    assert!(g.len() == n && b.len() == n && xhat.len() == n && out.len() == n);
    let (mv, rv) = (F8::splat(mean), F8::splat(r));
    let full = n / LANES * LANES;
    let (xs, gs, bs) = (groups(x).0, groups(g).0, groups(b).0);
    let (hs, os) = (
        xhat.as_chunks_mut::<LANES>().0,
        out.as_chunks_mut::<LANES>().0,
    );
    for ((((x, g), b), h), o) in xs.iter().zip(gs).zip(bs).zip(hs).zip(os) {
        let xh = F8::load(x).sub(mv).mul(rv);
        *h = xh.lanes();
        *o = F8::load(g).mul_add(xh, F8::load(b)).lanes();
    }
    for i in full..n {
        xhat[i] = (x[i] - mean) * r;
        out[i] = mul_add(g[i], xhat[i], b[i]);
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use std::vec;
    use std::vec::Vec;

    /// The order the module promises, written out one lane at a time.
    fn lanes_reference(x: &[f32], term: impl Fn(usize) -> f32, fused: bool) -> f32 {
        let mut acc = [0f32; LANES];
        for i in 0..x.len() {
            let l = i % LANES;
            acc[l] = if fused {
                let d = x[i];
                mul_add(d, term(i), acc[l])
            } else {
                acc[l] + term(i)
            };
        }
        ((acc[0] + acc[1]) + (acc[2] + acc[3])) + ((acc[4] + acc[5]) + (acc[6] + acc[7]))
    }

    /// `n` values of mixed sign and scale: uniform in `[-3.5, 3.5)`.
    fn data(n: usize, seed: u32) -> Vec<f32> {
        let mut rng = crate::rng::Rng::seed_from_u64(u64::from(seed));
        (0..n).map(|_| rng.uniform_range(-3.5, 3.5)).collect()
    }

    #[test]
    fn every_length_sums_in_the_promised_lane_order() {
        // Lengths around the lane width and the built-in widths, so the vector groups and
        // the scalar tail both count; values of mixed sign and scale, so another order would
        // round differently (checked: summing in plain index order differs for most lengths).
        let mut differs = 0;
        for n in (0..40).chain([64, 101, 128, 255, 256]) {
            let (a, b) = (data(n, n as u32), data(n, 1000 + n as u32));
            let want = lanes_reference(&a, |i| a[i], false);
            assert_eq!(sum8(&a).to_bits(), want.to_bits(), "sum8, length {n}");
            let want = lanes_reference(&a, |i| b[i], true);
            assert_eq!(dot8(&a, &b).to_bits(), want.to_bits(), "dot8, length {n}");
            let c = 0.37;
            let d: Vec<f32> = a.iter().map(|v| v - c).collect();
            let want = lanes_reference(&d, |i| d[i], true);
            assert_eq!(
                sq_dev8(&a, c).to_bits(),
                want.to_bits(),
                "sq_dev8, length {n}"
            );
            differs += usize::from(a.iter().sum::<f32>().to_bits() != sum8(&a).to_bits());
        }
        assert!(
            differs > 10,
            "the data cannot tell the orders apart ({differs})"
        );
    }

    #[test]
    fn max8_is_the_largest_entry() {
        for n in (1..40).chain([101, 128]) {
            let a = data(n, 77 + n as u32);
            let want = a.iter().copied().fold(f32::NEG_INFINITY, f32::max);
            assert_eq!(max8(&a).to_bits(), want.to_bits(), "length {n}");
            // The largest in every position, the vector groups' and the tail's.
            for at in 0..n {
                let mut b = a.clone();
                b[at] = 100.0 + at as f32;
                assert_eq!(max8(&b), b[at], "length {n}, largest at {at}");
            }
        }
    }

    #[test]
    fn normalize_into_rounds_as_the_scalar_form() {
        for n in [5, 8, 13, 64, 128, 131] {
            let (x, g, b) = (data(n, 1), data(n, 2), data(n, 3));
            let (mean, r) = (0.3f32, 1.7f32);
            let (mut xhat, mut out) = (vec![0f32; n], vec![0f32; n]);
            normalize_into(&x, mean, r, &g, &b, &mut xhat, &mut out);
            for i in 0..n {
                let xh = (x[i] - mean) * r;
                assert_eq!(xhat[i].to_bits(), xh.to_bits(), "xhat[{i}] of {n}");
                let o = mul_add(g[i], xh, b[i]);
                assert_eq!(out[i].to_bits(), o.to_bits(), "out[{i}] of {n}");
            }
        }
    }
}
