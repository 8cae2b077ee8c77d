//! The guidewire scenario in the service, short: the wire runs in its own
//! RT thread, the scripted hand inserts it up the descending aorta, the
//! report's `wire.*` keys are filled and finite, and neither the loop, the
//! device thread nor the wire thread calls the system allocator after
//! start. Runs RT threads: run it alone (`cargo test --release --test
//! guidewire_service_reports_the_wire_and_allocates_nothing`).

mod common;

#[global_allocator]
static ALLOC: nvtmm::rt::alloc::RtAllocator = nvtmm::rt::alloc::RtAllocator;

#[test]
fn a_short_guidewire_run_reports_finite_wire_keys_and_allocates_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = common::guidewire::write(
        dir.path(),
        4.0,
        "[[0.0, 0.02, 0.0], [0.3, 0.02, 0.0], [3.3, 0.08, 0.5]]",
        std::env::var("GW_LOAD_WALL").map(|v| v != "0").unwrap_or(true),
    );
    let report = common::guidewire::run_unless_the_machine_paused(&cfg);
    let w = report.wire.as_ref().expect("wire.* keys");
    assert!(w.steps > 2000, "{} wire steps", w.steps);
    assert!(
        w.inserted_m > 0.06 && w.inserted_m <= 0.085,
        "inserted {}",
        w.inserted_m
    );
    assert!(w.nodes > 20, "{} nodes", w.nodes);
    for (k, v) in [
        ("inserted_m", w.inserted_m),
        ("max_penetration_m", w.max_penetration_m),
        ("axial_force_max_n", w.axial_force_max_n),
        ("contacts_p50", w.contacts_p50),
        ("step_us.p50", w.step_us.p50),
        ("step_us.p99", w.step_us.p99),
        ("step_us.p999", w.step_us.p999),
    ] {
        assert!(v.is_finite() && v >= 0.0, "wire.{k} = {v}");
    }
    assert!(w.step_us.p50 > 0.0 && w.step_us.p50 <= w.step_us.p99 && w.step_us.p99 <= w.step_us.p999);
    assert!(w.tip_m.iter().all(|c| c.is_finite()));
    assert_eq!(w.tip_segment, "aorta", "the tip is still in the descending aorta");
    assert!(w.max_penetration_m < 0.2e-3, "penetration {} m", w.max_penetration_m);
    assert!(w.wall_updates > 0, "the wall followed the reduced model");
    assert_eq!(w.resets, 0);
    // The default budget never binds: no step was cut short, and the most
    // a step took is counted.
    assert!(w.evaluations_max >= 3, "{} evaluations", w.evaluations_max);
    assert_eq!(w.budget_spent_steps, 0);
    assert!(report.allocator_installed);
    assert_eq!(w.allocations_after_start, 0, "wire thread allocations");
    assert_eq!(report.allocations_after_start, 0, "loop + device + wire allocations");
    let json = serde_json::to_value(&report).unwrap();
    for k in [
        "nodes",
        "inserted_m",
        "tip_segment",
        "contacts_max",
        "contacts_p50",
        "max_penetration_m",
        "axial_force_max_n",
        "step_us",
        "evaluations_max",
        "budget_spent_steps",
        "time_limited_steps",
        "resets",
    ] {
        assert!(json["wire"].get(k).is_some(), "wire.{k} missing");
    }
    // Two instruments behind the one seam (the loop above allocated
    // nothing with both): the report lists each, the guidewire's section
    // with the same keys as `wire.*`.
    let ids: Vec<(&str, &str)> = report
        .instruments
        .iter()
        .map(|i| (i.id.as_str(), i.kind.as_str()))
        .collect();
    assert_eq!(ids, [("probe", "probe"), ("guidewire", "guidewire")]);
    let g = &json["instruments"][1]["keys"];
    assert_eq!(g["steps"], json["wire"]["steps"]);
    assert_eq!(g["tip_segment"], json["wire"]["tip_segment"]);
    assert!(g.get("hub_ring_full").is_some());
    assert_eq!(report.instruments[1].faults, w.resets + w.stalls);
}
