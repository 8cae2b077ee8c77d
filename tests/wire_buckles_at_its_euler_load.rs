//! A straight wire pushed against a stop inside a tube buckles at its
//! Euler load: the hub is a clamp, the tip rests on the tube's frictionless
//! end wall and may slide across it, so the free span is a clamped–free
//! column loaded along its axis, P_cr = π² E I / (4 L²). Pushed slowly
//! (0.5 mm/s, quasi-static: the span's first bending mode is near 150 Hz),
//! the wire must leave the straight line once the load passes P_cr, hold
//! the buckled plateau within 10 % of P_cr while it bows across the tube,
//! and never spike above 1.5 P_cr. A perfect column is a saddle past P_cr;
//! the step finds it by the static Hessian's negative curvature and
//! follows it (docs/WIRE.md "Buckling").
//!
//! `cargo test --release --test wire_buckles_at_its_euler_load -- --nocapture`

use nvtmm::math::Vec3;
use nvtmm::wire::{StraightTube, Wire, WireParams};

struct Run {
    p_cr: f64,
    onset: Option<(f64, f64)>,
    plateau: Vec<f64>,
    peak: f64,
    lateral: f64,
    steps: usize,
    buckled_steps: usize,
    span: f64,
}

/// Pushes the wire against the stop; `check`: the buckling check on.
fn push(check: bool) -> Run {
    // The end wall at x = 60 mm; the tube 5 mm in radius, wide enough for
    // the wire to bow by 3.4 mm (what 0.12 mm of feed past the span takes)
    // without touching its side wall.
    let stop = 0.06;
    let tube = StraightTube::new(Vec3::new(-0.01, 0.0, 0.0), Vec3::x(), stop + 0.01, 5e-3, true).expect("tube");
    let p = WireParams {
        segment_length_m: 2e-3,
        max_nodes: 64,
        friction: 0.0,
        tip_length_m: 0.0,
        tip_curvature_per_m: 0.0,
        tip_stiffness_factor: 1.0,
        ..WireParams::default()
    };
    let r = 0.5 * p.diameter_m;
    // Clamp (the hub, at x = 0) to where the tip's centre rests on the stop.
    let span = stop - r;
    let p_cr = std::f64::consts::PI.powi(2) * p.bending_stiffness() / (4.0 * span * span);
    let mut w = Wire::new(&p, Vec3::zeros(), Vec3::x(), span - 1e-3).expect("wire");
    w.set_buckling_check(check);
    // Up to 0.1 mm short of the stop at 10 mm/s, then on at 0.5 mm/s until
    // the hub has fed 0.12 mm more than the span.
    let mut inserted = w.inserted();
    let mut run = Run {
        p_cr,
        onset: None,
        plateau: Vec::new(),
        peak: 0.0,
        lateral: 0.0,
        steps: 0,
        buckled_steps: 0,
        span,
    };
    while inserted < span + 1.2e-4 {
        let speed = if inserted < span - 1e-4 { 0.01 } else { 5e-4 };
        inserted += speed * p.dt_s;
        w.set_hub(inserted, 0.0);
        let rep = w.step(&tube).expect("step");
        run.steps += 1;
        run.buckled_steps += rep.buckled as usize;
        let f = rep.hub_axial_force_n;
        run.peak = run.peak.max(f);
        run.lateral = w
            .positions()
            .iter()
            .map(|x| (x.y * x.y + x.z * x.z).sqrt())
            .fold(0.0, f64::max);
        if run.onset.is_none() && run.lateral > 0.1e-3 {
            run.onset = Some((f, w.inserted()));
        }
        // The plateau: bowed by 0.5 mm or more.
        if run.lateral > 0.5e-3 {
            run.plateau.push(f);
        }
        assert!(
            rep.max_penetration_m < 0.2e-3,
            "step {}: {} mm into the wall",
            run.steps,
            rep.max_penetration_m * 1e3
        );
    }
    let p_cr = run.p_cr;
    let mean = run.plateau.iter().sum::<f64>() / run.plateau.len().max(1) as f64;
    let (lo, hi) = run
        .plateau
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &f| (a.min(f), b.max(f)));
    let onset = run
        .onset
        .map(|(f, at)| {
            format!(
                "{f:.4} N ({:.4} P_cr, {:.2} µm past the span)",
                f / p_cr,
                (at - run.span) * 1e6
            )
        })
        .unwrap_or_else(|| "never".into());
    println!(
        "check {check}: P_cr {p_cr:.4} N (span {:.2} mm); left the line at {onset}; plateau over {} steps: \
         mean {mean:.4} N ({:.4} P_cr), {lo:.4}..{hi:.4} N; peak {:.4} N ({:.3} P_cr); lateral at the end {:.2} mm; \
         {} of {} steps moved off a saddle",
        run.span * 1e3,
        run.plateau.len(),
        mean / p_cr,
        run.peak,
        run.peak / p_cr,
        run.lateral * 1e3,
        run.buckled_steps,
        run.steps
    );
    run
}

#[test]
fn a_wire_pushed_against_a_stop_buckles_at_its_euler_load_without_a_spike() {
    let run = push(true);
    let p_cr = run.p_cr;
    assert!(run.onset.is_some(), "the wire never left the straight line");
    assert!(
        run.plateau.len() > 50,
        "the buckled plateau lasted {} steps",
        run.plateau.len()
    );
    let mean = run.plateau.iter().sum::<f64>() / run.plateau.len() as f64;
    assert!(
        (mean / p_cr - 1.0).abs() < 0.1,
        "plateau {mean} N against P_cr {p_cr} N"
    );
    for &f in &run.plateau {
        assert!(
            (f / p_cr - 1.0).abs() < 0.1,
            "plateau force {f} N against P_cr {p_cr} N"
        );
    }
    assert!(run.peak < 1.5 * p_cr, "peak {} N against P_cr {p_cr} N", run.peak);
    assert!(run.buckled_steps > 0, "no step moved off the saddle");
}

/// What the check is for: without it the same push stays straight past
/// the Euler load, and the force spikes before the column gives.
#[test]
fn without_the_buckling_check_the_same_push_spikes_past_the_euler_load() {
    let run = push(false);
    assert_eq!(run.buckled_steps, 0);
    assert!(
        run.peak > 1.5 * run.p_cr,
        "peak {} N against P_cr {} N: the test no longer shows what the check is for",
        run.peak,
        run.p_cr
    );
}
