//! `nvtmm basis …` and `nvtmm bench reduced …` subcommands.

use indicatif::{ProgressBar, ProgressStyle};
use nvtmm::bench::reduced::bench_reduced;
use nvtmm::reduced::cache::{basis_for_scene, CacheStatus};
use nvtmm::scene::Scene;
use std::path::Path;
use std::time::Duration;

type Result<T> = std::result::Result<T, Box<dyn std::error::Error>>;

/// `nvtmm basis SCENE.toml [--r R] [--force]`.
pub fn basis(scene_path: &Path, r: Option<usize>, force: bool) -> Result<()> {
    let scene = Scene::load(scene_path)?;
    let bar = ProgressBar::new_spinner();
    bar.set_style(
        ProgressStyle::with_template("{spinner} [{elapsed_precise}] {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_spinner()),
    );
    bar.enable_steady_tick(Duration::from_millis(120));
    bar.set_message("building the mesh");
    let built = scene.build()?;
    bar.set_message(format!(
        "basis on {} nodes ({} fixed): cache lookup, else shift-invert subspace iteration",
        built.mesh.num_nodes(),
        built.fixed.len()
    ));
    let res = basis_for_scene(&scene, &built, r, force);
    bar.finish_and_clear();
    let (b, outcome) = res?;
    let what = match &outcome.status {
        CacheStatus::Hit => "loaded from the cache".to_string(),
        CacheStatus::Computed => format!("computed in {:.2} s", outcome.compute_s),
        CacheStatus::Bypassed => format!("computed in {:.2} s (cache not read)", outcome.compute_s),
        CacheStatus::Recomputed(why) => format!("computed in {:.2} s (cache file unusable: {why})", outcome.compute_s),
    };
    let f = |w: f64| w.max(0.0).sqrt() / (2.0 * std::f64::consts::PI);
    println!(
        "basis: {} vectors ({} static), {} nodes, {what}; frequencies {:.2}..{:.2} Hz",
        b.len(),
        b.num_static,
        b.num_nodes(),
        b.omega2.first().map_or(0.0, |&w| f(w)),
        b.omega2.last().map_or(0.0, |&w| f(w)),
    );
    match (&outcome.path, &outcome.store_error) {
        (_, Some(e)) => eprintln!("warning: could not store the basis: {e}"),
        (Some(p), None) => println!("cache: {} (key {:016x})", p.display(), outcome.key),
        (None, None) => println!("cache: off"),
    }
    Ok(())
}

/// `nvtmm bench reduced --r R [--nodes N] [--steps S] [--json]`.
pub fn bench_reduced_cmd(r: usize, nodes: usize, steps: usize, json: bool) -> Result<()> {
    let b = bench_reduced(r, nodes, steps)?;
    if json {
        println!("{}", serde_json::to_string_pretty(&b)?);
    } else {
        println!(
            "reduced r = {} on {} nodes: step {:.2} µs median, {:.2} µs p99; refresh {:.2} ms \
             (+ {:.2} ms tangent assembly in the full step); basis {:.2} s cold ({} iterations), \
             {:.2} s warm ({} iterations)",
            b.r,
            b.nodes,
            b.us_per_step,
            b.us_per_step_p99,
            b.refresh_ms,
            b.refresh_assembly_ms,
            b.basis_s,
            b.basis_iterations,
            b.basis_warm_s,
            b.basis_warm_iterations
        );
    }
    Ok(())
}

/// `nvtmm experiment reduced [--out DIR] [--quick]`.
pub fn experiment_reduced(out: &Path, quick: bool) -> Result<()> {
    nvtmm::experiment::reduced::run(out, quick)?;
    let md = out.join("reduced.md");
    print!(
        "{}",
        std::fs::read_to_string(&md).map_err(|e| format!("{}: {e}", md.display()))?
    );
    println!(
        "wrote {}, {}, {}",
        out.join("reduced.csv").display(),
        out.join("roi.csv").display(),
        md.display()
    );
    Ok(())
}

/// The options of `nvtmm experiment contact`.
#[derive(clap::Args)]
pub struct ContactArgs {
    /// 1458 nodes, r = 16, 60 points (else 5832 nodes, r = 32, 120 points).
    #[arg(long)]
    pub quick: bool,
    /// JSON on stdout (the ratio and settle-time keys), no table.
    #[arg(long)]
    pub json: bool,
    /// Arch nodes (overrides the size --quick or the default picks).
    #[arg(long)]
    pub nodes: Option<usize>,
    /// Surface points (half on the inner wall, half on the outer).
    #[arg(long)]
    pub points: Option<usize>,
    /// The arch with its three supra-aortic branches (every vessel end
    /// fixed) instead of the unbranched one.
    #[arg(long)]
    pub branched: bool,
    /// Random seed of the surface points.
    #[arg(long, default_value_t = 7)]
    pub seed: u64,
    /// How far the probe is held into the undeformed wall (mm), one run
    /// per value, comma-separated, each in (0, 3] (at most the probe's radius).
    #[arg(long, value_delimiter = ',', default_value = "0.5")]
    pub push_mm: Vec<f64>,
    /// The wall: `paper` (NVTMM StVK 65 kPa) or `human` (the human aorta
    /// scene's Neo-Hookean 0.7 MPa, which holds arterial pressure).
    #[arg(long, default_value = "paper")]
    pub wall: String,
    /// Steady luminal pressure (Pa) the wall is inflated to before the
    /// probe pushes; needs --wall human.
    #[arg(long, default_value_t = 0.0)]
    pub pressure_pa: f64,
    /// Push the loop's probe in from where it touches the wall at this
    /// speed (mm/s, in (0, 1000]), as the reference is pushed in, instead
    /// of placing it at its depth on the first tick; the first tick and
    /// the settle time then count from its arrival.
    #[arg(long)]
    pub push_speed_mm_s: Option<f64>,
}

/// `nvtmm experiment contact`.
pub fn experiment_contact(a: &ContactArgs) -> Result<()> {
    use nvtmm::experiment::contact::{run, ContactExperiment, Wall};
    let mut e = if a.quick {
        ContactExperiment::quick()
    } else {
        ContactExperiment::full()
    };
    if let Some(n) = a.nodes {
        e.nodes = n;
    }
    if let Some(p) = a.points {
        if p < 2 {
            return Err(format!("--points {p}: at least 2 (one per wall)").into());
        }
        e.points = p;
    }
    e.branched = a.branched;
    e.seed = a.seed;
    e.wall = match a.wall.as_str() {
        "paper" => Wall::Paper,
        "human" => Wall::Human,
        w => return Err(format!("--wall {w:?}: one of \"paper\", \"human\"").into()),
    };
    if !(a.pressure_pa.is_finite() && (0.0..=40e3).contains(&a.pressure_pa)) {
        return Err(format!("--pressure-pa {}: must be in [0, 40000] Pa", a.pressure_pa).into());
    }
    if a.pressure_pa > 0.0 && e.wall == Wall::Paper {
        return Err(format!(
            "--pressure-pa {}: the paper's 65 kPa wall cannot hold a luminal pressure (docs/PRESSURE.md, \"Material\"); add --wall human",
            a.pressure_pa
        )
        .into());
    }
    e.pressure_pa = a.pressure_pa;
    if let Some(v) = a.push_speed_mm_s {
        if !(v.is_finite() && v > 0.0 && v <= 1000.0) {
            return Err(format!("--push-speed-mm-s {v}: must be in (0, 1000] mm/s").into());
        }
        e.push_speed_m_s = v * 1e-3;
    }
    let tool_mm = nvtmm::haptics::contact::ContactParams::default().tool_radius_m * 1e3;
    if a.push_mm.is_empty() {
        return Err("--push-mm: give at least one depth".into());
    }
    for &d in &a.push_mm {
        if !(d.is_finite() && d > 0.0 && d <= tool_mm) {
            return Err(
                format!("--push-mm {d}: each depth must be in (0, {tool_mm}] mm (at most the probe's radius)").into(),
            );
        }
    }
    let mut runs = Vec::new();
    for &d in &a.push_mm {
        e.push_m = d * 1e-3;
        let r = run(&e)?;
        if !a.json {
            print_contact(&r, a.branched);
        }
        runs.push(r);
    }
    if a.json {
        let v: Vec<serde_json::Value> = runs
            .iter()
            .map(|r| {
                serde_json::json!({
                    "nodes": r.nodes,
                    "branched": a.branched,
                    "r": r.r,
                    "seed": a.seed,
                    "push_mm": r.push_m * 1e3,
                    "wall": r.wall,
                    "pressure_pa": r.pressure_pa,
                    "inflation_mm": r.inflation_m * 1e3,
                    "points": r.points.len(),
                    "dropped": r.dropped,
                    "within_10_percent": r.points.iter().filter(|p| (p.ratio_settled - 1.0).abs() <= 0.1).count(),
                    "ratio_settled_p05": r.ratio_settled.p05,
                    "ratio_settled_p50": r.ratio_settled.p50,
                    "ratio_settled_p95": r.ratio_settled.p95,
                    "ratio_settled_worst": r.ratio_settled.worst,
                    "ratio_first_p05": r.ratio_first.p05,
                    "ratio_first_p50": r.ratio_first.p50,
                    "ratio_first_p95": r.ratio_first.p95,
                    "ratio_basis_only_p50": r.ratio_settled_basis_only.p50,
                    "ratio_basis_only_worst": r.ratio_settled_basis_only.worst,
                    "settle_ms_p50": r.settle_ms.p50,
                    "settle_ms_p99": r.settle_ms.worst,
                    "reference_nodes_max": r.points.iter().map(|p| p.reference_nodes).max().unwrap_or(0),
                    "reference_rounds_max": r.points.iter().map(|p| p.reference_rounds).max().unwrap_or(0),
                    "table_s": r.table.seconds,
                    "table_solves": r.table.solves,
                })
            })
            .collect();
        let v = if v.len() == 1 {
            v[0].clone()
        } else {
            serde_json::Value::Array(v)
        };
        println!("{}", serde_json::to_string_pretty(&v)?);
    }
    Ok(())
}

fn print_contact(r: &nvtmm::experiment::contact::ContactResult, branched: bool) {
    println!(
        "contact anywhere: {} points on the {}-node {}arch, push {} mm, wall {}, pressure {} Pa (inflation {:.2} mm), r = {} (vibration modes only), residual compliance table {:.2} s ({} solves, {} blocks)",
        r.points.len(),
        r.nodes,
        if branched { "branched " } else { "" },
        r.push_m * 1e3,
        r.wall.name(),
        r.pressure_pa,
        r.inflation_m * 1e3,
        r.r,
        r.table.seconds,
        r.table.solves,
        r.table.blocks
    );
    let within = r.points.iter().filter(|p| (p.ratio_settled - 1.0).abs() <= 0.1).count();
    println!(
        "{within} of {} points settle within 10 % of the reference",
        r.points.len()
    );
    println!("| rendered / full force | p05 | p50 | p95 | worst |\n|---|---|---|---|---|");
    for (name, s) in [
        ("settled, with the residual compliance", &r.ratio_settled),
        ("first tick, with the residual compliance", &r.ratio_first),
        ("settled, the basis alone", &r.ratio_settled_basis_only),
    ] {
        println!(
            "| {name} | {:.3} | {:.3} | {:.3} | {:.3} |",
            s.p05, s.p50, s.p95, s.worst
        );
    }
    println!(
        "settle time (force within 10 % of the full model's from then on): p50 {:.0} ms, worst {:.0} ms",
        r.settle_ms.p50, r.settle_ms.worst
    );
    let (nodes, rounds) = r.points.iter().fold((0, 0), |(n, k), p| {
        (n.max(p.reference_nodes), k.max(p.reference_rounds))
    });
    println!("reference: up to {nodes} nodes solved for, up to {rounds} active-set rounds");
    if r.dropped.is_empty() {
        println!("no point dropped");
    }
    for d in &r.dropped {
        println!(
            "dropped node {} ({} wall): {}",
            d.node,
            if d.inner { "inner" } else { "outer" },
            d.reason
        );
    }
}

/// `nvtmm bench contact`.
pub fn bench_contact_cmd(nodes: usize, patches: usize, ticks: usize, json: bool) -> Result<()> {
    let b = nvtmm::bench::contact::bench_contact(nodes, patches, ticks)?;
    if json {
        println!("{}", serde_json::to_string_pretty(&b)?);
    } else {
        let p = &b.tick_us;
        println!(
            "contact anywhere, {} nodes, r = {}, {} patches ({} touched nodes): tick p50 {:.1} µs, p99 {:.1} µs, p99.9 {:.1} µs, max {:.1} µs (table {:.2} s)",
            b.nodes, b.r, b.patches, b.touched_nodes, p.p50, p.p99, p.p999, p.max, b.table_s
        );
        println!(
            "last tick: {} candidates, {} deformed positions, {} triangles, {} pressure samples, {} series iterations; {} of {} ticks searched the grid",
            b.candidates, b.positions, b.triangles, b.samples, b.iterations, b.search_ticks, ticks
        );
    }
    Ok(())
}
