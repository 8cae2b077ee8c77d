//! Friction that holds and turns: a load below μN holds a wire still
//! against the wall (static friction, a stick anchor per contact), and
//! friction resists roll as well as sliding (the wire's surface spins
//! against the wall when it rolls), so a rolled wire's tip lags its hub in
//! a curved tube by an amount that grows with μ.

use nvtmm::math::Vec3;
use nvtmm::wire::{CurvedTube, CurvedTubeShape, StraightTube, Wire, WireParams};

/// A wire lying on the floor of a straight tube under a downward line load
/// q, then pushed sideways (along the wall) by `side` × μ q per length for
/// `seconds`: the tip's largest displacement from where it lay (m).
fn sideways(mu: f64, side: f64, seconds: f64) -> f64 {
    let tube = StraightTube::new(Vec3::new(-0.01, 0.0, 0.0), Vec3::x(), 0.2, 2e-3, false).expect("tube");
    let p = WireParams {
        tip_length_m: 0.0,
        friction: mu,
        ..WireParams::default()
    };
    let mut w = Wire::new(&p, Vec3::zeros(), Vec3::x(), 0.1).expect("wire");
    let q = 2.0;
    w.set_line_load(Vec3::new(0.0, 0.0, -q));
    for _ in 0..1000 {
        w.step(&tube).expect("finite");
    }
    let lay = w.tip();
    assert!(lay.z < -1e-3, "the wire lies on the floor: {lay:?}");
    w.set_line_load(Vec3::new(0.0, side * mu * q, -q));
    let mut most: f64 = 0.0;
    for _ in 0..(seconds / p.dt_s).round() as usize {
        w.step(&tube).expect("finite");
        most = most.max((w.tip() - lay).norm());
    }
    most
}

#[test]
fn a_load_of_half_mu_n_holds_the_tip_within_a_hundredth_of_a_millimetre_for_a_minute() {
    let held = sideways(0.5, 0.5, 60.0);
    println!("0.5 μN sideways for 60 s: tip moved {:.3} µm", held * 1e6);
    assert!(held < 1e-5, "the tip crept {held} m");
    // Not vacuous: twice μN slides it up the wall within a second.
    let slid = sideways(0.5, 2.0, 1.0);
    println!("2 μN sideways for 1 s: tip moved {:.3} mm", slid * 1e3);
    assert!(slid > 2e-4, "{slid}");
}

/// A straight wire through a rigid quarter-bend (its bending presses it on
/// the outer wall), its hub rolled by 1 rad over 1 s and then held for
/// 0.5 s: how far the tip's material frame lags the hub's roll (rad).
fn roll_lag(mu: f64) -> f64 {
    let tube = CurvedTube::new(&CurvedTubeShape {
        start: Vec3::new(-0.005, 0.0, 0.0),
        tangent: Vec3::x(),
        toward: Vec3::y(),
        inlet: 0.02,
        bend_radius: 0.03,
        angle: std::f64::consts::FRAC_PI_2,
        outlet: 0.1,
        radius: 2e-3,
    })
    .expect("tube");
    let p = WireParams {
        tip_length_m: 0.0,
        friction: 0.0,
        segment_length_m: 2e-3,
        ..WireParams::default()
    };
    let mut w = Wire::new(&p, Vec3::zeros(), Vec3::x(), 0.005).expect("wire");
    let full = 0.1;
    let mut l = w.inserted();
    while l < full {
        l = (l + 1e-4).min(full);
        w.set_hub(l, 0.0);
        w.step(&tube).expect("finite");
    }
    for _ in 0..500 {
        w.step(&tube).expect("finite");
    }
    w.set_friction(mu);
    for _ in 0..100 {
        w.step(&tube).expect("finite");
    }
    let last = w.num_nodes() - 2;
    let (t0, m0, _) = w.material_frame(last);
    let roll = 1.0;
    let mut torque: f64 = 0.0;
    for k in 1..=1500 {
        w.set_hub(full, roll * (k as f64 / 1000.0).min(1.0));
        let r = w.step(&tube).expect("finite");
        torque = torque.max(r.hub_torque_nm.abs());
    }
    let (t1, m1, _) = w.material_frame(last);
    assert!((t1 - t0).norm() < 0.02, "the tip's tangent stays: {t0:?} {t1:?}");
    let turned = m0.cross(&m1).dot(&t1).atan2(m0.dot(&m1));
    println!(
        "μ {mu}: tip turned {turned:.5} rad of {roll}, lag {:.5} rad, hub torque up to {torque:.3e} N·m, contacts {}",
        roll - turned,
        w.contacts().len()
    );
    roll - turned
}

#[test]
fn the_roll_lag_in_a_curved_tube_is_nonzero_and_scales_with_mu() {
    let free = roll_lag(0.0);
    let (a, b) = (roll_lag(0.1), roll_lag(0.2));
    assert!(free.abs() < 1e-3, "without friction the tip follows: lag {free}");
    assert!(a > 5e-3, "μ = 0.1: lag {a}");
    let ratio = (b - free) / (a - free);
    assert!((ratio - 2.0).abs() < 0.4, "lag at μ 0.2 / at μ 0.1 = {ratio}");
}
