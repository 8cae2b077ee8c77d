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
//! - [`LinearSolverKind::CholeskyPcg`]: CG preconditioned by a lagged
//!   sparse Cholesky factor (f64 or f32).
//!
//! Layout: [`cg`] holds the CG loop (written once, used by both CG solvers)
//! and the block preconditioners, [`cholesky`] the faer factorization, and
//! [`cholesky_pcg`] the lagged-factor PCG; this file the solver choice, the
//! failures and the statistics.
//!
//! Nothing here knows about time or force models.

pub mod cg;
pub mod cholesky;
pub mod cholesky_pcg;

pub use cg::{BlockRows, Cg, IC0_SHIFTS};
pub use cholesky::{CholeskySolver, FactorScalar};
pub use cholesky_pcg::CholeskyPcg;

use crate::math::Mat3;
use crate::math::Vec3;
use crate::model::BlockTangent;

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

fn dot(a: &[Vec3], b: &[Vec3]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x.dot(y)).sum()
}

fn norm(a: &[Vec3]) -> f64 {
    dot(a, a).sqrt()
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
