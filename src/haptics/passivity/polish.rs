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
    use nalgebra::{SMatrix, SVector};
    let mut f = f0;
    let mut lam = [
        set.norm.unwrap_or(0.0),
        set.rate.unwrap_or(0.0),
        set.energy.unwrap_or(0.0),
    ];
    let on = [set.norm.is_some(), set.rate.is_some(), set.energy.is_some()];
    let obj = |f: &Vec3| {
        let r = (f - f_prev).norm();
        (f - f_des).norm_squared() + if set.slack { w * (r - delta).max(0.0) } else { 0.0 }
    };
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
