//! Mesh file formats: reading volume meshes a user brings and writing them
//! (and their surfaces) for ParaView and other tools.
//!
//! The format is chosen from the file extension ([`Format::from_path`]):
//! [`read_mesh`] / [`read_mesh_scaled`] and [`write_mesh`] dispatch on it;
//! [`read_mesh_bytes`] and [`read_tetgen_bytes`] parse files held in memory.
//! Each format lives in its own submodule (`gmsh`, `vtk`, `vtu`, `tetgen`,
//! `surface`); `scan` is the byte cursor they share. For simulation output,
//! [`write_vtu_with_data`] and [`PvdSeries`] write ParaView time series.
//! `docs/FORMATS.md` says what each reader keeps, skips and rejects.
//!
//! Every reader returns a [`MeshError`] naming the file, the line, element or
//! byte offset and what is wrong; no reader panics on any input, and no
//! header count is trusted for an allocation beyond what the file can hold.
//! Coordinates are read as they are in the file; callers choose the unit (see
//! [`read_mesh_scaled`]). Writers print `f64` in shortest round-trip form, so
//! write-then-read is bit-exact.
//!
//! ```
//! use nvtmm::mesh::arch::{generate, ArchParams};
//! use nvtmm::mesh::io::{read_mesh, write_mesh};
//! let mesh = generate(&ArchParams::default(), 300).unwrap().mesh;
//! let dir = tempfile::tempdir().unwrap();
//! let path = dir.path().join("arch.vtu");
//! write_mesh(&mesh, &path).unwrap();
//! let back = read_mesh(&path).unwrap();
//! assert_eq!(back.rest(), mesh.rest());
//! assert_eq!(back.node_sets(), mesh.node_sets());
//! ```

mod gmsh;
pub(crate) mod scan;
mod surface;
mod tetgen;
pub(crate) mod vtk;
pub(crate) mod vtkdata;
pub(crate) mod vtu;

pub use gmsh::write_gmsh;
pub use surface::{write_obj, write_ply, write_stl};
pub use tetgen::{read_tetgen_bytes, write_tetgen};
pub use vtk::write_vtk;
pub use vtu::{write_vtu, write_vtu_cells, write_vtu_with_data, PvdSeries};

use super::{TetMesh, TopologyError};
use crate::math::Vec3;
use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, Write};
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
    /// Binary data that does not follow the format, located by byte offset.
    #[error("{path}: byte {offset}: {msg}")]
    Binary {
        /// The file.
        path: PathBuf,
        /// Byte offset from the start of the file.
        offset: usize,
        /// What is wrong.
        msg: String,
    },
    /// An element (cell) the reader cannot use: a 3-D element that is not a
    /// linear tetrahedron, or one of an unknown type.
    #[error("{path}:{line}: {kind} {element}: {msg}")]
    Element {
        /// The file.
        path: PathBuf,
        /// 1-based line number (for binary VTK, the line of the data's header).
        line: usize,
        /// What the format calls it: "element" (Gmsh) or "cell" (VTK).
        kind: &'static str,
        /// The element's tag (Gmsh) or zero-based cell index (VTK).
        element: u64,
        /// What is wrong.
        msg: String,
    },
    /// Data handed to a writer does not fit the mesh (wrong length, non-finite time, …).
    #[error("{path}: {what}")]
    InvalidData {
        /// The file being written.
        path: PathBuf,
        /// What is wrong.
        what: String,
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
/// file in millimetres). TetGen pairs are found from either file's path.
pub fn read_mesh_scaled(path: &Path, scale: f64) -> Result<TetMesh, MeshError> {
    let format = Format::from_path(path)?;
    check_scale(path, scale)?;
    if format == Format::TetGen {
        return tetgen::read(path, scale);
    }
    if format.is_surface_only() {
        return read_mesh_bytes(format, path, &[], scale);
    }
    let bytes = std::fs::read(path).map_err(|source| MeshError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    read_mesh_bytes(format, path, &bytes, scale)
}

/// Parses a volume mesh held in memory; `path` only names it in errors.
/// TetGen needs two files: use [`read_tetgen_bytes`].
pub fn read_mesh_bytes(format: Format, path: &Path, bytes: &[u8], scale: f64) -> Result<TetMesh, MeshError> {
    check_scale(path, scale)?;
    let raw = match format {
        Format::Gmsh => gmsh::read(path, bytes)?,
        Format::VtkLegacy => vtk::read(path, bytes)?,
        Format::Vtu => vtu::read(path, bytes)?,
        Format::TetGen => {
            return Err(MeshError::Unsupported {
                path: path.to_path_buf(),
                what: "a TetGen mesh is two files (.node and .ele); use read_tetgen_bytes".into(),
            })
        }
        Format::Ply | Format::Obj | Format::Stl => {
            return Err(MeshError::Unsupported {
                path: path.to_path_buf(),
                what: "a surface-only file, not a volume (tet) mesh: if it is a vessel's lumen, \
                       `nvtmm mesh vessel FILE --out wall.vtu` builds the wall mesh from it (or give it as \
                       `[mesh] vessel = { surface = \"FILE\" }` in a scene); `nvtmm mesh info` describes it"
                    .into(),
            })
        }
    };
    raw.build(path, scale)
}

/// Writes a mesh in the format named by the extension (surface formats write
/// the boundary surface; TetGen writes both `.node` and `.ele`, 1-based).
pub fn write_mesh(mesh: &TetMesh, path: &Path) -> Result<(), MeshError> {
    match Format::from_path(path)? {
        Format::Gmsh => write_gmsh(mesh, path),
        Format::VtkLegacy => write_vtk(mesh, path),
        Format::Vtu => write_vtu(mesh, path),
        Format::TetGen => write_tetgen(mesh, path, 1),
        Format::Ply => write_ply(mesh, path),
        Format::Obj => write_obj(mesh, path),
        Format::Stl => write_stl(mesh, path),
    }
}

/// A scale must be finite and positive (a negative one would invert every tet).
fn check_scale(path: &Path, scale: f64) -> Result<(), MeshError> {
    if scale.is_finite() && scale > 0.0 {
        Ok(())
    } else {
        Err(MeshError::InvalidData {
            path: path.to_path_buf(),
            what: format!("scale {scale} must be finite and positive"),
        })
    }
}

/// What a reader hands back before mesh validation.
#[derive(Default)]
struct RawMesh {
    nodes: Vec<Vec3>,
    tets: Vec<[u32; 4]>,
    sets: BTreeMap<String, Vec<u32>>,
}

impl RawMesh {
    /// Scales, tidies node sets (sorted, unique) and validates.
    fn build(mut self, path: &Path, scale: f64) -> Result<TetMesh, MeshError> {
        if scale != 1.0 {
            for p in &mut self.nodes {
                *p *= scale;
            }
        }
        for ids in self.sets.values_mut() {
            ids.sort_unstable();
            ids.dedup();
        }
        TetMesh::new(self.nodes, self.tets, self.sets).map_err(|source| MeshError::Topology {
            path: path.to_path_buf(),
            source,
        })
    }
}

/// Runs `body` on a buffered new file and maps every I/O error to the path.
fn write_file(path: &Path, body: impl FnOnce(&mut BufWriter<File>) -> std::io::Result<()>) -> Result<(), MeshError> {
    let io = |source| MeshError::Io {
        path: path.to_path_buf(),
        source,
    };
    let file = File::create(path).map_err(io)?;
    let mut w = BufWriter::new(file);
    body(&mut w).map_err(io)?;
    w.flush().map_err(io)
}
