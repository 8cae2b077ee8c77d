//! The haptic loop thread: absolute-deadline wake-ups at the loop rate, one
//! [`HapticTick`] per period, and the rings around it (pose in, force out,
//! contact forces to the background, models in and out, state snapshots to
//! the publisher). Each tick reads top to bottom: device (the newest
//! pose) → each instrument's contribution → vessel step → passivity →
//! gain (the last three in [`HapticTick::run_with`]) → push. Timing goes
//! into fixed histograms; live figures into [`LiveStats`] atomics; nothing
//! here allocates, locks, logs or blocks after start.

use super::background::{ContactMsg, CONTACT_MSG_NODES};
use super::device_io::ForceCmd;
use super::instrument::{Hand, LoopSide, Selector};
use super::live::LiveStats;
use super::publisher::StateSnapshot;
use crate::haptics::device::DeviceSample;
use crate::haptics::frame::DeviceFrame;
use crate::haptics::passivity::PassivityStats;
use crate::haptics::phases::{Phase, TickPhases, TickSplit};
use crate::haptics::servo::{flags, LoopModel, ServoCounters};
use crate::haptics::tick::{Contribution, HapticTick, TickInput, MAX_INSTRUMENTS};
use crate::math::Vec3;
use crate::rt::clock::{self, Nanos};
use crate::rt::stats::Histogram;
use crate::rt::thread::{setup_current, RtGrant, RtRequest};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

/// The loop ticks this long after the device thread reads a sample (ns).
pub(super) const LOOP_PHASE: Nanos = 200_000;

/// Everything gathered from the loop thread at the end.
pub(super) struct LoopResult {
    pub jitter: Histogram,
    pub compute: Histogram,
    pub baseline: Histogram,
    pub qp_us: Histogram,
    pub phases: TickPhases,
    pub grant: RtGrant,
    pub counters: ServoCounters,
    pub contact: crate::service::report::ContactReport,
    pub qp: PassivityStats,
    pub misses: u64,
    pub misses_compute: u64,
    pub allocations: u64,
    pub page_faults: (u64, u64),
    pub allocator_installed: bool,
    pub max_force: f64,
    pub max_depth: f64,
    pub seconds: f64,
    pub force_ring_full: u64,
    pub contact_ring_full: u64,
    pub state_ring_full: u64,
    pub swaps_deferred: u64,
    /// Presses of the switch button that changed the active instrument.
    pub instrument_switches: u64,
    /// The second device's port (None without `[device.second]`).
    pub second: Option<SecondResult>,
}

/// What the loop gathered of the second device's port.
pub(super) struct SecondResult {
    /// Largest force commanded to it (N).
    pub max_force: f64,
    /// Ticks without a fresh pose from it (its instrument held, its force
    /// ramped to zero).
    pub silent_ticks: u64,
    /// Force commands its ring had no room for.
    pub force_ring_full: u64,
    /// Its passivity filter's counters.
    pub qp: PassivityStats,
}

/// The second device's rings and port on the loop (`[device.second]`): it
/// drives one hub-driven instrument on its own and feels that instrument's
/// force, through its own passivity filter.
pub(super) struct SecondIo {
    /// Its poses (device frame).
    pub pose: rtrb::Consumer<DeviceSample>,
    /// Its force commands (device frame).
    pub force: rtrb::Producer<ForceCmd>,
    /// The instrument it drives (index in the loop's list).
    pub instrument: usize,
    /// The passivity filter of its port (the same parameters as the first
    /// device's).
    pub filter: crate::haptics::passivity::PassivityFilter,
    /// A pose older than this (ns, by arrival) is no pose: its instrument
    /// holds its hub and the force ramps to zero (`watchdog.device_timeout_ms`).
    pub timeout: Nanos,
}

/// Loop-side rings.
pub(super) struct LoopIo<const R: usize> {
    pub pose: rtrb::Consumer<DeviceSample>,
    pub force: rtrb::Producer<ForceCmd>,
    pub contact: rtrb::Producer<ContactMsg>,
    pub models: rtrb::Consumer<Box<LoopModel<R>>>,
    pub returned: rtrb::Producer<Box<LoopModel<R>>>,
    pub state: rtrb::Producer<StateSnapshot<R>>,
    pub stop: Arc<AtomicBool>,
    pub live: Arc<LiveStats>,
    pub faults: Arc<super::faults::FaultSwitches>,
    /// The instruments' loop sides, in registry order (at most
    /// [`MAX_INSTRUMENTS`]).
    pub instruments: Vec<Box<dyn LoopSide>>,
    /// The second device, if any.
    pub second: Option<SecondIo>,
}

/// When and how the loop runs.
pub(super) struct LoopPlan {
    pub request: RtRequest,
    pub period: Nanos,
    pub start: Nanos,
    pub loop_start: Nanos,
    pub baseline_s: f64,
    pub pool_bytes: usize,
    pub state_every: u64,
    /// Rotation and scale of `[device.frame]` (its offset is the servo's
    /// device origin); None: device axes are scene axes.
    pub frame: Option<DeviceFrame>,
}

/// The loop thread's body: the jitter baseline, then ticks until `stop`.
pub(super) fn loop_thread<const R: usize>(mut tick: HapticTick<R>, mut io: LoopIo<R>, plan: LoopPlan) -> LoopResult {
    let grant = setup_current(&plan.request);
    let pool = crate::rt::alloc::enter_rt(plan.pool_bytes);
    let allocator_installed = pool.map(|p| p.installed).unwrap_or(false);
    // Whatever clarabel sizes or frees on its first solve happens now.
    tick.prime();
    tick.set_rt_granted(grant.fifo);
    let mut res = LoopResult {
        jitter: Histogram::new(),
        compute: Histogram::new(),
        baseline: Histogram::new(),
        qp_us: Histogram::new(),
        phases: TickPhases::new(crate::haptics::phases::TAIL_US),
        grant,
        counters: ServoCounters::default(),
        contact: Default::default(),
        qp: *tick.qp_stats(),
        misses: 0,
        misses_compute: 0,
        allocations: 0,
        page_faults: (0, 0),
        allocator_installed,
        max_force: 0.0,
        max_depth: 0.0,
        seconds: 0.0,
        force_ring_full: 0,
        contact_ring_full: 0,
        state_ring_full: 0,
        swaps_deferred: 0,
        instrument_switches: 0,
        second: None,
    };
    if let Some(sec) = io.second.as_mut() {
        sec.filter.prime();
    }
    let mut second = SecondPort::default();
    let period = plan.period;
    // The jitter baseline: a bare absolute-deadline sleep loop, same thread,
    // same CPU, same policy, same run.
    let mut next = plan.start;
    let base_end = plan.start + (plan.baseline_s * 1e9) as Nanos;
    while next < base_end && !io.stop.load(Ordering::Relaxed) {
        clock::sleep_until(next);
        res.baseline.record((clock::now_ns() - next) as f64 * 1e-3);
        next += period;
    }
    next = next.max(plan.loop_start);
    let sys0 = crate::rt::alloc::thread_system_calls();
    let faults0 = crate::rt::thread::thread_page_faults();
    let t_begin = clock::now_ns();
    let mut streak = 0u32;
    // The second device's instrument is its own: the switch button does
    // not select it.
    let own = io.second.as_ref().map(|s| s.instrument);
    let mut selector = Selector::new(
        io.instruments
            .iter()
            .enumerate()
            .map(|(k, i)| i.hub_driven() && Some(k) != own),
    );
    let mut last: Option<DeviceSample> = None;
    let mut last_pose_time: Nanos = 0;
    let mut n: u64 = 0;
    let mut window_max_us = 0.0f64;
    // A retired model the return ring had no room for (kept, never freed here).
    let mut pending_return: Option<Box<LoopModel<R>>> = None;
    // A model taken from the ring and warmed, to swap in on the next tick.
    let mut incoming: Option<Box<LoopModel<R>>> = None;
    let mut contact_msg = ContactMsg {
        tick: 0,
        nodes: heapless::Vec::new(),
    };
    while !io.stop.load(Ordering::Relaxed) {
        clock::sleep_until(next);
        let wake = clock::now_ns();
        res.jitter.record((wake - next) as f64 * 1e-3);
        n += 1;
        let mut split = TickSplit::starting_at(wake);

        // Freshest pose (drain).
        while let Ok(s) = io.pose.pop() {
            last_pose_time = (s.time_s * 1e9) as Nanos + clock::epoch();
            last = Some(s);
        }
        if let Some(sec) = io.second.as_mut() {
            second.drain(sec, wake);
        }
        split.lap(Phase::Drain);
        // The model taken and warmed on an earlier tick swaps in between
        // ticks; only if the models it retires can be returned (never
        // freed here).
        if incoming.is_some() && !io.faults.holding_models() {
            if pending_return.is_none() && io.returned.slots() >= 2 {
                if let Some(m) = incoming.take() {
                    if let Some(old) = tick.swap(m) {
                        if let Err(rtrb::PushError::Full(old)) = io.returned.push(old) {
                            pending_return = Some(old);
                        }
                    }
                    split.lap(Phase::Swap);
                }
            } else {
                res.swaps_deferred += 1;
            }
        }
        let now_s = clock::to_s(wake);
        let scene_sample = match (&plan.frame, &last) {
            (Some(f), Some(s)) => Some(f.sample_to_scene(s)),
            _ => last,
        };
        // Each instrument's contribution, in one shape (docs/INSTRUMENTS.md).
        selector.update(last.as_ref());
        let mut parts: heapless::Vec<Contribution<'_>, MAX_INSTRUMENTS> = heapless::Vec::new();
        let mut second_force = Vec3::zeros();
        for (k, inst) in io.instruments.iter_mut().enumerate() {
            if own == Some(k) {
                // Driven by the second device, whose hand feels its force.
                let mut c = inst.contribute(&second.hand(now_s));
                second_force = std::mem::replace(&mut c.force, Vec3::zeros());
                let _ = parts.push(c);
            } else {
                let _ = parts.push(inst.contribute(&selector.hand(k, last.as_ref(), now_s)));
            }
        }
        split.lap(Phase::Instruments);
        let out = tick.run_with(
            TickInput {
                sample: scene_sample.as_ref(),
                now_s,
                overrun_streak: streak,
            },
            &parts,
        );
        drop(parts);
        split.absorb(tick.split());
        let device_force = match &plan.frame {
            Some(f) => f.force_to_device(out.force),
            None => out.force,
        };
        if out.qp_solved {
            res.qp_us.record(out.qp_us);
        }
        res.max_force = res.max_force.max(out.force.norm());
        res.max_depth = res.max_depth.max(out.depth);
        if io
            .force
            .push(ForceCmd {
                force: device_force,
                pose_time: last_pose_time,
            })
            .is_err()
        {
            res.force_ring_full += 1;
        }
        if let Some(sec) = io.second.as_mut() {
            let f = match &plan.frame {
                Some(fr) => fr.force_to_device(second_force),
                None => second_force,
            };
            let faulted = out.flags & flags::WATCHDOG != 0;
            second.output(sec, f, tick.servo().gain(), faulted);
        }
        let c = tick.servo().contact();
        if !c.nodes.is_empty() {
            contact_msg.tick = n;
            contact_msg.nodes.clear();
            for nc in c.nodes.iter().take(CONTACT_MSG_NODES) {
                let _ = contact_msg.nodes.push(*nc);
            }
            if io.contact.push(contact_msg.clone()).is_err() {
                res.contact_ring_full += 1;
            }
        }
        // The instruments' point loads load the reduced model only, never
        // the contact ring: the full solve does not see them, since the
        // wire already feels the wall's compliance in series with its
        // contact and a delayed copy of its own dent in ū would close the
        // loop the lumen leaves open (docs/WIRE.md, "The wall under the
        // wire").
        if pending_return.is_none() {
            pending_return = tick.servo_mut().take_retired();
        }
        if let Some(old) = pending_return.take() {
            if let Err(rtrb::PushError::Full(old)) = io.returned.push(old) {
                pending_return = Some(old);
            }
        }
        split.lap(Phase::Output);
        // A refreshed model is taken from the ring after the force is out
        // and swapped in on the next tick: reading its memory now (written
        // by the background thread on the other core) lets the swap tick
        // find it in this core's cache, and its state correction is
        // computed here, off the swap tick (`Servo::prepare`).
        if incoming.is_none() && !io.models.is_empty() && !io.faults.holding_models() {
            if let Ok(m) = io.models.pop() {
                std::hint::black_box(tick.prepare(&m));
                incoming = Some(m);
                split.lap(Phase::Warm);
            }
        }
        let end = clock::now_ns();
        let compute = end - wake;
        res.compute.record(compute as f64 * 1e-3);
        res.phases.record(&split, compute);
        window_max_us = window_max_us.max(compute as f64 * 1e-3);
        io.live.record_tick(n, now_s, &out, res.misses);
        io.live.record_model(tick.servo().model().epoch, tick.servo().gain());
        if n % plan.state_every == 0 {
            let model = tick.servo().model();
            let snap = StateSnapshot {
                time_s: now_s,
                epoch: model.epoch,
                q: *model.dynamics.q(),
                q_loads: tick.servo().point_load_part().q,
                tool: out.tool,
                force: out.force,
                flags: out.flags,
                tick_max_us: window_max_us as f32,
            };
            window_max_us = 0.0;
            if io.state.push(snap).is_err() {
                res.state_ring_full += 1;
            }
        }
        // Deadlines: a tick that ends after the next deadline is a miss; the
        // loop re-phases to the next future deadline instead of bursting.
        next += period;
        if end > next {
            res.misses += 1;
            if compute > period {
                res.misses_compute += 1;
            }
            streak += 1;
            let behind = (end - next) / period + 1;
            next += behind * period;
        } else {
            streak = 0;
        }
    }
    res.allocations = crate::rt::alloc::thread_system_calls() - sys0;
    let faults1 = crate::rt::thread::thread_page_faults();
    res.page_faults = (faults1.0 - faults0.0, faults1.1 - faults0.1);
    // Off the clock: whatever was not returned is freed with the thread.
    drop(pending_return);
    drop(incoming);
    res.seconds = (clock::now_ns() - t_begin) as f64 * 1e-9;
    res.instrument_switches = selector.switches();
    res.second = io.second.as_ref().map(|sec| SecondResult {
        max_force: second.max_force,
        silent_ticks: second.silent_ticks,
        force_ring_full: second.force_ring_full,
        qp: *sec.filter.stats(),
    });
    res.counters = *tick.counters();
    res.contact =
        crate::service::report::ContactReport::from_loop(tick.contact_events(), tick.counters(), period as f64 * 1e-9);
    res.qp = *tick.qp_stats();
    crate::rt::alloc::leave_rt();
    res
}

/// The second device's port on the loop thread: its newest pose, and its
/// force through its own passivity filter. Plain data; allocates nothing.
#[derive(Default)]
struct SecondPort {
    /// The newest pose and when it arrived (ns).
    last: Option<(DeviceSample, Nanos)>,
    /// Whether the newest pose is fresh this tick (within the timeout).
    fresh: bool,
    /// The pose became fresh this tick (the first, or the first after a
    /// silence): the instrument takes the stylus up where it is.
    engaged: bool,
    /// The sequence number the filter saw last.
    last_seq: Option<u64>,
    /// The pose time of the newest pose (ns, service clock): the force
    /// command answers it.
    pose_time: Nanos,
    max_force: f64,
    silent_ticks: u64,
    force_ring_full: u64,
}

impl SecondPort {
    /// Takes the second device's newest pose.
    fn drain(&mut self, sec: &mut SecondIo, wake: Nanos) {
        while let Ok(s) = sec.pose.pop() {
            self.pose_time = (s.time_s * 1e9) as Nanos + clock::epoch();
            self.last = Some((s, wake));
        }
        let was = self.fresh;
        self.fresh = matches!(self.last, Some((_, at)) if wake - at <= sec.timeout);
        self.engaged = self.fresh && !was;
        if !self.fresh {
            self.silent_ticks += 1;
        }
    }

    /// What its instrument is given: the newest pose while it is fresh
    /// (without one the instrument holds its hub and gives no force); it is
    /// always the active instrument of its own device, and takes the
    /// stylus up where it is when the device comes (back): a second hand
    /// picks the instrument up where it lies, it does not jump to where
    /// the stylus's absolute position would put it.
    fn hand(&self, now_s: f64) -> Hand<'_> {
        Hand {
            sample: self.last.as_ref().filter(|_| self.fresh).map(|(s, _)| s),
            now_s,
            active: true,
            engaged: self.engaged,
        }
    }

    /// Filters its instrument's force `f` (N, device frame) for its port,
    /// applies the loop's watchdog gain (`faulted`: ramping down) and
    /// pushes it to its device.
    fn output(&mut self, sec: &mut SecondIo, f: Vec3, gain: f64, faulted: bool) {
        let sample = self.last.as_ref().filter(|_| self.fresh).map(|(s, _)| *s);
        let seq = sample.map(|s| s.seq);
        let repeated = seq.is_some() && seq == self.last_seq;
        if seq.is_some() {
            self.last_seq = seq;
        }
        if sample.is_none() || repeated {
            // No motion of the port measured this tick (as the first
            // port's `HapticTick::run_with`).
            sec.filter.skip_sample();
        }
        let (x, v) = sample.map_or((Vec3::zeros(), Vec3::zeros()), |s| (s.position, s.velocity));
        let desired = if f.iter().all(|c| c.is_finite()) {
            f
        } else {
            Vec3::zeros()
        };
        let filtered = sec.filter.filter(desired, x, v).force;
        // The loop's gain, ramping in within this port's rate row (as the
        // first port's `HapticTick::run_with`); a fault's ramp-down as it is.
        let mut force = if faulted {
            filtered * gain.clamp(0.0, 1.0)
        } else {
            sec.filter.ramp_in_within_rate(filtered, gain)
        };
        if !force.iter().all(|c| c.is_finite()) {
            sec.filter.reset();
            force = Vec3::zeros();
        } else {
            sec.filter.set_commanded(force);
        }
        self.max_force = self.max_force.max(force.norm());
        if sec
            .force
            .push(ForceCmd {
                force,
                pose_time: self.pose_time,
            })
            .is_err()
        {
            self.force_ring_full += 1;
        }
    }
}
