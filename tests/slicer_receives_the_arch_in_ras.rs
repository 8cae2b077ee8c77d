//! 3D Slicer's world frame is RAS (x to the patient's Right, y Anterior, z
//! Superior); the scene frame is LPS (docs/reference/coordinates.md). What
//! the OpenIGTLink server sends, decoded as Slicer's OpenIGTLinkIF reads it,
//! puts the built-in branched arch the right way round: the left
//! subclavian's outlet on the patient's left of the brachiocephalic trunk's,
//! the ascending aorta's root anterior of the descending aorta, the branch
//! outlets superior of the root; the tool's translation and the force are
//! converted the same way.

use nvtmm::mesh::vessel::branched::{branched_arch, default_wall_ratio};
use nvtmm::mesh::vessel::implicit::BranchedArchParams;
use nvtmm::mesh::TetMesh;
use nvtmm::stream::igtl::{self, IgtlFrame, IgtlServer, Message};
use std::io::Read;
use std::net::TcpStream;
use std::time::{Duration, Instant};

/// Mean of a node set's positions in the frame `points` gives.
fn centroid(m: &TetMesh, set: &str, points: &[[f32; 3]]) -> [f64; 3] {
    let nodes = m.node_set(set).unwrap_or_else(|| panic!("no node set {set}"));
    let mut c = [0.0; 3];
    for &i in nodes {
        for k in 0..3 {
            c[k] += points[i as usize][k] as f64 / nodes.len() as f64;
        }
    }
    c
}

#[test]
fn slicer_receives_the_arch_in_ras() {
    let params = BranchedArchParams::default();
    let arch = branched_arch(&params, 1458, 1, default_wall_ratio(&params)).expect("branched arch");
    let m = &arch.wall.mesh;
    let scene: Vec<[f32; 3]> = m.rest().iter().map(|p| [p.x as f32, p.y as f32, p.z as f32]).collect();
    let triangles: Vec<[u32; 3]> = m.surface().to_vec();

    let mut server = IgtlServer::bind("127.0.0.1:0".parse().unwrap(), 2, 4).unwrap();
    let addr = server.local_addr().unwrap();
    server.set_topology(1, &triangles);
    let mut client = TcpStream::connect(addr).unwrap();
    client.set_read_timeout(Some(Duration::from_millis(50))).unwrap();
    let frame = IgtlFrame {
        time_s: 0.0,
        positions: &scene,
        tool_position: [0.01, 0.02, 0.03],
        force: [1.0, 2.0, 3.0],
        flags: 0,
        loop_rate_hz: 1000.0,
        instruments: &[],
    };
    let (mut surface, mut tool, mut status) = (None, None, None);
    let mut data = Vec::new();
    let mut buf = vec![0u8; 1 << 16];
    let t0 = Instant::now();
    while (surface.is_none() || tool.is_none() || status.is_none()) && t0.elapsed() < Duration::from_secs(20) {
        server.publish(&frame);
        if let Ok(k) = client.read(&mut buf) {
            data.extend_from_slice(&buf[..k]);
        }
        while let Ok((msg, used)) = igtl::decode(&data, 1 << 24) {
            data.drain(..used);
            match msg {
                Message::PolyData {
                    device,
                    points,
                    polygons,
                    ..
                } if device == "VesselSurface" => surface = Some((points, polygons)),
                Message::Transform { device, values } if device == "ToolTip" => tool = Some(values),
                Message::String { device, text } if device == "Status" => status = Some(text),
                _ => {}
            }
        }
    }
    let (ras, polygons) = surface.expect("no VesselSurface received");
    assert_eq!(ras.len(), scene.len());
    assert_eq!(polygons.len(), triangles.len());
    // Negating x and y is a rotation: the triangles keep their winding.
    assert_eq!(polygons[0], triangles[0].to_vec());

    let left_subclavian = centroid(m, "outlet_left_subclavian", &ras);
    let brachiocephalic = centroid(m, "outlet_brachiocephalic", &ras);
    let root = centroid(m, "inlet", &ras);
    let descending = centroid(m, "outlet_descending", &ras);
    println!(
        "RAS mm: left subclavian {left_subclavian:.1?}, brachiocephalic {brachiocephalic:.1?}, \
         root {root:.1?}, descending {descending:.1?}"
    );
    // R: +x is the patient's right.
    assert!(
        left_subclavian[0] < brachiocephalic[0] - 10.0,
        "the left subclavian must be on the patient's left (smaller R) of the brachiocephalic trunk"
    );
    assert!(
        descending[0] < root[0],
        "the descending aorta is on the left of the ascending aorta's root"
    );
    // A: +y is anterior.
    assert!(
        root[1] > descending[1] + 30.0,
        "the aortic root must be anterior (larger A) of the descending aorta"
    );
    // S: +z is superior.
    assert!(left_subclavian[2] > root[2] && brachiocephalic[2] > root[2]);

    let v = tool.expect("no ToolTip received");
    assert_eq!(
        &v[9..12],
        &[-10.0, -20.0, 30.0],
        "the tool (0.01, 0.02, 0.03) m LPS in RAS mm"
    );
    let s = status.expect("no Status received");
    assert!(s.contains("force=-1.0000,-2.0000,3.0000 N"), "{s}");
}
