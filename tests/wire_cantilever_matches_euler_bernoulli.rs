//! A clamped straight wire under a tip load: a small load deflects the tip
//! by δ = F L³ / (3 E I) within 1 %; a large one puts the tip on the elastica
//! (integrated here by shooting with RK4 to far better than the bound)
//! within 2 % of the length.

use nvtmm::math::Vec3;
use nvtmm::wire::{NoWall, Wire, WireParams};

const L: f64 = 0.1;

fn wire() -> Wire {
    let p = WireParams {
        segment_length_m: 1e-3,
        max_nodes: 110,
        tip_length_m: 0.0,
        friction: 0.0,
        newton_iterations: 5,
        ..WireParams::default()
    };
    let w = Wire::new(&p, Vec3::zeros(), Vec3::x(), L).expect("wire");
    assert!((w.inserted() - L).abs() < 1e-12);
    w
}

/// Steps until the tip stops moving; returns the tip.
fn settle(w: &mut Wire) -> Vec3 {
    let mut last = w.tip();
    for k in 0..20000 {
        w.step(&NoWall).expect("finite");
        let t = w.tip();
        if k > 10 && (t - last).norm() < 1e-11 {
            return t;
        }
        last = t;
    }
    panic!("did not settle");
}

#[test]
fn small_tip_load_deflects_as_euler_bernoulli() {
    let mut w = wire();
    let ei = w.params().bending_stiffness();
    // δ / L = 0.2 %: the linear theory's own error is far below 1 %.
    let f = 3.0 * ei * 0.002 * L / (L * L * L);
    w.set_tip_load(Vec3::new(0.0, 0.0, -f));
    let tip = settle(&mut w);
    let expect = f * L.powi(3) / (3.0 * ei);
    let got = -tip.z;
    let err = (got - expect).abs() / expect;
    println!(
        "tip deflection {got:e} m, Euler–Bernoulli {expect:e} m, error {:.4} %",
        err * 100.0
    );
    assert!(err < 0.01, "error {:.3} %", err * 100.0);
}

/// The elastica of a cantilever under a tip load F (pointing −z): θ(s) the
/// tangent's angle from +x, EI θ'' = F cos θ, θ(0) = 0, θ'(L) = 0. Returns
/// the tip (x, z).
fn elastica_tip(alpha: f64) -> (f64, f64) {
    // In units of L: θ'' = α cos θ with α = F L² / EI.
    let shoot = |c: f64| -> (f64, f64, f64) {
        let n = 20000;
        let h = 1.0 / n as f64;
        let (mut th, mut om, mut x, mut z) = (0.0f64, c, 0.0f64, 0.0f64);
        let rhs = |th: f64, om: f64| (om, alpha * th.cos(), th.cos(), th.sin());
        for _ in 0..n {
            let k1 = rhs(th, om);
            let k2 = rhs(th + 0.5 * h * k1.0, om + 0.5 * h * k1.1);
            let k3 = rhs(th + 0.5 * h * k2.0, om + 0.5 * h * k2.1);
            let k4 = rhs(th + h * k3.0, om + h * k3.1);
            th += h / 6.0 * (k1.0 + 2.0 * k2.0 + 2.0 * k3.0 + k4.0);
            om += h / 6.0 * (k1.1 + 2.0 * k2.1 + 2.0 * k3.1 + k4.1);
            x += h / 6.0 * (k1.2 + 2.0 * k2.2 + 2.0 * k3.2 + k4.2);
            z += h / 6.0 * (k1.3 + 2.0 * k2.3 + 2.0 * k3.3 + k4.3);
        }
        (om, x, z)
    };
    // θ'(0) = −α x_tip ∈ [−α, 0]; θ'(L) rises with θ'(0).
    let (mut lo, mut hi) = (-alpha, 0.0);
    for _ in 0..80 {
        let mid = 0.5 * (lo + hi);
        if shoot(mid).0 > 0.0 {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    let (_, x, z) = shoot(0.5 * (lo + hi));
    (x * L, z * L)
}

#[test]
fn large_tip_load_puts_the_tip_on_the_elastica() {
    // Sanity of the reference: Bisshopp & Drucker (1945) give, for
    // α = F L² / EI = 1, a vertical tip deflection of 0.3017 L.
    let (_, z1) = elastica_tip(1.0);
    assert!((-z1 / L - 0.3017).abs() < 5e-4, "reference {}", -z1 / L);

    let mut w = wire();
    let ei = w.params().bending_stiffness();
    let alpha = 3.0;
    let f = alpha * ei / (L * L);
    w.set_tip_load(Vec3::new(0.0, 0.0, -f));
    let tip = settle(&mut w);
    let (xr, zr) = elastica_tip(alpha);
    let err = ((tip.x - xr).powi(2) + (tip.z - zr).powi(2)).sqrt() / L;
    println!(
        "α = {alpha}: tip ({:.5}, {:.5}) m, elastica ({xr:.5}, {zr:.5}) m, error {:.3} % of L",
        tip.x,
        tip.z,
        err * 100.0
    );
    assert!(err < 0.02, "error {:.3} % of L", err * 100.0);
}
