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
//! That is the default coupling, [`Coupling::GaussSeidel`]. The other,
//! [`Coupling::Lagged`] (block Jacobi), hands the catheter the wire's
//! contact forces of the period before, so that both rods step from the
//! state at the period's start only, and their two steps can run at once
//! on two cores ([`Coaxial::step_on`] with a [`CatheterWorker`]).
//!
//! Why this shape, and the measured cost: docs/CATHETER.md. Every buffer
//! is sized at construction: a step allocates nothing.

use super::lumen::Lumen;
use super::rod::{StepReport, Wire, WireContact, WireError, WireFault};
use super::WireParams;
use crate::config::{Checker, ConfigError};
use crate::math::Vec3;
use crate::rt::reserved::Reserved;
use std::path::Path;

mod worker;
pub use worker::CatheterWorker;

/// How the two rods' steps of one period depend on each other.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Coupling {
    /// Block Gauss–Seidel: the wire steps inside the catheter as the last
    /// period left it, then the catheter under the wire's contact forces of
    /// this period. The two steps run one after the other.
    #[default]
    GaussSeidel,
    /// Block Jacobi: the wire steps as in [`Coupling::GaussSeidel`], the
    /// catheter under the wire's contact forces (and with its inserted
    /// length) of the period before. Both steps start from the period's
    /// state only, so they may run at once ([`Coaxial::step_on`]). The step
    /// after construction or a restore, which has no forces of a period
    /// before, is a Gauss–Seidel one (docs/CATHETER.md "The lagged
    /// coupling").
    Lagged,
}

impl Coupling {
    /// Both, by name.
    pub const ALL: [Coupling; 2] = [Coupling::GaussSeidel, Coupling::Lagged];

    /// Its name in configuration files and reports (`gauss_seidel`,
    /// `lagged`).
    pub fn name(self) -> &'static str {
        match self {
            Coupling::GaussSeidel => "gauss_seidel",
            Coupling::Lagged => "lagged",
        }
    }

    /// The coupling named `name` ([`Coupling::name`]).
    pub fn from_name(name: &str) -> Option<Coupling> {
        Coupling::ALL.into_iter().find(|c| c.name() == name)
    }
}

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
    /// The catheter's step panicked on its worker thread
    /// ([`Coaxial::step_on`]); the catheter's state is then unusable.
    #[error("catheter: its step panicked on the worker thread")]
    Worker,
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
    coupling: Coupling,
    /// The wire's sheath contacts are those of the last period's step on
    /// the pair's present state (false after construction and a restore:
    /// a lagged step then couples as Gauss–Seidel).
    primed: bool,
    /// The wire's contact forces on the catheter, as handed to it (sized
    /// at construction, and so are a clone's).
    loads: Reserved<(Vec3, Vec3)>,
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
        // A wire node touches the catheter at one point at most.
        let loads = Reserved::with_capacity(wire.max_nodes + 2);
        Ok(Coaxial {
            wire: w,
            catheter: c,
            friction: WIRE_CATHETER_FRICTION,
            load_share: LOAD_STIFFNESS_SHARE,
            coupling: Coupling::GaussSeidel,
            primed: false,
            loads,
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

    /// Sets how the two rods' steps depend on each other ([`Coupling`];
    /// Gauss–Seidel by default). Takes effect at the next step.
    pub fn set_coupling(&mut self, coupling: Coupling) {
        self.coupling = coupling;
    }

    /// How the two rods' steps depend on each other.
    pub fn coupling(&self) -> Coupling {
        self.coupling
    }

    /// Advances the pair by one time step against the vessel `lumen`, in
    /// this thread: with [`Coupling::GaussSeidel`] the wire inside the
    /// catheter as it is, then the catheter under the wire's forces and
    /// with its stiffness (module docs); with [`Coupling::Lagged`] the
    /// same two steps from the period's state, the catheter under the
    /// wire's forces of the period before ([`Coaxial::step_on`] runs them
    /// at once, with the same result to the bit).
    pub fn step(&mut self, lumen: &dyn Lumen) -> Result<CoaxialReport, CoaxialFault> {
        if self.lagging() {
            self.hand_over(true);
            let rw = self.wire.step(lumen);
            let rc = self.catheter.step(lumen).map_err(CoaxialFault::Catheter);
            return self.finish(rw, rc);
        }
        self.set_wire_sheath();
        let rw = self.wire.step(lumen);
        if rw.is_err() {
            return self.finish(rw, Ok(StepReport::default()));
        }
        self.hand_over(false);
        let rc = self.catheter.step(lumen).map_err(CoaxialFault::Catheter);
        self.finish(rw, rc)
    }

    /// [`Coaxial::step`] with the catheter's step of a lagged coupling on
    /// `worker`'s thread while the wire steps in this one: the coupled
    /// step takes about the longer of the two rods' steps instead of their
    /// sum. The result is the one [`Coaxial::step`] gives to the bit (both
    /// rods' steps depend on their inputs only, unless a time limit,
    /// `residual_time_limit_us`, cuts one short). A Gauss–Seidel step (the
    /// coupling, or a lagged one's first after construction or a restore)
    /// runs in this thread. Neither thread allocates, locks or blocks in
    /// it: this one waits for the worker spinning ([`CatheterWorker`]).
    pub fn step_on<L: Lumen + Sync>(
        &mut self,
        lumen: &L,
        worker: &mut CatheterWorker,
    ) -> Result<CoaxialReport, CoaxialFault> {
        if !self.lagging() {
            return self.step(lumen);
        }
        self.hand_over(true);
        let pending = worker.start(&mut self.catheter, lumen);
        let rw = self.wire.step(lumen);
        let rc = match pending.finish() {
            Some(r) => r.map_err(CoaxialFault::Catheter),
            None => Err(CoaxialFault::Worker),
        };
        self.finish(rw, rc)
    }

    fn lagging(&self) -> bool {
        self.coupling == Coupling::Lagged && self.primed
    }

    /// The wire inside the catheter as the catheter now stands.
    fn set_wire_sheath(&mut self) {
        let c = &self.catheter;
        self.wire.set_sheath(
            c.positions(),
            c.velocities(),
            c.inserted(),
            0.5 * c.params().inner_diameter_m,
            self.friction,
        );
    }

    /// The exchange between the rods before the catheter's step: the
    /// wire's contact forces on the catheter (equal and opposite), their
    /// stabilising spring and the wire as the catheter's core. `lagged`:
    /// before the wire's step too (the forces and the wire's inserted
    /// length are the last period's), so the wire is also put inside the
    /// catheter as it stands. The spring stays anchored at the catheter's
    /// state at the step's start, as in the Gauss–Seidel step: anchored
    /// where the wire found the forces (a period earlier) it resisted the
    /// catheter twice over, and the pair settled more slowly
    /// (docs/CATHETER.md "The lagged coupling").
    fn hand_over(&mut self, lagged: bool) {
        self.loads.clear();
        for c in self.wire.sheath_contacts() {
            if self.loads.len() == self.loads.capacity() {
                break;
            }
            self.loads.push((c.point, -(c.normal * c.normal_force + c.friction)));
        }
        if lagged {
            self.set_wire_sheath();
        }
        self.catheter.set_point_loads(self.loads.iter().copied());
        self.catheter
            .set_point_load_stiffness(self.load_share * self.wire.params().contact_stiffness_n_per_m);
        self.catheter.set_core(Some((self.wire.params(), self.wire.inserted())));
    }

    /// The pair's report from its rods' steps (the wire's fault first).
    fn finish(
        &mut self,
        rw: Result<StepReport, WireFault>,
        rc: Result<StepReport, CoaxialFault>,
    ) -> Result<CoaxialReport, CoaxialFault> {
        self.primed = false;
        let rw = rw.map_err(CoaxialFault::Wire)?;
        let rc = rc?;
        let mut normal = 0.0;
        for k in self.wire.sheath_contacts() {
            normal += k.normal_force;
        }
        self.primed = true;
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
        self.primed = false;
    }
}
