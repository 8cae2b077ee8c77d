//! Torsion: rolling the hub of a straight wire turns its tip's material frame
//! by the same angle (quasi-static), and a pre-shaped tip's bend turns with
//! it — how a trainee steers the tip into a branch.

use nvtmm::math::Vec3;
use nvtmm::wire::{NoWall, Wire, WireParams};

/// Angle of `v`'s component perpendicular to x, about +x.
fn angle_about_x(v: Vec3) -> f64 {
    v.z.atan2(v.y)
}

fn wrap(a: f64) -> f64 {
    (a + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI
}

fn roll_to(w: &mut Wire, inserted: f64, roll: f64, steps: usize) {
    let r0 = w.roll();
    for k in 1..=steps {
        w.set_hub(inserted, r0 + (roll - r0) * k as f64 / steps as f64);
        w.step(&NoWall).expect("finite");
    }
    for _ in 0..200 {
        w.step(&NoWall).expect("finite");
    }
}

#[test]
fn rolling_the_hub_turns_a_straight_tip_by_the_same_angle() {
    let p = WireParams {
        segment_length_m: 2e-3,
        tip_length_m: 0.0,
        ..WireParams::default()
    };
    let l = 0.2;
    let mut w = Wire::new(&p, Vec3::zeros(), Vec3::x(), l).expect("wire");
    let last = w.num_nodes() - 2;
    let before = angle_about_x(w.material_frame(last).1);
    for roll in [1.0, 2.5, -0.7] {
        roll_to(&mut w, l, roll, 300);
        let after = angle_about_x(w.material_frame(last).1);
        let turned = wrap(after - before);
        println!("hub roll {roll:.3} rad: tip turned {turned:.6} rad");
        assert!((turned - wrap(roll)).abs() < 0.01 * roll.abs(), "{turned} vs {roll}");
    }
}

#[test]
fn rolling_the_hub_turns_a_preshaped_tip() {
    let p = WireParams {
        segment_length_m: 2e-3,
        tip_length_m: 0.02,
        tip_curvature_per_m: 40.0,
        ..WireParams::default()
    };
    let l = 0.15;
    let mut w = Wire::new(&p, Vec3::zeros(), Vec3::x(), l).expect("wire");
    roll_to(&mut w, l, 0.0, 1);
    let bend = |w: &Wire| angle_about_x(w.tip() - Vec3::new(w.tip().x, 0.0, 0.0));
    let off = (w.tip().y.powi(2) + w.tip().z.powi(2)).sqrt();
    assert!(off > 3e-3, "the tip is not bent: {off}");
    let before = bend(&w);
    for roll in [std::f64::consts::FRAC_PI_2, 2.0] {
        roll_to(&mut w, l, roll, 500);
        let turned = wrap(bend(&w) - before);
        println!("hub roll {roll:.3} rad: bent tip turned {turned:.6} rad");
        assert!((turned - roll).abs() < 0.01 * roll, "{turned} vs {roll}");
    }
}
