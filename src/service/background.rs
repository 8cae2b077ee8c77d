//! The background thread: the full NVTMM implicit-Euler solve under the
//! contact forces the haptic loop reports, and after every step a new
//! linearization of the reduced model (K_r(ū), ū, Φᵀf̄) sent to the loop
//! through a ring. Models the loop hands back are freed here, off the RT
//! thread. This thread may allocate; it never blocks the loop (every ring
//! operation is a non-blocking push or pop).

use crate::haptics::contact::NodeContact;
use crate::haptics::servo::LoopModel;
use crate::mesh::Vec3;
use crate::model::ForceModel;
use crate::reduced::{BasisRows, DynamicsParams, ReducedDynamics, Refresher};
use crate::rt::clock;
use crate::rt::stats::Histogram;
use crate::solver::loads::{Loads, NodalLoad, TimeProfile};
use crate::solver::{ImplicitEuler, TissueState};
use nalgebra::{DMatrix, SMatrix, SVector};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
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
}

/// Statistics of the background thread.
#[derive(Debug, Clone, Default)]
pub struct BackgroundStats {
    /// Full steps done.
    pub steps: u64,
    /// Full steps that failed (state kept).
    pub failed_steps: u64,
    /// Wall time per full step (µs).
    pub step_us: Histogram,
    /// Wall time per linearization refresh (µs).
    pub refresh_us: Histogram,
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
}

/// Rings and shared flags of the background thread.
pub struct BackgroundIo<const R: usize> {
    /// Contact forces from the loop.
    pub contact: rtrb::Consumer<ContactMsg>,
    /// New models to the loop.
    pub models: rtrb::Producer<Box<LoopModel<R>>>,
    /// Old models back from the loop.
    pub returned: rtrb::Consumer<Box<LoopModel<R>>>,
    /// ū of each model sent, for the stream publisher (keep-latest: dropped
    /// when full).
    pub offsets: Option<rtrb::Producer<(u64, Arc<Vec<Vec3>>)>>,
    /// Set to stop.
    pub stop: Arc<AtomicBool>,
    /// The loop's tick counter.
    pub loop_ticks: Arc<AtomicU64>,
}

impl<const R: usize> Background<R> {
    /// Builds the model for displacement `u` under the contact force `fbar`
    /// (per node), with the transfer from the last model sent.
    pub fn build_model(&mut self, u: &[Vec3], fbar: &[Vec3], epoch: u64) -> Option<Box<LoopModel<R>>> {
        let kr = self.refresher.reduced_stiffness(self.model.as_ref(), u);
        self.model_from(kr, u, fbar, epoch)
    }

    /// As [`Background::build_model`] with the tangent the last full step
    /// assembled (at its start state, one background step behind `u`),
    /// which saves the assembly.
    pub fn build_model_from_step(&mut self, u: &[Vec3], fbar: &[Vec3], epoch: u64) -> Option<Box<LoopModel<R>>> {
        let kr = self.refresher.project_tangent(self.solver.last_stiffness());
        self.model_from(kr, u, fbar, epoch)
    }

    fn model_from(&mut self, kr: DMatrix<f64>, u: &[Vec3], fbar: &[Vec3], epoch: u64) -> Option<Box<LoopModel<R>>> {
        let r = self.refresher.len();
        let dynamics = ReducedDynamics::with_rows(self.rows.clone(), r, &kr, &self.dynamics).ok()?;
        let qbar = to_s::<R>(&self.refresher.project_mass(u).as_slice()[..r]);
        let fb = to_s::<R>(&self.refresher.project_force(fbar).as_slice()[..r]);
        let offset = Arc::new(u.to_vec());
        Some(Box::new(LoopModel {
            epoch,
            dynamics,
            offset,
            f_bar: fb,
            transfer: SMatrix::identity(),
            // Same basis: δq₁ = δq₀ + Φᵀ M (ū₀ − ū₁).
            shift: self.last_sent.1 - qbar,
            created_s: clock::now_s(),
        }))
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
    }))
}

/// Runs the background loop until `io.stop` is set. Returns its statistics.
pub fn run<const R: usize>(mut bg: Background<R>, mut io: BackgroundIo<R>) -> BackgroundStats {
    let mut stats = BackgroundStats::default();
    let n = bg.refresher.phi().nrows() / 3;
    let mut state = TissueState::at_rest(n);
    let mut sum = vec![Vec3::zeros(); n];
    let mut touched: Vec<u32> = Vec::new();
    let mut fbar = vec![Vec3::zeros(); n];
    let mut last_tick = io.loop_ticks.load(Ordering::Relaxed);
    let mut epoch = bg.last_sent.2;
    let mut pending: Option<Box<LoopModel<R>>> = None;
    let dt = bg.solver.params().dt;
    let t_start = clock::now_ns();
    while !io.stop.load(Ordering::Relaxed) {
        let t0 = clock::now_ns();
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
        let now_tick = io.loop_ticks.load(Ordering::Relaxed);
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
        let loads = Loads {
            nodal,
            gravity: Vec3::zeros(),
        };
        let rep = bg.solver.step(&mut state, bg.model.as_mut(), &loads, &bg.fixed);
        stats.steps += 1;
        if !rep.ok() {
            stats.failed_steps += 1;
        }
        let t1 = clock::now_ns();
        stats.step_us.record((t1 - t0) as f64 * 1e-3);

        // Re-linearize and send (keep-latest if the ring is full).
        epoch += 1;
        let built = if rep.ok() {
            bg.build_model_from_step(&state.u, &fbar, epoch)
        } else {
            bg.build_model(&state.u, &fbar, epoch)
        };
        match built {
            Some(m) => pending = Some(m),
            None => stats.refresh_failures += 1,
        }
        if let Some(m) = pending.take() {
            // Built against the current last-sent model (nothing is sent in
            // between), so its shift is right: recover its Φᵀ M ū.
            let qbar = bg.last_sent.1 - m.shift;
            let offset = m.offset.clone();
            match io.models.push(m) {
                Ok(()) => {
                    stats.models_sent += 1;
                    bg.last_sent = (offset.clone(), qbar, epoch);
                    if let Some(tx) = io.offsets.as_mut() {
                        let _ = tx.push((epoch, offset));
                    }
                }
                Err(rtrb::PushError::Full(m)) => {
                    stats.model_ring_full += 1;
                    pending = Some(m);
                }
            }
        }
        stats.refresh_us.record((clock::now_ns() - t1) as f64 * 1e-3);
        while let Ok(old) = io.returned.pop() {
            drop(old);
            stats.models_freed += 1;
        }
        // Never run ahead of real time.
        let wall = (clock::now_ns() - t_start) as f64 * 1e-9;
        let sim = stats.steps as f64 * dt;
        if sim > wall {
            clock::sleep_until(t_start + (sim * 1e9) as i64);
        }
    }
    stats.sim_time_s = stats.steps as f64 * dt;
    stats.wall_s = (clock::now_ns() - t_start) as f64 * 1e-9;
    stats.max_displacement_m = state.u.iter().map(|u| u.norm()).fold(0.0, f64::max);
    stats
}
