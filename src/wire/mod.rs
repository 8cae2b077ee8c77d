//! The guidewire: an elastic rod with bending and twist, nearly
//! inextensible, driven at its hub (insertion and roll) and touching the
//! vessel's inner wall along its whole length with Coulomb friction.
//!
//! - [`WireParams`]: the wire's configuration (`[wire]` keys), validated with
//!   errors naming the key and the allowed range.
//! - [`rod::Wire`]: the discrete elastic rod (centreline nodes plus one twist
//!   angle per edge), its implicit step, its driving (`set_hub`) and its
//!   contacts; every buffer sized at construction, `step` allocates nothing.
//! - [`lumen`]: what the wire touches (rigid tubes, a moving triangle
//!   surface).
//! - [`band`]: the banded L D Lᵀ solve behind the implicit step.
//! - [`drive`]: the hub drive, stylus to insertion and roll and the wire's
//!   resistance back to the hand (`[wire.drive]` keys).
//! - [`catheter`]: the catheter as the same rod (a braided tube with a
//!   lumen and a shaped tip, [`catheter::TipShape`]).
//! - [`coaxial`]: a wire inside a catheter, stepped together.
//!
//! The formulation and why it was chosen: docs/WIRE.md. The service wiring
//! (report keys, the stream's polyline) lives elsewhere.

pub mod band;
pub mod catheter;
pub mod coaxial;
pub mod coupling;
pub mod drive;
pub mod lumen;
pub mod rod;

pub use drive::{DriveParams, HubCommand, HubDrive};
pub use lumen::{
    CurvedTube, CurvedTubeShape, Lumen, LumenError, NoWall, Opening, StraightTube, TriangleLumen, WallHit,
};
pub use rod::{StepReport, Wire, WireContact, WireError, WireFault};

use crate::config::{load_toml, parse_toml, Checker, ConfigError};
use std::path::Path;

/// The wire's configuration. SI units; defaults describe a 0.035" nitinol
/// guidewire with a soft angled tip.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct WireParams {
    /// Total wire length (m): the inserted length never exceeds it.
    pub length_m: f64,
    /// Outer diameter (m); 0.89 mm is 0.035".
    pub diameter_m: f64,
    /// Inner diameter (m) of a tube, a catheter's lumen; 0 for a solid
    /// wire. The cross-section's area, bending and twisting moments are
    /// those of the annulus (I = π (D⁴ − d⁴) / 64).
    pub inner_diameter_m: f64,
    /// Young's modulus (Pa): nitinol ≈ 40–80 GPa, stainless steel ≈ 200 GPa.
    pub youngs_modulus_pa: f64,
    /// Poisson's ratio, giving the shear modulus G = E / (2 (1 + ν)).
    pub poisson_ratio: f64,
    /// Density (kg/m³).
    pub density_kg_m3: f64,
    /// Length of the soft, pre-shaped distal segment (m); 0 for none.
    pub tip_length_m: f64,
    /// Rest curvature of the distal segment (1/m): a J tip is a half turn
    /// (curvature π / tip length), an angled tip a short segment turning by
    /// its angle (curvature = angle / tip length).
    pub tip_curvature_per_m: f64,
    /// Bending and twisting stiffness of the distal segment relative to the
    /// shaft.
    pub tip_stiffness_factor: f64,
    /// The rest shape of the distal part as arcs of constant curvature,
    /// listed from the tip back (a catheter's shaped tip, see
    /// [`catheter::TipShape`]). Empty: `tip_curvature_per_m` over
    /// `tip_length_m`. Given, it replaces that pair's curvature (the
    /// stiffness factor still applies over `tip_length_m`).
    pub rest_shape: Vec<RestArc>,
    /// Rest length of a segment (m).
    pub segment_length_m: f64,
    /// Capacity in nodes (hub and one node behind it included): the inserted
    /// length is at most about (max_nodes − 1.5) segments.
    pub max_nodes: usize,
    /// Coulomb friction coefficient against the wall.
    pub friction: f64,
    /// Slip per step (m) below which friction is smoothed (a stiffness
    /// μλ/ε sticking, the force μλ slipping): smaller holds a still wire
    /// more firmly but makes fast steps with several contacts harder to
    /// converge (docs/WIRE.md "Friction's smoothing"). Default 1 µm
    /// (1 mm/s at 1 kHz).
    pub friction_smoothing_m: f64,
    /// Penalty stiffness of the wall contact (N/m per node).
    pub contact_stiffness_n_per_m: f64,
    /// Gap (m) at which the contact's penalty begins: its stiffness rises
    /// from 0 there to `contact_stiffness_n_per_m` at touch, so a node that
    /// Newton's last iterate left just short of the wall already sees it
    /// (docs/WIRE.md "Fast pulls", change 3). The force at touch is
    /// k · onset / 2. Default 10 µm; 0 for the plain penalty.
    pub contact_onset_m: f64,
    /// The grip's limit (N): while the wire pushes back on the hand harder
    /// than this, the hub slips and feeds no more wire in (pulling back is
    /// always possible). Keeps a blocked wire's force bounded, as a
    /// clinician's grip or a torque device does.
    pub max_hub_force_n: f64,
    /// Viscous drag of the surrounding fluid (N·s/m² per unit length).
    pub drag_n_s_per_m2: f64,
    /// Time step (s).
    pub dt_s: f64,
    /// Newton iterations per step (the usual count; see
    /// `residual_tolerance_n` for more).
    pub newton_iterations: usize,
    /// Past `newton_iterations`, the step goes on (up to four times as many
    /// iterations, within `max_evaluations`) while some free node's net
    /// force exceeds this (N): a step that ends far from equilibrium hands
    /// its error to the next. Default 0.2 N; 0 stops at
    /// `newton_iterations` (docs/WIRE.md "Fast pulls", change 4).
    pub residual_tolerance_n: f64,
    /// Wall-clock time (µs) after which a step stops going on past
    /// `newton_iterations` for `residual_tolerance_n`: the extra
    /// iterations run only while the step has run less than this, so a
    /// hard step ends in time for its thread's period. 0 (the library's
    /// default): no time limit, a step's outcome depends on nothing but
    /// its inputs; the shipped service file sets 500 µs for its 1 ms wire
    /// thread (docs/WIRE.md "A time limit on the extra iterations").
    pub residual_time_limit_us: f64,
    /// Iterations past `newton_iterations` a step may take at most (for
    /// `residual_tolerance_n`, or a node deep in the wall). A fixed count,
    /// unlike `residual_time_limit_us`, so a scripted run's outcome does
    /// not depend on the machine's load. `None` (the key left out): three
    /// times `newton_iterations` (docs/WIRE.md "A fixed budget of extra
    /// iterations").
    pub max_extra_iterations: Option<usize>,
    /// Evaluations of the incremental potential per step at most (Newton
    /// assemblies, line-search trials and the reactions' evaluation): the
    /// step's cost is about this many evaluations at worst, whatever the
    /// contacts do. A step that spends it ends at its last accepted
    /// iterate (still lower in energy than where it began).
    pub max_evaluations: usize,
    /// How the stylus drives the hub (the `[drive]` table, `[wire.drive]`
    /// in a service file).
    pub drive: DriveParams,
}

impl Default for WireParams {
    fn default() -> Self {
        WireParams {
            length_m: 1.5,
            diameter_m: 0.89e-3,
            inner_diameter_m: 0.0,
            youngs_modulus_pa: 60e9,
            poisson_ratio: 0.33,
            density_kg_m3: 6450.0,
            tip_length_m: 0.02,
            tip_curvature_per_m: 40.0,
            tip_stiffness_factor: 0.1,
            rest_shape: Vec::new(),
            segment_length_m: 3e-3,
            max_nodes: 128,
            friction: 0.1,
            friction_smoothing_m: rod::FRICTION_SMOOTHING_M,
            contact_stiffness_n_per_m: 1e6,
            contact_onset_m: rod::CONTACT_ONSET_M,
            max_hub_force_n: 10.0,
            drag_n_s_per_m2: 1e-3,
            dt_s: 1e-3,
            newton_iterations: 3,
            residual_tolerance_n: rod::RESIDUAL_TOLERANCE_N,
            residual_time_limit_us: 0.0,
            max_extra_iterations: None,
            max_evaluations: 1000,
            drive: DriveParams::default(),
        }
    }
}

impl WireParams {
    /// Reads and validates a TOML file holding these keys.
    pub fn load(path: &Path) -> Result<WireParams, ConfigError> {
        let p: WireParams = load_toml(path)?;
        p.validate(path)?;
        Ok(p)
    }

    /// Parses and validates TOML text (`path` is used in messages).
    pub fn from_toml_str(text: &str, path: &Path) -> Result<WireParams, ConfigError> {
        let p: WireParams = parse_toml(text, path)?;
        p.validate(path)?;
        Ok(p)
    }

    /// Checks every key against its allowed range; errors name `path`, the
    /// key and the range.
    pub fn validate(&self, path: &Path) -> Result<(), ConfigError> {
        let c = Checker::new(path);
        c.f64_in("length_m", self.length_m, 1e-3, 10.0, "m")?;
        c.f64_in("diameter_m", self.diameter_m, 1e-5, 1e-2, "m")?;
        if !(self.inner_diameter_m >= 0.0 && self.inner_diameter_m <= 0.95 * self.diameter_m) {
            return Err(c.err(
                "inner_diameter_m",
                format!(
                    "{}: must be at least 0 and at most 0.95 diameter_m ({} m)",
                    self.inner_diameter_m,
                    0.95 * self.diameter_m
                ),
            ));
        }
        c.f64_in("youngs_modulus_pa", self.youngs_modulus_pa, 1e4, 1e12, "Pa")?;
        c.f64_in("poisson_ratio", self.poisson_ratio, 0.0, 0.5, "")?;
        c.f64_in("density_kg_m3", self.density_kg_m3, 1.0, 3e4, "kg/m³")?;
        c.f64_in("tip_length_m", self.tip_length_m, 0.0, self.length_m, "m")?;
        c.f64_in("tip_curvature_per_m", self.tip_curvature_per_m, -2e3, 2e3, "1/m")?;
        c.f64_in("tip_stiffness_factor", self.tip_stiffness_factor, 1e-4, 10.0, "")?;
        if self.rest_shape.len() > MAX_REST_ARCS {
            return Err(c.err(
                "rest_shape",
                format!("{} arcs: at most {MAX_REST_ARCS}", self.rest_shape.len()),
            ));
        }
        let mut total = 0.0;
        for (k, a) in self.rest_shape.iter().enumerate() {
            let key = |f: &str| format!("rest_shape[{k}].{f}");
            if !(a.length_m > 0.0 && a.length_m <= self.length_m) {
                return Err(c.err(
                    &key("length_m"),
                    format!("{}: must be in (0, length_m = {}] m", a.length_m, self.length_m),
                ));
            }
            if a.curvature_per_m.is_nan() || a.curvature_per_m.abs() > 2e3 {
                return Err(c.err(
                    &key("curvature_per_m"),
                    format!("{}: must be in [-2000, 2000] 1/m", a.curvature_per_m),
                ));
            }
            if a.plane_rad.is_nan() || a.plane_rad.abs() > std::f64::consts::TAU {
                return Err(c.err(&key("plane_rad"), format!("{}: must be in [-2π, 2π] rad", a.plane_rad)));
            }
            total += a.length_m;
        }
        if total > self.length_m {
            return Err(c.err(
                "rest_shape",
                format!("the arcs add up to {total} m, more than length_m ({} m)", self.length_m),
            ));
        }
        c.f64_in("segment_length_m", self.segment_length_m, 1e-4, 0.1, "m")?;
        if self.segment_length_m < self.diameter_m {
            return Err(c.err(
                "segment_length_m",
                format!(
                    "{}: must be at least diameter_m ({} m) and at most 0.1 m",
                    self.segment_length_m, self.diameter_m
                ),
            ));
        }
        c.int_in("max_nodes", self.max_nodes, 4, 4096)?;
        c.f64_in("friction", self.friction, 0.0, 2.0, "")?;
        c.f64_in("friction_smoothing_m", self.friction_smoothing_m, 1e-9, 1e-3, "m")?;
        c.f64_in(
            "contact_stiffness_n_per_m",
            self.contact_stiffness_n_per_m,
            1.0,
            1e9,
            "N/m",
        )?;
        c.f64_in("contact_onset_m", self.contact_onset_m, 0.0, 0.1 * self.diameter_m, "m")?;
        c.f64_in("max_hub_force_n", self.max_hub_force_n, 0.01, 1e4, "N")?;
        c.f64_in("drag_n_s_per_m2", self.drag_n_s_per_m2, 0.0, 1e3, "N·s/m²")?;
        c.f64_in("dt_s", self.dt_s, 1e-6, 0.01, "s")?;
        c.int_in("newton_iterations", self.newton_iterations, 1, 100)?;
        c.int_in("max_evaluations", self.max_evaluations, 3, 10_000)?;
        if let Some(k) = self.max_extra_iterations {
            c.int_in("max_extra_iterations", k, 0, 300)?;
        }
        c.f64_in("residual_tolerance_n", self.residual_tolerance_n, 0.0, 1e3, "N")?;
        c.f64_in(
            "residual_time_limit_us",
            self.residual_time_limit_us,
            0.0,
            1e6 * self.dt_s,
            "µs (at most the time step; 0: no limit)",
        )?;
        self.drive.validate(path, "drive.")?;
        Ok(())
    }

    /// The most iterations a step takes: `newton_iterations` plus
    /// `max_extra_iterations` (three times `newton_iterations` when unset).
    pub fn max_iterations(&self) -> usize {
        self.newton_iterations + self.max_extra_iterations.unwrap_or(3 * self.newton_iterations)
    }

    /// The fastest the hub feeds wire in or out (m/s): a quarter of the
    /// diameter per step (see [`rod::Wire::step`]).
    pub fn max_feed_speed_m_s(&self) -> f64 {
        0.25 * self.diameter_m / self.dt_s
    }

    /// The most that can be inserted (m): the wire's length, or what
    /// `max_nodes` segments hold (the hub edge may stretch to 1.5 segments),
    /// whichever is less.
    pub fn max_inserted_m(&self) -> f64 {
        let h = self.segment_length_m;
        (self.max_nodes.saturating_sub(3) as f64 * h + 1.5 * h).min(self.length_m)
    }

    /// Cross-section area (m²): π (D² − d²) / 4 (d the inner diameter, 0
    /// for a solid wire).
    pub fn area(&self) -> f64 {
        std::f64::consts::PI * (self.diameter_m.powi(2) - self.inner_diameter_m.powi(2)) / 4.0
    }

    /// Polar moment of the cross-section J = π (D⁴ − d⁴) / 32 (m⁴).
    pub fn polar_moment(&self) -> f64 {
        std::f64::consts::PI * (self.diameter_m.powi(4) - self.inner_diameter_m.powi(4)) / 32.0
    }

    /// Bending stiffness E I of the shaft (N·m²), I = π (D⁴ − d⁴) / 64.
    pub fn bending_stiffness(&self) -> f64 {
        self.youngs_modulus_pa * 0.5 * self.polar_moment()
    }

    /// Twisting stiffness G J of the shaft (N·m²), G = E / (2 (1 + ν)).
    pub fn twisting_stiffness(&self) -> f64 {
        self.youngs_modulus_pa / (2.0 * (1.0 + self.poisson_ratio)) * self.polar_moment()
    }

    /// The bending stiffness at material coordinate `u` (arc length from
    /// the tip, m): the shaft's, times `tip_stiffness_factor` within
    /// `tip_length_m` of the tip.
    pub fn bending_stiffness_at(&self, u: f64) -> f64 {
        if u < self.tip_length_m {
            self.bending_stiffness() * self.tip_stiffness_factor
        } else {
            self.bending_stiffness()
        }
    }

    /// The rest shape's turning over material coordinates `a..b` (m from
    /// the tip, a ≤ b): ∫ κ (cos φ, sin φ) du over the arcs of
    /// `rest_shape` (rad, in the material frame's (m1, m2) plane).
    pub fn rest_turning(&self, a: f64, b: f64) -> (f64, f64) {
        let (mut t1, mut t2) = (0.0, 0.0);
        let mut u0 = 0.0;
        for arc in &self.rest_shape {
            let u1 = u0 + arc.length_m;
            let overlap = (b.min(u1) - a.max(u0)).max(0.0);
            if overlap > 0.0 {
                let (s, c) = arc.plane_rad.sin_cos();
                t1 += arc.curvature_per_m * c * overlap;
                t2 += arc.curvature_per_m * s * overlap;
            }
            u0 = u1;
            if u0 >= b {
                break;
            }
        }
        (t1, t2)
    }
}

/// Arcs a [`WireParams::rest_shape`] holds at most.
pub const MAX_REST_ARCS: usize = 16;

/// One arc of a rest shape: `length_m` of constant curvature
/// `curvature_per_m`, bending toward the material direction at angle
/// `plane_rad` from m1 (toward m2): arcs at different angles make a shape
/// out of one plane.
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct RestArc {
    /// Length of the arc along the rod (m).
    pub length_m: f64,
    /// Its curvature (1/m): it turns by curvature × length.
    pub curvature_per_m: f64,
    /// The direction it bends toward, from m1 toward m2 (rad); 0 is the
    /// plane of `tip_curvature_per_m`.
    #[serde(default)]
    pub plane_rad: f64,
}
