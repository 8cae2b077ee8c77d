//! Active-set polishing: when the interior-point solver stops near a
//! degenerate optimum, the answer is re-derived exactly on its guessed
//! active set (and the set's subsets), so the output sits on its bounds to
//! round-off.

use super::filter::EnergyBall;
use crate::math::Vec3;

/// The active set the interior-point answer shows, with initial multipliers.
#[derive(Debug, Clone, Copy)]
pub(super) struct PolishSet {
    pub(super) norm: Option<f64>,
    pub(super) rate: Option<f64>,
    pub(super) energy: Option<f64>,
    /// The rate slack is positive: the rate row's multiplier is then exactly
    /// w and the rate term is the smooth penalty `w ‖F − F_prev‖`.
    pub(super) slack: bool,
}

/// [`polish`] with the active set the solver's multipliers show, then, if
/// that fails, with each smaller subset of it (a constraint that is almost
/// active at the optimum can show a small positive multiplier when the
/// solver stops; a wrong guess gives a negative multiplier or an
/// infeasible point, and is rejected), then the same with the rate term
/// read the other way (hard row vs slack). Any accepted point is the
/// optimum (a feasible KKT point of a convex problem). At most 16 attempts
/// of ≤ 8 Newton steps on a 6 × 6 system; no allocation.
#[allow(clippy::too_many_arguments)]
pub(super) fn polish_any(
    f0: Vec3,
    f_des: Vec3,
    f_prev: Vec3,
    bound: f64,
    delta: f64,
    w: f64,
    ball: EnergyBall,
    set: PolishSet,
) -> Option<Vec3> {
    // The solver's guess, then the same with the rate term read the other
    // way: at the kink of w·max(0, ‖F − F_prev‖ − δ) the optimum can sit
    // exactly on the rate sphere (hard row, multiplier ≤ w/δ) while the
    // solver's slack is a hair above zero, or the reverse.
    let toggled = if set.slack {
        PolishSet {
            rate: Some(0.5 * w / delta.max(1e-12)),
            slack: false,
            ..set
        }
    } else {
        PolishSet {
            rate: None,
            slack: set.rate.is_some(),
            ..set
        }
    };
    for base in [set, toggled] {
        if let Some(f) = polish(f0, f_des, f_prev, bound, delta, w, ball, base) {
            return Some(f);
        }
        let on = [base.norm.is_some(), base.rate.is_some(), base.energy.is_some()];
        let full: u8 = (0..3).filter(|&i| on[i]).map(|i| 1u8 << i).sum();
        // Proper subsets of the active set, larger ones first.
        let mut masks: [u8; 8] = [0; 8];
        let mut n = 0;
        for m in (0..full).rev() {
            if m & !full == 0 {
                masks[n] = m;
                n += 1;
            }
        }
        masks[..n].sort_unstable_by_key(|m| std::cmp::Reverse(m.count_ones()));
        let found = masks[..n].iter().find_map(|&m| {
            let sub = PolishSet {
                norm: base.norm.filter(|_| m & 1 != 0),
                rate: base.rate.filter(|_| m & 2 != 0),
                energy: base.energy.filter(|_| m & 4 != 0),
                slack: base.slack,
            };
            polish(f0, f_des, f_prev, bound, delta, w, ball, sub)
        });
        if found.is_some() {
            return found;
        }
    }
    None
}

/// Polishes an interior-point answer: Newton on the KKT equations of the
/// active set the solver found (the three rows are balls: the norm bound
/// around 0, the rate bound around `F_prev`, the energy ball) (equality-constrained, ≤ 6 unknowns, fixed
/// size, no allocation). An interior-point method stops with a duality gap
/// of ~1e-9, which on a curved (cone) boundary leaves the force off by
/// ~sqrt(gap) (1e-5 N); the polished answer is exact to round-off. It is
/// accepted only if it is feasible, its multipliers have the right sign and
/// it is no worse than the solver's; otherwise `None` (keep the solver's).
#[allow(clippy::too_many_arguments)]
pub(super) fn polish(
    f0: Vec3,
    f_des: Vec3,
    f_prev: Vec3,
    bound: f64,
    delta: f64,
    w: f64,
    ball: EnergyBall,
    set: PolishSet,
) -> Option<Vec3> {
    let rows = Rows {
        f_des,
        f_prev,
        bound,
        delta,
        w,
        ball,
    };
    let (f, lam) = newton(&rows, set, f0)?;
    let on = [set.norm.is_some(), set.rate.is_some(), set.energy.is_some()];
    let obj = |f: &Vec3| {
        let r = (f - f_prev).norm();
        (f - f_des).norm_squared() + if set.slack { w * (r - delta).max(0.0) } else { 0.0 }
    };
    let tol = 1e-10 * bound.max(1.0);
    let r = (f - f_prev).norm();
    let feasible = f.norm() <= bound + tol
        && ball.contains(&f, tol)
        && (set.slack || r <= delta + tol)
        && (!set.slack || r >= delta - tol);
    let signs = (0..3).all(|i| !on[i] || lam[i] >= -tol);
    // The rate row is soft (weight w on its slack): a hard rate row is
    // optimal only while its force λ δ does not exceed w.
    let soft_ok = set.slack || !on[1] || lam[1] * delta <= w * (1.0 + 1e-9) + tol;
    let finite = f.iter().all(|c| c.is_finite());
    // A feasible KKT point with the right signs is the optimum (convex
    // problem); the objective test is only a sanity check.
    (finite && feasible && signs && soft_ok && obj(&f) <= obj(&f0) + 1e-6 * (1.0 + obj(&f0).abs())).then_some(f)
}

/// Newton's method on the KKT equations of the active set `set` of the
/// QP `d` from `f0` (the rows of `set` held at equality, the others left
/// out): at most 8 steps on a 6 × 6 system. Returns the last point and the
/// rows' multipliers (0 for the rows left out), None if a step was
/// singular.
fn newton(d: &Rows, set: PolishSet, f0: Vec3) -> Option<(Vec3, [f64; 3])> {
    use nalgebra::{SMatrix, SVector};
    let (f_des, f_prev, bound, delta, w, ball) = (d.f_des, d.f_prev, d.bound, d.delta, d.w, d.ball);
    let mut f = f0;
    let mut lam = [
        set.norm.unwrap_or(0.0),
        set.rate.unwrap_or(0.0),
        set.energy.unwrap_or(0.0),
    ];
    let on = [set.norm.is_some(), set.rate.is_some(), set.energy.is_some()];
    for _ in 0..8 {
        let mut kkt = SMatrix::<f64, 6, 6>::zeros();
        let mut rhs = SVector::<f64, 6>::zeros();
        let mut hess = nalgebra::Matrix3::<f64>::identity() * 2.0;
        let mut grad = (f - f_des) * 2.0;
        if set.slack {
            let d = f - f_prev;
            let r = d.norm();
            if r < 1e-12 {
                return None;
            }
            let u = d / r;
            grad += u * w;
            hess += (nalgebra::Matrix3::identity() - u * u.transpose()) * (w / r);
        }
        // Each row is 0.5 (‖F − centre‖² − radius²) ≤ 0.
        let jac = [f, f - f_prev, f - ball.c];
        let cons = [
            0.5 * (f.norm_squared() - bound * bound),
            0.5 * ((f - f_prev).norm_squared() - delta * delta),
            0.5 * ((f - ball.c).norm_squared() - ball.r * ball.r),
        ];
        for i in 0..3 {
            if on[i] {
                grad += jac[i] * lam[i];
                hess += nalgebra::Matrix3::identity() * lam[i];
                for r in 0..3 {
                    kkt[(r, 3 + i)] = jac[i][r];
                    kkt[(3 + i, r)] = jac[i][r];
                }
                rhs[3 + i] = -cons[i];
            } else {
                kkt[(3 + i, 3 + i)] = 1.0;
            }
        }
        kkt.fixed_view_mut::<3, 3>(0, 0).copy_from(&hess);
        rhs.fixed_rows_mut::<3>(0).copy_from(&(-grad));
        let step = kkt.lu().solve(&rhs)?;
        f += Vec3::new(step[0], step[1], step[2]);
        for i in 0..3 {
            if on[i] {
                lam[i] += step[3 + i];
            }
        }
        if step.norm() < 1e-14 * (1.0 + f.norm()) {
            break;
        }
    }
    Some((f, lam))
}

/// The QP's data for [`exact`].
#[derive(Debug, Clone, Copy)]
pub(super) struct Rows {
    pub(super) f_des: Vec3,
    pub(super) f_prev: Vec3,
    pub(super) bound: f64,
    pub(super) delta: f64,
    pub(super) w: f64,
    pub(super) ball: EnergyBall,
}

/// Which rows an active-set guess holds at equality (bits: 1 norm, 2 rate
/// as a hard row, 4 energy) and whether the rate term is the smooth
/// penalty `w (‖F − F_prev‖ − Δ)` (the slack is positive).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub(super) struct Guess {
    pub(super) mask: u8,
    pub(super) slack: bool,
}

/// Every active set of the QP other than the empty one (which is the
/// interior shortcut), in the order the exact step tries them after the
/// last tick's: one row, two rows, three; then the same with the rate term
/// as the penalty (a hard rate row and the penalty exclude each other).
const GUESSES: [Guess; 11] = [
    Guess { mask: 1, slack: false },
    Guess { mask: 4, slack: false },
    Guess { mask: 2, slack: false },
    Guess { mask: 5, slack: false },
    Guess { mask: 3, slack: false },
    Guess { mask: 6, slack: false },
    Guess { mask: 7, slack: false },
    Guess { mask: 0, slack: true },
    Guess { mask: 1, slack: true },
    Guess { mask: 4, slack: true },
    Guess { mask: 5, slack: true },
];

/// The QP solved exactly by enumerating its active sets, without the
/// interior-point solver: for each guess (`first`, the last tick's set,
/// then [`GUESSES`]), Newton on the guess's KKT equations, and the point is
/// accepted only with a KKT certificate: stationary, the guessed rows at
/// equality, the other rows satisfied, the multipliers non-negative and
/// the hard rate row's force within the penalty's weight (or, for the
/// penalty, the rate sphere left). A KKT point of this convex problem is
/// its optimum, unique since the objective is strictly convex in F; so the
/// answer is the solver's, to round-off instead of the solver's
/// tolerance. None if no guess is certified (a degenerate case: the
/// solver then runs). At most 12 guesses of ≤ 8 Newton steps on a 6 × 6
/// system; no allocation.
pub(super) fn exact(d: &Rows, first: Option<Guess>) -> Option<(Vec3, Guess)> {
    let skip_energy = d.ball.slack;
    let tries = first
        .into_iter()
        .chain(GUESSES.iter().copied().filter(|g| Some(*g) != first));
    for g in tries {
        if skip_energy && g.mask & 4 != 0 {
            continue;
        }
        if let Some(f) = certified(d, g) {
            return Some((f, g));
        }
    }
    None
}

/// One guess of [`exact`]: a start point and multipliers from the rows'
/// projections, Newton, and the KKT certificate.
#[allow(clippy::needless_range_loop)] // index arithmetic reads as the formula
fn certified(d: &Rows, g: Guess) -> Option<Vec3> {
    let (fd, fp, delta, w, ball) = (d.f_des, d.f_prev, d.delta, d.w, d.ball);
    let bound = d.bound;
    // Start: F_des moved by the penalty's pull, then projected on each
    // guessed sphere in turn; each multiplier from its row's projection
    // of F_des (exact for one row).
    let mut f0 = fd;
    if g.slack {
        let u = fd - fp;
        let n = u.norm();
        if n > 0.0 {
            f0 = fd - u * (0.5 * w / n);
        }
    }
    let spheres = [(Vec3::zeros(), bound), (fp, delta), (ball.c, ball.r)];
    let mut lam = [None; 3];
    for (i, (c, r)) in spheres.iter().enumerate() {
        if g.mask & (1 << i) == 0 {
            continue;
        }
        let off = f0 - c;
        let n = off.norm();
        if n > 0.0 && r.is_finite() {
            f0 = c + off * (r / n);
        }
        let nd = (fd - c).norm();
        lam[i] = Some(if *r > 0.0 { (2.0 * (nd / r - 1.0)).max(0.0) } else { 0.0 });
    }
    let set = PolishSet {
        norm: lam[0],
        rate: lam[1],
        energy: lam[2],
        slack: g.slack,
    };
    let (f, lam) = newton(d, set, f0)?;
    if !f.iter().chain(lam.iter()).all(|v| v.is_finite()) {
        return None;
    }
    // The certificate: stationarity, the guessed rows on, the others
    // satisfied, the signs.
    let scale = bound.max(1.0);
    let tol = 1e-10 * scale;
    let mut grad = (f - fd) * 2.0;
    let dr = f - fp;
    let r = dr.norm();
    if g.slack {
        if !(r >= delta - tol && r > 0.0) {
            return None;
        }
        grad += dr * (w / r);
    }
    let jac = [f, dr, f - ball.c];
    let dist = [f.norm(), r, (f - ball.c).norm()];
    for i in 0..3 {
        let (_, radius) = spheres[i];
        if g.mask & (1 << i) != 0 {
            if (dist[i] - radius).abs() > tol || lam[i] < -tol {
                return None;
            }
            grad += jac[i] * lam[i];
        } else if i == 1 {
            if !g.slack && r > delta + tol {
                return None;
            }
        } else if dist[i] > radius + tol {
            return None;
        }
    }
    // A hard rate row is the optimum only while its force λ‖F − F_prev‖
    // does not exceed the penalty's weight (beyond it the slack opens).
    if g.mask & 2 != 0 && lam[1] * delta > w * (1.0 + 1e-9) + tol {
        return None;
    }
    (grad.norm() <= 1e-9 * (scale + fd.norm() + if g.slack { w } else { 0.0 })).then_some(f)
}
