//! A second device (a second UDP peer, `[device.second]`) drives the
//! catheter while the first drives the guidewire: the catheter service
//! (the guidewire tests' branched arch) with two peers on loopback, each
//! sending a pose every millisecond. The first pushes its stylus in while
//! the second holds still, then the second pushes while the first holds.
//! Each device's motion moves its own instrument only, the other holding;
//! the second device's instrument takes its stylus up where it is when it
//! connects (no jump); the switch button of the first device changes
//! nothing; each peer feels its own instrument's force: the second
//! peer's stylus is held 2 mm off the drive's axis and only it feels the
//! catheter's guide pulling it back. Both forces are finite and within the
//! passivity filter's peak, and nothing allocates after start. Runs RT
//! threads: run it alone.

mod common;

use nvtmm::haptics::udp::{decode_force, encode_pose_v2, PoseDatagram};
use nvtmm::math::Vec3;
use nvtmm::service::{Service, Snapshot, StartOptions};
use std::net::UdpSocket;
use std::path::Path;
use std::time::{Duration, Instant};

#[global_allocator]
static ALLOC: nvtmm::rt::alloc::RtAllocator = nvtmm::rt::alloc::RtAllocator;

fn length(s: &Snapshot, kind: &str) -> f64 {
    s.frame
        .as_ref()
        .and_then(|f| f.instruments.iter().find(|i| i.kind == kind))
        .map(|w| {
            w.points
                .windows(2)
                .map(|w| (0..3).map(|k| (w[1][k] - w[0][k]).powi(2)).sum::<f32>().sqrt() as f64)
                .sum::<f64>()
        })
        .unwrap_or(f64::NAN)
}

/// A peer on loopback sending poses to `to` and reading its forces.
struct Peer {
    socket: UdpSocket,
    to: String,
    seq: u64,
    forces: Vec<[f64; 3]>,
}

impl Peer {
    fn new(to: &str) -> Peer {
        let socket = UdpSocket::bind("127.0.0.1:0").unwrap();
        socket.set_nonblocking(true).unwrap();
        Peer {
            socket,
            to: to.into(),
            seq: 0,
            forces: Vec::new(),
        }
    }

    fn send(&mut self, t: f64, position: Vec3, velocity: Vec3, buttons: u32) {
        self.seq += 1;
        let pose = PoseDatagram {
            seq: self.seq,
            device_time_s: t,
            position: position.into(),
            velocity: velocity.into(),
            buttons,
            status: 0,
            error_code: 0,
            gimbal_rad: [0.0; 3],
        };
        self.socket.send_to(&encode_pose_v2(&pose), &self.to).unwrap();
        let mut buf = [0u8; 128];
        while let Ok((n, _)) = self.socket.recv_from(&mut buf) {
            if let Ok(f) = decode_force(&buf[..n]) {
                self.forces.push(f.force);
            }
        }
    }
}

#[test]
fn each_device_drives_its_own_instrument_and_feels_its_force() {
    let dir = tempfile::tempdir().unwrap();
    let free = || {
        UdpSocket::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .to_string()
    };
    let (device, device2, stream, hud) = (free(), free(), free(), free());
    let base = common::guidewire::write_udp(dir.path(), &device, &stream, &hud);
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let udp2 = std::fs::read_to_string(root.join("rt-config/udp_browser.toml"))
        .unwrap()
        .replace("127.0.0.1:47010", &device2);
    std::fs::write(dir.path().join("udp2.toml"), udp2).unwrap();
    let text = std::fs::read_to_string(&base).unwrap()
        + r#"
[catheter]
shape = "vertebral"
french = 5.0
max_nodes = 96
inserted_m = 0.015

[device.second]
udp = "udp2.toml"
instrument = "catheter"
"#;
    let path = dir.path().join("two_devices.toml");
    std::fs::write(&path, text).unwrap();
    let cfg = nvtmm::service::config::ServiceConfig::load(&path).expect("the configuration loads");
    let wire = cfg.wire.as_ref().expect("[wire]");
    let g = cfg.guidewire.as_ref().expect("[guidewire]");
    let axis = Vec3::from(wire.drive.axis).normalize();
    // The first stylus where the wire's hub is (it follows the stylus's
    // absolute position); the second anywhere on the workspace's axis
    // (its catheter takes it up where it is), 2 mm off it sideways.
    let start1 = wire.drive.stylus_at(g.inserted_m);
    let side = if axis.x.abs() < 0.9 { Vec3::x() } else { Vec3::y() };
    let off = (side - axis * side.dot(&axis)).normalize() * 2e-3;
    let start2 = wire.drive.stylus_at(0.06) + off;
    let peak = cfg.passivity.peak_force_n;

    let handle = Service::start(StartOptions::file(&path)).expect("the service starts");
    let (mut p1, mut p2) = (Peer::new(&device), Peer::new(&device2));
    let speed = 0.01;
    // The first pushes from 0.8 to 1.3 s (and presses its button at
    // 1.0 s), the second from 1.6 to 2.1 s.
    let pushed = |t: f64, from: f64| speed * (t.clamp(from, from + 0.5) - from);
    let moving = |t: f64, from: f64| t > from && t < from + 0.5;
    let marks = [0.7, 1.4, 1.5, 2.2];
    let mut snaps: Vec<Snapshot> = Vec::new();
    let t0 = Instant::now();
    loop {
        let t = t0.elapsed().as_secs_f64();
        if t > 2.5 {
            break;
        }
        let v = |m: bool| axis * if m { speed } else { 0.0 };
        let press = (1.0..1.05).contains(&t) as u32;
        p1.send(t, start1 + axis * pushed(t, 0.8), v(moving(t, 0.8)), press);
        p2.send(t, start2 + axis * pushed(t, 1.6), v(moving(t, 1.6)), 0);
        if snaps.len() < marks.len() && t >= marks[snaps.len()] {
            snaps.push(handle.snapshot());
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    let report = handle.stop().expect("the service stops");
    println!("{}", report.render());

    let len: Vec<[f64; 2]> = snaps
        .iter()
        .map(|s| [length(s, "guidewire"), length(s, "catheter")])
        .collect();
    for (m, l) in marks.iter().zip(&len) {
        println!("t {m:.1} s: wire {:.2} mm, catheter {:.2} mm", l[0] * 1e3, l[1] * 1e3);
    }
    assert!(
        len.iter().flatten().all(|l| l.is_finite()),
        "a polyline is missing: {len:?}"
    );
    let advance = speed * wire.drive.insertion_scale * 0.5;
    // The first device moves the wire; the catheter holds where it
    // started (the second stylus, still, did not move it).
    assert!(
        len[1][0] - len[0][0] > 0.8 * advance,
        "the wire did not follow the first device: {len:?}"
    );
    assert!(
        (len[1][1] - len[0][1]).abs() < 1e-3,
        "the catheter moved with the first device: {len:?}"
    );
    // The second device moves the catheter; the wire holds.
    assert!(
        len[3][1] - len[2][1] > 0.8 * advance,
        "the catheter did not follow the second device: {len:?}"
    );
    assert!(
        (len[3][0] - len[2][0]).abs() < 1e-3,
        "the wire moved with the second device: {len:?}"
    );
    assert_eq!(
        report.instrument_switches, 0,
        "the switch button with one instrument a device"
    );

    // Each feels its own instrument: only the second is pulled back to the
    // catheter's axis (its stylus 2 mm off it, the guide's spring).
    let sideways = |f: &[f64; 3]| Vec3::from(*f).dot(&off.normalize());
    let mean_side = |fs: &[[f64; 3]]| {
        let tail = &fs[fs.len() / 2..];
        tail.iter().map(sideways).sum::<f64>() / tail.len().max(1) as f64
    };
    assert!(
        p1.forces.len() > 1000 && p2.forces.len() > 1000,
        "force datagrams: {} and {}",
        p1.forces.len(),
        p2.forces.len()
    );
    for f in p1.forces.iter().chain(&p2.forces) {
        assert!(f.iter().all(|c| c.is_finite()), "a non-finite force");
        assert!(
            Vec3::from(*f).norm() <= peak + 1e-9,
            "force {f:?} above the peak {peak} N"
        );
    }
    let (s1, s2) = (mean_side(&p1.forces), mean_side(&p2.forces));
    let guide = wire.drive.guide_stiffness_n_per_m * off.norm();
    println!("sideways force: first device {s1:.3} N, second {s2:.3} N (the guide: {guide:.3} N toward the axis)");
    assert!(
        s2 < -0.5 * guide,
        "the second device does not feel its catheter's guide: {s2} N"
    );
    assert!(
        s1.abs() < 0.1 * guide,
        "the first device feels the catheter's guide: {s1} N"
    );

    let d2 = report.second_device.as_ref().expect("second_device.* keys");
    assert_eq!(d2.instrument, "catheter");
    assert!(d2.device_ticks > 1000, "{} periods", d2.device_ticks);
    let w = report.wire.as_ref().expect("wire.*");
    assert_eq!(w.resets, 0);
    assert!(
        w.max_penetration_m < 0.2e-3,
        "the wire {} m into the wall",
        w.max_penetration_m
    );
    assert!(report.allocator_installed);
    assert_eq!(report.allocations_after_start, 0, "loop + devices + pair allocations");
}
