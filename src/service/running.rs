//! A started service: the threads, the rings between them and what the
//! report needs at the end. `start_with` builds the rings and starts the
//! threads at the reduced capacity R; `Running::stop` stops them, joins
//! them and assembles the [`Report`].

use super::background::{
    self, Background, BackgroundIo, BackgroundStats, BasisJob, BasisPolicy, BasisStats, BasisWorker, ContactMsg,
    NewBasis, OffsetMsg,
};
use super::config::Backend;
use super::device_io::{device_thread, DeviceIo, DeviceResult, ForceCmd};
use super::faults::FaultSwitches;
use super::live::{LiveStats, Snapshot};
use super::loop_thread::{loop_thread, LoopIo, LoopPlan, LoopResult, SecondIo, LOOP_PHASE};
use super::publisher::{publisher_thread, PublisherPlan, StateSnapshot};
use super::report::{BackgroundReport, LostThread, QpReport, Report, RingReport};
use super::setup::Prepared;
use super::ServiceError;
use crate::haptics::contact::SurfaceIndex;
use crate::haptics::device::{DeviceSample, HapticDevice};
use crate::haptics::passivity::PassivityFilter;
use crate::haptics::servo::{LoopModel, Servo, ServoParams};
use crate::haptics::tick::HapticTick;
use crate::math::Vec3;
use crate::reduced::{basis_rows, BasisParams, Refresher};
use crate::rt::clock::{self, Nanos};
use crate::rt::stats::Percentiles;
use crate::rt::thread::{lock_memory, set_current_nice, setup_current, RtRequest};
use crate::service::config::RingConfig;
use crate::solver::ImplicitEuler;
use nalgebra::SVector;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;

/// The RT allocator's pool (bytes), shared by every RT thread of the
/// service (the loop, the device, the instruments' threads). The process
/// has one pool, sized by the first thread that enters it, so every thread
/// asks for this size: a smaller first request (the guidewire's thread
/// asked for 1 MiB) left the pool nearly full after the wire thread's
/// set-up, and the device thread's next allocation fell back to the
/// system allocator.
pub(crate) const RT_POOL_BYTES: usize = 8 << 20;

/// A device I/O thread: its figures and its device when it ends.
type DeviceHandle = JoinHandle<(DeviceResult, Box<dyn HapticDevice>)>;

/// A running service at reduced capacity R (type-erased by [`Service`]).
pub(super) struct Running<const R: usize> {
    stop: Arc<AtomicBool>,
    live: Arc<LiveStats>,
    started: std::time::Instant,
    planned_s: f64,
    loop_handle: Option<JoinHandle<LoopResult>>,
    dev_handle: Option<DeviceHandle>,
    /// The second device's I/O thread and the id of the instrument it
    /// drives (`[device.second]`).
    second_handle: Option<(DeviceHandle, String)>,
    bg_handle: Option<JoinHandle<BackgroundStats>>,
    basis_handle: Option<JoinHandle<BasisStats>>,
    pub_handle: Option<JoinHandle<super::publisher::PublisherResult>>,
    /// The thread keeping the loop's CPU awake (`loop.keep_cpu_awake`).
    awake_handle: Option<JoinHandle<()>>,
    refusals: Vec<String>,
    memory_locked: bool,
    rings: RingConfig,
    device_name: String,
    basis_refresh_on: bool,
    nodes: usize,
    tets: usize,
    r: usize,
    basis_s: f64,
    basis_cache: String,
    scripted_press_depth_m: Option<f64>,
    model_timeout_ms: f64,
    faults: Arc<FaultSwitches>,
    /// The instruments' service sides, in registry order.
    instruments: Vec<Box<dyn super::instrument::ServiceSide>>,
}

/// What [`super::Handle`] needs of a running service, whatever its R.
pub(super) trait RunningService: Send {
    fn snapshot(&self) -> Snapshot;
    fn planned_s(&self) -> f64;
    fn is_finished(&self) -> bool;
    fn stop(&mut self) -> Result<Report, ServiceError>;
    fn faults(&self) -> Arc<FaultSwitches>;
}

/// What a start that fails part-way undoes when dropped, until
/// [`UndoOnFailure::disarm`] once the service is handed out: the stop flag
/// is set, so every thread it had already spawned ends; the device, while
/// this holds it (started or not), is stopped (its force set to zero); the
/// memory lock the start took is released. An embedding application whose
/// start fails keeps neither threads running, nor a device pushing, nor its
/// memory locked.
struct UndoOnFailure {
    stop: Option<Arc<AtomicBool>>,
    device: Option<Box<dyn HapticDevice>>,
    unlock_memory: bool,
}

impl UndoOnFailure {
    /// The start succeeded: nothing to undo.
    fn disarm(&mut self) {
        self.stop = None;
        self.unlock_memory = false;
    }
}

impl Drop for UndoOnFailure {
    fn drop(&mut self) {
        if let Some(s) = &self.stop {
            s.store(true, Ordering::Relaxed);
        }
        if let Some(d) = self.device.as_mut() {
            d.stop();
        }
        if self.unlock_memory {
            crate::rt::thread::unlock_memory();
        }
    }
}

/// Joins a thread; a panic becomes an error naming the thread and the
/// panic message.
fn join<T>(h: Option<JoinHandle<T>>, name: &'static str) -> Result<T, ServiceError> {
    let h = h.ok_or_else(|| ServiceError::Thread(name, "already stopped".into()))?;
    h.join().map_err(|p| {
        let msg = p
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| p.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "unknown payload".into());
        ServiceError::Thread(name, format!("panicked: {msg}"))
    })
}

impl<const R: usize> RunningService for Running<R> {
    fn snapshot(&self) -> Snapshot {
        self.live.snapshot(self.started.elapsed().as_secs_f64())
    }

    fn planned_s(&self) -> f64 {
        self.planned_s
    }

    fn faults(&self) -> Arc<FaultSwitches> {
        self.faults.clone()
    }

    fn is_finished(&self) -> bool {
        self.loop_handle.as_ref().is_none_or(|h| h.is_finished())
            || self.dev_handle.as_ref().is_none_or(|h| h.is_finished())
    }

    fn stop(&mut self) -> Result<Report, ServiceError> {
        self.stop.store(true, Ordering::Relaxed);
        let lr = join(self.loop_handle.take(), "haptic loop")?;
        let (dr, mut dev) = join(self.dev_handle.take(), "device")?;
        dev.stop();
        let second = match self.second_handle.take() {
            Some((h, id)) => {
                let (d2, mut dev2) = join(Some(h), "second device")?;
                dev2.stop();
                Some((d2, id))
            }
            None => None,
        };
        // A lost helper thread does not lose the report: the loop ran on
        // with its last model, and the report names the thread.
        let mut threads_lost = Vec::new();
        let bs: Option<BackgroundStats> = match self.bg_handle.take() {
            Some(h) => survive(join(Some(h), "background"), &mut threads_lost),
            None => None,
        };
        let basis_stats: BasisStats = match self.basis_handle.take() {
            Some(h) => survive(join(Some(h), "basis"), &mut threads_lost).unwrap_or_default(),
            None => BasisStats::default(),
        };
        let pr = survive(join(self.pub_handle.take(), "stream"), &mut threads_lost).unwrap_or_default();
        let kept_awake = match self.awake_handle.take() {
            Some(h) => survive(join(Some(h), "keep-awake"), &mut threads_lost).is_some(),
            None => false,
        };
        let (stream_frames, stream_errors, stream_error) = (pr.frames, pr.errors, pr.first_error);
        let mut refusals = std::mem::take(&mut self.refusals);
        let (rings, memory_locked) = (self.rings, self.memory_locked);
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
            None => (lr.qp.absorbed_j, lr.qp.delivered_j, "observer"),
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
                basis_refresh_on: self.basis_refresh_on,
                basis_requests: b.basis_requests,
                basis_recomputed: basis_stats.recomputed,
                basis_failures: basis_stats.failures,
                basis_swaps: b.basis_swaps_sent,
                basis_recompute_s: Percentiles::of(&basis_stats.seconds),
                basis_iterations: basis_stats.iterations.clone(),
            },
            None => BackgroundReport::default(),
        };
        let mut report = Report {
            ticks: lr.counters.ticks,
            seconds: lr.seconds,
            deadline_misses: lr.misses,
            deadline_misses_compute: lr.misses_compute,
            period_jitter_us: lr.jitter.percentiles(),
            tick_compute_us: lr.compute.percentiles(),
            tick_phases: lr.phases.report(),
            pose_to_force_latency_us: dr.latency.percentiles(),
            baseline_jitter_us: lr.baseline.percentiles(),
            allocations_after_start: lr.allocations
                + dr.allocations
                + second.as_ref().map_or(0, |(d2, _)| d2.allocations),
            loop_page_faults_after_start: lr.page_faults.0 + lr.page_faults.1,
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
                observed_out_j: qp.delivered_j,
                observed_in_j: qp.absorbed_j,
                unobserved_j: qp.unobserved_j,
                uncredited_j: qp.uncredited_j,
                shortcuts: qp.interior,
                exact_solves: qp.exact,
                command_change_max_n: qp.command_change_max_n,
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
            loop_cpu_kept_awake: kept_awake,
            device: self.device_name.clone(),
            nodes: self.nodes,
            tets: self.tets,
            r: self.r,
            r_capacity: R,
            basis_s: self.basis_s,
            basis_cache: self.basis_cache.clone(),
            background,
            watchdog: lr.counters,
            contact: lr.contact.clone(),
            device_ticks: dr.ticks,
            device_errors: dr.errors,
            max_depth_m: lr.max_depth,
            stream_frames,
            igtl: pr.igtl,
            scripted_press_depth_m: self.scripted_press_depth_m,
            model_timeout_ms: self.model_timeout_ms,
            threads_lost,
            device_loop_silent_periods: dr.loop_silent,
            wire: None,
            task: pr.task,
            hand_watches: pr.hand_watches,
            instruments: Vec::new(),
            instrument_switches: lr.instrument_switches,
            second_device: match (&second, &lr.second) {
                (Some((d2, id)), Some(l2)) => Some(super::report::SecondDeviceReport {
                    instrument: id.clone(),
                    device_ticks: d2.ticks,
                    device_errors: d2.errors,
                    silent_ticks: l2.silent_ticks,
                    max_force_n: l2.max_force,
                    qp_solves: l2.qp.solves,
                    qp_active_rate: l2.qp.active_rate,
                    pose_ring_full: d2.pose_ring_full,
                    force_ring_full: l2.force_ring_full,
                    pose_to_force_latency_us: d2.latency.percentiles(),
                }),
                _ => None,
            },
        };
        // Each instrument joins its thread and adds its section (and the
        // guidewire its `wire.*` keys and its thread's allocations).
        for inst in self.instruments.iter_mut() {
            let section = inst.finish(&mut report)?;
            report.instruments.push(section);
        }
        Ok(report)
    }
}

/// The result of a helper thread, or None with the thread listed as lost.
fn survive<T>(r: Result<T, ServiceError>, lost: &mut Vec<LostThread>) -> Option<T> {
    match r {
        Ok(v) => Some(v),
        Err(e) => {
            let (thread, message) = match e {
                ServiceError::Thread(name, message) => (name.to_string(), message),
                other => ("unknown".to_string(), other.to_string()),
            };
            lost.push(LostThread { thread, message });
            None
        }
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

/// Builds the rings and starts every thread at reduced capacity R.
pub(super) fn start_with<const R: usize>(p: Prepared) -> Result<Running<R>, ServiceError> {
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
        compliance,
        pressure,
        inflated,
        hand_watcher,
    } = p;
    let n = mesh.num_nodes();
    let rows = basis_rows::<R>(&basis)?;
    let mut refresher = Refresher::new(&mesh, &basis, &mass);
    // The first model: at rest, or with a pressure at the inflated wall.
    let (mut first, first_qbar) = match &inflated {
        Some(s) => background::inflated_model::<R>(rows.clone(), &mut refresher, s, &dynamics)?,
        None => {
            let k0 = refresher.reduced_stiffness(model.as_ref(), &vec![Vec3::zeros(); n]);
            (
                background::rest_model::<R>(rows.clone(), &k0, &dynamics, n)?,
                SVector::zeros(),
            )
        }
    };
    first.compliance = compliance.as_ref().map(|c| c.0.clone());
    let index = Arc::new(SurfaceIndex::new(&mesh, &cfg.contact));
    let period = (1e9 / cfg.servo.rate_hz).round() as Nanos;
    let w = &cfg.watchdog;
    let servo_params = ServoParams {
        dt: period as f64 * 1e-9,
        contact: cfg.contact,
        device_origin: match &cfg.device.frame {
            Some(f) => Vec3::from(f.offset_m),
            None => Vec3::from(cfg.device.origin_m),
        },
        device_timeout_s: w.device_timeout_ms * 1e-3,
        model_timeout_s: if cfg.background.enabled {
            w.model_timeout_ms * 1e-3
        } else {
            f64::INFINITY
        },
        model_max_age_s: if cfg.background.enabled {
            w.model_max_age_ms * 1e-3
        } else {
            f64::INFINITY
        },
        max_speed_m_s: w.max_speed_m_s,
        max_reach_m: w.max_reach_m,
        overrun_streak: w.overrun_streak,
        ramp_down_s: w.ramp_down_ms * 1e-3,
        ramp_in_s: w.ramp_in_s,
        swap_blend_s: cfg.servo.swap_blend_ms * 1e-3,
        command_timeout_s: w.command_timeout_ms * 1e-3,
    };
    let filter = PassivityFilter::new(&passivity)?;
    let rings = cfg.rings;
    let (pose_tx, pose_rx) = rtrb::RingBuffer::<DeviceSample>::new(rings.pose);
    let (force_tx, force_rx) = rtrb::RingBuffer::<ForceCmd>::new(rings.force);
    let (contact_tx, contact_rx) = rtrb::RingBuffer::<ContactMsg>::new(rings.contact);
    let (model_tx, model_rx) = rtrb::RingBuffer::<Box<LoopModel<R>>>::new(rings.model);
    let (ret_tx, ret_rx) = rtrb::RingBuffer::<Box<LoopModel<R>>>::new(rings.returned);
    let stop = Arc::new(AtomicBool::new(false));
    // A start that fails from here undoes what it did (`UndoOnFailure`:
    // disarmed once the service is handed out).
    let mut undo = UndoOnFailure {
        stop: Some(stop.clone()),
        device: None,
        unlock_memory: false,
    };
    let live = Arc::new(LiveStats::default());
    let faults = Arc::new(FaultSwitches::default());
    let (state_tx, state_rx) = rtrb::RingBuffer::<StateSnapshot<R>>::new(rings.state);
    let (offset_tx, offset_rx) = rtrb::RingBuffer::<OffsetMsg<R>>::new(16);
    let state_every = ((cfg.servo.rate_hz / cfg.stream.rate_hz).round() as u64).max(1);

    if cfg.servo.lock_memory {
        crate::rt::thread::return_large_blocks();
    }
    let memory_locked = cfg.servo.lock_memory && lock_memory().is_ok();
    let mut refusals = Vec::new();
    if cfg.servo.lock_memory && !memory_locked {
        refusals.push("mlockall refused (RLIMIT_MEMLOCK); memory not locked".to_string());
    }
    // From here a start that fails stops the device (force to zero) and
    // releases the memory lock it took, as a stop would.
    undo.device = Some(device);
    undo.unlock_memory = memory_locked;
    let device_name = match undo.device.as_mut() {
        Some(d) => {
            d.start().map_err(|e| ServiceError::Device(e.to_string()))?;
            d.name().to_string()
        }
        None => return Err(ServiceError::Device("no device".into())),
    };

    clock::epoch();
    // The baseline runs first on the loop's thread; the device and the
    // background start with the loop.
    let start = clock::now_ns() + 50_000_000;
    let loop_start = start + (cfg.servo.baseline_s * 1e9) as Nanos + LOOP_PHASE;
    let pool_bytes = RT_POOL_BYTES;

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
            last_sent: (first.offset.clone(), first_qbar, 0),
            dt_max: cfg.background.dt_max,
            basis_policy,
            compliance: first.compliance.clone(),
            pressure: pressure
                .map(|p| background::BackgroundPressure::new(p).starting_at(inflated.as_ref().map(|s| s.u.clone()))),
        };
        let bg_cpu = cpu(cfg.background.cpu);
        // The basis thread, when the basis refresh is on.
        let basis_io = if basis_policy.every_s > 0.0 {
            let (job_tx, job_rx) = rtrb::RingBuffer::<BasisJob>::new(1);
            let (new_tx, new_rx) = rtrb::RingBuffer::<Option<NewBasis<R>>>::new(1);
            let worker = BasisWorker {
                mesh: mesh.clone(),
                mass: mass.clone(),
                fixed: fixed.clone(),
                contact: contact.clone(),
                r: basis.len(),
                max_static,
                params: BasisParams::default(),
                current: basis.clone(),
                compliance: compliance.as_ref().map(|c| c.1),
            };
            let stop_b = stop.clone();
            let faults_b = faults.clone();
            let nice = cfg.background.basis_nice;
            let h = std::thread::Builder::new()
                .name("nvtmm-basis".into())
                .spawn(move || {
                    // The recomputation runs on its own rayon pool (its
                    // `rayon::join`s would otherwise run on the global pool,
                    // beside the full solve's work, at the same priority),
                    // every thread of it at `basis_nice` and unpinned: it
                    // takes the CPU time the full solve leaves on either
                    // core. Raising one's own nice value is never refused
                    // on Linux; if it were, the basis would only compete
                    // as before, so a refusal is not fatal.
                    let _ = set_current_nice(nice);
                    let pool = rayon::ThreadPoolBuilder::new()
                        .num_threads(rayon::current_num_threads())
                        .thread_name(|i| format!("nvtmm-basis-{i}"))
                        .start_handler(move |_| {
                            let _ = set_current_nice(nice);
                        })
                        .build();
                    match pool {
                        Ok(pool) => {
                            pool.install(|| background::basis_thread::<R>(worker, job_rx, new_tx, stop_b, faults_b))
                        }
                        Err(_) => background::basis_thread::<R>(worker, job_rx, new_tx, stop_b, faults_b),
                    }
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
            offsets: Some(offset_tx),
            stop: stop.clone(),
            live: live.clone(),
            basis: basis_io,
            faults: faults.clone(),
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

    // The instruments, in registry order; those with a thread of their own
    // (the guidewire's, half a period after the loop) start it here.
    let built = super::instrument::build_all::<R>(&super::instrument::BuildContext {
        cfg: &cfg,
        mesh: &mesh,
        vessel: &first,
        stop: stop.clone(),
        faults: faults.clone(),
        loop_start,
        state_every,
    })?;
    let second_index = match &cfg.device.second {
        Some(sd) => Some(
            built
                .iter()
                .position(|b| b.id == sd.instrument && b.loop_side.hub_driven())
                .ok_or_else(|| {
                    ServiceError::Device(format!(
                        "device.second.instrument = \"{}\": no hub-driven instrument of that id in this run",
                        sd.instrument
                    ))
                })?,
        ),
        None => None,
    };
    // The hub-driven instruments in the switch button's order: what the
    // watching hand calls instrument 0, 1, ...
    let hub_driven: Vec<usize> = built
        .iter()
        .enumerate()
        .filter(|(_, b)| b.loop_side.hub_driven())
        .map(|(k, _)| k)
        .collect();
    let mut loop_sides = Vec::with_capacity(built.len());
    let mut published = Vec::with_capacity(built.len());
    let mut service_sides = Vec::with_capacity(built.len());
    for b in built {
        loop_sides.push(b.loop_side);
        published.push(super::publisher::PublishedInstrument {
            id: b.id,
            kind: b.kind,
            side: b.publisher_side,
        });
        service_sides.push(b.service_side);
    }

    // The device's buttons, for the task metrics on the publisher's side.
    let buttons = Arc::new(std::sync::atomic::AtomicU32::new(0));
    // Stream publisher: always runs (it also keeps the latest frame for
    // `Handle::snapshot`); it sends only where `[stream]` or `--record` say.
    let pub_handle = {
        let topology = crate::stream::decimate::surface(&mesh, cfg.stream.decimate_vertices);
        let publisher = crate::stream::Publisher::new(cfg.stream.clone(), topology, record.as_deref())
            .map_err(|e| ServiceError::Device(format!("stream: {e}")))?;
        let plan = PublisherPlan::<R> {
            publisher,
            rows: rows.clone(),
            state: state_rx,
            offsets: offset_rx,
            first_offset: first.offset.clone(),
            tool_radius: cfg.contact.tool_radius_m,
            simulated: cfg.device.backend == Backend::TouchxSim,
            send: cfg.stream.enabled || record.is_some() || cfg.stream.igtl.is_some(),
            stop: stop.clone(),
            live: live.clone(),
            faults: faults.clone(),
            task: match &cfg.task {
                Some(t) => Some(super::task_feed::TaskFeed::new(&cfg, t, &mesh, buttons.clone())?),
                None => None,
            },
            instruments: published,
            hand_watcher: hand_watcher.map(|w| (w, hub_driven)),
        };
        std::thread::Builder::new()
            .name("nvtmm-stream".into())
            .spawn(move || publisher_thread::<R>(plan))
            .map_err(|e| ServiceError::Thread("stream", e.to_string()))?
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
        buttons,
    };
    // The device thread stops the device when it ends (the stop flag of a
    // start that fails later ends it).
    let Some(device) = undo.device.take() else {
        return Err(ServiceError::Device("no device".into()));
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

    // The second device (`[device.second]`): its own UDP peer, rings and
    // I/O thread, in phase with the first's.
    let (second_io, second_handle) = match (&cfg.device.second, second_index) {
        (Some(sd), Some(k)) => {
            let params = crate::haptics::udp::UdpParams::load(&cfg.resolve(&sd.udp))?;
            let mut dev2: Box<dyn HapticDevice> = Box::new(crate::haptics::udp::UdpDevice::new(params));
            dev2.start()
                .map_err(|e| ServiceError::Device(format!("device.second: {e}")))?;
            let (pose2_tx, pose2_rx) = rtrb::RingBuffer::<DeviceSample>::new(rings.pose);
            let (force2_tx, force2_rx) = rtrb::RingBuffer::<ForceCmd>::new(rings.force);
            let dio2 = DeviceIo {
                pose: pose2_tx,
                force: force2_rx,
                stop: stop.clone(),
                buttons: Arc::new(std::sync::atomic::AtomicU32::new(0)),
            };
            let req2 = dev_req;
            let h = std::thread::Builder::new()
                .name("nvtmm-device2".into())
                .stack_size(1 << 20)
                .spawn(move || {
                    device_thread(
                        dev2,
                        dio2,
                        req2,
                        loop_start - LOOP_PHASE,
                        dev_period,
                        dev_period / 2,
                        pool_bytes,
                    )
                })
                .map_err(|e| ServiceError::Thread("second device", e.to_string()))?;
            let io = SecondIo {
                pose: pose2_rx,
                force: force2_tx,
                instrument: k,
                filter: PassivityFilter::new(&passivity)?,
                timeout: (cfg.watchdog.device_timeout_ms * 1e6) as Nanos,
            };
            (Some(io), Some((h, sd.instrument.clone())))
        }
        _ => (None, None),
    };

    // The haptic loop, phased 200 µs after the device read.
    let tick = HapticTick::new(Servo::new(first, index, servo_params, clock::now_s()), filter);
    let lio = LoopIo {
        pose: pose_rx,
        force: force_tx,
        contact: contact_tx,
        models: model_rx,
        returned: ret_tx,
        state: state_tx,
        stop: stop.clone(),
        live: live.clone(),
        faults: faults.clone(),
        instruments: loop_sides,
        second: second_io,
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
        frame: cfg.device.frame.as_ref().map(|f| {
            crate::haptics::frame::DeviceFrame::new(&crate::haptics::frame::DeviceFrameParams {
                offset_m: [0.0; 3],
                ..f.clone()
            })
        }),
    };
    let loop_handle = std::thread::Builder::new()
        .name("nvtmm-haptic".into())
        .stack_size(cfg.servo.stack_kib * 1024)
        .spawn(move || loop_thread::<R>(tick, lio, plan))
        .map_err(|e| ServiceError::Thread("haptic loop", e.to_string()))?;
    // The loop's CPU kept from idling (validated: the loop is pinned);
    // started last, as nothing after it can fail and leave it spinning.
    let awake_handle = match usize::try_from(cfg.servo.cpu) {
        Ok(c) if cfg.servo.keep_cpu_awake => crate::rt::thread::spawn_keep_awake_noting(c, stop.clone(), &mut refusals),
        _ => None,
    };
    undo.disarm();
    Ok(Running {
        stop,
        live,
        started: std::time::Instant::now(),
        planned_s: cfg.servo.baseline_s + seconds,
        loop_handle: Some(loop_handle),
        dev_handle: Some(dev_handle),
        second_handle,
        bg_handle,
        basis_handle,
        pub_handle: Some(pub_handle),
        awake_handle,
        refusals,
        memory_locked,
        rings,
        device_name,
        basis_refresh_on: cfg.background.basis_refresh_s > 0.0,
        nodes: n,
        tets: mesh.tets().len(),
        r: basis.len(),
        basis_s,
        basis_cache,
        scripted_press_depth_m: (cfg.device.backend == Backend::TouchxSim && cfg.wire.is_none())
            .then_some(cfg.interaction.press_depth_m),
        model_timeout_ms: cfg.watchdog.model_timeout_ms,
        faults,
        instruments: service_sides,
    })
}
