//! `nvtmm run` end to end on a small arch for ten seconds (a basis
//! recomputation takes 4 s on a loaded 2-core machine and must reach the
//! loop: it runs at the normal nice level here, since at the service's
//! default of 19 other jobs on the machine starved it past the ten
//! seconds), with the RT
//! allocator installed as in the binary: the loop and device threads make no
//! system-allocator call after start (clarabel's per-solve allocation goes
//! to the RT pool), every histogram fills sensibly, models are refreshed and
//! swapped, the stream is recorded, and the report has its keys.

use nvtmm::rt::stats::Percentiles;
use nvtmm::service::{run_service, StartOptions};

#[global_allocator]
static ALLOC: nvtmm::rt::alloc::RtAllocator = nvtmm::rt::alloc::RtAllocator;

fn sane(name: &str, p: &Percentiles) {
    assert!(
        p.p50 <= p.p99 && p.p99 <= p.p999 && p.p999 <= p.max.max(p.p999),
        "{name}: {p:?}"
    );
    assert!(p.max > 0.0 && p.max.is_finite(), "{name}: {p:?}");
}

#[test]
fn a_short_run_allocates_nothing_after_start_and_fills_every_histogram() {
    let dir = tempfile::tempdir().unwrap();
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let scene = dir.path().join("scene.toml");
    std::fs::write(
        &scene,
        format!(
            r#"model = "nvtmm"
duration = 1.0
[mesh]
arch_nodes = 1458
[material]
law = "stvk"
youngs_pa = 65e3
poisson = 0.45
density = 1050.0
[[prony]]
alpha = 0.5
tau = 0.58
[fixed]
sets = ["inlet", "outlet_descending"]
[integrator]
dt = 1e-2
rayleigh_beta = 1e-3
newton = {{ max_iters = 1 }}
linear = {{ kind = "cg", precond = "block_ic0", tol = 1e-6, max_iter = 500 }}
[reduced]
r = 16
contact_modes = true
contact_region = {{ center = [0.0065, -0.031, 0.177], radius = 0.015, set = "outer_wall" }}
alpha = 5.0
beta = 1e-3
cache_dir = "{}"
"#,
            dir.path().join("cache").display()
        ),
    )
    .unwrap();
    let cfg = dir.path().join("nvtmm.toml");
    std::fs::write(
        &cfg,
        format!(
            r#"scene = "scene.toml"
seconds = 10.0
[loop]
baseline_s = 0.5
[device]
touchx = "{}"
origin_m = [0.0065, -0.031, 0.177]
[interaction]
phases_s = [0.3, 0.3, 0.3, 0.6, 0.3, 0.3]
[stream]
enabled = false
[background]
basis_refresh_s = 0.5
basis_refresh_m = 1e-5
basis_nice = 0
"#,
            root.join("rt-config/touchx.toml").display()
        ),
    )
    .unwrap();
    let record = dir.path().join("run.nvts");
    let report = run_service(&StartOptions {
        record: Some(record.clone()),
        ..StartOptions::file(cfg)
    })
    .unwrap();
    eprintln!("{}", report.render());
    assert!(report.allocator_installed, "the RT pool serves the loop thread");
    assert_eq!(report.allocations_after_start, 0);
    assert!(report.ticks > 1000, "{} ticks", report.ticks);
    for (name, p) in [
        ("period_jitter_us", &report.period_jitter_us),
        ("tick_compute_us", &report.tick_compute_us),
        ("pose_to_force_latency_us", &report.pose_to_force_latency_us),
        ("baseline_jitter_us", &report.baseline_jitter_us),
    ] {
        sane(name, p);
    }
    assert!(report.watchdog.contact_ticks > 0, "the probe touched the wall");
    // Contact anywhere: the probe's touches are new patches, each
    // corrected by the residual compliance from its first tick (the table
    // is built with the basis, before the loop starts).
    let c = &report.contact;
    assert!(c.new_patches >= 1, "{c:?}");
    assert!(
        c.corrected_patches >= 1 && c.corrected_patches + c.never_corrected <= c.new_patches,
        "{c:?}"
    );
    assert_eq!(c.corrected_after_ms.max, 0.0, "{c:?}");
    assert!(c.patches_max >= 1 && c.contact_ticks == report.watchdog.contact_ticks);
    assert_eq!(c.immediate_only_ticks, report.watchdog.compliance_ticks);
    assert!(report.max_force_n > 0.0 && report.max_force_n <= 7.9);
    assert!(report.model_swaps > 0, "refreshed models reached the loop");
    assert!(report.background.steps > 0);
    // The background basis refresh ran and the loop switched basis without
    // allocating.
    assert!(report.background.basis_requests >= 1, "a new basis was asked for");
    assert!(report.background.basis_recomputed >= 1, "a basis was recomputed");
    assert!(
        report.background.basis_swaps >= 1,
        "a model in the new basis reached the loop"
    );
    assert!(report.stream_frames > 0);
    assert!(std::fs::metadata(&record).unwrap().len() > 0);
    assert!(report.energy_out_j <= report.energy_in_j + 0.01 + 1e-12);
    let json = serde_json::to_value(&report).unwrap();
    for key in [
        "ticks",
        "seconds",
        "deadline_misses",
        "period_jitter_us",
        "tick_compute_us",
        "pose_to_force_latency_us",
        "baseline_jitter_us",
        "allocations_after_start",
        "max_force_n",
        "qp",
        "energy_in_j",
        "energy_out_j",
        "ring_overflows",
        "model_swaps",
        "rt_policy_granted",
    ] {
        assert!(json.get(key).is_some(), "report key {key}");
    }
    for key in ["p50", "p99", "p999", "max"] {
        assert!(json["tick_compute_us"].get(key).is_some());
    }
    // Where the tick's time goes: every tick runs the rings, contact, the
    // step, the filter and the output; swaps and cross-fades ran; the
    // phases and the unattributed rest add up to the whole compute time.
    let ph = &report.tick_phases;
    for key in ["drain", "instruments", "contact", "step", "filter", "output", "other"] {
        assert_eq!(ph.phases[key].ticks, report.ticks, "tick_phases.phases.{key}");
        sane(key, &ph.phases[key].us);
    }
    assert_eq!(ph.phases["swap"].ticks, report.model_swaps);
    // Each model swapped in was taken and warmed on an earlier tick; one
    // more may have been taken just before the stop.
    let warmed = ph.phases["warm"].ticks;
    assert!(
        warmed >= report.model_swaps && warmed <= report.model_swaps + 1,
        "warmed {warmed}, swapped {}",
        report.model_swaps
    );
    assert!(ph.phases["fade"].ticks > 0, "the cross-fade ran");
    // A cross-fade ends early at most once, and only a swap's.
    assert!(
        report.watchdog.fades_ended_early <= report.model_swaps,
        "{} fades ended early, {} swaps",
        report.watchdog.fades_ended_early,
        report.model_swaps
    );
    assert_eq!(ph.phases["series"].ticks, report.watchdog.compliance_ticks);
    // The probe slides, so its sphere leaves its kept triangles' slack and
    // searches again; never on more ticks than contact ran.
    let searched = ph.phases["search"].ticks;
    assert!(searched > 0 && searched < report.ticks, "search ticks {searched}");
    let shares: f64 = ph
        .phases
        .iter()
        .filter(|(k, _)| !matches!(**k, "search" | "series" | "qp_solve"))
        .map(|(_, st)| st.share)
        .sum();
    assert!(
        (shares - 1.0).abs() < 1e-6,
        "the outer phases and `other` make up the tick: {shares}"
    );
    let slowest = ph.slowest_tick_us["compute"];
    assert_eq!(slowest, report.tick_compute_us.max);
    for key in ["p50", "p99", "p999", "max"] {
        assert!(json["tick_phases"]["phases"]["contact"]["us"].get(key).is_some());
    }
    for key in ["ticks", "mean_us", "per_tick_us", "share"] {
        assert!(json["tick_phases"]["phases"]["step"].get(key).is_some());
    }
    for key in ["slowest_tick_us", "tail_threshold_us", "tail_ticks", "tail_mean_us"] {
        assert!(json["tick_phases"].get(key).is_some(), "tick_phases.{key}");
    }
    for key in [
        "solves",
        "active_norm",
        "active_rate",
        "active_energy",
        "iters_p99",
        "solve_us_p99",
    ] {
        assert!(json["qp"].get(key).is_some(), "qp.{key}");
    }
    // The report lists each instrument: here the probe alone.
    let ids: Vec<(&str, &str)> = report
        .instruments
        .iter()
        .map(|i| (i.id.as_str(), i.kind.as_str()))
        .collect();
    assert_eq!(ids, [("probe", "probe")]);
    assert_eq!(
        json["instruments"][0]["keys"]["contact_ticks"],
        report.watchdog.contact_ticks
    );
    assert!(report.wire.is_none());
}

#[test]
fn bad_configuration_names_the_file_and_key() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("nvtmm.toml");
    std::fs::write(&cfg, "scene = \"x.toml\"\n[loop]\npriority = 200\n").unwrap();
    let err = run_service(&StartOptions::file(cfg.clone())).unwrap_err().to_string();
    assert!(err.contains("nvtmm.toml") && err.contains("loop.priority"), "{err}");
    std::fs::write(&cfg, "scene = \"missing.toml\"\n").unwrap();
    let err = run_service(&StartOptions::file(cfg.clone())).unwrap_err().to_string();
    assert!(
        err.contains("missing.toml") && err.contains("nvtmm.toml") && err.contains("scene"),
        "the error names the config file, its key and the scene file: {err}"
    );
}
