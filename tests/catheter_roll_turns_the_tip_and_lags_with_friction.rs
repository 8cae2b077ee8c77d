//! Torque at the catheter's hub: rolled with a wire inside it, a 5 F
//! catheter's tip turns by the hub's angle in a straight tube (nothing
//! touches the wall); in a quarter-turn bend, where it presses on the wall,
//! friction resists the roll (the surface spins against the wall) and the
//! tip lags the hub by an amount that grows with the vessel's μ.

use nvtmm::math::Vec3;
use nvtmm::wire::catheter::{catheter_params, TipShape};
use nvtmm::wire::coaxial::Coaxial;
use nvtmm::wire::{CurvedTube, CurvedTubeShape, Lumen, StraightTube, WireParams};

/// A 5 F straight catheter and a straight 0.035" wire, 3 mm segments.
fn pair(mu: f64) -> Coaxial {
    let c = WireParams {
        max_nodes: 60,
        friction: mu,
        ..catheter_params(5.0, TipShape::Straight)
    };
    let w = WireParams {
        tip_length_m: 0.0,
        segment_length_m: 3e-3,
        max_nodes: 60,
        friction: 0.0,
        ..WireParams::default()
    };
    Coaxial::new(&w, &c, Vec3::zeros(), Vec3::x(), 0.005, 0.01).expect("pair")
}

/// Advances the catheter to `to` (m) at 100 mm/s with the wire 20 mm
/// behind its tip, then lets the pair settle.
fn advance(p: &mut Coaxial, lumen: &dyn Lumen, to: f64) {
    let mut l = p.catheter().inserted();
    while l < to {
        l = (l + 1e-4).min(to);
        p.set_hubs((l - 0.02).max(0.005), 0.0, l, 0.0);
        p.step(lumen).expect("finite");
    }
    for _ in 0..300 {
        p.step(lumen).expect("finite");
    }
}

/// The angle (rad) by which the catheter's tip edge turned about its own
/// tangent while its hub rolled by `roll` over 1 s, held 0.5 s.
fn roll_tip(p: &mut Coaxial, lumen: &dyn Lumen, roll: f64) -> f64 {
    let (wl, cl) = (p.wire().inserted(), p.catheter().inserted());
    let last = p.catheter().num_nodes() - 2;
    let (t0, m0, _) = p.catheter().material_frame(last);
    for k in 1..=1500 {
        p.set_hubs(wl, 0.0, cl, roll * (k as f64 / 1000.0).min(1.0));
        p.step(lumen).expect("finite");
        assert!(p.is_finite());
    }
    let (t1, m1, _) = p.catheter().material_frame(last);
    assert!((t1 - t0).norm() < 0.02, "the tip's tangent stays: {t0:?} {t1:?}");
    m0.cross(&m1).dot(&t1).atan2(m0.dot(&m1))
}

#[test]
fn in_a_straight_tube_the_tip_turns_by_the_hub_roll() {
    let tube = StraightTube::new(Vec3::new(-0.005, 0.0, 0.0), Vec3::x(), 0.3, 3e-3, false).expect("tube");
    let mut p = pair(0.2);
    advance(&mut p, &tube, 0.12);
    for roll in [1.0, 2.5] {
        let before = p.catheter().roll();
        let turned = roll_tip(&mut p, &tube, roll);
        let want = roll - before;
        println!(
            "straight tube: hub rolled {want:.3} rad, catheter tip turned {turned:.5} rad, {} wall contacts",
            p.catheter().contacts().len()
        );
        assert!((turned - want).abs() < 0.01 * want.abs(), "{turned} vs {want}");
    }
}

fn bend_lag(mu: f64) -> (f64, usize) {
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
    // In without friction (the same shape for every μ), then friction on.
    let mut p = pair(0.0);
    advance(&mut p, &tube, 0.1);
    p.catheter_mut().set_friction(mu);
    for _ in 0..100 {
        p.step(&tube).expect("finite");
    }
    let contacts = p.catheter().contacts().len();
    let roll = 1.0;
    let turned = roll_tip(&mut p, &tube, roll);
    println!(
        "bend, μ = {mu}: tip turned {turned:.5} rad of {roll}, lag {:.5} rad, {contacts} wall contacts",
        roll - turned
    );
    (roll - turned, contacts)
}

#[test]
fn in_a_bend_the_tip_lags_by_more_as_friction_grows() {
    let (free, contacts) = bend_lag(0.0);
    assert!(
        contacts >= 2,
        "the catheter presses on the bend's wall: {contacts} contacts"
    );
    let (a, _) = bend_lag(0.1);
    let (b, _) = bend_lag(0.3);
    assert!(free.abs() < 2e-3, "without friction the tip follows: lag {free}");
    assert!(a - free > 2e-3, "μ = 0.1: lag {a}");
    assert!(b - free > 2.0 * (a - free), "μ = 0.3: lag {b}, μ = 0.1: {a}");
    assert!(b < 1.0, "the tip turns at all: lag {b}");
}
