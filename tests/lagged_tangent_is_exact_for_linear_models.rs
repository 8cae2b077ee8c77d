//! `stiffness_every` > 1 reuses the Newton matrix and the prepared linear
//! solver across steps. For a linear model (tensor-mass TMM) the tangent does
//! not change, so the lagged step must equal the exact one — with Cholesky
//! and with CG, and also across a change of the fixed set, which must force a
//! rebuild (a stale projection would leave wrong rows in A).

mod common;

use common::{block, material};
use nvtmm::math::Vec3;
use nvtmm::model::tmm::Tmm;
use nvtmm::solver::loads::{Loads, NodalLoad, TimeProfile};
use nvtmm::solver::{ImplicitEuler, ImplicitEulerParams, LinearSolverKind, NewtonParams, Preconditioner, TissueState};

fn run(linear: LinearSolverKind, stiffness_every: usize) -> Vec<TissueState> {
    let mesh = block(5, 2, 2, 0.01);
    let model_mat = material();
    let mut model = Tmm::new(&mesh, &model_mat);
    let fixed_a = mesh.node_set("x_min").unwrap().to_vec();
    let mut fixed_b = fixed_a.clone();
    fixed_b.extend_from_slice(mesh.node_set("x_max").unwrap());
    fixed_b.sort_unstable();
    let loads = Loads {
        nodal: vec![NodalLoad {
            nodes: mesh.node_set("x_max").unwrap().to_vec(),
            force: Vec3::new(0.0, 0.02, -0.05),
            profile: TimeProfile::Ramp { t0: 0.0, t1: 0.01 },
        }],
        gravity: Vec3::new(0.0, 0.0, -9.81),
        pressure: None,
    };
    let params = ImplicitEulerParams {
        dt: 1e-3,
        rayleigh_alpha: 0.5,
        rayleigh_beta: 1e-3,
        newton: NewtonParams::linearized(),
        linear,
        stiffness_every,
        max_halvings: 0,
    };
    let mut euler = ImplicitEuler::new(&mesh, mesh.lumped_mass(model_mat.density), params).unwrap();
    let mut state = TissueState::at_rest(mesh.num_nodes());
    let mut out = Vec::new();
    for step in 0..30 {
        let fixed = if (12..20).contains(&step) { &fixed_b } else { &fixed_a };
        let rep = euler.step(&mut state, &mut model, &loads, fixed);
        assert!(rep.ok(), "step {step}: {:?}", rep.failure);
        out.push(state.clone());
    }
    out
}

fn rel_diff(a: &[Vec3], b: &[Vec3]) -> f64 {
    let num: f64 = a.iter().zip(b).map(|(x, y)| (x - y).norm_squared()).sum::<f64>().sqrt();
    let den: f64 = b.iter().map(|y| y.norm_squared()).sum::<f64>().sqrt();
    num / den.max(f64::MIN_POSITIVE)
}

#[test]
fn lagged_tangent_is_exact_for_linear_models() {
    let cg = LinearSolverKind::Cg {
        precond: Preconditioner::BlockIc0,
        tol: 1e-12,
        max_iter: 2000,
        strict: true,
    };
    let cpcg = LinearSolverKind::CholeskyPcg {
        tol: 1e-12,
        max_iter: 30,
        refactor_every: 4,
        factor_f32: false,
    };
    let cpcg32 = LinearSolverKind::CholeskyPcg {
        tol: 1e-12,
        max_iter: 30,
        refactor_every: 4,
        factor_f32: true,
    };
    for (linear, tol) in [
        (LinearSolverKind::Cholesky, 1e-10),
        (cg, 1e-8),
        (cpcg, 1e-8),
        (cpcg32, 1e-8),
    ] {
        let exact = run(linear, 1);
        for every in [2, 7, 1000] {
            let lagged = run(linear, every);
            for (step, (e, l)) in exact.iter().zip(&lagged).enumerate() {
                let du = rel_diff(&l.u, &e.u);
                let dv = rel_diff(&l.v, &e.v);
                assert!(
                    du < tol && dv < tol,
                    "{linear:?}, every {every}, step {step}: rel diff u {du:e}, v {dv:e}"
                );
            }
        }
    }
}
