//! Prony viscoelasticity (paper section III) against the analytic
//! standard-linear-solid curves at small strain, and its invariance under
//! rigid rotation.
//!
//! Because the history acts on the whole stress, the viscoelastic response of
//! any body at small strain is the elastic one scaled in time (correspondence
//! principle): a held displacement relaxes the reaction as α(t) (eq. 11), and
//! a held load creeps the displacement as E₀ J(t), with for one term
//! J(t) E₀ = 1/(1−α) − α/(1−α) · exp(−t (1−α)/τ).

use nalgebra::{DMatrix, DVector, Rotation3};
use nvtmm::material::{relaxation, Law, Material, PronyTerm};
use nvtmm::math::Vec3;
use nvtmm::mesh::block::block;
use nvtmm::mesh::TetMesh;
use nvtmm::model::nvtmm::Nvtmm;
use nvtmm::model::viscoelastic::Viscoelastic;
use nvtmm::model::{BlockTangent, ForceModel};

fn bar() -> (TetMesh, Material) {
    let mesh = block([6, 2, 2], [0.06, 0.01, 0.01]).unwrap();
    (
        mesh,
        Material {
            youngs_pa: 50e3,
            poisson: 0.3,
            density: 1000.0,
        },
    )
}

fn x_force_on(mesh: &TetMesh, f: &[Vec3], set: &str) -> f64 {
    mesh.node_set(set).unwrap().iter().map(|&i| f[i as usize].x).sum()
}

#[test]
fn held_strain_relaxes_as_the_prony_series() {
    let (mesh, mat) = bar();
    let terms = [PronyTerm { alpha: 0.4, tau: 0.5 }, PronyTerm { alpha: 0.25, tau: 0.05 }];
    let mut model = Viscoelastic::new(Nvtmm::new(&mesh, &mat), &mesh, &mat, Law::Stvk, &terms);
    let eps = 1e-5;
    let u: Vec<Vec3> = mesh.rest().iter().map(|x| Vec3::new(eps * x.x, 0.0, 0.0)).collect();
    let mut f0 = vec![Vec3::zeros(); mesh.num_nodes()];
    model.elastic().add_forces(&u, &mut f0);
    let reaction0 = x_force_on(&mesh, &f0, "x_max");
    assert!(reaction0 < 0.0);
    let dt = 1.25e-4; // τ_min / 400
    let mut worst: f64 = 0.0;
    let mut t = 0.0;
    for step in 1..=16_000 {
        model.begin_step(dt);
        t += dt;
        let mut f = vec![Vec3::zeros(); mesh.num_nodes()];
        model.add_forces(&u, &mut f);
        model.end_step(&u);
        if step % 200 == 0 {
            let got = x_force_on(&mesh, &f, "x_max") / reaction0;
            let want = relaxation(&terms, t);
            worst = worst.max((got - want).abs() / want);
        }
    }
    assert!(worst < 0.01, "relaxation error {worst}");
}

/// Quasi-static equilibrium f_int(u) + f_ext = 0 with x_min fixed, by
/// Newton-like iterations on a factorised elastic stiffness.
struct Statics {
    free: Vec<usize>,
    lu: nalgebra::LU<f64, nalgebra::Dyn, nalgebra::Dyn>,
}

impl Statics {
    fn new(mesh: &TetMesh, model: &dyn ForceModel, scale: f64) -> Statics {
        let fixed: Vec<u32> = mesh.node_set("x_min").unwrap().to_vec();
        let free: Vec<usize> = (0..mesh.num_nodes())
            .filter(|i| !fixed.contains(&(*i as u32)))
            .flat_map(|i| [3 * i, 3 * i + 1, 3 * i + 2])
            .collect();
        let mut k = BlockTangent::zeros(mesh);
        model.add_stiffness(&vec![Vec3::zeros(); mesh.num_nodes()], &mut k);
        let kd = k.to_dense() * scale;
        let kf = DMatrix::from_fn(free.len(), free.len(), |a, b| kd[(free[a], free[b])]);
        Statics { free, lu: kf.lu() }
    }

    fn solve(&self, model: &dyn ForceModel, ext: &[Vec3], u: &mut [Vec3]) {
        for _ in 0..20 {
            let mut r = ext.to_vec();
            model.add_forces(u, &mut r);
            let rf = DVector::from_iterator(self.free.len(), self.free.iter().map(|&d| r[d / 3][d % 3]));
            let norm = rf.norm();
            let du = self.lu.solve(&rf).unwrap();
            for (a, &d) in self.free.iter().enumerate() {
                u[d / 3][d % 3] += du[a];
            }
            if norm < 1e-13 {
                break;
            }
        }
    }
}

#[test]
fn held_load_creeps_as_the_standard_linear_solid() {
    let (mesh, mat) = bar();
    let (alpha, tau) = (0.5, 0.2);
    let terms = [PronyTerm { alpha, tau }];
    let mut model = Viscoelastic::new(Nvtmm::new(&mesh, &mat), &mesh, &mat, Law::Stvk, &terms);
    let tip = mesh.node_set("x_max").unwrap().to_vec();
    let mut ext = vec![Vec3::zeros(); mesh.num_nodes()];
    for &i in &tip {
        ext[i as usize].x = 1e-4 / tip.len() as f64; // ≈ 1e-5 strain
    }
    let mean_tip = |u: &[Vec3]| tip.iter().map(|&i| u[i as usize].x).sum::<f64>() / tip.len() as f64;
    // Elastic reference displacement.
    let elastic = Statics::new(&mesh, model.elastic(), 1.0);
    let mut u_el = vec![Vec3::zeros(); mesh.num_nodes()];
    elastic.solve(model.elastic(), &ext, &mut u_el);
    let u0 = mean_tip(&u_el);
    assert!(u0 > 0.0);

    let dt = tau / 1000.0;
    model.begin_step(dt);
    let statics = Statics::new(&mesh, &model, 1.0);
    let mut u = vec![Vec3::zeros(); mesh.num_nodes()];
    let tau_c = tau / (1.0 - alpha);
    let mut t = 0.0;
    let mut worst: f64 = 0.0;
    let steps = (6.0 * tau_c / dt) as usize;
    for step in 1..=steps {
        if step > 1 {
            model.begin_step(dt);
        }
        t += dt;
        statics.solve(&model, &ext, &mut u);
        model.end_step(&u);
        if step % 100 == 0 {
            let got = mean_tip(&u) / u0;
            let want = 1.0 / (1.0 - alpha) - alpha / (1.0 - alpha) * (-t / tau_c).exp();
            worst = worst.max((got - want).abs() / want);
        }
    }
    assert!(worst < 0.01, "creep error {worst}");
}

#[test]
fn rigid_rotation_creates_no_viscous_force() {
    let (mesh, mat) = bar();
    let terms = [PronyTerm { alpha: 0.6, tau: 0.01 }];
    let mut model = Viscoelastic::new(Nvtmm::new(&mesh, &mat), &mesh, &mat, Law::Stvk, &terms);
    let dt = 1e-3;
    // Round-off scale: the force of a unit strain on the bar's cross-section.
    let unit = mat.youngs_pa * 0.01 * 0.01;
    // A body spinning rigidly (large angles) builds no history and feels no force.
    for step in 1..=200 {
        let r = Rotation3::from_axis_angle(&Vec3::y_axis(), 0.02 * step as f64);
        let u: Vec<Vec3> = mesh.rest().iter().map(|x| r * x - x).collect();
        model.begin_step(dt);
        let mut f = vec![Vec3::zeros(); mesh.num_nodes()];
        model.add_forces(&u, &mut f);
        let fmax = f.iter().map(|v| v.norm()).fold(0.0, f64::max);
        // Total force: round-off of the quartic polynomial at |∇U| ~ 1.
        assert!(fmax < 1e-10 * unit, "step {step}: force {fmax} N on a rigid rotation");
        // The viscous part (viscoelastic minus scaled elastic) is zero.
        let mut fe = vec![Vec3::zeros(); mesh.num_nodes()];
        model.elastic().add_forces(&u, &mut fe);
        let scale = model.prony().elastic_scale();
        let visc = f
            .iter()
            .zip(&fe)
            .map(|(a, b)| (a - b * scale).norm())
            .fold(0.0, f64::max);
        assert!(
            visc < 1e-14 * unit,
            "step {step}: viscous force {visc} N on a rigid rotation"
        );
        model.end_step(&u);
    }
    // A stretched body with history, then rotated: the force rotates with it
    // (no spurious viscous force from the rotation itself).
    model.reset_history();
    let stretch: Vec<Vec3> = mesh.rest().iter().map(|x| Vec3::new(0.05 * x.x, 0.0, 0.0)).collect();
    for _ in 0..50 {
        model.begin_step(dt);
        model.end_step(&stretch);
    }
    model.begin_step(dt);
    let mut f = vec![Vec3::zeros(); mesh.num_nodes()];
    model.add_forces(&stretch, &mut f);
    let r = Rotation3::from_axis_angle(&Vec3::z_axis(), 1.1);
    let rotated: Vec<Vec3> = mesh.rest().iter().zip(&stretch).map(|(x, u)| r * (x + u) - x).collect();
    let mut fr = vec![Vec3::zeros(); mesh.num_nodes()];
    model.add_forces(&rotated, &mut fr);
    let scale = f.iter().map(|v| v.norm()).fold(0.0, f64::max);
    for (a, b) in f.iter().zip(&fr) {
        assert!((r * a - b).norm() < 1e-9 * scale);
    }
}
