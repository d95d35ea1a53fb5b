//! What one update measured: [`UpdateStats`], defined together with its names and values in
//! one list, so a statistic's name can never label another's value (the host's metrics
//! columns are [`UpdateStats::NAMES`] and [`UpdateStats::values`]).

/// Defines [`UpdateStats`] from one list of documented fields: the struct, the field names
/// in order ([`UpdateStats::NAMES`]) and their values in the same order
/// ([`UpdateStats::values`]).
macro_rules! update_stats {
    ($($(#[$doc:meta])+ $name:ident: $ty:ty,)+) => {
        /// What one update measured (for logging; returned, not stored).
        #[derive(Clone, Copy, Debug, Default, PartialEq)]
        pub struct UpdateStats {
            $($(#[$doc])+ pub $name: $ty,)+
        }

        impl UpdateStats {
            /// Number of statistics.
            pub const COUNT: usize = [$(stringify!($name)),+].len();
            /// The statistics' names in field order (a metrics file's column names).
            pub const NAMES: [&'static str; Self::COUNT] = [$(stringify!($name)),+];

            /// The statistics as numbers, in [`Self::NAMES`] order.
            pub fn values(&self) -> [f64; Self::COUNT] {
                [$(self.$name as f64),+]
            }

            /// Statistics from numbers in [`Self::NAMES`] order (the tests' way of giving
            /// every field a distinct value).
            #[cfg(test)]
            fn from_values(v: [f64; Self::COUNT]) -> Self {
                let mut v = v.into_iter();
                Self { $($name: v.next().unwrap() as $ty,)+ }
            }
        }
    };
}

update_stats! {
    /// `0.5 mean (Q - y)^2` before the critic step.
    critic_loss: f32,
    /// Mean TD target.
    target_mean: f32,
    /// Mean `Q` over the E-step samples.
    q_mean: f32,
    /// Smallest E-step `Q`.
    q_min: f32,
    /// Largest E-step `Q`.
    q_max: f32,
    /// Temperature `eta*`.
    eta: f32,
    /// Mean KL(q || pi_old) of the E-step weights (at the constraint: `eps_eta`).
    estep_kl: f32,
    /// Temperature solver iterations.
    estep_iterations: u32,
    /// Temperature of the action-penalty objective (0 without action penalization).
    eta_penalty: f32,
    /// Mean over the E-step samples of `|a - clip(a, -1, 1)|^2`.
    action_excess: f32,
    /// Mean `alpha_mu` over dimensions, after the update.
    alpha_mean: f32,
    /// Mean `alpha_Sigma` over dimensions, after the update.
    alpha_cov: f32,
    /// Mean over states of KL_mu(target || online) before the last M-step iteration.
    kl_mean: f32,
    /// Mean over states of KL_Sigma(target || online) before the last M-step iteration.
    kl_cov: f32,
    /// `kl_mean / eps_mean` (1.0 = at the constraint).
    kl_mean_rel: f32,
    /// `kl_cov / eps_cov`.
    kl_cov_rel: f32,
    /// Weighted negative log-likelihood part of the M-step loss (last iteration).
    policy_nll: f32,
    /// Actor gradient norm before clipping (last iteration).
    actor_grad_norm: f32,
    /// Critic gradient norm before clipping.
    critic_grad_norm: f32,
    /// Mean of the online policy's means over states and dimensions.
    mu_mean: f32,
    /// Mean of `|mu|`.
    mu_abs_mean: f32,
    /// Mean standard deviation over states and dimensions.
    std_mean: f32,
    /// Smallest standard deviation.
    std_min: f32,
    /// Largest standard deviation.
    std_max: f32,
}

#[cfg(test)]
mod tests {
    extern crate std;
    use std::format;
    use std::string::String;
    use std::vec::Vec;

    use super::*;

    /// Every name labels its own field's value: the derived `Debug` (written by the compiler
    /// from the struct, not from the macro's lists) shows `name: value` pairs in the order and
    /// with the values that `NAMES` and `values` give.
    #[test]
    fn names_and_values_follow_the_fields() {
        let v: [f64; UpdateStats::COUNT] = core::array::from_fn(|i| (i + 1) as f64);
        let s = UpdateStats::from_values(v);
        assert_eq!(s.values(), v);
        let debug = format!("{s:?}");
        let body = debug
            .strip_prefix("UpdateStats { ")
            .and_then(|b| b.strip_suffix(" }"))
            .unwrap();
        let pairs: Vec<(String, f64)> = body
            .split(", ")
            .map(|p| {
                let (n, x) = p.split_once(": ").unwrap();
                (n.into(), x.parse().unwrap())
            })
            .collect();
        assert_eq!(pairs.len(), UpdateStats::COUNT);
        for (i, (n, x)) in pairs.iter().enumerate() {
            assert_eq!(n, UpdateStats::NAMES[i], "column {i}");
            assert_eq!(*x, s.values()[i], "value of {n}");
        }
    }
}
