//! Where the contact tick's time goes: `cargo run --release --example
//! contact_profile [nodes] [patches]`. Times, over the same pressed
//! state, the contact evaluation alone (rest positions, plain penalty;
//! deformed positions; with the residual compliance in series) and the
//! whole servo tick. A profiling aid behind docs/BENCHMARKS.md
//! ("Contact anywhere"), not a benchmark of record.

use nvtmm::experiment::contact::Setup;
use nvtmm::haptics::contact::{evaluate_spheres, Candidates, ContactOutput};
use nvtmm::haptics::device::DeviceSample;
use nvtmm::math::Vec3;
use nvtmm::reduced::compliance::ComplianceParams;
use std::time::Instant;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn time(reps: usize, mut f: impl FnMut()) -> f64 {
    let mut us = Vec::with_capacity(reps);
    for _ in 0..reps {
        let t0 = Instant::now();
        f();
        us.push(t0.elapsed().as_secs_f64() * 1e6);
    }
    median(us)
}

fn main() -> Result<(), String> {
    let args: Vec<String> = std::env::args().collect();
    let nodes: usize = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(5832);
    let patches: usize = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(1);
    let setup = Setup::new(nodes, 32, &ComplianceParams::default())?;
    let mesh = &setup.mesh;
    let normals = mesh.surface_vertex_normals();
    let outer = mesh.node_set("outer_wall").unwrap_or(&[]).to_vec();
    let mut s = 0x9E37_79B9_7F4A_7C15u64;
    let mut centres = Vec::new();
    while centres.len() < patches {
        s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        let i = outer[((s >> 33) as usize) % outer.len()];
        if setup.fixed.binary_search(&i).is_ok() {
            continue;
        }
        let i = i as usize;
        centres.push(mesh.rest()[i] + normals[i] * (setup.cp.tool_radius_m - 1e-3));
    }
    let mut servo = setup.servo(true)?;
    servo.set_extra_spheres(&centres[1..]);
    let reps = 3000;
    let mut t = 0u64;
    let mut tick = || {
        t += 1;
        let sample = DeviceSample::held_at(t, t as f64 * 1e-3, centres[0]);
        servo.tick(Some(&sample), t as f64 * 1e-3, 0);
    };
    for _ in 0..500 {
        tick();
    }
    let tick_us = time(reps, &mut tick);
    let mut free = setup.servo(true)?;
    let far = centres[0] + Vec3::new(0.0, 0.0, 1.0);
    let mut u = 0u64;
    let free_us = time(reps, || {
        u += 1;
        let sample = DeviceSample::held_at(u, u as f64 * 1e-3, far);
        free.tick(Some(&sample), u as f64 * 1e-3, 0);
    });
    println!("tick out of contact {free_us:.1} µs");
    let index = &setup.index;
    let mut scratch = Candidates::new();
    let mut out = ContactOutput::<32>::for_index(index);
    let rest_us = time(
        reps * std::env::var("REST_REPS")
            .ok()
            .and_then(|s| s.parse::<usize>().ok())
            .unwrap_or(1),
        || {
            evaluate_spheres(
                index,
                &setup.cp,
                &centres,
                |i| mesh.rest()[i as usize],
                |_| None,
                None,
                None,
                &mut scratch,
                &mut out,
            )
        },
    );
    let rows = &setup.rows;
    let q = nalgebra::SVector::<f64, 32>::from_fn(|i, _| 1e-4 * (i as f64).sin());
    // The same positions and rows, without and with the residual compliance.
    let mut deformed = |compliance: Option<&nvtmm::reduced::compliance::LocalCompliance>| {
        time(reps, || {
            evaluate_spheres(
                index,
                &setup.cp,
                &centres,
                |i| mesh.rest()[i as usize] + rows[i as usize] * q,
                |i| rows.get(i as usize),
                compliance,
                None,
                &mut scratch,
                &mut out,
            )
        })
    };
    let deformed_us = deformed(None);
    let series_us = deformed(Some(&setup.table));
    println!(
        "{} nodes, {patches} patches: tick {tick_us:.1} µs; contact alone: rest {rest_us:.1} µs, deformed {deformed_us:.1} µs, with compliance {series_us:.1} µs",
        mesh.num_nodes()
    );
    println!(
        "last evaluation: {} candidates, {} positions, {} triangles, {} samples, {} touched nodes, {} iterations",
        out.candidates,
        out.positions,
        out.triangles,
        out.samples,
        out.nodes.len(),
        out.iterations
    );
    Ok(())
}
