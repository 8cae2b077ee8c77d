//! The OpenIGTLink server, checked from the outside: a byte-level decoder
//! written here from the specification (not the server's code) reads what
//! clients receive; a fixture checked by hand pins the framing; four clients
//! at once, one of which stops reading, do not slow the publisher and that
//! client's drops are counted; malformed client messages are counted, never
//! a panic. Also: an independent client, pyigtl (the OpenIGTLink Python
//! package), receives the tool-tip transform and the status string.

use nvtmm::stream::igtl::{self, IgtlServer};
use nvtmm::stream::{IgtlConfig, Publisher, StateFrame, StreamConfig, Topology};
use std::io::{Read, Write};
use std::net::TcpStream;
use std::time::{Duration, Instant};

/// CRC-64/ECMA-182 bit by bit (polynomial 0x42F0E1EBA9EA3693, init 0, no
/// reflection, no final xor), independent of the crate's table version.
fn crc64_bitwise(data: &[u8]) -> u64 {
    let mut crc = 0u64;
    for &b in data {
        crc ^= (b as u64) << 56;
        for _ in 0..8 {
            crc = if crc & (1 << 63) != 0 {
                (crc << 1) ^ 0x42F0_E1EB_A9EA_3693
            } else {
                crc << 1
            };
        }
    }
    crc
}

/// One message as the specification lays it out.
#[derive(Debug)]
struct Raw {
    version: u16,
    kind: String,
    device: String,
    body: Vec<u8>,
    crc_ok: bool,
}

/// Splits a byte stream into messages (header 58 bytes, big-endian).
fn split(mut b: &[u8]) -> (Vec<Raw>, usize) {
    let mut out = Vec::new();
    let mut used = 0;
    while b.len() >= 58 {
        let size = u64::from_be_bytes(b[42..50].try_into().unwrap()) as usize;
        if b.len() < 58 + size {
            break;
        }
        let body = b[58..58 + size].to_vec();
        let crc = u64::from_be_bytes(b[50..58].try_into().unwrap());
        let s = |r: std::ops::Range<usize>| String::from_utf8_lossy(&b[r]).trim_end_matches('\0').to_string();
        out.push(Raw {
            version: u16::from_be_bytes([b[0], b[1]]),
            kind: s(2..14),
            device: s(14..34),
            crc_ok: crc64_bitwise(&body) == crc,
            body,
        });
        b = &b[58 + size..];
        used += 58 + size;
    }
    (out, used)
}

/// POLYDATA content after the 12-byte extended header: (points, polygons).
fn polydata_counts(body: &[u8]) -> (u32, u32) {
    let c = &body[12..];
    let u = |i: usize| u32::from_be_bytes(c[4 * i..4 * i + 4].try_into().unwrap());
    (u(0), u(5))
}

fn topology(n: usize) -> Topology {
    let rest: Vec<[f32; 3]> = (0..n).map(|i| [i as f32 * 1e-3, 0.0, 0.0]).collect();
    Topology {
        epoch: 1,
        triangles: (0..n as u32 - 2).map(|i| [i, i + 1, i + 2]).collect(),
        node_ids: (0..n as u32).collect(),
        rest_positions: rest,
    }
}

fn frame(positions: &[[f32; 3]], t: f64) -> StateFrame<'_> {
    StateFrame {
        time_s: t,
        positions,
        tool_position: [0.01, 0.02, 0.03],
        tool_radius: 0.003,
        force: [0.0, 0.0, 1.5],
        flags: 2,
        loop_rate_hz: 1000.0,
        tick_p99_us: 20.0,
        instruments: &[],
    }
}

fn publisher(n: usize) -> Publisher {
    let cfg = StreamConfig {
        enabled: false,
        igtl: Some(IgtlConfig {
            listen: "127.0.0.1:0".into(),
            max_clients: 8,
            queue_frames: 4,
        }),
        ..StreamConfig::default()
    };
    Publisher::new(cfg, topology(n), None).unwrap()
}

#[test]
fn a_transform_message_matches_the_specification_byte_for_byte() {
    let mut b = Vec::new();
    igtl::encode_message(&mut b, "TRANSFORM", "ToolTip", 1.5, |o| {
        igtl::transform_content(o, [10.0, 20.0, 30.0])
    });
    // Header (58 bytes).
    assert_eq!(&b[0..2], &[0x00, 0x02], "version 2");
    assert_eq!(&b[2..14], b"TRANSFORM\0\0\0", "type, NUL-padded to 12");
    assert_eq!(
        &b[14..34],
        b"ToolTip\0\0\0\0\0\0\0\0\0\0\0\0\0",
        "device name, NUL-padded to 20"
    );
    assert_eq!(&b[34..38], &[0, 0, 0, 1], "time stamp: 1 s");
    assert_eq!(&b[38..42], &[0x80, 0, 0, 0], "time stamp: 0.5 s in units of 2^-32 s");
    assert_eq!(
        &b[42..50],
        &[0, 0, 0, 0, 0, 0, 0, 60],
        "body: 12 extended header + 48 content"
    );
    // Extended header: size 12, no metadata, message id 0.
    assert_eq!(&b[58..70], &[0, 12, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0]);
    // Content: R11 R21 R31 R12 R22 R32 R13 R23 R33 TX TY TZ, float32 BE.
    let one = 1.0f32.to_be_bytes();
    let zero = 0.0f32.to_be_bytes();
    for (k, want) in [one, zero, zero, zero, one, zero, zero, zero, one].iter().enumerate() {
        assert_eq!(&b[70 + 4 * k..74 + 4 * k], want, "rotation entry {k}");
    }
    assert_eq!(&b[106..110], &10.0f32.to_be_bytes());
    assert_eq!(&b[110..114], &20.0f32.to_be_bytes());
    assert_eq!(&b[114..118], &30.0f32.to_be_bytes());
    assert_eq!(b.len(), 118);
    assert_eq!(
        u64::from_be_bytes(b[50..58].try_into().unwrap()),
        crc64_bitwise(&b[58..])
    );
    // The check value of CRC-64/ECMA-182.
    assert_eq!(crc64_bitwise(b"123456789"), 0x6C40_DF5F_0B49_7347);
}

#[test]
fn four_clients_one_stalled_get_every_frame_at_the_stream_rate_and_the_stall_is_counted() {
    let n = 2000;
    let mut p = publisher(n);
    let addr = p.igtl_addr().unwrap();
    let readers: Vec<std::thread::JoinHandle<(Vec<Raw>, f64)>> = (0..3)
        .map(|_| {
            std::thread::spawn(move || {
                let mut s = TcpStream::connect(addr).unwrap();
                s.set_read_timeout(Some(Duration::from_millis(1500))).unwrap();
                let mut data = Vec::new();
                let mut buf = vec![0u8; 1 << 16];
                let mut first = None;
                let mut last = Instant::now();
                while let Ok(k) = s.read(&mut buf) {
                    if k == 0 {
                        break;
                    }
                    first.get_or_insert_with(Instant::now);
                    last = Instant::now();
                    data.extend_from_slice(&buf[..k]);
                }
                let span = first.map(|f| (last - f).as_secs_f64()).unwrap_or(0.0);
                (split(&data).0, span)
            })
        })
        .collect();
    // The stalled client connects and never reads.
    let _stalled = TcpStream::connect(addr).unwrap();
    let positions: Vec<[f32; 3]> = (0..n).map(|i| [i as f32 * 1e-3, 0.0, 0.0]).collect();
    // Let the server accept all four.
    let t0 = Instant::now();
    while p.igtl_stats().unwrap().accepted < 4 && t0.elapsed() < Duration::from_secs(5) {
        p.publish(&frame(&positions, 0.0)).unwrap();
        std::thread::sleep(Duration::from_millis(5));
    }
    assert_eq!(p.igtl_stats().unwrap().accepted, 4);
    // 2 s at 60 Hz, timing each publish.
    let frames = 120;
    let start = Instant::now();
    let mut worst_ms = 0.0f64;
    for k in 0..frames {
        let next = start + Duration::from_secs_f64(k as f64 / 60.0);
        if let Some(d) = next.checked_duration_since(Instant::now()) {
            std::thread::sleep(d);
        }
        let t = Instant::now();
        p.publish(&frame(&positions, k as f64 / 60.0)).unwrap();
        worst_ms = worst_ms.max(t.elapsed().as_secs_f64() * 1e3);
    }
    let stats = p.igtl_stats().unwrap();
    drop(p); // closes every connection
    let mut rates = Vec::new();
    for h in readers {
        let (msgs, span) = h.join().unwrap();
        assert!(msgs.iter().all(|m| m.crc_ok && m.version == 2), "every CRC is right");
        let surfaces: Vec<&Raw> = msgs.iter().filter(|m| m.kind == "POLYDATA").collect();
        assert!(surfaces.len() >= frames, "{} surface frames", surfaces.len());
        for s in &surfaces {
            assert_eq!(s.device, "VesselSurface");
            assert_eq!(
                polydata_counts(&s.body),
                (n as u32, n as u32 - 2),
                "points and triangles"
            );
        }
        assert!(msgs.iter().any(|m| m.kind == "TRANSFORM" && m.device == "ToolTip"));
        assert!(msgs.iter().any(|m| m.kind == "STRING" && m.device == "Status"));
        rates.push((surfaces.len() - 1) as f64 / span.max(1e-9));
    }
    let stalled = stats.clients.iter().max_by_key(|c| c.frames_dropped).unwrap();
    eprintln!(
        "receive rates {rates:.1?} frames/s; worst publish {worst_ms:.2} ms; stalled client dropped {} of {} frames",
        stalled.frames_dropped,
        stalled.frames_dropped + stalled.frames_sent
    );
    for r in &rates {
        assert!(*r >= 55.0, "at least 55 frames per second at 60 Hz: {r}");
    }
    assert!(
        stalled.frames_dropped > 0,
        "the stalled client's frames are dropped and counted"
    );
    // Never blocked on the stalled client: a write blocked on its full socket
    // would not return until the connection closed (seconds here), so every
    // publish returning well inside that is the structural check. Its typical
    // figure (well under a frame period on a quiet machine) is printed above;
    // a tighter bound would test the machine's load, not the server.
    assert!(
        worst_ms < 500.0,
        "a publish waited {worst_ms} ms: blocked on the stalled client"
    );
}

#[test]
fn malformed_client_messages_are_counted_never_a_panic() {
    let mut server = IgtlServer::bind("127.0.0.1:0".parse().unwrap(), 8, 4).unwrap();
    let addr = server.local_addr().unwrap();
    let mut good = Vec::new();
    igtl::encode_message(&mut good, "STRING", "Hello", 0.0, |o| igtl::string_content(o, "hi"));
    let mut bad_crc = good.clone();
    let last = bad_crc.len() - 1;
    bad_crc[last] ^= 1;
    let mut c1 = TcpStream::connect(addr).unwrap();
    c1.write_all(&good).unwrap();
    c1.write_all(&bad_crc).unwrap();
    // Random junk shaped like a header with a sane size.
    let mut junk = vec![0xA5u8; 58 + 100];
    junk[42..50].copy_from_slice(&100u64.to_be_bytes());
    c1.write_all(&junk).unwrap();
    // A second client declares a 1 TB body: dropped.
    let mut c2 = TcpStream::connect(addr).unwrap();
    let mut huge = good[..58].to_vec();
    huge[42..50].copy_from_slice(&(1u64 << 40).to_be_bytes());
    c2.write_all(&huge).unwrap();
    let t0 = Instant::now();
    while t0.elapsed() < Duration::from_secs(2) {
        server.poll();
        let s = server.stats();
        let bad: u64 = s.clients.iter().map(|c| c.bad_messages).sum();
        if bad >= 3 && s.disconnected >= 1 {
            break;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    let s = server.stats();
    let good_n: u64 = s.clients.iter().map(|c| c.messages_received).sum();
    let bad: u64 = s.clients.iter().map(|c| c.bad_messages).sum();
    assert_eq!(good_n, 1, "{s:?}");
    assert_eq!(bad, 3, "bad CRC, junk, huge size: {s:?}");
    assert_eq!(s.disconnected, 1, "the client with the huge size is dropped: {s:?}");
    // Random bytes straight into the decoder: never a panic.
    let mut x = 0x1234_5678_9abc_def0u64;
    for len in 0..2000usize {
        let bytes: Vec<u8> = (0..len % 300)
            .map(|_| {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                x as u8
            })
            .collect();
        let _ = igtl::decode(&bytes, 1 << 20);
        let mut m = good.clone();
        if !m.is_empty() {
            let k = (x as usize) % m.len();
            m[k] = x as u8;
        }
        let _ = igtl::decode(&m, 1 << 20);
    }
}

#[test]
fn pyigtl_receives_the_tip_transform_and_the_status() {
    let script = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tools/igtl_pyigtl_client.py");
    let ci = std::env::var("CI").is_ok_and(|v| v == "true");
    let probe = std::process::Command::new("python3")
        .args(["-c", "import pyigtl"])
        .output();
    match probe {
        Ok(o) if o.status.success() => {}
        _ => {
            assert!(!ci, "CI=true but python3 with pyigtl is missing (.ci/run installs it)");
            eprintln!("SKIPPED: python3 with pyigtl not found (python3 -m pip install pyigtl)");
            return;
        }
    }
    let mut p = publisher(100);
    let addr = p.igtl_addr().unwrap();
    let child = std::process::Command::new("python3")
        .arg(&script)
        .arg(addr.ip().to_string())
        .arg(addr.port().to_string())
        .arg("20")
        .stdout(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let positions: Vec<[f32; 3]> = (0..100).map(|i| [i as f32 * 1e-3, 0.0, 0.0]).collect();
    let done = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let d2 = done.clone();
    let server = std::thread::spawn(move || {
        let mut k = 0;
        while !d2.load(std::sync::atomic::Ordering::Relaxed) && k < 60 * 30 {
            p.publish(&frame(&positions, k as f64 / 60.0)).unwrap();
            std::thread::sleep(Duration::from_millis(16));
            k += 1;
        }
    });
    let out = child.wait_with_output().unwrap();
    done.store(true, std::sync::atomic::Ordering::Relaxed);
    server.join().unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    eprintln!("pyigtl: {text}");
    assert!(out.status.success(), "pyigtl client failed: {text}");
    let v: serde_json::Value = serde_json::from_str(text.trim()).unwrap();
    assert_eq!(v["tip_type"], "TRANSFORM");
    // The tool at (0.01, 0.02, 0.03) m (LPS) arrives in RAS millimetres.
    let m = &v["tip_matrix"];
    for (row, want) in [(0, -10.0), (1, -20.0), (2, 30.0)] {
        let got = m[row][3].as_f64().unwrap();
        assert!((got - want).abs() < 1e-4, "translation row {row}: {got}");
    }
    assert_eq!(v["status_type"], "STRING");
    let s = v["status"].as_str().unwrap();
    assert!(s.contains("|F|=1.5000 N") && s.contains("flags=0x2"), "{s}");
}

#[test]
fn each_instrument_goes_as_its_own_polydata_and_tip_transform() {
    let n = 50;
    let mut p = publisher(n);
    let addr = p.igtl_addr().unwrap();
    let reader = std::thread::spawn(move || {
        let mut s = TcpStream::connect(addr).unwrap();
        s.set_read_timeout(Some(Duration::from_millis(1000))).unwrap();
        let mut data = Vec::new();
        let mut buf = vec![0u8; 1 << 16];
        while let Ok(k) = s.read(&mut buf) {
            if k == 0 {
                break;
            }
            data.extend_from_slice(&buf[..k]);
        }
        split(&data).0
    });
    let positions: Vec<[f32; 3]> = (0..n).map(|i| [i as f32 * 1e-3, 0.0, 0.0]).collect();
    let probe = [[0.01f32, 0.02, 0.03]];
    let wire = [[0.0f32, 0.0, 0.0], [0.0, 0.0, 0.01], [0.0, 0.002, 0.02]];
    let lines = [
        nvtmm::stream::InstrumentLine {
            id: 0,
            kind: 1,
            points: &probe,
        },
        nvtmm::stream::InstrumentLine {
            id: 1,
            kind: 2,
            points: &wire,
        },
        nvtmm::stream::InstrumentLine {
            id: 2,
            kind: 9,
            points: &wire[..2],
        },
    ];
    let t0 = Instant::now();
    while p.igtl_stats().unwrap().accepted < 1 && t0.elapsed() < Duration::from_secs(5) {
        p.publish(&frame(&positions, 0.0)).unwrap();
        std::thread::sleep(Duration::from_millis(5));
    }
    for k in 0..5 {
        p.publish(&StateFrame {
            instruments: &lines,
            ..frame(&positions, k as f64 / 60.0)
        })
        .unwrap();
        std::thread::sleep(Duration::from_millis(10));
    }
    drop(p);
    let msgs = reader.join().unwrap();
    let last = |kind: &str, device: &str| {
        msgs.iter()
            .rev()
            .find(|m| m.kind == kind && m.device == device)
            .unwrap_or_else(|| panic!("no {kind} {device}"))
    };
    // One polyline per instrument, named for its kind (an unknown kind by
    // its id), its points and one LINES cell; each with its tip.
    for (device, points) in [("Probe", 1u32), ("Wire", 3), ("Instrument2", 2)] {
        let m = last("POLYDATA", device);
        assert_eq!(polydata_counts(&m.body).0, points, "{device}");
        last("TRANSFORM", &format!("{device}Tip"));
    }
}
