//! Two Newton iterations a step follow a converged push: the default wire
//! pushed at 20 and at 50 mm/s into the trade experiment's rigid
//! arch-shaped tube (`experiment::wire_trade::tube`), once with two
//! iterations a step and once with eight (the trade's reference, 1.5 mm
//! segments): the tips stay within 0.2 mm of each other.
//!
//! Guards where a push starts its step (docs/WIRE.md "Pushes start from
//! the unmoved wire once it has settled"). When every push slid the wire
//! along itself by the feed, two iterations ended 3.7 mm (20 mm/s) and
//! 0.66 mm (50 mm/s) from eight over this insertion's 2.5 s
//! (`nvtmm experiment trade --wire`); the slide set every contact slipping
//! by the whole feed, which two iterations did not undo.

use nvtmm::experiment::wire_trade;
use nvtmm::math::Vec3;
use nvtmm::wire::{Wire, WireParams};

/// The tip every 10 ms over `seconds` of pushing at `speed` m/s from 20 mm
/// inserted, and the most evaluations a step took.
fn tips(iterations: usize, speed: f64, seconds: f64) -> (Vec<Vec3>, usize) {
    let tube = wire_trade::tube().unwrap();
    let p = WireParams {
        newton_iterations: iterations,
        ..wire_trade::reference_params()
    };
    let mut w = Wire::new(&p, Vec3::zeros(), Vec3::x(), 0.02).unwrap();
    let steps = (seconds / p.dt_s).round() as usize;
    let mut out = Vec::new();
    let mut most = 0;
    for k in 1..=steps {
        w.set_hub(0.02 + speed * k as f64 * p.dt_s, 0.0);
        let r = w.step(&tube).unwrap();
        most = most.max(r.evaluations);
        if k % 10 == 0 {
            out.push(w.tip());
        }
    }
    (out, most)
}

#[test]
fn two_iterations_a_step_follow_a_converged_push() {
    for (speed, seconds) in [(0.02, 2.5), (0.05, 2.5)] {
        let (reference, _) = tips(8, speed, seconds);
        let (two, most) = tips(2, speed, seconds);
        let worst = reference
            .iter()
            .zip(&two)
            .map(|(a, b)| (a - b).norm())
            .fold(0.0, f64::max);
        println!(
            "{:.0} mm/s: tips apart by {:.4} mm at most (two iterations, {most} evaluations a step at most)",
            speed * 1e3,
            worst * 1e3
        );
        // The wire went round the bend (past the inlet and the half turn's
        // start), so the comparison covers contact with the curved wall.
        let last = reference.last().unwrap();
        assert!(last.y > 0.01, "the tip did not go round the bend: {last:?}");
        assert!(worst < 2e-4, "{:.0} mm/s: {:.3} mm apart", speed * 1e3, worst * 1e3);
    }
}
