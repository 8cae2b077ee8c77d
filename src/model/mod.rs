//! Force models: what turns nodal displacements into internal forces.
//!
//! Every model — [`msm`] (mass-spring), [`tmm`] (linear tensor-mass),
//! [`nvtmm`] (nonlinear tensor-mass StVK with Prony viscoelasticity) and
//! [`fem`] (element-wise hyperelastic FEM) — implements [`ForceModel`]: the
//! internal force f(u) = −∂W/∂u (eq. 7), its derivative as a tangent-vector
//! product (eq. 8), an assembled tangent, and the energy W. Viscoelastic
//! history ([`viscoelastic`]) advances through [`ForceModel::begin_step`] /
//! [`ForceModel::end_step`], called by the time integrator.
//!
//! The tangent of all of these models couples only nodes that share an edge,
//! so it is stored as [`BlockTangent`]: one 3×3 block per vertex and one per
//! edge, in the mesh's own numbering. No model here knows about time
//! integration or linear solvers (see `solver`).

pub mod factory;
pub mod fem;
pub mod msm;
pub mod nvtmm;
pub mod tmm;
pub mod viscoelastic;

use crate::math::Mat3;
use crate::math::Vec3;
use crate::mesh::TetMesh;
use std::sync::{Mutex, PoisonError};

/// Working memory a model sizes at construction and reuses on every call, so
/// that forces, tangent-vector products and tangents allocate nothing (the
/// background solver runs next to the RT loop; see `ImplicitEuler`).
///
/// The [`ForceModel`] methods take `&self`, so the buffers sit behind a
/// mutex. A second caller at the same time waits for the first one (it never
/// allocates its own copy); the solvers call a model from one thread at a
/// time, so the lock is uncontended and costs one atomic operation. A buffer
/// left behind by a panicking caller is reused: every user overwrites what it
/// reads. Cloning a model gives the clone its own buffers.
pub(crate) struct Scratch<T>(Mutex<T>);

impl<T> Scratch<T> {
    /// Wraps buffers sized by the caller.
    pub(crate) fn new(buffers: T) -> Scratch<T> {
        Scratch(Mutex::new(buffers))
    }

    /// Runs `f` with the buffers.
    #[inline]
    pub(crate) fn with<R>(&self, f: impl FnOnce(&mut T) -> R) -> R {
        let mut guard = self.0.lock().unwrap_or_else(PoisonError::into_inner);
        f(&mut guard)
    }
}

impl<T: Clone> Clone for Scratch<T> {
    fn clone(&self) -> Scratch<T> {
        Scratch::new(self.with(|t| t.clone()))
    }
}

impl<T> std::fmt::Debug for Scratch<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Scratch")
    }
}

/// Which force model a scene uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ModelKind {
    /// Mass-spring on the mesh edges.
    Msm,
    /// Linear tensor-mass.
    Tmm,
    /// Nonlinear viscoelastic tensor-mass.
    Nvtmm,
    /// Element-wise hyperelastic FEM.
    Fem,
}

impl ModelKind {
    /// Lower-case name as used in scenes and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            ModelKind::Msm => "msm",
            ModelKind::Tmm => "tmm",
            ModelKind::Nvtmm => "nvtmm",
            ModelKind::Fem => "fem",
        }
    }
}

impl std::str::FromStr for ModelKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "msm" => Ok(ModelKind::Msm),
            "tmm" => Ok(ModelKind::Tmm),
            "nvtmm" => Ok(ModelKind::Nvtmm),
            "fem" => Ok(ModelKind::Fem),
            _ => Err(format!("unknown model '{s}' (allowed: msm, tmm, nvtmm, fem)")),
        }
    }
}

/// The interface every force model implements. Forces follow the sign of
/// eq. 7 as a restoring force: f = −∂W/∂u, so K = −∂f/∂u is the (positive
/// semi-definite at rest) stiffness. Methods add into their output so models
/// and loads can be summed without temporaries.
pub trait ForceModel: Send + Sync {
    /// Short name for reports.
    fn name(&self) -> &'static str;

    /// Adds the internal force f(u) = −∂W/∂u into `out` (one entry per node).
    fn add_forces(&self, u: &[Vec3], out: &mut [Vec3]);

    /// Adds (∂f/∂u)(u) · du into `out` (eq. 8 as a tangent-vector product).
    fn add_df(&self, u: &[Vec3], du: &[Vec3], out: &mut [Vec3]);

    /// Adds the stiffness K(u) = −∂f/∂u into `k` (same pattern as the mesh).
    fn add_stiffness(&self, u: &[Vec3], k: &mut BlockTangent);

    /// Elastic energy W(u) (J). For viscoelastic models this is the energy of
    /// the elastic (instantaneous) law; the history force is not conservative.
    fn energy(&self, u: &[Vec3]) -> f64;

    /// Starts an implicit step of length `dt`: viscoelastic models fix their
    /// Prony coefficients A_i, B_i (eq. 15) for the forces and tangents that
    /// follow. Elastic models ignore it.
    fn begin_step(&mut self, _dt: f64) {}

    /// Ends a converged step at displacement `u`: viscoelastic models update
    /// their history γ_i (eq. 15). Elastic models ignore it.
    fn end_step(&mut self, _u: &[Vec3]) {}

    /// Forgets any viscoelastic history (back to a relaxed state).
    fn reset_history(&mut self) {}

    /// Saves the internal state that `end_step` advances (the Prony history)
    /// into memory allocated at construction, so that [`ForceModel::restore_state`]
    /// can undo the steps taken since: the integrator's step halving
    /// (`ImplicitEulerParams::max_halvings`) rolls back a step whose
    /// sub-steps did not all succeed. Elastic models have no such state.
    fn save_state(&mut self) {}

    /// Returns to the state of the last [`ForceModel::save_state`].
    fn restore_state(&mut self) {}

    /// Whether the model carries viscoelastic history.
    fn is_viscoelastic(&self) -> bool {
        false
    }
}

/// Symmetric block-sparse matrix with the mesh's vertex/edge pattern: block
/// (i, i) is `diag[i]`, block (a, b) for edge e = (a, b), a < b, is `off[e]`,
/// and block (b, a) is its transpose.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct BlockTangent {
    /// Diagonal blocks, one per node.
    pub diag: Vec<Mat3>,
    /// Upper off-diagonal blocks, one per mesh edge (low, high).
    pub off: Vec<Mat3>,
    /// The edges (low, high) the off-diagonal blocks belong to.
    pub edges: Vec<[u32; 2]>,
}

impl BlockTangent {
    /// A zero matrix with the mesh's pattern.
    pub fn zeros(mesh: &TetMesh) -> BlockTangent {
        BlockTangent {
            diag: vec![Mat3::zeros(); mesh.num_nodes()],
            off: vec![Mat3::zeros(); mesh.edges().len()],
            edges: mesh.edges().to_vec(),
        }
    }

    /// Sets every block to zero (keeps the pattern and memory).
    pub fn clear(&mut self) {
        self.diag.iter_mut().for_each(|b| *b = Mat3::zeros());
        self.off.iter_mut().for_each(|b| *b = Mat3::zeros());
    }

    /// Number of nodes (block rows).
    pub fn num_nodes(&self) -> usize {
        self.diag.len()
    }

    /// y += A x.
    pub fn mul_add(&self, x: &[Vec3], y: &mut [Vec3]) {
        for (i, d) in self.diag.iter().enumerate() {
            y[i] += d * x[i];
        }
        for (b, &[i, j]) in self.off.iter().zip(&self.edges) {
            let (i, j) = (i as usize, j as usize);
            y[i] += b * x[j];
            y[j] += b.tr_mul(&x[i]);
        }
    }

    /// y = A x.
    pub fn mul(&self, x: &[Vec3], y: &mut [Vec3]) {
        y.iter_mut().for_each(|v| *v = Vec3::zeros());
        self.mul_add(x, y);
    }

    /// Adds `s` times another matrix with the same pattern.
    pub fn add_scaled(&mut self, s: f64, other: &BlockTangent) {
        for (a, b) in self.diag.iter_mut().zip(&other.diag) {
            *a += b * s;
        }
        for (a, b) in self.off.iter_mut().zip(&other.off) {
            *a += b * s;
        }
    }

    /// Adds `m` to block (a, b) and, by symmetry, `mᵀ` to block (b, a), given
    /// the edge index `e` joining a and b (ignored when `a == b`; then `m` must
    /// be symmetric). Call it once per unordered pair of nodes.
    #[inline]
    pub fn add_block(&mut self, a: u32, b: u32, e: u32, m: &Mat3) {
        if a == b {
            self.diag[a as usize] += m;
        } else if a < b {
            self.off[e as usize] += m;
        } else {
            self.off[e as usize] += m.transpose();
        }
    }

    /// The matrix as a dense 3n×3n array (tests and small problems only).
    pub fn to_dense(&self) -> nalgebra::DMatrix<f64> {
        let n = self.num_nodes();
        let mut m = nalgebra::DMatrix::zeros(3 * n, 3 * n);
        for (i, d) in self.diag.iter().enumerate() {
            m.fixed_view_mut::<3, 3>(3 * i, 3 * i).copy_from(d);
        }
        for (b, &[i, j]) in self.off.iter().zip(&self.edges) {
            let (i, j) = (i as usize, j as usize);
            m.fixed_view_mut::<3, 3>(3 * i, 3 * j).copy_from(b);
            m.fixed_view_mut::<3, 3>(3 * j, 3 * i).copy_from(&b.transpose());
        }
        m
    }
}

/// For each tet, the edge index joining each ordered pair of its local
/// vertices (diagonal entries unused), for scattering element blocks.
pub fn tet_pair_edges(mesh: &TetMesh) -> Vec<[[u32; 4]; 4]> {
    mesh.tet_edges()
        .iter()
        .map(|te| {
            let mut m = [[u32::MAX; 4]; 4];
            for (k, [i, j]) in crate::mesh::TET_EDGE_LOCAL.iter().enumerate() {
                m[*i][*j] = te[k];
                m[*j][*i] = te[k];
            }
            m
        })
        .collect()
}
