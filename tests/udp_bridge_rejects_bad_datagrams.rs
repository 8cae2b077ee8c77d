//! The UDP bridge never panics on any bytes, rejects malformed, out-of-range,
//! out-of-order and stale poses and counts them by reason, and round-trips
//! poses and forces with a peer thread on loopback.

use nvtmm::haptics::udp::{
    decode_force, decode_pose, encode_force, encode_pose, encode_pose_v2, ForceDatagram, PoseDatagram, Reject,
    UdpDevice, UdpParams, FLAG_SATURATED, FLAG_STOP, FORCE_LEN, POSE_LEN, POSE_LEN_V2, STATUS_FAULT,
};
use nvtmm::haptics::{DeviceError, HapticDevice};
use nvtmm::math::Vec3;
use proptest::prelude::*;
use std::net::{SocketAddr, UdpSocket};
use std::time::Duration;

fn pose(seq: u64, x: f64) -> PoseDatagram {
    PoseDatagram {
        seq,
        device_time_s: seq as f64 * 1e-3,
        position: [x, 0.01, -0.02],
        velocity: [0.1, 0.0, 0.0],
        buttons: 1,
        status: 0,
        error_code: 0,
        gimbal_rad: [0.0; 3],
    }
}

fn bridge(max_age_s: f64) -> (UdpDevice, SocketAddr) {
    let p = UdpParams {
        bind: "127.0.0.1:0".into(),
        max_age_s,
        ..UdpParams::default()
    };
    let mut d = UdpDevice::new(p);
    d.start().expect("bind on loopback");
    let addr = d.local_addr().expect("bound");
    (d, addr)
}

/// Reads until `done` says the datagrams sent so far have all been seen
/// (loopback delivery is not synchronous with `send_to`). Waits for
/// arrival, not for a deadline: the bound only stops a broken test.
fn read_until(
    d: &mut UdpDevice,
    now_s: f64,
    done: impl Fn(&UdpDevice) -> bool,
) -> Result<nvtmm::haptics::DeviceSample, DeviceError> {
    let mut r = d.read(now_s);
    for _ in 0..5000 {
        if done(d) {
            break;
        }
        std::thread::sleep(Duration::from_millis(1));
        r = d.read(now_s);
    }
    r
}

proptest! {
    #[test]
    fn decoders_never_panic_on_any_bytes(bytes in proptest::collection::vec(any::<u8>(), 0..200)) {
        let _ = decode_pose(&bytes);
        let _ = decode_force(&bytes);
    }

    #[test]
    fn any_body_with_a_valid_header_decodes_or_is_non_finite(body in proptest::collection::vec(any::<u8>(), POSE_LEN - 8)) {
        let mut b = encode_pose(&pose(1, 0.0)).to_vec();
        b[8..].copy_from_slice(&body);
        match decode_pose(&b) {
            Ok(d) => prop_assert!(d.position.iter().chain(&d.velocity).all(|v| v.is_finite())),
            Err(r) => prop_assert_eq!(r, Reject::NonFinite),
        }
    }

    #[test]
    fn any_v2_body_with_a_valid_header_decodes_or_is_non_finite(body in proptest::collection::vec(any::<u8>(), POSE_LEN_V2 - 8)) {
        let mut b = encode_pose_v2(&pose(1, 0.0)).to_vec();
        b[8..].copy_from_slice(&body);
        match decode_pose(&b) {
            Ok(d) => prop_assert!(d.position.iter().chain(&d.velocity).chain(&d.gimbal_rad).all(|v| v.is_finite())),
            Err(r) => prop_assert_eq!(r, Reject::NonFinite),
        }
    }

    #[test]
    fn finite_v2_datagrams_round_trip(seq in any::<u64>(), x in -1.0f64..1.0, a in proptest::array::uniform3(-7.0f64..7.0)) {
        let mut p = pose(seq, x);
        p.gimbal_rad = a;
        prop_assert_eq!(decode_pose(&encode_pose_v2(&p)), Ok(p));
    }

    #[test]
    fn finite_datagrams_round_trip(seq in any::<u64>(), t in -1e9f64..1e9, x in -1.0f64..1.0, f in -100.0f64..100.0, flags in any::<u32>()) {
        let mut p = pose(seq, x);
        p.device_time_s = t;
        prop_assert_eq!(decode_pose(&encode_pose(&p)), Ok(p));
        let fd = ForceDatagram { seq, pose_seq: seq ^ 1, force: [f, -f, 0.5 * f], flags };
        prop_assert_eq!(decode_force(&encode_force(&fd)), Ok(fd));
    }

    #[test]
    fn the_bridge_survives_random_datagrams(dgrams in proptest::collection::vec(proptest::collection::vec(any::<u8>(), 0..300), 1..20)) {
        let (mut d, addr) = bridge(10.0);
        let peer = UdpSocket::bind("127.0.0.1:0").expect("peer");
        for g in &dgrams {
            peer.send_to(g, addr).expect("send");
        }
        let n = dgrams.len() as u64;
        let r = read_until(&mut d, 0.0, |d| {
            let c = d.counters();
            c.accepted + c.short + c.long + c.bad_magic + c.bad_version + c.non_finite + c.out_of_range + c.out_of_order >= n
        });
        // Random bytes are never a valid pose (the magic alone is 1 in 2^32).
        prop_assert_eq!(r, Err(DeviceError::Stale));
        prop_assert_eq!(d.counters().accepted, 0);
        prop_assert_eq!(d.counters().short + d.counters().long + d.counters().bad_magic, n);
    }
}

#[test]
fn bad_datagrams_are_rejected_and_counted_by_reason() {
    let (mut d, addr) = bridge(10.0);
    let peer = UdpSocket::bind("127.0.0.1:0").expect("peer");
    let good = encode_pose(&pose(5, 0.0));
    let mut sends: Vec<Vec<u8>> = Vec::new();
    sends.push(good[..40].to_vec()); // short
    let mut long = good.to_vec();
    long.push(0);
    sends.push(long); // long
    let mut m = good;
    m[0] = b'X';
    sends.push(m.to_vec()); // bad magic
    let mut v = good;
    v[4] = 2;
    sends.push(v.to_vec()); // bad version
    let mut nan = pose(6, 0.0);
    nan.velocity[1] = f64::NAN;
    sends.push(encode_pose(&nan).to_vec()); // non-finite
    sends.push(encode_pose(&pose(7, 0.5)).to_vec()); // outside the workspace
    let mut fast = pose(8, 0.0);
    fast.velocity = [10.0, 0.0, 0.0];
    sends.push(encode_pose(&fast).to_vec()); // above the speed limit
    sends.push(good.to_vec()); // valid, seq 5
    sends.push(encode_pose(&pose(4, 0.0)).to_vec()); // out of order
    sends.push(good.to_vec()); // duplicate
    sends.push(encode_pose(&pose(9, 0.02)).to_vec()); // valid, newest
    for s in &sends {
        peer.send_to(s, addr).expect("send");
    }
    let s = read_until(&mut d, 1.0, |d| {
        let c = d.counters();
        c.accepted + c.short + c.long + c.bad_magic + c.bad_version + c.non_finite + c.out_of_range + c.out_of_order
            >= sends.len() as u64
    })
    .expect("a valid pose arrived");
    let c = d.counters();
    assert_eq!(
        (
            c.short,
            c.long,
            c.bad_magic,
            c.bad_version,
            c.non_finite,
            c.out_of_range,
            c.out_of_order,
            c.accepted
        ),
        (1, 1, 1, 1, 1, 2, 2, 2),
        "{c:?}"
    );
    // Drained to the newest valid pose.
    assert_eq!(s.position, Vec3::new(0.02, 0.01, -0.02));
    assert_eq!(s.buttons, 1);
    assert_eq!(s.time_s, 1.0, "stamped with the reading thread's clock");
    // Nothing new: the same sample again, counted as a repeat.
    let again = d.read(1.001).expect("still fresh");
    assert_eq!(again.seq, s.seq);
    assert_eq!(d.counters().repeated_reads, 1);
    // Nothing new for longer than max_age: stale.
    assert_eq!(d.read(11.5), Err(DeviceError::Stale));
    assert_eq!(d.counters().stale_reads, 1);
    // A pose reporting a device fault is passed on as an error.
    let mut f = pose(10, 0.0);
    f.status = STATUS_FAULT;
    f.error_code = 0x300;
    peer.send_to(&encode_pose(&f), addr).expect("send");
    let r = read_until(&mut d, 12.0, |d| d.counters().accepted == 3);
    assert_eq!(r, Err(DeviceError::Fault(0x300)));
}

#[test]
fn a_restarted_peer_is_accepted_after_a_run_of_old_sequence_numbers() {
    let (mut d, addr) = bridge(10.0);
    let peer = UdpSocket::bind("127.0.0.1:0").expect("peer");
    peer.send_to(&encode_pose(&pose(1000, 0.0)), addr).expect("send");
    read_until(&mut d, 0.0, |d| d.counters().accepted == 1).expect("first pose");
    for seq in 1..=nvtmm::haptics::udp::RESYNC_AFTER {
        peer.send_to(&encode_pose(&pose(seq, 0.001)), addr).expect("send");
    }
    let s = read_until(&mut d, 0.5, |d| d.counters().resyncs == 1).expect("resynced");
    assert_eq!(d.counters().out_of_order, nvtmm::haptics::udp::RESYNC_AFTER - 1);
    assert_eq!(s.position.x, 0.001);
}

#[test]
fn poses_and_forces_round_trip_with_a_peer_on_loopback() {
    let (mut d, addr) = bridge(1.0);
    const N: u64 = 200;
    let k = 200.0; // N/m: a virtual spring towards the origin
    let peer = std::thread::spawn(move || {
        let sock = UdpSocket::bind("127.0.0.1:0").expect("peer");
        sock.set_read_timeout(Some(Duration::from_secs(5))).expect("timeout");
        let mut got = Vec::new();
        let mut buf = [0u8; 128];
        for seq in 1..=N {
            let x = 0.05 * ((seq as f64) * 0.05).sin();
            sock.send_to(&encode_pose(&pose(seq, x)), addr).expect("send pose");
            // Wait for the force answering this pose.
            loop {
                let (n, _) = sock.recv_from(&mut buf).expect("a force arrives");
                let f = decode_force(&buf[..n]).expect("a valid force datagram");
                if f.pose_seq == seq {
                    got.push((x, f));
                    break;
                }
            }
        }
        // The stop datagram.
        let (n, _) = sock.recv_from(&mut buf).expect("stop arrives");
        assert_eq!(n, FORCE_LEN);
        let stop = decode_force(&buf[..n]).expect("valid");
        (got, stop)
    });
    let mut last_seq = 0;
    let mut answered = 0;
    let mut spins = 0u64;
    while answered < N && spins < 10_000_000 {
        spins += 1;
        match d.read(nvtmm::rt::clock::now_s()) {
            Ok(s) if s.seq != last_seq => {
                last_seq = s.seq;
                // A stiff spring far out saturates (−200 N/m × 0.05 m = 10 N > 7.9 N).
                d.write_force(-s.position * k).expect("send force");
                answered += 1;
            }
            _ => std::thread::yield_now(),
        }
    }
    d.stop();
    d.stop();
    let (got, stop) = peer.join().expect("peer thread");
    assert_eq!(got.len() as u64, N);
    let mut saturated = 0;
    for (x, f) in &got {
        let want = Vec3::new(-k * x, -k * 0.01, k * 0.02);
        let want = if want.norm() > 7.9 {
            want * (7.9 / want.norm())
        } else {
            want
        };
        let have = Vec3::new(f.force[0], f.force[1], f.force[2]);
        assert!((have - want).norm() < 1e-12, "{have:?} vs {want:?}");
        if f.flags & FLAG_SATURATED != 0 {
            saturated += 1;
        }
    }
    assert!(saturated > 0, "some forces were saturated and flagged");
    assert_eq!(stop.flags & FLAG_STOP, FLAG_STOP);
    assert_eq!(stop.force, [0.0; 3]);
    let c = d.counters();
    assert_eq!(c.accepted, N);
    assert_eq!(c.forces_sent, N + 1);
    assert_eq!(c.out_of_order + c.short + c.bad_magic + c.non_finite, 0);
}

#[test]
fn udp_datagram_v2_carries_the_gimbal_angles() {
    let (mut d, addr) = bridge(10.0);
    let peer = UdpSocket::bind("127.0.0.1:0").expect("peer");
    let mut p = pose(1, 0.01);
    p.gimbal_rad = [0.5, -1.25, 3.0];
    let v2 = encode_pose_v2(&p);
    assert_eq!(v2.len(), 108);
    assert_eq!(&v2[4..6], &2u16.to_le_bytes(), "version 2");
    assert_eq!(&v2[..4], b"NVTP");
    assert_eq!(v2[84..92], 0.5f64.to_le_bytes(), "the angles follow version 1's fields");
    peer.send_to(&v2, addr).expect("send");
    let s = read_until(&mut d, 0.0, |d| d.counters().accepted == 1).expect("a v2 pose");
    assert_eq!(s.gimbal_rad, [0.5, -1.25, 3.0]);
    assert_eq!(s.roll_rad(), 3.0);
    assert_eq!(s.position, Vec3::new(0.01, 0.01, -0.02));
    // Version 1 is still accepted, with zero angles.
    peer.send_to(&encode_pose(&pose(2, 0.02)), addr).expect("send");
    let s = read_until(&mut d, 0.0, |d| d.counters().accepted == 2).expect("a v1 pose");
    assert_eq!(s.gimbal_rad, [0.0; 3]);
    assert_eq!(s.position.x, 0.02);

    // Bad version-2 datagrams are rejected and counted by reason.
    let good = encode_pose_v2(&pose(3, 0.0));
    let mut sends: Vec<Vec<u8>> = Vec::new();
    sends.push(good[..POSE_LEN_V2 - 1].to_vec()); // short (a v2 missing its last byte)
    let mut long = good.to_vec();
    long.push(0);
    sends.push(long); // long
    let mut v1_as_v2 = encode_pose(&pose(4, 0.0));
    v1_as_v2[4] = 2;
    sends.push(v1_as_v2.to_vec()); // a v1 layout claiming version 2: bad version
    let mut v2_as_v1 = good;
    v2_as_v1[4] = 1;
    sends.push(v2_as_v1.to_vec()); // a v2 layout claiming version 1: bad version
    let mut nan = pose(5, 0.0);
    nan.gimbal_rad[2] = f64::NAN;
    sends.push(encode_pose_v2(&nan).to_vec()); // non-finite angle
    let mut wild = pose(6, 0.0);
    wild.gimbal_rad[2] = 7.0; // beyond one turn
    sends.push(encode_pose_v2(&wild).to_vec());
    let mut v1_long = encode_pose(&pose(7, 0.0)).to_vec();
    v1_long.extend_from_slice(&[0; 10]);
    sends.push(v1_long); // a v1 with 10 trailing bytes: long
    for s in &sends {
        peer.send_to(s, addr).expect("send");
    }
    let n = sends.len() as u64;
    read_until(&mut d, 0.0, |d| {
        let c = d.counters();
        c.short + c.long + c.bad_version + c.non_finite + c.gimbal_out_of_range >= n
    })
    .expect("the last valid pose is still fresh");
    let c = d.counters();
    assert_eq!(
        (
            c.short,
            c.long,
            c.bad_version,
            c.non_finite,
            c.gimbal_out_of_range,
            c.accepted
        ),
        (1, 2, 2, 1, 1, 2),
        "{c:?}"
    );
    assert_eq!(decode_pose(&good[..POSE_LEN_V2 - 1]), Err(Reject::Short));
    assert_eq!(decode_pose(&v1_as_v2), Err(Reject::BadVersion));
    assert_eq!(decode_pose(&encode_pose_v2(&nan)), Err(Reject::NonFinite));
}
