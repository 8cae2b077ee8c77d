//! A structured box of tets: test bodies, patch tests and simple scenes.
//!
//! The box [0, size] is split into `cells` hexahedral cells, each cut into six
//! tets by the Kuhn subdivision (conforming). Node sets name the six faces:
//! `x_min`, `x_max`, `y_min`, `y_max`, `z_min`, `z_max`.

use super::{signed_volume, TetMesh, TopologyError};
use crate::math::Vec3;
use std::collections::BTreeMap;

/// Builds a box of `cells[0] × cells[1] × cells[2]` cells spanning [0, size] (m).
pub fn block(cells: [usize; 3], size: [f64; 3]) -> Result<TetMesh, TopologyError> {
    let [nx, ny, nz] = cells.map(|c| c.max(1));
    let idx = |i: usize, j: usize, k: usize| ((k * (ny + 1) + j) * (nx + 1) + i) as u32;
    let mut rest = Vec::with_capacity((nx + 1) * (ny + 1) * (nz + 1));
    for k in 0..=nz {
        for j in 0..=ny {
            for i in 0..=nx {
                rest.push(Vec3::new(
                    size[0] * i as f64 / nx as f64,
                    size[1] * j as f64 / ny as f64,
                    size[2] * k as f64 / nz as f64,
                ));
            }
        }
    }
    const PERMS: [[usize; 3]; 6] = [[0, 1, 2], [0, 2, 1], [1, 0, 2], [1, 2, 0], [2, 0, 1], [2, 1, 0]];
    let mut tets = Vec::with_capacity(6 * nx * ny * nz);
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                for perm in PERMS {
                    let mut c = [i, j, k];
                    let mut tet = [idx(c[0], c[1], c[2]), 0, 0, 0];
                    for (s, &axis) in perm.iter().enumerate() {
                        c[axis] += 1;
                        tet[s + 1] = idx(c[0], c[1], c[2]);
                    }
                    let v = tet.map(|n| rest[n as usize]);
                    if signed_volume(&v[0], &v[1], &v[2], &v[3]) < 0.0 {
                        tet.swap(2, 3);
                    }
                    tets.push(tet);
                }
            }
        }
    }
    let mut sets = BTreeMap::new();
    for (axis, name) in ["x", "y", "z"].iter().enumerate() {
        let lo: Vec<u32> = (0..rest.len() as u32)
            .filter(|&n| rest[n as usize][axis] == 0.0)
            .collect();
        let hi: Vec<u32> = (0..rest.len() as u32)
            .filter(|&n| rest[n as usize][axis] == size[axis])
            .collect();
        sets.insert(format!("{name}_min"), lo);
        sets.insert(format!("{name}_max"), hi);
    }
    TetMesh::new(rest, tets, sets)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn block_counts_and_volume() {
        let m = block([3, 2, 2], [0.3, 0.2, 0.1]).unwrap();
        assert_eq!(m.num_nodes(), 4 * 3 * 3);
        assert_eq!(m.tets().len(), 6 * 12);
        assert_eq!(m.report().inverted, 0);
        assert!((m.total_volume() - 0.006).abs() < 1e-15);
        assert_eq!(m.node_set("x_max").unwrap().len(), 9);
        // Closed box surface: 2 triangles per boundary cell face.
        assert_eq!(m.surface().len(), 2 * 2 * (3 * 2 + 3 * 2 + 2 * 2));
    }
}
