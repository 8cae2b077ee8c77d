//! The simulated Touch X behaves like the device the haptic loop must cope
//! with: forces are clamped to the peak and, when sustained, to the
//! continuous limit; the reported position is quantized to the encoder
//! resolution; the scripted hand moves the stylus along its script; the
//! workspace stops it; port energy is bookkept exactly (zero without force,
//! F·Δx with a constant force); injected faults appear as documented.

use nvtmm::haptics::touchx::{TouchXParams, TouchXSim, Waypoint};
use nvtmm::haptics::{DeviceError, HapticDevice};
use nvtmm::math::Vec3;

const DT: f64 = 1e-3;

fn started(sim: TouchXSim) -> TouchXSim {
    let mut sim = sim;
    sim.start().expect("sim starts");
    sim
}

fn hold(params: TouchXParams) -> TouchXSim {
    started(TouchXSim::holding(params, Vec3::zeros()).expect("valid script"))
}

/// Runs the 1 kHz read/write loop from tick `from` to `to` (exclusive) with a
/// constant command; returns the last returned force.
fn run(sim: &mut TouchXSim, from: usize, to: usize, f: Vec3) -> Vec3 {
    let mut out = Vec3::zeros();
    for i in from..to {
        sim.read(i as f64 * DT).expect("read");
        out = sim.write_force(f).expect("write");
    }
    out
}

#[test]
fn force_is_clamped_to_the_peak_keeping_its_direction() {
    let mut sim = hold(TouchXParams::default());
    sim.read(0.0).expect("read");
    let cmd = Vec3::new(12.0, -16.0, 0.0); // 20 N
    let f = sim.write_force(cmd).expect("write");
    assert!((f.norm() - 7.9).abs() < 1e-12, "{f:?}");
    assert!((f.normalize() - cmd.normalize()).norm() < 1e-12);
    assert_eq!(sim.state().applied_force, f);
    assert_eq!(sim.state().peak_clamps, 1);
    // Below the peak, the command passes unchanged.
    let small = Vec3::new(0.5, 0.2, -0.1);
    assert_eq!(sim.write_force(small).expect("write"), small);
}

#[test]
fn sustained_force_is_limited_to_the_continuous_force() {
    let p = TouchXParams::default();
    let (c, tau) = (p.continuous_force_n, p.thermal_tau_s);
    let mut sim = hold(p);
    let cmd = Vec3::new(0.0, 0.0, 5.0);
    // Filtered mean of |F|² rises as 25 (1 − e^(−t/τ)); it reaches c² at
    // t* = −τ ln(1 − c²/25) ≈ 1.31 s. Before: unlimited.
    let t_star = -tau * (1.0 - c * c / 25.0).ln();
    let before = ((t_star - 0.05) / DT) as usize;
    let f = run(&mut sim, 0, before, cmd);
    assert_eq!(
        f, cmd,
        "no thermal limit before the mean force reaches the continuous limit"
    );
    assert_eq!(sim.state().thermal_limits, 0);
    // Well after: limited to the continuous force, and the filtered RMS stays
    // pinned just above the limit.
    let f = run(&mut sim, before, 30_000, cmd);
    assert!((f.norm() - c).abs() < 1e-12, "{f:?}");
    let rms = sim.state().rms_force_n;
    assert!(rms >= c && rms < c * 1.001, "rms {rms}");
    assert!(sim.state().thermal_limits > 0);
    // A small command lets it cool below the limit; then a large command
    // passes again until it heats up.
    run(&mut sim, 30_000, 40_000, Vec3::new(0.0, 0.0, 0.5));
    assert!(sim.state().rms_force_n < c);
    let f = run(&mut sim, 40_000, 40_010, cmd);
    assert_eq!(f, cmd);
}

#[test]
fn reported_position_is_quantized_to_the_resolution() {
    let p = TouchXParams::default();
    let r = p.resolution_m;
    let a = Vec3::new(-0.02, 0.01, 0.003);
    let b = Vec3::new(0.0312345, -0.0101, 0.0);
    let mut sim = started(
        TouchXSim::new(
            p,
            &[Waypoint { t_s: 0.0, position: a }, Waypoint { t_s: 0.5, position: b }],
        )
        .expect("script"),
    );
    let mut distinct = std::collections::BTreeSet::new();
    for i in 0..700 {
        let s = sim.read(i as f64 * DT).expect("read");
        let truth = sim.state().position;
        for k in 0..3 {
            let steps = s.position[k] / r;
            assert!(
                (steps - steps.round()).abs() < 1e-6,
                "axis {k}: {} is not a multiple of {r}",
                s.position[k]
            );
            assert!(
                (s.position[k] - truth[k]).abs() <= 0.5 * r + 1e-15,
                "quantization error above r/2"
            );
        }
        distinct.insert((s.position.x / r).round() as i64);
    }
    assert!(distinct.len() > 100, "the stylus moved over many encoder steps");
}

#[test]
fn hand_moves_the_stylus_along_the_script() {
    let p = TouchXParams::default();
    let a = Vec3::new(0.0, 0.0, 0.0);
    let b = Vec3::new(0.03, -0.01, 0.02);
    let mut sim = started(
        TouchXSim::new(
            p,
            &[Waypoint { t_s: 0.0, position: a }, Waypoint { t_s: 1.0, position: b }],
        )
        .expect("script"),
    );
    let mut max_lag: f64 = 0.0;
    let (mut v_rep, mut v_true) = (Vec3::zeros(), Vec3::zeros());
    for i in 0..=2000 {
        let t = i as f64 * DT;
        let s = sim.read(t).expect("read");
        sim.write_force(Vec3::zeros()).expect("write");
        let u = t.min(1.0);
        let target = a + (b - a) * 0.5 * (1.0 - (std::f64::consts::PI * u).cos());
        max_lag = max_lag.max((sim.state().position - target).norm());
        if (400..600).contains(&i) {
            v_rep += s.velocity;
            v_true += sim.state().velocity;
        }
    }
    // Lag ≈ (m·a + friction + viscous)/k_hand ≈ 0.3 mm with the shipped figures.
    assert!(max_lag < 1e-3, "tracking error {max_lag} m");
    assert!((sim.state().position - b).norm() < 0.5e-3, "ends at the last waypoint");
    // The driver-style velocity (differenced, quantized, low-passed) matches
    // the true velocity on average.
    assert!(
        (v_rep - v_true).norm() < 0.05 * v_true.norm(),
        "{v_rep:?} vs {v_true:?}"
    );
}

#[test]
fn workspace_stops_the_stylus() {
    let p = TouchXParams {
        hand_stiffness_n_per_m: 0.0,
        hand_damping_ns_per_m: 0.0,
        ..TouchXParams::default()
    };
    let half = p.half_extent();
    let mut sim = hold(p);
    run(&mut sim, 0, 1000, Vec3::new(7.9, 0.0, 0.0));
    let st = sim.state();
    assert_eq!(st.position.x, half.x, "stopped at the +x face");
    assert_eq!(st.velocity.x, 0.0);
    assert!(st.workspace_stops > 0);
    let s = sim.read(1.0).expect("read");
    assert!(s.position.x <= half.x + 0.5 * sim.params().resolution_m);
}

#[test]
fn port_energy_is_zero_without_force_and_f_dx_with_a_constant_force() {
    let p = TouchXParams::default();
    let a = Vec3::zeros();
    let b = Vec3::new(0.02, 0.01, -0.01);
    let script = [Waypoint { t_s: 0.0, position: a }, Waypoint { t_s: 0.3, position: b }];
    // The hand moves the stylus, the device pushes nothing: no energy.
    let mut sim = started(TouchXSim::new(p.clone(), &script).expect("script"));
    run(&mut sim, 0, 500, Vec3::zeros());
    let e = sim.port_energy().expect("the sim knows its port energy");
    assert_eq!((e.delivered_j, e.absorbed_j), (0.0, 0.0));
    // A constant force while the hand moves the stylus back and forth:
    // net energy delivered = F·(x_end − x_start), to round-off. The force
    // is written every period, as the service does (a command older than
    // the command timeout stops playing).
    let mut sim = started(TouchXSim::new(p, &script).expect("script"));
    sim.read(0.0).expect("read");
    let f = Vec3::new(1.0, -0.5, 0.25);
    sim.write_force(f).expect("write");
    let x0 = sim.state().position;
    for i in 1..800 {
        sim.read(i as f64 * DT).expect("read");
        sim.write_force(f).expect("write");
    }
    assert_eq!(sim.state().command_timeouts, 0);
    let x1 = sim.state().position;
    let e = sim.port_energy().expect("energy");
    let expect = f.dot(&(x1 - x0));
    assert!(e.delivered_j >= 0.0 && e.absorbed_j >= 0.0);
    assert!(
        (e.net_delivered_j() - expect).abs() <= 1e-12 * (e.delivered_j + e.absorbed_j).max(1e-9),
        "net {} vs F·Δx {expect}",
        e.net_delivered_j()
    );
    assert!(e.delivered_j > 0.0, "the stylus moved along the force");
}

#[test]
fn injected_faults_appear_as_documented() {
    let mut sim = hold(TouchXParams::default());
    sim.inject_silence(0.010, 0.005);
    sim.inject_non_finite(0.020);
    let mut stale = Vec::new();
    let mut non_finite = Vec::new();
    for i in 0..30 {
        match sim.read(i as f64 * DT) {
            Err(DeviceError::Stale) => stale.push(i),
            Ok(s) if !s.is_finite() => non_finite.push(i),
            Ok(_) => {}
            Err(e) => panic!("unexpected {e}"),
        }
    }
    assert_eq!(stale, vec![10, 11, 12, 13, 14]);
    assert_eq!(non_finite, vec![20]);
}

#[test]
fn misuse_is_an_error_not_a_panic() {
    let mut sim = TouchXSim::holding(TouchXParams::default(), Vec3::zeros()).expect("script");
    assert_eq!(sim.read(0.0), Err(DeviceError::Start(0)));
    assert_eq!(sim.write_force(Vec3::x()), Err(DeviceError::Start(0)));
    sim.start().expect("start");
    sim.read(0.0).expect("read");
    sim.write_force(Vec3::x()).expect("write");
    assert_eq!(
        sim.write_force(Vec3::new(f64::NAN, 0.0, 0.0)),
        Err(DeviceError::BadData)
    );
    assert_eq!(
        sim.state().applied_force,
        Vec3::zeros(),
        "a non-finite command plays zero"
    );
    assert_eq!(sim.read(f64::INFINITY), Err(DeviceError::BadData));
    sim.stop();
    sim.stop();
}
