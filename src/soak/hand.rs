//! The soak's careless hand: a seeded random script for the simulated
//! Touch X over every part of the vessel wall the device can reach — slow
//! presses that wander from point to point, fast strikes up to the hand's
//! top speed, long presses, and slides along the wall.

use crate::haptics::touchx::Waypoint;
use crate::math::Vec3;
use crate::mesh::TetMesh;

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

#[cfg(test)]
mod tests {
    use super::*;

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
}
