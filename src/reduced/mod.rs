//! The reduced model the haptic loop runs (docs/ARCHITECTURE.md, "The
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
//! - [`cubic`]: the exact reduced StVK force and tangent as a cubic
//!   polynomial in q (Barbič & James 2005), precomputed per basis, and
//!   nonlinear implicit-Euler dynamics on it: an option for small r.
//! - [`derivatives`]: modal derivatives, the basis enrichment the cubic
//!   model needs at large deformation.
//! - [`refresh`]: re-linearizing the full model at the background solve's
//!   displacement in a fixed basis (K_r = ΦᵀK(ū)Φ) and the state transfer
//!   the loop applies when it swaps models.
//!
//! The background thread and the swap through rings live in the service.

pub mod basis;
pub mod cache;
pub mod compliance;
pub mod cubic;
pub mod derivatives;
pub mod dynamics;
pub mod refresh;

pub use basis::{static_split, BasisParams, BasisSpec, ModalBasis, ReducedError, Statics, Stiffness};
pub use cubic::{CubicReducedDynamics, CubicStepError, CubicStvk};
pub use dynamics::{basis_rows, BasisRows, DynamicsParams, ModalPulse, NodeOutOfRange, ReducedDynamics, ReducedPart};
pub use refresh::Refresher;
