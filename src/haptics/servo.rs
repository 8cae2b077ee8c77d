//! The haptic loop's computation for one tick, without threads or rings so
//! it can be tested directly: read the tool pose, find the contact with the
//! deformed surface, step the reduced model with the contact implicit,
//! produce the tool force, and guard it with the watchdog (ramp to zero on a
//! silent device, a non-finite value or an overrun streak; reset the reduced
//! state on a non-finite value). The passivity filter sits between the
//! contact force and the watchdog gain (see `service`).
//!
//! Everything here is sized at construction: [`Servo::tick`] and
//! [`Servo::swap`] never allocate, free, lock or block.

use super::contact::{self, Candidates, ContactOutput, ContactParams, SurfaceIndex};
use super::device::DeviceSample;
use super::phases::{Phase, TickSplit};
use crate::math::Vec3;
use crate::reduced::compliance::LocalCompliance;
use crate::reduced::{ReducedDynamics, ReducedPart};
use crate::rt::clock;
use nalgebra::{SMatrix, SVector};
use std::sync::Arc;

/// A reduced model as the loop runs it: linear reduced dynamics about the
/// background solve's displacement ū, in coordinates δq (u ≈ ū + Φ δq).
#[derive(Debug, Clone)]
pub struct LoopModel<const R: usize> {
    /// Sequence number of the refresh (0: the model linearized at rest).
    pub epoch: u64,
    /// The reduced dynamics (K_r(ū), shared Φ rows, state δq).
    pub dynamics: ReducedDynamics<R>,
    /// ū per mesh node (m).
    pub offset: Arc<Vec<Vec3>>,
    /// Φᵀ f̄_c: the reduced contact force the full solve was given.
    pub f_bar: SVector<f64, R>,
    /// State transfer from the previous epoch: δq ← T δq + s.
    pub transfer: SMatrix<f64, R, R>,
    /// See `transfer`.
    pub shift: SVector<f64, R>,
    /// Creation time (s on the service clock).
    pub created_s: f64,
    /// The residual compliance of the model's basis (contact anywhere,
    /// `crate::reduced::compliance`); None: the reduced model alone.
    pub compliance: Option<Arc<LocalCompliance>>,
    /// How far the swap moves any node (m), when this model shares the
    /// previous epoch's model's basis rows (its transfer is then I): the
    /// largest ‖ū_new,i − ū_old,i + Φᵢ s‖ over the mesh, s the `shift`,
    /// i.e. how far a node's position at the carried state q + s lies from
    /// its position at q in the previous model. That is the part of ū's
    /// change the basis does not follow, far less than the change itself
    /// (the shift follows the rest). None: a new basis, or not known.
    /// Measured on the background thread, so that the swap carries the
    /// contact's kept triangles over instead of searching the surface on
    /// the loop ([`Servo::swap`]).
    pub surface_moved_m: Option<f64>,
}

/// Watchdog and contact settings of the loop.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ServoParams {
    /// Tick period (s).
    pub dt: f64,
    /// Contact.
    pub contact: ContactParams,
    /// Scene position of the device origin (m).
    pub device_origin: Vec3,
    /// Device silence before the force ramps down (s).
    pub device_timeout_s: f64,
    /// Model age that raises the stale-model flag (s); infinite to disable.
    pub model_timeout_s: f64,
    /// Model age at which the force ramps down (s; ≥ `model_timeout_s`):
    /// the background thread has stopped refreshing (stalled or lost).
    /// Infinite to disable.
    pub model_max_age_s: f64,
    /// Fastest plausible stylus motion (m/s): a sample that moved farther
    /// from the last accepted one than this speed allows (plus 1 mm) is a
    /// wild pose, dropped, and a fault.
    pub max_speed_m_s: f64,
    /// Farthest plausible stylus position from the device origin (m): a
    /// sample beyond it is a wild pose.
    pub max_reach_m: f64,
    /// Consecutive deadline misses that ramp the force down.
    pub overrun_streak: u32,
    /// Full-to-zero ramp time on a fault (s).
    pub ramp_down_s: f64,
    /// Zero-to-full ramp time at start and after a fault (s).
    pub ramp_in_s: f64,
    /// Cross-fade time of a model swap (s): both models run and the output
    /// force blends from the old to the new one over this time (0: switch).
    pub swap_blend_s: f64,
    /// The device side's command timeout (s, `watchdog.command_timeout_ms`;
    /// [`crate::haptics::device::DEFAULT_COMMAND_TIMEOUT_S`]): over a gap
    /// between samples longer than this the device may have dropped the
    /// held force, so the energy observer gives no credit for it.
    pub command_timeout_s: f64,
}

/// A model swap's cross-fade ends at the first tick where the old and the
/// new model's forces on the hand differ by at most this (N): the output
/// then steps by less than 1 mN, well under what a hand feels through a
/// stylus (tens of millinewtons), and the old model's contact and step stop
/// costing the loop a tick sooner. Out of contact that is the swap's first
/// tick.
pub const FADE_DONE_N: f64 = 1e-3;

/// Status bits of a tick (also the stream's flags).
pub mod flags {
    /// The watchdog is holding the force down (a fault is active).
    pub const WATCHDOG: u32 = 1 << 0;
    /// The tool touches the surface.
    pub const CONTACT: u32 = 1 << 1;
    /// The passivity filter changed the force.
    pub const LIMITED: u32 = 1 << 2;
    /// The reduced model is older than the model timeout.
    pub const MODEL_STALE: u32 = 1 << 3;
    /// No fresh device sample within the device timeout.
    pub const DEVICE_SILENT: u32 = 1 << 4;
    /// A non-finite value was caught this tick (state reset).
    pub const NONFINITE: u32 = 1 << 5;
    /// Too many consecutive deadline misses.
    pub const OVERRUN: u32 = 1 << 6;
    /// The contact list overflowed and was truncated.
    pub const TRUNCATED: u32 = 1 << 7;
    /// The loop runs under SCHED_FIFO.
    pub const RT_GRANTED: u32 = 1 << 8;
    /// The device sent an implausible pose (beyond the reach, or a jump
    /// faster than the speed limit); it was dropped.
    pub const BAD_POSE: u32 = 1 << 9;
    /// The model is older than the maximum age: the force ramps down.
    pub const MODEL_EXPIRED: u32 = 1 << 10;
}

/// Counters of the loop (read at the end).
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct ServoCounters {
    /// Ticks run.
    pub ticks: u64,
    /// Models swapped in.
    pub model_swaps: u64,
    /// Ticks with a non-finite value (each resets the reduced state).
    pub nonfinite: u64,
    /// Ticks with the device silent.
    pub device_silent_ticks: u64,
    /// Ticks with a stale model.
    pub model_stale_ticks: u64,
    /// Ticks with a model past its maximum age (force ramped down).
    pub model_expired_ticks: u64,
    /// Samples dropped as wild poses.
    pub bad_pose_samples: u64,
    /// Ticks with the watchdog gain below 1 because of a fault.
    pub watchdog_ticks: u64,
    /// Ticks in contact.
    pub contact_ticks: u64,
    /// Ticks whose contact list was truncated.
    pub truncated_ticks: u64,
    /// Ticks where the contact stiffness was dropped (not PSD).
    pub contact_stiffness_dropped: u64,
    /// Most touched nodes in one tick.
    pub contact_nodes_max: u64,
    /// Most contact spheres (tool plus instrument points) touching at once.
    pub contact_patches_max: u64,
    /// Ticks where some touched nodes went without the residual compliance
    /// (more than `contact::MAX_COMPLIANT_PATCHES` patches at once).
    pub uncorrected_ticks: u64,
    /// Ticks the residual compliance was applied (contact anywhere).
    pub compliance_ticks: u64,
    /// Of `compliance_ticks`, the ticks that read node-pair blocks of the
    /// residual compliance from its table (a patch whose touched nodes
    /// changed); on the others every patch reused the blocks it kept.
    pub compliance_lookup_ticks: u64,
    /// Swaps that carried the contact's kept triangles over to the new
    /// model (same basis, the swap moved the surface less than the slack,
    /// [`LoopModel::surface_moved_m`]): the swap tick searches only if the
    /// swap's change of state uses up the rest of the slack.
    pub swaps_carried: u64,
    /// Swaps whose state correction (the contact match and the static step)
    /// was computed on the tick before ([`Servo::prepare`]).
    pub swaps_prepared: u64,
    /// Spheres of the old model's contact in a cross-fade that took over
    /// the triangles the new model's contact had just searched for, instead
    /// of searching the same surface again on the same tick
    /// ([`contact::ContactOutput::adopt_searches`]).
    pub fade_searches_shared: u64,
    /// Cross-fades ended before their time because the two models' forces
    /// on the hand agreed within [`FADE_DONE_N`].
    pub fades_ended_early: u64,
}

/// Longest delay from a patch's first touch to its first corrected tick
/// that [`ContactEvents`] bins to the tick; longer ones share the last bin.
pub const CORRECTION_DELAY_BINS: usize = 1024;

/// New contact patches and how long each waited for the residual
/// compliance correction (contact anywhere), kept by the loop in fixed
/// memory. A patch is a tool sphere that starts touching; it is corrected
/// on the first tick the correction applies to every patch
/// ([`ContactOutput::corrected`]).
#[derive(Debug, Clone)]
pub struct ContactEvents {
    /// Per sphere, the tick its current touch began (0: not touching).
    touch_tick: [u64; contact::MAX_SPHERES],
    /// Per sphere, touching and not corrected yet.
    waiting: [bool; contact::MAX_SPHERES],
    /// Delays in ticks, one bin per tick.
    delays: Box<[u32; CORRECTION_DELAY_BINS]>,
    /// Patches that began touching.
    pub new_patches: u64,
    /// Patches whose touch ended before any corrected tick.
    pub never_corrected: u64,
}

impl Default for ContactEvents {
    fn default() -> Self {
        ContactEvents {
            touch_tick: [0; contact::MAX_SPHERES],
            waiting: [false; contact::MAX_SPHERES],
            delays: Box::new([0; CORRECTION_DELAY_BINS]),
            new_patches: 0,
            never_corrected: 0,
        }
    }
}

impl ContactEvents {
    /// Records tick `tick` (counted from 1): which spheres touch, and
    /// whether the correction applied. Allocates nothing.
    pub fn record(&mut self, tick: u64, sphere_forces: &[Vec3], corrected: bool) {
        for s in 0..contact::MAX_SPHERES {
            let touching = sphere_forces.get(s).is_some_and(|f| f.norm_squared() > 0.0);
            if touching {
                if self.touch_tick[s] == 0 {
                    self.new_patches += 1;
                    self.touch_tick[s] = tick.max(1);
                    self.waiting[s] = true;
                }
                if self.waiting[s] && corrected {
                    let ticks = tick.saturating_sub(self.touch_tick[s]) as usize;
                    self.delays[ticks.min(CORRECTION_DELAY_BINS - 1)] += 1;
                    self.waiting[s] = false;
                }
            } else {
                if self.waiting[s] {
                    self.never_corrected += 1;
                }
                self.touch_tick[s] = 0;
                self.waiting[s] = false;
            }
        }
    }

    /// Patches corrected so far.
    pub fn corrected(&self) -> u64 {
        self.delays.iter().map(|&n| n as u64).sum()
    }

    /// The delay (ticks) below which a fraction `q` of the corrected
    /// patches were corrected (nearest rank; 0 with none).
    pub fn delay_quantile(&self, q: f64) -> usize {
        let n = self.corrected();
        if n == 0 {
            return 0;
        }
        let rank = ((n as f64 - 1.0) * q.clamp(0.0, 1.0)).round() as u64;
        let mut seen = 0u64;
        for (ticks, &count) in self.delays.iter().enumerate() {
            seen += count as u64;
            if seen > rank {
                return ticks;
            }
        }
        CORRECTION_DELAY_BINS - 1
    }

    /// The longest delay (ticks; the last bin means at least that).
    pub fn delay_max(&self) -> usize {
        self.delays.iter().rposition(|&n| n > 0).unwrap_or(0)
    }
}

/// What one tick produced.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TickOutput {
    /// The desired (unfiltered) force on the tool (N), scene frame.
    pub desired: Vec3,
    /// Tool centre (m, scene frame).
    pub tool: Vec3,
    /// Status bits ([`flags`]).
    pub flags: u32,
    /// Deepest penetration (m).
    pub depth: f64,
}

/// Contact of the tool against `m`'s deformed surface.
fn eval_contact<const R: usize>(
    m: &LoopModel<R>,
    index: &SurfaceIndex,
    params: &ContactParams,
    centers: &[Vec3],
    scratch: &mut Candidates,
    out: &mut ContactOutput<R>,
) {
    let dynamics = &m.dynamics;
    let offset = &m.offset;
    contact::evaluate_spheres(
        index,
        params,
        centers,
        |i| {
            let base = index.rest(i) + offset.get(i as usize).copied().unwrap_or_else(Vec3::zeros);
            base + dynamics.displacement_at(i).unwrap_or_else(Vec3::zeros)
        },
        |i| dynamics.rows_at(i),
        m.compliance.as_deref(),
        Some(contact::Motion {
            q: dynamics.q(),
            row_bound: dynamics.row_bound(),
            offset: Some(offset.as_slice()),
        }),
        scratch,
        out,
    );
}

/// Steps `m` under its contact; returns the tool force and whether all was
/// finite.
/// Σ Φᵢᵀ fᵢ of point loads (mesh node, force) on `d`'s rows; a node
/// outside the basis is skipped. Allocates nothing.
fn project_point_loads<const R: usize>(d: &ReducedDynamics<R>, loads: &[(u32, Vec3)]) -> SVector<f64, R> {
    let mut f = SVector::<f64, R>::zeros();
    for (i, fi) in loads {
        if let Some(rows) = d.rows_at(*i) {
            f += rows.tr_mul(fi);
        }
    }
    f
}

/// G += w ΦᵢᵀΦᵢ for one node's three rows, in one pass over G: each
/// entry takes its three products at once, on contiguous columns, which
/// vectorize (a 3 × r `tr_mul` takes a 3-long dot per entry, and three
/// rank-one updates load and store G three times).
fn add_gram<const R: usize>(g: &mut SMatrix<f64, R, R>, w: f64, rows: &SMatrix<f64, 3, R>) {
    let r0: SVector<f64, R> = rows.row(0).transpose();
    let r1: SVector<f64, R> = rows.row(1).transpose();
    let r2: SVector<f64, R> = rows.row(2).transpose();
    let (r0, r1, r2) = (r0.as_slice(), r1.as_slice(), r2.as_slice());
    for (j, col) in g.as_mut_slice().chunks_exact_mut(R).enumerate() {
        let (a0, a1, a2) = (w * r0[j], w * r1[j], w * r2[j]);
        for (((gij, &x0), &x1), &x2) in col.iter_mut().zip(r0).zip(r1).zip(r2) {
            *gij += x0 * a0 + x1 * a1 + x2 * a2;
        }
    }
}

fn step_model<const R: usize>(
    m: &mut LoopModel<R>,
    c: &ContactOutput<R>,
    loads: &[(u32, Vec3)],
    part: Option<&mut ReducedPart<R>>,
    hand_sphere: bool,
    counters: &mut ServoCounters,
) -> (Vec3, bool) {
    // Point loads of the instruments (the guidewire inside), summed.
    let f_loads = project_point_loads(&m.dynamics, loads);
    let f = c.reduced_force - m.f_bar + f_loads;
    // The hand feels the tool sphere only (extra spheres are other contact
    // points of the instruments); without the probe, no sphere is felt.
    let desired = if hand_sphere {
        c.sphere_forces.first().copied().unwrap_or(c.tool_force)
    } else {
        Vec3::zeros()
    };
    let finite = desired.iter().all(|v| v.is_finite()) && f.iter().all(|v| v.is_finite());
    if finite {
        let stiff = match part {
            Some(part) => m
                .dynamics
                .step_with_contact_and(&f, &c.reduced_stiffness, part, &f_loads),
            None => m.dynamics.step_with_contact(&f, &c.reduced_stiffness),
        };
        if !stiff {
            counters.contact_stiffness_dropped += 1;
        }
    }
    let state_ok = m.dynamics.q().iter().all(|v| v.is_finite()) && m.dynamics.qd().iter().all(|v| v.is_finite());
    (if finite { desired } else { Vec3::zeros() }, finite && state_ok)
}

/// The loop state.
pub struct Servo<const R: usize> {
    model: Box<LoopModel<R>>,
    index: Arc<SurfaceIndex>,
    params: ServoParams,
    scratch: Candidates,
    // Boxed, both: a swap exchanges the two outputs (tens of KB each
    // inline) by pointer.
    contact: Box<ContactOutput<R>>,
    gain: f64,
    last_seq: u64,
    last_fresh_s: f64,
    last_pose: Option<(Vec3, f64)>,
    counters: ServoCounters,
    tool: Vec3,
    now_s: f64,
    fault_until_s: f64,
    fading: Option<Box<LoopModel<R>>>,
    /// While fading on the same basis: the swap's bound on how far the
    /// models' surfaces differ (m) and the new model's state shift (the
    /// old model's contact takes over the new one's searches with it).
    fade_carry: Option<(f64, SVector<f64, R>)>,
    fade_scratch: Candidates,
    fade_contact: Box<ContactOutput<R>>,
    blend: f64,
    retired: Option<Box<LoopModel<R>>>,
    /// The next swap's state correction, computed on the tick before it
    /// ([`Servo::prepare`]).
    prepared: Option<PreparedSwap<R>>,
    extra: heapless::Vec<Vec3, { contact::MAX_SPHERES - 1 }>,
    centers: heapless::Vec<Vec3, { contact::MAX_SPHERES }>,
    events: ContactEvents,
    point_loads: heapless::Vec<(u32, Vec3), MAX_POINT_LOADS>,
    /// The share of the current model's state the point loads caused.
    loads_part: ReducedPart<R>,
    /// This tick's time in contact, the step and the cross-fade.
    split: TickSplit,
    /// Whether the tool sphere at the hand takes part in the contact (the
    /// sphere probe is an instrument).
    hand_sphere: bool,
}

/// A swap's state correction prepared a tick ahead: the contact match and
/// the static step to equilibrium under the contact, as a change of the
/// transferred state (q ← T q + shift + `correction`).
#[derive(Debug, Clone, Copy)]
struct PreparedSwap<const R: usize> {
    /// The model it was computed for (its address: a boxed model does not
    /// move between the ring, the loop and the swap).
    model: usize,
    /// The servo's tick count when it was computed.
    tick: u64,
    correction: SVector<f64, R>,
}

/// Ticks a prepared swap correction stays usable: the state it was
/// computed from moves on by one tick's dynamics before the swap.
const PREPARED_SWAP_TICKS: u64 = 2;

/// One static Newton step of `new`'s reduced model from `q` toward
/// equilibrium under the contact's reduced force `f_c` and stiffness `k_c`
/// and the point loads (q unchanged if the step is not finite).
fn static_step<const R: usize>(
    new: &LoopModel<R>,
    mut q: SVector<f64, R>,
    f_c: &SVector<f64, R>,
    k_c: &SMatrix<f64, R, R>,
    point_loads: &[(u32, Vec3)],
) -> SVector<f64, R> {
    let k = new.dynamics.stiffness() + k_c;
    let r = f_c - new.f_bar - new.dynamics.stiffness() * q + project_point_loads(&new.dynamics, point_loads);
    if let Some(step) = k.cholesky().map(|ch| ch.solve(&r)) {
        if step.iter().all(|v| v.is_finite()) {
            q += step;
        }
    }
    q
}

/// Most point loads the servo keeps ([`Servo::set_point_loads`],
/// [`Servo::add_point_loads`]), over all instruments.
pub const MAX_POINT_LOADS: usize = 128;

/// How long a fault keeps the force down after its last tick, beyond the
/// ramp-down time (s): a single bad sample still takes the force to zero
/// before it ramps back in.
pub const FAULT_HOLD_S: f64 = 0.1;

impl<const R: usize> Servo<R> {
    /// A loop on `model` with the surface `index`. Allocates here only.
    pub fn new(model: Box<LoopModel<R>>, index: Arc<SurfaceIndex>, params: ServoParams, now_s: f64) -> Servo<R> {
        let contact = Box::new(ContactOutput::for_index(&index));
        let fade_contact = Box::new(ContactOutput::for_index(&index));
        Servo {
            model,
            index,
            params,
            scratch: Candidates::new(),
            contact,
            gain: 0.0,
            last_seq: 0,
            last_fresh_s: now_s,
            last_pose: None,
            counters: ServoCounters::default(),
            tool: Vec3::zeros(),
            now_s,
            fault_until_s: f64::NEG_INFINITY,
            fading: None,
            fade_carry: None,
            fade_scratch: Candidates::new(),
            fade_contact,
            blend: 1.0,
            retired: None,
            prepared: None,
            extra: heapless::Vec::new(),
            centers: heapless::Vec::new(),
            events: ContactEvents::default(),
            point_loads: heapless::Vec::new(),
            loads_part: ReducedPart::default(),
            split: TickSplit::default(),
            hand_sphere: true,
        }
    }

    /// Swaps in a new model, carrying the state over by its transfer
    /// (δq ← T δq + s, δq̇ ← T δq̇: the M-orthogonal projection of the
    /// displacement), then corrects δq so that the touched nodes keep their
    /// displacement as well as the basis can (least squares weighted by each
    /// node's load), so the contact force does not jump where ū has a part
    /// outside the basis. Returns the old model (to be sent
    /// back for freeing off this thread). A transferred state that is not
    /// finite resets the reduced state. Allocates nothing.
    ///
    /// With a cross-fade time the old model keeps running and the output
    /// blends to the new one; it is then handed out by
    /// [`Servo::take_retired`]. The returned model is the one that was
    /// still fading from a previous swap (None if there was none), or,
    /// without a cross-fade, the model just replaced.
    pub fn swap(&mut self, new: Box<LoopModel<R>>) -> Option<Box<LoopModel<R>>> {
        let old = self.swap_in(new);
        if self.params.swap_blend_s > 0.0 {
            let previous = self.fading.replace(old);
            self.blend = 0.0;
            previous
        } else {
            Some(old)
        }
    }

    /// A model whose cross-fade has finished, to be sent back for freeing.
    pub fn take_retired(&mut self) -> Option<Box<LoopModel<R>>> {
        self.retired.take()
    }

    /// Gives back a model [`Servo::take_retired`] handed out that could not
    /// be sent yet (it is handed out again next time).
    pub fn keep_retired(&mut self, m: Box<LoopModel<R>>) {
        self.retired = Some(m);
    }

    /// Whether a cross-fade is running.
    pub fn is_blending(&self) -> bool {
        self.fading.is_some()
    }

    fn swap_in(&mut self, mut new: Box<LoopModel<R>>) -> Box<LoopModel<R>> {
        // In the same basis the reduced coordinates mean the same motion in
        // both models (T = I), and every node's position differs between
        // them by ū's change, measured on the background thread: the
        // contact's kept triangles stay valid with that much more motion
        // allowed, so the swap tick searches nothing.
        let same_basis = Arc::ptr_eq(new.dynamics.rows(), self.model.dynamics.rows());
        let carry = new.surface_moved_m.filter(|_| same_basis);
        let q = new.transfer * self.model.dynamics.q() + new.shift;
        let qd = new.transfer * self.model.dynamics.qd();
        let mut evaluated_new = false;
        if q.iter().chain(qd.iter()).all(|v| v.is_finite()) {
            let address = std::ptr::addr_of!(*new) as usize;
            let ticks = self.counters.ticks;
            let prepared = self
                .prepared
                .take()
                .filter(|p| same_basis && p.model == address && ticks.saturating_sub(p.tick) <= PREPARED_SWAP_TICKS);
            let mut q = match prepared {
                // Matched and stepped to equilibrium on the tick before.
                Some(p) => {
                    self.counters.swaps_prepared += 1;
                    q + p.correction
                }
                None => q + self.contact_match(&new, &q),
            };
            if prepared.is_none() && self.params.swap_blend_s > 0.0 && !self.contact.nodes.is_empty() {
                // The cross-fade hides a step: start the new model at its
                // equilibrium under the contact (one static Newton step),
                // so it does not ring after the fade.
                let (f_c, k_c) = if same_basis {
                    // The last tick's contact is in the new model's
                    // coordinates, and the match has put the touched nodes
                    // where it found them: its force and stiffness are the
                    // new model's at the matched state, up to what of ū's
                    // change the basis cannot follow at those nodes. The
                    // tick that follows evaluates the contact on the new
                    // model; the swap need not do it twice.
                    (self.contact.reduced_force, self.contact.reduced_stiffness)
                } else {
                    // A new basis: the old contact's reduced force is in
                    // the old coordinates, so evaluate it on the new model
                    // (on a search: the triangles were found on another
                    // basis's positions).
                    new.dynamics.set_state(&q, &qd);
                    self.fade_contact.forget();
                    eval_contact(
                        &new,
                        &self.index,
                        &self.params.contact,
                        &self.centers,
                        &mut self.fade_scratch,
                        &mut self.fade_contact,
                    );
                    evaluated_new = true;
                    (self.fade_contact.reduced_force, self.fade_contact.reduced_stiffness)
                };
                q = static_step(&new, q, &f_c, &k_c, &self.point_loads);
            }
            new.dynamics.set_state(&q, &qd);
            self.loads_part = self.loads_part.transferred(&new.transfer);
        } else {
            new.dynamics.reset();
            self.loads_part = ReducedPart::default();
            self.counters.nonfinite += 1;
        }
        self.counters.model_swaps += 1;
        // Each contact output keeps the triangles it found on one model's
        // positions (`contact::Motion`), so each follows its model: the
        // tick's, kept on the old model, runs on with it in the cross-fade,
        // and the other becomes the tick's on the new model, with the
        // tick's triangles carried over in the same basis (or, after an
        // evaluation on a new basis, the ones it found there). Only an
        // output without triangles found on its model's positions searches
        // again (a full search costs several times a tick).
        std::mem::swap(&mut self.contact, &mut self.fade_contact);
        self.fade_carry = match (evaluated_new, carry) {
            (false, Some(d)) => Some((d, new.shift)),
            _ => None,
        };
        let carried = match (evaluated_new, carry) {
            (true, _) => 0,
            (false, Some(d)) => self.contact.carry_from(&self.fade_contact, d, &new.shift),
            (false, None) => {
                self.contact.forget();
                0
            }
        };
        if carried > 0 {
            self.counters.swaps_carried += 1;
        }
        if self.params.swap_blend_s <= 0.0 {
            self.fade_contact.forget();
        }
        std::mem::replace(&mut self.model, new)
    }

    /// Reads the memory of `new`, a model that the background thread built
    /// on the other core and that is to be swapped in on a later tick: its
    /// matrices, its state transfer and its offset ū at the nodes of the
    /// contact's kept triangles (the nodes the swap's match and the first
    /// contact evaluation on it read). Otherwise the swap tick waits for
    /// each of those cache lines in turn as its computation reaches them;
    /// here the reads are independent and overlap. Returns a sum of what
    /// it read (to keep the reads). Allocates nothing.
    pub fn warm(&self, new: &LoopModel<R>) -> f64 {
        let lines = |m: &[f64]| m.iter().step_by(8).sum::<f64>();
        let mut sum = new.dynamics.touch()
            + lines(new.transfer.as_slice())
            + lines(new.shift.as_slice())
            + lines(new.f_bar.as_slice());
        let offset = new.offset.as_slice();
        let mut at = |i: u32| {
            if let Some(u) = offset.get(i as usize) {
                sum += u.x;
            }
        };
        self.contact.for_each_kept_node(&self.index, &mut at);
        for c in self.contact.nodes.iter() {
            at(c.node);
        }
        sum
    }

    /// [`Servo::warm`], and on the same basis also the swap's state
    /// correction (the contact match and the static step to equilibrium
    /// under the contact), so that the swap tick, which often also searches
    /// the surface, only adds it: the swap's cost moves to the tick before,
    /// one tick of the old model's motion earlier. A swap more than
    /// two ticks later, or of another model, computes
    /// it afresh. Returns what [`Servo::warm`] returns. Allocates nothing.
    pub fn prepare(&mut self, new: &LoopModel<R>) -> f64 {
        let sum = self.warm(new);
        self.prepared = None;
        if !Arc::ptr_eq(new.dynamics.rows(), self.model.dynamics.rows()) {
            // A new basis: the swap evaluates the contact on the new model.
            return sum;
        }
        let q0 = new.transfer * self.model.dynamics.q() + new.shift;
        if !q0.iter().all(|v| v.is_finite()) {
            return sum;
        }
        let mut q = q0 + self.contact_match(new, &q0);
        if self.params.swap_blend_s > 0.0 && !self.contact.nodes.is_empty() {
            let (f_c, k_c) = (self.contact.reduced_force, self.contact.reduced_stiffness);
            q = static_step(new, q, &f_c, &k_c, &self.point_loads);
        }
        let correction = q - q0;
        if correction.iter().all(|v| v.is_finite()) {
            self.prepared = Some(PreparedSwap {
                model: std::ptr::addr_of!(*new) as usize,
                tick: self.counters.ticks,
                correction,
            });
        }
        sum
    }

    /// The Δ with Φᵢ(q + Δ) + ū_new,i closest to u_old,i over the touched
    /// nodes, weighted by their load (slightly regularized, so modes the
    /// touched nodes do not see stay put).
    fn contact_match(&self, new: &LoopModel<R>, q: &SVector<f64, R>) -> SVector<f64, R> {
        // Least squares over every touched node, weighted by its load:
        // min Σ w_a |Φ_a (q + Δ) + ū_new,a − u_old,a|² + ε |Δ|².
        let fmax = self.contact.nodes.iter().map(|c| c.force.norm()).fold(0.0, f64::max);
        if !(fmax > 0.0 && fmax.is_finite()) {
            return SVector::zeros();
        }
        let mut g = SMatrix::<f64, R, R>::zeros();
        let mut b = SVector::<f64, R>::zeros();
        for c in self.contact.nodes.iter() {
            let i = c.node as usize;
            let (Some(rows_new), Some(rows_old)) = (new.dynamics.rows_at(c.node), self.model.dynamics.rows_at(c.node))
            else {
                continue;
            };
            let w = c.force.norm() / fmax;
            let old =
                self.model.offset.get(i).copied().unwrap_or_else(Vec3::zeros) + rows_old * self.model.dynamics.q();
            let now = new.offset.get(i).copied().unwrap_or_else(Vec3::zeros) + rows_new * q;
            add_gram(&mut g, w, rows_new);
            b += rows_new.tr_mul(&(old - now)) * w;
        }
        let scale = g.trace() / R as f64;
        if !(scale > 0.0 && scale.is_finite()) {
            return SVector::zeros();
        }
        for k in 0..R {
            g[(k, k)] += 1e-8 * scale;
        }
        match g.cholesky() {
            Some(ch) => {
                let dq = ch.solve(&b);
                if dq.iter().all(|v| v.is_finite()) {
                    dq
                } else {
                    SVector::zeros()
                }
            }
            None => SVector::zeros(),
        }
    }

    /// More contact spheres besides the tool (scene frame, the tool's
    /// radius; at most [`contact::MAX_SPHERES`] − 1, the rest ignored): the
    /// other points where an instrument touches the wall. They load the
    /// tissue and couple with the tool's patch; their reactions are in
    /// `contact().sphere_forces[1..]`. Allocates nothing.
    pub fn set_extra_spheres(&mut self, centers: &[Vec3]) {
        self.extra.clear();
        for c in centers.iter().take(contact::MAX_SPHERES - 1) {
            let _ = self.extra.push(*c);
        }
    }

    /// Point loads on mesh nodes (N, on the tissue) from another
    /// instrument, e.g. the guidewire's contacts on the inner wall: they
    /// load the reduced model (Φᵢᵀ fᵢ) from the next tick on, until replaced.
    /// At most [`MAX_POINT_LOADS`], the rest ignored; non-finite ones are
    /// skipped. Allocates nothing.
    pub fn set_point_loads(&mut self, loads: &[(u32, Vec3)]) {
        self.point_loads.clear();
        self.add_point_loads(loads);
    }

    /// Adds point loads to those already set, for another instrument: the
    /// reduced model sees the sum (two loads on one node add, by linearity
    /// of Φᵢᵀ fᵢ). Same rules as [`Servo::set_point_loads`]; beyond
    /// [`MAX_POINT_LOADS`] in all, the rest are ignored. Allocates nothing.
    pub fn add_point_loads(&mut self, loads: &[(u32, Vec3)]) {
        for l in loads.iter().filter(|l| l.1.iter().all(|v| v.is_finite())) {
            if self.point_loads.push(*l).is_err() {
                break;
            }
        }
    }

    /// Removes every point load (before the instruments add this tick's).
    pub fn clear_point_loads(&mut self) {
        self.point_loads.clear();
    }

    /// The point loads in use (mesh node, N), over all instruments.
    pub fn point_loads(&self) -> &[(u32, Vec3)] {
        &self.point_loads
    }

    /// Whether the tool sphere at the hand takes part in the contact and
    /// its reaction is the hand's force (the sphere probe; on by default).
    /// Off, only the extra spheres touch and the hand feels none of them.
    pub fn set_hand_sphere(&mut self, on: bool) {
        self.hand_sphere = on;
    }

    /// Another part of the loop (the guidewire) saw a fault: the force
    /// ramps to zero and is held as for the loop's own faults
    /// ([`Servo::apply_gain`]).
    pub fn raise_fault(&mut self) {
        self.fault_until_s = self.now_s + self.params.ramp_down_s + FAULT_HOLD_S;
    }

    /// The model in use.
    pub fn model(&self) -> &LoopModel<R> {
        &self.model
    }

    /// New contact patches and their correction delays so far.
    pub fn contact_events(&self) -> &ContactEvents {
        &self.events
    }

    /// The contact of the last tick.
    pub fn contact(&self) -> &ContactOutput<R> {
        &self.contact
    }

    /// The settings it was built with.
    pub fn params(&self) -> &ServoParams {
        &self.params
    }

    /// Counters so far.
    pub fn counters(&self) -> &ServoCounters {
        &self.counters
    }

    /// The watchdog gain in [0, 1] applied to the output force.
    pub fn gain(&self) -> f64 {
        self.gain
    }

    /// Deformed position of mesh node `i` under the current model and state.
    pub fn node_position(&self, i: u32) -> Vec3 {
        let m = &self.model;
        let base = self.index.rest(i) + m.offset.get(i as usize).copied().unwrap_or_else(Vec3::zeros);
        match m.dynamics.displacement_at(i) {
            Some(d) => base + d,
            None => base,
        }
    }

    /// Deformed position of mesh node `i` without the share of the
    /// deformation the point loads ([`Servo::set_point_loads`]) caused: the
    /// wall as the instrument that loads it must see it, since that
    /// instrument already feels the wall's compliance in series with its
    /// contact (the guidewire, `wire::coupling`). Seeing its own dent too
    /// would close a loop through the wall with a gain of about
    /// k_contact × compliance ≫ 1.
    pub fn node_position_without_point_loads(&self, i: u32) -> Vec3 {
        let m = &self.model;
        let base = self.index.rest(i) + m.offset.get(i as usize).copied().unwrap_or_else(Vec3::zeros);
        match m.dynamics.rows_at(i) {
            Some(rows) => base + rows * (m.dynamics.q() - self.loads_part.q),
            None => base,
        }
    }

    /// The last tick's time in its phases: contact (with the series solve),
    /// the reduced step and the cross-fade's old model.
    pub fn split(&self) -> &TickSplit {
        &self.split
    }

    /// The share of the current model's reduced state that the point loads
    /// caused (by linearity of the reduced step).
    pub fn point_load_part(&self) -> &ReducedPart<R> {
        &self.loads_part
    }

    /// One tick: the freshest device `sample` (None if the ring was empty),
    /// the time `now_s`, and the current streak of deadline misses. Returns
    /// the desired force and the status; the caller filters it and then
    /// applies [`Servo::apply_gain`]. Allocates nothing.
    pub fn tick(&mut self, sample: Option<&DeviceSample>, now_s: f64, overrun_streak: u32) -> TickOutput {
        self.counters.ticks += 1;
        self.now_s = now_s;
        self.split.clear();
        let mut fl = 0u32;
        let p = self.params;
        if let Some(s) = sample {
            if !s.is_finite() {
                fl |= flags::NONFINITE;
            } else if self.implausible(s.position, now_s) {
                fl |= flags::BAD_POSE;
                if s.seq != self.last_seq {
                    self.last_seq = s.seq;
                    self.counters.bad_pose_samples += 1;
                }
            } else {
                if s.seq != self.last_seq {
                    self.last_seq = s.seq;
                    self.last_fresh_s = now_s;
                }
                self.last_pose = Some((s.position, now_s));
                self.tool = s.position + p.device_origin;
            }
        }
        if now_s - self.last_fresh_s > p.device_timeout_s {
            fl |= flags::DEVICE_SILENT;
            self.counters.device_silent_ticks += 1;
        }
        if overrun_streak >= p.overrun_streak {
            fl |= flags::OVERRUN;
        }
        let age = now_s - self.model.created_s;
        if age > p.model_timeout_s && self.model.epoch > 0 {
            fl |= flags::MODEL_STALE;
            self.counters.model_stale_ticks += 1;
            if age > p.model_max_age_s {
                fl |= flags::MODEL_EXPIRED;
                self.counters.model_expired_ticks += 1;
            }
        }

        // Contact against the surface as the current state deforms it.
        let tool = self.tool;
        self.centers.clear();
        if self.hand_sphere {
            let _ = self.centers.push(tool);
        }
        for c in self.extra.iter() {
            let _ = self.centers.push(*c);
        }
        let t0 = clock::now_ns();
        eval_contact(
            &self.model,
            &self.index,
            &p.contact,
            &self.centers,
            &mut self.scratch,
            &mut self.contact,
        );
        self.split.add_since(Phase::Contact, t0);
        if self.contact.series_ns > 0 {
            self.split.add(Phase::Series, self.contact.series_ns);
        }
        if self.contact.search_ns > 0 {
            self.split.add(Phase::Search, self.contact.search_ns);
        }
        if !self.contact.nodes.is_empty() {
            fl |= flags::CONTACT;
            self.counters.contact_ticks += 1;
        }
        if self.contact.truncated {
            fl |= flags::TRUNCATED;
            self.counters.truncated_ticks += 1;
        }
        let c = &self.contact;
        self.events.record(self.counters.ticks, &c.sphere_forces, c.corrected);
        let touching = c.sphere_forces.iter().filter(|f| f.norm_squared() > 0.0).count() as u64;
        self.counters.contact_patches_max = self.counters.contact_patches_max.max(touching);
        self.counters.contact_nodes_max = self.counters.contact_nodes_max.max(c.nodes.len() as u64);
        if c.uncorrected > 0 {
            self.counters.uncorrected_ticks += 1;
        }
        if !c.nodes.is_empty() && self.model.compliance.is_some() {
            self.counters.compliance_ticks += 1;
            if c.pair_lookups > 0 {
                self.counters.compliance_lookup_ticks += 1;
            }
        }
        let t0 = clock::now_ns();
        let (mut desired, mut finite) = step_model(
            &mut self.model,
            &self.contact,
            &self.point_loads,
            Some(&mut self.loads_part),
            self.hand_sphere,
            &mut self.counters,
        );
        let t0 = self.split.add_since(Phase::Step, t0);
        // A cross-fade: the old model runs on and the force blends over.
        if let Some(old) = self.fading.as_mut() {
            if let Some((d, shift)) = &self.fade_carry {
                let motion = contact::Motion {
                    q: old.dynamics.q(),
                    row_bound: old.dynamics.row_bound(),
                    offset: Some(old.offset.as_slice()),
                };
                self.counters.fade_searches_shared +=
                    self.fade_contact
                        .adopt_searches(&self.contact, *d, shift, &self.centers, &motion) as u64;
            }
            eval_contact(
                old,
                &self.index,
                &p.contact,
                &self.centers,
                &mut self.fade_scratch,
                &mut self.fade_contact,
            );
            let (f_old, ok_old) = step_model(
                old,
                &self.fade_contact,
                &self.point_loads,
                None,
                self.hand_sphere,
                &mut self.counters,
            );
            if self.fade_contact.search_ns > 0 {
                self.split.add(Phase::Search, self.fade_contact.search_ns);
            }
            self.blend = (self.blend + p.dt / p.swap_blend_s.max(p.dt)).min(1.0);
            if (f_old - desired).norm() <= FADE_DONE_N && self.blend < 1.0 {
                // Nothing left to hide: the models agree on the hand's
                // force (out of contact, both give none).
                self.blend = 1.0;
                self.counters.fades_ended_early += 1;
            }
            desired = f_old * (1.0 - self.blend) + desired * self.blend;
            finite &= ok_old;
            if self.blend >= 1.0 {
                self.retired = self.fading.take();
            }
            self.split.add_since(Phase::Fade, t0);
        }
        if !finite {
            fl |= flags::NONFINITE;
        }
        if fl & flags::NONFINITE != 0 {
            self.model.dynamics.reset();
            self.loads_part = ReducedPart::default();
            if let Some(old) = self.fading.as_mut() {
                old.dynamics.reset();
            }
            self.counters.nonfinite += 1;
        }
        TickOutput {
            desired: if finite { desired } else { Vec3::zeros() },
            tool,
            flags: fl,
            depth: self.contact.max_depth,
        }
    }

    /// Whether a finite `position` (device frame) is a wild pose: beyond the
    /// reach, or farther from the last accepted pose than the speed limit
    /// allows in the time since (plus 1 mm of encoder noise).
    fn implausible(&self, position: Vec3, now_s: f64) -> bool {
        let p = &self.params;
        if position.norm() > p.max_reach_m {
            return true;
        }
        match self.last_pose {
            Some((x, t)) => (position - x).norm() > p.max_speed_m_s * (now_s - t).max(p.dt) + 1e-3,
            None => false,
        }
    }

    /// Applies the watchdog to the (filtered) force of this tick: a fault in
    /// `tick_flags` ramps the gain to zero within the ramp-down time and
    /// holds it there for the ramp-down time plus [`FAULT_HOLD_S`] after the
    /// fault's last tick; then the gain ramps back in. A non-finite `force`
    /// counts as zero. Returns the force to command.
    pub fn apply_gain(&mut self, force: Vec3, tick_flags: &mut u32) -> Vec3 {
        let p = self.params;
        if *tick_flags
            & (flags::DEVICE_SILENT | flags::NONFINITE | flags::OVERRUN | flags::BAD_POSE | flags::MODEL_EXPIRED)
            != 0
        {
            self.fault_until_s = self.now_s + p.ramp_down_s + FAULT_HOLD_S;
        }
        let fault = self.now_s < self.fault_until_s;
        if fault {
            self.gain = if p.ramp_down_s > 0.0 {
                (self.gain - p.dt / p.ramp_down_s).max(0.0)
            } else {
                0.0
            };
            *tick_flags |= flags::WATCHDOG;
            self.counters.watchdog_ticks += 1;
        } else {
            self.gain = if p.ramp_in_s > 0.0 {
                (self.gain + p.dt / p.ramp_in_s).min(1.0)
            } else {
                1.0
            };
        }
        if force.iter().all(|v| v.is_finite()) {
            force * self.gain
        } else {
            Vec3::zeros()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn contact_events_count_new_patches_and_their_correction_delays() {
        let mut e = ContactEvents::default();
        let on = Vec3::new(0.0, 0.0, 1.0);
        let off = Vec3::zeros();
        // Tick 3: sphere 0 touches, no correction; tick 4: sphere 1 too;
        // tick 5: corrected (delays 2 and 1); tick 10: sphere 2 touches
        // uncorrected and leaves on tick 11.
        e.record(1, &[off], true);
        e.record(3, &[on, off], false);
        e.record(4, &[on, on], false);
        e.record(5, &[on, on], true);
        e.record(6, &[on, on], true);
        e.record(10, &[on, on, on], false);
        e.record(11, &[on, on, off], true);
        assert_eq!(e.new_patches, 3);
        assert_eq!(e.corrected(), 2);
        assert_eq!(e.never_corrected, 1);
        assert_eq!(e.delay_quantile(0.0), 1);
        assert_eq!(e.delay_quantile(1.0), 2);
        assert_eq!(e.delay_max(), 2);
        // Leaving and touching again is a new patch, corrected at once.
        e.record(12, &[off, on], true);
        e.record(13, &[on, on], true);
        assert_eq!(e.new_patches, 4);
        assert_eq!(e.delay_quantile(0.0), 0);
    }
}
