//! A timing harness for implicit steps.
//! Not a test: it measures wall-clock time on whatever machine it runs.

use crate::model::ForceModel;
use crate::solver::loads::Loads;
use crate::solver::{ImplicitEuler, StepFailure, TissueState};
use std::time::Instant;

/// Timing and work statistics over a run of steps.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct StepTimings {
    /// Steps attempted.
    pub steps: usize,
    /// Steps that failed (the state then stayed put; the run stops at the first).
    pub failed: usize,
    /// Mean, median, 99th percentile and maximum wall time per step (s).
    pub mean_s: f64,
    /// Median step time (s).
    pub median_s: f64,
    /// 99th-percentile step time (s).
    pub p99_s: f64,
    /// Slowest step (s).
    pub max_s: f64,
    /// Mean Newton iterations per step.
    pub mean_newton_iters: f64,
    /// Mean CG iterations per step (0 with Cholesky).
    pub mean_linear_iters: f64,
    /// Steps accepted without meeting the Newton tolerance.
    pub unconverged: usize,
    /// The first failure, as text.
    pub first_failure: Option<String>,
}

/// Runs `steps` steps and times each one. Stops at the first failed step.
pub fn time_steps(
    euler: &mut ImplicitEuler,
    state: &mut TissueState,
    model: &mut dyn ForceModel,
    loads: &Loads,
    fixed: &[u32],
    steps: usize,
) -> StepTimings {
    let mut times = Vec::with_capacity(steps);
    let (mut newton, mut linear, mut unconverged) = (0usize, 0usize, 0usize);
    let mut failure: Option<StepFailure> = None;
    for _ in 0..steps {
        let t = Instant::now();
        let rep = euler.step(state, model, loads, fixed);
        times.push(t.elapsed().as_secs_f64());
        newton += rep.newton_iters;
        linear += rep.linear_iters;
        if let Some(f) = rep.failure {
            failure = Some(f);
            break;
        }
        unconverged += usize::from(!rep.converged);
    }
    let n = times.len().max(1) as f64;
    let mean_s = times.iter().sum::<f64>() / n;
    times.sort_by(f64::total_cmp);
    let pick = |q: f64| {
        times
            .get(((times.len() as f64 - 1.0) * q).round() as usize)
            .copied()
            .unwrap_or(0.0)
    };
    StepTimings {
        steps: times.len(),
        failed: usize::from(failure.is_some()),
        mean_s,
        median_s: pick(0.5),
        p99_s: pick(0.99),
        max_s: times.last().copied().unwrap_or(0.0),
        mean_newton_iters: newton as f64 / n,
        mean_linear_iters: linear as f64 / n,
        unconverged,
        first_failure: failure.map(|f| f.to_string()),
    }
}
