//! The end-of-run report of `nvtmm run`: JSON with fixed keys (scripts
//! depend on them, see `docs/SERVICE.md`) and a human-readable summary.

use crate::rt::stats::Percentiles;
use serde::Serialize;
use std::collections::BTreeMap;

/// The passivity QP's part of the report.
#[derive(Debug, Clone, Default, Serialize)]
pub struct QpReport {
    /// QP solves.
    pub solves: u64,
    /// Ticks with the norm bound active.
    pub active_norm: u64,
    /// Ticks with the rate bound active.
    pub active_rate: u64,
    /// Ticks with the energy bound active.
    pub active_energy: u64,
    /// 99th percentile of interior-point iterations.
    pub iters_p99: u32,
    /// 99th percentile of the solve time (µs).
    pub solve_us_p99: f64,
    /// Median solve time (µs).
    pub solve_us_p50: f64,
    /// Solver fallbacks (safe force used instead).
    pub fallbacks: u64,
    /// Lowest tank level (J).
    pub tank_low_j: f64,
    /// Energy the filter's observer counted as delivered to the hand (J):
    /// the commanded force times the measured motion. Beside the device's
    /// own figure (`energy_out_j` when the device reports it), it shows
    /// how well the observer sees the port.
    pub observed_out_j: f64,
    /// Energy the filter's observer counted as put in by the hand (J).
    pub observed_in_j: f64,
    /// Energy the observer charged for intervals it could not see (a
    /// rejected pose, a repeated sample, none: the held force's work at the
    /// last measured velocity; J).
    pub unobserved_j: f64,
    /// Energy the port absorbed over intervals longer than the device's
    /// command timeout (a stalled host, a clock leap), not credited to the
    /// tank: the device may have dropped the force there (J).
    pub uncredited_j: f64,
    /// Ticks whose model force was inside every bound and went out as it
    /// was, without a solve (the shortcut).
    pub shortcuts: u64,
    /// Of `solves`, those the exact active-set step answered with a KKT
    /// certificate, without the interior-point solver (docs/PASSIVITY.md).
    pub exact_solves: u64,
    /// The largest change of the force commanded to the device from one
    /// loop tick to the next (N): at most `passivity.rate_n_per_tick`
    /// unless the energy row needed a faster change or the watchdog ramped
    /// the force down.
    pub command_change_max_n: f64,
}

/// One ring's counters.
#[derive(Debug, Clone, Default, Serialize)]
pub struct RingReport {
    /// Capacity (items).
    pub capacity: usize,
    /// What happens when it is full.
    pub policy: &'static str,
    /// Items that could not be pushed (dropped or deferred).
    pub overflows: u64,
}

/// The background solve's part.
#[derive(Debug, Clone, Default, Serialize)]
pub struct BackgroundReport {
    /// Whether the background solve ran.
    pub enabled: bool,
    /// Full steps done.
    pub steps: u64,
    /// Failed steps (state kept).
    pub failed_steps: u64,
    /// Steps covered by halved sub-steps after a failure at full length.
    pub split_steps: u64,
    /// Full step wall time (ms).
    pub step_ms: Percentiles,
    /// Linearization refresh time (ms).
    pub refresh_ms: Percentiles,
    /// Refreshes per second of wall time.
    pub refresh_hz: f64,
    /// Simulated time / wall time of the full solve.
    pub real_time_factor: f64,
    /// Largest displacement of the full solve at the end (m).
    pub max_displacement_m: f64,
    /// Whether the background basis refresh was on.
    pub basis_refresh_on: bool,
    /// Basis recomputations asked for.
    pub basis_requests: u64,
    /// Bases recomputed (warm-started) by the basis thread.
    pub basis_recomputed: u64,
    /// Recomputations that failed (the basis in use was kept).
    pub basis_failures: u64,
    /// Models sent to the loop that switched to a new basis.
    pub basis_swaps: u64,
    /// Wall time of the recomputations (s; p50, p99, p999, max).
    pub basis_recompute_s: Percentiles,
    /// Subspace iterations of each recomputation.
    pub basis_iterations: Vec<usize>,
}

/// The guidewire's part (`wire.*`; null without `[wire]`).
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct WireReport {
    /// Active nodes at the end (ghost and hub included).
    pub nodes: usize,
    /// Inserted length at the end (m).
    pub inserted_m: f64,
    /// Most inserted during the run (m).
    pub inserted_max_m: f64,
    /// The segment of the inner-wall node nearest the tip at the end
    /// (`aorta`, `brachiocephalic`, `left_common_carotid`,
    /// `left_subclavian`; "unlabelled" on a mesh without segment labels).
    pub tip_segment: String,
    /// How far the rod runs in `tip_segment` back from its tip (m, along
    /// the rod, to the first node nearer another segment's wall): how deep
    /// the tip is in its segment.
    pub tip_depth_m: f64,
    /// Tip position at the end (m, scene frame).
    pub tip_m: [f64; 3],
    /// Most wall contacts in one step.
    pub contacts_max: usize,
    /// Median wall contacts per step.
    pub contacts_p50: f64,
    /// Deepest penetration of the wire's surface into the wall (m).
    pub max_penetration_m: f64,
    /// Largest axial hub force (N, the resistance the hand feels).
    pub axial_force_max_n: f64,
    /// Wire step time in its thread (µs).
    pub step_us: Percentiles,
    /// Wire steps taken.
    pub steps: u64,
    /// Most Newton iterations in one step.
    pub iterations_max: usize,
    /// Most evaluations of the wire's potential in one step (at most the
    /// wire's `max_evaluations`).
    pub evaluations_max: usize,
    /// Steps that ended because they spent `max_evaluations`.
    pub budget_spent_steps: u64,
    /// Steps that stopped going on past `newton_iterations` because they
    /// had run the wire's `residual_time_limit_us`, still off equilibrium
    /// by more than its `residual_tolerance_n`.
    pub time_limited_steps: u64,
    /// Times the wire went back to its last good state (a non-finite step,
    /// a node deeper than the diameter in the wall, or a stalled thread);
    /// each ramps the hand's force to zero.
    pub resets: u64,
    /// Times the loop saw the wire thread stop stepping.
    pub stalls: u64,
    /// Inner-wall updates the wire took from the reduced model.
    pub wall_updates: u64,
    /// Whether the wire thread got SCHED_FIFO.
    pub rt_policy_granted: bool,
    /// Wire thread CPU, if pinned.
    pub cpu: Option<usize>,
    /// System-allocator calls the wire thread made after start.
    pub allocations_after_start: u64,
    /// Wall-load messages the loop had no room for.
    pub loads_ring_full: u64,
    /// Whether the wire's contacts load the vessel (`guidewire.load_wall`).
    pub load_wall: bool,
    /// The inner wall's normal compliance the wire's contact sees in series
    /// (m/N): median and largest over the wall's vertices (0 with a rigid
    /// lumen).
    pub wall_compliance_p50_m_per_n: f64,
    /// See `wall_compliance_p50_m_per_n`.
    pub wall_compliance_max_m_per_n: f64,
    /// Largest give of the wall under one contact (m): compliance × normal
    /// force, what the wire's contact took as the wall's share.
    pub wall_deflection_max_m: f64,
    /// Largest displacement of an inner-wall vertex under the wire's loads
    /// as the stream shows it (m): the reduced model's share plus the
    /// residual compliance's.
    pub wall_dent_max_m: f64,
}

/// The whole report. Keys are a scripting contract.
#[derive(Debug, Clone, Default, Serialize)]
pub struct Report {
    /// Loop ticks run.
    pub ticks: u64,
    /// Seconds the loop ran.
    pub seconds: f64,
    /// Ticks whose computation ended after the next tick's deadline.
    pub deadline_misses: u64,
    /// Deadline misses whose own compute time exceeded the period.
    pub deadline_misses_compute: u64,
    /// Wake-up lateness of the loop against its absolute deadlines (µs).
    pub period_jitter_us: Percentiles,
    /// Work per tick, wake-up to force pushed (µs).
    pub tick_compute_us: Percentiles,
    /// Where the tick's work goes: per phase (rings, swap, wire, contact
    /// and its series solve, step, cross-fade, filter and its QP solves,
    /// output) p50, p99, p99.9 and max over the ticks it ran, its share,
    /// the slowest tick's split and the mean split of the ticks over
    /// [`crate::haptics::phases::TAIL_US`].
    pub tick_phases: crate::haptics::phases::PhasesReport,
    /// Device sample time to that sample's force written to the device (µs).
    pub pose_to_force_latency_us: Percentiles,
    /// A bare absolute-deadline sleep loop on the loop's thread and CPU,
    /// measured in the same run just before the loop started (µs).
    pub baseline_jitter_us: Percentiles,
    /// System-allocator calls made by the RT threads after start.
    pub allocations_after_start: u64,
    /// Page faults (minor + major) the haptic loop thread took after the
    /// jitter baseline (`getrusage(RUSAGE_THREAD)`): first touches of pages
    /// not yet resident; 0 when everything it uses was touched and locked
    /// before.
    pub loop_page_faults_after_start: u64,
    /// Whether the RT threads' allocator was installed (false: the count
    /// above could not be taken and is 0 by construction).
    pub allocator_installed: bool,
    /// Largest force commanded (N).
    pub max_force_n: f64,
    /// The passivity QP.
    pub qp: QpReport,
    /// Energy the hand put into the device port (J).
    pub energy_in_j: f64,
    /// Energy the device port delivered to the hand (J).
    pub energy_out_j: f64,
    /// Where the energies come from ("device" true port velocity, or
    /// "observer" measured velocity).
    pub energy_source: &'static str,
    /// Per-ring capacity, policy and overflows.
    pub ring_overflows: BTreeMap<&'static str, RingReport>,
    /// Models swapped into the loop.
    pub model_swaps: u64,
    /// Whether the loop got SCHED_FIFO.
    pub rt_policy_granted: bool,
    /// What the OS refused (one line each).
    pub rt_refusals: Vec<String>,
    /// Loop CPU, if pinned.
    pub loop_cpu: Option<usize>,
    /// Memory locked (mlockall).
    pub memory_locked: bool,
    /// The loop's CPU was kept from idling (`loop.keep_cpu_awake`).
    pub loop_cpu_kept_awake: bool,
    /// Device backend.
    pub device: String,
    /// Mesh nodes and tets of the full model.
    pub nodes: usize,
    /// Tets.
    pub tets: usize,
    /// Reduced model size r and capacity R.
    pub r: usize,
    /// Capacity R.
    pub r_capacity: usize,
    /// Basis: seconds to compute (0 on a cache hit) and where it came from.
    pub basis_s: f64,
    /// "hit", "computed", ...
    pub basis_cache: String,
    /// The background solve.
    pub background: BackgroundReport,
    /// Watchdog and loop counters.
    pub watchdog: crate::haptics::servo::ServoCounters,
    /// Contact anywhere: new patches, correction delays.
    pub contact: ContactReport,
    /// Device ticks, stale reads and errors.
    pub device_ticks: u64,
    /// Device reads that returned an error.
    pub device_errors: u64,
    /// Largest tool penetration (m).
    pub max_depth_m: f64,
    /// Stream frames published (0 with the stream off).
    pub stream_frames: u64,
    /// The OpenIGTLink server's counters (null when `[stream] igtl` is off):
    /// clients accepted, refused, gone, and per client frames sent and
    /// dropped and messages received and malformed.
    pub igtl: Option<crate::stream::igtl::IgtlStats>,
    /// How far past the undeformed wall the simulated hand's script pushes
    /// the probe (m); None with a real device.
    pub scripted_press_depth_m: Option<f64>,
    /// The model age that counts as stale (ms, `watchdog.model_timeout_ms`).
    pub model_timeout_ms: f64,
    /// Threads that ended before the stop (a panic), each with its panic
    /// message; the loop ran on with its last model. Empty on a clean run.
    pub threads_lost: Vec<LostThread>,
    /// Device periods in which the device thread zeroed the force itself
    /// because the loop had sent no command for 20 ms.
    pub device_loop_silent_periods: u64,
    /// The guidewire (None without `[wire]`); also in `instruments`.
    pub wire: Option<WireReport>,
    /// The task's metrics (None without `[task]`; docs/DRIVING.md).
    pub task: Option<crate::task::TaskSummary>,
    /// The simulated hand's watched moves, in script order (empty unless
    /// `catheter.script` has some; docs/INSTRUMENTS.md "A hand that
    /// watches").
    pub hand_watches: Vec<HandWatchReport>,
    /// Every instrument of the run, in the loop's order: its id, kind,
    /// faults raised and its kind's own keys (docs/INSTRUMENTS.md).
    pub instruments: Vec<crate::service::instrument::InstrumentReport>,
    /// Presses of the switch button that changed the active hub-driven
    /// instrument (docs/INSTRUMENTS.md, "Two instruments, one hand").
    pub instrument_switches: u64,
    /// The second device (`[device.second]`; None without one).
    pub second_device: Option<SecondDeviceReport>,
}

/// How one watched move of the simulated hand ended (`hand_watches[]`).
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct HandWatchReport {
    /// Its row in `catheter.script`.
    pub row: usize,
    /// Whether the run reached it.
    pub reached: bool,
    /// Whether its condition held when it ended (false: it waited its
    /// `within_s`).
    pub met: bool,
    /// How long it moved (s; the script's clock stands still meanwhile).
    pub took_s: f64,
}

/// The second device's keys of the report (`second_device.*`).
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct SecondDeviceReport {
    /// The id of the instrument it drove.
    pub instrument: String,
    /// Its I/O thread's periods.
    pub device_ticks: u64,
    /// Its read and write errors (a stale pose counts).
    pub device_errors: u64,
    /// Loop ticks without a fresh pose from it (its instrument held).
    pub silent_ticks: u64,
    /// Largest force commanded to it (N).
    pub max_force_n: f64,
    /// Ticks its passivity filter solved its QP.
    pub qp_solves: u64,
    /// Ticks its force was at the rate bound or beyond it.
    pub qp_active_rate: u64,
    /// Pose and force commands its rings had no room for.
    pub pose_ring_full: u64,
    /// See `pose_ring_full`.
    pub force_ring_full: u64,
    /// Its pose → force latency (µs).
    pub pose_to_force_latency_us: Percentiles,
}

/// Contact anywhere in the run (the `contact` keys of the report).
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct ContactReport {
    /// Tool spheres that began touching (new contact patches).
    pub new_patches: u64,
    /// From a patch's first touch to its first tick with the residual
    /// compliance correction (ms): p50, p99, max. The table is computed
    /// for every surface node with the basis, so it is 0 whenever a table
    /// is installed.
    pub corrected_after_ms: CorrectionDelay,
    /// Patches corrected, and patches whose touch ended uncorrected.
    pub corrected_patches: u64,
    /// See `corrected_patches`.
    pub never_corrected: u64,
    /// Most spheres touching at once.
    pub patches_max: u64,
    /// Contact ticks, and of them the ticks the loop ran on the immediate
    /// correction only (the residual compliance in series with the
    /// reduced model; nvtmm swaps in no per-patch static modes, the
    /// correction is what makes the patch right once settled).
    pub contact_ticks: u64,
    /// See `contact_ticks`.
    pub immediate_only_ticks: u64,
}

/// Percentiles of the correction delay (ms).
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct CorrectionDelay {
    /// Median.
    pub p50: f64,
    /// 99th percentile.
    pub p99: f64,
    /// Longest.
    pub max: f64,
}

impl ContactReport {
    /// The figures from the loop's events and counters, at `dt_s` per tick.
    pub fn from_loop(
        events: &crate::haptics::servo::ContactEvents,
        counters: &crate::haptics::servo::ServoCounters,
        dt_s: f64,
    ) -> ContactReport {
        let ms = |ticks: usize| ticks as f64 * dt_s * 1e3;
        ContactReport {
            new_patches: events.new_patches,
            corrected_after_ms: CorrectionDelay {
                p50: ms(events.delay_quantile(0.5)),
                p99: ms(events.delay_quantile(0.99)),
                max: ms(events.delay_max()),
            },
            corrected_patches: events.corrected(),
            never_corrected: events.never_corrected,
            patches_max: counters.contact_patches_max,
            contact_ticks: counters.contact_ticks,
            immediate_only_ticks: counters.compliance_ticks,
        }
    }
}

/// A helper thread that ended before the stop.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct LostThread {
    /// Which thread: "background", "basis" or "stream".
    pub thread: String,
    /// Its panic message.
    pub message: String,
}

impl Report {
    /// The human-readable summary.
    pub fn render(&self) -> String {
        let p = |x: &Percentiles| {
            format!(
                "p50 {:.1}  p99 {:.1}  p99.9 {:.1}  max {:.1}",
                x.p50, x.p99, x.p999, x.max
            )
        };
        let mut s = String::new();
        s += &format!(
            "nvtmm run: {} ticks in {:.2} s on {} ({} nodes, {} tets, r = {} of {})\n",
            self.ticks, self.seconds, self.device, self.nodes, self.tets, self.r, self.r_capacity
        );
        s += &format!(
            "  RT: SCHED_FIFO {}, CPU {}, memory {}{}\n",
            if self.rt_policy_granted { "granted" } else { "REFUSED" },
            self.loop_cpu
                .map(|c| c.to_string())
                .unwrap_or_else(|| "not pinned".into()),
            if self.memory_locked { "locked" } else { "not locked" },
            if self.loop_cpu_kept_awake {
                ", loop CPU kept awake"
            } else {
                ""
            }
        );
        for r in &self.rt_refusals {
            s += &format!("    refused: {r}\n");
        }
        s += &format!(
            "  deadline misses: {} ({} from compute)\n",
            self.deadline_misses, self.deadline_misses_compute
        );
        if let Some(d) = &self.second_device {
            s += &format!(
                "  second device: drives the {}, {} periods, {} errors, {} ticks without a fresh pose, force max {:.3} N, pose→force {}\n",
                d.instrument,
                d.device_ticks,
                d.device_errors,
                d.silent_ticks,
                d.max_force_n,
                p(&d.pose_to_force_latency_us)
            );
        }
        s += &format!("  period jitter (µs):   {}\n", p(&self.period_jitter_us));
        s += &format!("  baseline jitter (µs): {}\n", p(&self.baseline_jitter_us));
        s += &format!("  tick compute (µs):    {}\n", p(&self.tick_compute_us));
        s += &self.tick_phases.render();
        s += &format!("  pose→force (µs):      {}\n", p(&self.pose_to_force_latency_us));
        s += &format!(
            "  loop page faults after start: {}\n",
            self.loop_page_faults_after_start
        );
        s += &format!(
            "  allocations after start: {}{}\n",
            self.allocations_after_start,
            if self.allocator_installed {
                ""
            } else {
                " (allocator not installed: not measured)"
            }
        );
        s += &format!(
            "  force: max {:.3} N, deepest contact {:.2} mm; energy in {:.4} J, out {:.4} J ({})\n",
            self.max_force_n,
            self.max_depth_m * 1e3,
            self.energy_in_j,
            self.energy_out_j,
            self.energy_source
        );
        if let Some(d) = self.scripted_press_depth_m {
            s += &format!(
                "    (the scripted hand aims {:.1} mm past the undeformed wall; the wall gives way under the probe, \
                 so the probe sinks only {:.2} mm into the deformed surface)\n",
                d * 1e3,
                self.max_depth_m * 1e3
            );
        }
        let q = &self.qp;
        if q.solves == 0 {
            s += &format!(
                "  QP: no solve needed: on all {} ticks the model's force was inside every bound (norm, rate, energy) \
                 and went out unchanged; {} fallbacks, tank low {:.4} J\n",
                q.shortcuts, q.fallbacks, q.tank_low_j
            );
        } else {
            s += &format!(
                "  QP: {} solves ({} exact on their active set, the rest by the interior-point solver; {} ticks inside every bound took the shortcut), active norm {} rate {} energy {}, \
                 iters p99 {}, solve p50 {:.1} µs p99 {:.1} µs, {} fallbacks, tank low {:.4} J; observer: in {:.4} J, out {:.4} J, unobserved {:.4} J, uncredited {:.4} J; \
                 the commanded force changed by {:.3} N a tick at most\n",
                q.solves,
                q.exact_solves,
                q.shortcuts,
                q.active_norm,
                q.active_rate,
                q.active_energy,
                q.iters_p99,
                q.solve_us_p50,
                q.solve_us_p99,
                q.fallbacks,
                q.tank_low_j,
                q.observed_in_j,
                q.observed_out_j,
                q.unobserved_j,
                q.uncredited_j,
                q.command_change_max_n
            );
        }
        let b = &self.background;
        if b.enabled {
            s += &format!(
                "  background: {} full steps ({} failed, {} split), step p50 {:.1} ms, refresh p50 {:.2} ms, {:.1} models/s, real-time factor {:.2}, {} swaps\n",
                b.steps, b.failed_steps, b.split_steps, b.step_ms.p50, b.refresh_ms.p50, b.refresh_hz, b.real_time_factor, self.model_swaps
            );
            s += &format!(
                "    (real-time factor {:.2}: the full model covers {:.2} s of tissue time per second of wall time{})\n",
                b.real_time_factor,
                b.real_time_factor,
                if b.real_time_factor < 0.95 {
                    "; it falls behind the hand, so the haptic model's linearization grows older as the run goes on"
                } else {
                    "; it keeps up with the hand"
                }
            );
            if b.basis_refresh_on {
                s += &format!(
                    "  basis refresh: {} asked, {} recomputed (warm start, p50 {:.2} s, max {:.2} s), {} failed, {} models switched basis\n",
                    b.basis_requests,
                    b.basis_recomputed,
                    b.basis_recompute_s.p50,
                    b.basis_recompute_s.max,
                    b.basis_failures,
                    b.basis_swaps
                );
            } else {
                s += "  basis refresh: off\n";
            }
        } else {
            s += "  background: off (linear reduced model at rest)\n";
        }
        let w = &self.watchdog;
        s += &format!(
            "  watchdog: {} ticks held down, device silent {} ticks, non-finite {}, wild poses {}, stale model {} ticks ({} past the maximum age); contact {} ticks\n",
            w.watchdog_ticks,
            w.device_silent_ticks,
            w.nonfinite,
            w.bad_pose_samples,
            w.model_stale_ticks,
            w.model_expired_ticks,
            w.contact_ticks
        );
        for l in &self.threads_lost {
            s += &format!(
                "  THREAD LOST: {} ({}); the loop ran on with its last model\n",
                l.thread, l.message
            );
        }
        s += &format!(
            "  contact anywhere: {} of {} contact ticks with the residual compliance (from the first touch: it is precomputed for every surface node), \
             up to {} touched nodes and {} patches at once, {} ticks with patches beyond the corrected {}\n",
            w.compliance_ticks,
            w.contact_ticks,
            w.contact_nodes_max,
            w.contact_patches_max,
            w.uncorrected_ticks,
            crate::haptics::contact::MAX_COMPLIANT_PATCHES
        );
        s += &format!(
            "    the compliance's pair blocks read from its table on {} of those ticks (the others reused them: same touched nodes); \
             {} of {} swaps kept the contact's triangles, {} were matched and stepped to equilibrium a tick ahead; \
             the old model took over {} of the new one's searches in the cross-fades; \
             {} cross-fades ended early (the models' forces within {} mN)\n",
            w.compliance_lookup_ticks,
            w.swaps_carried,
            w.model_swaps,
            w.swaps_prepared,
            w.fade_searches_shared,
            w.fades_ended_early,
            crate::haptics::servo::FADE_DONE_N * 1e3
        );
        let c = &self.contact;
        s += &format!(
            "    {} new patches, corrected after p50 {:.0} ms, p99 {:.0} ms, max {:.0} ms ({} never corrected)\n",
            c.new_patches,
            c.corrected_after_ms.p50,
            c.corrected_after_ms.p99,
            c.corrected_after_ms.max,
            c.never_corrected
        );
        if w.model_stale_ticks > 0 {
            s += &format!(
                "    (stale model: on {} ticks ({:.1} s) the loop rendered force from a model older than {:.0} ms; \
                 the hand still felt the tissue, linearized at an older state)\n",
                w.model_stale_ticks,
                w.model_stale_ticks as f64 / (self.ticks.max(1) as f64 / self.seconds.max(1e-9)),
                self.model_timeout_ms
            );
        }
        let rings: Vec<String> = self
            .ring_overflows
            .iter()
            .map(|(k, v)| format!("{k} {}/{}", v.overflows, v.capacity))
            .collect();
        s += &format!("  ring overflows: {}\n", rings.join(", "));
        if let Some(w) = &self.wire {
            s += &format!(
                "  wire: {} nodes, {:.1} mm inserted (most {:.1}), tip in {}; step (µs) {} over {} steps ({} Newton it., {} evaluations at most; {} spent the budget, {} the time limit), \
                 contacts p50 {:.0} max {}, deepest {:.3} mm, axial force max {:.3} N, {} resets, {} stalls, thread {} on CPU {}\n\
                 {}",
                w.nodes,
                w.inserted_m * 1e3,
                w.inserted_max_m * 1e3,
                w.tip_segment,
                p(&w.step_us),
                w.steps,
                w.iterations_max,
                w.evaluations_max,
                w.budget_spent_steps,
                w.time_limited_steps,
                w.contacts_p50,
                w.contacts_max,
                w.max_penetration_m * 1e3,
                w.axial_force_max_n,
                w.resets,
                w.stalls,
                if w.rt_policy_granted { "SCHED_FIFO" } else { "normal policy" },
                w.cpu.map(|c| c.to_string()).unwrap_or_else(|| "not pinned".into()),
                if w.load_wall {
                    format!(
                        "    wall under the wire: compliance p50 {:.3} max {:.3} mm/N, give max {:.3} mm, dent on the stream max {:.3} mm\n",
                        w.wall_compliance_p50_m_per_n * 1e3,
                        w.wall_compliance_max_m_per_n * 1e3,
                        w.wall_deflection_max_m * 1e3,
                        w.wall_dent_max_m * 1e3
                    )
                } else {
                    "    wall under the wire: not loaded (guidewire.load_wall = false)\n".to_string()
                }
            );
        }
        for h in &self.hand_watches {
            s += &format!(
                "  scripted hand: watched row {} {}\n",
                h.row,
                match (h.reached, h.met) {
                    (false, _) => "not reached".to_string(),
                    (true, true) => format!("met its condition after {:.2} s", h.took_s),
                    (true, false) => format!("waited its within_s ({:.2} s) in vain", h.took_s),
                }
            );
        }
        if let Some(t) = &self.task {
            s += &format!(
                "  task: {} ({}), tip path {:.1} mm, {} pull-backs, hub force peak {:.3} N, wall force peak {:.3} N ({:.2} s above 0.5 N, {:.2} s above 1.5 N), fluoroscopy {:.1} s, {} contrast injections\n",
                t.target_segment,
                match t.time_to_target_s {
                    Some(x) => format!("success at {x:.2} s"),
                    None => "not reached".into(),
                },
                t.tip_path_m * 1e3,
                t.pullbacks,
                t.hub_force_peak_n,
                t.wall_force_peak_n,
                t.wall_above_0_5_n_s,
                t.wall_above_1_5_n_s,
                t.fluoroscopy_s,
                t.contrast_injections
            );
        }
        for i in &self.instruments {
            s += &format!(
                "  instrument {} ({}): {}; {} faults raised\n",
                i.id, i.kind, i.summary, i.faults
            );
        }
        if let Some(g) = &self.igtl {
            let dropped: u64 = g.clients.iter().map(|c| c.frames_dropped).sum();
            let bad: u64 = g.clients.iter().map(|c| c.bad_messages).sum();
            s += &format!(
                "  OpenIGTLink: {} clients ({} refused), {} frames dropped for slow clients, {} malformed client messages\n",
                g.accepted, g.refused, dropped, bad
            );
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn no_solve_times_are_printed_when_nothing_was_solved() {
        let mut r = Report {
            ticks: 1000,
            seconds: 1.0,
            ..Report::default()
        };
        r.qp.shortcuts = 1000;
        let s = r.render();
        assert!(s.contains("no solve needed"), "{s}");
        assert!(!s.contains("solve p50"), "no percentile of zero samples: {s}");
        r.qp.solves = 3;
        r.qp.solve_us_p50 = 20.0;
        assert!(r.render().contains("solve p50 20.0"));
    }

    #[test]
    fn the_report_says_what_stale_ticks_and_the_press_depth_mean() {
        let mut r = Report {
            ticks: 2000,
            seconds: 2.0,
            scripted_press_depth_m: Some(5e-3),
            max_depth_m: 0.27e-3,
            model_timeout_ms: 500.0,
            ..Report::default()
        };
        r.watchdog.model_stale_ticks = 284;
        let s = r.render();
        assert!(s.contains("5.0 mm past the undeformed wall"), "{s}");
        assert!(s.contains("0.284 s") || s.contains("(0.3 s)"), "{s}");
        assert!(s.contains("older than 500 ms"), "{s}");
    }
}
