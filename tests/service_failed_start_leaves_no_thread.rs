//! A start that fails part-way (here: the recording file cannot be
//! created, after the background threads are already running) returns the
//! error and leaves no thread of the service behind: an embedding
//! application that retries does not pile up full solves.

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
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    std::fs::write(
        dir.path().join("scene.toml"),
        format!(
            r#"model = "nvtmm"
duration = 1.0
[mesh]
arch_nodes = 1458
[material]
youngs_pa = 65e3
poisson = 0.45
[fixed]
sets = ["inlet", "outlet_descending"]
[integrator]
dt = 1e-2
newton = {{ max_iters = 1 }}
linear = {{ kind = "cholesky_pcg", tol = 1e-6, refactor_every = 3, factor_f32 = true }}
[reduced]
r = 16
contact_modes = true
contact_region = {{ center = [0.0065, -0.031, 0.177], radius = 0.015, set = "outer_wall" }}
cache_dir = "{}"
"#,
            dir.path().join("cache").display()
        ),
    )
    .unwrap();
    let config = format!(
        r#"scene = "scene.toml"
seconds = 2.0
[loop]
baseline_s = 0.1
[device]
touchx = "{}"
origin_m = [0.0065, -0.031, 0.177]
[background]
enabled = true
basis_refresh_s = 5.0
[stream]
enabled = false
"#,
        root.join("rt-config/touchx.toml").display()
    );
    assert!(service_threads().is_empty(), "{:?}", service_threads());
    let options = StartOptions {
        record: Some(dir.path().join("no-such-directory").join("run.nvtrec")),
        ..StartOptions::text(config, dir.path().join("in-memory.toml"))
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
