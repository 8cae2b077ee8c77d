//! The guidewire scenario of `rt-config/guidewire.toml` without threads or
//! a device: the wire driven by the script's hub commands against the rest
//! inner wall of the scene's mesh, printing the tip's segment as it goes.
//! For tuning the script; the service runs the same wire in its thread.
//!
//! `cargo run --release --example guidewire_offline [rt-config/guidewire.toml]`
//! (`GUIDEWIRE_NO_BUCKLING=1`: without the buckling check).

use nvtmm::math::Vec3;
use nvtmm::service::ServiceConfig;
use nvtmm::wire::coupling::InnerWall;
use nvtmm::wire::Wire;
use std::path::Path;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let arg = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "rt-config/guidewire.toml".into());
    let cfg = ServiceConfig::load(Path::new(&arg))?;
    let scene = nvtmm::scene::Scene::load(&cfg.resolve(&cfg.scene))?;
    let built = scene.build()?;
    let (Some(wp), Some(g)) = (&cfg.wire, &cfg.guidewire) else {
        return Err("the configuration has no [wire] and [guidewire]".into());
    };
    let wall = InnerWall::from_mesh(&built.mesh, &g.wall_set)?;
    let lumen = wall.lumen()?;
    if let Some((names, label)) = built.mesh.segment_labels() {
        for (s, name) in names.iter().enumerate() {
            let pts: Vec<Vec3> = wall
                .mesh_nodes()
                .iter()
                .zip(wall.rest())
                .filter(|(&i, _)| label[i as usize] as usize == s)
                .map(|(_, p)| *p)
                .collect();
            let c = pts.iter().sum::<Vec3>() / pts.len().max(1) as f64;
            let lo = pts.iter().fold(Vec3::repeat(f64::INFINITY), |a, p| a.inf(p));
            let hi = pts.iter().fold(Vec3::repeat(f64::NEG_INFINITY), |a, p| a.sup(p));
            println!(
                "{name:>22}: {} wall vertices, centroid {:.1?} mm, box {:.1?} .. {:.1?} mm",
                pts.len(),
                (c * 1e3).as_slice(),
                (lo * 1e3).as_slice(),
                (hi * 1e3).as_slice()
            );
        }
    }
    let (access_point, axis) = g.hub_pose(&built.mesh, &wall, &lumen)?;
    println!(
        "hub at {:.1?} mm, axis {:.3?}",
        (access_point * 1e3).as_slice(),
        axis.as_slice()
    );
    let mut w = Wire::new(wp, access_point, axis, g.inserted_m)?;
    // `GUIDEWIRE_NO_BUCKLING=1`: without the buckling check, to compare.
    if std::env::var_os("GUIDEWIRE_NO_BUCKLING").is_some() {
        w.set_buckling_check(false);
    }
    let dt = wp.dt_s;
    let end = g.script.last().map(|r| r[0]).unwrap_or(1.0) + 1.0;
    let steps = (end / dt).round() as usize;
    let mut last_seg = String::new();
    let mut worst: f64 = 0.0;
    let mut buckled = 0usize;
    // The largest |axial hub force| and Newton residual over each 0.1 s.
    let (mut axial_max, mut residual_max, mut fed_max) = (0.0f64, 0.0f64, 0.0f64);
    // `GUIDEWIRE_TRACE=t0,t1` prints every step between t0 and t1 (s).
    let trace: Option<(f64, f64)> = std::env::var("GUIDEWIRE_TRACE").ok().and_then(|v| {
        let (a, b) = v.split_once(',')?;
        Some((a.trim().parse().ok()?, b.trim().parse().ok()?))
    });
    let t0 = std::time::Instant::now();
    let mut step_us = Vec::with_capacity(steps);
    for k in 0..steps {
        let t = k as f64 * dt;
        // Linear between script rows (the device eases; close enough here).
        let (ins, roll) = g.script_at(t);
        w.set_hub(ins, roll);
        let ts = std::time::Instant::now();
        let rep = w.step(&lumen).map_err(|e| format!("t = {t:.3} s: {e}"))?;
        step_us.push(ts.elapsed().as_secs_f64() * 1e6);
        worst = worst.max(rep.max_penetration_m);
        buckled += rep.buckled as usize;
        if let Some((a, b)) = trace {
            if t >= a && t <= b {
                println!(
                    "  step {k}: fed {:7.2} µm  nodes {}  it {}  axial {:8.3} N  residual {:.2e} N  slipped {}  contacts {}",
                    rep.fed_m * 1e6,
                    w.num_nodes(),
                    rep.iterations,
                    rep.hub_axial_force_n,
                    rep.residual_n,
                    rep.grip_slipped,
                    rep.contacts
                );
            }
        }
        axial_max = axial_max.max(rep.hub_axial_force_n.abs());
        residual_max = residual_max.max(rep.residual_n);
        fed_max = fed_max.max(rep.fed_m.abs());
        if k % 100 == 99 {
            let seg = wall.segment_at(wall.rest(), w.tip()).unwrap_or("?").to_string();
            if seg != last_seg || (k + 1) % 500 == 0 {
                println!(
                    "t {:5.2} s  inserted {:6.1} mm  roll {:5.2}  tip {:.1?} mm  {}  contacts {}  \
                     axial {:.3} N (0.1 s max {:.3})  residual max {:.2e} N  feed max {:.1} µm",
                    t,
                    w.inserted() * 1e3,
                    w.roll(),
                    (w.tip() * 1e3).as_slice(),
                    seg,
                    rep.contacts,
                    rep.hub_axial_force_n,
                    axial_max,
                    residual_max,
                    fed_max * 1e6
                );
                last_seg = seg;
            }
            axial_max = 0.0;
            residual_max = 0.0;
            fed_max = 0.0;
        }
    }
    println!(
        "end: tip in {}, {} nodes, deepest {:.3} mm, {:.1} µs a step, {buckled} steps moved off a saddle",
        wall.segment_at(wall.rest(), w.tip()).unwrap_or("?"),
        w.num_nodes(),
        worst * 1e3,
        t0.elapsed().as_secs_f64() / steps as f64 * 1e6
    );
    let p = nvtmm::rt::stats::Percentiles::of(&step_us);
    println!(
        "step time: p50 {:.1} µs, p99 {:.1} µs, p99.9 {:.1} µs, max {:.1} µs",
        p.p50, p.p99, p.p999, p.max
    );
    Ok(())
}
