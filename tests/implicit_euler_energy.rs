//! Energy behaviour of the backward Euler step.
//!
//! For a linear model with SPD M and K and no external force, backward Euler
//! satisfies exactly E_{n+1} + ½‖v₁ − v₀‖²_M + ½‖u₁ − u₀‖²_K = E_n (no
//! damping), so the total energy can only fall; Rayleigh damping removes
//! h v₁ᵀ D v₁ ≥ 0 more each step. A convex nonlinear energy keeps the
//! inequality (W(u₀) ≥ W(u₁) + f(u₁)·(u₀ − u₁)... i.e. W is above its
//! tangent), so it must not grow either.

mod common;

use common::{block, pseudo_random, Springs};
use nvtmm::math::Vec3;
use nvtmm::model::ForceModel;
use nvtmm::solver::loads::Loads;
use nvtmm::solver::{ImplicitEuler, ImplicitEulerParams, LinearSolverKind, NewtonParams, TissueState};

fn total_energy(state: &TissueState, mass: &[f64], model: &dyn ForceModel) -> f64 {
    state.kinetic_energy(mass) + model.energy(&state.u)
}

/// Runs `steps` steps from a perturbed state and returns the energy history.
fn energies(c: f64, alpha: f64, beta: f64, steps: usize) -> Vec<f64> {
    let mesh = block(3, 2, 2, 0.01);
    let fixed = mesh.node_set("x_min").unwrap().to_vec();
    let mut model = Springs::new(&mesh, 50.0, c);
    let params = ImplicitEulerParams {
        dt: 5e-4,
        rayleigh_alpha: alpha,
        rayleigh_beta: beta,
        newton: NewtonParams {
            max_iters: 20,
            rel_tol: 1e-12,
            require_convergence: true,
            ..NewtonParams::default()
        },
        linear: LinearSolverKind::Cholesky,
        ..ImplicitEulerParams::default()
    };
    let mass = mesh.lumped_mass(1100.0);
    let mut euler = ImplicitEuler::new(&mesh, mass.clone(), params).unwrap();
    let mut state = TissueState::at_rest(mesh.num_nodes());
    for (i, (u, v)) in pseudo_random(mesh.num_nodes(), 7)
        .into_iter()
        .zip(pseudo_random(mesh.num_nodes(), 8))
        .enumerate()
    {
        if !fixed.contains(&(i as u32)) {
            state.u[i] = u * 3e-3;
            state.v[i] = v * 0.1;
        }
    }
    let mut e = vec![total_energy(&state, &mass, &model)];
    for _ in 0..steps {
        let rep = euler.step(&mut state, &mut model, &Loads::none(), &fixed);
        assert!(rep.ok() && rep.converged, "{:?}", rep.failure);
        e.push(total_energy(&state, &mass, &model));
    }
    e
}

#[test]
fn undamped_linear_energy_never_grows() {
    let e = energies(0.0, 0.0, 0.0, 400);
    // Round-off only: the energy identity is exact in exact arithmetic.
    for w in e.windows(2) {
        assert!(w[1] <= w[0] * (1.0 + 1e-10), "energy grew: {} -> {}", w[0], w[1]);
    }
    // Backward Euler's numerical dissipation is real: the energy falls.
    assert!(e[400] < e[0], "{} -> {}", e[0], e[400]);
}

#[test]
fn undamped_nonlinear_energy_stays_bounded() {
    let e = energies(1e6, 0.0, 0.0, 400);
    for w in e.windows(2) {
        assert!(w[1] <= w[0] * (1.0 + 1e-9), "energy grew: {} -> {}", w[0], w[1]);
    }
}

#[test]
fn rayleigh_damped_energy_decays_monotonically() {
    for (alpha, beta, c) in [(5.0, 0.0, 0.0), (0.0, 1e-3, 0.0), (5.0, 1e-3, 1e6)] {
        let e = energies(c, alpha, beta, 300);
        for w in e.windows(2) {
            assert!(
                w[1] < w[0],
                "alpha={alpha} beta={beta}: energy did not fall: {} -> {}",
                w[0],
                w[1]
            );
        }
        // …and faster than without damping.
        let e0 = energies(c, 0.0, 0.0, 300);
        assert!(
            e[300] < e0[300],
            "alpha={alpha} beta={beta}: damping did not dissipate more"
        );
    }
}

/// One free node tied by three linear springs to the three fixed nodes of a
/// single tet: K = 3k I, an isotropic oscillator with ω = √(3k/m). Started
/// at u = (A, 0, 0), v = 0, it oscillates along x. Backward Euler's discrete
/// period is T_h = 2πh / atan(ωh) (its one-step factor is 1/(1 − iωh)), so
/// with 1000 steps per period the period error is (ωh)²/3 ≈ 1.3e-5. The
/// measured period (mean spacing of linearly interpolated down-crossings
/// over 3 periods; interpolation error O((ωh)²) ≈ 4e-5 per crossing, and
/// the BE amplitude decay of ≈ 2 % per period does not move the crossings
/// of a pure decaying cosine by more than that) must match 2π/ω to 2e-4 and
/// T_h to 1e-4.
#[test]
fn linear_oscillator_has_the_analytic_period() {
    let mesh = nvtmm::mesh::TetMesh::new(
        vec![
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(0.01, 0.0, 0.0),
            Vec3::new(0.0, 0.01, 0.0),
            Vec3::new(0.0, 0.0, 0.01),
        ],
        vec![[0, 1, 2, 3]],
        Default::default(),
    )
    .unwrap();
    let fixed = [0u32, 1, 2];
    let (k, m): (f64, f64) = (40.0, 2e-3);
    let omega = (3.0 * k / m).sqrt();
    let period = 2.0 * std::f64::consts::PI / omega;
    let h = period / 1000.0;
    let mut model = Springs::new(&mesh, k, 0.0);
    let params = ImplicitEulerParams {
        dt: h,
        newton: NewtonParams {
            max_iters: 1,
            ..NewtonParams::default()
        },
        linear: LinearSolverKind::Cholesky,
        ..ImplicitEulerParams::default()
    };
    let mut euler = ImplicitEuler::new(&mesh, vec![m; 4], params).unwrap();
    let mut state = TissueState::at_rest(4);
    state.u[3] = Vec3::new(1e-3, 0.0, 0.0);
    let mut crossings = Vec::new();
    let mut prev = (state.t, state.u[3].x);
    while crossings.len() < 4 {
        let rep = euler.step(&mut state, &mut model, &Loads::none(), &fixed);
        assert!(rep.ok() && rep.converged);
        let x = state.u[3].x;
        if prev.1 > 0.0 && x <= 0.0 {
            crossings.push(prev.0 + (state.t - prev.0) * prev.1 / (prev.1 - x));
        }
        prev = (state.t, x);
        assert!(state.u[3].y == 0.0 && state.u[3].z == 0.0);
    }
    let measured = (crossings[3] - crossings[0]) / 3.0;
    let t_be = 2.0 * std::f64::consts::PI * h / (omega * h).atan();
    assert!(
        ((measured - period) / period).abs() < 2e-4,
        "{measured} vs analytic {period}"
    );
    assert!(
        ((measured - t_be) / t_be).abs() < 1e-4,
        "{measured} vs backward Euler {t_be}"
    );
}
