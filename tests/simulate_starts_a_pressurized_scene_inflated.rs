//! `nvtmm simulate` starts a pressurized scene from the wall inflated to
//! its mean pressure, by the same `Scene::inflate` the service starts
//! from (docs/PRESSURE.md, "Pressure in the service"), not from rest with
//! the pressure ramped in: after two steps of 10 ms the wall is where the
//! static inflation puts it. Started from rest with a ramp, it would have
//! moved by a small fraction of that. The unbranched arch at 1458 nodes,
//! NVTMM, the living wall's 0.7 MPa, 12.4 kPa.

use nvtmm::scene::Scene;
use std::path::Path;

const SCENE: &str = r#"
model = "nvtmm"
duration = 0.02

[mesh]
arch_nodes = 1458

[material]
law = "stvk"
youngs_pa = 0.7e6
poisson = 0.45
density = 1050.0

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

#[test]
fn simulate_starts_a_pressurized_scene_from_the_inflated_wall() {
    let scene = Scene::parse(SCENE, Path::new("simulate_inflated_test.toml"), Path::new(".")).expect("scene");
    // The static inflation on its own, as the service computes it.
    let mut built = scene.build().expect("build");
    let mut load = built.loads.pressure.take().expect("pressure");
    let inflated = scene
        .inflate(&mut built, &mut load, scene.integrator.dt)
        .expect("inflation");
    assert!(inflated.max_u_m > 1e-3, "the wall inflates by {} m", inflated.max_u_m);

    let out = std::env::temp_dir().join(format!("nvtmm-simulate-inflated-{}", std::process::id()));
    let summary = nvtmm::simulate::run(&scene, &out, &nvtmm::observe::Observe::none()).expect("simulate");
    let _ = std::fs::remove_dir_all(&out);
    println!(
        "static inflation {:.3} mm; simulate after {} steps: {:.3} mm",
        inflated.max_u_m * 1e3,
        summary.steps,
        summary.max_displacement_m * 1e3
    );
    assert_eq!(summary.steps, 2);
    let ratio = summary.max_displacement_m / inflated.max_u_m;
    assert!(
        (ratio - 1.0).abs() <= 0.01,
        "simulate's wall after two steps is {ratio:.4} of the static inflation"
    );
}
