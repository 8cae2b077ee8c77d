//! Rigid motions cost no energy and produce no force in the hyperelastic FEM
//! (StVK, Neo-Hookean) and the mass-spring model, however large the rotation.
//! The linear tensor-mass model is exact for translations and infinitesimal
//! rotations only: a large rotation produces a spurious force (linear
//! elasticity is not rotation-invariant, a known property, asserted here).

mod common;

use common::*;
use nvtmm::math::Vec3;
use nvtmm::mesh::arch::{generate, ArchParams};
use nvtmm::mesh::TetMesh;
use nvtmm::model::ForceModel;

fn rotation(axis: Vec3, angle: f64) -> nvtmm::math::Mat3 {
    *nalgebra::Rotation3::from_axis_angle(&nalgebra::Unit::new_normalize(axis), angle).matrix()
}

/// Force magnitude of a 10% uniaxial stretch: the scale "zero" is relative to.
fn reference_force(model: &dyn ForceModel, mesh: &TetMesh) -> f64 {
    let u: Vec<Vec3> = mesh.rest().iter().map(|x| Vec3::new(0.1 * x.x, 0.0, 0.0)).collect();
    max_norm(&forces(model, &u))
}

fn rigid(mesh: &TetMesh, angle: f64) -> Vec<Vec3> {
    let c = mesh.rest().iter().sum::<Vec3>() / mesh.num_nodes() as f64;
    let r = rotation(Vec3::new(1.0, 2.0, 3.0), angle);
    let t = Vec3::new(0.3, -0.2, 0.1) * mean_edge(mesh);
    mesh.rest()
        .iter()
        .map(|x| (r - nvtmm::math::Mat3::identity()) * (x - c) + t)
        .collect()
}

fn check_mesh(mesh: &TetMesh) {
    for model in models(mesh) {
        let name = model.name();
        let fref = reference_force(model.as_ref(), mesh);
        assert!(fref > 0.0, "{name}");
        let translation = rigid(mesh, 0.0);
        let ft = max_norm(&forces(model.as_ref(), &translation)) / fref;
        assert!(ft < 1e-10, "{name}: translation gives relative force {ft:e}");
        for angle in [0.3, 1.2, 2.5, std::f64::consts::PI] {
            let u = rigid(mesh, angle);
            let fr = max_norm(&forces(model.as_ref(), &u)) / fref;
            if name == "tmm" {
                assert!(
                    fr > 1e-2,
                    "tmm: a rotation of {angle} rad should give a spurious force, got {fr:e}"
                );
            } else {
                assert!(
                    fr < 1e-10,
                    "{name}: rotation of {angle} rad gives relative force {fr:e}"
                );
                let w = model.energy(&u);
                let wref = model.energy(
                    &mesh
                        .rest()
                        .iter()
                        .map(|x| Vec3::new(0.1 * x.x, 0.0, 0.0))
                        .collect::<Vec<_>>(),
                );
                assert!(
                    w.abs() < 1e-10 * wref,
                    "{name}: rotation of {angle} rad has energy {w:e}"
                );
            }
        }
    }
}

#[test]
fn block_rigid_motions_are_force_free() {
    check_mesh(&block(3, 2, 2, 0.01));
}

#[test]
fn arch_rigid_motions_are_force_free() {
    let arch = generate(&ArchParams::default(), 1458).expect("default arch");
    check_mesh(&arch.mesh);
}

#[test]
fn tmm_is_force_free_for_infinitesimal_rotations() {
    // f = −K0 u is linear, so the linearized rotation u = ω × (X − c) must
    // lie in its kernel exactly (to round-off).
    let mesh = block(3, 2, 2, 0.01);
    let model = nvtmm::model::tmm::Tmm::new(&mesh, &material());
    let fref = reference_force(&model, &mesh);
    let w = Vec3::new(0.2, -0.4, 0.7);
    let u: Vec<Vec3> = mesh.rest().iter().map(|x| w.cross(x)).collect();
    let fr = max_norm(&forces(&model, &u)) / fref;
    assert!(fr < 1e-12, "tmm: linearized rotation gives relative force {fr:e}");
}
