//! Scenes: what to simulate, read from a TOML file and validated at start.
//!
//! A scene names the mesh (the built-in arch, a block, or a file), the
//! material and law, the model (`msm | tmm | nvtmm | fem`), Prony terms, fixed
//! regions, loads, the integrator and the outputs. Every key is checked before
//! anything runs; errors name the file, the key and the allowed range. See the
//! README ("Scenes") for the format, and `rt-config/scenes/` for examples.
//!
//! [`Scene::build`] (in `build`) turns a scene into the mesh, the model, the
//! fixed nodes and the loads the solver needs; the checks live in
//! `validate`; running it lives in [`crate::simulate`]. Parsing and errors
//! go through [`crate::config`], like every other configuration file.

use crate::config::Checker;
use crate::material::{Law, Material, PronyTerm};
use crate::math::Vec3;
use crate::mesh::arch::{generate, ArchParams};
use crate::mesh::block::block;
use crate::mesh::io::read_mesh_scaled;
use crate::mesh::roi::{extract, Region, CUT_SET};
use crate::mesh::TetMesh;
use crate::model::{ForceModel, ModelKind};
use crate::solver::loads::{nodes_in_box, Loads, NodalLoad, TimeProfile};
use crate::solver::pressure::PressureConfig;
use crate::solver::ImplicitEulerParams;
use serde::Deserialize;
use std::path::{Path, PathBuf};

mod build;
mod validate;

pub use build::{ArchBuild, Built, Inflated, UnloadBuild};

/// A scene error: the same type as every configuration error (the file,
/// the dotted key and what is allowed).
pub type SceneError = crate::config::ConfigError;

/// Where the mesh comes from.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MeshConfig {
    /// The built-in aortic arch with about this many nodes.
    pub arch_nodes: Option<usize>,
    /// Which built-in arch `arch_nodes` builds: `"none"` (the unbranched
    /// tube, when the key is absent) or `"three"` (with the brachiocephalic
    /// trunk, the left common carotid and the left subclavian, made by the
    /// vessel pipeline; docs/VESSEL.md). Only with `arch_nodes`.
    pub arch_branches: Option<ArchBranches>,
    /// A box of tets: `{ cells = [nx, ny, nz], size = [x, y, z] }` (m).
    pub block: Option<BlockConfig>,
    /// A mesh file (.msh .vtk .vtu .node/.ele), relative to the scene file.
    pub file: Option<PathBuf>,
    /// A vessel wall meshed at load from a lumen surface
    /// ([`crate::mesh::vessel::pipeline`]), cached on disk.
    pub vessel: Option<VesselConfig>,
    /// Factor applied to the file's coordinates (0.001 for millimetres).
    #[serde(default = "one")]
    pub scale: f64,
}

/// The branches of the built-in arch (`[mesh] arch_branches`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ArchBranches {
    /// The unbranched tube ([`crate::mesh::arch::generate`]).
    None,
    /// The three supra-aortic branches
    /// ([`crate::mesh::vessel::branched::branched_arch`], one layer, the
    /// default wall ratio, arch type I).
    Three,
}

/// The node counts `arch_branches = "three"` accepts: at least 200 lumen
/// vertices (the branched arch's own floor), and at most what meshes in
/// about half a minute on a 2-core machine (23 328 nodes take 2-4 s).
pub const BRANCHED_ARCH_NODES: std::ops::RangeInclusive<usize> = 400..=200_000;

/// `[mesh] vessel = { surface = "…", … }`: the options of `nvtmm mesh
/// vessel`. The wall is meshed when the scene is built and cached in the
/// basis cache directory ([`Scene::cache_dir`]) as
/// `vessel-<key>.vtu`, the key a hash of the surface file's bytes and
/// these options ([`Scene::vessel_key`]).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VesselConfig {
    /// The lumen surface (.stl .obj .ply .vtk .vtp), relative to the scene file.
    pub surface: PathBuf,
    /// Wall thickness (m); default 1.5 mm unless `wall_ratio` is given.
    pub wall_thickness: Option<f64>,
    /// Wall thickness as a fraction of the local lumen radius.
    pub wall_ratio: Option<f64>,
    /// Element layers through the wall.
    #[serde(default = "one_usize")]
    pub layers: usize,
    /// Node count of the wall (within 2 %); the surface's own triangles if
    /// neither this nor `edge_length` is given.
    pub nodes: Option<usize>,
    /// Lumen edge length (m).
    pub edge_length: Option<f64>,
    /// Factor applied to the surface's coordinates (0.001 for millimetres).
    #[serde(default = "one")]
    pub scale: f64,
}

fn one_usize() -> usize {
    1
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
    /// Contact anywhere: the residual compliance of the basis in series with
    /// the contact (docs/REDUCED.md, "Contact anywhere"); default on.
    #[serde(default = "yes")]
    pub contact_anywhere: bool,
    /// Coupling radius of the residual compliance (m), in [0.5 mm, 50 mm].
    #[serde(default = "d_couple")]
    pub couple_radius_m: f64,
    /// Probing separation (m), at least twice the coupling radius, ≤ 0.5 m.
    #[serde(default = "d_separation")]
    pub separation_m: f64,
}

fn d_couple() -> f64 {
    crate::reduced::compliance::ComplianceParams::default().couple_radius_m
}

fn d_separation() -> f64 {
    crate::reduced::compliance::ComplianceParams::default().separation_m
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
    /// Blood pressure on the lumen (docs/PRESSURE.md); none by default.
    #[serde(default)]
    pub pressure: Option<PressureConfig>,
    /// Directory of the scene file (relative mesh paths resolve against it).
    #[serde(skip)]
    pub base_dir: PathBuf,
    /// The scene file.
    #[serde(skip)]
    pub path: PathBuf,
}

impl Scene {
    /// Reads and validates a scene file.
    pub fn load(path: &Path) -> Result<Scene, SceneError> {
        let text = std::fs::read_to_string(path).map_err(|e| Checker::new(path).err("(file)", e.to_string()))?;
        let base = path.parent().map(Path::to_path_buf).unwrap_or_default();
        Scene::parse(&text, path, &base)
    }

    /// Parses and validates scene text; `path` is used in messages.
    pub fn parse(text: &str, path: &Path, base_dir: &Path) -> Result<Scene, SceneError> {
        let mut scene: Scene = crate::config::parse_toml(text, path)?;
        scene.base_dir = base_dir.to_path_buf();
        scene.path = path.to_path_buf();
        scene.validate()?;
        Ok(scene)
    }

    /// The range checker for this scene's file.
    fn checker(&self) -> Checker {
        Checker::new(&self.path)
    }

    fn err(&self, key: &str, msg: impl Into<String>) -> SceneError {
        self.checker().err(key, msg)
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

    /// The contact-anywhere settings of `[reduced]` (None: off or no
    /// `[reduced]`).
    pub fn compliance_params(&self) -> Option<crate::reduced::compliance::ComplianceParams> {
        let r = self.reduced.as_ref()?;
        r.contact_anywhere
            .then_some(crate::reduced::compliance::ComplianceParams {
                couple_radius_m: r.couple_radius_m,
                separation_m: r.separation_m,
            })
    }

    /// The material constants.
    pub fn material(&self) -> Material {
        Material {
            youngs_pa: self.material.youngs_pa,
            poisson: self.material.poisson,
            density: self.material.density,
        }
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
            (GOOD.replace("model = \"nvtmm\"", "model = \"foo\""), "model"),
            (GOOD.replace("model = \"nvtmm\"", "model = \"msm\""), "prony"),
            (GOOD.replace("duration = 0.01", "duration = -1"), "duration"),
            (format!("{GOOD}[integrator]\ndt = -1e-3\n"), "integrator.dt"),
            (format!("{GOOD}[integrator]\ndt = 1.0\n"), "integrator.dt"),
            (
                GOOD.replace("[fixed]", "[fixed]\nboxes = [{ min = [1, 0, 0], max = [0, 0, 0] }]"),
                "fixed.boxes[0]",
            ),
            (
                GOOD.replace("sets = [\"x_min\"]", "sets = [\"x_min\"]\nbogus = 1"),
                "fixed.bogus",
            ),
        ];
        for (text, key) in cases {
            let e = parse(&text).unwrap_err();
            assert_eq!(e.key, key, "{e}");
            assert!(e.to_string().contains("test.toml"), "{e}");
        }
        // A negative dt and a too large one get the same shape of message.
        for dt in ["-1e-3", "1.0"] {
            let e = parse(&format!("{GOOD}[integrator]\ndt = {dt}\n")).unwrap_err();
            assert!(e.msg.ends_with("must be in [0.000001, 0.1] s"), "{e}");
        }
        let e = parse(&GOOD.replace("x_min", "nope")).unwrap().build().err().unwrap();
        assert_eq!(e.key, "fixed.sets[0]");
        assert!(e.msg.contains("x_max"), "lists the available sets: {e}");
    }

    /// [`GOOD`] on the built-in arch with `branches`.
    fn arch_scene(branches: &str) -> String {
        GOOD.replace(
            "block = { cells = [2, 1, 1], size = [0.02, 0.01, 0.01] }",
            &format!("arch_nodes = 1458\narch_branches = {branches}"),
        )
        .replace("x_min", "inlet")
        .replace("x_max", "outer_wall")
    }

    #[test]
    fn arch_branches_picks_the_branched_arch() {
        let b = parse(&arch_scene("\"three\"")).unwrap().build_mesh().unwrap();
        assert!((b.num_nodes() as f64 / 1458.0 - 1.0).abs() <= 0.01, "{}", b.num_nodes());
        let (names, _) = b.segment_labels().expect("the branched arch carries segment labels");
        assert!(names.iter().any(|n| n == "left_subclavian"), "{names:?}");
        assert!(b.node_set("outlet_brachiocephalic").is_some());
        let u = parse(&arch_scene("\"none\"")).unwrap().build_mesh().unwrap();
        assert!(u.segment_labels().is_none() && u.node_set("outlet_brachiocephalic").is_none());
        // Without the key: the unbranched arch, as before the key existed.
        let plain = parse(&arch_scene("\"none\"").replace("arch_branches = \"none\"", "")).unwrap();
        assert_eq!(plain.build_mesh().unwrap().rest(), u.rest());
    }

    #[test]
    fn arch_branches_errors_name_the_key() {
        let cases = [
            (arch_scene("\"four\""), "mesh.arch_branches", "four"),
            (arch_scene("3"), "mesh.arch_branches", ""),
            (
                GOOD.replace("[mesh]", "[mesh]\narch_branches = \"three\""),
                "mesh.arch_branches",
                "only with mesh.arch_nodes",
            ),
            (
                arch_scene("\"three\"").replace("arch_nodes = 1458", ""),
                "mesh.arch_branches",
                "only with mesh.arch_nodes",
            ),
            (
                arch_scene("\"three\"").replace("arch_nodes = 1458", "arch_nodes = 300"),
                "mesh.arch_nodes",
                "400..=200000",
            ),
            (
                format!("{}[roi]\narclength = [0.0, 0.1]\n", arch_scene("\"three\"")),
                "roi.arclength",
                "unbranched",
            ),
        ];
        for (text, key, what) in cases {
            let e = parse(&text).unwrap_err();
            assert_eq!(e.key, key, "{e}");
            assert!(e.to_string().contains(what), "{e}");
        }
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
