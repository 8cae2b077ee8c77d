//! Navigation, in the service: on the branched arch (the guidewire tests'
//! 2000-node mesh), the shipped scenario's scripted hand inserts the wire
//! up the descending aorta, rolls the angled tip for the climb, rolls it
//! back toward the left subclavian's ostium and advances into the branch,
//! with the wall loaded by the wire's contacts (`load_wall = true`). The run
//! ends with the tip in the left subclavian, no penetration beyond 0.2 mm,
//! no reset (no non-finite step), the wall dented under the wire as much
//! as the wire's contacts gave into it, and no system allocation after
//! start. A run in which the machine paused the loop's RT thread long
//! enough for the wire's stall watchdog to trip is run again
//! (`common::guidewire::run_unless_the_machine_paused`). Runs RT threads: run it alone (`cargo test --release --test
//! guidewire_navigates_into_the_left_subclavian -- --nocapture`).

mod common;

#[global_allocator]
static ALLOC: nvtmm::rt::alloc::RtAllocator = nvtmm::rt::alloc::RtAllocator;

#[test]
fn the_scripted_run_ends_with_the_tip_in_the_left_subclavian() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let shipped = std::fs::read_to_string(root.join("rt-config/guidewire.toml")).unwrap();
    // The shipped script, as written there.
    let script = &shipped[shipped.find("script = [").unwrap() + "script = ".len()..];
    let script = &script[..=script.find("\n]").unwrap() + 1];
    let dir = tempfile::tempdir().unwrap();
    let cfg = common::guidewire::write(dir.path(), 11.0, script, true);
    let report = common::guidewire::run_unless_the_machine_paused(&cfg);
    let w = report.wire.as_ref().expect("wire.* keys");
    assert_eq!(w.tip_segment, "left_subclavian", "tip at {:?} m", w.tip_m);
    assert!(w.inserted_m > 0.165, "inserted {} m", w.inserted_m);
    assert!(w.max_penetration_m <= 0.2e-3, "penetration {} m", w.max_penetration_m);
    assert_eq!(w.resets, 0, "resets (a non-finite or too deep step)");
    assert_eq!(w.stalls, 0);
    assert!(w.load_wall);
    assert!(w.wall_compliance_p50_m_per_n > 0.0 && w.wall_compliance_max_m_per_n.is_finite());
    assert!(w.wall_deflection_max_m > 0.0, "the wall gave under the wire");
    assert!(
        w.wall_dent_max_m > 0.0,
        "the reduced model moved under the wire's loads"
    );
    // The dent the stream shows (the reduced model's share plus the
    // residual compliance's) is the give the wire's contacts assumed: not
    // much less, and at most what the contacts' gives add up to when they
    // press the same patch (each contact's series compliance is its own;
    // the wall couples them), with 20 % for the modes' dynamics.
    let (dent, give) = (w.wall_dent_max_m, w.wall_deflection_max_m);
    assert!(dent >= 0.5 * give, "dent {dent} m vs give {give} m");
    assert!(
        dent <= 1.2 * w.contacts_max as f64 * give,
        "dent {dent} m vs give {give} m at {} contacts",
        w.contacts_max
    );
    assert!(report.allocator_installed);
    assert_eq!(w.allocations_after_start, 0, "wire thread allocations");
    assert_eq!(report.allocations_after_start, 0, "loop + device + wire allocations");
    assert_eq!(report.watchdog.nonfinite, 0);
}
