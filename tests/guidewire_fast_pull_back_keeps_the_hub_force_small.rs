//! Fast pull-backs and pushes, in the service: on the branched arch (the
//! guidewire tests' 2000-node mesh, the wall loaded by the wire), the
//! shipped script takes the tip into the left subclavian; then the hand
//! pushes 10 mm further, rolls the tip 2.1 rad the other way, and pulls
//! back and pushes 15 mm twice at 100 mm/s (the drive's limit) and pulls
//! back 30 mm, with the wire pressed on the wall at several points.
//!
//! Guards the step's convergence on fast moves with several contacts
//! (docs/WIRE.md "Fast pulls"): friction's smoothing
//! (`wire::rod::FRICTION_SMOOTHING_M`), friction's lagged normal, the
//! penalty summed over the pieces of wall a node overlaps, the penalty's
//! onset and the iterations that go on past the usual count while a node
//! is off equilibrium. Before them, steps ended unconverged, the hub edge
//! held the feed and the hub force reached the grip's limit (10 N, which
//! the drive clamps to 3 N: the soak's guidewire hand felt it); with the
//! smoothing alone, one run in four still did (2026-11-27). Runs RT
//! threads: run it alone
//! (`cargo test --release --test guidewire_fast_pull_back_keeps_the_hub_force_small -- --nocapture`).

mod common;

#[global_allocator]
static ALLOC: nvtmm::rt::alloc::RtAllocator = nvtmm::rt::alloc::RtAllocator;

#[test]
fn fast_pulls_and_pushes_against_the_wall_keep_the_hub_force_small() {
    let script = "[
  [0.0, 0.02, 0.0],
  [0.5, 0.02, 0.0],
  [1.0, 0.02, 3.14],
  [5.0, 0.15, 3.14],
  [6.0, 0.15, 0.0],
  [10.0, 0.175, 0.0],
  [10.5, 0.185, 0.0],
  [11.0, 0.185, -2.1],
  [11.5, 0.185, -2.1],
  [11.65, 0.17, -2.1],
  [12.0, 0.17, -2.1],
  [12.15, 0.185, -2.1],
  [12.5, 0.185, -2.1],
  [12.65, 0.17, -2.1],
  [13.0, 0.17, -2.1],
  [13.3, 0.14, -2.1],
  [14.0, 0.14, -2.1],
]
";
    let dir = tempfile::tempdir().unwrap();
    let cfg = common::guidewire::write(dir.path(), 14.5, script, true);
    let report = common::guidewire::run_unless_the_machine_paused(&cfg);
    let w = report.wire.as_ref().expect("wire.* keys");
    assert!(w.inserted_max_m > 0.18, "the wire went in: {} m", w.inserted_max_m);
    assert!(
        w.contacts_max >= 3,
        "pressed on the wall at several points: {}",
        w.contacts_max
    );
    assert!(w.inserted_m < 0.15, "and came back out: {} m", w.inserted_m);
    assert!(
        w.axial_force_max_n < 1.0,
        "hub force {} N (the grip's limit is 10 N)",
        w.axial_force_max_n
    );
    assert_eq!(w.resets, 0);
    assert_eq!(w.allocations_after_start, 0);
}
