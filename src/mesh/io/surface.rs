//! Surface-only writers (the boundary of the mesh, outward normals): ASCII
//! `.ply`, `.obj`, binary `.stl`. Only surface nodes are written, renumbered
//! in increasing order of their mesh index.

use super::{write_file, MeshError};
use crate::math::Vec3;
use crate::mesh::TetMesh;
use std::io::Write;
use std::path::Path;

/// Surface vertices (positions) and triangles indexing them.
fn compact(mesh: &TetMesh) -> (Vec<Vec3>, Vec<[u32; 3]>) {
    let used = mesh.surface_nodes();
    let mut map = vec![u32::MAX; mesh.num_nodes()];
    for (k, &i) in used.iter().enumerate() {
        map[i as usize] = k as u32;
    }
    let verts = used.iter().map(|&i| mesh.rest()[i as usize]).collect();
    let tris = mesh.surface().iter().map(|t| t.map(|i| map[i as usize])).collect();
    (verts, tris)
}

/// Writes the boundary surface as ASCII PLY (double coordinates).
pub fn write_ply(mesh: &TetMesh, path: &Path) -> Result<(), MeshError> {
    let (v, t) = compact(mesh);
    write_file(path, |w| {
        writeln!(w, "ply\nformat ascii 1.0\ncomment nvtmm boundary surface")?;
        writeln!(
            w,
            "element vertex {}\nproperty double x\nproperty double y\nproperty double z",
            v.len()
        )?;
        writeln!(
            w,
            "element face {}\nproperty list uchar int vertex_indices\nend_header",
            t.len()
        )?;
        for x in &v {
            writeln!(w, "{} {} {}", x.x, x.y, x.z)?;
        }
        for f in &t {
            writeln!(w, "3 {} {} {}", f[0], f[1], f[2])?;
        }
        Ok(())
    })
}

/// Writes the boundary surface as Wavefront OBJ.
pub fn write_obj(mesh: &TetMesh, path: &Path) -> Result<(), MeshError> {
    let (v, t) = compact(mesh);
    write_file(path, |w| {
        writeln!(
            w,
            "# nvtmm boundary surface: {} vertices, {} triangles",
            v.len(),
            t.len()
        )?;
        for x in &v {
            writeln!(w, "v {} {} {}", x.x, x.y, x.z)?;
        }
        for f in &t {
            writeln!(w, "f {} {} {}", f[0] + 1, f[1] + 1, f[2] + 1)?;
        }
        Ok(())
    })
}

/// Writes the boundary surface as binary STL (f32, little-endian, with facet
/// normals).
pub fn write_stl(mesh: &TetMesh, path: &Path) -> Result<(), MeshError> {
    let n = u32::try_from(mesh.surface().len()).map_err(|_| MeshError::InvalidData {
        path: path.to_path_buf(),
        what: "more than 2^32 surface triangles".into(),
    })?;
    write_file(path, |w| {
        let mut header = [b' '; 80];
        let text = b"nvtmm boundary surface";
        header[..text.len()].copy_from_slice(text);
        w.write_all(&header)?;
        w.write_all(&n.to_le_bytes())?;
        for t in mesh.surface() {
            let [a, b, c] = t.map(|i| mesh.rest()[i as usize]);
            let nrm = (b - a).cross(&(c - a));
            let nrm = if nrm.norm() > 0.0 { nrm.normalize() } else { nrm };
            for p in [nrm, a, b, c] {
                for k in 0..3 {
                    w.write_all(&(p[k] as f32).to_le_bytes())?;
                }
            }
            w.write_all(&0u16.to_le_bytes())?;
        }
        Ok(())
    })
}
