//! Sparse Cholesky with faer: symbolic analysis once per pattern, numeric
//! factorization and solves in memory sized at construction.

use super::cg::BlockRows;
use super::{LinearFailure, SolveStats};
use crate::math::Vec3;
use crate::model::BlockTangent;
use faer::dyn_stack::{MemBuffer, MemStack, StackReq};
use faer::linalg::cholesky::llt::factor::LltRegularization;
use faer::sparse::linalg::cholesky::{
    factorize_symbolic_cholesky, CholeskySymbolicParams, LltRef, SymbolicCholesky, SymmetricOrdering,
};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use faer::{Conj, MatMut, Par, Side};

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

impl CholeskySolver<f64> {
    /// Solves A X = B in place for the `b.len() / dofs` columns of `b`
    /// (column-major, dofs = 3 × nodes rows, node-major within a column)
    /// with the factor of the last successful [`CholeskySolver::factor`].
    /// Many right-hand sides at once run the triangular solves as dense
    /// block products, several times faster per column than one at a
    /// time. Allocates its scratch (not for the RT thread).
    pub fn solve_factored_columns(&mut self, b: &mut [f64]) -> Result<(), LinearFailure> {
        let dofs = self.rhs.len();
        if !self.factored || dofs == 0 || b.len() % dofs != 0 {
            return Err(LinearFailure::NotPositiveDefinite);
        }
        let cols = b.len() / dofs;
        let mut scratch = MemBuffer::try_new(self.symbolic.solve_in_place_scratch::<f64>(cols, self.par))
            .map_err(|_| LinearFailure::NonFinite)?;
        let llt = LltRef::new(&self.symbolic, &self.l_values);
        let rhs = MatMut::from_column_major_slice_mut(b, dofs, cols);
        llt.solve_in_place_with_conj(Conj::No, rhs, self.par, MemStack::new(&mut scratch));
        if b.iter().any(|v| !v.is_finite()) {
            return Err(LinearFailure::NonFinite);
        }
        Ok(())
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
