//! numpy's `Generator(PCG64(SeedSequence(seed)))`, reimplemented draw for draw.
//!
//! Gymnasium seeds an environment with `np.random.Generator(np.random.PCG64(SeedSequence(seed)))`
//! (`gymnasium.utils.seeding.np_random`) and its MuJoCo tasks draw the initial state from it with
//! `uniform` and `standard_normal`. A task file with `convention = "gymnasium"` draws from this
//! stream, so a seed gives the initial states Gymnasium gives (tested against numbers printed by
//! numpy: `tests/numpy_generator.rs`).
//!
//! The pieces, as numpy 2 computes them:
//! - `SeedSequence(entropy)`: the integer seed as 32-bit words, hashed into a pool of four
//!   words, from which `generate_state(4, uint64)` draws PCG64's 128-bit state and increment;
//! - PCG64: a 128-bit LCG with numpy's multiplier, output XSL-RR (the high and low halves
//!   xor-ed and rotated by the top six bits), stepped before each output;
//! - `random()`: the top 53 bits of a 64-bit output, times 2^-53; `uniform(low, high)`:
//!   `low + (high - low) * random()`;
//! - `standard_normal()`: the 256-layer ziggurat of Marsaglia and Tsang on 52-bit mantissas, its
//!   tables built here by the recurrence that defines them (the layers have equal area `V`), in
//!   double precision as numpy's were (see [`tables`] for the one step where they differ).

use std::sync::OnceLock;

/// SeedSequence's hashing constants (numpy's `bit_generator.pyx`).
const INIT_A: u32 = 0x43b0_d7e5;
const MULT_A: u32 = 0x931e_8875;
const INIT_B: u32 = 0x8b51_f9dd;
const MULT_B: u32 = 0x58f3_8ded;
const MIX_MULT_L: u32 = 0xca01_f9dd;
const MIX_MULT_R: u32 = 0x4973_f715;
const XSHIFT: u32 = 16;
/// SeedSequence's pool: four 32-bit words.
const POOL: usize = 4;

/// numpy's PCG64 multiplier, 0x2360ed051fc65da4_4385df649fccf645.
const PCG_MULT: u128 = (2_549_297_995_355_413_924u128 << 64) | 4_865_540_595_714_422_341u128;

/// `hashmix`: one word hashed with the running constant, which advances.
fn hashmix(value: u32, hash_const: &mut u32) -> u32 {
    let mut v = value ^ *hash_const;
    *hash_const = hash_const.wrapping_mul(MULT_A);
    v = v.wrapping_mul(*hash_const);
    v ^ (v >> XSHIFT)
}

fn mix(x: u32, y: u32) -> u32 {
    let r = MIX_MULT_L
        .wrapping_mul(x)
        .wrapping_sub(MIX_MULT_R.wrapping_mul(y));
    r ^ (r >> XSHIFT)
}

/// `SeedSequence(seed).generate_state(4, np.uint64)`: the four 64-bit words PCG64 is seeded
/// with. The seed is split into 32-bit words, least significant first (zero is one word).
pub fn seed_sequence_state(seed: u64) -> [u64; 4] {
    let entropy: &[u32] = &[seed as u32, (seed >> 32) as u32];
    let entropy = if seed >> 32 == 0 {
        &entropy[..1]
    } else {
        entropy
    };
    // mix_entropy: the pool from the entropy words (zeros past them), then every word mixed
    // into every other.
    let mut hash_const = INIT_A;
    let mut pool = [0u32; POOL];
    for (i, p) in pool.iter_mut().enumerate() {
        *p = hashmix(entropy.get(i).copied().unwrap_or(0), &mut hash_const);
    }
    for src in 0..POOL {
        for dst in 0..POOL {
            if src != dst {
                pool[dst] = mix(pool[dst], hashmix(pool[src], &mut hash_const));
            }
        }
    }
    // (At most two entropy words: none is left over for the pool of four.)
    // generate_state: eight 32-bit words cycling through the pool, read as four little-endian
    // 64-bit words.
    let mut hash_const = INIT_B;
    let mut words = [0u32; 2 * POOL];
    for (i, w) in words.iter_mut().enumerate() {
        let mut v = pool[i % POOL] ^ hash_const;
        hash_const = hash_const.wrapping_mul(MULT_B);
        v = v.wrapping_mul(hash_const);
        *w = v ^ (v >> XSHIFT);
    }
    let mut out = [0u64; 4];
    for (i, o) in out.iter_mut().enumerate() {
        *o = u64::from(words[2 * i]) | (u64::from(words[2 * i + 1]) << 32);
    }
    out
}

/// numpy's `PCG64` bit generator (PCG XSL-RR 128/64).
#[derive(Clone, Debug)]
pub struct Pcg64 {
    state: u128,
    inc: u128,
}

impl Pcg64 {
    /// `PCG64(SeedSequence(seed))`.
    pub fn new(seed: u64) -> Self {
        let s = seed_sequence_state(seed);
        // pcg64_set_seed: state from words 0 (high) and 1 (low), increment from 2 and 3.
        let initstate = (u128::from(s[0]) << 64) | u128::from(s[1]);
        let initseq = (u128::from(s[2]) << 64) | u128::from(s[3]);
        let mut rng = Self {
            state: 0,
            inc: (initseq << 1) | 1,
        };
        rng.step();
        rng.state = rng.state.wrapping_add(initstate);
        rng.step();
        rng
    }

    fn step(&mut self) {
        self.state = self.state.wrapping_mul(PCG_MULT).wrapping_add(self.inc);
    }

    /// The next 64-bit output.
    pub fn next_u64(&mut self) -> u64 {
        self.step();
        let s = self.state;
        ((s >> 64) as u64 ^ s as u64).rotate_right((s >> 122) as u32)
    }

    /// A double in [0, 1) from the top 53 bits of one output.
    pub fn next_double(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / 9_007_199_254_740_992.0)
    }
}

/// The ziggurat's rightmost layer edge `r`, `1 / r`, and the area `V` of every layer.
const ZIG_R: f64 = 3.654_152_885_361_009;
const ZIG_INV_R: f64 = 0.273_661_237_329_758_3;
/// `V` as numpy's tables have it: the value their first entries (`w[0] = V / f(r) / 2^52`,
/// `k[0]`) imply, 6e-18 below `r f(r) + sqrt(pi / 2) erfc(r / sqrt 2)`.
const ZIG_V: f64 = 0.004_928_673_233_974_652;
/// The edge of layer 37 in numpy's tables (0.87327106808886), two ulps below what this
/// recurrence gives with glibc's `log` and `exp` (0.8732710680888602). Every other edge follows
/// from the recurrence; this one step was evidently rounded differently where numpy's tables
/// were made, and the 36 layers below inherit it. Found by recovering numpy's `w[i]` from its
/// draws (each `x = rabs * w[idx]` with known `rabs` pins `w` to one double).
const LAYER_37_EDGE: u64 = 0x3feb_f1d6_2abf_8232;
/// Layer widths are scaled to 52-bit integers.
const MANTISSA: f64 = 4_503_599_627_370_496.0;

/// The ziggurat's tables: per layer `i`, `k[i]` (a draw below it lies inside the layer's
/// rectangle under the curve), `w[i]` (the layer's width / 2^52) and `f[i]` (the density at its
/// edge).
struct Tables {
    k: [u64; 256],
    w: [f64; 256],
    f: [f64; 256],
}

/// Builds the tables from the bottom layer up (edges from `r` down to near 0): each layer's
/// edge `x` is where the density makes the layer beyond it have area `V`,
/// `x = sqrt(-2 ln(V / x_prev + f(x_prev)))`, in double precision with the platform's `ln`
/// and `exp` (glibc's, as numpy's legacy normals use), except layer 37's ([`LAYER_37_EDGE`]).
fn tables() -> &'static Tables {
    static TABLES: OnceLock<Tables> = OnceLock::new();
    TABLES.get_or_init(|| {
        let mut t = Tables {
            k: [0; 256],
            w: [0.0; 256],
            f: [0.0; 256],
        };
        let mut x1 = ZIG_R;
        t.w[255] = x1 / MANTISSA;
        t.f[255] = (-0.5 * x1 * x1).exp();
        // Layer 0 is the base strip with the tail: its "width" is V / f(r).
        t.k[0] = (x1 * t.f[255] / ZIG_V * MANTISSA) as u64;
        t.w[0] = ZIG_V / t.f[255] / MANTISSA;
        t.f[0] = 1.0;
        for i in (1..255).rev() {
            let x = if i == 37 {
                f64::from_bits(LAYER_37_EDGE)
            } else {
                (-2.0 * (ZIG_V / x1 + t.f[i + 1]).ln()).sqrt()
            };
            t.k[i + 1] = (x / x1 * MANTISSA) as u64;
            t.w[i] = x / MANTISSA;
            t.f[i] = (-0.5 * x * x).exp();
            x1 = x;
        }
        t.k[1] = 0;
        t
    })
}

/// numpy's `Generator` on PCG64: the draws Gymnasium's MuJoCo tasks make.
#[derive(Clone, Debug)]
pub struct Generator {
    bits: Pcg64,
}

impl Generator {
    /// `np.random.Generator(np.random.PCG64(np.random.SeedSequence(seed)))`, as Gymnasium's
    /// `reset(seed=seed)` makes it.
    pub fn new(seed: u64) -> Self {
        tables();
        Self {
            bits: Pcg64::new(seed),
        }
    }

    /// `random()`: a double in [0, 1).
    pub fn random(&mut self) -> f64 {
        self.bits.next_double()
    }

    /// `uniform(low, high)`: `low + (high - low) * random()`.
    pub fn uniform(&mut self, low: f64, high: f64) -> f64 {
        let range = high - low;
        low + range * self.random()
    }

    /// `standard_normal()`: the ziggurat. One 64-bit output gives the layer (8 bits), the sign
    /// (1 bit) and a 52-bit position; 99% of draws are accepted at once.
    pub fn standard_normal(&mut self) -> f64 {
        let t = tables();
        loop {
            let r = self.bits.next_u64();
            let idx = (r & 0xff) as usize;
            let r = r >> 8;
            let negative = r & 1 == 1;
            let rabs = (r >> 1) & 0x000f_ffff_ffff_ffff;
            let mut x = rabs as f64 * t.w[idx];
            if negative {
                x = -x;
            }
            if rabs < t.k[idx] {
                return x;
            }
            if idx == 0 {
                // The tail beyond r (Marsaglia's method; `1 - U` keeps log away from 0).
                loop {
                    let xx = -ZIG_INV_R * (-self.random()).ln_1p();
                    let yy = -(-self.random()).ln_1p();
                    if yy + yy > xx * xx {
                        return if (rabs >> 8) & 1 == 1 {
                            -(ZIG_R + xx)
                        } else {
                            ZIG_R + xx
                        };
                    }
                }
            } else if (t.f[idx - 1] - t.f[idx]) * self.random() + t.f[idx] < (-0.5 * x * x).exp() {
                return x;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_ziggurat_layers_fall_from_r_to_zero() {
        let t = tables();
        // Widths increase with the layer (layer 0 is the base strip, wider than r), densities
        // decrease, and the top layer's edge is near 0 (its area is V like every other).
        for i in 2..256 {
            assert!(t.w[i] > t.w[i - 1], "w[{i}]");
            assert!(t.f[i] < t.f[i - 1], "f[{i}]");
        }
        assert!(t.w[0] * MANTISSA > ZIG_R);
        let top = t.w[1] * MANTISSA;
        assert!(top > 0.0 && top < 0.25, "{top}");
        assert_eq!(t.k[1], 0);
    }

    #[test]
    fn standard_normals_have_unit_variance() {
        let mut g = Generator::new(3);
        let n = 200_000;
        let (mut s, mut s2) = (0.0, 0.0);
        for _ in 0..n {
            let x = g.standard_normal();
            s += x;
            s2 += x * x;
        }
        let mean = s / n as f64;
        let var = s2 / n as f64 - mean * mean;
        assert!(mean.abs() < 0.01, "{mean}");
        assert!((var - 1.0).abs() < 0.01, "{var}");
    }
}
