//! Every volume format we write reads back bit-identical (nodes, tets in the
//! same order and vertex order, node sets where the format carries them);
//! formats we only read are checked on small fixtures built here by hand
//! from the format specifications; surface writers give the right counts.

use nvtmm::math::Vec3;
use nvtmm::mesh::arch::{generate, ArchParams};
use nvtmm::mesh::io::{
    read_mesh, read_mesh_bytes, read_mesh_scaled, write_mesh, write_tetgen, write_vtu_with_data, Format, PvdSeries,
};
use nvtmm::mesh::TetMesh;
use std::path::Path;

fn arch() -> TetMesh {
    generate(&ArchParams::default(), 1458).unwrap().mesh
}

fn assert_same(a: &TetMesh, b: &TetMesh, sets: bool) {
    assert_eq!(a.num_nodes(), b.num_nodes());
    for (i, (p, q)) in a.rest().iter().zip(b.rest()).enumerate() {
        for k in 0..3 {
            assert_eq!(
                p[k].to_bits(),
                q[k].to_bits(),
                "node {i} axis {k}: {} vs {}",
                p[k],
                q[k]
            );
        }
    }
    assert_eq!(a.tets(), b.tets());
    assert_eq!(b.report().inverted, 0);
    if sets {
        assert_eq!(a.node_sets(), b.node_sets());
    } else {
        assert!(b.node_sets().is_empty());
    }
}

#[test]
fn volume_formats_round_trip_bit_exact() {
    let m = arch();
    assert_eq!(m.node_sets().len(), 4);
    let dir = tempfile::tempdir().unwrap();
    for (file, sets) in [("a.msh", true), ("a.vtk", true), ("a.vtu", true), ("a.node", false)] {
        let p = dir.path().join(file);
        write_mesh(&m, &p).unwrap();
        let back = read_mesh(&p).unwrap_or_else(|e| panic!("{file}: {e}"));
        assert_same(&m, &back, sets);
    }
}

#[test]
fn tetgen_reads_zero_and_one_based_from_either_file() {
    let m = arch();
    let dir = tempfile::tempdir().unwrap();
    for base in [0, 1] {
        let p = dir.path().join(format!("b{base}.ele"));
        write_tetgen(&m, &p, base).unwrap();
        let first = std::fs::read_to_string(p.with_extension("node")).unwrap();
        let second_line = first.lines().nth(2).unwrap();
        assert!(second_line.starts_with(&format!("{base} ")), "{second_line}");
        for q in [p.clone(), p.with_extension("node")] {
            assert_same(&m, &read_mesh(&q).unwrap(), false);
        }
    }
}

#[test]
fn scale_multiplies_coordinates() {
    let m = arch();
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("s.vtu");
    write_mesh(&m, &p).unwrap();
    let mm = read_mesh_scaled(&p, 1e3).unwrap();
    assert_eq!(mm.rest()[7], m.rest()[7] * 1e3);
}

#[test]
fn our_gmsh_output_parses_with_mshio() {
    // An independent parser agrees on what our 4.1 writer means.
    let m = arch();
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("x.msh");
    write_mesh(&m, &p).unwrap();
    let bytes = std::fs::read(&p).unwrap();
    let msh = mshio::parse_msh_bytes(&bytes).unwrap();
    assert_eq!(msh.total_node_count(), m.num_nodes());
    let counts = msh.count_element_types();
    assert_eq!(counts[&mshio::ElementType::Tet4], m.tets().len());
    assert_eq!(msh.volume_count(), 1);
    assert_eq!(msh.point_count(), 4);
}

/// Two tets sharing face 20-30-40; tags are sparse on purpose.
const GMSH22: &str = r#"$MeshFormat
2.2 0 8
$EndMeshFormat
$PhysicalNames
3
0 7 "tip"
2 5 "wall face"
3 9 "tissue"
$EndPhysicalNames
$Nodes
5
10 0 0 0
20 1 0 0
30 0 1 0
40 0 0 1
50 1 1 1
$EndNodes
$Comments
anything at all $Nodes
$EndComments
$Elements
5
1 15 2 7 1 50
2 1 2 0 1 10 20
3 2 2 5 1 10 20 30
4 4 2 9 1 10 20 30 40
5 4 2 9 1 20 30 40 50
$EndElements
"#;

#[test]
fn gmsh22_ascii_fixture() {
    let m = read_mesh_bytes(Format::Gmsh, Path::new("f.msh"), GMSH22.as_bytes(), 1.0).unwrap();
    assert_eq!(m.num_nodes(), 5);
    assert_eq!(m.tets(), &[[0, 1, 2, 3], [1, 2, 3, 4]]);
    assert_eq!(m.report().inverted, 0);
    assert_eq!(m.node_set("tip"), Some(&[4][..]));
    assert_eq!(m.node_set("wall face"), Some(&[0, 1, 2][..]));
    assert_eq!(m.node_set("tissue"), Some(&[0, 1, 2, 3, 4][..]));
    assert_eq!(m.rest()[4], Vec3::new(1.0, 1.0, 1.0));
}

/// Gmsh 4.1 binary, written by hand from the format description:
/// little-endian, size_t = 8; one point entity (physical 7 "tip"), one
/// volume (physical 9 "tissue"), the two tets of [`GMSH22`], one point element.
fn gmsh41_binary() -> Vec<u8> {
    let mut b = Vec::new();
    let sz = |b: &mut Vec<u8>, v: u64| b.extend_from_slice(&v.to_le_bytes());
    let int = |b: &mut Vec<u8>, v: i32| b.extend_from_slice(&v.to_le_bytes());
    let dbl = |b: &mut Vec<u8>, v: f64| b.extend_from_slice(&v.to_le_bytes());
    b.extend_from_slice(b"$MeshFormat\n4.1 1 8\n");
    int(&mut b, 1);
    b.extend_from_slice(b"\n$EndMeshFormat\n$PhysicalNames\n2\n0 7 \"tip\"\n3 9 \"tissue\"\n$EndPhysicalNames\n");
    b.extend_from_slice(b"$Entities\n");
    for n in [1, 0, 0, 1] {
        sz(&mut b, n);
    }
    // point 3 at (1,1,1), physical 7
    int(&mut b, 3);
    for _ in 0..3 {
        dbl(&mut b, 1.0);
    }
    sz(&mut b, 1);
    int(&mut b, 7);
    // volume 1, bbox, physical 9, no bounding surfaces
    int(&mut b, 1);
    for v in [0.0, 0.0, 0.0, 1.0, 1.0, 1.0] {
        dbl(&mut b, v);
    }
    sz(&mut b, 1);
    int(&mut b, 9);
    sz(&mut b, 0);
    b.extend_from_slice(b"\n$EndEntities\n$Nodes\n");
    for v in [1, 5, 10, 50] {
        sz(&mut b, v);
    }
    int(&mut b, 3);
    int(&mut b, 1);
    int(&mut b, 0);
    sz(&mut b, 5);
    for t in [10, 20, 30, 40, 50] {
        sz(&mut b, t);
    }
    for p in [
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, 0.0, 1.0],
        [1.0, 1.0, 1.0],
    ] {
        for v in p {
            dbl(&mut b, v);
        }
    }
    b.extend_from_slice(b"\n$EndNodes\n$Elements\n");
    for v in [2, 3, 1, 3] {
        sz(&mut b, v);
    }
    int(&mut b, 3);
    int(&mut b, 1);
    int(&mut b, 4);
    sz(&mut b, 2);
    for e in [[1, 10, 20, 30, 40], [2, 20, 30, 40, 50]] {
        for v in e {
            sz(&mut b, v);
        }
    }
    int(&mut b, 0);
    int(&mut b, 3);
    int(&mut b, 15);
    sz(&mut b, 1);
    sz(&mut b, 3);
    sz(&mut b, 50);
    b.extend_from_slice(b"\n$EndElements\n");
    b
}

#[test]
fn gmsh41_binary_fixture() {
    let bytes = gmsh41_binary();
    // mshio agrees the fixture follows the format.
    let msh = mshio::parse_msh_bytes(&bytes).unwrap();
    assert_eq!(msh.total_node_count(), 5);
    let m = read_mesh_bytes(Format::Gmsh, Path::new("b.msh"), &bytes, 1.0).unwrap();
    assert_eq!(m.tets(), &[[0, 1, 2, 3], [1, 2, 3, 4]]);
    assert_eq!(m.node_set("tip"), Some(&[4][..]));
    assert_eq!(m.node_set("tissue"), Some(&[0, 1, 2, 3, 4][..]));
    assert_eq!(m.rest()[1], Vec3::new(1.0, 0.0, 0.0));
}

/// VTK legacy BINARY (big-endian), classic cells, with a triangle to skip, an
/// inverted tet and a node set.
fn vtk_binary() -> Vec<u8> {
    let mut b = b"# vtk DataFile Version 3.0\nfixture\nBINARY\nDATASET UNSTRUCTURED_GRID\nPOINTS 5 double\n".to_vec();
    for p in [
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, 0.0, 1.0],
        [1.0, 1.0, 1.0],
    ] {
        for v in p {
            b.extend_from_slice(&f64::to_be_bytes(v));
        }
    }
    b.extend_from_slice(b"\nCELLS 3 14\n");
    for v in [4, 0, 1, 2, 3, 4, 1, 3, 2, 4, 3, 0, 1, 2] {
        b.extend_from_slice(&i32::to_be_bytes(v));
    }
    b.extend_from_slice(b"\nCELL_TYPES 3\n");
    for v in [10, 10, 5] {
        b.extend_from_slice(&i32::to_be_bytes(v));
    }
    b.extend_from_slice(b"\nPOINT_DATA 5\nSCALARS set_top%20node int 1\nLOOKUP_TABLE default\n");
    for v in [0, 0, 0, 0, 1] {
        b.extend_from_slice(&i32::to_be_bytes(v));
    }
    b.extend_from_slice(b"\nVECTORS u float\n");
    b.extend_from_slice(&[0u8; 5 * 12]);
    b.push(b'\n');
    b
}

#[test]
fn vtk_binary_big_endian_fixture() {
    let m = read_mesh_bytes(Format::VtkLegacy, Path::new("b.vtk"), &vtk_binary(), 1.0).unwrap();
    // The second tet is inverted in the file: reoriented and counted.
    assert_eq!(m.tets(), &[[0, 1, 2, 3], [1, 3, 4, 2]]);
    assert_eq!(m.report().inverted, 1);
    assert_eq!(m.node_set("top node"), Some(&[4][..]));
}

#[test]
fn vtk_5_offsets_layout_ascii() {
    let f = "# vtk DataFile Version 5.1\nx\nASCII\nDATASET UNSTRUCTURED_GRID\nPOINTS 4 float\n\
             0 0 0 1 0 0 0 1 0 0 0 1\nMETADATA\nINFORMATION 0\n\nCELLS 3 5\nOFFSETS vtktypeint64\n0 1 5\n\
             CONNECTIVITY vtktypeint64\n3 0 1 2 3\nCELL_TYPES 2\n1 10\nCELL_DATA 2\nSCALARS c double\n\
             LOOKUP_TABLE default\n1 2\n";
    let m = read_mesh_bytes(Format::VtkLegacy, Path::new("5.vtk"), f.as_bytes(), 1.0).unwrap();
    assert_eq!(m.tets(), &[[0, 1, 2, 3]]);
}

#[test]
fn surface_writers_have_the_boundary_triangle_count() {
    let m = arch();
    let nt = m.surface().len();
    let nv = m.surface_nodes().len();
    let dir = tempfile::tempdir().unwrap();

    let ply = dir.path().join("s.ply");
    write_mesh(&m, &ply).unwrap();
    let text = std::fs::read_to_string(&ply).unwrap();
    assert!(text.contains(&format!("element face {nt}\n")));
    assert!(text.contains(&format!("element vertex {nv}\n")));
    let body = text.split("end_header\n").nth(1).unwrap();
    assert_eq!(body.lines().filter(|l| l.starts_with("3 ")).count(), nt);

    let obj = dir.path().join("s.obj");
    write_mesh(&m, &obj).unwrap();
    let text = std::fs::read_to_string(&obj).unwrap();
    assert_eq!(text.lines().filter(|l| l.starts_with("f ")).count(), nt);
    assert_eq!(text.lines().filter(|l| l.starts_with("v ")).count(), nv);

    let stl = dir.path().join("s.stl");
    write_mesh(&m, &stl).unwrap();
    let bytes = std::fs::read(&stl).unwrap();
    let count = u32::from_le_bytes(bytes[80..84].try_into().unwrap()) as usize;
    assert_eq!(count, nt);
    assert_eq!(bytes.len(), 84 + 50 * nt);
    // The first facet's stored normal points out of the body (away from the centroid).
    let f32_at = |o: usize| f32::from_le_bytes(bytes[o..o + 4].try_into().unwrap()) as f64;
    let n = Vec3::new(f32_at(84), f32_at(88), f32_at(92));
    let a = Vec3::new(f32_at(96), f32_at(100), f32_at(104));
    assert!((n.norm() - 1.0).abs() < 1e-5);
    let t = m.surface()[0];
    let centroid_of_tet = m
        .tets()
        .iter()
        .find(|tet| t.iter().all(|v| tet.contains(v)))
        .map(|tet| tet.iter().map(|&i| m.rest()[i as usize]).sum::<Vec3>() / 4.0)
        .unwrap();
    assert!(n.dot(&(a - centroid_of_tet)) > 0.0);
}

#[test]
fn vtu_with_data_and_pvd_series() {
    let m = arch();
    let dir = tempfile::tempdir().unwrap();
    let u: Vec<Vec3> = m.rest().iter().map(|p| p * 0.01).collect();
    let moved: Vec<Vec3> = m.rest().iter().zip(&u).map(|(p, d)| p + d).collect();
    let s: Vec<f64> = (0..m.num_nodes()).map(|i| i as f64 * 0.5).collect();
    let mut series = PvdSeries::create(&dir.path().join("run"), "arch").unwrap();
    for k in 0..3 {
        let p = series
            .add_step(
                k as f64 * 1e-3,
                &m,
                Some(&moved),
                &[("displacement", &u)],
                &[("stress", &s)],
            )
            .unwrap();
        assert!(p.ends_with(format!("run/arch_{k:06}.vtu")));
    }
    assert_eq!(series.len(), 3);
    let pvd = series.finish().unwrap();
    let text = std::fs::read_to_string(&pvd).unwrap();
    assert_eq!(text.matches("<DataSet ").count(), 3);
    assert!(text.contains("timestep=\"0.002\""));
    assert!(text.contains("file=\"arch_000002.vtu\""));
    // A step reads back as a mesh at the drawn positions, with the node sets.
    let back = read_mesh(&dir.path().join("run/arch_000001.vtu")).unwrap();
    assert_eq!(back.rest(), &moved[..]);
    assert_eq!(back.tets(), m.tets());
    assert_eq!(back.node_sets(), m.node_sets());
    let vtu = std::fs::read_to_string(dir.path().join("run/arch_000001.vtu")).unwrap();
    assert!(vtu.contains("Name=\"displacement\" NumberOfComponents=\"3\""));
    assert!(vtu.contains("Name=\"stress\""));

    // Wrong lengths are refused.
    let short = &u[..10];
    let e = write_vtu_with_data(&dir.path().join("bad.vtu"), &m, None, &[("u", short)], &[]).unwrap_err();
    assert!(e.to_string().contains("'u' has 10 values"), "{e}");
}

/// Written by meshio (the appended ones by a script in the layout VTK uses,
/// and checked with meshio's reader); see the fixtures' README.
const FROM_MESHIO: [&str; 10] = [
    "mio22.msh",
    "mio41a.msh",
    "mio41b.msh",
    "mioa.vtk",
    "miob.vtk",
    "mio.vtu",
    "mio_b64.vtu",
    "mio_zlib.vtu",
    "appended_raw.vtu",
    "appended_zlib.vtu",
];

#[test]
fn files_written_by_meshio_read_the_same_mesh() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/meshio");
    let reference = read_mesh(&dir.join("small.vtu")).unwrap();
    for f in FROM_MESHIO {
        let m = read_mesh(&dir.join(f)).unwrap_or_else(|e| panic!("{f}: {e}"));
        assert_eq!(m.tets(), reference.tets(), "{f}");
        assert_eq!(m.report().inverted, 0, "{f}");
        // meshio's ASCII .vtu keeps 12 significant digits; the others are exact.
        let tol = if f == "mio.vtu" { 1e-10 } else { 1e-15 };
        for (p, q) in m.rest().iter().zip(reference.rest()) {
            assert!((p - q).norm() <= tol * q.norm().max(1e-3), "{f}: {p} vs {q}");
        }
    }
    // meshio keeps point data in VTK formats: the node set survives.
    for f in FROM_MESHIO.iter().filter(|f| !f.ends_with(".msh")) {
        let m = read_mesh(&dir.join(f)).unwrap();
        assert_eq!(m.node_set("inlet"), reference.node_set("inlet"), "{f}");
    }
}

#[test]
fn node_set_names_with_spaces_and_markup_and_empty_sets_survive() {
    let mut m = generate(&ArchParams::default(), 200).unwrap().mesh;
    m.set_node_set("wall face & <lumen>", vec![3, 1, 2]).unwrap();
    m.set_node_set("100% empty", vec![]).unwrap();
    let dir = tempfile::tempdir().unwrap();
    for file in ["n.msh", "n.vtk", "n.vtu"] {
        let p = dir.path().join(file);
        write_mesh(&m, &p).unwrap();
        let back = read_mesh(&p).unwrap_or_else(|e| panic!("{file}: {e}"));
        assert_eq!(back.node_sets(), m.node_sets(), "{file}");
        assert_eq!(back.node_set("wall face & <lumen>"), Some(&[1, 2, 3][..]), "{file}");
    }
}
