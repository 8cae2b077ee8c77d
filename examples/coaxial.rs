//! A shaped catheter straightened by its wire, and its curve re-forming as
//! the wire is pulled back: the clinician's move for a reverse-curve
//! (Simmons) catheter, offline.
//!
//! A 5 F catheter with the chosen tip shape (default `simmons`) and a
//! 0.035" nitinol wire inside it, its tip 5 mm behind the catheter's,
//! are advanced together at 100 mm/s into a straight 30 mm vessel (a
//! descending aorta) until 150 mm are in; the wire holds the shaped tip
//! nearly straight. Then the wire is pulled back 10 mm at a time at
//! 20 mm/s, the pair settling 0.5 s after each pull. After each stage the
//! example prints how far the wire's tip is behind the catheter's, the
//! catheter's tip angle (the turn from the shaft's direction to the tip's,
//! signed in the plane of the curve) against the shape's rest turn, and
//! the largest curvature along the shaped part.
//!
//! `cargo run --release --example coaxial -- [shape]` with `shape` one of
//! `straight`, `vertebral`, `berenstein`, `cobra`, `headhunter`,
//! `simmons`, `pigtail`.

use nvtmm::math::Vec3;
use nvtmm::wire::catheter::{catheter_params, TipShape};
use nvtmm::wire::coaxial::Coaxial;
use nvtmm::wire::{StraightTube, Wire, WireParams};

/// The signed turn (rad) from the catheter's shaft to its tip over its
/// last `shaped` metres, and the largest curvature there (1/m). The sign
/// is that of the main curve's plane, so a reverse curve subtracts.
fn tip_turn(c: &Wire, shaped: f64) -> (f64, f64) {
    let x = c.positions();
    let u = c.material_coordinates();
    let n = x.len();
    let mut turns = Vec::new();
    for i in 2..n - 1 {
        if u[i] > shaped + 3e-3 {
            continue;
        }
        let (e, f) = (x[i] - x[i - 1], x[i + 1] - x[i]);
        let b = e.cross(&f);
        let phi = b.norm().atan2(e.dot(&f));
        turns.push((b, phi, 0.5 * (e.norm() + f.norm())));
    }
    // The sum of the binormals (each |b| = sin φ |e| |f|) leans to the
    // longest turn, as the strongest single bend need not.
    let reference = turns.iter().fold(Vec3::zeros(), |a, t| a + t.0);
    let mut net = 0.0;
    let mut most: f64 = 0.0;
    for (b, phi, l) in turns {
        net += if b.dot(&reference) >= 0.0 { phi } else { -phi };
        most = most.max(phi / l);
    }
    (net, most)
}

fn main() {
    let name = std::env::args().nth(1).unwrap_or_else(|| "simmons".into());
    let Some(shape) = TipShape::from_name(&name) else {
        let names: Vec<&str> = TipShape::ALL.iter().map(|s| s.name()).collect();
        eprintln!("error: unknown tip shape {name:?}; one of {}", names.join(", "));
        std::process::exit(2);
    };
    let c = catheter_params(5.0, shape);
    let w = WireParams {
        tip_length_m: 0.0,
        segment_length_m: 3e-3,
        ..WireParams::default()
    };
    let vessel = StraightTube::new(Vec3::new(-0.005, 0.0, 0.0), Vec3::x(), 0.4, 15e-3, false).expect("vessel");
    let mut p = Coaxial::new(&w, &c, Vec3::zeros(), Vec3::x(), 0.005, 0.01).expect("pair");
    let step = |p: &mut Coaxial| {
        p.step(&vessel).unwrap_or_else(|e| {
            eprintln!("error: the coupled step failed: {e}");
            std::process::exit(1);
        })
    };
    let full = 0.15;
    let (mut lc, mut lw) = (p.catheter().inserted(), p.wire().inserted());
    while lc < full || lw < full - 0.005 {
        lc = (lc + 1e-4).min(full);
        lw = (lw + 1e-4).min(full - 0.005);
        p.set_hubs(lw, 0.0, lc, 0.0);
        step(&mut p);
    }
    for _ in 0..500 {
        step(&mut p);
    }
    let shaped = shape.shaped_length_m();
    println!(
        "{} 5 F catheter ({:.0} mm shaped, rest turn {:.1}°) over a 0.035\" nitinol wire, {:.0} mm inserted",
        shape.name(),
        shaped * 1e3,
        shape.net_turn_rad().to_degrees(),
        full * 1e3
    );
    println!("| wire's tip behind the catheter's (mm) | tip angle (°) | of the rest turn | largest curvature (1/m) | wire on the lumen (N) |");
    println!("|---:|---:|---:|---:|---:|");
    let mut pulled = 0.0;
    loop {
        let (turn, most) = tip_turn(p.catheter(), shaped);
        let r = step(&mut p);
        let rest = shape.net_turn_rad();
        let of = if rest != 0.0 {
            format!("{:.0} %", 100.0 * turn / rest)
        } else {
            "–".into()
        };
        println!(
            "| {:.0} | {:.1} | {of} | {:.1} | {:.3} |",
            -p.wire_lead_m() * 1e3,
            turn.to_degrees(),
            most,
            r.coaxial_normal_force_n
        );
        if pulled >= shaped + 0.02 {
            break;
        }
        // Pull back 10 mm at 20 mm/s, then settle for 0.5 s.
        let target = lw - 0.01;
        while lw > target {
            lw = (lw - 2e-5).max(target);
            p.set_hubs(lw, 0.0, lc, 0.0);
            step(&mut p);
        }
        for _ in 0..500 {
            step(&mut p);
        }
        pulled += 0.01;
    }
}
