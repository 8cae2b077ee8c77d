//! The simulated Touch X scripts the stylus's gimbal angles: a scripted roll
//! is reported wrapped to (−π, π] and quantized to the gimbal resolution, the
//! hub drive unwraps it back to the scripted turns, a NaN sample carries NaN
//! angles, and a bad gimbal script is refused.

use nvtmm::haptics::device::{wrap_angle, GIMBAL_ROLL};
use nvtmm::haptics::touchx::{GimbalWaypoint, ScriptError, TouchXParams, TouchXSim};
use nvtmm::haptics::HapticDevice;
use nvtmm::math::Vec3;
use nvtmm::wire::drive::{DriveParams, HubDrive};
use nvtmm::wire::WireParams;
use std::f64::consts::PI;

fn roll_to(t_s: f64, roll: f64) -> GimbalWaypoint {
    GimbalWaypoint {
        t_s,
        angles_rad: [0.1, -0.2, roll],
    }
}

#[test]
fn a_scripted_roll_is_reported_wrapped_and_quantized_and_unwraps_to_the_script() {
    let params = TouchXParams::default();
    let res = params.gimbal_resolution_rad;
    assert!((res - 2.0 * PI / 4096.0).abs() < 1e-18, "12 bits a turn by default");
    let mut sim = TouchXSim::holding(params, Vec3::zeros()).expect("sim");
    // Two full turns and a quarter in 2 s, then back by one turn.
    let turns = 2.0 * PI * 2.25;
    sim.set_gimbal_script(&[roll_to(0.5, 0.0), roll_to(2.5, turns), roll_to(3.5, turns - 2.0 * PI)])
        .expect("script");
    sim.start().expect("start");
    let drive_params = DriveParams {
        max_roll_speed_rad_s: 1000.0,
        ..DriveParams::default()
    };
    let wire = WireParams {
        drive: drive_params,
        ..WireParams::default()
    };
    let mut drive = HubDrive::new(&wire, 0.18, 0.0).expect("drive");
    let mut crossings = 0;
    let mut prev = 0.0;
    let mut worst: f64 = 0.0;
    for i in 0..=4000 {
        let t = i as f64 * 1e-3;
        let s = sim.read(t).expect("read");
        let truth = sim.state().gimbal_rad;
        let r = s.gimbal_rad[GIMBAL_ROLL];
        assert!(r > -PI && r <= PI, "reported in (−π, π]: {r}");
        assert!(s.is_valid());
        // Quantized: a multiple of the resolution (up to the wrap), within
        // half a step of the true angle.
        let steps = r / res;
        assert!((steps - steps.round()).abs() < 1e-6, "{r} is not a multiple of {res}");
        let err = wrap_angle(r - truth[GIMBAL_ROLL]).abs();
        worst = worst.max(err);
        assert!(err <= 0.5 * res + 1e-12, "t = {t}: {r} vs {}", truth[2]);
        assert!((s.gimbal_rad[0] - 0.1).abs() <= 0.5 * res && (s.gimbal_rad[1] + 0.2).abs() <= 0.5 * res);
        if (r - prev).abs() > PI {
            crossings += 1;
        }
        prev = r;
        let c = drive.command(&s, t);
        assert!(
            (c.roll_rad - truth[GIMBAL_ROLL]).abs() <= 0.5 * res + 1e-9,
            "t = {t}: the drive unwraps {} vs the script's {}",
            c.roll_rad,
            truth[2]
        );
    }
    assert!((sim.state().gimbal_rad[GIMBAL_ROLL] - (turns - 2.0 * PI)).abs() < 1e-12);
    // Up 2.25 turns from 0 crosses ±π twice, back one turn once more.
    assert_eq!(crossings, 3);
    println!("worst quantization error {worst:.3e} rad (resolution {res:.3e} rad)");
}

#[test]
fn without_a_script_the_angles_are_zero_and_a_nan_sample_carries_nan_angles() {
    let mut sim = TouchXSim::holding(TouchXParams::default(), Vec3::zeros()).expect("sim");
    sim.inject_non_finite(0.01);
    sim.start().expect("start");
    let s = sim.read(0.0).expect("read");
    assert_eq!(s.gimbal_rad, [0.0; 3]);
    let s = sim.read(0.01).expect("read");
    assert!(s.gimbal_rad.iter().all(|a| a.is_nan()) && !s.is_valid());
    // Unquantized when the resolution is 0.
    let p = TouchXParams {
        gimbal_resolution_rad: 0.0,
        ..TouchXParams::default()
    };
    let mut sim = TouchXSim::holding(p, Vec3::zeros()).expect("sim");
    sim.set_gimbal_script(&[roll_to(0.0, 0.123456789)]).expect("script");
    sim.start().expect("start");
    assert_eq!(sim.read(0.0).expect("read").roll_rad(), 0.123456789);
}

#[test]
fn bad_gimbal_scripts_are_refused() {
    let mut sim = TouchXSim::holding(TouchXParams::default(), Vec3::zeros()).expect("sim");
    assert_eq!(sim.set_gimbal_script(&[]), Err(ScriptError::Empty));
    assert_eq!(
        sim.set_gimbal_script(&[roll_to(0.0, 0.0), roll_to(f64::NAN, 0.0)]),
        Err(ScriptError::NonFinite(1))
    );
    assert_eq!(
        sim.set_gimbal_script(&[roll_to(0.0, f64::INFINITY)]),
        Err(ScriptError::NonFinite(0))
    );
    assert_eq!(
        sim.set_gimbal_script(&[roll_to(1.0, 0.0), roll_to(1.0, 1.0)]),
        Err(ScriptError::NotIncreasing(1))
    );
}

#[test]
fn gimbal_resolution_errors_name_the_key() {
    let text = std::fs::read_to_string("rt-config/touchx.toml").expect("touchx.toml");
    let path = std::path::Path::new("rt-config/touchx.toml");
    let p = TouchXParams::from_toml_str(&text, path).expect("shipped file");
    assert_eq!(p, TouchXParams::default());
    // Older files without the key still load, with the default.
    let old: String = text
        .lines()
        .filter(|l| !l.starts_with("gimbal_resolution_rad"))
        .collect::<Vec<_>>()
        .join("\n");
    assert_eq!(TouchXParams::from_toml_str(&old, path).expect("old file"), p);
    let bad = format!("{old}\ngimbal_resolution_rad = 0.5\n");
    let e = TouchXParams::from_toml_str(&bad, path).expect_err("too coarse");
    assert_eq!(e.key, "gimbal_resolution_rad");
    assert!(e.msg.contains("[0, 0.1] rad"), "{e}");
}
