//! Parameter sets seen as an ordered list of flat `f32` tensors.
//!
//! Networks, their gradients and their Adam moments share one type, so every optimiser or
//! bookkeeping routine (clipping, target copies, finiteness checks, checkpoints) is written
//! once over [`Params`] and walks the tensors in a fixed order: that fixed order is what keeps
//! the reductions (norms) bit-deterministic.

/// A set of parameters stored as `TENSORS` flat `f32` slices, visited in a fixed order.
pub trait Params {
    /// Number of tensors.
    const TENSORS: usize;
    /// Tensor `k` (`k < TENSORS`) as a flat slice.
    fn tensor(&self, k: usize) -> &[f32];
    /// Tensor `k` (`k < TENSORS`) as a flat mutable slice.
    fn tensor_mut(&mut self, k: usize) -> &mut [f32];
    /// Calls `f` with every tensor as a mutable slice, in tensor order, all borrowed at once
    /// (so a caller can hand disjoint tensors to different threads).
    fn visit_mut<'a>(&'a mut self, f: &mut dyn FnMut(&'a mut [f32]));

    /// Total number of scalars.
    fn len(&self) -> usize {
        (0..Self::TENSORS).map(|k| self.tensor(k).len()).sum()
    }
    /// True when the set holds no scalars.
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Sets every scalar to zero.
    fn fill_zero(&mut self) {
        for k in 0..Self::TENSORS {
            self.tensor_mut(k).fill(0.0);
        }
    }
    /// Copies every scalar from `src` (for example online -> target network).
    fn copy_from(&mut self, src: &Self) {
        for k in 0..Self::TENSORS {
            self.tensor_mut(k).copy_from_slice(src.tensor(k));
        }
    }
    /// Polyak averaging: `self = (1 - tau) * self + tau * src`.
    fn polyak_from(&mut self, src: &Self, tau: f32) {
        for k in 0..Self::TENSORS {
            for (d, s) in self.tensor_mut(k).iter_mut().zip(src.tensor(k)) {
                *d = (1.0 - tau) * *d + tau * *s;
            }
        }
    }
    /// Euclidean norm of all scalars, accumulated in f64 in tensor order.
    fn global_norm(&self) -> f32 {
        let mut s = 0f64;
        for k in 0..Self::TENSORS {
            for &x in self.tensor(k) {
                s += (x as f64) * (x as f64);
            }
        }
        libm::sqrt(s) as f32
    }
    /// Multiplies every scalar by `c`.
    fn scale(&mut self, c: f32) {
        for k in 0..Self::TENSORS {
            for x in self.tensor_mut(k) {
                *x *= c;
            }
        }
    }
    /// True when no scalar is NaN or infinite.
    fn all_finite(&self) -> bool {
        (0..Self::TENSORS).all(|k| self.tensor(k).iter().all(|x| x.is_finite()))
    }
    /// Calls `f` on every scalar in the fixed order (checksums, serialisation).
    fn for_each(&self, mut f: impl FnMut(f32)) {
        for k in 0..Self::TENSORS {
            self.tensor(k).iter().for_each(|&x| f(x));
        }
    }
    /// Bitwise equality of every scalar (NaN-aware, unlike `==`).
    fn bits_eq(&self, other: &Self) -> bool {
        (0..Self::TENSORS).all(|k| {
            let (a, b) = (self.tensor(k), other.tensor(k));
            a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
        })
    }
}

/// An array of parameter sets is one, its elements' tensors in element order (the residual
/// networks' blocks).
impl<T: Params, const D: usize> Params for [T; D] {
    const TENSORS: usize = D * T::TENSORS;
    fn tensor(&self, k: usize) -> &[f32] {
        self[k / T::TENSORS].tensor(k % T::TENSORS)
    }
    fn tensor_mut(&mut self, k: usize) -> &mut [f32] {
        self[k / T::TENSORS].tensor_mut(k % T::TENSORS)
    }
    fn visit_mut<'a>(&'a mut self, f: &mut dyn FnMut(&'a mut [f32])) {
        for x in self.iter_mut() {
            x.visit_mut(f);
        }
    }
}

/// Scales `grads` so their global norm is at most `max_norm`; returns the norm before clipping.
///
/// A non-finite norm is returned as is and the gradients are left untouched, so the caller's
/// finiteness check sees the problem instead of a silently zeroed step.
pub fn clip_global_norm<P: Params>(grads: &mut P, max_norm: f32) -> f32 {
    let norm = grads.global_norm();
    if norm.is_finite() && norm > max_norm && norm > 0.0 {
        grads.scale(max_norm / norm);
    }
    norm
}

/// FNV-1a over the bits of every scalar: a cheap, stable fingerprint for determinism checks.
pub fn fingerprint<P: Params>(p: &P) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    p.for_each(|x| {
        for b in x.to_bits().to_le_bytes() {
            h ^= b as u64;
            h = h.wrapping_mul(0x0000_0100_0000_01b3);
        }
    });
    h
}

/// Implements [`Params`] for a struct whose fields are themselves [`Params`], in field order.
///
/// `impl_params_for_fields!(Name<const A: usize, ...> { field: Type, ... })`
#[macro_export]
macro_rules! impl_params_for_fields {
    ($ty:ident < $(const $g:ident : usize),* > { $($field:ident : $fty:ty),+ $(,)? }) => {
        impl<$(const $g: usize),*> $crate::params::Params for $ty<$($g),*> {
            const TENSORS: usize = 0 $(+ <$fty as $crate::params::Params>::TENSORS)+;
            fn tensor(&self, k: usize) -> &[f32] {
                let mut k = k;
                $(
                    if k < <$fty as $crate::params::Params>::TENSORS {
                        return $crate::params::Params::tensor(&self.$field, k);
                    }
                    k -= <$fty as $crate::params::Params>::TENSORS;
                )+
                panic!("tensor index past the end by {}", k)
            }
            fn tensor_mut(&mut self, k: usize) -> &mut [f32] {
                let mut k = k;
                $(
                    if k < <$fty as $crate::params::Params>::TENSORS {
                        return $crate::params::Params::tensor_mut(&mut self.$field, k);
                    }
                    k -= <$fty as $crate::params::Params>::TENSORS;
                )+
                panic!("tensor index past the end by {}", k)
            }
            fn visit_mut<'a>(&'a mut self, f: &mut dyn FnMut(&'a mut [f32])) {
                $( $crate::params::Params::visit_mut(&mut self.$field, f); )+
            }
        }
    };
}
