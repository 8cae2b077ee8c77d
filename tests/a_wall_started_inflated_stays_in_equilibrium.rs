//! The haptic service starts a pressurized scene from the wall inflated to
//! its mean pressure (`Scene::inflate`, docs/PRESSURE.md "Pressure in the
//! service"): the static equilibrium of the relaxed modulus, with the
//! viscoelastic histories set to their steady state there. The full solve
//! started from that state, with the pressure on, must stay where it is:
//! the wall neither springs back (histories left empty: the instantaneous
//! modulus) nor creeps. The unbranched arch at 1458 nodes, NVTMM with one
//! Prony term, the living wall's 0.7 MPa, 12.4 kPa; a few seconds.

use nvtmm::math::Vec3;
use nvtmm::scene::Scene;
use nvtmm::solver::loads::Loads;
use nvtmm::solver::{ImplicitEuler, TissueState};
use std::path::Path;

const SCENE: &str = r#"
model = "nvtmm"
duration = 1.0

[mesh]
arch_nodes = 1458

[material]
law = "stvk"
youngs_pa = 0.7e6
poisson = 0.45
density = 1050.0

[[prony]]
alpha = 0.5
tau = 0.58

[fixed]
sets = ["inlet", "outlet_descending"]

[integrator]
dt = 1e-2
rayleigh_alpha = 0.0
rayleigh_beta = 1e-3
newton = { max_iters = 3, rel_tol = 1e-8 }
linear = { kind = "cholesky" }

[pressure]
mean_pa = 12.4e3
"#;

/// Largest distance (m) the wall moves from the inflated state over
/// `steps` full steps, with the histories relaxed there or left empty.
fn drift(relaxed: bool, steps: usize) -> (f64, f64) {
    let path = Path::new("inflated_wall_test.toml");
    let scene = Scene::parse(SCENE, path, Path::new(".")).expect("scene");
    let mut built = scene.build().expect("build");
    let mut load = built.loads.pressure.take().expect("pressure");
    let dt = scene.integrator.dt;
    let inflated = scene.inflate(&mut built, &mut load, dt).expect("inflation");
    assert_eq!(load.schedule.ramp_s, 0.0, "the pressure is on from the start");
    if !relaxed {
        built.model.reset_history();
    }
    let n = built.mesh.num_nodes();
    let mass = built.mesh.lumped_mass(scene.material.density);
    let mut solver = ImplicitEuler::new(&built.mesh, mass, scene.integrator).expect("solver");
    let mut state = TissueState::at_rest(n);
    state.u = inflated.u.clone();
    let loads = Loads {
        nodal: Vec::new(),
        gravity: Vec3::zeros(),
        pressure: Some(load),
    };
    let mut most: f64 = 0.0;
    for _ in 0..steps {
        let rep = solver.step(&mut state, built.model.as_mut(), &loads, &built.fixed);
        assert!(rep.ok(), "{rep:?}");
        let d = state
            .u
            .iter()
            .zip(&inflated.u)
            .map(|(a, b)| (a - b).norm())
            .fold(0.0, f64::max);
        most = most.max(d);
    }
    (most, inflated.max_u_m)
}

#[test]
fn a_viscoelastic_wall_started_inflated_to_the_mean_pressure_neither_springs_back_nor_creeps() {
    let (relaxed, inflation) = drift(true, 10);
    let (empty, _) = drift(false, 10);
    println!(
        "inflation {:.3} mm; drift over 10 steps of 10 ms: {:.2e} m with the histories relaxed, {:.2e} m with them empty",
        inflation * 1e3,
        relaxed,
        empty
    );
    assert!(inflation > 1e-3, "the wall inflates by {inflation} m");
    // Relaxed: in equilibrium to the static solve's tolerance.
    assert!(
        relaxed < 1e-3 * inflation,
        "drift {relaxed} m of an inflation of {inflation} m"
    );
    // Empty histories hold the wall at twice its relaxed stiffness: it
    // springs back by a good part of the inflation (the check has teeth).
    assert!(empty > 0.05 * inflation, "drift {empty} m with empty histories");
}
