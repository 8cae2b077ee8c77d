//! `nvtmm run` (the haptic service) and `nvtmm check-rt` (the box audit).

use nvtmm::rt::check::{audit, render, Level};
use nvtmm::service::{default_config, run_service_until, ServiceConfig, StartOptions};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};

/// Set by SIGINT or SIGTERM: `nvtmm run` then stops the service in order.
static INTERRUPTED: AtomicBool = AtomicBool::new(false);

extern "C" fn on_interrupt(sig: libc::c_int) {
    // Only async-signal-safe work here: an atomic store, and the default
    // disposition back so that a second Ctrl-C ends the process at once.
    INTERRUPTED.store(true, Ordering::Relaxed);
    // SAFETY: signal() is async-signal-safe (POSIX) and SIG_DFL is valid.
    unsafe {
        libc::signal(sig, libc::SIG_DFL);
    }
}

/// Routes SIGINT and SIGTERM to [`INTERRUPTED`] instead of ending the
/// process with the device's last force still commanded.
fn catch_interrupts() {
    let handler: extern "C" fn(libc::c_int) = on_interrupt;
    for sig in [libc::SIGINT, libc::SIGTERM] {
        // SAFETY: installs a handler that only stores an atomic and resets
        // its own disposition (both async-signal-safe).
        unsafe {
            libc::signal(sig, handler as libc::sighandler_t);
        }
    }
}

type Result<T> = std::result::Result<T, Box<dyn std::error::Error>>;

pub fn run(
    config: Option<&Path>,
    seconds: Option<f64>,
    report_json: Option<&Path>,
    record: Option<PathBuf>,
    quiet: bool,
) -> Result<()> {
    let config = config.map(Path::to_path_buf).unwrap_or_else(default_config);
    let opts = StartOptions {
        seconds,
        observer: crate::cli::progress::terminal(quiet),
        record,
        ..StartOptions::file(config)
    };
    catch_interrupts();
    let report = run_service_until(&opts, &INTERRUPTED)?;
    if INTERRUPTED.load(Ordering::Relaxed) {
        eprintln!("interrupted: the service stopped in order (the device at zero force, threads joined)");
    }
    print!("{}", report.render());
    if let Some(p) = report_json {
        if let Some(dir) = p.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir)?;
        }
        std::fs::write(p, serde_json::to_string_pretty(&report)? + "\n")
            .map_err(|e| format!("{}: {e}", p.display()))?;
        println!("report: {}", p.display());
    }
    Ok(())
}

pub fn check_rt(config: Option<&PathBuf>, json: bool) -> Result<()> {
    let cpu = match config {
        Some(p) => {
            let c = ServiceConfig::load(p)?;
            (c.servo.cpu >= 0).then_some(c.servo.cpu as usize)
        }
        None => {
            let d = default_config();
            ServiceConfig::load(&d)
                .ok()
                .and_then(|c| (c.servo.cpu >= 0).then_some(c.servo.cpu as usize))
        }
    };
    let checks = audit(cpu);
    if json {
        println!("{}", serde_json::to_string_pretty(&checks)?);
    } else {
        print!("{}", render(&checks));
        let fails = checks.iter().filter(|c| c.level == Level::Fail).count();
        let warns = checks.iter().filter(|c| c.level == Level::Warn).count();
        println!("{fails} fail, {warns} warn, {} pass", checks.len() - fails - warns);
    }
    Ok(())
}

/// `nvtmm soak`: runs the campaign, prints its summary, writes the JSON;
/// a failed check is an error (non-zero exit).
pub fn soak(config: Option<PathBuf>, minutes: f64, seed: u64, json: Option<&Path>, quiet: bool) -> Result<()> {
    let config = config.unwrap_or_else(default_config);
    let report = nvtmm::soak::run_soak(&nvtmm::soak::SoakOptions {
        config,
        minutes,
        seed,
        stiff_fraction: 0.25,
        observer: crate::cli::progress::terminal(quiet),
    })?;
    print!("{}", report.render());
    if let Some(p) = json {
        if let Some(dir) = p.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir)?;
        }
        std::fs::write(p, serde_json::to_string_pretty(&report)? + "\n")
            .map_err(|e| format!("{}: {e}", p.display()))?;
    }
    if report.passed {
        Ok(())
    } else {
        Err("the soak failed a check (see the FAIL lines above)".into())
    }
}
