//! A wire configuration with impossible values is refused with an error
//! naming the key and the allowed range; the defaults are valid.

use nvtmm::math::Vec3;
use nvtmm::wire::{Wire, WireError, WireParams};
use std::path::Path;

#[test]
fn defaults_are_valid() {
    let p = WireParams::default();
    p.validate(Path::new("x.toml")).expect("defaults");
    assert_eq!(p.diameter_m, 0.89e-3);
    assert_eq!(p.max_nodes, 128);
    assert_eq!(p.friction, 0.1);
    let w = Wire::new(&p, Vec3::zeros(), Vec3::x(), 0.1).expect("wire");
    assert!(w.num_nodes() <= 128);
    // The text form round-trips.
    let text = toml::to_string(&p).expect("toml");
    assert_eq!(WireParams::from_toml_str(&text, Path::new("w.toml")).expect("parse"), p);
}

#[test]
fn impossible_values_name_the_key_and_the_range() {
    let path = Path::new("rt-config/guidewire.toml");
    let cases: [(&str, &str, &str); 14] = [
        (
            "youngs_modulus_pa = -5.0",
            "youngs_modulus_pa",
            "[10000, 1000000000000] Pa",
        ),
        ("diameter_m = 0.0", "diameter_m", "[0.00001, 0.01] m"),
        ("poisson_ratio = 0.7", "poisson_ratio", "[0, 0.5]"),
        ("friction = -0.1", "friction", "[0, 2]"),
        (
            "friction_smoothing_m = 0.0",
            "friction_smoothing_m",
            "[0.000000001, 0.001] m",
        ),
        ("max_nodes = 2", "max_nodes", "4..=4096"),
        ("contact_onset_m = 0.001", "contact_onset_m", "[0, 0.000089] m"),
        ("residual_tolerance_n = -1.0", "residual_tolerance_n", "[0, 1000] N"),
        (
            "residual_time_limit_us = 2000.0",
            "residual_time_limit_us",
            "[0, 1000] µs",
        ),
        ("max_evaluations = 2", "max_evaluations", "3..=10000"),
        ("density_kg_m3 = nan", "density_kg_m3", "[1, 30000] kg/m³"),
        ("tip_stiffness_factor = 0.0", "tip_stiffness_factor", "[0.0001, 10]"),
        ("dt_s = 1.0", "dt_s", "[0.000001, 0.01] s"),
        ("segment_length_m = 0.0005", "segment_length_m", "at least diameter_m"),
    ];
    for (line, key, range) in cases {
        let e = WireParams::from_toml_str(line, path).expect_err(line);
        assert_eq!(e.key, key, "{line}: {e}");
        let msg = e.to_string();
        assert!(msg.starts_with("rt-config/guidewire.toml: "), "{msg}");
        assert!(msg.contains(range), "{line}: {msg} lacks {range}");
    }
    // Unknown keys are refused too.
    let e = WireParams::from_toml_str("stiffnes = 3.0", path).expect_err("unknown key");
    assert!(e.msg.contains("stiffnes"), "{e}");
    // The wire itself refuses bad values the same way.
    let p = WireParams {
        friction: 3.0,
        ..WireParams::default()
    };
    match Wire::new(&p, Vec3::zeros(), Vec3::x(), 0.1) {
        Err(WireError::Config(e)) => assert_eq!(e.key, "friction"),
        other => panic!("{other:?}"),
    }
    assert!(matches!(
        Wire::new(&WireParams::default(), Vec3::zeros(), Vec3::zeros(), 0.1),
        Err(WireError::Hub(_))
    ));
}

#[test]
fn drive_errors_name_the_key_and_the_range() {
    let path = Path::new("rt-config/guidewire.toml");
    // A [drive] table (`[wire.drive]` in a service file) with every key.
    let text = "friction = 0.1\n[drive]\naxis = [0.0, 0.0, -1.0]\norigin_m = [0.0, 0.0, 0.0]\n\
                inserted_at_origin_m = 0.2\ninsertion_scale = 2.5\nmax_speed_m_s = 0.1\nroll_index = 2\n\
                roll_scale = -1.0\nmax_roll_speed_rad_s = 6.0\nforce_scale = 1.0\n\
                guide_stiffness_n_per_m = 300.0\nguide_damping_ns_per_m = 2.0\nmax_force_n = 4.0\n";
    let p = WireParams::from_toml_str(text, path).expect("a full drive table");
    assert_eq!(p.drive.insertion_scale, 2.5);
    assert_eq!(p.drive.roll_scale, -1.0);
    let cases: [(&str, &str, &str); 8] = [
        ("[drive]\naxis = [0.0, 0.0, 0.0]", "drive.axis", "non-zero vector"),
        ("[drive]\naxis = [nan, 0.0, 1.0]", "drive.axis[0]", "[-1000, 1000]"),
        ("[drive]\ninsertion_scale = 0.0", "drive.insertion_scale", "[0.1, 100]"),
        ("[drive]\nmax_speed_m_s = 0.0", "drive.max_speed_m_s", "[0.001, 10] m/s"),
        ("[drive]\nroll_index = 3", "drive.roll_index", "0..=2"),
        (
            "[drive]\nforce_scale = 4.0",
            "drive.force_scale",
            "[0, 3] (≤ insertion_scale, so the map adds no energy)",
        ),
        (
            "[drive]\nguide_stiffness_n_per_m = -1.0",
            "drive.guide_stiffness_n_per_m",
            "[0, 5000] N/m",
        ),
        ("[drive]\nmax_force_n = 1000.0", "drive.max_force_n", "[0, 100] N"),
    ];
    for (text, key, range) in cases {
        let e = WireParams::from_toml_str(text, path).expect_err(text);
        assert_eq!(e.key, key, "{text}: {e}");
        let msg = e.to_string();
        assert!(msg.starts_with("rt-config/guidewire.toml: drive."), "{msg}");
        assert!(msg.contains(range), "{text}: {msg} lacks {range}");
    }
    let e = WireParams::from_toml_str("[drive]\naxes = [0.0, 0.0, 1.0]", path).expect_err("unknown key");
    assert!(e.msg.contains("axes"), "{e}");
    // The drive itself refuses an invalid table the same way.
    let p = WireParams {
        drive: nvtmm::wire::DriveParams {
            roll_scale: 20.0,
            ..Default::default()
        },
        ..WireParams::default()
    };
    let e = nvtmm::wire::HubDrive::new(&p, 0.1, 0.0).expect_err("bad roll scale");
    assert_eq!(e.key, "drive.roll_scale");
}
