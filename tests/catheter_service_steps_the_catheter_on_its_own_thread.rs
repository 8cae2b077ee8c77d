//! The catheter over the guidewire in the service with
//! `catheter.parallel = true`: the pair is coupled lagged and the
//! catheter steps on its own thread while the pair's thread steps the
//! wire. The scripted hand advances the wire, switches, tracks the
//! catheter over it and pulls the wire back a little; each ends where its
//! rows put it, neither rod goes 0.2 mm into a wall, nothing resets, the
//! report names the coupling and the catheter's thread, and no thread
//! calls the system allocator after start. Runs RT threads: run it alone
//! (`cargo test --release --test
//! catheter_service_steps_the_catheter_on_its_own_thread -- --nocapture`).

mod common;

#[global_allocator]
static ALLOC: nvtmm::rt::alloc::RtAllocator = nvtmm::rt::alloc::RtAllocator;

#[test]
fn the_catheter_steps_on_its_own_thread_and_allocates_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let base = common::guidewire::write(dir.path(), 5.0, "[]", true);
    let cfg = std::fs::read_to_string(&base).unwrap()
        + r#"
[catheter]
shape = "vertebral"
french = 5.0
max_nodes = 96
inserted_m = 0.02
parallel = true
cpu = 1
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
    let w = report.wire.as_ref().expect("wire.* keys: the pair's wire");
    let json = serde_json::to_value(&report).unwrap();
    let c = &json["instruments"][2]["keys"];
    let f = |k: &str| c[k].as_f64().unwrap_or_else(|| panic!("catheter key {k}: {}", c[k]));
    println!(
        "wire {:.1} mm in, catheter {:.1} mm in; coupling {}, catheter's thread {}",
        w.inserted_m * 1e3,
        f("inserted_m") * 1e3,
        c["coupling"],
        c["catheter_thread"]
    );
    assert_eq!(c["coupling"], "lagged");
    assert_eq!(c["parallel"], true);
    assert_eq!(c["catheter_thread"]["allocations_after_start"], 0);
    assert!((w.inserted_m - 0.065).abs() < 4e-3, "wire inserted {}", w.inserted_m);
    assert!(
        (f("inserted_m") - 0.05).abs() < 4e-3,
        "catheter inserted {}",
        f("inserted_m")
    );
    common::guidewire::assert_pair_ran_clean(&report, c);
    assert_eq!(
        report.allocations_after_start, 0,
        "loop + device + pair + catheter allocations"
    );
}
