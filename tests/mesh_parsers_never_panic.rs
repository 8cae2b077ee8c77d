//! No reader panics (or allocates from a header count) on any input: random
//! bytes and random edits of valid files of every readable format must give
//! Ok or Err. Case counts are kept modest so this runs in seconds in release.

use nvtmm::mesh::arch::{generate, ArchParams};
use nvtmm::mesh::io::{read_mesh_bytes, read_tetgen_bytes, write_mesh, write_tetgen, Format};
use proptest::prelude::*;
use std::path::Path;
use std::sync::OnceLock;

/// Valid files to mutate: (format, bytes). TetGen is the pair (node, ele).
struct Corpus {
    files: Vec<(Format, Vec<u8>)>,
    tetgen: (Vec<u8>, Vec<u8>),
}

fn corpus() -> &'static Corpus {
    static C: OnceLock<Corpus> = OnceLock::new();
    C.get_or_init(|| {
        let m = generate(&ArchParams::default(), 120).unwrap().mesh;
        let dir = tempfile::tempdir().unwrap();
        let mut files = Vec::new();
        for (name, f) in [
            ("a.msh", Format::Gmsh),
            ("a.vtk", Format::VtkLegacy),
            ("a.vtu", Format::Vtu),
        ] {
            let p = dir.path().join(name);
            write_mesh(&m, &p).unwrap();
            files.push((f, std::fs::read(&p).unwrap()));
        }
        files.push((Format::Gmsh, GMSH22.as_bytes().to_vec()));
        files.push((Format::Gmsh, gmsh41_binary()));
        files.push((Format::VtkLegacy, vtk_binary()));
        // Files from another writer (meshio), incl. binary Gmsh 4.1 and VTK 5.1.
        let fixtures = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/meshio");
        for name in [
            "mio22.msh",
            "mio41a.msh",
            "mio41b.msh",
            "mioa.vtk",
            "miob.vtk",
            "mio.vtu",
            "mio_zlib.vtu",
            "appended_raw.vtu",
            "appended_zlib.vtu",
        ] {
            let p = fixtures.join(name);
            files.push((Format::from_path(&p).unwrap(), std::fs::read(&p).unwrap()));
        }
        let p = dir.path().join("a.node");
        write_tetgen(&m, &p, 1).unwrap();
        let tetgen = (
            std::fs::read(&p).unwrap(),
            std::fs::read(p.with_extension("ele")).unwrap(),
        );
        Corpus { files, tetgen }
    })
}

const GMSH22: &str = "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$PhysicalNames\n2\n0 7 \"tip\"\n3 9 \"tissue\"\n\
$EndPhysicalNames\n$Nodes\n5\n10 0 0 0\n20 1 0 0\n30 0 1 0\n40 0 0 1\n50 1 1 1\n$EndNodes\n$Elements\n4\n\
1 15 2 7 1 50\n2 2 2 0 1 10 20 30\n3 4 2 9 1 10 20 30 40\n4 4 2 9 1 20 30 40 50\n$EndElements\n";

fn gmsh41_binary() -> Vec<u8> {
    let mut b = b"$MeshFormat\n4.1 1 8\n".to_vec();
    b.extend_from_slice(&1i32.to_le_bytes());
    b.extend_from_slice(b"\n$EndMeshFormat\n$PhysicalNames\n1\n3 9 \"tissue\"\n$EndPhysicalNames\n$Entities\n");
    let sz = |b: &mut Vec<u8>, v: u64| b.extend_from_slice(&v.to_le_bytes());
    let int = |b: &mut Vec<u8>, v: i32| b.extend_from_slice(&v.to_le_bytes());
    for n in [0, 0, 0, 1] {
        sz(&mut b, n);
    }
    int(&mut b, 1);
    for v in [0.0f64, 0.0, 0.0, 1.0, 1.0, 1.0] {
        b.extend_from_slice(&v.to_le_bytes());
    }
    sz(&mut b, 1);
    int(&mut b, 9);
    sz(&mut b, 0);
    b.extend_from_slice(b"\n$EndEntities\n$Nodes\n");
    for v in [1, 5, 1, 5] {
        sz(&mut b, v);
    }
    for v in [3, 1, 0] {
        int(&mut b, v);
    }
    sz(&mut b, 5);
    for t in 1..=5 {
        sz(&mut b, t);
    }
    for v in [0., 0., 0., 1., 0., 0., 0., 1., 0., 0., 0., 1., 1., 1., 1.] {
        b.extend_from_slice(&f64::to_le_bytes(v));
    }
    b.extend_from_slice(b"\n$EndNodes\n$Elements\n");
    for v in [1, 2, 1, 2] {
        sz(&mut b, v);
    }
    for v in [3, 1, 4] {
        int(&mut b, v);
    }
    sz(&mut b, 2);
    for v in [1, 1, 2, 3, 4, 2, 2, 3, 4, 5] {
        sz(&mut b, v);
    }
    b.extend_from_slice(b"\n$EndElements\n");
    b
}

fn vtk_binary() -> Vec<u8> {
    let mut b = b"# vtk DataFile Version 3.0\nx\nBINARY\nDATASET UNSTRUCTURED_GRID\nPOINTS 5 float\n".to_vec();
    for v in [0f32, 0., 0., 1., 0., 0., 0., 1., 0., 0., 0., 1., 1., 1., 1.] {
        b.extend_from_slice(&v.to_be_bytes());
    }
    b.extend_from_slice(b"\nCELLS 2 10\n");
    for v in [4, 0, 1, 2, 3, 4, 1, 2, 3, 4] {
        b.extend_from_slice(&i32::to_be_bytes(v));
    }
    b.extend_from_slice(b"\nCELL_TYPES 2\n");
    for v in [10, 10] {
        b.extend_from_slice(&i32::to_be_bytes(v));
    }
    b.extend_from_slice(b"\nPOINT_DATA 5\nSCALARS set_a int\nLOOKUP_TABLE default\n");
    for v in [0, 1, 0, 1, 0] {
        b.extend_from_slice(&i32::to_be_bytes(v));
    }
    b.push(b'\n');
    b
}

/// Values that break naive parsers when they replace a number.
const NASTY: &[&str] = &[
    "18446744073709551615",
    "99999999999999999999999",
    "4294967296",
    "2147483648",
    "-1",
    "-2147483649",
    "NaN",
    "inf",
    "-inf",
    "1e308",
    "-1e308",
    "0",
    "1e-320",
    "x",
    "",
    "3.5",
];

/// One edit of a file.
#[derive(Debug, Clone)]
enum Edit {
    Truncate(usize),
    Flip(usize, u8),
    DeleteLine(usize),
    DuplicateLine(usize),
    ReplaceNumber(usize, usize),
    Insert(usize, Vec<u8>),
}

fn edit() -> impl Strategy<Value = Edit> {
    prop_oneof![
        any::<usize>().prop_map(Edit::Truncate),
        (any::<usize>(), 1u8..=255).prop_map(|(i, x)| Edit::Flip(i, x)),
        any::<usize>().prop_map(Edit::DeleteLine),
        any::<usize>().prop_map(Edit::DuplicateLine),
        (any::<usize>(), 0..NASTY.len()).prop_map(|(i, k)| Edit::ReplaceNumber(i, k)),
        (any::<usize>(), proptest::collection::vec(any::<u8>(), 1..12)).prop_map(|(i, b)| Edit::Insert(i, b)),
    ]
}

/// Byte ranges of each line (including its newline).
fn lines(b: &[u8]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut start = 0;
    for (i, &c) in b.iter().enumerate() {
        if c == b'\n' {
            out.push((start, i + 1));
            start = i + 1;
        }
    }
    if start < b.len() {
        out.push((start, b.len()));
    }
    out
}

/// Byte ranges of numeric-looking tokens.
fn numbers(b: &[u8]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut i = 0;
    while i < b.len() {
        if b[i].is_ascii_digit() || b[i] == b'-' {
            let s = i;
            while i < b.len() && (b[i].is_ascii_alphanumeric() || b"+-.".contains(&b[i])) {
                i += 1;
            }
            out.push((s, i));
        } else {
            i += 1;
        }
    }
    out
}

fn apply(mut b: Vec<u8>, e: &Edit) -> Vec<u8> {
    if b.is_empty() {
        return b;
    }
    match e {
        Edit::Truncate(i) => b.truncate(i % b.len()),
        Edit::Flip(i, x) => {
            let n = b.len();
            b[i % n] ^= x;
        }
        Edit::DeleteLine(i) | Edit::DuplicateLine(i) => {
            let ls = lines(&b);
            let (s, t) = ls[i % ls.len()];
            if matches!(e, Edit::DeleteLine(_)) {
                b.drain(s..t);
            } else {
                let l = b[s..t].to_vec();
                b.splice(s..s, l);
            }
        }
        Edit::ReplaceNumber(i, k) => {
            let ns = numbers(&b);
            if !ns.is_empty() {
                let (s, t) = ns[i % ns.len()];
                b.splice(s..t, NASTY[*k].bytes());
            }
        }
        Edit::Insert(i, bytes) => {
            let n = b.len();
            b.splice(i % n..i % n, bytes.iter().copied());
        }
    }
    b
}

fn read_any(format: Format, bytes: &[u8]) {
    // The result does not matter, only that there is one.
    let _ = read_mesh_bytes(format, Path::new("fuzz"), bytes, 1.0);
}

const FORMATS: [Format; 3] = [Format::Gmsh, Format::VtkLegacy, Format::Vtu];

proptest! {
    #![proptest_config(ProptestConfig { cases: 1000, failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn random_bytes(bytes in proptest::collection::vec(any::<u8>(), 0..2048), f in 0usize..3) {
        read_any(FORMATS[f], &bytes);
        let _ = read_tetgen_bytes(Path::new("f.node"), &bytes, Path::new("f.ele"), &bytes, 1.0);
    }

    #[test]
    fn random_bytes_after_a_valid_header(tail in proptest::collection::vec(any::<u8>(), 0..512), f in any::<prop::sample::Index>()) {
        let (format, good) = f.get(&corpus().files);
        let mut b = good[..good.len().min(40)].to_vec();
        b.extend_from_slice(&tail);
        read_any(*format, &b);
    }

    #[test]
    fn edits_of_valid_files(f in any::<prop::sample::Index>(), edits in proptest::collection::vec(edit(), 1..4)) {
        let (format, good) = f.get(&corpus().files);
        let mut b = good.clone();
        for e in &edits {
            b = apply(b, e);
        }
        read_any(*format, &b);
    }

    #[test]
    fn edits_of_valid_tetgen_pairs(which in any::<bool>(), edits in proptest::collection::vec(edit(), 1..4)) {
        let (node, ele) = &corpus().tetgen;
        let (mut n, mut e) = (node.clone(), ele.clone());
        let target = if which { &mut n } else { &mut e };
        for ed in &edits {
            *target = apply(std::mem::take(target), ed);
        }
        let _ = read_tetgen_bytes(Path::new("f.node"), &n, Path::new("f.ele"), &e, 1.0);
    }
}

#[test]
fn corpus_files_are_valid() {
    for (f, b) in &corpus().files {
        read_mesh_bytes(*f, Path::new("good"), b, 1.0).unwrap_or_else(|e| panic!("{f:?}: {e}"));
    }
    let (n, e) = &corpus().tetgen;
    read_tetgen_bytes(Path::new("f.node"), n, Path::new("f.ele"), e, 1.0).unwrap();
}
