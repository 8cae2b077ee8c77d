//! Newton on the backward Euler residual converges quadratically on a smooth
//! nonlinear model: the Jacobian (1 + hα) M + hβ K₀ + h² K(u) is exact (the
//! damping tangent is frozen at the start of the step), so once the iterate
//! is close, r_{k+1} ≤ C r_k² until round-off.

mod common;

use common::{block, Springs};
use nvtmm::math::Vec3;
use nvtmm::solver::loads::{Loads, NodalLoad, TimeProfile};
use nvtmm::solver::{ImplicitEuler, ImplicitEulerParams, LinearSolverKind, NewtonParams, Preconditioner, TissueState};

fn run(linear: LinearSolverKind, beta: f64) -> Vec<f64> {
    let mesh = block(4, 3, 3, 0.01);
    let fixed = mesh.node_set("x_min").unwrap().to_vec();
    let loads = Loads {
        nodal: vec![NodalLoad {
            nodes: mesh.node_set("x_max").unwrap().to_vec(),
            force: Vec3::new(1.5, 0.8, -0.5),
            profile: TimeProfile::Constant { from_t0: 0.0 },
        }],
        gravity: Vec3::zeros(),
        pressure: None,
    };
    // |d| ~ 1 cm under this load: c|d|² ~ 1e2..1e3 against k = 100, so the
    // force is far from linear.
    let mut model = Springs::new(&mesh, 100.0, 2e6);
    let params = ImplicitEulerParams {
        dt: 0.01,
        rayleigh_alpha: 1.0,
        rayleigh_beta: beta,
        newton: NewtonParams {
            max_iters: 30,
            rel_tol: 1e-13,
            require_convergence: false,
            ..NewtonParams::default()
        },
        linear,
        ..ImplicitEulerParams::default()
    };
    let mut euler = ImplicitEuler::new(&mesh, mesh.lumped_mass(1100.0), params).unwrap();
    let mut state = TissueState::at_rest(mesh.num_nodes());
    let rep = euler.step(&mut state, &mut model, &loads, &fixed);
    assert!(rep.ok(), "{:?}", rep.failure);
    eprintln!("{linear:?} beta={beta}: {:?}", rep.residuals());
    rep.residuals().to_vec()
}

/// Checks the tail of the residual history: in the last iterations above the
/// round-off floor, r_{k+1} ≤ C r_k² with C = 10 (C measures how far the
/// model is from quadratic; a linearly convergent method with ratio ρ would
/// need C ≥ ρ / r_k, which grows without bound as r_k falls), and the
/// iteration reaches 1e-12.
fn assert_quadratic(res: &[f64]) {
    let floor = 1e-12;
    assert!(res.iter().any(|&r| r < floor), "did not reach {floor}: {res:?}");
    // Pairs (r_k, r_{k+1}) with r_k in the asymptotic range [1e-9, 1e-3]
    // (below 1e-3 the iterate is close; at 1e-9 the square is below round-off).
    let pairs: Vec<(f64, f64)> = res
        .windows(2)
        .map(|w| (w[0], w[1]))
        .filter(|&(a, _)| (1e-9..=1e-3).contains(&a))
        .collect();
    assert!(!pairs.is_empty(), "no iterate in the asymptotic range: {res:?}");
    for (a, b) in pairs {
        assert!(b <= 10.0 * a * a + 1e-14, "not quadratic: {a:e} -> {b:e} in {res:?}");
    }
}

#[test]
fn newton_with_cholesky_is_quadratic() {
    assert_quadratic(&run(LinearSolverKind::Cholesky, 0.0));
}

#[test]
fn newton_with_stiffness_damping_is_quadratic() {
    assert_quadratic(&run(LinearSolverKind::Cholesky, 1e-3));
}

#[test]
fn newton_with_tight_cg_is_quadratic() {
    for precond in [
        Preconditioner::Jacobi,
        Preconditioner::BlockJacobi,
        Preconditioner::BlockSsor,
        Preconditioner::BlockIc0,
    ] {
        assert_quadratic(&run(
            LinearSolverKind::Cg {
                precond,
                tol: 1e-14,
                max_iter: 2000,
                strict: true,
            },
            0.0,
        ));
    }
}
