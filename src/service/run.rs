//! Starting, running and stopping the service: builds the scene, the basis
//! (through the cache), the first reduced model, the surface index and the
//! device; starts the device I/O thread, the haptic loop, the background
//! solve (and the stream publisher); waits; stops everything and gathers the
//! report.
//!
//! Threads and rings (each ring: capacity from `[rings]`, overflow policy,
//! counter):
//!
//! ```text
//! device I/O --pose (drop newest)--> loop --force (drop newest)--> device I/O
//! loop --contact (drop newest)--> background --model (keep latest, retry)--> loop
//! loop --returned (loop defers the swap; never drops)--> background (frees)
//! loop --state (drop newest)--> publisher
//! ```

use super::background::{
    self, Background, BackgroundIo, BackgroundStats, BasisJob, BasisPolicy, BasisStats, BasisWorker, ContactMsg,
    NewBasis, OffsetMsg, CONTACT_MSG_NODES,
};
use super::config::{Backend, ServiceConfig};
use super::report::{BackgroundReport, QpReport, Report, RingReport};
use crate::haptics::contact::{NodeContact, SurfaceIndex};
use crate::haptics::device::{DeviceSample, HapticDevice, PortEnergy};
use crate::haptics::passivity::{PassivityFilter, PassivityParams};
use crate::haptics::servo::{flags, LoopModel, Servo, ServoCounters, ServoParams};
use crate::math::Vec3;
use crate::mesh::TetMesh;
use crate::reduced::cache::{load_or_compute, BasisRequest, CacheStatus};
use crate::reduced::{basis_rows, BasisParams, DynamicsParams, ModalBasis, Refresher};
use crate::rt::clock::{self, Nanos};
use crate::rt::stats::{Histogram, Percentiles};
use crate::rt::thread::{lock_memory, setup_current, RtGrant, RtRequest};
use crate::scene::Scene;
use crate::solver::ImplicitEuler;
use nalgebra::SVector;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;

/// Why the service could not start.
#[derive(Debug, thiserror::Error)]
pub enum ServiceError {
    /// Bad service configuration.
    #[error(transparent)]
    Config(#[from] crate::config::ConfigError),
    /// Bad scene.
    #[error(transparent)]
    Scene(#[from] crate::scene::SceneError),
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
    /// A thread could not be started or panicked.
    #[error("thread {0}: {1}")]
    Thread(&'static str, String),
}

/// Options of `nvtmm run`.
#[derive(Debug, Clone, Default)]
pub struct RunOptions {
    /// The service configuration file.
    pub config: PathBuf,
    /// Run length (s); None: the config's `seconds`.
    pub seconds: Option<f64>,
    /// Print progress to stderr.
    pub progress: bool,
    /// Record the state stream to this file (also when `[stream]` is off).
    pub record: Option<PathBuf>,
}

/// A force command (loop → device I/O).
#[derive(Debug, Clone, Copy)]
pub struct ForceCmd {
    /// Force on the hand (N, device frame).
    pub force: Vec3,
    /// Time of the device sample it answers (ns, monotonic).
    pub pose_time: Nanos,
}

/// A loop state snapshot (loop → stream publisher).
#[derive(Debug, Clone, Copy)]
pub struct StateSnapshot<const R: usize> {
    /// Loop time (s).
    pub time_s: f64,
    /// Epoch of the model in use.
    pub epoch: u64,
    /// Reduced coordinates δq.
    pub q: SVector<f64, R>,
    /// Tool centre (m, scene frame).
    pub tool: Vec3,
    /// Commanded force (N).
    pub force: Vec3,
    /// Status bits.
    pub flags: u32,
    /// Largest tick compute time since the previous snapshot (µs).
    pub tick_max_us: f32,
}

/// The scripted press for the simulated device: approach a wall point along
/// its outward normal, press, slide along the wall, release. Returns the
/// scene-frame waypoints (time s, tool centre m).
pub fn scripted_press(
    point: Vec3,
    normal: Vec3,
    tangent: Vec3,
    cfg: &super::config::InteractionConfig,
    radius: f64,
    seconds: f64,
) -> Vec<(f64, Vec3)> {
    let out = point + normal * (radius + cfg.clearance_m);
    let pressed = point + normal * (radius - cfg.press_depth_m);
    let slid = pressed + tangent * cfg.slide_m;
    let slid_out = out + tangent * cfg.slide_m;
    let ph = cfg.phases_s;
    let mut pts = Vec::new();
    let mut t = 0.0;
    loop {
        pts.push((t, out));
        t += ph[0];
        pts.push((t, out));
        t += ph[1];
        pts.push((t, pressed));
        t += ph[2];
        pts.push((t, pressed));
        t += ph[3];
        pts.push((t, slid));
        t += ph[4];
        pts.push((t, slid));
        t += ph[5];
        pts.push((t, slid_out));
        t += 0.5;
        if !cfg.repeat || t > seconds + 1.0 {
            pts.push((t, out));
            break;
        }
    }
    pts
}

/// The wall point the script presses: the surface node nearest the contact
/// region's centre (or the highest outer-wall node), its outward normal and
/// a tangent.
pub fn press_target(mesh: &TetMesh, scene: &Scene) -> (u32, Vec3, Vec3, Vec3) {
    let rest = mesh.rest();
    let normals = mesh.surface_vertex_normals();
    let candidates: Vec<u32> = match mesh.node_set("outer_wall") {
        Some(s) if !s.is_empty() => s.to_vec(),
        _ => mesh.surface_nodes(),
    };
    let center = scene
        .reduced
        .as_ref()
        .and_then(|r| r.contact_region.as_ref())
        .and_then(|c| c.center)
        .map(Vec3::from);
    let node = candidates
        .iter()
        .copied()
        .min_by(|&a, &b| {
            let key = |i: u32| match center {
                Some(c) => (rest[i as usize] - c).norm(),
                None => -rest[i as usize].z,
            };
            key(a).total_cmp(&key(b))
        })
        .unwrap_or(0);
    let n = normals.get(node as usize).copied().unwrap_or(Vec3::z());
    let n = if n.norm() > 0.5 { n } else { Vec3::z() };
    // A tangent: the horizontal direction orthogonal to n closest to x.
    let mut t = Vec3::x() - n * n.x;
    if t.norm() < 1e-6 {
        t = Vec3::y() - n * n.y;
    }
    (node, rest[node as usize], n, t.normalize())
}

/// The loop ticks this long after the device thread reads a sample (ns).
const LOOP_PHASE: Nanos = 200_000;

/// Everything gathered from the loop thread at the end.
struct LoopResult {
    jitter: Histogram,
    compute: Histogram,
    baseline: Histogram,
    qp_us: Histogram,
    grant: RtGrant,
    counters: ServoCounters,
    qp: crate::haptics::passivity::PassivityStats,
    misses: u64,
    misses_compute: u64,
    allocations: u64,
    allocator_installed: bool,
    max_force: f64,
    max_depth: f64,
    seconds: f64,
    force_ring_full: u64,
    contact_ring_full: u64,
    state_ring_full: u64,
    swaps_deferred: u64,
    energy_in: f64,
    energy_out: f64,
}

struct DeviceResult {
    latency: Histogram,
    ticks: u64,
    errors: u64,
    pose_ring_full: u64,
    energy: Option<PortEnergy>,
    allocations: u64,
}

/// Loop-side rings.
struct LoopIo<const R: usize> {
    pose: rtrb::Consumer<DeviceSample>,
    force: rtrb::Producer<ForceCmd>,
    contact: rtrb::Producer<ContactMsg>,
    models: rtrb::Consumer<Box<LoopModel<R>>>,
    returned: rtrb::Producer<Box<LoopModel<R>>>,
    state: Option<rtrb::Producer<StateSnapshot<R>>>,
    stop: Arc<AtomicBool>,
    ticks: Arc<AtomicU64>,
}

struct LoopPlan {
    request: RtRequest,
    period: Nanos,
    start: Nanos,
    loop_start: Nanos,
    baseline_s: f64,
    pool_bytes: usize,
    state_every: u64,
}

fn loop_thread<const R: usize>(
    mut servo: Servo<R>,
    mut filter: PassivityFilter,
    mut io: LoopIo<R>,
    plan: LoopPlan,
) -> LoopResult {
    let grant = setup_current(&plan.request);
    let pool = crate::rt::alloc::enter_rt(plan.pool_bytes);
    let allocator_installed = pool.map(|p| p.installed).unwrap_or(false);
    // Whatever clarabel sizes or frees on its first solve happens now.
    filter.prime();
    let mut res = LoopResult {
        jitter: Histogram::new(),
        compute: Histogram::new(),
        baseline: Histogram::new(),
        qp_us: Histogram::new(),
        grant,
        counters: ServoCounters::default(),
        qp: *filter.stats(),
        misses: 0,
        misses_compute: 0,
        allocations: 0,
        allocator_installed,
        max_force: 0.0,
        max_depth: 0.0,
        seconds: 0.0,
        force_ring_full: 0,
        contact_ring_full: 0,
        state_ring_full: 0,
        swaps_deferred: 0,
        energy_in: 0.0,
        energy_out: 0.0,
    };
    let period = plan.period;
    // The jitter baseline: a bare absolute-deadline sleep loop, same thread,
    // same CPU, same policy, same run.
    let mut next = plan.start;
    let base_end = plan.start + (plan.baseline_s * 1e9) as Nanos;
    while next < base_end && !io.stop.load(Ordering::Relaxed) {
        clock::sleep_until(next);
        res.baseline.record((clock::now_ns() - next) as f64 * 1e-3);
        next += period;
    }
    next = next.max(plan.loop_start);
    let sys0 = crate::rt::alloc::thread_system_calls();
    let t_begin = clock::now_ns();
    let mut streak = 0u32;
    let mut last: Option<DeviceSample> = None;
    let mut last_pose_time: Nanos = 0;
    let dt = period as f64 * 1e-9;
    let mut tick: u64 = 0;
    let mut window_max_us = 0.0f64;
    let mut v_prev = Vec3::zeros();
    // A retired model the return ring had no room for (kept, never freed here).
    let mut pending_return: Option<Box<LoopModel<R>>> = None;
    let mut contact_msg = ContactMsg {
        tick: 0,
        nodes: heapless::Vec::new(),
    };
    while !io.stop.load(Ordering::Relaxed) {
        clock::sleep_until(next);
        let wake = clock::now_ns();
        res.jitter.record((wake - next) as f64 * 1e-3);
        tick += 1;

        // Freshest pose (drain).
        while let Ok(s) = io.pose.pop() {
            last_pose_time = (s.time_s * 1e9) as Nanos + clock::epoch();
            last = Some(s);
        }
        // A new model between ticks; only if the models it retires can be
        // returned (never freed here).
        if !io.models.is_empty() {
            if pending_return.is_none() && io.returned.slots() >= 2 {
                if let Ok(m) = io.models.pop() {
                    if let Some(old) = servo.swap(m) {
                        if let Err(rtrb::PushError::Full(old)) = io.returned.push(old) {
                            pending_return = Some(old);
                        }
                    }
                }
            } else {
                res.swaps_deferred += 1;
            }
        }
        let now_s = clock::to_s(wake);
        let out = servo.tick(last.as_ref(), now_s, streak);
        let (x, v) = last
            .map(|s| (s.position, s.velocity))
            .unwrap_or((Vec3::zeros(), Vec3::zeros()));
        let q0 = clock::now_ns();
        let v_pred = crate::haptics::passivity::predict_velocity(v, v_prev);
        v_prev = v;
        let fo = filter.filter(out.desired, x, v_pred);
        res.qp_us.record((clock::now_ns() - q0) as f64 * 1e-3);
        let mut fl = out.flags;
        if res.grant.fifo {
            fl |= flags::RT_GRANTED;
        }
        if (fo.force - out.desired).norm() > 1e-9 {
            fl |= flags::LIMITED;
        }
        let force = servo.apply_gain(fo.force, &mut fl);
        if fl & flags::NONFINITE != 0 {
            filter.reset();
        }
        let p = force.dot(&v) * dt;
        if p > 0.0 {
            res.energy_out += p;
        } else {
            res.energy_in -= p;
        }
        res.max_force = res.max_force.max(force.norm());
        res.max_depth = res.max_depth.max(out.depth);
        if io
            .force
            .push(ForceCmd {
                force,
                pose_time: last_pose_time,
            })
            .is_err()
        {
            res.force_ring_full += 1;
        }
        let c = servo.contact();
        if !c.nodes.is_empty() {
            contact_msg.tick = tick;
            contact_msg.nodes.clear();
            for nc in c.nodes.iter().take(CONTACT_MSG_NODES) {
                let _ = contact_msg.nodes.push(NodeContact {
                    node: nc.node,
                    force: nc.force,
                });
            }
            if io.contact.push(contact_msg.clone()).is_err() {
                res.contact_ring_full += 1;
            }
        }
        if pending_return.is_none() {
            pending_return = servo.take_retired();
        }
        if let Some(old) = pending_return.take() {
            if let Err(rtrb::PushError::Full(old)) = io.returned.push(old) {
                pending_return = Some(old);
            }
        }
        io.ticks.store(tick, Ordering::Relaxed);
        let end = clock::now_ns();
        let compute = end - wake;
        res.compute.record(compute as f64 * 1e-3);
        window_max_us = window_max_us.max(compute as f64 * 1e-3);
        if let Some(tx) = io.state.as_mut() {
            if tick % plan.state_every == 0 {
                let snap = StateSnapshot {
                    time_s: now_s,
                    epoch: servo.model().epoch,
                    q: *servo.model().dynamics.q(),
                    tool: out.tool,
                    force,
                    flags: fl,
                    tick_max_us: window_max_us as f32,
                };
                window_max_us = 0.0;
                if tx.push(snap).is_err() {
                    res.state_ring_full += 1;
                }
            }
        }
        // Deadlines: a tick that ends after the next deadline is a miss; the
        // loop re-phases to the next future deadline instead of bursting.
        next += period;
        if end > next {
            res.misses += 1;
            if compute > period {
                res.misses_compute += 1;
            }
            streak += 1;
            let behind = (end - next) / period + 1;
            next += behind * period;
        } else {
            streak = 0;
        }
    }
    res.allocations = crate::rt::alloc::thread_system_calls() - sys0;
    // Off the clock: whatever was not returned is freed with the thread.
    drop(pending_return);
    res.seconds = (clock::now_ns() - t_begin) as f64 * 1e-9;
    res.counters = *servo.counters();
    res.qp = *filter.stats();
    crate::rt::alloc::leave_rt();
    res
}

struct DeviceIo {
    pose: rtrb::Producer<DeviceSample>,
    force: rtrb::Consumer<ForceCmd>,
    stop: Arc<AtomicBool>,
}

fn device_thread(
    mut dev: Box<dyn HapticDevice>,
    mut io: DeviceIo,
    request: RtRequest,
    start: Nanos,
    period: Nanos,
    write_offset: Nanos,
    pool_bytes: usize,
) -> (DeviceResult, Box<dyn HapticDevice>) {
    let _grant = setup_current(&request);
    let _ = crate::rt::alloc::enter_rt(pool_bytes);
    let sys0 = crate::rt::alloc::thread_system_calls();
    let mut res = DeviceResult {
        latency: Histogram::new(),
        ticks: 0,
        errors: 0,
        pose_ring_full: 0,
        energy: None,
        allocations: 0,
    };
    let mut next = start;
    while !io.stop.load(Ordering::Relaxed) {
        // Phase 0: the sample for the loop (which ticks 200 µs later).
        clock::sleep_until(next);
        res.ticks += 1;
        match dev.read(clock::now_s()) {
            Ok(s) => {
                if io.pose.push(s).is_err() {
                    res.pose_ring_full += 1;
                }
            }
            Err(_) => res.errors += 1,
        }
        // Phase `write_offset`: the newest force, normally the answer to
        // the sample just read.
        clock::sleep_until(next + write_offset);
        let mut cmd = None;
        while let Ok(c) = io.force.pop() {
            cmd = Some(c);
        }
        if let Some(c) = cmd {
            if dev.write_force(c.force).is_err() {
                res.errors += 1;
            }
            if c.pose_time > 0 {
                res.latency.record((clock::now_ns() - c.pose_time) as f64 * 1e-3);
            }
        }
        next += period;
        let now = clock::now_ns();
        if now > next {
            next += ((now - next) / period + 1) * period;
        }
    }
    let _ = dev.write_force(Vec3::zeros());
    res.energy = dev.port_energy();
    res.allocations = crate::rt::alloc::thread_system_calls() - sys0;
    crate::rt::alloc::leave_rt();
    (res, dev)
}

/// What the publisher thread needs.
struct PublisherPlan<const R: usize> {
    publisher: crate::stream::Publisher,
    rows: crate::reduced::BasisRows<R>,
    state: rtrb::Consumer<StateSnapshot<R>>,
    offsets: rtrb::Consumer<OffsetMsg<R>>,
    first_offset: Arc<Vec<Vec3>>,
    tool_radius: f64,
    simulated: bool,
    stop: Arc<AtomicBool>,
}

/// The stream publisher (normal priority): turns loop snapshots into stream
/// frames, x = X + ū + Φ δq at the stream's vertices, and publishes them.
/// Never blocks the loop (it only pops rings).
fn publisher_thread<const R: usize>(mut p: PublisherPlan<R>) -> (u64, u64, Option<String>) {
    use crate::stream::{flags as sf, StateFrame};
    let topo = p.publisher.topology().clone();
    let mut positions = vec![[0f32; 3]; topo.node_ids.len()];
    let mut offsets: std::collections::VecDeque<OffsetMsg<R>> = std::collections::VecDeque::new();
    offsets.push_back((0, p.first_offset.clone(), p.rows.clone()));
    let mut last_epoch = 0;
    let mut refreshed_at = f64::NEG_INFINITY;
    let mut times: std::collections::VecDeque<f64> = std::collections::VecDeque::new();
    let mut maxes: std::collections::VecDeque<f32> = std::collections::VecDeque::new();
    let mut errors = 0u64;
    let mut first_error = None;
    while !p.stop.load(Ordering::Relaxed) {
        while let Ok(o) = p.offsets.pop() {
            offsets.push_back(o);
            while offsets.len() > 8 {
                offsets.pop_front();
            }
        }
        let mut snap = None;
        while let Ok(s) = p.state.pop() {
            times.push_back(s.time_s);
            maxes.push_back(s.tick_max_us);
            snap = Some(s);
        }
        let Some(s) = snap else {
            std::thread::sleep(std::time::Duration::from_millis(2));
            continue;
        };
        while times.len() > 61 {
            times.pop_front();
            maxes.pop_front();
        }
        let (offset, rows) = match offsets
            .iter()
            .rev()
            .find(|(e, _, _)| *e == s.epoch)
            .or_else(|| offsets.back())
        {
            Some((_, o, r)) => (Some(o.clone()), r.clone()),
            None => (None, p.rows.clone()),
        };
        for (k, &node) in topo.node_ids.iter().enumerate() {
            let i = node as usize;
            let rest = Vec3::from(topo.rest_positions[k].map(f64::from));
            let ubar = offset
                .as_ref()
                .and_then(|o| o.get(i).copied())
                .unwrap_or_else(Vec3::zeros);
            let d = rows.get(i).map(|row| row * s.q).unwrap_or_else(Vec3::zeros);
            let x = rest + ubar + d;
            positions[k] = [x.x as f32, x.y as f32, x.z as f32];
        }
        if s.epoch != last_epoch {
            last_epoch = s.epoch;
            refreshed_at = s.time_s;
        }
        let mut fl = 0;
        for (a, b) in [
            (flags::WATCHDOG, sf::WATCHDOG_ACTIVE),
            (flags::CONTACT, sf::IN_CONTACT),
            (flags::LIMITED, sf::FORCE_LIMITED),
            (flags::RT_GRANTED, sf::RT_GRANTED),
        ] {
            if s.flags & a != 0 {
                fl |= b;
            }
        }
        if s.time_s - refreshed_at < 0.5 {
            fl |= sf::MODEL_REFRESHED;
        }
        if p.simulated {
            fl |= sf::DEVICE_SIMULATED;
        }
        let rate = match (times.front(), times.back()) {
            (Some(a), Some(b)) if b > a => {
                // Snapshots come every `state_every` ticks.
                (times.len() - 1) as f64 / (b - a) * (1e3 / 60.0f64).floor()
            }
            _ => 0.0,
        };
        let p99 = maxes.iter().copied().fold(0.0f32, f32::max);
        let frame = StateFrame {
            time_s: s.time_s,
            positions: &positions,
            tool_position: [s.tool.x as f32, s.tool.y as f32, s.tool.z as f32],
            tool_radius: p.tool_radius as f32,
            force: [s.force.x as f32, s.force.y as f32, s.force.z as f32],
            flags: fl,
            loop_rate_hz: rate as f32,
            tick_p99_us: p99,
        };
        if let Err(e) = p.publisher.publish(&frame) {
            errors += 1;
            first_error.get_or_insert_with(|| e.to_string());
        }
    }
    let frames = p.publisher.stats().frames;
    match p.publisher.finish() {
        Ok(_) => {}
        Err(e) => {
            first_error.get_or_insert_with(|| e.to_string());
        }
    }
    (frames, errors, first_error)
}

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
}

/// Loads the configuration and the scene, computes (or loads) the basis and
/// opens the device.
pub fn prepare(opts: &RunOptions) -> Result<Prepared, ServiceError> {
    let cfg = ServiceConfig::load(&opts.config)?;
    let seconds = opts.seconds.unwrap_or(cfg.seconds);
    crate::config::Checker::new(&opts.config).f64_in("--seconds", seconds, 0.1, 86_400.0, "s")?;
    let scene_path = cfg.resolve(&cfg.scene);
    let scene = Scene::load(&scene_path)?;
    let built = scene.build()?;
    let red = scene.reduced.clone().ok_or_else(|| crate::scene::SceneError {
        path: scene_path.clone(),
        key: "reduced".into(),
        msg: "the service needs a [reduced] table (r, contact_modes, contact_region)".into(),
    })?;
    let contact = if red.contact_modes {
        scene.contact_nodes(&built.mesh)?
    } else {
        Vec::new()
    };
    let mass = built.mesh.lumped_mass(built.material.density);
    if opts.progress {
        eprintln!(
            "nvtmm run: {} nodes, {} tets; basis r = {} ({} contact nodes)...",
            built.mesh.num_nodes(),
            built.mesh.tets().len(),
            red.r,
            contact.len()
        );
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
    let device = make_device(&cfg, &built.mesh, &scene, seconds)?;
    Ok(Prepared {
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
    })
}

/// Opens the configured device backend.
pub fn make_device(
    cfg: &ServiceConfig,
    mesh: &TetMesh,
    scene: &Scene,
    seconds: f64,
) -> Result<Box<dyn HapticDevice>, ServiceError> {
    let origin = Vec3::from(cfg.device.origin_m);
    match cfg.device.backend {
        Backend::TouchxSim => {
            use crate::haptics::touchx::{TouchXParams, TouchXSim, Waypoint};
            let params = TouchXParams::load(&cfg.resolve(&cfg.device.touchx))?;
            let (_, p, n, t) = press_target(mesh, scene);
            let pts: Vec<Waypoint> = scripted_press(p, n, t, &cfg.interaction, cfg.contact.tool_radius_m, seconds)
                .into_iter()
                .map(|(t_s, x)| Waypoint {
                    t_s,
                    position: x - origin,
                })
                .collect();
            let dev = TouchXSim::new(params, &pts).map_err(|e| ServiceError::Device(e.to_string()))?;
            Ok(Box::new(dev))
        }
        Backend::Udp => {
            use crate::haptics::udp::{UdpDevice, UdpParams};
            let params = UdpParams::load(&cfg.resolve(&cfg.device.udp))?;
            Ok(Box::new(UdpDevice::new(params)))
        }
        Backend::Openhaptics => open_openhaptics(),
    }
}

#[cfg(feature = "openhaptics")]
fn open_openhaptics() -> Result<Box<dyn HapticDevice>, ServiceError> {
    // Samples older than the device watchdog's limit count as stale.
    Ok(Box::new(crate::haptics::openhaptics::OpenHapticsDevice::new(0.005)))
}

#[cfg(not(feature = "openhaptics"))]
fn open_openhaptics() -> Result<Box<dyn HapticDevice>, ServiceError> {
    Err(ServiceError::Device(
        "this build has no OpenHaptics backend; rebuild with --features openhaptics on a box with the SDK".into(),
    ))
}

/// Runs the service with a prepared set-up at the reduced capacity the
/// basis needs.
pub fn run(p: Prepared, progress: bool) -> Result<Report, ServiceError> {
    match p.basis.len() {
        0..=16 => run_with::<16>(p, progress),
        17..=32 => run_with::<32>(p, progress),
        _ => run_with::<64>(p, progress),
    }
}

fn cpu(c: i32) -> Option<usize> {
    (c >= 0).then_some(c as usize)
}

fn ring_report(capacity: usize, policy: &'static str, overflows: u64) -> RingReport {
    RingReport {
        capacity,
        policy,
        overflows,
    }
}

/// Exact percentiles (ms) of samples in µs.
fn ms_of(us: &[f64]) -> Percentiles {
    let p = Percentiles::of(us);
    Percentiles {
        p50: p.p50 * 1e-3,
        p99: p.p99 * 1e-3,
        p999: p.p999 * 1e-3,
        max: p.max * 1e-3,
    }
}

fn run_with<const R: usize>(p: Prepared, progress: bool) -> Result<Report, ServiceError> {
    let Prepared {
        cfg,
        mesh,
        model,
        fixed,
        mass,
        basis,
        basis_s,
        basis_cache,
        dynamics,
        device,
        passivity,
        seconds,
        scene,
        record,
        contact,
        max_static,
    } = p;
    let n = mesh.num_nodes();
    let rows = basis_rows::<R>(&basis)?;
    let mut refresher = Refresher::new(&mesh, &basis, &mass);
    let zeros = vec![Vec3::zeros(); n];
    let k0 = refresher.reduced_stiffness(model.as_ref(), &zeros);
    let first = background::rest_model::<R>(rows.clone(), &k0, &dynamics, n)?;
    let index = Arc::new(SurfaceIndex::new(&mesh, &cfg.contact));
    let period = (1e9 / cfg.servo.rate_hz).round() as Nanos;
    let w = &cfg.watchdog;
    let servo_params = ServoParams {
        dt: period as f64 * 1e-9,
        contact: cfg.contact,
        device_origin: Vec3::from(cfg.device.origin_m),
        device_timeout_s: w.device_timeout_ms * 1e-3,
        model_timeout_s: if cfg.background.enabled {
            w.model_timeout_ms * 1e-3
        } else {
            f64::INFINITY
        },
        overrun_streak: w.overrun_streak,
        ramp_down_s: w.ramp_down_ms * 1e-3,
        ramp_in_s: w.ramp_in_s,
        swap_blend_s: cfg.servo.swap_blend_ms * 1e-3,
    };
    let filter = PassivityFilter::new(&passivity)?;
    let rings = cfg.rings;
    let (pose_tx, pose_rx) = rtrb::RingBuffer::<DeviceSample>::new(rings.pose);
    let (force_tx, force_rx) = rtrb::RingBuffer::<ForceCmd>::new(rings.force);
    let (contact_tx, contact_rx) = rtrb::RingBuffer::<ContactMsg>::new(rings.contact);
    let (model_tx, model_rx) = rtrb::RingBuffer::<Box<LoopModel<R>>>::new(rings.model);
    let (ret_tx, ret_rx) = rtrb::RingBuffer::<Box<LoopModel<R>>>::new(rings.returned);
    let stop = Arc::new(AtomicBool::new(false));
    let ticks = Arc::new(AtomicU64::new(0));
    let stream_on = cfg.stream.enabled || record.is_some();
    let (state_tx, state_rx) = rtrb::RingBuffer::<StateSnapshot<R>>::new(rings.state);
    let (offset_tx, offset_rx) = rtrb::RingBuffer::<OffsetMsg<R>>::new(16);
    let state_every = ((cfg.servo.rate_hz / cfg.stream.rate_hz).round() as u64).max(1);

    let memory_locked = cfg.servo.lock_memory && lock_memory().is_ok();
    let mut refusals = Vec::new();
    if cfg.servo.lock_memory && !memory_locked {
        refusals.push("mlockall refused (RLIMIT_MEMLOCK); memory not locked".to_string());
    }
    let mut device = device;
    device.start().map_err(|e| ServiceError::Device(e.to_string()))?;
    let device_name = device.name().to_string();

    clock::epoch();
    // The baseline runs first on the loop's thread; the device and the
    // background start with the loop.
    let start = clock::now_ns() + 50_000_000;
    let loop_start = start + (cfg.servo.baseline_s * 1e9) as Nanos + LOOP_PHASE;
    let pool_bytes = 8 << 20;

    // Background.
    let mut basis_handle: Option<std::thread::JoinHandle<BasisStats>> = None;
    let bg_handle = if cfg.background.enabled {
        let mut params = scene.integrator;
        params.dt = cfg.background.dt;
        let solver =
            ImplicitEuler::new(&mesh, mass.clone(), params).map_err(|e| ServiceError::Solver(e.to_string()))?;
        let basis_policy = BasisPolicy {
            every_s: cfg.background.basis_refresh_s,
            min_change_m: cfg.background.basis_refresh_m,
        };
        let bg = Background::<R> {
            model,
            solver,
            fixed: fixed.clone(),
            refresher,
            rows: rows.clone(),
            dynamics,
            last_sent: (first.offset.clone(), SVector::zeros(), 0),
            dt_max: cfg.background.dt_max,
            basis_policy,
        };
        let bg_cpu = cpu(cfg.background.cpu);
        // The basis thread, when the basis refresh is on.
        let basis_io = if basis_policy.every_s > 0.0 {
            let (job_tx, job_rx) = rtrb::RingBuffer::<BasisJob>::new(1);
            let (new_tx, new_rx) = rtrb::RingBuffer::<NewBasis<R>>::new(1);
            let worker = BasisWorker {
                mesh: mesh.clone(),
                mass: mass.clone(),
                fixed: fixed.clone(),
                contact: contact.clone(),
                r: basis.len(),
                max_static,
                params: BasisParams::default(),
                current: basis.clone(),
            };
            let stop_b = stop.clone();
            let h = std::thread::Builder::new()
                .name("nvtmm-basis".into())
                .spawn(move || {
                    if bg_cpu.is_some() {
                        setup_current(&RtRequest {
                            fifo_priority: None,
                            cpu: bg_cpu,
                            prefault_stack_bytes: 0,
                        });
                    }
                    background::basis_thread::<R>(worker, job_rx, new_tx, stop_b)
                })
                .map_err(|e| ServiceError::Thread("basis", e.to_string()))?;
            basis_handle = Some(h);
            Some((job_tx, new_rx))
        } else {
            None
        };
        let bio = BackgroundIo {
            contact: contact_rx,
            models: model_tx,
            returned: ret_rx,
            offsets: stream_on.then_some(offset_tx),
            stop: stop.clone(),
            loop_ticks: ticks.clone(),
            basis: basis_io,
        };
        Some(
            std::thread::Builder::new()
                .name("nvtmm-background".into())
                .spawn(move || {
                    clock::sleep_until(loop_start);
                    if bg_cpu.is_some() {
                        setup_current(&RtRequest {
                            fifo_priority: None,
                            cpu: bg_cpu,
                            prefault_stack_bytes: 0,
                        });
                    }
                    background::run(bg, bio)
                })
                .map_err(|e| ServiceError::Thread("background", e.to_string()))?,
        )
    } else {
        drop((contact_rx, model_tx, ret_rx, model, refresher, offset_tx));
        None
    };

    // Stream publisher.
    let pub_handle = if stream_on {
        let topology = crate::stream::decimate::surface(&mesh, cfg.stream.decimate_vertices);
        let mut scfg = cfg.stream.clone();
        // Recording without a live stream: send nowhere but the file.
        scfg.enabled = cfg.stream.enabled;
        let publisher = crate::stream::Publisher::new(scfg, topology, record.as_deref())
            .map_err(|e| ServiceError::Device(format!("stream: {e}")))?;
        let plan = PublisherPlan::<R> {
            publisher,
            rows: rows.clone(),
            state: state_rx,
            offsets: offset_rx,
            first_offset: first.offset.clone(),
            tool_radius: cfg.contact.tool_radius_m,
            simulated: cfg.device.backend == Backend::TouchxSim,
            stop: stop.clone(),
        };
        Some(
            std::thread::Builder::new()
                .name("nvtmm-stream".into())
                .spawn(move || publisher_thread::<R>(plan))
                .map_err(|e| ServiceError::Thread("stream", e.to_string()))?,
        )
    } else {
        drop(state_rx);
        None
    };

    // Device I/O.
    let dev_req = RtRequest {
        fifo_priority: (cfg.device.priority > 0).then_some(cfg.device.priority),
        cpu: cpu(cfg.device.cpu),
        prefault_stack_bytes: 256 * 1024,
    };
    let dev_period = (1e9 / cfg.device.rate_hz).round() as Nanos;
    let dio = DeviceIo {
        pose: pose_tx,
        force: force_rx,
        stop: stop.clone(),
    };
    let dev_handle = std::thread::Builder::new()
        .name("nvtmm-device".into())
        .stack_size(1 << 20)
        .spawn(move || {
            device_thread(
                device,
                dio,
                dev_req,
                loop_start - LOOP_PHASE,
                dev_period,
                dev_period / 2,
                pool_bytes,
            )
        })
        .map_err(|e| ServiceError::Thread("device", e.to_string()))?;

    // The haptic loop, phased 200 µs after the device read.
    let servo = Servo::new(first, index, servo_params, clock::now_s());
    let lio = LoopIo {
        pose: pose_rx,
        force: force_tx,
        contact: contact_tx,
        models: model_rx,
        returned: ret_tx,
        state: stream_on.then_some(state_tx),
        stop: stop.clone(),
        ticks: ticks.clone(),
    };
    let plan = LoopPlan {
        request: RtRequest {
            fifo_priority: (cfg.servo.priority > 0).then_some(cfg.servo.priority),
            cpu: cpu(cfg.servo.cpu),
            prefault_stack_bytes: cfg.servo.stack_kib * 1024 / 2,
        },
        period,
        start,
        loop_start,
        baseline_s: cfg.servo.baseline_s,
        pool_bytes,
        state_every,
    };
    let loop_handle = std::thread::Builder::new()
        .name("nvtmm-haptic".into())
        .stack_size(cfg.servo.stack_kib * 1024)
        .spawn(move || loop_thread::<R>(servo, filter, lio, plan))
        .map_err(|e| ServiceError::Thread("haptic loop", e.to_string()))?;

    // Reporter: wait, showing progress.
    let total = cfg.servo.baseline_s + seconds;
    let t0 = std::time::Instant::now();
    let bar = progress.then(|| {
        let b = indicatif::ProgressBar::new((total * 10.0) as u64);
        b.set_style(
            indicatif::ProgressStyle::with_template("{bar:40} {elapsed}/{duration} {msg}")
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        b
    });
    while t0.elapsed().as_secs_f64() < total + 0.05 {
        std::thread::sleep(std::time::Duration::from_millis(100));
        if let Some(b) = &bar {
            b.set_position((t0.elapsed().as_secs_f64() * 10.0) as u64);
            b.set_message(format!("{} ticks", ticks.load(Ordering::Relaxed)));
        }
        if loop_handle.is_finished() || dev_handle.is_finished() {
            break;
        }
    }
    if let Some(b) = bar {
        b.finish_and_clear();
    }
    stop.store(true, Ordering::Relaxed);
    let lr = loop_handle
        .join()
        .map_err(|_| ServiceError::Thread("haptic loop", "panicked".into()))?;
    let (dr, mut dev) = dev_handle
        .join()
        .map_err(|_| ServiceError::Thread("device", "panicked".into()))?;
    dev.stop();
    let bs: Option<BackgroundStats> = match bg_handle {
        Some(h) => Some(
            h.join()
                .map_err(|_| ServiceError::Thread("background", "panicked".into()))?,
        ),
        None => None,
    };
    let basis_stats: BasisStats = match basis_handle {
        Some(h) => h.join().map_err(|_| ServiceError::Thread("basis", "panicked".into()))?,
        None => BasisStats::default(),
    };
    let (stream_frames, stream_errors, stream_error) = match pub_handle {
        Some(h) => h
            .join()
            .map_err(|_| ServiceError::Thread("stream", "panicked".into()))?,
        None => (0, 0, None),
    };
    if let Some(e) = &stream_error {
        refusals.push(format!("stream: {stream_errors} publish errors, first: {e}"));
    }
    if memory_locked {
        crate::rt::thread::unlock_memory();
    }

    refusals.extend(lr.grant.refusals.iter().cloned());
    let mut ring_overflows = std::collections::BTreeMap::new();
    ring_overflows.insert("pose", ring_report(rings.pose, "drop newest", dr.pose_ring_full));
    ring_overflows.insert("force", ring_report(rings.force, "drop newest", lr.force_ring_full));
    ring_overflows.insert(
        "contact",
        ring_report(rings.contact, "drop newest", lr.contact_ring_full),
    );
    ring_overflows.insert(
        "model",
        ring_report(
            rings.model,
            "keep latest (background retries)",
            bs.as_ref().map(|b| b.model_ring_full).unwrap_or(0),
        ),
    );
    ring_overflows.insert(
        "returned",
        ring_report(rings.returned, "loop defers the swap", lr.swaps_deferred),
    );
    ring_overflows.insert("state", ring_report(rings.state, "drop newest", lr.state_ring_full));
    let (energy_in, energy_out, source) = match dr.energy {
        Some(e) => (e.absorbed_j, e.delivered_j, "device"),
        None => (lr.energy_in, lr.energy_out, "observer"),
    };
    let qp = &lr.qp;
    let background = match &bs {
        Some(b) => BackgroundReport {
            enabled: true,
            steps: b.steps,
            failed_steps: b.failed_steps,
            split_steps: b.split_steps,
            step_ms: ms_of(&b.step_us),
            refresh_ms: ms_of(&b.refresh_us),
            refresh_hz: b.models_sent as f64 / b.wall_s.max(1e-9),
            real_time_factor: b.sim_time_s / b.wall_s.max(1e-9),
            max_displacement_m: b.max_displacement_m,
            basis_refresh_on: cfg.background.basis_refresh_s > 0.0,
            basis_requests: b.basis_requests,
            basis_recomputed: basis_stats.recomputed,
            basis_failures: basis_stats.failures,
            basis_swaps: b.basis_swaps_sent,
            basis_recompute_s: Percentiles::of(&basis_stats.seconds),
            basis_iterations: basis_stats.iterations.clone(),
        },
        None => BackgroundReport::default(),
    };
    Ok(Report {
        ticks: lr.counters.ticks,
        seconds: lr.seconds,
        deadline_misses: lr.misses,
        deadline_misses_compute: lr.misses_compute,
        period_jitter_us: lr.jitter.percentiles(),
        tick_compute_us: lr.compute.percentiles(),
        pose_to_force_latency_us: dr.latency.percentiles(),
        baseline_jitter_us: lr.baseline.percentiles(),
        allocations_after_start: lr.allocations + dr.allocations,
        allocator_installed: lr.allocator_installed,
        max_force_n: lr.max_force,
        qp: QpReport {
            solves: qp.solves,
            active_norm: qp.active_norm,
            active_rate: qp.active_rate,
            active_energy: qp.active_energy,
            iters_p99: qp.iter_p99(),
            solve_us_p99: lr.qp_us.percentiles().p99,
            solve_us_p50: lr.qp_us.percentiles().p50,
            fallbacks: qp.fallbacks(),
            tank_low_j: qp.tank_low_j,
        },
        energy_in_j: energy_in,
        energy_out_j: energy_out,
        energy_source: source,
        ring_overflows,
        model_swaps: lr.counters.model_swaps,
        rt_policy_granted: lr.grant.fifo,
        rt_refusals: refusals,
        loop_cpu: lr.grant.cpu,
        memory_locked,
        device: device_name,
        nodes: n,
        tets: mesh.tets().len(),
        r: basis.len(),
        r_capacity: R,
        basis_s,
        basis_cache,
        background,
        watchdog: lr.counters,
        device_ticks: dr.ticks,
        device_errors: dr.errors,
        max_depth_m: lr.max_depth,
        stream_frames,
    })
}

/// Loads, prepares and runs; the whole of `nvtmm run`.
pub fn run_service(opts: &RunOptions) -> Result<Report, ServiceError> {
    let p = prepare(opts)?;
    run(p, opts.progress)
}

/// The default configuration file (`rt-config/nvtmm.toml`).
pub fn default_config() -> PathBuf {
    Path::new("rt-config").join("nvtmm.toml")
}
