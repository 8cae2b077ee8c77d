//! The nonlinear refresh of the reduced model: the background thread's full
//! NVTMM solve sits at a displacement ū; the haptic loop's linear reduced
//! model is re-linearized there,
//!
//! ```text
//! u ≈ ū + Φ δq,     δq̈ + D_r δq̇ + K_r(ū) δq = Φᵀ (f_c − f̄_c),     K_r(ū) = Φᵀ K(ū) Φ,
//! ```
//!
//! where f̄_c are the contact forces the full solve was given (its ū already
//! answers them; the reduced model answers the difference). One refresh costs
//! one tangent assembly, r block-sparse mat-vecs and a 3n × r × r product.
//!
//! When the loop swaps from the previous model (ū₀, Φ₀) to a new one
//! (ū₁, Φ₁) it carries its state over by the M-orthogonal projection of the
//! displacement it had, u = ū₀ + Φ₀ δq₀:
//!
//! ```text
//! δq₁ = Φ₁ᵀ M (ū₀ + Φ₀ δq₀ − ū₁) = T δq₀ + s,    T = Φ₁ᵀ M Φ₀,   s = Φ₁ᵀ M (ū₀ − ū₁)
//! ```
//!
//! (T = I for the same basis), so the loop does an r × r mat-vec at the
//! swap and no per-node work.

use super::basis::ModalBasis;
use crate::math::Vec3;
use crate::mesh::TetMesh;
use crate::model::{BlockTangent, ForceModel};
use faer::linalg::matmul::matmul;
use faer::{Accum, MatMut, MatRef, Par};
use nalgebra::{DMatrix, DVector};

/// Columns per chunk of the blocked multi-vector product.
const CHUNK: usize = 16;

/// A block of at most [`CHUNK`] basis columns stored node-major,
/// `x[(3 i + c) CHUNK + k]` = Φ(3i + c, first + k) for k < w (zero beyond),
/// so the product with a 3 × 3 block streams [`CHUNK`] contiguous numbers.
#[derive(Debug, Clone)]
struct Chunk {
    first: usize,
    w: usize,
    x: Vec<f64>,
    y: Vec<f64>,
}

/// Re-linearizes a full model in a fixed basis. Holds the scratch so that
/// repeated refreshes reuse their memory.
#[derive(Debug, Clone)]
pub struct Refresher {
    phi: DMatrix<f64>,
    mass3: DVector<f64>,
    tangent: BlockTangent,
    chunks: Vec<Chunk>,
}

/// y = K x for one column chunk (x, y node-major, [`CHUNK`] columns; the
/// fixed width lets the inner loops compile to SIMD).
fn mul_chunk(k: &BlockTangent, x: &[f64], y: &mut [f64]) {
    const W: usize = CHUNK;
    y.iter_mut().for_each(|v| *v = 0.0);
    let row = 3 * W;
    let lane = |s: &[f64], at: usize| -> [f64; W] { s[at..at + W].try_into().unwrap_or([0.0; W]) };
    for (i, d) in k.diag.iter().enumerate() {
        let (x0, x1, x2) = (lane(x, i * row), lane(x, i * row + W), lane(x, i * row + 2 * W));
        for a in 0..3 {
            let (d0, d1, d2) = (d[(a, 0)], d[(a, 1)], d[(a, 2)]);
            let yi = &mut y[i * row + a * W..i * row + (a + 1) * W];
            for c in 0..W {
                yi[c] += d0 * x0[c] + d1 * x1[c] + d2 * x2[c];
            }
        }
    }
    for (b, &[i, j]) in k.off.iter().zip(&k.edges) {
        let (i, j) = (i as usize, j as usize);
        let (xj0, xj1, xj2) = (lane(x, j * row), lane(x, j * row + W), lane(x, j * row + 2 * W));
        let (xi0, xi1, xi2) = (lane(x, i * row), lane(x, i * row + W), lane(x, i * row + 2 * W));
        // y_i += B x_j, y_j += Bᵀ x_i.
        for a in 0..3 {
            let (b0, b1, b2) = (b[(a, 0)], b[(a, 1)], b[(a, 2)]);
            let yi = &mut y[i * row + a * W..i * row + (a + 1) * W];
            for c in 0..W {
                yi[c] += b0 * xj0[c] + b1 * xj1[c] + b2 * xj2[c];
            }
            let (bt0, bt1, bt2) = (b[(0, a)], b[(1, a)], b[(2, a)]);
            let yj = &mut y[j * row + a * W..j * row + (a + 1) * W];
            for c in 0..W {
                yj[c] += bt0 * xi0[c] + bt1 * xi1[c] + bt2 * xi2[c];
            }
        }
    }
}

impl Refresher {
    /// A refresher for `basis` on `mesh` with the lumped `mass` (kg per node;
    /// missing entries count as zero).
    pub fn new(mesh: &TetMesh, basis: &ModalBasis, mass: &[f64]) -> Refresher {
        let n = mesh.num_nodes();
        let mut mass3 = DVector::zeros(3 * n);
        for (i, &m) in mass.iter().enumerate().take(n) {
            for c in 0..3 {
                mass3[3 * i + c] = m;
            }
        }
        let r = basis.len();
        let rows = basis.phi.nrows().min(3 * n);
        let mut chunks = Vec::new();
        let mut first = 0;
        while first < r {
            let w = CHUNK.min(r - first);
            // Padded to CHUNK columns (zeros beyond w).
            let mut x = vec![0.0; 3 * n * CHUNK];
            for row in 0..rows {
                for c in 0..w {
                    x[row * CHUNK + c] = basis.phi[(row, first + c)];
                }
            }
            chunks.push(Chunk {
                first,
                w,
                x,
                y: vec![0.0; 3 * n * CHUNK],
            });
            first += w;
        }
        Refresher {
            phi: basis.phi.clone(),
            mass3,
            tangent: BlockTangent::zeros(mesh),
            chunks,
        }
    }

    /// Basis size r.
    pub fn len(&self) -> usize {
        self.phi.ncols()
    }

    /// Whether the basis is empty.
    pub fn is_empty(&self) -> bool {
        self.phi.ncols() == 0
    }

    /// The basis.
    pub fn phi(&self) -> &DMatrix<f64> {
        &self.phi
    }

    /// K_r(u) = Φᵀ K(u) Φ (r × r, symmetrized) of `model` at displacement `u`:
    /// one tangent assembly, then [`Refresher::project_tangent`].
    pub fn reduced_stiffness(&mut self, model: &dyn ForceModel, u: &[Vec3]) -> DMatrix<f64> {
        self.reduced_stiffness_with(model, u, |_| {})
    }

    /// As [`Refresher::reduced_stiffness`] with `extra` adding to the
    /// assembled tangent before the projection (e.g. a load's stiffness).
    pub fn reduced_stiffness_with(
        &mut self,
        model: &dyn ForceModel,
        u: &[Vec3],
        extra: impl FnOnce(&mut BlockTangent),
    ) -> DMatrix<f64> {
        let mut k = std::mem::take(&mut self.tangent);
        k.clear();
        model.add_stiffness(u, &mut k);
        extra(&mut k);
        let kr = self.project_tangent(&k);
        self.tangent = k;
        kr
    }

    /// Φᵀ K Φ (r × r, symmetrized) of an assembled tangent `k` (e.g. the one
    /// the implicit step just built, [`crate::solver::ImplicitEuler::last_stiffness`]):
    /// a blocked multi-vector product, column chunks in parallel, then one
    /// small dense product per pair of chunks.
    pub fn project_tangent(&mut self, k: &BlockTangent) -> DMatrix<f64> {
        use rayon::prelude::*;
        let r = self.len();
        let n3 = self.mass3.len();
        if k.num_nodes() * 3 != n3 {
            return DMatrix::zeros(r, r);
        }
        self.chunks.par_iter_mut().for_each(|ch| mul_chunk(k, &ch.x, &mut ch.y));
        let mut kr = DMatrix::zeros(r, r);
        for a in &self.chunks {
            let xa = MatRef::from_column_major_slice(&a.x, CHUNK, n3);
            let xa = xa.subrows(0, a.w);
            for b in &self.chunks {
                let yb = MatRef::from_column_major_slice(&b.y, CHUNK, n3);
                let yb = yb.subrows(0, b.w);
                let mut blk = DMatrix::zeros(a.w, b.w);
                matmul(
                    MatMut::from_column_major_slice_mut(blk.as_mut_slice(), a.w, b.w),
                    Accum::Replace,
                    xa,
                    yb.transpose(),
                    1.0,
                    Par::Seq,
                );
                kr.view_mut((a.first, b.first), (a.w, b.w)).copy_from(&blk);
            }
        }
        (&kr + kr.transpose()) * 0.5
    }

    /// Φᵀ M u: the reduced coordinates of a displacement field `u`.
    pub fn project_mass(&self, u: &[Vec3]) -> DVector<f64> {
        let mut mu = DVector::zeros(self.mass3.len());
        for (i, ui) in u.iter().enumerate().take(self.mass3.len() / 3) {
            for c in 0..3 {
                mu[3 * i + c] = self.mass3[3 * i + c] * ui[c];
            }
        }
        self.phi.tr_mul(&mu)
    }

    /// Φᵀ f: the generalized force of nodal forces `f`.
    pub fn project_force(&self, f: &[Vec3]) -> DVector<f64> {
        let mut v = DVector::zeros(self.mass3.len());
        for (i, fi) in f.iter().enumerate().take(self.mass3.len() / 3) {
            for c in 0..3 {
                v[3 * i + c] = fi[c];
            }
        }
        self.phi.tr_mul(&v)
    }

    /// T = Φᵀ M Φ_prev, the state transfer from a previous basis (r × r_prev).
    pub fn transfer_from(&self, prev: &DMatrix<f64>) -> DMatrix<f64> {
        let mut mp = prev.clone();
        for mut col in mp.column_iter_mut() {
            col.component_mul_assign(&self.mass3);
        }
        self.phi.tr_mul(&mp)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::material::Material;
    use crate::mesh::block::block;
    use crate::model::nvtmm::Nvtmm;

    #[test]
    fn reduced_stiffness_matches_the_dense_projection_and_the_transfer_is_identity_on_one_basis() {
        let mesh = block([3, 2, 2], [0.03, 0.02, 0.02]).unwrap();
        let mat = Material::aorta();
        let model = Nvtmm::new(&mesh, &mat);
        let mass = mesh.lumped_mass(mat.density);
        let fixed = mesh.node_set("x_min").unwrap().to_vec();
        let u0 = vec![Vec3::zeros(); mesh.num_nodes()];
        let basis = ModalBasis::compute(&crate::reduced::BasisSpec {
            stiffness: crate::reduced::Stiffness::Model {
                mesh: &mesh,
                model: &model,
                u: &u0,
            },
            mass: &mass,
            fixed: &fixed,
            r: 6,
            statics: crate::reduced::Statics::None,
            warm: None,
            params: crate::reduced::BasisParams::default(),
        })
        .unwrap();
        let mut r = Refresher::new(&mesh, &basis, &mass);
        // At rest K_r = diag(ω²).
        let k0 = r.reduced_stiffness(&model, &u0);
        for i in 0..6 {
            for j in 0..6 {
                let want = if i == j { basis.omega2[i] } else { 0.0 };
                assert!((k0[(i, j)] - want).abs() <= 1e-6 * basis.omega2[5], "{i} {j}");
            }
        }
        // At a deformed state it equals Φᵀ K Φ with the dense K.
        let u: Vec<Vec3> = mesh
            .rest()
            .iter()
            .map(|x| Vec3::new(0.0, 0.0, 0.2 * x.x * x.x / 0.03))
            .collect();
        let mut kt = BlockTangent::zeros(&mesh);
        model.add_stiffness(&u, &mut kt);
        let dense = basis.phi.transpose() * kt.to_dense() * &basis.phi;
        let k1 = r.reduced_stiffness(&model, &u);
        assert!((&k1 - &dense).norm() <= 1e-9 * dense.norm());
        assert!(
            (&k1 - &k0).norm() > 1e-3 * k0.norm(),
            "the linearization must change with u"
        );
        let t = r.transfer_from(&basis.phi);
        assert!((t - DMatrix::<f64>::identity(6, 6)).norm() <= 1e-9);
        // Projections: Φᵀ M Φ q = q.
        let q = DVector::from_fn(6, |i, _| (i as f64 + 1.0) * 1e-4);
        let uq = basis.expand(&q);
        assert!((r.project_mass(&uq) - &q).norm() <= 1e-12);
    }
}
