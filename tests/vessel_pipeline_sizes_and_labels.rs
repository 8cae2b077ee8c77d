//! `mesh::vessel::pipeline` (`nvtmm mesh vessel --nodes / --edge-length`):
//! the lumen remeshed to a node count or an edge length before the wall is
//! grown, and segment labels from the openings' tree on any surface (a
//! Y-bifurcation splits at its junction).

mod common;

use common::open_tube as tube;
use nvtmm::math::Vec3;
use nvtmm::mesh::io::read_mesh;
use nvtmm::mesh::surface::{check_surface, CheckOptions};
use nvtmm::mesh::vessel::implicit::{lumen_surface, LumenTree, Segment};
use nvtmm::mesh::vessel::pipeline::{mesh_vessel, SurfaceSize, VesselOptions};
use nvtmm::mesh::vessel::wall::{Thickness, WallOptions};
use nvtmm::mesh::vessel::VesselError;
use std::f64::consts::TAU;
use std::path::Path;
use std::process::Command;

fn opts(size: SurfaceSize, layers: usize) -> VesselOptions {
    VesselOptions {
        wall: WallOptions {
            thickness: Thickness::Absolute(1e-3),
            layers,
        },
        size,
        ..VesselOptions::default()
    }
}

#[test]
fn node_count_is_met_within_two_percent() {
    let s = check_surface(&tube(0.006, 0.08, 64, 97), &CheckOptions::default()).unwrap();
    for (nodes, layers) in [(2400, 1), (6000, 2)] {
        let v = mesh_vessel(&s, &opts(SurfaceSize::Nodes(nodes), layers)).unwrap();
        let n = v.wall.mesh.num_nodes();
        println!("{nodes} nodes, {layers} layer(s): {n}, {:?}", v.remesh);
        assert!((n as f64 / nodes as f64 - 1.0).abs() <= 0.02, "{n} for {nodes}");
        assert_eq!(v.wall.mesh.report().inverted, 0);
        assert!(v.wall.quality.min_dihedral_deg >= 10.0, "{:?}", v.wall.quality);
        assert_eq!(v.wall.openings.len(), 2);
        // The inner nodes lie on the input tube (radius 6 mm; the remesher
        // projects onto its 64-gon, within its sagitta).
        let sagitta = 0.006 * (1.0 - (TAU / 128.0).cos());
        for &i in v.wall.mesh.node_set("inner_wall").unwrap() {
            let p = v.wall.mesh.rest()[i as usize];
            let rho = (p.x * p.x + p.y * p.y).sqrt();
            assert!(rho <= 0.006 + 1e-12 && rho >= 0.006 - sagitta - 1e-12, "{rho}");
        }
    }
}

#[test]
fn edge_length_sets_the_size_and_thin_vessels_keep_eight_around() {
    let s = check_surface(&tube(0.006, 0.08, 96, 121), &CheckOptions::default()).unwrap();
    let v = mesh_vessel(&s, &opts(SurfaceSize::EdgeLength(2e-3), 1)).unwrap();
    let (stats, size) = v.remesh.unwrap();
    assert_eq!(size, 2e-3);
    println!("{stats:?}");
    assert!((stats.edge_mean - 1.0).abs() < 0.1, "{stats:?}");
    // 20 mm asked on a 6 mm tube: the cap keeps at least 8 around.
    let v = mesh_vessel(&s, &opts(SurfaceSize::EdgeLength(20e-3), 1)).unwrap();
    for o in &v.wall.openings {
        // The opening set holds the ring in both layers.
        assert!(o.nodes / 2 >= 8, "{}: {} nodes", o.name, o.nodes);
    }
    assert_eq!(v.wall.mesh.report().inverted, 0);
}

#[test]
fn too_few_nodes_for_the_thinnest_vessel_is_refused() {
    let s = check_surface(&tube(0.006, 0.08, 96, 121), &CheckOptions::default()).unwrap();
    let e = mesh_vessel(&s, &opts(SurfaceSize::Nodes(60), 1)).unwrap_err();
    assert!(matches!(e, VesselError::TooCoarse { .. }), "{e}");
    let msg = e.to_string();
    assert!(
        msg.contains("60 nodes are too few") && msg.contains("8 nodes around") && msg.contains("6.000 mm"),
        "{msg}"
    );
}

/// A Y: a trunk along z (radius 5 mm, 40 mm) forking at 35° either side
/// into two branches of 3.5 mm radius, 35 mm long, blended over 3 mm.
fn y_tree() -> LumenTree {
    let mm = 1e-3;
    let fork = Vec3::new(0.0, 0.0, 40.0) * mm;
    let a = 35f64.to_radians();
    let arm = |side: f64| -> Vec<Vec3> {
        (0..=10)
            .map(|i| fork + Vec3::new(side * a.sin(), 0.0, a.cos()) * (35.0 * mm * i as f64 / 10.0))
            .collect()
    };
    let mut trunk: Vec<Vec3> = (0..10).map(|i| Vec3::new(0.0, 0.0, 4.0 * i as f64) * mm).collect();
    trunk.extend(arm(-1.0));
    let n = trunk.len();
    let radii: Vec<f64> = (0..n).map(|i| if i < 10 { 5.0 * mm } else { 3.5 * mm }).collect();
    LumenTree {
        segments: vec![
            Segment {
                name: "trunk_left".into(),
                points: trunk,
                radii,
                parent: None,
                proper_from: 0.0,
                open_start: true,
            },
            Segment {
                name: "right".into(),
                points: arm(1.0),
                radii: vec![3.5 * mm; 11],
                parent: Some(0),
                proper_from: 10.0 * mm,
                open_start: false,
            },
        ],
        blend: 3.0 * mm,
    }
}

#[test]
fn y_bifurcation_has_three_openings_and_labels_split_at_the_junction() {
    let tree = y_tree();
    let lumen = lumen_surface(&tree, 1.5e-3).unwrap();
    // Through a file, as a user's surface would come.
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("y.stl");
    let mut text = String::from("solid y\n");
    for t in &lumen.mesh.triangles {
        text += "facet normal 0 0 0\nouter loop\n";
        for &v in t {
            let p = lumen.mesh.vertices[v as usize] * 1e3;
            text += &format!("vertex {:.9} {:.9} {:.9}\n", p.x, p.y, p.z);
        }
        text += "endloop\nendfacet\n";
    }
    text += "endsolid y\n";
    std::fs::write(&path, text).unwrap();
    let s = nvtmm::mesh::surface::read_and_check(&path, 1e-3, &CheckOptions::default()).unwrap();
    let v = mesh_vessel(&s, &opts(SurfaceSize::Nodes(4000), 1)).unwrap();
    let m = &v.wall.mesh;
    println!(
        "Y: {} nodes, min dihedral {:.2}°, segments {:?}",
        m.num_nodes(),
        v.wall.quality.min_dihedral_deg,
        v.segments
    );
    assert!((m.num_nodes() as f64 / 4000.0 - 1.0).abs() <= 0.02);
    assert_eq!(m.report().inverted, 0);
    assert!(v.wall.quality.min_dihedral_deg >= 10.0, "{:?}", v.wall.quality);
    assert_eq!(v.wall.openings.len(), 3);
    for k in 0..3 {
        assert!(m.node_set(&format!("opening_{k}")).is_some());
    }
    // The trunk's opening is the largest (opening_0), at z = 0.
    assert!(v.wall.openings[0].centre.z.abs() < 1e-9);
    let (names, label) = m.segment_labels().unwrap();
    assert_eq!(names.len(), 3, "{names:?}");
    for want in ["root", "opening_1", "opening_2"] {
        assert!(names.iter().any(|n| n == want), "{names:?}");
    }
    // Each branch segment lies on its opening's side, the root below the
    // fork; they meet near the fork (z = 40 mm).
    let seg = |name: &str| names.iter().position(|n| n == name).unwrap();
    let label = &label;
    let nodes_of = |s: usize| -> Vec<Vec3> {
        (0..m.num_nodes())
            .filter(|&i| label[i] as usize == s)
            .map(|i| m.rest()[i])
            .collect()
    };
    let root_top = nodes_of(seg("root")).iter().map(|p| p.z).fold(f64::MIN, f64::max);
    println!("root segment up to z = {:.1} mm", root_top * 1e3);
    assert!(root_top < 0.050 && root_top > 0.035, "{root_top}");
    for k in [1, 2] {
        let side = v.wall.openings[k].centre.x.signum();
        let s = seg(&format!("opening_{k}"));
        let lowest = nodes_of(s).iter().map(|p| p.z).fold(f64::MAX, f64::min);
        assert!(lowest > 0.035, "opening_{k} segment down to z = {lowest}");
        assert!(
            nodes_of(s).iter().all(|p| p.x * side > -1e-3),
            "opening_{k} crosses the midline"
        );
        // Its opening's nodes carry its label.
        assert!(m
            .node_set(&format!("opening_{k}"))
            .unwrap()
            .iter()
            .all(|&i| label[i as usize] as usize == s));
    }
}

#[test]
fn cli_remeshes_to_a_node_count() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("wall.vtu");
    let fixture = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/surface/tube_binary.stl");
    let o = Command::new(env!("CARGO_BIN_EXE_nvtmm"))
        .args(["mesh", "vessel"])
        .arg(&fixture)
        .arg("--out")
        .arg(&out)
        .args(["--scale", "0.001", "--nodes", "2000"])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{stdout}\n{}", String::from_utf8_lossy(&o.stderr));
    assert!(stdout.contains("remeshed lumen"), "{stdout}");
    let m = read_mesh(&out).unwrap();
    assert!((m.num_nodes() as f64 / 2000.0 - 1.0).abs() <= 0.02, "{}", m.num_nodes());
    // Too few nodes: the error, and nothing written.
    let bad = dir.path().join("bad.vtu");
    let o = Command::new(env!("CARGO_BIN_EXE_nvtmm"))
        .args(["mesh", "vessel"])
        .arg(&fixture)
        .arg("--out")
        .arg(&bad)
        .args(["--scale", "0.001", "--nodes", "40"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        stderr.contains("too few") && stderr.contains("tube_binary.stl"),
        "{stderr}"
    );
    assert!(!bad.exists());
}
