//! `nvtmm bench wire --tick`: the whole guidewire tick in one thread, as
//! issue 16 asks it to be timed: the wire step inside the branched arch's
//! lumen, its wall loads applied to the reduced vessel model
//! ([`Servo::add_point_loads`], through the tick's contributions), the haptic tick (contact, reduced implicit
//! step, passivity QP, [`HapticTick::run`]) and, at the stream's 60 Hz, the
//! lumen's grid rebuilt from the deformed wall
//! ([`crate::wire::TriangleLumen::update_vertices`]).
//!
//! The scene is the service's (`rt-config/guidewire.toml` by default: the
//! branched arch, its cached basis, the `[wire]` and `[guidewire]` keys)
//! with the wire's capacity set to `nodes` and its segment length chosen so
//! that the script's last insertion fills them. The script is run first,
//! untimed (the wire alone, as `examples/guidewire_offline.rs` does). Then a
//! sideways line load presses the wire onto the wall along its length (for
//! the contacts the issue asks for), the hub moves ±1.5 mm at 1 Hz and
//! rolls ±0.3 rad, and after a settling second `ticks` ticks are timed.
//!
//! The wall vertices the lumen is rebuilt from are computed outside the
//! timed part (the service's stream publisher computes them in its own
//! thread); the rebuild itself is timed. A step that fails or leaves a node
//! deeper than the diameter in the wall restores the last good state (the
//! service's watchdog) and is counted.

use crate::haptics::contact::SurfaceIndex;
use crate::haptics::device::DeviceSample;
use crate::haptics::passivity::PassivityFilter;
use crate::haptics::servo::{Servo, ServoParams};
use crate::haptics::tick::{Contribution, HapticTick, TickInput};
use crate::math::Vec3;
use crate::reduced::{basis_rows, Refresher};
use crate::rt::stats::Percentiles;
use crate::service::setup::prepare;
use crate::service::{ConfigSource, StartOptions};
use crate::wire::coupling::{wall_loads, InnerWall, WallLoad, MAX_WALL_LOADS};
use crate::wire::{LumenError, TriangleLumen, Wire, WireParams};
use std::path::Path;
use std::time::Instant;

/// The reduced model's capacity the benchmark runs at (the service picks
/// 32 for r ≤ 32, which the guidewire scene's r = 32 is).
pub(super) const R: usize = 32;

/// What `nvtmm bench wire --tick` measured (JSON keys are a scripting
/// contract). Times in µs.
#[derive(Debug, Clone, serde::Serialize)]
pub struct WireTickBench {
    /// Wire nodes at the end (ghost and hub included).
    pub nodes: usize,
    /// Segment length (mm).
    pub segment_mm: f64,
    /// Inserted length at the end (mm).
    pub inserted_mm: f64,
    /// Newton iterations allowed per step.
    pub iterations_max: usize,
    /// Mean Newton iterations per step.
    pub iterations_mean: f64,
    /// Evaluations a step allowed (the wire's `max_evaluations`).
    pub evaluations_max_allowed: usize,
    /// Mean evaluations of the wire's incremental potential per step
    /// (assemblies, line-search trials, the final reactions').
    pub evaluations_mean: f64,
    /// The 99.9th percentile and the largest evaluations in a step.
    pub evaluations_p999: usize,
    /// See `evaluations_p999`.
    pub evaluations_max: usize,
    /// Steps that ended because they spent their evaluation budget.
    pub budget_spent: usize,
    /// Steps that stopped their extra iterations at the wire's
    /// `residual_time_limit_us`.
    pub time_limited: usize,
    /// Line load pressing the wire onto the wall (N/m).
    pub line_load_n_per_m: f64,
    /// Ticks timed.
    pub ticks: usize,
    /// Mean and largest contacts per tick.
    pub contacts_mean: f64,
    /// See `contacts_mean`.
    pub contacts_max: usize,
    /// Largest number of point loads on the reduced model.
    pub loads_max: usize,
    /// Ticks on which the passivity filter ran its QP solver (the others
    /// took the interior shortcut).
    pub qp_solved: usize,
    /// Ticks that rebuilt the lumen (60 Hz).
    pub lumen_updates: usize,
    /// Whether the lumen followed the reduced model's deformed wall.
    pub follow_wall: bool,
    /// Whether the ticks ran one a period (`--rt`), not back to back.
    pub paced: bool,
    /// What the OS granted the ticks' thread with `--rt` (default: nothing
    /// asked), and whether memory was locked.
    pub rt: crate::rt::thread::RtGrant,
    /// See `rt`; the refusal's text is among `rt.refusals`.
    pub memory_locked: bool,
    /// Timed steps whose buckling check factored the static Hessian
    /// (docs/WIRE.md "Buckling"), and those that then moved off a saddle.
    pub buckling_checks: usize,
    /// See `buckling_checks`.
    pub buckled: usize,
    /// The tip's position at the end (m): two builds whose steps agree bit
    /// for bit print the same.
    pub tip_m: [f64; 3],
    /// Steps restored to the last good state (failed or too deep).
    pub resets: usize,
    /// Deepest penetration over the timed ticks (mm).
    pub max_penetration_mm: f64,
    /// The whole tick: p50, p99, p99.9, max.
    pub tick_us: Percentiles,
    /// The wire step.
    pub wire_us: Percentiles,
    /// Wall loads from the contacts, onto the reduced model.
    pub loads_us: Percentiles,
    /// The haptic tick (contact, reduced step, QP, gain).
    pub haptic_us: Percentiles,
    /// The passivity filter within it.
    pub qp_us: Percentiles,
    /// The lumen's rebuild, on the ticks that had one: in the service the
    /// publisher's thread does it (in a twin the wire swaps in), so it is
    /// timed apart and not in `tick_us` (which has the swap).
    pub lumen_us: Percentiles,
}

/// What [`bench_wire_tick`] runs.
#[derive(Debug, Clone, Copy)]
pub struct WireTickOptions {
    /// Wire nodes.
    pub nodes: usize,
    /// Ticks timed.
    pub ticks: usize,
    /// Newton iterations a step at most (None: the configuration's).
    pub iterations: Option<usize>,
    /// Evaluations a step at most (the wire's `max_evaluations`; None: the
    /// configuration's).
    pub evaluations: Option<usize>,
    /// Sideways load pressing the wire onto the wall (N/m).
    pub line_load: f64,
    /// Rebuild the lumen from the reduced model's deformed wall.
    pub follow_wall: bool,
    /// Run the ticks as the service's wire thread does: pinned to this CPU
    /// at SCHED_FIFO priority [`RT_PRIORITY`] with memory locked (unlocked
    /// at the end) and the CPU kept awake (a `SCHED_IDLE` spinner there, as
    /// `loop.keep_cpu_awake`), one tick a period (`dt_s`). The calling thread keeps
    /// its policy and pinning afterwards. None: back to back, in an
    /// ordinary thread.
    pub rt_cpu: Option<usize>,
}

/// Undoes what `--rt` set up for the ticks: stops the keep-awake thread,
/// unlocks memory.
#[derive(Default)]
pub(super) struct RtGuard {
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
    awake: Option<std::thread::JoinHandle<()>>,
    /// Whether memory was locked (unlocked when the guard drops).
    pub locked: bool,
}

impl Drop for RtGuard {
    fn drop(&mut self) {
        self.stop.store(true, std::sync::atomic::Ordering::Relaxed);
        if let Some(h) = self.awake.take() {
            let _ = h.join();
        }
        if self.locked {
            crate::rt::thread::unlock_memory();
        }
    }
}

/// The SCHED_FIFO priority of the ticks with [`WireTickOptions::rt_cpu`]
/// (the shipped guidewire configuration's wire thread runs at 80).
pub const RT_PRIORITY: u8 = 80;

/// Runs it on the service configuration at `config`: a wire of `nodes`
/// nodes, at most `iterations` Newton iterations and `evaluations`
/// evaluations a step (None: the configuration's), pressed onto the wall
/// by `line_load` N/m, `ticks` ticks timed. With `follow_wall` the lumen is rebuilt from the reduced
/// model's deformed wall as the service's publisher does (without the
/// share of the deformation the wire's own loads caused; docs/WIRE.md
/// "The wall under the wire"), otherwise from the rest wall (the same
/// rebuild cost). With the configuration's `guidewire.load_wall` the
/// wire's contact has the wall's compliance in series, as in the service.
pub fn bench_wire_tick(config: &Path, o: &WireTickOptions) -> Result<WireTickBench, super::BenchError> {
    let WireTickOptions {
        nodes,
        ticks,
        iterations,
        evaluations,
        line_load,
        follow_wall,
        rt_cpu,
    } = *o;
    let arg = super::BenchError::Arg;
    if !(16..=4096).contains(&nodes) {
        return Err(arg(format!("--nodes {nodes}: must be in 16..=4096")));
    }
    check_steps_and_line_load(ticks, line_load)?;
    let TickScene {
        p,
        mut tick,
        wall,
        lumen,
    } = tick_scene(config)?;
    let (Some(wp), Some(g)) = (&p.cfg.wire, &p.cfg.guidewire) else {
        return Err(arg(format!("{}: no [wire] and [guidewire] tables", config.display())));
    };
    let mut lumen = lumen;

    // The wire: `nodes` nodes holding the script's last insertion.
    let end_ins = g.script.last().map(|r| r[1]).unwrap_or(g.inserted_m).max(g.inserted_m);
    let seg = (end_ins / (nodes as f64 - 1.6)).max(wp.diameter_m);
    let params = WireParams {
        max_nodes: nodes,
        segment_length_m: seg,
        newton_iterations: iterations.unwrap_or(wp.newton_iterations),
        max_evaluations: evaluations.unwrap_or(wp.max_evaluations),
        ..wp.clone()
    };
    params
        .validate(Path::new("(bench wire --tick)"))
        .map_err(|e| arg(e.to_string()))?;
    let axis = Vec3::from(g.axis);
    let mut wire =
        Wire::new(&params, Vec3::from(g.access_point_m), axis, g.inserted_m).map_err(|e| arg(e.to_string()))?;
    let dt = params.dt_s;
    let script_end = g.script.last().map(|r| r[0]).unwrap_or(0.0) + 0.5;
    let mut step = 0usize;
    let fail = |step: usize, reason: String| super::BenchError::Step { step, reason };
    // The script and the settling ticks below run with no time limit on
    // the extra iterations, so that the timed ticks begin where they began
    // last time however busy the machine was.
    wire.set_residual_time_limit_us(0.0);
    while (step as f64) * dt < script_end {
        let (ins, roll) = g.script_at(step as f64 * dt);
        wire.set_hub(ins, roll);
        step += 1;
        wire.step(&lumen).map_err(|e| fail(step, e.to_string()))?;
    }
    let (ins0, roll0) = (wire.inserted(), wire.roll());

    // Pressed sideways (across the arch's plane) onto the wall.
    wire.set_line_load(Vec3::new(0.0, -line_load, 0.0));
    wire.save_good_state();
    let mut loads: heapless::Vec<WallLoad, MAX_WALL_LOADS> = heapless::Vec::new();
    let mut point_loads: heapless::Vec<(u32, Vec3), MAX_WALL_LOADS> = heapless::Vec::new();
    let mut follow = WallFollow::new(&wall, &lumen);
    let settle = 1000;
    let cap = settle + ticks;
    let (mut t_tick, mut t_wire, mut t_loads, mut t_haptic, mut t_qp, mut t_lumen) = (
        Vec::with_capacity(cap),
        Vec::with_capacity(cap),
        Vec::with_capacity(cap),
        Vec::with_capacity(cap),
        Vec::with_capacity(cap),
        Vec::with_capacity(cap),
    );
    let mut evals = Vec::with_capacity(ticks);
    let mut budget_spent = 0usize;
    let mut time_limited = 0usize;
    let (mut buckling_checks, mut buckled) = (0usize, 0usize);
    let (mut iters, mut contacts, mut contacts_max, mut loads_max, mut qp_solved, mut resets) =
        (0usize, 0usize, 0usize, 0usize, 0usize, 0usize);
    let mut deepest: f64 = 0.0;
    let stream_every = (1.0 / (60.0 * dt)).round().max(1.0) as usize;
    let r_w = 0.5 * params.diameter_m;
    // As the service's wire thread: pinned, SCHED_FIFO, memory locked, one
    // tick a period (back to back, a FIFO thread would also run into the
    // kernel's RT throttling). The guard stops the keep-awake thread and
    // unlocks memory however the loop ends (a failed step returns early).
    let (grant, rt_guard) = rt_ticks(rt_cpu);
    let period_ns = (dt * 1e9).round() as i64;
    let mut next = crate::rt::clock::now_ns();
    for k in 0..cap {
        if k == settle {
            // The timed ticks with the time limit, as the service's.
            wire.set_residual_time_limit_us(params.residual_time_limit_us);
        }
        if rt_cpu.is_some() {
            next += period_ns;
            crate::rt::clock::sleep_until(next);
        }
        let t = k as f64 * dt;
        let phase = (std::f64::consts::TAU * t).sin();
        wire.set_hub(ins0 - 1.5e-3 + 1.5e-3 * phase, roll0 + 0.3 * phase);
        let update = k % stream_every == 0;
        let rebuild_us = if update {
            follow
                .publish(&tick, &wall, follow_wall)
                .map_err(|e| fail(k, e.to_string()))?
        } else {
            0.0
        };
        let t0 = Instant::now();
        if update {
            follow.swap_into(&mut lumen);
        }
        let t1 = Instant::now();
        let rep = wire.step(&lumen);
        let t2 = Instant::now();
        let deep = match &rep {
            Ok(r) => r.max_penetration_m > 2.0 * r_w,
            Err(_) => true,
        };
        if deep {
            wire.restore_good_state();
        }
        wall_loads(&wall, &lumen, wire.contacts(), &mut loads);
        point_loads.clear();
        for l in &loads {
            let _ = point_loads.push((l.node, l.force));
        }
        let axial = rep.as_ref().map(|r| r.hub_axial_force_n).unwrap_or(0.0);
        let wire_part = Contribution {
            force: -axis * axial.clamp(-3.0, 3.0),
            point_loads: &point_loads,
            ..Contribution::default()
        };
        let t3 = Instant::now();
        let sample = DeviceSample {
            seq: k as u64 + 1,
            time_s: t,
            ..DeviceSample::REST
        };
        let out = tick.run_with(
            TickInput {
                sample: Some(&sample),
                now_s: t,
                overrun_streak: 0,
            },
            &[Contribution::PROBE, wire_part],
        );
        let t4 = Instant::now();
        if k % 100 == 0 && !deep {
            wire.save_good_state();
        }
        if k >= settle {
            let us = |a: Instant, b: Instant| (b - a).as_secs_f64() * 1e6;
            t_tick.push(us(t0, t4));
            t_wire.push(us(t1, t2));
            t_loads.push(us(t2, t3));
            t_haptic.push(us(t3, t4));
            t_qp.push(out.qp_us);
            if update {
                t_lumen.push(rebuild_us);
            }
            qp_solved += out.qp_solved as usize;
            resets += deep as usize;
            let c = wire.contacts().len();
            contacts += c;
            contacts_max = contacts_max.max(c);
            loads_max = loads_max.max(point_loads.len());
            if let Ok(r) = &rep {
                iters += r.iterations;
                evals.push(r.evaluations);
                budget_spent += r.budget_spent as usize;
                time_limited += r.time_spent as usize;
                buckling_checks += r.buckling_checked as usize;
                buckled += r.buckled as usize;
                deepest = deepest.max(r.max_penetration_m);
            }
        }
    }
    let memory_locked = rt_guard.locked;
    drop(rt_guard);
    Ok(WireTickBench {
        nodes: wire.num_nodes(),
        segment_mm: seg * 1e3,
        inserted_mm: wire.inserted() * 1e3,
        iterations_max: params.newton_iterations,
        iterations_mean: iters as f64 / ticks as f64,
        evaluations_max_allowed: params.max_evaluations,
        evaluations_mean: evals.iter().sum::<usize>() as f64 / ticks as f64,
        evaluations_p999: {
            evals.sort_unstable();
            evals
                .get((evals.len() * 999 / 1000).min(evals.len().saturating_sub(1)))
                .copied()
                .unwrap_or(0)
        },
        evaluations_max: evals.iter().copied().max().unwrap_or(0),
        budget_spent,
        time_limited,
        line_load_n_per_m: line_load,
        ticks,
        contacts_mean: contacts as f64 / ticks as f64,
        contacts_max,
        loads_max,
        qp_solved,
        lumen_updates: t_lumen.len(),
        follow_wall,
        paced: rt_cpu.is_some(),
        rt: grant,
        memory_locked,
        buckling_checks,
        buckled,
        tip_m: wire.tip().into(),
        resets,
        max_penetration_mm: deepest * 1e3,
        tick_us: Percentiles::of(&t_tick),
        wire_us: Percentiles::of(&t_wire),
        loads_us: Percentiles::of(&t_loads),
        haptic_us: Percentiles::of(&t_haptic),
        qp_us: Percentiles::of(&t_qp),
        lumen_us: Percentiles::of(&t_lumen),
    })
}

/// What both whole-tick benchmarks run on: the service's configuration
/// prepared (scene, basis, keys), the haptic tick as the service builds it
/// (`service::running`), and the inner wall with its lumen (with
/// `guidewire.load_wall` the wall's compliance in series with the rods'
/// contacts, as in the service).
pub(super) struct TickScene {
    /// The prepared configuration.
    pub p: crate::service::setup::Prepared,
    /// The haptic tick, primed.
    pub tick: HapticTick<R>,
    /// The inner wall the rods touch.
    pub wall: InnerWall,
    /// Its lumen.
    pub lumen: crate::wire::TriangleLumen,
}

/// The publisher's part of a tick bench (another thread in the service),
/// on the ticks that stream: the deformed wall at the reduced model's
/// state, without the dent of the instruments' own loads (their contact
/// has the wall's compliance in series instead), and the lumen's grid
/// rebuilt in a twin (timed apart: it is not the RT threads' work) that
/// the rods then swap in.
pub(super) struct WallFollow {
    verts: Vec<Vec3>,
    twin: TriangleLumen,
    last_verts: Vec<Vec3>,
    moved: f64,
}

impl WallFollow {
    /// Starts from the rest wall and the rods' `lumen`.
    pub(super) fn new(wall: &InnerWall, lumen: &TriangleLumen) -> WallFollow {
        WallFollow {
            verts: wall.rest().to_vec(),
            twin: lumen.twin(),
            last_verts: lumen.vertices().to_vec(),
            moved: lumen.moved(),
        }
    }

    /// With `follow_wall` the wall read from `tick`'s model (otherwise the
    /// rest wall again), then the twin rebuilt; returns the rebuild's time
    /// (µs).
    pub(super) fn publish(
        &mut self,
        tick: &HapticTick<R>,
        wall: &InnerWall,
        follow_wall: bool,
    ) -> Result<f64, LumenError> {
        if follow_wall {
            let servo = tick.servo();
            for (v, &node) in self.verts.iter_mut().zip(wall.mesh_nodes()) {
                *v = servo.node_position_without_point_loads(node);
            }
        }
        let step = crate::math::max_distance(&self.verts, &self.last_verts);
        let tr = Instant::now();
        self.twin.update_twin(&self.verts, self.moved + step)?;
        let us = tr.elapsed().as_secs_f64() * 1e6;
        self.moved += step;
        self.last_verts.copy_from_slice(&self.verts);
        Ok(us)
    }

    /// Swaps the rebuilt twin in as the rods' `lumen`.
    pub(super) fn swap_into(&mut self, lumen: &mut TriangleLumen) {
        std::mem::swap(lumen, &mut self.twin);
    }
}

/// The tick benches' `--steps` (at least 1) and `--line-load` (0–100 N/m).
pub(super) fn check_steps_and_line_load(ticks: usize, line_load: f64) -> Result<(), super::BenchError> {
    let arg = super::BenchError::Arg;
    if ticks == 0 {
        return Err(arg("--steps must be at least 1".into()));
    }
    if !(line_load.is_finite() && (0.0..=100.0).contains(&line_load)) {
        return Err(arg(format!("--line-load {line_load}: must be in [0, 100] N/m")));
    }
    Ok(())
}

/// Prepares `config` (it must have `[wire]` and `[guidewire]`) for a
/// whole-tick benchmark.
pub(super) fn tick_scene(config: &Path) -> Result<TickScene, super::BenchError> {
    let arg = super::BenchError::Arg;
    let p = prepare(&StartOptions {
        config: ConfigSource::File(config.to_path_buf()),
        seconds: None,
        observer: crate::observe::Observe::none(),
        record: None,
        device: None,
    })
    .map_err(|e| arg(e.to_string()))?;
    let Some(g) = &p.cfg.guidewire else {
        return Err(arg(format!("{}: no [wire] and [guidewire] tables", config.display())));
    };
    if p.cfg.wire.is_none() {
        return Err(arg(format!("{}: no [wire] and [guidewire] tables", config.display())));
    }
    let mesh = &p.mesh;
    let n = mesh.num_nodes();

    // The haptic loop as the service builds it (running.rs).
    let rows = basis_rows::<R>(&p.basis).map_err(|e| arg(e.to_string()))?;
    let mut refresher = Refresher::new(mesh, &p.basis, &p.mass);
    let zeros = vec![Vec3::zeros(); n];
    // At rest, or with a pressure at the inflated wall, as the service.
    let mut first = match &p.inflated {
        Some(s) => {
            crate::service::background::inflated_model::<R>(rows, &mut refresher, s, &p.dynamics)
                .map_err(|e| arg(e.to_string()))?
                .0
        }
        None => {
            let k0 = refresher.reduced_stiffness(p.model.as_ref(), &zeros);
            crate::service::background::rest_model::<R>(rows, &k0, &p.dynamics, n).map_err(|e| arg(e.to_string()))?
        }
    };
    first.compliance = p.compliance.as_ref().map(|c| c.0.clone());
    let wall = InnerWall::from_mesh(mesh, &g.wall_set).map_err(|e| arg(e.to_string()))?;
    let mut lumen = wall.lumen().map_err(|e| arg(e.to_string()))?;
    // As the service: with `load_wall` the rods' contact has the wall's
    // compliance in series.
    if g.load_wall {
        let c = wall
            .normal_compliance(&first.dynamics, first.compliance.as_deref())
            .ok_or_else(|| arg("the reduced stiffness is singular".into()))?;
        lumen.set_compliance(&c).map_err(|e| arg(e.to_string()))?;
    }
    let index = std::sync::Arc::new(SurfaceIndex::new(mesh, &p.cfg.contact));
    let origin = match &p.cfg.device.frame {
        Some(f) => Vec3::from(f.offset_m),
        None => Vec3::from(p.cfg.device.origin_m),
    };
    let w = &p.cfg.watchdog;
    let sp = ServoParams {
        dt: 1.0 / p.cfg.servo.rate_hz,
        contact: p.cfg.contact,
        device_origin: origin,
        device_timeout_s: w.device_timeout_ms * 1e-3,
        model_timeout_s: f64::INFINITY,
        model_max_age_s: f64::INFINITY,
        max_speed_m_s: w.max_speed_m_s,
        max_reach_m: w.max_reach_m,
        overrun_streak: w.overrun_streak,
        ramp_down_s: w.ramp_down_ms * 1e-3,
        ramp_in_s: w.ramp_in_s,
        swap_blend_s: p.cfg.servo.swap_blend_ms * 1e-3,
        command_timeout_s: w.command_timeout_ms * 1e-3,
    };
    let filter = PassivityFilter::new(&p.passivity).map_err(|e| arg(e.to_string()))?;
    let mut tick = HapticTick::new(Servo::new(first, index, sp, 0.0), filter);
    tick.prime();
    Ok(TickScene { p, tick, wall, lumen })
}

/// With `Some(cpu)`, sets the calling thread up as the service's rod
/// thread (pinned to `cpu`, SCHED_FIFO [`RT_PRIORITY`], memory locked, the
/// CPU kept awake by a `SCHED_IDLE` spinner, as `loop.keep_cpu_awake`
/// does for the loop's: a halted virtual CPU wakes late and cold); what
/// the OS granted, and the guard that undoes it when dropped.
pub(super) fn rt_ticks(rt_cpu: Option<usize>) -> (crate::rt::thread::RtGrant, RtGuard) {
    let mut grant = crate::rt::thread::RtGrant::default();
    let mut rt_guard = RtGuard::default();
    if let Some(cpu) = rt_cpu {
        let locked = crate::rt::thread::lock_memory();
        rt_guard.locked = locked.is_ok();
        grant = crate::rt::thread::setup_current(&crate::rt::thread::RtRequest {
            fifo_priority: Some(RT_PRIORITY),
            cpu: Some(cpu),
            prefault_stack_bytes: 256 * 1024,
        });
        if let Err(e) = locked {
            grant.refusals.push(format!("mlockall refused ({e})"));
        }
        rt_guard.awake = crate::rt::thread::spawn_keep_awake_noting(cpu, rt_guard.stop.clone(), &mut grant.refusals);
    }
    (grant, rt_guard)
}
