//! `mpo-core`: Maximum a Posteriori Policy Optimisation (Abdolmaleki et al., 2018) for
//! robots: `#![no_std]`, no allocator, fixed sizes, bit-deterministic.
//!
//! The paper's concepts are the modules: [`gaussian`] (the policy's full-covariance
//! distribution), [`actor`] and [`critic`] (the networks, built from [`linear`] layers),
//! [`adam`], [`replay`] and [`rng`]. Every routine writes into buffers owned by the caller,
//! so nothing is allocated after construction; big state is created zeroed in place (on the
//! host with `bytemuck::zeroed_box`, on firmware in a static) and initialised with `init`.
//!
//! Shape letters used in the docs: `B` batch, `OBS` observation size, `ACT` action size,
//! `TRI = ACT (ACT + 1) / 2` Cholesky entries, `H1`/`H2` hidden widths.
#![no_std]
#![deny(missing_docs)]
#![forbid(unsafe_code)]
#![allow(clippy::needless_range_loop)]

pub mod actor;
pub mod adam;
pub mod config;
pub mod critic;
pub mod estep;
pub mod evaluation;
pub mod gaussian;
pub mod learner;
pub mod linear;
pub mod params;
pub mod replay;
pub mod rng;
pub mod selfcheck;

pub use bytemuck;
