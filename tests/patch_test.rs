//! Patch test: under a uniform affine displacement u = G X every element has
//! the same F = I + G, so interior nodes carry no net force and the forces on
//! a boundary face add up to the nominal traction of the analytic stress:
//! Σ_{nodes on face} f = −P N A (P the first Piola–Kirchhoff stress, N the
//! face's outward normal and A its area, both at rest).

mod common;

use common::*;
use nvtmm::material::{pk1, Law};
use nvtmm::math::Mat3;
use nvtmm::math::Vec3;
use nvtmm::model::{fem::Fem, tmm::Tmm, ForceModel};

const N: usize = 3;
const H: f64 = 0.01;

fn grad() -> Mat3 {
    // Stretch, shear and some rotation: 5–20% entries.
    Mat3::new(0.15, 0.05, -0.1, -0.08, -0.05, 0.12, 0.06, -0.2, 0.1)
}

/// Checks interior equilibrium and the six face resultants against `p`.
fn check(model: &dyn ForceModel, p: &Mat3) {
    let name = model.name();
    let mesh = block(N, N, N, H);
    let g = grad();
    let u: Vec<Vec3> = mesh.rest().iter().map(|x| g * x).collect();
    let f = forces(model, &u);
    let area = (N as f64 * H).powi(2);
    let scale = p.norm() * area;
    let len = N as f64 * H;
    let on = |x: f64, v: f64| (x - v).abs() < 1e-9 * len;
    for (i, x) in mesh.rest().iter().enumerate() {
        let interior = (0..3).all(|a| !on(x[a], 0.0) && !on(x[a], len));
        if interior {
            let r = f[i].norm() / scale;
            assert!(r < 1e-12, "{name}: interior node {i} has relative force {r:e}");
        }
    }
    for axis in 0..3 {
        for (side, sign) in [(0.0, -1.0), (len, 1.0)] {
            let normal = Vec3::ith(axis, sign);
            let total: Vec3 = mesh
                .rest()
                .iter()
                .zip(&f)
                .filter(|(x, _)| on(x[axis], side))
                .map(|(_, fi)| *fi)
                .sum();
            let expected = -(p * normal) * area;
            let r = (total - expected).norm() / scale;
            assert!(
                r < 1e-10,
                "{name}: face {axis}={side}: total {total:?}, expected {expected:?} (rel err {r:e})"
            );
        }
    }
}

#[test]
fn stvk_patch() {
    let m = material();
    let f = Mat3::identity() + grad();
    check(
        &Fem::new(&block(N, N, N, H), &m, Law::Stvk),
        &pk1(Law::Stvk, m.lame(), &f),
    );
}

#[test]
fn neo_hookean_patch() {
    let m = material();
    let f = Mat3::identity() + grad();
    check(
        &Fem::new(&block(N, N, N, H), &m, Law::NeoHookean),
        &pk1(Law::NeoHookean, m.lame(), &f),
    );
}

#[test]
fn linear_tensor_mass_patch() {
    // Linear elasticity: σ = λ tr(ε) I + 2μ ε with ε = sym(G).
    let m = material();
    let l = m.lame();
    let g = grad();
    let eps = (g + g.transpose()) * 0.5;
    let sigma = Mat3::identity() * (l.lambda * eps.trace()) + eps * (2.0 * l.mu);
    check(&Tmm::new(&block(N, N, N, H), &m), &sigma);
}
