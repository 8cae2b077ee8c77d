//! TetGen `.node` + `.ele` pairs.
//!
//! Following TetGen, the first point's number in `.node` sets the index base
//! (0 or 1) for both files, and points must be numbered consecutively from
//! it. Attributes and boundary markers are read past and ignored; `#` starts
//! a comment. TetGen files carry no named node sets.

use super::scan::Scan;
use super::{write_file, MeshError, RawMesh};
use crate::math::Vec3;
use crate::mesh::TetMesh;
use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};

/// The `.node` and `.ele` paths for either one of them.
fn pair(path: &Path) -> (PathBuf, PathBuf) {
    (path.with_extension("node"), path.with_extension("ele"))
}

fn read_bytes(path: &Path) -> Result<Vec<u8>, MeshError> {
    std::fs::read(path).map_err(|source| MeshError::Io {
        path: path.to_path_buf(),
        source,
    })
}

pub(crate) fn read(path: &Path, scale: f64) -> Result<TetMesh, MeshError> {
    let (node, ele) = pair(path);
    let nb = read_bytes(&node)?;
    let eb = read_bytes(&ele)?;
    read_tetgen_bytes(&node, &nb, &ele, &eb, scale)
}

/// Parses a TetGen pair held in memory; the paths only name the files in
/// errors. Coordinates are multiplied by `scale`.
pub fn read_tetgen_bytes(
    node_path: &Path,
    node: &[u8],
    ele_path: &Path,
    ele: &[u8],
    scale: f64,
) -> Result<TetMesh, MeshError> {
    super::check_scale(node_path, scale)?;
    let mut s = Scan::new(node_path, node).with_comments(b'#');
    let n = s.u64("the number of points")?;
    let dim = s.u64("the dimension")?;
    if dim != 3 {
        return Err(s.err(format!("dimension {dim} (only 3-D meshes are read)")));
    }
    let nattr = s.u64("the number of attributes")?;
    let nmark = s.u64("the number of boundary markers (0 or 1)")?;
    if nmark > 1 {
        return Err(s.err(format!("{nmark} boundary markers (TetGen allows 0 or 1)")));
    }
    let mut nodes = Vec::with_capacity(s.cap(n, 8));
    let mut base = 0u64;
    for i in 0..n {
        let id = s.u64("a point number")?;
        if i == 0 {
            if id > 1 {
                return Err(s.err(format!("the first point is numbered {id}; TetGen numbers from 0 or 1")));
            }
            base = id;
        } else if id != base + i {
            return Err(s.err(format!("point number {id} is out of sequence (expected {})", base + i)));
        }
        let x = Vec3::new(
            s.finite("point x coordinate")?,
            s.finite("point y coordinate")?,
            s.finite("point z coordinate")?,
        );
        for _ in 0..nattr.saturating_add(nmark) {
            s.f64("a point attribute or marker")?;
        }
        nodes.push(x);
    }
    if nodes.len() > u32::MAX as usize {
        return Err(s.err(format!("more than {} points", u32::MAX)));
    }

    let mut s = Scan::new(ele_path, ele).with_comments(b'#');
    let m = s.u64("the number of tetrahedra")?;
    let per = s.u64("the number of nodes per tetrahedron")?;
    if per != 4 {
        return Err(s.err(format!(
            "{per} nodes per tetrahedron; only linear (4-node) tets are supported"
        )));
    }
    let nreg = s.u64("the number of region attributes")?;
    let mut tets = Vec::with_capacity(s.cap(m, 10));
    for t in 0..m {
        let id = s.u64("a tetrahedron number")?;
        if id != base + t {
            return Err(s.err(format!(
                "tetrahedron number {id} is out of sequence (expected {})",
                base + t
            )));
        }
        let mut tet = [0u32; 4];
        for v in &mut tet {
            let k = s.u64("a tetrahedron's point number")?;
            let idx = k.checked_sub(base).filter(|&i| i < nodes.len() as u64);
            let Some(idx) = idx else {
                return Err(s.err(format!(
                    "tetrahedron {id}: point {k} does not exist (points are {base}..{})",
                    base + nodes.len() as u64
                )));
            };
            *v = idx as u32;
        }
        for _ in 0..nreg {
            s.f64("a region attribute")?;
        }
        tets.push(tet);
    }
    RawMesh {
        nodes,
        tets,
        sets: BTreeMap::new(),
    }
    .build(node_path, scale)
}

/// Writes `<path>.node` and `<path>.ele` (whichever of the two `path` names),
/// numbering from `base` (0 or 1; TetGen's own default is 1).
pub fn write_tetgen(mesh: &TetMesh, path: &Path, base: u32) -> Result<(), MeshError> {
    if base > 1 {
        return Err(MeshError::InvalidData {
            path: path.to_path_buf(),
            what: format!("TetGen index base must be 0 or 1, not {base}"),
        });
    }
    let (node, ele) = pair(path);
    let b = base as usize;
    write_file(&node, |w| {
        writeln!(w, "# nvtmm mesh: <points> <dim> <attributes> <markers>")?;
        writeln!(w, "{} 3 0 0", mesh.num_nodes())?;
        for (i, x) in mesh.rest().iter().enumerate() {
            writeln!(w, "{} {} {} {}", i + b, x.x, x.y, x.z)?;
        }
        Ok(())
    })?;
    write_file(&ele, |w| {
        writeln!(w, "# nvtmm mesh: <tetrahedra> <nodes per tet> <region attributes>")?;
        writeln!(w, "{} 4 0", mesh.tets().len())?;
        for (i, t) in mesh.tets().iter().enumerate() {
            writeln!(
                w,
                "{} {} {} {} {}",
                i + b,
                t[0] + base,
                t[1] + base,
                t[2] + base,
                t[3] + base
            )?;
        }
        Ok(())
    })
}
