//! `nvtmm experiment reduced`: reduced vs full response at the contact, over
//! r and with/without contact (static) modes, and the region-of-interest
//! trade. The definitions are in docs/RESULTS.md ("Reduced model against
//! the full model"); in short:
//!
//! - Arch with both ends fixed, NVTMM StVK linearized at rest (K(0)), aorta
//!   material. Probe patch: the outer-wall nodes within 5 mm of the arch top
//!   ([`crate::bench::reduced::probe_region`]). Load shape: equal −z forces on
//!   the patch nodes.
//! - Full: the static linear solution K u = f (sparse Cholesky); δ_full is
//!   the −z displacement of the top node per newton of total force.
//! - Reduced (r columns, mass-orthonormal, diagonal K_r): q = K_r⁻¹ Φᵀ f,
//!   u = Φ q; δ_red likewise.
//! - Contact force for a 5 mm indentation of the top node: F = 5 mm / δ;
//!   error |F_red − F_full| / F_full. Displacement at the contact under the
//!   full model's 5 mm force: |u_red − u_full| / |u_full| at the top node.
//! - ROI: the same full static solve under the standard load (0.15 N on the
//!   patch) on the sub-mesh of an arc-length interval around the arch top
//!   (cut fixed) against the whole mesh: nodes, solve time, basis time
//!   (r = 16, contact modes) and the top-node displacement error.

use super::ExperimentError;
use crate::bench::reduced::probe_region;
use crate::bench::{arch_top_node, standard_load, STANDARD_FORCE_N};
use crate::material::Material;
use crate::math::Vec3;
use crate::mesh::arch::{generate, ArchParams};
use crate::mesh::roi::{arch_node_arclength, extract, Region, CUT_SET};
use crate::mesh::TetMesh;
use crate::model::nvtmm::Nvtmm;
use crate::model::{BlockTangent, ForceModel};
use crate::reduced::{BasisParams, ModalBasis};
use crate::solver::linear::{project_fixed, CholeskySolver};
use std::io::Write;
use std::path::Path;
use std::time::Instant;

/// Indentation of the comparison (m).
pub const INDENT_M: f64 = 5e-3;

/// One row of the table over r.
#[derive(Debug, Clone, serde::Serialize)]
pub struct ReducedRow {
    /// Basis size.
    pub r: usize,
    /// Whether static modes of the patch were added.
    pub contact_modes: bool,
    /// Static directions in the basis.
    pub num_static: usize,
    /// Full contact force for 5 mm (N).
    pub force_full_n: f64,
    /// Reduced contact force for 5 mm (N).
    pub force_reduced_n: f64,
    /// |F_red − F_full| / F_full.
    pub force_err: f64,
    /// |u_red − u_full| / |u_full| at the top node under the full 5 mm force.
    pub disp_err: f64,
    /// Basis computation time (s).
    pub basis_s: f64,
}

/// One row of the region-of-interest table.
#[derive(Debug, Clone, serde::Serialize)]
pub struct RoiRow {
    /// Region: "whole" or the arc-length interval.
    pub region: String,
    /// Nodes simulated.
    pub nodes: usize,
    /// Tets simulated.
    pub tets: usize,
    /// Assembly + Cholesky factor + solve of the static problem (ms).
    pub static_solve_ms: f64,
    /// Basis r = 16 with contact modes (s).
    pub basis_s: f64,
    /// Top-node displacement under the standard load (m).
    pub top_disp_m: f64,
    /// Relative error of that displacement against the whole mesh.
    pub err: f64,
}

/// Static linear solution K(0) u = f with `fixed` clamped; returns u and the
/// time taken (ms).
fn full_static(mesh: &TetMesh, model: &dyn ForceModel, fixed: &[u32], f: &[Vec3]) -> Result<(Vec<Vec3>, f64), String> {
    let t0 = Instant::now();
    let n = mesh.num_nodes();
    let mut k = BlockTangent::zeros(mesh);
    model.add_stiffness(&vec![Vec3::zeros(); n], &mut k);
    let mut mask = vec![false; n];
    for &i in fixed {
        mask[i as usize] = true;
    }
    project_fixed(&mut k, &mask);
    let mut rhs = f.to_vec();
    for (r, &m) in rhs.iter_mut().zip(&mask) {
        if m {
            *r = Vec3::zeros();
        }
    }
    let mut u = vec![Vec3::zeros(); n];
    CholeskySolver::new(&k)?
        .solve(&k, &rhs, &mut u)
        .map_err(|e| format!("full solve: {e}"))?;
    Ok((u, t0.elapsed().as_secs_f64() * 1e3))
}

/// Reduced static displacement of `node` under nodal forces `f`.
fn reduced_static(basis: &ModalBasis, f: &[Vec3], node: u32) -> Vec3 {
    let fr = basis.project(f);
    let q = nalgebra::DVector::from_iterator(basis.len(), fr.iter().zip(&basis.omega2).map(|(a, w)| a / w));
    basis.displacement_at(node, &q).unwrap_or_else(Vec3::zeros)
}

/// Runs the experiment; writes `reduced.csv`, `roi.csv` and `reduced.md`
/// into `out`. `quick`: 1458 nodes, r = 8 and 16 only.
pub fn run(out: &Path, quick: bool) -> Result<(Vec<ReducedRow>, Vec<RoiRow>), ExperimentError> {
    std::fs::create_dir_all(out).map_err(|e| ExperimentError::io(out, e))?;
    let nodes = if quick { 1458 } else { 5832 };
    let rs: &[usize] = if quick { &[8, 16] } else { &[8, 16, 32, 48] };
    let arch = generate(&ArchParams::default(), nodes).map_err(|e| ExperimentError::Setup(e.to_string()))?;
    let mesh = &arch.mesh;
    let mat = Material::aorta();
    let model = Nvtmm::new(mesh, &mat);
    let mass = mesh.lumped_mass(mat.density);
    let load = standard_load(&arch, STANDARD_FORCE_N);
    let fixed = load.fixed.clone();
    let top = arch_top_node(&arch);
    let patch = probe_region(&arch);
    let mut f = vec![Vec3::zeros(); mesh.num_nodes()];
    for &p in &patch {
        f[p as usize] = Vec3::new(0.0, 0.0, -1.0 / patch.len() as f64);
    }
    let (u_full, _) = full_static(mesh, &model, &fixed, &f).map_err(ExperimentError::Setup)?;
    let d_full = u_full[top as usize];
    let force_full = INDENT_M / -d_full.z;
    let u0 = vec![Vec3::zeros(); mesh.num_nodes()];
    let params = BasisParams::default();
    let rmax = rs[rs.len() - 1];
    let t0 = Instant::now();
    let modes = ModalBasis::compute(&crate::reduced::BasisSpec {
        stiffness: crate::reduced::Stiffness::Model {
            mesh,
            model: &model,
            u: &u0,
        },
        mass: &mass,
        fixed: &fixed,
        r: rmax,
        statics: crate::reduced::Statics::All(&[]),
        warm: None,
        params,
    })
    .map_err(|e| ExperimentError::Setup(format!("basis: {e}")))?;
    let modes_s = t0.elapsed().as_secs_f64();
    let mut rows = Vec::new();
    for &r in rs {
        for contact_modes in [false, true] {
            let t = Instant::now();
            let basis = if contact_modes {
                ModalBasis::compute(&crate::reduced::BasisSpec {
                    stiffness: crate::reduced::Stiffness::Model {
                        mesh,
                        model: &model,
                        u: &u0,
                    },
                    mass: &mass,
                    fixed: &fixed,
                    r,
                    statics: crate::reduced::Statics::Compressed {
                        contact: &patch,
                        max_static: r / 2,
                    },
                    warm: Some(&modes),
                    params,
                })
                .map_err(|e| ExperimentError::Setup(format!("basis r = {r}: {e}")))?
            } else {
                ModalBasis {
                    phi: modes.phi.columns(0, r).into_owned(),
                    omega2: modes.omega2[..r].to_vec(),
                    num_static: 0,
                    fixed: modes.fixed.clone(),
                    iterations: modes.iterations,
                }
            };
            let basis_s = if contact_modes {
                t.elapsed().as_secs_f64()
            } else {
                modes_s
            };
            let d_red = reduced_static(&basis, &f, top);
            let force_red = INDENT_M / -d_red.z;
            rows.push(ReducedRow {
                r,
                contact_modes,
                num_static: basis.num_static,
                force_full_n: force_full,
                force_reduced_n: force_red,
                force_err: (force_red - force_full).abs() / force_full,
                disp_err: (d_red - d_full).norm() / d_full.norm(),
                basis_s,
            });
        }
    }

    // Region of interest around the arch top.
    let s_node = arch_node_arclength(&arch);
    let s_top = s_node[top as usize];
    let fz = |mesh: &TetMesh, nodes: &[u32]| {
        let mut f = vec![Vec3::zeros(); mesh.num_nodes()];
        for &p in nodes {
            f[p as usize] = Vec3::new(0.0, 0.0, -STANDARD_FORCE_N / nodes.len() as f64);
        }
        f
    };
    let mut roi_rows = Vec::new();
    let (u_whole, ms_whole) = full_static(mesh, &model, &fixed, &fz(mesh, &patch)).map_err(ExperimentError::Setup)?;
    let roi_basis = |mesh: &TetMesh, model: &dyn ForceModel, fixed: &[u32], patch: &[u32]| {
        let t = Instant::now();
        let m = mesh.lumped_mass(mat.density);
        let u0 = vec![Vec3::zeros(); mesh.num_nodes()];
        ModalBasis::compute(&crate::reduced::BasisSpec {
            stiffness: crate::reduced::Stiffness::Model { mesh, model, u: &u0 },
            mass: &m,
            fixed,
            r: 16,
            statics: crate::reduced::Statics::Compressed {
                contact: patch,
                max_static: 8,
            },
            warm: None,
            params,
        })
        .map(|_| t.elapsed().as_secs_f64())
        .map_err(|e| ExperimentError::Setup(format!("roi basis: {e}")))
    };
    let whole_top = u_whole[top as usize];
    roi_rows.push(RoiRow {
        region: "whole arch".into(),
        nodes: mesh.num_nodes(),
        tets: mesh.tets().len(),
        static_solve_ms: ms_whole,
        basis_s: roi_basis(mesh, &model, &fixed, &patch)?,
        top_disp_m: whole_top.norm(),
        err: 0.0,
    });
    for half in [0.06, 0.03, 0.015] {
        let region = Region::Interval {
            node_value: s_node.clone(),
            lo: s_top - half,
            hi: s_top + half,
        };
        let sub = extract(mesh, &region).map_err(|e| ExperimentError::Setup(e.to_string()))?;
        let smesh = &sub.mesh;
        let smodel = Nvtmm::new(smesh, &mat);
        let mut sfixed: Vec<u32> = fixed.iter().filter_map(|&v| sub.from_full(v)).collect();
        sfixed.extend_from_slice(smesh.node_set(CUT_SET).unwrap_or(&[]));
        sfixed.sort_unstable();
        sfixed.dedup();
        let spatch: Vec<u32> = patch.iter().filter_map(|&v| sub.from_full(v)).collect();
        let stop = sub
            .from_full(top)
            .ok_or_else(|| ExperimentError::Setup("the roi lost the top node".into()))?;
        let (u, ms) = full_static(smesh, &smodel, &sfixed, &fz(smesh, &spatch)).map_err(ExperimentError::Setup)?;
        let d = u[stop as usize];
        roi_rows.push(RoiRow {
            region: format!("arc length ±{:.0} mm", half * 1e3),
            nodes: smesh.num_nodes(),
            tets: smesh.tets().len(),
            static_solve_ms: ms,
            basis_s: roi_basis(smesh, &smodel, &sfixed, &spatch)?,
            top_disp_m: d.norm(),
            err: (d - whole_top).norm() / whole_top.norm(),
        });
    }
    write_outputs(out, mesh.num_nodes(), &rows, &roi_rows)?;
    Ok((rows, roi_rows))
}

fn write_outputs(out: &Path, nodes: usize, rows: &[ReducedRow], roi: &[RoiRow]) -> Result<(), ExperimentError> {
    let csv = out.join("reduced.csv");
    let mut s = String::from("r,contact_modes,num_static,force_full_n,force_reduced_n,force_err,disp_err,basis_s\n");
    for r in rows {
        s.push_str(&format!(
            "{},{},{},{:.6e},{:.6e},{:.6e},{:.6e},{:.3}\n",
            r.r, r.contact_modes, r.num_static, r.force_full_n, r.force_reduced_n, r.force_err, r.disp_err, r.basis_s
        ));
    }
    std::fs::write(&csv, s).map_err(|e| ExperimentError::io(&csv, e))?;
    let csv = out.join("roi.csv");
    let mut s = String::from("region,nodes,tets,static_solve_ms,basis_s,top_disp_m,err\n");
    for r in roi {
        s.push_str(&format!(
            "{},{},{},{:.3},{:.3},{:.6e},{:.6e}\n",
            r.region, r.nodes, r.tets, r.static_solve_ms, r.basis_s, r.top_disp_m, r.err
        ));
    }
    std::fs::write(&csv, s).map_err(|e| ExperimentError::io(&csv, e))?;
    let md = out.join("reduced.md");
    let mut f = std::fs::File::create(&md).map_err(|e| ExperimentError::io(&md, e))?;
    let mut text = format!(
        "Arch {nodes} nodes; 5 mm indentation of the arch top (linear static, probe patch load).\n\n\
         | r | contact modes | static dirs | F full (N) | F reduced (N) | force error | displacement error | basis (s) |\n\
         |---|---|---|---|---|---|---|---|\n"
    );
    for r in rows {
        text.push_str(&format!(
            "| {} | {} | {} | {:.4} | {:.4} | {:.2} % | {:.2} % | {:.2} |\n",
            r.r,
            if r.contact_modes { "yes" } else { "no" },
            r.num_static,
            r.force_full_n,
            r.force_reduced_n,
            100.0 * r.force_err,
            100.0 * r.disp_err,
            r.basis_s
        ));
    }
    text.push_str(
        "\nRegion of interest (standard load 0.15 N, linear static):\n\n\
         | region | nodes | tets | static solve (ms) | basis r=16 (s) | top |u| (mm) | error vs whole |\n\
         |---|---|---|---|---|---|---|\n",
    );
    for r in roi {
        text.push_str(&format!(
            "| {} | {} | {} | {:.1} | {:.2} | {:.4} | {:.2} % |\n",
            r.region,
            r.nodes,
            r.tets,
            r.static_solve_ms,
            r.basis_s,
            r.top_disp_m * 1e3,
            100.0 * r.err
        ));
    }
    f.write_all(text.as_bytes()).map_err(|e| ExperimentError::io(&md, e))?;
    Ok(())
}
