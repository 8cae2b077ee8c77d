//! After construction, `ImplicitEuler::step` allocates nothing (with a model
//! that does not allocate either), on the CG path with every preconditioner
//! and on the sparse Cholesky path: the background solver can run next to the
//! RT loop without touching the allocator.

mod common;

use common::counting::count_allocations;
use common::{block, Springs};
use nvtmm::math::Vec3;
use nvtmm::solver::loads::{Loads, NodalLoad, TimeProfile};
use nvtmm::solver::{ImplicitEuler, ImplicitEulerParams, LinearSolverKind, NewtonParams, Preconditioner, TissueState};

#[global_allocator]
static GLOBAL: common::counting::Counting = common::counting::Counting;

#[test]
fn implicit_step_allocates_nothing() {
    // The counter itself works: one box is one allocation.
    assert_eq!(count_allocations(|| drop(std::hint::black_box(Box::new(1u8)))).1, 1);
    let mesh = block(4, 3, 3, 0.01);
    let fixed = mesh.node_set("x_min").unwrap().to_vec();
    let loads = Loads {
        nodal: vec![NodalLoad {
            nodes: mesh.node_set("x_max").unwrap().to_vec(),
            force: Vec3::new(0.5, 0.2, 0.0),
            profile: TimeProfile::Sine {
                freq_hz: 10.0,
                phase: 0.0,
            },
        }],
        gravity: Vec3::new(0.0, 0.0, -9.81),
    };
    let mut kinds: Vec<LinearSolverKind> = [
        Preconditioner::None,
        Preconditioner::Jacobi,
        Preconditioner::BlockJacobi,
        Preconditioner::BlockSsor,
        Preconditioner::BlockIc0,
    ]
    .into_iter()
    .map(|precond| LinearSolverKind::Cg {
        precond,
        tol: 1e-10,
        max_iter: 500,
        strict: false,
    })
    .collect();
    kinds.push(LinearSolverKind::Cholesky);
    for factor_f32 in [false, true] {
        kinds.push(LinearSolverKind::CholeskyPcg {
            tol: 1e-10,
            max_iter: 30,
            refactor_every: 3,
            factor_f32,
        });
    }
    // Each solver with exact Newton and with the lagged tangent.
    let cases: Vec<(LinearSolverKind, usize)> = kinds.iter().flat_map(|&l| [(l, 1), (l, 3)]).collect();
    for (linear, stiffness_every) in cases {
        let mut model = Springs::new(&mesh, 100.0, 1e6);
        let params = ImplicitEulerParams {
            dt: 2e-3,
            rayleigh_alpha: 1.0,
            rayleigh_beta: 1e-3,
            newton: NewtonParams {
                max_iters: 4,
                ..NewtonParams::default()
            },
            linear,
            stiffness_every,
            max_halvings: 0,
        };
        let mut euler = ImplicitEuler::new(&mesh, mesh.lumped_mass(1100.0), params).unwrap();
        let mut state = TissueState::at_rest(mesh.num_nodes());
        let (ok, count) = count_allocations(|| {
            let mut ok = true;
            for _ in 0..5 {
                ok &= euler.step(&mut state, &mut model, &loads, &fixed).ok();
            }
            ok
        });
        assert!(ok, "{linear:?}, stiffness_every {stiffness_every}: a step failed");
        assert_eq!(
            count, 0,
            "{linear:?}, stiffness_every {stiffness_every}: step allocated"
        );
    }
}
