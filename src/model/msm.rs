//! Mass-spring model on the mesh edges: the paper's MSM baseline.
//!
//! Each edge e = (a, b) with rest length L_e is a nonlinear spring with energy
//! W_e = ½ k_e (l − L_e)², l = |x_b − x_a|, x = X + u, so the force on b is
//! f_b = −k_e (l − L_e) n with n = (x_b − x_a)/l, and f_a = −f_b.
//!
//! Spring stiffness from Young's modulus: Van Gelder's rule (A. Van Gelder,
//! "Approximate simulation of elastic membranes by triangulated spring
//! meshes", Journal of Graphics Tools 3(2), 1998): stiffness proportional to
//! E times the measure of the elements adjacent to the edge over the squared
//! edge length, here in its tetrahedral form k_e = E Σ_{tets t ∋ e} V_t / L_e².
//! Van Gelder shows that no spring network reproduces a given E and ν exactly
//! in general, and Lloyd, Székely and Harders ("Identification of spring
//! parameters for deformable object simulation", IEEE TVCG 13(5), 2007) find
//! the same for tetrahedra. Springs have no separate volumetric response, so
//! the effective Poisson ratio is set by the mesh geometry, not by ν.
//! `tests/msm_stiffness_is_of_fem_order.rs` measures the effective Young's
//! modulus and Poisson ratio of a block against FEM (E within a few percent,
//! ν ≈ 0.04 instead of 0.45 on the Kuhn-subdivided block).
//!
//! Zero length: the energy has a cone point at l = 0, where n and the
//! geometric stiffness (1 − L/l)(I − n nᵀ) do not exist. Below
//! l = [`DEGENERATE_FRACTION`] · L the spring uses its rest direction for n
//! and keeps only the axial stiffness k n nᵀ: forces and tangents stay finite
//! (no NaN) and push the two nodes apart along the rest edge.
//!
//! Compression: a spring's exact Hessian is
//! k [n nᵀ + (1 − L/l)(I − n nᵀ)]; for l < L the transverse factor
//! 1 − L/l is negative, so the assembled tangent of a compressed mesh is
//! indefinite and a Cholesky factorization fails. [`Msm::new`] uses the
//! standard remedy (K.-J. Choi and H.-S. Ko, "Stable but responsive cloth",
//! ACM Trans. Graphics 21(3), SIGGRAPH 2002): the transverse factor is
//! clamped at zero, max(0, 1 − L/l), in both `add_df` and `add_stiffness`,
//! which then stay each other's negative and are positive semi-definite for
//! every spring. Forces and energy are unchanged, so converged states are the
//! same; under compression the tangent is no longer the exact derivative of
//! the force, and Newton converges linearly there instead of quadratically.
//! [`Msm::with_exact_tangent`] keeps the exact Hessian (the derivative tests
//! use it).

use super::{BlockTangent, ForceModel};
use crate::material::Material;
use crate::math::Mat3;
use crate::math::Vec3;
use crate::mesh::TetMesh;

/// Below this fraction of its rest length a spring counts as collapsed (see
/// the module docs).
pub const DEGENERATE_FRACTION: f64 = 1e-9;

/// The mass-spring force model.
#[derive(Debug, Clone)]
pub struct Msm {
    edges: Vec<[u32; 2]>,
    rest_len: Vec<f64>,
    rest_dir: Vec<Vec3>,
    stiffness: Vec<f64>,
    rest: Vec<Vec3>,
    /// Whether the tangent keeps the negative transverse stiffness of
    /// compressed springs (see the module docs).
    exact_tangent: bool,
}

impl Msm {
    /// Builds springs on the edges of `mesh` with Van Gelder's tetrahedral
    /// stiffness k_e = E Σ_{t ∋ e} V_t / L_e² for the Young's modulus of
    /// `material` (its Poisson ratio cannot be represented; see module docs).
    /// The tangent drops the compressive transverse stiffness (positive
    /// semi-definite everywhere; see the module docs).
    pub fn new(mesh: &TetMesh, material: &Material) -> Msm {
        Msm::build(mesh, material, false)
    }

    /// As [`Msm::new`], with the spring's exact Hessian as the tangent
    /// (indefinite under compression): for derivative checks.
    pub fn with_exact_tangent(mesh: &TetMesh, material: &Material) -> Msm {
        Msm::build(mesh, material, true)
    }

    fn build(mesh: &TetMesh, material: &Material, exact_tangent: bool) -> Msm {
        let rest = mesh.rest().to_vec();
        let edges = mesh.edges().to_vec();
        let mut adjacent_volume = vec![0.0; edges.len()];
        for (te, v) in mesh.tet_edges().iter().zip(mesh.volumes()) {
            for &e in te {
                adjacent_volume[e as usize] += v;
            }
        }
        let (mut rest_len, mut rest_dir, mut stiffness) = (Vec::new(), Vec::new(), Vec::new());
        for (&[a, b], vol) in edges.iter().zip(&adjacent_volume) {
            let d = rest[b as usize] - rest[a as usize];
            // Mesh construction rejects coincident nodes of a tet, so L > 0.
            let l = d.norm();
            rest_len.push(l);
            rest_dir.push(d / l);
            stiffness.push(material.youngs_pa * vol / (l * l));
        }
        Msm {
            edges,
            rest_len,
            rest_dir,
            stiffness,
            rest,
            exact_tangent,
        }
    }

    /// Whether the tangent is the exact Hessian ([`Msm::with_exact_tangent`]).
    pub fn has_exact_tangent(&self) -> bool {
        self.exact_tangent
    }

    /// Spring stiffness k_e (N/m) per mesh edge.
    pub fn stiffness(&self) -> &[f64] {
        &self.stiffness
    }

    /// Rest length L_e (m) per mesh edge.
    pub fn rest_lengths(&self) -> &[f64] {
        &self.rest_len
    }

    /// Current edge vector x_b − x_a of edge `e`.
    #[inline]
    fn edge_vector(&self, e: usize, u: &[Vec3]) -> Vec3 {
        let [a, b] = self.edges[e].map(|i| i as usize);
        self.rest[b] - self.rest[a] + u[b] - u[a]
    }

    /// Force f_b = −k (l − L) n on the high end b of edge `e` (f_a = −f_b).
    #[inline]
    fn spring_force(&self, e: usize, u: &[Vec3]) -> Vec3 {
        let d = self.edge_vector(e, u);
        let (k, rl) = (self.stiffness[e], self.rest_len[e]);
        let l = d.norm();
        let n = if l > DEGENERATE_FRACTION * rl {
            d / l
        } else {
            self.rest_dir[e]
        };
        n * (-k * (l - rl))
    }

    /// The block K_bb = −∂f_b/∂x_b of edge `e` (K_aa = K_bb, K_ab = −K_bb),
    /// with the compressive transverse part dropped unless the tangent is
    /// exact.
    #[inline]
    fn spring_tangent(&self, e: usize, u: &[Vec3]) -> Mat3 {
        let d = self.edge_vector(e, u);
        let (k, rl) = (self.stiffness[e], self.rest_len[e]);
        let l = d.norm();
        if l > DEGENERATE_FRACTION * rl {
            let n = d / l;
            let nn = n * n.transpose();
            // k [n nᵀ + (1 − L/l)(I − n nᵀ)], the transverse factor clamped at 0.
            let transverse = if self.exact_tangent {
                1.0 - rl / l
            } else {
                (1.0 - rl / l).max(0.0)
            };
            (nn + (Mat3::identity() - nn) * transverse) * k
        } else {
            let n = self.rest_dir[e];
            n * n.transpose() * k
        }
    }
}

impl ForceModel for Msm {
    fn name(&self) -> &'static str {
        "msm"
    }

    fn add_forces(&self, u: &[Vec3], out: &mut [Vec3]) {
        debug_assert_eq!(u.len(), self.rest.len());
        for (e, &[a, b]) in self.edges.iter().enumerate() {
            let fb = self.spring_force(e, u);
            out[b as usize] += fb;
            out[a as usize] -= fb;
        }
    }

    fn add_df(&self, u: &[Vec3], du: &[Vec3], out: &mut [Vec3]) {
        debug_assert_eq!(u.len(), self.rest.len());
        for (e, &[a, b]) in self.edges.iter().enumerate() {
            let kb = self.spring_tangent(e, u);
            let dfb = -(kb * (du[b as usize] - du[a as usize]));
            out[b as usize] += dfb;
            out[a as usize] -= dfb;
        }
    }

    fn add_stiffness(&self, u: &[Vec3], k: &mut BlockTangent) {
        debug_assert_eq!(k.num_nodes(), self.rest.len());
        for (e, &[a, b]) in self.edges.iter().enumerate() {
            let kb = self.spring_tangent(e, u);
            k.diag[a as usize] += kb;
            k.diag[b as usize] += kb;
            k.add_block(a, b, e as u32, &(-kb));
        }
    }

    fn energy(&self, u: &[Vec3]) -> f64 {
        (0..self.edges.len())
            .map(|e| {
                let s = self.edge_vector(e, u).norm() - self.rest_len[e];
                0.5 * self.stiffness[e] * s * s
            })
            .sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::BTreeMap;

    #[test]
    fn collapsed_spring_stays_finite_and_pushes_apart() {
        let rest = vec![Vec3::zeros(), Vec3::x(), Vec3::y(), Vec3::z()];
        let mesh = TetMesh::new(rest.clone(), vec![[0, 1, 2, 3]], BTreeMap::new()).unwrap();
        let msm = Msm::new(&mesh, &Material::aorta());
        // Move node 1 onto node 0: edge (0, 1) has zero length.
        let mut u = vec![Vec3::zeros(); 4];
        u[1] = -Vec3::x();
        let mut f = vec![Vec3::zeros(); 4];
        msm.add_forces(&u, &mut f);
        let mut df = vec![Vec3::zeros(); 4];
        msm.add_df(&u, &[Vec3::new(0.1, 0.2, 0.3); 4], &mut df);
        let mut k = BlockTangent::zeros(&mesh);
        msm.add_stiffness(&u, &mut k);
        assert!(f.iter().chain(&df).all(|v| v.iter().all(|c| c.is_finite())));
        assert!(k.to_dense().iter().all(|c| c.is_finite()));
        assert!(msm.energy(&u).is_finite());
        // The collapsed spring alone pushes node 1 back along +x.
        let e01 = mesh.edges().iter().position(|&e| e == [0, 1]).unwrap();
        let fb = msm.spring_force(e01, &u);
        assert!(fb.x > 0.0 && fb.y.abs() < 1e-12 && fb.z.abs() < 1e-12);
    }

    #[test]
    fn van_gelder_stiffness() {
        // One unit right tet: every edge touches the single tet (V = 1/6).
        let rest = vec![Vec3::zeros(), Vec3::x(), Vec3::y(), Vec3::z()];
        let mesh = TetMesh::new(rest, vec![[0, 1, 2, 3]], BTreeMap::new()).unwrap();
        let m = Material::aorta();
        let msm = Msm::new(&mesh, &m);
        for (k, l) in msm.stiffness().iter().zip(msm.rest_lengths()) {
            assert!((k - m.youngs_pa / 6.0 / (l * l)).abs() <= 1e-12 * k);
        }
    }
}
