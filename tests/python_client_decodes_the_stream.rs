//! `tools/stream_client.py`, written from docs/STREAM.md alone, decodes a
//! recording to the same frames as the Rust decoder, every instrument's
//! polyline (id, kind, points) included.

use nvtmm::mesh::arch::{generate, ArchParams};
use nvtmm::stream::record::RecordReader;
use nvtmm::stream::{decimate, demo, Decoded, Decoder, StreamConfig};
use std::net::UdpSocket;
use std::process::Command;

#[test]
fn python_client_matches_the_rust_decoder() {
    if Command::new("python3").arg("--version").output().is_err() {
        eprintln!("SKIPPED python_client_matches_the_rust_decoder: no python3 on PATH");
        return;
    }
    let mesh = generate(&ArchParams::default(), 1458).unwrap().mesh;
    let topo = decimate::surface(&mesh, 300);
    let sink = UdpSocket::bind("127.0.0.1:0").unwrap();
    let cfg = StreamConfig {
        target: sink.local_addr().unwrap().to_string(),
        ..StreamConfig::default()
    };
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("run.nvts");
    let st = demo::publish_frames(&mesh, topo.clone(), cfg, Some(&rec), 40).unwrap();
    assert_eq!(st.frames, 40);

    let mut dec = Decoder::new();
    let mut rust = Vec::new();
    for r in RecordReader::open(&rec).unwrap() {
        if let Ok(Some(Decoded::State(s))) = dec.push(&r.unwrap().1) {
            let sum: f64 = s.positions.iter().flatten().map(|&v| v as f64).sum();
            let wire = s.polyline_of_kind(2);
            let wsum: f64 = wire.iter().flatten().map(|&v| v as f64).sum();
            let ids: Vec<(u8, u8, usize)> = s.instruments.iter().map(|l| (l.id, l.kind, l.points.len())).collect();
            rust.push((s.seq, s.time_s, s.force, s.flags, sum, wire.len(), wsum, ids));
        }
    }
    assert_eq!(rust.len(), 40);

    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/tools/stream_client.py");
    let out = Command::new("python3")
        .args([script, "--file"])
        .arg(&rec)
        .arg("--json")
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let lines: Vec<serde_json::Value> = String::from_utf8(out.stdout)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(lines[0]["kind"], "topology");
    assert_eq!(lines[0]["vertices"], topo.num_vertices());
    assert_eq!(lines[0]["triangles"], topo.triangles.len());
    let py: Vec<&serde_json::Value> = lines.iter().filter(|l| l["kind"] == "state").collect();
    assert_eq!(py.len(), rust.len());
    for (p, (seq, t, f, flags, sum, nw, wsum, ids)) in py.iter().zip(&rust) {
        assert!(*nw > 0, "the demo frames carry a wire");
        // Every instrument's id, kind and point count, in order.
        let pi = p["instruments"].as_array().expect("instruments");
        assert_eq!(pi.len(), ids.len());
        for (a, (id, kind, n)) in pi.iter().zip(ids) {
            assert_eq!(a["id"], *id);
            assert_eq!(a["kind"], *kind);
            assert_eq!(a["points"], *n);
        }
        assert_eq!(p["wire_points"], *nw);
        let pw = p["wire_sum"].as_f64().unwrap();
        assert!((pw - wsum).abs() <= 1e-9 * wsum.abs().max(1.0), "{pw} vs {wsum}");
        assert_eq!(p["seq"], *seq);
        assert_eq!(p["time_s"].as_f64().unwrap(), *t);
        assert_eq!(p["flags"], *flags);
        for k in 0..3 {
            assert_eq!(p["force"][k].as_f64().unwrap(), f[k] as f64);
        }
        let ps = p["positions_sum"].as_f64().unwrap();
        assert!((ps - sum).abs() <= 1e-9 * sum.abs().max(1.0), "{ps} vs {sum}");
    }
}
