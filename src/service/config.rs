//! The service configuration, `rt-config/nvtmm.toml`: rates, priorities,
//! CPUs, ring capacities, the device backend, the scripted interaction of the
//! simulated device, contact, watchdog and background-solve settings. Every
//! key is validated at start; errors name the file, the key and the range.

use crate::config::{load_toml, Checker, ConfigError};
use crate::haptics::contact::ContactParams;
use serde::Deserialize;
use std::path::{Path, PathBuf};

/// The whole service configuration.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ServiceConfig {
    /// The scene (mesh, material, model, fixed regions, `[reduced]`),
    /// relative to this file.
    pub scene: PathBuf,
    /// Default run length (s) when `--seconds` is not given.
    #[serde(default = "d_seconds")]
    pub seconds: f64,
    /// The haptic loop.
    #[serde(default, rename = "loop")]
    pub servo: LoopConfig,
    /// The device and its I/O thread.
    #[serde(default)]
    pub device: DeviceConfig,
    /// The scripted hand of the simulated device.
    #[serde(default)]
    pub interaction: InteractionConfig,
    /// Tool contact.
    #[serde(default)]
    pub contact: ContactParams,
    /// Watchdog.
    #[serde(default)]
    pub watchdog: WatchdogConfig,
    /// The background full solve.
    #[serde(default)]
    pub background: BackgroundConfig,
    /// Ring capacities.
    #[serde(default)]
    pub rings: RingConfig,
    /// The report.
    #[serde(default)]
    pub report: ReportConfig,
    /// The passivity QP (its `dt_s` is set from `loop.rate_hz`).
    #[serde(default)]
    pub passivity: crate::haptics::passivity::PassivityParams,
    /// The coarse state stream (docs/STREAM.md).
    #[serde(default)]
    pub stream: crate::stream::StreamConfig,
    /// The guidewire (`[wire]` with `[wire.drive]`, docs/WIRE.md); None: no
    /// wire.
    #[serde(default)]
    pub wire: Option<crate::wire::WireParams>,
    /// How the service runs the guidewire (`[guidewire]`, needed with
    /// `[wire]`).
    #[serde(default)]
    pub guidewire: Option<super::instrument::guidewire::GuidewireConfig>,
    /// A catheter over the guidewire (`[catheter]`, needs `[wire]` and
    /// `[guidewire]`; docs/INSTRUMENTS.md): the pair steps in one thread.
    #[serde(default)]
    pub catheter: Option<super::instrument::catheter::CatheterConfig>,
    /// A training task and its metrics (`[task]`, docs/DRIVING.md); None:
    /// no task.
    #[serde(default)]
    pub task: Option<crate::task::TaskConfig>,
    /// The file this was read from (for messages and relative paths).
    #[serde(skip)]
    pub path: PathBuf,
}

fn d_seconds() -> f64 {
    20.0
}

/// The 1 kHz haptic loop.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LoopConfig {
    /// Loop rate (Hz).
    pub rate_hz: f64,
    /// SCHED_FIFO priority (1..=99); 0 = normal policy.
    pub priority: u8,
    /// CPU to pin the loop to (-1: not pinned).
    pub cpu: i32,
    /// Stack size of the loop thread (KiB), prefaulted.
    pub stack_kib: usize,
    /// Lock all memory (mlockall) before starting.
    pub lock_memory: bool,
    /// Seconds of a bare absolute-deadline sleep loop, on the loop's thread
    /// and CPU, before the loop starts (the jitter baseline).
    pub baseline_s: f64,
    /// Cross-fade of a model swap (ms): the old and the new model both run
    /// and the force blends over; 0 switches at once.
    pub swap_blend_ms: f64,
    /// Keep the loop's CPU from going idle with a `SCHED_IDLE` spinning
    /// thread pinned there ([`crate::rt::thread::spawn_keep_awake`]), for
    /// virtual machines whose idle CPUs wake late. Needs `cpu` ≥ 0.
    pub keep_cpu_awake: bool,
}

impl Default for LoopConfig {
    fn default() -> Self {
        LoopConfig {
            rate_hz: 1000.0,
            priority: 80,
            cpu: 1,
            stack_kib: 1024,
            lock_memory: true,
            baseline_s: 2.0,
            swap_blend_ms: 20.0,
            keep_cpu_awake: false,
        }
    }
}

/// Which device backend.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Backend {
    /// The simulated Touch X with a scripted hand.
    TouchxSim,
    /// The UDP bridge to a process that owns the vendor driver.
    Udp,
    /// OpenHaptics HD (cargo feature `openhaptics`).
    Openhaptics,
    /// The host application pushes the poses in process
    /// (`haptics::host::host_device`, the C ABI's `nvtmm_start_host`).
    Host,
}

/// The device and its I/O thread.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DeviceConfig {
    /// Backend.
    pub backend: Backend,
    /// The Touch X parameter file, relative to this file.
    pub touchx: PathBuf,
    /// The UDP bridge parameter file, relative to this file.
    pub udp: PathBuf,
    /// Device I/O rate (Hz).
    pub rate_hz: f64,
    /// SCHED_FIFO priority of the I/O thread (0 = normal).
    pub priority: u8,
    /// CPU of the I/O thread (-1: not pinned).
    pub cpu: i32,
    /// Scene position (m) of the device frame's origin: the device frame is
    /// the scene frame translated by this offset.
    pub origin_m: [f64; 3],
    /// The full device-to-scene map (rotation, offset, scale;
    /// `[device.frame]`, see `haptics::frame`); when given it replaces
    /// `origin_m`.
    pub frame: Option<crate::haptics::frame::DeviceFrameParams>,
    /// A second device (`[device.second]`): a second UDP peer that drives
    /// one hub-driven instrument on its own and feels that instrument's
    /// force, while this device drives the others (docs/DRIVING.md "Two
    /// devices, one instrument each").
    pub second: Option<SecondDevice>,
}

/// `[device.second]`: a second UDP peer for one hub-driven instrument. Its
/// I/O thread runs at `device.rate_hz` with `device.priority` and
/// `device.cpu`; its poses are read in the same device frame
/// (`[device.frame]`) and mapped to its instrument's hub by the same drive
/// (`[wire.drive]`) as the first device's.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SecondDevice {
    /// The UDP bridge parameter file of the second peer (its own `bind`
    /// address), relative to this file.
    pub udp: PathBuf,
    /// The id of the instrument it drives: `guidewire` or `catheter`.
    pub instrument: String,
}

impl Default for SecondDevice {
    fn default() -> Self {
        SecondDevice {
            udp: PathBuf::from("udp_second.toml"),
            instrument: "catheter".into(),
        }
    }
}

impl Default for DeviceConfig {
    fn default() -> Self {
        DeviceConfig {
            backend: Backend::TouchxSim,
            touchx: PathBuf::from("touchx.toml"),
            udp: PathBuf::from("udp_device.toml"),
            rate_hz: 1000.0,
            priority: 70,
            cpu: 1,
            origin_m: [0.0; 3],
            frame: None,
            second: None,
        }
    }
}

/// The scripted interaction of the simulated device: approach the wall along
/// its normal, press, slide along the wall, release, rest.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct InteractionConfig {
    /// Start this far (m) outside the wall (tool surface to wall).
    pub clearance_m: f64,
    /// Press this far (m) into the undeformed wall (tool surface).
    pub press_depth_m: f64,
    /// Slide this far (m) along the wall while pressed.
    pub slide_m: f64,
    /// Durations (s) of approach, press, hold, slide, hold, release.
    pub phases_s: [f64; 6],
    /// Repeat the script until the run ends.
    pub repeat: bool,
}

impl Default for InteractionConfig {
    fn default() -> Self {
        InteractionConfig {
            clearance_m: 5e-3,
            press_depth_m: 5e-3,
            slide_m: 10e-3,
            phases_s: [1.0, 1.0, 1.0, 2.0, 1.0, 1.0],
            repeat: true,
        }
    }
}

/// Watchdog limits.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct WatchdogConfig {
    /// No new model from the background within this time (ms): keep the
    /// last one and flag it.
    pub model_timeout_ms: f64,
    /// No fresh device sample within this time (ms): ramp the force to zero.
    pub device_timeout_ms: f64,
    /// This many consecutive deadline misses: ramp the force to zero.
    pub overrun_streak: u32,
    /// Time (ms) to ramp the force from full to zero on a fault (≤ 10).
    pub ramp_down_ms: f64,
    /// Time (s) to ramp the force in at start and after a fault clears.
    pub ramp_in_s: f64,
    /// No new model within this time (ms, ≥ `model_timeout_ms`): the
    /// background has stopped (stalled or lost), ramp the force to zero.
    pub model_max_age_ms: f64,
    /// Fastest plausible stylus speed (m/s): a sample that jumped farther
    /// is a wild pose, dropped, and a fault.
    pub max_speed_m_s: f64,
    /// Farthest plausible stylus position from the device origin (m).
    pub max_reach_m: f64,
    /// The device side stops applying a force command older than this
    /// (ms): the OpenHaptics servo callback and the simulated Touch X zero
    /// the output until a newer command arrives. It guards against a stalled
    /// service, which the watchdog above cannot (it runs in the service).
    pub command_timeout_ms: f64,
}

impl Default for WatchdogConfig {
    fn default() -> Self {
        WatchdogConfig {
            model_timeout_ms: 500.0,
            device_timeout_ms: 5.0,
            overrun_streak: 5,
            ramp_down_ms: 4.0,
            ramp_in_s: 0.5,
            model_max_age_ms: 3000.0,
            max_speed_m_s: 5.0,
            max_reach_m: 0.25,
            command_timeout_ms: 10.0,
        }
    }
}

/// The background full NVTMM solve.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BackgroundConfig {
    /// Smallest time step of the full solve (s). Each step covers the time
    /// the solve is behind the wall clock, clamped to [dt, dt_max], so the
    /// full solve follows real time and makes up for a slow step with the
    /// next ones; it never runs ahead (it sleeps).
    pub dt: f64,
    /// Largest time step of the full solve (s).
    pub dt_max: f64,
    /// Run the full solve and refresh the reduced model (false: the loop
    /// keeps the model linearized at rest, a linear reduced model).
    pub enabled: bool,
    /// CPU of the background thread (-1: not pinned). The basis
    /// recomputation is not pinned: it runs at `basis_nice` on its own
    /// rayon pool, on whichever core the full solve leaves idle.
    pub cpu: i32,
    /// Background basis refresh: shortest time between recomputations of
    /// the modal basis at the full solve's state (s); 0 turns it off.
    pub basis_refresh_s: f64,
    /// Background basis refresh: recompute only once the full solve's
    /// displacement has changed by this much at some node since the basis
    /// in use was computed (m).
    pub basis_refresh_m: f64,
    /// Nice value (0..=19) of the basis thread and of its own rayon pool:
    /// the basis recomputation takes only the CPU time the full solve
    /// leaves, so it never slows the full solve down (docs/SERVICE.md).
    pub basis_nice: i32,
}

impl Default for BackgroundConfig {
    fn default() -> Self {
        BackgroundConfig {
            dt: 0.01,
            dt_max: 0.01,
            enabled: true,
            cpu: -1,
            basis_refresh_s: 5.0,
            basis_refresh_m: 5e-4,
            basis_nice: 19,
        }
    }
}

/// Ring capacities (items). Overflow policies are fixed per ring and
/// documented in `docs/SERVICE.md`.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RingConfig {
    /// Device → loop pose samples.
    pub pose: usize,
    /// Loop → device force commands.
    pub force: usize,
    /// Loop → background contact forces (one message per tick in contact).
    pub contact: usize,
    /// Background → loop new reduced models.
    pub model: usize,
    /// Loop → background returned models (to be freed off the RT thread).
    pub returned: usize,
    /// Loop → stream state snapshots.
    pub state: usize,
}

impl Default for RingConfig {
    fn default() -> Self {
        RingConfig {
            pose: 64,
            force: 64,
            contact: 2048,
            model: 2,
            returned: 4,
            state: 64,
        }
    }
}

/// The end-of-run report.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct ReportConfig {
    /// Print a one-line status every second while running.
    pub live: bool,
}

impl ServiceConfig {
    /// Reads and validates `path`.
    pub fn load(path: &Path) -> Result<ServiceConfig, ConfigError> {
        let mut cfg: ServiceConfig = load_toml(path)?;
        cfg.path = path.to_path_buf();
        cfg.validate()?;
        Ok(cfg)
    }

    /// Parses and validates configuration text; `path` names it in messages
    /// and is the base for its relative paths (it need not exist).
    pub fn parse(text: &str, path: &Path) -> Result<ServiceConfig, ConfigError> {
        let mut cfg: ServiceConfig = crate::config::parse_toml(text, path)?;
        cfg.path = path.to_path_buf();
        cfg.validate()?;
        Ok(cfg)
    }

    /// Resolves a path given in this file relative to the file's directory.
    pub fn resolve(&self, p: &Path) -> PathBuf {
        if p.is_absolute() {
            p.to_path_buf()
        } else {
            self.path.parent().unwrap_or(Path::new(".")).join(p)
        }
    }

    /// Checks every key against its allowed range.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let c = Checker::new(&self.path);
        c.f64_in("seconds", self.seconds, 0.1, 86_400.0, "s")?;
        let l = &self.servo;
        c.f64_in("loop.rate_hz", l.rate_hz, 100.0, 10_000.0, "Hz")?;
        c.int_in("loop.priority", l.priority, 0, 99)?;
        c.int_in("loop.cpu", l.cpu, -1, 1023)?;
        c.int_in("loop.stack_kib", l.stack_kib, 256, 65_536)?;
        c.f64_in("loop.baseline_s", l.baseline_s, 0.0, 60.0, "s")?;
        c.f64_in("loop.swap_blend_ms", l.swap_blend_ms, 0.0, 1000.0, "ms")?;
        if l.keep_cpu_awake && l.cpu < 0 {
            return Err(c.err(
                "loop.keep_cpu_awake",
                "needs the loop pinned: set loop.cpu to a CPU (0 or more)",
            ));
        }
        let d = &self.device;
        c.f64_in("device.rate_hz", d.rate_hz, 100.0, 10_000.0, "Hz")?;
        c.int_in("device.priority", d.priority, 0, 99)?;
        c.int_in("device.cpu", d.cpu, -1, 1023)?;
        for (k, v) in d.origin_m.iter().enumerate() {
            c.f64_in(&format!("device.origin_m[{k}]"), *v, -10.0, 10.0, "m")?;
        }
        if let Some(second) = &d.second {
            if second.instrument != "guidewire" && second.instrument != "catheter" {
                return Err(c.err(
                    "device.second.instrument",
                    format!(
                        "\"{}\": must be \"guidewire\" or \"catheter\" (a hub-driven instrument)",
                        second.instrument
                    ),
                ));
            }
            if self.catheter.is_none() {
                return Err(c.err(
                    "device.second",
                    "a second device drives one of two hub-driven instruments: it needs [catheter] \
                     (with [wire] and [guidewire]); with the guidewire alone the first device drives it",
                ));
            }
        }
        let i = &self.interaction;
        c.f64_in("interaction.clearance_m", i.clearance_m, 0.0, 0.05, "m")?;
        c.f64_in("interaction.press_depth_m", i.press_depth_m, 0.0, 0.03, "m")?;
        c.f64_in("interaction.slide_m", i.slide_m, 0.0, 0.1, "m")?;
        for (k, v) in i.phases_s.iter().enumerate() {
            c.f64_in(&format!("interaction.phases_s[{k}]"), *v, 0.01, 600.0, "s")?;
        }
        let k = &self.contact;
        c.f64_in("contact.tool_radius_m", k.tool_radius_m, 1e-4, 0.02, "m")?;
        c.f64_in("contact.pressure_stiffness", k.pressure_stiffness, 1.0, 1e12, "Pa/m")?;
        c.f64_in("contact.search_margin_m", k.search_margin_m, 0.0, 0.05, "m")?;
        let w = &self.watchdog;
        c.f64_in("watchdog.model_timeout_ms", w.model_timeout_ms, 1.0, 60_000.0, "ms")?;
        c.f64_in("watchdog.device_timeout_ms", w.device_timeout_ms, 1.0, 1_000.0, "ms")?;
        c.int_in("watchdog.overrun_streak", w.overrun_streak, 1, 10_000)?;
        c.f64_in("watchdog.ramp_down_ms", w.ramp_down_ms, 0.0, 10.0, "ms")?;
        c.f64_in("watchdog.ramp_in_s", w.ramp_in_s, 0.0, 10.0, "s")?;
        c.f64_in(
            "watchdog.model_max_age_ms",
            w.model_max_age_ms,
            w.model_timeout_ms,
            3_600_000.0,
            "ms",
        )?;
        c.f64_in("watchdog.max_speed_m_s", w.max_speed_m_s, 0.1, 100.0, "m/s")?;
        c.f64_in("watchdog.max_reach_m", w.max_reach_m, 0.01, 10.0, "m")?;
        c.f64_in("watchdog.command_timeout_ms", w.command_timeout_ms, 2.0, 1_000.0, "ms")?;
        let b = &self.background;
        c.f64_in("background.dt", b.dt, 1e-4, 0.1, "s")?;
        c.f64_in("background.dt_max", b.dt_max, b.dt, 1.0, "s (at least background.dt)")?;
        c.int_in("background.cpu", b.cpu, -1, 1023)?;
        c.f64_in(
            "background.basis_refresh_s",
            b.basis_refresh_s,
            0.0,
            3600.0,
            "s (0: off)",
        )?;
        c.f64_in("background.basis_refresh_m", b.basis_refresh_m, 0.0, 1.0, "m")?;
        c.int_in("background.basis_nice", b.basis_nice, 0, 19)?;
        let r = &self.rings;
        c.int_in("rings.pose", r.pose, 2, 65_536)?;
        c.int_in("rings.force", r.force, 2, 65_536)?;
        c.int_in("rings.contact", r.contact, 2, 65_536)?;
        c.int_in("rings.model", r.model, 1, 64)?;
        c.int_in("rings.returned", r.returned, 1, 64)?;
        c.int_in("rings.state", r.state, 2, 65_536)?;
        let mut qp = self.passivity.clone();
        qp.dt_s = 1.0 / l.rate_hz;
        qp.validate(&c, "passivity")?;
        self.stream.validate(&c, "stream")?;
        if let Some(f) = &d.frame {
            f.validate(&self.path, "device.frame.")?;
        }
        match (&self.wire, &self.guidewire) {
            (Some(w), Some(g)) => {
                w.validate(&self.path).map_err(|mut e| {
                    e.key = format!("wire.{}", e.key);
                    e
                })?;
                g.validate(&c, w)?;
            }
            (Some(_), None) => {
                return Err(c.err(
                    "guidewire",
                    "[wire] needs a [guidewire] table (access_point_m, axis, script; docs/SERVICE.md)",
                ))
            }
            (None, Some(_)) => return Err(c.err("wire", "[guidewire] needs a [wire] table (docs/WIRE.md)")),
            (None, None) => {}
        }
        if let Some(cat) = &self.catheter {
            match (&self.wire, &self.guidewire) {
                (Some(w), Some(g)) => cat.validate(&self.path, w, g)?,
                _ => {
                    return Err(c.err(
                        "catheter",
                        "[catheter] runs over the guidewire: it needs [wire] and [guidewire] (docs/INSTRUMENTS.md)",
                    ))
                }
            }
        }
        if let Some(t) = &self.task {
            if self.wire.is_none() {
                return Err(c.err("task", "a task needs an instrument: add [wire] and [guidewire]"));
            }
            t.validate(&c)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::parse_toml;

    #[test]
    fn defaults_validate_and_bad_keys_are_named() {
        let p = Path::new("nvtmm.toml");
        let mut cfg: ServiceConfig = parse_toml("scene = \"s.toml\"", p).unwrap();
        cfg.path = p.into();
        cfg.validate().unwrap();
        let mut bad: ServiceConfig = parse_toml("scene = \"s.toml\"\n[loop]\npriority = 120", p).unwrap();
        bad.path = p.into();
        let e = bad.validate().unwrap_err();
        assert_eq!(e.key, "loop.priority");
        let e = parse_toml::<ServiceConfig>("scene = \"s.toml\"\n[device]\nbackend = \"phantom\"", p).unwrap_err();
        assert!(e.msg.contains("phantom"), "{e}");
        let mut bad: ServiceConfig = parse_toml("scene = \"s.toml\"\n[watchdog]\nramp_down_ms = 50", p).unwrap();
        bad.path = p.into();
        assert_eq!(bad.validate().unwrap_err().key, "watchdog.ramp_down_ms");
        // Keeping the loop's CPU awake needs the loop pinned.
        let mut bad: ServiceConfig =
            parse_toml("scene = \"s.toml\"\n[loop]\ncpu = -1\nkeep_cpu_awake = true", p).unwrap();
        bad.path = p.into();
        let e = bad.validate().unwrap_err();
        assert_eq!(e.key, "loop.keep_cpu_awake");
        assert!(e.msg.contains("loop.cpu"), "{e}");
    }
}
