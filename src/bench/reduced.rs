//! `nvtmm bench reduced`: the cost of the reduced model at one mesh size.
//!
//! Set-up: the built-in arch with `nodes` nodes, both ends fixed (the
//! standard load's supports, [`crate::bench::standard_load`]), NVTMM (StVK)
//! with the aorta material. The contact region is the standard probe
//! footprint: the outer-wall nodes within [`PROBE_RADIUS_M`](crate::bench::PROBE_RADIUS_M) of the arch top
//! ([`arch_top_node`](crate::bench::arch_top_node)). Measured:
//!
//! - `basis_s`: [`ModalBasis::compute`] (`Statics::Compressed`) with r columns, up to ⌊r/2⌋
//!   of them static modes of the region, default tolerance, cold start;
//! - `us_per_step`, `us_per_step_p99`: median and 99th percentile of one
//!   [`ReducedDynamics::step_with_contact`] (the haptic loop's step), over
//!   `steps` steps of a probe pressing the region with a stiff penalty
//!   (10⁴ N/m per touched node along −z); only the call is timed;
//! - `refresh_ms`: one linearization refresh at a displacement of the
//!   pressed state as the service's background thread does it after each
//!   full step ([`crate::service::background::Background::build_model_from_step`]):
//!   K_r = Φᵀ K Φ from the tangent the full step assembled
//!   ([`Refresher::project_tangent`]: r block-sparse mat-vecs and Φᵀ(KΦ)),
//!   the projections Φᵀ M ū and Φᵀ f̄, and the new [`ReducedDynamics`] on
//!   the shared rows (median of 5);
//! - `refresh_assembly_ms` (extra key): the tangent assembly the full step
//!   does anyway, timed on its own (median of 5), so that
//!   `refresh_ms + refresh_assembly_ms` is a refresh that assembles its own
//!   tangent ([`Refresher::reduced_stiffness`]);
//! - `basis_warm_s`, `basis_warm_iterations` (extra keys): recomputing the
//!   basis at the pressed state warm-started from the rest basis, as a
//!   background basis refresh does; `basis_iterations` is the cold count.

use crate::bench::{standard_load, STANDARD_FORCE_N};
use crate::material::Material;
use crate::math::Vec3;
use crate::mesh::arch::{generate, ArchParams};
use crate::model::nvtmm::Nvtmm;
use crate::model::{BlockTangent, ForceModel};
use crate::reduced::refresh::Refresher;
use crate::reduced::{BasisParams, DynamicsParams, ModalBasis, ReducedDynamics};
use nalgebra::{SMatrix, SVector};
use std::time::Instant;

/// Result of `nvtmm bench reduced` (the JSON keys are a scripting contract).
#[derive(Debug, Clone, serde::Serialize)]
pub struct ReducedBench {
    /// Basis size.
    pub r: usize,
    /// Mesh nodes.
    pub nodes: usize,
    /// Median time of one `step_with_contact` (µs).
    pub us_per_step: f64,
    /// 99th percentile of the same (µs).
    pub us_per_step_p99: f64,
    /// One linearization refresh (ms).
    pub refresh_ms: f64,
    /// Basis computation (s).
    pub basis_s: f64,
    /// Subspace iterations of the cold basis computation.
    pub basis_iterations: usize,
    /// Tangent assembly of the full step (ms), not part of `refresh_ms`.
    pub refresh_assembly_ms: f64,
    /// Basis recomputation at the pressed state, warm-started (s).
    pub basis_warm_s: f64,
    /// Subspace iterations of the warm recomputation.
    pub basis_warm_iterations: usize,
}

/// Capacities the reduced model is compiled for; r runs at the smallest one
/// that holds it.
pub const CAPACITIES: [usize; 5] = [8, 16, 32, 48, 64];

pub use crate::bench::probe_region;

/// The reduced model's damping in the benchmark and experiments.
pub fn bench_dynamics_params() -> DynamicsParams {
    DynamicsParams {
        dt: 1e-3,
        alpha: 5.0,
        beta: 1e-4,
    }
}

/// Runs the benchmark (`steps` timed steps after 100 warm-up steps).
pub fn bench_reduced(r: usize, nodes: usize, steps: usize) -> Result<ReducedBench, String> {
    let cap = CAPACITIES
        .iter()
        .copied()
        .find(|&c| c >= r)
        .ok_or_else(|| format!("--r {r}: allowed 1..={}", CAPACITIES[CAPACITIES.len() - 1]))?;
    if r == 0 {
        return Err("--r 0: allowed 1..=64".into());
    }
    if steps == 0 {
        return Err("--steps must be at least 1".into());
    }
    match cap {
        8 => run::<8>(r, nodes, steps),
        16 => run::<16>(r, nodes, steps),
        32 => run::<32>(r, nodes, steps),
        48 => run::<48>(r, nodes, steps),
        _ => run::<64>(r, nodes, steps),
    }
}

fn run<const R: usize>(r: usize, nodes: usize, steps: usize) -> Result<ReducedBench, String> {
    let arch = generate(&ArchParams::default(), nodes).map_err(|e| e.to_string())?;
    let mesh = &arch.mesh;
    let mat = Material::aorta();
    let model = Nvtmm::new(mesh, &mat);
    let mass = mesh.lumped_mass(mat.density);
    let fixed = standard_load(&arch, STANDARD_FORCE_N).fixed;
    let contact = probe_region(&arch);
    let u0 = vec![Vec3::zeros(); mesh.num_nodes()];
    let t0 = Instant::now();
    let basis = ModalBasis::compute(&crate::reduced::BasisSpec {
        stiffness: crate::reduced::Stiffness::Model {
            mesh,
            model: &model,
            u: &u0,
        },
        mass: &mass,
        fixed: &fixed,
        r,
        statics: crate::reduced::Statics::Compressed {
            contact: &contact,
            max_static: r / 2,
        },
        warm: None,
        params: BasisParams::default(),
    })
    .map_err(|e| format!("basis: {e}"))?;
    let basis_s = t0.elapsed().as_secs_f64();
    let params = bench_dynamics_params();
    let mut d = Box::new(ReducedDynamics::<R>::new(&basis, &params).map_err(|e| e.to_string())?);

    // A probe pressing the region down: penalty k per touched node on the
    // penetration below a plane that descends 1 mm over the first 200 steps.
    let k_pen = 1e4;
    let n = Vec3::new(0.0, 0.0, 1.0);
    let z0: Vec<f64> = contact.iter().map(|&c| mesh.rest()[c as usize].z).collect();
    let zmax = z0.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let mut times = Vec::with_capacity(steps);
    let mut kc = Box::new(SMatrix::<f64, R, R>::zeros());
    for step in 0..steps + 100 {
        let plane = zmax - 1e-3 * ((step as f64) / 200.0).min(1.0);
        let mut f = SVector::<f64, R>::zeros();
        kc.fill(0.0);
        for (&c, &z) in contact.iter().zip(&z0) {
            let Some(rows) = d.rows_at(c) else { continue };
            let uz = (rows * d.q()).dot(&n);
            let pen = plane - (z + uz);
            if pen < 0.0 {
                let nr = rows.tr_mul(&n);
                f += nr * (k_pen * pen);
                *kc += nr * nr.transpose() * k_pen;
            }
        }
        let t = Instant::now();
        std::hint::black_box(d.step_with_contact(&f, &kc));
        let us = t.elapsed().as_secs_f64() * 1e6;
        if step >= 100 {
            times.push(us);
        }
    }
    times.sort_by(f64::total_cmp);
    let us_per_step = times[times.len() / 2];
    let us_per_step_p99 = times[((times.len() as f64 * 0.99) as usize).min(times.len() - 1)];

    // One refresh at the pressed state.
    let mut q = nalgebra::DVector::zeros(basis.len());
    for j in 0..basis.len() {
        q[j] = d.q()[j];
    }
    let u = basis.expand(&q);
    let mut refresher = Refresher::new(mesh, &basis, &mass);
    let rows = d.rows().clone();
    let fbar = vec![Vec3::zeros(); mesh.num_nodes()];
    let mut tangent = BlockTangent::zeros(mesh);
    let (mut rt, mut at) = (Vec::new(), Vec::new());
    for _ in 0..5 {
        let t = Instant::now();
        tangent.clear();
        model.add_stiffness(&u, &mut tangent);
        at.push(t.elapsed().as_secs_f64() * 1e3);
        let t = Instant::now();
        let kr = refresher.project_tangent(&tangent);
        let m = ReducedDynamics::<R>::with_rows(rows.clone(), basis.len(), &kr, &params).map_err(|e| e.to_string())?;
        std::hint::black_box((&m, refresher.project_mass(&u), refresher.project_force(&fbar)));
        rt.push(t.elapsed().as_secs_f64() * 1e3);
    }
    rt.sort_by(f64::total_cmp);
    at.sort_by(f64::total_cmp);

    // The background basis refresh: the same basis recomputed at the
    // pressed state, warm-started from the rest basis.
    let t = Instant::now();
    let warm = ModalBasis::compute(&crate::reduced::BasisSpec {
        stiffness: crate::reduced::Stiffness::Model {
            mesh,
            model: &model,
            u: &u,
        },
        mass: &mass,
        fixed: &fixed,
        r,
        statics: crate::reduced::Statics::Compressed {
            contact: &contact,
            max_static: r / 2,
        },
        warm: Some(&basis),
        params: BasisParams::default(),
    })
    .map_err(|e| format!("warm basis: {e}"))?;
    let basis_warm_s = t.elapsed().as_secs_f64();
    Ok(ReducedBench {
        r,
        nodes: mesh.num_nodes(),
        us_per_step,
        us_per_step_p99,
        refresh_ms: rt[2],
        basis_s,
        basis_iterations: basis.iterations,
        refresh_assembly_ms: at[2],
        basis_warm_s,
        basis_warm_iterations: warm.iterations,
    })
}
