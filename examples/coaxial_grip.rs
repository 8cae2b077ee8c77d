//! The wire's hub force in the instrument-switch test's pair, offline:
//! what holds the wire when its hub force is large.
//!
//! The test's scene (the guidewire tests' branched arch of about 2000
//! nodes, written to a temporary directory), its `[wire]`, and a 5 F
//! vertebral catheter over the wire, 20 mm and 15 mm inserted from the
//! guided access. The hubs follow the test's hand at 30 mm/s (the stylus at
//! 10 mm/s times the insertion scale): the wire from 0.8 to 1.3 s, the
//! catheter from 1.3 to 1.8 s, the wire again from 1.8 to 2.3 s, then both
//! held to 3 s. Against the rest wall (the service deforms it; here it
//! stays put), without the wire's time limit on its extra iterations.
//!
//! Printed: every step whose hub force exceeds the threshold (default
//! 3 N), with what could carry that force along the wire: the hub edge's
//! stretch, the friction of the catheter's lumen and of the vessel's wall
//! along the wire, the summed normal force on the lumen; and the step's
//! Newton iterations and residual. Then the largest hub force, how many
//! steps ended off equilibrium, and the last steps with both hubs held.
//!
//! `cargo run --release --example coaxial_grip [threshold_n]`

use nvtmm::service::ServiceConfig;
use nvtmm::wire::coaxial::Coaxial;
use nvtmm::wire::coupling::InnerWall;

#[allow(dead_code)]
#[path = "../tests/common/guidewire.rs"]
mod guidewire;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let threshold: f64 = match std::env::args().nth(1) {
        Some(a) => a.parse().map_err(|_| format!("threshold_n: {a:?} is not a number"))?,
        None => 3.0,
    };
    let dir = tempfile::tempdir()?;
    let base = guidewire::write(dir.path(), 3.0, "[]", false);
    let text = std::fs::read_to_string(&base)?
        + "\n[catheter]\nshape = \"vertebral\"\nfrench = 5.0\nmax_nodes = 96\ninserted_m = 0.015\n";
    let path = dir.path().join("switch.toml");
    std::fs::write(&path, text)?;
    let cfg = ServiceConfig::load(&path)?;
    let mesh = nvtmm::mesh::io::read_mesh(&dir.path().join("arch.vtu"))?;
    let (Some(wp), Some(g), Some(cat)) = (&cfg.wire, &cfg.guidewire, &cfg.catheter) else {
        return Err("the configuration has no [wire], [guidewire] and [catheter]".into());
    };
    let wp = nvtmm::wire::WireParams {
        residual_time_limit_us: 0.0,
        ..wp.clone()
    };
    let cp = cat.params(&wp);
    let wall = InnerWall::from_mesh(&mesh, &g.wall_set)?;
    let lumen = wall.lumen()?;
    let (access, axis) = g.hub_pose(&mesh, &wall, &lumen)?;
    let mut p = Coaxial::new(&wp, &cp, access, axis, g.inserted_m, cat.inserted_m)?;
    p.set_friction(cat.wire_friction);
    p.set_load_stiffness_share(cat.coupling_stiffness_share);
    let (w0, c0, v) = (g.inserted_m, cat.inserted_m, 0.03);
    let ea = wp.youngs_modulus_pa * wp.area();
    let (mut worst, mut worst_t, mut off) = (0.0f64, 0.0, 0);
    let steps = 3000;
    println!("|  t (s) | wire (mm) | catheter (mm) | hub force (N) | hub edge's stretch (N) | lumen's friction along the wire (N) | lumen's normal force (N) | wall's friction (N) | Newton it. | residual (N) |");
    println!("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for k in 0..steps {
        let t = k as f64 * wp.dt_s;
        let wl = w0 + v * ((t.clamp(0.8, 1.3) - 0.8) + (t.clamp(1.8, 2.3) - 1.8));
        let cl = c0 + v * (t.clamp(1.3, 1.8) - 1.3);
        p.set_hubs(wl, 0.0, cl, 0.0);
        let r = p.step(&lumen)?;
        let wire = p.wire();
        let x = wire.positions();
        let u = wire.material_coordinates();
        // The hub edge's tension (positive: stretched), from its rest length.
        let rest = u[1] - u[2];
        let stretch = ea / rest * ((x[2] - x[1]).norm() - rest);
        // Along the wire toward its tip at a node.
        let along = |i: usize| (x[(i + 1).min(x.len() - 1)] - x[i - 1]).normalize();
        let lumen_f: f64 = wire
            .sheath_contacts()
            .iter()
            .map(|c| c.friction.dot(&along(c.node)))
            .sum();
        let wall_f: f64 = wire.contacts().iter().map(|c| c.friction.dot(&along(c.node))).sum();
        let f = r.wire.hub_axial_force_n;
        if r.wire.residual_n > wp.residual_tolerance_n {
            off += 1;
        }
        if f.abs() > worst {
            (worst, worst_t) = (f.abs(), t);
        }
        if f.abs() > threshold || k + 4 >= steps {
            println!(
                "| {t:.3} | {:.2} | {:.2} | {f:.3} | {stretch:.3} | {lumen_f:.3} | {:.2} | {wall_f:.3} | {} | {:.3} |",
                wire.inserted() * 1e3,
                p.catheter().inserted() * 1e3,
                r.coaxial_normal_force_n,
                r.wire.iterations,
                r.wire.residual_n
            );
        }
    }
    println!(
        "largest hub force {worst:.3} N at {worst_t:.3} s; {off} of {steps} wire steps ended off equilibrium \
         (residual above {} N)",
        wp.residual_tolerance_n
    );
    Ok(())
}
