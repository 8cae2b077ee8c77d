//! The background thread: the full NVTMM implicit-Euler solve under the
//! contact forces the haptic loop reports, and after every step a new
//! linearization of the reduced model (K_r(ū), ū, Φᵀf̄) sent to the loop
//! through a ring. Models the loop hands back are freed here, off the RT
//! thread. This thread may allocate; it never blocks the loop (every ring
//! operation is a non-blocking push or pop).
//!
//! **Background basis refresh.** When the full solve has moved far enough
//! from the state the basis was computed at, the background thread hands
//! the tangent its last step assembled to a basis thread ([`basis_thread`]),
//! which recomputes the modal basis there warm-started from the previous
//! one ([`ModalBasis::compute`] from the step's tangent) and sends back a new
//! [`Refresher`] and basis rows. The next model built carries the loop's
//! state over to the new basis, δq₁ = Φ₁ᵀ M Φ₀ δq₀ + Φ₁ᵀ M (ū₀ − ū₁), and
//! the loop cross-fades as at every swap.

use super::faults::FaultSwitches;
use crate::haptics::contact::NodeContact;
use crate::haptics::servo::LoopModel;
use crate::math::Vec3;
use crate::mesh::TetMesh;
use crate::model::BlockTangent;
use crate::model::ForceModel;
use crate::reduced::compliance::{ComplianceParams, LocalCompliance};
use crate::reduced::{
    basis_rows, BasisParams, BasisRows, DynamicsParams, ModalBasis, ModalPulse, ReducedDynamics, Refresher,
};
use crate::rt::clock;
use crate::solver::loads::{Loads, NodalLoad, TimeProfile};
use crate::solver::pressure::{LuminalPressure, Waveform};
use crate::solver::{ImplicitEuler, TissueState};
use nalgebra::{DMatrix, SMatrix, SVector};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

/// Contact forces of one loop tick (loop → background).
#[derive(Debug, Clone)]
pub struct ContactMsg {
    /// Loop tick number.
    pub tick: u64,
    /// Nodal forces on the tissue (N); truncated at capacity.
    pub nodes: heapless::Vec<NodeContact, CONTACT_MSG_NODES>,
}

/// Node capacity of one [`ContactMsg`].
pub const CONTACT_MSG_NODES: usize = 64;

/// What the background thread needs.
pub struct Background<const R: usize> {
    /// The full force model (NVTMM, with Prony if the scene has it).
    pub model: Box<dyn ForceModel>,
    /// The integrator (its dt is the background step).
    pub solver: ImplicitEuler,
    /// Fixed nodes.
    pub fixed: Vec<u32>,
    /// Re-linearizes in the basis.
    pub refresher: Refresher,
    /// The basis rows shared with the loop's models.
    pub rows: BasisRows<R>,
    /// Reduced damping and step of the loop.
    pub dynamics: DynamicsParams,
    /// ū, Φᵀ M ū and the epoch of the last model sent.
    pub last_sent: (Arc<Vec<Vec3>>, SVector<f64, R>, u64),
    /// Largest background step (s) when following real time.
    pub dt_max: f64,
    /// When to recompute the basis in the background.
    pub basis_policy: BasisPolicy,
    /// The residual compliance of the basis in use (contact anywhere), given
    /// to every model sent; None: the reduced model alone.
    pub compliance: Option<Arc<LocalCompliance>>,
    /// Blood pressure (None: off).
    pub pressure: Option<BackgroundPressure>,
}

/// Blood pressure in the service: the full solve carries the steady mean
/// (ramped in), the loop's models the heartbeat as a modal load about it
/// ([`ModalPulse`]), so the beat costs the loop an R-vector per tick and
/// the full solve no extra Newton work.
#[derive(Debug, Clone)]
pub struct BackgroundPressure {
    /// The steady load of the full solve (the scene's schedule without its
    /// waveform).
    pub load: LuminalPressure,
    /// The heartbeat the loop adds, if any.
    pub waveform: Option<Waveform>,
    /// The full solve's simulated time (s), the beat's clock.
    pub t_s: f64,
    /// Work memory: the pressure force per pascal at ū.
    unit: Vec<Vec3>,
    /// The displacement the full solve starts from (the wall inflated to
    /// the mean; None: rest), taken by [`run`].
    start: Option<Vec<Vec3>>,
}

impl BackgroundPressure {
    /// Splits the scene's pressure into the steady load and the beat.
    pub fn new(mut load: LuminalPressure) -> BackgroundPressure {
        let waveform = load.schedule.waveform.take();
        let n = load.num_nodes();
        BackgroundPressure {
            load,
            waveform,
            t_s: 0.0,
            unit: vec![Vec3::zeros(); n],
            start: None,
        }
    }

    /// The full solve starts from displacement `u` (the wall in equilibrium
    /// at the mean pressure, its ramp dropped) instead of rest.
    pub fn starting_at(mut self, u: Option<Vec<Vec3>>) -> BackgroundPressure {
        self.start = u;
        self
    }

    /// The loop's modal pulse for a model linearized at `u`, once the ramp is
    /// over (before it, the full solve is still inflating the wall).
    fn pulse<const R: usize>(&mut self, refresher: &Refresher, u: &[Vec3]) -> Option<ModalPulse<R>> {
        let waveform = self.waveform?;
        let schedule = self.load.schedule;
        if self.t_s < schedule.ramp_s {
            return None;
        }
        self.unit.iter_mut().for_each(|f| *f = Vec3::zeros());
        self.load.add_forces(1.0, u, &mut self.unit);
        let r = refresher.len();
        Some(ModalPulse {
            load_per_pa: to_s::<R>(&refresher.project_force(&self.unit).as_slice()[..r]),
            waveform,
            mean_pa: schedule.mean_pa,
            t_s: self.t_s,
        })
    }
}

/// When the background thread asks for a new basis: at most every
/// `every_s` seconds, and only once the full solve's displacement has
/// changed by `min_change_m` somewhere since the basis in use was computed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BasisPolicy {
    /// Shortest time between requests (s); 0 disables the basis refresh.
    pub every_s: f64,
    /// Smallest change of the displacement field (max over nodes, m).
    pub min_change_m: f64,
}

impl BasisPolicy {
    /// No background basis refresh.
    pub const OFF: BasisPolicy = BasisPolicy {
        every_s: 0.0,
        min_change_m: 0.0,
    };
}

/// A request to the basis thread: the tangent of the full solve's last step.
#[derive(Debug)]
pub struct BasisJob {
    /// K at the full solve's state (fixed rows not projected).
    pub tangent: BlockTangent,
}

/// A recomputed basis, ready to be installed by the background thread.
pub struct NewBasis<const R: usize> {
    /// Re-linearizes in the new basis.
    pub refresher: Refresher,
    /// Its per-node rows, shared with the loop's models.
    pub rows: BasisRows<R>,
    /// Wall time of the computation (s).
    pub seconds: f64,
    /// Subspace iterations it took.
    pub iterations: usize,
    /// The residual compliance of the new basis (when contact anywhere is on).
    pub compliance: Option<Arc<LocalCompliance>>,
}

/// What the basis thread needs.
pub struct BasisWorker {
    /// The mesh.
    pub mesh: Arc<TetMesh>,
    /// Lumped mass per node (kg).
    pub mass: Vec<f64>,
    /// Fixed nodes.
    pub fixed: Vec<u32>,
    /// Contact region of the static modes.
    pub contact: Vec<u32>,
    /// Basis size.
    pub r: usize,
    /// Static directions kept (as at start).
    pub max_static: usize,
    /// Stopping rule.
    pub params: BasisParams,
    /// The basis in use: the warm start of the next computation.
    pub current: ModalBasis,
    /// Contact anywhere: the residual compliance is recomputed with each
    /// basis (None: off).
    pub compliance: Option<ComplianceParams>,
}

/// Statistics of the basis thread.
#[derive(Debug, Clone, Default)]
pub struct BasisStats {
    /// Bases recomputed and sent.
    pub recomputed: u64,
    /// Recomputations that failed (the basis in use was kept).
    pub failures: u64,
    /// Wall time of each recomputation (s).
    pub seconds: Vec<f64>,
    /// Subspace iterations of each recomputation.
    pub iterations: Vec<usize>,
}

/// The basis thread (normal priority): recomputes the basis for each job,
/// warm-started from the last one, until `stop` is set. Jobs arrive one at
/// a time (the background thread waits for the answer before asking again).
pub fn basis_thread<const R: usize>(
    mut w: BasisWorker,
    mut jobs: rtrb::Consumer<BasisJob>,
    mut out: rtrb::Producer<Option<NewBasis<R>>>,
    stop: Arc<AtomicBool>,
    faults: Arc<FaultSwitches>,
) -> BasisStats {
    let mut stats = BasisStats::default();
    while !stop.load(Ordering::Relaxed) {
        let Ok(job) = jobs.pop() else {
            std::thread::sleep(std::time::Duration::from_millis(5));
            continue;
        };
        if FaultSwitches::take(&faults.panic_basis) {
            panic!("injected fault: the basis thread panics");
        }
        let mut params = w.params;
        let injected = FaultSwitches::take(&faults.fail_next_basis);
        if injected {
            // No iteration at all: it fails even from a warm start that is
            // already converged (one iteration from the basis in use at an
            // unchanged tangent would succeed).
            params.max_iterations = 0;
        }
        let t = std::time::Instant::now();
        let basis = ModalBasis::compute(&crate::reduced::BasisSpec {
            stiffness: crate::reduced::Stiffness::Tangent(&job.tangent),
            mass: &w.mass,
            fixed: &w.fixed,
            r: w.r,
            statics: crate::reduced::Statics::Compressed {
                contact: &w.contact,
                max_static: w.max_static,
            },
            warm: Some(&w.current),
            params,
        });
        let Ok(basis) = basis else {
            stats.failures += 1;
            if injected {
                FaultSwitches::served(&faults.basis_failures_served);
            }
            // Answer the job: the background asks again later.
            let _ = out.push(None);
            continue;
        };
        let Ok(rows) = basis_rows::<R>(&basis) else {
            stats.failures += 1;
            let _ = out.push(None);
            continue;
        };
        let refresher = Refresher::new(&w.mesh, &basis, &w.mass);
        let compliance = match &w.compliance {
            Some(cp) => match LocalCompliance::compute(&w.mesh, &job.tangent, &basis, cp) {
                Ok((c, _)) => Some(Arc::new(c)),
                Err(_) => {
                    stats.failures += 1;
                    let _ = out.push(None);
                    continue;
                }
            },
            None => None,
        };
        let seconds = t.elapsed().as_secs_f64();
        stats.seconds.push(seconds);
        stats.iterations.push(basis.iterations);
        let msg = NewBasis {
            refresher,
            rows,
            seconds,
            iterations: basis.iterations,
            compliance,
        };
        if out.push(Some(msg)).is_ok() {
            stats.recomputed += 1;
            w.current = basis;
        } else {
            stats.failures += 1;
        }
    }
    stats
}

/// Statistics of the background thread.
#[derive(Debug, Clone, Default)]
pub struct BackgroundStats {
    /// Full steps done.
    pub steps: u64,
    /// Full steps that failed (state kept).
    pub failed_steps: u64,
    /// Full steps covered by halved sub-steps (`[integrator] max_halvings`).
    pub split_steps: u64,
    /// Wall time per full step (µs).
    pub step_us: Vec<f64>,
    /// Wall time per linearization refresh (µs).
    pub refresh_us: Vec<f64>,
    /// Refreshes that could not build a model (e.g. K_r not positive definite).
    pub refresh_failures: u64,
    /// Models pushed to the loop.
    pub models_sent: u64,
    /// Times the model ring was full (the model was kept and a newer one
    /// sent later: keep-latest).
    pub model_ring_full: u64,
    /// Models returned by the loop and freed here.
    pub models_freed: u64,
    /// Contact messages received.
    pub contact_msgs: u64,
    /// Simulated time of the full solve (s).
    pub sim_time_s: f64,
    /// Wall time spent (s).
    pub wall_s: f64,
    /// Largest nodal displacement of the full solve (m).
    pub max_displacement_m: f64,
    /// Basis refreshes requested from the basis thread.
    pub basis_requests: u64,
    /// New bases installed.
    pub basis_installed: u64,
    /// Models sent that changed the basis (their transfer is not I).
    pub basis_swaps_sent: u64,
}

/// Rings and shared flags of the background thread.
pub struct BackgroundIo<const R: usize> {
    /// Contact forces from the loop.
    pub contact: rtrb::Consumer<ContactMsg>,
    /// New models to the loop.
    pub models: rtrb::Producer<Box<LoopModel<R>>>,
    /// Old models back from the loop.
    pub returned: rtrb::Consumer<Box<LoopModel<R>>>,
    /// Set to stop.
    pub stop: Arc<AtomicBool>,
    /// Live figures: the loop's tick counter (read), the background's
    /// progress (written).
    pub live: Arc<super::live::LiveStats>,
    /// Jobs to the basis thread and its answers (None: no basis refresh).
    pub basis: Option<(rtrb::Producer<BasisJob>, rtrb::Consumer<Option<NewBasis<R>>>)>,
    /// ū and the basis rows of each model sent, for the stream publisher
    /// (keep-latest: dropped when full).
    pub offsets: Option<rtrb::Producer<OffsetMsg<R>>>,
    /// Fault injection ([`FaultSwitches`]).
    pub faults: Arc<FaultSwitches>,
}

/// ū and the basis rows of the model of one epoch (background → publisher).
pub type OffsetMsg<const R: usize> = (u64, Arc<Vec<Vec3>>, BasisRows<R>);

impl<const R: usize> Background<R> {
    /// Builds the model for displacement `u` under the contact force `fbar`
    /// (per node), with the transfer from the last model sent (whose basis
    /// is `sent_phi` if it differs from the current one). Returns the model
    /// and its Φᵀ M ū.
    pub fn build_model(
        &mut self,
        u: &[Vec3],
        fbar: &[Vec3],
        epoch: u64,
        sent_phi: Option<&DMatrix<f64>>,
    ) -> Option<(Box<LoopModel<R>>, SVector<f64, R>)> {
        let kr = reduced_tangent(&mut self.refresher, self.model.as_ref(), self.pressure.as_ref(), u);
        self.model_from(kr, u, fbar, epoch, sent_phi)
    }

    /// As [`Background::build_model`] with the tangent the last full step
    /// assembled (at its start state, one background step behind `u`),
    /// which saves the assembly.
    pub fn build_model_from_step(
        &mut self,
        u: &[Vec3],
        fbar: &[Vec3],
        epoch: u64,
        sent_phi: Option<&DMatrix<f64>>,
    ) -> Option<(Box<LoopModel<R>>, SVector<f64, R>)> {
        let kr = self.refresher.project_tangent(self.solver.last_stiffness());
        self.model_from(kr, u, fbar, epoch, sent_phi)
    }

    fn model_from(
        &mut self,
        kr: DMatrix<f64>,
        u: &[Vec3],
        fbar: &[Vec3],
        epoch: u64,
        sent_phi: Option<&DMatrix<f64>>,
    ) -> Option<(Box<LoopModel<R>>, SVector<f64, R>)> {
        let r = self.refresher.len();
        let mut dynamics = ReducedDynamics::with_rows(self.rows.clone(), r, &kr, &self.dynamics).ok()?;
        if let Some(p) = self.pressure.as_mut() {
            dynamics.set_pulse(p.pulse(&self.refresher, u));
        }
        let qbar = to_s::<R>(&self.refresher.project_mass(u).as_slice()[..r]);
        let fb = to_s::<R>(&self.refresher.project_force(fbar).as_slice()[..r]);
        let offset = Arc::new(u.to_vec());
        let (transfer, shift) = match sent_phi {
            // Same basis: δq₁ = δq₀ + Φᵀ M (ū₀ − ū₁).
            None => (SMatrix::identity(), self.last_sent.1 - qbar),
            // New basis: δq₁ = Φ₁ᵀ M Φ₀ δq₀ + Φ₁ᵀ M ū₀ − Φ₁ᵀ M ū₁.
            Some(phi0) => {
                let t = self.refresher.transfer_from(phi0);
                let mut tm = SMatrix::<f64, R, R>::zeros();
                for i in 0..t.nrows().min(R) {
                    for j in 0..t.ncols().min(R) {
                        tm[(i, j)] = t[(i, j)];
                    }
                }
                let q0 = to_s::<R>(&self.refresher.project_mass(&self.last_sent.0).as_slice()[..r]);
                (tm, q0 - qbar)
            }
        };
        // How far the swap moves any node, in the same basis: a node's
        // position at the carried state δq + s against its position at δq
        // in the last model sent, ū₁ − ū₀ + Φ s (the part of ū's change
        // the basis does not follow). The loop's swap keeps its contact
        // triangles with that much more motion allowed instead of
        // searching the surface. (f64::max skips a NaN: a change that is
        // not finite gives none.)
        let surface_moved_m = match sent_phi {
            None if self.last_sent.0.len() == u.len() && self.rows.len() == u.len() => u
                .iter()
                .zip(self.last_sent.0.iter())
                .zip(self.rows.iter())
                .map(|((a, b), phi)| (a - b + phi * shift).norm())
                .try_fold(0.0, |m: f64, d| d.is_finite().then(|| m.max(d))),
            _ => None,
        };
        if !(transfer.iter().all(|v| v.is_finite()) && shift.iter().all(|v| v.is_finite())) {
            return None;
        }
        let model = Box::new(LoopModel {
            epoch,
            dynamics,
            offset,
            f_bar: fb,
            transfer,
            shift,
            created_s: clock::now_s(),
            compliance: self.compliance.clone(),
            surface_moved_m,
        });
        Some((model, qbar))
    }
}

/// K_r at `u`: the wall's tangent plus, with a pressure, its load
/// stiffness at the pressure the full solve carries now (the symmetric part,
/// as the full step's tangent has it), so a model built from an assembly
/// matches one built from the step's tangent.
pub fn reduced_tangent(
    refresher: &mut Refresher,
    model: &dyn ForceModel,
    pressure: Option<&BackgroundPressure>,
    u: &[Vec3],
) -> DMatrix<f64> {
    match pressure {
        Some(p) => {
            let pa = p.load.schedule.pressure_at(p.t_s);
            refresher.reduced_stiffness_with(model, u, |k| p.load.add_stiffness(pa, u, k))
        }
        None => refresher.reduced_stiffness(model, u),
    }
}

fn to_s<const R: usize>(v: &[f64]) -> SVector<f64, R> {
    let mut out = SVector::<f64, R>::zeros();
    for (o, x) in out.iter_mut().zip(v) {
        *o = *x;
    }
    out
}

/// The model linearized at rest (epoch 0), the loop's first model.
pub fn rest_model<const R: usize>(
    rows: BasisRows<R>,
    k_r: &DMatrix<f64>,
    params: &DynamicsParams,
    n: usize,
) -> Result<Box<LoopModel<R>>, crate::reduced::ReducedError> {
    let r = k_r.nrows();
    let dynamics = ReducedDynamics::with_rows(rows, r, k_r, params)?;
    Ok(Box::new(LoopModel {
        epoch: 0,
        dynamics,
        offset: Arc::new(vec![Vec3::zeros(); n]),
        f_bar: SVector::zeros(),
        transfer: SMatrix::identity(),
        shift: SVector::zeros(),
        created_s: clock::now_s(),
        compliance: None,
        surface_moved_m: None,
    }))
}

/// The loop's first model with a pressure: linearized at the inflated wall
/// (offset ū = its displacement, K_r from its tangent with the load
/// stiffness), and its Φᵀ M ū.
pub fn inflated_model<const R: usize>(
    rows: BasisRows<R>,
    refresher: &mut Refresher,
    inflated: &crate::scene::Inflated,
    params: &DynamicsParams,
) -> Result<(Box<LoopModel<R>>, SVector<f64, R>), crate::reduced::ReducedError> {
    let kr = refresher.project_tangent(&inflated.tangent);
    let mut model = rest_model::<R>(rows, &kr, params, inflated.u.len())?;
    model.offset = Arc::new(inflated.u.clone());
    let r = refresher.len();
    Ok((model, to_s::<R>(&refresher.project_mass(&inflated.u).as_slice()[..r])))
}

/// Runs the background loop until `io.stop` is set. Returns its statistics.
pub fn run<const R: usize>(mut bg: Background<R>, mut io: BackgroundIo<R>) -> BackgroundStats {
    let mut stats = BackgroundStats::default();
    let n = bg.refresher.phi().nrows() / 3;
    let mut state = TissueState::at_rest(n);
    if let Some(u) = bg.pressure.as_mut().and_then(|p| p.start.take()) {
        if u.len() == n {
            state.u = u;
        }
    }
    let mut sum = vec![Vec3::zeros(); n];
    let mut touched: Vec<u32> = Vec::new();
    let mut fbar = vec![Vec3::zeros(); n];
    let mut last_tick = io.live.ticks();
    let mut epoch = bg.last_sent.2;
    // A built model not sent yet, its Φᵀ M ū and its basis generation.
    let mut pending: Option<(Box<LoopModel<R>>, SVector<f64, R>, u64)> = None;
    // Basis refresh: generation of the basis in use, the basis of the last
    // model sent when it differs, the displacement the basis in use was
    // asked at, and whether a request is out.
    let mut generation = 0u64;
    let mut sent_phi: Option<DMatrix<f64>> = None;
    let mut u_at_basis = vec![Vec3::zeros(); n];
    let mut in_flight = false;
    let mut last_request_ns = clock::now_ns();
    let dt_min = bg.solver.params().dt;
    let t_start = clock::now_ns();
    let mut sim = 0.0;
    while !io.stop.load(Ordering::Relaxed) {
        if FaultSwitches::take(&io.faults.panic_background) {
            panic!("injected fault: the background thread panics");
        }
        let stall_ms = io.faults.take_stall_ms();
        if stall_ms > 0 {
            std::thread::sleep(std::time::Duration::from_millis(stall_ms));
            FaultSwitches::served(&io.faults.stalls_served);
        }
        let t0 = clock::now_ns();
        // Follow real time: the step covers the time the solve is behind
        // the wall clock, between dt_min and dt_max (implicit Euler is
        // stable for any). A slow step is made up by the next ones (each
        // covers more than its own duration) instead of being lost, so the
        // solve keeps up whenever its mean step takes less than dt_max.
        let behind = (t0 - t_start) as f64 * 1e-9 - sim;
        let dt = behind.clamp(dt_min, bg.dt_max.max(dt_min));
        bg.solver.set_dt(dt);
        // Average the loop's contact forces since the last step.
        while let Ok(msg) = io.contact.pop() {
            stats.contact_msgs += 1;
            for c in &msg.nodes {
                let i = c.node as usize;
                if i < n && c.force.iter().all(|v| v.is_finite()) {
                    if sum[i] == Vec3::zeros() {
                        touched.push(c.node);
                    }
                    sum[i] += c.force;
                }
            }
        }
        let now_tick = io.live.ticks();
        let ticks = now_tick.saturating_sub(last_tick).max(1) as f64;
        last_tick = now_tick;
        for f in fbar.iter_mut() {
            *f = Vec3::zeros();
        }
        let mut nodal = Vec::with_capacity(touched.len());
        for &i in &touched {
            let f = sum[i as usize] / ticks;
            fbar[i as usize] = f;
            nodal.push(NodalLoad {
                nodes: vec![i],
                force: f,
                profile: TimeProfile::Constant { from_t0: 0.0 },
            });
            sum[i as usize] = Vec3::zeros();
        }
        touched.clear();
        let fail_injected = FaultSwitches::take(&io.faults.fail_next_step);
        if fail_injected {
            nodal.push(NodalLoad {
                nodes: vec![0],
                force: Vec3::new(f64::NAN, 0.0, 0.0),
                profile: TimeProfile::Constant { from_t0: 0.0 },
            });
        }
        // The pressure moves into the step's loads and back (no copy).
        let loads = Loads {
            nodal,
            gravity: Vec3::zeros(),
            pressure: bg
                .pressure
                .as_mut()
                .map(|p| std::mem::replace(&mut p.load, LuminalPressure::empty())),
        };
        let rep = bg.solver.step(&mut state, bg.model.as_mut(), &loads, &bg.fixed);
        if let (Some(p), Some(load)) = (bg.pressure.as_mut(), loads.pressure) {
            p.load = load;
            if rep.ok() {
                p.t_s = state.t;
            }
        }
        if fail_injected && !rep.ok() {
            FaultSwitches::served(&io.faults.step_failures_served);
        }
        stats.steps += 1;
        if rep.ok() {
            sim += dt;
        }
        if !rep.ok() {
            stats.failed_steps += 1;
        }
        if rep.substeps > 1 {
            stats.split_steps += 1;
        }
        let t1 = clock::now_ns();
        stats.step_us.push((t1 - t0) as f64 * 1e-3);

        // A new basis from the basis thread: install it; the next model
        // carries the state over from the last sent model's basis.
        if let Some((_, rx)) = io.basis.as_mut() {
            if let Ok(answer) = rx.pop() {
                // A failed recomputation answers None: keep the basis in
                // use and ask again at the next occasion.
                in_flight = false;
                if let Some(nb) = answer {
                    let old = std::mem::replace(&mut bg.refresher, nb.refresher);
                    if sent_phi.is_none() {
                        sent_phi = Some(old.phi().clone());
                    }
                    bg.rows = nb.rows;
                    bg.compliance = nb.compliance;
                    generation += 1;
                    stats.basis_installed += 1;
                }
            }
        }
        // Ask for a new basis when the state has moved far enough.
        if rep.ok() && !in_flight && bg.basis_policy.every_s > 0.0 {
            let due = (t1 - last_request_ns) as f64 * 1e-9 >= bg.basis_policy.every_s;
            if due {
                let change = crate::math::max_distance(&state.u, &u_at_basis);
                if change >= bg.basis_policy.min_change_m {
                    if let Some((tx, _)) = io.basis.as_mut() {
                        // The step's tangent, or (a step that started in
                        // equilibrium assembled none) one assembled here.
                        let mut tangent = bg.solver.last_stiffness().clone();
                        if !bg.solver.has_stiffness() {
                            tangent.clear();
                            bg.model.add_stiffness(&state.u, &mut tangent);
                        }
                        let job = BasisJob { tangent };
                        if tx.push(job).is_ok() {
                            in_flight = true;
                            last_request_ns = t1;
                            u_at_basis.copy_from_slice(&state.u);
                            stats.basis_requests += 1;
                        }
                    }
                }
            }
        }

        // Re-linearize and send (keep-latest if the ring is full).
        epoch += 1;
        // A step that started in equilibrium (at rest, no load) assembled
        // no tangent: build the model from a fresh assembly then, never
        // from the solver's all-zero stiffness (a loop model with K_r = 0
        // drifts under any load it is given).
        let built = if rep.ok() && bg.solver.has_stiffness() {
            bg.build_model_from_step(&state.u, &fbar, epoch, sent_phi.as_ref())
        } else {
            bg.build_model(&state.u, &fbar, epoch, sent_phi.as_ref())
        };
        match built {
            Some((m, qbar)) => pending = Some((m, qbar, generation)),
            None => stats.refresh_failures += 1,
        }
        if let Some((m, qbar, gen)) = pending.take() {
            // Built against the current last-sent model (nothing is sent in
            // between), so its transfer and shift are right.
            let offset = m.offset.clone();
            let new_basis = sent_phi.is_some() && gen == generation;
            let rows = m.dynamics.rows().clone();
            match io.models.push(m) {
                Ok(()) => {
                    stats.models_sent += 1;
                    bg.last_sent = (offset.clone(), qbar, epoch);
                    if new_basis {
                        sent_phi = None;
                        stats.basis_swaps_sent += 1;
                    }
                    if let Some(tx) = io.offsets.as_mut() {
                        let _ = tx.push((epoch, offset, rows));
                    }
                }
                Err(rtrb::PushError::Full(m)) => {
                    stats.model_ring_full += 1;
                    pending = Some((m, qbar, gen));
                }
            }
        }
        stats.refresh_us.push((clock::now_ns() - t1) as f64 * 1e-3);
        while let Ok(old) = io.returned.pop() {
            drop(old);
            stats.models_freed += 1;
        }
        // Never run ahead of real time.
        let wall = (clock::now_ns() - t_start) as f64 * 1e-9;
        io.live.record_background(stats.steps, sim, wall, stats.models_sent);
        io.live.record_bases(stats.basis_installed);
        if sim > wall {
            clock::sleep_until(t_start + (sim * 1e9) as i64);
        }
    }
    stats.sim_time_s = sim;
    stats.wall_s = (clock::now_ns() - t_start) as f64 * 1e-9;
    stats.max_displacement_m = state.u.iter().map(|u| u.norm()).fold(0.0, f64::max);
    stats
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::material::Material;
    use crate::mesh::arch::ArchGrid;
    use crate::mesh::tube::{generate, TubeParams};
    use crate::model::nvtmm::Nvtmm;
    use crate::reduced::{BasisParams, BasisSpec, ModalBasis, Statics, Stiffness};
    use crate::solver::pressure::{PressureSchedule, PressureTangent};

    #[test]
    fn the_reduced_tangent_holds_the_pressure_load_stiffness() {
        let mesh = generate(
            &TubeParams {
                inner_radius: 0.010,
                outer_radius: 0.012,
                length: 0.04,
            },
            ArchGrid {
                axial: 5,
                circumferential: 12,
                layers: 2,
            },
        )
        .unwrap();
        let mat = Material {
            youngs_pa: 1e6,
            ..Material::aorta()
        };
        let model = Nvtmm::new(&mesh, &mat);
        let mass = mesh.lumped_mass(mat.density);
        let mut fixed: Vec<u32> = mesh.node_set("end_0").unwrap().to_vec();
        fixed.extend_from_slice(mesh.node_set("end_1").unwrap());
        let u = vec![Vec3::zeros(); mesh.num_nodes()];
        let basis = ModalBasis::compute(&BasisSpec {
            stiffness: Stiffness::Model {
                mesh: &mesh,
                model: &model,
                u: &u,
            },
            mass: &mass,
            fixed: &fixed,
            r: 6,
            statics: Statics::None,
            warm: None,
            params: BasisParams::default(),
        })
        .unwrap();
        let mut refresher = Refresher::new(&mesh, &basis, &mass);
        let pa = 12e3;
        let schedule = PressureSchedule {
            ramp_s: 1.0,
            ..PressureSchedule::steady(pa)
        };
        let load = LuminalPressure::on_set(&mesh, "inner_wall", schedule, PressureTangent::Symmetric).unwrap();
        let mut p = BackgroundPressure::new(load.clone());
        p.t_s = 10.0; // past the ramp: the full pressure
        let plain = reduced_tangent(&mut refresher, &model, None, &u);
        let with = reduced_tangent(&mut refresher, &model, Some(&p), &u);
        // What the pressure alone projects to.
        let mut kp = BlockTangent::zeros(&mesh);
        load.add_stiffness(pa, &u, &mut kp);
        let kp_r = refresher.project_tangent(&kp);
        assert!(kp_r.norm() > 1e-6 * plain.norm(), "{}", kp_r.norm());
        let diff = (&with - &plain - &kp_r).norm();
        assert!(diff <= 1e-9 * plain.norm(), "{diff:e} vs {:e}", plain.norm());
        // Before the ramp starts nothing is added.
        p.t_s = 0.0;
        let at_start = reduced_tangent(&mut refresher, &model, Some(&p), &u);
        assert!((&at_start - &plain).norm() <= 1e-12 * plain.norm());
    }
}
