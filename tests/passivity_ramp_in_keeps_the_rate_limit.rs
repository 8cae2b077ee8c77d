//! While the watchdog's gain ramps in (the service's first half second, or
//! after a fault), the hand's force changes by no more than the passivity
//! filter's rate limit a tick (`PassivityFilter::ramp_in_within_rate`).
//!
//! The case it guards: the filter bounds its output's change against the
//! force held now, but the hand gets the output times the gain. A catheter
//! service's rods settling at the start gave a falling output (1.77 N held,
//! 0.77 N out of the filter, 1 N below) with the gain at 0.94: the plain
//! product fell by 1.05 N in one tick, over the 1 N limit. The scaled
//! force stays on the segment from `gain · filtered` to `filtered`, so it
//! keeps the filter's norm bound and energy ball.

use nvtmm::haptics::passivity::{PassivityFilter, PassivityParams};
use nvtmm::math::Vec3;

fn filter() -> PassivityFilter {
    PassivityFilter::new(&PassivityParams::default()).unwrap()
}

#[test]
fn a_falling_force_under_a_ramping_gain_changes_by_the_rate_limit_at_most() {
    let mut f = filter();
    let delta = f.params().rate_n_per_tick;
    let held = Vec3::new(0.0, 0.0, 1.77);
    f.set_commanded(held);
    let filtered = Vec3::new(0.0, 0.0, 0.77);
    let plain = filtered * 0.94;
    assert!((plain - held).norm() > delta, "the plain product is within the limit");
    let out = f.ramp_in_within_rate(filtered, 0.94);
    println!(
        "held {:.3} N, filtered {:.3} N, gain 0.94: plain {:.3} N, ramped {:.4} N",
        held.z, filtered.z, plain.z, out.z
    );
    assert!((out - held).norm() <= delta + 1e-12, "{out:?}");
    assert!(out.z >= plain.z && out.z <= filtered.z, "{out:?} off the segment");
}

#[test]
fn the_ramp_is_the_plain_gain_where_that_keeps_the_rate_and_never_exceeds_the_output() {
    let mut f = filter();
    let delta = f.params().rate_n_per_tick;
    // A deterministic spread of held forces, outputs and gains.
    let mut seed = 0x2545_f491_4f6c_dd1d_u64;
    let mut next = || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        (seed >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut slowed = 0;
    for _ in 0..10_000 {
        let held = Vec3::new(next() - 0.5, next() - 0.5, next() - 0.5) * 6.0;
        let step = Vec3::new(next() - 0.5, next() - 0.5, next() - 0.5) * 2.0 * delta;
        let filtered = held + step;
        let gain = next();
        f.set_commanded(held);
        let out = f.ramp_in_within_rate(filtered, gain);
        let plain = filtered * gain;
        // On the segment from the plain product to the filter's output.
        let s = if filtered.norm() > 0.0 {
            out.dot(&filtered) / filtered.norm_squared()
        } else {
            0.0
        };
        assert!((out - filtered * s).norm() < 1e-9, "off the output's line");
        assert!(s >= gain - 1e-12 && s <= 1.0 + 1e-12, "scale {s} outside [{gain}, 1]");
        // Within the rate whenever the filter's own output was.
        if step.norm() <= delta {
            assert!((out - held).norm() <= delta + 1e-9, "changed {} N", (out - held).norm());
        }
        // No slower than needed: the plain product where it keeps the rate.
        if (plain - held).norm() <= delta {
            assert_eq!(out, plain);
        } else {
            slowed += 1;
        }
    }
    println!("{slowed} of 10000 ticks slowed the ramp-in to keep the rate");
    assert!(slowed > 100, "too few cases exercise the slowed ramp");
}
