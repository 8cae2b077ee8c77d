//! `nvtmm simulate …` and `nvtmm bench …` subcommands.

use nvtmm::bench::{
    bench_step_params, extremes_cases, extremes_markdown, parse_linear, run_extreme_with, standard_params,
};
use nvtmm::material::{Law, PronyTerm};
use nvtmm::model::ModelKind;
use nvtmm::scene::Scene;
use nvtmm::solver::ImplicitEulerParams;
use std::path::Path;

type Result<T> = std::result::Result<T, Box<dyn std::error::Error>>;

pub fn simulate(scene_path: &Path, out: Option<&Path>, quiet: bool) -> Result<()> {
    let scene = Scene::load(scene_path)?;
    let default_out = Path::new("out").join(scene_path.file_stem().unwrap_or_default());
    let out = out.unwrap_or(&default_out);
    let summary = nvtmm::simulate::run(&scene, out, &crate::cli::progress::terminal(quiet))?;
    println!(
        "{} on {} nodes / {} tets: {} steps, {:.4} s simulated in {:.2} s wall ({:.3} ms/step median, {} CG iterations median, {} unconverged steps, {} split steps)",
        summary.model,
        summary.nodes,
        summary.tets,
        summary.steps,
        summary.sim_time_s,
        summary.wall_s,
        summary.ms_per_step,
        summary.cg_iters_median,
        summary.unconverged_steps,
        summary.split_steps
    );
    println!(
        "max displacement {:.3} mm, elastic energy {:.3e} J",
        summary.max_displacement_m * 1e3,
        summary.final_energy_j
    );
    for o in &summary.outputs {
        println!("wrote {}", o.display());
    }
    let json = out.join("summary.json");
    std::fs::write(&json, serde_json::to_string_pretty(&summary)?).map_err(|e| format!("{}: {e}", json.display()))?;
    println!("wrote {}", json.display());
    Ok(())
}

#[allow(clippy::too_many_arguments)] // one per CLI flag
pub fn bench_step_cmd(
    model: &str,
    law: &str,
    nodes: usize,
    steps: usize,
    prony: bool,
    linear: &str,
    stiffness_every: usize,
    no_final_residual: bool,
    json: bool,
) -> Result<()> {
    let linear = parse_linear(linear)?;
    let kind: ModelKind = model.parse()?;
    let law = match law {
        "stvk" => Law::Stvk,
        "neo_hookean" | "neohookean" => Law::NeoHookean,
        other => return Err(format!("--law {other}: allowed stvk, neo_hookean").into()),
    };
    let terms = if prony {
        vec![PronyTerm { alpha: 0.5, tau: 0.58 }]
    } else {
        vec![]
    };
    if prony && !matches!(kind, ModelKind::Nvtmm | ModelKind::Fem) {
        return Err("--prony applies to the nvtmm and fem models".into());
    }
    let r = {
        let mut params = ImplicitEulerParams {
            linear,
            stiffness_every,
            ..standard_params()
        };
        params.newton.check_final_residual = !no_final_residual;
        bench_step_params(kind, law, nodes, steps, &terms, params)?
    };
    if json {
        println!("{}", serde_json::to_string_pretty(&r)?);
    } else {
        println!(
            "{} ({}, {}, stiffness every {}) {} nodes / {} tets: {:.3} ms/step median over {} steps ({:.1} steps/s; mean {:.3} ms = {:.1} steps/s, max {:.3} ms), {} CG iterations median, loaded node {:.4} mm, setup {:.2} s, {} threads",
            r.model,
            r.law,
            r.linear,
            r.stiffness_every,
            r.nodes,
            r.tets,
            r.ms_per_step,
            r.steps,
            r.steps_per_sec,
            r.mean_ms_per_step,
            1e3 / r.mean_ms_per_step,
            r.max_ms_per_step,
            r.cg_iters,
            r.load_node_displacement_m * 1e3,
            r.setup_s,
            r.threads
        );
    }
    Ok(())
}

pub fn bench_extremes(quick: bool, halvings: usize, json: bool) -> Result<()> {
    if halvings > nvtmm::solver::MAX_HALVINGS {
        return Err(format!("--halvings {halvings}: allowed 0..={}", nvtmm::solver::MAX_HALVINGS).into());
    }
    let cases = extremes_cases(quick);
    let bar = indicatif::ProgressBar::new(cases.len() as u64);
    let results: Vec<_> = cases
        .iter()
        .map(|c| {
            let r = run_extreme_with(c, 500, halvings);
            bar.inc(1);
            r
        })
        .collect();
    bar.finish_and_clear();
    if json {
        println!("{}", serde_json::to_string_pretty(&results)?);
    } else {
        println!("{}", extremes_markdown(&results));
    }
    let bad = results.iter().filter(|r| r.non_finite).count();
    if bad > 0 {
        return Err(format!("{bad} case(s) produced a non-finite state").into());
    }
    Ok(())
}

pub fn experiment_fig5(out: &Path, quick: bool) -> Result<()> {
    use nvtmm::experiment::fig5::{run, Fig5Params};
    let p = if quick {
        Fig5Params::quick()
    } else {
        Fig5Params::paper()
    };
    let r = run(&p, out)?;
    println!(
        "node {} at ({:.4}, {:.4}, {:.4}) m, {} N from t = {} s, {} s at dt = {} s",
        r.node, r.node_position_m[0], r.node_position_m[1], r.node_position_m[2], p.force_n, p.t_load, p.duration, p.dt
    );
    for m in &r.models {
        println!(
            "{:>6}: overshoot {:.1}%, settle {:.3} s{}, final |u| {:.3} mm, final |f| {:.4} N, residual oscillation {:.4} mm",
            m.model,
            100.0 * m.overshoot,
            m.settle_time_s,
            if m.settled { "" } else { " (not settled)" },
            m.final_displacement_m * 1e3,
            m.final_force_n,
            m.residual_oscillation_m * 1e3
        );
    }
    println!(
        "paper's claim (NVTMM oscillates less and settles faster): overshoot less = {}, settles faster = {}",
        r.nvtmm_overshoots_less, r.nvtmm_settles_faster
    );
    for o in &r.outputs {
        println!("wrote {}", o.display());
    }
    Ok(())
}

pub fn experiment_table(out: &Path, quick: bool) -> Result<()> {
    let rows = nvtmm::experiment::table::run(out, quick)?;
    println!("{}", nvtmm::experiment::table::markdown(&rows));
    println!(
        "wrote {} and {}",
        out.join("table.md").display(),
        out.join("table.csv").display()
    );
    Ok(())
}

pub fn experiment_trade(out: &Path, quick: bool, wire_only: bool, wire_speed: f64) -> Result<()> {
    // The guidewire's knobs (docs/RESULTS.md, "Guidewire").
    let wire = nvtmm::experiment::wire_trade::rows(quick, wire_speed)?;
    let table = format!(
        "The guidewire pushed at {:.0} mm/s.\n\n{}",
        wire_speed * 1e3,
        nvtmm::experiment::wire_trade::markdown(&wire)
    );
    std::fs::create_dir_all(out)?;
    std::fs::write(out.join("trade_wire.md"), &table)?;
    println!("{table}");
    println!("wrote {}", out.join("trade_wire.md").display());
    if wire_only {
        return Ok(());
    }
    let (rows, finest) = nvtmm::experiment::trade::run(out, quick)?;
    println!("{}", nvtmm::experiment::trade::markdown(&rows, finest));
    println!(
        "wrote {}, {} and {}",
        out.join("trade.md").display(),
        out.join("trade.csv").display(),
        out.join("trade.png").display()
    );
    Ok(())
}
