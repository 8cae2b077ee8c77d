//! The catheter over the guidewire as instruments of the service
//! (docs/INSTRUMENTS.md "The catheter"): with `[catheter]`, the wire of
//! `[wire]` runs inside a catheter and the pair ([`Coaxial`]) steps in ONE
//! fixed-rate RT thread (SCHED_FIFO, pinned, prefaulted, no allocation, no
//! lock, no log after start), as the guidewire's own thread does. The loop
//! sees two hub-driven instruments, the guidewire and the catheter, each
//! with its own rings and figures, built from the guidewire's pieces
//! ([`super::guidewire`]): the stylus drives the active one through its
//! hub drive ([`super::Selector`]), the other holds its hub; each sends
//! its own wall loads (summed on the reduced model), its polyline and its
//! report section.
//!
//! ```text
//!  haptic loop (1 kHz)                      pair thread (1/dt_s, +500 µs)
//!  wire's HubDrive ──── wire hub ring ───▶  Coaxial::set_hubs(wire, catheter)
//!  catheter's HubDrive ─ catheter hub ring ▶ Coaxial::step(inner wall)
//!  hand force ◀── the active rod's axial force (atomics, one per rod)
//!  Servo point loads ◀── each rod's wall loads (two rings, summed)
//!  publisher: the inner wall (the catheter's side builds it) ── walls ──▶
//!  publisher ◀── each rod's polyline ─────  positions (stream)
//! ```
//!
//! Adding it took this module and one registry line, plus the `[catheter]`
//! field of the configuration (`ServiceConfig` refuses unknown tables),
//! the guidewire's builder standing aside when `[catheter]` is there (the
//! wire is then the pair's), a builder returning its two instruments
//! together (they share the thread), and the simulated hand's switching
//! script (`crate::service::script::switching_hand`).

use super::guidewire::{
    device_frame, newest_hub, rephase, rod_channels, rod_report, rt_request, take_newest_wall, wait_period,
    wall_and_lumen, GuidewireConfig, RodEnd, WallEnds, WireResult, WireShared, KIND as GUIDEWIRE, WIRE_PHASE,
};
use super::{BuildContext, Built, InstrumentReport, Kind, ServiceSide};
use crate::config::{Checker, ConfigError};
use crate::rt::clock::{self, Nanos};
use crate::rt::thread::{setup_current, RtGrant, RtRequest};
use crate::service::faults::FaultSwitches;
use crate::service::report::Report;
use crate::service::script::{parse_steps, planned_rows, switching_hand, HandStep, HubRow, SwitchingHand};
use crate::service::ServiceError;
use crate::wire::catheter::{catheter_params, TipShape, CATHETER_NEWTON_ITERATIONS};
use crate::wire::coaxial::{CatheterWorker, Coaxial, Coupling, LOAD_STIFFNESS_SHARE, WIRE_CATHETER_FRICTION};
use crate::wire::coupling::InnerWall;
use crate::wire::{TriangleLumen, WireParams};
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};

/// The catheter's kind.
pub const KIND: Kind = Kind {
    name: "catheter",
    code: 3,
};

/// `[catheter]`: a diagnostic catheter over the guidewire of `[wire]`,
/// entering at the guidewire's access (`[guidewire]`, whose thread keys,
/// wall and fault keys the pair's thread takes too). Its solver keys (time
/// step, Newton iterations, contact penalty, grip, drag) and its hub drive
/// are the wire's.
#[derive(Debug, Clone, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CatheterConfig {
    /// The tip shape's preset (`straight`, `vertebral`, `berenstein`,
    /// `cobra`, `headhunter`, `simmons`, `pigtail`; docs/CATHETER.md).
    pub shape: String,
    /// French size: the outer diameter in thirds of a millimetre.
    pub french: f64,
    /// Length (m).
    pub length_m: f64,
    /// Rest length of a segment (m).
    pub segment_length_m: f64,
    /// Capacity in nodes.
    pub max_nodes: usize,
    /// The shaft's effective Young's modulus (Pa).
    pub youngs_modulus_pa: f64,
    /// Density of the wall (kg/m³).
    pub density_kg_m3: f64,
    /// Stiffness of the distal part (30 mm, or the shape's length if
    /// longer) relative to the shaft.
    pub tip_stiffness_factor: f64,
    /// Friction coefficient against the vessel wall.
    pub friction: f64,
    /// Friction coefficient of the wire against the catheter's lumen.
    pub wire_friction: f64,
    /// Inserted length at start (m).
    pub inserted_m: f64,
    /// Newton iterations a catheter's step takes before the residual's
    /// extra ones (`wire.residual_tolerance_n`, `wire.max_extra_iterations`
    /// govern those, as for the wire). One by default: the catheter, loaded
    /// by the wire's forces of the same step, ends one iteration within the
    /// tolerance on nearly every step, and a second fixed one cost a third
    /// of the pair's step (docs/CATHETER.md "The catheter's iterations").
    pub newton_iterations: usize,
    /// The stabilising spring of the pair's coupling, as a share of the
    /// wire's contact penalty ([`Coaxial::set_load_stiffness_share`]; 0
    /// turns it off, and a shaped tip then swings the pair apart).
    pub coupling_stiffness_share: f64,
    /// Couple the pair lagged ([`Coupling::Lagged`]: the catheter under
    /// the wire's contact forces of the period before) and step the
    /// catheter on its own thread, pinned to `cpu`, while the pair's
    /// thread steps the wire (docs/CATHETER.md "The lagged coupling").
    pub parallel: bool,
    /// The CPU of the catheter's thread with `parallel` (−1: not pinned);
    /// not `guidewire.cpu`. It runs at `guidewire.priority`, below the
    /// haptic loop's when they share a CPU.
    pub cpu: i32,
    /// The simulated hand's script: timed rows `[time_s, instrument,
    /// inserted_m, roll_rad]`, instrument 0 the guidewire and 1 the
    /// catheter (the switch button's order), where a row naming the other
    /// instrument than the previous row switches to it, holding it where it
    /// was left ([`switching_hand`]); switch rows `{ t_s, switch_to }`; and
    /// watched moves, tables that move the active instrument until what the
    /// hand sees of a tip meets a condition ([`parse_steps`],
    /// [`crate::service::script::WatchingHand`]). Empty: `guidewire.script`
    /// drives the wire and the catheter stays where it starts.
    pub script: Vec<toml::Value>,
}

impl Default for CatheterConfig {
    fn default() -> Self {
        CatheterConfig {
            shape: "vertebral".into(),
            french: 5.0,
            length_m: 1.0,
            segment_length_m: 3e-3,
            max_nodes: 128,
            youngs_modulus_pa: 1.0e9,
            density_kg_m3: 1500.0,
            tip_stiffness_factor: 1.0 / 3.0,
            friction: 0.1,
            wire_friction: WIRE_CATHETER_FRICTION,
            inserted_m: 0.02,
            newton_iterations: CATHETER_NEWTON_ITERATIONS,
            coupling_stiffness_share: LOAD_STIFFNESS_SHARE,
            parallel: false,
            cpu: 1,
            script: Vec::new(),
        }
    }
}

impl CatheterConfig {
    /// The tip shape (the default's when the name is unknown; validation
    /// refuses it first).
    pub fn tip_shape(&self) -> TipShape {
        TipShape::from_name(&self.shape).unwrap_or(TipShape::Vertebral)
    }

    /// The catheter's rod parameters over the wire `wire`: the preset of
    /// [`catheter_params`] with these keys, and the wire's solver keys
    /// (but its own `newton_iterations`) and hub drive.
    pub fn params(&self, wire: &WireParams) -> WireParams {
        let base = catheter_params(self.french, self.tip_shape());
        WireParams {
            length_m: self.length_m,
            segment_length_m: self.segment_length_m,
            max_nodes: self.max_nodes,
            youngs_modulus_pa: self.youngs_modulus_pa,
            density_kg_m3: self.density_kg_m3,
            tip_stiffness_factor: self.tip_stiffness_factor,
            friction: self.friction,
            friction_smoothing_m: wire.friction_smoothing_m,
            contact_stiffness_n_per_m: wire.contact_stiffness_n_per_m,
            contact_onset_m: wire.contact_onset_m,
            max_hub_force_n: wire.max_hub_force_n,
            drag_n_s_per_m2: wire.drag_n_s_per_m2,
            dt_s: wire.dt_s,
            newton_iterations: self.newton_iterations,
            residual_tolerance_n: wire.residual_tolerance_n,
            residual_time_limit_us: wire.residual_time_limit_us,
            max_extra_iterations: wire.max_extra_iterations,
            max_evaluations: wire.max_evaluations,
            drive: wire.drive,
            ..base
        }
    }

    /// The hand's steps: `script` ([`parse_steps`]; `max_inserted`: the
    /// most the wire and the catheter insert), or without one
    /// `guidewire.script` on the wire (instrument 0). Errors: the row's key
    /// after `catheter.script` (e.g. `[3].speed_m_s`) and the message.
    pub fn steps(&self, g: &GuidewireConfig, max_inserted: [f64; 2]) -> Result<Vec<HandStep>, (String, String)> {
        if self.script.is_empty() {
            Ok(g.script
                .iter()
                .map(|r| {
                    HandStep::Timed(HubRow {
                        t_s: r[0],
                        instrument: 0,
                        inserted_m: r[1],
                        roll_rad: r[2],
                    })
                })
                .collect())
        } else {
            parse_steps(&self.script, 2, &max_inserted)
        }
    }

    /// Whether the hand watches: the script has a watched move or a switch
    /// row (a table), so the scripted Touch X plays it on line
    /// ([`crate::service::script::WatchingHand`]).
    pub fn watches(&self) -> bool {
        self.script.iter().any(toml::Value::is_table)
    }

    /// Each instrument's hub at the start (inserted m, roll rad).
    pub fn start(&self, g: &GuidewireConfig) -> [(f64, f64); 2] {
        [(g.inserted_m, 0.0), (self.inserted_m, 0.0)]
    }

    /// The hand's timed rows, a watched move as if it ran to its limits at
    /// its start ([`planned_rows`]); empty if the script does not parse
    /// (validation says why).
    pub fn rows(&self, g: &GuidewireConfig) -> Vec<HubRow> {
        self.steps(g, [f64::INFINITY; 2])
            .ok()
            .and_then(|s| planned_rows(&s, &self.start(g)).ok())
            .unwrap_or_default()
    }

    /// The simulated hand that follows the script's planned rows
    /// ([`switching_hand`] through the wire's drive; a hand that watches
    /// is played on line instead, and this checks its extremes).
    pub fn hand(&self, g: &GuidewireConfig, wire: &WireParams) -> Result<SwitchingHand, String> {
        let steps = self
            .steps(g, [f64::INFINITY; 2])
            .map_err(|(k, e)| format!("{k}: {e}"))?;
        let rows = planned_rows(&steps, &self.start(g))?;
        switching_hand(&rows, &wire.drive, &self.start(g))
    }

    /// Range checks; keys are named `catheter.…`.
    pub fn validate(&self, path: &Path, wire: &WireParams, g: &GuidewireConfig) -> Result<(), ConfigError> {
        let c = &Checker::new(path);
        if TipShape::from_name(&self.shape).is_none() {
            let names: Vec<&str> = TipShape::ALL.iter().map(|s| s.name()).collect();
            return Err(c.err(
                "catheter.shape",
                format!("\"{}\": must be one of {}", self.shape, names.join(", ")),
            ));
        }
        c.f64_in("catheter.french", self.french, 3.0, 10.0, "F")?;
        let p = self.params(wire);
        if p.inner_diameter_m <= wire.diameter_m {
            return Err(c.err(
                "catheter.french",
                format!(
                    "{} F: its lumen ({:.2} mm) must take the wire's diameter_m ({:.2} mm)",
                    self.french,
                    p.inner_diameter_m * 1e3,
                    wire.diameter_m * 1e3
                ),
            ));
        }
        c.f64_in("catheter.length_m", self.length_m, 0.05, 3.0, "m")?;
        c.f64_in("catheter.segment_length_m", self.segment_length_m, 0.5e-3, 0.02, "m")?;
        c.int_in("catheter.max_nodes", self.max_nodes, 8, 1024)?;
        c.f64_in("catheter.youngs_modulus_pa", self.youngs_modulus_pa, 1e6, 1e11, "Pa")?;
        c.f64_in("catheter.density_kg_m3", self.density_kg_m3, 100.0, 20_000.0, "kg/m^3")?;
        c.f64_in(
            "catheter.tip_stiffness_factor",
            self.tip_stiffness_factor,
            0.01,
            1.0,
            "",
        )?;
        c.f64_in("catheter.friction", self.friction, 0.0, 2.0, "")?;
        c.f64_in("catheter.wire_friction", self.wire_friction, 0.0, 2.0, "")?;
        c.int_in("catheter.newton_iterations", self.newton_iterations, 1, 100)?;
        c.f64_in(
            "catheter.coupling_stiffness_share",
            self.coupling_stiffness_share,
            0.0,
            1.0,
            "",
        )?;
        c.int_in("catheter.cpu", self.cpu, -1, 1023)?;
        if self.parallel && self.cpu >= 0 && self.cpu == g.cpu {
            return Err(c.err(
                "catheter.cpu",
                format!(
                    "{}: with catheter.parallel the catheter's thread needs a CPU other than guidewire.cpu ({})",
                    self.cpu, g.cpu
                ),
            ));
        }
        p.validate(path).map_err(|mut e| {
            e.key = format!("catheter.({})", e.key);
            e
        })?;
        c.f64_in(
            "catheter.inserted_m",
            self.inserted_m,
            0.0,
            p.max_inserted_m(),
            "m (at most what the catheter inserts)",
        )?;
        if !self.script.is_empty() && !g.script.is_empty() {
            return Err(c.err(
                "catheter.script",
                "with [catheter] the hand follows catheter.script (it has an instrument column): \
                 leave guidewire.script empty",
            ));
        }
        let max = [wire.max_inserted_m(), p.max_inserted_m()];
        self.steps(g, max)
            .map_err(|(k, e)| c.err(&format!("catheter.script{k}"), e))?;
        self.hand(g, wire).map_err(|e| c.err("catheter.script", e))?;
        Ok(())
    }
}

/// What the pair's thread needs.
struct CoaxialPlan {
    pair: Coaxial,
    lumen: Box<TriangleLumen>,
    wall: Arc<InnerWall>,
    /// The wire's ends, then the catheter's.
    ends: [RodEnd; 2],
    walls: WallEnds,
    stop: Arc<AtomicBool>,
    faults: Arc<FaultSwitches>,
    request: RtRequest,
    start: Nanos,
    period: Nanos,
    pool_bytes: usize,
    good_every: u32,
    polyline_every: u64,
    /// The catheter's thread (`catheter.parallel`).
    worker: Option<CatheterWorker>,
}

/// What the pair's thread returns: each rod's figures, and the pair's.
struct PairResult {
    wire: WireResult,
    catheter: WireResult,
    /// Deepest the wire went into the catheter's wall (m).
    sheath_penetration_max_m: f64,
    /// Largest sum of the wire's normal forces on the catheter (N).
    coaxial_normal_force_max_n: f64,
    /// The wire's tip beyond the catheter's at the end (m, along the rods).
    wire_lead_m: f64,
    /// How the pair was coupled.
    coupling: Coupling,
    /// What the OS granted the catheter's thread (`catheter.parallel`).
    worker: Option<RtGrant>,
    /// The catheter thread's system-allocator calls after its set-up.
    worker_allocations: u64,
}

/// The pair's thread, joined by whichever of the two service sides
/// finishes first; the other takes its result.
struct PairJoin {
    handle: Option<std::thread::JoinHandle<PairResult>>,
    result: Option<PairResult>,
}

/// The guidewire and the catheter over it when the configuration has
/// `[catheter]` (with `[wire]` and `[guidewire]`): the pair, both rods'
/// rings and sides, and the pair's thread, started half a period after the
/// loop. The guidewire comes first: it is the active instrument at the
/// start.
pub fn build_instrument<const R: usize>(ctx: &BuildContext<'_, R>) -> Result<Vec<Built>, ServiceError> {
    let (Some(wp), Some(g), Some(cat)) = (&ctx.cfg.wire, &ctx.cfg.guidewire, &ctx.cfg.catheter) else {
        return Ok(Vec::new());
    };
    let cp = cat.params(wp);
    let (wall, lumen) = wall_and_lumen(g, ctx.mesh, ctx.vessel)?;
    let (access_point, axis) = g
        .hub_pose(ctx.mesh, &wall, &lumen)
        .map_err(|e| ServiceError::Solver(format!("guidewire.access: {e}")))?;
    let mut pair = Coaxial::new(wp, &cp, access_point, axis, g.inserted_m, cat.inserted_m)
        .map_err(|e| ServiceError::Solver(format!("catheter: {e}")))?;
    pair.set_friction(cat.wire_friction);
    pair.set_load_stiffness_share(cat.coupling_stiffness_share);
    let pool_bytes = crate::service::running::RT_POOL_BYTES;
    let worker = if cat.parallel {
        pair.set_coupling(Coupling::Lagged);
        let request = RtRequest {
            cpu: (cat.cpu >= 0).then_some(cat.cpu as usize),
            ..rt_request(g)
        };
        Some(
            CatheterWorker::spawn(&request, Some(pool_bytes))
                .map_err(|e| ServiceError::Thread("catheter", e.to_string()))?,
        )
    } else {
        None
    };
    let frame = device_frame(ctx);
    let (w, c) = (pair.wire(), pair.catheter());
    let (wire_link, wire_pub, wire_end, _no_walls) =
        rod_channels(wp, w.inserted(), w.roll(), g, &wall, &lumen, ctx.vessel, frame, 0)?;
    let (cat_link, cat_pub, cat_end, walls) =
        rod_channels(&cp, c.inserted(), c.roll(), g, &wall, &lumen, ctx.vessel, frame, 3)?;
    let shared = [wire_end.shared.clone(), cat_end.shared.clone()];
    let wall = Arc::new(wall);
    let plan = CoaxialPlan {
        pair,
        lumen: Box::new(lumen),
        wall: wall.clone(),
        ends: [wire_end, cat_end],
        walls,
        stop: ctx.stop.clone(),
        faults: ctx.faults.clone(),
        request: rt_request(g),
        start: ctx.loop_start + WIRE_PHASE,
        period: (wp.dt_s * 1e9).round() as Nanos,
        pool_bytes,
        good_every: g.good_state_every,
        polyline_every: ctx.state_every.max(1),
        worker,
    };
    let handle = std::thread::Builder::new()
        .name("nvtmm-coaxial".into())
        .stack_size(1 << 20)
        .spawn(move || coaxial_thread(plan))
        .map_err(|e| ServiceError::Thread("wire", e.to_string()))?;
    let join = Arc::new(Mutex::new(PairJoin {
        handle: Some(handle),
        result: None,
    }));
    let [wire_shared, cat_shared] = shared;
    Ok(vec![
        Built {
            id: "guidewire",
            kind: GUIDEWIRE,
            loop_side: Box::new(wire_link),
            publisher_side: Box::new(wire_pub),
            service_side: Box::new(PairService {
                rod: Rod::Wire,
                join: join.clone(),
                wall: wall.clone(),
                shared: wire_shared,
            }),
        },
        Built {
            id: "catheter",
            kind: KIND,
            loop_side: Box::new(cat_link),
            publisher_side: Box::new(cat_pub),
            service_side: Box::new(PairService {
                rod: Rod::Catheter,
                join,
                wall,
                shared: cat_shared,
            }),
        },
    ])
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Rod {
    Wire,
    Catheter,
}

/// One rod's part the running service keeps: the shared join of the
/// pair's thread.
struct PairService {
    rod: Rod,
    join: Arc<Mutex<PairJoin>>,
    wall: Arc<InnerWall>,
    shared: Arc<WireShared>,
}

impl ServiceSide for PairService {
    fn finish(&mut self, report: &mut Report) -> Result<InstrumentReport, ServiceError> {
        let mut j = self
            .join
            .lock()
            .map_err(|_| ServiceError::Thread("wire", "the pair's join was poisoned".into()))?;
        if let Some(h) = j.handle.take() {
            let r = h
                .join()
                .map_err(|_| ServiceError::Thread("wire", "the pair's thread panicked".into()))?;
            // Counted once, for both rods.
            report.allocations_after_start += r.wire.allocations + r.worker_allocations;
            j.result = Some(r);
        }
        let r = j
            .result
            .as_ref()
            .ok_or_else(|| ServiceError::Thread("wire", "the pair's thread was lost".into()))?;
        match self.rod {
            Rod::Wire => {
                let (wr, out) = rod_report("guidewire", GUIDEWIRE, &r.wire, &self.wall, &self.shared);
                report.wire = Some(wr);
                Ok(out)
            }
            Rod::Catheter => {
                let (_, mut out) = rod_report("catheter", KIND, &r.catheter, &self.wall, &self.shared);
                if let Some(k) = out.keys.as_object_mut() {
                    k.insert("sheath_penetration_max_m".into(), r.sheath_penetration_max_m.into());
                    k.insert("coaxial_normal_force_max_n".into(), r.coaxial_normal_force_max_n.into());
                    k.insert("wire_lead_m".into(), r.wire_lead_m.into());
                    k.insert("coupling".into(), r.coupling.name().into());
                    k.insert("parallel".into(), r.worker.is_some().into());
                    if let Some(g) = &r.worker {
                        k.insert(
                            "catheter_thread".into(),
                            serde_json::json!({
                                "cpu": g.cpu,
                                "fifo": g.fifo,
                                "priority": g.priority,
                                "refusals": g.refusals,
                                "allocations_after_start": r.worker_allocations,
                            }),
                        );
                    }
                    // The pair's thread: its allocations are in the
                    // guidewire's section and the top-level key.
                    k.insert("allocations_after_start".into(), r.wire.allocations.into());
                }
                Ok(out)
            }
        }
    }
}

/// The pair's thread: one coupled step per period until `stop`. A step
/// that fails, goes non-finite or deeper than a rod's diameter (into the
/// vessel, or the wire into the catheter's wall), or a reset either rod's
/// loop side asks for, returns both rods to their last good states.
fn coaxial_thread(mut p: CoaxialPlan) -> PairResult {
    let grant = setup_current(&p.request);
    let mut wire = WireResult::start(grant.clone(), p.pair.wire(), &p.lumen);
    let mut cat = WireResult::start(grant, p.pair.catheter(), &p.lumen);
    let mut sheath_max = 0.0_f64;
    let mut normal_max = 0.0_f64;
    let _pool = crate::rt::alloc::enter_rt(p.pool_bytes);
    let wire_d = p.pair.wire().params().diameter_m;
    let cat_d = p.pair.catheter().params().diameter_m;
    let mut hubs = [
        (p.pair.wire().inserted(), p.pair.wire().roll()),
        (p.pair.catheter().inserted(), p.pair.catheter().roll()),
    ];
    let sys0 = crate::rt::alloc::thread_system_calls();
    let mut next = p.start;
    let mut since_good = 0u32;
    while !p.stop.load(Ordering::Relaxed) {
        wait_period(&mut next, p.period, &p.faults);
        for (hub, end) in hubs.iter_mut().zip(p.ends.iter_mut()) {
            if let Some(h) = newest_hub(&mut end.hub) {
                *hub = h;
            }
        }
        p.pair.set_hubs(hubs[0].0, hubs[0].1, hubs[1].0, hubs[1].1);
        if take_newest_wall(&mut p.walls, &mut p.lumen) {
            wire.wall_updates += 1;
            cat.wall_updates += 1;
        }
        if FaultSwitches::take(&p.faults.poison_wire) {
            p.pair.wire_mut().poison_for_tests();
        }
        let t0 = clock::now_ns();
        let step = match p.worker.as_mut() {
            Some(w) => {
                // Woken by the clock for the next period (`wait_period`
                // moved `next` on to it).
                w.wake_at(next);
                p.pair.step_on(&*p.lumen, w)
            }
            None => p.pair.step(&*p.lumen),
        };
        let us = (clock::now_ns() - t0) as f64 * 1e-3;
        wire.step_us.record(us);
        cat.step_us.record(us);
        wire.steps += 1;
        cat.steps += 1;
        let mut reset_asked = false;
        for end in &p.ends {
            reset_asked |= end.shared.take_reset_request();
        }
        let good = match step {
            Ok(rep)
                if rep.wire.max_penetration_m <= wire_d
                    && rep.catheter.max_penetration_m <= cat_d
                    && rep.wire.max_sheath_penetration_m <= wire_d
                    && p.pair.is_finite()
                    && !reset_asked =>
            {
                let [we, ce] = &mut p.ends;
                wire.good_step(&rep.wire, p.pair.wire(), we, &p.wall, &p.lumen);
                cat.good_step(&rep.catheter, p.pair.catheter(), ce, &p.wall, &p.lumen);
                sheath_max = sheath_max.max(rep.wire.max_sheath_penetration_m);
                normal_max = normal_max.max(rep.coaxial_normal_force_n);
                since_good += 1;
                if since_good >= p.good_every
                    && rep.wire.max_penetration_m < 0.25 * wire_d
                    && rep.catheter.max_penetration_m < 0.25 * cat_d
                    && rep.wire.max_sheath_penetration_m < 0.25 * wire_d
                {
                    p.pair.save_good_state();
                    since_good = 0;
                }
                true
            }
            _ => false,
        };
        if !good {
            p.pair.restore_good_state();
            since_good = 0;
        }
        let [we, ce] = &mut p.ends;
        wire.after_step(p.pair.wire(), we, good, p.polyline_every);
        cat.after_step(p.pair.catheter(), ce, good, p.polyline_every);
        rephase(&mut next, p.period);
    }
    wire.allocations = crate::rt::alloc::thread_system_calls() - sys0;
    cat.allocations = wire.allocations;
    crate::rt::alloc::leave_rt();
    let worker = p.worker.as_ref().map(|w| w.grant().clone());
    let worker_allocations = p.worker.take().map_or(0, CatheterWorker::stop);
    wire.finish(p.pair.wire(), &p.ends[0], &p.lumen);
    cat.finish(p.pair.catheter(), &p.ends[1], &p.lumen);
    PairResult {
        coupling: p.pair.coupling(),
        worker,
        worker_allocations,
        wire_lead_m: p.pair.wire_lead_m(),
        wire,
        catheter: cat,
        sheath_penetration_max_m: sheath_max,
        coaxial_normal_force_max_n: normal_max,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_parallel_catheter_refuses_the_wires_cpu() {
        let (w, g) = (WireParams::default(), GuidewireConfig::default());
        let c = CatheterConfig {
            parallel: true,
            cpu: g.cpu,
            ..CatheterConfig::default()
        };
        let e = c.validate(Path::new("x.toml"), &w, &g).expect_err("same CPU");
        assert_eq!(e.key, "catheter.cpu");
        let ok = CatheterConfig {
            parallel: true,
            cpu: g.cpu + 1,
            ..CatheterConfig::default()
        };
        assert!(ok.validate(Path::new("x.toml"), &w, &g).is_ok());
        let e = CatheterConfig {
            cpu: -2,
            ..CatheterConfig::default()
        }
        .validate(Path::new("x.toml"), &w, &g)
        .expect_err("range");
        assert_eq!(e.key, "catheter.cpu");
    }
}
