//! Scenes: what to simulate, read from a TOML file and validated at start.
//!
//! A scene names the mesh (the built-in arch, a block, or a file), the
//! material and law, the model (`msm | tmm | nvtmm | fem`), Prony terms, fixed
//! regions, loads, the integrator and the outputs. Every key is checked before
//! anything runs; errors name the file, the key and the allowed range. See the
//! README ("Scenes") for the format, and `rt-config/scenes/` for examples.
//!
//! [`Scene::build`] turns a scene into the mesh, the model, the fixed nodes
//! and the loads the solver needs; running it lives in [`crate::simulate`].

use crate::material::{Law, Material, PronyTerm};
use crate::math::Vec3;
use crate::mesh::arch::{generate, ArchParams};
use crate::mesh::block::block;
use crate::mesh::io::read_mesh_scaled;
use crate::mesh::roi::{extract, Region, CUT_SET};
use crate::mesh::TetMesh;
use crate::model::fem::Fem;
use crate::model::msm::Msm;
use crate::model::nvtmm::Nvtmm;
use crate::model::tmm::Tmm;
use crate::model::viscoelastic::Viscoelastic;
use crate::model::{ForceModel, ModelKind};
use crate::solver::loads::{nodes_in_box, Loads, NodalLoad, TimeProfile};
use crate::solver::ImplicitEulerParams;
use serde::Deserialize;
use std::path::{Path, PathBuf};

/// A scene configuration error: the file, the key and what is allowed.
#[derive(Debug, thiserror::Error)]
#[error("{path}: {key}: {msg}")]
pub struct SceneError {
    /// The scene file (or `<inline>`).
    pub path: PathBuf,
    /// The offending key, dotted (e.g. `material.poisson`).
    pub key: String,
    /// What is wrong and what is allowed.
    pub msg: String,
}

/// Where the mesh comes from.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MeshConfig {
    /// The built-in aortic arch with about this many nodes.
    pub arch_nodes: Option<usize>,
    /// A box of tets: `{ cells = [nx, ny, nz], size = [x, y, z] }` (m).
    pub block: Option<BlockConfig>,
    /// A mesh file (.msh .vtk .vtu .node/.ele), relative to the scene file.
    pub file: Option<PathBuf>,
    /// Factor applied to the file's coordinates (0.001 for millimetres).
    #[serde(default = "one")]
    pub scale: f64,
}

/// A box mesh.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BlockConfig {
    /// Cells along x, y, z.
    pub cells: [usize; 3],
    /// Size along x, y, z (m).
    pub size: [f64; 3],
}

fn one() -> f64 {
    1.0
}

/// Material and law.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialConfig {
    /// `stvk` or `neo_hookean`.
    #[serde(default = "default_law")]
    pub law: Law,
    /// Young's modulus (Pa).
    pub youngs_pa: f64,
    /// Poisson's ratio.
    pub poisson: f64,
    /// Density (kg/m³).
    #[serde(default = "default_density")]
    pub density: f64,
}

fn default_law() -> Law {
    Law::Stvk
}
fn default_density() -> f64 {
    1050.0
}

/// An axis-aligned box (m).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BoxConfig {
    /// Lower corner.
    pub min: [f64; 3],
    /// Upper corner.
    pub max: [f64; 3],
}

/// Fixed (Dirichlet) regions.
#[derive(Debug, Clone, PartialEq, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FixedConfig {
    /// Named node sets of the mesh.
    #[serde(default)]
    pub sets: Vec<String>,
    /// Boxes: every node inside is fixed.
    #[serde(default)]
    pub boxes: Vec<BoxConfig>,
}

/// A nodal load: which nodes, the total force, and its time profile.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LoadConfig {
    /// Explicit node indices.
    #[serde(default)]
    pub nodes: Vec<u32>,
    /// A named node set.
    pub set: Option<String>,
    /// The surface node nearest this point (m).
    pub near: Option<[f64; 3]>,
    /// Total force (N), shared equally by the nodes.
    pub force_n: [f64; 3],
    /// Time profile (default: constant from t = 0).
    #[serde(default = "default_profile")]
    pub profile: TimeProfile,
}

fn default_profile() -> TimeProfile {
    TimeProfile::Constant { from_t0: 0.0 }
}

/// Outputs.
#[derive(Debug, Clone, PartialEq, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OutputConfig {
    /// Write a `.vtu` frame (and the `.pvd` series) every this many steps; 0 = never.
    #[serde(default)]
    pub vtu_every: usize,
    /// Write a CSV row every this many steps (0 = never; default 1 when
    /// probes exist).
    pub csv_every: Option<usize>,
    /// Nodes whose displacement and force go into `probes.csv`. The loaded
    /// nodes are always included.
    #[serde(default)]
    pub csv_nodes: Vec<u32>,
}

/// Largest reduced basis a scene may ask for (the largest capacity the
/// reduced model is compiled for).
pub const MAX_REDUCED_R: usize = 64;

/// The `[reduced]` table: the modal model of the haptic loop.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReducedConfig {
    /// Basis size (reduced coordinates), 1..=[`MAX_REDUCED_R`]. With
    /// `contact_modes`, up to half of them are static (attachment) modes of
    /// the contact region and the rest are vibration modes.
    pub r: usize,
    /// Add static (attachment) modes of the contact region.
    #[serde(default)]
    pub contact_modes: bool,
    /// Where the tool can touch (required with `contact_modes`).
    pub contact_region: Option<ContactRegionConfig>,
    /// Keep the basis in an on-disk cache (default true).
    #[serde(default = "yes")]
    pub cache: bool,
    /// Cache directory (default: `$XDG_CACHE_HOME/nvtmm`, else
    /// `~/.cache/nvtmm`, else `.nvtmm-cache`); relative paths resolve against
    /// the scene file.
    pub cache_dir: Option<PathBuf>,
    /// Reduced mass-proportional Rayleigh damping α (1/s), in [0, 1e4].
    #[serde(default)]
    pub alpha: f64,
    /// Reduced stiffness-proportional Rayleigh damping β (s), in [0, 1].
    #[serde(default)]
    pub beta: f64,
}

fn yes() -> bool {
    true
}

/// Where the tool can touch: the nodes inside a sphere, the nodes of a named
/// set, or the nodes of the set inside the sphere.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ContactRegionConfig {
    /// Sphere centre (m).
    pub center: Option<[f64; 3]>,
    /// Sphere radius (m).
    pub radius: Option<f64>,
    /// A node set of the mesh (e.g. `outer_wall`).
    pub set: Option<String>,
}

/// A sphere (m).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SphereConfig {
    /// Centre.
    pub center: [f64; 3],
    /// Radius.
    pub radius: f64,
}

/// The `[roi]` table: exactly one of a box, a sphere, or an interval of arc
/// length along the built-in arch's centreline. A tet is kept when its
/// centroid is inside (for `arclength`: when all its nodes' rings are).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RoiConfig {
    /// An axis-aligned box (m).
    #[serde(rename = "box")]
    pub aabb: Option<BoxConfig>,
    /// A sphere (m).
    pub sphere: Option<SphereConfig>,
    /// `[s0, s1]`: arc length along the arch centreline from its descending
    /// end (m); only with `mesh.arch_nodes`.
    pub arclength: Option<[f64; 2]>,
}

/// A whole scene.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scene {
    /// The mesh.
    pub mesh: MeshConfig,
    /// The material.
    pub material: MaterialConfig,
    /// The force model.
    pub model: ModelKind,
    /// Prony terms (NVTMM and FEM only); none = elastic.
    #[serde(default)]
    pub prony: Vec<PronyTerm>,
    /// Fixed regions.
    #[serde(default)]
    pub fixed: FixedConfig,
    /// Nodal loads.
    #[serde(default, rename = "load")]
    pub loads: Vec<LoadConfig>,
    /// Gravity (m/s²).
    #[serde(default)]
    pub gravity: [f64; 3],
    /// Integrator settings.
    #[serde(default)]
    pub integrator: ImplicitEulerParams,
    /// Simulated time (s).
    pub duration: f64,
    /// Outputs.
    #[serde(default)]
    pub output: OutputConfig,
    /// The reduced (modal) model the haptic loop runs (docs/REDUCED.md).
    pub reduced: Option<ReducedConfig>,
    /// Region of interest: only tets inside are simulated, the cut surface
    /// is fixed (docs/REDUCED.md).
    pub roi: Option<RoiConfig>,
    /// Directory of the scene file (relative mesh paths resolve against it).
    #[serde(skip)]
    pub base_dir: PathBuf,
    /// The scene file.
    #[serde(skip)]
    pub path: PathBuf,
}

/// What [`Scene::build`] produces.
pub struct Built {
    /// The mesh (SI units).
    pub mesh: TetMesh,
    /// The force model.
    pub model: Box<dyn ForceModel>,
    /// The material.
    pub material: Material,
    /// Fixed nodes (sorted, unique).
    pub fixed: Vec<u32>,
    /// External loads.
    pub loads: Loads,
    /// Nodes written to the probe CSV.
    pub probes: Vec<u32>,
    /// With a `[roi]`: the whole-mesh node of each node of `mesh` (which is
    /// then the region's sub-mesh; its cut nodes are in `fixed`).
    pub roi_to_full: Option<Vec<u32>>,
}

impl Scene {
    /// Reads and validates a scene file.
    pub fn load(path: &Path) -> Result<Scene, SceneError> {
        let text = std::fs::read_to_string(path).map_err(|e| SceneError {
            path: path.to_path_buf(),
            key: "(file)".into(),
            msg: e.to_string(),
        })?;
        let base = path.parent().map(Path::to_path_buf).unwrap_or_default();
        Scene::parse(&text, path, &base)
    }

    /// Parses and validates scene text; `path` is used in messages.
    pub fn parse(text: &str, path: &Path, base_dir: &Path) -> Result<Scene, SceneError> {
        let mut scene: Scene = toml::from_str(text).map_err(|e| SceneError {
            path: path.to_path_buf(),
            key: "(syntax)".into(),
            msg: e.to_string().trim().replace('\n', " "),
        })?;
        scene.base_dir = base_dir.to_path_buf();
        scene.path = path.to_path_buf();
        scene.validate()?;
        Ok(scene)
    }

    fn err(&self, key: &str, msg: impl Into<String>) -> SceneError {
        SceneError {
            path: self.path.clone(),
            key: key.into(),
            msg: msg.into(),
        }
    }

    /// Checks every key against its allowed range.
    pub fn validate(&self) -> Result<(), SceneError> {
        let m = &self.mesh;
        let sources = m.arch_nodes.is_some() as u8 + m.block.is_some() as u8 + m.file.is_some() as u8;
        if sources != 1 {
            return Err(self.err("mesh", "give exactly one of arch_nodes, block, file"));
        }
        if let Some(n) = m.arch_nodes {
            if !(crate::mesh::arch::MIN_NODES..=crate::mesh::arch::MAX_NODES).contains(&n) {
                return Err(self.err(
                    "mesh.arch_nodes",
                    format!(
                        "{n} is out of range {}..={}",
                        crate::mesh::arch::MIN_NODES,
                        crate::mesh::arch::MAX_NODES
                    ),
                ));
            }
        }
        if let Some(b) = &m.block {
            if b.cells.iter().any(|&c| c == 0 || c > 400) {
                return Err(self.err("mesh.block.cells", format!("{:?}: each must be in 1..=400", b.cells)));
            }
            if b.size.iter().any(|&s| !(s.is_finite() && s > 0.0)) {
                return Err(self.err(
                    "mesh.block.size",
                    format!("{:?}: each must be finite and > 0 (m)", b.size),
                ));
            }
        }
        if !(m.scale.is_finite() && m.scale > 0.0) {
            return Err(self.err("mesh.scale", format!("{}: must be finite and > 0", m.scale)));
        }
        let mat = &self.material;
        if !(mat.youngs_pa.is_finite() && (1.0..=1e10).contains(&mat.youngs_pa)) {
            return Err(self.err(
                "material.youngs_pa",
                format!("{}: must be in [1, 1e10] Pa", mat.youngs_pa),
            ));
        }
        if !(mat.poisson.is_finite() && (0.0..=0.4999).contains(&mat.poisson)) {
            return Err(self.err("material.poisson", format!("{}: must be in [0, 0.4999]", mat.poisson)));
        }
        if !(mat.density.is_finite() && (1.0..=1e5).contains(&mat.density)) {
            return Err(self.err(
                "material.density",
                format!("{}: must be in [1, 1e5] kg/m^3", mat.density),
            ));
        }
        if !self.prony.is_empty() && !matches!(self.model, ModelKind::Nvtmm | ModelKind::Fem) {
            return Err(self.err(
                "prony",
                format!(
                    "Prony terms apply to the nvtmm and fem models, not {}",
                    self.model.name()
                ),
            ));
        }
        if self.model == ModelKind::Tmm && mat.law != Law::Stvk {
            return Err(self.err("material.law", "the tmm model is linear elasticity; use law = \"stvk\""));
        }
        let mut sum = 0.0;
        for (i, p) in self.prony.iter().enumerate() {
            if !(p.alpha.is_finite() && p.alpha > 0.0 && p.alpha < 1.0) {
                return Err(self.err(&format!("prony[{i}].alpha"), format!("{}: must be in (0, 1)", p.alpha)));
            }
            if !(p.tau.is_finite() && p.tau > 0.0) {
                return Err(self.err(
                    &format!("prony[{i}].tau"),
                    format!("{}: must be finite and > 0 (s)", p.tau),
                ));
            }
            sum += p.alpha;
        }
        if sum >= 1.0 {
            return Err(self.err("prony", format!("the alphas sum to {sum}: the sum must be < 1")));
        }
        for (i, b) in self.fixed.boxes.iter().enumerate() {
            if b.min.iter().chain(&b.max).any(|v| !v.is_finite()) || (0..3).any(|k| b.min[k] > b.max[k]) {
                return Err(self.err(
                    &format!("fixed.boxes[{i}]"),
                    "min and max must be finite with min <= max",
                ));
            }
        }
        for (i, l) in self.loads.iter().enumerate() {
            let key = format!("load[{i}]");
            let sel = (!l.nodes.is_empty()) as u8 + l.set.is_some() as u8 + l.near.is_some() as u8;
            if sel != 1 {
                return Err(self.err(&key, "give exactly one of nodes, set, near"));
            }
            if l.force_n.iter().any(|v| !v.is_finite()) {
                return Err(self.err(&format!("{key}.force_n"), "must be finite (N)"));
            }
            if l.near.is_some_and(|p| p.iter().any(|v| !v.is_finite())) {
                return Err(self.err(&format!("{key}.near"), "must be finite (m)"));
            }
            let ok = match l.profile {
                TimeProfile::Constant { from_t0 } => from_t0.is_finite(),
                TimeProfile::Ramp { t0, t1 } => t0.is_finite() && t1.is_finite(),
                TimeProfile::Sine { freq_hz, phase } => freq_hz.is_finite() && freq_hz >= 0.0 && phase.is_finite(),
            };
            if !ok {
                return Err(self.err(&format!("{key}.profile"), "parameters must be finite (freq_hz >= 0)"));
            }
        }
        if self.gravity.iter().any(|v| !v.is_finite()) {
            return Err(self.err("gravity", "must be finite (m/s^2)"));
        }
        self.validate_reduced()?;
        self.validate_roi()?;
        self.integrator.validate().map_err(|msg| self.err("integrator", msg))?;
        let dt = self.integrator.dt;
        if !(1e-6..=0.1).contains(&dt) {
            return Err(self.err("integrator.dt", format!("{dt}: must be in [1e-6, 0.1] s")));
        }
        if !(self.duration.is_finite() && self.duration > 0.0 && self.duration / dt <= 1e8) {
            return Err(self.err(
                "duration",
                format!("{}: must be > 0 and at most 1e8 steps of dt", self.duration),
            ));
        }
        Ok(())
    }

    fn validate_reduced(&self) -> Result<(), SceneError> {
        let Some(r) = &self.reduced else { return Ok(()) };
        if !(1..=MAX_REDUCED_R).contains(&r.r) {
            return Err(self.err("reduced.r", format!("{}: must be in 1..={MAX_REDUCED_R}", r.r)));
        }
        if !(r.alpha.is_finite() && (0.0..=1e4).contains(&r.alpha)) {
            return Err(self.err("reduced.alpha", format!("{}: must be in [0, 1e4] 1/s", r.alpha)));
        }
        if !(r.beta.is_finite() && (0.0..=1.0).contains(&r.beta)) {
            return Err(self.err("reduced.beta", format!("{}: must be in [0, 1] s", r.beta)));
        }
        if r.contact_modes && r.contact_region.is_none() {
            return Err(self.err(
                "reduced.contact_region",
                "contact_modes = true needs a contact_region ({ center, radius } and/or set)",
            ));
        }
        if let Some(c) = &r.contact_region {
            let key = "reduced.contact_region";
            if c.center.is_some() != c.radius.is_some() {
                return Err(self.err(key, "give center and radius together"));
            }
            if c.center.is_none() && c.set.is_none() {
                return Err(self.err(key, "give a sphere ({ center, radius }), a set, or both"));
            }
            if c.center.is_some_and(|p| p.iter().any(|v| !v.is_finite())) {
                return Err(self.err(&format!("{key}.center"), "must be finite (m)"));
            }
            if let Some(rad) = c.radius {
                if !(rad.is_finite() && rad > 0.0) {
                    return Err(self.err(&format!("{key}.radius"), format!("{rad}: must be finite and > 0 (m)")));
                }
            }
        }
        if r.cache_dir.as_ref().is_some_and(|d| d.as_os_str().is_empty()) {
            return Err(self.err("reduced.cache_dir", "must not be empty"));
        }
        Ok(())
    }

    fn validate_roi(&self) -> Result<(), SceneError> {
        let Some(roi) = &self.roi else { return Ok(()) };
        let kinds = roi.aabb.is_some() as u8 + roi.sphere.is_some() as u8 + roi.arclength.is_some() as u8;
        if kinds != 1 {
            return Err(self.err("roi", "give exactly one of box, sphere, arclength"));
        }
        if let Some(b) = &roi.aabb {
            if b.min.iter().chain(&b.max).any(|v| !v.is_finite()) || (0..3).any(|k| b.min[k] >= b.max[k]) {
                return Err(self.err("roi.box", "min and max must be finite with min < max (m)"));
            }
        }
        if let Some(sp) = &roi.sphere {
            if sp.center.iter().any(|v| !v.is_finite()) {
                return Err(self.err("roi.sphere.center", "must be finite (m)"));
            }
            if !(sp.radius.is_finite() && sp.radius > 0.0) {
                return Err(self.err(
                    "roi.sphere.radius",
                    format!("{}: must be finite and > 0 (m)", sp.radius),
                ));
            }
        }
        if let Some([s0, s1]) = roi.arclength {
            if self.mesh.arch_nodes.is_none() {
                return Err(self.err("roi.arclength", "only for the built-in arch (mesh.arch_nodes)"));
            }
            if !(s0.is_finite() && s1.is_finite() && s0 >= 0.0 && s0 < s1) {
                return Err(self.err("roi.arclength", format!("[{s0}, {s1}]: need 0 <= s0 < s1 (m)")));
            }
        }
        Ok(())
    }

    /// The contact nodes of `[reduced].contact_region` on `mesh` (sorted,
    /// unique; empty without a region). An error names the key if the set
    /// does not exist or the region holds no node.
    pub fn contact_nodes(&self, mesh: &TetMesh) -> Result<Vec<u32>, SceneError> {
        let Some(c) = self.reduced.as_ref().and_then(|r| r.contact_region.as_ref()) else {
            return Ok(Vec::new());
        };
        let key = "reduced.contact_region";
        let candidates: Vec<u32> = match &c.set {
            Some(s) => mesh
                .node_set(s)
                .ok_or_else(|| {
                    let names: Vec<&str> = mesh.node_sets().keys().map(String::as_str).collect();
                    self.err(
                        &format!("{key}.set"),
                        format!("no node set '{s}' (the mesh has: {})", names.join(", ")),
                    )
                })?
                .to_vec(),
            None => (0..mesh.num_nodes() as u32).collect(),
        };
        let mut nodes: Vec<u32> = match (c.center, c.radius) {
            (Some(p), Some(rad)) => {
                let p = Vec3::from(p);
                candidates
                    .into_iter()
                    .filter(|&i| (mesh.rest()[i as usize] - p).norm() <= rad)
                    .collect()
            }
            _ => candidates,
        };
        nodes.sort_unstable();
        nodes.dedup();
        if nodes.is_empty() {
            return Err(self.err(key, "holds no node of the mesh"));
        }
        Ok(nodes)
    }

    /// The basis cache directory: `[reduced].cache_dir` (relative to the
    /// scene file), else [`default_cache_dir`].
    pub fn cache_dir(&self) -> PathBuf {
        match self.reduced.as_ref().and_then(|r| r.cache_dir.as_ref()) {
            Some(d) if d.is_absolute() => d.clone(),
            Some(d) => self.base_dir.join(d),
            None => default_cache_dir(),
        }
    }

    /// The material constants.
    pub fn material(&self) -> Material {
        Material {
            youngs_pa: self.material.youngs_pa,
            poisson: self.material.poisson,
            density: self.material.density,
        }
    }

    /// Builds the mesh.
    pub fn build_mesh(&self) -> Result<TetMesh, SceneError> {
        let m = &self.mesh;
        if let Some(n) = m.arch_nodes {
            return generate(&ArchParams::default(), n)
                .map(|a| a.mesh)
                .map_err(|e| self.err("mesh.arch_nodes", e.to_string()));
        }
        if let Some(b) = &m.block {
            return block(b.cells, b.size).map_err(|e| self.err("mesh.block", e.to_string()));
        }
        let file = m.file.as_ref().ok_or_else(|| self.err("mesh", "no mesh source"))?;
        let full = if file.is_absolute() {
            file.clone()
        } else {
            self.base_dir.join(file)
        };
        read_mesh_scaled(&full, m.scale).map_err(|e| self.err("mesh.file", e.to_string()))
    }

    /// Builds the mesh the scene simulates: the whole mesh, or with a
    /// `[roi]` the region's sub-mesh (cut nodes in the set
    /// [`crate::mesh::roi::CUT_SET`]) and its map to whole-mesh nodes.
    pub fn build_roi_mesh(&self) -> Result<(TetMesh, Option<Vec<u32>>), SceneError> {
        let Some(roi) = &self.roi else {
            return Ok((self.build_mesh()?, None));
        };
        let (mesh, region) = if let Some([s0, s1]) = roi.arclength {
            let n = self
                .mesh
                .arch_nodes
                .ok_or_else(|| self.err("roi.arclength", "only for the built-in arch"))?;
            let arch = generate(&ArchParams::default(), n).map_err(|e| self.err("mesh.arch_nodes", e.to_string()))?;
            let node_value = crate::mesh::roi::arch_node_arclength(&arch);
            (
                arch.mesh,
                Region::Interval {
                    node_value,
                    lo: s0,
                    hi: s1,
                },
            )
        } else if let Some(b) = &roi.aabb {
            (
                self.build_mesh()?,
                Region::Box {
                    min: Vec3::from(b.min),
                    max: Vec3::from(b.max),
                },
            )
        } else if let Some(sp) = &roi.sphere {
            (
                self.build_mesh()?,
                Region::Sphere {
                    center: Vec3::from(sp.center),
                    radius: sp.radius,
                },
            )
        } else {
            return Err(self.err("roi", "give exactly one of box, sphere, arclength"));
        };
        let sub = extract(&mesh, &region).map_err(|e| self.err("roi", e.to_string()))?;
        Ok((sub.mesh, Some(sub.to_full)))
    }

    /// Builds everything the solver needs. With a `[roi]`, node indices in
    /// the scene (`load.nodes`, `output.csv_nodes`) are whole-mesh indices;
    /// node sets and boxes select the region's nodes; the cut nodes are
    /// fixed.
    pub fn build(&self) -> Result<Built, SceneError> {
        let (mesh, roi_to_full) = self.build_roi_mesh()?;
        // Whole-mesh node indices given in the scene → region nodes.
        let map_nodes = |key: &str, ids: &[u32]| -> Result<Vec<u32>, SceneError> {
            match &roi_to_full {
                None => Ok(ids.to_vec()),
                Some(map) => ids
                    .iter()
                    .map(|&v| {
                        map.binary_search(&v)
                            .map(|i| i as u32)
                            .map_err(|_| self.err(key, format!("node {v} is outside the roi")))
                    })
                    .collect(),
            }
        };
        let material = self.material();
        let model = build_model(self.model, &mesh, &material, self.material.law, &self.prony);
        let n = mesh.num_nodes();

        let mut fixed: Vec<u32> = Vec::new();
        for (i, s) in self.fixed.sets.iter().enumerate() {
            let ids = mesh.node_set(s).ok_or_else(|| {
                let names: Vec<&str> = mesh.node_sets().keys().map(String::as_str).collect();
                self.err(
                    &format!("fixed.sets[{i}]"),
                    format!("no node set '{s}' (the mesh has: {})", names.join(", ")),
                )
            })?;
            fixed.extend_from_slice(ids);
        }
        for b in &self.fixed.boxes {
            fixed.extend(nodes_in_box(&mesh, Vec3::from(b.min), Vec3::from(b.max)));
        }
        if roi_to_full.is_some() {
            fixed.extend_from_slice(mesh.node_set(CUT_SET).unwrap_or(&[]));
        }
        fixed.sort_unstable();
        fixed.dedup();

        let surface = mesh.surface_nodes();
        let mut loads = Loads {
            nodal: Vec::new(),
            gravity: Vec3::from(self.gravity),
        };
        let mut probes: Vec<u32> = Vec::new();
        for (i, l) in self.loads.iter().enumerate() {
            let key = format!("load[{i}]");
            let nodes: Vec<u32> = if let Some(s) = &l.set {
                mesh.node_set(s)
                    .ok_or_else(|| self.err(&format!("{key}.set"), format!("no node set '{s}'")))?
                    .to_vec()
            } else if let Some(p) = l.near {
                let p = Vec3::from(p);
                let best = surface.iter().copied().min_by(|&a, &b| {
                    (mesh.rest()[a as usize] - p)
                        .norm()
                        .total_cmp(&(mesh.rest()[b as usize] - p).norm())
                });
                vec![best.ok_or_else(|| self.err(&format!("{key}.near"), "the mesh has no surface"))?]
            } else {
                if let Some(&bad) = l.nodes.iter().find(|&&v| roi_to_full.is_none() && v as usize >= n) {
                    return Err(self.err(&format!("{key}.nodes"), format!("node {bad} is out of range 0..{n}")));
                }
                map_nodes(&format!("{key}.nodes"), &l.nodes)?
            };
            if nodes.is_empty() {
                return Err(self.err(&key, "selects no nodes"));
            }
            let per = Vec3::from(l.force_n) / nodes.len() as f64;
            probes.extend_from_slice(&nodes);
            loads.nodal.push(NodalLoad {
                nodes,
                force: per,
                profile: l.profile,
            });
        }
        if let Some(&bad) = self
            .output
            .csv_nodes
            .iter()
            .find(|&&v| roi_to_full.is_none() && v as usize >= n)
        {
            return Err(self.err("output.csv_nodes", format!("node {bad} is out of range 0..{n}")));
        }
        probes.extend(map_nodes("output.csv_nodes", &self.output.csv_nodes)?);
        probes.sort_unstable();
        probes.dedup();
        Ok(Built {
            mesh,
            model,
            material,
            fixed,
            loads,
            probes,
            roi_to_full,
        })
    }
}

/// `$XDG_CACHE_HOME/nvtmm` if set (and absolute), else `~/.cache/nvtmm`
/// if `$HOME` is set, else `.nvtmm-cache` in the working directory.
pub fn default_cache_dir() -> PathBuf {
    if let Some(x) = std::env::var_os("XDG_CACHE_HOME").map(PathBuf::from) {
        if x.is_absolute() {
            return x.join("nvtmm");
        }
    }
    match std::env::var_os("HOME") {
        Some(h) if !h.is_empty() => PathBuf::from(h).join(".cache").join("nvtmm"),
        _ => PathBuf::from(".nvtmm-cache"),
    }
}

/// Builds a force model. NVTMM with the Neo-Hookean law is evaluated per
/// element (log J has no tensor-mass polynomial form); Prony terms wrap the
/// elastic model in [`Viscoelastic`].
pub fn build_model(
    kind: ModelKind,
    mesh: &TetMesh,
    material: &Material,
    law: Law,
    prony: &[PronyTerm],
) -> Box<dyn ForceModel> {
    match (kind, law) {
        (ModelKind::Msm, _) => Box::new(Msm::new(mesh, material)),
        (ModelKind::Tmm, _) => Box::new(Tmm::new(mesh, material)),
        (ModelKind::Nvtmm, Law::Stvk) => {
            let m = Nvtmm::new(mesh, material);
            if prony.is_empty() {
                Box::new(m)
            } else {
                Box::new(Viscoelastic::new(m, mesh, material, law, prony))
            }
        }
        (ModelKind::Nvtmm, Law::NeoHookean) | (ModelKind::Fem, _) => {
            let m = Fem::new(mesh, material, law);
            if prony.is_empty() {
                Box::new(m)
            } else {
                Box::new(Viscoelastic::new(m, mesh, material, law, prony))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<Scene, SceneError> {
        Scene::parse(text, Path::new("test.toml"), Path::new("."))
    }

    const GOOD: &str = r#"
model = "nvtmm"
duration = 0.01
[mesh]
block = { cells = [2, 1, 1], size = [0.02, 0.01, 0.01] }
[material]
youngs_pa = 1e5
poisson = 0.4
[[prony]]
alpha = 0.5
tau = 0.5
[fixed]
sets = ["x_min"]
[[load]]
set = "x_max"
force_n = [0.0, 0.0, -0.01]
profile = { kind = "ramp", t0 = 0.0, t1 = 0.005 }
"#;

    #[test]
    fn good_scene_builds() {
        let s = parse(GOOD).unwrap();
        let b = s.build().unwrap();
        assert!(!b.fixed.is_empty());
        assert_eq!(b.loads.nodal.len(), 1);
        assert!(b.model.is_viscoelastic());
    }

    #[test]
    fn errors_name_the_key_and_range() {
        let cases = [
            (GOOD.replace("poisson = 0.4", "poisson = 0.5"), "material.poisson"),
            (GOOD.replace("youngs_pa = 1e5", "youngs_pa = -3"), "material.youngs_pa"),
            (GOOD.replace("alpha = 0.5", "alpha = 1.5"), "prony[0].alpha"),
            (GOOD.replace("tau = 0.5", "tau = 0"), "prony[0].tau"),
            (GOOD.replace("model = \"nvtmm\"", "model = \"foo\""), "(syntax)"),
            (GOOD.replace("model = \"nvtmm\"", "model = \"msm\""), "prony"),
            (GOOD.replace("duration = 0.01", "duration = -1"), "duration"),
            (
                GOOD.replace("[fixed]", "[fixed]\nboxes = [{ min = [1, 0, 0], max = [0, 0, 0] }]"),
                "fixed.boxes[0]",
            ),
            (
                GOOD.replace("sets = [\"x_min\"]", "sets = [\"x_min\"]\nbogus = 1"),
                "(syntax)",
            ),
        ];
        for (text, key) in cases {
            let e = parse(&text).unwrap_err();
            assert_eq!(e.key, key, "{e}");
            assert!(e.to_string().contains("test.toml"), "{e}");
        }
        let e = parse(&GOOD.replace("x_min", "nope")).unwrap().build().err().unwrap();
        assert_eq!(e.key, "fixed.sets[0]");
        assert!(e.msg.contains("x_max"), "lists the available sets: {e}");
    }

    const REDUCED: &str = r#"
[reduced]
r = 16
contact_modes = true
contact_region = { center = [0.02, 0.0, 0.0], radius = 0.006, set = "x_max" }
alpha = 5.0
beta = 1e-4
"#;

    #[test]
    fn reduced_section_parses_and_selects_contact_nodes() {
        let s = parse(&format!("{GOOD}{REDUCED}")).unwrap();
        let r = s.reduced.as_ref().unwrap();
        assert_eq!(r.r, 16);
        assert!(r.cache);
        let mesh = s.build_mesh().unwrap();
        let nodes = s.contact_nodes(&mesh).unwrap();
        assert!(!nodes.is_empty());
        let xmax = mesh.node_set("x_max").unwrap();
        assert!(nodes.iter().all(|n| xmax.contains(n)));
        assert!(s.cache_dir().ends_with("nvtmm") || s.cache_dir().ends_with(".nvtmm-cache"));
        let rel = parse(&format!("{GOOD}{REDUCED}cache_dir = \"cache\"\n")).unwrap();
        assert_eq!(rel.cache_dir(), Path::new("./cache"));
    }

    #[test]
    fn reduced_and_roi_errors_name_the_key() {
        let full = format!("{GOOD}{REDUCED}");
        let cases = [
            (full.replace("r = 16", "r = 65"), "reduced.r"),
            (full.replace("r = 16", "r = 0"), "reduced.r"),
            (full.replace("alpha = 5.0", "alpha = -1"), "reduced.alpha"),
            (full.replace("beta = 1e-4", "beta = 2"), "reduced.beta"),
            (
                full.replace("radius = 0.006", "radius = -1"),
                "reduced.contact_region.radius",
            ),
            (full.replace("radius = 0.006, ", ""), "reduced.contact_region"),
            (
                full.replace(
                    "contact_region = { center = [0.02, 0.0, 0.0], radius = 0.006, set = \"x_max\" }",
                    "",
                ),
                "reduced.contact_region",
            ),
            (
                format!("{GOOD}[roi]\nsphere = {{ center = [0, 0, 0], radius = 0 }}\n"),
                "roi.sphere.radius",
            ),
            (format!("{GOOD}[roi]\n"), "roi"),
            (format!("{GOOD}[roi]\narclength = [0.0, 0.1]\n"), "roi.arclength"),
            (
                format!("{GOOD}[roi]\nbox = {{ min = [0, 0, 0], max = [0, 1, 1] }}\n"),
                "roi.box",
            ),
        ];
        for (text, key) in cases {
            let e = parse(&text).unwrap_err();
            assert_eq!(e.key, key, "{e}");
        }
        let e = parse(&full.replace("\"x_max\" }", "\"nope\" }"))
            .unwrap()
            .contact_nodes(&block([2, 1, 1], [0.02, 0.01, 0.01]).unwrap())
            .unwrap_err();
        assert_eq!(e.key, "reduced.contact_region.set");
    }

    #[test]
    fn roi_keeps_the_region_and_fixes_the_cut() {
        let text = format!("{GOOD}[roi]\nbox = {{ min = [0.0, -1, -1], max = [0.01, 1, 1] }}\n")
            .replace("cells = [2, 1, 1]", "cells = [4, 1, 1]")
            .replace("set = \"x_max\"", "nodes = [0]");
        let s = parse(&text).unwrap();
        let b = s.build().unwrap();
        let map = b.roi_to_full.as_ref().unwrap();
        assert_eq!(map.len(), b.mesh.num_nodes());
        // The kept half of the bar: x_min plus the cut plane at x = 0.01 fixed.
        let cut = b.mesh.node_set(CUT_SET).unwrap();
        assert!(!cut.is_empty());
        assert!(cut.iter().all(|c| b.fixed.contains(c)));
        assert!(cut.iter().all(|&c| (b.mesh.rest()[c as usize].x - 0.01).abs() < 1e-12));
        let far = parse(&text.replace("nodes = [0]", "nodes = [4]")).unwrap();
        assert_eq!(far.build().err().unwrap().key, "load[0].nodes");
    }
}
