//! Haptics: the device abstraction and its backends, the map from the
//! device's frame to the scene's, contact between the tool and the vessel
//! surface, the passivity QP, and the 1 kHz servo loop that ties them to the
//! reduced model. (The guidewire's hub drive, which maps the stylus to
//! insertion and roll, lives with the wire: `wire::drive`.)
//!
//! Not here: thread set-up, clocks and timing statistics ([`crate::rt`]), the
//! service that starts the threads (`service`), the physics itself
//! ([`crate::reduced`], [`crate::model`]).

pub mod contact;
pub mod device;
pub mod frame;
pub mod host;
#[cfg(feature = "openhaptics")]
pub mod openhaptics;
pub mod passivity;
pub mod phases;
pub mod servo;
pub mod tick;
pub mod touchx;
pub mod udp;

pub use device::{DeviceError, DeviceSample, HapticDevice, PortEnergy};
pub use frame::{DeviceFrame, DeviceFrameParams};
