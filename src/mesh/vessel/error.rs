//! Why a lumen surface could not be turned into a vessel wall.

use crate::math::Vec3;
use crate::mesh::surface::SurfaceDefect;
use crate::mesh::TopologyError;

/// Formats a point in millimetres for messages.
pub(crate) fn mm(p: &Vec3) -> String {
    format!("({:.3}, {:.3}, {:.3}) mm", p.x * 1e3, p.y * 1e3, p.z * 1e3)
}

/// Why the vessel pipeline refused a surface or its options. Vertex and
/// triangle indices are those of the checked surface the step was given;
/// positions are printed in millimetres.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum VesselError {
    /// A wall option is out of range (thickness, ratio, layers).
    #[error("{0}")]
    BadOption(String),
    /// The surface is closed and no flat cap was found to open it.
    #[error(
        "the surface is closed: it has no opening (boundary loop) and no planar cap was detected \
         ({triangles} triangles); a vessel wall needs at least one open end: cut it open with \
         --cut px,py,pz,nx,ny,nz (a plane; the side the normal points to is removed)"
    )]
    NoOpening {
        /// Triangles of the surface.
        triangles: usize,
    },
    /// The surface was closed and was opened by removing the flat caps
    /// found on it; a later step failed. The caps may not be the vessel's
    /// ends (a segmentation can have flat patches that are not caps, and a
    /// cap that shares a vertex with another is kept).
    #[error(
        "{source}\n(the input surface was closed: it was opened by removing {caps} planar cap(s) detected on it, \
         centred at {centres}; if these are not the vessel's ends, open it where the vessel is cut instead: \
         --cut px,py,pz,nx,ny,nz per end (a plane; the side the normal points to is removed), \
         or `nvtmm mesh info FILE` to see its openings)"
    )]
    OpenedByCaps {
        /// How many caps were removed.
        caps: usize,
        /// Their centres (mm), for the message.
        centres: String,
        /// What failed after the opening.
        source: Box<VesselError>,
    },
    /// A cutting plane is unusable.
    #[error("cut {index} (point {}, normal ({:.3}, {:.3}, {:.3})): {what}", mm(point), normal.x, normal.y, normal.z)]
    BadCut {
        /// Zero-based index of the cut in the order given.
        index: usize,
        /// A point of the plane (m).
        point: Vec3,
        /// The plane's normal as given.
        normal: Vec3,
        /// What is wrong.
        what: String,
    },
    /// The surface is no longer valid after caps were removed or cuts made.
    #[error("after {step}: {source}")]
    Recheck {
        /// What was done ("removing 2 caps", "cut 0").
        step: String,
        /// What the check refused.
        source: SurfaceDefect,
    },
    /// A vertex has no usable normal (its triangles cancel out).
    #[error(
        "vertex {vertex} at {}: its triangles' normals cancel out, so there is no outward direction to offset along",
        mm(position)
    )]
    NoNormal {
        /// The vertex.
        vertex: usize,
        /// Its position (m).
        position: Vec3,
    },
    /// The local lumen radius (for a thickness ratio) could not be estimated.
    #[error("no vertex's inward ray hits the opposite wall: the local lumen radius cannot be estimated for --wall-ratio; give an absolute --wall-thickness")]
    NoRadius,
    /// The outward offset inverts (or flattens) a wall element: the
    /// thickness is larger than the surface's concave curvature radius
    /// allows there.
    #[error(
        "wall thickness too large: offsetting triangle {triangle} (vertices {}, {}, {}) by {:.3} mm inverts \
         layer {layer} near vertex {vertex} at {}, where the lumen surface curves concavely with a radius of \
         about {:.3} mm (the offset must stay well below it); use a thinner wall (--wall-thickness), a ratio \
         (--wall-ratio), or smooth the surface there",
        vertices[0], vertices[1], vertices[2], thickness * 1e3, mm(position), curvature_radius * 1e3
    )]
    Inverted {
        /// The lumen triangle whose prism inverts.
        triangle: usize,
        /// Its three vertices.
        vertices: [u32; 3],
        /// The prism layer (0 = next to the lumen).
        layer: usize,
        /// The triangle's vertex with the tightest concave curvature
        /// relative to its thickness.
        vertex: usize,
        /// That vertex's position (m).
        position: Vec3,
        /// Its wall thickness (m).
        thickness: f64,
        /// Its estimated concave curvature radius (m; infinite if convex).
        curvature_radius: f64,
    },
    /// The node count asked for cannot keep eight vertices around the
    /// thinnest vessel.
    #[error(
        "{nodes} nodes are too few for this surface: keeping 8 nodes around its thinnest vessel \
         (lumen radius {:.3} mm) takes at least about {fewest} nodes; ask for more (--nodes) or give an --edge-length",
        thinnest_radius * 1e3
    )]
    TooCoarse {
        /// The node count asked for.
        nodes: usize,
        /// The fewest nodes the size cap gives.
        fewest: usize,
        /// The smallest local lumen radius (m).
        thinnest_radius: f64,
    },
    /// The tetrahedral mesh was refused (should not happen after the checks above).
    #[error("building the tetrahedral wall: {0}")]
    Mesh(#[from] TopologyError),
}
