//! `max_halvings`: a step that fails is covered by halved sub-steps, equal
//! to taking those sub-steps by hand; when even the finest sub-step fails,
//! the state and the model's Prony history are rolled back bitwise.

mod common;

use common::{bits, block, pseudo_random};
use nvtmm::material::{Law, Material, PronyTerm};
use nvtmm::math::Vec3;
use nvtmm::mesh::TetMesh;
use nvtmm::model::nvtmm::Nvtmm;
use nvtmm::model::viscoelastic::Viscoelastic;
use nvtmm::model::{BlockTangent, ForceModel};
use nvtmm::solver::loads::{Loads, NodalLoad, TimeProfile};
use nvtmm::solver::{ImplicitEuler, ImplicitEulerParams, LinearSolverKind, StepFailure, TissueState};

type Visco = Viscoelastic<Nvtmm>;

/// A viscoelastic NVTMM model that returns a NaN force for steps longer
/// than `dt_limit`, and for every step once `poison_after` steps ended.
struct Picky {
    inner: Visco,
    dt_limit: f64,
    poison_after: usize,
    dt: f64,
    ended: usize,
}

impl Picky {
    fn new(inner: &Visco, dt_limit: f64, poison_after: usize) -> Picky {
        Picky {
            inner: inner.clone(),
            dt_limit,
            poison_after,
            dt: 0.0,
            ended: 0,
        }
    }
}

impl ForceModel for Picky {
    fn name(&self) -> &'static str {
        "picky"
    }
    fn add_forces(&self, u: &[Vec3], out: &mut [Vec3]) {
        self.inner.add_forces(u, out);
        if self.dt > self.dt_limit || self.ended >= self.poison_after {
            out[0].x = f64::NAN;
        }
    }
    fn add_df(&self, u: &[Vec3], du: &[Vec3], out: &mut [Vec3]) {
        self.inner.add_df(u, du, out)
    }
    fn add_stiffness(&self, u: &[Vec3], k: &mut BlockTangent) {
        self.inner.add_stiffness(u, k)
    }
    fn energy(&self, u: &[Vec3]) -> f64 {
        self.inner.energy(u)
    }
    fn begin_step(&mut self, dt: f64) {
        self.dt = dt;
        self.inner.begin_step(dt)
    }
    fn end_step(&mut self, u: &[Vec3]) {
        self.ended += 1;
        self.inner.end_step(u)
    }
    fn save_state(&mut self) {
        self.inner.save_state()
    }
    fn restore_state(&mut self) {
        self.inner.restore_state()
    }
}

struct Setup {
    mesh: TetMesh,
    fixed: Vec<u32>,
    loads: Loads,
    state: TissueState,
    model: Visco,
}

const H: f64 = 0.004;

fn setup() -> Setup {
    let mesh = block(3, 2, 2, 0.01);
    let fixed = mesh.node_set("x_min").unwrap().to_vec();
    let loads = Loads {
        nodal: vec![NodalLoad {
            nodes: mesh.node_set("x_max").unwrap().to_vec(),
            force: Vec3::new(0.5, 0.2, -0.3),
            profile: TimeProfile::Ramp { t0: 0.0, t1: 0.02 },
        }],
        gravity: Vec3::zeros(),
        pressure: None,
    };
    let mat = Material {
        youngs_pa: 1e5,
        poisson: 0.45,
        density: 1000.0,
    };
    let terms = [PronyTerm { alpha: 0.4, tau: 0.01 }];
    let mut model = Viscoelastic::new(Nvtmm::new(&mesh, &mat), &mesh, &mat, Law::Stvk, &terms);
    let mut state = TissueState::at_rest(mesh.num_nodes());
    for (i, u) in pseudo_random(mesh.num_nodes(), 5).into_iter().enumerate() {
        if !fixed.contains(&(i as u32)) {
            state.u[i] = u * 2e-4;
            state.v[i] = u * 0.01;
        }
    }
    // Some history to roll back: a few plain steps.
    let mut euler = ImplicitEuler::new(&mesh, mesh.lumped_mass(1000.0), params(H, 0)).unwrap();
    for _ in 0..3 {
        assert!(euler.step(&mut state, &mut model, &loads, &fixed).ok());
    }
    Setup {
        mesh,
        fixed,
        loads,
        state,
        model,
    }
}

fn params(dt: f64, max_halvings: usize) -> ImplicitEulerParams {
    ImplicitEulerParams {
        dt,
        rayleigh_beta: 1e-3,
        linear: LinearSolverKind::Cholesky,
        max_halvings,
        ..ImplicitEulerParams::default()
    }
}

/// The model's force at `u` for a step of `dt` (depends on the history).
fn force(model: &Visco, dt: f64, u: &[Vec3]) -> Vec<u64> {
    let mut m = model.clone();
    m.begin_step(dt);
    let mut f = vec![Vec3::zeros(); u.len()];
    m.add_forces(u, &mut f);
    f.iter()
        .flat_map(|v| v.iter().map(|c| c.to_bits()).collect::<Vec<_>>())
        .collect()
}

#[test]
fn a_failed_step_is_covered_by_the_sub_steps_a_user_would_take() {
    let s = setup();
    // Steps longer than H/4 fail: the step is retried at H/2 (fails), then
    // covered by four steps of H/4.
    let mut picky = Picky::new(&s.model, H / 4.0 * 1.0001, usize::MAX);
    let mut state = s.state.clone();
    let t0 = state.t;
    let mut euler = ImplicitEuler::new(&s.mesh, s.mesh.lumped_mass(1000.0), params(H, 3)).unwrap();
    let rep = euler.step(&mut state, &mut picky, &s.loads, &s.fixed);
    assert!(rep.ok(), "{:?}", rep.failure);
    assert_eq!(rep.substeps, 4);
    assert_eq!(state.t, t0 + H);
    assert_eq!(euler.params().dt, H, "the configured step is kept");

    // The same four quarter steps by hand.
    let mut by_hand = s.state.clone();
    let mut model = s.model.clone();
    let mut quarter = ImplicitEuler::new(&s.mesh, s.mesh.lumped_mass(1000.0), params(H / 4.0, 0)).unwrap();
    for _ in 0..4 {
        assert!(quarter.step(&mut by_hand, &mut model, &s.loads, &s.fixed).ok());
    }
    assert_eq!(
        bits(&TissueState {
            t: 0.0,
            ..state.clone()
        }),
        bits(&TissueState { t: 0.0, ..by_hand })
    );
    assert_eq!(force(&picky.inner, H, &state.u), force(&model, H, &state.u));

    // Without halving the same step fails and changes nothing.
    let mut state = s.state.clone();
    let mut picky = Picky::new(&s.model, H / 4.0 * 1.0001, usize::MAX);
    let mut plain = ImplicitEuler::new(&s.mesh, s.mesh.lumped_mass(1000.0), params(H, 0)).unwrap();
    let rep = plain.step(&mut state, &mut picky, &s.loads, &s.fixed);
    assert!(matches!(rep.failure, Some(StepFailure::NonFiniteForce { .. })));
    assert_eq!(rep.substeps, 0);
    assert_eq!(bits(&state), bits(&s.state));
}

#[test]
fn a_step_that_fails_at_the_finest_level_rolls_back_state_and_history() {
    let s = setup();
    // H fails; the first H/2 succeeds and advances the history; then every
    // step fails, down to H/4: the whole step must be undone.
    let mut picky = Picky::new(&s.model, H / 2.0 * 1.0001, 1);
    let mut state = s.state.clone();
    let mut euler = ImplicitEuler::new(&s.mesh, s.mesh.lumped_mass(1000.0), params(H, 2)).unwrap();
    let rep = euler.step(&mut state, &mut picky, &s.loads, &s.fixed);
    assert_eq!(picky.ended, 1, "one sub-step was committed before the failure");
    assert!(
        matches!(rep.failure, Some(StepFailure::NonFiniteForce { .. })),
        "{rep:?}"
    );
    assert_eq!(rep.substeps, 0);
    assert!(!rep.converged);
    assert_eq!(bits(&state), bits(&s.state), "state rolled back");
    assert_eq!(
        force(&picky.inner, H, &s.state.u),
        force(&s.model, H, &s.state.u),
        "Prony history rolled back"
    );

    // Bad input is not retried.
    let mut bad = s.state.clone();
    bad.u[1].x = f64::NAN;
    let rep = euler.step(&mut bad, &mut picky, &s.loads, &s.fixed);
    assert_eq!(rep.failure, Some(StepFailure::BadState));
}

#[test]
fn max_halvings_is_validated_and_read_from_toml() {
    let p: ImplicitEulerParams = toml::from_str("dt = 0.01\nmax_halvings = 4\n").unwrap();
    assert_eq!(p.max_halvings, 4);
    p.validate().unwrap();
    let bad = ImplicitEulerParams {
        max_halvings: nvtmm::solver::MAX_HALVINGS + 1,
        ..ImplicitEulerParams::default()
    };
    let err = bad.validate().unwrap_err();
    assert!(err.contains("max_halvings"), "{err}");
}
