//! The modal basis: the r lowest vibration modes of the full model linearized
//! at a displacement u, K(u) φ = ω² M φ, with the fixed nodes removed, the
//! lumped mass M, and Φᵀ M Φ = I.
//!
//! Method: shift-invert (shift 0) block subspace iteration with Rayleigh–Ritz
//! (Bathe's form). With y = M^½ x the problem is the standard symmetric
//! A y = λ y, A = M^-½ K M^-½; each iteration applies A⁻¹ = M^½ K⁻¹ M^½ to
//! a block Y of p ≥ r vectors, Z = A⁻¹ Y (one sparse Cholesky factorization
//! of K on the free DOFs, faer, sequential; the block's two column halves
//! are solved on two threads), and rotates Z to the Ritz vectors of A from
//! the p × p projections Zᵀ Y = Zᵀ A Z and Zᵀ Z (nalgebra), so neither a
//! product with K nor an orthonormalization of the tall block is needed,
//! and A times the Ritz vectors (Y S) comes for free for the residuals. The
//! tall products are faer GEMMs. The iteration stops when every one of the
//! r wanted modes has ‖Kφ − ω²Mφ‖ ≤ [`RESIDUAL_TOL`] ‖Kφ‖ (or has stagnated
//! at the rounding floor below [`ACCEPT_TOL`]). A block rather than a
//! Lanczos recurrence because it takes a previous basis as a warm start
//! directly: after a small change of u the old modes are nearly converged
//! already.
//!
//! Static (attachment) modes K⁻¹ e_d for the DOFs of given contact nodes can
//! be added ([`Statics::All`] in a [`BasisSpec`]): they make the reduced model's
//! stiffness at those nodes exact, which a few vibration modes alone cannot.

use crate::math::Vec3;
use crate::mesh::TetMesh;
use crate::model::{BlockTangent, ForceModel};
use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt::factor::LltRegularization;
use faer::linalg::matmul::matmul;
use faer::sparse::linalg::cholesky::{
    factorize_symbolic_cholesky, CholeskySymbolicParams, LltRef, SymbolicCholesky, SymmetricOrdering,
};
use faer::sparse::{SparseColMat, Triplet};
use faer::{Accum, Conj, MatMut, MatRef, Par, Side};
use nalgebra::{DMatrix, DVector, SymmetricEigen};

/// Default relative eigen-residual ‖Kφ − ω²Mφ‖ / ‖Kφ‖ every wanted mode
/// reaches before [`ModalBasis::compute`] returns. Eigenvalues are then accurate to
/// about its square. 1e-8 is reachable at every arch size (the rounding
/// floor is ≈ 2e-9 at 23k nodes) and far below the modal truncation error.
pub const RESIDUAL_TOL: f64 = 1e-8;

/// Rounding puts a floor under the residual that grows with the condition
/// number of K (≈ 2e-10 on a 1000-node arch). Once the worst residual is
/// below this bound and has stopped halving for [`STAGNATION_ITERATIONS`]
/// iterations, the basis is accepted as converged to rounding.
pub const ACCEPT_TOL: f64 = 1e-8;

/// See [`ACCEPT_TOL`].
pub const STAGNATION_ITERATIONS: usize = 3;

/// Default number of subspace iterations allowed before
/// [`ReducedError::NotConverged`].
pub const MAX_ITERATIONS: usize = 1000;

/// Stopping rule of the subspace iteration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BasisParams {
    /// Relative eigen-residual ‖Kφ − ω²Mφ‖ / ‖Kφ‖ every wanted mode must
    /// reach, in (0, 1). Default [`RESIDUAL_TOL`].
    pub tol: f64,
    /// Iteration limit. Default [`MAX_ITERATIONS`].
    pub max_iterations: usize,
}

impl Default for BasisParams {
    fn default() -> Self {
        BasisParams {
            tol: RESIDUAL_TOL,
            max_iterations: MAX_ITERATIONS,
        }
    }
}

/// Why a basis or a reduced model could not be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ReducedError {
    /// An input array does not have one entry per mesh node.
    #[error("{what} has {got} entries, the mesh has {expected} nodes")]
    SizeMismatch {
        /// Which input.
        what: &'static str,
        /// Its length.
        got: usize,
        /// The number of mesh nodes.
        expected: usize,
    },
    /// A node index (fixed or contact node) is not a node of the mesh.
    #[error("{what} node {node} is out of range (the mesh has {nodes} nodes)")]
    NodeOutOfRange {
        /// "fixed" or "contact".
        what: &'static str,
        /// The offending index.
        node: u32,
        /// The number of mesh nodes.
        nodes: usize,
    },
    /// A free node's lumped mass is not positive and finite.
    #[error("the lumped mass of free node {node} is {mass}; it must be positive and finite")]
    BadMass {
        /// The node.
        node: usize,
        /// Its mass (kg).
        mass: f64,
    },
    /// Zero modes, or more modes than free degrees of freedom.
    #[error("asked for {asked} modes; between 1 and {free_dofs} (the free degrees of freedom) are possible")]
    BadModeCount {
        /// Modes asked for.
        asked: usize,
        /// Free degrees of freedom.
        free_dofs: usize,
    },
    /// The stiffness has a NaN or infinite entry.
    #[error("the stiffness K(u) has a non-finite entry")]
    NonFinite,
    /// K on the free DOFs is not positive definite (too few nodes fixed to
    /// remove the rigid motions, or u beyond a buckling point).
    #[error(
        "the stiffness on the free nodes is not positive definite (too few nodes fixed, or u past a stability limit)"
    )]
    NotPositiveDefinite,
    /// The subspace iteration hit its iteration limit ([`BasisParams`]).
    #[error(
        "the subspace iteration did not converge in {iterations} iterations (worst relative residual {residual:e})"
    )]
    NotConverged {
        /// Iterations done.
        iterations: usize,
        /// Worst relative eigen-residual of a wanted mode.
        residual: f64,
    },
    /// A warm-start basis was made for a mesh of another size.
    #[error("the warm-start basis has {got} rows, this mesh needs {expected}")]
    WarmStartMismatch {
        /// Rows of the warm basis.
        got: usize,
        /// 3 × nodes.
        expected: usize,
    },
    /// A reduced model's capacity is smaller than the basis.
    #[error("the basis has {size} columns but the reduced model's capacity is {capacity}")]
    Capacity {
        /// Columns of the basis.
        size: usize,
        /// The const-generic capacity R.
        capacity: usize,
    },
    /// A dynamics parameter is out of range.
    #[error("{name} = {value} is out of range ({allowed})")]
    BadParameter {
        /// Parameter name.
        name: &'static str,
        /// Its value.
        value: f64,
        /// The allowed range.
        allowed: &'static str,
    },
}

/// A mass-orthonormal reduced basis of the full model at one linearization
/// point.
#[derive(Debug, Clone, PartialEq)]
pub struct ModalBasis {
    /// The basis, 3n × m: row 3i + c is component c of node i, one column per
    /// basis vector; the rows of fixed nodes are zero. Φᵀ M Φ = I.
    pub phi: DMatrix<f64>,
    /// ΦᵀKΦ is diag(`omega2`), ascending (rad²/s²). For pure vibration modes
    /// these are the eigenvalues ω²; for an augmented basis they are the
    /// Ritz values of the augmented subspace.
    pub omega2: Vec<f64>,
    /// Number of static (attachment) directions in the basis (0: the columns
    /// are the lowest vibration modes). When non-zero the columns are the
    /// Ritz vectors of span{modes, attachments}: still M-orthonormal with a
    /// diagonal reduced stiffness, but no longer eigenvectors of the full
    /// problem.
    pub num_static: usize,
    /// The fixed nodes (sorted, unique), whose rows of Φ are zero.
    pub fixed: Vec<u32>,
    /// Subspace iterations the computation took.
    pub iterations: usize,
}

/// Where the stiffness K of a basis comes from.
#[derive(Clone, Copy)]
pub enum Stiffness<'a> {
    /// `model.add_stiffness(u)` on `mesh`.
    Model {
        /// The mesh.
        mesh: &'a TetMesh,
        /// The force model.
        model: &'a dyn ForceModel,
        /// The displacement to linearize at (one entry per node).
        u: &'a [Vec3],
    },
    /// An already assembled tangent (e.g. the one the full implicit step just
    /// built): a background refresh needs neither the model nor an assembly.
    Tangent(&'a BlockTangent),
}

/// Static (attachment) modes K⁻¹ e_d added for a contact region.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Statics<'a> {
    /// Vibration modes only.
    None,
    /// Every attachment direction of the free nodes of the region, on top of
    /// the `r` modes (M-orthonormalized against them; directions already in
    /// the span dropped), the whole rotated to its Ritz vectors.
    All(&'a [u32]),
    /// Exactly `r` columns: the attachment responses of the free region
    /// nodes compressed to their `k = min(3 · free nodes, max_static)`
    /// dominant directions (best rank-k approximation of the region's
    /// compliance in the M inner product), and `r − k` vibration modes; see
    /// [`static_split`].
    Compressed {
        /// The region's nodes.
        contact: &'a [u32],
        /// Most static directions kept.
        max_static: usize,
    },
}

/// What basis to compute ([`ModalBasis::compute`]).
#[derive(Clone, Copy)]
pub struct BasisSpec<'a> {
    /// K.
    pub stiffness: Stiffness<'a>,
    /// Lumped mass per node (kg).
    pub mass: &'a [f64],
    /// Fixed nodes (their rows of Φ are zero).
    pub fixed: &'a [u32],
    /// Number of vibration modes (with [`Statics::Compressed`], of columns).
    pub r: usize,
    /// Static modes of a contact region.
    pub statics: Statics<'a>,
    /// A basis from a nearby state on the same mesh to start from.
    pub warm: Option<&'a ModalBasis>,
    /// Tolerance and iteration limit.
    pub params: BasisParams,
}

impl<'a> BasisSpec<'a> {
    /// `r` vibration modes of `model` linearized at `u`, default tolerance,
    /// no static modes, no warm start.
    pub fn modes(
        mesh: &'a TetMesh,
        model: &'a dyn ForceModel,
        u: &'a [Vec3],
        mass: &'a [f64],
        fixed: &'a [u32],
        r: usize,
    ) -> BasisSpec<'a> {
        BasisSpec {
            stiffness: Stiffness::Model { mesh, model, u },
            mass,
            fixed,
            r,
            statics: Statics::None,
            warm: None,
            params: BasisParams::default(),
        }
    }
}

impl ModalBasis {
    /// Computes the basis a [`BasisSpec`] asks for: the `r` lowest
    /// vibration modes of K φ = ω² M φ (fixed nodes removed, Φᵀ M Φ = I),
    /// optionally with static (attachment) modes of a contact region (see
    /// [`Statics`]), warm-started from a nearby basis if one is given.
    pub fn compute(spec: &BasisSpec<'_>) -> Result<ModalBasis, ReducedError> {
        let owned;
        let k = match spec.stiffness {
            Stiffness::Model { mesh, model, u } => {
                owned = tangent_at(mesh, model, u)?;
                &owned
            }
            Stiffness::Tangent(k) => k,
        };
        match spec.statics {
            Statics::None => compute_from_tangent(k, spec.mass, spec.fixed, spec.r, &[], None, spec.warm, &spec.params),
            Statics::All(contact) => {
                compute_from_tangent(k, spec.mass, spec.fixed, spec.r, contact, None, spec.warm, &spec.params)
            }
            Statics::Compressed { contact, max_static } => {
                let n = k.num_nodes();
                let mut is_fixed = vec![false; n];
                for &f in spec.fixed {
                    if let Some(x) = is_fixed.get_mut(f as usize) {
                        *x = true;
                    }
                }
                let mut free_contact: Vec<u32> = contact
                    .iter()
                    .copied()
                    .filter(|&c| !is_fixed.get(c as usize).copied().unwrap_or(false))
                    .collect();
                free_contact.sort_unstable();
                free_contact.dedup();
                let (modes, k_static) = static_split(spec.r, free_contact.len(), max_static);
                let contact_used: &[u32] = if k_static == 0 { &[] } else { contact };
                compute_from_tangent(
                    k,
                    spec.mass,
                    spec.fixed,
                    modes,
                    contact_used,
                    Some(k_static),
                    spec.warm,
                    &spec.params,
                )
            }
        }
    }

    /// Number of basis vectors (columns).
    pub fn len(&self) -> usize {
        self.phi.ncols()
    }

    /// Whether the basis has no columns.
    pub fn is_empty(&self) -> bool {
        self.phi.ncols() == 0
    }

    /// Number of mesh nodes the basis is defined on.
    pub fn num_nodes(&self) -> usize {
        self.phi.nrows() / 3
    }

    /// The generalized force Φᵀ f of nodal forces `f` (one per node).
    pub fn project(&self, f: &[Vec3]) -> DVector<f64> {
        let mut q = DVector::zeros(self.len());
        for (i, fi) in f.iter().enumerate().take(self.num_nodes()) {
            for c in 0..3 {
                if fi[c] != 0.0 {
                    q.axpy(fi[c], &self.phi.row(3 * i + c).transpose(), 1.0);
                }
            }
        }
        q
    }

    /// The nodal displacement Φ q of reduced coordinates `q`.
    pub fn expand(&self, q: &DVector<f64>) -> Vec<Vec3> {
        let x = &self.phi * q;
        x.as_slice()
            .chunks_exact(3)
            .map(|c| Vec3::new(c[0], c[1], c[2]))
            .collect()
    }

    /// Displacement of one node for reduced coordinates `q`, from that node's
    /// three rows of Φ only.
    pub fn displacement_at(&self, node: u32, q: &DVector<f64>) -> Option<Vec3> {
        let node = node as usize;
        if node >= self.num_nodes() || q.len() != self.len() {
            return None;
        }
        let row = |c: usize| self.phi.row(3 * node + c).transpose().dot(q);
        Some(Vec3::new(row(0), row(1), row(2)))
    }
}

/// How a basis of `r_total` columns for a contact region of
/// `free_contact_nodes` free nodes splits into (vibration modes, static
/// directions): k = min(3 · nodes, `max_static`, r_total − 1) static
/// directions, at least one vibration mode.
pub fn static_split(r_total: usize, free_contact_nodes: usize, max_static: usize) -> (usize, usize) {
    let k = (3 * free_contact_nodes).min(max_static).min(r_total.saturating_sub(1));
    (r_total - k, k)
}

/// The tangent K(u) of `model`, after checking u's length.
fn tangent_at(mesh: &TetMesh, model: &dyn ForceModel, u: &[Vec3]) -> Result<BlockTangent, ReducedError> {
    let n = mesh.num_nodes();
    if u.len() != n {
        return Err(ReducedError::SizeMismatch {
            what: "the displacement",
            got: u.len(),
            expected: n,
        });
    }
    let mut k = BlockTangent::zeros(mesh);
    model.add_stiffness(u, &mut k);
    Ok(k)
}

/// The basis on an assembled tangent: `max_static` None keeps every
/// attachment direction of `contact`.
#[allow(clippy::too_many_arguments)]
fn compute_from_tangent(
    k: &BlockTangent,
    mass: &[f64],
    fixed: &[u32],
    r: usize,
    contact: &[u32],
    max_static: Option<usize>,
    warm: Option<&ModalBasis>,
    params: &BasisParams,
) -> Result<ModalBasis, ReducedError> {
    if !(params.tol > 0.0 && params.tol < 1.0) {
        return Err(ReducedError::BadParameter {
            name: "tol",
            value: params.tol,
            allowed: "in (0, 1)",
        });
    }
    let n = k.num_nodes();
    if let Some(w) = warm {
        if w.phi.nrows() != 3 * n {
            return Err(ReducedError::WarmStartMismatch {
                got: w.phi.nrows(),
                expected: 3 * n,
            });
        }
    }
    let problem = FreeProblem::new(k, mass, fixed)?;
    let nf = problem.dofs();
    if r == 0 || r > nf {
        return Err(ReducedError::BadModeCount {
            asked: r,
            free_dofs: nf,
        });
    }
    for &c in contact {
        if c as usize >= n {
            return Err(ReducedError::NodeOutOfRange {
                what: "contact",
                node: c,
                nodes: n,
            });
        }
    }
    let warm_y = warm.map(|w| problem.to_y(&w.phi));
    let (mut y, mut lambda, iterations) = subspace_iteration(&problem, r, warm_y.as_ref(), params)?;
    let mut num_static = 0;
    if !contact.is_empty() {
        let (ya, la, ns) = augment(&problem, &y, contact, max_static);
        y = ya;
        lambda = la;
        num_static = ns;
    }
    let mut fixed: Vec<u32> = fixed.to_vec();
    fixed.sort_unstable();
    fixed.dedup();
    Ok(ModalBasis {
        phi: problem.to_phi(&y),
        omega2: lambda,
        num_static,
        fixed,
        iterations,
    })
}

/// K restricted to the free DOFs, its Cholesky factor and M^½ there.
struct FreeProblem {
    /// First free DOF of each node, `None` for fixed nodes.
    dof_of_node: Vec<Option<usize>>,
    /// M^½ per free DOF.
    sqrt_m: Vec<f64>,
    /// K_ff, both triangles, for products.
    kff: SparseColMat<usize, f64>,
    /// Symbolic analysis and numeric values of K_ff's Cholesky factor.
    symbolic: SymbolicCholesky<usize>,
    l_values: Vec<f64>,
}

impl FreeProblem {
    fn new(k: &BlockTangent, mass: &[f64], fixed: &[u32]) -> Result<FreeProblem, ReducedError> {
        let n = k.num_nodes();
        if mass.len() != n {
            return Err(ReducedError::SizeMismatch {
                what: "the lumped mass",
                got: mass.len(),
                expected: n,
            });
        }
        let mut is_fixed = vec![false; n];
        for &f in fixed {
            match is_fixed.get_mut(f as usize) {
                Some(x) => *x = true,
                None => {
                    return Err(ReducedError::NodeOutOfRange {
                        what: "fixed",
                        node: f,
                        nodes: n,
                    })
                }
            }
        }
        let mut dof_of_node = vec![None; n];
        let mut sqrt_m = Vec::new();
        for i in 0..n {
            if is_fixed[i] {
                continue;
            }
            let m = mass[i];
            if !(m.is_finite() && m > 0.0) {
                return Err(ReducedError::BadMass { node: i, mass: m });
            }
            dof_of_node[i] = Some(sqrt_m.len());
            sqrt_m.extend([m.sqrt(); 3]);
        }
        let mut entries = Vec::new();
        let mut push_block = |a: usize, b: usize, m: &crate::math::Mat3| {
            for r in 0..3 {
                for c in 0..3 {
                    if m[(r, c)] != 0.0 {
                        entries.push((a + r, b + c, m[(r, c)]));
                    }
                }
            }
        };
        for (i, d) in k.diag.iter().enumerate() {
            if let Some(a) = dof_of_node[i] {
                push_block(a, a, d);
            }
        }
        for (o, &[i, j]) in k.off.iter().zip(&k.edges) {
            if let (Some(a), Some(b)) = (dof_of_node[i as usize], dof_of_node[j as usize]) {
                push_block(a, b, o);
                push_block(b, a, &o.transpose());
            }
        }
        if entries.iter().any(|e| !e.2.is_finite()) {
            return Err(ReducedError::NonFinite);
        }
        let nf = sqrt_m.len();
        let triplets: Vec<Triplet<usize, usize, f64>> = entries
            .iter()
            .map(|&(row, col, val)| Triplet { row, col, val })
            .collect();
        let kff = SparseColMat::<usize, f64>::try_new_from_triplets(nf, nf, &triplets)
            .map_err(|_| ReducedError::NotPositiveDefinite)?;
        let symbolic = factorize_symbolic_cholesky(
            kff.symbolic(),
            Side::Lower,
            SymmetricOrdering::Amd,
            CholeskySymbolicParams::default(),
        )
        .map_err(|_| ReducedError::NotPositiveDefinite)?;
        let mut l_values = vec![0.0; symbolic.len_val()];
        // Sequential: faer's parallel factorization is slower on this
        // machine (docs/BENCHMARKS.md).
        let mut scratch = MemBuffer::new(symbolic.factorize_numeric_llt_scratch::<f64>(Par::Seq, Default::default()));
        symbolic
            .factorize_numeric_llt::<f64>(
                &mut l_values,
                kff.as_ref(),
                Side::Lower,
                LltRegularization::default(),
                Par::Seq,
                MemStack::new(&mut scratch),
                Default::default(),
            )
            .map_err(|_| ReducedError::NotPositiveDefinite)?;
        Ok(FreeProblem {
            dof_of_node,
            sqrt_m,
            kff,
            symbolic,
            l_values,
        })
    }

    fn dofs(&self) -> usize {
        self.sqrt_m.len()
    }

    /// Y ← A⁻¹ Y = M^½ K⁻¹ M^½ Y.
    fn apply_inverse(&self, y: &mut DMatrix<f64>) {
        self.scale_rows(y, false);
        let (rows, cols) = y.shape();
        // Two halves of the block on two threads: each triangular solve
        // streams the whole factor, so splitting the columns halves the time
        // per core where faer's own parallel solve does not pay.
        let half = cols.div_ceil(2);
        let (a, b) = y.as_mut_slice().split_at_mut(rows * half);
        let llt = LltRef::new(&self.symbolic, &self.l_values);
        let solve = |s: &mut [f64]| {
            let c = s.len() / rows.max(1);
            if c > 0 {
                let mut scratch = MemBuffer::new(self.symbolic.solve_in_place_scratch::<f64>(c, Par::Seq));
                llt.solve_in_place_with_conj(
                    Conj::No,
                    MatMut::from_column_major_slice_mut(s, rows, c),
                    Par::Seq,
                    MemStack::new(&mut scratch),
                );
            }
        };
        rayon::join(|| solve(a), || solve(b));
        self.scale_rows(y, false);
    }

    /// A Y = M^-½ K M^-½ Y.
    fn apply(&self, y: &DMatrix<f64>) -> DMatrix<f64> {
        let mut x = y.clone();
        self.scale_rows(&mut x, true);
        let mut out = DMatrix::zeros(y.nrows(), y.ncols());
        let (rows, cols) = out.shape();
        faer::sparse::linalg::matmul::sparse_dense_matmul(
            MatMut::from_column_major_slice_mut(out.as_mut_slice(), rows, cols),
            Accum::Replace,
            self.kff.as_ref(),
            MatRef::from_column_major_slice(x.as_slice(), x.nrows(), x.ncols()),
            1.0,
            Par::Seq,
        );
        self.scale_rows(&mut out, true);
        out
    }

    /// Multiplies row i by M^½ (or by M^-½ if `inverse`).
    fn scale_rows(&self, y: &mut DMatrix<f64>, inverse: bool) {
        for mut col in y.column_iter_mut() {
            for (v, s) in col.iter_mut().zip(&self.sqrt_m) {
                if inverse {
                    *v /= s;
                } else {
                    *v *= s;
                }
            }
        }
    }

    /// Full 3n-row Φ = M^-½ Y, zero on fixed nodes.
    fn to_phi(&self, y: &DMatrix<f64>) -> DMatrix<f64> {
        let n = self.dof_of_node.len();
        let mut phi = DMatrix::zeros(3 * n, y.ncols());
        for (i, d) in self.dof_of_node.iter().enumerate() {
            if let Some(a) = *d {
                for c in 0..3 {
                    let s = 1.0 / self.sqrt_m[a + c];
                    for k in 0..y.ncols() {
                        phi[(3 * i + c, k)] = y[(a + c, k)] * s;
                    }
                }
            }
        }
        phi
    }

    /// Y = M^½ Φ restricted to the free DOFs.
    fn to_y(&self, phi: &DMatrix<f64>) -> DMatrix<f64> {
        let mut y = DMatrix::zeros(self.dofs(), phi.ncols());
        for (i, d) in self.dof_of_node.iter().enumerate() {
            if let Some(a) = *d {
                for c in 0..3 {
                    for k in 0..phi.ncols() {
                        y[(a + c, k)] = phi[(3 * i + c, k)] * self.sqrt_m[a + c];
                    }
                }
            }
        }
        y
    }
}

/// Deterministic values in [−1, 1) (splitmix64), to fill a start block.
fn pseudo_random(seed: &mut u64) -> f64 {
    *seed = seed.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *seed;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    (z >> 11) as f64 / (1u64 << 52) as f64 - 1.0
}

/// Orthonormal columns spanning Y's (thin QR).
fn orthonormalize(y: DMatrix<f64>) -> DMatrix<f64> {
    y.qr().q()
}

/// Rayleigh–Ritz of A on the orthonormal block Q: returns the Ritz vectors,
/// A times them, and the Ritz values, ascending.
fn rayleigh_ritz(problem: &FreeProblem, q: &DMatrix<f64>) -> (DMatrix<f64>, DMatrix<f64>, Vec<f64>) {
    let aq = problem.apply(q);
    let h = gemm_tn(q, &aq);
    let h = (&h + h.transpose()) * 0.5;
    let eig = SymmetricEigen::new(h);
    let mut order: Vec<usize> = (0..eig.eigenvalues.len()).collect();
    order.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
    let s = DMatrix::from_fn(eig.eigenvectors.nrows(), order.len(), |i, j| {
        eig.eigenvectors[(i, order[j])]
    });
    let lambda = order.iter().map(|&j| eig.eigenvalues[j]).collect();
    (gemm_nn(q, &s), gemm_nn(&aq, &s), lambda)
}

/// Worst relative residual ‖Kφ − ω²Mφ‖ / ‖Kφ‖ over the first `r` Ritz
/// pairs, in x = M^-½ y coordinates: Kφ = M^½ A y and the residual is
/// M^½ (A y − λ y).
fn worst_residual(problem: &FreeProblem, y: &DMatrix<f64>, ay: &DMatrix<f64>, lambda: &[f64], r: usize) -> f64 {
    let mut worst: f64 = 0.0;
    for j in 0..r {
        let (mut res, mut kphi) = (0.0, 0.0);
        for (i, s) in problem.sqrt_m.iter().enumerate() {
            let a = ay[(i, j)];
            res += (s * (a - lambda[j] * y[(i, j)])).powi(2);
            kphi += (s * a).powi(2);
        }
        let rel = if kphi > 0.0 { (res / kphi).sqrt() } else { f64::INFINITY };
        worst = worst.max(if rel.is_nan() { f64::INFINITY } else { rel });
    }
    worst
}

/// Zᵀ Y for two tall column-major blocks (faer's GEMM).
fn gemm_tn(z: &DMatrix<f64>, y: &DMatrix<f64>) -> DMatrix<f64> {
    let mut out = DMatrix::zeros(z.ncols(), y.ncols());
    let (zr, yr) = (
        MatRef::from_column_major_slice(z.as_slice(), z.nrows(), z.ncols()),
        MatRef::from_column_major_slice(y.as_slice(), y.nrows(), y.ncols()),
    );
    let (rows, cols) = out.shape();
    matmul(
        MatMut::from_column_major_slice_mut(out.as_mut_slice(), rows, cols),
        Accum::Replace,
        zr.transpose(),
        yr,
        1.0,
        Par::Seq,
    );
    out
}

/// Z S for a tall column-major block and a small matrix (faer's GEMM).
fn gemm_nn(z: &DMatrix<f64>, s: &DMatrix<f64>) -> DMatrix<f64> {
    let mut out = DMatrix::zeros(z.nrows(), s.ncols());
    let (rows, cols) = out.shape();
    matmul(
        MatMut::from_column_major_slice_mut(out.as_mut_slice(), rows, cols),
        Accum::Replace,
        MatRef::from_column_major_slice(z.as_slice(), z.nrows(), z.ncols()),
        MatRef::from_column_major_slice(s.as_slice(), s.nrows(), s.ncols()),
        1.0,
        Par::Seq,
    );
    out
}

/// Ritz pairs of A on span(Z) given Z and Y = A Z (Bathe's projection: no
/// product with K and no orthonormalization of the tall block). Solves the
/// p × p generalized problem (Zᵀ Y) s = λ (Zᵀ Z) s after scaling Z's columns
/// to unit length, and returns (Z S, Y S, λ ascending) with Sᵀ Zᵀ Z S = I.
/// `None` if Zᵀ Z is numerically singular (the caller then
/// re-orthonormalizes).
fn ritz_from_pair(z: &DMatrix<f64>, y: &DMatrix<f64>) -> Option<(DMatrix<f64>, DMatrix<f64>, Vec<f64>)> {
    let g = gemm_tn(z, z);
    let h = gemm_tn(z, y);
    let p = g.nrows();
    let d: Vec<f64> = (0..p).map(|j| 1.0 / g[(j, j)].sqrt()).collect();
    if d.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let scale = |m: &DMatrix<f64>| DMatrix::from_fn(p, p, |i, j| 0.5 * (m[(i, j)] + m[(j, i)]) * d[i] * d[j]);
    let (g, h) = (scale(&g), scale(&h));
    let chol = nalgebra::Cholesky::new(g)?;
    let l = chol.l();
    // C = L⁻¹ H L⁻ᵀ.
    let lih = l.solve_lower_triangular(&h)?;
    let c = l.solve_lower_triangular(&lih.transpose())?;
    let c = (&c + c.transpose()) * 0.5;
    let eig = SymmetricEigen::new(c);
    let mut order: Vec<usize> = (0..p).collect();
    order.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
    let v = DMatrix::from_fn(p, p, |i, j| eig.eigenvectors[(i, order[j])]);
    // S = D L⁻ᵀ V.
    let mut s = l.transpose().solve_upper_triangular(&v)?;
    for (i, di) in d.iter().enumerate() {
        s.row_mut(i).scale_mut(*di);
    }
    if s.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let lambda = order.iter().map(|&j| eig.eigenvalues[j]).collect();
    Some((gemm_nn(z, &s), gemm_nn(y, &s), lambda))
}

/// The `r` lowest eigenpairs of A in y coordinates (orthonormal columns),
/// and the iterations taken.
///
/// Each iteration solves Z = A⁻¹ Y for the block (so A Z = Y is known
/// without a product with K), takes the Ritz pairs of A on span(Z) from the
/// small projections Zᵀ Y and Zᵀ Z, and continues from the Ritz vectors
/// (Bathe's subspace iteration). The Ritz vectors come with A times them,
/// which gives the residuals for free.
fn subspace_iteration(
    problem: &FreeProblem,
    r: usize,
    warm: Option<&DMatrix<f64>>,
    params: &BasisParams,
) -> Result<(DMatrix<f64>, Vec<f64>, usize), ReducedError> {
    let nf = problem.dofs();
    // Bathe's block size: convergence of mode r goes as (λ_r / λ_{p+1})^k.
    let p = (2 * r).max(r + 8).min(nf);
    let mut seed = 0x5EED_u64;
    let mut y = DMatrix::from_fn(nf, p, |_, _| pseudo_random(&mut seed));
    if let Some(w) = warm {
        let m = w.ncols().min(p);
        y.columns_mut(0, m).copy_from(&w.columns(0, m));
    }
    let mut y = orthonormalize(y);
    let mut residual = f64::INFINITY;
    // Best residual so far and the iteration it last halved.
    let (mut best, mut best_it) = (f64::INFINITY, 0);
    for it in 1..=params.max_iterations {
        let mut z = y.clone();
        problem.apply_inverse(&mut z);
        let (ritz, aritz, lambda) = match ritz_from_pair(&z, &y) {
            Some(t) => t,
            None => {
                // Z Z ill-conditioned: fall back to an orthonormal block and
                // an explicit product with A.
                let q = orthonormalize(z);
                rayleigh_ritz(problem, &q)
            }
        };
        residual = worst_residual(problem, &ritz, &aritz, &lambda, r);
        if residual <= 0.5 * best {
            (best, best_it) = (residual, it);
        }
        let stagnated = residual <= ACCEPT_TOL && it - best_it >= STAGNATION_ITERATIONS;
        if residual <= params.tol || stagnated {
            return Ok((ritz.columns(0, r).into_owned(), lambda[..r].to_vec(), it));
        }
        if !residual.is_finite() && it > 1 {
            break;
        }
        y = ritz;
    }
    Err(ReducedError::NotConverged {
        iterations: params.max_iterations,
        residual,
    })
}

/// Oversampling of the randomized range finder in [`compressed_attachment`].
const RANGE_OVERSAMPLING: usize = 10;
/// Power iterations of the randomized range finder (each sharpens the
/// decay of the singular values it sees by one more power).
const RANGE_POWER_ITERATIONS: usize = 2;

/// A ±1 entry of a fixed pseudo-random test matrix (splitmix64 of the
/// position): the same basis every run, so the cache key stays meaningful.
fn rademacher(i: usize, j: usize) -> f64 {
    let mut z = (i as u64)
        .wrapping_mul(0x9E37_79B9_7F4A_7C15)
        .wrapping_add((j as u64).wrapping_mul(0xD1B5_4A32_D192_ED03))
        .wrapping_add(0x2545_F491_4F6C_DD1D);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    if z & 1 == 0 {
        1.0
    } else {
        -1.0
    }
}

/// Removes from the columns of `x` their components along the orthonormal
/// columns of `y` (twice, for round-off).
fn project_out(y: &DMatrix<f64>, x: &mut DMatrix<f64>) {
    if y.ncols() == 0 {
        return;
    }
    for _ in 0..2 {
        let c = gemm_tn(y, x);
        *x -= gemm_nn(y, &c);
    }
}

/// Orthonormal columns spanning those of `x` (Householder QR).
fn orthonormal(x: DMatrix<f64>) -> DMatrix<f64> {
    x.qr().q()
}

/// The `k` dominant attachment directions of the `dofs` (in y coordinates,
/// their components along the orthonormal columns of `y` removed), scaled by
/// their singular values: the leading left singular vectors of
/// T = (I − Y Yᵀ) A⁻¹ B, B = [M^-½ e_d], by a randomized range finder
/// (Halko, Martinsson & Tropp, SIAM Review 53(2), 2011, Algorithms 4.3 and
/// 5.1): Q = orth((T Tᵀ)^q T Ω) for a ±1 test matrix Ω of k + 10 columns,
/// then the SVD of the small QᵀT. Costs (2q + 2)(k + 10) solves and
/// dofs × (k + 10) memory, where forming T costs one solve per column
/// (3 per contact node) and dofs × 3·contact memory (about 1 GB for 2400
/// contact nodes on the 5832-node arch).
fn compressed_attachment(problem: &FreeProblem, y: &DMatrix<f64>, dofs: &[usize], k: usize) -> DMatrix<f64> {
    let n = problem.dofs();
    let m = 3 * dofs.len();
    let l = (k + RANGE_OVERSAMPLING).min(m);
    // Z = B W for a (3·contact × l) W.
    let spread = |w: &dyn Fn(usize, usize) -> f64| {
        let mut z = DMatrix::zeros(n, l);
        for (a, &d) in dofs.iter().enumerate() {
            for c in 0..3 {
                for j in 0..l {
                    z[(d + c, j)] = w(3 * a + c, j) / problem.sqrt_m[d + c];
                }
            }
        }
        z
    };
    // Bᵀ X: the contact rows of X, scaled.
    let gather = |x: &DMatrix<f64>| {
        DMatrix::from_fn(m, x.ncols(), |i, j| {
            x[(dofs[i / 3] + i % 3, j)] / problem.sqrt_m[dofs[i / 3] + i % 3]
        })
    };
    let mut q = spread(&rademacher);
    problem.apply_inverse(&mut q);
    project_out(y, &mut q);
    let mut q = orthonormal(q);
    for _ in 0..RANGE_POWER_ITERATIONS {
        // Tᵀ Q = Bᵀ A⁻¹ (I − Y Yᵀ) Q = Bᵀ A⁻¹ Q (Q ⟂ Y).
        let mut x = q.clone();
        problem.apply_inverse(&mut x);
        let w = gather(&x);
        let w = orthonormal(w);
        let mut z = spread(&|i, j| w[(i, j)]);
        problem.apply_inverse(&mut z);
        project_out(y, &mut z);
        q = orthonormal(z);
    }
    // C = Qᵀ T = (A⁻¹ Q)ᵀ B (A symmetric, Q ⟂ Y), l × 3·contact.
    let mut x = q.clone();
    problem.apply_inverse(&mut x);
    let c = gather(&x).transpose();
    let svd = c.svd(true, false);
    let u = svd.u.expect("asked for U");
    let mut order: Vec<usize> = (0..svd.singular_values.len()).collect();
    order.sort_by(|&a, &b| svd.singular_values[b].total_cmp(&svd.singular_values[a]));
    let k = k.min(order.len());
    let us = DMatrix::from_fn(u.nrows(), k, |i, j| u[(i, order[j])] * svd.singular_values[order[j]]);
    gemm_nn(&q, &us)
}

/// Adds the attachment directions of the free `contact` nodes to the modes
/// `y` and rotates to Ritz vectors. Returns the basis, its Ritz values and
/// how many attachment directions were kept.
fn augment(
    problem: &FreeProblem,
    y: &DMatrix<f64>,
    contact: &[u32],
    max_static: Option<usize>,
) -> (DMatrix<f64>, Vec<f64>, usize) {
    let mut dofs: Vec<usize> = contact
        .iter()
        .filter_map(|&c| problem.dof_of_node.get(c as usize).copied().flatten())
        .collect();
    dofs.sort_unstable();
    dofs.dedup();
    let att = match max_static {
        Some(k) if k < 3 * dofs.len() => compressed_attachment(problem, y, &dofs, k),
        _ => {
            // A⁻¹ (M^-½ e_d) = M^½ K⁻¹ e_d: the attachment mode K⁻¹ e_d in y
            // coordinates.
            let mut att = DMatrix::zeros(problem.dofs(), 3 * dofs.len());
            for (k, &d) in dofs.iter().enumerate() {
                for c in 0..3 {
                    att[(d + c, 3 * k + c)] = 1.0 / problem.sqrt_m[d + c];
                }
            }
            problem.apply_inverse(&mut att);
            att
        }
    };
    let mut cols: Vec<DVector<f64>> = y.column_iter().map(|c| c.into_owned()).collect();
    let r = cols.len();
    for a in att.column_iter() {
        let mut v = a.into_owned();
        let norm0 = v.norm();
        // Twice is enough (Kahan–Parlett) for classical Gram–Schmidt.
        for _ in 0..2 {
            for c in &cols {
                let d = c.dot(&v);
                v.axpy(-d, c, 1.0);
            }
        }
        let norm = v.norm();
        if norm > 1e-8 * norm0 && norm.is_finite() {
            cols.push(v / norm);
        }
    }
    let kept = cols.len() - r;
    let s = DMatrix::from_columns(&cols);
    let (ritz, _, lambda) = rayleigh_ritz(problem, &s);
    (ritz, lambda, kept)
}
