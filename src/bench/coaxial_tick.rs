//! `nvtmm bench wire --tick --coaxial`: the whole haptic tick with a
//! guidewire inside a catheter in the branched arch, in one thread, as
//! issue 37 asks it to be timed: the coupled step of the pair
//! ([`Coaxial::step`]) in the arch's lumen, both rods' wall loads on the
//! reduced vessel model (two contributions, summed by the tick as the
//! service sums its instruments'), the haptic tick (contact, reduced
//! implicit step, passivity QP,
//! [`crate::haptics::tick::HapticTick::run_with`]) and, at the
//! stream's 60 Hz, the lumen's grid rebuilt (timed apart: the service's
//! publisher does it in its own thread).
//!
//! The scene is the service's (`rt-config/cannulate_left_subclavian.toml`
//! by default: the branched arch, its basis, the `[wire]`, `[guidewire]`
//! and `[catheter]` keys) with both rods' capacities set to `nodes` and
//! each one's segment length chosen so that the hand script's deepest
//! insertion of that rod fills them. The script (`catheter.script`, the
//! instrument column naming which hub moves) is run first, untimed, the
//! hubs following its rows directly (no stylus). Then a sideways line load
//! presses both rods onto the wall along their length (for the contacts
//! the issue asks for), both hubs move ±1.5 mm at 1 Hz and roll ±0.3 rad,
//! out of phase (the wire slides in the catheter), and after a settling
//! second `ticks` ticks are timed. The hand feels the wire's axial force
//! (the active instrument at the start).
//!
//! A coupled step that fails, goes non-finite or leaves a rod deeper than
//! its diameter in the wall (or the wire in the catheter's) restores the
//! pair's last good state, as the service's pair thread does, and is
//! counted. Steps whose rods end off equilibrium by more than their
//! `residual_tolerance_n` are counted too: whether the coupled step
//! converges in this scene.
//!
//! With `parallel` the pair is coupled lagged ([`Coupling::Lagged`]) and
//! the catheter's half of each step runs on a [`CatheterWorker`] pinned to
//! that CPU (SCHED_FIFO at the same priority with `rt_cpu`, its CPU kept
//! awake too, woken for each period by the clock), while the ticks' thread
//! steps the wire: the tick is timed with the two rods stepped at once.
//! `lagged` alone couples the pair lagged in the one thread (what the
//! coupling costs apart from the threads).
//!
//! Allocations in the timed ticks are counted with the project's RT
//! allocator ([`crate::rt::alloc`]): the ticks' thread draws from the RT
//! pool, as the service's threads do, and the benchmark reports the pool's
//! allocations in the rods' part and in the haptic tick, and the system
//! allocator's calls, apart.

use super::wire_tick::{check_steps_and_line_load, rt_ticks, tick_scene, TickScene, WallFollow};
use crate::haptics::device::DeviceSample;
use crate::haptics::tick::{Contribution, TickInput};
use crate::math::Vec3;
use crate::rt::stats::Percentiles;
use crate::service::script::HubRow;
use crate::wire::coaxial::{CatheterWorker, Coaxial, Coupling};
use crate::wire::coupling::{wall_loads, WallLoad, MAX_WALL_LOADS};
use crate::wire::WireParams;
use std::path::Path;
use std::time::Instant;

/// What `nvtmm bench wire --tick --coaxial` measured (JSON keys are a
/// scripting contract). Times in µs.
#[derive(Debug, Clone, serde::Serialize)]
pub struct CoaxialTickBench {
    /// The wire's nodes at the end (ghost and hub included).
    pub wire_nodes: usize,
    /// The catheter's nodes at the end.
    pub catheter_nodes: usize,
    /// The wire's and the catheter's segment lengths (mm).
    pub segment_mm: [f64; 2],
    /// The wire's and the catheter's inserted lengths at the end (mm).
    pub inserted_mm: [f64; 2],
    /// Newton iterations a rod's step allows before it goes on for its
    /// residual (the `[wire]` key, both rods).
    pub iterations_max: usize,
    /// Mean Newton iterations per step: the wire's, the catheter's.
    pub iterations_mean: [f64; 2],
    /// Most Newton iterations in a step: the wire's, the catheter's.
    pub iterations_most: [usize; 2],
    /// Mean evaluations of both rods' potentials per coupled step.
    pub evaluations_mean: f64,
    /// Most evaluations in a coupled step.
    pub evaluations_max: usize,
    /// Coupled steps whose wire or catheter ended off equilibrium by more
    /// than its `residual_tolerance_n` (not converged).
    pub unsettled_steps: usize,
    /// Steps of either rod that stopped their extra iterations at
    /// `residual_time_limit_us`.
    pub time_limited: usize,
    /// Line load pressing both rods onto the wall (N/m).
    pub line_load_n_per_m: f64,
    /// Ticks timed.
    pub ticks: usize,
    /// Mean and largest wall contacts per tick (the wire's outside the
    /// catheter and the catheter's).
    pub contacts_mean: f64,
    /// See `contacts_mean`.
    pub contacts_max: usize,
    /// Mean contacts of the wire on the catheter's inner wall per tick.
    pub sheath_contacts_mean: f64,
    /// Largest number of point loads on the reduced model (both rods).
    pub loads_max: usize,
    /// Ticks on which the passivity filter ran its QP solver.
    pub qp_solved: usize,
    /// Ticks that rebuilt the lumen (60 Hz).
    pub lumen_updates: usize,
    /// Whether the lumen followed the reduced model's deformed wall.
    pub follow_wall: bool,
    /// How the two rods' steps were coupled (`gauss_seidel`, `lagged`).
    pub coupling: Coupling,
    /// The CPU the catheter's worker thread was asked to run on
    /// (`--parallel`); None: both rods in the ticks' thread.
    pub parallel_cpu: Option<usize>,
    /// What the OS granted the catheter's worker thread.
    pub worker_rt: Option<crate::rt::thread::RtGrant>,
    /// System-allocator calls of the catheter's worker thread over its
    /// life (set-up and timed ticks): 0 is the requirement (0 and
    /// meaningless without the RT allocator).
    pub worker_system_allocations: u64,
    /// Timed ticks whose catheter step the ticks' thread took back and ran
    /// itself, the worker not having begun it when the wire's step was done
    /// (`CatheterWorker::taken_back`).
    pub worker_taken_back: u64,
    /// Whether the ticks ran one a period (`--rt`), not back to back.
    pub paced: bool,
    /// What the OS granted the ticks' thread with `--rt`.
    pub rt: crate::rt::thread::RtGrant,
    /// Whether memory was locked.
    pub memory_locked: bool,
    /// Coupled steps restored to the pair's last good state (failed,
    /// non-finite or too deep), in the set-up and in the timed ticks.
    pub resets_setup: usize,
    /// See `resets_setup`.
    pub resets: usize,
    /// Deepest penetration into the vessel's wall over the timed ticks
    /// (mm, either rod).
    pub max_penetration_mm: f64,
    /// Deepest penetration of the wire into the catheter's wall (mm).
    pub max_sheath_penetration_mm: f64,
    /// Allocations from the RT pool in the timed ticks' rods' part (the
    /// coupled step and the wall loads): 0 is the requirement.
    pub pool_allocations_rods: u64,
    /// Allocations from the RT pool in the timed haptic ticks (the QP
    /// solver's one small block a solve, which the pool exists for).
    pub pool_allocations_haptic: u64,
    /// System-allocator calls of the ticks' thread in the timed ticks
    /// (all parts, the lumen's rebuild included): 0 is the requirement.
    pub system_allocations: u64,
    /// Whether the RT allocator is this process's global allocator (the
    /// `nvtmm` binary's): without it the allocation counts are 0 and mean
    /// nothing.
    pub allocator_installed: bool,
    /// The whole tick: p50, p99, p99.9, max.
    pub tick_us: Percentiles,
    /// The coupled step (both rods).
    pub pair_us: Percentiles,
    /// Wall loads from both rods' contacts, onto the reduced model.
    pub loads_us: Percentiles,
    /// The haptic tick (contact, reduced step, QP, gain).
    pub haptic_us: Percentiles,
    /// The passivity filter within it.
    pub qp_us: Percentiles,
    /// The lumen's rebuild, on the ticks that had one (not in `tick_us`).
    pub lumen_us: Percentiles,
}

/// What [`bench_coaxial_tick`] runs.
#[derive(Debug, Clone, Copy)]
pub struct CoaxialTickOptions {
    /// Nodes of each rod.
    pub nodes: usize,
    /// Ticks timed.
    pub ticks: usize,
    /// Sideways load pressing both rods onto the wall (N/m).
    pub line_load: f64,
    /// Rebuild the lumen from the reduced model's deformed wall.
    pub follow_wall: bool,
    /// Run the ticks as the service's pair thread does (pinned to this CPU,
    /// SCHED_FIFO, memory locked, one tick a period); None: back to back.
    pub rt_cpu: Option<usize>,
    /// Couple the pair lagged ([`Coupling::Lagged`]) in the ticks' thread.
    pub lagged: bool,
    /// Couple the pair lagged and step the catheter on a worker thread
    /// pinned to this CPU (with `rt_cpu`: SCHED_FIFO as the ticks' thread,
    /// its CPU kept awake); implies `lagged`.
    pub parallel: Option<usize>,
}

/// Where a rod's hub is at script time `t_s`: linear between that
/// instrument's rows, its `start` before its first, its last row after.
fn hub_at(rows: &[HubRow], instrument: usize, start: (f64, f64), t_s: f64) -> (f64, f64) {
    let mut prev: Option<&HubRow> = None;
    for r in rows.iter().filter(|r| r.instrument == instrument) {
        if t_s <= r.t_s {
            return match prev {
                None => (r.inserted_m, r.roll_rad),
                Some(p) => {
                    let a = (t_s - p.t_s) / (r.t_s - p.t_s).max(1e-12);
                    (
                        p.inserted_m + a * (r.inserted_m - p.inserted_m),
                        p.roll_rad + a * (r.roll_rad - p.roll_rad),
                    )
                }
            };
        }
        prev = Some(r);
    }
    prev.map_or(start, |p| (p.inserted_m, p.roll_rad))
}

/// A rod's capacity set to `nodes`, with the segment length that makes its
/// deepest insertion `deepest_m` fill them.
fn sized(p: &WireParams, nodes: usize, deepest_m: f64) -> WireParams {
    WireParams {
        max_nodes: nodes,
        segment_length_m: (deepest_m / (nodes as f64 - 1.6)).max(p.diameter_m),
        ..p.clone()
    }
}

/// Runs it on the service configuration at `config` (with `[wire]`,
/// `[guidewire]` and `[catheter]`; module docs).
pub fn bench_coaxial_tick(config: &Path, o: &CoaxialTickOptions) -> Result<CoaxialTickBench, super::BenchError> {
    let CoaxialTickOptions {
        nodes,
        ticks,
        line_load,
        follow_wall,
        rt_cpu,
        lagged,
        parallel,
    } = *o;
    let arg = super::BenchError::Arg;
    if !(16..=1024).contains(&nodes) {
        return Err(arg(format!("--nodes {nodes}: must be in 16..=1024 with --coaxial")));
    }
    check_steps_and_line_load(ticks, line_load)?;
    let TickScene {
        p,
        mut tick,
        wall,
        mut lumen,
    } = tick_scene(config)?;
    let (Some(wp), Some(g), Some(cat)) = (&p.cfg.wire, &p.cfg.guidewire, &p.cfg.catheter) else {
        return Err(arg(format!(
            "{}: no [wire], [guidewire] and [catheter] tables",
            config.display()
        )));
    };
    let rows = cat.rows(g);
    let starts = [(g.inserted_m, 0.0), (cat.inserted_m, 0.0)];
    let deepest = |k: usize| {
        rows.iter()
            .filter(|r| r.instrument == k)
            .map(|r| r.inserted_m)
            .fold(starts[k].0, f64::max)
    };
    let wire_p = sized(wp, nodes, deepest(0));
    let cat_p = sized(&cat.params(wp), nodes, deepest(1));
    for (name, q) in [("wire", &wire_p), ("catheter", &cat_p)] {
        q.validate(Path::new(&format!("(bench wire --tick --coaxial: the {name})")))
            .map_err(|e| arg(e.to_string()))?;
    }
    let (access, axis) = g
        .hub_pose(&p.mesh, &wall, &lumen)
        .map_err(|e| arg(format!("guidewire.access: {e}")))?;
    let mut pair =
        Coaxial::new(&wire_p, &cat_p, access, axis, g.inserted_m, cat.inserted_m).map_err(|e| arg(e.to_string()))?;
    pair.set_friction(cat.wire_friction);
    pair.set_load_stiffness_share(cat.coupling_stiffness_share);
    if lagged || parallel.is_some() {
        pair.set_coupling(Coupling::Lagged);
    }
    // Set up as the ticks' thread will be (the RT pool only with `rt_cpu`:
    // the process's pool is reserved by the first thread that enters it).
    let mut worker = match parallel {
        Some(cpu) => Some(
            CatheterWorker::spawn(
                &crate::rt::thread::RtRequest {
                    fifo_priority: rt_cpu.map(|_| super::wire_tick::RT_PRIORITY),
                    cpu: Some(cpu),
                    prefault_stack_bytes: 256 * 1024,
                },
                rt_cpu.map(|_| crate::service::running::RT_POOL_BYTES),
            )
            .map_err(|e| arg(format!("--parallel {cpu}: the catheter's thread: {e}")))?,
        ),
        None => None,
    };
    let worker_rt = worker.as_ref().map(|w| w.grant().clone());
    let dt = wire_p.dt_s;
    let (wire_d, cat_d) = (wire_p.diameter_m, cat_p.diameter_m);
    let deep = |pair: &Coaxial, r: &Result<crate::wire::coaxial::CoaxialReport, _>| match r {
        Ok(r) => {
            r.wire.max_penetration_m > wire_d
                || r.catheter.max_penetration_m > cat_d
                || r.wire.max_sheath_penetration_m > wire_d
                || !pair.is_finite()
        }
        Err(_) => true,
    };

    // The set-up: the script's rows, untimed, as the service's pair
    // thread would step them (a bad step restores the last good state).
    // It and the settling ticks below run with no time limit on the extra
    // iterations: where a busy CPU made a step meet it, the timed ticks
    // began elsewhere (lagged, 27 to 49 wall contacts at 6 N/m from one
    // build).
    pair.wire_mut().set_residual_time_limit_us(0.0);
    pair.catheter_mut().set_residual_time_limit_us(0.0);
    let script_end = rows.last().map_or(0.0, |r| r.t_s) + 0.5;
    let mut resets_setup = 0usize;
    let mut step = 0usize;
    while (step as f64) * dt < script_end {
        let t = step as f64 * dt;
        let (wi, wr) = hub_at(&rows, 0, starts[0], t);
        let (ci, cr) = hub_at(&rows, 1, starts[1], t);
        pair.set_hubs(wi, wr, ci, cr);
        step += 1;
        let r = match worker.as_mut() {
            Some(w) => pair.step_on(&lumen, w),
            None => pair.step(&lumen),
        };
        if deep(&pair, &r) {
            pair.restore_good_state();
            resets_setup += 1;
        } else if step % 100 == 0 {
            pair.save_good_state();
        }
    }
    let hubs0 = [
        (pair.wire().inserted(), pair.wire().roll()),
        (pair.catheter().inserted(), pair.catheter().roll()),
    ];

    // Both pressed sideways (across the arch's plane) onto the wall.
    let sideways = Vec3::new(0.0, -line_load, 0.0);
    pair.wire_mut().set_line_load(sideways);
    pair.catheter_mut().set_line_load(sideways);
    pair.save_good_state();
    let mut loads: heapless::Vec<WallLoad, MAX_WALL_LOADS> = heapless::Vec::new();
    let mut wire_loads: heapless::Vec<(u32, Vec3), MAX_WALL_LOADS> = heapless::Vec::new();
    let mut cat_loads: heapless::Vec<(u32, Vec3), MAX_WALL_LOADS> = heapless::Vec::new();
    let mut follow = WallFollow::new(&wall, &lumen);
    let settle = 1000;
    let cap = settle + ticks;
    let mut times: [Vec<f64>; 6] = std::array::from_fn(|_| Vec::with_capacity(cap));
    let (mut iters, mut iters_most) = ([0usize; 2], [0usize; 2]);
    let (mut evals, mut evals_max, mut unsettled, mut time_limited) = (0usize, 0usize, 0usize, 0usize);
    let (mut contacts, mut contacts_max, mut sheath, mut loads_max, mut qp_solved, mut resets) =
        (0usize, 0usize, 0usize, 0usize, 0usize, 0usize);
    let (mut deepest_wall, mut deepest_sheath) = (0.0_f64, 0.0_f64);
    let (mut pool_rods, mut pool_haptic) = (0u64, 0u64);
    let tol = [wire_p.residual_tolerance_n, cat_p.residual_tolerance_n];
    let stream_every = (1.0 / (60.0 * dt)).round().max(1.0) as usize;
    // The worker's CPU kept awake too (a halted virtual CPU wakes late),
    // from here: a thread started after `rt_ticks` pins this one inherits
    // its CPU and could not move.
    let awake_stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let mut worker_rt = worker_rt;
    let worker_awake = match (rt_cpu, parallel, worker_rt.as_mut()) {
        (Some(_), Some(cpu), Some(g)) => {
            crate::rt::thread::spawn_keep_awake_noting(cpu, awake_stop.clone(), &mut g.refusals)
        }
        _ => None,
    };
    let (grant, rt_guard) = rt_ticks(rt_cpu);
    let pool = crate::rt::alloc::enter_rt(crate::service::running::RT_POOL_BYTES);
    let allocator_installed = pool.map(|p| p.installed).unwrap_or(false);
    let pool_allocs = || crate::rt::alloc::stats().pool_allocs;
    let fail = |step: usize, reason: String| super::BenchError::Step { step, reason };
    let period_ns = (dt * 1e9).round() as i64;
    let mut next = crate::rt::clock::now_ns();
    let mut system = 0u64;
    let mut taken0 = 0u64;
    for k in 0..cap {
        if k == settle {
            // The timed ticks with the time limit, as the service's.
            pair.wire_mut()
                .set_residual_time_limit_us(wire_p.residual_time_limit_us);
            pair.catheter_mut()
                .set_residual_time_limit_us(cat_p.residual_time_limit_us);
            system = crate::rt::alloc::thread_system_calls();
            taken0 = worker.as_ref().map_or(0, CatheterWorker::taken_back);
        }
        if rt_cpu.is_some() {
            next += period_ns;
            crate::rt::clock::sleep_until(next);
        }
        let t = k as f64 * dt;
        let (s, c) = (std::f64::consts::TAU * t).sin_cos();
        pair.set_hubs(
            hubs0[0].0 - 1.5e-3 + 1.5e-3 * s,
            hubs0[0].1 + 0.3 * s,
            hubs0[1].0 - 1.5e-3 + 1.5e-3 * c,
            hubs0[1].1 + 0.3 * c,
        );
        let update = k % stream_every == 0;
        let rebuild_us = if update {
            follow
                .publish(&tick, &wall, follow_wall)
                .map_err(|e| fail(k, e.to_string()))?
        } else {
            0.0
        };
        let a0 = pool_allocs();
        let t0 = Instant::now();
        if update {
            follow.swap_into(&mut lumen);
        }
        let t1 = Instant::now();
        let rep = match worker.as_mut() {
            Some(w) => {
                if rt_cpu.is_some() {
                    w.wake_at(next + period_ns);
                }
                pair.step_on(&lumen, w)
            }
            None => pair.step(&lumen),
        };
        let t2 = Instant::now();
        let bad = deep(&pair, &rep);
        if bad {
            pair.restore_good_state();
        }
        // Each rod's wall loads, one contribution each (as the service's
        // two instruments send them).
        for (contacts, out) in [
            (pair.wire().contacts(), &mut wire_loads),
            (pair.catheter().contacts(), &mut cat_loads),
        ] {
            wall_loads(&wall, &lumen, contacts, &mut loads);
            out.clear();
            for l in &loads {
                let _ = out.push((l.node, l.force));
            }
        }
        let axial = rep.as_ref().map(|r| r.wire.hub_axial_force_n).unwrap_or(0.0);
        let parts = [
            Contribution::PROBE,
            Contribution {
                force: -axis * axial.clamp(-3.0, 3.0),
                point_loads: &wire_loads,
                ..Contribution::default()
            },
            Contribution {
                point_loads: &cat_loads,
                ..Contribution::default()
            },
        ];
        let t3 = Instant::now();
        let a1 = pool_allocs();
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
            &parts,
        );
        let t4 = Instant::now();
        let a2 = pool_allocs();
        if k % 100 == 0 && !bad {
            pair.save_good_state();
        }
        if k >= settle {
            let us = |a: Instant, b: Instant| (b - a).as_secs_f64() * 1e6;
            for (v, x) in times
                .iter_mut()
                .zip([us(t0, t4), us(t1, t2), us(t2, t3), us(t3, t4), out.qp_us])
            {
                v.push(x);
            }
            if update {
                times[5].push(rebuild_us);
            }
            pool_rods += a1 - a0;
            pool_haptic += a2 - a1;
            qp_solved += out.qp_solved as usize;
            resets += bad as usize;
            let c = pair.wall_contacts().count();
            contacts += c;
            contacts_max = contacts_max.max(c);
            loads_max = loads_max.max(wire_loads.len() + cat_loads.len());
            if let Ok(r) = &rep {
                for (j, s) in [&r.wire, &r.catheter].into_iter().enumerate() {
                    iters[j] += s.iterations;
                    iters_most[j] = iters_most[j].max(s.iterations);
                    time_limited += s.time_spent as usize;
                    deepest_wall = deepest_wall.max(s.max_penetration_m);
                }
                evals += r.evaluations;
                evals_max = evals_max.max(r.evaluations);
                sheath += r.wire.sheath_contacts;
                deepest_sheath = deepest_sheath.max(r.wire.max_sheath_penetration_m);
                unsettled += (r.wire.residual_n > tol[0] || r.catheter.residual_n > tol[1]) as usize;
            }
        }
    }
    let system_allocations = crate::rt::alloc::thread_system_calls() - system;
    crate::rt::alloc::leave_rt();
    let memory_locked = rt_guard.locked;
    let worker_taken_back = worker.as_ref().map_or(0, |w| w.taken_back() - taken0);
    let worker_system_allocations = worker.take().map_or(0, CatheterWorker::stop);
    drop(rt_guard);
    awake_stop.store(true, std::sync::atomic::Ordering::Relaxed);
    if let Some(h) = worker_awake {
        let _ = h.join();
    }
    let per = |x: usize| x as f64 / ticks as f64;
    let [t_tick, t_pair, t_loads, t_haptic, t_qp, t_lumen] = &times;
    Ok(CoaxialTickBench {
        wire_nodes: pair.wire().num_nodes(),
        catheter_nodes: pair.catheter().num_nodes(),
        segment_mm: [wire_p.segment_length_m * 1e3, cat_p.segment_length_m * 1e3],
        inserted_mm: [pair.wire().inserted() * 1e3, pair.catheter().inserted() * 1e3],
        iterations_max: wire_p.newton_iterations,
        iterations_mean: [per(iters[0]), per(iters[1])],
        iterations_most: iters_most,
        evaluations_mean: per(evals),
        evaluations_max: evals_max,
        unsettled_steps: unsettled,
        time_limited,
        line_load_n_per_m: line_load,
        ticks,
        contacts_mean: per(contacts),
        contacts_max,
        sheath_contacts_mean: per(sheath),
        loads_max,
        qp_solved,
        lumen_updates: t_lumen.len(),
        follow_wall,
        coupling: pair.coupling(),
        parallel_cpu: parallel,
        worker_rt,
        worker_system_allocations,
        worker_taken_back,
        paced: rt_cpu.is_some(),
        rt: grant,
        memory_locked,
        resets_setup,
        resets,
        max_penetration_mm: deepest_wall * 1e3,
        max_sheath_penetration_mm: deepest_sheath * 1e3,
        pool_allocations_rods: pool_rods,
        pool_allocations_haptic: pool_haptic,
        system_allocations,
        allocator_installed,
        tick_us: Percentiles::of(t_tick),
        pair_us: Percentiles::of(t_pair),
        loads_us: Percentiles::of(t_loads),
        haptic_us: Percentiles::of(t_haptic),
        qp_us: Percentiles::of(t_qp),
        lumen_us: Percentiles::of(t_lumen),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_hub_follows_its_own_instruments_rows_only() {
        let row = |t_s, instrument, inserted_m| HubRow {
            t_s,
            instrument,
            inserted_m,
            roll_rad: 0.0,
        };
        let rows = [row(0.0, 0, 0.1), row(1.0, 0, 0.2), row(2.0, 1, 0.05), row(3.0, 1, 0.15)];
        assert!((hub_at(&rows, 0, (0.1, 0.0), 0.5).0 - 0.15).abs() < 1e-12);
        assert_eq!(hub_at(&rows, 0, (0.1, 0.0), 2.5).0, 0.2);
        assert_eq!(hub_at(&rows, 1, (0.05, 0.0), 1.0).0, 0.05);
        assert!((hub_at(&rows, 1, (0.05, 0.0), 2.5).0 - 0.1).abs() < 1e-12);
        assert_eq!(hub_at(&[], 1, (0.07, 0.3), 9.0), (0.07, 0.3));
    }
}
