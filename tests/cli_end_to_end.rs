//! The command line as a user runs it: the exact subcommands and JSON keys
//! scripts depend on, outputs on disk, and bad input giving a non-zero exit
//! with a message that names the file and the place.

use std::path::Path;
use std::process::{Command, Output};

fn nvtmm(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_nvtmm"))
        .args(args)
        .output()
        .expect("the binary runs")
}

fn ok(args: &[&str]) -> String {
    let out = nvtmm(args);
    assert!(
        out.status.success(),
        "{args:?} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

fn fails(args: &[&str]) -> String {
    let out = nvtmm(args);
    assert!(!out.status.success(), "{args:?} should fail");
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(!err.contains("panicked"), "{args:?} panicked: {err}");
    err
}

#[test]
fn mesh_arch_info_convert() {
    let dir = tempfile::tempdir().unwrap();
    let msh = dir.path().join("arch.msh");
    let msh = msh.to_str().unwrap();
    ok(&["mesh", "arch", "--nodes", "1458", "--out", msh]);
    let info: serde_json::Value = serde_json::from_str(&ok(&["mesh", "info", msh, "--json"])).unwrap();
    for key in [
        "nodes",
        "tets",
        "surface_triangles",
        "volume_m3",
        "inverted",
        "min_dihedral_deg",
        "max_aspect_ratio",
        "bbox_min",
        "bbox_max",
    ] {
        assert!(info.get(key).is_some(), "mesh info --json lacks {key}");
    }
    let n = info["nodes"].as_u64().unwrap() as f64;
    assert!((n - 1458.0).abs() / 1458.0 < 0.01);
    assert_eq!(info["inverted"], 0);
    assert!(info["min_dihedral_deg"].as_f64().unwrap() > 5.0);
    let vtu = dir.path().join("arch.vtu");
    ok(&["mesh", "convert", msh, vtu.to_str().unwrap()]);
    let again: serde_json::Value =
        serde_json::from_str(&ok(&["mesh", "info", vtu.to_str().unwrap(), "--json"])).unwrap();
    assert_eq!(again["tets"], info["tets"]);
    let png = dir.path().join("arch.png");
    ok(&["mesh", "render", "arch:300", "--out", png.to_str().unwrap()]);
    assert!(std::fs::metadata(&png).unwrap().len() > 1000);
}

#[test]
fn bad_mesh_files_name_file_and_line() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("bad.msh");
    std::fs::write(&bad, "$MeshFormat\n4.1 0 8\n$EndMeshFormat\n$Nodes\n1 2 1 2\ngarbage\n").unwrap();
    let err = fails(&["mesh", "info", bad.to_str().unwrap()]);
    assert!(err.contains("bad.msh") && err.contains(":6"), "{err}");
    let err = fails(&["mesh", "info", dir.path().join("missing.vtk").to_str().unwrap()]);
    assert!(err.contains("missing.vtk"), "{err}");
    let err = fails(&["mesh", "convert", bad.to_str().unwrap(), "x.unknown"]);
    assert!(err.contains("bad.msh"), "{err}");
    let err = fails(&[
        "mesh",
        "arch",
        "--nodes",
        "3",
        "--out",
        dir.path().join("a.vtu").to_str().unwrap(),
    ]);
    assert!(err.contains("--nodes 3"), "{err}");
}

const SCENE: &str = r#"
model = "nvtmm"
duration = 0.02
[mesh]
block = { cells = [4, 1, 1], size = [0.04, 0.01, 0.01] }
[material]
youngs_pa = 65e3
poisson = 0.45
[[prony]]
alpha = 0.5
tau = 0.1
[fixed]
sets = ["x_min"]
[[load]]
set = "x_max"
force_n = [0.0, 0.0, -0.01]
[integrator]
dt = 1e-3
[output]
vtu_every = 10
"#;

#[test]
fn simulate_writes_outputs_and_rejects_bad_scenes() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("bar.toml");
    std::fs::write(&scene, SCENE).unwrap();
    let out = dir.path().join("out");
    let stdout = ok(&[
        "simulate",
        scene.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--quiet",
    ]);
    assert!(stdout.contains("20 steps"), "{stdout}");
    for f in [
        "probes.csv",
        "frames.pvd",
        "frames_000000.vtu",
        "final.png",
        "summary.json",
    ] {
        assert!(Path::new(&out.join(f)).exists(), "{f} missing");
    }
    let csv = std::fs::read_to_string(out.join("probes.csv")).unwrap();
    assert_eq!(csv.lines().count(), 21, "header + one row per step");

    std::fs::write(&scene, SCENE.replace("poisson = 0.45", "poisson = 0.7")).unwrap();
    let err = fails(&[
        "simulate",
        scene.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--quiet",
    ]);
    assert!(
        err.contains("bar.toml") && err.contains("material.poisson") && err.contains("[0, 0.4999]"),
        "{err}"
    );
    std::fs::write(&scene, SCENE.replace("sets = [\"x_min\"]", "sets = [\"nope\"]")).unwrap();
    let err = fails(&[
        "simulate",
        scene.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--quiet",
    ]);
    assert!(err.contains("fixed.sets[0]") && err.contains("x_min"), "{err}");
    std::fs::write(&scene, "model = [").unwrap();
    let err = fails(&["simulate", scene.to_str().unwrap(), "--quiet"]);
    assert!(err.contains("bar.toml"), "{err}");
}

#[test]
fn bench_step_json_has_the_documented_keys() {
    let v: serde_json::Value = serde_json::from_str(&ok(&[
        "bench", "step", "--model", "nvtmm", "--nodes", "300", "--steps", "3", "--json",
    ]))
    .unwrap();
    for key in ["model", "nodes", "tets", "ms_per_step", "steps_per_sec", "cg_iters"] {
        assert!(v.get(key).is_some(), "bench step --json lacks {key}");
    }
    assert_eq!(v["model"], "nvtmm");
    let err = fails(&["bench", "step", "--model", "xyz"]);
    assert!(err.contains("xyz") && err.contains("nvtmm"), "{err}");
}
