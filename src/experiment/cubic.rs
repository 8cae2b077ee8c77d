//! `nvtmm experiment cubic`: the linear reduced model against the exact cubic
//! reduced StVK model ([`crate::reduced::cubic`]), side by side in one run:
//! precompute time, cost per step and accuracy against the full NVTMM
//! implicit Euler under a load large enough to be nonlinear. Results and
//! definitions: docs/RESULTS.md ("Cubic reduced StVK against the linear
//! reduced model"); in short:
//!
//! - Arch (5832 nodes; 1458 with `quick`), both ends fixed, aorta material,
//!   the standard probe patch ([`crate::bench::probe_region`]) pushed down
//!   (−z) by [`LOAD_N`] in total, ramped over [`RAMP_S`] and held to
//!   [`END_S`] (dt = 1 ms, Rayleigh α = 5 /s, β = 1e-4 s, as the reduced
//!   benchmark).
//! - Reference: the full NVTMM (StVK), implicit Euler with Newton to a
//!   relative residual of 1e-8 (sparse Cholesky).
//! - Two bases per r: "modes+static" (`ModalBasis::compute` with `Statics::Compressed`, r
//!   columns, ⌊r/2⌋ static modes of the patch, as the haptic loop uses) and
//!   "+derivatives" (⌈r/2⌉ such columns enriched to r with the modal
//!   derivatives the patch load excites most,
//!   [`crate::reduced::derivatives::with_load_derivatives`]). On each, the linear
//!   [`ReducedDynamics`] (K_r = diag ω²) and the cubic
//!   [`CubicReducedDynamics`] (2 Newton iterations).
//! - Accuracy: the top node's z displacement over time, error
//!   max_t |z_red − z_full| / max_t |z_full|, and the RMS over nodes and time
//!   of |u_red − u_full| relative to the RMS of |u_full| (every 5th step).
//! - Cost: median and 99th percentile of one `step` over [`TIMED_STEPS`]
//!   steps of the same load (only the call is timed); the cubic
//!   precomputation (`CubicStvk::new`) and the basis time.

use super::ExperimentError;
use crate::bench::reduced::bench_dynamics_params;
use crate::bench::{arch_top_node, probe_region, standard_load, STANDARD_FORCE_N};
use crate::material::Material;
use crate::math::Vec3;
use crate::mesh::arch::{generate, ArchParams};
use crate::mesh::TetMesh;
use crate::model::nvtmm::Nvtmm;
use crate::reduced::cubic::{CubicReducedDynamics, CubicStvk, DEFAULT_NEWTON_ITERS};
use crate::reduced::derivatives::with_load_derivatives;
use crate::reduced::{basis_rows, BasisParams, DynamicsParams, ModalBasis, ReducedDynamics};
use crate::solver::loads::{Loads, NodalLoad, TimeProfile};
use crate::solver::{ImplicitEuler, ImplicitEulerParams, LinearSolverKind, NewtonParams, TissueState};
use nalgebra::SVector;
use std::io::Write;
use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

/// Total load on the probe patch (N): four times the standard load.
pub const LOAD_N: f64 = 2.0 * STANDARD_FORCE_N;
/// Ramp time of the load (s).
pub const RAMP_S: f64 = 0.05;
/// End of the simulated interval (s).
pub const END_S: f64 = 0.15;
/// Steps timed per model.
pub const TIMED_STEPS: usize = 2000;
/// Full displacement fields are compared every this many steps.
const SAMPLE_EVERY: usize = 5;

/// One row: a reduced model on a basis.
#[derive(Debug, Clone, serde::Serialize)]
pub struct CubicRow {
    /// Basis size.
    pub r: usize,
    /// "modes+static" or "+derivatives".
    pub basis: String,
    /// "linear" or "cubic".
    pub model: String,
    /// Basis computation (s).
    pub basis_s: f64,
    /// Cubic precomputation (s; 0 for the linear model).
    pub precompute_s: f64,
    /// Stored cubic coefficients (MB; 0 for the linear model).
    pub coefficient_mb: f64,
    /// Median of one step (µs).
    pub us_median: f64,
    /// 99th percentile of one step (µs).
    pub us_p99: f64,
    /// max_t |z_red − z_full| / max_t |z_full| at the top node.
    pub top_err: f64,
    /// Top-node z at the end, reduced (m).
    pub top_end_m: f64,
    /// RMS over nodes and sampled steps of |u_red − u_full| / RMS |u_full|.
    pub rms_err: f64,
    /// Steps that failed (state kept).
    pub failed_steps: usize,
}

/// Precompute cost on a larger mesh (no dynamics).
#[derive(Debug, Clone, serde::Serialize)]
pub struct PrecomputeRow {
    /// Mesh nodes.
    pub nodes: usize,
    /// Mesh tets.
    pub tets: usize,
    /// Basis size.
    pub r: usize,
    /// Basis (s).
    pub basis_s: f64,
    /// Cubic precomputation (s).
    pub precompute_s: f64,
    /// Coefficients (MB).
    pub coefficient_mb: f64,
}

/// Everything the experiment measured.
#[derive(Debug, Clone, serde::Serialize)]
pub struct CubicResults {
    /// Mesh nodes.
    pub nodes: usize,
    /// Mesh tets.
    pub tets: usize,
    /// Full model: top-node z at the end (m).
    pub full_top_end_m: f64,
    /// Full model: mean wall time per step (ms).
    pub full_ms_per_step: f64,
    /// One row per (r, basis, model).
    pub rows: Vec<CubicRow>,
    /// Precompute-only rows (larger meshes; empty with `quick`).
    pub precompute: Vec<PrecomputeRow>,
}

fn load_scale(t: f64) -> f64 {
    (t / RAMP_S).clamp(0.0, 1.0)
}

struct Setup {
    mesh: TetMesh,
    model: Nvtmm,
    mass: Vec<f64>,
    fixed: Vec<u32>,
    patch: Vec<u32>,
    top: u32,
}

/// Top-node z per step, sampled fields, mean ms per step.
type FullRun = (Vec<f64>, Vec<Vec<Vec3>>, f64);

/// The full reference: top z per step and the fields every SAMPLE_EVERY steps.
fn full_reference(s: &Setup, params: &DynamicsParams, steps: usize) -> Result<FullRun, ExperimentError> {
    let per = Vec3::new(0.0, 0.0, -LOAD_N / s.patch.len() as f64);
    let loads = Loads {
        nodal: vec![NodalLoad {
            nodes: s.patch.clone(),
            force: per,
            profile: TimeProfile::Ramp { t0: 0.0, t1: RAMP_S },
        }],
        gravity: Vec3::zeros(),
        pressure: None,
    };
    let ip = ImplicitEulerParams {
        dt: params.dt,
        rayleigh_alpha: params.alpha,
        rayleigh_beta: params.beta,
        newton: NewtonParams {
            max_iters: 30,
            rel_tol: 1e-8,
            // Plain Newton (no line search) may overshoot on the way to a
            // converged step this far into the nonlinear range.
            max_residual_growth: 1e12,
            require_convergence: true,
            ..NewtonParams::default()
        },
        linear: LinearSolverKind::Cholesky,
        stiffness_every: 1,
        max_halvings: 0,
    };
    let mut ie = ImplicitEuler::new(&s.mesh, s.mass.clone(), ip).map_err(|e| ExperimentError::Setup(e.to_string()))?;
    let mut state = TissueState::at_rest(s.mesh.num_nodes());
    let mut model = s.model.clone();
    let (mut top, mut fields) = (Vec::with_capacity(steps), Vec::new());
    let t0 = Instant::now();
    for step in 1..=steps {
        let rep = ie.step(&mut state, &mut model, &loads, &s.fixed);
        if let Some(f) = rep.failure {
            return Err(ExperimentError::Step {
                model: "full nvtmm".into(),
                step,
                reason: f.to_string(),
            });
        }
        top.push(state.u[s.top as usize].z);
        if step % SAMPLE_EVERY == 0 {
            fields.push(state.u.clone());
        }
    }
    let ms = t0.elapsed().as_secs_f64() * 1e3 / steps as f64;
    Ok((top, fields, ms))
}

/// Reduced force Φᵀ f of the load at time t.
fn reduced_load<const R: usize>(rows: &[nalgebra::SMatrix<f64, 3, R>], patch: &[u32], t: f64) -> SVector<f64, R> {
    let per = Vec3::new(0.0, 0.0, -LOAD_N / patch.len() as f64) * load_scale(t);
    let mut f = SVector::zeros();
    for &p in patch {
        if let Some(row) = rows.get(p as usize) {
            f += row.tr_mul(&per);
        }
    }
    f
}

/// A reduced model as the experiment drives it.
trait Stepper<const R: usize> {
    fn advance(&mut self, f: &SVector<f64, R>) -> bool;
    fn coords(&self) -> SVector<f64, R>;
    fn restart(&mut self);
}

impl<const R: usize> Stepper<R> for ReducedDynamics<R> {
    fn advance(&mut self, f: &SVector<f64, R>) -> bool {
        self.step(f);
        true
    }
    fn coords(&self) -> SVector<f64, R> {
        *self.q()
    }
    fn restart(&mut self) {
        self.reset();
    }
}

impl<const R: usize> Stepper<R> for CubicReducedDynamics<R> {
    fn advance(&mut self, f: &SVector<f64, R>) -> bool {
        self.step(f).is_ok()
    }
    fn coords(&self) -> SVector<f64, R> {
        *self.q()
    }
    fn restart(&mut self) {
        self.reset();
    }
}

struct Measured {
    us_median: f64,
    us_p99: f64,
    top_err: f64,
    top_end: f64,
    rms_err: f64,
    failed: usize,
}

#[allow(clippy::too_many_arguments)]
fn measure<const R: usize>(
    d: &mut dyn Stepper<R>,
    rows: &[nalgebra::SMatrix<f64, 3, R>],
    s: &Setup,
    dt: f64,
    steps: usize,
    full_top: &[f64],
    full_fields: &[Vec<Vec3>],
) -> Measured {
    let mut failed = 0;
    let (mut e2, mut n2) = (0.0, 0.0);
    let mut top_err: f64 = 0.0;
    let full_max = full_top
        .iter()
        .fold(0.0f64, |a, z| a.max(z.abs()))
        .max(f64::MIN_POSITIVE);
    let mut top_end = 0.0;
    d.restart();
    for step in 1..=steps {
        let f = reduced_load(rows, &s.patch, step as f64 * dt);
        if !d.advance(&f) {
            failed += 1;
        }
        let q = d.coords();
        let top = rows.get(s.top as usize).map_or(0.0, |row| (row * q).z);
        top_end = top;
        top_err = top_err.max((top - full_top[step - 1]).abs() / full_max);
        if step % SAMPLE_EVERY == 0 {
            if let Some(field) = full_fields.get(step / SAMPLE_EVERY - 1) {
                for (row, uf) in rows.iter().zip(field) {
                    e2 += (row * q - uf).norm_squared();
                    n2 += uf.norm_squared();
                }
            }
        }
    }
    // Timing: the same load history, only the call timed.
    d.restart();
    let mut times = Vec::with_capacity(TIMED_STEPS);
    for step in 1..=TIMED_STEPS + 100 {
        let f = reduced_load(rows, &s.patch, step as f64 * dt);
        let t = Instant::now();
        std::hint::black_box(d.advance(&f));
        let us = t.elapsed().as_secs_f64() * 1e6;
        if step > 100 {
            times.push(us);
        }
    }
    times.sort_by(f64::total_cmp);
    Measured {
        us_median: times[times.len() / 2],
        us_p99: times[((times.len() as f64 * 0.99) as usize).min(times.len() - 1)],
        top_err,
        top_end,
        rms_err: if n2 > 0.0 { (e2 / n2).sqrt() } else { 0.0 },
        failed,
    }
}

/// Linear and cubic dynamics on one basis.
#[allow(clippy::too_many_arguments)]
fn run_basis<const R: usize>(
    s: &Setup,
    mat: &Material,
    basis: &ModalBasis,
    name: &str,
    basis_s: f64,
    params: &DynamicsParams,
    steps: usize,
    full_top: &[f64],
    full_fields: &[Vec<Vec3>],
) -> Result<Vec<CubicRow>, ExperimentError> {
    let setup = |e: crate::reduced::ReducedError| ExperimentError::Setup(format!("r = {}: {e}", basis.len()));
    let rows = basis_rows::<R>(basis).map_err(setup)?;
    let mut out = Vec::new();
    let mut lin = Box::new(ReducedDynamics::<R>::new(basis, params).map_err(setup)?);
    let m = measure::<R>(lin.as_mut(), &rows, s, params.dt, steps, full_top, full_fields);
    let row = |model: &str, pre: f64, mb: f64, m: Measured| CubicRow {
        r: basis.len(),
        basis: name.to_string(),
        model: model.to_string(),
        basis_s,
        precompute_s: pre,
        coefficient_mb: mb,
        us_median: m.us_median,
        us_p99: m.us_p99,
        top_err: m.top_err,
        top_end_m: m.top_end,
        rms_err: m.rms_err,
        failed_steps: m.failed,
    };
    out.push(row("linear", 0.0, 0.0, m));
    let cubic = Arc::new(CubicStvk::new(&s.mesh, mat, basis).map_err(setup)?);
    let (pre, mb) = (cubic.precompute_s(), cubic.coefficient_bytes() as f64 / 1e6);
    let mut cub =
        Box::new(CubicReducedDynamics::<R>::new(cubic, rows.clone(), params, DEFAULT_NEWTON_ITERS).map_err(setup)?);
    let m = measure::<R>(cub.as_mut(), &rows, s, params.dt, steps, full_top, full_fields);
    out.push(row("cubic", pre, mb, m));
    Ok(out)
}

/// Runs the experiment; writes `cubic.csv`, `cubic_precompute.csv`,
/// `cubic_series.csv` and `cubic.md` into `out`. `quick`: 1458 nodes,
/// r = 8 and 16, no precompute rows on larger meshes.
pub fn run(out: &Path, quick: bool) -> Result<CubicResults, ExperimentError> {
    std::fs::create_dir_all(out).map_err(|e| ExperimentError::io(out, e))?;
    let nodes = if quick { 1458 } else { 5832 };
    let rs: &[usize] = if quick { &[8, 16] } else { &[8, 16, 24, 32] };
    let arch = generate(&ArchParams::default(), nodes).map_err(|e| ExperimentError::Setup(e.to_string()))?;
    let mat = Material::aorta();
    let s = Setup {
        model: Nvtmm::new(&arch.mesh, &mat),
        mass: arch.mesh.lumped_mass(mat.density),
        fixed: standard_load(&arch, STANDARD_FORCE_N).fixed,
        patch: probe_region(&arch),
        top: arch_top_node(&arch),
        mesh: arch.mesh.clone(),
    };
    let params = bench_dynamics_params();
    let steps = (END_S / params.dt).round() as usize;
    let (full_top, full_fields, full_ms) = full_reference(&s, &params, steps)?;
    let u0 = vec![Vec3::zeros(); s.mesh.num_nodes()];
    let bp = BasisParams::default();
    let contact_basis = |r: usize| -> Result<(ModalBasis, f64), ExperimentError> {
        let t = Instant::now();
        let b = ModalBasis::compute(&crate::reduced::BasisSpec {
            stiffness: crate::reduced::Stiffness::Model {
                mesh: &s.mesh,
                model: &s.model,
                u: &u0,
            },
            mass: &s.mass,
            fixed: &s.fixed,
            r,
            statics: crate::reduced::Statics::Compressed {
                contact: &s.patch,
                max_static: r / 2,
            },
            warm: None,
            params: bp,
        })
        .map_err(|e| ExperimentError::Setup(format!("basis r = {r}: {e}")))?;
        Ok((b, t.elapsed().as_secs_f64()))
    };
    let mut load_pattern = vec![Vec3::zeros(); s.mesh.num_nodes()];
    for &p in &s.patch {
        load_pattern[p as usize] = Vec3::new(0.0, 0.0, -1.0);
    }
    let mut rows = Vec::new();
    let mut series: Vec<(String, Vec<f64>)> = Vec::new();
    for &r in rs {
        let (plain, plain_s) = contact_basis(r)?;
        let base_r = r.div_ceil(2);
        let t = Instant::now();
        let (base, _) = contact_basis(base_r)?;
        let enriched = with_load_derivatives(&s.mesh, &s.model, &s.mass, &base, &load_pattern, r)
            .map_err(|e| ExperimentError::Setup(format!("derivatives r = {r}: {e}")))?;
        let enriched_s = t.elapsed().as_secs_f64();
        for (b, name, bs) in [
            (&plain, "modes+static", plain_s),
            (&enriched, "+derivatives", enriched_s),
        ] {
            let got = match r {
                0..=8 => run_basis::<8>(&s, &mat, b, name, bs, &params, steps, &full_top, &full_fields)?,
                9..=16 => run_basis::<16>(&s, &mat, b, name, bs, &params, steps, &full_top, &full_fields)?,
                17..=24 => run_basis::<24>(&s, &mat, b, name, bs, &params, steps, &full_top, &full_fields)?,
                _ => run_basis::<32>(&s, &mat, b, name, bs, &params, steps, &full_top, &full_fields)?,
            };
            rows.extend(got);
        }
        if r == 16 {
            // Top-node histories of this r for the series file.
            for (b, name) in [(&plain, "modes+static"), (&enriched, "+derivatives")] {
                let rows16 = basis_rows::<16>(b).map_err(|e| ExperimentError::Setup(e.to_string()))?;
                let mut lin = Box::new(
                    ReducedDynamics::<16>::new(b, &params).map_err(|e| ExperimentError::Setup(e.to_string()))?,
                );
                let cubic =
                    Arc::new(CubicStvk::new(&s.mesh, &mat, b).map_err(|e| ExperimentError::Setup(e.to_string()))?);
                let mut cub = Box::new(
                    CubicReducedDynamics::<16>::new(cubic, rows16.clone(), &params, DEFAULT_NEWTON_ITERS)
                        .map_err(|e| ExperimentError::Setup(e.to_string()))?,
                );
                let (mut zl, mut zc) = (Vec::new(), Vec::new());
                for step in 1..=steps {
                    let f = reduced_load(&rows16, &s.patch, step as f64 * params.dt);
                    lin.step(&f);
                    let _ = cub.step(&f);
                    zl.push(lin.displacement_at(s.top).map_or(0.0, |u| u.z));
                    zc.push(cub.displacement_at(s.top).map_or(0.0, |u| u.z));
                }
                series.push((format!("linear {name}"), zl));
                series.push((format!("cubic {name}"), zc));
            }
        }
    }
    let mut precompute = Vec::new();
    if !quick {
        for (n, r) in [(23328, 8), (23328, 16)] {
            let arch = generate(&ArchParams::default(), n).map_err(|e| ExperimentError::Setup(e.to_string()))?;
            let mesh = &arch.mesh;
            let model = Nvtmm::new(mesh, &mat);
            let mass = mesh.lumped_mass(mat.density);
            let fixed = standard_load(&arch, STANDARD_FORCE_N).fixed;
            let patch = probe_region(&arch);
            let z = vec![Vec3::zeros(); mesh.num_nodes()];
            let t = Instant::now();
            let b = ModalBasis::compute(&crate::reduced::BasisSpec {
                stiffness: crate::reduced::Stiffness::Model {
                    mesh,
                    model: &model,
                    u: &z,
                },
                mass: &mass,
                fixed: &fixed,
                r,
                statics: crate::reduced::Statics::Compressed {
                    contact: &patch,
                    max_static: r / 2,
                },
                warm: None,
                params: bp,
            })
            .map_err(|e| ExperimentError::Setup(format!("basis {n} nodes: {e}")))?;
            let basis_s = t.elapsed().as_secs_f64();
            let c = CubicStvk::new(mesh, &mat, &b).map_err(|e| ExperimentError::Setup(e.to_string()))?;
            precompute.push(PrecomputeRow {
                nodes: mesh.num_nodes(),
                tets: mesh.tets().len(),
                r,
                basis_s,
                precompute_s: c.precompute_s(),
                coefficient_mb: c.coefficient_bytes() as f64 / 1e6,
            });
        }
    }
    let res = CubicResults {
        nodes: s.mesh.num_nodes(),
        tets: s.mesh.tets().len(),
        full_top_end_m: full_top.last().copied().unwrap_or(0.0),
        full_ms_per_step: full_ms,
        rows,
        precompute,
    };
    write_outputs(out, &res, params.dt, &full_top, &series)?;
    Ok(res)
}

fn write_outputs(
    out: &Path,
    res: &CubicResults,
    dt: f64,
    full_top: &[f64],
    series: &[(String, Vec<f64>)],
) -> Result<(), ExperimentError> {
    let write = |name: &str, text: &str| {
        let p = out.join(name);
        std::fs::File::create(&p)
            .and_then(|mut f| f.write_all(text.as_bytes()))
            .map_err(|e| ExperimentError::io(&p, e))
    };
    let mut s = String::from(
        "r,basis,model,basis_s,precompute_s,coefficient_mb,us_median,us_p99,top_err,top_end_m,rms_err,failed_steps\n",
    );
    for r in &res.rows {
        s.push_str(&format!(
            "{},{},{},{:.3},{:.4},{:.3},{:.3},{:.3},{:.6e},{:.6e},{:.6e},{}\n",
            r.r,
            r.basis,
            r.model,
            r.basis_s,
            r.precompute_s,
            r.coefficient_mb,
            r.us_median,
            r.us_p99,
            r.top_err,
            r.top_end_m,
            r.rms_err,
            r.failed_steps
        ));
    }
    write("cubic.csv", &s)?;
    let mut s = String::from("nodes,tets,r,basis_s,precompute_s,coefficient_mb\n");
    for p in &res.precompute {
        s.push_str(&format!(
            "{},{},{},{:.3},{:.3},{:.3}\n",
            p.nodes, p.tets, p.r, p.basis_s, p.precompute_s, p.coefficient_mb
        ));
    }
    write("cubic_precompute.csv", &s)?;
    let mut s = String::from("t_s,full_top_z_m");
    for (name, _) in series {
        let col = name
            .replace("modes+static", "modes_static")
            .replace("+derivatives", "derivatives");
        s.push_str(&format!(",{}_top_z_m", col.replace(' ', "_")));
    }
    s.push('\n');
    for (i, z) in full_top.iter().enumerate() {
        s.push_str(&format!("{:.4},{:.6e}", (i + 1) as f64 * dt, z));
        for (_, v) in series {
            s.push_str(&format!(",{:.6e}", v.get(i).copied().unwrap_or(f64::NAN)));
        }
        s.push('\n');
    }
    write("cubic_series.csv", &s)?;

    let mut md = format!(
        "Arch {} nodes, {} tets; probe patch pushed by {:.2} N (ramp {:.0} ms, held to {:.0} ms); \
         full NVTMM implicit Euler (Newton to 1e-8): top node z at the end {:.3} mm, {:.1} ms per step. \
         Cubic: {} Newton iterations per step.\n\n\
         | r | basis | model | basis (s) | precompute (s) | coeff. (MB) | step median (µs) | step p99 (µs) | top-node error | top z end (mm) | RMS error | failed steps |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|\n",
        res.nodes,
        res.tets,
        LOAD_N,
        RAMP_S * 1e3,
        END_S * 1e3,
        res.full_top_end_m * 1e3,
        res.full_ms_per_step,
        DEFAULT_NEWTON_ITERS,
    );
    for r in &res.rows {
        md.push_str(&format!(
            "| {} | {} | {} | {:.2} | {} | {} | {:.2} | {:.2} | {:.1} % | {:.3} | {:.1} % | {} |\n",
            r.r,
            r.basis,
            r.model,
            r.basis_s,
            if r.model == "cubic" {
                format!("{:.3}", r.precompute_s)
            } else {
                "–".into()
            },
            if r.model == "cubic" {
                format!("{:.2}", r.coefficient_mb)
            } else {
                "–".into()
            },
            r.us_median,
            r.us_p99,
            100.0 * r.top_err,
            r.top_end_m * 1e3,
            100.0 * r.rms_err,
            r.failed_steps
        ));
    }
    if !res.precompute.is_empty() {
        md.push_str(
            "\nPrecompute on a larger arch (basis: modes+static):\n\n\
             | nodes | tets | r | basis (s) | cubic precompute (s) | coeff. (MB) |\n|---|---|---|---|---|---|\n",
        );
        for p in &res.precompute {
            md.push_str(&format!(
                "| {} | {} | {} | {:.2} | {:.3} | {:.2} |\n",
                p.nodes, p.tets, p.r, p.basis_s, p.precompute_s, p.coefficient_mb
            ));
        }
    }
    write("cubic.md", &md)
}
