//! `newton.check_final_residual = false` only drops the residual evaluation
//! after the last allowed Newton update: the committed states are bitwise
//! those of the checked run, with exact and lagged tangents, and the setting
//! is refused together with `require_convergence`.

mod common;

use common::{block, Springs};
use nvtmm::math::Vec3;
use nvtmm::solver::loads::{Loads, NodalLoad, TimeProfile};
use nvtmm::solver::{ImplicitEuler, ImplicitEulerParams, LinearSolverKind, NewtonParams, TissueState};

#[test]
fn final_residual_check_does_not_change_the_state() {
    let mesh = block(4, 2, 2, 0.01);
    let fixed = mesh.node_set("x_min").unwrap().to_vec();
    let loads = Loads {
        nodal: vec![NodalLoad {
            nodes: mesh.node_set("x_max").unwrap().to_vec(),
            force: Vec3::new(0.4, -0.3, 0.1),
            profile: TimeProfile::Ramp { t0: 0.0, t1: 0.01 },
        }],
        gravity: Vec3::new(0.0, 0.0, -9.81),
        pressure: None,
    };
    for max_iters in [1, 3] {
        for stiffness_every in [1, 4] {
            let run = |check: bool| {
                let mut model = Springs::new(&mesh, 100.0, 1e6);
                let params = ImplicitEulerParams {
                    dt: 2e-3,
                    rayleigh_alpha: 1.0,
                    rayleigh_beta: 1e-3,
                    newton: NewtonParams {
                        max_iters,
                        rel_tol: 1e-14,
                        check_final_residual: check,
                        ..NewtonParams::default()
                    },
                    linear: LinearSolverKind::Cholesky,
                    stiffness_every,
                    max_halvings: 0,
                };
                let mut euler = ImplicitEuler::new(&mesh, mesh.lumped_mass(1100.0), params).unwrap();
                let mut state = TissueState::at_rest(mesh.num_nodes());
                let mut out = Vec::new();
                for _ in 0..15 {
                    let rep = euler.step(&mut state, &mut model, &loads, &fixed);
                    assert!(rep.ok(), "{:?}", rep.failure);
                    if !check {
                        assert!(rep.residuals().len() <= max_iters);
                    }
                    out.push(state.clone());
                }
                out
            };
            assert_eq!(
                run(true),
                run(false),
                "max_iters {max_iters}, stiffness_every {stiffness_every}"
            );
        }
    }
    let bad = ImplicitEulerParams {
        newton: NewtonParams {
            require_convergence: true,
            check_final_residual: false,
            ..NewtonParams::default()
        },
        ..ImplicitEulerParams::default()
    };
    let err = bad.validate().unwrap_err();
    assert!(err.contains("newton.check_final_residual"), "{err}");
}
