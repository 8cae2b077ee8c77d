//! Contact at depth, one point: is the loop's settled contact consistent
//! with its own geometry?
//!
//! `cargo run --release --example contact_depth_gaps -- NODE PUSH_MM [paper|human]`
//! holds the probe `PUSH_MM` into the branched arch's wall at surface node
//! NODE (as `nvtmm experiment contact --branched` does) for 1.5 s of the
//! loop, then compares, node by node, the loop's settled contact forces
//! with the reference's (the full linear model, its active set iterated to
//! convergence), and the displacement along the probe's axis: the loop's
//! modal part Φq, its residual dent ΔW f (the compliance table times the
//! loop's own node forces) and the reference's. Last, the plain contact
//! (no series solve) evaluated on the loop's surface with that dent added,
//! X + Φq + ΔW f: at an equilibrium that is consistent with its own
//! geometry, this gives back the loop's force (the reference satisfies
//! this by construction). docs/RESULTS.md, "At depth".
use nvtmm::experiment::contact::{reference, touched_of, Setup, SetupSpec, Wall};
use nvtmm::haptics::contact::{evaluate_spheres, Candidates, ContactOutput};
use nvtmm::haptics::device::DeviceSample;
use nvtmm::math::{Mat3, Vec3};
use nvtmm::reduced::compliance::ExactCompliance;
use std::collections::BTreeMap;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let node: u32 = args.get(1).expect("NODE").parse().expect("NODE");
    let push_m: f64 = args.get(2).expect("PUSH_MM").parse::<f64>().expect("PUSH_MM") * 1e-3;
    let human = args.get(3).map(String::as_str) == Some("human");
    let s = Setup::with(&SetupSpec {
        nodes: 5832,
        r: 32,
        branched: true,
        wall: if human { Wall::Human } else { Wall::Paper },
        pressure_pa: if human { 12.4e3 } else { 0.0 },
        ..SetupSpec::default()
    })
    .unwrap();
    let mesh = &s.mesh;
    let rest = mesh.rest();
    let nrm = mesh.surface_vertex_normals()[node as usize];
    let rt = s.cp.tool_radius_m;
    let tool = rest[node as usize] + nrm * (rt - push_m);
    let touching = rest[node as usize] + nrm * rt;
    let mut servo = s.servo(true).unwrap();
    let mut last = Vec3::zeros();
    let (mut lo, mut hi) = (f64::INFINITY, 0.0f64);
    for t in 1..=1500 {
        let smp = DeviceSample::held_at(t, t as f64 * 1e-3, tool);
        last = servo.tick(Some(&smp), t as f64 * 1e-3, 0).desired;
        if t > 1400 {
            lo = lo.min(last.norm());
            hi = hi.max(last.norm());
        }
    }
    println!("the loop's force over its last 100 ticks: {lo:.4} to {hi:.4} N");
    let c = servo.contact();
    let mut loop_f: BTreeMap<u32, Vec3> = BTreeMap::new();
    for nc in c.nodes.iter() {
        *loop_f.entry(nc.node).or_insert_with(Vec3::zeros) += nc.force;
    }
    let touched = touched_of(&servo);
    let seed: Vec<u32> = touched.iter().map(|t| t.node).collect();
    let mut exact = ExactCompliance::new(&s.k, &s.fixed).unwrap();
    let refr = reference(mesh, &s.cp, &s.index, &mut exact, &[tool], Some(&[touching]), &seed).unwrap();
    let ref_f: BTreeMap<u32, (Vec3, Vec3)> = refr.node_forces.iter().map(|&(i, f, u)| (i, (f, u))).collect();
    let block = |i: u32, j: u32| -> Mat3 {
        s.table
            .block(i, j)
            .copied()
            .or_else(|| s.table.block(j, i).map(|x| x.transpose()))
            .unwrap_or_else(Mat3::zeros)
    };
    let dent = |i: u32| -> Vec3 { loop_f.iter().map(|(&b, f)| block(i, b) * f).sum() };
    println!(
        "node {node}, push {} mm, wall {}: loop {:.4} N ({} nodes, series iterations {}), reference {:.4} N ({} in contact, {} solved for)",
        push_m * 1e3,
        if human { "human" } else { "paper" },
        last.norm(),
        loop_f.len(),
        c.iterations,
        refr.forces[0].norm(),
        refr.active,
        refr.nodes
    );
    println!("along the probe's axis n (into the wall is negative), mm; forces mN:");
    println!("node | rest dist to centre | loop |f| | ref |f| | loop Φq·n | loop ΔWf·n | loop total·n | ref u·n");
    let mut all: Vec<u32> = loop_f.keys().chain(ref_f.keys()).copied().collect();
    all.sort_unstable();
    all.dedup();
    for &i in &all {
        let modal = servo.node_position(i) - rest[i as usize];
        let d = dent(i);
        let (rf, ru) = ref_f.get(&i).copied().unwrap_or((Vec3::zeros(), Vec3::zeros()));
        println!(
            "{i:5} | {:6.2} | {:7.2} | {:7.2} | {:7.3} | {:7.3} | {:7.3} | {:7.3}",
            (rest[i as usize] - tool).norm() * 1e3,
            loop_f.get(&i).map_or(0.0, |f| f.norm()) * 1e3,
            rf.norm() * 1e3,
            modal.dot(&nrm) * 1e3,
            d.dot(&nrm) * 1e3,
            (modal + d).dot(&nrm) * 1e3,
            ru.dot(&nrm) * 1e3,
        );
    }
    // The plain contact on the loop's surface with its own dent.
    let mut scratch = Candidates::new();
    let mut out = ContactOutput::<1>::for_index(&s.index);
    for (label, with_dent) in [("X + Φq", false), ("X + Φq + ΔW f", true)] {
        evaluate_spheres(
            &s.index,
            &s.cp,
            &[tool],
            |i| {
                let x = servo.node_position(i);
                if with_dent {
                    x + dent(i)
                } else {
                    x
                }
            },
            |_| None,
            None,
            None,
            &mut scratch,
            &mut out,
        );
        let inward = out.nodes.iter().filter(|nc| nc.force.dot(&nrm) > 0.0).count();
        println!(
            "plain contact on {label}: {:.4} N on {} nodes ({} pushed outward, against the wall's normal), deepest {:.3} mm",
            out.tool_force.norm(),
            out.nodes.len(),
            inward,
            out.max_depth * 1e3
        );
    }
}
