//! `nvtmm bench reduced --r R [--nodes N] [--json]` prints the JSON keys
//! scripts depend on, plus the documented extras and nothing else (small
//! mesh, few steps; no timing thresholds).

use std::process::Command;

#[test]
fn bench_reduced_json_has_exactly_the_contract_keys() {
    let out = Command::new(env!("CARGO_BIN_EXE_nvtmm"))
        .args([
            "bench", "reduced", "--r", "10", "--nodes", "300", "--steps", "50", "--json",
        ])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON");
    let obj = v.as_object().expect("an object");
    let mut keys: Vec<&str> = obj.keys().map(String::as_str).collect();
    keys.sort_unstable();
    assert_eq!(
        keys,
        [
            "basis_iterations",
            "basis_s",
            "basis_warm_iterations",
            "basis_warm_s",
            "nodes",
            "r",
            "refresh_assembly_ms",
            "refresh_ms",
            "us_per_step",
            "us_per_step_p99"
        ]
    );
    assert_eq!(obj["r"], 10);
    assert!(obj["nodes"].as_u64().unwrap() > 250);
    for k in [
        "us_per_step",
        "us_per_step_p99",
        "refresh_ms",
        "basis_s",
        "refresh_assembly_ms",
        "basis_warm_s",
    ] {
        let x = obj[k].as_f64().unwrap();
        assert!(x.is_finite() && x > 0.0, "{k} = {x}");
    }
    assert!(obj["us_per_step_p99"].as_f64() >= obj["us_per_step"].as_f64());
    for k in ["basis_iterations", "basis_warm_iterations"] {
        assert!(obj[k].as_u64().unwrap() >= 1, "{k}");
    }

    let bad = Command::new(env!("CARGO_BIN_EXE_nvtmm"))
        .args(["bench", "reduced", "--r", "65", "--nodes", "300"])
        .output()
        .unwrap();
    assert!(!bad.status.success());
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(err.contains("--r 65") && !err.contains("panicked"), "{err}");
}
