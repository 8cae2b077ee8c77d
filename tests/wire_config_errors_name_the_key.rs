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
    let cases: [(&str, &str, &str); 9] = [
        (
            "youngs_modulus_pa = -5.0",
            "youngs_modulus_pa",
            "[10000, 1000000000000] Pa",
        ),
        ("diameter_m = 0.0", "diameter_m", "[0.00001, 0.01] m"),
        ("poisson_ratio = 0.7", "poisson_ratio", "[0, 0.5]"),
        ("friction = -0.1", "friction", "[0, 2]"),
        ("max_nodes = 2", "max_nodes", "4..=4096"),
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
