//! The shipped device configurations load, and a bad one is refused with a
//! message naming the file, the key and the allowed range.

use nvtmm::haptics::touchx::TouchXParams;
use nvtmm::haptics::udp::UdpParams;
use std::path::Path;

fn touchx_text() -> String {
    std::fs::read_to_string("rt-config/touchx.toml").expect("rt-config/touchx.toml exists")
}

#[test]
fn shipped_device_configs_load() {
    let p = TouchXParams::load(Path::new("rt-config/touchx.toml")).expect("touchx.toml is valid");
    assert_eq!(p, TouchXParams::default(), "the file and Default agree");
    let u = UdpParams::load(Path::new("rt-config/udp_device.toml")).expect("udp_device.toml is valid");
    assert_eq!(u, UdpParams::default(), "the file and Default agree");
    assert!(u.bind.starts_with("127.0.0.1:"), "loopback by default");
}

#[test]
fn touchx_errors_name_file_key_and_range() {
    let path = Path::new("rt-config/touchx.toml");
    let text = touchx_text().replace("peak_force_n = 7.9", "peak_force_n = -3.0");
    let e = TouchXParams::from_toml_str(&text, path).expect_err("negative peak force");
    assert_eq!(e.key, "peak_force_n");
    let msg = e.to_string();
    assert!(
        msg.starts_with("rt-config/touchx.toml: peak_force_n: -3: must be in [0.1, 100] N"),
        "{msg}"
    );

    let text = touchx_text().replace("continuous_force_n = 1.75", "continuous_force_n = 9.0");
    let e = TouchXParams::from_toml_str(&text, path).expect_err("continuous above peak");
    assert_eq!(e.key, "continuous_force_n");
    assert!(e.msg.contains("peak_force_n"), "{e}");

    let text = touchx_text().replace("workspace_m = [0.160,", "workspace_m = [0.0,");
    let e = TouchXParams::from_toml_str(&text, path).expect_err("zero workspace");
    assert_eq!(e.key, "workspace_m[0]");

    let text = touchx_text()
        .replace("hand_stiffness_n_per_m = 300.0", "hand_stiffness_n_per_m = 90000.0")
        .replace("substep_hz = 10000.0", "substep_hz = 1000.0");
    let e = TouchXParams::from_toml_str(&text, path).expect_err("unstable hand");
    assert_eq!(e.key, "hand_stiffness_n_per_m");
    assert!(e.msg.contains("substep_hz"), "{e}");

    let text = format!("{}\nbogus_key = 1\n", touchx_text());
    let e = TouchXParams::from_toml_str(&text, path).expect_err("unknown key");
    assert_eq!(e.key, "bogus_key", "an unknown key is named: {e}");
    assert!(e.msg.contains("unknown field"), "{e}");

    let text = touchx_text().replace("thermal_tau_s = 10.0", "");
    let e = TouchXParams::from_toml_str(&text, path).expect_err("missing key");
    assert!(e.msg.contains("thermal_tau_s"), "{e}");
}

#[test]
fn udp_errors_name_file_key_and_range() {
    let path = Path::new("rt-config/udp_device.toml");
    let text = std::fs::read_to_string(path).expect("udp_device.toml exists");
    let bad = text.replace("bind = \"127.0.0.1:47010\"", "bind = \"localhost\"");
    let e = UdpParams::from_toml_str(&bad, path).expect_err("bad bind");
    assert_eq!(e.key, "bind");
    let bad = text.replace("max_age_s = 0.005", "max_age_s = 0.0");
    let e = UdpParams::from_toml_str(&bad, path).expect_err("zero age");
    assert_eq!(e.key, "max_age_s");
    assert!(e.to_string().contains("must be in [0.0001, 1] s"), "{e}");
    let p = UdpParams {
        workspace_max_m: [0.08, -0.07, 0.06],
        ..UdpParams::default()
    };
    let e = p
        .validate(Path::new("rt-config/service.toml"), "device.udp.")
        .expect_err("inverted box");
    assert_eq!(e.key, "device.udp.workspace_max_m[1]");
}
