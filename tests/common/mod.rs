//! Small meshes and force models the solver tests share (the real models are
//! built elsewhere; these are simple enough to trust by inspection).
#![allow(dead_code)]

use nvtmm::mesh::{TetMesh, Vec3};
use nvtmm::model::{BlockTangent, ForceModel, Mat3};
use std::collections::BTreeMap;

/// An nx×ny×nz block of cubes of side `h` (m), each cut into 6 tets (Kuhn).
/// Node sets: `x0` (nodes at x = 0), `x1` (nodes at x = max).
pub fn block(nx: usize, ny: usize, nz: usize, h: f64) -> TetMesh {
    let id = |i: usize, j: usize, k: usize| (i + (nx + 1) * (j + (ny + 1) * k)) as u32;
    let mut rest = Vec::new();
    for k in 0..=nz {
        for j in 0..=ny {
            for i in 0..=nx {
                rest.push(Vec3::new(i as f64 * h, j as f64 * h, k as f64 * h));
            }
        }
    }
    let mut tets = Vec::new();
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let c = |d: usize| id(i + (d & 1), j + ((d >> 1) & 1), k + ((d >> 2) & 1));
                // Kuhn: the 6 paths from corner 0 to corner 7.
                for perm in [[1, 2, 4], [1, 4, 2], [2, 1, 4], [2, 4, 1], [4, 1, 2], [4, 2, 1]] {
                    let a = perm[0];
                    let b = a | perm[1];
                    tets.push([c(0), c(a), c(b), c(7)]);
                }
            }
        }
    }
    let mut sets = BTreeMap::new();
    sets.insert(
        "x0".to_string(),
        (0..rest.len() as u32).filter(|&n| rest[n as usize].x == 0.0).collect(),
    );
    let xmax = nx as f64 * h;
    sets.insert(
        "x1".to_string(),
        (0..rest.len() as u32)
            .filter(|&n| (rest[n as usize].x - xmax).abs() < 1e-12)
            .collect(),
    );
    TetMesh::new(rest, tets, sets).expect("valid block mesh")
}

/// Springs on the mesh edges acting on displacement differences d = u_j − u_i
/// with energy W = ½ k |d|² + ¼ c |d|⁴ per edge: linear for c = 0, smooth and
/// convex (SPD tangent once something is fixed) for c > 0, indefinite for
/// k < 0. Not rotation invariant; it does not need to be for these tests.
#[derive(Debug, Clone)]
pub struct Springs {
    pub edges: Vec<[u32; 2]>,
    pub k: f64,
    pub c: f64,
    /// Number of `end_step` calls seen.
    pub end_steps: usize,
    /// Number of `begin_step` calls seen.
    pub begin_steps: usize,
}

impl Springs {
    pub fn new(mesh: &TetMesh, k: f64, c: f64) -> Springs {
        Springs {
            edges: mesh.edges().to_vec(),
            k,
            c,
            end_steps: 0,
            begin_steps: 0,
        }
    }
    fn g(&self, d: &Vec3) -> Vec3 {
        d * (self.k + self.c * d.norm_squared())
    }
    fn hess(&self, d: &Vec3) -> Mat3 {
        Mat3::identity() * (self.k + self.c * d.norm_squared()) + d * d.transpose() * (2.0 * self.c)
    }
}

impl ForceModel for Springs {
    fn name(&self) -> &'static str {
        "test-springs"
    }
    fn add_forces(&self, u: &[Vec3], out: &mut [Vec3]) {
        for &[i, j] in &self.edges {
            let (i, j) = (i as usize, j as usize);
            let g = self.g(&(u[j] - u[i]));
            out[i] += g;
            out[j] -= g;
        }
    }
    fn add_df(&self, u: &[Vec3], du: &[Vec3], out: &mut [Vec3]) {
        for &[i, j] in &self.edges {
            let (i, j) = (i as usize, j as usize);
            let hd = self.hess(&(u[j] - u[i])) * (du[j] - du[i]);
            out[i] += hd;
            out[j] -= hd;
        }
    }
    fn add_stiffness(&self, u: &[Vec3], k: &mut BlockTangent) {
        for (e, &[i, j]) in self.edges.iter().enumerate() {
            let hm = self.hess(&(u[j as usize] - u[i as usize]));
            k.diag[i as usize] += hm;
            k.diag[j as usize] += hm;
            k.off[e] -= hm;
        }
    }
    fn energy(&self, u: &[Vec3]) -> f64 {
        self.edges
            .iter()
            .map(|&[i, j]| {
                let d2 = (u[j as usize] - u[i as usize]).norm_squared();
                0.5 * self.k * d2 + 0.25 * self.c * d2 * d2
            })
            .sum()
    }
    fn begin_step(&mut self, _dt: f64) {
        self.begin_steps += 1;
    }
    fn end_step(&mut self, _u: &[Vec3]) {
        self.end_steps += 1;
    }
}

/// Wraps a model and returns NaN forces from the `nan_after`-th force
/// evaluation on (counting from 0).
pub struct NanAfter<M> {
    pub inner: M,
    pub nan_after: usize,
    pub calls: std::sync::atomic::AtomicUsize,
}

impl<M: ForceModel> ForceModel for NanAfter<M> {
    fn name(&self) -> &'static str {
        "nan-after"
    }
    fn add_forces(&self, u: &[Vec3], out: &mut [Vec3]) {
        let c = self.calls.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        self.inner.add_forces(u, out);
        if c >= self.nan_after {
            out[out.len() / 2].x = f64::NAN;
        }
    }
    fn add_df(&self, u: &[Vec3], du: &[Vec3], out: &mut [Vec3]) {
        self.inner.add_df(u, du, out)
    }
    fn add_stiffness(&self, u: &[Vec3], k: &mut BlockTangent) {
        self.inner.add_stiffness(u, k)
    }
    fn energy(&self, u: &[Vec3]) -> f64 {
        self.inner.energy(u)
    }
    fn end_step(&mut self, u: &[Vec3]) {
        self.inner.end_step(u)
    }
}

/// A deterministic pseudo-random field in [-1, 1]³ per node (no rand crate).
pub fn pseudo_random(n: usize, seed: u64) -> Vec<Vec3> {
    let mut s = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
    let mut next = || {
        s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((s >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
    };
    (0..n).map(|_| Vec3::new(next(), next(), next())).collect()
}

/// Bitwise copy of a state's numbers for exact comparison.
pub fn bits(s: &nvtmm::solver::TissueState) -> Vec<u64> {
    s.u.iter()
        .chain(&s.v)
        .flat_map(|v| v.iter().map(|c| c.to_bits()).collect::<Vec<_>>())
        .chain(std::iter::once(s.t.to_bits()))
        .collect()
}
