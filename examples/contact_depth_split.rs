//! Contact at depth: is the gap between the rendered force and the
//! reference in the loop's rendering or in the comparison?
//!
//! `cargo run --release --example contact_depth_split -- PUSH_MM [paper|human] [COUPLE_MM SEPARATION_MM]`
//! runs `nvtmm experiment contact --branched --points 40 --seed 11
//! --push-mm PUSH_MM` (with `human`: `--wall human --pressure-pa 12400`;
//! with the last two, the residual compliance table's `couple_radius_m`
//! and `separation_m` in mm instead of the defaults 6 and 40)
//! and, at its eight worst points (farthest from 1), solves the reference's contact problem
//! (every surface node within the probe's radius plus 4 mm, the probe
//! pushed in from where it touches in 0.2 mm steps, Newton on the per-node
//! contact forces) twice: with the full model's compliance W = (K⁻¹)_CC, as
//! the reference does, and with the loop's own representation of it,
//! Φ K_r⁻¹ Φᵀ + ΔW (the basis and the residual compliance table, pairs
//! absent from the table taken as zero). If the loop's W solved this way
//! gives the reference's force, the basis and the table are right and the
//! gap is in how the loop solves the contact (one force magnitude per
//! patch with a fixed deflection shape); if it gives the loop's force, the
//! gap is in the representation. docs/RESULTS.md, "At depth".
use nalgebra::DMatrix;
use nvtmm::experiment::contact::{full_forces_from, run, ContactExperiment, Setup, SetupSpec, Wall};
use nvtmm::reduced::compliance::{ComplianceParams, ExactCompliance};

fn main() {
    let push_mm: f64 = std::env::args().nth(1).unwrap().parse().unwrap();
    let args: Vec<String> = std::env::args().collect();
    let human = args.get(2).map(String::as_str) == Some("human");
    let mut e = ContactExperiment::full();
    if let (Some(c), Some(sep)) = (args.get(3), args.get(4)) {
        e.compliance = ComplianceParams {
            couple_radius_m: c.parse::<f64>().expect("COUPLE_MM") * 1e-3,
            separation_m: sep.parse::<f64>().expect("SEPARATION_MM") * 1e-3,
        };
    }
    if human {
        e.wall = Wall::Human;
        e.pressure_pa = 12.4e3;
    }
    e.branched = true;
    e.points = 40;
    e.seed = 11;
    e.push_m = push_mm * 1e-3;
    let res = run(&e).unwrap();
    let q = res.ratio_settled;
    println!(
        "push {push_mm} mm, wall {}, table couple {} mm separation {} mm: settled p05 {:.3} p50 {:.3} p95 {:.3} worst {:.3}",
        e.wall.name(),
        e.compliance.couple_radius_m * 1e3,
        e.compliance.separation_m * 1e3,
        q.p05,
        q.p50,
        q.p95,
        q.worst
    );
    let s = Setup::with(&SetupSpec {
        nodes: 5832,
        r: 32,
        compliance: e.compliance,
        branched: true,
        wall: e.wall,
        pressure_pa: e.pressure_pa,
        ..SetupSpec::default()
    })
    .unwrap();
    let mesh = &s.mesh;
    let rest = mesh.rest();
    let normals = mesh.surface_vertex_normals();
    let surface = mesh.surface_nodes();
    let kr_inv = s.k0.clone().try_inverse().unwrap();
    let mut exact = ExactCompliance::new(&s.k, &s.fixed).unwrap();
    let mut pts = res.points.clone();
    pts.sort_by(|a, b| (b.ratio_settled - 1.0).abs().total_cmp(&(a.ratio_settled - 1.0).abs()));
    let rt = s.cp.tool_radius_m;
    for p in pts.iter().take(8) {
        let n = normals[p.node as usize];
        let tool = rest[p.node as usize] + n * (rt - e.push_m);
        let touching = rest[p.node as usize] + n * rt;
        let c: Vec<u32> = surface
            .iter()
            .copied()
            .filter(|&i| {
                (rest[i as usize] - tool).norm() <= rt + 4e-3 || (rest[i as usize] - touching).norm() <= rt + 4e-3
            })
            .collect();
        let w_ex = exact.blocks(&c).unwrap();
        let m = c.len();
        let mut w_lp = DMatrix::<f64>::zeros(3 * m, 3 * m);
        for (a, &i) in c.iter().enumerate() {
            for (b, &j) in c.iter().enumerate() {
                let red = s.rows[i as usize] * &kr_inv * s.rows[j as usize].transpose();
                let res_b = s
                    .table
                    .block(i, j)
                    .copied()
                    .or_else(|| s.table.block(j, i).map(|x| x.transpose()))
                    .unwrap_or_else(nvtmm::math::Mat3::zeros);
                for r in 0..3 {
                    for q in 0..3 {
                        w_lp[(3 * a + r, 3 * b + q)] = red[(r, q)] + res_b[(r, q)];
                    }
                }
            }
        }
        let solve = |w: &DMatrix<f64>| -> f64 {
            let mut u = nalgebra::DVector::zeros(3 * m);
            let steps = ((e.push_m / 0.2e-3).ceil() as usize).max(1);
            let mut f = 0.0;
            for k in 1..=steps {
                let t = k as f64 / steps as f64;
                let at = touching * (1.0 - t) + tool * t;
                match full_forces_from(mesh, &s.cp, &s.index, &[at], &c, w, &mut u) {
                    Ok(sol) => f = sol.forces[0].norm(),
                    Err(why) => {
                        println!("    fail: {why}");
                        return f64::NAN;
                    }
                }
            }
            f
        };
        let f_ex = solve(&w_ex);
        let f_lp = solve(&w_lp);
        // How far the loop's W is from the exact one on C.
        let diff = (&w_lp - &w_ex).norm() / w_ex.norm();
        println!(
            "node {} inner {} loop/ref {:.3} | ref {:.4} N, exact-W solve {:.4} N, loop-W solve {:.4} N (loop-W/exact-W {:.3}), |W_loop - W|/|W| {:.3}, {} nodes",
            p.node, p.inner, p.ratio_settled, p.full_n, f_ex, f_lp, f_lp / f_ex, diff, m
        );
    }
}
