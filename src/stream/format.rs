//! The wire format (`docs/STREAM.md` is the normative description; keep
//! the two in step): message payloads, the 28-byte datagram header, chunking,
//! and the [`Decoder`] that reassembles and validates datagrams.
//!
//! All integers and floats are little-endian. A *message* (one topology or
//! one state frame) is cut into chunks; each chunk travels in one datagram of
//! at most [`MAX_DATAGRAM`] bytes behind a header that names the message
//! (sequence number, kind, epoch, total length) and the chunk (index, count,
//! byte offset).

use super::{InstrumentLine, StateFrame, Topology, MAX_FRAME_INSTRUMENTS, MAX_INSTRUMENT_POINTS, MAX_VERTICES};
use std::collections::VecDeque;

/// First four bytes of every datagram.
pub const MAGIC: [u8; 4] = *b"NVTS";
/// Format version a sender writes. 3: state frames end with one polyline
/// per instrument (id, kind, points); 2: with the guidewire's polyline
/// alone. The decoder reads both; a receiver rejects any other.
pub const VERSION: u16 = 3;
/// The previous version, still read by [`Decoder`] (its polyline becomes
/// one guidewire instrument with id 0).
pub const VERSION_2: u16 = 2;
/// Datagram header length (bytes).
pub const HEADER_LEN: usize = 28;
/// Largest datagram a sender emits and a receiver accepts (bytes): fits the
/// 1280-byte IPv6 minimum MTU with IP and UDP headers.
pub const MAX_DATAGRAM: usize = 1200;
/// Largest chunk payload (bytes).
pub const MAX_CHUNK_PAYLOAD: usize = MAX_DATAGRAM - HEADER_LEN;
/// Largest message (bytes) a receiver reassembles.
pub const MAX_MESSAGE_LEN: usize = 8 << 20;
/// Message kind: topology.
pub const KIND_TOPOLOGY: u8 = 1;
/// Message kind: state frame.
pub const KIND_STATE: u8 = 2;
/// Fixed part of a state payload before the positions (bytes).
pub const STATE_FIXED_LEN: usize = 52;
/// Fixed part of a topology payload before the arrays (bytes).
pub const TOPOLOGY_FIXED_LEN: usize = 8;

/// Messages reassembled at once; a new one beyond this drops the oldest
/// incomplete one, and so does completing a message this many sequence
/// numbers ahead of it (counted in [`DecoderStats::incomplete`]).
const MAX_IN_FLIGHT: usize = 8;
/// Completed sequence numbers remembered to recognise duplicates.
const REMEMBER_COMPLETED: usize = 64;
/// A sequence number this far behind the newest is a sender restart, not a
/// late message.
const LATE_WINDOW: i64 = 64;
/// A jump this far ahead is a sender restart, not lost messages.
const GAP_WINDOW: i64 = 1 << 20;

fn put_u16(out: &mut Vec<u8>, v: u16) {
    out.extend_from_slice(&v.to_le_bytes());
}
fn put_u32(out: &mut Vec<u8>, v: u32) {
    out.extend_from_slice(&v.to_le_bytes());
}
fn put_f32(out: &mut Vec<u8>, v: f32) {
    out.extend_from_slice(&v.to_le_bytes());
}

/// Length of a topology payload with `v` vertices and `t` triangles.
pub fn topology_len(v: usize, t: usize) -> usize {
    TOPOLOGY_FIXED_LEN + 16 * v + 12 * t
}

/// Length of a state payload with `v` vertices and one polyline per
/// instrument of `points[k]` points.
pub fn state_len(v: usize, points: &[usize]) -> usize {
    STATE_FIXED_LEN + 12 * v + 4 + points.iter().map(|w| 4 + 12 * w).sum::<usize>()
}

/// The longest state payload with `v` vertices (every instrument slot
/// full).
pub fn state_len_max(v: usize) -> usize {
    state_len(v, &[MAX_INSTRUMENT_POINTS; MAX_FRAME_INSTRUMENTS])
}

/// Why a frame's instrument polylines do not fit the format (None: they
/// do).
pub fn instruments_invalid(lines: &[InstrumentLine<'_>]) -> Option<String> {
    if lines.len() > MAX_FRAME_INSTRUMENTS {
        return Some(format!("{} instruments, at most {MAX_FRAME_INSTRUMENTS}", lines.len()));
    }
    lines.iter().find(|l| l.points.len() > MAX_INSTRUMENT_POINTS).map(|l| {
        format!(
            "instrument {} has {} points, at most {MAX_INSTRUMENT_POINTS}",
            l.id,
            l.points.len()
        )
    })
}

/// Appends a topology payload to `out`.
pub fn encode_topology(t: &Topology, out: &mut Vec<u8>) {
    out.reserve(topology_len(t.rest_positions.len(), t.triangles.len()));
    put_u32(out, t.rest_positions.len() as u32);
    put_u32(out, t.triangles.len() as u32);
    for p in &t.rest_positions {
        p.iter().for_each(|&x| put_f32(out, x));
    }
    for tri in &t.triangles {
        tri.iter().for_each(|&i| put_u32(out, i));
    }
    t.node_ids.iter().for_each(|&i| put_u32(out, i));
}

/// Appends a state payload to `out` (the caller checks the instruments'
/// counts, [`instruments_invalid`]; the counts are written as given).
pub fn encode_state(f: &StateFrame, out: &mut Vec<u8>) {
    out.reserve(STATE_FIXED_LEN + 12 * f.positions.len() + 4);
    out.extend_from_slice(&f.time_s.to_le_bytes());
    put_u32(out, f.flags);
    put_u32(out, f.positions.len() as u32);
    f.tool_position.iter().for_each(|&x| put_f32(out, x));
    put_f32(out, f.tool_radius);
    f.force.iter().for_each(|&x| put_f32(out, x));
    put_f32(out, f.loop_rate_hz);
    put_f32(out, f.tick_p99_us);
    for p in f.positions {
        p.iter().for_each(|&x| put_f32(out, x));
    }
    put_u32(out, f.instruments.len() as u32);
    for line in f.instruments {
        out.push(line.id);
        out.push(line.kind);
        put_u16(out, line.points.len().min(u16::MAX as usize) as u16);
        for p in line.points {
            p.iter().for_each(|&x| put_f32(out, x));
        }
    }
}

/// The header fields of one datagram.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Header {
    /// Format version ([`VERSION`] or [`VERSION_2`]).
    pub version: u16,
    /// Message kind ([`KIND_TOPOLOGY`] or [`KIND_STATE`]).
    pub kind: u8,
    /// Message sequence number (one counter for all messages of a sender).
    pub seq: u32,
    /// Topology epoch.
    pub epoch: u32,
    /// Total message payload length (bytes).
    pub message_len: u32,
    /// Byte offset of this chunk in the message payload.
    pub chunk_offset: u32,
    /// Index of this chunk.
    pub chunk_index: u16,
    /// Number of chunks of the message.
    pub chunk_count: u16,
}

/// Cuts `message` into datagrams (header + at most `chunk_payload` bytes
/// each, clamped to [1, [`MAX_CHUNK_PAYLOAD`]]), building each one in `buf`
/// and handing it to `send`. Returns the number of datagrams, or `None` if
/// the message is empty or too large for the format.
pub fn chunk_message(
    kind: u8,
    seq: u32,
    epoch: u32,
    message: &[u8],
    chunk_payload: usize,
    buf: &mut Vec<u8>,
    mut send: impl FnMut(&[u8]),
) -> Option<usize> {
    let p = chunk_payload.clamp(1, MAX_CHUNK_PAYLOAD);
    let count = message.len().div_ceil(p);
    if message.is_empty() || message.len() > MAX_MESSAGE_LEN || count > u16::MAX as usize {
        return None;
    }
    for (k, chunk) in message.chunks(p).enumerate() {
        buf.clear();
        buf.extend_from_slice(&MAGIC);
        put_u16(buf, VERSION);
        buf.push(kind);
        buf.push(0);
        put_u32(buf, seq);
        put_u32(buf, epoch);
        put_u32(buf, message.len() as u32);
        put_u32(buf, (k * p) as u32);
        put_u16(buf, k as u16);
        put_u16(buf, count as u16);
        buf.extend_from_slice(chunk);
        send(buf);
    }
    Some(count)
}

/// Why a datagram or a reassembled message was rejected.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum RejectReason {
    /// Shorter than the header, or no payload.
    Short,
    /// Longer than [`MAX_DATAGRAM`].
    Oversized,
    /// Does not start with [`MAGIC`].
    BadMagic,
    /// A version other than [`VERSION`] and [`VERSION_2`].
    BadVersion,
    /// An unknown message kind.
    BadKind,
    /// Chunk fields out of range: index ≥ count, chunk beyond the message,
    /// message longer than [`MAX_MESSAGE_LEN`] or than its chunks can carry.
    BadChunk,
    /// Disagrees with other chunks of the same message (kind, epoch, length,
    /// count), chunks that do not tile the message, or a state frame whose
    /// vertex count differs from its epoch's topology.
    Inconsistent,
    /// The reassembled payload breaks its own rules (lengths, indices,
    /// non-finite numbers).
    BadPayload,
}

impl RejectReason {
    /// All reasons, in counter order.
    pub const ALL: [RejectReason; 8] = [
        RejectReason::Short,
        RejectReason::Oversized,
        RejectReason::BadMagic,
        RejectReason::BadVersion,
        RejectReason::BadKind,
        RejectReason::BadChunk,
        RejectReason::Inconsistent,
        RejectReason::BadPayload,
    ];

    /// Short snake_case name (counter and JSON key).
    pub fn name(self) -> &'static str {
        match self {
            RejectReason::Short => "short",
            RejectReason::Oversized => "oversized",
            RejectReason::BadMagic => "bad_magic",
            RejectReason::BadVersion => "bad_version",
            RejectReason::BadKind => "bad_kind",
            RejectReason::BadChunk => "bad_chunk",
            RejectReason::Inconsistent => "inconsistent",
            RejectReason::BadPayload => "bad_payload",
        }
    }

    fn index(self) -> usize {
        self as usize
    }
}

/// What a [`Decoder`] has seen.
#[derive(Debug, Clone, Default, PartialEq, Eq, serde::Serialize)]
pub struct DecoderStats {
    /// Datagrams pushed.
    pub datagrams: u64,
    /// Rejections by reason, in [`RejectReason::ALL`] order.
    pub rejected: [u64; 8],
    /// Chunks received twice, and chunks of messages already complete.
    pub duplicates: u64,
    /// Topology messages delivered.
    pub topologies: u64,
    /// State frames delivered.
    pub states: u64,
    /// Messages never seen so far, from jumps in the sequence numbers
    /// (decremented when a late one completes after all).
    pub gaps: u64,
    /// Messages that completed after a newer one.
    pub reordered: u64,
    /// State frames not delivered because a newer one was already delivered.
    pub stale: u64,
    /// Incomplete messages dropped to make room for newer ones.
    pub incomplete: u64,
    /// State frames not delivered because no topology of their epoch is known.
    pub awaiting_topology: u64,
    /// Sequence jumps so large they were taken as a sender restart.
    pub resyncs: u64,
}

impl DecoderStats {
    /// Total rejected datagrams and messages.
    pub fn total_rejected(&self) -> u64 {
        self.rejected.iter().sum()
    }

    /// Rejections of one reason.
    pub fn rejected_for(&self, r: RejectReason) -> u64 {
        self.rejected[r.index()]
    }
}

/// A decoded state frame (owned).
#[derive(Debug, Clone, PartialEq)]
pub struct OwnedState {
    /// Message sequence number.
    pub seq: u32,
    /// Epoch of the topology the positions index.
    pub epoch: u32,
    /// Simulation time (s).
    pub time_s: f64,
    /// Status bits ([`super::flags`]).
    pub flags: u32,
    /// Vertex positions (m).
    pub positions: Vec<[f32; 3]>,
    /// Tool centre (m).
    pub tool_position: [f32; 3],
    /// Tool radius (m).
    pub tool_radius: f32,
    /// Force on the hand (N).
    pub force: [f32; 3],
    /// Haptic loop rate (Hz).
    pub loop_rate_hz: f32,
    /// Tick compute p99 (µs).
    pub tick_p99_us: f32,
    /// One polyline per instrument (id, kind, points hub to tip in m).
    pub instruments: Vec<OwnedInstrumentLine>,
}

/// A decoded instrument polyline (owned).
#[derive(Debug, Clone, PartialEq)]
pub struct OwnedInstrumentLine {
    /// The instrument's id in the sender's run.
    pub id: u8,
    /// Its kind code ([`super::instrument_kind`]).
    pub kind: u8,
    /// Its points (m).
    pub points: Vec<[f32; 3]>,
}

impl OwnedInstrumentLine {
    /// Borrows it for a [`StateFrame`].
    pub fn as_line(&self) -> InstrumentLine<'_> {
        InstrumentLine {
            id: self.id,
            kind: self.kind,
            points: &self.points,
        }
    }
}

impl OwnedState {
    /// The instruments' polylines borrowed, for [`OwnedState::as_frame`].
    pub fn lines(&self) -> Vec<InstrumentLine<'_>> {
        self.instruments.iter().map(OwnedInstrumentLine::as_line).collect()
    }

    /// The first polyline of instrument kind `kind` (2: the guidewire), or
    /// an empty slice.
    pub fn polyline_of_kind(&self, kind: u8) -> &[[f32; 3]] {
        self.instruments
            .iter()
            .find(|l| l.kind == kind)
            .map(|l| l.points.as_slice())
            .unwrap_or(&[])
    }

    /// Borrows it as a [`StateFrame`] (e.g. to re-encode it) over `lines`
    /// ([`OwnedState::lines`]).
    pub fn as_frame<'a>(&'a self, lines: &'a [InstrumentLine<'a>]) -> StateFrame<'a> {
        StateFrame {
            time_s: self.time_s,
            positions: &self.positions,
            tool_position: self.tool_position,
            tool_radius: self.tool_radius,
            force: self.force,
            flags: self.flags,
            loop_rate_hz: self.loop_rate_hz,
            tick_p99_us: self.tick_p99_us,
            instruments: lines,
        }
    }
}

/// A complete, valid message.
#[derive(Debug, Clone, PartialEq)]
pub enum Decoded {
    /// A topology (replaces any previous one).
    Topology(Topology),
    /// A state frame of the current topology's epoch.
    State(OwnedState),
}

#[derive(Debug)]
struct Partial {
    header: Header,
    data: Vec<u8>,
    /// (offset, len) per chunk index; len 0 = not yet received.
    chunks: Vec<(u32, u32)>,
    received: usize,
}

/// Reassembles datagrams (in any order) into messages and validates them.
/// Never panics on any input; every rejection is counted by reason.
#[derive(Debug, Default)]
pub struct Decoder {
    partial: Vec<Partial>,
    completed: VecDeque<u32>,
    newest_seq: Option<u32>,
    newest_state_seq: Option<u32>,
    topology: Option<Topology>,
    stats: DecoderStats,
}

fn u16_at(b: &[u8], o: usize) -> u16 {
    u16::from_le_bytes([b[o], b[o + 1]])
}
fn u32_at(b: &[u8], o: usize) -> u32 {
    u32::from_le_bytes([b[o], b[o + 1], b[o + 2], b[o + 3]])
}
fn f32_at(b: &[u8], o: usize) -> f32 {
    f32::from_bits(u32_at(b, o))
}
fn vec3_at(b: &[u8], o: usize) -> [f32; 3] {
    [f32_at(b, o), f32_at(b, o + 4), f32_at(b, o + 8)]
}
fn finite3(p: &[f32; 3]) -> bool {
    p.iter().all(|v| v.is_finite())
}

/// Parses a datagram header (no range checks beyond the header's own
/// fields being readable).
pub fn parse_header(d: &[u8]) -> Result<Header, RejectReason> {
    if d.len() > MAX_DATAGRAM {
        return Err(RejectReason::Oversized);
    }
    if d.len() < 4 || d[..4] != MAGIC {
        return Err(if d.len() < 4 {
            RejectReason::Short
        } else {
            RejectReason::BadMagic
        });
    }
    if d.len() < 6 {
        return Err(RejectReason::Short);
    }
    let version = u16_at(d, 4);
    if version != VERSION && version != VERSION_2 {
        return Err(RejectReason::BadVersion);
    }
    if d.len() <= HEADER_LEN {
        return Err(RejectReason::Short);
    }
    let h = Header {
        version,
        kind: d[6],
        seq: u32_at(d, 8),
        epoch: u32_at(d, 12),
        message_len: u32_at(d, 16),
        chunk_offset: u32_at(d, 20),
        chunk_index: u16_at(d, 24),
        chunk_count: u16_at(d, 26),
    };
    if h.kind != KIND_TOPOLOGY && h.kind != KIND_STATE {
        return Err(RejectReason::BadKind);
    }
    let len = (d.len() - HEADER_LEN) as u64;
    let ml = h.message_len as u64;
    if h.chunk_count == 0
        || h.chunk_index >= h.chunk_count
        || ml == 0
        || ml > MAX_MESSAGE_LEN as u64
        || ml > h.chunk_count as u64 * MAX_CHUNK_PAYLOAD as u64
        || h.chunk_offset as u64 + len > ml
    {
        return Err(RejectReason::BadChunk);
    }
    Ok(h)
}

/// Decodes a topology payload (`epoch` from the header).
pub fn decode_topology(epoch: u32, p: &[u8]) -> Result<Topology, RejectReason> {
    if p.len() < TOPOLOGY_FIXED_LEN {
        return Err(RejectReason::BadPayload);
    }
    let v = u32_at(p, 0) as usize;
    let t = u32_at(p, 4) as usize;
    if v > MAX_VERTICES || t > 4 * MAX_VERTICES || topology_len(v, t) != p.len() {
        return Err(RejectReason::BadPayload);
    }
    let rest_positions: Vec<[f32; 3]> = (0..v).map(|i| vec3_at(p, 8 + 12 * i)).collect();
    if !rest_positions.iter().all(finite3) {
        return Err(RejectReason::BadPayload);
    }
    let to = 8 + 12 * v;
    let triangles: Vec<[u32; 3]> = (0..t)
        .map(|k| [0, 1, 2].map(|j| u32_at(p, to + 12 * k + 4 * j)))
        .collect();
    if triangles.iter().flatten().any(|&i| i as usize >= v) {
        return Err(RejectReason::BadPayload);
    }
    let no = to + 12 * t;
    let node_ids = (0..v).map(|i| u32_at(p, no + 4 * i)).collect();
    Ok(Topology {
        epoch,
        rest_positions,
        triangles,
        node_ids,
    })
}

/// The instrument polylines after the positions, from byte `o` of `p`:
/// version 3's list, or version 2's single guidewire polyline.
fn decode_instruments(version: u16, p: &[u8], o: usize) -> Result<Vec<OwnedInstrumentLine>, RejectReason> {
    let n = u32_at(p, o) as usize;
    let mut at = o + 4;
    if version == VERSION_2 {
        if n > MAX_INSTRUMENT_POINTS || at + 12 * n != p.len() {
            return Err(RejectReason::BadPayload);
        }
        if n == 0 {
            return Ok(Vec::new());
        }
        let points = (0..n).map(|i| vec3_at(p, at + 12 * i)).collect();
        return Ok(vec![OwnedInstrumentLine { id: 0, kind: 2, points }]);
    }
    if n > MAX_FRAME_INSTRUMENTS {
        return Err(RejectReason::BadPayload);
    }
    let mut out = Vec::with_capacity(n);
    for _ in 0..n {
        if at + 4 > p.len() {
            return Err(RejectReason::BadPayload);
        }
        let (id, kind, w) = (p[at], p[at + 1], u16_at(p, at + 2) as usize);
        at += 4;
        if w > MAX_INSTRUMENT_POINTS || at + 12 * w > p.len() {
            return Err(RejectReason::BadPayload);
        }
        let points = (0..w).map(|i| vec3_at(p, at + 12 * i)).collect();
        at += 12 * w;
        out.push(OwnedInstrumentLine { id, kind, points });
    }
    if at != p.len() {
        return Err(RejectReason::BadPayload);
    }
    Ok(out)
}

/// Decodes a state payload (`seq` and `epoch` from the header) of format
/// `version` ([`VERSION`] or [`VERSION_2`]).
pub fn decode_state(version: u16, seq: u32, epoch: u32, p: &[u8]) -> Result<OwnedState, RejectReason> {
    if p.len() < STATE_FIXED_LEN {
        return Err(RejectReason::BadPayload);
    }
    let v = u32_at(p, 12) as usize;
    if v > MAX_VERTICES || p.len() < state_len(v, &[]) {
        return Err(RejectReason::BadPayload);
    }
    let wo = STATE_FIXED_LEN + 12 * v;
    let instruments = decode_instruments(version, p, wo)?;
    let mut t = [0u8; 8];
    t.copy_from_slice(&p[0..8]);
    let s = OwnedState {
        seq,
        epoch,
        time_s: f64::from_le_bytes(t),
        flags: u32_at(p, 8),
        tool_position: vec3_at(p, 16),
        tool_radius: f32_at(p, 28),
        force: vec3_at(p, 32),
        loop_rate_hz: f32_at(p, 44),
        tick_p99_us: f32_at(p, 48),
        positions: (0..v).map(|i| vec3_at(p, STATE_FIXED_LEN + 12 * i)).collect(),
        instruments,
    };
    let ok = s.time_s.is_finite()
        && finite3(&s.tool_position)
        && finite3(&s.force)
        && s.tool_radius.is_finite()
        && s.loop_rate_hz.is_finite()
        && s.tick_p99_us.is_finite()
        && s.positions.iter().all(finite3)
        && s.instruments.iter().flat_map(|l| &l.points).all(finite3);
    if ok {
        Ok(s)
    } else {
        Err(RejectReason::BadPayload)
    }
}

impl Decoder {
    /// An empty decoder (no topology yet).
    pub fn new() -> Decoder {
        Decoder::default()
    }

    /// Counters so far.
    pub fn stats(&self) -> &DecoderStats {
        &self.stats
    }

    /// The current topology, if one has been received.
    pub fn topology(&self) -> Option<&Topology> {
        self.topology.as_ref()
    }

    fn reject<T>(&mut self, r: RejectReason) -> Result<T, RejectReason> {
        self.stats.rejected[r.index()] += 1;
        Err(r)
    }

    /// Takes one datagram. Returns the message it completes, if any;
    /// rejections are counted and returned as `Err`, duplicates and
    /// incomplete messages give `Ok(None)`.
    pub fn push(&mut self, d: &[u8]) -> Result<Option<Decoded>, RejectReason> {
        self.stats.datagrams += 1;
        let h = match parse_header(d) {
            Ok(h) => h,
            Err(r) => return self.reject(r),
        };
        if self.completed.contains(&h.seq) {
            self.stats.duplicates += 1;
            return Ok(None);
        }
        let chunk = &d[HEADER_LEN..];
        let slot = match self.partial.iter().position(|p| p.header.seq == h.seq) {
            Some(i) => {
                let ph = &self.partial[i].header;
                if ph.kind != h.kind
                    || ph.version != h.version
                    || ph.epoch != h.epoch
                    || ph.message_len != h.message_len
                    || ph.chunk_count != h.chunk_count
                {
                    return self.reject(RejectReason::Inconsistent);
                }
                i
            }
            None => {
                if self.partial.len() >= MAX_IN_FLIGHT {
                    // Drop the oldest (by sequence distance from this one).
                    let oldest = (0..self.partial.len())
                        .max_by_key(|&i| h.seq.wrapping_sub(self.partial[i].header.seq))
                        .unwrap_or(0);
                    self.partial.swap_remove(oldest);
                    self.stats.incomplete += 1;
                }
                self.partial.push(Partial {
                    header: h,
                    data: vec![0; h.message_len as usize],
                    chunks: vec![(0, 0); h.chunk_count as usize],
                    received: 0,
                });
                self.partial.len() - 1
            }
        };
        let p = &mut self.partial[slot];
        let k = h.chunk_index as usize;
        if p.chunks[k].1 != 0 {
            self.stats.duplicates += 1;
            return Ok(None);
        }
        let off = h.chunk_offset as usize;
        p.data[off..off + chunk.len()].copy_from_slice(chunk);
        p.chunks[k] = (h.chunk_offset, chunk.len() as u32);
        p.received += 1;
        if p.received < p.chunks.len() {
            return Ok(None);
        }
        let p = self.partial.swap_remove(slot);
        self.remember(h.seq);
        let mut expect = 0u64;
        for &(o, l) in &p.chunks {
            if o as u64 != expect {
                return self.reject(RejectReason::Inconsistent);
            }
            expect += l as u64;
        }
        if expect != h.message_len as u64 {
            return self.reject(RejectReason::Inconsistent);
        }
        self.complete(h, &p.data)
    }

    fn remember(&mut self, seq: u32) {
        if self.completed.len() >= REMEMBER_COMPLETED {
            self.completed.pop_front();
        }
        self.completed.push_back(seq);
    }

    /// Sequence bookkeeping for a completed message; returns whether it is
    /// newer than every message completed before.
    fn track_seq(&mut self, seq: u32) -> bool {
        let Some(newest) = self.newest_seq else {
            self.newest_seq = Some(seq);
            return true;
        };
        let d = seq.wrapping_sub(newest) as i32 as i64;
        if d > 0 && d < GAP_WINDOW {
            self.stats.gaps += (d - 1) as u64;
            self.newest_seq = Some(seq);
            // A message this far behind the newest has lost a chunk for good.
            let before = self.partial.len();
            self.partial
                .retain(|p| (seq.wrapping_sub(p.header.seq) as i32 as i64) <= MAX_IN_FLIGHT as i64);
            self.stats.incomplete += (before - self.partial.len()) as u64;
            true
        } else if d <= 0 && d > -LATE_WINDOW {
            self.stats.reordered += 1;
            self.stats.gaps = self.stats.gaps.saturating_sub(1);
            false
        } else {
            self.stats.resyncs += 1;
            self.newest_seq = Some(seq);
            self.newest_state_seq = None;
            true
        }
    }

    fn complete(&mut self, h: Header, data: &[u8]) -> Result<Option<Decoded>, RejectReason> {
        match h.kind {
            KIND_TOPOLOGY => {
                let t = match decode_topology(h.epoch, data) {
                    Ok(t) => t,
                    Err(r) => return self.reject(r),
                };
                self.track_seq(h.seq);
                self.stats.topologies += 1;
                self.topology = Some(t.clone());
                Ok(Some(Decoded::Topology(t)))
            }
            _ => {
                let s = match decode_state(h.version, h.seq, h.epoch, data) {
                    Ok(s) => s,
                    Err(r) => return self.reject(r),
                };
                let nv = match &self.topology {
                    Some(t) if t.epoch == h.epoch => t.rest_positions.len(),
                    _ => {
                        self.track_seq(h.seq);
                        self.stats.awaiting_topology += 1;
                        return Ok(None);
                    }
                };
                if nv != s.positions.len() {
                    return self.reject(RejectReason::Inconsistent);
                }
                self.track_seq(h.seq);
                let newer = match self.newest_state_seq {
                    None => true,
                    Some(n) => (h.seq.wrapping_sub(n) as i32) > 0,
                };
                if !newer {
                    self.stats.stale += 1;
                    return Ok(None);
                }
                self.newest_state_seq = Some(h.seq);
                self.stats.states += 1;
                Ok(Some(Decoded::State(s)))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn topo(n: usize) -> Topology {
        Topology {
            epoch: 3,
            rest_positions: (0..n).map(|i| [i as f32 * 1e-3, 0.0, 1.0]).collect(),
            triangles: (0..n.saturating_sub(2))
                .map(|i| [i as u32, i as u32 + 1, i as u32 + 2])
                .collect(),
            node_ids: (0..n as u32).map(|i| i * 2).collect(),
        }
    }

    fn frame(pos: &[[f32; 3]], t: f64) -> StateFrame<'_> {
        StateFrame {
            time_s: t,
            positions: pos,
            tool_position: [0.01, 0.02, 0.03],
            tool_radius: 0.002,
            force: [0.5, -1.0, 2.0],
            flags: super::super::flags::IN_CONTACT,
            loop_rate_hz: 1000.0,
            tick_p99_us: 42.0,
            instruments: &[],
        }
    }

    fn datagrams(kind: u8, seq: u32, epoch: u32, msg: &[u8]) -> Vec<Vec<u8>> {
        let mut out = Vec::new();
        let mut buf = Vec::new();
        chunk_message(kind, seq, epoch, msg, MAX_CHUNK_PAYLOAD, &mut buf, |d| {
            out.push(d.to_vec())
        })
        .unwrap();
        out
    }

    #[test]
    fn round_trip_in_any_order_with_gap_detection() {
        let t = topo(500);
        let mut m = Vec::new();
        encode_topology(&t, &mut m);
        assert_eq!(m.len(), topology_len(500, 498));
        let mut dec = Decoder::new();
        let mut dg = datagrams(KIND_TOPOLOGY, 0, 3, &m);
        assert!(dg.len() > 5);
        dg.reverse();
        let mut got = None;
        for d in &dg {
            if let Some(x) = dec.push(d).unwrap() {
                got = Some(x);
            }
        }
        assert_eq!(got, Some(Decoded::Topology(t.clone())));
        let pos: Vec<[f32; 3]> = t.rest_positions.iter().map(|p| [p[0], p[1] + 0.001, p[2]]).collect();
        let f = frame(&pos, 1.25);
        let mut m = Vec::new();
        encode_state(&f, &mut m);
        // seq 1 lost, seq 2 arrives interleaved with a duplicate chunk.
        let dg = datagrams(KIND_STATE, 2, 3, &m);
        dec.push(&dg[1]).unwrap();
        dec.push(&dg[1]).unwrap();
        let mut got = None;
        for d in dg.iter().rev() {
            if let Some(x) = dec.push(d).unwrap() {
                got = Some(x);
            }
        }
        match got {
            Some(Decoded::State(s)) => {
                assert_eq!(s.seq, 2);
                assert_eq!(s.positions, pos);
                assert_eq!(s.time_s, 1.25);
                assert_eq!(s.force, [0.5, -1.0, 2.0]);
                assert_eq!(s.tick_p99_us, 42.0);
            }
            other => panic!("{other:?}"),
        }
        assert_eq!(dec.stats().gaps, 1);
        assert_eq!(dec.stats().duplicates, 2);
        assert_eq!(dec.stats().total_rejected(), 0);
        // A late seq 1 fills the gap but is stale.
        for d in datagrams(KIND_STATE, 1, 3, &m) {
            assert_eq!(dec.push(&d).unwrap(), None);
        }
        assert_eq!(dec.stats().gaps, 0);
        assert_eq!(dec.stats().stale, 1);
    }

    #[test]
    fn each_bad_input_is_counted_under_its_reason() {
        let t = topo(10);
        let mut m = Vec::new();
        encode_topology(&t, &mut m);
        let good = datagrams(KIND_TOPOLOGY, 7, 3, &m).remove(0);
        let mut dec = Decoder::new();
        let expect = |d: Vec<u8>, r: RejectReason, dec: &mut Decoder| {
            assert_eq!(dec.push(&d), Err(r));
            assert_eq!(dec.stats().rejected_for(r), 1, "{r:?}");
        };
        expect(good[..10].to_vec(), RejectReason::Short, &mut dec);
        expect(vec![0; MAX_DATAGRAM + 1], RejectReason::Oversized, &mut dec);
        let mut d = good.clone();
        d[0] = b'X';
        expect(d, RejectReason::BadMagic, &mut dec);
        let mut d = good.clone();
        d[4] = (VERSION + 1) as u8;
        expect(d, RejectReason::BadVersion, &mut dec);
        let mut d = good.clone();
        d[6] = 9;
        expect(d, RejectReason::BadKind, &mut dec);
        let mut d = good.clone();
        d[24] = 5; // index 5 of 1
        expect(d, RejectReason::BadChunk, &mut dec);
        // A state frame with the wrong vertex count for the topology.
        for d in datagrams(KIND_TOPOLOGY, 8, 3, &m) {
            dec.push(&d).unwrap();
        }
        let pos = vec![[0.0f32; 3]; 4];
        let mut s = Vec::new();
        encode_state(&frame(&pos, 0.0), &mut s);
        expect(
            datagrams(KIND_STATE, 9, 3, &s).remove(0),
            RejectReason::Inconsistent,
            &mut dec,
        );
        let pos = vec![[f32::NAN; 3]; 10];
        let mut s = Vec::new();
        encode_state(&frame(&pos, 0.0), &mut s);
        expect(
            datagrams(KIND_STATE, 10, 3, &s).remove(0),
            RejectReason::BadPayload,
            &mut dec,
        );
    }

    #[test]
    fn state_of_an_unknown_epoch_waits_for_its_topology() {
        let pos = vec![[0.0f32; 3]; 3];
        let mut s = Vec::new();
        encode_state(&frame(&pos, 0.0), &mut s);
        let mut dec = Decoder::new();
        assert_eq!(dec.push(&datagrams(KIND_STATE, 0, 1, &s)[0]), Ok(None));
        assert_eq!(dec.stats().awaiting_topology, 1);
    }
}
