//! VTK legacy `.vtk` unstructured grids: reads ASCII and big-endian BINARY
//! (classic `CELLS n size` and the 5.x `OFFSETS`/`CONNECTIVITY` layout),
//! writes ASCII.
//!
//! Node sets travel as `POINT_DATA` integer `SCALARS` named `set_<name>`
//! (non-zero = member; spaces in names escaped as `%20`, as VTK does). Other
//! point and cell data are skipped.

use super::scan::{quote, Endian, Scan};
use super::{write_file, MeshError, RawMesh};
use crate::math::Vec3;
use crate::mesh::TetMesh;
use std::collections::BTreeMap;
use std::io::Write;
use std::path::Path;

/// VTK_TETRA.
const VTK_TETRA: i64 = 10;

/// Prefix of point-data arrays that hold node sets (shared with `.vtu`).
pub(crate) const SET_PREFIX: &str = "set_";

/// Lower-dimensional VTK cell types (skipped on read).
fn is_lower_dim(ty: i64) -> bool {
    matches!(
        ty,
        0..=9 | 21 | 22 | 23 | 28 | 30 | 34 | 35 | 36 | 68 | 69 | 70 | 75 | 76 | 77
    )
}

/// Name of a VTK 3-D cell type other than VTK_TETRA, if it is one.
pub(crate) fn solid_cell_name(ty: i64) -> Option<&'static str> {
    Some(match ty {
        11 => "VTK_VOXEL",
        12 => "VTK_HEXAHEDRON",
        13 => "VTK_WEDGE",
        14 => "VTK_PYRAMID",
        15 => "VTK_PENTAGONAL_PRISM",
        16 => "VTK_HEXAGONAL_PRISM",
        24 => "VTK_QUADRATIC_TETRA",
        25 => "VTK_QUADRATIC_HEXAHEDRON",
        26 => "VTK_QUADRATIC_WEDGE",
        27 => "VTK_QUADRATIC_PYRAMID",
        29 => "VTK_TRIQUADRATIC_HEXAHEDRON",
        31 => "VTK_QUADRATIC_LINEAR_WEDGE",
        32 => "VTK_BIQUADRATIC_QUADRATIC_WEDGE",
        33 => "VTK_BIQUADRATIC_QUADRATIC_HEXAHEDRON",
        37 => "VTK_TRIQUADRATIC_PYRAMID",
        41 => "VTK_CONVEX_POINT_SET",
        42 => "VTK_POLYHEDRON",
        71 => "VTK_LAGRANGE_TETRAHEDRON",
        72 => "VTK_LAGRANGE_HEXAHEDRON",
        73 => "VTK_LAGRANGE_WEDGE",
        74 => "VTK_LAGRANGE_PYRAMID",
        78 => "VTK_BEZIER_TETRAHEDRON",
        79 => "VTK_BEZIER_HEXAHEDRON",
        80 => "VTK_BEZIER_WEDGE",
        81 => "VTK_BEZIER_PYRAMID",
        _ => return None,
    })
}

/// Turns cells (connectivity per cell + type) into tets, skipping
/// lower-dimensional cells; shared by `.vtk` and `.vtu`. `line` locates the
/// cell data for error messages.
pub(crate) fn cells_to_tets(
    path: &Path,
    line: usize,
    cells: &[&[i64]],
    types: &[i64],
    nodes: usize,
) -> Result<Vec<[u32; 4]>, MeshError> {
    let err = |cell: usize, msg: String| MeshError::Element {
        path: path.to_path_buf(),
        line,
        kind: "cell",
        element: cell as u64,
        msg,
    };
    let mut tets = Vec::new();
    for (c, (conn, &ty)) in cells.iter().zip(types).enumerate() {
        for &v in conn.iter() {
            if v < 0 || v as u64 >= nodes as u64 {
                return Err(err(
                    c,
                    format!("point index {v} is out of range (the file has {nodes} points)"),
                ));
            }
        }
        if ty == VTK_TETRA {
            match **conn {
                [a, b, cc, d] => tets.push([a as u32, b as u32, cc as u32, d as u32]),
                _ => return Err(err(c, format!("VTK_TETRA with {} points (expected 4)", conn.len()))),
            }
        } else if let Some(name) = solid_cell_name(ty) {
            return Err(err(
                c,
                format!(
                    "cell type {ty} ({name}) is a 3-D cell other than VTK_TETRA (10); only linear tets are supported"
                ),
            ));
        } else if !is_lower_dim(ty) {
            return Err(err(c, format!("unknown cell type {ty}")));
        }
    }
    Ok(tets)
}

/// Reads a data array of `n` values of VTK type `ty`, as text or big-endian binary.
pub(crate) struct Arrays {
    pub(crate) binary: bool,
}

impl Arrays {
    pub(crate) fn size_of(s: &Scan, ty: &str) -> Result<usize, MeshError> {
        Ok(match ty {
            "bit" => return Err(s.err("data type 'bit' is not supported")),
            "char" | "unsigned_char" => 1,
            "short" | "unsigned_short" => 2,
            "int" | "unsigned_int" | "float" | "vtktypeint32" | "vtktypeuint32" => 4,
            "long" | "unsigned_long" | "double" | "vtktypeint64" | "vtktypeuint64" => 8,
            t => return Err(s.err(format!("unknown data type '{}'", quote(t)))),
        })
    }

    /// Integer values (indices, counts, cell types).
    pub(crate) fn ints(&self, s: &mut Scan, n: u64, ty: &str, what: &str) -> Result<Vec<i64>, MeshError> {
        let size = Self::size_of(s, ty)?;
        if matches!(ty, "float" | "double") {
            return Err(s.err(format!("{what} must be integers, not '{ty}'")));
        }
        let mut v = Vec::with_capacity(s.cap(n, if self.binary { size } else { 2 }));
        if self.binary {
            for _ in 0..n {
                let b = s.bytes(size, what)?;
                let x = if ty.starts_with("unsigned") || ty == "vtktypeuint64" || ty == "vtktypeuint32" {
                    i64::try_from(Endian::Big.u64(b)).unwrap_or(i64::MAX)
                } else {
                    Endian::Big.i64(b)
                };
                v.push(x);
            }
        } else {
            for _ in 0..n {
                v.push(s.i64(what)?);
            }
        }
        Ok(v)
    }

    /// Real values (coordinates, data).
    pub(crate) fn reals(&self, s: &mut Scan, n: u64, ty: &str, what: &str) -> Result<Vec<f64>, MeshError> {
        let size = Self::size_of(s, ty)?;
        let mut v = Vec::with_capacity(s.cap(n, if self.binary { size } else { 2 }));
        if self.binary {
            for _ in 0..n {
                let b = s.bytes(size, what)?;
                v.push(match ty {
                    "float" => Endian::Big.f32(b),
                    "double" => Endian::Big.f64(b),
                    _ => Endian::Big.i64(b) as f64,
                });
            }
        } else {
            for _ in 0..n {
                v.push(s.f64(what)?);
            }
        }
        Ok(v)
    }

    /// Values to skip.
    pub(crate) fn skip(&self, s: &mut Scan, n: u64, ty: &str, what: &str) -> Result<(), MeshError> {
        if self.binary {
            let size = Self::size_of(s, ty)?;
            let bytes = n.checked_mul(size as u64).and_then(|b| usize::try_from(b).ok());
            let Some(bytes) = bytes else {
                return Err(s.bin_err(format!("{what}: {n} values cannot fit in the file")));
            };
            s.bytes(bytes, what)?;
        } else {
            for _ in 0..n {
                s.token(what)?;
            }
        }
        Ok(())
    }

    /// Ends a header line before data (binary data starts right after its newline).
    pub(crate) fn start_data(&self, s: &mut Scan) {
        if self.binary {
            s.rest_of_line();
        }
    }
}

fn unescape(name: &str) -> String {
    name.replace("%20", " ").replace("%25", "%")
}

fn escape(name: &str) -> String {
    name.chars()
        .map(|c| match c {
            '%' => "%25".to_string(),
            c if c.is_whitespace() => "%20".to_string(),
            c => c.to_string(),
        })
        .collect()
}

/// Reads a legacy VTK file's header (version line, title, encoding) up to
/// its `DATASET` keyword; returns the arrays' encoding and the dataset type.
pub(crate) fn legacy_header<'a>(s: &mut Scan<'a>) -> Result<(Arrays, &'a str), MeshError> {
    let header = s.rest_of_line();
    if !header.starts_with(b"# vtk DataFile") {
        return Err(s.err_at(
            1,
            "not a VTK legacy file (the first line must start with '# vtk DataFile')",
        ));
    }
    s.rest_of_line(); // title
    let enc = s.token("ASCII or BINARY")?;
    let arrays = match enc.to_ascii_uppercase().as_str() {
        "ASCII" => Arrays { binary: false },
        "BINARY" => Arrays { binary: true },
        _ => return Err(s.err(format!("expected ASCII or BINARY, found '{}'", quote(enc)))),
    };
    s.expect("DATASET")?;
    Ok((arrays, s.token("the dataset type")?))
}

pub(super) fn read(path: &Path, data: &[u8]) -> Result<RawMesh, MeshError> {
    let mut s = Scan::new(path, data);
    let (arrays, ds) = legacy_header(&mut s)?;
    if ds != "UNSTRUCTURED_GRID" {
        return Err(s.err(format!(
            "dataset '{}' is not supported (only UNSTRUCTURED_GRID holds tets)",
            quote(ds)
        )));
    }
    let mut points: Option<Vec<Vec3>> = None;
    let mut cells: Option<(usize, Vec<i64>, Vec<usize>)> = None; // (line, connectivity, offsets)
    let mut types: Option<(usize, Vec<i64>)> = None;
    let mut sets = BTreeMap::new();
    while !s.at_eof() {
        let line = s.line();
        let kw = s.token("a keyword")?;
        match kw {
            "POINTS" => {
                let n = s.u64("the number of points")?;
                let ty = s.token("the point data type")?;
                arrays.start_data(&mut s);
                let v = arrays.reals(&mut s, n.saturating_mul(3), ty, "point coordinates")?;
                let mut pts = Vec::with_capacity(v.len() / 3);
                for (i, c) in v.chunks_exact(3).enumerate() {
                    let p = Vec3::new(c[0], c[1], c[2]);
                    if let Some(k) = (0..3).find(|&k| !p[k].is_finite()) {
                        return Err(s.err_at(
                            line,
                            format!("point {i}: coordinate {} is not finite ({})", ["x", "y", "z"][k], p[k]),
                        ));
                    }
                    pts.push(p);
                }
                points = Some(pts);
            }
            "CELLS" => {
                let (conn, offsets) = cell_list(&mut s, &arrays, line, "cell")?;
                cells = Some((line, conn, offsets));
            }
            "CELL_TYPES" => {
                let n = s.u64("the number of cell types")?;
                arrays.start_data(&mut s);
                types = Some((line, arrays.ints(&mut s, n, "int", "cell types")?));
            }
            "POINT_DATA" | "CELL_DATA" => {
                let n = s.u64("the number of data values")?;
                let is_point = kw == "POINT_DATA";
                let npts = points.as_ref().map_or(0, Vec::len) as u64;
                if is_point && n != npts {
                    return Err(s.err_at(line, format!("POINT_DATA {n} but the file has {npts} points")));
                }
                attributes(&mut s, &arrays, n, is_point, &mut sets)?;
            }
            "FIELD" => field(&mut s, &arrays, None)?,
            "METADATA" => metadata(&mut s),
            k => return Err(s.err(format!("unknown keyword '{}'", quote(k)))),
        }
    }
    let Some(points) = points else {
        return Err(s.err("no POINTS section"));
    };
    let Some((cline, conn, offsets)) = cells else {
        return Err(s.err("no CELLS section"));
    };
    let Some((tline, types)) = types else {
        return Err(s.err("no CELL_TYPES section"));
    };
    let ncells = offsets.len().saturating_sub(1);
    if types.len() != ncells {
        return Err(s.err_at(
            tline,
            format!("CELL_TYPES has {} entries but CELLS has {ncells} cells", types.len()),
        ));
    }
    let cell_list: Vec<&[i64]> = offsets.windows(2).map(|w| &conn[w[0]..w[1]]).collect();
    let tets = cells_to_tets(path, cline, &cell_list, &types, points.len())?;
    Ok(RawMesh {
        nodes: points,
        tets,
        sets,
    })
}

/// The cell list after a `CELLS` (or, in polydata, `POLYGONS`,
/// `TRIANGLE_STRIPS`, `VERTICES`, `LINES`) keyword: the classic layout `n
/// size` then per cell a count and its indices, or the 5.x layout `nOffsets
/// nConnectivity` then `OFFSETS` and `CONNECTIVITY` arrays. Returns the
/// connectivity and the offsets (one more than the cells, from 0). `line` is
/// the keyword's line; `kind` names a cell in errors.
pub(crate) fn cell_list(
    s: &mut Scan,
    arrays: &Arrays,
    line: usize,
    kind: &str,
) -> Result<(Vec<i64>, Vec<usize>), MeshError> {
    let a = s.u64(&format!("the number of {kind}s"))?;
    let b = s.u64(&format!("the size of the {kind} list"))?;
    if s.peek() == Some("OFFSETS") {
        // VTK 5.x: `CELLS nOffsets nConnectivity` then two arrays.
        s.expect("OFFSETS")?;
        let ty = s.token("the offsets data type")?;
        arrays.start_data(s);
        let off = arrays.ints(s, a, ty, &format!("{kind} offsets"))?;
        s.expect("CONNECTIVITY")?;
        let ty = s.token("the connectivity data type")?;
        arrays.start_data(s);
        let conn = arrays.ints(s, b, ty, &format!("{kind} connectivity"))?;
        let mut offsets = Vec::with_capacity(off.len());
        for (i, &o) in off.iter().enumerate() {
            if o < 0 || o as u64 > b || offsets.last().is_some_and(|&l| (o as usize) < l) {
                return Err(s.err_at(line, format!("{kind} offset {i} ({o}) is out of order or range")));
            }
            offsets.push(o as usize);
        }
        if offsets.first().is_some_and(|&o| o != 0) || offsets.last().is_some_and(|&o| o != conn.len()) {
            return Err(s.err_at(
                line,
                format!("{kind} offsets must start at 0 and end at the connectivity length"),
            ));
        }
        if offsets.is_empty() {
            offsets.push(0);
        }
        Ok((conn, offsets))
    } else {
        arrays.start_data(s);
        let list = arrays.ints(s, b, "int", &format!("the {kind} list"))?;
        // Classic layout: per cell, a count then that many indices.
        let mut conn = Vec::with_capacity(list.len());
        let mut offsets = vec![0usize];
        let mut i = 0usize;
        for c in 0..a {
            let Some(&k) = list.get(i) else {
                return Err(s.err_at(line, format!("the {kind} list ends before {kind} {c} (of {a})")));
            };
            let k = usize::try_from(k).ok().filter(|&k| k < list.len() - i);
            let Some(k) = k else {
                return Err(s.err_at(
                    line,
                    format!("{kind} {c}: point count is negative or overruns the list"),
                ));
            };
            conn.extend_from_slice(&list[i + 1..i + 1 + k]);
            offsets.push(conn.len());
            i += 1 + k;
        }
        if i != list.len() {
            return Err(s.err_at(
                line,
                format!("the {kind} list has {} values but {a} {kind}s use {i}", list.len()),
            ));
        }
        Ok((conn, offsets))
    }
}

/// The attributes after `POINT_DATA n` / `CELL_DATA n`, until the next
/// dataset keyword. Point `SCALARS set_*` become node sets.
pub(crate) fn attributes(
    s: &mut Scan,
    arrays: &Arrays,
    n: u64,
    is_point: bool,
    sets: &mut BTreeMap<String, Vec<u32>>,
) -> Result<(), MeshError> {
    loop {
        let Some(kw) = s.peek() else { return Ok(()) };
        match kw {
            "SCALARS" => {
                s.token("SCALARS")?;
                let name = unescape(s.token("the array name")?);
                let ty = s.token("the data type")?;
                // Optional component count, then LOOKUP_TABLE.
                let mut ncomp = 1u64;
                if s.peek() != Some("LOOKUP_TABLE") {
                    ncomp = s.u64("the number of components")?;
                    if !(1..=4).contains(&ncomp) {
                        return Err(s.err(format!("SCALARS with {ncomp} components (1 to 4 allowed)")));
                    }
                }
                s.expect("LOOKUP_TABLE")?;
                s.token("the lookup table name")?;
                arrays.start_data(s);
                let total = n.saturating_mul(ncomp);
                match name.strip_prefix(SET_PREFIX) {
                    Some(set) if is_point && ncomp == 1 => {
                        let v = arrays.reals(s, total, ty, "node set values")?;
                        sets.insert(set.to_string(), members(&v));
                    }
                    _ => arrays.skip(s, total, ty, "scalar values")?,
                }
            }
            "LOOKUP_TABLE" => {
                s.token("LOOKUP_TABLE")?;
                s.token("the table name")?;
                let size = s.u64("the table size")?;
                arrays.start_data(s);
                // RGBA: 4 floats in ASCII, 4 unsigned chars in binary.
                let ty = if arrays.binary { "unsigned_char" } else { "float" };
                arrays.skip(s, size.saturating_mul(4), ty, "lookup table values")?;
            }
            "VECTORS" | "NORMALS" | "TENSORS" | "TEXTURE_COORDINATES" | "COLOR_SCALARS" => {
                s.token("an attribute")?;
                s.token("the array name")?;
                let (per, ty) = match kw {
                    "VECTORS" | "NORMALS" => (3, s.token("the data type")?),
                    "TENSORS" => (9, s.token("the data type")?),
                    "TEXTURE_COORDINATES" => (s.u64("the dimension")?.min(3), s.token("the data type")?),
                    // COLOR_SCALARS: floats in ASCII, unsigned chars in binary.
                    _ => (
                        s.u64("the number of values")?.min(4),
                        if arrays.binary { "unsigned_char" } else { "float" },
                    ),
                };
                arrays.start_data(s);
                arrays.skip(s, n.saturating_mul(per), ty, "attribute values")?;
            }
            "FIELD" => {
                s.token("FIELD")?;
                field(s, arrays, is_point.then_some((n, &mut *sets)))?;
            }
            "METADATA" => {
                s.token("METADATA")?;
                metadata(s);
            }
            _ => return Ok(()),
        }
    }
}

/// `FIELD name count` then per array `name ncomp ntuples type` and values.
/// With `sets` (inside `POINT_DATA n`), one-component arrays `set_<name>` of
/// `n` tuples become node sets (meshio writes point data this way).
pub(crate) fn field(
    s: &mut Scan,
    arrays: &Arrays,
    mut sets: Option<(u64, &mut BTreeMap<String, Vec<u32>>)>,
) -> Result<(), MeshError> {
    s.token("the field name")?;
    let count = s.u64("the number of field arrays")?;
    for _ in 0..count {
        let name = unescape(s.token("the field array name")?);
        let ncomp = s.u64("the number of components")?;
        let ntup = s.u64("the number of tuples")?;
        let ty = s.token("the data type")?;
        arrays.start_data(s);
        match (name.strip_prefix(SET_PREFIX), sets.as_mut()) {
            (Some(set), Some((n, sets))) if ncomp == 1 && ntup == *n => {
                let v = arrays.reals(s, ntup, ty, "node set values")?;
                sets.insert(set.to_string(), members(&v));
            }
            _ => arrays.skip(s, ncomp.saturating_mul(ntup), ty, "field values")?,
        }
    }
    Ok(())
}

/// VTK 9's `METADATA` block: text lines up to the next blank line.
pub(crate) fn metadata(s: &mut Scan) {
    s.rest_of_line();
    loop {
        let line = s.rest_of_line();
        if line.iter().all(u8::is_ascii_whitespace) {
            return;
        }
    }
}

/// Writes a VTK legacy ASCII unstructured grid; node sets become point-data
/// `SCALARS set_<name> int` arrays (1 = member).
pub fn write_vtk(mesh: &TetMesh, path: &Path) -> Result<(), MeshError> {
    write_file(path, |w| {
        writeln!(
            w,
            "# vtk DataFile Version 3.0\nnvtmm tetrahedral mesh\nASCII\nDATASET UNSTRUCTURED_GRID"
        )?;
        writeln!(w, "POINTS {} double", mesh.num_nodes())?;
        for x in mesh.rest() {
            writeln!(w, "{} {} {}", x.x, x.y, x.z)?;
        }
        let m = mesh.tets().len();
        writeln!(w, "CELLS {m} {}", 5 * m)?;
        for t in mesh.tets() {
            writeln!(w, "4 {} {} {} {}", t[0], t[1], t[2], t[3])?;
        }
        writeln!(w, "CELL_TYPES {m}")?;
        for _ in 0..m {
            writeln!(w, "{VTK_TETRA}")?;
        }
        if !mesh.node_sets().is_empty() {
            writeln!(w, "POINT_DATA {}", mesh.num_nodes())?;
            for (name, ids) in mesh.node_sets() {
                writeln!(w, "SCALARS {SET_PREFIX}{} int 1\nLOOKUP_TABLE default", escape(name))?;
                for v in membership(mesh.num_nodes(), ids) {
                    writeln!(w, "{v}")?;
                }
            }
        }
        Ok(())
    })
}

/// The nodes of a membership mask (non-zero = member).
pub(crate) fn members(mask: &[f64]) -> Vec<u32> {
    (0..mask.len() as u32).filter(|&i| mask[i as usize] != 0.0).collect()
}

/// A 0/1 mask of a node set.
pub(crate) fn membership(n: usize, ids: &[u32]) -> Vec<u8> {
    let mut m = vec![0u8; n];
    for &i in ids {
        if let Some(v) = m.get_mut(i as usize) {
            *v = 1;
        }
    }
    m
}
