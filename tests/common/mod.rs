//! Shared helpers for the model integration tests: a structured block mesh,
//! a small deterministic random generator and the four models under test.
#![allow(dead_code)]

use nvtmm::material::{Law, Material};
use nvtmm::mesh::{TetMesh, Vec3};
use nvtmm::model::{fem::Fem, msm::Msm, tmm::Tmm, ForceModel};

/// A block of nx × ny × nz cubes of side `h` (m), Kuhn-subdivided
/// (`mesh::block`).
pub fn block(nx: usize, ny: usize, nz: usize, h: f64) -> TetMesh {
    nvtmm::mesh::block::block([nx, ny, nz], [nx as f64 * h, ny as f64 * h, nz as f64 * h]).expect("block mesh is valid")
}

/// Deterministic generator of uniform numbers in [-0.5, 0.5) (LCG; enough
/// for test data, no extra dependency).
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Rng {
        Rng(seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407))
    }
    pub fn next(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((self.0 >> 11) as f64 / (1u64 << 53) as f64) - 0.5
    }
    pub fn vec3(&mut self) -> Vec3 {
        Vec3::new(self.next(), self.next(), self.next())
    }
    /// `n` random vectors with components in [-amp/2, amp/2).
    pub fn vecs(&mut self, n: usize, amp: f64) -> Vec<Vec3> {
        (0..n).map(|_| self.vec3() * amp).collect()
    }
}

/// Porcine-aorta-like material (E = 65 kPa, ν = 0.45).
pub fn material() -> Material {
    Material::aorta()
}

/// The four models under test, with their names.
pub fn models(mesh: &TetMesh) -> Vec<Box<dyn ForceModel>> {
    let m = material();
    vec![
        Box::new(Fem::new(mesh, &m, Law::Stvk)),
        Box::new(Fem::new(mesh, &m, Law::NeoHookean)),
        Box::new(Tmm::new(mesh, &m)),
        Box::new(Msm::new(mesh, &m)),
    ]
}

pub fn forces(model: &dyn ForceModel, u: &[Vec3]) -> Vec<Vec3> {
    let mut f = vec![Vec3::zeros(); u.len()];
    model.add_forces(u, &mut f);
    f
}

pub fn df(model: &dyn ForceModel, u: &[Vec3], du: &[Vec3]) -> Vec<Vec3> {
    let mut f = vec![Vec3::zeros(); u.len()];
    model.add_df(u, du, &mut f);
    f
}

pub fn max_norm(v: &[Vec3]) -> f64 {
    v.iter().map(|x| x.norm()).fold(0.0, f64::max)
}

pub fn max_diff(a: &[Vec3], b: &[Vec3]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y).norm()).fold(0.0, f64::max)
}

pub fn dot(a: &[Vec3], b: &[Vec3]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x.dot(y)).sum()
}

/// u + s v.
pub fn axpy(u: &[Vec3], s: f64, v: &[Vec3]) -> Vec<Vec3> {
    u.iter().zip(v).map(|(a, b)| a + b * s).collect()
}

/// Mean edge length of a mesh (m).
pub fn mean_edge(mesh: &TetMesh) -> f64 {
    let r = mesh.rest();
    let s: f64 = mesh
        .edges()
        .iter()
        .map(|&[a, b]| (r[b as usize] - r[a as usize]).norm())
        .sum();
    s / mesh.edges().len() as f64
}
