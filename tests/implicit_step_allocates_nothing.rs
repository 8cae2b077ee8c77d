//! After construction, `ImplicitEuler::step` allocates nothing with the
//! product's force models (NVTMM with Prony viscoelasticity, FEM StVK, FEM
//! Neo-Hookean), on the CG path with every preconditioner, on the sparse
//! Cholesky path and on Cholesky-PCG: the models size their buffers at
//! construction, and the background solver can run next to the RT loop
//! without touching the allocator.
//!
//! The models run their loops on rayon's pool. Rayon itself allocates when a
//! thread outside its pool hands it work (its global job queue grows by one
//! block per 63 jobs, i.e. about one allocation every second NVTMM step on
//! this mesh, measured with this test), and nothing when a pool thread does.
//! So the steps here run on a pool thread (`ThreadPool::install`), as a
//! caller that must not allocate has to run them (see docs/SOLVERS.md).

mod common;

use common::block;
use common::counting::count_allocations;
use nvtmm::material::{Law, Material, PronyTerm};
use nvtmm::math::Vec3;
use nvtmm::model::{fem::Fem, nvtmm::Nvtmm, viscoelastic::Viscoelastic, ForceModel};
use nvtmm::solver::loads::{Loads, NodalLoad, TimeProfile};
use nvtmm::solver::{ImplicitEuler, ImplicitEulerParams, LinearSolverKind, NewtonParams, Preconditioner, TissueState};

#[global_allocator]
static GLOBAL: common::counting::Counting = common::counting::Counting;

/// Builds one of the models under test.
type MakeModel<'a> = Box<dyn Fn() -> Box<dyn ForceModel> + 'a>;

#[test]
fn implicit_step_allocates_nothing() {
    // The counter itself works: one box is one allocation.
    assert_eq!(count_allocations(|| drop(std::hint::black_box(Box::new(1u8)))).1, 1);
    // 576 tets: several of FEM's 256-element chunks, so its parallel path runs.
    let mesh = block(6, 4, 4, 0.005);
    let fixed = mesh.node_set("x_min").unwrap().to_vec();
    let loads = Loads {
        nodal: vec![NodalLoad {
            nodes: mesh.node_set("x_max").unwrap().to_vec(),
            force: Vec3::new(0.05, 0.02, 0.0),
            profile: TimeProfile::Sine {
                freq_hz: 10.0,
                phase: 0.0,
            },
        }],
        gravity: Vec3::new(0.0, 0.0, -9.81),
        pressure: None,
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
    let material = Material::aorta();
    let pool = rayon::ThreadPoolBuilder::new().num_threads(2).build().unwrap();
    let prony = [PronyTerm { alpha: 0.3, tau: 0.01 }, PronyTerm { alpha: 0.2, tau: 0.5 }];
    let models: [(&str, MakeModel); 3] = [
        (
            "nvtmm+prony",
            Box::new(|| {
                Box::new(Viscoelastic::new(
                    Nvtmm::new(&mesh, &material),
                    &mesh,
                    &material,
                    Law::Stvk,
                    &prony,
                ))
            }),
        ),
        ("fem-stvk", Box::new(|| Box::new(Fem::new(&mesh, &material, Law::Stvk)))),
        (
            "fem-neohookean",
            Box::new(|| Box::new(Fem::new(&mesh, &material, Law::NeoHookean))),
        ),
    ];
    for ((linear, stiffness_every), (name, make)) in cases.iter().flat_map(|c| models.iter().map(move |m| (*c, m))) {
        let mut model = make();
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
        let (ok, count) = pool.install(|| {
            count_allocations(|| {
                let mut ok = true;
                for _ in 0..20 {
                    ok &= euler.step(&mut state, model.as_mut(), &loads, &fixed).ok();
                }
                ok
            })
        });
        assert!(
            ok,
            "{name}, {linear:?}, stiffness_every {stiffness_every}: a step failed"
        );
        assert!(state.u.iter().any(|v| v.norm() > 0.0), "{name}: the load moved nothing");
        assert_eq!(
            count, 0,
            "{name}, {linear:?}, stiffness_every {stiffness_every}: step allocated"
        );
    }
}
