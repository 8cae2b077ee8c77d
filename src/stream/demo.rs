//! A synthetic stream source: a probe pressing a smooth dent into the top of
//! the vessel surface and releasing it (period 3 s, 8 mm deep, 20 mm wide), with a
//! spring-like force. It is not physics; it exercises the stream, the viewer
//! and the tools without the haptic service (`nvtmm stream-demo`, tests).

use super::{flags, InstrumentLine, StateFrame, Topology};
use crate::math::Vec3;
use crate::mesh::TetMesh;

/// The dent generator; see the module doc.
#[derive(Debug, Clone)]
pub struct Dent {
    rest: Vec<Vec3>,
    centre: Vec3,
    normal: Vec3,
    positions: Vec<[f32; 3]>,
    /// Dent radius on the surface (m).
    pub radius_m: f64,
    /// Largest dent depth (m).
    pub depth_m: f64,
    /// Press-and-release period (s).
    pub period_s: f64,
    /// Probe sphere radius (m).
    pub tool_radius_m: f64,
    /// Spring constant for the force (N/m).
    pub stiffness_n_per_m: f64,
    wire: Vec<[f32; 3]>,
}

impl Dent {
    /// A dent at the topology's highest vertex, pressed along that node's
    /// inward normal.
    pub fn new(mesh: &TetMesh, topology: &Topology) -> Dent {
        let rest: Vec<Vec3> = topology
            .rest_positions
            .iter()
            .map(|p| Vec3::new(p[0] as f64, p[1] as f64, p[2] as f64))
            .collect();
        let top = (0..rest.len())
            .max_by(|&a, &b| rest[a].z.total_cmp(&rest[b].z))
            .unwrap_or(0);
        let normals = mesh.surface_vertex_normals();
        let normal = topology
            .node_ids
            .get(top)
            .and_then(|&n| normals.get(n as usize))
            .copied()
            .filter(|n| n.norm() > 0.5)
            .unwrap_or(Vec3::z());
        Dent {
            wire: Vec::with_capacity(super::MAX_INSTRUMENT_POINTS),
            centre: rest.get(top).copied().unwrap_or_default(),
            positions: topology.rest_positions.clone(),
            rest,
            normal,
            radius_m: 0.02,
            depth_m: 0.008,
            period_s: 3.0,
            tool_radius_m: 0.004,
            stiffness_n_per_m: 300.0,
        }
    }

    /// Dent depth at time `t` (m).
    pub fn depth(&self, t: f64) -> f64 {
        self.depth_m * 0.5 * (1.0 - (std::f64::consts::TAU * t / self.period_s).cos())
    }

    /// The frame at simulation time `t`, handed to `use_frame`: two
    /// instruments, the probe (its sphere's centre) and a guidewire.
    pub fn with_frame<T>(&mut self, t: f64, use_frame: impl FnOnce(&StateFrame<'_>) -> T) -> T {
        let d = self.depth(t);
        for (p, x) in self.positions.iter_mut().zip(&self.rest) {
            let r2 = (x - self.centre).norm_squared() / (self.radius_m * self.radius_m);
            let w = if r2 < 1.0 { (1.0 - r2) * (1.0 - r2) } else { 0.0 };
            let y = x - self.normal * (d * w);
            *p = [y.x as f32, y.y as f32, y.z as f32];
        }
        let tool = self.centre + self.normal * (self.tool_radius_m - d);
        let f = self.normal * (self.stiffness_n_per_m * d);
        let mut fl = flags::DEVICE_SIMULATED;
        if d > 1e-5 {
            fl |= flags::IN_CONTACT;
        }
        // A guidewire polyline growing from the tool along the wall normal
        // (so a client sees the wire section of the frame change).
        self.wire.clear();
        let n = 4 + (t * 10.0) as usize % 16;
        for k in 0..n {
            let a = k as f64 * 0.3;
            let x = tool + self.normal * (k as f64 * 2e-3) + Vec3::new(a.cos(), a.sin(), 0.0) * 1e-3;
            self.wire.push([x.x as f32, x.y as f32, x.z as f32]);
        }
        let tool_position = [tool.x as f32, tool.y as f32, tool.z as f32];
        let probe = [tool_position];
        let lines = [
            InstrumentLine {
                id: 0,
                kind: 1,
                points: &probe,
            },
            InstrumentLine {
                id: 1,
                kind: 2,
                points: &self.wire,
            },
        ];
        use_frame(&StateFrame {
            time_s: t,
            positions: &self.positions,
            tool_position,
            tool_radius: self.tool_radius_m as f32,
            force: [f.x as f32, f.y as f32, f.z as f32],
            flags: fl,
            loop_rate_hz: 1000.0,
            tick_p99_us: 40.0 + 5.0 * (t * 0.7).sin() as f32,
            instruments: &lines,
        })
    }
}

/// Publishes `frames` dent frames, `1 / cfg.rate_hz` apart in simulation time
/// but as fast as possible in wall time, through a [`super::Publisher`] with
/// `record` (for tests and examples: a recording without waiting).
pub fn publish_frames(
    mesh: &TetMesh,
    topology: Topology,
    cfg: super::StreamConfig,
    record: Option<&std::path::Path>,
    frames: usize,
) -> Result<super::PublisherStats, super::StreamError> {
    let mut dent = Dent::new(mesh, &topology);
    let mut p = super::Publisher::new(cfg, topology, record)?;
    for k in 0..frames {
        let t = k as f64 * p.period_s();
        dent.with_frame(t, |f| p.publish(f))?;
    }
    p.finish()
}
