//! `nvtmm run` interrupted by SIGINT (Ctrl-C) or SIGTERM (`systemctl stop`)
//! stops the service in order, as at the end of its planned run: the device
//! at zero force, the threads joined, the report printed, exit status 0.
//! Without a handler the signal would end the process with the device's
//! last force command still in place.

use std::io::Read;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

mod common;

/// The recovery tests' small service (1458-node arch) as files in `dir`,
/// planned for far longer than the test waits, without the background basis
/// recomputation (a nice-19 thread a loaded machine can starve, which would
/// hold the stop for minutes).
fn write_config(dir: &std::path::Path) -> std::path::PathBuf {
    let config = common::service::write_scene_and_config(dir)
        .replace("seconds = 60.0", "seconds = 120.0")
        .replace("basis_refresh_s = 0.3", "basis_refresh_s = 0.0");
    let path = dir.join("service.toml");
    std::fs::write(&path, config).unwrap();
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
