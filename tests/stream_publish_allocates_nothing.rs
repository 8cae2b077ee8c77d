//! After the first frame, `Publisher::publish` (encode, chunk, send, record,
//! topology re-sends) and `Topology::positions_from_displacement` allocate
//! nothing: the stream thread never touches the allocator in steady state.

mod common;

use common::counting::count_allocations;
use nvtmm::math::Vec3;
use nvtmm::mesh::arch::{generate, ArchParams};
use nvtmm::stream::{decimate, flags, Publisher, StateFrame, StreamConfig};
use std::net::UdpSocket;

#[global_allocator]
static GLOBAL: common::counting::Counting = common::counting::Counting;

#[test]
fn publish_allocates_nothing_after_the_first_frame() {
    let mesh = generate(&ArchParams::default(), 1458).expect("arch").mesh;
    let topo = decimate::surface(&mesh, 500);
    let sink = UdpSocket::bind("127.0.0.1:0").expect("sink");
    let cfg = StreamConfig {
        target: sink.local_addr().expect("addr").to_string(),
        topology_period_s: 0.1,
        ..StreamConfig::default()
    };
    let dir = tempfile::tempdir().expect("tempdir");
    let mut p = Publisher::new(cfg, topo, Some(&dir.path().join("r.nvts"))).expect("publisher");
    let mut u = vec![Vec3::zeros(); mesh.num_nodes()];
    let mut pos = Vec::new();
    let mut frame = |p: &mut Publisher, pos: &mut Vec<[f32; 3]>, k: usize| {
        u.iter_mut().for_each(|x| x.z = -1e-5 * k as f64);
        p.topology().positions_from_displacement(&mesh, &u, pos);
        p.publish(&StateFrame {
            time_s: k as f64 / 60.0,
            positions: pos,
            tool_position: [0.0; 3],
            tool_radius: 0.002,
            force: [0.0, 0.0, 1.0],
            flags: flags::IN_CONTACT,
            loop_rate_hz: 1000.0,
            tick_p99_us: 30.0,
            instruments: &[],
        })
        .expect("publish");
    };
    frame(&mut p, &mut pos, 0);
    let ((), n) = count_allocations(|| {
        for k in 1..400 {
            if k % 100 == 0 {
                // Past the topology period: the next publish re-sends it.
                std::thread::sleep(std::time::Duration::from_millis(120));
            }
            frame(&mut p, &mut pos, k);
        }
    });
    let st = p.finish().expect("finish");
    assert_eq!(st.frames, 400);
    assert!(st.topologies >= 4, "{} topologies", st.topologies);
    assert_eq!(n, 0, "{n} allocations in 399 publishes");
}
