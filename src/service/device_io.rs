//! The device I/O thread: at the device rate it reads a sample and pushes it
//! to the loop, then (half a period later) writes the newest force command
//! the loop answered with. Runs under SCHED_FIFO with the RT allocator, like
//! the loop; on stop it writes a zero force.

use crate::haptics::device::{DeviceSample, HapticDevice, PortEnergy};
use crate::math::Vec3;
use crate::rt::clock::{self, Nanos};
use crate::rt::stats::Histogram;
use crate::rt::thread::{setup_current, RtRequest};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

/// A force command (loop → device I/O).
#[derive(Debug, Clone, Copy)]
pub struct ForceCmd {
    /// Force on the hand (N, device frame).
    pub force: Vec3,
    /// Time of the device sample it answers (ns, monotonic).
    pub pose_time: Nanos,
}

/// With no force command from the loop for this long (ns), the device
/// thread commands zero itself: a loop that died or hangs never leaves its
/// last force playing on the hand.
pub const LOOP_SILENCE_NS: Nanos = 20_000_000;

/// What the device thread gathered, returned at the end.
pub(super) struct DeviceResult {
    pub latency: Histogram,
    pub ticks: u64,
    pub errors: u64,
    pub pose_ring_full: u64,
    pub energy: Option<PortEnergy>,
    pub allocations: u64,
    /// Periods in which the device thread zeroed the force because the
    /// loop had sent nothing for [`LOOP_SILENCE_NS`].
    pub loop_silent: u64,
}

/// Device-side rings.
pub(super) struct DeviceIo {
    pub pose: rtrb::Producer<DeviceSample>,
    pub force: rtrb::Consumer<ForceCmd>,
    pub stop: Arc<AtomicBool>,
    /// The newest sample's buttons, for the task metrics (publisher side).
    pub buttons: Arc<std::sync::atomic::AtomicU32>,
}

/// The device thread's body.
pub(super) fn device_thread(
    mut dev: Box<dyn HapticDevice>,
    mut io: DeviceIo,
    request: RtRequest,
    start: Nanos,
    period: Nanos,
    write_offset: Nanos,
    pool_bytes: usize,
) -> (DeviceResult, Box<dyn HapticDevice>) {
    let _grant = setup_current(&request);
    let _ = crate::rt::alloc::enter_rt(pool_bytes);
    let sys0 = crate::rt::alloc::thread_system_calls();
    let mut res = DeviceResult {
        latency: Histogram::new(),
        ticks: 0,
        errors: 0,
        pose_ring_full: 0,
        energy: None,
        allocations: 0,
        loop_silent: 0,
    };
    let mut last_cmd = start;
    let mut next = start;
    while !io.stop.load(Ordering::Relaxed) {
        // Phase 0: the sample for the loop (which ticks 200 µs later).
        clock::sleep_until(next);
        res.ticks += 1;
        match dev.read(clock::now_s()) {
            Ok(s) => {
                io.buttons.store(s.buttons, Ordering::Relaxed);
                if io.pose.push(s).is_err() {
                    res.pose_ring_full += 1;
                }
            }
            Err(_) => res.errors += 1,
        }
        // Phase `write_offset`: the newest force, normally the answer to
        // the sample just read.
        clock::sleep_until(next + write_offset);
        let mut cmd = None;
        while let Ok(c) = io.force.pop() {
            cmd = Some(c);
        }
        if cmd.is_none() && clock::now_ns() - last_cmd > LOOP_SILENCE_NS {
            res.loop_silent += 1;
            if dev.write_force(Vec3::zeros()).is_err() {
                res.errors += 1;
            }
        }
        if let Some(c) = cmd {
            last_cmd = clock::now_ns();
            if dev.write_force(c.force).is_err() {
                res.errors += 1;
            }
            if c.pose_time > 0 {
                res.latency.record((clock::now_ns() - c.pose_time) as f64 * 1e-3);
            }
        }
        next += period;
        let now = clock::now_ns();
        if now > next {
            next += ((now - next) / period + 1) * period;
        }
    }
    let _ = dev.write_force(Vec3::zeros());
    res.energy = dev.port_energy();
    res.allocations = crate::rt::alloc::thread_system_calls() - sys0;
    crate::rt::alloc::leave_rt();
    (res, dev)
}
