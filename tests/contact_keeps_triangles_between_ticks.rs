//! The contact keeps each sphere's triangles from one tick to the next
//! while the sphere and the surface under it move less than the slack
//! (`contact::Motion`, `COHERENCE_SLACK_M`): the result must be the one a
//! fresh grid search gives, tick by tick, while a probe slides and presses
//! over a surface that the reduced state keeps deforming, and the search
//! must run on far fewer ticks than it is skipped.

use nalgebra::SVector;
use nvtmm::experiment::contact::Setup;
use nvtmm::haptics::contact::{evaluate_spheres, Candidates, ContactOutput, Motion};
use nvtmm::math::Vec3;
use nvtmm::reduced::compliance::ComplianceParams;
use nvtmm::reduced::dynamics::row_times;

const R: usize = 32;

#[test]
fn kept_triangles_give_the_contact_a_fresh_search_gives() {
    let s = Setup::new(1458, 16, &ComplianceParams::default()).unwrap();
    let mesh = &s.mesh;
    let normals = mesh.surface_vertex_normals();
    let rows = &s.rows;
    let row_bound = rows.iter().map(|r| r.norm()).fold(0.0, f64::max);
    // Two probes on the outer wall, away from the fixed ends: one slides,
    // one presses deeper and lets go.
    let outer: Vec<u32> = mesh
        .node_set("outer_wall")
        .unwrap()
        .iter()
        .copied()
        .filter(|i| s.fixed.binary_search(i).is_err())
        .collect();
    let (a, b) = (outer[outer.len() / 3] as usize, outer[2 * outer.len() / 3] as usize);
    let rho = s.cp.tool_radius_m;
    let tangent = normals[a].cross(&Vec3::z()).normalize();
    let (mut kept, mut fresh) = (
        ContactOutput::<R>::for_index(&s.index),
        ContactOutput::<R>::for_index(&s.index),
    );
    let (mut scratch_k, mut scratch_f) = (Candidates::new(), Candidates::new());
    let ticks = 600;
    let no_offset = vec![nvtmm::math::Vec3::zeros(); mesh.num_nodes()];
    let (mut searches, mut touching) = (0, 0);
    for t in 0..ticks {
        let phase = t as f64 / ticks as f64;
        // The surface deforms: a smooth history of q, no node moving more
        // than about 0.6 mm.
        let amplitude = 0.3e-3 / row_bound;
        let q = SVector::<f64, R>::from_fn(|j, _| {
            if j < 16 {
                amplitude * (std::f64::consts::TAU * phase + j as f64).sin() / (1.0 + j as f64).sqrt()
            } else {
                0.0
            }
        });
        let position = |i: u32| mesh.rest()[i as usize] + row_times(&rows[i as usize], &q);
        let centres = [
            mesh.rest()[a] + normals[a] * (rho - 1.2e-3) + tangent * (4e-3 * phase),
            mesh.rest()[b] + normals[b] * (rho - 1e-3 * (std::f64::consts::PI * 2.0 * phase).sin()),
        ];
        // The positions are rest + Φ q: ū = 0, which lets a search pass
        // over the candidates Φ q cannot bring within reach.
        let motion = Motion {
            q: &q,
            row_bound,
            offset: Some(&no_offset),
        };
        evaluate_spheres(
            &s.index,
            &s.cp,
            &centres,
            position,
            |i| rows.get(i as usize),
            Some(s.table.as_ref()),
            Some(motion),
            &mut scratch_k,
            &mut kept,
        );
        evaluate_spheres(
            &s.index,
            &s.cp,
            &centres,
            position,
            |i| rows.get(i as usize),
            Some(s.table.as_ref()),
            None,
            &mut scratch_f,
            &mut fresh,
        );
        searches += kept.searches;
        touching += usize::from(!fresh.nodes.is_empty());
        let scale = fresh.tool_force.norm().max(1e-9);
        assert!(
            (kept.tool_force - fresh.tool_force).norm() <= 1e-9 * scale,
            "tick {t}: kept {:?} vs fresh {:?}",
            kept.tool_force,
            fresh.tool_force
        );
        for (k, f) in kept.sphere_forces.iter().zip(fresh.sphere_forces.iter()) {
            assert!((k - f).norm() <= 1e-9 * scale, "tick {t}: sphere {k:?} vs {f:?}");
        }
        let ks = fresh.reduced_stiffness.norm().max(1e-9);
        assert!(
            (kept.reduced_stiffness - fresh.reduced_stiffness).norm() <= 1e-9 * ks,
            "tick {t}"
        );
        assert!((kept.reduced_force - fresh.reduced_force).norm() <= 1e-9 * fresh.reduced_force.norm().max(1e-12));
        assert_eq!(kept.nodes.len(), fresh.nodes.len(), "tick {t}: touched nodes");
    }
    eprintln!("{ticks} ticks, 2 spheres: {searches} searches with kept triangles, {touching} ticks touching");
    assert!(
        touching >= ticks * 9 / 10,
        "the probes touch the wall on {touching} of {ticks} ticks"
    );
    assert!(
        searches < ticks / 2,
        "{searches} searches for {} sphere-ticks",
        2 * ticks
    );
}

/// Each patch keeps the residual compliance's blocks of its node pairs
/// between evaluations (`contact::PAIR_CACHE_NODES`); a different table (a
/// new basis) must replace them: an output that went from one table to
/// the other gives what a new output gives with the second table.
#[test]
fn kept_pair_blocks_follow_the_compliance_table() {
    // Two bases (16 and 8 vibration modes): two residual compliances.
    let a = Setup::new(1458, 16, &ComplianceParams::default()).unwrap();
    let b = Setup::new(1458, 8, &ComplianceParams::default()).unwrap();
    assert_ne!(a.table.id(), b.table.id());
    assert_eq!(a.table.id(), a.table.as_ref().clone().id(), "a copy keeps the identity");
    let mesh = &a.mesh;
    assert_eq!(mesh.num_nodes(), b.mesh.num_nodes());
    let normals = mesh.surface_vertex_normals();
    let outer: Vec<u32> = mesh
        .node_set("outer_wall")
        .unwrap()
        .iter()
        .copied()
        .filter(|i| a.fixed.binary_search(i).is_err())
        .collect();
    let rho = a.cp.tool_radius_m;
    // Two patches near each other (they couple) and one apart.
    let (i, j) = (outer[outer.len() / 3] as usize, outer[outer.len() / 2] as usize);
    let t = normals[i].cross(&Vec3::z()).normalize();
    let centres = [
        mesh.rest()[i] + normals[i] * (rho - 1e-3),
        mesh.rest()[i] + t * 4e-3 + normals[i] * (rho - 1e-3),
        mesh.rest()[j] + normals[j] * (rho - 1e-3),
    ];
    let q = SVector::<f64, R>::zeros();
    let eval = |s: &Setup, out: &mut ContactOutput<R>| {
        let mut scratch = Candidates::new();
        evaluate_spheres(
            &s.index,
            &s.cp,
            &centres,
            |k| s.mesh.rest()[k as usize] + row_times(&s.rows[k as usize], &q),
            |k| s.rows.get(k as usize),
            Some(s.table.as_ref()),
            None,
            &mut scratch,
            out,
        );
    };
    let mut carried = ContactOutput::<R>::for_index(&a.index);
    for (s, name) in [(&a, "a"), (&b, "b"), (&b, "b again"), (&a, "a again")] {
        eval(s, &mut carried);
        let mut new = ContactOutput::<R>::for_index(&s.index);
        eval(s, &mut new);
        assert!(new.corrected && !new.nodes.is_empty(), "{name}: the patches press");
        assert_eq!(carried.tool_force, new.tool_force, "table {name}");
        assert_eq!(carried.sphere_forces, new.sphere_forces, "table {name}");
        assert_eq!(carried.reduced_stiffness, new.reduced_stiffness, "table {name}");
    }
    // The two tables give different contacts (else the test shows nothing).
    let (mut oa, mut ob) = (
        ContactOutput::<R>::for_index(&a.index),
        ContactOutput::<R>::for_index(&b.index),
    );
    eval(&a, &mut oa);
    eval(&b, &mut ob);
    assert_ne!(oa.tool_force, ob.tool_force);
}
