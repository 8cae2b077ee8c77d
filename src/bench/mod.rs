//! Every benchmark in one place: step timing on the built-in arch
//! (`nvtmm bench step`, here), the stability sweep over extreme parameters
//! ([`extremes`], `nvtmm bench extremes`), the reduced model's timings
//! ([`reduced`], `nvtmm bench reduced`) and a timing harness for implicit
//! steps ([`timing`]) and the guidewire's step against its node count
//! ([`wire`], `nvtmm bench wire`), and the whole guidewire tick in the
//! branched arch ([`wire_tick`], `nvtmm bench wire --tick`), and the
//! coupled step of a wire inside a catheter ([`coaxial`], `nvtmm bench
//! wire --coaxial`), and the whole tick with that pair in the branched
//! arch ([`coaxial_tick`], `nvtmm bench wire --tick --coaxial`). The scripts in `tools/` call these commands.
//!
//! The *standard load* is what every timing here uses: the built-in arch with
//! both ends fixed (`inlet`, `outlet_descending`) and a 0.15 N force pressing
//! the outer wall at the top of the arch down, spread over the outer-wall
//! nodes within 5 mm of the top (a probe's footprint), ramped in over 20 ms; implicit Euler at dt = 1 ms, one Newton iteration (SOFA's linearised
//! step), block IC(0)-preconditioned CG to 1e-6.

pub mod coaxial;
pub mod coaxial_tick;
pub mod contact;
pub mod extremes;
pub mod reduced;
pub mod timing;
pub mod wire;
pub mod wire_tick;

use crate::material::{Law, Material, PronyTerm};
use crate::math::Vec3;
use crate::mesh::arch::{generate, Arch, ArchParams};
use crate::model::factory::build_model;
use crate::model::ModelKind;
use crate::solver::loads::{Loads, NodalLoad, TimeProfile};
use crate::solver::{ImplicitEuler, ImplicitEulerParams, LinearSolverKind, NewtonParams, Preconditioner, TissueState};
pub use extremes::{extremes_cases, extremes_markdown, run_extreme, run_extreme_with, ExtremeCase, ExtremeResult};
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
        pressure: None,
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
        // Block IC(0)-CG to 1e-6: the benchmarks' and experiments' reference
        // solve (no factor to keep, so the same at every mesh size; the CLI's
        // --linear overrides it). It is not the fastest: the service's
        // background solve ships `cholesky_pcg`, about 4 times faster at
        // 5832 nodes (docs/BENCHMARKS.md, the background solver's table).
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
