//! The built-in branched aortic arch as a volume mesh: the implicit lumen
//! tree ([`super::implicit`]) meshed to a surface with a target vertex
//! count, checked, and turned into a wall ([`super::wall`]), with the
//! openings named after the tree's ends and the segment labels carried to
//! every node.

use super::implicit::{self, BranchedArchParams, ImplicitError, LumenTree, SEGMENT_NAMES};
use super::wall::{build_wall_per_vertex, Wall};
use super::VesselError;
use crate::mesh::surface::{check_surface, CheckOptions};

/// Why the branched arch could not be built.
#[derive(Debug, thiserror::Error)]
pub enum BranchedArchError {
    /// The implicit lumen or its surface.
    #[error(transparent)]
    Lumen(#[from] ImplicitError),
    /// The lumen surface failed its check.
    #[error("branched arch lumen: {0}")]
    Surface(#[from] crate::mesh::surface::SurfaceDefect),
    /// The wall.
    #[error(transparent)]
    Wall(#[from] VesselError),
    /// An option is out of range.
    #[error("branched arch: {0}")]
    BadOption(String),
}

/// The thinnest wall the branched arch gets (m): about the carotid's
/// intima-media thickness plus adventitia, and thick enough that the
/// prisms of the branches (edges of 2-3 mm) split into tets of fair shape.
pub const MIN_WALL_M: f64 = 1.0e-3;

/// The thinnest wall relative to the mean length of the lumen edges at a
/// vertex: prisms flatter than this split into tets with small dihedral
/// angles.
pub const MIN_WALL_PER_EDGE: f64 = 0.3;

/// The mean length of the edges at each vertex (m).
fn mean_edge_lengths(mesh: &crate::mesh::surface::SurfaceMesh) -> Vec<f64> {
    let mut sum = vec![0.0; mesh.vertices.len()];
    let mut count = vec![0usize; mesh.vertices.len()];
    for t in &mesh.triangles {
        for k in 0..3 {
            let (a, b) = (t[k] as usize, t[(k + 1) % 3] as usize);
            // Each interior edge is seen twice, once from each side: both
            // ends count it twice, so the mean is unchanged.
            let l = (mesh.vertices[a] - mesh.vertices[b]).norm();
            sum[a] += l;
            sum[b] += l;
            count[a] += 1;
            count[b] += 1;
        }
    }
    sum.iter()
        .zip(&count)
        .map(|(s, &c)| if c > 0 { s / c as f64 } else { 0.0 })
        .collect()
}

/// `passes` Jacobi steps replacing each value by the mean over the vertex
/// and its neighbours, never below its own value before the step: the wall
/// thickness changes over a few edges where the radius it follows jumps
/// (a junction), so neighbouring prisms' tops do not tilt.
fn smooth_over_neighbours(mesh: &crate::mesh::surface::SurfaceMesh, mut t: Vec<f64>, passes: usize) -> Vec<f64> {
    let n = t.len();
    for _ in 0..passes {
        let mut sum = t.clone();
        let mut count = vec![1usize; n];
        for tri in &mesh.triangles {
            for k in 0..3 {
                let (a, b) = (tri[k] as usize, tri[(k + 1) % 3] as usize);
                sum[a] += t[b];
                count[a] += 1;
                sum[b] += t[a];
                count[b] += 1;
            }
        }
        t = (0..n).map(|v| (sum[v] / count[v] as f64).max(t[v])).collect();
    }
    t
}

/// The version of what [`branched_arch`] makes from its options: part of
/// the key under which scenes cache the arch (`[mesh] arch_branches`), so
/// a change here must come with a new tag or old caches would be read as
/// the new mesh. Bump it whenever the same options give other nodes, tets,
/// sets or labels (here, in the implicit lumen, the remesher or the wall).
pub const MESHER_VERSION: &str = "nvtmm branched arch v1 (labelled-vessel wall thickness)";

/// A built branched arch.
#[derive(Debug, Clone)]
pub struct BranchedArch {
    /// The wall: mesh with node sets `inlet`, `outlet_descending`,
    /// `outlet_brachiocephalic`, `outlet_left_common_carotid`,
    /// `outlet_left_subclavian`, `inner_wall`, `outer_wall` and the segment
    /// labels (`segment_aorta`, …), its openings and quality.
    pub wall: Wall,
    /// The uniform lumen edge length the vertex-count search settled on (m;
    /// branches are meshed finer so each keeps 8 nodes around).
    pub surface_size_m: f64,
}

/// The wall thickness of the branched arch as a fraction of the local
/// lumen radius: the aorta's wall over its mean lumen radius (2 mm on
/// 13.7 mm: 0.146), so the branches' walls are thinner in proportion.
pub fn default_wall_ratio(params: &BranchedArchParams) -> f64 {
    let r = params.aorta.lumen_radius_mm;
    params.aorta.wall_mm / ((r[0] + r[1] + r[2]) / 3.0)
}

/// Builds the branched arch with `nodes` nodes (within 1 %), `layers`
/// element layers through the wall and a wall `wall_ratio` times the lumen
/// radius of the vessel each vertex is labelled with
/// ([`LumenTree::label_and_radius`]: a junction's fillet is the parent's, so
/// the aorta's wall keeps the aorta's thickness up to where each branch
/// proper begins; never below [`LumenTree::local_radius`]), at least
/// [`MIN_WALL_M`] and at least
/// [`MIN_WALL_PER_EDGE`] times the mean lumen edge at the vertex; then
/// four passes of a one-ring mean that only ever thickens, so the wall
/// does not step where the radius it follows jumps (at a junction).
pub fn branched_arch(
    params: &BranchedArchParams,
    nodes: usize,
    layers: usize,
    wall_ratio: f64,
) -> Result<BranchedArch, BranchedArchError> {
    if !(wall_ratio.is_finite() && wall_ratio > 0.0 && wall_ratio <= 0.5) {
        return Err(BranchedArchError::BadOption(format!(
            "wall ratio must be in (0, 0.5], got {wall_ratio}"
        )));
    }
    if layers == 0 || layers > 16 {
        return Err(BranchedArchError::BadOption(format!(
            "layers must be 1 to 16, got {layers}"
        )));
    }
    let per_layer = nodes / (layers + 1);
    if per_layer < 200 {
        return Err(BranchedArchError::BadOption(format!(
            "{nodes} nodes over {} node layers leave {per_layer} per layer; at least 200 are needed to resolve the branches",
            layers + 1
        )));
    }
    let tree = LumenTree::arch(params)?;
    let (size, lumen) = implicit::lumen_surface_with_vertices(&tree, per_layer, 0.008)?;
    let checked = check_surface(
        &lumen.mesh,
        &CheckOptions {
            self_intersections: false,
            ..CheckOptions::default()
        },
    )?;
    // The thickness follows the radius of the vessel a vertex is labelled
    // with (LumenTree::label_and_radius: a junction's fillet, before the
    // branch proper, belongs to the parent), so the aorta keeps its own
    // wall between the branch origins, where the probe presses, and a
    // branch's wall is the branch's. The radius the surface is meshed to
    // (LumenTree::local_radius, the branch's on a fillet) is never larger
    // there; it is kept as a floor so the wall is never thinner than the
    // mesh size it was tuned against.
    // Prisms flatter than about 1 : 4 split into tets with dihedral angles
    // below 10°: where the mesh is coarse for the wall (the junctions of
    // a coarse arch, meshed at the parent's size), the wall is at least
    // MIN_WALL_PER_EDGE of the mean edge at the vertex.
    let edge = mean_edge_lengths(&checked.mesh);
    let thickness: Vec<f64> = checked
        .mesh
        .vertices
        .iter()
        .zip(&edge)
        .map(|(p, &e)| {
            (wall_ratio * tree.local_radius(p).max(tree.label_and_radius(p).1))
                .max(MIN_WALL_M)
                .max(MIN_WALL_PER_EDGE * e)
        })
        .collect();
    let thickness = smooth_over_neighbours(&checked.mesh, thickness, 4);
    let mut wall = build_wall_per_vertex(&checked, &thickness, layers)?;
    // Name the openings after the tree's ends (nearest centre).
    let mut renamed = Vec::new();
    for o in wall.openings.iter_mut() {
        let Some(named) = lumen.openings.iter().min_by(|a, b| {
            (a.boundary.centre - o.centre)
                .norm()
                .total_cmp(&(b.boundary.centre - o.centre).norm())
        }) else {
            continue;
        };
        renamed.push((o.name.clone(), named.name.clone()));
        o.name = named.name.clone();
    }
    for (old, new) in renamed {
        if let Some(ids) = wall.mesh.node_set(&old).map(|s| s.to_vec()) {
            wall.mesh
                .set_node_set(&new, ids)
                .map_err(|e| BranchedArchError::BadOption(e.to_string()))?;
        }
    }
    let opening_sets: Vec<String> = wall
        .mesh
        .node_sets()
        .keys()
        .filter(|k| k.starts_with("opening_"))
        .cloned()
        .collect();
    for k in opening_sets {
        wall.mesh.remove_node_set(&k);
    }
    // Segment labels: wall node `layer · n + v` is a copy of lumen vertex v
    // of the checked surface, whose input vertex carries the label.
    let n = checked.mesh.vertices.len();
    let labels: Vec<u8> = (0..wall.mesh.num_nodes())
        .map(|i| {
            let v = checked.report.input_vertex[i % n] as usize;
            lumen.labels.get(v).copied().unwrap_or(0)
        })
        .collect();
    wall.mesh
        .set_segment_labels(&SEGMENT_NAMES, &labels)
        .map_err(|e| BranchedArchError::BadOption(e.to_string()))?;
    Ok(BranchedArch {
        wall,
        surface_size_m: size,
    })
}
