//! The pair held still settles: with both hubs held, the wire's friction
//! on the catheter's lumen and the force its hub feels stop changing,
//! instead of turning over every step.
//!
//! The instrument-switch test's pair, offline (`examples/coaxial_grip.rs`):
//! the guidewire tests' branched arch, their J-tip wire, a 5 F vertebral
//! catheter over it, 20 and 15 mm inserted from the guided access. The
//! hand advances the wire at 30 mm/s from 0.8 to 1.3 s, the catheter from
//! 1.3 to 1.8 s, the wire again from 1.8 to 2.3 s, then holds both to 3 s.
//!
//! What it guards: the wire's friction enters the catheter's step as a
//! function of the catheter's own motion (`Wire::set_point_frictions`,
//! docs/CATHETER.md "The coupled step"). Handed over as a dead load, it
//! stretched the catheter axially by μΣλ/(EA/L), about 7 µm here, seven
//! times the friction's smoothing length; the wire, its slip measured
//! against that motion, slipped back the next step, and the friction along
//! the wire (±0.32 N) and the hub force (−0.38/+0.25 N) turned over every
//! step, a 500 Hz buzz in the hand (docs/INSTRUMENTS.md "The pair held
//! still").
//!
//! The bounds, over the last 0.4 s (0.3 s after the hands stopped): held
//! still, nothing drives the pair, so the friction along the wire and the
//! hub force change from one step to the next by a small fraction of the
//! friction's limit μΣλ (0.3 N here). A tenth of it lies far below a
//! reversal (up to 2 μΣλ) and above what the solves' residual tolerance
//! leaves on the hub over a converged step. And the friction along the
//! wire does not change sign from one step to the next while it is more
//! than a twentieth of that limit. Both couplings.

mod common;

use nvtmm::service::ServiceConfig;
use nvtmm::wire::coaxial::{Coaxial, Coupling};
use nvtmm::wire::coupling::InnerWall;

/// The summed friction of the lumen on the wire along the wire (toward
/// its tip), N.
fn friction_along(p: &Coaxial) -> f64 {
    let w = p.wire();
    let x = w.positions();
    w.sheath_contacts()
        .iter()
        .map(|c| {
            let along = (x[(c.node + 1).min(x.len() - 1)] - x[c.node - 1]).normalize();
            c.friction.dot(&along)
        })
        .sum()
}

fn held_still(coupling: Coupling) {
    let dir = tempfile::tempdir().unwrap();
    let base = common::guidewire::write(dir.path(), 3.0, "[]", false);
    let text = std::fs::read_to_string(&base).unwrap()
        + "\n[catheter]\nshape = \"vertebral\"\nfrench = 5.0\nmax_nodes = 96\ninserted_m = 0.015\n";
    let path = dir.path().join("pair.toml");
    std::fs::write(&path, text).unwrap();
    let cfg = ServiceConfig::load(&path).expect("the configuration loads");
    let mesh = nvtmm::mesh::io::read_mesh(&dir.path().join("arch.vtu")).unwrap();
    let (wp, g, cat) = (
        cfg.wire.as_ref().unwrap(),
        cfg.guidewire.as_ref().unwrap(),
        cfg.catheter.as_ref().unwrap(),
    );
    // Offline: every step gets its extra iterations (no time limit).
    let wp = nvtmm::wire::WireParams {
        residual_time_limit_us: 0.0,
        ..wp.clone()
    };
    let cp = cat.params(&wp);
    let wall = InnerWall::from_mesh(&mesh, &g.wall_set).unwrap();
    let lumen = wall.lumen().unwrap();
    let (access, axis) = g.hub_pose(&mesh, &wall, &lumen).unwrap();
    let mut p = Coaxial::new(&wp, &cp, access, axis, g.inserted_m, cat.inserted_m).unwrap();
    p.set_friction(cat.wire_friction);
    p.set_load_stiffness_share(cat.coupling_stiffness_share);
    p.set_coupling(coupling);
    let mu = p.friction();
    let (w0, c0, v) = (g.inserted_m, cat.inserted_m, 0.03);
    let (mut hub, mut fric, mut limit) = (Vec::new(), Vec::new(), 0.0f64);
    for k in 0..3000 {
        let t = k as f64 * wp.dt_s;
        let wl = w0 + v * ((t.clamp(0.8, 1.3) - 0.8) + (t.clamp(1.8, 2.3) - 1.8));
        let cl = c0 + v * (t.clamp(1.3, 1.8) - 1.3);
        p.set_hubs(wl, 0.0, cl, 0.0);
        let r = p.step(&lumen).unwrap_or_else(|e| panic!("step {k}: {e}"));
        assert!(p.is_finite(), "step {k}");
        if k >= 2600 {
            hub.push(r.wire.hub_axial_force_n);
            fric.push(friction_along(&p));
            limit = limit.max(mu * r.coaxial_normal_force_n);
        }
    }
    let change = |v: &[f64]| v.windows(2).map(|d| (d[1] - d[0]).abs()).fold(0.0f64, f64::max);
    let turns = fric
        .windows(2)
        .filter(|d| d[0] * d[1] < 0.0 && d[0].abs().min(d[1].abs()) > 0.05 * limit)
        .count();
    println!("{coupling:?}: the last steps held (hub force, the lumen's friction along the wire, N):");
    for k in hub.len() - 4..hub.len() {
        println!("  {:+.4} {:+.4}", hub[k], fric[k]);
    }
    println!(
        "{coupling:?}: μΣλ {limit:.3} N; largest change in a step: hub {:.4} N, friction {:.4} N; \
         the friction turned over {turns} times in {} steps",
        change(&hub),
        change(&fric),
        fric.len()
    );
    assert!(limit > 0.1, "the wire presses on the lumen: μΣλ = {limit} N");
    assert_eq!(
        turns,
        0,
        "{coupling:?}: the friction along the wire turned over {turns} times in {} steps",
        fric.len()
    );
    assert!(
        change(&fric) < 0.1 * limit,
        "{coupling:?}: the friction along the wire changed by {} N in a step, μΣλ = {limit} N",
        change(&fric)
    );
    assert!(
        change(&hub) < 0.1 * limit,
        "{coupling:?}: the hub force changed by {} N in a step, μΣλ = {limit} N",
        change(&hub)
    );
}

#[test]
fn a_held_pair_settles_its_friction_and_hub_force_with_the_gauss_seidel_coupling() {
    held_still(Coupling::GaussSeidel);
}

#[test]
fn a_held_pair_settles_its_friction_and_hub_force_with_the_lagged_coupling() {
    held_still(Coupling::Lagged);
}
