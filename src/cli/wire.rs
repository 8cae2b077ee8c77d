//! `nvtmm bench wire …`: the guidewire's step time against its node count.

use nvtmm::bench::coaxial_tick::{bench_coaxial_tick, CoaxialTickOptions};
use nvtmm::bench::wire::bench_wire;
use nvtmm::bench::wire_tick::{bench_wire_tick, WireTickOptions};
use nvtmm::wire::coaxial::Coupling;
use std::path::{Path, PathBuf};

/// `rt-config/guidewire.toml` in the working directory if it is there,
/// else the one in the source tree this binary was built from.
pub fn default_guidewire_config() -> PathBuf {
    shipped_config("guidewire.toml")
}

/// `rt-config/cannulate_left_subclavian.toml` (a wire inside a catheter),
/// found as [`default_guidewire_config`] finds its file.
pub fn default_coaxial_config() -> PathBuf {
    shipped_config("cannulate_left_subclavian.toml")
}

/// `rt-config/<name>` in the working directory if it is there, else the
/// one in the source tree this binary was built from.
fn shipped_config(name: &str) -> PathBuf {
    let local = Path::new("rt-config").join(name);
    if local.is_file() {
        return local;
    }
    let built = Path::new(env!("CARGO_MANIFEST_DIR")).join("rt-config").join(name);
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
    println!(
        "buckling check factored on {} of {} steps, moved off a saddle on {}; tip at ({:.17e}, {:.17e}, {:.17e}) m",
        b.buckling_checks, b.ticks, b.buckled, b.tip_m[0], b.tip_m[1], b.tip_m[2]
    );
    print_paced(b.paced, &b.rt, b.memory_locked);
    print_parts(&[
        ("whole tick", &b.tick_us),
        ("wire step", &b.wire_us),
        ("wall loads → reduced model", &b.loads_us),
        ("haptic tick (contact, reduced step, QP)", &b.haptic_us),
        ("  of which the passivity filter", &b.qp_us),
        (
            "lumen rebuild (60 Hz ticks only; the publisher's thread, not in the whole tick)",
            &b.lumen_us,
        ),
    ]);
    Ok(())
}

/// `nvtmm bench wire --tick --coaxial [--config C] [--nodes N] [--steps S]
/// [--line-load F] [--follow-wall] [--rt CPU] [--lagged] [--parallel CPU]
/// [--json]`: the whole tick
/// with a wire inside a catheter in the branched arch, and its parts.
pub fn bench_coaxial_tick_cmd(config: &Path, o: &CoaxialTickOptions, json: bool) -> Result<()> {
    let b = bench_coaxial_tick(config, o)?;
    if json {
        println!("{}", serde_json::to_string_pretty(&b)?);
        return Ok(());
    }
    println!(
        "wire {} nodes ({:.2} mm segments, {:.1} mm inserted) inside catheter {} nodes ({:.2} mm, {:.1} mm), line load {} N/m: \
         wall contacts {:.1} mean, {} max; the wire on the catheter {:.1} mean; {} point loads at most; QP solved on {} of {} ticks; \
         {} lumen rebuilds ({})",
        b.wire_nodes,
        b.segment_mm[0],
        b.inserted_mm[0],
        b.catheter_nodes,
        b.segment_mm[1],
        b.inserted_mm[1],
        b.line_load_n_per_m,
        b.contacts_mean,
        b.contacts_max,
        b.sheath_contacts_mean,
        b.loads_max,
        b.qp_solved,
        b.ticks,
        b.lumen_updates,
        if b.follow_wall { "deformed wall" } else { "rest wall" },
    );
    println!(
        "Newton iterations ({} before the residual's extra ones): wire {:.2} mean, {} most; catheter {:.2} mean, {} most; \
         evaluations {:.1} mean, {} most; {} of {} steps ended off equilibrium, {} stopped at the time limit; \
         resets {} in the set-up, {} timed; deepest {:.3} mm into the wall, {:.3} mm into the catheter",
        b.iterations_max,
        b.iterations_mean[0],
        b.iterations_most[0],
        b.iterations_mean[1],
        b.iterations_most[1],
        b.evaluations_mean,
        b.evaluations_max,
        b.unsettled_steps,
        b.ticks,
        b.time_limited,
        b.resets_setup,
        b.resets,
        b.max_penetration_mm,
        b.max_sheath_penetration_mm,
    );
    println!(
        "allocations in the timed ticks: {} from the RT pool in the rods' part, {} in the haptic tick (the QP's), {} system calls{}",
        b.pool_allocations_rods,
        b.pool_allocations_haptic,
        b.system_allocations,
        if b.allocator_installed {
            ""
        } else {
            " (the RT allocator is not installed: not counted)"
        }
    );
    print_paced(b.paced, &b.rt, b.memory_locked);
    let pair = match (b.coupling, &b.worker_rt) {
        (Coupling::GaussSeidel, _) => "coupled step (Gauss–Seidel: wire, then catheter)",
        (Coupling::Lagged, None) => "coupled step (lagged, one thread: wire, then catheter)",
        (Coupling::Lagged, Some(_)) => "coupled step (lagged: wire and catheter at once)",
    };
    if let Some(g) = &b.worker_rt {
        println!(
            "the catheter's thread on CPU {}, {}{}; {} system-allocator calls; {} of the timed steps taken back by the ticks' thread",
            g.cpu.map_or("(not pinned)".to_string(), |c| c.to_string()),
            if g.fifo {
                format!("SCHED_FIFO {}", g.priority)
            } else {
                "ordinary policy".to_string()
            },
            if g.refusals.is_empty() {
                String::new()
            } else {
                format!(" (refused: {})", g.refusals.join("; "))
            },
            b.worker_system_allocations,
            b.worker_taken_back
        );
    }
    print_parts(&[
        ("whole tick", &b.tick_us),
        (pair, &b.pair_us),
        ("wall loads → reduced model (both rods)", &b.loads_us),
        ("haptic tick (contact, reduced step, QP)", &b.haptic_us),
        ("  of which the passivity filter", &b.qp_us),
        (
            "lumen rebuild (60 Hz ticks only; the publisher's thread, not in the whole tick)",
            &b.lumen_us,
        ),
    ]);
    Ok(())
}

/// How the ticks ran: paced on a CPU with what the OS granted, or back to
/// back.
fn print_paced(paced: bool, rt: &nvtmm::rt::thread::RtGrant, memory_locked: bool) {
    if paced {
        println!(
            "ticks one a period on CPU {}, {}, memory {}{}",
            rt.cpu.map_or("(not pinned)".to_string(), |c| c.to_string()),
            if rt.fifo {
                format!("SCHED_FIFO {}", rt.priority)
            } else {
                "ordinary policy".to_string()
            },
            if memory_locked { "locked" } else { "not locked" },
            if rt.refusals.is_empty() {
                String::new()
            } else {
                format!(" (refused: {})", rt.refusals.join("; "))
            }
        );
    } else {
        println!("ticks back to back in an ordinary thread (--rt CPU: as the service's wire thread)");
    }
}

/// The parts' percentiles as a Markdown table.
fn print_parts(parts: &[(&str, &nvtmm::rt::stats::Percentiles)]) {
    println!("| part | p50 µs | p99 µs | p99.9 µs | max µs |");
    println!("|:---|---:|---:|---:|---:|");
    for (name, p) in parts {
        println!(
            "| {name} | {:.1} | {:.1} | {:.1} | {:.1} |",
            p.p50, p.p99, p.p999, p.max
        );
    }
}
