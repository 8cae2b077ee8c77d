//! Extremes: a steel wire (200 GPa) and a very floppy one, inserted at
//! 100 mm/s into a tube with a dead end and pushed on until they buckle, with
//! μ from 0 to 0.5; and a pre-shaped wire driven around a tight bend at
//! 100 mm/s; and into a triangulated curved vessel whose wall moves every
//! tick. Never a NaN, never more than 0.2 mm into the wall; the reset
//! path brings back the last good state.

use nvtmm::math::Vec3;
use nvtmm::wire::{CurvedTube, CurvedTubeShape, Lumen, StraightTube, TriangleLumen, Wire, WireParams};

const MAX_PEN: f64 = 2e-4;

/// Inserts from `from` to `to` (m) at 100 mm/s; returns the largest
/// penetration and the largest axial hub force seen.
fn drive(w: &mut Wire, lumen: &dyn Lumen, to: f64, what: &str) -> (f64, f64) {
    let mut l = w.inserted();
    let (mut pen, mut force): (f64, f64) = (0.0, 0.0);
    let mut k = 0;
    while l < to {
        l = (l + 1e-4).min(to);
        w.set_hub(l, 0.3 * (k as f64 * 1e-3).sin());
        let r = w.step(lumen).unwrap_or_else(|e| panic!("{what}: step {k}: {e}"));
        assert!(w.is_finite(), "{what}: step {k}: not finite");
        assert!(r.hub_axial_force_n.is_finite());
        for c in w.contacts() {
            assert!(c.normal_force.is_finite() && c.friction.iter().all(|f| f.is_finite()));
        }
        pen = pen.max(r.max_penetration_m);
        force = force.max(r.hub_axial_force_n);
        assert!(
            r.max_penetration_m <= MAX_PEN,
            "{what}: step {k}: penetration {:.3} mm",
            r.max_penetration_m * 1e3
        );
        k += 1;
    }
    (pen, force)
}

#[test]
fn pushing_into_a_dead_end_buckles_without_nan_or_penetration() {
    let tube = StraightTube::new(Vec3::new(-0.01, 0.0, 0.0), Vec3::x(), 0.07, 2e-3, true).expect("tube");
    for (name, e) in [("steel", 200e9), ("floppy", 1e6)] {
        for mu in [0.0, 0.1, 0.5] {
            let p = WireParams {
                youngs_modulus_pa: e,
                segment_length_m: 2e-3,
                max_nodes: 80,
                friction: mu,
                ..WireParams::default()
            };
            let mut w = Wire::new(&p, Vec3::zeros(), Vec3::x(), 0.005).expect("wire");
            let what = format!("{name}, μ = {mu}");
            // 60 mm to the dead end, then 25 mm more.
            let (pen, force) = drive(&mut w, &tube, 0.085, &what);
            let lateral = w
                .positions()
                .iter()
                .map(|x| (x.y * x.y + x.z * x.z).sqrt())
                .fold(0.0, f64::max);
            let tip = w.tip();
            println!(
                "{what}: max penetration {:.4} mm, max hub force {force:.3} N, max lateral {:.3} mm, tip x {:.2} mm",
                pen * 1e3,
                lateral * 1e3,
                tip.x * 1e3
            );
            assert!(
                tip.x <= 0.06 + 1e-4,
                "{what}: the tip went through the dead end: {tip:?}"
            );
            assert!(lateral > 0.5e-3, "{what}: the wire did not buckle (lateral {lateral})");
            assert!(force > 0.0, "{what}: no resistance at the hub");
        }
    }
}

#[test]
fn a_shaped_tip_driven_around_a_tight_bend_stays_inside() {
    let tube = CurvedTube::new(&CurvedTubeShape {
        start: Vec3::new(-0.01, 0.0, 0.0),
        tangent: Vec3::x(),
        toward: Vec3::y(),
        inlet: 0.02,
        bend_radius: 0.015,
        angle: 2.5,
        outlet: 0.1,
        radius: 4e-3,
    })
    .expect("tube");
    for (e, mu) in [(200e9, 0.5), (60e9, 0.1), (1e6, 0.0)] {
        let p = WireParams {
            youngs_modulus_pa: e,
            friction: mu,
            segment_length_m: 2e-3,
            max_nodes: 80,
            ..WireParams::default()
        };
        let mut w = Wire::new(&p, Vec3::zeros(), Vec3::x(), 0.005).expect("wire");
        let what = format!("E = {e:e}, μ = {mu}");
        let (pen, force) = drive(&mut w, &tube, 0.1, &what);
        println!(
            "bend, {what}: max penetration {:.4} mm, max hub force {force:.3} N",
            pen * 1e3
        );
        // Every node inside the lumen (within the penetration bound).
        for x in w.positions().iter().skip(2) {
            let h = tube.probe(*x, 1.0).expect("tube walls are everywhere");
            assert!(
                h.distance > 0.5 * p.diameter_m - MAX_PEN,
                "{what}: node at {x:?} is out"
            );
        }

        // The reset path: save, drive on, restore.
        w.save_good_state();
        let saved: Vec<Vec3> = w.positions().to_vec();
        let l = w.inserted();
        for _ in 0..20 {
            w.set_hub(l + 2e-3, 1.0);
            w.step(&tube).expect("finite");
        }
        assert!(w.positions() != saved.as_slice());
        w.restore_good_state();
        assert_eq!(w.positions(), saved.as_slice());
        assert!(w.is_finite());
    }
}

/// A triangulated curved tube (inner radius `a`, centreline bending by
/// `angle` with radius `r` after a straight inlet), normals inward.
fn curved_mesh(a: f64, r: f64, angle: f64) -> (Vec<Vec3>, Vec<[u32; 3]>) {
    let (nr, nl) = (20, 90);
    let inlet = 0.03;
    let total = inlet + r * angle + 0.05;
    let mut v = Vec::new();
    for l in 0..=nl {
        let s = -0.01 + (total + 0.01) * l as f64 / nl as f64;
        // Centreline point and frame (tangent t, normal toward the bend n, binormal z).
        let (c, t, n) = if s <= inlet {
            (Vec3::new(s, 0.0, 0.0), Vec3::x(), Vec3::y())
        } else if s <= inlet + r * angle {
            let phi = (s - inlet) / r;
            (
                Vec3::new(inlet + r * phi.sin(), r * (1.0 - phi.cos()), 0.0),
                Vec3::new(phi.cos(), phi.sin(), 0.0),
                Vec3::new(-phi.sin(), phi.cos(), 0.0),
            )
        } else {
            let c0 = Vec3::new(inlet + r * angle.sin(), r * (1.0 - angle.cos()), 0.0);
            let t = Vec3::new(angle.cos(), angle.sin(), 0.0);
            (
                c0 + t * (s - inlet - r * angle),
                t,
                Vec3::new(-angle.sin(), angle.cos(), 0.0),
            )
        };
        let b = t.cross(&n);
        for k in 0..nr {
            let phi = k as f64 / nr as f64 * std::f64::consts::TAU;
            v.push(c + (n * phi.cos() + b * phi.sin()) * a);
        }
    }
    let mut tris = Vec::new();
    for l in 0..nl {
        for k in 0..nr {
            let i = |l: usize, k: usize| (l * nr + k % nr) as u32;
            tris.push([i(l, k), i(l + 1, k), i(l, k + 1)]);
            tris.push([i(l, k + 1), i(l + 1, k), i(l + 1, k + 1)]);
        }
    }
    // Check the winding: the first triangle's normal points to the axis.
    let [p0, p1, p2] = tris[0].map(|i| v[i as usize]);
    let nrm = (p1 - p0).cross(&(p2 - p0));
    let mid = (p0 + p1 + p2) / 3.0;
    assert!(nrm.dot(&(Vec3::new(mid.x, 0.0, 0.0) - mid)) > 0.0, "winding");
    (v, tris)
}

#[test]
fn a_moving_triangle_wall_is_not_tunnelled_at_100_mm_per_s() {
    let (verts, tris) = curved_mesh(3e-3, 0.03, 1.8);
    let mut lumen = TriangleLumen::new(&verts, &tris).expect("surface");
    let mut moved = verts.clone();
    for (e, mu) in [(200e9, 0.5), (60e9, 0.1)] {
        let p = WireParams {
            youngs_modulus_pa: e,
            friction: mu,
            segment_length_m: 2e-3,
            max_nodes: 80,
            ..WireParams::default()
        };
        let mut w = Wire::new(&p, Vec3::zeros(), Vec3::x(), 0.005).expect("wire");
        let what = format!("mesh, E = {e:e}, μ = {mu}");
        let mut pen: f64 = 0.0;
        let mut contacts = 0;
        for k in 0..1000 {
            // The wall breathes by ±5 % about the inlet axis every tick.
            let sc = 1.0 + 0.05 * (k as f64 * 0.03).sin();
            for (m, v) in moved.iter_mut().zip(&verts) {
                *m = Vec3::new(v.x, v.y, v.z * sc);
            }
            lumen.update_vertices(&moved).expect("update");
            w.set_hub(0.005 + 1e-4 * k as f64, 0.2 * (k as f64 * 2e-3).sin());
            let r = w.step(&lumen).unwrap_or_else(|e| panic!("{what}: step {k}: {e}"));
            assert!(w.is_finite());
            contacts += r.contacts;
            pen = pen.max(r.max_penetration_m);
            assert!(
                r.max_penetration_m <= MAX_PEN,
                "{what}: step {k}: penetration {}",
                r.max_penetration_m
            );
        }
        // Every node still inside the faceted wall.
        for x in w.positions().iter().skip(2) {
            let h = lumen.probe(*x, 1.0).expect("a wall within 1 m");
            assert!(h.distance > 0.0, "{what}: node at {x:?} is beyond the wall");
        }
        println!(
            "{what}: max penetration {:.4} mm, {contacts} contacts, tip {:?}",
            pen * 1e3,
            w.tip()
        );
        assert!(contacts > 100, "{what}: the wire never touched the wall");
    }
}
