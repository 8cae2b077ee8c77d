//! The device-to-scene map takes an OpenHaptics reading (y up, millimetres)
//! to the scene (SI, any orientation) and back, preserves power (force ·
//! velocity) so passivity carries over, reduces to the old `device.origin_m`
//! translation, and refuses bad configurations naming the key and the range.

use nvtmm::config::parse_toml;
use nvtmm::haptics::frame::{DeviceFrame, DeviceFrameParams, HD_LENGTH_M};
use nvtmm::haptics::DeviceSample;
use nvtmm::math::Vec3;
use std::path::Path;

#[test]
fn an_openhaptics_reading_in_mm_y_up_round_trips_through_the_scene_in_m() {
    // The scene is z-up; the device sits 2x-scaled with its origin at the arch top.
    let params = DeviceFrameParams {
        rotation_deg: [90.0, 0.0, 0.0],
        offset_m: [0.0065, -0.031, 0.177],
        scale: 2.0,
    };
    params.validate(Path::new("x.toml"), "device.frame.").expect("valid");
    let f = DeviceFrame::new(&params);
    // Raw HD reading: 12.5 mm right, 40 mm up, 30 mm away from the user (−z).
    let hd_mm = Vec3::new(12.5, 40.0, -30.0);
    let p_dev = hd_mm * HD_LENGTH_M; // what a backend reports (m, device axes)
    let q = f.point_to_scene(p_dev);
    // Device up (y) is scene up (z); device toward-the-user (+z) is scene −y.
    let want = Vec3::new(0.0065 + 2.0 * 0.0125, -0.031 + 2.0 * 0.030, 0.177 + 2.0 * 0.040);
    assert!((q - want).norm() < 1e-15, "{q:?} vs {want:?}");
    let back_mm = f.point_to_device(q) / HD_LENGTH_M;
    assert!((back_mm - hd_mm).norm() < 1e-12, "{back_mm:?}");
    // A sample maps position and velocity, and keeps the gimbal angles.
    let s = DeviceSample {
        position: p_dev,
        velocity: Vec3::new(0.0, 0.1, 0.0),
        gimbal_rad: [0.1, 0.2, 0.3],
        ..DeviceSample::REST
    };
    let t = f.sample_to_scene(&s);
    assert_eq!(t.position, q);
    assert!((t.velocity - Vec3::new(0.0, 0.0, 0.2)).norm() < 1e-15);
    assert_eq!(t.gimbal_rad, s.gimbal_rad);
}

#[test]
fn any_rotation_round_trips_and_preserves_power() {
    let mut seed = 12345u64;
    let mut rnd = || {
        seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (seed >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
    };
    for _ in 0..200 {
        let params = DeviceFrameParams {
            rotation_deg: [360.0 * rnd(), 360.0 * rnd(), 360.0 * rnd()],
            offset_m: [rnd(), rnd(), rnd()],
            scale: 10f64.powf(2.0 * rnd()),
        };
        params.validate(Path::new("x.toml"), "").expect("valid");
        let f = DeviceFrame::new(&params);
        let p = Vec3::new(rnd(), rnd(), rnd()) * 0.1;
        let v = Vec3::new(rnd(), rnd(), rnd());
        let force = Vec3::new(rnd(), rnd(), rnd()) * 5.0;
        assert!((f.point_to_device(f.point_to_scene(p)) - p).norm() < 1e-12);
        assert!((f.vector_to_device(f.vector_to_scene(v)) - v).norm() < 1e-12);
        assert!((f.force_to_scene(f.force_to_device(force)) - force).norm() < 1e-12);
        // The power the scene asks of the hand is the power the device renders.
        let p_scene = force.dot(&f.vector_to_scene(v));
        let p_dev = f.force_to_device(force).dot(&v);
        assert!(
            (p_scene - p_dev).abs() < 1e-12 * (1.0 + p_scene.abs()),
            "{p_scene} vs {p_dev}"
        );
        let r = f.rotation();
        assert!((r.determinant() - 1.0).abs() < 1e-12, "a proper rotation");
    }
}

#[test]
fn the_identity_rotation_is_the_old_origin_translation() {
    let o = Vec3::new(0.0065, -0.031, 0.177);
    let f = DeviceFrame::translation(o);
    let g = DeviceFrame::new(&DeviceFrameParams {
        offset_m: [o.x, o.y, o.z],
        ..DeviceFrameParams::default()
    });
    for p in [Vec3::new(0.01, -0.02, 0.03), Vec3::new(-0.07, 0.05, -0.055)] {
        assert_eq!(f.point_to_scene(p), p + o, "bit for bit what device.origin_m did");
        assert_eq!(g.point_to_scene(p), p + o);
        assert_eq!(f.force_to_device(p), p, "forces unchanged");
    }
    assert_eq!(DeviceFrame::default(), DeviceFrame::identity());
}

#[test]
fn frame_config_errors_name_the_key_and_the_range() {
    let path = Path::new("rt-config/nvtmm.toml");
    let parse = |text: &str| -> DeviceFrameParams { parse_toml(text, path).expect("parses") };
    let p = parse("rotation_deg = [90.0, 0.0, -45.0]\noffset_m = [0.0, 0.1, 0.2]\nscale = 1.5");
    p.validate(path, "device.frame.").expect("valid");
    assert_eq!(parse(""), DeviceFrameParams::default(), "every key has a default");
    let cases = [
        ("scale = 0.0", "device.frame.scale", "[0.01, 100]"),
        ("scale = nan", "device.frame.scale", "[0.01, 100]"),
        (
            "rotation_deg = [0.0, 400.0, 0.0]",
            "device.frame.rotation_deg[1]",
            "[-360, 360] degrees",
        ),
        ("offset_m = [0.0, 0.0, 11.0]", "device.frame.offset_m[2]", "[-10, 10] m"),
    ];
    for (text, key, range) in cases {
        let e = parse(text).validate(path, "device.frame.").expect_err(text);
        assert_eq!(e.key, key, "{e}");
        let msg = e.to_string();
        assert!(msg.starts_with("rt-config/nvtmm.toml: device.frame."), "{msg}");
        assert!(msg.contains(range), "{text}: {msg} lacks {range}");
    }
    let e = parse_toml::<DeviceFrameParams>("rotation = [0.0, 0.0, 0.0]", path).expect_err("unknown key");
    assert!(e.msg.contains("rotation"), "{e}");
}
