//! STL, ASCII and binary. A binary file is recognised by its size (an
//! 80-byte header, a `u32` triangle count n, then 50 bytes per triangle:
//! 84 + 50 n bytes), not by the word `solid`, which many binary writers put
//! in the header too. STL stores every triangle's three corners, so the
//! vertices are welded afterwards (1e-9 of the bounding-box diagonal).

use super::{bbox_diagonal, weld_vertices, SurfaceMesh};
use crate::math::Vec3;
use crate::mesh::io::scan::{quote, Endian, Scan};
use crate::mesh::io::MeshError;
use std::path::Path;

/// Relative welding tolerance (of the bounding-box diagonal).
const WELD_REL: f64 = 1e-9;

pub(super) fn read(path: &Path, data: &[u8]) -> Result<SurfaceMesh, MeshError> {
    let declared = data.get(80..84).map(|b| Endian::Little.u64(b));
    let binary_size = declared.map(|n| 84 + 50 * n);
    let mut mesh = if binary_size == Some(data.len() as u64) {
        read_binary(path, data)?
    } else {
        let text = data.iter().position(|b| !b.is_ascii_whitespace()).map(|i| &data[i..]);
        let looks_ascii = text.is_some_and(|t| t.len() >= 5 && t[..5].eq_ignore_ascii_case(b"solid"));
        let size_msg = || match (declared, binary_size) {
            (Some(n), Some(size)) => format!(
                "not a binary STL: the header declares {n} triangles, which take 84 + 50×{n} = {size} bytes, \
                 but the file has {} bytes (truncated or padded?)",
                data.len()
            ),
            _ => format!(
                "not a binary STL: the file has {} bytes, fewer than the 84 of the header",
                data.len()
            ),
        };
        if !looks_ascii {
            return Err(MeshError::Binary {
                path: path.to_path_buf(),
                offset: data.len(),
                msg: format!("{} and not an ASCII STL (it does not start with 'solid')", size_msg()),
            });
        }
        match read_ascii(path, data) {
            Ok(m) => m,
            // A binary file whose header starts with "solid" but whose size
            // is wrong: the size is the useful message.
            Err(_) if data.contains(&0) => {
                return Err(MeshError::Binary {
                    path: path.to_path_buf(),
                    offset: data.len(),
                    msg: size_msg(),
                })
            }
            Err(e) => return Err(e),
        }
    };
    let tol = WELD_REL * bbox_diagonal(&mesh.vertices);
    weld_vertices(&mut mesh, tol);
    Ok(mesh)
}

fn read_binary(path: &Path, data: &[u8]) -> Result<SurfaceMesh, MeshError> {
    let mut s = Scan::new(path, data);
    s.bytes(84, "the header")?;
    let n = (data.len() - 84) / 50;
    let mut vertices = Vec::with_capacity(3 * n);
    let mut triangles = Vec::with_capacity(n);
    for t in 0..n {
        s.bytes(12, "a facet normal")?;
        for k in 0..3 {
            let at = s.pos();
            let b = s.bytes(12, "a vertex")?;
            let p = Vec3::new(
                Endian::Little.f32(&b[0..4]),
                Endian::Little.f32(&b[4..8]),
                Endian::Little.f32(&b[8..12]),
            );
            if let Some(c) = (0..3).find(|&c| !p[c].is_finite()) {
                return Err(MeshError::Binary {
                    path: path.to_path_buf(),
                    offset: at + 4 * c,
                    msg: format!(
                        "triangle {t}, corner {k}: coordinate {} is not finite ({})",
                        ["x", "y", "z"][c],
                        p[c]
                    ),
                });
            }
            vertices.push(p);
        }
        s.bytes(2, "the attribute byte count")?;
        let v = (3 * t) as u32;
        triangles.push([v, v + 1, v + 2]);
    }
    Ok(SurfaceMesh { vertices, triangles })
}

fn read_ascii(path: &Path, data: &[u8]) -> Result<SurfaceMesh, MeshError> {
    let mut s = Scan::new(path, data);
    let mut vertices = Vec::new();
    let mut triangles = Vec::new();
    let mut in_solid = false;
    while !s.at_eof() {
        let kw = s.token("'solid', 'facet' or 'endsolid'")?;
        match kw.to_ascii_lowercase().as_str() {
            "solid" if !in_solid => {
                s.rest_of_line(); // the solid's name
                in_solid = true;
            }
            "endsolid" if in_solid => {
                s.rest_of_line();
                in_solid = false;
            }
            "facet" if in_solid => {
                let line = s.line();
                let t = triangles.len();
                keyword(&mut s, "normal")?;
                for _ in 0..3 {
                    s.token("a normal component")?;
                }
                keyword(&mut s, "outer")?;
                keyword(&mut s, "loop")?;
                let first = vertices.len() as u32;
                for k in 0..3 {
                    let w = s.token("'vertex'")?;
                    if !w.eq_ignore_ascii_case("vertex") {
                        return Err(s.err(format!(
                            "facet {t} (line {line}): expected 'vertex' {k} of 3, found '{}' \
                             (only triangles are allowed)",
                            quote(w)
                        )));
                    }
                    let mut p = Vec3::zeros();
                    for c in 0..3 {
                        p[c] = s.finite(&format!("facet {t}, vertex {k}: coordinate {}", ["x", "y", "z"][c]))?;
                    }
                    vertices.push(p);
                }
                let w = s.token("'endloop'")?;
                if !w.eq_ignore_ascii_case("endloop") {
                    return Err(s.err(format!(
                        "facet {t} (line {line}): expected 'endloop' after 3 vertices, found '{}' \
                         (only triangles are allowed)",
                        quote(w)
                    )));
                }
                keyword(&mut s, "endfacet")?;
                triangles.push([first, first + 1, first + 2]);
            }
            _ if !in_solid => {
                return Err(s.err(format!("expected 'solid', found '{}'", quote(kw))));
            }
            _ => {
                return Err(s.err(format!("expected 'facet' or 'endsolid', found '{}'", quote(kw))));
            }
        }
    }
    if in_solid {
        return Err(s.err("unexpected end of file: 'endsolid' is missing (truncated file?)"));
    }
    Ok(SurfaceMesh { vertices, triangles })
}

/// Consumes the keyword `word` (ASCII STL keywords are case-insensitive).
fn keyword(s: &mut Scan, word: &str) -> Result<(), MeshError> {
    let t = s.token(&format!("'{word}'"))?;
    if t.eq_ignore_ascii_case(word) {
        Ok(())
    } else {
        Err(s.err(format!("expected '{word}', found '{}'", quote(t))))
    }
}
