//! The extra Newton iterations of a wire's step (past `newton_iterations`,
//! while a node is off equilibrium) are a fixed count,
//! `max_extra_iterations`, not only a wall-clock limit: a scripted run then
//! gives the same result on any machine (docs/WIRE.md "A fixed budget of
//! extra iterations"). The service's wire pushed at 100 mm/s (the drive's
//! fastest) into the trade experiment's rigid arch-shaped tube, a push hard
//! enough that its steps want more than their configured iterations:
//!
//! - no step takes more than `newton_iterations + max_extra_iterations`
//!   (0, 1, 2), and with the key left out the default (three times
//!   `newton_iterations`) is reached, so the budget is what stops them;
//! - the same push run twice, with no time limit, ends bit for bit in the
//!   same state: a step's outcome depends on its inputs alone.

use nvtmm::experiment::wire_trade;
use nvtmm::math::Vec3;
use nvtmm::wire::{Wire, WireParams};

/// Pushes at 100 mm/s for 1.5 s; returns the most iterations a step took
/// and the nodes' positions at the end.
fn push(extra: Option<usize>) -> (usize, Vec<Vec3>) {
    let tube = wire_trade::tube().unwrap();
    let p = WireParams {
        newton_iterations: 2,
        residual_time_limit_us: 0.0,
        max_extra_iterations: extra,
        ..wire_trade::reference_params()
    };
    assert_eq!(p.max_iterations(), 2 + extra.unwrap_or(6));
    let mut w = Wire::new(&p, Vec3::zeros(), Vec3::x(), 0.02).unwrap();
    let mut most = 0;
    for k in 1..=1500 {
        w.set_hub(0.02 + 0.1 * k as f64 * p.dt_s, 0.0);
        let r = w.step(&tube).unwrap();
        assert!(!r.time_spent, "no time limit, yet step {k} says it ran out of time");
        most = most.max(r.iterations);
    }
    (most, w.positions().to_vec())
}

#[test]
fn the_extra_iterations_stop_at_their_budget() {
    let (unset, _) = push(None);
    println!("key left out: {unset} iterations a step at most (limit 8)");
    assert_eq!(unset, 8, "the push never needed the default's extra iterations");
    for extra in [0, 1, 2] {
        let (most, x) = push(Some(extra));
        println!("max_extra_iterations = {extra}: {most} iterations a step at most");
        assert!(most <= 2 + extra, "{most} iterations with a budget of 2 + {extra}");
        assert!(x.iter().all(|v| v.iter().all(|c| c.is_finite())));
    }
}

#[test]
fn the_same_push_twice_ends_bit_for_bit_the_same() {
    let (_, a) = push(Some(1));
    let (_, b) = push(Some(1));
    assert_eq!(a.len(), b.len());
    for (k, (p, q)) in a.iter().zip(&b).enumerate() {
        assert!(
            p.iter().zip(q.iter()).all(|(u, v)| u.to_bits() == v.to_bits()),
            "node {k}: {p:?} then {q:?}"
        );
    }
}
