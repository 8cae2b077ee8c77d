//! Measurements users regenerate: step timing on the built-in arch
//! (`nvtmm bench step`) and the stability sweep over extreme parameters
//! (`nvtmm bench extremes`).
//!
//! The *standard load* is what every timing here uses: the built-in arch with
//! both ends fixed (`inlet`, `outlet_descending`) and a 0.15 N force pressing
//! the outer wall at the top of the arch down, spread over the outer-wall
//! nodes within 5 mm of the top (a probe's footprint), ramped in over 20 ms; implicit Euler at dt = 1 ms, one Newton iteration (SOFA's linearised
//! step), block IC(0)-preconditioned CG to 1e-6.

use crate::material::{Law, Material, PronyTerm};
use crate::mesh::arch::{generate, Arch, ArchParams};
use crate::mesh::block::block;
use crate::mesh::{TetMesh, Vec3};
use crate::model::ModelKind;
use crate::scene::build_model;
use crate::solver::loads::{Loads, NodalLoad, TimeProfile};
use crate::solver::{ImplicitEuler, ImplicitEulerParams, LinearSolverKind, NewtonParams, Preconditioner, TissueState};
use std::time::Instant;

/// The standard load on an arch: fixed nodes, loaded node and loads.
#[derive(Debug, Clone)]
pub struct StandardLoad {
    /// Fixed nodes (both vessel ends).
    pub fixed: Vec<u32>,
    /// The loaded outer-wall node at the arch top.
    pub node: u32,
    /// The loads.
    pub loads: Loads,
}

/// The outer-wall node at the top of the arch (highest z).
pub fn arch_top_node(arch: &Arch) -> u32 {
    let mesh = &arch.mesh;
    let outer = mesh.node_set("outer_wall").unwrap_or(&[]);
    outer
        .iter()
        .copied()
        .max_by(|&a, &b| mesh.rest()[a as usize].z.total_cmp(&mesh.rest()[b as usize].z))
        .unwrap_or(0)
}

/// Total force of the standard load (N): ≈ 3 mm of indentation at the arch
/// top, below the thin wall's local buckling on the finest meshes.
pub const STANDARD_FORCE_N: f64 = 0.15;

/// Radius of the probe patch of the standard load (m).
pub const PROBE_RADIUS_M: f64 = 5e-3;

/// The standard probe region of an arch: the outer-wall nodes within
/// [`PROBE_RADIUS_M`] of the arch top (the top node alone if none).
pub fn probe_region(arch: &Arch) -> Vec<u32> {
    let mesh = &arch.mesh;
    let node = arch_top_node(arch);
    let top = mesh.rest()[node as usize];
    let mut nodes: Vec<u32> = mesh
        .node_set("outer_wall")
        .unwrap_or(&[])
        .iter()
        .copied()
        .filter(|&i| (mesh.rest()[i as usize] - top).norm() <= PROBE_RADIUS_M)
        .collect();
    if nodes.is_empty() {
        nodes.push(node);
    }
    nodes
}

/// The standard load: a total force `force_n` (N) pushing the arch top down
/// (−z), shared equally by the outer-wall nodes within [`PROBE_RADIUS_M`] of
/// the top node (a probe's footprint, so the load converges under mesh
/// refinement, unlike a point force), ramped in over 20 ms.
pub fn standard_load(arch: &Arch, force_n: f64) -> StandardLoad {
    let mesh = &arch.mesh;
    let mut fixed: Vec<u32> = ["inlet", "outlet_descending"]
        .iter()
        .flat_map(|s| mesh.node_set(s).unwrap_or(&[]).to_vec())
        .collect();
    fixed.sort_unstable();
    fixed.dedup();
    let node = arch_top_node(arch);
    let patch = probe_region(arch);
    let per = Vec3::new(0.0, 0.0, -force_n) / patch.len() as f64;
    let loads = Loads {
        nodal: vec![NodalLoad {
            nodes: patch,
            force: per,
            profile: TimeProfile::Ramp { t0: 0.0, t1: 0.02 },
        }],
        gravity: Vec3::zeros(),
    };
    StandardLoad { fixed, node, loads }
}

/// The integrator settings of the standard benchmark.
pub fn standard_params() -> ImplicitEulerParams {
    ImplicitEulerParams {
        dt: 1e-3,
        rayleigh_alpha: 0.0,
        rayleigh_beta: 1e-3,
        newton: NewtonParams::linearized(),
        // Block IC(0)-CG: the fastest exact solver here at 5832 nodes, measured
        // side by side with Cholesky and block-Jacobi (docs/BENCHMARKS.md).
        linear: LinearSolverKind::Cg {
            precond: Preconditioner::BlockIc0,
            tol: 1e-6,
            max_iter: 1000,
            strict: false,
        },
        stiffness_every: 1,
        max_halvings: 0,
    }
}

/// Result of `nvtmm bench step` (JSON keys are a scripting contract).
#[derive(Debug, Clone, serde::Serialize)]
pub struct StepBench {
    /// Model name.
    pub model: String,
    /// Law name.
    pub law: String,
    /// Nodes.
    pub nodes: usize,
    /// Tets.
    pub tets: usize,
    /// Steps timed.
    pub steps: usize,
    /// Median wall time per full implicit step (ms).
    pub ms_per_step: f64,
    /// 1000 / ms_per_step.
    pub steps_per_sec: f64,
    /// Mean wall time per step (ms): with `stiffness_every` > 1 the refresh
    /// steps are slower than the median one, and 1000 / mean is the
    /// sustained rate.
    pub mean_ms_per_step: f64,
    /// Slowest step (ms).
    pub max_ms_per_step: f64,
    /// Median CG iterations per step.
    pub cg_iters: usize,
    /// Linear solver used.
    pub linear: String,
    /// Tangent refresh interval (1: exact Newton every step).
    pub stiffness_every: usize,
    /// Whether the residual was re-evaluated after the last update.
    pub check_final_residual: bool,
    /// Model construction (precomputation) time (s).
    pub setup_s: f64,
    /// Displacement of the loaded node at the end (m).
    pub load_node_displacement_m: f64,
    /// Rayon threads used.
    pub threads: usize,
}

/// Errors of a benchmark.
#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    /// Bad argument.
    #[error("{0}")]
    Arg(String),
    /// A step failed.
    #[error("step {step} failed: {reason}")]
    Step {
        /// 1-based step.
        step: usize,
        /// Why.
        reason: String,
    },
}

/// Times `steps` full implicit steps of `kind` on the arch with `nodes` nodes
/// under the standard load (after 5 warm-up steps).
pub fn bench_step(
    kind: ModelKind,
    law: Law,
    nodes: usize,
    steps: usize,
    prony: &[PronyTerm],
    linear: LinearSolverKind,
) -> Result<StepBench, BenchError> {
    bench_step_lagged(kind, law, nodes, steps, prony, linear, 1)
}

/// [`bench_step`] with the tangent refreshed every `stiffness_every` steps
/// (`ImplicitEulerParams::stiffness_every`; 1 is exact Newton).
pub fn bench_step_lagged(
    kind: ModelKind,
    law: Law,
    nodes: usize,
    steps: usize,
    prony: &[PronyTerm],
    linear: LinearSolverKind,
    stiffness_every: usize,
) -> Result<StepBench, BenchError> {
    let params = ImplicitEulerParams {
        linear,
        stiffness_every,
        ..standard_params()
    };
    bench_step_params(kind, law, nodes, steps, prony, params)
}

/// [`bench_step`] with any integrator settings (the standard load's are
/// [`standard_params`]).
pub fn bench_step_params(
    kind: ModelKind,
    law: Law,
    nodes: usize,
    steps: usize,
    prony: &[PronyTerm],
    params: ImplicitEulerParams,
) -> Result<StepBench, BenchError> {
    let (linear, stiffness_every) = (params.linear, params.stiffness_every);
    if steps == 0 {
        return Err(BenchError::Arg("--steps must be at least 1".into()));
    }
    let arch = generate(&ArchParams::default(), nodes).map_err(|e| BenchError::Arg(e.to_string()))?;
    let mat = Material::aorta();
    let t0 = Instant::now();
    let mut model = build_model(kind, &arch.mesh, &mat, law, prony);
    let setup_s = t0.elapsed().as_secs_f64();
    let load = standard_load(&arch, STANDARD_FORCE_N);
    let mesh = &arch.mesh;
    let mut euler =
        ImplicitEuler::new(mesh, mesh.lumped_mass(mat.density), params).map_err(|e| BenchError::Arg(e.to_string()))?;
    let mut state = TissueState::at_rest(mesh.num_nodes());
    let mut times = Vec::with_capacity(steps);
    let mut iters = Vec::with_capacity(steps);
    for step in 1..=steps + 5 {
        let t = Instant::now();
        let rep = euler.step(&mut state, model.as_mut(), &load.loads, &load.fixed);
        let ms = t.elapsed().as_secs_f64() * 1e3;
        if let Some(f) = rep.failure {
            return Err(BenchError::Step {
                step,
                reason: f.to_string(),
            });
        }
        if step > 5 {
            times.push(ms);
            iters.push(rep.linear_iters);
        }
    }
    let mean = times.iter().sum::<f64>() / times.len() as f64;
    times.sort_by(f64::total_cmp);
    iters.sort_unstable();
    let ms = times[times.len() / 2];
    let max = times[times.len() - 1];
    Ok(StepBench {
        model: kind.name().into(),
        law: match law {
            Law::Stvk => "stvk".into(),
            Law::NeoHookean => "neo_hookean".into(),
        },
        nodes: mesh.num_nodes(),
        tets: mesh.tets().len(),
        steps,
        ms_per_step: ms,
        steps_per_sec: 1e3 / ms,
        mean_ms_per_step: mean,
        max_ms_per_step: max,
        cg_iters: iters[iters.len() / 2],
        linear: linear_name(&linear),
        stiffness_every,
        check_final_residual: params.newton.check_final_residual,
        setup_s,
        load_node_displacement_m: state.u[load.node as usize].norm(),
        threads: rayon::current_num_threads(),
    })
}

/// One case of the stability sweep.
#[derive(Debug, Clone, serde::Serialize)]
pub struct ExtremeCase {
    /// Model.
    pub model: String,
    /// Law.
    pub law: String,
    /// Young's modulus (Pa).
    pub youngs_pa: f64,
    /// Poisson ratio.
    pub poisson: f64,
    /// Time step (s).
    pub dt: f64,
    /// Prony terms (α, τ).
    pub prony: Vec<(f64, f64)>,
    /// Load, as a multiple of the force that strains the bar by 10% statically.
    pub load_factor: f64,
}

/// What happened in one case.
#[derive(Debug, Clone, serde::Serialize)]
pub struct ExtremeResult {
    /// The case.
    pub case: ExtremeCase,
    /// Steps attempted.
    pub steps: usize,
    /// Steps that advanced the state.
    pub ok_steps: usize,
    /// Steps that advanced but did not reach the Newton tolerance.
    pub unconverged: usize,
    /// First failure, if any (the state was kept unchanged).
    pub failure: Option<String>,
    /// Steps that were covered by halved sub-steps (`max_halvings` > 0).
    pub split_steps: usize,
    /// Whether any non-finite value was ever seen in the state (must be false).
    pub non_finite: bool,
    /// Largest displacement over the run relative to the bar length.
    pub max_rel_displacement: f64,
    /// Smallest det F over the elements at the end (< 0: inverted elements).
    pub min_det_f: f64,
}

/// The sweep the documentation reports: every model and law over ν, E, dt,
/// Prony τ ≪ dt and ≫ dt, Σα near 1 and loads that invert elements, on a
/// small clamped bar (a 4×2×2-cell block, 40 mm × 10 mm × 10 mm) pulled
/// sideways at its free end. `quick` keeps a representative subset.
pub fn extremes_cases(quick: bool) -> Vec<ExtremeCase> {
    let mut cases = Vec::new();
    let models: &[(ModelKind, Law)] = &[
        (ModelKind::Msm, Law::Stvk),
        (ModelKind::Tmm, Law::Stvk),
        (ModelKind::Nvtmm, Law::Stvk),
        (ModelKind::Fem, Law::Stvk),
        (ModelKind::Fem, Law::NeoHookean),
    ];
    let es: &[f64] = if quick { &[1e3, 1e7] } else { &[1e3, 65e3, 1e6, 1e7] };
    let nus: &[f64] = if quick { &[0.0, 0.499] } else { &[0.0, 0.3, 0.45, 0.499] };
    let dts: &[f64] = if quick { &[1e-4, 1e-2] } else { &[1e-4, 1e-3, 1e-2] };
    for &(m, law) in models {
        for &e in es {
            for &nu in nus {
                for &dt in dts {
                    cases.push(ExtremeCase {
                        model: m.name().into(),
                        law: law_name(law).into(),
                        youngs_pa: e,
                        poisson: nu,
                        dt,
                        prony: vec![],
                        load_factor: 1.0,
                    });
                }
            }
        }
        // Inverting loads.
        for &lf in if quick { &[20.0][..] } else { &[5.0, 20.0, 100.0][..] } {
            cases.push(ExtremeCase {
                model: m.name().into(),
                law: law_name(law).into(),
                youngs_pa: 65e3,
                poisson: 0.45,
                dt: 1e-3,
                prony: vec![],
                load_factor: lf,
            });
        }
    }
    // Viscoelastic extremes (NVTMM and FEM): τ ≪ dt, τ ≫ dt, Σα near 1.
    for (m, law) in [(ModelKind::Nvtmm, Law::Stvk), (ModelKind::Fem, Law::NeoHookean)] {
        for prony in [
            vec![(0.5, 1e-6)],
            vec![(0.5, 1e3)],
            vec![(0.6, 1e-3), (0.39, 0.1)],
            vec![(0.999, 0.05)],
        ] {
            for &dt in if quick { &[1e-3][..] } else { &[1e-4, 1e-2][..] } {
                cases.push(ExtremeCase {
                    model: m.name().into(),
                    law: law_name(law).into(),
                    youngs_pa: 65e3,
                    poisson: 0.45,
                    dt,
                    prony: prony.clone(),
                    load_factor: 1.0,
                });
            }
        }
        cases.push(ExtremeCase {
            model: m.name().into(),
            law: law_name(law).into(),
            youngs_pa: 65e3,
            poisson: 0.45,
            dt: 1e-3,
            prony: vec![(0.9, 0.01)],
            load_factor: 50.0,
        });
    }
    cases
}

fn law_name(l: Law) -> &'static str {
    match l {
        Law::Stvk => "stvk",
        Law::NeoHookean => "neo_hookean",
    }
}

/// Runs one case for `steps` steps (or 50 ms of simulated time, whichever
/// is shorter, at least 5 steps).
pub fn run_extreme(case: &ExtremeCase, steps: usize) -> ExtremeResult {
    run_extreme_with(case, steps, 0)
}

/// [`run_extreme`] with the integrator's step halving on failure
/// (`ImplicitEulerParams::max_halvings`).
pub fn run_extreme_with(case: &ExtremeCase, steps: usize, max_halvings: usize) -> ExtremeResult {
    let mesh: TetMesh = match block([4, 2, 2], [0.04, 0.01, 0.01]) {
        Ok(m) => m,
        Err(e) => {
            return ExtremeResult {
                case: case.clone(),
                steps: 0,
                ok_steps: 0,
                unconverged: 0,
                failure: Some(e.to_string()),
                split_steps: 0,
                non_finite: false,
                max_rel_displacement: 0.0,
                min_det_f: f64::NAN,
            }
        }
    };
    let kind: ModelKind = case.model.parse().unwrap_or(ModelKind::Nvtmm);
    let law = if case.law == "neo_hookean" {
        Law::NeoHookean
    } else {
        Law::Stvk
    };
    let mat = Material {
        youngs_pa: case.youngs_pa,
        poisson: case.poisson,
        density: 1050.0,
    };
    let prony: Vec<PronyTerm> = case
        .prony
        .iter()
        .map(|&(alpha, tau)| PronyTerm { alpha, tau })
        .collect();
    let mut model = build_model(kind, &mesh, &mat, law, &prony);
    let fixed = mesh.node_set("x_min").unwrap_or(&[]).to_vec();
    let tip = mesh.node_set("x_max").unwrap_or(&[]).to_vec();
    // A sideways tip force that bends the bar to ~10% strain statically, times the factor.
    let area = 1e-4;
    let total = case.load_factor * 0.1 * case.youngs_pa * area;
    let loads = Loads {
        nodal: vec![NodalLoad {
            nodes: tip.clone(),
            force: Vec3::new(-0.3 * total, 0.0, total) / tip.len().max(1) as f64,
            profile: TimeProfile::Ramp {
                t0: 0.0,
                t1: 10.0 * case.dt,
            },
        }],
        gravity: Vec3::zeros(),
    };
    let params = ImplicitEulerParams {
        dt: case.dt,
        rayleigh_alpha: 0.0,
        rayleigh_beta: 0.0,
        newton: NewtonParams {
            max_iters: 8,
            rel_tol: 1e-8,
            ..NewtonParams::default()
        },
        linear: LinearSolverKind::Cholesky,
        max_halvings,
        ..ImplicitEulerParams::default()
    };
    let mut res = ExtremeResult {
        case: case.clone(),
        steps: 0,
        ok_steps: 0,
        unconverged: 0,
        failure: None,
        split_steps: 0,
        non_finite: false,
        max_rel_displacement: 0.0,
        min_det_f: f64::NAN,
    };
    let mut euler = match ImplicitEuler::new(&mesh, mesh.lumped_mass(mat.density), params) {
        Ok(e) => e,
        Err(e) => {
            res.failure = Some(e.to_string());
            return res;
        }
    };
    let mut state = TissueState::at_rest(mesh.num_nodes());
    let n_steps = steps.min(((0.05 / case.dt).ceil() as usize).max(5));
    for _ in 0..n_steps {
        res.steps += 1;
        let before = state.clone();
        let rep = euler.step(&mut state, model.as_mut(), &loads, &fixed);
        if !state.is_finite() {
            res.non_finite = true;
        }
        if let Some(f) = rep.failure {
            if state != before {
                res.non_finite = true; // a failed step must leave the state unchanged
            }
            res.failure = Some(f.to_string());
            break;
        }
        res.ok_steps += 1;
        if rep.substeps > 1 {
            res.split_steps += 1;
        }
        if !rep.converged {
            res.unconverged += 1;
        }
        let m = state.u.iter().map(|u| u.norm()).fold(0.0, f64::max) / 0.04;
        res.max_rel_displacement = res.max_rel_displacement.max(m);
    }
    res.min_det_f = mesh
        .tets()
        .iter()
        .zip(mesh.grads())
        .map(|(tet, g)| {
            let mut f = crate::model::Mat3::identity();
            for k in 0..4 {
                f += state.u[tet[k] as usize] * g[k].transpose();
            }
            f.determinant()
        })
        .fold(f64::INFINITY, f64::min);
    res
}

/// The sweep as a Markdown table.
pub fn extremes_markdown(results: &[ExtremeResult]) -> String {
    let mut s = String::from("| model | law | E (Pa) | ν | dt (s) | Prony (α, τ) | load × | steps ok | split steps | unconverged | failure | NaN | max |u|/L | min det F |\n|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n");
    for r in results {
        let c = &r.case;
        let prony = if c.prony.is_empty() {
            "–".to_string()
        } else {
            c.prony
                .iter()
                .map(|(a, t)| format!("({a}, {t:e})"))
                .collect::<Vec<_>>()
                .join(" ")
        };
        s.push_str(&format!(
            "| {} | {} | {:e} | {} | {:e} | {} | {} | {}/{} | {} | {} | {} | {} | {:.3} | {:.3} |\n",
            c.model,
            c.law,
            c.youngs_pa,
            c.poisson,
            c.dt,
            prony,
            c.load_factor,
            r.ok_steps,
            r.steps,
            r.split_steps,
            r.unconverged,
            r.failure.as_deref().unwrap_or("–"),
            if r.non_finite { "**yes**" } else { "no" },
            r.max_rel_displacement,
            r.min_det_f
        ));
    }
    s
}

/// Short name of a linear solver setting (`cg-block_jacobi`, `cholesky`, …).
pub fn linear_name(l: &LinearSolverKind) -> String {
    match l {
        LinearSolverKind::Cg { precond, .. } => format!("cg-{}", precond_name(*precond)),
        LinearSolverKind::Cholesky => "cholesky".into(),
        LinearSolverKind::CholeskyPcg {
            refactor_every,
            factor_f32,
            ..
        } => format!("cholesky-pcg{}:{refactor_every}", if *factor_f32 { "32" } else { "" }),
    }
}

fn precond_name(p: Preconditioner) -> &'static str {
    match p {
        Preconditioner::None => "none",
        Preconditioner::Jacobi => "jacobi",
        Preconditioner::BlockJacobi => "block_jacobi",
        Preconditioner::BlockSsor => "block_ssor",
        Preconditioner::BlockIc0 => "block_ic0",
    }
}

/// Parses `cholesky`, `cholesky-pcg[:N]`, `cholesky-pcg32[:N]` (factor in
/// `f32`) or `cg-<precond>` (precond: none, jacobi, block_jacobi,
/// block_ssor, block_ic0) into the standard benchmark's linear solver.
pub fn parse_linear(s: &str) -> Result<LinearSolverKind, String> {
    let precond = match s {
        "cholesky" => return Ok(LinearSolverKind::Cholesky),
        s if s.starts_with("cholesky-pcg") => {
            let rest = s.strip_prefix("cholesky-pcg").unwrap_or("");
            let (factor_f32, rest) = match rest.strip_prefix("32") {
                Some(r) => (true, r),
                None => (false, rest),
            };
            let every = match rest {
                "" => 10,
                k => k.strip_prefix(':').and_then(|k| k.parse().ok()).ok_or_else(|| {
                    format!("--linear {s}: expected cholesky-pcg[32] or cholesky-pcg[32]:N (N ≥ 1)")
                })?,
            };
            let tol = match standard_params().linear {
                LinearSolverKind::Cg { tol, .. } => tol,
                _ => 1e-6,
            };
            let kind = LinearSolverKind::CholeskyPcg {
                tol,
                max_iter: 30,
                refactor_every: every,
                factor_f32,
            };
            kind.validate()?;
            return Ok(kind);
        }
        "cg" | "cg-block_jacobi" => Preconditioner::BlockJacobi,
        "cg-jacobi" => Preconditioner::Jacobi,
        "cg-none" => Preconditioner::None,
        "cg-block_ssor" => Preconditioner::BlockSsor,
        "cg-block_ic0" => Preconditioner::BlockIc0,
        _ => {
            return Err(format!(
                "--linear {s}: allowed cholesky, cholesky-pcg[:N], cholesky-pcg32[:N], cg-none, cg-jacobi, cg-block_jacobi, cg-block_ssor, cg-block_ic0"
            ))
        }
    };
    match standard_params().linear {
        LinearSolverKind::Cg {
            tol, max_iter, strict, ..
        } => Ok(LinearSolverKind::Cg {
            precond,
            tol,
            max_iter,
            strict,
        }),
        other => Ok(other),
    }
}
