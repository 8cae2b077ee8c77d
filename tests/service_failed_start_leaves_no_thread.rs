//! A start that fails part-way (here: the recording file cannot be
//! created, after the background threads are already running) returns the
//! error and leaves no thread of the service behind: an embedding
//! application that retries does not pile up full solves.

mod common;

use nvtmm::service::{Service, StartOptions};
use std::time::{Duration, Instant};

/// Threads of this process whose name starts with `nvtmm-`.
fn service_threads() -> Vec<String> {
    let mut out = Vec::new();
    for e in std::fs::read_dir("/proc/self/task").unwrap().flatten() {
        if let Ok(name) = std::fs::read_to_string(e.path().join("comm")) {
            if name.starts_with("nvtmm-") {
                out.push(name.trim().to_string());
            }
        }
    }
    out
}

#[test]
fn a_start_that_fails_after_spawning_threads_stops_them() {
    let dir = tempfile::tempdir().unwrap();
    assert!(service_threads().is_empty(), "{:?}", service_threads());
    // The recovery tests' small service (background and basis refresh on),
    // recording into a directory that does not exist.
    let options = StartOptions {
        record: Some(dir.path().join("no-such-directory").join("run.nvtrec")),
        ..common::service::options(dir.path())
    };
    let err = match Service::start(options) {
        Ok(_) => panic!("a recording into a missing directory must fail the start"),
        Err(e) => e.to_string(),
    };
    assert!(err.contains("stream"), "{err}");
    // The threads already spawned see the stop flag and end (a full step
    // or a basis recomputation in progress finishes first: up to 60 s on a
    // loaded machine).
    let t0 = Instant::now();
    while !service_threads().is_empty() && t0.elapsed() < Duration::from_secs(60) {
        std::thread::sleep(Duration::from_millis(50));
    }
    assert!(
        service_threads().is_empty(),
        "threads left behind {:.1} s after the failed start: {:?}",
        t0.elapsed().as_secs_f64(),
        service_threads()
    );
}
