//! Triangle surfaces: what users bring (a segmented lumen exported by 3D
//! Slicer, vmtk or ITK-SNAP as STL, OBJ, PLY or VTK polydata) and what the
//! vessel pipeline ([`crate::mesh::vessel`]) turns into a tetrahedral wall.
//!
//! [`SurfaceMesh`] is plain data: vertices in metres and triangles indexing
//! them. The readers and the checks that refuse bad surfaces (non-manifold
//! edges, self-intersections, several bodies, a size in the wrong unit) live
//! in the submodules.

use crate::math::Vec3;

/// A triangle surface: vertex positions (m) and triangles (vertex indices,
/// counter-clockwise seen from outside where the surface is closed).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SurfaceMesh {
    /// Vertex positions (m).
    pub vertices: Vec<Vec3>,
    /// Triangles as vertex indices.
    pub triangles: Vec<[u32; 3]>,
}
