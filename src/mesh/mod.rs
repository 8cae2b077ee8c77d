//! The P1 tetrahedral mesh every model, solver and the service share.
//!
//! [`TetMesh`] holds rest positions (metres) and positively oriented
//! tetrahedra, and builds once the derived topology the physics needs: unique
//! edges and triangles (the entities the tensor-mass method stores its tensors
//! on), the boundary surface with outward normals, vertex→tet adjacency, rest
//! volumes and shape-function gradients, plus named node sets that scenes fix
//! or load. Construction validates everything a user file can get wrong and
//! reorients inverted tets (reported, not silently).
//!
//! The procedural aortic arch lives in [`arch`], quality metrics in
//! [`quality`], file formats in [`io`], and a small software renderer for
//! pictures in [`render`]. Nothing here knows about materials or time.

pub mod arch;
pub mod block;
pub mod io;
pub mod quality;
pub mod render;
pub mod roi;
pub mod surface;
pub mod tube;
pub mod vessel;

use nalgebra::Matrix3;
use std::collections::{BTreeMap, HashMap};

use crate::math::Vec3;

/// What is wrong with a mesh's content (independent of the file it came from).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TopologyError {
    /// The mesh has no nodes.
    #[error("the mesh has no nodes")]
    NoNodes,
    /// The mesh has no tetrahedra.
    #[error("the mesh has no tetrahedra")]
    NoTets,
    /// A node coordinate is NaN or infinite.
    #[error("node {node}: coordinate {axis} is not finite ({value})")]
    NonFiniteNode {
        /// Zero-based node index.
        node: usize,
        /// Axis name (x, y or z).
        axis: char,
        /// The offending value.
        value: f64,
    },
    /// A tet refers to a node that does not exist.
    #[error("tet {tet}: node index {index} is out of range (the mesh has {nodes} nodes)")]
    IndexOutOfRange {
        /// Zero-based tet index.
        tet: usize,
        /// The offending node index.
        index: usize,
        /// Number of nodes in the mesh.
        nodes: usize,
    },
    /// A tet uses the same node twice.
    #[error("tet {tet}: node {node} appears twice")]
    RepeatedNode {
        /// Zero-based tet index.
        tet: usize,
        /// The repeated node index.
        node: usize,
    },
    /// A tet has (nearly) zero volume.
    #[error("tet {tet}: zero volume ({volume:e} m^3; its four nodes are coplanar)")]
    ZeroVolume {
        /// Zero-based tet index.
        tet: usize,
        /// Signed volume found.
        volume: f64,
    },
    /// Two tets share the same four nodes.
    #[error("tet {tet} duplicates tet {first} (same four nodes)")]
    DuplicateTet {
        /// Zero-based index of the later tet.
        tet: usize,
        /// Zero-based index of the first tet with these nodes.
        first: usize,
    },
    /// A face is shared by more than two tets (non-manifold).
    #[error("triangle {a}-{b}-{c} is shared by {count} tets (at most 2 allowed)")]
    NonManifoldFace {
        /// First node.
        a: usize,
        /// Second node.
        b: usize,
        /// Third node.
        c: usize,
        /// Number of tets sharing it.
        count: usize,
    },
    /// A named node set refers to a node that does not exist.
    #[error("node set '{set}': node index {index} is out of range (the mesh has {nodes} nodes)")]
    NodeSetOutOfRange {
        /// Name of the set.
        set: String,
        /// The offending node index.
        index: usize,
        /// Number of nodes in the mesh.
        nodes: usize,
    },
}

/// What construction found and fixed (nothing here is an error).
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct BuildReport {
    /// Tets found with negative orientation and reoriented.
    pub inverted: usize,
    /// Nodes that belong to no tet (kept, but they carry no stiffness).
    pub isolated_nodes: usize,
}

/// A P1 tetrahedral mesh in SI units with its derived topology.
///
/// Fields are read-only outside construction so the derived data can never go
/// stale; build a new mesh to change the geometry.
#[derive(Debug, Clone)]
pub struct TetMesh {
    rest: Vec<Vec3>,
    tets: Vec<[u32; 4]>,
    node_sets: BTreeMap<String, Vec<u32>>,
    edges: Vec<[u32; 2]>,
    triangles: Vec<[u32; 3]>,
    tet_edges: Vec<[u32; 6]>,
    tet_faces: Vec<[u32; 4]>,
    surface: Vec<[u32; 3]>,
    vertex_tet_offsets: Vec<u32>,
    vertex_tet_indices: Vec<u32>,
    volumes: Vec<f64>,
    grads: Vec<[Vec3; 4]>,
    report: BuildReport,
}

/// The local vertex pairs of a tet's six edges, in the order of
/// [`TetMesh::tet_edges`].
pub const TET_EDGE_LOCAL: [[usize; 2]; 6] = [[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]];

/// The local vertex triples of a tet's four faces, face `k` opposite vertex
/// `k`, each ordered so its normal points out of a positively oriented tet.
pub const TET_FACE_LOCAL: [[usize; 3]; 4] = [[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]];

/// Signed volume of the tet (a, b, c, d): positive when (b-a, c-a, d-a) is
/// right-handed.
pub fn signed_volume(a: &Vec3, b: &Vec3, c: &Vec3, d: &Vec3) -> f64 {
    (b - a).dot(&(c - a).cross(&(d - a))) / 6.0
}

fn sorted3(mut t: [u32; 3]) -> [u32; 3] {
    t.sort_unstable();
    t
}

impl TetMesh {
    /// Validates and builds a mesh from rest positions (m), tets and named
    /// node sets. Inverted tets are reoriented and counted in
    /// [`TetMesh::report`]; everything else that is wrong is an error naming
    /// the node, tet or set.
    pub fn new(
        rest: Vec<Vec3>,
        mut tets: Vec<[u32; 4]>,
        node_sets: BTreeMap<String, Vec<u32>>,
    ) -> Result<Self, TopologyError> {
        let n = rest.len();
        if n == 0 {
            return Err(TopologyError::NoNodes);
        }
        if tets.is_empty() {
            return Err(TopologyError::NoTets);
        }
        for (i, p) in rest.iter().enumerate() {
            for (axis, v) in ['x', 'y', 'z'].into_iter().zip(p.iter()) {
                if !v.is_finite() {
                    return Err(TopologyError::NonFiniteNode {
                        node: i,
                        axis,
                        value: *v,
                    });
                }
            }
        }
        for (set, ids) in &node_sets {
            if let Some(&bad) = ids.iter().find(|&&i| i as usize >= n) {
                return Err(TopologyError::NodeSetOutOfRange {
                    set: set.clone(),
                    index: bad as usize,
                    nodes: n,
                });
            }
        }
        // A zero-volume threshold relative to the mesh's own scale, so the
        // check works in metres and in millimetres alike.
        let (lo, hi) = bbox(&rest);
        let diag = (hi - lo).norm().max(f64::MIN_POSITIVE);
        let mut report = BuildReport::default();
        let mut seen: HashMap<[u32; 4], usize> = HashMap::with_capacity(tets.len());
        let mut mean_edge = 0.0;
        for (t, tet) in tets.iter().enumerate() {
            for &v in tet {
                if v as usize >= n {
                    return Err(TopologyError::IndexOutOfRange {
                        tet: t,
                        index: v as usize,
                        nodes: n,
                    });
                }
            }
            let mut key = *tet;
            key.sort_unstable();
            if let Some(w) = key.windows(2).find(|w| w[0] == w[1]) {
                return Err(TopologyError::RepeatedNode {
                    tet: t,
                    node: w[0] as usize,
                });
            }
            if let Some(&first) = seen.get(&key) {
                return Err(TopologyError::DuplicateTet { tet: t, first });
            }
            seen.insert(key, t);
            mean_edge += (rest[tet[1] as usize] - rest[tet[0] as usize]).norm();
        }
        mean_edge /= tets.len() as f64;
        let vol_eps = 1e-9 * mean_edge.max(1e-12 * diag).powi(3);
        let mut volumes = Vec::with_capacity(tets.len());
        for (t, tet) in tets.iter_mut().enumerate() {
            let [a, b, c, d] = tet.map(|i| rest[i as usize]);
            let mut v = signed_volume(&a, &b, &c, &d);
            if v.abs() <= vol_eps || !v.is_finite() {
                return Err(TopologyError::ZeroVolume { tet: t, volume: v });
            }
            if v < 0.0 {
                tet.swap(2, 3);
                v = -v;
                report.inverted += 1;
            }
            volumes.push(v);
        }

        // Unique edges and triangles, and each tet's references to them.
        let mut edge_id: HashMap<[u32; 2], u32> = HashMap::with_capacity(tets.len() * 2);
        let mut edges = Vec::new();
        let mut tri_id: HashMap<[u32; 3], u32> = HashMap::with_capacity(tets.len() * 3);
        let mut triangles = Vec::new();
        let mut tri_count: Vec<u32> = Vec::new();
        let mut tri_oriented: Vec<[u32; 3]> = Vec::new();
        let mut tet_edges = Vec::with_capacity(tets.len());
        let mut tet_faces = Vec::with_capacity(tets.len());
        for tet in &tets {
            let mut te = [0u32; 6];
            for (k, [i, j]) in TET_EDGE_LOCAL.iter().enumerate() {
                let (a, b) = (tet[*i].min(tet[*j]), tet[*i].max(tet[*j]));
                te[k] = *edge_id.entry([a, b]).or_insert_with(|| {
                    edges.push([a, b]);
                    (edges.len() - 1) as u32
                });
            }
            tet_edges.push(te);
            let mut tf = [0u32; 4];
            for (k, local) in TET_FACE_LOCAL.iter().enumerate() {
                let oriented = local.map(|i| tet[i]);
                let key = sorted3(oriented);
                let id = *tri_id.entry(key).or_insert_with(|| {
                    triangles.push(key);
                    tri_count.push(0);
                    tri_oriented.push(oriented);
                    (triangles.len() - 1) as u32
                });
                tri_count[id as usize] += 1;
                tf[k] = id;
            }
            tet_faces.push(tf);
        }
        // Edges sorted by (low, high): each node's upper edges form one range.
        let mut order: Vec<u32> = (0..edges.len() as u32).collect();
        order.sort_unstable_by_key(|&e| edges[e as usize]);
        let mut new_id = vec![0u32; edges.len()];
        for (new, &old) in order.iter().enumerate() {
            new_id[old as usize] = new as u32;
        }
        let edges: Vec<[u32; 2]> = order.iter().map(|&e| edges[e as usize]).collect();
        for te in &mut tet_edges {
            te.iter_mut().for_each(|e| *e = new_id[*e as usize]);
        }
        let mut surface = Vec::new();
        for (id, &c) in tri_count.iter().enumerate() {
            match c {
                1 => surface.push(tri_oriented[id]),
                2 => {}
                _ => {
                    let [a, b, c3] = triangles[id];
                    return Err(TopologyError::NonManifoldFace {
                        a: a as usize,
                        b: b as usize,
                        c: c3 as usize,
                        count: c as usize,
                    });
                }
            }
        }

        // Vertex -> tet adjacency (CSR).
        let mut vertex_tet_offsets = vec![0u32; n + 1];
        for tet in &tets {
            for &v in tet {
                vertex_tet_offsets[v as usize + 1] += 1;
            }
        }
        for i in 0..n {
            vertex_tet_offsets[i + 1] += vertex_tet_offsets[i];
        }
        report.isolated_nodes = (0..n)
            .filter(|&i| vertex_tet_offsets[i] == vertex_tet_offsets[i + 1])
            .count();
        let mut fill = vertex_tet_offsets.clone();
        let mut vertex_tet_indices = vec![0u32; vertex_tet_offsets[n] as usize];
        for (t, tet) in tets.iter().enumerate() {
            for &v in tet {
                vertex_tet_indices[fill[v as usize] as usize] = t as u32;
                fill[v as usize] += 1;
            }
        }

        let grads = tets
            .iter()
            .map(|tet| shape_gradients(&tet.map(|i| rest[i as usize])))
            .collect();

        Ok(TetMesh {
            rest,
            tets,
            node_sets,
            edges,
            triangles,
            tet_edges,
            tet_faces,
            surface,
            vertex_tet_offsets,
            vertex_tet_indices,
            volumes,
            grads,
            report,
        })
    }

    /// Rest positions (m).
    pub fn rest(&self) -> &[Vec3] {
        &self.rest
    }
    /// Number of nodes.
    pub fn num_nodes(&self) -> usize {
        self.rest.len()
    }
    /// Positively oriented tetrahedra (node indices).
    pub fn tets(&self) -> &[[u32; 4]] {
        &self.tets
    }
    /// Named node sets (sorted, unique indices).
    pub fn node_sets(&self) -> &BTreeMap<String, Vec<u32>> {
        &self.node_sets
    }
    /// One named node set, if present.
    pub fn node_set(&self, name: &str) -> Option<&[u32]> {
        self.node_sets.get(name).map(Vec::as_slice)
    }
    /// Unique edges, each as (low, high) node indices, sorted.
    pub fn edges(&self) -> &[[u32; 2]] {
        &self.edges
    }
    /// The index of the edge joining nodes `a` and `b` (either order), if any.
    pub fn edge_index(&self, a: u32, b: u32) -> Option<u32> {
        let key = [a.min(b), a.max(b)];
        self.edges.binary_search(&key).ok().map(|e| e as u32)
    }
    /// Unique triangles (interior and boundary), each with sorted node indices.
    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }
    /// For each tet, the indices into [`TetMesh::edges`] of its six edges in
    /// the local order [`TET_EDGE_LOCAL`].
    pub fn tet_edges(&self) -> &[[u32; 6]] {
        &self.tet_edges
    }
    /// For each tet, the indices into [`TetMesh::triangles`] of its four faces
    /// (face `k` opposite local vertex `k`).
    pub fn tet_faces(&self) -> &[[u32; 4]] {
        &self.tet_faces
    }
    /// Boundary triangles, ordered so their normals point out of the body.
    pub fn surface(&self) -> &[[u32; 3]] {
        &self.surface
    }
    /// The tets that contain node `v`.
    pub fn vertex_tets(&self, v: usize) -> &[u32] {
        let (a, b) = (
            self.vertex_tet_offsets[v] as usize,
            self.vertex_tet_offsets[v + 1] as usize,
        );
        &self.vertex_tet_indices[a..b]
    }
    /// Rest volume of each tet (m³, positive).
    pub fn volumes(&self) -> &[f64] {
        &self.volumes
    }
    /// Total rest volume (m³).
    pub fn total_volume(&self) -> f64 {
        self.volumes.iter().sum()
    }
    /// Shape-function gradients ∇N_i (1/m) of each tet's four nodes; constant
    /// on a P1 tet.
    pub fn grads(&self) -> &[[Vec3; 4]] {
        &self.grads
    }
    /// What construction found and fixed.
    pub fn report(&self) -> &BuildReport {
        &self.report
    }
    /// Axis-aligned bounding box of the rest positions (min, max).
    pub fn bbox(&self) -> (Vec3, Vec3) {
        bbox(&self.rest)
    }
    /// Lumped (row-sum) mass per node (kg) for a uniform density (kg/m³):
    /// each tet gives a quarter of its mass to each of its nodes.
    pub fn lumped_mass(&self, density: f64) -> Vec<f64> {
        let mut m = vec![0.0; self.rest.len()];
        for (tet, v) in self.tets.iter().zip(&self.volumes) {
            for &i in tet {
                m[i as usize] += density * v / 4.0;
            }
        }
        m
    }
    /// Nodes that lie on the boundary surface, sorted.
    pub fn surface_nodes(&self) -> Vec<u32> {
        let mut s: Vec<u32> = self.surface.iter().flatten().copied().collect();
        s.sort_unstable();
        s.dedup();
        s
    }
    /// Area-weighted outward unit normal at each node of the surface (zero for
    /// interior nodes).
    pub fn surface_vertex_normals(&self) -> Vec<Vec3> {
        crate::math::vertex_normals(&self.rest, &self.surface)
    }
    /// Returns a copy of this mesh with rest positions scaled by `s` (e.g.
    /// 1e-3 to turn millimetres into metres). Node sets are kept.
    pub fn scaled(&self, s: f64) -> Result<TetMesh, TopologyError> {
        TetMesh::new(
            self.rest.iter().map(|p| p * s).collect(),
            self.tets.clone(),
            self.node_sets.clone(),
        )
    }
    /// Sets the per-node segment labels (which branch of the vessel tree
    /// each node belongs to): `label[i]` indexes `names`. Stored as one node
    /// set per segment, named [`SEGMENT_SET_PREFIX`] + name, so every format
    /// that carries node sets carries the labels (Gmsh physical groups, VTK
    /// point data). Replaces earlier labels.
    pub fn set_segment_labels(&mut self, names: &[&str], label: &[u8]) -> Result<(), TopologyError> {
        if label.len() != self.rest.len() {
            return Err(TopologyError::NodeSetOutOfRange {
                set: format!("{SEGMENT_SET_PREFIX}*"),
                index: label.len(),
                nodes: self.rest.len(),
            });
        }
        self.node_sets.retain(|k, _| !k.starts_with(SEGMENT_SET_PREFIX));
        for (s, name) in names.iter().enumerate() {
            let ids: Vec<u32> = (0..label.len() as u32)
                .filter(|&i| label[i as usize] as usize == s)
                .collect();
            if !ids.is_empty() {
                self.node_sets.insert(format!("{SEGMENT_SET_PREFIX}{name}"), ids);
            }
        }
        Ok(())
    }

    /// The segment labels, if the mesh has them: the segment names (sorted)
    /// and, for each node, the index of its segment in them (`u8::MAX` for a
    /// node in none).
    pub fn segment_labels(&self) -> Option<(Vec<String>, Vec<u8>)> {
        let sets: Vec<(&String, &Vec<u32>)> = self
            .node_sets
            .iter()
            .filter(|(k, _)| k.starts_with(SEGMENT_SET_PREFIX))
            .take(u8::MAX as usize)
            .collect();
        if sets.is_empty() {
            return None;
        }
        let mut label = vec![u8::MAX; self.rest.len()];
        let mut names = Vec::with_capacity(sets.len());
        for (s, (name, ids)) in sets.iter().enumerate() {
            names.push(name[SEGMENT_SET_PREFIX.len()..].to_string());
            for &i in ids.iter() {
                label[i as usize] = s as u8;
            }
        }
        Some((names, label))
    }

    /// Removes a node set; returns whether it was there.
    pub fn remove_node_set(&mut self, name: &str) -> bool {
        self.node_sets.remove(name).is_some()
    }

    /// Adds or replaces a named node set (indices are sorted and deduplicated).
    pub fn set_node_set(&mut self, name: &str, mut ids: Vec<u32>) -> Result<(), TopologyError> {
        if let Some(&bad) = ids.iter().find(|&&i| i as usize >= self.rest.len()) {
            return Err(TopologyError::NodeSetOutOfRange {
                set: name.to_string(),
                index: bad as usize,
                nodes: self.rest.len(),
            });
        }
        ids.sort_unstable();
        ids.dedup();
        self.node_sets.insert(name.to_string(), ids);
        Ok(())
    }
}

/// Node sets whose name starts with this hold segment labels
/// ([`TetMesh::set_segment_labels`]).
pub const SEGMENT_SET_PREFIX: &str = "segment_";

/// Axis-aligned bounding box of a point set (min, max).
pub fn bbox(points: &[Vec3]) -> (Vec3, Vec3) {
    let mut lo = Vec3::repeat(f64::INFINITY);
    let mut hi = Vec3::repeat(f64::NEG_INFINITY);
    for p in points {
        lo = lo.inf(p);
        hi = hi.sup(p);
    }
    (lo, hi)
}

/// Gradients of the four P1 shape functions of a tet with vertices `x`.
///
/// With the edge matrix Dm = [x1-x0, x2-x0, x3-x0], ∇N_k (k = 1..3) are the
/// rows of Dm⁻¹ and ∇N_0 = −Σ ∇N_k. A degenerate tet yields zeros (callers
/// reject those before).
pub fn shape_gradients(x: &[Vec3; 4]) -> [Vec3; 4] {
    let dm = Matrix3::from_columns(&[x[1] - x[0], x[2] - x[0], x[3] - x[0]]);
    let inv = dm.try_inverse().unwrap_or_else(Matrix3::zeros);
    let g1: Vec3 = inv.row(0).transpose();
    let g2: Vec3 = inv.row(1).transpose();
    let g3: Vec3 = inv.row(2).transpose();
    [-(g1 + g2 + g3), g1, g2, g3]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit_tet() -> (Vec<Vec3>, Vec<[u32; 4]>) {
        (vec![Vec3::zeros(), Vec3::x(), Vec3::y(), Vec3::z()], vec![[0, 1, 2, 3]])
    }

    #[test]
    fn segment_labels_round_trip_through_node_sets_and_formats() {
        let (p, t) = unit_tet();
        let mut m = TetMesh::new(p, t, BTreeMap::new()).unwrap();
        assert!(m.segment_labels().is_none());
        m.set_segment_labels(&["aorta", "left_subclavian"], &[0, 0, 1, 0])
            .unwrap();
        let (names, label) = m.segment_labels().unwrap();
        assert_eq!(names, vec!["aorta".to_string(), "left_subclavian".to_string()]);
        assert_eq!(label, vec![0, 0, 1, 0]);
        assert!(m.set_segment_labels(&["aorta"], &[0, 0]).is_err());
        let dir = tempfile::tempdir().unwrap();
        for ext in ["msh", "vtk", "vtu"] {
            let path = dir.path().join(format!("m.{ext}"));
            crate::mesh::io::write_mesh(&m, &path).unwrap();
            let back = crate::mesh::io::read_mesh(&path).unwrap();
            assert_eq!(back.segment_labels(), m.segment_labels(), "{ext}");
        }
    }

    #[test]
    fn single_tet_topology() {
        let (p, t) = unit_tet();
        let m = TetMesh::new(p, t, BTreeMap::new()).unwrap();
        assert_eq!(m.edges().len(), 6);
        assert_eq!(m.triangles().len(), 4);
        assert_eq!(m.surface().len(), 4);
        assert!((m.total_volume() - 1.0 / 6.0).abs() < 1e-15);
        // Outward normals: each face normal points away from the centroid.
        let c = m.rest().iter().sum::<Vec3>() / 4.0;
        for f in m.surface() {
            let [a, b, d] = f.map(|i| m.rest()[i as usize]);
            let nrm = (b - a).cross(&(d - a));
            assert!(nrm.dot(&(a - c)) > 0.0);
        }
        // Gradients: sum to zero and reproduce linear fields.
        let g = m.grads()[0];
        assert!((g[0] + g[1] + g[2] + g[3]).norm() < 1e-14);
        let f = |x: &Vec3| 2.0 * x.x - 3.0 * x.y + 0.5 * x.z;
        let grad: Vec3 = (0..4).map(|k| g[k] * f(&m.rest()[k])).sum();
        assert!((grad - Vec3::new(2.0, -3.0, 0.5)).norm() < 1e-13);
    }

    #[test]
    fn inverted_tet_is_reoriented_and_reported() {
        let (p, _) = unit_tet();
        let m = TetMesh::new(p, vec![[0, 2, 1, 3]], BTreeMap::new()).unwrap();
        assert_eq!(m.report().inverted, 1);
        assert!(m.volumes()[0] > 0.0);
    }

    #[test]
    fn bad_tets_are_named() {
        let (p, _) = unit_tet();
        let e = TetMesh::new(p.clone(), vec![[0, 1, 2, 7]], BTreeMap::new()).unwrap_err();
        assert!(matches!(
            e,
            TopologyError::IndexOutOfRange {
                tet: 0,
                index: 7,
                nodes: 4
            }
        ));
        let e = TetMesh::new(p.clone(), vec![[0, 1, 1, 3]], BTreeMap::new()).unwrap_err();
        assert!(matches!(e, TopologyError::RepeatedNode { tet: 0, node: 1 }));
        let e = TetMesh::new(p.clone(), vec![[0, 1, 2, 3], [3, 2, 1, 0]], BTreeMap::new()).unwrap_err();
        assert!(matches!(e, TopologyError::DuplicateTet { tet: 1, first: 0 }));
        let mut flat = p.clone();
        flat[3] = Vec3::new(0.3, 0.3, 0.0);
        let e = TetMesh::new(flat, vec![[0, 1, 2, 3]], BTreeMap::new()).unwrap_err();
        assert!(matches!(e, TopologyError::ZeroVolume { tet: 0, .. }));
        let mut nan = p.clone();
        nan[2].y = f64::NAN;
        let e = TetMesh::new(nan, vec![[0, 1, 2, 3]], BTreeMap::new()).unwrap_err();
        assert!(matches!(e, TopologyError::NonFiniteNode { node: 2, axis: 'y', .. }));
        assert_eq!(
            TetMesh::new(vec![], vec![], BTreeMap::new()).unwrap_err(),
            TopologyError::NoNodes
        );
        assert_eq!(
            TetMesh::new(p, vec![], BTreeMap::new()).unwrap_err(),
            TopologyError::NoTets
        );
    }

    #[test]
    fn lumped_mass_sums_to_total() {
        let (p, t) = unit_tet();
        let m = TetMesh::new(p, t, BTreeMap::new()).unwrap();
        let mass: f64 = m.lumped_mass(1000.0).iter().sum();
        assert!((mass - 1000.0 / 6.0).abs() < 1e-12);
    }
}
