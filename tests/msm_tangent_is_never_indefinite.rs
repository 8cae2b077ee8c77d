//! The mass-spring tangent stays positive semi-definite under strong
//! compression (the compressive transverse stiffness of each spring is
//! dropped, Choi & Ko 2002), so a sparse Cholesky step with MSM at the
//! paper's visual step (1/60 s) does not fail; forces are those of the exact
//! springs, and where no spring is compressed the tangent is the exact one.

mod common;

use common::{block, df, forces, max_diff, max_norm, Rng};
use nvtmm::material::Material;
use nvtmm::math::Vec3;
use nvtmm::mesh::TetMesh;
use nvtmm::model::{msm::Msm, BlockTangent, ForceModel};
use nvtmm::solver::loads::{Loads, NodalLoad, TimeProfile};
use nvtmm::solver::{ImplicitEuler, ImplicitEulerParams, LinearSolverKind, NewtonParams, TissueState};

fn tangent(model: &dyn ForceModel, mesh: &TetMesh, u: &[Vec3]) -> nalgebra::DMatrix<f64> {
    let mut k = BlockTangent::zeros(mesh);
    model.add_stiffness(u, &mut k);
    k.to_dense()
}

/// Smallest and largest eigenvalue of a symmetric matrix.
fn eig_range(k: &nalgebra::DMatrix<f64>) -> (f64, f64) {
    let e = k.clone().symmetric_eigen().eigenvalues;
    (e.min(), e.max())
}

/// Uniform compression by `strain` (negative) about the block's corner, plus noise.
fn compressed(mesh: &TetMesh, strain: f64, noise: f64, seed: u64) -> Vec<Vec3> {
    let mut rng = Rng::new(seed);
    mesh.rest().iter().map(|x| x * strain + rng.vec3() * noise).collect()
}

#[test]
fn compressed_msm_tangent_is_positive_semidefinite() {
    let mesh = block(3, 3, 3, 0.01);
    let m = Material::aorta();
    let (clamped, exact) = (Msm::new(&mesh, &m), Msm::with_exact_tangent(&mesh, &m));
    assert!(!clamped.has_exact_tangent() && exact.has_exact_tangent());
    for (strain, seed) in [(-0.3, 1), (-0.6, 2), (-0.9, 3)] {
        let u = compressed(&mesh, strain, 2e-4, seed);
        let (ke, kc) = (tangent(&exact, &mesh, &u), tangent(&clamped, &mesh, &u));
        // The test can tell: the exact Hessian is indefinite here.
        let (emin, emax) = eig_range(&ke);
        assert!(
            emin < -1e-3 * emax,
            "strain {strain}: exact tangent not indefinite ({emin}, {emax})"
        );
        let (cmin, cmax) = eig_range(&kc);
        assert!(
            cmin >= -1e-12 * cmax,
            "strain {strain}: clamped tangent indefinite: λmin {cmin}, λmax {cmax}"
        );
        // Forces are the exact springs'.
        let (fc, fe) = (forces(&clamped, &u), forces(&exact, &u));
        assert!(max_diff(&fc, &fe) <= 1e-14 * max_norm(&fe));
        // K v = −add_df and add_df is symmetric for the clamped model too.
        let mut rng = Rng::new(seed + 10);
        let (v, w) = (rng.vecs(u.len(), 1.0), rng.vecs(u.len(), 1.0));
        let dfv = df(&clamped, &u, &v);
        let mut k = BlockTangent::zeros(&mesh);
        clamped.add_stiffness(&u, &mut k);
        let mut kv = vec![Vec3::zeros(); u.len()];
        k.mul(&v, &mut kv);
        let minus: Vec<Vec3> = dfv.iter().map(|x| -x).collect();
        assert!(max_diff(&kv, &minus) <= 1e-12 * max_norm(&dfv));
        let dfw = df(&clamped, &u, &w);
        let (a, b) = (common::dot(&w, &dfv), common::dot(&v, &dfw));
        assert!((a - b).abs() <= 1e-12 * a.abs().max(b.abs()));
    }
}

#[test]
fn stretched_msm_tangent_is_exact() {
    let mesh = block(3, 3, 3, 0.01);
    let m = Material::aorta();
    let (clamped, exact) = (Msm::new(&mesh, &m), Msm::with_exact_tangent(&mesh, &m));
    // Uniform stretch: every spring longer than at rest, nothing clamped.
    let u = compressed(&mesh, 0.2, 1e-5, 4);
    let (ke, kc) = (tangent(&exact, &mesh, &u), tangent(&clamped, &mesh, &u));
    assert!((&ke - &kc).amax() <= 1e-12 * ke.amax());
}

#[test]
fn cholesky_step_at_the_visual_rate_survives_strong_compression() {
    let mesh = block(4, 3, 3, 0.01);
    let fixed = mesh.node_set("x_min").unwrap().to_vec();
    let pushed = mesh.node_set("x_max").unwrap().to_vec();
    // A push along −x strong enough to compress the block by tens of percent.
    let loads = Loads {
        nodal: vec![NodalLoad {
            nodes: pushed,
            force: Vec3::new(-2.0, 0.3, 0.0),
            profile: TimeProfile::Constant { from_t0: 0.0 },
        }],
        gravity: Vec3::zeros(),
        pressure: None,
    };
    let params = ImplicitEulerParams {
        dt: 1.0 / 60.0,
        rayleigh_alpha: 1.0,
        rayleigh_beta: 1e-3,
        newton: NewtonParams::default(),
        linear: LinearSolverKind::Cholesky,
        stiffness_every: 1,
        max_halvings: 0,
    };
    let mut model = Msm::new(&mesh, &Material::aorta());
    let mut euler = ImplicitEuler::new(&mesh, mesh.lumped_mass(1100.0), params).unwrap();
    let mut state = TissueState::at_rest(mesh.num_nodes());
    let mut most = 0.0f64;
    for step in 0..30 {
        let report = euler.step(&mut state, &mut model, &loads, &fixed);
        assert!(report.ok(), "step {step} failed: {report:?}");
        most = most.max(state.u.iter().map(|v| -v.x).fold(0.0, f64::max));
    }
    // The block (4 cm long) was really compressed.
    assert!(most > 0.004, "deepest push {most} m");
}
