//! Where a wire presses on its catheter in a cannulation scenario, offline:
//! each inside node's normal force against where it lies along the
//! catheter's node polyline, and the summed normal force over time.
//!
//! The scenario's pair as the service builds it (its `[wire]`, `[guidewire]`
//! and `[catheter]`), against the wall inflated to its mean pressure and
//! held still and rigid (the service's wall moves and gives), the hubs
//! driven as the service drives them: the script's hand that watches the
//! tips (`catheter.script`, looking at both rods 60 times a second as the
//! stream does) through the stylus, the switch button and each
//! instrument's hub drive; without the wire's time limit on its extra
//! iterations.
//!
//! Printed: every `period` s, and at every step whose sum exceeds 50 N or
//! whose hub force exceeds half the grip's limit, the summed normal force
//! of the wire on the catheter, the most on one node, the deepest
//! penetration, the wire's hub force and both rods' iterations and
//! residuals. Then, at the step with the largest sum, every contact: the
//! node, its normal force, the catheter segment it lies along and where
//! along it (t: 0 and 1 are the catheter's nodes), the catheter's turn at
//! the nearer node and its sagitta over a segment, and which side of the
//! bend it presses. Last, over every step, the normal force summed by t
//! (docs/INSTRUMENTS.md "In the cannulation scenarios").
//!
//! `cargo run --release --example sheath_force -- [config] [seconds] [period_s]`
//! (default `rt-config/cannulate_left_common_carotid.toml`, its
//! `seconds`, 0.25 s).

use nvtmm::haptics::device::DeviceSample;
use nvtmm::haptics::touchx::LiveHand;
use nvtmm::math::Vec3;
use nvtmm::service::instrument::Selector;
use nvtmm::service::script::{TipWatch, TipWatcher, WatchingHand};
use nvtmm::service::setup::prepare;
use nvtmm::service::StartOptions;
use nvtmm::wire::coaxial::Coaxial;
use nvtmm::wire::coupling::InnerWall;
use nvtmm::wire::HubDrive;
use std::sync::Arc;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let path = args
        .next()
        .unwrap_or_else(|| "rt-config/cannulate_left_common_carotid.toml".into());
    let seconds: Option<f64> = args.next().map(|a| a.parse()).transpose()?;
    let period: f64 = args.next().map(|a| a.parse()).transpose()?.unwrap_or(0.25);
    let p = prepare(&StartOptions::file(&path))?;
    let (Some(wp), Some(g), Some(cat)) = (&p.cfg.wire, &p.cfg.guidewire, &p.cfg.catheter) else {
        return Err(format!("{path}: no [wire], [guidewire] and [catheter]").into());
    };
    let wp = nvtmm::wire::WireParams {
        residual_time_limit_us: 0.0,
        ..wp.clone()
    };
    let cp = cat.params(&wp);
    let wall = InnerWall::from_mesh(&p.mesh, &g.wall_set)?;
    let mut lumen = wall.lumen()?;
    let (access, axis) = g.hub_pose(&p.mesh, &wall, &lumen)?;
    if let Some(inf) = &p.inflated {
        let v: Vec<Vec3> = wall
            .mesh_nodes()
            .iter()
            .zip(wall.rest())
            .map(|(&i, x)| x + inf.u[i as usize])
            .collect();
        lumen.update_vertices(&v)?;
    }
    let steps_of_hand = cat
        .steps(g, [f64::INFINITY; 2])
        .map_err(|(k, e)| format!("catheter.script{k}: {e}"))?;
    let start = cat.start(g);
    let map = nvtmm::task::SegmentMap::from_mesh(&p.mesh, &g.wall_set)?;
    let watch = Arc::new(TipWatch::new(&steps_of_hand));
    let mut hand = WatchingHand::new(&steps_of_hand, &wp.drive, &start, map.names(), watch.clone())?;
    let mut watcher = TipWatcher::new(map, watch);
    let mut drives = [
        HubDrive::new(&wp, start[0].0, start[0].1)?,
        HubDrive::new(&wp, start[1].0, start[1].1)?,
    ];
    let mut selector = Selector::new([true, true]);
    let mut hubs = start;
    let end = seconds.unwrap_or(p.seconds);
    let look_every = (1.0 / (60.0 * wp.dt_s)).round().max(1.0) as usize;
    let line = |x: &[Vec3]| -> Vec<[f32; 3]> { x.iter().map(|p| [p.x as f32, p.y as f32, p.z as f32]).collect() };
    let mut pair = Coaxial::new(&wp, &cp, access, axis, g.inserted_m, cat.inserted_m)?;
    pair.set_friction(cat.wire_friction);
    pair.set_load_stiffness_share(cat.coupling_stiffness_share);
    let (r_in, r_w) = (0.5 * cp.inner_diameter_m, 0.5 * wp.diameter_m);
    println!(
        "{path}: {end} s; catheter segments {:.1} mm, inner radius {:.3} mm, wire radius {:.3} mm, clearance {:.3} mm",
        cp.segment_length_m * 1e3,
        r_in * 1e3,
        r_w * 1e3,
        (r_in - r_w) * 1e3
    );
    println!("| t (s) | wire (mm) | catheter (mm) | inside nodes | contacts | ΣN (N) | most on a node (N) | deepest (mm) | hub force (N) | wire it. | residual (N) | catheter it. | its residual (N) |");
    println!("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    let steps = (end / wp.dt_s).round() as usize;
    let every = (period / wp.dt_s).round().max(1.0) as usize;
    // Normal force summed by where along its catheter segment it presses
    // (ten bins of t), over every step.
    let mut by_t = [0.0f64; 10];
    let (mut worst, mut worst_t, mut worst_list) = (0.0f64, 0.0, Vec::new());
    let (mut hub_max, mut pen_max, mut sum_of_sums) = (0.0f64, 0.0f64, 0.0);
    for k in 0..steps {
        let t = k as f64 * wp.dt_s;
        let pose = hand.at(t);
        let sample = DeviceSample {
            position: pose.position,
            velocity: pose.velocity,
            buttons: pose.buttons,
            gimbal_rad: pose.gimbal_rad,
            time_s: t,
            ..DeviceSample::REST
        };
        selector.update(Some(&sample));
        for (j, d) in drives.iter_mut().enumerate() {
            let h = selector.hand(j, Some(&sample), t);
            if h.active {
                if h.engaged {
                    d.engage(&sample);
                }
                let c = d.command(&sample, t);
                hubs[j] = (c.inserted_m, c.roll_rad);
            }
        }
        pair.set_hubs(hubs[0].0, hubs[0].1, hubs[1].0, hubs[1].1);
        let r = pair.step(&lumen)?;
        let c = pair.catheter().positions().to_vec();
        let contacts = pair.wire().sheath_contacts();
        let x = pair.wire().positions();
        let mut most = 0.0f64;
        let mut list = Vec::with_capacity(contacts.len());
        for h in contacts {
            most = most.max(h.normal_force);
            // Where along the catheter's polyline the node lies.
            let (mut best, mut seg, mut tt) = (f64::INFINITY, 0, 0.0);
            for j in 0..c.len() - 1 {
                let e = c[j + 1] - c[j];
                let s = ((x[h.node] - c[j]).dot(&e) / e.norm_squared().max(1e-300)).clamp(0.0, 1.0);
                let d = (x[h.node] - (c[j] + e * s)).norm();
                if d < best {
                    (best, seg, tt) = (d, j, s);
                }
            }
            by_t[((tt * 10.0) as usize).min(9)] += h.normal_force;
            // The catheter's turn at the nearer of the segment's nodes, and
            // the bend's inner side there (toward the turn's centre).
            let m = if tt < 0.5 { seg } else { seg + 1 };
            let (turn, inward) = if m >= 1 && m + 1 < c.len() {
                let (e, f) = (c[m] - c[m - 1], c[m + 1] - c[m]);
                let phi = e.cross(&f).norm().atan2(e.dot(&f));
                (phi, (f.normalize() - e.normalize()).try_normalize(1e-12))
            } else {
                (0.0, None)
            };
            // The wall's normal points into the lumen: pressing the outer
            // side of the bend, that normal points toward the turn's centre.
            let side = inward.map_or(0.0, |v| h.normal.dot(&v));
            let lseg = (c[seg + 1] - c[seg]).norm();
            list.push((h.node, h.normal_force, seg, tt, turn, lseg, side, best));
        }
        hub_max = hub_max.max(r.wire.hub_axial_force_n.abs());
        pen_max = pen_max.max(r.wire.max_sheath_penetration_m);
        sum_of_sums += r.coaxial_normal_force_n;
        if r.coaxial_normal_force_n > worst {
            (worst, worst_t, worst_list) = (r.coaxial_normal_force_n, t, list);
        }
        let big = r.coaxial_normal_force_n > 50.0 || r.wire.hub_axial_force_n.abs() > 0.5 * wp.max_hub_force_n;
        if k % look_every == 0 {
            watcher.look(0, &line(pair.wire().inserted_polyline()));
            watcher.look(1, &line(pair.catheter().inserted_polyline()));
        }
        if k % every == 0 || k + 1 == steps || big {
            println!(
                "| {t:.3} | {:.1} | {:.1} | {} | {} | {:.2} | {most:.2} | {:.4} | {:.3} | {} | {:.3} | {} | {:.3} |",
                pair.wire().inserted() * 1e3,
                pair.catheter().inserted() * 1e3,
                pair.wire().inside_sheath().iter().filter(|&&b| b).count(),
                contacts.len(),
                r.coaxial_normal_force_n,
                r.wire.max_sheath_penetration_m * 1e3,
                r.wire.hub_axial_force_n,
                r.wire.iterations,
                r.wire.residual_n,
                r.catheter.iterations,
                r.catheter.residual_n
            );
        }
    }
    println!(
        "\nlargest ΣN {worst:.2} N at {worst_t:.3} s; mean ΣN {:.2} N; largest wire hub force {hub_max:.3} N; deepest {:.4} mm",
        sum_of_sums / steps as f64,
        pen_max * 1e3
    );
    println!("\nthe contacts at {worst_t:.3} s (side: +1 the bend's outer wall, -1 its inner):");
    println!("| node | N (N) | catheter segment | t | turn at the nearer node (deg) | sagitta L²κ/8 (mm) | side | off the polyline (mm) |");
    println!("|---:|---:|---:|---:|---:|---:|---:|---:|");
    for (node, f, seg, tt, turn, lseg, side, off) in &worst_list {
        // κ ≈ turn / L at a node of segments of length L.
        let sag = lseg * lseg * (turn / lseg) / 8.0;
        println!(
            "| {node} | {f:.3} | {seg} | {tt:.2} | {:.2} | {:.4} | {side:+.2} | {:.4} |",
            turn.to_degrees(),
            sag * 1e3,
            off * 1e3
        );
    }
    for w in watcher.report() {
        println!(
            "watched row {}: reached {}, met {} after {:.2} s",
            w.row, w.reached, w.met, w.took_s
        );
    }
    let total: f64 = by_t.iter().sum();
    println!("\nthe normal force over every step by t along the catheter's segment:");
    for (b, f) in by_t.iter().enumerate() {
        println!(
            "t {:.1}-{:.1}: {:5.1} %",
            b as f64 / 10.0,
            (b + 1) as f64 / 10.0,
            100.0 * f / total.max(1e-300)
        );
    }
    Ok(())
}
