//! The map from the device's frame to the scene's: a rotation, a scale and an
//! offset, configured as a `[device.frame]` table (or any table holding
//! [`DeviceFrameParams`]'s keys).
//!
//! Backends report in the device's own axes, already in SI units: the
//! OpenHaptics frame (x to the user's right, y up, z toward the user,
//! millimetres) becomes metres at the backend's edge ([`HD_LENGTH_M`]), its
//! axes unchanged. This map then takes a device point `p` (m) to the scene:
//!
//! ```text
//! q = offset + scale · R · p
//! ```
//!
//! Velocities and displacements map by `scale · R`; forces back to the device
//! by `scale · Rᵀ`, so that the power at the hand equals the power in the
//! scene (`F_dev · v_dev = F_scene · v_scene`): scaling motion up scales the
//! felt force up by the same factor, and the map neither creates nor destroys
//! energy (the passivity argument of docs/PASSIVITY.md carries over).
//!
//! `R` is built from three angles in degrees about the x, y and z axes,
//! applied in that order to the device vector (`R = Rz · Ry · Rx`, fixed
//! axes). E.g. `rotation_deg = [90, 0, 0]` turns the device's y-up into a
//! z-up scene (device y → scene z, device z → scene −y). The identity
//! rotation with scale 1 is a pure translation: the `device.origin_m` map
//! ([`DeviceFrame::translation`]).

use crate::config::{Checker, ConfigError};
use crate::haptics::device::DeviceSample;
use crate::math::{Mat3, Vec3};
use std::path::Path;

/// Metres per OpenHaptics length unit (the HD API works in millimetres).
pub const HD_LENGTH_M: f64 = 1e-3;

/// The device-to-scene map's keys. [`Default`] is the identity.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct DeviceFrameParams {
    /// Angles (degrees) about the x, y, z axes, applied to the device vector
    /// in that order (`R = Rz · Ry · Rx`).
    pub rotation_deg: [f64; 3],
    /// Scene position (m) of the device origin.
    pub offset_m: [f64; 3],
    /// Scene metres per device metre (motion scaling).
    pub scale: f64,
}

impl Default for DeviceFrameParams {
    fn default() -> Self {
        DeviceFrameParams {
            rotation_deg: [0.0; 3],
            offset_m: [0.0; 3],
            scale: 1.0,
        }
    }
}

impl DeviceFrameParams {
    /// Range checks. `prefix` is prepended to key names (e.g.
    /// `device.frame.`); errors name `path`, the key and the range.
    pub fn validate(&self, path: &Path, prefix: &str) -> Result<(), ConfigError> {
        let c = Checker::new(path);
        for (i, a) in self.rotation_deg.iter().enumerate() {
            c.f64_in(&format!("{prefix}rotation_deg[{i}]"), *a, -360.0, 360.0, "degrees")?;
        }
        for (i, o) in self.offset_m.iter().enumerate() {
            c.f64_in(&format!("{prefix}offset_m[{i}]"), *o, -10.0, 10.0, "m")?;
        }
        c.f64_in(
            &format!("{prefix}scale"),
            self.scale,
            0.01,
            100.0,
            "(scene m per device m)",
        )?;
        Ok(())
    }
}

/// Sine and cosine of an angle in degrees, exact at multiples of 90°.
fn sin_cos_deg(deg: f64) -> (f64, f64) {
    let q = deg / 90.0;
    if q == q.round() {
        match (q.round() as i64).rem_euclid(4) {
            0 => (0.0, 1.0),
            1 => (1.0, 0.0),
            2 => (0.0, -1.0),
            _ => (-1.0, 0.0),
        }
    } else {
        deg.to_radians().sin_cos()
    }
}

/// The device-to-scene map (see the module documentation). Plain data,
/// `Copy`: every method is a few multiplications, no allocation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DeviceFrame {
    rot: Mat3,
    offset: Vec3,
    scale: f64,
}

impl DeviceFrame {
    /// The identity map.
    pub fn identity() -> DeviceFrame {
        DeviceFrame {
            rot: Mat3::identity(),
            offset: Vec3::zeros(),
            scale: 1.0,
        }
    }

    /// The map `params` describe (validate them first; out-of-range values
    /// are used as given).
    pub fn new(params: &DeviceFrameParams) -> DeviceFrame {
        let [ax, ay, az] = params.rotation_deg;
        let (sx, cx) = sin_cos_deg(ax);
        let (sy, cy) = sin_cos_deg(ay);
        let (sz, cz) = sin_cos_deg(az);
        let rx = Mat3::new(1.0, 0.0, 0.0, 0.0, cx, -sx, 0.0, sx, cx);
        let ry = Mat3::new(cy, 0.0, sy, 0.0, 1.0, 0.0, -sy, 0.0, cy);
        let rz = Mat3::new(cz, -sz, 0.0, sz, cz, 0.0, 0.0, 0.0, 1.0);
        DeviceFrame {
            rot: rz * ry * rx,
            offset: Vec3::from(params.offset_m),
            scale: params.scale,
        }
    }

    /// A pure translation: the scene position of the device origin is
    /// `origin` (the map `device.origin_m` describes).
    pub fn translation(origin: Vec3) -> DeviceFrame {
        DeviceFrame {
            offset: origin,
            ..DeviceFrame::identity()
        }
    }

    /// The rotation `R` (device axes to scene axes).
    pub fn rotation(&self) -> Mat3 {
        self.rot
    }

    /// The scene position of the device origin (m).
    pub fn offset(&self) -> Vec3 {
        self.offset
    }

    /// Scene metres per device metre.
    pub fn scale(&self) -> f64 {
        self.scale
    }

    /// A device point (m) in the scene: `offset + scale · R · p`.
    pub fn point_to_scene(&self, p: Vec3) -> Vec3 {
        self.offset + self.rot * p * self.scale
    }

    /// A scene point (m) in the device frame (the inverse of
    /// [`DeviceFrame::point_to_scene`]).
    pub fn point_to_device(&self, q: Vec3) -> Vec3 {
        self.rot.transpose() * (q - self.offset) / self.scale
    }

    /// A device velocity or displacement in the scene: `scale · R · v`.
    pub fn vector_to_scene(&self, v: Vec3) -> Vec3 {
        self.rot * v * self.scale
    }

    /// A scene velocity or displacement in the device frame.
    pub fn vector_to_device(&self, v: Vec3) -> Vec3 {
        self.rot.transpose() * v / self.scale
    }

    /// A scene force (N) as the device must render it: `scale · Rᵀ · f`
    /// (power-preserving).
    pub fn force_to_device(&self, f: Vec3) -> Vec3 {
        self.rot.transpose() * f * self.scale
    }

    /// A device force (N) in the scene (the inverse of
    /// [`DeviceFrame::force_to_device`]).
    pub fn force_to_scene(&self, f: Vec3) -> Vec3 {
        self.rot * f / self.scale
    }

    /// The sample with its position and velocity in the scene; buttons,
    /// time, sequence and gimbal angles unchanged (the gimbal angles are
    /// joint angles of the device, not directions in space).
    pub fn sample_to_scene(&self, s: &DeviceSample) -> DeviceSample {
        DeviceSample {
            position: self.point_to_scene(s.position),
            velocity: self.vector_to_scene(s.velocity),
            ..*s
        }
    }
}

impl Default for DeviceFrame {
    fn default() -> Self {
        DeviceFrame::identity()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quarter_turns_are_exact_and_rotations_proper() {
        let f = DeviceFrame::new(&DeviceFrameParams {
            rotation_deg: [90.0, 0.0, 0.0],
            ..DeviceFrameParams::default()
        });
        assert_eq!(f.vector_to_scene(Vec3::y()), Vec3::z());
        assert_eq!(f.vector_to_scene(Vec3::z()), -Vec3::y());
        let g = DeviceFrame::new(&DeviceFrameParams {
            rotation_deg: [12.0, -47.0, 200.0],
            ..DeviceFrameParams::default()
        });
        let r = g.rotation();
        assert!((r.transpose() * r - Mat3::identity()).norm() < 1e-14);
        assert!((r.determinant() - 1.0).abs() < 1e-14);
    }
}
