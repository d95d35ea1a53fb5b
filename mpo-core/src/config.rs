//! The learner's hyperparameters: one flat struct, validated as a whole.
//!
//! Defaults are the report's (Table 1: eps 0.1, eps_mean 0.1, eps_cov 1e-4, gamma 0.99, Adam
//! 3e-4, five M-step iterations, actor gradient norm clipped at 0.1). Alternatives from the
//! reference implementations (`docs/algorithm.md`, "Settings of other implementations"), all
//! expressible here:
//! - Acme: `per_dim_kl = true` with eps_mean 2.5e-3 and eps_cov 1e-6 per dimension, dual lr
//!   1e-2, actor lr 1e-4, gradient clip 40, 5-step returns, target period 100;
//! - tonic: eps_mean 1e-3, eps_cov 1e-6, lr 3e-4, 5-step returns;
//! - the paper: Adam 5e-4.

/// Clamp of the M-step multipliers' `ln alpha` (Acme clamps the duals below at `exp(-18)`):
/// `-LOG_ALPHA_MAX` is the floor, and the default of the ceiling (`MpoConfig::log_alpha_max`).
/// It lives here, not in `mstep`, because the configuration's default and validation need it
/// and `mstep` reads the configuration.
pub const LOG_ALPHA_MAX: f32 = 18.0;

/// MPO hyperparameters.
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Zeroable)]
pub struct MpoConfig {
    /// E-step bound on KL(q || pi_old) per state (eps).
    pub eps_eta: f32,
    /// M-step bound on the mean part of KL(pi_old || pi) (eps_mu).
    pub eps_mean: f32,
    /// M-step bound on the covariance part (eps_Sigma).
    pub eps_cov: f32,
    /// One constraint (and multiplier) per action dimension, each with bound
    /// `eps / ACT`, instead of one on the sum (Acme's per-dimension KL).
    pub per_dim_kl: bool,
    /// Discount factor (used by Retrace; TD targets take the batch's bootstrap multipliers).
    pub gamma: f32,
    /// Actor Adam step size.
    pub actor_lr: f32,
    /// Critic Adam step size.
    pub critic_lr: f32,
    /// Adam step size of the M-step multipliers (on `ln alpha`).
    pub dual_lr: f32,
    /// Policy gradient steps per update (the report's inner iterations).
    pub mstep_iters: u32,
    /// Actor gradient global-norm clip.
    pub actor_clip: f32,
    /// Critic gradient global-norm clip.
    pub critic_clip: f32,
    /// Updates between copies of the online networks into the target networks.
    pub target_period: u32,
    /// Initial policy standard deviation.
    pub init_std: f32,
    /// Floor added to the Cholesky diagonal.
    pub std_floor: f32,
    /// Initial temperature (the solver then warm-starts from the last one).
    pub eta_init: f32,
    /// Initial multiplier of the mean constraint (the report gives none; Acme's values: start
    /// strict, and the log parameterisation relaxes it by orders of magnitude within about a
    /// hundred updates where the bound allows).
    pub alpha_mean_init: f32,
    /// Initial multiplier of the covariance constraint (Acme: 1000; the bound is tight).
    pub alpha_cov_init: f32,
    /// E-step tolerance: stop when `|KL - eps| <= tol * eps`.
    pub estep_tol: f64,
    /// E-step iteration limit (each costs `B M` exponentials).
    pub estep_max_iter: u32,
    /// Transitions per replayed sequence: 1 = the batch holds single transitions (TD(0), or
    /// n-step transitions folded by the caller: expected SARSA on the target policy); `L > 1`
    /// = Retrace (paper eq. 11) over `L` consecutive transitions. At most the learner's `L`.
    pub sequence_len: u32,
    /// Acme's action penalization (MO-MPO): a second E-step over the same samples for the
    /// objective `-|a - clip(a, -1, 1)|^2` with its own temperature and KL bound
    /// `eps_penalty`, whose weights join the M-step's weighted likelihood. Keeps the policy
    /// inside the actuators' range without touching the reward.
    pub action_penalization: bool,
    /// KL bound of the penalty objective's E-step (Acme: 1e-3).
    pub eps_penalty: f32,
    /// Acme's shared samples: the E- and M-steps run on the next states and reuse the `N`
    /// target-policy samples and target-critic values of the TD target (`B N` target-critic
    /// evaluations per update instead of `B (M + N)`). Needs `M = N` and `sequence_len = 1`.
    pub shared_samples: bool,
    /// Polyak averaging of the targets, `target = (1 - tau) target + tau online`, after every
    /// update; 0 = copy every `target_period` updates instead.
    pub target_tau: f32,
    /// Acme's `LayerNormMLP` critic torso: the first layer's pre-activations go through a
    /// layer norm and `tanh` instead of a ReLU (`crate::layer_norm`).
    pub critic_layer_norm: bool,
    /// Observation normalisation (tonic's, `crate::obs_norm`): every this many environment
    /// steps from the end of the warm-up, the policy's input normalisation is refit to the
    /// mean and standard deviation of the observations in the replay, and every batch is
    /// normalised with it before an update; 0 = off (the identity).
    pub obs_norm_interval: u32,
    /// tonic's squashed mean: the policy's mean is `tanh` of its head, so it stays inside the
    /// actuators' range `[-1, 1]` (`crate::squash`); off = the unbounded linear head.
    pub tanh_mean: bool,
    /// Acme's `ClipToSpec` before the critic: every action the critic is given (replayed
    /// actions in its loss and in Retrace's targets, target-policy samples in the targets and
    /// the E-step) is clipped to
    /// the actuators' range `[-1, 1]` first. The plant clips, so `Q(s, a) = Q(s, clip(a))`
    /// exactly; without it the critic extrapolates beyond the box, where it has no data, and
    /// the E-step weighs samples there by that extrapolation. Everything else reads the
    /// unclipped actions (the M-step's likelihood, the penalty objective, Retrace's ratios).
    pub clip_critic_actions: bool,
    /// The smallest atom of a categorical critic's support (`crate::value_head`; read only by
    /// critics with more than one output).
    pub value_min: f32,
    /// The largest atom of a categorical critic's support.
    pub value_max: f32,
    /// A categorical critic's targets: HL-Gauss with this standard deviation in atom spacings
    /// (Farebrother et al. 2024 recommend 0.75), or two-hot when 0.
    pub value_sigma: f32,
    /// Periodic resets (D'Oro et al. 2023): every this many updates, the networks are drawn
    /// afresh from the learner's stream and their optimisers and the multipliers restart,
    /// keeping the replay, the observation normalisation and the counters; 0 = never.
    pub reset_interval: u32,
    /// SimbaV2's alternative to resets ([`crate::hypersphere`]): after every optimiser step the
    /// hidden layers' incoming weight vectors are projected back onto the unit sphere, so the
    /// effective learning rate stays constant. Residual networks only (the learner refuses it
    /// for networks without the projection).
    pub weight_norm: bool,
    /// A categorical critic's atoms whose logit lies more than this below the largest get
    /// probability exactly 0 (`crate::value_head::softmax`): their probability is below
    /// `e^-floor` of the largest, and left in, it and the gradients made from it fall into
    /// f32's subnormal range, which x86 cores compute in microcode. 0 = off (every atom
    /// kept, the head's arithmetic before the floor existed).
    pub logit_floor: f32,
    /// The ceiling of `ln alpha` for both M-step multipliers (their floor is
    /// `-LOG_ALPHA_MAX`). The default, `LOG_ALPHA_MAX` (18), lets a multiplier reach
    /// `e^18`, about 6.6e7; the multipliers move by about `dual_lr` in `ln alpha` per M-step
    /// iteration, so they can cross that whole range within a thousand updates, and a
    /// multiplier that large leaves the actor's clipped gradient almost all KL term. A lower
    /// ceiling (e.g. 6.908, just above `ln 1000`, the initial covariance multiplier) bounds
    /// that; a run whose multipliers stay below it is bit-identical to one without it (an
    /// initial multiplier above it starts at it).
    pub log_alpha_max: f32,
}

impl MpoConfig {
    /// The report's settings.
    pub const REPORT: Self = Self {
        eps_eta: 0.1,
        eps_mean: 0.1,
        eps_cov: 1e-4,
        per_dim_kl: false,
        gamma: 0.99,
        actor_lr: 3e-4,
        critic_lr: 3e-4,
        dual_lr: 1e-2,
        mstep_iters: 5,
        actor_clip: 0.1,
        critic_clip: 40.0,
        target_period: 100,
        init_std: 0.5,
        std_floor: 1e-4,
        eta_init: 1.0,
        alpha_mean_init: 10.0,
        alpha_cov_init: 1000.0,
        estep_tol: 1e-3,
        estep_max_iter: 50,
        sequence_len: 1,
        action_penalization: false,
        eps_penalty: 1e-3,
        shared_samples: false,
        target_tau: 0.0,
        critic_layer_norm: false,
        obs_norm_interval: 0,
        tanh_mean: false,
        clip_critic_actions: false,
        value_min: -10.0,
        value_max: 110.0,
        value_sigma: 0.75,
        reset_interval: 0,
        weight_norm: false,
        logit_floor: 40.0,
        log_alpha_max: LOG_ALPHA_MAX,
    };

    /// Checks every field; the first problem found is returned.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let pos = |name: &'static str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(ConfigError {
                    field: name,
                    requirement: "a finite number > 0",
                })
            }
        };
        pos("eps_eta", self.eps_eta as f64)?;
        pos("eps_mean", self.eps_mean as f64)?;
        pos("eps_cov", self.eps_cov as f64)?;
        pos("actor_lr", self.actor_lr as f64)?;
        pos("critic_lr", self.critic_lr as f64)?;
        pos("dual_lr", self.dual_lr as f64)?;
        pos("actor_clip", self.actor_clip as f64)?;
        pos("critic_clip", self.critic_clip as f64)?;
        pos("init_std", self.init_std as f64)?;
        pos("std_floor", self.std_floor as f64)?;
        pos("eta_init", self.eta_init as f64)?;
        pos("alpha_mean_init", self.alpha_mean_init as f64)?;
        pos("alpha_cov_init", self.alpha_cov_init as f64)?;
        pos("estep_tol", self.estep_tol)?;
        pos("eps_penalty", self.eps_penalty as f64)?;
        if !(self.target_tau >= 0.0 && self.target_tau <= 1.0) {
            return Err(ConfigError {
                field: "target_tau",
                requirement: "in [0, 1]",
            });
        }
        if self.sequence_len == 0 {
            return Err(ConfigError {
                field: "sequence_len",
                requirement: "at least 1",
            });
        }
        if self.shared_samples && self.sequence_len != 1 {
            return Err(ConfigError {
                field: "shared_samples",
                requirement: "false with Retrace (sequence_len > 1)",
            });
        }
        if !(self.gamma >= 0.0 && self.gamma <= 1.0) {
            return Err(ConfigError {
                field: "gamma",
                requirement: "in [0, 1]",
            });
        }
        if self.mstep_iters == 0 {
            return Err(ConfigError {
                field: "mstep_iters",
                requirement: "at least 1",
            });
        }
        if self.target_period == 0 {
            return Err(ConfigError {
                field: "target_period",
                requirement: "at least 1",
            });
        }
        if self.estep_max_iter == 0 {
            return Err(ConfigError {
                field: "estep_max_iter",
                requirement: "at least 1",
            });
        }
        if !(self.value_min.is_finite()
            && self.value_max.is_finite()
            && self.value_max > self.value_min)
        {
            return Err(ConfigError {
                field: "value_max",
                requirement: "finite and above a finite value_min",
            });
        }
        if !(self.value_sigma.is_finite() && self.value_sigma >= 0.0) {
            return Err(ConfigError {
                field: "value_sigma",
                requirement: "a finite number >= 0 (0 = two-hot targets)",
            });
        }
        if !(self.logit_floor.is_finite() && self.logit_floor >= 0.0) {
            return Err(ConfigError {
                field: "logit_floor",
                requirement: "a finite number >= 0 (0 = off)",
            });
        }
        if !(self.log_alpha_max.is_finite()
            && self.log_alpha_max > -LOG_ALPHA_MAX
            && self.log_alpha_max <= LOG_ALPHA_MAX)
        {
            return Err(ConfigError {
                field: "log_alpha_max",
                requirement: "in (-18, 18] (the multipliers' floor is e^-18)",
            });
        }
        if self.std_floor >= self.init_std {
            return Err(ConfigError {
                field: "std_floor",
                requirement: "smaller than init_std",
            });
        }
        Ok(())
    }
}

/// Words of [`MpoConfig::to_words`].
pub const CONFIG_WORDS: usize = 36;

impl MpoConfig {
    /// The configuration as 32-bit words in a fixed order (floats as their bits, flags as
    /// 0/1, the f64 E-step tolerance as its low word then, last, its high word): how a host
    /// sends it to a device trainer, exactly.
    pub fn to_words(&self) -> [u32; CONFIG_WORDS] {
        let f = |x: f32| x.to_bits();
        [
            f(self.eps_eta),
            f(self.eps_mean),
            f(self.eps_cov),
            self.per_dim_kl as u32,
            f(self.gamma),
            f(self.actor_lr),
            f(self.critic_lr),
            f(self.dual_lr),
            self.mstep_iters,
            f(self.actor_clip),
            f(self.critic_clip),
            self.target_period,
            f(self.init_std),
            f(self.std_floor),
            f(self.eta_init),
            f(self.alpha_mean_init),
            f(self.alpha_cov_init),
            self.estep_tol.to_bits() as u32,
            self.estep_max_iter,
            self.sequence_len,
            self.action_penalization as u32,
            f(self.eps_penalty),
            self.shared_samples as u32,
            f(self.target_tau),
            (self.estep_tol.to_bits() >> 32) as u32,
            self.critic_layer_norm as u32,
            self.obs_norm_interval,
            self.tanh_mean as u32,
            self.clip_critic_actions as u32,
            f(self.value_min),
            f(self.value_max),
            f(self.value_sigma),
            self.reset_interval,
            self.weight_norm as u32,
            f(self.logit_floor),
            f(self.log_alpha_max),
        ]
    }

    /// The inverse of [`MpoConfig::to_words`], bit for bit; the result is validated.
    pub fn from_words(w: &[u32; CONFIG_WORDS]) -> Result<Self, ConfigError> {
        let f = f32::from_bits;
        let flag = |x: u32, field| match x {
            0 => Ok(false),
            1 => Ok(true),
            _ => Err(ConfigError {
                field,
                requirement: "0 or 1",
            }),
        };
        let cfg = Self {
            eps_eta: f(w[0]),
            eps_mean: f(w[1]),
            eps_cov: f(w[2]),
            per_dim_kl: flag(w[3], "per_dim_kl")?,
            gamma: f(w[4]),
            actor_lr: f(w[5]),
            critic_lr: f(w[6]),
            dual_lr: f(w[7]),
            mstep_iters: w[8],
            actor_clip: f(w[9]),
            critic_clip: f(w[10]),
            target_period: w[11],
            init_std: f(w[12]),
            std_floor: f(w[13]),
            eta_init: f(w[14]),
            alpha_mean_init: f(w[15]),
            alpha_cov_init: f(w[16]),
            estep_tol: f64::from_bits(w[17] as u64 | (w[24] as u64) << 32),
            estep_max_iter: w[18],
            sequence_len: w[19],
            action_penalization: flag(w[20], "action_penalization")?,
            eps_penalty: f(w[21]),
            shared_samples: flag(w[22], "shared_samples")?,
            target_tau: f(w[23]),
            critic_layer_norm: flag(w[25], "critic_layer_norm")?,
            obs_norm_interval: w[26],
            tanh_mean: flag(w[27], "tanh_mean")?,
            clip_critic_actions: flag(w[28], "clip_critic_actions")?,
            value_min: f(w[29]),
            value_max: f(w[30]),
            value_sigma: f(w[31]),
            reset_interval: w[32],
            weight_norm: flag(w[33], "weight_norm")?,
            logit_floor: f(w[34]),
            log_alpha_max: f(w[35]),
        };
        cfg.validate()?;
        Ok(cfg)
    }
}

impl Default for MpoConfig {
    fn default() -> Self {
        Self::REPORT
    }
}

/// A configuration field out of range.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ConfigError {
    /// The field's name.
    pub field: &'static str,
    /// What it must be.
    pub requirement: &'static str,
}

impl core::fmt::Display for ConfigError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(
            f,
            "configuration field `{}` must be {}",
            self.field, self.requirement
        )
    }
}

impl core::error::Error for ConfigError {}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn words_round_trip_every_field_and_invalid_words_are_refused() {
        let cfg = MpoConfig {
            per_dim_kl: true,
            sequence_len: 3,
            action_penalization: true,
            shared_samples: false,
            target_tau: 0.005,
            estep_tol: 1e-3,
            critic_layer_norm: true,
            obs_norm_interval: 1000,
            tanh_mean: true,
            clip_critic_actions: true,
            value_min: -3.0,
            value_max: 7.5,
            value_sigma: 0.0,
            reset_interval: 1000,
            weight_norm: true,
            logit_floor: 25.5,
            log_alpha_max: 6.9,
            ..MpoConfig::REPORT
        };
        let w = cfg.to_words();
        assert_eq!(MpoConfig::from_words(&w), Ok(cfg));
        let mut bad = w;
        bad[3] = 2;
        assert!(MpoConfig::from_words(&bad).is_err());
        let mut bad = w;
        bad[27] = 2;
        assert!(MpoConfig::from_words(&bad).is_err());
        let mut bad = w;
        bad[28] = 2;
        assert!(MpoConfig::from_words(&bad).is_err());
        let mut bad = w;
        bad[33] = 2;
        assert!(MpoConfig::from_words(&bad).is_err());
        let mut bad = w;
        bad[30] = (-4.0f32).to_bits(); // value_max below value_min
        assert!(MpoConfig::from_words(&bad).is_err());
        let mut bad = w;
        bad[4] = 2.0f32.to_bits(); // gamma out of range
        assert!(MpoConfig::from_words(&bad).is_err());
        // The multipliers' ceiling: above the old clamp, at or below its floor, or NaN.
        for v in [18.5f32, -18.0, f32::NAN] {
            let mut bad = w;
            bad[35] = v.to_bits();
            let e = MpoConfig::from_words(&bad).unwrap_err();
            assert_eq!(e.field, "log_alpha_max");
        }
    }
}
