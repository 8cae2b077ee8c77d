//! The mass-spring stiffness derived from E (Van Gelder's rule in its
//! tetrahedral form, see `model::msm`) gives a block under small uniaxial
//! stretch an effective Young's modulus of the right order next to FEM. It
//! cannot reproduce ν: the effective Poisson ratio of a spring network is set
//! by the mesh, and is reported, not asserted to match.
//!
//! Set-up (linearized at rest, so it measures the small-strain moduli): an
//! n×n×n block, u_x prescribed on the two end faces (0 and εL), the ends free
//! to contract laterally, three more components fixed to remove the rigid
//! modes. FEM reproduces the affine solution exactly, so its effective E and
//! ν are the material's, which also validates the set-up.

mod common;

use common::*;
use nalgebra::{DMatrix, DVector};
use nvtmm::material::Law;
use nvtmm::mesh::TetMesh;
use nvtmm::model::{fem::Fem, msm::Msm, BlockTangent, ForceModel};

const N: usize = 4;
const H: f64 = 0.01;
const EPS: f64 = 1e-3;

/// Returns (effective E, effective ν) of the block under the model's rest tangent.
fn uniaxial(model: &dyn ForceModel, mesh: &TetMesh) -> (f64, f64) {
    let n = mesh.num_nodes();
    let len = N as f64 * H;
    let on = |v: f64, w: f64| (v - w).abs() < 1e-9 * len;
    let mut k = BlockTangent::zeros(mesh);
    model.add_stiffness(&vec![nvtmm::math::Vec3::zeros(); n], &mut k);
    let kd = k.to_dense();
    // Prescribed dofs and their values.
    let mut fixed: Vec<Option<f64>> = vec![None; 3 * n];
    for (i, x) in mesh.rest().iter().enumerate() {
        if on(x.x, 0.0) {
            fixed[3 * i] = Some(0.0);
        }
        if on(x.x, len) {
            fixed[3 * i] = Some(EPS * len);
        }
        if on(x.x, 0.0) && on(x.y, 0.0) && on(x.z, 0.0) {
            fixed[3 * i + 1] = Some(0.0);
            fixed[3 * i + 2] = Some(0.0);
        }
        if on(x.x, 0.0) && on(x.y, len) && on(x.z, 0.0) {
            fixed[3 * i + 2] = Some(0.0);
        }
    }
    let free: Vec<usize> = (0..3 * n).filter(|&j| fixed[j].is_none()).collect();
    let mut uc = DVector::zeros(3 * n);
    for (j, v) in fixed.iter().enumerate() {
        if let Some(v) = v {
            uc[j] = *v;
        }
    }
    let rhs = -(&kd * &uc);
    let kff = DMatrix::from_fn(free.len(), free.len(), |a, b| kd[(free[a], free[b])]);
    let bf = DVector::from_fn(free.len(), |a, _| rhs[free[a]]);
    let sol = kff.lu().solve(&bf).expect("constrained tangent is non-singular");
    let mut u = uc;
    for (a, &j) in free.iter().enumerate() {
        u[j] = sol[a];
    }
    let reaction = &kd * &u;
    let force_x: f64 = (0..n)
        .filter(|&i| on(mesh.rest()[i].x, len))
        .map(|i| reaction[3 * i])
        .sum();
    let e_eff = force_x / (len * len * EPS);
    // Lateral strain: mean slope of u_y over y (least squares through all nodes).
    let ys: Vec<f64> = mesh.rest().iter().map(|x| x.y).collect();
    let my = ys.iter().sum::<f64>() / n as f64;
    let muy = (0..n).map(|i| u[3 * i + 1]).sum::<f64>() / n as f64;
    let slope = (0..n).map(|i| (ys[i] - my) * (u[3 * i + 1] - muy)).sum::<f64>()
        / ys.iter().map(|y| (y - my).powi(2)).sum::<f64>();
    (e_eff, -slope / EPS)
}

/// The block with interior nodes jittered by up to ±15% of the cube size
/// (the faces stay planar, so the set-up is unchanged).
fn jittered_block() -> TetMesh {
    let mesh = block(N, N, N, H);
    let len = N as f64 * H;
    let mut rng = Rng::new(42);
    let rest = mesh
        .rest()
        .iter()
        .map(|x| {
            let interior = (0..3).all(|a| x[a] > 1e-9 * len && x[a] < len * (1.0 - 1e-9));
            if interior {
                x + rng.vec3() * (0.3 * H)
            } else {
                *x
            }
        })
        .collect();
    TetMesh::new(rest, mesh.tets().to_vec(), Default::default()).expect("jittered block is valid")
}

#[test]
fn msm_effective_young_modulus_is_of_fem_order() {
    check(&block(N, N, N, H), "regular");
    check(&jittered_block(), "jittered");
}

fn check(mesh: &TetMesh, label: &str) {
    let m = material();
    let (e_fem, nu_fem) = uniaxial(&Fem::new(mesh, &m, Law::Stvk), mesh);
    assert!(
        (e_fem / m.youngs_pa - 1.0).abs() < 1e-8,
        "{label}: FEM effective E {e_fem}"
    );
    assert!((nu_fem - m.poisson).abs() < 1e-8, "{label}: FEM effective nu {nu_fem}");
    let (e_msm, nu_msm) = uniaxial(&Msm::new(mesh, &m), mesh);
    let ratio = e_msm / e_fem;
    println!("{label}: MSM/FEM effective E ratio {ratio:.3}; effective nu: MSM {nu_msm:.3}, FEM {nu_fem:.3}");
    assert!(
        (1.0 / 3.0..3.0).contains(&ratio),
        "{label}: MSM/FEM effective E ratio {ratio}"
    );
    assert!(nu_msm.is_finite());
}
