//! The real-time haptic service, as a library: start it from a
//! configuration file or an in-memory configuration, read its live state
//! while it runs, stop it and get the report. `nvtmm run` is one client of
//! this API; `examples/embed.rs` and the C ABI (`capi/`) are others.
//!
//! ```no_run
//! use nvtmm::service::{Service, StartOptions};
//! let handle = Service::start(StartOptions::file("rt-config/nvtmm.toml")).unwrap();
//! std::thread::sleep(std::time::Duration::from_secs(2));
//! let live = handle.snapshot();
//! println!("{} ticks, force {:?} N", live.ticks, live.force_n);
//! let report = handle.stop().unwrap();
//! println!("{}", report.render());
//! ```
//!
//! Threads (docs/ARCHITECTURE.md, docs/SERVICE.md): device I/O
//! ([`device_io`]), the 1 kHz haptic loop ([`loop_thread`], one
//! [`crate::haptics::tick::HapticTick`] per period), the background full
//! NVTMM solve and the basis thread ([`background`]), the stream
//! publisher ([`publisher`]), and the instruments' own threads
//! ([`instrument`]: the probe, the guidewire, behind one seam). [`setup`]
//! builds what they need before they start; [`running`] starts and stops
//! them and assembles the [`Report`].

pub mod background;
pub mod config;
pub mod device_io;
pub mod faults;
pub mod instrument;
pub mod live;
pub mod loop_thread;
pub mod publisher;
pub mod report;
pub mod running;
pub mod script;
pub mod setup;
mod task_feed;

/// The guidewire's service code, under its old path (it lives in
/// [`instrument::guidewire`]).
pub use instrument::guidewire as wire;

pub use config::ServiceConfig;
pub use live::{FaultTicks, FrameSnapshot, InstrumentPolyline, Snapshot};
pub use report::Report;

use running::RunningService;
use std::path::{Path, PathBuf};

/// Why the service could not start (or stop cleanly).
#[derive(Debug, thiserror::Error)]
pub enum ServiceError {
    /// Bad service configuration.
    #[error(transparent)]
    Config(#[from] crate::config::ConfigError),
    /// The scene the configuration names could not be used: the service
    /// configuration file and its `scene` key, then the scene's own error.
    #[error("{config}: scene = {scene:?}: {source}")]
    SceneOf {
        /// The service configuration file.
        config: PathBuf,
        /// The value of its `scene` key.
        scene: PathBuf,
        /// What is wrong with the scene.
        source: crate::scene::SceneError,
    },
    /// The reduced model could not be built.
    #[error("reduced model: {0}")]
    Reduced(#[from] crate::reduced::ReducedError),
    /// The device could not be set up.
    #[error("device: {0}")]
    Device(String),
    /// The passivity filter could not be built.
    #[error(transparent)]
    Passivity(#[from] crate::haptics::passivity::PassivityError),
    /// The full solver could not be built.
    #[error("background solver: {0}")]
    Solver(String),
    /// A thread could not be started or panicked (its name and the panic
    /// message).
    #[error("thread {0}: {1}")]
    Thread(&'static str, String),
}

/// Where the service configuration comes from.
#[derive(Debug, Clone, PartialEq)]
pub enum ConfigSource {
    /// A TOML file (`rt-config/nvtmm.toml`); relative paths in it (the
    /// scene, the device files) resolve against its directory.
    File(PathBuf),
    /// TOML text built in memory; `path` names it in messages and relative
    /// paths resolve against its directory (the file need not exist).
    Text {
        /// The configuration, TOML.
        toml: String,
        /// Label and base for relative paths, e.g. `rt-config/inline.toml`.
        path: PathBuf,
    },
}

/// How to start the service.
#[derive(Debug, Clone, PartialEq)]
pub struct StartOptions {
    /// The configuration.
    pub config: ConfigSource,
    /// Length of the simulated hand's script and of `nvtmm run` (s); None:
    /// the configuration's `seconds`. The service itself runs until
    /// [`Handle::stop`].
    pub seconds: Option<f64>,
    /// Where progress and messages go (preparation, the run's elapsed
    /// time); silent by default. The library never prints.
    pub observer: crate::observe::Observe,
    /// Record the state stream to this file (also when `[stream]` is off).
    pub record: Option<PathBuf>,
    /// Builds the device in place of the configured backend (the soak's
    /// instrumented device, a test double); None: the configured one.
    pub device: Option<DeviceFactory>,
}

/// What a [`DeviceFactory`] is given: the validated configuration, the mesh
/// and scene the service runs, and the run length.
#[derive(Debug, Clone, Copy)]
pub struct DeviceContext<'a> {
    /// The service configuration.
    pub cfg: &'a ServiceConfig,
    /// The mesh (scene frame, m).
    pub mesh: &'a crate::mesh::TetMesh,
    /// The scene.
    pub scene: &'a crate::scene::Scene,
    /// Run length (s).
    pub seconds: f64,
}

/// A device builder function: [`setup::make_device`] builds the configured
/// one, if the factory wants to wrap it.
pub type DeviceBuilder =
    dyn Fn(&DeviceContext<'_>) -> Result<Box<dyn crate::haptics::device::HapticDevice>, ServiceError> + Send + Sync;

/// A device builder to use instead of the configured backend
/// ([`StartOptions::device`]). Compares by identity.
#[derive(Clone)]
pub struct DeviceFactory(pub std::sync::Arc<DeviceBuilder>);

impl std::fmt::Debug for DeviceFactory {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("DeviceFactory(..)")
    }
}

impl PartialEq for DeviceFactory {
    fn eq(&self, other: &Self) -> bool {
        std::sync::Arc::ptr_eq(&self.0, &other.0)
    }
}

impl StartOptions {
    /// Options for the configuration file at `path`, everything else default.
    pub fn file(path: impl Into<PathBuf>) -> StartOptions {
        StartOptions {
            config: ConfigSource::File(path.into()),
            seconds: None,
            observer: crate::observe::Observe::none(),
            record: None,
            device: None,
        }
    }

    /// Options for an in-memory configuration (`path`: label and base
    /// directory for the relative paths in it).
    pub fn text(toml: impl Into<String>, path: impl Into<PathBuf>) -> StartOptions {
        StartOptions {
            config: ConfigSource::Text {
                toml: toml.into(),
                path: path.into(),
            },
            seconds: None,
            observer: crate::observe::Observe::none(),
            record: None,
            device: None,
        }
    }
}

/// The service: [`Service::start`] is the way in.
#[derive(Debug)]
pub struct Service;

impl Service {
    /// Reads and validates the configuration and the scene, computes or loads
    /// the reduced basis, opens the device and starts every thread. Returns
    /// once the threads run (the loop begins after its jitter baseline).
    pub fn start(opts: StartOptions) -> Result<Handle, ServiceError> {
        let p = setup::prepare(&opts)?;
        let inner: Box<dyn RunningService> = match p.basis.len() {
            0..=16 => Box::new(running::start_with::<16>(p)?),
            17..=32 => Box::new(running::start_with::<32>(p)?),
            _ => Box::new(running::start_with::<64>(p)?),
        };
        Ok(Handle { inner: Some(inner) })
    }
}

/// A running service. Dropping it stops the service (and discards the
/// report); call [`Handle::stop`] to get it.
pub struct Handle {
    inner: Option<Box<dyn RunningService>>,
}

impl std::fmt::Debug for Handle {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Handle")
            .field("running", &self.inner.is_some())
            .finish()
    }
}

impl Handle {
    /// Live figures and the latest state frame. Cheap (a copy of a few
    /// atomics and of the last frame); any thread, any time.
    pub fn snapshot(&self) -> Snapshot {
        self.inner.as_ref().map(|r| r.snapshot()).unwrap_or_default()
    }

    /// The jitter baseline plus the configured run length (s): how long
    /// `nvtmm run` lets it run.
    pub fn planned_seconds(&self) -> f64 {
        self.inner.as_ref().map(|r| r.planned_s()).unwrap_or(0.0)
    }

    /// Whether the loop or the device thread has ended on its own (a fault
    /// that stopped it); [`Handle::stop`] then says why.
    pub fn is_finished(&self) -> bool {
        self.inner.as_ref().is_none_or(|r| r.is_finished())
    }

    /// The fault-injection switches of this run ([`faults::FaultSwitches`]),
    /// for soak and recovery tests.
    pub fn faults(&self) -> std::sync::Arc<faults::FaultSwitches> {
        self.inner.as_ref().map(|r| r.faults()).unwrap_or_default()
    }

    /// Stops every thread, joins them and returns the report.
    pub fn stop(mut self) -> Result<Report, ServiceError> {
        match self.inner.take() {
            Some(mut r) => r.stop(),
            None => Err(ServiceError::Thread("service", "already stopped".into())),
        }
    }
}

impl Drop for Handle {
    fn drop(&mut self) {
        if let Some(mut r) = self.inner.take() {
            let _ = r.stop();
        }
    }
}

/// The whole of `nvtmm run`: start, let it run for the configured time
/// (its progress, in seconds, to `opts.observer` as task `"run"`), stop,
/// return the report.
pub fn run_service(opts: &StartOptions) -> Result<Report, ServiceError> {
    run_service_until(opts, &std::sync::atomic::AtomicBool::new(false))
}

/// [`run_service`] that also stops early, with the same orderly stop
/// (force to zero, threads joined, the report), once `interrupt` is set:
/// the command line sets it on SIGINT or SIGTERM, so Ctrl-C or `systemctl
/// stop` never leaves a force playing. A flag set before the service has
/// started stops it right after its start.
pub fn run_service_until(
    opts: &StartOptions,
    interrupt: &std::sync::atomic::AtomicBool,
) -> Result<Report, ServiceError> {
    let handle = Service::start(opts.clone())?;
    let total = handle.planned_seconds();
    let t0 = std::time::Instant::now();
    let obs = &opts.observer;
    while t0.elapsed().as_secs_f64() < total + 0.05 && !interrupt.load(std::sync::atomic::Ordering::Relaxed) {
        std::thread::sleep(std::time::Duration::from_millis(100));
        if obs.is_active() {
            let detail = format!("{} ticks", handle.snapshot().ticks);
            obs.progress("run", t0.elapsed().as_secs_f64().min(total), total, &detail);
        }
        if handle.is_finished() {
            break;
        }
    }
    obs.finished("run", true);
    handle.stop()
}

/// The default configuration file: `rt-config/nvtmm.toml` under the working
/// directory if it is there, else the one in the source tree this binary was
/// built from (so `nvtmm run` works from any directory of a checkout).
pub fn default_config() -> PathBuf {
    let local = Path::new("rt-config").join("nvtmm.toml");
    if local.is_file() {
        return local;
    }
    let built = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("rt-config")
        .join("nvtmm.toml");
    if built.is_file() {
        built
    } else {
        local
    }
}
