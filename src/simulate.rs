//! Running a scene: the full model stepped by implicit Euler, with outputs.
//!
//! [`run`] builds the scene, steps it for its duration, writes the probe CSV
//! (`probes.csv`: time, then displacement and internal force of each probe
//! node), a picture of the deformed surface coloured by displacement
//! (`final.png`) and, if asked, a `.pvd` + `.vtu` series, and returns a
//! [`RunSummary`]. A failed step stops the run with an error that says which
//! step and why; the state is never advanced with a non-finite value.

use crate::math::Vec3;
use crate::scene::{Scene, SceneError};
use crate::solver::{ImplicitEuler, StepReport, TissueState};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Errors of a simulation run.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    /// The scene is invalid.
    #[error(transparent)]
    Scene(#[from] SceneError),
    /// The integrator could not be built.
    #[error("{0}")]
    Solver(String),
    /// A step failed (diverged, non-finite, linear solver breakdown).
    #[error("step {step} (t = {t:.6} s) failed: {reason}; the last good state is kept and the run stops")]
    StepFailed {
        /// 1-based step number.
        step: usize,
        /// Time at the start of the step (s).
        t: f64,
        /// Why.
        reason: String,
    },
    /// An output could not be written.
    #[error("{path}: {msg}")]
    Output {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        msg: String,
    },
}

/// What a run did.
#[derive(Debug, Clone, serde::Serialize)]
pub struct RunSummary {
    /// Model name.
    pub model: String,
    /// Nodes of the mesh.
    pub nodes: usize,
    /// Tets of the mesh.
    pub tets: usize,
    /// Steps taken.
    pub steps: usize,
    /// Simulated time (s).
    pub sim_time_s: f64,
    /// Wall-clock time of the stepping loop (s).
    pub wall_s: f64,
    /// Median wall time per step (ms).
    pub ms_per_step: f64,
    /// Steps whose Newton iteration did not reach its tolerance.
    pub unconverged_steps: usize,
    /// Steps that failed at full length and were covered by halved
    /// sub-steps (`[integrator] max_halvings`).
    pub split_steps: usize,
    /// Median CG iterations per step.
    pub cg_iters_median: usize,
    /// Largest nodal displacement at the end (m).
    pub max_displacement_m: f64,
    /// Elastic energy at the end (J).
    pub final_energy_j: f64,
    /// Files written.
    pub outputs: Vec<PathBuf>,
}

fn median<T: Copy + PartialOrd>(v: &mut [T]) -> Option<T> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(|a, b| a.partial_cmp(b).unwrap_or(std::cmp::Ordering::Equal));
    Some(v[v.len() / 2])
}

/// Runs `scene`, writing outputs into `out_dir` (created if needed). Its
/// progress (steps, task `"simulate"`) goes to `observer`.
pub fn run(scene: &Scene, out_dir: &Path, observer: &crate::observe::Observe) -> Result<RunSummary, SimError> {
    let mut built = scene.build()?;
    let n = built.mesh.num_nodes();
    let mut state = TissueState::at_rest(n);
    let dt = scene.integrator.dt;
    // A living vessel is never deflated: a pressurized scene starts from
    // its wall inflated to the mean pressure, as the service starts it.
    if let Some(mut load) = built.loads.pressure.take() {
        observer.message(&format!(
            "nvtmm simulate: inflating the wall to {:.0} Pa...",
            load.schedule.mean_pa
        ));
        let inflated = scene.inflate(&mut built, &mut load, dt);
        built.loads.pressure = Some(load);
        let inflated = inflated?;
        observer.message(&format!(
            "nvtmm simulate: inflated by up to {:.2} mm ({} Newton iterations, {:.1} s)",
            inflated.max_u_m * 1e3,
            inflated.newton_iters,
            inflated.solve_s
        ));
        state.u = inflated.u;
    }
    let mesh = &built.mesh;
    let mass = mesh.lumped_mass(built.material.density);
    let mut euler = ImplicitEuler::new(mesh, mass, scene.integrator).map_err(|e| SimError::Solver(e.to_string()))?;
    let steps = (scene.duration / dt).round().max(1.0) as usize;
    let out_err = |path: &Path, e: &dyn std::fmt::Display| SimError::Output {
        path: path.to_path_buf(),
        msg: e.to_string(),
    };
    std::fs::create_dir_all(out_dir).map_err(|e| out_err(out_dir, &e))?;
    let mut outputs = Vec::new();

    let csv_every = scene
        .output
        .csv_every
        .unwrap_or(if built.probes.is_empty() { 0 } else { 1 });
    let csv_path = out_dir.join("probes.csv");
    let mut csv = if csv_every > 0 && !built.probes.is_empty() {
        let f = std::fs::File::create(&csv_path).map_err(|e| out_err(&csv_path, &e))?;
        let mut w = std::io::BufWriter::new(f);
        let mut header = String::from("t_s");
        for p in &built.probes {
            for c in ["ux_m", "uy_m", "uz_m", "fx_n", "fy_n", "fz_n"] {
                header.push_str(&format!(",n{p}_{c}"));
            }
        }
        writeln!(w, "{header}").map_err(|e| out_err(&csv_path, &e))?;
        outputs.push(csv_path.clone());
        Some(w)
    } else {
        None
    };
    let mut series = if scene.output.vtu_every > 0 {
        let s = crate::mesh::io::PvdSeries::create(out_dir, "frames").map_err(|e| out_err(out_dir, &e))?;
        outputs.push(out_dir.join("frames.pvd"));
        Some(s)
    } else {
        None
    };

    let mut detail = String::new();

    let mut times = Vec::with_capacity(steps);
    let mut cg = Vec::with_capacity(steps);
    let mut unconverged = 0;
    let mut split = 0;
    let mut force = vec![Vec3::zeros(); n];
    let t_start = Instant::now();
    for step in 1..=steps {
        let t0 = Instant::now();
        let rep: StepReport = euler.step(&mut state, built.model.as_mut(), &built.loads, &built.fixed);
        times.push(t0.elapsed().as_secs_f64() * 1e3);
        if let Some(f) = rep.failure {
            observer.finished("simulate", false);
            return Err(SimError::StepFailed {
                step,
                t: state.t,
                reason: f.to_string(),
            });
        }
        if !rep.converged {
            unconverged += 1;
        }
        if rep.substeps > 1 {
            split += 1;
        }
        cg.push(rep.linear_iters);
        let want_csv = csv.is_some() && step % csv_every.max(1) == 0;
        let want_vtu = series.is_some() && step % scene.output.vtu_every.max(1) == 0;
        if want_csv || want_vtu {
            force.iter_mut().for_each(|f| *f = Vec3::zeros());
            built.model.add_forces(&state.u, &mut force);
        }
        if let (true, Some(w)) = (want_csv, csv.as_mut()) {
            let mut line = format!("{}", state.t);
            for &p in &built.probes {
                let (u, f) = (state.u[p as usize], force[p as usize]);
                line.push_str(&format!(",{},{},{},{},{},{}", u.x, u.y, u.z, f.x, f.y, f.z));
            }
            writeln!(w, "{line}").map_err(|e| out_err(&csv_path, &e))?;
        }
        if let (true, Some(s)) = (want_vtu, series.as_mut()) {
            let pos: Vec<Vec3> = mesh.rest().iter().zip(&state.u).map(|(x, u)| x + u).collect();
            let disp_mag: Vec<f64> = state.u.iter().map(|u| u.norm()).collect();
            s.add_step(
                state.t,
                mesh,
                Some(&pos),
                &[("displacement", &state.u), ("force", &force)],
                &[("displacement_norm", &disp_mag)],
            )
            .map_err(|e| out_err(out_dir, &e))?;
        }
        if observer.is_active() {
            if step % 50 == 1 {
                detail = format!("{:.3}s", state.t);
            }
            observer.progress("simulate", step as f64, steps as f64, &detail);
        }
    }
    let wall_s = t_start.elapsed().as_secs_f64();
    observer.finished("simulate", true);
    if let Some(mut w) = csv {
        w.flush().map_err(|e| out_err(&csv_path, &e))?;
    }
    if let Some(s) = series {
        s.finish().map_err(|e| out_err(out_dir, &e))?;
    }
    // A quick look without ParaView: the deformed surface coloured by |u|.
    let png = out_dir.join("final.png");
    let pos: Vec<Vec3> = mesh.rest().iter().zip(&state.u).map(|(x, u)| x + u).collect();
    let mag: Vec<f64> = state.u.iter().map(|u| u.norm()).collect();
    let opt = crate::mesh::render::RenderOptions {
        edges: false,
        ..Default::default()
    };
    #[cfg_attr(not(feature = "tools"), allow(unused_mut))]
    let mut rgb = crate::mesh::render::render_surface(mesh, Some(&pos), Some(&mag), &opt);
    #[cfg(feature = "tools")]
    let (lo, hi) = mag
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| (a.min(x), b.max(x)));
    // The caption and colour bar need the plotting library (feature
    // `tools`); without it the picture has none.
    #[cfg(feature = "tools")]
    crate::experiment::plot::annotate_render(
        &mut rgb,
        opt.width,
        opt.height,
        &format!(
            "{}: deformed surface at t = {:.3} s, view along +y (x right, z up)",
            built.model.name(),
            state.t
        ),
        "|u| (mm)",
        lo * 1e3,
        hi * 1e3,
    )
    .map_err(|e| out_err(&png, &std::io::Error::other(e)))?;
    crate::mesh::render::write_png(&png, opt.width, opt.height, &rgb).map_err(|e| out_err(&png, &e))?;
    outputs.push(png);
    Ok(RunSummary {
        model: built.model.name().to_string(),
        nodes: n,
        tets: mesh.tets().len(),
        steps,
        sim_time_s: state.t,
        wall_s,
        ms_per_step: median(&mut times).unwrap_or(0.0),
        unconverged_steps: unconverged,
        split_steps: split,
        cg_iters_median: median(&mut cg).unwrap_or(0),
        max_displacement_m: state.u.iter().map(|u| u.norm()).fold(0.0, f64::max),
        final_energy_j: built.model.energy(&state.u),
        outputs,
    })
}
