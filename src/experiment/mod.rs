//! Experiments that reproduce the paper and measure the speed-for-accuracy
//! trade: `nvtmm experiment fig5|table`.
//!
//! Each experiment writes its data (CSV/JSON) and plots (PNG) into an output
//! directory; `docs/RESULTS.md` holds the committed figures with the exact
//! commands. Plotting lives in [`plot`]; the benchmarks' standard load in
//! [`crate::bench`].

pub mod contact;
pub mod cubic;
pub mod fig5;
pub mod plot;
pub mod reduced;
pub mod table;
pub mod trade;
pub mod wire_trade;

use std::path::{Path, PathBuf};

/// Errors of an experiment.
#[derive(Debug, thiserror::Error)]
pub enum ExperimentError {
    /// Building the mesh or solver failed.
    #[error("setup: {0}")]
    Setup(String),
    /// A step failed.
    #[error("{model}: step {step} failed: {reason}")]
    Step {
        /// Model.
        model: String,
        /// 1-based step.
        step: usize,
        /// Why.
        reason: String,
    },
    /// A file could not be written.
    #[error("{0}: {1}")]
    Io(PathBuf, std::io::Error),
    /// A plot could not be drawn.
    #[error("{0}: plot: {1}")]
    Plot(PathBuf, String),
}

impl ExperimentError {
    fn io(path: &Path, e: std::io::Error) -> ExperimentError {
        ExperimentError::Io(path.to_path_buf(), e)
    }
}
