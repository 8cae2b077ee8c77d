//! Measures the implicit-step linear solvers on the built-in aortic arch with
//! a linear elasticity stiffness assembled here from the mesh's shape
//! gradients (the real models live elsewhere). Not a test: numbers go to
//! `docs/SOLVERS.md`.
//!
//! `cargo run --release --example solver_bench [nodes] [E_Pa]`

use nvtmm::bench::timing::time_steps;
use nvtmm::math::Mat3;
use nvtmm::math::Vec3;
use nvtmm::mesh::arch::{generate, ArchParams};
use nvtmm::mesh::TetMesh;
use nvtmm::model::{tet_pair_edges, BlockTangent, ForceModel};
use nvtmm::solver::linear::{project_fixed, BlockRows, Cg, CholeskySolver};
use nvtmm::solver::loads::{Loads, NodalLoad, TimeProfile};
use nvtmm::solver::{ImplicitEuler, ImplicitEulerParams, LinearSolverKind, NewtonParams, Preconditioner, TissueState};
use std::time::Instant;

/// Small-strain linear elasticity, K assembled once: f = −K u.
struct LinearElastic {
    k: BlockTangent,
}

impl LinearElastic {
    fn new(mesh: &TetMesh, e: f64, nu: f64) -> LinearElastic {
        let lambda = nu * e / ((1.0 + nu) * (1.0 - 2.0 * nu));
        let mu = e / (2.0 * (1.0 + nu));
        let mut k = BlockTangent::zeros(mesh);
        let pairs = tet_pair_edges(mesh);
        for (t, tet) in mesh.tets().iter().enumerate() {
            let g = &mesh.grads()[t];
            let v = mesh.volumes()[t];
            for (a, (&na, ga)) in tet.iter().zip(g).enumerate() {
                for (b, (&nb, gb)) in tet.iter().zip(g).enumerate() {
                    // K_ab = V [λ g_a g_bᵀ + μ g_b g_aᵀ + μ (g_a·g_b) I]
                    let kab = (ga * gb.transpose() * lambda
                        + gb * ga.transpose() * mu
                        + Mat3::identity() * (mu * ga.dot(gb)))
                        * v;
                    if a == b || na < nb {
                        k.add_block(na, nb, pairs[t][a][b], &kab);
                    }
                }
            }
        }
        LinearElastic { k }
    }
}

impl ForceModel for LinearElastic {
    fn name(&self) -> &'static str {
        "bench-linear-elastic"
    }
    fn add_forces(&self, u: &[Vec3], out: &mut [Vec3]) {
        let mut ku = vec![Vec3::zeros(); u.len()];
        self.k.mul(u, &mut ku);
        out.iter_mut().zip(&ku).for_each(|(o, x)| *o -= x);
    }
    fn add_df(&self, _u: &[Vec3], du: &[Vec3], out: &mut [Vec3]) {
        let mut ku = vec![Vec3::zeros(); du.len()];
        self.k.mul(du, &mut ku);
        out.iter_mut().zip(&ku).for_each(|(o, x)| *o -= x);
    }
    fn add_stiffness(&self, _u: &[Vec3], k: &mut BlockTangent) {
        k.add_scaled(1.0, &self.k);
    }
    fn energy(&self, u: &[Vec3]) -> f64 {
        let mut ku = vec![Vec3::zeros(); u.len()];
        self.k.mul(u, &mut ku);
        0.5 * u.iter().zip(&ku).map(|(a, b)| a.dot(b)).sum::<f64>()
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn ms(s: f64) -> String {
    format!("{:.3}", s * 1e3)
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let nodes: usize = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(5832);
    let young: f64 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(1e6);
    let arch = match generate(&ArchParams::default(), nodes) {
        Ok(a) => a,
        Err(e) => {
            eprintln!("arch: {e}");
            std::process::exit(1);
        }
    };
    let mesh = &arch.mesh;
    let n = mesh.num_nodes();
    let (rho, nu) = (1100.0, 0.45);
    let mass = mesh.lumped_mass(rho);
    let model = LinearElastic::new(mesh, young, nu);
    let mut fixed: Vec<u32> = Vec::new();
    for set in ["inlet", "outlet_descending"] {
        fixed.extend_from_slice(mesh.node_set(set).unwrap_or(&[]));
    }
    let mut mask = vec![false; n];
    for &i in &fixed {
        mask[i as usize] = true;
    }
    println!(
        "arch: {n} nodes, {} tets, {} edges, {} DOF, {} fixed nodes; E = {young:e} Pa, nu = {nu}, rho = {rho}",
        mesh.tets().len(),
        mesh.edges().len(),
        3 * n,
        fixed.len()
    );

    // Mat-vec variants.
    let x: Vec<Vec3> = (0..n).map(|i| Vec3::new(i as f64, 1.0, -(i as f64).sqrt())).collect();
    let mut y = vec![Vec3::zeros(); n];
    let rows = BlockRows::new(n, &model.k.edges);
    let reps = 300;
    for (name, f) in [
        ("edge scatter (BlockTangent::mul)", 0),
        ("row gather, serial", 1),
        ("row gather, rayon", 2),
    ] {
        let t = Instant::now();
        for _ in 0..reps {
            match f {
                0 => model.k.mul(&x, &mut y),
                1 => rows.mul(&model.k, &x, &mut y, false),
                _ => rows.mul(&model.k, &x, &mut y, true),
            }
        }
        println!("mat-vec {name}: {} ms", ms(t.elapsed().as_secs_f64() / reps as f64));
    }

    for h in [1e-3, 1e-2] {
        // A = M + h² K (no damping), fixed rows projected; b = the first
        // Newton right-hand side of a step under a nodal load from rest.
        let mut a = model.k.clone();
        for (d, m) in a.diag.iter_mut().zip(&mass) {
            *d = *d * (h * h) + Mat3::identity() * *m;
        }
        a.off.iter_mut().for_each(|o| *o *= h * h);
        project_fixed(&mut a, &mask);
        let wall = mesh.node_set("outer_wall").unwrap_or(&[]);
        let mut b = vec![Vec3::zeros(); n];
        for (k, &i) in wall.iter().enumerate() {
            if k % 7 == 0 && !mask[i as usize] {
                b[i as usize] = Vec3::new(0.0, 0.0, -h * 0.01);
            }
        }
        println!("\nh = {} ms:", h * 1e3);
        println!("| solver | iterations | time per solve (ms) |");
        println!("|---|---|---|");
        for precond in [
            Preconditioner::None,
            Preconditioner::Jacobi,
            Preconditioner::BlockJacobi,
            Preconditioner::BlockSsor,
            Preconditioner::BlockIc0,
        ] {
            for parallel in [false, true] {
                let mut cg = Cg::new(&a, precond, 1e-8, 10_000, true);
                cg.parallel = parallel;
                let mut times = Vec::new();
                let mut iters = 0;
                for _ in 0..7 {
                    let mut xs = vec![Vec3::zeros(); n];
                    let t = Instant::now();
                    match cg.solve(&a, &b, &mut xs) {
                        Ok(s) => iters = s.iters,
                        Err(e) => println!("{precond:?}: {e}"),
                    }
                    times.push(t.elapsed().as_secs_f64());
                }
                let shift = if cg.ic0_shift() > 0.0 {
                    format!(" (shift {})", cg.ic0_shift())
                } else {
                    String::new()
                };
                println!(
                    "| CG {precond:?}{shift}{} tol 1e-8 cold | {iters} | {} |",
                    if parallel { " (rayon mat-vec)" } else { "" },
                    ms(median(times))
                );
            }
        }
        let t = Instant::now();
        let mut ch = match CholeskySolver::new(&a) {
            Ok(c) => c,
            Err(e) => {
                println!("cholesky: {e}");
                return;
            }
        };
        let symbolic = t.elapsed().as_secs_f64();
        let mut times = Vec::new();
        let mut xs = vec![Vec3::zeros(); n];
        for _ in 0..7 {
            let t = Instant::now();
            if let Err(e) = ch.solve(&a, &b, &mut xs) {
                println!("cholesky: {e}");
            }
            times.push(t.elapsed().as_secs_f64());
        }
        println!(
            "| Cholesky (symbolic {} ms once, L nnz {}) factor + solve | - | {} |",
            ms(symbolic),
            ch.factor_nnz(),
            ms(median(times))
        );
    }

    // Whole steps, linear model (one Newton iteration is exact; a second
    // residual evaluation confirms it), a sine load on part of the outer wall.
    let wall: Vec<u32> = mesh
        .node_set("outer_wall")
        .unwrap_or(&[])
        .iter()
        .copied()
        .filter(|i| !mask[*i as usize])
        .step_by(7)
        .collect();
    let loads = Loads {
        nodal: vec![NodalLoad {
            nodes: wall,
            force: Vec3::new(0.0, 0.0, -0.01),
            profile: TimeProfile::Sine {
                freq_hz: 5.0,
                phase: 0.0,
            },
        }],
        gravity: Vec3::zeros(),
        pressure: None,
    };
    println!("\nwhole steps (100 steps, h = 1 ms, Newton max 1 iteration, warm-started CG):");
    println!("| solver | mean CG iterations | mean step (ms) |");
    println!("|---|---|---|");
    for linear in [
        LinearSolverKind::Cg {
            precond: Preconditioner::Jacobi,
            tol: 1e-6,
            max_iter: 1000,
            strict: false,
        },
        LinearSolverKind::Cg {
            precond: Preconditioner::BlockJacobi,
            tol: 1e-6,
            max_iter: 1000,
            strict: false,
        },
        LinearSolverKind::Cg {
            precond: Preconditioner::BlockSsor,
            tol: 1e-6,
            max_iter: 1000,
            strict: false,
        },
        LinearSolverKind::Cg {
            precond: Preconditioner::BlockIc0,
            tol: 1e-6,
            max_iter: 1000,
            strict: false,
        },
        LinearSolverKind::Cholesky,
    ] {
        let params = ImplicitEulerParams {
            dt: 1e-3,
            rayleigh_alpha: 1.0,
            rayleigh_beta: 1e-4,
            newton: NewtonParams::linearized(),
            linear,
            ..ImplicitEulerParams::default()
        };
        let mut euler = match ImplicitEuler::new(mesh, mass.clone(), params) {
            Ok(e) => e,
            Err(e) => {
                println!("{e}");
                return;
            }
        };
        let mut model = LinearElastic { k: model.k.clone() };
        let mut state = TissueState::at_rest(n);
        let t = time_steps(&mut euler, &mut state, &mut model, &loads, &fixed, 100);
        if let Some(f) = &t.first_failure {
            println!("{linear:?}: {f}");
        }
        let name = match linear {
            LinearSolverKind::Cg { precond, tol, .. } => format!("CG {precond:?} tol {tol:e}"),
            LinearSolverKind::Cholesky => "Cholesky".into(),
            LinearSolverKind::CholeskyPcg { refactor_every, .. } => format!("Cholesky-PCG every {refactor_every}"),
        };
        println!(
            "| {name} | {:.1} | {} (median {}, max {}) |",
            t.mean_linear_iters,
            ms(t.mean_s),
            ms(t.median_s),
            ms(t.max_s)
        );
    }
}
