//! The modal basis of a small arch (both ends fixed, linear tensor-mass
//! stiffness at rest) is what it claims: Φᵀ M Φ = I, each column an
//! eigenvector of K φ = ω² M φ, ω² positive and ascending, and the lowest
//! eigenvalues those of a dense generalized eigen solve of the same problem.
//! A warm start from the converged basis takes fewer iterations to the same modes,
//! and a basis augmented with attachment modes stays M-orthonormal with
//! diagonal reduced stiffness.

use nalgebra::{DMatrix, SymmetricEigen};
use nvtmm::material::Material;
use nvtmm::math::Vec3;
use nvtmm::mesh::arch::{generate, Arch, ArchParams};
use nvtmm::model::{tmm::Tmm, BlockTangent, ForceModel};
use nvtmm::reduced::ModalBasis;

struct Setup {
    arch: Arch,
    model: Tmm,
    mass: Vec<f64>,
    fixed: Vec<u32>,
    u: Vec<Vec3>,
}

fn setup() -> Setup {
    let arch = generate(&ArchParams::default(), 300).expect("arch");
    let mat = Material::aorta();
    let model = Tmm::new(&arch.mesh, &mat);
    let mass = arch.mesh.lumped_mass(mat.density);
    let mut fixed = arch.mesh.node_set("inlet").expect("inlet").to_vec();
    fixed.extend_from_slice(arch.mesh.node_set("outlet_descending").expect("outlet"));
    let u = vec![Vec3::zeros(); arch.mesh.num_nodes()];
    Setup {
        arch,
        model,
        mass,
        fixed,
        u,
    }
}

/// Per-DOF mass and free mask.
fn dof_mass(s: &Setup) -> (Vec<f64>, Vec<bool>) {
    let n = s.arch.mesh.num_nodes();
    let mut free = vec![true; 3 * n];
    for &f in &s.fixed {
        for c in 0..3 {
            free[3 * f as usize + c] = false;
        }
    }
    let m = (0..3 * n).map(|d| s.mass[d / 3]).collect();
    (m, free)
}

fn stiffness(s: &Setup) -> DMatrix<f64> {
    let mut k = BlockTangent::zeros(&s.arch.mesh);
    s.model.add_stiffness(&s.u, &mut k);
    k.to_dense()
}

#[test]
fn modes_are_mass_orthonormal_eigenvectors_matching_a_dense_solve() {
    let s = setup();
    let r = 16;
    let basis = ModalBasis::compute(&nvtmm::reduced::BasisSpec {
        stiffness: nvtmm::reduced::Stiffness::Model {
            mesh: &s.arch.mesh,
            model: &s.model,
            u: &s.u,
        },
        mass: &s.mass,
        fixed: &s.fixed,
        r,
        statics: nvtmm::reduced::Statics::None,
        warm: None,
        params: nvtmm::reduced::BasisParams::default(),
    })
    .expect("basis");
    assert_eq!(basis.len(), r);
    assert_eq!(basis.num_static, 0);
    let (m, free) = dof_mass(&s);
    let phi = &basis.phi;

    // Φᵀ M Φ = I.
    let mphi = DMatrix::from_fn(phi.nrows(), r, |i, j| m[i] * phi[(i, j)]);
    let gram = phi.transpose() * &mphi;
    let orth = (&gram - DMatrix::identity(r, r)).abs().max();
    assert!(orth <= 1e-8, "max |ΦᵀMΦ − I| = {orth:e}");

    // Fixed rows are zero.
    for (d, f) in free.iter().enumerate() {
        if !f {
            assert!(phi.row(d).iter().all(|&v| v == 0.0));
        }
    }

    // Each column satisfies K φ = ω² M φ on the free DOFs.
    let k = stiffness(&s);
    let kphi = &k * phi;
    let mut worst: f64 = 0.0;
    for j in 0..r {
        let (mut res, mut norm) = (0.0f64, 0.0f64);
        for d in (0..phi.nrows()).filter(|&d| free[d]) {
            res += (kphi[(d, j)] - basis.omega2[j] * mphi[(d, j)]).powi(2);
            norm += kphi[(d, j)].powi(2);
        }
        worst = worst.max((res / norm).sqrt());
    }
    assert!(worst <= 1e-6, "worst relative eigen-residual {worst:e}");

    // ω² positive and ascending.
    assert!(basis.omega2[0] > 0.0);
    assert!(basis.omega2.windows(2).all(|w| w[0] <= w[1]), "{:?}", basis.omega2);

    // Dense generalized eigen solve of the same free problem.
    let idx: Vec<usize> = (0..phi.nrows()).filter(|&d| free[d]).collect();
    let a = DMatrix::from_fn(idx.len(), idx.len(), |i, j| {
        k[(idx[i], idx[j])] / (m[idx[i]] * m[idx[j]]).sqrt()
    });
    let a = (&a + a.transpose()) * 0.5;
    let mut dense: Vec<f64> = SymmetricEigen::new(a).eigenvalues.iter().copied().collect();
    dense.sort_by(f64::total_cmp);
    let worst_rel = basis
        .omega2
        .iter()
        .zip(&dense)
        .map(|(w, d)| (w - d).abs() / d)
        .fold(0.0f64, f64::max);
    println!(
        "free DOFs {}, iterations {}, worst residual {worst:e}, worst eigenvalue error {worst_rel:e}, f = {:.2?} Hz",
        idx.len(),
        basis.iterations,
        basis
            .omega2
            .iter()
            .map(|w| w.sqrt() / (2.0 * std::f64::consts::PI))
            .collect::<Vec<_>>()
    );
    assert!(worst_rel <= 1e-8, "worst relative eigenvalue error {worst_rel:e}");
}

#[test]
fn warm_start_converges_faster_to_the_same_modes() {
    let s = setup();
    let cold = ModalBasis::compute(&nvtmm::reduced::BasisSpec {
        stiffness: nvtmm::reduced::Stiffness::Model {
            mesh: &s.arch.mesh,
            model: &s.model,
            u: &s.u,
        },
        mass: &s.mass,
        fixed: &s.fixed,
        r: 12,
        statics: nvtmm::reduced::Statics::None,
        warm: None,
        params: nvtmm::reduced::BasisParams::default(),
    })
    .expect("cold");
    let warm = ModalBasis::compute(&nvtmm::reduced::BasisSpec {
        stiffness: nvtmm::reduced::Stiffness::Model {
            mesh: &s.arch.mesh,
            model: &s.model,
            u: &s.u,
        },
        mass: &s.mass,
        fixed: &s.fixed,
        r: 12,
        statics: nvtmm::reduced::Statics::None,
        warm: Some(&cold),
        params: nvtmm::reduced::BasisParams::default(),
    })
    .expect("warm");
    println!("cold {} iterations, warm {}", cold.iterations, warm.iterations);
    assert!(warm.iterations < cold.iterations);
    for (a, b) in cold.omega2.iter().zip(&warm.omega2) {
        assert!((a - b).abs() <= 1e-10 * a, "{a} vs {b}");
    }
}

#[test]
fn augmented_basis_is_mass_orthonormal_with_diagonal_stiffness() {
    let s = setup();
    let contact = [s.arch.node(s.arch.top_ring, 0, s.arch.grid.layers - 1) as u32];
    let basis = ModalBasis::compute(&nvtmm::reduced::BasisSpec {
        stiffness: nvtmm::reduced::Stiffness::Model {
            mesh: &s.arch.mesh,
            model: &s.model,
            u: &s.u,
        },
        mass: &s.mass,
        fixed: &s.fixed,
        r: 8,
        statics: nvtmm::reduced::Statics::All(&contact),
        warm: None,
        params: nvtmm::reduced::BasisParams::default(),
    })
    .expect("augmented");
    assert_eq!(basis.num_static, 3);
    assert_eq!(basis.len(), 11);
    let (m, _) = dof_mass(&s);
    let phi = &basis.phi;
    let mphi = DMatrix::from_fn(phi.nrows(), phi.ncols(), |i, j| m[i] * phi[(i, j)]);
    let gram = phi.transpose() * &mphi;
    let orth = (&gram - DMatrix::identity(phi.ncols(), phi.ncols())).abs().max();
    assert!(orth <= 1e-8, "max |ΦᵀMΦ − I| = {orth:e}");
    let kr = phi.transpose() * stiffness(&s) * phi;
    let kmax = kr.abs().max();
    for i in 0..kr.nrows() {
        for j in 0..kr.ncols() {
            let expect = if i == j { basis.omega2[i] } else { 0.0 };
            assert!(
                (kr[(i, j)] - expect).abs() <= 1e-8 * kmax,
                "K_r[{i},{j}] = {}",
                kr[(i, j)]
            );
        }
    }
}

#[test]
fn bad_inputs_are_errors() {
    let s = setup();
    let n = s.arch.mesh.num_nodes();
    let e = ModalBasis::compute(&nvtmm::reduced::BasisSpec {
        stiffness: nvtmm::reduced::Stiffness::Model {
            mesh: &s.arch.mesh,
            model: &s.model,
            u: &s.u,
        },
        mass: &s.mass,
        fixed: &[n as u32],
        r: 4,
        statics: nvtmm::reduced::Statics::None,
        warm: None,
        params: nvtmm::reduced::BasisParams::default(),
    });
    assert!(
        matches!(e, Err(nvtmm::reduced::ReducedError::NodeOutOfRange { .. })),
        "{e:?}"
    );
    let e = ModalBasis::compute(&nvtmm::reduced::BasisSpec {
        stiffness: nvtmm::reduced::Stiffness::Model {
            mesh: &s.arch.mesh,
            model: &s.model,
            u: &s.u,
        },
        mass: &s.mass,
        fixed: &s.fixed,
        r: 0,
        statics: nvtmm::reduced::Statics::None,
        warm: None,
        params: nvtmm::reduced::BasisParams::default(),
    });
    assert!(
        matches!(e, Err(nvtmm::reduced::ReducedError::BadModeCount { .. })),
        "{e:?}"
    );
    // Nothing fixed: K is singular (rigid motions).
    let e = ModalBasis::compute(&nvtmm::reduced::BasisSpec {
        stiffness: nvtmm::reduced::Stiffness::Model {
            mesh: &s.arch.mesh,
            model: &s.model,
            u: &s.u,
        },
        mass: &s.mass,
        fixed: &[],
        r: 4,
        statics: nvtmm::reduced::Statics::None,
        warm: None,
        params: nvtmm::reduced::BasisParams::default(),
    });
    assert!(
        matches!(e, Err(nvtmm::reduced::ReducedError::NotPositiveDefinite)),
        "{e:?}"
    );
    let params = nvtmm::reduced::BasisParams {
        tol: 0.0,
        max_iterations: 10,
    };
    let e = ModalBasis::compute(&nvtmm::reduced::BasisSpec {
        stiffness: nvtmm::reduced::Stiffness::Model {
            mesh: &s.arch.mesh,
            model: &s.model,
            u: &s.u,
        },
        mass: &s.mass,
        fixed: &s.fixed,
        r: 4,
        statics: nvtmm::reduced::Statics::All(&[]),
        warm: None,
        params,
    });
    assert!(
        matches!(e, Err(nvtmm::reduced::ReducedError::BadParameter { name: "tol", .. })),
        "{e:?}"
    );
    let e = ModalBasis::compute(&nvtmm::reduced::BasisSpec {
        stiffness: nvtmm::reduced::Stiffness::Model {
            mesh: &s.arch.mesh,
            model: &s.model,
            u: &s.u,
        },
        mass: &s.mass[1..],
        fixed: &s.fixed,
        r: 4,
        statics: nvtmm::reduced::Statics::None,
        warm: None,
        params: nvtmm::reduced::BasisParams::default(),
    });
    assert!(
        matches!(e, Err(nvtmm::reduced::ReducedError::SizeMismatch { .. })),
        "{e:?}"
    );
}

/// Static error of a basis (columns in node-major DOF order) for unit loads
/// at the `dofs`: ‖M^½ (K⁻¹B − Φ(ΦᵀKΦ)⁻¹ΦᵀB)‖_F over the free DOFs, with
/// the free-DOF stiffness `kff` and its inverse given.
fn static_error(
    phi: &DMatrix<f64>,
    kff: &DMatrix<f64>,
    kinv_b: &DMatrix<f64>,
    b: &DMatrix<f64>,
    sqrt_m: &[f64],
) -> f64 {
    let kr = phi.transpose() * kff * phi;
    let red = phi * kr.lu().solve(&(phi.transpose() * b)).expect("K_r invertible");
    let mut e = kinv_b - red;
    for (i, mut row) in e.row_iter_mut().enumerate() {
        row *= sqrt_m[i];
    }
    e.norm()
}

#[test]
fn compressed_static_modes_are_nearly_the_best_rank_k() {
    // The compressed static columns (a randomized range finder) against the
    // exact best rank-k directions of the attachment responses left over by
    // the vibration modes, both computed here densely: the static error for
    // unit loads at every contact DOF must be within 5 % of the exact one's.
    let s = setup();
    let (m, free) = dof_mass(&s);
    let kd = stiffness(&s);
    let idx: Vec<usize> = (0..free.len()).filter(|&d| free[d]).collect();
    let nf = idx.len();
    let kff = DMatrix::from_fn(nf, nf, |i, j| kd[(idx[i], idx[j])]);
    let sqrt_m: Vec<f64> = idx.iter().map(|&d| m[d].sqrt()).collect();
    let is_fixed = |n: u32| s.fixed.contains(&n);
    let contact: Vec<u32> = s
        .arch
        .mesh
        .node_set("outer_wall")
        .expect("outer_wall")
        .iter()
        .copied()
        .filter(|&n| !is_fixed(n))
        .take(60)
        .collect();
    let (r_total, k) = (24, 10);
    let (modes, k_static) = nvtmm::reduced::static_split(r_total, contact.len(), k);
    assert_eq!(k_static, k);
    let basis = ModalBasis::compute(&nvtmm::reduced::BasisSpec {
        stiffness: nvtmm::reduced::Stiffness::Model {
            mesh: &s.arch.mesh,
            model: &s.model,
            u: &s.u,
        },
        mass: &s.mass,
        fixed: &s.fixed,
        r: r_total,
        statics: nvtmm::reduced::Statics::Compressed {
            contact: &contact,
            max_static: k,
        },
        warm: None,
        params: nvtmm::reduced::BasisParams::default(),
    })
    .expect("basis");
    assert_eq!(basis.num_static, k);
    let phi_rand = DMatrix::from_fn(nf, basis.len(), |i, j| basis.phi[(idx[i], j)]);

    // Exact: the lowest `modes` eigenvectors Y of M^-½ K M^-½, then the top
    // k left singular vectors of (I − YYᵀ) M^½ K⁻¹ B.
    let a = DMatrix::from_fn(nf, nf, |i, j| kff[(i, j)] / (sqrt_m[i] * sqrt_m[j]));
    let eig = SymmetricEigen::new(a);
    let mut order: Vec<usize> = (0..nf).collect();
    order.sort_by(|&x, &y| eig.eigenvalues[x].total_cmp(&eig.eigenvalues[y]));
    let y = DMatrix::from_fn(nf, modes, |i, j| eig.eigenvectors[(i, order[j])]);
    let pos: Vec<usize> = contact
        .iter()
        .flat_map(|&n| (0..3).map(move |c| 3 * n as usize + c))
        .map(|d| idx.binary_search(&d).expect("free contact DOF"))
        .collect();
    let b = DMatrix::from_fn(nf, pos.len(), |i, j| if pos[j] == i { 1.0 } else { 0.0 });
    let kinv_b = kff.clone().lu().solve(&b).expect("K invertible");
    let mut t = DMatrix::from_fn(nf, pos.len(), |i, j| sqrt_m[i] * kinv_b[(i, j)]);
    t -= &y * (y.transpose() * &t);
    let svd = t.svd(true, false);
    let u = svd.u.expect("U");
    let mut so: Vec<usize> = (0..svd.singular_values.len()).collect();
    so.sort_by(|&x, &z| svd.singular_values[z].total_cmp(&svd.singular_values[x]));
    let mut cols: Vec<nalgebra::DVector<f64>> = (0..modes).map(|j| y.column(j).into_owned()).collect();
    cols.extend((0..k).map(|j| u.column(so[j]).into_owned()));
    let ys = DMatrix::from_columns(&cols);
    let phi_exact = DMatrix::from_fn(nf, ys.ncols(), |i, j| ys[(i, j)] / sqrt_m[i]);

    let e_rand = static_error(&phi_rand, &kff, &kinv_b, &b, &sqrt_m);
    let e_exact = static_error(&phi_exact, &kff, &kinv_b, &b, &sqrt_m);
    let y_only = DMatrix::from_fn(nf, modes, |i, j| y[(i, j)] / sqrt_m[i]);
    let e_modes = static_error(&y_only, &kff, &kinv_b, &b, &sqrt_m);
    eprintln!(
        "static error: vibration modes only {e_modes:.4e}, exact best rank-{k} {e_exact:.4e}, randomized {e_rand:.4e}"
    );
    assert!(e_exact < e_modes, "the static columns help: {e_exact} vs {e_modes}");
    assert!(e_rand <= 1.05 * e_exact, "randomized {e_rand:e} vs exact {e_exact:e}");
}
