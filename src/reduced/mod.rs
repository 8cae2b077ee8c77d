//! The reduced model the haptic loop runs (see `shared/DESIGN.md`, "The
//! reduced model"): a modal basis of the full model linearized at a
//! displacement, and linear dynamics in the basis coordinates.
//!
//! - [`basis`]: the r lowest vibration modes of K φ = ω² M φ (fixed nodes
//!   removed, lumped M, mass-normalized) by shift-invert block subspace
//!   iteration on faer's sparse Cholesky, with a warm start from a previous
//!   basis, and optional static (attachment) modes at contact nodes.
//! - [`dynamics`]: implicit Euler on r coordinates with fixed-size nalgebra
//!   matrices (const-generic capacity), factored once, with a `step` that
//!   never allocates, for the 1 kHz loop.
//!
//! Not here yet: the nonlinear refresh (re-linearizing the full NVTMM and
//! swapping models between ticks), the background thread, the reduced Prony
//! terms, cubic reduced-force polynomials and a region of interest.

pub mod basis;
pub mod cache;
pub mod dynamics;

pub use basis::{static_split, BasisParams, ModalBasis, ReducedError};
pub use dynamics::{basis_rows, BasisRows, DynamicsParams, NodeOutOfRange, ReducedDynamics};
