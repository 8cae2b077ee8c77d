//! The coarse state stream for renderers: a small, versioned, little-endian
//! binary format (documented byte by byte in `docs/STREAM.md`) carrying a
//! decimated vessel surface, the tool and the haptic force at 30–60 Hz over
//! UDP, recordable to a file, with a reference web viewer.
//!
//! - [`decimate`] builds the stream's [`Topology`] from a [`TetMesh`]'s
//!   surface (vertex clustering).
//! - [`format`](mod@format) encodes messages into datagrams and [`format::Decoder`]
//!   reassembles and validates them (never panics, counts every rejection).
//! - [`publisher::Publisher`] sends frames from a non-RT thread (non-blocking
//!   UDP, optional recording); [`record`] reads recordings, replays them and
//!   exports them for ParaView; [`viewer`] serves the browser viewer.
//! - [`demo`] is a synthetic source (a dent moving on the surface) for trying
//!   the viewer and for tests without the haptic service.
//!
//! Nothing here runs on the haptic loop: the service's stream thread
//! reconstructs positions from the latest state and calls
//! [`publisher::Publisher::publish`].

pub mod decimate;
pub mod demo;
pub mod drive;
pub mod format;
pub mod igtl;
pub mod publisher;
pub mod record;
pub mod viewer;

use crate::config::{Checker, ConfigError};
use crate::mesh::TetMesh;
use std::net::SocketAddr;
use std::path::PathBuf;

pub use format::{Decoded, Decoder, DecoderStats, OwnedState, RejectReason};
pub use publisher::{Publisher, PublisherStats};

/// Status bits of a state frame ([`StateFrame::flags`]). Bits not listed are
/// reserved: senders write 0, receivers ignore them.
pub mod flags {
    /// The watchdog is active: the output force is being ramped to zero.
    pub const WATCHDOG_ACTIVE: u32 = 1 << 0;
    /// The tool touches the vessel surface.
    pub const IN_CONTACT: u32 = 1 << 1;
    /// The output force was limited (device saturation or the passivity QP
    /// changed the model's force).
    pub const FORCE_LIMITED: u32 = 1 << 2;
    /// The haptic loop runs with the real-time policy it asked for.
    pub const RT_GRANTED: u32 = 1 << 3;
    /// A new reduced model was swapped in since the previous state frame.
    pub const MODEL_REFRESHED: u32 = 1 << 4;
    /// The device is simulated (no hardware).
    pub const DEVICE_SIMULATED: u32 = 1 << 5;
    /// Names of the defined bits, lowest first (for printing).
    pub const NAMES: [(u32, &str); 6] = [
        (WATCHDOG_ACTIVE, "watchdog"),
        (IN_CONTACT, "contact"),
        (FORCE_LIMITED, "limited"),
        (RT_GRANTED, "rt"),
        (MODEL_REFRESHED, "refreshed"),
        (DEVICE_SIMULATED, "simulated"),
    ];
}

/// The stream's surface: what a renderer needs once per topology epoch.
///
/// Positions are in metres, triangles are counter-clockwise seen from
/// outside (outward normals), indices refer to `rest_positions`.
#[derive(Debug, Clone, PartialEq)]
pub struct Topology {
    /// Changes whenever the vertex set or triangles change; state frames
    /// carry the epoch of the topology their positions index.
    pub epoch: u32,
    /// Rest position of each stream vertex (m).
    pub rest_positions: Vec<[f32; 3]>,
    /// Triangles (indices into `rest_positions`).
    pub triangles: Vec<[u32; 3]>,
    /// The mesh node each stream vertex follows (its position in a state
    /// frame is that node's current position).
    pub node_ids: Vec<u32>,
}

impl Topology {
    /// Number of stream vertices.
    pub fn num_vertices(&self) -> usize {
        self.rest_positions.len()
    }

    /// Checks the invariants the format relies on: one node id per vertex,
    /// triangle indices in range, finite positions.
    pub fn check(&self) -> Result<(), String> {
        let n = self.rest_positions.len();
        if self.node_ids.len() != n {
            return Err(format!("{} node ids for {n} vertices", self.node_ids.len()));
        }
        if let Some(i) = self
            .rest_positions
            .iter()
            .position(|p| !p.iter().all(|v| v.is_finite()))
        {
            return Err(format!("rest position of vertex {i} is not finite"));
        }
        if let Some((k, t)) = self
            .triangles
            .iter()
            .enumerate()
            .find(|(_, t)| t.iter().any(|&i| i as usize >= n))
        {
            return Err(format!("triangle {k} {t:?} refers to a vertex >= {n}"));
        }
        Ok(())
    }

    /// Current stream positions from mesh displacements `u` (per mesh node,
    /// metres): `rest[node] + u[node]` for each stream vertex, written into
    /// `out` (resized to the vertex count, no allocation once sized).
    pub fn positions_from_displacement(&self, mesh: &TetMesh, u: &[crate::math::Vec3], out: &mut Vec<[f32; 3]>) {
        out.resize(self.node_ids.len(), [0.0; 3]);
        let rest = mesh.rest();
        for (o, &id) in out.iter_mut().zip(&self.node_ids) {
            let i = id as usize;
            let x = rest.get(i).copied().unwrap_or_default() + u.get(i).copied().unwrap_or_default();
            *o = [x.x as f32, x.y as f32, x.z as f32];
        }
    }
}

/// One state sample to publish; the publisher adds the sequence number and
/// the topology epoch.
#[derive(Debug, Clone, Copy)]
pub struct StateFrame<'a> {
    /// Simulation time (s).
    pub time_s: f64,
    /// Current position of each topology vertex (m).
    pub positions: &'a [[f32; 3]],
    /// Tool (probe tip sphere) centre (m).
    pub tool_position: [f32; 3],
    /// Tool sphere radius (m).
    pub tool_radius: f32,
    /// Force rendered to the user's hand (N, world frame).
    pub force: [f32; 3],
    /// Status bits, see [`flags`].
    pub flags: u32,
    /// Measured haptic loop rate (Hz).
    pub loop_rate_hz: f32,
    /// 99th percentile of the loop's tick compute time (µs).
    pub tick_p99_us: f32,
    /// One polyline per instrument, in the sender's order (at most
    /// [`MAX_FRAME_INSTRUMENTS`], each at most [`MAX_INSTRUMENT_POINTS`]).
    pub instruments: &'a [InstrumentLine<'a>],
}

/// An instrument's polyline in a state frame: its id and kind, and its
/// centreline hub to tip (m; a probe's is its sphere's centre).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InstrumentLine<'a> {
    /// The instrument's id in the sender's run (its index in the list).
    pub id: u8,
    /// Its kind ([`instrument_kind`]: 1 probe, 2 guidewire, 3 catheter).
    pub kind: u8,
    /// The points (m).
    pub points: &'a [[f32; 3]],
}

/// The name of an instrument kind code on the stream (docs/STREAM.md);
/// None for a code this build does not know (receivers keep such
/// polylines and show them unnamed).
pub fn instrument_kind(code: u8) -> Option<&'static str> {
    match code {
        1 => Some("probe"),
        2 => Some("guidewire"),
        3 => Some("catheter"),
        _ => None,
    }
}

/// Errors of the stream: configuration, sockets, files, bad frames.
#[derive(Debug, thiserror::Error)]
pub enum StreamError {
    /// Bad `[stream]` configuration.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// A socket could not be opened or bound.
    #[error("{what} {addr}: {source}")]
    Socket {
        /// What the socket is for.
        what: &'static str,
        /// The address.
        addr: String,
        /// The OS error.
        source: std::io::Error,
    },
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// A recording is malformed.
    #[error("{path}: {what}")]
    BadRecording {
        /// The file.
        path: PathBuf,
        /// What is wrong and where (byte offset).
        what: String,
    },
    /// A topology or frame does not fit the format or the current topology.
    #[error("invalid {what}: {msg}")]
    Invalid {
        /// Which input (topology, state frame, ...).
        what: &'static str,
        /// What is wrong.
        msg: String,
    },
    /// Writing a ParaView series failed.
    #[error(transparent)]
    Mesh(#[from] crate::mesh::io::MeshError),
}

/// The `[stream]` table of the service configuration.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct StreamConfig {
    /// Publish at all.
    pub enabled: bool,
    /// State frames per second, in [1, 120]; 30–60 is the intended range.
    pub rate_hz: f64,
    /// Where datagrams go, `IP:PORT` (loopback by default).
    pub target: String,
    /// Stream vertices to aim for when decimating the surface; 0 sends the
    /// full surface.
    pub decimate_vertices: usize,
    /// Seconds between topology re-sends (late-joining receivers wait at most
    /// this long), in [0.1, 60].
    pub topology_period_s: f64,
    /// The OpenIGTLink server for 3D Slicer and other OpenIGTLink peers
    /// ([`igtl`]); off when absent.
    pub igtl: Option<IgtlConfig>,
}

/// `[stream] igtl = { listen = "127.0.0.1:18944" }`.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct IgtlConfig {
    /// TCP address to listen on, `IP:PORT` (18944 is the protocol's usual
    /// port; loopback keeps it on this machine).
    pub listen: String,
    /// Clients served at once, in [1, 64].
    #[serde(default = "d_igtl_clients")]
    pub max_clients: usize,
    /// Frames queued per client before frames are dropped for it, in [1, 64].
    #[serde(default = "d_igtl_queue")]
    pub queue_frames: usize,
}

fn d_igtl_clients() -> usize {
    8
}

fn d_igtl_queue() -> usize {
    4
}

impl Default for StreamConfig {
    fn default() -> Self {
        StreamConfig {
            enabled: true,
            rate_hz: 60.0,
            target: "127.0.0.1:7878".into(),
            decimate_vertices: 2000,
            topology_period_s: 1.0,
            igtl: None,
        }
    }
}

/// Upper bound on stream vertices (keeps a state message under 4 MiB).
pub const MAX_VERTICES: usize = 300_000;

/// Most points of one instrument's polyline in a state frame.
pub const MAX_INSTRUMENT_POINTS: usize = 256;

/// Most instrument polylines in a state frame.
pub const MAX_FRAME_INSTRUMENTS: usize = 8;

impl StreamConfig {
    /// Checks ranges; keys are reported as `<prefix>.<field>` (prefix e.g.
    /// `stream`).
    pub fn validate(&self, c: &Checker, prefix: &str) -> Result<(), ConfigError> {
        let k = |f: &str| format!("{prefix}.{f}");
        c.f64_in(&k("rate_hz"), self.rate_hz, 1.0, 120.0, "Hz")?;
        c.f64_in(&k("topology_period_s"), self.topology_period_s, 0.1, 60.0, "s")?;
        c.int_in(&k("decimate_vertices"), self.decimate_vertices, 0, MAX_VERTICES)?;
        if let Some(g) = &self.igtl {
            g.listen.parse::<SocketAddr>().map_err(|_| {
                c.err(
                    &k("igtl.listen"),
                    format!("'{}': must be IP:PORT, e.g. 127.0.0.1:18944", g.listen),
                )
            })?;
            c.int_in(&k("igtl.max_clients"), g.max_clients, 1, 64)?;
            c.int_in(&k("igtl.queue_frames"), g.queue_frames, 1, 64)?;
        }
        self.target_addr().map_err(|msg| c.err(&k("target"), msg)).map(|_| ())
    }

    /// The target as a socket address.
    pub fn target_addr(&self) -> Result<SocketAddr, String> {
        self.target
            .parse()
            .map_err(|_| format!("'{}': must be IP:PORT, e.g. 127.0.0.1:7878", self.target))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::parse_toml;
    use std::path::Path;

    #[test]
    fn config_parses_validates_and_names_bad_keys() {
        let p = Path::new("rt-config/nvtmm.toml");
        let c: StreamConfig = parse_toml("rate_hz = 30\ntarget = \"127.0.0.1:9000\"", p).unwrap();
        assert_eq!(c.rate_hz, 30.0);
        assert!(c.enabled);
        c.validate(&Checker::new(p), "stream").unwrap();
        let bad = StreamConfig {
            rate_hz: 500.0,
            ..StreamConfig::default()
        };
        let e = bad.validate(&Checker::new(p), "stream").unwrap_err();
        assert_eq!(e.key, "stream.rate_hz");
        assert!(e.msg.contains("[1, 120]"), "{e}");
        let bad = StreamConfig {
            target: "localhost".into(),
            ..StreamConfig::default()
        };
        assert_eq!(
            bad.validate(&Checker::new(p), "stream").unwrap_err().key,
            "stream.target"
        );
        let e = parse_toml::<StreamConfig>("rate = 30", p).unwrap_err();
        assert!(e.msg.contains("rate"), "{e}");
    }
}
