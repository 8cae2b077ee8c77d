//! `mesh::vessel::{wall, caps}` and `nvtmm mesh vessel`: a lumen surface
//! (generated here, or the checked-in fixtures written by
//! tools/make_surface_fixtures.py) turned into a tetrahedral wall.

mod common;

use nvtmm::math::Vec3;
use nvtmm::mesh::io::read_mesh;
use nvtmm::mesh::surface::{check_surface, read_and_check, CheckOptions, CheckedSurface, SurfaceMesh};
use nvtmm::mesh::vessel::caps::{open_surface, CapOptions, CutPlane};
use nvtmm::mesh::vessel::wall::{build_wall, Thickness, Wall, WallOptions};
use nvtmm::mesh::vessel::VesselError;
use std::collections::HashSet;
use std::f64::consts::{PI, TAU};
use std::path::Path;
use std::process::Command;

/// An open tube along z from 0 to `len` (m), `around` vertices per ring;
/// with `capped`, each end is closed by a fan around a centre vertex
/// (appended last).
fn tube(r: f64, len: f64, around: usize, rings: usize, capped: bool) -> SurfaceMesh {
    let mut s = common::open_tube(r, len, around, rings);
    let id = |j: usize, k: usize| (j * around + k % around) as u32;
    if capped {
        let c0 = s.vertices.len() as u32;
        s.vertices.push(Vec3::zeros());
        s.vertices.push(Vec3::new(0.0, 0.0, len));
        for k in 0..around {
            s.triangles.push([c0, id(0, k + 1), id(0, k)]);
            s.triangles.push([c0 + 1, id(rings - 1, k), id(rings - 1, k + 1)]);
        }
    }
    s
}

/// A torus section: tube radius `r` around the centreline circle of radius
/// `rb` in the xy plane, from angle 0 to `sweep`.
fn torus_section(rb: f64, r: f64, sweep: f64, around: usize, segments: usize) -> SurfaceMesh {
    let mut s = SurfaceMesh::default();
    for j in 0..=segments {
        let phi = sweep * j as f64 / segments as f64;
        let (radial, up) = (Vec3::new(phi.cos(), phi.sin(), 0.0), Vec3::z());
        for k in 0..around {
            let a = TAU * k as f64 / around as f64;
            s.vertices.push(radial * (rb + r * a.cos()) + up * (r * a.sin()));
        }
    }
    let id = |j: usize, k: usize| (j * around + k % around) as u32;
    for j in 0..segments {
        for k in 0..around {
            s.triangles.push([id(j, k), id(j + 1, k), id(j + 1, k + 1)]);
            s.triangles.push([id(j, k), id(j + 1, k + 1), id(j, k + 1)]);
        }
    }
    s
}

/// A closed UV sphere.
fn sphere(r: f64, around: usize, bands: usize) -> SurfaceMesh {
    let mut s = SurfaceMesh::default();
    s.vertices.push(Vec3::new(0.0, 0.0, -r));
    for j in 1..bands {
        let th = PI * j as f64 / bands as f64 - PI / 2.0;
        for k in 0..around {
            let a = TAU * k as f64 / around as f64;
            s.vertices
                .push(Vec3::new(r * th.cos() * a.cos(), r * th.cos() * a.sin(), r * th.sin()));
        }
    }
    s.vertices.push(Vec3::new(0.0, 0.0, r));
    let top = (s.vertices.len() - 1) as u32;
    let id = |j: usize, k: usize| (1 + (j - 1) * around + k % around) as u32;
    for k in 0..around {
        s.triangles.push([0, id(1, k + 1), id(1, k)]);
        s.triangles.push([top, id(bands - 1, k), id(bands - 1, k + 1)]);
    }
    for j in 1..bands - 1 {
        for k in 0..around {
            s.triangles.push([id(j, k), id(j, k + 1), id(j + 1, k + 1)]);
            s.triangles.push([id(j, k), id(j + 1, k + 1), id(j + 1, k)]);
        }
    }
    s
}

fn checked(s: &SurfaceMesh) -> CheckedSurface {
    check_surface(s, &CheckOptions::default()).unwrap()
}

fn wall(s: &CheckedSurface, thickness: Thickness, layers: usize) -> Wall {
    build_wall(s, &WallOptions { thickness, layers }).unwrap()
}

/// Area of the regular n-gon inscribed in a circle of radius r.
fn ngon(n: usize, r: f64) -> f64 {
    0.5 * n as f64 * r * r * (TAU / n as f64).sin()
}

fn bits(p: &Vec3) -> [u64; 3] {
    [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()]
}

/// Every `inner_wall` node is bit for bit an input vertex, and every input
/// vertex is one.
fn assert_inner_nodes_are_the_input(w: &Wall, input: &SurfaceMesh) {
    let input_bits: HashSet<[u64; 3]> = input.vertices.iter().map(bits).collect();
    let inner = w.mesh.node_set("inner_wall").unwrap();
    assert_eq!(inner.len(), input_bits.len());
    for &i in inner {
        assert!(
            input_bits.contains(&bits(&w.mesh.rest()[i as usize])),
            "inner node {i} is not an input vertex"
        );
    }
}

#[test]
fn straight_tube_wall_has_the_analytic_volume_and_openings() {
    let (r, len, t, n) = (0.005, 0.04, 0.001, 64);
    let s = tube(r, len, n, 21, false);
    let c = checked(&s);
    let w = wall(&c, Thickness::Absolute(t), 1);
    let analytic = PI * ((r + t).powi(2) - r * r) * len;
    // The polygonal cross-section (both rings inscribed) is short of the
    // annulus by 1 − sin(2π/N)/(2π/N) ≈ (2π/N)²/6 = 0.16 % at N = 64.
    let discrete = (ngon(n, r + t) - ngon(n, r)) * len;
    let v = w.mesh.total_volume();
    eprintln!(
        "tube: wall volume {v:.6e} m^3, analytic {analytic:.6e} ({:+.4} %), inscribed polygons {discrete:.6e} ({:+.2e} relative)",
        100.0 * (v / analytic - 1.0),
        v / discrete - 1.0
    );
    assert!((v / analytic - 1.0).abs() < 0.01);
    assert!((v / discrete - 1.0).abs() < 1e-3);
    assert_eq!(w.mesh.report().inverted, 0);
    assert!(w.quality.min_dihedral_deg > 0.0);
    assert_inner_nodes_are_the_input(&w, &s);
    // Inner node i is surface vertex i; the outer nodes sit at R + t.
    let nv = s.vertices.len();
    for &o in w.mesh.node_set("outer_wall").unwrap() {
        let p = w.mesh.rest()[o as usize];
        let rho = (p.x * p.x + p.y * p.y).sqrt();
        assert!((rho - (r + t)).abs() < 1e-3 * t, "outer node {o} at radius {rho}");
        assert!(o as usize >= nv);
    }
    // Two openings, same area: the one listed first is the first ring.
    assert_eq!(w.openings.len(), 2);
    let mut ends: Vec<_> = w.openings.iter().collect();
    ends.sort_by(|a, b| a.centre.z.total_cmp(&b.centre.z));
    for (o, z) in ends.iter().zip([0.0, len]) {
        assert!((o.centre - Vec3::new(0.0, 0.0, z)).norm() < 1e-12, "{:?}", o.centre);
        let outward = if z == 0.0 { -1.0 } else { 1.0 };
        assert!((o.normal - Vec3::z() * outward).norm() < 1e-12, "{:?}", o.normal);
        assert!((o.area / ngon(n, r) - 1.0).abs() < 1e-12);
        assert_eq!(o.nodes, 2 * n);
        let set = w.mesh.node_set(&o.name).unwrap();
        // The end face is planar: the outer copies stay in the opening's plane.
        for &i in set {
            assert!((w.mesh.rest()[i as usize].z - z).abs() < 1e-15);
        }
    }
    assert_eq!(w.openings[0].name, "opening_0");
    assert_eq!(w.openings[1].name, "opening_1");
}

#[test]
fn two_layers_double_the_tets_and_keep_the_volume() {
    let s = tube(0.005, 0.04, 32, 9, false);
    let c = checked(&s);
    let one = wall(&c, Thickness::Absolute(0.001), 1);
    let two = wall(&c, Thickness::Absolute(0.001), 2);
    assert_eq!(two.mesh.tets().len(), 2 * one.mesh.tets().len());
    assert_eq!(one.mesh.tets().len(), 3 * c.mesh.triangles.len());
    assert_eq!(two.mesh.num_nodes(), 3 * s.vertices.len());
    assert!((two.mesh.total_volume() / one.mesh.total_volume() - 1.0).abs() < 1e-12);
    assert_eq!(two.mesh.report().inverted, 0);
    // An opening set: the ring and its copies in both layers.
    assert_eq!(two.mesh.node_set("opening_0").unwrap().len(), 3 * 32);
    assert_inner_nodes_are_the_input(&two, &s);
}

#[test]
fn torus_section_wall_has_the_pappus_volume() {
    let (rb, r, t, sweep) = (0.03, 0.005, 0.001, PI / 2.0);
    let s = torus_section(rb, r, sweep, 48, 48);
    let c = checked(&s);
    let w = wall(&c, Thickness::Absolute(t), 1);
    // Pappus: the annulus's centroid is on the centreline, so the volume is
    // its area times the centreline length rb·sweep, with no correction for
    // the bend. The discretization is short by ≈ (2π/48)²/6 = 0.29 % across
    // and ≈ (sweep/48)²/6 = 0.02 % along.
    let analytic = PI * ((r + t).powi(2) - r * r) * rb * sweep;
    let v = w.mesh.total_volume();
    eprintln!(
        "torus section: wall volume {v:.6e} m^3, analytic {analytic:.6e} ({:+.4} %)",
        100.0 * (v / analytic - 1.0)
    );
    assert!((v / analytic - 1.0).abs() < 0.01);
    assert_eq!(w.mesh.report().inverted, 0);
    assert_inner_nodes_are_the_input(&w, &s);
    assert_eq!(w.openings.len(), 2);
    // Openings at angle 0 (normal −y) and at 90° (normal −x... +x rotated: the
    // tangent at 90° is −x).
    let ends = [
        (Vec3::new(rb, 0.0, 0.0), -Vec3::y()),
        (Vec3::new(0.0, rb, 0.0), -Vec3::x()),
    ];
    for (centre, normal) in ends {
        let o = w
            .openings
            .iter()
            .find(|o| (o.centre - centre).norm() < 1e-9)
            .unwrap_or_else(|| panic!("no opening at {centre:?}: {:?}", w.openings));
        assert!((o.normal - normal).norm() < 1e-9, "{:?}", o.normal);
        assert!((o.area / ngon(48, r) - 1.0).abs() < 1e-9);
    }
}

#[test]
fn capped_tube_gives_the_openings_and_mesh_of_the_open_one() {
    let open = checked(&tube(0.005, 0.04, 32, 9, false));
    let capped = checked(&tube(0.005, 0.04, 32, 9, true));
    assert!(capped.report.boundary_loops.is_empty());
    let opened = open_surface(&capped, &[], &CapOptions::default()).unwrap();
    assert_eq!(opened.caps.len(), 2);
    let a = wall(&open, Thickness::Absolute(0.001), 1);
    let b = wall(&opened.surface, Thickness::Absolute(0.001), 1);
    assert_eq!(a.openings.len(), b.openings.len());
    for (x, y) in a.openings.iter().zip(&b.openings) {
        assert_eq!(x.name, y.name);
        assert!((x.centre - y.centre).norm() < 1e-15);
        assert!((x.normal - y.normal).norm() < 1e-15);
        assert!((x.area - y.area).abs() < 1e-18);
        assert_eq!(x.nodes, y.nodes);
    }
    assert_eq!(a.mesh.rest(), b.mesh.rest());
    assert_eq!(a.mesh.tets(), b.mesh.tets());
    assert_eq!(a.mesh.node_sets(), b.mesh.node_sets());
    // An open surface passes through untouched.
    let same = open_surface(&open, &[], &CapOptions::default()).unwrap();
    assert!(same.caps.is_empty());
    assert_eq!(same.surface.mesh, open.mesh);
}

#[test]
fn a_cut_makes_a_planar_opening() {
    let c = checked(&tube(0.005, 0.04, 32, 9, false));
    let plane = CutPlane {
        point: Vec3::new(0.0, 0.0, 0.0313),
        normal: Vec3::new(0.0, 0.0, 2.0),
    };
    let opened = open_surface(&c, &[plane], &CapOptions::default()).unwrap();
    let w = wall(&opened.surface, Thickness::Absolute(0.001), 1);
    let top = w.openings.iter().find(|o| o.normal.z > 0.5).unwrap();
    assert!((top.centre - Vec3::new(0.0, 0.0, 0.0313)).norm() < 1e-12);
    assert!((top.area / ngon(32, 0.005) - 1.0).abs() < 1e-9);
    for &i in w.mesh.node_set(&top.name).unwrap() {
        assert!((w.mesh.rest()[i as usize].z - 0.0313).abs() < 1e-15);
    }
    let analytic = (ngon(32, 0.006) - ngon(32, 0.005)) * 0.0313;
    assert!((w.mesh.total_volume() / analytic - 1.0).abs() < 1e-3);
}

#[test]
fn millimetre_input_with_scale_gives_the_metre_mesh() {
    let dir = tempfile::tempdir().unwrap();
    let mm = tube(5.0, 40.0, 24, 7, false);
    let write = |name: &str, s: &SurfaceMesh, f: f64| {
        let mut text = String::new();
        for p in &s.vertices {
            text += &format!("v {:e} {:e} {:e}\n", p.x * f, p.y * f, p.z * f);
        }
        for t in &s.triangles {
            text += &format!("f {} {} {}\n", t[0] + 1, t[1] + 1, t[2] + 1);
        }
        let path = dir.path().join(name);
        std::fs::write(&path, text).unwrap();
        path
    };
    let in_mm = write("tube_mm.obj", &mm, 1.0);
    let in_m = write("tube_m.obj", &mm, 1e-3);
    let opts = WallOptions {
        thickness: Thickness::Absolute(0.001),
        layers: 2,
    };
    let a = build_wall(&read_and_check(&in_mm, 1e-3, &CheckOptions::default()).unwrap(), &opts).unwrap();
    let b = build_wall(&read_and_check(&in_m, 1.0, &CheckOptions::default()).unwrap(), &opts).unwrap();
    assert_eq!(a.mesh.tets(), b.mesh.tets());
    assert_eq!(a.mesh.node_sets(), b.mesh.node_sets());
    for (p, q) in a.mesh.rest().iter().zip(b.mesh.rest()) {
        assert!((p - q).norm() < 1e-15, "{p:?} vs {q:?}");
    }
    // Without the scale, the millimetre file is refused as the wrong unit.
    let e = read_and_check(&in_mm, 1.0, &CheckOptions::default()).unwrap_err();
    assert!(e.to_string().contains("scale 0.001"), "{e}");
}

#[test]
fn fixtures_in_every_format_give_the_same_wall() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/surface");
    let mut reference: Option<Wall> = None;
    for name in [
        "tube_ascii.stl",
        "tube_binary.stl",
        "tube_quads.obj",
        "tube_ascii.ply",
        "tube_binary_le.ply",
        "tube_ascii.vtk",
        "tube_ascii.vtp",
        "tube_appended_zlib.vtp",
    ] {
        let c = read_and_check(&dir.join(name), 1e-3, &CheckOptions::default()).unwrap();
        let w = wall(&c, Thickness::Absolute(0.0015), 1);
        // The fixture: radius 5 mm, 40 mm long, 16 around, 5 rings.
        assert_eq!(w.mesh.num_nodes(), 2 * 80, "{name}");
        assert_eq!(w.mesh.tets().len(), 3 * 128, "{name}");
        assert_eq!(w.mesh.report().inverted, 0, "{name}");
        let v = (ngon(16, 0.0065) - ngon(16, 0.005)) * 0.04;
        assert!(
            (w.mesh.total_volume() / v - 1.0).abs() < 1e-3,
            "{name}: {}",
            w.mesh.total_volume()
        );
        if let Some(r) = &reference {
            for (x, y) in r.openings.iter().zip(&w.openings) {
                assert!((x.centre - y.centre).norm() < 1e-9, "{name}");
                assert!((x.area - y.area).abs() < 1e-12, "{name}");
            }
            assert!(
                (r.mesh.total_volume() / w.mesh.total_volume() - 1.0).abs() < 1e-6,
                "{name}"
            );
        } else {
            reference = Some(w);
        }
    }
}

#[test]
fn ratio_thickness_follows_the_lumen_radius() {
    for r in [0.004, 0.008] {
        let s = tube(r, 0.05, 48, 11, false);
        let c = checked(&s);
        let w = wall(&c, Thickness::Ratio(0.2), 1);
        let (lo, hi) = w.thickness_range;
        eprintln!("ratio 0.2, R = {r}: thickness {lo:.6e} .. {hi:.6e} m");
        assert!((lo / (0.2 * r) - 1.0).abs() < 0.01 && (hi / (0.2 * r) - 1.0).abs() < 0.01);
        for &o in w.mesh.node_set("outer_wall").unwrap() {
            let p = w.mesh.rest()[o as usize];
            let rho = (p.x * p.x + p.y * p.y).sqrt();
            assert!((rho / (1.2 * r) - 1.0).abs() < 0.01, "outer node {o} at {rho}");
        }
    }
}

#[test]
fn a_closed_surface_without_caps_is_refused() {
    let c = checked(&sphere(0.01, 24, 12));
    let e = open_surface(&c, &[], &CapOptions::default()).unwrap_err();
    assert!(matches!(e, VesselError::NoOpening { .. }), "{e:?}");
    let msg = e.to_string();
    assert!(msg.contains("no opening") && msg.contains("--cut"), "{msg}");
    let e = build_wall(&c, &WallOptions::default()).unwrap_err();
    assert!(matches!(e, VesselError::NoOpening { .. }));
    // A cut opens it.
    let plane = CutPlane {
        point: Vec3::new(0.0, 0.0, 0.005),
        normal: Vec3::z(),
    };
    let opened = open_surface(&c, &[plane], &CapOptions::default()).unwrap();
    assert_eq!(opened.surface.report.boundary_loops.len(), 1);
    build_wall(&opened.surface, &WallOptions::default()).unwrap();
}

#[test]
fn a_thickness_beyond_the_bend_radius_is_refused() {
    // The inner side of a bend of radius 15 mm with a 5 mm lumen curves
    // concavely (seen from outside) with a radius of 10 mm.
    let c = checked(&torus_section(0.015, 0.005, PI / 2.0, 32, 32));
    wall(&c, Thickness::Absolute(0.004), 1);
    let e = build_wall(
        &c,
        &WallOptions {
            thickness: Thickness::Absolute(0.015),
            layers: 1,
        },
    )
    .unwrap_err();
    let msg = e.to_string();
    assert!(
        msg.contains("wall thickness too large") && msg.contains("triangle"),
        "{msg}"
    );
    let VesselError::Inverted {
        position,
        curvature_radius,
        ..
    } = e
    else {
        panic!("{e:?}")
    };
    // The named vertex is on the inner side of the bend.
    assert!(position.xy().norm() < 0.015, "{position:?}");
    assert!(
        curvature_radius > 0.005 && curvature_radius < 0.02,
        "{curvature_radius}"
    );
    // Bad options.
    for (t, l) in [
        (Thickness::Absolute(0.0), 1),
        (Thickness::Absolute(f64::NAN), 1),
        (Thickness::Ratio(-1.0), 1),
    ] {
        let e = build_wall(
            &c,
            &WallOptions {
                thickness: t,
                layers: l,
            },
        )
        .unwrap_err();
        assert!(e.to_string().contains("thickness"), "{e}");
    }
    let e = build_wall(
        &c,
        &WallOptions {
            thickness: Thickness::Absolute(0.001),
            layers: 0,
        },
    )
    .unwrap_err();
    assert!(e.to_string().contains("layers"), "{e}");
}

#[test]
fn cli_meshes_a_fixture_and_prints_the_openings() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("wall.msh");
    let fixture = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/surface/tube_binary.stl");
    let o = Command::new(env!("CARGO_BIN_EXE_nvtmm"))
        .args(["mesh", "vessel"])
        .arg(&fixture)
        .arg("--out")
        .arg(&out)
        .args(["--scale", "0.001", "--wall-thickness", "0.001", "--layers", "2"])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{stdout}\n{}", String::from_utf8_lossy(&o.stderr));
    assert!(stdout.contains("240 nodes, 768 tets"), "{stdout}");
    assert!(stdout.contains("opening_0") && stdout.contains("opening_1"), "{stdout}");
    assert!(stdout.contains("centre (0.000, 0.000, 40.000) mm"), "{stdout}");
    assert!(stdout.contains("centre (0.000, 0.000, 0.000) mm"), "{stdout}");
    assert!(stdout.contains(&format!("area {:.3} mm^2", ngon(16, 5.0))), "{stdout}");
    assert!(stdout.contains("dihedral angles"), "{stdout}");
    let m = read_mesh(&out).unwrap();
    assert_eq!(m.num_nodes(), 240);
    assert_eq!(m.tets().len(), 768);
    assert_eq!(m.node_set("opening_0").unwrap().len(), 48);
    assert_eq!(m.node_set("inner_wall").unwrap().len(), 80);
    assert_eq!(m.node_set("outer_wall").unwrap().len(), 80);

    // A closed surface: an error naming the problem, and nothing written.
    let sphere_path = dir.path().join("sphere.obj");
    let s = sphere(10.0, 16, 8);
    let mut text = String::new();
    for p in &s.vertices {
        text += &format!("v {} {} {}\n", p.x, p.y, p.z);
    }
    for t in &s.triangles {
        text += &format!("f {} {} {}\n", t[0] + 1, t[1] + 1, t[2] + 1);
    }
    std::fs::write(&sphere_path, text).unwrap();
    let bad_out = dir.path().join("sphere_wall.vtu");
    let o = Command::new(env!("CARGO_BIN_EXE_nvtmm"))
        .args(["mesh", "vessel"])
        .arg(&sphere_path)
        .arg("--out")
        .arg(&bad_out)
        .args(["--scale", "0.001"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        stderr.contains("sphere.obj") && stderr.contains("no opening"),
        "{stderr}"
    );
    assert!(!bad_out.exists());

    // The same sphere cut open by a plane 5 mm above its centre.
    let o = Command::new(env!("CARGO_BIN_EXE_nvtmm"))
        .args(["mesh", "vessel"])
        .arg(&sphere_path)
        .arg("--out")
        .arg(&bad_out)
        .args(["--scale", "0.001", "--cut", "0,0,5,0,0,1"])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{stdout}\n{}", String::from_utf8_lossy(&o.stderr));
    assert!(stdout.contains("centre (0.000, 0.000, 5.000) mm"), "{stdout}");
    assert!(bad_out.exists());
}

/// A bend (as [`torus_section`]) closed at both ends by flat fans around the
/// end centres: what a segmentation tool's capped export looks like.
fn capped_bend(rb: f64, r: f64, sweep: f64, around: usize, segments: usize) -> SurfaceMesh {
    let mut s = torus_section(rb, r, sweep, around, segments);
    let id = |j: usize, k: usize| (j * around + k % around) as u32;
    let c0 = s.vertices.len() as u32;
    s.vertices.push(Vec3::new(rb, 0.0, 0.0));
    s.vertices.push(Vec3::new(rb * sweep.cos(), rb * sweep.sin(), 0.0));
    for k in 0..around {
        s.triangles.push([c0, id(0, k), id(0, k + 1)]);
        s.triangles.push([c0 + 1, id(segments, k + 1), id(segments, k)]);
    }
    s
}

#[test]
fn a_closed_surface_opened_by_its_caps_says_so_when_the_wall_fails() {
    use nvtmm::mesh::vessel::pipeline::{mesh_vessel, VesselOptions};
    // Closed, its two flat ends found as caps and removed; then a wall
    // thicker than the bend's inner radius fails. The error keeps its cause
    // and adds where the openings came from and the way out (--cut).
    let c = checked(&capped_bend(0.015, 0.005, PI / 2.0, 32, 32));
    assert!(c.report.boundary_loops.is_empty(), "the test surface must be closed");
    let opts = |t: f64| VesselOptions {
        wall: WallOptions {
            thickness: Thickness::Absolute(t),
            layers: 1,
        },
        ..VesselOptions::default()
    };
    let ok = mesh_vessel(&c, &opts(0.002)).expect("a thin wall on the opened bend");
    assert_eq!(ok.caps.len(), 2, "both flat ends are found as caps");
    let e = mesh_vessel(&c, &opts(0.015)).unwrap_err();
    let msg = e.to_string();
    println!("{msg}");
    assert!(matches!(e, VesselError::OpenedByCaps { caps: 2, .. }), "{e:?}");
    for want in [
        "wall thickness too large",
        "was closed",
        "2 planar cap(s)",
        "--cut px,py,pz,nx,ny,nz",
    ] {
        assert!(msg.contains(want), "'{want}' not in: {msg}");
    }
}

#[test]
fn mesh_info_on_a_surface_points_to_mesh_vessel() {
    let dir = tempfile::tempdir().unwrap();
    let info = |name: &str, s: &SurfaceMesh| {
        let path = dir.path().join(name);
        let mut text = String::new();
        for p in &s.vertices {
            text += &format!("v {} {} {}\n", p.x, p.y, p.z);
        }
        for t in &s.triangles {
            text += &format!("f {} {} {}\n", t[0] + 1, t[1] + 1, t[2] + 1);
        }
        std::fs::write(&path, text).unwrap();
        let o = Command::new(env!("CARGO_BIN_EXE_nvtmm"))
            .args(["mesh", "info"])
            .arg(&path)
            .output()
            .unwrap();
        let out = String::from_utf8_lossy(&o.stdout).into_owned();
        println!("{name}: {out}{}", String::from_utf8_lossy(&o.stderr));
        assert!(o.status.success(), "{name}");
        out
    };
    // A closed sphere: no opening; the way out is named.
    let out = info("ball.obj", &sphere(0.01, 24, 12));
    for want in [
        "a surface, not a volume",
        "openings           0",
        "closed",
        "nvtmm mesh vessel",
        "--cut",
    ] {
        assert!(out.contains(want), "'{want}' not in: {out}");
    }
    // An open tube: two openings, and the command that makes its wall.
    let out = info("tube.obj", &tube(0.005, 0.04, 16, 5, false));
    assert!(
        out.contains("openings           2") && out.contains("nvtmm mesh vessel"),
        "{out}"
    );
    assert!(!out.contains("--cut"), "{out}");
}
