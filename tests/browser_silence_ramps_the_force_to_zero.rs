//! The browser as the device falls silent: the guidewire service on the UDP
//! bridge (the guidewire tests' branched arch), the view server's drive
//! server in process fed drive messages as the page sends them, the wire
//! inserted for 2 s against the wall's friction, then nothing. The drive
//! server stops its poses after its browser timeout; the service's force,
//! counted in its force datagrams (one per device period) from the last
//! pose it read, must reach exactly zero within the device timeout plus
//! 10 periods (10 ms), and stay there; the wire is held (its insertion does
//! not change while silent). Runs RT threads: run it alone.

mod common;

use nvtmm::service::{Service, StartOptions};
use nvtmm::stream::drive::{DriveServer, DriveSetup, BROWSER_TIMEOUT_S};
use std::net::UdpSocket;
use std::time::{Duration, Instant};

#[test]
fn silence_from_the_browser_ramps_the_force_to_zero_and_holds_the_wire() {
    let dir = tempfile::tempdir().unwrap();
    let free = || {
        UdpSocket::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .to_string()
    };
    let (device, stream, hud) = (free(), free(), free());
    let path = common::guidewire::write_udp(dir.path(), &device, &stream, &hud);
    let cfg = nvtmm::service::config::ServiceConfig::load(&path).unwrap();
    let timeout_ms = cfg.watchdog.device_timeout_ms;
    let setup = DriveSetup::from_service(&cfg, None).unwrap();
    let handle = Service::start(StartOptions::file(&path)).expect("the service starts");
    let drive = DriveServer::start(setup).unwrap();
    assert!(drive.connect());
    // Insert for 2 s at full speed, a message every 40 ms as the page does.
    let t0 = Instant::now();
    let mut seq = 0;
    while t0.elapsed() < Duration::from_secs(3) {
        seq += 1;
        let insert = if t0.elapsed() > Duration::from_secs(1) {
            1.0
        } else {
            0.0
        };
        drive
            .handle_text(&format!(
                r#"{{"seq":{seq},"insert":{insert},"roll":0,"insert_step_m":0,"roll_step_rad":0,"buttons":0}}"#
            ))
            .unwrap();
        std::thread::sleep(Duration::from_millis(40));
    }
    let driven = drive.status();
    assert!(driven.sending);
    println!(
        "driven to {:.1} mm, force now {:?} N",
        driven.inserted_m * 1e3,
        driven.force_n
    );
    // Silence.
    std::thread::sleep(Duration::from_secs_f64(BROWSER_TIMEOUT_S + 0.5));
    let (last_pose, zero_at, fig) = drive.silence_timing();
    let held = handle.snapshot();
    std::thread::sleep(Duration::from_millis(300));
    let later = handle.snapshot();
    let report = handle.stop().expect("the service stops");
    println!("{}", report.render());
    let st = drive.status();
    assert!(!st.sending, "poses still going out after the silence");
    assert_eq!(st.counters.silences, 1);
    assert!(fig.force_peak_n > 0.0, "no force came back while driving: {fig:?}");
    let periods = fig.periods_to_zero.expect("the force came back zero after the silence");
    let wall_ms = match (last_pose, zero_at) {
        (Some(a), Some(b)) => (b - a).as_secs_f64() * 1e3,
        _ => f64::NAN,
    };
    println!(
        "silence: force zero {periods} device periods after the last pose ({wall_ms:.1} ms by the view server's clock), \
         device timeout {timeout_ms} ms, force peak while driving {:.3} N",
        fig.force_peak_n
    );
    assert!(
        periods as f64 <= timeout_ms + 10.0,
        "the force reached zero {periods} periods after the last pose (device timeout {timeout_ms} ms + 10)"
    );
    assert_eq!(st.force_n, [0.0; 3], "the force is zero while silent");
    // The wire is held: its inserted length (the stream's polyline) does not change.
    let len = |s: &nvtmm::service::Snapshot| {
        s.frame
            .as_ref()
            .and_then(|f| f.instruments.iter().find(|i| i.kind == "guidewire"))
            .map(|w| {
                w.points
                    .windows(2)
                    .map(|w| (0..3).map(|k| (w[1][k] - w[0][k]).powi(2)).sum::<f32>().sqrt() as f64)
                    .sum::<f64>()
            })
            .unwrap_or(f64::NAN)
    };
    let (a, b) = (len(&held), len(&later));
    println!("inserted (polyline) while silent: {:.2} → {:.2} mm", a * 1e3, b * 1e3);
    assert!(a > 0.03, "the wire was inserted: {a} m");
    assert!((a - b).abs() < 1e-4, "the wire moved while silent: {a} → {b} m");
    assert_eq!(report.wire.as_ref().map(|w| w.resets), Some(0));
}
