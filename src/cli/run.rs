//! `nvtmm run` (the haptic service) and `nvtmm check-rt` (the box audit).

use nvtmm::rt::check::{audit, render, Level};
use nvtmm::service::{default_config, run_service, ServiceConfig, StartOptions};
use std::path::{Path, PathBuf};

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
    let report = run_service(&opts)?;
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
