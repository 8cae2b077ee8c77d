//! Where a full implicit step's time goes: force, tangent assembly, Cholesky
//! factor and solve, on the rayon pool and on one thread, for the nvtmm and
//! fem models on the arch. `cargo run --release --example step_profile -- [nodes]`.

use nvtmm::bench::standard_load;
use nvtmm::material::{Law, Material};
use nvtmm::math::Mat3;
use nvtmm::math::Vec3;
use nvtmm::mesh::arch::{generate, ArchParams};
use nvtmm::model::factory::build_model;
use nvtmm::model::{BlockTangent, ModelKind};
use nvtmm::solver::linear::{project_fixed, CholeskySolver};
use std::time::Instant;

fn time(reps: usize, mut f: impl FnMut()) -> f64 {
    f();
    let mut v: Vec<f64> = (0..reps)
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let nodes: usize = std::env::args().nth(1).and_then(|s| s.parse().ok()).unwrap_or(1458);
    let arch = generate(&ArchParams::default(), nodes).expect("arch");
    let mesh = &arch.mesh;
    let mat = Material::aorta();
    let load = standard_load(&arch, 0.3);
    let n = mesh.num_nodes();
    let u: Vec<Vec3> = mesh
        .rest()
        .iter()
        .map(|x| Vec3::new(1e-3 * x.z, 0.0, 2e-3 * x.x))
        .collect();
    let mass = mesh.lumped_mass(mat.density);
    let mut mask = vec![false; n];
    for &i in &load.fixed {
        mask[i as usize] = true;
    }
    let reps = if n > 10_000 { 7 } else { 31 };
    let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().expect("pool");
    println!(
        "{n} nodes, median of {reps} (ms): pool of {} threads | 1 thread",
        rayon::current_num_threads()
    );
    for kind in [ModelKind::Nvtmm, ModelKind::Fem] {
        let model = build_model(kind, mesh, &mat, Law::Stvk, &[]);
        let mut f = vec![Vec3::zeros(); n];
        let mut k = BlockTangent::zeros(mesh);
        let run = |label: &str, g: &mut (dyn FnMut() + Send)| {
            let p = time(reps, &mut *g);
            let s = one.install(|| time(reps, &mut *g));
            println!("  {:5} {label:10} {p:8.3} | {s:8.3}", kind.name());
        };
        run("force", &mut || model.add_forces(&u, &mut f));
        run("df", &mut || model.add_df(&u, &u, &mut f));
        run("stiffness", &mut || {
            k.clear();
            model.add_stiffness(&u, &mut k);
        });
    }
    let model = build_model(ModelKind::Nvtmm, mesh, &mat, Law::Stvk, &[]);
    let mut a = BlockTangent::zeros(mesh);
    model.add_stiffness(&u, &mut a);
    let h = 1e-3;
    for (i, d) in a.diag.iter_mut().enumerate() {
        *d = Mat3::identity() * mass[i] + *d * (h * h + h * 1e-3);
    }
    for o in a.off.iter_mut() {
        *o *= h * h + h * 1e-3;
    }
    project_fixed(&mut a, &mask);
    let mut ch = CholeskySolver::new(&a).expect("symbolic");
    let b = vec![Vec3::new(1e-6, 0.0, -1e-6); n];
    let mut x = vec![Vec3::zeros(); n];
    let tf = time(reps, || ch.factor(&a).expect("factor"));
    let ts = time(reps, || {
        ch.solve_factored(&b, &mut x).expect("solve");
    });
    let tm = time(reps, || a.mul(&b, &mut x));
    println!(
        "  cholesky factor {tf:8.3}, solve {ts:8.3} (L: {} entries); block mat-vec {tm:8.3}",
        ch.factor_nnz()
    );
    ch.set_parallel(true);
    let tf = time(reps, || ch.factor(&a).expect("factor"));
    let ts = time(reps, || {
        ch.solve_factored(&b, &mut x).expect("solve");
    });
    println!("  cholesky on rayon: factor {tf:8.3}, solve {ts:8.3}");
    let mut c32 = CholeskySolver::<f32>::for_pattern(&a).expect("symbolic");
    let mut y = vec![Vec3::zeros(); n];
    let tf = time(reps, || c32.factor(&a).expect("factor"));
    let ts = time(reps, || {
        c32.solve_factored(&b, &mut y).expect("solve");
    });
    let diff = x.iter().zip(&y).map(|(p, q)| (p - q).norm()).fold(0.0, f64::max);
    let scale = x.iter().map(|p| p.norm()).fold(0.0, f64::max);
    println!(
        "  cholesky in f32: factor {tf:8.3}, solve {ts:8.3} (max difference to f64 {:.1e} of max)",
        diff / scale
    );
}
