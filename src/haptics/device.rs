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

/// One pose sample from the device, in the device's frame (SI units; see
/// [`crate::haptics::frame`] for the map to the scene).
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
    /// The stylus's three gimbal angles (rad), in the order OpenHaptics
    /// reports `HD_CURRENT_GIMBAL_ANGLES` (joints 4, 5, 6 of the arm: the two
    /// gimbal joints, then the roll of the stylus about its own axis, see
    /// [`GIMBAL_ROLL`]). Zero from a backend that does not measure them.
    pub gimbal_rad: [f64; 3],
}

/// Index of the stylus roll in [`DeviceSample::gimbal_rad`].
pub const GIMBAL_ROLL: usize = 2;

/// Largest magnitude (rad) a gimbal angle may report: one full turn either
/// way. No Touch X gimbal joint turns further; a larger value is a device
/// fault, as a NaN pose is.
pub const GIMBAL_LIMIT_RAD: f64 = 2.0 * std::f64::consts::PI;

/// `a` (rad) wrapped to (−π, π]; NaN stays NaN.
pub fn wrap_angle(a: f64) -> f64 {
    use std::f64::consts::{PI, TAU};
    let w = a - TAU * (a / TAU).round();
    if w <= -PI {
        w + TAU
    } else {
        w
    }
}

/// Default age (s) after which a device side stops applying a force
/// command (`watchdog.command_timeout_ms`): ten periods of the 1 kHz loop.
pub const DEFAULT_COMMAND_TIMEOUT_S: f64 = 0.010;

/// The force a device-side servo applies for the command `f` (N ×3, then
/// the time it was written, s) at time `now_s`: the command, or zero once it
/// is older than `timeout_s`. A stalled writer must not leave a force
/// playing; a command with a non-finite time plays nothing, and one from a
/// clock that went back keeps playing. Used by the OpenHaptics servo
/// callback; the simulated Touch X counts the same age in sub-steps.
pub fn live_command(f: [f64; 4], now_s: f64, timeout_s: f64) -> [f64; 3] {
    if now_s - f[3] <= timeout_s {
        [f[0], f[1], f[2]]
    } else {
        [0.0; 3]
    }
}

impl DeviceSample {
    /// A sample at rest at the origin.
    pub const REST: DeviceSample = DeviceSample {
        position: Vec3::new(0.0, 0.0, 0.0),
        velocity: Vec3::new(0.0, 0.0, 0.0),
        buttons: 0,
        time_s: 0.0,
        seq: 0,
        gimbal_rad: [0.0; 3],
    };

    /// Sample `seq` at `time_s` (s) of a hand held still at `position` (m,
    /// the device frame), no button pressed.
    pub fn held_at(seq: u64, time_s: f64, position: Vec3) -> DeviceSample {
        DeviceSample {
            seq,
            time_s,
            position,
            ..DeviceSample::REST
        }
    }

    /// Whether every number in the sample (gimbal angles included) is finite.
    pub fn is_finite(&self) -> bool {
        self.position.iter().chain(self.velocity.iter()).all(|v| v.is_finite())
            && self.time_s.is_finite()
            && self.gimbal_rad.iter().all(|a| a.is_finite())
    }

    /// Whether every gimbal angle is finite and within
    /// ±[`GIMBAL_LIMIT_RAD`].
    pub fn gimbal_in_range(&self) -> bool {
        self.gimbal_rad
            .iter()
            .all(|a| a.is_finite() && a.abs() <= GIMBAL_LIMIT_RAD)
    }

    /// Whether the sample can be used: every number finite and the gimbal
    /// angles in range. Anything else is a device fault (force to zero).
    pub fn is_valid(&self) -> bool {
        self.is_finite() && self.gimbal_in_range()
    }

    /// The stylus roll (rad), [`DeviceSample::gimbal_rad`]`[`[`GIMBAL_ROLL`]`]`.
    pub fn roll_rad(&self) -> f64 {
        self.gimbal_rad[GIMBAL_ROLL]
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_servo_stops_playing_a_stale_command() {
        let f = [1.0, -2.0, 3.0, 10.0];
        assert_eq!(live_command(f, 10.004, 0.01), [1.0, -2.0, 3.0]);
        assert_eq!(live_command(f, 10.011, 0.01), [0.0; 3]);
        // A clock that went back keeps the command.
        assert_eq!(live_command(f, 9.0, 0.01), [1.0, -2.0, 3.0]);
        // A command with a NaN time plays nothing.
        assert_eq!(live_command([1.0, 1.0, 1.0, f64::NAN], 1.0, 0.01), [0.0; 3]);
    }
}
