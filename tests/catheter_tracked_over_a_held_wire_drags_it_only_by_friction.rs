//! A 5 F catheter tracked over a held 0.035" wire through a half turn of
//! the arch's radius (30 mm) presses on the wire about as the two do at
//! rest in that bend, and drags the wire's hub by no more than the lumen's
//! friction on that pressure. The pair has the cannulation scenarios'
//! budgets of Newton iterations.
//!
//! What it guards: the wire's nodes inside the catheter start each step
//! carried with the catheter's motion across its axis, not along it. Carried
//! along too, every inside node went forward by the catheter's feed each
//! step against the held hub and the nodes beyond the catheter's tip, a
//! stretch of hundreds of newtons for the wire's few Newton iterations to
//! undo; the steps that ended off equilibrium pressed the wire into the
//! catheter by hundreds of newtons summed and pulled its hub to the grip's
//! limit (docs/INSTRUMENTS.md "In the cannulation scenarios").
//!
//! The bounds: the wire held still while the catheter slides over it is
//! dragged by kinetic friction, μ times the summed normal force, so its hub
//! force stays below μ ΣN + 0.5 N (the 0.5 N: the wire's own steps, off
//! equilibrium by up to the residual tolerance); and the summed normal
//! force while tracking stays below twice the pair's at rest plus 1 N
//! (the catheter's motion changes where the wire lies across the
//! clearance, not how much it has to bend). Measured: 5.3 N summed at
//! rest, 5.7 N at most while tracking, the hub 0.33 N; with the inside
//! nodes carried along the catheter's axis too, 13.5 N and 1.84 N.

use nvtmm::math::Vec3;
use nvtmm::wire::catheter::{catheter_params, TipShape, CATHETER_NEWTON_ITERATIONS};
use nvtmm::wire::coaxial::Coaxial;
use nvtmm::wire::{CurvedTube, CurvedTubeShape, WireParams};

#[test]
fn a_catheter_tracked_over_a_held_wire_through_the_arch_bend_presses_as_at_rest_and_drags_by_friction() {
    let (r_bend, theta) = (0.03, std::f64::consts::PI);
    let tube = CurvedTube::new(&CurvedTubeShape {
        start: Vec3::new(-0.005, 0.0, 0.0),
        tangent: Vec3::x(),
        toward: Vec3::y(),
        inlet: 0.03,
        bend_radius: r_bend,
        angle: theta,
        outlet: 0.2,
        radius: 2e-3,
    })
    .expect("tube");
    // The cannulation scenarios' budgets: the wire two Newton iterations
    // a step and one more for its residual, the catheter one
    // (`CATHETER_NEWTON_ITERATIONS`), 4 mm catheter segments.
    let c = WireParams {
        max_nodes: 100,
        segment_length_m: 4e-3,
        newton_iterations: CATHETER_NEWTON_ITERATIONS,
        max_extra_iterations: Some(1),
        ..catheter_params(5.0, TipShape::Straight)
    };
    let w = WireParams {
        tip_length_m: 0.0,
        max_nodes: 200,
        newton_iterations: 2,
        max_extra_iterations: Some(1),
        residual_tolerance_n: 0.2,
        ..WireParams::default()
    };
    let mu = 0.05;
    let mut p = Coaxial::new(&w, &c, Vec3::zeros(), Vec3::x(), 0.01, 0.005).expect("pair");
    p.set_friction(mu);
    // The catheter through the bend and 10 mm into the outlet, the wire
    // 40 mm beyond its tip, both at 100 mm/s, then settled.
    let cath = 0.035 + r_bend * theta + 0.01;
    let wire = cath + 0.04;
    let (mut lc, mut lw) = (p.catheter().inserted(), p.wire().inserted());
    while lc < cath || lw < wire {
        lc = (lc + 1e-4).min(cath);
        lw = (lw + 1e-4).min(wire);
        p.set_hubs(lw, 0.0, lc, 0.0);
        p.step(&tube).expect("finite");
    }
    let (mut rest_sum, mut rest_n) = (0.0, 0);
    for k in 0..600 {
        let r = p.step(&tube).expect("finite");
        if k >= 400 {
            rest_sum += r.coaxial_normal_force_n;
            rest_n += 1;
        }
    }
    let rest = rest_sum / rest_n as f64;
    // The catheter tracked 15 mm over the held wire at 25 mm/s.
    let (mut most, mut hub_most, mut deepest) = (0.0f64, 0.0f64, 0.0f64);
    for _ in 0..600 {
        lc += 2.5e-5;
        p.set_hubs(lw, 0.0, lc, 0.0);
        let r = p.step(&tube).expect("finite");
        assert!(p.is_finite());
        most = most.max(r.coaxial_normal_force_n);
        hub_most = hub_most.max(r.wire.hub_axial_force_n.abs());
        deepest = deepest.max(r.wire.max_sheath_penetration_m);
    }
    println!(
        "summed normal force at rest {rest:.3} N, tracking {most:.3} N at most; the wire's hub force {hub_most:.3} N \
         at most (μ ΣN = {:.3} N); deepest into the catheter {:.4} mm",
        mu * most,
        deepest * 1e3
    );
    assert!(p.wire_lead_m() > 0.02, "the wire's tip stays out of the catheter");
    assert!(
        most < 2.0 * rest + 1.0,
        "tracking pressed {most} N summed, at rest {rest} N"
    );
    assert!(
        hub_most < mu * most + 0.5,
        "the wire's hub held {hub_most} N, the lumen's friction is at most {} N",
        mu * most
    );
    assert!(deepest < 0.2e-3, "the wire {deepest} m into the catheter's wall");
}
