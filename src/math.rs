//! The two small fixed-size types every module shares: [`Vec3`] (positions,
//! displacements, forces, in SI units) and [`Mat3`] (3×3 tensors and tangent
//! blocks). Kept apart from `mesh` and `model` so that neither has to import
//! the other for a type alias.

use nalgebra::{Matrix3, Vector3};

/// A 3-vector of f64 (positions, displacements, forces: SI units).
pub type Vec3 = Vector3<f64>;

/// A 3×3 f64 matrix (tensors, tangent blocks).
pub type Mat3 = Matrix3<f64>;
