//! Two contact patches 10 mm apart pressed at once (two points of an
//! instrument on the wall): once settled, the force the loop renders on
//! each matches the full linear model's with both loaded (same pressure
//! contact on the deformed surface triangles, exact K⁻¹ blocks), within
//! 10 %, on the outer and on the inner wall. The patches load each other
//! through the residual compliance, so each is also compared with the same
//! patch pressed alone (printed: the coupling the test covers).

use nvtmm::experiment::contact::{touched_of, Setup};
use nvtmm::haptics::device::DeviceSample;
use nvtmm::math::Vec3;
use nvtmm::reduced::compliance::ComplianceParams;

/// Settled loop reactions on `spheres` (the first is the tool).
fn settle(s: &Setup, spheres: &[Vec3], seconds: f64) -> (Vec<Vec3>, Vec<nvtmm::experiment::contact::Touched>) {
    let mut servo = s.servo(true).unwrap();
    servo.set_extra_spheres(&spheres[1..]);
    let ticks = (seconds / s.dynp.dt).round() as usize;
    for t in 1..=ticks {
        let sample = DeviceSample::held_at(t as u64, t as f64 * s.dynp.dt, spheres[0]);
        let out = servo.tick(Some(&sample), t as f64 * s.dynp.dt, 0);
        assert!(out.desired.iter().all(|v| v.is_finite()));
    }
    let c = servo.contact();
    (c.sphere_forces.iter().copied().collect(), touched_of(&servo))
}

#[test]
fn two_patches_10_mm_apart_each_match_the_full_model_with_both_loaded() {
    let s = Setup::new(5832, 32, &ComplianceParams::default()).unwrap();
    let mesh = &s.mesh;
    let normals = mesh.surface_vertex_normals();
    let rest = mesh.rest();
    let push = 0.5e-3;
    let rho = s.cp.tool_radius_m;
    let mut pairs = 0;
    for (set, picks) in [("outer_wall", [0.3, 0.45, 0.6]), ("inner_wall", [0.35, 0.5, 0.65])] {
        let free: Vec<u32> = mesh
            .node_set(set)
            .unwrap()
            .iter()
            .copied()
            .filter(|i| s.fixed.binary_search(i).is_err())
            .collect();
        for f in picks {
            let a = free[(f * free.len() as f64) as usize] as usize;
            // The node of the same wall nearest to 10 mm from a, on the
            // same side (normals within 45°).
            let b = free
                .iter()
                .map(|&j| j as usize)
                .filter(|&j| normals[j].dot(&normals[a]) > 0.7)
                .min_by(|&i, &j| {
                    let d = |k: usize| ((rest[k] - rest[a]).norm() - 10e-3).abs();
                    d(i).total_cmp(&d(j))
                })
                .unwrap();
            let gap = (rest[b] - rest[a]).norm();
            assert!(
                (gap - 10e-3).abs() < 1.5e-3,
                "{set}: nodes {a} and {b} are {gap} m apart"
            );
            let spheres = [rest[a] + normals[a] * (rho - push), rest[b] + normals[b] * (rho - push)];
            let (both, touched) = settle(&s, &spheres, 1.5);
            let full = s.full_reactions(&spheres, &touched).unwrap();
            let (alone, _) = settle(&s, &spheres[..1], 1.5);
            for k in 0..2 {
                let ratio = both[k].norm() / full[k].norm();
                eprintln!(
                    "{set} nodes {a}/{b} ({:.1} mm apart), patch {k}: loop {:.4} N, full {:.4} N, ratio {ratio:.3}; patch 0 alone {:.4} N",
                    gap * 1e3,
                    both[k].norm(),
                    full[k].norm(),
                    alone[0].norm()
                );
                assert!(full[k].norm() > 0.0, "the full model is pressed at patch {k}");
                assert!(
                    (ratio - 1.0).abs() <= 0.10,
                    "{set} nodes {a}/{b}, patch {k}: ratio {ratio:.3}"
                );
                // Same direction too.
                assert!(both[k].normalize().dot(&full[k].normalize()) > 0.98);
            }
            pairs += 1;
        }
    }
    assert_eq!(pairs, 6);
}
