//! The reduced model's Prony terms on a real basis (a clamped bar, 12 modes):
//! under a held tip load the reduced displacement creeps as the analytic
//! standard linear solid, u(t)/u_el = 1/(1−α) − α/(1−α) e^{−t(1−α)/τ}, the
//! same curve the full model follows (tests/prony_matches_analytic_creep.rs).

use nvtmm::material::{Material, PronyTerm};
use nvtmm::math::Vec3;
use nvtmm::mesh::block::block;
use nvtmm::model::tmm::Tmm;
use nvtmm::reduced::{DynamicsParams, ModalBasis, ReducedDynamics};

#[test]
fn reduced_prony_creep_matches_the_standard_linear_solid() {
    let mesh = block([6, 2, 2], [0.06, 0.01, 0.01]).unwrap();
    let mat = Material {
        youngs_pa: 5e6, // stiff: the damped modes settle fast next to τ (quasi-static creep)
        poisson: 0.3,
        density: 1000.0,
    };
    let model = Tmm::new(&mesh, &mat);
    let mass = mesh.lumped_mass(mat.density);
    let fixed = mesh.node_set("x_min").unwrap().to_vec();
    let tip = mesh.node_set("x_max").unwrap().to_vec();
    let u0 = vec![Vec3::zeros(); mesh.num_nodes()];
    let basis = ModalBasis::compute(&nvtmm::reduced::BasisSpec {
        stiffness: nvtmm::reduced::Stiffness::Model {
            mesh: &mesh,
            model: &model,
            u: &u0,
        },
        mass: &mass,
        fixed: &fixed,
        r: 12,
        statics: nvtmm::reduced::Statics::None,
        warm: None,
        params: nvtmm::reduced::BasisParams::default(),
    })
    .unwrap();
    let w1 = basis.omega2[0].sqrt();
    let params = DynamicsParams {
        dt: 1e-3,
        alpha: 2.0 * w1,
        beta: 1e-3,
    };
    let (alpha, tau) = (0.4, 1.0);
    let mut d = Box::new(ReducedDynamics::<16>::new(&basis, &params).unwrap());
    d.set_prony(&[PronyTerm { alpha, tau }]).unwrap();
    let loads: Vec<(u32, Vec3)> = tip
        .iter()
        .map(|&i| (i, Vec3::new(0.0, 0.0, -1e-4 / tip.len() as f64)))
        .collect();
    let f = d.project_nodal(&loads).unwrap();
    let q_el = d.static_solve(&f).unwrap();
    let node = tip[0];
    let mut probe = d.clone();
    probe.set_state(&q_el, &nalgebra::SVector::zeros());
    let u_el = probe.displacement_at(node).unwrap().z;
    assert!(u_el < 0.0);
    let tau_c = tau / (1.0 - alpha);
    let mut worst: f64 = 0.0;
    let steps = (5.0 * tau_c / params.dt) as usize;
    for n in 1..=steps {
        d.step(&f);
        let t = n as f64 * params.dt;
        if t > 0.5 && n % 50 == 0 {
            let got = d.displacement_at(node).unwrap().z / u_el;
            let want = 1.0 / (1.0 - alpha) - alpha / (1.0 - alpha) * (-t / tau_c).exp();
            worst = worst.max((got - want).abs() / want);
        }
    }
    assert!(worst < 0.01, "reduced creep error {worst}");
}
