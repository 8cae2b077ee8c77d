//! A simulated Touch X: the device a CI machine or a laptop drives instead of
//! the real one. It models what the haptic loop must cope with on hardware:
//!
//! - **Stylus dynamics.** The stylus tip is a point of apparent mass `m`
//!   with Coulomb + viscous backdrive friction, pushed by the device force
//!   and by a **scripted hand**: a spring-damper (stiffness `k_h`, damping
//!   `c_h`) pulling the tip towards a trajectory of waypoints, interpolated
//!   with cosine easing. Integrated with fixed sub-steps (semi-implicit
//!   Euler, `substep_hz`) up to the time the caller passes to
//!   [`HapticDevice::read`].
//! - **Workspace.** A box centred on the origin of the device frame; the tip
//!   stops at its faces (velocity into the face zeroed) and each stop is
//!   counted.
//! - **Encoders.** The reported position is quantized to the nominal
//!   resolution; the reported velocity is what drivers compute: a finite
//!   difference of quantized positions between reads, low-passed
//!   (first order, `velocity_cutoff_hz`).
//! - **Force saturation.** Per command, the norm is clamped to the peak
//!   force. A thermal model limits sustained output: `s`, a first-order
//!   filtered mean of |F|² (time constant `thermal_tau_s`), is updated every
//!   sub-step with the applied force; while √s exceeds the continuous force
//!   limit, new commands are scaled down to the continuous limit. The force
//!   [`HapticDevice::write_force`] returns is the force applied.
//! - **Port energy.** ∫ max(F·v, 0) dt (delivered to the hand) and
//!   ∫ max(−F·v, 0) dt (absorbed from it) with the true sub-step motion:
//!   F·Δx per sub-step, so a constant force gives exactly F·(x₁ − x₀).
//! - **Gimbal angles.** The stylus's three gimbal angles (yaw, pitch, roll
//!   of the stylus; [`DeviceSample::gimbal_rad`]) follow a second, kinematic
//!   script ([`TouchXSim::set_gimbal_script`], cosine-eased like the hand;
//!   zero without one): the Touch X renders no torque, so nothing pushes
//!   back on them. Reported quantized to `gimbal_resolution_rad` and wrapped
//!   to (−π, π], as an absolute angle sensor reads a continuous roll.
//! - **Buttons.** The stylus's buttons follow a third script
//!   ([`TouchXSim::set_button_script`]: from each row's time on, the
//!   buttons it holds; none without one), e.g. the switch between
//!   instruments on bit 0.
//! - **A live hand** ([`TouchXSim::set_live_hand`]): in place of the three
//!   scripts, an object that decides the hand's target, gimbal angles and
//!   buttons as it goes (a scripted hand that watches what the service
//!   shows, `crate::service::script::WatchingHand`). It is asked at every
//!   sub-step, in time order, and must not allocate.
//! - **Command timeout.** Like a device-side servo that stops playing a
//!   stale command, a force written more than the command timeout ago
//!   (device time; [`TouchXSim::set_command_timeout`], default
//!   [`DEFAULT_COMMAND_TIMEOUT_S`]) is no longer applied: the sub-steps
//!   after it run with zero force until the next write, and each lapse is
//!   counted. It covers a stalled host, which the service's own watchdog
//!   cannot (the service is what stalled).
//! - **Fault injection** for watchdog tests: [`TouchXSim::inject_silence`]
//!   (reads fail with [`DeviceError::Stale`] over a time window, the stylus
//!   keeps moving) and [`TouchXSim::inject_non_finite`] (one sample with a
//!   NaN position).
//!
//! Everything is sized in [`TouchXSim::new`]; `read` and `write_force` do not
//! allocate.
//!
//! Figures and their sources are in `rt-config/touchx.toml` and
//! `docs/DEVICE.md`.

use crate::config::{load_toml, parse_toml, Checker, ConfigError};
pub use crate::haptics::device::DEFAULT_COMMAND_TIMEOUT_S;
use crate::haptics::device::{wrap_angle, DeviceError, DeviceSample, HapticDevice, PortEnergy};
use crate::math::Vec3;
use std::path::Path;

/// The simulated device's parameters, as in `rt-config/touchx.toml` (SI
/// units). [`Default`] holds the file's shipped values.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct TouchXParams {
    /// Peak force (N): per-command norm clamp.
    pub peak_force_n: f64,
    /// Continuous force (N): the thermal limit on the filtered RMS force.
    pub continuous_force_n: f64,
    /// Time constant of the filtered mean of |F|² (s).
    pub thermal_tau_s: f64,
    /// Workspace box edge lengths (m), centred on the origin.
    pub workspace_m: [f64; 3],
    /// Encoder resolution of the reported position (m).
    pub resolution_m: f64,
    /// Mechanical stiffness of the device per axis (N/m). Not used by the
    /// simulated dynamics: the bound the service puts on rendered stiffness.
    pub stiffness_n_per_m: [f64; 3],
    /// Apparent mass at the tip (kg).
    pub apparent_mass_kg: f64,
    /// Coulomb backdrive friction (N).
    pub coulomb_friction_n: f64,
    /// Viscous backdrive friction (N·s/m).
    pub viscous_damping_ns_per_m: f64,
    /// Cut-off of the first-order low-pass on the reported velocity (Hz).
    pub velocity_cutoff_hz: f64,
    /// Integration rate of the stylus dynamics (Hz).
    pub substep_hz: f64,
    /// Stiffness of the scripted hand's grip (N/m).
    pub hand_stiffness_n_per_m: f64,
    /// Damping of the scripted hand's grip (N·s/m).
    pub hand_damping_ns_per_m: f64,
    /// Longest gap between reads that is integrated (s); a longer gap is
    /// integrated over its last `max_catchup_s` only, and counted.
    pub max_catchup_s: f64,
    /// Resolution of the reported gimbal angles (rad); 0 = no quantization.
    /// Optional in the file (older files lack it): the default applies.
    #[serde(default = "default_gimbal_resolution")]
    pub gimbal_resolution_rad: f64,
}

/// 12 bits a turn: a modelling choice, no vendor figure.
fn default_gimbal_resolution() -> f64 {
    2.0 * std::f64::consts::PI / 4096.0
}

impl Default for TouchXParams {
    fn default() -> Self {
        TouchXParams {
            peak_force_n: 7.9,
            continuous_force_n: 1.75,
            thermal_tau_s: 10.0,
            workspace_m: [0.160, 0.120, 0.120],
            resolution_m: 0.023e-3,
            stiffness_n_per_m: [1860.0, 2350.0, 1480.0],
            apparent_mass_kg: 0.045,
            coulomb_friction_n: 0.06,
            viscous_damping_ns_per_m: 0.2,
            velocity_cutoff_hz: 100.0,
            substep_hz: 10_000.0,
            hand_stiffness_n_per_m: 300.0,
            hand_damping_ns_per_m: 5.0,
            max_catchup_s: 0.1,
            gimbal_resolution_rad: default_gimbal_resolution(),
        }
    }
}

impl TouchXParams {
    /// Loads and validates `path` (e.g. `rt-config/touchx.toml`).
    pub fn load(path: &Path) -> Result<TouchXParams, ConfigError> {
        let p: TouchXParams = load_toml(path)?;
        p.validate(path)?;
        Ok(p)
    }

    /// Parses and validates TOML text; `path` names it in errors.
    pub fn from_toml_str(text: &str, path: &Path) -> Result<TouchXParams, ConfigError> {
        let p: TouchXParams = parse_toml(text, path)?;
        p.validate(path)?;
        Ok(p)
    }

    /// Range checks; errors name `path`, the key and the allowed range.
    pub fn validate(&self, path: &Path) -> Result<(), ConfigError> {
        let c = Checker::new(path);
        c.f64_in("peak_force_n", self.peak_force_n, 0.1, 100.0, "N")?;
        c.f64_in(
            "continuous_force_n",
            self.continuous_force_n,
            0.01,
            self.peak_force_n,
            "N (≤ peak_force_n)",
        )?;
        c.f64_in("thermal_tau_s", self.thermal_tau_s, 0.01, 3600.0, "s")?;
        for (i, w) in self.workspace_m.iter().enumerate() {
            c.f64_in(&format!("workspace_m[{i}]"), *w, 0.01, 2.0, "m")?;
        }
        c.f64_in("resolution_m", self.resolution_m, 0.0, 1e-3, "m (0 = no quantization)")?;
        for (i, k) in self.stiffness_n_per_m.iter().enumerate() {
            c.f64_in(&format!("stiffness_n_per_m[{i}]"), *k, 1.0, 1e6, "N/m")?;
        }
        c.f64_in("apparent_mass_kg", self.apparent_mass_kg, 1e-3, 10.0, "kg")?;
        c.f64_in("coulomb_friction_n", self.coulomb_friction_n, 0.0, 10.0, "N")?;
        c.f64_in(
            "viscous_damping_ns_per_m",
            self.viscous_damping_ns_per_m,
            0.0,
            100.0,
            "N·s/m",
        )?;
        c.f64_in("substep_hz", self.substep_hz, 1000.0, 1e6, "Hz")?;
        c.f64_in(
            "velocity_cutoff_hz",
            self.velocity_cutoff_hz,
            1.0,
            0.5 * self.substep_hz,
            "Hz (≤ substep_hz / 2)",
        )?;
        c.f64_in("hand_stiffness_n_per_m", self.hand_stiffness_n_per_m, 0.0, 1e5, "N/m")?;
        c.f64_in("hand_damping_ns_per_m", self.hand_damping_ns_per_m, 0.0, 1e3, "N·s/m")?;
        c.f64_in("max_catchup_s", self.max_catchup_s, 1e-3, 10.0, "s")?;
        c.f64_in(
            "gimbal_resolution_rad",
            self.gimbal_resolution_rad,
            0.0,
            0.1,
            "rad (0 = no quantization)",
        )?;
        // Semi-implicit Euler on m ẍ = −k x − c ẋ is stable for ω dt < 2 and
        // c dt / m < 2; keep a wide margin so the sim's own dynamics are
        // accurate, not merely bounded.
        let dt = 1.0 / self.substep_hz;
        let m = self.apparent_mass_kg;
        let w_dt = (self.hand_stiffness_n_per_m / m).sqrt() * dt;
        if w_dt > 0.2 {
            return Err(c.err(
                "hand_stiffness_n_per_m",
                format!(
                    "{}: with apparent_mass_kg = {m} and substep_hz = {}, ω·dt = {w_dt:.3}; must be ≤ 0.2 \
                     (raise substep_hz or lower the stiffness)",
                    self.hand_stiffness_n_per_m, self.substep_hz
                ),
            ));
        }
        let c_dt = (self.hand_damping_ns_per_m + self.viscous_damping_ns_per_m) * dt / m;
        if c_dt > 0.5 {
            return Err(c.err(
                "hand_damping_ns_per_m",
                format!(
                    "{}: (hand + viscous damping)·dt/m = {c_dt:.3}; must be ≤ 0.5 (raise substep_hz)",
                    self.hand_damping_ns_per_m
                ),
            ));
        }
        Ok(())
    }

    /// Half-extents of the workspace box (m).
    pub fn half_extent(&self) -> Vec3 {
        Vec3::new(self.workspace_m[0], self.workspace_m[1], self.workspace_m[2]) * 0.5
    }
}

/// One waypoint of the scripted hand: where the hand wants the tip (m, device
/// frame) at a script time (s, counted from the first read after start).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Waypoint {
    /// Script time (s).
    pub t_s: f64,
    /// Target tip position (m).
    pub position: Vec3,
}

/// One waypoint of the stylus's gimbal script: the three gimbal angles
/// (rad, [`DeviceSample::gimbal_rad`] order: roll last) the hand holds the
/// stylus at, at a script time (s, the same clock as [`Waypoint`]). Angles
/// may exceed ±π: a roll of 4 rad is reported as 4 − 2π.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GimbalWaypoint {
    /// Script time (s).
    pub t_s: f64,
    /// Gimbal angles (rad).
    pub angles_rad: [f64; 3],
}

/// Why a hand script was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ScriptError {
    /// No waypoints.
    #[error("the hand script has no waypoints")]
    Empty,
    /// A waypoint with a non-finite time or position.
    #[error("hand script waypoint {0}: non-finite time or position")]
    NonFinite(usize),
    /// Times not strictly increasing.
    #[error("hand script waypoint {0}: time must be greater than the previous waypoint's")]
    NotIncreasing(usize),
    /// A waypoint outside the workspace box.
    #[error(
        "hand script waypoint {index}: position {position:?} m is outside the workspace (half-extents {half:?} m)"
    )]
    OutsideWorkspace {
        /// Waypoint index.
        index: usize,
        /// Its position (m).
        position: [f64; 3],
        /// Workspace half-extents (m).
        half: [f64; 3],
    },
}

/// A cosine-eased trajectory through waypoints; holds the first position
/// before the first waypoint and the last after the last.
#[derive(Debug, Clone)]
pub struct HandScript {
    points: Vec<Waypoint>,
    /// Index of the segment last used (times are read in order).
    cursor: usize,
}

impl HandScript {
    /// Checks and stores the waypoints.
    pub fn new(points: &[Waypoint], params: &TouchXParams) -> Result<HandScript, ScriptError> {
        if points.is_empty() {
            return Err(ScriptError::Empty);
        }
        let half = params.half_extent();
        for (i, p) in points.iter().enumerate() {
            if !p.t_s.is_finite() || !p.position.iter().all(|v| v.is_finite()) {
                return Err(ScriptError::NonFinite(i));
            }
            if i > 0 && p.t_s <= points[i - 1].t_s {
                return Err(ScriptError::NotIncreasing(i));
            }
            if (0..3).any(|a| p.position[a].abs() > half[a]) {
                return Err(ScriptError::OutsideWorkspace {
                    index: i,
                    position: [p.position.x, p.position.y, p.position.z],
                    half: [half.x, half.y, half.z],
                });
            }
        }
        Ok(HandScript {
            points: points.to_vec(),
            cursor: 0,
        })
    }

    /// Target position (m) and velocity (m/s) at script time `t`.
    pub fn target(&mut self, t: f64) -> (Vec3, Vec3) {
        let p = &self.points;
        let n = p.len();
        if n == 1 || t <= p[0].t_s {
            return (p[0].position, Vec3::zeros());
        }
        if t >= p[n - 1].t_s {
            return (p[n - 1].position, Vec3::zeros());
        }
        // Find segment i with p[i].t <= t < p[i+1].t, starting at the cursor.
        let mut i = self.cursor.min(n - 2);
        if p[i].t_s > t {
            i = 0;
        }
        while i + 1 < n - 1 && p[i + 1].t_s <= t {
            i += 1;
        }
        self.cursor = i;
        let (a, b) = (p[i], p[i + 1]);
        let span = b.t_s - a.t_s;
        let u = (t - a.t_s) / span;
        let pi = std::f64::consts::PI;
        let s = 0.5 * (1.0 - (pi * u).cos());
        let ds = 0.5 * pi * (pi * u).sin() / span;
        let d = b.position - a.position;
        (a.position + d * s, d * ds)
    }

    /// The waypoints.
    pub fn points(&self) -> &[Waypoint] {
        &self.points
    }
}

/// A cosine-eased trajectory of gimbal angles (see [`HandScript`]).
#[derive(Debug, Clone)]
pub struct GimbalScript {
    points: Vec<GimbalWaypoint>,
    cursor: usize,
}

impl GimbalScript {
    /// Checks and stores the waypoints (finite, times strictly increasing).
    pub fn new(points: &[GimbalWaypoint]) -> Result<GimbalScript, ScriptError> {
        if points.is_empty() {
            return Err(ScriptError::Empty);
        }
        for (i, p) in points.iter().enumerate() {
            if !p.t_s.is_finite() || !p.angles_rad.iter().all(|v| v.is_finite()) {
                return Err(ScriptError::NonFinite(i));
            }
            if i > 0 && p.t_s <= points[i - 1].t_s {
                return Err(ScriptError::NotIncreasing(i));
            }
        }
        Ok(GimbalScript {
            points: points.to_vec(),
            cursor: 0,
        })
    }

    /// The (unwrapped) angles at script time `t`.
    pub fn target(&mut self, t: f64) -> [f64; 3] {
        let p = &self.points;
        let n = p.len();
        if n == 1 || t <= p[0].t_s {
            return p[0].angles_rad;
        }
        if t >= p[n - 1].t_s {
            return p[n - 1].angles_rad;
        }
        let mut i = self.cursor.min(n - 2);
        if p[i].t_s > t {
            i = 0;
        }
        while i + 1 < n - 1 && p[i + 1].t_s <= t {
            i += 1;
        }
        self.cursor = i;
        let (a, b) = (p[i], p[i + 1]);
        let u = (t - a.t_s) / (b.t_s - a.t_s);
        let s = 0.5 * (1.0 - (std::f64::consts::PI * u).cos());
        std::array::from_fn(|k| a.angles_rad[k] + (b.angles_rad[k] - a.angles_rad[k]) * s)
    }
}

/// What a live hand does at one instant: the stylus tip's target (m, device
/// frame) and its velocity (m/s), the gimbal angles (rad, unwrapped) and the
/// buttons it holds.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HandPose {
    /// Target tip position (m).
    pub position: Vec3,
    /// Target tip velocity (m/s).
    pub velocity: Vec3,
    /// Gimbal angles (rad, [`DeviceSample::gimbal_rad`] order).
    pub gimbal_rad: [f64; 3],
    /// Buttons held (bit 0 the first stylus button).
    pub buttons: u32,
}

/// A hand that decides as it goes ([`TouchXSim::set_live_hand`]), e.g. from
/// what it sees of the simulation. Runs on the device's thread after start:
/// [`LiveHand::at`] must not allocate, lock or block.
pub trait LiveHand: Send + std::fmt::Debug {
    /// The hand at script time `t` (s, from the first read); called at
    /// every sub-step, times increasing.
    fn at(&mut self, t: f64) -> HandPose;
    /// A copy of the hand (for [`Clone`] of the device).
    fn clone_box(&self) -> Box<dyn LiveHand>;
}

impl Clone for Box<dyn LiveHand> {
    fn clone(&self) -> Self {
        self.clone_box()
    }
}

/// The simulated device's true internal state (for tests and reports; a real
/// device does not expose it).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TouchXState {
    /// True tip position (m).
    pub position: Vec3,
    /// True tip velocity (m/s).
    pub velocity: Vec3,
    /// Force being applied (N), after saturation.
    pub applied_force: Vec3,
    /// Force the hand exerts on the stylus (N), last sub-step.
    pub hand_force: Vec3,
    /// True gimbal angles (rad, unwrapped) at the last read.
    pub gimbal_rad: [f64; 3],
    /// Filtered RMS force √s of the thermal model (N).
    pub rms_force_n: f64,
    /// Simulated time reached (s, caller's clock).
    pub time_s: f64,
    /// Number of sub-steps integrated.
    pub substeps: u64,
    /// Number of sub-steps that ended against a workspace face.
    pub workspace_stops: u64,
    /// Commands clamped to the peak force.
    pub peak_clamps: u64,
    /// Commands scaled to the continuous force by the thermal model.
    pub thermal_limits: u64,
    /// Reads whose gap exceeded `max_catchup_s` (time was skipped).
    pub catchup_skips: u64,
    /// Times a force command outlived the command timeout and the device
    /// stopped applying it.
    pub command_timeouts: u64,
}

/// The simulated Touch X. See the module documentation for the model.
#[derive(Debug, Clone)]
pub struct TouchXSim {
    p: TouchXParams,
    half: Vec3,
    dt: f64,
    script: HandScript,
    gimbal: Option<GimbalScript>,
    gimbal_rad: [f64; 3],
    /// The buttons' script: (script time s, buttons held from then on),
    /// times increasing; empty: no button is ever pressed.
    buttons: Vec<(f64, u32)>,
    /// Index of the button row last used (times are read in order).
    button_cursor: usize,
    /// A live hand in place of the scripts, and its last pose.
    live: Option<(Box<dyn LiveHand>, HandPose)>,
    started: bool,
    /// Caller time of the first read (script time 0), once known.
    origin_s: Option<f64>,
    /// Sub-steps integrated since `origin_s`.
    n: u64,
    x: Vec3,
    v: Vec3,
    force: Vec3,
    /// Sub-step count `n` when `force` was written.
    force_at_n: u64,
    /// Sub-steps a command stays applied (from the command timeout).
    command_steps: u64,
    /// Whether `force` has lapsed (counted once per lapse).
    lapsed: bool,
    hand_force: Vec3,
    mean_f2: f64,
    // Reported (driver-side) state.
    last_q: Vec3,
    last_read_s: f64,
    v_filt: Vec3,
    seq: u64,
    energy: PortEnergy,
    // Counters.
    workspace_stops: u64,
    peak_clamps: u64,
    thermal_limits: u64,
    catchup_skips: u64,
    command_timeouts: u64,
    // Fault injection.
    silent_from_s: f64,
    silent_until_s: f64,
    nan_at_s: Option<f64>,
}

impl TouchXSim {
    /// A simulated device with `params` (validate them first, e.g. through
    /// [`TouchXParams::load`]) and a hand following `waypoints`. The stylus
    /// starts at rest at the first waypoint.
    pub fn new(params: TouchXParams, waypoints: &[Waypoint]) -> Result<TouchXSim, ScriptError> {
        let script = HandScript::new(waypoints, &params)?;
        let x0 = script.points()[0].position;
        let mut sim = TouchXSim {
            half: params.half_extent(),
            dt: 1.0 / params.substep_hz,
            p: params,
            script,
            gimbal: None,
            gimbal_rad: [0.0; 3],
            buttons: Vec::new(),
            button_cursor: 0,
            live: None,
            started: false,
            origin_s: None,
            n: 0,
            x: x0,
            v: Vec3::zeros(),
            force: Vec3::zeros(),
            force_at_n: 0,
            command_steps: 0,
            lapsed: false,
            hand_force: Vec3::zeros(),
            mean_f2: 0.0,
            last_q: Vec3::zeros(),
            last_read_s: 0.0,
            v_filt: Vec3::zeros(),
            seq: 0,
            energy: PortEnergy::default(),
            workspace_stops: 0,
            peak_clamps: 0,
            thermal_limits: 0,
            catchup_skips: 0,
            command_timeouts: 0,
            silent_from_s: f64::INFINITY,
            silent_until_s: f64::NEG_INFINITY,
            nan_at_s: None,
        };
        sim.set_command_timeout(DEFAULT_COMMAND_TIMEOUT_S);
        Ok(sim)
    }

    /// Sets how long (s, device time) a written force keeps being applied
    /// without a newer one; a non-finite or non-positive value falls back to
    /// [`DEFAULT_COMMAND_TIMEOUT_S`]. The service passes
    /// `watchdog.command_timeout_ms`.
    pub fn set_command_timeout(&mut self, timeout_s: f64) {
        let t = if timeout_s.is_finite() && timeout_s > 0.0 {
            timeout_s
        } else {
            DEFAULT_COMMAND_TIMEOUT_S
        };
        self.command_steps = (t / self.dt).round().max(1.0).min(u64::MAX as f64) as u64;
    }

    /// A hand that holds the tip still at `position`.
    pub fn holding(params: TouchXParams, position: Vec3) -> Result<TouchXSim, ScriptError> {
        TouchXSim::new(params, &[Waypoint { t_s: 0.0, position }])
    }

    /// The parameters.
    pub fn params(&self) -> &TouchXParams {
        &self.p
    }

    /// The true internal state.
    pub fn state(&self) -> TouchXState {
        TouchXState {
            position: self.x,
            velocity: self.v,
            applied_force: self.applied(),
            hand_force: self.hand_force,
            gimbal_rad: self.gimbal_rad,
            rms_force_n: self.mean_f2.sqrt(),
            time_s: self.origin_s.map_or(0.0, |o| o + self.n as f64 * self.dt),
            substeps: self.n,
            workspace_stops: self.workspace_stops,
            peak_clamps: self.peak_clamps,
            thermal_limits: self.thermal_limits,
            catchup_skips: self.catchup_skips,
            command_timeouts: self.command_timeouts,
        }
    }

    /// Scripts the stylus's buttons (same script clock as the hand's
    /// waypoints): rows of (time s, the buttons held from that time on, bit
    /// 0 the first stylus button), times strictly increasing; before the
    /// first row no button is held. Replaces any earlier button script.
    /// Allocates: call before [`HapticDevice::start`].
    pub fn set_button_script(&mut self, rows: &[(f64, u32)]) -> Result<(), ScriptError> {
        for (i, r) in rows.iter().enumerate() {
            if !r.0.is_finite() {
                return Err(ScriptError::NonFinite(i));
            }
            if i > 0 && r.0 <= rows[i - 1].0 {
                return Err(ScriptError::NotIncreasing(i));
            }
        }
        self.buttons = rows.to_vec();
        self.button_cursor = 0;
        Ok(())
    }

    /// The buttons the script holds at script time `t` (s); reads in
    /// order, allocation-free.
    fn buttons_at(&mut self, t: f64) -> u32 {
        while self.button_cursor < self.buttons.len() && self.buttons[self.button_cursor].0 <= t {
            self.button_cursor += 1;
        }
        match self.button_cursor {
            0 => 0,
            k => self.buttons[k - 1].1,
        }
    }

    /// Puts a live hand in place of the waypoints, gimbal and button
    /// scripts: the stylus starts at rest where it is at time 0. Allocates:
    /// call before [`HapticDevice::start`].
    pub fn set_live_hand(&mut self, mut hand: Box<dyn LiveHand>) {
        let pose = hand.at(0.0);
        self.x = pose.position;
        self.v = Vec3::zeros();
        self.gimbal_rad = pose.gimbal_rad;
        self.live = Some((hand, pose));
    }

    /// Scripts the stylus's gimbal angles (same script clock as the hand's
    /// waypoints); replaces any earlier gimbal script. Allocates: call before
    /// [`HapticDevice::start`].
    pub fn set_gimbal_script(&mut self, points: &[GimbalWaypoint]) -> Result<(), ScriptError> {
        let mut g = GimbalScript::new(points)?;
        self.gimbal_rad = g.target(f64::NEG_INFINITY);
        self.gimbal = Some(g);
        Ok(())
    }

    /// The gimbal angles as reported: quantized, wrapped to (−π, π].
    fn reported_gimbal(&self) -> [f64; 3] {
        let r = self.p.gimbal_resolution_rad;
        self.gimbal_rad.map(|a| {
            let w = wrap_angle(a);
            if r > 0.0 {
                wrap_angle((w / r).round() * r)
            } else {
                w
            }
        })
    }

    /// Fault injection: reads at caller times in `[from_s, from_s +
    /// duration_s)` return [`DeviceError::Stale`] (the device went silent);
    /// the stylus dynamics keep running and the force last written keeps
    /// playing, as on a real device whose link dropped.
    pub fn inject_silence(&mut self, from_s: f64, duration_s: f64) {
        self.silent_from_s = from_s;
        self.silent_until_s = from_s + duration_s;
    }

    /// Fault injection: the first read at a caller time ≥ `at_s` returns
    /// one sample whose position and velocity are NaN (once).
    pub fn inject_non_finite(&mut self, at_s: f64) {
        self.nan_at_s = Some(at_s);
    }

    /// Quantizes a position to the encoder resolution.
    fn quantize(&self, x: Vec3) -> Vec3 {
        let r = self.p.resolution_m;
        if r > 0.0 {
            x.map(|c| (c / r).round() * r)
        } else {
            x
        }
    }

    /// The force being applied: the last command, or zero once it is older
    /// than the command timeout.
    fn applied(&self) -> Vec3 {
        if self.n.saturating_sub(self.force_at_n) > self.command_steps {
            Vec3::zeros()
        } else {
            self.force
        }
    }

    /// One semi-implicit Euler sub-step at script time `t` (the step's end).
    fn substep(&mut self, t: f64) {
        let dt = self.dt;
        let force = self.applied();
        if force != self.force && !self.lapsed {
            self.lapsed = true;
            self.command_timeouts += 1;
        }
        let m = self.p.apparent_mass_kg;
        let (xt, vt) = match self.live.as_mut() {
            Some((hand, pose)) => {
                *pose = hand.at(t);
                (pose.position, pose.velocity)
            }
            None => self.script.target(t),
        };
        let hand = (xt - self.x) * self.p.hand_stiffness_n_per_m + (vt - self.v) * self.p.hand_damping_ns_per_m;
        self.hand_force = hand;
        // Smooth forces first, then viscous friction implicitly, then
        // Coulomb friction as an impulse that may stop the tip but never
        // reverses it (stick when it can hold the tip).
        let v_free = (self.v * m + (force + hand) * dt) / (m + self.p.viscous_damping_ns_per_m * dt);
        let stop_impulse = self.p.coulomb_friction_n * dt / m;
        let speed = v_free.norm();
        let v_new = if speed <= stop_impulse {
            Vec3::zeros()
        } else {
            v_free * (1.0 - stop_impulse / speed)
        };
        let mut x_new = self.x + v_new * dt;
        let mut v_new = v_new;
        let mut stopped = false;
        for a in 0..3 {
            let h = self.half[a];
            if x_new[a] > h || x_new[a] < -h {
                x_new[a] = x_new[a].clamp(-h, h);
                v_new[a] = 0.0;
                stopped = true;
            }
        }
        if stopped {
            self.workspace_stops += 1;
        }
        // Port energy with the true sub-step motion: F·Δx.
        let w = force.dot(&(x_new - self.x));
        if w > 0.0 {
            self.energy.delivered_j += w;
        } else {
            self.energy.absorbed_j -= w;
        }
        self.x = x_new;
        self.v = v_new;
        // Thermal model: first-order filtered mean of |F|², exact
        // discretisation of ṡ = (|F|² − s)/τ over dt.
        let a = 1.0 - (-dt / self.p.thermal_tau_s).exp();
        self.mean_f2 += a * (force.norm_squared() - self.mean_f2);
    }

    /// Advances the dynamics to caller time `now_s` (whole sub-steps).
    fn advance(&mut self, now_s: f64) {
        let origin = match self.origin_s {
            Some(o) => o,
            None => {
                self.origin_s = Some(now_s);
                return;
            }
        };
        let target_n = ((now_s - origin) / self.dt + 1e-9).floor();
        // `now_s` is finite (checked by `read`), so `target_n` is too.
        if target_n <= self.n as f64 {
            return; // time did not advance (or went back): nothing to do
        }
        let max_steps = (self.p.max_catchup_s / self.dt).ceil() as u64;
        let mut steps = (target_n - self.n as f64) as u64;
        if steps > max_steps {
            self.catchup_skips += 1;
            self.n += steps - max_steps;
            steps = max_steps;
        }
        for _ in 0..steps {
            self.n += 1;
            let t = self.n as f64 * self.dt;
            self.substep(t);
        }
    }
}

impl HapticDevice for TouchXSim {
    fn name(&self) -> &'static str {
        "touchx-sim"
    }

    fn start(&mut self) -> Result<(), DeviceError> {
        self.started = true;
        self.force = Vec3::zeros();
        Ok(())
    }

    fn read(&mut self, now_s: f64) -> Result<DeviceSample, DeviceError> {
        if !self.started {
            return Err(DeviceError::Start(0));
        }
        if !now_s.is_finite() {
            return Err(DeviceError::BadData);
        }
        let first = self.origin_s.is_none();
        self.advance(now_s);
        if let Some(g) = self.gimbal.as_mut() {
            self.gimbal_rad = g.target(self.n as f64 * self.dt);
        }
        let mut buttons = self.buttons_at(self.n as f64 * self.dt);
        if let Some((_, pose)) = &self.live {
            self.gimbal_rad = pose.gimbal_rad;
            buttons = pose.buttons;
        }
        let q = self.quantize(self.x);
        if first {
            self.last_q = q;
            self.last_read_s = now_s;
        } else {
            let gap = now_s - self.last_read_s;
            if gap > 0.0 {
                let raw = (q - self.last_q) / gap;
                let alpha = 1.0 - (-2.0 * std::f64::consts::PI * self.p.velocity_cutoff_hz * gap).exp();
                self.v_filt += (raw - self.v_filt) * alpha;
                self.last_q = q;
                self.last_read_s = now_s;
            }
        }
        if now_s >= self.silent_from_s && now_s < self.silent_until_s {
            return Err(DeviceError::Stale);
        }
        self.seq += 1;
        let mut sample = DeviceSample {
            position: q,
            velocity: self.v_filt,
            buttons,
            time_s: now_s,
            seq: self.seq,
            gimbal_rad: self.reported_gimbal(),
        };
        if let Some(t) = self.nan_at_s {
            if now_s >= t {
                self.nan_at_s = None;
                sample.position = Vec3::new(f64::NAN, f64::NAN, f64::NAN);
                sample.velocity = Vec3::new(f64::NAN, f64::NAN, f64::NAN);
                sample.gimbal_rad = [f64::NAN; 3];
            }
        }
        Ok(sample)
    }

    fn write_force(&mut self, force: Vec3) -> Result<Vec3, DeviceError> {
        if !self.started {
            return Err(DeviceError::Start(0));
        }
        if !force.iter().all(|c| c.is_finite()) {
            self.force = Vec3::zeros();
            return Err(DeviceError::BadData);
        }
        let mut f = force;
        let n = f.norm();
        if n > self.p.peak_force_n {
            f *= self.p.peak_force_n / n;
            self.peak_clamps += 1;
        }
        let c = self.p.continuous_force_n;
        if self.mean_f2 > c * c {
            let n = f.norm();
            if n > c {
                f *= c / n;
                self.thermal_limits += 1;
            }
        }
        self.force = f;
        self.force_at_n = self.n;
        self.lapsed = false;
        Ok(f)
    }

    fn stop(&mut self) {
        self.force = Vec3::zeros();
        self.started = false;
    }

    fn port_energy(&self) -> Option<PortEnergy> {
        Some(self.energy)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn script_eases_between_waypoints_and_holds_outside() {
        let p = TouchXParams::default();
        let a = Vec3::new(0.0, 0.0, 0.0);
        let b = Vec3::new(0.01, 0.0, 0.0);
        let mut s = HandScript::new(
            &[Waypoint { t_s: 1.0, position: a }, Waypoint { t_s: 2.0, position: b }],
            &p,
        )
        .expect("script");
        assert_eq!(s.target(0.0), (a, Vec3::zeros()));
        let (x, v) = s.target(1.5);
        assert!((x.x - 0.005).abs() < 1e-15);
        // Peak speed of cosine easing: |b − a|·π/2 per unit time.
        assert!((v.x - 0.01 * std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        assert_eq!(s.target(3.0), (b, Vec3::zeros()));
        assert!(s.target(1.0).1.norm() < 1e-15);
    }

    #[test]
    fn bad_scripts_are_refused() {
        let p = TouchXParams::default();
        let w = |t, x| Waypoint {
            t_s: t,
            position: Vec3::new(x, 0.0, 0.0),
        };
        assert_eq!(HandScript::new(&[], &p).unwrap_err(), ScriptError::Empty);
        assert_eq!(
            HandScript::new(&[w(0.0, 0.0), w(0.0, 0.0)], &p).unwrap_err(),
            ScriptError::NotIncreasing(1)
        );
        assert_eq!(
            HandScript::new(&[w(f64::NAN, 0.0)], &p).unwrap_err(),
            ScriptError::NonFinite(0)
        );
        assert!(matches!(
            HandScript::new(&[w(0.0, 0.5)], &p).unwrap_err(),
            ScriptError::OutsideWorkspace { index: 0, .. }
        ));
    }

    #[test]
    fn angles_wrap_to_minus_pi_exclusive_pi_inclusive() {
        use std::f64::consts::PI;
        assert_eq!(wrap_angle(PI), PI);
        assert_eq!(wrap_angle(-PI), PI);
        assert!((wrap_angle(4.0) - (4.0 - 2.0 * PI)).abs() < 1e-15);
        assert!((wrap_angle(-7.0) - (-7.0 + 2.0 * PI)).abs() < 1e-15);
        assert_eq!(wrap_angle(0.5), 0.5);
    }

    #[test]
    fn shipped_defaults_validate() {
        TouchXParams::default()
            .validate(Path::new("default"))
            .expect("defaults are valid");
    }

    /// Holds a 2 N push for 5 ms, then the host stalls for 300 ms (one read
    /// after the leap, no write): the delivered energy and the applied force
    /// with the command timeout `timeout_s`.
    fn stall(timeout_s: f64) -> (f64, TouchXState) {
        let mut d = TouchXSim::holding(TouchXParams::default(), Vec3::zeros()).expect("sim");
        d.set_command_timeout(timeout_s);
        d.start().expect("start");
        let f = Vec3::new(2.0, 0.0, 0.0);
        for k in 0..=5 {
            d.read(k as f64 * 1e-3).expect("read");
            d.write_force(f).expect("write");
        }
        d.read(0.305).expect("read after the stall");
        (d.port_energy().expect("energy").delivered_j, d.state())
    }

    #[test]
    fn a_stalled_host_leaves_no_force_playing() {
        let (e_held, held) = stall(1.0);
        let (e_cut, cut) = stall(DEFAULT_COMMAND_TIMEOUT_S);
        assert_eq!(held.command_timeouts, 0);
        assert_eq!(held.applied_force, Vec3::new(2.0, 0.0, 0.0));
        assert_eq!(cut.command_timeouts, 1);
        assert_eq!(cut.applied_force, Vec3::zeros());
        // The catch-up integrates the last 100 ms of the leap: with the force
        // held it keeps pushing against the hand; cut, it pushed for 10 ms at
        // most, all before the stall's catch-up.
        assert!(e_cut < 0.25 * e_held, "cut {e_cut} J, held {e_held} J");
        assert!(e_cut > 0.0);
        // A new command plays again, and a lapse is counted once.
        let mut d = TouchXSim::holding(TouchXParams::default(), Vec3::zeros()).expect("sim");
        d.start().expect("start");
        d.read(0.0).expect("read");
        d.write_force(Vec3::new(0.5, 0.0, 0.0)).expect("write");
        d.read(0.05).expect("read");
        d.read(0.06).expect("read");
        assert_eq!(d.state().command_timeouts, 1);
        d.write_force(Vec3::new(0.5, 0.0, 0.0)).expect("write");
        d.read(0.061).expect("read");
        assert_eq!(d.state().applied_force, Vec3::new(0.5, 0.0, 0.0));
        assert_eq!(d.state().command_timeouts, 1);
    }
}
