//! After construction, the coupled step of a wire inside a catheter —
//! both fed in and out, rolled, touching a curved tube, the wire leading
//! and then pulled back inside — and the reset path allocate nothing.

mod common;

use common::counting::count_allocations;
use nvtmm::math::Vec3;
use nvtmm::wire::catheter::{catheter_params, TipShape};
use nvtmm::wire::coaxial::Coaxial;
use nvtmm::wire::WireParams;

#[global_allocator]
static GLOBAL: common::counting::Counting = common::counting::Counting;

#[test]
fn coaxial_step_allocates_nothing() {
    let tube = common::two_radian_bend(4e-3);
    let w = WireParams {
        max_nodes: 128,
        ..WireParams::default()
    };
    let c = catheter_params(5.0, TipShape::Vertebral);
    let mut pair = Coaxial::new(&w, &c, Vec3::zeros(), Vec3::x(), 0.02, 0.015).expect("pair");
    let ((), one) = count_allocations(|| drop(std::hint::black_box(Box::new(1u8))));
    assert_eq!(one, 1);
    let (mut sheath, mut walls) = (0, 0);
    let ((), count) = count_allocations(|| {
        for k in 0..1500 {
            // The wire leads at 50 mm/s, the catheter follows; then the
            // wire comes back inside.
            let t = k as f64 * 1e-3;
            let wi = if k < 1000 {
                0.02 + 0.05 * t
            } else {
                0.07 - 0.08 * (t - 1.0)
            };
            pair.set_hubs(wi, 0.3 * t, 0.015 + 0.04 * t.min(1.0), -0.5 * t);
            match pair.step(&tube) {
                Ok(r) => {
                    sheath += r.wire.sheath_contacts;
                    walls += pair.wall_contacts().count();
                    if k % 100 == 0 {
                        pair.save_good_state();
                    }
                }
                Err(_) => pair.restore_good_state(),
            }
        }
    });
    assert!(
        sheath > 0 && walls > 0,
        "no test: {sheath} sheath and {walls} wall contacts"
    );
    assert_eq!(count, 0, "{count} allocations in the coupled steps");
}
