//! Time integration: the implicit (backward) Euler step of eq. 2 and the
//! linear solvers it needs.
//!
//! Here live the tissue state ([`TissueState`]), boundary conditions and
//! external loads ([`loads`]), the Newton-based backward Euler integrator
//! ([`implicit_euler`]) and the linear solvers for its Newton systems
//! ([`linear`]: preconditioned CG on the assembled blocks, faer sparse
//! Cholesky; the step-timing harness is in [`crate::bench::timing`]). Force models live in [`crate::model`] and know nothing about
//! time; the reduced (modal) model and the haptic loop are elsewhere. The
//! formulation, sign conventions and measurements are in `docs/SOLVERS.md`.
//!
//! ```
//! use nvtmm::math::Vec3;
//! use nvtmm::mesh::arch::{generate, ArchParams};
//! use nvtmm::solver::loads::{nodes_in_box, Loads, NodalLoad, TimeProfile};
//! use nvtmm::solver::{ImplicitEuler, ImplicitEulerParams, LinearSolverKind, TissueState};
//!
//! let arch = generate(&ArchParams::default(), 1458).unwrap();
//! let mesh = &arch.mesh;
//! // Clamp both ends; pull on the outer wall with a 0.1 s ramp.
//! let mut fixed = mesh.node_set("inlet").unwrap().to_vec();
//! fixed.extend_from_slice(mesh.node_set("outlet_descending").unwrap());
//! let loads = Loads {
//!     nodal: vec![NodalLoad {
//!         nodes: mesh.node_set("outer_wall").unwrap().to_vec(),
//!         force: Vec3::new(0.0, 0.0, -1e-4),
//!         profile: TimeProfile::Ramp { t0: 0.0, t1: 0.1 },
//!     }],
//!     gravity: Vec3::zeros(),
//!     pressure: None,
//! };
//! let params = ImplicitEulerParams { dt: 1e-3, linear: LinearSolverKind::Cholesky, ..Default::default() };
//! let euler = ImplicitEuler::new(mesh, mesh.lumped_mass(1100.0), params).unwrap();
//! let state = TissueState::at_rest(mesh.num_nodes());
//! // With a force model `model: impl ForceModel`, each step is
//! // `let report = euler.step(&mut state, &mut model, &loads, &fixed);`
//! let (lo, hi) = mesh.bbox();
//! assert_eq!(nodes_in_box(mesh, lo, hi).len(), mesh.num_nodes());
//! # let _ = (euler, state, loads, fixed);
//! ```

pub mod implicit_euler;
pub mod linear;
pub mod loads;
pub mod pressure;
pub mod statics;
pub mod unload;

pub use implicit_euler::{
    ImplicitEuler, ImplicitEulerParams, NewtonParams, SolverError, StepFailure, StepReport, MAX_HALVINGS,
    MAX_NEWTON_ITERS,
};
pub use linear::{LinearSolverKind, Preconditioner};

use crate::math::Vec3;

/// The dynamic state of the tissue (SI units).
#[derive(Debug, Clone, PartialEq)]
pub struct TissueState {
    /// Nodal displacements from the rest positions (m).
    pub u: Vec<Vec3>,
    /// Nodal velocities (m/s).
    pub v: Vec<Vec3>,
    /// Time (s).
    pub t: f64,
}

impl TissueState {
    /// Zero displacement and velocity at t = 0 for `n` nodes.
    pub fn at_rest(n: usize) -> TissueState {
        TissueState {
            u: vec![Vec3::zeros(); n],
            v: vec![Vec3::zeros(); n],
            t: 0.0,
        }
    }

    /// Kinetic energy ½ vᵀ M v (J) with the lumped mass `mass` (kg per node).
    pub fn kinetic_energy(&self, mass: &[f64]) -> f64 {
        0.5 * self.v.iter().zip(mass).map(|(v, m)| m * v.norm_squared()).sum::<f64>()
    }

    /// Whether every number in the state is finite.
    pub fn is_finite(&self) -> bool {
        self.t.is_finite() && self.u.iter().chain(&self.v).all(|x| x.iter().all(|c| c.is_finite()))
    }
}
