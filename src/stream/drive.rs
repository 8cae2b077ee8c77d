//! The browser as a haptic device (`nvtmm view --drive CONFIG`,
//! docs/DRIVING.md).
//!
//! The page sends small JSON commands over the view server's `/drive`
//! WebSocket: insertion and roll rates (keys, gamepad), insertion and roll
//! steps (mouse wheel, drag) and three buttons (instrument switch,
//! contrast, fluoroscopy). A pose thread integrates them and sends the
//! service's UDP bridge a version-2 pose datagram every millisecond
//! (`haptics::udp`), the stylus placed on the wire's hub drive axis
//! (`[wire.drive]`: `stylus_at(inserted)`, `gimbal_for(roll)`), so the
//! service runs unchanged with `device.backend = "udp"`. When the page falls
//! silent for [`BROWSER_TIMEOUT_S`] the thread stops sending: the bridge goes
//! stale and the service's watchdog ramps the force to zero while the wire
//! is held, as for any silent device.
//!
//! Every message is checked: at most [`MAX_MESSAGE_BYTES`] of text, exactly
//! the known fields, every number finite and in range, a sequence number
//! above the last one, and at most [`RATE_BURST`] messages at once and
//! [`RATE_PER_S`] a second sustained. A refused message changes nothing and
//! is counted by reason ([`DriveCounters`]).

use crate::haptics::device::wrap_angle;
use crate::haptics::udp::{decode_force, encode_pose_v2, PoseDatagram, FORCE_LEN};
use crate::wire::drive::DriveParams;
use serde::{Deserialize, Serialize};
use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

/// Longest drive message (bytes of text).
pub const MAX_MESSAGE_BYTES: usize = 512;
/// Sustained messages a second a driver may send (more are refused).
pub const RATE_PER_S: f64 = 120.0;
/// Messages a driver may send at once (the token bucket's size).
pub const RATE_BURST: f64 = 30.0;
/// The page is silent after this long without a valid message (s): the
/// poses stop, the service's watchdog takes over. The page sends at least
/// every 50 ms while it drives.
pub const BROWSER_TIMEOUT_S: f64 = 0.25;
/// Insertion speed of the wire at `insert` = ±1 (m/s).
pub const MAX_INSERT_SPEED_M_S: f64 = 0.03;
/// Roll speed of the wire at `roll` = ±1 (rad/s).
pub const MAX_ROLL_SPEED_RAD_S: f64 = 3.0;
/// Largest insertion step of one message (m).
pub const MAX_INSERT_STEP_M: f64 = 0.005;
/// Largest roll step of one message (rad).
pub const MAX_ROLL_STEP_RAD: f64 = std::f64::consts::FRAC_PI_4;
/// Buttons the page may set (bits 0–2, `crate::task::BUTTON_*`).
pub const BUTTON_MASK: u32 = 0b111;
/// Pose datagrams a second.
pub const POSE_RATE_HZ: f64 = 1000.0;

/// One command from the page (JSON text; every field required).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct DriveMessage {
    /// Strictly increasing per connection.
    pub seq: u64,
    /// Insertion rate, a fraction of [`MAX_INSERT_SPEED_M_S`] in [−1, 1]
    /// (+ inserts).
    pub insert: f64,
    /// Roll rate, a fraction of [`MAX_ROLL_SPEED_RAD_S`] in [−1, 1].
    pub roll: f64,
    /// A one-off insertion (m) in ±[`MAX_INSERT_STEP_M`] (mouse wheel).
    pub insert_step_m: f64,
    /// A one-off roll (rad) in ±[`MAX_ROLL_STEP_RAD`] (mouse drag).
    pub roll_step_rad: f64,
    /// Buttons held ([`BUTTON_MASK`] bits).
    pub buttons: u32,
}

/// Why a message was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Refusal {
    /// Longer than [`MAX_MESSAGE_BYTES`].
    Oversized,
    /// Binary, not JSON, unknown or missing fields, wrong types.
    Malformed,
    /// A number out of its range or not finite.
    OutOfRange,
    /// A sequence number not above the last accepted one.
    OutOfOrder,
    /// Over the rate limit.
    RateLimited,
}

/// What the drive server counted.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct DriveCounters {
    /// Messages applied.
    pub accepted: u64,
    /// Refused: too long.
    pub oversized: u64,
    /// Refused: not a drive message.
    pub malformed: u64,
    /// Refused: a number out of range.
    pub out_of_range: u64,
    /// Refused: sequence number not increasing.
    pub out_of_order: u64,
    /// Refused: over the rate limit.
    pub rate_limited: u64,
    /// Connections refused: wrong or missing token.
    pub unauthorized: u64,
    /// Connections refused: another page drives.
    pub busy: u64,
    /// Pose datagrams sent.
    pub poses: u64,
    /// Pose datagrams the socket would not send.
    pub send_errors: u64,
    /// Times the page fell silent while driving.
    pub silences: u64,
}

impl DriveCounters {
    /// Messages refused, all reasons.
    pub fn refused(&self) -> u64 {
        self.oversized + self.malformed + self.out_of_range + self.out_of_order + self.rate_limited
    }
}

/// The drive server's settings (the CLI builds them from the service
/// configuration: its UDP bridge, its `[wire.drive]`, its `[guidewire]`).
#[derive(Debug, Clone, PartialEq)]
pub struct DriveSetup {
    /// Where the service's UDP bridge receives poses.
    pub device: SocketAddr,
    /// The wire's hub drive map.
    pub drive: DriveParams,
    /// Inserted length (m) when driving starts (the wire's at start).
    pub start_inserted_m: f64,
    /// Most the wire inserts (m).
    pub max_inserted_m: f64,
    /// The bridge's workspace box (m, device frame).
    pub workspace_min_m: [f64; 3],
    /// See `workspace_min_m`.
    pub workspace_max_m: [f64; 3],
    /// A token the page must present (`/drive?token=…`); None: none asked
    /// (loopback only).
    pub token: Option<String>,
}

impl DriveSetup {
    /// The setup for the service configured by `cfg`: its UDP bridge (the
    /// address and workspace of `device.udp`), its `[wire.drive]`, its
    /// `[guidewire] inserted_m`. An error says what is missing (the UDP
    /// backend, a wire) or names the file and key.
    pub fn from_service(
        cfg: &crate::service::config::ServiceConfig,
        token: Option<String>,
    ) -> Result<DriveSetup, String> {
        use crate::service::config::Backend;
        if cfg.device.backend != Backend::Udp {
            return Err(format!(
                "{}: device.backend is {:?}; the browser drives through the UDP bridge: set device.backend = \"udp\"",
                cfg.path.display(),
                cfg.device.backend
            ));
        }
        let (Some(wire), Some(g)) = (&cfg.wire, &cfg.guidewire) else {
            return Err(format!(
                "{}: no [wire] and [guidewire]: there is nothing to drive",
                cfg.path.display()
            ));
        };
        let udp = crate::haptics::udp::UdpParams::load(&cfg.resolve(&cfg.device.udp)).map_err(|e| e.to_string())?;
        let device: SocketAddr = udp
            .bind
            .parse()
            .map_err(|e| format!("device.udp bind {:?}: {e}", udp.bind))?;
        Ok(DriveSetup {
            device,
            drive: wire.drive,
            start_inserted_m: g.inserted_m,
            max_inserted_m: wire.max_inserted_m(),
            workspace_min_m: udp.workspace_min_m,
            workspace_max_m: udp.workspace_max_m,
            token,
        })
    }
}

/// Token bucket.
#[derive(Debug, Clone, Copy)]
struct Bucket {
    level: f64,
    at: Instant,
}

impl Bucket {
    fn take(&mut self, now: Instant) -> bool {
        let dt = now.saturating_duration_since(self.at).as_secs_f64();
        self.at = now;
        self.level = (self.level + dt * RATE_PER_S).min(RATE_BURST);
        if self.level >= 1.0 {
            self.level -= 1.0;
            true
        } else {
            false
        }
    }
}

/// The state the page commands and the pose thread integrates.
#[derive(Debug)]
struct State {
    counters: DriveCounters,
    last_seq: Option<u64>,
    bucket: Bucket,
    insert_rate: f64,
    roll_rate: f64,
    pending_insert_m: f64,
    pending_roll_rad: f64,
    buttons: u32,
    last_message: Option<Instant>,
    inserted_m: f64,
    roll_rad: f64,
    sending: bool,
    connected: bool,
    force_n: [f64; 3],
    last_pose_at: Option<Instant>,
    zero_force_at: Option<Instant>,
    last_pose_seq: u64,
    silence: SilenceFigures,
    /// The stream's newest wire polyline length (m), to start from where
    /// the wire is (a restarted page or view server must not yank it).
    stream_inserted_m: Option<f64>,
}

/// A running drive server (its pose thread runs until the value is dropped).
#[derive(Debug)]
pub struct DriveServer {
    setup: DriveSetup,
    state: Arc<Mutex<State>>,
    stop: Arc<AtomicBool>,
    addr: SocketAddr,
}

/// How the service answered the last silence of the page: counted in its
/// force datagrams, one per device period.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct SilenceFigures {
    /// Force datagrams that answered the last pose sent (the service had
    /// read nothing newer) before the first zero force.
    pub periods_to_zero: Option<u64>,
    /// Force datagrams answering the last pose so far.
    pub periods: u64,
    /// Largest force magnitude (N) received while poses went out.
    pub force_peak_n: f64,
}

/// What the page is told a few times a second.
#[derive(Debug, Clone, Serialize)]
pub struct DriveStatus {
    /// Whether poses are going out.
    pub sending: bool,
    /// Commanded inserted length (m).
    pub inserted_m: f64,
    /// Commanded roll (rad).
    pub roll_rad: f64,
    /// Buttons held.
    pub buttons: u32,
    /// The newest force the service sent back (N, device frame).
    pub force_n: [f64; 3],
    /// Counters.
    pub counters: DriveCounters,
}

impl DriveServer {
    /// Binds a UDP socket toward the bridge and starts the pose thread.
    pub fn start(setup: DriveSetup) -> std::io::Result<DriveServer> {
        let local: SocketAddr = if setup.device.is_ipv4() {
            "0.0.0.0:0".parse().expect("literal")
        } else {
            "[::]:0".parse().expect("literal")
        };
        let sock = UdpSocket::bind(local)?;
        sock.connect(setup.device)?;
        sock.set_nonblocking(true)?;
        let addr = sock.local_addr()?;
        let state = Arc::new(Mutex::new(State {
            counters: DriveCounters::default(),
            last_seq: None,
            bucket: Bucket {
                level: RATE_BURST,
                at: Instant::now(),
            },
            insert_rate: 0.0,
            roll_rate: 0.0,
            pending_insert_m: 0.0,
            pending_roll_rad: 0.0,
            buttons: 0,
            last_message: None,
            inserted_m: setup.start_inserted_m,
            roll_rad: 0.0,
            sending: false,
            connected: false,
            force_n: [0.0; 3],
            last_pose_at: None,
            zero_force_at: None,
            last_pose_seq: 0,
            silence: SilenceFigures::default(),
            stream_inserted_m: None,
        }));
        let stop = Arc::new(AtomicBool::new(false));
        let (st, sp, su) = (state.clone(), stop.clone(), setup.clone());
        std::thread::Builder::new()
            .name("view-drive".into())
            .spawn(move || pose_thread(sock, &su, &st, &sp))?;
        Ok(DriveServer {
            setup,
            state,
            stop,
            addr,
        })
    }

    fn lock(&self) -> MutexGuard<'_, State> {
        lock(&self.state)
    }

    /// The local address poses go out from (forces come back to it).
    pub fn local_addr(&self) -> SocketAddr {
        self.addr
    }

    /// Whether `token` opens the drive (always, when none is configured).
    /// Compared in constant time.
    pub fn authorized(&self, token: Option<&str>) -> bool {
        let Some(want) = &self.setup.token else { return true };
        let got = token.unwrap_or("").as_bytes();
        let want = want.as_bytes();
        let mut diff = (got.len() != want.len()) as u8;
        for (i, w) in want.iter().enumerate() {
            diff |= w ^ got.get(i).copied().unwrap_or(0);
        }
        diff == 0
    }

    /// Counts a connection refused for its token.
    pub fn count_unauthorized(&self) {
        self.lock().counters.unauthorized += 1;
    }

    /// Takes the drive for one page; false (and counted) if another page has it.
    pub fn connect(&self) -> bool {
        let mut s = self.lock();
        if s.connected {
            s.counters.busy += 1;
            return false;
        }
        s.connected = true;
        s.last_seq = None;
        true
    }

    /// Releases the drive (the page went away; the poses stop at the timeout).
    pub fn disconnect(&self) {
        let mut s = self.lock();
        s.connected = false;
        s.insert_rate = 0.0;
        s.roll_rate = 0.0;
    }

    /// Checks one text message and applies it; a refusal is counted.
    pub fn handle_text(&self, text: &str) -> Result<(), Refusal> {
        self.handle_at(text, Instant::now())
    }

    /// Counts a binary message (refused as malformed).
    pub fn handle_binary(&self) -> Refusal {
        self.lock().counters.malformed += 1;
        Refusal::Malformed
    }

    fn handle_at(&self, text: &str, now: Instant) -> Result<(), Refusal> {
        let mut s = self.lock();
        if !s.bucket.take(now) {
            s.counters.rate_limited += 1;
            return Err(Refusal::RateLimited);
        }
        let r = check(text, s.last_seq);
        match r {
            Ok(m) => {
                s.counters.accepted += 1;
                s.last_seq = Some(m.seq);
                s.insert_rate = m.insert;
                s.roll_rate = m.roll;
                s.pending_insert_m += m.insert_step_m;
                s.pending_roll_rad += m.roll_step_rad;
                s.buttons = m.buttons;
                s.last_message = Some(now);
                Ok(())
            }
            Err(e) => {
                let c = &mut s.counters;
                match e {
                    Refusal::Oversized => c.oversized += 1,
                    Refusal::Malformed => c.malformed += 1,
                    Refusal::OutOfRange => c.out_of_range += 1,
                    Refusal::OutOfOrder => c.out_of_order += 1,
                    Refusal::RateLimited => c.rate_limited += 1,
                }
                Err(e)
            }
        }
    }

    /// Tells the server where the wire is by the stream (its polyline's
    /// length, m), for the start of the next drive.
    pub fn note_stream_inserted(&self, inserted_m: f64) {
        if inserted_m.is_finite() {
            self.lock().stream_inserted_m = Some(inserted_m);
        }
    }

    /// Counters and commanded state.
    pub fn status(&self) -> DriveStatus {
        let s = self.lock();
        DriveStatus {
            sending: s.sending,
            inserted_m: s.inserted_m,
            roll_rad: s.roll_rad,
            buttons: s.buttons,
            force_n: s.force_n,
            counters: s.counters,
        }
    }

    /// When the last pose went out, when the service's force first came
    /// back zero after it, and the same counted in device periods (for the
    /// silence measurement).
    pub fn silence_timing(&self) -> (Option<Instant>, Option<Instant>, SilenceFigures) {
        let s = self.lock();
        (s.last_pose_at, s.zero_force_at, s.silence)
    }
}

impl Drop for DriveServer {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
    }
}

fn lock(m: &Mutex<State>) -> MutexGuard<'_, State> {
    // Every field is replaced whole; a panicking holder leaves nothing half-done.
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// Parses and range-checks a message (any text; never panics).
pub fn check(text: &str, last_seq: Option<u64>) -> Result<DriveMessage, Refusal> {
    if text.len() > MAX_MESSAGE_BYTES {
        return Err(Refusal::Oversized);
    }
    let m: DriveMessage = serde_json::from_str(text).map_err(|_| Refusal::Malformed)?;
    let within = |v: f64, lim: f64| v.is_finite() && v.abs() <= lim;
    if !(within(m.insert, 1.0)
        && within(m.roll, 1.0)
        && within(m.insert_step_m, MAX_INSERT_STEP_M)
        && within(m.roll_step_rad, MAX_ROLL_STEP_RAD)
        && m.buttons & !BUTTON_MASK == 0)
    {
        return Err(Refusal::OutOfRange);
    }
    if last_seq.is_some_and(|l| m.seq <= l) {
        return Err(Refusal::OutOfOrder);
    }
    Ok(m)
}

/// The inserted-length range (m) whose stylus points lie in the bridge's
/// workspace (the drive map is affine along its axis).
fn insert_range(setup: &DriveSetup) -> (f64, f64) {
    let (mut lo, mut hi) = (0.0f64, setup.max_inserted_m);
    let a = setup.drive.stylus_at(0.0);
    let b = setup.drive.stylus_at(1.0);
    for k in 0..3 {
        let slope = b[k] - a[k];
        if slope.abs() < 1e-12 {
            continue;
        }
        // a + slope·x within [min, max] (a small margin inside).
        let m = 1e-4;
        let x0 = (setup.workspace_min_m[k] + m - a[k]) / slope;
        let x1 = (setup.workspace_max_m[k] - m - a[k]) / slope;
        lo = lo.max(x0.min(x1));
        hi = hi.min(x0.max(x1));
    }
    (lo, hi.max(lo))
}

fn pose_thread(sock: UdpSocket, setup: &DriveSetup, state: &Mutex<State>, stop: &AtomicBool) {
    let epoch = Instant::now();
    let period = Duration::from_secs_f64(1.0 / POSE_RATE_HZ);
    let (lo, hi) = insert_range(setup);
    let mut seq = 0u64;
    let mut prev: Option<(crate::math::Vec3, Instant)> = None;
    let mut buf = [0u8; 2 * FORCE_LEN];
    let mut next = Instant::now();
    while !stop.load(Ordering::Relaxed) {
        next += period;
        let now = Instant::now();
        if next > now {
            std::thread::sleep(next - now);
        } else {
            next = now;
        }
        let now = Instant::now();
        // Forces back from the service.
        while let Ok(n) = sock.recv(&mut buf) {
            if let Ok(f) = decode_force(&buf[..n]) {
                let mut s = lock(state);
                s.force_n = f.force;
                if s.sending {
                    let m = f.force.iter().map(|v| v * v).sum::<f64>().sqrt();
                    s.silence.force_peak_n = s.silence.force_peak_n.max(m);
                } else if f.pose_seq == s.last_pose_seq {
                    s.silence.periods += 1;
                    if f.force == [0.0; 3] && s.zero_force_at.is_none() {
                        s.zero_force_at = Some(now);
                        s.silence.periods_to_zero = Some(s.silence.periods);
                    }
                }
            }
        }
        let mut s = lock(state);
        let live = s
            .last_message
            .is_some_and(|t| now.saturating_duration_since(t).as_secs_f64() <= BROWSER_TIMEOUT_S);
        if !live {
            if s.sending {
                s.sending = false;
                s.counters.silences += 1;
                s.zero_force_at = None;
                s.silence.periods = 0;
                s.silence.periods_to_zero = None;
            }
            s.insert_rate = 0.0;
            s.roll_rate = 0.0;
            s.pending_insert_m = 0.0;
            s.pending_roll_rad = 0.0;
            prev = None;
            continue;
        }
        if !s.sending {
            // A new drive starts where the wire is (by the stream), so
            // the hub is not pulled to a stale insertion.
            if let Some(x) = s
                .stream_inserted_m
                .filter(|_| s.last_pose_at.is_none_or(|t| now - t > Duration::from_secs(1)))
            {
                s.inserted_m = x.clamp(lo, hi);
            }
            s.sending = true;
        }
        let dt = period.as_secs_f64();
        let insert = s.insert_rate * MAX_INSERT_SPEED_M_S * dt + s.pending_insert_m;
        let roll = s.roll_rate * MAX_ROLL_SPEED_RAD_S * dt + s.pending_roll_rad;
        s.pending_insert_m = 0.0;
        s.pending_roll_rad = 0.0;
        s.inserted_m = (s.inserted_m + insert).clamp(lo, hi);
        s.roll_rad += roll;
        let position = setup.drive.stylus_at(s.inserted_m);
        let mut gimbal = setup.drive.gimbal_for(s.roll_rad);
        for g in &mut gimbal {
            *g = wrap_angle(*g);
        }
        let velocity = match prev {
            Some((p, t)) if now > t => (position - p) / (now - t).as_secs_f64(),
            _ => crate::math::Vec3::zeros(),
        };
        prev = Some((position, now));
        seq += 1;
        let d = PoseDatagram {
            seq,
            device_time_s: now.duration_since(epoch).as_secs_f64(),
            position: [position.x, position.y, position.z],
            velocity: [velocity.x, velocity.y, velocity.z],
            buttons: s.buttons,
            status: 0,
            error_code: 0,
            gimbal_rad: gimbal,
        };
        match sock.send(&encode_pose_v2(&d)) {
            Ok(_) => {
                s.counters.poses += 1;
                s.last_pose_at = Some(now);
                s.last_pose_seq = seq;
            }
            Err(_) => s.counters.send_errors += 1,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn setup(device: SocketAddr) -> DriveSetup {
        DriveSetup {
            device,
            drive: DriveParams {
                inserted_at_origin_m: 0.12,
                ..DriveParams::default()
            },
            start_inserted_m: 0.02,
            max_inserted_m: 0.28,
            workspace_min_m: [-0.08, -0.06, -0.06],
            workspace_max_m: [0.08, 0.06, 0.06],
            token: Some("s3cret".into()),
        }
    }

    fn msg(seq: u64, insert: f64) -> String {
        format!(r#"{{"seq":{seq},"insert":{insert},"roll":0,"insert_step_m":0,"roll_step_rad":0,"buttons":4}}"#)
    }

    #[test]
    fn garbage_and_out_of_range_messages_are_refused_and_counted() {
        let peer = UdpSocket::bind("127.0.0.1:0").unwrap();
        let d = DriveServer::start(setup(peer.local_addr().unwrap())).unwrap();
        let t0 = Instant::now();
        let at = |k: u64| t0 + Duration::from_millis(20 * k);
        assert_eq!(d.handle_at(&msg(1, 0.5), at(1)), Ok(()));
        let cases: [(&str, Refusal); 12] = [
            ("", Refusal::Malformed),
            ("{", Refusal::Malformed),
            ("null", Refusal::Malformed),
            (r#"{"seq":2}"#, Refusal::Malformed),
            (
                r#"{"seq":2,"insert":0,"roll":0,"insert_step_m":0,"roll_step_rad":0,"buttons":0,"x":1}"#,
                Refusal::Malformed,
            ),
            (
                r#"{"seq":-2,"insert":0,"roll":0,"insert_step_m":0,"roll_step_rad":0,"buttons":0}"#,
                Refusal::Malformed,
            ),
            (&msg(2, 1.5), Refusal::OutOfRange),
            (
                r#"{"seq":2,"insert":0,"roll":0,"insert_step_m":1e300,"roll_step_rad":0,"buttons":0}"#,
                Refusal::OutOfRange,
            ),
            (
                r#"{"seq":2,"insert":0,"roll":0,"insert_step_m":0,"roll_step_rad":0,"buttons":8}"#,
                Refusal::OutOfRange,
            ),
            (
                r#"{"seq":2,"insert":0,"roll":-1.0000001,"insert_step_m":0,"roll_step_rad":0,"buttons":0}"#,
                Refusal::OutOfRange,
            ),
            (&msg(1, 0.0), Refusal::OutOfOrder),
            (&"x".repeat(MAX_MESSAGE_BYTES + 1), Refusal::Oversized),
        ];
        for (k, (text, why)) in cases.iter().enumerate() {
            assert_eq!(d.handle_at(text, at(2 + k as u64)), Err(*why), "{text:?}");
        }
        assert_eq!(d.handle_binary(), Refusal::Malformed);
        let c = d.status().counters;
        assert_eq!(c.accepted, 1);
        assert_eq!((c.malformed, c.out_of_range, c.out_of_order, c.oversized), (7, 4, 1, 1));
        assert_eq!(c.refused(), 13);
        // A refused message changed nothing: the rate is the accepted one.
        assert_eq!(lock(&d.state).insert_rate, 0.5);
        // Random bytes as text never panic.
        let mut x = 0x2545F4914F6CDD1Du64;
        for _ in 0..2000 {
            let n = (x % 80) as usize;
            let s: String = (0..n)
                .map(|_| {
                    x ^= x << 13;
                    x ^= x >> 7;
                    x ^= x << 17;
                    b"{}\":,0123456789.eE-+ seqinrtolbu_mpad"[(x % 36) as usize] as char
                })
                .collect();
            let _ = check(&s, Some(5));
        }
    }

    #[test]
    fn a_flood_is_rate_limited() {
        let peer = UdpSocket::bind("127.0.0.1:0").unwrap();
        let d = DriveServer::start(setup(peer.local_addr().unwrap())).unwrap();
        let t0 = Instant::now();
        // 200 messages within 10 ms: the burst passes, the rest is refused.
        let mut ok = 0;
        for k in 0..200u64 {
            if d.handle_at(&msg(k + 1, 0.0), t0 + Duration::from_micros(50 * k))
                .is_ok()
            {
                ok += 1;
            }
        }
        let c = d.status().counters;
        assert!(ok as f64 <= RATE_BURST + 2.0, "{ok} accepted");
        assert_eq!(c.rate_limited, 200 - ok);
        // A second later the bucket is full again.
        assert!(d.handle_at(&msg(1000, 0.0), t0 + Duration::from_secs(2)).is_ok());
    }

    #[test]
    fn the_token_is_checked_and_one_page_drives() {
        let peer = UdpSocket::bind("127.0.0.1:0").unwrap();
        let d = DriveServer::start(setup(peer.local_addr().unwrap())).unwrap();
        assert!(d.authorized(Some("s3cret")));
        for bad in [None, Some(""), Some("s3cre"), Some("s3cret!"), Some("S3cret")] {
            assert!(!d.authorized(bad), "{bad:?}");
        }
        assert!(d.connect());
        assert!(!d.connect());
        assert_eq!(d.status().counters.busy, 1);
        d.disconnect();
        assert!(d.connect());
    }

    #[test]
    fn poses_follow_the_page_and_stop_when_it_falls_silent() {
        use crate::haptics::udp::decode_pose;
        let peer = UdpSocket::bind("127.0.0.1:0").unwrap();
        peer.set_read_timeout(Some(Duration::from_secs(2))).unwrap();
        let s = setup(peer.local_addr().unwrap());
        let d = DriveServer::start(s.clone()).unwrap();
        assert!(d.connect());
        d.handle_text(&msg(1, 1.0)).unwrap();
        let mut buf = [0u8; 256];
        let n = peer.recv(&mut buf).unwrap();
        let first = decode_pose(&buf[..n]).unwrap();
        assert_eq!(first.buttons, 4);
        // Keep driving for 100 ms: the stylus moves along the axis (−z
        // inserts), the insertion grows at the commanded speed.
        let t0 = Instant::now();
        let mut k = 2;
        while t0.elapsed() < Duration::from_millis(100) {
            d.handle_text(&msg(k, 1.0)).unwrap();
            k += 1;
            std::thread::sleep(Duration::from_millis(20));
        }
        let st = d.status();
        assert!(st.sending);
        assert!(
            st.inserted_m > 0.02 + 0.5 * 0.1 * MAX_INSERT_SPEED_M_S,
            "{}",
            st.inserted_m
        );
        let mut last = first;
        while let Ok(n) = peer.recv(&mut buf) {
            last = decode_pose(&buf[..n]).unwrap();
            if last.seq > first.seq + 50 {
                break;
            }
        }
        assert!(last.position[2] < first.position[2]);
        assert_eq!(last.position[0], 0.0);
        // Silence: the poses stop after the browser timeout.
        std::thread::sleep(Duration::from_secs_f64(BROWSER_TIMEOUT_S + 0.2));
        assert!(!d.status().sending);
        assert_eq!(d.status().counters.silences, 1);
        peer.set_read_timeout(Some(Duration::from_millis(100))).unwrap();
        while peer.recv(&mut buf).is_ok() {}
        assert!(peer.recv(&mut buf).is_err(), "a pose after the silence");
    }

    #[test]
    fn the_insertion_stays_in_the_workspace() {
        let peer = UdpSocket::bind("127.0.0.1:0").unwrap();
        let s = setup(peer.local_addr().unwrap());
        let (lo, hi) = insert_range(&s);
        // Axis −z, 3 mm of wire per mm of stylus around 0.12 m: z in ±0.06.
        assert!((lo - 0.0).abs() < 1e-9, "{lo}");
        assert_eq!(hi, s.max_inserted_m);
        let long = DriveSetup {
            max_inserted_m: 1.0,
            ..s.clone()
        };
        let (_, hi) = insert_range(&long);
        assert!((hi - (0.12 + 3.0 * (0.06 - 1e-4))).abs() < 1e-9, "{hi}");
        for x in [lo, hi] {
            let p = s.drive.stylus_at(x);
            assert!(p.z.abs() <= 0.06);
        }
    }
}
