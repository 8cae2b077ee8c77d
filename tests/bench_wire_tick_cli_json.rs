//! `nvtmm bench wire --tick --json` runs the whole guidewire tick on the
//! service's scene (`rt-config/guidewire.toml`: the branched arch and its
//! cached basis) and prints the JSON keys scripts depend on; the wire got
//! through the script without a reset and every part was timed. No timing
//! thresholds (the machine is shared). An evaluation budget of 12 bounds
//! every step's evaluations. With `--rt` the ticks run paced and say what
//! the OS granted; the 127-node wire on the wall gets through the hub's
//! turn in few evaluations (a count, not a time). The first run on a
//! fresh checkout meshes the arch and computes its basis (minutes; cached
//! after).

use std::process::Command;

/// One run at a time: on a fresh checkout the first meshes the arch and
/// computes its basis (minutes), and the others then read the cache
/// instead of computing it alongside.
static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// Runs `nvtmm bench wire --tick ARGS --json` in the source tree, checks it
/// succeeded and returns its JSON.
fn bench_tick_json(args: &[&str]) -> serde_json::Value {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let out = Command::new(env!("CARGO_BIN_EXE_nvtmm"))
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .args(["bench", "wire", "--tick"])
        .args(args)
        .arg("--json")
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&out.stdout).expect("JSON")
}

#[test]
fn bench_wire_tick_json_has_the_contract_keys_and_no_resets() {
    let v = bench_tick_json(&["--nodes", "64", "--steps", "200", "--evaluations", "12"]);
    let obj = v.as_object().expect("an object");
    let mut keys: Vec<&str> = obj.keys().map(String::as_str).collect();
    keys.sort_unstable();
    assert_eq!(
        keys,
        [
            "buckled",
            "buckling_checks",
            "budget_spent",
            "contacts_max",
            "contacts_mean",
            "evaluations_max",
            "evaluations_max_allowed",
            "evaluations_mean",
            "evaluations_p999",
            "follow_wall",
            "haptic_us",
            "inserted_mm",
            "iterations_max",
            "iterations_mean",
            "line_load_n_per_m",
            "loads_max",
            "loads_us",
            "lumen_updates",
            "lumen_us",
            "max_penetration_mm",
            "memory_locked",
            "nodes",
            "paced",
            "qp_solved",
            "qp_us",
            "resets",
            "rt",
            "segment_mm",
            "tick_us",
            "ticks",
            "time_limited",
            "tip_m",
            "wire_us"
        ]
    );
    assert_eq!(obj["ticks"], 200);
    // The buckling check's counts are of the timed steps.
    assert!(obj["buckled"].as_u64().unwrap() <= obj["buckling_checks"].as_u64().unwrap());
    assert!(obj["buckling_checks"].as_u64().unwrap() <= 200);
    assert_eq!(obj["tip_m"].as_array().map(Vec::len), Some(3));
    assert_eq!(obj["resets"], 0);
    assert_eq!(obj["follow_wall"], false);
    // Back to back in an ordinary thread unless asked.
    assert_eq!(obj["paced"], false);
    assert_eq!(obj["rt"]["fifo"], false);
    // The budget bounds every step's evaluations.
    assert_eq!(obj["evaluations_max_allowed"], 12);
    let most = obj["evaluations_max"].as_u64().unwrap();
    assert!((3..=12).contains(&most), "{most} evaluations");
    assert!(obj["evaluations_p999"].as_u64().unwrap() <= most);
    let nodes = obj["nodes"].as_u64().unwrap();
    assert!((50..=64).contains(&nodes), "{nodes} nodes");
    assert!(obj["inserted_mm"].as_f64().unwrap() > 150.0);
    assert!(obj["max_penetration_mm"].as_f64().unwrap() < 0.445);
    assert!(obj["lumen_updates"].as_u64().unwrap() >= 11);
    for k in ["tick_us", "wire_us", "loads_us", "haptic_us", "qp_us", "lumen_us"] {
        let p = obj[k].as_object().unwrap_or_else(|| panic!("{k}"));
        let p50 = p["p50"].as_f64().unwrap();
        let max = p["max"].as_f64().unwrap();
        assert!(p50.is_finite() && p50 >= 0.0 && max >= p50, "{k}: {p:?}");
    }
    // The whole tick holds its parts.
    assert!(obj["tick_us"]["p50"].as_f64() >= obj["wire_us"]["p50"].as_f64());
}

#[test]
fn bench_wire_tick_with_rt_runs_paced_and_says_what_the_os_granted() {
    let v = bench_tick_json(&["--nodes", "32", "--steps", "100", "--rt", "0"]);
    assert_eq!(v["paced"], true);
    assert_eq!(v["ticks"], 100);
    assert_eq!(v["resets"], 0);
    // Granted, or refused with the reason said (an unprivileged machine).
    let refusals: Vec<String> = v["rt"]["refusals"]
        .as_array()
        .expect("refusals")
        .iter()
        .map(|r| r.as_str().unwrap().to_string())
        .collect();
    let said = |what: &str| refusals.iter().any(|r| r.contains(what));
    assert!(v["rt"]["fifo"] == true || said("SCHED_FIFO"), "{refusals:?}");
    assert!(v["rt"]["cpu"] == 0 || said("CPU 0"), "{refusals:?}");
    assert!(v["memory_locked"] == true || said("mlockall"), "{refusals:?}");
    assert_eq!(v["rt"]["priority"], 80);
}

#[test]
fn the_hub_turning_to_push_costs_few_evaluations() {
    // The bench's 127-node wire pressed onto the deformed wall by 5 N/m
    // (33 contacts), its hub moved ±1.5 mm at 1 Hz: where the hub turns to
    // push, the contacts break from sticking into slipping. Sliding the
    // whole wire by each small feed started every contact slipping, and
    // those steps took up to 14 evaluations here, 15 over 3000 ticks (docs/WIRE.md "Slow pushes
    // start from the unmoved wire"). The timed second covers a turn.
    let v = bench_tick_json(&["--steps", "1000", "--follow-wall", "--line-load", "5"]);
    assert_eq!(v["resets"], 0);
    let contacts = v["contacts_mean"].as_f64().unwrap();
    assert!(
        contacts >= 25.0,
        "{contacts} contacts on average: not the wall-loaded wire"
    );
    let most = v["evaluations_max"].as_u64().unwrap();
    assert!(most <= 8, "{most} evaluations in a step");
}
