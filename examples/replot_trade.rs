//! Draws the speed-for-accuracy figure again from its table, without
//! re-running the experiment: `docs/trade.csv` (written by `nvtmm experiment
//! trade`) into `docs/img/trade.png` (the figure of docs/RESULTS.md).
//!
//! ```text
//! cargo run --release --example replot_trade [-- CSV PNG]
//! ```

use std::path::PathBuf;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let csv = PathBuf::from(args.next().unwrap_or_else(|| "docs/trade.csv".into()));
    let png = PathBuf::from(args.next().unwrap_or_else(|| "docs/img/trade.png".into()));
    let rows = nvtmm::experiment::trade::read_csv(&csv)?;
    nvtmm::experiment::trade::plot(&rows, &png)?;
    println!("{}: {} rows -> {}", csv.display(), rows.len(), png.display());
    Ok(())
}
