//! A clone of a wire, or of a wire inside a catheter, is a full second
//! rod: it keeps every contact and point load the original would, steps
//! exactly as the original does, and allocates nothing when it steps.
//! (A clone's contact and load lists once had the capacity of what they
//! held when cloned, so a clone made before its contacts came dropped
//! them, and the catheter of a cloned pair lost the wire's forces.)

mod common;

use common::counting::count_allocations;
use nvtmm::math::Vec3;
use nvtmm::wire::catheter::{catheter_params, TipShape};
use nvtmm::wire::coaxial::Coaxial;
use nvtmm::wire::{CurvedTube, Wire, WireParams};

#[global_allocator]
static GLOBAL: common::counting::Counting = common::counting::Counting;

fn bend(radius: f64) -> CurvedTube {
    common::two_radian_bend(radius)
}

#[test]
fn a_cloned_wire_keeps_every_contact_and_steps_as_the_original() {
    // A narrow tube: the wire lies on its wall along most of its length.
    let tube = bend(1.5e-3);
    let p = WireParams {
        max_nodes: 64,
        ..WireParams::default()
    };
    let mut original = Wire::new(&p, Vec3::zeros(), Vec3::x(), 0.02).expect("wire");
    // Cloned before it touches anything: its lists held nothing then.
    let mut clone = original.clone();
    // Pressed sideways onto the wall along its length, and pushed round
    // the bend: contacts along the whole wire.
    let load = Vec3::new(0.0, 0.0, -20.0);
    original.set_line_load(load);
    clone.set_line_load(load);
    let mut most = 0;
    for k in 0..800 {
        let ins = 0.02 + 0.12 * (k as f64 * 1e-3);
        original.set_hub(ins, 0.0);
        clone.set_hub(ins, 0.0);
        let a = original.step(&tube).expect("original's step");
        let (b, allocations) = count_allocations(|| clone.step(&tube));
        let b = b.expect("clone's step");
        assert_eq!(
            allocations, 0,
            "step {k}: the clone's step allocated {allocations} times"
        );
        assert_eq!(a.contacts, b.contacts, "step {k}: contacts");
        assert_eq!(
            original.contacts().len(),
            clone.contacts().len(),
            "step {k}: the clone's contact list"
        );
        assert_eq!(original.positions(), clone.positions(), "step {k}: positions");
        most = most.max(a.contacts);
    }
    eprintln!("the wire: {most} wall contacts at most");
    assert!(most >= 8, "no test: {most} contacts at most");
}

#[test]
fn a_cloned_pair_keeps_the_wires_forces_on_the_catheter() {
    let tube = bend(4e-3);
    let w = WireParams {
        max_nodes: 64,
        ..WireParams::default()
    };
    let c = WireParams {
        max_nodes: 64,
        ..catheter_params(5.0, TipShape::Vertebral)
    };
    let mut original = Coaxial::new(&w, &c, Vec3::zeros(), Vec3::x(), 0.02, 0.015).expect("pair");
    original.set_load_stiffness_share(0.6);
    let mut clone = original.clone();
    let mut most = 0;
    for k in 0..600 {
        let t = k as f64 * 1e-3;
        let (wi, ci) = (0.02 + 0.06 * t, 0.015 + 0.05 * t);
        original.set_hubs(wi, 0.3 * t, ci, -0.3 * t);
        clone.set_hubs(wi, 0.3 * t, ci, -0.3 * t);
        let a = original.step(&tube).expect("original's step");
        let (b, allocations) = count_allocations(|| clone.step(&tube));
        let b = b.expect("clone's step");
        assert_eq!(
            allocations, 0,
            "step {k}: the clone's step allocated {allocations} times"
        );
        assert_eq!(
            a.wire.sheath_contacts, b.wire.sheath_contacts,
            "step {k}: sheath contacts"
        );
        assert_eq!(
            original.wall_contacts().count(),
            clone.wall_contacts().count(),
            "step {k}: wall contacts"
        );
        assert_eq!(
            original.wire().positions(),
            clone.wire().positions(),
            "step {k}: the wire"
        );
        assert_eq!(
            original.catheter().positions(),
            clone.catheter().positions(),
            "step {k}: the catheter"
        );
        most = most.max(a.wire.sheath_contacts);
    }
    eprintln!("the pair: {most} sheath contacts at most");
    assert!(most >= 3, "no test: {most} sheath contacts at most");
}
