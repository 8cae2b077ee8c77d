//! Element-by-element hyperelastic FEM on P1 tets: the paper's FEM baseline.
//!
//! Per tet, with rest volume V and shape-function gradients D_i:
//! F = I + Σ_i u_i ⊗ D_i (eq. 1), P = ∂Ψ/∂F from [`crate::material::pk1`],
//! nodal force f_p = −V P D_p (eq. 7), force derivative
//! df_p = −V dP(F; Σ_q du_q ⊗ D_q) D_p (eq. 8), and the element tangent
//! K_pq[:, b] = V · dP(F; e_b ⊗ D_q) · D_p, so K = −∂f/∂u. The energy is
//! Σ V Ψ(F) (eq. 4 and 6 for StVK, eq. 9 for Neo-Hookean).
//!
//! Elements are evaluated in parallel (rayon, fixed-size chunks) into a
//! per-element buffer and then scattered serially into the nodes, so results
//! are bit-for-bit reproducible whatever the thread schedule. The buffers
//! (element forces, element tangents, chunk energies) are sized at
//! construction: no call allocates.

use super::{tet_pair_edges, BlockTangent, ForceModel, Scratch};
use crate::material::{dpk1, energy_density, pk1, Lame, Law, Material};
use crate::math::Mat3;
use crate::math::Vec3;
use crate::mesh::TetMesh;
use rayon::prelude::*;

/// Elements per parallel task: large enough that rayon's overhead is small
/// next to the work, small enough to balance two to eight cores on the arch.
const CHUNK: usize = 256;

/// Deformation gradient F = I + Σ_i u_i ⊗ D_i of a P1 tet (eq. 1), from the
/// shape-function gradients `grads` and the displacements `u` of its nodes.
#[inline]
pub fn deformation_gradient(grads: &[Vec3; 4], u: &[Vec3; 4]) -> Mat3 {
    let mut f = Mat3::identity();
    for (ui, di) in u.iter().zip(grads) {
        f += ui * di.transpose();
    }
    f
}

/// Gradient increment dF = Σ_i du_i ⊗ D_i (the same map as
/// [`deformation_gradient`] without the identity).
#[inline]
pub fn gradient_increment(grads: &[Vec3; 4], du: &[Vec3; 4]) -> Mat3 {
    let mut f = Mat3::zeros();
    for (ui, di) in du.iter().zip(grads) {
        f += ui * di.transpose();
    }
    f
}

/// Nodal internal forces f_p = −V P(F) D_p of one tet at deformation gradient `f`.
#[inline]
pub fn element_forces(law: Law, lame: Lame, volume: f64, grads: &[Vec3; 4], f: &Mat3) -> [Vec3; 4] {
    let vp = pk1(law, lame, f) * (-volume);
    grads.map(|d| vp * d)
}

/// Element tangent of one tet at `f`: block `[p][q]` is K_pq = −∂f_p/∂u_q,
/// column b being V · dP(F; e_b ⊗ D_q) · D_p. Symmetric: K_qp = K_pqᵀ.
///
/// StVK uses the closed form
/// K_pq = V [(D_qᵀ S D_p) I + λ (F D_p) ⊗ (F D_q) + μ (F D_q) ⊗ (F D_p) + μ (D_p·D_q) F Fᵀ]
/// (S the second Piola–Kirchhoff stress); Neo-Hookean evaluates the
/// directional derivative of P along the twelve unit directions.
pub fn element_stiffness(law: Law, lame: Lame, volume: f64, grads: &[Vec3; 4], f: &Mat3) -> [[Mat3; 4]; 4] {
    match law {
        Law::Stvk => stvk_element_stiffness(lame, volume, grads, f),
        Law::NeoHookean => element_stiffness_by_directions(law, lame, volume, grads, f),
    }
}

fn stvk_element_stiffness(lame: Lame, volume: f64, grads: &[Vec3; 4], f: &Mat3) -> [[Mat3; 4]; 4] {
    let s = crate::material::stvk_pk2(lame, &crate::material::green_strain(f)) * volume;
    let ffv = f * f.transpose() * (lame.mu * volume);
    let fd = grads.map(|d| f * d);
    let mut k = [[Mat3::zeros(); 4]; 4];
    for p in 0..4 {
        for q in p..4 {
            let fp_fq = fd[p] * fd[q].transpose() * volume;
            let b = Mat3::identity() * grads[q].dot(&(s * grads[p]))
                + fp_fq * lame.lambda
                + fp_fq.transpose() * lame.mu
                + ffv * grads[p].dot(&grads[q]);
            k[p][q] = b;
            k[q][p] = b.transpose();
        }
    }
    k
}

/// The element tangent from twelve directional derivatives of P (any law).
fn element_stiffness_by_directions(law: Law, lame: Lame, volume: f64, grads: &[Vec3; 4], f: &Mat3) -> [[Mat3; 4]; 4] {
    let mut k = [[Mat3::zeros(); 4]; 4];
    for q in 0..4 {
        for b in 0..3 {
            // e_b ⊗ D_q: row b is D_qᵀ.
            let mut df = Mat3::zeros();
            df.set_row(b, &grads[q].transpose());
            let dp = dpk1(law, lame, f, &df) * volume;
            for p in 0..4 {
                k[p][q].set_column(b, &(dp * grads[p]));
            }
        }
    }
    k
}

/// The element-wise hyperelastic FEM force model (StVK or Neo-Hookean).
#[derive(Debug, Clone)]
pub struct Fem {
    law: Law,
    lame: Lame,
    num_nodes: usize,
    tets: Vec<[u32; 4]>,
    grads: Vec<[Vec3; 4]>,
    volumes: Vec<f64>,
    pair_edges: Vec<[[u32; 4]; 4]>,
    scratch: Scratch<FemScratch>,
}

/// Per-element results, reused between calls (see [`Scratch`]).
#[derive(Debug, Clone)]
struct FemScratch {
    /// Nodal vectors of each tet (forces or force derivatives).
    nodal: Vec<[Vec3; 4]>,
    /// Element tangents.
    blocks: Vec<[[Mat3; 4]; 4]>,
    /// Energy of each chunk of `CHUNK` tets.
    energy: Vec<f64>,
}

impl Fem {
    /// Builds the model for `mesh` with the elastic constants of `material`
    /// and the hyperelastic `law`. Copies the per-tet data it needs.
    pub fn new(mesh: &TetMesh, material: &Material, law: Law) -> Fem {
        Fem {
            law,
            lame: material.lame(),
            num_nodes: mesh.num_nodes(),
            tets: mesh.tets().to_vec(),
            grads: mesh.grads().to_vec(),
            volumes: mesh.volumes().to_vec(),
            pair_edges: tet_pair_edges(mesh),
            scratch: Scratch::new(FemScratch {
                nodal: vec![[Vec3::zeros(); 4]; mesh.tets().len()],
                blocks: vec![[[Mat3::zeros(); 4]; 4]; mesh.tets().len()],
                energy: vec![0.0; mesh.tets().len().div_ceil(CHUNK)],
            }),
        }
    }

    /// The hyperelastic law.
    pub fn law(&self) -> Law {
        self.law
    }

    /// The Lamé coefficients (eq. 5).
    pub fn lame(&self) -> Lame {
        self.lame
    }

    #[inline]
    fn gather(&self, t: usize, u: &[Vec3]) -> [Vec3; 4] {
        self.tets[t].map(|i| u[i as usize])
    }

    #[inline]
    fn f_of(&self, t: usize, u: &[Vec3]) -> Mat3 {
        deformation_gradient(&self.grads[t], &self.gather(t, u))
    }

    /// Evaluates `elem` on every tet in parallel, then adds the four nodal
    /// vectors of each tet into `out`.
    fn scatter_elements<E>(&self, out: &mut [Vec3], elem: E)
    where
        E: Fn(usize) -> [Vec3; 4] + Sync,
    {
        self.scratch.with(|sc| {
            let buf = &mut sc.nodal;
            buf.par_chunks_mut(CHUNK).enumerate().for_each(|(c, chunk)| {
                for (k, slot) in chunk.iter_mut().enumerate() {
                    *slot = elem(c * CHUNK + k);
                }
            });
            for (tet, fs) in self.tets.iter().zip(buf.iter()) {
                for (&i, fi) in tet.iter().zip(fs) {
                    out[i as usize] += fi;
                }
            }
        });
    }
}

impl ForceModel for Fem {
    fn name(&self) -> &'static str {
        match self.law {
            Law::Stvk => "fem-stvk",
            Law::NeoHookean => "fem-neohookean",
        }
    }

    fn add_forces(&self, u: &[Vec3], out: &mut [Vec3]) {
        debug_assert_eq!(u.len(), self.num_nodes);
        self.scatter_elements(out, |t| {
            element_forces(self.law, self.lame, self.volumes[t], &self.grads[t], &self.f_of(t, u))
        });
    }

    fn add_df(&self, u: &[Vec3], du: &[Vec3], out: &mut [Vec3]) {
        debug_assert_eq!(u.len(), self.num_nodes);
        debug_assert_eq!(du.len(), self.num_nodes);
        self.scatter_elements(out, |t| {
            let g = &self.grads[t];
            let f = self.f_of(t, u);
            let df = gradient_increment(g, &self.gather(t, du));
            let vdp = dpk1(self.law, self.lame, &f, &df) * (-self.volumes[t]);
            g.map(|d| vdp * d)
        });
    }

    fn add_stiffness(&self, u: &[Vec3], k: &mut BlockTangent) {
        debug_assert_eq!(k.num_nodes(), self.num_nodes);
        self.scratch.with(|sc| {
            let blocks = &mut sc.blocks;
            blocks.par_chunks_mut(CHUNK).enumerate().for_each(|(c, chunk)| {
                for (k, kt) in chunk.iter_mut().enumerate() {
                    let t = c * CHUNK + k;
                    *kt = element_stiffness(self.law, self.lame, self.volumes[t], &self.grads[t], &self.f_of(t, u));
                }
            });
            for ((tet, pe), kt) in self.tets.iter().zip(&self.pair_edges).zip(blocks.iter()) {
                for p in 0..4 {
                    // K_qp = K_pqᵀ, so the upper triangle (p ≤ q) carries everything.
                    for q in p..4 {
                        k.add_block(tet[p], tet[q], pe[p][q], &kt[p][q]);
                    }
                }
            }
        });
    }

    fn energy(&self, u: &[Vec3]) -> f64 {
        // Chunk sums stored in order, then summed serially: reproducible.
        self.scratch.with(|sc| {
            sc.energy
                .par_iter_mut()
                .zip(self.volumes.par_chunks(CHUNK))
                .enumerate()
                .for_each(|(c, (e, vs))| {
                    *e = vs
                        .iter()
                        .enumerate()
                        .map(|(k, v)| v * energy_density(self.law, self.lame, &self.f_of(c * CHUNK + k, u)))
                        .sum::<f64>();
                });
            sc.energy.iter().sum()
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stvk_element_tangent_matches_closed_form() {
        // K_pq = V [(D_qᵀ S D_p) I + λ (F D_p)⊗(F D_q) + μ (F D_q)⊗(F D_p) + μ (D_p·D_q) F Fᵀ]
        // (the tensor-mass reference sheet, with K = −∂f/∂u).
        let x = [
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(1.1, 0.1, -0.2),
            Vec3::new(0.3, 0.9, 0.1),
            Vec3::new(0.2, 0.3, 1.2),
        ];
        let g = crate::mesh::shape_gradients(&x);
        let v = crate::mesh::signed_volume(&x[0], &x[1], &x[2], &x[3]);
        let l = Lame::from_young_poisson(65e3, 0.45);
        let u = [
            Vec3::new(0.05, -0.1, 0.02),
            Vec3::new(-0.03, 0.08, 0.1),
            Vec3::new(0.12, 0.0, -0.07),
            Vec3::new(0.0, 0.04, 0.09),
        ];
        let f = deformation_gradient(&g, &u);
        let s = crate::material::stvk_pk2(l, &crate::material::green_strain(&f));
        let k = element_stiffness(Law::Stvk, l, v, &g, &f);
        let kd = element_stiffness_by_directions(Law::Stvk, l, v, &g, &f);
        for p in 0..4 {
            for q in 0..4 {
                let (fp, fq) = (f * g[p], f * g[q]);
                let closed = (Mat3::identity() * g[q].dot(&(s * g[p]))
                    + fp * fq.transpose() * l.lambda
                    + fq * fp.transpose() * l.mu
                    + f * f.transpose() * (l.mu * g[p].dot(&g[q])))
                    * v;
                assert!((k[p][q] - closed).amax() <= 1e-12 * closed.amax(), "block {p}{q}");
                assert!(
                    (kd[p][q] - closed).amax() <= 1e-12 * closed.amax(),
                    "block {p}{q} (dP path)"
                );
                assert!((k[p][q] - k[q][p].transpose()).amax() <= 1e-12 * closed.amax());
            }
        }
        // Forces: f_p = −V F S D_p.
        let fe = element_forces(Law::Stvk, l, v, &g, &f);
        for p in 0..4 {
            assert!((fe[p] + f * s * g[p] * v).norm() <= 1e-12 * fe[p].norm());
        }
    }

    #[test]
    fn neo_hookean_inverted_tet_is_finite_and_pushed_back() {
        let x = [Vec3::zeros(), Vec3::x(), Vec3::y(), Vec3::z()];
        let mesh = TetMesh::new(x.to_vec(), vec![[0, 1, 2, 3]], Default::default()).unwrap();
        let fem = Fem::new(&mesh, &Material::aorta(), Law::NeoHookean);
        // Node 3 pushed through the opposite face: J = -0.5.
        let u = [Vec3::zeros(), Vec3::zeros(), Vec3::zeros(), Vec3::new(0.0, 0.0, -1.5)];
        let mut f = vec![Vec3::zeros(); 4];
        fem.add_forces(&u, &mut f);
        let mut df = vec![Vec3::zeros(); 4];
        fem.add_df(&u, &[Vec3::new(0.1, -0.2, 0.3); 4], &mut df);
        let mut k = BlockTangent::zeros(&mesh);
        fem.add_stiffness(&u, &mut k);
        assert!(f.iter().chain(&df).all(|v| v.iter().all(|c| c.is_finite())));
        assert!(k.to_dense().iter().all(|c| c.is_finite()) && fem.energy(&u).is_finite());
        assert!(f[3].z > 0.0, "inverted tet should push node 3 back up, got {:?}", f[3]);
    }
}
