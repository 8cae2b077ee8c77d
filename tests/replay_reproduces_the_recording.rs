//! `nvtmm replay` sends a recording's datagrams byte for byte, and
//! `nvtmm replay --vtu` writes one ParaView step per state frame.

use nvtmm::mesh::arch::{generate, ArchParams};
use nvtmm::stream::record::RecordReader;
use nvtmm::stream::{decimate, demo, StreamConfig};
use std::net::UdpSocket;
use std::process::Command;
use std::time::Duration;

fn recording(dir: &std::path::Path, frames: usize) -> (std::path::PathBuf, usize) {
    let mesh = generate(&ArchParams::default(), 1458).unwrap().mesh;
    let topo = decimate::surface(&mesh, 200);
    let tris = topo.triangles.len();
    let sink = UdpSocket::bind("127.0.0.1:0").unwrap();
    let cfg = StreamConfig {
        target: sink.local_addr().unwrap().to_string(),
        ..StreamConfig::default()
    };
    let rec = dir.join("run.nvts");
    demo::publish_frames(&mesh, topo, cfg, Some(&rec), frames).unwrap();
    (rec, tris)
}

#[test]
fn replay_sends_the_recorded_datagrams_byte_for_byte() {
    let dir = tempfile::tempdir().unwrap();
    let (rec, _) = recording(dir.path(), 10);
    let recorded: Vec<Vec<u8>> = RecordReader::open(&rec).unwrap().map(|r| r.unwrap().1).collect();
    let rx = UdpSocket::bind("127.0.0.1:0").unwrap();
    rx.set_read_timeout(Some(Duration::from_secs(20))).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_nvtmm"))
        .args(["replay", "--speed", "2", "--to", &rx.local_addr().unwrap().to_string()])
        .arg(&rec)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let mut buf = [0u8; 2048];
    for (k, want) in recorded.iter().enumerate() {
        let n = rx.recv(&mut buf).unwrap_or_else(|e| panic!("datagram {k}: {e}"));
        assert_eq!(&buf[..n], &want[..], "datagram {k}");
    }
}

#[test]
fn vtu_export_writes_one_step_per_frame() {
    let dir = tempfile::tempdir().unwrap();
    let (rec, tris) = recording(dir.path(), 12);
    let out_dir = dir.path().join("pv");
    let out = Command::new(env!("CARGO_BIN_EXE_nvtmm"))
        .arg("replay")
        .arg(&rec)
        .arg("--vtu")
        .arg(&out_dir)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    for name in ["surface", "tool"] {
        let pvd = std::fs::read_to_string(out_dir.join(format!("{name}.pvd"))).unwrap();
        assert_eq!(pvd.matches("<DataSet ").count(), 12, "{name}.pvd");
    }
    let vtu = std::fs::read_to_string(out_dir.join("surface_000011.vtu")).unwrap();
    assert!(vtu.contains(&format!("NumberOfCells=\"{tris}\"")));
    assert!(vtu.contains("Name=\"displacement_magnitude\""));
    let tool = std::fs::read_to_string(out_dir.join("tool_000000.vtu")).unwrap();
    assert!(tool.contains("Name=\"force\""));
}
