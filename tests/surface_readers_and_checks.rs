//! The lumen-surface readers and checks (`nvtmm::mesh::surface`): one open
//! tube written in every format (here, and by an independent Python writer:
//! `tools/make_surface_fixtures.py` -> `tests/fixtures/surface/`) reads back
//! the same; every defect gets its message; no input makes a reader panic.

use nvtmm::math::Vec3;
use nvtmm::mesh::surface::{
    check_surface, read_and_check, read_surface, read_surface_bytes, weld_vertices, CheckOptions, SurfaceDefect,
    SurfaceError, SurfaceFormat, SurfaceMesh,
};
use std::f64::consts::PI;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

// The tube of tools/make_surface_fixtures.py (millimetres).
const N_THETA: usize = 16;
const N_RINGS: usize = 5;
const RADIUS: f64 = 5.0;
const LENGTH: f64 = 40.0;

fn idx(j: usize, k: usize) -> u32 {
    (j * N_THETA + k % N_THETA) as u32
}

fn quads() -> Vec<[u32; 4]> {
    let mut q = Vec::new();
    for j in 0..N_RINGS - 1 {
        for k in 0..N_THETA {
            q.push([idx(j, k), idx(j, k + 1), idx(j + 1, k + 1), idx(j + 1, k)]);
        }
    }
    q
}

/// The open tube in millimetres, normals out.
fn tube() -> SurfaceMesh {
    let mut vertices = Vec::new();
    for j in 0..N_RINGS {
        let z = LENGTH * j as f64 / (N_RINGS - 1) as f64;
        for k in 0..N_THETA {
            let a = 2.0 * PI * k as f64 / N_THETA as f64;
            vertices.push(Vec3::new(RADIUS * a.cos(), RADIUS * a.sin(), z));
        }
    }
    let triangles = quads()
        .iter()
        .flat_map(|&[a, b, c, d]| [[a, b, c], [a, c, d]])
        .collect();
    SurfaceMesh { vertices, triangles }
}

fn scaled(m: &SurfaceMesh, s: f64) -> SurfaceMesh {
    SurfaceMesh {
        vertices: m.vertices.iter().map(|p| p * s).collect(),
        triangles: m.triangles.clone(),
    }
}

/// Whether two surfaces have the same oriented triangles (as corner
/// positions, up to rotation of a triangle's corners) within `tol`, in any
/// vertex and triangle order.
fn same_surface(a: &SurfaceMesh, b: &SurfaceMesh, tol: f64) -> Result<(), String> {
    if a.triangles.len() != b.triangles.len() {
        return Err(format!("{} vs {} triangles", a.triangles.len(), b.triangles.len()));
    }
    let corners = |m: &SurfaceMesh, t: usize| m.triangles[t].map(|i| m.vertices[i as usize]);
    let mut used = vec![false; b.triangles.len()];
    for t in 0..a.triangles.len() {
        let p = corners(a, t);
        let hit = (0..b.triangles.len()).find(|&u| {
            !used[u] && {
                let q = corners(b, u);
                (0..3).any(|r| (0..3).all(|k| (p[k] - q[(k + r) % 3]).norm() <= tol))
            }
        });
        match hit {
            Some(u) => used[u] = true,
            None => return Err(format!("triangle {t} {p:?} has no match")),
        }
    }
    Ok(())
}

// ---- writers used only by these tests (the crate writes no surfaces) ----

fn f32s(p: &Vec3) -> [f32; 3] {
    [p.x as f32, p.y as f32, p.z as f32]
}

fn stl_ascii(m: &SurfaceMesh) -> Vec<u8> {
    let mut s = String::from("solid tube\n");
    for t in &m.triangles {
        s.push_str(" facet normal 0 0 0\n  outer loop\n");
        for &i in t {
            let [x, y, z] = f32s(&m.vertices[i as usize]);
            writeln!(s, "   vertex {x} {y} {z}").unwrap();
        }
        s.push_str("  endloop\n endfacet\n");
    }
    s.push_str("endsolid tube\n");
    s.into_bytes()
}

fn stl_binary(m: &SurfaceMesh) -> Vec<u8> {
    let mut b = b"solid but binary".to_vec();
    b.resize(80, b' ');
    b.extend((m.triangles.len() as u32).to_le_bytes());
    for t in &m.triangles {
        b.extend([0u8; 12]);
        for &i in t {
            for c in f32s(&m.vertices[i as usize]) {
                b.extend(c.to_le_bytes());
            }
        }
        b.extend([0u8; 2]);
    }
    b
}

fn obj(m: &SurfaceMesh) -> Vec<u8> {
    let mut s = String::from("# tube\no tube\n");
    for p in &m.vertices {
        writeln!(s, "v {} {} {}", p.x, p.y, p.z).unwrap();
    }
    s.push_str("vt 0 0\nvn 0 0 1\n");
    let n = m.vertices.len() as i64;
    for (k, t) in m.triangles.iter().enumerate() {
        let c: Vec<String> = t
            .iter()
            .map(|&i| match k % 4 {
                0 => format!("{}", i + 1),
                1 => format!("{}/1", i + 1),
                2 => format!("{}/1/1", i + 1),
                _ => format!("{}", i as i64 - n),
            })
            .collect();
        writeln!(s, "f {}", c.join(" ")).unwrap();
    }
    s.into_bytes()
}

fn ply_ascii(m: &SurfaceMesh, f32_coords: bool) -> Vec<u8> {
    let ty = if f32_coords { "float" } else { "double" };
    let mut s = format!(
        "ply\nformat ascii 1.0\nelement vertex {}\nproperty {ty} x\nproperty {ty} y\nproperty {ty} z\n\
         element face {}\nproperty list uchar int vertex_indices\nend_header\n",
        m.vertices.len(),
        m.triangles.len()
    );
    for p in &m.vertices {
        if f32_coords {
            let [x, y, z] = f32s(p);
            writeln!(s, "{x} {y} {z}").unwrap();
        } else {
            writeln!(s, "{} {} {}", p.x, p.y, p.z).unwrap();
        }
    }
    for t in &m.triangles {
        writeln!(s, "3 {} {} {}", t[0], t[1], t[2]).unwrap();
    }
    s.into_bytes()
}

fn ply_binary(m: &SurfaceMesh, big: bool) -> Vec<u8> {
    let fmt = if big {
        "binary_big_endian"
    } else {
        "binary_little_endian"
    };
    let mut b = format!(
        "ply\nformat {fmt} 1.0\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\n\
         element face {}\nproperty list uchar int vertex_indices\nend_header\n",
        m.vertices.len(),
        m.triangles.len()
    )
    .into_bytes();
    for p in &m.vertices {
        for c in f32s(p) {
            b.extend(if big { c.to_be_bytes() } else { c.to_le_bytes() });
        }
    }
    for t in &m.triangles {
        b.push(3);
        for &i in t {
            b.extend(if big {
                (i as i32).to_be_bytes()
            } else {
                (i as i32).to_le_bytes()
            });
        }
    }
    b
}

fn vtk_ascii(m: &SurfaceMesh) -> Vec<u8> {
    let mut s = format!(
        "# vtk DataFile Version 3.0\ntube\nASCII\nDATASET POLYDATA\nPOINTS {} double\n",
        m.vertices.len()
    );
    for p in &m.vertices {
        writeln!(s, "{} {} {}", p.x, p.y, p.z).unwrap();
    }
    writeln!(s, "POLYGONS {} {}", m.triangles.len(), 4 * m.triangles.len()).unwrap();
    for t in &m.triangles {
        writeln!(s, "3 {} {} {}", t[0], t[1], t[2]).unwrap();
    }
    s.into_bytes()
}

fn vtk_binary(m: &SurfaceMesh) -> Vec<u8> {
    let mut b = format!(
        "# vtk DataFile Version 5.1\ntube\nBINARY\nDATASET POLYDATA\nPOINTS {} double\n",
        m.vertices.len()
    )
    .into_bytes();
    for p in &m.vertices {
        for c in [p.x, p.y, p.z] {
            b.extend(c.to_be_bytes());
        }
    }
    let n = m.triangles.len();
    b.extend(format!("\nPOLYGONS {} {}\nOFFSETS vtktypeint64\n", n + 1, 3 * n).bytes());
    for i in 0..=n {
        b.extend((3 * i as i64).to_be_bytes());
    }
    b.extend(b"\nCONNECTIVITY vtktypeint64\n");
    for t in &m.triangles {
        for &i in t {
            b.extend((i as i64).to_be_bytes());
        }
    }
    b.push(b'\n');
    b
}

fn base64(bytes: &[u8]) -> String {
    const A: &[u8] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut s = String::new();
    for c in bytes.chunks(3) {
        let n =
            (u32::from(c[0]) << 16) | (u32::from(*c.get(1).unwrap_or(&0)) << 8) | u32::from(*c.get(2).unwrap_or(&0));
        for k in 0..4 {
            if k <= c.len() {
                s.push(A[(n >> (18 - 6 * k)) as usize & 63] as char);
            } else {
                s.push('=');
            }
        }
    }
    s
}

fn vtp(m: &SurfaceMesh, binary: bool) -> Vec<u8> {
    let arr = |ty: &str, name: &str, ncomp: usize, text: Vec<String>, raw: Vec<u8>| {
        if binary {
            let mut head = base64(&(raw.len() as u32).to_le_bytes());
            head.push_str(&base64(&raw));
            format!("<DataArray type=\"{ty}\" Name=\"{name}\" NumberOfComponents=\"{ncomp}\" format=\"binary\">{head}</DataArray>")
        } else {
            format!(
                "<DataArray type=\"{ty}\" Name=\"{name}\" NumberOfComponents=\"{ncomp}\" format=\"ascii\">{}</DataArray>",
                text.join(" ")
            )
        }
    };
    let pts = arr(
        "Float64",
        "Points",
        3,
        m.vertices.iter().map(|p| format!("{} {} {}", p.x, p.y, p.z)).collect(),
        m.vertices
            .iter()
            .flat_map(|p| [p.x, p.y, p.z])
            .flat_map(f64::to_le_bytes)
            .collect(),
    );
    let conn = arr(
        "Int32",
        "connectivity",
        1,
        m.triangles
            .iter()
            .map(|t| format!("{} {} {}", t[0], t[1], t[2]))
            .collect(),
        m.triangles
            .iter()
            .flatten()
            .flat_map(|&i| (i as i32).to_le_bytes())
            .collect(),
    );
    let offs = arr(
        "Int32",
        "offsets",
        1,
        (1..=m.triangles.len()).map(|i| (3 * i).to_string()).collect(),
        (1..=m.triangles.len())
            .flat_map(|i| (3 * i as i32).to_le_bytes())
            .collect(),
    );
    format!(
        "<?xml version=\"1.0\"?>\n<VTKFile type=\"PolyData\" version=\"0.1\" byte_order=\"LittleEndian\">\n<PolyData>\n\
         <Piece NumberOfPoints=\"{}\" NumberOfPolys=\"{}\">\n<Points>\n{pts}\n</Points>\n<Polys>\n{conn}\n{offs}\n</Polys>\n\
         </Piece>\n</PolyData>\n</VTKFile>\n",
        m.vertices.len(),
        m.triangles.len()
    )
    .into_bytes()
}

/// Every format of the tube (mm): (file name, bytes).
fn all_files(m: &SurfaceMesh) -> Vec<(&'static str, Vec<u8>)> {
    vec![
        ("tube_ascii.stl", stl_ascii(m)),
        ("tube_binary.stl", stl_binary(m)),
        ("tube.obj", obj(m)),
        ("tube_ascii.ply", ply_ascii(m, false)),
        ("tube_ascii_f32.ply", ply_ascii(m, true)),
        ("tube_le.ply", ply_binary(m, false)),
        ("tube_be.ply", ply_binary(m, true)),
        ("tube_ascii.vtk", vtk_ascii(m)),
        ("tube_binary.vtk", vtk_binary(m)),
        ("tube_ascii.vtp", vtp(m, false)),
        ("tube_binary.vtp", vtp(m, true)),
    ]
}

fn parse(name: &str, bytes: &[u8], scale: f64) -> Result<SurfaceMesh, SurfaceError> {
    let path = Path::new(name);
    read_surface_bytes(SurfaceFormat::from_path(path)?, path, bytes, scale)
}

fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/surface")
}

/// f32 storage of millimetre coordinates read in metres: 1e-6 of a 5 mm
/// radius is far above f32 rounding and far below the tube's features.
const TOL: f64 = 1e-9;

#[test]
fn every_format_written_here_reads_the_same_tube() {
    let m = tube();
    let want = scaled(&m, 1e-3);
    let dir = tempfile::tempdir().unwrap();
    for (name, bytes) in all_files(&m) {
        let path = dir.path().join(name);
        std::fs::write(&path, &bytes).unwrap();
        let got = read_surface(&path, 1e-3).unwrap_or_else(|e| panic!("{name}: {e}"));
        same_surface(&got, &want, TOL).unwrap_or_else(|e| panic!("{name}: {e}"));
        // Only STL welds (and renumbers); the others keep the file's vertices.
        if !name.ends_with(".stl") {
            assert_eq!(got.triangles, m.triangles, "{name}");
            assert_eq!(got.vertices.len(), m.vertices.len(), "{name}");
        } else {
            assert_eq!(got.vertices.len(), m.vertices.len(), "{name}: STL corners welded");
        }
    }
    // Extensions are case-insensitive.
    let upper = dir.path().join("TUBE.STL");
    std::fs::write(&upper, stl_binary(&m)).unwrap();
    assert_eq!(read_surface(&upper, 1.0).unwrap().triangles.len(), m.triangles.len());
}

/// The same triangles and vertices, coordinates equal to f32 precision.
fn equal_to_f32(a: &SurfaceMesh, b: &SurfaceMesh) -> bool {
    a.triangles == b.triangles
        && a.vertices.len() == b.vertices.len()
        && a.vertices
            .iter()
            .zip(&b.vertices)
            .all(|(p, q)| (p - q).norm() <= 1e-7 * p.norm().max(1.0))
}

#[test]
fn binary_and_ascii_read_equal() {
    let m = tube();
    let r = |name: &str, b: Vec<u8>| parse(name, &b, 1.0).unwrap();
    // f32 in binary, its shortest decimal form in ASCII.
    assert!(equal_to_f32(&r("a.stl", stl_ascii(&m)), &r("b.stl", stl_binary(&m))));
    assert!(equal_to_f32(
        &r("a.ply", ply_ascii(&m, true)),
        &r("b.ply", ply_binary(&m, false))
    ));
    // Binary of either byte order: bit-identical.
    assert_eq!(r("a.ply", ply_binary(&m, true)), r("b.ply", ply_binary(&m, false)));
    // Doubles: bit-exact, and equal to what was written.
    assert_eq!(r("a.vtk", vtk_ascii(&m)), r("b.vtk", vtk_binary(&m)));
    assert_eq!(r("a.vtp", vtp(&m, false)), r("b.vtp", vtp(&m, true)));
    assert_eq!(r("a.vtk", vtk_ascii(&m)), m);
    assert_eq!(r("a.obj", obj(&m)), m);
    assert_eq!(r("a.ply", ply_ascii(&m, false)), m);
}

#[test]
fn fixtures_from_an_independent_writer_read_the_same_tube() {
    let want = scaled(&tube(), 1e-3);
    let want_report = check_surface(&want, &CheckOptions::default()).unwrap().report;
    let mut n = 0;
    for entry in std::fs::read_dir(fixtures()).unwrap() {
        let path = entry.unwrap().path();
        let name = path.file_name().unwrap().to_string_lossy().to_string();
        let got = read_surface(&path, 1e-3).unwrap_or_else(|e| panic!("{name}: {e}"));
        let checked = check_surface(&got, &CheckOptions::default()).unwrap_or_else(|e| panic!("{name}: {e}"));
        if name == "tube_strips.vtk" {
            // Strips split each quad along the other diagonal: the same
            // vertices, openings and (to the chord error) area and volume.
            assert_eq!(got.triangles.len(), want.triangles.len());
            assert_eq!(checked.report.flipped, 0, "strip orientation is kept");
            let r = &checked.report;
            assert_eq!(r.boundary_loops.len(), 2);
            assert!(
                (r.area - want_report.area).abs() < 1e-3 * want_report.area,
                "{name}: area"
            );
            assert!(
                (r.volume - want_report.volume).abs() < 1e-2 * want_report.volume,
                "{name}: volume"
            );
        } else {
            same_surface(&got, &want, TOL).unwrap_or_else(|e| panic!("{name}: {e}"));
            assert_eq!(checked.report.boundary_loops.len(), 2, "{name}");
            assert_eq!(checked.report.flipped, 0, "{name}");
        }
        n += 1;
    }
    assert_eq!(n, 12, "one fixture per format variant in tests/fixtures/surface");
}

#[test]
fn scale_multiplies_coordinates() {
    let m = tube();
    for (name, bytes) in all_files(&m) {
        let one = parse(name, &bytes, 1.0).unwrap();
        let milli = parse(name, &bytes, 1e-3).unwrap();
        assert_eq!(one.triangles, milli.triangles, "{name}");
        for (a, b) in one.vertices.iter().zip(&milli.vertices) {
            assert_eq!(a * 1e-3, *b, "{name}");
        }
    }
    for bad in [0.0, -1e-3, f64::NAN, f64::INFINITY] {
        let e = parse("t.obj", &obj(&m), bad).unwrap_err();
        assert!(e.to_string().contains("must be finite and positive"), "{e}");
    }
}

#[test]
fn a_tube_has_two_openings_with_outward_normals() {
    let m = scaled(&tube(), 1e-3);
    let c = check_surface(&m, &CheckOptions::default()).unwrap();
    let r = &c.report;
    assert_eq!(c.mesh, m, "a clean surface passes unchanged");
    assert_eq!((r.flipped, r.unused_vertices), (0, 0));
    assert!(r.degenerate.is_empty() && r.duplicates.is_empty());
    assert_eq!(r.boundary_loops.len(), 2);
    let (rad, len) = (RADIUS * 1e-3, LENGTH * 1e-3);
    let polygon = 0.5 * N_THETA as f64 * rad * rad * (2.0 * PI / N_THETA as f64).sin();
    for lp in &r.boundary_loops {
        assert_eq!(lp.vertices.len(), N_THETA);
        assert!((lp.area - polygon).abs() < 1e-12 * polygon, "{} vs {polygon}", lp.area);
        let at_inlet = lp.centre.z < 0.5 * len;
        let z = if at_inlet { 0.0 } else { len };
        assert!((lp.centre - Vec3::new(0.0, 0.0, z)).norm() < 1e-15, "{:?}", lp.centre);
        // Out of the lumen: -z at the inlet, +z at the outlet.
        let out = if at_inlet { -Vec3::z() } else { Vec3::z() };
        assert!((lp.normal - out).norm() < 1e-12, "{:?}", lp.normal);
        let side = 2.0 * rad * (PI / N_THETA as f64).sin();
        assert!((lp.perimeter - N_THETA as f64 * side).abs() < 1e-12);
    }
    assert!((r.volume - polygon * len).abs() < 1e-9 * polygon * len, "{}", r.volume);
    assert!((r.bbox_diagonal - (8.0 * rad * rad + len * len).sqrt()).abs() < 1e-12);

    // Turned inside out, or with some triangles flipped: fixed and counted.
    let mut inside_out = m.clone();
    inside_out.triangles.iter_mut().for_each(|t| t.swap(1, 2));
    let c2 = check_surface(&inside_out, &CheckOptions::default()).unwrap();
    assert_eq!(c2.report.flipped, m.triangles.len());
    assert_eq!(c2.mesh, m);
    let mut mixed = m.clone();
    for t in [3usize, 40, 41, 100] {
        mixed.triangles[t].swap(0, 1);
    }
    let c3 = check_surface(&mixed, &CheckOptions::default()).unwrap();
    assert_eq!(c3.report.flipped, 4);
    same_surface(&c3.mesh, &m, 0.0).unwrap();
}

#[test]
fn a_closed_surface_has_no_openings() {
    // The tube capped with a fan at each end (a new centre vertex each).
    let mut m = scaled(&tube(), 1e-3);
    let last = N_RINGS - 1;
    let c0 = m.vertices.len() as u32;
    m.vertices.push(Vec3::zeros());
    m.vertices.push(Vec3::new(0.0, 0.0, LENGTH * 1e-3));
    for k in 0..N_THETA {
        m.triangles.push([c0, idx(0, k + 1), idx(0, k)]);
        m.triangles.push([c0 + 1, idx(last, k), idx(last, k + 1)]);
    }
    let c = check_surface(&m, &CheckOptions::default()).unwrap();
    assert!(c.report.boundary_loops.is_empty());
    assert_eq!(c.report.flipped, 0);
    assert!(c.report.volume > 0.0);
}

#[test]
fn degenerate_duplicate_and_unused_are_removed_and_reported() {
    let mut m = scaled(&tube(), 1e-3);
    m.vertices.push(Vec3::new(1.0, 1.0, 1.0)); // unused, and far away
    m.triangles.push([0, 0, 1]); // degenerate: a repeated vertex
    let dup = m.triangles[5];
    m.triangles.push([dup[1], dup[2], dup[0]]); // duplicate of triangle 5
    let n = m.triangles.len();
    let c = check_surface(&m, &CheckOptions::default()).unwrap();
    assert_eq!(c.report.degenerate, vec![n - 2]);
    assert_eq!(c.report.duplicates, vec![n - 1]);
    assert_eq!(c.report.unused_vertices, 1);
    assert_eq!(c.mesh, scaled(&tube(), 1e-3));
    assert_eq!(c.report.input_triangle.len(), n - 2);

    // An STL facet whose corners weld (a sliver of zero width along an
    // existing edge) is removed the same way.
    let mut stl = stl_binary(&tube());
    let facet = stl[84 + 12..84 + 36].to_vec(); // corners 0 and 1 of facet 0
    stl[80..84].copy_from_slice(&129u32.to_le_bytes());
    stl.extend([0u8; 12]);
    stl.extend(&facet[..12]);
    stl.extend(&facet[..12]);
    stl.extend(&facet[12..]);
    stl.extend([0u8; 2]);
    let s = parse("w.stl", &stl, 1e-3).unwrap();
    let c = check_surface(&s, &CheckOptions::default()).unwrap();
    assert_eq!(c.report.degenerate, vec![128]);
    assert_eq!(c.mesh.triangles.len(), 128);
    same_surface(&c.mesh, &scaled(&tube(), 1e-3), TOL).unwrap();
}

#[test]
fn collinear_triangle_is_refused_with_its_vertices() {
    let m = SurfaceMesh {
        vertices: vec![
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(0.01, 0.0, 0.0),
            Vec3::new(0.02, 0.0, 0.0),
            Vec3::new(0.0, 0.01, 0.0),
        ],
        triangles: vec![[0, 1, 3], [0, 1, 2]],
    };
    let e = check_surface(&m, &CheckOptions::default()).unwrap_err();
    let msg = e.to_string();
    assert!(
        matches!(
            e,
            SurfaceDefect::ZeroArea {
                triangle: 1,
                vertices: [0, 1, 2],
                ..
            }
        ),
        "{msg}"
    );
    assert!(msg.contains("triangle 1 (vertices 0, 1, 2"), "{msg}");
}

#[test]
fn non_manifold_edge_names_its_vertices_and_coordinates() {
    let mut m = scaled(&tube(), 1e-3);
    let (a, b) = (idx(1, 0), idx(2, 0));
    let fin = m.vertices.len() as u32;
    m.vertices.push(Vec3::new(0.012, 0.0, 0.015));
    m.triangles.push([a, b, fin]);
    let e = check_surface(&m, &CheckOptions::default()).unwrap_err();
    let msg = e.to_string();
    match &e {
        SurfaceDefect::NonManifoldEdge {
            a: x,
            b: y,
            pa,
            pb,
            triangles,
        } => {
            assert_eq!((*x, *y), (a, b));
            assert_eq!((*pa, *pb), (m.vertices[a as usize], m.vertices[b as usize]));
            assert_eq!(triangles.len(), 3);
            assert!(triangles.contains(&(m.triangles.len() - 1)));
        }
        other => panic!("{other}"),
    }
    assert!(msg.contains(&format!("non-manifold edge {a}-{b}")), "{msg}");
    assert!(msg.contains("(5.000000e-3, 0.000000e0, 1.000000e-2)"), "{msg}");
    assert!(msg.contains("shared by 3 triangles"), "{msg}");
}

#[test]
fn non_manifold_vertex_and_non_orientable_are_refused() {
    // Two tetrahedra touching at one vertex.
    let p = |x: f64, y: f64, z: f64| Vec3::new(x, y, z) * 0.01;
    let m = SurfaceMesh {
        vertices: vec![
            p(0.0, 0.0, 0.0),
            p(1.0, 0.0, 0.0),
            p(0.0, 1.0, 0.0),
            p(0.0, 0.0, 1.0),
            p(-1.0, 0.0, 0.0),
            p(0.0, -1.0, 0.0),
            p(0.0, 0.0, -1.0),
        ],
        triangles: vec![
            [0, 2, 1],
            [0, 1, 3],
            [0, 3, 2],
            [1, 2, 3],
            [0, 5, 4],
            [0, 4, 6],
            [0, 6, 5],
            [4, 5, 6],
        ],
    };
    let e = check_surface(&m, &CheckOptions::default()).unwrap_err();
    assert!(
        matches!(e, SurfaceDefect::NonManifoldVertex { vertex: 0, fans: 2, .. }),
        "{e}"
    );
    assert!(e.to_string().contains("non-manifold vertex 0"), "{e}");

    // A Möbius band.
    let n = 24;
    let mut verts = Vec::new();
    for k in 0..n {
        let u = 2.0 * PI * k as f64 / n as f64;
        for v in [-0.005, 0.005] {
            let r = 0.02 + v * (u / 2.0).cos();
            verts.push(Vec3::new(r * u.cos(), r * u.sin(), v * (u / 2.0).sin()));
        }
    }
    let mut tris = Vec::new();
    for k in 0..n {
        let (b0, t0) = (2 * k as u32, 2 * k as u32 + 1);
        // The half twist: the last band joins bottom to top.
        let (b1, t1) = if k + 1 == n {
            (1, 0)
        } else {
            (2 * k as u32 + 2, 2 * k as u32 + 3)
        };
        tris.push([b0, b1, t1]);
        tris.push([b0, t1, t0]);
    }
    let e = check_surface(
        &SurfaceMesh {
            vertices: verts,
            triangles: tris,
        },
        &CheckOptions::default(),
    )
    .unwrap_err();
    assert!(matches!(e, SurfaceDefect::NonOrientable { .. }), "{e}");
    assert!(e.to_string().contains("not orientable"), "{e}");
}

#[test]
fn two_bodies_are_refused_or_the_largest_kept() {
    let one = tube();
    let mut m = one.clone();
    let off = m.vertices.len() as u32;
    m.vertices
        .extend(one.vertices.iter().map(|p| p + Vec3::new(20.0, 0.0, 0.0)));
    // The second tube shorter: its first two bands only.
    m.triangles
        .extend(one.triangles[..2 * 2 * N_THETA].iter().map(|t| t.map(|i| i + off)));
    let m = scaled(&m, 1e-3);
    let e = check_surface(&m, &CheckOptions::default()).unwrap_err();
    assert_eq!(e, SurfaceDefect::SeveralBodies { sizes: vec![128, 64] });
    assert!(
        e.to_string()
            .contains("2 disconnected bodies (triangles in each: 128, 64)"),
        "{e}"
    );
    let opts = CheckOptions {
        keep_largest_body: true,
        ..CheckOptions::default()
    };
    let c = check_surface(&m, &opts).unwrap();
    assert_eq!(c.report.dropped_bodies, vec![64]);
    assert_eq!(c.mesh, scaled(&one, 1e-3));
    assert_eq!(c.report.unused_vertices, 80, "the dropped body's vertices go too");
}

#[test]
fn wrong_unit_names_the_scale_to_pass() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("tube.stl");
    std::fs::write(&path, stl_binary(&tube())).unwrap();
    // Millimetres read as metres.
    let e = read_and_check(&path, 1.0, &CheckOptions::default()).unwrap_err();
    let msg = e.to_string();
    match &e {
        SurfaceError::Defect {
            source: SurfaceDefect::WrongUnit { suggested, scale, .. },
            ..
        } => assert_eq!((*suggested, *scale), (Some(0.001), 1.0)),
        other => panic!("{other}"),
    }
    assert!(
        msg.contains("tube.stl") && msg.contains("read it with scale 0.001"),
        "{msg}"
    );
    // Metres read as millimetres.
    let e = read_and_check(&path, 1e-6, &CheckOptions::default()).unwrap_err();
    assert!(e.to_string().contains("read it with scale 0.001"), "{e}");
    assert!(read_and_check(&path, 1e-3, &CheckOptions::default()).is_ok());
    // A tube of 1 mm: too small.
    let tiny = scaled(&tube(), 1e-6);
    let e = check_surface(&tiny, &CheckOptions::default()).unwrap_err();
    assert!(
        matches!(e, SurfaceDefect::WrongUnit { suggested: Some(s), .. } if s == 1e3),
        "{e}"
    );
    let off = CheckOptions {
        check_unit: false,
        ..CheckOptions::default()
    };
    assert!(check_surface(&tiny, &off).is_ok());
}

#[test]
fn self_intersection_names_two_triangles() {
    let mut m = tube();
    // Pull one wall vertex through the lumen and out of the opposite wall.
    let v = idx(2, 0) as usize;
    m.vertices[v] = Vec3::new(-1.6 * RADIUS, 0.3, 20.0);
    let m = scaled(&m, 1e-3);
    let e = check_surface(&m, &CheckOptions::default()).unwrap_err();
    let SurfaceDefect::SelfIntersection {
        first, second, pairs, ..
    } = e.clone()
    else {
        panic!("{e}");
    };
    assert!(first < second && pairs >= 2, "{e}");
    // One of the pair uses the moved vertex, the other is on the far wall.
    let uses = |t: usize| m.triangles[t].contains(&(v as u32));
    assert!(uses(first) || uses(second), "{e}");
    assert!(
        e.to_string()
            .contains(&format!("triangles {first} and {second} intersect")),
        "{e}"
    );
    let off = CheckOptions {
        self_intersections: false,
        ..CheckOptions::default()
    };
    assert!(check_surface(&m, &off).is_ok());

    // Two tubes crossing, joined into one body by nothing: refused as two
    // bodies first; kept-largest of crossing equal tubes still intersects.
    let base = tube();
    let mut x = base.clone();
    let off_v = x.vertices.len() as u32;
    x.vertices
        .extend(base.vertices.iter().map(|p| Vec3::new(p.z - 20.0, p.y, p.x + 20.0)));
    x.triangles.extend(base.triangles.iter().map(|t| t.map(|i| i + off_v)));
    let x = scaled(&x, 1e-3);
    assert!(matches!(
        check_surface(&x, &CheckOptions::default()).unwrap_err(),
        SurfaceDefect::SeveralBodies { .. }
    ));
}

#[test]
fn truncated_files_say_so() {
    let m = tube();
    let stl = stl_binary(&m);
    let e = parse("t.stl", &stl[..stl.len() - 10], 1.0).unwrap_err().to_string();
    assert!(
        e.contains("declares 128 triangles, which take 84 + 50×128 = 6484 bytes, but the file has 6474 bytes"),
        "{e}"
    );
    let ascii = stl_ascii(&m);
    let cut = ascii[..ascii.len() / 2].iter().rposition(|&b| b == b'\n').unwrap() + 1;
    let e = parse("t.stl", &ascii[..cut], 1.0).unwrap_err().to_string();
    assert!(e.starts_with("t.stl:") && e.contains("unexpected end of file"), "{e}");
    for (name, b) in [("t.ply", ply_binary(&m, false)), ("t.vtk", vtk_binary(&m))] {
        let e = parse(name, &b[..b.len() * 2 / 3], 1.0).unwrap_err().to_string();
        assert!(e.contains("file ends inside"), "{name}: {e}");
    }
    let e = parse("t.ply", &ply_ascii(&m, false)[..3000], 1.0)
        .unwrap_err()
        .to_string();
    assert!(e.contains("unexpected end of file"), "{e}");
    let v = vtp(&m, true);
    let cut = v.windows(8).position(|w| w == b"</Polys>").unwrap();
    let e = parse("t.vtp", &v[..cut], 1.0).unwrap_err().to_string();
    assert!(e.contains("the file ends inside <"), "{e}");
    let o = obj(&m);
    let cut = o.len() - 8; // in the last face line
    let e = parse("t.obj", &o[..cut], 1.0);
    // Cutting a face line may leave a shorter valid face or a broken token.
    if let Err(e) = e {
        assert!(e.to_string().starts_with("t.obj:"), "{e}");
    }
    let e = parse("t.ply", b"ply\nformat ascii 1.0\nelement vertex 3\n", 1.0)
        .unwrap_err()
        .to_string();
    assert!(e.contains("no 'end_header'"), "{e}");
}

#[test]
fn bad_index_names_the_line() {
    let obj = b"# a triangle\nv 0 0 0\nv 1 0 0\nv 0 1 0\n\nf 1 2 3\nf 1 2 9\n";
    let e = parse("t.obj", obj, 1.0).unwrap_err().to_string();
    assert_eq!(e, "t.obj:7: vertex index 9 is out of range (the file has 3 vertices)");
    let e = parse("t.obj", b"v 0 0 0\nv 1 0 0\nf 1 2 -3\n", 1.0)
        .unwrap_err()
        .to_string();
    assert!(e.starts_with("t.obj:3: relative vertex index -3"), "{e}");
    let e = parse("t.obj", b"v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 0\n", 1.0)
        .unwrap_err()
        .to_string();
    assert!(e.starts_with("t.obj:4: vertex index 0"), "{e}");
    let e = parse("t.obj", b"v 0 0 0\nv 1 0 x\n", 1.0).unwrap_err().to_string();
    assert!(
        e.starts_with("t.obj:2: vertex 2: coordinate z 'x' is not a number"),
        "{e}"
    );

    let ply = b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n\
element face 2\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n3 0 1 5\n";
    let e = parse("t.ply", ply, 1.0).unwrap_err().to_string();
    assert_eq!(
        e,
        "t.ply:14: face 1: vertex index 5 is out of range (the file has 3 vertices)"
    );

    let vtk = b"# vtk DataFile Version 3.0\nt\nASCII\nDATASET POLYDATA\nPOINTS 3 float\n0 0 0 1 0 0 0 1 0\n\
POLYGONS 2 8\n3 0 1 2\n3 0 1 7\n";
    let e = parse("t.vtk", vtk, 1.0).unwrap_err().to_string();
    assert_eq!(
        e,
        "t.vtk:7: polygon 1: point index 7 is out of range (the file has 3 points)"
    );

    let vtp = b"<VTKFile type=\"PolyData\"><PolyData><Piece NumberOfPoints=\"3\" NumberOfPolys=\"1\">\n<Points>\n\
<DataArray type=\"Float32\" NumberOfComponents=\"3\" format=\"ascii\">0 0 0 1 0 0 0 1 0</DataArray></Points>\n<Polys>\n\
<DataArray type=\"Int32\" Name=\"connectivity\" format=\"ascii\">0 1 3</DataArray>\n\
<DataArray type=\"Int32\" Name=\"offsets\" format=\"ascii\">3</DataArray></Polys></Piece></PolyData></VTKFile>";
    let e = parse("t.vtp", vtp, 1.0).unwrap_err().to_string();
    assert_eq!(
        e,
        "t.vtp:5: polygon 0: point index 3 is out of range (the file has 3 points)"
    );

    // Binary PLY: the byte offset.
    let mut b = ply_binary(&tube(), false);
    let at = b.len() - 4; // the last index of the last face
    b[at..].copy_from_slice(&1000i32.to_le_bytes());
    let e = parse("t.ply", &b, 1.0).unwrap_err().to_string();
    assert_eq!(
        e,
        format!(
            "t.ply: byte {}: face 127: vertex index 1000 is out of range (the file has 80 vertices)",
            b.len()
        )
    );
}

#[test]
fn other_refusals_are_explained() {
    let cases: &[(&str, &[u8], &str)] = &[
        ("t.xyz", b"", "unknown surface format"),
        ("t.stl", b"hello", "not an ASCII STL"),
        ("t.stl", b"solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\nvertex 1 1 0\n", "only triangles are allowed"),
        ("t.ply", b"ply\nformat binary_middle_endian 1.0\nend_header\n", "unknown PLY format"),
        ("t.ply", b"ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\nproperty float z\nend_header\n", "no 'face' element"),
        ("t.vtk", b"# vtk DataFile Version 3.0\nt\nASCII\nDATASET UNSTRUCTURED_GRID\n", "only POLYDATA"),
        ("t.vtk", b"# vtk DataFile Version 3.0\nt\nASCII\nDATASET POLYDATA\nPOINTS 1 float\n0 0 0\n", "no POLYGONS"),
        ("t.vtp", b"<VTKFile type=\"UnstructuredGrid\"></VTKFile>", "is not PolyData"),
        ("t.vtp", b"<VTKFile type=\"PolyData\" compressor=\"vtkLZ4DataCompressor\"></VTKFile>", "not supported"),
        ("t.obj", b"v 0 0 0\nv 1 0 0\nf 1 2\n", "at least 3"),
        ("t.obj", b"# nothing\n", "no triangles"),
        ("t.obj", b"v 0 0 nan\n", "not finite"),
    ];
    for (name, bytes, want) in cases {
        let e = match SurfaceFormat::from_path(Path::new(name)) {
            Ok(f) => read_surface_bytes(f, Path::new(name), bytes, 1.0).unwrap_err(),
            Err(e) => e,
        };
        assert!(e.to_string().contains(want), "{name}: {e} (wanted '{want}')");
    }
    let e = read_surface(Path::new("/nonexistent/t.stl"), 1.0).unwrap_err();
    assert!(matches!(e, SurfaceError::Io { .. }), "{e}");
}

#[test]
fn welding_merges_within_the_tolerance_only() {
    let mut m = SurfaceMesh {
        vertices: vec![
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(1e-10, 0.0, 0.0),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(-0.0, 0.0, 0.0),
        ],
        triangles: vec![[0, 1, 2], [3, 2, 1]],
    };
    let mut exact = m.clone();
    assert_eq!(weld_vertices(&mut exact, 0.0), 1, "-0 and +0 are the same point");
    assert_eq!(weld_vertices(&mut m, 1e-9), 2);
    assert_eq!(m.vertices.len(), 2);
    assert_eq!(m.triangles, vec![[0, 0, 1], [0, 1, 0]]);
}

/// A small deterministic generator (xorshift64*).
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

#[test]
fn no_input_makes_a_reader_or_the_check_panic() {
    let m = tube();
    let mut files = all_files(&m);
    for entry in std::fs::read_dir(fixtures()).unwrap() {
        let path = entry.unwrap().path();
        let name: &'static str = Box::leak(path.file_name().unwrap().to_string_lossy().to_string().into_boxed_str());
        files.push((name, std::fs::read(&path).unwrap()));
    }
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    let mut cases = 0usize;
    let run = |name: &str, bytes: &[u8]| {
        if let Ok(s) = parse(name, bytes, 1e-3) {
            let _ = check_surface(&s, &CheckOptions::default());
        }
    };
    for (name, bytes) in &files {
        // Truncations: every length for small files, ~1500 evenly spaced otherwise.
        let step = (bytes.len() / 1500).max(1);
        for len in (0..bytes.len()).step_by(step) {
            run(name, &bytes[..len]);
            cases += 1;
        }
        // Mutations: 1-8 bytes overwritten with random or interesting values.
        for _ in 0..600 {
            let mut b = bytes.clone();
            for _ in 0..1 + rng.below(8) {
                let at = rng.below(b.len());
                b[at] = match rng.below(6) {
                    0 => 0,
                    1 => 0xff,
                    2 => b'9',
                    3 => b'\n',
                    4 => b'-',
                    _ => rng.next() as u8,
                };
            }
            run(name, &b);
            cases += 1;
        }
        // Random bytes behind the file's real header.
        for _ in 0..100 {
            let keep = rng.below(bytes.len().min(400));
            let mut b = bytes[..keep].to_vec();
            b.extend((0..rng.below(2000)).map(|_| rng.next() as u8));
            run(name, &b);
            cases += 1;
        }
    }
    // Pure random bytes for every format.
    for ext in ["stl", "obj", "ply", "vtk", "vtp"] {
        let name = format!("r.{ext}");
        for _ in 0..300 {
            let b: Vec<u8> = (0..rng.below(3000)).map(|_| rng.next() as u8).collect();
            run(&name, &b);
            cases += 1;
        }
    }
    // Binary STL whose size matches the declared count, with random content
    // (NaNs, huge values, coincident corners).
    for _ in 0..300 {
        let n = 1 + rng.below(20);
        let mut b = vec![0u8; 80];
        b.extend((n as u32).to_le_bytes());
        b.extend((0..50 * n).map(|_| if rng.below(3) == 0 { 0 } else { rng.next() as u8 }));
        run("r.stl", &b);
        cases += 1;
    }
    assert!(cases > 20_000, "{cases} cases");
}

#[test]
fn checks_never_panic_on_random_surfaces() {
    let mut rng = Rng(42);
    for case in 0..2000 {
        let nv = 1 + rng.below(12);
        // Coordinates on a coarse grid so that coincident, collinear and
        // coplanar configurations are common.
        let vertices = (0..nv)
            .map(|_| Vec3::new(rng.below(3) as f64, rng.below(3) as f64, rng.below(3) as f64) * 0.01)
            .collect();
        let triangles = (0..1 + rng.below(16))
            .map(|_| [0; 3].map(|_: u32| rng.below(nv + usize::from(case % 50 == 0)) as u32))
            .collect();
        let m = SurfaceMesh { vertices, triangles };
        let opts = CheckOptions {
            keep_largest_body: case % 2 == 0,
            ..CheckOptions::default()
        };
        if let Ok(c) = check_surface(&m, &opts) {
            // What passes is clean: every edge in at most two triangles,
            // every loop closed, no triangle repeated.
            let r = &c.report;
            assert_eq!(r.input_triangle.len(), c.mesh.triangles.len());
            assert_eq!(r.input_vertex.len(), c.mesh.vertices.len());
            for lp in &r.boundary_loops {
                assert!(lp.vertices.len() >= 3);
            }
        }
    }
}
