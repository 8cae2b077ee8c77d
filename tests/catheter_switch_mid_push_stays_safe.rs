//! A switch of the active instrument in the middle of a push (an extreme
//! of issue 37): the catheter service (the guidewire tests' branched arch,
//! a 5 F vertebral catheter over the wire) on the UDP bridge, a peer on
//! loopback sending a pose every millisecond as a stylus pushed in at
//! 10 mm/s, and pressing the switch button twice while it pushes (the
//! wire, then the catheter, then the wire again). Nothing goes non-finite,
//! neither rod goes more than 0.2 mm into the vessel's wall nor the wire
//! into the catheter's, no step is reset, the instrument not worked holds
//! its hub while the other advances, and the force the peer receives never
//! exceeds the passivity filter's peak and never changes faster than its
//! rate limit, around the presses and over the whole run from the start
//! (the datagrams and the loop's commanded force). Runs RT threads: run it
//! alone.

mod common;

use nvtmm::haptics::udp::{decode_force, encode_pose_v2, PoseDatagram};
use nvtmm::service::{Service, Snapshot, StartOptions};
use std::net::UdpSocket;
use std::time::{Duration, Instant};

/// The length of instrument `kind`'s polyline in `s` (m): its inserted
/// length, hub to tip.
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

#[test]
fn switching_the_active_instrument_mid_push_stays_finite_clamped_and_passive() {
    let dir = tempfile::tempdir().unwrap();
    let free = || {
        UdpSocket::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .to_string()
    };
    let (device, stream, hud) = (free(), free(), free());
    let base = common::guidewire::write_udp(dir.path(), &device, &stream, &hud);
    let cfg_text = std::fs::read_to_string(&base).unwrap()
        + r#"
[catheter]
shape = "vertebral"
french = 5.0
max_nodes = 96
inserted_m = 0.015
"#;
    let path = dir.path().join("switch.toml");
    std::fs::write(&path, cfg_text).unwrap();
    let cfg = nvtmm::service::config::ServiceConfig::load(&path).expect("the configuration loads");
    let wire = cfg.wire.as_ref().expect("[wire]");
    let inserted0 = cfg.guidewire.as_ref().expect("[guidewire]").inserted_m;
    // The stylus starts where the wire's hub is (the active instrument
    // follows the stylus's absolute position at the start).
    let start = wire.drive.stylus_at(inserted0);
    let axis = nvtmm::math::Vec3::from(wire.drive.axis).normalize();
    let (peak, rate) = (cfg.passivity.peak_force_n, cfg.passivity.rate_n_per_tick);

    let handle = Service::start(StartOptions::file(&path)).expect("the service starts");
    let peer = UdpSocket::bind("127.0.0.1:0").unwrap();
    peer.set_nonblocking(true).unwrap();
    // The stylus: still for 0.8 s, pushed at 10 mm/s for 1.5 s (the hub
    // at 10 mm/s times the insertion scale), the switch button pressed for
    // 50 ms at 1.3 s and at 1.8 s while it moves, then still.
    let speed = 0.01;
    let (push_from, push_to) = (0.8, 2.3);
    let presses = [1.3, 1.8];
    let mut forces: Vec<(u64, u64, [f64; 3])> = Vec::new();
    let mut sent_at: Vec<f64> = Vec::new();
    let mut snaps: Vec<(f64, Snapshot)> = Vec::new();
    let marks = [1.25, 1.4, 1.75, 1.9, 2.25];
    let mut next_mark = 0;
    let mut buf = [0u8; 128];
    let t0 = Instant::now();
    let mut seq = 0u64;
    loop {
        let t = t0.elapsed().as_secs_f64();
        if t > 2.8 {
            break;
        }
        let along = speed * (t.clamp(push_from, push_to) - push_from);
        let moving = t > push_from && t < push_to;
        let pressed = presses.iter().any(|&p| t >= p && t < p + 0.05);
        seq += 1;
        let pose = PoseDatagram {
            seq,
            device_time_s: t,
            position: (start + axis * along).into(),
            velocity: (axis * if moving { speed } else { 0.0 }).into(),
            buttons: pressed as u32,
            status: 0,
            error_code: 0,
            gimbal_rad: [0.0; 3],
        };
        peer.send_to(&encode_pose_v2(&pose), &device).unwrap();
        sent_at.push(t);
        while let Ok((n, _)) = peer.recv_from(&mut buf) {
            if let Ok(f) = decode_force(&buf[..n]) {
                forces.push((f.seq, f.pose_seq, f.force));
            }
        }
        if next_mark < marks.len() && t >= marks[next_mark] {
            snaps.push((t, handle.snapshot()));
            next_mark += 1;
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    let report = handle.stop().expect("the service stops");
    println!("{}", report.render());

    assert_eq!(report.instrument_switches, 2, "two presses of the switch button");
    // The instrument not worked holds: the catheter while the wire
    // advances before the first press, the wire while the catheter
    // advances between the presses, the catheter again after the second.
    let len: Vec<[f64; 2]> = snaps
        .iter()
        .map(|(_, s)| [length(s, "guidewire"), length(s, "catheter")])
        .collect();
    for (k, (t, _)) in snaps.iter().enumerate() {
        println!(
            "t {t:.2} s: wire {:.2} mm, catheter {:.2} mm",
            len[k][0] * 1e3,
            len[k][1] * 1e3
        );
    }
    assert!(
        len.iter().flatten().all(|l| l.is_finite()),
        "a polyline is missing or non-finite"
    );
    let advance = speed * wire.drive.insertion_scale * 0.35;
    let held = 1e-3;
    // Between the first press and the second (marks 1 and 2): the
    // catheter advances, the wire holds.
    assert!(
        (len[2][0] - len[1][0]).abs() < held,
        "the wire moved while held: {len:?}"
    );
    assert!(
        len[2][1] - len[1][1] > 0.5 * advance,
        "the catheter did not advance: {len:?}"
    );
    // After the second press (marks 3 and 4): the wire advances, the
    // catheter holds.
    assert!(
        (len[4][1] - len[3][1]).abs() < held,
        "the catheter moved while held: {len:?}"
    );
    assert!(
        len[4][0] - len[3][0] > 0.5 * advance,
        "the wire did not advance: {len:?}"
    );

    // The hand's force: finite, within the peak; its size grows no faster
    // than the passivity filter's rate limit anywhere; and around each
    // press (from 50 ms before to 150 ms after it) it changes, in any
    // direction, no faster than that limit. One force datagram a device
    // period, one loop tick a period (the device thread sends the newest
    // command once a period: where the loop and the device drift a tick
    // apart, one datagram's change spans two ticks).
    // Over the whole run, from the start (where the rods settle before any
    // push), neither the datagrams nor the loop's own figure
    // (`qp.command_change_max_n`, every tick's commanded force) change
    // faster than the limit (docs/INSTRUMENTS.md "The force while the gain
    // ramps in").
    assert!(forces.len() > 1000, "{} force datagrams", forces.len());
    let pose_time = |seq: u64| sent_at.get((seq as usize).wrapping_sub(1)).copied().unwrap_or(f64::NAN);
    let near_press = |seq: u64| presses.iter().any(|&p| (p - 0.05..p + 0.15).contains(&pose_time(seq)));
    let norm = |f: &[f64; 3]| (f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt();
    let (mut grow_most, mut near_most, mut any_most): (f64, f64, (f64, usize)) = (0.0, 0.0, (0.0, 0));
    for (k, w) in forces.windows(2).enumerate() {
        let ((n0, _, a), (n1, s1, b)) = (w[0], w[1]);
        assert!(a.iter().chain(&b).all(|c| c.is_finite()), "a non-finite force");
        assert!(norm(&b) <= peak + 1e-9, "force {b:?} above the peak {peak} N");
        let ticks = n1.saturating_sub(n0).max(1) as f64;
        let jump = norm(&[b[0] - a[0], b[1] - a[1], b[2] - a[2]]) / ticks;
        grow_most = grow_most.max((norm(&b) - norm(&a)) / ticks);
        if near_press(s1) {
            near_most = near_most.max(jump);
        }
        if jump > any_most.0 {
            any_most = (jump, k + 1);
        }
    }
    // The force at rest, before the push: what the rods' settling gives
    // the hand (printed every 100 ms).
    let mut next_print = 0.0;
    for (n, s, f) in &forces {
        let t = pose_time(*s);
        if t >= next_print && t < push_from {
            println!("  at rest, {t:.2} s (datagram {n}): |F| {:.3} N", norm(f));
            next_print = t + 0.1;
        }
    }
    let biggest = forces.iter().map(|(_, _, f)| norm(f)).fold(0.0, f64::max);
    let at = any_most.1;
    println!(
        "force: {biggest:.3} N at most; a tick's change at most {near_most:.3} N around the presses, \
         {:.3} N anywhere, its size's growth at most {grow_most:.3} N (limit {rate} N); the largest change:",
        any_most.0
    );
    for (n, s, f) in &forces[at.saturating_sub(2)..(at + 2).min(forces.len())] {
        println!("  force datagram {n} (pose {s} sent at {:.4} s): {f:?}", pose_time(*s));
    }
    assert!(
        near_most <= rate + 1e-6,
        "the force changed {near_most} N in a tick at a switch"
    );
    assert!(grow_most <= rate + 1e-6, "the force grew {grow_most} N in a tick");
    assert!(
        any_most.0 <= rate + 1e-6,
        "the force changed {} N in a tick (datagram {at})",
        any_most.0
    );
    println!(
        "the loop's commanded force: {:.4} N a tick at most over the whole run",
        report.qp.command_change_max_n
    );
    assert!(
        report.qp.command_change_max_n <= rate + 1e-6,
        "the commanded force changed {} N in a tick",
        report.qp.command_change_max_n
    );

    // Both rods stayed in their walls, finite, never reset.
    let w = report.wire.as_ref().expect("wire.*");
    let json = serde_json::to_value(&report).unwrap();
    let c = &json["instruments"][2]["keys"];
    let f = |k: &str| c[k].as_f64().unwrap_or_else(|| panic!("catheter key {k}: {}", c[k]));
    println!(
        "wire: axial force at most {:.3} N, {:.1} mm inserted at most; the wire on the catheter: \
         {:.0} N at most (normal, summed), {:.3} mm into its wall at most",
        w.axial_force_max_n,
        w.inserted_max_m * 1e3,
        f("coaxial_normal_force_max_n"),
        f("sheath_penetration_max_m") * 1e3
    );
    assert!(w.inserted_m.is_finite() && f("inserted_m").is_finite());
    assert!(
        w.max_penetration_m < 0.2e-3,
        "the wire {} m into the wall",
        w.max_penetration_m
    );
    assert!(
        f("max_penetration_m") < 0.2e-3,
        "the catheter {} m into the wall",
        f("max_penetration_m")
    );
    assert!(
        f("sheath_penetration_max_m") < 0.2e-3,
        "the wire {} m into the catheter",
        f("sheath_penetration_max_m")
    );
    assert_eq!(w.resets, 0, "the pair was reset");
    assert_eq!(json["instruments"][1]["faults"], 0, "the guidewire's faults");
    assert_eq!(json["instruments"][2]["faults"], 0, "the catheter's faults");
}
