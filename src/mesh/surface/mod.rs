//! Triangle surfaces: what users bring (a segmented lumen exported by 3D
//! Slicer, vmtk or ITK-SNAP as STL, OBJ, PLY or VTK polydata) and what the
//! vessel pipeline ([`crate::mesh::vessel`]) turns into a tetrahedral wall.
//!
//! [`SurfaceMesh`] is plain data: vertices in metres and triangles indexing
//! them. [`read_surface`] / [`read_surface_bytes`] read the five formats
//! (chosen by extension, [`SurfaceFormat::from_path`]); [`check_surface`]
//! cleans a surface (degenerate and duplicate triangles, unused vertices,
//! orientation) and refuses what cannot be meshed (non-manifold edges and
//! vertices, several bodies, a size in the wrong unit, self-intersections),
//! and extracts the openings (boundary loops) with their centres, normals and
//! areas. [`read_and_check`] does both. `docs/FORMATS.md` ("Surface
//! formats") says what each reader keeps, skips and rejects.
//!
//! No reader panics on any input, and no count a file declares is trusted
//! for an allocation beyond what the file can hold. Errors name the file and
//! the line (text formats), the byte offset (binary data) and the element.
//!
//! ```
//! use nvtmm::mesh::surface::{check_surface, read_surface_bytes, CheckOptions, SurfaceFormat};
//! // One triangle in millimetres, as an OBJ file.
//! let obj = b"v 0 0 0\nv 10 0 0\nv 0 10 0\nf 1 2 3\n";
//! let s = read_surface_bytes(SurfaceFormat::Obj, "tri.obj".as_ref(), obj, 1e-3).unwrap();
//! assert_eq!(s.triangles, vec![[0, 1, 2]]);
//! assert_eq!(s.vertices[1].x, 0.01);
//! let checked = check_surface(&s, &CheckOptions::default()).unwrap();
//! assert_eq!(checked.report.boundary_loops.len(), 1); // an open triangle: one opening
//! ```

pub mod check;
mod intersect;
mod obj;
mod ply;
mod stl;
mod vtk;

pub use check::{check_surface, BoundaryLoop, CheckOptions, CheckedSurface, SurfaceDefect, SurfaceReport};

use crate::math::Vec3;
use crate::mesh::io::MeshError;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// A triangle surface: vertex positions (m) and triangles (vertex indices,
/// counter-clockwise seen from outside where the surface is closed).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SurfaceMesh {
    /// Vertex positions (m).
    pub vertices: Vec<Vec3>,
    /// Triangles as vertex indices.
    pub triangles: Vec<[u32; 3]>,
}

impl SurfaceMesh {
    /// An open circular tube along z from 0 to `length`, `around` vertices
    /// on each of `rings` rings (at least 2), triangles wound so that their
    /// normals point out of the lumen: the simplest vessel-like surface, for
    /// trying the wall builder and the readers.
    pub fn open_tube(radius: f64, length: f64, around: usize, rings: usize) -> SurfaceMesh {
        let mut s = SurfaceMesh::default();
        let rings = rings.max(2);
        for j in 0..rings {
            for k in 0..around {
                let a = std::f64::consts::TAU * k as f64 / around as f64;
                s.vertices.push(Vec3::new(
                    radius * a.cos(),
                    radius * a.sin(),
                    length * j as f64 / (rings - 1) as f64,
                ));
            }
        }
        let id = |j: usize, k: usize| (j * around + k % around) as u32;
        for j in 0..rings - 1 {
            for k in 0..around {
                s.triangles.push([id(j, k), id(j, k + 1), id(j + 1, k + 1)]);
                s.triangles.push([id(j, k), id(j + 1, k + 1), id(j + 1, k)]);
            }
        }
        s
    }
}

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
    /// The file's text does not follow the format.
    #[error("{path}:{line}: {msg}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong (and which element, vertex or index).
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
    /// The content is malformed or the surface is unusable: `what` says
    /// what is wrong and where (line, element, vertices).
    #[error("{path}: {what}")]
    Invalid {
        /// The file (or a label for an in-memory surface).
        path: PathBuf,
        /// What is wrong and where.
        what: String,
    },
    /// The surface was read but [`check_surface`] refused it.
    #[error("{path}: {source}")]
    Defect {
        /// The file.
        path: PathBuf,
        /// What is wrong with the surface.
        source: SurfaceDefect,
    },
}

impl SurfaceError {
    /// The error of a reader built on the volume-mesh scanner, with the same
    /// location (line, byte offset or cell).
    fn from_mesh(e: MeshError) -> SurfaceError {
        match e {
            MeshError::Io { path, source } => SurfaceError::Io { path, source },
            MeshError::Parse { path, line, msg } => SurfaceError::Parse { path, line, msg },
            MeshError::Binary { path, offset, msg } => SurfaceError::Binary { path, offset, msg },
            MeshError::Element {
                path,
                line,
                kind,
                element,
                msg,
            } => SurfaceError::Parse {
                path,
                line,
                msg: format!("{kind} {element}: {msg}"),
            },
            MeshError::UnknownFormat { path, .. } => SurfaceError::UnknownFormat { path },
            MeshError::Unsupported { path, what } | MeshError::InvalidData { path, what } => {
                SurfaceError::Invalid { path, what }
            }
            MeshError::Topology { path, source } => SurfaceError::Invalid {
                path,
                what: source.to_string(),
            },
        }
    }
}

/// A surface file format, chosen by extension (case-insensitive).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SurfaceFormat {
    /// `.stl`: ASCII or binary (told apart by the file size, 84 + 50 n).
    Stl,
    /// `.obj`: Wavefront `v` and `f` lines.
    Obj,
    /// `.ply`: Stanford PLY, ASCII or binary of either byte order.
    Ply,
    /// `.vtk`: VTK legacy `POLYDATA`, ASCII or BINARY.
    Vtk,
    /// `.vtp`: VTK XML `PolyData`.
    Vtp,
}

impl SurfaceFormat {
    /// The format for a path's extension.
    pub fn from_path(path: &Path) -> Result<SurfaceFormat, SurfaceError> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .unwrap_or("")
            .to_ascii_lowercase();
        Ok(match ext.as_str() {
            "stl" => SurfaceFormat::Stl,
            "obj" => SurfaceFormat::Obj,
            "ply" => SurfaceFormat::Ply,
            "vtk" => SurfaceFormat::Vtk,
            "vtp" => SurfaceFormat::Vtp,
            _ => {
                return Err(SurfaceError::UnknownFormat {
                    path: path.to_path_buf(),
                })
            }
        })
    }
}

/// Reads a surface file (STL ASCII or binary, OBJ, PLY, VTK legacy
/// polydata, VTP), multiplying coordinates by `scale` (0.001 for a file in
/// millimetres). The format is chosen by extension.
pub fn read_surface(path: &Path, scale: f64) -> Result<SurfaceMesh, SurfaceError> {
    let format = SurfaceFormat::from_path(path)?;
    check_scale(path, scale)?;
    let bytes = std::fs::read(path).map_err(|source| SurfaceError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    read_surface_bytes(format, path, &bytes, scale)
}

/// Parses a surface held in memory; `label` only names it in errors.
/// Coordinates are multiplied by `scale`. STL vertices (stored once per
/// triangle) are welded ([`weld_vertices`] with 1e-9 of the bounding-box
/// diagonal); other formats keep the file's vertices and their order.
/// Triangles keep the file's order (polygons are split into fans in place).
pub fn read_surface_bytes(
    format: SurfaceFormat,
    label: &Path,
    bytes: &[u8],
    scale: f64,
) -> Result<SurfaceMesh, SurfaceError> {
    check_scale(label, scale)?;
    let mut mesh = match format {
        SurfaceFormat::Stl => stl::read(label, bytes),
        SurfaceFormat::Obj => obj::read(label, bytes),
        SurfaceFormat::Ply => ply::read(label, bytes),
        SurfaceFormat::Vtk => vtk::read_legacy(label, bytes),
        SurfaceFormat::Vtp => vtk::read_vtp(label, bytes),
    }
    .map_err(SurfaceError::from_mesh)?;
    if mesh.triangles.is_empty() {
        return Err(SurfaceError::Invalid {
            path: label.to_path_buf(),
            what: "the file holds no triangles".into(),
        });
    }
    if scale != 1.0 {
        for p in &mut mesh.vertices {
            *p *= scale;
        }
    }
    if let Some(i) = mesh.vertices.iter().position(|p| !p.iter().all(|v| v.is_finite())) {
        return Err(SurfaceError::Invalid {
            path: label.to_path_buf(),
            what: format!("vertex {i}: a coordinate times the scale {scale} is not finite"),
        });
    }
    Ok(mesh)
}

/// Reads a surface ([`read_surface`]) and checks it ([`check_surface`]);
/// `options.scale` is replaced by `scale`, so a wrong-unit error names the
/// scale to pass instead.
pub fn read_and_check(path: &Path, scale: f64, options: &CheckOptions) -> Result<CheckedSurface, SurfaceError> {
    let mesh = read_surface(path, scale)?;
    let options = CheckOptions { scale, ..*options };
    check_surface(&mesh, &options).map_err(|source| SurfaceError::Defect {
        path: path.to_path_buf(),
        source,
    })
}

/// A scale must be finite and positive (a negative one would turn the surface inside out).
fn check_scale(path: &Path, scale: f64) -> Result<(), SurfaceError> {
    if scale.is_finite() && scale > 0.0 {
        Ok(())
    } else {
        Err(SurfaceError::Invalid {
            path: path.to_path_buf(),
            what: format!("scale {scale} must be finite and positive"),
        })
    }
}

/// Merges vertices closer than `tol` (Euclidean distance; 0 merges only
/// bit-identical positions), renumbering the triangles, in O(n): first
/// bit-identical positions (one hash look-up each), then the distinct
/// positions on a hashed grid of cell 2 `tol` (8 cells looked up each). The
/// first vertex of a group keeps its position and vertices keep their
/// first-seen order. Returns the number of vertices removed. Triangles that
/// become degenerate (a repeated vertex) are kept: [`check_surface`] removes
/// and counts them.
pub fn weld_vertices(mesh: &mut SurfaceMesh, tol: f64) -> usize {
    let n = mesh.vertices.len();
    let mut map = vec![0u32; n];
    let mut kept: Vec<Vec3> = Vec::with_capacity(n);
    let mut seen: FastMap<[u64; 3], u32> = FastMap::with_capacity_and_hasher(n, Default::default());
    for (i, p) in mesh.vertices.iter().enumerate() {
        // +0.0 and -0.0 are the same position.
        let bits = [p.x + 0.0, p.y + 0.0, p.z + 0.0].map(f64::to_bits);
        map[i] = *seen.entry(bits).or_insert_with(|| {
            kept.push(*p);
            (kept.len() - 1) as u32
        });
    }
    drop(seen);
    if tol > 0.0 && tol.is_finite() {
        let h = 2.0 * tol;
        let mut grid: FastMap<[i64; 3], Vec<u32>> = FastMap::with_capacity_and_hasher(kept.len(), Default::default());
        let mut merged: Vec<Vec3> = Vec::with_capacity(kept.len());
        let mut to = vec![0u32; kept.len()];
        for (i, p) in kept.iter().enumerate() {
            let c = p / h;
            let k = c.map(|x| x.floor() as i64);
            // The tol-ball reaches at most the neighbour cell on the nearer side.
            let side = [0, 1, 2].map(|a| if c[a] - c[a].floor() < 0.5 { -1i64 } else { 1 });
            let mut found = None;
            'search: for m in 0..8 {
                let key = [0, 1, 2].map(|a| {
                    if m >> a & 1 == 1 {
                        k[a].saturating_add(side[a])
                    } else {
                        k[a]
                    }
                });
                if let Some(ids) = grid.get(&key) {
                    if let Some(&j) = ids.iter().find(|&&j| (merged[j as usize] - p).norm() <= tol) {
                        found = Some(j);
                        break 'search;
                    }
                }
            }
            to[i] = found.unwrap_or_else(|| {
                let j = merged.len() as u32;
                merged.push(*p);
                grid.entry([k.x, k.y, k.z]).or_default().push(j);
                j
            });
        }
        for m in &mut map {
            *m = to[*m as usize];
        }
        kept = merged;
    }
    for t in &mut mesh.triangles {
        for v in t.iter_mut() {
            if let Some(&m) = map.get(*v as usize) {
                *v = m;
            }
        }
    }
    let removed = n - kept.len();
    mesh.vertices = kept;
    removed
}

/// A fast hash for the integer keys of the welding and intersection grids
/// (the multiply-rotate of rustc's FxHash); inputs are not adversarial
/// enough for SipHash to matter, and it is several times faster.
#[derive(Default, Clone, Copy)]
pub(crate) struct FastHasher(u64);

impl std::hash::Hasher for FastHasher {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.write_u64(u64::from(b));
        }
    }
    fn write_u64(&mut self, x: u64) {
        self.0 = (self.0.rotate_left(5) ^ x).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
    }
    fn write_i64(&mut self, x: i64) {
        self.write_u64(x as u64);
    }
    fn write_usize(&mut self, x: usize) {
        self.write_u64(x as u64);
    }
}

/// A hash map with [`FastHasher`].
pub(crate) type FastMap<K, V> = HashMap<K, V, std::hash::BuildHasherDefault<FastHasher>>;

/// The diagonal of a point set's bounding box (0 for no points).
pub(crate) fn bbox_diagonal(points: &[Vec3]) -> f64 {
    if points.is_empty() {
        return 0.0;
    }
    let (lo, hi) = crate::mesh::bbox(points);
    (hi - lo).norm()
}

/// Splits a polygon into a fan of triangles around its first vertex.
fn fan(poly: &[u32], out: &mut Vec<[u32; 3]>) {
    for k in 1..poly.len().saturating_sub(1) {
        out.push([poly[0], poly[k], poly[k + 1]]);
    }
}

/// An index from a file as a vertex index, if it is in `0..n`.
fn vertex_index(i: i64, n: usize) -> Option<u32> {
    u32::try_from(i).ok().filter(|&v| (v as usize) < n)
}
