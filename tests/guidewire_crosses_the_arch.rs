//! Guided access, in the service: the shipped
//! `rt-config/guidewire_cross_the_arch.toml` as it is (the shipped
//! 5796-node arch with a living aorta's stiffness; a J-tip wire entering
//! 100 mm below the descending aorta's opening, in that opening's
//! continuation, `guidewire.access = "outlet_descending"`; the wall loaded
//! by the wire and giving under it). The scripted hand advances the wire;
//! the vessel, not the clamp, steers it up the descending aorta, over the
//! arch and down the ascending aorta: the tip ends in the ascending aorta
//! within 40 mm of the aortic root, with no reset and no allocation after
//! start. Runs RT threads: run it alone (`cargo test --release --test
//! guidewire_crosses_the_arch -- --nocapture`); about 25 s, and once more
//! the first time for the scene's reduced basis.

mod common;

#[global_allocator]
static ALLOC: nvtmm::rt::alloc::RtAllocator = nvtmm::rt::alloc::RtAllocator;

#[test]
fn a_j_tip_wire_scripted_up_the_guided_access_crosses_the_arch_into_the_ascending_aorta() {
    use nvtmm::mesh::vessel::implicit::BranchedArchParams;
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let cfg = root.join("rt-config/guidewire_cross_the_arch.toml");
    let report = common::guidewire::run_unless_the_machine_paused(&cfg);
    let w = report.wire.as_ref().expect("wire.* keys");
    // The aortic root: the ascending aorta's end, on its axis.
    let a = BranchedArchParams::default().aorta;
    let aortic_root = nvtmm::math::Vec3::new(a.ascending_xy_mm[0], a.ascending_xy_mm[1], a.ascending_end_z_mm) * 1e-3;
    let tip = nvtmm::math::Vec3::from(w.tip_m);
    let to_root = (tip - aortic_root).norm();
    println!(
        "tip {:.1?} mm, {:.1} mm from the aortic root",
        (tip * 1e3).as_slice(),
        to_root * 1e3
    );
    assert_eq!(w.tip_segment, "aorta", "tip at {:?} m", w.tip_m);
    // Past the arch: on the ascending side (the descending aorta is at
    // y = 0, the ascending at y = -62 mm), below the arch's top.
    assert!(tip.y < 0.5 * aortic_root.y, "the tip is on the ascending side: {tip:?}");
    assert!(to_root < 0.040, "the tip is {to_root} m from the aortic root");
    assert!(w.max_penetration_m <= 0.2e-3, "penetration {} m", w.max_penetration_m);
    assert_eq!(w.resets, 0, "resets (a non-finite or too deep step)");
    assert_eq!(w.stalls, 0);
    assert_eq!(w.allocations_after_start, 0, "wire thread allocations");
    assert_eq!(report.allocations_after_start, 0, "loop + device + wire allocations");
}
