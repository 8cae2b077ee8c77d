//! The guidewire as an instrument of the service (docs/INSTRUMENTS.md): its
//! own fixed-rate RT thread (SCHED_FIFO, pinned, prefaulted, fixed
//! allocation, no locks), its loop side that drives it from the stylus and
//! feeds its resistance to the hand, its publisher side, and what goes
//! between them and the other threads.
//!
//! ```text
//!  haptic loop (1 kHz)                         wire thread (1/dt_s, +500 µs)
//!  HubDrive::command(sample) ── hub ring ───▶  Wire::set_hub, Wire::step(inner wall)
//!  hand force ◀── axial force (atomic) ──────  StepReport::hub_axial_force_n
//!  Servo point loads (reduced only) ◀─ loads ─  wall_loads (barycentric)
//!  publisher: x = X + ū + Φ (δq − δq_w) at the inner-wall vertices ── walls ──▶ TriangleLumen
//!  (δq_w: the share of δq the wire's loads caused; the wire's contact has
//!  the wall's compliance in series instead, docs/WIRE.md)
//!  publisher ◀── polyline ring ─────────────  positions (stream)
//! ```
//!
//! The wire step (docs/WIRE.md: ~1 µs per node per Newton iteration) does
//! not fit in the 1 kHz tick beside the vessel, so it runs beside the loop,
//! half a period after it: the force the hand feels uses the axial force of
//! the step that ended before the tick, at most one tick old. A step that
//! goes non-finite (or deeper into the wall than the wire's diameter), or a
//! wire thread that stops stepping, makes the loop's watchdog ramp the force
//! to zero and the wire return to its last good state (counted in
//! `wire.resets`).

use super::{BuildContext, Built, Hand, InstrumentReport, Kind, LoopSide, PublisherSide, ServiceSide, VesselView};
use crate::config::{Checker, ConfigError};
use crate::haptics::frame::DeviceFrame;
use crate::haptics::tick::Contribution;
use crate::haptics::touchx::{GimbalWaypoint, Waypoint};
use crate::math::Vec3;
use crate::rt::clock::{self, Nanos};
use crate::rt::stats::Histogram;
use crate::rt::thread::{setup_current, RtGrant, RtRequest};
use crate::service::faults::FaultSwitches;
use crate::service::report::{Report, WireReport};
use crate::service::ServiceError;
use crate::wire::coupling::{wall_loads, InnerWall, WallLoad, MAX_WALL_LOADS};
use crate::wire::{HubDrive, TriangleLumen, Wire, WireParams};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;

/// The guidewire's kind.
pub const KIND: Kind = Kind {
    name: "guidewire",
    code: 2,
};

/// Most points of the wire's polyline on the stream (a longer wire is
/// sampled every k-th node, tip always kept).
pub const MAX_POLYLINE: usize = crate::stream::MAX_INSTRUMENT_POINTS;

/// The wire thread runs this long after the loop's tick (ns): its step ends
/// before the next tick reads the axial force.
pub(super) const WIRE_PHASE: Nanos = 500_000;

/// `[guidewire]`: how the service runs the wire of `[wire]`.
#[derive(Debug, Clone, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct GuidewireConfig {
    /// Scene position of the access point (m): the hub, where the wire
    /// enters the vessel.
    pub access_point_m: [f64; 3],
    /// Insertion direction in the scene (into the vessel; normalised).
    pub axis: [f64; 3],
    /// Access by name: a mesh node set holding an opening's ring
    /// (`outlet_descending` on the built-in arches, `opening_<k>` on a
    /// generated mesh). The wire then enters through that opening's
    /// continuation, a straight rigid tube that guides it in from
    /// `access_depth_m` beyond the opening, along its axis, inward;
    /// `access_point_m` and `axis` are not used. Empty (the default): the
    /// wire is clamped at `access_point_m` along `axis`.
    pub access: String,
    /// With `access`: how far beyond the opening's plane the hub sits,
    /// along the opening's continuation (m): the guided path below the
    /// mesh (the lower descending and abdominal aorta for the descending
    /// outlet). Default 0.1 m, range 0–1 m.
    pub access_depth_m: f64,
    /// Inserted length at start (m).
    pub inserted_m: f64,
    /// The mesh's node set of the inner wall (the lumen the wire touches).
    pub wall_set: String,
    /// Whether the wire's contact forces load the vessel (the reduced model
    /// and the background solve); false: a rigid lumen that still follows
    /// the vessel's deformation.
    pub load_wall: bool,
    /// CPU of the wire thread (-1: not pinned).
    pub cpu: i32,
    /// SCHED_FIFO priority of the wire thread (0: normal policy).
    pub priority: u8,
    /// The loop raises a fault when the wire has not stepped for this long
    /// (ms): the force ramps to zero and the wire is reset when it returns.
    pub stall_ms: f64,
    /// Steps between saves of the last good state.
    pub good_state_every: u32,
    /// The simulated hand's script in the wire's terms: rows of
    /// `[time_s, inserted_m, roll_rad]`, turned into stylus waypoints and
    /// gimbal angles through the inverse of `[wire.drive]`.
    pub script: Vec<[f64; 3]>,
}

impl GuidewireConfig {
    /// The script's hub command (inserted length m, roll rad) at time `t_s`,
    /// linear between rows; before the first row its values, after the last
    /// the last; with no script, `inserted_m` and no roll.
    pub fn script_at(&self, t_s: f64) -> (f64, f64) {
        let Some(first) = self.script.first() else {
            return (self.inserted_m, 0.0);
        };
        if t_s <= first[0] {
            return (first[1], first[2]);
        }
        for w in self.script.windows(2) {
            if t_s <= w[1][0] {
                let a = (t_s - w[0][0]) / (w[1][0] - w[0][0]).max(1e-12);
                return (w[0][1] + a * (w[1][1] - w[0][1]), w[0][2] + a * (w[1][2] - w[0][2]));
            }
        }
        let last = self.script[self.script.len() - 1];
        (last[1], last[2])
    }
}

impl GuidewireConfig {
    /// The hub's access point and insertion axis: through the opening
    /// `access` names (see [`InnerWall::access_through`]), else
    /// `access_point_m` along `axis`.
    pub fn hub_pose(
        &self,
        mesh: &crate::mesh::TetMesh,
        wall: &InnerWall,
        lumen: &TriangleLumen,
    ) -> Result<(Vec3, Vec3), crate::wire::coupling::CouplingError> {
        if self.access.is_empty() {
            Ok((Vec3::from(self.access_point_m), Vec3::from(self.axis)))
        } else {
            wall.access_through(mesh, lumen, &self.access, self.access_depth_m)
        }
    }
}

impl Default for GuidewireConfig {
    fn default() -> Self {
        GuidewireConfig {
            access_point_m: [0.0; 3],
            axis: [0.0, 0.0, 1.0],
            access: String::new(),
            access_depth_m: 0.1,
            inserted_m: 0.02,
            wall_set: "inner_wall".into(),
            load_wall: true,
            cpu: 0,
            priority: 75,
            stall_ms: 20.0,
            good_state_every: 100,
            script: Vec::new(),
        }
    }
}

impl GuidewireConfig {
    /// Range checks; keys are named `guidewire.…`.
    pub fn validate(&self, c: &Checker, wire: &WireParams) -> Result<(), ConfigError> {
        for (k, v) in self.access_point_m.iter().enumerate() {
            c.f64_in(&format!("guidewire.access_point_m[{k}]"), *v, -10.0, 10.0, "m")?;
        }
        for (k, v) in self.axis.iter().enumerate() {
            c.f64_in(&format!("guidewire.axis[{k}]"), *v, -1000.0, 1000.0, "")?;
        }
        if Vec3::from(self.axis).norm() < 1e-9 {
            return Err(c.err("guidewire.axis", "must not be zero"));
        }
        c.f64_in("guidewire.access_depth_m", self.access_depth_m, 0.0, 1.0, "m")?;
        c.f64_in(
            "guidewire.inserted_m",
            self.inserted_m,
            0.0,
            wire.max_inserted_m(),
            "m (at most what the wire inserts)",
        )?;
        c.int_in("guidewire.cpu", self.cpu, -1, 1023)?;
        c.int_in("guidewire.priority", self.priority, 0, 99)?;
        c.f64_in("guidewire.stall_ms", self.stall_ms, 2.0, 10_000.0, "ms")?;
        c.int_in("guidewire.good_state_every", self.good_state_every, 1, 1_000_000)?;
        let mut last = f64::NEG_INFINITY;
        for (k, row) in self.script.iter().enumerate() {
            c.f64_in(&format!("guidewire.script[{k}][0]"), row[0], 0.0, 86_400.0, "s")?;
            if row[0] <= last {
                return Err(c.err(
                    &format!("guidewire.script[{k}][0]"),
                    format!("{}: times must increase", row[0]),
                ));
            }
            last = row[0];
            c.f64_in(
                &format!("guidewire.script[{k}][1]"),
                row[1],
                0.0,
                wire.max_inserted_m(),
                "m",
            )?;
            c.f64_in(&format!("guidewire.script[{k}][2]"), row[2], -1000.0, 1000.0, "rad")?;
        }
        if wire.max_nodes > 1024 {
            return Err(c.err(
                "wire.max_nodes",
                format!("{}: the service runs at most 1024", wire.max_nodes),
            ));
        }
        Ok(())
    }
}

/// The simulated hand of the script: stylus waypoints (device frame) and
/// gimbal angles, from `[time, inserted, roll]` rows through the inverse of
/// the drive's map (position along `drive.axis` from `drive.origin_m`,
/// roll on `drive.roll_index` divided by `drive.roll_scale`).
pub fn hand_script(g: &GuidewireConfig, wire: &WireParams) -> (Vec<Waypoint>, Vec<GimbalWaypoint>) {
    let d = &wire.drive;
    let rows: Vec<[f64; 3]> = if g.script.is_empty() {
        vec![[0.0, g.inserted_m, 0.0]]
    } else {
        g.script.clone()
    };
    let mut pts = Vec::new();
    let mut gim = Vec::new();
    for r in rows {
        pts.push(Waypoint {
            t_s: r[0],
            position: d.stylus_at(r[1]),
        });
        gim.push(GimbalWaypoint {
            t_s: r[0],
            angles_rad: d.gimbal_for(r[2]),
        });
    }
    (pts, gim)
}

/// Wire ↔ loop shared figures (atomics, f64 as bits).
#[derive(Debug, Default)]
pub struct WireShared {
    axial_bits: AtomicU64,
    inserted_bits: AtomicU64,
    roll_bits: AtomicU64,
    steps: AtomicU64,
    resets: AtomicU64,
    reset_request: AtomicBool,
    /// Stalls the loop saw, and hub commands its ring had no room for.
    stalls: AtomicU64,
    hub_ring_full: AtomicU64,
    /// Largest displacement of an inner-wall vertex under the wire's loads
    /// on the stream (m, bits; the publisher's).
    dent_max_bits: AtomicU64,
}

impl WireShared {
    fn set(a: &AtomicU64, v: f64) {
        a.store(v.to_bits(), Ordering::Release);
    }
    fn get(a: &AtomicU64) -> f64 {
        f64::from_bits(a.load(Ordering::Acquire))
    }
    /// Steps the wire thread has taken.
    pub fn steps(&self) -> u64 {
        self.steps.load(Ordering::Acquire)
    }
    /// Resets so far.
    pub fn resets(&self) -> u64 {
        self.resets.load(Ordering::Acquire)
    }
    /// The inserted length after the last step (m).
    pub fn inserted_m(&self) -> f64 {
        Self::get(&self.inserted_bits)
    }
    /// Takes a reset the loop asked for (true once per request).
    pub(super) fn take_reset_request(&self) -> bool {
        self.reset_request.swap(false, Ordering::AcqRel)
    }
}

/// A hub command (loop → wire).
#[derive(Debug, Clone, Copy)]
pub(super) struct HubMsg {
    inserted_m: f64,
    roll_rad: f64,
}

/// The wall loads of one wire step (wire → loop).
#[derive(Debug, Clone)]
pub(super) struct LoadMsg {
    loads: heapless::Vec<WallLoad, MAX_WALL_LOADS>,
}

/// The wire's polyline, hub to tip (wire → publisher), scene frame (m).
#[derive(Debug, Clone)]
pub(super) struct PolylineMsg {
    points: heapless::Vec<[f32; 3], MAX_POLYLINE>,
    /// The wall loads of the step it was taken at (for the stream's dent).
    loads: heapless::Vec<WallLoad, MAX_WALL_LOADS>,
    /// Largest force of one wire–wall contact (N) over the steps since the
    /// previous polyline (the task metrics' wall force).
    contact_force_max_n: f64,
}

/// The loop's side: the hub drive, the rings to and from the wire thread.
pub(super) struct WireLink {
    drive: HubDrive,
    frame: DeviceFrame,
    hub: rtrb::Producer<HubMsg>,
    loads_in: rtrb::Consumer<LoadMsg>,
    shared: Arc<WireShared>,
    current: heapless::Vec<(u32, Vec3), MAX_WALL_LOADS>,
    last_steps: u64,
    last_progress_s: f64,
    stall_s: f64,
    resets_seen: u64,
    stalled: bool,
    load_wall: bool,
}

impl WireLink {
    /// The wire's contribution to this tick: drive the hub from the hand's
    /// sample (device frame) while the wire is the active instrument, read
    /// the wire's latest axial force and wall loads, and give the hand force
    /// (scene frame; none while another instrument is active: the hub then
    /// holds), the point loads (the reduced model only) and a fault when the
    /// wire thread stalled or reset.
    pub(super) fn contribute(&mut self, hand: &Hand<'_>) -> Contribution<'_> {
        let (sample, now_s) = (hand.sample, hand.now_s);
        let mut fault = false;
        let steps = self.shared.steps();
        if steps != self.last_steps || !self.last_progress_s.is_finite() {
            self.last_steps = steps;
            self.last_progress_s = now_s;
            self.stalled = false;
        } else if now_s - self.last_progress_s > self.stall_s && !self.stalled {
            self.stalled = true;
            self.shared.stalls.fetch_add(1, Ordering::Relaxed);
            self.shared.reset_request.store(true, Ordering::Release);
        }
        let resets = self.shared.resets();
        if resets != self.resets_seen {
            self.resets_seen = resets;
            self.drive.reseat(
                WireShared::get(&self.shared.inserted_bits),
                WireShared::get(&self.shared.roll_bits),
            );
            fault = true;
        }
        fault |= self.stalled;
        let mut latest = None;
        while let Ok(m) = self.loads_in.pop() {
            latest = Some(m);
        }
        if let Some(m) = latest {
            self.current.clear();
            if self.load_wall {
                for l in &m.loads {
                    let _ = self.current.push((l.node, l.force));
                }
            }
        }
        let force = match sample {
            Some(s) if hand.active => {
                if hand.engaged {
                    self.drive.engage(s);
                }
                let cmd = self.drive.command(s, now_s);
                if self
                    .hub
                    .push(HubMsg {
                        inserted_m: cmd.inserted_m,
                        roll_rad: cmd.roll_rad,
                    })
                    .is_err()
                {
                    self.shared.hub_ring_full.fetch_add(1, Ordering::Relaxed);
                }
                let axial = if self.stalled {
                    0.0
                } else {
                    WireShared::get(&self.shared.axial_bits)
                };
                self.frame.force_to_scene(self.drive.hand_force(s, axial))
            }
            _ => Vec3::zeros(),
        };
        Contribution {
            force,
            point_loads: &self.current,
            fault,
            ..Contribution::default()
        }
    }
}

/// What the wire thread needs.
pub(super) struct WirePlan {
    pub wire: Wire,
    pub lumen: Box<TriangleLumen>,
    pub wall: Arc<InnerWall>,
    pub end: RodEnd,
    pub walls: WallEnds,
    pub stop: Arc<AtomicBool>,
    pub faults: Arc<FaultSwitches>,
    pub request: RtRequest,
    pub start: Nanos,
    pub period: Nanos,
    pub pool_bytes: usize,
    pub good_every: u32,
    pub polyline_every: u64,
}

/// What the wire thread returns.
pub(super) struct WireResult {
    pub grant: RtGrant,
    pub step_us: Histogram,
    pub contacts: Histogram,
    pub steps: u64,
    pub resets: u64,
    pub nodes: usize,
    pub inserted_m: f64,
    pub max_inserted_m: f64,
    pub tip: Vec3,
    pub contacts_max: usize,
    pub max_penetration_m: f64,
    pub axial_force_max_n: f64,
    pub iterations_max: usize,
    pub evaluations_max: usize,
    pub budget_spent: u64,
    pub time_spent: u64,
    pub allocations: u64,
    pub wall_updates: u64,
    pub loads_ring_full: u64,
    pub loads_dropped: u64,
    pub wall: Vec<Vec3>,
    /// The rod's inserted polyline at the end (hub to tip).
    pub line: Vec<Vec3>,
    pub load_wall: bool,
    pub compliance_p50: f64,
    pub compliance_max: f64,
    pub deflection_max: f64,
}

/// Builds the rings, the loop's link, the publisher's part and the wire
/// thread's plan.
pub(super) struct WireParts {
    pub link: WireLink,
    pub plan: WirePlan,
    pub publisher: PublisherWire,
}

/// The publisher's part: the inner wall it computes for the wire at the
/// stream rate — the vertices and the lumen's search grid, in one of the
/// twin lumens that circulate publisher → wire → publisher (the wire thread
/// only swaps it in) — and the polyline it streams.
pub(super) struct PublisherWire {
    pub nodes: Vec<u32>,
    pub rest: Vec<Vec3>,
    pub walls_out: rtrb::Producer<Box<TriangleLumen>>,
    pub walls_free: rtrb::Consumer<Box<TriangleLumen>>,
    pub polyline: rtrb::Consumer<PolylineMsg>,
    pub points: Vec<[f32; 3]>,
    /// The vertices being computed, and those last sent.
    pub verts: Vec<Vec3>,
    pub last: Vec<Vec3>,
    /// The twins' running bound on the wall's motion (m).
    pub moved: f64,
    /// A twin whose update failed (non-finite vertices), kept for the next.
    pub spare: Option<Box<TriangleLumen>>,
    /// The residual compliance of contact anywhere (None: the reduced
    /// model alone) and the newest wall loads: the stream shows the wall's
    /// residual dent under the wire too ([`PublisherWire::add_residual_dent`]).
    pub residual: Option<Arc<crate::reduced::compliance::LocalCompliance>>,
    pub loads: Vec<WallLoad>,
    /// Largest wire–wall contact force (N) over the polylines taken by the
    /// last [`PublisherWire::update`].
    pub contact_force_n: f64,
    pub shared: Arc<WireShared>,
    /// See [`WireShared`]'s `dent_max_bits`.
    pub dent_max_m: f64,
}

impl PublisherWire {
    /// Sends the wall at the current state (`position(mesh node, rest)`)
    /// to the wire thread, its grid rebuilt here, if a twin lumen is free;
    /// takes the newest polyline.
    pub(super) fn update(&mut self, position: impl Fn(u32, Vec3) -> Vec3) {
        let free = self.spare.take().or_else(|| self.walls_free.pop().ok());
        if let Some(mut lumen) = free {
            for (k, (&i, &x)) in self.nodes.iter().zip(&self.rest).enumerate() {
                self.verts[k] = position(i, x);
            }
            let step = crate::math::max_distance(&self.verts, &self.last);
            match lumen.update_twin(&self.verts, self.moved + step) {
                Ok(()) => {
                    self.moved += step;
                    self.last.copy_from_slice(&self.verts);
                    // Capacity equals the lumens in circulation: never full.
                    let _ = self.walls_out.push(lumen);
                }
                Err(_) => self.spare = Some(lumen),
            }
        }
        self.contact_force_n = 0.0;
        while let Ok(p) = self.polyline.pop() {
            self.contact_force_n = self.contact_force_n.max(p.contact_force_max_n);
            self.points.clear();
            self.points.extend_from_slice(&p.points);
            self.loads.clear();
            self.loads.extend_from_slice(&p.loads);
        }
    }

    /// Adds to `dent` (one entry per mesh node) the residual compliance's
    /// share of the wall's displacement under the wire's newest loads,
    /// Σ_j ΔW_ij f_j (ΔW_ij = ΔW_jiᵀ, from row j of the table), and lists the
    /// nodes it touched in `touched` (the caller zeroes them again). The
    /// reduced model's share is in δq already; together they are the dent
    /// the wire's contact assumed (its series compliance). Display only.
    pub(super) fn add_residual_dent(&self, dent: &mut [Vec3], touched: &mut Vec<u32>) {
        let Some(table) = self.residual.as_ref() else {
            return;
        };
        for l in &self.loads {
            for (i, block) in table.row(l.node) {
                if let Some(d) = dent.get_mut(i as usize) {
                    if *d == Vec3::zeros() {
                        touched.push(i);
                    }
                    *d += block.tr_mul(&l.force);
                }
            }
        }
    }
}

/// The inner wall the rods touch and its lumen: with `g.load_wall`, the
/// wall's compliance in series with the contact (the lumen without the
/// rods' own dent, docs/WIRE.md).
pub(super) fn wall_and_lumen<const R: usize>(
    g: &GuidewireConfig,
    mesh: &crate::mesh::TetMesh,
    vessel: &crate::haptics::servo::LoopModel<R>,
) -> Result<(InnerWall, TriangleLumen), ServiceError> {
    let wall = InnerWall::from_mesh(mesh, &g.wall_set).map_err(|e| ServiceError::Solver(format!("guidewire: {e}")))?;
    let mut lumen = wall
        .lumen()
        .map_err(|e| ServiceError::Solver(format!("guidewire: {e}")))?;
    if g.load_wall {
        let c = wall
            .normal_compliance(&vessel.dynamics, vessel.compliance.as_deref())
            .ok_or_else(|| ServiceError::Solver("guidewire: the reduced stiffness is singular".into()))?;
        lumen
            .set_compliance(&c)
            .map_err(|e| ServiceError::Solver(format!("guidewire: {e}")))?;
    }
    Ok((wall, lumen))
}

/// One rod's end of its rings in the thread that steps it: the hub
/// commands in, its wall loads and polyline out, the shared figures.
pub(super) struct RodEnd {
    pub hub: rtrb::Consumer<HubMsg>,
    pub loads_out: rtrb::Producer<LoadMsg>,
    pub polyline: rtrb::Producer<PolylineMsg>,
    pub shared: Arc<WireShared>,
    /// The newest wall loads (sized once: pushing clones a fixed vector).
    pub msg: LoadMsg,
    /// The polyline being filled.
    pub poly: PolylineMsg,
}

/// The publisher's rings of the walls it builds for a rod thread: the
/// thread's ends.
pub(super) struct WallEnds {
    pub walls_in: rtrb::Consumer<Box<TriangleLumen>>,
    pub walls_back: rtrb::Producer<Box<TriangleLumen>>,
}

/// The rings and sides of one rod driven by the stylus: its loop side
/// (`drive` from `params`, starting at `inserted_m`, `roll_rad`), its
/// publisher side and its thread's end. With `twins` > 0 the publisher
/// side also builds the wall for the thread (that many twin lumens of
/// `lumen` circulate; [`WallEnds`] returned); a second rod of the same
/// thread takes 0.
#[allow(clippy::too_many_arguments)]
pub(super) fn rod_channels<const R: usize>(
    params: &WireParams,
    inserted_m: f64,
    roll_rad: f64,
    g: &GuidewireConfig,
    wall: &InnerWall,
    lumen: &TriangleLumen,
    vessel: &crate::haptics::servo::LoopModel<R>,
    frame: DeviceFrame,
    twins: usize,
) -> Result<(WireLink, PublisherWire, RodEnd, WallEnds), ServiceError> {
    let drive = HubDrive::new(params, inserted_m, roll_rad)?;
    let shared = Arc::new(WireShared::default());
    WireShared::set(&shared.inserted_bits, inserted_m);
    WireShared::set(&shared.roll_bits, roll_rad);
    let (hub_tx, hub_rx) = rtrb::RingBuffer::<HubMsg>::new(HUB_RING);
    let (loads_tx, loads_rx) = rtrb::RingBuffer::<LoadMsg>::new(4);
    let (walls_tx, walls_rx) = rtrb::RingBuffer::<Box<TriangleLumen>>::new(twins.max(1));
    let (mut free_tx, free_rx) = rtrb::RingBuffer::<Box<TriangleLumen>>::new(twins.max(1));
    let (poly_tx, poly_rx) = rtrb::RingBuffer::<PolylineMsg>::new(4);
    // Twin lumens circulate publisher → thread → publisher: the publisher
    // rebuilds their grids, the thread swaps them in.
    for _ in 0..twins {
        let _ = free_tx.push(Box::new(lumen.twin()));
    }
    let publisher = PublisherWire {
        nodes: wall.mesh_nodes().to_vec(),
        rest: wall.rest().to_vec(),
        walls_out: walls_tx,
        walls_free: free_rx,
        polyline: poly_rx,
        points: Vec::with_capacity(MAX_POLYLINE),
        verts: wall.rest().to_vec(),
        last: lumen.vertices().to_vec(),
        moved: lumen.moved(),
        spare: None,
        residual: if g.load_wall { vessel.compliance.clone() } else { None },
        loads: Vec::with_capacity(MAX_WALL_LOADS),
        contact_force_n: 0.0,
        shared: shared.clone(),
        dent_max_m: 0.0,
    };
    let link = WireLink {
        drive,
        frame,
        hub: hub_tx,
        loads_in: loads_rx,
        shared: shared.clone(),
        current: heapless::Vec::new(),
        last_steps: 0,
        last_progress_s: f64::NAN,
        stall_s: g.stall_ms * 1e-3,
        resets_seen: 0,
        stalled: false,
        load_wall: g.load_wall,
    };
    let end = RodEnd {
        hub: hub_rx,
        loads_out: loads_tx,
        polyline: poly_tx,
        shared,
        msg: LoadMsg {
            loads: heapless::Vec::new(),
        },
        poly: PolylineMsg {
            points: heapless::Vec::new(),
            loads: heapless::Vec::new(),
            contact_force_max_n: 0.0,
        },
    };
    let walls = WallEnds {
        walls_in: walls_rx,
        walls_back: free_tx,
    };
    Ok((link, publisher, end, walls))
}

/// The thread's request from `[guidewire]`: its priority and CPU.
pub(super) fn rt_request(g: &GuidewireConfig) -> RtRequest {
    RtRequest {
        fifo_priority: (g.priority > 0).then_some(g.priority),
        cpu: (g.cpu >= 0).then_some(g.cpu as usize),
        prefault_stack_bytes: 256 * 1024,
    }
}

/// Everything the service needs to run the wire, built before the threads
/// start.
#[allow(clippy::too_many_arguments)]
pub(super) fn build<const R: usize>(
    params: &WireParams,
    g: &GuidewireConfig,
    mesh: &crate::mesh::TetMesh,
    vessel: &crate::haptics::servo::LoopModel<R>,
    frame: DeviceFrame,
    stop: Arc<AtomicBool>,
    faults: Arc<FaultSwitches>,
    start: Nanos,
    stream_every: u64,
) -> Result<WireParts, ServiceError> {
    let (wall, lumen) = wall_and_lumen(g, mesh, vessel)?;
    let (access_point, axis) = g
        .hub_pose(mesh, &wall, &lumen)
        .map_err(|e| ServiceError::Solver(format!("guidewire.access: {e}")))?;
    let wire = Wire::new(params, access_point, axis, g.inserted_m)
        .map_err(|e| ServiceError::Solver(format!("guidewire: {e}")))?;
    let (link, publisher, end, walls) =
        rod_channels(params, wire.inserted(), wire.roll(), g, &wall, &lumen, vessel, frame, 3)?;
    let plan = WirePlan {
        wire,
        lumen: Box::new(lumen),
        wall: Arc::new(wall),
        end,
        walls,
        stop,
        faults,
        request: rt_request(g),
        start,
        period: (params.dt_s * 1e9).round() as Nanos,
        pool_bytes: crate::service::running::RT_POOL_BYTES,
        good_every: g.good_state_every,
        polyline_every: stream_every.max(1),
    };
    Ok(WireParts { link, plan, publisher })
}

impl LoopSide for WireLink {
    fn contribute(&mut self, hand: &Hand<'_>) -> Contribution<'_> {
        WireLink::contribute(self, hand)
    }

    fn hub_driven(&self) -> bool {
        true
    }
}

impl PublisherSide for PublisherWire {
    fn update(&mut self, view: &VesselView<'_>) {
        PublisherWire::update(self, view.without_point_loads);
        if view.point_loads_active {
            for &i in &self.nodes {
                self.dent_max_m = self.dent_max_m.max((view.point_load_dent)(i).norm());
            }
            WireShared::set(&self.shared.dent_max_bits, self.dent_max_m);
        }
    }

    fn add_dent(&self, dent: &mut [Vec3], touched: &mut Vec<u32>) {
        self.add_residual_dent(dent, touched);
    }

    fn polyline(&self) -> &[[f32; 3]] {
        &self.points
    }

    fn wall_force_n(&self) -> f64 {
        self.contact_force_n
    }
}

/// The guidewire's instrument when the configuration has `[wire]` and
/// `[guidewire]` (and no `[catheter]`: then the wire runs inside the
/// catheter, in the catheter's thread, [`super::catheter`]): the rings, the
/// loop and publisher sides, and the wire thread, started half a period
/// after the loop.
pub fn build_instrument<const R: usize>(ctx: &BuildContext<'_, R>) -> Result<Vec<Built>, ServiceError> {
    let (Some(wp), Some(g), None) = (&ctx.cfg.wire, &ctx.cfg.guidewire, &ctx.cfg.catheter) else {
        return Ok(Vec::new());
    };
    let parts = build(
        wp,
        g,
        ctx.mesh,
        ctx.vessel,
        device_frame(ctx),
        ctx.stop.clone(),
        ctx.faults.clone(),
        ctx.loop_start + WIRE_PHASE,
        ctx.state_every,
    )?;
    let wall = parts.plan.wall.clone();
    let shared = parts.plan.end.shared.clone();
    let plan = parts.plan;
    let handle = std::thread::Builder::new()
        .name("nvtmm-wire".into())
        .stack_size(1 << 20)
        .spawn(move || wire_thread(plan))
        .map_err(|e| ServiceError::Thread("wire", e.to_string()))?;
    Ok(vec![Built {
        id: "guidewire",
        kind: KIND,
        loop_side: Box::new(parts.link),
        publisher_side: Box::new(parts.publisher),
        service_side: Box::new(GuidewireService {
            handle: Some(handle),
            wall,
            shared,
        }),
    }])
}

/// The device frame of the configuration (identity without `[device.frame]`).
pub(super) fn device_frame<const R: usize>(ctx: &BuildContext<'_, R>) -> DeviceFrame {
    ctx.cfg
        .device
        .frame
        .as_ref()
        .map(DeviceFrame::new)
        .unwrap_or_else(DeviceFrame::identity)
}

/// The guidewire's part the running service keeps: the wire thread.
struct GuidewireService {
    handle: Option<std::thread::JoinHandle<WireResult>>,
    wall: Arc<InnerWall>,
    shared: Arc<WireShared>,
}

impl ServiceSide for GuidewireService {
    fn finish(&mut self, report: &mut Report) -> Result<InstrumentReport, ServiceError> {
        let h = self
            .handle
            .take()
            .ok_or_else(|| ServiceError::Thread("wire", "already stopped".into()))?;
        let w = h.join().map_err(|_| ServiceError::Thread("wire", "panicked".into()))?;
        let (wr, out) = rod_report("guidewire", KIND, &w, &self.wall, &self.shared);
        report.allocations_after_start += wr.allocations_after_start;
        report.wire = Some(wr);
        Ok(out)
    }
}

/// A rod's report section from its thread's result: its `wire.*`-shaped
/// figures and its instrument section (`id`, `kind`, those figures as its
/// keys with `hub_ring_full`).
pub(super) fn rod_report(
    id: &str,
    kind: Kind,
    w: &WireResult,
    wall: &InnerWall,
    shared: &WireShared,
) -> (WireReport, InstrumentReport) {
    let (tip_segment, tip_depth_m) = tip_segment_and_depth(wall, &w.wall, &w.line);
    let wr = WireReport {
        nodes: w.nodes,
        inserted_m: w.inserted_m,
        inserted_max_m: w.max_inserted_m,
        tip_segment,
        tip_depth_m,
        tip_m: [w.tip.x, w.tip.y, w.tip.z],
        contacts_max: w.contacts_max,
        contacts_p50: w.contacts.quantile(0.5),
        max_penetration_m: w.max_penetration_m,
        axial_force_max_n: w.axial_force_max_n,
        step_us: w.step_us.percentiles(),
        steps: w.steps,
        iterations_max: w.iterations_max,
        evaluations_max: w.evaluations_max,
        budget_spent_steps: w.budget_spent,
        time_limited_steps: w.time_spent,
        resets: w.resets,
        stalls: shared.stalls.load(Ordering::Acquire),
        wall_updates: w.wall_updates,
        rt_policy_granted: w.grant.fifo,
        cpu: w.grant.cpu,
        allocations_after_start: w.allocations,
        loads_ring_full: w.loads_ring_full,
        load_wall: w.load_wall,
        wall_compliance_p50_m_per_n: w.compliance_p50,
        wall_compliance_max_m_per_n: w.compliance_max,
        wall_deflection_max_m: w.deflection_max,
        wall_dent_max_m: WireShared::get(&shared.dent_max_bits),
    };
    let mut keys = serde_json::to_value(&wr).unwrap_or_default();
    if let Some(k) = keys.as_object_mut() {
        // Hub commands the loop could not send (ring of `HUB_RING`).
        k.insert(
            "hub_ring_full".into(),
            shared.hub_ring_full.load(Ordering::Acquire).into(),
        );
    }
    let out = InstrumentReport {
        id: id.into(),
        kind: kind.name.into(),
        faults: wr.resets + wr.stalls,
        keys,
        summary: format!(
            "{:.1} mm inserted, tip {:.1} mm into {}, {} resets, {} stalls",
            wr.inserted_m * 1e3,
            wr.tip_depth_m * 1e3,
            wr.tip_segment,
            wr.resets,
            wr.stalls
        ),
    };
    (wr, out)
}

/// The segment of the wall nearest the rod's tip (`line`, hub to tip; the
/// wall at `positions`) and how far the rod runs in it back from the tip
/// (m, along the rod, up to the first node nearer another segment):
/// "unlabelled" and 0 on a mesh without labels or an empty line.
pub(super) fn tip_segment_and_depth(wall: &InnerWall, positions: &[Vec3], line: &[Vec3]) -> (String, f64) {
    let Some(&tip) = line.last() else {
        return ("unlabelled".into(), 0.0);
    };
    let Some(seg) = wall.segment_at(positions, tip) else {
        return ("unlabelled".into(), 0.0);
    };
    let mut depth = 0.0;
    for w in line.windows(2).rev() {
        if wall.segment_at(positions, w[0]) != Some(seg) {
            break;
        }
        depth += (w[1] - w[0]).norm();
    }
    (seg.to_string(), depth)
}

/// Capacity of the hub ring (loop → wire thread).
const HUB_RING: usize = 64;

impl WireResult {
    /// The figures before the first step of a rod thread that got `grant`,
    /// for `wire` against `lumen`.
    pub(super) fn start(grant: RtGrant, wire: &Wire, lumen: &TriangleLumen) -> WireResult {
        let mut res = WireResult {
            grant,
            step_us: Histogram::new(),
            contacts: Histogram::new(),
            steps: 0,
            resets: 0,
            nodes: wire.num_nodes(),
            inserted_m: wire.inserted(),
            max_inserted_m: wire.inserted(),
            tip: wire.tip(),
            contacts_max: 0,
            max_penetration_m: 0.0,
            axial_force_max_n: 0.0,
            iterations_max: 0,
            evaluations_max: 0,
            budget_spent: 0,
            time_spent: 0,
            allocations: 0,
            wall_updates: 0,
            loads_ring_full: 0,
            loads_dropped: 0,
            wall: Vec::new(),
            line: Vec::new(),
            load_wall: !lumen.compliance().is_empty(),
            compliance_p50: 0.0,
            compliance_max: 0.0,
            deflection_max: 0.0,
        };
        let mut c = lumen.compliance().to_vec();
        c.sort_by(f64::total_cmp);
        if let (Some(mid), Some(max)) = (c.get(c.len() / 2), c.last()) {
            res.compliance_p50 = *mid;
            res.compliance_max = *max;
        }
        res
    }

    /// Counts a good step `rep` of `wire` (its contacts, forces and
    /// effort), the largest contact force into `end`'s polyline, publishes
    /// its axial force and sends its wall loads (`wall`, `lumen`).
    pub(super) fn good_step(
        &mut self,
        rep: &crate::wire::StepReport,
        wire: &Wire,
        end: &mut RodEnd,
        wall: &InnerWall,
        lumen: &TriangleLumen,
    ) {
        self.contacts.record(rep.contacts as f64);
        self.contacts_max = self.contacts_max.max(rep.contacts);
        self.max_penetration_m = self.max_penetration_m.max(rep.max_penetration_m);
        self.axial_force_max_n = self.axial_force_max_n.max(rep.hub_axial_force_n.abs());
        for c in wire.contacts() {
            self.deflection_max = self.deflection_max.max(c.wall_deflection);
            let f = (c.normal * c.normal_force + c.friction).norm();
            if f.is_finite() {
                end.poly.contact_force_max_n = end.poly.contact_force_max_n.max(f);
            }
        }
        self.iterations_max = self.iterations_max.max(rep.iterations);
        self.evaluations_max = self.evaluations_max.max(rep.evaluations);
        self.budget_spent += rep.budget_spent as u64;
        self.time_spent += rep.time_spent as u64;
        WireShared::set(&end.shared.axial_bits, rep.hub_axial_force_n);
        self.loads_dropped += wall_loads(wall, lumen, wire.contacts(), &mut end.msg.loads) as u64;
        if end.loads_out.push(end.msg.clone()).is_err() {
            self.loads_ring_full += 1;
        }
    }

    /// After the step (good or not, `good`): publishes `wire`'s hub state
    /// and the step count, and every `polyline_every` steps its polyline.
    pub(super) fn after_step(&mut self, wire: &Wire, end: &mut RodEnd, good: bool, polyline_every: u64) {
        if !good {
            WireShared::set(&end.shared.axial_bits, 0.0);
            end.msg.loads.clear();
            let _ = end.loads_out.push(end.msg.clone());
        }
        WireShared::set(&end.shared.inserted_bits, wire.inserted());
        WireShared::set(&end.shared.roll_bits, wire.roll());
        if !good {
            end.shared.resets.fetch_add(1, Ordering::AcqRel);
        }
        end.shared.steps.fetch_add(1, Ordering::AcqRel);
        self.inserted_m = wire.inserted();
        self.max_inserted_m = self.max_inserted_m.max(self.inserted_m);
        if self.steps % polyline_every == 0 {
            let line = wire.inserted_polyline();
            let stride = line.len().div_ceil(MAX_POLYLINE - 1).max(1);
            end.poly.points.clear();
            for (k, x) in line.iter().enumerate() {
                if k % stride == 0 || k + 1 == line.len() {
                    let _ = end.poly.points.push([x.x as f32, x.y as f32, x.z as f32]);
                }
            }
            end.poly.loads.clone_from(&end.msg.loads);
            let _ = end.polyline.push(end.poly.clone());
            end.poly.contact_force_max_n = 0.0;
        }
    }

    /// At the thread's end (outside the RT section: allocates): the rod's
    /// final figures.
    pub(super) fn finish(&mut self, wire: &Wire, end: &RodEnd, lumen: &TriangleLumen) {
        self.nodes = wire.num_nodes();
        self.tip = wire.tip();
        self.resets = end.shared.resets();
        self.wall = lumen.vertices().to_vec();
        self.line = wire.inserted_polyline().to_vec();
    }
}

/// The newest hub command in `hub`, if any arrived.
pub(super) fn newest_hub(hub: &mut rtrb::Consumer<HubMsg>) -> Option<(f64, f64)> {
    let mut cmd = None;
    while let Ok(c) = hub.pop() {
        cmd = Some((c.inserted_m, c.roll_rad));
    }
    cmd
}

/// Swaps the newest wall the publisher built into `lumen`; the older ones
/// go back. True if one came.
pub(super) fn take_newest_wall(walls: &mut WallEnds, lumen: &mut Box<TriangleLumen>) -> bool {
    let mut wall = None;
    while let Ok(w) = walls.walls_in.pop() {
        if let Some(old) = wall.replace(w) {
            let _ = walls.walls_back.push(old);
        }
    }
    match wall {
        Some(w) => {
            let old = std::mem::replace(lumen, w);
            let _ = walls.walls_back.push(old);
            true
        }
        None => false,
    }
}

/// Sleeps until the next period, after an injected stall if one is asked.
pub(super) fn wait_period(next: &mut Nanos, period: Nanos, faults: &FaultSwitches) {
    clock::sleep_until(*next);
    *next += period;
    let stall = faults.stall_wire_ms.swap(0, Ordering::Relaxed);
    if stall > 0 {
        std::thread::sleep(std::time::Duration::from_millis(stall));
    }
}

/// Re-phases after an overrun instead of bursting.
pub(super) fn rephase(next: &mut Nanos, period: Nanos) {
    let now = clock::now_ns();
    if now > *next {
        *next += ((now - *next) / period + 1) * period;
    }
}

/// The wire thread's body: one wire step per period until `stop`.
pub(super) fn wire_thread(mut p: WirePlan) -> WireResult {
    let grant = setup_current(&p.request);
    let mut res = WireResult::start(grant, &p.wire, &p.lumen);
    let _pool = crate::rt::alloc::enter_rt(p.pool_bytes);
    let radius = 0.5 * p.wire.params().diameter_m;
    let diameter = 2.0 * radius;
    let sys0 = crate::rt::alloc::thread_system_calls();
    let mut next = p.start;
    let mut since_good = 0u32;
    while !p.stop.load(Ordering::Relaxed) {
        wait_period(&mut next, p.period, &p.faults);
        if let Some((ins, roll)) = newest_hub(&mut p.end.hub) {
            p.wire.set_hub(ins, roll);
        }
        if take_newest_wall(&mut p.walls, &mut p.lumen) {
            res.wall_updates += 1;
        }
        if FaultSwitches::take(&p.faults.poison_wire) {
            p.wire.poison_for_tests();
        }
        let t0 = clock::now_ns();
        let step = p.wire.step(&*p.lumen);
        res.step_us.record((clock::now_ns() - t0) as f64 * 1e-3);
        res.steps += 1;
        let reset_asked = p.end.shared.take_reset_request();
        let good = match step {
            Ok(rep) if rep.max_penetration_m <= diameter && !reset_asked => {
                res.good_step(&rep, &p.wire, &mut p.end, &p.wall, &p.lumen);
                since_good += 1;
                if since_good >= p.good_every && rep.max_penetration_m < 0.5 * radius {
                    p.wire.save_good_state();
                    since_good = 0;
                }
                true
            }
            _ => false,
        };
        if !good {
            p.wire.restore_good_state();
            since_good = 0;
        }
        res.after_step(&p.wire, &mut p.end, good, p.polyline_every);
        rephase(&mut next, p.period);
    }
    res.allocations = crate::rt::alloc::thread_system_calls() - sys0;
    crate::rt::alloc::leave_rt();
    res.finish(&p.wire, &p.end, &p.lumen);
    res
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_script_is_linear_between_rows_and_held_outside() {
        let mut g = GuidewireConfig {
            script: vec![],
            ..GuidewireConfig::default()
        };
        assert_eq!(g.script_at(3.0), (g.inserted_m, 0.0));
        g.script = vec![[1.0, 0.10, 0.0], [3.0, 0.20, 1.0]];
        assert_eq!(g.script_at(0.0), (0.10, 0.0));
        let (ins, roll) = g.script_at(2.0);
        assert!((ins - 0.15).abs() < 1e-12 && (roll - 0.5).abs() < 1e-12);
        assert_eq!(g.script_at(9.0), (0.20, 1.0));
    }
}
