//! CG preconditioned by a lagged sparse Cholesky factor (f64 or f32), with a
//! refactorization when the factor is too old or CG misses its tolerance.

use super::cg::pcg_loop;
use super::cholesky::CholeskySolver;
use super::{rhs_norm, LinearFailure, SolveStats};
use crate::math::Vec3;
use crate::model::BlockTangent;

/// CG preconditioned by a lagged sparse Cholesky factor
/// ([`LinearSolverKind::CholeskyPcg`](super::LinearSolverKind::CholeskyPcg)).
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
        pcg_loop(
            b,
            x,
            bnorm,
            *tol,
            *max_iter,
            [r, z, p, q],
            |v, out| a.mul(v, out),
            |r, z| chol.solve_factored(r, z).map(|_| ()),
        )
    }
}
