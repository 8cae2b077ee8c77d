//! `nvtmm experiment contact`: does the haptic loop render the full model's
//! stiffness wherever the tool touches?
//!
//! Set-up: the service's scene (the built-in arch, NVTMM, both ends fixed)
//! with a basis of vibration modes only (no contact region declared), the
//! residual compliance table of that basis ([`crate::reduced::compliance`]),
//! the service's contact (3 mm probe sphere, k_p = 1e8 Pa/m). At random
//! surface nodes of the inner and the outer wall, the probe is held pushed
//! `push_m` into the wall along the surface normal while the loop ticks at
//! 1 kHz ([`crate::haptics::servo::Servo`]). The rendered force is compared
//! with the full linear model's at the same state (rest, or the wall
//! inflated to a luminal pressure) under the same sphere contact
//! ([`reference()`]: the surface nodes near the probe move by the exact
//! columns of K⁻¹, the probe is pushed in from where it touches, and the
//! active set is iterated to convergence), so the ratio isolates the
//! reduced model's error. Every point drawn but not compared is reported
//! with the reason ([`DroppedPoint`]).
//!
//! Reported: the ratio of rendered to full force on the first tick and once
//! settled (after `settle_s`), with and without the compliance table (the
//! basis alone), and the settle time (first tick from which the force stays
//! within 10 % of the full model's).

use crate::haptics::contact::{ContactParams, SurfaceIndex};
use crate::haptics::device::DeviceSample;
use crate::haptics::servo::{Servo, ServoParams};
use crate::material::Material;
use crate::math::Vec3;
use crate::mesh::arch::{generate, ArchParams};
use crate::model::BlockTangent;
use crate::reduced::compliance::{ComplianceParams, ComplianceStats, ExactCompliance, LocalCompliance};
use crate::reduced::{basis_rows, DynamicsParams, ModalBasis, Refresher};
use crate::service::background::rest_model;
use nalgebra::DMatrix;
use std::sync::Arc;

/// What to run.
#[derive(Debug, Clone, PartialEq)]
pub struct ContactExperiment {
    /// Arch size (nodes).
    pub nodes: usize,
    /// Basis size (vibration modes only).
    pub r: usize,
    /// Surface points (half inner wall, half outer wall).
    pub points: usize,
    /// How far the probe is held into the undeformed wall (m).
    pub push_m: f64,
    /// Simulated time per point (s).
    pub settle_s: f64,
    /// Random seed of the points.
    pub seed: u64,
    /// The compliance table's settings.
    pub compliance: ComplianceParams,
    /// On the arch with its three supra-aortic branches.
    pub branched: bool,
    /// The vessel wall.
    pub wall: Wall,
    /// Steady luminal pressure (Pa); 0: none. Above 0 the wall is inflated
    /// statically to it and the loop and the reference are linearized there.
    pub pressure_pa: f64,
    /// How fast the loop's probe is pushed in from where it touches the
    /// wall (m/s), as the reference is; infinite: placed at its depth on
    /// the first tick. A probe placed at once deeper than the wall is thick
    /// starts sunk into the wall, and the loop can settle there, pressing
    /// the wall's far surface from inside (the reference's second
    /// equilibrium, [`reference()`]). The first-tick ratio and the settle
    /// time count from the tick the probe reaches its depth.
    pub push_speed_m_s: f64,
}

/// The wall of the contact experiment.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Wall {
    /// The paper's wall: NVTMM, St Venant–Kirchhoff, 65 kPa (cannot hold
    /// arterial pressure).
    #[default]
    Paper,
    /// The human aorta scene's wall (`rt-config/scenes/aorta_pressure.toml`):
    /// Neo-Hookean (element FEM), 0.7 MPa, ν = 0.45 (docs/PRESSURE.md).
    Human,
}

impl Wall {
    /// The material, the law and the model kind of this wall.
    pub fn material(self) -> (Material, crate::material::Law, crate::model::ModelKind) {
        use crate::material::Law;
        use crate::model::ModelKind;
        match self {
            Wall::Paper => (Material::aorta(), Law::Stvk, ModelKind::Nvtmm),
            Wall::Human => (
                Material {
                    youngs_pa: 0.7e6,
                    poisson: 0.45,
                    density: 1050.0,
                },
                Law::NeoHookean,
                ModelKind::Fem,
            ),
        }
    }

    /// Its name in reports.
    pub fn name(self) -> &'static str {
        match self {
            Wall::Paper => "paper (NVTMM StVK 65 kPa)",
            Wall::Human => "human aorta (Neo-Hookean 0.7 MPa)",
        }
    }
}

impl ContactExperiment {
    /// The service's size (5832 nodes, r = 32), 120 points.
    pub fn full() -> ContactExperiment {
        ContactExperiment {
            nodes: 5832,
            r: 32,
            points: 120,
            push_m: 0.5e-3,
            settle_s: 1.5,
            seed: 7,
            compliance: ComplianceParams::default(),
            branched: false,
            wall: Wall::Paper,
            pressure_pa: 0.0,
            push_speed_m_s: f64::INFINITY,
        }
    }

    /// A quick version (1458 nodes, r = 16, 60 points).
    pub fn quick() -> ContactExperiment {
        ContactExperiment {
            nodes: 1458,
            r: 16,
            points: 60,
            push_m: 0.5e-3,
            settle_s: 1.5,
            seed: 7,
            compliance: ComplianceParams::default(),
            branched: false,
            wall: Wall::Paper,
            pressure_pa: 0.0,
            push_speed_m_s: f64::INFINITY,
        }
    }
}

/// One surface point.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct ContactPoint {
    /// Mesh node pushed.
    pub node: u32,
    /// Whether it is on the inner (lumen) wall.
    pub inner: bool,
    /// Full linear model's force (N).
    pub full_n: f64,
    /// Rendered / full, first tick, with the compliance table.
    pub ratio_first: f64,
    /// Rendered / full, settled, with the compliance table.
    pub ratio_settled: f64,
    /// Rendered / full, settled, the basis alone.
    pub ratio_settled_basis_only: f64,
    /// First time from which the force stays within 10 % of the full (ms).
    pub settle_ms: f64,
    /// Touched nodes at the end.
    pub touched: usize,
    /// Nodes the reference solved for (its converged candidate set).
    pub reference_nodes: usize,
    /// Nodes in contact in the reference at its equilibrium.
    pub reference_active: usize,
    /// Rounds of the reference's active-set iteration.
    pub reference_rounds: usize,
}

/// A point left out of the statistics, and why.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct DroppedPoint {
    /// Mesh node.
    pub node: u32,
    /// Whether it is on the inner (lumen) wall.
    pub inner: bool,
    /// Why.
    pub reason: String,
}

/// Quantiles of a sample.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize)]
pub struct Spread {
    /// 5th percentile.
    pub p05: f64,
    /// Median.
    pub p50: f64,
    /// 95th percentile.
    pub p95: f64,
    /// Farthest from 1 (for ratios) or largest (for times).
    pub worst: f64,
}

impl Spread {
    fn of(v: &[f64], worst_from_one: bool) -> Spread {
        let mut s: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
        if s.is_empty() {
            return Spread::default();
        }
        s.sort_by(f64::total_cmp);
        let q = |p: f64| s[((p * (s.len() - 1) as f64).round() as usize).min(s.len() - 1)];
        let worst = if worst_from_one {
            s.iter()
                .copied()
                .max_by(|a, b| (a - 1.0).abs().total_cmp(&(b - 1.0).abs()))
                .unwrap_or(1.0)
        } else {
            s[s.len() - 1]
        };
        Spread {
            p05: q(0.05),
            p50: q(0.5),
            p95: q(0.95),
            worst,
        }
    }
}

/// The whole result.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ContactResult {
    /// Arch nodes.
    pub nodes: usize,
    /// Basis size.
    pub r: usize,
    /// Every point compared.
    pub points: Vec<ContactPoint>,
    /// Every point drawn but not compared, with the reason.
    pub dropped: Vec<DroppedPoint>,
    /// How far the probe was held into the wall (m).
    pub push_m: f64,
    /// The wall.
    pub wall: Wall,
    /// Steady luminal pressure (Pa).
    pub pressure_pa: f64,
    /// Largest displacement of the inflation to that pressure (m).
    pub inflation_m: f64,
    /// Settled ratio, with the table.
    pub ratio_settled: Spread,
    /// First-tick ratio, with the table.
    pub ratio_first: Spread,
    /// Settled ratio, the basis alone.
    pub ratio_settled_basis_only: Spread,
    /// Settle time (ms).
    pub settle_ms: Spread,
    /// Building the table.
    pub table: ComplianceStats,
}

const R: usize = 32;

/// The force magnitude per tick and the touched nodes at the end.
type LoopTrace = (Vec<f64>, Vec<Touched>);

/// A touched node at the end of a run: which node, the contact normal (from
/// the tool's centre) and which sphere touched it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Touched {
    /// Mesh node.
    pub node: u32,
    /// Unit normal, from the sphere centre through the node.
    pub normal: Vec3,
    /// Index of the sphere.
    pub sphere: usize,
}

/// The touched nodes of the servo's last tick.
pub fn touched_of(servo: &Servo<R>) -> Vec<Touched> {
    let c = servo.contact();
    c.nodes
        .iter()
        .map(|nc| Touched {
            node: nc.node,
            normal: nc.force / nc.force.norm().max(1e-300),
            sphere: nc.sphere as usize,
        })
        .collect()
}

/// The experiment's model: the built-in arch with both ends fixed, NVTMM
/// at rest, a vibration-only basis, its residual compliance table, the
/// service's contact and a loop model ready to run.
pub struct Setup {
    /// The mesh the setup runs on.
    pub mesh: crate::mesh::TetMesh,
    /// Largest displacement of the inflation to the pressure (m; 0 without).
    pub inflation_m: f64,
    /// The unbranched arch's grid and centreline (None on the branched
    /// arch).
    pub arch: Option<crate::mesh::arch::Arch>,
    /// Fixed nodes (sorted).
    pub fixed: Vec<u32>,
    /// K at rest.
    pub k: BlockTangent,
    /// The residual compliance table.
    pub table: Arc<LocalCompliance>,
    /// What building it cost.
    pub stats: ComplianceStats,
    /// Loop rows of the basis.
    pub rows: crate::reduced::BasisRows<R>,
    /// Reduced stiffness at rest.
    pub k0: DMatrix<f64>,
    /// Reduced dynamics settings (1 kHz, α = 5, β = 1e-3).
    pub dynp: DynamicsParams,
    /// Contact (the service's defaults).
    pub cp: ContactParams,
    /// Surface index.
    pub index: Arc<SurfaceIndex>,
    /// Loop settings (no watchdog in the way).
    pub sp: ServoParams,
}

/// What [`Setup::with`] builds on.
#[derive(Debug, Clone, PartialEq)]
pub struct SetupSpec {
    /// Arch nodes.
    pub nodes: usize,
    /// Vibration modes in the basis (≤ 32).
    pub r: usize,
    /// The residual compliance table's settings.
    pub compliance: ComplianceParams,
    /// Young's modulus of the paper's wall (Pa); the rest is the aorta's.
    pub youngs_pa: f64,
    /// The wall ([`Wall::Human`] ignores `youngs_pa`).
    pub wall: Wall,
    /// Steady luminal pressure (Pa) on the inner wall; 0: none.
    pub pressure_pa: f64,
    /// The built-in arch with its three supra-aortic branches (every vessel
    /// end fixed) instead of the unbranched one (both ends fixed).
    pub branched: bool,
}

impl Default for SetupSpec {
    fn default() -> Self {
        SetupSpec {
            nodes: 5832,
            r: 32,
            compliance: ComplianceParams::default(),
            youngs_pa: Material::aorta().youngs_pa,
            branched: false,
            wall: Wall::Paper,
            pressure_pa: 0.0,
        }
    }
}

impl Setup {
    /// Builds it: the unbranched arch of `nodes`, basis of `r` ≤ 32
    /// vibration modes.
    pub fn new(nodes: usize, r: usize, compliance: &ComplianceParams) -> Result<Setup, String> {
        Setup::with(&SetupSpec {
            nodes,
            r,
            compliance: *compliance,
            ..SetupSpec::default()
        })
    }

    /// Builds it as `spec` says.
    pub fn with(spec: &SetupSpec) -> Result<Setup, String> {
        let (nodes, r, compliance) = (spec.nodes, spec.r, &spec.compliance);
        if r > R {
            return Err(format!("r = {r} is above the experiment's capacity {R}"));
        }
        let (owned, arch) = if spec.branched {
            use crate::mesh::vessel::branched::{branched_arch, default_wall_ratio};
            use crate::mesh::vessel::implicit::BranchedArchParams;
            let params = BranchedArchParams::default();
            let b = branched_arch(&params, nodes, 1, default_wall_ratio(&params)).map_err(|x| x.to_string())?;
            (b.wall.mesh, None)
        } else {
            let arch = generate(&ArchParams::default(), nodes).map_err(|x| x.to_string())?;
            (arch.mesh.clone(), Some(arch))
        };
        let (mut mat, law, kind) = spec.wall.material();
        if spec.wall == Wall::Paper {
            mat.youngs_pa = spec.youngs_pa;
        }
        let model = crate::model::factory::build_model(kind, &owned, &mat, law, &[]);
        // Every vessel end (the inlet and each outlet) fixed.
        let mut fixed: Vec<u32> = owned
            .node_sets()
            .iter()
            .filter(|(name, _)| name.starts_with("inlet") || name.starts_with("outlet"))
            .flat_map(|(_, nodes)| nodes.iter().copied())
            .collect();
        fixed.sort_unstable();
        fixed.dedup();
        let n = owned.num_nodes();
        // The state the loop and the reference are linearized at: rest, or
        // the wall inflated statically to the pressure; its tangent holds
        // the pressure's load stiffness (symmetric part).
        let mut u0 = vec![Vec3::zeros(); n];
        let mut k = BlockTangent::zeros(&owned);
        if spec.pressure_pa > 0.0 {
            use crate::solver::pressure::{LuminalPressure, PressureSchedule, PressureTangent};
            use crate::solver::statics::{mask_of_fixed, solve_pressurized, StaticParams};
            let load = LuminalPressure::on_set(
                &owned,
                "inner_wall",
                PressureSchedule::steady(spec.pressure_pa),
                PressureTangent::Symmetric,
            )
            .map_err(|e| e.to_string())?;
            let params = StaticParams {
                load_steps: 8,
                ..StaticParams::default()
            };
            solve_pressurized(
                &owned,
                model.as_ref(),
                &load,
                spec.pressure_pa,
                &mask_of_fixed(n, &fixed),
                &params,
                &mut u0,
            )
            .map_err(|e| {
                format!(
                    "inflating the {} wall to {} Pa: {e}",
                    spec.wall.name(),
                    spec.pressure_pa
                )
            })?;
            load.add_stiffness(spec.pressure_pa, &u0, &mut k);
        }
        model.add_stiffness(&u0, &mut k);
        let inflation_m = u0.iter().map(|v| v.norm()).fold(0.0, f64::max);
        // The contact sees the inflated surface: a mesh whose rest is there
        // (same nodes, tets and sets, so the tangent's layout is its own).
        let owned = if spec.pressure_pa > 0.0 {
            let x: Vec<Vec3> = owned.rest().iter().zip(&u0).map(|(x, u)| x + u).collect();
            crate::mesh::TetMesh::new(x, owned.tets().to_vec(), owned.node_sets().clone()).map_err(|e| e.to_string())?
        } else {
            owned
        };
        let mesh = &owned;
        let mass = mesh.lumped_mass(mat.density);
        let basis = ModalBasis::compute(&crate::reduced::BasisSpec {
            stiffness: crate::reduced::Stiffness::Tangent(&k),
            mass: &mass,
            fixed: &fixed,
            r,
            statics: crate::reduced::Statics::None,
            warm: None,
            params: crate::reduced::BasisParams::default(),
        })
        .map_err(|x| x.to_string())?;
        let (table, stats) = LocalCompliance::compute(mesh, &k, &basis, compliance)?;
        let table = Arc::new(table);
        let rows = basis_rows::<R>(&basis).map_err(|x| x.to_string())?;
        let k0 = Refresher::new(mesh, &basis, &mass).project_tangent(&k);
        let dynp = DynamicsParams {
            dt: 1e-3,
            alpha: 5.0,
            beta: 1e-3,
        };
        let cp = ContactParams::default();
        let index = Arc::new(SurfaceIndex::new(mesh, &cp));
        let sp = ServoParams {
            dt: dynp.dt,
            contact: cp,
            device_origin: Vec3::zeros(),
            device_timeout_s: f64::INFINITY,
            model_timeout_s: f64::INFINITY,
            model_max_age_s: f64::INFINITY,
            max_speed_m_s: 100.0,
            max_reach_m: 10.0,
            overrun_streak: u32::MAX,
            ramp_down_s: 0.01,
            ramp_in_s: 0.0,
            swap_blend_s: 0.0,
            command_timeout_s: crate::haptics::device::DEFAULT_COMMAND_TIMEOUT_S,
        };
        Ok(Setup {
            mesh: owned,
            inflation_m,
            arch,
            fixed,
            k,
            table,
            stats,
            rows,
            k0,
            dynp,
            cp,
            index,
            sp,
        })
    }

    /// A loop at rest, with or without the residual compliance.
    pub fn servo(&self, with_table: bool) -> Result<Servo<R>, String> {
        let n = self.mesh.num_nodes();
        let mut m = rest_model::<R>(self.rows.clone(), &self.k0, &self.dynp, n).map_err(|x| x.to_string())?;
        m.compliance = with_table.then(|| self.table.clone());
        Ok(Servo::new(m, self.index.clone(), self.sp, 0.0))
    }

    /// The full model's reaction on each sphere with the same contact
    /// ([`reference()`]: the active set iterated to convergence), starting
    /// from the nodes the loop `touched`.
    pub fn full_reactions(&self, spheres: &[Vec3], touched: &[Touched]) -> Result<Vec<Vec3>, String> {
        let mut exact = ExactCompliance::new(&self.k, &self.fixed)?;
        let seed: Vec<u32> = touched.iter().map(|t| t.node).collect();
        Ok(reference(&self.mesh, &self.cp, &self.index, &mut exact, spheres, None, &seed)?.forces)
    }
}

/// Runs the experiment.
pub fn run(e: &ContactExperiment) -> Result<ContactResult, String> {
    if e.r > R {
        return Err(format!("r = {} is above the experiment's capacity {R}", e.r));
    }
    if e.push_speed_m_s.is_nan() || e.push_speed_m_s <= 0.0 {
        return Err(format!("push speed {} m/s: must be above 0", e.push_speed_m_s));
    }
    if !(e.push_m > 0.0 && e.push_m <= ContactParams::default().tool_radius_m) {
        return Err(format!(
            "push {} mm: must be in (0, {}] mm (at most the tool's radius)",
            e.push_m * 1e3,
            ContactParams::default().tool_radius_m * 1e3
        ));
    }
    let s = Setup::with(&SetupSpec {
        nodes: e.nodes,
        r: e.r,
        compliance: e.compliance,
        branched: e.branched,
        wall: e.wall,
        pressure_pa: e.pressure_pa,
        ..SetupSpec::default()
    })?;
    let Setup {
        mesh,
        fixed,
        stats,
        dynp,
        cp,
        index,
        ..
    } = &s;
    let (stats, dynp, cp) = (*stats, *dynp, *cp);
    let n = mesh.num_nodes();
    let mut exact = ExactCompliance::new(&s.k, fixed)?;
    let normals = mesh.surface_vertex_normals();
    let is_fixed = |i: u32| fixed.binary_search(&i).is_ok();
    let pick = |set: &str, count: usize, seed: u64| -> Vec<u32> {
        let cand: Vec<u32> = mesh
            .node_set(set)
            .unwrap_or(&[])
            .iter()
            .copied()
            .filter(|&i| !is_fixed(i))
            .collect();
        let mut s = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (0..count)
            .filter_map(|_| {
                s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                (!cand.is_empty()).then(|| cand[((s >> 33) as usize) % cand.len()])
            })
            .collect()
    };
    let mut targets: Vec<(u32, bool)> = pick("inner_wall", e.points / 2, e.seed)
        .into_iter()
        .map(|i| (i, true))
        .collect();
    targets.extend(
        pick("outer_wall", e.points - e.points / 2, e.seed + 1)
            .into_iter()
            .map(|i| (i, false)),
    );
    let ticks = (e.settle_s / dynp.dt).round() as usize;
    let mut points = Vec::new();
    let mut dropped = Vec::new();
    for (node, inner) in targets {
        let drop = |reason: String| DroppedPoint { node, inner, reason };
        let nrm = normals[node as usize];
        if nrm.norm() < 0.5 {
            dropped.push(drop(format!(
                "no surface normal at the node (|n| = {:.2}: its triangles' normals cancel)",
                nrm.norm()
            )));
            continue;
        }
        let tool = mesh.rest()[node as usize] + nrm * (cp.tool_radius_m - e.push_m);
        // Where the probe just touches the undeformed wall.
        let touching = mesh.rest()[node as usize] + nrm * cp.tool_radius_m;
        // The tick (from 1) on which the probe reaches its depth; it is
        // then held there for `settle_s`.
        let arrival = ((e.push_m / e.push_speed_m_s / dynp.dt).ceil() as usize).max(1);
        let total = arrival - 1 + ticks.max(1);
        let run_loop = |with_table: bool| -> Result<LoopTrace, String> {
            let mut servo = s.servo(with_table)?;
            let mut trace = Vec::with_capacity(total);
            for t in 1..=total {
                let w = (t as f64 / arrival as f64).min(1.0);
                let s = DeviceSample::held_at(t as u64, t as f64 * dynp.dt, touching * (1.0 - w) + tool * w);
                let out = servo.tick(Some(&s), t as f64 * dynp.dt, 0);
                trace.push(out.desired.norm());
            }
            let touched = touched_of(&servo);
            Ok((trace, touched))
        };
        let (trace, touched) = run_loop(true)?;
        let (trace_basis, _) = run_loop(false)?;
        let seed: Vec<u32> = touched.iter().map(|t| t.node).collect();
        // The reference pushes the probe in from where it just touches.
        let refr = match reference(mesh, &cp, index, &mut exact, &[tool], Some(&[touching]), &seed) {
            Ok(r) => r,
            Err(why) => {
                dropped.push(drop(format!("no reference: {why}")));
                continue;
            }
        };
        let full = refr.forces[0].norm();
        if full.is_nan() || full <= 0.0 {
            dropped.push(drop(format!(
                "the reference takes no force (the probe, {} mm into the undeformed wall, touches nothing there)",
                e.push_m * 1e3
            )));
            continue;
        }
        let last = |tr: &[f64]| tr.last().copied().unwrap_or(0.0);
        // From the tick the probe reaches its depth.
        let (trace, trace_basis) = (&trace[arrival - 1..], &trace_basis[arrival - 1..]);
        let settled_from = trace
            .iter()
            .rposition(|f| (f / full - 1.0).abs() > 0.1)
            .map(|k| k + 1)
            .unwrap_or(0);
        points.push(ContactPoint {
            node,
            inner,
            full_n: full,
            ratio_first: trace.first().copied().unwrap_or(0.0) / full,
            ratio_settled: last(trace) / full,
            ratio_settled_basis_only: last(trace_basis) / full,
            settle_ms: (settled_from as f64 + 1.0) * dynp.dt * 1e3,
            touched: touched.len(),
            reference_nodes: refr.nodes,
            reference_active: refr.active,
            reference_rounds: refr.rounds,
        });
    }
    let col = |f: fn(&ContactPoint) -> f64| points.iter().map(f).collect::<Vec<f64>>();
    Ok(ContactResult {
        nodes: n,
        r: e.r,
        ratio_settled: Spread::of(&col(|p| p.ratio_settled), true),
        ratio_first: Spread::of(&col(|p| p.ratio_first), true),
        ratio_settled_basis_only: Spread::of(&col(|p| p.ratio_settled_basis_only), true),
        settle_ms: Spread::of(&col(|p| p.settle_ms), false),
        points,
        dropped,
        push_m: e.push_m,
        wall: e.wall,
        pressure_pa: e.pressure_pa,
        inflation_m: s.inflation_m,
        table: stats,
    })
}

/// The nodes the `spheres` press at rest (the plain contact on the
/// undeformed surface), sorted.
pub fn pressed_at_rest(
    mesh: &crate::mesh::TetMesh,
    cp: &ContactParams,
    index: &SurfaceIndex,
    spheres: &[Vec3],
) -> Vec<u32> {
    let mut scratch = crate::haptics::contact::Candidates::new();
    let mut out = crate::haptics::contact::ContactOutput::<1>::for_index(index);
    crate::haptics::contact::evaluate_spheres(
        index,
        cp,
        spheres,
        |i| mesh.rest()[i as usize],
        |_| None,
        None,
        None,
        &mut scratch,
        &mut out,
    );
    let mut nodes: Vec<u32> = out.nodes.iter().map(|c| c.node).collect();
    nodes.sort_unstable();
    nodes.dedup();
    nodes
}

/// The full linear model's answer to the tool: the reaction on each sphere
/// and how it was found ([`reference()`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Reference {
    /// Reaction on each sphere (N).
    pub forces: Vec<Vec3>,
    /// Nodes solved for (the converged candidate set).
    pub nodes: usize,
    /// Nodes in contact at equilibrium.
    pub active: usize,
    /// Rounds of the active-set iteration.
    pub rounds: usize,
    /// The contact force on each node in contact (N) and its displacement (m).
    pub node_forces: Vec<(u32, Vec3, Vec3)>,
}

/// Rounds of [`reference()`]'s active-set iteration before it gives up.
pub const REFERENCE_ROUNDS: usize = 8;

/// Longest move of a sphere between two solves of [`reference()`] (m).
pub const REFERENCE_STEP_M: f64 = 0.2e-3;

/// The full linear model's reactions on the tool `spheres` with the same
/// contact as the loop (the pressure on the deformed surface triangles,
/// [`crate::haptics::contact`]), its active set iterated to convergence.
///
/// The unknowns are the displacements of a candidate set C of surface
/// nodes: every node within the tool radius plus the longest surface edge
/// of a sphere centre, and the `seed` nodes. They satisfy u_C = W f_C(x)
/// with W = (K⁻¹)_CC (exact columns) and f the contact forces at the
/// deformed positions, so every candidate, pressed or not, moves as the
/// full model moves it under the contact, and the triangles the contact
/// integrates over have their true shape at any depth. Once solved
/// ([`full_forces`]), a node that takes force but is not in C (the patch
/// grew past the candidates) joins C, with the surface nodes near it, and
/// the solve is repeated, until the active set lies within C.
///
/// With `from` (where each sphere starts, e.g. just touching the wall),
/// the spheres are moved from there to `spheres` in steps of at most
/// [`REFERENCE_STEP_M`], each solve starting from the last: the
/// equilibrium a probe pushed in reaches. A probe held deeper into the
/// undeformed wall than the wall is thick has a second, unphysical
/// equilibrium (the sphere sunk into the wall, pushing its far surface from
/// inside), which a solve started from rest can find instead.
pub fn reference(
    mesh: &crate::mesh::TetMesh,
    cp: &ContactParams,
    index: &SurfaceIndex,
    exact: &mut ExactCompliance,
    spheres: &[Vec3],
    from: Option<&[Vec3]>,
    seed: &[u32],
) -> Result<Reference, String> {
    let rest = mesh.rest();
    let surface = mesh.surface_nodes();
    let longest = mesh
        .surface()
        .iter()
        .flat_map(|t| [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])])
        .map(|(a, b)| (rest[a as usize] - rest[b as usize]).norm())
        .fold(0.0, f64::max);
    let near = |centres: &[Vec3], reach: f64| -> Vec<u32> {
        surface
            .iter()
            .copied()
            .filter(|&i| centres.iter().any(|c| (rest[i as usize] - c).norm() <= reach))
            .collect()
    };
    let start = from.unwrap_or(spheres);
    if start.len() != spheres.len() {
        return Err(format!("{} start positions for {} spheres", start.len(), spheres.len()));
    }
    let travel = start
        .iter()
        .zip(spheres)
        .map(|(a, b)| (a - b).norm())
        .fold(0.0, f64::max);
    let steps = ((travel / REFERENCE_STEP_M).ceil() as usize).max(1);
    let path: Vec<Vec<Vec3>> = (1..=steps)
        .map(|k| {
            let w = k as f64 / steps as f64;
            start.iter().zip(spheres).map(|(a, b)| a * (1.0 - w) + b * w).collect()
        })
        .collect();
    let mut set: Vec<u32> = near(spheres, cp.tool_radius_m + longest);
    set.extend(near(start, cp.tool_radius_m + longest));
    set.extend_from_slice(seed);
    set.extend(pressed_at_rest(mesh, cp, index, spheres));
    set.sort_unstable();
    set.dedup();
    if set.is_empty() {
        return Err("no surface node near the tool".into());
    }
    'rounds: for round in 1..=REFERENCE_ROUNDS {
        let w = exact.blocks(&set)?;
        let mut u = nalgebra::DVector::zeros(3 * set.len());
        let mut solved = None;
        for (k, at) in path.iter().enumerate() {
            let s = full_forces_from(mesh, cp, index, at, &set, &w, &mut u)
                .map_err(|e| format!("{e} (step {} of {steps} of the push)", k + 1))?;
            if !s.outside.is_empty() {
                let grown: Vec<Vec3> = s.outside.iter().map(|&i| rest[i as usize]).collect();
                set.extend(s.outside.iter().copied());
                set.extend(near(&grown, longest));
                set.sort_unstable();
                set.dedup();
                continue 'rounds;
            }
            solved = Some(s);
        }
        let solved = solved.ok_or("no step")?;
        {
            return Ok(Reference {
                forces: solved.forces,
                nodes: set.len(),
                active: solved.active,
                rounds: round,
                node_forces: solved.node_forces,
            });
        }
    }
    Err(format!(
        "the active set still grew after {REFERENCE_ROUNDS} rounds ({} candidates)",
        set.len()
    ))
}

/// What [`full_forces`] found.
#[derive(Debug, Clone, PartialEq)]
pub struct Solved {
    /// Reaction on each sphere (N).
    pub forces: Vec<Vec3>,
    /// Nodes of `nodes` in contact at the solution.
    pub active: usize,
    /// The contact force on each node in contact (N), and its displacement (m).
    pub node_forces: Vec<(u32, Vec3, Vec3)>,
    /// Nodes not in `nodes` that take contact force at the solution (the
    /// candidate set was too small; empty when it was not).
    pub outside: Vec<u32>,
}

/// Solves the contact of the tool `spheres` with the surface whose nodes
/// `nodes` sit at x = X + u with u = W f(x) (W = K⁻¹ on `nodes`, all three
/// components; every other node at rest): Newton's method on
/// r(u) = u − W f(u) with a central-difference Jacobian of the contact
/// forces and a backtracking line search on ‖r‖ (the forces are only
/// piecewise smooth). An error says why it did not converge.
pub fn full_forces(
    mesh: &crate::mesh::TetMesh,
    cp: &ContactParams,
    index: &SurfaceIndex,
    spheres: &[Vec3],
    nodes: &[u32],
    w: &DMatrix<f64>,
) -> Result<Solved, String> {
    let mut u = nalgebra::DVector::zeros(3 * nodes.len());
    full_forces_from(mesh, cp, index, spheres, nodes, w, &mut u)
}

/// As [`full_forces`], starting from the displacements `u` of `nodes`
/// (3 per node), which it leaves at the solution.
pub fn full_forces_from(
    mesh: &crate::mesh::TetMesh,
    cp: &ContactParams,
    index: &SurfaceIndex,
    spheres: &[Vec3],
    nodes: &[u32],
    w: &DMatrix<f64>,
    u: &mut nalgebra::DVector<f64>,
) -> Result<Solved, String> {
    use crate::haptics::contact::{evaluate_spheres, Candidates, ContactOutput};
    use nalgebra::DVector;
    let m = nodes.len();
    let slot: std::collections::HashMap<u32, usize> = nodes.iter().enumerate().map(|(a, &i)| (i, a)).collect();
    let mut scratch = Candidates::new();
    let mut out = ContactOutput::<1>::for_index(index);
    // Node forces on `nodes` (3m), the reaction on each sphere, the nodes
    // in contact in and outside `nodes`.
    let mut forces = |u: &DVector<f64>| -> (DVector<f64>, Vec<Vec3>, usize, Vec<u32>) {
        evaluate_spheres(
            index,
            cp,
            spheres,
            |i| {
                let x = mesh.rest()[i as usize];
                match slot.get(&i) {
                    Some(&a) => x + Vec3::new(u[3 * a], u[3 * a + 1], u[3 * a + 2]),
                    None => x,
                }
            },
            |_| None,
            None,
            None,
            &mut scratch,
            &mut out,
        );
        let mut f = DVector::<f64>::zeros(3 * m);
        let (mut active, mut outside) = (0, Vec::new());
        for c in out.nodes.iter() {
            match slot.get(&c.node) {
                Some(&a) => {
                    active += 1;
                    for k in 0..3 {
                        f[3 * a + k] += c.force[k];
                    }
                }
                None if c.force.norm() > 0.0 => outside.push(c.node),
                None => {}
            }
        }
        (f, out.sphere_forces.iter().copied().collect(), active, outside)
    };
    let scale = cp.tool_radius_m;
    let tol = 1e-10 * scale;
    let h = 1e-6 * scale;
    if u.len() != 3 * m {
        return Err(format!("{} start displacements for {m} nodes", u.len()));
    }
    let residual = |u: &DVector<f64>, f: &DVector<f64>| u - w * f;
    let (f0, ..) = forces(u);
    let mut r = residual(u, &f0);
    let mut rn = r.norm();
    let mut iters = 0;
    while rn > tol {
        iters += 1;
        if iters > 200 {
            return Err(format!(
                "the reference's Newton did not converge in 200 iterations (‖r‖ = {:.1e} m on {m} nodes)",
                rn
            ));
        }
        let mut df = DMatrix::<f64>::zeros(3 * m, 3 * m);
        for j in 0..3 * m {
            let mut up = u.clone();
            up[j] += h;
            let mut dn = u.clone();
            dn[j] -= h;
            let col = (forces(&up).0 - forces(&dn).0) / (2.0 * h);
            df.set_column(j, &col);
        }
        let jac = DMatrix::<f64>::identity(3 * m, 3 * m) - w * df;
        let step = jac
            .lu()
            .solve(&r)
            .ok_or_else(|| format!("the reference's Jacobian is singular on {m} nodes"))?;
        // Backtrack until ‖r‖ falls; a full step that does not is halved
        // down to 2⁻²⁰, then taken anyway (a kink of the piecewise law).
        let mut t = 1.0;
        loop {
            let trial = &*u - &step * t;
            let (ft, ..) = forces(&trial);
            let rt = residual(&trial, &ft);
            if rt.norm() < (1.0 - 1e-4 * t) * rn || t < 1e-6 {
                *u = trial;
                r = rt;
                rn = r.norm();
                break;
            }
            t *= 0.5;
        }
    }
    let (f_end, reactions, active, mut outside) = forces(u);
    if !reactions.iter().all(|f| f.iter().all(|v| v.is_finite())) {
        return Err("the reference's force is not finite".into());
    }
    outside.sort_unstable();
    outside.dedup();
    let node_forces = (0..m)
        .filter_map(|a| {
            let f = Vec3::new(f_end[3 * a], f_end[3 * a + 1], f_end[3 * a + 2]);
            (f.norm() > 0.0).then(|| (nodes[a], f, Vec3::new(u[3 * a], u[3 * a + 1], u[3 * a + 2])))
        })
        .collect();
    Ok(Solved {
        forces: reactions,
        active,
        node_forces,
        outside,
    })
}

/// A probe sliding over the wall ([`slide`]).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct SlideResult {
    /// Arch nodes.
    pub nodes: usize,
    /// Sliding speed (m/s).
    pub speed_m_s: f64,
    /// Ticks run while sliding.
    pub ticks: usize,
    /// Rendered force magnitude per tick (N).
    pub force_n: Vec<f64>,
    /// Largest tick-to-tick change of the force vector relative to the
    /// larger of the two magnitudes, over the slide.
    pub max_jump: f64,
    /// Tick of `max_jump`.
    pub max_jump_tick: usize,
    /// Ticks with a non-finite force.
    pub nonfinite: usize,
    /// Smallest and largest force magnitude while sliding (N).
    pub force_range_n: [f64; 2],
}

/// Slides the probe along the outer wall from the arch top down to the
/// descending end at `speed_m_s`, held `push_m` into the undeformed wall
/// along the interpolated surface normal, after `settle_s` pressed at the
/// start; the basis of vibration modes with its residual compliance table.
pub fn slide(s: &Setup, speed_m_s: f64, push_m: f64, settle_s: f64) -> Result<SlideResult, String> {
    let arch = s.arch.as_ref().ok_or("the slide follows the unbranched arch's grid")?;
    let g = arch.grid;
    let mesh = &arch.mesh;
    let normals = mesh.surface_vertex_normals();
    let c = g.circumferential / 4;
    let l = g.layers - 1;
    // Outer-wall points of the path: ring a at angle index c, outer layer;
    // from the top ring towards ring 1 (ring 0 is fixed).
    let ring_point = |a: usize| -> (Vec3, Vec3) {
        let i = arch.node(a, c, l);
        (mesh.rest()[i], normals[i])
    };
    let rings: Vec<usize> = (1..=arch.top_ring).rev().collect();
    let mut arc = vec![0.0];
    for w in rings.windows(2) {
        let d = (ring_point(w[1]).0 - ring_point(w[0]).0).norm();
        arc.push(arc.last().copied().unwrap_or(0.0) + d);
    }
    let total = arc.last().copied().unwrap_or(0.0);
    let at = |dist: f64| -> Vec3 {
        let k = arc.partition_point(|&x| x <= dist).clamp(1, arc.len() - 1);
        let w = ((dist - arc[k - 1]) / (arc[k] - arc[k - 1]).max(1e-12)).clamp(0.0, 1.0);
        let (x0, n0) = ring_point(rings[k - 1]);
        let (x1, n1) = ring_point(rings[k]);
        let x = x0 * (1.0 - w) + x1 * w;
        let n = (n0 * (1.0 - w) + n1 * w).normalize();
        x + n * (s.cp.tool_radius_m - push_m)
    };
    let dt = s.dynp.dt;
    let mut servo = s.servo(true)?;
    let settle = (settle_s / dt).round() as usize;
    let ticks = (total / (speed_m_s * dt)).floor() as usize;
    let mut force_n = Vec::with_capacity(ticks);
    let (mut max_jump, mut max_jump_tick, mut nonfinite) = (0.0f64, 0, 0);
    let mut prev: Option<Vec3> = None;
    for t in 1..=settle + ticks {
        let dist = (t.saturating_sub(settle) as f64 * speed_m_s * dt).min(total);
        let tool = at(dist);
        let sample = DeviceSample::held_at(t as u64, t as f64 * dt, tool);
        let f = servo.tick(Some(&sample), t as f64 * dt, 0).desired;
        if t <= settle {
            prev = Some(f);
            continue;
        }
        if !f.iter().all(|v| v.is_finite()) {
            nonfinite += 1;
            continue;
        }
        if let Some(p) = prev {
            let jump = (f - p).norm() / f.norm().max(p.norm()).max(1e-12);
            if jump > max_jump {
                max_jump = jump;
                max_jump_tick = t - settle;
            }
        }
        prev = Some(f);
        force_n.push(f.norm());
    }
    let lo = force_n.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = force_n.iter().copied().fold(0.0, f64::max);
    Ok(SlideResult {
        nodes: mesh.num_nodes(),
        speed_m_s,
        ticks,
        force_n,
        max_jump,
        max_jump_tick,
        nonfinite,
        force_range_n: [lo, hi],
    })
}
