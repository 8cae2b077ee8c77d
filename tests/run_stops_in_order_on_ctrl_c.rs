//! `nvtmm run` interrupted by SIGINT (Ctrl-C) or SIGTERM (`systemctl stop`)
//! stops the service in order, as at the end of its planned run: the device
//! at zero force, the threads joined, the report printed, exit status 0.
//! Without a handler the signal would end the process with the device's
//! last force command still in place.

use std::io::Read;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

fn write_config(dir: &std::path::Path) -> std::path::PathBuf {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
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
cache_dir = "{}"
"#,
            dir.join("cache").display()
        ),
    )
    .unwrap();
    let path = dir.join("service.toml");
    std::fs::write(
        &path,
        format!(
            r#"scene = "scene.toml"
seconds = 120.0
[loop]
baseline_s = 0.1
[device]
touchx = "{}"
origin_m = [0.0065, -0.031, 0.177]
[stream]
enabled = false
"#,
            root.join("rt-config/touchx.toml").display()
        ),
    )
    .unwrap();
    path
}

fn interrupted_run_reports(signal: libc::c_int) {
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path());
    let mut child = Command::new(env!("CARGO_BIN_EXE_nvtmm"))
        .args(["run", config.to_str().unwrap(), "--quiet"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Long enough to be running (or still setting up: a signal then stops
    // the service right after its start), far short of its 120 s.
    std::thread::sleep(Duration::from_secs(6));
    let t0 = Instant::now();
    // SAFETY: kill() on our own child's pid with a valid signal number.
    assert_eq!(unsafe { libc::kill(child.id() as libc::pid_t, signal) }, 0);
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(90),
            "nvtmm run did not stop within 90 s of the signal"
        );
        std::thread::sleep(Duration::from_millis(50));
    };
    let mut out = String::new();
    let mut err = String::new();
    child.stdout.take().unwrap().read_to_string(&mut out).unwrap();
    child.stderr.take().unwrap().read_to_string(&mut err).unwrap();
    println!(
        "stderr:\n{err}\nstdout (head):\n{}",
        out.lines().take(6).collect::<Vec<_>>().join("\n")
    );
    assert!(
        status.success(),
        "exit status {status} after signal {signal}; stderr: {err}"
    );
    assert!(err.contains("interrupted"), "the interruption is said: {err}");
    assert!(out.contains("allocations"), "the report is printed: {out}");
}

#[test]
fn sigint_stops_the_service_in_order_and_prints_the_report() {
    interrupted_run_reports(libc::SIGINT);
}

#[test]
fn sigterm_stops_the_service_in_order_and_prints_the_report() {
    interrupted_run_reports(libc::SIGTERM);
}
