//! The passivity filter's limits and tuning (`[passivity]` in the service
//! configuration), with their range checks.

use crate::config::{Checker, ConfigError};
use serde::{Deserialize, Serialize};

use super::MAX_ITER_CAP;

/// Where the norm bound comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum NormBound {
    /// Always the peak force.
    Peak,
    /// Always the continuous force.
    Continuous,
    /// Peak when cold, sliding smoothly to continuous as a filtered mean of
    /// `|F|²` (time constant `thermal_tau_s`) reaches continuous² (see the
    /// module doc).
    Thermal,
}

/// Limits and tuning of the passivity filter (`[passivity]` in the service
/// configuration). SI units.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PassivityParams {
    /// Tick period T (s).
    pub dt_s: f64,
    /// Peak force (N); 7.9 for the Touch X.
    pub peak_force_n: f64,
    /// Continuous force (N); 1.75 for the Touch X.
    pub continuous_force_n: f64,
    /// Which norm bound to use.
    pub norm_bound: NormBound,
    /// Time constant of the thermal model (s); used by [`NormBound::Thermal`].
    pub thermal_tau_s: f64,
    /// Rate bound Δ: largest change of the force vector per tick (N).
    pub rate_n_per_tick: f64,
    /// Weight w of the rate slack (N): an exact penalty, keep it above twice
    /// the largest `‖F_des − F‖` you expect.
    pub rate_slack_weight_n: f64,
    /// Energy in the tank at start (J). A watchdog reset
    /// ([`super::PassivityFilter::reset`]) keeps the level it finds (a
    /// fault never refills the tank).
    pub tank_initial_j: f64,
    /// Reserve the output never draws on (J); covers the one-tick prediction
    /// error of the energy row.
    pub tank_min_j: f64,
    /// Tank capacity (J): the most energy the device can return in a burst.
    pub tank_max_j: f64,
    /// Physical damping of the device credited to the tank (N·s/m); 0 for no
    /// credit. Must not exceed the device's real damping.
    pub damping_credit_ns_per_m: f64,
    /// The lightest mass the output force accelerates (kg): the device's
    /// apparent mass at the tip without the hand (the Touch X: 45 g). The
    /// energy row counts the work the force does by moving that mass during
    /// the tick it is held (`T²‖F‖²/(2m)`, the module doc of `passivity`);
    /// a larger value is less conservative.
    #[serde(default = "default_stylus_mass")]
    pub stylus_mass_kg: f64,
    /// How long after the pose it is computed from a force reaches the
    /// motors, in ticks (0..=1): the force of tick k is held from
    /// t_k + φT to t_{k+1} + φT, so over the poses' interval
    /// [t_{k−1}, t_k] the device held the force before the last for a
    /// fraction φ and the last one for the rest; the energy observer counts
    /// that mix. 0 (the default): the force lands with the pose, as in a
    /// device callback that reads and writes at once. The service measures
    /// it (`pose→force` in its report: p50 0.51 ms at 1 kHz through the
    /// device thread, φ ≈ 0.5).
    #[serde(default)]
    pub hold_delay_ticks: f64,
    /// Interior-point iteration limit (1..=100).
    pub max_iter: u32,
    /// Absolute duality-gap tolerance.
    pub tol_gap_abs: f64,
    /// Relative duality-gap tolerance.
    pub tol_gap_rel: f64,
    /// Feasibility tolerance.
    pub tol_feas: f64,
}

/// The Touch X's apparent mass at the tip (kg), as the simulated device's
/// default ([`crate::haptics::touchx::TouchXParams`]).
fn default_stylus_mass() -> f64 {
    0.045
}

impl Default for PassivityParams {
    /// Touch X figures at 1 kHz.
    fn default() -> Self {
        PassivityParams {
            dt_s: 1e-3,
            peak_force_n: 7.9,
            continuous_force_n: 1.75,
            norm_bound: NormBound::Thermal,
            thermal_tau_s: 10.0,
            rate_n_per_tick: 1.0,
            rate_slack_weight_n: 1e3,
            tank_initial_j: 0.01,
            tank_min_j: 3e-3,
            tank_max_j: 0.05,
            damping_credit_ns_per_m: 0.0,
            stylus_mass_kg: default_stylus_mass(),
            hold_delay_ticks: 0.0,
            max_iter: 30,
            tol_gap_abs: 1e-8,
            tol_gap_rel: 1e-8,
            tol_feas: 1e-8,
        }
    }
}

impl PassivityParams {
    /// Checks every field; errors name the file (from `checker`), the key
    /// (`prefix.field`) and the allowed range.
    pub fn validate(&self, checker: &Checker, prefix: &str) -> Result<(), ConfigError> {
        let k = |f: &str| {
            if prefix.is_empty() {
                f.to_string()
            } else {
                format!("{prefix}.{f}")
            }
        };
        checker.f64_in(&k("dt_s"), self.dt_s, 1e-5, 0.1, "s")?;
        checker.f64_in(&k("peak_force_n"), self.peak_force_n, 1e-3, 1000.0, "N")?;
        checker.f64_in(
            &k("continuous_force_n"),
            self.continuous_force_n,
            1e-3,
            self.peak_force_n,
            "N (at most peak_force_n)",
        )?;
        checker.f64_in(&k("thermal_tau_s"), self.thermal_tau_s, 1e-2, 3600.0, "s")?;
        checker.f64_in(&k("rate_n_per_tick"), self.rate_n_per_tick, 1e-6, 1000.0, "N")?;
        checker.f64_in(&k("rate_slack_weight_n"), self.rate_slack_weight_n, 1e-3, 1e6, "N")?;
        checker.f64_in(&k("tank_min_j"), self.tank_min_j, 0.0, 100.0, "J")?;
        checker.f64_in(
            &k("tank_max_j"),
            self.tank_max_j,
            self.tank_min_j,
            1000.0,
            "J (at least tank_min_j)",
        )?;
        checker.f64_in(
            &k("tank_initial_j"),
            self.tank_initial_j,
            self.tank_min_j,
            self.tank_max_j,
            "J (between tank_min_j and tank_max_j)",
        )?;
        checker.f64_in(
            &k("damping_credit_ns_per_m"),
            self.damping_credit_ns_per_m,
            0.0,
            100.0,
            "N·s/m",
        )?;
        checker.f64_in(&k("stylus_mass_kg"), self.stylus_mass_kg, 1e-3, 10.0, "kg")?;
        checker.f64_in(&k("hold_delay_ticks"), self.hold_delay_ticks, 0.0, 1.0, "ticks")?;
        checker.int_in(&k("max_iter"), self.max_iter, 1, MAX_ITER_CAP)?;
        checker.f64_in(&k("tol_gap_abs"), self.tol_gap_abs, 1e-12, 1e-3, "")?;
        checker.f64_in(&k("tol_gap_rel"), self.tol_gap_rel, 1e-12, 1e-3, "")?;
        checker.f64_in(&k("tol_feas"), self.tol_feas, 1e-12, 1e-3, "")?;
        Ok(())
    }
}

/// Why a filter could not be built.
#[derive(Debug, thiserror::Error)]
pub enum PassivityError {
    /// A parameter is out of range.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// clarabel refused the problem or the settings.
    #[error("passivity QP set-up failed: {0}")]
    Solver(String),
}
