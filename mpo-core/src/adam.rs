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

impl AdamState {
    /// Counts one step (call once per step, before [`AdamState::apply`]).
    pub fn advance(&mut self, cfg: &AdamConfig) {
        self.t += 1;
        self.beta1_pow *= cfg.beta1;
        self.beta2_pow *= cfg.beta2;
    }

    /// Applies the current step to one flat tensor and its moments.
    pub fn apply(&self, cfg: &AdamConfig, p: &mut [f32], g: &[f32], m: &mut [f32], v: &mut [f32]) {
        let c1 = 1.0 / (1.0 - self.beta1_pow);
        let c2 = 1.0 / (1.0 - self.beta2_pow);
        for i in 0..p.len() {
            m[i] = cfg.beta1 * m[i] + (1.0 - cfg.beta1) * g[i];
            v[i] = cfg.beta2 * v[i] + (1.0 - cfg.beta2) * (g[i] * g[i]);
            let m_hat = m[i] * c1;
            let v_hat = v[i] * c2;
            p[i] -= cfg.lr * m_hat / (libm::sqrtf(v_hat) + cfg.eps);
        }
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
