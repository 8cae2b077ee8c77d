//! From a validated scene to what the solver needs: the mesh (or the
//! region of interest's sub-mesh), the force model, fixed nodes, loads and
//! probe nodes.

use super::*;
use crate::model::factory::build_model;
use crate::model::BlockTangent;
use crate::solver::pressure::LuminalPressure;

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
    /// With `[pressure] unload_reference = true`: how the zero-pressure
    /// reference (now `mesh`) was found.
    pub unloaded: Option<UnloadBuild>,
}

/// The zero-pressure reference of `[pressure] unload_reference` and where it
/// came from.
#[derive(Debug, Clone)]
pub struct UnloadBuild {
    /// Whether it was read from the cache.
    pub cache_hit: bool,
    /// The cache file (`<cache_dir>/unload-<key>.vtu`).
    pub path: std::path::PathBuf,
    /// Fixed-point iterations (0 on a cache hit).
    pub iters: usize,
    /// Largest distance (m) between the inflated reference and the image
    /// at the last iteration (0 on a cache hit).
    pub max_error_m: f64,
    /// Why a computed reference could not be cached (it is still used).
    pub cache_error: Option<String>,
    /// The mesh's positions as given (the image), in the reference's node
    /// order.
    pub image: Vec<Vec3>,
}

/// The wall in static equilibrium at the scene's mean pressure
/// ([`Scene::inflate`]): where the haptic service starts when the scene has
/// a `[pressure]`, so that the instruments meet the inflated lumen (the
/// image, with `unload_reference`) and the wall's compliance under them is
/// the pressurized wall's from the first tick (docs/PRESSURE.md, "Pressure
/// in the service").
#[derive(Debug, Clone)]
pub struct Inflated {
    /// Displacement from the mesh's rest positions (m).
    pub u: Vec<Vec3>,
    /// The full model's tangent there with the pressure's load stiffness
    /// (its symmetric part), as the next step of length `dt` assembles it.
    pub tangent: BlockTangent,
    /// Largest displacement of the inflation (m).
    pub max_u_m: f64,
    /// Newton iterations of the static solve.
    pub newton_iters: usize,
    /// Wall time of the static solve (s).
    pub solve_s: f64,
}

/// The wall of `[mesh] vessel` and where it came from.
#[derive(Debug, Clone)]
pub struct VesselBuild {
    /// The wall.
    pub mesh: TetMesh,
    /// Whether it was read from the cache.
    pub cache_hit: bool,
    /// The cache file.
    pub path: std::path::PathBuf,
}

/// The branched built-in arch (`[mesh] arch_branches = "three"`) and where
/// it came from.
#[derive(Debug, Clone)]
pub struct ArchBuild {
    /// The wall.
    pub mesh: TetMesh,
    /// Whether it was read from the cache.
    pub cache_hit: bool,
    /// The cache file.
    pub path: std::path::PathBuf,
    /// Why a freshly meshed arch could not be cached (the mesh is still
    /// good; the next load meshes again). None on a hit or a stored miss.
    pub cache_error: Option<String>,
}

/// The arch's options as the scene gives them: type I, one layer, the
/// default wall ratio.
fn scene_arch_options() -> (crate::mesh::vessel::implicit::BranchedArchParams, usize, f64) {
    use crate::mesh::vessel::branched::default_wall_ratio;
    let params = crate::mesh::vessel::implicit::BranchedArchParams::default();
    let ratio = default_wall_ratio(&params);
    (params, 1, ratio)
}

impl Scene {
    /// Builds the mesh.
    pub fn build_mesh(&self) -> Result<TetMesh, SceneError> {
        let m = &self.mesh;
        if let Some(n) = m.arch_nodes {
            if m.arch_branches == Some(ArchBranches::Three) {
                return self.branched_arch_mesh().map(|b| b.mesh);
            }
            return generate(&ArchParams::default(), n)
                .map(|a| a.mesh)
                .map_err(|e| self.err("mesh.arch_nodes", e.to_string()));
        }
        if let Some(b) = &m.block {
            return block(b.cells, b.size).map_err(|e| self.err("mesh.block", e.to_string()));
        }
        if m.vessel.is_some() {
            return self.vessel_mesh().map(|v| v.mesh);
        }
        let file = m.file.as_ref().ok_or_else(|| self.err("mesh", "no mesh source"))?;
        let full = if file.is_absolute() {
            file.clone()
        } else {
            self.base_dir.join(file)
        };
        read_mesh_scaled(&full, m.scale).map_err(|e| self.err("mesh.file", e.to_string()))
    }

    /// The cache key of `[mesh] vessel`: FNV-1a 64 of a tag, the surface
    /// file's bytes and every option (thickness, layers, size, scale).
    pub fn vessel_key(&self) -> Result<u64, SceneError> {
        let v = self
            .mesh
            .vessel
            .as_ref()
            .ok_or_else(|| self.err("mesh.vessel", "not given"))?;
        let path = self.resolve(&v.surface);
        let bytes =
            std::fs::read(&path).map_err(|e| self.err("mesh.vessel.surface", format!("{}: {e}", path.display())))?;
        let mut h = crate::reduced::cache::Fnv1a::default();
        // v2: the prism split is optimised (the same options give other tets).
        h.str("nvtmm vessel mesh v2");
        h.u64(bytes.len() as u64);
        h.bytes(&bytes);
        let opt = |h: &mut crate::reduced::cache::Fnv1a, x: Option<f64>| match x {
            Some(x) => {
                h.u64(1);
                h.f64(x);
            }
            None => h.u64(0),
        };
        opt(&mut h, v.wall_thickness);
        opt(&mut h, v.wall_ratio);
        h.u64(v.layers as u64);
        opt(&mut h, v.nodes.map(|n| n as f64));
        opt(&mut h, v.edge_length);
        h.f64(v.scale);
        Ok(h.finish())
    }

    /// The cache key of the branched built-in arch: FNV-1a 64 of the
    /// mesher's version tag ([`crate::mesh::vessel::branched::MESHER_VERSION`]),
    /// every anatomical parameter (their `Debug` text, which prints each
    /// float exactly), the node count, the layers and the wall ratio.
    pub fn branched_arch_key(&self) -> Result<u64, SceneError> {
        let n = self
            .mesh
            .arch_nodes
            .ok_or_else(|| self.err("mesh.arch_nodes", "not given"))?;
        let (params, layers, ratio) = scene_arch_options();
        let mut h = crate::reduced::cache::Fnv1a::default();
        h.str(crate::mesh::vessel::branched::MESHER_VERSION);
        h.str(&format!("{params:?}"));
        h.u64(n as u64);
        h.u64(layers as u64);
        h.f64(ratio);
        Ok(h.finish())
    }

    /// The branched built-in arch of `[mesh] arch_nodes` (with
    /// `arch_branches = "three"`): read from the cache
    /// (`<cache_dir>/branched-arch-<key>.vtu`, [`Self::branched_arch_key`])
    /// if there, else meshed and written there through a temporary file
    /// and a rename. A cached file that cannot be read is meshed again and
    /// replaced. Only a failed meshing is an error (naming
    /// `mesh.arch_nodes`); a cache that cannot be written is reported in
    /// [`ArchBuild::cache_error`], as the basis cache reports its own.
    pub fn branched_arch_mesh(&self) -> Result<ArchBuild, SceneError> {
        use crate::mesh::vessel::branched::branched_arch;
        let n = self
            .mesh
            .arch_nodes
            .ok_or_else(|| self.err("mesh.arch_nodes", "not given"))?;
        let key = self.branched_arch_key()?;
        let dir = self.cache_dir();
        let path = dir.join(format!("branched-arch-{key:016x}.vtu"));
        if path.exists() {
            if let Ok(mesh) = crate::mesh::io::read_mesh(&path) {
                return Ok(ArchBuild {
                    mesh,
                    cache_hit: true,
                    path,
                    cache_error: None,
                });
            }
        }
        let (params, layers, ratio) = scene_arch_options();
        let mesh = branched_arch(&params, n, layers, ratio)
            .map(|b| b.wall.mesh)
            .map_err(|e| self.err("mesh.arch_nodes", format!("the branched arch: {e}")))?;
        let tmp = dir.join(format!("branched-arch-{key:016x}.{}.tmp.vtu", std::process::id()));
        let stored = std::fs::create_dir_all(&dir)
            .map_err(|e| format!("cache directory {}: {e}", dir.display()))
            .and_then(|_| crate::mesh::io::write_mesh(&mesh, &tmp).map_err(|e| e.to_string()))
            .and_then(|_| std::fs::rename(&tmp, &path).map_err(|e| e.to_string()));
        let cache_error = stored.err().map(|e| {
            let _ = std::fs::remove_file(&tmp);
            format!("caching the branched arch in {}: {e}", path.display())
        });
        Ok(ArchBuild {
            mesh,
            cache_hit: false,
            path,
            cache_error,
        })
    }

    fn resolve(&self, p: &std::path::Path) -> std::path::PathBuf {
        if p.is_absolute() {
            p.to_path_buf()
        } else {
            self.base_dir.join(p)
        }
    }

    /// The wall of `[mesh] vessel`: read from the cache
    /// (`<cache_dir>/vessel-<key>.vtu`) if there, else meshed from the
    /// surface and written there (through a temporary file and a rename).
    /// A cached file that cannot be read is meshed again. Errors name the
    /// key (`mesh.vessel.…`) and the surface.
    pub fn vessel_mesh(&self) -> Result<VesselBuild, SceneError> {
        use crate::mesh::surface::{read_and_check, CheckOptions};
        use crate::mesh::vessel::pipeline::{mesh_vessel, SurfaceSize, VesselOptions};
        use crate::mesh::vessel::wall::{Thickness, WallOptions};
        let v = self
            .mesh
            .vessel
            .as_ref()
            .ok_or_else(|| self.err("mesh.vessel", "not given"))?;
        let key = self.vessel_key()?;
        let dir = self.cache_dir();
        let path = dir.join(format!("vessel-{key:016x}.vtu"));
        if path.exists() {
            if let Ok(mesh) = crate::mesh::io::read_mesh(&path) {
                return Ok(VesselBuild {
                    mesh,
                    cache_hit: true,
                    path,
                });
            }
        }
        let surface = self.resolve(&v.surface);
        let checked = read_and_check(
            &surface,
            v.scale,
            &CheckOptions {
                scale: v.scale,
                ..CheckOptions::default()
            },
        )
        .map_err(|e| self.err("mesh.vessel.surface", e.to_string()))?;
        let thickness = match (v.wall_thickness, v.wall_ratio) {
            (_, Some(f)) => Thickness::Ratio(f),
            (Some(t), None) => Thickness::Absolute(t),
            (None, None) => WallOptions::default().thickness,
        };
        let size = match (v.nodes, v.edge_length) {
            (Some(n), _) => SurfaceSize::Nodes(n),
            (None, Some(e)) => SurfaceSize::EdgeLength(e),
            (None, None) => SurfaceSize::Input,
        };
        let opts = VesselOptions {
            wall: WallOptions {
                thickness,
                layers: v.layers,
            },
            size,
            ..VesselOptions::default()
        };
        let built =
            mesh_vessel(&checked, &opts).map_err(|e| self.err("mesh.vessel", format!("{}: {e}", surface.display())))?;
        let mesh = built.wall.mesh;
        std::fs::create_dir_all(&dir)
            .map_err(|e| self.err("mesh.vessel", format!("cache directory {}: {e}", dir.display())))?;
        let tmp = dir.join(format!("vessel-{key:016x}.{}.tmp.vtu", std::process::id()));
        crate::mesh::io::write_mesh(&mesh, &tmp)
            .map_err(|e| e.to_string())
            .and_then(|_| std::fs::rename(&tmp, &path).map_err(|e| e.to_string()))
            .map_err(|e| self.err("mesh.vessel", format!("caching the wall in {}: {e}", path.display())))?;
        Ok(VesselBuild {
            mesh,
            cache_hit: false,
            path,
        })
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
        let (mut mesh, roi_to_full) = self.build_roi_mesh()?;
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

        let mut unloaded = None;
        if let Some(p) = self.pressure.as_ref().filter(|p| p.unload_reference) {
            let (reference, mut build) = self.zero_pressure_mesh(&mesh, &fixed, p)?;
            build.image = mesh.rest().to_vec();
            mesh = reference;
            unloaded = Some(build);
        }
        let model = build_model(self.model, &mesh, &material, self.material.law, &self.prony);
        let surface = mesh.surface_nodes();
        let mut loads = Loads {
            nodal: Vec::new(),
            gravity: Vec3::from(self.gravity),
            pressure: None,
        };
        if let Some(p) = &self.pressure {
            loads.pressure = Some(
                LuminalPressure::on_set(&mesh, &p.set, p.schedule(), p.tangent)
                    .map_err(|e| self.err("pressure.set", e.to_string()))?,
            );
        }
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
            unloaded,
        })
    }

    /// The zero-pressure reference of `image` for `[pressure]` (docs/PRESSURE.md):
    /// read from `<cache_dir>/unload-<key>.vtu` if there, else computed by
    /// the backward-displacement fixed point and written there through a
    /// temporary file and a rename. With Prony terms it is computed for the
    /// relaxed modulus (1 − Σα_i) E, where a steady pressure leaves the wall.
    /// An error names `pressure.unload_reference` and says why it failed.
    pub fn zero_pressure_mesh(
        &self,
        image: &TetMesh,
        fixed: &[u32],
        p: &PressureConfig,
    ) -> Result<(TetMesh, UnloadBuild), SceneError> {
        use crate::solver::unload::{UnloadParams, UnloadRequest};
        let key_name = "pressure.unload_reference";
        let mut material = self.material();
        material.youngs_pa *= 1.0 - self.prony.iter().map(|t| t.alpha).sum::<f64>();
        let req = UnloadRequest {
            image,
            kind: self.model,
            material,
            law: self.material.law,
            set: &p.set,
            pressure_pa: p.schedule().mean_pa,
            fixed,
            params: UnloadParams::default(),
        };
        let key = req.key();
        let dir = self.cache_dir();
        let path = dir.join(format!("unload-{key:016x}.vtu"));
        if path.exists() {
            if let Ok(mesh) = crate::mesh::io::read_mesh(&path) {
                if mesh.num_nodes() == image.num_nodes() && mesh.tets() == image.tets() {
                    return Ok((
                        mesh,
                        UnloadBuild {
                            cache_hit: true,
                            path,
                            iters: 0,
                            max_error_m: 0.0,
                            cache_error: None,
                            image: Vec::new(),
                        },
                    ));
                }
            }
        }
        let out = req.solve().map_err(|e| self.err(key_name, e.to_string()))?;
        let tmp = dir.join(format!("unload-{key:016x}.{}.tmp.vtu", std::process::id()));
        let stored = std::fs::create_dir_all(&dir)
            .map_err(|e| format!("cache directory {}: {e}", dir.display()))
            .and_then(|_| crate::mesh::io::write_mesh(&out.mesh, &tmp).map_err(|e| e.to_string()))
            .and_then(|_| std::fs::rename(&tmp, &path).map_err(|e| e.to_string()));
        let cache_error = stored.err().map(|e| {
            let _ = std::fs::remove_file(&tmp);
            format!("caching the zero-pressure reference in {}: {e}", path.display())
        });
        let build = UnloadBuild {
            cache_hit: false,
            path,
            iters: out.iters,
            max_error_m: out.history.last().copied().unwrap_or(0.0),
            cache_error,
            image: Vec::new(),
        };
        Ok((out.mesh, build))
    }

    /// Inflates the wall of `built` statically to the mean of `load` and
    /// relaxes the model's viscoelastic history there, ready for implicit
    /// steps of length `dt`. The equilibrium is that of the relaxed modulus
    /// (1 − Σα_i) E, where a steady pressure leaves a viscoelastic wall (the
    /// zero-pressure reference is computed for the same modulus, so with
    /// `unload_reference` the inflated wall is the image, and the static
    /// solve starts from it); the history is then set to its steady state
    /// at that displacement, γ_i = α_i S, so that a full solve started there
    /// is in equilibrium. The load's ramp is dropped: the pressure is on
    /// from the start. An error names `pressure.mean_pa`: a pressure the
    /// material cannot hold.
    pub fn inflate(&self, built: &mut Built, load: &mut LuminalPressure, dt: f64) -> Result<Inflated, SceneError> {
        use crate::solver::statics::{mask_of_fixed, solve_pressurized, StaticParams};
        let t0 = std::time::Instant::now();
        let mean = load.schedule.mean_pa;
        let mut relaxed = self.material();
        relaxed.youngs_pa *= 1.0 - self.prony.iter().map(|t| t.alpha).sum::<f64>();
        let elastic = build_model(self.model, &built.mesh, &relaxed, self.material.law, &[]);
        let n = built.mesh.num_nodes();
        let mask = mask_of_fixed(n, &built.fixed);
        // From the image when there is one (within the reference's
        // tolerance of the equilibrium), else from rest in increments.
        let image = built.unloaded.as_ref().map(|b| b.image.as_slice()).unwrap_or(&[]);
        let mut u: Vec<Vec3> = if image.len() == n {
            image.iter().zip(built.mesh.rest()).map(|(x, x0)| x - x0).collect()
        } else {
            vec![Vec3::zeros(); n]
        };
        let params = StaticParams {
            load_steps: if image.len() == n { 1 } else { 8 },
            ..StaticParams::default()
        };
        let report =
            solve_pressurized(&built.mesh, elastic.as_ref(), load, mean, &mask, &params, &mut u).map_err(|e| {
                self.err(
                    "pressure.mean_pa",
                    format!("the wall cannot be inflated to {mean} Pa (a pressure the material cannot hold): {e}"),
                )
            })?;
        // A step as long as the ages makes γ_i = α_i S(u) (A_i → α_i, B_i → 0).
        built.model.begin_step(1e12);
        built.model.end_step(&u);
        built.model.begin_step(dt);
        let mut tangent = BlockTangent::zeros(&built.mesh);
        built.model.add_stiffness(&u, &mut tangent);
        load.add_stiffness(mean, &u, &mut tangent);
        load.schedule.ramp_s = 0.0;
        Ok(Inflated {
            max_u_m: u.iter().map(|v| v.norm()).fold(0.0, f64::max),
            u,
            tangent,
            newton_iters: report.total_iters(),
            solve_s: t0.elapsed().as_secs_f64(),
        })
    }
}
