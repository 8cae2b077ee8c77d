//! Backward Euler for eq. 2, M ü + D u̇ − f(u) = f_ext, with Newton on the
//! new velocity.
//!
//! With h the step, the unknown is v₁ and u₁ = u₀ + h v₁. The residual is
//!
//! ```text
//! r(v₁) = M (v₁ − v₀) − h [ f(u₀ + h v₁) − D v₁ + f_ext(t₀ + h) ],   D = α M + β K₀
//! ```
//!
//! where f = −∂W/∂u is the model's internal force and K₀ = K(u₀) the tangent
//! at the start of the step (K = −∂f/∂u). Freezing the damping tangent over
//! the step keeps r an exact function of v₁, so the Newton Jacobian
//!
//! ```text
//! A = (1 + hα) M + hβ K₀ + h² K(u₀ + h v₁)
//! ```
//!
//! is exact and Newton converges quadratically even with stiffness damping.
//! Newton starts from v₁ = 0, i.e. it linearizes at u₀: with one iteration
//! the step is exactly the linearized implicit Euler step SOFA's
//! `EulerImplicitSolver` takes (A = (1 + hα) M + (hβ + h²) K(u₀)).
//!
//! With `stiffness_every = k > 1` the Newton matrix A (and the linear
//! solver's preconditioner or factor, and the stiffness-damping tangent) is
//! built at the first Newton iteration of every k-th step only and reused
//! until the next refresh: a chord method whose residual still uses the
//! exact forces, trading Newton's quadratic convergence (and, with one
//! iteration, some accuracy per step) for skipping the assembly and the
//! factorization.
//!
//! Fixed nodes keep u = 0 and v = 0: their rows and columns of A are replaced
//! by the identity and their residual is zero.
//!
//! All vectors and matrices are allocated in [`ImplicitEuler::new`] and
//! reused; [`ImplicitEuler::step`] does not allocate (the CG path and the
//! Cholesky path, whose scratch is sized up front). A failed step leaves the
//! state exactly as it was.

use super::linear::{project_fixed, LinearFailure, LinearSolver, LinearSolverKind};
use super::loads::{validate_fixed, LoadError, Loads};
use super::TissueState;
use crate::math::Mat3;
use crate::math::Vec3;
use crate::mesh::TetMesh;
use crate::model::{BlockTangent, ForceModel};

/// Largest allowed `newton.max_iters` (the report stores one residual per
/// iteration in a fixed array).
pub const MAX_NEWTON_ITERS: usize = 32;

fn default_max_iters() -> usize {
    5
}
fn default_rel_tol() -> f64 {
    1e-6
}
fn default_growth() -> f64 {
    1e3
}
fn default_dt() -> f64 {
    1e-3
}
fn default_stiffness_every() -> usize {
    1
}
fn default_true() -> bool {
    true
}

/// Newton iteration control.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NewtonParams {
    /// Maximum Newton iterations (linear solves) per step, 1..=32. One gives
    /// the linearized step of SOFA's EulerImplicit.
    #[serde(default = "default_max_iters")]
    pub max_iters: usize,
    /// Converged when ‖r_k‖ ≤ rel_tol ‖r_0‖ (r_0: residual at v₁ = 0).
    #[serde(default = "default_rel_tol")]
    pub rel_tol: f64,
    /// … or when ‖r_k‖ ≤ abs_tol (N·s; the residual is a momentum).
    #[serde(default)]
    pub abs_tol: f64,
    /// If true, a step that has not converged after `max_iters` fails (state
    /// unchanged); if false it is accepted and reported as not converged.
    #[serde(default)]
    pub require_convergence: bool,
    /// The step fails if ‖r_k‖ > max_residual_growth ‖r_0‖ (divergence).
    #[serde(default = "default_growth")]
    pub max_residual_growth: f64,
    /// Re-evaluate the residual after the last allowed update (one extra
    /// force evaluation per step) so the report carries the committed
    /// state's true residual and `converged` flag. The default, true. With
    /// false a step that uses all `max_iters` updates stops right after the
    /// last one: the committed state is bitwise the same, but the report
    /// lacks its residual and says `converged = false`; this needs
    /// `require_convergence = false`.
    #[serde(default = "default_true")]
    pub check_final_residual: bool,
}

impl Default for NewtonParams {
    fn default() -> Self {
        NewtonParams {
            max_iters: default_max_iters(),
            rel_tol: default_rel_tol(),
            abs_tol: 0.0,
            require_convergence: false,
            max_residual_growth: default_growth(),
            check_final_residual: true,
        }
    }
}

impl NewtonParams {
    /// One Newton iteration, always accepted: the linearized step.
    pub fn linearized() -> NewtonParams {
        NewtonParams {
            max_iters: 1,
            ..NewtonParams::default()
        }
    }
}

/// Integrator configuration (scene TOML `[integrator]`).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ImplicitEulerParams {
    /// Time step h (s).
    #[serde(default = "default_dt")]
    pub dt: f64,
    /// Rayleigh mass coefficient α (1/s): D = α M + β K.
    #[serde(default)]
    pub rayleigh_alpha: f64,
    /// Rayleigh stiffness coefficient β (s).
    #[serde(default)]
    pub rayleigh_beta: f64,
    /// Newton control.
    #[serde(default)]
    pub newton: NewtonParams,
    /// Linear solver for the Newton systems.
    #[serde(default)]
    pub linear: LinearSolverKind,
    /// Tangent refresh interval k ≥ 1. With 1 (the default) every Newton
    /// iteration re-assembles K and rebuilds the preconditioner or
    /// factorization: exact Newton. With k > 1 the Newton matrix A, the
    /// stiffness-damping tangent and the preconditioner/factor are rebuilt
    /// only at the first Newton iteration of every k-th step and reused for
    /// every Newton iteration of the steps in between (a chord method; with
    /// one Newton iteration a semi-implicit step with a lagged Jacobian).
    /// The residual always uses the exact current forces. It is also rebuilt
    /// after a failed step and when the fixed set changes. Accuracy cost:
    /// `docs/SOLVERS.md`.
    #[serde(default = "default_stiffness_every")]
    pub stiffness_every: usize,
    /// Step halving on failure, 0..=[`MAX_HALVINGS`]. With 0 (the default) a
    /// failed step is reported as it is. With m > 0 a step that fails for a
    /// numerical reason (indefinite or singular Newton matrix, non-finite
    /// force, residual growth, no convergence, blow-up) is retried over the
    /// same interval with steps of h/2; a sub-step that fails again is
    /// halved again, down to h/2^m. The loads are evaluated at each
    /// sub-step's end time and the Prony history advances per sub-step. If
    /// a sub-step fails at h/2^m the whole step is rolled back (state and
    /// model history) and reported with the last failure.
    /// `StepReport::substeps` tells how many sub-steps a step took.
    #[serde(default)]
    pub max_halvings: usize,
}

/// Largest `max_halvings`: sub-steps of h/4096.
pub const MAX_HALVINGS: usize = 12;

impl Default for ImplicitEulerParams {
    fn default() -> Self {
        ImplicitEulerParams {
            dt: default_dt(),
            rayleigh_alpha: 0.0,
            rayleigh_beta: 0.0,
            newton: NewtonParams::default(),
            linear: LinearSolverKind::default(),
            stiffness_every: default_stiffness_every(),
            max_halvings: 0,
        }
    }
}

impl ImplicitEulerParams {
    /// Checks every field; the error names the key and the allowed range.
    pub fn validate(&self) -> Result<(), String> {
        let n = &self.newton;
        if !(self.dt.is_finite() && self.dt > 0.0) {
            return Err(format!("dt = {}: must be finite and > 0", self.dt));
        }
        if !(self.rayleigh_alpha.is_finite() && self.rayleigh_alpha >= 0.0) {
            return Err(format!(
                "rayleigh_alpha = {}: must be finite and >= 0",
                self.rayleigh_alpha
            ));
        }
        if !(self.rayleigh_beta.is_finite() && self.rayleigh_beta >= 0.0) {
            return Err(format!(
                "rayleigh_beta = {}: must be finite and >= 0",
                self.rayleigh_beta
            ));
        }
        if !(1..=MAX_NEWTON_ITERS).contains(&n.max_iters) {
            return Err(format!(
                "newton.max_iters = {}: must be in 1..={MAX_NEWTON_ITERS}",
                n.max_iters
            ));
        }
        if !(n.rel_tol.is_finite() && n.rel_tol >= 0.0 && n.rel_tol < 1.0) {
            return Err(format!("newton.rel_tol = {}: must be in [0, 1)", n.rel_tol));
        }
        if !(n.abs_tol.is_finite() && n.abs_tol >= 0.0) {
            return Err(format!("newton.abs_tol = {}: must be finite and >= 0", n.abs_tol));
        }
        if n.require_convergence && !n.check_final_residual {
            return Err(
                "newton.check_final_residual = false: needs newton.require_convergence = false (convergence would be unknown)"
                    .into(),
            );
        }
        if !(n.max_residual_growth.is_finite() && n.max_residual_growth >= 1.0) {
            return Err(format!(
                "newton.max_residual_growth = {}: must be finite and >= 1",
                n.max_residual_growth
            ));
        }
        if self.stiffness_every == 0 {
            return Err("stiffness_every = 0: must be at least 1".into());
        }
        if self.max_halvings > MAX_HALVINGS {
            return Err(format!(
                "max_halvings = {}: must be in 0..={MAX_HALVINGS}",
                self.max_halvings
            ));
        }
        self.linear.validate()
    }
}

/// Why a step failed. The state is unchanged when a step reports one.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum StepFailure {
    /// The state passed in has the wrong length or a non-finite value.
    BadState,
    /// A fixed node or a load is invalid.
    BadLoads(LoadError),
    /// The internal or external force is not finite at this Newton iteration.
    NonFiniteForce {
        /// Newton iteration (0-based).
        newton_iter: usize,
    },
    /// The assembled stiffness is not finite at this Newton iteration.
    NonFiniteStiffness {
        /// Newton iteration (0-based).
        newton_iter: usize,
    },
    /// The linear solver failed at this Newton iteration.
    Linear {
        /// Newton iteration (0-based).
        newton_iter: usize,
        /// What the linear solver reported.
        reason: LinearFailure,
    },
    /// The residual grew beyond `max_residual_growth` times the initial one.
    ResidualGrowth {
        /// Newton iteration (0-based) where it was seen.
        newton_iter: usize,
        /// ‖r_k‖ / ‖r_0‖.
        ratio: f64,
    },
    /// Not converged after `max_iters` with `require_convergence` set.
    NotConverged {
        /// Final ‖r‖ / ‖r_0‖.
        rel_residual: f64,
    },
    /// The new displacement is finite but absurd: larger than
    /// [`MAX_DISPLACEMENT_DIAGONALS`] times the mesh's bounding-box diagonal
    /// (a blow-up that produced no NaN).
    Blowup {
        /// Largest nodal displacement of the rejected iterate (m).
        max_displacement: f64,
    },
}

impl StepFailure {
    /// Whether a smaller step might succeed (everything but bad input).
    pub fn retryable(&self) -> bool {
        !matches!(self, StepFailure::BadState | StepFailure::BadLoads(_))
    }
}

/// A step whose largest displacement exceeds this many bounding-box
/// diagonals of the rest mesh is rejected as a blow-up.
pub const MAX_DISPLACEMENT_DIAGONALS: f64 = 10.0;

impl std::fmt::Display for StepFailure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            StepFailure::BadState => write!(f, "state has the wrong size or a non-finite value"),
            StepFailure::BadLoads(e) => write!(f, "{e}"),
            StepFailure::NonFiniteForce { newton_iter } => {
                write!(f, "non-finite force at Newton iteration {newton_iter}")
            }
            StepFailure::NonFiniteStiffness { newton_iter } => {
                write!(f, "non-finite stiffness at Newton iteration {newton_iter}")
            }
            StepFailure::Linear { newton_iter, reason } => write!(f, "Newton iteration {newton_iter}: {reason}"),
            StepFailure::ResidualGrowth { newton_iter, ratio } => {
                write!(
                    f,
                    "Newton diverged: residual grew {ratio:e}x by iteration {newton_iter}"
                )
            }
            StepFailure::NotConverged { rel_residual } => {
                write!(f, "Newton not converged (relative residual {rel_residual:e})")
            }
            StepFailure::Blowup { max_displacement } => write!(
                f,
                "blow-up: a displacement of {max_displacement:e} m exceeds {MAX_DISPLACEMENT_DIAGONALS} mesh diagonals"
            ),
        }
    }
}

/// What one step did. `Copy`, fixed size: the RT path can keep it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepReport {
    /// Newton iterations (linear solves) done.
    pub newton_iters: usize,
    /// Total CG iterations over the step (0 with Cholesky).
    pub linear_iters: usize,
    residuals: [f64; MAX_NEWTON_ITERS + 1],
    num_residuals: usize,
    /// Whether the Newton tolerance was met (by every sub-step).
    pub converged: bool,
    /// Why the step failed; `None` when the state was advanced.
    pub failure: Option<StepFailure>,
    /// Sub-steps the step was covered with: 1 without halving, more when
    /// `max_halvings` split it; 0 when it failed.
    pub substeps: usize,
}

impl StepReport {
    fn new() -> StepReport {
        StepReport {
            newton_iters: 0,
            linear_iters: 0,
            residuals: [0.0; MAX_NEWTON_ITERS + 1],
            num_residuals: 0,
            converged: false,
            failure: None,
            substeps: 1,
        }
    }

    /// Relative residuals ‖r_k‖ / ‖r_0‖, one per evaluated iterate (the first
    /// is 1, or 0 when r_0 = 0); the last one belongs to the accepted iterate.
    pub fn residuals(&self) -> &[f64] {
        &self.residuals[..self.num_residuals]
    }

    /// Whether the state was advanced.
    pub fn ok(&self) -> bool {
        self.failure.is_none()
    }

    fn push(&mut self, r: f64) {
        if self.num_residuals < self.residuals.len() {
            self.residuals[self.num_residuals] = r;
            self.num_residuals += 1;
        }
    }
}

/// What is wrong with the integrator's construction.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SolverError {
    /// A parameter is out of range.
    #[error("integrator: {0}")]
    Params(String),
    /// The mass vector does not match the mesh.
    #[error("integrator: {got} nodal masses for a mesh of {nodes} nodes")]
    MassLength {
        /// Masses given.
        got: usize,
        /// Nodes in the mesh.
        nodes: usize,
    },
    /// A nodal mass is not finite and positive.
    #[error("integrator: mass of node {node} is {value} (must be finite and > 0)")]
    BadMass {
        /// The node.
        node: usize,
        /// Its mass.
        value: f64,
    },
    /// The linear solver could not be built.
    #[error("integrator: {0}")]
    Linear(String),
}

/// The backward Euler integrator with its preallocated work memory.
#[derive(Debug)]
pub struct ImplicitEuler {
    /// Bounding-box diagonal of the rest mesh (m), for the blow-up check.
    diagonal: f64,
    params: ImplicitEulerParams,
    mass: Vec<f64>,
    linear: LinearSolver,
    fixed_mask: Vec<bool>,
    /// The fixed set the lagged tangent was built with.
    lag_mask: Vec<bool>,
    /// Steps completed since the lagged tangent (A and the prepared linear
    /// solver) was built; `None` when there is none to reuse.
    tangent_age: Option<usize>,
    u0: Vec<Vec3>,
    v1: Vec<Vec3>,
    ut: Vec<Vec3>,
    f: Vec<Vec3>,
    fext: Vec<Vec3>,
    r: Vec<Vec3>,
    dv: Vec<Vec3>,
    k0v: Vec<Vec3>,
    k: BlockTangent,
    /// Whether `k` holds an assembled stiffness (a step that starts in
    /// equilibrium stops before assembling one).
    k_assembled: bool,
    k0: BlockTangent,
    a: BlockTangent,
    /// The state at the start of a step being split (`max_halvings`).
    saved_u: Vec<Vec3>,
    saved_v: Vec<Vec3>,
}

fn all_finite(x: &[Vec3]) -> bool {
    x.iter().all(|v| v.iter().all(|c| c.is_finite()))
}

fn block_finite(k: &BlockTangent) -> bool {
    k.diag.iter().chain(&k.off).all(|b| b.iter().all(|c| c.is_finite()))
}

impl ImplicitEuler {
    /// Builds the integrator for `mesh` with lumped nodal masses `mass` (kg).
    pub fn new(mesh: &TetMesh, mass: Vec<f64>, params: ImplicitEulerParams) -> Result<ImplicitEuler, SolverError> {
        params.validate().map_err(SolverError::Params)?;
        let n = mesh.num_nodes();
        if mass.len() != n {
            return Err(SolverError::MassLength {
                got: mass.len(),
                nodes: n,
            });
        }
        if let Some((node, &value)) = mass.iter().enumerate().find(|(_, m)| !(m.is_finite() && **m > 0.0)) {
            return Err(SolverError::BadMass { node, value });
        }
        let k = BlockTangent::zeros(mesh);
        let linear = LinearSolver::new(&params.linear, &k).map_err(SolverError::Linear)?;
        let zeros = vec![Vec3::zeros(); n];
        let (lo, hi) = mesh.bbox();
        Ok(ImplicitEuler {
            diagonal: (hi - lo).norm(),
            params,
            mass,
            linear,
            fixed_mask: vec![false; n],
            lag_mask: vec![false; n],
            tangent_age: None,
            u0: zeros.clone(),
            v1: zeros.clone(),
            ut: zeros.clone(),
            f: zeros.clone(),
            fext: zeros.clone(),
            r: zeros.clone(),
            dv: zeros.clone(),
            k0v: zeros.clone(),
            saved_u: zeros.clone(),
            saved_v: zeros,
            k0: k.clone(),
            a: k.clone(),
            k,
            k_assembled: false,
        })
    }

    /// The configuration.
    pub fn params(&self) -> &ImplicitEulerParams {
        &self.params
    }

    /// The lumped nodal masses (kg).
    pub fn mass(&self) -> &[f64] {
        &self.mass
    }

    /// The last assembled Newton matrix A (fixed rows projected), for
    /// inspection and tests.
    pub fn last_matrix(&self) -> &BlockTangent {
        &self.a
    }

    /// Changes the time step for the following steps (the haptic service's
    /// background solve follows real time). A non-positive or non-finite
    /// `dt` is ignored. Forces a fresh tangent on the next step.
    pub fn set_dt(&mut self, dt: f64) {
        if dt.is_finite() && dt > 0.0 && dt != self.params.dt {
            self.params.dt = dt;
            self.tangent_age = None;
        }
    }

    /// The stiffness K(u) assembled at the last Newton iterate of the last
    /// step (for the linearized step: at the step's start), before the
    /// fixed rows were projected. The background solve of the haptic service
    /// projects it into the reduced basis instead of assembling it again.
    pub fn last_stiffness(&self) -> &BlockTangent {
        &self.k
    }

    /// Whether [`ImplicitEuler::last_stiffness`] holds an assembled
    /// stiffness. It does not before the first step that iterated: a step
    /// that starts in equilibrium (zero residual, e.g. at rest under no
    /// load) converges before assembling one, and the stiffness is then
    /// still all zeros.
    pub fn has_stiffness(&self) -> bool {
        self.k_assembled
    }

    /// v₁ += Δv on the free nodes; when `last` (the final iteration and no
    /// final residual check), also forms the committed iterate and returns
    /// true so the Newton loop stops.
    fn apply_update(&mut self, last: bool, h: f64) -> bool {
        for ((v1, dv), &fx) in self.v1.iter_mut().zip(&self.dv).zip(&self.fixed_mask) {
            if !fx {
                *v1 += dv;
            }
        }
        if last {
            self.set_iterate(h);
        }
        last
    }

    /// ut = u₀ + h v₁ (the iterate the step commits).
    fn set_iterate(&mut self, h: f64) {
        for ((ut, u0), v1) in self.ut.iter_mut().zip(&self.u0).zip(&self.v1) {
            *ut = u0 + h * v1;
        }
    }

    /// Advances `state` by one step of length `params.dt`. Calls
    /// `model.begin_step(dt)` first and `model.end_step(&u)` after a
    /// successful step. On failure `state` is left bitwise unchanged (and
    /// `end_step` is not called) and the report says why.
    pub fn step(
        &mut self,
        state: &mut TissueState,
        model: &mut dyn ForceModel,
        loads: &Loads,
        fixed: &[u32],
    ) -> StepReport {
        let mut rep = self.step_inner(state, model, loads, fixed);
        if !rep.ok() {
            // A, K or the prepared solver may be half-updated.
            self.tangent_age = None;
            rep.substeps = 0;
            if self.params.max_halvings > 0 && rep.failure.is_some_and(|f| f.retryable()) {
                return self.split_step(state, model, loads, fixed, rep);
            }
        }
        rep
    }

    /// Covers the step that just failed with halved sub-steps (see
    /// [`ImplicitEulerParams::max_halvings`]); rolls everything back if a
    /// sub-step fails at the finest level.
    fn split_step(
        &mut self,
        state: &mut TissueState,
        model: &mut dyn ForceModel,
        loads: &Loads,
        fixed: &[u32],
        first: StepReport,
    ) -> StepReport {
        let h = self.params.dt;
        let t0 = state.t;
        let max = self.params.max_halvings;
        self.saved_u.copy_from_slice(&state.u);
        self.saved_v.copy_from_slice(&state.v);
        model.save_state();
        let mut out = first;
        out.converged = true;
        out.substeps = 0;
        // The interval in units of h / 2^max; a sub-step at `level` covers
        // 2^(max − level) of them, so the remainder stays a multiple.
        let mut remaining: u64 = 1 << max;
        let mut level = 1;
        let mut failure = None;
        self.params.dt = h / 2.0;
        self.tangent_age = None;
        while remaining > 0 {
            let rep = self.step_inner(state, model, loads, fixed);
            out.newton_iters += rep.newton_iters;
            out.linear_iters += rep.linear_iters;
            if rep.ok() {
                remaining -= 1 << (max - level);
                out.substeps += 1;
                out.converged &= rep.converged;
                out.residuals = rep.residuals;
                out.num_residuals = rep.num_residuals;
                continue;
            }
            self.tangent_age = None;
            if level == max || !rep.failure.is_some_and(|f| f.retryable()) {
                failure = rep.failure;
                break;
            }
            level += 1;
            self.params.dt = h / (1u64 << level) as f64;
        }
        self.params.dt = h;
        self.tangent_age = None;
        if let Some(f) = failure {
            state.u.copy_from_slice(&self.saved_u);
            state.v.copy_from_slice(&self.saved_v);
            state.t = t0;
            model.restore_state();
            out.failure = Some(f);
            out.converged = false;
            out.substeps = 0;
        } else {
            // Exact end time (the sub-steps' sum may differ in the last bit).
            state.t = t0 + h;
            out.failure = None;
        }
        out
    }

    fn step_inner(
        &mut self,
        state: &mut TissueState,
        model: &mut dyn ForceModel,
        loads: &Loads,
        fixed: &[u32],
    ) -> StepReport {
        let mut rep = StepReport::new();
        let n = self.mass.len();
        if state.u.len() != n || state.v.len() != n || !state.is_finite() {
            rep.failure = Some(StepFailure::BadState);
            return rep;
        }
        if let Err(e) = validate_fixed(fixed, n).and_then(|_| loads.validate(n)) {
            rep.failure = Some(StepFailure::BadLoads(e));
            return rep;
        }
        let h = self.params.dt;
        let (alpha, beta) = (self.params.rayleigh_alpha, self.params.rayleigh_beta);
        let np = self.params.newton;
        let t1 = state.t + h;
        // The damping tangent K₀ needs its own copy only if the stiffness is
        // re-assembled later in the step.
        let keep_k0 = beta != 0.0 && np.max_iters > 1;

        self.fixed_mask.iter_mut().for_each(|m| *m = false);
        for &i in fixed {
            self.fixed_mask[i as usize] = true;
        }
        // Tangent reuse (`stiffness_every` > 1): rebuild A at the first
        // Newton iteration when it is k steps old, missing, or built for
        // another fixed set; otherwise every iteration reuses it.
        let every = self.params.stiffness_every;
        let lagged = every > 1;
        let rebuild = match self.tangent_age {
            Some(age) => age + 1 >= every || self.lag_mask != self.fixed_mask,
            None => true,
        };
        let mut built = false;
        for ((u0, u), &fx) in self.u0.iter_mut().zip(&state.u).zip(&self.fixed_mask) {
            *u0 = if fx { Vec3::zeros() } else { *u };
        }
        self.fext.iter_mut().for_each(|x| *x = Vec3::zeros());
        loads.add_forces(t1, &self.mass, &mut self.fext);
        self.v1.iter_mut().for_each(|x| *x = Vec3::zeros());

        model.begin_step(h);
        let mut r0 = 0.0;
        let mut k = 0;
        loop {
            // Residual at the current iterate.
            self.set_iterate(h);
            self.f.copy_from_slice(&self.fext);
            model.add_forces(&self.ut, &mut self.f);
            loads.add_follower_forces(t1, &self.ut, &mut self.f);
            if !all_finite(&self.f) {
                rep.failure = Some(StepFailure::NonFiniteForce { newton_iter: k });
                return rep;
            }
            let damp_k = beta != 0.0 && k > 0;
            if damp_k {
                let k0 = if keep_k0 { &self.k0 } else { &self.k };
                k0.mul(&self.v1, &mut self.k0v);
            }
            let mut rn2 = 0.0;
            for i in 0..n {
                if self.fixed_mask[i] {
                    self.r[i] = Vec3::zeros();
                    continue;
                }
                let m = self.mass[i];
                let mut damping = alpha * m * self.v1[i];
                if damp_k {
                    damping += beta * self.k0v[i];
                }
                let ri = m * (self.v1[i] - state.v[i]) - h * (self.f[i] - damping);
                rn2 += ri.norm_squared();
                self.r[i] = ri;
            }
            let rn = rn2.sqrt();
            if !rn.is_finite() {
                rep.failure = Some(StepFailure::NonFiniteForce { newton_iter: k });
                return rep;
            }
            if k == 0 {
                r0 = rn;
            }
            let rel = if r0 > 0.0 { rn / r0 } else { 0.0 };
            rep.push(rel);
            if rn <= np.rel_tol * r0 || rn <= np.abs_tol || r0 == 0.0 {
                rep.converged = true;
                break;
            }
            if rel > np.max_residual_growth {
                rep.failure = Some(StepFailure::ResidualGrowth {
                    newton_iter: k,
                    ratio: rel,
                });
                return rep;
            }
            if k == np.max_iters {
                break;
            }

            if lagged && !(k == 0 && rebuild) {
                // Chord iteration on the lagged A (exact forces in r).
                for (i, x) in self.r.iter_mut().enumerate() {
                    *x = -*x;
                    self.dv[i] = if k == 0 && !self.fixed_mask[i] {
                        state.v[i]
                    } else {
                        Vec3::zeros()
                    };
                }
                match self.linear.solve_prepared(&self.a, &self.r, &mut self.dv) {
                    Ok(s) => rep.linear_iters += s.iters,
                    Err(reason) => {
                        rep.failure = Some(StepFailure::Linear { newton_iter: k, reason });
                        return rep;
                    }
                }
                k += 1;
                rep.newton_iters = k;
                if self.apply_update(k == np.max_iters && !np.check_final_residual, h) {
                    break;
                }
                continue;
            }

            // Newton matrix A = (1 + hα) M + hβ K₀ + h² K(u_k).
            self.k.clear();
            self.k_assembled = false;
            model.add_stiffness(&self.ut, &mut self.k);
            loads.add_follower_stiffness(t1, &self.ut, &mut self.k);
            if !block_finite(&self.k) {
                rep.failure = Some(StepFailure::NonFiniteStiffness { newton_iter: k });
                return rep;
            }
            self.k_assembled = true;
            if k == 0 && keep_k0 {
                // Not `clone_from`: the derived one reallocates.
                self.k0.diag.copy_from_slice(&self.k.diag);
                self.k0.off.copy_from_slice(&self.k.off);
            }
            let cm = 1.0 + h * alpha;
            let (ck, ck0) = if k == 0 || !keep_k0 {
                // At k = 0, K(u_k) = K₀; without a kept K₀ (β = 0 or a
                // single iteration) the hβ term is either zero or K(u₀).
                (h * h + if k == 0 { h * beta } else { 0.0 }, 0.0)
            } else {
                (h * h, h * beta)
            };
            for (i, (ad, kd)) in self.a.diag.iter_mut().zip(&self.k.diag).enumerate() {
                *ad = Mat3::identity() * (cm * self.mass[i]) + kd * ck;
            }
            for (ao, ko) in self.a.off.iter_mut().zip(&self.k.off) {
                *ao = ko * ck;
            }
            if ck0 != 0.0 {
                self.a.add_scaled(ck0, &self.k0);
            }
            project_fixed(&mut self.a, &self.fixed_mask);
            if lagged {
                if let Err(reason) = self.linear.prepare(&self.a) {
                    rep.failure = Some(StepFailure::Linear { newton_iter: k, reason });
                    return rep;
                }
                built = true;
                self.lag_mask.copy_from_slice(&self.fixed_mask);
            }

            // Solve A Δv = −r, warm-starting CG with v₀ at the first
            // iteration (Δv = v₁ there) and zero afterwards.
            for (i, x) in self.r.iter_mut().enumerate() {
                *x = -*x;
                self.dv[i] = if k == 0 && !self.fixed_mask[i] {
                    state.v[i]
                } else {
                    Vec3::zeros()
                };
            }
            let solved = if lagged {
                self.linear.solve_prepared(&self.a, &self.r, &mut self.dv)
            } else {
                self.linear.solve(&self.a, &self.r, &mut self.dv)
            };
            match solved {
                Ok(s) => rep.linear_iters += s.iters,
                Err(reason) => {
                    rep.failure = Some(StepFailure::Linear { newton_iter: k, reason });
                    return rep;
                }
            }
            k += 1;
            rep.newton_iters = k;
            if self.apply_update(k == np.max_iters && !np.check_final_residual, h) {
                break;
            }
        }
        if !rep.converged && np.require_convergence {
            rep.failure = Some(StepFailure::NotConverged {
                rel_residual: rep.residuals().last().copied().unwrap_or(f64::NAN),
            });
            return rep;
        }
        let max_u = self.ut.iter().map(|u| u.norm()).fold(0.0, f64::max);
        if max_u > MAX_DISPLACEMENT_DIAGONALS * self.diagonal {
            rep.failure = Some(StepFailure::Blowup {
                max_displacement: max_u,
            });
            return rep;
        }
        if lagged {
            self.tangent_age = if built {
                Some(0)
            } else {
                self.tangent_age.map(|a| a + 1)
            };
        }
        // Accept: ut = u₀ + h v₁ belongs to the final v₁.
        state.u.copy_from_slice(&self.ut);
        state.v.copy_from_slice(&self.v1);
        state.t = t1;
        model.end_step(&state.u);
        rep
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solver::Preconditioner;

    #[test]
    fn params_from_scene_toml() {
        let p: ImplicitEulerParams = toml::from_str(
            "dt = 0.005\nrayleigh_alpha = 0.1\n[newton]\nmax_iters = 3\n\
             [linear]\nkind = \"cg\"\nprecond = \"block_ssor\"\ntol = 1e-6\n",
        )
        .unwrap();
        assert_eq!(p.dt, 0.005);
        assert_eq!(p.newton.max_iters, 3);
        assert_eq!(p.newton.rel_tol, 1e-6);
        assert_eq!(
            p.linear,
            LinearSolverKind::Cg {
                precond: Preconditioner::BlockSsor,
                tol: 1e-6,
                max_iter: 500,
                strict: false
            }
        );
        p.validate().unwrap();
        let c: ImplicitEulerParams = toml::from_str("[linear]\nkind = \"cholesky\"\n").unwrap();
        assert_eq!(c.linear, LinearSolverKind::Cholesky);
        assert!(toml::from_str::<ImplicitEulerParams>("[linear]\nkind = \"lu\"\n").is_err());
        assert!(toml::from_str::<ImplicitEulerParams>("dtt = 1.0\n").is_err());
    }
}
