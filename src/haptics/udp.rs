//! A UDP bridge to a separate process that owns the vendor driver (e.g. an
//! OpenHaptics program on another OS, or `tools/udp_device_peer.py`). The
//! peer sends pose datagrams; the service answers each write with a force
//! datagram. Both are small, fixed-size, versioned and little-endian; every
//! number is SI (m, m/s, N, s). Layouts are in `docs/DEVICE.md` and in
//! [`POSE_LEN`] / [`FORCE_LEN`] below.
//!
//! ## Pose datagram (peer → service), version 1, 84 bytes
//!
//! | offset | type     | field                                              |
//! |-------:|----------|----------------------------------------------------|
//! | 0      | [u8; 4]  | magic `b"NVTP"`                                    |
//! | 4      | u16      | version = 1                                        |
//! | 6      | u16      | reserved (send 0, ignored)                         |
//! | 8      | u64      | seq: strictly increasing per datagram              |
//! | 16     | f64      | device time (s, the peer's clock)                  |
//! | 24     | 3 × f64  | position (m)                                       |
//! | 48     | 3 × f64  | velocity (m/s)                                     |
//! | 72     | u32      | buttons (bit 0 = first button)                     |
//! | 76     | u32      | status: 0 ok, 1 communication error, 2 fault       |
//! | 80     | i32      | vendor error code (e.g. an HD error), 0 if none    |
//!
//! ## Pose datagram, version 2, 108 bytes
//!
//! Version 1's fields at the same offsets (with version = 2), then:
//!
//! | offset | type     | field                                              |
//! |-------:|----------|----------------------------------------------------|
//! | 84     | 3 × f64  | gimbal angles (rad), `HD_CURRENT_GIMBAL_ANGLES`    |
//! |        |          | order: the two gimbal joints, then the stylus roll |
//!
//! Both versions are accepted; a version-1 pose has zero gimbal angles.
//!
//! ## Force datagram (service → peer), version 1, 56 bytes
//!
//! | offset | type     | field                                              |
//! |-------:|----------|----------------------------------------------------|
//! | 0      | [u8; 4]  | magic `b"NVTF"`                                    |
//! | 4      | u16      | version = 1                                        |
//! | 6      | u16      | reserved (0)                                       |
//! | 8      | u64      | seq of this force datagram (from 1)                |
//! | 16     | u64      | seq of the newest pose the service had read        |
//! | 24     | 3 × f64  | force (N), already saturated                       |
//! | 48     | u32      | flags: bit 0 saturated, bit 1 stop (force is zero, |
//! |        |          | the service is stopping)                           |
//! | 52     | u32      | reserved (0)                                       |
//!
//! ## Receiving
//!
//! [`HapticDevice::read`] drains the socket without blocking and keeps the
//! newest valid pose. Datagrams are rejected, and counted by reason
//! ([`UdpCounters`]), when they are short, long, have a bad magic or version,
//! carry a non-finite number, a position outside the configured workspace or
//! a speed above the configured limit, a gimbal angle beyond
//! ±[`GIMBAL_LIMIT_RAD`], or a sequence number not above the last accepted
//! one (out of order or duplicated). The length picks the layout: shorter
//! than version 1 is short, longer than version 2 long, and a datagram of
//! one version's length whose version field names the other is a bad
//! version. A read returns
//! [`DeviceError::Stale`] when the newest valid pose arrived more than
//! `max_age_s` ago; with no new datagram but a recent one it returns the same
//! sample again (same `seq`). The decoder never panics on any bytes
//! (property-tested).

use crate::config::{load_toml, parse_toml, Checker, ConfigError};
use crate::haptics::device::{DeviceError, DeviceSample, HapticDevice, GIMBAL_LIMIT_RAD};
use crate::math::Vec3;
use std::io::ErrorKind;
use std::net::{SocketAddr, UdpSocket};
use std::path::Path;

/// Magic of a pose datagram.
pub const POSE_MAGIC: [u8; 4] = *b"NVTP";
/// Magic of a force datagram.
pub const FORCE_MAGIC: [u8; 4] = *b"NVTF";
/// Datagram format version 1 (the force datagram's only version, and the
/// pose datagram without gimbal angles).
pub const VERSION: u16 = 1;
/// Pose datagram version 2: version 1 plus the three gimbal angles.
pub const POSE_VERSION_2: u16 = 2;
/// Length of a version-1 pose datagram (bytes).
pub const POSE_LEN: usize = 84;
/// Length of a version-2 pose datagram (bytes).
pub const POSE_LEN_V2: usize = 108;
/// Length of a version-1 force datagram (bytes).
pub const FORCE_LEN: usize = 56;
/// Force flag: the force was saturated by the service.
pub const FLAG_SATURATED: u32 = 1;
/// Force flag: the service is stopping; the force is zero.
pub const FLAG_STOP: u32 = 2;
/// Pose status: the peer reports a communication error with its device.
pub const STATUS_COMM_ERROR: u32 = 1;
/// Pose status: the peer reports a device fault.
pub const STATUS_FAULT: u32 = 2;
/// Most datagrams drained per read (bounds the time a read takes).
pub const MAX_DRAIN: usize = 256;
/// Consecutive out-of-order datagrams after which the bridge accepts the
/// peer's new sequence (a restarted peer counts from 1 again).
pub const RESYNC_AFTER: u64 = 100;

/// A decoded pose datagram.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseDatagram {
    /// Sequence number.
    pub seq: u64,
    /// Peer's device time (s).
    pub device_time_s: f64,
    /// Position (m).
    pub position: [f64; 3],
    /// Velocity (m/s).
    pub velocity: [f64; 3],
    /// Button bits.
    pub buttons: u32,
    /// Status (0 ok, [`STATUS_COMM_ERROR`], [`STATUS_FAULT`]).
    pub status: u32,
    /// Vendor error code.
    pub error_code: i32,
    /// Gimbal angles (rad); zero in a version-1 datagram.
    pub gimbal_rad: [f64; 3],
}

/// A decoded force datagram.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ForceDatagram {
    /// Sequence number of this force datagram.
    pub seq: u64,
    /// Newest pose sequence number the service had read.
    pub pose_seq: u64,
    /// Force (N).
    pub force: [f64; 3],
    /// Flags ([`FLAG_SATURATED`], [`FLAG_STOP`]).
    pub flags: u32,
}

/// Why a datagram was rejected by the decoder.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Reject {
    /// Shorter than the layout.
    Short,
    /// Longer than the layout.
    Long,
    /// Wrong magic.
    BadMagic,
    /// Unknown version.
    BadVersion,
    /// A non-finite number.
    NonFinite,
}

fn f64_at(b: &[u8], off: usize) -> f64 {
    let mut a = [0u8; 8];
    a.copy_from_slice(&b[off..off + 8]);
    f64::from_le_bytes(a)
}

fn u64_at(b: &[u8], off: usize) -> u64 {
    let mut a = [0u8; 8];
    a.copy_from_slice(&b[off..off + 8]);
    u64::from_le_bytes(a)
}

fn u32_at(b: &[u8], off: usize) -> u32 {
    let mut a = [0u8; 4];
    a.copy_from_slice(&b[off..off + 4]);
    u32::from_le_bytes(a)
}

fn u16_at(b: &[u8], off: usize) -> u16 {
    u16::from_le_bytes([b[off], b[off + 1]])
}

fn vec_at(b: &[u8], off: usize) -> [f64; 3] {
    [f64_at(b, off), f64_at(b, off + 8), f64_at(b, off + 16)]
}

fn header(b: &[u8], len: usize, magic: [u8; 4]) -> Result<(), Reject> {
    if b.len() < len {
        return Err(Reject::Short);
    }
    if b.len() > len {
        return Err(Reject::Long);
    }
    if b[0..4] != magic {
        return Err(Reject::BadMagic);
    }
    if u16_at(b, 4) != VERSION {
        return Err(Reject::BadVersion);
    }
    Ok(())
}

/// Checks a pose datagram's length, magic and version; returns the version.
fn pose_header(b: &[u8]) -> Result<u16, Reject> {
    if b.len() < POSE_LEN {
        return Err(Reject::Short);
    }
    if b.len() > POSE_LEN_V2 {
        return Err(Reject::Long);
    }
    if b[0..4] != POSE_MAGIC {
        return Err(Reject::BadMagic);
    }
    let v = u16_at(b, 4);
    let want = match v {
        VERSION => POSE_LEN,
        POSE_VERSION_2 => POSE_LEN_V2,
        _ => return Err(Reject::BadVersion),
    };
    match b.len() {
        n if n == want => Ok(v),
        // The other version's layout with this version's number.
        POSE_LEN | POSE_LEN_V2 => Err(Reject::BadVersion),
        n if n < want => Err(Reject::Short),
        _ => Err(Reject::Long),
    }
}

/// Decodes a pose datagram of either version (any bytes; never panics).
pub fn decode_pose(b: &[u8]) -> Result<PoseDatagram, Reject> {
    let version = pose_header(b)?;
    let d = PoseDatagram {
        seq: u64_at(b, 8),
        device_time_s: f64_at(b, 16),
        position: vec_at(b, 24),
        velocity: vec_at(b, 48),
        buttons: u32_at(b, 72),
        status: u32_at(b, 76),
        error_code: u32_at(b, 80) as i32,
        gimbal_rad: if version == POSE_VERSION_2 {
            vec_at(b, 84)
        } else {
            [0.0; 3]
        },
    };
    let finite = d.device_time_s.is_finite()
        && d.position
            .iter()
            .chain(&d.velocity)
            .chain(&d.gimbal_rad)
            .all(|v| v.is_finite());
    if !finite {
        return Err(Reject::NonFinite);
    }
    Ok(d)
}

/// Encodes a version-1 pose datagram (no gimbal angles: `d.gimbal_rad` is
/// not sent).
pub fn encode_pose(d: &PoseDatagram) -> [u8; POSE_LEN] {
    let mut b = [0u8; POSE_LEN];
    write_pose_v1(d, &mut b);
    b
}

/// Encodes a version-2 pose datagram (with the gimbal angles).
pub fn encode_pose_v2(d: &PoseDatagram) -> [u8; POSE_LEN_V2] {
    let mut b = [0u8; POSE_LEN_V2];
    write_pose_v1(d, &mut b[..POSE_LEN]);
    b[4..6].copy_from_slice(&POSE_VERSION_2.to_le_bytes());
    for i in 0..3 {
        b[84 + 8 * i..92 + 8 * i].copy_from_slice(&d.gimbal_rad[i].to_le_bytes());
    }
    b
}

/// Writes version 1's 84 bytes into `b` (exactly [`POSE_LEN`] long).
fn write_pose_v1(d: &PoseDatagram, b: &mut [u8]) {
    b[0..4].copy_from_slice(&POSE_MAGIC);
    b[4..6].copy_from_slice(&VERSION.to_le_bytes());
    b[8..16].copy_from_slice(&d.seq.to_le_bytes());
    b[16..24].copy_from_slice(&d.device_time_s.to_le_bytes());
    for i in 0..3 {
        b[24 + 8 * i..32 + 8 * i].copy_from_slice(&d.position[i].to_le_bytes());
        b[48 + 8 * i..56 + 8 * i].copy_from_slice(&d.velocity[i].to_le_bytes());
    }
    b[72..76].copy_from_slice(&d.buttons.to_le_bytes());
    b[76..80].copy_from_slice(&d.status.to_le_bytes());
    b[80..84].copy_from_slice(&d.error_code.to_le_bytes());
}

/// Decodes a force datagram (any bytes; never panics).
pub fn decode_force(b: &[u8]) -> Result<ForceDatagram, Reject> {
    header(b, FORCE_LEN, FORCE_MAGIC)?;
    let d = ForceDatagram {
        seq: u64_at(b, 8),
        pose_seq: u64_at(b, 16),
        force: vec_at(b, 24),
        flags: u32_at(b, 48),
    };
    if !d.force.iter().all(|v| v.is_finite()) {
        return Err(Reject::NonFinite);
    }
    Ok(d)
}

/// Encodes a force datagram.
pub fn encode_force(d: &ForceDatagram) -> [u8; FORCE_LEN] {
    let mut b = [0u8; FORCE_LEN];
    b[0..4].copy_from_slice(&FORCE_MAGIC);
    b[4..6].copy_from_slice(&VERSION.to_le_bytes());
    b[8..16].copy_from_slice(&d.seq.to_le_bytes());
    b[16..24].copy_from_slice(&d.pose_seq.to_le_bytes());
    for i in 0..3 {
        b[24 + 8 * i..32 + 8 * i].copy_from_slice(&d.force[i].to_le_bytes());
    }
    b[48..52].copy_from_slice(&d.flags.to_le_bytes());
    b
}

/// The bridge's configuration (e.g. a `[device.udp]` table of the service
/// file, or `rt-config/udp_device.toml`).
#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct UdpParams {
    /// Address to bind (receives poses). Loopback by default; binding any
    /// other address exposes the force loop to that network.
    pub bind: String,
    /// Where to send forces. Empty: to the source of the newest valid pose.
    #[serde(default)]
    pub peer: String,
    /// A pose older than this (s, by arrival) makes reads fail as stale.
    pub max_age_s: f64,
    /// Workspace box (m), minimum corner; poses outside are rejected.
    pub workspace_min_m: [f64; 3],
    /// Workspace box (m), maximum corner.
    pub workspace_max_m: [f64; 3],
    /// Speeds above this (m/s) are rejected as out of range.
    pub max_speed_m_s: f64,
    /// Forces are clamped to this norm (N) before sending.
    pub max_force_n: f64,
}

impl Default for UdpParams {
    fn default() -> Self {
        UdpParams {
            bind: "127.0.0.1:47010".into(),
            peer: String::new(),
            max_age_s: 0.005,
            workspace_min_m: [-0.08, -0.06, -0.06],
            workspace_max_m: [0.08, 0.06, 0.06],
            max_speed_m_s: 5.0,
            max_force_n: 7.9,
        }
    }
}

impl UdpParams {
    /// Loads and validates a file holding only these keys.
    pub fn load(path: &Path) -> Result<UdpParams, ConfigError> {
        let p: UdpParams = load_toml(path)?;
        p.validate(path, "")?;
        Ok(p)
    }

    /// Parses and validates TOML text; `path` names it in errors.
    pub fn from_toml_str(text: &str, path: &Path) -> Result<UdpParams, ConfigError> {
        let p: UdpParams = parse_toml(text, path)?;
        p.validate(path, "")?;
        Ok(p)
    }

    /// Range checks. `prefix` is prepended to key names (e.g. `device.udp.`)
    /// when the table is embedded in a larger file.
    pub fn validate(&self, path: &Path, prefix: &str) -> Result<(), ConfigError> {
        let c = Checker::new(path);
        let k = |s: &str| format!("{prefix}{s}");
        if self.bind.parse::<SocketAddr>().is_err() {
            return Err(c.err(
                &k("bind"),
                format!("{:?}: must be an IP:port address, e.g. \"127.0.0.1:47010\"", self.bind),
            ));
        }
        if !self.peer.is_empty() && self.peer.parse::<SocketAddr>().is_err() {
            return Err(c.err(
                &k("peer"),
                format!("{:?}: must be empty or an IP:port address", self.peer),
            ));
        }
        c.f64_in(&k("max_age_s"), self.max_age_s, 1e-4, 1.0, "s")?;
        for a in 0..3 {
            c.f64_in(
                &k(&format!("workspace_min_m[{a}]")),
                self.workspace_min_m[a],
                -2.0,
                2.0,
                "m",
            )?;
            c.f64_in(
                &k(&format!("workspace_max_m[{a}]")),
                self.workspace_max_m[a],
                self.workspace_min_m[a],
                2.0,
                "m (≥ workspace_min_m)",
            )?;
        }
        c.f64_in(&k("max_speed_m_s"), self.max_speed_m_s, 0.01, 100.0, "m/s")?;
        c.f64_in(&k("max_force_n"), self.max_force_n, 0.0, 100.0, "N")?;
        Ok(())
    }
}

/// What the bridge counted (read after the fact; plain fields, the bridge is
/// owned by one thread).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct UdpCounters {
    /// Valid poses accepted (including ones superseded within a drain).
    pub accepted: u64,
    /// Valid poses that a newer one in the same drain replaced.
    pub superseded: u64,
    /// Rejected: shorter than the layout.
    pub short: u64,
    /// Rejected: longer than the layout.
    pub long: u64,
    /// Rejected: bad magic.
    pub bad_magic: u64,
    /// Rejected: unknown version.
    pub bad_version: u64,
    /// Rejected: non-finite number.
    pub non_finite: u64,
    /// Rejected: position outside the workspace or speed above the limit.
    pub out_of_range: u64,
    /// Rejected: a gimbal angle beyond ±[`GIMBAL_LIMIT_RAD`] (version 2).
    pub gimbal_out_of_range: u64,
    /// Rejected: sequence number not above the last accepted one.
    pub out_of_order: u64,
    /// Times the bridge accepted a restarted peer's sequence.
    pub resyncs: u64,
    /// Reads that returned [`DeviceError::Stale`].
    pub stale_reads: u64,
    /// Reads that found no new datagram but a recent one.
    pub repeated_reads: u64,
    /// Force datagrams sent.
    pub forces_sent: u64,
    /// Force datagrams not sent (no peer yet, or the socket was full).
    pub forces_dropped: u64,
    /// Socket errors other than "would block".
    pub io_errors: u64,
}

/// The UDP bridge device.
#[derive(Debug)]
pub struct UdpDevice {
    p: UdpParams,
    fixed_peer: Option<SocketAddr>,
    socket: Option<UdpSocket>,
    reply_to: Option<SocketAddr>,
    last: Option<(PoseDatagram, f64)>,
    last_seq: Option<u64>,
    sample_seq: u64,
    consecutive_out_of_order: u64,
    force_seq: u64,
    counters: UdpCounters,
    buf: [u8; 2 * POSE_LEN_V2],
}

impl UdpDevice {
    /// A bridge with `params` (validated with [`UdpParams::validate`]).
    /// Nothing is bound until [`HapticDevice::start`].
    pub fn new(params: UdpParams) -> UdpDevice {
        let fixed_peer = params.peer.parse().ok();
        UdpDevice {
            p: params,
            fixed_peer,
            socket: None,
            reply_to: None,
            last: None,
            last_seq: None,
            sample_seq: 0,
            consecutive_out_of_order: 0,
            force_seq: 0,
            counters: UdpCounters::default(),
            buf: [0; 2 * POSE_LEN_V2],
        }
    }

    /// The counters so far.
    pub fn counters(&self) -> UdpCounters {
        self.counters
    }

    /// The bound address, once started (useful with port 0).
    pub fn local_addr(&self) -> Option<SocketAddr> {
        self.socket.as_ref().and_then(|s| s.local_addr().ok())
    }

    fn in_range(&self, d: &PoseDatagram) -> bool {
        let (lo, hi) = (&self.p.workspace_min_m, &self.p.workspace_max_m);
        let inside = (0..3).all(|a| d.position[a] >= lo[a] && d.position[a] <= hi[a]);
        let v2: f64 = d.velocity.iter().map(|v| v * v).sum();
        inside && v2 <= self.p.max_speed_m_s * self.p.max_speed_m_s
    }

    /// Classifies one received datagram and keeps it if it is the newest
    /// valid pose.
    fn take(&mut self, len: usize, from: SocketAddr, now_s: f64) {
        let c = &mut self.counters;
        let d = match decode_pose(&self.buf[..len]) {
            Ok(d) => d,
            Err(r) => {
                match r {
                    Reject::Short => c.short += 1,
                    Reject::Long => c.long += 1,
                    Reject::BadMagic => c.bad_magic += 1,
                    Reject::BadVersion => c.bad_version += 1,
                    Reject::NonFinite => c.non_finite += 1,
                }
                return;
            }
        };
        if !self.in_range(&d) {
            self.counters.out_of_range += 1;
            return;
        }
        if d.gimbal_rad.iter().any(|a| a.abs() > GIMBAL_LIMIT_RAD) {
            self.counters.gimbal_out_of_range += 1;
            return;
        }
        if let Some(s) = self.last_seq {
            if d.seq <= s {
                self.consecutive_out_of_order += 1;
                if self.consecutive_out_of_order < RESYNC_AFTER {
                    self.counters.out_of_order += 1;
                    return;
                }
                self.counters.resyncs += 1;
            }
        }
        self.consecutive_out_of_order = 0;
        self.counters.accepted += 1;
        if self.last.is_some_and(|(_, t)| t == now_s) {
            self.counters.superseded += 1;
        }
        self.last_seq = Some(d.seq);
        self.last = Some((d, now_s));
        self.sample_seq += 1;
        self.reply_to = Some(from);
    }
}

impl HapticDevice for UdpDevice {
    fn name(&self) -> &'static str {
        "udp"
    }

    fn start(&mut self) -> Result<(), DeviceError> {
        if self.socket.is_some() {
            return Ok(());
        }
        let addr: SocketAddr = self.p.bind.parse().map_err(|_| DeviceError::Start(libc::EINVAL))?;
        let s = UdpSocket::bind(addr).map_err(|e| DeviceError::Start(e.raw_os_error().unwrap_or(-1)))?;
        s.set_nonblocking(true)
            .map_err(|e| DeviceError::Start(e.raw_os_error().unwrap_or(-1)))?;
        self.socket = Some(s);
        Ok(())
    }

    fn read(&mut self, now_s: f64) -> Result<DeviceSample, DeviceError> {
        let Some(sock) = self.socket.take() else {
            return Err(DeviceError::Start(0));
        };
        let before = self.sample_seq;
        for _ in 0..MAX_DRAIN {
            match sock.recv_from(&mut self.buf) {
                Ok((len, from)) => self.take(len, from, now_s),
                Err(e) if e.kind() == ErrorKind::WouldBlock => break,
                Err(e) if e.kind() == ErrorKind::Interrupted => continue,
                Err(_) => {
                    // e.g. ECONNREFUSED from an earlier send (ICMP); keep reading.
                    self.counters.io_errors += 1;
                    break;
                }
            }
        }
        self.socket = Some(sock);
        let Some((d, t)) = self.last else {
            self.counters.stale_reads += 1;
            return Err(DeviceError::Stale);
        };
        if now_s - t > self.p.max_age_s {
            self.counters.stale_reads += 1;
            return Err(DeviceError::Stale);
        }
        if self.sample_seq == before {
            self.counters.repeated_reads += 1;
        }
        match d.status {
            0 => {}
            STATUS_COMM_ERROR => return Err(DeviceError::Comm(d.error_code)),
            _ => return Err(DeviceError::Fault(d.error_code)),
        }
        let v3 = |a: [f64; 3]| Vec3::new(a[0], a[1], a[2]);
        Ok(DeviceSample {
            position: v3(d.position),
            velocity: v3(d.velocity),
            buttons: d.buttons,
            time_s: t,
            seq: self.sample_seq,
            gimbal_rad: d.gimbal_rad,
        })
    }

    fn write_force(&mut self, force: Vec3) -> Result<Vec3, DeviceError> {
        let (f, res) = if force.iter().all(|c| c.is_finite()) {
            (force, Ok(()))
        } else {
            (Vec3::zeros(), Err(DeviceError::BadData))
        };
        let n = f.norm();
        let (f, flags) = if n > self.p.max_force_n {
            (f * (self.p.max_force_n / n), FLAG_SATURATED)
        } else {
            (f, 0)
        };
        self.send(f, flags)?;
        res.map(|()| f)
    }

    fn stop(&mut self) {
        if self.socket.is_some() {
            let _ = self.send(Vec3::zeros(), FLAG_STOP);
        }
        self.socket = None;
    }
}

/// A dropped bridge stops like a stopped one: its peer gets the stop
/// datagram with a zero force (a service whose device thread could not be
/// spawned drops the device without its stop).
impl Drop for UdpDevice {
    fn drop(&mut self) {
        self.stop();
    }
}

impl UdpDevice {
    fn send(&mut self, f: Vec3, flags: u32) -> Result<(), DeviceError> {
        let Some(sock) = self.socket.as_ref() else {
            return Err(DeviceError::Start(0));
        };
        let Some(to) = self.fixed_peer.or(self.reply_to) else {
            self.counters.forces_dropped += 1;
            return Ok(());
        };
        self.force_seq += 1;
        let d = ForceDatagram {
            seq: self.force_seq,
            pose_seq: self.last_seq.unwrap_or(0),
            force: [f.x, f.y, f.z],
            flags,
        };
        match sock.send_to(&encode_force(&d), to) {
            Ok(_) => {
                self.counters.forces_sent += 1;
                Ok(())
            }
            Err(e) if e.kind() == ErrorKind::WouldBlock => {
                self.counters.forces_dropped += 1;
                Ok(())
            }
            Err(e) => {
                self.counters.io_errors += 1;
                self.counters.forces_dropped += 1;
                match e.kind() {
                    // The peer is not listening (ICMP port unreachable): not
                    // fatal, the pose side decides staleness.
                    ErrorKind::ConnectionRefused => Ok(()),
                    _ => Err(DeviceError::Comm(e.raw_os_error().unwrap_or(-1))),
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Dropped without a stop (a service whose device thread could not be
    /// spawned), the bridge still sends its peer the stop datagram.
    #[test]
    fn a_dropped_bridge_sends_the_stop() {
        let peer = UdpSocket::bind("127.0.0.1:0").unwrap();
        peer.set_read_timeout(Some(std::time::Duration::from_secs(5))).unwrap();
        let mut d = UdpDevice::new(UdpParams {
            bind: "127.0.0.1:0".into(),
            peer: peer.local_addr().unwrap().to_string(),
            ..UdpParams::default()
        });
        d.start().unwrap();
        drop(d);
        let mut buf = [0u8; 256];
        let n = peer.recv(&mut buf).expect("no stop datagram");
        let f = decode_force(&buf[..n]).unwrap();
        assert!(f.flags & FLAG_STOP != 0 && f.force == [0.0; 3], "{f:?}");
    }

    #[test]
    fn pose_and_force_round_trip() {
        let p = PoseDatagram {
            seq: 7,
            device_time_s: 1.25,
            position: [0.01, -0.02, 0.03],
            velocity: [0.1, 0.2, -0.3],
            buttons: 3,
            status: 0,
            error_code: -5,
            gimbal_rad: [0.0; 3],
        };
        assert_eq!(decode_pose(&encode_pose(&p)), Ok(p));
        let p2 = PoseDatagram {
            gimbal_rad: [0.1, -0.2, 3.0],
            ..p
        };
        assert_eq!(decode_pose(&encode_pose_v2(&p2)), Ok(p2));
        // Version 1 drops the angles.
        assert_eq!(decode_pose(&encode_pose(&p2)), Ok(p));
        let f = ForceDatagram {
            seq: 9,
            pose_seq: 7,
            force: [1.0, -2.0, 0.5],
            flags: FLAG_SATURATED,
        };
        assert_eq!(decode_force(&encode_force(&f)), Ok(f));
        let b = encode_pose(&p);
        assert_eq!(decode_pose(&b[..83]), Err(Reject::Short));
        assert_eq!(decode_force(&b), Err(Reject::Long));
    }
}
