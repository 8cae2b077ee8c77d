//! The instruments the hand works, behind one seam (docs/INSTRUMENTS.md).
//! The haptic loop, the publisher, the report, the stream and the C ABI
//! iterate over one list of instruments and never name a kind. Each kind
//! lives in its own module here ([`probe`], [`guidewire`]) and is built by
//! one line of [`registry`] into three parts:
//!
//! - a [`LoopSide`], run on the haptic loop thread once per tick: it gives
//!   its [`Contribution`] (force on the device's channels, point loads on
//!   the reduced model, contact spheres, faults) in one shape, without
//!   allocating, locking or blocking;
//! - a [`PublisherSide`], run on the stream publisher thread: what it needs
//!   of the deformed vessel, and its polyline for the stream;
//! - a [`ServiceSide`], kept by the running service: its own thread, if it
//!   has one (started by the builder), joined at the stop, and its section
//!   of the report.
//!
//! What does not live here: the loop's own stages (`crate::haptics::tick`)
//! and the physics of an instrument (`crate::wire` for the rods).

pub mod guidewire;
pub mod probe;

use super::config::ServiceConfig;
use super::faults::FaultSwitches;
use super::report::Report;
use super::ServiceError;
use crate::haptics::device::DeviceSample;
use crate::haptics::servo::LoopModel;
use crate::haptics::tick::{Contribution, MAX_INSTRUMENTS};
use crate::math::Vec3;
use crate::rt::clock::Nanos;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

/// What kind of instrument: its name (the report's `kind`, OpenIGTLink's
/// device name) and its code on the state stream (docs/STREAM.md).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Kind {
    /// Lower-case name, e.g. `guidewire`.
    pub name: &'static str,
    /// The stream's kind byte (1 probe, 2 guidewire, 3 catheter; 0 unused).
    pub code: u8,
}

/// What an instrument's loop side is given each tick.
#[derive(Debug, Clone, Copy)]
pub struct Hand<'a> {
    /// The freshest device sample, in the device's own frame (None before
    /// the first).
    pub sample: Option<&'a DeviceSample>,
    /// Loop time (s).
    pub now_s: f64,
}

/// An instrument's part in the haptic loop. Runs on the loop thread after
/// start: [`LoopSide::contribute`] must not allocate, free, lock, log or
/// block (rings and atomics only).
pub trait LoopSide: Send {
    /// This tick's contribution, borrowing the instrument's own buffers.
    fn contribute(&mut self, hand: &Hand<'_>) -> Contribution<'_>;
}

/// The deformed vessel as the publisher sees it for one state snapshot.
pub struct VesselView<'a> {
    /// Tool centre (m, scene frame).
    pub tool: Vec3,
    /// Position of mesh node `i` with rest position `x` (m), deformed by
    /// the vessel but without the instruments' point loads: the wall a rod
    /// that feels the wall's compliance in series must see (docs/WIRE.md,
    /// "The wall under the wire").
    pub without_point_loads: &'a dyn Fn(u32, Vec3) -> Vec3,
    /// Displacement of mesh node `i` the instruments' point loads caused
    /// (m): the reduced model's share plus the residual compliance's dent.
    pub point_load_dent: &'a dyn Fn(u32) -> Vec3,
    /// Whether any point load moved the wall in this snapshot.
    pub point_loads_active: bool,
}

/// An instrument's part on the stream publisher thread (a normal thread).
pub trait PublisherSide: Send {
    /// Takes one state snapshot: sends the instrument's thread what it needs
    /// of the vessel, takes its newest polyline.
    fn update(&mut self, view: &VesselView<'_>);
    /// Adds the display-only share of the wall's displacement under this
    /// instrument's loads to `dent` (one entry per mesh node) and lists the
    /// nodes it touched in `touched` (the caller zeroes them again).
    fn add_dent(&self, _dent: &mut [Vec3], _touched: &mut Vec<u32>) {}
    /// Its centreline for the stream, hub to tip (m, scene frame; at most
    /// [`crate::stream::MAX_INSTRUMENT_POINTS`]).
    fn polyline(&self) -> &[[f32; 3]];
    /// Its largest contact force on the vessel wall in the newest polyline's
    /// step (N; 0 for an instrument that loads no wall): the task metrics'
    /// wall force.
    fn wall_force_n(&self) -> f64 {
        0.0
    }
}

/// An instrument's part the running service keeps until the stop.
pub trait ServiceSide: Send {
    /// After the loop and the publisher have stopped: joins the
    /// instrument's thread and returns its section of the report; may also
    /// fill the report's own keys for the kind (`wire.*`).
    fn finish(&mut self, report: &mut Report) -> Result<InstrumentReport, ServiceError>;
}

/// An instrument built for a run.
pub struct Built {
    /// Its id in this run (unique; the report's and OpenIGTLink's name).
    pub id: &'static str,
    /// Its kind.
    pub kind: Kind,
    /// Its loop side.
    pub loop_side: Box<dyn LoopSide>,
    /// Its publisher side.
    pub publisher_side: Box<dyn PublisherSide>,
    /// Its service side (with its thread, if any, already started).
    pub service_side: Box<dyn ServiceSide>,
}

/// What a builder is given: the configuration and everything built before
/// the threads start.
pub struct BuildContext<'a, const R: usize> {
    /// The validated configuration.
    pub cfg: &'a ServiceConfig,
    /// The mesh (scene frame, m).
    pub mesh: &'a crate::mesh::TetMesh,
    /// The loop's first model (the reduced model at rest).
    pub vessel: &'a LoopModel<R>,
    /// The service's stop flag (an instrument's thread ends when it is set).
    pub stop: Arc<AtomicBool>,
    /// The fault-injection switches of the run.
    pub faults: Arc<FaultSwitches>,
    /// When the loop's first tick is due (ns, service clock).
    pub loop_start: Nanos,
    /// Loop ticks per state snapshot.
    pub state_every: u64,
}

/// Builds a kind's instrument when the configuration asks for it (None:
/// not in this run).
pub type Builder<const R: usize> = fn(&BuildContext<'_, R>) -> Result<Option<Built>, ServiceError>;

/// Every instrument kind, in the order the loop runs them. A new kind is
/// its own module and one line here (docs/INSTRUMENTS.md).
pub fn registry<const R: usize>() -> [Builder<R>; 2] {
    [probe::build::<R>, guidewire::build_instrument::<R>]
}

/// Builds the instruments the configuration asks for, in registry order;
/// at most [`MAX_INSTRUMENTS`].
pub fn build_all<const R: usize>(ctx: &BuildContext<'_, R>) -> Result<Vec<Built>, ServiceError> {
    let mut out = Vec::new();
    for build in registry::<R>() {
        if let Some(b) = build(ctx)? {
            out.push(b);
        }
    }
    if out.len() > MAX_INSTRUMENTS {
        return Err(ServiceError::Solver(format!(
            "{} instruments configured; the loop runs at most {MAX_INSTRUMENTS}",
            out.len()
        )));
    }
    Ok(out)
}

/// One instrument's section of the report (`instruments[k]`).
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct InstrumentReport {
    /// Its id in the run.
    pub id: String,
    /// Its kind (`probe`, `guidewire`).
    pub kind: String,
    /// Times it raised the watchdog (a stalled or reset thread).
    pub faults: u64,
    /// The kind's own figures (for the guidewire the same keys as
    /// `wire.*`).
    pub keys: serde_json::Value,
    /// One line for the human-readable summary.
    #[serde(skip)]
    pub summary: String,
}
