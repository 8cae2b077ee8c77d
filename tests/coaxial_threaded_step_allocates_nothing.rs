//! After construction, lagged coupled steps with the catheter's half on a
//! worker thread (`Coaxial::step_on`) allocate nothing, in either thread:
//! the pair fed in and out and rolled in a curved tube, and the reset path.
//! The allocator counts every thread's allocations while counting is on
//! (this file holds one test, so no other test's thread runs then).

use nvtmm::math::Vec3;
use nvtmm::rt::thread::RtRequest;
use nvtmm::wire::catheter::{catheter_params, TipShape};
use nvtmm::wire::coaxial::{CatheterWorker, Coaxial, Coupling};
use nvtmm::wire::WireParams;

mod common;
use common::counting::{count_every_thread_allocations as counted, EveryThread};

#[global_allocator]
static GLOBAL: EveryThread = EveryThread;

#[test]
fn the_threaded_coaxial_step_allocates_nothing() {
    let tube = common::two_radian_bend(4e-3);
    let w = WireParams {
        max_nodes: 128,
        ..WireParams::default()
    };
    let c = catheter_params(5.0, TipShape::Vertebral);
    let mut pair = Coaxial::new(&w, &c, Vec3::zeros(), Vec3::x(), 0.02, 0.015).expect("pair");
    pair.set_coupling(Coupling::Lagged);
    let request = RtRequest {
        fifo_priority: None,
        cpu: None,
        prefault_stack_bytes: 0,
    };
    let mut worker = CatheterWorker::spawn(&request, None).expect("worker");
    let ((), one) = counted(|| {
        let w = std::thread::spawn(|| drop(std::hint::black_box(Box::new(1u8))));
        let _ = w.join();
    });
    assert!(one >= 1, "the counter does not see other threads");
    let (mut sheath, mut walls, mut steps) = (0, 0, 0);
    let ((), count) = counted(|| {
        for k in 0..1500 {
            let t = k as f64 * 1e-3;
            let wi = if k < 1000 {
                0.02 + 0.05 * t
            } else {
                0.07 - 0.08 * (t - 1.0)
            };
            pair.set_hubs(wi, 0.3 * t, 0.015 + 0.04 * t.min(1.0), -0.5 * t);
            // Half the steps with the worker sleeping till a wake time.
            if k % 2 == 0 {
                worker.wake_at(nvtmm::rt::clock::now_ns() + 50_000);
            }
            match pair.step_on(&tube, &mut worker) {
                Ok(r) => {
                    steps += 1;
                    sheath += r.wire.sheath_contacts;
                    walls += pair.wall_contacts().count();
                    if k % 100 == 0 {
                        pair.save_good_state();
                    }
                }
                Err(_) => pair.restore_good_state(),
            }
            if k == 700 {
                pair.restore_good_state();
            }
        }
    });
    assert!(
        sheath > 0 && walls > 0 && steps > 1000,
        "no test: {steps} steps, {sheath} sheath and {walls} wall contacts"
    );
    assert_eq!(count, 0, "{count} allocations in the threaded coupled steps");
    drop(worker);
}
