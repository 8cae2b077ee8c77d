//! Rough timings of the reduced model (single runs with `Instant` on a shared
//! machine, not a benchmark): modal basis computation cold and warm-started,
//! and the reduced implicit Euler `step` at r = 8, 16, 32.
//!
//! `cargo run --release --example reduced_timing [nodes]` (default 1458).

use nalgebra::SVector;
use nvtmm::material::Material;
use nvtmm::math::Vec3;
use nvtmm::mesh::arch::{generate, ArchParams};
use nvtmm::model::nvtmm::Nvtmm;
use nvtmm::model::{BlockTangent, ForceModel};
use nvtmm::reduced::{BasisParams, DynamicsParams, ModalBasis, ReducedDynamics};
use nvtmm::solver::linear::{project_fixed, CholeskySolver};
use std::time::Instant;

fn time_steps<const R: usize>(basis: &ModalBasis, node: u32) -> Result<f64, Box<dyn std::error::Error>> {
    let params = DynamicsParams {
        dt: 1e-3,
        alpha: 5.0,
        beta: 1e-4,
    };
    let mut d = Box::new(ReducedDynamics::<R>::new(basis, &params)?);
    let f = d
        .project_nodal(&[(node, Vec3::new(0.0, 0.0, -0.1))])
        .map_err(|e| format!("node {} out of range", e.0))?;
    let steps = 100_000;
    let t = Instant::now();
    let mut acc = SVector::<f64, R>::zeros();
    for _ in 0..steps {
        d.step(&f);
        acc += d.q();
    }
    std::hint::black_box(acc);
    Ok(t.elapsed().as_secs_f64() / steps as f64)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let n: usize = std::env::args().nth(1).and_then(|s| s.parse().ok()).unwrap_or(1458);
    let arch = generate(&ArchParams::default(), n)?;
    let mesh = &arch.mesh;
    let mat = Material::aorta();
    let model = Nvtmm::new(mesh, &mat);
    let mass = mesh.lumped_mass(mat.density);
    let mut fixed = mesh.node_set("inlet").ok_or("no inlet")?.to_vec();
    fixed.extend_from_slice(mesh.node_set("outlet_descending").ok_or("no outlet")?);
    let node = arch.node(arch.top_ring, 0, arch.grid.layers - 1) as u32;
    let rest = vec![Vec3::zeros(); mesh.num_nodes()];
    // A nearby linearization point: the linear response to a point load at
    // the arch top, scaled to 0.5 mm there.
    let pressed = {
        let mut k = BlockTangent::zeros(mesh);
        model.add_stiffness(&rest, &mut k);
        let mut mask = vec![false; mesh.num_nodes()];
        fixed.iter().for_each(|&f| mask[f as usize] = true);
        project_fixed(&mut k, &mask);
        let mut f = vec![Vec3::zeros(); mesh.num_nodes()];
        f[node as usize] = Vec3::new(0.0, 0.0, -1.0);
        let mut u = vec![Vec3::zeros(); mesh.num_nodes()];
        CholeskySolver::new(&k)?
            .solve(&k, &f, &mut u)
            .map_err(|e| format!("{e:?}"))?;
        let s = 5e-4 / u[node as usize].norm();
        u.iter().map(|x| x * s).collect::<Vec<Vec3>>()
    };
    println!(
        "{} nodes, {} tets (rough single-run timings)",
        mesh.num_nodes(),
        mesh.tets().len()
    );
    for r in [8, 16, 32] {
        let t = Instant::now();
        let cold = ModalBasis::compute(&nvtmm::reduced::BasisSpec {
            stiffness: nvtmm::reduced::Stiffness::Model {
                mesh,
                model: &model,
                u: &rest,
            },
            mass: &mass,
            fixed: &fixed,
            r,
            statics: nvtmm::reduced::Statics::None,
            warm: None,
            params: nvtmm::reduced::BasisParams::default(),
        })
        .map_err(|e| format!("rest: {e}"))?;
        let t_cold = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let warm = ModalBasis::compute(&nvtmm::reduced::BasisSpec {
            stiffness: nvtmm::reduced::Stiffness::Model {
                mesh,
                model: &model,
                u: &pressed,
            },
            mass: &mass,
            fixed: &fixed,
            r,
            statics: nvtmm::reduced::Statics::None,
            warm: Some(&cold),
            params: nvtmm::reduced::BasisParams::default(),
        })
        .map_err(|e| format!("pressed: {e}"))?;
        let t_warm = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let again = ModalBasis::compute(&nvtmm::reduced::BasisSpec {
            stiffness: nvtmm::reduced::Stiffness::Model {
                mesh,
                model: &model,
                u: &pressed,
            },
            mass: &mass,
            fixed: &fixed,
            r,
            statics: nvtmm::reduced::Statics::None,
            warm: None,
            params: nvtmm::reduced::BasisParams::default(),
        })?;
        let t_again = t.elapsed().as_secs_f64();
        // The same refresh at a looser tolerance, where the start matters.
        let loose = BasisParams {
            tol: 1e-6,
            ..BasisParams::default()
        };
        let t = Instant::now();
        let lw = ModalBasis::compute(&nvtmm::reduced::BasisSpec {
            stiffness: nvtmm::reduced::Stiffness::Model {
                mesh,
                model: &model,
                u: &pressed,
            },
            mass: &mass,
            fixed: &fixed,
            r,
            statics: nvtmm::reduced::Statics::All(&[]),
            warm: Some(&cold),
            params: loose,
        })?;
        let t_lw = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let lc = ModalBasis::compute(&nvtmm::reduced::BasisSpec {
            stiffness: nvtmm::reduced::Stiffness::Model {
                mesh,
                model: &model,
                u: &pressed,
            },
            mass: &mass,
            fixed: &fixed,
            r,
            statics: nvtmm::reduced::Statics::All(&[]),
            warm: None,
            params: loose,
        })?;
        let t_lc = t.elapsed().as_secs_f64();
        println!(
            "r = {r:2}, tol 1e-6 at pressed u: warm {t_lw:.3} s ({} it) vs cold {t_lc:.3} s ({} it)",
            lw.iterations, lc.iterations
        );
        let t = Instant::now();
        let aug = ModalBasis::compute(&nvtmm::reduced::BasisSpec {
            stiffness: nvtmm::reduced::Stiffness::Model {
                mesh,
                model: &model,
                u: &rest,
            },
            mass: &mass,
            fixed: &fixed,
            r,
            statics: nvtmm::reduced::Statics::All(&[node]),
            warm: None,
            params: nvtmm::reduced::BasisParams::default(),
        })?;
        let t_aug = t.elapsed().as_secs_f64();
        let step = match r {
            8 => time_steps::<8>(&cold, node)?,
            16 => time_steps::<16>(&cold, node)?,
            _ => time_steps::<32>(&cold, node)?,
        };
        let step_aug = match r {
            8 => time_steps::<11>(&aug, node)?,
            16 => time_steps::<19>(&aug, node)?,
            _ => time_steps::<35>(&aug, node)?,
        };
        println!(
            "r = {r:2}: basis cold {t_cold:.3} s ({} it), at pressed u warm {t_warm:.3} s ({} it) vs cold {t_again:.3} s ({} it); \
             +3 attachment modes {t_aug:.3} s; step {:.2} µs (R = r), {:.2} µs (R = r + 3)",
            cold.iterations,
            warm.iterations,
            again.iterations,
            step * 1e6,
            step_aug * 1e6
        );
    }
    Ok(())
}
