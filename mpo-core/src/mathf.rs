//! Elementary functions written from `+`, `*`, fma and integer operations on the bits, in a
//! fixed order: the same bits on every CPU and build (like the kernels, `crate::linear`), and
//! branch-free, so a loop of them vectorises (`libm::expf` is software and scalar).
//!
//! Used where a function runs per unit of a batch: the categorical critic's softmax over its
//! bins ([`crate::value_head`]), the layer-normalised critic's `tanh`
//! ([`crate::layer_norm`]) and the squashed mean ([`crate::squash`]).

use crate::linear::mul_add;

/// `log2(e)`.
const LOG2E: f32 = core::f32::consts::LOG2_E;
/// `ln 2` split into a part exact in few bits and the rest (Cody and Waite), so `x - n ln 2`
/// is exact for the `n` that occur.
const LN2_HI: f32 = 0.693_359_4;
const LN2_LO: f32 = -2.121_944_4e-4;
/// `1.5 * 2^23`: adding and subtracting it rounds an `f32` of magnitude below `2^22` to the
/// nearest integer (ties to even) in the current rounding mode, without a branch.
const ROUND: f32 = 12_582_912.0;

/// `e^x`, within 2 ulp of the exact value for `x` in `[-87, 88]` (inputs outside are clamped
/// there, so the result is always a normal number; NaN stays NaN).
///
/// `x = n ln 2 + r` with `n = round(x log2 e)` and `|r| <= ln 2 / 2`; `e^r` by its degree-6
/// Taylor polynomial in Horner form (Cephes' `expf` coefficients), scaled by `2^n` through
/// the exponent bits.
#[inline(always)]
pub fn exp(x: f32) -> f32 {
    let x = x.clamp(-87.0, 88.0);
    let n = mul_add(x, LOG2E, ROUND) - ROUND;
    let r = mul_add(-n, LN2_HI, x);
    let r = mul_add(-n, LN2_LO, r);
    let mut p = 1.987_569_1e-4;
    p = mul_add(p, r, 1.398_199_9e-3);
    p = mul_add(p, r, 8.333_452e-3);
    p = mul_add(p, r, 4.166_579_6e-2);
    p = mul_add(p, r, 1.666_666_5e-1);
    p = mul_add(p, r, 5e-1);
    p = mul_add(p, r * r, r) + 1.0;
    let scale = f32::from_bits((((n as i32) + 127) as u32) << 23);
    p * scale
}

/// Below this `|x|`, [`tanh`] takes the odd polynomial (where `1 - 2 / (e^2x + 1)` would lose
/// the relative precision of a small result to cancellation).
const TANH_SMALL: f32 = 0.625;

/// `tanh(x)`, within 2 ulp of the exact value everywhere (`tanh(x) = +-1` beyond about 9.01;
/// NaN stays NaN), branch-free so a loop of it vectorises (`libm::tanhf` does not).
///
/// For `|x| < 0.625` the odd minimax polynomial `x + x^3 P(x^2)` (Cephes' `tanhf`
/// coefficients); above, `1 - 2 / (e^(2|x|) + 1)` with [`exp`], and the sign of `x`.
#[inline(always)]
pub fn tanh(x: f32) -> f32 {
    let a = x.abs();
    let z = x * x;
    let mut p = -5.704_988_7e-3;
    p = mul_add(p, z, 2.063_909e-2);
    p = mul_add(p, z, -5.373_971_6e-2);
    p = mul_add(p, z, 1.333_144_2e-1);
    p = mul_add(p, z, -3.333_328e-1);
    let small = mul_add(p * z, x, x);
    let large = (1.0 - 2.0 / (exp(a + a) + 1.0)).copysign(x);
    if a < TANH_SMALL { small } else { large }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;

    /// Against the correctly rounded f64 `exp` over the whole clamped range, densely near
    /// zero (where the softmax's largest bins are): at most 2 ulp, and exactly 1 at 0.
    #[test]
    fn exp_is_within_two_ulp() {
        assert_eq!(exp(0.0), 1.0);
        let mut worst = 0f64;
        let mut x = -87.0f32;
        while x <= 88.0 {
            for dx in [0.0f32, 1e-3, 0.3137] {
                let v = x + dx;
                if v > 88.0 {
                    continue;
                }
                let want = (v as f64).exp();
                let got = exp(v) as f64;
                let ulp = f32::EPSILON as f64 * want.abs().max(f32::MIN_POSITIVE as f64);
                worst = worst.max((got - want).abs() / ulp);
            }
            x += 0.0625;
        }
        assert!(worst <= 2.0, "worst error {worst} ulp");
        assert!(exp(-1e9) > 0.0 && exp(-1e9).is_normal());
        assert!(exp(f32::NAN).is_nan());
    }

    /// Against f64 `tanh` over `[-12, 12]` in steps of 1/4096 plus points near 0 and the
    /// switch at 0.625: at most 2 ulp of the exact value (1.05 measured); odd, saturating, NaN kept.
    #[test]
    fn tanh_is_within_two_ulp_and_odd() {
        let mut worst = 0f64;
        let mut check = |v: f32| {
            let want = (v as f64).tanh();
            let got = tanh(v) as f64;
            let ulp = f32::EPSILON as f64 * want.abs().max(f32::MIN_POSITIVE as f64);
            worst = worst.max((got - want).abs() / ulp);
            assert_eq!(tanh(-v), -tanh(v), "not odd at {v}");
        };
        let mut k = -12 * 4096;
        while k <= 12 * 4096 {
            check(k as f32 / 4096.0);
            k += 1;
        }
        for v in [1e-30f32, 1e-8, 1e-4, 0.1, 0.624_999_9, 0.625, 0.625_000_1] {
            check(v);
        }
        std::eprintln!("tanh: worst error {worst:.2} ulp");
        assert!(worst <= 2.0, "worst error {worst} ulp");
        assert_eq!(tanh(0.0), 0.0);
        assert_eq!(tanh(20.0), 1.0);
        assert_eq!(tanh(-1e30), -1.0);
        assert!(tanh(f32::NAN).is_nan());
    }
}
