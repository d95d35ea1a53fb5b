//! SimbaV2's projection of weights onto the unit hypersphere (Lee et al., 2025, "Hyperspherical
//! Normalization for Scalable Deep Reinforcement Learning"): after every optimiser step, each
//! output unit's incoming weight vector is scaled back to unit L2 norm.
//!
//! Why: in a network trained for long, the weights' norms grow, so the same Adam step moves
//! them less and less (the effective learning rate decays) and the network loses plasticity;
//! periodic resets ([`crate::config::MpoConfig::reset_interval`]) restore it by forgetting.
//! Held on the sphere, every step is the same fraction of a weight's norm for the whole run,
//! without forgetting anything. The layer norms' gains stay free and carry the scale the
//! projection takes away (the role of SimbaV2's scaler vectors). What is projected, and what
//! this does not take from SimbaV2 (its feature normalisation and interpolated residuals), is
//! in [`crate::residual`].
//!
//! Determinism: each column's squares are summed in input order, part after part, with plain
//! `+` and `*` (never fused), the norm is the correctly rounded square root and every weight
//! is divided by it, so the bits are those of every build and CPU.

use crate::linear::sqrt;

/// Scales column `o` of the stacked input-major matrices `parts` (input rows of the first
/// part, then of the next, ...) to unit L2 norm, for every `o`. A column that is all zeros
/// stays zero (it has no direction).
pub fn normalize_columns<const O: usize>(parts: &mut [&mut [[f32; O]]]) {
    let mut sq = [0f32; O];
    for part in parts.iter() {
        for row in part.iter() {
            for (s, &x) in sq.iter_mut().zip(row) {
                *s += x * x;
            }
        }
    }
    let mut norm = [0f32; O];
    for (n, &s) in norm.iter_mut().zip(&sq) {
        *n = sqrt(s);
    }
    for part in parts.iter_mut() {
        for row in part.iter_mut() {
            for (x, &n) in row.iter_mut().zip(&norm) {
                if n > 0.0 {
                    *x /= n;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_column_of_the_stacked_parts_ends_at_unit_norm_and_keeps_its_direction() {
        let mut a = [[3.0f32, 0.0, 1.0], [0.0, 0.0, 2.0]];
        let mut b = [[4.0f32, 0.0, 2.0]];
        normalize_columns(&mut [&mut a[..], &mut b[..]]);
        // Column 0 is (3, 0, 4): norm 5. Column 1 is zero and stays so. Column 2 is (1, 2, 2).
        assert_eq!([a[0][0], a[1][0], b[0][0]], [0.6, 0.0, 0.8]);
        assert_eq!([a[0][1], a[1][1], b[0][1]], [0.0; 3]);
        assert_eq!(
            [a[0][2], a[1][2], b[0][2]],
            [1.0 / 3.0, 2.0 / 3.0, 2.0 / 3.0]
        );
    }
}
