//! `nvtmm experiment cubic` (the linear against the cubic reduced model).

use std::path::Path;

type Result<T> = std::result::Result<T, Box<dyn std::error::Error>>;

/// `nvtmm experiment cubic [--out DIR] [--quick]`: runs the experiment and
/// prints its markdown table.
pub fn experiment_cubic(out: &Path, quick: bool) -> Result<()> {
    nvtmm::experiment::cubic::run(out, quick)?;
    let md = out.join("cubic.md");
    print!(
        "{}",
        std::fs::read_to_string(&md).map_err(|e| format!("{}: {e}", md.display()))?
    );
    println!(
        "wrote {}, {}, {}, {}",
        out.join("cubic.csv").display(),
        out.join("cubic_precompute.csv").display(),
        out.join("cubic_series.csv").display(),
        md.display()
    );
    Ok(())
}
