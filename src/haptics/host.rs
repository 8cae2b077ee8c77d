//! A host application as the device: a game engine (Unity, Unreal) or any
//! program that owns the haptic device pushes the stylus pose each tick and
//! reads the force back, in process (docs/DRIVING.md "A host application as
//! the device").
//!
//! [`host_device`] returns a [`crate::service::DeviceFactory`] to put in
//! [`crate::service::StartOptions::device`] and the [`HostPort`] the host
//! keeps. [`HostPort::push_pose`] sends a pose down a lock-free ring (it
//! never blocks; a full ring drops the pose and counts it); the device I/O
//! thread pops the newest one each period ([`HostDevice`]) and its force
//! comes back through atomics ([`HostPort::force`]). A pose older than
//! `max_age_s` makes reads stale, and the service's watchdog ramps the force
//! to zero, as for any silent device.

use super::device::{DeviceError, DeviceSample, HapticDevice};
use crate::math::Vec3;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

/// One pose from the host (device frame, SI).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HostPose {
    /// Stylus position (m).
    pub position: [f64; 3],
    /// Gimbal angles (rad, `HD_CURRENT_GIMBAL_ANGLES` order; the roll last).
    pub gimbal_rad: [f64; 3],
    /// Buttons (bit 0 = first; `crate::task::BUTTON_*`).
    pub buttons: u32,
}

/// Why a pose was not sent.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum PushError {
    /// A non-finite number, or a gimbal angle beyond ±2π.
    #[error("the pose has a non-finite number or a gimbal angle beyond ±2π")]
    Invalid,
    /// The ring was full (the device thread is not reading).
    #[error("the pose ring is full (the service's device thread is not reading)")]
    Full,
}

#[derive(Debug, Default)]
struct Shared {
    force: [AtomicU64; 3],
    writes: AtomicU64,
    dropped: AtomicU64,
}

/// The host's end: push poses, read the force.
#[derive(Debug)]
pub struct HostPort {
    ring: Mutex<rtrb::Producer<(HostPose, f64)>>,
    shared: Arc<Shared>,
}

impl HostPort {
    /// Sends a pose, stamped with the service's monotonic clock. Never
    /// blocks (a host on several threads serialises on a mutex the device
    /// thread never takes).
    pub fn push_pose(&self, pose: &HostPose) -> Result<(), PushError> {
        let sample = DeviceSample {
            position: Vec3::from(pose.position),
            gimbal_rad: pose.gimbal_rad,
            ..DeviceSample::REST
        };
        if !sample.is_valid() {
            return Err(PushError::Invalid);
        }
        let now = crate::rt::clock::now_s();
        let mut ring = self.ring.lock().unwrap_or_else(|e| e.into_inner());
        ring.push((*pose, now)).map_err(|_| {
            self.shared.dropped.fetch_add(1, Ordering::Relaxed);
            PushError::Full
        })
    }

    /// The newest force the service commanded (N, device frame); zero before
    /// the first and after the service stopped.
    pub fn force(&self) -> [f64; 3] {
        [0, 1, 2].map(|k| f64::from_bits(self.shared.force[k].load(Ordering::Acquire)))
    }

    /// Forces written so far, and poses dropped for a full ring.
    pub fn counters(&self) -> (u64, u64) {
        (
            self.shared.writes.load(Ordering::Relaxed),
            self.shared.dropped.load(Ordering::Relaxed),
        )
    }
}

/// The service's end: a [`HapticDevice`] fed by the host.
pub struct HostDevice {
    ring: rtrb::Consumer<(HostPose, f64)>,
    shared: Arc<Shared>,
    last: Option<(DeviceSample, f64)>,
    seq: u64,
    max_age_s: f64,
    max_force_n: f64,
}

/// Poses the ring holds (a host pushing at 1 kHz fills it in 64 ms).
pub const RING: usize = 64;

impl HostDevice {
    /// A device fed by the returned port; forces are clamped to
    /// `max_force_n`, a pose older than `max_age_s` is stale.
    pub fn new(max_force_n: f64, max_age_s: f64) -> (HostDevice, HostPort) {
        let (tx, rx) = rtrb::RingBuffer::new(RING);
        let shared = Arc::new(Shared::default());
        (
            HostDevice {
                ring: rx,
                shared: shared.clone(),
                last: None,
                seq: 0,
                max_age_s,
                max_force_n,
            },
            HostPort {
                ring: Mutex::new(tx),
                shared,
            },
        )
    }

    fn set_force(&self, f: Vec3) {
        for k in 0..3 {
            self.shared.force[k].store(f[k].to_bits(), Ordering::Release);
        }
    }
}

impl HapticDevice for HostDevice {
    fn name(&self) -> &'static str {
        "host"
    }

    fn start(&mut self) -> Result<(), DeviceError> {
        self.set_force(Vec3::zeros());
        Ok(())
    }

    fn read(&mut self, now_s: f64) -> Result<DeviceSample, DeviceError> {
        let mut newest = None;
        while let Ok(p) = self.ring.pop() {
            newest = Some(p);
        }
        if let Some((pose, t)) = newest {
            self.seq += 1;
            let position = Vec3::from(pose.position);
            // The velocity by finite difference over the host's own stamps.
            let velocity = match self.last {
                Some((prev, pt)) if t > pt => (position - prev.position) / (t - pt),
                _ => Vec3::zeros(),
            };
            let s = DeviceSample {
                position,
                velocity,
                buttons: pose.buttons,
                time_s: t,
                seq: self.seq,
                gimbal_rad: pose.gimbal_rad,
            };
            self.last = Some((s, t));
        }
        match self.last {
            Some((s, t)) if now_s - t <= self.max_age_s => Ok(s),
            _ => Err(DeviceError::Stale),
        }
    }

    fn write_force(&mut self, force: Vec3) -> Result<Vec3, DeviceError> {
        let n = force.norm();
        let f = if !n.is_finite() {
            Vec3::zeros()
        } else if n > self.max_force_n {
            force * (self.max_force_n / n)
        } else {
            force
        };
        self.set_force(f);
        self.shared.writes.fetch_add(1, Ordering::Relaxed);
        Ok(f)
    }

    fn stop(&mut self) {
        self.set_force(Vec3::zeros());
    }
}

/// A device factory for [`crate::service::StartOptions::device`] and the
/// host's port. Forces are clamped to the configuration's
/// `passivity.peak_force_n`; a pose is stale after the configuration's
/// `watchdog.device_timeout_ms`.
pub fn host_device() -> (crate::service::DeviceFactory, Arc<HostPort>) {
    // The port is made with the device, when the service starts; until then
    // the host holds a slot that the factory fills.
    let slot: Arc<Mutex<Option<HostDevice>>> = Arc::new(Mutex::new(None));
    let (dev, port) = HostDevice::new(7.9, 0.005);
    *slot.lock().unwrap_or_else(|e| e.into_inner()) = Some(dev);
    let port = Arc::new(port);
    let factory = crate::service::DeviceFactory(Arc::new(move |ctx: &crate::service::DeviceContext<'_>| {
        let mut d = slot.lock().unwrap_or_else(|e| e.into_inner()).take().ok_or_else(|| {
            crate::service::ServiceError::Device("the host device was already used by a start".into())
        })?;
        d.max_force_n = ctx.cfg.passivity.peak_force_n;
        d.max_age_s = ctx.cfg.watchdog.device_timeout_ms * 1e-3;
        Ok(Box::new(d) as Box<dyn HapticDevice>)
    }));
    (factory, port)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn poses_go_in_forces_come_back_and_silence_is_stale() {
        let (mut d, port) = HostDevice::new(2.0, 0.005);
        d.start().unwrap();
        assert_eq!(d.read(0.0), Err(DeviceError::Stale));
        let pose = HostPose {
            position: [0.01, 0.0, -0.02],
            gimbal_rad: [0.0, 0.0, 1.0],
            buttons: 4,
        };
        port.push_pose(&pose).unwrap();
        let now = crate::rt::clock::now_s();
        let s = d.read(now).unwrap();
        assert_eq!(s.position, Vec3::new(0.01, 0.0, -0.02));
        assert_eq!((s.buttons, s.roll_rad(), s.seq), (4, 1.0, 1));
        // The same sample again without a new pose; stale after max_age_s.
        assert_eq!(d.read(now + 0.001).unwrap().seq, 1);
        assert_eq!(d.read(now + 0.01), Err(DeviceError::Stale));
        // Forces are clamped and come back.
        let f = d.write_force(Vec3::new(3.0, 4.0, 0.0)).unwrap();
        assert!((f.norm() - 2.0).abs() < 1e-12);
        assert_eq!(port.force(), [f.x, f.y, f.z]);
        d.write_force(Vec3::new(f64::NAN, 0.0, 0.0)).unwrap();
        assert_eq!(port.force(), [0.0; 3]);
        d.stop();
        assert_eq!(port.force(), [0.0; 3]);
        // Bad poses are refused; a full ring drops and counts.
        let bad = HostPose {
            position: [f64::NAN, 0.0, 0.0],
            ..pose
        };
        assert_eq!(port.push_pose(&bad), Err(PushError::Invalid));
        let wild = HostPose {
            gimbal_rad: [0.0, 0.0, 7.0],
            ..pose
        };
        assert_eq!(port.push_pose(&wild), Err(PushError::Invalid));
        for _ in 0..RING {
            port.push_pose(&pose).unwrap();
        }
        assert_eq!(port.push_pose(&pose), Err(PushError::Full));
        assert_eq!(port.counters().1, 1);
    }
}
