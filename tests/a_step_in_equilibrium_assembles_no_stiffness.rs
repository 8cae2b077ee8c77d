//! A step that starts in equilibrium (at rest, no load) converges before
//! Newton assembles a tangent, so `last_stiffness` is still all zeros then;
//! `has_stiffness` says so. The haptic service's background thread builds
//! the loop's reduced model from that tangent: before this flag it sent the
//! loop models with K_r = 0 whenever the full solve sat at rest, and a
//! point load on such a model (the guidewire's, which the full solve does
//! not see) made the wall drift without bound.

mod common;

use common::{block, Springs};
use nvtmm::math::Vec3;
use nvtmm::solver::loads::{Loads, NodalLoad, TimeProfile};
use nvtmm::solver::{ImplicitEuler, ImplicitEulerParams, NewtonParams, TissueState};

#[test]
fn a_step_in_equilibrium_assembles_no_stiffness_and_says_so() {
    let mesh = block(3, 2, 2, 0.01);
    let fixed = mesh.node_set("x_min").unwrap().to_vec();
    let mut model = Springs::new(&mesh, 100.0, 1e5);
    for newton in [NewtonParams::linearized(), NewtonParams::default()] {
        let params = ImplicitEulerParams {
            dt: 2e-3,
            newton,
            ..ImplicitEulerParams::default()
        };
        let mut euler = ImplicitEuler::new(&mesh, mesh.lumped_mass(1100.0), params).unwrap();
        let mut state = TissueState::at_rest(mesh.num_nodes());
        assert!(!euler.has_stiffness());
        let none = Loads {
            nodal: vec![],
            gravity: Vec3::zeros(),
            pressure: None,
        };
        for _ in 0..3 {
            let rep = euler.step(&mut state, &mut model, &none, &fixed);
            assert!(rep.ok() && rep.converged, "{:?}", rep.failure);
        }
        assert!(!euler.has_stiffness(), "no tangent was assembled at rest");
        assert!(euler.last_stiffness().diag.iter().all(|b| b.iter().all(|&v| v == 0.0)));
        let free = (0..mesh.num_nodes() as u32).find(|i| !fixed.contains(i)).unwrap();
        let push = Loads {
            nodal: vec![NodalLoad {
                nodes: vec![free],
                force: Vec3::new(0.0, 0.0, 0.1),
                profile: TimeProfile::Constant { from_t0: 0.0 },
            }],
            gravity: Vec3::zeros(),
            pressure: None,
        };
        let rep = euler.step(&mut state, &mut model, &push, &fixed);
        assert!(rep.ok(), "{:?}", rep.failure);
        assert!(euler.has_stiffness());
        let d = euler.last_stiffness().diag[free as usize];
        assert!(d.norm() > 0.0, "the assembled tangent is not zero at a free node");
    }
}
