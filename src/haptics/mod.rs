//! Haptics: the device abstraction and its backends, contact between the tool
//! and the vessel surface, the passivity QP, and the 1 kHz servo loop that
//! ties them to the reduced model.
//!
//! Not here: thread set-up, clocks and timing statistics ([`crate::rt`]), the
//! service that starts the threads (`service`), the physics itself
//! ([`crate::reduced`], [`crate::model`]).

pub mod contact;
pub mod device;
#[cfg(feature = "openhaptics")]
pub mod openhaptics;
pub mod passivity;
pub mod servo;
pub mod tick;
pub mod touchx;
pub mod udp;

pub use device::{DeviceError, DeviceSample, HapticDevice, PortEnergy};
