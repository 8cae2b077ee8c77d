//! Boundary conditions and external loads for the implicit step.
//!
//! - Fixed (Dirichlet) nodes: a list of node indices held at zero
//!   displacement and zero velocity. Scenes build it from named node sets or
//!   with [`nodes_in_box`].
//! - Nodal forces: a force vector (N, applied to *each* listed node) scaled
//!   by a [`TimeProfile`].
//! - Gravity: f_i = m_i g with the lumped mass of the integrator.
//! - Luminal pressure ([`super::pressure`]): a follower load on the inner
//!   wall, evaluated at every Newton iterate with its load stiffness.

use super::pressure::LuminalPressure;
use crate::math::Vec3;
use crate::mesh::TetMesh;
use crate::model::BlockTangent;

/// How a nodal load's force vector is scaled in time: f(t) = s(t) · F.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum TimeProfile {
    /// s(t) = 0 for t < `from_t0`, 1 for t ≥ `from_t0` (a step switched on
    /// at `from_t0`, s).
    Constant {
        /// Switch-on time (s).
        from_t0: f64,
    },
    /// s(t) = 0 for t ≤ t0, (t − t0)/(t1 − t0) on [t0, t1], 1 for t ≥ t1. With
    /// t1 ≤ t0 it is a step at t0 (s = 1 for t ≥ t0).
    Ramp {
        /// Start of the ramp (s).
        t0: f64,
        /// End of the ramp (s).
        t1: f64,
    },
    /// s(t) = sin(2π · freq_hz · t + phase), from t = 0 on (phase in rad).
    Sine {
        /// Frequency (Hz).
        freq_hz: f64,
        /// Phase (rad).
        phase: f64,
    },
}

impl TimeProfile {
    /// The scale s(t).
    pub fn scale(&self, t: f64) -> f64 {
        match *self {
            TimeProfile::Constant { from_t0 } => {
                if t >= from_t0 {
                    1.0
                } else {
                    0.0
                }
            }
            TimeProfile::Ramp { t0, t1 } => {
                if t < t0 {
                    0.0
                } else if t1 <= t0 || t >= t1 {
                    1.0
                } else {
                    (t - t0) / (t1 - t0)
                }
            }
            TimeProfile::Sine { freq_hz, phase } => (2.0 * std::f64::consts::PI * freq_hz * t + phase).sin(),
        }
    }

    fn is_finite(&self) -> bool {
        match *self {
            TimeProfile::Constant { from_t0 } => from_t0.is_finite(),
            TimeProfile::Ramp { t0, t1 } => t0.is_finite() && t1.is_finite(),
            TimeProfile::Sine { freq_hz, phase } => freq_hz.is_finite() && phase.is_finite(),
        }
    }
}

/// A force applied to each of a list of nodes, scaled in time.
#[derive(Debug, Clone, PartialEq)]
pub struct NodalLoad {
    /// Loaded nodes.
    pub nodes: Vec<u32>,
    /// Force applied to each node at full scale (N).
    pub force: Vec3,
    /// Time scaling.
    pub profile: TimeProfile,
}

/// Everything external that pushes on the tissue.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Loads {
    /// Nodal forces.
    pub nodal: Vec<NodalLoad>,
    /// Gravitational acceleration (m/s²), applied as m_i g with the lumped
    /// mass; zero for none.
    pub gravity: Vec3,
    /// Blood pressure on the lumen, if any: it depends on the displacement,
    /// so the integrator evaluates it at every Newton iterate
    /// ([`Loads::add_follower_forces`]) and adds its load stiffness
    /// ([`Loads::add_follower_stiffness`]).
    pub pressure: Option<LuminalPressure>,
}

/// What is wrong with a set of loads or fixed nodes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LoadError {
    /// A node index is out of range.
    NodeOutOfRange {
        /// Index of the nodal load (or `usize::MAX` for the fixed list).
        load: usize,
        /// The offending node index.
        node: u32,
    },
    /// A force, gravity or profile parameter is not finite.
    NonFinite {
        /// Index of the nodal load (or `usize::MAX` for gravity).
        load: usize,
    },
    /// The pressure schedule gives a non-finite pressure.
    NonFinitePressure,
    /// The pressure load was built for a mesh of another size.
    PressureMesh {
        /// Nodes of the mesh the pressure was built for.
        built_for: usize,
        /// Nodes of the mesh being solved.
        nodes: usize,
    },
}

impl std::fmt::Display for LoadError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match *self {
            LoadError::NodeOutOfRange { load: usize::MAX, node } => write!(f, "fixed node {node} is out of range"),
            LoadError::NodeOutOfRange { load, node } => write!(f, "nodal load {load}: node {node} is out of range"),
            LoadError::NonFinite { load: usize::MAX } => write!(f, "gravity is not finite"),
            LoadError::NonFinitePressure => write!(f, "the pressure is not finite"),
            LoadError::NonFinite { load } => write!(f, "nodal load {load}: force or profile is not finite"),
            LoadError::PressureMesh { built_for, nodes } => write!(
                f,
                "the pressure load was built for a mesh of {built_for} nodes, not {nodes}"
            ),
        }
    }
}

impl Loads {
    /// No loads.
    pub fn none() -> Loads {
        Loads::default()
    }

    /// Checks node indices against `num_nodes` and that every number is finite.
    pub fn validate(&self, num_nodes: usize) -> Result<(), LoadError> {
        if !self.gravity.iter().all(|c| c.is_finite()) {
            return Err(LoadError::NonFinite { load: usize::MAX });
        }
        for (k, l) in self.nodal.iter().enumerate() {
            if !(l.force.iter().all(|c| c.is_finite()) && l.profile.is_finite()) {
                return Err(LoadError::NonFinite { load: k });
            }
            if let Some(&node) = l.nodes.iter().find(|&&i| i as usize >= num_nodes) {
                return Err(LoadError::NodeOutOfRange { load: k, node });
            }
        }
        if let Some(p) = &self.pressure {
            if p.num_nodes() != num_nodes {
                return Err(LoadError::PressureMesh {
                    built_for: p.num_nodes(),
                    nodes: num_nodes,
                });
            }
            if !(0..8).all(|k| p.schedule.pressure_at(k as f64 * 0.1).is_finite()) {
                return Err(LoadError::NonFinitePressure);
            }
        }
        Ok(())
    }

    /// Adds the displacement-dependent (follower) forces at time `t` and
    /// displacement `u` into `out`: the luminal pressure on the deformed
    /// wall.
    pub fn add_follower_forces(&self, t: f64, u: &[Vec3], out: &mut [Vec3]) {
        if let Some(p) = &self.pressure {
            p.add_forces(p.schedule.pressure_at(t), u, out);
        }
    }

    /// Adds the load stiffness −∂f/∂u of the follower forces at time `t` and
    /// displacement `u` into `k` (its symmetric part, or nothing: see
    /// [`super::pressure::PressureTangent`]).
    pub fn add_follower_stiffness(&self, t: f64, u: &[Vec3], k: &mut BlockTangent) {
        if let Some(p) = &self.pressure {
            p.add_stiffness(p.schedule.pressure_at(t), u, k);
        }
    }

    /// Adds the external force at time `t` into `out` (nodes must have been
    /// validated; out-of-range ones are skipped).
    pub fn add_forces(&self, t: f64, mass: &[f64], out: &mut [Vec3]) {
        if self.gravity != Vec3::zeros() {
            for (o, m) in out.iter_mut().zip(mass) {
                *o += *m * self.gravity;
            }
        }
        for l in &self.nodal {
            let f = l.profile.scale(t) * l.force;
            for &i in &l.nodes {
                if let Some(o) = out.get_mut(i as usize) {
                    *o += f;
                }
            }
        }
    }
}

/// Checks fixed node indices against `num_nodes`.
pub fn validate_fixed(fixed: &[u32], num_nodes: usize) -> Result<(), LoadError> {
    match fixed.iter().find(|&&i| i as usize >= num_nodes) {
        Some(&node) => Err(LoadError::NodeOutOfRange { load: usize::MAX, node }),
        None => Ok(()),
    }
}

/// Nodes whose rest position lies in the closed box [min, max] (m), sorted.
pub fn nodes_in_box(mesh: &TetMesh, min: Vec3, max: Vec3) -> Vec<u32> {
    mesh.rest()
        .iter()
        .enumerate()
        .filter(|(_, p)| (0..3).all(|k| p[k] >= min[k] && p[k] <= max[k]))
        .map(|(i, _)| i as u32)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn profiles() {
        let c = TimeProfile::Constant { from_t0: 0.5 };
        assert_eq!(c.scale(0.49), 0.0);
        assert_eq!(c.scale(0.5), 1.0);
        let r = TimeProfile::Ramp { t0: 1.0, t1: 3.0 };
        assert_eq!(r.scale(0.0), 0.0);
        assert_eq!(r.scale(2.0), 0.5);
        assert_eq!(r.scale(5.0), 1.0);
        let step = TimeProfile::Ramp { t0: 1.0, t1: 1.0 };
        assert_eq!(step.scale(0.99), 0.0);
        assert_eq!(step.scale(1.0), 1.0);
        let s = TimeProfile::Sine {
            freq_hz: 2.0,
            phase: std::f64::consts::FRAC_PI_2,
        };
        assert!((s.scale(0.0) - 1.0).abs() < 1e-15);
        assert!((s.scale(0.25) + 1.0).abs() < 1e-12);
    }

    #[test]
    fn profile_from_toml() {
        #[derive(serde::Deserialize)]
        struct W {
            p: TimeProfile,
        }
        let w: W = toml::from_str("p = { kind = \"ramp\", t0 = 0.0, t1 = 0.1 }").unwrap();
        assert_eq!(w.p, TimeProfile::Ramp { t0: 0.0, t1: 0.1 });
        assert!(toml::from_str::<W>("p = { kind = \"sine\", freq_hz = 1.0 }").is_err());
    }
}
