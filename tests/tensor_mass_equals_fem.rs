//! The nonlinear tensor-mass StVK model (`Nvtmm`) and the element FEM StVK
//! model (`Fem`) are two implementations of the same energy (eq. 3–6): their
//! energies, forces, force derivatives and tangents must agree to round-off
//! on any mesh and displacement, including large ones. At rest the tangent of
//! both is the linear tensor-mass K0 (`Tmm::k0`).

mod common;

use common::*;
use nvtmm::material::Law;
use nvtmm::math::Vec3;
use nvtmm::mesh::arch::{generate, ArchParams};
use nvtmm::mesh::TetMesh;
use nvtmm::model::{fem::Fem, nvtmm::Nvtmm, tmm::Tmm, BlockTangent, ForceModel};

fn compare(mesh: &TetMesh, seed: u64, strain: f64) {
    let m = material();
    let (tm, fem) = (Nvtmm::new(mesh, &m), Fem::new(mesh, &m, Law::Stvk));
    let mut rng = Rng::new(seed);
    let g = nvtmm::math::Mat3::from_fn(|_, _| 2.0 * strain * rng.next());
    let h = mean_edge(mesh);
    let u: Vec<Vec3> = mesh.rest().iter().map(|x| g * x + rng.vec3() * (strain * h)).collect();
    let du = rng.vecs(mesh.num_nodes(), h);

    let (wt, wf) = (tm.energy(&u), fem.energy(&u));
    assert!(
        (wt - wf).abs() <= 1e-10 * wf.abs(),
        "energy: tensor-mass {wt} vs FEM {wf}"
    );
    let (ft, ff) = (forces(&tm, &u), forces(&fem, &u));
    let e = max_diff(&ft, &ff) / max_norm(&ff);
    assert!(e <= 1e-10, "forces differ, rel {e:e}");
    let (dt, dff) = (df(&tm, &u, &du), df(&fem, &u, &du));
    let e = max_diff(&dt, &dff) / max_norm(&dff);
    assert!(e <= 1e-10, "add_df differs, rel {e:e}");
    let (mut kt, mut kf) = (BlockTangent::zeros(mesh), BlockTangent::zeros(mesh));
    tm.add_stiffness(&u, &mut kt);
    fem.add_stiffness(&u, &mut kf);
    let scale = kf.diag.iter().chain(&kf.off).map(|b| b.amax()).fold(0.0, f64::max);
    let e = kt
        .diag
        .iter()
        .zip(&kf.diag)
        .chain(kt.off.iter().zip(&kf.off))
        .map(|(a, b)| (a - b).amax())
        .fold(0.0, f64::max)
        / scale;
    assert!(e <= 1e-10, "tangent blocks differ, rel {e:e}");
}

#[test]
fn block_tensor_mass_equals_fem_at_large_strain() {
    let mesh = block(3, 2, 2, 0.01);
    for (seed, strain) in [(1, 0.01), (2, 0.15), (3, 0.4)] {
        compare(&mesh, seed, strain);
    }
}

#[test]
fn arch_tensor_mass_equals_fem() {
    let arch = generate(&ArchParams::default(), 1458).expect("default arch");
    compare(&arch.mesh, 9, 0.15);
}

/// The branched arch (the vessel pipeline's wall, with its three
/// supra-aortic branches) at the paper's smallest size.
#[test]
fn branched_arch_tensor_mass_equals_fem() {
    use nvtmm::mesh::vessel::branched::{branched_arch, default_wall_ratio};
    use nvtmm::mesh::vessel::implicit::BranchedArchParams;
    let p = BranchedArchParams::default();
    let b = branched_arch(&p, 1458, 1, default_wall_ratio(&p)).expect("branched arch");
    compare(&b.wall.mesh, 9, 0.15);
}

#[test]
fn rest_tangent_is_linear_tensor_mass() {
    let mesh = block(2, 2, 1, 0.01);
    let m = material();
    let zero = vec![Vec3::zeros(); mesh.num_nodes()];
    let k0 = Tmm::new(&mesh, &m).k0;
    for model in [
        Box::new(Nvtmm::new(&mesh, &m)) as Box<dyn ForceModel>,
        Box::new(Fem::new(&mesh, &m, Law::Stvk)),
    ] {
        let mut k = BlockTangent::zeros(&mesh);
        model.add_stiffness(&zero, &mut k);
        let (a, b) = (k.to_dense(), k0.to_dense());
        assert!(
            (&a - &b).amax() <= 1e-12 * b.amax(),
            "{}: rest tangent is not K0",
            model.name()
        );
    }
}
