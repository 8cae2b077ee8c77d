//! The `--quick` experiments run end to end and write well-formed outputs
//! (structure and sanity, not timing).

use nvtmm::experiment::{fig5, table, trade};

fn csv_rows(path: &std::path::Path) -> Vec<Vec<String>> {
    let text = std::fs::read_to_string(path).unwrap();
    text.lines().map(|l| l.split(',').map(String::from).collect()).collect()
}

#[test]
fn fig5_quick_writes_csv_png_json_with_finite_metrics() {
    let dir = tempfile::tempdir().unwrap();
    let r = fig5::run(&fig5::Fig5Params::quick(), dir.path()).unwrap();
    let rows = csv_rows(&dir.path().join("fig5.csv"));
    assert_eq!(
        rows[0],
        [
            "t_s",
            "tmm_force_n",
            "tmm_displacement_m",
            "nvtmm_force_n",
            "nvtmm_displacement_m"
        ]
    );
    assert!(rows.len() > 100);
    assert!(std::fs::metadata(dir.path().join("fig5.png")).unwrap().len() > 10_000);
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("fig5.json")).unwrap()).unwrap();
    for m in json["models"].as_array().unwrap() {
        for key in ["overshoot", "settle_time_s", "final_displacement_m"] {
            assert!(m[key].as_f64().unwrap().is_finite(), "{key}");
        }
    }
    // Before the load nothing moves; after it, the node moves and the force at
    // the node balances the applied one.
    for m in &r.models {
        assert!(m.final_displacement_m > 1e-5, "{m:?}");
        assert!(
            (m.final_force_n - r.params.force_n).abs() < 0.05 * r.params.force_n,
            "{m:?}"
        );
    }
    let t_load = r.params.t_load;
    let first_load_row = rows
        .iter()
        .skip(1)
        .position(|row| row[0].parse::<f64>().unwrap() >= t_load)
        .unwrap();
    assert!(rows[1..=first_load_row]
        .iter()
        .all(|r| r[2].parse::<f64>().unwrap() == 0.0));
}

#[test]
fn table_quick_has_the_paper_columns() {
    let dir = tempfile::tempdir().unwrap();
    let rows = table::run(dir.path(), true).unwrap();
    assert_eq!(rows.len(), 3);
    for r in &rows {
        // A rate is either measured or its failure is reported.
        assert!(r.visual_fps > 0.0 || r.failure.is_some(), "{r:?}");
        assert!(r.haptic_fps > 0.0 || r.failure.is_some(), "{r:?}");
        assert!(r.paper_visual_fps > 0.0);
    }
    // The paper's method runs at both rates.
    let nv = rows.iter().find(|r| r.model == "nvtmm").unwrap();
    assert!(
        nv.failure.is_none() && nv.visual_fps.is_finite() && nv.haptic_fps.is_finite(),
        "{nv:?}"
    );
    // The reduced model's rate is on the NVTMM row only.
    assert!(
        nv.reduced_haptic_fps.is_finite() && nv.reduced_haptic_fps > 0.0,
        "{nv:?}"
    );
    assert!(rows
        .iter()
        .filter(|r| r.model != "nvtmm")
        .all(|r| r.reduced_haptic_fps.is_nan()));
    let md = std::fs::read_to_string(dir.path().join("table.md")).unwrap();
    assert!(md.contains("paper") && md.contains("nvtmm") && md.contains("cores"));
    assert_eq!(csv_rows(&dir.path().join("table.csv")).len(), 4);
}

#[test]
fn trade_quick_errors_shrink_with_dt_and_resolution() {
    let dir = tempfile::tempdir().unwrap();
    let (rows, finest) = trade::run(dir.path(), true).unwrap();
    assert!(finest > 0);
    for r in &rows {
        assert!(
            (r.ms_per_step > 0.0 && r.err_load_disp.is_finite()) || r.value.contains("failed"),
            "{r:?}"
        );
    }
    let nv_dt: Vec<_> = rows.iter().filter(|r| r.knob == "dt" && r.model == "nvtmm").collect();
    let (first, last) = (nv_dt.first().unwrap(), nv_dt.last().unwrap());
    assert!(
        first.err_load_disp < last.err_load_disp,
        "smaller dt must be closer to the reference: {first:?} {last:?}"
    );
    let mesh: Vec<_> = rows.iter().filter(|r| r.knob == "mesh_nodes").collect();
    assert!(mesh.first().unwrap().err_load_disp > mesh.last().unwrap().err_load_disp);
    // The service's background solve against the converged run of the same
    // press: measured, and longer steps are further off.
    let bg: Vec<_> = rows.iter().filter(|r| r.knob == "background").collect();
    assert!(bg.len() >= 2, "{bg:?}");
    assert!(
        bg.iter().all(|r| r.err_load_disp.is_finite() && r.err_load_disp < 1.0),
        "{bg:?}"
    );
    assert!(
        bg.first().unwrap().err_load_disp < bg.last().unwrap().err_load_disp,
        "longer background steps must be further from the reference: {bg:?}"
    );
    for f in ["trade.csv", "trade.png", "trade.md"] {
        assert!(dir.path().join(f).exists(), "{f}");
    }
    assert!(std::fs::read_to_string(dir.path().join("trade.md"))
        .unwrap()
        .contains("1 kHz haptic"));
}
