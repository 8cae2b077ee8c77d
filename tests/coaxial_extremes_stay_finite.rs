//! Extremes of a wire and a catheter stepped together (`Coaxial`), at
//! 100 mm/s: the catheter advanced through a bend with no wire in it; the
//! wire pulled back wholly inside the catheter and out to the hub; both
//! pushed into a dead end; and both pushed on until the catheter's grip
//! slips. Never a NaN, never more than 0.2 mm into a wall, no tip through
//! the dead end; the reset path brings back the last good state. The pair
//! is coupled as the service couples it, with the stabilising spring on
//! ([`LOAD_STIFFNESS_SHARE`], docs/CATHETER.md "The stabilising spring").

use nvtmm::math::Vec3;
use nvtmm::wire::catheter::{catheter_params, TipShape};
use nvtmm::wire::coaxial::{Coaxial, CoaxialReport, LOAD_STIFFNESS_SHARE};
use nvtmm::wire::{CurvedTube, CurvedTubeShape, Lumen, StraightTube, WireParams};

const MAX_PEN: f64 = 2e-4;

fn pair(shape: TipShape, wire_in: f64, cath_in: f64) -> Coaxial {
    let c = WireParams {
        max_nodes: 80,
        ..catheter_params(5.0, shape)
    };
    let w = WireParams {
        segment_length_m: 3e-3,
        max_nodes: 80,
        ..WireParams::default()
    };
    let mut p = Coaxial::new(&w, &c, Vec3::zeros(), Vec3::x(), wire_in, cath_in).expect("pair");
    p.set_load_stiffness_share(LOAD_STIFFNESS_SHARE);
    p
}

/// Drives both hubs to (`wire`, `cath`) inserted at 100 mm/s each and then
/// `hold` steps more, checking every step; the largest penetration of any
/// kind and the catheter's largest hub force.
fn drive(p: &mut Coaxial, lumen: &dyn Lumen, wire: f64, cath: f64, hold: usize, what: &str) -> (f64, f64, bool) {
    let (mut wl, mut cl) = (p.wire().inserted(), p.catheter().inserted());
    let (mut pen, mut force, mut slipped): (f64, f64, bool) = (0.0, 0.0, false);
    let mut k = 0;
    let mut check = |r: &CoaxialReport, p: &Coaxial, k: usize| {
        assert!(p.is_finite(), "{what}: step {k}: not finite");
        for rr in [&r.wire, &r.catheter] {
            assert!(
                rr.hub_axial_force_n.is_finite() && rr.hub_torque_nm.is_finite(),
                "{what}: step {k}"
            );
        }
        for c in p.wall_contacts().chain(p.wire().sheath_contacts()) {
            assert!(
                c.normal_force.is_finite() && c.friction.iter().all(|f| f.is_finite()),
                "{what}: step {k}"
            );
        }
        let deepest = r
            .wire
            .max_penetration_m
            .max(r.wire.max_sheath_penetration_m)
            .max(r.catheter.max_penetration_m);
        assert!(
            deepest <= MAX_PEN,
            "{what}: step {k}: penetration {:.4} mm",
            deepest * 1e3
        );
        pen = pen.max(deepest);
        force = force.max(r.catheter.hub_axial_force_n);
        slipped |= r.catheter.grip_slipped;
    };
    while wl != wire || cl != cath || k < hold {
        wl += (wire - wl).clamp(-1e-4, 1e-4);
        cl += (cath - cl).clamp(-1e-4, 1e-4);
        p.set_hubs(wl, 0.3 * (k as f64 * 1e-3).sin(), cl, 0.0);
        let r = p.step(lumen).unwrap_or_else(|e| panic!("{what}: step {k}: {e}"));
        check(&r, p, k);
        k += 1;
        if wl == wire && cl == cath && k >= hold {
            break;
        }
    }
    println!(
        "{what}: deepest {:.4} mm, catheter hub force up to {force:.3} N{}",
        pen * 1e3,
        if slipped { ", the grip slipped" } else { "" }
    );
    (pen, force, slipped)
}

fn bend() -> CurvedTube {
    CurvedTube::new(&CurvedTubeShape {
        start: Vec3::new(-0.005, 0.0, 0.0),
        tangent: Vec3::x(),
        toward: Vec3::y(),
        inlet: 0.02,
        bend_radius: 0.02,
        angle: 2.0,
        outlet: 0.15,
        radius: 2.5e-3,
    })
    .expect("tube")
}

#[test]
fn a_catheter_advanced_with_no_wire_in_it_stays_finite_and_inside() {
    let tube = bend();
    for shape in [TipShape::Simmons, TipShape::Cobra] {
        // The wire's shortest insertion: half a segment, in the hub.
        let mut p = pair(shape, 0.0, 0.01);
        let what = format!("{} catheter, no wire", shape.name());
        drive(&mut p, &tube, 0.0, 0.17, 200, &what);
        assert!(p.wire_lead_m() < -0.15, "{what}: the wire stayed at the hub");
        assert!(
            p.catheter().tip().y > 0.02,
            "{what}: the catheter went round the bend: {:?}",
            p.catheter().tip()
        );
    }
}

#[test]
fn a_wire_pulled_wholly_inside_the_catheter_and_out_to_the_hub_stays_finite() {
    let tube = bend();
    let mut p = pair(TipShape::Vertebral, 0.005, 0.01);
    let what = "wire leading into the bend";
    drive(&mut p, &tube, 0.14, 0.12, 0, what);
    drive(&mut p, &tube, 0.06, 0.12, 100, "wire pulled back inside");
    assert!(p.wire_lead_m() < -0.05);
    drive(&mut p, &tube, 0.0, 0.12, 100, "wire pulled out to the hub");
    drive(&mut p, &tube, 0.15, 0.12, 100, "wire advanced out again");
    assert!(p.wire_lead_m() > 0.02);
}

#[test]
fn both_pushed_into_a_dead_end_and_on_to_the_grips_limit_stay_finite() {
    // A 5 mm tube with a dead end 60 mm in.
    let tube = StraightTube::new(Vec3::new(-0.01, 0.0, 0.0), Vec3::x(), 0.07, 2.5e-3, true).expect("tube");
    let mut p = pair(TipShape::Vertebral, 0.005, 0.01);
    // To the end (the wire 5 mm ahead), then 25 mm more of both.
    drive(&mut p, &tube, 0.085, 0.08, 0, "both into the dead end");
    for (name, tip) in [("wire", p.wire().tip()), ("catheter", p.catheter().tip())] {
        assert!(
            tip.x <= 0.06 + 1e-4,
            "the {name}'s tip went through the dead end: {tip:?}"
        );
    }
    // On until the catheter's grip slips.
    let (_, force, slipped) = drive(&mut p, &tube, 0.12, 0.12, 200, "both pushed on");
    let grip = p.catheter().params().max_hub_force_n;
    assert!(slipped, "the catheter's grip slipped");
    assert!(force <= grip * 1.05, "hub force {force} N past the grip's {grip} N");
    assert!(
        p.catheter().inserted() < 0.12 - 0.01,
        "the catheter slipped back in the grip: {}",
        p.catheter().inserted()
    );
    // The reset path.
    p.save_good_state();
    let saved: Vec<Vec3> = p.catheter().positions().to_vec();
    let saved_w: Vec<Vec3> = p.wire().positions().to_vec();
    drive(&mut p, &tube, 0.05, 0.05, 0, "pulled back");
    assert!(p.catheter().positions() != saved.as_slice());
    p.restore_good_state();
    assert_eq!(p.catheter().positions(), saved.as_slice());
    assert_eq!(p.wire().positions(), saved_w.as_slice());
    assert!(p.is_finite());
}
