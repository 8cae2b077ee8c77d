//! Modal derivatives (Barbič & James 2005, section 3.2): the basis
//! enrichment that makes the cubic reduced StVK model ([`super::cubic`])
//! usable at large deformation.
//!
//! A basis of linear modes (and static modes) cannot represent the
//! second-order displacement a large deflection drags along — the axial
//! shortening of a bent beam, the in-plane pull of a dented wall — so the
//! exact nonlinear force restricted to it stiffens far beyond the full
//! model ("locking"; measured in docs/REDUCED.md). The modal derivative of
//! columns i, j is the static response to the change of stiffness along one
//! of them, applied to the other:
//!
//! ```text
//! K(0) ψ_ij = −(∂K/∂u [φ_i]) φ_j
//! ```
//!
//! For StVK, K(εφ) is a quadratic polynomial in ε, so the directional
//! derivative is exactly the central difference (K(εφ_i) − K(−εφ_i)) φ_j / 2ε
//! (up to rounding), taken with the model's own tangent-vector product.
//! One sparse Cholesky of K(0) on the free DOFs serves every pair.
//!
//! [`with_modal_derivatives`] appends ψ_ij for the pairs of the first
//! `of` columns, in the order of Barbič–James's weighting (smallest ω_i ω_j
//! first), until the basis has the requested size, then M-orthonormalizes and
//! rotates the whole set to its Ritz vectors, so the result is again a
//! mass-orthonormal basis with a diagonal ΦᵀK(0)Φ that every reduced model
//! accepts.

use super::basis::{ModalBasis, ReducedError};
use crate::math::Vec3;
use crate::mesh::TetMesh;
use crate::model::{BlockTangent, ForceModel};
use crate::solver::linear::{project_fixed, CholeskySolver};
use nalgebra::{DMatrix, SymmetricEigen};

/// A column whose M-norm falls below this fraction of its norm before
/// orthogonalization is already in the span and is dropped.
const DEPENDENCE_TOL: f64 = 1e-8;

/// `basis` enriched with modal derivatives of its first `of` columns up to
/// `r_total` columns (fewer if the pairs run out or are dependent), at the
/// rest state: M-orthonormal, ΦᵀK(0)Φ = diag(ω²) ascending. `model` is the
/// force model the basis was computed with (StVK for exact derivatives),
/// `mass` the lumped mass per node. `num_static` of the result is that of
/// `basis` (its columns are mixed by the Ritz rotation).
pub fn with_modal_derivatives(
    mesh: &TetMesh,
    model: &dyn ForceModel,
    mass: &[f64],
    basis: &ModalBasis,
    of: usize,
    r_total: usize,
) -> Result<ModalBasis, ReducedError> {
    let of = of.min(basis.len());
    // Pairs by Barbič–James's weight ω_i ω_j (smallest first).
    let mut pairs: Vec<(usize, usize)> = (0..of).flat_map(|j| (0..=j).map(move |i| (i, j))).collect();
    let w = |i: usize| basis.omega2.get(i).copied().unwrap_or(1.0).abs().sqrt();
    pairs.sort_by(|a, b| (w(a.0) * w(a.1)).total_cmp(&(w(b.0) * w(b.1))));
    enrich(mesh, model, mass, basis, &pairs, r_total)
}

/// As [`with_modal_derivatives`], with the pairs chosen for a load pattern
/// instead of free vibration: with q = diag(ω²)⁻¹ Φᵀ `load` the basis'
/// static response to it, the pairs (i ≤ j) of all columns in descending
/// order of |q_i q_j| — the second-order terms that load actually excites
/// (for a contact basis these are mostly the static, local directions,
/// which the lowest-ω rule never picks).
pub fn with_load_derivatives(
    mesh: &TetMesh,
    model: &dyn ForceModel,
    mass: &[f64],
    basis: &ModalBasis,
    load: &[Vec3],
    r_total: usize,
) -> Result<ModalBasis, ReducedError> {
    if load.len() != mesh.num_nodes() {
        return Err(ReducedError::SizeMismatch {
            what: "load",
            got: load.len(),
            expected: mesh.num_nodes(),
        });
    }
    let fr = basis.project(load);
    let q: Vec<f64> = (0..basis.len())
        .map(|i| {
            let w2 = basis.omega2.get(i).copied().unwrap_or(0.0);
            if w2 > 0.0 {
                fr[i] / w2
            } else {
                0.0
            }
        })
        .collect();
    let r0 = basis.len();
    let mut pairs: Vec<(usize, usize)> = (0..r0).flat_map(|j| (0..=j).map(move |i| (i, j))).collect();
    let w = |p: &(usize, usize)| (q[p.0] * q[p.1]).abs();
    pairs.sort_by(|a, b| w(b).total_cmp(&w(a)));
    enrich(mesh, model, mass, basis, &pairs, r_total)
}

/// Appends the derivatives of `pairs`, in order, until `r_total` columns.
fn enrich(
    mesh: &TetMesh,
    model: &dyn ForceModel,
    mass: &[f64],
    basis: &ModalBasis,
    pairs: &[(usize, usize)],
    r_total: usize,
) -> Result<ModalBasis, ReducedError> {
    let n = mesh.num_nodes();
    if basis.num_nodes() != n {
        return Err(ReducedError::SizeMismatch {
            what: "the basis (rows / 3)",
            got: basis.num_nodes(),
            expected: n,
        });
    }
    if mass.len() != n {
        return Err(ReducedError::SizeMismatch {
            what: "mass",
            got: mass.len(),
            expected: n,
        });
    }
    if let Some((node, &m)) = mass.iter().enumerate().find(|(_, m)| !(m.is_finite() && **m > 0.0)) {
        return Err(ReducedError::BadMass { node, mass: m });
    }
    let r0 = basis.len();
    if pairs.iter().any(|&(i, j)| i >= r0 || j >= r0) {
        return Err(ReducedError::BadModeCount {
            asked: pairs.iter().map(|&(i, j)| i.max(j) + 1).max().unwrap_or(0),
            free_dofs: r0,
        });
    }
    let mut fixed_mask = vec![false; n];
    for &f in &basis.fixed {
        if let Some(x) = fixed_mask.get_mut(f as usize) {
            *x = true;
        }
    }
    let zeros = vec![Vec3::zeros(); n];
    let mut k = BlockTangent::zeros(mesh);
    model.add_stiffness(&zeros, &mut k);
    let k0 = k.clone();
    project_fixed(&mut k, &fixed_mask);
    let mut chol = CholeskySolver::new(&k).map_err(|_| ReducedError::NotPositiveDefinite)?;
    chol.factor(&k).map_err(|_| ReducedError::NotPositiveDefinite)?;

    let col = |j: usize| -> Vec<Vec3> {
        basis
            .phi
            .column(j)
            .as_slice()
            .chunks_exact(3)
            .map(|c| Vec3::new(c[0], c[1], c[2]))
            .collect()
    };
    let wanted = r_total.saturating_sub(r0);

    // Columns: the basis, then derivatives (scaled to unit max entry).
    let mut cols: Vec<Vec<f64>> = (0..r0).map(|j| basis.phi.column(j).as_slice().to_vec()).collect();
    let scale = basis.phi.amax().max(f64::MIN_POSITIVE);
    let mut plus = vec![Vec3::zeros(); n];
    let mut minus = vec![Vec3::zeros(); n];
    let mut df = vec![Vec3::zeros(); n];
    let mut dfm = vec![Vec3::zeros(); n];
    let mut psi = vec![Vec3::zeros(); n];
    for &(i, j) in pairs.iter().take(wanted) {
        let (pi, pj) = (col(i), col(j));
        // ε φ_i as large as 1e-3 of the mesh diagonal: exact for a quadratic
        // K(εφ) up to rounding, far above the rounding floor.
        let amax = pi.iter().map(|v| v.amax()).fold(0.0, f64::max);
        if amax == 0.0 {
            continue;
        }
        let eps = 1e-3 / amax * mesh_scale(mesh);
        for ((p, m), x) in plus.iter_mut().zip(minus.iter_mut()).zip(&pi) {
            *p = x * eps;
            *m = -x * eps;
        }
        // add_df gives ∂f/∂u·du = −K du, so −(∂K/∂u[φ_i])φ_j = (df(+) − df(−)) / 2ε.
        df.iter_mut().for_each(|v| *v = Vec3::zeros());
        model.add_df(&plus, &pj, &mut df);
        dfm.iter_mut().for_each(|v| *v = Vec3::zeros());
        model.add_df(&minus, &pj, &mut dfm);
        for ((d, m), &fx) in df.iter_mut().zip(&dfm).zip(&fixed_mask) {
            *d = if fx { Vec3::zeros() } else { (*d - m) / (2.0 * eps) };
        }
        chol.solve_factored(&df, &mut psi)
            .map_err(|_| ReducedError::NotPositiveDefinite)?;
        let mut c: Vec<f64> = psi.iter().flat_map(|v| [v.x, v.y, v.z]).collect();
        let cmax = c.iter().fold(0.0f64, |a, v| a.max(v.abs()));
        if !(cmax.is_finite()) {
            return Err(ReducedError::NonFinite);
        }
        if cmax > 0.0 {
            c.iter_mut().for_each(|v| *v *= scale / cmax);
            cols.push(c);
        }
    }

    // M-orthonormalize (modified Gram–Schmidt, twice), dropping dependent columns.
    let mdot = |a: &[f64], b: &[f64]| -> f64 {
        a.chunks_exact(3)
            .zip(b.chunks_exact(3))
            .zip(mass)
            .map(|((x, y), m)| m * (x[0] * y[0] + x[1] * y[1] + x[2] * y[2]))
            .sum()
    };
    let mut ortho: Vec<Vec<f64>> = Vec::with_capacity(cols.len());
    for mut c in cols {
        let norm0 = mdot(&c, &c).sqrt();
        for _ in 0..2 {
            for o in &ortho {
                let d = mdot(o, &c);
                c.iter_mut().zip(o).for_each(|(x, y)| *x -= d * y);
            }
        }
        let norm = mdot(&c, &c).sqrt();
        if norm > DEPENDENCE_TOL * norm0 && norm > 0.0 {
            c.iter_mut().for_each(|x| *x /= norm);
            ortho.push(c);
        }
    }
    let r = ortho.len();
    let mut phi = DMatrix::zeros(3 * n, r);
    for (j, c) in ortho.iter().enumerate() {
        phi.column_mut(j).copy_from_slice(c);
    }
    // Ritz rotation: ΦᵀK(0)Φ = V diag(ω²) Vᵀ, Φ ← Φ V.
    let mut kphi = DMatrix::zeros(3 * n, r);
    let mut y = vec![Vec3::zeros(); n];
    for j in 0..r {
        let x: Vec<Vec3> = phi
            .column(j)
            .as_slice()
            .chunks_exact(3)
            .map(|c| Vec3::new(c[0], c[1], c[2]))
            .collect();
        k0.mul(&x, &mut y);
        for (i, v) in y.iter().enumerate() {
            for c in 0..3 {
                kphi[(3 * i + c, j)] = v[c];
            }
        }
    }
    let mut kr = phi.transpose() * &kphi;
    kr = (&kr + kr.transpose()) * 0.5;
    if kr.iter().any(|v| !v.is_finite()) {
        return Err(ReducedError::NonFinite);
    }
    let eig = SymmetricEigen::new(kr);
    let mut order: Vec<usize> = (0..r).collect();
    order.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
    let v = DMatrix::from_fn(r, r, |i, j| eig.eigenvectors[(i, order[j])]);
    let omega2: Vec<f64> = order.iter().map(|&j| eig.eigenvalues[j]).collect();
    Ok(ModalBasis {
        phi: phi * v,
        omega2,
        num_static: basis.num_static,
        fixed: basis.fixed.clone(),
        iterations: basis.iterations,
    })
}

/// Bounding-box diagonal of the rest mesh (m).
fn mesh_scale(mesh: &TetMesh) -> f64 {
    let mut lo = Vec3::repeat(f64::INFINITY);
    let mut hi = Vec3::repeat(f64::NEG_INFINITY);
    for x in mesh.rest() {
        lo = lo.inf(x);
        hi = hi.sup(x);
    }
    let d = (hi - lo).norm();
    if d.is_finite() && d > 0.0 {
        d
    } else {
        1.0
    }
}
