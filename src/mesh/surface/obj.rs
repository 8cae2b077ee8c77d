//! Wavefront OBJ: `v x y z [w]` vertices and `f` faces whose corners are
//! `v`, `v/vt`, `v/vt/vn` or `v//vn`, with 1-based or negative (relative)
//! indices; polygons are split into fans. A line ending in `\` continues on
//! the next. Every other statement (`vt`, `vn`, `g`, `o`, `s`, `usemtl`,
//! `mtllib`, `l`, `p`, …) and `#` comments are ignored.

use super::{fan, SurfaceMesh};
use crate::math::Vec3;
use crate::mesh::io::scan::quote;
use crate::mesh::io::MeshError;
use std::path::Path;

pub(super) fn read(path: &Path, data: &[u8]) -> Result<SurfaceMesh, MeshError> {
    let err = |line: usize, msg: String| MeshError::Parse {
        path: path.to_path_buf(),
        line,
        msg,
    };
    let mut vertices: Vec<Vec3> = Vec::new();
    let mut triangles = Vec::new();
    // Positive indices may refer to vertices defined later: checked at the end.
    let mut forward: Vec<(usize, i64)> = Vec::new(); // (line, index)
    let mut poly: Vec<u32> = Vec::new();
    let mut joined = String::new();
    let mut lines = data.split(|&b| b == b'\n').enumerate();
    while let Some((i, raw)) = lines.next() {
        let lineno = i + 1;
        let text = |raw: &[u8]| -> Result<String, MeshError> {
            let raw = raw.strip_suffix(b"\r").unwrap_or(raw);
            // Comments may hold any bytes (names in a local encoding).
            let raw = match raw.iter().position(|&b| b == b'#') {
                Some(k) => &raw[..k],
                None => raw,
            };
            String::from_utf8(raw.to_vec()).map_err(|_| err(lineno, "the line is not UTF-8 text".into()))
        };
        joined.clear();
        joined.push_str(&text(raw)?);
        while joined.trim_end().ends_with('\\') {
            let cut = joined.trim_end().len() - 1;
            joined.truncate(cut);
            joined.push(' ');
            match lines.next() {
                Some((_, next)) => joined.push_str(&text(next)?),
                None => break,
            }
        }
        let mut tok = joined.split_ascii_whitespace();
        match tok.next() {
            Some("v") => {
                let mut p = Vec3::zeros();
                for (c, axis) in ["x", "y", "z"].iter().enumerate() {
                    let Some(t) = tok.next() else {
                        return Err(err(
                            lineno,
                            format!("vertex {}: expected 3 coordinates", vertices.len() + 1),
                        ));
                    };
                    let v: f64 = t.parse().map_err(|_| {
                        err(
                            lineno,
                            format!(
                                "vertex {}: coordinate {axis} '{}' is not a number",
                                vertices.len() + 1,
                                quote(t)
                            ),
                        )
                    })?;
                    if !v.is_finite() {
                        return Err(err(
                            lineno,
                            format!("vertex {}: coordinate {axis} is not finite ({v})", vertices.len() + 1),
                        ));
                    }
                    p[c] = v;
                }
                vertices.push(p);
            }
            Some("f") => {
                poly.clear();
                for corner in tok {
                    let idx = corner.split('/').next().unwrap_or("");
                    let v: i64 = idx.parse().map_err(|_| {
                        err(
                            lineno,
                            format!("face corner '{}': the vertex index is not an integer", quote(corner)),
                        )
                    })?;
                    let n = vertices.len() as i64;
                    let abs = match v {
                        0 => return Err(err(lineno, "vertex index 0 (OBJ indices start at 1)".into())),
                        v if v < 0 => {
                            let a = n + v;
                            if a < 0 {
                                return Err(err(
                                    lineno,
                                    format!("relative vertex index {v} reaches before the first vertex ({n} defined so far)"),
                                ));
                            }
                            a
                        }
                        v => {
                            if v > n {
                                forward.push((lineno, v));
                            }
                            v - 1
                        }
                    };
                    let Ok(abs) = u32::try_from(abs) else {
                        return Err(err(lineno, format!("vertex index {v} is too large")));
                    };
                    poly.push(abs);
                }
                if poly.len() < 3 {
                    return Err(err(
                        lineno,
                        format!("a face with {} vertices (at least 3 needed)", poly.len()),
                    ));
                }
                fan(&poly, &mut triangles);
            }
            _ => {}
        }
    }
    let n = vertices.len();
    if let Some(&(line, v)) = forward.iter().find(|&&(_, v)| v as u64 > n as u64) {
        return Err(err(
            line,
            format!("vertex index {v} is out of range (the file has {n} vertices)"),
        ));
    }
    Ok(SurfaceMesh { vertices, triangles })
}
