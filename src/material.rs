//! Materials: elastic constants, the two hyperelastic laws and Prony terms.
//!
//! - Lamé coefficients from E and ν (eq. 5).
//! - St Venant–Kirchhoff (eq. 3–4): W = λ/2 (tr E)² + μ tr(E²), E = ½(FᵀF − I).
//! - Neo-Hookean (eq. 9): Ψ = μ/2 (tr FᵀF − 3) − μ log J + λ/2 (log J)².
//!   Inversion: log J has no value at J ≤ 0. We replace log J below
//!   `J_MIN` by its second-order Taylor extension ℓ(J) (C¹ in J, finite for
//!   every J) and write every J⁻¹F⁻ᵀ as the cofactor matrix cof F = J F⁻ᵀ,
//!   which is a polynomial in F. Stress and tangent are therefore finite for
//!   any F, inverted and degenerate elements included, and unchanged for
//!   J ≥ `J_MIN`. An inverted element feels a strong restoring force (the
//!   extension keeps decreasing for J < J_MIN, so energy rises as J falls).
//!
//! Functions here are per-element kernels of the deformation gradient F; the
//! models assemble them. Nothing here knows about meshes.

use crate::math::Mat3;

/// Threshold below which the Neo-Hookean log J is replaced by its quadratic
/// extension (see the module docs).
pub const J_MIN: f64 = 0.2;

/// Elastic constants and density of a homogeneous material (SI units).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Material {
    /// Young's modulus E (Pa).
    pub youngs_pa: f64,
    /// Poisson's ratio ν (dimensionless, in [0, 0.5)).
    pub poisson: f64,
    /// Density (kg/m³).
    pub density: f64,
}

impl Material {
    /// Porcine-aorta-like defaults (docs/MODELS.md, "Material", has the sources):
    /// E = 65 kPa instantaneous, ν = 0.45, ρ = 1050 kg/m³.
    pub fn aorta() -> Material {
        Material {
            youngs_pa: 65e3,
            poisson: 0.45,
            density: 1050.0,
        }
    }

    /// Lamé coefficients (λ, μ) of eq. 5.
    pub fn lame(&self) -> Lame {
        Lame::from_young_poisson(self.youngs_pa, self.poisson)
    }
}

/// Lamé coefficients λ and μ (Pa).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Lame {
    /// First Lamé coefficient λ (Pa).
    pub lambda: f64,
    /// Shear modulus μ (Pa).
    pub mu: f64,
}

impl Lame {
    /// Eq. 5: λ = νE / ((1+ν)(1−2ν)), μ = E / (2(1+ν)).
    pub fn from_young_poisson(e: f64, nu: f64) -> Lame {
        Lame {
            lambda: nu * e / ((1.0 + nu) * (1.0 - 2.0 * nu)),
            mu: e / (2.0 * (1.0 + nu)),
        }
    }
}

/// The hyperelastic law.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Law {
    /// St Venant–Kirchhoff (eq. 3–4).
    Stvk,
    /// Neo-Hookean (eq. 9) with the inversion-safe extension.
    NeoHookean,
}

/// One Maxwell element of the Prony series (eq. 11): α_i and τ_i (s).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PronyTerm {
    /// Normalised modulus α_i (0 < α_i, Σ α_i < 1).
    pub alpha: f64,
    /// Relaxation time τ_i (s, > 0).
    pub tau: f64,
}

/// Relaxation function α(t) = 1 − Σ α_i (1 − e^{−t/τ_i}) (eq. 11).
pub fn relaxation(terms: &[PronyTerm], t: f64) -> f64 {
    1.0 - terms.iter().map(|p| p.alpha * (1.0 - (-t / p.tau).exp())).sum::<f64>()
}

/// Cofactor matrix cof F = det(F) F⁻ᵀ, computed without dividing: column k
/// is the cross product of the other two columns of F.
#[inline]
pub fn cofactor(f: &Mat3) -> Mat3 {
    let (c0, c1, c2) = (f.column(0), f.column(1), f.column(2));
    Mat3::from_columns(&[c1.cross(&c2), c2.cross(&c0), c0.cross(&c1)])
}

/// Directional derivative of the cofactor matrix at F along dF.
#[inline]
pub fn dcofactor(f: &Mat3, df: &Mat3) -> Mat3 {
    let (c0, c1, c2) = (f.column(0), f.column(1), f.column(2));
    let (d0, d1, d2) = (df.column(0), df.column(1), df.column(2));
    Mat3::from_columns(&[
        d1.cross(&c2) + c1.cross(&d2),
        d2.cross(&c0) + c2.cross(&d0),
        d0.cross(&c1) + c0.cross(&d1),
    ])
}

/// log J and its first two derivatives, extended quadratically below J_MIN.
#[inline]
fn log_ext(j: f64) -> (f64, f64, f64) {
    if j >= J_MIN {
        (j.ln(), 1.0 / j, -1.0 / (j * j))
    } else {
        let d = j - J_MIN;
        (
            J_MIN.ln() + d / J_MIN - d * d / (2.0 * J_MIN * J_MIN),
            1.0 / J_MIN - d / (J_MIN * J_MIN),
            -1.0 / (J_MIN * J_MIN),
        )
    }
}

/// Green–Lagrange strain E = ½(FᵀF − I) (eq. 3 with F = I + ∇U).
#[inline]
pub fn green_strain(f: &Mat3) -> Mat3 {
    (f.tr_mul(f) - Mat3::identity()) * 0.5
}

/// Strain energy density Ψ(F) (J/m³).
pub fn energy_density(law: Law, l: Lame, f: &Mat3) -> f64 {
    match law {
        Law::Stvk => {
            let e = green_strain(f);
            let tr = e.trace();
            0.5 * l.lambda * tr * tr + l.mu * e.component_mul(&e).sum()
        }
        Law::NeoHookean => {
            let (lj, _, _) = log_ext(f.determinant());
            0.5 * l.mu * (f.norm_squared() - 3.0) - l.mu * lj + 0.5 * l.lambda * lj * lj
        }
    }
}

/// Second Piola–Kirchhoff stress of St Venant–Kirchhoff: S = λ tr(E) I + 2μ E.
#[inline]
pub fn stvk_pk2(l: Lame, e: &Mat3) -> Mat3 {
    Mat3::identity() * (l.lambda * e.trace()) + e * (2.0 * l.mu)
}

/// First Piola–Kirchhoff stress P = ∂Ψ/∂F (Pa).
pub fn pk1(law: Law, l: Lame, f: &Mat3) -> Mat3 {
    match law {
        Law::Stvk => f * stvk_pk2(l, &green_strain(f)),
        Law::NeoHookean => {
            let (lj, dl, _) = log_ext(f.determinant());
            // ∂/∂F of −μ ℓ(J) + λ/2 ℓ² = (λℓ − μ) ℓ'(J) cof F.
            f * l.mu + cofactor(f) * ((l.lambda * lj - l.mu) * dl)
        }
    }
}

/// Directional derivative dP = ∂P/∂F : dF.
pub fn dpk1(law: Law, l: Lame, f: &Mat3, df: &Mat3) -> Mat3 {
    match law {
        Law::Stvk => {
            let e = green_strain(f);
            let de = (df.tr_mul(f) + f.tr_mul(df)) * 0.5;
            df * stvk_pk2(l, &e) + f * stvk_pk2(l, &de)
        }
        Law::NeoHookean => {
            let j = f.determinant();
            let (lj, dl, ddl) = log_ext(j);
            let cof = cofactor(f);
            let dj = cof.component_mul(df).sum();
            let a = (l.lambda * lj - l.mu) * dl;
            let da = (l.lambda * dl * dl + (l.lambda * lj - l.mu) * ddl) * dj;
            df * l.mu + cof * da + dcofactor(f, df) * a
        }
    }
}

/// Second Piola–Kirchhoff stress S = F⁻¹ P, the rest-frame stress the Prony
/// history acts on. For StVK it is exact for any F. For Neo-Hookean it needs
/// F invertible: returns `None` when |det F| is below 1e-8 (callers keep the
/// history unchanged for such an element; see `model::viscoelastic`).
pub fn pk2(law: Law, l: Lame, f: &Mat3) -> Option<Mat3> {
    match law {
        Law::Stvk => Some(stvk_pk2(l, &green_strain(f))),
        Law::NeoHookean => {
            let j = f.determinant();
            if j.abs() < 1e-8 || !j.is_finite() {
                return None;
            }
            let (lj, dl, _) = log_ext(j);
            // S = μ I + (λℓ − μ) ℓ' · F⁻¹ cof F, and F⁻¹ cof F = J C⁻¹.
            let c_inv_j = f.try_inverse()? * cofactor(f);
            Some(Mat3::identity() * l.mu + c_inv_j * ((l.lambda * lj - l.mu) * dl))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample_f(seed: u64) -> Mat3 {
        // Small deterministic generator: no extra dependency for unit tests.
        let mut s = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        let mut next = || {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((s >> 11) as f64 / (1u64 << 53) as f64) - 0.5
        };
        Mat3::identity() + Mat3::from_fn(|_, _| 0.6 * next())
    }

    fn fd_check(law: Law, f: &Mat3) {
        let l = Lame::from_young_poisson(1e5, 0.45);
        let p = pk1(law, l, f);
        let h = 1e-6;
        for a in 0..3 {
            for b in 0..3 {
                let mut fp = *f;
                fp[(a, b)] += h;
                let mut fm = *f;
                fm[(a, b)] -= h;
                let num = (energy_density(law, l, &fp) - energy_density(law, l, &fm)) / (2.0 * h);
                assert!(
                    (num - p[(a, b)]).abs() <= 1e-6 * p.norm().max(1.0),
                    "{law:?} P[{a}{b}] {num} vs {}",
                    p[(a, b)]
                );
                let mut dfm = Mat3::zeros();
                dfm[(a, b)] = 1.0;
                let dp = dpk1(law, l, f, &dfm);
                let num_dp = (pk1(law, l, &fp) - pk1(law, l, &fm)) / (2.0 * h);
                assert!(
                    (num_dp - dp).norm() <= 1e-6 * dp.norm().max(l.mu),
                    "{law:?} dP/dF[{a}{b}]"
                );
            }
        }
    }

    #[test]
    fn stress_is_energy_gradient_and_tangent_is_its_derivative() {
        for seed in 0..20 {
            let f = sample_f(seed);
            fd_check(Law::Stvk, &f);
            fd_check(Law::NeoHookean, &f);
        }
    }

    #[test]
    fn neo_hookean_finite_when_inverted_or_flat() {
        let l = Lame::from_young_poisson(1e5, 0.49);
        for f in [
            Mat3::from_diagonal(&nalgebra::Vector3::new(1.0, 1.0, -0.5)),
            Mat3::from_diagonal(&nalgebra::Vector3::new(1.0, 1.0, 0.0)),
            Mat3::zeros(),
            Mat3::from_diagonal(&nalgebra::Vector3::new(0.1, 0.1, 0.1)),
        ] {
            assert!(energy_density(Law::NeoHookean, l, &f).is_finite());
            assert!(pk1(Law::NeoHookean, l, &f).iter().all(|v| v.is_finite()));
            assert!(dpk1(Law::NeoHookean, l, &f, &Mat3::identity())
                .iter()
                .all(|v| v.is_finite()));
            fd_check(Law::NeoHookean, &f);
        }
        // An inverted element is pushed back: the energy decreases as J grows from negative.
        let f_of = |j: f64| Mat3::from_diagonal(&nalgebra::Vector3::new(1.0, 1.0, j));
        assert!(energy_density(Law::NeoHookean, l, &f_of(-0.5)) > energy_density(Law::NeoHookean, l, &f_of(0.0)));
    }

    #[test]
    fn both_laws_agree_with_linear_elasticity_for_small_strain() {
        let l = Lame::from_young_poisson(1e5, 0.3);
        let eps = 1e-6;
        let grad = Mat3::new(0.3, 0.1, -0.2, 0.05, -0.4, 0.1, 0.0, 0.2, 0.25) * eps;
        let f = Mat3::identity() + grad;
        let strain = (grad + grad.transpose()) * 0.5;
        let lin = Mat3::identity() * (l.lambda * strain.trace()) + strain * (2.0 * l.mu);
        for law in [Law::Stvk, Law::NeoHookean] {
            let p = pk1(law, l, &f);
            assert!((p - lin).norm() < 1e-4 * lin.norm(), "{law:?}");
            let s = pk2(law, l, &f).unwrap();
            assert!((s - lin).norm() < 1e-4 * lin.norm(), "{law:?}");
        }
    }

    #[test]
    fn lame_of_eq5() {
        let l = Lame::from_young_poisson(3.0, 0.25);
        assert!((l.lambda - 1.2).abs() < 1e-14);
        assert!((l.mu - 1.2).abs() < 1e-14);
    }
}
