//! One haptic tick, in one place: the instruments' contributions → contact
//! → reduced step → passivity QP → watchdog gain. The service's loop thread
//! and the closed-loop tests call [`HapticTick::run_with`] (or
//! [`HapticTick::run`] for the probe alone); nothing else strings these
//! steps together.
//!
//! ```text
//! contributions (one per instrument, fixed capacity): hand force, point
//!           loads (summed), contact spheres, the probe's sphere, faults
//! sample ─▶ Servo::tick (watchdog flags, contact with the deformed surface,
//!           reduced step with the contact implicit) ─▶ desired force
//!           + the instruments' hand forces
//!        ─▶ PassivityFilter::filter (norm, rate and energy-tank rows)
//!        ─▶ Servo::apply_gain (ramp to zero on a fault, ramp back in)
//!        ─▶ commanded force; the filter's energy observer is told the
//!           force actually commanded, so the port energy is counted once.
//! ```
//!
//! Allocates nothing, locks nothing, blocks on nothing: the loop thread may
//! call it after start.

use super::device::DeviceSample;
use super::passivity::{predict_velocity, PassivityFilter, PassivityStats, QpStatus};
use super::phases::{Phase, TickSplit};
use super::servo::{flags, LoopModel, Servo, ServoCounters};
use crate::math::Vec3;
use crate::rt::clock;

/// Most instruments one tick takes ([`HapticTick::run_with`]; the rest are
/// ignored).
pub const MAX_INSTRUMENTS: usize = 4;

/// What one instrument gives the loop on one tick, the same shape for every
/// kind (docs/INSTRUMENTS.md): it borrows the instrument's own buffers, so
/// building it allocates nothing.
#[derive(Debug, Clone, Copy, Default)]
pub struct Contribution<'a> {
    /// Force on the device's channels (N, on the hand, scene frame), added
    /// to the model's force before the passivity filter (a rod's hub
    /// resistance). Non-finite counts as zero.
    pub force: Vec3,
    /// Point loads on mesh nodes (N, on the tissue): they load the reduced
    /// model only (Φᵢᵀ fᵢ), summed over the instruments
    /// ([`Servo::add_point_loads`]); the full solve does not see them.
    pub point_loads: &'a [(u32, Vec3)],
    /// Contact spheres (scene frame, the tool's radius) the vessel step
    /// resolves with the contact implicit; they load the tissue and the
    /// full solve, and the hand does not feel them.
    pub spheres: &'a [Vec3],
    /// A contact sphere at the hand's tool point whose reaction the hand
    /// feels: the sphere probe.
    pub hand_sphere: bool,
    /// The instrument saw a fault (a stalled or reset thread): the
    /// watchdog ramps the force to zero ([`Servo::raise_fault`]).
    pub fault: bool,
}

impl Contribution<'static> {
    /// The sphere probe's contribution: a sphere at the hand, felt.
    pub const PROBE: Contribution<'static> = Contribution {
        force: Vec3::new(0.0, 0.0, 0.0),
        point_loads: &[],
        spheres: &[],
        hand_sphere: true,
        fault: false,
    };
}

/// What one tick takes besides the loop state.
#[derive(Debug, Clone, Copy)]
pub struct TickInput<'a> {
    /// The freshest device sample (None if none arrived since the last tick).
    pub sample: Option<&'a DeviceSample>,
    /// Loop time (s).
    pub now_s: f64,
    /// Consecutive deadline misses so far.
    pub overrun_streak: u32,
}

/// What one tick produced.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TickResult {
    /// The force to command (N, on the hand, scene frame = device frame
    /// axes): filtered by the passivity QP and scaled by the watchdog gain.
    pub force: Vec3,
    /// The model's force before the filter and the gain (N).
    pub desired: Vec3,
    /// Tool centre (m, scene frame).
    pub tool: Vec3,
    /// Status bits ([`flags`]).
    pub flags: u32,
    /// Deepest penetration this tick (m).
    pub depth: f64,
    /// Time spent in the passivity filter (µs).
    pub qp_us: f64,
    /// Whether the filter ran the QP solver (false: the model's force was
    /// inside every bound and was used as it is, the shortcut).
    pub qp_solved: bool,
}

/// The haptic loop's state: the servo (contact, reduced model, watchdog)
/// and the passivity filter. Built before start; [`HapticTick::run`] once
/// per period.
pub struct HapticTick<const R: usize> {
    servo: Servo<R>,
    filter: PassivityFilter,
    v_prev: Vec3,
    /// The last sample's sequence number (None before the first).
    last_seq: Option<u64>,
    /// The last tick's time and the last sample's device time (s).
    last_now_s: f64,
    last_sample_s: f64,
    rt_granted: bool,
    split: TickSplit,
    spheres: heapless::Vec<Vec3, { crate::haptics::contact::MAX_SPHERES - 1 }>,
}

impl<const R: usize> HapticTick<R> {
    /// A tick over `servo` and `filter`.
    pub fn new(servo: Servo<R>, filter: PassivityFilter) -> HapticTick<R> {
        HapticTick {
            servo,
            filter,
            v_prev: Vec3::zeros(),
            last_seq: None,
            last_now_s: f64::NAN,
            last_sample_s: f64::NAN,
            rt_granted: false,
            split: TickSplit::default(),
            spheres: heapless::Vec::new(),
        }
    }

    /// Call once on the loop thread before the first tick (after the RT
    /// allocator is entered): lets the QP solver do its one-time allocation
    /// work now (see [`PassivityFilter::prime`]).
    pub fn prime(&mut self) {
        self.filter.prime();
    }

    /// Whether the loop runs under SCHED_FIFO (sets [`flags::RT_GRANTED`]).
    pub fn set_rt_granted(&mut self, granted: bool) {
        self.rt_granted = granted;
    }

    /// One tick with the sphere probe as the only instrument. Allocates
    /// nothing.
    pub fn run(&mut self, input: TickInput<'_>) -> TickResult {
        self.run_with(input, &[Contribution::PROBE])
    }

    /// One tick with the instruments' `contributions` (at most
    /// [`MAX_INSTRUMENTS`], the rest ignored): their point loads are summed
    /// onto the reduced model, their spheres and the probe's join the
    /// contact, their faults raise the watchdog, and their hand forces are
    /// added to the model's force before the passivity filter, which sees
    /// the sum. Allocates nothing.
    pub fn run_with(&mut self, input: TickInput<'_>, contributions: &[Contribution<'_>]) -> TickResult {
        let contributions = &contributions[..contributions.len().min(MAX_INSTRUMENTS)];
        let mut hand_force = Vec3::zeros();
        let mut hand_sphere = false;
        self.spheres.clear();
        self.servo.clear_point_loads();
        for c in contributions {
            if c.force.iter().all(|v| v.is_finite()) {
                hand_force += c.force;
            }
            self.servo.add_point_loads(c.point_loads);
            for x in c.spheres {
                let _ = self.spheres.push(*x);
            }
            hand_sphere |= c.hand_sphere;
            if c.fault {
                self.servo.raise_fault();
            }
        }
        self.servo.set_extra_spheres(&self.spheres);
        self.servo.set_hand_sphere(hand_sphere);
        let mut out = self.servo.tick(input.sample, input.now_s, input.overrun_streak);
        if out.flags & flags::NONFINITE == 0 {
            out.desired += hand_force;
        }
        let (x, v) = input
            .sample
            .map(|s| (s.position, s.velocity))
            .unwrap_or((Vec3::zeros(), Vec3::zeros()));
        let q0 = clock::now_ns();
        // A rejected pose (a jump no hand makes) is not a motion of the
        // port, a tick without a sample has no position, and the same
        // sample again (a silent device: the loop hands the tick the last
        // one it has) says nothing of the motion since: the observer counts
        // neither the jump to such a sample nor the one back, and charges
        // the held force's work at the last measured velocity instead
        // (`PassivityFilter::skip_sample`; the watchdog ramps the force
        // down meanwhile).
        let seq = input.sample.map(|s| s.seq);
        let repeated = seq.is_some() && seq == self.last_seq;
        if seq.is_some() {
            self.last_seq = seq;
        }
        if out.flags & flags::BAD_POSE != 0 || input.sample.is_none() || repeated {
            self.filter.skip_sample();
        }
        // A tick or a sample that came more than the device's command
        // timeout after the last one: the device may have dropped the held
        // force meanwhile (`PassivityFilter::withhold_credit`). A NaN time
        // (the first tick) compares false.
        let timeout = self.servo.params().command_timeout_s;
        let sample_s = input.sample.map_or(f64::NAN, |s| s.time_s);
        if input.now_s - self.last_now_s > timeout || sample_s - self.last_sample_s > timeout {
            self.filter.withhold_credit();
        }
        self.last_now_s = input.now_s;
        if !repeated && sample_s.is_finite() {
            self.last_sample_s = sample_s;
        }
        let v_pred = predict_velocity(v, self.v_prev);
        self.v_prev = v;
        let fo = self.filter.filter(out.desired, x, v_pred);
        let filtered = fo.force;
        let qp_solved = !matches!(fo.status, QpStatus::Interior | QpStatus::NotRun);
        let q1 = clock::now_ns();
        let qp_us = (q1 - q0) as f64 * 1e-3;
        self.split = *self.servo.split();
        self.split
            .add(if qp_solved { Phase::QpSolve } else { Phase::Filter }, q1 - q0);
        if qp_solved {
            self.split.add(Phase::Filter, q1 - q0);
        }
        let mut fl = out.flags;
        if self.rt_granted {
            fl |= flags::RT_GRANTED;
        }
        if (filtered - out.desired).norm() > 1e-9 {
            fl |= flags::LIMITED;
        }
        let mut force = self.servo.apply_gain(filtered, &mut fl);
        if fl & flags::WATCHDOG == 0 {
            // Ramping in: the gain must not add to the rate row's step.
            force = self.filter.ramp_in_within_rate(filtered, self.servo.gain());
        }
        if fl & flags::NONFINITE != 0 {
            self.filter.reset();
            self.v_prev = Vec3::zeros();
        } else {
            // The force held until the next tick is the gained one: the
            // energy observer and the rate row must see that one.
            self.filter.set_commanded(force);
        }
        self.split.add_since(Phase::Output, q1);
        TickResult {
            force,
            desired: out.desired,
            tool: out.tool,
            flags: fl,
            depth: out.depth,
            qp_us,
            qp_solved,
        }
    }

    /// The last tick's time in its phases (contact, series solve, step,
    /// cross-fade, filter, QP solve, gain).
    pub fn split(&self) -> &TickSplit {
        &self.split
    }

    /// Swaps in a refreshed model (see [`Servo::swap`]); returns the model
    /// to send back for freeing off the loop thread.
    pub fn swap(&mut self, model: Box<LoopModel<R>>) -> Option<Box<LoopModel<R>>> {
        self.servo.swap(model)
    }

    /// Prepares a model's swap a tick before it (see [`Servo::prepare`]);
    /// returns a sum of what it read.
    pub fn prepare(&mut self, model: &LoopModel<R>) -> f64 {
        self.servo.prepare(model)
    }

    /// The servo (contact, model, watchdog).
    pub fn servo(&self) -> &Servo<R> {
        &self.servo
    }

    /// The servo, mutable (to hand retired models back).
    pub fn servo_mut(&mut self) -> &mut Servo<R> {
        &mut self.servo
    }

    /// The passivity filter.
    pub fn filter(&self) -> &PassivityFilter {
        &self.filter
    }

    /// Loop counters so far.
    pub fn counters(&self) -> &ServoCounters {
        self.servo.counters()
    }

    /// New contact patches and their correction delays so far.
    pub fn contact_events(&self) -> &crate::haptics::servo::ContactEvents {
        self.servo.contact_events()
    }

    /// QP counters so far, including the port energy the observer counted
    /// (`delivered_j`, `absorbed_j`).
    pub fn qp_stats(&self) -> &PassivityStats {
        self.filter.stats()
    }
}
