//! Closed loop: a 45 g stylus (Touch X apparent mass, light viscous
//! friction) held by a simulated hand (a spring-damper to a moving reference)
//! is pushed into a stiff virtual wall rendered at 1 kHz with a zero-order
//! hold, a one-tick delay and a little negative damping (all three generate
//! energy). With the passivity filter, the energy delivered to the hand never
//! exceeds what the hand put in plus the initial tank; without it, the same
//! set-up pumps energy into the hand (the test has teeth). Energy is
//! integrated at 100 sub-steps per tick.

use nvtmm::haptics::passivity::{NormBound, PassivityFilter, PassivityParams};
use nvtmm::math::Vec3;

const T: f64 = 1e-3;
const SUB: usize = 100;
const MASS: f64 = 0.045; // kg
const B_DEV: f64 = 0.05; // N·s/m, the stylus' real viscous friction
const K_WALL: f64 = 3000.0; // N/m
const B_WALL: f64 = -0.5; // N·s/m: negative damping, deliberately active
const K_HAND: f64 = 200.0; // N/m
const B_HAND: f64 = 1.0; // N·s/m

struct Run {
    /// Max over time of the energy delivered to the hand minus the energy
    /// the hand put in (J).
    max_to_hand: f64,
    /// Mean penetration (m) and mean wall force (N) over the last 0.5 s.
    mean_pen: f64,
    mean_force: f64,
    fallbacks: u64,
}

/// `speed`: approach speed of the hand's reference (m/s); `filter`: None for
/// the raw wall (saturated at the peak force only).
fn run(speed: f64, mut filter: Option<&mut PassivityFilter>) -> Run {
    let dir = Vec3::new(0.3, 0.1, -1.0).normalize(); // mostly into the wall z < 0
    let start = Vec3::new(0.0, 0.0, 0.01);
    let depth = 0.012; // the reference ends 12 mm inside the wall
    let travel = (start.z + depth) / -dir.z;
    let t_end = travel / speed + 2.0;
    let reference = |t: f64| -> (Vec3, Vec3) {
        let s = (t * speed).min(travel);
        let v = if t * speed < travel { dir * speed } else { Vec3::zeros() };
        (start + dir * s, v)
    };
    let (mut x, mut v) = (start, Vec3::zeros());
    let (mut x_meas_prev, mut v_meas_prev) = (x, v);
    let mut to_hand = 0.0;
    let mut max_to_hand: f64 = 0.0;
    let (mut pen_sum, mut f_sum, mut n_sum) = (0.0, 0.0, 0usize);
    let ticks = (t_end / T) as usize;
    let h = T / SUB as f64;
    for k in 0..ticks {
        let t = k as f64 * T;
        // The model's force from the previous tick's sample (one tick of delay).
        let pen = (-x_meas_prev.z).max(0.0);
        let f_des = if pen > 0.0 {
            Vec3::new(0.0, 0.0, K_WALL * pen - B_WALL * v_meas_prev.z)
        } else {
            Vec3::zeros()
        };
        let f = match filter.as_deref_mut() {
            Some(fl) => fl.filter(f_des, x, v).force,
            None => {
                let n = f_des.norm();
                if n > 7.9 {
                    f_des * (7.9 / n)
                } else {
                    f_des
                }
            }
        };
        x_meas_prev = x;
        v_meas_prev = v;
        if t > t_end - 0.5 {
            pen_sum += (-x.z).max(0.0);
            f_sum += f.z;
            n_sum += 1;
        }
        // Zero-order hold over the tick, fine sub-steps (semi-implicit Euler).
        for j in 0..SUB {
            let (xr, vr) = reference(t + j as f64 * h);
            let f_hand = (xr - x) * K_HAND + (vr - v) * B_HAND; // hand on the stylus
            let a = (f + f_hand - v * B_DEV) / MASS;
            let v_new = v + a * h;
            let v_mid = (v + v_new) * 0.5;
            // Power from the stylus into the hand: −F_hand·v.
            to_hand += -f_hand.dot(&v_mid) * h;
            v = v_new;
            x += v * h;
            max_to_hand = max_to_hand.max(to_hand);
        }
    }
    Run {
        max_to_hand,
        mean_pen: pen_sum / n_sum as f64,
        mean_force: f_sum / n_sum as f64,
        fallbacks: filter.map_or(0, |f| f.stats().fallbacks()),
    }
}

fn params(credit: f64) -> PassivityParams {
    PassivityParams {
        norm_bound: NormBound::Peak,
        tank_initial_j: 5e-3,
        tank_min_j: 1e-3,
        tank_max_j: 0.02,
        damping_credit_ns_per_m: credit,
        ..PassivityParams::default()
    }
}

#[test]
fn the_raw_wall_generates_energy() {
    for speed in [0.05, 0.2, 0.5] {
        let r = run(speed, None);
        eprintln!("raw  speed {speed}: max energy to hand {:.4} J", r.max_to_hand);
        assert!(
            r.max_to_hand > 4.0 * params(0.0).tank_initial_j,
            "speed {speed}: {:.4} J",
            r.max_to_hand
        );
    }
}

#[test]
fn the_filtered_wall_is_passive_and_still_a_wall() {
    for credit in [0.0, 0.04] {
        for speed in [0.05, 0.2, 0.5] {
            let p = params(credit);
            let mut f = PassivityFilter::new(&p).unwrap();
            let r = run(speed, Some(&mut f));
            let s = f.stats();
            eprintln!(
                "qp credit {credit} speed {speed}: max to hand {:.5} J, pen {:.2} mm, force {:.2} N, energy rows {}, rate rows {}, tank low {:.5} J",
                r.max_to_hand,
                r.mean_pen * 1e3,
                r.mean_force,
                s.active_energy,
                s.active_rate,
                s.tank_low_j
            );
            assert!(
                r.max_to_hand <= p.tank_initial_j,
                "credit {credit} speed {speed}: {:.6} J delivered > initial tank {} J",
                r.max_to_hand,
                p.tank_initial_j
            );
            assert_eq!(r.fallbacks, 0, "{s:?}");
            assert!(
                s.active_energy > 0,
                "the energy row never acted: the test would not test it"
            );
            // Still a wall: the hand's steady push is held well short of the
            // 12 mm the hand's reference goes in (the filter softens an
            // active wall: the energy it withholds is what the delay and the
            // negative damping would have generated).
            assert!(r.mean_pen < 5e-3, "{:.2} mm", r.mean_pen * 1e3);
            assert!(r.mean_force > 1.0, "{:.2} N", r.mean_force);
        }
    }
}
