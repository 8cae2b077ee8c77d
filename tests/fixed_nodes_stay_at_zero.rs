//! Fixed (Dirichlet) nodes keep exactly zero displacement and velocity under
//! gravity, time-varying loads (also applied to the fixed nodes themselves)
//! and with every linear solver; a non-zero displacement a caller left on a
//! fixed node is reset to zero by the step.

mod common;

use common::{block, Springs};
use nvtmm::math::Vec3;
use nvtmm::solver::loads::{nodes_in_box, Loads, NodalLoad, TimeProfile};
use nvtmm::solver::{ImplicitEuler, ImplicitEulerParams, LinearSolverKind, NewtonParams, Preconditioner, TissueState};

#[test]
fn fixed_nodes_stay_exactly_at_zero() {
    let mesh = block(4, 2, 2, 0.01);
    // The x ≤ 5 mm slab: the x = 0 face (node set "x_min") only, as a box.
    let fixed = nodes_in_box(&mesh, Vec3::new(-1.0, -1.0, -1.0), Vec3::new(0.005, 1.0, 1.0));
    assert_eq!(fixed, mesh.node_set("x_min").unwrap());
    let all: Vec<u32> = (0..mesh.num_nodes() as u32).collect();
    let loads = Loads {
        nodal: vec![
            NodalLoad {
                nodes: all,
                force: Vec3::new(0.05, 0.1, -0.02),
                profile: TimeProfile::Sine {
                    freq_hz: 20.0,
                    phase: 0.3,
                },
            },
            NodalLoad {
                nodes: fixed.clone(),
                force: Vec3::new(10.0, 10.0, 10.0),
                profile: TimeProfile::Constant { from_t0: 0.0 },
            },
        ],
        gravity: Vec3::new(0.0, 0.0, -9.81),
        pressure: None,
    };
    for linear in [
        LinearSolverKind::Cholesky,
        LinearSolverKind::Cg {
            precond: Preconditioner::BlockSsor,
            tol: 1e-8,
            max_iter: 200,
            strict: false,
        },
        LinearSolverKind::Cg {
            precond: Preconditioner::Jacobi,
            tol: 1e-6,
            max_iter: 3,
            strict: false,
        },
    ] {
        let mut model = Springs::new(&mesh, 100.0, 1e5);
        let params = ImplicitEulerParams {
            dt: 2e-3,
            rayleigh_alpha: 1.0,
            newton: NewtonParams::linearized(),
            linear,
            ..ImplicitEulerParams::default()
        };
        let mut euler = ImplicitEuler::new(&mesh, mesh.lumped_mass(1100.0), params).unwrap();
        let mut state = TissueState::at_rest(mesh.num_nodes());
        state.u[fixed[0] as usize] = Vec3::new(1e-3, 0.0, 0.0);
        let mut moved = 0.0f64;
        for _ in 0..60 {
            let rep = euler.step(&mut state, &mut model, &loads, &fixed);
            assert!(rep.ok(), "{linear:?}: {:?}", rep.failure);
            for &i in &fixed {
                assert_eq!(state.u[i as usize], Vec3::zeros(), "{linear:?}");
                assert_eq!(state.v[i as usize], Vec3::zeros(), "{linear:?}");
            }
            moved = moved.max(state.u.iter().map(|u| u.norm()).fold(0.0, f64::max));
        }
        assert!(moved > 1e-4, "{linear:?}: the free nodes did not move ({moved})");
    }
}
