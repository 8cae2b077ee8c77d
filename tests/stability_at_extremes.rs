//! Stability at the extremes: every model and law over ν ∈ {0, 0.499},
//! E ∈ {1 kPa, 10 MPa}, dt ∈ {0.1 ms, 10 ms}, Prony τ ≪ dt and ≫ dt, Σα near
//! 1, and loads large enough to invert elements. No NaN or infinity ever; a
//! step either advances or reports failure and leaves the state unchanged
//! (`run_extreme` marks a changed state on failure as non-finite too).
//! The full sweep's table is in docs/EXTREMES.md (`nvtmm bench extremes`).

use nvtmm::bench::{extremes_cases, run_extreme, run_extreme_with};

#[test]
fn no_nan_and_failures_are_safe_over_the_sweep() {
    let cases = extremes_cases(true);
    assert!(cases.len() > 40);
    let mut completed = 0;
    for c in &cases {
        let r = run_extreme(c, 60);
        assert!(!r.non_finite, "non-finite or changed state on failure: {c:?} -> {r:?}");
        assert!(r.steps > 0, "{c:?}");
        assert!(r.min_det_f.is_finite(), "{c:?}");
        if r.failure.is_none() {
            assert_eq!(r.ok_steps, r.steps);
            completed += 1;
        } else {
            assert_eq!(r.ok_steps + 1, r.steps, "a failure ends the run: {r:?}");
        }
    }
    // The moderate part of the range must run through, not just fail safely.
    assert!(
        completed * 4 >= cases.len() * 3,
        "only {completed} of {} cases completed",
        cases.len()
    );
}

#[test]
fn step_halving_keeps_the_guarantees_and_never_completes_fewer_cases() {
    let cases = extremes_cases(true);
    let (mut plain, mut halved, mut split) = (0, 0, 0);
    for c in &cases {
        let a = run_extreme(c, 60);
        let b = run_extreme_with(c, 60, 4);
        assert!(!b.non_finite, "non-finite or changed state on failure: {c:?} -> {b:?}");
        assert!(b.min_det_f.is_finite(), "{c:?}");
        // A case that never fails never splits a step: the same run.
        if a.failure.is_none() {
            assert!(b.failure.is_none() && b.split_steps == 0, "{c:?}: {b:?}");
            plain += 1;
        }
        if b.failure.is_none() {
            halved += 1;
        }
        split += b.split_steps;
    }
    assert!(halved >= plain);
    eprintln!(
        "completed without halving {plain}, with up to 4 halvings {halved} of {}; split steps {split}",
        cases.len()
    );
}
