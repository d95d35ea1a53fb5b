//! `mpo-core`: Maximum a Posteriori Policy Optimisation (Abdolmaleki et al., 2018) for
//! robots: `#![no_std]`, no allocator, fixed sizes, bit-deterministic.
//!
//! The paper's concepts are the modules: [`gaussian`] (the policy's full-covariance
//! distribution), [`actor`] and [`critic`] (the two-layer networks, built from [`linear`]
//! layers and, optionally for the critic, a [`layer_norm`]), [`residual`] (the residual,
//! layer-normalised networks; the learner takes either form of each through the traits of
//! [`network`]; a critic's output is a value or a categorical distribution, [`value_head`];
//! the policy's input goes through [`obs_norm`], its mean through [`squash`]), [`adam`], [`replay`] (which fills a [`batch`]) and [`rng`];
//! the algorithm's steps are [`evaluation`] (policy evaluation targets), [`estep`] and
//! [`mstep`], each with its per-row work on a batch chunk beside its maths, composed by
//! [`learner`], which spreads the work over threads through [`parallel`] with the same bits
//! for any thread count. `docs/algorithm.md` derives what these modules compute. Every routine
//! writes into buffers owned by the caller, so nothing is allocated after construction; big
//! state is created zeroed in place (on the host with `bytemuck::zeroed_box`, on firmware in a
//! static) and initialised with `init`.
//!
//! The `train` feature (on by default) holds everything only training needs: backward passes,
//! tapes, the critic, Adam, the replay, the E- and M-steps and the learner. Firmware builds with
//! `default-features = false` and keeps the policy network, its forward pass and the Gaussian.
//!
//! Shape letters used in the docs: `B` batch, `OBS` observation size, `ACT` action size,
//! `TRI = ACT (ACT + 1) / 2` Cholesky entries, `H1`/`H2` hidden widths.
#![no_std]
#![deny(missing_docs)]
// On a Cortex-M with an FPU, `linear::mul_add` is `core`'s (unstable) fused multiply-add, the
// `vfma.f32` instruction; that build is made with `-Zbuild-std` (scripts/cortex-m-cargo).
#![cfg_attr(
    all(
        target_arch = "arm",
        target_feature = "mclass",
        target_feature = "fpregs"
    ),
    feature(core_float_math)
)]
// The exceptions: `linear::mul_add`, which calls the FMA instruction when the build enables it
// (a register-only intrinsic), and `linear::wide`, the 512-bit kernels chosen at run time.
#![deny(unsafe_code)]
#![allow(clippy::needless_range_loop)]

pub mod actor;
#[cfg(feature = "train")]
pub mod adam;
#[cfg(feature = "train")]
pub mod agent;
#[cfg(feature = "train")]
pub mod batch;
#[cfg(feature = "train")]
pub mod config;
#[cfg(feature = "train")]
pub mod critic;
#[cfg(feature = "train")]
pub mod estep;
#[cfg(feature = "train")]
pub mod evaluation;
pub mod explore;
pub mod export;
pub mod gaussian;
#[cfg(feature = "train")]
pub mod hypersphere;
pub mod lanes;
pub mod layer_norm;
#[cfg(feature = "train")]
pub mod learner;
pub mod linear;
pub mod mathf;
#[cfg(feature = "train")]
pub mod mstep;
#[cfg(feature = "train")]
mod nets;
pub mod network;
pub mod obs_norm;
#[cfg(feature = "train")]
pub mod parallel;
pub mod params;
#[cfg(feature = "train")]
pub mod replay;
pub mod residual;
pub mod rng;
#[cfg(feature = "train")]
pub mod selfcheck;
pub mod squash;
#[cfg(feature = "train")]
pub mod value_head;

pub use bytemuck;
