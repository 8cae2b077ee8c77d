//! A start that fails after the device was started (here: the recording
//! file cannot be created) stops the device, as a stop would: a UDP bridge's
//! peer receives the stop datagram with a zero force, and the memory lock
//! the start took is released. An embedding application whose start fails
//! keeps neither a device holding its last command nor its memory locked.
//!
//! In its own test binary: the memory lock is the whole process's.

mod common;

use nvtmm::haptics::udp::{decode_force, FLAG_STOP};
use nvtmm::service::{Service, StartOptions};
use std::net::UdpSocket;
use std::time::Duration;

/// The process's locked memory (kB), from /proc/self/status.
fn locked_kb() -> u64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap();
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmLck:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
        .unwrap()
}

#[test]
fn a_start_that_fails_stops_its_device_and_unlocks_memory() {
    let dir = tempfile::tempdir().unwrap();
    let peer = UdpSocket::bind("127.0.0.1:0").unwrap();
    peer.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
    // The shipped bridge parameters, bound to any free port and sending
    // forces to this test's socket.
    let shipped = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/rt-config/udp_device.toml")).unwrap();
    let udp: String = shipped
        .lines()
        .map(|l| {
            if l.starts_with("bind") {
                "bind = \"127.0.0.1:0\"".to_string()
            } else if l.starts_with("peer") {
                format!("peer = \"{}\"", peer.local_addr().unwrap())
            } else {
                l.to_string()
            }
        })
        .collect::<Vec<_>>()
        .join("\n");
    std::fs::write(dir.path().join("udp.toml"), udp).unwrap();
    // The recovery tests' small scene (written by their options).
    let _ = common::service::options(dir.path());
    let config = "scene = \"scene.toml\"\nseconds = 10.0\n[loop]\nbaseline_s = 0.1\nlock_memory = true\n\
                  [device]\nbackend = \"udp\"\nudp = \"udp.toml\"\n[background]\nenabled = false\n[stream]\nenabled = false\n";
    assert_eq!(locked_kb(), 0, "memory locked before the start");
    let options = StartOptions {
        record: Some(dir.path().join("no-such-directory").join("run.nvtrec")),
        ..StartOptions::text(config, dir.path().join("in-memory.toml"))
    };
    let err = match Service::start(options) {
        Ok(_) => panic!("a recording into a missing directory must fail the start"),
        Err(e) => e.to_string(),
    };
    assert!(err.contains("stream"), "{err}");
    // The device was started (its socket bound) before the failure: its
    // stop sent the peer a zero force flagged as the stop.
    let mut buf = [0u8; 256];
    let n = peer
        .recv(&mut buf)
        .expect("no datagram from the device: it was not stopped");
    let d = decode_force(&buf[..n]).expect("a force datagram");
    assert!(d.flags & FLAG_STOP != 0, "{d:?}");
    assert_eq!(d.force, [0.0; 3], "{d:?}");
    // The memory lock taken by the start is released (where the OS granted
    // it at all: without RLIMIT_MEMLOCK room there was nothing to undo).
    assert_eq!(locked_kb(), 0, "memory left locked after the failed start");
}
