//! The haptic device abstraction: read a pose sample, write a force. Every
//! backend works in SI units (m, m/s, N, s); millimetre devices convert at
//! their own edge.
//!
//! Contract for backends: [`HapticDevice::read`] and [`HapticDevice::write_force`]
//! are called from the 1 kHz device I/O thread (or from the device's own
//! servo callback) and must not allocate, lock or block after
//! [`HapticDevice::start`]. A force the device cannot render is saturated by
//! the backend, never passed through.

use crate::math::Vec3;

/// One pose sample from the device, in the service's frame (SI units).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DeviceSample {
    /// Stylus tip position (m).
    pub position: Vec3,
    /// Stylus tip velocity (m/s).
    pub velocity: Vec3,
    /// Button bits (bit 0 = first button).
    pub buttons: u32,
    /// Time of the sample on the service's monotonic clock (s since the
    /// service's epoch, see [`crate::rt::clock`]).
    pub time_s: f64,
    /// Sequence number, incremented by the backend per fresh sample; a
    /// repeated number means no new data arrived.
    pub seq: u64,
}

impl DeviceSample {
    /// A sample at rest at the origin.
    pub const REST: DeviceSample = DeviceSample {
        position: Vec3::new(0.0, 0.0, 0.0),
        velocity: Vec3::new(0.0, 0.0, 0.0),
        buttons: 0,
        time_s: 0.0,
        seq: 0,
    };

    /// Whether every number in the sample is finite.
    pub fn is_finite(&self) -> bool {
        self.position.iter().chain(self.velocity.iter()).all(|v| v.is_finite()) && self.time_s.is_finite()
    }
}

/// Why a device operation failed. Small and `Copy`: returned from the RT
/// path without allocating.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum DeviceError {
    /// No fresh sample within the backend's timeout (device silent).
    #[error("the device sent no fresh sample in time")]
    Stale,
    /// The device (or the bridge peer) reported a communication error.
    #[error("device communication error (code {0})")]
    Comm(i32),
    /// The device reported a fault (e.g. over-temperature, over-force).
    #[error("device fault (code {0})")]
    Fault(i32),
    /// The device sent a non-finite or out-of-workspace value.
    #[error("the device sent an invalid value")]
    BadData,
    /// The device could not be opened or started.
    #[error("the device could not be started (code {0})")]
    Start(i32),
}

/// A haptic device: a pose source and a force sink.
pub trait HapticDevice: Send {
    /// Backend name for reports ("touchx-sim", "udp", "openhaptics").
    fn name(&self) -> &'static str;
    /// Starts the device (opens it, enables force output at zero). Called
    /// once before the loop; may allocate.
    fn start(&mut self) -> Result<(), DeviceError>;
    /// The latest pose sample. `now_s` is the caller's monotonic time (s),
    /// which simulated backends use to advance their own dynamics.
    fn read(&mut self, now_s: f64) -> Result<DeviceSample, DeviceError>;
    /// Commands a force (N) at the stylus tip, held until the next call.
    /// The backend saturates it to the device's limits and returns the force
    /// actually commanded.
    fn write_force(&mut self, force: Vec3) -> Result<Vec3, DeviceError>;
    /// Sets the force to zero and stops the device. Called once at the end,
    /// and on any fatal error; must be safe to call twice.
    fn stop(&mut self);
    /// Energy exchanged at the device port so far, where the backend knows
    /// it (the simulated device integrates it with its true, sub-step
    /// velocity). Real devices return `None`: they only know measured
    /// velocity, which the passivity observer uses itself.
    fn port_energy(&self) -> Option<PortEnergy> {
        None
    }
}

/// Energy bookkeeping at the device port (J), from the device force `F` on
/// the stylus and the stylus velocity `v`: `delivered_j` = ∫ max(F·v, 0) dt is
/// the work the device did on the hand, `absorbed_j` = ∫ max(−F·v, 0) dt the
/// work the hand did against the device. A passive rendering keeps
/// `delivered_j − absorbed_j` ≤ the initial energy tank.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct PortEnergy {
    /// Work done by the device on the hand (J, ≥ 0).
    pub delivered_j: f64,
    /// Work done by the hand against the device (J, ≥ 0).
    pub absorbed_j: f64,
}

impl PortEnergy {
    /// Net energy delivered to the hand (J): `delivered_j − absorbed_j`.
    pub fn net_delivered_j(&self) -> f64 {
        self.delivered_j - self.absorbed_j
    }
}
