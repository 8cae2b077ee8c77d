//! A forward leap of the service clock (a suspended process, a paused
//! virtual machine): every thread sees it at once. The loop counts the
//! missed deadlines and re-phases instead of bursting, the force is at full
//! gain again within the ramp-in time, the models keep coming, and nothing
//! allocates. Its own test binary: the
//! leap is process-wide.

mod common;

use common::service::{start, wait_for};
use nvtmm::rt::clock;

#[global_allocator]
static ALLOC: nvtmm::rt::alloc::RtAllocator = nvtmm::rt::alloc::RtAllocator;

#[test]
fn the_loop_rephases_and_the_force_ramps_back_in_after_a_clock_jump() {
    let dir = tempfile::tempdir().unwrap();
    let h = start(dir.path());
    assert!(wait_for(&h, 60.0, |s| s.model_epoch >= 2 && s.gain >= 0.999));
    let before = h.snapshot();
    clock::inject_jump(300_000_000);
    assert_eq!(clock::injected_jumps(), 1);
    // The device thread reads the simulated device at once on the new time,
    // so the loop sees no silence (behind the UDP bridge it does, and the
    // soak sees the force go down and come back). Either way the force is
    // at full gain again within hold + ramp-in (0.1 + 0.5 s), with slack.
    let t = std::time::Instant::now();
    std::thread::sleep(std::time::Duration::from_millis(50));
    assert!(wait_for(&h, 10.0, |s| s.gain >= 0.999), "{:?}", h.snapshot());
    let back_s = t.elapsed().as_secs_f64();
    let epoch = h.snapshot().model_epoch;
    assert!(wait_for(&h, 30.0, |s| s.model_epoch > epoch), "models keep coming");
    let after = h.snapshot();
    // A 300 ms leap at 1 kHz is 300 periods; the loop skips them rather
    // than running them back to back.
    assert!(after.ticks > before.ticks);
    assert!(after.deadline_misses > before.deadline_misses, "the leap is a miss");
    assert!(
        after.deadline_misses - before.deadline_misses < 50,
        "re-phased, not a miss per skipped period: {}",
        after.deadline_misses - before.deadline_misses
    );
    let report = h.stop().unwrap();
    assert!(report.threads_lost.is_empty());
    assert_eq!(report.allocations_after_start, 0);
    assert!(back_s < 5.0, "force back in {back_s:.2} s");
}
