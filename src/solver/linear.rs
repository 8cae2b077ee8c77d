//! Linear solvers for the Newton system A Δv = b of the implicit step.
//!
//! A is symmetric with the mesh's vertex/edge block pattern ([`BlockTangent`]),
//! and rows/columns of fixed nodes have already been replaced by the identity
//! (see [`project_fixed`]), so both solvers see an SPD matrix whenever the
//! stiffness is positive semi-definite on the free nodes.
//!
//! - [`LinearSolverKind::Cg`]: preconditioned conjugate gradient on the
//!   assembled blocks (row-gather mat-vec, optionally on rayon), with Jacobi,
//!   block-Jacobi or symmetric block Gauss–Seidel (SSOR, ω = 1)
//!   preconditioning. Detects pᵀAp ≤ 0 (negative curvature) as a breakdown.
//! - [`LinearSolverKind::Cholesky`]: faer's supernodal sparse LLᵀ with AMD
//!   ordering; the symbolic analysis is done once for the pattern and the
//!   numeric factorization is redone in place for every new matrix, with all
//!   scratch memory sized at construction.
//!
//! Nothing here knows about time or force models.

use crate::math::Mat3;
use crate::math::Vec3;
use crate::model::BlockTangent;
use faer::dyn_stack::{MemBuffer, MemStack, StackReq};
use faer::linalg::cholesky::llt::factor::LltRegularization;
use faer::sparse::linalg::cholesky::{
    factorize_symbolic_cholesky, CholeskySymbolicParams, LltRef, SymbolicCholesky, SymmetricOrdering,
};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use faer::{Conj, MatMut, Par, Side};
use rayon::prelude::*;

/// Which preconditioner CG uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Preconditioner {
    /// No preconditioning (identity).
    None,
    /// Inverse of the scalar diagonal of A.
    Jacobi,
    /// Inverse of each node's 3×3 diagonal block of A.
    BlockJacobi,
    /// Block incomplete Cholesky with no fill, IC(0), in the form
    /// P = (D̃ + L̃) D̃⁻¹ (D̃ + L̃ᵀ) with L̃ on A's own block pattern. Same
    /// application cost as `block_ssor`, plus a setup of Σ deg² block
    /// products. If a pivot block is not SPD (IC(0) can break down on an SPD
    /// matrix) it retries on A + σ·blockdiag(A) for σ in [`IC0_SHIFTS`].
    BlockIc0,
    /// Symmetric block Gauss–Seidel (block SSOR with ω = 1):
    /// P = (D + L) D⁻¹ (D + U), D the 3×3 diagonal blocks. Costs about two
    /// mat-vecs per application and is sequential, but never breaks down on
    /// an SPD matrix.
    BlockSsor,
}

fn default_cg_tol() -> f64 {
    1e-8
}
fn default_cg_max_iter() -> usize {
    500
}
fn default_precond() -> Preconditioner {
    Preconditioner::BlockSsor
}
fn default_pcg_max_iter() -> usize {
    30
}
fn default_refactor_every() -> usize {
    10
}

/// The linear solver a scene selects (TOML: `linear = { kind = "cg", precond
/// = "block_ssor", tol = 1e-8, max_iter = 500, strict = false }` or
/// `{ kind = "cholesky" }`; CG fields left out take those values).
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize, serde::Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum LinearSolverKind {
    /// Preconditioned conjugate gradient.
    Cg {
        /// Preconditioner.
        #[serde(default = "default_precond")]
        precond: Preconditioner,
        /// Relative residual tolerance ‖b − A x‖ ≤ tol ‖b‖.
        #[serde(default = "default_cg_tol")]
        tol: f64,
        /// Maximum CG iterations per solve.
        #[serde(default = "default_cg_max_iter")]
        max_iter: usize,
        /// If true, not reaching `tol` within `max_iter` fails the step; if
        /// false the last iterate is used (inexact Newton) and the Newton
        /// residual decides.
        #[serde(default)]
        strict: bool,
    },
    /// Direct sparse Cholesky (faer, supernodal, AMD ordering). The default:
    /// on the arch meshes measured (up to 17k DOF) it is 3–10× faster per
    /// Newton iteration than the best PCG (`docs/SOLVERS.md`).
    #[default]
    Cholesky,
    /// CG on the current matrix, preconditioned by the sparse Cholesky factor
    /// of an earlier one: refactored every `refactor_every` solves, and at
    /// once whenever CG misses `tol` within `max_iter` or breaks down (so a
    /// solve never ends worse than CG's tolerance because the factor is
    /// stale). Solves to `tol` like CG; amortises the factorization.
    CholeskyPcg {
        /// Relative residual tolerance ‖b − A x‖ ≤ tol ‖b‖.
        #[serde(default = "default_cg_tol")]
        tol: f64,
        /// CG iterations tried with a lagged factor before refactoring.
        #[serde(default = "default_pcg_max_iter")]
        max_iter: usize,
        /// Refactor after this many solves (1: every solve, i.e. Cholesky
        /// followed by a residual check).
        #[serde(default = "default_refactor_every")]
        refactor_every: usize,
        /// Keep the factor in single precision (`f32`): it only
        /// preconditions, so the solve still reaches `tol` in `f64`, and
        /// the factorization and triangular solves move half the memory
        /// (1.3–1.5× faster at 23k nodes; `docs/SOLVERS.md`).
        #[serde(default)]
        factor_f32: bool,
    },
}

impl LinearSolverKind {
    /// Checks the parameters; the error names the offending field.
    pub fn validate(&self) -> Result<(), String> {
        if let LinearSolverKind::Cg { tol, max_iter, .. } = *self {
            if !(tol.is_finite() && tol > 0.0 && tol < 1.0) {
                return Err(format!("linear.tol = {tol}: must be in (0, 1)"));
            }
            if max_iter == 0 {
                return Err("linear.max_iter = 0: must be at least 1".into());
            }
        }
        if let LinearSolverKind::CholeskyPcg {
            tol,
            max_iter,
            refactor_every,
            ..
        } = *self
        {
            if !(tol.is_finite() && tol > 0.0 && tol < 1.0) {
                return Err(format!("linear.tol = {tol}: must be in (0, 1)"));
            }
            if max_iter == 0 {
                return Err("linear.max_iter = 0: must be at least 1".into());
            }
            if refactor_every == 0 {
                return Err("linear.refactor_every = 0: must be at least 1".into());
            }
        }
        Ok(())
    }
}

/// Why a linear solve failed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LinearFailure {
    /// CG found pᵀAp ≤ 0 (A not positive definite) or a non-finite value at
    /// this iteration.
    CgBreakdown {
        /// CG iteration (0-based) where it happened.
        iter: usize,
    },
    /// CG did not reach its tolerance within `max_iter` (only with `strict`).
    CgNotConverged {
        /// Iterations done.
        iters: usize,
        /// Final relative residual.
        rel_residual: f64,
    },
    /// A diagonal block could not be inverted for the preconditioner.
    SingularDiagonal {
        /// Node whose block is singular or non-finite.
        node: usize,
    },
    /// The sparse Cholesky factorization found a non-positive pivot.
    NotPositiveDefinite,
    /// The solution contains a non-finite value.
    NonFinite,
}

impl std::fmt::Display for LinearFailure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            LinearFailure::CgBreakdown { iter } => {
                write!(f, "CG breakdown at iteration {iter} (pᵀAp ≤ 0 or non-finite)")
            }
            LinearFailure::CgNotConverged { iters, rel_residual } => {
                write!(
                    f,
                    "CG not converged after {iters} iterations (relative residual {rel_residual:e})"
                )
            }
            LinearFailure::SingularDiagonal { node } => write!(f, "diagonal block of node {node} is singular"),
            LinearFailure::NotPositiveDefinite => write!(f, "Cholesky: matrix is not positive definite"),
            LinearFailure::NonFinite => write!(f, "linear solution is not finite"),
        }
    }
}

/// What one linear solve did.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SolveStats {
    /// CG iterations (0 for Cholesky).
    pub iters: usize,
    /// Final relative residual ‖b − A x‖ / ‖b‖ as CG measured it (0 for
    /// Cholesky, which does not compute it).
    pub rel_residual: f64,
    /// Whether CG reached its tolerance (always true for Cholesky).
    pub converged: bool,
}

/// Replaces the rows and columns of the fixed nodes by the identity:
/// diagonal block I, every edge block touching a fixed node zero.
pub fn project_fixed(a: &mut BlockTangent, fixed_mask: &[bool]) {
    for (d, &f) in a.diag.iter_mut().zip(fixed_mask) {
        if f {
            *d = Mat3::identity();
        }
    }
    for (b, &[i, j]) in a.off.iter_mut().zip(&a.edges) {
        if fixed_mask[i as usize] || fixed_mask[j as usize] {
            *b = Mat3::zeros();
        }
    }
}

/// A row's neighbours (node, edge).
type Nbrs<'a> = &'a [(u32, u32)];

/// Row-wise view of a [`BlockTangent`] pattern: for each node its neighbours
/// sorted by index with the edge joining them, so a row can be gathered
/// without scattering (parallel mat-vec, Gauss–Seidel sweeps).
#[derive(Debug, Clone)]
pub struct BlockRows {
    start: Vec<u32>,
    /// Index into `nbr` of the first neighbour with a higher index, per row.
    mid: Vec<u32>,
    nbr: Vec<(u32, u32)>,
}

impl BlockRows {
    /// Builds the row structure of `edges` over `n` nodes.
    pub fn new(n: usize, edges: &[[u32; 2]]) -> BlockRows {
        let mut count = vec![0u32; n + 1];
        for &[i, j] in edges {
            count[i as usize + 1] += 1;
            count[j as usize + 1] += 1;
        }
        for k in 0..n {
            count[k + 1] += count[k];
        }
        let start = count.clone();
        let mut fill = count;
        let mut nbr = vec![(0u32, 0u32); start[n] as usize];
        for (e, &[i, j]) in edges.iter().enumerate() {
            nbr[fill[i as usize] as usize] = (j, e as u32);
            fill[i as usize] += 1;
            nbr[fill[j as usize] as usize] = (i, e as u32);
            fill[j as usize] += 1;
        }
        let mut mid = vec![0u32; n];
        for i in 0..n {
            let row = &mut nbr[start[i] as usize..start[i + 1] as usize];
            row.sort_unstable();
            mid[i] = start[i] + row.partition_point(|&(j, _)| (j as usize) < i) as u32;
        }
        BlockRows { start, mid, nbr }
    }

    /// Neighbours of row i with a lower index, and with a higher index.
    #[inline]
    fn split(&self, i: usize) -> (Nbrs<'_>, Nbrs<'_>) {
        let (s, m, e) = (self.start[i] as usize, self.mid[i] as usize, self.start[i + 1] as usize);
        (&self.nbr[s..m], &self.nbr[m..e])
    }

    /// Row i of A x.
    #[inline]
    fn row_mul(&self, a: &BlockTangent, x: &[Vec3], i: usize) -> Vec3 {
        let (lo, hi) = self.split(i);
        let mut y = a.diag[i] * x[i];
        for &(j, e) in lo {
            y += a.off[e as usize].tr_mul(&x[j as usize]);
        }
        for &(j, e) in hi {
            y += a.off[e as usize] * x[j as usize];
        }
        y
    }

    /// y = A x by row gather; on rayon when `parallel`.
    pub fn mul(&self, a: &BlockTangent, x: &[Vec3], y: &mut [Vec3], parallel: bool) {
        if parallel {
            y.par_chunks_mut(512).enumerate().for_each(|(c, ys)| {
                for (k, yi) in ys.iter_mut().enumerate() {
                    *yi = self.row_mul(a, x, c * 512 + k);
                }
            });
        } else {
            for (i, yi) in y.iter_mut().enumerate() {
                *yi = self.row_mul(a, x, i);
            }
        }
    }
}

fn dot(a: &[Vec3], b: &[Vec3]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x.dot(y)).sum()
}

fn norm(a: &[Vec3]) -> f64 {
    dot(a, a).sqrt()
}

/// y = A x: serial edge scatter (each off-diagonal block read once, the
/// fastest serial form) or rayon row gather (each block read twice).
fn matvec(rows: &BlockRows, a: &BlockTangent, x: &[Vec3], y: &mut [Vec3], parallel: bool) {
    if parallel {
        rows.mul(a, x, y, true);
    } else {
        a.mul(x, y);
    }
}

/// z = P⁻¹ r for the preconditioner `precond` with the diagonal block
/// inverses `dinv`.
fn apply_precond(
    precond: Preconditioner,
    rows: &BlockRows,
    dinv: &[Mat3],
    ic: &[Mat3],
    a: &BlockTangent,
    r: &[Vec3],
    z: &mut [Vec3],
) {
    match precond {
        Preconditioner::None => z.copy_from_slice(r),
        Preconditioner::Jacobi | Preconditioner::BlockJacobi => {
            for ((zi, ri), di) in z.iter_mut().zip(r).zip(dinv) {
                *zi = di * ri;
            }
        }
        Preconditioner::BlockSsor | Preconditioner::BlockIc0 => {
            // SSOR uses A's own blocks and diagonal, IC(0) its factor's
            // (both in upper form: block (low, high) per edge).
            let up = if precond == Preconditioner::BlockIc0 {
                ic
            } else {
                &a.off[..]
            };
            // Forward: (D + L) y = r.
            for i in 0..z.len() {
                let (lo, _) = rows.split(i);
                let mut s = r[i];
                for &(j, e) in lo {
                    s -= up[e as usize].tr_mul(&z[j as usize]);
                }
                z[i] = dinv[i] * s;
            }
            // Backward: (D + U) z = D y, i.e. z_i = y_i − D_i⁻¹ Σ_{j>i} A_ij z_j.
            for i in (0..z.len()).rev() {
                let (_, hi) = rows.split(i);
                let mut s = Vec3::zeros();
                for &(j, e) in hi {
                    s += up[e as usize] * z[j as usize];
                }
                z[i] -= dinv[i] * s;
            }
        }
    }
}

/// Diagonal shifts σ tried in turn by the IC(0) preconditioner.
pub const IC0_SHIFTS: [f64; 6] = [0.0, 1e-3, 1e-2, 0.05, 0.2, 1.0];

/// Block IC(0) of A + σ·blockdiag(A) in upper form (see
/// [`Preconditioner::BlockIc0`]); on a non-SPD pivot returns its node.
fn ic0_factor(a: &BlockTangent, rows: &BlockRows, shift: f64, ic: &mut [Mat3], dinv: &mut [Mat3]) -> Result<(), usize> {
    for i in 0..a.num_nodes() {
        let (lo_i, _) = rows.split(i);
        // U_(k,i) = A_ki − Σ_{j<k, j~i, j~k} U_(j,k)ᵀ D̃_j⁻¹ U_(j,i).
        for (pos, &(k, e_ki)) in lo_i.iter().enumerate() {
            let (lo_k, _) = rows.split(k as usize);
            let mut u = a.off[e_ki as usize];
            let (mut p, mut q) = (0, 0);
            while p < pos && q < lo_k.len() {
                let (ji, e_ji) = lo_i[p];
                let (jk, e_jk) = lo_k[q];
                if ji < jk {
                    p += 1;
                } else if jk < ji {
                    q += 1;
                } else {
                    u -= ic[e_jk as usize].transpose() * dinv[ji as usize] * ic[e_ji as usize];
                    p += 1;
                    q += 1;
                }
            }
            ic[e_ki as usize] = u;
        }
        // D̃_i = (1 + σ) A_ii − Σ_{j<i} U_(j,i)ᵀ D̃_j⁻¹ U_(j,i).
        let mut d = a.diag[i] * (1.0 + shift);
        for &(j, e) in lo_i {
            let u = &ic[e as usize];
            d -= u.transpose() * dinv[j as usize] * u;
        }
        match d.cholesky() {
            Some(c) if c.l_dirty().iter().all(|x| x.is_finite()) => dinv[i] = c.inverse(),
            _ => return Err(i),
        }
    }
    Ok(())
}

/// Preconditioned CG with its preallocated work vectors.
#[derive(Debug, Clone)]
pub struct Cg {
    precond: Preconditioner,
    tol: f64,
    max_iter: usize,
    strict: bool,
    /// Use the rayon row-gather mat-vec instead of the serial edge-scatter
    /// one. Off by default: on the 2-core machine, shared, it did not pay
    /// (`docs/SOLVERS.md`).
    pub parallel: bool,
    rows: BlockRows,
    dinv: Vec<Mat3>,
    /// IC(0) factor blocks in upper form (block (low, high) of L̃ᵀ per edge);
    /// empty unless the preconditioner is `block_ic0`.
    ic: Vec<Mat3>,
    ic0_shift: f64,
    r: Vec<Vec3>,
    z: Vec<Vec3>,
    p: Vec<Vec3>,
    q: Vec<Vec3>,
}

impl Cg {
    /// A CG solver for matrices with the pattern of `pattern` (n nodes).
    pub fn new(pattern: &BlockTangent, precond: Preconditioner, tol: f64, max_iter: usize, strict: bool) -> Cg {
        let n = pattern.num_nodes();
        Cg {
            precond,
            tol,
            max_iter,
            strict,
            parallel: false,
            rows: BlockRows::new(n, &pattern.edges),
            dinv: vec![Mat3::zeros(); n],
            ic: if precond == Preconditioner::BlockIc0 {
                vec![Mat3::zeros(); pattern.edges.len()]
            } else {
                Vec::new()
            },
            ic0_shift: 0.0,
            r: vec![Vec3::zeros(); n],
            z: vec![Vec3::zeros(); n],
            p: vec![Vec3::zeros(); n],
            q: vec![Vec3::zeros(); n],
        }
    }

    /// The diagonal shift σ the last IC(0) setup needed (0 if none).
    pub fn ic0_shift(&self) -> f64 {
        self.ic0_shift
    }

    fn setup(&mut self, a: &BlockTangent) -> Result<(), LinearFailure> {
        match self.precond {
            Preconditioner::None => {}
            Preconditioner::Jacobi => {
                for (i, (di, d)) in self.dinv.iter_mut().zip(&a.diag).enumerate() {
                    *di = Mat3::zeros();
                    for k in 0..3 {
                        let v = d[(k, k)];
                        if !(v.is_finite() && v > 0.0) {
                            return Err(LinearFailure::SingularDiagonal { node: i });
                        }
                        di[(k, k)] = 1.0 / v;
                    }
                }
            }
            Preconditioner::BlockIc0 => {
                // Manteuffel's shift: if a pivot block is not SPD, factor
                // A + σ·blockdiag(A) instead, with growing σ.
                let mut last = 0;
                for shift in IC0_SHIFTS {
                    match ic0_factor(a, &self.rows, shift, &mut self.ic, &mut self.dinv) {
                        Ok(()) => {
                            self.ic0_shift = shift;
                            return Ok(());
                        }
                        Err(node) => last = node,
                    }
                }
                return Err(LinearFailure::SingularDiagonal { node: last });
            }
            Preconditioner::BlockJacobi | Preconditioner::BlockSsor => {
                for (i, (di, d)) in self.dinv.iter_mut().zip(&a.diag).enumerate() {
                    // Cholesky of the block: it must be SPD for the
                    // preconditioner to be (and it is when A is).
                    match d.cholesky() {
                        Some(c) if c.l_dirty().iter().all(|x| x.is_finite()) => *di = c.inverse(),
                        _ => return Err(LinearFailure::SingularDiagonal { node: i }),
                    }
                }
            }
        }
        Ok(())
    }

    /// Solves A x = b starting from the content of `x` (warm start). A zero
    /// b gives x = 0. A warm start worse than zero is replaced by zero.
    pub fn solve(&mut self, a: &BlockTangent, b: &[Vec3], x: &mut [Vec3]) -> Result<SolveStats, LinearFailure> {
        self.setup(a)?;
        self.solve_prepared(a, b, x)
    }

    /// Builds the preconditioner for A (what [`Cg::solve`] does first).
    pub fn prepare(&mut self, a: &BlockTangent) -> Result<(), LinearFailure> {
        self.setup(a)
    }

    /// Solves A x = b with the preconditioner of the last [`Cg::prepare`]
    /// (built for A or for an earlier matrix with the same pattern).
    pub fn solve_prepared(
        &mut self,
        a: &BlockTangent,
        b: &[Vec3],
        x: &mut [Vec3],
    ) -> Result<SolveStats, LinearFailure> {
        let bnorm = match rhs_norm(b, x) {
            Ok(n) => n,
            Err(done) => return done,
        };
        let Cg {
            precond,
            tol,
            max_iter,
            strict,
            parallel,
            rows,
            dinv,
            ic,
            r,
            z,
            p,
            q,
            ..
        } = self;
        let (precond, parallel) = (*precond, *parallel);
        matvec(rows, a, x, q, parallel);
        for ((ri, bi), qi) in r.iter_mut().zip(b).zip(q.iter()) {
            *ri = bi - qi;
        }
        let mut rnorm = norm(r);
        if !(rnorm.is_finite() && rnorm <= bnorm) {
            x.iter_mut().for_each(|v| *v = Vec3::zeros());
            r.copy_from_slice(b);
            rnorm = bnorm;
        }
        let goal = *tol * bnorm;
        let precond = |r: &[Vec3], z: &mut [Vec3]| apply_precond(precond, rows, dinv, ic, a, r, z);
        precond(r, z);
        p.copy_from_slice(z);
        let mut rz = dot(r, z);
        let mut iters = 0;
        while rnorm > goal && iters < *max_iter {
            matvec(rows, a, p, q, parallel);
            let pq = dot(p, q);
            if !(pq.is_finite() && pq > 0.0 && rz.is_finite() && rz > 0.0) {
                return Err(LinearFailure::CgBreakdown { iter: iters });
            }
            let alpha = rz / pq;
            for ((xi, ri), (pi, qi)) in x.iter_mut().zip(r.iter_mut()).zip(p.iter().zip(q.iter())) {
                *xi += alpha * pi;
                *ri -= alpha * qi;
            }
            rnorm = norm(r);
            iters += 1;
            if rnorm <= goal {
                break;
            }
            precond(r, z);
            let rz_new = dot(r, z);
            let beta = rz_new / rz;
            rz = rz_new;
            for (pi, zi) in p.iter_mut().zip(z.iter()) {
                *pi = zi + beta * *pi;
            }
        }
        if !rnorm.is_finite() || x.iter().any(|v| !v.iter().all(|c| c.is_finite())) {
            return Err(LinearFailure::NonFinite);
        }
        let converged = rnorm <= goal;
        if !converged && *strict {
            return Err(LinearFailure::CgNotConverged {
                iters,
                rel_residual: rnorm / bnorm,
            });
        }
        Ok(SolveStats {
            iters,
            rel_residual: rnorm / bnorm,
            converged,
        })
    }
}

/// Sparse Cholesky A = L Lᵀ with faer (supernodal, AMD ordering). The lower
/// triangle of A in compressed-column form, the symbolic factorization, the
/// factor values and all scratch memory are built once for the pattern;
/// [`CholeskySolver::solve`] refills the values, refactors and solves
/// without allocating.
pub struct CholeskySolver<T: FactorScalar = f64> {
    rows: BlockRows,
    col_ptr: Vec<usize>,
    row_idx: Vec<usize>,
    values: Vec<T>,
    symbolic: SymbolicCholesky<usize>,
    l_values: Vec<T>,
    rhs: Vec<T>,
    scratch: MemBuffer,
    par: Par,
    /// Whether `l_values` holds a valid factor.
    factored: bool,
}

/// Scalar of a Cholesky factor: `f64`, or `f32` for a factor used only as
/// a preconditioner (half the memory traffic; the CG around it still
/// iterates in `f64`).
pub trait FactorScalar: faer::traits::RealField + Copy + Send + Sync + 'static {
    /// Rounds an `f64` to this type.
    fn of_f64(x: f64) -> Self;
    /// Widens to `f64`.
    fn to_f64(self) -> f64;
    /// Whether the value is finite.
    fn finite(self) -> bool {
        self.to_f64().is_finite()
    }
}

impl FactorScalar for f64 {
    fn of_f64(x: f64) -> f64 {
        x
    }
    fn to_f64(self) -> f64 {
        self
    }
}

impl FactorScalar for f32 {
    fn of_f64(x: f64) -> f32 {
        x as f32
    }
    fn to_f64(self) -> f64 {
        self as f64
    }
}

impl<T: FactorScalar> std::fmt::Debug for CholeskySolver<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CholeskySolver")
            .field("dofs", &self.rhs.len())
            .field("nnz_lower", &self.values.len())
            .field("nnz_factor", &self.l_values.len())
            .finish()
    }
}

impl CholeskySolver<f64> {
    /// Symbolic analysis for matrices with the pattern of `pattern`, for an
    /// `f64` factor ([`CholeskySolver::for_pattern`] picks the scalar).
    pub fn new(pattern: &BlockTangent) -> Result<CholeskySolver<f64>, String> {
        CholeskySolver::for_pattern(pattern)
    }
}

impl<T: FactorScalar> CholeskySolver<T> {
    /// Symbolic analysis for matrices with the pattern of `pattern`.
    pub fn for_pattern(pattern: &BlockTangent) -> Result<CholeskySolver<T>, String> {
        let n = pattern.num_nodes();
        let rows = BlockRows::new(n, &pattern.edges);
        let dofs = 3 * n;
        // Column 3a+c holds rows 3a+r (r ≥ c) of the diagonal block, then
        // rows 3b+r of each higher neighbour b, in increasing order.
        let mut col_ptr = Vec::with_capacity(dofs + 1);
        let mut row_idx = Vec::new();
        col_ptr.push(0);
        for a in 0..n {
            let (_, hi) = rows.split(a);
            for c in 0..3 {
                for r in c..3 {
                    row_idx.push(3 * a + r);
                }
                for &(b, _) in hi {
                    for r in 0..3 {
                        row_idx.push(3 * b as usize + r);
                    }
                }
                col_ptr.push(row_idx.len());
            }
        }
        let values = vec![T::of_f64(0.0); row_idx.len()];
        let sym = SymbolicSparseColMatRef::new_checked(dofs, dofs, &col_ptr, None, &row_idx);
        let symbolic = factorize_symbolic_cholesky(
            sym,
            Side::Lower,
            SymmetricOrdering::Amd,
            CholeskySymbolicParams::default(),
        )
        .map_err(|e| format!("sparse Cholesky symbolic analysis failed: {e:?}"))?;
        let par = Par::Seq;
        // Sized for both the sequential and the rayon path (`set_par`).
        let rayon = Par::rayon(0);
        let req = StackReq::any_of(&[
            symbolic.factorize_numeric_llt_scratch::<T>(par, Default::default()),
            symbolic.solve_in_place_scratch::<T>(1, par),
            symbolic.factorize_numeric_llt_scratch::<T>(rayon, Default::default()),
            symbolic.solve_in_place_scratch::<T>(1, rayon),
        ]);
        let scratch = MemBuffer::try_new(req).map_err(|_| "sparse Cholesky: out of memory for scratch".to_string())?;
        let l_values = vec![T::of_f64(0.0); symbolic.len_val()];
        Ok(CholeskySolver {
            rows,
            col_ptr,
            row_idx,
            values,
            symbolic,
            l_values,
            rhs: vec![T::of_f64(0.0); dofs],
            scratch,
            par,
            factored: false,
        })
    }

    /// Runs the factorization and solves on rayon (`true`) or on the calling
    /// thread only (`false`, the default: allocation-free and, on the
    /// shared 2-core machine, not slower; `docs/BENCHMARKS.md`).
    pub fn set_parallel(&mut self, parallel: bool) {
        self.par = if parallel { Par::rayon(0) } else { Par::Seq };
    }

    /// Number of stored entries of the factor L.
    pub fn factor_nnz(&self) -> usize {
        self.l_values.len()
    }

    fn fill(&mut self, a: &BlockTangent) {
        let mut k = 0;
        for (i, d) in a.diag.iter().enumerate() {
            let (_, hi) = self.rows.split(i);
            for c in 0..3 {
                for r in c..3 {
                    self.values[k] = T::of_f64(d[(r, c)]);
                    k += 1;
                }
                for &(_, e) in hi {
                    // Block (b, a) = off[e]ᵀ, so entry (r, c) is off[e][(c, r)].
                    let o = &a.off[e as usize];
                    for r in 0..3 {
                        self.values[k] = T::of_f64(o[(c, r)]);
                        k += 1;
                    }
                }
            }
        }
    }

    /// Factors A (lower triangle read) and solves A x = b.
    pub fn solve(&mut self, a: &BlockTangent, b: &[Vec3], x: &mut [Vec3]) -> Result<SolveStats, LinearFailure> {
        self.factor(a)?;
        self.solve_factored(b, x)
    }

    /// Factors A (lower triangle read) in place, for [`CholeskySolver::solve_factored`].
    pub fn factor(&mut self, a: &BlockTangent) -> Result<(), LinearFailure> {
        self.factored = false;
        self.fill(a);
        if self.values.iter().any(|v| !v.finite()) {
            return Err(LinearFailure::NonFinite);
        }
        let dofs = self.rhs.len();
        let sym = SymbolicSparseColMatRef::new_checked(dofs, dofs, &self.col_ptr, None, &self.row_idx);
        let mat = SparseColMatRef::new(sym, &self.values);
        let stack = MemStack::new(&mut self.scratch);
        self.symbolic
            .factorize_numeric_llt::<T>(
                &mut self.l_values,
                mat,
                Side::Lower,
                LltRegularization::default(),
                self.par,
                stack,
                Default::default(),
            )
            .map_err(|_| LinearFailure::NotPositiveDefinite)?;
        self.factored = true;
        Ok(())
    }

    /// Solves A x = b with the factor of the last successful
    /// [`CholeskySolver::factor`] (triangular solves only).
    pub fn solve_factored(&mut self, b: &[Vec3], x: &mut [Vec3]) -> Result<SolveStats, LinearFailure> {
        if !self.factored {
            return Err(LinearFailure::NotPositiveDefinite);
        }
        let dofs = self.rhs.len();
        for (i, bi) in b.iter().enumerate() {
            for c in 0..3 {
                self.rhs[3 * i + c] = T::of_f64(bi[c]);
            }
        }
        let llt = LltRef::new(&self.symbolic, &self.l_values);
        let rhs = MatMut::from_column_major_slice_mut(&mut self.rhs, dofs, 1);
        llt.solve_in_place_with_conj(Conj::No, rhs, self.par, MemStack::new(&mut self.scratch));
        if self.rhs.iter().any(|v| !v.finite()) {
            return Err(LinearFailure::NonFinite);
        }
        for (i, xi) in x.iter_mut().enumerate() {
            *xi = Vec3::new(
                self.rhs[3 * i].to_f64(),
                self.rhs[3 * i + 1].to_f64(),
                self.rhs[3 * i + 2].to_f64(),
            );
        }
        Ok(SolveStats {
            iters: 0,
            rel_residual: 0.0,
            converged: true,
        })
    }
}

/// CG preconditioned by a lagged sparse Cholesky factor
/// ([`LinearSolverKind::CholeskyPcg`]).
#[derive(Debug)]
pub struct CholeskyPcg {
    chol: PcgFactor,
    tol: f64,
    max_iter: usize,
    refactor_every: usize,
    /// Solves since the last factorization; `None` when there is no factor.
    age: Option<usize>,
    r: Vec<Vec3>,
    z: Vec<Vec3>,
    p: Vec<Vec3>,
    q: Vec<Vec3>,
}

/// The preconditioning factor of [`CholeskyPcg`], in either precision.
#[derive(Debug)]
enum PcgFactor {
    F64(CholeskySolver<f64>),
    F32(CholeskySolver<f32>),
}

impl PcgFactor {
    /// Factors `a`. An `f32` factorization that meets a non-positive pivot
    /// (A too ill-conditioned for single precision) switches this solver to
    /// `f64` for good — one allocation, on the solver's own thread — so it
    /// fails only where the `f64` factor fails too.
    fn factor(&mut self, a: &BlockTangent) -> Result<(), LinearFailure> {
        match self {
            PcgFactor::F64(c) => c.factor(a),
            PcgFactor::F32(c) => match c.factor(a) {
                Err(LinearFailure::NotPositiveDefinite) => {
                    let mut wide = CholeskySolver::new(a).map_err(|_| LinearFailure::NotPositiveDefinite)?;
                    let out = wide.factor(a);
                    *self = PcgFactor::F64(wide);
                    out
                }
                other => other,
            },
        }
    }

    fn is_f32(&self) -> bool {
        matches!(self, PcgFactor::F32(_))
    }

    fn solve_factored(&mut self, b: &[Vec3], x: &mut [Vec3]) -> Result<SolveStats, LinearFailure> {
        match self {
            PcgFactor::F64(c) => c.solve_factored(b, x),
            PcgFactor::F32(c) => c.solve_factored(b, x),
        }
    }
}

impl CholeskyPcg {
    /// Symbolic analysis for matrices with the pattern of `pattern`; the
    /// factor is kept in `f32` when `factor_f32`.
    pub fn new(
        pattern: &BlockTangent,
        tol: f64,
        max_iter: usize,
        refactor_every: usize,
        factor_f32: bool,
    ) -> Result<CholeskyPcg, String> {
        let n = pattern.num_nodes();
        let chol = if factor_f32 {
            PcgFactor::F32(CholeskySolver::for_pattern(pattern)?)
        } else {
            PcgFactor::F64(CholeskySolver::new(pattern)?)
        };
        Ok(CholeskyPcg {
            chol,
            tol,
            max_iter,
            refactor_every,
            age: None,
            r: vec![Vec3::zeros(); n],
            z: vec![Vec3::zeros(); n],
            p: vec![Vec3::zeros(); n],
            q: vec![Vec3::zeros(); n],
        })
    }

    /// Whether the factor is held in `f32` (false after a fallback to `f64`).
    pub fn factor_is_f32(&self) -> bool {
        self.chol.is_f32()
    }

    /// Factors `a` now (the next solves use this factor).
    pub fn factor(&mut self, a: &BlockTangent) -> Result<(), LinearFailure> {
        self.age = None;
        self.chol.factor(a)?;
        self.age = Some(0);
        Ok(())
    }

    /// Solves A x = b (warm start in `x`) by PCG with the current factor,
    /// refactoring first when it is `refactor_every` solves old, and once
    /// more with `a` if CG misses the tolerance.
    pub fn solve(&mut self, a: &BlockTangent, b: &[Vec3], x: &mut [Vec3]) -> Result<SolveStats, LinearFailure> {
        let fresh = match self.age {
            Some(k) if k < self.refactor_every => false,
            _ => {
                self.factor(a)?;
                true
            }
        };
        let first = self.pcg(a, b, x);
        let out = match first {
            Ok(s) if s.converged || fresh => Ok(s),
            _ if !fresh => {
                // The lagged factor no longer preconditions well enough.
                self.factor(a)?;
                x.iter_mut().for_each(|v| *v = Vec3::zeros());
                self.pcg(a, b, x).map(|s| SolveStats {
                    iters: s.iters + first.map(|f| f.iters).unwrap_or(0),
                    ..s
                })
            }
            other => other,
        };
        if let Some(k) = self.age.as_mut() {
            *k += 1;
        }
        out
    }

    fn pcg(&mut self, a: &BlockTangent, b: &[Vec3], x: &mut [Vec3]) -> Result<SolveStats, LinearFailure> {
        let bnorm = match rhs_norm(b, x) {
            Ok(n) => n,
            Err(done) => return done,
        };
        let CholeskyPcg {
            chol,
            tol,
            max_iter,
            r,
            z,
            p,
            q,
            ..
        } = self;
        a.mul(x, q);
        for ((ri, bi), qi) in r.iter_mut().zip(b).zip(q.iter()) {
            *ri = bi - qi;
        }
        let mut rnorm = norm(r);
        if !(rnorm.is_finite() && rnorm <= bnorm) {
            x.iter_mut().for_each(|v| *v = Vec3::zeros());
            r.copy_from_slice(b);
            rnorm = bnorm;
        }
        let goal = *tol * bnorm;
        let mut iters = 0;
        if rnorm > goal {
            chol.solve_factored(r, z)?;
            p.copy_from_slice(z);
            let mut rz = dot(r, z);
            while iters < *max_iter {
                a.mul(p, q);
                let pq = dot(p, q);
                if !(pq.is_finite() && pq > 0.0 && rz.is_finite() && rz > 0.0) {
                    return Err(LinearFailure::CgBreakdown { iter: iters });
                }
                let alpha = rz / pq;
                for ((xi, ri), (pi, qi)) in x.iter_mut().zip(r.iter_mut()).zip(p.iter().zip(q.iter())) {
                    *xi += alpha * pi;
                    *ri -= alpha * qi;
                }
                rnorm = norm(r);
                iters += 1;
                if rnorm <= goal {
                    break;
                }
                chol.solve_factored(r, z)?;
                let rz_new = dot(r, z);
                let beta = rz_new / rz;
                rz = rz_new;
                for (pi, zi) in p.iter_mut().zip(z.iter()) {
                    *pi = zi + beta * *pi;
                }
            }
        }
        if !rnorm.is_finite() || x.iter().any(|v| !v.iter().all(|c| c.is_finite())) {
            return Err(LinearFailure::NonFinite);
        }
        Ok(SolveStats {
            iters,
            rel_residual: rnorm / bnorm,
            converged: rnorm <= goal,
        })
    }
}

/// A linear solver built for one pattern, as selected by [`LinearSolverKind`].
#[derive(Debug)]
pub enum LinearSolver {
    /// Preconditioned CG.
    Cg(Box<Cg>),
    /// Sparse Cholesky.
    Cholesky(Box<CholeskySolver>),
    /// CG preconditioned by a lagged sparse Cholesky factor.
    CholeskyPcg(Box<CholeskyPcg>),
}

impl LinearSolver {
    /// Builds the solver (and, for Cholesky, the symbolic analysis).
    pub fn new(kind: &LinearSolverKind, pattern: &BlockTangent) -> Result<LinearSolver, String> {
        kind.validate()?;
        Ok(match *kind {
            LinearSolverKind::Cg {
                precond,
                tol,
                max_iter,
                strict,
            } => LinearSolver::Cg(Box::new(Cg::new(pattern, precond, tol, max_iter, strict))),
            LinearSolverKind::Cholesky => LinearSolver::Cholesky(Box::new(CholeskySolver::new(pattern)?)),
            LinearSolverKind::CholeskyPcg {
                tol,
                max_iter,
                refactor_every,
                factor_f32,
            } => LinearSolver::CholeskyPcg(Box::new(CholeskyPcg::new(
                pattern,
                tol,
                max_iter,
                refactor_every,
                factor_f32,
            )?)),
        })
    }

    /// Solves A x = b; `x` holds the warm start for CG (ignored by Cholesky).
    pub fn solve(&mut self, a: &BlockTangent, b: &[Vec3], x: &mut [Vec3]) -> Result<SolveStats, LinearFailure> {
        match self {
            LinearSolver::Cg(cg) => cg.solve(a, b, x),
            LinearSolver::Cholesky(ch) => ch.solve(a, b, x),
            LinearSolver::CholeskyPcg(cp) => cp.solve(a, b, x),
        }
    }

    /// Builds what depends on the matrix values only (CG: the
    /// preconditioner; Cholesky: the numeric factorization), so that several
    /// [`LinearSolver::solve_prepared`] calls can reuse it.
    pub fn prepare(&mut self, a: &BlockTangent) -> Result<(), LinearFailure> {
        match self {
            LinearSolver::Cg(cg) => cg.prepare(a),
            LinearSolver::Cholesky(ch) => ch.factor(a),
            LinearSolver::CholeskyPcg(cp) => cp.factor(a),
        }
    }

    /// Solves A x = b reusing the last [`LinearSolver::prepare`]. CG iterates
    /// on `a` itself (preconditioned by what was prepared, possibly for an
    /// earlier matrix); Cholesky solves with the prepared factor and ignores
    /// `a`, so `a` must be the prepared matrix for an exact solve.
    pub fn solve_prepared(
        &mut self,
        a: &BlockTangent,
        b: &[Vec3],
        x: &mut [Vec3],
    ) -> Result<SolveStats, LinearFailure> {
        match self {
            LinearSolver::Cg(cg) => cg.solve_prepared(a, b, x),
            LinearSolver::Cholesky(ch) => ch.solve_factored(b, x),
            LinearSolver::CholeskyPcg(cp) => cp.solve(a, b, x),
        }
    }
}

/// ‖b‖ for a CG solve, or the finished answer when there is nothing to solve:
/// a non-finite b fails, a zero b gives x = 0 at once.
fn rhs_norm(b: &[Vec3], x: &mut [Vec3]) -> Result<f64, Result<SolveStats, LinearFailure>> {
    let bnorm = norm(b);
    if !bnorm.is_finite() {
        return Err(Err(LinearFailure::NonFinite));
    }
    if bnorm == 0.0 {
        x.iter_mut().for_each(|v| *v = Vec3::zeros());
        return Err(Ok(SolveStats {
            iters: 0,
            rel_residual: 0.0,
            converged: true,
        }));
    }
    Ok(bnorm)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn f32_factor_falls_back_to_f64_when_single_precision_is_singular() {
        // Two nodes coupled by 1 − 1e-10: SPD in f64 (smallest eigenvalue
        // 1e-10), exactly singular once rounded to f32.
        let c = 1.0 - 1e-10;
        let a = BlockTangent {
            diag: vec![Mat3::identity(); 2],
            off: vec![Mat3::identity() * c],
            edges: vec![[0, 1]],
        };
        let mut pcg = CholeskyPcg::new(&a, 1e-10, 30, 3, true).unwrap();
        assert!(pcg.factor_is_f32());
        let b = vec![Vec3::new(1.0, 2.0, 3.0), Vec3::new(1.0, 2.0, 3.0 + 1e-6)];
        let mut x = vec![Vec3::zeros(); 2];
        let stats = pcg.solve(&a, &b, &mut x).unwrap();
        assert!(!pcg.factor_is_f32());
        assert!(stats.converged);
        let mut ax = vec![Vec3::zeros(); 2];
        a.mul(&x, &mut ax);
        let err: f64 = ax.iter().zip(&b).map(|(p, q)| (p - q).norm()).sum();
        assert!(err < 1e-8, "residual {err:e}");
    }

    /// A symmetric, diagonally dominant block matrix on an irregular pattern
    /// over more nodes than one rayon chunk.
    fn matrix(n: usize) -> BlockTangent {
        let mut edges = Vec::new();
        for i in 0..n as u32 - 1 {
            edges.push([i, i + 1]);
            if i % 3 == 0 && i + 17 < n as u32 {
                edges.push([i, i + 17]);
            }
        }
        let val = |k: usize| ((k * 7919) % 101) as f64 / 101.0 - 0.5;
        let off: Vec<Mat3> = (0..edges.len())
            .map(|e| Mat3::from_fn(|r, c| val(9 * e + 3 * r + c)))
            .collect();
        let diag = (0..n)
            .map(|i| {
                let s = Mat3::from_fn(|r, c| val(5 * i + r + c));
                Mat3::identity() * 20.0 + (s + s.transpose()) * 0.5
            })
            .collect();
        BlockTangent { diag, off, edges }
    }

    #[test]
    fn row_gather_matches_edge_scatter() {
        let a = matrix(1300);
        let rows = BlockRows::new(a.num_nodes(), &a.edges);
        let x: Vec<Vec3> = (0..a.num_nodes())
            .map(|i| Vec3::new(i as f64, 1.0, -(i as f64).sqrt()))
            .collect();
        let (mut y0, mut y1, mut y2) = (
            vec![Vec3::zeros(); 1300],
            vec![Vec3::zeros(); 1300],
            vec![Vec3::zeros(); 1300],
        );
        a.mul(&x, &mut y0);
        rows.mul(&a, &x, &mut y1, false);
        rows.mul(&a, &x, &mut y2, true);
        for i in 0..1300 {
            assert!((y0[i] - y1[i]).norm() <= 1e-12 * y0[i].norm().max(1.0));
            assert_eq!(y1[i], y2[i]);
        }
    }

    #[test]
    fn parallel_cg_matches_serial_cg() {
        let a = matrix(1300);
        let b: Vec<Vec3> = (0..a.num_nodes())
            .map(|i| Vec3::new(1.0, (i % 7) as f64, -2.0))
            .collect();
        for precond in [Preconditioner::BlockIc0, Preconditioner::Jacobi] {
            let mut xs = vec![Vec3::zeros(); 1300];
            let mut xp = xs.clone();
            let mut cg = Cg::new(&a, precond, 1e-12, 500, true);
            cg.solve(&a, &b, &mut xs).unwrap();
            cg.parallel = true;
            cg.solve(&a, &b, &mut xp).unwrap();
            let mut r = vec![Vec3::zeros(); 1300];
            a.mul(&xp, &mut r);
            let res: f64 = r
                .iter()
                .zip(&b)
                .map(|(p, q)| (p - q).norm_squared())
                .sum::<f64>()
                .sqrt();
            assert!(res <= 1e-10 * norm(&b));
            for (p, q) in xs.iter().zip(&xp) {
                assert!((p - q).norm() <= 1e-9 * q.norm().max(1e-3));
            }
        }
    }
}
