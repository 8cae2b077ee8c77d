//! PCG (every preconditioner) and the sparse Cholesky solve the same Newton
//! system to the accuracy CG was asked for, and both match a dense solve.

mod common;

use common::{block, pseudo_random, Springs};
use nvtmm::math::Mat3;
use nvtmm::math::Vec3;
use nvtmm::model::{BlockTangent, ForceModel};
use nvtmm::solver::linear::{project_fixed, LinearSolver};
use nvtmm::solver::loads::{Loads, NodalLoad, TimeProfile};
use nvtmm::solver::{ImplicitEuler, ImplicitEulerParams, LinearSolverKind, NewtonParams, Preconditioner, TissueState};

const PRECONDS: [Preconditioner; 5] = [
    Preconditioner::None,
    Preconditioner::Jacobi,
    Preconditioner::BlockJacobi,
    Preconditioner::BlockSsor,
    Preconditioner::BlockIc0,
];

fn rel_diff(a: &[Vec3], b: &[Vec3]) -> f64 {
    let num: f64 = a.iter().zip(b).map(|(x, y)| (x - y).norm_squared()).sum();
    let den: f64 = b.iter().map(|y| y.norm_squared()).sum();
    (num / den).sqrt()
}

/// A = c_m M + c_k K(u) at a random u, fixed rows projected.
fn newton_matrix() -> (BlockTangent, Vec<Vec3>, Vec<bool>) {
    let mesh = block(5, 3, 3, 0.01);
    let n = mesh.num_nodes();
    let model = Springs::new(&mesh, 200.0, 1e6);
    let u: Vec<Vec3> = pseudo_random(n, 11).into_iter().map(|x| x * 5e-3).collect();
    let mut k = BlockTangent::zeros(&mesh);
    model.add_stiffness(&u, &mut k);
    let (h, mass) = (5e-3, mesh.lumped_mass(1100.0));
    let mut a = k.clone();
    for (d, m) in a.diag.iter_mut().zip(&mass) {
        *d = *d * (h * h) + Mat3::identity() * *m;
    }
    for o in a.off.iter_mut() {
        *o *= h * h;
    }
    let mut mask = vec![false; n];
    for &i in mesh.node_set("x_min").unwrap() {
        mask[i as usize] = true;
    }
    project_fixed(&mut a, &mask);
    let mut b = pseudo_random(n, 12);
    for (bi, &f) in b.iter_mut().zip(&mask) {
        if f {
            *bi = Vec3::zeros();
        }
    }
    (a, b, mask)
}

#[test]
fn linear_solvers_agree_with_a_dense_solve() {
    let (a, b, mask) = newton_matrix();
    let n = a.num_nodes();
    let dense = a.to_dense();
    let rhs = nalgebra::DVector::from_iterator(3 * n, b.iter().flat_map(|v| v.iter().copied()));
    let xd = dense.clone().cholesky().expect("SPD").solve(&rhs);
    let xd: Vec<Vec3> = (0..n)
        .map(|i| Vec3::new(xd[3 * i], xd[3 * i + 1], xd[3 * i + 2]))
        .collect();
    // Condition number, for the CG tolerance below.
    let eig = dense.symmetric_eigenvalues();
    let cond = eig.max() / eig.min();

    let mut x = vec![Vec3::zeros(); n];
    let mut chol = LinearSolver::new(&LinearSolverKind::Cholesky, &a).unwrap();
    chol.solve(&a, &b, &mut x).unwrap();
    assert!(rel_diff(&x, &xd) < 1e-12, "Cholesky vs dense: {}", rel_diff(&x, &xd));
    for (xi, &f) in x.iter().zip(&mask) {
        if f {
            assert_eq!(*xi, Vec3::zeros());
        }
    }
    // ‖x − x*‖/‖x*‖ ≤ cond(A) ‖r‖/‖b‖ with ‖r‖ ≤ tol ‖b‖.
    let tol = 1e-12;
    for precond in PRECONDS {
        let kind = LinearSolverKind::Cg {
            precond,
            tol,
            max_iter: 5000,
            strict: true,
        };
        let mut cg = LinearSolver::new(&kind, &a).unwrap();
        let mut xc = vec![Vec3::zeros(); n];
        let stats = cg.solve(&a, &b, &mut xc).unwrap();
        let d = rel_diff(&xc, &xd);
        eprintln!(
            "{precond:?}: {} iterations, rel. error {d:e} (cond {cond:e})",
            stats.iters
        );
        assert!(
            stats.converged && d <= cond * tol,
            "{precond:?}: {d:e} > {:e}",
            cond * tol
        );
        // A warm start at the answer needs (almost) no iterations.
        let again = cg.solve(&a, &b, &mut xc).unwrap();
        assert!(
            again.iters <= 1,
            "{precond:?}: warm start took {} iterations",
            again.iters
        );
    }
}

#[test]
fn a_step_with_cg_matches_a_step_with_cholesky() {
    let mesh = block(4, 3, 3, 0.01);
    let fixed = mesh.node_set("x_min").unwrap().to_vec();
    let loads = Loads {
        nodal: vec![NodalLoad {
            nodes: mesh.node_set("x_max").unwrap().to_vec(),
            force: Vec3::new(0.3, -0.7, 0.2),
            profile: TimeProfile::Ramp { t0: 0.0, t1: 0.02 },
        }],
        gravity: Vec3::new(0.0, -9.81, 0.0),
        pressure: None,
    };
    let run = |linear: LinearSolverKind| {
        let mut model = Springs::new(&mesh, 100.0, 1e6);
        let params = ImplicitEulerParams {
            dt: 5e-3,
            rayleigh_alpha: 2.0,
            rayleigh_beta: 1e-3,
            newton: NewtonParams {
                max_iters: 10,
                rel_tol: 1e-11,
                require_convergence: true,
                ..NewtonParams::default()
            },
            linear,
            ..ImplicitEulerParams::default()
        };
        let mut euler = ImplicitEuler::new(&mesh, mesh.lumped_mass(1100.0), params).unwrap();
        let mut state = TissueState::at_rest(mesh.num_nodes());
        for _ in 0..10 {
            let rep = euler.step(&mut state, &mut model, &loads, &fixed);
            assert!(rep.ok() && rep.converged, "{linear:?}: {:?}", rep.failure);
        }
        state
    };
    let reference = run(LinearSolverKind::Cholesky);
    for precond in PRECONDS {
        let s = run(LinearSolverKind::Cg {
            precond,
            tol: 1e-12,
            max_iter: 5000,
            strict: false,
        });
        // Both converge Newton to 1e-11 relative; the states agree to the
        // conditioning of A times that.
        assert!(
            rel_diff(&s.v, &reference.v) < 1e-8,
            "{precond:?} v: {:e}",
            rel_diff(&s.v, &reference.v)
        );
        assert!(
            rel_diff(&s.u, &reference.u) < 1e-8,
            "{precond:?} u: {:e}",
            rel_diff(&s.u, &reference.u)
        );
    }
    // CG preconditioned by a lagged Cholesky factor (refactored every 3
    // solves; a Newton step with a nonlinear model changes A every solve).
    // With the factor in f32 the solve still reaches the f64 tolerance.
    for factor_f32 in [false, true] {
        let s = run(LinearSolverKind::CholeskyPcg {
            tol: 1e-12,
            max_iter: 30,
            refactor_every: 3,
            factor_f32,
        });
        assert!(
            rel_diff(&s.v, &reference.v) < 1e-8 && rel_diff(&s.u, &reference.u) < 1e-8,
            "cholesky-pcg (f32 factor: {factor_f32}): v {:e}, u {:e}",
            rel_diff(&s.v, &reference.v),
            rel_diff(&s.u, &reference.u)
        );
    }
}
