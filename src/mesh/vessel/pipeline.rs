//! The whole `nvtmm mesh vessel` pipeline as one function: a checked lumen
//! surface opened (cuts, caps), remeshed to a target size if asked,
//! checked again, labelled by segment ([`super::centreline`]) and turned
//! into a wall ([`super::wall`]).
//!
//! The target size is either a vertex count or an edge length. Either way
//! the size is capped by the local lumen radius so that every vessel keeps
//! at least eight vertices around ([`super::remesh::graded_size`]); a node
//! count too small for that is refused ([`VesselError::TooCoarse`]) rather
//! than met by dropping below eight around the thinnest branch.

use super::caps::{open_surface, Cap, CapOptions, CutPlane};
use super::centreline::segment_labels;
use super::remesh::{around_cap, remesh, remesh_to_vertex_count, RemeshError, RemeshOptions, RemeshStats};
use super::wall::{build_wall, local_lumen_radius, Wall, WallOptions};
use super::VesselError;
use crate::math::Vec3;
use crate::mesh::surface::{check_surface, CheckOptions, CheckedSurface};
use parry3d_f64::math::Vector as PVec;
use parry3d_f64::shape::{CompositeShapeRef, TriMesh};

/// The fewest vertices around a vessel that the remeshed lumen keeps.
pub const NODES_AROUND: usize = 8;

/// The size the lumen is remeshed to.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum SurfaceSize {
    /// Keep the surface's own triangles.
    Input,
    /// A node count of the wall (within 2 %): the lumen gets
    /// nodes / (layers + 1) vertices.
    Nodes(usize),
    /// A target edge length (m).
    EdgeLength(f64),
}

/// What [`mesh_vessel`] does.
#[derive(Debug, Clone, PartialEq)]
pub struct VesselOptions {
    /// Thickness and layers.
    pub wall: WallOptions,
    /// Target size of the lumen.
    pub size: SurfaceSize,
    /// Cutting planes, applied in order before caps are looked for.
    pub cuts: Vec<CutPlane>,
    /// Cap detection.
    pub caps: CapOptions,
}

impl Default for VesselOptions {
    fn default() -> Self {
        VesselOptions {
            wall: WallOptions::default(),
            size: SurfaceSize::Input,
            cuts: Vec::new(),
            caps: CapOptions::default(),
        }
    }
}

/// What [`mesh_vessel`] built.
#[derive(Debug, Clone)]
pub struct VesselMesh {
    /// The wall, with segment labels on every node.
    pub wall: Wall,
    /// Caps removed.
    pub caps: Vec<Cap>,
    /// Per cut, the triangles (of the surface it cut) of the pieces dropped.
    pub dropped_pieces: Vec<Vec<usize>>,
    /// The remeshing, if a size was asked for: its figures and the largest
    /// target edge length (m).
    pub remesh: Option<(RemeshStats, f64)>,
    /// Segment names, in label order.
    pub segments: Vec<String>,
}

/// The tolerance on the lumen vertex count for [`SurfaceSize::Nodes`]: the
/// node count is the vertex count times (layers + 1), asked within 2 %.
const COUNT_TOLERANCE: f64 = 0.015;

/// Runs the pipeline on a checked surface (see the module documentation).
pub fn mesh_vessel(checked: &CheckedSurface, opts: &VesselOptions) -> Result<VesselMesh, VesselError> {
    let layers = opts.wall.layers;
    if layers == 0 || layers > 64 {
        return Err(VesselError::BadOption(format!(
            "layers must be between 1 and 64, got {layers}"
        )));
    }
    let opened = open_surface(checked, &opts.cuts, &opts.caps)?;
    // A closed input opened only by removing caps: a later failure may come
    // from caps that are not the vessel's ends, so the error says so and
    // names the way out.
    let by_caps_only = checked.report.boundary_loops.is_empty() && opts.cuts.is_empty() && !opened.caps.is_empty();
    let caps: Vec<Vec3> = opened.caps.iter().map(|c| c.centre).collect();
    mesh_opened(opened, opts).map_err(|e| {
        // An option out of range is not the openings' fault.
        if by_caps_only && !matches!(e, VesselError::BadOption(_)) {
            VesselError::OpenedByCaps {
                caps: caps.len(),
                centres: caps
                    .iter()
                    .map(|c| format!("({:.1}, {:.1}, {:.1}) mm", c.x * 1e3, c.y * 1e3, c.z * 1e3))
                    .collect::<Vec<_>>()
                    .join(", "),
                source: Box::new(e),
            }
        } else {
            e
        }
    })
}

/// [`mesh_vessel`] after the opening.
fn mesh_opened(opened: super::caps::Opened, opts: &VesselOptions) -> Result<VesselMesh, VesselError> {
    let layers = opts.wall.layers;
    let mut surface = opened.surface;
    let mut remesh_info = None;
    if opts.size != SurfaceSize::Input {
        let radius = local_lumen_radius(&surface)?;
        let lookup = RadiusLookup::new(&surface, &radius);
        let c = around_cap(NODES_AROUND);
        let cap = |p: &Vec3| c * lookup.at(p);
        let ropts = RemeshOptions::default();
        let (r, size) = match opts.size {
            SurfaceSize::Input | SurfaceSize::EdgeLength(_) => {
                let e = match opts.size {
                    SurfaceSize::EdgeLength(e) => e,
                    _ => f64::INFINITY,
                };
                if !(e.is_finite() && e > 0.0) {
                    return Err(VesselError::BadOption(format!(
                        "edge length must be finite and positive, got {e} m"
                    )));
                }
                let field = |p: &Vec3| e.min(cap(p));
                (remesh(&surface.mesh, &field, &ropts).map_err(remesh_error)?, e)
            }
            SurfaceSize::Nodes(nodes) => {
                let per_layer = nodes / (layers + 1);
                if per_layer < 16 {
                    return Err(VesselError::BadOption(format!(
                        "{nodes} nodes over {} node layers leave {per_layer} lumen vertices; at least 16 are needed",
                        layers + 1
                    )));
                }
                match remesh_to_vertex_count(&surface.mesh, per_layer, &cap, &ropts, COUNT_TOLERANCE) {
                    Ok((s, r)) => (r, s),
                    Err(RemeshError::CountNotReached { best, .. }) if best > per_layer => {
                        let thinnest = radius.iter().copied().fold(f64::INFINITY, f64::min);
                        return Err(VesselError::TooCoarse {
                            nodes,
                            fewest: best * (layers + 1),
                            thinnest_radius: thinnest,
                        });
                    }
                    Err(e) => return Err(remesh_error(e)),
                }
            }
        };
        let stats = r.stats;
        surface = check_surface(&r.mesh, &CheckOptions::default()).map_err(|source| VesselError::Recheck {
            step: "remeshing".to_string(),
            source,
        })?;
        remesh_info = Some((stats, size));
    }
    let seg = segment_labels(&surface);
    let mut wall = build_wall(&surface, &opts.wall)?;
    let n = surface.mesh.vertices.len();
    let labels: Vec<u8> = (0..wall.mesh.num_nodes()).map(|i| seg.labels[i % n]).collect();
    let names: Vec<&str> = seg.names.iter().map(String::as_str).collect();
    wall.mesh.set_segment_labels(&names, &labels)?;
    Ok(VesselMesh {
        wall,
        caps: opened.caps,
        dropped_pieces: opened.dropped_pieces,
        remesh: remesh_info,
        segments: seg.names,
    })
}

fn remesh_error(e: RemeshError) -> VesselError {
    VesselError::BadOption(format!("remeshing the lumen: {e}"))
}

/// The local lumen radius anywhere near the surface: the mean of the
/// radii at the corners of the closest triangle.
struct RadiusLookup<'a> {
    bvh: Option<TriMesh>,
    triangles: &'a [[u32; 3]],
    radius: &'a [f64],
    fallback: f64,
}

impl<'a> RadiusLookup<'a> {
    fn new(surface: &'a CheckedSurface, radius: &'a [f64]) -> Self {
        let m = &surface.mesh;
        let verts = m.vertices.iter().map(|p| PVec::new(p.x, p.y, p.z)).collect();
        RadiusLookup {
            bvh: TriMesh::new(verts, m.triangles.clone()).ok(),
            triangles: &m.triangles,
            radius,
            fallback: radius.iter().copied().fold(f64::INFINITY, f64::min),
        }
    }

    fn at(&self, p: &Vec3) -> f64 {
        let Some(bvh) = &self.bvh else {
            return self.fallback;
        };
        match CompositeShapeRef(bvh).project_local_point_and_get_location(PVec::new(p.x, p.y, p.z), f64::MAX, false) {
            Some((t, _, _)) => match self.triangles.get(t as usize) {
                Some(tri) => tri.iter().map(|&v| self.radius[v as usize]).sum::<f64>() / 3.0,
                None => self.fallback,
            },
            None => self.fallback,
        }
    }
}
