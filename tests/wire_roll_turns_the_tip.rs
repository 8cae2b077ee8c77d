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

#[test]
fn the_roll_survives_nodes_entering_and_leaving_at_the_hub() {
    let p = WireParams {
        segment_length_m: 2e-3,
        tip_length_m: 0.0,
        ..WireParams::default()
    };
    let l0 = 0.1;
    let mut w = Wire::new(&p, Vec3::zeros(), Vec3::x(), l0).expect("wire");
    let tip_edge = |w: &Wire| w.num_nodes() - 2;
    let before = angle_about_x(w.material_frame(tip_edge(&w)).1);
    roll_to(&mut w, l0, 1.2, 300);
    let n0 = w.num_nodes();
    // In by 30 mm and back out by 50 mm at 50 mm/s, roll held.
    let mut l = l0;
    for k in 0..1600 {
        l += if k < 600 { 5e-5 } else { -5e-5 };
        w.set_hub(l, 1.2);
        w.step(&NoWall).expect("finite");
        if k == 599 {
            assert!(
                w.num_nodes() >= n0 + 14,
                "nodes did not enter: {} vs {n0}",
                w.num_nodes()
            );
        }
    }
    for _ in 0..200 {
        w.step(&NoWall).expect("finite");
    }
    assert!(
        w.num_nodes() <= n0 - 9,
        "nodes did not leave: {} vs {n0}",
        w.num_nodes()
    );
    assert!((w.inserted() - 0.08).abs() < 1e-9, "inserted {}", w.inserted());
    let turned = wrap(angle_about_x(w.material_frame(tip_edge(&w)).1) - before);
    println!("after feeding in and out: tip turned {turned:.6} rad for a hub roll of 1.2 rad");
    assert!((turned - 1.2).abs() < 0.012, "{turned}");
}
