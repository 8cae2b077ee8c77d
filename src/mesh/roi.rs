//! Regions of interest: the sub-mesh of the tets inside a region, with its
//! nodes renumbered, a map back to the whole mesh, and the *cut* nodes (those
//! on faces that were interior in the whole mesh and are boundary now), which
//! a scene fixes so the region behaves as if clamped to the tissue around it.
//!
//! A tet is inside when its centroid is (for an interval of a per-node
//! value such as arc length: when all four of its nodes are, so an arch is
//! cut cleanly across its rings). Node sets carry over, restricted
//! to the kept nodes (possibly empty), plus a set `roi_cut` of the cut nodes.

use super::arch::Arch;
use super::{TetMesh, TopologyError};
use crate::math::Vec3;
use std::collections::{BTreeMap, HashSet};

/// Name of the node set of the cut nodes in a sub-mesh.
pub const CUT_SET: &str = "roi_cut";

/// Which tets to keep.
#[derive(Debug, Clone, PartialEq)]
pub enum Region {
    /// An axis-aligned box (m).
    Box {
        /// Lower corner.
        min: Vec3,
        /// Upper corner.
        max: Vec3,
    },
    /// A sphere (m).
    Sphere {
        /// Centre.
        center: Vec3,
        /// Radius.
        radius: f64,
    },
    /// An interval of a per-node coordinate (e.g. arc length along the arch
    /// centreline, [`arch_node_arclength`]): keeps tets whose four nodes'
    /// values all lie in [lo, hi].
    Interval {
        /// One value per node of the whole mesh.
        node_value: Vec<f64>,
        /// Lower bound.
        lo: f64,
        /// Upper bound.
        hi: f64,
    },
}

/// Why a region of interest could not be cut.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RoiError {
    /// No tet lies inside the region.
    #[error("the region of interest contains no tet of the mesh")]
    Empty,
    /// An interval's per-node values do not match the mesh.
    #[error("the region has {got} node values, the mesh has {expected} nodes")]
    SizeMismatch {
        /// Values given.
        got: usize,
        /// Mesh nodes.
        expected: usize,
    },
    /// The sub-mesh is not a valid mesh (a bug, reported rather than hidden).
    #[error("sub-mesh: {0}")]
    Topology(#[from] TopologyError),
}

/// A region of interest cut out of a mesh.
#[derive(Debug, Clone)]
pub struct SubMesh {
    /// The kept tets, nodes renumbered 0.. in increasing order of their
    /// index in the whole mesh.
    pub mesh: TetMesh,
    /// Node of the whole mesh of each sub-mesh node.
    pub to_full: Vec<u32>,
    /// Sub-mesh nodes on the cut surface (sorted).
    pub cut: Vec<u32>,
}

impl SubMesh {
    /// Sub-mesh node of whole-mesh node `full` (None if it was cut away).
    pub fn from_full(&self, full: u32) -> Option<u32> {
        self.to_full.binary_search(&full).ok().map(|i| i as u32)
    }
}

/// Arc length (m) along the arch centreline of every node of `arch.mesh`
/// (the arc length of its ring).
pub fn arch_node_arclength(arch: &Arch) -> Vec<f64> {
    let per_ring = arch.grid.circumferential * arch.grid.layers;
    (0..arch.mesh.num_nodes())
        .map(|i| {
            arch.ring_arclength
                .get(i / per_ring.max(1))
                .copied()
                .unwrap_or(f64::NAN)
        })
        .collect()
}

/// Cuts the tets of `mesh` inside `region` out as a new mesh.
pub fn extract(mesh: &TetMesh, region: &Region) -> Result<SubMesh, RoiError> {
    let rest = mesh.rest();
    if let Region::Interval { node_value, .. } = region {
        if node_value.len() != mesh.num_nodes() {
            return Err(RoiError::SizeMismatch {
                got: node_value.len(),
                expected: mesh.num_nodes(),
            });
        }
    }
    let inside = |tet: &[u32; 4]| -> bool {
        match region {
            Region::Box { min, max } => {
                let c = tet.iter().map(|&i| rest[i as usize]).sum::<Vec3>() / 4.0;
                (0..3).all(|k| c[k] >= min[k] && c[k] <= max[k])
            }
            Region::Sphere { center, radius } => {
                let c = tet.iter().map(|&i| rest[i as usize]).sum::<Vec3>() / 4.0;
                (c - center).norm() <= *radius
            }
            Region::Interval { node_value, lo, hi } => tet.iter().all(|&i| {
                let s = node_value[i as usize];
                s >= *lo && s <= *hi
            }),
        }
    };
    let kept: Vec<[u32; 4]> = mesh.tets().iter().copied().filter(|t| inside(t)).collect();
    if kept.is_empty() {
        return Err(RoiError::Empty);
    }
    let mut used = vec![false; mesh.num_nodes()];
    for t in &kept {
        for &v in t {
            used[v as usize] = true;
        }
    }
    let to_full: Vec<u32> = (0..mesh.num_nodes() as u32).filter(|&i| used[i as usize]).collect();
    let mut to_sub = vec![u32::MAX; mesh.num_nodes()];
    for (s, &f) in to_full.iter().enumerate() {
        to_sub[f as usize] = s as u32;
    }
    let tets: Vec<[u32; 4]> = kept.iter().map(|t| t.map(|v| to_sub[v as usize])).collect();
    let mut sets: BTreeMap<String, Vec<u32>> = BTreeMap::new();
    for (name, ids) in mesh.node_sets() {
        let sub: Vec<u32> = ids
            .iter()
            .filter(|&&i| used[i as usize])
            .map(|&i| to_sub[i as usize])
            .collect();
        // Kept even when empty, so a scene that fixes a set the region
        // does not reach still builds.
        sets.insert(name.clone(), sub);
    }
    let sub_rest: Vec<Vec3> = to_full.iter().map(|&f| rest[f as usize]).collect();
    let mut sub = TetMesh::new(sub_rest, tets, sets)?;
    // A boundary face of the sub-mesh that is not a boundary face of the
    // whole mesh is a cut face.
    let sorted = |t: [u32; 3]| {
        let mut t = t;
        t.sort_unstable();
        t
    };
    let outer: HashSet<[u32; 3]> = mesh.surface().iter().map(|&t| sorted(t)).collect();
    let mut cut: Vec<u32> = Vec::new();
    for tri in sub.surface() {
        let full = sorted(tri.map(|v| to_full[v as usize]));
        if !outer.contains(&full) {
            cut.extend_from_slice(tri);
        }
    }
    cut.sort_unstable();
    cut.dedup();
    sub.set_node_set(CUT_SET, cut.clone())?;
    Ok(SubMesh {
        mesh: sub,
        to_full,
        cut,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::block::block;

    #[test]
    fn half_a_block_is_cut_on_one_plane() {
        let m = block([4, 2, 2], [0.04, 0.02, 0.02]).unwrap();
        let region = Region::Box {
            min: Vec3::new(-1.0, -1.0, -1.0),
            max: Vec3::new(0.02, 1.0, 1.0),
        };
        let s = extract(&m, &region).unwrap();
        assert_eq!(s.mesh.tets().len(), m.tets().len() / 2);
        assert_eq!(s.mesh.num_nodes(), 3 * 3 * 3);
        // The cut is the plane x = 0.02: 3 × 3 nodes.
        assert_eq!(s.cut.len(), 9);
        for &c in &s.cut {
            assert!((s.mesh.rest()[c as usize].x - 0.02).abs() < 1e-12);
        }
        assert_eq!(s.mesh.node_set(CUT_SET).unwrap(), &s.cut[..]);
        // x_min survives, x_max is empty.
        assert!(!s.mesh.node_set("x_min").unwrap().is_empty());
        assert_eq!(s.mesh.node_set("x_max"), Some(&[][..]));
        for (i, &f) in s.to_full.iter().enumerate() {
            assert_eq!(s.mesh.rest()[i], m.rest()[f as usize]);
            assert_eq!(s.from_full(f), Some(i as u32));
        }
        let empty = Region::Sphere {
            center: Vec3::new(5.0, 5.0, 5.0),
            radius: 0.001,
        };
        assert_eq!(extract(&m, &empty).unwrap_err(), RoiError::Empty);
    }
}
