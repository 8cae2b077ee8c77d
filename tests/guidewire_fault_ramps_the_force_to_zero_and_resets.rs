//! A wire step that goes non-finite in the running service: the watchdog
//! ramps the hand's force to zero and the wire goes back to its last good
//! state, counted in `wire.resets`; the run goes on. Runs RT threads: run
//! it alone.

mod common;

use nvtmm::service::{Service, StartOptions};
use std::sync::atomic::Ordering;

#[test]
fn a_non_finite_wire_step_zeroes_the_force_and_resets_the_wire() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = common::guidewire::write(
        dir.path(),
        60.0,
        "[[0.0, 0.02, 0.0], [0.3, 0.02, 0.0], [3.0, 0.06, 0.0]]",
        true,
    );
    let h = Service::start(StartOptions::file(cfg)).expect("the guidewire service starts");
    assert!(
        common::service::wait_for(&h, 20.0, |s| s.gain > 0.999 && s.ticks > 1000),
        "the force ramped in"
    );
    h.faults().poison_wire.store(true, Ordering::Relaxed);
    assert!(
        common::service::wait_for(&h, 5.0, |s| s.gain == 0.0),
        "the watchdog took the force to zero"
    );
    assert!(
        common::service::wait_for(&h, 5.0, |s| s.gain > 0.999),
        "the force ramped back in"
    );
    let r = h.stop().unwrap();
    println!("{}", r.render());
    let w = r.wire.expect("wire.* keys");
    assert_eq!(w.resets, 1, "one reset");
    assert!(r.watchdog.watchdog_ticks > 0);
    assert!(w.inserted_m.is_finite() && w.tip_m.iter().all(|c| c.is_finite()));
    assert!(
        w.inserted_m > 0.021,
        "the wire went on after the reset: {}",
        w.inserted_m
    );
}
