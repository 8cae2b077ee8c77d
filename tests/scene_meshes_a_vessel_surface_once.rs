//! `[mesh] vessel = { surface = "…", … }` in a scene: the wall is meshed at
//! load through the vessel pipeline and cached on disk under a key of the
//! surface's bytes and the options; a second load is a cache hit, a changed
//! key meshes again, and bad values are refused naming their key.

use nvtmm::scene::Scene;
use std::f64::consts::TAU;
use std::path::Path;

/// An open tube in millimetres (r 5, 40 long) as OBJ text.
fn tube_obj(around: usize, rings: usize) -> String {
    let mut t = String::new();
    for j in 0..rings {
        for k in 0..around {
            let a = TAU * k as f64 / around as f64;
            t += &format!(
                "v {} {} {}\n",
                5.0 * a.cos(),
                5.0 * a.sin(),
                40.0 * j as f64 / (rings - 1) as f64
            );
        }
    }
    let id = |j: usize, k: usize| j * around + k % around + 1;
    for j in 0..rings - 1 {
        for k in 0..around {
            t += &format!("f {} {} {}\n", id(j, k), id(j, k + 1), id(j + 1, k + 1));
            t += &format!("f {} {} {}\n", id(j, k), id(j + 1, k + 1), id(j + 1, k));
        }
    }
    t
}

fn scene(dir: &Path, vessel: &str) -> std::path::PathBuf {
    let text = format!(
        r#"
model = "nvtmm"
duration = 0.01
[mesh]
vessel = {vessel}
[material]
youngs_pa = 1e5
poisson = 0.4
[fixed]
sets = ["opening_0"]
[reduced]
r = 4
cache_dir = "cache"
"#
    );
    let p = dir.join("scene.toml");
    std::fs::write(&p, text).unwrap();
    p
}

#[test]
fn vessel_scene_meshes_once_and_then_hits_the_cache() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("lumen.obj"), tube_obj(24, 9)).unwrap();
    let v = r#"{ surface = "lumen.obj", scale = 0.001, wall_thickness = 0.001, layers = 1, nodes = 1200 }"#;
    let s = Scene::load(&scene(dir.path(), v)).unwrap();
    let first = s.vessel_mesh().unwrap();
    assert!(!first.cache_hit);
    assert!(first.path.starts_with(dir.path().join("cache")), "{:?}", first.path);
    assert!(first.path.exists());
    let n = first.mesh.num_nodes();
    assert!((n as f64 / 1200.0 - 1.0).abs() <= 0.02, "{n}");
    assert!(first.mesh.node_set("opening_0").is_some());
    assert!(first.mesh.segment_labels().is_some());
    assert_eq!(first.mesh.report().inverted, 0);

    // Loaded again: read from the cache, the same mesh.
    let s2 = Scene::load(&scene(dir.path(), v)).unwrap();
    let second = s2.vessel_mesh().unwrap();
    assert!(second.cache_hit);
    assert_eq!(second.path, first.path);
    assert_eq!(second.mesh.num_nodes(), n);
    assert_eq!(second.mesh.tets(), first.mesh.tets());
    assert_eq!(second.mesh.node_sets(), first.mesh.node_sets());
    assert_eq!(s2.build_mesh().unwrap().num_nodes(), n);

    // A changed option is a new key: meshed again.
    let v2 = v.replace("layers = 1", "layers = 2");
    let third = Scene::load(&scene(dir.path(), &v2)).unwrap().vessel_mesh().unwrap();
    assert!(!third.cache_hit);
    assert_ne!(third.path, first.path);
    // So is a changed surface (same options).
    std::fs::write(dir.path().join("lumen.obj"), tube_obj(24, 13)).unwrap();
    let fourth = Scene::load(&scene(dir.path(), v)).unwrap().vessel_mesh().unwrap();
    assert!(!fourth.cache_hit);
    assert_ne!(fourth.path, first.path);

    // A corrupt cache file is meshed again, not a failure.
    std::fs::write(&fourth.path, b"not a mesh").unwrap();
    let fifth = Scene::load(&scene(dir.path(), v)).unwrap().vessel_mesh().unwrap();
    assert!(!fifth.cache_hit);
    assert_eq!(fifth.mesh.num_nodes(), fourth.mesh.num_nodes());
}

#[test]
fn vessel_scene_errors_name_the_key() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("lumen.obj"), tube_obj(24, 9)).unwrap();
    let cases = [
        (r#"{ surface = "missing.obj", scale = 0.001 }"#, "mesh.vessel.surface"),
        (
            r#"{ surface = "lumen.obj", scale = 0.001, nodes = 4 }"#,
            "mesh.vessel.nodes",
        ),
        (
            r#"{ surface = "lumen.obj", scale = 0.001, wall_thickness = 0.001, wall_ratio = 0.2 }"#,
            "mesh.vessel",
        ),
        (
            r#"{ surface = "lumen.obj", scale = 0.001, layers = 0 }"#,
            "mesh.vessel.layers",
        ),
        (
            r#"{ surface = "lumen.obj", scale = 0.001, edge_length = -1.0 }"#,
            "mesh.vessel.edge_length",
        ),
        // Millimetres read as metres: the surface check's message, under the key.
        (r#"{ surface = "lumen.obj" }"#, "mesh.vessel.surface"),
        // Too few nodes for 8 around.
        (r#"{ surface = "lumen.obj", scale = 0.001, nodes = 40 }"#, "too few"),
    ];
    for (v, want) in cases {
        let msg = match Scene::load(&scene(dir.path(), v)) {
            Err(e) => e.to_string(),
            Ok(s) => match s.vessel_mesh() {
                Err(e) => e.to_string(),
                Ok(_) => panic!("{v}: accepted"),
            },
        };
        println!("{v}: {msg}");
        assert!(msg.contains(want), "{v}: '{want}' not in {msg}");
        assert!(msg.contains("scene.toml"), "{msg}");
    }
    // Nothing was cached by the failures.
    let cached = std::fs::read_dir(dir.path().join("cache"))
        .map(|d| d.count())
        .unwrap_or(0);
    assert_eq!(cached, 0);
}
