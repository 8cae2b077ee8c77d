//! After construction, the wire's step — feeding nodes in and out at the
//! hub, rolling, touching rigid tubes and a triangle wall that moves every
//! tick (grid rebuilt) — and its reset path allocate nothing.

mod common;

use common::counting::count_allocations;
use nvtmm::math::Vec3;
use nvtmm::wire::lumen::tube_wall;
use nvtmm::wire::{CurvedTube, CurvedTubeShape, Lumen, StraightTube, TriangleLumen, Wire, WireParams};

#[global_allocator]
static GLOBAL: common::counting::Counting = common::counting::Counting;

#[test]
fn wire_step_allocates_nothing() {
    let p = WireParams {
        segment_length_m: 2e-3,
        max_nodes: 64,
        ..WireParams::default()
    };
    let straight = StraightTube::new(Vec3::new(-0.01, 0.0, 0.0), Vec3::x(), 0.2, 2e-3, true).expect("tube");
    let curved = CurvedTube::new(&CurvedTubeShape {
        start: Vec3::new(-0.01, 0.0, 0.0),
        tangent: Vec3::x(),
        toward: Vec3::y(),
        inlet: 0.02,
        bend_radius: 0.03,
        angle: 2.0,
        outlet: 0.1,
        radius: 3e-3,
    })
    .expect("tube");
    let (verts, tris) = tube_wall(-0.01, 0.2, 2.5e-3, 16, 60, 0.0);
    let mut mesh = TriangleLumen::new(&verts, &tris).expect("surface");
    let mut moved = verts.clone();

    // The counter itself works: one box is one allocation.
    let ((), one) = count_allocations(|| drop(std::hint::black_box(Box::new(1u8))));
    assert_eq!(one, 1);

    let mut w = Wire::new(&p, Vec3::zeros(), Vec3::x(), 0.005).expect("wire");
    let mut contacts = 0;
    let mut nodes_seen = (usize::MAX, 0);
    let ((), count) = count_allocations(|| {
        for (which, lumen) in [(0, &straight as &dyn Lumen), (1, &curved as &dyn Lumen)] {
            for k in 0..1500 {
                // In at 100 mm/s for 0.8 s, then back out.
                let l = if k < 800 {
                    0.005 + 1e-4 * k as f64
                } else {
                    0.085 - 1e-4 * (k - 800) as f64
                };
                w.set_hub(l, 0.5 * (k as f64 * 2e-3).sin() + which as f64);
                if w.step(lumen).is_err() {
                    w.restore_good_state();
                } else if k % 100 == 0 {
                    w.save_good_state();
                }
                contacts += w.contacts().len();
                nodes_seen = (nodes_seen.0.min(w.num_nodes()), nodes_seen.1.max(w.num_nodes()));
            }
        }
        // The triangle wall, breathing every tick.
        for k in 0..800 {
            let s = 1.0 + 0.05 * (k as f64 * 0.02).sin();
            for (m, v) in moved.iter_mut().zip(&verts) {
                *m = Vec3::new(v.x, v.y * s, v.z * s);
            }
            if mesh.update_vertices(&moved).is_err() {
                break;
            }
            w.set_hub(0.005 + 1e-4 * k as f64, 0.0);
            if w.step(&mesh).is_err() {
                w.restore_good_state();
            }
            contacts += w.contacts().len();
        }
    });
    assert!(contacts > 0, "no contact was made");
    assert!(
        nodes_seen.1 > nodes_seen.0 + 20,
        "nodes did not enter and leave: {nodes_seen:?}"
    );
    assert_eq!(count, 0, "{count} allocations in the wire's steps");
}
