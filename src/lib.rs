//! # nvtmm — real-time nonlinear viscoelastic tensor-mass vessel tissue
//!
//! A simulator of blood-vessel tissue for haptic training of endovascular
//! surgery, after *Performance Evaluation of the Vascular Model Based on the
//! Nonlinear Viscoelastic Tensor-Mass Method* (NVTMM): St Venant–Kirchhoff in
//! tensor-mass form, a Neo-Hookean option, Prony-series viscoelasticity and
//! implicit Euler on a P1 tetrahedral mesh of an aortic arch, with mass-spring
//! and FEM baselines.
//!
//! The product around it (docs/ARCHITECTURE.md in the repository):
//!
//! ```text
//!  device I/O (1 kHz)  --pose ring-->  haptic loop (1 kHz, reduced NVTMM, passivity QP)
//!                      <--force ring--        |  ^ new reduced models
//!                                             v  |
//!                            background: full NVTMM implicit Euler, basis refresh
//!                                             |
//!                                             v coarse state (30-60 Hz) -> any renderer
//! ```
//!
//! Modules, one concept each: [`mesh`] (the tet mesh, the built-in arch, file
//! formats).
//!
//! ```
//! use nvtmm::mesh::arch::{generate, ArchParams};
//! let arch = generate(&ArchParams::default(), 1458).unwrap();
//! assert!((arch.mesh.num_nodes() as f64 - 1458.0).abs() / 1458.0 < 0.01);
//! ```
#![warn(missing_docs)]
#![warn(clippy::undocumented_unsafe_blocks)]

#[cfg(feature = "tools")]
pub mod bench;
pub mod config;
#[cfg(feature = "tools")]
pub mod experiment;
pub mod haptics;
pub mod material;
pub mod math;
pub mod mesh;
pub mod model;
pub mod observe;
pub mod reduced;
pub mod rt;
pub mod scene;
pub mod service;
pub mod simulate;
#[cfg(feature = "tools")]
pub mod soak;
pub mod solver;
pub mod stream;
pub mod task;
pub mod wire;
