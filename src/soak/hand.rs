//! The soak's careless hands: seeded random scripts for the simulated
//! Touch X. In a probe scene ([`random_hand`]), over every part of the
//! vessel wall the device can reach — slow presses that wander from point
//! to point, fast strikes up to the hand's top speed, long presses, and
//! slides along the wall. In a guidewire scene ([`random_wire_hand`]),
//! on the wire's hub — advances, pull-backs, quick jabs faster than the
//! drive follows, rolls either way, and pulls of the stylus off the
//! insertion axis against the virtual guide.

use crate::haptics::touchx::{GimbalWaypoint, Waypoint};
use crate::math::Vec3;
use crate::mesh::TetMesh;
use crate::service::instrument::guidewire::GuidewireConfig;
use crate::wire::WireParams;

/// The top speed of the soak's hand (m/s). A modelling choice: quick,
/// deliberate wrist and arm movements peak at about 1 m/s; the bridge
/// rejects anything above its `max_speed_m_s` (5 m/s) as implausible.
pub const HAND_TOP_SPEED_M_S: f64 = 1.0;

/// Counts of the script's moves.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct HandMoves {
    /// Slow presses wandering to a nearby point.
    pub walks: u32,
    /// Fast strikes.
    pub strikes: u32,
    /// Presses held for seconds.
    pub long_presses: u32,
    /// Slides along the wall.
    pub slides: u32,
    /// Guidewire hand: advances of the wire.
    #[serde(default)]
    pub advances: u32,
    /// Guidewire hand: pull-backs.
    #[serde(default)]
    pub pullbacks: u32,
    /// Guidewire hand: quick jabs in or out, faster than the drive follows.
    #[serde(default)]
    pub jabs: u32,
    /// Guidewire hand: rolls of the stylus.
    #[serde(default)]
    pub rolls: u32,
    /// Guidewire hand: pulls of the stylus off the insertion axis.
    #[serde(default)]
    pub off_axis: u32,
    /// Presses of the switch button (a catheter over the wire: the hand
    /// changes the instrument it works, at random, often mid-push).
    #[serde(default)]
    pub switches: u32,
}

/// A small reproducible generator (SplitMix64).
#[derive(Debug, Clone)]
pub struct Rng(u64);

impl Rng {
    /// Seeded.
    pub fn new(seed: u64) -> Rng {
        Rng(seed)
    }

    /// Next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [lo, hi).
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * ((self.next_u64() >> 11) as f64 / (1u64 << 53) as f64)
    }

    /// Uniform index below `n` (n > 0).
    pub fn index(&mut self, n: usize) -> usize {
        (self.next_u64() % n.max(1) as u64) as usize
    }
}

/// Wall points the device can reach: surface node positions and outward
/// normals, in the device frame.
struct Targets {
    points: Vec<(Vec3, Vec3)>,
}

impl Targets {
    fn new(mesh: &TetMesh, origin: Vec3, half: Vec3, radius: f64) -> Targets {
        let normals = mesh.surface_vertex_normals();
        let nodes: Vec<u32> = match mesh.node_set("outer_wall") {
            Some(s) if !s.is_empty() => s.to_vec(),
            _ => mesh.surface_nodes(),
        };
        let margin = 0.025 + radius;
        let points = nodes
            .iter()
            .filter_map(|&i| {
                let x = mesh.rest()[i as usize] - origin;
                let n = normals[i as usize];
                let inside = (0..3).all(|a| x[a].abs() + margin < half[a]);
                (inside && n.norm() > 0.5).then(|| (x, n.normalize()))
            })
            .collect();
        Targets { points }
    }

    /// The reachable point nearest to `x` among a few random ones within `reach` of it.
    fn near(&self, rng: &mut Rng, x: Vec3, reach: f64) -> (Vec3, Vec3) {
        for _ in 0..64 {
            let p = self.points[rng.index(self.points.len())];
            if (p.0 - x).norm() <= reach {
                return p;
            }
        }
        self.points[rng.index(self.points.len())]
    }
}

/// The script: `seconds` of random moves over the wall points of `mesh`
/// that a device centred at `origin` (scene frame, m) with workspace
/// half-extents `half` (m) reaches, for a tool sphere of `radius` (m).
/// `strike_fraction` of the moves are fast strikes. Returns the waypoints
/// (device frame) and the move counts; None if no wall point is reachable.
pub fn random_hand(
    mesh: &TetMesh,
    origin: Vec3,
    half: Vec3,
    radius: f64,
    seconds: f64,
    strike_fraction: f64,
    seed: u64,
) -> Option<(Vec<Waypoint>, HandMoves)> {
    let targets = Targets::new(mesh, origin, half, radius);
    if targets.points.is_empty() {
        return None;
    }
    let mut rng = Rng::new(seed);
    let mut moves = HandMoves::default();
    let mut pts: Vec<Waypoint> = Vec::new();
    let mut t = 0.0;
    let (mut p, mut n) = targets.points[rng.index(targets.points.len())];
    let mut x = p + n * (radius + 0.01);
    pts.push(Waypoint { t_s: 0.0, position: x });
    let go = |pts: &mut Vec<Waypoint>, t: &mut f64, x: &mut Vec3, to: Vec3, speed: f64| {
        let d = (to - *x).norm();
        *t += (d / speed).max(0.02);
        *x = to;
        pts.push(Waypoint { t_s: *t, position: to });
    };
    let hold = |pts: &mut Vec<Waypoint>, t: &mut f64, x: Vec3, dur: f64| {
        *t += dur;
        pts.push(Waypoint { t_s: *t, position: x });
    };
    while t < seconds + 1.0 {
        let r = rng.range(0.0, 1.0);
        if r < strike_fraction {
            // A strike: back off, then hit the wall at up to the top speed.
            moves.strikes += 1;
            (p, n) = targets.near(&mut rng, p, 0.03);
            let back = p + n * (radius + rng.range(0.01, 0.02));
            go(&mut pts, &mut t, &mut x, back, 0.1);
            let hit = p + n * (radius - rng.range(0.002, 0.006));
            go(&mut pts, &mut t, &mut x, hit, rng.range(0.3, 1.0) * HAND_TOP_SPEED_M_S);
            hold(&mut pts, &mut t, x, rng.range(0.05, 0.3));
            go(&mut pts, &mut t, &mut x, back, 0.2);
        } else if r < strike_fraction + 0.2 {
            // A long press.
            moves.long_presses += 1;
            (p, n) = targets.near(&mut rng, p, 0.03);
            let above = p + n * (radius + 0.005);
            go(&mut pts, &mut t, &mut x, above, 0.05);
            let pressed = p + n * (radius - rng.range(0.002, 0.006));
            go(&mut pts, &mut t, &mut x, pressed, 0.02);
            hold(&mut pts, &mut t, x, rng.range(2.0, 5.0));
            go(&mut pts, &mut t, &mut x, above, 0.02);
        } else if r < strike_fraction + 0.45 {
            // A slide along the wall through a few nearby points.
            moves.slides += 1;
            let depth = rng.range(0.001, 0.004);
            for _ in 0..4 {
                (p, n) = targets.near(&mut rng, p, 0.012);
                go(&mut pts, &mut t, &mut x, p + n * (radius - depth), 0.03);
            }
            go(&mut pts, &mut t, &mut x, p + n * (radius + 0.005), 0.03);
        } else {
            // A slow press that wanders to another point.
            moves.walks += 1;
            (p, n) = targets.near(&mut rng, p, 0.04);
            let above = p + n * (radius + 0.005);
            go(&mut pts, &mut t, &mut x, above, 0.05);
            let pressed = p + n * (radius - rng.range(0.001, 0.005));
            go(&mut pts, &mut t, &mut x, pressed, 0.03);
            hold(&mut pts, &mut t, x, rng.range(0.2, 1.0));
            go(&mut pts, &mut t, &mut x, above, 0.03);
        }
    }
    Some((pts, moves))
}

/// The wire's hub speed of the guidewire hand's quick jabs (m/s of wire,
/// up to): half again the drive's usual limit (`drive.max_speed_m_s`,
/// 0.1 m/s), so the drive's rate limit is exercised too.
pub const WIRE_JAB_SPEED_M_S: f64 = 0.15;

/// How far the guidewire hand pulls the stylus off the insertion axis
/// (m, up to): against the virtual guide (200 N/m in the shipped scene,
/// so up to 1.2 N).
pub const WIRE_OFF_AXIS_M: f64 = 0.006;

/// The guidewire scene's script: `seconds` of random hub motions through
/// the inverse of the drive's map (as [`crate::service::instrument::guidewire::hand_script`]
/// maps the configured script). The inserted length stays between the
/// start (`guidewire.inserted_m`) and the farthest the configured script
/// goes plus 10 mm (or 0.1 m past the start without a script), within
/// what the wire inserts and with the stylus inside the workspace
/// (half-extents `half`, device frame); the roll stays within ±π of the
/// start. `jab_fraction` of the moves are quick jabs. Returns the stylus
/// waypoints and gimbal angles (device frame, one shared clock) and the
/// move counts; None if the drive's map leaves no room to move.
pub fn random_wire_hand(
    g: &GuidewireConfig,
    wire: &WireParams,
    half: Vec3,
    seconds: f64,
    jab_fraction: f64,
    seed: u64,
) -> Option<(Vec<Waypoint>, Vec<GimbalWaypoint>, HandMoves)> {
    let d = &wire.drive;
    let axis = Vec3::from(d.axis).try_normalize(1e-12)?;
    if d.insertion_scale <= 0.0 {
        return None;
    }
    let stylus = |ins: f64| d.stylus_at(ins);
    let inside = |x: Vec3| (0..3).all(|a| x[a].abs() + WIRE_OFF_AXIS_M + 0.005 < half[a]);
    let farthest = g.script.iter().map(|r| r[1]).fold(f64::NEG_INFINITY, f64::max);
    let hi = if farthest.is_finite() {
        farthest + 0.01
    } else {
        g.inserted_m + 0.1
    };
    let lo_want = g.inserted_m;
    let hi_want = hi.min(wire.max_inserted_m());
    // Shrink the range to what keeps the stylus in the workspace.
    let steps = 200;
    let ok: Vec<f64> = (0..=steps)
        .map(|k| lo_want + (hi_want - lo_want) * k as f64 / steps as f64)
        .filter(|&i| inside(stylus(i)))
        .collect();
    let (lo, hi) = (*ok.first()?, *ok.last()?);
    if hi - lo < 0.005 {
        return None;
    }
    let side = crate::wire::lumen::perpendicular(axis);
    let side2 = axis.cross(&side);
    let roll_speed = d.max_roll_speed_rad_s.clamp(0.5, 10.0);
    let mut rng = Rng::new(seed);
    let mut moves = HandMoves::default();
    // The hand's state: time, inserted length, roll, sideways offset.
    let (mut t, mut ins, mut roll, mut off) = (0.0, lo, 0.0_f64, Vec3::zeros());
    let mut pts = Vec::new();
    let mut gim = Vec::new();
    let push = |pts: &mut Vec<Waypoint>, gim: &mut Vec<GimbalWaypoint>, t: f64, ins: f64, roll: f64, off: Vec3| {
        pts.push(Waypoint {
            t_s: t,
            position: stylus(ins) + off,
        });
        gim.push(GimbalWaypoint {
            t_s: t,
            angles_rad: d.gimbal_for(roll),
        });
    };
    push(&mut pts, &mut gim, t, ins, roll, off);
    // Hold still for the service's ramp-in.
    t += 1.0;
    push(&mut pts, &mut gim, t, ins, roll, off);
    while t < seconds + 1.0 {
        let r = rng.range(0.0, 1.0);
        let (mut to_ins, mut to_roll, mut to_off) = (ins, roll, off);
        let dur;
        if r < jab_fraction {
            // A quick jab in or out and a short hold.
            moves.jabs += 1;
            let dl = rng.range(0.003, 0.012) * if rng.range(0.0, 1.0) < 0.6 { 1.0 } else { -1.0 };
            to_ins = (ins + dl).clamp(lo, hi);
            dur = (to_ins - ins).abs() / rng.range(0.5, 1.0) / WIRE_JAB_SPEED_M_S;
        } else if r < jab_fraction + 0.35 {
            // An advance, rolling on the way one time in three.
            moves.advances += 1;
            to_ins = (ins + rng.range(0.005, 0.05)).min(hi);
            dur = (to_ins - ins) / rng.range(0.01, 0.06);
            if rng.range(0.0, 1.0) < 1.0 / 3.0 {
                to_roll = rng.range(-3.0, 3.0);
            }
        } else if r < jab_fraction + 0.5 {
            // A pull-back.
            moves.pullbacks += 1;
            to_ins = (ins - rng.range(0.005, 0.04)).max(lo);
            dur = (ins - to_ins) / rng.range(0.01, 0.05);
        } else if r < jab_fraction + 0.75 {
            // A roll either way, the hub held.
            moves.rolls += 1;
            to_roll = rng.range(-3.0, 3.0);
            dur = 0.0;
        } else if r < jab_fraction + 0.85 {
            // The stylus pulled off the axis (or back onto it).
            moves.off_axis += 1;
            to_off = if off == Vec3::zeros() {
                let a = rng.range(0.0, std::f64::consts::TAU);
                (side * a.cos() + side2 * a.sin()) * rng.range(0.001, WIRE_OFF_AXIS_M)
            } else {
                Vec3::zeros()
            };
            dur = (to_off - off).norm() / rng.range(0.01, 0.05);
        } else {
            // A pause.
            dur = rng.range(0.2, 1.0);
        }
        let dur = dur.max((to_roll - roll).abs() / roll_speed).max(0.02);
        t += dur;
        (ins, roll, off) = (to_ins, to_roll, to_off);
        push(&mut pts, &mut gim, t, ins, roll, off);
        // A short hold after each move.
        t += rng.range(0.05, 0.4);
        push(&mut pts, &mut gim, t, ins, roll, off);
    }
    Some((pts, gim, moves))
}

/// The careless hand's switch button: presses of
/// [`crate::service::instrument::SWITCH_BUTTON`] at random times, 0.3 to 4 s
/// apart, each held 30 to 200 ms, over `seconds`, regardless of what the
/// stylus is doing (so many land mid-push). Returns the button script
/// ((time s, buttons from then on), for
/// [`crate::haptics::touchx::TouchXSim::set_button_script`]) and the count.
pub fn random_switches(seconds: f64, seed: u64) -> (Vec<(f64, u32)>, u32) {
    let mut rng = Rng::new(seed ^ 0x5717C4);
    let (mut t, mut rows, mut n) = (1.0, Vec::new(), 0);
    while t < seconds {
        t += rng.range(0.3, 4.0);
        rows.push((t, crate::service::instrument::SWITCH_BUTTON));
        t += rng.range(0.03, 0.2);
        rows.push((t, 0));
        n += 1;
    }
    (rows, n)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_switch_presses_are_reproducible_and_released_between() {
        let (rows, n) = random_switches(60.0, 5);
        assert!(n >= 10, "{n} presses in 60 s");
        assert_eq!(rows.len(), 2 * n as usize);
        for (k, w) in rows.windows(2).enumerate() {
            assert!(w[1].0 > w[0].0);
            assert_eq!(
                w[0].1,
                if k % 2 == 0 {
                    crate::service::instrument::SWITCH_BUTTON
                } else {
                    0
                }
            );
        }
        assert_eq!(random_switches(60.0, 5).0, rows);
    }

    #[test]
    fn the_hand_stays_in_the_workspace_and_under_the_top_speed() {
        let arch = crate::mesh::arch::generate(&crate::mesh::arch::ArchParams::default(), 1458).unwrap();
        let origin = Vec3::new(0.0065, -0.031, 0.177);
        let half = Vec3::new(0.08, 0.06, 0.06);
        let (pts, moves) = random_hand(&arch.mesh, origin, half, 0.003, 60.0, 0.2, 7).unwrap();
        assert!(pts.last().unwrap().t_s >= 60.0);
        assert!(moves.strikes > 0 && moves.walks > 0 && moves.slides > 0 && moves.long_presses > 0);
        let mut fastest: f64 = 0.0;
        for w in pts.windows(2) {
            assert!(w[1].t_s > w[0].t_s);
            fastest = fastest.max((w[1].position - w[0].position).norm() / (w[1].t_s - w[0].t_s));
        }
        assert!(fastest <= HAND_TOP_SPEED_M_S * (1.0 + 1e-9), "{fastest}");
        assert!(fastest > 0.3, "strikes are fast: {fastest}");
        for w in &pts {
            for a in 0..3 {
                assert!(w.position[a].abs() < half[a], "{:?}", w.position);
            }
        }
        // The same seed gives the same script.
        let (again, _) = random_hand(&arch.mesh, origin, half, 0.003, 60.0, 0.2, 7).unwrap();
        assert_eq!(pts.len(), again.len());
    }

    /// The guidewire hand, through the shipped scene's drive map: the wire
    /// goes in and out within its range, jabs faster than the drive
    /// follows, rolls both ways within ±π, leaves the axis by at most
    /// `WIRE_OFF_AXIS_M`, and the stylus stays in the workspace.
    #[test]
    fn the_wire_hand_moves_the_hub_within_its_range_and_the_workspace() {
        let cfg = crate::service::ServiceConfig::load(std::path::Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/rt-config/guidewire.toml"
        )))
        .unwrap();
        let (g, wire) = (cfg.guidewire.as_ref().unwrap(), cfg.wire.as_ref().unwrap());
        let half = Vec3::new(0.08, 0.06, 0.06);
        let (pts, gim, moves) = random_wire_hand(g, wire, half, 60.0, 0.2, 3).unwrap();
        assert_eq!(pts.len(), gim.len());
        assert!(pts.last().unwrap().t_s >= 60.0);
        assert!(
            moves.advances > 0 && moves.pullbacks > 0 && moves.jabs > 0 && moves.rolls > 0 && moves.off_axis > 0,
            "{moves:?}"
        );
        let d = &wire.drive;
        let axis = Vec3::from(d.axis).normalize();
        let origin = Vec3::from(d.origin_m);
        let inserted = |p: Vec3| d.inserted_at_origin_m + (p - origin).dot(&axis) * d.insertion_scale;
        let (mut lo, mut hi, mut fastest) = (f64::INFINITY, f64::NEG_INFINITY, 0.0_f64);
        let (mut roll_lo, mut roll_hi) = (0.0_f64, 0.0_f64);
        for (w, a) in pts.windows(2).zip(gim.windows(2)) {
            assert!(w[1].t_s > w[0].t_s && a[1].t_s == w[1].t_s);
            let v = (inserted(w[1].position) - inserted(w[0].position)).abs() / (w[1].t_s - w[0].t_s);
            fastest = fastest.max(v);
            let roll = a[1].angles_rad[d.roll_index] * d.roll_scale;
            (roll_lo, roll_hi) = (roll_lo.min(roll), roll_hi.max(roll));
        }
        for w in &pts {
            let i = inserted(w.position);
            (lo, hi) = (lo.min(i), hi.max(i));
            let along = origin + axis * (w.position - origin).dot(&axis);
            assert!((w.position - along).norm() <= WIRE_OFF_AXIS_M + 1e-12);
            for a in 0..3 {
                assert!(w.position[a].abs() < half[a], "{:?}", w.position);
            }
        }
        assert!((lo - g.inserted_m).abs() < 1e-9, "{lo}");
        assert!(hi > 0.15 && hi <= 0.175 + 0.01 + 1e-9, "{hi}");
        assert!(
            fastest > d.max_speed_m_s && fastest <= WIRE_JAB_SPEED_M_S * (1.0 + 1e-9),
            "{fastest}"
        );
        assert!(roll_lo < -2.0 && roll_hi > 2.0 && roll_lo >= -3.0 && roll_hi <= 3.0);
        let (again, _, _) = random_wire_hand(g, wire, half, 60.0, 0.2, 3).unwrap();
        assert_eq!(pts.len(), again.len());
    }
}
