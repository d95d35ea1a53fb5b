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
/// the `vsqrt.f32` instruction, on x86-64 builds with AVX (the host target) the VEX-encoded
/// `vsqrtss`, elsewhere `libm::sqrtf`. For the hot loops (Adam: one per parameter per update;
/// each layer norm row).
///
/// Not `libm::sqrtf` on the host: on x86 it is an inline-assembly `sqrtss`, the legacy SSE
/// encoding, which is slow among the 256- and 512-bit kernels on the AVX-512 Xeons this
/// project is measured on (the likely cause: an SSE/AVX transition on the vector registers'
/// upper state): a layer norm of 256 rows of 128 took 62 us with it, 33 us with `vsqrtss`,
/// beside 110 us for the 128 x 256 layer after it (`cargo bench --bench kernels -- norm`,
/// docs/core.md).
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
    #[cfg(all(target_arch = "x86_64", target_feature = "avx"))]
    {
        use core::arch::x86_64::{_mm_cvtss_f32, _mm_set_ss, _mm_sqrt_ss};
        // SAFETY: the `avx` target feature is enabled for the whole build (checked by the cfg
        // above), so every CPU this binary may run on has the instruction; the intrinsics only
        // touch registers.
        #[allow(unsafe_code)]
        unsafe {
            _mm_cvtss_f32(_mm_sqrt_ss(_mm_set_ss(x)))
        }
    }
    #[cfg(not(any(
        all(target_arch = "x86_64", target_feature = "avx"),
        all(
            target_arch = "arm",
            target_feature = "mclass",
            target_feature = "fpregs"
        )
    )))]
    {
        libm::sqrtf(x)
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
