//! The order each output of every kernel is computed in, whatever the path (8-wide tiles,
//! 512-bit tiles, a single state, software FMA on a device): its start value ([`Start`]),
//! then one fused multiply-add ([`mul_add`]) per input in ascending order, then, for a fused
//! ReLU, [`relu_one`]. Every path computing exactly this is why a batch forward gives the
//! bits of a single-state one, and why no target CPU changes a result.

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

/// `a * b + c` with one rounding (IEEE 754 fusedMultiplyAdd).
///
/// On x86-64 builds with the `fma` target feature (the workspace's x86-64-v3 host target) this
/// is the FMA instruction, which the compiler vectorises; elsewhere (the baseline target of the
/// freestanding binaries, microcontrollers) it is `libm::fmaf`, correctly rounded in software
/// or with the instruction when the CPU has one. Both give the same bits for the same inputs.
#[inline(always)]
pub fn mul_add(a: f32, b: f32, c: f32) -> f32 {
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
    #[cfg(not(all(target_arch = "x86_64", target_feature = "fma")))]
    {
        libm::fmaf(a, b, c)
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
