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
use super::instrument::{LoopSide, Selector};
use super::live::LiveStats;
use super::publisher::StateSnapshot;
use crate::haptics::device::DeviceSample;
use crate::haptics::frame::DeviceFrame;
use crate::haptics::passivity::PassivityStats;
use crate::haptics::phases::{Phase, TickPhases, TickSplit};
use crate::haptics::servo::{LoopModel, ServoCounters};
use crate::haptics::tick::{Contribution, HapticTick, TickInput, MAX_INSTRUMENTS};
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
    };
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
    let mut selector = Selector::new(io.instruments.iter().map(|i| i.hub_driven()));
    let mut last: Option<DeviceSample> = None;
    let mut last_pose_time: Nanos = 0;
    let mut n: u64 = 0;
    let mut window_max_us = 0.0f64;
    // A retired model the return ring had no room for (kept, never freed here).
    let mut pending_return: Option<Box<LoopModel<R>>> = None;
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
        split.lap(Phase::Drain);
        // A new model between ticks; only if the models it retires can be
        // returned (never freed here).
        if !io.models.is_empty() && !io.faults.holding_models() {
            if pending_return.is_none() && io.returned.slots() >= 2 {
                if let Ok(m) = io.models.pop() {
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
        for (k, inst) in io.instruments.iter_mut().enumerate() {
            let _ = parts.push(inst.contribute(&selector.hand(k, last.as_ref(), now_s)));
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
    res.seconds = (clock::now_ns() - t_begin) as f64 * 1e-9;
    res.instrument_switches = selector.switches();
    res.counters = *tick.counters();
    res.contact =
        crate::service::report::ContactReport::from_loop(tick.contact_events(), tick.counters(), period as f64 * 1e-9);
    res.qp = *tick.qp_stats();
    crate::rt::alloc::leave_rt();
    res
}
