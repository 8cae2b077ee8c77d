//! Everything built before the threads start: the configuration and the
//! scene are read and validated, the basis is computed or loaded from the
//! cache, and the device is opened. Errors name the file and the key.

use super::config::{Backend, ServiceConfig};
use super::script::{press_target, scripted_press};
use super::{ConfigSource, ServiceError, StartOptions};
use crate::haptics::device::HapticDevice;
use crate::haptics::passivity::PassivityParams;
use crate::math::Vec3;
use crate::mesh::TetMesh;
use crate::model::BlockTangent;
use crate::reduced::cache::{load_or_compute, BasisRequest, CacheStatus, Pressurized};
use crate::reduced::compliance::{ComplianceParams, ComplianceStats, LocalCompliance};
use crate::reduced::{BasisParams, DynamicsParams, ModalBasis};
use crate::scene::{Inflated, Scene};
use std::path::PathBuf;
use std::sync::Arc;

/// Everything built before the threads start (shared by all capacities).
pub struct Prepared {
    /// The configuration.
    pub cfg: ServiceConfig,
    /// The scene.
    pub scene: Scene,
    /// The mesh.
    pub mesh: Arc<TetMesh>,
    /// The full model.
    pub model: Box<dyn crate::model::ForceModel>,
    /// Fixed nodes.
    pub fixed: Vec<u32>,
    /// Lumped mass.
    pub mass: Vec<f64>,
    /// The basis.
    pub basis: ModalBasis,
    /// Basis seconds (0 on a cache hit).
    pub basis_s: f64,
    /// Cache outcome.
    pub basis_cache: String,
    /// Reduced damping.
    pub dynamics: DynamicsParams,
    /// The device.
    pub device: Box<dyn HapticDevice>,
    /// The eyes of the simulated hand that watches (a `catheter.script`
    /// with watched moves), for the stream publisher's thread; None
    /// otherwise.
    pub hand_watcher: Option<super::script::TipWatcher>,
    /// The passivity parameters.
    pub passivity: PassivityParams,
    /// The loop runs this long (s).
    pub seconds: f64,
    /// Record the stream here.
    pub record: Option<PathBuf>,
    /// Contact region of the basis's static modes.
    pub contact: Vec<u32>,
    /// Static directions the basis keeps.
    pub max_static: usize,
    /// Contact anywhere: the residual compliance of the basis and how it
    /// was built (None: off).
    pub compliance: Option<(Arc<LocalCompliance>, ComplianceParams, ComplianceStats)>,
    /// The scene's luminal pressure (None: off), for the background solve.
    pub pressure: Option<crate::solver::pressure::LuminalPressure>,
    /// With a pressure: the wall inflated to its mean, where the service
    /// starts (None: at rest; docs/PRESSURE.md "Pressure in the service").
    pub inflated: Option<Inflated>,
}

/// Loads the configuration and the scene, computes (or loads) the basis and
/// opens the device.
pub fn prepare(opts: &StartOptions) -> Result<Prepared, ServiceError> {
    let cfg = match &opts.config {
        ConfigSource::File(path) => ServiceConfig::load(path)?,
        ConfigSource::Text { toml, path } => ServiceConfig::parse(toml, path)?,
    };
    let seconds = opts.seconds.unwrap_or(cfg.seconds);
    crate::config::Checker::new(&cfg.path).f64_in("--seconds", seconds, 0.1, 86_400.0, "s")?;
    let scene_path = cfg.resolve(&cfg.scene);
    let scene = Scene::load(&scene_path).map_err(|e| ServiceError::SceneOf {
        config: cfg.path.clone(),
        scene: cfg.scene.clone(),
        source: e,
    })?;
    let t_build = std::time::Instant::now();
    let mut built = scene.build()?;
    let build_s = t_build.elapsed().as_secs_f64();
    let mut pressure = built.loads.pressure.take();
    let red = scene.reduced.clone().ok_or_else(|| {
        crate::config::Checker::new(&scene_path).err(
            "reduced",
            "the service needs a [reduced] table (r, contact_modes, contact_region)",
        )
    })?;
    let contact = if red.contact_modes {
        scene.contact_nodes(&built.mesh)?
    } else {
        Vec::new()
    };
    let mass = built.mesh.lumped_mass(built.material.density);
    let inflated = match pressure.as_mut() {
        Some(load) => {
            if let Some(u) = &built.unloaded {
                opts.observer.message(&if u.cache_hit {
                    format!("nvtmm run: zero-pressure reference read from {}", u.path.display())
                } else {
                    format!(
                        "nvtmm run: zero-pressure reference computed ({} iterations, {:.3} mm from the image; scene built in {:.1} s), cached in {}",
                        u.iters,
                        u.max_error_m * 1e3,
                        build_s,
                        u.path.display()
                    )
                });
            }
            opts.observer.message(&format!(
                "nvtmm run: inflating the wall to {:.0} Pa...",
                load.schedule.mean_pa
            ));
            let s = scene.inflate(&mut built, load, cfg.background.dt)?;
            opts.observer.message(&format!(
                "nvtmm run: inflated by up to {:.2} mm ({} Newton iterations, {:.1} s)",
                s.max_u_m * 1e3,
                s.newton_iters,
                s.solve_s
            ));
            Some(s)
        }
        None => None,
    };
    if opts.observer.is_active() {
        opts.observer.message(&format!(
            "nvtmm run: {} nodes, {} tets; basis r = {} ({} contact nodes)...",
            built.mesh.num_nodes(),
            built.mesh.tets().len(),
            red.r,
            contact.len()
        ));
    }
    let req = BasisRequest {
        mesh: &built.mesh,
        model: built.model.as_ref(),
        material: built.material,
        law: scene.material.law,
        mass: &mass,
        fixed: &built.fixed,
        r: red.r,
        contact: &contact,
        max_static: red.r / 2,
        params: BasisParams::default(),
        // With a pressure, the modes of the inflated wall: its tangent
        // has the pressure's load stiffness (docs/PRESSURE.md).
        pressurized: inflated.as_ref().map(|s| Pressurized {
            mean_pa: pressure.as_ref().map_or(0.0, |l| l.schedule.mean_pa),
            tangent: &s.tangent,
        }),
    };
    let max_static = red.r / 2;
    let dir = red.cache.then(|| scene.cache_dir());
    let (basis, outcome) = load_or_compute(&req, dir.as_deref(), false)?;
    let basis_cache = match &outcome.status {
        CacheStatus::Hit => "hit".to_string(),
        CacheStatus::Computed => "computed".to_string(),
        CacheStatus::Recomputed(why) => format!("recomputed ({why})"),
        CacheStatus::Bypassed => "off".to_string(),
    };
    let mut passivity = cfg.passivity.clone();
    passivity.dt_s = 1.0 / cfg.servo.rate_hz;
    let dynamics = DynamicsParams {
        dt: 1.0 / cfg.servo.rate_hz,
        alpha: red.alpha,
        beta: red.beta,
    };
    let compliance = match scene.compliance_params() {
        Some(cp) => {
            opts.observer
                .message("nvtmm run: residual compliance for contact anywhere...");
            let (table, stats) = match &inflated {
                Some(s) => LocalCompliance::compute(&built.mesh, &s.tangent, &basis, &cp),
                None => {
                    let mut k = BlockTangent::zeros(&built.mesh);
                    let zeros = vec![Vec3::zeros(); built.mesh.num_nodes()];
                    built.model.add_stiffness(&zeros, &mut k);
                    LocalCompliance::compute(&built.mesh, &k, &basis, &cp)
                }
            }
            .map_err(ServiceError::Solver)?;
            Some((Arc::new(table), cp, stats))
        }
        None => None,
    };
    let (device, hand_watcher) = match &opts.device {
        Some(factory) => (
            (factory.0)(&super::DeviceContext {
                cfg: &cfg,
                mesh: &built.mesh,
                scene: &scene,
                seconds,
            })?,
            None,
        ),
        None => make_watched_device(&cfg, &built.mesh, &scene, seconds)?,
    };
    Ok(Prepared {
        hand_watcher,
        compliance,
        basis_s: outcome.compute_s,
        basis_cache,
        mesh: Arc::new(built.mesh),
        model: built.model,
        fixed: built.fixed,
        mass,
        basis,
        dynamics,
        device,
        passivity,
        seconds,
        record: opts.record.clone(),
        contact,
        max_static,
        scene,
        cfg,
        pressure,
        inflated,
    })
}

/// Opens the configured device backend. A simulated hand that watches
/// (`catheter.script` with watched moves) sees nothing through this one:
/// its watched moves run to their limits and wait their `within_s`; the
/// service opens it with its eyes ([`make_watched_device`]).
pub fn make_device(
    cfg: &ServiceConfig,
    mesh: &TetMesh,
    scene: &Scene,
    seconds: f64,
) -> Result<Box<dyn HapticDevice>, ServiceError> {
    make_watched_device(cfg, mesh, scene, seconds).map(|(d, _)| d)
}

/// Opens the configured device backend and, for a simulated hand that
/// watches, the watcher that shows it the instruments' tips (the stream
/// publisher runs it).
pub fn make_watched_device(
    cfg: &ServiceConfig,
    mesh: &TetMesh,
    scene: &Scene,
    seconds: f64,
) -> Result<(Box<dyn HapticDevice>, Option<super::script::TipWatcher>), ServiceError> {
    let origin = Vec3::from(cfg.device.origin_m);
    let command_timeout_s = cfg.watchdog.command_timeout_ms * 1e-3;
    match cfg.device.backend {
        Backend::TouchxSim => {
            use crate::haptics::touchx::{TouchXParams, TouchXSim, Waypoint};
            let params = TouchXParams::load(&cfg.resolve(&cfg.device.touchx))?;
            if let (Some(wire), Some(g), Some(cat)) = (&cfg.wire, &cfg.guidewire, &cfg.catheter) {
                if cat.watches() {
                    return watching_hand(params, cfg, mesh, wire, g, cat).map(|(d, w)| (d, Some(w)));
                }
                // The pair's scripted hand: one stylus, the switch button
                // between the guidewire and the catheter.
                let hand = cat
                    .hand(g, wire)
                    .map_err(|e| ServiceError::Device(format!("catheter.script: {e}")))?;
                let mut dev = TouchXSim::new(params, &hand.points).map_err(|e| ServiceError::Device(e.to_string()))?;
                dev.set_gimbal_script(&hand.gimbal)
                    .and_then(|()| dev.set_button_script(&hand.buttons))
                    .map_err(|e| ServiceError::Device(e.to_string()))?;
                dev.set_command_timeout(command_timeout_s);
                return Ok((Box::new(dev), None));
            }
            if let (Some(wire), Some(g)) = (&cfg.wire, &cfg.guidewire) {
                // The guidewire's scripted hand: stylus along the drive's
                // axis, roll on its gimbal joint.
                let (pts, gimbal) = super::instrument::guidewire::hand_script(g, wire);
                let mut dev = TouchXSim::new(params, &pts).map_err(|e| ServiceError::Device(e.to_string()))?;
                dev.set_gimbal_script(&gimbal)
                    .map_err(|e| ServiceError::Device(e.to_string()))?;
                dev.set_command_timeout(command_timeout_s);
                return Ok((Box::new(dev), None));
            }
            let (_, p, n, t) = press_target(mesh, scene);
            let pts: Vec<Waypoint> = scripted_press(p, n, t, &cfg.interaction, cfg.contact.tool_radius_m, seconds)
                .into_iter()
                .map(|(t_s, x)| Waypoint {
                    t_s,
                    position: x - origin,
                })
                .collect();
            let mut dev = TouchXSim::new(params, &pts).map_err(|e| ServiceError::Device(e.to_string()))?;
            dev.set_command_timeout(command_timeout_s);
            Ok((Box::new(dev), None))
        }
        Backend::Udp => {
            use crate::haptics::udp::{UdpDevice, UdpParams};
            let params = UdpParams::load(&cfg.resolve(&cfg.device.udp))?;
            Ok((Box::new(UdpDevice::new(params)), None))
        }
        Backend::Openhaptics => open_openhaptics(command_timeout_s).map(|d| (d, None)),
        Backend::Host => Err(ServiceError::Device(
            "device.backend = \"host\": the host application starts the service with its device \
             (haptics::host::host_device in StartOptions::device, or nvtmm_start_host in the C ABI)"
                .into(),
        )),
    }
}

/// The simulated Touch X with the pair's hand that watches: it plays
/// `catheter.script` on line ([`super::script::WatchingHand`]), seeing the
/// tips through the returned watcher. Errors name the row.
fn watching_hand(
    params: crate::haptics::touchx::TouchXParams,
    cfg: &ServiceConfig,
    mesh: &TetMesh,
    wire: &crate::wire::WireParams,
    g: &super::instrument::guidewire::GuidewireConfig,
    cat: &super::instrument::catheter::CatheterConfig,
) -> Result<(Box<dyn HapticDevice>, super::script::TipWatcher), ServiceError> {
    use super::script::{TipWatch, TipWatcher, WatchingHand};
    use crate::haptics::touchx::{TouchXSim, Waypoint};
    let bad = |e: String| ServiceError::Device(format!("catheter.script{e}"));
    // Checks order, switches and the stylus's extremes.
    cat.hand(g, wire).map_err(|e| bad(format!(": {e}")))?;
    let steps = cat
        .steps(g, [f64::INFINITY; 2])
        .map_err(|(k, e)| bad(format!("{k}: {e}")))?;
    let map = crate::task::SegmentMap::from_mesh(mesh, &g.wall_set).map_err(|e| bad(format!(": {e}")))?;
    let watch = Arc::new(TipWatch::new(&steps));
    let start = cat.start(g);
    let hand = WatchingHand::new(&steps, &wire.drive, &start, map.names(), watch.clone()).map_err(bad)?;
    let mut dev = TouchXSim::new(
        params,
        &[Waypoint {
            t_s: 0.0,
            position: wire.drive.stylus_at(start[0].0),
        }],
    )
    .map_err(|e| ServiceError::Device(e.to_string()))?;
    dev.set_live_hand(Box::new(hand));
    dev.set_command_timeout(cfg.watchdog.command_timeout_ms * 1e-3);
    Ok((Box::new(dev), TipWatcher::new(map, watch)))
}

#[cfg(feature = "openhaptics")]
fn open_openhaptics(command_timeout_s: f64) -> Result<Box<dyn HapticDevice>, ServiceError> {
    // Samples older than the device watchdog's limit count as stale.
    Ok(Box::new(crate::haptics::openhaptics::OpenHapticsDevice::new(
        0.005,
        command_timeout_s,
    )))
}

#[cfg(not(feature = "openhaptics"))]
fn open_openhaptics(_command_timeout_s: f64) -> Result<Box<dyn HapticDevice>, ServiceError> {
    Err(ServiceError::Device(
        "this build has no OpenHaptics backend; rebuild with --features openhaptics on a box with the SDK".into(),
    ))
}
