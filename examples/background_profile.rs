//! Where the background full solve's time goes: the service scene's model
//! (NVTMM + one Prony term, arch, both rings fixed) under a 0.12 N force at
//! the arch top varying as a 2 Hz sine, stepped with the service's
//! integrator settings at a fixed dt; the model's calls are timed through a
//! wrapper, the rest of the step is the integrator and the linear solve.
//!
//! `cargo run --release --example background_profile -- [nodes] [dt] [steps] [linear] [stiffness_every] [no-final-residual]`
//! with `linear` one of `bench step --linear`'s names (default
//! `cholesky-pcg32:3`).

use nvtmm::bench::{arch_top_node, parse_linear, probe_region};
use nvtmm::material::{Law, Material, PronyTerm};
use nvtmm::math::Vec3;
use nvtmm::mesh::arch::{generate, ArchParams};
use nvtmm::model::factory::build_model;
use nvtmm::model::{BlockTangent, ForceModel, ModelKind};
use nvtmm::solver::loads::{Loads, NodalLoad, TimeProfile};
use nvtmm::solver::{ImplicitEuler, ImplicitEulerParams, NewtonParams, TissueState};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

/// Seconds accumulated in nanoseconds (the model is `Sync`).
#[derive(Default)]
struct Acc(AtomicU64);

impl Acc {
    fn add(&self, t: Instant) {
        self.0.fetch_add(t.elapsed().as_nanos() as u64, Ordering::Relaxed);
    }
    fn get(&self) -> f64 {
        self.0.load(Ordering::Relaxed) as f64 * 1e-9
    }
}

struct Timed {
    inner: Box<dyn ForceModel>,
    force: Acc,
    stiffness: Acc,
    df: Acc,
    end: f64,
}

impl ForceModel for Timed {
    fn name(&self) -> &'static str {
        self.inner.name()
    }
    fn add_forces(&self, u: &[Vec3], out: &mut [Vec3]) {
        let t = Instant::now();
        self.inner.add_forces(u, out);
        self.force.add(t);
    }
    fn add_df(&self, u: &[Vec3], du: &[Vec3], out: &mut [Vec3]) {
        let t = Instant::now();
        self.inner.add_df(u, du, out);
        self.df.add(t);
    }
    fn add_stiffness(&self, u: &[Vec3], k: &mut BlockTangent) {
        let t = Instant::now();
        self.inner.add_stiffness(u, k);
        self.stiffness.add(t);
    }
    fn energy(&self, u: &[Vec3]) -> f64 {
        self.inner.energy(u)
    }
    fn begin_step(&mut self, dt: f64) {
        self.inner.begin_step(dt)
    }
    fn end_step(&mut self, u: &[Vec3]) {
        let t = Instant::now();
        self.inner.end_step(u);
        self.end += t.elapsed().as_secs_f64();
    }
    fn save_state(&mut self) {
        self.inner.save_state()
    }
    fn restore_state(&mut self) {
        self.inner.restore_state()
    }
    fn is_viscoelastic(&self) -> bool {
        self.inner.is_viscoelastic()
    }
}

fn main() {
    let mut args = std::env::args().skip(1);
    let nodes: usize = args.next().and_then(|s| s.parse().ok()).unwrap_or(5832);
    let dt: f64 = args.next().and_then(|s| s.parse().ok()).unwrap_or(0.05);
    let steps: usize = args.next().and_then(|s| s.parse().ok()).unwrap_or(40);
    let mut linear = parse_linear(&args.next().unwrap_or_else(|| "cholesky-pcg32:3".into())).expect("linear");
    // PCG tolerance from the environment (default 1e-6, as the service).
    if let (Ok(t), nvtmm::solver::LinearSolverKind::CholeskyPcg { tol, .. }) = (std::env::var("PCG_TOL"), &mut linear) {
        *tol = t.parse().expect("PCG_TOL");
    }
    let every: usize = args.next().and_then(|s| s.parse().ok()).unwrap_or(1);
    let check_final_residual = args.next().as_deref() != Some("no-final-residual");
    let arch = generate(&ArchParams::default(), nodes).expect("arch");
    let mesh = &arch.mesh;
    let mat = Material::aorta();
    let prony = [PronyTerm { alpha: 0.5, tau: 0.58 }];
    let inner = build_model(ModelKind::Nvtmm, mesh, &mat, Law::Stvk, &prony);
    let mut model = Timed {
        inner,
        force: Acc::default(),
        stiffness: Acc::default(),
        df: Acc::default(),
        end: 0.0,
    };
    let mut fixed: Vec<u32> = ["inlet", "outlet_descending"]
        .iter()
        .flat_map(|s| mesh.node_set(s).unwrap_or(&[]).to_vec())
        .collect();
    fixed.sort_unstable();
    fixed.dedup();
    let _ = probe_region(&arch);
    let loads = Loads {
        nodal: vec![NodalLoad {
            nodes: vec![arch_top_node(&arch)],
            force: Vec3::new(0.0, 0.0, -0.12),
            profile: TimeProfile::Sine {
                freq_hz: 2.0,
                phase: 0.0,
            },
        }],
        gravity: Vec3::zeros(),
        pressure: None,
    };
    let params = ImplicitEulerParams {
        dt,
        rayleigh_alpha: 0.0,
        rayleigh_beta: 1e-3,
        newton: NewtonParams {
            check_final_residual,
            ..NewtonParams::linearized()
        },
        linear,
        stiffness_every: every,
        max_halvings: 3,
    };
    let mut euler = ImplicitEuler::new(mesh, mesh.lumped_mass(mat.density), params).expect("integrator");
    let mut state = TissueState::at_rest(mesh.num_nodes());
    let mut total = 0.0;
    let mut iters = 0;
    let mut times = Vec::new();
    for _ in 0..steps {
        let t = Instant::now();
        let rep = euler.step(&mut state, &mut model, &loads, &fixed);
        let s = t.elapsed().as_secs_f64();
        total += s;
        times.push(s * 1e3);
        iters += rep.linear_iters;
        assert!(
            rep.ok(),
            "step {}: {:?} (substeps {})",
            times.len(),
            rep.failure,
            rep.substeps
        );
    }
    times.sort_by(f64::total_cmp);
    let ms = |x: f64| x * 1e3 / steps as f64;
    let model_s = model.force.get() + model.stiffness.get() + model.df.get() + model.end;
    println!(
        "{} nodes, dt {dt}, {steps} steps, k = {every}: mean {:.1} ms/step (median {:.1}, max {:.1}); per step: force {:.1}, tangent {:.1}, df {:.1}, end_step {:.1}, integrator + linear {:.1} ms; CG iterations/step {:.1}",
        mesh.num_nodes(),
        ms(total),
        times[times.len() / 2],
        times[times.len() - 1],
        ms(model.force.get()),
        ms(model.stiffness.get()),
        ms(model.df.get()),
        ms(model.end),
        ms(total - model_s),
        iters as f64 / steps as f64
    );
}
