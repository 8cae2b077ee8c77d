//! The speed-for-accuracy trade: time per step against error relative to a
//! converged reference, one knob at a time.
//!
//! Set-up: the benchmark's standard load ([`crate::bench::standard_load`],
//! a force pressing the arch top, ramped in over 20 ms), simulated to
//! T = 40 ms. The reference is NVTMM (StVK) on the same mesh with dt =
//! 0.25 ms, Newton to 1e-10 and Cholesky. Error metrics (documented in
//! docs/RESULTS.md):
//! - `err_load_disp`: |u_load(T) − u_ref(T)| / |u_ref(T)| at the loaded node;
//! - `err_rms_surface`: RMS over surface nodes of |u(T) − u_ref(T)|, divided
//!   by the RMS of |u_ref(T)| (same mesh only);
//! - `err_reaction`: |R(T) − R_ref(T)| / |R_ref(T)| for the support reaction
//!   R, the internal force summed over the fixed nodes (what the vessel's
//!   ends feel);
//! - for mesh resolution, the loaded-node displacement and the reaction
//!   against the finest mesh (the load sits at the same physical place on
//!   every mesh; RMS is not compared across meshes).
//!
//! Knobs: model (msm, tmm, nvtmm, fem), dt, Newton iterations, CG tolerance,
//! preconditioner or linear solver, and mesh resolution.
//!
//! The `background` rows measure the haptic service's background full solve
//! ([`background_rows`]): NVTMM with the service scene's Prony term and
//! integrator settings (one Newton iteration, Cholesky-PCG, no final
//! residual check) taking the long steps it takes in the service, against
//! a converged solve of the same model under the same load history (a
//! press, hold and release at the probe patch), over the whole history. Each row reports
//! the median wall time per step. The reduced model's knobs (r, contact
//! modes, region of interest) are measured by `nvtmm experiment reduced`
//! ([`super::reduced`]).

use super::plot::{line_plot, Series};
use super::ExperimentError;
use crate::bench::{standard_load, standard_params, STANDARD_FORCE_N};
use crate::material::{Law, Material, PronyTerm};
use crate::math::Vec3;
use crate::mesh::arch::{generate, Arch, ArchParams};
use crate::model::factory::build_model;
use crate::model::ModelKind;
use crate::solver::loads::{Loads, NodalLoad, TimeProfile};
use crate::solver::{ImplicitEuler, ImplicitEulerParams, LinearSolverKind, NewtonParams, Preconditioner, TissueState};
use plotters::style::RGBColor;
use std::io::Write;
use std::path::Path;
use std::time::Instant;

/// Simulated time at which errors are measured (s).
pub const T_END: f64 = 0.04;

/// One measured configuration.
#[derive(Debug, Clone, serde::Serialize)]
pub struct TradeRow {
    /// Which knob was varied.
    pub knob: String,
    /// Its value, as text.
    pub value: String,
    /// Model.
    pub model: String,
    /// Nodes of the mesh.
    pub nodes: usize,
    /// Median wall time per step (ms).
    pub ms_per_step: f64,
    /// Wall time to simulate one second (s): ms_per_step / dt.
    pub wall_per_sim_s: f64,
    /// Relative error of the loaded node's displacement.
    pub err_load_disp: f64,
    /// Relative RMS error of surface displacement (NaN across meshes).
    pub err_rms_surface: f64,
    /// Relative error of the support reaction (force on the fixed ends).
    pub err_reaction: f64,
}

struct Outcome {
    u: Vec<Vec3>,
    /// Support reaction at T: the internal force summed over the fixed nodes.
    reaction: Vec3,
    ms: f64,
}

fn run_one(arch: &Arch, kind: ModelKind, params: ImplicitEulerParams) -> Result<Outcome, ExperimentError> {
    let mesh = &arch.mesh;
    let mat = Material::aorta();
    let mut model = build_model(kind, mesh, &mat, Law::Stvk, &[]);
    let load = standard_load(arch, STANDARD_FORCE_N);
    let mut euler = ImplicitEuler::new(mesh, mesh.lumped_mass(mat.density), params)
        .map_err(|e| ExperimentError::Setup(e.to_string()))?;
    let mut state = TissueState::at_rest(mesh.num_nodes());
    let steps = (T_END / params.dt).round() as usize;
    let mut times = Vec::with_capacity(steps);
    for step in 1..=steps {
        let t0 = Instant::now();
        let rep = euler.step(&mut state, model.as_mut(), &load.loads, &load.fixed);
        times.push(t0.elapsed().as_secs_f64() * 1e3);
        if let Some(f) = rep.failure {
            return Err(ExperimentError::Step {
                model: kind.name().into(),
                step,
                reason: f.to_string(),
            });
        }
    }
    times.sort_by(f64::total_cmp);
    let mut f = vec![Vec3::zeros(); mesh.num_nodes()];
    model.add_forces(&state.u, &mut f);
    let reaction = load.fixed.iter().map(|&i| f[i as usize]).sum();
    Ok(Outcome {
        u: state.u,
        reaction,
        ms: times[times.len() / 2],
    })
}

fn push_failed(rows: &mut Vec<TradeRow>, knob: &str, value: String, kind: ModelKind, arch: &Arch, reason: String) {
    rows.push(TradeRow {
        knob: knob.into(),
        value: format!("{value} (failed: {reason})"),
        model: kind.name().into(),
        nodes: arch.mesh.num_nodes(),
        ms_per_step: f64::NAN,
        wall_per_sim_s: f64::NAN,
        err_load_disp: f64::NAN,
        err_rms_surface: f64::NAN,
        err_reaction: f64::NAN,
    });
}

fn reference_params() -> ImplicitEulerParams {
    ImplicitEulerParams {
        dt: 2.5e-4,
        newton: NewtonParams {
            max_iters: 8,
            rel_tol: 1e-10,
            ..NewtonParams::default()
        },
        linear: LinearSolverKind::Cholesky,
        ..standard_params()
    }
}

fn errors(arch: &Arch, u: &[Vec3], reference: &[Vec3]) -> (f64, f64) {
    let node = standard_load(arch, STANDARD_FORCE_N).node as usize;
    let e_load = (u[node] - reference[node]).norm() / reference[node].norm().max(1e-300);
    let surf = arch.mesh.surface_nodes();
    let num: f64 = surf
        .iter()
        .map(|&i| (u[i as usize] - reference[i as usize]).norm_squared())
        .sum();
    let den: f64 = surf.iter().map(|&i| reference[i as usize].norm_squared()).sum();
    (e_load, (num / den.max(1e-300)).sqrt())
}

/// Runs the study on an arch of `nodes` nodes (plus coarser and finer meshes
/// for the resolution knob) and writes `trade.csv`, `trade.png`, `trade.md`.
/// Returns the rows and the node count of the finest (reference) mesh.
pub fn run(out: &Path, quick: bool) -> Result<(Vec<TradeRow>, usize), ExperimentError> {
    std::fs::create_dir_all(out).map_err(|e| ExperimentError::io(out, e))?;
    let nodes = if quick { 300 } else { 1458 };
    let arch = generate(&ArchParams::default(), nodes).map_err(|e| ExperimentError::Setup(e.to_string()))?;
    let reference = run_one(&arch, ModelKind::Nvtmm, reference_params())?;
    let mut rows = Vec::new();
    // Runs one setting on the study mesh; a model that cannot take the step
    // is a result (a "failed" row), not an abort.
    let record =
        |rows: &mut Vec<TradeRow>, knob: &str, value: String, kind: ModelKind, p: ImplicitEulerParams| match run_one(
            &arch, kind, p,
        ) {
            Ok(o) => {
                let (el, er) = errors(&arch, &o.u, &reference.u);
                let ereac = (o.reaction - reference.reaction).norm() / reference.reaction.norm().max(1e-300);
                rows.push(TradeRow {
                    knob: knob.into(),
                    value,
                    model: kind.name().into(),
                    nodes: arch.mesh.num_nodes(),
                    ms_per_step: o.ms,
                    wall_per_sim_s: o.ms * 1e-3 / p.dt,
                    err_load_disp: el,
                    err_rms_surface: er,
                    err_reaction: ereac,
                });
                Ok(())
            }
            Err(ExperimentError::Step { reason, .. }) => {
                push_failed(rows, knob, value, kind, &arch, reason);
                Ok(())
            }
            Err(e) => Err(e),
        };
    let base = standard_params();
    // Model x dt.
    let dts: &[f64] = if quick {
        &[5e-4, 2e-3, 1e-2]
    } else {
        &[5e-4, 1e-3, 2e-3, 5e-3, 1e-2]
    };
    for kind in [ModelKind::Msm, ModelKind::Tmm, ModelKind::Nvtmm, ModelKind::Fem] {
        for &dt in dts {
            record(
                &mut rows,
                "dt",
                format!("{dt}"),
                kind,
                ImplicitEulerParams { dt, ..base },
            )?;
        }
    }
    // NVTMM: Newton iterations, CG tolerance, linear solver (dt = 1 ms).
    for iters in [1usize, 2, 4] {
        let newton = NewtonParams {
            max_iters: iters,
            rel_tol: 1e-10,
            ..NewtonParams::default()
        };
        record(
            &mut rows,
            "newton_iters",
            iters.to_string(),
            ModelKind::Nvtmm,
            ImplicitEulerParams { newton, ..base },
        )?;
    }
    let cg = |precond, tol| LinearSolverKind::Cg {
        precond,
        tol,
        max_iter: 5000,
        strict: false,
    };
    for tol in [1e-2, 1e-4, 1e-6, 1e-8] {
        let p = ImplicitEulerParams {
            linear: cg(Preconditioner::BlockJacobi, tol),
            ..base
        };
        record(&mut rows, "cg_tol", format!("{tol:e}"), ModelKind::Nvtmm, p)?;
    }
    for (name, linear) in [
        ("jacobi", cg(Preconditioner::Jacobi, 1e-6)),
        ("block_jacobi", cg(Preconditioner::BlockJacobi, 1e-6)),
        ("block_ssor", cg(Preconditioner::BlockSsor, 1e-6)),
        ("block_ic0", cg(Preconditioner::BlockIc0, 1e-6)),
        ("cholesky", LinearSolverKind::Cholesky),
        (
            "cholesky_pcg_3",
            LinearSolverKind::CholeskyPcg {
                tol: 1e-6,
                max_iter: 30,
                refactor_every: 3,
                factor_f32: false,
            },
        ),
        (
            "cholesky_pcg32_3",
            LinearSolverKind::CholeskyPcg {
                tol: 1e-6,
                max_iter: 30,
                refactor_every: 3,
                factor_f32: true,
            },
        ),
    ] {
        record(
            &mut rows,
            "linear_solver",
            name.into(),
            ModelKind::Nvtmm,
            ImplicitEulerParams { linear, ..base },
        )?;
    }
    // The service's background solve against a converged run of the same
    // load history.
    rows.extend(background_rows(&arch, quick)?);
    // Mesh resolution: loaded-node displacement against the finest mesh.
    let sizes: &[usize] = if quick {
        &[150, 300, 700]
    } else {
        &[300, 1458, 5832, 23328]
    };
    // Every mesh with the same (benchmark) settings, so the differences are
    // spatial; the finest mesh is the reference and gets no row.
    let mut runs = Vec::with_capacity(sizes.len());
    for &n in sizes {
        let a = generate(&ArchParams::default(), n).map_err(|e| ExperimentError::Setup(e.to_string()))?;
        match run_one(&a, ModelKind::Nvtmm, base) {
            Ok(o) => {
                let node = standard_load(&a, STANDARD_FORCE_N).node as usize;
                runs.push((a.mesh.num_nodes(), o.ms, o.u[node], o.reaction));
            }
            Err(ExperimentError::Step { reason, .. }) => push_failed(
                &mut rows,
                "mesh_nodes",
                a.mesh.num_nodes().to_string(),
                ModelKind::Nvtmm,
                &a,
                reason,
            ),
            Err(e) => return Err(e),
        }
    }
    if let Some(&(_, _, fine_disp, fine_reaction)) = runs.last() {
        for &(n, ms, disp, reaction) in &runs[..runs.len() - 1] {
            rows.push(TradeRow {
                knob: "mesh_nodes".into(),
                value: n.to_string(),
                model: "nvtmm".into(),
                nodes: n,
                ms_per_step: ms,
                wall_per_sim_s: ms * 1e-3 / base.dt,
                err_load_disp: (disp - fine_disp).norm() / fine_disp.norm().max(1e-300),
                err_rms_surface: f64::NAN,
                err_reaction: (reaction - fine_reaction).norm() / fine_reaction.norm().max(1e-300),
            });
        }
    }
    let finest_nodes = runs.last().map(|r| r.0).unwrap_or(0);

    let csv = out.join("trade.csv");
    let mut w = std::fs::File::create(&csv).map_err(|e| ExperimentError::io(&csv, e))?;
    writeln!(
        w,
        "knob,value,model,nodes,ms_per_step,wall_per_sim_s,err_load_disp,err_rms_surface,err_reaction"
    )
    .map_err(|e| ExperimentError::io(&csv, e))?;
    for r in &rows {
        writeln!(
            w,
            "{},{},{},{},{:.4},{:.4},{:.3e},{:.3e},{:.3e}",
            r.knob,
            r.value,
            r.model,
            r.nodes,
            r.ms_per_step,
            r.wall_per_sim_s,
            r.err_load_disp,
            r.err_rms_surface,
            r.err_reaction
        )
        .map_err(|e| ExperimentError::io(&csv, e))?;
    }
    let png = out.join("trade.png");
    plot(&rows, &png)?;
    let md = out.join("trade.md");
    std::fs::write(&md, markdown(&rows, finest_nodes)).map_err(|e| ExperimentError::io(&md, e))?;
    Ok((rows, finest_nodes))
}

/// The service scene's Prony term (`rt-config/scenes/arch_service.toml`).
pub const SERVICE_PRONY: [PronyTerm; 1] = [PronyTerm { alpha: 0.5, tau: 0.58 }];

/// Peak force of the background study's press (N): twice the benchmark's
/// standard load and 60 % of the largest contact force of the scripted hand
/// in `nvtmm run` (0.51 N at 5832 nodes, spread over up to 8 touched
/// nodes). On the 1458-node study mesh the probe patch is a single node,
/// and 0.5 N there buckles the wall under it (the converged reference's
/// tangent became indefinite 0.79 s into the press).
pub const BACKGROUND_FORCE_N: f64 = 0.3;

/// The background study's load history, in seconds: press (ramp in),
/// hold, release (ramp out), then rest; the service's hand script has the
/// same phases (`[interaction]` in `rt-config/nvtmm.toml`).
pub const BACKGROUND_PHASES_S: [f64; 4] = [1.0, 1.0, 1.0, 0.5];

/// The background full solve's integrator as the service scene sets it
/// (`rt-config/scenes/arch_service.toml`), at step `dt`.
pub fn service_params(dt: f64) -> ImplicitEulerParams {
    ImplicitEulerParams {
        dt,
        rayleigh_alpha: 0.0,
        rayleigh_beta: 1e-3,
        newton: NewtonParams {
            max_iters: 1,
            check_final_residual: false,
            ..NewtonParams::default()
        },
        linear: LinearSolverKind::CholeskyPcg {
            tol: 1e-6,
            max_iter: 15,
            refactor_every: 3,
            factor_f32: true,
        },
        stiffness_every: 1,
        max_halvings: 3,
    }
}

/// The press of the background study: [`BACKGROUND_FORCE_N`] along −z shared
/// by the probe patch, ramped in over the first phase, held, ramped out.
fn press_loads(arch: &Arch) -> Loads {
    let patch = crate::bench::probe_region(arch);
    let per = Vec3::new(0.0, 0.0, -BACKGROUND_FORCE_N) / patch.len() as f64;
    let [press, hold, release, _] = BACKGROUND_PHASES_S;
    Loads {
        nodal: vec![
            NodalLoad {
                nodes: patch.clone(),
                force: per,
                profile: TimeProfile::Ramp { t0: 0.0, t1: press },
            },
            NodalLoad {
                nodes: patch,
                force: -per,
                profile: TimeProfile::Ramp {
                    t0: press + hold,
                    t1: press + hold + release,
                },
            },
        ],
        gravity: Vec3::zeros(),
        pressure: None,
    }
}

/// Displacement and support reaction at the sample times of one run.
struct History {
    /// Per sample: the displacement field.
    u: Vec<Vec<Vec3>>,
    /// Per sample: the support reaction.
    reaction: Vec<Vec3>,
    /// Median wall time per step (ms).
    ms: f64,
}

/// Runs the press with `params`, sampling every `every` steps.
fn run_history(arch: &Arch, params: ImplicitEulerParams, every: usize) -> Result<History, ExperimentError> {
    let mesh = &arch.mesh;
    let mat = Material::aorta();
    let mut model = build_model(ModelKind::Nvtmm, mesh, &mat, Law::Stvk, &SERVICE_PRONY);
    let fixed = standard_load(arch, STANDARD_FORCE_N).fixed;
    let loads = press_loads(arch);
    let mut euler = ImplicitEuler::new(mesh, mesh.lumped_mass(mat.density), params)
        .map_err(|e| ExperimentError::Setup(e.to_string()))?;
    let mut state = TissueState::at_rest(mesh.num_nodes());
    let total: f64 = BACKGROUND_PHASES_S.iter().sum();
    let steps = (total / params.dt).round() as usize;
    let mut out = History {
        u: Vec::new(),
        reaction: Vec::new(),
        ms: 0.0,
    };
    let mut times = Vec::with_capacity(steps);
    let mut f = vec![Vec3::zeros(); mesh.num_nodes()];
    for step in 1..=steps {
        let t0 = Instant::now();
        let rep = euler.step(&mut state, model.as_mut(), &loads, &fixed);
        times.push(t0.elapsed().as_secs_f64() * 1e3);
        if let Some(fail) = rep.failure {
            return Err(ExperimentError::Step {
                model: "nvtmm+prony".into(),
                step,
                reason: fail.to_string(),
            });
        }
        if step % every == 0 {
            f.iter_mut().for_each(|x| *x = Vec3::zeros());
            model.add_forces(&state.u, &mut f);
            out.reaction.push(fixed.iter().map(|&i| f[i as usize]).sum());
            out.u.push(state.u.clone());
        }
    }
    times.sort_by(f64::total_cmp);
    out.ms = times[times.len() / 2];
    Ok(out)
}

/// The background full solve of the haptic service against a converged
/// solve of the same model and load history, one row per background step
/// length (the service's steps follow real time: each covers the time the
/// solve is behind, up to `background.dt_max`).
///
/// Reference: the same model (NVTMM + the service's Prony term) with dt =
/// 1 ms (2 ms with `quick`), Newton to 1e-10 and Cholesky. Both runs are
/// sampled at every background step end; the errors are the largest over
/// the history, relative to the largest reference value over the history:
/// `err_load_disp` at the arch-top node, `err_rms_surface` the RMS over the
/// surface nodes, `err_reaction` the support reaction.
pub fn background_rows(arch: &Arch, quick: bool) -> Result<Vec<TradeRow>, ExperimentError> {
    let dt_ref = if quick { 2e-3 } else { 1e-3 };
    // Background steps: the old shipped dt_max (50 ms), a typical service
    // step at 5832 nodes (60 ms), 100 ms, and the shipped dt_max (250 ms:
    // taken after a slow step at 5832 nodes, and every step at 23 328).
    let dts: &[f64] = if quick { &[0.05, 0.25] } else { &[0.05, 0.06, 0.1, 0.25] };
    // Sample the reference on the 10 ms grid every background step lies on.
    let grid: f64 = 0.01;
    let ref_every = (grid / dt_ref).round() as usize;
    let reference_params = ImplicitEulerParams {
        dt: dt_ref,
        newton: NewtonParams {
            max_iters: 8,
            rel_tol: 1e-10,
            ..NewtonParams::default()
        },
        linear: LinearSolverKind::Cholesky,
        max_halvings: 0,
        ..service_params(dt_ref)
    };
    let reference = run_history(arch, reference_params, ref_every)?;
    let node = standard_load(arch, STANDARD_FORCE_N).node as usize;
    let surf = arch.mesh.surface_nodes();
    let rms = |u: &[Vec3]| (surf.iter().map(|&i| u[i as usize].norm_squared()).sum::<f64>() / surf.len() as f64).sqrt();
    let peak_node = reference
        .u
        .iter()
        .map(|u| u[node].norm())
        .fold(0.0, f64::max)
        .max(1e-300);
    let peak_rms = reference.u.iter().map(|u| rms(u)).fold(0.0, f64::max).max(1e-300);
    let peak_reac = reference
        .reaction
        .iter()
        .map(|r| r.norm())
        .fold(0.0, f64::max)
        .max(1e-300);
    let mut rows = Vec::new();
    for &dt in dts {
        let stride = (dt / grid).round() as usize;
        let value = format!("service step {dt} s");
        match run_history(arch, service_params(dt), 1) {
            Ok(h) => {
                let (mut e_node, mut e_rms, mut e_reac) = (0.0f64, 0.0f64, 0.0f64);
                for (k, (u, r)) in h.u.iter().zip(&h.reaction).enumerate() {
                    let j = (k + 1) * stride - 1;
                    let (Some(ur), Some(rr)) = (reference.u.get(j), reference.reaction.get(j)) else {
                        break;
                    };
                    let d: Vec<Vec3> = u.iter().zip(ur).map(|(a, b)| a - b).collect();
                    e_node = e_node.max(d[node].norm());
                    e_rms = e_rms.max(rms(&d));
                    e_reac = e_reac.max((r - rr).norm());
                }
                rows.push(TradeRow {
                    knob: "background".into(),
                    value,
                    model: "nvtmm+prony".into(),
                    nodes: arch.mesh.num_nodes(),
                    ms_per_step: h.ms,
                    wall_per_sim_s: h.ms * 1e-3 / dt,
                    err_load_disp: e_node / peak_node,
                    err_rms_surface: e_rms / peak_rms,
                    err_reaction: e_reac / peak_reac,
                });
            }
            Err(ExperimentError::Step { reason, .. }) => {
                push_failed(&mut rows, "background", value, ModelKind::Nvtmm, arch, reason)
            }
            Err(e) => return Err(e),
        }
    }
    Ok(rows)
}

/// The rows as Markdown, with the recommended settings for the 30 Hz visual
/// budget (33 ms per step) and the 1 kHz haptic budget (1 ms per step).
pub fn markdown(rows: &[TradeRow], finest: usize) -> String {
    let dash = |v: f64| {
        if v.is_nan() {
            "–".to_string()
        } else {
            format!("{v:.2e}")
        }
    };
    let mut s = format!("Machine: {}.\n\n| knob | value | model | nodes | ms/step | wall s per sim s | err (loaded node) | err (RMS surface) | err (reaction) |\n|---|---|---|---|---|---|---|---|---|\n", super::table::machine());
    for r in rows {
        s.push_str(&format!(
            "| {} | {} | {} | {} | {:.2} | {:.2} | {:.2e} | {} | {} |\n",
            r.knob,
            r.value,
            r.model,
            r.nodes,
            r.ms_per_step,
            r.wall_per_sim_s,
            r.err_load_disp,
            dash(r.err_rms_surface),
            dash(r.err_reaction)
        ));
    }
    for (name, budget) in [
        ("30 Hz visual (one step ≤ 33 ms)", 33.3),
        ("1 kHz haptic (one step ≤ 1 ms)", 1.0),
    ] {
        s.push_str(&format!("\n**{name}:** "));
        // Time and solver knobs on the study mesh (errors against its reference).
        let best = rows
            .iter()
            .filter(|r| {
                !matches!(r.knob.as_str(), "mesh_nodes" | "background")
                    && r.ms_per_step <= budget
                    && r.err_load_disp.is_finite()
            })
            .min_by(|a, b| a.err_load_disp.total_cmp(&b.err_load_disp));
        match best {
            Some(r) => s.push_str(&format!(
                "on the {}-node mesh, {} with {} = {}: {:.2} ms/step, loaded-node error {:.1e} against the converged run on that mesh. ",
                r.nodes, r.model, r.knob, r.value, r.ms_per_step, r.err_load_disp
            )),
            None => s.push_str("no full-model setting on the study mesh fits this budget on this machine. "),
        }
        // Spatial resolution: the finest mesh (other than the reference) that fits.
        let mesh = rows
            .iter()
            .filter(|r| r.knob == "mesh_nodes" && r.ms_per_step <= budget)
            .max_by_key(|r| r.nodes);
        match mesh {
            Some(r) => s.push_str(&format!(
                "Finest mesh that fits: {} nodes ({:.2} ms/step), loaded-node error {:.1e} against the {finest}-node mesh.\n",
                r.nodes, r.ms_per_step, r.err_load_disp
            )),
            None => s.push_str("No mesh in the study fits this budget with the full model: this is what the reduced model is for.\n"),
        }
    }
    s
}

/// Draws `trade.png` from the rows (the curves per model over dt, the mesh
/// resolution and the solver's knobs).
pub fn plot(rows: &[TradeRow], png: &Path) -> Result<(), ExperimentError> {
    let colors = [
        RGBColor(31, 119, 180),
        RGBColor(255, 127, 14),
        RGBColor(44, 160, 44),
        RGBColor(214, 39, 40),
        RGBColor(148, 103, 189),
        RGBColor(90, 90, 90),
    ];
    let mut series = Vec::new();
    for (i, m) in ["msm", "tmm", "nvtmm", "fem"].iter().enumerate() {
        let mut pts: Vec<(f64, f64)> = rows
            .iter()
            .filter(|r| r.knob == "dt" && r.model == *m)
            .map(|r| (r.wall_per_sim_s, r.err_load_disp.max(1e-9)))
            .collect();
        pts.sort_by(|a, b| a.0.total_cmp(&b.0));
        series.push(Series {
            name: format!("{m}: dt 0.5-10 ms"),
            color: colors[i],
            points: pts,
            markers: true,
        });
    }
    let mut mesh_pts: Vec<(f64, f64)> = rows
        .iter()
        .filter(|r| r.knob == "mesh_nodes" && r.err_load_disp > 0.0)
        .map(|r| (r.wall_per_sim_s, r.err_load_disp))
        .collect();
    mesh_pts.sort_by(|a, b| a.0.total_cmp(&b.0));
    series.push(Series {
        name: "nvtmm: mesh resolution".into(),
        color: colors[4],
        points: mesh_pts,
        markers: true,
    });
    let mut solver_pts: Vec<(f64, f64)> = rows
        .iter()
        .filter(|r| matches!(r.knob.as_str(), "cg_tol" | "newton_iters"))
        .map(|r| (r.wall_per_sim_s, r.err_load_disp.max(1e-9)))
        .collect();
    solver_pts.sort_by(|a, b| a.0.total_cmp(&b.0));
    series.push(Series {
        name: "nvtmm: Newton iters, CG tol".into(),
        color: colors[5],
        points: solver_pts,
        markers: true,
    });
    line_plot(
        png,
        "Speed for accuracy (arch, standard load, error at t = 40 ms)",
        "wall time per simulated second (s)",
        "relative error of the loaded node's displacement",
        &series,
        true,
        true,
    )
    .map_err(|e| ExperimentError::Plot(png.to_path_buf(), e))?;
    Ok(())
}

/// Reads a `trade.csv` written by [`run`] (e.g. docs/trade.csv), to plot
/// it again.
pub fn read_csv(path: &Path) -> Result<Vec<TradeRow>, ExperimentError> {
    let text = std::fs::read_to_string(path).map_err(|e| ExperimentError::io(path, e))?;
    let bad = |line: usize, what: &str| {
        ExperimentError::io(
            path,
            std::io::Error::new(std::io::ErrorKind::InvalidData, format!("line {line}: {what}")),
        )
    };
    let mut rows = Vec::new();
    for (i, line) in text.lines().enumerate().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        if f.len() != 9 {
            return Err(bad(i + 1, "expected 9 fields"));
        }
        let num = |k: usize| f[k].trim().parse::<f64>().map_err(|_| bad(i + 1, "not a number"));
        rows.push(TradeRow {
            knob: f[0].to_string(),
            value: f[1].to_string(),
            model: f[2].to_string(),
            nodes: f[3].trim().parse().map_err(|_| bad(i + 1, "nodes: not an integer"))?,
            ms_per_step: num(4)?,
            wall_per_sim_s: num(5)?,
            err_load_disp: num(6)?,
            err_rms_surface: num(7)?,
            err_reaction: num(8)?,
        });
    }
    Ok(rows)
}
