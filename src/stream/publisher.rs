//! Sends state frames over UDP (and into a recording) from a non-RT thread.
//!
//! The caller (the service's stream thread) builds positions from the latest
//! state it got off the haptic/background rings and calls
//! [`Publisher::publish`] at [`StreamConfig::rate_hz`]. Sends are
//! non-blocking and a failed send is counted, never an error: a missing
//! renderer must not disturb the simulator. Buffers are reused, so a publish
//! allocates nothing once the first frame has been sent.

use super::format::{self, KIND_STATE, KIND_TOPOLOGY, MAX_CHUNK_PAYLOAD, MAX_MESSAGE_LEN};
use super::record::RecordWriter;
use super::{StateFrame, StreamConfig, StreamError, Topology};
use crate::config::Checker;
use crate::rt::clock;
use std::io::ErrorKind;
use std::net::{SocketAddr, UdpSocket};
use std::path::{Path, PathBuf};

/// Publisher counters.
#[derive(Debug, Clone, Default, PartialEq, Eq, serde::Serialize)]
pub struct PublisherStats {
    /// State frames published.
    pub frames: u64,
    /// Topology messages sent (first frame, periodic re-sends, epoch changes).
    pub topologies: u64,
    /// Datagrams handed to the socket successfully.
    pub datagrams: u64,
    /// Bytes in those datagrams.
    pub bytes: u64,
    /// Sends that failed because the socket buffer was full.
    pub would_block: u64,
    /// Sends that failed otherwise (no route, refused, ...).
    pub send_errors: u64,
    /// Frames refused (wrong vertex count, non-finite values).
    pub rejected_frames: u64,
    /// Datagrams written to the recording.
    pub recorded: u64,
    /// Recording write failures (the recording stops at the first).
    pub record_errors: u64,
}

/// A stream sender; see the module doc.
#[derive(Debug)]
pub struct Publisher {
    cfg: StreamConfig,
    target: SocketAddr,
    socket: UdpSocket,
    topology: Topology,
    topology_msg: Vec<u8>,
    msg: Vec<u8>,
    dgram: Vec<u8>,
    seq: u32,
    topology_due_ns: Option<clock::Nanos>,
    start_ns: clock::Nanos,
    recorder: Option<(PathBuf, RecordWriter)>,
    stats: PublisherStats,
    igtl: Option<super::igtl::IgtlServer>,
}

fn check_topology(t: &Topology) -> Result<Vec<u8>, StreamError> {
    t.check()
        .map_err(|msg| StreamError::Invalid { what: "topology", msg })?;
    if t.num_vertices() > super::MAX_VERTICES {
        return Err(StreamError::Invalid {
            what: "topology",
            msg: format!("{} vertices (at most {})", t.num_vertices(), super::MAX_VERTICES),
        });
    }
    let mut m = Vec::new();
    format::encode_topology(t, &mut m);
    if m.len() > MAX_MESSAGE_LEN {
        return Err(StreamError::Invalid {
            what: "topology",
            msg: format!("{} bytes encoded (at most {MAX_MESSAGE_LEN})", m.len()),
        });
    }
    Ok(m)
}

impl Publisher {
    /// Opens a non-blocking UDP socket towards `cfg.target` and, with
    /// `record`, creates (truncates) a recording file. The topology goes out
    /// with the first frame and then every `cfg.topology_period_s`.
    pub fn new(cfg: StreamConfig, topology: Topology, record: Option<&Path>) -> Result<Publisher, StreamError> {
        cfg.validate(&Checker::new(Path::new("(stream config)")), "stream")?;
        let target = cfg.target_addr().map_err(|msg| StreamError::Invalid {
            what: "stream target",
            msg,
        })?;
        let topology_msg = check_topology(&topology)?;
        let bind: SocketAddr = if target.is_ipv4() {
            ([0, 0, 0, 0], 0).into()
        } else {
            (std::net::Ipv6Addr::UNSPECIFIED, 0).into()
        };
        let sock_err = |source| StreamError::Socket {
            what: "UDP socket for",
            addr: target.to_string(),
            source,
        };
        let socket = UdpSocket::bind(bind).map_err(sock_err)?;
        socket.set_nonblocking(true).map_err(sock_err)?;
        let start_ns = clock::now_ns();
        let recorder = match record {
            Some(p) => Some((p.to_path_buf(), RecordWriter::create(p)?)),
            None => None,
        };
        let igtl = match &cfg.igtl {
            Some(g) => {
                let addr: SocketAddr = g.listen.parse().map_err(|_| StreamError::Invalid {
                    what: "stream igtl.listen",
                    msg: format!("'{}': must be IP:PORT", g.listen),
                })?;
                let mut s = super::igtl::IgtlServer::bind(addr, g.max_clients, g.queue_frames).map_err(|source| {
                    StreamError::Socket {
                        what: "OpenIGTLink server on",
                        addr: addr.to_string(),
                        source,
                    }
                })?;
                s.set_topology(topology.epoch, &topology.triangles);
                Some(s)
            }
            None => None,
        };
        Ok(Publisher {
            igtl,
            cfg,
            target,
            socket,
            msg: Vec::with_capacity(format::state_len_max(topology.num_vertices())),
            dgram: Vec::with_capacity(format::MAX_DATAGRAM),
            topology,
            topology_msg,
            seq: 0,
            topology_due_ns: None,
            start_ns,
            recorder,
            stats: PublisherStats::default(),
        })
    }

    /// The OpenIGTLink server's counters (None when it is off).
    pub fn igtl_stats(&self) -> Option<super::igtl::IgtlStats> {
        self.igtl.as_ref().map(|s| s.stats())
    }

    /// The OpenIGTLink server's address (None when it is off).
    pub fn igtl_addr(&self) -> Option<SocketAddr> {
        self.igtl.as_ref().and_then(|s| s.local_addr().ok())
    }

    /// Counters so far.
    pub fn stats(&self) -> &PublisherStats {
        &self.stats
    }

    /// The topology being published.
    pub fn topology(&self) -> &Topology {
        &self.topology
    }

    /// The configuration.
    pub fn config(&self) -> &StreamConfig {
        &self.cfg
    }

    /// Seconds between frames at the configured rate.
    pub fn period_s(&self) -> f64 {
        1.0 / self.cfg.rate_hz
    }

    /// Where datagrams go.
    pub fn target(&self) -> SocketAddr {
        self.target
    }

    /// The local address of the sending socket.
    pub fn local_addr(&self) -> Option<SocketAddr> {
        self.socket.local_addr().ok()
    }

    /// Replaces the topology (a new epoch, which must differ from the
    /// current one); it is sent with the next frame.
    pub fn set_topology(&mut self, topology: Topology) -> Result<(), StreamError> {
        if topology.epoch == self.topology.epoch {
            return Err(StreamError::Invalid {
                what: "topology",
                msg: format!("a new topology needs a new epoch (still {})", topology.epoch),
            });
        }
        self.topology_msg = check_topology(&topology)?;
        self.topology = topology;
        self.topology_due_ns = None;
        Ok(())
    }

    /// Publishes one frame (and the topology when due). Send failures are
    /// counted, not returned; errors are a frame that does not match the
    /// topology or has non-finite values (nothing sent), and the first
    /// recording write failure (the recording is then closed; sending goes on).
    pub fn publish(&mut self, frame: &StateFrame) -> Result<(), StreamError> {
        let n = self.topology.num_vertices();
        if frame.positions.len() != n {
            self.stats.rejected_frames += 1;
            return Err(StreamError::Invalid {
                what: "state frame",
                msg: format!("{} positions for a topology of {n} vertices", frame.positions.len()),
            });
        }
        if let Some(msg) = format::instruments_invalid(frame.instruments) {
            self.stats.rejected_frames += 1;
            return Err(StreamError::Invalid {
                what: "state frame",
                msg,
            });
        }
        let finite = frame.time_s.is_finite()
            && frame
                .instruments
                .iter()
                .flat_map(|i| i.points)
                .flatten()
                .all(|v| v.is_finite())
            && frame.positions.iter().flatten().all(|v| v.is_finite())
            && frame.tool_position.iter().chain(&frame.force).all(|v| v.is_finite())
            && [frame.tool_radius, frame.loop_rate_hz, frame.tick_p99_us]
                .iter()
                .all(|v| v.is_finite());
        if !finite {
            self.stats.rejected_frames += 1;
            return Err(StreamError::Invalid {
                what: "state frame",
                msg: format!("non-finite value at t = {} s", frame.time_s),
            });
        }
        if let Some(g) = self.igtl.as_mut() {
            g.set_topology(self.topology.epoch, &self.topology.triangles);
            g.publish(&super::igtl::IgtlFrame {
                time_s: frame.time_s,
                positions: frame.positions,
                tool_position: frame.tool_position,
                force: frame.force,
                flags: frame.flags,
                loop_rate_hz: frame.loop_rate_hz,
                instruments: frame.instruments,
            });
        }
        let now = clock::now_ns();
        let mut record_err = None;
        if self.topology_due_ns.is_none_or(|due| now >= due) {
            let period_ns = (self.cfg.topology_period_s * 1e9) as clock::Nanos;
            self.topology_due_ns = Some(now + period_ns);
            let msg = std::mem::take(&mut self.topology_msg);
            record_err = self.send_message(KIND_TOPOLOGY, &msg, now);
            self.topology_msg = msg;
            self.stats.topologies += 1;
        }
        let mut msg = std::mem::take(&mut self.msg);
        msg.clear();
        format::encode_state(frame, &mut msg);
        record_err = record_err.or(self.send_message(KIND_STATE, &msg, now));
        self.msg = msg;
        self.stats.frames += 1;
        match record_err {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }

    /// Sends one message; returns the recording error if the recording
    /// failed (and closes it).
    fn send_message(&mut self, kind: u8, msg: &[u8], now: clock::Nanos) -> Option<StreamError> {
        let seq = self.seq;
        self.seq = self.seq.wrapping_add(1);
        let t_ns = (now - self.start_ns).max(0) as u64;
        let Publisher {
            socket,
            target,
            stats,
            recorder,
            dgram,
            topology,
            ..
        } = self;
        let mut failed = None;
        let send = self.cfg.enabled;
        format::chunk_message(kind, seq, topology.epoch, msg, MAX_CHUNK_PAYLOAD, dgram, |d| {
            // UDP off ([stream] enabled = false): only the recording.
            if send {
                match socket.send_to(d, *target) {
                    Ok(_) => {
                        stats.datagrams += 1;
                        stats.bytes += d.len() as u64;
                    }
                    Err(e) if e.kind() == ErrorKind::WouldBlock => stats.would_block += 1,
                    Err(_) => stats.send_errors += 1,
                }
            }
            if let Some((path, w)) = recorder.as_mut() {
                if failed.is_none() {
                    match w.write(t_ns, d) {
                        Ok(()) => stats.recorded += 1,
                        Err(source) => {
                            stats.record_errors += 1;
                            failed = Some(StreamError::Io {
                                path: path.clone(),
                                source,
                            });
                        }
                    }
                }
            }
        });
        if failed.is_some() {
            self.recorder = None;
        }
        failed
    }

    /// Flushes and closes the recording (if any) and returns the counters.
    pub fn finish(mut self) -> Result<PublisherStats, StreamError> {
        if let Some((path, w)) = self.recorder.take() {
            w.finish().map_err(|source| StreamError::Io { path, source })?;
        }
        Ok(self.stats)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stream::{Decoded, Decoder};

    #[test]
    fn frames_arrive_decoded_and_recorded() {
        let rx = UdpSocket::bind("127.0.0.1:0").unwrap();
        rx.set_read_timeout(Some(std::time::Duration::from_secs(5))).unwrap();
        let cfg = StreamConfig {
            target: rx.local_addr().unwrap().to_string(),
            ..StreamConfig::default()
        };
        let topo = Topology {
            epoch: 4,
            rest_positions: (0..300).map(|i| [i as f32, 0.0, 0.0]).collect(),
            triangles: (0..298).map(|i| [i, i + 1, i + 2]).collect(),
            node_ids: (0..300).collect(),
        };
        let dir = tempfile::tempdir().unwrap();
        let rec = dir.path().join("r.nvts");
        let mut p = Publisher::new(cfg, topo.clone(), Some(&rec)).unwrap();
        let pos = topo.rest_positions.clone();
        let mut f = StateFrame {
            time_s: 0.5,
            positions: &pos,
            tool_position: [0.0; 3],
            tool_radius: 0.002,
            force: [0.0, 1.0, 0.0],
            flags: 0,
            loop_rate_hz: 1000.0,
            tick_p99_us: 30.0,
            instruments: &[],
        };
        p.publish(&f).unwrap();
        f.time_s = 0.6;
        p.publish(&f).unwrap();
        let bad = vec![[0.0f32; 3]; 3];
        assert!(p.publish(&StateFrame { positions: &bad, ..f }).is_err());
        let st = p.finish().unwrap();
        assert_eq!((st.frames, st.topologies, st.rejected_frames), (2, 1, 1));
        assert_eq!(st.datagrams, st.recorded);
        let mut dec = Decoder::new();
        let mut buf = [0u8; 2048];
        let mut times = Vec::new();
        for _ in 0..st.datagrams {
            let n = rx.recv(&mut buf).unwrap();
            match dec.push(&buf[..n]).unwrap() {
                Some(Decoded::Topology(t)) => assert_eq!(t, topo),
                Some(Decoded::State(s)) => times.push(s.time_s),
                None => {}
            }
        }
        assert_eq!(times, vec![0.5, 0.6]);
        let mut dec = Decoder::new();
        let mut n = 0;
        for r in crate::stream::record::RecordReader::open(&rec).unwrap() {
            let (_, d) = r.unwrap();
            if let Ok(Some(Decoded::State(_))) = dec.push(&d) {
                n += 1;
            }
        }
        assert_eq!(n, 2);
    }
}
