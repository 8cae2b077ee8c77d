//! Linear reduced dynamics for the haptic loop: q̈ + D_r q̇ + K_r q = Φᵀ f in
//! the r coordinates of a mass-orthonormal basis (reduced mass I), with
//! Rayleigh damping D_r = α I + β K_r, integrated by implicit Euler:
//!
//! ```text
//! (I + h D_r + h² K_r) q̇ₙ₊₁ = q̇ₙ + h (fₙ₊₁ − K_r qₙ),   qₙ₊₁ = qₙ + h q̇ₙ₊₁
//! ```
//!
//! All matrices are nalgebra fixed-size with a const-generic capacity `R`;
//! a basis of r ≤ R columns fills the leading block and the rest is the
//! identity in the system matrix and zero elsewhere, so the unused
//! coordinates stay at rest. The system matrix is factored (Cholesky) once at
//! construction; [`ReducedDynamics::step`] is two triangular solves and two
//! small mat-vecs on the stack and never allocates.
//!
//! **Prony terms in reduced form** (paper eq. 10–15). For the linear reduced
//! model the elastic restoring force is g = K_r q, and projecting the
//! paper's force recurrence through Φ (a linear map, so it commutes with the
//! recurrence) gives, per term i, a reduced history γ_i ∈ ℝʳ:
//!
//! ```text
//! γ_iⁿ = A_i K_r qⁿ + B_i γ_iⁿ⁻¹,   A_i = h α_i/(h + τ_i),  B_i = τ_i/(h + τ_i)   (eq. 15)
//! f_int(qⁿ) = −(K_r qⁿ − Σ γ_iⁿ) = −s K_r qⁿ + Σ B_i γ_iⁿ⁻¹,  s = 1 − Σ A_i     (eq. 13)
//! ```
//!
//! so inside the implicit step the elastic stiffness is scaled by s and the
//! history adds a constant force H = Σ B_i γ_iⁿ⁻¹:
//!
//! ```text
//! (I + h D_r + h² s K_r) q̇ₙ₊₁ = q̇ₙ + h (fₙ₊₁ − s K_r qₙ + H),   then γ_i ← A_i K_r qₙ₊₁ + B_i γ_i
//! ```
//!
//! Under a held q the history tends to γ_i = α_i K_r q and the force to
//! −(1 − Σ α_i) K_r q, the relaxed modulus of eq. 11. At most
//! [`MAX_PRONY_TERMS`] terms, in fixed arrays; with none (the default) s = 1,
//! H = 0 and the step is exactly the elastic one.

use super::basis::{ModalBasis, ReducedError};
use crate::material::PronyTerm;
use crate::math::Vec3;
use crate::solver::pressure::Waveform;
use nalgebra::{Cholesky, Const, DMatrix, SMatrix, SVector};
use std::sync::Arc;

/// The three rows of Φ of every mesh node, at capacity `R` (columns beyond
/// the active size are zero). Shared between reduced models built on the
/// same basis, so a linearization refresh copies no per-node data.
pub type BasisRows<const R: usize> = Arc<Vec<SMatrix<f64, 3, R>>>;

/// The per-node rows of Φ of `basis` at capacity `R`.
pub fn basis_rows<const R: usize>(basis: &ModalBasis) -> Result<BasisRows<R>, ReducedError> {
    let r = basis.len();
    if r > R {
        return Err(ReducedError::Capacity { size: r, capacity: R });
    }
    let n = basis.num_nodes();
    let mut rows = vec![SMatrix::<f64, 3, R>::zeros(); n];
    for (i, row) in rows.iter_mut().enumerate() {
        for c in 0..3 {
            for j in 0..r {
                row[(c, j)] = basis.phi[(3 * i + c, j)];
            }
        }
    }
    Ok(Arc::new(rows))
}

/// max over the nodes of ‖Φᵢ‖₂, the largest factor by which a node's rows
/// stretch a change of q ([`ReducedDynamics::row_bound`]). The Frobenius
/// norm bounds it too but is up to √3 larger (on the branched arch's
/// 32-mode basis the spectral bound is 0.71 of it), and every bit of the
/// bound shortens how long the contact keeps its triangles. The largest
/// eigenvalue of the 3 × 3 Gram matrix ΦᵢΦᵢᵀ comes in closed form, padded
/// by a relative 10⁻⁶ against its rounding and capped by the Frobenius
/// norm; a node whose Frobenius norm is under the bound so far cannot raise
/// it and is skipped. A NaN row is skipped, as `f64::max` does.
fn row_bound_of<const R: usize>(rows: &[SMatrix<f64, 3, R>]) -> f64 {
    let mut bound = 0.0f64;
    for row in rows {
        let frob = row.norm();
        if frob.is_nan() || frob <= bound {
            continue;
        }
        let g = row * row.transpose();
        let spectral = (largest_symmetric_eigenvalue(&g).max(0.0).sqrt() * (1.0 + 1e-6)).min(frob);
        if spectral.is_finite() {
            bound = bound.max(spectral);
        }
    }
    bound
}

/// The largest eigenvalue of a symmetric 3 × 3 matrix (the trigonometric
/// closed form: O. K. Smith, "Eigenvalues of a symmetric 3 × 3 matrix",
/// Comm. ACM 4(4), 1961).
fn largest_symmetric_eigenvalue(a: &SMatrix<f64, 3, 3>) -> f64 {
    let off = a[(0, 1)] * a[(0, 1)] + a[(0, 2)] * a[(0, 2)] + a[(1, 2)] * a[(1, 2)];
    let mean = (a[(0, 0)] + a[(1, 1)] + a[(2, 2)]) / 3.0;
    let spread = (a[(0, 0)] - mean).powi(2) + (a[(1, 1)] - mean).powi(2) + (a[(2, 2)] - mean).powi(2) + 2.0 * off;
    let p = (spread / 6.0).sqrt();
    if p.is_nan() || p <= 0.0 {
        // A multiple of the identity (or NaN).
        return a[(0, 0)].max(a[(1, 1)]).max(a[(2, 2)]);
    }
    let b = (a - SMatrix::<f64, 3, 3>::identity() * mean) / p;
    let r = (b.determinant() / 2.0).clamp(-1.0, 1.0);
    mean + 2.0 * p * (r.acos() / 3.0).cos()
}

/// Φᵀ f for forces on a few nodes, from those nodes' rows of Φ only.
pub(crate) fn project_on_rows<const R: usize>(
    rows: &[SMatrix<f64, 3, R>],
    loads: &[(u32, Vec3)],
) -> Result<SVector<f64, R>, NodeOutOfRange> {
    let mut out = SVector::<f64, R>::zeros();
    for &(node, f) in loads {
        let row = rows.get(node as usize).ok_or(NodeOutOfRange(node))?;
        out += row.tr_mul(&f);
    }
    Ok(out)
}

/// Φ v at one node from its rows (None if the node is not in the mesh).
pub(crate) fn rows_times<const R: usize>(rows: &[SMatrix<f64, 3, R>], node: u32, v: &SVector<f64, R>) -> Option<Vec3> {
    rows.get(node as usize).map(|row| row_times(row, v))
}

/// Φᵢ v for one node's 3 × R rows, with four independent partial sums per
/// component. The contact evaluates it for every node under a patch each
/// tick; nalgebra's product runs one dependent chain of R multiply-adds
/// per component. At R = 32, on rows in cache: 20 ns against 35 ns
/// (2-core VM, 2026-11-25).
pub fn row_times<const R: usize>(row: &SMatrix<f64, 3, R>, v: &SVector<f64, R>) -> Vec3 {
    // Column-major: column j is (a[3j], a[3j + 1], a[3j + 2]).
    let (a, v) = (row.as_slice(), v.as_slice());
    let mut acc = [[0.0f64; 3]; 4];
    let body = a.chunks_exact(12);
    let (tail_a, tail_v) = (body.remainder(), &v[R - R % 4..]);
    for (cols, vs) in body.zip(v.chunks_exact(4)) {
        for k in 0..4 {
            for c in 0..3 {
                acc[k][c] += cols[3 * k + c] * vs[k];
            }
        }
    }
    for (col, &vj) in tail_a.chunks_exact(3).zip(tail_v) {
        for c in 0..3 {
            acc[0][c] += col[c] * vj;
        }
    }
    Vec3::from_fn(|c, _| (acc[0][c] + acc[1][c]) + (acc[2][c] + acc[3][c]))
}

/// Time step and Rayleigh damping of the reduced model.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DynamicsParams {
    /// Time step h (s), e.g. 1e-3 for the 1 kHz loop.
    pub dt: f64,
    /// Mass-proportional damping α (1/s).
    pub alpha: f64,
    /// Stiffness-proportional damping β (s).
    pub beta: f64,
}

/// Most Prony terms a reduced model carries (fixed arrays, no heap).
pub const MAX_PRONY_TERMS: usize = 4;

/// A node index outside the basis (returned by the RT-path helpers; carries
/// the index, allocates nothing).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct NodeOutOfRange(pub u32);

/// A share of a reduced model's state: the part of (q, q̇) and of the Prony
/// histories that one load alone caused, stepped beside the whole state by
/// [`ReducedDynamics::step_with_contact_and`]. Fixed size, plain data.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReducedPart<const R: usize> {
    /// Its share of q.
    pub q: SVector<f64, R>,
    /// Its share of q̇.
    pub qd: SVector<f64, R>,
    gamma: [SVector<f64, R>; MAX_PRONY_TERMS],
}

impl<const R: usize> Default for ReducedPart<R> {
    fn default() -> Self {
        ReducedPart {
            q: SVector::zeros(),
            qd: SVector::zeros(),
            gamma: [SVector::zeros(); MAX_PRONY_TERMS],
        }
    }
}

impl<const R: usize> ReducedPart<R> {
    /// The share carried into another basis by the swap's transfer T
    /// (q ← T q, q̇ ← T q̇; the Prony histories start empty, as a new
    /// model's do); a share that is not finite is zeroed.
    pub fn transferred(&self, t: &SMatrix<f64, R, R>) -> ReducedPart<R> {
        let mut p = ReducedPart {
            q: t * self.q,
            qd: t * self.qd,
            gamma: [SVector::zeros(); MAX_PRONY_TERMS],
        };
        if !p.is_finite() {
            p = ReducedPart::default();
        }
        p
    }

    /// Whether every entry is finite.
    pub fn is_finite(&self) -> bool {
        self.q.iter().chain(self.qd.iter()).all(|v| v.is_finite())
            && self.gamma.iter().all(|g| g.iter().all(|v| v.is_finite()))
    }
}

/// The reduced model with capacity `R`: state (q, q̇), the reduced stiffness,
/// the factored implicit-Euler matrix and, per node, its 3 rows of Φ.
#[derive(Debug, Clone)]
pub struct ReducedDynamics<const R: usize> {
    r: usize,
    dt: f64,
    k: SMatrix<f64, R, R>,
    a: SMatrix<f64, R, R>,
    system: Cholesky<f64, Const<R>>,
    rows: BasisRows<R>,
    q: SVector<f64, R>,
    qd: SVector<f64, R>,
    alpha: f64,
    beta: f64,
    /// Number of active Prony terms and their A_i, B_i (eq. 15).
    prony_n: usize,
    prony_terms: [PronyTerm; MAX_PRONY_TERMS],
    prony_a: [f64; MAX_PRONY_TERMS],
    prony_b: [f64; MAX_PRONY_TERMS],
    /// Reduced histories γ_i.
    gamma: [SVector<f64, R>; MAX_PRONY_TERMS],
    /// s = 1 − Σ A_i.
    prony_scale: f64,
    /// max over nodes of ‖Φᵢ‖₂ ([`ReducedDynamics::row_bound`]).
    row_bound: f64,
    /// The heartbeat's pulsatile load, if any.
    pulse: Option<ModalPulse<R>>,
}

/// The pulsatile part of the blood pressure as a modal load: the model is
/// linearized about the wall at the mean pressure, so the beat adds
/// (p(t) − p_mean) times the reduced pressure load per pascal, Φᵀ ∂f_p/∂p
/// at ū. Evaluated once per step: a waveform sample and an R-vector axpy.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ModalPulse<const R: usize> {
    /// Φᵀ f_p(ū) / p: the reduced pressure load per pascal (N/Pa).
    pub load_per_pa: SVector<f64, R>,
    /// The heartbeat.
    pub waveform: Waveform,
    /// The pressure the model is linearized at (Pa).
    pub mean_pa: f64,
    /// Time in the beat (s) at the end of the last step.
    pub t_s: f64,
}

impl<const R: usize> ModalPulse<R> {
    /// The reduced pulsatile load at beat time `t` (s).
    #[inline]
    pub fn load_at(&self, t: f64) -> SVector<f64, R> {
        self.load_per_pa * (self.waveform.pressure_at(t) - self.mean_pa)
    }
}

impl<const R: usize> ReducedDynamics<R> {
    /// A reduced model on `basis` with K_r = diag(ω²) (the basis is
    /// mass-orthonormal with diagonal reduced stiffness), at rest.
    pub fn new(basis: &ModalBasis, params: &DynamicsParams) -> Result<ReducedDynamics<R>, ReducedError> {
        let k = DMatrix::from_diagonal(&nalgebra::DVector::from_column_slice(&basis.omega2));
        ReducedDynamics::with_stiffness(basis, &k, params)
    }

    /// A reduced model on `basis` with a given symmetric reduced stiffness
    /// `k_r` (m × m, m the basis size), e.g. ΦᵀK(ū)Φ at another
    /// linearization point, at rest.
    pub fn with_stiffness(
        basis: &ModalBasis,
        k_r: &DMatrix<f64>,
        params: &DynamicsParams,
    ) -> Result<ReducedDynamics<R>, ReducedError> {
        let rows = basis_rows::<R>(basis)?;
        ReducedDynamics::with_rows(rows, basis.len(), k_r, params)
    }

    /// A reduced model on shared basis rows (`r` active columns) with the
    /// symmetric reduced stiffness `k_r` (r × r), at rest. This is what a
    /// linearization refresh builds: new K_r, same rows.
    pub fn with_rows(
        rows: BasisRows<R>,
        r: usize,
        k_r: &DMatrix<f64>,
        params: &DynamicsParams,
    ) -> Result<ReducedDynamics<R>, ReducedError> {
        if r > R {
            return Err(ReducedError::Capacity { size: r, capacity: R });
        }
        if k_r.nrows() != r || k_r.ncols() != r {
            return Err(ReducedError::SizeMismatch {
                what: "the reduced stiffness",
                got: k_r.nrows(),
                expected: r,
            });
        }
        if k_r.iter().any(|v| !v.is_finite()) {
            return Err(ReducedError::NonFinite);
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
        let mut k = SMatrix::<f64, R, R>::zeros();
        for i in 0..r {
            for j in 0..r {
                k[(i, j)] = 0.5 * (k_r[(i, j)] + k_r[(j, i)]);
            }
        }
        let h = params.dt;
        // Unused coordinates: K = 0 and D = αI there, so the system is
        // (1 + hα) on their diagonal; step() also zeroes their forcing.
        let a = SMatrix::<f64, R, R>::identity() * (1.0 + h * params.alpha) + k * (h * params.beta + h * h);
        let system = Cholesky::new(a).ok_or(ReducedError::NotPositiveDefinite)?;
        let row_bound = row_bound_of(&rows);
        Ok(ReducedDynamics {
            r,
            dt: h,
            k,
            a,
            system,
            rows,
            q: SVector::zeros(),
            qd: SVector::zeros(),
            alpha: params.alpha,
            beta: params.beta,
            prony_n: 0,
            prony_terms: [PronyTerm { alpha: 0.0, tau: 1.0 }; MAX_PRONY_TERMS],
            prony_a: [0.0; MAX_PRONY_TERMS],
            prony_b: [0.0; MAX_PRONY_TERMS],
            gamma: [SVector::zeros(); MAX_PRONY_TERMS],
            prony_scale: 1.0,
            row_bound,
            pulse: None,
        })
    }

    /// Sets (or with None removes) the heartbeat's modal load; entries
    /// beyond the active size are ignored.
    pub fn set_pulse(&mut self, pulse: Option<ModalPulse<R>>) {
        self.pulse = pulse.map(|mut p| {
            for v in p.load_per_pa.iter_mut().skip(self.r) {
                *v = 0.0;
            }
            p
        });
    }

    /// The heartbeat's modal load, if any.
    pub fn pulse(&self) -> Option<&ModalPulse<R>> {
        self.pulse.as_ref()
    }

    /// Advances the beat by one step (before the step's right-hand side).
    #[inline]
    fn advance_pulse(&mut self) {
        if let Some(p) = self.pulse.as_mut() {
            p.t_s += self.dt;
        }
    }

    /// Sets the Prony terms (at most [`MAX_PRONY_TERMS`]; each α_i in (0, 1),
    /// τ_i > 0, Σ α_i < 1; an empty slice switches viscoelasticity off),
    /// refactors the step matrix with s = 1 − Σ A_i and clears the
    /// histories. Not for the RT path (it factors an R × R matrix).
    pub fn set_prony(&mut self, terms: &[PronyTerm]) -> Result<(), ReducedError> {
        if terms.len() > MAX_PRONY_TERMS {
            return Err(ReducedError::BadParameter {
                name: "prony terms",
                value: terms.len() as f64,
                allowed: "at most MAX_PRONY_TERMS (4)",
            });
        }
        let mut sum = 0.0;
        for t in terms {
            if !(t.alpha.is_finite() && t.alpha > 0.0 && t.alpha < 1.0) {
                return Err(ReducedError::BadParameter {
                    name: "prony alpha",
                    value: t.alpha,
                    allowed: "in (0, 1)",
                });
            }
            if !(t.tau.is_finite() && t.tau > 0.0) {
                return Err(ReducedError::BadParameter {
                    name: "prony tau",
                    value: t.tau,
                    allowed: "> 0 s",
                });
            }
            sum += t.alpha;
        }
        if sum >= 1.0 {
            return Err(ReducedError::BadParameter {
                name: "prony alpha sum",
                value: sum,
                allowed: "< 1",
            });
        }
        let h = self.dt;
        let mut a_sum = 0.0;
        let mut pa = [0.0; MAX_PRONY_TERMS];
        let mut pb = [0.0; MAX_PRONY_TERMS];
        let mut pt = [PronyTerm { alpha: 0.0, tau: 1.0 }; MAX_PRONY_TERMS];
        for (i, t) in terms.iter().enumerate() {
            pa[i] = h * t.alpha / (h + t.tau);
            pb[i] = t.tau / (h + t.tau);
            pt[i] = *t;
            a_sum += pa[i];
        }
        let scale = 1.0 - a_sum;
        let a = SMatrix::<f64, R, R>::identity() * (1.0 + h * self.alpha) + self.k * (h * self.beta + h * h * scale);
        let system = Cholesky::new(a).ok_or(ReducedError::NotPositiveDefinite)?;
        self.a = a;
        self.system = system;
        self.prony_n = terms.len();
        self.prony_terms = pt;
        self.prony_a = pa;
        self.prony_b = pb;
        self.prony_scale = scale;
        self.gamma = [SVector::zeros(); MAX_PRONY_TERMS];
        Ok(())
    }

    /// The active Prony terms.
    pub fn prony(&self) -> &[PronyTerm] {
        &self.prony_terms[..self.prony_n]
    }

    /// The reduced Prony histories γ_i (one per active term).
    pub fn prony_history(&self) -> &[SVector<f64, R>] {
        &self.gamma[..self.prony_n]
    }

    /// Sets the histories (e.g. carried over from the previous model by
    /// projection at a swap); extra entries are ignored, missing ones zeroed.
    pub fn set_prony_history(&mut self, gamma: &[SVector<f64, R>]) {
        for i in 0..self.prony_n {
            self.gamma[i] = gamma.get(i).copied().unwrap_or_else(SVector::zeros);
            for v in self.gamma[i].iter_mut().skip(self.r) {
                *v = 0.0;
            }
        }
    }

    /// The right-hand side q̇ₙ + h (f − s K_r qₙ + H), inactive entries
    /// zeroed; f includes the heartbeat's load at the step's end.
    fn rhs(&self, f: &SVector<f64, R>) -> SVector<f64, R> {
        match &self.pulse {
            Some(p) => self.rhs_of(&self.q, &self.qd, &self.gamma, &(f + p.load_at(p.t_s))),
            None => self.rhs_of(&self.q, &self.qd, &self.gamma, f),
        }
    }

    /// [`ReducedDynamics::rhs`] for the state (`q`, `qd`, `gamma`).
    fn rhs_of(
        &self,
        q: &SVector<f64, R>,
        qd: &SVector<f64, R>,
        gamma: &[SVector<f64, R>; MAX_PRONY_TERMS],
        f: &SVector<f64, R>,
    ) -> SVector<f64, R> {
        let mut force = f - self.k * q * self.prony_scale;
        for (g, b) in gamma.iter().zip(&self.prony_b).take(self.prony_n) {
            force += g * *b;
        }
        let mut rhs = qd + force * self.dt;
        for v in rhs.iter_mut().skip(self.r) {
            *v = 0.0;
        }
        rhs
    }

    /// γ_i ← A_i K_r qₙ₊₁ + B_i γ_i after a step (eq. 15).
    fn update_history(&mut self) {
        let q = self.q;
        let mut gamma = self.gamma;
        self.update_history_of(&q, &mut gamma);
        self.gamma = gamma;
    }

    /// [`ReducedDynamics::update_history`] for the histories `gamma` of a
    /// state at `q`.
    fn update_history_of(&self, q: &SVector<f64, R>, gamma: &mut [SVector<f64, R>; MAX_PRONY_TERMS]) {
        if self.prony_n == 0 {
            return;
        }
        let kq = self.k * q;
        for ((g, a), b) in gamma
            .iter_mut()
            .zip(&self.prony_a)
            .zip(&self.prony_b)
            .take(self.prony_n)
        {
            *g = kq * *a + *g * *b;
        }
    }

    /// One implicit Euler step under the reduced force `f` (Φᵀ f_ext, e.g.
    /// from [`ReducedDynamics::project_nodal`]). Entries beyond the active
    /// size are ignored. Allocates nothing.
    pub fn step(&mut self, f: &SVector<f64, R>) {
        self.advance_pulse();
        let mut rhs = self.rhs(f);
        self.system.solve_mut(&mut rhs);
        self.qd = rhs;
        self.q += self.qd * self.dt;
        self.update_history();
    }

    /// One implicit Euler step under the reduced force `f` = Φᵀ f_c(qₙ) of a
    /// stiff contact whose reduced stiffness −∂(Φᵀf_c)/∂q is `k_c` (symmetric
    /// positive semi-definite, e.g. Σ k Φᵢᵀ n nᵀ Φᵢ over the touched nodes).
    /// The contact is linearized about qₙ, f_c(qₙ₊₁) ≈ f_c(qₙ) − k_c h q̇ₙ₊₁,
    /// so a penalty far stiffer than the explicit limit 4/h² stays stable.
    /// Factors the R × R system on the stack (no allocation; with k_c = 0,
    /// out of contact, it solves with the factor made with the model); if
    /// it is not positive definite (k_c not PSD) the contact stiffness is
    /// dropped for this step and `false` is returned.
    pub fn step_with_contact(&mut self, f: &SVector<f64, R>, k_c: &SMatrix<f64, R, R>) -> bool {
        let h = self.dt;
        self.advance_pulse();
        let mut rhs = self.rhs(f);
        let ok = self.solve_with_contact(k_c, &mut rhs, None);
        self.qd = rhs;
        self.q += self.qd * h;
        self.update_history();
        ok
    }

    /// [`ReducedDynamics::step_with_contact`] that also steps `part`, the
    /// component of the state that answers to the load `f_part` alone
    /// (`f_part` is included in `f`): the same implicit-Euler system with the
    /// same contact stiffness, factored once. By linearity `part` stays the
    /// exact share of q that `f_part`'s history caused, e.g. the wall's
    /// displacement under the guidewire's own loads, which the wire's lumen
    /// leaves out. Allocates nothing.
    pub fn step_with_contact_and(
        &mut self,
        f: &SVector<f64, R>,
        k_c: &SMatrix<f64, R, R>,
        part: &mut ReducedPart<R>,
        f_part: &SVector<f64, R>,
    ) -> bool {
        let h = self.dt;
        self.advance_pulse();
        let mut rhs = self.rhs(f);
        let mut rhs_part = self.rhs_of(&part.q, &part.qd, &part.gamma, f_part);
        let ok = self.solve_with_contact(k_c, &mut rhs, Some(&mut rhs_part));
        self.qd = rhs;
        self.q += self.qd * h;
        self.update_history();
        part.qd = rhs_part;
        part.q += part.qd * h;
        let q = part.q;
        self.update_history_of(&q, &mut part.gamma);
        ok
    }

    /// Solves the step's system with the contact stiffness `k_c` added,
    /// (A + h² k_c) x = rhs, in place for `rhs` and `extra`, factored once
    /// on the stack; false (and the system without `k_c`) if that is not
    /// positive definite.
    fn solve_with_contact(
        &self,
        k_c: &SMatrix<f64, R, R>,
        rhs: &mut SVector<f64, R>,
        extra: Option<&mut SVector<f64, R>>,
    ) -> bool {
        // Out of contact k_c is exactly zero and A + h² k_c is A, whose
        // factor was computed when the model was built (off the loop):
        // solving with it gives the same result as factoring A again.
        if k_c.iter().all(|&v| v == 0.0) {
            self.system.solve_mut(rhs);
            if let Some(x) = extra {
                self.system.solve_mut(x);
            }
            return true;
        }
        let h = self.dt;
        let mut a = self.a;
        for i in 0..self.r {
            for j in 0..self.r {
                a[(i, j)] += h * h * k_c[(i, j)];
            }
        }
        match Cholesky::new(a) {
            Some(chol) => {
                chol.solve_mut(rhs);
                if let Some(x) = extra {
                    chol.solve_mut(x);
                }
                true
            }
            None => {
                self.system.solve_mut(rhs);
                if let Some(x) = extra {
                    self.system.solve_mut(x);
                }
                false
            }
        }
    }

    /// Reads one value of every cache line of the model's matrices (K_r,
    /// the step matrix and its factor) and its Prony histories, and returns
    /// their sum: a model built on another core is read here once, before
    /// the loop needs it, so that the loop's swap and first steps on it do
    /// not wait for memory ([`crate::haptics::servo::Servo::warm`]).
    pub fn touch(&self) -> f64 {
        // 8 f64 = 64 bytes, one cache line.
        let lines = |m: &[f64]| m.iter().step_by(8).sum::<f64>();
        let mut sum = lines(self.k.as_slice()) + lines(self.a.as_slice()) + lines(self.system.l_dirty().as_slice());
        for g in &self.gamma {
            sum += lines(g.as_slice());
        }
        if let Some(p) = &self.pulse {
            sum += lines(p.load_per_pa.as_slice());
        }
        sum
    }

    /// The three rows of Φ at `node` (None if the node is not in the mesh).
    pub fn rows_at(&self, node: u32) -> Option<&SMatrix<f64, 3, R>> {
        self.rows.get(node as usize)
    }

    /// An upper bound on how far any node moves per unit change of q: the
    /// largest spectral norm of a node's rows (a relative 10⁻⁶ over it,
    /// never over the row's Frobenius norm), so ‖Φᵢ (q₁ − q₀)‖ ≤
    /// `row_bound()` ‖q₁ − q₀‖ at every node. The contact uses it to keep a
    /// patch's triangles from one tick to the next: the smaller the bound,
    /// the longer they last.
    pub fn row_bound(&self) -> f64 {
        self.row_bound
    }

    /// The shared basis rows.
    pub fn rows(&self) -> &BasisRows<R> {
        &self.rows
    }

    /// Zeroes the state (q = q̇ = 0 and the Prony histories).
    pub fn reset(&mut self) {
        self.q = SVector::zeros();
        self.qd = SVector::zeros();
        self.gamma = [SVector::zeros(); MAX_PRONY_TERMS];
    }

    /// Φᵀ f for forces on a few nodes, from those nodes' rows of Φ only.
    pub fn project_nodal(&self, loads: &[(u32, Vec3)]) -> Result<SVector<f64, R>, NodeOutOfRange> {
        project_on_rows(&self.rows, loads)
    }

    /// Displacement Φ q at one node (None if the node is not in the mesh).
    pub fn displacement_at(&self, node: u32) -> Option<Vec3> {
        rows_times(&self.rows, node, &self.q)
    }

    /// Velocity Φ q̇ at one node (None if the node is not in the mesh).
    pub fn velocity_at(&self, node: u32) -> Option<Vec3> {
        rows_times(&self.rows, node, &self.qd)
    }

    /// The static reduced response: q solving K_r q = f on the active
    /// coordinates (None if K_r is singular there). Does not touch the state.
    pub fn static_solve(&self, f: &SVector<f64, R>) -> Option<SVector<f64, R>> {
        let mut k = self.k;
        for i in self.r..R {
            k[(i, i)] = 1.0;
        }
        let mut q = Cholesky::new(k)?.solve(f);
        for v in q.iter_mut().skip(self.r) {
            *v = 0.0;
        }
        Some(q)
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

    /// Active size r (basis columns in use).
    pub fn active(&self) -> usize {
        self.r
    }

    /// The reduced stiffness K_r (zero beyond the active block).
    pub fn stiffness(&self) -> &SMatrix<f64, R, R> {
        &self.k
    }

    /// Time step (s).
    pub fn dt(&self) -> f64 {
        self.dt
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row_times_matches_the_product_at<const R: usize>() {
        let row = SMatrix::<f64, 3, R>::from_fn(|i, j| (1.0 + i as f64) * (j as f64 * 0.7).sin() - 0.1 * j as f64);
        let v = SVector::<f64, R>::from_fn(|j, _| (j as f64 * 1.3).cos() + 0.01 * j as f64);
        let (fast, plain) = (row_times(&row, &v), row * v);
        assert!(
            (fast - plain).norm() <= 1e-13 * (1.0 + plain.norm()),
            "R = {R}: {fast} vs {plain}"
        );
    }

    #[test]
    fn row_times_is_the_matrix_vector_product_for_every_size() {
        row_times_matches_the_product_at::<1>();
        row_times_matches_the_product_at::<3>();
        row_times_matches_the_product_at::<4>();
        row_times_matches_the_product_at::<5>();
        row_times_matches_the_product_at::<32>();
        row_times_matches_the_product_at::<47>();
    }

    #[test]
    fn the_row_bound_is_the_largest_spectral_norm_and_bounds_every_nodes_motion() {
        // Rows of assorted shapes: random, rank one, a multiple of a
        // 3 × 3 identity block, zero.
        let mut seed = 7u64;
        let mut next = || {
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((seed >> 11) as f64 / (1u64 << 53) as f64) - 0.5
        };
        let mut rows: Vec<SMatrix<f64, 3, 8>> = (0..200).map(|_| SMatrix::from_fn(|_, _| next())).collect();
        let u = SVector::<f64, 8>::from_fn(|j, _| (j as f64 + 1.0).sin());
        rows.push(SMatrix::<f64, 3, 1>::new(1.0, -2.0, 0.5) * u.transpose() * 0.3);
        let mut eye = SMatrix::<f64, 3, 8>::zeros();
        eye.fixed_view_mut::<3, 3>(0, 2)
            .copy_from(&(SMatrix::<f64, 3, 3>::identity() * 0.9));
        rows.push(eye);
        rows.push(SMatrix::zeros());
        let bound = row_bound_of(&rows);
        let frobenius = rows.iter().map(|r| r.norm()).fold(0.0, f64::max);
        let spectral = rows
            .iter()
            .map(|r| r.svd(false, false).singular_values.max())
            .fold(0.0, f64::max);
        assert!(
            bound >= spectral && bound <= spectral * (1.0 + 1e-5),
            "{bound} vs {spectral}"
        );
        assert!(bound <= frobenius);
        for r in &rows {
            let s = r.svd(false, false).singular_values.max();
            assert!(
                (largest_symmetric_eigenvalue(&(r * r.transpose())).max(0.0).sqrt() - s).abs() <= 1e-9 * (1.0 + s),
                "{r}"
            );
            for _ in 0..20 {
                let dq = SVector::<f64, 8>::from_fn(|_, _| next());
                assert!((r * dq).norm() <= bound * dq.norm());
            }
        }
        assert_eq!(row_bound_of::<8>(&[]), 0.0);
    }

    /// One node, one mode along x with ω² = 4 (unit mass).
    fn one_mode() -> ModalBasis {
        ModalBasis {
            phi: DMatrix::from_column_slice(3, 1, &[1.0, 0.0, 0.0]),
            omega2: vec![4.0],
            num_static: 0,
            fixed: Vec::new(),
            iterations: 0,
        }
    }

    #[test]
    fn step_matches_the_scalar_implicit_euler_recurrence() {
        let p = DynamicsParams {
            dt: 0.01,
            alpha: 0.3,
            beta: 0.02,
        };
        let mut d = ReducedDynamics::<4>::new(&one_mode(), &p).unwrap();
        let f = d.project_nodal(&[(0, Vec3::new(2.0, 5.0, -1.0))]).unwrap();
        assert_eq!(f[0], 2.0);
        assert!(f.iter().skip(1).all(|&v| v == 0.0));
        let (k, h) = (4.0, p.dt);
        let (mut q, mut v) = (0.0f64, 0.0f64);
        let mut forced = f;
        // Forcing on inactive coordinates is ignored.
        forced[3] = 7.0;
        for _ in 0..200 {
            v = (v + h * (2.0 - k * q)) / (1.0 + h * (p.alpha + p.beta * k) + h * h * k);
            q += h * v;
            d.step(&forced);
        }
        assert!((d.q()[0] - q).abs() <= 1e-12 * q.abs());
        assert!((d.displacement_at(0).unwrap() - Vec3::new(q, 0.0, 0.0)).norm() <= 1e-12 * q.abs());
        assert!(d.q().iter().skip(1).all(|&v| v == 0.0));
        assert_eq!(d.static_solve(&f).unwrap()[0], 0.5);
    }

    /// Out of contact (k_c = 0) the step solves with the factor made with
    /// the model instead of factoring A again: the same state as a fresh
    /// factorization of A + h² · 0, to round-off, and a nonzero k_c still
    /// takes the fresh one.
    #[test]
    fn a_step_without_contact_stiffness_reuses_the_models_factor() {
        let p = DynamicsParams {
            dt: 1e-3,
            alpha: 5.0,
            beta: 1e-3,
        };
        let basis = ModalBasis {
            phi: DMatrix::from_fn(6, 2, |i, j| ((i + 1) * (j + 2)) as f64 * 0.1),
            omega2: vec![4.0, 9.0],
            num_static: 0,
            fixed: Vec::new(),
            iterations: 0,
        };
        let k_r = DMatrix::from_row_slice(2, 2, &[4.0, 0.5, 0.5, 9.0]);
        let mut d = ReducedDynamics::<4>::with_stiffness(&basis, &k_r, &p).unwrap();
        let f = SVector::<f64, 4>::new(1.0, -2.0, 0.0, 0.0);
        for k_c in [SMatrix::<f64, 4, 4>::zeros(), SMatrix::<f64, 4, 4>::identity() * 30.0] {
            d.set_state(
                &SVector::<f64, 4>::new(1e-3, -2e-3, 0.0, 0.0),
                &SVector::<f64, 4>::new(0.1, 0.2, 0.0, 0.0),
            );
            let mut a = d.a;
            for i in 0..2 {
                for j in 0..2 {
                    a[(i, j)] += p.dt * p.dt * k_c[(i, j)];
                }
            }
            let expected = Cholesky::new(a).unwrap().solve(&d.rhs(&f));
            assert!(d.step_with_contact(&f, &k_c));
            assert!((d.qd() - expected).norm() <= 1e-14 * expected.norm(), "k_c = {k_c}");
        }
    }

    /// The heartbeat's modal load is the explicit force g (p(t) − p_mean)
    /// at each step's end time, in every kind of step.
    #[test]
    fn the_pulse_is_the_modal_load_times_the_pulsatile_pressure() {
        use crate::solver::pressure::{WaveShape, Waveform};
        let p = DynamicsParams {
            dt: 0.01,
            alpha: 0.3,
            beta: 0.02,
        };
        let waveform = Waveform {
            systolic_pa: 16e3,
            diastolic_pa: 10e3,
            heart_rate_bpm: 75.0,
            shape: WaveShape::Aortic,
        };
        let mut g = SVector::<f64, 4>::zeros();
        g[0] = 2e-4;
        g[3] = 1.0; // inactive: ignored
        let mut beating = ReducedDynamics::<4>::new(&one_mode(), &p).unwrap();
        beating.set_pulse(Some(ModalPulse {
            load_per_pa: g,
            waveform,
            mean_pa: 12e3,
            t_s: 0.3,
        }));
        let mut plain = ReducedDynamics::<4>::new(&one_mode(), &p).unwrap();
        let kc = SMatrix::<f64, 4, 4>::identity() * 3.0;
        let mut t = 0.3;
        for k in 0..150 {
            t += p.dt;
            let mut f = SVector::<f64, 4>::zeros();
            f[0] = 2e-4 * (waveform.pressure_at(t) - 12e3);
            if k % 2 == 0 {
                beating.step(&SVector::zeros());
                plain.step(&f);
            } else {
                beating.step_with_contact(&SVector::zeros(), &kc);
                plain.step_with_contact(&f, &kc);
            }
        }
        assert!(plain.q()[0].abs() > 0.0);
        assert!((beating.q() - plain.q()).norm() <= 1e-12 * plain.q().norm());
        assert!((beating.pulse().unwrap().t_s - t).abs() < 1e-12);
    }

    #[test]
    fn stiff_contact_is_stable_and_reaches_the_penalty_equilibrium() {
        // A contact 1e4 times stiffer than the explicit limit 4/h²: the
        // linearized implicit step stays bounded and settles where
        // K q + k_c (q − g) = 0 for a constant gap g.
        let p = DynamicsParams {
            dt: 1e-3,
            alpha: 5.0,
            beta: 0.0,
        };
        let mut d = ReducedDynamics::<4>::new(&one_mode(), &p).unwrap();
        let kc_s = 4e10;
        let mut kc = SMatrix::<f64, 4, 4>::zeros();
        kc[(0, 0)] = kc_s;
        let g = 1e-3;
        for _ in 0..2000 {
            let mut f = SVector::<f64, 4>::zeros();
            f[0] = kc_s * (g - d.q()[0]);
            assert!(d.step_with_contact(&f, &kc));
            assert!(d.q()[0].abs() <= 2.0 * g);
        }
        let q_eq = kc_s * g / (kc_s + 4.0);
        assert!((d.q()[0] - q_eq).abs() <= 1e-9, "{} vs {q_eq}", d.q()[0]);
        d.reset();
        assert_eq!(d.q()[0], 0.0);
        // A non-PSD "contact" is refused for that step.
        kc[(0, 0)] = -1e12;
        assert!(!d.step_with_contact(&SVector::zeros(), &kc));
    }

    #[test]
    fn bad_sizes_and_parameters_are_errors() {
        let b = one_mode();
        let p = DynamicsParams {
            dt: 1e-3,
            alpha: 0.0,
            beta: 0.0,
        };
        assert!(matches!(
            ReducedDynamics::<0>::new(&b, &p),
            Err(ReducedError::Capacity { size: 1, capacity: 0 })
        ));
        let bad = DynamicsParams { dt: 0.0, ..p };
        assert!(matches!(
            ReducedDynamics::<2>::new(&b, &bad),
            Err(ReducedError::BadParameter { name: "dt", .. })
        ));
        let d = ReducedDynamics::<2>::new(&b, &p).unwrap();
        assert_eq!(d.project_nodal(&[(1, Vec3::zeros())]), Err(NodeOutOfRange(1)));
        assert_eq!(d.displacement_at(1), None);
    }

    #[test]
    fn prony_creep_follows_the_standard_linear_solid() {
        // One mode, stiff and critically damped next to τ: the held-force
        // response is quasi-static, u(t)/u_el = 1/(1−α) − α/(1−α) e^{−t(1−α)/τ}.
        let omega2: f64 = 1e6;
        let b = ModalBasis {
            omega2: vec![omega2],
            ..one_mode()
        };
        let p = DynamicsParams {
            dt: 1e-4,
            alpha: 2.0 * omega2.sqrt(),
            beta: 0.0,
        };
        let (a, tau) = (0.5, 0.5);
        let mut d = ReducedDynamics::<4>::new(&b, &p).unwrap();
        d.set_prony(&[PronyTerm { alpha: a, tau }]).unwrap();
        assert_eq!(d.prony().len(), 1);
        let mut f = SVector::<f64, 4>::zeros();
        f[0] = 1.0;
        let u_el = 1.0 / omega2;
        let tau_c = tau / (1.0 - a);
        let mut worst: f64 = 0.0;
        for n in 1..=(5.0 * tau_c / p.dt) as usize {
            d.step(&f);
            let t = n as f64 * p.dt;
            if t > 0.02 {
                let want = 1.0 / (1.0 - a) - a / (1.0 - a) * (-t / tau_c).exp();
                worst = worst.max((d.q()[0] / u_el - want).abs() / want);
            }
        }
        assert!(worst < 5e-3, "creep error {worst}");
        // Off again: the plain elastic step, bit for bit.
        let mut e = ReducedDynamics::<4>::new(&b, &p).unwrap();
        d.set_prony(&[]).unwrap();
        d.reset();
        for _ in 0..50 {
            d.step(&f);
            e.step(&f);
        }
        assert_eq!(d.q(), e.q());
        assert!(d
            .set_prony(&[PronyTerm { alpha: 0.6, tau: 1.0 }, PronyTerm { alpha: 0.5, tau: 1.0 }])
            .is_err());
    }

    #[test]
    fn a_part_stepped_beside_the_state_is_the_response_to_its_load_alone() {
        // Two modes with Prony terms and a contact stiffness that changes
        // every step: the part stepped with load b equals a model driven by
        // b alone, and the rest equals a model driven by a alone.
        let b = ModalBasis {
            phi: DMatrix::from_column_slice(3, 2, &[1.0, 0.0, 0.0, 0.3, 1.0, 0.0]),
            omega2: vec![4.0, 90.0],
            ..one_mode()
        };
        let p = DynamicsParams {
            dt: 1e-3,
            alpha: 5.0,
            beta: 1e-3,
        };
        let prony = [PronyTerm { alpha: 0.3, tau: 0.05 }];
        let mk = || {
            let mut d = ReducedDynamics::<4>::new(&b, &p).unwrap();
            d.set_prony(&prony).unwrap();
            d
        };
        let (mut whole, mut only_a, mut only_b) = (mk(), mk(), mk());
        let mut part = ReducedPart::<4>::default();
        for n in 0..3000 {
            let t = n as f64 * 1e-3;
            let mut kc = SMatrix::<f64, 4, 4>::zeros();
            kc[(0, 0)] = 1e6 * (1.0 + (7.0 * t).sin());
            kc[(0, 1)] = 2e5;
            kc[(1, 0)] = 2e5;
            kc[(1, 1)] = 1e6;
            let fa = SVector::<f64, 4>::from_column_slice(&[(3.0 * t).cos(), 0.5, 0.0, 0.0]);
            let fb = SVector::<f64, 4>::from_column_slice(&[-0.2, (11.0 * t).sin(), 0.0, 0.0]);
            assert!(whole.step_with_contact_and(&(fa + fb), &kc, &mut part, &fb));
            only_a.step_with_contact(&fa, &kc);
            only_b.step_with_contact(&fb, &kc);
        }
        let scale = whole.q().norm();
        assert!(
            (part.q - only_b.q()).norm() <= 1e-12 * scale,
            "{} vs {}",
            part.q,
            only_b.q()
        );
        assert!((whole.q() - part.q - only_a.q()).norm() <= 1e-12 * scale);
        assert!((part.qd - only_b.qd()).norm() <= 1e-9 * (1.0 + only_b.qd().norm()));
        assert!(part.q.norm() > 1e-3 * scale, "the test's loads must move the part");
        // The transfer carries it; a non-finite one is dropped.
        let t = SMatrix::<f64, 4, 4>::identity() * 2.0;
        assert_eq!(part.transferred(&t).q, part.q * 2.0);
        let mut bad = part;
        bad.q[0] = f64::NAN;
        assert_eq!(bad.transferred(&t), ReducedPart::default());
    }
}
