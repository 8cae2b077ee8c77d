//! After construction, the reduced model's `step` and `step_with_contact`,
//! with and without Prony terms — and the RT-path helpers around them,
//! `project_nodal`, `rows_at` and `displacement_at` — allocate nothing over
//! 1000 steps: the haptic loop can run them without touching the allocator.

mod common;

use common::counting::count_allocations;
use nalgebra::SMatrix;
use nvtmm::material::{Material, PronyTerm};
use nvtmm::math::Vec3;
use nvtmm::mesh::arch::{generate, ArchParams};
use nvtmm::model::tmm::Tmm;
use nvtmm::reduced::{DynamicsParams, ModalBasis, ReducedDynamics};

#[global_allocator]
static GLOBAL: common::counting::Counting = common::counting::Counting;

#[test]
fn reduced_step_allocates_nothing() {
    let arch = generate(&ArchParams::default(), 300).expect("arch");
    let mesh = &arch.mesh;
    let mat = Material::aorta();
    let model = Tmm::new(mesh, &mat);
    let mass = mesh.lumped_mass(mat.density);
    let mut fixed = mesh.node_set("inlet").expect("inlet").to_vec();
    fixed.extend_from_slice(mesh.node_set("outlet_descending").expect("outlet"));
    let u0 = vec![Vec3::zeros(); mesh.num_nodes()];
    let node = arch.node(arch.top_ring, 0, arch.grid.layers - 1) as u32;
    let basis = ModalBasis::compute(&nvtmm::reduced::BasisSpec {
        stiffness: nvtmm::reduced::Stiffness::Model {
            mesh,
            model: &model,
            u: &u0,
        },
        mass: &mass,
        fixed: &fixed,
        r: 8,
        statics: nvtmm::reduced::Statics::All(&[node]),
        warm: None,
        params: nvtmm::reduced::BasisParams::default(),
    })
    .expect("basis");
    let params = DynamicsParams {
        dt: 1e-3,
        alpha: 5.0,
        beta: 1e-4,
    };
    // Boxed: the capacity-16 matrices are moved once here, not per step.
    let mut d = Box::new(ReducedDynamics::<16>::new(&basis, &params).expect("model"));
    let mut moved = 0.0;

    // The counter itself works: one box is one allocation.
    let ((), one) = count_allocations(|| drop(std::hint::black_box(Box::new(1u8))));
    assert_eq!(one, 1);

    let ((), count) = count_allocations(|| {
        for i in 0..1000 {
            let t = i as f64 * 1e-3;
            let force = Vec3::new(0.0, 0.02 * (40.0 * t).sin(), -0.05);
            let f = match d.project_nodal(&[(node, force)]) {
                Ok(f) => f,
                Err(_) => break,
            };
            d.step(&f);
            moved += d.displacement_at(node).map_or(0.0, |x| x.norm());
        }
    });

    assert!(moved > 0.0, "the loaded node did not move");
    assert_eq!(count, 0, "{count} allocations in 1000 reduced steps");

    // The same with two Prony terms, alternating plain steps and steps with
    // a stiff linearized contact at the node (k n nᵀ projected through its rows).
    d.reset();
    d.set_prony(&[PronyTerm { alpha: 0.3, tau: 0.05 }, PronyTerm { alpha: 0.2, tau: 0.5 }])
        .expect("prony");
    let mut kc = Box::new(SMatrix::<f64, 16, 16>::zeros());
    let ((), count) = count_allocations(|| {
        for i in 0..1000 {
            let force = Vec3::new(0.0, 0.0, -0.05);
            let f = match d.project_nodal(&[(node, force)]) {
                Ok(f) => f,
                Err(_) => break,
            };
            if i % 2 == 0 {
                d.step(&f);
            } else if let Some(rows) = d.rows_at(node) {
                let n = Vec3::new(0.0, 0.0, 1.0);
                let nr = rows.tr_mul(&n);
                *kc = nr * nr.transpose() * 1e3;
                let _ = d.step_with_contact(&f, &kc);
            }
            moved += d.displacement_at(node).map_or(0.0, |x| x.norm());
        }
    });
    assert_eq!(d.prony_history().len(), 2);
    assert!(d.prony_history()[0].norm() > 0.0, "the history did not grow");
    assert_eq!(
        count, 0,
        "{count} allocations in 1000 reduced steps with Prony terms and contact"
    );
}
