//! Adam with bias correction (Kingma and Ba, 2015), over any [`Params`].

use crate::params::Params;

/// Adam's hyperparameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AdamConfig {
    /// Step size.
    pub lr: f32,
    /// First-moment decay.
    pub beta1: f32,
    /// Second-moment decay.
    pub beta2: f32,
    /// Denominator floor.
    pub eps: f32,
}

impl AdamConfig {
    /// The usual defaults with the given step size.
    pub const fn with_lr(lr: f32) -> Self {
        Self {
            lr,
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-8,
        }
    }
}

/// Step count and the running powers `beta^t` used for bias correction (kept as products,
/// not recomputed with `powf`, so a checkpoint restores them exactly). The all-zero value is
/// not a valid state: start from `AdamState::default()`.
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Zeroable)]
pub struct AdamState {
    /// Steps taken.
    pub t: u64,
    /// `beta1^t`.
    pub beta1_pow: f32,
    /// `beta2^t`.
    pub beta2_pow: f32,
}

impl Default for AdamState {
    fn default() -> Self {
        Self {
            t: 0,
            beta1_pow: 1.0,
            beta2_pow: 1.0,
        }
    }
}

/// One Adam step: `p -= lr * m_hat / (sqrt(v_hat) + eps)` with `m` and `v` the moment
/// estimates (same shape as `params`) and hats their bias-corrected values.
pub fn adam_step<P: Params>(
    cfg: &AdamConfig,
    state: &mut AdamState,
    params: &mut P,
    grads: &P,
    m: &mut P,
    v: &mut P,
) {
    state.advance(cfg);
    for k in 0..P::TENSORS {
        state.apply(
            cfg,
            params.tensor_mut(k),
            grads.tensor(k),
            m.tensor_mut(k),
            v.tensor_mut(k),
        );
    }
}

/// A block of at most this many scalars is one work item of [`adam_step_with`].
#[cfg(feature = "train")]
const BLOCK: usize = 16_384;

/// One work item of [`adam_step_with`]: matching pieces of parameters, gradients and moments.
#[cfg(feature = "train")]
type Piece<'a> = (&'a mut [f32], &'a [f32], &'a mut [f32], &'a mut [f32]);

/// [`adam_step`] with the gradients multiplied by `scale` (gradient clipping folded in), the
/// tensors cut into blocks of at most 16,384 scalars and the blocks spread by `par`
/// (elementwise, so the bits are those of the serial step).
#[cfg(feature = "train")]
#[allow(clippy::too_many_arguments)]
pub fn adam_step_with<P: Params, Q: crate::parallel::Parallel>(
    par: &Q,
    cfg: &AdamConfig,
    state: &mut AdamState,
    params: &mut P,
    grads: &P,
    scale: f32,
    m: &mut P,
    v: &mut P,
) {
    state.advance(cfg);
    let mut pieces: heapless::Vec<Piece<'_>, 64> = heapless::Vec::new();
    let mut ps: heapless::Vec<&mut [f32], 64> = heapless::Vec::new();
    let mut ms: heapless::Vec<&mut [f32], 64> = heapless::Vec::new();
    let mut vs: heapless::Vec<&mut [f32], 64> = heapless::Vec::new();
    for (list, x) in [(&mut ps, params), (&mut ms, m), (&mut vs, v)] {
        x.visit_mut(&mut |t| {
            for c in t.chunks_mut(BLOCK) {
                assert!(list.push(c).is_ok(), "more than 64 Adam blocks");
            }
        });
    }
    for (k, ((p, m), v)) in ps.into_iter().zip(ms).zip(vs).enumerate() {
        // The gradient's tensors cut the same way.
        let (t, off) = block_of(grads, k);
        let g = &grads.tensor(t)[off..off + p.len()];
        assert!(
            pieces.push((p, g, m, v)).is_ok(),
            "more than 64 Adam blocks"
        );
    }
    let st = *state;
    par.for_each(&mut pieces, &|_, (p, g, m, v)| {
        st.apply_scaled(cfg, p, g, scale, m, v)
    });
}

/// Tensor and offset of block `k` when every tensor of `x` is cut into [`BLOCK`]s.
#[cfg(feature = "train")]
fn block_of<P: Params>(x: &P, mut k: usize) -> (usize, usize) {
    for t in 0..P::TENSORS {
        let blocks = x.tensor(t).len().div_ceil(BLOCK);
        if k < blocks {
            return (t, k * BLOCK);
        }
        k -= blocks;
    }
    panic!("block index past the end")
}

impl AdamState {
    /// Counts one step (call once per step, before [`AdamState::apply`]).
    pub fn advance(&mut self, cfg: &AdamConfig) {
        self.t += 1;
        self.beta1_pow *= cfg.beta1;
        self.beta2_pow *= cfg.beta2;
    }

    /// Applies the current step to one flat tensor and its moments.
    pub fn apply(&self, cfg: &AdamConfig, p: &mut [f32], g: &[f32], m: &mut [f32], v: &mut [f32]) {
        self.apply_scaled(cfg, p, g, 1.0, m, v);
    }

    /// [`AdamState::apply`] with the gradient `g * scale`.
    pub fn apply_scaled(
        &self,
        cfg: &AdamConfig,
        p: &mut [f32],
        g: &[f32],
        scale: f32,
        m: &mut [f32],
        v: &mut [f32],
    ) {
        let c1 = 1.0 / (1.0 - self.beta1_pow);
        let c2 = 1.0 / (1.0 - self.beta2_pow);
        // Every slice cut to the parameters' length first: with the bounds checked once, the
        // loop vectorises (elementwise, every lane the same operations: the same bits). With a
        // check per element it ran scalar, 6% of a suite row's update in instructions
        // (docs/core.md, "Where the time goes").
        let n = p.len();
        let (g, m, v) = (&g[..n], &mut m[..n], &mut v[..n]);
        for i in 0..n {
            let gi = g[i] * scale;
            m[i] = flush_subnormal(cfg.beta1 * m[i] + (1.0 - cfg.beta1) * gi);
            v[i] = flush_subnormal(cfg.beta2 * v[i] + (1.0 - cfg.beta2) * (gi * gi));
            let m_hat = m[i] * c1;
            let v_hat = v[i] * c2;
            p[i] -= cfg.lr * m_hat / (crate::linear::sqrt(v_hat) + cfg.eps);
        }
    }
}

/// `x` with a subnormal magnitude replaced by a zero of the same sign.
///
/// Why: the moments of a parameter whose gradient has stopped (a dead ReLU unit, a constant
/// input) decay geometrically and spend thousands of steps as subnormal numbers, and every
/// arithmetic operation on a subnormal takes a microcode assist on x86, which once made Adam
/// most of an update's time (docs/core.md, "Subnormal optimizer moments", has the
/// measurement and its command). The CPU's flush-to-zero
/// mode would change results between the host and the software-float firmware; this explicit
/// flush is the same on every target. It changes no parameter in practice: a moment below
/// 1.2e-38 moves a parameter by less than 1e-30 relative to `lr`, far below any non-zero
/// parameter's last bit.
#[inline(always)]
pub fn flush_subnormal(x: f32) -> f32 {
    if x.abs() < f32::MIN_POSITIVE {
        0.0f32.copysign(x)
    } else {
        x
    }
}

/// Adam on a single scalar.
pub fn adam_step_scalar(
    cfg: &AdamConfig,
    state: &mut AdamState,
    p: &mut f32,
    g: f32,
    m: &mut f32,
    v: &mut f32,
) {
    state.advance(cfg);
    state.apply(
        cfg,
        core::slice::from_mut(p),
        &[g],
        core::slice::from_mut(m),
        core::slice::from_mut(v),
    );
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::linear::Linear;
    use bytemuck::Zeroable;

    /// A parameter whose gradient stops: its moments decay to zero without ever being stored
    /// as subnormal numbers (which cost a microcode assist per operation on x86), and the
    /// parameter's trajectory is bit for bit the one of the unflushed update written out here.
    #[test]
    fn stopped_gradients_leave_no_subnormal_moments_and_the_same_parameter() {
        let cfg = AdamConfig::with_lr(1e-3);
        let mut st = AdamState::default();
        let (mut p, mut m, mut v) = ([0.3f32, -0.2], [0f32; 2], [0f32; 2]);
        let (mut rp, mut rm, mut rv) = (p, m, v);
        let mut subnormal_unflushed = 0;
        for t in 0..20_000 {
            let g = if t < 3 {
                [1e-12f32, -1e-12]
            } else {
                [0.0, -0.0]
            };
            st.advance(&cfg);
            st.apply(&cfg, &mut p, &g, &mut m, &mut v);
            let (c1, c2) = (1.0 / (1.0 - st.beta1_pow), 1.0 / (1.0 - st.beta2_pow));
            for i in 0..2 {
                rm[i] = cfg.beta1 * rm[i] + (1.0 - cfg.beta1) * g[i];
                rv[i] = cfg.beta2 * rv[i] + (1.0 - cfg.beta2) * (g[i] * g[i]);
                rp[i] -= cfg.lr * (rm[i] * c1) / (crate::linear::sqrt(rv[i] * c2) + cfg.eps);
                subnormal_unflushed +=
                    rm[i].is_subnormal() as usize + rv[i].is_subnormal() as usize;
                assert!(
                    !m[i].is_subnormal() && !v[i].is_subnormal(),
                    "step {t}: {m:?} {v:?}"
                );
                assert_eq!(p[i].to_bits(), rp[i].to_bits(), "step {t}");
            }
        }
        assert!(
            subnormal_unflushed > 1000,
            "the case must produce subnormals unflushed"
        );
        assert_eq!(
            m,
            [0.0, -0.0],
            "the first moments decayed past the subnormal range"
        );
        assert_eq!(
            m[1].to_bits(),
            (-0.0f32).to_bits(),
            "the sign survives the flush"
        );
    }

    #[test]
    fn flush_subnormal_keeps_normals_and_signs() {
        assert_eq!(flush_subnormal(f32::MIN_POSITIVE), f32::MIN_POSITIVE);
        assert_eq!(flush_subnormal(-1.5), -1.5);
        assert_eq!(flush_subnormal(1e-40).to_bits(), 0.0f32.to_bits());
        assert_eq!(flush_subnormal(-1e-40).to_bits(), (-0.0f32).to_bits());
        assert_eq!(flush_subnormal(0.0).to_bits(), 0.0f32.to_bits());
    }

    #[test]
    fn first_step_moves_each_weight_by_lr_against_its_gradient_sign() {
        // With bias correction the first step is exactly lr * sign(g) (up to eps).
        let mut p = Linear::<3, 2>::zeroed();
        let mut g = Linear::<3, 2>::zeroed();
        let (mut m, mut v) = (Linear::<3, 2>::zeroed(), Linear::<3, 2>::zeroed());
        g.w = [[1.0, -2.0], [0.5, 3.0], [-0.1, 0.0]];
        let cfg = AdamConfig::with_lr(0.01);
        let mut st = AdamState::default();
        adam_step(&cfg, &mut st, &mut p, &g, &mut m, &mut v);
        let expect = [[-0.01, 0.01], [-0.01, -0.01], [0.01, 0.0]];
        for i in 0..3 {
            for o in 0..2 {
                assert!(
                    (p.w[i][o] - expect[i][o]).abs() < 1e-6,
                    "{i} {o}: {}",
                    p.w[i][o]
                );
            }
        }
        assert_eq!(st.t, 1);
    }

    #[test]
    fn the_denominator_floor_adds_to_the_root_of_the_second_moment() {
        // Gradients near eps: the first step is lr g / (|g| + eps), a fraction of lr that
        // only the floor decides (a floor subtracted instead would reverse the step).
        let mut p = Linear::<1, 2>::zeroed();
        let mut g = Linear::<1, 2>::zeroed();
        let (mut m, mut v) = (Linear::<1, 2>::zeroed(), Linear::<1, 2>::zeroed());
        g.w = [[1e-9, -3e-8]];
        let cfg = AdamConfig::with_lr(0.01);
        adam_step(&cfg, &mut AdamState::default(), &mut p, &g, &mut m, &mut v);
        for (got, gi) in p.w[0].iter().zip(g.w[0]) {
            let want = -0.01 * gi as f64 / (gi.abs() as f64 + 1e-8);
            assert!(
                (*got as f64 - want).abs() < 1e-4 * want.abs(),
                "{got} vs {want}"
            );
        }
    }

    #[test]
    fn blocked_scaled_step_equals_scaling_then_the_plain_step() {
        // Tensors larger than a block, so they are split.
        type P = Linear<300, 70>;
        let mut rng = crate::rng::Rng::seed_from_u64(3);
        let (mut a, mut g) = (P::zeroed(), P::zeroed());
        a.init_uniform(&mut rng);
        g.init_uniform(&mut rng);
        let mut b = a.clone();
        let (mut ma, mut va, mut mb, mut vb) = (P::zeroed(), P::zeroed(), P::zeroed(), P::zeroed());
        let (mut sa, mut sb) = (AdamState::default(), AdamState::default());
        let cfg = AdamConfig::with_lr(1e-3);
        for _ in 0..3 {
            let mut gs = g.clone();
            gs.scale(0.37);
            adam_step(&cfg, &mut sa, &mut a, &gs, &mut ma, &mut va);
            adam_step_with(
                &crate::parallel::Serial,
                &cfg,
                &mut sb,
                &mut b,
                &g,
                0.37,
                &mut mb,
                &mut vb,
            );
        }
        assert!(a.bits_eq(&b) && ma.bits_eq(&mb) && va.bits_eq(&vb));
        assert_eq!(sa, sb);
    }

    #[test]
    fn minimises_a_quadratic() {
        let (mut x, mut m, mut v) = (5.0f32, 0.0, 0.0);
        let mut st = AdamState::default();
        let cfg = AdamConfig::with_lr(0.1);
        for _ in 0..2000 {
            let g = 2.0 * (x - 1.5);
            adam_step_scalar(&cfg, &mut st, &mut x, g, &mut m, &mut v);
        }
        assert!((x - 1.5).abs() < 1e-3, "{x}");
    }
}
