//! Linear tensor-mass model (Cotin/Delingette): linear elasticity with its
//! stiffness stored on the mesh's vertices and edges.
//!
//! Per tet with rest volume V and shape-function gradients D_i, the linear
//! elastic stiffness between nodes p and q is
//! K_pq = V [λ D_p ⊗ D_q + μ D_q ⊗ D_p + μ (D_p·D_q) I] (the tangent of eq. 4
//! at U = 0; twice the B_pq of the tensor-mass reference sheet). Summing the
//! per-tet blocks into the vertex (p = q) and edge (p ≠ q) they belong to
//! gives [`Tmm::k0`]; the force is then f = −K0 u by one loop over vertices
//! and one over edges, and W = ½ uᵀ K0 u.
//!
//! Linear elasticity is not invariant to rotation: a large rigid rotation
//! produces spurious forces. That is the known limit the nonlinear model
//! (`nvtmm`, which reuses `k0` as its quadratic part) removes.

use super::{tet_pair_edges, BlockTangent, ForceModel};
use crate::material::{Lame, Material};
use crate::math::Mat3;
use crate::math::Vec3;
use crate::mesh::TetMesh;

/// One tet's linear stiffness block between its local nodes with gradients
/// `dp` and `dq`: V [λ D_p ⊗ D_q + μ D_q ⊗ D_p + μ (D_p·D_q) I].
#[inline]
pub fn linear_block(lame: Lame, volume: f64, dp: &Vec3, dq: &Vec3) -> Mat3 {
    (dp * dq.transpose() * lame.lambda + dq * dp.transpose() * lame.mu + Mat3::identity() * (lame.mu * dp.dot(dq)))
        * volume
}

/// The linear tensor-mass force model.
#[derive(Debug, Clone)]
pub struct Tmm {
    /// The rest stiffness K0 on the mesh's vertex/edge pattern: K0 = −∂f/∂u,
    /// constant. The nonlinear tensor-mass model reuses it as its linear part.
    pub k0: BlockTangent,
}

impl Tmm {
    /// Precomputes the vertex and edge stiffness tensors of `mesh` for the
    /// elastic constants of `material`.
    pub fn new(mesh: &TetMesh, material: &Material) -> Tmm {
        let lame = material.lame();
        let mut k0 = BlockTangent::zeros(mesh);
        let pair_edges = tet_pair_edges(mesh);
        for ((tet, g), (v, pe)) in mesh
            .tets()
            .iter()
            .zip(mesh.grads())
            .zip(mesh.volumes().iter().zip(&pair_edges))
        {
            for p in 0..4 {
                for q in p..4 {
                    k0.add_block(tet[p], tet[q], pe[p][q], &linear_block(lame, *v, &g[p], &g[q]));
                }
            }
        }
        Tmm { k0 }
    }

    /// out −= K0 x, by the vertex loop and the edge loop.
    fn sub_k0(&self, x: &[Vec3], out: &mut [Vec3]) {
        for (i, d) in self.k0.diag.iter().enumerate() {
            out[i] -= d * x[i];
        }
        for (b, &[i, j]) in self.k0.off.iter().zip(&self.k0.edges) {
            let (i, j) = (i as usize, j as usize);
            out[i] -= b * x[j];
            out[j] -= b.tr_mul(&x[i]);
        }
    }
}

impl ForceModel for Tmm {
    fn name(&self) -> &'static str {
        "tmm"
    }

    fn add_forces(&self, u: &[Vec3], out: &mut [Vec3]) {
        debug_assert_eq!(u.len(), self.k0.num_nodes());
        self.sub_k0(u, out);
    }

    fn add_df(&self, _u: &[Vec3], du: &[Vec3], out: &mut [Vec3]) {
        debug_assert_eq!(du.len(), self.k0.num_nodes());
        self.sub_k0(du, out);
    }

    fn add_stiffness(&self, _u: &[Vec3], k: &mut BlockTangent) {
        k.add_scaled(1.0, &self.k0);
    }

    fn energy(&self, u: &[Vec3]) -> f64 {
        let diag: f64 = self.k0.diag.iter().zip(u).map(|(d, ui)| ui.dot(&(d * ui))).sum();
        let off: f64 = self
            .k0
            .off
            .iter()
            .zip(&self.k0.edges)
            .map(|(b, &[i, j])| u[i as usize].dot(&(b * u[j as usize])))
            .sum();
        0.5 * diag + off
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::material::Law;
    use crate::model::fem::Fem;
    use std::collections::BTreeMap;

    /// Two irregular tets sharing a face: no symmetry that could hide a
    /// transposed outer product.
    fn two_tets() -> TetMesh {
        let rest = vec![
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(1.1, 0.1, -0.2),
            Vec3::new(0.3, 0.9, 0.1),
            Vec3::new(0.2, 0.3, 1.2),
            Vec3::new(1.0, 1.0, 0.9),
        ];
        TetMesh::new(rest, vec![[0, 1, 2, 3], [1, 2, 3, 4]], BTreeMap::new()).unwrap()
    }

    #[test]
    fn k0_is_the_fem_tangent_at_rest() {
        let mesh = two_tets();
        let m = Material::aorta();
        let tmm = Tmm::new(&mesh, &m);
        let zero = vec![Vec3::zeros(); mesh.num_nodes()];
        for law in [Law::Stvk, Law::NeoHookean] {
            let mut k = BlockTangent::zeros(&mesh);
            Fem::new(&mesh, &m, law).add_stiffness(&zero, &mut k);
            let (a, b) = (tmm.k0.to_dense(), k.to_dense());
            assert!(
                (&a - &b).amax() <= 1e-12 * b.amax(),
                "{law:?}: K0 differs from FEM at rest"
            );
        }
        // The transposed outer products would differ: make sure the test can tell.
        let l = m.lame();
        let g = mesh.grads()[0];
        let swapped = (g[1] * g[2].transpose() * l.mu + g[2] * g[1].transpose() * l.lambda) * mesh.volumes()[0];
        let right = (g[1] * g[2].transpose() * l.lambda + g[2] * g[1].transpose() * l.mu) * mesh.volumes()[0];
        assert!((swapped - right).amax() > 1e-3 * right.amax());
    }

    #[test]
    fn energy_is_half_u_k0_u() {
        let mesh = two_tets();
        let tmm = Tmm::new(&mesh, &Material::aorta());
        let u: Vec<Vec3> = (0..5)
            .map(|i| Vec3::new(0.01 * i as f64, -0.02, 0.005 * (i * i) as f64))
            .collect();
        let mut f = vec![Vec3::zeros(); 5];
        tmm.add_forces(&u, &mut f);
        let w: f64 = -0.5 * u.iter().zip(&f).map(|(a, b)| a.dot(b)).sum::<f64>();
        assert!((w - tmm.energy(&u)).abs() <= 1e-12 * w.abs());
    }
}
