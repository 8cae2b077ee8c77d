//! `nvtmm bench wire …`: the guidewire's step time against its node count.

use nvtmm::bench::wire::bench_wire;
use nvtmm::bench::wire_tick::{bench_wire_tick, WireTickOptions};
use std::path::{Path, PathBuf};

/// `rt-config/guidewire.toml` in the working directory if it is there,
/// else the one in the source tree this binary was built from.
pub fn default_guidewire_config() -> PathBuf {
    let local = Path::new("rt-config").join("guidewire.toml");
    if local.is_file() {
        return local;
    }
    let built = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("rt-config")
        .join("guidewire.toml");
    if built.is_file() {
        built
    } else {
        local
    }
}

type Result<T> = std::result::Result<T, Box<dyn std::error::Error>>;

/// `nvtmm bench wire [--nodes N] [--steps S] [--iterations K] [--json]`: without `--nodes`,
/// sweeps 32, 64, 128, 256, 512 nodes, each in free space and on a wall.
pub fn bench_wire_cmd(nodes: Option<usize>, steps: usize, iterations: usize, json: bool) -> Result<()> {
    let sizes: Vec<usize> = match nodes {
        Some(n) => vec![n],
        None => vec![32, 64, 128, 256, 512],
    };
    let mut rows = Vec::new();
    for &n in &sizes {
        for contacts in [false, true] {
            rows.push(bench_wire(n, steps, contacts, iterations)?);
        }
    }
    if json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
    } else {
        println!("| nodes | contacts | p50 µs | p99 µs | max µs | ns/node | iterations | contacts/step |");
        println!("|---:|:---|---:|---:|---:|---:|---:|---:|");
        for r in &rows {
            println!(
                "| {} | {} | {:.1} | {:.1} | {:.1} | {:.0} | {:.2} | {:.1} |",
                r.nodes,
                if r.contacts { "yes" } else { "no" },
                r.us_p50,
                r.us_p99,
                r.us_max,
                r.ns_per_node,
                r.iterations_mean,
                r.contacts_mean
            );
        }
    }
    Ok(())
}

/// `nvtmm bench wire --coaxial [--nodes N] [--steps S] [--json]`: the
/// coupled step of a wire inside a catheter in a curved tube.
pub fn bench_coaxial_cmd(nodes: usize, steps: usize, json: bool) -> Result<()> {
    let b = nvtmm::bench::coaxial::bench_coaxial(nodes, steps)?;
    if json {
        println!("{}", serde_json::to_string_pretty(&b)?);
        return Ok(());
    }
    println!(
        "coupled step, {} wire nodes inside {} catheter nodes, {} steps: p50 {:.1} µs, p99 {:.1} µs, p99.9 {:.1} µs, max {:.1} µs",
        b.wire_nodes, b.catheter_nodes, b.steps, b.us_p50, b.us_p99, b.us_p999, b.us_max
    );
    println!(
        "  {} Gauss–Seidel pass a step; Newton iterations: wire mean {:.2} (most {}), catheter mean {:.2} (most {}); evaluations mean {:.1} (most {})",
        b.passes_per_step,
        b.wire_iterations_mean,
        b.wire_iterations_max,
        b.catheter_iterations_mean,
        b.catheter_iterations_max,
        b.evaluations_mean,
        b.evaluations_max
    );
    println!(
        "  contacts a step: {:.1} with the wall, {:.1} of the wire on the catheter; {} steps ended off equilibrium",
        b.wall_contacts_mean, b.sheath_contacts_mean, b.unsettled_steps
    );
    Ok(())
}

/// `nvtmm bench wire --tick [--config C] [--nodes N] [--steps S]
/// [--iterations K] [--evaluations E] [--line-load F] [--follow-wall] [--rt CPU] [--json]`: the whole guidewire tick in
/// the branched arch, and its parts.
pub fn bench_wire_tick_cmd(config: &Path, o: &WireTickOptions, json: bool) -> Result<()> {
    let b = bench_wire_tick(config, o)?;
    if json {
        println!("{}", serde_json::to_string_pretty(&b)?);
        return Ok(());
    }
    println!(
        "{} nodes ({:.2} mm segments, {:.1} mm inserted), {} Newton iterations at most ({:.2} mean), \
         evaluations a step {:.2} mean, {} p99.9, {} max ({} allowed, {} steps spent them, {} stopped at the time limit), line load {} N/m: contacts {:.1} mean, {} max; {} point loads at most; QP solved on {} of {} ticks; \
         {} lumen rebuilds ({}); {} resets; deepest {:.3} mm",
        b.nodes,
        b.segment_mm,
        b.inserted_mm,
        b.iterations_max,
        b.iterations_mean,
        b.evaluations_mean,
        b.evaluations_p999,
        b.evaluations_max,
        b.evaluations_max_allowed,
        b.budget_spent,
        b.time_limited,
        b.line_load_n_per_m,
        b.contacts_mean,
        b.contacts_max,
        b.loads_max,
        b.qp_solved,
        b.ticks,
        b.lumen_updates,
        if b.follow_wall { "deformed wall" } else { "rest wall" },
        b.resets,
        b.max_penetration_mm
    );
    if b.paced {
        println!(
            "ticks one a period on CPU {}, {}, memory {}{}",
            b.rt.cpu.map_or("(not pinned)".to_string(), |c| c.to_string()),
            if b.rt.fifo {
                format!("SCHED_FIFO {}", b.rt.priority)
            } else {
                "ordinary policy".to_string()
            },
            if b.memory_locked { "locked" } else { "not locked" },
            if b.rt.refusals.is_empty() {
                String::new()
            } else {
                format!(" (refused: {})", b.rt.refusals.join("; "))
            }
        );
    } else {
        println!("ticks back to back in an ordinary thread (--rt CPU: as the service's wire thread)");
    }
    println!("| part | p50 µs | p99 µs | p99.9 µs | max µs |");
    println!("|:---|---:|---:|---:|---:|");
    for (name, p) in [
        ("whole tick", &b.tick_us),
        ("wire step", &b.wire_us),
        ("wall loads → reduced model", &b.loads_us),
        ("haptic tick (contact, reduced step, QP)", &b.haptic_us),
        ("  of which the passivity filter", &b.qp_us),
        (
            "lumen rebuild (60 Hz ticks only; the publisher's thread, not in the whole tick)",
            &b.lumen_us,
        ),
    ] {
        println!(
            "| {name} | {:.1} | {:.1} | {:.1} | {:.1} |",
            p.p50, p.p99, p.p999, p.max
        );
    }
    Ok(())
}
