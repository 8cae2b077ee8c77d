//! OpenIGTLink: the live state for 3D Slicer (OpenIGTLinkIF), PLUS and any
//! other OpenIGTLink peer, over TCP. Off by default; `[stream] igtl = {
//! listen = "127.0.0.1:18944" }` turns it on (docs/STREAM.md, "OpenIGTLink").
//!
//! The framing is short and written here. Every message is a 58-byte header
//! and a body, all big-endian (OpenIGTLink protocol, version 2 headers):
//!
//! ```text
//! header  u16 version (2) | char[12] type | char[20] device name
//!         | u32 seconds | u32 fraction (2^-32 s) | u64 body size | u64 CRC-64 of the body
//! body    extended header: u16 size (12) | u16 metadata header size (0)
//!                          | u32 metadata size (0) | u32 message id
//!         content (per type, below); no metadata
//! ```
//!
//! The CRC is CRC-64/ECMA-182 (polynomial 0x42F0E1EBA9EA3693, initial value
//! 0, no reflection, no final xor), as the reference implementation's
//! `igtl_util.c` computes it.
//!
//! Coordinates: the scene frame is LPS (x to the patient's left, y
//! posterior, z superior: DICOM's patient frame, the built-in arch's);
//! Slicer's world frame, where OpenIGTLinkIF puts what it receives, is RAS.
//! Every point, translation and force is sent in RAS millimetres (newtons
//! for the force), [`scene_to_ras_mm`]: x and y negated, a half turn about
//! the superior axis, so no triangle changes its winding
//! (docs/reference/coordinates.md). Content sent each frame:
//!
//! - `POLYDATA` "VesselSurface": the stream surface, points in RAS mm (float32
//!   x y z) and triangles as POLYGONS cells (u32 count 3, u32 indices). The
//!   full polydata goes every frame: Slicer replaces a model's whole
//!   polydata with each message, so a points-only message would drop its
//!   faces; the connectivity bytes are encoded once per topology and copied.
//! - `TRANSFORM` "ToolTip": 12 float32, the rotation column-major then the
//!   translation in RAS mm.
//! - `STRING` "Status": `t=… s force=fx,fy,fz N |F|=… N flags=0x… loop=… Hz`,
//!   the force on the hand in RAS
//!   (u16 encoding 3 = US-ASCII, u16 length, bytes).
//! - One `POLYDATA` per instrument of the frame, named for its kind
//!   ([`instrument_device_name`]: "Probe", "Wire" for the guidewire,
//!   "Catheter", else `Instrument<id>`): its polyline's points in mm and
//!   one LINES cell; and a `TRANSFORM` `<name>Tip` at its last point.
//!
//! The server ([`IgtlServer`]) never blocks its caller: sockets are
//! non-blocking, each client has a bounded queue (whole frames dropped and
//! counted when it is full, e.g. a client that stopped reading), and what a
//! client sends is parsed defensively (bad headers, wrong CRC, huge declared
//! sizes are counted and skipped, or the client is dropped; never a panic,
//! never an allocation larger than the bound).

use std::collections::VecDeque;
use std::io::{ErrorKind, Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::sync::Arc;

/// Bytes of a message header.
pub const HEADER_SIZE: usize = 58;
/// Bytes of the version-2 extended header.
pub const EXT_HEADER_SIZE: usize = 12;
/// The largest body the server accepts from a client (bytes); larger
/// declared sizes drop the client.
pub const MAX_CLIENT_BODY: u64 = 1 << 20;

const fn crc_table() -> [u64; 256] {
    let poly: u64 = 0x42F0_E1EB_A9EA_3693;
    let mut t = [0u64; 256];
    let mut i = 0;
    while i < 256 {
        let mut c = (i as u64) << 56;
        let mut k = 0;
        while k < 8 {
            c = if c & (1 << 63) != 0 { (c << 1) ^ poly } else { c << 1 };
            k += 1;
        }
        t[i] = c;
        i += 1;
    }
    t
}

static CRC_TABLE: [u64; 256] = crc_table();

/// CRC-64/ECMA-182 of `data` (OpenIGTLink's body checksum).
pub fn crc64(data: &[u8]) -> u64 {
    data.iter().fold(0u64, |crc, &b| {
        CRC_TABLE[(((crc >> 56) as u8) ^ b) as usize] ^ (crc << 8)
    })
}

/// A message header.
#[derive(Debug, Clone, PartialEq)]
pub struct Header {
    /// Protocol header version (1 or 2).
    pub version: u16,
    /// Message type, e.g. "TRANSFORM".
    pub kind: String,
    /// Device name.
    pub device: String,
    /// Time stamp (s).
    pub timestamp_s: f64,
    /// Body size (bytes).
    pub body_size: u64,
    /// CRC-64 of the body.
    pub crc: u64,
}

fn fixed_str(b: &[u8]) -> String {
    let end = b.iter().position(|&c| c == 0).unwrap_or(b.len());
    String::from_utf8_lossy(&b[..end]).into_owned()
}

impl Header {
    /// Parses the first [`HEADER_SIZE`] bytes of `b` (None if shorter).
    pub fn parse(b: &[u8]) -> Option<Header> {
        let b = b.get(..HEADER_SIZE)?;
        let u32_at = |i: usize| u32::from_be_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]]);
        let u64_at = |i: usize| u64::from_be_bytes(b[i..i + 8].try_into().unwrap_or([0; 8]));
        Some(Header {
            version: u16::from_be_bytes([b[0], b[1]]),
            kind: fixed_str(&b[2..14]),
            device: fixed_str(&b[14..34]),
            timestamp_s: u32_at(34) as f64 + u32_at(38) as f64 / 4_294_967_296.0,
            body_size: u64_at(42),
            crc: u64_at(50),
        })
    }
}

/// Appends one version-2 message: header, extended header, the content
/// `content` writes, with the body size and CRC filled in.
pub fn encode_message(
    out: &mut Vec<u8>,
    kind: &str,
    device: &str,
    timestamp_s: f64,
    content: impl FnOnce(&mut Vec<u8>),
) {
    let start = out.len();
    out.extend_from_slice(&2u16.to_be_bytes());
    let mut name = [0u8; 12];
    for (d, s) in name.iter_mut().zip(kind.bytes()) {
        *d = s;
    }
    out.extend_from_slice(&name);
    let mut dev = [0u8; 20];
    for (d, s) in dev.iter_mut().zip(device.bytes()) {
        *d = s;
    }
    out.extend_from_slice(&dev);
    let t = if timestamp_s.is_finite() {
        timestamp_s.max(0.0)
    } else {
        0.0
    };
    let secs = t.floor().min(u32::MAX as f64) as u32;
    let frac = ((t - t.floor()) * 4_294_967_296.0).min(u32::MAX as f64) as u32;
    out.extend_from_slice(&secs.to_be_bytes());
    out.extend_from_slice(&frac.to_be_bytes());
    out.extend_from_slice(&[0u8; 16]); // body size, CRC: filled below
    let body = out.len();
    out.extend_from_slice(&(EXT_HEADER_SIZE as u16).to_be_bytes());
    out.extend_from_slice(&0u16.to_be_bytes());
    out.extend_from_slice(&0u32.to_be_bytes());
    out.extend_from_slice(&0u32.to_be_bytes());
    content(out);
    let size = (out.len() - body) as u64;
    let crc = crc64(&out[body..]);
    out[start + 42..start + 50].copy_from_slice(&size.to_be_bytes());
    out[start + 50..start + 58].copy_from_slice(&crc.to_be_bytes());
}

fn put_f32(out: &mut Vec<u8>, v: f32) {
    out.extend_from_slice(&v.to_be_bytes());
}

fn put_u32(out: &mut Vec<u8>, v: u32) {
    out.extend_from_slice(&v.to_be_bytes());
}

/// A scene point (m, LPS) in Slicer's RAS frame (mm): x and y negated.
pub fn scene_to_ras_mm(p: &[f32; 3]) -> [f32; 3] {
    [-p[0] * 1e3, -p[1] * 1e3, p[2] * 1e3]
}

/// TRANSFORM content: a pure translation (mm).
pub fn transform_content(out: &mut Vec<u8>, translation_mm: [f32; 3]) {
    for v in [1.0f32, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0] {
        put_f32(out, v);
    }
    for v in translation_mm {
        put_f32(out, v);
    }
}

/// STRING content (US-ASCII; longer than 65 535 bytes is cut).
pub fn string_content(out: &mut Vec<u8>, text: &str) {
    let bytes: Vec<u8> = text.bytes().map(|b| if b.is_ascii() { b } else { b'?' }).collect();
    let n = bytes.len().min(u16::MAX as usize);
    out.extend_from_slice(&3u16.to_be_bytes());
    out.extend_from_slice(&(n as u16).to_be_bytes());
    out.extend_from_slice(&bytes[..n]);
}

/// The POLYDATA cells block of triangles: per cell u32 3 and three u32
/// indices (what [`polydata_content`] takes as `polygons`).
pub fn triangle_cells(triangles: &[[u32; 3]]) -> Vec<u8> {
    let mut b = Vec::with_capacity(triangles.len() * 16);
    for t in triangles {
        put_u32(&mut b, 3);
        for &i in t {
            put_u32(&mut b, i);
        }
    }
    b
}

/// POLYDATA content: points (mm), a pre-encoded POLYGONS cell block with
/// `npolygons` cells, and an optional single LINES cell through all points.
pub fn polydata_content(out: &mut Vec<u8>, points_mm: &[[f32; 3]], polygons: &[u8], npolygons: u32, line: bool) {
    let np = points_mm.len() as u32;
    let (nlines, size_lines) = if line && np > 0 { (1, 4 * (np + 1)) } else { (0, 0) };
    for v in [np, 0, 0, nlines, size_lines, npolygons, polygons.len() as u32, 0, 0, 0] {
        put_u32(out, v);
    }
    for p in points_mm {
        for &c in p {
            put_f32(out, c);
        }
    }
    if nlines > 0 {
        put_u32(out, np);
        for i in 0..np {
            put_u32(out, i);
        }
    }
    out.extend_from_slice(polygons);
}

/// A decoded message (what the tests and a client need).
#[derive(Debug, Clone, PartialEq)]
pub enum Message {
    /// A TRANSFORM: the 12 values as sent.
    Transform {
        /// Device name.
        device: String,
        /// R11 R21 R31 R12 R22 R32 R13 R23 R33 TX TY TZ.
        values: [f32; 12],
    },
    /// A STRING.
    String {
        /// Device name.
        device: String,
        /// The text.
        text: String,
    },
    /// A POLYDATA.
    PolyData {
        /// Device name.
        device: String,
        /// Points (mm).
        points: Vec<[f32; 3]>,
        /// LINES cells (each a list of point indices).
        lines: Vec<Vec<u32>>,
        /// POLYGONS cells.
        polygons: Vec<Vec<u32>>,
    },
    /// Any other type (body skipped).
    Other {
        /// The header.
        header: Header,
    },
}

/// Why a message could not be decoded.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DecodeError {
    /// Not enough bytes yet.
    #[error("incomplete message")]
    Incomplete,
    /// The body's CRC does not match the header.
    #[error("CRC mismatch: header {header:#018x}, body {body:#018x}")]
    Crc {
        /// From the header.
        header: u64,
        /// Computed.
        body: u64,
    },
    /// The declared body size is beyond the limit.
    #[error("declared body size {0} bytes is beyond the limit")]
    TooLarge(u64),
    /// The content does not match its type's layout.
    #[error("{kind}: malformed content: {what}")]
    Malformed {
        /// Message type.
        kind: String,
        /// What is wrong.
        what: String,
    },
}

struct Cursor<'a> {
    b: &'a [u8],
    at: usize,
}

impl Cursor<'_> {
    fn take(&mut self, n: usize) -> Option<&[u8]> {
        let s = self.b.get(self.at..self.at.checked_add(n)?)?;
        self.at += n;
        Some(s)
    }
    fn u16(&mut self) -> Option<u16> {
        self.take(2).map(|s| u16::from_be_bytes([s[0], s[1]]))
    }
    fn u32(&mut self) -> Option<u32> {
        self.take(4).map(|s| u32::from_be_bytes([s[0], s[1], s[2], s[3]]))
    }
    fn f32(&mut self) -> Option<f32> {
        self.u32().map(f32::from_bits)
    }
    fn cells(&mut self, count: u32, size: u32) -> Option<Vec<Vec<u32>>> {
        let end = self.at.checked_add(size as usize)?;
        if end > self.b.len() {
            return None;
        }
        let mut out = Vec::new();
        for _ in 0..count {
            let n = self.u32()?;
            if self.at + 4 * n as usize > end {
                return None;
            }
            out.push((0..n).map(|_| self.u32()).collect::<Option<Vec<u32>>>()?);
        }
        (self.at == end).then_some(out)
    }
}

/// Decodes the first message of `buf` (header + body), checking the CRC and
/// limiting the body to `max_body` bytes. Returns the message and the bytes
/// it used. Never panics.
pub fn decode(buf: &[u8], max_body: u64) -> Result<(Message, usize), DecodeError> {
    let h = Header::parse(buf).ok_or(DecodeError::Incomplete)?;
    if h.body_size > max_body {
        return Err(DecodeError::TooLarge(h.body_size));
    }
    let total = HEADER_SIZE + h.body_size as usize;
    let body = buf.get(HEADER_SIZE..total).ok_or(DecodeError::Incomplete)?;
    let crc = crc64(body);
    if crc != h.crc {
        return Err(DecodeError::Crc {
            header: h.crc,
            body: crc,
        });
    }
    let bad = |what: &str| DecodeError::Malformed {
        kind: h.kind.clone(),
        what: what.into(),
    };
    let content = if h.version >= 2 {
        let mut c = Cursor { b: body, at: 0 };
        let ext = c.u16().ok_or_else(|| bad("extended header"))? as usize;
        let meta_h = c.u16().ok_or_else(|| bad("extended header"))? as usize;
        let meta = c.u32().ok_or_else(|| bad("extended header"))? as usize;
        let end = body
            .len()
            .checked_sub(meta_h + meta)
            .filter(|&e| e >= ext)
            .ok_or_else(|| bad("extended header sizes"))?;
        &body[ext..end]
    } else {
        body
    };
    let mut c = Cursor { b: content, at: 0 };
    let msg = match h.kind.as_str() {
        "TRANSFORM" => {
            let mut values = [0f32; 12];
            for v in values.iter_mut() {
                *v = c.f32().ok_or_else(|| bad("12 float32 expected"))?;
            }
            Message::Transform {
                device: h.device.clone(),
                values,
            }
        }
        "STRING" => {
            let _enc = c.u16().ok_or_else(|| bad("encoding"))?;
            let n = c.u16().ok_or_else(|| bad("length"))? as usize;
            let s = c.take(n).ok_or_else(|| bad("string shorter than its length"))?;
            Message::String {
                device: h.device.clone(),
                text: String::from_utf8_lossy(s).into_owned(),
            }
        }
        "POLYDATA" => {
            let mut hd = [0u32; 10];
            for v in hd.iter_mut() {
                *v = c.u32().ok_or_else(|| bad("header"))?;
            }
            let np = hd[0] as usize;
            if np.checked_mul(12).is_none_or(|b| b > content.len()) {
                return Err(bad("more points than bytes"));
            }
            let mut points = Vec::with_capacity(np);
            for _ in 0..np {
                let x = c.f32().ok_or_else(|| bad("points"))?;
                let y = c.f32().ok_or_else(|| bad("points"))?;
                let z = c.f32().ok_or_else(|| bad("points"))?;
                points.push([x, y, z]);
            }
            let _vertices = c.cells(hd[1], hd[2]).ok_or_else(|| bad("VERTICES"))?;
            let lines = c.cells(hd[3], hd[4]).ok_or_else(|| bad("LINES"))?;
            let polygons = c.cells(hd[5], hd[6]).ok_or_else(|| bad("POLYGONS"))?;
            Message::PolyData {
                device: h.device.clone(),
                points,
                lines,
                polygons,
            }
        }
        _ => Message::Other { header: h.clone() },
    };
    Ok((msg, total))
}

/// Per-client counters.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct ClientStats {
    /// Peer address.
    pub peer: String,
    /// Frames queued for it.
    pub frames_sent: u64,
    /// Frames dropped because its queue was full (it reads too slowly).
    pub frames_dropped: u64,
    /// Messages it sent that were malformed (bad header, CRC, content).
    pub bad_messages: u64,
    /// Well-formed messages it sent (ignored: the server only publishes).
    pub messages_received: u64,
}

/// Server counters.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct IgtlStats {
    /// Clients accepted.
    pub accepted: u64,
    /// Clients gone (closed, errors, or dropped for a huge declared size).
    pub disconnected: u64,
    /// Clients refused (more than the limit at once).
    pub refused: u64,
    /// Counters of the clients connected now, and of those that left.
    pub clients: Vec<ClientStats>,
}

struct Client {
    stream: TcpStream,
    queue: VecDeque<Arc<Vec<u8>>>,
    sent_of_front: usize,
    inbuf: Vec<u8>,
    skip: u64,
    stats: ClientStats,
    alive: bool,
}

/// The OpenIGTLink server: accepts clients and sends them frames; see the
/// module doc.
pub struct IgtlServer {
    listener: TcpListener,
    clients: Vec<Client>,
    gone: Vec<ClientStats>,
    max_clients: usize,
    queue_frames: usize,
    stats: IgtlStats,
    polygons: Vec<u8>,
    npolygons: u32,
    epoch: Option<u32>,
    buf: Vec<u8>,
}

impl std::fmt::Debug for IgtlServer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("IgtlServer")
            .field("addr", &self.listener.local_addr().ok())
            .field("clients", &self.clients.len())
            .finish_non_exhaustive()
    }
}

/// What one frame carries to the clients.
#[derive(Debug, Clone, Copy)]
pub struct IgtlFrame<'a> {
    /// Simulation time (s).
    pub time_s: f64,
    /// Surface points (m).
    pub positions: &'a [[f32; 3]],
    /// Tool centre (m).
    pub tool_position: [f32; 3],
    /// Force on the hand (N).
    pub force: [f32; 3],
    /// Status bits.
    pub flags: u32,
    /// Haptic loop rate (Hz).
    pub loop_rate_hz: f32,
    /// One polyline per instrument (m).
    pub instruments: &'a [super::InstrumentLine<'a>],
}

/// The OpenIGTLink device name of an instrument's polyline (its tip's
/// transform adds "Tip"): by kind, as a Slicer scene names its models.
pub fn instrument_device_name(line: &super::InstrumentLine<'_>) -> String {
    match super::instrument_kind(line.kind) {
        Some("probe") => "Probe".into(),
        Some("guidewire") => "Wire".into(),
        Some("catheter") => "Catheter".into(),
        _ => format!("Instrument{}", line.id),
    }
}

impl IgtlServer {
    /// Listens on `addr` (non-blocking), for at most `max_clients` clients
    /// with `queue_frames` frames of backlog each.
    pub fn bind(addr: SocketAddr, max_clients: usize, queue_frames: usize) -> std::io::Result<IgtlServer> {
        let listener = TcpListener::bind(addr)?;
        listener.set_nonblocking(true)?;
        Ok(IgtlServer {
            listener,
            clients: Vec::new(),
            gone: Vec::new(),
            max_clients: max_clients.max(1),
            queue_frames: queue_frames.max(1),
            stats: IgtlStats::default(),
            polygons: Vec::new(),
            npolygons: 0,
            epoch: None,
            buf: Vec::new(),
        })
    }

    /// The address it listens on.
    pub fn local_addr(&self) -> std::io::Result<SocketAddr> {
        self.listener.local_addr()
    }

    /// Clients connected now.
    pub fn num_clients(&self) -> usize {
        self.clients.len()
    }

    /// Counters, with every client seen.
    pub fn stats(&self) -> IgtlStats {
        let mut s = self.stats.clone();
        s.clients = self
            .gone
            .iter()
            .chain(self.clients.iter().map(|c| &c.stats))
            .cloned()
            .collect();
        s
    }

    /// Sets the surface triangles (encoded once; `epoch` identifies them).
    pub fn set_topology(&mut self, epoch: u32, triangles: &[[u32; 3]]) {
        if self.epoch != Some(epoch) {
            self.polygons = triangle_cells(triangles);
            self.npolygons = triangles.len() as u32;
            self.epoch = Some(epoch);
        }
    }

    /// Accepts, reads what clients sent, writes what is queued. Never
    /// blocks.
    pub fn poll(&mut self) {
        while let Ok((stream, peer)) = self.listener.accept() {
            if self.clients.len() >= self.max_clients || stream.set_nonblocking(true).is_err() {
                self.stats.refused += 1;
                continue;
            }
            let _ = stream.set_nodelay(true);
            bound_send_buffer(&stream);
            self.stats.accepted += 1;
            self.clients.push(Client {
                stream,
                queue: VecDeque::new(),
                sent_of_front: 0,
                inbuf: Vec::new(),
                skip: 0,
                stats: ClientStats {
                    peer: peer.to_string(),
                    ..ClientStats::default()
                },
                alive: true,
            });
        }
        for c in self.clients.iter_mut() {
            read_client(c);
            write_client(c);
        }
        let before = self.clients.len();
        let (alive, dead): (Vec<Client>, Vec<Client>) =
            std::mem::take(&mut self.clients).into_iter().partition(|c| c.alive);
        self.clients = alive;
        self.gone.extend(dead.into_iter().map(|c| c.stats));
        self.stats.disconnected += (before - self.clients.len()) as u64;
    }

    /// Encodes one frame (surface, tool tip, status, wire) and queues it to
    /// every client (dropped and counted for a client whose queue is full),
    /// then polls.
    pub fn publish(&mut self, f: &IgtlFrame<'_>) {
        self.poll();
        if self.clients.is_empty() {
            return;
        }
        let mm = scene_to_ras_mm;
        let mut buf = std::mem::take(&mut self.buf);
        buf.clear();
        let pts: Vec<[f32; 3]> = f.positions.iter().map(mm).collect();
        let (polygons, npolygons) = (&self.polygons, self.npolygons);
        encode_message(&mut buf, "POLYDATA", "VesselSurface", f.time_s, |o| {
            polydata_content(o, &pts, polygons, npolygons, false)
        });
        encode_message(&mut buf, "TRANSFORM", "ToolTip", f.time_s, |o| {
            transform_content(o, mm(&f.tool_position))
        });
        for line in f.instruments.iter().filter(|l| !l.points.is_empty()) {
            let name = instrument_device_name(line);
            let wpts: Vec<[f32; 3]> = line.points.iter().map(mm).collect();
            encode_message(&mut buf, "POLYDATA", &name, f.time_s, |o| {
                polydata_content(o, &wpts, &[], 0, true)
            });
            if let Some(tip) = line.points.last() {
                encode_message(&mut buf, "TRANSFORM", &format!("{name}Tip"), f.time_s, |o| {
                    transform_content(o, mm(tip))
                });
            }
        }
        // The force in RAS too, like the points.
        let fv = [-f.force[0], -f.force[1], f.force[2]];
        let norm = (fv[0] * fv[0] + fv[1] * fv[1] + fv[2] * fv[2]).sqrt();
        let text = format!(
            "t={:.3} s force={:.4},{:.4},{:.4} N |F|={:.4} N flags=0x{:x} loop={:.0} Hz",
            f.time_s, fv[0], fv[1], fv[2], norm, f.flags, f.loop_rate_hz
        );
        encode_message(&mut buf, "STRING", "Status", f.time_s, |o| string_content(o, &text));
        let frame = Arc::new(buf.clone());
        self.buf = buf;
        for c in self.clients.iter_mut() {
            if c.queue.len() >= self.queue_frames {
                c.stats.frames_dropped += 1;
            } else {
                c.queue.push_back(frame.clone());
                c.stats.frames_sent += 1;
            }
        }
        self.poll();
    }
}

fn read_client(c: &mut Client) {
    let mut tmp = [0u8; 4096];
    loop {
        match c.stream.read(&mut tmp) {
            Ok(0) => {
                c.alive = false;
                return;
            }
            Ok(n) => {
                let mut data = &tmp[..n];
                if c.skip > 0 {
                    let s = (c.skip as usize).min(data.len());
                    c.skip -= s as u64;
                    data = &data[s..];
                }
                c.inbuf.extend_from_slice(data);
                parse_client(c);
                if !c.alive {
                    return;
                }
            }
            Err(e) if e.kind() == ErrorKind::WouldBlock => return,
            Err(e) if e.kind() == ErrorKind::Interrupted => continue,
            Err(_) => {
                c.alive = false;
                return;
            }
        }
    }
}

/// Consumes whole messages from the client's input; counts them.
fn parse_client(c: &mut Client) {
    loop {
        if c.skip > 0 {
            let s = (c.skip as usize).min(c.inbuf.len());
            c.inbuf.drain(..s);
            c.skip -= s as u64;
            if c.skip > 0 {
                return;
            }
        }
        let Some(h) = Header::parse(&c.inbuf) else { return };
        if h.body_size > MAX_CLIENT_BODY {
            // No way to resynchronize a stream with a lying header: drop it.
            c.stats.bad_messages += 1;
            c.alive = false;
            return;
        }
        let total = HEADER_SIZE + h.body_size as usize;
        if c.inbuf.len() < total {
            return;
        }
        match decode(&c.inbuf[..total], MAX_CLIENT_BODY) {
            Ok(_) => c.stats.messages_received += 1,
            Err(_) => c.stats.bad_messages += 1,
        }
        c.inbuf.drain(..total);
    }
}

fn write_client(c: &mut Client) {
    while let Some(front) = c.queue.front() {
        match c.stream.write(&front[c.sent_of_front..]) {
            Ok(0) => {
                c.alive = false;
                return;
            }
            Ok(n) => {
                c.sent_of_front += n;
                if c.sent_of_front >= front.len() {
                    c.queue.pop_front();
                    c.sent_of_front = 0;
                }
            }
            Err(e) if e.kind() == ErrorKind::WouldBlock => return,
            Err(e) if e.kind() == ErrorKind::Interrupted => continue,
            Err(_) => {
                c.alive = false;
                return;
            }
        }
    }
}

/// Kernel send-buffer size requested for each client socket (Linux doubles
/// it for bookkeeping). Small on purpose: a client that stops reading fills
/// this and its receive window within a fraction of a second, after which its
/// own queue fills and frames are dropped and counted, instead of seconds of
/// stale frames piling up in the kernel (the default buffers auto-tune to
/// several MiB).
pub const CLIENT_SEND_BUFFER_BYTES: usize = 64 * 1024;

/// Caps the kernel send buffer of a client socket at
/// [`CLIENT_SEND_BUFFER_BYTES`] (best effort: a refusal leaves the default).
fn bound_send_buffer(stream: &TcpStream) {
    #[cfg(unix)]
    {
        use std::os::fd::AsRawFd;
        let size = CLIENT_SEND_BUFFER_BYTES as libc::c_int;
        // SAFETY: a valid open socket descriptor, a pointer to a c_int that
        // lives across the call, and its exact size.
        unsafe {
            libc::setsockopt(
                stream.as_raw_fd(),
                libc::SOL_SOCKET,
                libc::SO_SNDBUF,
                (&size as *const libc::c_int).cast(),
                std::mem::size_of::<libc::c_int>() as libc::socklen_t,
            );
        }
    }
    #[cfg(not(unix))]
    let _ = stream;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc64_matches_the_ecma_182_check_value() {
        // CRC-64/ECMA-182 of "123456789" (the catalogue's check value).
        assert_eq!(crc64(b"123456789"), 0x6C40_DF5F_0B49_7347);
        assert_eq!(crc64(b""), 0);
    }

    #[test]
    fn every_message_type_round_trips() {
        let mut b = Vec::new();
        encode_message(&mut b, "TRANSFORM", "ToolTip", 12.5, |o| {
            transform_content(o, [1.0, 2.0, 3.0])
        });
        encode_message(&mut b, "STRING", "Status", 12.5, |o| string_content(o, "hello"));
        let tris = [[0u32, 1, 2]];
        let cells = triangle_cells(&tris);
        encode_message(&mut b, "POLYDATA", "VesselSurface", 12.5, |o| {
            polydata_content(
                o,
                &[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
                &cells,
                1,
                false,
            )
        });
        encode_message(&mut b, "POLYDATA", "Wire", 12.5, |o| {
            polydata_content(o, &[[0.0, 0.0, 0.0], [0.0, 0.0, 5.0]], &[], 0, true)
        });
        let mut at = 0;
        let mut got = Vec::new();
        while at < b.len() {
            let (m, n) = decode(&b[at..], 1 << 20).unwrap();
            got.push(m);
            at += n;
        }
        assert_eq!(got.len(), 4);
        match &got[0] {
            Message::Transform { device, values } => {
                assert_eq!(device, "ToolTip");
                assert_eq!(&values[9..], &[1.0, 2.0, 3.0]);
                assert_eq!(values[0], 1.0);
            }
            m => panic!("{m:?}"),
        }
        assert_eq!(
            got[1],
            Message::String {
                device: "Status".into(),
                text: "hello".into()
            }
        );
        match &got[2] {
            Message::PolyData { points, polygons, .. } => {
                assert_eq!(points.len(), 3);
                assert_eq!(polygons, &vec![vec![0, 1, 2]]);
            }
            m => panic!("{m:?}"),
        }
        match &got[3] {
            Message::PolyData { points, lines, .. } => {
                assert_eq!(points.len(), 2);
                assert_eq!(lines, &vec![vec![0, 1]]);
            }
            m => panic!("{m:?}"),
        }
        // A flipped body byte fails the CRC.
        let mut bad = b.clone();
        bad[HEADER_SIZE + 20] ^= 0x40;
        assert!(matches!(decode(&bad, 1 << 20), Err(DecodeError::Crc { .. })));
        assert!(matches!(decode(&b[..30], 1 << 20), Err(DecodeError::Incomplete)));
        let h = Header::parse(&b).unwrap();
        assert_eq!((h.version, h.kind.as_str()), (2, "TRANSFORM"));
        assert!((h.timestamp_s - 12.5).abs() < 1e-9);
    }
}
