//! The passivity filter: statistics, the QP set-up and solve, the energy
//! observer and tank (the maths is in the module doc of `passivity`).

use super::params::*;
use super::polish::*;
use super::*;
use crate::config::Checker;
use crate::math::Vec3;
use clarabel::algebra::CscMatrix;
use clarabel::solver::{
    DefaultSettings, DefaultSettingsBuilder, DefaultSolver, IPSolver, SolverStatus, SupportedConeT,
};
use std::path::Path;

/// The solver's verdict, without clarabel's types.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum QpStatus {
    /// Solved to tolerance.
    Solved,
    /// Solved to the reduced tolerance.
    AlmostSolved,
    /// Stopped at `max_iter`.
    MaxIterations,
    /// Any other status (numerical error, infeasibility claim, ...).
    Failed,
    /// Not run: `F_des` already satisfies every row, so it is the answer.
    Interior,
    /// Solved exactly on an active set with a KKT certificate, without the
    /// interior-point solver (`polish::exact`).
    Exact,
    /// Not run this tick (non-finite input).
    NotRun,
}

/// Which bounds the output sits on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Active {
    /// `‖F‖ = B`.
    pub norm: bool,
    /// `‖F − F_prev‖ ≥ Δ` (at the rate bound or beyond it through the slack).
    pub rate: bool,
    /// The energy ball is binding.
    pub energy: bool,
}

/// Why the output did not come from the QP.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Fallback {
    /// The solver failed: `α F_prev` (see the module doc).
    Solver,
    /// A non-finite input: zero force.
    NonFinite,
}

/// The result of one tick.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FilterOutput {
    /// The force to command (N, on the hand).
    pub force: Vec3,
    /// Which bounds are active.
    pub active: Active,
    /// Interior-point iterations.
    pub iterations: u32,
    /// Solver status.
    pub status: QpStatus,
    /// Set when the output is a fallback.
    pub fallback: Option<Fallback>,
    /// How far the rate bound was exceeded (N): `max(0, ‖F − F_prev‖ − Δ)`.
    pub rate_excess_n: f64,
    /// The norm bound used this tick (N).
    pub bound_n: f64,
    /// Tank level after this tick's observer update (J).
    pub tank_j: f64,
}

/// Counters for reports. Fixed size, `Copy`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PassivityStats {
    /// Ticks that ran the QP.
    pub solves: u64,
    /// Ticks with the norm bound active.
    pub active_norm: u64,
    /// Ticks with the rate bound active.
    pub active_rate: u64,
    /// Ticks where the rate bound was exceeded through the slack.
    pub rate_exceeded: u64,
    /// Ticks with the energy ball active.
    pub active_energy: u64,
    /// Solver fallbacks.
    pub fallbacks_solver: u64,
    /// Of which: stopped at `max_iter`.
    pub status_max_iter: u64,
    /// Of which: any other failure status (numerical error, ...).
    pub status_failed: u64,
    /// Solves whose answer was polished (see `polish`).
    pub polished: u64,
    /// Ticks where `F_des` satisfied every row (no solve needed).
    pub interior: u64,
    /// Solves answered by the exact active-set step with a KKT certificate
    /// (the interior-point solver did not run; counted in `solves`, not in
    /// `iter_hist`).
    pub exact: u64,
    /// Solves stopped at `max_iter` whose iterate the polish step turned
    /// into a verified optimum (not counted as fallbacks).
    pub recovered: u64,
    /// Non-finite-input fallbacks.
    pub fallbacks_nonfinite: u64,
    /// Iteration histogram: `iter_hist[i]` = solves that took `i` iterations.
    pub iter_hist: [u64; ITER_HIST_LEN],
    /// Energy the port delivered to the hand (J, sum of positive parts).
    pub delivered_j: f64,
    /// Energy the hand put into the port (J, sum of positive parts).
    pub absorbed_j: f64,
    /// Damping credit given (J).
    pub credit_j: f64,
    /// Energy thrown away at the tank's top (J).
    pub spilled_j: f64,
    /// Energy charged for the intervals the observer could not see (a
    /// repeated, rejected or missing sample at either end): what the held
    /// force delivers at the last measured velocity, `T v·F + T²‖F‖²/2m`,
    /// when positive; never credited (J).
    pub unobserved_j: f64,
    /// Energy the port absorbed over intervals too long for the held force
    /// to be known (a stalled host: the device may have dropped it), not
    /// credited to the tank (J; [`PassivityFilter::withhold_credit`]; the
    /// damping credit is not given there either, and not counted here).
    pub uncredited_j: f64,
    /// Lowest tank level seen (J).
    pub tank_low_j: f64,
    /// The largest change of the commanded force from one tick to the next
    /// (N, [`PassivityFilter::set_commanded`]): the rate row's limit, unless
    /// the energy row used the slack or the watchdog ramped the force down.
    pub command_change_max_n: f64,
}

impl PassivityStats {
    fn new(tank: f64) -> Self {
        PassivityStats {
            solves: 0,
            active_norm: 0,
            active_rate: 0,
            rate_exceeded: 0,
            active_energy: 0,
            fallbacks_solver: 0,
            status_max_iter: 0,
            status_failed: 0,
            polished: 0,
            interior: 0,
            exact: 0,
            recovered: 0,
            fallbacks_nonfinite: 0,
            iter_hist: [0; ITER_HIST_LEN],
            delivered_j: 0.0,
            absorbed_j: 0.0,
            credit_j: 0.0,
            spilled_j: 0.0,
            unobserved_j: 0.0,
            uncredited_j: 0.0,
            tank_low_j: tank,
            command_change_max_n: 0.0,
        }
    }

    /// All fallbacks.
    pub fn fallbacks(&self) -> u64 {
        self.fallbacks_solver + self.fallbacks_nonfinite
    }

    /// The iteration count at quantile `q` in [0, 1] (0 if nothing solved).
    pub fn iter_quantile(&self, q: f64) -> u32 {
        let n: u64 = self.iter_hist.iter().sum();
        if n == 0 {
            return 0;
        }
        let rank = ((q.clamp(0.0, 1.0) * n as f64).ceil() as u64).max(1);
        let mut acc = 0;
        for (i, c) in self.iter_hist.iter().enumerate() {
            acc += c;
            if acc >= rank {
                return i as u32;
            }
        }
        MAX_ITER_CAP
    }

    /// 99th percentile of iterations.
    pub fn iter_p99(&self) -> u32 {
        self.iter_quantile(0.99)
    }
}

// Row layout of A (clarabel: A x + z = b, z in the cones).
pub(super) const N_VARS: usize = 4; // F (3), s
pub(super) const N_ROWS: usize = 13;
// Nonneg row 0: s ≥ 0.
pub(super) const ROW_NORM: usize = 1; // SOC(4): (B, F)
pub(super) const ROW_RATE: usize = 5; // SOC(4): (Δ + s, F − F_prev)
pub(super) const ROW_ENERGY: usize = 9; // SOC(4): (ρ, F − c)

/// Least gap (N) between the energy ball's radius and its centre's
/// distance from the origin: keeps `F = 0` strictly inside (the
/// interior-point method wants a strictly feasible problem). It lets the
/// port deliver at most `T²·2‖c‖·1e-9/(2m)` more per tick (~1e-12 J).
pub(super) const RHO_FLOOR_N: f64 = 1e-9;

/// The energy row as a ball of forces, `‖F − c‖ ≤ r` (N); it always
/// contains `F = 0`. See the module doc of `passivity`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EnergyBall {
    /// Centre (N): `−(m/T) v`.
    pub c: Vec3,
    /// Radius (N): `(m/T)·sqrt(|v|² + 2 (E − E_min)/m)`.
    pub r: f64,
    /// The ball holds the whole norm ball (`‖c‖ + B ≤ r`): it cannot bind,
    /// and the QP gets a stand-in centred at 0 of radius `2B + 1`.
    pub slack: bool,
}

impl EnergyBall {
    /// The energy ball for the predicted stylus velocity `v` (m/s), the
    /// tank's budget above its reserve `budget` (J, ≥ 0), the stylus mass
    /// `m` (kg), the period `dt` (s) and the norm bound `bound` (N).
    pub fn new(v: Vec3, budget: f64, m: f64, dt: f64, bound: f64) -> EnergyBall {
        let k = m / dt;
        let c = -v * k;
        let cn = c.norm();
        let r = (k * (v.norm_squared() + 2.0 * budget.max(0.0) / m).sqrt()).max(cn + RHO_FLOOR_N);
        if !(r.is_finite() && cn.is_finite()) || r >= cn + bound {
            EnergyBall {
                c: Vec3::zeros(),
                r: 2.0 * bound + 1.0,
                slack: true,
            }
        } else {
            EnergyBall { c, r, slack: false }
        }
    }

    /// Whether `f` lies in the ball (to `tol`, N).
    pub fn contains(&self, f: &Vec3, tol: f64) -> bool {
        (f - self.c).norm() <= self.r + tol
    }

    /// The largest `α ∈ [0, 1]` with `α f` in the ball (the ball holds 0).
    pub fn scale_into(&self, f: &Vec3) -> f64 {
        if self.contains(f, 0.0) {
            return 1.0;
        }
        // |f|² α² − 2 (f·c) α + (|c| − r)(|c| + r) = 0, the root in (0, 1).
        let ff = f.norm_squared();
        let fc = f.dot(&self.c);
        let cn = self.c.norm();
        let k = (cn - self.r) * (cn + self.r);
        let disc = (fc * fc - ff * k).max(0.0);
        let a = (fc + disc.sqrt()) / ff;
        if a.is_finite() {
            a.clamp(0.0, 1.0)
        } else {
            0.0
        }
    }
}

/// What one QP solve returns (before the post-processing of `filter`).
#[derive(Debug, Clone, Copy)]
pub(super) struct QpAnswer {
    pub(super) f: Vec3,
    pub(super) status: QpStatus,
    pub(super) iterations: u32,
}

/// The passivity filter: one clarabel solver, the energy tank and the thermal
/// state. Build once, call [`PassivityFilter::filter`] every tick.
pub struct PassivityFilter {
    params: PassivityParams,
    solver: DefaultSolver<f64>,
    // Preallocated problem data; the update calls take &Vec.
    q: Vec<f64>,
    b: Vec<f64>,
    // State.
    f_prev: Vec3,
    /// The force held before `f_prev` (the device still held it for the
    /// first `hold_delay_ticks` of the last interval).
    f_prev2: Vec3,
    x_prev: Vec3,
    have_prev: bool,
    /// The last fresh sample's velocity (for unobserved intervals).
    v_last: Vec3,
    /// The coming call's sample is not a fresh measurement.
    skip: bool,
    /// The coming call's interval is too long for the held force to be
    /// known (the device may have dropped it): no credit for it.
    withhold: bool,
    /// The last call's sample was not one: the interval that follows it
    /// has no observed start.
    gap: bool,
    tank: f64,
    theta: f64,
    stats: PassivityStats,
    /// The force commanded at the last [`Self::set_commanded`].
    commanded: Vec3,
    /// The active set of the last solved tick: the exact step tries it
    /// first (consecutive ticks mostly share it).
    last_guess: Option<Guess>,
    #[cfg(test)]
    inject_failure: bool,
}

impl std::fmt::Debug for PassivityFilter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PassivityFilter")
            .field("params", &self.params)
            .field("f_prev", &self.f_prev)
            .field("tank", &self.tank)
            .field("theta", &self.theta)
            .finish_non_exhaustive()
    }
}

/// A in CSC order: column j of F holds −1 in the tail of each cone (norm,
/// rate, energy); the slack column holds −1 (s ≥ 0) and −1 (rate cone
/// head). A never changes: the data of each tick (bound, `F_prev`, the
/// energy ball) is all in b.
fn a_matrix() -> CscMatrix<f64> {
    let mut rowval = Vec::with_capacity(11);
    let mut nzval = Vec::with_capacity(11);
    for j in 0..3 {
        rowval.extend_from_slice(&[ROW_NORM + 1 + j, ROW_RATE + 1 + j, ROW_ENERGY + 1 + j]);
        nzval.extend_from_slice(&[-1.0, -1.0, -1.0]);
    }
    rowval.extend_from_slice(&[0, ROW_RATE]);
    nzval.extend_from_slice(&[-1.0, -1.0]);
    CscMatrix::new(N_ROWS, N_VARS, vec![0, 3, 6, 9, 11], rowval, nzval)
}

fn settings(p: &PassivityParams) -> Result<DefaultSettings<f64>, PassivityError> {
    DefaultSettingsBuilder::default()
        .verbose(false)
        .presolve_enable(false)
        .input_sparse_dropzeros(false)
        .max_iter(p.max_iter)
        .tol_gap_abs(p.tol_gap_abs)
        .tol_gap_rel(p.tol_gap_rel)
        .tol_feas(p.tol_feas)
        .build()
        .map_err(|e| PassivityError::Solver(e.to_string()))
}

impl PassivityFilter {
    /// Validates `params` and builds the solver (allocates; call before the
    /// loop).
    pub fn new(params: &PassivityParams) -> Result<PassivityFilter, PassivityError> {
        params.validate(&Checker::new(Path::new("<passivity params>")), "passivity")?;
        let p = params.clone();
        // P = 2 I on F (upper triangle), 0 on s.
        let pm = CscMatrix::new(N_VARS, N_VARS, vec![0, 1, 2, 3, 3], vec![0, 1, 2], vec![2.0; 3]);
        let a = a_matrix();
        let q = vec![-2.0, -2.0, -2.0, p.rate_slack_weight_n];
        let mut b = vec![0.0; N_ROWS];
        b[ROW_NORM] = p.peak_force_n;
        b[ROW_RATE] = p.rate_n_per_tick;
        b[ROW_ENERGY] = 2.0 * p.peak_force_n + 1.0;
        let cones = [
            SupportedConeT::NonnegativeConeT(1),
            SupportedConeT::SecondOrderConeT(4),
            SupportedConeT::SecondOrderConeT(4),
            SupportedConeT::SecondOrderConeT(4),
        ];
        let mut solver = DefaultSolver::new(&pm, &q, &a, &b, &cones, settings(&p)?)
            .map_err(|e| PassivityError::Solver(e.to_string()))?;
        if !solver.is_data_update_allowed() {
            return Err(PassivityError::Solver("clarabel does not allow data updates".into()));
        }
        // One solve at set-up: whatever clarabel sizes lazily is sized now.
        solver.solve();
        Ok(PassivityFilter {
            tank: p.tank_initial_j,
            stats: PassivityStats::new(p.tank_initial_j),
            params: p,
            solver,
            q,
            b,
            f_prev: Vec3::zeros(),
            f_prev2: Vec3::zeros(),
            commanded: Vec3::zeros(),
            x_prev: Vec3::zeros(),
            have_prev: false,
            v_last: Vec3::zeros(),
            skip: false,
            withhold: false,
            gap: false,
            theta: 0.0,
            last_guess: None,
            #[cfg(test)]
            inject_failure: false,
        })
    }

    /// The parameters.
    pub fn params(&self) -> &PassivityParams {
        &self.params
    }

    /// Counters since construction.
    pub fn stats(&self) -> &PassivityStats {
        &self.stats
    }

    /// Tank level (J).
    pub fn tank_j(&self) -> f64 {
        self.tank
    }

    /// The last force output (N).
    pub fn last_force(&self) -> Vec3 {
        self.f_prev
    }

    /// Runs one throw-away solve (state untouched). Call it on the RT
    /// thread after [`crate::rt::alloc::enter_rt`] and before the loop:
    /// clarabel's `solve()` frees the timer block of its previous solve, and
    /// the first solve on a new thread frees one that was allocated off that
    /// thread (by the system allocator); priming moves that one free out of
    /// the loop. Allocates (from the RT pool on an RT thread).
    pub fn prime(&mut self) {
        let bound = self.bound_n();
        let ball = EnergyBall {
            c: Vec3::zeros(),
            r: 1.0,
            slack: false,
        };
        let _ = self.solve(Vec3::new(1.0, 1.0, 1.0) * bound, Vec3::zeros(), bound, ball);
    }

    /// Forgets the force history (watchdog): force 0, observer restarted
    /// (the interval across a fault is not accounted). The tank keeps its
    /// level, debt included: a fault never refills it. The thermal state
    /// keeps its heat. Counters stay.
    pub fn reset(&mut self) {
        self.last_guess = None;
        self.f_prev = Vec3::zeros();
        self.have_prev = false;
        // The device is commanded zero from here.
        self.set_commanded(Vec3::zeros());
    }

    /// Tells the filter that the sample of the coming call to
    /// [`PassivityFilter::filter`] is not a fresh measurement of the port:
    /// a sample the watchdog rejected (a pose jump no hand makes), the same
    /// sample again (the device fell silent), or none. The observer then
    /// does not count the motion to or from it (a jump is not a motion the
    /// port made); it charges the tank, for the interval that just ended
    /// and for the one after, what the held force delivers at the last
    /// measured velocity (`T v·F + T²‖F‖²/2m` when positive, never a
    /// credit; [`PassivityStats::unobserved_j`]). While nothing is
    /// observed the force still pushes the moving stylus (the watchdog
    /// takes a few milliseconds to notice a silent device and ramp the
    /// force down): not counting it handed that energy out for free.
    pub fn skip_sample(&mut self) {
        self.skip = true;
    }

    /// The interval ending with the coming call's sample lasted longer than
    /// the device side's command timeout (a stalled host, a clock leap):
    /// the device may have stopped applying the held force somewhere in
    /// it, so what the observer measures there is no evidence of energy
    /// absorbed. Work delivered over it is charged as usual; work absorbed
    /// is counted in [`PassivityStats::uncredited_j`], not credited, and
    /// the damping credit is not given. Before this, a 300 ms clock leap
    /// in the guidewire soak credited the tank with the hand's pull against
    /// a force the device had already dropped.
    pub fn withhold_credit(&mut self) {
        self.withhold = true;
    }

    /// Tells the filter the force actually commanded after its output (the
    /// watchdog may scale it down): that force is held until the next tick,
    /// so the energy observer and the rate row use it. A non-finite force
    /// counts as zero.
    pub fn set_commanded(&mut self, force: Vec3) {
        self.f_prev = if force.iter().all(|c| c.is_finite()) {
            force
        } else {
            Vec3::zeros()
        };
        let change = (self.f_prev - self.commanded).norm();
        self.stats.command_change_max_n = self.stats.command_change_max_n.max(change);
        self.commanded = self.f_prev;
    }

    /// The force to command for the filter's output `filtered` under the
    /// watchdog's gain `gain` while it ramps IN (no fault): `g′·filtered`
    /// with the least `g′` between `gain` and 1 whose change from the force held
    /// now (the last [`Self::set_commanded`]) is within the rate row.
    ///
    /// Why: the rate row bounds the filter's output against the commanded
    /// force, but the hand gets the output times the gain. While the gain
    /// is below one, a falling output lost its (1 − gain) share on top of
    /// the rate's step: at a catheter service's start, the rods settling
    /// and the gain at 0.94, the hand's force fell from 1.77 to 0.72 N in
    /// one tick, over the 1 N limit. `g′·filtered` lies between
    /// `gain·filtered` and `filtered`, so it keeps the norm bound and the
    /// energy ball (both hold `filtered` and the origin, and are convex);
    /// the ramp-in is slowed only as much as the rate needs. When even
    /// `filtered` is beyond the rate (the energy row used the slack), the
    /// plain `gain·filtered`. A fault's ramp-down does not come here: it
    /// is the watchdog's to be fast.
    pub fn ramp_in_within_rate(&self, filtered: Vec3, gain: f64) -> Vec3 {
        let g = gain.clamp(0.0, 1.0);
        let delta = self.params.rate_n_per_tick;
        let (ff, fp) = (filtered.norm_squared(), filtered.dot(&self.f_prev));
        let pp = self.f_prev.norm_squared();
        let usable = ff > 0.0 && ff.is_finite();
        if !usable || (filtered * g - self.f_prev).norm() <= delta {
            return filtered * g;
        }
        // ‖g′F − P‖² ≤ Δ²: g′ between the roots of ff g′² − 2 fp g′ + pp − Δ².
        let disc = fp * fp - ff * (pp - delta * delta);
        if disc.is_nan() || disc < 0.0 {
            return filtered * g;
        }
        let (lo, hi) = ((fp - disc.sqrt()) / ff, (fp + disc.sqrt()) / ff);
        if hi < g || lo > 1.0 {
            return filtered * g;
        }
        filtered * lo.clamp(g, 1.0)
    }

    /// The norm bound for the current thermal state (N).
    pub fn bound_n(&self) -> f64 {
        let p = &self.params;
        match p.norm_bound {
            NormBound::Peak => p.peak_force_n,
            NormBound::Continuous => p.continuous_force_n,
            NormBound::Thermal => {
                let (pk2, c2) = (p.peak_force_n.powi(2), p.continuous_force_n.powi(2));
                (pk2 - (pk2 - c2) * (self.theta / c2).min(1.0)).max(c2).sqrt()
            }
        }
    }

    /// One tick: `f_des` the model's force on the hand (N), `x` and `v` the
    /// measured stylus position (m) and velocity (m/s). Returns the force to
    /// command, held until the next call. Does not allocate (but see the
    /// module doc on clarabel's timers).
    pub fn filter(&mut self, f_des: Vec3, x: Vec3, v: Vec3) -> FilterOutput {
        let p = &self.params;
        let (dt, delta) = (p.dt_s, p.rate_n_per_tick);
        let x_ok = x.iter().chain(v.iter()).all(|c| c.is_finite());
        let fresh = x_ok && !std::mem::take(&mut self.skip);
        let withhold = std::mem::take(&mut self.withhold);
        // The force the device held over the interval that just ended:
        // F_prev, and the one before it for the first `hold_delay_ticks`.
        let phi = p.hold_delay_ticks;
        let held = self.f_prev2 * phi + self.f_prev * (1.0 - phi);
        self.f_prev2 = self.f_prev;
        // Energy observer for that interval.
        if fresh && self.have_prev {
            let dx = x - self.x_prev;
            let mut delivered = held.dot(&dx);
            let mut credit = p.damping_credit_ns_per_m * dx.norm_squared() / dt;
            if delivered > 0.0 {
                self.stats.delivered_j += delivered;
            } else {
                self.stats.absorbed_j -= delivered;
            }
            if withhold {
                self.stats.uncredited_j -= delivered.min(0.0);
                delivered = delivered.max(0.0);
                credit = 0.0;
            }
            self.stats.credit_j += credit;
            let e = self.tank - delivered + credit;
            if e > p.tank_max_j {
                self.stats.spilled_j += e - p.tank_max_j;
            }
            self.tank = e.min(p.tank_max_j);
            self.stats.tank_low_j = self.stats.tank_low_j.min(self.tank);
        } else if !fresh || self.gap {
            // Unobserved (see `skip_sample`): charge the prediction.
            let f = held;
            let est = super::predicted_work(f, self.v_last, p.stylus_mass_kg, dt).max(0.0);
            self.stats.unobserved_j += est;
            self.tank -= est;
            self.stats.tank_low_j = self.stats.tank_low_j.min(self.tank);
        }
        self.gap = !fresh;
        self.have_prev = fresh;
        if fresh {
            self.x_prev = x;
            self.v_last = v;
        }
        // The thermal state sees the force held during the last interval.
        self.theta += (dt / p.thermal_tau_s).min(1.0) * (self.f_prev.norm_squared() - self.theta);
        let bound = self.bound_n();

        if !x_ok || !f_des.iter().all(|c| c.is_finite()) {
            self.stats.fallbacks_nonfinite += 1;
            self.f_prev = Vec3::zeros();
            return FilterOutput {
                force: Vec3::zeros(),
                active: Active::default(),
                iterations: 0,
                status: QpStatus::NotRun,
                fallback: Some(Fallback::NonFinite),
                rate_excess_n: 0.0,
                bound_n: bound,
                tank_j: self.tank,
            };
        }

        // The energy ball (module doc).
        let budget = (self.tank - p.tank_min_j).max(0.0);
        let ball = EnergyBall::new(v, budget, p.stylus_mass_kg, dt, bound);

        // F_des inside every row is the answer: no solve (exact, and it
        // spares the solver the most common case, free motion).
        let interior = f_des.norm() <= bound && ball.contains(&f_des, 0.0) && (f_des - self.f_prev).norm() <= delta;
        let ans = if interior {
            self.stats.interior += 1;
            QpAnswer {
                f: f_des,
                status: QpStatus::Interior,
                iterations: 0,
            }
        } else if let Some(f) = self.exact(f_des, bound, ball) {
            self.stats.exact += 1;
            QpAnswer {
                f,
                status: QpStatus::Exact,
                iterations: 0,
            }
        } else {
            self.last_guess = None;
            self.solve(f_des, self.f_prev, bound, ball)
        };
        let ok = matches!(
            ans.status,
            QpStatus::Solved | QpStatus::AlmostSolved | QpStatus::Interior | QpStatus::Exact
        ) && ans.f.iter().all(|c| c.is_finite());
        let (mut f, fallback) = if ok {
            (ans.f, None)
        } else {
            self.stats.fallbacks_solver += 1;
            self.stats.status_max_iter += (ans.status == QpStatus::MaxIterations) as u64;
            self.stats.status_failed += (ans.status == QpStatus::Failed) as u64;
            let n = self.f_prev.norm();
            let ramp = if n > 0.0 { (1.0 - delta / n).max(0.0) } else { 0.0 };
            (self.f_prev * ramp, Some(Fallback::Solver))
        };
        // Hard rows exactly, not to the solver's tolerance.
        let mut alpha: f64 = 1.0;
        let n = f.norm();
        if n > bound {
            alpha = bound / n;
        }
        alpha *= ball.scale_into(&(f * alpha));
        f *= alpha.clamp(0.0, 1.0);

        let tol = 1e-6 * bound.max(1.0);
        let change = (f - self.f_prev).norm();
        let active = Active {
            norm: f.norm() >= bound - tol,
            rate: change >= delta - tol,
            energy: !ball.slack && (f - ball.c).norm() >= ball.r - tol,
        };
        let excess = (change - delta).max(0.0);
        if ans.status == QpStatus::Interior {
            self.last_guess = None;
        }
        self.stats.solves += (ans.status != QpStatus::Interior) as u64;
        self.stats.active_norm += active.norm as u64;
        self.stats.active_rate += active.rate as u64;
        self.stats.rate_exceeded += (excess > tol) as u64;
        self.stats.active_energy += active.energy as u64;
        if !matches!(ans.status, QpStatus::Interior | QpStatus::Exact) {
            self.stats.iter_hist[(ans.iterations as usize).min(ITER_HIST_LEN - 1)] += 1;
        }
        self.f_prev = f;
        FilterOutput {
            force: f,
            active,
            iterations: ans.iterations,
            status: ans.status,
            fallback,
            rate_excess_n: excess,
            bound_n: bound,
            tank_j: self.tank,
        }
    }

    /// The QP solved exactly on its active sets, the last tick's first
    /// (`polish::exact`): the optimum with a KKT certificate, or None (the
    /// interior-point solver then runs). Remembers the set that was
    /// certified.
    fn exact(&mut self, f_des: Vec3, bound: f64, ball: EnergyBall) -> Option<Vec3> {
        #[cfg(test)]
        if self.inject_failure {
            return None;
        }
        let rows = Rows {
            f_des,
            f_prev: self.f_prev,
            bound,
            delta: self.params.rate_n_per_tick,
            w: self.params.rate_slack_weight_n,
            ball,
        };
        let (f, guess) = exact(&rows, self.last_guess)?;
        self.last_guess = Some(guess);
        Some(f)
    }

    /// Updates q and b in place and solves `min ‖F − f_des‖² + w s` s.t.
    /// `‖F‖ ≤ bound`, `‖F − f_prev‖ ≤ Δ + s`, `s ≥ 0`, `‖F − c‖ ≤ r`.
    fn solve(&mut self, f_des: Vec3, f_prev: Vec3, bound: f64, ball: EnergyBall) -> QpAnswer {
        for j in 0..3 {
            self.q[j] = -2.0 * f_des[j];
            self.b[ROW_NORM + 1 + j] = 0.0;
            self.b[ROW_RATE + 1 + j] = -f_prev[j];
            self.b[ROW_ENERGY + 1 + j] = -ball.c[j];
        }
        self.q[3] = self.params.rate_slack_weight_n;
        self.b[0] = 0.0;
        self.b[ROW_ENERGY] = ball.r;
        self.b[ROW_NORM] = bound;
        self.b[ROW_RATE] = self.params.rate_n_per_tick;
        // The updates only fail on a dimension mismatch or a presolved
        // problem, both excluded at construction.
        let upd = self
            .solver
            .update_q(&self.q)
            .and_then(|_| self.solver.update_b(&self.b));
        if upd.is_err() {
            return QpAnswer {
                f: Vec3::zeros(),
                status: QpStatus::Failed,
                iterations: 0,
            };
        }
        self.solver.solve();
        #[cfg(test)]
        if self.inject_failure {
            return QpAnswer {
                f: Vec3::repeat(f64::NAN),
                status: QpStatus::Failed,
                iterations: 0,
            };
        }
        let sol = &self.solver.solution;
        let status = match sol.status {
            SolverStatus::Solved => QpStatus::Solved,
            SolverStatus::AlmostSolved => QpStatus::AlmostSolved,
            SolverStatus::MaxIterations => QpStatus::MaxIterations,
            _ => QpStatus::Failed,
        };
        let mut f = Vec3::new(sol.x[0], sol.x[1], sol.x[2]);
        let mut status = status;
        if matches!(
            status,
            QpStatus::Solved | QpStatus::AlmostSolved | QpStatus::MaxIterations
        ) {
            let z = &sol.z;
            let scale = bound.max(1.0);
            let act = |zi: f64| zi > 1e-7 * scale;
            let delta = self.params.rate_n_per_tick;
            let s_val = sol.x[3];
            let dual_norm = z[ROW_NORM];
            let dual_rate = z[ROW_RATE];
            let dual_energy = z[ROW_ENERGY];
            let set = PolishSet {
                norm: act(dual_norm).then_some(dual_norm / bound),
                rate: (s_val <= 1e-9 * scale && act(dual_rate)).then_some(dual_rate / delta),
                energy: act(dual_energy).then_some(dual_energy / ball.r),
                slack: s_val > 1e-9 * scale,
            };
            if let Some(fp) = polish_any(
                f,
                f_des,
                f_prev,
                bound,
                delta,
                self.params.rate_slack_weight_n,
                ball,
                set,
            ) {
                f = fp;
                self.stats.polished += 1;
                if status == QpStatus::MaxIterations {
                    // The polish verified optimality (feasible KKT point of
                    // a convex problem): a certificate, so the answer stands.
                    self.stats.recovered += 1;
                    status = QpStatus::AlmostSolved;
                }
            }
        }
        QpAnswer {
            f,
            status,
            iterations: sol.iterations,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn params() -> PassivityParams {
        PassivityParams {
            norm_bound: NormBound::Peak,
            tol_gap_abs: 1e-10,
            tol_gap_rel: 1e-10,
            tol_feas: 1e-10,
            max_iter: 50,
            ..PassivityParams::default()
        }
    }

    // ---- An independent solver: exact projection by enumerating the faces
    // of {‖F‖ ≤ R} ∩ {‖F − P‖ ≤ r} ∩ {‖F − c‖ ≤ ρ}, and a golden-section
    // search over the slack s on the convex function φ(s) + w s. ----

    struct Sets {
        r1: f64,
        p: Vec3,
        r2: f64, // < 0: no rate ball
        c: Vec3,
        r3: f64,
    }

    impl Sets {
        fn feasible(&self, x: &Vec3) -> bool {
            let t = 1e-9;
            x.norm() <= self.r1 + t
                && (self.r2 < 0.0 || (x - self.p).norm() <= self.r2 + t)
                && (x - self.c).norm() <= self.r3 + t
        }
    }

    /// Critical points of the distance from y on the circle (c, n, rho).
    fn circle_points(y: &Vec3, c: Vec3, n: Vec3, rho: f64, out: &mut Vec<Vec3>) {
        let yp = y - n * (y - c).dot(&n);
        let d = yp - c;
        if d.norm() > 1e-14 {
            let u = d.normalize();
            out.push(c + u * rho);
            out.push(c - u * rho);
        }
    }

    fn basis(n: Vec3) -> (Vec3, Vec3) {
        let a = if n.x.abs() < 0.9 { Vec3::x() } else { Vec3::y() };
        let u = n.cross(&a).normalize();
        (u, n.cross(&u))
    }

    /// Circle where two spheres meet.
    fn sphere_sphere(c1: Vec3, r1: f64, c2: Vec3, r2: f64) -> Option<(Vec3, Vec3, f64)> {
        let d = (c2 - c1).norm();
        if d < 1e-14 || d > r1 + r2 || d < (r1 - r2).abs() {
            return None;
        }
        let n = (c2 - c1) / d;
        let a = (r1 * r1 - r2 * r2 + d * d) / (2.0 * d);
        Some((c1 + n * a, n, (r1 * r1 - a * a).max(0.0).sqrt()))
    }

    fn project(y: Vec3, s: &Sets) -> Option<Vec3> {
        let mut cand = vec![y];
        let has2 = s.r2 >= 0.0;
        let radial = |c: Vec3, r: f64, cand: &mut Vec<Vec3>| {
            if (y - c).norm() > 0.0 {
                cand.push(c + (y - c) * (r / (y - c).norm()));
            }
        };
        radial(Vec3::zeros(), s.r1, &mut cand);
        if has2 {
            radial(s.p, s.r2, &mut cand);
        }
        radial(s.c, s.r3, &mut cand);
        let mut circles = vec![];
        if has2 {
            circles.extend(sphere_sphere(Vec3::zeros(), s.r1, s.p, s.r2));
            circles.extend(sphere_sphere(s.p, s.r2, s.c, s.r3));
        }
        circles.extend(sphere_sphere(Vec3::zeros(), s.r1, s.c, s.r3));
        for &(c, n, rho) in &circles {
            circle_points(&y, c, n, rho, &mut cand);
        }
        // Triple points: the first two spheres' circle cut by the plane the
        // first and third spheres meet on, 2c·x = |c|² + r1² − r3².
        let cn = s.c.norm();
        if has2 && cn > 1e-14 {
            if let Some((c, n, rho)) = sphere_sphere(Vec3::zeros(), s.r1, s.p, s.r2) {
                let g = s.c / cn;
                let h = (cn * cn + s.r1 * s.r1 - s.r3 * s.r3) / (2.0 * cn);
                let (u, w) = basis(n);
                let (a, b) = (rho * g.dot(&u), rho * g.dot(&w));
                let rhs = h - g.dot(&c);
                let m = (a * a + b * b).sqrt();
                if m > 1e-14 && rhs.abs() <= m {
                    let phi = b.atan2(a);
                    let dphi = (rhs / m).acos();
                    for t in [phi + dphi, phi - dphi] {
                        cand.push(c + (u * t.cos() + w * t.sin()) * rho);
                    }
                }
            }
        }
        cand.into_iter()
            .filter(|c| s.feasible(c))
            .min_by(|a, b| (a - y).norm().total_cmp(&(b - y).norm()))
    }

    /// The reference answer of the QP.
    fn reference(f_des: Vec3, f_prev: Vec3, bound: f64, delta: f64, w: f64, ball: EnergyBall) -> Vec3 {
        let no_rate = Sets {
            r1: bound,
            p: f_prev,
            r2: -1.0,
            c: ball.c,
            r3: ball.r,
        };
        let pk_prev = project(f_prev, &no_rate).expect("K is never empty");
        let pk_des = project(f_des, &no_rate).expect("K is never empty");
        let s_lo = ((pk_prev - f_prev).norm() - delta).max(0.0);
        let s_hi = ((pk_des - f_prev).norm() - delta).max(s_lo);
        let at = |s: f64| {
            let sets = Sets {
                r1: bound,
                p: f_prev,
                r2: delta + s,
                c: ball.c,
                r3: ball.r,
            };
            project(f_des, &sets).map(|f| (f, (f - f_des).norm_squared() + w * s))
        };
        if s_hi - s_lo < 1e-15 {
            return at(s_hi).expect("feasible at s_hi").0;
        }
        let (mut a, mut b) = (s_lo, s_hi);
        let r = (5f64.sqrt() - 1.0) / 2.0;
        let val = |s: f64| at(s).map(|x| x.1).unwrap_or(f64::INFINITY);
        for _ in 0..300 {
            let (c, d) = (b - r * (b - a), a + r * (b - a));
            if val(c) <= val(d) {
                b = d;
            } else {
                a = c;
            }
        }
        let s = 0.5 * (a + b);
        // The ends are candidates too (the minimum may sit on one).
        [s, s_lo, s_hi]
            .iter()
            .filter_map(|&s| at(s))
            .min_by(|x, y| x.1.total_cmp(&y.1))
            .expect("feasible")
            .0
    }

    fn unit(a: f64, b: f64) -> Vec3 {
        // a ∈ [-1, 1] (cos polar), b ∈ [0, 2π)
        let sa = (1.0 - a * a).max(0.0).sqrt();
        Vec3::new(sa * b.cos(), sa * b.sin(), a)
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(300))]
        #[test]
        fn qp_matches_an_independent_solver(
            fd in prop::array::uniform3(-15.0f64..15.0),
            pa in -1.0f64..1.0, pb in 0.0f64..std::f64::consts::TAU, pr in 0.0f64..1.0,
            ca in -1.0f64..1.0, cb in 0.0f64..std::f64::consts::TAU,
            cr in prop::sample::select(vec![0.0, 0.5, 3.0, 20.0, 60.0]),
            gap in prop::sample::select(vec![RHO_FLOOR_N, 0.01, 0.3, 2.0, 8.0]),
            bound in 1.0f64..7.9,
            delta in 0.05f64..2.0,
            w in prop::sample::select(vec![50.0, 1e3]),
        ) {
            let mut flt = PassivityFilter::new(&PassivityParams { rate_n_per_tick: delta, rate_slack_weight_n: w, ..params() }).unwrap();
            let f_des = Vec3::from(fd);
            let f_prev = unit(pa, pb) * (pr * bound);
            let ball = EnergyBall { c: unit(ca, cb) * cr, r: cr + gap, slack: false };
            let ans = flt.solve(f_des, f_prev, bound, ball);
            prop_assert!(matches!(ans.status, QpStatus::Solved | QpStatus::AlmostSolved), "{:?}", ans.status);
            let r = reference(f_des, f_prev, bound, delta, w, ball);
            prop_assert!((ans.f - r).norm() < 1e-6, "qp {:?} ref {:?} diff {:e}", ans.f, r, (ans.f - r).norm());
            // The exact active-set step, whenever it answers, from any first
            // guess, gives the same optimum.
            let rows = Rows { f_des, f_prev, bound, delta, w, ball };
            for first in [None, Some(Guess { mask: 7, slack: false }), Some(Guess { mask: 0, slack: true })] {
                if let Some((f, _)) = exact(&rows, first) {
                    prop_assert!((f - r).norm() < 1e-6, "exact {:?} ref {:?} diff {:e}", f, r, (f - r).norm());
                }
            }
        }

        #[test]
        fn always_feasible_and_hard_rows_hold(
            fd in prop::array::uniform3(-50.0f64..50.0),
            xs in prop::collection::vec(prop::array::uniform3(-1.0f64..1.0), 1..40),
            tank in 0.0f64..0.05,
        ) {
            let d = PassivityParams::default();
            let p = PassivityParams { tank_initial_j: tank.max(d.tank_min_j), ..d };
            let mut flt = PassivityFilter::new(&p).unwrap();
            let mut x = Vec3::zeros();
            for (k, v) in xs.iter().enumerate() {
                let v = Vec3::from(*v);
                let f_des = Vec3::from(fd) * ((k % 3) as f64 - 1.0);
                x += v * p.dt_s;
                let out = flt.filter(f_des, x, v);
                prop_assert!(out.fallback.is_none(), "{:?}", out);
                prop_assert!(out.force.norm() <= out.bound_n * (1.0 + 1e-12));
                // The work the force does over the next tick on the
                // stylus mass moving at v: within the tank's budget.
                let budget = (out.tank_j - p.tank_min_j).max(0.0);
                let t = p.dt_s;
                let work = crate::haptics::passivity::predicted_work(out.force, v, p.stylus_mass_kg, t);
                prop_assert!(work <= budget + 1e-11, "work {work} budget {budget} {:?}", out);
            }
        }
    }

    #[test]
    fn the_exact_step_answers_the_common_cases_without_the_solver() {
        // Over the norm, over the rate, into an empty tank's ball, and all
        // three: each is answered exactly, with the last tick's set first.
        let mut flt = PassivityFilter::new(&params()).unwrap();
        let cases = [
            (Vec3::new(0.0, 0.0, 0.5), Vec3::new(0.0, 0.0, 9.0), Vec3::zeros()),
            (Vec3::new(0.0, 0.0, 0.5), Vec3::new(0.0, 3.0, 0.5), Vec3::zeros()),
            (
                Vec3::new(1.0, 0.0, 0.0),
                Vec3::new(1.5, 0.0, 0.0),
                Vec3::new(0.05, 0.0, 0.0),
            ),
        ];
        let mut answered = 0;
        let mut total = 0;
        for (f_prev, f_des, v) in cases {
            for budget in [1.0, 1e-6] {
                let bound = flt.bound_n();
                let ball = EnergyBall::new(v, budget, flt.params.stylus_mass_kg, flt.params.dt_s, bound);
                flt.f_prev = f_prev;
                let rows = Rows {
                    f_des,
                    f_prev,
                    bound,
                    delta: flt.params.rate_n_per_tick,
                    w: flt.params.rate_slack_weight_n,
                    ball,
                };
                let interior =
                    f_des.norm() <= bound && ball.contains(&f_des, 0.0) && (f_des - f_prev).norm() <= rows.delta;
                if interior {
                    continue;
                }
                total += 1;
                let r = reference(f_des, f_prev, bound, rows.delta, rows.w, ball);
                if let Some(f) = flt.exact(f_des, bound, ball) {
                    answered += 1;
                    assert!((f - r).norm() < 1e-9, "{f:?} vs {r:?}");
                    // The set it found comes first next time, and holds.
                    assert!(flt.last_guess.is_some());
                    assert_eq!(flt.exact(f_des, bound, ball), Some(f));
                }
            }
        }
        assert!(total >= 4);
        assert_eq!(answered, total, "every common case answered exactly");
    }

    #[test]
    fn inside_all_bounds_returns_f_des() {
        let mut flt = PassivityFilter::new(&params()).unwrap();
        let f_des = Vec3::new(0.3, -0.2, 0.4);
        let out = flt.filter(f_des, Vec3::zeros(), Vec3::zeros());
        assert!((out.force - f_des).norm() < 1e-7, "{out:?}");
        assert_eq!(out.active, Active::default());
        assert_eq!(out.fallback, None);
    }

    #[test]
    fn over_the_norm_scales_to_the_bound() {
        let p = PassivityParams {
            rate_n_per_tick: 100.0,
            ..params()
        };
        let mut flt = PassivityFilter::new(&p).unwrap();
        let f_des = Vec3::new(10.0, -20.0, 5.0);
        let out = flt.filter(f_des, Vec3::zeros(), Vec3::zeros());
        let want = f_des * (7.9 / f_des.norm());
        assert!((out.force - want).norm() < 1e-6, "{out:?}");
        assert!(out.active.norm && !out.active.energy && !out.active.rate);
    }

    #[test]
    fn rate_bound_limits_a_step() {
        let mut flt = PassivityFilter::new(&params()).unwrap();
        let out = flt.filter(Vec3::new(0.0, 0.0, 5.0), Vec3::zeros(), Vec3::zeros());
        assert!((out.force - Vec3::new(0.0, 0.0, 1.0)).norm() < 1e-6, "{out:?}");
        assert!(out.active.rate && out.rate_excess_n < 1e-6);
    }

    #[test]
    fn empty_tank_stops_output_along_the_motion() {
        let p = PassivityParams {
            tank_initial_j: 1e-3,
            tank_min_j: 1e-3,
            ..params()
        };
        let mut flt = PassivityFilter::new(&p).unwrap();
        let v = Vec3::new(0.0, 0.0, 0.1);
        // Pushing along the motion: nothing may be delivered.
        let out = flt.filter(Vec3::new(0.0, 0.0, 0.5), Vec3::zeros(), v);
        assert!(out.force.norm() < 1e-6, "{out:?}");
        assert!(out.active.energy);
        // Across the motion a force still moves the stylus along itself
        // (T²‖F‖²/2m): with nothing in the tank it must lean against the
        // motion. The answer is the closest point of the energy ball,
        // centred at −(m/T) v through the origin.
        let f_des = Vec3::new(0.5, 0.0, 0.0);
        let out = flt.filter(f_des, v * p.dt_s, v);
        let k = p.stylus_mass_kg / p.dt_s;
        let c = -v * k;
        let want = c + (f_des - c) * ((c.norm() + RHO_FLOOR_N) / (f_des - c).norm());
        assert!((out.force - want).norm() < 1e-6, "{out:?} vs {want:?}");
        assert!(out.force.x > 0.1 && out.force.z < 0.0 && out.active.energy, "{out:?}");
        // Opposing the motion (absorbing) is allowed up to the force that
        // would stop the stylus within the tick and send it back (2 m v / T).
        let mut flt = PassivityFilter::new(&p).unwrap();
        let out = flt.filter(Vec3::new(0.0, 0.0, -0.5), Vec3::zeros(), v);
        assert!((out.force - Vec3::new(0.0, 0.0, -0.5)).norm() < 1e-6, "{out:?}");
        assert!(!out.active.energy);
        let mut flt = PassivityFilter::new(&p).unwrap();
        let out = flt.filter(Vec3::new(0.0, 0.0, -20.0), Vec3::zeros(), v);
        assert!(out.force.norm() <= 2.0 * k * v.norm() + 1e-6, "{out:?}");
    }

    #[test]
    fn a_full_tank_leaves_the_force_alone_and_an_empty_one_at_rest_gives_none() {
        let mut flt = PassivityFilter::new(&params()).unwrap();
        // 7 mJ above the reserve: the ball holds every force within 7.9 N.
        let ball = EnergyBall::new(Vec3::new(0.3, 0.0, 0.0), 7e-3, 0.045, 1e-3, 7.9);
        assert!(ball.slack, "{ball:?}");
        let out = flt.filter(Vec3::new(3.0, 0.0, 0.0), Vec3::zeros(), Vec3::zeros());
        assert!((out.force.x - 1.0).abs() < 1e-6 && !out.active.energy, "{out:?}");
        // Nothing above the reserve, stylus at rest: no force at all.
        let p = PassivityParams {
            tank_initial_j: 1e-3,
            tank_min_j: 1e-3,
            ..params()
        };
        let mut flt = PassivityFilter::new(&p).unwrap();
        let out = flt.filter(Vec3::new(0.5, 0.0, 0.0), Vec3::zeros(), Vec3::zeros());
        assert!(out.force.norm() < 1e-6, "{out:?}");
        // The ball scales a force into itself along the ray from 0.
        let ball = EnergyBall::new(Vec3::new(0.0, 0.0, 0.1), 1e-6, 0.045, 1e-3, 7.9);
        let f = Vec3::new(2.0, 0.0, 1.0);
        let a = ball.scale_into(&f);
        assert!(
            a > 0.0 && a < 1.0 && ((f * a - ball.c).norm() - ball.r).abs() < 1e-9,
            "{a}"
        );
    }

    #[test]
    fn a_reset_keeps_the_tank_level() {
        let p = PassivityParams {
            tank_max_j: 10.0,
            ..params()
        };
        let mut flt = PassivityFilter::new(&p).unwrap();
        // The hand pulls against the force: the tank fills.
        let mut x = Vec3::zeros();
        for _ in 0..200 {
            let v = Vec3::new(-0.1, 0.0, 0.0);
            x += v * p.dt_s;
            flt.filter(Vec3::new(1.0, 0.0, 0.0), x, v);
        }
        let full = flt.tank_j();
        assert!(full > p.tank_initial_j, "{full}");
        flt.reset();
        assert_eq!(flt.tank_j(), full);
        assert_eq!(flt.last_force(), Vec3::zeros());
    }

    #[test]
    fn tank_accounts_exactly() {
        let p = PassivityParams {
            damping_credit_ns_per_m: 0.5,
            tank_max_j: 10.0,
            ..params()
        };
        let mut flt = PassivityFilter::new(&p).unwrap();
        let mut x = Vec3::zeros();
        let mut rng = 1u64;
        let mut next = || {
            rng = rng.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (rng >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        for k in 0..500 {
            let v = Vec3::new(next(), next(), next()) * 0.2;
            x += v * p.dt_s;
            // Now and then a sample that is not fresh: charged, not observed.
            if k % 7 == 3 {
                flt.skip_sample();
            }
            // And now and then an interval too long to credit.
            if k % 11 == 5 {
                flt.withhold_credit();
            }
            flt.filter(Vec3::new(next(), next(), next()) * 4.0, x, v);
        }
        let s = flt.stats();
        assert!(s.unobserved_j > 0.0 && s.uncredited_j > 0.0);
        let want = p.tank_initial_j - s.delivered_j + s.absorbed_j + s.credit_j
            - s.spilled_j
            - s.unobserved_j
            - s.uncredited_j;
        assert!((flt.tank_j() - want).abs() < 1e-12, "{} vs {want}", flt.tank_j());
        assert!(s.delivered_j > 0.0 && s.absorbed_j > 0.0 && s.credit_j > 0.0);
        assert_eq!(s.fallbacks(), 0);
        // Every solve is counted once: answered exactly on its active set
        // (no interior-point iterations), or by the solver, in the
        // iteration histogram.
        assert!(s.exact > 0);
        assert_eq!(s.iter_hist.iter().sum::<u64>() + s.exact, s.solves);
        assert!(s.iter_p99() >= s.iter_quantile(0.5));
    }

    /// Over an interval the device may not have held the force through (a
    /// stalled host), the hand's pull against the force is no credit, and
    /// the work the force delivered is still charged.
    #[test]
    fn a_withheld_interval_charges_but_never_credits() {
        let p = PassivityParams {
            tank_initial_j: 0.02,
            tank_max_j: 0.05,
            damping_credit_ns_per_m: 0.01,
            ..params()
        };
        let f = Vec3::new(1.0, 0.0, 0.0);
        let run = |withhold: bool, dx: f64| {
            let mut flt = PassivityFilter::new(&p).unwrap();
            flt.filter(f, Vec3::zeros(), Vec3::zeros());
            flt.set_commanded(f);
            if withhold {
                flt.withhold_credit();
            }
            // The hand moved the stylus by dx along x over the interval.
            flt.filter(f, Vec3::new(dx, 0.0, 0.0), Vec3::zeros());
            (flt.tank_j(), flt.stats().uncredited_j, flt.stats().credit_j)
        };
        // Pulled 10 mm against 1 N: 10 mJ (and the damping credit) into the tank...
        let (credited, none, credit) = run(false, -0.01);
        assert!((credited - (0.02 + 0.01 + credit)).abs() < 1e-12 && credit > 0.0);
        assert_eq!(none, 0.0);
        // ...but nothing over a withheld interval, counted as uncredited.
        let (held, uncredited, no_credit) = run(true, -0.01);
        assert_eq!(held, 0.02);
        assert!((uncredited - 0.01).abs() < 1e-12);
        assert_eq!(no_credit, 0.0);
        // Pushed 10 mm along 1 N: charged either way.
        let (along, _, c) = run(false, 0.01);
        assert!((run(true, 0.01).0 - (along - c)).abs() < 1e-12);
        assert!((run(true, 0.01).0 - 0.01).abs() < 1e-12);
        // The flag is for one interval only.
        let mut flt = PassivityFilter::new(&p).unwrap();
        flt.filter(f, Vec3::zeros(), Vec3::zeros());
        flt.set_commanded(f);
        flt.withhold_credit();
        flt.filter(f, Vec3::zeros(), Vec3::zeros());
        flt.set_commanded(f);
        let t = flt.tank_j();
        flt.filter(f, Vec3::new(-0.01, 0.0, 0.0), Vec3::zeros());
        assert!(flt.tank_j() > t + 0.0099);
    }

    /// A skipped sample charges the interval before it and the one after
    /// with what the held force delivers at the last fresh velocity, and
    /// the jump to the skipped pose and back is not counted.
    #[test]
    fn skipped_samples_charge_the_held_force_at_the_last_velocity() {
        let p = PassivityParams {
            tank_initial_j: 0.04,
            tank_max_j: 0.05,
            damping_credit_ns_per_m: 0.0,
            ..params()
        };
        let dt = p.dt_s;
        let mut flt = PassivityFilter::new(&p).unwrap();
        let v = Vec3::new(0.1, 0.0, 0.0);
        let f = Vec3::new(1.0, 0.0, 0.0);
        let mut x = Vec3::zeros();
        flt.filter(f, x, v);
        flt.set_commanded(f);
        x += v * dt;
        let t0 = flt.tank_j();
        // A wild pose 1 m away, not fresh.
        flt.skip_sample();
        flt.filter(f, x + Vec3::new(1.0, 0.0, 0.0), v);
        flt.set_commanded(f);
        let per = crate::haptics::passivity::predicted_work(f, v, p.stylus_mass_kg, dt);
        assert!(
            (t0 - per - flt.tank_j()).abs() < 1e-15,
            "{} vs {}",
            t0 - per,
            flt.tank_j()
        );
        x += v * dt;
        // Back to a fresh sample: the interval from the skipped one is charged too.
        flt.filter(f, x, v);
        assert!((t0 - 2.0 * per - flt.tank_j()).abs() < 1e-15);
        let s = flt.stats();
        assert!((s.unobserved_j - 2.0 * per).abs() < 1e-15);
        assert_eq!(s.delivered_j, 0.0, "the jump was not counted");
        // Moving away from the force: nothing charged, nothing credited.
        flt.set_commanded(-f);
        let t1 = flt.tank_j();
        flt.skip_sample();
        flt.filter(f, x, v);
        assert_eq!(flt.tank_j(), t1);
    }

    /// With the force landing half a tick after its pose, the observer
    /// counts half of each interval at the force before.
    #[test]
    fn a_delayed_hold_counts_the_force_before_for_its_share() {
        let p = PassivityParams {
            hold_delay_ticks: 0.5,
            damping_credit_ns_per_m: 0.0,
            ..params()
        };
        let mut flt = PassivityFilter::new(&p).unwrap();
        let dx = Vec3::new(1e-4, 0.0, 0.0);
        let (f1, f2) = (Vec3::new(1.0, 0.0, 0.0), Vec3::new(0.2, 0.0, 0.0));
        flt.filter(f1, Vec3::zeros(), Vec3::zeros());
        flt.set_commanded(f1);
        flt.filter(f2, dx, Vec3::zeros());
        flt.set_commanded(f2);
        // First interval: half nothing (before the first force), half f1.
        assert!((flt.stats().delivered_j - 0.5 * f1.dot(&dx)).abs() < 1e-15);
        flt.filter(f2, dx * 2.0, Vec3::zeros());
        // Second: half f1, half f2.
        let want = 0.5 * f1.dot(&dx) + 0.5 * (f1 + f2).dot(&dx);
        assert!(
            (flt.stats().delivered_j - want).abs() < 1e-15,
            "{} vs {want}",
            flt.stats().delivered_j
        );
        let bad = PassivityParams {
            hold_delay_ticks: 1.5,
            ..params()
        };
        assert!(PassivityFilter::new(&bad).is_err());
    }

    #[test]
    fn non_finite_input_gives_zero_and_is_counted() {
        let mut flt = PassivityFilter::new(&params()).unwrap();
        flt.filter(Vec3::new(0.5, 0.0, 0.0), Vec3::zeros(), Vec3::zeros());
        let out = flt.filter(Vec3::new(f64::NAN, 0.0, 0.0), Vec3::zeros(), Vec3::zeros());
        assert_eq!(out.force, Vec3::zeros());
        assert_eq!(out.fallback, Some(Fallback::NonFinite));
        let out = flt.filter(
            Vec3::new(0.5, 0.0, 0.0),
            Vec3::new(f64::INFINITY, 0.0, 0.0),
            Vec3::zeros(),
        );
        assert_eq!(out.force, Vec3::zeros());
        assert_eq!(flt.stats().fallbacks_nonfinite, 2);
        assert!(flt.tank_j().is_finite());
        let out = flt.filter(Vec3::new(0.5, 0.0, 0.0), Vec3::zeros(), Vec3::zeros());
        assert!(out.fallback.is_none() && (out.force.x - 0.5).abs() < 1e-6);
    }

    #[test]
    fn solver_failure_ramps_down_within_the_hard_rows() {
        let mut flt = PassivityFilter::new(&params()).unwrap();
        flt.inject_failure = true;
        flt.f_prev = Vec3::new(3.0, 0.0, 0.0);
        let out = flt.filter(Vec3::new(5.0, 0.0, 0.0), Vec3::zeros(), Vec3::zeros());
        assert_eq!(out.fallback, Some(Fallback::Solver));
        assert!((out.force - Vec3::new(2.0, 0.0, 0.0)).norm() < 1e-12, "{out:?}");
        let out = flt.filter(Vec3::new(5.0, 0.0, 0.0), Vec3::zeros(), Vec3::zeros());
        assert!((out.force - Vec3::new(1.0, 0.0, 0.0)).norm() < 1e-12, "{out:?}");
        assert_eq!(flt.stats().fallbacks_solver, 2);
    }

    #[test]
    fn thermal_bound_slides_to_continuous() {
        let p = PassivityParams {
            norm_bound: NormBound::Thermal,
            thermal_tau_s: 0.05,
            ..params()
        };
        let mut flt = PassivityFilter::new(&p).unwrap();
        let mut last = f64::INFINITY;
        let mut out = flt.filter(Vec3::new(20.0, 0.0, 0.0), Vec3::zeros(), Vec3::zeros());
        assert!((out.bound_n - 7.9).abs() < 1e-12);
        for _ in 0..2000 {
            out = flt.filter(Vec3::new(20.0, 0.0, 0.0), Vec3::zeros(), Vec3::zeros());
            assert!(out.bound_n <= last + 1e-9);
            last = out.bound_n;
        }
        assert!((out.bound_n - 1.75).abs() < 1e-3, "{out:?}");
        assert!((out.force.norm() - out.bound_n).abs() < 1e-6);
    }

    #[test]
    fn bad_params_name_the_key() {
        let c = Checker::new(Path::new("rt-config/service.toml"));
        let p = PassivityParams {
            continuous_force_n: 9.0,
            ..PassivityParams::default()
        };
        let e = p.validate(&c, "passivity").unwrap_err();
        assert_eq!(e.key, "passivity.continuous_force_n");
        assert!(e.to_string().contains("rt-config/service.toml"), "{e}");
        assert!(PassivityFilter::new(&p).is_err());
        let e = crate::config::parse_toml::<PassivityParams>("dt_s = 0.001\nbogus = 1", Path::new("x.toml"));
        assert!(e.is_err());
        let text = toml::to_string(&PassivityParams::default()).unwrap();
        let back: PassivityParams = crate::config::parse_toml(&text, Path::new("x.toml")).unwrap();
        assert_eq!(back, PassivityParams::default());
        back.validate(&c, "passivity").unwrap();
    }
}
