//! The stream's surface: the mesh's outward boundary triangles, decimated by
//! vertex clustering on a voxel grid.
//!
//! Each occupied voxel becomes one stream vertex, represented by the mesh
//! surface node nearest the voxel's mean (so every stream vertex follows a
//! real node and its position is that node's position). Nodes are also split
//! by the dominant axis of their outward normal, so the inner and outer faces
//! of a thin vessel wall never merge into one sheet. Triangles are remapped to
//! clusters; degenerate ones (two corners in one cluster) and duplicates are
//! dropped. The voxel size is found by bisection so the vertex count is at
//! most the target and as close to it as the grid allows.

use super::Topology;
use crate::math::Vec3;
use crate::mesh::TetMesh;
use std::collections::HashMap;

/// The full surface (`target_vertices == 0`, or a target at least the
/// surface's node count) or a decimated one with at most `target_vertices`
/// vertices. Epoch 1; change it when you publish a different topology.
pub fn surface(mesh: &TetMesh, target_vertices: usize) -> Topology {
    let nodes = mesh.surface_nodes();
    if target_vertices == 0 || target_vertices >= nodes.len() {
        return full(mesh, &nodes);
    }
    let normals = mesh.surface_vertex_normals();
    let (lo, hi) = mesh.bbox();
    let diag = (hi - lo).norm().max(f64::MIN_POSITIVE);
    // Cluster count falls as the voxel grows: bisect on log(voxel size).
    let (mut small, mut big) = (diag * 1e-6, diag);
    let mut best = None;
    for _ in 0..40 {
        let h = (small * big).sqrt();
        let n = cluster(mesh, &nodes, &normals, lo, h).1;
        if n <= target_vertices {
            best = Some(h);
            big = h;
        } else {
            small = h;
        }
        if big / small < 1.0 + 1e-4 {
            break;
        }
    }
    let h = best.unwrap_or(diag);
    let (of_node, n) = cluster(mesh, &nodes, &normals, lo, h);
    build(mesh, &nodes, &of_node, n)
}

fn full(mesh: &TetMesh, nodes: &[u32]) -> Topology {
    let of_node: HashMap<u32, u32> = nodes.iter().enumerate().map(|(i, &n)| (n, i as u32)).collect();
    build(mesh, nodes, &of_node, nodes.len())
}

fn normal_bucket(n: &Vec3) -> u8 {
    let a = n.abs();
    let (axis, v) = if a.x >= a.y && a.x >= a.z {
        (0, n.x)
    } else if a.y >= a.z {
        (1, n.y)
    } else {
        (2, n.z)
    };
    2 * axis + u8::from(v < 0.0)
}

/// Cluster index of each surface node, and the number of clusters.
fn cluster(mesh: &TetMesh, nodes: &[u32], normals: &[Vec3], lo: Vec3, h: f64) -> (HashMap<u32, u32>, usize) {
    let mut cells: HashMap<(i64, i64, i64, u8), u32> = HashMap::new();
    let mut of_node = HashMap::with_capacity(nodes.len());
    for &n in nodes {
        let x = mesh.rest()[n as usize];
        let c = ((x - lo) / h).map(|v| v.floor() as i64);
        let key = (c.x, c.y, c.z, normal_bucket(&normals[n as usize]));
        let next = cells.len() as u32;
        let id = *cells.entry(key).or_insert(next);
        of_node.insert(n, id);
    }
    (of_node, cells.len())
}

fn build(mesh: &TetMesh, nodes: &[u32], of_node: &HashMap<u32, u32>, clusters: usize) -> Topology {
    let rest = mesh.rest();
    // Representative: the member nearest the cluster mean.
    let mut sum = vec![(Vec3::zeros(), 0usize); clusters];
    for &n in nodes {
        let c = of_node[&n] as usize;
        sum[c].0 += rest[n as usize];
        sum[c].1 += 1;
    }
    let mut rep: Vec<Option<(f64, u32)>> = vec![None; clusters];
    for &n in nodes {
        let c = of_node[&n] as usize;
        let mean = sum[c].0 / sum[c].1 as f64;
        let d = (rest[n as usize] - mean).norm_squared();
        if rep[c].is_none_or(|(best, _)| d < best) {
            rep[c] = Some((d, n));
        }
    }
    // Remap triangles; drop degenerate and duplicate ones.
    let mut seen = std::collections::HashSet::new();
    let mut tris = Vec::new();
    for t in mesh.surface() {
        let c = t.map(|n| of_node[&n]);
        if c[0] == c[1] || c[1] == c[2] || c[0] == c[2] {
            continue;
        }
        let mut key = c;
        key.sort_unstable();
        if seen.insert(key) {
            tris.push(c);
        }
    }
    // Keep only clusters some triangle uses, numbered in first-use order.
    let mut new_id = vec![u32::MAX; clusters];
    let mut node_ids = Vec::new();
    for t in &mut tris {
        for c in t.iter_mut() {
            let k = *c as usize;
            if new_id[k] == u32::MAX {
                new_id[k] = node_ids.len() as u32;
                node_ids.push(rep[k].map_or(0, |(_, n)| n));
            }
            *c = new_id[k];
        }
    }
    let rest_positions = node_ids
        .iter()
        .map(|&n| {
            let x = rest[n as usize];
            [x.x as f32, x.y as f32, x.z as f32]
        })
        .collect();
    Topology {
        epoch: 1,
        rest_positions,
        triangles: tris,
        node_ids,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::arch::{generate, ArchParams};

    #[test]
    fn full_and_decimated_surfaces_are_valid_and_sized() {
        let mesh = generate(&ArchParams::default(), 1458).unwrap().mesh;
        let full = surface(&mesh, 0);
        full.check().unwrap();
        assert_eq!(full.num_vertices(), mesh.surface_nodes().len());
        assert_eq!(full.triangles.len(), mesh.surface().len());
        for target in [100, 400] {
            let t = surface(&mesh, target);
            t.check().unwrap();
            assert!(t.num_vertices() <= target, "{} > {target}", t.num_vertices());
            assert!(t.num_vertices() > target / 3, "{} for {target}", t.num_vertices());
            assert!(t.triangles.len() > t.num_vertices());
            // Every stream vertex sits on its mesh node, and no triangle is degenerate.
            for (p, &n) in t.rest_positions.iter().zip(&t.node_ids) {
                let x = mesh.rest()[n as usize];
                assert_eq!(*p, [x.x as f32, x.y as f32, x.z as f32]);
            }
            assert!(t.triangles.iter().all(|c| c[0] != c[1] && c[1] != c[2] && c[0] != c[2]));
        }
    }
}
