//! The instruments the hand works, behind one seam (docs/INSTRUMENTS.md).
//! The haptic loop, the publisher, the report, the stream and the C ABI
//! iterate over one list of instruments and never name a kind. Each kind
//! lives in its own module here ([`probe`], [`guidewire`], [`catheter`]) and is built by
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

pub mod catheter;
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
    /// Whether the stylus works this instrument's hub now (always true for
    /// an instrument that is not hub-driven, [`LoopSide::hub_driven`]). An
    /// instrument that is not active holds its hub where it is, as a hand
    /// holds one instrument while it works the other, and gives the hand no
    /// force.
    pub active: bool,
    /// True on the tick the instrument became active: it takes the stylus
    /// up where it is ([`crate::wire::HubDrive::engage`]).
    pub engaged: bool,
}

/// An instrument's part in the haptic loop. Runs on the loop thread after
/// start: [`LoopSide::contribute`] must not allocate, free, lock, log or
/// block (rings and atomics only).
pub trait LoopSide: Send {
    /// This tick's contribution, borrowing the instrument's own buffers.
    fn contribute(&mut self, hand: &Hand<'_>) -> Contribution<'_>;
    /// Whether the stylus drives this instrument through a hub (a wire, a
    /// catheter), so that the switch button selects among such
    /// instruments ([`Selector`]). The probe is the stylus itself: false.
    fn hub_driven(&self) -> bool {
        false
    }
}

/// The device button that switches the active instrument: bit 0, the
/// Touch X's first stylus button (the page's `i` key and a gamepad's X
/// send it too, docs/DRIVING.md).
pub const SWITCH_BUTTON: u32 = 1;

/// Which hub-driven instrument the stylus works. The first hub-driven
/// instrument in registry order is active at the start; each press of
/// [`SWITCH_BUTTON`] (its rising edge) makes the next one active, in turn.
/// The others hold. Plain data: runs on the loop thread.
#[derive(Debug, Clone)]
pub struct Selector {
    hub_driven: heapless::Vec<bool, MAX_INSTRUMENTS>,
    active: Option<usize>,
    pressed: bool,
    engaged: bool,
    switches: u64,
}

impl Selector {
    /// A selector over instruments whose [`LoopSide::hub_driven`] are
    /// `hub_driven`, in loop order (at most [`MAX_INSTRUMENTS`]).
    pub fn new(hub_driven: impl IntoIterator<Item = bool>) -> Selector {
        let mut v = heapless::Vec::new();
        for h in hub_driven {
            let _ = v.push(h);
        }
        let active = v.iter().position(|&h| h);
        Selector {
            hub_driven: v,
            active,
            pressed: false,
            engaged: false,
            switches: 0,
        }
    }

    /// Reads this tick's sample: a fresh press of the switch button moves
    /// to the next hub-driven instrument. Allocates nothing.
    pub fn update(&mut self, sample: Option<&DeviceSample>) {
        self.engaged = false;
        let Some(s) = sample else { return };
        let pressed = s.buttons & SWITCH_BUTTON != 0;
        let edge = pressed && !self.pressed;
        self.pressed = pressed;
        let Some(a) = self.active else { return };
        if !edge {
            return;
        }
        let n = self.hub_driven.len();
        if let Some(next) = (1..n).map(|k| (a + k) % n).find(|&k| self.hub_driven[k]) {
            self.active = Some(next);
            self.engaged = true;
            self.switches += 1;
        }
    }

    /// The hand instrument `k` is given this tick.
    pub fn hand<'a>(&self, k: usize, sample: Option<&'a DeviceSample>, now_s: f64) -> Hand<'a> {
        let hub = self.hub_driven.get(k).copied().unwrap_or(false);
        let active = !hub || self.active == Some(k);
        Hand {
            sample,
            now_s,
            active,
            engaged: hub && active && self.engaged,
        }
    }

    /// The active hub-driven instrument's index, if there is one.
    pub fn active(&self) -> Option<usize> {
        self.active
    }

    /// Switches so far.
    pub fn switches(&self) -> u64 {
        self.switches
    }
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

/// Builds a kind's instruments when the configuration asks for them
/// (empty: not in this run). Usually one; a builder whose instruments
/// share one thread returns them together (the catheter and the wire
/// inside it, stepped as one coupled pair).
pub type Builder<const R: usize> = fn(&BuildContext<'_, R>) -> Result<Vec<Built>, ServiceError>;

/// Every instrument kind, in the order the loop runs them. A new kind is
/// its own module and one line here (docs/INSTRUMENTS.md).
pub fn registry<const R: usize>() -> [Builder<R>; 3] {
    [
        probe::build::<R>,
        guidewire::build_instrument::<R>,
        catheter::build_instrument::<R>,
    ]
}

/// Builds the instruments the configuration asks for, in registry order;
/// at most [`MAX_INSTRUMENTS`].
pub fn build_all<const R: usize>(ctx: &BuildContext<'_, R>) -> Result<Vec<Built>, ServiceError> {
    let mut out = Vec::new();
    for build in registry::<R>() {
        out.extend(build(ctx)?);
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
    /// Its kind (`probe`, `guidewire`, `catheter`).
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

#[cfg(test)]
mod tests {
    use super::*;

    fn pressed(buttons: u32) -> DeviceSample {
        DeviceSample {
            buttons,
            ..DeviceSample::REST
        }
    }

    #[test]
    fn each_press_of_the_switch_button_moves_to_the_next_hub_driven_instrument() {
        // A probe, a wire, a catheter.
        let mut s = Selector::new([false, true, true]);
        assert_eq!(s.active(), Some(1));
        let h = s.hand(0, None, 0.0);
        assert!(h.active && !h.engaged, "the probe is always active");
        assert!(!s.hand(2, None, 0.0).active);
        s.update(Some(&pressed(SWITCH_BUTTON)));
        assert_eq!(s.active(), Some(2));
        assert!(s.hand(2, None, 0.0).engaged && !s.hand(1, None, 0.0).active);
        // Held down: no further switch; engaged for one tick only.
        s.update(Some(&pressed(SWITCH_BUTTON | 4)));
        assert_eq!(s.active(), Some(2));
        assert!(!s.hand(2, None, 0.0).engaged);
        // Released, other buttons, no sample: nothing.
        s.update(Some(&pressed(4)));
        s.update(None);
        assert_eq!((s.active(), s.switches()), (Some(2), 1));
        // Pressed again: back to the wire, skipping the probe.
        s.update(Some(&pressed(SWITCH_BUTTON)));
        assert_eq!((s.active(), s.switches()), (Some(1), 2));
    }

    #[test]
    fn with_one_hub_driven_instrument_the_button_switches_nothing() {
        let mut s = Selector::new([false, true]);
        for b in [SWITCH_BUTTON, 0, SWITCH_BUTTON] {
            s.update(Some(&pressed(b)));
        }
        assert_eq!((s.active(), s.switches()), (Some(1), 0));
        assert!(!s.hand(1, None, 0.0).engaged);
        let mut none = Selector::new([false]);
        none.update(Some(&pressed(SWITCH_BUTTON)));
        assert_eq!(none.active(), None);
        assert!(none.hand(0, None, 0.0).active);
    }
}
