//! Malformed mesh files give errors that name the file, the line (or element,
//! cell, byte offset) and what is wrong, so a user can fix the input.

use nvtmm::mesh::io::{read_mesh, read_mesh_bytes, read_tetgen_bytes, Format, MeshError};
use std::path::Path;

fn err(format: Format, name: &str, text: &str) -> String {
    match read_mesh_bytes(format, Path::new(name), text.as_bytes(), 1.0) {
        Ok(_) => panic!("{name} should not parse:\n{text}"),
        Err(e) => e.to_string(),
    }
}

fn has(msg: &str, parts: &[&str]) {
    for p in parts {
        assert!(msg.contains(p), "expected '{p}' in: {msg}");
    }
}

const HEAD22: &str = "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n";
const NODES22: &str = "$Nodes\n5\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n5 1 1 1\n$EndNodes\n";

fn gmsh22(elements: &str) -> String {
    format!("{HEAD22}{NODES22}$Elements\n{elements}$EndElements\n")
}

#[test]
fn gmsh_non_tet_3d_element_names_its_tag_and_type() {
    // Line 15 holds element 7, a hexahedron.
    let e = err(
        Format::Gmsh,
        "h.msh",
        &gmsh22("2\n1 4 2 0 1 1 2 3 4\n7 5 2 0 1 1 2 3 4 5 1 2 3\n"),
    );
    has(&e, &["h.msh:15:", "element 7", "type 5", "hexahedron"]);
    let e = err(Format::Gmsh, "t.msh", &gmsh22("1\n3 11 2 0 1 1 2 3 4 5 1 2 3 4 5\n"));
    has(&e, &["element 3", "type 11", "10-node tetrahedron"]);
}

#[test]
fn gmsh41_prism_block_names_the_element() {
    let f = "$MeshFormat\n4.1 0 8\n$EndMeshFormat\n$Nodes\n1 6 1 6\n3 1 0 6\n1\n2\n3\n4\n5\n6\n\
             0 0 0\n1 0 0\n0 1 0\n0 0 1\n1 0 1\n0 1 1\n$EndNodes\n$Elements\n1 1 1 1\n3 1 6 1\n42 1 2 3 4 5 6\n$EndElements\n";
    let e = err(Format::Gmsh, "p.msh", f);
    has(&e, &["p.msh:", "element 42", "type 6", "prism"]);
}

#[test]
fn gmsh_bad_numbers_and_tags_name_the_line() {
    let f = format!("{HEAD22}$Nodes\n2\n1 0 0 0\n2 1 abc 0\n$EndNodes\n");
    has(
        &err(Format::Gmsh, "n.msh", &f),
        &["n.msh:7:", "node y coordinate", "'abc'"],
    );
    let f = format!("{HEAD22}$Nodes\n2\n1 0 0 0\n2 1 nan 0\n$EndNodes\n");
    has(&err(Format::Gmsh, "n.msh", &f), &["n.msh:7:", "not finite"]);
    let e = err(Format::Gmsh, "m.msh", &gmsh22("1\n1 4 2 0 1 1 2 3 99\n"));
    has(&e, &["m.msh:14:", "element 1", "node tag 99 is not in $Nodes"]);
    let f = format!("{HEAD22}$Nodes\n2\n1 0 0 0\n1 1 0 0\n$EndNodes\n");
    has(
        &err(Format::Gmsh, "d.msh", &f),
        &["d.msh:7:", "node tag 1 appears twice"],
    );
}

#[test]
fn gmsh_huge_declared_counts_fail_fast_without_allocating() {
    let f = format!("{HEAD22}$Nodes\n18446744073709551615\n1 0 0 0\n$EndNodes\n");
    has(
        &err(Format::Gmsh, "c.msh", &f),
        &["c.msh:7:", "expected a node tag", "'$EndNodes'"],
    );
    let f = "$MeshFormat\n4.1 0 8\n$EndMeshFormat\n$Nodes\n1 18446744073709551615 1 2\n3 1 0 18446744073709551615\n1\n";
    has(&err(Format::Gmsh, "c.msh", f), &["unexpected end of file"]);
    let f = "$MeshFormat\n4.1 0 99999999999999999999999\n$EndMeshFormat\n";
    has(&err(Format::Gmsh, "c.msh", f), &["c.msh:2:", "data size"]);
}

#[test]
fn gmsh_version_and_structure() {
    has(
        &err(Format::Gmsh, "v.msh", "$MeshFormat\n4.0 0 8\n$EndMeshFormat\n"),
        &["v.msh:2:", "version '4.0' is not supported"],
    );
    has(&err(Format::Gmsh, "e.msh", ""), &["e.msh:1:", "expected '$MeshFormat'"]);
    has(&err(Format::Gmsh, "x.msh", HEAD22), &["no $Nodes section"]);
    has(
        &err(Format::Gmsh, "u.msh", &format!("{HEAD22}$Stuff\n1 2 3\n")),
        &["u.msh:4:", "has no '$EndStuff'"],
    );
    let truncated = format!("{HEAD22}{NODES22}$Elements\n2\n1 4 2 0 1 1 2 3 4\n");
    has(
        &err(Format::Gmsh, "t.msh", &truncated),
        &["t.msh:", "unexpected end of file", "element tag"],
    );
}

#[test]
fn gmsh_binary_errors_give_the_byte_offset() {
    let mut b = b"$MeshFormat\n4.1 1 8\n".to_vec();
    b.extend_from_slice(&1i32.to_le_bytes());
    b.extend_from_slice(b"\n$EndMeshFormat\n$Nodes\n");
    b.extend_from_slice(&1u64.to_le_bytes());
    b.extend_from_slice(&[0, 1]);
    let e = read_mesh_bytes(Format::Gmsh, Path::new("b.msh"), &b, 1.0).unwrap_err();
    assert!(matches!(e, MeshError::Binary { .. }), "{e:?}");
    has(
        &e.to_string(),
        &["b.msh: byte ", "file ends inside", "the number of nodes"],
    );
}

#[test]
fn mesh_level_problems_name_the_file_and_tet() {
    let e = err(
        Format::Gmsh,
        "dup.msh",
        &gmsh22("2\n1 4 2 0 1 1 2 3 4\n2 4 2 0 1 4 3 2 1\n"),
    );
    has(&e, &["dup.msh:", "tet 1 duplicates tet 0"]);
    let f = format!("{HEAD22}$Nodes\n4\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 1 1 0\n$EndNodes\n$Elements\n1\n1 4 2 0 1 1 2 3 4\n$EndElements\n");
    has(&err(Format::Gmsh, "flat.msh", &f), &["flat.msh:", "tet 0: zero volume"]);
    has(
        &err(Format::Gmsh, "none.msh", &gmsh22("0\n")),
        &["none.msh:", "no tetrahedra"],
    );
    let e = err(Format::Gmsh, "rep.msh", &gmsh22("1\n1 4 2 0 1 1 2 2 4\n"));
    has(&e, &["rep.msh:", "tet 0: node 1 appears twice"]);
}

const VTK_HEAD: &str = "# vtk DataFile Version 3.0\nt\nASCII\nDATASET UNSTRUCTURED_GRID\n\
POINTS 5 double\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n1 1 1\n";

#[test]
fn vtk_cells_are_named_by_index() {
    let f = format!("{VTK_HEAD}CELLS 2 14\n4 0 1 2 3\n8 0 1 2 3 4 0 1 2\nCELL_TYPES 2\n10\n12\n");
    has(
        &err(Format::VtkLegacy, "h.vtk", &f),
        &["h.vtk:11:", "cell 1", "VTK_HEXAHEDRON"],
    );
    let f = format!("{VTK_HEAD}CELLS 2 9\n3 0 1 2\n4 0 1 2 9\nCELL_TYPES 2\n5\n10\n");
    has(
        &err(Format::VtkLegacy, "r.vtk", &f),
        &["r.vtk:11:", "cell 1", "point index 9 is out of range"],
    );
    let f = format!("{VTK_HEAD}CELLS 1 5\n4 0 1 2 3\nCELL_TYPES 1\n99\n");
    has(
        &err(Format::VtkLegacy, "u.vtk", &f),
        &["cell 0", "unknown cell type 99"],
    );
    let f = format!("{VTK_HEAD}CELLS 1 5\n4 0 1 2 3\nCELL_TYPES 2\n10 10\n");
    has(
        &err(Format::VtkLegacy, "c.vtk", &f),
        &["c.vtk:13:", "CELL_TYPES has 2 entries but CELLS has 1"],
    );
}

#[test]
fn vtk_bad_values_name_the_line() {
    let f = VTK_HEAD.replace("0 1 0\n", "0 x 0\n");
    has(
        &err(Format::VtkLegacy, "x.vtk", &f),
        &["x.vtk:8:", "point coordinates", "'x'"],
    );
    let f = VTK_HEAD.replace("0 1 0\n", "0 inf 0\n");
    has(
        &err(Format::VtkLegacy, "i.vtk", &f),
        &["i.vtk:5:", "point 2", "not finite"],
    );
    has(
        &err(Format::VtkLegacy, "n.vtk", "hello\n"),
        &["n.vtk:1:", "not a VTK legacy file"],
    );
    has(
        &err(
            Format::VtkLegacy,
            "s.vtk",
            &VTK_HEAD.replace("UNSTRUCTURED_GRID", "POLYDATA"),
        ),
        &["s.vtk:4:", "'POLYDATA' is not supported"],
    );
    let f = format!("{VTK_HEAD}CELLS 18446744073709551615 18446744073709551615\n4 0 1 2 3\n");
    has(
        &err(Format::VtkLegacy, "h.vtk", &f),
        &["h.vtk:", "unexpected end of file"],
    );
}

const VTU: &str = r#"<?xml version="1.0"?>
<VTKFile type="UnstructuredGrid" version="1.0">
  <UnstructuredGrid>
    <Piece NumberOfPoints="4" NumberOfCells="1">
      <Points>
        <DataArray type="Float64" NumberOfComponents="3" format="ascii">
0 0 0
1 0 0
0 1 0
0 0 1
        </DataArray>
      </Points>
      <Cells>
        <DataArray type="Int64" Name="connectivity" format="ascii">0 1 2 3</DataArray>
        <DataArray type="Int64" Name="offsets" format="ascii">4</DataArray>
        <DataArray type="UInt8" Name="types" format="ascii">10</DataArray>
      </Cells>
    </Piece>
  </UnstructuredGrid>
</VTKFile>
"#;

#[test]
fn vtu_errors_name_the_line() {
    read_mesh_bytes(Format::Vtu, Path::new("ok.vtu"), VTU.as_bytes(), 1.0).unwrap();
    has(
        &err(Format::Vtu, "b.vtu", &VTU.replace("1 0 0\n", "1 zz 0\n")),
        &["b.vtu:8:", "'zz'"],
    );
    has(
        &err(
            Format::Vtu,
            "f.vtu",
            &VTU.replace("format=\"ascii\">0 1", "format=\"binary\">0 1"),
        ),
        &["f.vtu:14:", "DataArray 'connectivity'", "base64 data ends early"],
    );
    has(
        &err(Format::Vtu, "t.vtu", &VTU.replace(">10<", ">12<")),
        &["t.vtu:14:", "cell 0", "VTK_HEXAHEDRON"],
    );
    has(
        &err(Format::Vtu, "m.vtu", &VTU.replace("Name=\"offsets\"", "Name=\"offs\"")),
        &["m.vtu:4:", "no Cells DataArray named 'offsets'"],
    );
    has(
        &err(Format::Vtu, "c.vtu", &VTU[..300]),
        &["c.vtu:13:", "unterminated tag"],
    );
    has(&err(Format::Vtu, "e.vtu", ""), &["e.vtu:1:", "no <VTKFile>"]);
}

fn tetgen_err(node: &str, ele: &str) -> String {
    read_tetgen_bytes(
        Path::new("m.node"),
        node.as_bytes(),
        Path::new("m.ele"),
        ele.as_bytes(),
        1.0,
    )
    .unwrap_err()
    .to_string()
}

#[test]
fn tetgen_errors_name_file_and_line() {
    let node1 = "# one-based\n4 3 0 0\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n";
    has(
        &tetgen_err(node1, "1 4 0\n1 0 1 2 3\n"),
        &["m.ele:2:", "tetrahedron 1: point 0 does not exist"],
    );
    has(
        &tetgen_err(node1, "1 10 0\n"),
        &["m.ele:1:", "10 nodes per tetrahedron"],
    );
    let bad_seq = node1.replace("3 0 1 0", "7 0 1 0");
    has(
        &tetgen_err(&bad_seq, "1 4 0\n1 1 2 3 4\n"),
        &["m.node:5:", "point number 7 is out of sequence"],
    );
    has(&tetgen_err("4 2 0 0\n", ""), &["m.node:1:", "dimension 2"]);
    // The sibling file must exist.
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("only.node");
    std::fs::write(&p, node1).unwrap();
    let e = read_mesh(&p).unwrap_err().to_string();
    has(&e, &["only.ele"]);
}

#[test]
fn surface_files_and_unknown_extensions_are_refused() {
    let e = read_mesh(Path::new("x.stl")).unwrap_err().to_string();
    has(&e, &["x.stl", "surface-only"]);
    let e = read_mesh(Path::new("x.foo")).unwrap_err().to_string();
    has(&e, &["x.foo", "unknown mesh format"]);
}

#[test]
fn scale_must_be_finite_and_positive() {
    let f = gmsh22("1\n1 4 2 0 1 1 2 3 4\n");
    read_mesh_bytes(Format::Gmsh, Path::new("ok.msh"), f.as_bytes(), 1e-3).unwrap();
    for s in [0.0, -1.0, f64::NAN, f64::INFINITY] {
        let e = read_mesh_bytes(Format::Gmsh, Path::new("s.msh"), f.as_bytes(), s).unwrap_err();
        has(&e.to_string(), &["s.msh:", "must be finite and positive"]);
    }
}

#[test]
fn vtu_values_after_information_keys_are_read() {
    // VTK 9 writes <InformationKey> elements before the values of some arrays.
    let f = VTU.replace(
        "format=\"ascii\">\n0 0 0\n",
        "format=\"ascii\">\n<InformationKey name=\"L2_NORM_RANGE\" location=\"vtkDataArray\" length=\"2\">\n\
         <Value index=\"0\">\n0\n</Value>\n<Value index=\"1\">\n1\n</Value>\n</InformationKey>\n0 0 0\n",
    );
    let m = read_mesh_bytes(Format::Vtu, Path::new("k.vtu"), f.as_bytes(), 1.0).unwrap();
    assert_eq!(m.num_nodes(), 4);
    let bad = f.replace("0 1 0\n0 0 1", "0 1 0\n0 q 1");
    has(&err(Format::Vtu, "k.vtu", &bad), &["k.vtu:18:", "'q'"]);
}
