//! Times the pieces of one reduced-model refresh on the arch:
//! `cargo run --release --example refresh_timing -- [nodes] [r]`.
use nvtmm::bench::standard_load;
use nvtmm::material::Material;
use nvtmm::math::Vec3;
use nvtmm::mesh::arch::{generate, ArchParams};
use nvtmm::model::nvtmm::Nvtmm;
use nvtmm::model::{BlockTangent, ForceModel};
use nvtmm::reduced::{ModalBasis, Refresher};
use std::time::Instant;

fn main() {
    let args: Vec<usize> = std::env::args().skip(1).filter_map(|a| a.parse().ok()).collect();
    let nodes = args.first().copied().unwrap_or(5832);
    let r = args.get(1).copied().unwrap_or(32);
    let arch = generate(&ArchParams::default(), nodes).expect("arch");
    let mesh = &arch.mesh;
    let mat = Material::aorta();
    let model = Nvtmm::new(mesh, &mat);
    let mass = mesh.lumped_mass(mat.density);
    let load = standard_load(&arch, 0.1);
    let u0 = vec![Vec3::zeros(); mesh.num_nodes()];
    let t = Instant::now();
    let basis = ModalBasis::compute(&nvtmm::reduced::BasisSpec {
        stiffness: nvtmm::reduced::Stiffness::Model {
            mesh,
            model: &model,
            u: &u0,
        },
        mass: &mass,
        fixed: &load.fixed,
        r,
        statics: nvtmm::reduced::Statics::None,
        warm: None,
        params: nvtmm::reduced::BasisParams::default(),
    })
    .expect("basis");
    println!("basis {:.3} s", t.elapsed().as_secs_f64());
    let u: Vec<Vec3> = mesh
        .rest()
        .iter()
        .map(|x| Vec3::new(0.0, 0.0, -1e-3 * (x.y * 30.0).sin()))
        .collect();
    let mut k = BlockTangent::zeros(mesh);
    for _ in 0..3 {
        let t = Instant::now();
        k.clear();
        model.add_stiffness(&u, &mut k);
        println!("add_stiffness {:.2} ms", t.elapsed().as_secs_f64() * 1e3);
    }
    let mut refr = Refresher::new(mesh, &basis, &mass);
    for _ in 0..3 {
        let t = Instant::now();
        let kr = refr.reduced_stiffness(&model, &u);
        println!(
            "reduced_stiffness {:.2} ms ({}x{})",
            t.elapsed().as_secs_f64() * 1e3,
            kr.nrows(),
            kr.ncols()
        );
    }
    for _ in 0..3 {
        let t = Instant::now();
        let kr = refr.project_tangent(&k);
        println!(
            "project_tangent {:.2} ms ({}x{})",
            t.elapsed().as_secs_f64() * 1e3,
            kr.nrows(),
            kr.ncols()
        );
    }
    let t = Instant::now();
    let _ = refr.project_mass(&u);
    let _ = refr.project_force(&u);
    println!("projections {:.2} ms", t.elapsed().as_secs_f64() * 1e3);
    let t = Instant::now();
    let phi = basis.phi.clone();
    let _ = phi.tr_mul(&phi);
    println!("gemm 3n x r x r {:.2} ms", t.elapsed().as_secs_f64() * 1e3);
}
