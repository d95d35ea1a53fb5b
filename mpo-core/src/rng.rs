//! The one random source of the core: xoshiro256++, always explicitly seeded.
//!
//! Every draw goes through the `libm` crate and fixed arithmetic, so a seed fixes the bits of
//! every sample on every target (no platform maths, no hidden entropy).

use rand_core::{Rng as _, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;

/// The tags of the learner's per-row random streams ([`Rng::for_stream`]), in one
/// list so no two uses share a stream.
pub mod stream {
    /// The E-step's `M` samples at a row's state.
    pub const ESTEP: u32 = 0;
    /// The `N` next-action samples of sequence position `k` are stream `NEXT_ACTIONS + k`.
    pub const NEXT_ACTIONS: u32 = 1;
}

/// Seeded random source with the draws the algorithm needs.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Rng {
    inner: Xoshiro256PlusPlus,
}

impl Rng {
    /// Seeds the generator from one integer (SplitMix64 expansion, as `rand` does).
    pub fn seed_from_u64(seed: u64) -> Self {
        Self {
            inner: Xoshiro256PlusPlus::seed_from_u64(seed),
        }
    }

    /// Restores a generator from [`Rng::state`], bit for bit (for checkpoints).
    pub fn from_state(state: [u8; 32]) -> Self {
        Self {
            inner: Xoshiro256PlusPlus::from_seed(state),
        }
    }

    /// The full generator state; [`Rng::from_state`] continues the same stream.
    pub fn state(&self) -> [u8; 32] {
        self.inner.state()
    }

    /// A stream keyed by `(seed, stream, index)`: the key is hashed (SplitMix64's finaliser,
    /// twice) before seeding, so neighbouring keys give unrelated generators. The learner
    /// gives every batch row its own stream this way, which is what makes its draws
    /// independent of how the batch is split over chunks and threads.
    pub fn for_stream(seed: u64, stream: u32, index: u32) -> Self {
        let key = ((stream as u64) << 32) | index as u64;
        Self::seed_from_u64(mix64(seed ^ mix64(key)))
    }

    /// An independent stream: the state 2^128 draws ahead, so streams never overlap.
    pub fn split(&mut self) -> Self {
        let child = self.clone();
        self.inner.jump();
        child
    }

    /// 64 uniformly random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.inner.next_u64()
    }

    /// Uniform in [0, 1) with 24 random bits (every representable step of that grid).
    pub fn uniform(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 * (1.0 / (1u32 << 24) as f32)
    }

    /// Uniform in (0, 1]: safe to take the logarithm of.
    pub fn uniform_open0(&mut self) -> f32 {
        ((self.next_u64() >> 40) + 1) as f32 * (1.0 / (1u32 << 24) as f32)
    }

    /// Uniform in [lo, hi).
    pub fn uniform_range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.uniform()
    }

    /// Uniform integer in [0, n) without modulo bias (Lemire's multiply-and-reject).
    ///
    /// # Panics
    /// If `n == 0`.
    pub fn below(&mut self, n: u64) -> u64 {
        assert!(n > 0, "Rng::below(0)");
        let threshold = n.wrapping_neg() % n;
        loop {
            let m = (self.next_u64() as u128) * (n as u128);
            if (m as u64) >= threshold {
                return (m >> 64) as u64;
            }
        }
    }

    /// Standard normal draw (Box-Muller's cosine half: one output per call, so the stream is
    /// one word sequence with no cached value to checkpoint).
    pub fn normal(&mut self) -> f32 {
        let u1 = self.uniform_open0();
        let u2 = self.uniform();
        libm::sqrtf(-2.0 * libm::logf(u1)) * libm::cosf(core::f32::consts::TAU * u2)
    }

    /// Fills `out` with standard normal draws, in order: both halves of each Box-Muller pair
    /// (`r cos t`, then `r sin t`), an odd last element from [`Rng::normal`]. The values
    /// depend only on the stream and the length, so a caller that fills the same lengths in
    /// the same order gets the same draws anywhere.
    pub fn fill_normal(&mut self, out: &mut [f32]) {
        let mut pairs = out.chunks_exact_mut(2);
        for p in &mut pairs {
            let u1 = self.uniform_open0();
            let u2 = self.uniform();
            let r = libm::sqrtf(-2.0 * libm::logf(u1));
            let (s, c) = libm::sincosf(core::f32::consts::TAU * u2);
            p[0] = r * c;
            p[1] = r * s;
        }
        if let [x] = pairs.into_remainder() {
            *x = self.normal();
        }
    }
}

/// SplitMix64's output function: a bijective 64-bit mix.
fn mix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_seed_same_stream_and_state_round_trip() {
        let mut a = Rng::seed_from_u64(7);
        let mut b = Rng::seed_from_u64(7);
        for _ in 0..100 {
            assert_eq!(a.next_u64(), b.next_u64());
        }
        let mut c = Rng::from_state(a.state());
        for _ in 0..100 {
            assert_eq!(a.normal().to_bits(), c.normal().to_bits());
        }
        let (mut x, mut y) = ([0f32; 7], [0f32; 7]);
        a.fill_normal(&mut x);
        c.fill_normal(&mut y);
        assert_eq!(x.map(f32::to_bits), y.map(f32::to_bits));
        assert_ne!(
            Rng::seed_from_u64(8).next_u64(),
            Rng::seed_from_u64(7).next_u64()
        );
    }

    #[test]
    fn uniform_and_normal_moments() {
        let mut r = Rng::seed_from_u64(1);
        let n = 200_000;
        let (mut s, mut s2, mut u) = (0f64, 0f64, 0f64);
        let mut pair = [0f32; 2];
        let mut cross = 0f64;
        for k in 0..n {
            // Alternate the single draw and both halves of a pair: every path is a standard
            // normal, and the two halves of a pair are uncorrelated.
            let z = if k % 2 == 0 {
                r.normal() as f64
            } else {
                r.fill_normal(&mut pair);
                cross += pair[0] as f64 * pair[1] as f64;
                pair[1] as f64
            };
            s += z;
            s2 += z * z;
            let x = r.uniform();
            assert!((0.0..1.0).contains(&x));
            u += x as f64;
        }
        let mean = s / n as f64;
        let var = s2 / n as f64 - mean * mean;
        assert!(mean.abs() < 0.01, "normal mean {mean}");
        assert!((var - 1.0).abs() < 0.01, "normal variance {var}");
        assert!((u / n as f64 - 0.5).abs() < 0.005);
        assert!((cross / (n / 2) as f64).abs() < 0.01, "pair correlation");
    }

    #[test]
    fn below_is_in_range_and_covers() {
        let mut r = Rng::seed_from_u64(3);
        let mut seen = [0u32; 7];
        for _ in 0..7000 {
            seen[r.below(7) as usize] += 1;
        }
        assert!(seen.iter().all(|&c| (850..1150).contains(&c)), "{seen:?}");
    }
}
