//! Mesh file formats: reading volume meshes a user brings and writing them
//! (and their surfaces) for ParaView and other tools.
//!
//! The format is chosen from the file extension ([`Format::from_path`]).
//! Every reader returns a [`MeshError`] naming the file, the line or element
//! and what is wrong; no reader panics on any input. Coordinates are read as
//! they are in the file; callers choose the unit (see [`read_mesh_scaled`]).

use super::{TetMesh, TopologyError};
use std::path::{Path, PathBuf};

/// A mesh file format, chosen by extension.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    /// Gmsh `.msh` (reads 4.1 ASCII/binary and 2.2 ASCII; writes 4.1 ASCII).
    Gmsh,
    /// VTK legacy unstructured grid `.vtk`.
    VtkLegacy,
    /// VTK XML unstructured grid `.vtu`.
    Vtu,
    /// TetGen `.node` + `.ele` pair (either path may be given).
    TetGen,
    /// Surface only: Stanford `.ply`.
    Ply,
    /// Surface only: Wavefront `.obj`.
    Obj,
    /// Surface only: binary `.stl`.
    Stl,
}

impl Format {
    /// The format for a path's extension.
    pub fn from_path(path: &Path) -> Result<Format, MeshError> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .unwrap_or("")
            .to_ascii_lowercase();
        Ok(match ext.as_str() {
            "msh" => Format::Gmsh,
            "vtk" => Format::VtkLegacy,
            "vtu" => Format::Vtu,
            "node" | "ele" => Format::TetGen,
            "ply" => Format::Ply,
            "obj" => Format::Obj,
            "stl" => Format::Stl,
            _ => {
                return Err(MeshError::UnknownFormat {
                    path: path.to_path_buf(),
                    ext,
                });
            }
        })
    }

    /// Whether this format holds only a surface (cannot be read as a volume mesh).
    pub fn is_surface_only(self) -> bool {
        matches!(self, Format::Ply | Format::Obj | Format::Stl)
    }
}

/// Errors reading or writing mesh files. Each names the file and, where it
/// applies, the line or element.
#[derive(Debug, thiserror::Error)]
pub enum MeshError {
    /// The file could not be opened, read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// The extension names no format we know.
    #[error("{path}: unknown mesh format '.{ext}' (use .msh, .vtk, .vtu, .node/.ele, or .ply/.obj/.stl for surfaces)")]
    UnknownFormat {
        /// The file.
        path: PathBuf,
        /// The extension found.
        ext: String,
    },
    /// The format can be written but not read as a volume mesh.
    #[error("{path}: {what}")]
    Unsupported {
        /// The file.
        path: PathBuf,
        /// What is not supported.
        what: String,
    },
    /// The file's text or bytes do not follow the format.
    #[error("{path}:{line}: {msg}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// 1-based line number (0 when the format is binary or the line is unknown).
        line: usize,
        /// What is wrong.
        msg: String,
    },
    /// The file parsed but its mesh is invalid.
    #[error("{path}: {source}")]
    Topology {
        /// The file.
        path: PathBuf,
        /// What is wrong with the mesh.
        source: TopologyError,
    },
}

/// Reads a volume mesh, coordinates taken as they are in the file.
pub fn read_mesh(path: &Path) -> Result<TetMesh, MeshError> {
    read_mesh_scaled(path, 1.0)
}

/// Reads a volume mesh and multiplies coordinates by `scale` (e.g. 1e-3 for a
/// file in millimetres).
pub fn read_mesh_scaled(path: &Path, scale: f64) -> Result<TetMesh, MeshError> {
    let _ = (Format::from_path(path)?, scale);
    Err(MeshError::Unsupported {
        path: path.to_path_buf(),
        what: "reading is not implemented yet".into(),
    })
}

/// Writes a mesh in the format named by the extension (surface formats write
/// the boundary surface).
pub fn write_mesh(mesh: &TetMesh, path: &Path) -> Result<(), MeshError> {
    let _ = (Format::from_path(path)?, mesh);
    Err(MeshError::Unsupported {
        path: path.to_path_buf(),
        what: "writing is not implemented yet".into(),
    })
}
