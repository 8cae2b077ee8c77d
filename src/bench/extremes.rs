//! The stability sweep over extreme parameters (`nvtmm bench extremes`):
//! E, ν, dt, Prony terms and load factors at the ends of their ranges, each
//! case run for a fixed number of steps and reported (no NaN, ever).

use crate::material::{Law, Material, PronyTerm};
use crate::math::Vec3;
use crate::mesh::block::block;
use crate::mesh::TetMesh;
use crate::model::factory::build_model;
use crate::model::ModelKind;
use crate::solver::loads::{Loads, NodalLoad, TimeProfile};
use crate::solver::{ImplicitEuler, ImplicitEulerParams, LinearSolverKind, NewtonParams, TissueState};

/// One case of the stability sweep.
#[derive(Debug, Clone, serde::Serialize)]
pub struct ExtremeCase {
    /// Model.
    pub model: String,
    /// Law.
    pub law: String,
    /// Young's modulus (Pa).
    pub youngs_pa: f64,
    /// Poisson ratio.
    pub poisson: f64,
    /// Time step (s).
    pub dt: f64,
    /// Prony terms (α, τ).
    pub prony: Vec<(f64, f64)>,
    /// Load, as a multiple of the force that strains the bar by 10% statically.
    pub load_factor: f64,
}

/// What happened in one case.
#[derive(Debug, Clone, serde::Serialize)]
pub struct ExtremeResult {
    /// The case.
    pub case: ExtremeCase,
    /// Steps attempted.
    pub steps: usize,
    /// Steps that advanced the state.
    pub ok_steps: usize,
    /// Steps that advanced but did not reach the Newton tolerance.
    pub unconverged: usize,
    /// First failure, if any (the state was kept unchanged).
    pub failure: Option<String>,
    /// Steps that were covered by halved sub-steps (`max_halvings` > 0).
    pub split_steps: usize,
    /// Whether any non-finite value was ever seen in the state (must be false).
    pub non_finite: bool,
    /// Largest displacement over the run relative to the bar length.
    pub max_rel_displacement: f64,
    /// Smallest det F over the elements at the end (< 0: inverted elements).
    pub min_det_f: f64,
}

/// The sweep the documentation reports: every model and law over ν, E, dt,
/// Prony τ ≪ dt and ≫ dt, Σα near 1 and loads that invert elements, on a
/// small clamped bar (a 4×2×2-cell block, 40 mm × 10 mm × 10 mm) pulled
/// sideways at its free end. `quick` keeps a representative subset.
pub fn extremes_cases(quick: bool) -> Vec<ExtremeCase> {
    let mut cases = Vec::new();
    let models: &[(ModelKind, Law)] = &[
        (ModelKind::Msm, Law::Stvk),
        (ModelKind::Tmm, Law::Stvk),
        (ModelKind::Nvtmm, Law::Stvk),
        (ModelKind::Fem, Law::Stvk),
        (ModelKind::Fem, Law::NeoHookean),
    ];
    let es: &[f64] = if quick { &[1e3, 1e7] } else { &[1e3, 65e3, 1e6, 1e7] };
    let nus: &[f64] = if quick { &[0.0, 0.499] } else { &[0.0, 0.3, 0.45, 0.499] };
    let dts: &[f64] = if quick { &[1e-4, 1e-2] } else { &[1e-4, 1e-3, 1e-2] };
    for &(m, law) in models {
        for &e in es {
            for &nu in nus {
                for &dt in dts {
                    cases.push(ExtremeCase {
                        model: m.name().into(),
                        law: law_name(law).into(),
                        youngs_pa: e,
                        poisson: nu,
                        dt,
                        prony: vec![],
                        load_factor: 1.0,
                    });
                }
            }
        }
        // Inverting loads.
        for &lf in if quick { &[20.0][..] } else { &[5.0, 20.0, 100.0][..] } {
            cases.push(ExtremeCase {
                model: m.name().into(),
                law: law_name(law).into(),
                youngs_pa: 65e3,
                poisson: 0.45,
                dt: 1e-3,
                prony: vec![],
                load_factor: lf,
            });
        }
    }
    // Viscoelastic extremes (NVTMM and FEM): τ ≪ dt, τ ≫ dt, Σα near 1.
    for (m, law) in [(ModelKind::Nvtmm, Law::Stvk), (ModelKind::Fem, Law::NeoHookean)] {
        for prony in [
            vec![(0.5, 1e-6)],
            vec![(0.5, 1e3)],
            vec![(0.6, 1e-3), (0.39, 0.1)],
            vec![(0.999, 0.05)],
        ] {
            for &dt in if quick { &[1e-3][..] } else { &[1e-4, 1e-2][..] } {
                cases.push(ExtremeCase {
                    model: m.name().into(),
                    law: law_name(law).into(),
                    youngs_pa: 65e3,
                    poisson: 0.45,
                    dt,
                    prony: prony.clone(),
                    load_factor: 1.0,
                });
            }
        }
        cases.push(ExtremeCase {
            model: m.name().into(),
            law: law_name(law).into(),
            youngs_pa: 65e3,
            poisson: 0.45,
            dt: 1e-3,
            prony: vec![(0.9, 0.01)],
            load_factor: 50.0,
        });
    }
    cases
}

fn law_name(l: Law) -> &'static str {
    match l {
        Law::Stvk => "stvk",
        Law::NeoHookean => "neo_hookean",
    }
}

/// Runs one case for `steps` steps (or 50 ms of simulated time, whichever
/// is shorter, at least 5 steps).
pub fn run_extreme(case: &ExtremeCase, steps: usize) -> ExtremeResult {
    run_extreme_with(case, steps, 0)
}

/// [`run_extreme`] with the integrator's step halving on failure
/// (`ImplicitEulerParams::max_halvings`).
pub fn run_extreme_with(case: &ExtremeCase, steps: usize, max_halvings: usize) -> ExtremeResult {
    let mesh: TetMesh = match block([4, 2, 2], [0.04, 0.01, 0.01]) {
        Ok(m) => m,
        Err(e) => {
            return ExtremeResult {
                case: case.clone(),
                steps: 0,
                ok_steps: 0,
                unconverged: 0,
                failure: Some(e.to_string()),
                split_steps: 0,
                non_finite: false,
                max_rel_displacement: 0.0,
                min_det_f: f64::NAN,
            }
        }
    };
    let kind: ModelKind = case.model.parse().unwrap_or(ModelKind::Nvtmm);
    let law = if case.law == "neo_hookean" {
        Law::NeoHookean
    } else {
        Law::Stvk
    };
    let mat = Material {
        youngs_pa: case.youngs_pa,
        poisson: case.poisson,
        density: 1050.0,
    };
    let prony: Vec<PronyTerm> = case
        .prony
        .iter()
        .map(|&(alpha, tau)| PronyTerm { alpha, tau })
        .collect();
    let mut model = build_model(kind, &mesh, &mat, law, &prony);
    let fixed = mesh.node_set("x_min").unwrap_or(&[]).to_vec();
    let tip = mesh.node_set("x_max").unwrap_or(&[]).to_vec();
    // A sideways tip force that bends the bar to ~10% strain statically, times the factor.
    let area = 1e-4;
    let total = case.load_factor * 0.1 * case.youngs_pa * area;
    let loads = Loads {
        nodal: vec![NodalLoad {
            nodes: tip.clone(),
            force: Vec3::new(-0.3 * total, 0.0, total) / tip.len().max(1) as f64,
            profile: TimeProfile::Ramp {
                t0: 0.0,
                t1: 10.0 * case.dt,
            },
        }],
        gravity: Vec3::zeros(),
        pressure: None,
    };
    let params = ImplicitEulerParams {
        dt: case.dt,
        rayleigh_alpha: 0.0,
        rayleigh_beta: 0.0,
        newton: NewtonParams {
            max_iters: 8,
            rel_tol: 1e-8,
            ..NewtonParams::default()
        },
        linear: LinearSolverKind::Cholesky,
        max_halvings,
        ..ImplicitEulerParams::default()
    };
    let mut res = ExtremeResult {
        case: case.clone(),
        steps: 0,
        ok_steps: 0,
        unconverged: 0,
        failure: None,
        split_steps: 0,
        non_finite: false,
        max_rel_displacement: 0.0,
        min_det_f: f64::NAN,
    };
    let mut euler = match ImplicitEuler::new(&mesh, mesh.lumped_mass(mat.density), params) {
        Ok(e) => e,
        Err(e) => {
            res.failure = Some(e.to_string());
            return res;
        }
    };
    let mut state = TissueState::at_rest(mesh.num_nodes());
    let n_steps = steps.min(((0.05 / case.dt).ceil() as usize).max(5));
    for _ in 0..n_steps {
        res.steps += 1;
        let before = state.clone();
        let rep = euler.step(&mut state, model.as_mut(), &loads, &fixed);
        if !state.is_finite() {
            res.non_finite = true;
        }
        if let Some(f) = rep.failure {
            if state != before {
                res.non_finite = true; // a failed step must leave the state unchanged
            }
            res.failure = Some(f.to_string());
            break;
        }
        res.ok_steps += 1;
        if rep.substeps > 1 {
            res.split_steps += 1;
        }
        if !rep.converged {
            res.unconverged += 1;
        }
        let m = state.u.iter().map(|u| u.norm()).fold(0.0, f64::max) / 0.04;
        res.max_rel_displacement = res.max_rel_displacement.max(m);
    }
    res.min_det_f = mesh
        .tets()
        .iter()
        .zip(mesh.grads())
        .map(|(tet, g)| {
            let mut f = crate::math::Mat3::identity();
            for k in 0..4 {
                f += state.u[tet[k] as usize] * g[k].transpose();
            }
            f.determinant()
        })
        .fold(f64::INFINITY, f64::min);
    res
}

/// The sweep as a Markdown table.
pub fn extremes_markdown(results: &[ExtremeResult]) -> String {
    let mut s = String::from("| model | law | E (Pa) | ν | dt (s) | Prony (α, τ) | load × | steps ok | split steps | unconverged | failure | NaN | max |u|/L | min det F |\n|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n");
    for r in results {
        let c = &r.case;
        let prony = if c.prony.is_empty() {
            "–".to_string()
        } else {
            c.prony
                .iter()
                .map(|(a, t)| format!("({a}, {t:e})"))
                .collect::<Vec<_>>()
                .join(" ")
        };
        s.push_str(&format!(
            "| {} | {} | {:e} | {} | {:e} | {} | {} | {}/{} | {} | {} | {} | {} | {:.3} | {:.3} |\n",
            c.model,
            c.law,
            c.youngs_pa,
            c.poisson,
            c.dt,
            prony,
            c.load_factor,
            r.ok_steps,
            r.steps,
            r.split_steps,
            r.unconverged,
            r.failure.as_deref().unwrap_or("–"),
            if r.non_finite { "**yes**" } else { "no" },
            r.max_rel_displacement,
            r.min_det_f
        ));
    }
    s
}
