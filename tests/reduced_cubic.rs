//! The cubic reduced StVK model (`reduced::cubic`) is exact: its force and
//! tangent equal the full NVTMM's projected through the basis at large
//! displacements; its dynamics follow the full implicit Euler under a large
//! load better than the linear reduced model; its step allocates nothing and
//! refuses bad input without touching the state.

mod common;

use common::counting::count_allocations;
use nalgebra::{DMatrix, DVector, SMatrix, SVector};
use nvtmm::material::Material;
use nvtmm::math::Vec3;
use nvtmm::mesh::TetMesh;
use nvtmm::model::nvtmm::Nvtmm;
use nvtmm::model::{BlockTangent, ForceModel};
use nvtmm::reduced::cubic::{CubicReducedDynamics, CubicStepError, CubicStvk};
use nvtmm::reduced::derivatives::with_modal_derivatives;
use nvtmm::reduced::{basis_rows, BasisParams, DynamicsParams, ModalBasis, ReducedDynamics};
use nvtmm::solver::loads::{Loads, NodalLoad, TimeProfile};
use nvtmm::solver::{ImplicitEuler, ImplicitEulerParams, LinearSolverKind, NewtonParams, TissueState};
use std::sync::Arc;

#[global_allocator]
static GLOBAL: common::counting::Counting = common::counting::Counting;

/// A 15 × 5 × 5 mm cantilever (6 × 2 × 2 cubes), clamped at x = 0.
struct Beam {
    mesh: TetMesh,
    model: Nvtmm,
    mass: Vec<f64>,
    fixed: Vec<u32>,
    tip: Vec<u32>,
}

fn beam() -> Beam {
    let mesh = common::block(6, 2, 2, 2.5e-3);
    let mat = Material::aorta();
    let model = Nvtmm::new(&mesh, &mat);
    let mass = mesh.lumped_mass(mat.density);
    let fixed = mesh.node_set("x_min").expect("x_min").to_vec();
    let tip = mesh.node_set("x_max").expect("x_max").to_vec();
    Beam {
        mesh,
        model,
        mass,
        fixed,
        tip,
    }
}

fn modes(b: &Beam, r: usize) -> ModalBasis {
    let u0 = vec![Vec3::zeros(); b.mesh.num_nodes()];
    ModalBasis::compute(&nvtmm::reduced::BasisSpec {
        stiffness: nvtmm::reduced::Stiffness::Model {
            mesh: &b.mesh,
            model: &b.model,
            u: &u0,
        },
        mass: &b.mass,
        fixed: &b.fixed,
        r,
        statics: nvtmm::reduced::Statics::None,
        warm: None,
        params: nvtmm::reduced::BasisParams::default(),
    })
    .expect("basis")
}

fn flat(v: &[Vec3]) -> DVector<f64> {
    DVector::from_iterator(3 * v.len(), v.iter().flat_map(|x| [x.x, x.y, x.z]))
}

/// A random q scaled so the largest nodal displacement is `umax` (m).
fn random_q(basis: &ModalBasis, seed: u64, umax: f64) -> DVector<f64> {
    let mut rng = common::Rng::new(seed);
    let q = DVector::from_fn(basis.len(), |_, _| rng.next());
    let u = basis.expand(&q);
    let m = u.iter().map(|x| x.norm()).fold(0.0, f64::max);
    q * (umax / m)
}

#[test]
fn force_and_tangent_equal_the_projected_full_model_at_large_displacement() {
    let b = beam();
    let basis = modes(&b, 8);
    let cubic = CubicStvk::new(&b.mesh, &Material::aorta(), &basis).expect("cubic");
    let phi = &basis.phi;
    // Up to 5 mm on a 15 mm beam: far outside the linear range.
    for (seed, umax) in [(1, 1e-4), (2, 1e-3), (3, 3e-3), (4, 5e-3)] {
        let q = random_q(&basis, seed, umax);
        let (fr, kr) = cubic.eval_dyn(&q).expect("eval");
        let u = basis.expand(&q);
        let mut f = vec![Vec3::zeros(); u.len()];
        b.model.add_forces(&u, &mut f);
        let f_full = phi.transpose() * flat(&f);
        let err = (&fr - &f_full).norm() / f_full.norm();
        assert!(err <= 1e-10, "umax {umax}: force error {err:e}");

        let mut k = BlockTangent::zeros(&b.mesh);
        b.model.add_stiffness(&u, &mut k);
        let k_full = phi.transpose() * k.to_dense() * phi;
        let err = (&kr - &k_full).norm() / k_full.norm();
        assert!(err <= 1e-10, "umax {umax}: tangent error {err:e}");

        // Central differences of f_r: K_r = −∂f_r/∂q.
        let eps = 1e-6 * q.amax().max(1e-9);
        let mut k_fd = DMatrix::zeros(8, 8);
        for j in 0..8 {
            let mut qp = q.clone();
            let mut qm = q.clone();
            qp[j] += eps;
            qm[j] -= eps;
            let d = (cubic.eval_dyn(&qp).expect("eval").0 - cubic.eval_dyn(&qm).expect("eval").0) / (2.0 * eps);
            k_fd.set_column(j, &(-d));
        }
        let err = (&kr - &k_fd).norm() / kr.norm();
        assert!(err <= 1e-6, "umax {umax}: finite-difference tangent error {err:e}");

        // The energy is W(Φq) and its gradient is −f_r.
        let mut qs = SVector::<f64, 8>::zeros();
        qs.copy_from(&q);
        let w = cubic.energy(&qs).expect("energy");
        let w_full = b.model.energy(&u);
        assert!((w - w_full).abs() <= 1e-9 * w_full, "{w} vs {w_full}");
    }
}

#[test]
fn at_rest_the_polynomial_gives_no_force_and_the_eigenvalues() {
    let b = beam();
    let basis = modes(&b, 8);
    let cubic = CubicStvk::new(&b.mesh, &Material::aorta(), &basis).expect("cubic");
    let mut f = SVector::<f64, 8>::repeat(1.0);
    let mut k = SMatrix::<f64, 8, 8>::zeros();
    cubic.eval(&SVector::zeros(), &mut f, &mut k).expect("eval");
    assert_eq!(f.norm(), 0.0);
    let w2 = DMatrix::from_diagonal(&DVector::from_column_slice(&basis.omega2));
    let err = (DMatrix::from_fn(8, 8, |i, j| k[(i, j)]) - &w2).norm() / w2.norm();
    assert!(err <= 1e-9, "K_r(0) vs diag(ω²): {err:e}");
    assert_eq!(cubic.rest_stiffness(), DMatrix::from_fn(8, 8, |i, j| k[(i, j)]));
}

/// Tip displacement histories (z) of the full NVTMM (converged implicit
/// Euler), the linear reduced and the cubic reduced model under a tip load
/// ramped to `force` (N, −z) over 50 ms and held to 150 ms.
fn tip_histories(b: &Beam, basis: &ModalBasis, force: f64) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let params = DynamicsParams {
        dt: 1e-3,
        alpha: 20.0,
        beta: 1e-4,
    };
    let steps = 150;
    let per = Vec3::new(0.0, 0.0, -force / b.tip.len() as f64);
    let loads = Loads {
        nodal: vec![NodalLoad {
            nodes: b.tip.clone(),
            force: per,
            profile: TimeProfile::Ramp { t0: 0.0, t1: 0.05 },
        }],
        gravity: Vec3::zeros(),
        pressure: None,
    };
    let full_params = ImplicitEulerParams {
        dt: params.dt,
        rayleigh_alpha: params.alpha,
        rayleigh_beta: params.beta,
        newton: NewtonParams {
            max_iters: 10,
            rel_tol: 1e-10,
            ..NewtonParams::default()
        },
        linear: LinearSolverKind::Cholesky,
        stiffness_every: 1,
        max_halvings: 0,
    };
    let mut ie = ImplicitEuler::new(&b.mesh, b.mass.clone(), full_params).expect("integrator");
    let mut state = TissueState::at_rest(b.mesh.num_nodes());
    let mut model = b.model.clone();
    let probe = b.tip[b.tip.len() / 2];
    let mut full = Vec::new();
    for _ in 0..steps {
        let rep = ie.step(&mut state, &mut model, &loads, &b.fixed);
        assert!(rep.ok(), "{:?}", rep.failure);
        full.push(state.u[probe as usize].z);
    }
    let mut lin = ReducedDynamics::<16>::new(basis, &params).expect("linear");
    let rows = basis_rows::<16>(basis).expect("rows");
    let cubic = Arc::new(CubicStvk::new(&b.mesh, &Material::aorta(), basis).expect("cubic"));
    let mut cub = CubicReducedDynamics::<16>::new(cubic, rows, &params, 3).expect("cubic dynamics");
    let (mut l, mut c) = (Vec::new(), Vec::new());
    for n in 1..=steps {
        let s = (n as f64 * params.dt / 0.05).min(1.0);
        let nodal: Vec<(u32, Vec3)> = b.tip.iter().map(|&i| (i, per * s)).collect();
        let f = lin.project_nodal(&nodal).expect("nodes");
        lin.step(&f);
        cub.step(&f).expect("cubic step");
        l.push(lin.displacement_at(probe).expect("node").z);
        c.push(cub.displacement_at(probe).expect("node").z);
    }
    (full, l, c)
}

fn rms_error(a: &[f64], reference: &[f64]) -> f64 {
    let e: f64 = a.iter().zip(reference).map(|(x, y)| (x - y).powi(2)).sum();
    let n: f64 = reference.iter().map(|y| y * y).sum();
    (e / n).sqrt()
}

/// The beam's basis for the dynamics tests: 6 columns (3 static modes at
/// the tip), enriched with modal derivatives of all 6 to 16 columns.
fn derivative_basis(b: &Beam) -> ModalBasis {
    let u0 = vec![Vec3::zeros(); b.mesh.num_nodes()];
    let basis = ModalBasis::compute(&nvtmm::reduced::BasisSpec {
        stiffness: nvtmm::reduced::Stiffness::Model {
            mesh: &b.mesh,
            model: &b.model,
            u: &u0,
        },
        mass: &b.mass,
        fixed: &b.fixed,
        r: 6,
        statics: nvtmm::reduced::Statics::Compressed {
            contact: &b.tip,
            max_static: 3,
        },
        warm: None,
        params: BasisParams::default(),
    })
    .expect("basis");
    with_modal_derivatives(&b.mesh, &b.model, &b.mass, &basis, 6, 16).expect("derivatives")
}

#[test]
fn cubic_dynamics_follow_the_full_model_better_than_the_linear_one_under_a_large_load() {
    // 0.05 N on the tip: the full model deflects it 5.3 mm, a third of the
    // beam's length. Same basis for both reduced models (r = 16).
    let b = beam();
    let basis = derivative_basis(&b);
    assert_eq!(basis.len(), 16);
    // The enriched basis is again M-orthonormal with diagonal ΦᵀK(0)Φ.
    let m = DMatrix::from_diagonal(&DVector::from_iterator(
        3 * b.mass.len(),
        b.mass.iter().flat_map(|&m| [m, m, m]),
    ));
    let gram = basis.phi.transpose() * m * &basis.phi;
    assert!((gram - DMatrix::<f64>::identity(16, 16)).amax() < 1e-10);
    let cubic = CubicStvk::new(&b.mesh, &Material::aorta(), &basis).expect("cubic");
    let k1 = cubic.rest_stiffness();
    let w2 = DMatrix::from_diagonal(&DVector::from_column_slice(&basis.omega2));
    assert!((k1 - &w2).norm() <= 1e-9 * w2.norm());
    let (full, lin, cub) = tip_histories(&b, &basis, 0.05);
    let (e_lin, e_cub) = (rms_error(&lin, &full), rms_error(&cub, &full));
    assert!(full.last().copied().unwrap_or(0.0) < -5e-3, "{:?}", full.last());
    // Measured: linear 11 %, cubic 0.5 %.
    assert!(e_lin > 0.05, "linear error {e_lin}");
    assert!(e_cub < 0.02 && e_cub < 0.2 * e_lin, "cubic {e_cub} vs linear {e_lin}");
    // Without the derivatives the exact polynomial locks (too stiff): the
    // reason the enrichment exists.
    let u0 = vec![Vec3::zeros(); b.mesh.num_nodes()];
    let plain = ModalBasis::compute(&nvtmm::reduced::BasisSpec {
        stiffness: nvtmm::reduced::Stiffness::Model {
            mesh: &b.mesh,
            model: &b.model,
            u: &u0,
        },
        mass: &b.mass,
        fixed: &b.fixed,
        r: 16,
        statics: nvtmm::reduced::Statics::Compressed {
            contact: &b.tip,
            max_static: 8,
        },
        warm: None,
        params: BasisParams::default(),
    })
    .expect("basis");
    let (full, _, cub) = tip_histories(&b, &plain, 0.05);
    assert!(rms_error(&cub, &full) > 0.3, "{}", rms_error(&cub, &full));
}

#[test]
fn cubic_step_allocates_nothing() {
    let b = beam();
    let basis = derivative_basis(&b);
    let params = DynamicsParams {
        dt: 1e-3,
        alpha: 5.0,
        beta: 1e-4,
    };
    let mut d = Box::new(
        CubicReducedDynamics::<16>::from_basis(&b.mesh, &Material::aorta(), &basis, &params).expect("dynamics"),
    );
    let node = b.tip[0];
    let mut kc = Box::new(SMatrix::<f64, 16, 16>::zeros());
    let mut failures = 0;
    let mut moved = 0.0;
    let ((), count) = count_allocations(|| {
        for i in 0..1000 {
            let f = match d.project_nodal(&[(node, Vec3::new(0.0, 0.0, -0.01))]) {
                Ok(f) => f,
                Err(_) => break,
            };
            let res = if i % 2 == 0 {
                d.step(&f)
            } else if let Some(rows) = d.rows_at(node) {
                let nr = rows.tr_mul(&Vec3::new(0.0, 0.0, 1.0));
                *kc = nr * nr.transpose() * 10.0;
                d.step_with_contact(&f, &kc)
            } else {
                Ok(())
            };
            if res.is_err() {
                failures += 1;
            }
            moved += d.displacement_at(node).map_or(0.0, |x| x.norm());
        }
    });
    assert_eq!(failures, 0);
    assert!(moved > 0.0);
    assert_eq!(count, 0, "{count} allocations in 1000 cubic steps");
}

#[test]
fn bad_input_leaves_the_state_unchanged_and_is_reported() {
    let b = beam();
    let basis = modes(&b, 6);
    let params = DynamicsParams {
        dt: 1e-3,
        alpha: 5.0,
        beta: 1e-4,
    };
    let mut d = CubicReducedDynamics::<8>::from_basis(&b.mesh, &Material::aorta(), &basis, &params).expect("dynamics");
    let f = d
        .project_nodal(&[(b.tip[0], Vec3::new(0.0, 0.0, -0.01))])
        .expect("node");
    for _ in 0..20 {
        d.step(&f).expect("step");
    }
    let (q, qd) = (*d.q(), *d.qd());
    assert!(q.norm() > 0.0);
    let mut bad = f;
    bad[2] = f64::NAN;
    assert_eq!(d.step(&bad), Err(CubicStepError::NonFiniteInput));
    assert_eq!((d.q(), d.qd()), (&q, &qd));
    let mut kc = SMatrix::<f64, 8, 8>::zeros();
    kc[(0, 0)] = f64::INFINITY;
    assert_eq!(d.step_with_contact(&f, &kc), Err(CubicStepError::NonFiniteInput));
    // A strongly negative "contact" makes the Newton matrix indefinite.
    kc[(0, 0)] = -1e12;
    assert_eq!(
        d.step_with_contact(&f, &kc),
        Err(CubicStepError::NotPositiveDefinite { newton_iter: 0 })
    );
    // A force so large the iterate runs away to infinity or an indefinite
    // tangent: refused, never NaN.
    let huge = f * 1e300;
    assert!(d.step(&huge).is_err());
    assert_eq!((d.q(), d.qd()), (&q, &qd));
    // Entries beyond the active size are ignored, also when NaN.
    let mut padded = f;
    padded[7] = f64::NAN;
    d.step(&padded).expect("inactive entries ignored");
    assert!(d.q().iter().all(|v| v.is_finite()) && d.q()[7] == 0.0);
    // Bad parameters are construction errors.
    let rows = basis_rows::<8>(&basis).expect("rows");
    let cubic = d.cubic().clone();
    assert!(CubicReducedDynamics::<8>::new(cubic.clone(), rows.clone(), &params, 0).is_err());
    assert!(
        CubicReducedDynamics::<8>::new(cubic.clone(), rows.clone(), &DynamicsParams { dt: -1.0, ..params }, 2).is_err()
    );
    assert!(CubicReducedDynamics::<4>::new(cubic, basis_rows::<4>(&modes(&b, 4)).expect("rows"), &params, 2).is_err());
}
