//! The discrete elastic rod (after Bergou et al., *Discrete Elastic Rods*,
//! 2008 and *Discrete Viscous Threads*, 2010): nodes on the centreline, one
//! twist angle per edge measured from a reference frame carried along by
//! parallel transport in time. Energies per edge (stretch) and per interior
//! node (bend, twist); an implicit step minimising the incremental potential
//! with Newton iterations on a banded Hessian, a line search on the energy
//! and a cap on how far a node moves per iteration (no tunnelling).
//!
//! Layout: node 0 is a ghost behind the access point, node 1 the hub at the
//! access point (both fixed: together they clamp the wire along the
//! insertion axis), nodes 2… run to the tip (the last node). Edge j joins
//! nodes j and j + 1; edge 0 (ghost–hub) carries the hub's roll. The material
//! coordinate of a node is its arc length from the tip, so the pre-shaped
//! tip stays with the material as nodes enter and leave at the hub.

use super::band::BandMatrix;
use super::lumen::{perpendicular, Lumen, ProbeCache, WallHit, WallOverlap, WallOverlaps, NO_TRIANGLE, OPENING_TAG};
use super::WireParams;
use crate::config::ConfigError;
use crate::math::{Mat3, Vec3};
use crate::rt::reserved::Reserved;
use std::path::Path;

/// Half-bandwidth of the Hessian: a node's bend/twist stencil spans
/// x_{i−1}, θ_{i−1}, x_i, θ_i, x_{i+1}, i.e. 11 consecutive unknowns.
const BAND: usize = 10;

/// Errors building a wire.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum WireError {
    /// A configuration value is out of range.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// The access point or the insertion axis is unusable.
    #[error("hub: {0}")]
    Hub(&'static str),
}

/// Why a step failed (the state is then unusable: restore the last good one).
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum WireFault {
    /// A position or twist became NaN or infinite.
    #[error("the wire state is not finite")]
    NonFinite,
}

/// One wire–wall contact after a step. The force on the wall is the
/// opposite of the force on the wire: −(normal_force · normal + friction).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WireContact {
    /// Node index (1 is the hub, the last node the tip).
    pub node: usize,
    /// The nearest wall point (m).
    pub point: Vec3,
    /// Wall normal into the lumen.
    pub normal: Vec3,
    /// Normal force of the wall on the wire (N, ≥ 0, along `normal`).
    pub normal_force: f64,
    /// Friction force of the wall on the wire (N, tangent to the wall).
    pub friction: Vec3,
    /// How far the wire's surface is beyond the wall as the contact pushes
    /// it (m, ≥ 0): the penalty's share, normal_force / contact stiffness.
    pub penetration: f64,
    /// How far the contact pushes a compliant wall back (m, ≥ 0): its
    /// normal compliance times the normal force; 0 against a rigid wall.
    pub wall_deflection: f64,
    /// The wall triangle touched ([`super::lumen::WallHit::triangle`]).
    pub triangle: u32,
}

/// What a step did.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct StepReport {
    /// Newton iterations taken.
    pub iterations: usize,
    /// Contacts after the step.
    pub contacts: usize,
    /// Deepest penetration of the wire's surface into the wall (m).
    pub max_penetration_m: f64,
    /// Axial force the wire exerts on the hand (N), positive when it resists
    /// insertion (pushes the hand back).
    pub hub_axial_force_n: f64,
    /// Roll torque the wire exerts on the hand about the axis (N·m).
    pub hub_torque_nm: f64,
    /// Largest remaining Newton update (m or rad) at the end.
    pub last_update: f64,
    /// The wire slipped in the grip: the hub force reached
    /// `max_hub_force_n` and the inserted length fell back to what the wire
    /// took.
    pub grip_slipped: bool,
    /// Newton residual at the end of the step: the largest net force on a
    /// free node (N), i.e. the norm of the incremental potential's gradient
    /// there. Zero when the step's minimisation converged.
    pub residual_n: f64,
    /// Material fed in (positive) or withdrawn at the hub this step (m).
    pub fed_m: f64,
    /// Evaluations of the incremental potential this step (Newton
    /// iterations' assemblies plus line-search trials plus the final
    /// reactions'): what the step's cost scales with; at most the wire's
    /// `max_evaluations`.
    pub evaluations: usize,
    /// The step stopped because its evaluation budget (`max_evaluations`)
    /// was spent, not because it converged or ran its iterations.
    pub budget_spent: bool,
    /// The step stopped going on past `newton_iterations` because it had
    /// run `residual_time_limit_us`, off equilibrium by more than
    /// `residual_tolerance_n`.
    pub time_spent: bool,
    /// Contacts with the sheath's inner wall after the step (a wire inside
    /// a catheter, [`Wire::set_sheath`]); not counted in `contacts`.
    pub sheath_contacts: usize,
    /// Deepest penetration of the rod's surface into the sheath's inner
    /// wall (m).
    pub max_sheath_penetration_m: f64,
    /// The step began on a saddle of the wire's static energy (a column
    /// past its buckling load) and moved off it along a direction of
    /// negative curvature (docs/WIRE.md "Buckling").
    pub buckled: bool,
    /// The step's buckling check factored the static Hessian (the wire
    /// had settled in the last step, pushed, with a compressed, nearly
    /// unbent edge): what the check costs, in how many steps.
    pub buckling_checked: bool,
}

/// The coaxial terms of a rod (docs/CATHETER.md): the sheath it may run
/// inside (the rod is a wire in a catheter), and the loads and stiffness
/// of a core running inside it (the rod is the catheter). Every buffer is
/// sized at construction.
#[derive(Debug, Clone)]
struct Coax {
    /// The sheath's centreline, its ghost node first (empty: no sheath).
    sheath: Reserved<Vec3>,
    /// Its nodes' velocities (m/s): friction's slip is measured against
    /// the sheath's motion.
    sheath_v: Reserved<Vec3>,
    /// Nodes whose arc length from the hub is at most this are inside the
    /// sheath (m): the sheath's inserted length.
    sheath_reach: f64,
    /// The sheath's inner radius (m).
    sheath_radius: f64,
    /// Coulomb friction against the sheath's inner wall.
    sheath_mu: f64,
    /// Per node: the sheath segment nearest at the last probe (a hint).
    sheath_seg: Vec<usize>,
    /// Per node, fixed through a step: inside the sheath (it touches the
    /// sheath's inner wall, not the lumen's).
    inside: Vec<bool>,
    /// Per node inside the sheath: the radius of its lip's funnel (m),
    /// at least the sheath's inner radius. A node that comes inside by its
    /// arc length while it lies outside the lumen (a J-tip beside the
    /// sheath's tip, a node pulled back in) starts with the funnel wide
    /// enough that it does not overlap the wall; the funnel closes as the
    /// node comes in, and by [`FUNNEL_CLOSING_M_PER_S`] at least.
    funnel: Vec<f64>,
    /// The sheath contacts of the last step.
    sheath_contacts: Reserved<WireContact>,
    /// Dead point loads for the next step (point, force), spread onto the
    /// nearest segment's two nodes when the step begins.
    point_loads: Reserved<(Vec3, Vec3)>,
    /// Per node: the dead load of this step (N).
    node_load: Vec<Vec3>,
    /// Stiffness (N/m) with which each point load resists this rod's
    /// motion over the step along its own direction (0: dead loads only).
    load_stiffness: f64,
    /// Per node: that stiffness's share, k n nᵀ summed (N/m).
    node_spring: Vec<Mat3>,
    /// The core's bending stiffness along this rod, if a core runs inside.
    core: Option<CoreStiffness>,
    /// Per node: the curvature binormal at the step's start, from which
    /// the core's stiffness term measures the change.
    kb0: Vec<Vec3>,
}

/// A core's bending stiffness as a rod sees it: the core's inserted
/// length from the same hub and its stiffness by its own material
/// coordinate.
#[derive(Debug, Clone, Copy, PartialEq)]
struct CoreStiffness {
    reach: f64,
    ei: f64,
    mass_per_m: f64,
    tip_length: f64,
    tip_factor: f64,
}

/// Point loads a rod takes at most per step ([`Wire::set_point_loads`]).
pub const MAX_POINT_LOADS: usize = 4096;

/// How fast a sheath's lip funnel closes on a node that entered it
/// outside the lumen, at least (m/s): at the rod's contact stiffness
/// (10⁶ N/m, 1 ms steps) a force of 2 N per step at most.
pub const FUNNEL_CLOSING_M_PER_S: f64 = 2e-3;

/// The point of the polyline `poly` (at least two points) nearest to `p`
/// over all its segments (the same ends as [`nearest_on_polyline`]): for a
/// node with no good hint, since a downhill search from a far segment
/// stops at a local minimum (the other leg of a sheath bent back on
/// itself).
pub(crate) fn nearest_on_polyline_everywhere(poly: &[Vec3], p: Vec3, seg: &mut usize) -> (usize, f64, Vec3) {
    let mut best = (0, 0.0, poly[0]);
    let mut d_best = f64::INFINITY;
    for k in 0..poly.len() - 1 {
        let (t, q, d) = nearest_on_segment(poly, k, p);
        if d < d_best {
            d_best = d;
            best = (k, t, q);
        }
    }
    *seg = best.0;
    best
}

/// The point of segment `k` of `poly` nearest to `p`: its parameter t, the
/// point and the squared distance (t unclamped behind the first segment's
/// start and beyond the last one's end).
fn nearest_on_segment(poly: &[Vec3], k: usize, p: Vec3) -> (f64, Vec3, f64) {
    let last = poly.len() - 2;
    let (a, b) = (poly[k], poly[k + 1]);
    let e = b - a;
    let l2 = e.norm_squared().max(1e-300);
    let mut t = (p - a).dot(&e) / l2;
    if k > 0 {
        t = t.max(0.0);
    }
    if k < last {
        t = t.min(1.0);
    }
    let q = a + e * t;
    (t, q, (p - q).norm_squared())
}

/// Sheath nodes at most ([`Wire::set_sheath`]).
pub const MAX_SHEATH_NODES: usize = 4096;

impl Coax {
    fn new(cap: usize) -> Coax {
        Coax {
            sheath: Reserved::with_capacity(MAX_SHEATH_NODES),
            sheath_v: Reserved::with_capacity(MAX_SHEATH_NODES),
            sheath_reach: 0.0,
            sheath_radius: 0.0,
            sheath_mu: 0.0,
            sheath_seg: vec![0; cap],
            inside: vec![false; cap],
            funnel: vec![0.0; cap],
            sheath_contacts: Reserved::with_capacity(cap),
            point_loads: Reserved::with_capacity(MAX_POINT_LOADS),
            node_load: vec![Vec3::zeros(); cap],
            load_stiffness: 0.0,
            node_spring: vec![Mat3::zeros(); cap],
            core: None,
            kb0: vec![Vec3::zeros(); cap],
        }
    }

    /// Moves the per-node state of nodes 2..`n` up by one with the nodes
    /// when [`Wire::feed`] puts a node in at 2. The new node 2 has none: it
    /// enters the sheath afresh (searched for, through the funnel) if it
    /// lies inside. Left unmoved, the node at the sheath's tip took its
    /// outer neighbour's state and entered anew each time a node was fed
    /// in: its friction started afresh.
    fn shift_nodes_up(&mut self, n: usize) {
        self.inside[2..=n].rotate_right(1);
        self.funnel[2..=n].rotate_right(1);
        self.sheath_seg[2..=n].rotate_right(1);
        self.inside[2] = false;
        self.funnel[2] = self.sheath_radius;
    }

    /// [`Coax::shift_nodes_up`]'s inverse, when [`Wire::feed`] takes node 2
    /// out of `n` nodes.
    fn shift_nodes_down(&mut self, n: usize) {
        self.inside[2..n].rotate_left(1);
        self.funnel[2..n].rotate_left(1);
        self.sheath_seg[2..n].rotate_left(1);
    }

    /// Forgets which nodes are inside the sheath, so that each one inside
    /// at the next step enters afresh where it lies (the whole sheath
    /// searched, through the lip's funnel). After a return to the last good
    /// state the flags and funnels are the failed step's, not that state's:
    /// a node flagged inside but lying outside the lumen then started deep
    /// in the sheath's wall, the step failed again, and the service's pair
    /// reset thousands of times in a row.
    fn forget_inside(&mut self) {
        for f in &mut self.inside {
            *f = false;
        }
    }
}

/// The point of the polyline `poly` (at least two points) nearest to `p`,
/// searched downhill from segment `*seg` (updated): its segment, the
/// parameter t along it and the point. The first segment runs on behind
/// its start and the last beyond its end (t unclamped there): a sheath's
/// lumen goes on straight past its tip and behind its hub.
pub(crate) fn nearest_on_polyline(poly: &[Vec3], p: Vec3, seg: &mut usize) -> (usize, f64, Vec3) {
    let m = poly.len();
    let last = m - 2;
    let at = |k: usize| nearest_on_segment(poly, k, p);
    let mut k = (*seg).min(last);
    let mut best = at(k);
    for _ in 0..m {
        let mut moved = false;
        if k > 0 {
            let c = at(k - 1);
            if c.2 < best.2 {
                k -= 1;
                best = c;
                moved = true;
            }
        }
        if !moved && k < last {
            let c = at(k + 1);
            if c.2 < best.2 {
                k += 1;
                best = c;
                moved = true;
            }
        }
        if !moved {
            break;
        }
    }
    *seg = k;
    (k, best.0, best.1)
}

/// The state that [`Wire::save_good_state`] keeps.
#[derive(Debug, Clone)]
struct State {
    n: usize,
    x: Vec<Vec3>,
    v: Vec<Vec3>,
    theta: Vec<f64>,
    d1: Vec<Vec3>,
    ref_twist: Vec<f64>,
    u: Vec<f64>,
    rest: Vec<f64>,
    lam: Vec<f64>,
    /// The wall normal of each node's contact in the last step (lagged with
    /// `lam`): friction's tangent plane.
    nrm: Vec<Vec3>,
    /// The wall's normal compliance at each node's contact in the last step
    /// (m/N; negative where the node had none): the contact's series
    /// compliance through this step (docs/WIRE.md "The wall's compliance
    /// held through a step").
    comp: Vec<f64>,
    /// Each node's stick anchor: where friction's slip is measured from
    /// (docs/WIRE.md "Friction that holds and turns"). It stays put while
    /// the contact sticks and trails the node by the smoothing length
    /// once it slips, so a load below μλ holds still instead of creeping.
    anchor: Vec<Vec3>,
    /// The twist of the edge at each node's contact when its anchor was
    /// set (rad): the spin's share of the slip is measured from it.
    anchor_twist: Vec<f64>,
    inserted: f64,
    roll: f64,
}

impl State {
    fn new(cap: usize) -> State {
        State {
            n: 0,
            x: vec![Vec3::zeros(); cap],
            v: vec![Vec3::zeros(); cap],
            theta: vec![0.0; cap],
            d1: vec![Vec3::zeros(); cap],
            ref_twist: vec![0.0; cap],
            u: vec![0.0; cap],
            rest: vec![0.0; cap],
            lam: vec![0.0; cap],
            nrm: vec![Vec3::zeros(); cap],
            comp: vec![-1.0; cap],
            anchor: vec![Vec3::zeros(); cap],
            anchor_twist: vec![0.0; cap],
            inserted: 0.0,
            roll: 0.0,
        }
    }

    fn copy_from(&mut self, o: &State) {
        self.n = o.n;
        self.x.copy_from_slice(&o.x);
        self.v.copy_from_slice(&o.v);
        self.theta.copy_from_slice(&o.theta);
        self.d1.copy_from_slice(&o.d1);
        self.ref_twist.copy_from_slice(&o.ref_twist);
        self.u.copy_from_slice(&o.u);
        self.rest.copy_from_slice(&o.rest);
        self.lam.copy_from_slice(&o.lam);
        self.nrm.copy_from_slice(&o.nrm);
        self.comp.copy_from_slice(&o.comp);
        self.anchor.copy_from_slice(&o.anchor);
        self.anchor_twist.copy_from_slice(&o.anchor_twist);
        self.inserted = o.inserted;
        self.roll = o.roll;
    }

    fn is_finite(&self) -> bool {
        let n = self.n;
        self.x[..n].iter().all(|p| p.iter().all(|c| c.is_finite()))
            && self.theta[..n].iter().all(|t| t.is_finite())
            && self.v[..n].iter().all(|p| p.iter().all(|c| c.is_finite()))
    }
}

/// The guidewire. Build with [`Wire::new`], drive with [`Wire::set_hub`],
/// advance with [`Wire::step`].
#[derive(Debug, Clone)]
pub struct Wire {
    p: WireParams,
    cap: usize,
    hub: Vec3,
    axis: Vec3,
    d1_hub: Vec3,
    target: f64,
    max_inserted: f64,
    tip_load: Vec3,
    line_load: Vec3,
    s: State,
    good: State,
    // Step-start copies.
    x0: Vec<Vec3>,
    th0: Vec<f64>,
    d10: Vec<Vec3>,
    t0: Vec<Vec3>,
    rt0: Vec<f64>,
    /// sin and cos of `rt0` (it changes once an iteration, the geometry is
    /// evaluated several times).
    rt0_sc: Vec<(f64, f64)>,
    xtilde: Vec<Vec3>,
    // Trial state and its geometry.
    xt: Vec<Vec3>,
    tht: Vec<f64>,
    tan: Vec<Vec3>,
    len: Vec<f64>,
    d1c: Vec<Vec3>,
    m1: Vec<Vec3>,
    m2: Vec<Vec3>,
    rt: Vec<f64>,
    // Newton.
    grad: Vec<f64>,
    dx: Vec<f64>,
    /// H⁻¹ u for the grip's rank-one correction (`Wire::newton_direction`).
    dz: Vec<f64>,
    h: BandMatrix,
    /// The static Hessian (no inertia, with the compressive geometric
    /// stiffness) for the buckling check, and its direction of negative
    /// curvature (`Wire::buckle`).
    hs: BandMatrix,
    dv: Vec<f64>,
    /// Per node: friction's Hessian blocks at the last assembly (on the
    /// node, node–twist, twist–twist), which the static Hessian leaves out.
    fric_h: Vec<(Mat3, Vec3, f64)>,
    /// `eval_at` leaves out inertia and drag: the wire's static potential.
    statics: bool,
    /// Whether a step looks for the saddle of a buckling column
    /// (`Wire::set_buckling_check`).
    buckling_check: bool,
    hub_grad: Vec3,
    hub_dtheta: f64,
    /// The hub's axial force at the end of the last step (N): while it is
    /// at the grip's limit the next step feeds nothing in.
    last_axial: f64,
    /// `last_axial` as it was when the good state was saved.
    good_axial: f64,
    /// The last step's residual (`StepReport::residual_n`; infinite before
    /// the first step and after a restore): whether the next push slides.
    last_residual: f64,
    eval_pen: f64,
    contacts: Reserved<WireContact>,
    /// Per node: what the lumen keeps near it between probes (moves with
    /// the node when nodes enter or leave at the hub).
    probe_cache: Vec<ProbeCache>,
    /// Per node: the wall probe of the last evaluation.
    hits: Vec<Option<WallHit>>,
    /// Per node: where it was when the lumen was last probed for it in
    /// this step, and how far the wall was from there at least (m;
    /// −∞ before its first probe of the step). See `Wire::eval_at`.
    probe_at: Vec<Vec3>,
    probe_clear: Vec<f64>,
    /// Per node: the wall's penalty force on it at the last evaluation
    /// (summed over the pieces of wall its sphere overlaps; zero out of
    /// contact).
    wall_force: Vec<Vec3>,
    /// Scratch: one node's overlaps with the wall.
    overlaps: WallOverlaps,
    /// Per node and edge: the step's coefficients.
    coef: Vec<Coef>,
    /// Per edge: 1 / its length at the trial state.
    inv_len: Vec<f64>,
    /// Per edge: a twist angle near the trial's with its sine and cosine
    /// (`sin_cos_near`).
    th_near: Vec<(f64, f64, f64)>,
    /// Per node: the same for the reference twist `rt0`.
    rt_near: Vec<(f64, f64, f64)>,
    /// Per node: the direction the wire's surface at its contact moves
    /// per radian of twist of the contact's edge, times the radius (n × t
    /// r, fixed through a step; zero out of contact).
    spin: Vec<Vec3>,
    /// The coaxial terms (a sheath around, a core inside).
    cx: Coax,
}

/// The terms' coefficients at a node i and the edge j = i that leaves it,
/// fixed within a step (they depend on the rest lengths and material
/// coordinates only): computed once a step by `Wire::coefficients`.
#[derive(Debug, Clone, Copy, Default)]
struct Coef {
    /// Node i's inertia m_i / dt² (free nodes).
    mass: f64,
    /// Node i's drag c l̄_i / dt (free nodes).
    drag: f64,
    /// Node i's share of the line load's length, l̄_i (free nodes).
    lbar: f64,
    /// Edge j's twist inertia.
    twist_mass: f64,
    /// Edge j's axial stiffness EA / ē_j.
    stretch: f64,
    /// Node i's bending stiffness EI / l̄_i (tip factor included).
    bend: f64,
    /// Node i's twisting stiffness GJ / l̄_i (tip factor included).
    twist: f64,
    /// Node i's rest curvature κ̄₁.
    kb_rest: f64,
    /// Node i's rest curvature κ̄₂.
    kb_rest2: f64,
    /// The core's bending stiffness at node i over l̄_i (0: no core).
    core_bend: f64,
    /// The core's mass at node i over dt² (free nodes; 0: no core).
    core_mass: f64,
}

/// How much of the incremental potential's evaluation the buffers hold at
/// the current Newton iterate, in increasing order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
enum Have {
    /// Nothing: the geometry is that of another state.
    Nothing,
    /// Its geometry (frames, curvatures, reference twist) and energy.
    Geometry,
    /// And its gradient.
    Gradient,
    /// And its Hessian.
    Hessian,
}

/// The default of [`WireParams::friction_smoothing_m`]: the slip per step
/// (m) below which Coulomb friction is smoothed (a quadratic
/// potential: a stiffness μλ/ε that turns into the constant force μλ
/// beyond it): 1 µm, i.e. 1 mm/s at 1 kHz. With 0.1 µm, a wire pulled or
/// pushed at 100 mm/s against several contacts stopped converging: the
/// line search met the friction's near-kink in the second Newton
/// iteration, and the step ended with the hub edge stretched by the feed,
/// its force at the grip's limit (10 N, which the drive clamps to 3 N and
/// the hand felt; found by the soak's guidewire hand, 2026-11-27). The
/// capstan test is closer to e^{μθ} with 1 µm too (0.3 % against 1.4 %).
/// What it costs: below 1 mm/s, sticking is a stiff viscous creep, not a
/// hold.
pub const FRICTION_SMOOTHING_M: f64 = 1e-6;

/// The default `contact_onset_m`: the contact's penalty begins 10 µm before
/// the wall (docs/WIRE.md "Fast pulls", change 3).
pub const CONTACT_ONSET_M: f64 = 1e-5;

/// Feeds up to this many `friction_smoothing_m` a step do not slide the
/// wire along itself (the step's starting point, `Wire::slide`): the step starts from the unmoved
/// nodes. The slide puts every contact at a slip of the whole feed; for a
/// feed near the smoothing, as when the hub starts pushing again after a
/// turn, most contacts should stay stuck or barely slip, and started
/// slipping (where the Newton model has no stiffness along the slip) the
/// step took up to 15 evaluations. From the unmoved nodes the contacts
/// start stuck, where that model is exact, and the hub edge's compression
/// (a few micrometres) is the grip's piecewise model's to resolve
/// (docs/WIRE.md "Slow pushes start from the unmoved wire"). This bound
/// matters only after a step that ended off equilibrium: after one that
/// settled, no feed slides (docs/WIRE.md "Pushes start from the unmoved
/// wire once it has settled").
pub const SLIDE_MIN_FEED_SMOOTHINGS: f64 = 10.0;

/// The buckling check adds a compressed edge's geometric stiffness only
/// where the bends at its ends are within this of their rest curvature
/// (the material curvature, about the turning angle a segment): the
/// Gauss–Newton bend Hessian leaves out terms of that size, and where the
/// wire is bent far from its rest shape (around the arch, the J tip held
/// straight) the approximate static Hessian showed negative curvature the
/// wire did not have; following it jammed a J-tip wire in the ascending
/// aorta at the grip's limit (docs/WIRE.md "Buckling").
pub const BUCKLING_BEND_OFF: f64 = 0.02;

/// The buckling check factors the static Hessian only where its bound by
/// the bending alone (`Wire::may_buckle`) does not rule out negative
/// curvature with the compressed edges' forces taken this many times:
/// the bound is exact for a straight wire, and the margin covers the
/// bend's Gauss–Newton form and its coupling to the twist on a wire bent
/// within [`BUCKLING_BEND_OFF`] of its rest shape.
pub const BUCKLING_GATE_MARGIN: f64 = 2.0;

/// A Newton update that the cap on node moves and twists would scale
/// below this is solved again within a trust region of the cap's size
/// (`Wire::damp_hessian`, which says why). Above it the update is scaled
/// as before: with every capped update solved again (a threshold of 1),
/// a wire following a converged push with two iterations a step drifted
/// 1.9 mm from it (0.0005 mm with 0.1;
/// `tests/wire_two_iterations_follow_a_converged_push.rs`) and fast pulls
/// in the arch reached 3.45 N at the hub (under 1 N with 0.1;
/// `tests/guidewire_fast_pull_back_keeps_the_hub_force_small.rs`). The
/// floppy wire's updates were scaled by 0.005–0.03.
pub const TRUST_REGION_BELOW: f64 = 0.1;

/// The default `residual_tolerance_n` (docs/WIRE.md "Fast pulls", change 4).
pub const RESIDUAL_TOLERANCE_N: f64 = 0.2;

/// Parallel transport of `d` from tangent `a` to tangent `b` (unit vectors).
#[inline(always)]
fn transport(d: Vec3, a: Vec3, b: Vec3) -> Vec3 {
    let k = a.cross(&b);
    let c = a.dot(&b);
    let s2 = k.norm_squared();
    // The rotation about k = a × b taking a to b (Rodrigues, with
    // |k|² = (1 − c)(1 + c)): no square root and one division. For turns
    // beyond 90° (1 + c small), the normalised form below.
    if c >= 0.0 {
        if s2 >= 1e-28 {
            return d * c + k.cross(&d) + k * (k.dot(&d) / (1.0 + c));
        }
        // Parallel (an edge that did not turn): as `transport_slow`.
        return d;
    }
    transport_slow(d, a, b)
}

/// [`transport`] through the normalised binormal: for any turn, and the
/// parallel and reversed cases.
fn transport_slow(d: Vec3, a: Vec3, b: Vec3) -> Vec3 {
    let c = a.cross(&b);
    let s = c.norm();
    if s < 1e-14 {
        if a.dot(&b) > 0.0 {
            return d;
        }
        // Reversed tangent: keep d, made perpendicular to b.
        let q = d - b * d.dot(&b);
        let n = q.norm();
        return if n > 1e-14 { q / n } else { perpendicular(b) };
    }
    let bn = c / s;
    let n1 = a.cross(&bn);
    let n2 = b.cross(&bn);
    d.dot(&a) * b + d.dot(&n1) * n2 + d.dot(&bn) * bn
}

/// Rotates `v` about the unit `axis` by `angle` (Rodrigues).
fn rotate(v: Vec3, axis: Vec3, angle: f64) -> Vec3 {
    let (s, c) = angle.sin_cos();
    rotate_sc(v, axis, s, c)
}

/// [`rotate`] by the angle whose sine and cosine are `s` and `c`.
#[inline]
fn rotate_sc(v: Vec3, axis: Vec3, s: f64, c: f64) -> Vec3 {
    v * c + axis.cross(&v) * s + axis * axis.dot(&v) * (1.0 - c)
}

/// Signed angle from `u` to `v` about `axis`.
fn signed_angle(u: Vec3, v: Vec3, axis: Vec3) -> f64 {
    let (y, x) = (u.cross(&v).dot(&axis), u.dot(&v));
    // The geometry's angles (a reference twist's change within a step) are
    // small: atan(t) by its series below |t| = 10⁻², whose first dropped
    // term, t¹¹/11, is below 10⁻²³ (a tenth of an ulp of t).
    if x > 0.0 && y.abs() < 1e-2 * x {
        let t = y / x;
        let t2 = t * t;
        return t * (1.0 - t2 * (1.0 / 3.0 - t2 * (1.0 / 5.0 - t2 * (1.0 / 7.0 - t2 * (1.0 / 9.0)))));
    }
    y.atan2(x)
}

/// sin and cos of `theta` from those of a nearby `(angle, sin, cos)`
/// (`near`), by the angle-sum formulas with the difference's series when it
/// is below 10⁻² (first dropped terms δ⁹/9!, δ¹⁰/10!: below 10⁻²³); else
/// computed anew, and `near` moves to `theta`. A wire's twists move by
/// micro-radians between the geometry's evaluations.
#[inline]
fn sin_cos_near(theta: f64, near: &mut (f64, f64, f64)) -> (f64, f64) {
    let d = theta - near.0;
    if d.abs() < 1e-2 {
        let d2 = d * d;
        let sd = d * (1.0 - d2 / 6.0 * (1.0 - d2 / 20.0 * (1.0 - d2 / 42.0 * (1.0 - d2 / 72.0))));
        let cd = 1.0 - d2 / 2.0 * (1.0 - d2 / 12.0 * (1.0 - d2 / 30.0 * (1.0 - d2 / 56.0)));
        let (s0, c0) = (near.1, near.2);
        return (s0 * cd + c0 * sd, c0 * cd - s0 * sd);
    }
    let (s, c) = theta.sin_cos();
    *near = (theta, s, c);
    (s, c)
}

/// Lanes of `Wire::geometry`'s vectorised loops:
/// that many edges or nodes at once, one per lane, in arrays the compiler
/// keeps in vector registers. Each lane does the scalar code's operations
/// in its order, so the results are the same bits.
const LANES: usize = 8;

/// `L` vectors, one per lane, by coordinate.
#[derive(Clone, Copy)]
struct Lv<const L: usize> {
    x: [f64; L],
    y: [f64; L],
    z: [f64; L],
}

#[inline(always)]
fn lmap<const L: usize>(f: impl Fn(usize) -> f64) -> [f64; L] {
    std::array::from_fn(f)
}

impl<const L: usize> Lv<L> {
    /// Lanes `v[at..at + L]`.
    #[inline(always)]
    fn load(v: &[Vec3], at: usize) -> Lv<L> {
        let v = &v[at..at + L];
        Lv {
            x: lmap(|l| v[l].x),
            y: lmap(|l| v[l].y),
            z: lmap(|l| v[l].z),
        }
    }

    #[inline(always)]
    fn store(&self, v: &mut [Vec3], at: usize) {
        for (l, o) in v[at..at + L].iter_mut().enumerate() {
            *o = Vec3::new(self.x[l], self.y[l], self.z[l]);
        }
    }

    #[inline(always)]
    fn get(&self, l: usize) -> Vec3 {
        Vec3::new(self.x[l], self.y[l], self.z[l])
    }

    #[inline(always)]
    fn set(&mut self, l: usize, v: Vec3) {
        (self.x[l], self.y[l], self.z[l]) = (v.x, v.y, v.z);
    }

    // As nalgebra's for `Vec3`, operation for operation: a − b, a + b,
    // a s, −a, a × b, a · b ((x x' + y y') + z z').
    #[inline(always)]
    fn sub(&self, b: &Lv<L>) -> Lv<L> {
        Lv {
            x: lmap(|l| self.x[l] - b.x[l]),
            y: lmap(|l| self.y[l] - b.y[l]),
            z: lmap(|l| self.z[l] - b.z[l]),
        }
    }

    #[inline(always)]
    fn add(&self, b: &Lv<L>) -> Lv<L> {
        Lv {
            x: lmap(|l| self.x[l] + b.x[l]),
            y: lmap(|l| self.y[l] + b.y[l]),
            z: lmap(|l| self.z[l] + b.z[l]),
        }
    }

    #[inline(always)]
    fn scale(&self, s: &[f64; L]) -> Lv<L> {
        Lv {
            x: lmap(|l| self.x[l] * s[l]),
            y: lmap(|l| self.y[l] * s[l]),
            z: lmap(|l| self.z[l] * s[l]),
        }
    }

    #[inline(always)]
    fn neg(&self) -> Lv<L> {
        Lv {
            x: lmap(|l| -self.x[l]),
            y: lmap(|l| -self.y[l]),
            z: lmap(|l| -self.z[l]),
        }
    }

    #[inline(always)]
    fn cross(&self, b: &Lv<L>) -> Lv<L> {
        Lv {
            x: lmap(|l| self.y[l] * b.z[l] - self.z[l] * b.y[l]),
            y: lmap(|l| self.z[l] * b.x[l] - self.x[l] * b.z[l]),
            z: lmap(|l| self.x[l] * b.y[l] - self.y[l] * b.x[l]),
        }
    }

    #[inline(always)]
    fn dot(&self, b: &Lv<L>) -> [f64; L] {
        lmap(|l| self.x[l] * b.x[l] + self.y[l] * b.y[l] + self.z[l] * b.z[l])
    }
}

/// [`transport`] in every lane; a lane off its fast path (a turn beyond
/// 90°, or none) takes the scalar function.
#[inline(always)]
fn transport_lanes<const L: usize>(d: &Lv<L>, a: &Lv<L>, b: &Lv<L>) -> Lv<L> {
    let k = a.cross(b);
    let c = a.dot(b);
    let s2 = k.dot(&k);
    let q = k.dot(d);
    let q = lmap(|l| q[l] / (1.0 + c[l]));
    let mut r = d.scale(&c).add(&k.cross(d)).add(&k.scale(&q));
    for l in 0..L {
        if !(c[l] >= 0.0 && s2[l] >= 1e-28) {
            r.set(l, transport(d.get(l), a.get(l), b.get(l)));
        }
    }
    r
}

/// [`sin_cos_near`] in every lane (`theta`, `near`: `L` long).
#[inline(always)]
fn sin_cos_near_lanes<const L: usize>(theta: &[f64], near: &mut [(f64, f64, f64)]) -> ([f64; L], [f64; L]) {
    let d: [f64; L] = lmap(|k| theta[k] - near[k].0);
    let d2: [f64; L] = lmap(|k| d[k] * d[k]);
    let sd: [f64; L] =
        lmap(|k| d[k] * (1.0 - d2[k] / 6.0 * (1.0 - d2[k] / 20.0 * (1.0 - d2[k] / 42.0 * (1.0 - d2[k] / 72.0)))));
    let cd: [f64; L] = lmap(|k| 1.0 - d2[k] / 2.0 * (1.0 - d2[k] / 12.0 * (1.0 - d2[k] / 30.0 * (1.0 - d2[k] / 56.0))));
    let mut sn: [f64; L] = lmap(|k| near[k].1 * cd[k] + near[k].2 * sd[k]);
    let mut cs: [f64; L] = lmap(|k| near[k].2 * cd[k] - near[k].1 * sd[k]);
    for k in 0..L {
        if d[k].abs() < 1e-2 {
            continue;
        }
        (sn[k], cs[k]) = sin_cos_near(theta[k], &mut near[k]);
    }
    (sn, cs)
}

/// [`signed_angle`] in every lane.
#[inline(always)]
fn signed_angle_lanes<const L: usize>(u: &Lv<L>, v: &Lv<L>, axis: &Lv<L>) -> [f64; L] {
    let y = u.cross(v).dot(axis);
    let x = u.dot(v);
    let t: [f64; L] = lmap(|k| y[k] / x[k]);
    lmap(|k| {
        if x[k] > 0.0 && y[k].abs() < 1e-2 * x[k] {
            let (t, t2) = (t[k], t[k] * t[k]);
            t * (1.0 - t2 * (1.0 / 3.0 - t2 * (1.0 / 5.0 - t2 * (1.0 / 7.0 - t2 * (1.0 / 9.0)))))
        } else {
            y[k].atan2(x[k])
        }
    })
}

/// The contact penalty at penetration `pen` (m; negative: a gap) with
/// stiffness `k` and onset `onset` (m): energy, force and stiffness. Zero
/// below −onset; cubic from there to contact, its stiffness rising
/// linearly from 0 to k; quadratic beyond (force k (pen + onset / 2)). With
/// a zero onset, the plain ½ k pen² for pen > 0.
fn penalty(pen: f64, k: f64, onset: f64) -> (f64, f64, f64) {
    if pen <= -onset {
        (0.0, 0.0, 0.0)
    } else if pen < 0.0 {
        let a = pen + onset;
        (k * a * a * a / (6.0 * onset), k * a * a / (2.0 * onset), k * a / onset)
    } else {
        (
            k * (onset * onset / 6.0 + 0.5 * onset * pen + 0.5 * pen * pen),
            k * (pen + 0.5 * onset),
            k,
        )
    }
}

/// The gradient of the friction potential μλ·f(|u|) (f: u²/2ε below ε,
/// u − ε/2 above) at slip `ut` of length `un`, `mu_lam` = μλ: the force
/// of friction on the wire is its opposite.
fn friction_gradient(ut: Vec3, un: f64, mu_lam: f64, eps: f64) -> Vec3 {
    if un < eps {
        ut * (mu_lam / eps)
    } else {
        ut / un * mu_lam
    }
}

/// The nearest positive semi-definite matrix to a symmetric `m`: its
/// negative eigenvalues set to zero.
///
/// Why the closed form: a node over a ridge or in a valley of the wall
/// has its contact block projected every evaluation (about 40 a step in
/// the wall-loaded tick bench), and the iterative eigensolver took ~0.3 µs
/// each, 5 % of the step. The eigenvalues come from the characteristic
/// cubic (trigonometric form), the one eigenvector needed (of the single
/// negative eigenvalue, or of the single positive one) from a cross
/// product of two rows of m − λI. Where that vector is ill-determined
/// (two eigenvalues too close to tell apart on the sign's side), the
/// iterative solver decides as before.
fn psd(m: Mat3) -> Mat3 {
    let l = sym3_eigenvalues(&m);
    if l[2] >= 0.0 {
        return m;
    }
    if l[0] <= 0.0 {
        return Mat3::zeros();
    }
    let scale = l[0].max(-l[2]);
    // Eigenvalues within the closed form's own error of zero (a rank-one
    // block's two zero eigenvalues come out as ±1e-9 of it, whose
    // eigenvectors are not determined): taken as zero.
    let tiny = PSD_ZERO * scale;
    if l[1] >= 0.0 && l[2] >= -tiny {
        return m;
    }
    if l[1] < 0.0 && l[0] <= tiny {
        return Mat3::zeros();
    }
    // One negative eigenvalue: take it out; two: keep the positive one.
    let (lam, keep) = if l[1] >= 0.0 { (l[2], false) } else { (l[0], true) };
    if let Some(v) = sym3_eigenvector(&m, lam, scale) {
        let vv = outer(&v, &v) * lam;
        return if keep { vv } else { m - vv };
    }
    psd_iterative(m)
}

/// Eigenvalues of a contact block within this fraction of its largest
/// are zero to [`psd`]: above the closed form's error near a double
/// eigenvalue (about 10⁻⁸ of the block), far below what the Newton model
/// can feel.
const PSD_ZERO: f64 = 3e-8;

/// [`psd`] by the iterative symmetric eigensolver.
fn psd_iterative(m: Mat3) -> Mat3 {
    let e = nalgebra::SymmetricEigen::new(m);
    if e.eigenvalues.iter().all(|&l| l >= 0.0) {
        return m;
    }
    let l = e.eigenvalues.map(|l| l.max(0.0));
    e.eigenvectors * Mat3::from_diagonal(&l) * e.eigenvectors.transpose()
}

/// The eigenvalues of the symmetric `m`, largest first (the
/// characteristic cubic's trigonometric solution; absolute error a few
/// ulps of |m|, more where two nearly coincide).
fn sym3_eigenvalues(m: &Mat3) -> [f64; 3] {
    let (a, b, c) = (m[(0, 0)], m[(1, 1)], m[(2, 2)]);
    let (d, e, f) = (m[(1, 0)], m[(2, 0)], m[(2, 1)]);
    let q = (a + b + c) / 3.0;
    let (aq, bq, cq) = (a - q, b - q, c - q);
    let p2 = aq * aq + bq * bq + cq * cq + 2.0 * (d * d + e * e + f * f);
    if p2.is_nan() || p2 <= 0.0 {
        return [q; 3];
    }
    let p = (p2 / 6.0).sqrt();
    // det((m − qI) / p) / 2, in [−1, 1] up to rounding.
    let det = aq * (bq * cq - f * f) - d * (d * cq - f * e) + e * (d * f - bq * e);
    let r = (0.5 * det / (p * p * p)).clamp(-1.0, 1.0);
    let phi = r.acos() / 3.0;
    let l0 = q + 2.0 * p * phi.cos();
    let l2 = q + 2.0 * p * (phi + 2.0 * std::f64::consts::FRAC_PI_3).cos();
    [l0, 3.0 * q - l0 - l2, l2]
}

/// A unit eigenvector of the symmetric `m` for its eigenvalue `lam` (|m|
/// about `scale`): the longest cross product of two rows of m − λI, None
/// when that is too short to give the direction (λ not a simple
/// eigenvalue as far as rounding can tell).
fn sym3_eigenvector(m: &Mat3, lam: f64, scale: f64) -> Option<Vec3> {
    let s = m - Mat3::identity() * lam;
    let (r0, r1, r2) = (
        Vec3::new(s[(0, 0)], s[(0, 1)], s[(0, 2)]),
        Vec3::new(s[(1, 0)], s[(1, 1)], s[(1, 2)]),
        Vec3::new(s[(2, 0)], s[(2, 1)], s[(2, 2)]),
    );
    let mut best = r0.cross(&r1);
    for c in [r0.cross(&r2), r1.cross(&r2)] {
        if c.norm_squared() > best.norm_squared() {
            best = c;
        }
    }
    let n2 = best.norm_squared();
    // Its direction is good to about ε scale² / |c|: ask for 1e-8.
    if n2.is_finite() && n2 > 1e-16 * (scale * scale) * (scale * scale) {
        Some(best / n2.sqrt())
    } else {
        None
    }
}

fn outer(a: &Vec3, b: &Vec3) -> Mat3 {
    a * b.transpose()
}

impl Wire {
    /// A wire from `params`, its hub at `access_point` with the insertion
    /// `axis` (pointing into the body), `inserted_m` metres inserted (straight
    /// along the axis) and roll 0.
    pub fn new(params: &WireParams, access_point: Vec3, axis: Vec3, inserted_m: f64) -> Result<Wire, WireError> {
        params.validate(Path::new("(wire)"))?;
        let an = axis.norm();
        if !(an.is_finite() && an > 1e-12) {
            return Err(WireError::Hub("the insertion axis must be a finite non-zero vector"));
        }
        if !access_point.iter().all(|c| c.is_finite()) {
            return Err(WireError::Hub("the access point must be finite"));
        }
        let axis = axis / an;
        let cap = params.max_nodes;
        let max_inserted = params.max_inserted_m();
        let mut w = Wire {
            p: params.clone(),
            cap,
            hub: access_point,
            axis,
            d1_hub: perpendicular(axis),
            target: 0.0,
            max_inserted,
            tip_load: Vec3::zeros(),
            line_load: Vec3::zeros(),
            s: State::new(cap),
            good: State::new(cap),
            x0: vec![Vec3::zeros(); cap],
            th0: vec![0.0; cap],
            d10: vec![Vec3::zeros(); cap],
            t0: vec![Vec3::zeros(); cap],
            rt0: vec![0.0; cap],
            rt0_sc: vec![(0.0, 1.0); cap],
            xtilde: vec![Vec3::zeros(); cap],
            xt: vec![Vec3::zeros(); cap],
            tht: vec![0.0; cap],
            tan: vec![Vec3::zeros(); cap],
            len: vec![0.0; cap],
            d1c: vec![Vec3::zeros(); cap],
            m1: vec![Vec3::zeros(); cap],
            m2: vec![Vec3::zeros(); cap],
            rt: vec![0.0; cap],
            grad: vec![0.0; 4 * cap],
            dx: vec![0.0; 4 * cap],
            dz: vec![0.0; 4 * cap],
            h: BandMatrix::new(4 * cap, BAND),
            hs: BandMatrix::new(4 * cap, BAND),
            dv: vec![0.0; 4 * cap],
            fric_h: vec![(Mat3::zeros(), Vec3::zeros(), 0.0); cap],
            statics: false,
            buckling_check: true,
            hub_grad: Vec3::zeros(),
            hub_dtheta: 0.0,
            last_axial: 0.0,
            good_axial: 0.0,
            last_residual: f64::INFINITY,
            eval_pen: 0.0,
            contacts: Reserved::with_capacity(cap),
            probe_cache: vec![ProbeCache::default(); cap],
            hits: vec![None; cap],
            probe_at: vec![Vec3::zeros(); cap],
            probe_clear: vec![f64::NEG_INFINITY; cap],
            wall_force: vec![Vec3::zeros(); cap],
            overlaps: WallOverlaps::new(),
            coef: vec![Coef::default(); cap],
            inv_len: vec![0.0; cap],
            th_near: vec![(0.0, 0.0, 1.0); cap],
            rt_near: vec![(0.0, 0.0, 1.0); cap],
            spin: vec![Vec3::zeros(); cap],
            cx: Coax::new(cap),
        };
        w.lay_straight(inserted_m);
        w.save_good_state();
        Ok(w)
    }

    /// Places the wire straight along the axis with `inserted` metres in.
    fn lay_straight(&mut self, inserted: f64) {
        let h = self.p.segment_length_m;
        let l = inserted.clamp(0.5 * h, self.max_inserted);
        let k = ((l - 0.5 * h) / h).floor().max(0.0) as usize;
        let k = k.min(self.cap - 3);
        let n = k + 3;
        let s = &mut self.s;
        s.n = n;
        s.inserted = l;
        self.target = l;
        s.u[0] = l + h;
        s.u[1] = l;
        for i in 2..n {
            s.u[i] = (n - 1 - i) as f64 * h;
        }
        for i in 0..n {
            s.x[i] = self.hub + self.axis * (l - s.u[i]);
            s.v[i] = Vec3::zeros();
            s.theta[i] = s.roll;
            s.d1[i] = self.d1_hub;
            s.ref_twist[i] = 0.0;
            s.lam[i] = 0.0;
            s.comp[i] = -1.0;
            s.anchor[i] = s.x[i];
            s.anchor_twist[i] = s.theta[i];
        }
        for j in 0..n - 1 {
            s.rest[j] = s.u[j] - s.u[j + 1];
        }
    }

    /// The parameters.
    pub fn params(&self) -> &WireParams {
        &self.p
    }

    /// Drives the hub: `inserted_m` metres of wire inside (clamped to what the
    /// wire's length and node capacity allow), rolled by `roll_rad` about the
    /// insertion axis. Takes effect at the next [`Wire::step`].
    pub fn set_hub(&mut self, inserted_m: f64, roll_rad: f64) {
        let h = self.p.segment_length_m;
        if inserted_m.is_finite() {
            self.target = inserted_m.clamp(0.5 * h, self.max_inserted);
        }
        if roll_rad.is_finite() {
            self.s.roll = roll_rad;
        }
    }

    /// Changes the friction coefficient (clamped to the allowed [0, 2]).
    pub fn set_friction(&mut self, mu: f64) {
        if mu.is_finite() {
            self.p.friction = mu.clamp(0.0, 2.0);
        }
    }

    /// Turns the buckling check on (the default) or off: with it off, a
    /// perfect column pushed past its Euler load stays straight until
    /// rounding lets it buckle (docs/WIRE.md "Buckling"; for comparisons).
    pub fn set_buckling_check(&mut self, on: bool) {
        self.buckling_check = on;
    }

    /// Sets `residual_time_limit_us` (µs; 0 or less: no limit): past it,
    /// no extra Newton iteration starts. An untimed set-up turns it off so
    /// that its result does not hang on how busy the machine is.
    pub fn set_residual_time_limit_us(&mut self, us: f64) {
        self.p.residual_time_limit_us = if us.is_finite() { us.max(0.0) } else { 0.0 };
    }

    /// A dead load on the tip node (N), e.g. for a cantilever test.
    pub fn set_tip_load(&mut self, f: Vec3) {
        self.tip_load = f;
    }

    /// A load per unit length on the inserted wire (N/m), e.g. its weight
    /// in blood (ρ − ρ_blood) A g, or a push against a wall.
    pub fn set_line_load(&mut self, f_per_m: Vec3) {
        self.line_load = f_per_m;
    }

    /// The most that can be inserted (m).
    pub fn max_inserted(&self) -> f64 {
        self.max_inserted
    }

    /// The inserted length (m).
    pub fn inserted(&self) -> f64 {
        self.s.inserted
    }

    /// The hub's roll (rad).
    pub fn roll(&self) -> f64 {
        self.s.roll
    }

    /// Active nodes (ghost and hub included).
    pub fn num_nodes(&self) -> usize {
        self.s.n
    }

    /// Node positions (m): index 0 is the ghost behind the hub, 1 the hub,
    /// the last the tip.
    pub fn positions(&self) -> &[Vec3] {
        &self.s.x[..self.s.n]
    }

    /// The inserted part as a polyline, hub to tip.
    pub fn inserted_polyline(&self) -> &[Vec3] {
        &self.s.x[1..self.s.n]
    }

    /// The tip position (m).
    pub fn tip(&self) -> Vec3 {
        self.s.x[self.s.n - 1]
    }

    /// Material coordinate (arc length from the tip, m) of each node.
    pub fn material_coordinates(&self) -> &[f64] {
        &self.s.u[..self.s.n]
    }

    /// Tangent and material frame (t, m1, m2) of edge `j` (0 ≤ j < nodes − 1).
    pub fn material_frame(&self, j: usize) -> (Vec3, Vec3, Vec3) {
        let s = &self.s;
        let e = s.x[j + 1] - s.x[j];
        let t = e / e.norm();
        let d2 = t.cross(&s.d1[j]);
        let (sn, cs) = s.theta[j].sin_cos();
        (t, s.d1[j] * cs + d2 * sn, -s.d1[j] * sn + d2 * cs)
    }

    /// The contacts of the last step.
    pub fn contacts(&self) -> &[WireContact] {
        &self.contacts
    }

    /// Whether every position, velocity and twist is finite.
    pub fn is_finite(&self) -> bool {
        self.s.is_finite()
    }

    /// Remembers the current state as the last good one (copies into
    /// buffers sized at construction: no allocation).
    pub fn save_good_state(&mut self) {
        self.good.copy_from(&self.s);
        self.good_axial = self.last_axial;
    }

    /// Returns to the last good state (velocities zeroed), e.g. after a
    /// [`WireFault`]; the hub keeps its commanded insertion and roll.
    pub fn restore_good_state(&mut self) {
        let roll = self.s.roll;
        self.s.copy_from(&self.good);
        self.s.roll = roll;
        for v in &mut self.s.v[..self.s.n] {
            *v = Vec3::zeros();
        }
        self.contacts.clear();
        self.cx.sheath_contacts.clear();
        self.last_residual = f64::INFINITY;
        // The hub force goes back with the state: the failed step's, at the
        // grip's limit, would hold back the next step's feed.
        self.last_axial = self.good_axial;
        self.cx.forget_inside();
    }

    /// The net force on a node (N) below which a step counts as having
    /// ended at equilibrium for [`Wire::slide`]: the wire's
    /// `residual_tolerance_n`, or its default where that is 0 (no
    /// iterations past `newton_iterations`).
    fn settled_tolerance(&self) -> f64 {
        if self.p.residual_tolerance_n > 0.0 {
            self.p.residual_tolerance_n
        } else {
            RESIDUAL_TOLERANCE_N
        }
    }

    fn h_seg(&self) -> f64 {
        self.p.segment_length_m
    }

    /// Feeds or withdraws material at the hub toward the target insertion:
    /// the hub edge's rest length follows it; nodes are added when it grows
    /// past 1.6 segments and removed when it shrinks below half a segment.
    fn feed(&mut self) {
        let h = self.h_seg();
        let s = &mut self.s;
        // A slipping grip: no feeding in while the wire pushes back as hard
        // as the grip holds.
        // The feed per step is at most a quarter of the wire's diameter
        // (220 mm/s for 0.89 mm at 1 kHz), so that a hand far ahead of a
        // slipping wire does not feed a jump.
        let max_feed = 0.25 * self.p.diameter_m;
        let feed = (self.target - s.inserted).clamp(-max_feed, max_feed);
        if feed <= 0.0 || self.last_axial < 0.999 * self.p.max_hub_force_n {
            s.inserted += feed;
        }
        s.u[1] = s.inserted;
        s.u[0] = s.inserted + h;
        loop {
            let r = s.u[1] - s.u[2];
            if r > 1.6 * h && s.n < self.cap {
                let n = s.n;
                // Shift nodes 2.. (and edges 1..) up by one.
                for i in (2..n).rev() {
                    s.x[i + 1] = s.x[i];
                    s.v[i + 1] = s.v[i];
                    s.u[i + 1] = s.u[i];
                    s.lam[i + 1] = s.lam[i];
                    s.nrm[i + 1] = s.nrm[i];
                    s.comp[i + 1] = s.comp[i];
                    s.anchor[i + 1] = s.anchor[i];
                    s.anchor_twist[i + 1] = s.anchor_twist[i];
                    s.ref_twist[i + 1] = s.ref_twist[i];
                }
                self.probe_cache[2..=n].rotate_right(1);
                self.cx.shift_nodes_up(n);
                for j in (1..n - 1).rev() {
                    s.theta[j + 1] = s.theta[j];
                    s.d1[j + 1] = s.d1[j];
                    s.rest[j + 1] = s.rest[j];
                }
                // The new node sits one segment (its edge's rest length)
                // before node 3 along the old hub edge, so that the slide
                // of this step's feed (`Wire::slide`, which lengthens the
                // hub edge) leaves both edges at their rest lengths; it
                // enters moving with the wire.
                let l = (s.x[3] - s.x[1]).norm();
                let frac = if l > h { (l - h) / l } else { (r - h) / r };
                s.x[2] = s.x[1] + (s.x[3] - s.x[1]) * frac;
                s.v[2] = s.v[3];
                s.u[2] = s.u[3] + h;
                s.lam[2] = 0.0;
                s.comp[2] = -1.0;
                s.anchor[2] = s.x[2];
                s.ref_twist[2] = 0.0;
                s.rest[2] = h;
                s.n = n + 1;
            } else if r < 0.5 * h && s.n > 3 {
                let n = s.n;
                // Merge edges 1 and 2: the new hub edge keeps edge 2's twist,
                // its frame carried to the new tangent, and the two
                // reference twists add up.
                let t_old = (s.x[3] - s.x[2]).normalize();
                let t_new = (s.x[3] - s.x[1]).normalize();
                let d1 = transport(s.d1[2], t_old, t_new);
                let theta = s.theta[2];
                let rt = s.ref_twist[1] + s.ref_twist[2];
                for i in 2..n - 1 {
                    s.x[i] = s.x[i + 1];
                    s.v[i] = s.v[i + 1];
                    s.u[i] = s.u[i + 1];
                    s.lam[i] = s.lam[i + 1];
                    s.nrm[i] = s.nrm[i + 1];
                    s.comp[i] = s.comp[i + 1];
                    s.anchor[i] = s.anchor[i + 1];
                    s.anchor_twist[i] = s.anchor_twist[i + 1];
                    s.ref_twist[i] = s.ref_twist[i + 1];
                }
                self.probe_cache[2..n].rotate_left(1);
                self.cx.shift_nodes_down(n);
                for j in 1..n - 2 {
                    s.theta[j] = s.theta[j + 1];
                    s.d1[j] = s.d1[j + 1];
                    s.rest[j] = s.rest[j + 1];
                }
                s.d1[1] = d1;
                s.theta[1] = theta;
                // Re-measure the hub's reference twist continuously.
                let ut = rotate(transport(self.d1_hub, self.axis, t_new), t_new, rt);
                s.ref_twist[1] = rt + signed_angle(ut, d1, t_new);
                s.n = n - 1;
            } else {
                break;
            }
        }
        s.rest[0] = h;
        s.rest[1] = s.u[1] - s.u[2];
        s.x[0] = self.hub - self.axis * h;
        s.x[1] = self.hub;
        s.theta[0] = s.roll;
        s.d1[0] = self.d1_hub;
    }

    /// Copies the state as the step's start and sets the inertial target.
    fn begin_step(&mut self) {
        let n = self.s.n;
        let dt = self.p.dt_s;
        for i in 0..n {
            self.x0[i] = self.s.x[i];
            self.xtilde[i] = self.s.x[i] + self.s.v[i] * dt;
            self.th0[i] = self.s.theta[i];
            self.d10[i] = self.s.d1[i];
            self.rt0[i] = self.s.ref_twist[i];
            self.rt0_sc[i] = sin_cos_near(self.rt0[i], &mut self.rt_near[i]);
            self.xt[i] = self.s.x[i];
            self.tht[i] = self.s.theta[i];
        }
        for j in 0..n - 1 {
            let e = self.s.x[j + 1] - self.s.x[j];
            // As `geometry` computes it: unmoved frames stay bit for bit.
            self.t0[j] = e * (1.0 / e.norm());
        }
        self.begin_coaxial();
        let r_w = 0.5 * self.p.diameter_m;
        for i in 0..n {
            self.spin[i] = if i >= 2 && self.s.lam[i] > 0.0 {
                let t = self.t0[Self::contact_edge(i, n)];
                self.s.nrm[i].cross(&t) * r_w
            } else {
                Vec3::zeros()
            };
        }
        self.coefficients();
    }

    /// The step's coefficients of every term (`coef`), from the rest
    /// lengths and material coordinates after the feed.
    fn coefficients(&mut self) {
        let n = self.s.n;
        let p = &self.p;
        let s = &self.s;
        let dt = p.dt_s;
        let area = p.area();
        let ea = p.youngs_modulus_pa * area;
        let ei = p.bending_stiffness();
        let gj = p.twisting_stiffness();
        let rho_a = p.density_kg_m3 * area;
        let rho_j = p.density_kg_m3 * p.polar_moment();
        for (i, c) in self.coef[..n].iter_mut().enumerate() {
            *c = Coef::default();
            if i >= 2 {
                let lbar = if i == n - 1 {
                    0.5 * s.rest[i - 1]
                } else {
                    0.5 * (s.rest[i - 1] + s.rest[i])
                };
                c.mass = rho_a * lbar / (dt * dt);
                if let Some(core) = self.cx.core {
                    if s.inserted - s.u[i] <= core.reach {
                        c.core_mass = core.mass_per_m * lbar / (dt * dt);
                    }
                }
                c.drag = p.drag_n_s_per_m2 * lbar / dt;
                c.lbar = lbar;
            }
            if i >= 1 && i < n - 1 {
                c.twist_mass = rho_j * s.rest[i] / (dt * dt);
                c.stretch = ea / s.rest[i];
                let lbar = if i == 1 {
                    0.5 * s.rest[1]
                } else {
                    0.5 * (s.rest[i - 1] + s.rest[i])
                };
                let (factor, k0) = if s.u[i] < p.tip_length_m {
                    (p.tip_stiffness_factor, p.tip_curvature_per_m)
                } else {
                    (1.0, 0.0)
                };
                if p.rest_shape.is_empty() {
                    c.kb_rest = if k0 == 0.0 { 0.0 } else { 2.0 * (0.5 * k0 * lbar).tan() };
                } else {
                    // The rest shape's turning over the node's share of the
                    // rod, whatever the arcs' ends: the discrete curvature
                    // 2 tan(φ/2) of that turning φ.
                    let (a, b) = if i == 1 {
                        (s.u[1] - 0.5 * s.rest[1], s.u[1])
                    } else {
                        (s.u[i] - 0.5 * s.rest[i], s.u[i] + 0.5 * s.rest[i - 1])
                    };
                    let (t1, t2) = p.rest_turning(a.max(0.0), b.max(0.0));
                    let phi = (t1 * t1 + t2 * t2).sqrt();
                    if phi > 0.0 {
                        let m = 2.0 * (0.5 * phi.min(3.0)).tan() / phi;
                        c.kb_rest = t1 * m;
                        c.kb_rest2 = t2 * m;
                    }
                }
                c.bend = ei * factor / lbar;
                c.twist = gj * factor / lbar;
                if let Some(core) = self.cx.core {
                    // The core's material coordinate at this node: it
                    // enters at the same hub.
                    let from_hub = s.inserted - s.u[i];
                    if from_hub <= core.reach {
                        let uc = core.reach - from_hub;
                        let f = if uc < core.tip_length { core.tip_factor } else { 1.0 };
                        c.core_bend = core.ei * f / lbar;
                    }
                }
            }
        }
    }

    /// Advances the wire by one time step against `lumen`.
    pub fn step(&mut self, lumen: &dyn Lumen) -> Result<StepReport, WireFault> {
        let before = self.s.inserted;
        self.feed();
        self.begin_step();
        let fed = self.s.inserted - before;
        self.forget_probes();
        self.slide(fed, lumen);
        let n = self.s.n;
        let r_w = 0.5 * self.p.diameter_m;
        let cap_step = 0.5 * r_w;
        let mut rep = StepReport {
            fed_m: fed,
            // The feed withheld at the grip's limit (`Wire::feed`) is a slip.
            grip_slipped: fed == 0.0 && self.target > before && self.last_axial >= 0.999 * self.p.max_hub_force_n,
            ..StepReport::default()
        };
        // Past the configured iterations, go on (up to the extra budget)
        // only while the wire is off equilibrium or deep in the wall.
        let max_it = self.p.max_iterations();
        // What the buffers hold at the current iterate (`s.x`, `xt`): its
        // geometry, energy (`e_cur`), penetration (`eval_pen`), gradient,
        // Hessian. A line search's first trial assembles what the next
        // iteration (or the reactions) will want there, so an accepted
        // full step costs one evaluation instead of two.
        let mut have = Have::Nothing;
        let mut e_cur = 0.0;
        // The extra iterations' time limit (0: none); read only if set.
        let limit_ns = (self.p.residual_time_limit_us * 1e3) as i64;
        let t_start = if limit_ns > 0 { crate::rt::clock::now_ns() } else { 0 };
        // A pushed wire that settled may sit on a saddle of its static
        // energy (a straight column past its buckling load): look for
        // negative curvature there, and leave the saddle along it. (A wire
        // off equilibrium is not on a saddle, and its own motion breaks
        // any symmetry.) The evaluation is the first iteration's.
        if self.buckling_check
            && self.last_axial > 0.0
            && self.last_residual <= self.settled_tolerance()
            && n >= 4
            && self.p.max_evaluations >= 6
        {
            rep.evaluations += 1;
            e_cur = self.eval_at(lumen, true, true, true);
            have = Have::Hessian;
            if e_cur.is_finite() && self.buckle(lumen, e_cur, &mut rep) {
                have = Have::Nothing;
            }
        }
        for it in 0..max_it {
            // `eval_pen` is that of the current iterate for it ≥ 1 (the
            // accepted trial's evaluation).
            if it >= self.p.newton_iterations && self.eval_pen < 0.25 * r_w {
                // Past the configured count: go on only while the iterate is
                // off equilibrium by more than the tolerance (its gradient
                // tells; a trial that assembled none is evaluated here, which
                // the reactions would do anyway if the step stops).
                let tol = self.p.residual_tolerance_n;
                if tol <= 0.0 {
                    break;
                }
                if have < Have::Gradient {
                    // The reactions want this evaluation anyway.
                    rep.evaluations += 1;
                    e_cur = self.eval_at(lumen, have == Have::Nothing, true, true);
                    have = Have::Hessian;
                }
                let off = (2..n).any(|i| {
                    Vec3::new(self.grad[4 * i], self.grad[4 * i + 1], self.grad[4 * i + 2]).norm_squared() > tol * tol
                });
                // Room for a trial and the reactions' evaluation?
                if !off || !e_cur.is_finite() || rep.evaluations + 2 > self.p.max_evaluations {
                    break;
                }
                // Off equilibrium, but out of time: only such a step counts
                // as stopped by the limit.
                if limit_ns > 0 && crate::rt::clock::now_ns() - t_start > limit_ns {
                    rep.time_spent = true;
                    break;
                }
            }
            // Room for this iteration's assembly, one trial and the
            // reactions' evaluation at the end?
            if have != Have::Hessian && rep.evaluations + 3 > self.p.max_evaluations {
                rep.budget_spent = true;
                break;
            }
            let e0 = if have == Have::Hessian {
                e_cur
            } else {
                // Re-based frames at an evaluated iterate are its frames:
                // no geometry to redo.
                rep.evaluations += 1;
                self.eval_at(lumen, have == Have::Nothing, true, true)
            };
            have = Have::Hessian;
            e_cur = e0;
            if !e0.is_finite() {
                break;
            }
            let dofs = 4 * n;
            if !self.newton_direction() {
                break;
            }
            // Cap the largest node move (no tunnelling) and twist change.
            let (mut mx, mut mt) = self.update_size();
            let mut scale = (cap_step / mx.max(1e-300)).min(0.5 / mt.max(1e-300)).min(1.0);
            // Far beyond the cap, the update follows a soft direction of
            // the model that the energy does not have (a slipping
            // contact's flat cone): solve again within a trust region of
            // the cap's size instead of scaling the whole update down.
            if scale < TRUST_REGION_BELOW && rep.evaluations + 4 <= self.p.max_evaluations {
                rep.evaluations += 1;
                self.eval_at(lumen, false, true, true);
                self.damp_hessian(cap_step);
                if !self.newton_direction() {
                    break;
                }
                (mx, mt) = self.update_size();
                scale = (cap_step / mx.max(1e-300)).min(0.5 / mt.max(1e-300)).min(1.0);
            }
            if !scale.is_finite() {
                break;
            }
            // An update this small is rounding (a hundred times the last
            // bit of a 0.1 m coordinate): the iterate has converged. A line
            // search along it would compare energies that differ by
            // rounding alone, and ran out its trials.
            if mx < 1e-15 && mt < 1e-14 {
                rep.iterations = it + 1;
                rep.last_update = mx.max(mt);
                break;
            }
            let slope: f64 = (0..dofs).map(|k| self.grad[k] * self.dx[k]).sum::<f64>() * scale;
            // What the first trial assembles: nothing beyond its energy if
            // the step was capped (the model is then far from the energy;
            // since the grip's piecewise model capped updates are rare, 114
            // of 26 100 in the wall-loaded tick bench); else the
            // Hessian if another iteration is likely to follow (below the
            // configured count, or deep in the wall), else the gradient
            // (the reactions').
            let first = if scale < 1.0 {
                Have::Geometry
            } else if it + 1 < max_it && (it + 1 < self.p.newton_iterations || self.eval_pen >= 0.25 * r_w) {
                Have::Hessian
            } else {
                Have::Gradient
            };
            let mut alpha = scale;
            let mut last_secant = f64::INFINITY;
            let mut accepted = false;
            for trial in 0..12 {
                // Keep one evaluation for the reactions.
                if rep.evaluations + 2 > self.p.max_evaluations {
                    rep.budget_spent = true;
                    break;
                }
                for i in 0..n {
                    let d = Vec3::new(self.dx[4 * i], self.dx[4 * i + 1], self.dx[4 * i + 2]);
                    self.xt[i] = self.s.x[i] + d * alpha;
                    self.tht[i] = self.s.theta[i] + self.dx[4 * i + 3] * alpha;
                }
                let want = if trial == 0 { first } else { Have::Geometry };
                let e1 = self.eval_at(lumen, true, want >= Have::Gradient, want == Have::Hessian);
                rep.evaluations += 1;
                have = want;
                e_cur = e1;
                if e1.is_finite() && e1 <= e0 + 1e-4 * (alpha / scale) * slope.min(0.0) + 1e-12 * e0.abs() {
                    accepted = true;
                    break;
                }
                // The energy rose, and along the last shorter trial it rose
                // at least half as steeply: along a smooth descent
                // direction the secant's slope (e₁ − e₀)/α falls by more
                // than half when α is cut to at most half. It did not: the
                // energy has a kink here (a node over the ridge between
                // two facets of the wall, whose distance is the smaller of
                // two), and no shorter step will do better.
                let secant = (e1 - e0) / alpha;
                if trial > 0 && e1 > e0 && secant >= 0.5 * last_secant {
                    break;
                }
                last_secant = secant;
                // Backtrack to the minimiser of the quadratic through e0,
                // the slope and e1, within [0.1, 0.5] of the last trial (a
                // contact or friction switching on along the step wants a
                // much shorter one than halving finds in one trial).
                let d = slope / scale;
                let c = e1 - e0 - d * alpha;
                alpha = if e1.is_finite() && d < 0.0 && c > 0.0 {
                    (-d * alpha * alpha / (2.0 * c)).clamp(0.1 * alpha, 0.5 * alpha)
                } else {
                    0.5 * alpha
                };
            }
            rep.iterations = it + 1;
            if !accepted {
                for i in 0..n {
                    self.xt[i] = self.s.x[i];
                    self.tht[i] = self.s.theta[i];
                }
                have = Have::Nothing;
                break;
            }
            // Accept, and carry the reference frames to the new iterate: the
            // bend gradient below is exact where the frames were transported
            // from, so each iteration's gradient is exact. (The frames
            // transported to themselves are unchanged, so the geometry, and
            // what the trial assembled, stay those of the new iterate.)
            for i in 0..n {
                self.s.x[i] = self.xt[i];
                self.s.theta[i] = self.tht[i];
                self.d10[i] = self.d1c[i];
                self.t0[i] = self.tan[i];
                self.rt0[i] = self.rt[i];
                self.rt0_sc[i] = sin_cos_near(self.rt0[i], &mut self.rt_near[i]);
            }
            rep.last_update = alpha * mx.max(mt);
            if alpha * mx < 1e-10 && alpha * mt < 1e-8 {
                break;
            }
        }
        // Final geometry, reactions and contacts at the accepted state.
        if have < Have::Gradient {
            rep.evaluations += 1;
            self.eval_at(lumen, have == Have::Nothing, true, false);
        }
        self.reactions();
        let dt = self.p.dt_s;
        for i in 0..n {
            self.s.v[i] = (self.s.x[i] - self.x0[i]) / dt;
            self.s.ref_twist[i] = self.rt[i];
        }
        for j in 0..n - 1 {
            self.s.d1[j] = self.d1c[j];
        }
        self.s.v[0] = Vec3::zeros();
        self.s.v[1] = Vec3::zeros();
        // Off equilibrium, the hub edge holds what node 2 leaves unbalanced
        // along it: a feed the step did not carry into the wire, not a load.
        // The hub keeps it for the next step (docs/INSTRUMENTS.md "Why the
        // wire reaches the grip's limit").
        let (t1, k1) = (self.tan[1], self.coef[1].stretch);
        let g2 = Vec3::new(self.grad[8], self.grad[9], self.grad[10]).dot(&t1);
        let st = self.len[1] - self.s.rest[1];
        let f1 = (k1 * st).clamp(-self.p.max_hub_force_n, self.p.max_hub_force_n);
        if n >= 3 && g2.abs() > self.settled_tolerance() && g2 * f1 > 0.0 {
            rep.grip_slipped |= (k1 * st).abs() > self.p.max_hub_force_n;
            let df = g2.signum() * g2.abs().min(f1.abs());
            self.set_hub_rest(self.len[1] - (f1 - df) / k1);
            self.hub_grad += t1 * df;
            for c in 0..3 {
                self.grad[8 + c] -= t1[c] * df;
            }
        }
        let hub_force = -self.hub_grad;
        rep.hub_axial_force_n = -hub_force.dot(&self.axis);
        rep.hub_torque_nm = -self.hub_dtheta;
        self.last_axial = rep.hub_axial_force_n;
        // The grip slipped: the hub edge keeps the length it can hold.
        let k1 = self.p.youngs_modulus_pa * self.p.area() / self.s.rest[1];
        let st = self.len[1] - self.s.rest[1];
        if (k1 * st).abs() > self.p.max_hub_force_n {
            let rest = self.len[1] + st.signum() * -self.p.max_hub_force_n / k1;
            self.set_hub_rest(rest);
            rep.grip_slipped = true;
        }
        rep.residual_n = (2..n)
            .map(|i| Vec3::new(self.grad[4 * i], self.grad[4 * i + 1], self.grad[4 * i + 2]).norm())
            .fold(0.0, f64::max);
        self.last_residual = rep.residual_n;
        rep.contacts = self.contacts.len();
        rep.max_penetration_m = self.contacts.iter().map(|c| c.penetration).fold(0.0, f64::max);
        rep.sheath_contacts = self.cx.sheath_contacts.len();
        rep.max_sheath_penetration_m = self
            .cx
            .sheath_contacts
            .iter()
            .map(|c| c.penetration)
            .fold(0.0, f64::max);
        if !self.s.is_finite() || !rep.hub_axial_force_n.is_finite() {
            return Err(WireFault::NonFinite);
        }
        Ok(rep)
    }

    /// Gives the hub edge the rest length `rest` (at least a quarter
    /// segment): the inserted length and the hub's material coordinates
    /// follow, the free nodes stay (the grip slipping, or a feed the step
    /// did not carry handed back).
    fn set_hub_rest(&mut self, rest: f64) {
        let rest = rest.max(0.25 * self.p.segment_length_m);
        self.s.rest[1] = rest;
        self.s.inserted = self.s.u[2] + rest;
        self.s.u[1] = self.s.inserted;
        self.s.u[0] = self.s.inserted + self.p.segment_length_m;
    }

    /// The buckling check at the step's start, with the incremental
    /// potential's gradient and Hessian assembled there (`grad`, `h`, its
    /// energy `e0`): true if it evaluated trials, so the buffers no longer
    /// hold the start's evaluation (`StepReport::buckled` says whether the
    /// wire moved off a saddle of its static energy).
    ///
    /// Why: a straight column loaded past its Euler load is a saddle of
    /// its potential energy, and a perfect one stays on it (its lateral
    /// gradient is zero, and the step's Hessian cannot show the saddle: it
    /// drops the compressive stretch's geometric stiffness to stay
    /// positive, and its inertia ρA/dt² outweighs the negative curvature
    /// of a long span). The wire then builds force at the hub until
    /// rounding lets it buckle, at several times the Euler load. Here the
    /// static Hessian, the step's less its inertia and drag plus every
    /// compressed edge's geometric stiffness (f/|e|)(I − t tᵀ), f < 0, is
    /// factored L D Lᵀ without requiring positive pivots
    /// (`BandMatrix::factor_indefinite`); a negative pivot d_k gives the
    /// direction v, Lᵀ v = e_k, of negative curvature vᵀ H v = d_k. The
    /// wire moves along ±v (downhill, the step's cap on node moves and
    /// twists, halved until the static energy falls by at least half what
    /// its quadratic model predicts and no node goes deeper into the wall
    /// than at the start or a tenth of its radius; at most four trials).
    /// Only a wire that settled in the last step is checked. The move
    /// shifts the step's start and inertial target with it: it is a
    /// change of state that lowers the potential energy and adds no
    /// kinetic energy, the perturbation that a real wire's imperfections
    /// supply. Nothing allocates: `hs` and `dv` are sized at construction.
    fn buckle(&mut self, lumen: &dyn Lumen, e0: f64, rep: &mut StepReport) -> bool {
        let n = self.s.n;
        let dofs = 4 * n;
        if !self.may_buckle() {
            return false;
        }
        // The static Hessian and gradient from the step's.
        self.hs.copy_from(&self.h);
        let mut inertia_energy = 0.0;
        for i in 2..n {
            let (km, kd) = (self.coef[i].mass, self.coef[i].drag);
            for c in 0..3 {
                self.hs.add(4 * i + c, 4 * i + c, -(km + kd));
            }
            let a = self.s.x[i] - self.xtilde[i];
            let b = self.s.x[i] - self.x0[i];
            inertia_energy += 0.5 * km * a.norm_squared() + 0.5 * kd * b.norm_squared();
        }
        for j in 1..n - 1 {
            let kt = self.coef[j].twist_mass;
            self.hs.add(4 * j + 3, 4 * j + 3, -kt);
            let d = self.s.theta[j] - self.th0[j];
            inertia_energy += 0.5 * kt * d * d;
        }
        // Friction is not a potential of the static problem: its stick
        // stiffness would pin every contact and make any compressed span
        // between two contacts look like a column to buckle. It enters the
        // move's energy instead, as the work to slip the contacts.
        for i in 2..n {
            let (hf, h_xs, h_ss) = self.fric_h[i];
            if h_ss == 0.0 && hf == Mat3::zeros() {
                continue;
            }
            let ts = 4 * Self::contact_edge(i, n) + 3;
            for r in 0..3 {
                for c in 0..=r {
                    self.hs.add(4 * i + r, 4 * i + c, -hf[(r, c)]);
                }
                if h_ss > 0.0 {
                    self.hs.add(4 * i + r, ts, -h_xs[r]);
                }
            }
            if h_ss > 0.0 {
                self.hs.add(ts, ts, -h_ss);
            }
        }
        let mut compressed = false;
        // Node j + 1's bend, kept for edge j + 1 (whose node j + 1 it is).
        let mut next_off: Option<(usize, f64)> = None;
        for j in 1..n - 1 {
            let Some(force) = self.buckling_edge_force(j, &mut next_off) else {
                continue;
            };
            compressed = true;
            let geo = force * self.inv_len[j];
            let t = self.tan[j];
            for r in 0..3 {
                for c in 0..=r {
                    let b = geo * (if r == c { 1.0 } else { 0.0 } - t[r] * t[c]);
                    // Node j + 1's block, and node j's and the coupling
                    // unless node j is the clamped hub.
                    self.hs.add(4 * (j + 1) + r, 4 * (j + 1) + c, b);
                    if j >= 2 {
                        self.hs.add(4 * j + r, 4 * j + c, b);
                        self.hs.add(4 * (j + 1) + r, 4 * j + c, -b);
                        if r != c {
                            self.hs.add(4 * (j + 1) + c, 4 * j + r, -b);
                        }
                    }
                }
            }
        }
        if !compressed {
            return false;
        }
        rep.buckling_checked = true;
        let Ok(Some((k, d))) = self.hs.factor_indefinite() else {
            return false;
        };
        self.hs.unit_back_solve(k, &mut self.dv[..dofs]);
        // Downhill for the static energy (whose gradient is the step's
        // less the inertia's), within the step's cap.
        let mut slope = 0.0;
        let (mut mx, mut mt): (f64, f64) = (0.0, 0.0);
        for i in 0..n {
            let mut g = Vec3::new(self.grad[4 * i], self.grad[4 * i + 1], self.grad[4 * i + 2]);
            if i >= 2 {
                let (km, kd) = (self.coef[i].mass, self.coef[i].drag);
                g -= (self.s.x[i] - self.xtilde[i]) * km + (self.s.x[i] - self.x0[i]) * kd;
            }
            let v = Vec3::new(self.dv[4 * i], self.dv[4 * i + 1], self.dv[4 * i + 2]);
            let mut gt = self.grad[4 * i + 3];
            if i >= 1 && i < n - 1 {
                gt -= self.coef[i].twist_mass * (self.s.theta[i] - self.th0[i]);
            }
            slope += g.dot(&v) + gt * self.dv[4 * i + 3];
            mx = mx.max(v.norm());
            mt = mt.max(self.dv[4 * i + 3].abs());
        }
        let cap = (0.5 * self.p.diameter_m * 0.5 / mx.max(1e-300)).min(0.5 / mt.max(1e-300));
        if !(cap.is_finite() && cap > 0.0) {
            return false;
        }
        let sign = if slope > 0.0 { -1.0 } else { 1.0 };
        let (slope, curv) = (-slope.abs(), d);
        // The static energy at the start: the step's less its inertia's.
        let v0 = e0 - inertia_energy;
        // No deeper into the wall than the start (or a tenth of the radius).
        let pen_max = self.eval_pen.max(0.05 * self.p.diameter_m);
        let mut alpha = cap;
        let mut tried = false;
        for _ in 0..4 {
            if rep.evaluations + 4 > self.p.max_evaluations {
                break;
            }
            tried = true;
            rep.evaluations += 1;
            let v1 = self.eval_energy_static(lumen, alpha, sign);
            let model = alpha * slope + 0.5 * alpha * alpha * curv;
            if v1.is_finite() && v1 - v0 <= 0.5 * model && self.eval_pen <= pen_max {
                // Move the state, the step's start and its inertial target
                // together; frames re-based as for an accepted iterate.
                for i in 0..n {
                    let dxi = self.xt[i] - self.s.x[i];
                    self.s.x[i] = self.xt[i];
                    self.x0[i] += dxi;
                    self.xtilde[i] += dxi;
                    let dth = self.tht[i] - self.s.theta[i];
                    self.s.theta[i] = self.tht[i];
                    self.th0[i] += dth;
                    self.d10[i] = self.d1c[i];
                    self.t0[i] = self.tan[i];
                    self.rt0[i] = self.rt[i];
                    self.rt0_sc[i] = sin_cos_near(self.rt0[i], &mut self.rt_near[i]);
                }
                rep.buckled = true;
                return true;
            }
            alpha *= 0.5;
        }
        // Back to the step's start (the caller evaluates it again if a
        // trial overwrote its geometry).
        for i in 0..n {
            self.xt[i] = self.s.x[i];
            self.tht[i] = self.s.theta[i];
        }
        tried
    }

    /// Whether the buckling check's static Hessian could have negative
    /// curvature, by the bound of its bending alone (cheap, O(n)): false
    /// when no edge is compressed and nearly unbent, or when even
    /// [`BUCKLING_GATE_MARGIN`] times their compression could not bow the
    /// wire against its bending stiffness.
    ///
    /// Why: the check's indefinite factorisation cost about a tenth of a
    /// wall-loaded step, and it ran on every step of a wire that rests
    /// pushed against the wall (3000 of 3000 in the tick bench, none of
    /// which moved). The bound: the static Hessian is its compressed
    /// edges' geometric stiffness added to terms that are each positive
    /// semi-definite (stretch, twist, contact, loads; the Gauss–Newton
    /// bend). Of those, the bend alone, on a nearly straight wire, is
    /// Σᵢ Bᵢ |uᵢ − uᵢ₋₁|² in the edges' changes of direction u_j
    /// (B the nodes' EI / l̄, u₀ = 0 at the clamp), and the geometric term
    /// of a compressed edge of force −P_j is −P_j ℓ_j |u_j|². So if the
    /// tridiagonal matrix of the first less the second (each P_j times
    /// the margin) is positive definite, so is the static Hessian, and
    /// the check would find no saddle: the discrete form of Euler's load
    /// π² EI / (4 L²) of the clamped, otherwise free, column, with the
    /// compression where it acts. The margin covers what the bound
    /// neglects: the bend's Gauss–Newton form on a wire bent within
    /// [`BUCKLING_BEND_OFF`] of its rest shape, and its coupling to the
    /// twist there. A check the bound skips would have returned without
    /// trials, leaving the step's evaluation as it was: the step is the
    /// same, bit for bit.
    fn may_buckle(&self) -> bool {
        let n = self.s.n;
        let mut next_off: Option<(usize, f64)> = None;
        let mut compressed = false;
        // L D Lᵀ of the tridiagonal over edges 1..=n − 2; `prev` the last
        // pivot (∞ before edge 1: u₀ is clamped).
        let mut prev = f64::INFINITY;
        for j in 1..n - 1 {
            let geo = match self.buckling_edge_force(j, &mut next_off) {
                Some(force) => {
                    compressed = true;
                    -force * BUCKLING_GATE_MARGIN * self.len[j]
                }
                None => 0.0,
            };
            let bj = self.coef[j].bend;
            let next = if j + 1 < n - 1 { self.coef[j + 1].bend } else { 0.0 };
            let d = bj + next - geo - bj * bj / prev;
            if !(d > 0.0 && d.is_finite()) {
                return compressed || (j + 1..n - 1).any(|k| self.buckling_edge_force(k, &mut next_off).is_some());
            }
            prev = d;
        }
        false
    }

    /// Edge j's force (N, negative) if the buckling check adds its
    /// geometric stiffness: compressed (the hub edge's force capped at
    /// the grip's limit), with the bends at both its ends within
    /// [`BUCKLING_BEND_OFF`] of their rest (the Gauss–Newton bend Hessian
    /// leaves out terms of that size, so only where it is small is the
    /// static Hessian accurate enough to tell a saddle). `next_off` keeps
    /// node j + 1's bend for edge j + 1 (call in increasing j).
    fn buckling_edge_force(&self, j: usize, next_off: &mut Option<(usize, f64)>) -> Option<f64> {
        let k = self.coef[j].stretch;
        let st = self.len[j] - self.s.rest[j];
        let f_grip = self.p.max_hub_force_n;
        let force = if j == 1 && (k * st).abs() > f_grip {
            f_grip * st.signum()
        } else {
            k * st
        };
        if force >= 0.0 {
            return None;
        }
        let off_j = match *next_off {
            Some((i, v)) if i == j => v,
            _ => self.bend_off(j),
        };
        let off_next = self.bend_off(j + 1);
        *next_off = Some((j + 1, off_next));
        if off_j.max(off_next) > BUCKLING_BEND_OFF {
            return None;
        }
        Some(force)
    }

    /// How far node i's bend is from its rest (material curvature, about
    /// the turning angle per segment); 0 at the ends.
    fn bend_off(&self, i: usize) -> f64 {
        let n = self.s.n;
        if i == 0 || i + 1 >= n {
            return 0.0;
        }
        let (te, tf) = (self.tan[i - 1], self.tan[i]);
        let kb = te.cross(&tf) * (2.0 / (1.0 + te.dot(&tf)).max(1e-12));
        let k1 = 0.5 * kb.dot(&(self.m2[i - 1] + self.m2[i]));
        let k2 = -0.5 * kb.dot(&(self.m1[i - 1] + self.m1[i]));
        ((k1 - self.coef[i].kb_rest).powi(2) + k2 * k2).sqrt()
    }

    /// The static potential (no inertia or drag) at the state moved by
    /// `sign · alpha · dv`, left in `xt`, `tht` and their geometry.
    fn eval_energy_static(&mut self, lumen: &dyn Lumen, alpha: f64, sign: f64) -> f64 {
        let n = self.s.n;
        for i in 0..n {
            let d = Vec3::new(self.dv[4 * i], self.dv[4 * i + 1], self.dv[4 * i + 2]);
            self.xt[i] = self.s.x[i] + d * (sign * alpha);
            self.tht[i] = self.s.theta[i] + self.dv[4 * i + 3] * (sign * alpha);
        }
        self.statics = true;
        let e = self.eval_at(lumen, true, false, false);
        self.statics = false;
        e
    }

    /// The Newton update's largest node move (m) and twist change (rad).
    fn update_size(&self) -> (f64, f64) {
        let (mut mx, mut mt): (f64, f64) = (0.0, 0.0);
        for i in 0..self.s.n {
            let d = Vec3::new(self.dx[4 * i], self.dx[4 * i + 1], self.dx[4 * i + 2]);
            mx = mx.max(d.norm());
            mt = mt.max(self.dx[4 * i + 3].abs());
        }
        (mx, mt)
    }

    /// Adds a Levenberg–Marquardt damping to the assembled Hessian `h`: on
    /// every free node's translation, the largest net force on a free node
    /// over `cap` (m); on every free twist, the largest twist gradient over
    /// half a radian (the twist's cap). A mode whose model stiffness is
    /// below the damping then moves by at most about the cap, while a mode
    /// much stiffer (a node in the wall, a stuck contact) takes its full
    /// Newton update. Used on an update the cap would scale below
    /// [`TRUST_REGION_BELOW`].
    ///
    /// Why: a contact slipping beyond friction's smoothing has no model
    /// stiffness along its slip (Coulomb's cone is flat there), and a
    /// floppy wire crumpled in a tube (E = 1 MPa: ρA/dt² ≈ 8 N/m a node,
    /// bending less) has almost none either. The update then moved such
    /// a node by tens of millimetres, and the cap scaled the whole update
    /// by 1/200, so a node deep in the wall, whose own update was right,
    /// came out by 1/200 of it an iteration. Steps ended unconverged, and
    /// over hundreds of them the node went 0.28 mm deep against 300 N of
    /// unbalanced penalty (docs/WIRE.md "A trust region for the capped
    /// update").
    fn damp_hessian(&mut self, cap: f64) {
        let n = self.s.n;
        let (mut gx, mut gt): (f64, f64) = (0.0, 0.0);
        for i in 2..n {
            gx = gx.max(Vec3::new(self.grad[4 * i], self.grad[4 * i + 1], self.grad[4 * i + 2]).norm());
        }
        for j in 1..n - 1 {
            gt = gt.max(self.grad[4 * j + 3].abs());
        }
        let (lx, lt) = (gx / cap, gt / 0.5);
        for i in 2..n {
            for c in 0..3 {
                self.h.add(4 * i + c, 4 * i + c, lx);
            }
        }
        for j in 1..n - 1 {
            self.h.add(4 * j + 3, 4 * j + 3, lt);
        }
    }

    /// The Newton update `dx = −H⁻¹ g` from the assembled gradient and
    /// Hessian (`h`, left factored), with the grip's state chosen where
    /// the update lands: false if the Hessian could not be factored.
    ///
    /// Why: the hub edge's Huber energy is quadratic (stiffness
    /// k = EA/ē ≈ 10⁷–10⁸ N/m) while the grip holds and linear once its
    /// force passes the grip's limit. Assembled where the grip slips, its
    /// Hessian has no axial stiffness, so the Newton model lets the whole
    /// wire slide through the hand: in the arch it predicted the wire to
    /// swing by 2–3 mm while the true minimum lay a fraction of a
    /// micrometre away, where the grip holds again; every such update was
    /// capped and the line search backtracked four or five times (a third
    /// of all iterations on the wall-loaded arch). The model here is the
    /// piecewise one: the edge's stretch st is linearised (st + t·δx₂),
    /// its energy kept piecewise (stick, or slip on either side), and the
    /// piece the update lands in is the one assembled (a one-dimensional
    /// active set). Changing the piece changes H by a rank-one term
    /// Δk t tᵀ on node 2 and the gradient along t, so one more solve
    /// z = H⁻¹ u (u: t at node 2) gives every candidate update in closed
    /// form (Sherman–Morrison): x = dx + c z − Δk w z, where c is the
    /// force's change and w = (u·dx + c u·z) / (1 + Δk u·z) the edge's
    /// predicted stretch change. The Huber energy is convex in st, so the
    /// consistent piece's update minimises a convex model whose gradient
    /// at the iterate is the true one: a descent direction.
    ///
    /// The piece assembled is the holding grip's, whatever the iterate's:
    /// its solve is the update whenever the grip holds after it, which is
    /// nearly always (a push that starts from the unmoved wire begins past
    /// the grip's limit by its feed, which the update relaxes). Assembled
    /// at the iterate's piece instead, 42 % of the tick bench's Newton
    /// updates took the second solve (docs/WIRE.md "The grip in the Newton
    /// model").
    fn newton_direction(&mut self) -> bool {
        let n = self.s.n;
        let dofs = 4 * n;
        if self.h.factor().is_err() {
            return false;
        }
        for k in 0..dofs {
            self.dx[k] = -self.grad[k];
        }
        if n < 3 {
            self.h.solve(&mut self.dx[..dofs]);
            return true;
        }
        let f_grip = self.p.max_hub_force_n;
        let k1 = self.coef[1].stretch;
        let st0 = self.len[1] - self.s.rest[1];
        let t = self.tan[1];
        let slip0 = (k1 * st0).abs() > f_grip;
        // The grip's piece: its force at the iterate and axial stiffness.
        let piece = |slip: bool, side: f64| if slip { (f_grip * side, 0.0) } else { (k1 * st0, k1) };
        // The Hessian holds the holding grip's piece (`eval_at`), the
        // likely one after the update: a feed left in the hub edge starts
        // the step past the grip's limit, and the update relaxes it. Its
        // model's gradient differs from the true one by the change of the
        // edge's force along t at node 2.
        let f_true = piece(slip0, st0.signum()).0;
        let (f0, ka0) = piece(false, 0.0);
        for c in 0..3 {
            self.dx[8 + c] -= (f0 - f_true) * t[c];
        }
        self.h.solve(&mut self.dx[..dofs]);
        let fits = |slip: bool, side: f64, st1: f64| {
            let s1 = (k1 * st1).abs() > f_grip;
            s1 == slip && (!slip || st1.signum() == side)
        };
        let a = t.dot(&Vec3::new(self.dx[8], self.dx[9], self.dx[10]));
        if fits(false, 0.0, st0 + a) {
            return true;
        }
        self.dz[..dofs].fill(0.0);
        self.dz[8..11].copy_from_slice(t.as_slice());
        self.h.solve(&mut self.dz[..dofs]);
        let b = t.dot(&Vec3::new(self.dz[8], self.dz[9], self.dz[10]));
        // Holding, the update lands past the grip's limit: slip on that
        // side, and from there the pieces in turn.
        let (mut slip, mut side) = (true, (st0 + a).signum());
        for _ in 0..3 {
            let (f1, ka1) = piece(slip, side);
            let (c, dk) = (f0 - f1, ka1 - ka0);
            let den = 1.0 + dk * b;
            if den.is_nan() || den <= 1e-12 {
                break;
            }
            let w = (a + c * b) / den;
            let st1 = st0 + w;
            if fits(slip, side, st1) {
                let m = c - dk * w;
                for k in 0..dofs {
                    self.dx[k] += m * self.dz[k];
                }
                return true;
            }
            if slip {
                (slip, side) = (false, 0.0);
            } else {
                (slip, side) = (true, st1.signum());
            }
        }
        true
    }

    /// The Newton iterations' starting point after `fed` metres entered
    /// (or left, if negative) at the hub, for a wire off equilibrium: every
    /// free node slides by `fed` along the wire's own centreline, toward
    /// the tip (the tip along its last edge). On pull-back nothing slides:
    /// the hub edge takes the feed (the body says why; docs/WIRE.md
    /// "Friction's smoothing" what made fast pull-backs converge). After a
    /// step that ended at equilibrium nothing slides either: the grip's
    /// piecewise Newton model takes the feed left in the hub edge in one
    /// solve, and the slide's start biased steps that two iterations did
    /// not finish (docs/WIRE.md "Pushes start from the unmoved wire once
    /// it has settled").
    ///
    /// Why it slides a wire off equilibrium: the feed lengthens the hub
    /// edge's rest length, and the nearly inextensible wire (EA/h ≈ 10⁷
    /// N/m) must follow within a micrometre. Started from the unmoved
    /// nodes, the hub edge begins the step compressed by the whole feed
    /// (0.1 mm: ~10³ N), far beyond the grip's limit; where the updates
    /// are capped (the wire far from equilibrium, as a straight-laid
    /// pre-shaped tip springing into shape), the cap scales down the hub
    /// edge's share of the update too, and the step ends with the hub force
    /// near the grip's limit although nothing resists. (Before the grip's
    /// piecewise Newton model, every push did.) Sliding the wire along
    /// itself keeps every edge's length to second order in the turning
    /// angle, so the step starts near equilibrium, in the stiff regime,
    /// and converges there; the slide is part of the step's motion, so
    /// inertia and friction see it. A tip against the wall slides along
    /// it; a tip heading into the wall (a dead end) blocks the slide: the
    /// feed stays in the hub edge, where the grip caps the force. A feed
    /// of at most [`SLIDE_MIN_FEED_SMOOTHINGS`] friction smoothings slides
    /// nothing (docs/WIRE.md "Slow pushes start from the unmoved wire").
    fn slide(&mut self, fed: f64, lumen: &dyn Lumen) {
        let n = self.s.n;
        // Pulling back stretches the hub edge instead: the grip does not
        // cap a pull, so Newton stays in the stiff regime and converges
        // from the unmoved nodes (sliding them back along the bent wire
        // cut the inside of a bend: tests/wire_capstan_matches_euler_eytelwein.rs).
        // A slow push (see SLIDE_MIN_FEED_SMOOTHINGS), and any push after a
        // step that ended at equilibrium, start from the unmoved nodes too.
        let settled = self.last_residual <= self.settled_tolerance();
        if settled || fed <= SLIDE_MIN_FEED_SMOOTHINGS * self.p.friction_smoothing_m || n < 3 {
            return;
        }
        let x = &mut self.s.x;
        {
            // The tip leaves the centreline, along its last edge. Against
            // the wall it slides along the wall (its component into the
            // wall dropped); heading into the wall more steeply than 30°
            // off the wall's plane, the wire's front is blocked: nothing
            // slides, the feed stays in the hub edge, whose force the grip
            // caps (a steel wire rammed into a dead end).
            let (a, b) = (x[n - 2], x[n - 1]);
            let l = (b - a).norm();
            let mut tip_dir = if l > 1e-12 { (b - a) / l } else { Vec3::zeros() };
            let r_w = 0.5 * self.p.diameter_m;
            if let Some(hit) = lumen.probe(b + tip_dir * fed, 3.0 * r_w) {
                if hit.distance <= r_w {
                    let dn = tip_dir.dot(&hit.normal);
                    if dn < -0.5 {
                        return;
                    }
                    tip_dir -= hit.normal * dn.min(0.0);
                }
            }
            // Toward the tip: node i along edge i (its old end, not yet moved).
            for i in 2..n {
                let dir = if i + 1 < n {
                    let e = x[i + 1] - x[i];
                    let l = e.norm();
                    if l > 1e-12 {
                        e / l
                    } else {
                        tip_dir
                    }
                } else {
                    tip_dir
                };
                x[i] += dir * fed;
            }
        }
        for i in 2..n {
            self.xt[i] = self.s.x[i];
        }
    }

    /// Frames, curvature and twist at the trial state.
    ///
    /// `LANES` edges (then nodes) at a time, each lane the scalar code's
    /// operations in its order (the same bits; a lane off the fast path of
    /// `transport`, `sin_cos_near` or `signed_angle` takes the scalar
    /// function), the rest one by one: the scalar loop is bound by its
    /// arithmetic (about 230 operations a node), which vector registers
    /// do `LANES` at once.
    fn geometry(&mut self) {
        let n = self.s.n;
        let edges = n - 1;
        let mut j = 0;
        while j + LANES <= edges {
            let e = Lv::<LANES>::load(&self.xt, j + 1).sub(&Lv::<LANES>::load(&self.xt, j));
            let ee = e.dot(&e);
            let l: [f64; LANES] = lmap(|k| ee[k].sqrt());
            let il: [f64; LANES] = lmap(|k| 1.0 / l[k]);
            self.len[j..j + LANES].copy_from_slice(&l);
            self.inv_len[j..j + LANES].copy_from_slice(&il);
            let t = e.scale(&il);
            t.store(&mut self.tan, j);
            let d1 = transport_lanes(&Lv::<LANES>::load(&self.d10, j), &Lv::<LANES>::load(&self.t0, j), &t);
            d1.store(&mut self.d1c, j);
            let d2 = t.cross(&d1);
            let (sn, cs) = sin_cos_near_lanes::<LANES>(&self.tht[j..j + LANES], &mut self.th_near[j..j + LANES]);
            d1.scale(&cs).add(&d2.scale(&sn)).store(&mut self.m1, j);
            d1.neg().scale(&sn).add(&d2.scale(&cs)).store(&mut self.m2, j);
            j += LANES;
        }
        for j in j..edges {
            let e = self.xt[j + 1] - self.xt[j];
            let l = e.norm();
            let il = 1.0 / l;
            self.len[j] = l;
            self.inv_len[j] = il;
            self.tan[j] = e * il;
            self.d1c[j] = transport(self.d10[j], self.t0[j], self.tan[j]);
            let d2 = self.tan[j].cross(&self.d1c[j]);
            let (sn, cs) = sin_cos_near(self.tht[j], &mut self.th_near[j]);
            self.m1[j] = self.d1c[j] * cs + d2 * sn;
            self.m2[j] = -self.d1c[j] * sn + d2 * cs;
        }
        let mut i = 1;
        while i + LANES < n {
            let (te, tf) = (Lv::<LANES>::load(&self.tan, i - 1), Lv::<LANES>::load(&self.tan, i));
            let ut = transport_lanes(&Lv::<LANES>::load(&self.d1c, i - 1), &te, &tf);
            let sc = &self.rt0_sc[i..i + LANES];
            let (sn, cs): ([f64; LANES], [f64; LANES]) = (lmap(|k| sc[k].0), lmap(|k| sc[k].1));
            // rotate_sc(ut, tf, sn, cs).
            let ad = tf.dot(&ut);
            let omc: [f64; LANES] = lmap(|k| 1.0 - cs[k]);
            let ut = ut
                .scale(&cs)
                .add(&tf.cross(&ut).scale(&sn))
                .add(&tf.scale(&ad).scale(&omc));
            let ang = signed_angle_lanes(&ut, &Lv::<LANES>::load(&self.d1c, i), &tf);
            for ((rt, rt0), a) in self.rt[i..i + LANES].iter_mut().zip(&self.rt0[i..i + LANES]).zip(&ang) {
                *rt = rt0 + a;
            }
            i += LANES;
        }
        for i in i..n - 1 {
            let ut = transport(self.d1c[i - 1], self.tan[i - 1], self.tan[i]);
            let (sn, cs) = self.rt0_sc[i];
            let ut = rotate_sc(ut, self.tan[i], sn, cs);
            self.rt[i] = self.rt0[i] + signed_angle(ut, self.d1c[i], self.tan[i]);
        }
    }

    /// Makes the next evaluation probe the lumen at every node.
    ///
    /// Why: the wall's distance changes by at most as much as the point
    /// it is seen from moves (a distance to a fixed set), so a node that
    /// an earlier evaluation of this step found at least D from the wall
    /// (D: the probe's range when nothing was within it) and that has
    /// moved by δ since is at least D − δ from it now. Where that is
    /// beyond the penalty's reach (the radius plus the onset) the probe
    /// cannot change the evaluation, and the later evaluations of a step
    /// (its line searches' trials, micrometres apart) skip it; a third
    /// of a step's time went to probes, most of them for nodes clear of
    /// the wall. The bound holds for one lumen only: a step (whose lumen
    /// is fixed) starts by forgetting it. The continuation of a wall's
    /// opening, whose distance jumps where its plane is crossed, is
    /// always probed again.
    fn forget_probes(&mut self) {
        self.probe_clear.fill(f64::NEG_INFINITY);
    }

    /// The incremental potential at the trial state (`xt`, `tht`); with
    /// `assemble`, also its gradient (`grad`) and a positive semi-definite
    /// approximation of its Hessian (`h`: exact stretch with the compressive
    /// geometric term dropped, Gauss–Newton bend and twist, exact contact
    /// normal and friction terms), fixed unknowns pinned.
    fn eval(&mut self, lumen: &dyn Lumen, assemble: bool) -> f64 {
        self.eval_at(lumen, true, assemble, assemble)
    }

    /// [`Wire::eval`] with the geometry (`geometry`: false when the frames
    /// already are those of `xt`, `tht`), the gradient (`grad`) and the
    /// Hessian (`hess`, only with `grad`) chosen separately. Every node's
    /// wall probe is kept in `hits`.
    #[allow(clippy::needless_range_loop)] // each term reads several per-node arrays
    fn eval_at(&mut self, lumen: &dyn Lumen, geometry: bool, assemble: bool, hess: bool) -> f64 {
        if geometry {
            self.geometry();
        }
        let n = self.s.n;
        let dofs = 4 * n;
        if assemble {
            self.grad[..dofs].fill(0.0);
        }
        if hess {
            self.h.reset(dofs);
        }
        let p = &self.p;
        let r_w = 0.5 * p.diameter_m;
        let kc = p.contact_stiffness_n_per_m;
        let mu = p.friction;
        let eps_v = p.friction_smoothing_m;
        let s = &self.s;
        let coef = &self.coef[..n];
        let onset = p.contact_onset_m;
        let mut energy = 0.0;
        let mut max_pen: f64 = 0.0;

        // Inertia and drag (free nodes), twist inertia (free edges); none in
        // the static potential (the buckling check's).
        let dynamic = if self.statics { 0 } else { n };
        for i in 2..dynamic {
            let (km, kd) = (coef[i].mass, coef[i].drag);
            let a = self.xt[i] - self.xtilde[i];
            let b = self.xt[i] - self.x0[i];
            energy += 0.5 * km * a.norm_squared() + 0.5 * kd * b.norm_squared();
            if assemble {
                let g = a * km + b * kd;
                for c in 0..3 {
                    self.grad[4 * i + c] += g[c];
                    if hess {
                        self.h.add(4 * i + c, 4 * i + c, km + kd);
                    }
                }
            }
        }
        for j in 1..dynamic.saturating_sub(1) {
            let kt = coef[j].twist_mass;
            let d = self.tht[j] - self.th0[j];
            energy += 0.5 * kt * d * d;
            if assemble {
                self.grad[4 * j + 3] += kt * d;
                if hess {
                    self.h.add(4 * j + 3, 4 * j + 3, kt);
                }
            }
        }

        // Stretch (edge 0 joins two fixed nodes: constant). The hub edge
        // passes through the grip: its force is capped at the grip's limit
        // (a Huber energy), beyond which the wire slips in the hand.
        let f_grip = p.max_hub_force_n;
        for j in 1..n - 1 {
            let k = coef[j].stretch;
            let st = self.len[j] - s.rest[j];
            let slipping = j == 1 && (k * st).abs() > f_grip;
            // The Hessian keeps the holding grip's axial stiffness k where
            // it slips too (`Wire::newton_direction` chooses the piece).
            let force = if slipping {
                energy += f_grip * st.abs() - 0.5 * f_grip * f_grip / k;
                f_grip * st.signum()
            } else {
                energy += 0.5 * k * st * st;
                k * st
            };
            if assemble {
                let t = self.tan[j];
                let g = t * force;
                for c in 0..3 {
                    self.grad[4 * (j + 1) + c] += g[c];
                    self.grad[4 * j + c] -= g[c];
                }
                if !hess {
                    continue;
                }
                let geo = (force * self.inv_len[j]).max(0.0);
                let kt = k - geo;
                let mut km = [[0.0; 3]; 3];
                for (r, row) in km.iter_mut().enumerate() {
                    for (c, v) in row.iter_mut().enumerate() {
                        *v = t[r] * t[c] * kt + if r == c { geo } else { 0.0 };
                    }
                }
                self.h.add_spring3(4 * j, 4 * (j + 1), &km);
            }
        }

        // Bend and twist at interior nodes 1..n−2.
        for i in 1..n - 1 {
            let Coef {
                bend,
                twist,
                kb_rest,
                kb_rest2,
                ..
            } = coef[i];
            let (te, tf) = (self.tan[i - 1], self.tan[i]);
            let chi = (1.0 + te.dot(&tf)).max(1e-12);
            let ichi = 1.0 / chi;
            let kb = te.cross(&tf) * (2.0 * ichi);
            let (m1e, m1f, m2e, m2f) = (self.m1[i - 1], self.m1[i], self.m2[i - 1], self.m2[i]);
            let k1 = 0.5 * kb.dot(&(m2e + m2f));
            let k2 = -0.5 * kb.dot(&(m1e + m1f));
            let (d1v, d2v) = (k1 - kb_rest, k2 - kb_rest2);
            energy += 0.5 * bend * (d1v * d1v + d2v * d2v);
            let m = self.tht[i] - self.tht[i - 1] + self.rt[i];
            energy += 0.5 * twist * m * m;
            if assemble {
                let (ile, ilf) = (self.inv_len[i - 1], self.inv_len[i]);
                let tt = (te + tf) * ichi;
                let td1 = (m1e + m1f) * ichi;
                let td2 = (m2e + m2f) * ichi;
                let dk1de = (-tt * k1 + tf.cross(&td2)) * ile;
                let dk1df = (-tt * k1 - te.cross(&td2)) * ilf;
                let dk2de = (-tt * k2 - tf.cross(&td1)) * ile;
                let dk2df = (-tt * k2 + te.cross(&td1)) * ilf;
                let mut g1 = [0.0; 11];
                let mut g2 = [0.0; 11];
                let mut gt = [0.0; 11];
                for c in 0..3 {
                    g1[c] = -dk1de[c];
                    g1[4 + c] = dk1de[c] - dk1df[c];
                    g1[8 + c] = dk1df[c];
                    g2[c] = -dk2de[c];
                    g2[4 + c] = dk2de[c] - dk2df[c];
                    g2[8 + c] = dk2df[c];
                    let a = kb[c] * (0.5 * ile);
                    let b = kb[c] * (0.5 * ilf);
                    gt[c] = -a;
                    gt[4 + c] = a - b;
                    gt[8 + c] = b;
                }
                g1[3] = -0.5 * kb.dot(&m1e);
                g1[7] = -0.5 * kb.dot(&m1f);
                g2[3] = -0.5 * kb.dot(&m2e);
                g2[7] = -0.5 * kb.dot(&m2f);
                gt[3] = -1.0;
                gt[7] = 1.0;
                let base = 4 * (i - 1);
                for r in 0..11 {
                    self.grad[base + r] += bend * (d1v * g1[r] + d2v * g2[r]) + twist * m * gt[r];
                }
                if hess {
                    self.h.add_gram(base, &[g1, g2, gt], &[bend, bend, twist]);
                }
            }
        }

        // Wall contact and friction on free nodes. Friction acts wherever
        // the last step left a contact (its normal force and normal
        // lagged), whether or not the trial point touches the wall: the
        // energy is then continuous, and smooth, as the trial crosses the
        // wall's surface or the nearest facet changes (docs/WIRE.md "Fast
        // pulls", change 2).
        for i in 2..n {
            let inside = self.cx.inside[i];
            // Inside the sheath: the distance ρ from its centreline and the
            // directions along it and out to the node, for the tube's
            // curvature in the Hessian (below).
            let mut tube = None;
            let hit = if inside {
                // Inside the sheath: its inner wall is the node's lumen (a
                // tube of its inner radius about its centreline).
                let (k, _, q) = nearest_on_polyline(&self.cx.sheath, self.xt[i], &mut self.cx.sheath_seg[i]);
                let d = self.xt[i] - q;
                let rho = d.norm();
                let out = if rho > 1e-15 {
                    d / rho
                } else {
                    perpendicular(self.tan[Self::contact_edge(i, n)])
                };
                let along = self.cx.sheath[k + 1] - self.cx.sheath[k];
                tube = Some((rho, out, along));
                let a = self.cx.funnel[i].max(self.cx.sheath_radius);
                Some(WallHit {
                    distance: a - rho,
                    normal: -out,
                    point: q + out * a,
                    compliance: 0.0,
                    triangle: NO_TRIANGLE,
                })
            } else if self.probe_clear[i] - (self.xt[i] - self.probe_at[i]).norm() > r_w + onset + 1e-6 * r_w {
                // Farther from the wall than the penalty reaches (see
                // `Wire::forget_probes`): no contact, whatever the probe.
                None
            } else {
                let hit = lumen.probe_cached(self.xt[i], 3.0 * r_w, &mut self.probe_cache[i]);
                self.probe_at[i] = self.xt[i];
                self.probe_clear[i] = match hit {
                    None => 3.0 * r_w,
                    // A mesh's triangle (fewer than 2³¹) or an analytic
                    // wall; an opening's continuation is tagged from
                    // `OPENING_TAG` down.
                    Some(h) if h.triangle == NO_TRIANGLE || h.triangle < OPENING_TAG / 2 => h.distance,
                    Some(_) => f64::NEG_INFINITY,
                };
                hit
            };
            self.hits[i] = hit;
            let mut g = Vec3::zeros();
            let mut hm = Mat3::zeros();
            let mut touched = false;
            self.wall_force[i] = Vec3::zeros();
            if let Some(hit) = hit.filter(|h| h.distance < r_w + onset) {
                // The penalty over every piece of wall the node's sphere
                // overlaps (`Lumen::overlaps_cached`: smooth where pieces
                // meet). A compliant wall gives in series with the penalty:
                // a piece's stiffness is 1/(1/k_c + c), and the depth the
                // penalty alone takes (the wire's surface beyond the pushed
                // wall) is k pen / k_c.
                if inside {
                    self.overlaps.clear();
                    let _ = self.overlaps.push(WallOverlap::from_hit(&hit));
                } else {
                    lumen.overlaps_cached(
                        self.xt[i],
                        r_w + onset,
                        &hit,
                        &mut self.probe_cache[i],
                        &mut self.overlaps,
                    );
                }
                let mut signed = false;
                // The compliance of the node's contact at the end of the
                // last step, held through this step: interpolated at each
                // trial point instead, it made the energy depend on where
                // along the wall the node sits through a term the gradient
                // leaves out (∂k/∂x), with kinks at the triangles' edges,
                // and line searches failed on it. A node touching for the
                // first time takes the wall's under it.
                let c_lag = s.comp[i];
                for o in &self.overlaps {
                    let pen = r_w - o.distance;
                    let c = if c_lag >= 0.0 { c_lag } else { o.compliance };
                    let k = kc / (1.0 + kc * c);
                    let (e, f, kk) = penalty(pen, k, onset);
                    // The depth reported is the penalty's share of the
                    // force, f / k_c (with the onset, k_c · onset / 2 at touch).
                    // The sheath's depth is reported apart; its one
                    // overlap has weight one, and its block k nnᵀ needs no
                    // eigen-decomposition to stay positive semi-definite.
                    if !inside {
                        if o.weight > 0.0 {
                            max_pen = max_pen.max(f / kc);
                        } else {
                            signed = true;
                        }
                    }
                    energy += o.weight * e;
                    g -= o.normal * (o.weight * f);
                    hm += outer(&o.normal, &o.normal) * (o.weight * kk);
                }
                // Edges enter with negative weight: keep the Hessian's
                // contact block positive semi-definite.
                if signed {
                    hm = psd(hm);
                }
                // The tube's inner wall curves about the node at its small
                // radius: the penalty force f along the outward direction
                // turns with the node's move across it, a stiffness
                // f / ρ in the cross-section's other direction. Left out,
                // it is of the order of the penalty's own (ρ is the
                // clearance plus the depth, a tenth of a millimetre), far
                // above the wire's bending stiffness at a node, and each
                // Newton update overshot around the tube: the pair's steps
                // ran out of iterations off equilibrium (docs/CATHETER.md
                // "The coupled solve").
                if let Some((rho, out, along)) = tube {
                    let f = g.dot(&out);
                    if f > 0.0 && rho > 1e-9 * r_w {
                        let t = along - out * out.dot(&along);
                        let tn = t.norm();
                        let mut pr = Mat3::identity() - outer(&out, &out);
                        if tn > 1e-300 {
                            let t = t / tn;
                            pr -= outer(&t, &t);
                        }
                        hm += pr * (f / rho);
                    }
                }
                self.wall_force[i] = -g;
                touched = true;
            }
            let lam = s.lam[i];
            let mu = if inside { self.cx.sheath_mu } else { mu };
            // Friction's slip includes the surface's spin (the edge's twist
            // times the radius, along n × t): it resists roll as well as
            // sliding. Its gradient and Hessian on that twist.
            let mut g_spin = 0.0;
            let mut h_xs = Vec3::zeros();
            let mut h_ss = 0.0;
            let mut h_f = Mat3::zeros();
            if mu > 0.0 && lam > 0.0 {
                let (pm, ut, un) = self.slip(i);
                energy += mu
                    * lam
                    * if un < eps_v {
                        0.5 * un * un / eps_v
                    } else {
                        un - 0.5 * eps_v
                    };
                let gf = friction_gradient(ut, un, mu * lam, eps_v);
                g += gf;
                let hf = if un < eps_v {
                    pm * (mu * lam / eps_v)
                } else {
                    let uh = ut / un;
                    (pm - outer(&uh, &uh)) * (mu * lam / un)
                };
                hm += hf;
                h_f = hf;
                let b = self.spin[i];
                g_spin = b.dot(&gf);
                h_xs = hf * b;
                h_ss = b.dot(&h_xs);
                touched = true;
            }
            if hess {
                self.fric_h[i] = (h_f, h_xs, h_ss);
            }
            if assemble && touched {
                let ts = 4 * Self::contact_edge(i, n) + 3;
                self.grad[ts] += g_spin;
                if hess && h_ss > 0.0 {
                    self.h.add(ts, ts, h_ss);
                }
                for r in 0..3 {
                    self.grad[4 * i + r] += g[r];
                    if hess {
                        for c in 0..=r {
                            self.h.add(4 * i + r, 4 * i + c, hm[(r, c)]);
                        }
                        if h_ss > 0.0 {
                            self.h.add(4 * i + r, ts, h_xs[r]);
                        }
                    }
                }
            }
        }

        self.eval_pen = max_pen;
        // The load per length, lumped on the free nodes.
        if self.line_load != Vec3::zeros() {
            for i in 2..n {
                let f = self.line_load * coef[i].lbar;
                energy -= f.dot(&(self.xt[i] - self.x0[i]));
                if assemble {
                    for c in 0..3 {
                        self.grad[4 * i + c] -= f[c];
                    }
                }
            }
        }
        // A core's inertia, on the motion over the step: ½ m/dt² |x − x₀|²
        // (docs/CATHETER.md "The coupled step": without it the wire's
        // inertia, a dead load on the lighter catheter, swung it further
        // each step).
        if self.cx.core.is_some() {
            for i in 2..n {
                let km = coef[i].core_mass;
                if km > 0.0 {
                    let b = self.xt[i] - self.x0[i];
                    energy += 0.5 * km * b.norm_squared();
                    if assemble {
                        for c in 0..3 {
                            self.grad[4 * i + c] += km * b[c];
                            if hess {
                                self.h.add(4 * i + c, 4 * i + c, km);
                            }
                        }
                    }
                }
            }
        }
        // Dead loads at nodes (a core's contact forces on a catheter).
        for i in 2..n {
            let f = self.cx.node_load[i];
            if f != Vec3::zeros() {
                energy -= f.dot(&(self.xt[i] - self.x0[i]));
                if assemble {
                    for c in 0..3 {
                        self.grad[4 * i + c] -= f[c];
                    }
                }
            }
        }
        // The point loads' stiffness on the motion over the step along
        // each load: ½ (x − x₀)ᵀ K (x − x₀), K = Σ k n nᵀ (a contact whose
        // source holds still, linearised: without it the wire's penalty
        // forces, dead loads on the catheter, swung it further each step).
        if self.cx.load_stiffness > 0.0 {
            for i in 2..n {
                let k = self.cx.node_spring[i];
                if k == Mat3::zeros() {
                    continue;
                }
                let b = self.xt[i] - self.x0[i];
                let kb = k * b;
                energy += 0.5 * b.dot(&kb);
                if assemble {
                    for c in 0..3 {
                        self.grad[4 * i + c] += kb[c];
                        if hess {
                            for d in 0..=c {
                                self.h.add(4 * i + c, 4 * i + d, k[(c, d)]);
                            }
                        }
                    }
                }
            }
        }
        // A core's bending stiffness on the change of the curvature vector
        // over the step: ½ b |κb − κb₀|² (docs/CATHETER.md "The coupled
        // step"). κb = 2 e × f / (|e||f| + e·f) in space, so a core that
        // follows this rod's centreline resists a change of its shape,
        // whatever this rod's twist.
        if self.cx.core.is_some() {
            for i in 1..n - 1 {
                let b = coef[i].core_bend;
                if b <= 0.0 {
                    continue;
                }
                let e = self.xt[i] - self.xt[i - 1];
                let f = self.xt[i + 1] - self.xt[i];
                let (le, lf) = (self.len[i - 1], self.len[i]);
                let den = (le * lf + e.dot(&f)).max(1e-30);
                let kb = e.cross(&f) * (2.0 / den);
                let r = kb - self.cx.kb0[i];
                energy += 0.5 * b * r.norm_squared();
                if assemble {
                    // Scaled by 1/den once: a division per entry (18 a
                    // node) was most of this term's cost.
                    let inv = 1.0 / den;
                    let dde = (e * (lf / le) + f) * inv;
                    let ddf = (f * (le / lf) + e) * inv;
                    // Rows of ∂κb/∂e and ∂κb/∂f: ∂(e × f)/∂e_k = u_k × f,
                    // ∂(e × f)/∂f_k = e × u_k (u_k the k-th unit vector).
                    let (f2, e2) = (f * (2.0 * inv), e * (2.0 * inv));
                    let uf = [[0.0, -f2.z, f2.y], [f2.z, 0.0, -f2.x], [-f2.y, f2.x, 0.0]];
                    let eu = [[0.0, e2.z, -e2.y], [-e2.z, 0.0, e2.x], [e2.y, -e2.x, 0.0]];
                    let mut rows = [[0.0; 11]; 3];
                    for (c, row) in rows.iter_mut().enumerate() {
                        for k in 0..3 {
                            let je = uf[k][c] - kb[c] * dde[k];
                            let jf = eu[k][c] - kb[c] * ddf[k];
                            row[k] = -je;
                            row[4 + k] = je - jf;
                            row[8 + k] = jf;
                        }
                    }
                    let base = 4 * (i - 1);
                    for (r_c, row) in r.iter().zip(&rows) {
                        for k in 0..11 {
                            self.grad[base + k] += b * r_c * row[k];
                        }
                    }
                    if hess {
                        self.h.add_gram(base, &rows, &[b, b, b]);
                    }
                }
            }
        }
        // The tip's dead load.
        let tip = n - 1;
        energy -= self.tip_load.dot(&(self.xt[tip] - self.x0[tip]));
        if assemble {
            for c in 0..3 {
                self.grad[4 * tip + c] -= self.tip_load[c];
            }
            // Reactions at the clamp, then pin the fixed unknowns.
            self.hub_grad = Vec3::new(
                self.grad[0] + self.grad[4],
                self.grad[1] + self.grad[5],
                self.grad[2] + self.grad[6],
            );
            self.hub_dtheta = self.grad[3];
            for k in [0, 1, 2, 3, 4, 5, 6, 4 * tip + 3] {
                self.grad[k] = 0.0;
                if hess {
                    self.h.pin(k);
                }
            }
        }
        energy
    }

    /// Node i's slip over the step at the trial state in its lagged
    /// contact's tangent plane: that plane's projector, the slip and its
    /// length (friction's argument, in the energy and the reactions alike).
    fn slip(&self, i: usize) -> (Mat3, Vec3, f64) {
        let nn = self.s.nrm[i];
        let pm = Mat3::identity() - outer(&nn, &nn);
        let j = Self::contact_edge(i, self.s.n);
        let ut = pm * (self.xt[i] - self.s.anchor[i]) + self.spin[i] * (self.tht[j] - self.s.anchor_twist[i]);
        (pm, ut, ut.norm())
    }

    /// The edge whose twist turns the wire's surface at node `i`'s
    /// contact: the edge leaving it, the tip's last edge at the tip.
    fn contact_edge(i: usize, n: usize) -> usize {
        if i + 1 < n {
            i
        } else {
            i - 1
        }
    }

    /// The contact list at the trial state, from the wall probes and
    /// penalty forces of its evaluation (`hits`, `wall_force`), and the
    /// next step's lagged normal forces and normals. The
    /// hub's reactions are in `hub_grad`, `hub_dtheta`: they come from the
    /// elastic terms only, and the assembled gradient at the clamp holds
    /// exactly those (inertia acts on free nodes).
    fn reactions(&mut self) {
        let n = self.s.n;
        let kc = self.p.contact_stiffness_n_per_m;
        let mu = self.p.friction;
        let eps_v = self.p.friction_smoothing_m;
        self.contacts.clear();
        self.cx.sheath_contacts.clear();
        for i in 2..n {
            // The wall's penalty force at the evaluation: its size is the
            // contact's normal force, its direction the contact's normal
            // (the nearest wall's normal against one piece of wall).
            let f = self.wall_force[i];
            let lam = f.norm();
            let j = Self::contact_edge(i, n);
            let Some(hit) = self.hits[i].filter(|_| lam > 0.0) else {
                self.s.lam[i] = 0.0;
                self.s.comp[i] = -1.0;
                self.s.anchor[i] = self.xt[i];
                self.s.anchor_twist[i] = self.tht[j];
                continue;
            };
            // The compliance this step's contact had (the held one, or the
            // wall's under the node at a first touch), and the next step's:
            // the wall's where the node now touches it.
            let c_step = if self.s.comp[i] >= 0.0 {
                self.s.comp[i]
            } else {
                hit.compliance
            };
            self.s.comp[i] = hit.compliance;
            let nn = f / lam;
            // Friction as the step's energy had it: the lagged normal force
            // and normal.
            let lam_prev = self.s.lam[i];
            let mu = if self.cx.inside[i] { self.cx.sheath_mu } else { mu };
            let friction = if mu > 0.0 && lam_prev > 0.0 {
                let (pm, ut, un) = self.slip(i);
                // The anchor stays while the contact sticks (slip below the
                // smoothing) and trails the node by the smoothing once it
                // slips: its slip, translation and spin alike, is cut back
                // to the smoothing length.
                if un > eps_v {
                    let cut = 1.0 - eps_v / un;
                    let (a, at) = (self.s.anchor[i], self.s.anchor_twist[i]);
                    self.s.anchor[i] = a + pm * (self.xt[i] - a) * cut;
                    self.s.anchor_twist[i] = at + (self.tht[j] - at) * cut;
                }
                -friction_gradient(ut, un, mu * lam_prev, eps_v)
            } else {
                // A new contact sticks where it begins.
                self.s.anchor[i] = self.xt[i];
                self.s.anchor_twist[i] = self.tht[j];
                Vec3::zeros()
            };
            self.s.lam[i] = lam;
            self.s.nrm[i] = nn;
            let list = if self.cx.inside[i] {
                &mut self.cx.sheath_contacts
            } else {
                &mut self.contacts
            };
            if list.len() < list.capacity() {
                list.push(WireContact {
                    node: i,
                    point: hit.point,
                    normal: nn,
                    normal_force: lam,
                    friction,
                    penetration: lam / kc,
                    wall_deflection: lam * c_step,
                    triangle: hit.triangle,
                });
            }
        }
    }

    /// The incremental potential at the current state against `lumen` as if
    /// a step were starting now, with its gradient (for tests of the
    /// energy's derivatives).
    #[doc(hidden)]
    pub fn energy_and_gradient_at(
        &mut self,
        lumen: &dyn Lumen,
        x: &[Vec3],
        theta: &[f64],
        rebase: bool,
    ) -> (f64, Vec<f64>) {
        let n = self.s.n;
        self.xt[..n].copy_from_slice(&x[..n]);
        self.tht[..n].copy_from_slice(&theta[..n]);
        self.coefficients();
        if rebase {
            self.geometry();
            for i in 0..n {
                self.d10[i] = self.d1c[i];
                self.t0[i] = self.tan[i];
                self.rt0[i] = self.rt[i];
                self.rt0_sc[i] = sin_cos_near(self.rt0[i], &mut self.rt_near[i]);
            }
        }
        self.forget_probes();
        let e = self.eval(lumen, true);
        (e, self.grad[..4 * n].to_vec())
    }

    /// Starts a step without taking it (for tests of the energy's
    /// derivatives: sets the step-start frames and inertial target).
    #[doc(hidden)]
    pub fn begin_step_for_tests(&mut self) {
        self.feed();
        self.begin_step();
    }

    /// Makes the tip's position NaN, so the next step fails with
    /// [`WireFault::NonFinite`] (fault injection for the service's
    /// watchdog tests).
    #[doc(hidden)]
    pub fn poison_for_tests(&mut self) {
        let tip = self.s.n - 1;
        self.s.x[tip] = Vec3::repeat(f64::NAN);
    }

    /// Current twist angles of the edges (rad).
    pub fn twists(&self) -> &[f64] {
        &self.s.theta[..self.s.n]
    }

    /// Node velocities at the end of the last step (m/s), as
    /// [`Wire::positions`].
    pub fn velocities(&self) -> &[Vec3] {
        &self.s.v[..self.s.n]
    }

    /// Puts the rod inside a sheath for the next steps (a wire inside a
    /// catheter): the sheath's node positions and velocities (its ghost
    /// node first, as [`Wire::positions`]), its inserted length from the
    /// same hub and its inner radius (m). The rod's nodes whose arc length
    /// from the hub is at most `reach` touch the sheath's inner wall (a
    /// tube of `inner_radius` about its centreline, going on straight past
    /// its tip) instead of the lumen's, with this rod's contact stiffness
    /// and Coulomb friction `friction`, the slip measured against the
    /// sheath's motion.
    /// Copies into buffers sized at construction (at most
    /// [`MAX_SHEATH_NODES`] nodes; fewer than two: no sheath).
    pub fn set_sheath(
        &mut self,
        positions: &[Vec3],
        velocities: &[Vec3],
        reach: f64,
        inner_radius: f64,
        friction: f64,
    ) {
        let m = positions.len().min(velocities.len()).min(MAX_SHEATH_NODES);
        self.cx.sheath.clear();
        self.cx.sheath_v.clear();
        if m < 2 || !reach.is_finite() || inner_radius.is_nan() || inner_radius <= 0.0 {
            return;
        }
        self.cx.sheath.extend_from_slice(&positions[..m]);
        self.cx.sheath_v.extend_from_slice(&velocities[..m]);
        self.cx.sheath_reach = reach;
        self.cx.sheath_radius = inner_radius;
        self.cx.sheath_mu = if friction.is_finite() {
            friction.clamp(0.0, 2.0)
        } else {
            0.0
        };
    }

    /// Takes the rod out of its sheath.
    pub fn clear_sheath(&mut self) {
        self.cx.sheath.clear();
        self.cx.sheath_v.clear();
    }

    /// Which nodes were inside the sheath in the last step (as
    /// [`Wire::positions`]).
    pub fn inside_sheath(&self) -> &[bool] {
        &self.cx.inside[..self.s.n]
    }

    /// The contacts with the sheath's inner wall of the last step (the
    /// force on the sheath is the opposite of each one's on this rod).
    pub fn sheath_contacts(&self) -> &[WireContact] {
        &self.cx.sheath_contacts
    }

    /// Dead point loads (point, force in N) for the next step only, each
    /// spread onto the two nodes of the segment nearest its point when the
    /// step begins (a wire's contact forces on its catheter). At most
    /// [`MAX_POINT_LOADS`]; the rest are dropped.
    pub fn set_point_loads(&mut self, loads: impl IntoIterator<Item = (Vec3, Vec3)>) {
        self.cx.point_loads.clear();
        for l in loads {
            if self.cx.point_loads.len() == self.cx.point_loads.capacity() {
                break;
            }
            if l.0.iter().chain(l.1.iter()).all(|c| c.is_finite()) {
                self.cx.point_loads.push(l);
            }
        }
    }

    /// The stiffness (N/m, ≥ 0; 0 by default) with which each point load
    /// ([`Wire::set_point_loads`]) also resists this rod's motion over the
    /// step along the load's own direction: a contact force whose source
    /// holds still through the step, linearised (the wire's contact forces
    /// on its catheter: docs/CATHETER.md "The coupled step").
    pub fn set_point_load_stiffness(&mut self, k: f64) {
        self.cx.load_stiffness = if k.is_finite() { k.max(0.0) } else { 0.0 };
    }

    /// A core inside this rod from the same hub (a wire inside a
    /// catheter): `reach` metres of it inserted, with `core`'s bending
    /// stiffness by its own material coordinate. Within the overlap, each
    /// step adds the core's bending stiffness to this rod's, on the change
    /// of the centreline's curvature over the step (docs/CATHETER.md "The
    /// coupled step"). `None`: no core.
    pub fn set_core(&mut self, core: Option<(&WireParams, f64)>) {
        self.cx.core = core
            .filter(|(_, reach)| reach.is_finite())
            .map(|(c, reach)| CoreStiffness {
                reach,
                ei: c.bending_stiffness(),
                mass_per_m: c.density_kg_m3 * c.area(),
                tip_length: c.tip_length_m,
                tip_factor: c.tip_stiffness_factor,
            });
    }

    /// The step's coaxial state once the feed is done: which nodes are
    /// inside the sheath (their friction anchors carried with the sheath's
    /// motion), the point loads spread onto nodes, and the curvature at
    /// the start.
    fn begin_coaxial(&mut self) {
        let n = self.s.n;
        let dt = self.p.dt_s;
        let r_w = 0.5 * self.p.diameter_m;
        let cx = &mut self.cx;
        let has_sheath = cx.sheath.len() >= 2;
        for i in 0..n {
            let inside = has_sheath && i >= 2 && self.s.inserted - self.s.u[i] <= cx.sheath_reach;
            if inside && !cx.inside[i] {
                // Entering: search the whole sheath once (a downhill search
                // from its hub stops on the wrong leg of a sheath bent back
                // on itself, 100 mm from the node in a half turn).
                let (_, _, q) = nearest_on_polyline_everywhere(&cx.sheath, self.s.x[i], &mut cx.sheath_seg[i]);
                // A node outside the lumen (a J-tip beside the sheath's
                // tip) enters through the lip's funnel, not deep in the
                // wall with a kilonewton penalty.
                cx.funnel[i] = (self.s.x[i] - q).norm() + r_w;
            }
            if inside && cx.inside[i] {
                // The node starts the step carried with the sheath's last
                // motion across its axis (a predictor): a sheath that moved
                // sideways by more than the clearance would otherwise leave
                // the node deep in its wall, more than Newton's capped
                // updates can undo in one step (docs/CATHETER.md "The
                // coupled step"). Not along its axis: a catheter tracked
                // over a held wire would carry every inside node forward
                // by its feed, a stretch of the edges at the hub and at the
                // catheter's tip of EA/ē ≈ 1.2 × 10⁷ N/m times the feed
                // (300 N at 26 µm a step) for two or three Newton
                // iterations to undo (docs/INSTRUMENTS.md "In the
                // cannulation scenarios"). The friction anchor moves with
                // the whole motion: riding along is no slip, and a node
                // that the solve leaves behind slips.
                let (k, t, _) = nearest_on_polyline(&cx.sheath, self.s.x[i], &mut cx.sheath_seg[i]);
                let t = t.clamp(0.0, 1.0);
                let d = (cx.sheath_v[k] * (1.0 - t) + cx.sheath_v[k + 1] * t) * dt;
                let across = match (cx.sheath[k + 1] - cx.sheath[k]).try_normalize(1e-300) {
                    Some(a) => d - a * a.dot(&d),
                    None => d,
                };
                self.s.x[i] += across;
                self.xt[i] = self.s.x[i];
                self.s.anchor[i] += d;
                // The funnel closes as the node comes in, and steadily.
                if cx.funnel[i] > cx.sheath_radius {
                    let (_, _, q) = nearest_on_polyline(&cx.sheath, self.s.x[i], &mut cx.sheath_seg[i]);
                    let open = (self.s.x[i] - q).norm() + r_w;
                    cx.funnel[i] = open.min(cx.funnel[i] - FUNNEL_CLOSING_M_PER_S * dt);
                }
            }
            if inside != cx.inside[i] {
                // A contact with another wall: friction starts afresh.
                self.s.lam[i] = 0.0;
                self.s.comp[i] = -1.0;
                self.s.anchor[i] = self.s.x[i];
            }
            cx.inside[i] = inside;
        }
        for f in &mut cx.node_load[..n] {
            *f = Vec3::zeros();
        }
        for k in &mut cx.node_spring[..n] {
            *k = Mat3::zeros();
        }
        if !cx.point_loads.is_empty() && n >= 3 {
            let poly = &self.s.x[..n];
            let mut seg = 0;
            for (j, &(at, f)) in cx.point_loads.iter().enumerate() {
                // The first over the whole rod (a downhill search from the
                // hub stops on the wrong leg of a rod bent back on
                // itself), the next ones from their predecessor's segment.
                let (k, t, _) = if j == 0 {
                    nearest_on_polyline_everywhere(poly, at, &mut seg)
                } else {
                    nearest_on_polyline(poly, at, &mut seg)
                };
                let t = t.clamp(0.0, 1.0);
                cx.node_load[k] += f * (1.0 - t);
                cx.node_load[k + 1] += f * t;
                if cx.load_stiffness > 0.0 {
                    if let Some(d) = f.try_normalize(1e-12) {
                        let nn = d * d.transpose() * cx.load_stiffness;
                        cx.node_spring[k] += nn * (1.0 - t);
                        cx.node_spring[k + 1] += nn * t;
                    }
                }
            }
            cx.point_loads.clear();
        }
        if cx.core.is_some() {
            let x = &self.s.x;
            for i in 1..n - 1 {
                let e = x[i] - x[i - 1];
                let f = x[i + 1] - x[i];
                let den = (e.norm() * f.norm() + e.dot(&f)).max(1e-30);
                cx.kb0[i] = e.cross(&f) * (2.0 / den);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::wire::lumen::{NoWall, StraightTube};

    /// The geometry's fast angles agree with the library's to a few ulps:
    /// the series branches (small angles) and the fall-backs.
    #[test]
    fn the_closed_form_psd_matches_the_iterative_eigensolver() {
        // Contact blocks as the wall gives them: faces (+1), edges (−1) and
        // vertices with unit normals and penalty stiffnesses, and general
        // symmetric matrices; the projection is the iterative solver's to
        // 1e-7 of the block's size, and positive semi-definite.
        let mut s = 0x9e37_79b9_7f4a_7c15u64;
        let mut rnd = move || {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((s >> 11) as f64 / (1u64 << 53) as f64) - 0.5
        };
        let mut worst: f64 = 0.0;
        for case in 0..20000 {
            let mut m = Mat3::zeros();
            if case % 2 == 0 {
                let terms = 1 + case % 5;
                let base = Vec3::new(rnd(), rnd(), rnd()).normalize();
                for t in 0..terms {
                    // Normals near each other (a shallow valley or ridge).
                    let n = (base + Vec3::new(rnd(), rnd(), rnd()) * (0.3 * (case % 3) as f64)).normalize();
                    let w = if t % 3 == 1 { -1.0 } else { 1.0 };
                    m += outer(&n, &n) * (w * 1e6 * (1.0 + rnd()));
                }
            } else {
                for r in 0..3 {
                    for c in 0..=r {
                        let v = 1e6 * rnd();
                        m[(r, c)] = v;
                        m[(c, r)] = v;
                    }
                }
            }
            let scale = m.norm().max(1e-300);
            let (a, b) = (psd(m), psd_iterative(m));
            worst = worst.max((a - b).norm() / scale);
            let l = nalgebra::SymmetricEigen::new(a).eigenvalues.min();
            assert!(l >= -1e-9 * scale, "case {case}: {l} of {a}");
        }
        assert!(worst < 1e-7, "largest difference {worst:e} of the block");
        // Exactly semi-definite blocks come back unchanged; negative ones
        // vanish.
        let n = Vec3::new(0.6, 0.0, 0.8);
        let m = outer(&n, &n) * 2e6 + Mat3::identity() * 1e3;
        assert_eq!(psd(m), m);
        assert_eq!(psd(-m), Mat3::zeros());
    }

    #[test]
    fn series_angles_match_the_library() {
        let mut near = (0.3, 0.3f64.sin(), 0.3f64.cos());
        for k in 0..4000 {
            let theta = 0.3 + (k as f64 - 2000.0) * 1e-5 * (1.0 + (k as f64).sin());
            let (s, c) = sin_cos_near(theta, &mut near);
            assert!(
                (s - theta.sin()).abs() < 4e-16 && (c - theta.cos()).abs() < 4e-16,
                "θ = {theta}"
            );
        }
        let axis = Vec3::z();
        for k in 0..4000 {
            let a = (k as f64 - 2000.0) * 1e-5 + if k % 7 == 0 { 2.5 } else { 0.0 };
            let u = Vec3::new(1.3, 0.0, 0.2);
            let v = Vec3::new(0.7 * a.cos(), 0.7 * a.sin(), -0.4);
            let want = u.cross(&v).dot(&axis).atan2(u.dot(&v));
            let got = signed_angle(u, v, axis);
            assert!(
                (got - want).abs() <= 4e-16 * want.abs().max(1e-300),
                "{got} against {want}"
            );
        }
    }

    /// The geometry's lanes give the scalar functions' bits, lane by lane,
    /// on their fast paths and through every fall-back: turns beyond 90°,
    /// none, and reversed; twists far from the kept angle; reference
    /// twists beyond the series' range.
    #[test]
    #[allow(clippy::needless_range_loop)] // lanes against the scalar code
    fn geometry_lanes_give_the_scalar_bits() {
        const L: usize = 8;
        let mut seed = 0x2545_f491_4f6c_dd1du64;
        let mut rnd = || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        for round in 0..400 {
            let mut unit = |spread: f64, base: Vec3| (base + Vec3::new(rnd(), rnd(), rnd()) * spread).normalize();
            let base = unit(1.0, Vec3::zeros());
            let a: Vec<Vec3> = (0..L).map(|_| unit(0.02, base)).collect();
            let mut b: Vec<Vec3> = (0..L)
                .map(|k| unit(if k % 3 == 0 { 2.0 } else { 0.02 }, a[k]))
                .collect();
            b[round % L] = a[round % L];
            b[(round + 3) % L] = -a[(round + 3) % L];
            let d: Vec<Vec3> = a.iter().map(|&t| perpendicular(t)).collect();
            let (la, lb, ld) = (Lv::<L>::load(&a, 0), Lv::<L>::load(&b, 0), Lv::<L>::load(&d, 0));
            let got = transport_lanes(&ld, &la, &lb);
            let axis = Lv::<L>::load(&b, 0);
            let angle = signed_angle_lanes(&got, &ld, &axis);
            let dot = la.dot(&lb);
            let cross = la.cross(&lb).sub(&ld).add(&la).scale(&dot).neg();
            for k in 0..L {
                let want = transport(d[k], a[k], b[k]);
                assert_eq!(got.get(k), want, "transport, round {round} lane {k}");
                assert_eq!(angle[k].to_bits(), signed_angle(want, d[k], b[k]).to_bits(), "angle");
                assert_eq!(dot[k].to_bits(), a[k].dot(&b[k]).to_bits(), "dot");
                assert_eq!(
                    cross.get(k),
                    -((a[k].cross(&b[k]) - d[k] + a[k]) * a[k].dot(&b[k])),
                    "ops"
                );
            }
            let theta: Vec<f64> = (0..L).map(|k| rnd() * if k % 4 == 0 { 0.1 } else { 1e-4 }).collect();
            let mut near: Vec<(f64, f64, f64)> = (0..L).map(|_| (0.0, 0.0, 1.0)).collect();
            let mut near_scalar = near.clone();
            let (sn, cs) = sin_cos_near_lanes::<L>(&theta, &mut near);
            for k in 0..L {
                let (s1, c1) = sin_cos_near(theta[k], &mut near_scalar[k]);
                assert_eq!(
                    (sn[k].to_bits(), cs[k].to_bits()),
                    (s1.to_bits(), c1.to_bits()),
                    "sin, cos"
                );
                assert_eq!(near[k], near_scalar[k]);
            }
        }
    }

    /// The assembled gradient is that of the energy (central differences),
    /// on a bent, twisted, pre-shaped wire touching a tube wall with friction.
    /// The largest gap between the assembled gradient and central
    /// differences of the energy at a state perturbed off the step's start,
    /// and the largest gradient entry.
    fn gradient_gap(w: &mut Wire, lumen: &dyn Lumen, amplitude: f64) -> (f64, f64) {
        w.begin_step_for_tests();
        let n = w.num_nodes();
        let mut x: Vec<Vec3> = w.positions().to_vec();
        let mut th: Vec<f64> = w.twists().to_vec();
        // Perturb the free unknowns a little off the start state.
        for i in 2..n {
            x[i] += Vec3::new((i as f64).sin(), (i as f64 * 1.3).cos(), (i as f64 * 0.7).sin()) * amplitude;
            if i < n - 1 {
                th[i] += 0.05 * (i as f64).cos();
            }
        }
        let (_, g) = w.energy_and_gradient_at(lumen, &x, &th, true);
        let mut worst: f64 = 0.0;
        let mut scale: f64 = 0.0;
        for i in 2..n {
            for c in 0..4 {
                if c == 3 && i == n - 1 {
                    continue;
                }
                let hstep = if c == 3 { 1e-7 } else { 1e-10 };
                let mut xp = x.clone();
                let mut tp = th.clone();
                let mut xm = x.clone();
                let mut tm = th.clone();
                if c == 3 {
                    tp[i] += hstep;
                    tm[i] -= hstep;
                } else {
                    xp[i][c] += hstep;
                    xm[i][c] -= hstep;
                }
                let (ep, _) = w.energy_and_gradient_at(lumen, &xp, &tp, false);
                let (em, _) = w.energy_and_gradient_at(lumen, &xm, &tm, false);
                let fd = (ep - em) / (2.0 * hstep);
                let a = g[4 * i + c];
                worst = worst.max((fd - a).abs());
                scale = scale.max(a.abs());
            }
        }
        (worst, scale)
    }

    #[test]
    fn gradient_matches_finite_differences() {
        let p = WireParams {
            segment_length_m: 2e-3,
            max_nodes: 16,
            tip_length_m: 8e-3,
            tip_curvature_per_m: 60.0,
            youngs_modulus_pa: 1e9,
            ..WireParams::default()
        };
        let mut w = Wire::new(&p, Vec3::zeros(), Vec3::x(), 0.02).unwrap();
        let tube = StraightTube::new(Vec3::new(-0.01, 0.0, 0.0), Vec3::x(), 0.1, 1.2e-3, false).unwrap();
        // A few steps to bend it against the wall and get friction going.
        w.set_tip_load(Vec3::new(0.0, 0.05, 0.02));
        w.set_hub(0.021, 0.3);
        for _ in 0..5 {
            w.step(&tube).unwrap();
        }
        w.set_hub(0.0215, 0.5);
        let (worst, scale) = gradient_gap(&mut w, &tube, 2e-5);
        assert!(worst < 1e-4 * scale, "worst {worst:e} of {scale:e}");
    }

    /// The coaxial terms' gradient is the energy's too: a rod inside a
    /// sheath (a bent polyline around it, with friction), with a core's
    /// stiffness on its curvature change and point loads on it.
    #[test]
    fn the_coaxial_terms_gradient_matches_finite_differences() {
        let p = WireParams {
            segment_length_m: 2e-3,
            max_nodes: 16,
            inner_diameter_m: 0.5e-3,
            rest_shape: vec![
                crate::wire::RestArc {
                    length_m: 6e-3,
                    curvature_per_m: 50.0,
                    plane_rad: 0.4,
                },
                crate::wire::RestArc {
                    length_m: 5e-3,
                    curvature_per_m: -30.0,
                    plane_rad: 0.0,
                },
            ],
            youngs_modulus_pa: 1e9,
            ..WireParams::default()
        };
        let mut w = Wire::new(&p, Vec3::zeros(), Vec3::x(), 0.02).unwrap();
        // A sheath bending away from the axis, so that nodes press on it.
        let sheath: Vec<Vec3> = (0..14)
            .map(|k| {
                let x = -2e-3 + 2e-3 * k as f64;
                Vec3::new(x, 3e-3 * (x / 0.02).powi(2), 0.0)
            })
            .collect();
        let vel = vec![Vec3::new(1e-3, 0.0, 0.0); sheath.len()];
        w.set_sheath(&sheath, &vel, 0.012, 0.46e-3, 0.2);
        let core = WireParams::default();
        w.set_core(Some((&core, 0.015)));
        w.set_point_load_stiffness(2e3);
        w.set_hub(0.021, 0.3);
        for _ in 0..5 {
            w.set_point_loads([(Vec3::new(0.01, 0.0, 0.0), Vec3::new(0.0, 0.02, 0.01))]);
            w.step(&NoWall).unwrap();
        }
        assert!(
            w.sheath_contacts().len() >= 3,
            "{} sheath contacts",
            w.sheath_contacts().len()
        );
        w.set_point_loads([(Vec3::new(0.01, 0.0, 0.0), Vec3::new(0.0, 0.02, 0.01))]);
        w.set_hub(0.0215, 0.5);
        let (worst, scale) = gradient_gap(&mut w, &NoWall, 2e-5);
        assert!(worst < 1e-4 * scale, "worst {worst:e} of {scale:e}");
    }

    /// A wire fed through a straight sheath whose tip it passes: a node fed
    /// in at the hub shifts every node's sheath state with it, so no node
    /// that stays inside enters the sheath anew (which restarted its
    /// friction); only the new node at the hub does.
    #[test]
    fn a_node_fed_in_keeps_each_inside_nodes_sheath_state() {
        let p = WireParams {
            segment_length_m: 2e-3,
            max_nodes: 40,
            ..WireParams::default()
        };
        let mut w = Wire::new(&p, Vec3::zeros(), Vec3::x(), 0.03).unwrap();
        let sheath: Vec<Vec3> = (0..12).map(|k| Vec3::new(-2e-3 + 2e-3 * k as f64, 0.0, 0.0)).collect();
        let vel = vec![Vec3::zeros(); sheath.len()];
        // A sideways load presses the nodes near the sheath's tip onto its
        // wall.
        w.set_line_load(Vec3::new(0.0, -50.0, 0.0));
        let (mut fed, mut checked) = (0, 0);
        for step in 0..400 {
            w.set_sheath(&sheath, &vel, 0.015, 0.55e-3, 0.1);
            w.set_hub(0.03 + 2e-5 * step as f64, 0.0);
            let (n0, inside0) = (w.num_nodes(), w.cx.inside.clone());
            let lam0 = w.s.lam.clone();
            w.step(&NoWall).unwrap();
            if w.num_nodes() == n0 + 1 {
                fed += 1;
                // After the step, node i + 1 is the node that was i: one
                // that touched the sheath and stays inside slides on with
                // its friction (kinetic: the wire is fed).
                for i in 2..n0 {
                    if inside0[i] && w.cx.inside[i + 1] && lam0[i] > 0.0 {
                        let c = w.sheath_contacts().iter().find(|c| c.node == i + 1);
                        let f = c.map_or(0.0, |c| c.friction.norm());
                        assert!(f > 0.0, "step {step}: node {i} (now {}) slid without friction", i + 1);
                        checked += 1;
                    }
                }
            }
        }
        assert!(
            fed >= 3 && checked >= fed,
            "{fed} nodes fed in, {checked} contacts followed"
        );
    }

    /// A square duct of circumradius 1.2 mm along x (triangles wound
    /// inward), a corner straight below the axis (−y), and a wire lying in
    /// that corner under a line load toward it, its hub in the corner too
    /// (a straight wire: no pre-shaped tip).
    fn wire_in_a_corner(friction: f64, tolerance: f64) -> (Wire, crate::wire::lumen::TriangleLumen) {
        use crate::wire::lumen::{tube_wall, TriangleLumen};
        let (v, t) = tube_wall(-0.01, 0.2, 1.2e-3, 4, 40, -std::f64::consts::FRAC_PI_2);
        let duct = TriangleLumen::new(&v, &t).unwrap();
        let p = WireParams {
            segment_length_m: 2e-3,
            max_nodes: 40,
            friction,
            tip_length_m: 0.0,
            newton_iterations: 3,
            residual_tolerance_n: tolerance,
            ..WireParams::default()
        };
        // The hub where the wire's centreline lies in the corner unloaded:
        // (r_w + the penalty's onset) √2 above it.
        let y = -1.2e-3 + (0.5 * p.diameter_m + p.contact_onset_m) * std::f64::consts::SQRT_2;
        let mut w = Wire::new(&p, Vec3::new(0.0, y, 0.0), Vec3::x(), 0.06).unwrap();
        w.set_line_load(Vec3::new(0.0, -3.0, 0.0));
        (w, duct)
    }

    #[test]
    fn the_contact_energy_is_smooth_in_a_corner_of_the_wall() {
        // Nodes pressed into the corner overlap both faces and the edge
        // between them (the overlaps' signed sum) and sit in the penalty's
        // onset: the gradient is still the energy's.
        let (mut w, duct) = wire_in_a_corner(0.1, 0.0);
        for _ in 0..50 {
            w.step(&duct).unwrap();
        }
        let mut o = crate::wire::lumen::WallOverlaps::new();
        let r_w = 0.5 * w.params().diameter_m + w.params().contact_onset_m;
        let mut two = 0;
        for &x in &w.positions()[2..] {
            let mut cache = ProbeCache::default();
            if let Some(hit) = duct.probe_cached(x, 3.0 * r_w, &mut cache) {
                duct.overlaps_cached(x, r_w, &hit, &mut cache, &mut o);
                two += usize::from(o.iter().filter(|p| p.weight > 0.0).count() >= 2);
            }
        }
        assert!(two >= 10, "{two} nodes touch both faces: no test of the corner");
        for amplitude in [2e-6, 2e-5] {
            let (worst, scale) = gradient_gap(&mut w, &duct, amplitude);
            assert!(
                worst < 1e-4 * scale,
                "amplitude {amplitude:e}: worst {worst:e} of {scale:e}"
            );
        }
    }

    #[test]
    fn the_gradient_holds_on_a_wall_whose_compliance_varies() {
        // A wire pressed onto a compliant wall whose compliance changes
        // fivefold from vertex to vertex (a series stiffness of 20 to
        // 100 N/m under each contact). Interpolated at the trial point, the
        // compliance made the contact energy depend on where along the wall
        // a node sits through a term the gradient left out: here 3.9 mN off
        // the central differences, against 6 mN of load a node (the check
        // failed so). Held through the step, it is a constant of the
        // energy.
        use crate::wire::lumen::{tube_wall, TriangleLumen};
        let (v, t) = tube_wall(-0.01, 0.2, 1.2e-3, 12, 100, 0.0);
        let mut wall = TriangleLumen::new(&v, &t).unwrap();
        let comp: Vec<f64> = (0..v.len()).map(|i| 0.01 + 0.01 * ((7 * i) % 5) as f64).collect();
        wall.set_compliance(&comp).unwrap();
        let p = WireParams {
            segment_length_m: 2e-3,
            max_nodes: 40,
            tip_length_m: 0.0,
            newton_iterations: 3,
            ..WireParams::default()
        };
        let mut w = Wire::new(&p, Vec3::zeros(), Vec3::x(), 0.06).unwrap();
        w.set_line_load(Vec3::new(0.0, -3.0, 0.5));
        for _ in 0..60 {
            w.step(&wall).unwrap();
        }
        // Slide it along the wall so that friction and the contacts move.
        w.set_hub(0.0602, 0.2);
        for _ in 0..3 {
            w.step(&wall).unwrap();
        }
        let touching = w.contacts().len();
        assert!(touching >= 5, "{touching} contacts: no test of the compliant wall");
        let gave = w.contacts().iter().map(|c| c.wall_deflection).fold(0.0, f64::max);
        assert!(
            gave > 1e-5,
            "the wall gave {gave:e} m at most: no test of its compliance"
        );
        w.set_hub(0.0604, 0.3);
        for amplitude in [2e-6, 2e-5] {
            let (worst, scale) = gradient_gap(&mut w, &wall, amplitude);
            assert!(
                worst < 1e-4 * scale,
                "amplitude {amplitude:e}: worst {worst:e} of {scale:e}"
            );
        }
    }

    #[test]
    fn a_wire_pressed_into_a_corner_reaches_equilibrium() {
        // Against the nearest face alone, a node in the corner had no
        // equilibrium (its force turned from one face's normal to the
        // other's as it crossed the corner's plane); with both faces it has
        // one, and Newton's three iterations find it.
        let (mut w, duct) = wire_in_a_corner(0.0, 0.0);
        let mut worst: f64 = 0.0;
        for k in 0..300 {
            let r = w.step(&duct).unwrap();
            if k >= 200 {
                worst = worst.max(r.residual_n);
            }
        }
        assert!(worst < 1e-6, "largest residual {worst:e} N");
        // Both faces carry the load alike (no sideways force), and in the
        // middle third, away from the clamp and the free tip (the wire is a
        // beam on the wall's elastic foundation), each node's share of it:
        // 3 N/m over a segment, straight up.
        let n = w.num_nodes();
        let share = 3.0 * w.params().segment_length_m;
        let (mut sum, mut middle) = (0.0, 0);
        for c in w.contacts() {
            let up = c.normal * c.normal_force;
            assert!(
                up.z.abs() < 1e-6 * share,
                "node {}: a sideways force {} N",
                c.node,
                up.z
            );
            if 3 * c.node >= n && 3 * c.node < 2 * n {
                sum += up.y;
                middle += 1;
            }
        }
        assert!(middle >= 8, "{middle} contacts in the middle third");
        let mean = sum / middle as f64;
        assert!(
            (mean - share).abs() < 0.02 * share,
            "the wall carries {mean} N a node in the middle, the load {share} N"
        );
    }

    #[test]
    fn the_time_limit_stops_the_extra_iterations_only() {
        // With a tolerance of 1e-9 N, a step still off equilibrium after
        // its three configured iterations goes on; a time limit the step
        // has always run past when it checks (1 ns) stops it at three, and
        // says so; without a limit none is stopped by time. The two runs
        // are the same up to the first step that went on.
        let run = |limit_us: f64| {
            let (mut w, duct) = wire_in_a_corner(0.1, 1e-9);
            // Through the setter a set-up uses to turn the limit off.
            w.set_residual_time_limit_us(limit_us);
            (0..40).map(|_| w.step(&duct).unwrap()).collect::<Vec<_>>()
        };
        let free = run(0.0);
        assert!(free.iter().all(|r| !r.time_spent));
        let k0 = free
            .iter()
            .position(|r| r.iterations > 3)
            .expect("no step went on past its iterations: no test of the limit");
        let limited = run(1e-3);
        assert_eq!(
            limited[..k0],
            free[..k0],
            "the same steps before the first that went on"
        );
        assert!(
            limited[k0].time_spent && limited[k0].iterations == 3,
            "{:?}",
            limited[k0]
        );
        assert!(limited.iter().all(|r| r.iterations <= 3));
        // A step that ran its three iterations within the tolerance (here
        // 1000 N: every step) is not one the limit stopped, though it has
        // run past the limit when it checks.
        let (mut w, duct) = wire_in_a_corner(0.1, 1e3);
        w.p.residual_time_limit_us = 1e-3;
        let reps: Vec<_> = (0..40).map(|_| w.step(&duct).unwrap()).collect();
        assert!(
            reps.iter().any(|r| r.iterations == 3),
            "no step ran its three iterations: no test"
        );
        assert!(
            reps.iter().all(|r| !r.time_spent),
            "a converged step counted as stopped by time"
        );
    }

    /// A wire that has come to rest (the hand still, nothing moving) costs
    /// one evaluation a step: a Newton update of rounding size is
    /// convergence, not a direction to search along. Before, the line
    /// search met energies equal to rounding and ran all its twelve trials:
    /// 13–14 evaluations a step while the service's hand held still.
    #[test]
    fn a_wire_at_rest_costs_one_evaluation_a_step() {
        let p = WireParams {
            segment_length_m: 2e-3,
            max_nodes: 40,
            ..WireParams::default()
        };
        // In free space and lying on a wall under a load.
        let tube = StraightTube::new(Vec3::new(-0.01, 0.0, 0.0), Vec3::x(), 0.2, 1.5e-3, false).unwrap();
        for (lumen, load) in [(&NoWall as &dyn Lumen, 0.0), (&tube as &dyn Lumen, 3.0)] {
            let mut w = Wire::new(&p, Vec3::zeros(), Vec3::x(), 0.03).unwrap();
            w.set_line_load(Vec3::new(0.0, load, 0.0));
            // Settle (the straight-laid tip springs into its shape).
            for _ in 0..2000 {
                w.step(lumen).unwrap();
            }
            let reps: Vec<_> = (0..50).map(|_| w.step(lumen).unwrap()).collect();
            assert!(reps.iter().all(|r| r.residual_n < 1e-4), "not at rest: {:?}", reps[0]);
            let most = reps.iter().map(|r| r.evaluations).max().unwrap();
            assert!(most <= 2, "load {load} N/m: {most} evaluations a step at rest");
        }
    }

    #[test]
    fn the_evaluation_budget_bounds_every_step() {
        let run = |budget: usize| {
            let p = WireParams {
                segment_length_m: 2e-3,
                max_nodes: 40,
                max_evaluations: budget,
                ..WireParams::default()
            };
            let mut w = Wire::new(&p, Vec3::zeros(), Vec3::x(), 0.03).unwrap();
            let tube = StraightTube::new(Vec3::new(-0.01, 0.0, 0.0), Vec3::x(), 0.2, 1.5e-3, false).unwrap();
            w.set_line_load(Vec3::new(0.0, 3.0, 0.0));
            let (mut most, mut spent) = (0, 0);
            for k in 0..300 {
                w.set_hub(0.03 + 1e-4 * k as f64, 0.002 * k as f64);
                let r = w.step(&tube).unwrap();
                assert!(r.evaluations <= budget, "{} > {budget}", r.evaluations);
                most = most.max(r.evaluations);
                spent += r.budget_spent as usize;
                assert!(w.is_finite());
            }
            (most, spent, w.tip())
        };
        let (free_most, free_spent, free_tip) = run(1000);
        assert_eq!(free_spent, 0);
        assert!(
            free_most > 4,
            "the wire needed only {free_most} evaluations: no test of the budget"
        );
        let (most, spent, _) = run(4);
        assert!(most <= 4 && spent > 0, "most {most}, spent {spent}");
        let (_, _, tip) = run(free_most);
        assert_eq!(tip, free_tip, "a budget never reached changed the run");
    }

    /// The hand pulls the wire back by a few micrometres in one step: the
    /// hub edge starts the step stretched to six times the grip's limit.
    /// The Newton update lands where the grip holds, so the wire follows
    /// the hand (no friction: as far as the hand went) with the grip
    /// holding, at most one evaluation dearer than a pull a hundred times
    /// shorter, which the grip holds from the start. Assembled where the
    /// grip slips, the Hessian had no axial stiffness there and the model
    /// slid the whole wire through the hand: the line search found no
    /// decrease, the step ended where it began with the grip slipping and
    /// a 10 N residual.
    #[test]
    fn a_pull_past_the_grips_limit_is_followed_with_the_grip_holding() {
        let p = WireParams {
            segment_length_m: 2e-3,
            max_nodes: 40,
            friction: 0.0,
            ..WireParams::default()
        };
        let mut w = Wire::new(&p, Vec3::zeros(), Vec3::x(), 0.03).unwrap();
        let tube = StraightTube::new(Vec3::new(-0.01, 0.0, 0.0), Vec3::x(), 0.2, 1.5e-3, false).unwrap();
        for _ in 0..100 {
            w.step(&tube).unwrap();
        }
        let k1 = p.youngs_modulus_pa * p.area() / p.segment_length_m;
        let pull = |w: &mut Wire, d: f64| {
            let tip = w.tip();
            w.set_hub(w.inserted() - d, 0.0);
            let r = w.step(&tube).unwrap();
            (r, (tip - w.tip()).x)
        };
        // Six times the grip's limit, and 6 % of it.
        let d = 6.0 * p.max_hub_force_n / k1;
        let (rc, back_c) = pull(&mut w.clone(), 0.01 * d);
        let (r, back) = pull(&mut w, d);
        assert!(
            r.evaluations <= rc.evaluations + 1,
            "{} evaluations against {} for a pull the grip holds: {r:?}",
            r.evaluations,
            rc.evaluations
        );
        assert!(!r.grip_slipped, "the grip slipped: {r:?}");
        assert!(
            (back - 100.0 * back_c).abs() < 0.05 * back && (back - d).abs() < 0.05 * d,
            "the tip came back {back:e} m of {d:e}, the short pull's {back_c:e}: {r:?}"
        );
    }

    /// A restore takes the hub force back with the state: a wire whose
    /// failed step left its hub force at the grip's limit, returned to a
    /// good state saved at rest, feeds in again on the next step (with the
    /// failed step's hub force it fed nothing).
    #[test]
    fn a_restored_wire_feeds_in_again_after_a_step_at_the_grips_limit() {
        let p = WireParams {
            segment_length_m: 2e-3,
            max_nodes: 40,
            ..WireParams::default()
        };
        let mut w = Wire::new(&p, Vec3::zeros(), Vec3::x(), 0.03).unwrap();
        let tube = StraightTube::new(Vec3::new(-0.01, 0.0, 0.0), Vec3::x(), 0.2, 1.5e-3, false).unwrap();
        for _ in 0..20 {
            w.step(&tube).unwrap();
        }
        w.save_good_state();
        let good = w.inserted();
        // A step that failed pushing against the grip's limit (a fault the
        // service resets from) leaves that hub force behind.
        w.last_axial = p.max_hub_force_n;
        w.restore_good_state();
        assert_eq!(w.inserted(), good);
        w.set_hub(good + 1e-3, 0.0);
        w.step(&tube).unwrap();
        assert!(
            w.inserted() > good + 1e-4,
            "fed {} m after the restore",
            w.inserted() - good
        );
    }

    /// A wire pressed by a sideways load into the corner of a hexagonal
    /// duct, whose wall distance has a kink along the corner (the smaller
    /// of two faces' distances): its nodes settle on that ridge, where a
    /// Newton update that is downhill for one face is uphill for the
    /// other. The line search stops when the energy's secant slope does
    /// not fall as the trial shortens, instead of halving twelve times.
    #[test]
    fn a_line_search_stops_at_a_kink_of_the_wall() {
        use crate::wire::lumen::{tube_wall, TriangleLumen};
        // A hexagonal duct of circumradius 1.2 mm along x, wound inward,
        // with a corner straight below the axis (−y).
        let (v, t) = tube_wall(-0.01, 0.2, 1.2e-3, 6, 40, -std::f64::consts::FRAC_PI_2);
        let duct = TriangleLumen::new(&v, &t).unwrap();
        let p = WireParams {
            segment_length_m: 2e-3,
            max_nodes: 40,
            friction: 0.0,
            ..WireParams::default()
        };
        let mut w = Wire::new(&p, Vec3::zeros(), Vec3::x(), 0.06).unwrap();
        w.set_line_load(Vec3::new(0.0, -3.0, 0.0));
        let (mut most, mut on_ridge) = (0, 0);
        for k in 0..300 {
            w.set_hub(0.06 + 2e-5 * (k as f64 * 0.05).sin(), 0.0);
            let r = w.step(&duct).unwrap();
            assert!(w.is_finite());
            if k >= 100 {
                most = most.max(r.evaluations);
                // Nodes within a micrometre of the corner's plane x–y.
                on_ridge += w.positions()[2..].iter().filter(|x| x.z.abs() < 1e-6).count();
            }
        }
        assert!(
            on_ridge > 1000,
            "{on_ridge} node-steps on the ridge: no test of the kink"
        );
        assert!(most <= 8, "a step took {most} evaluations");
    }
}
