//! Recovery paths of the service's helper threads, each injected into a
//! real run (`Handle::faults`): a background thread that panics (the loop
//! keeps its last model, flags it, ramps the force down once the model is
//! past its maximum age, and the report names the thread and the message),
//! a panicking basis thread and stream publisher (the run goes on, the
//! report names them), and a basis recomputation that fails (the service
//! keeps the old basis and a later recomputation succeeds).

mod common;

use common::service::{start, wait_for};
use nvtmm::haptics::servo::flags;
use std::sync::atomic::Ordering;
use std::sync::Mutex;
use std::time::{Duration, Instant};

#[global_allocator]
static ALLOC: nvtmm::rt::alloc::RtAllocator = nvtmm::rt::alloc::RtAllocator;

/// One service at a time: the machine has two cores.
static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

#[test]
fn a_panicking_background_thread_leaves_the_last_model_then_ramps_the_force_down() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let dir = tempfile::tempdir().unwrap();
    let h = start(dir.path());
    // Models flow first.
    assert!(wait_for(&h, 60.0, |s| s.model_epoch >= 2 && s.gain >= 0.999));
    h.faults().panic_background.store(true, Ordering::Relaxed);
    // The loop flags the old model, then, past the maximum age, ramps down.
    assert!(
        wait_for(&h, 30.0, |s| s.flags & flags::MODEL_EXPIRED != 0 && s.gain == 0.0),
        "the force ramps to zero once the model is too old: {:?}",
        h.snapshot()
    );
    let epoch = h.snapshot().model_epoch;
    std::thread::sleep(Duration::from_millis(300));
    let s = h.snapshot();
    assert!(!h.is_finished(), "the loop runs on");
    assert_eq!(s.model_epoch, epoch, "no model after the background is gone");
    assert_eq!(s.gain, 0.0, "the force stays down");
    let report = h.stop().expect("a lost helper thread does not lose the report");
    assert_eq!(report.threads_lost.len(), 1, "{:?}", report.threads_lost);
    assert_eq!(report.threads_lost[0].thread, "background");
    assert!(
        report.threads_lost[0]
            .message
            .contains("injected fault: the background thread panics"),
        "{}",
        report.threads_lost[0].message
    );
    assert!(report.watchdog.model_expired_ticks > 0);
    assert!(report.render().contains("THREAD LOST: background"));
    assert_eq!(report.allocations_after_start, 0);
}

#[test]
fn a_panicking_basis_thread_or_publisher_is_reported_and_the_loop_runs_on() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let dir = tempfile::tempdir().unwrap();
    let h = start(dir.path());
    assert!(wait_for(&h, 60.0, |s| s.model_epoch >= 2));
    h.faults().panic_basis.store(true, Ordering::Relaxed);
    h.faults().panic_publisher.store(true, Ordering::Relaxed);
    // Both take the switch at their next job or frame (a basis job comes
    // every 0.3 s once the last one is done).
    let t = Instant::now();
    while (h.faults().panic_basis.load(Ordering::Relaxed) || h.faults().panic_publisher.load(Ordering::Relaxed))
        && t.elapsed().as_secs() < 120
    {
        std::thread::sleep(Duration::from_millis(10));
    }
    // The background keeps sending models without its basis thread.
    let sent = h.snapshot().models_sent;
    assert!(wait_for(&h, 30.0, |s| s.models_sent > sent + 20));
    assert!(!h.is_finished());
    let report = h.stop().unwrap();
    let mut lost: Vec<&str> = report.threads_lost.iter().map(|l| l.thread.as_str()).collect();
    lost.sort();
    assert_eq!(lost, ["basis", "stream"], "{:?}", report.threads_lost);
    assert!(report.threads_lost.iter().all(|l| l.message.contains("injected fault")));
}

#[test]
fn a_failing_basis_recomputation_keeps_the_old_basis_and_the_next_one_succeeds() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let dir = tempfile::tempdir().unwrap();
    let h = start(dir.path());
    assert!(wait_for(&h, 60.0, |s| s.model_epoch >= 2));
    let f = h.faults();
    f.fail_next_basis.store(true, Ordering::Relaxed);
    let t = Instant::now();
    while f.basis_failures_served.load(Ordering::Relaxed) == 0 && t.elapsed().as_secs() < 60 {
        std::thread::sleep(Duration::from_millis(10));
    }
    assert_eq!(
        f.basis_failures_served.load(Ordering::Relaxed),
        1,
        "the failure was met"
    );
    // Models keep flowing on the old basis while the next recomputation runs.
    let sent = h.snapshot().models_sent;
    assert!(wait_for(&h, 30.0, |s| s.models_sent > sent + 5));
    // Let a later recomputation finish (warm start: under a second here,
    // up to a minute on a loaded machine).
    std::thread::sleep(Duration::from_secs(3));
    let report = h.stop().unwrap();
    assert!(report.threads_lost.is_empty());
    assert!(report.background.basis_failures >= 1);
    assert!(
        report.background.basis_recomputed >= 1,
        "a later recomputation succeeds: {:?}",
        report.background
    );
}
