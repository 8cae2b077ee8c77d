//! The passivity filter: each tick a small second-order-cone QP (clarabel,
//! built once, re-solved with new data) finds the force closest to the
//! model's force that the device may output, and an energy observer/tank at
//! the device port keeps the output passive.
//!
//! # The QP
//!
//! Variables `x = [F; s]`: the force on the hand `F` (N, 3) and a rate slack
//! `s` (N).
//!
//! ```text
//! minimize    ‖F − F_des‖² + w s
//! subject to  ‖F‖ ≤ B                   norm bound (second-order cone, hard)
//!             ‖F − F_prev‖ ≤ Δ + s      rate bound (second-order cone, soft)
//!             s ≥ 0
//!             ‖F − c‖ ≤ ρ               energy bound (second-order cone, hard)
//! ```
//!
//! # The energy ball
//!
//! The force `F` is held for the coming tick. The port then delivers `F·Δx`,
//! and the stylus moves by `Δx ≈ T v + T² F/(2m)`: `v` the stylus velocity
//! predicted for the tick, `m` the lightest mass the force accelerates (the
//! device's apparent mass at the tip, `stylus_mass_kg`; the hand only adds
//! mass). So the energy row is
//!
//! ```text
//! T v·F + T² ‖F‖² / (2m) ≤ E − E_min
//! ⇔ ‖F + (m/T) v‖² ≤ (m/T)² ‖v‖² + 2 m (E − E_min) / T²
//! ```
//!
//! a ball with centre `c = −(m/T) v` and radius
//! `ρ = (m/T)·sqrt(‖v‖² + 2 (E − E_min)/m)`, through or around the origin
//! (`ρ ≥ ‖c‖`). A linear row `T v·F ≤ E − E_min` alone (the `m → ∞` limit,
//! this filter until 2026-11-27) lets any force across the motion through
//! with an empty tank; that force still pushes the light stylus along
//! itself, and the energy it delivers put the tank in debt tick after tick
//! (a guidewire's stiff, delayed hub force drove the soak's port to 0.19 J
//! over a 50 mJ tank; `tests/guidewire_closed_loop_is_passive.rs`). With
//! the ball an empty tank at rest allows no force; a stylus moving into
//! the force still gets up to `2 m ‖v‖ / T` against it (the force that
//! stops it within the tick), so pressing into a wall refills the tank.
//! While the tank holds more than `T² B²/(2m)` (0.7 mJ at 7.9 N and 45 g)
//! beyond what `v` needs, the ball contains the whole norm ball and the QP
//! gets a stand-in of radius `2B + 1` centred at 0, never binding. All the
//! per-tick data (bound, `F_prev`, the ball) is in the right-hand side `b`;
//! the matrix `A` never changes.
//!
//! The rate bound is the Euclidean norm of the change (rotation invariant: the
//! device frame has no meaning for the tissue). It is soft because together
//! with the energy row it can be infeasible (the tank empties while the force
//! pushes along the motion: the energy row then asks for a faster change than
//! Δ). The penalty `w s` is linear, an exact penalty: whenever the hard rows
//! leave room, and the rate row's multiplier (≈ 2‖F − F_des‖) is below `w`,
//! the rate bound holds exactly; otherwise it is exceeded by the least amount.
//!
//! **Always feasible** (and strictly, so the interior-point method is on safe
//! ground): `F = 0` satisfies the norm cone (`B > 0`) and the energy ball
//! (`ρ ≥ ‖c‖ + 1e-9 N`, a floor that lets the port deliver ~1e-12 J a
//! tick more); `s = ‖F_prev‖` satisfies the rate row; `F = ε c/‖c‖` (or
//! `F = 0` when `c = 0`), `s` large is a strictly interior point.
//!
//! # The norm bound `B`
//!
//! [`NormBound::Peak`] and [`NormBound::Continuous`] are constants;
//! [`NormBound::Thermal`] models the motors' heating: `θ`, a first-order
//! filter (time constant `thermal_tau_s`) of `|F|²`, and
//! `B² = peak² − (peak² − cont²)·min(θ/cont², 1)`. A cold device gets the
//! peak force; the sustained force converges to exactly the continuous rating
//! (the fixed point of `B² = θ` is `θ = cont²`). The bound moves smoothly (by
//! at most `T/τ` of the span per tick) instead of jumping from peak to
//! continuous, which the hard cone would pass straight to the hand.
//!
//! # The energy observer and tank
//!
//! At tick `k` the force `F_{k−1}` has been held during the last interval, so
//! the energy the port delivered is exactly `F_{k−1}·(x_k − x_{k−1})` (the
//! Hannaford–Ryu observer with the zero-order hold integrated exactly from the
//! measured positions, rather than `T v·F`). The tank gains what the hand puts
//! in (that quantity when negative), loses what the port delivers, and is
//! credited `b_dev |Δx|²/T`, a lower bound of the energy the device's own
//! damping `b_dev` dissipated in the interval (Cauchy–Schwarz:
//! `∫|v|² ≥ |Δx|²/T`; Kim–Ryu energy bounding). The tank is clamped at
//! `E_max` (energy above it is thrown away, which is conservative) but NOT at
//! `E_min`: the QP predicts with `v_k`, the hold delivers along the real
//! path, and clamping a small overshoot below `E_min` would forgive it. A
//! tank below `E_min` is a debt; the energy ball's budget is 0 until it is
//! repaid.
//!
//! An interval the observer cannot see — its start or end sample is a
//! pose the watchdog rejected, the same sample again (a silent device), or
//! none — is not measured: the jump to such a pose is no motion of the
//! port. It is charged instead with what the held force delivers at the
//! last measured velocity, `T v·F + T²‖F‖²/(2m)` when positive, never
//! credited (`unobserved`). Before 2026-11-27 these intervals were left
//! out: while the watchdog noticed a silent device and ramped the force
//! down, the force went on pushing the moving stylus for free (the soak's
//! faults added ~12 mJ to its worst window that way). So, at every tick,
//! exactly:
//! `delivered − absorbed + unobserved = E_0 − E + credit − (thrown away at E_max)`.
//! A watchdog reset ([`PassivityFilter::reset`]) zeroes the force and
//! restarts the observer but keeps the tank's level, debt included: a
//! fault never hands out a fresh tank.
//!
//! # Fallback
//!
//! If the solver returns a status other than solved / almost solved or a
//! non-finite answer, the output is `α F_prev` with the largest
//! `α ≤ max(0, 1 − Δ/‖F_prev‖)` that keeps the norm and energy bounds: the force
//! ramps to zero at the rate bound and never breaks a hard row. A non-finite
//! input (`F_des`, `x` or `v`) gives zero force (the service zeroes on NaN);
//! a non-finite `x` or `v` also restarts the observer (the interval it spans
//! is not accounted). Both are counted.
//!
//! Even a solved answer is scaled down (by at most the solver tolerance) so
//! the norm and energy rows hold exactly, not to the solver's tolerance.
//!
//! Nothing in [`PassivityFilter::filter`] allocates except clarabel's
//! `solve()`, which makes one small allocation per call (its timers): run the
//! loop's thread under [`crate::rt::alloc`] so that block comes from the RT
//! pool.

//!
//! The code: `params` (the limits, their checks), `filter` (the filter,
//! its statistics, the solve), `polish` (the active-set polishing of
//! near-degenerate solver answers).

mod filter;
mod params;
mod polish;

pub use filter::*;
pub use params::*;

use crate::math::Vec3;

/// Largest `max_iter` accepted; the iteration histogram has one bin per count.
pub const MAX_ITER_CAP: u32 = 100;
/// Bins of [`PassivityStats::iter_hist`] (iteration counts 0..=`MAX_ITER_CAP`).
pub const ITER_HIST_LEN: usize = MAX_ITER_CAP as usize + 1;

/// The work a force `f` (N) held for `dt` (s) does on a stylus of mass
/// `m` (kg) moving at `v` (m/s): `dt v·f + dt² ‖f‖² / (2m)`, the energy
/// row's prediction (the energy ball is the set where it stays within the
/// budget).
pub fn predicted_work(f: Vec3, v: Vec3, m: f64, dt: f64) -> f64 {
    dt * v.dot(&f) + dt * dt * f.norm_squared() / (2.0 * m)
}

/// The stylus velocity over the coming tick, for the energy row: the
/// measured velocity extrapolated by its last change (constant
/// acceleration). The force is held for the whole next period while a
/// measured velocity lags the true one (filtering, one tick of delay);
/// without this a rebound off a stiff wall can draw more from the tank
/// than the row allowed (seen in
/// `tests/closed_loop_with_the_simulated_touchx_is_passive.rs`).
pub fn predict_velocity(v: Vec3, v_prev: Vec3) -> Vec3 {
    let p = v * 2.0 - v_prev;
    if p.iter().all(|c| c.is_finite()) {
        p
    } else {
        v
    }
}
