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
//! with the full linear model's at the same state (rest) under the same
//! sphere contact: the touched nodes move by (K⁻¹)_SS f (exact columns, 3
//! solves per touched node on a Cholesky factor of K) and the penalty and
//! the sphere geometry are solved to equilibrium, so the ratio isolates the
//! reduced model's error.
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
use crate::model::nvtmm::Nvtmm;
use crate::model::{BlockTangent, ForceModel};
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
    /// Every point.
    pub points: Vec<ContactPoint>,
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
    /// Young's modulus of the wall (Pa); the rest is the aorta's.
    pub youngs_pa: f64,
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
        let mat = Material {
            youngs_pa: spec.youngs_pa,
            ..Material::aorta()
        };
        let mesh = &owned;
        let model = Nvtmm::new(mesh, &mat);
        // Every vessel end (the inlet and each outlet) fixed.
        let mut fixed: Vec<u32> = mesh
            .node_sets()
            .iter()
            .filter(|(name, _)| name.starts_with("inlet") || name.starts_with("outlet"))
            .flat_map(|(_, nodes)| nodes.iter().copied())
            .collect();
        fixed.sort_unstable();
        fixed.dedup();
        let n = mesh.num_nodes();
        let mass = mesh.lumped_mass(mat.density);
        let zeros = vec![Vec3::zeros(); n];
        let basis = ModalBasis::compute(&crate::reduced::BasisSpec {
            stiffness: crate::reduced::Stiffness::Model {
                mesh,
                model: &model,
                u: &zeros,
            },
            mass: &mass,
            fixed: &fixed,
            r,
            statics: crate::reduced::Statics::None,
            warm: None,
            params: crate::reduced::BasisParams::default(),
        })
        .map_err(|x| x.to_string())?;
        let mut k = BlockTangent::zeros(mesh);
        model.add_stiffness(&zeros, &mut k);
        let (table, stats) = LocalCompliance::compute(mesh, &k, &basis, compliance)?;
        let table = Arc::new(table);
        let rows = basis_rows::<R>(&basis).map_err(|x| x.to_string())?;
        let k0 = Refresher::new(mesh, &basis, &mass).reduced_stiffness(&model, &zeros);
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
    /// ([`full_forces`]), on the nodes the spheres press at rest and the
    /// ones the loop `touched`.
    pub fn full_reactions(&self, spheres: &[Vec3], touched: &[Touched]) -> Result<Vec<Vec3>, String> {
        let mut exact = ExactCompliance::new(&self.k, &self.fixed)?;
        let mesh = &self.mesh;
        let mut nodes = pressed_at_rest(mesh, &self.cp, &self.index, spheres);
        nodes.extend(touched.iter().map(|t| t.node));
        nodes.sort_unstable();
        nodes.dedup();
        let w = exact.blocks(&nodes)?;
        Ok(full_forces(mesh, &self.cp, &self.index, spheres, &nodes, &w))
    }
}

/// Runs the experiment.
pub fn run(e: &ContactExperiment) -> Result<ContactResult, String> {
    if e.r > R {
        return Err(format!("r = {} is above the experiment's capacity {R}", e.r));
    }
    let s = Setup::with(&SetupSpec {
        nodes: e.nodes,
        r: e.r,
        compliance: e.compliance,
        branched: e.branched,
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
    for (node, inner) in targets {
        let nrm = normals[node as usize];
        if nrm.norm() < 0.5 {
            continue;
        }
        let tool = mesh.rest()[node as usize] + nrm * (cp.tool_radius_m - e.push_m);
        let run_loop = |with_table: bool| -> Result<LoopTrace, String> {
            let mut servo = s.servo(with_table)?;
            let mut trace = Vec::with_capacity(ticks);
            for t in 1..=ticks {
                let s = DeviceSample {
                    seq: t as u64,
                    time_s: t as f64 * dynp.dt,
                    position: tool,
                    velocity: Vec3::zeros(),
                    ..DeviceSample::REST
                };
                let out = servo.tick(Some(&s), t as f64 * dynp.dt, 0);
                trace.push(out.desired.norm());
            }
            let touched = touched_of(&servo);
            Ok((trace, touched))
        };
        let (trace, touched) = run_loop(true)?;
        let (trace_basis, _) = run_loop(false)?;
        // The full linear model with the same penalty contact, on the
        // nodes the probe touches (normals from the loop's last tick).
        let mut nodes = pressed_at_rest(mesh, &cp, index, &[tool]);
        nodes.extend(touched.iter().map(|t| t.node));
        nodes.sort_unstable();
        nodes.dedup();
        if nodes.is_empty() {
            continue;
        }
        let w = exact.blocks(&nodes)?;
        let full = full_forces(mesh, &cp, index, &[tool], &nodes, &w)[0].norm();
        if full.is_nan() || full <= 0.0 {
            continue;
        }
        let last = |tr: &[f64]| tr.last().copied().unwrap_or(0.0);
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
            ratio_settled: last(&trace) / full,
            ratio_settled_basis_only: last(&trace_basis) / full,
            settle_ms: (settled_from as f64 + 1.0) * dynp.dt * 1e3,
            touched: nodes.len(),
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

/// The full linear model's reactions on the tool `spheres` with the same
/// contact as the loop (the pressure on the deformed surface triangles,
/// [`crate::haptics::contact`]): the nodes `nodes` sit at x = X + u with
/// u = W f(x) (W = (K⁻¹) on `nodes`, all three components; every other
/// node at rest), solved by Newton's method with a finite-difference
/// Jacobian of the contact forces. Non-finite if it does not converge.
pub fn full_forces(
    mesh: &crate::mesh::TetMesh,
    cp: &ContactParams,
    index: &SurfaceIndex,
    spheres: &[Vec3],
    nodes: &[u32],
    w: &DMatrix<f64>,
) -> Vec<Vec3> {
    use crate::haptics::contact::{evaluate_spheres, Candidates, ContactOutput};
    let m = nodes.len();
    let slot: std::collections::HashMap<u32, usize> = nodes.iter().enumerate().map(|(a, &i)| (i, a)).collect();
    let mut scratch = Candidates::new();
    let mut out = ContactOutput::<1>::for_index(index);
    // Node forces on `nodes` (3m) and the reaction on each sphere.
    let mut forces = |u: &nalgebra::DVector<f64>| -> (nalgebra::DVector<f64>, Vec<Vec3>) {
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
        let mut f = nalgebra::DVector::<f64>::zeros(3 * m);
        for c in out.nodes.iter() {
            if let Some(&a) = slot.get(&c.node) {
                for k in 0..3 {
                    f[3 * a + k] += c.force[k];
                }
            }
        }
        (f, out.sphere_forces.iter().copied().collect())
    };
    let mut u = nalgebra::DVector::<f64>::zeros(3 * m);
    let h = 1e-4 * cp.tool_radius_m;
    for _ in 0..60 {
        let (f, _) = forces(&u);
        let r = &u - w * &f;
        if r.norm() <= 1e-12 * cp.tool_radius_m {
            break;
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
        let Some(step) = jac.lu().solve(&r) else {
            return vec![Vec3::repeat(f64::NAN); spheres.len()];
        };
        // Damped: never move a node by more than a tenth of the radius at once.
        let big = step.amax();
        let damp = if big > 0.1 * cp.tool_radius_m {
            0.1 * cp.tool_radius_m / big
        } else {
            1.0
        };
        u -= step * damp;
    }
    let (f, reactions) = forces(&u);
    let r = &u - w * &f;
    if r.norm().is_nan() || r.norm() > 1e-9 * cp.tool_radius_m {
        return vec![Vec3::repeat(f64::NAN); spheres.len()];
    }
    reactions
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
        let sample = DeviceSample {
            seq: t as u64,
            time_s: t as f64 * dt,
            position: tool,
            velocity: Vec3::zeros(),
            ..DeviceSample::REST
        };
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
