//! `nvtmm bench wire …`: the guidewire's step time against its node count.

use nvtmm::bench::wire::bench_wire;

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
