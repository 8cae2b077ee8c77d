//! A guidewire inside a catheter, both entering at one access point along
//! one insertion axis, stepped together: [`Coaxial`].
//!
//! Each step is one pass of a partitioned (block Gauss–Seidel) coupling
//! between the two rods, each taking its own implicit step:
//!
//! 1. the wire, with the catheter's current centreline as a moving lumen
//!    for its nodes inside the catheter (a tube of the catheter's inner
//!    radius, friction measured against the catheter's motion), and the
//!    vessel for the rest;
//! 2. the catheter, against the vessel, loaded by the opposite of the
//!    wire's contact forces on its inner wall (normal and friction, dead
//!    loads), and stiffened where the wire lies inside it by the wire's
//!    bending stiffness acting on the change of the centreline's
//!    curvature over the step.
//!
//! Why this shape, and the measured cost: docs/CATHETER.md. Every buffer
//! is sized at construction: a step allocates nothing.

use super::lumen::Lumen;
use super::rod::{StepReport, Wire, WireContact, WireError, WireFault};
use super::WireParams;
use crate::config::{Checker, ConfigError};
use crate::math::Vec3;
use std::path::Path;

/// The default friction of the wire against the catheter's lumen (a
/// PTFE-lined lumen).
pub const WIRE_CATHETER_FRICTION: f64 = 0.05;

/// The share of the wire's contact penalty with which the wire's contact
/// forces on the catheter resist the catheter's motion over its step: the
/// stabilising spring, on at this share by default
/// ([`Coaxial::set_load_stiffness_share`]). The wire, held through the catheter's step, pushes back at
/// most at its penalty's stiffness K_w; with a stiffness K̃ on the change,
/// each pass multiplies the error by (K̃ − K_w) / (K_c + K̃), below one in
/// size for any K̃ above K_w / 2. As dead loads alone (K̃ = 0) the factor
/// is −K_w / K_c: a curved wire tip inside a shaped catheter's soft tip
/// swung it further each step, and the pair diverged within tens of steps.
/// The price: while the wire and the catheter move together sideways, the
/// spring also resists the catheter's share of that motion, so the pair
/// settles more slowly where the wire is soft.
pub const LOAD_STIFFNESS_SHARE: f64 = 0.6;

/// Errors building a [`Coaxial`].
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CoaxialError {
    /// The wire's parameters or hub are unusable.
    #[error("wire: {0}")]
    Wire(WireError),
    /// The catheter's parameters or hub are unusable.
    #[error("catheter: {0}")]
    Catheter(WireError),
    /// The two do not fit together (the wire does not pass the lumen).
    #[error(transparent)]
    Fit(#[from] ConfigError),
}

/// Which rod's step failed (the pair is then unusable: restore the last
/// good state of both, [`Coaxial::restore_good_state`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum CoaxialFault {
    /// The wire's step.
    #[error("wire: {0}")]
    Wire(WireFault),
    /// The catheter's step.
    #[error("catheter: {0}")]
    Catheter(WireFault),
}

/// What a coupled step did.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct CoaxialReport {
    /// The wire's step (its `contacts` are with the vessel, its
    /// `sheath_contacts` with the catheter's inner wall).
    pub wire: StepReport,
    /// The catheter's step (its `contacts` are with the vessel).
    pub catheter: StepReport,
    /// Evaluations of the two rods' incremental potentials together.
    pub evaluations: usize,
    /// The sum of the wire's normal forces on the catheter's inner wall (N).
    pub coaxial_normal_force_n: f64,
}

/// A guidewire inside a catheter. Build with [`Coaxial::new`], drive both
/// hubs with [`Coaxial::set_hubs`], advance with [`Coaxial::step`].
#[derive(Debug, Clone)]
pub struct Coaxial {
    wire: Wire,
    catheter: Wire,
    friction: f64,
    /// The stabilising spring's share of the wire's penalty (0: off).
    load_share: f64,
}

impl Coaxial {
    /// A wire with `wire` parameters inside a catheter with `catheter`
    /// parameters, both hubs at `access_point` along the insertion `axis`,
    /// `wire_inserted_m` and `catheter_inserted_m` inserted, laid straight.
    /// The wire's diameter must be below the catheter's inner diameter.
    pub fn new(
        wire: &WireParams,
        catheter: &WireParams,
        access_point: Vec3,
        axis: Vec3,
        wire_inserted_m: f64,
        catheter_inserted_m: f64,
    ) -> Result<Coaxial, CoaxialError> {
        if wire.diameter_m.partial_cmp(&catheter.inner_diameter_m) != Some(std::cmp::Ordering::Less) {
            return Err(Checker::new(Path::new("(catheter)"))
                .err(
                    "inner_diameter_m",
                    format!(
                        "{} m: must exceed the wire's diameter_m ({} m) for the wire to pass",
                        catheter.inner_diameter_m, wire.diameter_m
                    ),
                )
                .into());
        }
        let mut w = Wire::new(wire, access_point, axis, wire_inserted_m).map_err(CoaxialError::Wire)?;
        let mut c = Wire::new(catheter, access_point, axis, catheter_inserted_m).map_err(CoaxialError::Catheter)?;
        // The buckling check judges one rod's own static Hessian; in the
        // pair each rod's stiffness leans on the other's (the sheath's
        // wall, the core's stiffness), which that Hessian does not hold, so
        // its negative curvature is not the pair's (docs/CATHETER.md).
        w.set_buckling_check(false);
        c.set_buckling_check(false);
        Ok(Coaxial {
            wire: w,
            catheter: c,
            friction: WIRE_CATHETER_FRICTION,
            load_share: LOAD_STIFFNESS_SHARE,
        })
    }

    /// Drives both hubs (inserted lengths in m, rolls in rad), for the next
    /// step; each is clamped as [`Wire::set_hub`] clamps it.
    pub fn set_hubs(
        &mut self,
        wire_inserted_m: f64,
        wire_roll_rad: f64,
        catheter_inserted_m: f64,
        catheter_roll_rad: f64,
    ) {
        self.wire.set_hub(wire_inserted_m, wire_roll_rad);
        self.catheter.set_hub(catheter_inserted_m, catheter_roll_rad);
    }

    /// The friction coefficient of the wire against the catheter's inner
    /// wall (clamped to [0, 2]).
    pub fn set_friction(&mut self, mu: f64) {
        if mu.is_finite() {
            self.friction = mu.clamp(0.0, 2.0);
        }
    }

    /// Sets the stabilising spring with which the wire's contact forces
    /// resist the catheter's motion over its step, at `share` of the wire's
    /// contact penalty ([`LOAD_STIFFNESS_SHARE`], the default and the
    /// service's; 0 turns it off; clamped to [0, 1]). Needed where a shaped
    /// wire tip or a shaped catheter presses the two together; off, a pair
    /// without either settles a gentle shared curve faster (its doc names
    /// the cost).
    pub fn set_load_stiffness_share(&mut self, share: f64) {
        if share.is_finite() {
            self.load_share = share.clamp(0.0, 1.0);
        }
    }

    /// The friction coefficient of the wire against the catheter's inner wall.
    pub fn friction(&self) -> f64 {
        self.friction
    }

    /// Advances the pair by one time step against the vessel `lumen`: the
    /// wire inside the catheter as it is, then the catheter under the
    /// wire's forces and with its stiffness (module docs).
    pub fn step(&mut self, lumen: &dyn Lumen) -> Result<CoaxialReport, CoaxialFault> {
        let c = &self.catheter;
        self.wire.set_sheath(
            c.positions(),
            c.velocities(),
            c.inserted(),
            0.5 * c.params().inner_diameter_m,
            self.friction,
        );
        let rw = self.wire.step(lumen).map_err(CoaxialFault::Wire)?;
        let mut normal = 0.0;
        for k in self.wire.sheath_contacts() {
            normal += k.normal_force;
        }
        // Equal and opposite: the wire's contact forces, on the catheter.
        self.catheter.set_point_loads(
            self.wire
                .sheath_contacts()
                .iter()
                .map(|k| (k.point, -(k.normal * k.normal_force + k.friction))),
        );
        self.catheter
            .set_point_load_stiffness(self.load_share * self.wire.params().contact_stiffness_n_per_m);
        self.catheter.set_core(Some((self.wire.params(), self.wire.inserted())));
        let rc = self.catheter.step(lumen).map_err(CoaxialFault::Catheter)?;
        Ok(CoaxialReport {
            wire: rw,
            catheter: rc,
            evaluations: rw.evaluations + rc.evaluations,
            coaxial_normal_force_n: normal,
        })
    }

    /// The guidewire.
    pub fn wire(&self) -> &Wire {
        &self.wire
    }

    /// The catheter.
    pub fn catheter(&self) -> &Wire {
        &self.catheter
    }

    /// The guidewire, to set loads or friction on it.
    pub fn wire_mut(&mut self) -> &mut Wire {
        &mut self.wire
    }

    /// The catheter, to set loads or friction on it.
    pub fn catheter_mut(&mut self) -> &mut Wire {
        &mut self.catheter
    }

    /// How far the wire's tip lies beyond the catheter's (m, along the
    /// rods; negative: the wire's tip is inside the catheter).
    pub fn wire_lead_m(&self) -> f64 {
        self.wire.inserted() - self.catheter.inserted()
    }

    /// Every contact with the vessel's wall of the last step, the wire's
    /// (where it runs outside the catheter) then the catheter's: the wall
    /// loads on the vessel are their opposites.
    pub fn wall_contacts(&self) -> impl Iterator<Item = &WireContact> {
        self.wire.contacts().iter().chain(self.catheter.contacts())
    }

    /// Whether both rods' states are finite.
    pub fn is_finite(&self) -> bool {
        self.wire.is_finite() && self.catheter.is_finite()
    }

    /// Remembers both rods' states as the last good ones (no allocation).
    pub fn save_good_state(&mut self) {
        self.wire.save_good_state();
        self.catheter.save_good_state();
    }

    /// Returns both rods to their last good states (after a
    /// [`CoaxialFault`]); the hubs keep their commands.
    pub fn restore_good_state(&mut self) {
        self.wire.restore_good_state();
        self.catheter.restore_good_state();
    }
}
