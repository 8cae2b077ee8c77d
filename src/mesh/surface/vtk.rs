//! VTK polydata: the legacy `.vtk` `DATASET POLYDATA` (ASCII, or BINARY
//! big-endian) and the XML `.vtp` `PolyData`, read with the volume readers'
//! scanners ([`crate::mesh::io`]'s `vtk` and `vtu`).
//!
//! Legacy: `POINTS`, `POLYGONS` and `TRIANGLE_STRIPS` in the classic layout
//! (`n size`, then per cell a count and its indices) or the VTK ≥ 5.1 one
//! (`OFFSETS` and `CONNECTIVITY` arrays); `VERTICES`, `LINES`, point and cell
//! data, `FIELD` and `METADATA` are skipped. XML: the `Points` and the
//! `Polys` and `Strips` `connectivity`/`offsets` arrays of one `Piece`, as
//! ascii, inline base64, or appended (raw or base64), uncompressed or
//! zlib-compressed; `Verts` and `Lines` are ignored. Polygons are split into
//! fans, strips into their triangles (alternate ones reversed so all keep the
//! strip's orientation).

use super::{fan, vertex_index, SurfaceMesh};
use crate::math::Vec3;
use crate::mesh::io::scan::{quote, Scan};
use crate::mesh::io::vtk::{attributes, cell_list, field, legacy_header, metadata};
use crate::mesh::io::vtu::{ints, reals, scan_doc, Doc};
use crate::mesh::io::MeshError;
use std::collections::BTreeMap;
use std::path::Path;

/// Appends the triangles of cells (`conn` split by `offsets`, which start
/// at 0) of kind `kind` ("polygon" or "strip"); errors name the cell and
/// `line` (the section's line).
fn add_cells(
    path: &Path,
    line: usize,
    kind: &str,
    conn: &[i64],
    offsets: &[usize],
    nverts: usize,
    out: &mut Vec<[u32; 3]>,
) -> Result<(), MeshError> {
    let err = |msg: String| MeshError::Parse {
        path: path.to_path_buf(),
        line,
        msg,
    };
    let mut poly = Vec::new();
    for (c, w) in offsets.windows(2).enumerate() {
        let Some(cell) = conn.get(w[0]..w[1]) else {
            return Err(err(format!(
                "{kind} {c}: offsets out of order or past the connectivity"
            )));
        };
        if cell.len() < 3 {
            return Err(err(format!("{kind} {c} has {} points (at least 3 needed)", cell.len())));
        }
        poly.clear();
        for &v in cell {
            let Some(v) = vertex_index(v, nverts) else {
                return Err(err(format!(
                    "{kind} {c}: point index {v} is out of range (the file has {nverts} points)"
                )));
            };
            poly.push(v);
        }
        if kind == "strip" {
            for k in 0..poly.len() - 2 {
                let t = if k % 2 == 0 {
                    [poly[k], poly[k + 1], poly[k + 2]]
                } else {
                    [poly[k + 1], poly[k], poly[k + 2]]
                };
                out.push(t);
            }
        } else {
            fan(&poly, out);
        }
    }
    Ok(())
}

/// Points from flat coordinates, refusing non-finite ones.
fn points(v: &[f64], err: impl Fn(String) -> MeshError) -> Result<Vec<Vec3>, MeshError> {
    let mut pts = Vec::with_capacity(v.len() / 3);
    for (i, c) in v.chunks_exact(3).enumerate() {
        let p = Vec3::new(c[0], c[1], c[2]);
        if let Some(k) = (0..3).find(|&k| !p[k].is_finite()) {
            return Err(err(format!(
                "point {i}: coordinate {} is not finite ({})",
                ["x", "y", "z"][k],
                p[k]
            )));
        }
        pts.push(p);
    }
    Ok(pts)
}

pub(super) fn read_legacy(path: &Path, data: &[u8]) -> Result<SurfaceMesh, MeshError> {
    let mut s = Scan::new(path, data);
    let (arrays, ds) = legacy_header(&mut s)?;
    if ds != "POLYDATA" {
        return Err(s.err(format!(
            "dataset '{}' is not a surface: only POLYDATA is read as a surface",
            quote(ds)
        )));
    }
    let mut verts: Option<Vec<Vec3>> = None;
    // (line, kind, connectivity, offsets), resolved once the points are known.
    let mut cells: Vec<(usize, &str, Vec<i64>, Vec<usize>)> = Vec::new();
    let mut unused_sets = BTreeMap::new();
    while !s.at_eof() {
        let line = s.line();
        let kw = s.token("a keyword")?;
        match kw {
            "POINTS" => {
                let n = s.u64("the number of points")?;
                let ty = s.token("the point data type")?;
                arrays.start_data(&mut s);
                let v = arrays.reals(&mut s, n.saturating_mul(3), ty, "point coordinates")?;
                verts = Some(points(&v, |m| s.err_at(line, m))?);
            }
            "POLYGONS" | "TRIANGLE_STRIPS" => {
                let kind = if kw == "POLYGONS" { "polygon" } else { "strip" };
                let (conn, offsets) = cell_list(&mut s, &arrays, line, kind)?;
                cells.push((line, kind, conn, offsets));
            }
            "VERTICES" | "LINES" => {
                cell_list(&mut s, &arrays, line, "cell")?;
            }
            "POINT_DATA" | "CELL_DATA" => {
                let n = s.u64("the number of data values")?;
                attributes(&mut s, &arrays, n, false, &mut unused_sets)?;
            }
            "FIELD" => field(&mut s, &arrays, None)?,
            "METADATA" => metadata(&mut s),
            k => return Err(s.err(format!("unknown keyword '{}'", quote(k)))),
        }
    }
    let Some(vertices) = verts else {
        return Err(s.err("no POINTS section"));
    };
    if cells.is_empty() {
        return Err(s.err("no POLYGONS or TRIANGLE_STRIPS section: the file holds no surface"));
    }
    let mut triangles = Vec::new();
    for (line, kind, conn, offsets) in &cells {
        add_cells(path, *line, kind, conn, offsets, vertices.len(), &mut triangles)?;
    }
    Ok(SurfaceMesh { vertices, triangles })
}

pub(super) fn read_vtp(path: &Path, data: &[u8]) -> Result<SurfaceMesh, MeshError> {
    let doc = scan_doc(path, data, "PolyData")?;
    let npts = doc.required("NumberOfPoints")?;
    let pline = doc.piece_line();
    let Some(pa) = doc.arrays_in("Points").last() else {
        return Err(doc.err(pline, "no <Points> DataArray"));
    };
    if pa.ncomp != 3 {
        return Err(doc.err(pa.line, "Points must have NumberOfComponents=\"3\""));
    }
    let coords = reals(&doc.ctx, pa, npts.saturating_mul(3))?;
    let vertices = points(&coords, |m| doc.err(pa.line, m))?;
    let mut triangles = Vec::new();
    let mut any = false;
    for (section, key, kind) in [
        ("Polys", "NumberOfPolys", "polygon"),
        ("Strips", "NumberOfStrips", "strip"),
    ] {
        let n = doc.count(key)?.unwrap_or(0);
        if n == 0 {
            continue;
        }
        any = true;
        let (conn_a, off_a) = (find(&doc, section, "connectivity")?, find(&doc, section, "offsets")?);
        let ends = ints(&doc.ctx, off_a, Some(n))?;
        let conn = ints(&doc.ctx, conn_a, None)?;
        let mut offsets = Vec::with_capacity(ends.len() + 1);
        offsets.push(0usize);
        for (c, &o) in ends.iter().enumerate() {
            let prev = offsets.last().copied().unwrap_or(0);
            let o = usize::try_from(o).ok().filter(|&o| o >= prev && o <= conn.len());
            let Some(o) = o else {
                return Err(doc.err(
                    off_a.line,
                    format!("{kind} {c}: offset is out of order or past the connectivity"),
                ));
            };
            offsets.push(o);
        }
        add_cells(path, conn_a.line, kind, &conn, &offsets, vertices.len(), &mut triangles)?;
    }
    if !any {
        return Err(doc.err(
            pline,
            "the Piece has no polygons or strips (NumberOfPolys and NumberOfStrips are 0 or absent): no surface",
        ));
    }
    Ok(SurfaceMesh { vertices, triangles })
}

/// The array `name` inside the element `section`.
fn find<'d, 'a>(
    doc: &'d Doc<'a>,
    section: &'d str,
    name: &str,
) -> Result<&'d crate::mesh::io::vtu::Array<'a>, MeshError> {
    doc.arrays_in(section)
        .find(|a| a.name == name)
        .ok_or_else(|| doc.err(doc.piece_line(), format!("no {section} DataArray named '{name}'")))
}
