//! The stream publisher thread (normal priority): turns the loop's state
//! snapshots into stream frames, x = X + ū + Φ δq at the stream's vertices,
//! publishes them (UDP, recording; see `crate::stream`) and keeps the latest
//! one for [`crate::service::Handle::snapshot`]. Never blocks the loop: it
//! only pops rings.

use super::background::OffsetMsg;
use super::instrument::VesselView;
use super::live::{FrameSnapshot, InstrumentPolyline, LiveStats};
use crate::haptics::servo::flags;
use crate::math::Vec3;
use nalgebra::SVector;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

/// A loop state snapshot (loop → stream publisher).
#[derive(Debug, Clone, Copy)]
pub struct StateSnapshot<const R: usize> {
    /// Loop time (s).
    pub time_s: f64,
    /// Epoch of the model in use.
    pub epoch: u64,
    /// Reduced coordinates δq.
    pub q: SVector<f64, R>,
    /// The share of δq the instruments' point loads caused: a rod's lumen
    /// is the wall without it (`Servo::node_position_without_point_loads`).
    pub q_loads: SVector<f64, R>,
    /// Tool centre (m, scene frame).
    pub tool: Vec3,
    /// Commanded force (N).
    pub force: Vec3,
    /// Status bits.
    pub flags: u32,
    /// Largest tick compute time since the previous snapshot (µs).
    pub tick_max_us: f32,
}

/// What the publisher thread returns at the end.
#[derive(Default)]
pub(super) struct PublisherResult {
    pub frames: u64,
    pub errors: u64,
    pub first_error: Option<String>,
    pub igtl: Option<crate::stream::igtl::IgtlStats>,
    /// The task's figures at the end (None without `[task]`).
    pub task: Option<crate::task::TaskSummary>,
    /// The watching hand's watched moves (the report's `hand_watches`).
    pub hand_watches: Vec<super::report::HandWatchReport>,
}

/// What the publisher thread needs.
pub(super) struct PublisherPlan<const R: usize> {
    pub publisher: crate::stream::Publisher,
    pub rows: crate::reduced::BasisRows<R>,
    pub state: rtrb::Consumer<StateSnapshot<R>>,
    pub offsets: rtrb::Consumer<OffsetMsg<R>>,
    pub first_offset: Arc<Vec<Vec3>>,
    pub tool_radius: f64,
    pub simulated: bool,
    /// Send or record frames (`[stream] enabled`, or `--record`); without
    /// it the thread only keeps the latest frame for snapshots.
    pub send: bool,
    pub stop: Arc<AtomicBool>,
    pub live: Arc<LiveStats>,
    pub faults: Arc<super::faults::FaultSwitches>,
    /// The task metrics, fed one sample per state frame (None: no task).
    pub task: Option<super::task_feed::TaskFeed>,
    /// The instruments' publisher sides, in registry order, with their
    /// stream id (their index in the run's list) and kind.
    pub instruments: Vec<PublishedInstrument>,
    /// The simulated hand's eyes and the places in `instruments` of the
    /// hub-driven ones, in the switch button's order (None: the hand does
    /// not watch).
    pub hand_watcher: Option<(super::script::TipWatcher, Vec<usize>)>,
}

/// One instrument on the publisher thread.
pub(super) struct PublishedInstrument {
    pub id: &'static str,
    pub kind: super::instrument::Kind,
    pub side: Box<dyn super::instrument::PublisherSide>,
}

/// The stream publisher (normal priority): turns loop snapshots into stream
/// frames, x = X + ū + Φ δq at the stream's vertices, and publishes them.
/// Never blocks the loop (it only pops rings).
pub(super) fn publisher_thread<const R: usize>(mut p: PublisherPlan<R>) -> PublisherResult {
    use crate::stream::{flags as sf, InstrumentLine, StateFrame};
    let topo = p.publisher.topology().clone();
    let mut positions = vec![[0f32; 3]; topo.node_ids.len()];
    let mut offsets: std::collections::VecDeque<OffsetMsg<R>> = std::collections::VecDeque::new();
    offsets.push_back((0, p.first_offset.clone(), p.rows.clone()));
    let mut last_epoch = 0;
    let mut refreshed_at = f64::NEG_INFINITY;
    let mut times: std::collections::VecDeque<f64> = std::collections::VecDeque::new();
    let mut maxes: std::collections::VecDeque<f32> = std::collections::VecDeque::new();
    let mut errors = 0u64;
    let mut first_error = None;
    let mut dent = vec![Vec3::zeros(); p.rows.len()];
    let mut dent_touched: Vec<u32> = Vec::new();
    while !p.stop.load(Ordering::Relaxed) {
        while let Ok(o) = p.offsets.pop() {
            offsets.push_back(o);
            while offsets.len() > 8 {
                offsets.pop_front();
            }
        }
        let mut snap = None;
        while let Ok(s) = p.state.pop() {
            times.push_back(s.time_s);
            maxes.push_back(s.tick_max_us);
            snap = Some(s);
        }
        let Some(s) = snap else {
            std::thread::sleep(std::time::Duration::from_millis(2));
            continue;
        };
        if super::faults::FaultSwitches::take(&p.faults.panic_publisher) {
            panic!("injected fault: the stream publisher panics");
        }
        while times.len() > 61 {
            times.pop_front();
            maxes.pop_front();
        }
        let (offset, rows) = match offsets
            .iter()
            .rev()
            .find(|(e, _, _)| *e == s.epoch)
            .or_else(|| offsets.back())
        {
            Some((_, o, r)) => (Some(o.clone()), r.clone()),
            None => (None, p.rows.clone()),
        };
        // The wall's residual dent under the instruments' newest loads
        // (the reduced model's share is in δq).
        for &i in &dent_touched {
            dent[i as usize] = Vec3::zeros();
        }
        dent_touched.clear();
        for inst in &p.instruments {
            inst.side.add_dent(&mut dent, &mut dent_touched);
        }
        for (k, &node) in topo.node_ids.iter().enumerate() {
            let i = node as usize;
            let rest = Vec3::from(topo.rest_positions[k].map(f64::from));
            let ubar = offset
                .as_ref()
                .and_then(|o| o.get(i).copied())
                .unwrap_or_else(Vec3::zeros);
            let d = rows.get(i).map(|row| row * s.q).unwrap_or_else(Vec3::zeros);
            let x = rest + ubar + d + dent.get(i).copied().unwrap_or_else(Vec3::zeros);
            positions[k] = [x.x as f32, x.y as f32, x.z as f32];
        }
        {
            let q_wall = s.q - s.q_loads;
            let without_point_loads = |i: u32, rest: Vec3| {
                let ubar = offset
                    .as_ref()
                    .and_then(|o| o.get(i as usize).copied())
                    .unwrap_or_else(Vec3::zeros);
                rest + ubar + rows.get(i as usize).map(|row| row * q_wall).unwrap_or_else(Vec3::zeros)
            };
            let point_load_dent = |i: u32| {
                let residual = dent.get(i as usize).copied().unwrap_or_else(Vec3::zeros);
                rows.get(i as usize)
                    .map(|row| row * s.q_loads)
                    .unwrap_or_else(Vec3::zeros)
                    + residual
            };
            let view = VesselView {
                tool: s.tool,
                without_point_loads: &without_point_loads,
                point_load_dent: &point_load_dent,
                point_loads_active: s.q_loads.iter().any(|&v| v != 0.0) || !dent_touched.is_empty(),
            };
            for inst in p.instruments.iter_mut() {
                inst.side.update(&view);
            }
        }
        // The scripted hand watches the tips as the stream shows them.
        if let Some((w, hub)) = p.hand_watcher.as_mut() {
            for (rod, &k) in hub.iter().enumerate() {
                if let Some(i) = p.instruments.get(k) {
                    w.look(rod, i.side.polyline());
                }
            }
        }
        if s.epoch != last_epoch {
            last_epoch = s.epoch;
            refreshed_at = s.time_s;
        }
        let mut fl = 0;
        for (a, b) in [
            (flags::WATCHDOG, sf::WATCHDOG_ACTIVE),
            (flags::CONTACT, sf::IN_CONTACT),
            (flags::LIMITED, sf::FORCE_LIMITED),
            (flags::RT_GRANTED, sf::RT_GRANTED),
        ] {
            if s.flags & a != 0 {
                fl |= b;
            }
        }
        if s.time_s - refreshed_at < 0.5 {
            fl |= sf::MODEL_REFRESHED;
        }
        if p.simulated {
            fl |= sf::DEVICE_SIMULATED;
        }
        let rate = match (times.front(), times.back()) {
            (Some(a), Some(b)) if b > a => {
                // Snapshots come every `state_every` ticks.
                (times.len() - 1) as f64 / (b - a) * (1e3 / 60.0f64).floor()
            }
            _ => 0.0,
        };
        let p99 = maxes.iter().copied().fold(0.0f32, f32::max);
        // One polyline per instrument; its stream id is its place in the
        // run's list.
        let lines: Vec<InstrumentLine<'_>> = p
            .instruments
            .iter()
            .enumerate()
            .map(|(k, i)| InstrumentLine {
                id: k as u8,
                kind: i.kind.code,
                points: i.side.polyline(),
            })
            .collect();
        let frame = StateFrame {
            time_s: s.time_s,
            positions: &positions,
            tool_position: [s.tool.x as f32, s.tool.y as f32, s.tool.z as f32],
            tool_radius: p.tool_radius as f32,
            force: [s.force.x as f32, s.force.y as f32, s.force.z as f32],
            flags: fl,
            loop_rate_hz: rate as f32,
            tick_p99_us: p99,
            instruments: &lines,
        };
        if let Some(t) = p.task.as_mut() {
            // The task follows the first guidewire of the run.
            let wire = p.instruments.iter().find(|i| i.kind.name == "guidewire");
            let wall = wire.map_or(0.0, |w| w.side.wall_force_n());
            let polyline = wire.map_or(&[][..], |w| w.side.polyline());
            // The force as the stream carries it (f32), so that a script over
            // the recording finds the same peak.
            let f = frame.force.map(f64::from);
            t.push(
                s.time_s,
                polyline,
                (f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt(),
                wall,
            );
        }
        p.live.record_frame(FrameSnapshot {
            time_s: s.time_s,
            node_ids: topo.node_ids.clone(),
            positions: positions.clone(),
            tool_position: frame.tool_position,
            force: frame.force,
            flags: fl,
            triangles: topo.triangles.clone(),
            instruments: p
                .instruments
                .iter()
                .zip(&lines)
                .map(|(i, l)| InstrumentPolyline {
                    id: i.id.to_string(),
                    kind: i.kind.name.to_string(),
                    stream_id: l.id,
                    kind_code: l.kind,
                    points: l.points.to_vec(),
                })
                .collect(),
        });
        if !p.send {
            continue;
        }
        if let Err(e) = p.publisher.publish(&frame) {
            errors += 1;
            first_error.get_or_insert_with(|| e.to_string());
        }
    }
    let frames = p.publisher.stats().frames;
    let igtl = p.publisher.igtl_stats();
    match p.publisher.finish() {
        Ok(_) => {}
        Err(e) => {
            first_error.get_or_insert_with(|| e.to_string());
        }
    }
    let task = p.task.map(|t| {
        let (summary, error) = t.finish();
        if let Some(e) = error {
            first_error.get_or_insert(e);
        }
        summary
    });
    let hand_watches = p.hand_watcher.map_or_else(Vec::new, |(w, _)| w.report());
    PublisherResult {
        frames,
        errors,
        first_error,
        igtl,
        task,
        hand_watches,
    }
}
