//! The embedding API (`Service::start` → `Handle::snapshot` → `Handle::stop`)
//! drives the service as a renderer or a training app would: from an
//! in-memory configuration, with live figures that advance while it runs,
//! a state frame of the deformed surface, and a report at the end.

use nvtmm::service::{Service, StartOptions};
use std::time::Duration;

mod common;

#[global_allocator]
static ALLOC: nvtmm::rt::alloc::RtAllocator = nvtmm::rt::alloc::RtAllocator;

#[test]
fn start_snapshot_stop_from_an_in_memory_config() {
    let dir = tempfile::tempdir().unwrap();
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    common::service::write_small_scene(dir.path());
    let config = format!(
        r#"scene = "scene.toml"
seconds = 2.0
[loop]
baseline_s = 0.1
[device]
touchx = "{}"
origin_m = [0.0065, -0.031, 0.177]
[stream]
enabled = false
"#,
        root.join("rt-config/touchx.toml").display()
    );
    // Nothing is read from this path: it labels messages and anchors
    // the relative scene path.
    let label = dir.path().join("in-memory.toml");
    let handle = Service::start(StartOptions::text(config, label)).unwrap();
    std::thread::sleep(Duration::from_millis(700));
    let a = handle.snapshot();
    // The first state frame comes from the publisher thread (normal
    // priority): wait for it, up to 20 s on a loaded machine.
    let mut b = handle.snapshot();
    for _ in 0..200 {
        std::thread::sleep(Duration::from_millis(100));
        b = handle.snapshot();
        if b.frame.is_some() && b.ticks > a.ticks {
            break;
        }
    }
    assert!(!handle.is_finished());
    assert!(b.ticks > a.ticks, "the loop advances: {} then {}", a.ticks, b.ticks);
    assert!(b.elapsed_s > a.elapsed_s);
    assert!(b.force_n.iter().all(|v| v.is_finite()));
    let frame = b.frame.expect("the publisher keeps the latest state frame");
    assert!(!frame.positions.is_empty());
    assert_eq!(frame.positions.len(), frame.node_ids.len());
    assert!(frame.positions.iter().flatten().all(|v| v.is_finite()));
    // Each instrument's polyline: the probe's one point is the tool.
    assert_eq!(frame.instruments.len(), 1);
    let probe = &frame.instruments[0];
    assert_eq!(
        (probe.id.as_str(), probe.kind.as_str(), probe.kind_code),
        ("probe", "probe", 1)
    );
    assert_eq!(probe.points.len(), 1);
    assert!(probe.points[0].iter().all(|v| v.is_finite()));
    let report = handle.stop().unwrap();
    assert!(report.ticks >= b.ticks, "the report counts every tick");
    assert_eq!(report.nodes, 1456);
    assert_eq!(report.allocations_after_start, 0, "no allocation on the RT threads");
}

#[test]
fn a_bad_in_memory_config_names_its_label_and_key() {
    let err = Service::start(StartOptions::text(
        "scene = \"s.toml\"\n[loop]\nrate_hz = 5.0\n",
        "inline.toml",
    ))
    .unwrap_err()
    .to_string();
    assert!(err.contains("inline.toml") && err.contains("loop.rate_hz"), "{err}");
}
