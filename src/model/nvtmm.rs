//! NVTMM: the nonlinear (St Venant–Kirchhoff) tensor-mass model with
//! Prony-series viscoelasticity (paper sections II–III; Picinbono et al. 2003).
//!
//! Per tet, with shape gradients D_i, d_ij = D_i·D_j and rest volume V, the
//! StVK energy (eq. 3–6) is a quartic polynomial of the nodal displacements
//! (Picinbono, Delingette and Ayache, Graphical Models 65(5), 2003):
//!
//! W = Σ_ij U_iᵀ B_ij U_j + Σ_ijk (U_i·U_j)(C_ijk·U_k) + Σ_ijkl 𝒟_ijkl (U_i·U_j)(U_k·U_l)
//!
//! The tensor-mass idea is to sum these per-tet coefficients, at rest and
//! once, onto the mesh entities named by their distinct vertices. We index
//! the scalar products s_P = U_i·U_j by *pairs* P = {i, j}: a vertex (i = j)
//! or an edge (i ≠ j). Then
//!
//! W(u) = ½ uᵀ K₀ u + sᵀ 𝒞 u + sᵀ 𝔇 s
//!
//! where K₀ = 2B are the per-vertex and per-edge linear tensors (exactly the
//! linear [`Tmm`] model), 𝒞 holds one 3-vector per (pair, vertex) that share a
//! tet (so on vertices, edges and triangles), and 𝔇 one scalar per (pair,
//! pair) that share a tet (vertices, edges, triangles and tets). Forces,
//! tangent-vector products and the assembled tangent are then sparse products
//! with these precomputed tensors — no per-element work at run time. With
//! h_{P,r} = ∂s_P/∂U_r (2U_v for a vertex pair, U_b for r = a of edge {a,b}):
//!
//! - ∂W/∂U_r = (K₀u)_r + (𝒞ᵀs)_r + Σ_{P∋r} w_P h_{P,r},  w = 𝒞u + 2𝔇s   (eq. 7)
//! - ∂²W/∂U_r∂U_t = K₀_rt + Σ_P [h_{P,r} ⊗ (𝒞_Pt + 2 z_Pt) + 𝒞_Pr ⊗ h_{P,t}
//!   + w_P ∂h_{P,r}/∂U_t], z_Pt = Σ_Q 𝔇_PQ h_{Q,t}   (eq. 8)
//!
//! Viscoelasticity (section III) wraps this model in [`Viscoelastic`], which
//! applies the Prony series per element on the rest-frame (second
//! Piola–Kirchhoff) stress, so a rigid rotation creates no viscous force: the
//! tensor-mass elastic part is scaled by (1 − Σ A_i) and the history stress
//! adds its own force and tangent. The Neo-Hookean law has no
//! polynomial (tensor-mass) form because of log J; `Law::NeoHookean` is served
//! by the element [`Fem`] model with the same Prony machinery.
//!
//! [`Tmm`]: super::tmm::Tmm
//! [`Fem`]: super::fem::Fem
//! [`Viscoelastic`]: super::viscoelastic::Viscoelastic

use super::{BlockTangent, ForceModel, Scratch};
use crate::material::Material;
use crate::math::Mat3;
use crate::math::Vec3;
use crate::mesh::{TetMesh, TET_EDGE_LOCAL};
use rayon::prelude::*;

/// One tet's contributions: 𝒞 triplets, 𝔇 triplets and K₀ blocks.
type TetTensors = (Vec<(u32, u32, Vec3)>, Vec<(u32, u32, f64)>, [[Mat3; 4]; 4]);

/// Sentinel edge id for a (node, node) pair on the diagonal.
const NONE: u32 = u32::MAX;

/// Nonlinear viscoelastic tensor-mass model (StVK + Prony).
#[derive(Debug, Clone)]
pub struct Nvtmm {
    n: usize,
    edges: Vec<[u32; 2]>,
    /// Linear tensors (per vertex and per edge), K₀ = 2B.
    k0: BlockTangent,
    /// 𝒞 as CSR: rows are pairs (vertices then edges), columns vertices.
    c_ptr: Vec<u32>,
    c_col: Vec<u32>,
    c_val: Vec<Vec3>,
    /// For each 𝒞 slot (P, t): the edge joining each member r of P to t
    /// (`NONE` when r == t; second entry unused for vertex pairs).
    c_edge: Vec<[u32; 2]>,
    /// 𝒞ᵀ as CSR over vertices: (pair, coefficient) for g = 𝒞ᵀ s.
    ct_ptr: Vec<u32>,
    ct_pair: Vec<u32>,
    ct_val: Vec<Vec3>,
    /// 𝔇 as symmetric CSR over pairs (both triangles stored).
    d_ptr: Vec<u32>,
    d_col: Vec<u32>,
    d_val: Vec<f64>,
    /// For each 𝔇 entry (P, Q): the 𝒞 slot in row P of each member t of Q
    /// (second entry `NONE` for a vertex pair Q).
    d_slot: Vec<[u32; 2]>,
    /// Working memory of the force, df and tangent passes.
    scratch: Scratch<NvtmmScratch>,
}

/// Buffers sized at construction (see [`Scratch`]): no call allocates.
#[derive(Debug, Clone)]
struct NvtmmScratch {
    /// s, w and their derivatives δs, δw, one entry per pair.
    s: Vec<f64>,
    w: Vec<f64>,
    ds: Vec<f64>,
    dw: Vec<f64>,
    /// The elastic gradient (or its derivative), one entry per node.
    grad: Vec<Vec3>,
    /// h_{P,r} per pair P, for its members r = (a, b): (2U_a, 0) for a vertex
    /// pair, (U_b, U_a) for an edge.
    h: Vec<[Vec3; 2]>,
    /// The tangent assembly's parts, one per parallel task.
    parts: Vec<AssemblyPart>,
}

/// One parallel task of the tangent assembly: a contiguous range of pairs
/// (balanced on 𝒞 slots, fixed at construction, so the sum is deterministic),
/// its own block buffers, and a row of z.
#[derive(Debug, Clone)]
struct AssemblyPart {
    pairs: std::ops::Range<usize>,
    diag: Vec<Mat3>,
    off: Vec<Mat3>,
    /// z_Pt = Σ_Q 𝔇_PQ h_{Q,t} of the current row P (longest 𝒞 row).
    z: Vec<Vec3>,
}

/// Members of a pair: (a, a) for a vertex pair, (low, high) for an edge.
#[inline]
fn pair_nodes(n: usize, edges: &[[u32; 2]], p: usize) -> [u32; 2] {
    if p < n {
        [p as u32, p as u32]
    } else {
        edges[p - n]
    }
}

impl Nvtmm {
    /// Precomputes the tensors of `mesh` for an StVK material.
    pub fn new(mesh: &TetMesh, material: &Material) -> Nvtmm {
        let lame = material.lame();
        let (lam, mu) = (lame.lambda, lame.mu);
        let n = mesh.num_nodes();
        let edges = mesh.edges().to_vec();
        let np = n + edges.len();

        // Per-tet coefficients as (row, col, value) triplets, merged by sorting.
        let per_tet: Vec<TetTensors> = mesh
            .tets()
            .par_iter()
            .enumerate()
            .map(|(t, tet)| {
                let g = &mesh.grads()[t];
                let v = mesh.volumes()[t];
                let te = &mesh.tet_edges()[t];
                let mut d = [[0.0; 4]; 4];
                for i in 0..4 {
                    for j in 0..4 {
                        d[i][j] = g[i].dot(&g[j]);
                    }
                }
                // Local pairs: 4 vertex pairs then 6 edge pairs.
                let mut lp = [(0usize, 0usize, 0u32, 1.0f64); 10];
                for i in 0..4 {
                    lp[i] = (i, i, tet[i], 1.0);
                }
                for (k, [i, j]) in TET_EDGE_LOCAL.iter().enumerate() {
                    lp[4 + k] = (*i, *j, (n as u32) + te[k], 2.0);
                }
                let mut c = Vec::with_capacity(40);
                for &(i, j, pid, m) in &lp {
                    for k in 0..4 {
                        let cijk = (g[k] * (0.5 * lam * d[i][j]) + (g[j] * d[i][k] + g[i] * d[j][k]) * (0.5 * mu)) * v;
                        c.push((pid, tet[k], cijk * m));
                    }
                }
                let mut dd = Vec::with_capacity(100);
                for &(i, j, p, mp) in &lp {
                    for &(k, l, q, mq) in &lp {
                        let dijkl =
                            v * (lam / 8.0 * d[i][j] * d[k][l] + mu / 8.0 * (d[i][k] * d[j][l] + d[j][k] * d[i][l]));
                        dd.push((p, q, dijkl * mp * mq));
                    }
                }
                let mut b = [[Mat3::zeros(); 4]; 4];
                for i in 0..4 {
                    for j in 0..4 {
                        // K₀_ij = 2 B_ij = V [λ D_i⊗D_j + μ D_j⊗D_i + μ d_ij I].
                        b[i][j] = (g[i] * g[j].transpose() * lam
                            + g[j] * g[i].transpose() * mu
                            + Mat3::identity() * (mu * d[i][j]))
                            * v;
                    }
                }
                (c, dd, b)
            })
            .collect();

        let mut k0 = BlockTangent::zeros(mesh);
        let mut c_trip: Vec<(u32, u32, Vec3)> = Vec::new();
        let mut d_trip: Vec<(u32, u32, f64)> = Vec::new();
        for (t, (c, dd, b)) in per_tet.into_iter().enumerate() {
            let tet = mesh.tets()[t];
            let te = &mesh.tet_edges()[t];
            for i in 0..4 {
                k0.diag[tet[i] as usize] += b[i][i];
            }
            for (k, [i, j]) in TET_EDGE_LOCAL.iter().enumerate() {
                // Block (tet[i], tet[j]); stored as (low, high).
                let m = if tet[*i] < tet[*j] { b[*i][*j] } else { b[*j][*i] };
                k0.off[te[k] as usize] += m;
            }
            c_trip.extend(c);
            d_trip.extend(dd);
        }
        c_trip.par_sort_unstable_by_key(|&(p, k, _)| ((p as u64) << 32) | k as u64);
        d_trip.par_sort_unstable_by_key(|&(p, q, _)| ((p as u64) << 32) | q as u64);
        let (c_ptr, c_col, c_val) = merge_csr(np, &c_trip, |a, b| a + b, Vec3::zeros());
        drop(c_trip);
        let (d_ptr, d_col, d_val) = merge_csr(np, &d_trip, |a, b| a + b, 0.0);
        drop(d_trip);

        let edge_of = |a: u32, b: u32| {
            if a == b {
                NONE
            } else {
                mesh.edge_index(a, b).unwrap_or(NONE)
            }
        };
        let c_edge: Vec<[u32; 2]> = (0..np)
            .into_par_iter()
            .flat_map_iter(|p| {
                let [a, b] = pair_nodes(n, &edges, p);
                let (s, e) = (c_ptr[p] as usize, c_ptr[p + 1] as usize);
                c_col[s..e]
                    .iter()
                    .map(move |&t| [edge_of(a, t), edge_of(b, t)])
                    .collect::<Vec<_>>()
            })
            .collect();
        let slot_in_row = |p: usize, t: u32| -> u32 {
            let (s, e) = (c_ptr[p] as usize, c_ptr[p + 1] as usize);
            match c_col[s..e].binary_search(&t) {
                Ok(i) => (s + i) as u32,
                Err(_) => NONE,
            }
        };
        let d_slot: Vec<[u32; 2]> = (0..np)
            .into_par_iter()
            .flat_map_iter(|p| {
                let (s, e) = (d_ptr[p] as usize, d_ptr[p + 1] as usize);
                d_col[s..e]
                    .iter()
                    .map(|&q| {
                        let [a, b] = pair_nodes(n, &edges, q as usize);
                        [slot_in_row(p, a), if a == b { NONE } else { slot_in_row(p, b) }]
                    })
                    .collect::<Vec<_>>()
            })
            .collect();

        // Transpose of 𝒞 (rows = vertices) for the gather g = 𝒞ᵀ s.
        let mut ct_ptr = vec![0u32; n + 1];
        for &k in &c_col {
            ct_ptr[k as usize + 1] += 1;
        }
        for i in 0..n {
            ct_ptr[i + 1] += ct_ptr[i];
        }
        let mut fill = ct_ptr.clone();
        let mut ct_pair = vec![0u32; c_col.len()];
        let mut ct_val = vec![Vec3::zeros(); c_col.len()];
        for p in 0..np {
            for s in c_ptr[p] as usize..c_ptr[p + 1] as usize {
                let k = c_col[s] as usize;
                let at = fill[k] as usize;
                ct_pair[at] = p as u32;
                ct_val[at] = c_val[s];
                fill[k] += 1;
            }
        }

        // Tangent assembly: each 𝒞 slot scatters into blocks of both its
        // nodes, so the pairs are split into one contiguous range per thread
        // (balanced on 𝒞 slots), each summed into its own block buffers.
        let parts = rayon::current_num_threads().clamp(1, 16);
        let total = c_val.len();
        let bounds: Vec<usize> = (0..=parts)
            .map(|c| {
                if c == parts {
                    np
                } else {
                    let goal = (total * c / parts) as u32;
                    c_ptr[..np].partition_point(|&x| x < goal)
                }
            })
            .collect();
        let longest_row = (0..np).map(|p| (c_ptr[p + 1] - c_ptr[p]) as usize).max().unwrap_or(0);
        let scratch = NvtmmScratch {
            s: vec![0.0; np],
            w: vec![0.0; np],
            ds: vec![0.0; np],
            dw: vec![0.0; np],
            grad: vec![Vec3::zeros(); n],
            h: vec![[Vec3::zeros(); 2]; np],
            parts: bounds
                .windows(2)
                .map(|b| AssemblyPart {
                    pairs: b[0]..b[1],
                    diag: vec![Mat3::zeros(); n],
                    off: vec![Mat3::zeros(); edges.len()],
                    z: vec![Vec3::zeros(); longest_row],
                })
                .collect(),
        };

        Nvtmm {
            n,
            edges,
            k0,
            c_ptr,
            c_col,
            c_val,
            c_edge,
            ct_ptr,
            ct_pair,
            ct_val,
            d_ptr,
            d_col,
            d_val,
            d_slot,
            scratch: Scratch::new(scratch),
        }
    }

    /// The linear part K₀ (per-vertex and per-edge tensors).
    pub fn linear_tensors(&self) -> &BlockTangent {
        &self.k0
    }

    /// Number of stored tensor coefficients: (K₀ blocks, 𝒞 vectors, 𝔇 scalars).
    pub fn tensor_counts(&self) -> (usize, usize, usize) {
        (
            self.k0.diag.len() + self.k0.off.len(),
            self.c_val.len(),
            self.d_val.len(),
        )
    }

    /// Bytes held by the precomputed tensors (the memory cost the paper notes).
    pub fn tensor_bytes(&self) -> usize {
        use std::mem::size_of;
        (self.k0.diag.len() + self.k0.off.len()) * size_of::<Mat3>()
            + self.c_val.len() * (size_of::<Vec3>() * 2 + 4 + 8)
            + self.d_val.len() * (8 + 4 + 8)
            + (self.c_ptr.len() + self.d_ptr.len() + self.ct_ptr.len()) * 4
    }

    fn pair_members(&self, p: usize) -> [u32; 2] {
        pair_nodes(self.n, &self.edges, p)
    }

    /// s_P = U_a·U_b for every pair.
    fn pair_products(&self, u: &[Vec3], s: &mut [f64]) {
        s[..self.n]
            .par_iter_mut()
            .zip(u)
            .for_each(|(s, u)| *s = u.norm_squared());
        s[self.n..]
            .par_iter_mut()
            .zip(&self.edges)
            .for_each(|(s, &[a, b])| *s = u[a as usize].dot(&u[b as usize]));
    }

    /// δs_P = U_a·δU_b + δU_a·U_b.
    fn pair_products_d(&self, u: &[Vec3], du: &[Vec3], ds: &mut [f64]) {
        ds[..self.n]
            .par_iter_mut()
            .enumerate()
            .for_each(|(i, s)| *s = 2.0 * u[i].dot(&du[i]));
        ds[self.n..].par_iter_mut().zip(&self.edges).for_each(|(s, &[a, b])| {
            let (a, b) = (a as usize, b as usize);
            *s = u[a].dot(&du[b]) + du[a].dot(&u[b]);
        });
    }

    /// w = 𝒞u + 2𝔇s, per pair.
    fn pair_weights(&self, u: &[Vec3], s: &[f64], w: &mut [f64]) {
        w.par_iter_mut().enumerate().for_each(|(p, w)| {
            let (cs, ce) = (self.c_ptr[p] as usize, self.c_ptr[p + 1] as usize);
            let (ds, de) = (self.d_ptr[p] as usize, self.d_ptr[p + 1] as usize);
            *w = dot3_gather(&self.c_val[cs..ce], &self.c_col[cs..ce], u)
                + 2.0 * dot_gather(&self.d_val[ds..de], &self.d_col[ds..de], s);
        });
    }

    /// grad_r = (K₀u)_r + (𝒞ᵀs)_r + Σ_{P∋r} w_P h_{P,r}, for given s and w
    /// (also used with δ-quantities by linearity, see `add_df`).
    fn gradient_from(&self, u: &[Vec3], s: &[f64], w: &[f64], grad: &mut [Vec3]) {
        grad.par_iter_mut().enumerate().for_each(|(r, g)| {
            let (a, b) = (self.ct_ptr[r] as usize, self.ct_ptr[r + 1] as usize);
            *g = axpy3_gather(&self.ct_val[a..b], &self.ct_pair[a..b], s) + u[r] * (2.0 * w[r]);
        });
        // Edge terms and K₀u: scatter (cheap, sequential).
        self.k0.mul_add(u, grad);
        for (e, &[a, b]) in self.edges.iter().enumerate() {
            let we = w[self.n + e];
            let (a, b) = (a as usize, b as usize);
            grad[a] += u[b] * we;
            grad[b] += u[a] * we;
        }
    }
}

// The sparse rows below are short (≈ 20 entries); one accumulator would make
// each product wait for the previous one (a 4-cycle FMA latency chain), so
// they keep four independent partial sums. The summation order is fixed, so
// results stay deterministic.

/// Σ_i v_i x[c_i].
#[inline]
fn dot_gather(v: &[f64], c: &[u32], x: &[f64]) -> f64 {
    let mut a = [0.0f64; 4];
    let (vc, cc) = (v.chunks_exact(4), c.chunks_exact(4));
    let (vr, cr) = (vc.remainder(), cc.remainder());
    for (v, c) in vc.zip(cc) {
        for k in 0..4 {
            a[k] += v[k] * x[c[k] as usize];
        }
    }
    let mut r = (a[0] + a[1]) + (a[2] + a[3]);
    for (v, c) in vr.iter().zip(cr) {
        r += v * x[*c as usize];
    }
    r
}

/// Σ_i v_i · x[c_i] (3-vectors).
#[inline]
fn dot3_gather(v: &[Vec3], c: &[u32], x: &[Vec3]) -> f64 {
    let mut a = [0.0f64; 4];
    let (vc, cc) = (v.chunks_exact(4), c.chunks_exact(4));
    let (vr, cr) = (vc.remainder(), cc.remainder());
    for (v, c) in vc.zip(cc) {
        for k in 0..4 {
            a[k] += v[k].dot(&x[c[k] as usize]);
        }
    }
    let mut r = (a[0] + a[1]) + (a[2] + a[3]);
    for (v, c) in vr.iter().zip(cr) {
        r += v.dot(&x[*c as usize]);
    }
    r
}

/// Σ_i v_i x[c_i] (3-vectors scaled by scalars).
#[inline]
fn axpy3_gather(v: &[Vec3], c: &[u32], x: &[f64]) -> Vec3 {
    let mut a = [Vec3::zeros(); 2];
    let (vc, cc) = (v.chunks_exact(2), c.chunks_exact(2));
    let (vr, cr) = (vc.remainder(), cc.remainder());
    for (v, c) in vc.zip(cc) {
        a[0] += v[0] * x[c[0] as usize];
        a[1] += v[1] * x[c[1] as usize];
    }
    let mut r = a[0] + a[1];
    for (v, c) in vr.iter().zip(cr) {
        r += v * x[*c as usize];
    }
    r
}

/// Merges sorted (row, col, value) triplets into CSR, summing duplicates.
fn merge_csr<T: Copy>(
    rows: usize,
    trip: &[(u32, u32, T)],
    add: impl Fn(T, T) -> T,
    zero: T,
) -> (Vec<u32>, Vec<u32>, Vec<T>) {
    let mut ptr = vec![0u32; rows + 1];
    let mut col: Vec<u32> = Vec::with_capacity(trip.len() / 2);
    let mut val: Vec<T> = Vec::with_capacity(trip.len() / 2);
    let mut last: Option<(u32, u32)> = None;
    for &(r, c, v) in trip {
        if last == Some((r, c)) {
            if let Some(x) = val.last_mut() {
                *x = add(*x, v);
            }
        } else {
            col.push(c);
            val.push(add(zero, v));
            ptr[r as usize + 1] += 1;
            last = Some((r, c));
        }
    }
    for i in 0..rows {
        ptr[i + 1] += ptr[i];
    }
    (ptr, col, val)
}

impl ForceModel for Nvtmm {
    fn name(&self) -> &'static str {
        "nvtmm"
    }

    fn add_forces(&self, u: &[Vec3], out: &mut [Vec3]) {
        self.scratch.with(|sc| {
            self.pair_products(u, &mut sc.s);
            self.pair_weights(u, &sc.s, &mut sc.w);
            self.gradient_from(u, &sc.s, &sc.w, &mut sc.grad);
            out.par_iter_mut().zip(&sc.grad).for_each(|(o, g)| *o -= g);
        });
    }

    fn add_df(&self, u: &[Vec3], du: &[Vec3], out: &mut [Vec3]) {
        self.scratch.with(|sc| {
            let NvtmmScratch {
                s,
                w,
                ds,
                dw,
                grad: dgrad,
                ..
            } = sc;
            self.pair_products(u, s);
            self.pair_weights(u, s, w);
            self.pair_products_d(u, du, ds);
            self.pair_weights(du, ds, dw);
            // δgrad = K₀δu + 𝒞ᵀδs + Σ (δw_P h_P + w_P δh_P). The two h-terms are
            // `gradient_from` with (u, δw) and (δu, w), minus the K₀ and 𝒞ᵀ parts
            // counted twice; assemble directly instead.
            dgrad.par_iter_mut().enumerate().for_each(|(r, g)| {
                let (a, b) = (self.ct_ptr[r] as usize, self.ct_ptr[r + 1] as usize);
                *g = axpy3_gather(&self.ct_val[a..b], &self.ct_pair[a..b], ds)
                    + u[r] * (2.0 * dw[r])
                    + du[r] * (2.0 * w[r]);
            });
            self.k0.mul_add(du, dgrad);
            for (e, &[a, b]) in self.edges.iter().enumerate() {
                let (we, dwe) = (w[self.n + e], dw[self.n + e]);
                let (a, b) = (a as usize, b as usize);
                dgrad[a] += u[b] * dwe + du[b] * we;
                dgrad[b] += u[a] * dwe + du[a] * we;
            }
            out.par_iter_mut().zip(&*dgrad).for_each(|(o, g)| *o -= g);
        });
    }

    fn add_stiffness(&self, u: &[Vec3], kt: &mut BlockTangent) {
        self.scratch.with(|sc| {
            let NvtmmScratch { s, w, h, parts, .. } = sc;
            self.pair_products(u, s);
            self.pair_weights(u, s, w);
            // h_{P,r} once per pair (not once per 𝔇 entry that reads it).
            h.par_iter_mut().enumerate().for_each(|(p, hp)| {
                let [a, b] = self.pair_members(p);
                *hp = if a == b {
                    [u[a as usize] * 2.0, Vec3::zeros()]
                } else {
                    [u[b as usize], u[a as usize]]
                };
            });
            let h = &*h;
            parts.par_iter_mut().for_each(|part| self.assemble_part(h, part));
            // Plus K₀ and w_P ∂h_{P,r}/∂U_t: 2w I on vertices, w I on edges.
            let (parts, w) = (&*parts, &*w);
            kt.diag.par_iter_mut().enumerate().for_each(|(i, d)| {
                let mut acc = self.k0.diag[i] + Mat3::identity() * (2.0 * w[i]);
                for part in parts {
                    acc += part.diag[i];
                }
                *d += acc;
            });
            kt.off.par_iter_mut().enumerate().for_each(|(e, o)| {
                let mut acc = self.k0.off[e] + Mat3::identity() * w[self.n + e];
                for part in parts {
                    acc += part.off[e];
                }
                *o += acc;
            });
        });
    }

    fn energy(&self, u: &[Vec3]) -> f64 {
        self.scratch.with(|sc| {
            let np = self.n + self.edges.len();
            let (s, k0u) = (&mut sc.s, &mut sc.grad);
            self.pair_products(u, s);
            k0u.iter_mut().for_each(|v| *v = Vec3::zeros());
            self.k0.mul_add(u, k0u);
            let quad: f64 = 0.5 * u.iter().zip(k0u.iter()).map(|(a, b)| a.dot(b)).sum::<f64>();
            let s = &*s;
            let rest: f64 = (0..np)
                .into_par_iter()
                .map(|p| {
                    let mut c = 0.0;
                    for i in self.c_ptr[p] as usize..self.c_ptr[p + 1] as usize {
                        c += self.c_val[i].dot(&u[self.c_col[i] as usize]);
                    }
                    let mut l = 0.0;
                    for i in self.d_ptr[p] as usize..self.d_ptr[p + 1] as usize {
                        l += self.d_val[i] * s[self.d_col[i] as usize];
                    }
                    s[p] * (c + l)
                })
                .sum();
            quad + rest
        })
    }
}

impl Nvtmm {
    /// One part of the tangent: for each pair P of `part`, the row z_P·
    /// (eq. 8) and then the blocks h_{P,r} ⊗ (𝒞_Pt + 2 z_Pt) and
    /// 𝒞_Pt ⊗ h_{P,r}, summed into the part's own buffers.
    fn assemble_part(&self, h: &[[Vec3; 2]], part: &mut AssemblyPart) {
        let AssemblyPart { pairs, diag, off, z } = part;
        diag.iter_mut().for_each(|b| *b = Mat3::zeros());
        off.iter_mut().for_each(|b| *b = Mat3::zeros());
        let mut add = |x: u32, y: u32, e: u32, m: Mat3| {
            if x == y {
                diag[x as usize] += m;
            } else if x < y && e != NONE {
                off[e as usize] += m;
            }
        };
        for p in pairs.clone() {
            let (base, end) = (self.c_ptr[p] as usize, self.c_ptr[p + 1] as usize);
            // z_Pt = Σ_Q 𝔇_PQ h_{Q,t}, on row P of the 𝒞 pattern.
            let z = &mut z[..end - base];
            z.iter_mut().for_each(|v| *v = Vec3::zeros());
            for i in self.d_ptr[p] as usize..self.d_ptr[p + 1] as usize {
                let (hq, dv) = (&h[self.d_col[i] as usize], self.d_val[i]);
                let [s0, s1] = self.d_slot[i];
                if s0 != NONE {
                    z[s0 as usize - base] += hq[0] * dv;
                }
                if s1 != NONE {
                    z[s1 as usize - base] += hq[1] * dv;
                }
            }
            let [a, b] = self.pair_members(p);
            let members = if a == b { 1 } else { 2 };
            for (slot, &zt) in (base..end).zip(z.iter()) {
                let t = self.c_col[slot];
                let cpt = self.c_val[slot];
                let row = cpt + zt * 2.0;
                for (m, &r) in [a, b].iter().enumerate().take(members) {
                    let hr = h[p][m];
                    let e = self.c_edge[slot][m];
                    // (r, t): h_{P,r} ⊗ (𝒞_Pt + 2 z_Pt); (t, r): 𝒞_Pt ⊗ h_{P,r}.
                    add(r, t, e, hr * row.transpose());
                    add(t, r, e, cpt * hr.transpose());
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::material::{energy_density, pk1, Law};
    use crate::mesh::arch::{generate, ArchParams};

    fn lcg(seed: &mut u64) -> f64 {
        *seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((*seed >> 11) as f64 / (1u64 << 53) as f64) - 0.5
    }

    fn element_stvk(mesh: &TetMesh, mat: &Material, u: &[Vec3]) -> (Vec<Vec3>, f64) {
        let l = mat.lame();
        let mut f = vec![Vec3::zeros(); mesh.num_nodes()];
        let mut w = 0.0;
        for (t, tet) in mesh.tets().iter().enumerate() {
            let g = &mesh.grads()[t];
            let mut fm = Mat3::identity();
            for k in 0..4 {
                fm += u[tet[k] as usize] * g[k].transpose();
            }
            let p = pk1(Law::Stvk, l, &fm);
            for k in 0..4 {
                f[tet[k] as usize] -= p * g[k] * mesh.volumes()[t];
            }
            w += mesh.volumes()[t] * energy_density(Law::Stvk, l, &fm);
        }
        (f, w)
    }

    fn setup() -> (TetMesh, Material, Vec<Vec3>) {
        let mesh = generate(&ArchParams::default(), 300).unwrap().mesh;
        let mat = Material {
            youngs_pa: 1e5,
            poisson: 0.45,
            density: 1000.0,
        };
        let mut seed = 7;
        // Smooth large displacement plus noise: strains of tens of percent.
        let u = mesh
            .rest()
            .iter()
            .map(|x| {
                Vec3::new(0.3 * x.z, -0.2 * x.x, 0.25 * x.y)
                    + Vec3::new(lcg(&mut seed), lcg(&mut seed), lcg(&mut seed)) * 2e-3
            })
            .collect();
        (mesh, mat, u)
    }

    fn rel(a: &[Vec3], b: &[Vec3]) -> f64 {
        let num: f64 = a.iter().zip(b).map(|(x, y)| (x - y).norm_squared()).sum::<f64>().sqrt();
        let den: f64 = b.iter().map(|y| y.norm_squared()).sum::<f64>().sqrt();
        num / den
    }

    #[test]
    fn force_and_energy_equal_element_stvk() {
        let (mesh, mat, u) = setup();
        let m = Nvtmm::new(&mesh, &mat);
        let mut f = vec![Vec3::zeros(); mesh.num_nodes()];
        m.add_forces(&u, &mut f);
        let (fe, we) = element_stvk(&mesh, &mat, &u);
        assert!(rel(&f, &fe) < 1e-10, "force rel err {}", rel(&f, &fe));
        assert!(
            (m.energy(&u) - we).abs() < 1e-10 * we.abs(),
            "{} vs {}",
            m.energy(&u),
            we
        );
    }

    #[test]
    fn df_and_stiffness_are_force_derivatives() {
        let (mesh, mat, u) = setup();
        let m = Nvtmm::new(&mesh, &mat);
        let mut seed = 3;
        let du: Vec<Vec3> = (0..mesh.num_nodes())
            .map(|_| Vec3::new(lcg(&mut seed), lcg(&mut seed), lcg(&mut seed)))
            .collect();
        let h = 1e-7;
        let up: Vec<Vec3> = u.iter().zip(&du).map(|(a, b)| a + b * h).collect();
        let um: Vec<Vec3> = u.iter().zip(&du).map(|(a, b)| a - b * h).collect();
        let (mut fp, mut fm) = (
            vec![Vec3::zeros(); mesh.num_nodes()],
            vec![Vec3::zeros(); mesh.num_nodes()],
        );
        m.add_forces(&up, &mut fp);
        m.add_forces(&um, &mut fm);
        let fd: Vec<Vec3> = fp.iter().zip(&fm).map(|(a, b)| (a - b) / (2.0 * h)).collect();
        let mut df = vec![Vec3::zeros(); mesh.num_nodes()];
        m.add_df(&u, &du, &mut df);
        assert!(rel(&df, &fd) < 1e-6, "df vs fd {}", rel(&df, &fd));
        let mut k = BlockTangent::zeros(&mesh);
        m.add_stiffness(&u, &mut k);
        let mut kdu = vec![Vec3::zeros(); mesh.num_nodes()];
        k.mul(&du, &mut kdu);
        let neg: Vec<Vec3> = kdu.iter().map(|v| -v).collect();
        assert!(rel(&neg, &df) < 1e-10, "K du vs -df {}", rel(&neg, &df));
    }
}
