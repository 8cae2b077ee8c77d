//! Preconditioned conjugate gradient: the CG loop (one copy, shared with
//! [`super::CholeskyPcg`]), the row-wise pattern view for gathers and sweeps,
//! and the Jacobi, block-Jacobi, block SSOR and block IC(0) preconditioners.

use super::{dot, norm, rhs_norm, LinearFailure, Preconditioner, SolveStats};
use crate::math::Mat3;
use crate::math::Vec3;
use crate::model::BlockTangent;
use rayon::prelude::*;

/// A row's neighbours (node, edge).
pub(super) type Nbrs<'a> = &'a [(u32, u32)];

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
    pub(super) fn split(&self, i: usize) -> (Nbrs<'_>, Nbrs<'_>) {
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
        let stats = pcg_loop(
            b,
            x,
            bnorm,
            *tol,
            *max_iter,
            [r, z, p, q],
            |v, out| matvec(rows, a, v, out, parallel),
            |r, z| {
                apply_precond(precond, rows, dinv, ic, a, r, z);
                Ok(())
            },
        )?;
        if !stats.converged && *strict {
            return Err(LinearFailure::CgNotConverged {
                iters: stats.iters,
                rel_residual: stats.rel_residual,
            });
        }
        Ok(stats)
    }
}

/// The preconditioned CG iteration for A x = b, warm-started from `x` (a
/// start worse than zero is replaced by zero), with ‖b‖ = `bnorm` > 0,
/// relative tolerance `tol`, the work vectors `[r, z, p, q]`, the product
/// y = A v and the preconditioner z = P⁻¹ r. Fails on pᵀAp ≤ 0 or rᵀz ≤ 0
/// (breakdown) and on a non-finite result; a miss of the tolerance is
/// reported in the statistics.
#[allow(clippy::too_many_arguments)]
pub(super) fn pcg_loop(
    b: &[Vec3],
    x: &mut [Vec3],
    bnorm: f64,
    tol: f64,
    max_iter: usize,
    [r, z, p, q]: [&mut Vec<Vec3>; 4],
    mut matvec: impl FnMut(&[Vec3], &mut [Vec3]),
    mut precond: impl FnMut(&[Vec3], &mut [Vec3]) -> Result<(), LinearFailure>,
) -> Result<SolveStats, LinearFailure> {
    matvec(x, q);
    for ((ri, bi), qi) in r.iter_mut().zip(b).zip(q.iter()) {
        *ri = bi - qi;
    }
    let mut rnorm = norm(r);
    if !(rnorm.is_finite() && rnorm <= bnorm) {
        x.iter_mut().for_each(|v| *v = Vec3::zeros());
        r.copy_from_slice(b);
        rnorm = bnorm;
    }
    let goal = tol * bnorm;
    let mut iters = 0;
    if rnorm > goal {
        precond(r, z)?;
        p.copy_from_slice(z);
        let mut rz = dot(r, z);
        while iters < max_iter {
            matvec(p, q);
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
            precond(r, z)?;
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
