//! Why an update was rejected.

/// Where a non-finite value was found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum NonFinite {
    /// The batch (observations, actions, rewards or bootstrap multipliers).
    Batch,
    /// The critic's TD targets or loss.
    CriticLoss,
    /// The critic's gradients.
    CriticGradients,
    /// The E-step values or temperature.
    EStep,
    /// The M-step loss, KLs or actor gradients.
    ActorGradients,
    /// Parameters after the step.
    Parameters,
}

/// Why an update was rejected (its changes are undone).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum UpdateError {
    /// A NaN or infinity appeared.
    NonFinite(NonFinite),
}

impl core::fmt::Display for UpdateError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::NonFinite(w) => write!(f, "non-finite value in {w:?}; the update was undone"),
        }
    }
}

impl core::error::Error for UpdateError {}
