//! `nvtmm bench wire --coaxial`: the coupled step of a guidewire inside a
//! catheter ([`crate::wire::coaxial::Coaxial`]), timed per step.
//!
//! The scene: a curved tube like a vessel taking a turn (radius 2 mm, a
//! 200 mm straight inlet, a quarter-turn bend of 50 mm radius, a 200 mm
//! outlet). A 5 F straight-tipped catheter and a straight 0.035" nitinol
//! wire, both of `nodes` nodes at 3 mm segments, are advanced from the
//! inlet at 100 mm/s until the catheter's tip is 60 mm past the bend's
//! end, with the wire 20 mm ahead of it. (In a 4 mm tube with a 2 rad bend
//! of 30 mm radius, a cobra catheter and a J-tip wire, the coupled step
//! did not converge: docs/CATHETER.md "What the coupling does not do
//! yet".) Then both hubs move in and out by ±2 mm at 1 Hz, out of
//! phase, so that the wire slides in the catheter, and roll by ±0.5 rad:
//! every step solves a changing problem with contacts between the wire and
//! the catheter and between both and the wall. Each coupled step is one
//! block Gauss–Seidel pass (the wire's implicit step, then the catheter's:
//! docs/CATHETER.md), coupled as the service couples the pair, with the
//! stabilising spring at [`LOAD_STIFFNESS_SHARE`] of the wire's penalty;
//! the bench reports each rod's Newton iterations and evaluations of its
//! potential.

use crate::math::Vec3;
use crate::wire::catheter::{catheter_params, TipShape, CATHETER_NEWTON_ITERATIONS};
use crate::wire::coaxial::{Coaxial, LOAD_STIFFNESS_SHARE};
use crate::wire::{CurvedTube, CurvedTubeShape, WireParams};
use std::time::Instant;

/// The result of `nvtmm bench wire --coaxial` (JSON keys are a scripting
/// contract).
#[derive(Debug, Clone, serde::Serialize)]
pub struct CoaxialBench {
    /// The wire's nodes after the set-up (ghost and hub included).
    pub wire_nodes: usize,
    /// The catheter's nodes after the set-up.
    pub catheter_nodes: usize,
    /// Coupled steps timed (after the set-up and 200 warm-up steps).
    pub steps: usize,
    /// Median coupled step time (µs).
    pub us_p50: f64,
    /// 99th percentile (µs).
    pub us_p99: f64,
    /// 99.9th percentile (µs).
    pub us_p999: f64,
    /// Slowest step (µs).
    pub us_max: f64,
    /// Gauss–Seidel passes between the rods per coupled step (one: each
    /// rod takes one implicit step per coupled step).
    pub passes_per_step: usize,
    /// The wire's mean Newton iterations per step.
    pub wire_iterations_mean: f64,
    /// The wire's most Newton iterations in a step.
    pub wire_iterations_max: usize,
    /// The catheter's mean Newton iterations per step.
    pub catheter_iterations_mean: f64,
    /// The catheter's most Newton iterations in a step.
    pub catheter_iterations_max: usize,
    /// Mean evaluations of both rods' potentials per step.
    pub evaluations_mean: f64,
    /// Most evaluations in a step.
    pub evaluations_max: usize,
    /// Mean wall contacts per step (the wire's and the catheter's).
    pub wall_contacts_mean: f64,
    /// Mean contacts of the wire on the catheter's inner wall per step.
    pub sheath_contacts_mean: f64,
    /// Steps whose wire or catheter ended off equilibrium by more than its
    /// `residual_tolerance_n`.
    pub unsettled_steps: usize,
}

/// Times `steps` coupled steps of a wire of `nodes` nodes inside a catheter
/// of `nodes` nodes in the curved tube (module docs).
pub fn bench_coaxial(nodes: usize, steps: usize) -> Result<CoaxialBench, super::BenchError> {
    if !(16..=1024).contains(&nodes) {
        return Err(super::BenchError::Arg(format!(
            "--nodes {nodes}: must be in 16..=1024 with --coaxial"
        )));
    }
    if steps == 0 {
        return Err(super::BenchError::Arg("--steps must be at least 1".into()));
    }
    let arg = |e: String| super::BenchError::Arg(e);
    let (bend_r, angle) = (0.05, std::f64::consts::FRAC_PI_2);
    let tube = CurvedTube::new(&CurvedTubeShape {
        start: Vec3::new(-0.005, 0.0, 0.0),
        tangent: Vec3::x(),
        toward: Vec3::y(),
        inlet: 0.2,
        bend_radius: bend_r,
        angle,
        outlet: 0.2,
        radius: 2e-3,
    })
    .map_err(|e| arg(e.to_string()))?;
    // The catheter's iterations as the service runs them.
    let c = WireParams {
        max_nodes: nodes,
        newton_iterations: CATHETER_NEWTON_ITERATIONS,
        ..catheter_params(5.0, TipShape::Straight)
    };
    let w = WireParams {
        segment_length_m: 3e-3,
        max_nodes: nodes,
        tip_length_m: 0.0,
        ..WireParams::default()
    };
    let mut p = Coaxial::new(&w, &c, Vec3::zeros(), Vec3::x(), 0.03, 0.01).map_err(|e| arg(e.to_string()))?;
    // Coupled as the service couples the pair: without the stabilising
    // spring, the hubs' roll set the pair swinging and every step ended
    // off equilibrium (docs/CATHETER.md "The cost of a coupled step").
    p.set_load_stiffness_share(LOAD_STIFFNESS_SHARE);
    // Room for both at their furthest (the wire 20 mm ahead, 2 mm more).
    let reach = p.wire().max_inserted().min(p.catheter().max_inserted() + 0.02) - 0.025;
    let cath = (0.2 + bend_r * angle + 0.06).min(reach - 0.02);
    if cath < 0.05 {
        return Err(arg(format!("--nodes {nodes}: too few to reach into the tube")));
    }
    let step = |p: &mut Coaxial, k: usize| {
        p.step(&tube).map_err(|e| super::BenchError::Step {
            step: k + 1,
            reason: e.to_string(),
        })
    };
    let (mut lc, mut lw) = (p.catheter().inserted(), p.wire().inserted());
    let mut k = 0;
    while lc < cath || lw < cath + 0.02 {
        lc = (lc + 1e-4).min(cath);
        lw = (lw + 1e-4).min(cath + 0.02);
        p.set_hubs(lw, 0.0, lc, 0.0);
        step(&mut p, k)?;
        k += 1;
    }
    let mut times = Vec::with_capacity(steps);
    let (mut wit, mut cit, mut wmax, mut cmax) = (0usize, 0usize, 0usize, 0usize);
    let (mut evals, mut emax, mut wall, mut sheath, mut unsettled) = (0usize, 0usize, 0usize, 0usize, 0usize);
    let (wtol, ctol) = (w.residual_tolerance_n, c.residual_tolerance_n);
    for j in 0..steps + 200 {
        let t = j as f64 * 1e-3;
        let (s, co) = (std::f64::consts::TAU * t).sin_cos();
        p.set_hubs(lw + 2e-3 * s, 0.5 * s, lc + 2e-3 * co, 0.5 * co);
        let t0 = Instant::now();
        let r = p.step(&tube);
        let us = t0.elapsed().as_secs_f64() * 1e6;
        let r = r.map_err(|e| super::BenchError::Step {
            step: k + j + 1,
            reason: e.to_string(),
        })?;
        if j >= 200 {
            times.push(us);
            wit += r.wire.iterations;
            cit += r.catheter.iterations;
            wmax = wmax.max(r.wire.iterations);
            cmax = cmax.max(r.catheter.iterations);
            evals += r.evaluations;
            emax = emax.max(r.evaluations);
            wall += r.wire.contacts + r.catheter.contacts;
            sheath += r.wire.sheath_contacts;
            if r.wire.residual_n > wtol || r.catheter.residual_n > ctol {
                unsettled += 1;
            }
        }
    }
    times.sort_by(f64::total_cmp);
    let pct = |q: f64| times[((times.len() - 1) as f64 * q).round() as usize];
    let per = |x: usize| x as f64 / steps as f64;
    Ok(CoaxialBench {
        wire_nodes: p.wire().num_nodes(),
        catheter_nodes: p.catheter().num_nodes(),
        steps,
        us_p50: pct(0.5),
        us_p99: pct(0.99),
        us_p999: pct(0.999),
        us_max: pct(1.0),
        passes_per_step: 1,
        wire_iterations_mean: per(wit),
        wire_iterations_max: wmax,
        catheter_iterations_mean: per(cit),
        catheter_iterations_max: cmax,
        evaluations_mean: per(evals),
        evaluations_max: emax,
        wall_contacts_mean: per(wall),
        sheath_contacts_mean: per(sheath),
        unsettled_steps: unsettled,
    })
}
