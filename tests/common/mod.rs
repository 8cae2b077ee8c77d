//! Shared helpers for the integration tests: a structured block mesh, a small
//! deterministic random generator, the models under test, and simple spring
//! models the solver tests use (simple enough to trust by inspection).
#![allow(dead_code)]

pub mod chromium;
pub mod counting;
pub mod guidewire;
pub mod service;

use nvtmm::material::{Law, Material};
use nvtmm::math::Mat3;
use nvtmm::math::Vec3;
use nvtmm::mesh::surface::SurfaceMesh;
use nvtmm::mesh::TetMesh;
use nvtmm::model::{fem::Fem, msm::Msm, tmm::Tmm, BlockTangent, ForceModel};

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

/// The four models under test, with their names. MSM keeps its exact
/// Hessian here (the derivative checks need it); its default tangent drops
/// the compressive part (`tests/msm_tangent_is_never_indefinite.rs`).
pub fn models(mesh: &TetMesh) -> Vec<Box<dyn ForceModel>> {
    let m = material();
    vec![
        Box::new(Fem::new(mesh, &m, Law::Stvk)),
        Box::new(Fem::new(mesh, &m, Law::NeoHookean)),
        Box::new(Tmm::new(mesh, &m)),
        Box::new(Msm::with_exact_tangent(mesh, &m)),
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

/// The coaxial tests' bend: a tube of inner `radius` (m) from
/// (−10 mm, 0, 0) along x, 30 mm straight, then turning toward +y by 2 rad
/// on a 30 mm radius, then 200 mm straight.
pub fn two_radian_bend(radius: f64) -> nvtmm::wire::CurvedTube {
    nvtmm::wire::CurvedTube::new(&nvtmm::wire::CurvedTubeShape {
        start: Vec3::new(-0.01, 0.0, 0.0),
        tangent: Vec3::x(),
        toward: Vec3::y(),
        inlet: 0.03,
        bend_radius: 0.03,
        angle: 2.0,
        outlet: 0.2,
        radius,
    })
    .expect("tube")
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
    fn begin_step(&mut self, dt: f64) {
        self.inner.begin_step(dt)
    }
    fn save_state(&mut self) {
        self.inner.save_state()
    }
    fn restore_state(&mut self) {
        self.inner.restore_state()
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

/// A 24 × 24 × 4 mm NVTMM plate (12 × 12 × 2 cells) with the nodes of
/// `fixed_sets` fixed and an r-column basis whose r/2 static modes sit on
/// the top-face nodes within 5 mm of the contact point (0.012, 0.012, 0.004),
/// for the haptic-loop tests.
pub struct ContactPlate {
    pub mesh: TetMesh,
    pub model: nvtmm::model::nvtmm::Nvtmm,
    pub mass: Vec<f64>,
    pub fixed: Vec<u32>,
    pub basis: nvtmm::reduced::ModalBasis,
    pub center: Vec3,
    /// The top-face nodes within 5 mm of the centre (the static modes' region).
    pub contact: Vec<u32>,
}

pub fn contact_plate(mat: &Material, fixed_sets: &[&str], r: usize) -> ContactPlate {
    let mesh = block(12, 12, 2, 2e-3);
    let model = nvtmm::model::nvtmm::Nvtmm::new(&mesh, mat);
    let mass = mesh.lumped_mass(mat.density);
    let mut fixed: Vec<u32> = fixed_sets
        .iter()
        .flat_map(|s| mesh.node_set(s).expect("block node set").to_vec())
        .collect();
    fixed.sort_unstable();
    fixed.dedup();
    let center = Vec3::new(0.012, 0.012, 0.004);
    let contact: Vec<u32> = mesh
        .node_set("z_max")
        .expect("block node set")
        .iter()
        .copied()
        .filter(|&i| (mesh.rest()[i as usize] - center).norm() <= 5e-3)
        .collect();
    let zeros = vec![Vec3::zeros(); mesh.num_nodes()];
    let basis = nvtmm::reduced::ModalBasis::compute(&nvtmm::reduced::BasisSpec {
        stiffness: nvtmm::reduced::Stiffness::Model {
            mesh: &mesh,
            model: &model,
            u: &zeros,
        },
        mass: &mass,
        fixed: &fixed,
        r,
        statics: nvtmm::reduced::Statics::Compressed {
            contact: &contact,
            max_static: r / 2,
        },
        warm: None,
        params: nvtmm::reduced::BasisParams::default(),
    })
    .expect("plate basis");
    ContactPlate {
        mesh,
        model,
        mass,
        fixed,
        basis,
        center,
        contact,
    }
}

/// An open tube along z (in whatever unit), `around` vertices per ring.
pub fn open_tube(r: f64, len: f64, around: usize, rings: usize) -> SurfaceMesh {
    SurfaceMesh::open_tube(r, len, around, rings)
}

/// A servo on the aorta-material [`contact_plate`] (edges `x_min`, `x_max`
/// and `z_min` fixed, r = `R`) whose probe's hand rests 0.3 m above the
/// plate: the sphere never touches it, so only instruments' loads move
/// the vessel. Returns the servo and the plate.
pub fn far_plate_servo<const R: usize>(dt: f64) -> (nvtmm::haptics::servo::Servo<R>, ContactPlate) {
    use nvtmm::haptics::contact::{ContactParams, SurfaceIndex};
    use nvtmm::haptics::servo::{Servo, ServoParams};
    let plate = contact_plate(&Material::aorta(), &["x_min", "x_max", "z_min"], R);
    let zeros = vec![Vec3::zeros(); plate.mesh.num_nodes()];
    let rows = nvtmm::reduced::basis_rows::<R>(&plate.basis).unwrap();
    let k0 =
        nvtmm::reduced::Refresher::new(&plate.mesh, &plate.basis, &plate.mass).reduced_stiffness(&plate.model, &zeros);
    let dynp = nvtmm::reduced::DynamicsParams {
        dt,
        alpha: 5.0,
        beta: 1e-3,
    };
    let first = nvtmm::service::background::rest_model::<R>(rows, &k0, &dynp, plate.mesh.num_nodes()).unwrap();
    let cp = ContactParams {
        tool_radius_m: 3e-3,
        pressure_stiffness: 1e9,
        search_margin_m: 3e-3,
    };
    let index = std::sync::Arc::new(SurfaceIndex::new(&plate.mesh, &cp));
    let sp = ServoParams {
        dt,
        contact: cp,
        device_origin: plate.center + Vec3::new(0.0, 0.0, 0.3),
        device_timeout_s: 5e-3,
        model_timeout_s: f64::INFINITY,
        model_max_age_s: f64::INFINITY,
        max_speed_m_s: 5.0,
        max_reach_m: 0.25,
        overrun_streak: 5,
        ramp_down_s: 10e-3,
        ramp_in_s: 0.0,
        swap_blend_s: 0.02,
        command_timeout_s: nvtmm::haptics::device::DEFAULT_COMMAND_TIMEOUT_S,
    };
    (Servo::new(first, index, sp, 0.0), plate)
}
