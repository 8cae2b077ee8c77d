//! On-disk cache of modal bases, so a restart does not recompute them.
//!
//! A basis is stored under a key: a 64-bit FNV-1a hash (stable across Rust
//! versions and platforms, unlike `DefaultHasher`) of everything it depends
//! on — the cache format version, the mesh's rest positions and tets, the
//! model name, the material constants and law, the lumped masses, the fixed
//! nodes, r, the contact nodes and static-mode budget, and the basis
//! tolerance and iteration limit; for a basis linearized about a
//! pressurized state ([`Pressurized`]), also the pressure and that state's
//! tangent (each entry rounded to single precision, so the last bits of a
//! static solve do not change the key). The file is `basis-<key as 16 hex>.bin` in
//! the cache directory.
//!
//! File format (all integers and floats little-endian; see docs/REDUCED.md):
//!
//! ```text
//! offset  size      field
//! 0       8         magic "NVTMMBAS"
//! 8       4         format version (u32) = FORMAT_VERSION
//! 12      8         key (u64)
//! 20      8         rows = 3 × nodes (u64)
//! 28      8         cols = m, basis vectors (u64)
//! 36      8         num_static (u64)
//! 44      8         iterations (u64)
//! 52      8         nfixed (u64)
//! 60      8·m       omega2 (f64)
//! ..      4·nfixed  fixed nodes (u32)
//! ..      8·rows·m  phi, column-major (f64)
//! ..      8         FNV-1a 64 of every byte before it (u64)
//! ```
//!
//! Writes go to a temporary file in the same directory, then `rename` over
//! the final name, so a reader never sees a half-written file. A missing file
//! is a miss; a corrupt, truncated or mismatched one is reported in the
//! [`CacheOutcome`] and recomputed (and rewritten), never a panic.

use super::basis::{BasisParams, ModalBasis, ReducedError};
use crate::material::{Law, Material};
use crate::math::Vec3;
use crate::mesh::TetMesh;
use crate::model::ForceModel;
use nalgebra::DMatrix;
use std::io::Write;
use std::path::{Path, PathBuf};

/// Version of the file format and of the key's content; bump it when either
/// changes so old files are recomputed, not misread.
pub const FORMAT_VERSION: u32 = 1;

/// The file's first eight bytes.
pub const MAGIC: &[u8; 8] = b"NVTMMBAS";

const HEADER_LEN: usize = 60;

/// FNV-1a, 64 bit: a small, stable, well-specified hash.
#[derive(Debug, Clone, Copy)]
pub struct Fnv1a(u64);

impl Default for Fnv1a {
    fn default() -> Self {
        Fnv1a(0xcbf2_9ce4_8422_2325)
    }
}

impl Fnv1a {
    /// Feeds bytes.
    pub fn bytes(&mut self, b: &[u8]) {
        for &x in b {
            self.0 ^= x as u64;
            self.0 = self.0.wrapping_mul(0x0000_0100_0000_01b3);
        }
    }
    /// Feeds a u64 (little-endian bytes).
    pub fn u64(&mut self, v: u64) {
        self.bytes(&v.to_le_bytes());
    }
    /// Feeds an f64 by its bit pattern (little-endian).
    pub fn f64(&mut self, v: f64) {
        self.u64(v.to_bits());
    }
    /// Feeds a length-prefixed string.
    pub fn str(&mut self, s: &str) {
        self.u64(s.len() as u64);
        self.bytes(s.as_bytes());
    }
    /// Feeds a material's constants and its law's name.
    pub fn material(&mut self, m: &Material, law: Law) {
        self.f64(m.youngs_pa);
        self.f64(m.poisson);
        self.f64(m.density);
        self.str(match law {
            Law::Stvk => "stvk",
            Law::NeoHookean => "neo_hookean",
        });
    }
    /// The hash.
    pub fn finish(&self) -> u64 {
        self.0
    }
}

/// Everything a cached basis depends on, and what computing it needs. The
/// basis is the linearization at rest (u = 0).
pub struct BasisRequest<'a> {
    /// The mesh.
    pub mesh: &'a TetMesh,
    /// The elastic force model whose rest stiffness K(0) defines the modes
    /// (a viscoelastic wrapper scales K by the step's 1 − Σ A_i: pass the
    /// elastic model).
    pub model: &'a dyn ForceModel,
    /// Material constants (hashed).
    pub material: Material,
    /// Law (hashed).
    pub law: Law,
    /// Lumped mass per node (kg).
    pub mass: &'a [f64],
    /// Fixed nodes.
    pub fixed: &'a [u32],
    /// Basis size.
    pub r: usize,
    /// Contact nodes (empty: no static modes).
    pub contact: &'a [u32],
    /// Static-mode budget for [`Statics::Compressed`](crate::reduced::basis::Statics::Compressed).
    pub max_static: usize,
    /// Stopping rule.
    pub params: BasisParams,
    /// None: linearized at rest (u = 0, `model`'s stiffness). Some: about
    /// the wall inflated to a luminal pressure, whose tangent carries the
    /// pressure's load stiffness.
    pub pressurized: Option<Pressurized<'a>>,
}

/// The state a basis is linearized about when the vessel holds a luminal
/// pressure (docs/PRESSURE.md, "The reduced model at pressure").
#[derive(Debug, Clone, Copy)]
pub struct Pressurized<'a> {
    /// The steady pressure the wall is inflated to (Pa).
    pub mean_pa: f64,
    /// The full model's tangent there, with the pressure's load stiffness
    /// ([`crate::scene::Inflated::tangent`]).
    pub tangent: &'a crate::model::BlockTangent,
}

impl BasisRequest<'_> {
    /// The cache key (see the module doc for what goes in).
    pub fn key(&self) -> u64 {
        let mut h = Fnv1a::default();
        h.bytes(MAGIC);
        h.u64(FORMAT_VERSION as u64);
        h.u64(self.mesh.num_nodes() as u64);
        for p in self.mesh.rest() {
            for c in p.iter() {
                h.f64(*c);
            }
        }
        h.u64(self.mesh.tets().len() as u64);
        for t in self.mesh.tets() {
            for &v in t {
                h.bytes(&v.to_le_bytes());
            }
        }
        h.str(self.model.name());
        h.material(&self.material, self.law);
        h.u64(self.mass.len() as u64);
        for &m in self.mass {
            h.f64(m);
        }
        let mut fixed = self.fixed.to_vec();
        fixed.sort_unstable();
        fixed.dedup();
        h.u64(fixed.len() as u64);
        for v in fixed {
            h.bytes(&v.to_le_bytes());
        }
        h.u64(self.r as u64);
        let mut contact = self.contact.to_vec();
        contact.sort_unstable();
        contact.dedup();
        h.u64(contact.len() as u64);
        for v in contact {
            h.bytes(&v.to_le_bytes());
        }
        h.u64(self.max_static as u64);
        h.f64(self.params.tol);
        h.u64(self.params.max_iterations as u64);
        if let Some(p) = &self.pressurized {
            h.str("pressurized");
            h.f64(p.mean_pa);
            let t = p.tangent;
            h.u64((t.diag.len() + t.off.len()) as u64);
            for b in t.diag.iter().chain(&t.off) {
                for v in b.iter() {
                    h.bytes(&(*v as f32).to_bits().to_le_bytes());
                }
            }
        }
        h.finish()
    }

    /// Computes the basis (no cache).
    pub fn compute(&self) -> Result<ModalBasis, ReducedError> {
        let u = vec![Vec3::zeros(); self.mesh.num_nodes()];
        ModalBasis::compute(&crate::reduced::BasisSpec {
            stiffness: match &self.pressurized {
                Some(p) => crate::reduced::Stiffness::Tangent(p.tangent),
                None => crate::reduced::Stiffness::Model {
                    mesh: self.mesh,
                    model: self.model,
                    u: &u,
                },
            },
            mass: self.mass,
            fixed: self.fixed,
            r: self.r,
            statics: crate::reduced::Statics::Compressed {
                contact: self.contact,
                max_static: self.max_static,
            },
            warm: None,
            params: self.params,
        })
    }
}

/// The cache file of `key` in `dir`.
pub fn cache_path(dir: &Path, key: u64) -> PathBuf {
    dir.join(format!("basis-{key:016x}.bin"))
}

/// What the cache did.
#[derive(Debug, Clone, PartialEq)]
pub enum CacheStatus {
    /// Loaded from the file.
    Hit,
    /// No file: computed (and stored unless storing failed).
    Computed,
    /// A file was there but unusable (the reason); recomputed and rewritten.
    Recomputed(String),
    /// Caching off, or `force`: computed, the file (if any) not read.
    Bypassed,
}

/// The outcome of [`load_or_compute`].
#[derive(Debug, Clone, PartialEq)]
pub struct CacheOutcome {
    /// What happened.
    pub status: CacheStatus,
    /// The cache file (None when caching is off).
    pub path: Option<PathBuf>,
    /// The key.
    pub key: u64,
    /// Why the basis could not be stored, if it could not (the basis is
    /// still returned).
    pub store_error: Option<String>,
    /// Wall time of the computation (s), 0 on a hit.
    pub compute_s: f64,
}

/// Errors reading a cache file (reported in [`CacheStatus::Recomputed`]).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CacheFileError {
    /// Not a basis file.
    #[error("bad magic (not an nvtmm basis file)")]
    Magic,
    /// Another format version.
    #[error("format version {0}, expected {FORMAT_VERSION}")]
    Version(u32),
    /// The key in the file is not the one asked for.
    #[error("key {got:016x} in the file, expected {expected:016x}")]
    Key {
        /// In the file.
        got: u64,
        /// Asked for.
        expected: u64,
    },
    /// Sizes disagree with the file length or the request.
    #[error("{0}")]
    Size(String),
    /// The checksum does not match (the file is corrupt).
    #[error("checksum mismatch (corrupt file)")]
    Checksum,
    /// A non-finite number.
    #[error("non-finite value in the basis")]
    NonFinite,
}

/// Serializes a basis with its key.
pub fn encode(basis: &ModalBasis, key: u64) -> Vec<u8> {
    let (rows, cols) = basis.phi.shape();
    let mut out = Vec::with_capacity(HEADER_LEN + 8 * cols + 4 * basis.fixed.len() + 8 * rows * cols + 8);
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
    out.extend_from_slice(&key.to_le_bytes());
    for v in [rows, cols, basis.num_static, basis.iterations, basis.fixed.len()] {
        out.extend_from_slice(&(v as u64).to_le_bytes());
    }
    for &w in &basis.omega2 {
        out.extend_from_slice(&w.to_le_bytes());
    }
    for &f in &basis.fixed {
        out.extend_from_slice(&f.to_le_bytes());
    }
    for &v in basis.phi.as_slice() {
        out.extend_from_slice(&v.to_le_bytes());
    }
    let mut h = Fnv1a::default();
    h.bytes(&out);
    out.extend_from_slice(&h.finish().to_le_bytes());
    out
}

/// Parses a basis file; `key` is the expected key, `rows` the expected
/// 3 × nodes.
pub fn decode(bytes: &[u8], key: u64, rows: usize) -> Result<ModalBasis, CacheFileError> {
    if bytes.len() < 12 || &bytes[..8] != MAGIC {
        return Err(CacheFileError::Magic);
    }
    let u32_at = |o: usize| u32::from_le_bytes([bytes[o], bytes[o + 1], bytes[o + 2], bytes[o + 3]]);
    let version = u32_at(8);
    if version != FORMAT_VERSION {
        return Err(CacheFileError::Version(version));
    }
    if bytes.len() < HEADER_LEN + 8 {
        return Err(CacheFileError::Size(format!(
            "{} bytes: shorter than the header",
            bytes.len()
        )));
    }
    let u64_at = |o: usize| {
        let mut b = [0u8; 8];
        b.copy_from_slice(&bytes[o..o + 8]);
        u64::from_le_bytes(b)
    };
    let body = bytes.len() - 8;
    let mut h = Fnv1a::default();
    h.bytes(&bytes[..body]);
    if h.finish() != u64_at(body) {
        return Err(CacheFileError::Checksum);
    }
    let got_key = u64_at(12);
    if got_key != key {
        return Err(CacheFileError::Key {
            got: got_key,
            expected: key,
        });
    }
    let [f_rows, cols, num_static, iterations, nfixed] = [20, 28, 36, 44, 52].map(u64_at);
    if f_rows != rows as u64 {
        return Err(CacheFileError::Size(format!("{f_rows} rows, the mesh needs {rows}")));
    }
    // Sizes in u128 so a corrupt header cannot overflow the arithmetic.
    let need = HEADER_LEN as u128 + 8 * cols as u128 + 4 * nfixed as u128 + 8 * f_rows as u128 * cols as u128 + 8;
    if need != bytes.len() as u128 || num_static > cols {
        return Err(CacheFileError::Size(format!(
            "header says {cols} columns and {nfixed} fixed nodes ({need} bytes), the file has {} bytes",
            bytes.len()
        )));
    }
    let (cols, nfixed) = (cols as usize, nfixed as usize);
    let f64_at = |o: usize| f64::from_bits(u64_at(o));
    let mut o = HEADER_LEN;
    let omega2: Vec<f64> = (0..cols).map(|j| f64_at(o + 8 * j)).collect();
    o += 8 * cols;
    let fixed: Vec<u32> = (0..nfixed).map(|j| u32_at(o + 4 * j)).collect();
    o += 4 * nfixed;
    let data: Vec<f64> = (0..rows * cols).map(|j| f64_at(o + 8 * j)).collect();
    if omega2.iter().chain(&data).any(|v| !v.is_finite()) {
        return Err(CacheFileError::NonFinite);
    }
    if fixed.iter().any(|&f| f as usize >= rows / 3) {
        return Err(CacheFileError::Size("a fixed node is out of range".into()));
    }
    Ok(ModalBasis {
        phi: DMatrix::from_vec(rows, cols, data),
        omega2,
        num_static: num_static as usize,
        fixed,
        iterations: iterations as usize,
    })
}

/// Writes `bytes` to `path` atomically: a temporary file in the same
/// directory (created if missing), synced, then renamed over `path`.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let dir = path.parent().unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir)?;
    let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("basis");
    let tmp = dir.join(format!(".{name}.{}.tmp", std::process::id()));
    let res = (|| {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if res.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    res
}

/// The basis `req` asks for: from `dir`'s cache file if it is there and
/// valid, otherwise computed and stored. `dir = None` turns caching off;
/// `force` recomputes and overwrites. Only a failed computation is an error;
/// a cache problem is reported in the outcome.
pub fn load_or_compute(
    req: &BasisRequest<'_>,
    dir: Option<&Path>,
    force: bool,
) -> Result<(ModalBasis, CacheOutcome), ReducedError> {
    let key = req.key();
    let path = dir.map(|d| cache_path(d, key));
    let mut status = CacheStatus::Computed;
    if let Some(p) = &path {
        if force {
            status = CacheStatus::Bypassed;
        } else {
            match std::fs::read(p) {
                Ok(bytes) => match decode(&bytes, key, 3 * req.mesh.num_nodes()) {
                    Ok(b) => {
                        let outcome = CacheOutcome {
                            status: CacheStatus::Hit,
                            path: path.clone(),
                            key,
                            store_error: None,
                            compute_s: 0.0,
                        };
                        return Ok((b, outcome));
                    }
                    Err(e) => status = CacheStatus::Recomputed(format!("{}: {e}", p.display())),
                },
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
                Err(e) => status = CacheStatus::Recomputed(format!("{}: {e}", p.display())),
            }
        }
    } else {
        status = CacheStatus::Bypassed;
    }
    let t0 = std::time::Instant::now();
    let basis = req.compute()?;
    let compute_s = t0.elapsed().as_secs_f64();
    let store_error = path.as_ref().and_then(|p| {
        write_atomic(p, &encode(&basis, key))
            .err()
            .map(|e| format!("{}: {e}", p.display()))
    });
    Ok((
        basis,
        CacheOutcome {
            status,
            path,
            key,
            store_error,
            compute_s,
        },
    ))
}

/// The basis a scene asks for (its `[reduced]` table; `r_override`
/// replaces `r`), on the mesh [`crate::scene::Scene::build`] made (region of
/// interest and fixed nodes included), linearized at rest with the scene's
/// elastic model (Prony terms do not change the instantaneous modes), through
/// the cache unless `[reduced].cache = false`. `force` recomputes and
/// overwrites. Errors name the scene key or the failed computation.
pub fn basis_for_scene(
    scene: &crate::scene::Scene,
    built: &crate::scene::Built,
    r_override: Option<usize>,
    force: bool,
) -> Result<(ModalBasis, CacheOutcome), String> {
    let red = scene.reduced.as_ref();
    let r = match (r_override, red) {
        (Some(r), _) => r,
        (None, Some(c)) => c.r,
        (None, None) => return Err(format!("{}: no [reduced] table (or give --r)", scene.path.display())),
    };
    if !(1..=crate::scene::MAX_REDUCED_R).contains(&r) {
        return Err(format!("r = {r}: must be in 1..={}", crate::scene::MAX_REDUCED_R));
    }
    let contact_modes = red.is_some_and(|c| c.contact_modes);
    let contact = if contact_modes {
        scene.contact_nodes(&built.mesh).map_err(|e| e.to_string())?
    } else {
        Vec::new()
    };
    let material = scene.material();
    let model = crate::model::factory::build_model(scene.model, &built.mesh, &material, scene.material.law, &[]);
    let mass = built.mesh.lumped_mass(material.density);
    let req = BasisRequest {
        mesh: &built.mesh,
        model: model.as_ref(),
        material,
        law: scene.material.law,
        mass: &mass,
        fixed: &built.fixed,
        r,
        contact: &contact,
        max_static: if contact_modes { r / 2 } else { 0 },
        params: BasisParams::default(),
        pressurized: None,
    };
    let dir = if red.is_none_or(|c| c.cache) {
        Some(scene.cache_dir())
    } else {
        None
    };
    load_or_compute(&req, dir.as_deref(), force).map_err(|e| format!("basis (r = {r}): {e}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fnv1a_matches_the_reference_vectors() {
        let h = |s: &str| {
            let mut f = Fnv1a::default();
            f.bytes(s.as_bytes());
            f.finish()
        };
        assert_eq!(h(""), 0xcbf2_9ce4_8422_2325);
        assert_eq!(h("a"), 0xaf63_dc4c_8601_ec8c);
        assert_eq!(h("foobar"), 0x8594_4171_f739_67e8);
    }

    #[test]
    fn decode_refuses_every_truncation() {
        let b = ModalBasis {
            phi: DMatrix::from_fn(6, 2, |i, j| (i * 2 + j) as f64),
            omega2: vec![1.0, 2.0],
            num_static: 1,
            fixed: vec![0],
            iterations: 3,
        };
        let bytes = encode(&b, 42);
        assert_eq!(decode(&bytes, 42, 6).unwrap(), b);
        assert!(matches!(decode(&bytes, 43, 6), Err(CacheFileError::Key { .. })));
        for len in 0..bytes.len() {
            assert!(decode(&bytes[..len], 42, 6).is_err(), "truncated to {len}");
        }
        for i in 0..bytes.len() {
            let mut c = bytes.clone();
            c[i] ^= 0x10;
            assert!(decode(&c, 42, 6).is_err(), "flipped byte {i}");
        }
    }
}
