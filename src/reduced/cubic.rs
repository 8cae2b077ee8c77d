//! The exact reduced St Venant–Kirchhoff model of Barbič & James (2005): for
//! a fixed basis Φ, the reduced internal force f_r(q) = Φᵀ f_int(Φ q) of StVK
//! is a cubic polynomial in q, precomputed once, so the haptic loop can step
//! the *nonlinear* reduced model without touching the mesh. An option next to
//! the linear model of [`super::dynamics`] for small r (see docs/REDUCED.md,
//! "Cubic reduced StVK (option)").
//!
//! **The form we store.** Per tet e, with shape gradients D_i, the
//! displacement gradient of u = Σ_a q_a φ_a is G = Σ_a q_a G_a with
//! G_a = Σ_i φ_a(node i) ⊗ D_i, and the Green strain is
//!
//! ```text
//! E = Σ_a q_a L_a + ½ Σ_ab q_a q_b N_ab,   L_a = sym G_a,   N_ab = sym(G_aᵀ G_b)
//! ```
//!
//! The StVK energy is W_e = ⟨E, E⟩_e with the inner product
//! ⟨A, B⟩_e = V_e (μ A:B + ½λ trA trB) (eq. 3–6). Writing every symmetric
//! matrix S as the 7-vector v_e(S) = (√(μV)·(S₁₁, S₂₂, S₃₃, √2 S₁₂, √2 S₁₃,
//! √2 S₂₃), √(λV/2)·tr S), so that ⟨A, B⟩_e = v_e(A)·v_e(B), and stacking
//! over all tets the columns v(L_a) (a < r) and v(N_ab) (a ≤ b: the
//! m = r(r+1)/2 unordered pairs) into one tall matrix Y (7·#tets × (r+m)),
//! every coefficient of W comes out of the single Gram matrix YᵀY:
//!
//! ```text
//! W(q) = qᵀ A q + Σ_a Σ_bc B_a,bc q_a q_b q_c + ¼ Σ_abcd C_ab,cd q_a q_b q_c q_d,
//! A = Σ_e ⟨L_a, L_b⟩,  B_a,bc = Σ_e ⟨L_a, N_bc⟩,  C_ab,cd = Σ_e ⟨N_ab, N_cd⟩
//! ```
//!
//! Precomputation is therefore one symmetric rank-k update (faer's
//! triangular GEMM) per block of tets: 7·#tets·(r+m)² flops, O(#tets·r⁴)
//! with a small constant and at GEMM speed, done in a fixed number of
//! contiguous parts on the rayon pool and summed in order (reproducible).
//!
//! **What the loop evaluates.** Rather than the force polynomial (which then
//! needs a separate, costlier derivative for Newton), we store the Hessian of
//! each homogeneous part of W, which gives the tangent directly and the
//! force by Euler's theorem for homogeneous functions (∇W_d = H_d q/(d−1)):
//!
//! ```text
//! K₁ = 2A,   H₃(q)_jk = Σ_a N_(jk),a q_a,   H₄(q)_jk = Σ_(ab) M_(jk),(ab) s_(ab)
//! N_(jk),a = 2 (B_a,jk + B_j,ka + B_k,ja),   M_(jk),(ab) = C_jk,ab + C_ja,kb + C_jb,ka
//! s_(ab) = q_a², a = b;  2 q_a q_b, a < b
//! K_r(q) = K₁ + H₃(q) + H₄(q),   f_r(q) = −(K₁ + ½ H₃(q) + ⅓ H₄(q)) q
//! W(q) = ½ qᵀK₁q + ⅙ qᵀH₃q + 1⁄12 qᵀH₄q
//! ```
//!
//! The signs follow [`crate::model::ForceModel`]: f = −∂W/∂u is the restoring
//! force and K = −∂f/∂u the stiffness, so K_r(q) = −∂f_r/∂q = Φᵀ K(Φq) Φ.
//! One evaluation of force *and* tangent is one dense symmetric m × m
//! mat-vec (M, r⁴/4 multiply-adds) plus an m × r one (N, r³/2): ≈ 4.6k
//! multiply-adds at r = 8, 18.5k at r = 16, 90k at r = 24, 280k at r = 32.
//! Storage is m² + m·r + r² doubles (149 KB at r = 16, 2.4 MB at r = 32).
//! Barbič–James's own layout (force polynomial with r⁴/6 terms, tangent by
//! differentiating it, ≈ r⁴/2) costs more per Newton iteration, which needs
//! both.
//!
//! [`CubicReducedDynamics`] integrates q̈ + D q̇ − f_r(q) = Φᵀ f_ext (reduced
//! mass I, Φ mass-orthonormal) by implicit Euler with a fixed number of
//! Newton iterations, each one fixed-size Cholesky; see its docs.

use super::basis::{ModalBasis, ReducedError};
use super::dynamics::{basis_rows, BasisRows, DynamicsParams, NodeOutOfRange};
use crate::material::Material;
use crate::math::Mat3;
use crate::math::Vec3;
use crate::mesh::TetMesh;
use faer::linalg::matmul::triangular::{matmul as triangular_matmul, BlockStructure};
use faer::{Accum, Mat, Par};
use nalgebra::{Cholesky, DMatrix, DVector, SMatrix, SVector};
use rayon::prelude::*;
use std::sync::Arc;

/// Tets per block of the Gram update: 7 · 128 = 896 rows, so a block of Y
/// stays in L2 at r = 16 and the GEMM is tall enough to run at speed.
const BLOCK_TETS: usize = 128;

/// Contiguous parts the tets are split into for the parallel precompute
/// (fixed, so the summation order does not depend on the thread count).
const PARTS: usize = 4;

/// Number of unordered pairs (a ≤ b) of r coordinates: r(r+1)/2.
pub const fn num_pairs(r: usize) -> usize {
    r * (r + 1) / 2
}

/// Index of the unordered pair {j, k} in the packed order (column-major
/// upper triangle: (0,0), (0,1), (1,1), (0,2), …).
#[inline]
fn pair(j: usize, k: usize) -> usize {
    let (lo, hi) = if j <= k { (j, k) } else { (k, j) };
    hi * (hi + 1) / 2 + lo
}

/// Dot product with four independent accumulators (so it vectorizes without
/// fast-math).
#[inline]
fn dot(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len().min(b.len());
    let (a, b) = (&a[..n], &b[..n]);
    let mut acc = [0.0f64; 4];
    let (ca, cb) = (a.chunks_exact(4), b.chunks_exact(4));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        for i in 0..4 {
            acc[i] += x[i] * y[i];
        }
    }
    let mut tail = 0.0;
    for (x, y) in ra.iter().zip(rb) {
        tail += x * y;
    }
    (acc[0] + acc[1]) + (acc[2] + acc[3]) + tail
}

/// The exact cubic reduced StVK force and tangent for one basis (see the
/// module docs for the formulas). Coefficients live on the heap, allocated
/// once in [`CubicStvk::new`]; evaluation allocates nothing.
#[derive(Debug, Clone)]
pub struct CubicStvk {
    r: usize,
    m: usize,
    /// K₁ = ΦᵀK(0)Φ, r × r column-major.
    k1: Vec<f64>,
    /// N, m × r row-major (row (jk) is contiguous).
    n3: Vec<f64>,
    /// M, m × m symmetric, column-major (column (jk) is contiguous).
    m4: Vec<f64>,
    /// Precompute wall time (s).
    precompute_s: f64,
}

/// 7-vector of a symmetric matrix in the element inner product (module docs).
#[inline]
fn v7(s: &Mat3, w: &[f64; 3]) -> [f64; 7] {
    [
        w[0] * s[(0, 0)],
        w[0] * s[(1, 1)],
        w[0] * s[(2, 2)],
        w[1] * s[(0, 1)],
        w[1] * s[(0, 2)],
        w[1] * s[(1, 2)],
        w[2] * s.trace(),
    ]
}

impl CubicStvk {
    /// Precomputes the cubic polynomial of the StVK model of `mesh` with the
    /// elastic constants of `material` (the same law as
    /// [`crate::model::nvtmm::Nvtmm`]) in the basis `basis` (any 3n × r
    /// matrix works; the dynamics assume it is mass-orthonormal).
    pub fn new(mesh: &TetMesh, material: &Material, basis: &ModalBasis) -> Result<CubicStvk, ReducedError> {
        CubicStvk::from_phi(mesh, material, &basis.phi)
    }

    /// As [`CubicStvk::new`] from the basis matrix Φ (3n × r, row 3i + c is
    /// component c of node i).
    pub fn from_phi(mesh: &TetMesh, material: &Material, phi: &DMatrix<f64>) -> Result<CubicStvk, ReducedError> {
        let t0 = std::time::Instant::now();
        let n = mesh.num_nodes();
        if phi.nrows() != 3 * n {
            return Err(ReducedError::SizeMismatch {
                what: "the basis (rows / 3)",
                got: phi.nrows() / 3,
                expected: n,
            });
        }
        let r = phi.ncols();
        if r == 0 {
            return Err(ReducedError::BadModeCount {
                asked: 0,
                free_dofs: 3 * n,
            });
        }
        if phi.iter().any(|v| !v.is_finite()) {
            return Err(ReducedError::NonFinite);
        }
        let lame = material.lame();
        let check = |name, value: f64, ok: bool, allowed| {
            if ok && value.is_finite() {
                Ok(())
            } else {
                Err(ReducedError::BadParameter { name, value, allowed })
            }
        };
        check(
            "lambda",
            lame.lambda,
            lame.lambda >= 0.0,
            ">= 0 Pa (Poisson ratio in [0, 0.5))",
        )?;
        check("mu", lame.mu, lame.mu > 0.0, "> 0 Pa")?;
        let m = num_pairs(r);
        let p = r + m;

        // Φ node-major: rows[i*3r + c*r + a] = Φ[3i + c, a].
        let mut rows = vec![0.0; 3 * n * r];
        for a in 0..r {
            let col = phi.column(a);
            for i in 0..n {
                for c in 0..3 {
                    rows[i * 3 * r + c * r + a] = col[3 * i + c];
                }
            }
        }
        // Tets that move at all (a tet whose four nodes have zero rows adds nothing).
        let moving: Vec<usize> = (0..mesh.tets().len())
            .filter(|&t| {
                mesh.tets()[t].iter().any(|&i| {
                    rows[i as usize * 3 * r..(i as usize + 1) * 3 * r]
                        .iter()
                        .any(|&v| v != 0.0)
                })
            })
            .collect();

        let part_len = moving.len().div_ceil(PARTS).max(1);
        let grams: Vec<Mat<f64>> = moving
            .par_chunks(part_len)
            .map(|tets| {
                let mut acc = Mat::<f64>::zeros(p, p);
                let mut y = Mat::<f64>::zeros(7 * BLOCK_TETS, p);
                let mut g = vec![Mat3::zeros(); r];
                for block in tets.chunks(BLOCK_TETS) {
                    for (le, &t) in block.iter().enumerate() {
                        let tet = mesh.tets()[t];
                        let grads = &mesh.grads()[t];
                        let v = mesh.volumes()[t].abs();
                        let w = [
                            (lame.mu * v).sqrt(),
                            (2.0 * lame.mu * v).sqrt(),
                            (0.5 * lame.lambda * v).sqrt(),
                        ];
                        for (a, ga) in g.iter_mut().enumerate() {
                            let mut acc3 = Mat3::zeros();
                            for (k, &node) in tet.iter().enumerate() {
                                let base = node as usize * 3 * r;
                                let phi_a = Vec3::new(rows[base + a], rows[base + r + a], rows[base + 2 * r + a]);
                                acc3 += phi_a * grads[k].transpose();
                            }
                            *ga = acc3;
                        }
                        let row0 = 7 * le;
                        for (a, ga) in g.iter().enumerate() {
                            let l = (ga + ga.transpose()) * 0.5;
                            for (k, x) in v7(&l, &w).iter().enumerate() {
                                y[(row0 + k, a)] = *x;
                            }
                        }
                        for hi in 0..r {
                            for lo in 0..=hi {
                                let gg = g[lo].tr_mul(&g[hi]);
                                let ns = (gg + gg.transpose()) * 0.5;
                                let col = r + pair(lo, hi);
                                for (k, x) in v7(&ns, &w).iter().enumerate() {
                                    y[(row0 + k, col)] = *x;
                                }
                            }
                        }
                    }
                    let yb = y.as_ref().subrows(0, 7 * block.len());
                    triangular_matmul(
                        acc.as_mut(),
                        BlockStructure::TriangularUpper,
                        Accum::Add,
                        yb.transpose(),
                        BlockStructure::Rectangular,
                        yb,
                        BlockStructure::Rectangular,
                        1.0,
                        Par::Seq,
                    );
                }
                acc
            })
            .collect();
        // Sum the parts in order; only the upper triangle is meaningful.
        let mut gram = Mat::<f64>::zeros(p, p);
        for part in &grams {
            for j in 0..p {
                for i in 0..=j {
                    gram[(i, j)] += part[(i, j)];
                }
            }
        }
        drop(grams);
        let gr = |i: usize, j: usize| if i <= j { gram[(i, j)] } else { gram[(j, i)] };
        let b = |a: usize, x: usize, y: usize| gr(a, r + pair(x, y));
        let c = |w: usize, x: usize, y: usize, z: usize| gr(r + pair(w, x), r + pair(y, z));

        let mut k1 = vec![0.0; r * r];
        for j in 0..r {
            for i in 0..r {
                k1[j * r + i] = 2.0 * gr(i, j);
            }
        }
        let mut n3 = vec![0.0; m * r];
        for kk in 0..r {
            for j in 0..=kk {
                let row = pair(j, kk);
                for a in 0..r {
                    n3[row * r + a] = 2.0 * (b(a, j, kk) + b(j, kk, a) + b(kk, j, a));
                }
            }
        }
        let mut m4 = vec![0.0; m * m];
        for kk in 0..r {
            for j in 0..=kk {
                let row = pair(j, kk);
                for bb in 0..r {
                    for a in 0..=bb {
                        let col = pair(a, bb);
                        m4[col * m + row] = c(j, kk, a, bb) + c(j, a, kk, bb) + c(j, bb, kk, a);
                    }
                }
            }
        }
        Ok(CubicStvk {
            r,
            m,
            k1,
            n3,
            m4,
            precompute_s: t0.elapsed().as_secs_f64(),
        })
    }

    /// Basis size r.
    pub fn len(&self) -> usize {
        self.r
    }

    /// Whether the basis is empty (never, for a built model).
    pub fn is_empty(&self) -> bool {
        self.r == 0
    }

    /// Wall time the precomputation took (s).
    pub fn precompute_s(&self) -> f64 {
        self.precompute_s
    }

    /// Bytes of stored coefficients (K₁, N and M).
    pub fn coefficient_bytes(&self) -> usize {
        (self.k1.len() + self.n3.len() + self.m4.len()) * std::mem::size_of::<f64>()
    }

    /// The linear stiffness K₁ = K_r(0) = ΦᵀK(0)Φ (r × r).
    pub fn rest_stiffness(&self) -> DMatrix<f64> {
        DMatrix::from_column_slice(self.r, self.r, &self.k1)
    }

    /// The reduced internal force f_r(q) = Φᵀ f_int(Φq) into `force` and the
    /// reduced tangent K_r(q) = −∂f_r/∂q = Φᵀ K(Φq) Φ into `tangent` (both
    /// zero beyond the active size r; entries of `q` beyond r are ignored).
    /// Allocates nothing. Errors only if r > R.
    pub fn eval<const R: usize>(
        &self,
        q: &SVector<f64, R>,
        force: &mut SVector<f64, R>,
        tangent: &mut SMatrix<f64, R, R>,
    ) -> Result<(), ReducedError> {
        let mut grad = SMatrix::<f64, R, R>::zeros();
        self.hessians(q, tangent, &mut grad)?;
        let mut qa = *q;
        qa.iter_mut().skip(self.r).for_each(|v| *v = 0.0);
        *force = -(grad * qa);
        Ok(())
    }

    /// The elastic energy W(q) = W(Φq) of the full model (J). Allocates nothing.
    pub fn energy<const R: usize>(&self, q: &SVector<f64, R>) -> Result<f64, ReducedError> {
        let (r, m) = (self.r, self.m);
        if r > R {
            return Err(ReducedError::Capacity { size: r, capacity: R });
        }
        let mut sbuf = SMatrix::<f64, R, R>::zeros();
        let s = &mut sbuf.as_mut_slice()[..m];
        self.pair_products(q, s);
        let qs = &q.as_slice()[..r];
        let mut w = 0.0;
        for kk in 0..r {
            for j in 0..=kk {
                let p = pair(j, kk);
                let h3 = dot(&self.n3[p * r..(p + 1) * r], qs);
                let h4 = dot(&self.m4[p * m..(p + 1) * m], s);
                let mult = if j == kk { 1.0 } else { 2.0 };
                w += mult * q[j] * q[kk] * (0.5 * self.k1[kk * r + j] + h3 / 6.0 + h4 / 12.0);
            }
        }
        Ok(w)
    }

    /// f_r and K_r for a dynamic-size q (tests and offline use; allocates).
    pub fn eval_dyn(&self, q: &DVector<f64>) -> Result<(DVector<f64>, DMatrix<f64>), ReducedError> {
        if q.len() != self.r {
            return Err(ReducedError::SizeMismatch {
                what: "q",
                got: q.len(),
                expected: self.r,
            });
        }
        let r = self.r;
        let mut k = DMatrix::from_column_slice(r, r, &self.k1);
        let mut g = k.clone();
        let mut s = vec![0.0; self.m];
        for kk in 0..r {
            for j in 0..=kk {
                s[pair(j, kk)] = if j == kk { q[j] * q[j] } else { 2.0 * q[j] * q[kk] };
            }
        }
        for kk in 0..r {
            for j in 0..=kk {
                let p = pair(j, kk);
                let h3 = dot(&self.n3[p * r..(p + 1) * r], q.as_slice());
                let h4 = dot(&self.m4[p * self.m..(p + 1) * self.m], &s);
                k[(j, kk)] += h3 + h4;
                g[(j, kk)] += 0.5 * h3 + h4 / 3.0;
                if j != kk {
                    k[(kk, j)] += h3 + h4;
                    g[(kk, j)] += 0.5 * h3 + h4 / 3.0;
                }
            }
        }
        Ok((-(g * q), k))
    }

    /// s_(ab) into `s` (length m).
    #[inline]
    fn pair_products<const R: usize>(&self, q: &SVector<f64, R>, s: &mut [f64]) {
        for kk in 0..self.r {
            let base = kk * (kk + 1) / 2;
            let qk = q[kk];
            for j in 0..kk {
                s[base + j] = 2.0 * q[j] * qk;
            }
            s[base + kk] = qk * qk;
        }
    }

    /// K₁ + H₃ + H₄ into `tangent`, K₁ + ½H₃ + ⅓H₄ into `grad` (∇W = grad·q).
    fn hessians<const R: usize>(
        &self,
        q: &SVector<f64, R>,
        tangent: &mut SMatrix<f64, R, R>,
        grad: &mut SMatrix<f64, R, R>,
    ) -> Result<(), ReducedError> {
        let (r, m) = (self.r, self.m);
        if r > R {
            return Err(ReducedError::Capacity { size: r, capacity: R });
        }
        // R² ≥ m: the pair products fit in a stack matrix's storage.
        let mut sbuf = SMatrix::<f64, R, R>::zeros();
        let s = &mut sbuf.as_mut_slice()[..m];
        self.pair_products(q, s);
        let qs = &q.as_slice()[..r];
        tangent.fill(0.0);
        grad.fill(0.0);
        for kk in 0..r {
            for j in 0..=kk {
                let p = pair(j, kk);
                let h3 = dot(&self.n3[p * r..(p + 1) * r], qs);
                let h4 = dot(&self.m4[p * m..(p + 1) * m], s);
                let k1 = self.k1[kk * r + j];
                let t = k1 + h3 + h4;
                let g = k1 + 0.5 * h3 + h4 / 3.0;
                tangent[(j, kk)] = t;
                tangent[(kk, j)] = t;
                grad[(j, kk)] = g;
                grad[(kk, j)] = g;
            }
        }
        Ok(())
    }
}

/// Default Newton iterations per step of [`CubicReducedDynamics`].
pub const DEFAULT_NEWTON_ITERS: usize = 2;

/// Most Newton iterations per step (a step's cost is bounded).
pub const MAX_NEWTON_ITERS: usize = 8;

/// Why a step of [`CubicReducedDynamics`] did not advance the state (which is
/// then unchanged). `Copy`, allocation-free: returned on the RT path.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CubicStepError {
    /// The reduced force or the contact stiffness has a NaN or infinity.
    NonFiniteInput,
    /// The Newton matrix was not positive definite at this iteration
    /// (0-based): a contact stiffness that is not PSD, or a state beyond the
    /// stability limit of StVK (K_r(q) indefinite enough to beat I/h²).
    NotPositiveDefinite {
        /// Newton iteration (0-based).
        newton_iter: usize,
    },
    /// The internal force, tangent or update became non-finite at this iteration.
    NonFinite {
        /// Newton iteration (0-based).
        newton_iter: usize,
    },
}

impl std::fmt::Display for CubicStepError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            CubicStepError::NonFiniteInput => write!(f, "non-finite reduced force or contact stiffness"),
            CubicStepError::NotPositiveDefinite { newton_iter } => {
                write!(f, "Newton matrix not positive definite at iteration {newton_iter}")
            }
            CubicStepError::NonFinite { newton_iter } => {
                write!(f, "non-finite value at Newton iteration {newton_iter}")
            }
        }
    }
}

/// Nonlinear reduced dynamics on the exact cubic StVK polynomial, capacity
/// `R` (the active size r ≤ R fills the leading block; the rest stays at
/// rest), with reduced mass I (Φ mass-orthonormal). Implicit Euler on the
/// new velocity v = q̇ₙ₊₁, qₙ₊₁ = qₙ + h v, exactly as the full
/// [`crate::solver::ImplicitEuler`] does it:
///
/// ```text
/// r(v) = v − q̇ₙ − h [fₙ₊₁ + f_r(qₙ + h v) − D v − h K_c v],   D = α I + β K_r(qₙ)
/// A    = (1 + hα) I + hβ K_r(qₙ) + h² (K_r(qₙ + h v) + K_c)
/// ```
///
/// **Damping choice:** Rayleigh with the stiffness term frozen at the start
/// of the step, K_r(qₙ), as the full integrator freezes K(u₀). At the first
/// Newton iteration (v = 0) that tangent is the one just evaluated, so the
/// damping costs nothing extra; near rest it equals the linear reduced
/// model's β K_r. With one Newton iteration the step is the linearized
/// implicit Euler step (SOFA's); more iterations converge to the exact
/// implicit Euler step of the reduced StVK model. The contact (force fₙ₊₁
/// evaluated at qₙ, reduced stiffness K_c) is linearized about qₙ like
/// [`super::ReducedDynamics::step_with_contact`].
///
/// Each Newton iteration: one [`CubicStvk::eval`] and one fixed-size
/// Cholesky of the R × R Newton matrix, on the stack. A step never
/// allocates, never panics and never writes NaN: on a non-finite input or
/// iterate, or a Newton matrix that is not positive definite, the state is
/// left unchanged and the error returned. No Prony terms (the linear model
/// has them; a reduced viscoelastic history for the nonlinear force is not
/// built here).
#[derive(Debug, Clone)]
pub struct CubicReducedDynamics<const R: usize> {
    cubic: Arc<CubicStvk>,
    rows: BasisRows<R>,
    r: usize,
    dt: f64,
    alpha: f64,
    beta: f64,
    newton_iters: usize,
    q: SVector<f64, R>,
    qd: SVector<f64, R>,
}

impl<const R: usize> CubicReducedDynamics<R> {
    /// Precomputes the cubic model of `mesh`/`material` in `basis` and builds
    /// the dynamics at rest with [`DEFAULT_NEWTON_ITERS`].
    pub fn from_basis(
        mesh: &TetMesh,
        material: &Material,
        basis: &ModalBasis,
        params: &DynamicsParams,
    ) -> Result<CubicReducedDynamics<R>, ReducedError> {
        let cubic = Arc::new(CubicStvk::new(mesh, material, basis)?);
        let rows = basis_rows::<R>(basis)?;
        CubicReducedDynamics::new(cubic, rows, params, DEFAULT_NEWTON_ITERS)
    }

    /// The dynamics on a precomputed polynomial and the basis rows it was
    /// built from (same r), at rest.
    pub fn new(
        cubic: Arc<CubicStvk>,
        rows: BasisRows<R>,
        params: &DynamicsParams,
        newton_iters: usize,
    ) -> Result<CubicReducedDynamics<R>, ReducedError> {
        let r = cubic.len();
        if r > R {
            return Err(ReducedError::Capacity { size: r, capacity: R });
        }
        let check = |name, value: f64, ok: bool, allowed| {
            if ok && value.is_finite() {
                Ok(())
            } else {
                Err(ReducedError::BadParameter { name, value, allowed })
            }
        };
        check("dt", params.dt, params.dt > 0.0, "> 0 s")?;
        check("alpha", params.alpha, params.alpha >= 0.0, ">= 0 1/s")?;
        check("beta", params.beta, params.beta >= 0.0, ">= 0 s")?;
        check(
            "newton_iters",
            newton_iters as f64,
            (1..=MAX_NEWTON_ITERS).contains(&newton_iters),
            "1..=8",
        )?;
        Ok(CubicReducedDynamics {
            cubic,
            rows,
            r,
            dt: params.dt,
            alpha: params.alpha,
            beta: params.beta,
            newton_iters,
            q: SVector::zeros(),
            qd: SVector::zeros(),
        })
    }

    /// Sets the Newton iterations per step (1..=[`MAX_NEWTON_ITERS`]).
    pub fn set_newton_iters(&mut self, iters: usize) -> Result<(), ReducedError> {
        if !(1..=MAX_NEWTON_ITERS).contains(&iters) {
            return Err(ReducedError::BadParameter {
                name: "newton_iters",
                value: iters as f64,
                allowed: "1..=8",
            });
        }
        self.newton_iters = iters;
        Ok(())
    }

    /// Newton iterations per step.
    pub fn newton_iters(&self) -> usize {
        self.newton_iters
    }

    /// One implicit Euler step under the reduced external force `f`
    /// (Φᵀ f_ext; entries beyond r ignored). Allocates nothing; on error the
    /// state is unchanged.
    pub fn step(&mut self, f: &SVector<f64, R>) -> Result<(), CubicStepError> {
        self.advance(f, None)
    }

    /// One step under a stiff contact: `f` = Φᵀ f_c(qₙ) and `k_c` its reduced
    /// stiffness −∂(Φᵀf_c)/∂q (symmetric PSD), linearized about qₙ (see the
    /// type docs). Allocates nothing; on error the state is unchanged.
    pub fn step_with_contact(&mut self, f: &SVector<f64, R>, k_c: &SMatrix<f64, R, R>) -> Result<(), CubicStepError> {
        self.advance(f, Some(k_c))
    }

    fn advance(&mut self, f: &SVector<f64, R>, k_c: Option<&SMatrix<f64, R, R>>) -> Result<(), CubicStepError> {
        let (r, h) = (self.r, self.dt);
        let finite = |x: f64| x.is_finite();
        if !f.iter().take(r).copied().all(finite) {
            return Err(CubicStepError::NonFiniteInput);
        }
        let mut kc = SMatrix::<f64, R, R>::zeros();
        if let Some(k) = k_c {
            for j in 0..r {
                for i in 0..r {
                    let x = k[(i, j)];
                    if !x.is_finite() {
                        return Err(CubicStepError::NonFiniteInput);
                    }
                    kc[(i, j)] = x;
                }
            }
        }
        let mut fe = *f;
        fe.iter_mut().skip(r).for_each(|v| *v = 0.0);
        let mut fint = SVector::<f64, R>::zeros();
        let mut kt = SMatrix::<f64, R, R>::zeros();
        let mut v = SVector::<f64, R>::zeros();
        let mut damping = SMatrix::<f64, R, R>::zeros();
        for it in 0..self.newton_iters {
            let qt = self.q + v * h;
            if self.cubic.eval(&qt, &mut fint, &mut kt).is_err() {
                return Err(CubicStepError::NonFinite { newton_iter: it });
            }
            if !(fint.iter().copied().all(finite) && kt.iter().copied().all(finite)) {
                return Err(CubicStepError::NonFinite { newton_iter: it });
            }
            if it == 0 {
                damping = kt * self.beta;
                for i in 0..R {
                    damping[(i, i)] += self.alpha;
                }
            }
            let res = v - self.qd - (fe + fint - damping * v - kc * v * h) * h;
            let a = SMatrix::<f64, R, R>::identity() + damping * h + (kt + kc) * (h * h);
            let Some(chol) = Cholesky::new(a) else {
                return Err(CubicStepError::NotPositiveDefinite { newton_iter: it });
            };
            let mut dv = -res;
            chol.solve_mut(&mut dv);
            v += dv;
            if !v.iter().copied().all(finite) {
                return Err(CubicStepError::NonFinite { newton_iter: it });
            }
        }
        let q = self.q + v * h;
        if !q.iter().copied().all(finite) {
            return Err(CubicStepError::NonFinite {
                newton_iter: self.newton_iters - 1,
            });
        }
        self.q = q;
        self.qd = v;
        Ok(())
    }

    /// The reduced internal force f_r(q) and tangent K_r(q) at the current
    /// state (allocates nothing).
    pub fn internal(&self, force: &mut SVector<f64, R>, tangent: &mut SMatrix<f64, R, R>) {
        // r ≤ R was checked at construction, so this cannot fail.
        let _ = self.cubic.eval(&self.q, force, tangent);
    }

    /// The shared polynomial.
    pub fn cubic(&self) -> &Arc<CubicStvk> {
        &self.cubic
    }

    /// The three rows of Φ at `node` (None if the node is not in the mesh).
    pub fn rows_at(&self, node: u32) -> Option<&SMatrix<f64, 3, R>> {
        self.rows.get(node as usize)
    }

    /// The shared basis rows.
    pub fn rows(&self) -> &BasisRows<R> {
        &self.rows
    }

    /// Φᵀ f for forces on a few nodes, from those nodes' rows of Φ only.
    pub fn project_nodal(&self, loads: &[(u32, Vec3)]) -> Result<SVector<f64, R>, NodeOutOfRange> {
        super::dynamics::project_on_rows(&self.rows, loads)
    }

    /// Displacement Φ q at one node (None if the node is not in the mesh).
    pub fn displacement_at(&self, node: u32) -> Option<Vec3> {
        super::dynamics::rows_times(&self.rows, node, &self.q)
    }

    /// Velocity Φ q̇ at one node (None if the node is not in the mesh).
    pub fn velocity_at(&self, node: u32) -> Option<Vec3> {
        super::dynamics::rows_times(&self.rows, node, &self.qd)
    }

    /// Reduced coordinates q.
    pub fn q(&self) -> &SVector<f64, R> {
        &self.q
    }

    /// Reduced velocities q̇.
    pub fn qd(&self) -> &SVector<f64, R> {
        &self.qd
    }

    /// Sets the state (entries beyond the active size are zeroed).
    pub fn set_state(&mut self, q: &SVector<f64, R>, qd: &SVector<f64, R>) {
        self.q = *q;
        self.qd = *qd;
        for i in self.r..R {
            self.q[i] = 0.0;
            self.qd[i] = 0.0;
        }
    }

    /// Zeroes the state.
    pub fn reset(&mut self) {
        self.q = SVector::zeros();
        self.qd = SVector::zeros();
    }

    /// Active size r.
    pub fn active(&self) -> usize {
        self.r
    }

    /// Time step (s).
    pub fn dt(&self) -> f64 {
        self.dt
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::nvtmm::Nvtmm;
    use crate::model::ForceModel;

    fn one_tet() -> TetMesh {
        let x = vec![
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(0.011, 0.001, -0.002),
            Vec3::new(0.003, 0.009, 0.001),
            Vec3::new(0.002, 0.003, 0.012),
        ];
        TetMesh::new(x, vec![[0, 1, 2, 3]], Default::default()).expect("tet")
    }

    #[test]
    fn pair_index_is_the_packed_upper_triangle() {
        let mut seen = vec![false; num_pairs(5)];
        for k in 0..5 {
            for j in 0..=k {
                assert_eq!(pair(j, k), pair(k, j));
                assert!(!seen[pair(j, k)]);
                seen[pair(j, k)] = true;
            }
        }
        assert!(seen.iter().all(|&s| s));
        assert_eq!(dot(&[1.0, 2.0, 3.0, 4.0, 5.0, 6.0], &[1.0; 6]), 21.0);
    }

    #[test]
    fn translations_give_no_force_and_the_polynomial_matches_the_tet() {
        // Columns: the three rigid translations, then three arbitrary fields.
        let mesh = one_tet();
        let mut phi = DMatrix::zeros(12, 6);
        for i in 0..4 {
            for c in 0..3 {
                phi[(3 * i + c, c)] = 1.0;
                for a in 3..6 {
                    phi[(3 * i + c, a)] = ((i * 7 + c * 3 + a * 5) % 11) as f64 * 1e-3 - 5e-3;
                }
            }
        }
        let mat = Material::aorta();
        let cubic = CubicStvk::from_phi(&mesh, &mat, &phi).unwrap();
        let mut f = SVector::<f64, 8>::zeros();
        let mut k = SMatrix::<f64, 8, 8>::zeros();
        // A pure translation of any size: no force, no energy, K_r = K₁ on
        // the deforming block only.
        let mut q = SVector::<f64, 8>::zeros();
        q[0] = 0.3;
        q[1] = -1.7;
        q[2] = 12.0;
        cubic.eval(&q, &mut f, &mut k).unwrap();
        assert!(f.norm() <= 1e-12, "{f}");
        assert!(cubic.energy(&q).unwrap().abs() <= 1e-18);
        // At q = 0 nothing at all.
        cubic.eval(&SVector::zeros(), &mut f, &mut k).unwrap();
        assert_eq!(f.norm(), 0.0);
        // A large general q against the full model.
        let model = Nvtmm::new(&mesh, &mat);
        let mut q = SVector::<f64, 8>::zeros();
        // (No translation here: the tensor-mass form works with absolute
        // displacements and loses digits to a large one.)
        for a in 3..6 {
            q[a] = 0.8 - 0.3 * a as f64;
        }
        q[6] = 99.0; // beyond r: ignored
        cubic.eval(&q, &mut f, &mut k).unwrap();
        let qd = DVector::from_iterator(6, q.iter().take(6).copied());
        let x = &phi * &qd;
        let u: Vec<Vec3> = x
            .as_slice()
            .chunks_exact(3)
            .map(|c| Vec3::new(c[0], c[1], c[2]))
            .collect();
        let mut full = vec![Vec3::zeros(); 4];
        model.add_forces(&u, &mut full);
        let fv = DVector::from_iterator(12, full.iter().flat_map(|v| [v.x, v.y, v.z]));
        let fr = phi.transpose() * fv;
        let err = (0..6).map(|a| (f[a] - fr[a]).abs()).fold(0.0, f64::max);
        assert!(err <= 1e-10 * fr.amax(), "{err} vs {}", fr.amax());
        assert_eq!(f[6], 0.0);
        let fem = crate::model::fem::Fem::new(&mesh, &mat, crate::material::Law::Stvk);
        let w = cubic.energy(&q).unwrap();
        assert!((w - fem.energy(&u)).abs() <= 1e-10 * w.abs(), "{w} {}", fem.energy(&u));
        // The dynamic-size evaluation agrees.
        let (fd, kd) = cubic.eval_dyn(&qd).unwrap();
        for a in 0..6 {
            assert!((fd[a] - f[a]).abs() <= 1e-12 * fr.amax());
            for b in 0..6 {
                assert!((kd[(a, b)] - k[(a, b)]).abs() <= 1e-12 * kd.amax());
            }
        }
        // Capacity too small.
        let mut f2 = SVector::<f64, 4>::zeros();
        let mut k2 = SMatrix::<f64, 4, 4>::zeros();
        assert!(matches!(
            cubic.eval(&SVector::<f64, 4>::zeros(), &mut f2, &mut k2),
            Err(ReducedError::Capacity { size: 6, capacity: 4 })
        ));
    }
}
