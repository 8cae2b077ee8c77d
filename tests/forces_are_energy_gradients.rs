//! Every model's force is minus the gradient of its energy, its `add_df` is
//! the derivative of its force, and its assembled tangent is −`add_df`
//! (symmetric), checked by central finite differences at random displacements
//! of realistic size (up to ~15% strain), on a small block and on the arch.

mod common;

use common::*;
use nvtmm::math::Vec3;
use nvtmm::mesh::arch::{generate, ArchParams};
use nvtmm::mesh::TetMesh;
use nvtmm::model::{BlockTangent, ForceModel};

/// Random displacement: a random affine part (up to ~10% strain) plus
/// per-node noise of `noise` edge lengths.
fn random_u(mesh: &TetMesh, rng: &mut Rng, noise: f64) -> Vec<Vec3> {
    let g = nvtmm::math::Mat3::from_fn(|_, _| 0.2 * rng.next());
    let h = mean_edge(mesh);
    mesh.rest().iter().map(|x| g * x + rng.vec3() * (noise * h)).collect()
}

/// Directional checks that scale to large meshes: −dW/ds along v equals f·v,
/// d f/ds along du equals add_df, K du equals −add_df, and add_df is
/// symmetric (v·df(w) = w·df(v)).
fn directional_checks(model: &dyn ForceModel, mesh: &TetMesh, u: &[Vec3], rng: &mut Rng) {
    let name = model.name();
    let n = mesh.num_nodes();
    let h = mean_edge(mesh);
    let f = forces(model, u);
    let fscale = max_norm(&f).max(1e-300);
    for trial in 0..3 {
        let v = rng.vecs(n, h);
        let w = rng.vecs(n, h);
        // Energy: the step makes nodes move ~1e-6 edge lengths.
        let s = 1e-6;
        let dw = (model.energy(&axpy(u, s, &v)) - model.energy(&axpy(u, -s, &v))) / (2.0 * s);
        let fv = dot(&f, &v);
        let scale = f.iter().zip(&v).map(|(a, b)| a.norm() * b.norm()).sum::<f64>();
        assert!(
            (dw + fv).abs() <= 1e-6 * scale,
            "{name} trial {trial}: -dW/ds = {} but f.v = {fv}",
            -dw
        );
        // Force derivative.
        let dfv = df(model, u, &v);
        let num: Vec<Vec3> = forces(model, &axpy(u, s, &v))
            .iter()
            .zip(&forces(model, &axpy(u, -s, &v)))
            .map(|(a, b)| (a - b) / (2.0 * s))
            .collect();
        let dscale = max_norm(&dfv).max(fscale * 1e-3);
        let err = max_diff(&num, &dfv) / dscale;
        assert!(
            err <= 1e-6,
            "{name} trial {trial}: add_df vs FD of forces, rel err {err:e}"
        );
        // Assembled tangent.
        let mut k = BlockTangent::zeros(mesh);
        model.add_stiffness(u, &mut k);
        let mut kv = vec![Vec3::zeros(); n];
        k.mul(&v, &mut kv);
        let minus_df: Vec<Vec3> = dfv.iter().map(|x| -x).collect();
        let err = max_diff(&kv, &minus_df) / dscale;
        assert!(err <= 1e-12, "{name} trial {trial}: K v vs -add_df, rel err {err:e}");
        // Symmetry of the operator (the stored tangent is symmetric by construction).
        let dfw = df(model, u, &w);
        let (a, b) = (dot(&w, &dfv), dot(&v, &dfw));
        assert!(
            (a - b).abs() <= 1e-12 * (a.abs() + b.abs()).max(dscale * h * h),
            "{name} trial {trial}: add_df not symmetric: {a} vs {b}"
        );
    }
}

#[test]
fn block_forces_are_minus_energy_gradient_per_dof() {
    let mesh = block(2, 2, 2, 0.01);
    let mut rng = Rng::new(7);
    for model in models(&mesh) {
        let name = model.name();
        for trial in 0..2 {
            let u = random_u(&mesh, &mut rng, 0.05);
            let f = forces(model.as_ref(), &u);
            let fscale = max_norm(&f);
            assert!(fscale > 0.0, "{name}: zero force at a deformed state");
            let s = 1e-8; // m, ~1e-6 of the edge length
            for i in 0..mesh.num_nodes() {
                for a in 0..3 {
                    let mut up = u.clone();
                    up[i][a] += s;
                    let mut um = u.clone();
                    um[i][a] -= s;
                    let num = -(model.energy(&up) - model.energy(&um)) / (2.0 * s);
                    assert!(
                        (num - f[i][a]).abs() <= 1e-6 * fscale,
                        "{name} trial {trial} node {i} axis {a}: -dW/du = {num}, f = {}",
                        f[i][a]
                    );
                }
            }
        }
    }
}

#[test]
fn block_dense_tangent_is_finite_difference_jacobian() {
    let mesh = block(2, 1, 1, 0.01);
    let n = mesh.num_nodes();
    let mut rng = Rng::new(11);
    for model in models(&mesh) {
        let name = model.name();
        let u = random_u(&mesh, &mut rng, 0.05);
        let mut k = BlockTangent::zeros(&mesh);
        model.add_stiffness(&u, &mut k);
        let kd = k.to_dense();
        let kscale = kd.amax();
        let s = 1e-8;
        for j in 0..3 * n {
            let mut up = u.clone();
            up[j / 3][j % 3] += s;
            let mut um = u.clone();
            um[j / 3][j % 3] -= s;
            let (fp, fm) = (forces(model.as_ref(), &up), forces(model.as_ref(), &um));
            for i in 0..3 * n {
                let num = -(fp[i / 3][i % 3] - fm[i / 3][i % 3]) / (2.0 * s);
                assert!(
                    (num - kd[(i, j)]).abs() <= 1e-6 * kscale,
                    "{name}: K[{i},{j}] = {} but -df_i/du_j = {num}",
                    kd[(i, j)]
                );
            }
        }
    }
}

#[test]
fn block_directional_derivatives_agree() {
    let mesh = block(3, 2, 2, 0.01);
    let mut rng = Rng::new(3);
    for model in models(&mesh) {
        let u = random_u(&mesh, &mut rng, 0.05);
        directional_checks(model.as_ref(), &mesh, &u, &mut rng);
    }
}

#[test]
fn arch_directional_derivatives_agree() {
    let arch = generate(&ArchParams::default(), 1458).expect("default arch");
    let mesh = &arch.mesh;
    let mut rng = Rng::new(5);
    for model in models(mesh) {
        let u = random_u(mesh, &mut rng, 0.05);
        directional_checks(model.as_ref(), mesh, &u, &mut rng);
    }
}
