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
use crate::mesh::arch::{generate, ArchParams};
use crate::mesh::block::block;
use crate::mesh::io::read_mesh_scaled;
use crate::mesh::{TetMesh, Vec3};
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

    /// Builds everything the solver needs.
    pub fn build(&self) -> Result<Built, SceneError> {
        let mesh = self.build_mesh()?;
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
                if let Some(&bad) = l.nodes.iter().find(|&&v| v as usize >= n) {
                    return Err(self.err(&format!("{key}.nodes"), format!("node {bad} is out of range 0..{n}")));
                }
                l.nodes.clone()
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
        if let Some(&bad) = self.output.csv_nodes.iter().find(|&&v| v as usize >= n) {
            return Err(self.err("output.csv_nodes", format!("node {bad} is out of range 0..{n}")));
        }
        probes.extend_from_slice(&self.output.csv_nodes);
        probes.sort_unstable();
        probes.dedup();
        Ok(Built {
            mesh,
            model,
            material,
            fixed,
            loads,
            probes,
        })
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
}
