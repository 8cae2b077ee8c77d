//! After `start`, the simulated Touch X's `read` and `write_force` (and the
//! bookkeeping the passivity test reads) allocate nothing, including across
//! saturation, workspace stops and injected faults: the device I/O thread
//! can drive it without touching the allocator.

mod common;

use common::counting::count_allocations;
use nvtmm::haptics::touchx::{TouchXParams, TouchXSim, Waypoint};
use nvtmm::haptics::HapticDevice;
use nvtmm::math::Vec3;

#[global_allocator]
static GLOBAL: common::counting::Counting = common::counting::Counting;

#[test]
fn simulated_touchx_read_and_write_allocate_nothing() {
    // The counter counts: a Vec allocates.
    let (_, n) = count_allocations(|| std::hint::black_box(vec![1u8; 16]));
    assert!(n > 0, "the counting allocator is installed");

    let script: Vec<Waypoint> = (0..20)
        .map(|i| Waypoint {
            t_s: 0.1 * i as f64,
            position: Vec3::new(0.07 * ((i % 3) as f64 - 1.0), 0.02 * (i % 2) as f64, -0.01),
        })
        .collect();
    let mut sim = TouchXSim::new(TouchXParams::default(), &script).expect("script");
    sim.inject_silence(0.5, 0.05);
    sim.inject_non_finite(0.7);
    sim.start().expect("start");
    let (ok, n) = count_allocations(|| {
        let mut ok = 0usize;
        for i in 0..3000 {
            let t = i as f64 * 1e-3;
            if sim.read(t).is_ok() {
                ok += 1;
            }
            let f = Vec3::new(9.0 * (t * 7.0).sin(), 3.0, -2.0);
            let _ = sim.write_force(f);
            let _ = sim.port_energy();
            let _ = sim.state();
        }
        ok
    });
    assert_eq!(n, 0, "read/write_force allocated {n} times");
    assert_eq!(ok, 3000 - 50, "the silence window is the only failure");
    assert!(sim.state().peak_clamps > 0 && sim.state().workspace_stops > 0);
}
