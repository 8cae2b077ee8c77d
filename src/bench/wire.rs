//! `nvtmm bench wire`: the guidewire's step time against its node count
//! (32 … 512), in free space and lying on a tube wall along its whole
//! length, to show that the step is O(n) (docs/WIRE.md).
//!
//! The scene: a straight wire of n nodes (2 mm segments, the default
//! 0.035" nitinol wire) fully inserted along +x, its hub moving in and out
//! by ±2 mm at 1 Hz and rolling by ±0.5 rad, so that every step solves a
//! changing problem. With contacts, it lies in a 1.2 mm-radius straight tube
//! under a sideways load of 2 N/m, so that the free nodes touch the wall
//! and slides on it with friction μ = 0.1.

use crate::math::Vec3;
use crate::wire::{Lumen, NoWall, StraightTube, Wire, WireParams};
use std::time::Instant;

/// One row of `nvtmm bench wire` (JSON keys are a scripting contract).
#[derive(Debug, Clone, serde::Serialize)]
pub struct WireBench {
    /// Nodes (ghost and hub included).
    pub nodes: usize,
    /// Whether the wire lay on a wall.
    pub contacts: bool,
    /// Steps timed (after 200 warm-up steps).
    pub steps: usize,
    /// Median step time (µs).
    pub us_p50: f64,
    /// 99th percentile (µs).
    pub us_p99: f64,
    /// Slowest step (µs).
    pub us_max: f64,
    /// Median time per node (ns).
    pub ns_per_node: f64,
    /// Newton iterations allowed per step.
    pub iterations_max: usize,
    /// Mean Newton iterations per step.
    pub iterations_mean: f64,
    /// Mean contacts per step.
    pub contacts_mean: f64,
}

/// Times `steps` wire steps with `nodes` nodes, with or without the wall, at
/// most `iterations` Newton iterations a step.
pub fn bench_wire(
    nodes: usize,
    steps: usize,
    contacts: bool,
    iterations: usize,
) -> Result<WireBench, super::BenchError> {
    if !(8..=4096).contains(&nodes) {
        return Err(super::BenchError::Arg(format!("--nodes {nodes}: must be in 8..=4096")));
    }
    if !(1..=100).contains(&iterations) {
        return Err(super::BenchError::Arg(format!(
            "--iterations {iterations}: must be in 1..=100"
        )));
    }
    if steps == 0 {
        return Err(super::BenchError::Arg("--steps must be at least 1".into()));
    }
    let p = WireParams {
        segment_length_m: 2e-3,
        max_nodes: nodes,
        length_m: 10.0,
        newton_iterations: iterations,
        ..WireParams::default()
    };
    let mut w = Wire::new(&p, Vec3::zeros(), Vec3::x(), 1.0).map_err(|e| super::BenchError::Arg(e.to_string()))?;
    let full = w.max_inserted() - 3e-3;
    let tube = StraightTube::new(Vec3::new(-0.01, 0.0, 0.0), Vec3::x(), 20.0, 1.2e-3, false)
        .map_err(|e| super::BenchError::Arg(e.to_string()))?;
    let lumen: &dyn Lumen = if contacts { &tube } else { &NoWall };
    if contacts {
        w.set_line_load(Vec3::new(0.0, -2.0, 0.0));
    }
    let mut times = Vec::with_capacity(steps);
    let (mut iters, mut ncont) = (0usize, 0usize);
    for k in 0..steps + 200 {
        let t = k as f64 * 1e-3;
        let phase = (std::f64::consts::TAU * t).sin();
        w.set_hub(full - 2e-3 + 2e-3 * phase, 0.5 * phase);
        let t0 = Instant::now();
        let r = w.step(lumen);
        let us = t0.elapsed().as_secs_f64() * 1e6;
        let r = r.map_err(|e| super::BenchError::Step {
            step: k + 1,
            reason: e.to_string(),
        })?;
        if k >= 200 {
            times.push(us);
            iters += r.iterations;
            ncont += r.contacts;
        }
    }
    times.sort_by(f64::total_cmp);
    let pct = |q: f64| times[((times.len() - 1) as f64 * q).round() as usize];
    let n = w.num_nodes();
    Ok(WireBench {
        nodes: n,
        contacts,
        steps,
        us_p50: pct(0.5),
        us_p99: pct(0.99),
        us_max: pct(1.0),
        ns_per_node: pct(0.5) * 1e3 / n as f64,
        iterations_max: iterations,
        iterations_mean: iters as f64 / steps as f64,
        contacts_mean: ncont as f64 / steps as f64,
    })
}
