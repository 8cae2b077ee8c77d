//! Contact anywhere at the extremes: the stiffest wall (10 MPa) struck at a
//! fresh place at the hand's top speed, 32 patches at once, a contact on a
//! fixed node and a patch across a branch junction. No NaN ever, no
//! allocation in the loop's tick, and the force is continuous: from one
//! tick to the next it changes by no more than the pressure law allows for
//! the tool's motion over this tick or the one before (the full contact
//! disk's stiffness times the distance moved, 2×: the wall follows the tool
//! a tick late); under a still tool the wall moves on (the 10 MPa wall
//! struck at top speed rings, its force falling by up to ~10 % per tick,
//! printed), so there the rate of change itself may change by at most 5 %
//! of the force from one tick to the next: smooth. A lost or found contact
//! (what this guards against) is a jump of the whole force.

mod common;

use common::counting::count_allocations;
use nvtmm::experiment::contact::{Setup, SetupSpec};
use nvtmm::haptics::contact::MAX_SPHERES;
use nvtmm::haptics::device::DeviceSample;
use nvtmm::math::Vec3;
use nvtmm::soak::hand::HAND_TOP_SPEED_M_S;

#[global_allocator]
static GLOBAL: common::counting::Counting = common::counting::Counting;

fn sample(t: usize, dt: f64, position: Vec3) -> DeviceSample {
    DeviceSample {
        seq: t as u64,
        time_s: t as f64 * dt,
        position,
        velocity: Vec3::zeros(),
        ..DeviceSample::REST
    }
}

/// Free outer-wall nodes of `s`.
fn free_outer(s: &Setup) -> Vec<u32> {
    s.mesh
        .node_set("outer_wall")
        .unwrap()
        .iter()
        .copied()
        .filter(|i| s.fixed.binary_search(i).is_err())
        .collect()
}

/// Runs the servo along `path` (tool positions, one per tick) with `extra`
/// spheres; asserts finite forces, no allocation after the first tick and
/// a continuous force. Returns the largest force (N).
fn run_path(s: &Setup, path: &[Vec3], extra: &[Vec3]) -> f64 {
    let mut servo = s.servo(true).unwrap();
    servo.set_extra_spheres(extra);
    let dt = s.dynp.dt;
    // The stiffest a patch can press: the pressure stiffness over the
    // whole contact disk of the tool.
    let k_disk = s.cp.pressure_stiffness * std::f64::consts::PI * s.cp.tool_radius_m.powi(2);
    let (mut last, mut max_force, mut still_change) = (Vec3::zeros(), 0.0f64, 0.0f64);
    let mut last_delta = 0.0f64;
    let mut allocations = 0;
    for (t, x) in path.iter().enumerate() {
        let step_at = |t: usize| if t == 0 { 0.0 } else { (path[t] - path[t - 1]).norm() };
        let step = step_at(t).max(step_at(t.saturating_sub(1)));
        let (out, n) = count_allocations(|| servo.tick(Some(&sample(t + 1, dt, *x)), (t + 1) as f64 * dt, 0));
        if t > 0 {
            allocations += n;
        }
        let f = out.desired;
        assert!(f.iter().all(|v| v.is_finite()), "tick {t}: {f:?}");

        let c = servo.contact();
        assert!(c.sphere_forces.iter().all(|f| f.iter().all(|v| v.is_finite())));
        // Continuity (module doc).
        let allowed = (2.0 * k_disk * step).max(last_delta + 0.05 * f.norm().max(last.norm()));
        if step == 0.0 && last.norm() > 0.0 {
            still_change = still_change.max((f - last).norm() / f.norm().max(last.norm()));
        }
        assert!(
            (f - last).norm() <= allowed + 1e-6,
            "tick {t}: force {:.4} N after {:.4} N for a {:.4} mm step",
            f.norm(),
            last.norm(),
            step * 1e3
        );
        last_delta = (f - last).norm();
        last = f;
        max_force = max_force.max(f.norm());
    }
    assert_eq!(allocations, 0, "the tick allocated");
    eprintln!(
        "largest change per tick with the tool still: {:.1} %",
        100.0 * still_change
    );
    max_force
}

#[test]
fn the_stiffest_wall_struck_at_a_fresh_place_at_top_speed_stays_finite_and_continuous() {
    let s = Setup::with(&SetupSpec {
        nodes: 1458,
        r: 16,
        youngs_pa: 10e6,
        ..SetupSpec::default()
    })
    .unwrap();
    let normals = s.mesh.surface_vertex_normals();
    let outer = free_outer(&s);
    let rho = s.cp.tool_radius_m;
    let dt = s.dynp.dt;
    for f in [0.3, 0.5, 0.7] {
        let a = outer[(f * outer.len() as f64) as usize] as usize;
        let (x, n) = (s.mesh.rest()[a], normals[a]);
        // From 10 mm off the wall to 2 mm into it at the top speed, then held.
        let (from, to) = (x + n * (rho + 10e-3), x + n * (rho - 2e-3));
        let ticks = ((from - to).norm() / (HAND_TOP_SPEED_M_S * dt)).ceil() as usize;
        let mut path: Vec<Vec3> = (0..=ticks)
            .map(|k| from + (to - from) * (k as f64 / ticks as f64))
            .collect();
        path.extend(std::iter::repeat_n(to, 300));
        let fmax = run_path(&s, &path, &[]);
        eprintln!("10 MPa, node {a}: struck at {HAND_TOP_SPEED_M_S} m/s, largest force {fmax:.3} N");
        assert!(fmax > 0.0);
    }
}

#[test]
fn thirty_two_patches_at_once_are_all_corrected_and_finite() {
    let s = Setup::new(1458, 16, &Default::default()).unwrap();
    let normals = s.mesh.surface_vertex_normals();
    let outer = free_outer(&s);
    let rho = s.cp.tool_radius_m;
    let spheres: Vec<Vec3> = (0..MAX_SPHERES)
        .map(|k| {
            let a = outer[(k * outer.len()) / MAX_SPHERES + 3] as usize;
            s.mesh.rest()[a] + normals[a] * (rho - 1e-3)
        })
        .collect();
    let a = outer[3] as usize;
    let mut path: Vec<Vec3> = (0..=100)
        .map(|k| s.mesh.rest()[a] + normals[a] * (rho + 3e-3 - 4e-3 * k as f64 / 100.0))
        .collect();
    path.extend(std::iter::repeat_n(spheres[0], 400));
    let mut servo = s.servo(true).unwrap();
    servo.set_extra_spheres(&spheres[1..]);
    run_path(&s, &path, &spheres[1..]);
    for t in 1..=50 {
        servo.tick(Some(&sample(t, s.dynp.dt, spheres[0])), t as f64 * s.dynp.dt, 0);
    }
    let c = servo.contact();
    let touching = c.sphere_forces.iter().filter(|f| f.norm() > 0.0).count();
    eprintln!(
        "{touching} of {MAX_SPHERES} patches touching, {} nodes, corrected {}, truncated {}",
        c.nodes.len(),
        c.corrected,
        c.truncated
    );
    assert!(touching >= MAX_SPHERES - 2, "{touching} patches touching");
    assert!(c.corrected && !c.truncated && c.uncorrected == 0);
}

#[test]
fn a_contact_on_a_fixed_node_is_finite_and_pushes_back() {
    let s = Setup::new(1458, 16, &Default::default()).unwrap();
    let normals = s.mesh.surface_vertex_normals();
    let rho = s.cp.tool_radius_m;
    // An outer-wall node of the fixed inlet ring.
    let a = s
        .mesh
        .node_set("outer_wall")
        .unwrap()
        .iter()
        .copied()
        .find(|i| s.fixed.binary_search(i).is_ok())
        .expect("a fixed outer-wall node") as usize;
    let (x, n) = (s.mesh.rest()[a], normals[a]);
    let path: Vec<Vec3> = (0..400)
        .map(|k| x + n * (rho + 2e-3 - 3e-3 * (k.min(200) as f64 / 200.0)))
        .collect();
    let fmax = run_path(&s, &path, &[]);
    eprintln!("fixed node {a}: largest force {fmax:.3} N");
    assert!(fmax > 0.0, "the fixed wall pushes back");
}

#[test]
fn a_patch_across_a_branch_junction_is_finite_and_continuous() {
    let s = Setup::with(&SetupSpec {
        nodes: 1458,
        r: 16,
        branched: true,
        ..SetupSpec::default()
    })
    .unwrap();
    let mesh = &s.mesh;
    let normals = mesh.surface_vertex_normals();
    let rho = s.cp.tool_radius_m;
    let segment = |i: u32| -> Option<&str> {
        mesh.node_sets()
            .iter()
            .find(|(name, nodes)| name.starts_with("segment_") && nodes.binary_search(&i).is_ok())
            .map(|(name, _)| name.as_str())
    };
    let outer = free_outer(&s);
    // An outer-wall surface triangle whose vertices lie in two segments:
    // the aorta and a branch.
    let tri = mesh
        .surface()
        .iter()
        .find(|t| {
            t.iter().all(|v| outer.binary_search(v).is_ok())
                && t.iter().any(|&v| segment(v) == Some("segment_aorta"))
                && t.iter().any(|&v| segment(v).is_some_and(|n| n != "segment_aorta"))
        })
        .expect("an outer-wall triangle across a junction");
    let x = tri.iter().map(|&v| mesh.rest()[v as usize]).sum::<Vec3>() / 3.0;
    let n = tri.iter().map(|&v| normals[v as usize]).sum::<Vec3>().normalize();
    let labels: Vec<_> = tri.iter().map(|&v| segment(v)).collect();
    // Press 1.5 mm in, then slide 6 mm across the junction line.
    let along = (mesh.rest()[tri[1] as usize] - mesh.rest()[tri[0] as usize]).normalize();
    let mut path: Vec<Vec3> = (0..300)
        .map(|k| x + n * (rho + 2e-3 - 3.5e-3 * (k.min(150) as f64 / 150.0)))
        .collect();
    let held = *path.last().unwrap();
    path.extend((1..=300).map(|k| held + along * (6e-3 * (k as f64 / 300.0 - 0.5))));
    let fmax = run_path(&s, &path, &[]);
    eprintln!("junction triangle {tri:?} ({labels:?}): largest force {fmax:.3} N");
    assert!(fmax > 0.0);
}
