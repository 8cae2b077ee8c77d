//! The catheter over the guidewire in the service, short: with
//! `[catheter]` the pair steps in one RT thread, the loop sees two
//! hub-driven instruments (the guidewire, then the catheter), the scripted
//! hand advances the wire, presses the switch button, tracks the catheter
//! over it and switches back to pull the wire back a little, and each instrument ends where its rows put
//! it while the other held. The report has a section per instrument with
//! its tip segment and depth, and neither the loop, the device thread nor
//! the pair's thread calls the system allocator after start. Runs RT
//! threads: run it alone (`cargo test --release --test
//! catheter_service_steps_the_pair_and_allocates_nothing -- --nocapture`).

mod common;

#[global_allocator]
static ALLOC: nvtmm::rt::alloc::RtAllocator = nvtmm::rt::alloc::RtAllocator;

#[test]
fn the_pair_steps_in_one_thread_switches_on_the_button_and_allocates_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let base = common::guidewire::write(dir.path(), 5.0, "[]", true);
    // [time, instrument (0 wire, 1 catheter), inserted m, roll rad].
    let cfg = std::fs::read_to_string(&base).unwrap()
        + r#"
[catheter]
shape = "vertebral"
french = 5.0
max_nodes = 96
inserted_m = 0.02
script = [
  [0.0, 0, 0.02, 0.0],
  [0.3, 0, 0.02, 0.0],
  [1.8, 0, 0.07, 0.0],
  [2.0, 1, 0.02, 0.0],
  [3.4, 1, 0.05, 0.4],
  [3.6, 0, 0.07, 0.0],
  [4.4, 0, 0.065, 0.0],
]
"#;
    let path = dir.path().join("catheter.toml");
    std::fs::write(&path, cfg).unwrap();
    let report = common::guidewire::run_unless_the_machine_paused(&path);
    let ids: Vec<(&str, &str)> = report
        .instruments
        .iter()
        .map(|i| (i.id.as_str(), i.kind.as_str()))
        .collect();
    assert_eq!(
        ids,
        [("probe", "probe"), ("guidewire", "guidewire"), ("catheter", "catheter")]
    );
    assert_eq!(report.instrument_switches, 2, "two presses of the switch button");
    let w = report.wire.as_ref().expect("wire.* keys: the pair's wire");
    let json = serde_json::to_value(&report).unwrap();
    let c = &json["instruments"][2]["keys"];
    let f = |k: &str| c[k].as_f64().unwrap_or_else(|| panic!("catheter key {k}: {}", c[k]));
    println!(
        "wire {:.1} mm in {} ({:.1} mm deep); catheter {:.1} mm in {} ({:.1} mm deep)",
        w.inserted_m * 1e3,
        w.tip_segment,
        w.tip_depth_m * 1e3,
        f("inserted_m") * 1e3,
        c["tip_segment"],
        f("tip_depth_m") * 1e3
    );
    // Each where its rows left it, the other held while one moved (within
    // what the pair lets slip: the wire, pushed to the grip's limit at the
    // end of its advance, and the catheter over it drag each other a few
    // millimetres).
    assert!((w.inserted_m - 0.065).abs() < 4e-3, "wire inserted {}", w.inserted_m);
    assert!(
        (f("inserted_m") - 0.05).abs() < 4e-3,
        "catheter inserted {}",
        f("inserted_m")
    );
    assert!(
        (f("inserted_max_m") - 0.05).abs() < 4e-3,
        "catheter inserted at most {}",
        f("inserted_max_m")
    );
    assert!(
        (f("wire_lead_m") - (w.inserted_m - f("inserted_m"))).abs() < 1e-9,
        "wire lead {}",
        f("wire_lead_m")
    );
    assert_eq!(w.tip_segment, "aorta");
    assert_eq!(c["tip_segment"], "aorta");
    assert!(w.tip_depth_m > 0.0 && f("tip_depth_m") > 0.0);
    for k in [
        "steps",
        "tip_m",
        "tip_depth_m",
        "axial_force_max_n",
        "max_penetration_m",
        "sheath_penetration_max_m",
        "coaxial_normal_force_max_n",
        "hub_ring_full",
    ] {
        assert!(c.get(k).is_some(), "catheter.{k} missing");
    }
    assert_eq!(c["steps"], json["wire"]["steps"], "one thread steps both");
    common::guidewire::assert_pair_ran_clean(&report, c);
    assert_eq!(w.allocations_after_start, 0, "pair thread allocations");
    assert_eq!(report.allocations_after_start, 0, "loop + device + pair allocations");
}
