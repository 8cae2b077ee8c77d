//! Measurements of the luminal pressure load (docs/PRESSURE.md and the
//! "Blood pressure" section of docs/BENCHMARKS.md).
//!
//! `cargo run --release --example pressure_bench -- newton` — Newton
//! iterations of a static inflation (a tube clamped at one end, free at the
//! other, so the rim's unsymmetric load stiffness is not held away) with the
//! exact unsymmetric tangent (dense LU), its symmetric part (Cholesky) and
//! none; and of the implicit step on the 5832-node arch under a 13 kPa
//! pressure, with the symmetric part and without.
//!
//! `cargo run --release --example pressure_bench -- unload [NODES]` — the
//! zero-pressure reference of the built-in arch (default 5832 nodes), ends
//! fixed, Neo-Hookean 1 MPa wall, 12 kPa mean pressure: time and iterations.
//!
//! `cargo run --release --example pressure_bench -- tick` — the loop's
//! reduced step (R = 32, with contact) with and without the heartbeat's
//! modal load.
//!
//! `cargo run --release --example pressure_bench -- give [SCENE]` — the
//! wall's static normal compliance under a point load (n·K⁻¹n at inner-wall
//! nodes of the aorta at least 15 mm from every fixed node) in the
//! guidewire scene (`rt-config/scenes/guidewire_arch_living.toml`), with
//! its pressure (the wall inflated to the mean as the service starts it)
//! and without (the image at rest), and the paper's 65 kPa wall at rest
//! (`rt-config/scenes/guidewire_arch.toml`); the give under 0.3 N is the
//! compliance times 0.3 N (docs/PRESSURE.md, "The wall's give under the
//! wire").
//!
//! `cargo run --release --example pressure_bench -- modes [R]` — the first
//! vibration modes of the living scene's wall at rest, of that basis at the
//! inflated wall's tangent, and of the basis computed at the inflated wall
//! (default R = 32), and the share of the give the modes carry
//! (docs/PRESSURE.md, "The reduced model at pressure").
//!
//! `cargo run --release --example pressure_bench -- step [NODES] [SECONDS]` —
//! the service scene's full solve (NVTMM + Prony, 10 ms linearized steps,
//! Cholesky-preconditioned CG) on a 1 MPa wall with and without a 12 kPa
//! pressure: wall time per step against the step length (real-time factor
//! of the full solve alone, fixed 10 ms steps).

use nvtmm::material::{Law, Material, PronyTerm};
use nvtmm::math::Vec3;
use nvtmm::mesh::arch::{generate, ArchGrid, ArchParams};
use nvtmm::mesh::tube::{self, TubeParams};
use nvtmm::model::factory::build_model;
use nvtmm::model::ModelKind;
use nvtmm::solver::loads::Loads;
use nvtmm::solver::pressure::{LuminalPressure, PressureSchedule, PressureTangent};
use nvtmm::solver::statics::{mask_of_fixed, solve_pressurized, StaticParams, StaticTangent};
use nvtmm::solver::unload::{UnloadParams, UnloadRequest};
use nvtmm::solver::{ImplicitEuler, ImplicitEulerParams, LinearSolverKind, NewtonParams, TissueState};
use std::time::Instant;

fn aorta_wall() -> Material {
    Material {
        youngs_pa: 1e6,
        poisson: 0.45,
        density: 1050.0,
    }
}

fn newton() {
    let mesh = tube::generate(
        &TubeParams {
            inner_radius: 0.010,
            outer_radius: 0.0115,
            length: 0.03,
        },
        ArchGrid {
            axial: 7,
            circumferential: 24,
            layers: 2,
        },
    )
    .expect("tube");
    let fixed = mesh.node_set("end_0").expect("end_0").to_vec();
    let mask = mask_of_fixed(mesh.num_nodes(), &fixed);
    let model = build_model(ModelKind::Nvtmm, &mesh, &aorta_wall(), Law::NeoHookean, &[]);
    println!(
        "static inflation to 13 kPa, tube {} nodes, one end clamped, Neo-Hookean 1 MPa, 4 load steps, rel_tol 1e-9",
        mesh.num_nodes()
    );
    for (name, tangent, st) in [
        ("exact (dense LU)", PressureTangent::Symmetric, StaticTangent::Exact),
        ("symmetric part", PressureTangent::Symmetric, StaticTangent::AsLoad),
        ("none", PressureTangent::None, StaticTangent::AsLoad),
    ] {
        let load = LuminalPressure::on_set(&mesh, "inner_wall", PressureSchedule::steady(13e3), tangent).expect("set");
        let mut u = vec![Vec3::zeros(); mesh.num_nodes()];
        let params = StaticParams {
            tangent: st,
            max_iters: 200,
            ..StaticParams::default()
        };
        let t0 = Instant::now();
        match solve_pressurized(&mesh, model.as_ref(), &load, 13e3, &mask, &params, &mut u) {
            Ok(rep) => println!(
                "  {name:18} Newton iterations per load step {:?} (total {}), {:.2} s",
                rep.newton_iters,
                rep.total_iters(),
                t0.elapsed().as_secs_f64()
            ),
            Err(e) => println!("  {name:18} failed: {e}"),
        }
    }

    let arch = generate(&ArchParams::default(), 5832).expect("arch");
    let mesh = &arch.mesh;
    let mut fixed = mesh.node_set("inlet").expect("inlet").to_vec();
    fixed.extend_from_slice(mesh.node_set("outlet_descending").expect("outlet"));
    let mat = aorta_wall();
    println!(
        "implicit Euler, arch {} nodes, NVTMM StVK 1 MPa, 13 kPa step-on, dt 1 ms, Newton to 1e-8, Cholesky, 20 steps",
        mesh.num_nodes()
    );
    for (name, tangent) in [
        ("symmetric part", PressureTangent::Symmetric),
        ("none", PressureTangent::None),
    ] {
        let mut model = build_model(ModelKind::Nvtmm, mesh, &mat, Law::Stvk, &[]);
        let params = ImplicitEulerParams {
            dt: 1e-3,
            linear: LinearSolverKind::Cholesky,
            newton: NewtonParams {
                max_iters: 32,
                rel_tol: 1e-8,
                ..NewtonParams::default()
            },
            ..ImplicitEulerParams::default()
        };
        let mut euler = ImplicitEuler::new(mesh, mesh.lumped_mass(mat.density), params).expect("solver");
        let mut sched = PressureSchedule::steady(13e3);
        sched.ramp_s = 0.0;
        let loads = Loads {
            pressure: Some(LuminalPressure::on_set(mesh, "inner_wall", sched, tangent).expect("set")),
            ..Loads::none()
        };
        let mut state = TissueState::at_rest(mesh.num_nodes());
        let mut iters = Vec::new();
        let t0 = Instant::now();
        for _ in 0..20 {
            let rep = euler.step(&mut state, model.as_mut(), &loads, &fixed);
            if !rep.ok() {
                println!("  {name}: step failed: {:?}", rep.failure);
                break;
            }
            iters.push(rep.newton_iters);
        }
        let total: usize = iters.iter().sum();
        println!(
            "  {name:18} Newton iterations per step {:?} (total {total}), {:.2} s",
            iters,
            t0.elapsed().as_secs_f64()
        );
    }
}

fn unload(nodes: usize) {
    let arch = generate(&ArchParams::default(), nodes).expect("arch");
    let mesh = &arch.mesh;
    let mut fixed = mesh.node_set("inlet").expect("inlet").to_vec();
    fixed.extend_from_slice(mesh.node_set("outlet_descending").expect("outlet"));
    let req = UnloadRequest {
        image: mesh,
        kind: ModelKind::Fem,
        material: aorta_wall(),
        law: Law::NeoHookean,
        set: "inner_wall",
        pressure_pa: 12e3,
        fixed: &fixed,
        params: UnloadParams::default(),
    };
    let t0 = Instant::now();
    match req.solve() {
        Ok(out) => println!(
            "zero-pressure reference, arch {} nodes: {:.1} s, {} fixed-point iterations, {} Newton iterations, errors (m) {:?}",
            mesh.num_nodes(),
            t0.elapsed().as_secs_f64(),
            out.iters,
            out.newton_iters,
            out.history.iter().map(|e| format!("{e:.1e}")).collect::<Vec<_>>()
        ),
        Err(e) => println!("failed after {:.1} s: {e}", t0.elapsed().as_secs_f64()),
    }
}

fn step(nodes: usize, seconds: f64) {
    let arch = generate(&ArchParams::default(), nodes).expect("arch");
    let mesh = &arch.mesh;
    let mut fixed = mesh.node_set("inlet").expect("inlet").to_vec();
    fixed.extend_from_slice(mesh.node_set("outlet_descending").expect("outlet"));
    // The service scene's solver and Prony term on a wall that can hold
    // arterial pressure (the paper's 65 kPa cannot: docs/PRESSURE.md).
    let mat = aorta_wall();
    let prony = [PronyTerm { alpha: 0.5, tau: 0.58 }];
    let params = ImplicitEulerParams {
        dt: 1e-2,
        rayleigh_beta: 1e-3,
        newton: NewtonParams {
            max_iters: 1,
            check_final_residual: false,
            ..NewtonParams::default()
        },
        linear: LinearSolverKind::CholeskyPcg {
            tol: 1e-6,
            max_iter: 15,
            refactor_every: 3,
            factor_f32: true,
        },
        max_halvings: 3,
        ..ImplicitEulerParams::default()
    };
    println!(
        "full solve with the service scene's solver, arch {} nodes, NVTMM StVK 1 MPa + Prony, 10 ms linearized steps",
        mesh.num_nodes()
    );
    for p in [0.0, 12e3] {
        let mut model = build_model(ModelKind::Nvtmm, mesh, &mat, Law::Stvk, &prony);
        let mut euler = ImplicitEuler::new(mesh, mesh.lumped_mass(mat.density), params).expect("solver");
        let mut sched = PressureSchedule::steady(p);
        sched.ramp_s = 0.25;
        let loads = Loads {
            pressure: (p > 0.0)
                .then(|| LuminalPressure::on_set(mesh, "inner_wall", sched, PressureTangent::Symmetric).expect("set")),
            ..Loads::none()
        };
        let mut state = TissueState::at_rest(mesh.num_nodes());
        let steps = (seconds / 1e-2).round() as usize;
        let mut times = Vec::with_capacity(steps);
        let mut failed = 0;
        for _ in 0..steps {
            let t0 = Instant::now();
            let rep = euler.step(&mut state, model.as_mut(), &loads, &fixed);
            times.push(t0.elapsed().as_secs_f64());
            failed += usize::from(!rep.ok());
        }
        let total: f64 = times.iter().sum();
        times.sort_by(f64::total_cmp);
        let max_u = state.u.iter().map(|u| u.norm()).fold(0.0, f64::max);
        println!(
            "  p = {:5.0} Pa: {steps} steps, step p50 {:.1} ms, p99 {:.1} ms, real-time factor {:.2}, failed {failed}, max displacement {:.1} mm",
            p,
            times[steps / 2] * 1e3,
            times[(steps * 99) / 100] * 1e3,
            steps as f64 * 1e-2 / total,
            max_u * 1e3
        );
    }
}

/// The haptic loop's reduced step at R = 32 with the contact stiffness (the
/// service's step) with and without the heartbeat's modal load, interleaved
/// in blocks so both see the same machine load.
fn tick() {
    use nvtmm::reduced::{DynamicsParams, ModalPulse, ReducedDynamics};
    use nvtmm::solver::pressure::{WaveShape, Waveform};
    const R: usize = 32;
    let n = 100;
    let rows = std::sync::Arc::new(vec![
        nalgebra::SMatrix::<f64, 3, R>::from_fn(
            |i, j| 1e-3 * ((i + j) as f64).sin()
        );
        n
    ]);
    let k = nalgebra::DMatrix::<f64>::from_fn(R, R, |i, j| if i == j { 1e4 * (1.0 + i as f64) } else { 0.0 });
    let params = DynamicsParams {
        dt: 1e-3,
        alpha: 5.0,
        beta: 1e-3,
    };
    let mut plain = ReducedDynamics::<R>::with_rows(rows.clone(), R, &k, &params).expect("dynamics");
    let mut beating = ReducedDynamics::<R>::with_rows(rows, R, &k, &params).expect("dynamics");
    beating.set_pulse(Some(ModalPulse {
        load_per_pa: nalgebra::SVector::<f64, R>::from_fn(|i, _| 1e-6 * (i as f64 + 1.0)),
        waveform: Waveform {
            systolic_pa: 16e3,
            diastolic_pa: 10.67e3,
            heart_rate_bpm: 70.0,
            shape: WaveShape::Aortic,
        },
        mean_pa: 12.4e3,
        t_s: 0.0,
    }));
    let f = nalgebra::SVector::<f64, R>::from_fn(|i, _| 1e-3 * i as f64);
    let kc = nalgebra::SMatrix::<f64, R, R>::identity() * 10.0;
    let (mut a, mut b) = (Vec::new(), Vec::new());
    for _ in 0..200 {
        for (dyn_, out) in [(&mut plain, &mut a), (&mut beating, &mut b)] {
            for _ in 0..50 {
                let t0 = Instant::now();
                dyn_.step_with_contact(&f, &kc);
                out.push(t0.elapsed().as_secs_f64() * 1e6);
            }
        }
    }
    let p = |v: &mut Vec<f64>, q: f64| {
        v.sort_by(f64::total_cmp);
        v[((v.len() - 1) as f64 * q) as usize]
    };
    println!(
        "reduced step with contact, R = {R}, 10000 steps each: without pulse p50 {:.2} us p99 {:.2} us; with pulse p50 {:.2} us p99 {:.2} us",
        p(&mut a, 0.5),
        p(&mut a, 0.99),
        p(&mut b, 0.5),
        p(&mut b, 0.99)
    );
}

/// n·K⁻¹n at `nodes` (unit normals `normals`) for the tangent `k` with the
/// `fixed` nodes held.
fn normal_compliance(
    mesh: &nvtmm::mesh::TetMesh,
    k: &mut nvtmm::model::BlockTangent,
    fixed: &[u32],
    nodes: &[u32],
    normals: &[Vec3],
) -> Vec<f64> {
    use nvtmm::solver::linear::CholeskySolver;
    use nvtmm::solver::statics::project_dofs;
    let n = mesh.num_nodes();
    project_dofs(k, &mask_of_fixed(n, fixed));
    let mut chol = CholeskySolver::new(k).expect("symbolic");
    chol.factor(k).expect("the tangent is positive definite");
    let mut out = Vec::with_capacity(nodes.len());
    for (chunk, nrm) in nodes.chunks(48).zip(normals.chunks(48)) {
        let mut b = vec![0.0; 3 * n * chunk.len()];
        for (c, (&i, v)) in chunk.iter().zip(nrm).enumerate() {
            for d in 0..3 {
                b[c * 3 * n + 3 * i as usize + d] = v[d];
            }
        }
        chol.solve_factored_columns(&mut b).expect("solve");
        for (c, (&i, v)) in chunk.iter().zip(nrm).enumerate() {
            let x = &b[c * 3 * n + 3 * i as usize..c * 3 * n + 3 * i as usize + 3];
            out.push(x[0] * v[0] + x[1] * v[1] + x[2] * v[2]);
        }
    }
    out
}

fn give(scene: Option<&str>) {
    use nvtmm::scene::Scene;
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let living = scene
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| root.join("rt-config/scenes/guidewire_arch_living.toml"));
    let paper = root.join("rt-config/scenes/guidewire_arch.toml");
    let on = Scene::load(&living).expect("scene");
    let mut off = on.clone();
    off.pressure = None;
    let image = off.build().expect("scene without pressure");
    let (nodes, normals, on_wall) = give_sample(&image);
    println!(
        "{} inner-wall nodes of the aorta at least 15 mm from the fixed openings (of {} on the inner wall)",
        nodes.len(),
        on_wall
    );
    let report = |name: &str, c: &[f64]| {
        let mut s = c.to_vec();
        s.sort_by(f64::total_cmp);
        let q = |f: f64| s[((s.len() - 1) as f64 * f).round() as usize];
        println!(
            "| {name} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} |",
            q(0.05) * 1e3,
            q(0.5) * 1e3,
            q(0.95) * 1e3,
            s[s.len() - 1] * 1e3,
            q(0.5) * 0.3 * 1e3,
            q(0.95) * 0.3 * 1e3
        );
        s
    };
    println!("| wall | c p05 (mm/N) | p50 | p95 | max | give at 0.3 N p50 (mm) | p95 |");
    println!("|---|---:|---:|---:|---:|---:|---:|");
    let rest_compliance = |scene: &Scene| {
        let b = scene.build().expect("scene");
        let mut k = nvtmm::model::BlockTangent::zeros(&b.mesh);
        let zeros = vec![Vec3::zeros(); b.mesh.num_nodes()];
        b.model.add_stiffness(&zeros, &mut k);
        normal_compliance(&b.mesh, &mut k, &b.fixed, &nodes, &normals)
    };
    let paper_scene = Scene::load(&paper).expect("paper scene");
    report("65 kPa (paper), no pressure", &rest_compliance(&paper_scene));
    let c_off = rest_compliance(&off);
    report(
        &format!("{:.2} MPa, no pressure", off.material.youngs_pa * 1e-6),
        &c_off,
    );
    let t0 = Instant::now();
    let mut b = on.build().expect("scene with pressure");
    let mut load = b.loads.pressure.take().expect("the scene has a [pressure]");
    let inflated = on.inflate(&mut b, &mut load, on.integrator.dt).expect("inflation");
    let mut k = inflated.tangent.clone();
    let c_on = normal_compliance(&b.mesh, &mut k, &b.fixed, &nodes, &normals);
    report(
        &format!(
            "{:.2} MPa, {:.1} kPa",
            on.material.youngs_pa * 1e-6,
            load.schedule.mean_pa * 1e-3
        ),
        &c_on,
    );
    let ratio: Vec<f64> = {
        let mut r: Vec<f64> = c_off.iter().zip(&c_on).map(|(a, b)| b / a).collect();
        r.sort_by(f64::total_cmp);
        r
    };
    println!(
        "(sorted separately; per node, pressure on / off: p50 {:.2}; inflation by up to {:.2} mm, {} Newton iterations; {:.1} s with the build)",
        ratio[ratio.len() / 2],
        inflated.max_u_m * 1e3,
        inflated.newton_iters,
        t0.elapsed().as_secs_f64()
    );
}

/// The give's sample: inner-wall nodes of the aorta, 15 mm or more from
/// every fixed node, with the outward normal (against the lumen's) at each,
/// and how many nodes the inner wall has.
fn give_sample(image: &nvtmm::scene::Built) -> (Vec<u32>, Vec<Vec3>, usize) {
    use nvtmm::wire::coupling::InnerWall;
    // Normals into the lumen on the image (the reference keeps the image's
    // node order).
    let wall = InnerWall::from_mesh(&image.mesh, "inner_wall").expect("inner_wall");
    let aorta: std::collections::HashSet<u32> = image
        .mesh
        .node_set("segment_aorta")
        .expect("segment_aorta")
        .iter()
        .copied()
        .collect();
    let x = image.mesh.rest();
    let normals_all = wall.vertex_normals();
    let (mut nodes, mut normals) = (Vec::new(), Vec::new());
    for (&i, nrm) in wall.mesh_nodes().iter().zip(&normals_all) {
        let far = image
            .fixed
            .iter()
            .all(|&f| (x[f as usize] - x[i as usize]).norm() >= 0.015);
        if aorta.contains(&i) && far {
            nodes.push(i);
            // Pushed outward, against the lumen normal.
            normals.push(-nrm);
        }
    }
    (nodes, normals, wall.mesh_nodes().len())
}

/// The reduced model at pressure: the first vibration modes of the living
/// scene's wall at rest, of the same basis with the inflated wall's tangent
/// (its Ritz values: the reduced stiffness K_r = ΦᵀK_pΦ a basis computed
/// at rest gives at pressure), and of the basis computed at the inflated
/// wall (the pressure's load stiffness in it); and the share of the static
/// give under a point load that the modes carry, φᵀK_r⁻¹φ / nᵀK_p⁻¹n with
/// φ = Φᵢᵀn, at the give's sample nodes (the rest is the residual
/// compliance's).
fn modes(r: usize) {
    use nvtmm::model::BlockTangent;
    use nvtmm::reduced::{BasisParams, BasisSpec, ModalBasis, Refresher, Statics, Stiffness};
    use nvtmm::scene::Scene;
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let on = Scene::load(&root.join("rt-config/scenes/guidewire_arch_living.toml")).expect("scene");
    let mut b = on.build().expect("scene with pressure");
    let mut load = b.loads.pressure.take().expect("the scene has a [pressure]");
    let inflated = on.inflate(&mut b, &mut load, on.integrator.dt).expect("inflation");
    let (nodes, normals, _) = give_sample(&b);
    let mass = b.mesh.lumped_mass(b.material.density);
    let elastic = build_model(on.model, &b.mesh, &on.material(), on.material.law, &[]);
    let mut k0 = BlockTangent::zeros(&b.mesh);
    elastic.add_stiffness(&vec![Vec3::zeros(); b.mesh.num_nodes()], &mut k0);
    let basis = |k: &BlockTangent| {
        let t0 = Instant::now();
        let basis = ModalBasis::compute(&BasisSpec {
            stiffness: Stiffness::Tangent(k),
            mass: &mass,
            fixed: &b.fixed,
            r,
            statics: Statics::None,
            warm: None,
            params: BasisParams::default(),
        })
        .expect("basis");
        (basis, t0.elapsed().as_secs_f64())
    };
    let (rest, rest_s) = basis(&k0);
    let (press, press_s) = basis(&inflated.tangent);
    let kr = Refresher::new(&b.mesh, &rest, &mass).project_tangent(&inflated.tangent);
    let mut ritz: Vec<f64> = kr.clone().symmetric_eigenvalues().iter().copied().collect();
    ritz.sort_by(f64::total_cmp);
    let hz = |w2: f64| w2.max(0.0).sqrt() / (2.0 * std::f64::consts::PI);
    println!(
        "living arch, {} nodes, r = {r} vibration modes; inflated to {:.1} kPa by up to {:.2} mm; bases {:.1} s at rest, {:.1} s inflated",
        b.mesh.num_nodes(),
        load.schedule.mean_pa * 1e-3,
        inflated.max_u_m * 1e3,
        rest_s,
        press_s
    );
    println!("| mode | at rest (Hz) | rest basis, inflated tangent (Hz) | inflated basis (Hz) |");
    println!("|---:|---:|---:|---:|");
    let rows = rest.omega2.iter().zip(&ritz).zip(&press.omega2).take(6);
    for (m, ((rest_w2, ritz_w2), press_w2)) in rows.enumerate() {
        println!(
            "| {} | {:.2} | {:.2} | {:.2} |",
            m + 1,
            hz(*rest_w2),
            hz(*ritz_w2),
            hz(*press_w2)
        );
    }
    // The modes' share of the static give at the sample nodes.
    let exact = normal_compliance(&b.mesh, &mut inflated.tangent.clone(), &b.fixed, &nodes, &normals);
    let share = |phi: &nalgebra::DMatrix<f64>, kr_inv: &nalgebra::DMatrix<f64>| -> Vec<f64> {
        let mut s: Vec<f64> = nodes
            .iter()
            .zip(&normals)
            .zip(&exact)
            .map(|((&i, n), c)| {
                let g = phi.rows(3 * i as usize, 3).transpose() * nalgebra::Vector3::new(n.x, n.y, n.z);
                (g.transpose() * kr_inv * &g)[(0, 0)] / c
            })
            .collect();
        s.sort_by(f64::total_cmp);
        s
    };
    let kr_inv = kr.try_inverse().expect("K_r invertible");
    let diag_inv = nalgebra::DMatrix::from_diagonal(&nalgebra::DVector::from_iterator(
        press.omega2.len(),
        press.omega2.iter().map(|w| 1.0 / w),
    ));
    let q = |s: &[f64], f: f64| s[((s.len() - 1) as f64 * f).round() as usize];
    for (name, s) in [
        ("rest basis, inflated tangent", share(&rest.phi, &kr_inv)),
        ("inflated basis", share(&press.phi, &diag_inv)),
    ] {
        println!(
            "modal share of the give at {} nodes, {name}: p05 {:.3} p50 {:.3} p95 {:.3}",
            nodes.len(),
            q(&s, 0.05),
            q(&s, 0.5),
            q(&s, 0.95)
        );
    }
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let num = |i: usize, d: f64| args.get(i).and_then(|s| s.parse().ok()).unwrap_or(d);
    match args.first().map(String::as_str) {
        Some("newton") => newton(),
        Some("unload") => unload(num(1, 5832.0) as usize),
        Some("step") => step(num(1, 5832.0) as usize, num(2, 5.0)),
        Some("tick") => tick(),
        Some("give") => give(args.get(1).map(String::as_str)),
        Some("modes") => modes(num(1, 32.0) as usize),
        _ => eprintln!(
            "usage: pressure_bench newton | unload [NODES] | step [NODES] [SECONDS] | tick | give [SCENE] | modes [R]"
        ),
    }
}
