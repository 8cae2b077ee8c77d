//! `nvtmm mesh vessel` on bad lumen surfaces: each case gives an error that
//! names the problem and where, exits with failure and writes nothing; and
//! the pipeline never panics on perturbed small surfaces (proptest).

mod common;

use common::open_tube as tube;
use nvtmm::math::Vec3;
use nvtmm::mesh::surface::{check_surface, CheckOptions, SurfaceMesh};
use nvtmm::mesh::vessel::pipeline::{mesh_vessel, SurfaceSize, VesselOptions};
use nvtmm::mesh::vessel::wall::{Thickness, WallOptions};
use proptest::prelude::*;
use std::path::Path;
use std::process::Command;

fn write_obj(path: &Path, s: &SurfaceMesh) {
    let mut text = String::new();
    for p in &s.vertices {
        text += &format!("v {} {} {}\n", p.x, p.y, p.z);
    }
    for t in &s.triangles {
        text += &format!("f {} {} {}\n", t[0] + 1, t[1] + 1, t[2] + 1);
    }
    std::fs::write(path, text).unwrap();
}

/// Runs `mesh vessel` on `s` (millimetres unless `args` says otherwise);
/// asserts failure, that nothing was written and that stderr names the
/// file and contains every `want`.
fn refused(name: &str, s: &SurfaceMesh, args: &[&str], want: &[&str]) {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join(format!("{name}.obj"));
    write_obj(&input, s);
    let out = dir.path().join("wall.vtu");
    let o = Command::new(env!("CARGO_BIN_EXE_nvtmm"))
        .args(["mesh", "vessel"])
        .arg(&input)
        .arg("--out")
        .arg(&out)
        .args(args)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    println!("{name}: {stderr}");
    assert!(!o.status.success(), "{name}: accepted");
    assert!(!out.exists(), "{name}: a mesh was written");
    assert!(stderr.contains(&format!("{name}.obj")), "{name}: {stderr}");
    for w in want {
        assert!(stderr.contains(w), "{name}: '{w}' not in {stderr}");
    }
    assert!(!stderr.contains("panicked"), "{stderr}");
}

#[test]
fn a_non_manifold_edge_is_named_by_its_vertices() {
    let mut s = tube(5.0, 40.0, 16, 5);
    // A fin on the ring edge between vertices 32 and 33, mid-tube (a
    // third triangle on it).
    s.vertices.push(Vec3::new(9.0, 3.0, 20.0));
    let f = (s.vertices.len() - 1) as u32;
    s.triangles.push([32, 33, f]);
    refused(
        "fin",
        &s,
        &["--scale", "0.001"],
        &["non-manifold edge 32-33", "3 triangles"],
    );
}

#[test]
fn a_self_intersection_is_named_by_its_triangles() {
    let mut s = tube(5.0, 40.0, 16, 5);
    // A middle-ring vertex pushed through the opposite wall.
    s.vertices[2 * 16] = Vec3::new(-7.0, 0.0, 20.0);
    refused("dent", &s, &["--scale", "0.001"], &["self-intersection: triangles"]);
}

#[test]
fn several_bodies_are_refused_with_their_sizes() {
    let mut s = tube(5.0, 40.0, 16, 5);
    let other = tube(3.0, 20.0, 12, 3);
    let off = s.vertices.len() as u32;
    s.vertices
        .extend(other.vertices.iter().map(|p| p + Vec3::new(30.0, 0.0, 0.0)));
    s.triangles.extend(other.triangles.iter().map(|t| t.map(|v| v + off)));
    refused("two", &s, &["--scale", "0.001"], &["2 disconnected bodies", "128, 48"]);
}

#[test]
fn a_closed_surface_without_caps_is_refused() {
    // A tube closed by cones at both ends: no boundary loop, no flat cap.
    let mut s = tube(5.0, 40.0, 16, 5);
    s.vertices.push(Vec3::new(0.0, 0.0, -6.0));
    s.vertices.push(Vec3::new(0.0, 0.0, 46.0));
    let (a, b) = ((s.vertices.len() - 2) as u32, (s.vertices.len() - 1) as u32);
    for k in 0..16u32 {
        s.triangles.push([a, (k + 1) % 16, k]);
        s.triangles.push([b, 4 * 16 + k, 4 * 16 + (k + 1) % 16]);
    }
    refused(
        "closed",
        &s,
        &["--scale", "0.001"],
        &["no opening", "no planar cap", "--cut"],
    );
}

#[test]
fn millimetres_read_as_metres_is_a_wrong_unit() {
    let s = tube(5.0, 40.0, 16, 5);
    refused("mm", &s, &[], &["wrong unit", "scale 0.001"]);
}

#[test]
fn too_few_nodes_for_the_thinnest_branch_is_refused() {
    let s = tube(5.0, 40.0, 16, 5);
    refused(
        "coarse",
        &s,
        &["--scale", "0.001", "--nodes", "60"],
        &["60 nodes are too few", "8 nodes around", "5.000 mm"],
    );
}

#[test]
fn a_bad_size_option_is_refused() {
    let s = tube(5.0, 40.0, 16, 5);
    refused(
        "size",
        &s,
        &["--scale", "0.001", "--edge-length=-1"],
        &["edge length must be finite and positive"],
    );
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 128, ..ProptestConfig::default() })]

    /// Perturbed, partly broken small tubes: the pipeline returns a mesh
    /// or an error, never panics.
    #[test]
    fn the_pipeline_never_panics_on_perturbed_small_surfaces(
        around in 3usize..10,
        rings in 2usize..5,
        noise in proptest::collection::vec(-1.0f64..1.0, 120),
        amp in 0.0f64..0.8,
        drop in proptest::option::of(0usize..60),
        layers in 1usize..3,
        size in 0usize..4,
        thickness in 0.02f64..0.6,
    ) {
        let mut s = tube(0.005, 0.03, around, rings);
        for (i, p) in s.vertices.iter_mut().enumerate() {
            let k = 3 * i % noise.len();
            *p += Vec3::new(noise[k], noise[(k + 1) % noise.len()], noise[(k + 2) % noise.len()]) * (amp * 0.005);
        }
        if let Some(d) = drop {
            if d < s.triangles.len() {
                s.triangles.remove(d);
            }
        }
        if let Ok(c) = check_surface(&s, &CheckOptions::default()) {
            let opts = VesselOptions {
                wall: WallOptions { thickness: if size % 2 == 0 { Thickness::Absolute(thickness * 0.005) } else { Thickness::Ratio(thickness) }, layers },
                size: match size {
                    0 => SurfaceSize::Input,
                    1 => SurfaceSize::EdgeLength(0.004),
                    2 => SurfaceSize::Nodes(200),
                    _ => SurfaceSize::Nodes(20),
                },
                ..VesselOptions::default()
            };
            let _ = mesh_vessel(&c, &opts);
        }
    }
}
