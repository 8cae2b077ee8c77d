//! Accuracy cost of `integrator.stiffness_every` (tangent refresh interval)
//! on the standard load: the loaded node's displacement over N steps with
//! refresh every k steps against k = 1 (exact linearised step), run side by
//! side. `[HALVINGS=m] cargo run --release --example lag_accuracy -- [model] [nodes] [steps] [linear]`.

use nvtmm::bench::{parse_linear, standard_load, standard_params};
use nvtmm::material::{Law, Material};
use nvtmm::mesh::arch::{generate, ArchParams};
use nvtmm::model::factory::build_model;
use nvtmm::model::ModelKind;
use nvtmm::solver::{ImplicitEuler, ImplicitEulerParams, TissueState};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let kind: ModelKind = args.get(1).map(String::as_str).unwrap_or("nvtmm").parse()?;
    let nodes: usize = args.get(2).map(|s| s.parse()).transpose()?.unwrap_or(1458);
    let steps: usize = args.get(3).map(|s| s.parse()).transpose()?.unwrap_or(200);
    let linear = parse_linear(args.get(4).map(String::as_str).unwrap_or("cholesky"))?;
    let arch = generate(&ArchParams::default(), nodes)?;
    let mesh = &arch.mesh;
    let mat = Material::aorta();
    let load = standard_load(&arch, 0.3);
    let everies = [1usize, 2, 5, 10, 20, 50, 1_000_000];
    // HALVINGS=m retries failed steps with dt/2 … dt/2^m (docs/SOLVERS.md).
    let max_halvings: usize = std::env::var("HALVINGS").ok().and_then(|s| s.parse().ok()).unwrap_or(0);
    let mut runs: Vec<_> = everies
        .iter()
        .map(|&k| {
            let params = ImplicitEulerParams {
                linear,
                stiffness_every: k,
                max_halvings,
                ..standard_params()
            };
            let euler = ImplicitEuler::new(mesh, mesh.lumped_mass(mat.density), params).expect("integrator");
            let model = build_model(kind, mesh, &mat, Law::Stvk, &[]);
            (
                k,
                euler,
                model,
                TissueState::at_rest(mesh.num_nodes()),
                0.0f64,
                None::<String>,
            )
        })
        .collect();
    let node = load.node as usize;
    let mut max_ref = 0.0f64;
    for step in 1..=steps {
        for (_, euler, model, state, _, failed) in runs.iter_mut() {
            if failed.is_some() {
                continue;
            }
            let rep = euler.step(state, model.as_mut(), &load.loads, &load.fixed);
            if let Some(f) = rep.failure {
                *failed = Some(format!("step {step}: {f}"));
            }
        }
        if let Some(f) = &runs[0].5 {
            return Err(format!("the reference (k = 1) failed at {f}").into());
        }
        let uref = runs[0].3.u[node];
        max_ref = max_ref.max(uref.norm());
        for (_, _, _, state, err, failed) in runs.iter_mut().skip(1) {
            if failed.is_none() {
                *err = err.max((state.u[node] - uref).norm());
            }
        }
    }
    println!(
        "{} {} nodes, {} steps of the standard load, loaded node max |u| = {:.4} mm (k = 1), final {:.4} mm",
        kind.name(),
        mesh.num_nodes(),
        steps,
        max_ref * 1e3,
        runs[0].3.u[node].norm() * 1e3
    );
    println!("| stiffness_every | max error (µm) | max error / max |u| | final |u| (mm) |");
    println!("|---:|---:|---:|---:|");
    for (k, _, _, state, err, failed) in &runs {
        if let Some(f) = failed {
            println!("| {k} | failed at {f} | | |");
            continue;
        }
        println!(
            "| {} | {:.3} | {:.2e} | {:.4} |",
            k,
            err * 1e6,
            err / max_ref,
            state.u[node].norm() * 1e3
        );
    }
    Ok(())
}
