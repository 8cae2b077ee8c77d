//! No penetration beyond 0.2 mm in a coaxial advance through a curved
//! tube: a J-tip wire leading a vertebral-tip 5 F catheter, both advanced
//! at 100 mm/s through a 115° bend of 20 mm radius, the wire then pulled
//! back inside the catheter while the catheter advances alone, and
//! advanced again out of it. At every step: the wire no deeper than 0.2 mm
//! into the vessel's wall or the catheter's inner wall, the catheter no
//! deeper than 0.2 mm into the vessel's wall, and every node of both
//! inside the vessel.

use nvtmm::math::Vec3;
use nvtmm::wire::catheter::{catheter_params, TipShape};
use nvtmm::wire::coaxial::Coaxial;
use nvtmm::wire::{CurvedTube, CurvedTubeShape, Lumen, WireParams};

const MAX_PEN: f64 = 2e-4;

#[test]
fn a_coaxial_advance_through_a_bend_stays_within_a_fifth_of_a_millimetre_of_both_walls() {
    let tube = CurvedTube::new(&CurvedTubeShape {
        start: Vec3::new(-0.005, 0.0, 0.0),
        tangent: Vec3::x(),
        toward: Vec3::y(),
        inlet: 0.03,
        bend_radius: 0.02,
        angle: 2.0,
        outlet: 0.15,
        radius: 2.5e-3,
    })
    .expect("tube");
    let c = WireParams {
        max_nodes: 80,
        friction: 0.1,
        ..catheter_params(5.0, TipShape::Vertebral)
    };
    let w = WireParams {
        segment_length_m: 3e-3,
        max_nodes: 80,
        friction: 0.1,
        ..WireParams::default()
    };
    let mut p = Coaxial::new(&w, &c, Vec3::zeros(), Vec3::x(), 0.005, 0.01).expect("pair");
    // (wire, catheter) inserted lengths to go to in turn, at 100 mm/s each.
    let legs = [(0.15, 0.13), (0.10, 0.13), (0.10, 0.16), (0.20, 0.16)];
    let (mut wl, mut cl) = (p.wire().inserted(), p.catheter().inserted());
    let (mut pw, mut ps, mut pc): (f64, f64, f64) = (0.0, 0.0, 0.0);
    let (mut sheath_contacts, mut k) = (0, 0);
    for (wt, ct) in legs {
        while wl != wt || cl != ct {
            wl += (wt - wl).clamp(-1e-4, 1e-4);
            cl += (ct - cl).clamp(-1e-4, 1e-4);
            p.set_hubs(wl, 0.0, cl, 0.0);
            let r = p.step(&tube).unwrap_or_else(|e| panic!("step {k}: {e}"));
            assert!(p.is_finite(), "step {k}");
            pw = pw.max(r.wire.max_penetration_m);
            ps = ps.max(r.wire.max_sheath_penetration_m);
            pc = pc.max(r.catheter.max_penetration_m);
            sheath_contacts += r.wire.sheath_contacts;
            assert!(
                r.wire.max_penetration_m <= MAX_PEN
                    && r.wire.max_sheath_penetration_m <= MAX_PEN
                    && r.catheter.max_penetration_m <= MAX_PEN,
                "step {k}: wire into the vessel {:.4} mm, into the catheter {:.4} mm, catheter into the vessel {:.4} mm",
                r.wire.max_penetration_m * 1e3,
                r.wire.max_sheath_penetration_m * 1e3,
                r.catheter.max_penetration_m * 1e3
            );
            k += 1;
        }
    }
    println!(
        "{k} coupled steps: deepest wire into the vessel {:.4} mm, wire into the catheter {:.4} mm, catheter into the vessel {:.4} mm; {sheath_contacts} wire–catheter contacts",
        pw * 1e3,
        ps * 1e3,
        pc * 1e3
    );
    assert!(sheath_contacts > 100, "the wire pressed on the catheter's inner wall");
    // Both went round the bend, and every node is inside the vessel.
    assert!(
        p.catheter().tip().y > 0.02 && p.wire().tip().y > 0.03,
        "round the bend: {:?} {:?}",
        p.catheter().tip(),
        p.wire().tip()
    );
    for (name, rod, r) in [
        ("wire", p.wire(), 0.5 * w.diameter_m),
        ("catheter", p.catheter(), 0.5 * c.diameter_m),
    ] {
        for x in rod.positions().iter().skip(2) {
            let h = tube.probe(*x, 1.0).expect("walls everywhere");
            assert!(
                h.distance > r - MAX_PEN,
                "{name}: node at {x:?} is out ({} m from the wall)",
                h.distance
            );
        }
    }
}
