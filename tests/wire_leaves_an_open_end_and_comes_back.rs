//! An opening of the vessel mesh is an open boundary: a wire whose tip went
//! out of an open branch end is pulled back and rolled freely.

use nvtmm::math::Vec3;
use nvtmm::wire::lumen::tube_wall;
use nvtmm::wire::{TriangleLumen, Wire, WireParams};

/// Steps as the service's wire thread does: a step deeper in the wall than
/// the wire's diameter (or non-finite) goes back to the last good state,
/// saved every 100 good steps. Returns the resets.
fn run(w: &mut Wire, lumen: &TriangleLumen, steps: usize, hub: impl Fn(usize) -> (f64, f64), since: &mut u32) -> usize {
    let d = w.params().diameter_m;
    let mut resets = 0;
    for k in 0..steps {
        let (ins, roll) = hub(k);
        w.set_hub(ins, roll);
        match w.step(lumen) {
            Ok(r) if r.max_penetration_m <= d => {
                *since += 1;
                if *since >= 100 && r.max_penetration_m < 0.25 * d {
                    w.save_good_state();
                    *since = 0;
                }
            }
            _ => {
                w.restore_good_state();
                *since = 0;
                resets += 1;
            }
        }
    }
    resets
}

/// The angle of the tip's offset from the tube's axis (x), about x.
fn bend_angle(w: &Wire) -> f64 {
    let t = w.tip();
    t.z.atan2(t.y)
}

#[test]
fn a_wire_whose_tip_went_out_of_an_open_branch_end_is_pulled_back_and_rolled_freely() {
    // A branch stub 3 mm in radius, open at x = 0.09 m.
    let (v, t) = tube_wall(-0.01, 0.1, 3e-3, 16, 40, 0.0);
    let lumen = TriangleLumen::new(&v, &t).expect("surface");
    let p = WireParams {
        tip_curvature_per_m: 60.0,
        ..WireParams::default()
    };
    let d = p.diameter_m;
    let pull_and_roll = |w: &mut Wire, from: f64, since: &mut u32| {
        let r0 = bend_angle(w);
        let resets = run(
            w,
            &lumen,
            3000,
            |k| {
                let a = (k as f64 / 2000.0).min(1.0);
                (from - 0.06 * a, 2.2 * a)
            },
            since,
        );
        let turned = (bend_angle(w) - r0).rem_euclid(std::f64::consts::TAU);
        (resets, turned)
    };

    // Laid out of the end, its pre-shaped tip springing into shape outside
    // the stub, then pulled back 60 mm and rolled by 2.2 rad.
    let mut w = Wire::new(&p, Vec3::zeros(), Vec3::x(), 0.13).expect("wire");
    let mut since = 0;
    let r_out = run(&mut w, &lumen, 500, |_| (0.13, 0.0), &mut since);
    let out = w.tip();
    let (r_back, turned) = pull_and_roll(&mut w, 0.13, &mut since);
    let back = w.tip();
    println!(
        "laid out: tip {out:?}; pulled back: tip {back:?}, inserted {}, turned {turned}",
        w.inserted()
    );
    assert_eq!((r_out, r_back), (0, 0), "resets");
    assert!(out.x > 0.1, "the tip is out of the stub: {out:?}");
    assert!(
        (w.inserted() - 0.07).abs() < 1e-9,
        "the hub went back: {}",
        w.inserted()
    );
    assert!(
        back.x < 0.075 && back.y.hypot(back.z) < 3e-3,
        "the tip is back in the stub: {back:?}"
    );
    assert!((turned - 2.2).abs() < 0.3, "the tip turned by {turned} rad");
    let deepest = w.contacts().iter().map(|c| c.penetration).fold(0.0, f64::max);
    assert!(deepest < 0.1 * d, "{deepest}");

    // Pushed out of the end from inside (30 mm past it), then the same.
    let mut w = Wire::new(&p, Vec3::zeros(), Vec3::x(), 0.05).expect("wire");
    let mut since = 0;
    let r_push = run(
        &mut w,
        &lumen,
        3000,
        |k| (0.05 + 0.07 * (k as f64 / 2500.0).min(1.0), 0.0),
        &mut since,
    );
    let out = w.tip();
    let (r_back, turned) = pull_and_roll(&mut w, 0.12, &mut since);
    let back = w.tip();
    println!(
        "pushed: tip {out:?}, inserted {}; pulled back: tip {back:?}, turned {turned}",
        0.12
    );
    assert_eq!((r_push, r_back), (0, 0), "resets");
    assert!(out.x > 0.1, "the tip left the stub: {out:?}");
    assert!(
        (w.inserted() - 0.06).abs() < 1e-9,
        "the hub went back: {}",
        w.inserted()
    );
    assert!(back.x < 0.065, "the tip is back: {back:?}");
    assert!((turned - 2.2).abs() < 0.3, "the tip turned by {turned} rad");
}
