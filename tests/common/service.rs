//! A small running service for the recovery tests, and a poll helper.

use nvtmm::service::{Handle, Service, Snapshot, StartOptions};
use std::time::{Duration, Instant};

/// Starts a small service (1458-node arch, r = 16) with the basis refresh
/// every 0.3 s (at nice 0: at the service's default of 19, other jobs on a
/// loaded machine starve it for tens of seconds) and short model
/// timeouts, in `dir`.
pub fn start(dir: &std::path::Path) -> Handle {
    Service::start(options(dir)).unwrap()
}

/// The options [`start`] starts with (the scene file written into `dir`).
pub fn options(dir: &std::path::Path) -> StartOptions {
    let config = write_scene_and_config(dir);
    StartOptions::text(config, dir.join("in-memory.toml"))
}

/// Writes the small service's scene (`dir/scene.toml`: the 1458-node arch,
/// r = 16, its basis cached in `dir/cache`).
pub fn write_small_scene(dir: &std::path::Path) {
    std::fs::write(
        dir.join("scene.toml"),
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
            dir.join("cache").display()
        ),
    )
    .unwrap();
}

/// Writes the small service's scene (`dir/scene.toml`) and returns its
/// service configuration's text (relative paths anchored in `dir`).
pub fn write_scene_and_config(dir: &std::path::Path) -> String {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    write_small_scene(dir);
    format!(
        r#"scene = "scene.toml"
seconds = 60.0
[loop]
baseline_s = 0.1
[device]
touchx = "{}"
origin_m = [0.0065, -0.031, 0.177]
[watchdog]
model_timeout_ms = 300.0
model_max_age_ms = 1000.0
[background]
basis_refresh_s = 0.3
basis_refresh_m = 0.0
basis_nice = 0
[stream]
enabled = false
"#,
        root.join("rt-config/touchx.toml").display()
    )
}

/// Polls `cond` on snapshots every 10 ms for up to `secs` (a loaded
/// machine is slow); true if it held.
pub fn wait_for(h: &Handle, secs: f64, cond: impl Fn(&Snapshot) -> bool) -> bool {
    let t = Instant::now();
    while t.elapsed().as_secs_f64() < secs {
        if cond(&h.snapshot()) {
            return true;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    false
}
