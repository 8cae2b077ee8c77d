//! Every way a step can fail leaves the state bitwise unchanged, does not
//! commit the model's history (`end_step`), and says why.

mod common;

use common::{bits, block, pseudo_random, NanAfter, Springs};
use nvtmm::math::Vec3;
use nvtmm::model::ForceModel;
use nvtmm::solver::linear::LinearFailure;
use nvtmm::solver::loads::{LoadError, Loads, NodalLoad, TimeProfile};
use nvtmm::solver::{
    ImplicitEuler, ImplicitEulerParams, LinearSolverKind, NewtonParams, Preconditioner, StepFailure, TissueState,
};

struct Setup {
    mesh: nvtmm::mesh::TetMesh,
    fixed: Vec<u32>,
    loads: Loads,
    state: TissueState,
}

fn setup() -> Setup {
    let mesh = block(3, 2, 2, 0.01);
    let fixed = mesh.node_set("x_min").unwrap().to_vec();
    let loads = Loads {
        nodal: vec![NodalLoad {
            nodes: mesh.node_set("x_max").unwrap().to_vec(),
            force: Vec3::new(2.0, 0.5, 0.0),
            profile: TimeProfile::Constant { from_t0: 0.0 },
        }],
        gravity: Vec3::new(0.0, 0.0, -9.81),
        pressure: None,
    };
    let mut state = TissueState::at_rest(mesh.num_nodes());
    for (i, u) in pseudo_random(mesh.num_nodes(), 3).into_iter().enumerate() {
        if !fixed.contains(&(i as u32)) {
            state.u[i] = u * 1e-3;
            state.v[i] = u * 0.01;
        }
    }
    state.t = 0.123;
    Setup {
        mesh,
        fixed,
        loads,
        state,
    }
}

fn params(newton: NewtonParams, linear: LinearSolverKind) -> ImplicitEulerParams {
    ImplicitEulerParams {
        dt: 0.01,
        newton,
        linear,
        ..ImplicitEulerParams::default()
    }
}

/// Steps once and checks the state did not change; returns the failure.
fn fail_once(s: &mut Setup, p: ImplicitEulerParams, model: &mut dyn ForceModel, loads: &Loads) -> StepFailure {
    let mut euler = ImplicitEuler::new(&s.mesh, s.mesh.lumped_mass(1100.0), p).unwrap();
    let before = bits(&s.state);
    let rep = euler.step(&mut s.state, model, loads, &s.fixed);
    assert_eq!(bits(&s.state), before, "state changed on a failed step");
    assert!(!rep.ok());
    rep.failure.unwrap()
}

#[test]
fn nan_force_fails_cleanly() {
    for nan_after in [0, 1, 2] {
        let mut s = setup();
        let mut model = NanAfter {
            inner: Springs::new(&s.mesh, 100.0, 1e6),
            nan_after,
            calls: Default::default(),
        };
        let loads = s.loads.clone();
        let f = fail_once(
            &mut s,
            params(NewtonParams::default(), LinearSolverKind::Cholesky),
            &mut model,
            &loads,
        );
        assert_eq!(f, StepFailure::NonFiniteForce { newton_iter: nan_after });
        assert_eq!(model.inner.end_steps, 0);
        assert!(f.to_string().contains("non-finite force"));
    }
}

#[test]
fn strict_cg_that_cannot_converge_fails_cleanly() {
    let mut s = setup();
    let mut model = Springs::new(&s.mesh, 100.0, 1e6);
    let linear = LinearSolverKind::Cg {
        precond: Preconditioner::Jacobi,
        tol: 1e-15,
        max_iter: 1,
        strict: true,
    };
    let loads = s.loads.clone();
    let f = fail_once(&mut s, params(NewtonParams::default(), linear), &mut model, &loads);
    assert!(
        matches!(
            f,
            StepFailure::Linear {
                newton_iter: 0,
                reason: LinearFailure::CgNotConverged { iters: 1, .. }
            }
        ),
        "{f:?}"
    );
    assert_eq!(model.end_steps, 0);
}

#[test]
fn unconverged_newton_with_required_convergence_fails_cleanly() {
    let mut s = setup();
    let mut model = Springs::new(&s.mesh, 100.0, 1e7);
    let newton = NewtonParams {
        max_iters: 1,
        rel_tol: 1e-12,
        require_convergence: true,
        ..NewtonParams::default()
    };
    let loads = s.loads.clone();
    let f = fail_once(&mut s, params(newton, LinearSolverKind::Cholesky), &mut model, &loads);
    assert!(
        matches!(f, StepFailure::NotConverged { rel_residual } if rel_residual > 1e-12),
        "{f:?}"
    );
    // The same step accepted without the requirement does move the state.
    let mut euler = ImplicitEuler::new(
        &s.mesh,
        s.mesh.lumped_mass(1100.0),
        params(
            NewtonParams {
                require_convergence: false,
                ..newton
            },
            LinearSolverKind::Cholesky,
        ),
    )
    .unwrap();
    let rep = euler.step(&mut s.state, &mut model, &loads, &s.fixed);
    assert!(rep.ok() && !rep.converged && rep.newton_iters == 1);
    assert_eq!(model.end_steps, 1);
}

#[test]
fn indefinite_stiffness_fails_cleanly() {
    // Negative spring stiffness: A = M + h² K is indefinite at h = 10 ms.
    for linear in [
        LinearSolverKind::Cholesky,
        LinearSolverKind::Cg {
            precond: Preconditioner::None,
            tol: 1e-10,
            max_iter: 500,
            strict: false,
        },
    ] {
        let mut s = setup();
        let mut model = Springs::new(&s.mesh, -1e3, 0.0);
        let loads = s.loads.clone();
        let f = fail_once(&mut s, params(NewtonParams::default(), linear), &mut model, &loads);
        match (linear, f) {
            (
                LinearSolverKind::Cholesky,
                StepFailure::Linear {
                    reason: LinearFailure::NotPositiveDefinite,
                    ..
                },
            ) => {}
            (
                LinearSolverKind::Cg { .. },
                StepFailure::Linear {
                    reason: LinearFailure::CgBreakdown { .. },
                    ..
                },
            ) => {}
            _ => panic!("{linear:?}: unexpected {f:?}"),
        }
    }
}

#[test]
fn bad_input_fails_cleanly() {
    let mut s = setup();
    let mut model = Springs::new(&s.mesh, 100.0, 0.0);
    let p = params(NewtonParams::default(), LinearSolverKind::Cholesky);
    let n = s.mesh.num_nodes() as u32;
    let mut loads = s.loads.clone();
    loads.nodal[0].nodes.push(n);
    assert_eq!(
        fail_once(&mut s, p, &mut model, &loads),
        StepFailure::BadLoads(LoadError::NodeOutOfRange { load: 0, node: n })
    );
    let mut loads = s.loads.clone();
    loads.gravity.z = f64::INFINITY;
    assert!(matches!(
        fail_once(&mut s, p, &mut model, &loads),
        StepFailure::BadLoads(LoadError::NonFinite { .. })
    ));
    s.fixed.push(n + 5);
    let loads = s.loads.clone();
    assert!(matches!(
        fail_once(&mut s, p, &mut model, &loads),
        StepFailure::BadLoads(_)
    ));
    s.fixed.pop();
    s.state.v[3].y = f64::NAN;
    let mut euler = ImplicitEuler::new(&s.mesh, s.mesh.lumped_mass(1100.0), p).unwrap();
    let rep = euler.step(&mut s.state, &mut model, &loads, &s.fixed);
    assert_eq!(rep.failure, Some(StepFailure::BadState));
    assert!(s.state.v[3].y.is_nan());
}

#[test]
fn bad_parameters_are_refused_with_the_key() {
    let s = setup();
    let m = s.mesh.lumped_mass(1100.0);
    let bad = [
        (
            ImplicitEulerParams {
                dt: 0.0,
                ..Default::default()
            },
            "dt",
        ),
        (
            ImplicitEulerParams {
                rayleigh_beta: -1.0,
                ..Default::default()
            },
            "rayleigh_beta",
        ),
        (
            ImplicitEulerParams {
                newton: NewtonParams {
                    max_iters: 0,
                    ..Default::default()
                },
                ..Default::default()
            },
            "newton.max_iters",
        ),
        (
            params(
                NewtonParams::default(),
                LinearSolverKind::Cg {
                    precond: Preconditioner::Jacobi,
                    tol: 0.0,
                    max_iter: 5,
                    strict: false,
                },
            ),
            "linear.tol",
        ),
    ];
    for (p, key) in bad {
        let e = ImplicitEuler::new(&s.mesh, m.clone(), p).unwrap_err();
        assert!(e.to_string().contains(key), "{e}");
    }
    let mut short = m.clone();
    short.pop();
    assert!(ImplicitEuler::new(&s.mesh, short, ImplicitEulerParams::default()).is_err());
    let mut zero = m;
    zero[2] = 0.0;
    assert!(ImplicitEuler::new(&s.mesh, zero, ImplicitEulerParams::default()).is_err());
}

#[test]
fn finite_blowup_is_a_failure_not_a_state() {
    // A soft linear model under an enormous load: the solve is finite, but
    // the new displacement would be kilometres on a 3 cm block.
    let mut s = setup();
    let mut model = Springs::new(&s.mesh, 1e-3, 0.0);
    let p = params(NewtonParams::default(), LinearSolverKind::Cholesky);
    let mut loads = s.loads.clone();
    loads.nodal[0].force = Vec3::new(1e9, 0.0, 0.0);
    match fail_once(&mut s, p, &mut model, &loads) {
        StepFailure::Blowup { max_displacement } => assert!(max_displacement > 0.3, "{max_displacement}"),
        f => panic!("unexpected {f:?}"),
    }
}
