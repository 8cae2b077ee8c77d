//! Static equilibrium under luminal pressure: f(u) + f_p(u) = 0.
//!
//! Newton on the displacement with incremental loading: the pressure rises
//! to its target in `load_steps` equal increments, and each increment
//! iterates K(u) Δu = f(u) + f_p(u) with K = −∂(f + f_p)/∂u until the
//! residual falls below `rel_tol` times the pressure force of the increment.
//! An increment that fails (the tangent is not positive definite, Newton
//! diverges or runs out of iterations) is retried from the last converged
//! state at half the size, down to a 1024th of an increment: a curved
//! vessel under pressure straightens (the Bourdon-tube effect) and can move
//! far before the wall's tension holds it.
//! Constraints are per degree of freedom (a plane-strain slice holds only
//! u_z), unlike the integrator's all-or-nothing fixed nodes.
//!
//! The load stiffness enters as the integrator's does ([`PressureTangent`]):
//! its symmetric part, solved by sparse Cholesky, or none; or, with
//! [`StaticTangent::Exact`], the full unsymmetric tangent solved by dense LU
//! (small meshes only: it is there to measure what the symmetric solvers give
//! up, docs/PRESSURE.md).
//!
//! This is what the zero-pressure reference ([`super::unload`]) inflates,
//! and what the pressurized reduced model is linearized about.

use super::linear::{CholeskySolver, LinearFailure};
use super::pressure::{LuminalPressure, PressureTangent};
use crate::math::Vec3;
use crate::mesh::TetMesh;
use crate::model::{BlockTangent, ForceModel};

/// Which tangent the static Newton uses for the pressure.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StaticTangent {
    /// As the load says ([`LuminalPressure::tangent`]), with sparse Cholesky.
    AsLoad,
    /// The exact unsymmetric tangent, with dense LU (small meshes only).
    Exact,
}

/// Static solve control.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StaticParams {
    /// Equal pressure increments to the target (≥ 1).
    pub load_steps: usize,
    /// Newton iterations allowed per increment.
    pub max_iters: usize,
    /// Converged when ‖r‖ ≤ rel_tol · ‖f_p‖ (the increment's pressure force
    /// at the start of the solve).
    pub rel_tol: f64,
    /// Which tangent.
    pub tangent: StaticTangent,
}

impl Default for StaticParams {
    fn default() -> Self {
        StaticParams {
            load_steps: 4,
            max_iters: 40,
            rel_tol: 1e-9,
            tangent: StaticTangent::AsLoad,
        }
    }
}

/// What a static solve did.
#[derive(Debug, Clone, PartialEq)]
pub struct StaticReport {
    /// Newton iterations of each increment.
    pub newton_iters: Vec<usize>,
    /// Final ‖r‖ / ‖f_p‖.
    pub rel_residual: f64,
}

impl StaticReport {
    /// Newton iterations over all increments.
    pub fn total_iters(&self) -> usize {
        self.newton_iters.iter().sum()
    }
}

/// Why a static solve failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum StaticError {
    /// The constraint mask does not match the mesh.
    #[error("static solve: {got} constraint entries for {nodes} nodes")]
    Constraints {
        /// Entries given.
        got: usize,
        /// Nodes in the mesh.
        nodes: usize,
    },
    /// The stiffness was not positive definite or a value was not finite: at
    /// this pressure the wall buckles or balloons (or is not held in place).
    #[error(
        "static solve at {pressure_pa:.0} Pa: {reason} (the wall cannot hold this pressure, or is not held in place)"
    )]
    Linear {
        /// The increment's pressure (Pa).
        pressure_pa: f64,
        /// What the linear solver said.
        reason: String,
    },
    /// Newton did not converge within the iteration limit.
    #[error("static solve at {pressure_pa:.0} Pa: Newton not converged after {iters} iterations (relative residual {rel_residual:.1e})")]
    NotConverged {
        /// The increment's pressure (Pa).
        pressure_pa: f64,
        /// Iterations done.
        iters: usize,
        /// ‖r‖ / ‖f_p‖ at the end.
        rel_residual: f64,
    },
}

fn norm(v: &[Vec3]) -> f64 {
    v.iter().map(|x| x.norm_squared()).sum::<f64>().sqrt()
}

/// Replaces the constrained rows and columns of `k` by the identity.
pub fn project_dofs(k: &mut BlockTangent, mask: &[[bool; 3]]) {
    for (d, m) in k.diag.iter_mut().zip(mask) {
        for c in 0..3 {
            if m[c] {
                for j in 0..3 {
                    d[(c, j)] = 0.0;
                    d[(j, c)] = 0.0;
                }
                d[(c, c)] = 1.0;
            }
        }
    }
    for (b, &[i, j]) in k.off.iter_mut().zip(&k.edges) {
        let (mi, mj) = (mask[i as usize], mask[j as usize]);
        for c in 0..3 {
            if mi[c] {
                b.row_mut(c).fill(0.0);
            }
            if mj[c] {
                b.column_mut(c).fill(0.0);
            }
        }
    }
}

/// Every degree of freedom of the nodes in `fixed` constrained.
pub fn mask_of_fixed(num_nodes: usize, fixed: &[u32]) -> Vec<[bool; 3]> {
    let mut m = vec![[false; 3]; num_nodes];
    for &i in fixed {
        if let Some(x) = m.get_mut(i as usize) {
            *x = [true; 3];
        }
    }
    m
}

/// Solves for the equilibrium of `model` on `mesh` under `pressure` at `p`
/// Pa with the constrained degrees of freedom held at their value in `u`.
/// `u` is the starting guess (its constrained entries are kept) and returns
/// the solution; on failure it holds the last iterate.
pub fn solve_pressurized(
    mesh: &TetMesh,
    model: &dyn ForceModel,
    pressure: &LuminalPressure,
    p: f64,
    mask: &[[bool; 3]],
    params: &StaticParams,
    u: &mut [Vec3],
) -> Result<StaticReport, StaticError> {
    let n = mesh.num_nodes();
    if mask.len() != n || u.len() != n {
        return Err(StaticError::Constraints {
            got: mask.len(),
            nodes: n,
        });
    }
    let mut k = BlockTangent::zeros(mesh);
    let mut chol = match params.tangent {
        StaticTangent::AsLoad => {
            Some(CholeskySolver::new(&k).map_err(|reason| StaticError::Linear { pressure_pa: p, reason })?)
        }
        StaticTangent::Exact => None,
    };
    let mut r = vec![Vec3::zeros(); n];
    let mut du = vec![Vec3::zeros(); n];
    let steps = params.load_steps.max(1);
    let mut report = StaticReport {
        newton_iters: Vec::with_capacity(steps),
        rel_residual: 0.0,
    };
    // Newton at pressure `ps` from the current `u`: the iterations taken,
    // or why it failed (then `u` is the last iterate).
    let mut newton = |ps: f64, u: &mut [Vec3], rel_out: &mut f64| -> Result<usize, StaticError> {
        r.iter_mut().for_each(|x| *x = Vec3::zeros());
        pressure.add_forces(ps, u, &mut r);
        let scale = norm(&r).max(f64::MIN_POSITIVE);
        let mut iters = 0;
        loop {
            r.iter_mut().for_each(|x| *x = Vec3::zeros());
            model.add_forces(u, &mut r);
            pressure.add_forces(ps, u, &mut r);
            for (x, m) in r.iter_mut().zip(mask) {
                for (c, &held) in m.iter().enumerate() {
                    if held {
                        x[c] = 0.0;
                    }
                }
            }
            let rel = norm(&r) / scale;
            *rel_out = rel;
            if !rel.is_finite() || rel > 1e8 {
                return Err(StaticError::Linear {
                    pressure_pa: ps,
                    reason: "the iterate diverged".into(),
                });
            }
            if rel <= params.rel_tol {
                return Ok(iters);
            }
            if iters == params.max_iters {
                return Err(StaticError::NotConverged {
                    pressure_pa: ps,
                    iters,
                    rel_residual: rel,
                });
            }
            match chol.as_mut() {
                Some(chol) => {
                    k.clear();
                    model.add_stiffness(u, &mut k);
                    pressure.add_stiffness(ps, u, &mut k);
                    project_dofs(&mut k, mask);
                    chol.solve(&k, &r, &mut du)
                        .map_err(|e: LinearFailure| StaticError::Linear {
                            pressure_pa: ps,
                            reason: e.to_string(),
                        })?;
                }
                None => exact_newton_update(mesh, model, pressure, ps, u, mask, &r, &mut du).map_err(|reason| {
                    StaticError::Linear {
                        pressure_pa: ps,
                        reason,
                    }
                })?,
            }
            for (x, d) in u.iter_mut().zip(&du) {
                *x += d;
            }
            iters += 1;
        }
    };
    // Increments of 1/steps of the pressure; one that fails is retried from
    // the last converged state at half the size, down to 1/(steps · 2¹⁰).
    let base = 1.0 / steps as f64;
    let mut done = 0.0;
    let mut inc = base;
    let mut saved = u.to_vec();
    while done < 1.0 {
        let target = (done + inc).min(1.0);
        match newton(p * target, u, &mut report.rel_residual) {
            Ok(iters) => {
                report.newton_iters.push(iters);
                done = target;
                saved.copy_from_slice(u);
                inc = (2.0 * inc).min(base);
            }
            Err(e) => {
                u.copy_from_slice(&saved);
                inc *= 0.5;
                if inc < base / 1024.0 {
                    return Err(e);
                }
            }
        }
    }
    Ok(report)
}

/// Solves (K + K_p) Δu = r with the full unsymmetric load stiffness by
/// dense LU.
#[allow(clippy::too_many_arguments)]
fn exact_newton_update(
    mesh: &TetMesh,
    model: &dyn ForceModel,
    pressure: &LuminalPressure,
    p: f64,
    u: &[Vec3],
    mask: &[[bool; 3]],
    r: &[Vec3],
    du: &mut [Vec3],
) -> Result<(), String> {
    let n = mesh.num_nodes();
    let mut k = BlockTangent::zeros(mesh);
    model.add_stiffness(u, &mut k);
    let mut a = k.to_dense() + pressure.dense_stiffness(p, u);
    for (i, m) in mask.iter().enumerate() {
        for (c, &held) in m.iter().enumerate() {
            if held {
                let d = 3 * i + c;
                a.row_mut(d).fill(0.0);
                a.column_mut(d).fill(0.0);
                a[(d, d)] = 1.0;
            }
        }
    }
    let b = nalgebra::DVector::from_iterator(3 * n, r.iter().flat_map(|v| v.iter().copied()));
    let x = a.lu().solve(&b).ok_or("singular tangent")?;
    for (i, d) in du.iter_mut().enumerate() {
        *d = Vec3::new(x[3 * i], x[3 * i + 1], x[3 * i + 2]);
    }
    Ok(())
}

/// Which load stiffness `tangent` puts into Newton's matrix, for reports.
pub fn tangent_name(t: StaticTangent, load: PressureTangent) -> &'static str {
    match (t, load) {
        (StaticTangent::Exact, _) => "exact (dense LU)",
        (StaticTangent::AsLoad, PressureTangent::Symmetric) => "symmetric part",
        (StaticTangent::AsLoad, PressureTangent::None) => "none",
    }
}
