//! Recordings: the datagrams exactly as sent, each with its send time, behind
//! a 24-byte header (layout in `docs/STREAM.md`). Replay to UDP at the
//! recorded pace, or export to a ParaView `.pvd` + `.vtu` series.

use super::format::{self, MAX_DATAGRAM};
use super::{flags, Decoded, Decoder, DecoderStats, StreamError};
use crate::math::Vec3;
use crate::mesh::io::{write_vtu_cells, PvdSeries};
use crate::rt::clock;
use std::fs::File;
use std::io::{BufReader, BufWriter, ErrorKind, Read, Write};
use std::net::{SocketAddr, UdpSocket};
use std::path::{Path, PathBuf};

/// First eight bytes of a recording.
pub const RECORD_MAGIC: [u8; 8] = *b"NVTSREC\0";
/// Recording container version.
pub const RECORD_VERSION: u16 = 1;
/// Recording header length (bytes).
pub const RECORD_HEADER_LEN: usize = 24;
/// Per-datagram record header length (bytes): `t_ns` u64 + `len` u32.
pub const RECORD_ENTRY_LEN: usize = 12;

/// Appends datagrams to a recording file.
#[derive(Debug)]
pub struct RecordWriter {
    w: BufWriter<File>,
}

impl RecordWriter {
    /// Creates (truncates) `path` and writes the header.
    pub fn create(path: &Path) -> Result<RecordWriter, StreamError> {
        let io = |source| StreamError::Io {
            path: path.to_path_buf(),
            source,
        };
        let mut w = BufWriter::new(File::create(path).map_err(io)?);
        let unix_ns = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos() as u64);
        let mut h = Vec::with_capacity(RECORD_HEADER_LEN);
        h.extend_from_slice(&RECORD_MAGIC);
        h.extend_from_slice(&RECORD_VERSION.to_le_bytes());
        h.extend_from_slice(&format::VERSION.to_le_bytes());
        h.extend_from_slice(&(RECORD_HEADER_LEN as u32).to_le_bytes());
        h.extend_from_slice(&unix_ns.to_le_bytes());
        w.write_all(&h).map_err(io)?;
        Ok(RecordWriter { w })
    }

    /// Appends one datagram sent `t_ns` after the recording started.
    pub fn write(&mut self, t_ns: u64, datagram: &[u8]) -> std::io::Result<()> {
        self.w.write_all(&t_ns.to_le_bytes())?;
        self.w.write_all(&(datagram.len() as u32).to_le_bytes())?;
        self.w.write_all(datagram)
    }

    /// Flushes to disk.
    pub fn finish(mut self) -> std::io::Result<()> {
        self.w.flush()
    }
}

/// Reads a recording: an iterator of `(t_ns, datagram)`.
#[derive(Debug)]
pub struct RecordReader {
    path: PathBuf,
    r: BufReader<File>,
    offset: u64,
    /// Wall-clock start of the recording (ns since the Unix epoch).
    pub start_unix_ns: u64,
    /// Stream format version of the recorded datagrams.
    pub stream_version: u16,
    done: bool,
}

impl RecordReader {
    /// Opens `path` and checks its header.
    pub fn open(path: &Path) -> Result<RecordReader, StreamError> {
        let io = |source| StreamError::Io {
            path: path.to_path_buf(),
            source,
        };
        let bad = |what: String| StreamError::BadRecording {
            path: path.to_path_buf(),
            what,
        };
        let mut r = BufReader::new(File::open(path).map_err(io)?);
        let mut h = [0u8; RECORD_HEADER_LEN];
        r.read_exact(&mut h).map_err(|e| {
            if e.kind() == ErrorKind::UnexpectedEof {
                bad(format!("shorter than the {RECORD_HEADER_LEN}-byte header"))
            } else {
                io(e)
            }
        })?;
        if h[..8] != RECORD_MAGIC {
            return Err(bad("not an nvtmm stream recording (bad magic at byte 0)".into()));
        }
        let version = u16::from_le_bytes([h[8], h[9]]);
        if version != RECORD_VERSION {
            return Err(bad(format!(
                "recording version {version} at byte 8 (this build reads {RECORD_VERSION})"
            )));
        }
        let stream_version = u16::from_le_bytes([h[10], h[11]]);
        let header_len = u32::from_le_bytes([h[12], h[13], h[14], h[15]]) as u64;
        if header_len < RECORD_HEADER_LEN as u64 {
            return Err(bad(format!(
                "header length {header_len} at byte 12 (at least {RECORD_HEADER_LEN})"
            )));
        }
        let extra = header_len - RECORD_HEADER_LEN as u64;
        std::io::copy(&mut (&mut r).take(extra), &mut std::io::sink()).map_err(io)?;
        let mut u = [0u8; 8];
        u.copy_from_slice(&h[16..24]);
        Ok(RecordReader {
            path: path.to_path_buf(),
            r,
            offset: header_len,
            start_unix_ns: u64::from_le_bytes(u),
            stream_version,
            done: false,
        })
    }

    fn bad(&self, what: String) -> StreamError {
        StreamError::BadRecording {
            path: self.path.clone(),
            what,
        }
    }

    fn next_record(&mut self) -> Result<Option<(u64, Vec<u8>)>, StreamError> {
        let mut e = [0u8; RECORD_ENTRY_LEN];
        let mut got = 0;
        while got < e.len() {
            match self.r.read(&mut e[got..]) {
                Ok(0) if got == 0 => return Ok(None),
                Ok(0) => return Err(self.bad(format!("truncated record header at byte {}", self.offset))),
                Ok(n) => got += n,
                Err(err) if err.kind() == ErrorKind::Interrupted => {}
                Err(source) => {
                    return Err(StreamError::Io {
                        path: self.path.clone(),
                        source,
                    })
                }
            }
        }
        let mut t = [0u8; 8];
        t.copy_from_slice(&e[..8]);
        let len = u32::from_le_bytes([e[8], e[9], e[10], e[11]]) as usize;
        if len > MAX_DATAGRAM {
            return Err(self.bad(format!(
                "record at byte {} claims {len} bytes (datagrams are at most {MAX_DATAGRAM})",
                self.offset
            )));
        }
        let mut d = vec![0u8; len];
        self.r
            .read_exact(&mut d)
            .map_err(|_| self.bad(format!("truncated datagram in the record at byte {}", self.offset)))?;
        self.offset += (RECORD_ENTRY_LEN + len) as u64;
        Ok(Some((u64::from_le_bytes(t), d)))
    }
}

impl Iterator for RecordReader {
    type Item = Result<(u64, Vec<u8>), StreamError>;
    fn next(&mut self) -> Option<Self::Item> {
        if self.done {
            return None;
        }
        let r = self.next_record().transpose();
        if !matches!(r, Some(Ok(_))) {
            self.done = true;
        }
        r
    }
}

/// What a replay or export did.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct ReplaySummary {
    /// Datagrams read from the recording.
    pub datagrams: u64,
    /// Recorded duration (s, first to last datagram).
    pub duration_s: f64,
    /// Datagrams that could not be sent.
    pub send_errors: u64,
    /// Frames written (export only).
    pub frames_written: u64,
    /// What the decoder saw (export only).
    pub decoder: DecoderStats,
}

/// Sends a recording's datagrams to `to` at the recorded pace divided by
/// `speed` (> 0; 2 = twice as fast).
pub fn replay_udp(path: &Path, to: SocketAddr, speed: f64) -> Result<ReplaySummary, StreamError> {
    if !(speed.is_finite() && speed > 0.0) {
        return Err(StreamError::Invalid {
            what: "replay speed",
            msg: format!("{speed}: must be a positive number"),
        });
    }
    let bind: SocketAddr = if to.is_ipv4() {
        ([0, 0, 0, 0], 0).into()
    } else {
        (std::net::Ipv6Addr::UNSPECIFIED, 0).into()
    };
    let sock = UdpSocket::bind(bind).map_err(|source| StreamError::Socket {
        what: "UDP socket for",
        addr: to.to_string(),
        source,
    })?;
    let start = clock::now_ns();
    let mut s = ReplaySummary::default();
    let mut first = None;
    for r in RecordReader::open(path)? {
        let (t, d) = r?;
        let t0 = *first.get_or_insert(t);
        let rel = t.saturating_sub(t0);
        s.duration_s = rel as f64 * 1e-9;
        clock::sleep_until(start + (rel as f64 / speed) as i64);
        if sock.send_to(&d, to).is_err() {
            s.send_errors += 1;
        }
        s.datagrams += 1;
    }
    Ok(s)
}

/// Serves a recording over OpenIGTLink on `addr` (see [`super::igtl`]) at
/// the recorded pace divided by `speed`: waits up to `wait_s` for a first
/// client, then sends every state frame to the clients connected.
pub fn replay_igtl(path: &Path, addr: SocketAddr, speed: f64, wait_s: f64) -> Result<ReplaySummary, StreamError> {
    if !(speed.is_finite() && speed > 0.0) {
        return Err(StreamError::Invalid {
            what: "replay speed",
            msg: format!("{speed}: must be a positive number"),
        });
    }
    let mut server = super::igtl::IgtlServer::bind(addr, 8, 8).map_err(|source| StreamError::Socket {
        what: "OpenIGTLink server on",
        addr: addr.to_string(),
        source,
    })?;
    let t_wait = clock::now_ns();
    while server.num_clients() == 0 && ((clock::now_ns() - t_wait) as f64) < wait_s * 1e9 {
        server.poll();
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
    let start = clock::now_ns();
    let mut dec = Decoder::new();
    let mut s = ReplaySummary::default();
    let mut first = None;
    for r in RecordReader::open(path)? {
        let (t, d) = r?;
        s.datagrams += 1;
        let t0 = *first.get_or_insert(t);
        let rel = t.saturating_sub(t0);
        s.duration_s = rel as f64 * 1e-9;
        let Ok(Some(Decoded::State(st))) = dec.push(&d) else {
            continue;
        };
        let Some(topo) = dec.topology() else { continue };
        clock::sleep_until(start + (rel as f64 / speed) as i64);
        server.set_topology(topo.epoch, &topo.triangles);
        server.publish(&super::igtl::IgtlFrame {
            time_s: st.time_s,
            positions: &st.positions,
            tool_position: st.tool_position,
            force: st.force,
            flags: st.flags,
            loop_rate_hz: st.loop_rate_hz,
            instruments: &st.lines(),
        });
        s.frames_written += 1;
    }
    // Let the clients drain what is queued.
    for _ in 0..50 {
        server.poll();
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
    s.decoder = dec.stats().clone();
    Ok(s)
}

fn v3(p: &[f32; 3]) -> Vec3 {
    Vec3::new(p[0] as f64, p[1] as f64, p[2] as f64)
}

/// Exports a recording to `dir`: `surface.pvd` (the stream surface per state
/// frame, with `displacement` vectors and `displacement_magnitude` from
/// rest) and `tool.pvd` (one point per frame at the tool centre with `force`,
/// `radius` and `flags`). Times are the frames' simulation times.
pub fn export_vtu(path: &Path, dir: &Path) -> Result<ReplaySummary, StreamError> {
    let mut surface = PvdSeries::create(dir, "surface")?;
    let mut tool = PvdSeries::create(dir, "tool")?;
    let mut dec = Decoder::new();
    let mut s = ReplaySummary::default();
    let mut first = None;
    for r in RecordReader::open(path)? {
        let (t, d) = r?;
        s.datagrams += 1;
        s.duration_s = t.saturating_sub(*first.get_or_insert(t)) as f64 * 1e-9;
        let Ok(Some(Decoded::State(st))) = dec.push(&d) else {
            continue;
        };
        let Some(topo) = dec.topology() else { continue };
        let pts: Vec<Vec3> = st.positions.iter().map(v3).collect();
        let disp: Vec<Vec3> = pts.iter().zip(&topo.rest_positions).map(|(p, r)| p - v3(r)).collect();
        let mag: Vec<f64> = disp.iter().map(|u| u.norm()).collect();
        let cells: Vec<u32> = topo.triangles.iter().flatten().copied().collect();
        surface.add_file(st.time_s, |p| {
            write_vtu_cells(
                p,
                &pts,
                5,
                3,
                &cells,
                &[("displacement", &disp)],
                &[("displacement_magnitude", &mag)],
            )
        })?;
        let force = [v3(&st.force)];
        let radius = [st.tool_radius as f64];
        let fl = [st.flags as f64];
        let contact = [f64::from(st.flags & flags::IN_CONTACT != 0)];
        tool.add_file(st.time_s, |p| {
            write_vtu_cells(
                p,
                &[v3(&st.tool_position)],
                1,
                1,
                &[0],
                &[("force", &force)],
                &[("radius", &radius), ("flags", &fl), ("in_contact", &contact)],
            )
        })?;
        s.frames_written += 1;
    }
    surface.finish()?;
    tool.finish()?;
    s.decoder = dec.stats().clone();
    Ok(s)
}

/// One instrument's tip in a row of [`tip_trace`].
#[derive(Debug, Clone, PartialEq)]
pub struct TipSample {
    /// The instrument's id in the recorded run.
    pub id: u8,
    /// Its kind code ([`super::instrument_kind`]).
    pub kind: u8,
    /// The tip: the polyline's last point (m).
    pub tip_m: Vec3,
    /// The segment the caller's `segment_of` gave for the tip.
    pub segment: Option<String>,
}

/// One row of [`tip_trace`]: a state frame's time and its instruments' tips.
#[derive(Debug, Clone, PartialEq)]
pub struct TipRow {
    /// Simulation time of the frame (s).
    pub time_s: f64,
    /// Every instrument's tip, in the frame's order.
    pub tips: Vec<TipSample>,
    /// Whether an instrument's segment differs from the row before (the
    /// first row: false).
    pub entered: bool,
}

/// Where each instrument's tip went in a recording: the first state frame,
/// then a frame at least every `every_s` of simulation time, every frame in
/// which a tip's segment (`segment_of` of the tip) changed, and the last
/// frame. For scripted scenarios: which branch a tip entered, and when.
pub fn tip_trace(
    path: &Path,
    every_s: f64,
    segment_of: &dyn Fn(Vec3) -> Option<String>,
) -> Result<(Vec<TipRow>, DecoderStats), StreamError> {
    let mut dec = Decoder::new();
    let mut rows: Vec<TipRow> = Vec::new();
    // The newest frame not yet written, and the last row's time.
    let mut pending: Option<TipRow> = None;
    let mut last_t = f64::NEG_INFINITY;
    for r in RecordReader::open(path)? {
        let (_, d) = r?;
        let Ok(Some(Decoded::State(st))) = dec.push(&d) else {
            continue;
        };
        let tips: Vec<TipSample> = st
            .instruments
            .iter()
            .filter_map(|l| {
                let p = l.points.last()?;
                let tip = v3(p);
                Some(TipSample {
                    id: l.id,
                    kind: l.kind,
                    tip_m: tip,
                    segment: segment_of(tip),
                })
            })
            .collect();
        let before = pending.as_ref().or(rows.last());
        let entered = before.is_some_and(|b| {
            tips.iter()
                .any(|t| b.tips.iter().any(|u| u.id == t.id && u.segment != t.segment))
        });
        let row = TipRow {
            time_s: st.time_s,
            tips,
            entered,
        };
        if rows.is_empty() || entered || st.time_s - last_t >= every_s {
            last_t = st.time_s;
            rows.push(row);
            pending = None;
        } else {
            pending = Some(row);
        }
    }
    rows.extend(pending);
    Ok((rows, dec.stats().clone()))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A recording of a wire whose tip rises 1 mm a frame (every 10 ms)
    /// into a "branch" above z = 5.5 mm: the trace keeps the first frame, one
    /// every 0.1 s, the frame the tip entered the branch (marked), and the
    /// last.
    #[test]
    fn the_tip_trace_keeps_each_change_of_segment() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("tips.nvts");
        let mut w = RecordWriter::create(&p).unwrap();
        let (mut msg, mut buf) = (Vec::new(), Vec::new());
        let topology = super::super::Topology {
            epoch: 0,
            rest_positions: vec![[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
            triangles: vec![[0, 1, 2]],
            node_ids: vec![0, 1, 2],
        };
        format::encode_topology(&topology, &mut msg);
        format::chunk_message(format::KIND_TOPOLOGY, 0, 0, &msg, 1400, &mut buf, |d| {
            w.write(0, d).unwrap()
        })
        .unwrap();
        for k in 0..30u32 {
            let pts = [[0.0f32, 0.0, 0.0], [0.0, 0.0, k as f32 * 1e-3]];
            let lines = [super::super::InstrumentLine {
                id: 1,
                kind: 2,
                points: &pts,
            }];
            let frame = super::super::StateFrame {
                time_s: k as f64 * 0.01,
                positions: &topology.rest_positions,
                tool_position: [0.0; 3],
                tool_radius: 0.0,
                force: [0.0; 3],
                flags: 0,
                loop_rate_hz: 1000.0,
                tick_p99_us: 0.0,
                instruments: &lines,
            };
            msg.clear();
            format::encode_state(&frame, &mut msg);
            format::chunk_message(format::KIND_STATE, k + 1, 0, &msg, 1400, &mut buf, |d| {
                w.write(u64::from(k) * 10_000_000, d).unwrap()
            })
            .unwrap();
        }
        w.finish().unwrap();
        let segment = |x: Vec3| Some(if x.z > 5.5e-3 { "branch" } else { "aorta" }.to_string());
        let (rows, stats) = tip_trace(&p, 0.1, &segment).unwrap();
        assert_eq!(stats.total_rejected(), 0);
        let at: Vec<(u32, bool)> = rows
            .iter()
            .map(|r| ((r.time_s * 100.0).round() as u32, r.entered))
            .collect();
        assert_eq!(
            at,
            [(0, false), (6, true), (16, false), (26, false), (29, false)],
            "{rows:?}"
        );
        assert_eq!(rows[1].tips[0].segment.as_deref(), Some("branch"));
        assert!((rows[1].tips[0].tip_m.z - 6e-3).abs() < 1e-9);
        assert_eq!((rows[1].tips[0].id, rows[1].tips[0].kind), (1, 2));
    }

    #[test]
    fn bad_recordings_are_refused_with_the_place() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("x.nvts");
        std::fs::write(&p, b"hello").unwrap();
        let e = RecordReader::open(&p).unwrap_err().to_string();
        assert!(e.contains("header"), "{e}");
        std::fs::write(&p, [0u8; 40]).unwrap();
        assert!(RecordReader::open(&p).unwrap_err().to_string().contains("magic"));
        let mut w = RecordWriter::create(&p).unwrap();
        w.write(5, &[1, 2, 3]).unwrap();
        w.finish().unwrap();
        let mut bytes = std::fs::read(&p).unwrap();
        let rs: Vec<_> = RecordReader::open(&p).unwrap().collect();
        assert_eq!(rs.len(), 1);
        assert_eq!(rs[0].as_ref().unwrap(), &(5, vec![1, 2, 3]));
        bytes.pop();
        std::fs::write(&p, &bytes).unwrap();
        let e = RecordReader::open(&p).unwrap().next().unwrap().unwrap_err().to_string();
        assert!(e.contains("byte 24"), "{e}");
    }
}
