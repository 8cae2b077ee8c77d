//! The real-time haptic service, `nvtmm run`: the threads of
//! `shared/DESIGN.md` (device I/O, the 1 kHz haptic loop, the background
//! full NVTMM solve with its model refresh, the stream publisher and the
//! reporter), the rings between them, and the end-of-run report.

pub mod background;
pub mod config;
pub mod report;
pub mod run;

pub use config::ServiceConfig;
