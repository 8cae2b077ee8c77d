//! Live figures of a running service, readable from any thread while it
//! runs ([`crate::service::Handle::snapshot`]): the loop and the background
//! thread store them in atomics (lock-free, no allocation); the publisher
//! keeps the latest state frame behind a mutex (it is a normal thread, never
//! the loop).

use crate::haptics::servo::flags;
use crate::haptics::tick::TickResult;
use crate::math::Vec3;
use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};
use std::sync::Mutex;

/// An f64 in an atomic (bit pattern).
#[derive(Debug, Default)]
struct AtomicF64(AtomicU64);

impl AtomicF64 {
    fn store(&self, v: f64) {
        self.0.store(v.to_bits(), Ordering::Relaxed);
    }
    fn load(&self) -> f64 {
        f64::from_bits(self.0.load(Ordering::Relaxed))
    }
}

/// The latest state frame, owned (surface positions at the stream's
/// vertices, tool, force).
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct FrameSnapshot {
    /// Loop time of the frame (s).
    pub time_s: f64,
    /// Mesh node of each stream vertex.
    pub node_ids: Vec<u32>,
    /// Deformed positions of the stream vertices (m).
    pub positions: Vec<[f32; 3]>,
    /// Tool centre (m).
    pub tool_position: [f32; 3],
    /// Commanded force (N).
    pub force: [f32; 3],
    /// Stream status bits (`crate::stream::flags`).
    pub flags: u32,
    /// The surface's triangles (indices into `positions`, counter-clockwise
    /// seen from outside the tissue).
    pub triangles: Vec<[u32; 3]>,
    /// One polyline per instrument of the run, in the loop's order.
    pub instruments: Vec<InstrumentPolyline>,
}

/// An instrument's polyline in a [`FrameSnapshot`].
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct InstrumentPolyline {
    /// Its id in the run (`probe`, `guidewire`).
    pub id: String,
    /// Its kind (`probe`, `guidewire`).
    pub kind: String,
    /// Its id on the state stream (its index in the run's list).
    pub stream_id: u8,
    /// Its kind's code on the state stream (docs/STREAM.md).
    pub kind_code: u8,
    /// Its centreline, hub to tip (m, scene frame; the probe's is its
    /// sphere's centre).
    pub points: Vec<[f32; 3]>,
}

/// Shared live state of one service run.
#[derive(Debug, Default)]
pub struct LiveStats {
    ticks: AtomicU64,
    misses: AtomicU64,
    flags: AtomicU32,
    loop_time: AtomicF64,
    force: [AtomicF64; 3],
    tool: [AtomicF64; 3],
    max_force: AtomicF64,
    bg_steps: AtomicU64,
    bg_sim_s: AtomicF64,
    bg_wall_s: AtomicF64,
    models_sent: AtomicU64,
    epoch: AtomicU64,
    gain: AtomicF64,
    bases: AtomicU64,
    fault_ticks: [AtomicU64; 5],
    frame: Mutex<Option<FrameSnapshot>>,
}

impl LiveStats {
    /// Called by the loop after each tick. Lock-free, allocates nothing.
    pub fn record_tick(&self, ticks: u64, now_s: f64, out: &TickResult, misses: u64) {
        self.ticks.store(ticks, Ordering::Relaxed);
        self.misses.store(misses, Ordering::Relaxed);
        self.flags.store(out.flags, Ordering::Relaxed);
        for ((_, bit), count) in FAULT_CAUSES.iter().zip(&self.fault_ticks) {
            if out.flags & bit != 0 {
                count.fetch_add(1, Ordering::Relaxed);
            }
        }
        self.loop_time.store(now_s);
        for k in 0..3 {
            self.force[k].store(out.force[k]);
            self.tool[k].store(out.tool[k]);
        }
        let f = out.force.norm();
        if f > self.max_force.load() {
            self.max_force.store(f);
        }
    }

    /// Called by the loop after each tick: the epoch of the model in use and
    /// the watchdog gain. Lock-free, allocates nothing.
    pub fn record_model(&self, epoch: u64, gain: f64) {
        self.epoch.store(epoch, Ordering::Relaxed);
        self.gain.store(gain);
    }

    /// Called by the background thread: bases installed by the background
    /// basis refresh so far.
    pub fn record_bases(&self, installed: u64) {
        self.bases.store(installed, Ordering::Relaxed);
    }

    /// Called by the background thread after each full step.
    pub fn record_background(&self, steps: u64, sim_s: f64, wall_s: f64, models_sent: u64) {
        self.bg_steps.store(steps, Ordering::Relaxed);
        self.bg_sim_s.store(sim_s);
        self.bg_wall_s.store(wall_s);
        self.models_sent.store(models_sent, Ordering::Relaxed);
    }

    /// Called by the publisher with each frame it builds.
    pub fn record_frame(&self, frame: FrameSnapshot) {
        if let Ok(mut slot) = self.frame.lock() {
            *slot = Some(frame);
        }
    }

    /// Loop ticks so far.
    pub fn ticks(&self) -> u64 {
        self.ticks.load(Ordering::Relaxed)
    }

    /// A copy of everything, with `elapsed_s` since start.
    pub fn snapshot(&self, elapsed_s: f64) -> Snapshot {
        let v = |a: &[AtomicF64; 3]| Vec3::new(a[0].load(), a[1].load(), a[2].load());
        let bg_wall = self.bg_wall_s.load();
        Snapshot {
            elapsed_s,
            ticks: self.ticks(),
            loop_time_s: self.loop_time.load(),
            deadline_misses: self.misses.load(Ordering::Relaxed),
            flags: self.flags.load(Ordering::Relaxed),
            force_n: v(&self.force).into(),
            tool_m: v(&self.tool).into(),
            max_force_n: self.max_force.load(),
            background_steps: self.bg_steps.load(Ordering::Relaxed),
            background_real_time_factor: if bg_wall > 0.0 {
                self.bg_sim_s.load() / bg_wall
            } else {
                0.0
            },
            models_sent: self.models_sent.load(Ordering::Relaxed),
            model_epoch: self.epoch.load(Ordering::Relaxed),
            gain: self.gain.load(),
            bases_installed: self.bases.load(Ordering::Relaxed),
            fault_ticks: {
                let c = |k: usize| self.fault_ticks[k].load(Ordering::Relaxed);
                FaultTicks {
                    device_silent: c(0),
                    nonfinite: c(1),
                    overrun: c(2),
                    bad_pose: c(3),
                    model_expired: c(4),
                }
            },
            frame: self.frame.lock().ok().and_then(|f| f.clone()),
        }
    }
}

/// What [`crate::service::Handle::snapshot`] returns: live figures and the
/// latest state frame.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct Snapshot {
    /// Wall time since the service started (s).
    pub elapsed_s: f64,
    /// Loop ticks so far.
    pub ticks: u64,
    /// Loop time of the last tick (s, service clock).
    pub loop_time_s: f64,
    /// Deadline misses so far.
    pub deadline_misses: u64,
    /// Status bits of the last tick (`crate::haptics::servo::flags`).
    pub flags: u32,
    /// Force commanded on the last tick (N).
    pub force_n: [f64; 3],
    /// Tool centre on the last tick (m, scene frame).
    pub tool_m: [f64; 3],
    /// Largest force commanded so far (N).
    pub max_force_n: f64,
    /// Full steps of the background solve so far.
    pub background_steps: u64,
    /// Simulated time / wall time of the background solve so far.
    pub background_real_time_factor: f64,
    /// Refreshed models the background sent so far.
    pub models_sent: u64,
    /// Epoch of the model the loop runs (0: the rest model).
    pub model_epoch: u64,
    /// Watchdog gain of the last tick (0 after a fault, ramping back to 1).
    pub gain: f64,
    /// Bases the background basis refresh has installed so far.
    pub bases_installed: u64,
    /// Ticks so far that raised each watchdog cause.
    pub fault_ticks: FaultTicks,
    /// The latest state frame (None before the first one).
    pub frame: Option<FrameSnapshot>,
}

/// Ticks that raised each cause of the watchdog (a tick can raise several),
/// counted since the service started: what made the gain drop.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct FaultTicks {
    /// No fresh device sample within the device timeout
    /// ([`flags::DEVICE_SILENT`]).
    pub device_silent: u64,
    /// A non-finite sample or force ([`flags::NONFINITE`]).
    pub nonfinite: u64,
    /// A streak of deadline misses ([`flags::OVERRUN`]).
    pub overrun: u64,
    /// An implausible pose ([`flags::BAD_POSE`]).
    pub bad_pose: u64,
    /// The loop's model too old ([`flags::MODEL_EXPIRED`]).
    pub model_expired: u64,
}

impl FaultTicks {
    /// The causes whose count grew since `earlier`, by name (in field order).
    pub fn grown_since(&self, earlier: &FaultTicks) -> impl Iterator<Item = &'static str> {
        let now = self.as_array();
        let then = earlier.as_array();
        FAULT_CAUSES
            .into_iter()
            .zip(now.into_iter().zip(then))
            .filter(|(_, (a, b))| a > b)
            .map(|((name, _), _)| name)
    }

    fn as_array(&self) -> [u64; 5] {
        [
            self.device_silent,
            self.nonfinite,
            self.overrun,
            self.bad_pose,
            self.model_expired,
        ]
    }
}

/// The watchdog causes: name and flag bit, in [`FaultTicks`] field order.
const FAULT_CAUSES: [(&str, u32); 5] = [
    ("device_silent", flags::DEVICE_SILENT),
    ("nonfinite", flags::NONFINITE),
    ("overrun", flags::OVERRUN),
    ("bad_pose", flags::BAD_POSE),
    ("model_expired", flags::MODEL_EXPIRED),
];

#[cfg(test)]
mod tests {
    use super::*;

    fn tick(flags: u32) -> TickResult {
        TickResult {
            force: Vec3::zeros(),
            desired: Vec3::zeros(),
            tool: Vec3::zeros(),
            flags,
            depth: 0.0,
            qp_us: 0.0,
            qp_solved: false,
        }
    }

    #[test]
    fn fault_ticks_count_each_cause_and_name_what_grew() {
        let live = LiveStats::default();
        live.record_tick(1, 0.001, &tick(0), 0);
        let start = live.snapshot(0.0).fault_ticks;
        assert_eq!(start, FaultTicks::default());
        live.record_tick(2, 0.002, &tick(flags::DEVICE_SILENT | flags::OVERRUN), 1);
        live.record_tick(3, 0.003, &tick(flags::DEVICE_SILENT | flags::WATCHDOG), 1);
        let now = live.snapshot(0.0).fault_ticks;
        assert_eq!(now.device_silent, 2);
        assert_eq!(now.overrun, 1);
        assert_eq!(now.nonfinite + now.bad_pose + now.model_expired, 0);
        let grown: Vec<&str> = now.grown_since(&start).collect();
        assert_eq!(grown, ["device_silent", "overrun"]);
        assert_eq!(now.grown_since(&now).count(), 0);
    }
}
