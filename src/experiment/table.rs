//! The paper's Tables I and II on our arch: visual and haptic refresh rates
//! of MSM, FEM and NVTMM at 1458, 5832 and 23328 nodes, with the paper's
//! figures beside ours.
//!
//! Definitions (the paper gives none precisely):
//! - **visual rate**: frames per second when each frame advances the full
//!   model by one implicit step of 1/60 s (the visual loop's own period at 60
//!   FPS) and then updates the surface for drawing (deformed surface
//!   positions and area-weighted vertex normals);
//! - **haptic rate (full model)**: steps per second when each haptic frame
//!   advances the full model by one implicit step of 1 ms and reads the
//!   reaction force at the contact node (the internal force there);
//! - **haptic rate (reduced model)**: steps per second of this project's
//!   reduced model (r = 32, half of them contact modes of the probe patch)
//!   taking its implicit step with the probe's contact stiffness, as the 1
//!   kHz loop does: 10⁶ / `us_per_step` of [`crate::bench::reduced`]. The
//!   reduced model is built from the NVTMM tangent, so it is reported on the
//!   NVTMM rows.
//!
//! All full-model rates use the benchmark's standard load
//! ([`crate::bench::standard_load`]), the StVK law, 1 Newton iteration and
//! the fastest exact linear solver measured ([`TABLE_LINEAR`]), and report
//! the median over the timed frames.

use super::ExperimentError;
use crate::bench::{arch_top_node, standard_load, standard_params, STANDARD_FORCE_N};
use crate::material::{Law, Material};
use crate::math::Vec3;
use crate::mesh::arch::{generate, ArchParams};
use crate::model::factory::build_model;
use crate::model::ModelKind;
use crate::solver::{ImplicitEuler, ImplicitEulerParams, LinearSolverKind, TissueState};
use std::io::Write;
use std::path::Path;
use std::time::Instant;

/// The table's linear solver: CG to 1e-6 preconditioned by an f32 Cholesky
/// factor refreshed every 3 solves, the fastest exact setting at every size
/// in `tools/bench_step.sh` (docs/BENCHMARKS.md).
pub const TABLE_LINEAR: LinearSolverKind = LinearSolverKind::CholeskyPcg {
    tol: 1e-6,
    max_iter: 30,
    refactor_every: 3,
    factor_f32: true,
};

/// Reduced-model columns r (contact modes: r / 2) and timed steps.
const REDUCED_R: usize = 32;

/// The paper's figures: (nodes, model, visual FPS, haptic FPS).
pub const PAPER: [(usize, &str, f64, f64); 9] = [
    (1458, "msm", 276.0, 142.0),
    (1458, "fem", 94.0, 87.0),
    (1458, "nvtmm", 103.0, 124.0),
    (5832, "msm", 70.0, 33.0),
    (5832, "fem", 26.0, 25.0),
    (5832, "nvtmm", 55.0, 58.0),
    (23328, "msm", 18.0, 6.0),
    (23328, "fem", 4.0, 4.0),
    (23328, "nvtmm", 13.0, 12.0),
];

/// One row of the table (CSV columns).
#[derive(Debug, Clone, serde::Serialize)]
pub struct TableRow {
    /// Requested nodes (the paper's size).
    pub nodes: usize,
    /// Actual nodes of our arch.
    pub our_nodes: usize,
    /// Model.
    pub model: String,
    /// Our visual rate (FPS).
    pub visual_fps: f64,
    /// The paper's visual rate (FPS).
    pub paper_visual_fps: f64,
    /// Our haptic rate with the full model (FPS).
    pub haptic_fps: f64,
    /// The paper's haptic rate (FPS).
    pub paper_haptic_fps: f64,
    /// Steps per second of the reduced model's contact step (NaN where not
    /// applicable: the MSM and FEM rows).
    pub reduced_haptic_fps: f64,
    /// Median CG iterations per haptic step.
    pub cg_iters: usize,
    /// Why a measurement failed (the rate is then NaN), if it did.
    pub failure: Option<String>,
}

fn time_frames(
    kind: ModelKind,
    nodes: usize,
    dt: f64,
    frames: usize,
    visual: bool,
) -> Result<(f64, usize, usize), ExperimentError> {
    let arch = generate(&ArchParams::default(), nodes).map_err(|e| ExperimentError::Setup(e.to_string()))?;
    let mesh = &arch.mesh;
    let mat = Material::aorta();
    let mut model = build_model(kind, mesh, &mat, Law::Stvk, &[]);
    let load = standard_load(&arch, STANDARD_FORCE_N);
    let node = arch_top_node(&arch) as usize;
    let params = ImplicitEulerParams {
        dt,
        linear: TABLE_LINEAR,
        ..standard_params()
    };
    let mut euler = ImplicitEuler::new(mesh, mesh.lumped_mass(mat.density), params)
        .map_err(|e| ExperimentError::Setup(e.to_string()))?;
    let mut state = TissueState::at_rest(mesh.num_nodes());
    let surface = mesh.surface();
    let mut positions = vec![Vec3::zeros(); mesh.num_nodes()];
    let mut normals = vec![Vec3::zeros(); mesh.num_nodes()];
    let mut force = vec![Vec3::zeros(); mesh.num_nodes()];
    let mut times = Vec::with_capacity(frames);
    let mut iters = Vec::with_capacity(frames);
    let mut sink = 0.0;
    for frame in 0..frames + 3 {
        let t0 = Instant::now();
        let rep = euler.step(&mut state, model.as_mut(), &load.loads, &load.fixed);
        if let Some(f) = rep.failure {
            return Err(ExperimentError::Step {
                model: kind.name().into(),
                step: frame + 1,
                reason: f.to_string(),
            });
        }
        if visual {
            for (p, (x, u)) in positions.iter_mut().zip(mesh.rest().iter().zip(&state.u)) {
                *p = x + u;
            }
            normals.iter_mut().for_each(|n| *n = Vec3::zeros());
            for t in surface {
                let [a, b, c] = t.map(|i| i as usize);
                let n = (positions[b] - positions[a]).cross(&(positions[c] - positions[a]));
                normals[a] += n;
                normals[b] += n;
                normals[c] += n;
            }
            sink += normals[surface[0][0] as usize].norm();
        } else {
            force.iter_mut().for_each(|f| *f = Vec3::zeros());
            model.add_forces(&state.u, &mut force);
            sink += force[node].norm();
        }
        if frame >= 3 {
            times.push(t0.elapsed().as_secs_f64());
            iters.push(rep.linear_iters);
        }
    }
    std::hint::black_box(sink);
    times.sort_by(f64::total_cmp);
    iters.sort_unstable();
    Ok((1.0 / times[times.len() / 2], iters[iters.len() / 2], mesh.num_nodes()))
}

/// Measures the table. `quick` times only the 1458-node arch, with few frames.
pub fn run(out: &Path, quick: bool) -> Result<Vec<TableRow>, ExperimentError> {
    std::fs::create_dir_all(out).map_err(|e| ExperimentError::io(out, e))?;
    let frames = if quick { 4 } else { 15 };
    let reduced_steps = if quick { 2000 } else { 20000 };
    let mut reduced: Vec<(usize, f64)> = Vec::new();
    let mut rows = Vec::new();
    for &(nodes, model, pv, ph) in PAPER.iter().filter(|r| !quick || r.0 == 1458) {
        let kind: ModelKind = model.parse().map_err(ExperimentError::Setup)?;
        let mut failures: Vec<String> = Vec::new();
        let mut measure = |dt: f64, visual: bool| match time_frames(kind, nodes, dt, frames, visual) {
            Ok(r) => Ok(r),
            Err(ExperimentError::Step { step, reason, .. }) => {
                failures.push(format!(
                    "{} at dt = {dt:.4} s, step {step}: {reason}",
                    if visual { "visual" } else { "haptic" }
                ));
                Ok((f64::NAN, 0, 0))
            }
            Err(e) => Err(e),
        };
        let (visual, _, _) = measure(1.0 / 60.0, true)?;
        let (haptic, cg, _) = measure(1e-3, false)?;
        let our_nodes = generate(&ArchParams::default(), nodes)
            .map(|a| a.mesh.num_nodes())
            .unwrap_or(0);
        let reduced_haptic_fps = if kind == ModelKind::Nvtmm {
            match reduced.iter().find(|(n, _)| *n == nodes) {
                Some(&(_, fps)) => fps,
                None => {
                    let fps = match crate::bench::reduced::bench_reduced(REDUCED_R, nodes, reduced_steps) {
                        Ok(b) => 1e6 / b.us_per_step,
                        Err(e) => {
                            failures.push(format!("reduced model: {e}"));
                            f64::NAN
                        }
                    };
                    reduced.push((nodes, fps));
                    fps
                }
            }
        } else {
            f64::NAN
        };
        let failure = if failures.is_empty() {
            None
        } else {
            Some(failures.join("; "))
        };
        rows.push(TableRow {
            nodes,
            our_nodes,
            model: model.into(),
            visual_fps: visual,
            paper_visual_fps: pv,
            haptic_fps: haptic,
            paper_haptic_fps: ph,
            reduced_haptic_fps,
            cg_iters: cg,
            failure,
        });
    }
    let csv = out.join("table.csv");
    let mut w = std::fs::File::create(&csv).map_err(|e| ExperimentError::io(&csv, e))?;
    writeln!(
        w,
        "nodes,our_nodes,model,visual_fps,paper_visual_fps,haptic_fps,paper_haptic_fps,reduced_haptic_fps,cg_iters"
    )
    .map_err(|e| ExperimentError::io(&csv, e))?;
    for r in &rows {
        writeln!(
            w,
            "{},{},{},{:.2},{},{:.2},{},{},{}",
            r.nodes,
            r.our_nodes,
            r.model,
            r.visual_fps,
            r.paper_visual_fps,
            r.haptic_fps,
            r.paper_haptic_fps,
            if r.reduced_haptic_fps.is_finite() {
                format!("{:.0}", r.reduced_haptic_fps)
            } else {
                String::new()
            },
            r.cg_iters
        )
        .map_err(|e| ExperimentError::io(&csv, e))?;
    }
    let md = out.join("table.md");
    std::fs::write(&md, markdown(&rows)).map_err(|e| ExperimentError::io(&md, e))?;
    Ok(rows)
}

/// The machine, for the table's caption.
pub fn machine() -> String {
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .map(|l| l.split(':').nth(1).unwrap_or("").trim().to_string())
        })
        .unwrap_or_else(|| "unknown CPU".into());
    let load = std::fs::read_to_string("/proc/loadavg")
        .ok()
        .and_then(|s| s.split_whitespace().next().map(String::from))
        .unwrap_or_default();
    format!(
        "{} cores ({cpu}), load average {load}, {} rayon threads",
        std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1),
        rayon::current_num_threads()
    )
}

/// The rows as a Markdown table with the paper's figures beside ours.
pub fn markdown(rows: &[TableRow]) -> String {
    let mut s = format!(
        "Ours: {}. Paper: Intel i7-10750H laptop (6 cores), SOFA 20.06.\n\n\
         | nodes (ours) | model | visual FPS, ours | visual FPS, paper | haptic FPS (full model), ours | haptic FPS, paper | haptic FPS (reduced model, r = 32), ours | PCG iters |\n\
         |---|---|---|---|---|---|---|---|\n",
        machine()
    );
    let fps = |v: f64| {
        if v.is_finite() {
            format!("{v:.1}")
        } else {
            "failed¹".into()
        }
    };
    for r in rows {
        s.push_str(&format!(
            "| {} ({}) | {} | {} | {} | {} | {} | {} | {} |\n",
            r.nodes,
            r.our_nodes,
            r.model,
            fps(r.visual_fps),
            r.paper_visual_fps,
            fps(r.haptic_fps),
            r.paper_haptic_fps,
            if r.model == "nvtmm" {
                format!("{:.0}", r.reduced_haptic_fps)
            } else {
                "–".into()
            },
            r.cg_iters
        ));
    }
    for r in rows.iter().filter(|r| r.failure.is_some()) {
        s.push_str(&format!(
            "\n¹ {} at {} nodes: {}\n",
            r.model,
            r.nodes,
            r.failure.as_deref().unwrap_or("")
        ));
    }
    s
}
