//! A tube under internal pressure, solved by the full nonlinear tensor-mass
//! model with the follower pressure load in the small-strain limit, against
//! the closed forms: Lamé's thick-walled cylinder (plane strain) within 1 %,
//! and the thin-wall radial compliance dr/dp = r²/(E h) (open ends).

use nvtmm::material::{Law, Material};
use nvtmm::math::Vec3;
use nvtmm::mesh::arch::ArchGrid;
use nvtmm::mesh::tube::{generate, TubeParams};
use nvtmm::mesh::TetMesh;
use nvtmm::model::factory::build_model;
use nvtmm::model::ModelKind;
use nvtmm::solver::pressure::{LuminalPressure, PressureSchedule, PressureTangent};
use nvtmm::solver::statics::{solve_pressurized, StaticParams};

const E: f64 = 1e6;
const NU: f64 = 0.3;
/// p / E = 1e-4: strains of that order, so geometric nonlinearity is far
/// below the 1 % checked.
const P: f64 = 100.0;

/// Radial displacement of every node of a layer, averaged.
fn mean_radial(mesh: &TetMesh, u: &[Vec3], set: &str) -> (f64, f64) {
    let ids = mesh.node_set(set).unwrap();
    let (mut ur, mut r) = (0.0, 0.0);
    for &i in ids {
        let x = mesh.rest()[i as usize];
        let radial = Vec3::new(x.x, x.y, 0.0);
        ur += u[i as usize].dot(&radial.normalize());
        r += radial.norm();
    }
    (ur / ids.len() as f64, r / ids.len() as f64)
}

/// Holds the in-plane rigid motions (nodes on the ±x axis keep u_y = 0, on
/// the +y axis u_x = 0: by symmetry the pressure moves them only radially)
/// and u_z on the rings listed.
fn mask(mesh: &TetMesh, z_rings: &[&str]) -> Vec<[bool; 3]> {
    let mut m = vec![[false; 3]; mesh.num_nodes()];
    for set in z_rings {
        for &i in mesh.node_set(set).unwrap() {
            m[i as usize][2] = true;
        }
    }
    for (i, x) in mesh.rest().iter().enumerate() {
        if x.y.abs() < 1e-12 {
            m[i][1] = true;
        }
        if x.x.abs() < 1e-12 && x.y > 0.0 {
            m[i][0] = true;
        }
    }
    m
}

fn solve(mesh: &TetMesh, mask: &[[bool; 3]]) -> Vec<Vec3> {
    let mat = Material {
        youngs_pa: E,
        poisson: NU,
        density: 1000.0,
    };
    let model = build_model(ModelKind::Nvtmm, mesh, &mat, Law::Stvk, &[]);
    let load = LuminalPressure::on_set(
        mesh,
        "inner_wall",
        PressureSchedule::steady(P),
        PressureTangent::Symmetric,
    )
    .unwrap();
    let mut u = vec![Vec3::zeros(); mesh.num_nodes()];
    let rep = solve_pressurized(mesh, model.as_ref(), &load, P, mask, &StaticParams::default(), &mut u).unwrap();
    assert!(rep.rel_residual <= 1e-9);
    u
}

#[test]
fn thick_walled_cylinder_matches_lame_plane_strain_within_one_percent() {
    let (a, b) = (0.010, 0.020);
    // A one-cell slice with u_z = 0 on both faces: exactly plane strain.
    let grid = ArchGrid {
        axial: 2,
        circumferential: 128,
        layers: 13,
    };
    let mesh = generate(
        &TubeParams {
            inner_radius: a,
            outer_radius: b,
            length: (b - a) / 12.0,
        },
        grid,
    )
    .unwrap();
    let u = solve(&mesh, &mask(&mesh, &["end_0", "end_1"]));
    let big_a = P * a * a / (b * b - a * a);
    let big_b = P * a * a * b * b / (b * b - a * a);
    let lame = |r: f64| (1.0 + NU) / E * ((1.0 - 2.0 * NU) * big_a * r + big_b / r);
    for set in ["inner_wall", "outer_wall"] {
        let (ur, r) = mean_radial(&mesh, &u, set);
        let exact = lame(r);
        let err = (ur - exact).abs() / exact;
        println!(
            "{set}: r = {r:.5} m, u_r = {ur:.4e} m, Lamé {exact:.4e} m, error {:.3} %",
            100.0 * err
        );
        assert!(err < 0.01, "{set}: {ur:e} vs Lamé {exact:e} ({:.2} %)", 100.0 * err);
    }
    // Plane strain: nothing moves along the axis.
    assert!(u.iter().all(|d| d.z == 0.0));
}

#[test]
fn thin_tube_radial_compliance_matches_r2_over_eh() {
    // r/h = 20, open ends: u_z held on one face only, so σ_z ≈ 0.
    let (a, h) = (0.010, 0.0005);
    let grid = ArchGrid {
        axial: 2,
        circumferential: 160,
        layers: 3,
    };
    let mesh = generate(
        &TubeParams {
            inner_radius: a,
            outer_radius: a + h,
            length: 0.0004,
        },
        grid,
    )
    .unwrap();
    let u = solve(&mesh, &mask(&mesh, &["end_0"]));
    // The middle layer is at the mean radius.
    let mid: Vec<u32> = (0..mesh.num_nodes() as u32).filter(|&i| i % 3 == 1).collect();
    let (mut ur, mut r) = (0.0, 0.0);
    for &i in &mid {
        let x = mesh.rest()[i as usize];
        let radial = Vec3::new(x.x, x.y, 0.0);
        ur += u[i as usize].dot(&radial.normalize());
        r += radial.norm();
    }
    let (ur, r) = (ur / mid.len() as f64, r / mid.len() as f64);
    let compliance = ur / P;
    let thin = r * r / (E * h);
    // Lamé with σ_z = 0 (plane stress), the exact answer the thin-wall
    // estimate approximates to O(h/r).
    let b = a + h;
    let big_a = P * a * a / (b * b - a * a);
    let big_b = P * a * a * b * b / (b * b - a * a);
    let lame = ((1.0 - NU) * big_a * r + (1.0 + NU) * big_b / r) / E / P;
    let err_thin = (compliance - thin).abs() / thin;
    let err_lame = (compliance - lame).abs() / lame;
    println!(
        "dr/dp = {compliance:.4e} m/Pa; r²/(E h) = {thin:.4e} ({:.2} %); Lamé plane stress {lame:.4e} ({:.2} %)",
        100.0 * err_thin,
        100.0 * err_lame
    );
    assert!(
        err_lame < 0.01,
        "against Lamé (plane stress): {:.2} %",
        100.0 * err_lame
    );
    // The thin-wall estimate itself is off by about h/(2r) ≈ 2.5 % here.
    assert!(err_thin < 0.03, "against r²/(E h): {:.2} %", 100.0 * err_thin);
}
