//! Embedding the haptic service in your own program: start it from a
//! configuration built in memory, read its live state while it runs, stop
//! it and print the report. A renderer or a training app does the same,
//! drawing `snapshot().frame` (the deformed surface, the tool, the force)
//! at its own rate.
//!
//! ```sh
//! cargo run --release --example embed
//! ```

use nvtmm::service::{Service, StartOptions};
use std::path::Path;
use std::time::{Duration, Instant};

/// The RT allocator: a fixed pool for the service's RT threads that also
/// counts any system-allocator call they make (the report's
/// `allocations_after_start`). An embedder installs it the same way.
#[global_allocator]
static ALLOCATOR: nvtmm::rt::alloc::RtAllocator = nvtmm::rt::alloc::RtAllocator;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    // The shipped scene (the arch at 5832 nodes) and the simulated Touch X;
    // relative paths resolve against the directory of `label`.
    let config = r#"
scene = "scenes/arch_service.toml"
seconds = 2.0
[loop]
baseline_s = 0.2
[device]
backend = "touchx-sim"
touchx = "touchx.toml"
origin_m = [0.0065, -0.031, 0.177]
[stream]
enabled = false
"#;
    let label = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("rt-config")
        .join("embedded.toml");
    let handle = Service::start(StartOptions::text(config, label))?;
    let t0 = Instant::now();
    while t0.elapsed() < Duration::from_secs(2) {
        std::thread::sleep(Duration::from_millis(500));
        let s = handle.snapshot();
        let f = s.force_n;
        println!(
            "t = {:4.1} s: {:5} ticks, force ({:+.3}, {:+.3}, {:+.3}) N, {} background steps, frame: {}",
            s.elapsed_s,
            s.ticks,
            f[0],
            f[1],
            f[2],
            s.background_steps,
            s.frame
                .as_ref()
                .map(|fr| format!("{} vertices at t = {:.3} s", fr.positions.len(), fr.time_s))
                .unwrap_or_else(|| "none yet".into())
        );
    }
    let report = handle.stop()?;
    print!("{}", report.render());
    Ok(())
}
